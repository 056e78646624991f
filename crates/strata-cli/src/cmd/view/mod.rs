//! `strata view`: a web viewer served by strata itself — orbit a scene, switch methods and their
//! options, read each frame's statistics.
//!
//! ```text
//! browser ── GET /            page.html, page.js, page.css (compiled into the binary)
//!         ── GET /ws ───────▶ session::run, one per page:
//!                              requests (JSON text) → render on the shared workers → PNG frames
//!                              with --mfr: settings and pointer events → mfr::run, a slow and
//!                              a fast client composed (seed 004) → PNG frames at the FC's pace
//!                              with --nodes: settings → remote::run, a display of render nodes
//!                              (seed 000) steered by the page → PNG frames as they are composed
//! ```
//!
//! The server is axum on tokio; rendering runs on one rayon pool shared by every page
//! (`--threads`), outside the async workers. The messages are in [`protocol`], a page's
//! connection in [`session`]. The page does the navigation itself (orbit, pan and zoom change
//! the camera it sends) and asks for frames the size of its canvas, or of `?size=WxH`.
//!
//! What the page offers is read from the same places the command line reads: the methods from
//! `strata_stores::METHODS`, each option's help and default from the `--k`, `--budget`, …
//! arguments of [`crate::options::MethodParams`], and every request is checked by the functions
//! `strata render` and `compare --methods` use.

mod compare;
mod mfr;
mod probe;
mod protocol;
mod remote;
mod session;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, Result};
use axum::Router;
use axum::extract::{State, WebSocketUpgrade};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use clap::Args as _;
use serde_json::{Value, json};
use strata_scene::Scene;
use strata_stores::MethodOptions;

use crate::cmd::display::{Link, LinkArgs, parse_node_address};
use crate::options::{open_scene, search_path, thread_pool};
use protocol::Mode;

/// Serve a web page that shows a scene rendered by strata: orbit, pan and zoom with the mouse or
/// touch, switch the method and its options, and read each frame's statistics.
///
/// Open the printed address in a browser (on a remote machine, forward the port: `ssh -L
/// 7300:localhost:7300 host`). The page asks for frames the size of its window; add
/// `?size=1280x720` to the address to fix the size. The camera panel shows the view as lines to
/// paste into a scene file. Stop with Ctrl-C.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name (`strata scenes` lists them).
    pub(crate) scene: String,

    /// Address to listen on. The default accepts only this machine; `0.0.0.0:7300` accepts
    /// anyone who can reach it. Port 0 picks a free port (printed).
    #[arg(long, default_value = "127.0.0.1:7300")]
    pub(crate) listen: SocketAddr,

    /// The method a page starts with, as `compare --methods` writes it: a name and options,
    /// `kbuffer:k=8` or `vkbuffer:budget=25%:k-from=optimal` (`strata methods` lists them).
    #[arg(long, short, default_value = "abuffer")]
    pub(crate) method: String,

    /// Multi-frame-rate mode (seed 004): the scene renders on a slow client, and what you point
    /// at or drag renders on a fast client composed with it every frame. Hover an object to
    /// hand it to the fast client, press and drag to move it; the page shows both clients'
    /// rates, the age of the slow client's buffer, and lets you switch the composition (`deep`
    /// is exact; `digital` and `optical` show the artefacts of the original systems) and audit
    /// every frame against the whole scene rendered at once. Try `strata view mfr-cars --mfr`.
    /// Both clients keep every fragment, so `--method` does not apply.
    #[arg(long, conflicts_with = "method")]
    pub(crate) mfr: bool,

    /// Remote mode (seed 000): the page is the display of these render nodes (`strata node`),
    /// comma-separated `host:port`. Every frame is requested from every node through the page's
    /// camera, merged and resolved here; the panel shows each node's status, what it sent and
    /// took, and its incidents (a node that dies is held or dropped and reconnected). The
    /// nodes must serve the same scene. `--transfer`, `--codec` and the other options below are
    /// `strata display`'s. Try `strata node --scene mixed --listen 127.0.0.1:7400 &` then
    /// `strata view mixed --nodes 127.0.0.1:7400`.
    #[arg(long, value_delimiter = ',', value_parser = parse_node_address,
          conflicts_with_all = ["mfr", "method"])]
    pub(crate) nodes: Vec<String>,

    /// With --nodes: how the nodes send fragments and how the display waits for them.
    #[command(flatten)]
    pub(crate) link: LinkArgs,

    /// Pages served at once; more are refused with a message until one closes.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u16).range(1..=256))]
    pub(crate) max_pages: u16,

    /// Worker threads, shared by every page (default: every available core).
    #[arg(long, short = 'j')]
    pub(crate) threads: Option<usize>,

    /// Extra directory to look for mesh files in, searched before STRATA_MODEL_PATH (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,
}

/// What every page's connection shares.
pub(crate) struct Shared {
    scene: Arc<Scene>,
    pool: rayon::ThreadPool,
    /// The hello message, the same for every page.
    hello: String,
    pages: AtomicUsize,
    max_pages: usize,
    /// Pages run the multi-frame-rate session instead of rendering views.
    mfr: bool,
    /// Pages display these render nodes instead of rendering views.
    remote: Option<Remote>,
}

/// What a remote page's display connects to and asks for.
pub(crate) struct Remote {
    pub(crate) nodes: Vec<String>,
    pub(crate) link: Link,
}

/// A page's place among the `--max-pages`; given back when dropped.
struct Seat<'a>(&'a AtomicUsize);

impl Drop for Seat<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

impl Shared {
    /// What the pages do.
    fn mode(&self) -> Mode {
        match (self.mfr, &self.remote) {
            (true, _) => Mode::Mfr,
            (false, Some(_)) => Mode::Remote,
            (false, None) => Mode::Views,
        }
    }

    /// A seat for one more page, or `None` if every seat is taken.
    fn enter(&self) -> Option<Seat<'_>> {
        self.pages
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < self.max_pages).then_some(n + 1)
            })
            .ok()
            .map(|_| Seat(&self.pages))
    }
}

const PAGE_HTML: &str = include_str!("page/page.html");
const PAGE_JS: &str = include_str!("page/page.js");
const PAGE_CSS: &str = include_str!("page/page.css");

/// The method options a page may set: name, help, default and whether it is a flag, read from
/// the command line's own arguments. `--weights` names a file on the server, so it is left out.
fn option_specs() -> Vec<Value> {
    let command = crate::options::MethodParams::augment_args(clap::Command::new("options"));
    command
        .get_arguments()
        .filter_map(|a| {
            let name = a.get_long()?;
            if name == "weights" || !strata_stores::options::OPTION_NAMES.contains(&name) {
                return None;
            }
            let flag = matches!(a.get_action(), clap::ArgAction::SetTrue);
            let default = a
                .get_default_values()
                .first()
                .map(|v| v.to_string_lossy().into_owned());
            Some(json!({
                "name": name,
                "help": a.get_help().map(|h| h.to_string()).unwrap_or_default(),
                "default": if flag { Some("false".to_owned()) } else { default },
                "flag": flag,
            }))
        })
        .collect()
}

/// Splits a method spec (`kbuffer:k=8`) into its method, checked options and option strings.
fn initial_method(spec: &str) -> Result<(String, serde_json::Map<String, Value>)> {
    let (method, settings) = crate::options::split_spec(spec);
    let settings: std::collections::BTreeMap<String, String> = settings
        .map(|(k, v)| (k.to_owned(), v.unwrap_or("true").to_owned()))
        .collect();
    // The page's own check, so the first view is refused exactly as a later one would be.
    protocol::choice(method.to_owned(), &settings).with_context(|| format!("--method '{spec}'"))?;
    let settings = settings.into_iter().map(|(k, v)| (k, json!(v))).collect();
    Ok((method.to_owned(), settings))
}

/// The hello message: the scene, the methods and their options, the first view.
fn hello(
    scene: &Scene,
    method: &str,
    settings: serde_json::Map<String, Value>,
    mfr: bool,
    remote: Option<&Remote>,
) -> String {
    let methods: Vec<Value> = strata_stores::METHODS
        .iter()
        .map(|m| {
            json!({
                "name": m.name,
                "summary": m.summary,
                "fidelity": m.fidelity(&MethodOptions::default()).describe(),
                "options": m.options,
            })
        })
        .collect();
    json!({
        "type": "hello",
        "strata": env!("CARGO_PKG_VERSION"),
        "scene": scene.name,
        "origin": scene.origin,
        "width": scene.width,
        "height": scene.height,
        "frames": scene.frame_count(),
        "triangles": scene.triangle_count(),
        "camera": protocol::camera_json(&scene.camera),
        "methods": methods,
        "options": option_specs(),
        "method": method,
        "method_options": settings,
        "max_side": protocol::MAX_SIDE,
        "mfr": mfr.then(|| json!({
            "objects": scene.objects.len(),
            "max_fc_hz": protocol::MAX_FC_HZ,
            "max_sc_interval_ms": protocol::MAX_SC_INTERVAL_MS,
            "max_side": protocol::MAX_MFR_SIDE,
        })),
        "remote": remote.map(|r| json!({
            "nodes": r.nodes,
            "transfer": r.link.label(),
            "codec": r.link.codec.to_string(),
            "in_flight": r.link.in_flight,
            "timeout_s": r.link.timeout.as_secs_f64(),
            "on_fault": match r.link.on_fault {
                strata_remote::display::OnFault::Hold => "hold",
                strata_remote::display::OnFault::Drop => "drop",
            },
            "max_fps": protocol::MAX_FC_HZ,
            "max_side": protocol::MAX_REMOTE_SIDE,
        })),
    })
    .to_string()
}

/// Runs `strata view`.
pub(crate) fn run(args: Args) -> Result<()> {
    let (method, settings) = initial_method(&args.method)?;
    let remote = if args.nodes.is_empty() {
        if !args.link.is_default() {
            anyhow::bail!(
                "--transfer, --layers, --opacity-threshold, --tolerance, --codec, --in-flight, \
                 --timeout and --on-fault apply to the remote mode only: add --nodes"
            );
        }
        None
    } else {
        if args.nodes.len() > strata_remote::merge::MAX_NODES {
            anyhow::bail!(
                "--nodes: {} nodes given; one display merges at most {}",
                args.nodes.len(),
                strata_remote::merge::MAX_NODES
            );
        }
        Some(Remote {
            nodes: args.nodes.clone(),
            link: args.link.check()?,
        })
    };
    let scene = open_scene(&args.scene, &search_path(&args.model_dirs))?;
    let pool = thread_pool(args.threads)?;
    let shared = Arc::new(Shared {
        hello: hello(&scene, &method, settings, args.mfr, remote.as_ref()),
        remote,
        scene: Arc::new(scene),
        pool,
        pages: AtomicUsize::new(0),
        max_pages: usize::from(args.max_pages),
        mfr: args.mfr,
    });
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the server's runtime")?;
    runtime.block_on(serve(args.listen, shared))
}

async fn serve(listen: SocketAddr, shared: Arc<Shared>) -> Result<()> {
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .with_context(|| format!("cannot listen on {listen}"))?;
    let local = listener
        .local_addr()
        .context("cannot read the bound address")?;
    eprintln!(
        "strata view: serving {} at http://{local}/ (Ctrl-C to stop)",
        shared.scene.name
    );
    let app = Router::new()
        .route(
            "/",
            get(|| async { asset("text/html; charset=utf-8", PAGE_HTML) }),
        )
        .route(
            "/page.js",
            get(|| async { asset("text/javascript; charset=utf-8", PAGE_JS) }),
        )
        .route(
            "/page.css",
            get(|| async { asset("text/css; charset=utf-8", PAGE_CSS) }),
        )
        .route("/ws", get(socket))
        .with_state(shared);
    axum::serve(listener, app)
        .await
        .context("the server stopped")
}

fn asset(kind: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

async fn socket(
    ws: WebSocketUpgrade,
    headers: HeaderMap,
    State(shared): State<Arc<Shared>>,
) -> Response {
    if let Err(why) = same_origin(&headers) {
        return (StatusCode::FORBIDDEN, why).into_response();
    }
    ws.max_message_size(1 << 20)
        .on_upgrade(move |socket| session::run(socket, shared))
}

/// Refuses a WebSocket opened by a page from another site: browsers let any page open sockets
/// to `localhost`, and a viewer's socket renders, reads and exports the scene. A client that is
/// not a browser sends no `Origin` and is let in.
fn same_origin(headers: &HeaderMap) -> Result<(), String> {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return Ok(());
    };
    let origin = origin.to_str().unwrap_or_default();
    let host = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or_default();
    let origin_host = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .unwrap_or_default();
    if !host.is_empty() && origin_host.eq_ignore_ascii_case(host) {
        Ok(())
    } else {
        Err(format!(
            "strata view: a page from {origin} may not use this viewer (it serves {host} only)"
        ))
    }
}
