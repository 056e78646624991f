//! FLIP, NVIDIA's perceptual image difference (Andersson et al. 2020, used by Tsopouridis 2021 §5), through
//! the `nv-flip` crate (which builds NVIDIA's C++ reference code).
//!
//! `strata compare` is the only place that computes it, so only this binary needs a C++ compiler
//! for it; the library crates build without one. The result is the mean of the per-pixel error
//! map, in `[0, 1]`, and the map itself through FLIP's magma colour map (black: no error), at 67
//! pixels per degree by default. [`magma_stops`] gives that colour map for the report's legend.

use strata_core::Rgb8Image;
use strata_core::metrics::{SizeMismatch, check_same_size};

/// Why a FLIP comparison failed.
#[derive(Debug, thiserror::Error)]
pub(crate) enum FlipError {
    /// The images differ in size.
    #[error(transparent)]
    Size(#[from] SizeMismatch),
    /// FLIP returned a heat map of another size than its input.
    #[error("FLIP returned a heat map of another size than the images compared")]
    Heatmap,
}

/// The pixels per degree FLIP assumes by default (a 0.7 m viewing distance from a 24" 4K screen).
pub(crate) const DEFAULT_PIXELS_PER_DEGREE: f32 = 67.0;

/// A FLIP comparison: the mean error and the error map rendered as a heat map.
#[derive(Clone, Debug)]
pub(crate) struct Flip {
    /// Mean of the per-pixel FLIP error, in `[0, 1]`; 0 for identical images.
    pub(crate) mean: f64,
    /// The error map through FLIP's magma colour map (black: no error).
    pub(crate) heatmap: Rgb8Image,
}

/// FLIP of `test` against `reference` at `pixels_per_degree`.
pub(crate) fn flip(
    reference: &Rgb8Image,
    test: &Rgb8Image,
    pixels_per_degree: f32,
) -> Result<Flip, FlipError> {
    check_same_size(reference, test)?;
    let (w, h) = (reference.width(), reference.height());
    let r = nv_flip::FlipImageRgb8::with_data(w, h, reference.as_bytes());
    let t = nv_flip::FlipImageRgb8::with_data(w, h, test.as_bytes());
    let error = nv_flip::flip(r, t, pixels_per_degree);
    let mean = f64::from(nv_flip::FlipPool::from_image(&error).mean());
    let heat = error.apply_color_lut(&nv_flip::magma_lut());
    let heatmap = Rgb8Image::from_raw(w, h, heat.to_vec()).ok_or(FlipError::Heatmap)?;
    Ok(Flip { mean, heatmap })
}

/// `n` colours of FLIP's magma colour map, evenly spaced from error 0 (left) to error 1.
pub(crate) fn magma_stops(n: usize) -> Vec<[u8; 3]> {
    let lut = nv_flip::magma_lut().to_vec();
    let entries = lut.len() / 3;
    let n = n.max(2);
    (0..n)
        .filter_map(|i| {
            let at = 3 * (i * (entries - 1) / (n - 1));
            Some([*lut.get(at)?, *lut.get(at + 1)?, *lut.get(at + 2)?])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flip_is_zero_for_identical_images_and_grows_with_the_difference() {
        let mut a = Rgb8Image::filled(32, 32, [128, 128, 128]);
        a.as_bytes_mut()[..96].fill(30);
        let same = flip(&a, &a, DEFAULT_PIXELS_PER_DEGREE).unwrap();
        assert_eq!(same.mean, 0.0);
        let zero = same.heatmap.pixel(0, 0);
        assert!(
            same.heatmap.as_bytes().chunks(3).all(|p| p == zero),
            "one colour for no error"
        );
        let mut small = a.clone();
        small.as_bytes_mut()[32 * 16 * 3..32 * 17 * 3].fill(140);
        let mut large = a.clone();
        large.as_bytes_mut()[32 * 16 * 3..32 * 17 * 3].fill(255);
        let (s, l) = (
            flip(&a, &small, 67.0).unwrap(),
            flip(&a, &large, 67.0).unwrap(),
        );
        assert!(s.mean > 0.0 && l.mean > s.mean, "{} {}", s.mean, l.mean);
        assert_eq!((l.heatmap.width(), l.heatmap.height()), (32, 32));
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let a = Rgb8Image::filled(2, 1, [0; 3]);
        let b = Rgb8Image::filled(1, 2, [0; 3]);
        assert!(matches!(flip(&a, &b, 67.0), Err(FlipError::Size(_))));
    }

    #[test]
    fn magma_runs_from_the_no_error_colour_to_bright() {
        let stops = magma_stops(17);
        assert_eq!(stops.len(), 17);
        let a = Rgb8Image::filled(8, 8, [50, 50, 50]);
        let zero = flip(&a, &a, DEFAULT_PIXELS_PER_DEGREE)
            .unwrap()
            .heatmap
            .pixel(0, 0);
        assert_eq!(
            stops[0], zero,
            "the legend starts at the colour of no error"
        );
        let sum = |c: [u8; 3]| c.iter().map(|&v| u32::from(v)).sum::<u32>();
        assert!(sum(stops[16]) > sum(stops[8]) && sum(stops[8]) > sum(stops[0]));
    }
}
