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
    #[arg(long, value_parser = parse_size)]
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

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

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

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("'{s}': expected WIDTHxHEIGHT such as 640x360, each 1 to 16384");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

/// `virtual:sc_ms=N,fc_ms=N[,transfer_ms=N]`.
fn parse_clock(s: &str) -> Result<VirtualClock> {
    let Some(params) = s.strip_prefix("virtual:") else {
        bail!(
            "--clock {s}: expected virtual:sc_ms=N,fc_ms=N[,transfer_ms=N] (real time is not \
             built yet)"
        );
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
    Ok(clock)
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
    let frames = args.frames.unwrap_or_else(|| {
        ((trace.duration_ms() + 3.0 * clock.sc_ms + clock.transfer_ms) / clock.fc_ms).ceil() as u64
            + 1
    });
    if frames == 0 || frames > 1_000_000 {
        bail!("--frames must be 1 to 1000000");
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
    run_virtual(
        &scene,
        trace,
        clock,
        migration,
        composition,
        size,
        frames,
        |f| {
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
                    f.frame.resolve(scene.background).write_png(&path)?;
                }
                if args.save_deep
                    && let Some(dir) = &args.out_dir
                {
                    let path = dir.join(format!("frame-{:04}.exr", f.index));
                    let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view_pose);
                    let bytes = crate::images::deep_exr_bytes(
                        &f.frame,
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
        },
    )?;
    bar.finish_and_clear();
    if let Some(e) = failure {
        return Err(e);
    }
    if let Some((mut w, path)) = log {
        w.flush()
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    let summary = summary_json(&args, &scene, clock, size, &mut totals);
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
    let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view_pose);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let r = reference.render(scene, &f.snapshot, &view, &all)?;
    Ok(audit(&f.frame, &r, scene.background))
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
        "fragments": f.frame.fragment_count(),
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
    clock: VirtualClock,
    size: (u32, u32),
    t: &mut Totals,
) -> serde_json::Value {
    json!({
        "scene": scene.name,
        "trace": args.trace,
        "migration": format!("{:?}", args.migration).to_lowercase(),
        "mode": format!("{:?}", args.mode).to_lowercase(),
        "clock": {"kind": "virtual", "sc_ms": clock.sc_ms, "fc_ms": clock.fc_ms, "transfer_ms": clock.transfer_ms},
        "width": size.0,
        "height": size.1,
        "fc_frames": t.frames,
        "sc_frames_used": t.sc_frames_used.len(),
        "sc_age_ms": median_p95(&mut t.sc_age_ms),
        "frames_with_bad_pixels": t.frames_with_bad_pixels,
        "max_bad_pixels": t.max_bad_pixels,
        "ghost_pixel_frames": t.ghost_pixel_frames,
        "hole_pixel_frames": t.hole_pixel_frames,
        "blend_pixel_frames": t.blend_pixel_frames,
    })
}

fn summary_text(s: &serde_json::Value) -> String {
    format!(
        "strata mfr: {} ({}x{}), {} migration, {} composition, virtual clock SC {} ms / FC {} ms / transfer {} ms\n  \
         {} FC frames with {} SC buffers; SC buffer age median {} ms\n  \
         against the single renderer: {} frame(s) with bad pixels (> 2/255, at most {} in a frame); \
         frames with ghost / hole / blend pixels: {} / {} / {}",
        s["scene"].as_str().unwrap_or("?"),
        s["width"],
        s["height"],
        s["migration"].as_str().unwrap_or("?"),
        s["mode"].as_str().unwrap_or("?"),
        s["clock"]["sc_ms"],
        s["clock"]["fc_ms"],
        s["clock"]["transfer_ms"],
        s["fc_frames"],
        s["sc_frames_used"],
        s["sc_age_ms"]["median"],
        s["frames_with_bad_pixels"],
        s["max_bad_pixels"],
        s["ghost_pixel_frames"],
        s["hole_pixel_frames"],
        s["blend_pixel_frames"],
    )
}
