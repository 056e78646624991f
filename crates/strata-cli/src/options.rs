//! Options shared by several subcommands: threads, method, model search path, scene opening.
//!
//! Method options are checked twice over: their values by the argument parser (the range-checking
//! parse functions of `strata_stores::options`), and whether the chosen method reads them by
//! [`MethodParams::checked_for`], from the names [`given_method_options`] found set on the command
//! line (clap's value source tells a user's value from a default).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use clap::parser::ValueSource;
use strata_scene::{Scene, SearchPath};
use strata_stores::options as opt;
use strata_stores::{Budget, ImportanceParams, KFrom, MethodOptions, PoolCapacity};

/// Parameters of the fragment stores. Each method reads some of them (`strata methods` says
/// which); one given on the command line that the chosen method does not read is an error.
///
/// The values are parsed and range-checked by the same functions as `key=value` in a method spec
/// (`strata compare --methods kbuffer:k=8`).
#[derive(Args, Debug, Clone)]
#[command(next_help_heading = "Method options")]
pub(crate) struct MethodParams {
    /// abuffer, tfss: node pool — `auto` (grow to fit, never drop), a positive multiple of the
    /// pixel count (`4x`), or a number of fragments. Fixed pools drop and count what overflows.
    #[arg(long, default_value = "auto", value_parser = |s: &str| s.parse::<PoolCapacity>())]
    pub(crate) pool: PoolCapacity,

    /// abuffer-array: fragments per pixel (A), 1 to 1024.
    #[arg(long, default_value_t = 8, value_parser = opt::parse_array_size)]
    pub(crate) array_size: u32,

    /// kbuffer: fragments kept per pixel (k), 1 to 1024.
    #[arg(short, long, default_value_t = 4, value_parser = opt::parse_k)]
    pub(crate) k: u32,

    /// kbuffer: blend the fragments beyond the k nearest behind them instead of dropping them.
    #[arg(long)]
    pub(crate) tail_blend: bool,

    /// vkbuffer: memory budget — a share of the frame's fragments above 0 % and up to 100 %
    /// (`50%`), an average per pixel (`2x`), bytes (`20MB`, `16MiB`) or a number of fragments.
    #[arg(long, default_value = "50%", value_parser = |s: &str| s.parse::<Budget>())]
    pub(crate) budget: Budget,

    /// vkbuffer: where k(p) comes from — `importance` maps, the `optimal` (Optimal-K) oracle,
    /// `analytic` (water-filling an error model of each pixel's layers from their mean colour and
    /// opacity, gathered in the counting pass: no learning), or `learned` (a small network
    /// corrects that model from per-pixel features of the counting pass; see --weights).
    #[arg(long, default_value = "importance", value_parser = |s: &str| s.parse::<KFrom>())]
    pub(crate) k_from: KFrom,

    /// vkbuffer with `--k-from learned`: a weights file written by `strata learn train`
    /// (default: the weights built into strata; `strata learn info` describes them).
    #[arg(long, value_name = "FILE", value_parser = parse_weights)]
    pub(crate) weights: Option<std::sync::Arc<strata_stores::kbuffer::LearnedModel>>,

    /// vkbuffer importance: periphery fall-off exponent d, greater than 0 and at most 64.
    #[arg(long, default_value_t = 2.0, value_parser = opt::parse_periphery_exponent)]
    pub(crate) periphery_exponent: f64,

    /// vkbuffer importance: depth-complexity range bias α in [0, 1].
    #[arg(long, default_value_t = 0.1, value_parser = opt::parse_range_bias)]
    pub(crate) range_bias: f64,

    /// vkbuffer importance: N_limit, the layer count of full importance, at least 1 (default: the
    /// frame's largest per-pixel fragment count).
    #[arg(long, value_parser = opt::parse_n_limit)]
    pub(crate) n_limit: Option<u32>,

    /// vkbuffer importance: noise level λ in [0, 1].
    #[arg(long, default_value_t = 0.1, value_parser = opt::parse_noise)]
    pub(crate) noise: f64,

    /// vkbuffer importance: point of interest as `x,y` fractions of the image, each in [0, 1]
    /// (0.5,0.5 = centre).
    #[arg(long, default_value = "0.5,0.5", value_parser = opt::parse_point_of_interest)]
    pub(crate) point_of_interest: [f64; 2],

    /// vkbuffer importance: seed of the noise.
    #[arg(long, default_value_t = 0, value_parser = opt::parse_seed)]
    pub(crate) seed: u64,

    /// tfss: fragments per T-buffer section (L_num), 1 to 64.
    #[arg(long, default_value_t = 2, value_parser = opt::parse_l_num)]
    pub(crate) l_num: u32,

    /// tfss: leading-zeros elimination of colours, with a Length table.
    #[arg(long)]
    pub(crate) leading_zeros: bool,

    /// depth-peeling, dual-depth-peeling: most layers to peel (0: until nothing is left).
    #[arg(long, default_value_t = 0, value_parser = opt::parse_max_layers)]
    pub(crate) max_layers: u32,

    /// The options above that the command line set (not left at their defaults), by name;
    /// filled in by `main` after parsing.
    #[arg(skip)]
    pub(crate) given: Vec<&'static str>,
}

/// Splits a method spec, `name[:key=value[:key]…]`, into the method's name and its settings (a
/// flag written without a value has none), as `compare --methods` and `view --method` read it.
pub(crate) fn split_spec(spec: &str) -> (&str, impl Iterator<Item = (&str, Option<&str>)>) {
    let mut parts = spec.split(':');
    let method = parts.next().unwrap_or_default().trim();
    let settings = parts.map(|part| match part.split_once('=') {
        Some((k, v)) => (k.trim(), Some(v.trim())),
        None => (part.trim(), None),
    });
    (method, settings)
}

/// Sets `settings` (an option's name and its value; a flag may have none) on top of `base` for
/// `method`, refusing an unknown option, a bad value, and any option that `method` does not
/// read once every option is set (`k-from` decides whether the importance options are read).
/// Method specs (`compare --methods kbuffer:k=8`) and the viewer's form both come through here.
pub(crate) fn configure<'s>(
    method: &str,
    base: &MethodOptions,
    settings: impl IntoIterator<Item = (&'s str, Option<&'s str>)>,
) -> Result<MethodOptions> {
    let mut options = base.clone();
    let mut set = Vec::new();
    for (key, value) in settings {
        let option = options.set(key, value)?;
        set.push((option, key.trim()));
    }
    for (option, shown) in set {
        strata_stores::check_option(method, option, shown, &options)?;
    }
    Ok(options)
}

/// Reads `--weights FILE`.
fn parse_weights(s: &str) -> Result<std::sync::Arc<strata_stores::kbuffer::LearnedModel>, String> {
    strata_stores::kbuffer::LearnedModel::read(std::path::Path::new(s))
        .map(std::sync::Arc::new)
        .map_err(|e| e.to_string())
}

/// The method options `matches` (one subcommand's) got from the command line, by name.
pub(crate) fn given_method_options(matches: &clap::ArgMatches) -> Vec<&'static str> {
    opt::OPTION_NAMES
        .iter()
        .copied()
        .filter(|name| {
            let id = name.replace('-', "_");
            matches.ids().any(|i| i.as_str() == id)
                && matches.value_source(&id) == Some(ValueSource::CommandLine)
        })
        .collect()
}

impl MethodParams {
    /// The options the methods read, unchecked (see [`MethodParams::checked_for`]).
    pub(crate) fn method_options(&self) -> MethodOptions {
        MethodOptions {
            pool: self.pool,
            array_size: self.array_size,
            k: self.k,
            tail_blend: self.tail_blend,
            budget: self.budget,
            k_from: self.k_from,
            importance: ImportanceParams {
                periphery_exponent: self.periphery_exponent,
                alpha: self.range_bias,
                n_limit: self.n_limit,
                noise: self.noise,
                point_of_interest: self.point_of_interest,
                seed: self.seed,
            },
            l_num: self.l_num,
            leading_zeros: self.leading_zeros,
            max_layers: self.max_layers,
            features: false,
            weights: self.weights.clone(),
        }
    }

    /// The options for `method`, refusing an unknown method and any option the command line set
    /// that `method` does not read.
    pub(crate) fn checked_for(&self, method: &str) -> Result<MethodOptions> {
        let options = self.method_options();
        strata_stores::find(method)?;
        for option in &self.given {
            strata_stores::check_option(method, option, &format!("--{option}"), &options)?;
        }
        Ok(options)
    }
}

/// How to render: which method, with which options, on how many threads.
#[derive(Args, Debug, Clone)]
pub(crate) struct RenderOptions {
    /// Fragment store to use (`strata methods` lists them).
    #[arg(long, short, default_value = "abuffer")]
    pub(crate) method: String,

    #[command(flatten)]
    pub(crate) params: MethodParams,

    /// Worker threads (default: every available core).
    #[arg(long, short = 'j')]
    pub(crate) threads: Option<usize>,

    /// Extra directory to look for mesh files in, searched before STRATA_MODEL_PATH (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

impl RenderOptions {
    /// The options the methods read, unchecked (see [`RenderOptions::checked_method_options`]).
    pub(crate) fn method_options(&self) -> MethodOptions {
        self.params.method_options()
    }

    /// The options for `--method`, refusing an unknown method and any option the command line
    /// set that the method does not read.
    pub(crate) fn checked_method_options(&self) -> Result<MethodOptions> {
        self.params.checked_for(&self.method)
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
    if path.is_dir() {
        anyhow::bail!("cannot write {}: it is a directory", path.display());
    }
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() && !dir.is_dir() => anyhow::bail!(
            "cannot write {}: the directory {} does not exist",
            path.display(),
            dir.display()
        ),
        _ => Ok(()),
    }
}

/// `WIDTHxHEIGHT` (`--size`), each side 1 to the largest frame a scene may have.
pub(crate) fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let max = strata_scene::scene::file::MAX_IMAGE_SIDE;
    let bad = || format!("'{s}': expected WIDTHxHEIGHT such as 1280x720, each side 1 to {max}");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if !(1..=max).contains(&w) || !(1..=max).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
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
