//! `strata node`: a render node of Jähne 2014's remote rendering, or a node that replays a
//! recorded stream from memory.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use strata_remote::node::{NodeConfig, NodeEvent, serve};
use strata_remote::recording::{Recorder, Recording, serve_recording};
use strata_wire::DecodeOptions;

use crate::options::{RenderOptions, open_scene};

/// The arguments of `strata node` (its help text is on the subcommand in `main.rs`).
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Address to listen on, e.g. 0.0.0.0:7400 (port 0: any free port).
    #[arg(long, value_name = "ADDR")]
    pub(crate) listen: String,

    /// Scene file (TOML) or built-in scene name; the display must use the same scene.
    #[arg(long, required_unless_present = "replay")]
    pub(crate) scene: Option<String>,

    /// Objects to render, by name or index in the scene, comma-separated (default: all).
    #[arg(long, value_delimiter = ',', conflicts_with = "replay")]
    pub(crate) objects: Vec<String>,

    /// Record every request and its reply into FILE (replaced), for `--replay`.
    #[arg(long, value_name = "FILE", conflicts_with = "replay")]
    pub(crate) record: Option<PathBuf>,

    /// Serve the recording FILE from memory instead of rendering (takes no scene; the
    /// rendering options do not apply).
    #[arg(long, value_name = "FILE", conflicts_with = "scene")]
    pub(crate) replay: Option<PathBuf>,

    #[command(flatten)]
    pub(crate) render: RenderOptions,
}

pub(crate) fn run(args: Args) -> Result<()> {
    if let Some(path) = &args.replay {
        return replay(&args.listen, path);
    }
    if let Some(n) = args.render.threads {
        anyhow::ensure!(n >= 1, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("setting up the worker threads")?;
    }
    let scene_name = args
        .scene
        .as_deref()
        .context("--scene is required (or --replay FILE)")?;
    let scene = Arc::new(open_scene(scene_name, &args.render.search_path())?);
    let objects = NodeConfig::select_objects(&scene, &args.objects)?;
    let mut config = NodeConfig {
        scene: scene.clone(),
        objects,
        method: args.render.method.clone(),
        method_options: args.render.method_options(),
        limits: DecodeOptions::default(),
        record: None,
    };
    config.check()?;
    if let Some(path) = &args.record {
        config.record = Some(Arc::new(Recorder::create(path, &config.hello())?));
    }
    let names: Vec<&str> = scene
        .objects
        .iter()
        .filter(|o| config.objects.contains(&o.id))
        .map(|o| o.name.as_str())
        .collect();
    let runtime = runtime()?;
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(&args.listen)
            .await
            .with_context(|| format!("cannot listen on {}", args.listen))?;
        let addr = listener.local_addr()?;
        outln!("listening on {addr}")?;
        eprintln!(
            "strata node: scene {}, objects [{}], method {}",
            scene.name,
            names.join(", "),
            config.method
        );
        if let Some(r) = &config.record {
            eprintln!("strata node: recording to {}", r.path().display());
        }
        serve(listener, config, log).await.context("serving")
    })
}

/// Serves the recording at `path` from memory.
fn replay(listen: &str, path: &std::path::Path) -> Result<()> {
    let limits = DecodeOptions::default();
    let recording = Arc::new(Recording::load(path, &limits)?);
    let runtime = runtime()?;
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .with_context(|| format!("cannot listen on {listen}"))?;
        let addr = listener.local_addr()?;
        outln!("listening on {addr}")?;
        let hello = recording.hello();
        eprintln!(
            "strata node: replaying {} ({} request(s) of scene {}, objects [{}]) from memory",
            path.display(),
            recording.requests(),
            hello.scene,
            hello
                .objects
                .iter()
                .map(|(_, n)| n.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
        serve_recording(listener, recording, limits, log)
            .await
            .context("serving")
    })
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the I/O runtime")
}

fn log(e: NodeEvent) {
    match e {
        NodeEvent::Connected(peer) => eprintln!("strata node: display {peer} connected"),
        NodeEvent::Closed(peer, None) => eprintln!("strata node: display {peer} disconnected"),
        NodeEvent::Closed(peer, Some(why)) => {
            eprintln!("strata node: connection from {peer} ended: {why}")
        }
    }
}
