//! The exact local render of the whole scene a display is checked against: every object, the
//! linked-list A-buffer, the display's camera and size — what one machine would have shown.

use strata_core::{DeepFrame, Rgb8Image};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::{MethodOptions, create};

/// Renders and resolves every object of `scene` at animation frame `frame`, `width × height`.
pub fn exact_image(
    scene: &Scene,
    frame: u64,
    width: u32,
    height: u32,
    raster: &mut Rasterizer,
) -> Result<Rgb8Image, String> {
    Ok(exact_frame(scene, frame, width, height, raster)?.resolve(scene.background))
}

/// The exact DeepFrame of the whole scene (see [`exact_image`]).
pub fn exact_frame(
    scene: &Scene,
    frame: u64,
    width: u32,
    height: u32,
    raster: &mut Rasterizer,
) -> Result<DeepFrame, String> {
    let mut method = create("abuffer", &MethodOptions::default()).map_err(|e| e.to_string())?;
    let mut input = FrameInput::from_scene(scene, u32::try_from(frame).unwrap_or(u32::MAX));
    input.width = width;
    input.height = height;
    input.projection = scene.camera.projection(width, height);
    method.clear(width, height).map_err(|e| e.to_string())?;
    method
        .capture(raster, &input, &mut strata_core::PassTimings::new())
        .map_err(|e| e.to_string())?;
    match method.deep_frame() {
        Some(r) => r.map_err(|e| e.to_string()),
        None => Err("the A-buffer exports no DeepFrame".into()),
    }
}
