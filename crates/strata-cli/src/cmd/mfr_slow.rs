//! `strata mfr-slow`: the slow client of multi-frame-rate rendering as its own process, serving
//! `strata mfr --clock real --transport tcp:ADDR` over TCP.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use strata_mfr::ScPriority;
use strata_mfr::tcp::{GIGABIT_BYTES_PER_S, ScEvent, ScServer};
use strata_wire::Codec;

use crate::options::{open_scene, search_path};

/// Serve a fast client as the slow client of multi-frame-rate rendering.
///
/// Listens on ADDR and serves one fast client (`strata mfr SCENE --clock real --transport
/// tcp:ADDR`) at a time, for as long as it runs (stop it with Ctrl-C). The fast client sends the
/// scene's state whenever it changes; the slow client renders the newest state whenever it is
/// free (the objects nobody is manipulating) and sends every fragment back as a DeepFrame. Both
/// must load the same scene: the handshake compares a fingerprint of its geometry, materials and
/// camera, and refuses a fast client with another scene or, with --size, another frame size. The
/// first line on stdout is `listening on HOST:PORT`.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name; the fast client must use the same scene.
    pub(crate) scene: String,

    /// Address to listen on, e.g. 0.0.0.0:7500 (port 0: any free port).
    #[arg(long, value_name = "ADDR")]
    pub(crate) listen: String,

    /// Frame size WxH the slow client insists on (default: the fast client's).
    #[arg(long, value_parser = crate::options::parse_size)]
    pub(crate) size: Option<(u32, u32)>,

    /// How DeepFrames are encoded: raw, lz4, zstd, deep-lz4, deep-zstd, deep-huff (see `strata codecs`).
    #[arg(long, default_value = "deep-huff")]
    pub(crate) codec: String,

    /// Pace sending to emulate a slower network: `gigabit` (90 MB/s, what gigabit Ethernet
    /// delivers to an application) or a rate in MB/s.
    #[arg(long, value_name = "gigabit|MB/s")]
    pub(crate) link: Option<String>,

    /// Rendering threads (default: one per core).
    #[arg(long)]
    pub(crate) threads: Option<usize>,

    /// Priority of the rendering threads: `low` gives a fast client on the same machine the
    /// cores first (nice 19, Linux).
    #[arg(long, value_enum, default_value_t = PriorityArg::Normal)]
    pub(crate) priority: PriorityArg,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

/// `--priority`, `--sc-priority`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum PriorityArg {
    /// As every other thread.
    Normal,
    /// Nice 19: runs when nothing else needs the core.
    Low,
}

impl From<PriorityArg> for ScPriority {
    fn from(p: PriorityArg) -> Self {
        match p {
            PriorityArg::Normal => ScPriority::Normal,
            PriorityArg::Low => ScPriority::Low,
        }
    }
}

/// `--link`: bytes per second.
pub(crate) fn parse_link(s: &str) -> Result<f64> {
    if s.eq_ignore_ascii_case("gigabit") {
        return Ok(GIGABIT_BYTES_PER_S);
    }
    let mb: f64 = s
        .trim()
        .trim_end_matches("MB/s")
        .trim()
        .parse()
        .ok()
        .filter(|v: &f64| v.is_finite() && *v > 0.0 && *v <= 1e6)
        .with_context(|| format!("--link {s}: expected gigabit or a rate in MB/s, e.g. 90"))?;
    Ok(mb * 1e6)
}

pub(crate) fn run(args: Args) -> Result<()> {
    let codec: Codec = args
        .codec
        .parse()
        .map_err(|e| anyhow::anyhow!("--codec {}: {e}", args.codec))?;
    let link = args.link.as_deref().map(parse_link).transpose()?;
    if args.threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    let scene = Arc::new(open_scene(&args.scene, &search_path(&args.model_dirs))?);
    let server = ScServer {
        size: args.size,
        codec,
        link_bytes_per_s: link,
        threads: args.threads.unwrap_or(0),
        priority: args.priority.into(),
        ..ScServer::new(Arc::clone(&scene))
    };
    let listener = std::net::TcpListener::bind(&args.listen)
        .with_context(|| format!("cannot listen on {}", args.listen))?;
    outln!("listening on {}", listener.local_addr()?)?;
    eprintln!(
        "strata mfr-slow: scene {}, codec {codec}{}",
        scene.name,
        link.map_or(String::new(), |b| format!(", paced to {:.0} MB/s", b / 1e6))
    );
    server
        .serve(
            &listener,
            |e| {
                if let ScEvent::Connected { peer, size } = e {
                    eprintln!(
                        "strata mfr-slow: fast client {peer} connected ({}x{})",
                        size.0, size.1
                    );
                }
            },
            |peer, result| match result {
                Ok(sent) => {
                    eprintln!(
                        "strata mfr-slow: fast client {peer} disconnected after {sent} frames"
                    )
                }
                Err(e) => eprintln!("strata mfr-slow: connection from {peer} ended: {e}"),
            },
        )
        .context("serving")
}
