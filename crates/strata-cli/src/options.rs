//! Options shared by several subcommands: threads, method, model search path, scene opening.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use strata_scene::{Scene, SearchPath};
use strata_stores::{MethodOptions, PoolCapacity};

/// How to render: which method, with which options, on how many threads.
#[derive(Args, Debug, Clone)]
pub(crate) struct RenderOptions {
    /// Fragment store to use (`abuffer`: the per-pixel linked-list A-buffer).
    #[arg(long, short, default_value = "abuffer")]
    pub(crate) method: String,

    /// Node pool of the linked-list A-buffer: `auto` (grow to fit, never drop), a multiple of the
    /// pixel count (`4x`), or a number of fragments. Fixed pools drop and count what overflows.
    #[arg(long, default_value = "auto", value_parser = parse_pool)]
    pub(crate) pool: PoolCapacity,

    /// Worker threads (default: every available core).
    #[arg(long, short = 'j')]
    pub(crate) threads: Option<usize>,

    /// Extra directory to look for mesh files in, searched before STRATA_MODEL_PATH (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

fn parse_pool(s: &str) -> Result<PoolCapacity, String> {
    s.parse()
}

impl RenderOptions {
    /// The options the methods read.
    pub(crate) fn method_options(&self) -> MethodOptions {
        MethodOptions { pool: self.pool }
    }

    /// The mesh search path: `--models` directories, then the environment's.
    pub(crate) fn search_path(&self) -> SearchPath {
        search_path(&self.model_dirs)
    }
}

/// `dirs` first, then `STRATA_MODEL_PATH` and the user model folder.
pub(crate) fn search_path(dirs: &[PathBuf]) -> SearchPath {
    let mut search = SearchPath::from_env();
    for d in dirs.iter().rev() {
        search.prepend(d.clone());
    }
    search
}

/// A rayon pool with `threads` workers (all cores when `None`).
pub(crate) fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let n = match threads {
        Some(0) => anyhow::bail!("--threads must be at least 1"),
        Some(n) => n,
        None => default_threads(),
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .with_context(|| format!("cannot start {n} worker threads"))
}

/// Fails early, before any rendering, if `path`'s directory does not exist.
pub(crate) fn check_output(path: &std::path::Path) -> Result<()> {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() && !dir.is_dir() => anyhow::bail!(
            "cannot write {}: the directory {} does not exist",
            path.display(),
            dir.display()
        ),
        _ => Ok(()),
    }
}

/// Every available core.
pub(crate) fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Opens a scene file or built-in scene, saying on stderr what takes time.
pub(crate) fn open_scene(spec: &str, search: &SearchPath) -> Result<Scene> {
    let start = Instant::now();
    let scene = strata_scene::open_scene(spec, search)?;
    let elapsed = start.elapsed();
    if elapsed.as_millis() >= 200 {
        eprintln!(
            "loaded {} ({} objects, {} triangles) in {:.2} s",
            scene.name,
            scene.objects.len(),
            scene.triangle_count(),
            elapsed.as_secs_f64()
        );
    }
    Ok(scene)
}
