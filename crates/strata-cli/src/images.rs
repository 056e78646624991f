//! Image files by extension: flat PNG (8 or 16 bits, opaque or transparent), flat and deep EXR.
//!
//! Every command that writes an image goes through here, so one set of rules holds everywhere:
//!
//! - the format comes from the extension, `.png` or `.exr` (any case); any other extension is an
//!   error before anything is rendered, never PNG bytes under another name;
//! - `.png` is 8-bit RGB on the scene's background by default; `--alpha` writes RGBA with straight
//!   alpha and no background; `--bits 16` writes 16 bits a channel;
//! - `.exr` is a flat scanline file of premultiplied float RGBA (`--half` for 16-bit floats); the
//!   background is composited in (alpha 1) unless `--alpha`;
//! - `--deep FILE.exr` is an OpenEXR deep scanline file of the DeepFrame (docs/deep-exr.md).
//!
//! Flat images other than the 8-bit opaque PNG are made from the DeepFrame
//! ([`RgbaF32Image::from_deep_frame`]), so they need a method that keeps fragments; the 8-bit
//! opaque PNG is the method's own resolve, so every method can write it.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use strata_core::{DeepFrame, PngAlpha, PngDepth, RgbaF32Image};
use strata_exr::{
    CameraMatrices, Compression, DepthMapping, FlatImage, FrameOptions, SampleType, WriteOptions,
};
use strata_scene::Camera;

/// The flat image formats strata writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum FlatFormat {
    /// Portable Network Graphics.
    Png,
    /// OpenEXR, flat scanline.
    Exr,
}

impl FlatFormat {
    /// The format a path's extension names.
    pub(crate) fn from_path(path: &Path) -> Result<Self> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("png") => Ok(FlatFormat::Png),
            Some("exr") => Ok(FlatFormat::Exr),
            Some(other) => bail!(
                "cannot write {}: strata writes .png and .exr images, not .{other}",
                path.display()
            ),
            None => bail!(
                "cannot write {}: name the format with an extension, .png or .exr",
                path.display()
            ),
        }
    }
}

/// EXR compression as the command line names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum ExrCompression {
    /// No compression.
    None,
    /// Run-length encoding.
    Rle,
    /// zlib, one scanline per block: what every OpenEXR reader takes for deep files.
    Zips,
    /// zlib, 16 scanlines per block (flat files only; OpenEXR's library reads no deep ZIP files).
    Zip,
}

impl From<ExrCompression> for Compression {
    fn from(c: ExrCompression) -> Self {
        match c {
            ExrCompression::None => Compression::None,
            ExrCompression::Rle => Compression::Rle,
            ExrCompression::Zips => Compression::Zips,
            ExrCompression::Zip => Compression::Zip,
        }
    }
}

/// How flat and deep images are written.
#[derive(clap::Args, Debug, Clone)]
#[command(next_help_heading = "Image output")]
pub(crate) struct ImageOptions {
    /// Leave the background out: a PNG gets straight alpha (RGBA), an EXR the coverage in A.
    #[arg(long)]
    pub(crate) alpha: bool,

    /// Bits per channel of a PNG: 8 or 16.
    #[arg(long, default_value_t = 8, value_parser = parse_bits)]
    pub(crate) bits: u8,

    /// Compression of EXR files. Deep files take none, rle or zips.
    #[arg(long, value_enum, default_value_t = ExrCompression::Zips)]
    pub(crate) compression: ExrCompression,

    /// Write EXR colour and alpha as 16-bit half floats: smaller files, and still exact for
    /// strata's 8-bit colours. Depth stays 32-bit float.
    #[arg(long)]
    pub(crate) half: bool,
}

pub(crate) fn parse_bits(s: &str) -> Result<u8, String> {
    match s.trim() {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(format!("'{s}': PNG bits per channel are 8 or 16")),
    }
}

impl ImageOptions {
    /// Checks the options against a flat output path; returns its format.
    pub(crate) fn check_flat(&self, path: &Path) -> Result<FlatFormat> {
        let format = FlatFormat::from_path(path)?;
        if format == FlatFormat::Exr && self.bits != 8 {
            bail!(
                "--bits is for PNG files; {} is an EXR (32-bit float, or --half)",
                path.display()
            );
        }
        Ok(format)
    }

    /// Checks that `--half` and `--compression` have an EXR to apply to: the flat output or a
    /// deep one.
    pub(crate) fn check_exr_options(&self, flat: &Path, deep: Option<&Path>) -> Result<()> {
        let writes_exr = deep.is_some() || FlatFormat::from_path(flat)? == FlatFormat::Exr;
        if writes_exr {
            return Ok(());
        }
        if self.half {
            bail!(
                "--half is for EXR files, and {} is a PNG (use --bits 16, or --deep FILE.exr)",
                flat.display()
            );
        }
        if self.compression != ExrCompression::Zips {
            bail!(
                "--compression is for EXR files, and {} is a PNG",
                flat.display()
            );
        }
        Ok(())
    }

    /// Checks the options against a deep output path.
    pub(crate) fn check_deep(&self, path: &Path) -> Result<()> {
        if FlatFormat::from_path(path)? != FlatFormat::Exr {
            bail!(
                "cannot write {}: deep images are OpenEXR files (.exr)",
                path.display()
            );
        }
        if self.compression == ExrCompression::Zip {
            bail!(
                "--compression zip is for flat EXR files: OpenEXR's own library cannot read deep \
                 ZIP files; use zips (the default), rle or none"
            );
        }
        Ok(())
    }

    /// True when a flat output needs more than the method's own 8-bit opaque resolve.
    pub(crate) fn needs_float(&self, format: FlatFormat) -> bool {
        format == FlatFormat::Exr || self.alpha || self.bits == 16
    }

    fn write_options(&self) -> WriteOptions {
        WriteOptions {
            compression: self.compression.into(),
            ..WriteOptions::default()
        }
    }

    fn colour_type(&self) -> SampleType {
        if self.half {
            SampleType::Half
        } else {
            SampleType::Float
        }
    }

    /// Encodes a flat image (premultiplied, without background) for `path`.
    pub(crate) fn encode_flat(
        &self,
        path: &Path,
        image: &RgbaF32Image,
        background: [f32; 3],
    ) -> Result<EncodedFile> {
        let bytes = match self.check_flat(path)? {
            FlatFormat::Png => {
                let depth = if self.bits == 16 {
                    PngDepth::Sixteen
                } else {
                    PngDepth::Eight
                };
                let alpha = if self.alpha {
                    PngAlpha::Transparent
                } else {
                    PngAlpha::Over(background)
                };
                let mut bytes = Vec::new();
                image
                    .encode_png(&mut bytes, depth, alpha)
                    .with_context(|| format!("cannot encode {}", path.display()))?;
                bytes
            }
            FlatFormat::Exr => {
                let shown = if self.alpha {
                    image.clone()
                } else {
                    image.over(background)
                };
                let pixels: Vec<[f32; 4]> = shown
                    .as_slice()
                    .chunks_exact(4)
                    .map(|p| [p[0], p[1], p[2], p[3]])
                    .collect();
                let flat = FlatImage::from_rgba(
                    image.width(),
                    image.height(),
                    &pixels,
                    self.colour_type(),
                )?;
                strata_exr::write_flat(&flat, &self.write_options())?
            }
        };
        Ok(EncodedFile {
            path: path.to_owned(),
            bytes,
        })
    }

    /// Encodes a DeepFrame rendered through `camera` as a deep EXR for `path`.
    pub(crate) fn encode_deep(
        &self,
        path: &Path,
        frame: &DeepFrame,
        camera: &Camera,
    ) -> Result<EncodedFile> {
        self.check_deep(path)?;
        let mapping = DepthMapping::new(f64::from(camera.near), f64::from(camera.far))?;
        let options = FrameOptions {
            color: self.colour_type(),
            camera: Some(CameraMatrices {
                view: camera.view().to_cols_array(),
                projection: camera
                    .projection(frame.width(), frame.height())
                    .to_cols_array(),
            }),
            ..FrameOptions::default()
        };
        let image = strata_exr::deep_from_frame(frame, mapping, &options)?;
        let bytes = strata_exr::write_deep(&image, &self.write_options())?;
        Ok(EncodedFile {
            path: path.to_owned(),
            bytes,
        })
    }
}

/// A DeepFrame rendered with `view` and `projection` by a camera with clip planes `near`, `far`,
/// as the bytes of a deep EXR (float colour, ZIPS): what `--save-deep` writes.
pub(crate) fn deep_exr_bytes(
    frame: &DeepFrame,
    (near, far): (f32, f32),
    view: glam::Mat4,
    projection: glam::Mat4,
) -> Result<Vec<u8>> {
    let mapping = DepthMapping::new(f64::from(near), f64::from(far))?;
    let options = FrameOptions {
        camera: Some(CameraMatrices {
            view: view.to_cols_array(),
            projection: projection.to_cols_array(),
        }),
        ..FrameOptions::default()
    };
    let image = strata_exr::deep_from_frame(frame, mapping, &options)?;
    Ok(strata_exr::write_deep(&image, &WriteOptions::default())?)
}

/// Refuses an output that names the same file as another output or as an input (after
/// resolving `.`/`..` and links where the file exists), so nothing is overwritten unseen.
pub(crate) fn check_distinct(outputs: &[&Path], inputs: &[&Path]) -> Result<()> {
    let key = |p: &Path| -> PathBuf {
        if let Ok(c) = std::fs::canonicalize(p) {
            return c;
        }
        // Not there yet: its directory resolved, plus its name.
        let dir = p.parent().filter(|d| !d.as_os_str().is_empty());
        let dir = dir.map_or_else(|| std::fs::canonicalize("."), std::fs::canonicalize);
        match (dir, p.file_name()) {
            (Ok(d), Some(name)) => d.join(name),
            _ => p.to_owned(),
        }
    };
    for (i, out) in outputs.iter().enumerate() {
        let k = key(out);
        if let Some(other) = outputs[..i].iter().find(|o| key(o) == k) {
            bail!(
                "{} and {} name the same file; give each output its own name",
                other.display(),
                out.display()
            );
        }
        if let Some(input) = inputs.iter().find(|p| key(p) == k) {
            bail!(
                "{} is both an input and an output; write the output elsewhere",
                input.display()
            );
        }
    }
    Ok(())
}

/// A file's bytes, made before any file is written so that a late error leaves nothing behind.
pub(crate) struct EncodedFile {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl EncodedFile {
    /// Wraps bytes made elsewhere.
    pub(crate) fn new(path: PathBuf, bytes: Vec<u8>) -> Self {
        EncodedFile { path, bytes }
    }

    /// Writes the file and says so on stderr.
    pub(crate) fn write(&self) -> Result<()> {
        std::fs::write(&self.path, &self.bytes)
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        eprintln!("wrote {}", self.path.display());
        Ok(())
    }
}

/// Writes every file, in order.
pub(crate) fn write_all(files: &[EncodedFile]) -> Result<()> {
    files.iter().try_for_each(EncodedFile::write)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_by_extension_and_nothing_else() {
        assert_eq!(
            FlatFormat::from_path(Path::new("a/b.PNG")).unwrap(),
            FlatFormat::Png
        );
        assert_eq!(
            FlatFormat::from_path(Path::new("b.exr")).unwrap(),
            FlatFormat::Exr
        );
        let err = FlatFormat::from_path(Path::new("b.jpg")).unwrap_err();
        assert!(err.to_string().contains("not .jpg"), "{err}");
        let err = FlatFormat::from_path(Path::new("noext")).unwrap_err();
        assert!(err.to_string().contains("extension"), "{err}");
    }
}
