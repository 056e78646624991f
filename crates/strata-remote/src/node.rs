//! The render node (Jähne 2014 Algorithms A.2, A.4): renders its objects of a scene at the camera
//! the display sends, chooses fragments with the requested transfer method, encodes, sends.
//!
//! # Stages
//!
//! One display connection at a time (a new one is served when the last closes). Per connection:
//!
//! ```text
//! reader task ──render requests──► render thread ──(request, DeepFrame)──► encode thread ──┐
//!      │                           clear, capture,                       select, encode,  │
//!      │                           export DeepFrame ◄──frames off the ring── keep recent  ▼
//!      └──fixup requests──► blocking task: restrict a recent frame, encode ──────────► writer task
//! ```
//!
//! The depth-limited transfer's choice (the nearest N fragments, up to an opacity) is made in
//! the export: the store cuts each sorted run as it gathers it ([`strata_core::RunLimit`]), so
//! the exported frame is what is sent, and the encode thread has nothing to select. Cutting a
//! whole exported frame afterwards took 30–33 ms of a 1280×720 dragon frame beside the next
//! render, on a 2-core AMD EPYC.
//!
//! Channels between stages hold at most two items, so while frame *t* is on the wire, *t + 1* is
//! being encoded and *t + 2* rendered: throughput is set by the slowest stage, not their sum. The
//! render thread owns the fragment store and the rasterizer; the encode thread owns the
//! difference state, which must see frames in order, and a [`FrameEncoder`] whose section
//! buffers serve every frame. Fixups (of the difference and reprojection transfers, whose
//! frames alone are kept) read the ring of recent frames and do not wait behind renders. A
//! frame that leaves the ring, or a frame of another transfer once it is encoded, when nothing
//! else holds it (a fixup being answered), goes back to the render thread over a channel of
//! two, and the next export assembles into its buffers ([`strata_stores::export_frame`]); a
//! message the writer has sent goes back to the
//! encode thread the same way, and the next message is encoded into it: a stream of frames then
//! needs no fresh memory.
//!
//! Whatever goes wrong with a connection (a malformed request, a store error) is sent to the
//! display as an error message before the connection closes; the node keeps listening.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use strata_core::{DeepFrame, ObjectId, RunLimit};
use strata_raster::{FragmentOutput, FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::{ExportError, Method, MethodOptions, check_exports, export_frame};
use strata_wire::{
    DecodeOptions, FrameEncoder, FrameHeader, Hello, MessageType, NodeStats, PixelMask, Request,
    RequestKind, TransferMethod, WireError, encode_delta_into, encode_error_into, message_type,
    seed_layout_bytes,
};
use tokio::io::AsyncWriteExt;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

use crate::difference::DiffEncoder;
use crate::recording::{Recorder, RecordingError};
use crate::reprojection::{ReprojEncoder, TooDeep, View};
use crate::select::restrict;
use crate::stream::{ReadError, read_message};
use crate::{FrameOutOfRange, animation_frame};

/// Stores that keep every fragment whatever its colour bytes hold: the ones a node can render
/// normal fragments with (the others read alpha, which a packed normal does not have, or drop
/// fragments beyond a fixed size, as `abuffer-array` does).
pub const EXACT_STORES: &[&str] = &["abuffer", "sbuffer"];

/// Frames kept for fixup requests.
const RECENT_FRAMES: usize = 8;

/// What a node renders and how.
#[derive(Clone)]
pub struct NodeConfig {
    /// The scene (the node renders only `objects` of it).
    pub scene: Arc<Scene>,
    /// The objects this node renders.
    pub objects: Vec<ObjectId>,
    /// Fragment store (must export DeepFrames: `abuffer`, `abuffer-array`, `sbuffer`, `kbuffer`…).
    pub method: String,
    /// Its options.
    pub method_options: MethodOptions,
    /// Limits on what the node accepts from a display.
    pub limits: DecodeOptions,
    /// Where to record every exchange (request and reply), for a display measured alone
    /// later ([`crate::recording`]); `None`: nothing is recorded.
    pub record: Option<Arc<Recorder>>,
}

/// Why a configuration cannot serve.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// No such store, or it cannot export DeepFrames.
    #[error("{0}")]
    Method(String),
    /// `--objects` names something the scene does not have.
    #[error("{0}")]
    Objects(String),
}

impl NodeConfig {
    /// The objects of `scene` named (or numbered from 0, in scene order) by `selection`; all when
    /// `selection` is empty.
    pub fn select_objects(scene: &Scene, selection: &[String]) -> Result<Vec<ObjectId>, NodeError> {
        if selection.is_empty() {
            return Ok(scene.objects.iter().map(|o| o.id).collect());
        }
        let mut ids = Vec::new();
        for s in selection {
            let found = scene
                .objects
                .iter()
                .enumerate()
                .find(|(i, o)| o.name == *s || s.parse::<usize>() == Ok(*i));
            match found {
                Some((_, o)) if !ids.contains(&o.id) => ids.push(o.id),
                Some(_) => {}
                None => {
                    let names: Vec<String> = scene
                        .objects
                        .iter()
                        .enumerate()
                        .map(|(i, o)| format!("{i}: {}", o.name))
                        .collect();
                    return Err(NodeError::Objects(format!(
                        "scene '{}' has no object '{s}'; its objects are {}",
                        scene.name,
                        names.join(", ")
                    )));
                }
            }
        }
        Ok(ids)
    }

    /// Checks the method exists and exports DeepFrames (by building and capturing an empty frame).
    pub fn check(&self) -> Result<(), NodeError> {
        let mut m = self.store()?;
        let fail = |e: String| NodeError::Method(format!("method '{}': {e}", self.method));
        match check_exports(m.as_mut(), &FrameInput::from_scene(&self.scene, 0)) {
            Ok(()) => Ok(()),
            Err(ExportError::NoDeepFrame(_)) => Err(fail(
                "does not keep fragment lists, so it cannot feed a display; use abuffer, \
                 abuffer-array, sbuffer or kbuffer"
                    .into(),
            )),
            Err(e) => Err(fail(e.to_string())),
        }
    }

    fn store(&self) -> Result<Box<dyn Method>, NodeError> {
        strata_stores::create(&self.method, &self.method_options)
            .map_err(|e| NodeError::Method(e.to_string()))
    }

    /// What the node says first on every connection.
    pub fn hello(&self) -> Hello {
        let objects: Vec<(u32, String)> = self
            .scene
            .objects
            .iter()
            .filter(|o| self.objects.contains(&o.id))
            .map(|o| (o.id.0, o.name.clone()))
            .collect();
        let triangles = self
            .scene
            .objects
            .iter()
            .filter(|o| self.objects.contains(&o.id))
            .map(|o| o.mesh.triangles().len() as u64)
            .sum();
        Hello {
            triangles,
            scene: self.scene.name.clone(),
            objects,
        }
    }
}

/// What happened on a node, for its log.
#[derive(Debug)]
pub enum NodeEvent {
    /// A display connected.
    Connected(String),
    /// The connection ended: cleanly (`None`) or with a reason.
    Closed(String, Option<ConnectionError>),
}

/// Why a display connection ended other than by the display closing it.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConnectionError {
    /// The hello did not encode (a scene or object name too long for the wire).
    #[error("encoding the hello: {0}")]
    HelloEncode(#[source] WireError),
    /// The socket failed.
    #[error("{what}: {source}")]
    Io {
        /// What the node was doing.
        what: &'static str,
        /// The socket's error.
        source: std::io::Error,
    },
    /// A message from the display that is not a well-formed strata message.
    #[error("reading a request: {0}")]
    Wire(#[source] WireError),
    /// A request could not be read for another reason.
    #[error("reading a request: {0}")]
    Read(#[source] ReadError),
    /// A message from the display that is not a request.
    #[error("expected a request, got a {0:?} message")]
    NotARequest(MessageType),
    /// A request that does not decode.
    #[error("malformed request: {0}")]
    Request(#[source] WireError),
    /// A reprojection request to a node whose store may lose fragments or read alpha.
    #[error(
        "the reprojection transfer needs every fragment with its normal, from one of {stores}; \
         this node runs '{method}'",
        stores = EXACT_STORES.join(", ")
    )]
    NeedsExactStore {
        /// The node's store.
        method: String,
    },
    /// A replaying node has no recorded answer to a request.
    #[error("{0}")]
    NotRecorded(String),
    /// The exchange could not be recorded.
    #[error(transparent)]
    Record(#[from] RecordingError),
    /// A fixup request that cannot be answered.
    #[error(transparent)]
    Fixup(#[from] FixupError),
    /// A stage ended before the connection did (it reported why to the display).
    #[error("the {0} stage stopped")]
    StageStopped(&'static str),
    /// A stage's thread could not start.
    #[error("starting the {stage} thread: {source}")]
    Spawn {
        /// The stage.
        stage: &'static str,
        /// Why.
        source: std::io::Error,
    },
    /// A stage panicked: a bug in strata.
    #[error("the {stage} stage panicked: {message}")]
    Panicked {
        /// The stage.
        stage: &'static str,
        /// The panic's message.
        message: String,
    },
}

/// Why a fixup request cannot be answered.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FixupError {
    /// The frame is no longer (or was never) among the recent frames.
    #[error("fixup for frame {0}, which is not among the {RECENT_FRAMES} most recent frames")]
    NotRecent(u64),
    /// The mask is for another frame size.
    #[error("fixup mask of {mask} pixels for a {width}x{height} frame")]
    MaskSize {
        /// Pixels the mask covers.
        mask: u32,
        /// The frame's size.
        width: u32,
        /// The frame's size.
        height: u32,
    },
    /// The reply did not encode.
    #[error("encoding the fixup reply: {0}")]
    Encode(#[source] WireError),
}

/// Serves displays forever, one connection at a time.
pub async fn serve(
    listener: TcpListener,
    config: NodeConfig,
    log: impl Fn(NodeEvent) + Send + Sync + 'static,
) -> std::io::Result<()> {
    config.check().map_err(std::io::Error::other)?;
    let log = Arc::new(log);
    loop {
        let (stream, peer) = listener.accept().await?;
        let peer = peer.to_string();
        log(NodeEvent::Connected(peer.clone()));
        let result = serve_connection(stream, config.clone()).await;
        log(NodeEvent::Closed(peer, result.err()));
    }
}

/// Work for the render thread.
struct RenderJob {
    request: Request,
}

/// Work for the encode thread.
struct EncodeJob {
    request: Request,
    /// The animation frame the request's frame number poses the scene at.
    pose: u32,
    frame: DeepFrame,
    /// Fragments the store held: the frame's, before a depth-limited export cut its runs.
    fragments_rendered: u64,
    render_us: u64,
}

type Recent = Arc<Mutex<VecDeque<(u64, Arc<DeepFrame>)>>>;

/// Serves one display until it disconnects; the error says why the connection ended otherwise.
pub async fn serve_connection(
    stream: TcpStream,
    config: NodeConfig,
) -> Result<(), ConnectionError> {
    // Only latency depends on it.
    let _ = stream.set_nodelay(true);
    let (mut reader, mut writer) = stream.into_split();
    let mut hello = Vec::new();
    config
        .hello()
        .encode_into(&mut hello)
        .map_err(ConnectionError::HelloEncode)?;
    writer
        .write_all(&hello)
        .await
        .map_err(|source| ConnectionError::Io {
            what: "sending the hello",
            source,
        })?;

    let (out_tx, out_rx) = mpsc::channel::<Vec<u8>>(2);
    let (render_tx, render_rx) = mpsc::channel::<RenderJob>(2);
    let (encode_tx, encode_rx) = mpsc::channel::<EncodeJob>(2);
    let recent: Recent = Arc::new(Mutex::new(VecDeque::new()));
    // Frames that left the ring of recent frames and that nothing else holds go back to the
    // render thread, whose exports reuse their buffers.
    let (recycle_tx, recycle_rx) = std::sync::mpsc::sync_channel::<DeepFrame>(2);
    // Messages the writer has sent go back to the encode thread, which encodes the next frames
    // into their buffers.
    let (written_tx, written_rx) = std::sync::mpsc::sync_channel::<Vec<u8>>(2);

    let spawn = |stage: &'static str, f: Box<dyn FnOnce() + Send>| {
        std::thread::Builder::new()
            .name(format!("strata-node-{stage}"))
            .spawn(f)
            .map(|h| (stage, h))
            .map_err(|source| ConnectionError::Spawn { stage, source })
    };
    let render = {
        let (config, out) = (config.clone(), out_tx.clone());
        spawn(
            "render",
            Box::new(move || render_thread(config, render_rx, encode_tx, out, recycle_rx)),
        )?
    };
    let encode = {
        let (config, out, recent) = (config.clone(), out_tx.clone(), recent.clone());
        spawn(
            "encode",
            Box::new(move || encode_thread(config, encode_rx, out, recent, recycle_tx, written_rx)),
        )?
    };
    let writer_task = tokio::spawn(write_messages(writer, out_rx, written_tx));

    let result = serve_requests(&mut reader, &config, &render_tx, &out_tx, &recent).await;
    if let Err(e) = &result {
        let mut bytes = Vec::new();
        encode_error_into(&mut bytes, &format!("render node: {e}"));
        // A closed channel means the writer already stopped: the display is gone.
        let _ = out_tx.send(bytes).await;
    }
    drop(render_tx);
    drop(out_tx);
    // The stages end when their inputs close; the writer when every sender is gone. A stage
    // that panicked is the real reason the connection ended.
    let stages = tokio::task::spawn_blocking(move || join_stages([render, encode]))
        .await
        .map_err(|e| ConnectionError::Panicked {
            stage: "join",
            message: e.to_string(),
        })
        .and_then(|r| r);
    let writer = writer_task.await.map_err(|e| ConnectionError::Panicked {
        stage: "writer",
        message: e.to_string(),
    });
    stages.and(writer).and(result)
}

/// Writes queued messages until every sender is gone, a write fails, or an error message
/// (after which the node closes the connection) is written. Each written message's buffer goes
/// back over `written` for another, if there is room.
async fn write_messages(
    mut writer: OwnedWriteHalf,
    mut queue: mpsc::Receiver<Vec<u8>>,
    written: std::sync::mpsc::SyncSender<Vec<u8>>,
) {
    while let Some(bytes) = queue.recv().await {
        let is_error = message_type(&bytes) == Some(MessageType::Error);
        if writer.write_all(&bytes).await.is_err() || is_error {
            break;
        }
        let _ = written.try_send(bytes);
    }
    // The display may already have closed its end; nothing is left to tell it.
    let _ = writer.shutdown().await;
}

/// Waits for the stage threads; the first that panicked is the error.
fn join_stages(
    stages: [(&'static str, std::thread::JoinHandle<()>); 2],
) -> Result<(), ConnectionError> {
    let mut result = Ok(());
    for (stage, handle) in stages {
        if let Err(panic) = handle.join() {
            let message = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "no message".into());
            result = result.and(Err(ConnectionError::Panicked { stage, message }));
        }
    }
    result
}

/// The display's next request, or `None` when it closed the connection.
pub(crate) async fn next_request(
    reader: &mut OwnedReadHalf,
    limits: &DecodeOptions,
) -> Result<Option<Request>, ConnectionError> {
    let msg = match read_message(reader, limits).await {
        Ok(m) => m,
        Err(ReadError::Closed) => return Ok(None),
        Err(ReadError::Io(source)) => {
            return Err(ConnectionError::Io {
                what: "reading a request",
                source,
            });
        }
        Err(ReadError::Wire(e)) => return Err(ConnectionError::Wire(e)),
        Err(other) => return Err(ConnectionError::Read(other)),
    };
    if msg.kind != MessageType::Request {
        return Err(ConnectionError::NotARequest(msg.kind));
    }
    Request::decode(&msg.bytes, limits)
        .map(Some)
        .map_err(ConnectionError::Request)
}

/// Reads the display's requests and hands them to the stages until the display closes the
/// connection (`Ok`) or something goes wrong.
async fn serve_requests(
    reader: &mut OwnedReadHalf,
    config: &NodeConfig,
    render: &mpsc::Sender<RenderJob>,
    out: &mpsc::Sender<Vec<u8>>,
    recent: &Recent,
) -> Result<(), ConnectionError> {
    loop {
        let Some(request) = next_request(reader, &config.limits).await? else {
            return Ok(());
        };
        if request.transfer == TransferMethod::Reprojection
            && !EXACT_STORES.contains(&config.method.as_str())
        {
            return Err(ConnectionError::NeedsExactStore {
                method: config.method.clone(),
            });
        }
        match request.kind {
            RequestKind::Render { .. } => {
                if render.send(RenderJob { request }).await.is_err() {
                    return Err(ConnectionError::StageStopped("render"));
                }
            }
            RequestKind::Fixup(ref mask) => {
                let mask = mask.clone();
                let recent = recent.clone();
                let record = config.record.clone();
                let reply = tokio::task::spawn_blocking(move || {
                    let reply = fixup(&recent, &request, &mask)?;
                    if let Some(r) = record {
                        r.record(&request, &reply)?;
                    }
                    Ok::<_, ConnectionError>(reply)
                })
                .await
                .map_err(|e| ConnectionError::Panicked {
                    stage: "fixup",
                    message: e.to_string(),
                })??;
                if out.send(reply).await.is_err() {
                    return Err(ConnectionError::StageStopped("writer"));
                }
            }
        }
    }
}

/// Sends `text` to the display as an error message (after which the writer closes the
/// connection).
fn send_error(out: &mpsc::Sender<Vec<u8>>, text: &str) {
    let mut bytes = Vec::new();
    encode_error_into(&mut bytes, &format!("render node: {text}"));
    // A closed channel means the connection is already over.
    let _ = out.blocking_send(bytes);
}

/// Why a frame could not be rendered.
#[derive(Debug, thiserror::Error)]
enum RenderError {
    /// The frame number cannot pose the scene.
    #[error(transparent)]
    Frame(#[from] FrameOutOfRange),
    /// The store failed, or its fragments form no DeepFrame.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// Reprojection: the store lost fragments.
    #[error(
        "the store dropped {0} fragments; the reprojection transfer needs every one (use a \
         growing pool: --pool auto)"
    )]
    Dropped(u64),
}

/// Renders each requested frame with the node's store and hands it to the encode thread.
fn render_thread(
    config: NodeConfig,
    mut jobs: mpsc::Receiver<RenderJob>,
    encode: mpsc::Sender<EncodeJob>,
    out: mpsc::Sender<Vec<u8>>,
    recycled: std::sync::mpsc::Receiver<DeepFrame>,
) {
    let mut method = match config.store() {
        Ok(m) => m,
        Err(e) => return send_error(&out, &e.to_string()),
    };
    let mut raster = Rasterizer::default();
    while let Some(RenderJob { request }) = jobs.blocking_recv() {
        let start = Instant::now();
        let rendered = animation_frame(request.frame_number)
            .map_err(RenderError::from)
            .and_then(|pose| {
                let reuse = recycled.try_recv().ok();
                render(&config, method.as_mut(), &mut raster, &request, pose, reuse)
                    .map(|f| (pose, f))
            });
        let (pose, (frame, fragments_rendered)) = match rendered {
            Ok(r) => r,
            Err(e) => return send_error(&out, &format!("frame {}: {e}", request.frame_number)),
        };
        let job = EncodeJob {
            request,
            pose,
            frame,
            fragments_rendered,
            render_us: start.elapsed().as_micros() as u64,
        };
        if encode.blocking_send(job).is_err() {
            return;
        }
    }
}

/// Renders the node's objects posed at `pose` with the request's camera and size: clear,
/// capture and export the DeepFrame (into the buffers of `reuse`, a frame no longer needed,
/// where the store can), with the fragments the store held.
fn render(
    config: &NodeConfig,
    method: &mut dyn Method,
    raster: &mut Rasterizer,
    request: &Request,
    pose: u32,
    reuse: Option<DeepFrame>,
) -> Result<(DeepFrame, u64), RenderError> {
    let mut input = FrameInput::from_scene(&config.scene, pose);
    input.objects.retain(|o| config.objects.contains(&o.id));
    input.width = request.width;
    input.height = request.height;
    input.view = glam::Mat4::from_cols_array(&request.view);
    input.projection = glam::Mat4::from_cols_array(&request.projection);
    if request.transfer == TransferMethod::Reprojection {
        input.output = FragmentOutput::PackedNormal;
    }
    // Captured and exported in one call: the linked list and the k-buffer gather each strip's
    // fragments as its scan ends, while they are in the cache, keeping what the transfer sends.
    let exported = export_frame(
        method,
        raster,
        &input,
        export_limit(request.transfer),
        reuse,
    )?;
    // Reprojection: the display must be able to hold exactly what was rendered.
    if request.transfer == TransferMethod::Reprojection && exported.capture.dropped > 0 {
        return Err(RenderError::Dropped(exported.capture.dropped));
    }
    Ok((exported.frame, exported.capture.fragments_stored))
}

/// What of each pixel's run a frame rendered for `transfer` keeps: the depth-limited transfer's
/// prefix, every fragment for the others.
fn export_limit(transfer: TransferMethod) -> RunLimit {
    match transfer {
        TransferMethod::DepthLimited {
            layers,
            opacity_threshold,
        } => RunLimit::new(layers, opacity_threshold),
        TransferMethod::Full | TransferMethod::Difference | TransferMethod::Reprojection => {
            RunLimit::NONE
        }
    }
}

fn header_for(request: &Request, fixup: bool) -> FrameHeader {
    FrameHeader {
        frame_number: request.frame_number,
        node_id: request.node_id,
        view: request.view,
        projection: request.projection,
        transfer: request.transfer,
        fixup,
    }
}

/// Why a frame could not be encoded.
#[derive(Debug, thiserror::Error)]
enum EncodeError {
    /// The wire encoder refused it.
    #[error(transparent)]
    Wire(#[from] WireError),
    /// The reprojection delta does not fit the wire format.
    #[error(transparent)]
    Reprojection(#[from] TooDeep),
}

/// The encode thread's state across frames: what the difference and reprojection transfers
/// remember of the frames before.
struct Encoders {
    /// The wire encoder, whose buffers serve frame after frame.
    wire: FrameEncoder,
    background: [f32; 3],
    diff: DiffEncoder,
    reproj: ReprojEncoder,
}

/// What selecting and encoding one frame did.
struct Encoded {
    /// Fragments in the message.
    sent: u64,
    select_us: u64,
    encode_us: u64,
}

/// Selects fragments of `frame` with the request's transfer (the difference and reprojection
/// transfers; a depth-limited frame was cut as it was exported) and encodes them into `bytes`.
fn select_and_encode(
    enc: &mut Encoders,
    config: &NodeConfig,
    request: &Request,
    pose: u32,
    frame: &Arc<DeepFrame>,
    bytes: &mut Vec<u8>,
) -> Result<Encoded, EncodeError> {
    let header = header_for(request, false);
    let reset = matches!(request.kind, RequestKind::Render { reset: true });
    let select_start = Instant::now();
    let micros = |t: Instant| t.elapsed().as_micros() as u64;
    match request.transfer {
        TransferMethod::Difference => {
            if reset {
                enc.diff = DiffEncoder::new(enc.background, request.tolerance);
            }
            let d = enc.diff.diff(frame.clone());
            let select_us = micros(select_start);
            let t = Instant::now();
            enc.wire.encode_delta_into(
                bytes,
                &header,
                &d.changed,
                &d.stale,
                &d.runs,
                request.codec,
            )?;
            Ok(Encoded {
                sent: d.runs.fragment_count() as u64,
                select_us,
                encode_us: micros(t),
            })
        }
        // The export kept only what the transfer sends (`export_limit`): both are sent whole.
        TransferMethod::DepthLimited { .. } | TransferMethod::Full => {
            let t = Instant::now();
            enc.wire
                .encode_frame_into(bytes, &header, frame, request.codec)?;
            Ok(Encoded {
                sent: frame.fragment_count() as u64,
                select_us: 0,
                encode_us: micros(t),
            })
        }
        TransferMethod::Reprojection => {
            if reset {
                enc.reproj = ReprojEncoder::new(request.tolerance);
            }
            let view = View::new(
                &config.scene,
                &config.objects,
                pose,
                (request.width, request.height),
                glam::Mat4::from_cols_array(&request.view),
                glam::Mat4::from_cols_array(&request.projection),
            );
            let d = enc.reproj.encode(&view, frame)?;
            let select_us = micros(select_start);
            let t = Instant::now();
            enc.wire.encode_reprojection_into(
                bytes,
                &header,
                &d.touched,
                &d.removals,
                &d.inserts,
                request.codec,
            )?;
            let sent = d.inserts.fragment_count() as u64;
            enc.reproj.recycle(d);
            Ok(Encoded {
                sent,
                select_us,
                encode_us: micros(t),
            })
        }
    }
}

/// Selects (where the transfer has a choice left), encodes and sends each rendered frame with its
/// stats; keeps it for fixups where its transfer asks for them, else hands it back to the render
/// thread at once.
fn encode_thread(
    config: NodeConfig,
    mut jobs: mpsc::Receiver<EncodeJob>,
    out: mpsc::Sender<Vec<u8>>,
    recent: Recent,
    recycle: std::sync::mpsc::SyncSender<DeepFrame>,
    written: std::sync::mpsc::Receiver<Vec<u8>>,
) {
    let background = config.scene.background;
    let mut enc = Encoders {
        wire: FrameEncoder::new(),
        background,
        diff: DiffEncoder::new(background, 0),
        reproj: ReprojEncoder::new(0),
    };
    while let Some(EncodeJob {
        request,
        pose,
        frame,
        fragments_rendered,
        render_us,
    }) = jobs.blocking_recv()
    {
        let frame = Arc::new(frame);
        // A sent message's buffer where there is one: no fresh pages for the next message.
        let mut bytes = written.try_recv().unwrap_or_default();
        let encoded = match select_and_encode(&mut enc, &config, &request, pose, &frame, &mut bytes)
        {
            Ok(e) => e,
            Err(e) => {
                let text = format!("encoding frame {}: {e}", request.frame_number);
                return send_error(&out, &text);
            }
        };
        let pixels = u64::from(request.width) * u64::from(request.height);
        let sent = encoded.sent;
        let stats = NodeStats {
            frame_number: request.frame_number,
            fragments_rendered,
            fragments_sent: sent,
            // The thesis's layout: 4-byte heads, 12-byte colour or 24-byte normal fragments.
            raw_bytes: if request.transfer == TransferMethod::Reprojection {
                seed_layout_bytes(pixels, sent) + 12 * sent
            } else {
                seed_layout_bytes(pixels, sent)
            },
            render_us,
            select_us: encoded.select_us,
            encode_us: encoded.encode_us,
            fixup: false,
        };
        append_stats(&mut bytes, &stats);
        if let Some(r) = &config.record
            && let Err(e) = r.record(&request, &bytes)
        {
            return send_error(&out, &e.to_string());
        }
        // Only the difference and reprojection transfers ask for fixups; any other frame goes
        // back to the render thread at once, so a stream of them needs no fresh columns after
        // its first frames (and the node holds two or three frames, not the ring's eight).
        let done = if asks_for_fixups(request.transfer) {
            keep_recent(&recent, request.frame_number, frame)
        } else {
            Some(frame)
        };
        if let Some(old) = done
            && let Ok(old) = Arc::try_unwrap(old)
        {
            // A full channel or a render thread that has stopped: the frame is freed here.
            let _ = recycle.try_send(old);
        }
        if out.blocking_send(bytes).is_err() {
            return;
        }
    }
}

/// Whether a display receiving `transfer` may ask for fixups of its frames, which are answered
/// from the ring of recent frames: the difference and reprojection transfers (the display's
/// `needs_fixups`). A fixup of another transfer's frame is answered with `NotRecent`.
fn asks_for_fixups(transfer: TransferMethod) -> bool {
    match transfer {
        TransferMethod::Difference | TransferMethod::Reprojection => true,
        TransferMethod::Full | TransferMethod::DepthLimited { .. } => false,
    }
}

/// Keeps `frame` among the recent frames fixup requests are answered from; returns the frame
/// that leaves the ring to make room, if one does.
fn keep_recent(
    recent: &Recent,
    frame_number: u64,
    frame: Arc<DeepFrame>,
) -> Option<Arc<DeepFrame>> {
    let mut r = recent.lock().unwrap_or_else(|e| e.into_inner());
    let old = if r.len() == RECENT_FRAMES {
        r.pop_front().map(|(_, f)| f)
    } else {
        None
    };
    r.push_back((frame_number, frame));
    old
}

fn append_stats(bytes: &mut Vec<u8>, stats: &NodeStats) {
    let mut s = Vec::new();
    stats.encode_into(&mut s);
    bytes.extend_from_slice(&s);
}

/// The reply to a fixup: exact runs of a recent frame at the requested pixels.
fn fixup(recent: &Recent, request: &Request, mask: &PixelMask) -> Result<Vec<u8>, FixupError> {
    let start = Instant::now();
    let frame = {
        let r = recent.lock().unwrap_or_else(|e| e.into_inner());
        r.iter()
            .find(|(n, _)| *n == request.frame_number)
            .map(|(_, f)| f.clone())
    };
    let Some(frame) = frame else {
        return Err(FixupError::NotRecent(request.frame_number));
    };
    let pixels = u64::from(frame.width()) * u64::from(frame.height());
    if u64::from(mask.frame_pixels()) != pixels {
        return Err(FixupError::MaskSize {
            mask: mask.frame_pixels(),
            width: frame.width(),
            height: frame.height(),
        });
    }
    let runs = restrict(&frame, mask);
    let select_us = start.elapsed().as_micros() as u64;
    let t = Instant::now();
    let mut bytes = Vec::new();
    // The reply is a difference fixup frame under either transfer (see strata-wire's control
    // module): the runs as rendered, replacing nothing the display holds.
    let header = FrameHeader {
        transfer: TransferMethod::Difference,
        ..header_for(request, true)
    };
    encode_delta_into(
        &mut bytes,
        &header,
        mask,
        &PixelMask::empty(mask.frame_pixels()),
        &runs,
        request.codec,
    )
    .map_err(FixupError::Encode)?;
    let stats = NodeStats {
        frame_number: request.frame_number,
        fragments_rendered: frame.fragment_count() as u64,
        fragments_sent: runs.fragment_count() as u64,
        raw_bytes: seed_layout_bytes(pixels, runs.fragment_count() as u64),
        render_us: 0,
        select_us,
        encode_us: t.elapsed().as_micros() as u64,
        fixup: true,
    };
    append_stats(&mut bytes, &stats);
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ring keeps the last [`RECENT_FRAMES`] frames and hands back the one that leaves it,
    /// which the encode thread recycles only when nothing else holds it.
    #[test]
    fn only_transfers_with_fixups_keep_their_frames() {
        assert!(asks_for_fixups(TransferMethod::Difference));
        assert!(asks_for_fixups(TransferMethod::Reprojection));
        assert!(!asks_for_fixups(TransferMethod::Full));
        assert!(!asks_for_fixups(TransferMethod::DepthLimited {
            layers: 6,
            opacity_threshold: Some(0.9),
        }));
    }

    #[test]
    fn the_ring_hands_back_the_frame_that_leaves_it() {
        let recent: Recent = Arc::new(Mutex::new(VecDeque::new()));
        let frames: Vec<Arc<DeepFrame>> = (0..=RECENT_FRAMES as u32)
            .map(|i| Arc::new(DeepFrame::empty(i + 1, 1)))
            .collect();
        for (n, f) in frames.iter().take(RECENT_FRAMES).enumerate() {
            assert!(keep_recent(&recent, n as u64, f.clone()).is_none());
        }
        let last = RECENT_FRAMES as u64;
        let old = keep_recent(&recent, last, frames[RECENT_FRAMES].clone()).expect("one left");
        assert!(
            Arc::ptr_eq(&old, &frames[0]),
            "the oldest frame leaves first"
        );
        let r = recent.lock().unwrap();
        assert_eq!(r.len(), RECENT_FRAMES);
        assert_eq!((r[0].0, r[RECENT_FRAMES - 1].0), (1, last));
        drop(r);
        // Still held here (as a fixup would hold it): not the encode thread's to recycle.
        assert!(Arc::try_unwrap(old).is_err());
    }
}
