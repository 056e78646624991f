//! `strata display`: the display node of Jähne 2014's remote rendering.

use std::fs;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use strata_core::{Rgb8Image, metrics};
use strata_raster::Rasterizer;
use strata_remote::display::{self, DisplayConfig, Observer, OnFault};
use strata_remote::reference::exact_image;
use strata_remote::report::{FrameStats, NodeIncident, Outcome, Summary};
use strata_remote::transfer;
use strata_wire::{Codec, DecodeOptions};

use crate::Failed;
use crate::options::{open_scene, search_path};

/// Exit status of a run in which no node delivered any frame.
const EXIT_NOTHING_DELIVERED: u8 = 1;
/// Exit status of a run in which some node missed frames.
const EXIT_DEGRADED: u8 = 3;

/// The arguments of `strata display` (its help text, with the exit statuses, is on the
/// subcommand in `main.rs`).
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name: the same scene the nodes serve.
    #[arg(long)]
    pub(crate) scene: String,

    /// Render node addresses, comma-separated (`host:port`, IPv6 as `[::1]:7400`).
    #[arg(long, value_delimiter = ',', required = true, value_parser = parse_node_address)]
    pub(crate) nodes: Vec<String>,

    /// How the nodes choose and encode fragments, and how the display waits for them.
    #[command(flatten)]
    pub(crate) link: LinkArgs,

    /// Frames to compose.
    #[arg(long, default_value_t = 72)]
    pub(crate) frames: u64,

    /// First animation frame.
    #[arg(long, default_value_t = 0)]
    pub(crate) first_frame: u64,

    /// Frame size WIDTHxHEIGHT (default: the scene's).
    #[arg(long, value_parser = crate::options::parse_size)]
    pub(crate) size: Option<(u32, u32)>,

    /// Compare every frame with the exact local render after the run (off: --no-check).
    #[arg(long = "no-check", action = clap::ArgAction::SetFalse)]
    pub(crate) check: bool,

    /// A pixel is bad if some channel differs from the exact render by more than this many 8-bit
    /// steps.
    #[arg(long, default_value_t = metrics::DEFAULT_BAD_PIXEL_THRESHOLD)]
    pub(crate) threshold: u8,

    /// Folder for summary.json, summary.txt and (with --save-frames, --save-deep) the frames as
    /// PNG and deep EXR.
    #[arg(long)]
    pub(crate) out_dir: Option<PathBuf>,

    /// Write every composed frame as frame-NNNN.png into --out-dir.
    #[arg(long, requires = "out_dir")]
    pub(crate) save_frames: bool,

    /// Write every composed frame's merged fragments as an OpenEXR deep image,
    /// frame-NNNN.exr, into --out-dir (see `strata render --deep`).
    #[arg(long, requires = "out_dir")]
    pub(crate) save_deep: bool,

    /// Measure the nodes alone: drop every frame as soon as it has arrived, without decoding,
    /// merging or resolving it (no check against the exact render, nothing to save).
    #[arg(long, conflicts_with_all = ["save_frames", "save_deep"])]
    pub(crate) discard: bool,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

/// The display's side of the link to its nodes: what it asks them to send and how it waits —
/// shared by `strata display` and `strata view --nodes`.
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub(crate) struct LinkArgs {
    /// Transfer method: full, depth-limited (with --layers), difference, reprojection.
    #[arg(long, default_value = "full")]
    pub(crate) transfer: String,

    /// depth-limited: fragments per pixel to send (the N nearest).
    #[arg(long)]
    pub(crate) layers: Option<u32>,

    /// depth-limited: stop a pixel once the opacity in front reaches this, in (0, 1].
    #[arg(long)]
    pub(crate) opacity_threshold: Option<f32>,

    /// difference: colour changes of at most this many 8-bit steps are not sent (default 0:
    /// exact; 2: no bad pixels at the default --threshold, with fewer fragments).
    /// reprojection: a reprojected fragment is kept while it shades within this many steps of
    /// the node's render (default 1: at most 2 steps off with the normal packing, so no bad
    /// pixels at the default --threshold; 0: equal colours).
    #[arg(long)]
    pub(crate) tolerance: Option<u8>,

    /// Codec the nodes encode with: raw, lz4, zstd or zstd:LEVEL, deep-lz4, deep-zstd or
    /// deep-zstd:LEVEL, deep-huff (the default: the deep layout in Huffman or LZ4 blocks; see
    /// `strata codecs`).
    #[arg(long, default_value = "deep-huff")]
    pub(crate) codec: Codec,

    /// Frames requested ahead of the one being composed, so nodes render while frames travel.
    #[arg(long, default_value_t = 2)]
    pub(crate) in_flight: usize,

    /// Seconds to wait for a node's frame (and for a connection) before reporting it.
    #[arg(long, default_value_t = 5.0)]
    pub(crate) timeout: f64,

    /// Without a node's frame: compose with its last frame (hold) or without it (drop).
    #[arg(long, default_value = "hold", value_parser = ["hold", "drop"])]
    pub(crate) on_fault: String,
}

/// [`LinkArgs`] checked.
#[derive(Clone, Debug)]
pub(crate) struct Link {
    pub(crate) transfer: transfer::Transfer,
    pub(crate) tolerance: u8,
    pub(crate) codec: Codec,
    pub(crate) in_flight: usize,
    pub(crate) timeout: Duration,
    pub(crate) on_fault: OnFault,
}

impl LinkArgs {
    /// Checks the options together (`--layers` only with depth-limited, …).
    pub(crate) fn check(&self) -> Result<Link> {
        let (t, tolerance) = choose_transfer(
            &self.transfer,
            self.layers,
            self.opacity_threshold,
            self.tolerance,
        )?;
        if !(self.timeout > 0.0 && self.timeout <= 3600.0) {
            bail!("--timeout must be within (0, 3600] seconds");
        }
        self.codec
            .validate()
            .map_err(|e| anyhow::anyhow!("--codec {}: {e}", self.codec))?;
        if self.in_flight == 0 {
            bail!("--in-flight must be at least 1");
        }
        Ok(Link {
            transfer: t,
            tolerance,
            codec: self.codec,
            in_flight: self.in_flight,
            timeout: Duration::from_secs_f64(self.timeout),
            on_fault: if self.on_fault == "drop" {
                OnFault::Drop
            } else {
                OnFault::Hold
            },
        })
    }

    /// True when every option is at its default (`strata view` without `--nodes` refuses
    /// the others).
    /// The defaults are read from the arguments' own declarations (an empty command line
    /// parsed), so they cannot drift apart.
    pub(crate) fn is_default(&self) -> bool {
        use clap::{Args as _, FromArgMatches as _};
        let command = LinkArgs::augment_args(clap::Command::new("defaults"));
        command
            .try_get_matches_from(["defaults"])
            .ok()
            .and_then(|m| LinkArgs::from_arg_matches(&m).ok())
            .is_some_and(|defaults| &defaults == self)
    }
}

/// The transfer method `name` with its options, and its tolerance (the default per transfer
/// when none is given): the rules of `--transfer`, `--layers`, `--opacity-threshold` and
/// `--tolerance`, for the command line and the viewer's page alike.
pub(crate) fn choose_transfer(
    name: &str,
    layers: Option<u32>,
    opacity_threshold: Option<f32>,
    tolerance: Option<u8>,
) -> Result<(transfer::Transfer, u8)> {
    let t = transfer::parse(name, layers, opacity_threshold)?;
    let tolerance = match (t, tolerance) {
        (transfer::Transfer::Difference, tol) => tol.unwrap_or(0),
        (transfer::Transfer::Reprojection, tol) => tol.unwrap_or(1),
        (_, None) => 0,
        (_, Some(_)) => {
            bail!("--tolerance applies to --transfer difference and reprojection only")
        }
    };
    Ok((t, tolerance))
}

impl Link {
    /// The transfer method and its options as the summary names them.
    pub(crate) fn label(&self) -> String {
        transfer_label(self.transfer, self.tolerance)
    }
}

pub(crate) fn parse_node_address(s: &str) -> Result<String, String> {
    display::check_address(s).map_err(|e| e.to_string())?;
    Ok(s.to_string())
}

/// Shows progress, keeps frames for the check, saves them when asked.
struct Progress {
    bar: ProgressBar,
    images: Vec<(u64, Rgb8Image)>,
    keep: bool,
    save: Option<PathBuf>,
    /// Where and through which camera to write deep frames (`--save-deep`).
    save_deep: Option<(PathBuf, strata_scene::Camera)>,
    error: Option<anyhow::Error>,
}

impl Progress {
    /// Writes one merged frame as `frame-NNNN.exr`.
    fn write_deep(&self, t: u64, deep: &strata_core::DeepFrame) -> Result<()> {
        let Some((dir, camera)) = &self.save_deep else {
            return Ok(());
        };
        let path = dir.join(format!("frame-{t:04}.exr"));
        let bytes = crate::images::deep_exr_bytes(
            deep,
            (camera.near, camera.far),
            camera.view(),
            camera.projection(deep.width(), deep.height()),
        )?;
        std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))
    }
}

impl Observer for Progress {
    fn frame(&mut self, stats: &FrameStats, image: &Rgb8Image) {
        let mb = stats.bytes() as f64 / 1e6;
        self.bar.set_message(format!(
            "frame {}: {mb:.2} MB, {} fragments sent",
            stats.frame,
            stats.fragments_sent()
        ));
        self.bar.inc(1);
        if let Some(dir) = &self.save
            && self.error.is_none()
        {
            let path = dir.join(format!("frame-{:04}.png", stats.frame));
            if let Err(e) = image.write_png(&path) {
                self.error = Some(anyhow::anyhow!("writing {}: {e}", path.display()));
            }
        }
        if self.keep {
            self.images.push((stats.frame, image.clone()));
        }
    }

    fn wants_deep_frames(&self) -> bool {
        self.save_deep.is_some() && self.error.is_none()
    }

    fn deep_frame(
        &mut self,
        t: u64,
        deep: Result<&strata_core::DeepFrame, &strata_core::DeepFrameError>,
    ) {
        let written = match deep {
            Ok(deep) => self.write_deep(t, deep),
            Err(e) => Err(anyhow::anyhow!(
                "frame {t}: cannot merge the nodes' fragments: {e}"
            )),
        };
        if let Err(e) = written {
            self.error = Some(e);
        }
    }

    fn incident(&mut self, i: &NodeIncident) {
        self.bar
            .println(format!("frame {}: node {}: {}", i.frame, i.node, i.what));
    }
}

pub(crate) fn run(args: Args) -> Result<()> {
    let link = args.link.check()?;
    let (t, tolerance) = (link.transfer, link.tolerance);
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    let scene = Arc::new(open_scene(&args.scene, &search_path(&args.model_dirs))?);
    let (width, height) = args.size.unwrap_or((scene.width, scene.height));
    if let Some(dir) = &args.out_dir {
        fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let config = DisplayConfig {
        scene: scene.clone(),
        nodes: args.nodes.clone(),
        transfer: t,
        codec: link.codec,
        tolerance,
        first_frame: args.first_frame,
        frames: args.frames,
        width,
        height,
        in_flight: link.in_flight,
        timeout: link.timeout,
        on_fault: link.on_fault,
        limits: DecodeOptions::default(),
    };
    let summary = |incidents, per_frame| {
        Summary::new(
            scene.name.clone(),
            width,
            height,
            link.label(),
            link.codec.to_string(),
            args.nodes.clone(),
            args.threshold,
            incidents,
            per_frame,
        )
    };
    if args.discard {
        let result = strata_remote::sink::discard(config)?;
        let mut summary = summary(result.incidents, result.per_frame);
        summary.discarded = true;
        return report(&summary, args.out_dir.as_deref());
    }
    let bar = ProgressBar::new(args.frames).with_style(
        ProgressStyle::with_template("{spinner} {pos}/{len} frames [{elapsed_precise}] {wide_msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut progress = Progress {
        bar,
        images: Vec::new(),
        keep: args.check,
        save: args.save_frames.then(|| args.out_dir.clone()).flatten(),
        save_deep: args
            .save_deep
            .then(|| args.out_dir.clone())
            .flatten()
            .map(|dir| (dir, scene.camera)),
        error: None,
    };
    let result = display::run(config, &mut progress)?;
    progress.bar.finish_and_clear();
    if let Some(e) = progress.error {
        return Err(e);
    }
    let mut per_frame = result.per_frame;
    // Comparing blank frames with the exact render says nothing when no node delivered.
    if args.check && per_frame.iter().any(FrameStats::delivered) {
        check_frames(
            &scene,
            &progress.images,
            &mut per_frame,
            (width, height),
            args.threshold,
        )?;
    }
    report(
        &summary(result.incidents, per_frame),
        args.out_dir.as_deref(),
    )
}

/// Prints the summary, writes it into `out_dir`, and turns its outcome into the exit status.
fn report(summary: &Summary, out_dir: Option<&std::path::Path>) -> Result<()> {
    let table = summary.to_table();
    out!("{table}")?;
    if let Some(dir) = out_dir {
        let json = dir.join("summary.json");
        fs::write(&json, summary.to_json())
            .with_context(|| format!("writing {}", json.display()))?;
        let txt = dir.join("summary.txt");
        fs::write(&txt, &table).with_context(|| format!("writing {}", txt.display()))?;
        eprintln!("wrote {} and {}", json.display(), txt.display());
    }
    exit_status(summary)
}

/// Counts each kept frame's bad pixels against the exact local render of the whole scene.
fn check_frames(
    scene: &strata_scene::Scene,
    images: &[(u64, Rgb8Image)],
    per_frame: &mut [FrameStats],
    (width, height): (u32, u32),
    threshold: u8,
) -> Result<()> {
    let bar = ProgressBar::new(images.len() as u64).with_style(
        ProgressStyle::with_template("checking against the exact render {pos}/{len}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut raster = Rasterizer::default();
    for ((f, image), stats) in images.iter().zip(per_frame.iter_mut()) {
        let exact = exact_image(scene, *f, width, height, &mut raster)?;
        stats.bad_pixels = Some(metrics::bad_pixels(image, &exact, threshold)?.count);
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(())
}

/// The transfer method and its options as the summary names them.
pub(crate) fn transfer_label(t: transfer::Transfer, tolerance: u8) -> String {
    match t {
        transfer::Transfer::DepthLimited {
            layers,
            opacity_threshold: Some(o),
        } => format!("depth-limited --layers {layers} --opacity-threshold {o}"),
        transfer::Transfer::DepthLimited { layers, .. } => {
            format!("depth-limited --layers {layers}")
        }
        transfer::Transfer::Difference if tolerance > 0 => {
            format!("difference --tolerance {tolerance}")
        }
        transfer::Transfer::Reprojection => format!("reprojection --tolerance {tolerance}"),
        other => transfer::name(other).to_string(),
    }
}

/// Success only when every node delivered every frame; otherwise an error with the run's exit
/// status that says which nodes failed and how.
fn exit_status(summary: &Summary) -> Result<()> {
    let why = |node: &str| {
        summary
            .incidents
            .iter()
            .find(|i| i.node == node)
            .map_or_else(
                || "sent no frame".to_string(),
                |i| format!("frame {}: {}", i.frame, i.what),
            )
    };
    match summary.outcome {
        Outcome::Complete => Ok(()),
        Outcome::NothingDelivered => {
            let nodes: Vec<String> = summary
                .nodes
                .iter()
                .map(|n| format!("{n}: {}", why(n)))
                .collect();
            Err(Failed {
                status: EXIT_NOTHING_DELIVERED,
                message: format!(
                    "no node delivered a frame, so nothing was displayed ({})",
                    nodes.join("; ")
                ),
            }
            .into())
        }
        Outcome::Degraded => {
            let nodes: Vec<String> = summary
                .shortfalls
                .iter()
                .map(|s| {
                    format!(
                        "{} delivered {} of {} frames ({})",
                        s.node,
                        s.delivered,
                        summary.frames,
                        why(&s.node)
                    )
                })
                .collect();
            Err(Failed {
                status: EXIT_DEGRADED,
                message: format!("the run was degraded: {}", nodes.join("; ")),
            }
            .into())
        }
    }
}
