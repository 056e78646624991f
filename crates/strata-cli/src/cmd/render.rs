//! `strata render`: one frame of a scene to an image (PNG or EXR), a deep EXR, statistics, maps.

use std::path::PathBuf;

use anyhow::{Context, Result};
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::kbuffer::maps::heat_map;
use strata_stores::render_frame;

use crate::images::{EncodedFile, ImageOptions};
use crate::options::{RenderOptions, check_output, open_scene, thread_pool};
use crate::report::{maps_page, stats_json, summary_line};

/// Render one frame of a scene to an image, and optionally its fragments as a deep EXR.
///
/// The image format comes from --out's extension: `.png` (8-bit RGB on the scene's background;
/// `--alpha` for RGBA with a transparent background, `--bits 16` for 16 bits a channel) or `.exr`
/// (flat premultiplied float RGBA). `--deep FILE.exr` writes every fragment of every pixel as an
/// OpenEXR deep scanline image (premultiplied R G B A, Z = distance from the eye, objectid),
/// which compositing tools such as Nuke, Houdini and OpenImageIO read. Everything is checked
/// before rendering, and nothing is written if any check fails. Prints a one-line summary
/// (fragments, depth complexity, per-pass times) on stderr.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name (`strata scenes` lists them).
    pub(crate) scene: String,

    /// Output image, `.png` or `.exr`. Default: `<scene>.png` in the current directory.
    #[arg(long, short)]
    pub(crate) out: Option<PathBuf>,

    /// Also write every pixel's fragments as an OpenEXR deep image (`.exr`). Needs a method that
    /// keeps fragments (every method but wboit).
    #[arg(long, value_name = "FILE.exr")]
    pub(crate) deep: Option<PathBuf>,

    /// Also write statistics (fragments, depth complexity and histogram, memory, per-pass
    /// milliseconds) as JSON to this file.
    #[arg(long)]
    pub(crate) stats: Option<PathBuf>,

    /// Also write the per-pixel maps the method computes (vkbuffer: `k` and `importance`) into
    /// this folder, each as a heat map PNG and a NumPy `.npy` (float32, height × width), and
    /// maps.html showing them with their colour scales. vkbuffer also writes the per-pixel
    /// features a learned k reads: features.npy (float32, height × width × features) and
    /// features.json (the feature names, units and definitions, in column order).
    #[arg(long, value_name = "DIR")]
    pub(crate) maps: Option<PathBuf>,

    /// Animation frame to pose the scene at (0-based).
    #[arg(long, default_value_t = 0)]
    pub(crate) frame: u32,

    #[command(flatten)]
    pub(crate) render: RenderOptions,

    #[command(flatten)]
    pub(crate) image: ImageOptions,
}

/// The scene's short name as a scene would report it: a file's stem, or the built-in's name.
fn scene_stem(spec: &str) -> String {
    let p = std::path::Path::new(spec);
    p.file_stem()
        .map_or_else(|| spec.to_owned(), |s| s.to_string_lossy().into_owned())
}

/// Refuses, before anything is rendered or written, outputs that cannot be written: a missing
/// directory for the image or the statistics, `--maps` for a method that computes none, or a
/// `--maps` path that is a file.
fn check_outputs(
    args: &Args,
    out: &std::path::Path,
    options: &strata_stores::MethodOptions,
) -> Result<()> {
    check_output(out)?;
    let format = args.image.check_flat(out)?;
    if let Some(deep) = &args.deep {
        check_output(deep)?;
        args.image.check_deep(deep)?;
    }
    args.image.check_exr_options(out, args.deep.as_deref())?;
    if let Some(deep) = &args.deep {
        crate::images::check_distinct(&[out, deep.as_path()], &[])?;
    }
    if options.tail_blend && (args.deep.is_some() || args.image.needs_float(format)) {
        anyhow::bail!(
            "--tail-blend blends the fragments beyond the k nearest into the 8-bit opaque image \
             only; the DeepFrame holds the k nearest, so a deep, EXR, 16-bit or transparent \
             output would silently leave the tail out"
        );
    }
    let info = strata_stores::find(&args.render.method)?;
    if info.fidelity(options) == strata_stores::Fidelity::Approximate {
        let what = if args.deep.is_some() {
            Some("a deep image (--deep)")
        } else if args.image.needs_float(format) {
            Some("an EXR, a 16-bit PNG or a transparent PNG (--alpha)")
        } else {
            None
        };
        if let Some(what) = what {
            anyhow::bail!(
                "method {} blends fragments without keeping them, so it cannot write {what}; it writes only 8-bit opaque PNGs",
                info.name
            );
        }
    }
    if let Some(stats) = &args.stats {
        check_output(stats)?;
    }
    if let Some(dir) = &args.maps {
        let info = strata_stores::find(&args.render.method)?;
        if info.pixel_maps.is_empty() {
            let with_maps: Vec<&str> = strata_stores::METHODS
                .iter()
                .filter(|m| !m.pixel_maps.is_empty())
                .map(|m| m.name)
                .collect();
            anyhow::bail!(
                "--maps: method {} computes no per-pixel maps (methods that do: {})",
                info.name,
                with_maps.join(", ")
            );
        }
        if dir.exists() && !dir.is_dir() {
            anyhow::bail!("--maps {}: not a directory", dir.display());
        }
    }
    Ok(())
}

/// Writes every per-pixel map of `method` into `dir` as `.npy` and heat-map PNG, and `maps.html`
/// showing them with their colour scales.
fn write_maps(dir: &std::path::Path, method: &dyn strata_stores::Method) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut legends = Vec::new();
    for m in method.pixel_maps() {
        strata_core::npy::write_f32(
            dir.join(format!("{}.npy", m.name)),
            m.width,
            m.height,
            &m.values,
        )?;
        heat_map(&m.values, m.width, m.height, None)
            .write_png(dir.join(format!("{}.png", m.name)))?;
        let max = m.values.iter().copied().fold(0.0f32, f32::max);
        legends.push((m.name, max));
    }
    if let Some(features) = method.feature_maps() {
        write_features(dir, features)?;
    }
    let page = maps_page(method.name(), &legends);
    let path = dir.join("maps.html");
    std::fs::write(&path, page).with_context(|| format!("cannot write {}", path.display()))?;
    eprintln!(
        "wrote the per-pixel maps into {} (see maps.html)",
        dir.display()
    );
    Ok(())
}

/// Writes `features.npy` ([height, width, features] float32) and `features.json` (the list).
fn write_features(
    dir: &std::path::Path,
    features: &strata_stores::kbuffer::FeatureMaps,
) -> Result<()> {
    use strata_stores::kbuffer::features::{FEATURE_COUNT, FEATURE_SET, FEATURES};
    let (w, h) = features.size();
    strata_core::npy::write(
        dir.join("features.npy"),
        &[h as usize, w as usize, FEATURE_COUNT],
        strata_core::npy::NpyData::F32(&features.interleaved()),
    )?;
    let list: Vec<serde_json::Value> = FEATURES
        .iter()
        .map(|f| serde_json::json!({"name": f.name, "unit": f.unit, "definition": f.definition}))
        .collect();
    let frame = features.frame().map(|f| {
        serde_json::json!({"fragments": f.total, "covered_pixels": f.covered, "budget": f.budget})
    });
    let json = serde_json::json!({
        "feature_set": FEATURE_SET,
        "shape": [h, w, FEATURE_COUNT],
        "features": list,
        "frame": frame,
    });
    let path = dir.join("features.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Runs `strata render`: validate everything, then render, then write.
pub(crate) fn run(args: Args) -> Result<()> {
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("{}.png", scene_stem(&args.scene))));
    let mut options = args.render.checked_method_options()?;
    check_outputs(&args, &out, &options)?;
    options.features = args.maps.is_some();
    let scene = open_scene(&args.scene, &args.render.search_path())?;
    scene.check_frame(args.frame)?;
    let mut method = strata_stores::create(&args.render.method, &options)?;
    let pool = thread_pool(args.render.threads)?;
    let input = FrameInput::from_scene(&scene, args.frame);
    let mut raster = Rasterizer::default();
    let result =
        pool.install(|| render_frame(method.as_mut(), &mut raster, &input, scene.background))?;
    let files = encode_images(&args, &out, method.as_ref(), &result.image, &scene)?;
    crate::images::write_all(&files)?;
    if let Some(path) = &args.stats {
        let json = stats_json(
            &scene,
            method.name(),
            args.frame,
            pool.current_num_threads(),
            &result,
        );
        let text = serde_json::to_string_pretty(&json)?;
        std::fs::write(path, text + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(dir) = &args.maps {
        write_maps(dir, method.as_ref())?;
    }
    eprintln!("{}", summary_line(&scene, &result));
    Ok(())
}

/// The flat image and the deep image, encoded but not yet written.
fn encode_images(
    args: &Args,
    out: &std::path::Path,
    method: &dyn strata_stores::Method,
    image: &strata_core::Rgb8Image,
    scene: &strata_scene::Scene,
) -> Result<Vec<EncodedFile>> {
    let format = args.image.check_flat(out)?;
    let needs_frame = args.deep.is_some() || args.image.needs_float(format);
    let frame = if needs_frame {
        let Some(frame) = method.deep_frame() else {
            anyhow::bail!("method {} keeps no fragments", method.name());
        };
        Some(frame.with_context(|| format!("method {} gave an invalid DeepFrame", method.name()))?)
    } else {
        None
    };
    let mut files = Vec::new();
    match &frame {
        Some(frame) if args.image.needs_float(format) => {
            let rgba = strata_core::RgbaF32Image::from_deep_frame(frame);
            files.push(args.image.encode_flat(out, &rgba, scene.background)?);
        }
        _ => {
            let mut bytes = Vec::new();
            image
                .encode_png(&mut bytes)
                .with_context(|| format!("cannot encode {}", out.display()))?;
            files.push(EncodedFile::new(out.to_owned(), bytes));
        }
    }
    if let (Some(path), Some(frame)) = (&args.deep, &frame) {
        files.push(args.image.encode_deep(path, frame, &scene.camera)?);
    }
    Ok(files)
}
