//! `strata mfr`: slow and fast clients on a virtual or real clock, every frame audited.
//!
//! - `mod.rs`: the arguments and the run (clients, audit, frames written);
//! - `clock.rs`: `--clock` and `--trace` parsed;
//! - `deferred.rs`: `--deferred` (the SC's deep G-buffer lit by the FC);
//! - `interleaved.rs`: `--interleaved` (both clients on one thread) and its summary;
//! - `summary.rs`: totals, the per-frame JSON line, `summary.json` and the text summary;
//! - `view.rs`: navigation figures — against the current view, warping's holes, view latency.
//! - `volume.rs`: `--volume`, volume ray casting with the FC's stencil re-cast.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use strata_mfr::FrameRecord;
use strata_mfr::client::Client;
use strata_mfr::simulate::{FcFrame, Migration, VirtualClock, run_virtual};
use strata_mfr::tcp::TcpOptions;
use strata_mfr::{Composition, FrameAudit, RealConfig, ScLoad, Transport, run_real};

use crate::cmd::mfr_slow::PriorityArg;
use crate::options::{open_scene, search_path};

mod clock;
mod contact_sheet;
mod deferred;
mod interleaved;
mod summary;
mod view;
mod volume;

use clock::{make_trace, parse_clock};
use summary::{Totals, frame_json, incidents_text, summary_json, summary_text};

/// Multi-frame-rate rendering: a slow and a fast client composited, every frame audited.
///
/// The slow client (SC) renders the scene's objects that nobody is manipulating, at the newest
/// state whenever it is free; the fast client (FC) renders the objects the user points at, holds
/// or just released, every frame, and composes them with the newest SC buffer by merging
/// fragment lists (deep composition), so transparent objects composite correctly across the two;
/// `--mode digital` and `--mode optical` compose as the original multi-frame-rate systems did, to
/// show their artefacts.
/// Time is simulated (`--clock virtual:sc_ms=…,fc_ms=…,transfer_ms=…`): rendering is real and
/// results are reproducible at any SC:FC ratio. Each FC frame is compared with the whole scene
/// rendered at once: bad pixels (> 2/255), and ghost, hole and blend pixels (an object shown where
/// it is not, missing where it is, or blended wrongly). The trace is a file (`.toml` or `.jsonl`,
/// see docs/mfr.md) or a generator: `grab:object=NAME,start_ms=…,over_lead_ms=…,hold_ms=…,
/// distance=…,linger_ms=…`, `orbit:period_ms=…,duration_ms=…` or `lights:count=…,period_ms=…,
/// duration_ms=…,step_ms=…` (point lights circling the scene, for --deferred). Exit status 0 when the run
/// completed (artefacts are reported, not failures), 2 on bad input.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name.
    pub(crate) scene: String,

    /// Interaction trace: a file (.toml, .jsonl) or `grab:…` / `orbit:…` / `lights:…`.
    #[arg(long, default_value = "grab:")]
    pub(crate) trace: String,

    /// How objects move between the clients: `predictive` (pre-selection on OVER and Table 6.1
    /// with object versions) or `naive` (only the selected object moves, on select and release).
    #[arg(long, value_enum, default_value_t = MigrationArg::Predictive)]
    pub(crate) migration: MigrationArg,

    /// How the FC combines its objects with the SC buffer: `deep` (merge fragment lists; exact),
    /// `digital` (colour + front depth: loses FC objects behind transparent SC objects and cannot
    /// remove stale SC copies) or `optical` (the FC's image over the SC's, as two overlapped
    /// projectors show them: no depth between the two, so FC objects are always drawn over SC
    /// objects, even those in front of them, and stale SC copies stay; exact only where the FC's
    /// objects lie in front of everything else).
    #[arg(long, value_enum, default_value_t = ModeArg::Deep)]
    pub(crate) mode: ModeArg,

    /// The clock: `virtual:sc_ms=N,fc_ms=N[,transfer_ms=N]` (simulated time) or
    /// `real[:fc_hz=N]` (the clients on their own threads, the FC at N Hz, default 30).
    #[arg(long, default_value = "virtual:sc_ms=300,fc_ms=33")]
    pub(crate) clock: String,

    /// Real clock only: where the slow client runs — `thread` (in this process) or
    /// `tcp:HOST:PORT` (a `strata mfr-slow SCENE --listen HOST:PORT` with the same scene, here
    /// or on another machine). A link that fails during the run is reported as an incident and
    /// the FC goes on with the last SC buffer it received.
    #[arg(long, default_value = "thread")]
    pub(crate) transport: String,

    /// Real clock only: what the slow client does — `busy` (renders every new state), `idle`
    /// (renders the first state once, then nothing) or `off` (no slow client: the FC draws every
    /// object every frame, as a conventional single renderer).
    #[arg(long, value_enum, default_value_t = ScLoadArg::Busy)]
    pub(crate) sc_load: ScLoadArg,

    /// Real clock only: priority of the slow client's threads, or with `--transport tcp` of the
    /// threads receiving and decoding its buffers (`low`: nice 19 on Linux, so the FC is
    /// scheduled first; give `strata mfr-slow` its own `--priority`).
    #[arg(long, value_enum, default_value_t = PriorityArg::Normal)]
    pub(crate) sc_priority: PriorityArg,

    /// Real clock only: both clients on one thread — each FC frame first, then the slow
    /// client's frame in chunks of geometry and its export in bands of rows, in the time left
    /// before the FC's next deadline, swapped in when complete. `adaptive` (the default) sizes
    /// each chunk and band from a cost model fitted as the run goes (per triangle or row, and
    /// per fragment of the previous slow-client frame); `fixed:N` captures N triangles a chunk
    /// and exports in one step.
    #[arg(long, value_name = "CHUNKING", num_args = 0..=1, default_missing_value = "adaptive")]
    pub(crate) interleaved: Option<String>,

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

    /// Write a contact sheet per select and release into --out-dir (event-NN-select.png …): the
    /// frames around the event with the SC's part greyed, and under each its error map.
    #[arg(long, requires = "out_dir")]
    pub(crate) contact_sheets: bool,

    /// Real clock only: do not keep the frames to audit them after the run (for long or large
    /// benchmark runs; the summary then has no artefact figures).
    #[arg(long)]
    pub(crate) no_audit: bool,

    /// Deferred shading (virtual clock): the slow client renders a deep G-buffer (every
    /// fragment's depth, normal and object), the fast client lights every fragment each frame
    /// with the current point lights — the trace's `light` events; when it has none, a ring of
    /// --lights lights circling the scene (the `lights:` trace) is added to it — so moving lights
    /// show at the fast client's rate. Prints the light-to-screen lag, the bad pixels against the
    /// whole scene lit by the frame's lights, both clients' times and the G-buffer's size.
    #[arg(long)]
    pub(crate) deferred: bool,

    /// With --deferred: how many point lights circle the scene when the trace has none (1 to 64).
    #[arg(long, default_value_t = 4, requires = "deferred")]
    pub(crate) lights: u32,

    /// With --deferred: who lights the slow client's objects — `fc` (deferred: the fast client,
    /// with the lights of its own frame) or `sc` (forward, for comparison: the slow client, with
    /// the lights of the state it renders, so lights on its objects move at its rate).
    #[arg(long, value_enum, default_value_t = deferred::ShadeOnArg::Fc, requires = "deferred")]
    pub(crate) shade_on: deferred::ShadeOnArg,

    /// Virtual clock only: warp the SC buffer to the current view every FC frame (its fragments
    /// moved by their depths; holes where the SC saw nothing filled from their neighbours), so
    /// camera moves reach the screen at the FC's rate instead of the SC's. Warped fragments keep
    /// the SC's shading. summary.json's `view` section gives the holes, the bad pixels against the
    /// exact render at the current view and the view-to-screen latency.
    #[arg(long, conflicts_with = "deferred")]
    pub(crate) warp: bool,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,

    /// Volume ray casting instead (scenes with a `[volume]` table: `volume-head`, `volume-ch2`):
    /// the SC casts the whole image once through its static objects (floor, glass), the FC moves
    /// the well path (and any moving glass) each of --frames frames (default 8), re-casts only the
    /// rays whose fragments it changes and is compared bit for bit with the single renderer. Prints the full cast and re-cast times; --trace, --clock and --mode do not
    /// apply (giving one is an error).
    #[arg(long, conflicts_with_all = ["trace", "clock", "mode", "migration", "deferred", "warp"])]
    pub(crate) volume: bool,

    /// With --volume: samples along the volume box's diagonal (default: the scene's `samples`).
    #[arg(long, requires = "volume", value_parser = clap::value_parser!(u32).range(1..=65536))]
    pub(crate) volume_samples: Option<u32>,
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
    /// The FC's image over the SC's, no depth test (optical superposition, as two projectors).
    Optical,
}

/// `--migration`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum MigrationArg {
    /// Pre-selection and Table 6.1 with versions.
    Predictive,
    /// The seed's naive hand-over.
    Naive,
}

/// `--sc-load`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum ScLoadArg {
    /// The SC renders every new state.
    Busy,
    /// The SC renders the first state only.
    Idle,
    /// No SC.
    Off,
}

/// `--transport`.
fn parse_transport(s: &str) -> Result<Transport> {
    if s == "thread" {
        return Ok(Transport::Thread);
    }
    match s.strip_prefix("tcp:") {
        Some(addr) if !addr.trim().is_empty() => Ok(Transport::Tcp(TcpOptions::new(addr.trim()))),
        _ => bail!("--transport {s}: expected thread or tcp:HOST:PORT"),
    }
}

/// `--clock`.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Clock {
    /// Simulated time.
    Virtual(VirtualClock),
    /// Real time: the FC at `fc_hz`, the SC on its own thread as fast as it can.
    Real { fc_hz: f64 },
}

/// Runs `strata mfr`.
pub(crate) fn run(args: Args) -> Result<()> {
    if args.volume {
        return volume::run(&args);
    }
    let clock = parse_clock(&args.clock)?;
    let transport = parse_transport(&args.transport)?;
    if matches!(clock, Clock::Virtual(_))
        && (transport != Transport::Thread
            || args.sc_load != ScLoadArg::Busy
            || args.sc_priority != PriorityArg::Normal)
    {
        bail!("--transport, --sc-load and --sc-priority need the real clock (--clock real)");
    }
    if args.warp && !matches!(clock, Clock::Virtual(_)) {
        bail!("--warp needs the virtual clock (--clock virtual:…)");
    }
    let chunking = match &args.interleaved {
        Some(_) if matches!(clock, Clock::Virtual(_)) => {
            bail!("--interleaved needs the real clock (--clock real)")
        }
        Some(value) => Some(interleaved::parse_interleaved(
            value,
            transport == Transport::Thread
                && args.sc_load == ScLoadArg::Busy
                && args.sc_priority == PriorityArg::Normal,
        )?),
        None => None,
    };
    let mut interleaved_summary = None;
    if let Some(dir) = &args.out_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let scene = open_scene(&args.scene, &search_path(&args.model_dirs))?;
    if scene.objects.is_empty() && scene.volume.is_some() {
        bail!(
            "{} is a volume scene with no objects: add --volume",
            args.scene
        );
    }
    let mut trace = make_trace(&args.trace, &scene)?;
    if args.deferred {
        trace = deferred::with_lights(trace, &scene, args.lights)?;
    }
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
    if args.deferred {
        return deferred::run(&args, &scene, trace, clock, migration, size, frames);
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
    let mut views = view::ViewTotals::default();
    let mut view_reference = Client::new(size.0, size.1);
    let mut failure: Option<anyhow::Error> = None;
    let composition = match args.mode {
        ModeArg::Deep => Composition::Deep,
        ModeArg::Digital => Composition::Digital,
        ModeArg::Optical => Composition::Optical,
    };
    // Contact sheets show each event until two SC buffers have followed it.
    let (period_ms, settle_ms) = match clock {
        Clock::Virtual(c) => (c.fc_ms, 2.0 * (c.sc_ms + c.transfer_ms) + c.fc_ms),
        Clock::Real { fc_hz } => (1000.0 / fc_hz, 500.0),
    };
    let mut sheets = args
        .contact_sheets
        .then(|| contact_sheet::ContactSheets::new(&trace, period_ms, settle_ms));
    let mut handle = |f: &FcFrame, shown_ms: f64| {
        if failure.is_some() {
            return;
        }
        let result = audit_frame(&scene, &mut reference, f).and_then(|(a, reference)| {
            views.add(&scene, &mut view_reference, f, &a, shown_ms)?;
            let r = FrameRecord::of(f, shown_ms, Some(a));
            if let Some(sheets) = &mut sheets {
                sheets.offer(f, &reference, &a);
            }
            if let Some((w, path)) = &mut log {
                writeln!(w, "{}", frame_json(&scene, f, &r))
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
            totals.add(r, f.sc.as_ref().map(|sc| sc.sc_frame));
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
            let on_frame = |f: &FcFrame| handle(f, f.t_ms + c.fc_ms);
            if args.warp {
                strata_mfr::warp::run_virtual_warped(
                    &scene,
                    trace.clone(),
                    c,
                    migration,
                    composition,
                    size,
                    frames,
                    on_frame,
                )?;
            } else {
                run_virtual(
                    &scene,
                    trace.clone(),
                    c,
                    migration,
                    composition,
                    size,
                    frames,
                    on_frame,
                )?;
            }
            None
        }
        Clock::Real { fc_hz } => {
            // Audited after the run, so auditing does not take the FC thread's time; frames past
            // the memory budget are not kept.
            let mut shown = Vec::new();
            let mut unaudited = Vec::new();
            let mut kept = 0u64;
            let scene = std::sync::Arc::new(scene.clone());
            let config = RealConfig {
                fc_hz,
                migration,
                composition,
                transport,
                sc_load: match args.sc_load {
                    ScLoadArg::Busy => ScLoad::Busy,
                    ScLoadArg::Idle => ScLoad::Idle,
                    ScLoadArg::Off => ScLoad::Off,
                },
                sc_priority: args.sc_priority.into(),
                ..RealConfig::new(size, frames)
            };
            let keep = |f: &FcFrame| {
                let bytes = f.fc.memory_bytes() + f.image.as_bytes().len() as u64;
                if !args.no_audit && kept + bytes <= AUDIT_BUDGET {
                    kept += bytes;
                    shown.push(f.clone());
                } else {
                    unaudited.push((
                        FrameRecord::of(f, f.t_ms, None),
                        f.sc.as_ref().map(|sc| sc.sc_frame),
                    ));
                }
            };
            let stats = match chunking {
                Some(chunking) => {
                    let s = strata_mfr::run_interleaved(
                        &scene,
                        trace.clone(),
                        &config,
                        chunking,
                        keep,
                    )?;
                    interleaved_summary = Some(interleaved::interleaved_json(chunking, &s));
                    interleaved::real_stats(&s)
                }
                None => run_real(scene, trace.clone(), &config, keep)?,
            };
            // A frame is on screen when its work is done.
            let shown_at = |index: u64, t_ms: f64| {
                t_ms + stats
                    .fc_frame_ms
                    .get(index as usize)
                    .copied()
                    .unwrap_or(0.0)
            };
            for f in &shown {
                handle(f, shown_at(f.index, f.t_ms));
            }
            for (mut r, sc_frame) in unaudited {
                r.shown_ms = shown_at(r.index, r.t_ms);
                totals.add(r, sc_frame);
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
    if let (Some(sheets), Some(dir)) = (&sheets, &args.out_dir) {
        let written = sheets.write(dir)?;
        eprintln!(
            "wrote {} contact sheet(s) into {}",
            written.len(),
            dir.display()
        );
    }
    let mut summary = summary_json(&args, &scene, &trace, clock, size, &mut totals, real);
    // A trace that only places the camera where the scene has it (as `grab:` does) does not
    // navigate; one that moves it does.
    let cam = &scene.camera;
    let navigates = trace.events().iter().any(|e| {
        matches!(e.event, strata_mfr::Event::View { eye, target, up }
            if (eye, target, up) != (cam.eye, cam.target, cam.up))
    });
    if args.warp || navigates {
        summary["view"] = views.json(&trace, args.warp);
    }
    let mut text = summary_text(&summary);
    if let Some(v) = interleaved_summary {
        text.push_str(&interleaved::interleaved_text(&v));
        summary["interleaved"] = v;
    }
    outln!("{}{}", text, incidents_text(&summary))?;
    if let Some(v) = summary.get("view") {
        outln!("{}", view::view_text(v))?;
    }
    if let Some(dir) = &args.out_dir {
        let path = dir.join("summary.json");
        std::fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {} and frames.jsonl", path.display());
    }
    Ok(())
}

/// The frame against the whole scene rendered at once: the audit and the reference image.
fn audit_frame(
    scene: &strata_scene::Scene,
    reference: &mut Client,
    f: &FcFrame,
) -> Result<(FrameAudit, strata_core::Rgb8Image)> {
    Ok(strata_mfr::audit::audit_fc_frame(scene, reference, f)?)
}
