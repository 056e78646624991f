//! A display that discards: it asks the nodes for frames as the display does and drops every
//! message as soon as its last byte has arrived — no decoding, merging or resolving — so the
//! rate it measures is the nodes' own (render, select and encode overlapped) plus the socket.
//! It is how a node is measured alone on a machine too small to host a node and a real display
//! side by side.
//!
//! It sends the display's render requests, not its fixup requests: under the difference and
//! reprojection transfers with nodes whose objects overlap on screen, the display also asks
//! for exact runs of the shared pixels after each frame, and that work of the nodes is left
//! out here. With one node, or nodes that do not overlap, the requests are the display's.
//!
//! # Tasks
//!
//! ```text
//!        ┌─ node 0: connect ─ hello ─ [request t+in_flight ◄─ read frame t + stats, drop] ─┐
//! run ───┤                                                                               ├─► per-frame stats
//!        └─ node n: …                                                                    ┘
//! ```
//!
//! Each node gets its own task and keeps `in_flight` requests outstanding, as the display's
//! driver does; a node is never waited for by another. A node that fails (refuses, stalls past
//! the timeout, reports an error, serves another scene) is recorded as an incident and misses
//! the rest of the run, its frames counted as dropped whatever `on_fault` says; there is no
//! reconnection, because a benchmark with a reconnect in it measures the reconnect.
//!
//! The frames' [`FrameStats`] are the display's, with nothing on the display's side: decode,
//! merge and resolve are 0, and a frame's interval is the time between the arrivals of the last
//! node's message for it and for the frame before.

use std::time::Instant;

use strata_wire::{NodeStats, RequestKind};
use tokio::io::AsyncWriteExt;
use tokio::time::timeout;

use crate::display::{
    DisplayConfig, DisplayError, RunResult, check_config, connect, encode_request,
    read_frame_and_stats, request_camera,
};
use crate::report::{FrameStats, NodeFrame, NodeIncident, NodeStatus};

/// What arrived from one node for one frame.
struct Got {
    at: Instant,
    bytes: u64,
    stats: NodeStats,
    transfer_ms: f64,
}

/// What one node's task brought back: a slot per frame of the run, and why it stopped early.
struct Drained {
    got: Vec<Option<Got>>,
    incident: Option<(u64, String)>,
}

/// Requests `config.frames` frames from every node and drops them on arrival; the result has
/// the display's shape, so the same summary reports it.
///
/// An error means the run could not start; a node that fails is an incident.
pub fn discard(config: DisplayConfig) -> Result<RunResult, DisplayError> {
    check_config(&config)?;
    let camera = request_camera(&config);
    // A request that cannot be encoded is refused before anything connects; the rest are
    // encoded as they are sent, so a long run holds no more than its statistics.
    for node in 0..config.nodes.len() {
        request(&config, &camera, config.first_frame, node)?;
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let drained: Vec<Drained> = runtime.block_on(async {
        let tasks: Vec<_> = (0..config.nodes.len())
            .map(|i| tokio::spawn(drain(config.clone(), camera, i)))
            .collect();
        let mut out = Vec::with_capacity(tasks.len());
        for (i, task) in tasks.into_iter().enumerate() {
            out.push(task.await.unwrap_or_else(|e| Drained {
                got: Vec::new(),
                incident: Some((config.first_frame, format!("node {i}'s task failed: {e}"))),
            }));
        }
        out
    });
    Ok(result(&config, drained))
}

/// Node `node`'s render request for frame `t` of the run, encoded.
fn request(
    config: &DisplayConfig,
    (view, projection): &([f32; 16], [f32; 16]),
    t: u64,
    node: usize,
) -> Result<Vec<u8>, DisplayError> {
    let reset = t == config.first_frame;
    encode_request(
        config,
        (view, projection),
        t,
        node,
        RequestKind::Render { reset },
    )
}

/// One node: connect, keep `in_flight` requests outstanding, read and drop every frame.
async fn drain(config: DisplayConfig, camera: ([f32; 16], [f32; 16]), node: usize) -> Drained {
    let frames = config.frames as usize;
    let mut got: Vec<Option<Got>> = Vec::new();
    let first = config.first_frame;
    let stop = |got: Vec<Option<Got>>, t: u64, what: String| Drained {
        got,
        incident: Some((t, what)),
    };
    let addr = &config.nodes[node];
    let (mut rd, mut wr, hello) = match connect(addr, &config.limits, config.timeout).await {
        Ok(c) => c,
        Err(e) => return stop(got, first, format!("down: {e}")),
    };
    if hello.scene != config.scene.name {
        let what = format!(
            "serves scene '{}', not '{}': left out",
            hello.scene, config.scene.name
        );
        return stop(got, first, what);
    }
    let mut sent = 0;
    // Each message is read into the last one's memory, as a display does.
    let mut buffer = Vec::new();
    for t in 0..frames {
        let frame = first + t as u64;
        while sent < frames && sent < t.saturating_add(config.in_flight) {
            let bytes = match request(&config, &camera, first + sent as u64, node) {
                Ok(b) => b,
                Err(e) => return stop(got, frame, format!("encoding a request: {e}")),
            };
            if let Err(e) = wr.write_all(&bytes).await {
                let what = format!("sending the request for frame {}: {e}", first + sent as u64);
                return stop(got, frame, what);
            }
            sent += 1;
        }
        let (bytes, stats, transfer) = match timeout(
            config.timeout,
            read_frame_and_stats(&mut rd, &config.limits, std::mem::take(&mut buffer)),
        )
        .await
        {
            Ok(Ok(raw)) => raw,
            Ok(Err(e)) => return stop(got, frame, format!("down: {e}")),
            Err(_) => {
                let what = format!(
                    "no frame within {:.1} s: stalled",
                    config.timeout.as_secs_f64()
                );
                return stop(got, frame, what);
            }
        };
        let at = Instant::now();
        if stats.frame_number != frame || stats.fixup {
            let what = format!(
                "sent frame {} (fixup: {}) where frame {frame} was due",
                stats.frame_number, stats.fixup
            );
            return stop(got, frame, what);
        }
        got.push(Some(Got {
            at,
            bytes: bytes.len() as u64,
            stats,
            transfer_ms: transfer.as_secs_f64() * 1e3,
        }));
        buffer = bytes;
    }
    // The node may already have closed its end; the run is over either way.
    let _ = wr.shutdown().await;
    Drained {
        got,
        incident: None,
    }
}

/// The per-frame statistics of a discarding run.
fn result(config: &DisplayConfig, mut drained: Vec<Drained>) -> RunResult {
    let frames = config.frames as usize;
    let ms = |us: u64| us as f64 / 1e3;
    let mut per_frame = Vec::with_capacity(frames);
    let mut last_arrival: Option<Instant> = None;
    let mut first_arrival: Option<Instant> = None;
    for t in 0..frames {
        let mut arrival: Option<Instant> = None;
        let nodes = drained
            .iter_mut()
            .enumerate()
            .map(|(i, d)| {
                let node = config.nodes[i].clone();
                match d.got.get_mut(t).and_then(Option::take) {
                    Some(g) => {
                        arrival = Some(arrival.map_or(g.at, |a| a.max(g.at)));
                        NodeFrame {
                            node,
                            status: NodeStatus::Ok,
                            bytes: g.bytes,
                            raw_bytes: g.stats.raw_bytes,
                            fragments_rendered: g.stats.fragments_rendered,
                            fragments_sent: g.stats.fragments_sent,
                            render_ms: ms(g.stats.render_us),
                            select_ms: ms(g.stats.select_us),
                            encode_ms: ms(g.stats.encode_us),
                            transfer_ms: g.transfer_ms,
                            ..NodeFrame::default()
                        }
                    }
                    None => NodeFrame {
                        node,
                        status: NodeStatus::Dropped,
                        ..NodeFrame::default()
                    },
                }
            })
            .collect();
        let interval_ms = match (arrival, last_arrival) {
            (Some(a), Some(b)) => a.saturating_duration_since(b).as_secs_f64() * 1e3,
            _ => 0.0,
        };
        if arrival.is_some() {
            last_arrival = arrival;
            first_arrival = first_arrival.or(arrival);
        }
        per_frame.push(FrameStats {
            frame: config.first_frame + t as u64,
            nodes,
            interval_ms,
            ..FrameStats::default()
        });
    }
    let incidents = drained
        .iter()
        .enumerate()
        .filter_map(|(i, d)| {
            d.incident.as_ref().map(|(frame, what)| NodeIncident {
                frame: *frame,
                node: config.nodes[i].clone(),
                what: what.clone(),
            })
        })
        .collect();
    let elapsed_s = match (first_arrival, last_arrival) {
        (Some(a), Some(b)) => (b - a).as_secs_f64(),
        _ => 0.0,
    };
    RunResult {
        per_frame,
        incidents,
        elapsed_s,
    }
}
