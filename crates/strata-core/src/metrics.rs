//! Image quality against a reference (DESIGN §2): RMSE and bad pixels.
//!
//! - **RMSE** over the RGB channels in `[0, 1]`.
//! - **Bad pixels**: pixels whose largest channel difference exceeds a threshold in 8-bit steps
//!   (DESIGN default 2/255: seed 000 fig. 6.2 counts visible differences). Every printed figure
//!   states its threshold.
//! - **FLIP**: NVIDIA's perceptual difference (Andersson et al. 2020, used by seed 001 §5) through
//!   the `nv-flip` crate, at 67 pixels per degree by default: the mean of the per-pixel error map,
//!   and the map itself as a magma heat map image.

use crate::image::Rgb8Image;

/// The images being compared differ in size.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("cannot compare a {a_w}x{a_h} image with a {b_w}x{b_h} one")]
pub struct SizeMismatch {
    a_w: u32,
    a_h: u32,
    b_w: u32,
    b_h: u32,
}

fn check(a: &Rgb8Image, b: &Rgb8Image) -> Result<(), SizeMismatch> {
    if a.width() == b.width() && a.height() == b.height() {
        Ok(())
    } else {
        Err(SizeMismatch {
            a_w: a.width(),
            a_h: a.height(),
            b_w: b.width(),
            b_h: b.height(),
        })
    }
}

/// The default bad-pixel threshold: a channel off by more than 2/255.
pub const DEFAULT_BAD_PIXEL_THRESHOLD: u8 = 2;

/// Root-mean-square error over all RGB channels, in `[0, 1]` units.
pub fn rmse(a: &Rgb8Image, b: &Rgb8Image) -> Result<f64, SizeMismatch> {
    check(a, b)?;
    let n = a.as_bytes().len();
    if n == 0 {
        return Ok(0.0);
    }
    let sum: u64 = a
        .as_bytes()
        .iter()
        .zip(b.as_bytes())
        .map(|(&x, &y)| {
            let d = u64::from(x.abs_diff(y));
            d * d
        })
        .sum();
    Ok((sum as f64 / n as f64).sqrt() / 255.0)
}

/// Pixels that differ visibly from a reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BadPixels {
    /// Pixels whose largest channel difference exceeds `threshold`.
    pub count: u64,
    /// All pixels compared.
    pub total: u64,
    /// The threshold in 8-bit steps (a pixel is bad if some channel differs by more).
    pub threshold: u8,
}

impl BadPixels {
    /// `count / total` (0 for an empty image).
    pub fn share(&self) -> f64 {
        if self.total == 0 {
            0.0
        } else {
            self.count as f64 / self.total as f64
        }
    }
}

/// Counts pixels whose largest channel difference exceeds `threshold` (8-bit steps).
pub fn bad_pixels(a: &Rgb8Image, b: &Rgb8Image, threshold: u8) -> Result<BadPixels, SizeMismatch> {
    check(a, b)?;
    let count = a
        .as_bytes()
        .chunks_exact(3)
        .zip(b.as_bytes().chunks_exact(3))
        .filter(|(p, q)| {
            p.iter()
                .zip(q.iter())
                .any(|(&x, &y)| x.abs_diff(y) > threshold)
        })
        .count() as u64;
    Ok(BadPixels {
        count,
        total: u64::from(a.width()) * u64::from(a.height()),
        threshold,
    })
}

/// The largest difference of any channel of any pixel, in 8-bit steps.
pub fn max_channel_difference(a: &Rgb8Image, b: &Rgb8Image) -> Result<u8, SizeMismatch> {
    check(a, b)?;
    Ok(a.as_bytes()
        .iter()
        .zip(b.as_bytes())
        .map(|(&x, &y)| x.abs_diff(y))
        .max()
        .unwrap_or(0))
}

/// The pixels per degree FLIP assumes by default (a 0.7 m viewing distance from a 24" 4K screen).
pub const DEFAULT_PIXELS_PER_DEGREE: f32 = 67.0;

/// A FLIP comparison: the mean error and the error map rendered as a heat map.
#[derive(Clone, Debug)]
pub struct Flip {
    /// Mean of the per-pixel FLIP error, in `[0, 1]`; 0 for identical images.
    pub mean: f64,
    /// The error map through FLIP's magma colour map (black: no error).
    pub heatmap: Rgb8Image,
}

/// FLIP of `test` against `reference` at `pixels_per_degree`.
pub fn flip(
    reference: &Rgb8Image,
    test: &Rgb8Image,
    pixels_per_degree: f32,
) -> Result<Flip, SizeMismatch> {
    check(reference, test)?;
    let (w, h) = (reference.width(), reference.height());
    let r = nv_flip::FlipImageRgb8::with_data(w, h, reference.as_bytes());
    let t = nv_flip::FlipImageRgb8::with_data(w, h, test.as_bytes());
    let error = nv_flip::flip(r, t, pixels_per_degree);
    let mean = f64::from(nv_flip::FlipPool::from_image(&error).mean());
    let heat = error.apply_color_lut(&nv_flip::magma_lut());
    let heatmap = Rgb8Image::from_raw(w, h, heat.to_vec())
        .expect("FLIP returns an image of the size it was given");
    Ok(Flip { mean, heatmap })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_no_error() {
        let a = Rgb8Image::filled(4, 4, [9, 8, 7]);
        assert_eq!(rmse(&a, &a).unwrap(), 0.0);
        assert_eq!(bad_pixels(&a, &a, 2).unwrap().count, 0);
    }

    #[test]
    fn hand_computed_rmse_and_bad_pixels() {
        let a = Rgb8Image::filled(2, 1, [0, 0, 0]);
        let mut b = a.clone();
        // One pixel off by 255 in one channel: mean square = 255²/6.
        b.as_bytes_mut()[0] = 255;
        assert!((rmse(&a, &b).unwrap() - (1.0f64 / 6.0).sqrt()).abs() < 1e-12);
        // A difference of exactly the threshold is not bad; one more is.
        b.as_bytes_mut()[3] = 2;
        let bad = bad_pixels(&a, &b, 2).unwrap();
        assert_eq!((bad.count, bad.total), (1, 2));
        b.as_bytes_mut()[3] = 3;
        assert_eq!(bad_pixels(&a, &b, 2).unwrap().count, 2);
        assert_eq!(max_channel_difference(&a, &b).unwrap(), 255);
    }

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
        assert!(rmse(&a, &b).is_err());
        assert!(bad_pixels(&a, &b, 2).is_err());
        assert!(flip(&a, &b, 67.0).is_err());
    }
}
