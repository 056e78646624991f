//! The display node (seed 000 Algorithms A.3, A.5): drives the animation, asks every render node
//! for each frame, receives from all of them concurrently, applies what arrives to its copy of
//! each node's runs, merges the copies per pixel and resolves.
//!
//! # Tasks
//!
//! ```text
//!            ┌─ link 0: connect ─ hello ─ write requests ─┐   reader 0 ─► decoder 0 ─┐
//! driver ────┤                                            │                          ├─► driver
//!            └─ link n: …                                 ┘   reader n ─► decoder n ─┘
//! ```
//!
//! The driver requests up to `in_flight` frames ahead, so nodes render frame *t + 1* while *t*
//! travels and is decoded. Each node has a link task that owns its connection and reconnects
//! when it is lost, a reader task that reads whole messages, and a decoder task that decodes them
//! on the blocking pool — every node's decoding overlaps the others' and the network. Every
//! connection is a *generation*; events of an old generation are ignored, so a reconnected node
//! starts clean (its first request after reconnecting carries `reset`).
//!
//! # Faults
//!
//! A node that refuses connections, closes, reports an error, sends a message that does not
//! decode, or sends nothing for frame *t* within `timeout`, is recorded as an incident; the frame
//! is composed without it — from its last good copy (`OnFault::Hold`) or with nothing
//! (`OnFault::Drop`) — and its link reconnects in the background with a growing delay (0.1 s to
//! 2 s). Under the `difference` transfer a missed frame breaks the chain of deltas, so a stalled
//! node is always disconnected and restarted with a reset. Nothing waits longer than `timeout`.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::Mat4;
use strata_core::{DeepFrame, ObjectId, Rgb8Image};
use strata_scene::Scene;
use strata_wire::{
    Codec, DecodeOptions, FrameMessage, Hello, MessageType, NodeStats, Request, RequestKind,
    decode_error, decode_frame,
};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;
use tokio::net::tcp::OwnedReadHalf;
use tokio::sync::mpsc;
use tokio::time::{timeout, timeout_at};

use crate::Transfer;
use crate::difference::{NodeCopy, stale_shared};
use crate::merge::{MAX_NODES, merge_resolve};
use crate::report::{FrameStats, NodeFrame, NodeIncident};
use crate::reprojection::{ReprojCopy, View, ambiguous};
use crate::stream::{ReadError, read_message};

/// What to compose with when a node's frame is missing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OnFault {
    /// Keep using the node's last good runs.
    Hold,
    /// Leave the node out until it is back.
    Drop,
}

/// Everything the display needs.
#[derive(Clone)]
pub struct DisplayConfig {
    /// The scene: its camera, background and animation.
    pub scene: Arc<Scene>,
    /// Node addresses (`host:port`), one node each.
    pub nodes: Vec<String>,
    /// How nodes choose fragments.
    pub transfer: Transfer,
    /// How they encode them.
    pub codec: Codec,
    /// Difference and reprojection transfers: colour errors of at most this many 8-bit steps
    /// are not corrected (0: exact; see the difference and reprojection modules).
    pub tolerance: u8,
    /// First animation frame.
    pub first_frame: u64,
    /// Frames to compose.
    pub frames: u64,
    /// Frame size.
    pub width: u32,
    /// Frame size.
    pub height: u32,
    /// Frames requested ahead of the one being composed (≥ 1).
    pub in_flight: usize,
    /// Longest wait for a node's frame (and for a connection and its hello).
    pub timeout: Duration,
    /// What to do without a node's frame.
    pub on_fault: OnFault,
    /// Limits on what the display accepts.
    pub limits: DecodeOptions,
}

/// Why a display run could not start.
#[derive(Debug, thiserror::Error)]
pub enum DisplayError {
    /// The configuration is unusable.
    #[error("{0}")]
    Config(String),
    /// The async runtime could not start.
    #[error("starting the I/O runtime: {0}")]
    Runtime(#[from] std::io::Error),
}

/// Receives each composed frame and each incident as they happen.
pub trait Observer {
    /// A frame was composed.
    fn frame(&mut self, _stats: &FrameStats, _image: &Rgb8Image) {}
    /// Something happened to a node.
    fn incident(&mut self, _incident: &NodeIncident) {}
}

/// An observer that ignores everything.
impl Observer for () {}

/// What a run produced.
#[derive(Debug)]
pub struct RunResult {
    /// Every composed frame.
    pub per_frame: Vec<FrameStats>,
    /// Faults and reconnections.
    pub incidents: Vec<NodeIncident>,
    /// Seconds from the first composed frame to the last.
    pub elapsed_s: f64,
}

/// Runs the display: composes `config.frames` frames.
pub fn run(config: DisplayConfig, observer: &mut dyn Observer) -> Result<RunResult, DisplayError> {
    if config.nodes.is_empty() {
        return Err(DisplayError::Config("no render nodes given".into()));
    }
    if config.nodes.len() > MAX_NODES {
        return Err(DisplayError::Config(format!(
            "{} nodes given; one display merges at most {MAX_NODES}",
            config.nodes.len()
        )));
    }
    if config.width == 0 || config.height == 0 {
        return Err(DisplayError::Config(
            "the frame size must be at least 1x1".into(),
        ));
    }
    if config.in_flight == 0 {
        return Err(DisplayError::Config(
            "--in-flight must be at least 1".into(),
        ));
    }
    config
        .codec
        .validate()
        .map_err(|e| DisplayError::Config(e.to_string()))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    Ok(runtime.block_on(drive(config, observer)))
}

/// Commands from the driver to a link.
enum LinkCmd {
    /// Write these bytes if the link is still on generation `.0`.
    Send(u64, Vec<u8>),
    /// Drop the connection and reconnect.
    Reconnect,
}

/// A decoded frame message and what came with it.
struct Arrival {
    msg: FrameMessage,
    stats: NodeStats,
    bytes: u64,
    transfer: Duration,
    decode: Duration,
}

/// Events from links to the driver.
enum LinkEvent {
    Up(usize, u64, Hello),
    Down(usize, u64, String),
    Arrived(usize, u64, Box<Arrival>),
}

/// The driver's view of one node.
struct NodeState {
    addr: String,
    cmd: mpsc::Sender<LinkCmd>,
    up: bool,
    generation: u64,
    copy: NodeCopy,
    /// Reprojection transfer: the node's held normal fragments.
    reproj: ReprojCopy,
    /// Reprojection transfer: the depth error bound of its last frame.
    depth_error: f32,
    /// The next frame to request on this generation.
    next_request: u64,
    /// The first frame requested on this generation (its request carries `reset`).
    first_request: u64,
    /// The scene the display shows; a node serving another one is left out.
    scene: String,
    /// Left out for good (it serves another scene).
    refused: bool,
}

async fn drive(config: DisplayConfig, observer: &mut dyn Observer) -> RunResult {
    let (evt_tx, mut evt_rx) = mpsc::channel::<LinkEvent>(64);
    let mut nodes: Vec<NodeState> = Vec::new();
    for (i, addr) in config.nodes.iter().enumerate() {
        let (cmd_tx, cmd_rx) = mpsc::channel(64);
        tokio::spawn(link(
            i,
            addr.clone(),
            cmd_rx,
            evt_tx.clone(),
            config.limits.clone(),
            config.timeout,
        ));
        nodes.push(NodeState {
            addr: addr.clone(),
            cmd: cmd_tx,
            up: false,
            generation: 0,
            copy: NodeCopy::empty(config.width, config.height),
            reproj: ReprojCopy::empty(config.width, config.height),
            depth_error: 0.0,
            next_request: config.first_frame,
            first_request: config.first_frame,
            scene: config.scene.name.clone(),
            refused: false,
        });
    }
    drop(evt_tx);
    let view = config.scene.camera.view().to_cols_array();
    let projection = config
        .scene
        .camera
        .projection(config.width, config.height)
        .to_cols_array();
    let all_objects: Vec<ObjectId> = config.scene.objects.iter().map(|o| o.id).collect();
    let request = |frame: u64, node: usize, kind: RequestKind| -> Vec<u8> {
        let r = Request {
            frame_number: frame,
            node_id: node as u32,
            width: config.width,
            height: config.height,
            view,
            projection,
            transfer: config.transfer,
            codec: config.codec,
            kind,
            tolerance: match config.transfer {
                Transfer::Difference | Transfer::Reprojection => config.tolerance,
                _ => 0,
            },
        };
        let mut b = Vec::new();
        // The configuration was validated; a request always encodes.
        r.encode_into(&mut b).ok();
        b
    };

    let end = config.first_frame + config.frames;
    let mut buffer: HashMap<(usize, u64, bool), Box<Arrival>> = HashMap::new();
    let mut incidents: Vec<NodeIncident> = Vec::new();
    let mut per_frame = Vec::new();
    let mut first_composed: Option<Instant> = None;
    let mut last_composed: Option<Instant> = None;

    // Wait for the first connections (up to the timeout) so frame 0 is not composed empty.
    let deadline = tokio::time::Instant::now() + config.timeout;
    while nodes.iter().any(|n| !n.up) {
        match timeout_at(deadline, evt_rx.recv()).await {
            Ok(Some(e)) => on_event(
                e,
                &mut nodes,
                &mut buffer,
                (config.first_frame, config.first_frame),
                &mut incidents,
                observer,
            ),
            _ => break,
        }
    }

    for t in config.first_frame..end {
        // Keep every live node `in_flight` frames ahead.
        for (i, n) in nodes.iter_mut().enumerate() {
            while n.up && n.next_request < end && n.next_request < t + config.in_flight as u64 {
                let f = n.next_request;
                let kind = RequestKind::Render {
                    reset: f == n.first_request,
                };
                n.cmd
                    .send(LinkCmd::Send(n.generation, request(f, i, kind)))
                    .await
                    .ok();
                n.next_request += 1;
            }
        }
        // Wait for frame t from every node that was asked for it.
        let wanted = |n: &NodeState| n.up && n.first_request <= t && t < n.next_request;
        let deadline = tokio::time::Instant::now() + config.timeout;
        loop {
            let missing = nodes
                .iter()
                .enumerate()
                .any(|(i, n)| wanted(n) && !buffer.contains_key(&(i, t, false)));
            if !missing {
                break;
            }
            match timeout_at(deadline, evt_rx.recv()).await {
                Ok(Some(e)) => on_event(
                    e,
                    &mut nodes,
                    &mut buffer,
                    (t, t + 1),
                    &mut incidents,
                    observer,
                ),
                Ok(None) => break,
                Err(_) => {
                    for (i, n) in nodes.iter_mut().enumerate() {
                        if wanted(n) && !buffer.contains_key(&(i, t, false)) {
                            let what = format!(
                                "no frame within {:.1} s: stalled; reconnecting",
                                config.timeout.as_secs_f64()
                            );
                            fault(n, t, what, observer, &mut incidents).await;
                        }
                    }
                    break;
                }
            }
        }

        // Apply what arrived.
        let apply_start = Instant::now();
        let mut stats: Vec<NodeFrame> = nodes
            .iter()
            .map(|n| NodeFrame {
                node: n.addr.clone(),
                ..NodeFrame::default()
            })
            .collect();
        let mut taking_part = vec![false; nodes.len()];
        let reproj_view = (config.transfer == Transfer::Reprojection).then(|| {
            View::new(
                &config.scene,
                &all_objects,
                t,
                (config.width, config.height),
                Mat4::from_cols_array(&view),
                Mat4::from_cols_array(&projection),
            )
        });
        for (i, n) in nodes.iter_mut().enumerate() {
            let s = &mut stats[i];
            // A node that faulted keeps nothing it sent before: its next frame is a reset.
            match buffer.remove(&(i, t, false)).filter(|_| n.up) {
                Some(a) => {
                    if t == n.first_request {
                        n.copy = NodeCopy::empty(config.width, config.height);
                        n.reproj = ReprojCopy::empty(config.width, config.height);
                    }
                    record(s, &a);
                    s.status = "ok";
                    let Arrival { msg, .. } = *a;
                    match (msg.changed, msg.stale, msg.removals, &reproj_view) {
                        (Some(changed), Some(stale), None, None) => {
                            n.copy.apply_delta(&changed, &stale, &msg.frame)
                        }
                        (Some(_), None, Some(_), Some(_))
                            if msg.header.view != view || msg.header.projection != projection =>
                        {
                            let what = format!(
                                "rendered frame {t} with other matrices than the display sent; \
                                 reconnecting"
                            );
                            fault(n, t, what, observer, &mut incidents).await;
                            s.status = "held";
                            continue;
                        }
                        (Some(touched), None, Some(removals), Some(v)) => {
                            s.removals = removals.total() as u64;
                            let applied = tokio::task::block_in_place(|| {
                                n.reproj.apply(v, &touched, &removals, &msg.frame)
                            });
                            match applied {
                                Ok(()) => {
                                    n.depth_error = removals.depth_error();
                                    n.copy.replace(n.reproj.held().to_frame())
                                }
                                Err(e) => {
                                    // Both ends start over from an empty state.
                                    let what = format!("{e}; reconnecting");
                                    fault(n, t, what, observer, &mut incidents).await;
                                    s.status = "held";
                                    continue;
                                }
                            }
                        }
                        (None, None, None, None) => n.copy.replace(msg.frame),
                        _ => {
                            let what = format!(
                                "sent a frame of another transfer than {}; reconnecting",
                                crate::transfer::name(config.transfer)
                            );
                            fault(n, t, what, observer, &mut incidents).await;
                            s.status = "held";
                            continue;
                        }
                    }
                    taking_part[i] = true;
                }
                None => {
                    s.status = match config.on_fault {
                        OnFault::Hold => "held",
                        OnFault::Drop => {
                            n.copy = NodeCopy::empty(config.width, config.height);
                            "dropped"
                        }
                    };
                }
            }
        }
        let mut merge_ms = apply_start.elapsed().as_secs_f64() * 1e3;

        // Difference: pixels shared between nodes need current depths from every node there.
        // Reprojection: so do pixels where reprojected depths of two nodes are too close to order.
        let fixups = match config.transfer {
            Transfer::Difference | Transfer::Reprojection => nodes.len() > 1,
            _ => false,
        };
        if fixups {
            let fix_start = Instant::now();
            let stale = tokio::task::block_in_place(|| {
                if config.transfer == Transfer::Difference {
                    let copies: Vec<&NodeCopy> = nodes.iter().map(|n| &n.copy).collect();
                    stale_shared(&copies, &taking_part)
                } else {
                    let frames: Vec<&DeepFrame> = nodes.iter().map(|n| n.copy.frame()).collect();
                    let errors: Vec<f32> = nodes.iter().map(|n| n.depth_error).collect();
                    ambiguous(&frames, &errors, &taking_part)
                }
            });
            let mut asked = Vec::new();
            for (i, m) in stale.into_iter().enumerate() {
                if !m.is_empty() && nodes[i].up {
                    stats[i].fixup_pixels = u64::from(m.len());
                    let n = &nodes[i];
                    n.cmd
                        .send(LinkCmd::Send(
                            n.generation,
                            request(t, i, RequestKind::Fixup(m)),
                        ))
                        .await
                        .ok();
                    asked.push(i);
                }
            }
            merge_ms += fix_start.elapsed().as_secs_f64() * 1e3;
            let deadline = tokio::time::Instant::now() + config.timeout;
            while asked
                .iter()
                .any(|&i| nodes[i].up && !buffer.contains_key(&(i, t, true)))
            {
                match timeout_at(deadline, evt_rx.recv()).await {
                    Ok(Some(e)) => on_event(
                        e,
                        &mut nodes,
                        &mut buffer,
                        (t, t + 1),
                        &mut incidents,
                        observer,
                    ),
                    _ => {
                        for &i in &asked {
                            if !buffer.contains_key(&(i, t, true)) {
                                let what = "no fixup reply within the timeout; reconnecting";
                                fault(&mut nodes[i], t, what.into(), observer, &mut incidents)
                                    .await;
                            }
                        }
                        break;
                    }
                }
            }
            let fix_start = Instant::now();
            for &i in &asked {
                if let Some(a) = buffer.remove(&(i, t, true)).filter(|_| nodes[i].up) {
                    record(&mut stats[i], &a);
                    if let Some(mask) = &a.msg.changed {
                        match &reproj_view {
                            // Exact runs for this frame's composition; the held state stays.
                            Some(v) => {
                                let runs =
                                    tokio::task::block_in_place(|| v.shade_frame(&a.msg.frame));
                                nodes[i].copy.apply(mask, &runs);
                            }
                            None => nodes[i].copy.apply(mask, &a.msg.frame),
                        }
                    }
                }
            }
            merge_ms += fix_start.elapsed().as_secs_f64() * 1e3;
        }
        // Late or superseded messages are of no use any more.
        buffer.retain(|&(_, f, _), _| f > t);

        let resolve_start = Instant::now();
        let copies: Vec<&DeepFrame> = nodes.iter().map(|n| n.copy.frame()).collect();
        let image = tokio::task::block_in_place(|| {
            merge_resolve(
                &copies,
                config.width,
                config.height,
                config.scene.background,
            )
        });
        let resolve_ms = resolve_start.elapsed().as_secs_f64() * 1e3;
        let now = Instant::now();
        let interval_ms = last_composed.map_or(0.0, |l| (now - l).as_secs_f64() * 1e3);
        first_composed.get_or_insert(now);
        last_composed = Some(now);
        let fs = FrameStats {
            frame: t,
            fragments_displayed: copies.iter().map(|c| c.fragment_count() as u64).sum(),
            nodes: stats,
            merge_ms,
            resolve_ms,
            interval_ms,
            bad_pixels: None,
        };
        tokio::task::block_in_place(|| observer.frame(&fs, &image));
        per_frame.push(fs);
    }
    // Closing the command channels ends the links and their connections.
    drop(nodes);
    let elapsed_s = match (first_composed, last_composed) {
        (Some(a), Some(b)) => (b - a).as_secs_f64(),
        _ => 0.0,
    };
    RunResult {
        per_frame,
        incidents,
        elapsed_s,
    }
}

/// Reports `what` about node `n` at frame `t` and drops its connection: the link reconnects
/// and the node starts over from a reset.
async fn fault(
    n: &mut NodeState,
    t: u64,
    what: String,
    observer: &mut dyn Observer,
    incidents: &mut Vec<NodeIncident>,
) {
    report(&n.addr, t, what, observer, incidents);
    n.up = false;
    n.cmd.send(LinkCmd::Reconnect).await.ok();
}

/// Tells the observer and keeps the incident for the summary.
fn report(
    node: &str,
    t: u64,
    what: String,
    observer: &mut dyn Observer,
    incidents: &mut Vec<NodeIncident>,
) {
    let inc = NodeIncident {
        frame: t,
        node: node.to_string(),
        what,
    };
    observer.incident(&inc);
    incidents.push(inc);
}

fn record(s: &mut NodeFrame, a: &Arrival) {
    let ms = |us: u64| us as f64 / 1e3;
    s.bytes += a.bytes;
    s.raw_bytes += a.stats.raw_bytes;
    s.fragments_sent += a.stats.fragments_sent;
    if !a.stats.fixup {
        s.fragments_rendered = a.stats.fragments_rendered;
        s.render_ms = ms(a.stats.render_us);
    }
    s.select_ms += ms(a.stats.select_us);
    s.encode_ms += ms(a.stats.encode_us);
    s.transfer_ms += a.transfer.as_secs_f64() * 1e3;
    s.decode_ms += a.decode.as_secs_f64() * 1e3;
}

fn on_event(
    e: LinkEvent,
    nodes: &mut [NodeState],
    buffer: &mut HashMap<(usize, u64, bool), Box<Arrival>>,
    (t, join_at): (u64, u64),
    incidents: &mut Vec<NodeIncident>,
    observer: &mut dyn Observer,
) {
    let mut note =
        |node: &NodeState, what: String| report(&node.addr, t, what, observer, incidents);
    match e {
        LinkEvent::Up(i, generation, hello) => {
            let n = &mut nodes[i];
            if n.refused {
                return;
            }
            if hello.scene != n.scene {
                n.refused = true;
                note(
                    n,
                    format!(
                        "serves scene '{}', not '{}': left out",
                        hello.scene, n.scene
                    ),
                );
                return;
            }
            n.up = true;
            n.generation = generation;
            // Whatever the old connection left in the buffer belongs to a chain of deltas that
            // has ended.
            buffer.retain(|&(j, _, _), _| j != i);
            // It joins with the next frame not yet composed, from a clean state.
            n.next_request = join_at;
            n.first_request = join_at;
            if generation > 1 {
                note(
                    n,
                    format!(
                        "reconnected ({} object(s), {} triangles); restarting from frame {}",
                        hello.objects.len(),
                        hello.triangles,
                        n.first_request
                    ),
                );
            }
        }
        LinkEvent::Down(i, generation, reason) => {
            let n = &mut nodes[i];
            if generation == n.generation {
                n.up = false;
                note(n, format!("down: {reason}"));
            }
        }
        LinkEvent::Arrived(i, generation, a) => {
            let n = &nodes[i];
            let f = a.msg.header.frame_number;
            let node_ok = a.msg.header.node_id == i as u32
                && a.msg.frame.width() == n.copy.frame().width()
                && a.msg.frame.height() == n.copy.frame().height();
            if generation != n.generation || !n.up {
                return;
            }
            if !node_ok {
                note(
                    n,
                    format!(
                        "sent frame {f} as node {} at {}x{}, not what was asked; reconnecting",
                        a.msg.header.node_id,
                        a.msg.frame.width(),
                        a.msg.frame.height()
                    ),
                );
                nodes[i].up = false;
                nodes[i].cmd.try_send(LinkCmd::Reconnect).ok();
                return;
            }
            if f >= t {
                buffer.insert((i, f, a.msg.header.fixup), a);
            }
        }
    }
}

/// One node's connection, kept alive: connect, read its hello, forward requests, reconnect.
async fn link(
    node: usize,
    addr: String,
    mut cmds: mpsc::Receiver<LinkCmd>,
    events: mpsc::Sender<LinkEvent>,
    limits: DecodeOptions,
    wait: Duration,
) {
    let mut generation = 0u64;
    let mut backoff = Duration::from_millis(100);
    // Report a failure to connect once, not on every retry.
    let mut announced = false;
    loop {
        let connected = async {
            let stream = timeout(wait, TcpStream::connect(&addr))
                .await
                .map_err(|_| format!("no connection within {:.1} s", wait.as_secs_f64()))?
                .map_err(|e| format!("cannot connect: {e}"))?;
            stream.set_nodelay(true).ok();
            let (mut rd, wr) = stream.into_split();
            let m = timeout(wait, read_message(&mut rd, &limits))
                .await
                .map_err(|_| "connected, but no hello from the node".to_string())?
                .map_err(|e| format!("reading the hello: {e}"))?;
            let hello = match m.kind {
                MessageType::Hello => {
                    Hello::decode(&m.bytes, &limits).map_err(|e| e.to_string())?
                }
                MessageType::Error => {
                    return Err(format!(
                        "node reported: {}",
                        decode_error(&m.bytes, &limits).unwrap_or_else(|e| e.to_string())
                    ));
                }
                k => return Err(format!("expected a hello, got a {k:?} message")),
            };
            Ok::<_, String>((rd, wr, hello))
        }
        .await;
        let reason = match connected {
            Err(reason) => reason,
            Ok((rd, mut wr, hello)) => {
                generation += 1;
                announced = false;
                backoff = Duration::from_millis(100);
                if events
                    .send(LinkEvent::Up(node, generation, hello))
                    .await
                    .is_err()
                {
                    return;
                }
                let (in_tx, mut in_rx) = mpsc::channel(4);
                let reader = tokio::spawn(read_frames(rd, limits.clone(), in_tx));
                let reason = loop {
                    tokio::select! {
                        cmd = cmds.recv() => match cmd {
                            None => {
                                reader.abort();
                                wr.shutdown().await.ok();
                                return;
                            }
                            Some(LinkCmd::Send(g, bytes)) if g == generation => {
                                if let Err(e) = wr.write_all(&bytes).await {
                                    break format!("sending a request: {e}");
                                }
                            }
                            Some(LinkCmd::Send(..)) => {}
                            Some(LinkCmd::Reconnect) => break "disconnected by the display".to_string(),
                        },
                        got = in_rx.recv() => match got {
                            Some(Ok(a)) => {
                                if events.send(LinkEvent::Arrived(node, generation, a)).await.is_err() {
                                    reader.abort();
                                    return;
                                }
                            }
                            Some(Err(reason)) => break reason,
                            None => break "the connection's reader stopped".to_string(),
                        },
                    }
                };
                reader.abort();
                reason
            }
        };
        if !announced {
            announced = true;
            if events
                .send(LinkEvent::Down(node, generation, reason))
                .await
                .is_err()
            {
                return;
            }
        }
        // Wait before reconnecting; commands meanwhile are for a dead connection.
        let until = tokio::time::Instant::now() + backoff;
        loop {
            match timeout_at(until, cmds.recv()).await {
                Ok(Some(_)) => {}
                Ok(None) => return,
                Err(_) => break,
            }
        }
        backoff = (backoff * 2).min(Duration::from_secs(2));
    }
}

/// Reads frame + stats message pairs and decodes them on the blocking pool, in order.
async fn read_frames(
    mut rd: OwnedReadHalf,
    limits: DecodeOptions,
    out: mpsc::Sender<Result<Box<Arrival>, String>>,
) {
    let (raw_tx, mut raw_rx) = mpsc::channel::<(Vec<u8>, NodeStats, Duration)>(2);
    let decoder = {
        let limits = limits.clone();
        let out = out.clone();
        tokio::spawn(async move {
            while let Some((bytes, stats, transfer)) = raw_rx.recv().await {
                let limits = limits.clone();
                let len = bytes.len() as u64;
                let start = Instant::now();
                let decoded =
                    tokio::task::spawn_blocking(move || decode_frame(&bytes, &limits)).await;
                let decode = start.elapsed();
                let item = match decoded {
                    Ok(Ok(msg)) => Ok(Box::new(Arrival {
                        msg,
                        stats,
                        bytes: len,
                        transfer,
                        decode,
                    })),
                    Ok(Err(e)) => Err(format!("sent a frame that does not decode: {e}")),
                    Err(e) => Err(format!("decoding failed: {e}")),
                };
                let failed = item.is_err();
                if out.send(item).await.is_err() || failed {
                    return;
                }
            }
        })
    };
    let fail = |reason: String| {
        let out = out.clone();
        async move {
            out.send(Err(reason)).await.ok();
        }
    };
    loop {
        let m = match read_message(&mut rd, &limits).await {
            Ok(m) => m,
            Err(ReadError::Closed) => break fail("the node closed the connection".into()).await,
            Err(e) => break fail(format!("reading from the node: {e}")).await,
        };
        match m.kind {
            MessageType::Frame => {
                let s = match read_message(&mut rd, &limits).await {
                    Ok(s) if s.kind == MessageType::Stats => s,
                    Ok(s) => {
                        break fail(format!(
                            "expected the frame's stats, got a {:?} message",
                            s.kind
                        ))
                        .await;
                    }
                    Err(e) => break fail(format!("reading the frame's stats: {e}")).await,
                };
                let stats = match NodeStats::decode(&s.bytes, &limits) {
                    Ok(st) => st,
                    Err(e) => break fail(format!("malformed stats: {e}")).await,
                };
                let transfer = m.body_time + s.body_time;
                if raw_tx.send((m.bytes, stats, transfer)).await.is_err() {
                    break;
                }
            }
            MessageType::Error => {
                let text = decode_error(&m.bytes, &limits).unwrap_or_else(|e| e.to_string());
                break fail(format!("node reported: {text}")).await;
            }
            k => break fail(format!("unexpected {k:?} message from a node")).await,
        }
    }
    drop(raw_tx);
    decoder.await.ok();
}
