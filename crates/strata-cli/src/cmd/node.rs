//! `strata node`: a render node of Jähne 2014's remote rendering.

use std::sync::Arc;

use anyhow::{Context, Result};
use strata_remote::node::{NodeConfig, NodeEvent, serve};
use strata_wire::DecodeOptions;

use crate::options::{RenderOptions, open_scene};

/// The arguments of `strata node` (its help text is on the subcommand in `main.rs`).
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Address to listen on, e.g. 0.0.0.0:7400 (port 0: any free port).
    #[arg(long, value_name = "ADDR")]
    pub(crate) listen: String,

    /// Scene file (TOML) or built-in scene name; the display must use the same scene.
    #[arg(long)]
    pub(crate) scene: String,

    /// Objects to render, by name or index in the scene, comma-separated (default: all).
    #[arg(long, value_delimiter = ',')]
    pub(crate) objects: Vec<String>,

    #[command(flatten)]
    pub(crate) render: RenderOptions,
}

pub(crate) fn run(args: Args) -> Result<()> {
    if let Some(n) = args.render.threads {
        anyhow::ensure!(n >= 1, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("setting up the worker threads")?;
    }
    let scene = Arc::new(open_scene(&args.scene, &args.render.search_path())?);
    let objects = NodeConfig::select_objects(&scene, &args.objects)?;
    let config = NodeConfig {
        scene: scene.clone(),
        objects,
        method: args.render.method.clone(),
        method_options: args.render.method_options(),
        limits: DecodeOptions::default(),
    };
    config.check()?;
    let names: Vec<&str> = scene
        .objects
        .iter()
        .filter(|o| config.objects.contains(&o.id))
        .map(|o| o.name.as_str())
        .collect();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the I/O runtime")?;
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
        serve(listener, config, |e| match e {
            NodeEvent::Connected(peer) => eprintln!("strata node: display {peer} connected"),
            NodeEvent::Closed(peer, None) => eprintln!("strata node: display {peer} disconnected"),
            NodeEvent::Closed(peer, Some(why)) => {
                eprintln!("strata node: connection from {peer} ended: {why}")
            }
        })
        .await
        .context("serving")
    })
}
