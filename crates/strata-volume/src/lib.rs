//! strata-volume: a CPU volume ray caster and its multi-frame-rate split.
//!
//! - [`volume`]: a dense scalar grid normalised to [0, 1], trilinear sampling, procedural volumes;
//! - [`nifti`]: a NIfTI-1 reader (`.nii`, `.nii.gz`; 8- and 16-bit scalars) that refuses hostile
//!   files with clear errors;
//! - [`transfer`]: piecewise-linear colour/opacity transfer functions and their per-step tables;
//! - [`cast`]: fixed steps from the ray's entry into the volume box, opacity correction, front-to-back
//!   compositing with early termination, rays ending at opaque geometry;
//! - [`fragments`]: deep fragments along each pixel's ray, walked together with the sample grid
//!   (translucent geometry inside the volume);
//! - [`geometry`]: analytic solids, opaque and translucent (boxes, tubes — the "well path");
//! - [`raster`]: the same objects as meshes rasterized by strata's rasterizer into deep fragments
//!   on each pixel's ray;
//! - [`spec`]: a scene file's `[volume]` table made into a [`stencil::VolumeScene`];
//! - [`stencil`]: the slow client casts the whole image over its static geometry; the fast client
//!   re-casts only the rays its interactive objects change, matching the single renderer exactly.
//!
//! ```
//! use strata_volume::{cast::{CastParams, VolumeBox}, stencil::{Renderer, VolumeScene},
//!     transfer::{TfPoint, TransferFunction}, volume::Volume};
//! use glam::{Mat4, Vec3};
//! let scene = VolumeScene {
//!     volume: Volume::constant([4, 4, 4], 1.0),
//!     transfer: TransferFunction::new(vec![TfPoint { value: 0.0, color: [1.0; 3], alpha: 0.5 }], 1.0).unwrap(),
//!     placement: VolumeBox { min: Vec3::splat(-0.5), max: Vec3::splat(0.5) },
//!     width: 8, height: 8,
//!     view_proj: Mat4::perspective_rh_gl(0.5, 1.0, 0.1, 10.0)
//!         * Mat4::look_at_rh(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y),
//!     statics: vec![], static_glass: vec![], interactive: vec![], interactive_glass: vec![],
//! };
//! let r = Renderer::new(&scene, CastParams { step: 0.01, termination: 0.0 });
//! let centre = r.slow().image[4 * 8 + 4];
//! // One unit of a medium of unit opacity 0.5 (white) over black: 0.5.
//! assert!((centre[0] - 0.5).abs() < 0.01);
//! ```

pub mod cast;
pub mod fragments;
pub mod geometry;
pub mod nifti;
pub mod raster;
pub mod spec;
pub mod stencil;
pub mod transfer;
pub mod volume;

pub use nifti::{NiftiError, NiftiVolume, read_nifti};
pub use transfer::{TfPoint, TransferError, TransferFunction};
pub use volume::Volume;
