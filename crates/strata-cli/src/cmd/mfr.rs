//! `strata mfr`: slow and fast clients on a virtual clock, every frame audited.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use strata_mfr::client::Client;
use strata_mfr::simulate::{FcFrame, Migration, VirtualClock, run_virtual};
use strata_mfr::trace::{GrabParams, Trace, grab, orbit};
use strata_mfr::{Composition, FrameAudit, audit, table_6_1_row};
use strata_mfr::{RealStats, run_real};

use crate::options::{open_scene, search_path};

/// Multi-frame-rate rendering: a slow and a fast client composited, every frame audited.
///
/// The slow client (SC) renders the scene's objects that nobody is manipulating, at the newest
/// state whenever it is free; the fast client (FC) renders the objects the user points at, holds
/// or just released, every frame, and composes them with the newest SC buffer by merging
/// fragment lists (deep composition), so transparent objects composite correctly across the two.
/// Time is simulated (`--clock virtual:sc_ms=…,fc_ms=…,transfer_ms=…`): rendering is real and
/// results are reproducible at any SC:FC ratio. Each FC frame is compared with the whole scene
/// rendered at once: bad pixels (> 2/255), and ghost, hole and blend pixels (an object shown where
/// it is not, missing where it is, or blended wrongly). The trace is a file (`.toml` or `.jsonl`,
/// see docs/mfr.md) or a generator: `grab:object=NAME,start_ms=…,over_lead_ms=…,hold_ms=…,
/// distance=…,linger_ms=…` or `orbit:period_ms=…,duration_ms=…`. Exit status 0 when the run
/// completed (artefacts are reported, not failures), 2 on bad input.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name.
    pub(crate) scene: String,

    /// Interaction trace: a file (.toml, .jsonl) or `grab:…` / `orbit:…`.
    #[arg(long, default_value = "grab:")]
    pub(crate) trace: String,

    /// How objects move between the clients: `predictive` (pre-selection on OVER and Table 6.1
    /// with object versions) or `naive` (only the selected object moves, on select and release).
    #[arg(long, value_enum, default_value_t = MigrationArg::Predictive)]
    pub(crate) migration: MigrationArg,

    /// How the FC combines its objects with the SC buffer: `deep` (merge fragment lists; exact)
    /// or `digital` (the seed's colour + front depth, which loses FC objects behind transparent
    /// SC objects and cannot remove stale SC copies).
    #[arg(long, value_enum, default_value_t = ModeArg::Deep)]
    pub(crate) mode: ModeArg,

    /// The simulated clock: `virtual:sc_ms=N,fc_ms=N[,transfer_ms=N]`.
    #[arg(long, default_value = "virtual:sc_ms=300,fc_ms=33")]
    pub(crate) clock: String,

    /// FC frames to run (default: until the trace is over and the SC has caught up).
    #[arg(long)]
    pub(crate) frames: Option<u64>,

    /// Frame size WxH (default: the scene's).
    #[arg(long, value_parser = crate::options::parse_size)]
    pub(crate) size: Option<(u32, u32)>,

    /// Folder for summary.json, frames.jsonl and (with --save-frames, --save-deep) the frames as
    /// PNG and deep EXR.
    #[arg(long)]
    pub(crate) out_dir: Option<PathBuf>,

    /// Write every composed FC frame as frame-NNNN.png into --out-dir.
    #[arg(long, requires = "out_dir")]
    pub(crate) save_frames: bool,

    /// Write every composed FC frame's fragments as an OpenEXR deep image, frame-NNNN.exr, into
    /// --out-dir (see `strata render --deep`).
    #[arg(long, requires = "out_dir")]
    pub(crate) save_deep: bool,

    /// Real clock only: do not keep the frames to audit them after the run (for long or large
    /// benchmark runs; the summary then has no artefact figures).
    #[arg(long)]
    pub(crate) no_audit: bool,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

/// Composed frames a real-time run keeps to audit afterwards, at most (bytes).
const AUDIT_BUDGET: u64 = 1 << 30;

/// `--mode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum ModeArg {
    /// Merge fragment lists (exact).
    Deep,
    /// Colour + front depth (the seed's digital composition).
    Digital,
}

/// `--migration`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum MigrationArg {
    /// Pre-selection and Table 6.1 with versions.
    Predictive,
    /// The seed's naive hand-over.
    Naive,
}

/// `--clock`.
#[derive(Clone, Copy, Debug)]
enum Clock {
    /// Simulated time.
    Virtual(VirtualClock),
    /// Real time: the FC at `fc_hz`, the SC on its own thread as fast as it can.
    Real { fc_hz: f64 },
}

/// `virtual:sc_ms=N,fc_ms=N[,transfer_ms=N]` or `real[:fc_hz=N]`.
fn parse_clock(s: &str) -> Result<Clock> {
    if s == "real" || s.starts_with("real:") {
        let mut fc_hz = 30.0;
        for item in s
            .trim_start_matches("real")
            .trim_start_matches(':')
            .split(',')
        {
            if item.trim().is_empty() {
                continue;
            }
            match item.split_once('=') {
                Some(("fc_hz", v)) => {
                    fc_hz = v
                        .trim()
                        .parse()
                        .ok()
                        .filter(|v: &f64| v.is_finite() && *v > 0.0 && *v <= 1000.0)
                        .with_context(|| {
                            format!("--clock: {item}: expected a rate in (0, 1000] Hz")
                        })?;
                }
                _ => bail!("--clock real: '{item}': expected fc_hz=N"),
            }
        }
        return Ok(Clock::Real { fc_hz });
    }
    let Some(params) = s.strip_prefix("virtual:") else {
        bail!("--clock {s}: expected virtual:sc_ms=N,fc_ms=N[,transfer_ms=N] or real[:fc_hz=N]");
    };
    let mut clock = VirtualClock {
        sc_ms: 300.0,
        fc_ms: 33.0,
        transfer_ms: 0.0,
    };
    for item in params.split(',').filter(|i| !i.trim().is_empty()) {
        let (key, value) = item
            .split_once('=')
            .with_context(|| format!("--clock: '{item}': expected key=value"))?;
        let v: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && *v >= 0.0 && *v <= 3.6e6)
            .with_context(|| format!("--clock: {item}: expected milliseconds, 0 to 3600000"))?;
        match key.trim() {
            "sc_ms" => clock.sc_ms = v,
            "fc_ms" => clock.fc_ms = v,
            "transfer_ms" => clock.transfer_ms = v,
            other => bail!("--clock: unknown '{other}' (sc_ms, fc_ms, transfer_ms)"),
        }
    }
    if clock.sc_ms <= 0.0 || clock.fc_ms <= 0.0 {
        bail!("--clock: sc_ms and fc_ms must be more than 0");
    }
    Ok(Clock::Virtual(clock))
}

/// The trace `spec` names for `scene`.
fn make_trace(spec: &str, scene: &strata_scene::Scene) -> Result<Trace> {
    if let Some(params) = spec.strip_prefix("grab:") {
        return Ok(grab(scene, &GrabParams::parse(params)?)?);
    }
    if let Some(params) = spec.strip_prefix("orbit:") {
        let (mut period, mut duration) = (4000.0, 4000.0);
        for item in params.split(',').filter(|i| !i.trim().is_empty()) {
            let (key, value) = item
                .split_once('=')
                .with_context(|| format!("--trace orbit: '{item}': expected key=value"))?;
            let v: f64 = value
                .trim()
                .parse()
                .with_context(|| format!("--trace orbit: {item}: expected milliseconds"))?;
            match key.trim() {
                "period_ms" => period = v,
                "duration_ms" => duration = v,
                other => bail!("--trace orbit: unknown '{other}' (period_ms, duration_ms)"),
            }
        }
        return Ok(orbit(scene, period, duration, 33.0)?);
    }
    Ok(Trace::read(std::path::Path::new(spec))?)
}

/// Totals over a run.
#[derive(Default)]
struct Totals {
    frames: u64,
    sc_frames_used: std::collections::BTreeSet<u64>,
    frames_with_bad_pixels: u64,
    max_bad_pixels: u64,
    ghost_pixel_frames: u64,
    hole_pixel_frames: u64,
    blend_pixel_frames: u64,
    sc_age_ms: Vec<f64>,
}

/// Runs `strata mfr`.
pub(crate) fn run(args: Args) -> Result<()> {
    let clock = parse_clock(&args.clock)?;
    if let Some(dir) = &args.out_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let scene = open_scene(&args.scene, &search_path(&args.model_dirs))?;
    let trace = make_trace(&args.trace, &scene)?;
    let migration = match args.migration {
        MigrationArg::Predictive => Migration::Predictive,
        MigrationArg::Naive => Migration::Naive,
    };
    let size = args.size.unwrap_or((scene.width, scene.height));
    let frames = args.frames.unwrap_or_else(|| match clock {
        Clock::Virtual(c) => {
            ((trace.duration_ms() + 3.0 * c.sc_ms + c.transfer_ms) / c.fc_ms).ceil() as u64 + 1
        }
        // The trace, then a second for the SC to catch up.
        Clock::Real { fc_hz } => ((trace.duration_ms() + 1000.0) * fc_hz / 1000.0).ceil() as u64,
    });
    if frames == 0 || frames > 1_000_000 {
        match args.frames {
            Some(_) => bail!("--frames must be 1 to 1000000"),
            None => bail!(
                "the trace lasts {} ms: {frames} FC frames, more than 1000000; give --frames",
                trace.duration_ms()
            ),
        }
    }
    let mut log = match &args.out_dir {
        Some(dir) => {
            let path = dir.join("frames.jsonl");
            Some((
                std::io::BufWriter::new(
                    std::fs::File::create(&path)
                        .with_context(|| format!("cannot write {}", path.display()))?,
                ),
                path,
            ))
        }
        None => None,
    };
    let bar = ProgressBar::new(frames).with_style(
        ProgressStyle::with_template(
            "{spinner} {pos}/{len} FC frames [{elapsed_precise}] {wide_msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut reference = Client::new(size.0, size.1);
    let mut totals = Totals::default();
    let mut failure: Option<anyhow::Error> = None;
    let composition = match args.mode {
        ModeArg::Deep => Composition::Deep,
        ModeArg::Digital => Composition::Digital,
    };
    let mut handle = |f: &FcFrame| {
        if failure.is_some() {
            return;
        }
        let result = audit_frame(&scene, &mut reference, f).and_then(|a| {
            record(&mut totals, f, &a);
            if let Some((w, path)) = &mut log {
                writeln!(w, "{}", frame_json(&scene, f, &a))
                    .with_context(|| format!("cannot write {}", path.display()))?;
            }
            if args.save_frames
                && let Some(dir) = &args.out_dir
            {
                let path = dir.join(format!("frame-{:04}.png", f.index));
                f.image.write_png(&path)?;
            }
            if args.save_deep
                && let Some(dir) = &args.out_dir
            {
                let path = dir.join(format!("frame-{:04}.exr", f.index));
                let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view);
                let bytes = crate::images::deep_exr_bytes(
                    &f.composed()?,
                    (scene.camera.near, scene.camera.far),
                    view.matrix(),
                    scene.camera.projection(size.0, size.1),
                )?;
                std::fs::write(&path, bytes)
                    .with_context(|| format!("cannot write {}", path.display()))?;
            }
            bar.set_message(format!("bad pixels {}", a.bad_pixels));
            bar.inc(1);
            Ok(())
        });
        if let Err(e) = result {
            failure = Some(e);
        }
    };
    let real = match clock {
        Clock::Virtual(c) => {
            run_virtual(
                &scene,
                trace,
                c,
                migration,
                composition,
                size,
                frames,
                |f| handle(f),
            )?;
            None
        }
        Clock::Real { fc_hz } => {
            // Audited after the run, so auditing does not take the FC thread's time; frames past
            // the memory budget are not kept.
            let mut shown = Vec::new();
            let mut kept = 0u64;
            let scene = std::sync::Arc::new(scene.clone());
            let stats = run_real(
                scene,
                trace,
                fc_hz,
                migration,
                composition,
                size,
                frames,
                |f| {
                    let bytes = f.fc.memory_bytes() + f.image.as_bytes().len() as u64;
                    if !args.no_audit && kept + bytes <= AUDIT_BUDGET {
                        kept += bytes;
                        shown.push(f.clone());
                    }
                },
            )?;
            for f in &shown {
                handle(f);
            }
            Some(stats)
        }
    };
    bar.finish_and_clear();
    if let Some(e) = failure {
        return Err(e);
    }
    if let Some((mut w, path)) = log {
        w.flush()
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if args.no_audit && matches!(clock, Clock::Virtual(_)) {
        eprintln!("note: --no-audit applies to real-clock runs; this run was audited");
    }
    let summary = summary_json(&args, &scene, clock, size, &mut totals, real);
    outln!("{}", summary_text(&summary))?;
    if let Some(dir) = &args.out_dir {
        let path = dir.join("summary.json");
        std::fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {} and frames.jsonl", path.display());
    }
    Ok(())
}

/// The frame against the whole scene rendered at once.
fn audit_frame(
    scene: &strata_scene::Scene,
    reference: &mut Client,
    f: &FcFrame,
) -> Result<FrameAudit> {
    let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let r = reference.render(scene, &f.snapshot, &view, &all)?;
    Ok(audit(&f.composed()?, &r, scene.background))
}

fn record(t: &mut Totals, f: &FcFrame, a: &FrameAudit) {
    t.frames += 1;
    if let Some(sc) = &f.sc {
        t.sc_frames_used.insert(sc.sc_frame);
        t.sc_age_ms.push(f.t_ms - sc.snapshot_t_ms);
    }
    t.frames_with_bad_pixels += u64::from(a.bad_pixels > 0);
    t.max_bad_pixels = t.max_bad_pixels.max(a.bad_pixels);
    t.ghost_pixel_frames += u64::from(a.ghost_pixels > 0);
    t.hole_pixel_frames += u64::from(a.hole_pixels > 0);
    t.blend_pixel_frames += u64::from(a.blend_pixels > 0);
}

fn frame_json(scene: &strata_scene::Scene, f: &FcFrame, a: &FrameAudit) -> serde_json::Value {
    let objects: Vec<serde_json::Value> = f
        .fc_objects
        .iter()
        .map(|&i| {
            let pose = &f.snapshot.objects[i];
            let contained =
                f.sc.as_ref()
                    .is_some_and(|sc| sc.contains(pose.id, pose.version));
            json!({
                "object": scene.objects[i].name,
                "state": pose.state,
                "table_6_1_row": table_6_1_row(pose.state, contained),
            })
        })
        .collect();
    json!({
        "fc_frame": f.index,
        "t_ms": f.t_ms,
        "snapshot": f.snapshot.id,
        "sc_frame": f.sc.as_ref().map(|s| s.sc_frame),
        "sc_age_ms": f.sc.as_ref().map(|s| f.t_ms - s.snapshot_t_ms),
        "fc_objects": objects,
        "fc_fragments": f.fc.fragment_count(),
        "audit": a,
    })
}

fn median_p95(v: &mut [f64]) -> serde_json::Value {
    if v.is_empty() {
        return serde_json::Value::Null;
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    json!({"median": at(0.5), "p95": at(0.95)})
}

fn summary_json(
    args: &Args,
    scene: &strata_scene::Scene,
    clock: Clock,
    size: (u32, u32),
    t: &mut Totals,
    real: Option<RealStats>,
) -> serde_json::Value {
    let clock_json = match clock {
        Clock::Virtual(c) => {
            json!({"kind": "virtual", "sc_ms": c.sc_ms, "fc_ms": c.fc_ms, "transfer_ms": c.transfer_ms})
        }
        Clock::Real { fc_hz } => json!({"kind": "real", "fc_hz": fc_hz}),
    };
    let mut v = json!({
        "scene": scene.name,
        "trace": args.trace,
        "migration": format!("{:?}", args.migration).to_lowercase(),
        "mode": format!("{:?}", args.mode).to_lowercase(),
        "clock": clock_json,
        "width": size.0,
        "height": size.1,
        "fc_frames": real.as_ref().map_or(t.frames, |r| r.fc_frame_ms.len() as u64),
        "audited_frames": t.frames,
        "sc_frames_used": t.sc_frames_used.len(),
        "sc_age_ms": median_p95(&mut t.sc_age_ms),
        "frames_with_bad_pixels": t.frames_with_bad_pixels,
        "max_bad_pixels": t.max_bad_pixels,
        "ghost_pixel_frames": t.ghost_pixel_frames,
        "hole_pixel_frames": t.hole_pixel_frames,
        "blend_pixel_frames": t.blend_pixel_frames,
    });
    if let Some(mut r) = real {
        let mut swap: Vec<f64> = r.publish_us.iter().chain(&r.read_us).copied().collect();
        let max = swap.iter().copied().fold(0.0, f64::max);
        v["cpu"] = json!(crate::report::cpu_model());
        v["fc_frame_ms"] = median_p95(&mut r.fc_frame_ms);
        v["sc_frame_ms"] = median_p95(&mut r.sc_frame_ms);
        v["sc_frames"] = json!(r.sc_frame_ms.len());
        v["swap_us"] = json!({"median": median_p95(&mut swap)["median"], "max": max});
        v["fc_deadlines_missed"] = json!(r.fc_deadlines_missed);
    }
    v
}

fn clock_text(s: &serde_json::Value) -> String {
    let c = &s["clock"];
    if c["kind"] == "real" {
        format!(
            "real, FC at {} Hz: FC frame {} ms median / {} p95, SC frame {} ms median ({} SC frames), \
             hand-over {} µs median / {} max, {} FC deadlines missed ({})",
            c["fc_hz"],
            fmt(&s["fc_frame_ms"]["median"]),
            fmt(&s["fc_frame_ms"]["p95"]),
            fmt(&s["sc_frame_ms"]["median"]),
            s["sc_frames"],
            fmt(&s["swap_us"]["median"]),
            fmt(&s["swap_us"]["max"]),
            s["fc_deadlines_missed"],
            s["cpu"].as_str().unwrap_or("?"),
        )
    } else {
        format!(
            "virtual, SC {} ms / FC {} ms / transfer {} ms",
            c["sc_ms"], c["fc_ms"], c["transfer_ms"]
        )
    }
}

fn fmt(v: &serde_json::Value) -> String {
    v.as_f64()
        .map_or_else(|| "-".to_owned(), |x| format!("{x:.2}"))
}

fn summary_text(s: &serde_json::Value) -> String {
    let head = format!(
        "strata mfr: {} ({}x{}), {} migration, {} composition, clock {}",
        s["scene"].as_str().unwrap_or("?"),
        s["width"],
        s["height"],
        s["migration"].as_str().unwrap_or("?"),
        s["mode"].as_str().unwrap_or("?"),
        clock_text(s),
    );
    if s["audited_frames"] == 0 {
        return format!(
            "{head}\n  {} FC frames, not audited (--no-audit)",
            s["fc_frames"]
        );
    }
    format!(
        "{head}\n  {} FC frames with {} SC buffers; age of the state in the SC buffer, median {} ms\n  \
         audited {} of them against the single renderer: {} frame(s) with bad pixels (> 2/255, at \
         most {} in a frame); frames with ghost / hole / blend pixels: {} / {} / {}",
        s["fc_frames"],
        s["sc_frames_used"],
        fmt(&s["sc_age_ms"]["median"]),
        s["audited_frames"],
        s["frames_with_bad_pixels"],
        s["max_bad_pixels"],
        s["ghost_pixel_frames"],
        s["hole_pixel_frames"],
        s["blend_pixel_frames"],
    )
}
