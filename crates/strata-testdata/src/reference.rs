//! Exact comparison of a rendered image against a reference PNG kept in the repository.
//!
//! A reference is an 8-bit RGB PNG `<dir>/<name>.png`. [`assert_matches_reference`] compares the
//! rendered pixels with it byte for byte:
//!
//! - equal: the test goes on;
//! - `STRATA_BLESS=1`: the reference is (re)written from the rendered image and a `BLESSED:` line
//!   is printed — run this after an intended change, look at the new PNG, and commit it;
//! - different: `<dir>/<name>.actual.png` (what was rendered) and `<dir>/<name>.diff.png` (the
//!   reference dimmed to a quarter, every differing pixel in red, brighter the larger the
//!   difference) are written next to the reference, and the test fails naming both, the number
//!   of differing pixels, the largest channel difference and the first differing pixel.
//!
//! Keep references small (a few hundred pixels wide): they live in git.

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::{Path, PathBuf};

/// The environment variable that rewrites reference images when set to `1`.
pub const BLESS_VAR: &str = "STRATA_BLESS";

/// Pixels as the references store them: 8-bit RGB, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rgb8<'a> {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` bytes.
    pub data: &'a [u8],
}

/// Why a reference could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReferenceError {
    /// The file could not be opened or created.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a PNG the decoder accepts.
    #[error("{path}: cannot decode PNG: {source}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: png::DecodingError,
    },
    /// Encoding failed.
    #[error("{path}: cannot encode PNG: {source}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: png::EncodingError,
    },
    /// The PNG is not 8-bit RGB.
    #[error("{path}: references are 8-bit RGB PNGs, this one is {color:?} with {bits:?} bits")]
    Layout {
        /// The file.
        path: PathBuf,
        /// Its colour type.
        color: png::ColorType,
        /// Its bit depth.
        bits: png::BitDepth,
    },
}

/// An owned 8-bit RGB image read from a PNG.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OwnedRgb8 {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` bytes.
    pub data: Vec<u8>,
}

/// Reads an 8-bit RGB PNG.
pub fn read_rgb8_png(path: &Path) -> Result<OwnedRgb8, ReferenceError> {
    let file = File::open(path).map_err(|source| ReferenceError::Io {
        path: path.to_owned(),
        source,
    })?;
    let decode = |source| ReferenceError::Decode {
        path: path.to_owned(),
        source,
    };
    let mut reader = png::Decoder::new(BufReader::new(file))
        .read_info()
        .map_err(decode)?;
    let mut data = vec![0; reader.output_buffer_size().unwrap_or(0)];
    let info = reader.next_frame(&mut data).map_err(decode)?;
    if (info.color_type, info.bit_depth) != (png::ColorType::Rgb, png::BitDepth::Eight) {
        return Err(ReferenceError::Layout {
            path: path.to_owned(),
            color: info.color_type,
            bits: info.bit_depth,
        });
    }
    data.truncate(info.buffer_size());
    Ok(OwnedRgb8 {
        width: info.width,
        height: info.height,
        data,
    })
}

/// Writes an 8-bit RGB PNG (best compression: references are committed).
pub fn write_rgb8_png(path: &Path, image: &Rgb8<'_>) -> Result<(), ReferenceError> {
    let encode = |source| ReferenceError::Encode {
        path: path.to_owned(),
        source,
    };
    let file = File::create(path).map_err(|source| ReferenceError::Io {
        path: path.to_owned(),
        source,
    })?;
    let mut encoder = png::Encoder::new(BufWriter::new(file), image.width, image.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::High);
    let mut writer = encoder.write_header().map_err(encode)?;
    writer.write_image_data(image.data).map_err(encode)?;
    writer.finish().map_err(encode)
}

/// How two same-sized images differ.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Difference {
    /// Pixels with at least one differing channel.
    pub pixels: u64,
    /// The largest absolute difference of one channel.
    pub max_channel: u8,
    /// The first differing pixel in row-major order, `(x, y)`.
    pub first: Option<(u32, u32)>,
    /// The diff image: the reference at a quarter brightness, differing pixels red.
    pub image: Vec<u8>,
}

/// Compares `actual` with `want` (both `width` pixels wide, same length).
pub fn difference(width: u32, want: &[u8], actual: &[u8]) -> Difference {
    let mut d = Difference {
        pixels: 0,
        max_channel: 0,
        first: None,
        image: Vec::with_capacity(want.len()),
    };
    for (i, (w, a)) in want.chunks_exact(3).zip(actual.chunks_exact(3)).enumerate() {
        let worst = w
            .iter()
            .zip(a)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0);
        if worst == 0 {
            d.image.extend(w.iter().map(|c| c / 4));
            continue;
        }
        d.pixels += 1;
        d.max_channel = d.max_channel.max(worst);
        let i = i as u32;
        d.first.get_or_insert((i % width.max(1), i / width.max(1)));
        d.image
            .extend_from_slice(&[128u8.saturating_add(worst.saturating_mul(8).min(127)), 0, 0]);
    }
    d
}

/// Whether `STRATA_BLESS` asks to rewrite references.
fn blessing() -> bool {
    match std::env::var_os(BLESS_VAR) {
        None => false,
        Some(v) if v.is_empty() || v == "0" => false,
        Some(v) if v == "1" => true,
        Some(v) => panic!("{BLESS_VAR} must be 1 (rewrite reference images) or 0, not {v:?}"),
    }
}

/// What [`check_reference`] did when the image was acceptable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Checked {
    /// The image equals the reference.
    Matched,
    /// The reference was rewritten from the image (this path).
    Blessed(PathBuf),
}

/// Compares `image` with the reference `<dir>/<name>.png`, or rewrites the reference when `bless`
/// is set. On a difference, writes the actual and diff images next to the reference and returns
/// the failure message.
pub fn check_reference(
    dir: &Path,
    name: &str,
    image: &Rgb8<'_>,
    bless: bool,
) -> Result<Checked, String> {
    let expected_len = image.width as usize * image.height as usize * 3;
    if image.data.len() != expected_len {
        return Err(format!(
            "{name}: {}×{} RGB pixels need {expected_len} bytes, got {}",
            image.width,
            image.height,
            image.data.len()
        ));
    }
    let reference = dir.join(format!("{name}.png"));
    if bless {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        write_rgb8_png(&reference, image).map_err(|e| e.to_string())?;
        return Ok(Checked::Blessed(reference));
    }
    let want = read_rgb8_png(&reference).map_err(|e| {
        format!(
            "cannot read the reference image: {e}\n(run the test with {BLESS_VAR}=1 to create it)"
        )
    })?;
    if (want.width, want.height) == (image.width, image.height) && want.data == image.data {
        return Ok(Checked::Matched);
    }
    let actual_path = dir.join(format!("{name}.actual.png"));
    write_rgb8_png(&actual_path, image).map_err(|e| e.to_string())?;
    if (want.width, want.height) != (image.width, image.height) {
        return Err(format!(
            "{name}: rendered {}×{} but the reference {} is {}×{}; wrote {}",
            image.width,
            image.height,
            reference.display(),
            want.width,
            want.height,
            actual_path.display()
        ));
    }
    let diff = difference(image.width, &want.data, image.data);
    let diff_path = dir.join(format!("{name}.diff.png"));
    let diff_image = Rgb8 {
        data: &diff.image,
        ..image.clone()
    };
    write_rgb8_png(&diff_path, &diff_image).map_err(|e| e.to_string())?;
    Err(format!(
        "{name}: {} of {} pixels differ from {} (largest channel difference {}, first at {:?}); \
         wrote {} and {}. If the change is intended, rerun with {BLESS_VAR}=1 and commit the new reference.",
        diff.pixels,
        u64::from(image.width) * u64::from(image.height),
        reference.display(),
        diff.max_channel,
        diff.first.unwrap_or_default(),
        actual_path.display(),
        diff_path.display()
    ))
}

/// Asserts that `image` equals the reference `<dir>/<name>.png` exactly; with `STRATA_BLESS=1`
/// rewrites the reference instead and prints a `BLESSED:` line (see the module docs).
#[track_caller]
pub fn assert_matches_reference(dir: &Path, name: &str, image: &Rgb8<'_>) {
    match check_reference(dir, name, image, blessing()) {
        Ok(Checked::Matched) => {}
        Ok(Checked::Blessed(path)) => crate::say(&format!("BLESSED: {} rewritten", path.display())),
        Err(message) => panic!("{message}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<u8> = (0..2 * 3 * 3).map(|i| (i * 13) as u8).collect();
        let img = Rgb8 {
            width: 2,
            height: 3,
            data: &data,
        };
        let path = dir.path().join("x.png");
        write_rgb8_png(&path, &img).unwrap();
        let back = read_rgb8_png(&path).unwrap();
        assert_eq!((back.width, back.height, &back.data[..]), (2, 3, &data[..]));
    }

    #[test]
    fn difference_counts_and_locates_pixels() {
        let want = [10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110, 120];
        let mut actual = want;
        actual[7] = 83; // pixel 2 (x 0, y 1 at width 2), green off by 3
        actual[9] = 0; // pixel 3, red off by 100
        let d = difference(2, &want, &actual);
        assert_eq!((d.pixels, d.max_channel, d.first), (2, 100, Some((0, 1))));
        assert_eq!(&d.image[..6], &[2, 5, 7, 10, 12, 15], "equal pixels dimmed");
        assert_eq!(
            &d.image[6..],
            &[152, 0, 0, 255, 0, 0],
            "differing pixels red"
        );
    }

    #[test]
    fn mismatch_writes_actual_and_diff_next_to_the_reference() {
        let dir = tempfile::tempdir().unwrap();
        let want = [0u8; 12];
        write_rgb8_png(
            &dir.path().join("r.png"),
            &Rgb8 {
                width: 2,
                height: 2,
                data: &want,
            },
        )
        .unwrap();
        let mut got = want;
        got[4] = 9;
        let img = Rgb8 {
            width: 2,
            height: 2,
            data: &got,
        };
        let msg = check_reference(dir.path(), "r", &img, false).expect_err("the images differ");
        assert!(
            msg.starts_with("r: 1 of 4 pixels differ from") && msg.contains("first at (1, 0)"),
            "{msg}"
        );
        let actual = read_rgb8_png(&dir.path().join("r.actual.png")).unwrap();
        assert_eq!(actual.data, got);
        let diff = read_rgb8_png(&dir.path().join("r.diff.png")).unwrap();
        assert_eq!(&diff.data[3..6], &[200, 0, 0]);
        // The reference itself matches; blessing rewrites it from the new image.
        let same = Rgb8 {
            data: &want,
            ..img.clone()
        };
        assert_eq!(
            check_reference(dir.path(), "r", &same, false),
            Ok(Checked::Matched)
        );
        let blessed = check_reference(dir.path(), "r", &img, true);
        assert_eq!(blessed, Ok(Checked::Blessed(dir.path().join("r.png"))));
        assert_eq!(
            check_reference(dir.path(), "r", &img, false),
            Ok(Checked::Matched)
        );
    }
}
