//! `strata render`: one frame of a scene to a PNG (and statistics JSON).

use std::path::PathBuf;

use anyhow::{Context, Result};
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::kbuffer::maps::heat_map;
use strata_stores::render_frame;

use crate::options::{RenderOptions, check_output, open_scene, thread_pool};
use crate::report::{stats_json, summary_line};

/// Render one frame of a scene to a PNG.
///
/// Prints a one-line summary (fragments, depth complexity, per-pass times) on stderr.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name (`strata scenes` lists them).
    pub(crate) scene: String,

    /// Output image (PNG). Default: `<scene>.png` in the current directory.
    #[arg(long, short)]
    pub(crate) out: Option<PathBuf>,

    /// Also write statistics (fragments, depth complexity and histogram, memory, per-pass
    /// milliseconds) as JSON to this file.
    #[arg(long)]
    pub(crate) stats: Option<PathBuf>,

    /// Also write the per-pixel maps the method computes (vkbuffer: `k` and `importance`) into
    /// this folder, each as a heat map PNG and a NumPy `.npy` (float32, height × width).
    #[arg(long, value_name = "DIR")]
    pub(crate) maps: Option<PathBuf>,

    /// Animation frame to pose the scene at (0-based).
    #[arg(long, default_value_t = 0)]
    pub(crate) frame: u32,

    #[command(flatten)]
    pub(crate) render: RenderOptions,
}

/// The scene's short name as a scene would report it: a file's stem, or the built-in's name.
fn scene_stem(spec: &str) -> String {
    let p = std::path::Path::new(spec);
    p.file_stem()
        .map_or_else(|| spec.to_owned(), |s| s.to_string_lossy().into_owned())
}

/// Runs `strata render`.
pub(crate) fn run(args: Args) -> Result<()> {
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("{}.png", scene_stem(&args.scene))));
    check_output(&out)?;
    if let Some(stats) = &args.stats {
        check_output(stats)?;
    }
    if let Some(dir) = &args.maps {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let scene = open_scene(&args.scene, &args.render.search_path())?;
    scene.check_frame(args.frame)?;
    let mut method = strata_stores::create(&args.render.method, &args.render.method_options())?;
    let pool = thread_pool(args.render.threads)?;
    let input = FrameInput::from_scene(&scene, args.frame);
    let mut raster = Rasterizer::default();
    let result =
        pool.install(|| render_frame(method.as_mut(), &mut raster, &input, scene.background))?;
    result.image.write_png(&out)?;
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
        let maps = method.pixel_maps();
        if maps.is_empty() {
            anyhow::bail!(
                "method {} computes no per-pixel maps (vkbuffer does)",
                method.name()
            );
        }
        for m in maps {
            strata_core::npy::write_f32(
                dir.join(format!("{}.npy", m.name)),
                m.width,
                m.height,
                &m.values,
            )?;
            heat_map(&m.values, m.width, m.height, None)
                .write_png(dir.join(format!("{}.png", m.name)))?;
        }
        eprintln!("wrote the per-pixel maps into {}", dir.display());
    }
    eprintln!("{}", summary_line(&scene, &result));
    eprintln!("wrote {}", out.display());
    Ok(())
}
