//! One page's connection: read its requests, render the latest, send each frame as it is done.
//!
//! ```text
//!  socket ──text──▶ protocol::parse ──Job──▶ watch (latest request) ──▶ render loop
//!    ▲                    │ refused                                          │ spawn_blocking:
//!    │                    ▼                                                  │ store → PNG
//!    └──── error text ◀───┘            watch (latest frame) ◀── frame message┘
//!    └──── frame binary ◀──────────────────────┘
//! ```
//!
//! Both hand-overs are `tokio::sync::watch` channels, which hold one value: a request that
//! arrives while a frame renders replaces any request still waiting, and a frame done while the
//! socket is still sending the previous one replaces any frame still waiting. So a page that
//! moves the camera quickly, or reads slowly over a slow link, gets the newest view next instead
//! of a queue of stale ones. Refusals are answered at once by the connection's own task.
//!
//! A pixel to inspect goes to the render loop through a small queue (it needs the store, which
//! the loop owns between frames) and its answer comes back through another, so neither is ever
//! replaced by a newer request or frame.
//!
//! Each connection has its own store and rasterizer (their buffers reused from frame to frame);
//! all share the server's worker threads. A render that fails or panics becomes an error
//! message for the page; the server and the other pages go on.
//!
//! With `--mfr` the same connection feeds [`super::mfr::run`] instead of the render loop: the
//! page's settings go through a watch like a view's, its pointer events through a queue of
//! [`POINTER_WAITING`] (in order: a press must not overtake the move before it), and frames
//! come back at the fast client's pace through the same frame watch.
//!
//! With `--nodes` it feeds [`super::remote::run`]: the page's settings (camera, size) go through
//! a watch, and frames come back as the display composes them, through the frame watch.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use axum::extract::ws::{Message, WebSocket};
use serde_json::json;
use strata_core::DeepFrame;
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::Camera;
use strata_stores::{FrameResult, Method, render_frame};
use tokio::sync::{mpsc, watch};

use super::Shared;
use super::compare;
use super::probe::{self, Shown};
use super::protocol::{
    self, Job, MethodChoice, MfrJob, Mode, PointerInput, Probe, RemoteJob, Request,
};
use crate::report::{ms, stats_json};

/// Serves one page until it goes away.
pub(crate) async fn run(mut socket: WebSocket, shared: Arc<Shared>) {
    let Some(_seat) = shared.enter() else {
        let message = format!(
            "too many pages are open ({} at most); close one and reload",
            shared.max_pages
        );
        send(
            &mut socket,
            Message::Text(protocol::error_json(None, &message).into()),
        )
        .await;
        return;
    };
    if !send(&mut socket, Message::Text(shared.hello.clone().into())).await {
        return;
    }
    let (job_tx, job_rx) = watch::channel::<Option<Job>>(None);
    let (mfr_tx, mfr_rx) = watch::channel::<Option<MfrJob>>(None);
    let (remote_tx, remote_rx) = watch::channel::<Option<RemoteJob>>(None);
    let (pointer_tx, pointer_rx) = mpsc::channel::<PointerInput>(POINTER_WAITING);
    let (frame_tx, mut frame_rx) = watch::channel::<Option<Message>>(None);
    let (probe_tx, probe_rx) = mpsc::channel::<Probe>(PROBES_WAITING);
    let (answer_tx, mut answer_rx) = mpsc::channel::<Message>(PROBES_WAITING);
    let inbox = Inbox {
        jobs: job_rx,
        mfr: mfr_rx,
        remote: remote_rx,
        pointer: pointer_rx,
        probes: probe_rx,
    };
    let outbox = Outbox {
        frames: frame_tx,
        answers: answer_tx,
    };
    let renderer = match shared.mode() {
        Mode::Views => tokio::spawn(render_loop(inbox, outbox, shared.clone())),
        Mode::Mfr => tokio::spawn(super::mfr::run(inbox, outbox, shared.clone())),
        Mode::Remote => tokio::spawn(super::remote::run(inbox, outbox, shared.clone())),
    };
    let mut heartbeat =
        tokio::time::interval_at(tokio::time::Instant::now() + HEARTBEAT, HEARTBEAT);
    let mut last_heard = Instant::now();
    loop {
        tokio::select! {
            incoming = socket.recv() => {
                last_heard = Instant::now();
                let reply = match incoming {
                    Some(Ok(Message::Text(text))) => match protocol::parse(&text, &shared.scene, shared.mode()) {
                        Ok(Request::View(job)) => {
                            job_tx.send_replace(Some(*job));
                            None
                        }
                        Ok(Request::Mfr(job)) => {
                            mfr_tx.send_replace(Some(*job));
                            None
                        }
                        Ok(Request::Remote(job)) => {
                            remote_tx.send_replace(Some(*job));
                            None
                        }
                        Ok(Request::Pointer(p)) => pointer_tx.try_send(p).err().map(|_| {
                            protocol::error_json(
                                None,
                                "too many pointer events at once; the session is behind",
                            )
                        }),
                        Ok(Request::About(probe)) => probe_tx.try_send(probe).err().map(|_| {
                            protocol::error_json(
                                None,
                                "too many questions at once; wait for the answers",
                            )
                        }),
                        Err(e) => Some(protocol::error_json(
                            protocol::request_id(&text),
                            &format!("{e:#}"),
                        )),
                    },
                    Some(Ok(Message::Binary(_))) => Some(protocol::error_json(
                        None,
                        "binary messages are not understood; send JSON text",
                    )),
                    Some(Ok(Message::Ping(_) | Message::Pong(_))) => None,
                    Some(Ok(Message::Close(_)) | Err(_)) | None => break,
                };
                if let Some(reply) = reply
                    && !send(&mut socket, Message::Text(reply.into())).await
                {
                    break;
                }
            }
            Some(answer) = answer_rx.recv() => {
                if !send(&mut socket, answer).await {
                    break;
                }
            }
            _ = heartbeat.tick() => {
                // A page that went away without closing (a laptop put to sleep, a dropped link)
                // answers no ping: its seat is given back. Browsers answer pings by themselves.
                if last_heard.elapsed() > 3 * HEARTBEAT
                    || !send(&mut socket, Message::Ping(Vec::new().into())).await
                {
                    break;
                }
            }
            changed = frame_rx.changed() => {
                if changed.is_err() {
                    // The render loop ended; its last words (an error) may still be queued.
                    while let Ok(answer) = answer_rx.try_recv() {
                        if !send(&mut socket, answer).await {
                            break;
                        }
                    }
                    break;
                }
                let message = frame_rx.borrow_and_update().clone();
                if let Some(message) = message
                    && !send(&mut socket, message).await
                {
                    break;
                }
            }
        }
    }
    // Every channel to and from the render loop closes, so it ends after the work in hand even
    // if it was waiting to hand over an answer nobody will read; the seat is given back when it
    // has.
    drop((
        job_tx, mfr_tx, remote_tx, pointer_tx, probe_tx, frame_rx, answer_rx,
    ));
    let _ = renderer.await;
}

/// Sends one message; false if the page is gone, or has read nothing for [`SEND_TIMEOUT`] (a
/// page that stops reading would otherwise hold its seat for ever).
async fn send(socket: &mut WebSocket, message: Message) -> bool {
    matches!(
        tokio::time::timeout(SEND_TIMEOUT, socket.send(message)).await,
        Ok(Ok(()))
    )
}

/// How long one message may take to leave: a 4 MB frame at 1 Mbit/s, with room to spare.
const SEND_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(60);

/// How often a quiet page is pinged; one silent for three of these is gone.
const HEARTBEAT: std::time::Duration = std::time::Duration::from_secs(20);

/// Pixels a page may ask about before it has its answers.
const PROBES_WAITING: usize = 8;

/// Pointer events a multi-frame-rate page may send before the session takes them (it takes
/// them all every FC tick).
const POINTER_WAITING: usize = 1024;

/// What the render loop (or the multi-frame-rate loop) receives.
pub(crate) struct Inbox {
    pub(crate) jobs: watch::Receiver<Option<Job>>,
    pub(crate) mfr: watch::Receiver<Option<MfrJob>>,
    pub(crate) remote: watch::Receiver<Option<RemoteJob>>,
    pub(crate) pointer: mpsc::Receiver<PointerInput>,
    pub(crate) probes: mpsc::Receiver<Probe>,
}

/// Where the render loop sends.
pub(crate) struct Outbox {
    pub(crate) frames: watch::Sender<Option<Message>>,
    pub(crate) answers: mpsc::Sender<Message>,
}

/// Renders the latest request whenever there is a new one, and answers pixel questions between
/// frames.
async fn render_loop(mut inbox: Inbox, outbox: Outbox, shared: Arc<Shared>) {
    let mut renderer = Renderer::new(shared);
    loop {
        let work = tokio::select! {
            changed = inbox.jobs.changed() => {
                if changed.is_err() {
                    return;
                }
                let Some(job) = inbox.jobs.borrow_and_update().clone() else {
                    continue;
                };
                Work::Frame(Box::new(job))
            }
            Some(probe) = inbox.probes.recv() => Work::Probe(probe),
        };
        if outbox.frames.is_closed() || outbox.answers.is_closed() {
            return; // the page has gone: no more work for it
        }
        let id = match &work {
            Work::Frame(job) => Some(job.id),
            Work::Probe(..) => None,
        };
        let shared = Arc::clone(&renderer.shared);
        // Everything parallel in the work (render, DeepFrame export, comparison) runs on the
        // server's pool, so `-j` bounds the whole server.
        let done = tokio::task::spawn_blocking(move || {
            let message = shared.pool.install(|| match work {
                Work::Frame(job) => renderer.frame(&job),
                Work::Probe(probe) => renderer.answer(probe),
            });
            (renderer, message)
        })
        .await;
        let sent = match done {
            Ok((r, message)) => {
                renderer = r;
                match id {
                    None => outbox.answers.send(message).await.is_ok(),
                    Some(_) => outbox.frames.send(Some(message)).is_ok(),
                }
            }
            Err(e) => {
                let why = if e.is_panic() {
                    "the render failed (a bug in strata: please report it with the scene and \
                     the view); reload the page to go on"
                } else {
                    "the render was cancelled"
                };
                let _ = outbox
                    .answers
                    .send(Message::Text(protocol::error_json(id, why).into()))
                    .await;
                return;
            }
        };
        if !sent {
            return;
        }
    }
}

/// One piece of work for the render loop.
enum Work {
    Frame(Box<Job>),
    Probe(Probe),
}

/// A page's store and rasterizer, kept from frame to frame.
struct Renderer {
    shared: Arc<Shared>,
    raster: Rasterizer,
    /// The store and the method key it was built for.
    store: Option<(String, Box<dyn Method>)>,
    /// The reference's store, when the page compares.
    reference: Option<(String, Box<dyn Method>)>,
    /// The request id, size and camera of the frame the store holds.
    last: Option<(u64, u32, u32, Camera)>,
}

impl Renderer {
    fn new(shared: Arc<Shared>) -> Self {
        Renderer {
            shared,
            raster: Rasterizer::default(),
            store: None,
            reference: None,
            last: None,
        }
    }

    /// The answer to a question about the latest frame, or an error message.
    fn answer(&self, probe: Probe) -> Message {
        let Some((id, width, height, camera)) = self.last else {
            return Message::Text(protocol::error_json(None, "no frame yet").into());
        };
        let frame = match self.deep_frame() {
            Ok(frame) => frame,
            Err(e) => {
                return Message::Text(protocol::error_json(Some(id), &format!("{e:#}")).into());
            }
        };
        let shown = Shown {
            id,
            frame: &frame,
            method: self
                .store
                .as_ref()
                .map(|(_, s)| s.name().to_owned())
                .unwrap_or_default(),
            near_far: (camera.near, camera.far),
            view: camera.view(),
            projection: camera.projection(width, height),
            client: None,
        };
        probe::answer(&self.shared.scene, probe, &shown)
    }

    /// The latest frame's DeepFrame, or why there is none.
    fn deep_frame(&self) -> Result<DeepFrame> {
        let Some((_, store)) = &self.store else {
            anyhow::bail!("no frame yet");
        };
        match store.deep_frame() {
            None => anyhow::bail!(
                "method {} blends fragments without keeping them: it has no fragment lists",
                store.name()
            ),
            Some(frame) => {
                frame.with_context(|| format!("method {} gave an invalid DeepFrame", store.name()))
            }
        }
    }

    /// The frame message for `job`, or an error message.
    fn frame(&mut self, job: &Job) -> Message {
        match self.render(job) {
            Ok(bytes) => Message::Binary(bytes.into()),
            Err(e) => Message::Text(protocol::error_json(Some(job.id), &format!("{e:#}")).into()),
        }
    }

    fn render(&mut self, job: &Job) -> Result<Vec<u8>> {
        self.last = None;
        let mut scene = (*self.shared.scene).clone();
        scene.width = job.width;
        scene.height = job.height;
        scene.camera = job.camera;
        let input = FrameInput::from_scene(&scene, job.frame);
        let threads = self.shared.pool.current_num_threads();

        let start = Instant::now();
        let slot = self.store.take();
        let (store, result) = self.run(slot, &job.main, &input)?;
        let render_ms = ms(start.elapsed());
        let mut header = json!({
            "type": "frame",
            "id": job.id,
            "stats": stats_json(&scene, store.name(), job.frame, threads, &result),
            "camera": protocol::camera_json(&job.camera),
            "camera_toml": protocol::view_toml(&job.camera, job.width, job.height),
            "render_ms": render_ms,
        });
        let mut images = vec![("main", result.image)];
        // Put back once rendered: a store that failed mid-frame is rebuilt for the next.
        self.store = Some((job.main.key.clone(), store));

        if let Some((choice, with_flip)) = &job.compare {
            let start = Instant::now();
            let slot = self.reference.take();
            let (reference, ref_result) = self.run(slot, choice, &input)?;
            let ref_ms = ms(start.elapsed());
            let start = Instant::now();
            let (mut numbers, maps) =
                compare::compare(&ref_result.image, &images[0].1, *with_flip)?;
            numbers["method"] = json!(reference.name());
            numbers["stats"] =
                stats_json(&scene, reference.name(), job.frame, threads, &ref_result);
            numbers["render_ms"] = json!(ref_ms);
            numbers["compare_ms"] = json!(ms(start.elapsed()));
            header["compare"] = numbers;
            images.push(("reference", ref_result.image));
            images.extend(maps);
            self.reference = Some((choice.key.clone(), reference));
        }

        let start = Instant::now();
        let encoded = protocol::encode_pngs(&images)?;
        header["encode_ms"] = json!(ms(start.elapsed()));
        header["png_bytes"] = json!(protocol::Part::image_bytes(&encoded, "main"));
        self.last = Some((job.id, job.width, job.height, job.camera));
        Ok(protocol::frame_message(header, &encoded))
    }

    /// Renders `input` with the store in `slot` if it was built for `choice`, else a new one.
    fn run(
        &mut self,
        slot: Option<(String, Box<dyn Method>)>,
        choice: &MethodChoice,
        input: &FrameInput<'_>,
    ) -> Result<(Box<dyn Method>, FrameResult)> {
        let mut store = match slot {
            Some((key, store)) if key == choice.key => store,
            _ => strata_stores::create(&choice.method, &choice.options)?,
        };
        let result = render_frame(store.as_mut(), &mut self.raster, input, input.background)?;
        Ok((store, result))
    }
}
