//! The TOML scene file (DESIGN §2): schema, validation, mesh resolution.
//!
//! Every key of DESIGN §2 is accepted; unknown keys are errors (a typo must not silently fall back
//! to a default). Syntax and type errors carry the TOML line and column; range errors name the
//! key (`objects[2].color`). Defaults for keys left out:
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
//! An object names exactly one of `mesh` (a file, found through [`SearchPath`]) or `builtin` (a
//! shape of [`crate::builtin::shapes`]).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec3};
use serde::Deserialize;
use strata_core::{Material, ObjectId, Shading};

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
    let file: SceneFile = toml::from_str(text).map_err(|e| {
        SceneError::new(
            &label,
            None,
            SceneErrorKind::Toml(e.to_string().trim_end().to_owned()),
        )
    })?;
    Resolver {
        label: &label,
        origin,
        search,
        models: HashMap::new(),
        shapes: HashMap::new(),
    }
    .resolve(file)
}

// ----- schema ---------------------------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    width: Option<u32>,
    height: Option<u32>,
    background: Option<[f32; 3]>,
    camera: Option<CameraFile>,
    #[serde(default)]
    objects: Vec<ObjectFile>,
    animation: Option<AnimationFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    eye: Option<[f32; 3]>,
    target: Option<[f32; 3]>,
    up: Option<[f32; 3]>,
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
    color: Option<[f32; 4]>,
    shading: Option<ShadingFile>,
    translate: Option<[f32; 3]>,
    rotate_deg: Option<[f32; 3]>,
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
                mut seq: A,
            ) -> Result<ScaleFile, A::Error> {
                let mut s = [0.0f32; 3];
                for (i, slot) in s.iter_mut().enumerate() {
                    *slot = seq
                        .next_element()?
                        .ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
                }
                if seq.next_element::<f32>()?.is_some() {
                    return Err(serde::de::Error::invalid_length(4, &self));
                }
                Ok(ScaleFile(s))
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AnimationFile {
    frames: u32,
    #[serde(default)]
    rotate_deg_per_frame: [f32; 3],
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
    origin: SceneOrigin<'a>,
    search: &'a SearchPath,
    models: HashMap<PathBuf, Arc<Vec<LoadedPart>>>,
    shapes: HashMap<String, Arc<Vec<LoadedPart>>>,
}

impl Resolver<'_> {
    fn invalid(&self, key: impl Into<String>, msg: impl Into<String>) -> SceneError {
        SceneError::new(
            self.label,
            Some(key.into()),
            SceneErrorKind::Invalid(msg.into()),
        )
    }

    fn resolve(mut self, file: SceneFile) -> Result<Scene, SceneError> {
        let width = file.width.unwrap_or(1280);
        let height = file.height.unwrap_or(720);
        for (key, v) in [("width", width), ("height", height)] {
            if v == 0 || v > MAX_IMAGE_SIDE {
                return Err(
                    self.invalid(key, format!("{v} is outside 1..={MAX_IMAGE_SIDE} pixels"))
                );
            }
        }
        let background = file.background.unwrap_or([1.0; 3]);
        self.unit_range("background", &background)?;
        let camera = self.camera(file.camera)?;
        if file.objects.is_empty() {
            return Err(self.invalid("objects", "the scene has no [[objects]]; add at least one"));
        }
        let mut objects = Vec::new();
        for (i, obj) in file.objects.into_iter().enumerate() {
            self.object(i, obj, &mut objects)?;
        }
        let animation = match file.animation {
            None => None,
            Some(a) => {
                if a.frames == 0 {
                    return Err(self.invalid("animation.frames", "must be at least 1"));
                }
                self.finite("animation.rotate_deg_per_frame", &a.rotate_deg_per_frame)?;
                Some(Animation {
                    frames: a.frames,
                    rotate_deg_per_frame: Vec3::from(a.rotate_deg_per_frame),
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
        })
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
            eye: c.eye.map_or(d.eye, Vec3::from),
            target: c.target.map_or(d.target, Vec3::from),
            up: c.up.map_or(d.up, Vec3::from),
            fovy_deg: c.fovy_deg.unwrap_or(d.fovy_deg),
            near: c.near.unwrap_or(d.near),
            far: c.far.unwrap_or(d.far),
        };
        self.finite("camera.eye", &cam.eye.to_array())?;
        self.finite("camera.target", &cam.target.to_array())?;
        self.finite("camera.up", &cam.up.to_array())?;
        let dir = cam.target - cam.eye;
        if dir.length_squared() == 0.0 {
            return Err(self.invalid(
                "camera.target",
                "equals camera.eye; the camera must look somewhere",
            ));
        }
        if cam.up.cross(dir).length_squared()
            <= 1e-12 * cam.up.length_squared() * dir.length_squared()
        {
            return Err(self.invalid("camera.up", "is zero or parallel to the viewing direction"));
        }
        if !(cam.fovy_deg > 0.0 && cam.fovy_deg < 180.0) {
            return Err(self.invalid(
                "camera.fovy_deg",
                format!("{} is outside (0, 180) degrees", cam.fovy_deg),
            ));
        }
        if !(cam.near > 0.0 && cam.near.is_finite()) {
            return Err(self.invalid(
                "camera.near",
                format!("{} must be a positive distance", cam.near),
            ));
        }
        if !(cam.far > cam.near && cam.far.is_finite()) {
            return Err(self.invalid(
                "camera.far",
                format!(
                    "{} must be finite and greater than near ({})",
                    cam.far, cam.near
                ),
            ));
        }
        Ok(cam)
    }

    fn object(
        &mut self,
        i: usize,
        obj: ObjectFile,
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
        let name = obj.name.unwrap_or(default_name);
        if let Some(c) = &obj.color {
            self.unit_range(&key("color"), c)?;
        }
        let translate = obj.translate.unwrap_or_default();
        self.finite(&key("translate"), &translate)?;
        let rotate_deg = obj.rotate_deg.unwrap_or_default();
        self.finite(&key("rotate_deg"), &rotate_deg)?;
        let scale = obj.scale.map_or([1.0; 3], |s| s.0);
        if let Some(s) = scale.iter().find(|s| !s.is_finite() || **s == 0.0) {
            return Err(self.invalid(
                key("scale"),
                format!("{s} must be a finite, non-zero factor"),
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
        let several = parts.len() > 1;
        for part in parts.iter() {
            let id = u32::try_from(out.len())
                .map_err(|_| self.invalid("objects", "more than 2^32 objects"))?;
            out.push(SceneObject {
                name: if several {
                    format!("{name}/{}", part.name)
                } else {
                    name.clone()
                },
                id: ObjectId(id),
                mesh: part.mesh.clone(),
                base: fit * part.transform,
                translate: Vec3::from(translate),
                rotate_deg: Vec3::from(rotate_deg),
                scale: Vec3::from(scale),
                material: Material {
                    color: obj
                        .color
                        .or(part.base_color)
                        .unwrap_or(Material::default().color),
                    shading,
                },
            });
        }
        Ok(())
    }

    fn mesh(&mut self, key: &str, name: &str) -> Result<Arc<Vec<LoadedPart>>, SceneError> {
        let path = self
            .search
            .resolve(name, self.origin.dir())
            .map_err(|tried| {
                SceneError::new(
                    self.label,
                    Some(key.to_owned()),
                    SceneErrorKind::MeshNotFound {
                        name: name.to_owned(),
                        tried,
                    },
                )
            })?;
        let canonical = path.canonicalize().unwrap_or_else(|_| path.clone());
        if let Some(m) = self.models.get(&canonical) {
            return Ok(m.clone());
        }
        let model = load::load_model(&path).map_err(|e| {
            SceneError::new(
                self.label,
                Some(key.to_owned()),
                SceneErrorKind::Load(Box::new(e)),
            )
        })?;
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

    fn shape(&mut self, key: &str, name: &str) -> Result<Arc<Vec<LoadedPart>>, SceneError> {
        if let Some(s) = self.shapes.get(name) {
            return Ok(s.clone());
        }
        let mesh = shapes::shape(name).ok_or_else(|| {
            SceneError::new(
                self.label,
                Some(key.to_owned()),
                SceneErrorKind::UnknownBuiltin {
                    what: "shape",
                    name: name.to_owned(),
                    known: shapes::SHAPE_NAMES.to_vec(),
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
