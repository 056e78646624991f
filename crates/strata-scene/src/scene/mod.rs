//! A loaded scene: image size, background, camera, objects with their meshes, and the animation.
//!
//! A [`Scene`] is what the scene file (strata's shared conventions, parsed in [`file`](mod@file)) or a built-in scene resolves
//! to: every mesh loaded and validated, every glTF mesh node expanded into its own object with its
//! own [`ObjectId`], `fit` folded into each object's base transform. Nothing in a `Scene` refers
//! back to files, so rendering it cannot fail.
//!
//! # Transforms
//!
//! An object's model matrix at animation frame `k` is
//!
//! ```text
//! M(k) = T · A(k) · R · S · F · N
//! ```
//!
//! - `N`: the glTF node's world transform (identity for other formats);
//! - `F`: `fit` — recentre on the bounding-box centre of the whole model (all its nodes), scale the
//!   largest extent to 1; identity without `fit`;
//! - `S`, `R = Rz · Ry · Rx`, `T`: `scale`, `rotate_deg`, `translate` (Jähne 2014 eq. 5.2);
//! - `A(k) = Rz(k·az) · Ry(k·ay) · Rx(k·ax)` with `[ax, ay, az] = animation.rotate_deg_per_frame`: the
//!   object turns about its own origin (the point `translate` puts it at) around the world axes —
//!   the turntable of Jähne 2014 §6.1, 5° a frame about y.

pub mod file;
mod keys;
pub mod volume;

use std::path::PathBuf;
use std::sync::Arc;

use glam::{Mat4, Vec3, Vec4};
use strata_core::{Material, ObjectId};

use crate::camera::Camera;
use crate::load::LoadError;
use crate::mesh::Mesh;

/// A scene ready to render; see the module docs.
#[derive(Clone, Debug)]
pub struct Scene {
    /// A short name: the file stem or the built-in scene's name.
    pub name: String,
    /// Where it came from, as errors name it: the file path or `built-in scene 'name'`.
    pub origin: String,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Opaque background colour, RGB in `[0, 1]`.
    pub background: [f32; 3],
    /// The camera.
    pub camera: Camera,
    /// The objects, in file order; a glTF file contributes one object per mesh node.
    pub objects: Vec<SceneObject>,
    /// The animation, if the scene has one.
    pub animation: Option<Animation>,
    /// The `[volume]` table, if the scene has one (see [`volume`]).
    pub volume: Option<volume::VolumeSpec>,
}

/// One object: a mesh, where it is, what it looks like, and its id.
#[derive(Clone, Debug)]
pub struct SceneObject {
    /// The object's name (the scene's `name`, suffixed with the glTF node name for glTF parts).
    pub name: String,
    /// The id every fragment of this object carries.
    pub id: ObjectId,
    /// The geometry, shared between objects that use the same file.
    pub mesh: Arc<Mesh>,
    /// `F · N`: fit and glTF node transform, applied before `scale`.
    pub base: Mat4,
    /// `translate`.
    pub translate: Vec3,
    /// `rotate_deg`, applied as `Rz · Ry · Rx`.
    pub rotate_deg: Vec3,
    /// `scale`, per axis.
    pub scale: Vec3,
    /// Colour and shading.
    pub material: Material,
}

/// A sequence of frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Animation {
    /// Number of frames, ≥ 1.
    pub frames: u32,
    /// Degrees each object turns per frame about the world x, y and z axes through its origin.
    pub rotate_deg_per_frame: Vec3,
}

/// `Rz(z) · Ry(y) · Rx(x)` with angles in degrees.
///
/// The sines and cosines come from the `libm` crate, not the platform's maths library, so every
/// machine computes the same matrices bit for bit: remote nodes and displays rebuild the same
/// object placements independently (the reprojection transfer depends on it).
pub fn rotation_zyx_deg(deg: Vec3) -> Mat4 {
    let sin_cos = |d: f32| {
        let r = d.to_radians();
        (libm::sinf(r), libm::cosf(r))
    };
    let (sx, cx) = sin_cos(deg.x);
    let (sy, cy) = sin_cos(deg.y);
    let (sz, cz) = sin_cos(deg.z);
    // The matrices of glam's from_rotation_{z,y,x}, with portable trigonometry.
    let rz = Mat4::from_cols(
        Vec4::new(cz, sz, 0.0, 0.0),
        Vec4::new(-sz, cz, 0.0, 0.0),
        Vec4::Z,
        Vec4::W,
    );
    let ry = Mat4::from_cols(
        Vec4::new(cy, 0.0, -sy, 0.0),
        Vec4::Y,
        Vec4::new(sy, 0.0, cy, 0.0),
        Vec4::W,
    );
    let rx = Mat4::from_cols(
        Vec4::X,
        Vec4::new(0.0, cx, sx, 0.0),
        Vec4::new(0.0, -sx, cx, 0.0),
        Vec4::W,
    );
    rz * ry * rx
}

impl SceneObject {
    /// The model matrix at animation frame `frame` (see the module docs).
    pub fn model_matrix(&self, animation: Option<&Animation>, frame: u32) -> Mat4 {
        let spin = animation.map_or(Mat4::IDENTITY, |a| {
            rotation_zyx_deg(a.rotate_deg_per_frame * frame as f32)
        });
        Mat4::from_translation(self.translate)
            * spin
            * rotation_zyx_deg(self.rotate_deg)
            * Mat4::from_scale(self.scale)
            * self.base
    }
}

impl Scene {
    /// Frames in the scene's animation (1 without an animation).
    pub fn frame_count(&self) -> u32 {
        self.animation.map_or(1, |a| a.frames)
    }

    /// Triangles over all objects.
    pub fn triangle_count(&self) -> u64 {
        self.objects
            .iter()
            .map(|o| o.mesh.triangles().len() as u64)
            .sum()
    }

    /// Checks that `frame` exists, with an error a person can act on.
    pub fn check_frame(&self, frame: u32) -> Result<(), SceneError> {
        if frame < self.frame_count() {
            Ok(())
        } else {
            Err(SceneError::new(
                &self.origin,
                Some("animation.frames".into()),
                SceneErrorKind::Invalid(match self.animation {
                    Some(a) => format!(
                        "frame {frame} does not exist: the animation has frames 0..{}",
                        a.frames - 1
                    ),
                    None => format!(
                        "frame {frame} does not exist: the scene has no [animation], only frame 0"
                    ),
                }),
            ))
        }
    }
}

/// What went wrong building a scene.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneErrorKind {
    /// The scene file could not be read.
    #[error("{0}")]
    Io(#[source] std::io::Error),
    /// The file is not valid TOML or does not match the scene schema.
    #[error("{0}")]
    Toml(String),
    /// A value is out of range or inconsistent.
    #[error("{0}")]
    Invalid(String),
    /// A mesh file was not found anywhere on the search path.
    #[error("cannot find mesh '{name}' (looked in: {}); set STRATA_MODEL_PATH to the folder that holds it, or run scripts/fetch-models", looked_in(.tried))]
    MeshNotFound {
        /// The name in the scene file.
        name: String,
        /// Every path that was tried.
        tried: Vec<PathBuf>,
    },
    /// A mesh file was found but could not be loaded.
    #[error("{0}")]
    Load(#[source] Box<LoadError>),
    /// No built-in scene or shape has that name (for scenes: and no file of that name exists).
    #[error("{} built-in {what} named '{name}' (known: {})", if *.what == "scene" { "no scene file and no" } else { "no" }, .known.join(", "))]
    UnknownBuiltin {
        /// "scene" or "shape".
        what: &'static str,
        /// The name asked for.
        name: String,
        /// The names that exist.
        known: Box<[&'static str]>,
    },
}

fn looked_in(tried: &[PathBuf]) -> String {
    if tried.is_empty() {
        "nowhere: no scene directory and an empty search path".to_owned()
    } else {
        tried
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// A place in a scene text: a 1-based line and, where known, a 1-based column.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextPosition {
    /// The line, counting from 1.
    pub line: u32,
    /// The column in characters, counting from 1, when the error points into the line.
    pub column: Option<u32>,
}

impl std::fmt::Display for TextPosition {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.column {
            Some(c) => write!(f, "line {}, column {c}", self.line),
            None => write!(f, "line {}", self.line),
        }
    }
}

/// A scene error: where (file or built-in scene, line, and the key) and what.
///
/// It reads `scene.toml: line 12: objects[2].color: 1.5 is outside [0, 1]`; the line and the key
/// are left out when the error has none (a file that cannot be read, a key left at its default).
#[derive(Debug, thiserror::Error)]
#[error(
    "{origin}: {}{}{kind}",
    .at.map(|p| format!("{p}: ")).unwrap_or_default(),
    .key.as_deref().map(|k| format!("{k}: ")).unwrap_or_default()
)]
pub struct SceneError {
    /// The scene file's path or the built-in scene's name.
    pub origin: String,
    /// Where in the scene text, when the error concerns a place in it.
    pub at: Option<TextPosition>,
    /// The key path (`objects[2].color`), when the error is about one key.
    pub key: Option<String>,
    /// What went wrong.
    pub kind: SceneErrorKind,
}

impl SceneError {
    /// An error about `origin`, optionally at `key`, without a position.
    pub fn new(origin: impl Into<String>, key: Option<String>, kind: SceneErrorKind) -> Self {
        SceneError {
            origin: origin.into(),
            at: None,
            key,
            kind,
        }
    }

    /// The same error, placed at `at`.
    pub fn at(mut self, at: Option<TextPosition>) -> Self {
        self.at = at;
        self
    }
}
