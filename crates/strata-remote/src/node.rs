//! The render node (seed 000 Algorithms A.2, A.4): renders its objects of a scene at the camera
//! the display sends, chooses fragments with the requested transfer method, encodes, sends.
//!
//! # Stages
//!
//! One display connection at a time (a new one is served when the last closes). Per connection:
//!
//! ```text
//! reader task ──render requests──► render thread ──(request, DeepFrame)──► encode thread ──┐
//!      │                           clear, capture,                       select, encode,  │
//!      │                           export DeepFrame                      keep recent      ▼
//!      └──fixup requests──► blocking task: restrict a recent frame, encode ──────────► writer task
//! ```
//!
//! Channels between stages hold at most two items, so while frame *t* is on the wire, *t + 1* is
//! being encoded and *t + 2* rendered: throughput is set by the slowest stage, not their sum. The
//! render thread owns the fragment store and the rasterizer; the encode thread owns the
//! difference state, which must see frames in order. Fixups read the ring of recent frames and do
//! not wait behind renders.
//!
//! Whatever goes wrong with a connection (a malformed request, a store error) is sent to the
//! display as an error message before the connection closes; the node keeps listening.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use strata_core::{DeepFrame, ObjectId, PassTimings};
use strata_raster::{FragmentOutput, FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::{Method, MethodOptions};
use strata_wire::{
    DecodeOptions, FrameHeader, Hello, MessageType, NodeStats, PixelMask, Request, RequestKind,
    TransferMethod, WireError, encode_delta_into, encode_error_into, encode_frame_into,
    encode_reprojection_into, seed_layout_bytes,
};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

use crate::difference::DiffEncoder;
use crate::reprojection::{ReprojEncoder, View};
use crate::select::{depth_limit, restrict};
use crate::stream::{ReadError, read_message};

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
        let input = FrameInput {
            objects: Vec::new(),
            ..FrameInput::from_scene(&self.scene, 0)
        };
        let fail = |e: String| NodeError::Method(format!("method '{}': {e}", self.method));
        m.clear(1, 1).map_err(|e| fail(e.to_string()))?;
        let input = FrameInput {
            width: 1,
            height: 1,
            ..input
        };
        m.capture(&mut Rasterizer::default(), &input, &mut PassTimings::new())
            .map_err(|e| fail(e.to_string()))?;
        match m.deep_frame() {
            Some(Ok(_)) => Ok(()),
            Some(Err(e)) => Err(fail(e.to_string())),
            None => Err(fail(
                "does not keep fragment lists, so it cannot feed a display; use abuffer, \
                 abuffer-array, sbuffer or kbuffer"
                    .into(),
            )),
        }
    }

    fn store(&self) -> Result<Box<dyn Method>, NodeError> {
        strata_stores::create(&self.method, &self.method_options)
            .map_err(|e| NodeError::Method(e.to_string()))
    }

    fn hello(&self) -> Hello {
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
#[derive(Debug, Clone)]
pub enum NodeEvent {
    /// A display connected.
    Connected(String),
    /// The connection ended: cleanly (`None`) or with a reason.
    Closed(String, Option<String>),
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
    frame: DeepFrame,
    render_us: u64,
}

type Recent = Arc<Mutex<VecDeque<(u64, Arc<DeepFrame>)>>>;

/// Serves one display until it disconnects; the error says why the connection ended otherwise.
pub async fn serve_connection(stream: TcpStream, config: NodeConfig) -> Result<(), String> {
    stream.set_nodelay(true).ok();
    let (mut reader, mut writer) = stream.into_split();
    let mut hello = Vec::new();
    config
        .hello()
        .encode_into(&mut hello)
        .map_err(|e| e.to_string())?;
    writer.write_all(&hello).await.map_err(|e| e.to_string())?;

    let (out_tx, mut out_rx) = mpsc::channel::<Vec<u8>>(2);
    let (render_tx, render_rx) = mpsc::channel::<RenderJob>(2);
    let (encode_tx, encode_rx) = mpsc::channel::<EncodeJob>(2);
    let recent: Recent = Arc::new(Mutex::new(VecDeque::new()));

    let render = {
        let config = config.clone();
        let out = out_tx.clone();
        std::thread::Builder::new()
            .name("strata-node-render".into())
            .spawn(move || render_thread(config, render_rx, encode_tx, out))
            .map_err(|e| e.to_string())?
    };
    let encode = {
        let config = config.clone();
        let out = out_tx.clone();
        let recent = recent.clone();
        std::thread::Builder::new()
            .name("strata-node-encode".into())
            .spawn(move || encode_thread(config, encode_rx, out, recent))
            .map_err(|e| e.to_string())?
    };
    let writer_task = tokio::spawn(async move {
        while let Some(bytes) = out_rx.recv().await {
            let is_error = bytes.get(6) == Some(&(MessageType::Error as u8));
            if writer.write_all(&bytes).await.is_err() || is_error {
                break;
            }
        }
        writer.shutdown().await.ok();
    });

    let result = loop {
        let msg = match read_message(&mut reader, &config.limits).await {
            Ok(m) => m,
            Err(ReadError::Closed) => break Ok(()),
            Err(e) => break Err(format!("reading a request: {e}")),
        };
        if msg.kind != MessageType::Request {
            break Err(format!("expected a request, got a {:?} message", msg.kind));
        }
        let request = match Request::decode(&msg.bytes, &config.limits) {
            Ok(r) => r,
            Err(e) => break Err(format!("malformed request: {e}")),
        };
        if request.transfer == TransferMethod::Reprojection
            && !EXACT_STORES.contains(&config.method.as_str())
        {
            break Err(format!(
                "the reprojection transfer needs every fragment with its normal, from one of {}; \
                 this node runs '{}'",
                EXACT_STORES.join(", "),
                config.method
            ));
        }
        match request.kind {
            RequestKind::Render { .. } => {
                if render_tx.send(RenderJob { request }).await.is_err() {
                    break Err("the render stage stopped".into());
                }
            }
            RequestKind::Fixup(ref mask) => {
                let mask = mask.clone();
                let recent = recent.clone();
                let out = out_tx.clone();
                let reply = tokio::task::spawn_blocking(move || fixup(&recent, &request, &mask))
                    .await
                    .map_err(|e| e.to_string())
                    .and_then(|r| r);
                match reply {
                    Ok(bytes) => {
                        if out.send(bytes).await.is_err() {
                            break Err("the connection's writer stopped".into());
                        }
                    }
                    Err(e) => break Err(e),
                }
            }
        }
    };
    if let Err(e) = &result {
        let mut bytes = Vec::new();
        encode_error_into(&mut bytes, &format!("render node: {e}"));
        out_tx.send(bytes).await.ok();
    }
    drop(render_tx);
    drop(out_tx);
    // The stages end when their inputs close; the writer when every sender is gone.
    tokio::task::spawn_blocking(move || {
        render.join().ok();
        encode.join().ok();
    })
    .await
    .ok();
    writer_task.await.ok();
    result
}

fn render_thread(
    config: NodeConfig,
    mut jobs: mpsc::Receiver<RenderJob>,
    encode: mpsc::Sender<EncodeJob>,
    out: mpsc::Sender<Vec<u8>>,
) {
    let fail = |e: String| {
        let mut bytes = Vec::new();
        encode_error_into(&mut bytes, &format!("render node: {e}"));
        out.blocking_send(bytes).ok();
    };
    let mut method = match config.store() {
        Ok(m) => m,
        Err(e) => return fail(e.to_string()),
    };
    let mut raster = Rasterizer::default();
    while let Some(RenderJob { request }) = jobs.blocking_recv() {
        let start = Instant::now();
        let frame_index = u32::try_from(request.frame_number).unwrap_or(u32::MAX);
        let mut input = FrameInput::from_scene(&config.scene, frame_index);
        input.objects.retain(|o| config.objects.contains(&o.id));
        input.width = request.width;
        input.height = request.height;
        input.view = glam::Mat4::from_cols_array(&request.view);
        input.projection = glam::Mat4::from_cols_array(&request.projection);
        if request.transfer == TransferMethod::Reprojection {
            input.output = FragmentOutput::PackedNormal;
        }
        let frame = method
            .clear(input.width, input.height)
            .and_then(|()| method.capture(&mut raster, &input, &mut PassTimings::new()))
            .map_err(|e| e.to_string())
            .and_then(|report| {
                // Reprojection: the display must be able to hold exactly what was rendered.
                if request.transfer == TransferMethod::Reprojection && report.dropped > 0 {
                    return Err(format!(
                        "the store dropped {} fragments; the reprojection transfer needs every \
                         one (use a growing pool: --pool auto)",
                        report.dropped
                    ));
                }
                Ok(())
            })
            .and_then(|()| match method.deep_frame() {
                Some(Ok(f)) => Ok(f),
                Some(Err(e)) => Err(e.to_string()),
                None => Err(format!("method '{}' exports no DeepFrame", config.method)),
            });
        match frame {
            Ok(frame) => {
                let job = EncodeJob {
                    request,
                    frame,
                    render_us: start.elapsed().as_micros() as u64,
                };
                if encode.blocking_send(job).is_err() {
                    return;
                }
            }
            Err(e) => return fail(format!("frame {}: {e}", request.frame_number)),
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

fn encode_thread(
    config: NodeConfig,
    mut jobs: mpsc::Receiver<EncodeJob>,
    out: mpsc::Sender<Vec<u8>>,
    recent: Recent,
) {
    let background = config.scene.background;
    let mut diff = DiffEncoder::new(background, 0);
    let mut reproj = ReprojEncoder::new(0);
    while let Some(EncodeJob {
        request,
        frame,
        render_us,
    }) = jobs.blocking_recv()
    {
        let frame = Arc::new(frame);
        let pixels = u64::from(request.width) * u64::from(request.height);
        let rendered = frame.fragment_count() as u64;
        let header = header_for(&request, false);
        let mut bytes = Vec::new();
        let select_start = Instant::now();
        let (sent, select_us, encode_us, result) = match request.transfer {
            TransferMethod::Difference => {
                if matches!(request.kind, RequestKind::Render { reset: true }) {
                    diff = DiffEncoder::new(background, request.tolerance);
                }
                let d = diff.diff(frame.clone());
                let select_us = select_start.elapsed().as_micros() as u64;
                let t = Instant::now();
                let r = encode_delta_into(
                    &mut bytes,
                    &header,
                    &d.changed,
                    &d.stale,
                    &d.runs,
                    request.codec,
                );
                (
                    d.runs.fragment_count() as u64,
                    select_us,
                    t.elapsed().as_micros() as u64,
                    r,
                )
            }
            TransferMethod::DepthLimited {
                layers,
                opacity_threshold,
            } => {
                let chosen = depth_limit(&frame, layers, opacity_threshold);
                let select_us = select_start.elapsed().as_micros() as u64;
                let t = Instant::now();
                let r = encode_frame_into(&mut bytes, &header, &chosen, request.codec);
                (
                    chosen.fragment_count() as u64,
                    select_us,
                    t.elapsed().as_micros() as u64,
                    r,
                )
            }
            TransferMethod::Reprojection => {
                if matches!(request.kind, RequestKind::Render { reset: true }) {
                    reproj = ReprojEncoder::new(request.tolerance);
                }
                let view = View::new(
                    &config.scene,
                    &config.objects,
                    request.frame_number,
                    (request.width, request.height),
                    glam::Mat4::from_cols_array(&request.view),
                    glam::Mat4::from_cols_array(&request.projection),
                );
                match reproj.encode(&view, &frame) {
                    Ok(d) => {
                        let select_us = select_start.elapsed().as_micros() as u64;
                        let t = Instant::now();
                        let r = encode_reprojection_into(
                            &mut bytes,
                            &header,
                            &d.touched,
                            &d.removals,
                            &d.inserts,
                            request.codec,
                        );
                        (
                            d.inserts.fragment_count() as u64,
                            select_us,
                            t.elapsed().as_micros() as u64,
                            r,
                        )
                    }
                    Err(e) => (0, 0, 0, Err(WireError::Encode(e.to_string()))),
                }
            }
            TransferMethod::Full => {
                let t = Instant::now();
                let r = encode_frame_into(&mut bytes, &header, &frame, request.codec);
                (rendered, 0, t.elapsed().as_micros() as u64, r)
            }
        };
        if let Err(e) = result {
            encode_error_into(
                &mut bytes,
                &format!("render node: encoding frame {}: {e}", request.frame_number),
            );
            out.blocking_send(bytes).ok();
            return;
        }
        let stats = NodeStats {
            frame_number: request.frame_number,
            fragments_rendered: rendered,
            fragments_sent: sent,
            // The seed's layout: 4-byte heads, 12-byte colour or 24-byte normal fragments.
            raw_bytes: if request.transfer == TransferMethod::Reprojection {
                seed_layout_bytes(pixels, sent) + 12 * sent
            } else {
                seed_layout_bytes(pixels, sent)
            },
            render_us,
            select_us,
            encode_us,
            fixup: false,
        };
        append_stats(&mut bytes, &stats);
        {
            let mut r = recent.lock().unwrap_or_else(|e| e.into_inner());
            if r.len() == RECENT_FRAMES {
                r.pop_front();
            }
            r.push_back((request.frame_number, frame));
        }
        if out.blocking_send(bytes).is_err() {
            return;
        }
    }
}

fn append_stats(bytes: &mut Vec<u8>, stats: &NodeStats) {
    let mut s = Vec::new();
    stats.encode_into(&mut s);
    bytes.extend_from_slice(&s);
}

/// The reply to a fixup: exact runs of a recent frame at the requested pixels.
fn fixup(recent: &Recent, request: &Request, mask: &PixelMask) -> Result<Vec<u8>, String> {
    let start = Instant::now();
    let frame = {
        let r = recent.lock().unwrap_or_else(|e| e.into_inner());
        r.iter()
            .find(|(n, _)| *n == request.frame_number)
            .map(|(_, f)| f.clone())
    };
    let Some(frame) = frame else {
        return Err(format!(
            "fixup for frame {}, which is not among the {RECENT_FRAMES} most recent frames",
            request.frame_number
        ));
    };
    let pixels = u64::from(frame.width()) * u64::from(frame.height());
    if u64::from(mask.frame_pixels()) != pixels {
        return Err(format!(
            "fixup mask of {} pixels for a {}x{} frame",
            mask.frame_pixels(),
            frame.width(),
            frame.height()
        ));
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
    .map_err(|e| e.to_string())?;
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
