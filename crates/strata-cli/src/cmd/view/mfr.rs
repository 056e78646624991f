//! A multi-frame-rate page (`strata view --mfr`): the scene on a slow client, the objects a
//! person points at or drags on the fast client, composed every FC frame (seed 004).
//!
//! ```text
//!  settings (watch: newest wins) ─┐
//!  pointer events (queue, in order)┼─▶ mfr loop, every 1/fc_hz:  spawn_blocking on the shared pool:
//!  questions (queue) ─────────────┘     settings → Live (restarted on a new size or migration;
//!                                        camera → a view event; SC pacing)
//!                                       pointer events → Live::pointer (rays, select, drag)
//!                                       if Live::has_news or the settings changed:
//!                                         FC frame (+ the single renderer and its audit) → PNGs
//!  frame (watch: newest wins) ◀──────── header: FC / SC rates, SC buffer age, who draws what
//! ```
//!
//! The session itself is [`strata_mfr::Live`]: the authority, the SC on its own thread (at low
//! priority, so the FC comes first on a busy machine), the FC's frame. This module paces the FC,
//! measures what the page shows, and answers questions about the composed frame (its pixels'
//! fragments, with the client each came from; its deep EXR).
//!
//! The frame header (`type` "frame") carries `mfr`:
//! `{fc_fps, sc_fps, fc_ms, sc_ms, sc_age_ms, sc_frame, snapshot, composition, migration,
//!   fc_objects, over, selected, moved: [{name, offset}], handle_px, pointer_seq, incidents,
//!   audit}`,
//! where `sc_age_ms` is how much older the SC buffer's state is than the frame's, `handle_px`
//! the pixel of something to grab, `pointer_seq` the newest pointer event the frame shows, and
//! `audit` (with `audit` set) the bad, ghost, hole and blend pixels against the whole scene
//! rendered at once — whose image and bad-pixel map come as the images `reference` and `bad`.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use axum::extract::ws::Message;
use glam::Vec3;
use serde_json::{Value, json};
use strata_mfr::audit::audit_fc_frame;
use strata_mfr::client::Client;
use strata_mfr::simulate::{FcFrame, Migration};
use strata_mfr::{Composition, Live, ObjectState, ScPriority, Snapshot};
use strata_scene::Camera;

use super::Shared;
use super::compare;
use super::probe::{self, Shown};
use super::protocol::{self, MfrJob, PointerInput, Probe};
use super::session::{Inbox, Outbox};
use crate::report::ms;

/// How long a failed session waits before it is rebuilt.
const RETRY_AFTER: Duration = Duration::from_secs(1);

/// Pointer events kept between two FC ticks once coalesced (see [`Page::take_pointer`]).
const MAX_POINTER_WAITING: usize = 256;

/// Runs a multi-frame-rate page until it goes away.
pub(crate) async fn run(mut inbox: Inbox, outbox: Outbox, shared: Arc<Shared>) {
    let mut page = Page::new(shared);
    let mut period = Duration::from_secs_f64(1.0 / 30.0);
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            changed = inbox.mfr.changed() => {
                if changed.is_err() {
                    return;
                }
                let settings = inbox.mfr.borrow_and_update().clone();
                if let Some(s) = &settings {
                    let wanted = Duration::from_secs_f64(1.0 / s.fc_hz);
                    if wanted != period {
                        period = wanted;
                        tick = tokio::time::interval(period);
                        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                    }
                }
                page.next = settings;
                continue;
            }
            Some(p) = inbox.pointer.recv() => {
                page.take_pointer(p);
                while let Ok(p) = inbox.pointer.try_recv() {
                    page.take_pointer(p);
                }
                continue;
            }
            Some(probe) = inbox.probes.recv() => {
                if outbox.answers.is_closed() {
                    return;
                }
                let (p, answer) = blocking(page, move |p| {
                    let answer = p.answer(probe);
                    (p, answer)
                })
                .await;
                let Some(p) = p else {
                    let _ = outbox.answers.send(answer).await;
                    return;
                };
                page = p;
                if outbox.answers.send(answer).await.is_err() {
                    return;
                }
            }
            _ = tick.tick() => {
                if outbox.frames.is_closed() || outbox.answers.is_closed() {
                    return;
                }
                if page.idle() {
                    continue; // nothing new: no worker is woken
                }
                let (p, message) = blocking(page, |mut p| {
                    let message = p.step();
                    (p, message)
                })
                .await;
                let Some(p) = p else {
                    let _ = outbox.answers.send(message.unwrap_or_else(|| bug(None))).await;
                    return;
                };
                page = p;
                let sent = match message {
                    Some(frame @ Message::Binary(_)) => outbox.frames.send(Some(frame)).is_ok(),
                    Some(error) => outbox.answers.send(error).await.is_ok(),
                    None => true,
                };
                if !sent {
                    return;
                }
            }
        }
    }
}

/// Runs `work` on the page in a blocking thread, inside the shared pool; the page back, or
/// `None` (and an error message) if the work panicked.
async fn blocking<T>(
    page: Page,
    work: impl FnOnce(Page) -> (Page, T) + Send + 'static,
) -> (Option<Page>, T)
where
    T: From<Message> + Send + 'static,
{
    let shared = Arc::clone(&page.shared);
    match tokio::task::spawn_blocking(move || shared.pool.install(|| work(page))).await {
        Ok((page, out)) => (Some(page), out),
        Err(_) => (None, T::from(bug(None))),
    }
}

/// The message for a panic: a bug in strata.
fn bug(id: Option<u64>) -> Message {
    Message::Text(
        protocol::error_json(
            id,
            "the multi-frame-rate session failed (a bug in strata: please report it with the \
             scene); reload the page to go on",
        )
        .into(),
    )
}

/// A page's session and what it has shown.
struct Page {
    shared: Arc<Shared>,
    /// Settings received and not yet applied.
    next: Option<MfrJob>,
    /// Settings in force.
    settings: Option<MfrJob>,
    /// Pointer events received and not yet applied.
    pointer: Vec<PointerInput>,
    /// The newest pointer event applied.
    pointer_seq: Option<u64>,
    /// Pointer events were dropped since the last tick.
    pointer_overflow: bool,
    live: Option<Live>,
    /// The state to go on from when the session is rebuilt after an error.
    resume: Option<Arc<Snapshot>>,
    /// Not before this is a failed session rebuilt.
    retry_at: Option<Instant>,
    /// The object to point the page at and its point at rest.
    handle: Option<(usize, Vec3)>,
    /// The single renderer, for the audit.
    reference: Option<Client>,
    /// The last frame sent (for questions) and the settings id it answered.
    shown: Option<(u64, FcFrame)>,
    /// A frame is due whatever the session says (settings changed).
    due: bool,
    fc_times: VecDeque<Instant>,
    sc_counts: VecDeque<(Instant, u64)>,
    /// What went wrong without stopping the session, newest last (at most [`INCIDENTS_SHOWN`]).
    incidents: VecDeque<String>,
}

/// Incidents sent with every frame (the newest).
const INCIDENTS_SHOWN: usize = 10;

impl Page {
    /// Queues a pointer event (see [`coalesce`]); a flood beyond [`MAX_POINTER_WAITING`] is
    /// dropped and reported.
    fn take_pointer(&mut self, p: PointerInput) {
        if !coalesce(&mut self.pointer, p) {
            self.pointer_overflow = true;
        }
    }

    fn new(shared: Arc<Shared>) -> Self {
        Page {
            shared,
            next: None,
            settings: None,
            pointer: Vec::new(),
            pointer_seq: None,
            pointer_overflow: false,
            live: None,
            resume: None,
            retry_at: None,
            handle: None,
            reference: None,
            shown: None,
            due: false,
            fc_times: VecDeque::new(),
            sc_counts: VecDeque::new(),
            incidents: VecDeque::new(),
        }
    }

    /// True when a tick would find nothing to do: no settings or input waiting, and no new
    /// state or SC buffer (checked here, on the async task: it costs microseconds when no
    /// input waits). A session with news is marked due, so the tick's step makes its frame.
    fn idle(&mut self) -> bool {
        if self.next.is_some() || !self.pointer.is_empty() || self.due || self.pointer_overflow {
            return false;
        }
        match self.live.as_mut().map(Live::has_news) {
            Some(true) => {
                self.due = true;
                false
            }
            Some(false) => true,
            // No session: idle until settings come, or one is to be rebuilt and its time came.
            None => self.settings.is_none() || self.retry_at.is_some_and(|t| Instant::now() < t),
        }
    }

    /// One FC tick: the settings and input that came, then a frame if anything changed. `None`
    /// when there is nothing new to show.
    fn step(&mut self) -> Option<Message> {
        let id = self.next.as_ref().or(self.settings.as_ref()).map(|s| s.id);
        match self.try_step() {
            Ok(message) => message,
            Err(e) => {
                // The session is rebuilt a second later (an error that lasts is reported once a
                // second, not every tick), with the objects where they were: from the session
                // that failed, or — when it was a restart that failed — from the state it was
                // to go on from.
                if let Some(live) = self.live.take() {
                    self.resume = Some(live.snapshot());
                }
                self.retry_at = Some(Instant::now() + RETRY_AFTER);
                Some(Message::Text(
                    protocol::error_json(id, &format!("{e:#}")).into(),
                ))
            }
        }
    }

    fn try_step(&mut self) -> Result<Option<Message>> {
        if let Some(next) = self.next.take() {
            self.apply(next)?;
        }
        if self.pointer_overflow {
            self.pointer_overflow = false;
            anyhow::bail!(
                "more than {MAX_POINTER_WAITING} presses and releases arrived within one frame; \
                 some were dropped"
            );
        }
        let Some(settings) = self.settings.clone() else {
            self.pointer.clear(); // no session to point into yet
            return Ok(None);
        };
        let live = match &mut self.live {
            Some(live) => live,
            None => {
                if self.retry_at.is_some_and(|t| Instant::now() < t) {
                    self.pointer.clear(); // nothing to point into until the session is back
                    return Ok(None);
                }
                // The state to go on from is kept until a session has started from it.
                let from = self.resume.clone();
                self.start(&settings, from.as_deref())?;
                self.resume = None;
                self.retry_at = None;
                self.live.as_mut().context("the session did not start")?
            }
        };
        for p in self.pointer.drain(..) {
            live.pointer(p.x, p.y, p.pressed)?;
            self.pointer_seq = p.seq.or(self.pointer_seq);
        }
        if !(live.has_news() || std::mem::take(&mut self.due)) {
            return Ok(None);
        }
        let start = Instant::now();
        let frame = live.frame(settings.composition)?;
        let fc_ms = ms(start.elapsed());
        self.frame_message(&settings, frame, fc_ms).map(Some)
    }

    /// Takes new settings: a new size or migration restarts the session (both clients' buffers
    /// are sized and their shares decided at the start); a new camera is a view event.
    fn apply(&mut self, next: MfrJob) -> Result<()> {
        let restart = self.live.as_ref().is_none_or(|live| {
            live.size() != (next.width, next.height) || live.migration() != next.migration
        });
        if restart {
            // The objects stay where the person left them; only what is held is let go.
            if let Some(live) = self.live.take() {
                self.resume = Some(live.snapshot());
            }
            let from = self.resume.clone();
            self.start(&next, from.as_deref())?;
            self.resume = None;
        }
        let live = self.live.as_mut().context("the session did not start")?;
        let c = &next.camera;
        live.view(c.eye, c.target, c.up)?;
        live.set_sc_interval(Duration::from_secs_f64(next.sc_interval_ms / 1e3));
        self.settings = Some(next);
        self.due = true;
        Ok(())
    }

    fn start(&mut self, settings: &MfrJob, from: Option<&Snapshot>) -> Result<()> {
        let size = (settings.width, settings.height);
        let mut live = Live::start_from(
            Arc::clone(&self.shared.scene),
            size,
            settings.migration,
            ScPriority::Low,
            from,
        )?;
        let c = &settings.camera;
        live.view(c.eye, c.target, c.up)?;
        live.set_sc_interval(Duration::from_secs_f64(settings.sc_interval_ms / 1e3));
        self.handle = live.handle();
        self.reference = None;
        self.shown = None;
        self.pointer.clear();
        self.sc_counts.clear();
        self.live = Some(live);
        self.due = true;
        Ok(())
    }

    /// The frame message: the header of the module docs and the images.
    fn frame_message(&mut self, settings: &MfrJob, frame: FcFrame, fc_ms: f64) -> Result<Message> {
        let live = self.live.as_ref().context("the session did not start")?;
        for incident in live.take_incidents() {
            self.incidents.push_back(incident.what);
            if self.incidents.len() > INCIDENTS_SHOWN {
                self.incidents.pop_front();
            }
        }
        let scene = &self.shared.scene;
        let now = Instant::now();
        let second = Duration::from_secs(1);
        self.fc_times.push_back(now);
        while self.fc_times.front().is_some_and(|&t| now - t > second) {
            self.fc_times.pop_front();
        }
        let sc = live.sc_status();
        self.sc_counts.push_back((now, sc.frames));
        while self.sc_counts.len() > 2
            && self
                .sc_counts
                .front()
                .is_some_and(|&(t, _)| now - t > second)
        {
            self.sc_counts.pop_front();
        }
        let sc_fps = match (self.sc_counts.front(), self.sc_counts.back()) {
            (Some(&(t0, n0)), Some(&(t1, n1))) if t1 > t0 => {
                (n1 - n0) as f64 / (t1 - t0).as_secs_f64()
            }
            _ => 0.0,
        };

        let snapshot = &frame.snapshot;
        let name = |i: usize| scene.objects[i].name.as_str();
        let named = |state: ObjectState| -> Option<&str> {
            snapshot
                .objects
                .iter()
                .position(|o| o.state == state)
                .map(name)
        };
        let moved: Vec<Value> = snapshot
            .objects
            .iter()
            .enumerate()
            .filter(|(_, o)| o.offset != Vec3::ZERO)
            .map(|(i, o)| json!({"name": name(i), "offset": o.offset.to_array()}))
            .collect();
        let view = frame.sc.as_ref().map_or(snapshot.view, |sc| sc.view);
        let handle_px = self.handle.and_then(|(i, at_rest)| {
            let (x, y) = live.project(&view, at_rest + snapshot.objects[i].offset)?;
            Some([x, y])
        });
        let camera = Camera {
            eye: view.eye,
            target: view.target,
            up: view.up,
            ..scene.camera
        };
        let mut mfr = json!({
            "fc_fps": self.fc_times.len(),
            "sc_fps": sc_fps,
            "fc_ms": fc_ms,
            "sc_ms": sc.last_ms,
            "sc_frames": sc.frames,
            "sc_age_ms": frame.sc.as_ref().map(|sc| snapshot.t_ms - sc.snapshot_t_ms),
            "sc_frame": frame.sc.as_ref().map(|sc| sc.sc_frame),
            "snapshot": snapshot.id,
            "composition": composition_name(settings.composition),
            "migration": migration_name(settings.migration),
            "fc_objects": frame.fc_objects.iter().map(|&i| name(i)).collect::<Vec<_>>(),
            "over": named(ObjectState::Over),
            "selected": named(ObjectState::Selected),
            "moved": moved,
            "handle_px": handle_px,
            "pointer_seq": self.pointer_seq,
            "incidents": self.incidents,
            "audit": null,
        });
        let mut images = vec![("main", frame.image.clone())];
        if settings.audit {
            let (w, h) = (settings.width, settings.height);
            let reference = self.reference.get_or_insert_with(|| Client::new(w, h));
            let start = Instant::now();
            let (audit, reference_image) = audit_fc_frame(scene, reference, &frame)?;
            let (_, maps) = compare::compare(&reference_image, &frame.image, false)?;
            mfr["audit"] = json!({
                "bad_pixels": audit.bad_pixels,
                "ghost_pixels": audit.ghost_pixels,
                "hole_pixels": audit.hole_pixels,
                "blend_pixels": audit.blend_pixels,
                "rmse": audit.rmse,
                "ms": ms(start.elapsed()),
            });
            images.push(("reference", reference_image));
            images.extend(maps);
        }
        let start = Instant::now();
        let encoded = protocol::encode_pngs(&images)?;
        let header = json!({
            "type": "frame",
            "id": settings.id,
            "mfr": mfr,
            "camera": protocol::camera_json(&camera),
            "camera_toml": protocol::view_toml(&camera, settings.width, settings.height),
            "render_ms": fc_ms,
            "encode_ms": ms(start.elapsed()),
            "png_bytes": protocol::Part::image_bytes(&encoded, "main"),
        });
        self.shown = Some((settings.id, frame));
        Ok(Message::Binary(
            protocol::frame_message(header, &encoded).into(),
        ))
    }

    /// The answer to a question about the frame shown last: its composed fragments.
    fn answer(&self, probe: Probe) -> Message {
        let Some((id, frame)) = &self.shown else {
            return Message::Text(protocol::error_json(None, "no frame yet").into());
        };
        let composed = match frame.composed() {
            Ok(f) => f,
            Err(e) => {
                let text = format!("cannot compose the frame: {e}");
                return Message::Text(protocol::error_json(Some(*id), &text).into());
            }
        };
        let scene = &self.shared.scene;
        let view = frame.sc.as_ref().map_or(frame.snapshot.view, |sc| sc.view);
        let client = |object| {
            if frame.fc_ids.binary_search(&object).is_ok() {
                "FC".to_owned()
            } else {
                "SC".to_owned()
            }
        };
        let shown = Shown {
            id: *id,
            frame: &composed,
            method: format!("{} composition", composition_name(frame.composition)),
            near_far: (scene.camera.near, scene.camera.far),
            view: view.matrix(),
            projection: scene.camera.projection(composed.width(), composed.height()),
            client: Some(&client),
        };
        probe::answer(scene, probe, &shown)
    }
}

/// Appends `p` to `queue`, coalescing: of each run of events with the button in the same state
/// only the first (a press or a release happens there) and the newest (where the pointer is
/// now) matter — a drag follows the pointer, not its path, and hovering picks under the pointer
/// only. False, and `p` dropped, when [`MAX_POINTER_WAITING`] events wait already.
fn coalesce(queue: &mut Vec<PointerInput>, p: PointerInput) -> bool {
    let n = queue.len();
    if n >= 2 && queue[n - 1].pressed == p.pressed && queue[n - 2].pressed == p.pressed {
        queue[n - 1] = p;
    } else if n < MAX_POINTER_WAITING {
        queue.push(p);
    } else {
        return false;
    }
    true
}

fn composition_name(c: Composition) -> &'static str {
    match c {
        Composition::Deep => "deep",
        Composition::Digital => "digital",
        Composition::Optical => "optical",
    }
}

fn migration_name(m: Migration) -> &'static str {
    match m {
        Migration::Predictive => "predictive",
        Migration::Naive => "naive",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f32, pressed: bool) -> PointerInput {
        PointerInput {
            x,
            y: 0.0,
            pressed,
            seq: Some(x as u64),
        }
    }

    #[test]
    fn pointer_runs_keep_their_first_and_newest_events() {
        let mut queue = Vec::new();
        // hover 1..3, press at 4, drag 5..7, release at 8, hover 9..10
        for (x, pressed) in [
            (1.0, false),
            (2.0, false),
            (3.0, false),
            (4.0, true),
            (5.0, true),
            (6.0, true),
            (7.0, true),
            (8.0, false),
            (9.0, false),
            (10.0, false),
        ] {
            assert!(coalesce(&mut queue, at(x, pressed)));
        }
        let kept: Vec<(f32, bool)> = queue.iter().map(|p| (p.x, p.pressed)).collect();
        assert_eq!(
            kept,
            [
                (1.0, false),
                (3.0, false),
                (4.0, true),
                (7.0, true),
                (8.0, false),
                (10.0, false)
            ]
        );
        // Presses and releases alone cannot be coalesced: the queue has a bound.
        let mut queue = Vec::new();
        let kept = (0..2 * MAX_POINTER_WAITING)
            .filter(|&i| coalesce(&mut queue, at(i as f32, i % 2 == 0)))
            .count();
        assert_eq!(
            (kept, queue.len()),
            (MAX_POINTER_WAITING, MAX_POINTER_WAITING)
        );
    }
}
