//! The TOML scene file (strata's shared conventions): schema, validation, mesh resolution.
//!
//! Every key of strata's shared conventions is accepted; unknown keys are errors (a typo must not silently fall back
//! to a default), and so are arrays of the wrong length (serde's own `[f32; 3]` stops reading
//! after three elements and the TOML deserializer ignores the rest, so `[r, g, b, a]` would pass
//! as `[r, g, b]`: `Numbers` counts them all). Every error names the key (`objects[2].color`)
//! and its line, found by a second, spanned parse (module `keys`) when an error is reported;
//! syntax and type errors also give the column. Object names must be unique, non-empty and not plain numbers: remote nodes select
//! objects by name or by position. Defaults for keys left out:
//!
//! | key | default |
//! | --- | --- |
//! | `width`, `height` | 1280, 720 |
//! | `background` | `[1, 1, 1]` |
//! | `[camera]` | eye `[0, 0, 1.6]`, target origin, up `+y`, `fovy_deg` 45, near 0.01, far 100 |
//! | object `name` | the built-in shape's name or the mesh file's stem |
//! | `fit` | `false` |
//! | `color` | the glTF material's base colour, else `[0.8, 0.8, 0.8, 1]` |
//! | `shading` | `"headlight"` |
//! | `translate`, `rotate_deg`, `scale` | `[0, 0, 0]`, `[0, 0, 0]`, `1` (`scale` may also be `[x, y, z]`) |
//!
//! A negative `scale` factor mirrors the object. That reverses its triangles' winding, which
//! changes nothing here: no face is culled, the rasterizer covers either winding, normals go
//! through the inverse transpose (which mirrors them too) and headlight shading uses `|N·L|`. A
//! zero factor is refused: it flattens the object and makes the normal matrix singular.
//!
//! An object names exactly one of `mesh` (a file, found through [`SearchPath`]) or `builtin` (a
//! shape of [`crate::builtin::shapes`]).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec3};
use serde::Deserialize;
use strata_core::{Material, ObjectId, Shading};

use super::keys::KeyIndex;
use super::{Animation, Scene, SceneError, SceneErrorKind, SceneObject};
use crate::builtin::shapes;
use crate::camera::Camera;
use crate::load;
use crate::mesh::{Aabb, Mesh};
use crate::search_path::SearchPath;

/// The largest accepted image side, in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// Where a scene text came from: decides how errors name it and where relative meshes are found.
#[derive(Clone, Copy, Debug)]
pub enum SceneOrigin<'a> {
    /// A file on disk; meshes are looked up next to it first.
    File(&'a Path),
    /// A built-in scene with this name; meshes come from the search path only.
    Builtin(&'a str),
}

impl SceneOrigin<'_> {
    fn label(&self) -> String {
        match self {
            SceneOrigin::File(p) => p.display().to_string(),
            SceneOrigin::Builtin(n) => format!("built-in scene '{n}'"),
        }
    }

    fn name(&self) -> String {
        match self {
            SceneOrigin::File(p) => file_stem(p),
            SceneOrigin::Builtin(n) => (*n).to_owned(),
        }
    }

    fn dir(&self) -> Option<&Path> {
        match self {
            SceneOrigin::File(p) => Some(
                p.parent()
                    .filter(|d| !d.as_os_str().is_empty())
                    .unwrap_or(Path::new(".")),
            ),
            SceneOrigin::Builtin(_) => None,
        }
    }
}

/// Reads and resolves the scene file at `path`.
pub fn load(path: &Path, search: &SearchPath) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SceneError::new(path.display().to_string(), None, SceneErrorKind::Io(e)))?;
    parse(&text, SceneOrigin::File(path), search)
}

/// Parses, validates and resolves a scene text.
pub fn parse(
    text: &str,
    origin: SceneOrigin<'_>,
    search: &SearchPath,
) -> Result<Scene, SceneError> {
    let label = origin.label();
    let file: SceneFile = toml::from_str(text).map_err(|e| toml_error(&label, text, &e))?;
    Resolver {
        label: &label,
        text,
        origin,
        search,
        models: HashMap::new(),
        shapes: HashMap::new(),
    }
    .resolve(file)
}

/// A TOML syntax or schema error, with the key and the position its span points at.
fn toml_error(label: &str, text: &str, e: &toml::de::Error) -> SceneError {
    let message = e.message().trim_end().to_owned();
    let Some(span) = e.span() else {
        return SceneError::new(label, None, SceneErrorKind::Toml(message));
    };
    let keys = KeyIndex::new(text);
    SceneError::new(
        label,
        keys.key_at(&span).map(str::to_owned),
        SceneErrorKind::Toml(message),
    )
    .at(Some(keys.position(span.start)))
}

// ----- schema ---------------------------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    // Signed, so that `width = -5` is refused with the allowed range rather than a type name.
    width: Option<i64>,
    height: Option<i64>,
    background: Option<Numbers<3>>,
    camera: Option<CameraFile>,
    #[serde(default)]
    objects: Vec<ObjectFile>,
    animation: Option<AnimationFile>,
    volume: Option<super::volume::VolumeFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    eye: Option<Numbers<3>>,
    target: Option<Numbers<3>>,
    up: Option<Numbers<3>>,
    fovy_deg: Option<f32>,
    near: Option<f32>,
    far: Option<f32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectFile {
    name: Option<String>,
    mesh: Option<String>,
    builtin: Option<String>,
    #[serde(default)]
    fit: bool,
    color: Option<Numbers<4>>,
    shading: Option<ShadingFile>,
    translate: Option<Numbers<3>>,
    rotate_deg: Option<Numbers<3>>,
    scale: Option<ScaleFile>,
}

#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "lowercase")]
enum ShadingFile {
    Headlight,
    Unlit,
}

/// `scale = 2.0` or `scale = [1.0, 2.0, 0.5]`.
#[derive(Clone, Copy)]
struct ScaleFile([f32; 3]);

impl<'de> Deserialize<'de> for ScaleFile {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = ScaleFile;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or an array of 3 numbers")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<ScaleFile, E> {
                Ok(ScaleFile([v as f32; 3]))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<ScaleFile, E> {
                Ok(ScaleFile([v as f32; 3]))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                seq: A,
            ) -> Result<ScaleFile, A::Error> {
                NumbersVisitor::<3>.visit_seq(seq).map(|n| ScaleFile(n.0))
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AnimationFile {
    frames: i64,
    #[serde(default)]
    rotate_deg_per_frame: Numbers<3>,
}

/// An array of exactly `N` numbers (integers or floats).
///
/// Unlike serde's `[f32; N]`, which reads `N` elements and leaves the rest unread (and the TOML
/// deserializer does not object), every element is counted, so `[1, 0, 0, 99]` is an error.
#[derive(Clone, Copy, Debug)]
pub(super) struct Numbers<const N: usize>(pub(super) [f32; N]);

impl<const N: usize> Default for Numbers<N> {
    fn default() -> Self {
        Numbers([0.0; N])
    }
}

impl<'de, const N: usize> Deserialize<'de> for Numbers<N> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_seq(NumbersVisitor::<N>)
    }
}

struct NumbersVisitor<const N: usize>;

impl<'de, const N: usize> serde::de::Visitor<'de> for NumbersVisitor<N> {
    type Value = Numbers<N>;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "an array of {N} numbers")
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Numbers<N>, A::Error> {
        let mut out = [0.0f32; N];
        let mut found = 0usize;
        for slot in out.iter_mut() {
            match seq.next_element::<f32>()? {
                Some(v) => *slot = v,
                None => break,
            }
            found += 1;
        }
        while seq.next_element::<serde::de::IgnoredAny>()?.is_some() {
            found += 1;
        }
        if found == N {
            Ok(Numbers(out))
        } else {
            Err(serde::de::Error::custom(format!(
                "expected an array of {N} numbers, found {found} value{}",
                if found == 1 { "" } else { "s" }
            )))
        }
    }
}

impl super::volume::Checker for Resolver<'_> {
    fn invalid_at(&self, key: &str, msg: String) -> SceneError {
        self.invalid(key, msg)
    }

    fn find_file(&self, key: &str, name: &str) -> Result<PathBuf, SceneError> {
        self.find(key, name)
    }
}

// ----- validation and resolution --------------------------------------------------------------

/// One loaded model, shared by every object that names the same file.
struct LoadedPart {
    name: String,
    mesh: Arc<Mesh>,
    transform: Mat4,
    base_color: Option<[f32; 4]>,
}

struct Resolver<'a> {
    label: &'a str,
    /// The scene text, for the lines of errors.
    text: &'a str,
    origin: SceneOrigin<'a>,
    search: &'a SearchPath,
    models: HashMap<PathBuf, Arc<Vec<LoadedPart>>>,
    shapes: HashMap<String, Arc<Vec<LoadedPart>>>,
}

impl Resolver<'_> {
    fn invalid(&self, key: impl Into<String>, msg: impl Into<String>) -> SceneError {
        self.error(key, SceneErrorKind::Invalid(msg.into()))
    }

    /// An error at `key`, placed at the key's line (or its table's, for a key left out).
    fn error(&self, key: impl Into<String>, kind: SceneErrorKind) -> SceneError {
        let key = key.into();
        let at = KeyIndex::new(self.text).position_of(&key);
        SceneError::new(self.label, Some(key), kind).at(at)
    }

    fn resolve(mut self, file: SceneFile) -> Result<Scene, SceneError> {
        let width = self.image_side("width", file.width.unwrap_or(1280))?;
        let height = self.image_side("height", file.height.unwrap_or(720))?;
        let background = file.background.map_or([1.0; 3], |b| b.0);
        self.unit_range("background", &background)?;
        let camera = self.camera(file.camera)?;
        let volume = file
            .volume
            .map(|v| super::volume::check(&self, v))
            .transpose()?;
        if file.objects.is_empty() && volume.is_none() {
            return Err(self.invalid("objects", "the scene has no [[objects]]; add at least one"));
        }
        let mut objects = Vec::new();
        let mut names = Names::default();
        for (i, obj) in file.objects.into_iter().enumerate() {
            self.object(i, obj, &mut names, &mut objects)?;
        }
        let animation = match file.animation {
            None => None,
            Some(a) => {
                let frames = u32::try_from(a.frames)
                    .ok()
                    .filter(|&f| f >= 1)
                    .ok_or_else(|| {
                        self.invalid(
                            "animation.frames",
                            format!("{} is outside 1..={}", a.frames, u32::MAX),
                        )
                    })?;
                self.finite("animation.rotate_deg_per_frame", &a.rotate_deg_per_frame.0)?;
                Some(Animation {
                    frames,
                    rotate_deg_per_frame: Vec3::from(a.rotate_deg_per_frame.0),
                })
            }
        };
        Ok(Scene {
            name: self.origin.name(),
            origin: self.label.to_owned(),
            width,
            height,
            background,
            camera,
            objects,
            animation,
            volume,
        })
    }

    /// `width` or `height`, in 1..=[`MAX_IMAGE_SIDE`].
    fn image_side(&self, key: &str, v: i64) -> Result<u32, SceneError> {
        u32::try_from(v)
            .ok()
            .filter(|s| (1..=MAX_IMAGE_SIDE).contains(s))
            .ok_or_else(|| self.invalid(key, format!("{v} is outside 1..={MAX_IMAGE_SIDE} pixels")))
    }

    fn finite(&self, key: &str, v: &[f32]) -> Result<(), SceneError> {
        match v.iter().find(|c| !c.is_finite()) {
            Some(c) => Err(self.invalid(key, format!("{c} is not a finite number"))),
            None => Ok(()),
        }
    }

    fn unit_range(&self, key: &str, v: &[f32]) -> Result<(), SceneError> {
        match v.iter().find(|c| !(0.0..=1.0).contains(*c)) {
            Some(c) => Err(self.invalid(key, format!("{c} is outside [0, 1]"))),
            None => Ok(()),
        }
    }

    fn camera(&self, file: Option<CameraFile>) -> Result<Camera, SceneError> {
        let d = Camera::default();
        let Some(c) = file else { return Ok(d) };
        let cam = Camera {
            eye: c.eye.map_or(d.eye, |v| Vec3::from(v.0)),
            target: c.target.map_or(d.target, |v| Vec3::from(v.0)),
            up: c.up.map_or(d.up, |v| Vec3::from(v.0)),
            fovy_deg: c.fovy_deg.unwrap_or(d.fovy_deg),
            near: c.near.unwrap_or(d.near),
            far: c.far.unwrap_or(d.far),
        };
        cam.check().map_err(|e| self.invalid(e.key, e.message))?;
        Ok(cam)
    }

    fn object(
        &mut self,
        i: usize,
        obj: ObjectFile,
        names: &mut Names,
        out: &mut Vec<SceneObject>,
    ) -> Result<(), SceneError> {
        let key = |k: &str| format!("objects[{i}].{k}");
        let (parts, default_name) = match (&obj.mesh, &obj.builtin) {
            (Some(_), Some(_)) => {
                return Err(self.invalid(
                    format!("objects[{i}]"),
                    "has both `mesh` and `builtin`; give exactly one",
                ));
            }
            (None, None) => {
                return Err(self.invalid(
                    format!("objects[{i}]"),
                    "needs `mesh = \"file\"` or `builtin = \"shape\"`",
                ));
            }
            (Some(mesh), None) => (self.mesh(&key("mesh"), mesh)?, file_stem(Path::new(mesh))),
            (None, Some(name)) => (self.shape(&key("builtin"), name)?, name.clone()),
        };
        let name = self.object_name(i, obj.name, default_name, names)?;
        let color = obj.color.map(|c| c.0);
        if let Some(c) = &color {
            self.unit_range(&key("color"), c)?;
        }
        let translate = obj.translate.unwrap_or_default().0;
        self.finite(&key("translate"), &translate)?;
        let rotate_deg = obj.rotate_deg.unwrap_or_default().0;
        self.finite(&key("rotate_deg"), &rotate_deg)?;
        let scale = obj.scale.map_or([1.0; 3], |s| s.0);
        if let Some(s) = scale.iter().find(|s| !s.is_finite() || **s == 0.0) {
            return Err(self.invalid(
                key("scale"),
                format!("{s} must be a finite, non-zero factor (a negative one mirrors)"),
            ));
        }
        let fit = if obj.fit {
            let mut b = Aabb::EMPTY;
            for p in parts.iter() {
                for v in p.mesh.positions() {
                    b.include(p.transform.transform_point3(Vec3::from(*v)));
                }
            }
            let extent = b.extent().max_element();
            if b.is_empty() || !extent.is_finite() || extent <= 0.0 {
                return Err(self.invalid(key("fit"), "the mesh has no extent to fit"));
            }
            Mat4::from_scale(Vec3::splat(1.0 / extent)) * Mat4::from_translation(-b.center())
        } else {
            Mat4::IDENTITY
        };
        let shading = match obj.shading.unwrap_or(ShadingFile::Headlight) {
            ShadingFile::Headlight => Shading::Headlight,
            ShadingFile::Unlit => Shading::Unlit,
        };
        let part_names = part_names(&name, &parts);
        for (part, part_name) in parts.iter().zip(part_names) {
            let id = u32::try_from(out.len())
                .map_err(|_| self.invalid("objects", "more than 2^32 objects"))?;
            self.claim_part_name(i, &part_name, names)?;
            out.push(SceneObject {
                name: part_name,
                id: ObjectId(id),
                mesh: part.mesh.clone(),
                base: fit * part.transform,
                translate: Vec3::from(translate),
                rotate_deg: Vec3::from(rotate_deg),
                scale: Vec3::from(scale),
                material: Material {
                    color: color
                        .or(part.base_color)
                        .unwrap_or(Material::default().color),
                    shading,
                },
            });
        }
        Ok(())
    }

    /// The object's name: `given`, else `default`; checked and recorded in `names`.
    fn object_name(
        &self,
        i: usize,
        given: Option<String>,
        default: String,
        names: &mut Names,
    ) -> Result<String, SceneError> {
        let explicit = given.is_some();
        let key = if explicit {
            format!("objects[{i}].name")
        } else {
            format!("objects[{i}]")
        };
        let name = given.unwrap_or(default);
        let whose = if explicit {
            ""
        } else {
            " (the default name, from `mesh` or `builtin`)"
        };
        if name.trim().is_empty() {
            return Err(self.invalid(key, "is empty; give the object a name"));
        }
        if name.bytes().all(|b| b.is_ascii_digit()) {
            return Err(self.invalid(
                key,
                format!(
                    "'{name}'{whose} is a number, which would read as an object's position \
                     where objects are selected; set `name` to one with a letter in it"
                ),
            ));
        }
        if let Some(&j) = names.objects.get(&name) {
            return Err(self.invalid(
                key,
                format!(
                    "'{name}'{whose} is already the name of {}; objects are selected by name, \
                     so set `name` to tell them apart",
                    self.object_place(j)
                ),
            ));
        }
        names.objects.insert(name.clone(), i);
        Ok(name)
    }

    /// Records the name of one scene object (a glTF part's `name/part`, else the object's name).
    fn claim_part_name(&self, i: usize, name: &str, names: &mut Names) -> Result<(), SceneError> {
        if let Some(&j) = names.parts.get(name) {
            return Err(self.invalid(
                format!("objects[{i}]"),
                format!(
                    "makes an object named '{name}', a name {} already gave an object; \
                     set `name` to tell them apart",
                    self.object_place(j)
                ),
            ));
        }
        names.parts.insert(name.to_owned(), i);
        Ok(())
    }

    /// `objects[3] (line 12)`, for messages that point at a second place.
    fn object_place(&self, j: usize) -> String {
        let key = format!("objects[{j}]");
        match KeyIndex::new(self.text).position_of(&format!("{key}.name")) {
            Some(at) => format!("{key} ({at})"),
            None => key,
        }
    }

    fn mesh(&mut self, key: &str, name: &str) -> Result<Arc<Vec<LoadedPart>>, SceneError> {
        let path = self
            .search
            .resolve(name, self.origin.dir())
            .map_err(|tried| self.not_found(key, name, tried))?;
        let canonical = path.canonicalize().unwrap_or_else(|_| path.clone());
        if let Some(m) = self.models.get(&canonical) {
            return Ok(m.clone());
        }
        let model = load::load_model(&path)
            .map_err(|e| self.error(key, SceneErrorKind::Load(Box::new(e))))?;
        let parts: Arc<Vec<LoadedPart>> = Arc::new(
            model
                .parts
                .into_iter()
                .map(|p| LoadedPart {
                    name: p.name,
                    mesh: Arc::new(p.mesh.locality_ordered()),
                    transform: p.transform,
                    base_color: p.base_color,
                })
                .collect(),
        );
        if parts.is_empty() {
            return Err(self.invalid(key, format!("{} contains no triangles", path.display())));
        }
        self.models.insert(canonical, parts.clone());
        Ok(parts)
    }

    /// The error for a mesh that `resolve` did not find: a directory where a file was expected
    /// says so; otherwise every place tried is listed.
    fn not_found(&self, key: &str, name: &str, tried: Vec<PathBuf>) -> SceneError {
        match tried.iter().find(|p| p.is_dir()) {
            Some(dir) => self.error(
                key,
                SceneErrorKind::Load(Box::new(load::LoadError {
                    path: dir.clone(),
                    location: None,
                    kind: load::LoadErrorKind::IsDirectory,
                })),
            ),
            None => self.error(
                key,
                SceneErrorKind::MeshNotFound {
                    name: name.to_owned(),
                    tried,
                },
            ),
        }
    }

    /// A file other than a mesh (a volume), found like one.
    fn find(&self, key: &str, name: &str) -> Result<PathBuf, SceneError> {
        self.search
            .resolve(name, self.origin.dir())
            .map_err(|tried| self.not_found(key, name, tried))
    }

    fn shape(&mut self, key: &str, name: &str) -> Result<Arc<Vec<LoadedPart>>, SceneError> {
        if let Some(s) = self.shapes.get(name) {
            return Ok(s.clone());
        }
        let mesh = shapes::shape(name).ok_or_else(|| {
            self.error(
                key,
                SceneErrorKind::UnknownBuiltin {
                    what: "shape",
                    name: name.to_owned(),
                    known: shapes::SHAPE_NAMES.into(),
                },
            )
        })?;
        let parts = Arc::new(vec![LoadedPart {
            name: name.to_owned(),
            mesh: Arc::new(mesh.locality_ordered()),
            transform: Mat4::IDENTITY,
            base_color: None,
        }]);
        self.shapes.insert(name.to_owned(), parts.clone());
        Ok(parts)
    }
}

/// The names taken so far, each with the index of the file object that took it.
#[derive(Default)]
struct Names {
    /// File objects' names (`name`, or the default from `mesh` or `builtin`).
    objects: HashMap<String, usize>,
    /// Scene objects' names: as above, or `name/part` for each part of a glTF model.
    parts: HashMap<String, usize>,
}

/// The scene-object names of an object called `name` with these parts: `name` for a single
/// part, else `name/part` with repeated part names (glTF allows them) numbered `part#2`, `part#3`.
fn part_names(name: &str, parts: &[LoadedPart]) -> Vec<String> {
    if parts.len() == 1 {
        return vec![name.to_owned()];
    }
    let mut seen: HashMap<&str, usize> = HashMap::new();
    parts
        .iter()
        .map(|p| {
            let n = seen.entry(p.name.as_str()).or_insert(0);
            *n += 1;
            if *n == 1 {
                format!("{name}/{}", p.name)
            } else {
                format!("{name}/{}#{n}", p.name)
            }
        })
        .collect()
}

/// `dragon_vrip.ply.gz` → `dragon_vrip`.
fn file_stem(p: &Path) -> String {
    let name = p
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    match name.rsplit_once('.') {
        Some((stem, _)) if !stem.is_empty() => stem.to_owned(),
        _ => name.to_owned(),
    }
}
