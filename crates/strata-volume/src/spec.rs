//! A scene file's `[volume]` table made into a [`VolumeScene`]: the volume read or generated,
//! the transfer function checked, a floor plate as the static opaque geometry, the well path as
//! the interactive one, and the table's glass boxes as translucent objects — static, or
//! interactive when they move with the path.
//!
//! The floor lies just beyond the volume box along the camera's down direction (the box face
//! whose normal is most nearly the camera's `up`), one box-size wide on each side, so it shows
//! through and around the volume and the path can pass in front of it.

use glam::{Mat4, Vec3};
use strata_scene::Scene;
use strata_scene::scene::volume::{VolumeGlass, VolumeSource, VolumeSpec};

use crate::cast::{CastParams, VolumeBox};
use crate::geometry::{Glass, Shape, Solid, well_path};
use crate::nifti::{NiftiError, read_nifti};
use crate::stencil::VolumeScene;
use crate::transfer::{TfPoint, TransferError, TransferFunction};
use crate::volume::Volume;

/// Why a scene's volume could not be set up.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SpecError {
    /// The scene has no `[volume]` table.
    #[error("scene '{0}' has no [volume] table (try the built-in scene volume-head)")]
    NoVolume(String),
    /// The volume file could not be read.
    #[error(transparent)]
    Nifti(#[from] NiftiError),
    /// The transfer function is unusable.
    #[error(transparent)]
    Transfer(#[from] TransferError),
}

/// The floor's colour.
const FLOOR: [f32; 3] = [0.55, 0.55, 0.5];

/// Builds the volume scene of `scene` at `width` × `height`, with its step for `samples` samples
/// along the box diagonal (`None`: the table's own `samples`).
pub fn volume_scene(
    scene: &Scene,
    width: u32,
    height: u32,
    samples: Option<u32>,
) -> Result<(VolumeScene, CastParams), SpecError> {
    let spec = scene
        .volume
        .as_ref()
        .ok_or_else(|| SpecError::NoVolume(scene.name.clone()))?;
    let volume = load_volume(&spec.source)?;
    let transfer = TransferFunction::new(
        spec.points
            .iter()
            .map(|p| TfPoint {
                value: p.value,
                color: p.color,
                alpha: p.alpha,
            })
            .collect(),
        spec.unit_length,
    )?;
    let placement = VolumeBox {
        min: spec.min,
        max: spec.max,
    };
    let cam = &scene.camera;
    let (view, projection) = camera(scene, width, height);
    let view_proj = projection * view;
    let params = CastParams::for_samples(&placement, samples.unwrap_or(spec.samples));
    let vs = VolumeScene {
        volume,
        transfer,
        placement,
        width,
        height,
        view_proj,
        statics: vec![floor(spec, cam.up)],
        static_glass: glass(spec, false, Vec3::ZERO),
        interactive: path(spec, Vec3::ZERO),
        interactive_glass: glass(spec, true, Vec3::ZERO),
    };
    Ok((vs, params))
}

/// The scene camera's view and projection at `width` × `height`: what the rasterizer draws
/// the objects through; their product is the rays' view-projection.
pub fn camera(scene: &Scene, width: u32, height: u32) -> (Mat4, Mat4) {
    (scene.camera.view(), scene.camera.projection(width, height))
}

/// The glass boxes that move (`moves`) or stay, moved by `offset`.
pub fn glass(spec: &VolumeSpec, moves: bool, offset: Vec3) -> Vec<Glass> {
    spec.glass
        .iter()
        .filter(|g| g.moves == moves)
        .map(|g: &VolumeGlass| Glass {
            shape: Shape::Cuboid {
                min: g.min + offset,
                max: g.max + offset,
            },
            color: g.color,
            alpha: g.alpha,
        })
        .collect()
}

/// The well path moved by `offset`.
pub fn path(spec: &VolumeSpec, offset: Vec3) -> Vec<Solid> {
    let pts: Vec<Vec3> = spec.path.iter().map(|&p| p + offset).collect();
    well_path(&pts, spec.path_radius, spec.path_color)
}

fn load_volume(source: &VolumeSource) -> Result<Volume, NiftiError> {
    match source {
        VolumeSource::File(path) => Ok(read_nifti(path)?.volume),
        // "head" is the only procedural volume the scene format accepts.
        VolumeSource::Procedural { size, .. } => Ok(Volume::procedural_head(*size as usize)),
    }
}

/// A plate just beyond the box's face towards `-up`.
fn floor(spec: &VolumeSpec, up: Vec3) -> Solid {
    let axis = up.abs().max_position();
    let size = spec.max - spec.min;
    let (mut min, mut max) = (spec.min - size, spec.max + size);
    let gap = 0.05 * size[axis];
    let thick = 0.04 * size[axis];
    if up[axis] >= 0.0 {
        max[axis] = spec.min[axis] - gap;
        min[axis] = max[axis] - thick;
    } else {
        min[axis] = spec.max[axis] + gap;
        max[axis] = min[axis] + thick;
    }
    Solid {
        shape: Shape::Cuboid { min, max },
        color: FLOOR,
    }
}
