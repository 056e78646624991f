//! strata scenes: the TOML scene file, mesh loaders, built-in shapes and scenes, the camera.
//!
//! The first stage of the pipeline (the pipeline design): everything up to a [`Scene`] whose meshes are
//! loaded, validated and placed, ready for the rasterizer.
//!
//! ```
//! use strata_scene::{open_scene, SearchPath};
//! let scene = open_scene("spheres", &SearchPath::default()).unwrap();
//! assert_eq!((scene.width, scene.height), (1280, 720));
//! assert_eq!(scene.objects.len(), 6);
//! ```

pub mod builtin;
pub mod camera;
pub mod load;
pub mod mesh;
pub mod scene;
pub mod search_path;

use std::path::Path;

pub use camera::{Camera, CameraError};
pub use mesh::{Aabb, Mesh, MeshError};
pub use scene::{Animation, Scene, SceneError, SceneErrorKind, SceneObject, TextPosition};
pub use search_path::SearchPath;

/// Opens `spec` as a scene file if a file of that name exists, else as a built-in scene name.
///
/// Names that look like paths (containing a separator or ending in `.toml`) are always treated as
/// files, so a typo in a path says "no such file" rather than "no such built-in scene".
pub fn open_scene(spec: &str, search: &SearchPath) -> Result<Scene, SceneError> {
    let path = Path::new(spec);
    if path.is_dir() {
        return Err(SceneError::new(
            spec,
            None,
            SceneErrorKind::Invalid(
                "is a directory, not a scene file (give the .toml file inside it)".into(),
            ),
        ));
    }
    let looks_like_path =
        spec.contains(std::path::MAIN_SEPARATOR) || spec.contains('/') || spec.ends_with(".toml");
    if path.is_file() || looks_like_path {
        scene::file::load(path, search)
    } else {
        builtin::load(spec, search)
    }
}
