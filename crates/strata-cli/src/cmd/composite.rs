//! `strata composite`: deep-merge deep OpenEXR images and flatten the result.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use strata_core::RgbaF32Image;
use strata_exr::{DeepImage, FlatImage, Limits, WriteOptions};

use crate::images::{EncodedFile, ExrCompression, FlatFormat};

/// Deep-merge deep OpenEXR images (strata's or any tool's) and flatten the result.
///
/// Every pixel's samples from all inputs are merged front to back by Z (volumetric samples that
/// overlap are split, as OpenImageIO's `--deepmerge` does), then composited front to back with
/// OVER (as `--flatten` does). The inputs may cover different data windows; the result covers
/// their union. The output format comes from -o's extension: `.exr` (flat, every flattened
/// channel) or `.png` (RGBA with straight alpha, or RGB over `--background`).
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Deep OpenEXR files to merge (one or more).
    #[arg(required = true, value_name = "DEEP.exr")]
    pub(crate) inputs: Vec<PathBuf>,

    /// The flattened image: `.exr` or `.png`.
    #[arg(long, short)]
    pub(crate) out: PathBuf,

    /// Also write the merged deep image (before flattening) to this `.exr`.
    #[arg(long, value_name = "FILE.exr")]
    pub(crate) deep_out: Option<PathBuf>,

    /// PNG only: composite onto this opaque background `r,g,b` (each in [0, 1]) and write RGB;
    /// without it the PNG is RGBA with a transparent background.
    #[arg(long, value_parser = parse_rgb)]
    pub(crate) background: Option<[f32; 3]>,

    /// Bits per channel of a PNG: 8 or 16.
    #[arg(long, default_value_t = 8, value_parser = crate::images::parse_bits)]
    pub(crate) bits: u8,

    /// Compression of the EXR files written. Deep files take none, rle or zips.
    #[arg(long, value_enum, default_value_t = ExrCompression::Zips)]
    pub(crate) compression: ExrCompression,
}

fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let parts: Vec<f32> = s
        .split(',')
        .map(|v| v.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}': expected r,g,b such as 1,1,1"))?;
    match parts[..] {
        [r, g, b] if [r, g, b].iter().all(|v| (0.0..=1.0).contains(v)) => Ok([r, g, b]),
        _ => Err(format!(
            "'{s}': expected three numbers in [0, 1], such as 1,1,1"
        )),
    }
}

/// Runs `strata composite`.
pub(crate) fn run(args: Args) -> Result<()> {
    let format = FlatFormat::from_path(&args.out)?;
    if format == FlatFormat::Exr && (args.bits != 8 || args.background.is_some()) {
        bail!(
            "--bits and --background are for PNG output; {} is an EXR (premultiplied float RGBA)",
            args.out.display()
        );
    }
    if let Some(deep) = &args.deep_out {
        if FlatFormat::from_path(deep)? != FlatFormat::Exr {
            bail!("--deep-out {}: deep images are .exr files", deep.display());
        }
        if args.compression == ExrCompression::Zip {
            bail!("--compression zip is for flat EXR files; deep files take none, rle or zips");
        }
    }
    if format == FlatFormat::Png
        && args.deep_out.is_none()
        && args.compression != ExrCompression::Zips
    {
        bail!(
            "--compression is for EXR files, and {} is a PNG (add --deep-out FILE.exr to write one)",
            args.out.display()
        );
    }
    crate::options::check_output(&args.out)?;
    let mut outputs = vec![args.out.as_path()];
    if let Some(deep) = &args.deep_out {
        crate::options::check_output(deep)?;
        outputs.push(deep.as_path());
    }
    let inputs: Vec<&std::path::Path> = args.inputs.iter().map(PathBuf::as_path).collect();
    crate::images::check_distinct(&outputs, &inputs)?;

    let images = common_channels(read_inputs(&args.inputs)?)?;
    let merged = strata_exr::merge(&images).context("cannot merge the inputs")?;
    let flat = without_window_depth(
        strata_exr::flatten(&merged).context("cannot flatten the merged image")?,
    )?;
    let options = WriteOptions {
        compression: args.compression.into(),
        ..WriteOptions::default()
    };

    let mut files = Vec::new();
    if let Some(deep) = &args.deep_out {
        files.push(EncodedFile::new(
            deep.clone(),
            strata_exr::write_deep(&merged, &options)?,
        ));
    }
    let bytes = match format {
        FlatFormat::Exr => strata_exr::write_flat(&flat, &options)?,
        FlatFormat::Png => {
            let rgba = rgba_of(&flat)?;
            let depth = if args.bits == 16 {
                strata_core::PngDepth::Sixteen
            } else {
                strata_core::PngDepth::Eight
            };
            let alpha = match args.background {
                Some(bg) => strata_core::PngAlpha::Over(bg),
                None => strata_core::PngAlpha::Transparent,
            };
            let mut bytes = Vec::new();
            rgba.encode_png(&mut bytes, depth, alpha)
                .with_context(|| format!("cannot encode {}", args.out.display()))?;
            bytes
        }
    };
    files.push(EncodedFile::new(args.out.clone(), bytes));

    let samples: usize = images.iter().map(DeepImage::sample_count).sum();
    eprintln!(
        "merged {} deep image(s), {} samples in all, into {}x{} pixels ({} samples)",
        images.len(),
        samples,
        merged.width(),
        merged.height(),
        merged.sample_count()
    );
    crate::images::write_all(&files)
}

/// The inputs restricted to the channels they all have (tools add their own, such as strata's
/// `objectid`), saying on stderr what is left out; an error if `A` or `Z` is not among them.
fn common_channels(images: Vec<DeepImage>) -> Result<Vec<DeepImage>> {
    let names = |image: &DeepImage| -> Vec<String> {
        image.channels().iter().map(|c| c.name.clone()).collect()
    };
    let Some(first) = images.first() else {
        bail!("no input");
    };
    let common: Vec<String> = names(first)
        .into_iter()
        .filter(|n| images.iter().all(|i| i.channel_index(n).is_some()))
        .collect();
    for needed in ["A", "Z"] {
        if !common.iter().any(|n| n == needed) {
            bail!("not every input has a `{needed}` channel, so they cannot be depth-composited");
        }
    }
    if images.iter().all(|i| names(i) == common) {
        return Ok(images);
    }
    let mut dropped: Vec<String> = images
        .iter()
        .flat_map(names)
        .filter(|n| !common.contains(n))
        .collect();
    dropped.sort();
    dropped.dedup();
    eprintln!(
        "note: merging the channels every input has ({}); left out: {}",
        common.join(" "),
        dropped.join(" ")
    );
    images
        .into_iter()
        .map(|image| {
            let keep: Vec<usize> = common
                .iter()
                .filter_map(|n| image.channel_index(n))
                .collect();
            let channels = keep.iter().map(|&c| image.channels()[c].clone()).collect();
            let columns = keep.iter().map(|&c| image.column(c).clone()).collect();
            let mut out = DeepImage::new(
                image.data_window(),
                channels,
                image.offsets().to_vec(),
                columns,
            )?;
            out.set_display_window(image.display_window());
            for a in image.attributes() {
                out.set_attribute(a.clone());
            }
            Ok(out)
        })
        .collect()
}

/// The flat image without strata's per-sample window depth, which has no flat meaning.
fn without_window_depth(flat: FlatImage) -> Result<FlatImage> {
    let Some(skip) = flat.channel_index(strata_exr::WINDOW_DEPTH_CHANNEL) else {
        return Ok(flat);
    };
    let keep: Vec<usize> = (0..flat.channels().len()).filter(|&c| c != skip).collect();
    let mut out = FlatImage::new(
        flat.data_window(),
        keep.iter().map(|&c| flat.channels()[c].clone()).collect(),
        keep.iter().map(|&c| flat.column(c).clone()).collect(),
    )?;
    out.set_display_window(flat.display_window());
    for a in flat.attributes() {
        out.set_attribute(a.clone());
    }
    Ok(out)
}

/// Reads every input as a deep image, saying which file is wrong.
fn read_inputs(paths: &[PathBuf]) -> Result<Vec<DeepImage>> {
    let limits = Limits::default();
    paths
        .iter()
        .map(|path| {
            let bytes = strata_exr::read_file_bytes(path, &limits)
                .with_context(|| format!("cannot read {}", path.display()))?;
            let info = strata_exr::read_info(&bytes)
                .with_context(|| format!("{} is not a readable OpenEXR file", path.display()))?;
            if !info.deep {
                bail!(
                    "{} is a flat image; composite merges deep images (oiiotool IN --deepen -o OUT \
                     makes a deep image of a flat one)",
                    path.display()
                );
            }
            strata_exr::read_deep(&bytes, &limits)
                .with_context(|| format!("cannot read the deep image {}", path.display()))
        })
        .collect()
}

/// The premultiplied RGBA of a flattened image (missing colour channels are 0).
fn rgba_of(flat: &FlatImage) -> Result<RgbaF32Image> {
    if flat.channel_index("A").is_none() {
        bail!("the flattened image has no A channel, so it cannot be written as a PNG");
    }
    let data: Vec<f32> = flat.rgba().into_iter().flatten().collect();
    let width = u32::try_from(flat.width()).context("image too wide")?;
    let height = u32::try_from(flat.height()).context("image too high")?;
    RgbaF32Image::from_raw(width, height, data).context("inconsistent flattened image")
}
