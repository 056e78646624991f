//! `strata bench`: per-pass medians over repeated runs, and thread scaling.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use strata_core::stats::median;
use strata_core::{DeepFrame, DepthStats, PassTimings, RunLimit};
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::{CaptureReport, Method, check_exports, export_frame, render_frame};

use crate::options::{
    MethodParams, check_output, default_threads, open_scene, search_path, thread_pool,
};
use crate::report::{bytes_per_fragment, cpu_model};

/// Time each pass of a method on a scene: median, min and max over repeated runs.
///
/// Every run is a full frame (clear, capture, resolve) with buffers reused from the previous run,
/// as in an animation. Give several thread counts (`--threads 1,2`) to see the scaling. Timings are
/// wall-clock on a possibly shared machine, measured on the CPU named in the output: compare
/// medians from one invocation. Where a figure measured elsewhere exists for the scene and method
/// (the full dragon with abuffer), it is printed after the results as a reference, with the
/// machine it comes from. With `--export` a run is a render node's frame instead: clear, capture
/// and export the DeepFrame that `strata node` then encodes.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name.
    pub(crate) scene: String,

    /// Fragment store to measure.
    #[arg(long, short, default_value = "abuffer")]
    pub(crate) method: String,

    #[command(flatten)]
    pub(crate) params: MethodParams,

    /// Time what a render node renders (`strata node`): clear, capture and export the DeepFrame
    /// (every pixel's fragments sorted front to back), instead of clear, capture and resolve.
    #[arg(long)]
    pub(crate) export: bool,

    /// With `--export`, keep at most N nearest fragments of every pixel, as a render node
    /// serving the depth-limited transfer does (`strata display --transfer depth-limited
    /// --layers N`): each run is cut as it is exported.
    #[arg(long, value_name = "N", requires = "export", value_parser = clap::value_parser!(u32).range(1..))]
    pub(crate) export_layers: Option<u32>,

    /// Timed runs per thread count.
    #[arg(long, default_value_t = 15)]
    pub(crate) runs: usize,

    /// Untimed runs first (page faults, pool growth, caches).
    #[arg(long, default_value_t = 3)]
    pub(crate) warmup: usize,

    /// Thread counts to measure, comma-separated (default: every available core).
    #[arg(long, short = 'j', value_delimiter = ',')]
    pub(crate) threads: Vec<usize>,

    /// Animation frame to pose the scene at.
    #[arg(long, default_value_t = 0)]
    pub(crate) frame: u32,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,

    /// Also write the figures as JSON to this file.
    #[arg(long)]
    pub(crate) json: Option<PathBuf>,
}

/// A figure measured elsewhere that a benchmark is printed beside, for scale: what ran, on which
/// machine, and how long it took.
struct ReferenceFigure {
    what: &'static str,
    cpu: &'static str,
    ms: f64,
}

/// The reference figures for `method` on `scene` (width × height), if there are any: the
/// linked-list A-buffer on the full dragon at 1280×720 as GLSL shaders on a software GPU.
fn reference_figures(scene: &str, size: (u32, u32), method: &str) -> &'static [ReferenceFigure] {
    const WHAT: &str = "the linked-list A-buffer GLSL shaders of the thesis strata follows, run by \
                        Mesa llvmpipe (a software GPU driver), full dragon at 1280x720";
    const DRAGON: &[ReferenceFigure] = &[
        ReferenceFigure {
            what: WHAT,
            cpu: "AMD EPYC, 2 cores",
            ms: 257.0,
        },
        ReferenceFigure {
            what: WHAT,
            cpu: "Intel Xeon, 2 cores",
            ms: 347.0,
        },
        ReferenceFigure {
            what: WHAT,
            cpu: "AMD EPYC with AVX-512, 2 cores",
            ms: 184.0,
        },
    ];
    match (scene, size, method) {
        ("dragon", (1280, 720), "abuffer") => DRAGON,
        _ => &[],
    }
}

#[derive(Default)]
struct Samples {
    order: Vec<&'static str>,
    by_name: BTreeMap<&'static str, Vec<Duration>>,
    totals: Vec<Duration>,
}

impl Samples {
    fn add(&mut self, timings: &PassTimings) {
        for (n, d) in timings.iter() {
            if !self.by_name.contains_key(n) {
                self.order.push(n);
            }
            self.by_name.entry(n).or_default().push(d);
        }
        self.totals.push(timings.total());
    }
}

/// What one timed run leaves behind for the report.
struct Run {
    timings: PassTimings,
    capture: CaptureReport,
    depth: DepthStats,
    memory_bytes: u64,
    used_memory_bytes: u64,
    /// The exported frame (none when resolved).
    frame: Option<DeepFrame>,
}

/// What a timed frame ends with.
enum RunKind {
    /// The resolve ([`render_frame`]).
    Resolve,
    /// A DeepFrame export as a render node runs it ([`export_frame`]), each run cut to the
    /// limit, in the buffers of the frame held, if any.
    Export(RunLimit, Option<DeepFrame>),
}

/// One timed frame (for an export, the depth statistics come from the exported frame).
fn one_run(
    method: &mut dyn Method,
    raster: &mut Rasterizer,
    input: &FrameInput<'_>,
    background: [f32; 3],
    kind: RunKind,
) -> Result<Run> {
    if let RunKind::Export(limit, reuse) = kind {
        let r = export_frame(method, raster, input, limit, reuse)?;
        Ok(Run {
            depth: r.frame.depth_stats(),
            frame: Some(r.frame),
            timings: r.timings,
            capture: r.capture,
            memory_bytes: r.memory_bytes,
            used_memory_bytes: r.used_memory_bytes,
        })
    } else {
        let r = render_frame(method, raster, input, background)?;
        Ok(Run {
            depth: r.depth.unwrap_or_default(),
            timings: r.timings,
            capture: r.capture,
            memory_bytes: r.memory_bytes,
            used_memory_bytes: r.used_memory_bytes,
            frame: None,
        })
    }
}

/// Median, min, max in milliseconds (zeros for no samples).
fn stats(v: &[Duration]) -> (f64, f64, f64) {
    let ms = || v.iter().map(|d| d.as_secs_f64() * 1e3);
    let min = ms().reduce(f64::min).unwrap_or(0.0);
    let max = ms().reduce(f64::max).unwrap_or(0.0);
    (median(ms()).unwrap_or(0.0), min, max)
}

/// Runs `strata bench`.
pub(crate) fn run(args: Args) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let threads = if args.threads.is_empty() {
        vec![default_threads()]
    } else {
        args.threads.clone()
    };
    // Check everything that can be checked before minutes of measuring.
    if threads.contains(&0) {
        bail!("--threads must be at least 1 (got {threads:?})");
    }
    if let Some(path) = &args.json {
        check_output(path)?;
    }
    let options = args.params.checked_for(&args.method)?;
    let cpu = cpu_model();
    let scene = open_scene(&args.scene, &search_path(&args.model_dirs))?;
    scene.check_frame(args.frame)?;
    let input = FrameInput::from_scene(&scene, args.frame);
    if args.export {
        let mut method = strata_stores::create(&args.method, &options)?;
        check_exports(method.as_mut(), &input)
            .with_context(|| format!("--export cannot time method '{}'", args.method))?;
    }

    let limit = args
        .export_layers
        .map_or(RunLimit::NONE, |n| RunLimit::new(n, None));
    let what = match args.export_layers {
        Some(n) if args.export => format!(
            "clear, capture and export a DeepFrame of at most {n} fragments a pixel (a depth-limited render node's frame)"
        ),
        _ if args.export => "clear, capture and export a DeepFrame (a render node's frame)".into(),
        _ => "clear, capture and resolve".into(),
    };
    outln!(
        "strata bench: {} ({} triangles, {}x{}), method {}, frame {}, {} runs after {} warm-up, each {what}; measured on {cpu}",
        scene.name,
        scene.triangle_count(),
        scene.width,
        scene.height,
        args.method,
        args.frame,
        args.runs,
        args.warmup
    )?;
    let mut per_threads = Vec::new();
    let mut medians = Vec::new();
    for &n in &threads {
        let pool = thread_pool(Some(n))?;
        let mut method = strata_stores::create(&args.method, &options)?;
        let mut raster = Rasterizer::default();
        let mut samples = Samples::default();
        let mut last: Option<Run> = None;
        for run in 0..args.warmup + args.runs {
            let kind = if args.export {
                // An exported frame lends its buffers to the next, as a render node's frames do.
                RunKind::Export(limit, last.as_mut().and_then(|r| r.frame.take()))
            } else {
                RunKind::Resolve
            };
            let r = pool.install(|| {
                one_run(method.as_mut(), &mut raster, &input, scene.background, kind)
            })?;
            if run >= args.warmup {
                samples.add(&r.timings);
            }
            last = Some(r);
        }
        let last = last.context("no run")?;
        let depth = last.depth.clone();
        let fragments = last.capture.fragments_stored;
        let (total_med, total_min, total_max) = stats(&samples.totals);
        outln!()?;
        outln!(
            "threads {n}: {fragments} fragments{}, {} covered pixels, depth max {} mean {:.2}, memory {:.1} MiB used of {:.1} MiB allocated = {:.1} B/fragment{}",
            match (&last.frame, args.export_layers) {
                // The depth statistics are the exported frame's.
                (Some(f), Some(_)) => format!(" ({} exported)", f.fragment_count()),
                _ => String::new(),
            },
            depth.covered_pixels(),
            depth.max_depth_complexity(),
            depth.mean_depth_complexity(),
            last.used_memory_bytes as f64 / (1 << 20) as f64,
            last.memory_bytes as f64 / (1 << 20) as f64,
            bytes_per_fragment(last.used_memory_bytes, fragments),
            if last.capture.dropped > 0 {
                format!(", {} DROPPED", last.capture.dropped)
            } else {
                String::new()
            },
        )?;
        outln!(
            "  {:<18} {:>9} {:>9} {:>9}",
            "pass (ms)",
            "median",
            "min",
            "max"
        )?;
        let mut passes = serde_json::Map::new();
        for name in &samples.order {
            let (med, min, max) = stats(&samples.by_name[name]);
            let label = match name.split_once('.') {
                Some((_, stage)) => format!("  {stage}"),
                None => (*name).to_owned(),
            };
            outln!("  {label:<18} {med:>9.2} {min:>9.2} {max:>9.2}")?;
            passes.insert(
                (*name).to_owned(),
                json!({"median": med, "min": min, "max": max}),
            );
        }
        outln!(
            "  {:<18} {total_med:>9.2} {total_min:>9.2} {total_max:>9.2}",
            "total"
        )?;
        let fps = fragments as f64 / (total_med / 1e3);
        outln!(
            "  {:.1} M fragments/s (fragments / median total), on {cpu}",
            fps / 1e6
        )?;
        medians.push((n, total_med));
        per_threads.push(json!({
            "threads": n,
            "passes_ms": Value::Object(passes),
            "total_ms": {"median": total_med, "min": total_min, "max": total_max},
            "fragments": fragments,
            // What the export kept (fewer than the store held with --export-layers).
            "exported_fragments": last.frame.as_ref().map(|f| f.fragment_count()),
            "fragments_per_second": fps,
            "memory_bytes": last.memory_bytes,
            "used_memory_bytes": last.used_memory_bytes,
            "bytes_per_fragment": bytes_per_fragment(last.used_memory_bytes, fragments),
            "dropped_fragments": last.capture.dropped,
            "max_depth_complexity": depth.max_depth_complexity(),
            "covered_pixels": depth.covered_pixels(),
        }));
    }
    if medians.len() > 1 {
        let (n0, t0) = medians[0];
        let parts: Vec<String> = medians
            .iter()
            .map(|&(n, t)| format!("{n} thread(s) {t:.2} ms ({:.2}x)", t0 / t))
            .collect();
        outln!(
            "\nscaling (median total, relative to {n0} thread(s)), on {cpu}: {}",
            parts.join(", ")
        )?;
    }
    // The reference figures are of a resolved frame.
    let figures = if args.export {
        &[][..]
    } else {
        reference_figures(&scene.name, (scene.width, scene.height), &args.method)
    };
    if let (Some(first), Some(&(n, best))) = (figures.first(), medians.last()) {
        outln!(
            "\nreference figures, measured elsewhere and not by this run: {}:",
            first.what
        )?;
        for f in figures {
            outln!("  {:.0} ms on {}", f.ms, f.cpu)?;
        }
        outln!("  strata, this run: {best:.2} ms with {n} thread(s) on {cpu}")?;
        outln!(
            "  (machines of one kind differ; scripts/raster-anchor measures the anchor and strata \
             alternately on this machine and prints the ratio)"
        )?;
    }
    if let Some(path) = &args.json {
        let doc = json!({
            "scene": scene.name,
            "method": args.method,
            "export": args.export,
            "export_layers": args.export_layers,
            "frame": args.frame,
            "width": scene.width,
            "height": scene.height,
            "triangles": scene.triangle_count(),
            "runs": args.runs,
            "warmup": args.warmup,
            "cpu": cpu,
            "results": per_threads,
            "reference_figures": figures
                .iter()
                .map(|f| json!({"what": f.what, "cpu": f.cpu, "ms": f.ms, "measured_by_this_run": false}))
                .collect::<Vec<_>>(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&doc)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_figures_only_for_the_full_dragon_with_the_a_buffer() {
        let f = reference_figures("dragon", (1280, 720), "abuffer");
        let by_cpu: Vec<(&str, f64)> = f.iter().map(|f| (f.cpu, f.ms)).collect();
        assert_eq!(
            by_cpu,
            [
                ("AMD EPYC, 2 cores", 257.0),
                ("Intel Xeon, 2 cores", 347.0),
                ("AMD EPYC with AVX-512, 2 cores", 184.0)
            ]
        );
        assert!(f.iter().all(|f| f.what.contains("llvmpipe")));
        assert!(reference_figures("dragon", (640, 360), "abuffer").is_empty());
        assert!(reference_figures("dragon", (1280, 720), "sbuffer").is_empty());
        assert!(reference_figures("bunny", (1280, 720), "abuffer").is_empty());
    }

    #[test]
    fn stats_are_median_min_max_in_milliseconds() {
        let d = |ms| Duration::from_millis(ms);
        assert_eq!(stats(&[d(5), d(1), d(3), d(10)]), (4.0, 1.0, 10.0));
        assert_eq!(stats(&[]), (0.0, 0.0, 0.0));
    }
}
