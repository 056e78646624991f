//! Image quality against a reference (strata's shared conventions): RMSE and bad pixels.
//!
//! FLIP, the perceptual difference, lives in the command-line tool (`strata compare`), the one
//! place that computes it, so that this crate builds without a C++ compiler.
//!
//! - **RMSE** over the RGB channels in `[0, 1]`.
//! - **Bad pixels**: pixels whose largest channel difference exceeds a threshold in 8-bit steps
//!   (default 2/255: Jähne 2014 fig. 6.2 counts visible differences). Every printed figure
//!   states its threshold.

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

/// Refuses images of different sizes.
pub fn check_same_size(a: &Rgb8Image, b: &Rgb8Image) -> Result<(), SizeMismatch> {
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
    check_same_size(a, b)?;
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
    check_same_size(a, b)?;
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
    check_same_size(a, b)?;
    Ok(a.as_bytes()
        .iter()
        .zip(b.as_bytes())
        .map(|(&x, &y)| x.abs_diff(y))
        .max()
        .unwrap_or(0))
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
    fn size_mismatch_is_an_error() {
        let a = Rgb8Image::filled(2, 1, [0; 3]);
        let b = Rgb8Image::filled(1, 2, [0; 3]);
        assert!(rmse(&a, &b).is_err());
        assert!(bad_pixels(&a, &b, 2).is_err());
    }
}
