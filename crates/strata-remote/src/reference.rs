//! The exact local render of the whole scene a display is checked against: every object, the
//! linked-list A-buffer, the display's camera and size — what one machine would have shown.

use strata_core::{DeepFrame, DeepFrameError, Rgb8Image};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::{MethodOptions, StoreError, UnknownMethod, create};

use crate::{FrameOutOfRange, animation_frame};

/// Why the exact render failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReferenceError {
    /// The frame number cannot pose the scene.
    #[error(transparent)]
    Frame(#[from] FrameOutOfRange),
    /// The A-buffer is not available.
    #[error("the exact render: {0}")]
    Method(#[from] UnknownMethod),
    /// The A-buffer failed (out of memory for its pool, a frame too large…).
    #[error("the exact render: {0}")]
    Store(#[from] StoreError),
    /// Its fragments do not form a DeepFrame.
    #[error("the exact render: {0}")]
    DeepFrame(#[from] DeepFrameError),
    /// The A-buffer exports no DeepFrame.
    #[error("the exact render: the A-buffer exports no DeepFrame")]
    NoDeepFrame,
}

/// Renders and resolves every object of `scene` at animation frame `frame`, `width × height`.
pub fn exact_image(
    scene: &Scene,
    frame: u64,
    width: u32,
    height: u32,
    raster: &mut Rasterizer,
) -> Result<Rgb8Image, ReferenceError> {
    Ok(exact_frame(scene, frame, width, height, raster)?.resolve(scene.background))
}

/// The exact DeepFrame of the whole scene (see [`exact_image`]).
pub fn exact_frame(
    scene: &Scene,
    frame: u64,
    width: u32,
    height: u32,
    raster: &mut Rasterizer,
) -> Result<DeepFrame, ReferenceError> {
    let pose = animation_frame(frame)?;
    let mut method = create("abuffer", &MethodOptions::default())?;
    let mut input = FrameInput::from_scene(scene, pose);
    input.width = width;
    input.height = height;
    input.projection = scene.camera.projection(width, height);
    method.clear(width, height)?;
    method.capture(raster, &input, &mut strata_core::PassTimings::new())?;
    Ok(method.deep_frame().ok_or(ReferenceError::NoDeepFrame)??)
}
