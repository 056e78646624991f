//! Per-pixel maps (k, importance) as heat-map images, like Tsopouridis 2021 Figure 3.9.
//!
//! The ramp runs black → red → yellow → white over `[0, max]` (the "hot" colour map): brighter and
//! redder is more. Values are row-major, one per pixel; the image is 8-bit RGB, written as PNG with
//! [`Rgb8Image::write_png`] or [`write_heat_map`].

use std::path::Path;

use rayon::prelude::*;
use strata_core::{ImageError, Rgb8Image};

/// The hot ramp at `t` in `[0, 1]` (clamped): black → red (⅓) → yellow (⅔) → white.
pub fn hot(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let ch = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [ch(3.0 * t), ch(3.0 * t - 1.0), ch(3.0 * t - 2.0)]
}

/// `values` (row-major, `width` × `height`) as a heat map over `[0, max]`; `max` defaults to the
/// largest value (an all-zero map is black).
///
/// # Panics
/// If `values` does not have one entry per pixel.
pub fn heat_map(values: &[f32], width: u32, height: u32, max: Option<f32>) -> Rgb8Image {
    assert_eq!(
        values.len(),
        width as usize * height as usize,
        "one value per pixel"
    );
    let max = max.unwrap_or_else(|| values.par_iter().copied().reduce(|| 0.0, f32::max));
    let scale = if max > 0.0 { 1.0 / max } else { 0.0 };
    let mut image = Rgb8Image::filled(width, height, [0; 3]);
    image
        .as_bytes_mut()
        .par_chunks_mut(3 * 4096)
        .zip(values.par_chunks(4096))
        .for_each(|(out, v)| {
            for (px, &v) in out.chunks_exact_mut(3).zip(v) {
                px.copy_from_slice(&hot(v * scale));
            }
        });
    image
}

/// A k map (or any per-pixel count) as a heat map over `[0, max k]`.
pub fn k_heat_map(k: &[u32], width: u32, height: u32) -> Rgb8Image {
    let values: Vec<f32> = k.par_iter().map(|&k| k as f32).collect();
    heat_map(&values, width, height, None)
}

/// Writes [`heat_map`] of `values` as a PNG file.
pub fn write_heat_map(
    path: impl AsRef<Path>,
    values: &[f32],
    width: u32,
    height: u32,
    max: Option<f32>,
) -> Result<(), ImageError> {
    heat_map(values, width, height, max).write_png(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_ends_and_thirds() {
        assert_eq!(hot(0.0), [0, 0, 0]);
        assert_eq!(hot(1.0 / 3.0), [255, 0, 0]);
        assert_eq!(hot(2.0 / 3.0), [255, 255, 0]);
        assert_eq!(hot(1.0), [255, 255, 255]);
        assert_eq!(hot(7.0), [255, 255, 255]);
        assert_eq!(hot(f32::NAN), [0, 0, 0]);
    }

    #[test]
    fn map_scales_to_its_maximum() {
        let img = k_heat_map(&[0, 3, 6, 9], 2, 2);
        assert_eq!(img.pixel(0, 0), [0, 0, 0]);
        assert_eq!(img.pixel(1, 0), [255, 0, 0]);
        assert_eq!(img.pixel(0, 1), [255, 255, 0]);
        assert_eq!(img.pixel(1, 1), [255, 255, 255]);
        assert_eq!(heat_map(&[0.0; 4], 2, 2, None).pixel(1, 1), [0, 0, 0]);
        assert_eq!(
            heat_map(&[1.0; 4], 2, 2, Some(3.0)).pixel(0, 0),
            [255, 0, 0]
        );
    }
}
