//! The display node (Jähne 2014 Algorithms A.3, A.5): drives the animation, asks every render node
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
//!
//! # Steering
//!
//! The [`Observer`] that receives the frames may also steer the run: it gives each frame's
//! camera ([`Observer::camera`], asked once a frame, when the frame's first request is written,
//! so every node and every fixup of that frame renders through the same matrices) and may stop
//! the run ([`Observer::stop`], asked before each frame and every [`STOP_POLL`] while the
//! driver waits, so a stop never waits out a silent node's timeout). `strata display` does
//! neither (the scene's camera, a fixed number of frames); `strata view --nodes` follows the
//! page's camera and runs until the page goes.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::Mat4;
use strata_core::{DeepFrame, DeepFrameError, ObjectId, Rgb8Image};
use strata_scene::{Camera, Scene};
use strata_wire::{
    Codec, DecodeOptions, FrameDecoder, FrameMessage, Hello, MessageType, NodeStats, PixelMask,
    Request, RequestKind, decode_error,
};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::mpsc;
use tokio::time::{timeout, timeout_at};

use crate::difference::{NodeCopy, stale_shared};
use crate::merge::{MAX_NODES, merge_frames, merge_resolve_into};
use crate::report::{FrameStats, NodeFrame, NodeIncident, NodeStatus};
use crate::reprojection::{ReprojCopy, View, ambiguous};
use crate::stream::{ReadError, read_message, read_message_into};
use crate::{FrameOutOfRange, Transfer, animation_frame};

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

/// Why a display run could not start, or had to stop.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DisplayError {
    /// No node addresses.
    #[error("no render nodes given")]
    NoNodes,
    /// More nodes than one display merges.
    #[error("{given} nodes given; one display merges at most {max}")]
    TooManyNodes {
        /// Nodes given.
        given: usize,
        /// The most a display merges.
        max: usize,
    },
    /// A node address is not `host:port`.
    #[error("--nodes: {0}")]
    Address(#[from] AddressError),
    /// A frame of zero pixels.
    #[error("the frame size must be at least 1x1")]
    EmptyFrame,
    /// `in_flight` is 0.
    #[error("--in-flight must be at least 1")]
    InFlight,
    /// The codec's parameters are out of range.
    #[error("{0}")]
    Codec(#[source] strata_wire::WireError),
    /// The frames asked for go beyond the last frame a scene can be posed at.
    #[error("--first-frame {first} with --frames {frames}: {source}")]
    FrameRange {
        /// First frame.
        first: u64,
        /// Frames.
        frames: u64,
        /// The first frame number out of range.
        source: FrameOutOfRange,
    },
    /// A request did not encode (the configuration was checked, so this is a bug).
    #[error("encoding a request: {0}")]
    Request(#[source] strata_wire::WireError),
    /// The async runtime could not start.
    #[error("starting the I/O runtime: {0}")]
    Runtime(#[from] std::io::Error),
}

/// Why a node address is not `host:port`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum AddressError {
    /// No `:port`.
    #[error("'{0}' is not HOST:PORT (such as 127.0.0.1:7400, render1:7400 or [::1]:7400)")]
    NoPort(String),
    /// The port is not a number in 1..=65535.
    #[error("'{address}': the port '{port}' is not a number in 1..=65535")]
    Port {
        /// The address.
        address: String,
        /// Its port part.
        port: String,
    },
    /// The host is empty or not a host name or IP address.
    #[error("'{address}': '{host}' is not a host name or IP address (IPv6 goes in brackets)")]
    Host {
        /// The address.
        address: String,
        /// Its host part.
        host: String,
    },
}

/// Checks that `address` is `host:port` as `--nodes` takes it: a host name, an IPv4 address or
/// a bracketed IPv6 address, and a port in 1..=65535. Nothing is resolved or connected.
pub fn check_address(address: &str) -> Result<(), AddressError> {
    let (host, port) = address
        .rsplit_once(':')
        .ok_or_else(|| AddressError::NoPort(address.to_string()))?;
    if !matches!(port.parse::<u16>(), Ok(p) if p > 0) {
        return Err(AddressError::Port {
            address: address.to_string(),
            port: port.to_string(),
        });
    }
    let host_ok = match host.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
        Some(v6) => v6.parse::<std::net::Ipv6Addr>().is_ok(),
        None => {
            !host.is_empty()
                && host
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '.' | '_'))
        }
    };
    if !host_ok {
        return Err(AddressError::Host {
            address: address.to_string(),
            host: host.to_string(),
        });
    }
    Ok(())
}

/// Receives each composed frame and each incident as they happen, and may steer the run (see
/// the module's "Steering").
pub trait Observer {
    /// The camera to render frame `frame` through (its projection at the run's size), or `None`
    /// for the scene's. Asked once per frame, when the driver writes the first request for it —
    /// `in_flight` frames ahead of the frame being composed, so a camera given here is shown
    /// that many frames later at the earliest.
    fn camera(&mut self, _frame: u64) -> Option<Camera> {
        None
    }
    /// Asked before each frame, and every [`STOP_POLL`] while the driver waits for nodes:
    /// true ends the run there, with the frames composed so far.
    fn stop(&mut self) -> bool {
        false
    }
    /// Whether the run's result should hold every frame's figures and every incident (`strata
    /// display` summarises them). An observer of an endless run (a viewer) says no, so the
    /// driver's memory does not grow with every frame; it sees each frame and incident anyway.
    fn keep_history(&self) -> bool {
        true
    }
    /// A frame was composed.
    fn frame(&mut self, _stats: &FrameStats, _image: &Rgb8Image) {}
    /// True if [`Observer::deep_frame`] should receive every composed frame's merged fragments
    /// (merging them costs a pass over every fragment, so only when asked).
    fn wants_deep_frames(&self) -> bool {
        false
    }
    /// The merged fragments of a composed frame, when [`Observer::wants_deep_frames`].
    fn deep_frame(&mut self, _frame: u64, _deep: Result<&DeepFrame, &DeepFrameError>) {}
    /// Something happened to a node.
    fn incident(&mut self, _incident: &NodeIncident) {}
    /// Node `node` (its address) connected, or reconnected, and serves the display's scene:
    /// its hello says which objects it renders.
    fn node_up(&mut self, _node: &str, _hello: &Hello) {}
}

/// How often a driver waiting for nodes asks the observer whether to stop.
pub const STOP_POLL: Duration = Duration::from_millis(100);

/// An observer that ignores everything.
impl Observer for () {}

/// What a run produced.
#[derive(Debug)]
pub struct RunResult {
    /// Every composed frame (none when the observer keeps no history).
    pub per_frame: Vec<FrameStats>,
    /// Faults and reconnections (none when the observer keeps no history).
    pub incidents: Vec<NodeIncident>,
    /// Seconds from the first composed frame to the last.
    pub elapsed_s: f64,
}

/// Runs the display: composes `config.frames` frames.
///
/// An error means the run could not start (the configuration is unusable) or had to stop; a
/// node that fails is not an error but an incident, and shows in the frames' node statuses.
pub fn run(config: DisplayConfig, observer: &mut dyn Observer) -> Result<RunResult, DisplayError> {
    check_config(&config)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    runtime.block_on(async move { Driver::start(config, observer).run().await })
}

/// Everything `run` refuses before it connects to anything.
pub(crate) fn check_config(config: &DisplayConfig) -> Result<(), DisplayError> {
    if config.nodes.is_empty() {
        return Err(DisplayError::NoNodes);
    }
    if config.nodes.len() > MAX_NODES {
        return Err(DisplayError::TooManyNodes {
            given: config.nodes.len(),
            max: MAX_NODES,
        });
    }
    for a in &config.nodes {
        check_address(a)?;
    }
    if config.width == 0 || config.height == 0 {
        return Err(DisplayError::EmptyFrame);
    }
    if config.in_flight == 0 {
        return Err(DisplayError::InFlight);
    }
    config.codec.validate().map_err(DisplayError::Codec)?;
    // Every frame number of the run must pose the scene: the last one is first + frames - 1.
    let range_error = |source| DisplayError::FrameRange {
        first: config.first_frame,
        frames: config.frames,
        source,
    };
    let last = config
        .first_frame
        .checked_add(config.frames.saturating_sub(1))
        .ok_or(range_error(FrameOutOfRange(u64::MAX)))?;
    animation_frame(last).map_err(range_error)?;
    Ok(())
}

/// The request a display with `config` sends node `node` for frame `frame`, encoded; `camera`
/// is the view and projection every request carries (column-major).
pub(crate) fn encode_request(
    config: &DisplayConfig,
    (view, projection): (&[f32; 16], &[f32; 16]),
    frame: u64,
    node: usize,
    kind: RequestKind,
) -> Result<Vec<u8>, DisplayError> {
    let r = Request {
        frame_number: frame,
        node_id: u32::try_from(node).map_err(|_| DisplayError::TooManyNodes {
            given: config.nodes.len(),
            max: MAX_NODES,
        })?,
        width: config.width,
        height: config.height,
        view: *view,
        projection: *projection,
        transfer: config.transfer,
        codec: config.codec,
        kind,
        tolerance: match config.transfer {
            Transfer::Difference | Transfer::Reprojection => config.tolerance,
            _ => 0,
        },
    };
    let mut b = Vec::new();
    r.encode_into(&mut b).map_err(DisplayError::Request)?;
    Ok(b)
}

/// The view and projection (column-major) of every request of a run with `config`.
pub(crate) fn request_camera(config: &DisplayConfig) -> ([f32; 16], [f32; 16]) {
    let camera = &config.scene.camera;
    (
        camera.view().to_cols_array(),
        camera
            .projection(config.width, config.height)
            .to_cols_array(),
    )
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
    Down(usize, u64, LinkError),
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
    /// Where frames this node sent go once applied, for its decoder to reuse.
    spare: Spare<DeepFrame>,
}

/// What waiting for the next link event gave.
enum Next {
    Event(LinkEvent),
    /// Every link is gone.
    Closed,
    /// The deadline passed.
    Deadline,
    /// The observer asked to stop.
    Stop,
}

/// Arrivals not yet applied, by node, frame number and whether they answer a fixup request.
type Buffer = HashMap<(usize, u64, bool), Box<Arrival>>;

/// What one frame's composition collects before it is resolved.
struct FrameWork {
    /// The frame.
    t: u64,
    /// Per node: what it sent and whether it took part.
    stats: Vec<NodeFrame>,
    /// Nodes whose copy was updated for this frame (the fixup round looks at these).
    taking_part: Vec<bool>,
    /// Reprojection: the frame's view, to shade what nodes send.
    reproj_view: Option<View>,
}

/// The display's state for one run: the nodes, what arrived early, what happened so far.
///
/// Per frame *t* the driver: requests frames ahead ([`Driver::request_ahead`]), waits for *t*
/// from every node asked for it ([`Driver::wait_for_frames`]), applies what arrived
/// ([`Driver::apply_arrivals`]), runs the fixup round where nodes overlap
/// ([`Driver::fixup_round`]), then merges and resolves ([`Driver::compose`]).
struct Driver<'o> {
    config: DisplayConfig,
    observer: &'o mut dyn Observer,
    events: mpsc::Receiver<LinkEvent>,
    nodes: Vec<NodeState>,
    buffer: Buffer,
    incidents: Vec<NodeIncident>,
    per_frame: Vec<FrameStats>,
    first_composed: Option<Instant>,
    last_composed: Option<Instant>,
    /// The scene's camera, column-major view and projection: what a frame is rendered through
    /// unless the observer gives another.
    scene_camera: ([f32; 16], [f32; 16]),
    /// The camera of every frame requested and not yet composed, decided when its first
    /// request was written: every node and every fixup of the frame uses the same.
    cameras: std::collections::BTreeMap<u64, ([f32; 16], [f32; 16])>,
    /// Every object of the scene (the reprojection view shades any node's fragments).
    all_objects: Vec<ObjectId>,
    /// The composed image, resolved into again for every frame (no fresh pages per frame).
    image: Rgb8Image,
    /// Keep every frame's figures and every incident for the result.
    keep_history: bool,
    /// The observer asked to stop while the driver waited.
    stopping: bool,
}

impl<'o> Driver<'o> {
    /// Spawns a link per node; nothing is requested yet.
    fn start(config: DisplayConfig, observer: &'o mut dyn Observer) -> Self {
        let (evt_tx, events) = mpsc::channel::<LinkEvent>(64);
        let mut nodes = Vec::new();
        for (i, addr) in config.nodes.iter().enumerate() {
            let (cmd_tx, cmd_rx) = mpsc::channel(64);
            let spare = Spare::default();
            tokio::spawn(link(
                i,
                addr.clone(),
                cmd_rx,
                evt_tx.clone(),
                config.limits.clone(),
                config.timeout,
                spare.clone(),
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
                spare,
            });
        }
        let scene_camera = request_camera(&config);
        let all_objects = config.scene.objects.iter().map(|o| o.id).collect();
        let keep_history = observer.keep_history();
        Driver {
            config,
            observer,
            events,
            nodes,
            buffer: HashMap::new(),
            incidents: Vec::new(),
            per_frame: Vec::new(),
            first_composed: None,
            last_composed: None,
            scene_camera,
            cameras: std::collections::BTreeMap::new(),
            all_objects,
            image: Rgb8Image::filled(0, 0, [0; 3]),
            keep_history,
            stopping: false,
        }
    }

    /// Composes every frame of the run.
    async fn run(mut self) -> Result<RunResult, DisplayError> {
        self.wait_for_first_connections().await;
        let end = self.config.first_frame + self.config.frames;
        for t in self.config.first_frame..end {
            // A node that came back while no frame was awaited (every node was down) joins
            // here: its link's news is read only while the driver waits.
            while let Ok(e) = self.events.try_recv() {
                self.on_event(e, (t, t));
            }
            if self.stopping || self.observer.stop() {
                break;
            }
            self.request_ahead(t, end).await?;
            self.wait_for_frames(t).await;
            if self.stopping {
                break;
            }
            let apply_start = Instant::now();
            let mut work = self.frame_work(t)?;
            self.apply_arrivals(&mut work).await;
            let mut merge_ms = apply_start.elapsed().as_secs_f64() * 1e3;
            if self.needs_fixups() {
                merge_ms += self.fixup_round(&mut work).await?;
                if self.stopping {
                    break;
                }
            }
            // Late or superseded messages are of no use any more, nor is this frame's camera.
            self.buffer.retain(|&(_, f, _), _| f > t);
            self.cameras.retain(|&f, _| f > t);
            self.compose(work, merge_ms);
        }
        let elapsed_s = match (self.first_composed, self.last_composed) {
            (Some(a), Some(b)) => (b - a).as_secs_f64(),
            _ => 0.0,
        };
        // Dropping the nodes closes the command channels, which ends the links and their
        // connections.
        Ok(RunResult {
            per_frame: self.per_frame,
            incidents: self.incidents,
            elapsed_s,
        })
    }

    /// The next link event before `deadline`; every [`STOP_POLL`] meanwhile the observer is
    /// asked whether to stop, so a stop never waits for a silent node's timeout.
    async fn next_event(&mut self, deadline: tokio::time::Instant) -> Next {
        loop {
            let slice = deadline.min(tokio::time::Instant::now() + STOP_POLL);
            match timeout_at(slice, self.events.recv()).await {
                Ok(Some(e)) => return Next::Event(e),
                Ok(None) => return Next::Closed,
                Err(_) if tokio::time::Instant::now() >= deadline => return Next::Deadline,
                Err(_) => {
                    if self.observer.stop() {
                        self.stopping = true;
                        return Next::Stop;
                    }
                }
            }
        }
    }

    /// Waits for the first connections (up to the timeout) so the first frame is not composed
    /// without nodes that are merely slow to answer.
    async fn wait_for_first_connections(&mut self) {
        let first = self.config.first_frame;
        let deadline = tokio::time::Instant::now() + self.config.timeout;
        while self.nodes.iter().any(|n| !n.up && !n.refused) {
            match self.next_event(deadline).await {
                Next::Event(e) => self.on_event(e, (first, first)),
                _ => break,
            }
        }
    }

    /// The view and projection (column-major) frame `frame` is rendered through: decided the
    /// first time it is asked for, the same for every later request of that frame.
    fn camera_for(&mut self, frame: u64) -> ([f32; 16], [f32; 16]) {
        if let Some(&c) = self.cameras.get(&frame) {
            return c;
        }
        let (width, height) = (self.config.width, self.config.height);
        let c = match self.observer.camera(frame) {
            Some(camera) => (
                camera.view().to_cols_array(),
                camera.projection(width, height).to_cols_array(),
            ),
            None => self.scene_camera,
        };
        self.cameras.insert(frame, c);
        c
    }

    /// The request for frame `frame` of node `node`, encoded.
    fn request(
        &mut self,
        frame: u64,
        node: usize,
        kind: RequestKind,
    ) -> Result<Vec<u8>, DisplayError> {
        let (view, projection) = self.camera_for(frame);
        encode_request(&self.config, (&view, &projection), frame, node, kind)
    }

    /// Hands node `i`'s link a request for frame `frame` on its current connection.
    async fn send_request(
        &mut self,
        i: usize,
        frame: u64,
        kind: RequestKind,
    ) -> Result<(), DisplayError> {
        let bytes = self.request(frame, i, kind)?;
        let n = &self.nodes[i];
        if n.cmd
            .send(LinkCmd::Send(n.generation, bytes))
            .await
            .is_err()
        {
            self.link_gone(i, frame);
        }
        Ok(())
    }

    /// Node `i`'s link task ended, which only a bug does while the run lasts: the node is
    /// left out from here on.
    fn link_gone(&mut self, i: usize, t: u64) {
        let n = &mut self.nodes[i];
        n.up = false;
        n.refused = true;
        self.report(
            i,
            t,
            "its connection task ended unexpectedly: left out".into(),
        );
    }

    /// Keeps every live node `in_flight` frames ahead of `t` (never past `end`).
    async fn request_ahead(&mut self, t: u64, end: u64) -> Result<(), DisplayError> {
        let ahead = t.saturating_add(self.config.in_flight as u64);
        for i in 0..self.nodes.len() {
            loop {
                let n = &self.nodes[i];
                if !(n.up && n.next_request < end && n.next_request < ahead) {
                    break;
                }
                let f = n.next_request;
                let reset = f == n.first_request;
                self.send_request(i, f, RequestKind::Render { reset })
                    .await?;
                self.nodes[i].next_request += 1;
            }
        }
        Ok(())
    }

    /// Whether node `i` was asked for frame `t` and its frame has not arrived yet.
    fn waiting_for(&self, i: usize, t: u64) -> bool {
        let n = &self.nodes[i];
        n.up && n.first_request <= t
            && t < n.next_request
            && !self.buffer.contains_key(&(i, t, false))
    }

    /// Waits (at most the timeout) for frame `t` from every node asked for it; a node that
    /// does not deliver in time is reported stalled and reconnected.
    async fn wait_for_frames(&mut self, t: u64) {
        let deadline = tokio::time::Instant::now() + self.config.timeout;
        while (0..self.nodes.len()).any(|i| self.waiting_for(i, t)) {
            match self.next_event(deadline).await {
                Next::Event(e) => self.on_event(e, (t, t + 1)),
                Next::Closed | Next::Stop => return,
                Next::Deadline => {
                    let what = format!(
                        "no frame within {:.1} s: stalled; reconnecting",
                        self.config.timeout.as_secs_f64()
                    );
                    for i in 0..self.nodes.len() {
                        if self.waiting_for(i, t) {
                            self.fault(i, t, what.clone()).await;
                        }
                    }
                    return;
                }
            }
        }
    }

    /// Empty per-node figures for frame `t`, and its view under the reprojection transfer.
    fn frame_work(&mut self, t: u64) -> Result<FrameWork, DisplayError> {
        let (view, projection) = self.camera_for(t);
        let config = &self.config;
        let reproj_view = match config.transfer {
            Transfer::Reprojection => {
                let pose = animation_frame(t).map_err(|source| DisplayError::FrameRange {
                    first: config.first_frame,
                    frames: config.frames,
                    source,
                })?;
                Some(View::new(
                    &config.scene,
                    &self.all_objects,
                    pose,
                    (config.width, config.height),
                    Mat4::from_cols_array(&view),
                    Mat4::from_cols_array(&projection),
                ))
            }
            _ => None,
        };
        Ok(FrameWork {
            t,
            stats: self
                .nodes
                .iter()
                .map(|n| NodeFrame {
                    node: n.addr.clone(),
                    ..NodeFrame::default()
                })
                .collect(),
            taking_part: vec![false; self.nodes.len()],
            reproj_view,
        })
    }

    /// Applies every node's frame `t` to its copy; a node without one is held or dropped.
    async fn apply_arrivals(&mut self, work: &mut FrameWork) {
        for i in 0..self.nodes.len() {
            self.apply_arrival(i, work).await;
        }
    }

    /// Applies node `i`'s frame `work.t`, or marks it missing.
    async fn apply_arrival(&mut self, i: usize, work: &mut FrameWork) {
        let t = work.t;
        // A node that faulted keeps nothing it sent before: its next frame is a reset.
        let Some(a) = self
            .buffer
            .remove(&(i, t, false))
            .filter(|_| self.nodes[i].up)
        else {
            work.stats[i].status = self.missing(i);
            return;
        };
        let (width, height) = (self.config.width, self.config.height);
        let n = &mut self.nodes[i];
        if t == n.first_request {
            n.copy = NodeCopy::empty(width, height);
            n.reproj = ReprojCopy::empty(width, height);
        }
        let s = &mut work.stats[i];
        record(s, &a);
        s.status = NodeStatus::Ok;
        match self.apply_message(i, t, a.msg, s, work.reproj_view.as_ref()) {
            Ok(()) => work.taking_part[i] = true,
            Err(what) => {
                self.fault(i, t, format!("{what}; reconnecting")).await;
                work.stats[i].status = self.missing(i);
            }
        }
    }

    /// Applies one frame message to node `i`'s copy; the error says why it does not fit.
    fn apply_message(
        &mut self,
        i: usize,
        t: u64,
        msg: FrameMessage,
        s: &mut NodeFrame,
        reproj_view: Option<&View>,
    ) -> Result<(), String> {
        let (view, projection) = self.camera_for(t);
        let n = &mut self.nodes[i];
        match (msg.changed, msg.stale, msg.removals, reproj_view) {
            (Some(changed), Some(stale), None, None) => {
                n.copy.apply_delta(&changed, &stale, &msg.frame);
                n.spare.put(msg.frame);
            }
            (Some(_), None, Some(_), Some(_))
                if msg.header.view != view || msg.header.projection != projection =>
            {
                return Err(format!(
                    "rendered frame {t} with other matrices than the display sent"
                ));
            }
            (Some(touched), None, Some(removals), Some(v)) => {
                s.removals = removals.total() as u64;
                // On error both ends start over from an empty state.
                tokio::task::block_in_place(|| n.reproj.apply(v, &touched, &removals, &msg.frame))
                    .map_err(|e| e.to_string())?;
                n.depth_error = removals.depth_error();
                // The message's buffers (its inserts) grow into the new copy; the copy it
                // replaces, the size of a full frame, serves the next decode.
                let frame = tokio::task::block_in_place(|| n.reproj.held().frame_into(msg.frame));
                n.spare.put(n.copy.replace(frame));
            }
            (None, None, None, None) => n.spare.put(n.copy.replace(msg.frame)),
            _ => {
                return Err(format!(
                    "sent a frame of another transfer than {}",
                    crate::transfer::name(self.config.transfer)
                ));
            }
        }
        Ok(())
    }

    /// What node `i` contributes to a frame it did not deliver: its last good copy
    /// (`OnFault::Hold`) or nothing (`OnFault::Drop`, which empties the copy).
    fn missing(&mut self, i: usize) -> NodeStatus {
        match self.config.on_fault {
            OnFault::Hold => NodeStatus::Held,
            OnFault::Drop => {
                self.nodes[i].copy = NodeCopy::empty(self.config.width, self.config.height);
                NodeStatus::Dropped
            }
        }
    }

    /// Difference: pixels shared between nodes need current depths from every node there.
    /// Reprojection: so do pixels where reprojected depths of two nodes are too close to order.
    fn needs_fixups(&self) -> bool {
        matches!(
            self.config.transfer,
            Transfer::Difference | Transfer::Reprojection
        ) && self.nodes.len() > 1
    }

    /// Asks the nodes for exact runs where their copies cannot be merged as they are, waits
    /// for the replies and applies them; returns the milliseconds spent outside the wait.
    async fn fixup_round(&mut self, work: &mut FrameWork) -> Result<f64, DisplayError> {
        let start = Instant::now();
        let stale = self.pixels_to_fix(&work.taking_part);
        let mut asked = Vec::new();
        for (i, mask) in stale.into_iter().enumerate() {
            if !mask.is_empty() && self.nodes[i].up {
                work.stats[i].fixup_pixels = u64::from(mask.len());
                self.send_request(i, work.t, RequestKind::Fixup(mask))
                    .await?;
                asked.push(i);
            }
        }
        let mut ms = start.elapsed().as_secs_f64() * 1e3;
        self.wait_for_fixups(work.t, &asked).await;
        let start = Instant::now();
        self.apply_fixups(work, &asked);
        ms += start.elapsed().as_secs_f64() * 1e3;
        Ok(ms)
    }

    /// Per node, the pixels it must send exact runs for.
    fn pixels_to_fix(&self, taking_part: &[bool]) -> Vec<PixelMask> {
        tokio::task::block_in_place(|| {
            if self.config.transfer == Transfer::Difference {
                let copies: Vec<&NodeCopy> = self.nodes.iter().map(|n| &n.copy).collect();
                stale_shared(&copies, taking_part)
            } else {
                let frames: Vec<&DeepFrame> = self.nodes.iter().map(|n| n.copy.frame()).collect();
                let errors: Vec<f32> = self.nodes.iter().map(|n| n.depth_error).collect();
                ambiguous(&frames, &errors, taking_part)
            }
        })
    }

    /// Waits (at most the timeout) for the fixup replies of `asked`; a node that does not
    /// answer in time is reported and reconnected.
    async fn wait_for_fixups(&mut self, t: u64, asked: &[usize]) {
        let deadline = tokio::time::Instant::now() + self.config.timeout;
        while asked
            .iter()
            .any(|&i| self.nodes[i].up && !self.buffer.contains_key(&(i, t, true)))
        {
            match self.next_event(deadline).await {
                Next::Event(e) => self.on_event(e, (t, t + 1)),
                Next::Stop => return,
                Next::Closed | Next::Deadline => {
                    for &i in asked {
                        if !self.buffer.contains_key(&(i, t, true)) {
                            let what = "no fixup reply within the timeout; reconnecting";
                            self.fault(i, t, what.into()).await;
                        }
                    }
                    return;
                }
            }
        }
    }

    /// Applies the fixup replies that arrived to this frame's copies.
    fn apply_fixups(&mut self, work: &mut FrameWork, asked: &[usize]) {
        for &i in asked {
            let Some(a) = self
                .buffer
                .remove(&(i, work.t, true))
                .filter(|_| self.nodes[i].up)
            else {
                continue;
            };
            record(&mut work.stats[i], &a);
            let Some(mask) = &a.msg.changed else {
                continue;
            };
            let copy = &mut self.nodes[i].copy;
            match &work.reproj_view {
                // Exact runs for this frame's composition; the held state stays.
                Some(v) => {
                    let runs = tokio::task::block_in_place(|| v.shade_frame(&a.msg.frame));
                    copy.apply(mask, &runs);
                }
                None => copy.apply(mask, &a.msg.frame),
            }
        }
    }

    /// Merges every node's copy, resolves, and hands the frame to the observer.
    fn compose(&mut self, work: FrameWork, merge_ms: f64) {
        let config = &self.config;
        let resolve_start = Instant::now();
        let copies: Vec<&DeepFrame> = self.nodes.iter().map(|n| n.copy.frame()).collect();
        let image = &mut self.image;
        if (image.width(), image.height()) != (config.width, config.height) {
            *image = Rgb8Image::filled(config.width, config.height, [0; 3]);
        }
        tokio::task::block_in_place(|| {
            merge_resolve_into(&copies, config.scene.background, image);
        });
        let image = &self.image;
        let resolve_ms = resolve_start.elapsed().as_secs_f64() * 1e3;
        let now = Instant::now();
        let interval_ms = self
            .last_composed
            .map_or(0.0, |l| (now - l).as_secs_f64() * 1e3);
        self.first_composed.get_or_insert(now);
        self.last_composed = Some(now);
        let fs = FrameStats {
            frame: work.t,
            fragments_displayed: copies.iter().map(|c| c.fragment_count() as u64).sum(),
            nodes: work.stats,
            merge_ms,
            resolve_ms,
            interval_ms,
            bad_pixels: None,
        };
        let observer = &mut *self.observer;
        tokio::task::block_in_place(|| observer.frame(&fs, image));
        if observer.wants_deep_frames() {
            tokio::task::block_in_place(|| {
                let merged = merge_frames(&copies, config.width, config.height);
                observer.deep_frame(work.t, merged.as_ref());
            });
        }
        if self.keep_history {
            self.per_frame.push(fs);
        }
    }

    /// Reports `what` about node `i` at frame `t` and drops its connection: the link
    /// reconnects and the node starts over from a reset.
    async fn fault(&mut self, i: usize, t: u64, what: String) {
        self.report(i, t, what);
        self.nodes[i].up = false;
        if self.nodes[i].cmd.send(LinkCmd::Reconnect).await.is_err() {
            self.link_gone(i, t);
        }
    }

    /// Tells the observer and keeps the incident for the summary.
    fn report(&mut self, i: usize, t: u64, what: String) {
        let inc = NodeIncident {
            frame: t,
            node: self.nodes[i].addr.clone(),
            what,
        };
        self.observer.incident(&inc);
        if self.keep_history {
            self.incidents.push(inc);
        }
    }

    /// Handles one link event while composing frame `t`; a node that (re)connects joins at
    /// frame `join_at`.
    fn on_event(&mut self, e: LinkEvent, (t, join_at): (u64, u64)) {
        match e {
            LinkEvent::Up(i, generation, hello) => self.on_up(i, generation, &hello, t, join_at),
            LinkEvent::Down(i, generation, reason) => {
                if generation == self.nodes[i].generation {
                    self.nodes[i].up = false;
                    self.report(i, t, format!("down: {reason}"));
                }
            }
            LinkEvent::Arrived(i, generation, a) => self.on_arrival(i, generation, a, t),
        }
    }

    /// A node connected (again): check its scene, start a new generation at `join_at`.
    fn on_up(&mut self, i: usize, generation: u64, hello: &Hello, t: u64, join_at: u64) {
        let n = &mut self.nodes[i];
        if n.refused {
            return;
        }
        if hello.scene != n.scene {
            n.refused = true;
            let what = format!(
                "serves scene '{}', not '{}': left out",
                hello.scene, n.scene
            );
            self.report(i, t, what);
            return;
        }
        n.up = true;
        n.generation = generation;
        self.observer.node_up(&n.addr, hello);
        // It joins with the next frame not yet composed, from a clean state.
        n.next_request = join_at;
        n.first_request = join_at;
        // Whatever the old connection left in the buffer belongs to a chain of deltas that
        // has ended.
        self.buffer.retain(|&(j, _, _), _| j != i);
        if generation > 1 {
            let what = format!(
                "reconnected ({} object(s), {} triangles); restarting from frame {join_at}",
                hello.objects.len(),
                hello.triangles,
            );
            self.report(i, t, what);
        }
    }

    /// A frame message from node `i` arrived: keep it for its frame if it is what was asked.
    fn on_arrival(&mut self, i: usize, generation: u64, a: Box<Arrival>, t: u64) {
        let n = &self.nodes[i];
        if generation != n.generation || !n.up {
            return;
        }
        let f = a.msg.header.frame_number;
        // The view's size (a reprojection frame's inserts are compacted: not the frame's).
        let (width, height) = a.msg.size;
        let node_ok = a.msg.header.node_id as usize == i
            && width == n.copy.frame().width()
            && height == n.copy.frame().height();
        if !node_ok {
            let what = format!(
                "sent frame {f} as node {} at {width}x{height}, not what was asked; reconnecting",
                a.msg.header.node_id,
            );
            self.report(i, t, what);
            self.nodes[i].up = false;
            // A full command queue means the link is already busy reconnecting.
            if let Err(mpsc::error::TrySendError::Closed(_)) =
                self.nodes[i].cmd.try_send(LinkCmd::Reconnect)
            {
                self.link_gone(i, t);
            }
            return;
        }
        if f >= t {
            self.buffer.insert((i, f, a.msg.header.fixup), a);
        }
    }
}

/// Adds what came with an arrival to the node's figures for the frame.
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

/// One node's connection, kept alive: connect, read its hello, forward requests, reconnect.
async fn link(
    node: usize,
    addr: String,
    mut cmds: mpsc::Receiver<LinkCmd>,
    events: mpsc::Sender<LinkEvent>,
    limits: DecodeOptions,
    wait: Duration,
    spare: Spare<DeepFrame>,
) {
    let mut generation = 0u64;
    let mut backoff = Duration::from_millis(100);
    // Report a failure to connect once, not on every retry.
    let mut announced = false;
    loop {
        let connected = connect(&addr, &limits, wait).await;
        let reason = match connected {
            Err(reason) => reason,
            Ok((rd, wr, hello)) => {
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
                let io = (rd, wr, &spare);
                match carry(node, generation, io, &mut cmds, &events, &limits).await {
                    ConnectionEnd::Lost(reason) => reason,
                    ConnectionEnd::Finished => return,
                }
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

/// How a link's connection ended.
enum ConnectionEnd {
    /// It was lost, for this reason: reconnect.
    Lost(LinkError),
    /// The driver is done with the link.
    Finished,
}

/// Writes the driver's requests for connection `generation` and hands the frames that arrive
/// to the driver, until the connection is lost or the driver is done.
async fn carry(
    node: usize,
    generation: u64,
    (rd, mut wr, spare): (OwnedReadHalf, OwnedWriteHalf, &Spare<DeepFrame>),
    cmds: &mut mpsc::Receiver<LinkCmd>,
    events: &mpsc::Sender<LinkEvent>,
    limits: &DecodeOptions,
) -> ConnectionEnd {
    let (in_tx, mut in_rx) = mpsc::channel(4);
    let reader = tokio::spawn(read_frames(rd, limits.clone(), in_tx, spare.clone()));
    let end = loop {
        tokio::select! {
            cmd = cmds.recv() => match cmd {
                None => {
                    // The node may already have closed its end; the run is over either way.
                    let _ = wr.shutdown().await;
                    break ConnectionEnd::Finished;
                }
                Some(LinkCmd::Send(g, bytes)) if g == generation => {
                    if let Err(e) = wr.write_all(&bytes).await {
                        break ConnectionEnd::Lost(LinkError::Send(e));
                    }
                }
                Some(LinkCmd::Send(..)) => {}
                Some(LinkCmd::Reconnect) => {
                    break ConnectionEnd::Lost(LinkError::Disconnected);
                }
            },
            got = in_rx.recv() => match got {
                Some(Ok(a)) => {
                    if events.send(LinkEvent::Arrived(node, generation, a)).await.is_err() {
                        break ConnectionEnd::Finished;
                    }
                }
                Some(Err(reason)) => break ConnectionEnd::Lost(reason),
                None => break ConnectionEnd::Lost(LinkError::ReaderStopped),
            },
        }
    };
    reader.abort();
    end
}

/// Why a link lost (or never got) its connection; reported as "down: …".
#[derive(Debug, thiserror::Error)]
pub(crate) enum LinkError {
    #[error("no connection within {0:.1} s")]
    ConnectTimeout(f64),
    #[error("cannot connect: {0}")]
    Connect(#[source] std::io::Error),
    #[error("connected, but no hello from the node")]
    NoHello,
    #[error("reading the hello: {0}")]
    ReadHello(#[source] ReadError),
    #[error("{0}")]
    Hello(#[source] strata_wire::WireError),
    #[error("expected a hello, got a {0:?} message")]
    NotAHello(MessageType),
    /// The node's error message, as it wrote it.
    #[error("node reported: {0}")]
    NodeReported(String),
    #[error("sending a request: {0}")]
    Send(#[source] std::io::Error),
    #[error("disconnected by the display")]
    Disconnected,
    #[error("the connection's reader stopped")]
    ReaderStopped,
    #[error("the node closed the connection")]
    Closed,
    #[error("reading from the node: {0}")]
    Read(#[source] ReadError),
    #[error("expected the frame's stats, got a {0:?} message")]
    NoStats(MessageType),
    #[error("reading the frame's stats: {0}")]
    ReadStats(#[source] ReadError),
    #[error("malformed stats: {0}")]
    Stats(#[source] strata_wire::WireError),
    #[error("sent a frame that does not decode: {0}")]
    Decode(#[source] strata_wire::WireError),
    #[error("unexpected {0:?} message from a node")]
    Unexpected(MessageType),
    #[error("the frame decoder failed: {0}")]
    Decoder(#[source] tokio::task::JoinError),
}

/// The text of a node's error message (or why it does not decode).
fn node_reported(bytes: &[u8], limits: &DecodeOptions) -> LinkError {
    LinkError::NodeReported(decode_error(bytes, limits).unwrap_or_else(|e| e.to_string()))
}

/// Connects to the node at `addr` and reads its hello, each within `wait`; the error says why
/// the node cannot be used.
pub(crate) async fn connect(
    addr: &str,
    limits: &DecodeOptions,
    wait: Duration,
) -> Result<(OwnedReadHalf, OwnedWriteHalf, Hello), LinkError> {
    let stream = timeout(wait, TcpStream::connect(addr))
        .await
        .map_err(|_| LinkError::ConnectTimeout(wait.as_secs_f64()))?
        .map_err(LinkError::Connect)?;
    // Only latency depends on it.
    let _ = stream.set_nodelay(true);
    let (mut rd, wr) = stream.into_split();
    let m = timeout(wait, read_message(&mut rd, limits))
        .await
        .map_err(|_| LinkError::NoHello)?
        .map_err(LinkError::ReadHello)?;
    let hello = match m.kind {
        MessageType::Hello => Hello::decode(&m.bytes, limits).map_err(LinkError::Hello)?,
        MessageType::Error => return Err(node_reported(&m.bytes, limits)),
        k => return Err(LinkError::NotAHello(k)),
    };
    Ok((rd, wr, hello))
}

/// A frame message's bytes, the stats that followed it, and how long both bodies took to
/// arrive.
pub(crate) type RawFrame = (Vec<u8>, NodeStats, Duration);

/// Memory a later stage is done with, handed back to an earlier one so that the next frame
/// lands in it instead of fresh pages: the frames the driver has applied go back to their
/// node's decoder ([`FrameDecoder::recycle`]), and the message buffers the decoder has read go
/// back to the reader.
#[derive(Clone)]
struct Spare<T>(Arc<std::sync::Mutex<Option<T>>>);

impl<T> Default for Spare<T> {
    fn default() -> Self {
        Spare(Arc::new(std::sync::Mutex::new(None)))
    }
}

impl<T> Spare<T> {
    fn put(&self, value: T) {
        // A poisoned lock only means a panic elsewhere; the slot itself is always valid.
        *self.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(value);
    }

    fn take(&self) -> Option<T> {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

/// Reads frame + stats message pairs and decodes them on the blocking pool, in order.
async fn read_frames(
    mut rd: OwnedReadHalf,
    limits: DecodeOptions,
    out: mpsc::Sender<Result<Box<Arrival>, LinkError>>,
    spare: Spare<DeepFrame>,
) {
    let (raw_tx, raw_rx) = mpsc::channel::<RawFrame>(2);
    let buffers = Spare::default();
    let decoder = tokio::spawn(decode_frames(
        raw_rx,
        limits.clone(),
        out.clone(),
        (spare, buffers.clone()),
    ));
    let failed = loop {
        let buffer = buffers.take().unwrap_or_default();
        match read_frame_and_stats(&mut rd, &limits, buffer).await {
            Ok(raw) => {
                if raw_tx.send(raw).await.is_err() {
                    break None;
                }
            }
            Err(e) => break Some(e),
        }
    };
    drop(raw_tx);
    // The decoder reports what it decoded before the reader's failure.
    let failed = match decoder.await {
        Err(e) if e.is_panic() => Some(LinkError::Decoder(e)),
        _ => failed,
    };
    if let Some(e) = failed {
        // A closed channel means the link has moved on: nobody is left to tell.
        let _ = out.send(Err(e)).await;
    }
}

/// Reads the next frame message and the stats message that follows it.
/// `buffer` is reused for the frame message (see [`read_message_into`]).
pub(crate) async fn read_frame_and_stats(
    rd: &mut OwnedReadHalf,
    limits: &DecodeOptions,
    buffer: Vec<u8>,
) -> Result<RawFrame, LinkError> {
    let m = match read_message_into(rd, limits, buffer).await {
        Ok(m) => m,
        Err(ReadError::Closed) => return Err(LinkError::Closed),
        Err(e) => return Err(LinkError::Read(e)),
    };
    match m.kind {
        MessageType::Frame => {}
        MessageType::Error => return Err(node_reported(&m.bytes, limits)),
        k => return Err(LinkError::Unexpected(k)),
    }
    let s = read_message(rd, limits)
        .await
        .map_err(LinkError::ReadStats)?;
    if s.kind != MessageType::Stats {
        return Err(LinkError::NoStats(s.kind));
    }
    let stats = NodeStats::decode(&s.bytes, limits).map_err(LinkError::Stats)?;
    Ok((m.bytes, stats, m.body_time + s.body_time))
}

/// Decodes each frame on the blocking pool, in order, and hands it on; stops at the first
/// frame that does not decode.
async fn decode_frames(
    mut raw: mpsc::Receiver<RawFrame>,
    limits: DecodeOptions,
    out: mpsc::Sender<Result<Box<Arrival>, LinkError>>,
    (spare, buffers): (Spare<DeepFrame>, Spare<Vec<u8>>),
) {
    // Kept across frames: its buffers, and the frames the driver hands back, are reused
    // instead of fresh pages.
    let mut decoder = FrameDecoder::new();
    while let Some((bytes, stats, transfer)) = raw.recv().await {
        let limits = limits.clone();
        let len = bytes.len() as u64;
        let start = Instant::now();
        let mut d = std::mem::take(&mut decoder);
        let old = spare.take();
        let decoded = tokio::task::spawn_blocking(move || {
            if let Some(old) = old {
                d.recycle(old);
            }
            let msg = d.decode_frame(&bytes, &limits);
            (d, msg, bytes)
        })
        .await
        .map(|(d, msg, bytes)| {
            decoder = d;
            buffers.put(bytes);
            msg
        });
        let decode = start.elapsed();
        let item = match decoded {
            Ok(Ok(msg)) => Ok(Box::new(Arrival {
                msg,
                stats,
                bytes: len,
                transfer,
                decode,
            })),
            Ok(Err(e)) => Err(LinkError::Decode(e)),
            Err(e) => Err(LinkError::Decoder(e)),
        };
        let failed = item.is_err();
        if out.send(item).await.is_err() || failed {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_addresses_are_host_and_port() {
        for good in [
            "127.0.0.1:7400",
            "render-1.lan:1",
            "localhost:65535",
            "[::1]:7400",
        ] {
            assert_eq!(check_address(good), Ok(()), "{good}");
        }
        let no_port = |a: &str| AddressError::NoPort(a.into());
        let port = |a: &str, p: &str| AddressError::Port {
            address: a.into(),
            port: p.into(),
        };
        let host = |a: &str, h: &str| AddressError::Host {
            address: a.into(),
            host: h.into(),
        };
        for (bad, want) in [
            ("not-an-address", no_port("not-an-address")),
            ("127.0.0.1:0", port("127.0.0.1:0", "0")),
            ("127.0.0.1:65536", port("127.0.0.1:65536", "65536")),
            ("127.0.0.1:http", port("127.0.0.1:http", "http")),
            (":7400", host(":7400", "")),
            ("::1:7400", host("::1:7400", "::1")),
            ("[::zz]:7400", host("[::zz]:7400", "[::zz]")),
            ("two words:7400", host("two words:7400", "two words")),
        ] {
            assert_eq!(check_address(bad), Err(want), "{bad}");
        }
    }
}
