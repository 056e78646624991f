//! A frame compared with a reference rendered for the same view: the numbers `strata compare`
//! reports (RMSE, bad pixels, FLIP) and the images the page shows beside the frame.
//!
//! The bad-pixel map is the frame in faint grey with every bad pixel (some channel more than
//! `threshold` 8-bit steps from the reference's) in red, so that a few scattered bad pixels are
//! as visible as a region of them. FLIP's heat map is FLIP's magma colour map (black: no
//! error), as in `strata compare`'s report.

use anyhow::Result;
use serde_json::{Value, json};
use strata_core::Rgb8Image;
use strata_core::metrics::{self, BadPixels};

use crate::flip;

/// The colour of a bad pixel in the bad-pixel map.
const BAD: [u8; 3] = [220, 20, 60];

/// Compares `test` with `reference`. Returns the numbers as JSON and the images to show: the
/// bad-pixel map and, with `with_flip`, FLIP's heat map.
pub(crate) fn compare(
    reference: &Rgb8Image,
    test: &Rgb8Image,
    with_flip: bool,
) -> Result<(Value, Vec<(&'static str, Rgb8Image)>)> {
    let threshold = metrics::DEFAULT_BAD_PIXEL_THRESHOLD;
    let rmse = metrics::rmse(reference, test)?;
    let bad = metrics::bad_pixels(reference, test, threshold)?;
    let map = bad_map(reference, test, threshold)
        .ok_or_else(|| anyhow::anyhow!("the bad-pixel map has another size than the frame"))?;
    let mut images = vec![("bad", map)];
    let mean_flip = if with_flip {
        let f = flip::flip(reference, test, flip::DEFAULT_PIXELS_PER_DEGREE)?;
        images.push(("flip", f.heatmap));
        Some(f.mean)
    } else {
        None
    };
    let BadPixels { count, total, .. } = bad;
    let numbers = json!({
        "rmse": rmse,
        "bad_pixels": {"count": count, "total": total, "share": bad.share(), "threshold": threshold},
        "mean_flip": mean_flip,
        "pixels_per_degree": flip::DEFAULT_PIXELS_PER_DEGREE,
    });
    Ok((numbers, images))
}

/// `test` in faint grey, its bad pixels against `reference` in red.
fn bad_map(reference: &Rgb8Image, test: &Rgb8Image, threshold: u8) -> Option<Rgb8Image> {
    let data = reference
        .as_bytes()
        .chunks_exact(3)
        .zip(test.as_bytes().chunks_exact(3))
        .flat_map(|(r, t)| {
            if r.iter().zip(t).any(|(&a, &b)| a.abs_diff(b) > threshold) {
                BAD
            } else {
                let luma =
                    (u32::from(t[0]) * 54 + u32::from(t[1]) * 183 + u32::from(t[2]) * 19) >> 8;
                let v = (255 - (255 - luma) * 3 / 10) as u8;
                [v, v, v]
            }
        })
        .collect();
    Rgb8Image::from_raw(test.width(), test.height(), data)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(pixels: &[[u8; 3]]) -> Rgb8Image {
        Rgb8Image::from_raw(pixels.len() as u32, 1, pixels.concat()).expect("size")
    }

    #[test]
    fn bad_pixels_are_red_and_counted_as_compare_counts_them() {
        let reference = image(&[[10, 10, 10], [200, 100, 50], [0, 0, 0]]);
        let test = image(&[[12, 10, 10], [200, 103, 50], [0, 0, 0]]);
        let (numbers, images) = compare(&reference, &test, false).expect("same size");
        assert_eq!(numbers["bad_pixels"]["count"], 1);
        assert_eq!(numbers["mean_flip"], Value::Null);
        let (name, map) = &images[0];
        assert_eq!(*name, "bad");
        let px: Vec<&[u8]> = map.as_bytes().chunks(3).collect();
        assert_ne!(px[0], BAD); // 2 steps: not more than the threshold
        assert_eq!(px[1], BAD);
        assert_eq!(px[2], [179, 179, 179]); // black, faded to 30 %
    }

    #[test]
    fn flip_is_computed_only_when_asked() {
        let reference = image(&[[10, 10, 10]; 16]);
        let (numbers, images) = compare(&reference, &reference, true).expect("same size");
        assert_eq!(numbers["mean_flip"], 0.0);
        assert_eq!(numbers["rmse"], 0.0);
        assert_eq!(
            images.iter().map(|(n, _)| *n).collect::<Vec<_>>(),
            ["bad", "flip"]
        );
    }
}
