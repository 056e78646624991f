//! The resolved frame with its coverage: premultiplied RGBA in 32-bit float, and its PNG forms.
//!
//! [`Rgb8Image`](crate::Rgb8Image) is what a resolve onto an opaque background gives. Compositing
//! tools want more: the colour *without* the background and how much of the pixel the fragments
//! cover (alpha), at more than 8 bits. [`RgbaF32Image`] holds exactly that.
//!
//! # Layout
//!
//! ```text
//! data: [f32; 4 * w * h]    pixel (x, y) at 4 * (y * w + x): R G B A, row 0 at the top
//! ```
//!
//! The colour is **premultiplied** by alpha, as OpenEXR and compositing tools expect: compositing
//! a pixel's run front to back with the transmittance `T` (see [`composite`](crate::composite)),
//!
//! ```text
//! C = Σ T_i · α_i · c_i        A = 1 − Π (1 − α_i)
//! ```
//!
//! and the pixel over an opaque background `b` is `C + (1 − A) · b`. An empty pixel is `(0,0,0,0)`.
//!
//! PNG stores *straight* (unpremultiplied) alpha: [`RgbaF32Image::write_png`] divides by `A` when
//! it writes RGBA, and composites onto the background when it writes RGB.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use rayon::prelude::*;

use crate::deep_frame::DeepFrame;
use crate::fragment::UNORM8_TO_F32;
use crate::image::ImageError;

/// Bits per channel of a written PNG.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngDepth {
    /// 8 bits per channel (`round(v · 255)`).
    Eight,
    /// 16 bits per channel (`round(v · 65535)`).
    Sixteen,
}

/// What a written PNG holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PngAlpha {
    /// RGBA with straight alpha: the background is left out (transparent).
    Transparent,
    /// RGB: the image composited onto this opaque background.
    Over([f32; 3]),
}

/// A premultiplied RGBA image in 32-bit float, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaF32Image {
    width: u32,
    height: u32,
    data: Vec<f32>,
}

impl RgbaF32Image {
    /// A transparent image (every channel 0).
    pub fn transparent(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize * 4;
        RgbaF32Image {
            width,
            height,
            data: vec![0.0; n],
        }
    }

    /// An image from premultiplied RGBA values, or `None` if `data` is not `4 · w · h` long.
    pub fn from_raw(width: u32, height: u32, data: Vec<f32>) -> Option<Self> {
        (data.len() == width as usize * height as usize * 4).then_some(RgbaF32Image {
            width,
            height,
            data,
        })
    }

    /// Composites every run of `frame` front to back, leaving the background out.
    pub fn from_deep_frame(frame: &DeepFrame) -> Self {
        let mut image = Self::transparent(frame.width(), frame.height());
        const PIXELS: usize = 4096;
        image
            .data
            .par_chunks_mut(PIXELS * 4)
            .enumerate()
            .for_each(|(chunk, out)| {
                let p0 = chunk * PIXELS;
                for (i, px) in out.chunks_exact_mut(4).enumerate() {
                    let run = frame.run(p0 + i);
                    let (acc, t) = crate::composite::front_to_back_f32(
                        run.color
                            .iter()
                            .map(|c| c.0.map(|v| UNORM8_TO_F32[v as usize])),
                    );
                    px.copy_from_slice(&[acc[0], acc[1], acc[2], 1.0 - t]);
                }
            });
        image
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The premultiplied RGBA of pixel (x, y).
    ///
    /// # Panics
    /// If (x, y) is outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 4] {
        assert!(x < self.width && y < self.height, "pixel out of range");
        let i = (y as usize * self.width as usize + x as usize) * 4;
        [
            self.data[i],
            self.data[i + 1],
            self.data[i + 2],
            self.data[i + 3],
        ]
    }

    /// Row-major premultiplied RGBA values.
    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }

    /// The pixel values a PNG of this image holds, before quantisation, in `[0, 1]`: straight
    /// RGBA (`C / A`, 0 where `A` is 0) or RGB over the background.
    fn png_values(&self, alpha: PngAlpha) -> impl Iterator<Item = f32> + '_ {
        self.data.chunks_exact(4).flat_map(move |px| {
            let [r, g, b, a] = [px[0], px[1], px[2], px[3]];
            match alpha {
                PngAlpha::Transparent if a > 0.0 => [r / a, g / a, b / a, a].into_iter().take(4),
                PngAlpha::Transparent => [0.0; 4].into_iter().take(4),
                PngAlpha::Over(bg) => {
                    let t = 1.0 - a;
                    [r + t * bg[0], g + t * bg[1], b + t * bg[2], 1.0]
                        .into_iter()
                        .take(3)
                }
            }
        })
    }

    /// Encodes a PNG into `out`: RGBA with straight alpha or RGB over a background, 8 or 16 bits.
    pub fn encode_png(
        &self,
        out: impl Write,
        depth: PngDepth,
        alpha: PngAlpha,
    ) -> Result<(), png::EncodingError> {
        let mut encoder = png::Encoder::new(out, self.width, self.height);
        encoder.set_color(match alpha {
            PngAlpha::Transparent => png::ColorType::Rgba,
            PngAlpha::Over(_) => png::ColorType::Rgb,
        });
        encoder.set_compression(png::Compression::Fast);
        // Paeth for every row rather than an adaptive choice per row: as small, faster (see
        // `Rgb8Image::encode_png`).
        encoder.set_filter(png::Filter::Paeth);
        let bytes: Vec<u8> = match depth {
            PngDepth::Eight => {
                encoder.set_depth(png::BitDepth::Eight);
                self.png_values(alpha)
                    .map(crate::fragment::unorm8)
                    .collect()
            }
            PngDepth::Sixteen => {
                encoder.set_depth(png::BitDepth::Sixteen);
                // PNG stores 16-bit samples big-endian.
                self.png_values(alpha)
                    .flat_map(|v| unorm16(v).to_be_bytes())
                    .collect()
            }
        };
        let mut writer = encoder.write_header()?;
        writer.write_image_data(&bytes)?;
        writer.finish()
    }

    /// Writes a PNG file (see [`RgbaF32Image::encode_png`]).
    pub fn write_png(
        &self,
        path: impl AsRef<Path>,
        depth: PngDepth,
        alpha: PngAlpha,
    ) -> Result<(), ImageError> {
        let path = path.as_ref();
        let io = |source| ImageError::Io {
            path: path.to_owned(),
            source,
        };
        let mut out = BufWriter::new(File::create(path).map_err(io)?);
        self.encode_png(&mut out, depth, alpha)
            .map_err(|source| ImageError::Encode {
                path: path.to_owned(),
                source,
            })?;
        out.flush().map_err(io)
    }

    /// This image composited onto an opaque background: `C + (1 − A) · b`, alpha 1.
    pub fn over(&self, background: [f32; 3]) -> RgbaF32Image {
        let data = self
            .data
            .chunks_exact(4)
            .flat_map(|px| {
                let t = 1.0 - px[3];
                [
                    px[0] + t * background[0],
                    px[1] + t * background[1],
                    px[2] + t * background[2],
                    1.0,
                ]
            })
            .collect();
        RgbaF32Image {
            width: self.width,
            height: self.height,
            data,
        }
    }
}

/// `round(clamp(v, 0, 1) · 65535)`; NaN becomes 0.
fn unorm16(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fragment::{ObjectId, Rgba8};

    /// Two pixels: half-transparent red over half-transparent blue, and nothing.
    fn frame() -> DeepFrame {
        DeepFrame::from_pixel_lists(
            2,
            1,
            &[
                vec![
                    crate::Fragment {
                        depth: 0.25,
                        color: Rgba8([255, 0, 0, 128]),
                        object: ObjectId(0),
                    },
                    crate::Fragment {
                        depth: 0.5,
                        color: Rgba8([0, 0, 255, 128]),
                        object: ObjectId(1),
                    },
                ],
                vec![],
            ],
        )
        .expect("valid frame")
    }

    #[test]
    fn premultiplied_composite_without_background() {
        let img = RgbaF32Image::from_deep_frame(&frame());
        let a = 128.0 / 255.0;
        let [r, g, b, alpha] = img.pixel(0, 0);
        assert!((r - a).abs() < 1e-6, "{r}");
        assert_eq!(g, 0.0);
        assert!((b - (1.0 - a) * a).abs() < 1e-6, "{b}");
        assert!(
            (alpha - (1.0 - (1.0 - a) * (1.0 - a))).abs() < 1e-6,
            "{alpha}"
        );
        assert_eq!(img.pixel(1, 0), [0.0; 4]);
    }

    #[test]
    fn over_background_matches_the_8_bit_resolve() {
        let f = frame();
        let bg = [1.0, 1.0, 1.0];
        let eight = f.resolve(bg);
        let float = RgbaF32Image::from_deep_frame(&f).over(bg);
        for x in 0..2 {
            let p = float.pixel(x, 0);
            let q = eight.pixel(x, 0);
            for c in 0..3 {
                assert_eq!(crate::fragment::unorm8(p[c]), q[c], "pixel {x} channel {c}");
            }
        }
    }

    #[test]
    fn png_round_trip_straight_alpha_and_16_bit() {
        let img = RgbaF32Image::from_deep_frame(&frame());
        let mut bytes = Vec::new();
        img.encode_png(&mut bytes, PngDepth::Sixteen, PngAlpha::Transparent)
            .expect("encodes");
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = decoder.read_info().expect("decodes");
        let info = reader.info();
        assert_eq!(info.color_type, png::ColorType::Rgba);
        assert_eq!(info.bit_depth, png::BitDepth::Sixteen);
        let mut buf = vec![0; reader.output_buffer_size().expect("size")];
        reader.next_frame(&mut buf).expect("frame");
        let px: Vec<u16> = buf
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect();
        let [_, _, _, a] = img.pixel(0, 0);
        assert_eq!(px[3], unorm16(a));
        // Straight colour: red over blue, un-premultiplied, red channel = (α) / A.
        assert_eq!(px[0], unorm16(img.pixel(0, 0)[0] / a));
        // The empty pixel is fully transparent.
        assert_eq!(&px[4..8], &[0, 0, 0, 0]);
    }
}
