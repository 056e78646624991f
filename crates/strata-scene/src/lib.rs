//! strata scenes: the TOML scene file, mesh loaders, built-in shapes and scenes, the camera.

pub mod load;
pub mod mesh;

pub use mesh::{Aabb, Mesh, MeshError};
