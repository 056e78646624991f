//! A remote page (`strata view SCENE --nodes …`): the page is the display of render nodes
//! (seed 000), steered by the person looking at it.
//!
//! ```text
//!  settings (watch: newest wins) ─▶ page task ─▶ Steering: newest settings, questions, gone
//!  questions (queue) ─────────────▶     │              ▲ read by the display's observer
//!                                       │ starts, restarts on a new size, stops
//!                                       ▼
//!  display thread: strata_remote::display::run(nodes, the page's size, PageDisplay)
//!     camera(t)   the newest settings' camera — every node renders frame t through it
//!     stop()      the page went, or asked for another size or transfer (the run restarts)
//!     frame()     PNG + header → frame watch (newest wins), then wait out 1 / max_fps
//!     deep_frame  the merged fragments, asked only while a question waits → its answer
//!     incident()  kept; the newest are sent with every frame
//! ```
//!
//! The display is the same driver as `strata display`'s — links that reconnect, frames
//! requested `--in-flight` ahead, a node that misses a frame held or dropped — on a thread and
//! runtime of its own, so a page's display never stalls the server's sockets. The animation
//! plays: frame *t* poses the scene at *t*, as `strata display` does (a restart at a new size
//! starts again at frame 0). The driver keeps no history for a page (see
//! [`Observer::keep_history`]), and asks [`Observer::stop`] while it waits for silent nodes, so
//! a page that goes gives its seat back within a tenth of a second.
//!
//! The frame header (`type` "frame") carries `remote`:
//! `{frame, fps, transfer, codec, nodes: [NodeFrame…], merge_ms, resolve_ms, interval_ms,
//!   fragments_displayed, bytes, raw_bytes, incidents: [{frame, node, what}…], incident_count}`,
//! where each node's figures are those of `strata display`'s summary.json (its status `ok`,
//! `held` or `dropped`, bytes, fragments rendered and sent, its render, select, encode,
//! transfer and decode milliseconds), and `incidents` the newest [`INCIDENTS_SHOWN`].

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use axum::extract::ws::Message;
use serde_json::{Value, json};
use strata_core::{DeepFrame, DeepFrameError, ObjectId, Rgb8Image};
use strata_remote::display::{self, DisplayConfig, Observer};
use strata_remote::report::{FrameStats, NodeIncident};
use strata_scene::Camera;
use strata_wire::{DecodeOptions, Hello};
use tokio::sync::{mpsc, oneshot, watch};

use super::Shared;
use super::probe::{self, Shown};
use super::protocol::{self, Probe, RemoteJob};
use super::session::{Inbox, Outbox};
use crate::report::ms;

/// Incidents sent with every frame (the newest).
const INCIDENTS_SHOWN: usize = 20;

/// Questions kept while the display has not answered them.
const PROBES_WAITING: usize = 8;

/// How long a display that failed to run waits before it is started again.
const RETRY_AFTER: Duration = Duration::from_secs(1);

/// Frames a remote page's display runs for at most: it ends when the page goes.
const FRAMES: u64 = 1 << 32;

/// What the page task and the display thread share.
struct Steering {
    /// The newest settings.
    settings: Mutex<RemoteJob>,
    /// Questions about the frame, answered with the next frame's merged fragments.
    probes: Mutex<Vec<Probe>>,
    /// Set when the page has gone: the display stops before its next frame.
    gone: AtomicBool,
    /// Incidents so far (the newest [`INCIDENTS_SHOWN`]) and how many in all, over every run.
    incidents: Mutex<(VecDeque<NodeIncident>, u64)>,
    frames: watch::Sender<Option<Message>>,
    answers: mpsc::Sender<Message>,
}

/// Locks a mutex whose data stays valid whatever panicked while it was held.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Steering {
    fn settings(&self) -> RemoteJob {
        lock(&self.settings).clone()
    }
}

/// Runs a remote page until it goes away.
pub(crate) async fn run(mut inbox: Inbox, outbox: Outbox, shared: Arc<Shared>) {
    // Nothing runs until the page says what size and camera it wants.
    let first = loop {
        if inbox.remote.changed().await.is_err() {
            return;
        }
        if let Some(s) = inbox.remote.borrow_and_update().clone() {
            break s;
        }
    };
    let steering = Arc::new(Steering {
        settings: Mutex::new(first),
        probes: Mutex::new(Vec::new()),
        gone: AtomicBool::new(false),
        incidents: Mutex::new((VecDeque::new(), 0)),
        frames: outbox.frames,
        answers: outbox.answers.clone(),
    });
    loop {
        let (done_tx, mut done) = oneshot::channel();
        let started = {
            let (steering, shared) = (steering.clone(), shared.clone());
            std::thread::Builder::new()
                .name("strata-view-display".into())
                .spawn(move || {
                    let _ = done_tx.send(run_display(&shared, steering));
                })
        };
        if let Err(e) = started {
            let text = format!("cannot start the display's thread: {e}");
            let _ = outbox.answers.send(error(None, &text)).await;
            return;
        }
        // Until the run ends: settings and questions go to the display as they come.
        let ended = loop {
            tokio::select! {
                changed = inbox.remote.changed(), if !steering.gone.load(Ordering::Acquire) => {
                    if changed.is_err() {
                        steering.gone.store(true, Ordering::Release);
                        continue; // the run stops before its next frame
                    }
                    if let Some(s) = inbox.remote.borrow_and_update().clone() {
                        *lock(&steering.settings) = s;
                    }
                }
                Some(probe) = inbox.probes.recv() => {
                    let full = {
                        let mut probes = lock(&steering.probes);
                        let full = probes.len() >= PROBES_WAITING;
                        if !full {
                            probes.push(probe);
                        }
                        full
                    };
                    if full {
                        let text = "too many questions at once; wait for the answers";
                        let _ = outbox.answers.try_send(error(None, text));
                    }
                }
                result = &mut done => break result,
            }
        };
        if steering.gone.load(Ordering::Acquire) || steering.frames.is_closed() {
            return;
        }
        match ended {
            // Stopped for a new size or transfer: start again at once.
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let id = Some(steering.settings().id);
                if outbox
                    .answers
                    .send(error(id, &format!("{e:#}")))
                    .await
                    .is_err()
                {
                    return;
                }
                tokio::time::sleep(RETRY_AFTER).await;
            }
            Err(_) => {
                let text = "the display failed (a bug in strata: please report it with the scene \
                            and the nodes); reload the page to go on";
                let _ = outbox.answers.send(error(None, text)).await;
                return;
            }
        }
    }
}

fn error(id: Option<u64>, text: &str) -> Message {
    Message::Text(protocol::error_json(id, text).into())
}

/// Runs the display at the newest settings' size and transfer until it is stopped (the page
/// went, or wants another size or transfer).
fn run_display(shared: &Shared, steering: Arc<Steering>) -> anyhow::Result<()> {
    let remote = shared
        .remote
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("this viewer has no render nodes"))?;
    let settings = steering.settings();
    let link = &remote.link;
    let (transfer, tolerance) = settings.transfer.unwrap_or((link.transfer, link.tolerance));
    let config = DisplayConfig {
        scene: shared.scene.clone(),
        nodes: remote.nodes.clone(),
        transfer,
        codec: link.codec,
        tolerance,
        first_frame: 0,
        frames: FRAMES,
        width: settings.width,
        height: settings.height,
        in_flight: link.in_flight,
        timeout: link.timeout,
        on_fault: link.on_fault,
        limits: DecodeOptions::default(),
    };
    let mut page = PageDisplay {
        shared,
        steering,
        size: (settings.width, settings.height),
        transfer: (transfer, tolerance),
        asked: BTreeMap::new(),
        shown: None,
        sent: VecDeque::new(),
        next_at: None,
        owners: HashMap::new(),
    };
    display::run(config, &mut page)?;
    Ok(())
}

/// The display's observer: steers it from the page's settings and sends it each frame.
struct PageDisplay<'a> {
    shared: &'a Shared,
    steering: Arc<Steering>,
    /// The size this run composes at.
    size: (u32, u32),
    /// The transfer method and tolerance this run asks the nodes for.
    transfer: (strata_remote::Transfer, u8),
    /// Each frame requested and not yet composed: the settings id and camera it was asked with.
    asked: BTreeMap<u64, (u64, Camera)>,
    /// The frame composed last: its number, settings id and camera.
    shown: Option<(u64, u64, Camera)>,
    /// When recent frames were sent, for the rate.
    sent: VecDeque<Instant>,
    /// Not before this is the next frame composed (`max_fps`).
    next_at: Option<Instant>,
    /// The node (address) that renders each object, from the nodes' hellos.
    owners: HashMap<u32, String>,
}

impl PageDisplay<'_> {
    /// The run's transfer method and its options, as `strata display` names them.
    fn label(&self) -> String {
        crate::cmd::display::transfer_label(self.transfer.0, self.transfer.1)
    }

    /// The transfer the page asks for now: its own choice, or the command line's.
    fn wanted_transfer(&self, s: &RemoteJob) -> (strata_remote::Transfer, u8) {
        let link = self.shared.remote.as_ref().map(|r| &r.link);
        s.transfer
            .or(link.map(|l| (l.transfer, l.tolerance)))
            .unwrap_or(self.transfer)
    }

    /// The frame message for a composed frame, or an error message.
    fn message(&mut self, stats: &FrameStats, image: &Rgb8Image) -> Message {
        let Some((_, id, camera)) = self.shown else {
            return error(None, "a frame nobody asked for was composed");
        };
        let remote = self.shared.remote.as_ref();
        let now = Instant::now();
        self.sent.push_back(now);
        while self
            .sent
            .front()
            .is_some_and(|&t| now - t > Duration::from_secs(1))
        {
            self.sent.pop_front();
        }
        let (incidents, incident_count) = {
            let kept = lock(&self.steering.incidents);
            (kept.0.iter().cloned().collect::<Vec<_>>(), kept.1)
        };
        let nodes = serde_json::to_value(&stats.nodes).unwrap_or(Value::Null);
        let remote_json = json!({
            "frame": stats.frame,
            "fps": self.sent.len(),
            "transfer": self.label(),
            "codec": remote.map(|r| r.link.codec.to_string()),
            "nodes": nodes,
            "merge_ms": stats.merge_ms,
            "resolve_ms": stats.resolve_ms,
            "interval_ms": stats.interval_ms,
            "fragments_displayed": stats.fragments_displayed,
            "bytes": stats.bytes(),
            "raw_bytes": stats.raw_bytes(),
            "incidents": incidents
                .iter()
                .map(|i| json!({"frame": i.frame, "node": i.node, "what": i.what}))
                .collect::<Vec<_>>(),
            "incident_count": incident_count,
        });
        let start = Instant::now();
        // Encoded where it lies: the display resolves into the same image every frame.
        let encoded = match protocol::encode_pngs(&[("main", image)]) {
            Ok(encoded) => encoded,
            Err(e) => return error(Some(id), &format!("{e:#}")),
        };
        let (w, h) = self.size;
        let header = json!({
            "type": "frame",
            "id": id,
            "remote": remote_json,
            "camera": protocol::camera_json(&camera),
            "camera_toml": protocol::view_toml(&camera, w, h),
            "render_ms": stats.merge_ms + stats.resolve_ms,
            "encode_ms": ms(start.elapsed()),
            "png_bytes": protocol::Part::image_bytes(&encoded, "main"),
        });
        Message::Binary(protocol::frame_message(header, &encoded).into())
    }
}

impl Observer for PageDisplay<'_> {
    /// A page's display runs until the page goes: it keeps only what the page is shown.
    fn keep_history(&self) -> bool {
        false
    }

    fn camera(&mut self, frame: u64) -> Option<Camera> {
        let s = self.steering.settings();
        self.asked.insert(frame, (s.id, s.camera));
        Some(s.camera)
    }

    fn stop(&mut self) -> bool {
        let s = self.steering.settings();
        self.steering.gone.load(Ordering::Acquire)
            || self.steering.frames.is_closed()
            || (s.width, s.height) != self.size
            || self.wanted_transfer(&s) != self.transfer
    }

    fn frame(&mut self, stats: &FrameStats, image: &Rgb8Image) {
        // Frames are composed in order: what was asked before this one is done with.
        let t = stats.frame;
        let asked = self.asked.remove(&t);
        self.asked.retain(|&f, _| f > t);
        self.shown = asked.map(|(id, camera)| (t, id, camera));
        let message = self.message(stats, image);
        match message {
            frame @ Message::Binary(_) => {
                self.steering.frames.send_replace(Some(frame));
            }
            // A full queue means the page has errors to read already.
            other => {
                let _ = self.steering.answers.try_send(other);
            }
        }
        // Held to max_fps: the driver asks for the next frames only after this returns. The
        // wait is cut short when the page goes or wants another size or transfer.
        let period = Duration::from_secs_f64(1.0 / self.steering.settings().max_fps);
        let now = Instant::now();
        let due = self.next_at.map_or(now, |at| at.max(now));
        while Instant::now() < due && !self.stop() {
            std::thread::sleep(
                due.saturating_duration_since(Instant::now())
                    .min(display::STOP_POLL),
            );
        }
        self.next_at = Some(due + period);
    }

    fn wants_deep_frames(&self) -> bool {
        !lock(&self.steering.probes).is_empty()
    }

    fn deep_frame(&mut self, frame: u64, deep: Result<&DeepFrame, &DeepFrameError>) {
        let probes = std::mem::take(&mut *lock(&self.steering.probes));
        let answers: Vec<Message> = match (deep, self.shown) {
            (Ok(deep), Some((t, id, camera))) if t == frame => {
                let remote = self.shared.remote.as_ref();
                let owners = &self.owners;
                let node = |object: ObjectId| {
                    owners
                        .get(&object.0)
                        .cloned()
                        .unwrap_or_else(|| "no node".to_owned())
                };
                let shown = Shown {
                    id,
                    frame: deep,
                    method: format!(
                        "the display (frame {frame}, {} from {} node(s))",
                        self.label(),
                        remote.map_or(0, |r| r.nodes.len())
                    ),
                    near_far: (camera.near, camera.far),
                    view: camera.view(),
                    projection: camera.projection(deep.width(), deep.height()),
                    client: Some(&node),
                };
                probes
                    .into_iter()
                    .map(|p| probe::answer(&self.shared.scene, p, &shown))
                    .collect()
            }
            (Err(e), _) => {
                let text = format!("cannot merge the nodes' fragments of frame {frame}: {e}");
                probes.iter().map(|_| error(None, &text)).collect()
            }
            _ => probes.iter().map(|_| error(None, "no frame yet")).collect(),
        };
        for a in answers {
            let _ = self.steering.answers.try_send(a);
        }
    }

    fn node_up(&mut self, node: &str, hello: &Hello) {
        for (id, _) in &hello.objects {
            self.owners.insert(*id, node.to_owned());
        }
    }

    fn incident(&mut self, incident: &NodeIncident) {
        let mut kept = lock(&self.steering.incidents);
        kept.0.push_back(incident.clone());
        kept.1 += 1;
        while kept.0.len() > INCIDENTS_SHOWN {
            kept.0.pop_front();
        }
    }
}
