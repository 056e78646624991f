//! The resolved frame: an 8-bit RGB image, row 0 at the top, and its PNG form.

use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

/// Errors reading or writing images.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImageError {
    /// The file could not be created, opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
    /// PNG encoding failed.
    #[error("{path}: cannot encode PNG: {source}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: png::EncodingError,
    },
    /// PNG decoding failed.
    #[error("{path}: cannot decode PNG: {source}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: png::DecodingError,
    },
    /// The PNG is valid but not 8-bit RGB or RGBA.
    #[error(
        "{path}: unsupported PNG layout {color:?} with {bits:?} bits (expected 8-bit RGB or RGBA)"
    )]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The colour type found.
        color: png::ColorType,
        /// The bit depth found.
        bits: png::BitDepth,
    },
}

/// An 8-bit RGB image stored row-major, row 0 at the top, 3 bytes per pixel.
#[derive(Clone, PartialEq, Eq)]
pub struct Rgb8Image {
    width: u32,
    height: u32,
    data: Vec<u8>,
}

impl std::fmt::Debug for Rgb8Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Rgb8Image({}x{})", self.width, self.height)
    }
}

impl Rgb8Image {
    /// An image filled with one colour.
    pub fn filled(width: u32, height: u32, rgb: [u8; 3]) -> Self {
        let n = width as usize * height as usize;
        let data = rgb.repeat(n);
        Rgb8Image {
            width,
            height,
            data,
        }
    }

    /// Wraps row-major RGB bytes; `None` if the length is not `width * height * 3`.
    pub fn from_raw(width: u32, height: u32, data: Vec<u8>) -> Option<Self> {
        (data.len() == width as usize * height as usize * 3).then_some(Rgb8Image {
            width,
            height,
            data,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The pixel at column `x`, row `y` (row 0 at the top).
    ///
    /// # Panics
    /// If `(x, y)` is outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside {self:?}"
        );
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Row-major RGB bytes.
    pub fn as_bytes(&self) -> &[u8] {
        &self.data
    }

    /// Mutable row-major RGB bytes (for resolves that write rows in parallel).
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }

    /// Encodes as an 8-bit RGB PNG into `out`.
    pub fn encode_png(&self, out: impl Write) -> Result<(), png::EncodingError> {
        self.encode_png_rows(0..self.height, out)
    }

    /// Encodes rows `rows` (full width) as an 8-bit RGB PNG of their own into `out`: the bands
    /// of a split of `0..height`, stacked in order, are the image (the viewer encodes the bands
    /// of a frame in parallel). An empty band is the encoder's error (a PNG has a row).
    ///
    /// # Panics
    /// If the rows end below the image, like a slice indexed past its end.
    pub fn encode_png_rows(
        &self,
        rows: std::ops::Range<u32>,
        out: impl Write,
    ) -> Result<(), png::EncodingError> {
        assert!(
            rows.end <= self.height,
            "rows {rows:?} of an image of {} rows",
            self.height
        );
        let mut encoder = png::Encoder::new(out, self.width, rows.len() as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        // The default deflate level costs more than rendering a frame; fast is ~10 % larger.
        encoder.set_compression(png::Compression::Fast);
        // One filter for every row instead of trying all five per row (`Fast`'s adaptive
        // choice): Paeth gives files as small (within 1 % on the built-in and Stanford scenes)
        // in 20-48 % less time, which the viewer pays once a frame.
        encoder.set_filter(png::Filter::Paeth);
        let row = self.width as usize * 3;
        let mut writer = encoder.write_header()?;
        writer.write_image_data(&self.data[rows.start as usize * row..rows.end as usize * row])?;
        writer.finish()
    }

    /// Writes an 8-bit RGB PNG file.
    pub fn write_png(&self, path: impl AsRef<Path>) -> Result<(), ImageError> {
        let path = path.as_ref();
        let file = File::create(path).map_err(|source| ImageError::Io {
            path: path.to_owned(),
            source,
        })?;
        let mut out = BufWriter::new(file);
        self.encode_png(&mut out)
            .map_err(|source| ImageError::Encode {
                path: path.to_owned(),
                source,
            })?;
        out.flush().map_err(|source| ImageError::Io {
            path: path.to_owned(),
            source,
        })
    }

    /// Reads an 8-bit RGB or RGBA PNG file (alpha is dropped).
    pub fn read_png(path: impl AsRef<Path>) -> Result<Self, ImageError> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|source| ImageError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::decode_png(BufReader::new(file), path)
    }

    fn decode_png(
        input: impl std::io::BufRead + std::io::Seek,
        path: &Path,
    ) -> Result<Self, ImageError> {
        let decode = |source| ImageError::Decode {
            path: path.to_owned(),
            source,
        };
        let mut reader = png::Decoder::new(input).read_info().map_err(decode)?;
        let size = reader.output_buffer_size().unwrap_or(0);
        let mut buf = vec![0; size];
        let info = reader.next_frame(&mut buf).map_err(decode)?;
        let channels = match (info.color_type, info.bit_depth) {
            (png::ColorType::Rgb, png::BitDepth::Eight) => 3,
            (png::ColorType::Rgba, png::BitDepth::Eight) => 4,
            (color, bits) => {
                return Err(ImageError::Unsupported {
                    path: path.to_owned(),
                    color,
                    bits,
                });
            }
        };
        let data: Vec<u8> = buf[..info.buffer_size()]
            .chunks_exact(channels)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect();
        Ok(Rgb8Image {
            width: info.width,
            height: info.height,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip() {
        let mut img = Rgb8Image::filled(3, 2, [1, 2, 3]);
        img.as_bytes_mut()[3..6].copy_from_slice(&[200, 100, 50]);
        let dir = std::env::temp_dir().join(format!("strata-core-png-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.png");
        img.write_png(&path).unwrap();
        let back = Rgb8Image::read_png(&path).unwrap();
        assert_eq!(back, img);
        assert_eq!(back.pixel(1, 0), [200, 100, 50]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bands_encoded_apart_stack_into_the_image() {
        let (w, h) = (7u32, 11u32);
        let data = (0..w * h * 3).map(|i| (i * 37 % 251) as u8).collect();
        let img = Rgb8Image::from_raw(w, h, data).unwrap();
        let mut stacked = Vec::new();
        for rows in [0..4, 4..5, 5..11] {
            let mut png = Vec::new();
            img.encode_png_rows(rows.clone(), &mut png).unwrap();
            let band = Rgb8Image::decode_png(std::io::Cursor::new(png), Path::new("band")).unwrap();
            assert_eq!((band.width(), band.height()), (w, rows.len() as u32));
            stacked.extend_from_slice(band.as_bytes());
        }
        assert_eq!(stacked, img.as_bytes());
        assert!(
            img.encode_png_rows(3..3, &mut Vec::new()).is_err(),
            "no rows"
        );
    }

    #[test]
    #[should_panic(expected = "rows 9..12 of an image of 11 rows")]
    fn a_band_past_the_image_is_a_bug() {
        let img = Rgb8Image::filled(2, 11, [0; 3]);
        let _ = img.encode_png_rows(9..12, &mut Vec::new());
    }

    #[test]
    fn reading_garbage_is_an_error_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("strata-core-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bad.png");
        std::fs::write(&path, b"not a png").unwrap();
        let err = Rgb8Image::read_png(&path).unwrap_err().to_string();
        assert!(err.contains("bad.png"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
