//! Built-in shapes and scenes, so strata renders something meaningful on a machine with no files.
//!
//! The scenes are ordinary scene files compiled into the binary (`scenes/*.toml`), so they exercise
//! the same parser as user scenes and `strata scenes --print NAME` can show them as examples.
//! Scenes made for order-independent transparency need no files; the mesh scenes reproduce the
//! benchmark settings of the seeds and need the Stanford/Khronos meshes on the search path
//! (`scripts/fetch-models`).

pub mod shapes;

use crate::scene::file::{self, SceneOrigin};
use crate::scene::{Scene, SceneError, SceneErrorKind};
use crate::search_path::SearchPath;

/// A scene compiled into the binary.
#[derive(Clone, Copy, Debug)]
pub struct BuiltinScene {
    /// The name it is selected by.
    pub name: &'static str,
    /// One line saying what it shows.
    pub description: &'static str,
    /// The scene file text.
    pub source: &'static str,
    /// Mesh files it needs from the search path (empty: self-contained).
    pub meshes: &'static [&'static str],
}

/// Every built-in scene: first the self-contained ones, then those that need mesh files.
pub const SCENES: &[BuiltinScene] = &[
    BuiltinScene {
        name: "slabs",
        description: "interpenetrating translucent slabs: no object order composites them correctly",
        source: include_str!("scenes/slabs.toml"),
        meshes: &[],
    },
    BuiltinScene {
        name: "spheres",
        description: "nested translucent spheres threaded by intersecting tori; depth complexity up to 16",
        source: include_str!("scenes/spheres.toml"),
        meshes: &[],
    },
    BuiltinScene {
        name: "mixed",
        description: "opaque and translucent objects intersecting each other",
        source: include_str!("scenes/mixed.toml"),
        meshes: &[],
    },
    BuiltinScene {
        name: "overlap",
        description: "half-transparent red over half-transparent blue over white (Jähne 2014, fig. 1.1)",
        source: include_str!("scenes/overlap.toml"),
        meshes: &[],
    },
    BuiltinScene {
        name: "mfr-cars",
        description: "for `strata mfr`: a car with a transparent windscreen before 108 translucent and opaque objects",
        source: include_str!("scenes/mfr-cars.toml"),
        meshes: &[],
    },
    BuiltinScene {
        name: "volume-head",
        description: "for `strata mfr --volume`: a procedural volume cut by a glass sheet, with a well path of thin tubes through both",
        source: include_str!("scenes/volume-head.toml"),
        meshes: &[],
    },
    BuiltinScene {
        name: "bunny",
        description: "Stanford bunny, alpha 0.5, 1280x720 (needs bunny.obj)",
        source: include_str!("scenes/bunny.toml"),
        meshes: &["bunny.obj"],
    },
    BuiltinScene {
        name: "dragon",
        description: "full Stanford dragon, 871,414 triangles, alpha 0.5, 1280x720 (needs dragon_vrip.ply.gz)",
        source: include_str!("scenes/dragon.toml"),
        meshes: &["dragon_vrip.ply.gz"],
    },
    BuiltinScene {
        name: "dragon-res2",
        description: "decimated Stanford dragon, 202,520 triangles (needs dragon_vrip_res2.ply.gz)",
        source: include_str!("scenes/dragon-res2.toml"),
        meshes: &["dragon_vrip_res2.ply.gz"],
    },
    BuiltinScene {
        name: "armadillo",
        description: "Stanford armadillo, 52,000 triangles (needs armadillo.off)",
        source: include_str!("scenes/armadillo.toml"),
        meshes: &["armadillo.off"],
    },
    BuiltinScene {
        name: "engine",
        description: "Khronos 2 Cylinder Engine glTF, one object per mesh node (needs 2CylinderEngine.glb)",
        source: include_str!("scenes/engine.toml"),
        meshes: &["2CylinderEngine.glb"],
    },
    BuiltinScene {
        name: "mfr-engine",
        description: "for `strata mfr`: the translucent 2 Cylinder Engine, one object per mesh node (needs 2CylinderEngine.glb)",
        source: include_str!("scenes/mfr-engine.toml"),
        meshes: &["2CylinderEngine.glb"],
    },
    BuiltinScene {
        name: "volume-ch2",
        description: "for `strata mfr --volume`: the ch2 head MRI, 181x217x181 voxels, with a well path (needs ch2.nii.gz)",
        source: include_str!("scenes/volume-ch2.toml"),
        meshes: &["ch2.nii.gz"],
    },
];

impl BuiltinScene {
    /// Whether it is a volume scene (a `[volume]` table, no meshes to rasterize): for
    /// `strata mfr --volume`, not for the fragment renderers.
    pub fn is_volume(&self) -> bool {
        self.source.contains("\n[volume]")
    }
}

/// The built-in scene called `name`.
pub fn find(name: &str) -> Option<&'static BuiltinScene> {
    SCENES.iter().find(|s| s.name == name)
}

/// Names of all built-in scenes.
pub fn names() -> Vec<&'static str> {
    SCENES.iter().map(|s| s.name).collect()
}

impl BuiltinScene {
    /// True if every mesh it needs is on the search path.
    pub fn available(&self, search: &SearchPath) -> bool {
        self.meshes.iter().all(|m| search.resolve(m, None).is_ok())
    }

    /// Parses and resolves the scene.
    pub fn load(&self, search: &SearchPath) -> Result<Scene, SceneError> {
        file::parse(self.source, SceneOrigin::Builtin(self.name), search)
    }
}

/// Loads the built-in scene called `name`.
pub fn load(name: &str, search: &SearchPath) -> Result<Scene, SceneError> {
    find(name)
        .ok_or_else(|| {
            SceneError::new(
                name,
                None,
                SceneErrorKind::UnknownBuiltin {
                    what: "scene",
                    name: name.to_owned(),
                    known: names().into(),
                },
            )
        })?
        .load(search)
}
