//! `strata dataset`: per-pixel features labelled by the Optimal-K oracle, as NumPy arrays.

use std::path::PathBuf;

use anyhow::{Context, Result};
use strata_learn::dataset::{Dataset, DatasetSpec, parse_budget};
use strata_scene::Scene;

use crate::options::{open_scene, search_path, thread_pool};

/// Write a training set for a learned variable k-buffer: per-pixel features of scenes seen from
/// several views, each labelled with the Optimal-K oracle's k at several memory budgets.
///
/// Every scene is rendered from `--views` cameras evenly spaced on a circle around its target
/// (view 0 is the scene's own camera). Each view is labelled at every `--budgets` share of its
/// fragments: the oracle keeps, under that budget, the fragments whose removal would change the
/// image most. One row is written per covered pixel, or a seeded sample of
/// `--pixels-per-frame` of them.
///
/// Scenes: `--procedural N` generated scenes (random translucent and opaque spheres, cubes and
/// slabs, 2 to 40 layers deep; the same `--seed` gives the same scenes), and any `--scenes`
/// (built-in names or scene files; the mesh scenes need their mesh files, see
/// `strata scenes`). Every resolution of one mesh belongs to one family (dragon, dragon-res2),
/// so a family can be held out of training later.
///
/// Writes into `--out`: features.npy (float32, rows × features), labels.npy (float32, rows ×
/// 3: k, kept fraction (k − 1)/(count − 1), k / fragments of the frame), frame.npy, scene.npy
/// and pixel.npy (uint32, one per row) and manifest.json (feature and label names, scenes and
/// families, frames with budget, fragments, covered pixels and Σk, and a hash of each file).
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Folder to write the dataset into (created if missing).
    #[arg(long, short, value_name = "DIR")]
    pub(crate) out: PathBuf,

    /// Built-in scene names or scene files, comma-separated (slabs,spheres,mixed,bunny,dragon).
    #[arg(long, value_delimiter = ',', value_name = "SCENES")]
    pub(crate) scenes: Vec<String>,

    /// Generated scenes to include.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub(crate) procedural: u32,

    /// Views per scene, on a circle around the scene's target.
    #[arg(long, default_value_t = 8)]
    pub(crate) views: u32,

    /// Budgets, in percent of each frame's fragments, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "30,50,70,85")]
    pub(crate) budgets: Vec<String>,

    /// Rows written per frame at most: a seeded random choice of the covered pixels (default:
    /// every covered pixel).
    #[arg(long, value_name = "N")]
    pub(crate) pixels_per_frame: Option<usize>,

    /// Seed of the generated scenes and of the pixel sampling.
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,

    /// Render at this size instead of each scene's own (WIDTHxHEIGHT); generated scenes are
    /// 320x240 unless given.
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub(crate) size: Option<(u32, u32)>,

    /// Leave out, with a note, scenes whose mesh files are not found (default: stop with an error).
    #[arg(long)]
    pub(crate) skip_missing: bool,

    /// Worker threads (default: every available core). The data does not depend on it.
    #[arg(long, short = 'j')]
    pub(crate) threads: Option<usize>,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

/// `WIDTHxHEIGHT`, each from 1 to 16384.
fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("{s}: expected WIDTHxHEIGHT, each from 1 to 16384, such as 320x240");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let dim = |d: &str| {
        d.trim()
            .parse::<u32>()
            .ok()
            .filter(|v| (1..=16384).contains(v))
    };
    Ok((dim(w).ok_or_else(bad)?, dim(h).ok_or_else(bad)?))
}

/// The spec, checked before anything is rendered.
fn spec(args: &Args) -> Result<DatasetSpec> {
    let budgets = args
        .budgets
        .iter()
        .map(|b| parse_budget(b).with_context(|| "--budgets".to_owned()))
        .collect::<Result<Vec<_>>>()?;
    if args.views == 0 {
        anyhow::bail!("--views must be at least 1");
    }
    if args.scenes.is_empty() && args.procedural == 0 {
        anyhow::bail!("nothing to render: give --scenes, --procedural N, or both");
    }
    check_writable(&args.out)?;
    Ok(DatasetSpec {
        views: args.views,
        budgets,
        pixels_per_frame: args.pixels_per_frame,
        seed: args.seed,
    })
}

/// Creates `dir` if missing and checks a file can be written in it, before anything is rendered.
fn check_writable(dir: &std::path::Path) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!("--out {}: not a directory", dir.display());
    }
    std::fs::create_dir_all(dir)
        .with_context(|| format!("--out {}: cannot create the folder", dir.display()))?;
    let probe = dir.join(".strata-dataset-probe");
    std::fs::write(&probe, b"")
        .with_context(|| format!("--out {}: cannot write into the folder", dir.display()))?;
    std::fs::remove_file(&probe)
        .with_context(|| format!("--out {}: cannot remove {}", dir.display(), probe.display()))
}

/// Every scene to render, loaded (and resized) before any rendering.
fn scenes(args: &Args) -> Result<Vec<Scene>> {
    let search = search_path(&args.model_dirs);
    let mut out = Vec::new();
    for i in 0..args.procedural {
        let seed = strata_learn::procedural::mix(args.seed.wrapping_add(u64::from(i)));
        let (w, h) = args.size.unwrap_or((320, 240));
        out.push(strata_learn::generate(seed, w, h).scene);
    }
    for name in &args.scenes {
        let mut scene = match open_scene(name, &search) {
            Ok(scene) => scene,
            Err(e) if args.skip_missing && is_missing_mesh(&e) => {
                eprintln!("leaving out {name}: {e:#}");
                continue;
            }
            Err(e) => return Err(e),
        };
        if let Some((w, h)) = args.size {
            (scene.width, scene.height) = (w, h);
        }
        out.push(scene);
    }
    Ok(out)
}

/// Whether `e` says a mesh file was not found.
fn is_missing_mesh(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<strata_scene::SceneError>()
            .is_some_and(|s| matches!(s.kind, strata_scene::SceneErrorKind::MeshNotFound { .. }))
    })
}

/// Runs `strata dataset`.
pub(crate) fn run(args: Args) -> Result<()> {
    let spec = spec(&args)?;
    let scenes = scenes(&args)?;
    let pool = thread_pool(args.threads)?;
    let mut data = Dataset::new(spec)?;
    let frames_per_scene = args.views as usize * data.spec.budgets.len();
    for (i, scene) in scenes.iter().enumerate() {
        eprintln!(
            "scene {}/{}: {} ({}x{}), {} frames",
            i + 1,
            scenes.len(),
            scene.name,
            scene.width,
            scene.height,
            frames_per_scene
        );
        pool.install(|| {
            data.add_scene(scene, |f| {
                eprintln!(
                    "  view {} at {:.0} %: {} fragments, budget {}, {} rows",
                    f.view,
                    f.budget_share * 100.0,
                    f.fragments,
                    f.budget,
                    f.rows
                );
            })
        })
        .with_context(|| format!("cannot label {}", scene.name))?;
    }
    data.write(&args.out)?;
    eprintln!(
        "wrote {} rows from {} frames of {} scenes into {} (see manifest.json)",
        data.rows(),
        data.frames.len(),
        data.scenes.len(),
        args.out.display()
    );
    Ok(())
}
