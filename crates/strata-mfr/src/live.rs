//! A live session: both clients following a person's input as it comes instead of a trace
//! (`strata view --mfr`).
//!
//! ```text
//! page pointer (pixel, pressed) ─► Live::pointer ─► ray through the view on screen ─┐
//! page camera (eye, target, up) ─► Live::view    ─► Event::View                     ├► Authority::push
//!                                                                                    ┘  (stamped now)
//! Live::frame ─► authority.advance_to(now) ─► snapshot ──triple buffer──► SC thread (realtime's)
//!             ◄─ newest SC buffer ◄─────────────────────triple buffer─────┘
//!             ─► fc_frame: the FC's objects through the SC buffer's view, composed ─► FcFrame
//! ```
//!
//! The authority, the SC thread, the triple buffers and the FC's frame are those of
//! [`crate::realtime`]; what differs is where the events come from and who sets the pace: the
//! caller asks for a frame when it can show one ([`Live::has_news`] says whether it would differ
//! from the last), and the SC renders the newest snapshot whenever it is free, optionally held to
//! a slower rate ([`Live::set_sc_interval`]) so a light scene behaves like a heavy one.
//!
//! # Input
//!
//! Events are stamped with the session's clock when they arrive, each at least 10 µs after the
//! last, so their order is kept. A pointer position is a pixel of the frame last shown; its ray
//! goes through that frame's view (the SC buffer's: what the person sees).
//!
//! - Moving without the button: an [`Event::Pointer`]; picking makes the object under it OVER,
//!   and predictive migration hands it to the FC before it is grabbed (the seed's pre-selection).
//! - Pressing: the pointer, then [`Button::Down`], which selects an OVER object. The point of
//!   the object under the pointer is the grab point.
//! - Moving while pressed with an object selected: the object is dragged so the grab point stays
//!   under the pointer, in the plane through it that faces the camera: an [`Event::Drag`] of the
//!   displacement over 1 µs per move. The pointer ray travels with the object (the wand carries
//!   it, as in a trace's drag).
//! - Releasing: [`Button::Up`].

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use glam::{Mat4, Vec3, Vec4Swizzles};
use strata_scene::Scene;

use crate::authority::{Authority, Snapshot, ViewPose};
use crate::client::Client;
use crate::compose::Composition;
use crate::realtime::{Incidents, RealConfig, ScGauge, ScPriority, ScThread};
use crate::simulate::{FcFrame, Migration, SimulateError, fc_frame};
use crate::state::ObjectState;
use crate::trace::{Button, Event, TimedEvent, Trace, TraceError};
use crate::transfer::{Latest, Publisher, TransferBuffer, exchange};

/// The time one live drag step takes (ms).
const STEP_MS: f64 = 1e-3;

/// The least time between two events (ms): ten drag steps, so a step is over, exactly, by the
/// next event whatever the rounding of the times.
const SPACING_MS: f64 = 1e-2;

/// An object being dragged: which, and where its grab point is now.
#[derive(Clone, Copy, Debug)]
struct Grab {
    /// The plane the grab point moves in: a point on it and its normal (the view direction).
    point: Vec3,
    normal: Vec3,
}

/// What the SC has done so far, for a person to read.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScStatus {
    /// SC frames published.
    pub frames: u64,
    /// The last one's render time (ms).
    pub last_ms: f64,
}

/// A live multi-frame-rate session; see the module docs. Dropping it stops the SC thread
/// without waiting for it.
pub struct Live {
    scene: Arc<Scene>,
    size: (u32, u32),
    migration: Migration,
    origin: Instant,
    authority: Authority,
    /// The time of the last event pushed (ms since `origin`).
    last_event_ms: f64,
    snapshots_out: Publisher<Snapshot>,
    published: u64,
    buffers_in: Latest<TransferBuffer>,
    stop: Arc<AtomicBool>,
    sc: Option<ScThread>,
    gauge: Arc<ScGauge>,
    /// What went wrong without stopping the session (the SC's priority could not be lowered).
    incidents: Incidents,
    fc: Client,
    frames: u64,
    /// The snapshot the last frame made showed (`None` before the first).
    framed_snapshot: Option<u64>,
    /// The view of the last frame made (what the person sees), for pointer rays.
    shown_view: ViewPose,
    pressed: bool,
    grab: Option<Grab>,
}

impl Live {
    /// Starts a session on `scene` at `size`: the authority at the scene's camera with every
    /// object at rest, and the SC on its own thread (of `priority`).
    ///
    /// # Errors
    /// The SC thread cannot start.
    pub fn start(
        scene: Arc<Scene>,
        size: (u32, u32),
        migration: Migration,
        priority: ScPriority,
    ) -> Result<Self, SimulateError> {
        Self::start_from(scene, size, migration, priority, None)
    }

    /// Like [`Live::start`], going on from `from` (a snapshot of an earlier session on the same
    /// scene: the view and the objects where it has them, nothing held), e.g. when the page's
    /// size changes.
    pub fn start_from(
        scene: Arc<Scene>,
        size: (u32, u32),
        migration: Migration,
        priority: ScPriority,
        from: Option<&Snapshot>,
    ) -> Result<Self, SimulateError> {
        let origin = Instant::now();
        let (snapshots_out, snapshots_in) = exchange::<Snapshot>();
        let (buffers_out, buffers_in) = exchange::<TransferBuffer>();
        let stop = Arc::new(AtomicBool::new(false));
        let gauge = Arc::new(ScGauge::default());
        let incidents = Incidents::new(origin);
        let mut config = RealConfig::new(size, 0);
        config.migration = migration;
        config.sc_priority = priority;
        let sc = ScThread::spawn(
            Arc::clone(&scene),
            &config,
            snapshots_in,
            buffers_out,
            Arc::clone(&stop),
            &incidents,
            Arc::clone(&gauge),
            false,
        )?;
        let authority = match from {
            Some(snapshot) => Authority::resume(&scene, Trace::default(), snapshot),
            None => Authority::new(&scene, Trace::default()),
        };
        let shown_view = authority.current().view;
        let mut live = Live {
            fc: Client::new(size.0, size.1),
            scene,
            size,
            migration,
            origin,
            authority,
            last_event_ms: 0.0,
            snapshots_out,
            published: u64::MAX,
            buffers_in,
            stop,
            sc: Some(sc),
            gauge,
            incidents,
            frames: 0,
            framed_snapshot: None,
            shown_view,
            pressed: false,
            grab: None,
        };
        live.advance();
        Ok(live)
    }

    /// The frame size.
    pub fn size(&self) -> (u32, u32) {
        self.size
    }

    /// How objects move between the clients.
    pub fn migration(&self) -> Migration {
        self.migration
    }

    /// Milliseconds since the session started.
    pub fn now_ms(&self) -> f64 {
        self.origin.elapsed().as_secs_f64() * 1e3
    }

    /// Holds the SC to at most one frame every `interval` (zero: as fast as it can).
    pub fn set_sc_interval(&self, interval: Duration) {
        self.gauge.set_min_interval(interval);
    }

    /// What went wrong since the last call without stopping the session — the SC's priority
    /// could not be lowered (off Linux, or refused), say — each once.
    pub fn take_incidents(&self) -> Vec<crate::Incident> {
        self.incidents.take()
    }

    /// What the SC has done so far.
    pub fn sc_status(&self) -> ScStatus {
        let (frames, last_ms) = self.gauge.read();
        ScStatus { frames, last_ms }
    }

    /// The newest snapshot.
    pub fn snapshot(&self) -> Arc<Snapshot> {
        self.authority.current()
    }

    /// Moves the camera, if it differs from the newest snapshot's.
    ///
    /// # Errors
    /// `eye` and `target` coincide, or a vector is not finite.
    pub fn view(&mut self, eye: Vec3, target: Vec3, up: Vec3) -> Result<(), TraceError> {
        let finite = eye.is_finite() && target.is_finite() && up.is_finite();
        if !finite || (target - eye).length_squared() == 0.0 || up.length_squared() == 0.0 {
            return Err(TraceError::new(
                "live input",
                "a view needs finite eye, target and up, with target away from eye",
            ));
        }
        let pose = ViewPose { eye, target, up };
        if pose == self.authority.current().view {
            return Ok(());
        }
        self.push(Event::View { eye, target, up })
    }

    /// The pointer at pixel `(x, y)` of the frame last shown (fractions allowed), the button
    /// `pressed` or not; see the module docs for what it does.
    ///
    /// # Errors
    /// The position is not finite.
    pub fn pointer(&mut self, x: f32, y: f32, pressed: bool) -> Result<(), TraceError> {
        if !(x.is_finite() && y.is_finite()) {
            return Err(TraceError::new(
                "live input",
                format!("pointer at ({x}, {y}): expected finite pixel coordinates"),
            ));
        }
        let (origin, dir) = self.ray(x, y);
        match (self.pressed, pressed) {
            (false, false) => self.push(Event::Pointer { origin, dir })?,
            (false, true) => {
                self.push(Event::Pointer { origin, dir })?;
                self.push(Event::Button(Button::Down))?;
                let now = self.advance();
                self.grab = now
                    .objects
                    .iter()
                    .any(|o| o.state == ObjectState::Selected)
                    .then(|| self.authority.nearest_hit_at(origin, dir))
                    .flatten()
                    .map(|(_, t)| Grab {
                        point: origin + dir * t,
                        normal: (self.shown_view.target - self.shown_view.eye).normalize(),
                    });
            }
            (true, true) => {
                if let Some(grab) = &mut self.grab {
                    let facing = dir.dot(grab.normal);
                    let t = (grab.point - origin).dot(grab.normal) / facing;
                    if facing.abs() > 1e-6 && t.is_finite() && t > 0.0 {
                        let to = origin + dir * t;
                        let by = to - grab.point;
                        grab.point = to;
                        if by != Vec3::ZERO {
                            self.push(Event::Drag {
                                by,
                                duration_ms: STEP_MS,
                            })?;
                        }
                    }
                }
            }
            (true, false) => {
                self.grab = None;
                self.push(Event::Button(Button::Up))?;
            }
        }
        self.pressed = pressed;
        Ok(())
    }

    /// Applies the input up to now and hands the SC the newest snapshot if it is new; true if a
    /// frame made now would differ from the last one made (another state than it showed, or a
    /// new SC buffer).
    pub fn has_news(&mut self) -> bool {
        let newest = self.advance().id;
        self.framed_snapshot != Some(newest) || self.buffers_in.updated()
    }

    /// The FC's frame now: input applied up to now, the FC's objects rendered through the newest
    /// SC buffer's view and composed with it as `composition` says.
    ///
    /// # Errors
    /// The FC cannot render or compose, or the SC has stopped on an error.
    pub fn frame(&mut self, composition: Composition) -> Result<FcFrame, SimulateError> {
        if let Some(why) = self.gauge.failure() {
            return Err(SimulateError::Thread(format!(
                "the slow client stopped: {why}"
            )));
        }
        let snapshot = self.advance();
        let sc = self.buffers_in.latest().cloned();
        let work = fc_frame(
            &self.scene,
            &mut self.fc,
            &snapshot,
            sc.as_deref(),
            self.migration,
            composition,
        )?;
        self.shown_view = sc.as_ref().map_or(snapshot.view, |sc| sc.view);
        self.framed_snapshot = Some(snapshot.id);
        let t_ms = snapshot.t_ms;
        let frame = work.into_frame(self.frames, t_ms, snapshot, sc, composition);
        self.frames += 1;
        Ok(frame)
    }

    /// Where pixel `(x, y)` of `view` at this size is, as a ray from the eye: the pixel's
    /// position in world space is the inverse of the camera's projection at a depth inside the
    /// frustum.
    pub fn pixel_ray(&self, view: &ViewPose, x: f32, y: f32) -> (Vec3, Vec3) {
        let (w, h) = (self.size.0 as f32, self.size.1 as f32);
        let clip = self.scene.camera.projection(self.size.0, self.size.1) * view.matrix();
        let inverse: Mat4 = clip.inverse();
        let ndc = glam::Vec4::new(2.0 * x / w - 1.0, 1.0 - 2.0 * y / h, 0.5, 1.0);
        let p = inverse * ndc;
        let point = p.xyz() / p.w;
        let dir = (point - view.eye).normalize_or_zero();
        (view.eye, if dir == Vec3::ZERO { -Vec3::Z } else { dir })
    }

    /// The pixel where world point `p` appears through `view` at this size (fractions kept),
    /// if it lies in front of the eye.
    pub fn project(&self, view: &ViewPose, p: Vec3) -> Option<(f32, f32)> {
        let (w, h) = (self.size.0 as f32, self.size.1 as f32);
        let clip = self.scene.camera.projection(self.size.0, self.size.1) * view.matrix();
        let c = clip * p.extend(1.0);
        (c.w > 0.0).then(|| {
            let (x, y) = (c.x / c.w, c.y / c.w);
            ((x + 1.0) * 0.5 * w, (1.0 - y) * 0.5 * h)
        })
    }

    /// The view of the last frame made (the SC buffer's it composed with): what a person sees.
    pub fn shown_view(&self) -> ViewPose {
        self.shown_view
    }

    /// Something to grab at the start: the first object, in scene order, that a ray from the
    /// scene's eye reaches before any other (what the `grab:` trace takes by default), and the
    /// point of it the ray meets, at rest.
    pub fn handle(&self) -> Option<(usize, Vec3)> {
        let eye = self.scene.camera.eye;
        // Every object at rest, whatever this session has moved.
        let at_rest = Authority::new(&self.scene, Trace::default());
        (0..self.scene.objects.len()).find_map(|i| {
            let dir = crate::trace::aim_at(&self.scene, i, eye)?;
            let (hit, t) = at_rest.nearest_hit_at(eye, dir)?;
            (hit == i).then_some((i, eye + dir * t))
        })
    }

    fn ray(&self, x: f32, y: f32) -> (Vec3, Vec3) {
        self.pixel_ray(&self.shown_view, x, y)
    }

    /// Stamps `event` now (at least [`SPACING_MS`] after the last) and hands it to the
    /// authority.
    fn push(&mut self, event: Event) -> Result<(), TraceError> {
        let t_ms = self.now_ms().max(self.last_event_ms + SPACING_MS);
        self.authority.push(TimedEvent { t_ms, event })?;
        self.last_event_ms = t_ms;
        Ok(())
    }

    /// Applies every event pushed so far (a drag step to its end) and publishes the newest
    /// snapshot if it is new.
    fn advance(&mut self) -> Arc<Snapshot> {
        let t_ms = self.now_ms().max(self.last_event_ms + SPACING_MS);
        let snapshot = self.authority.advance_to(t_ms);
        if snapshot.id != self.published {
            drop(self.snapshots_out.publish(Arc::clone(&snapshot)));
            self.published = snapshot.id;
            if let Some(sc) = &self.sc {
                sc.wake();
            }
        }
        snapshot
    }
}

impl Drop for Live {
    /// Tells the SC thread to stop and returns at once: the SC ends after the frame it is
    /// rendering (seconds for a large frame), joined by a thread of its own, so whoever drops a
    /// session (an async worker, a render worker) never waits for it.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(sc) = self.sc.take() {
            sc.wake();
            // Its result is the SC's timings, of no use now; a failure was shown by `frame`.
            let reaper = std::thread::Builder::new()
                .name("strata-mfr-sc-join".into())
                .spawn(move || drop(sc.join()));
            // Without a thread to join it, the SC is detached: it still stops on its own.
            drop(reaper);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::audit::audit_fc_frame;

    /// A session on `scene` at `size`, predictive, the SC at normal priority.
    fn live(scene: &Arc<Scene>, size: (u32, u32)) -> Live {
        Live::start(
            Arc::clone(scene),
            size,
            Migration::Predictive,
            ScPriority::Normal,
        )
        .expect("start")
    }

    fn scene() -> Arc<Scene> {
        let scene = strata_scene::open_scene("mfr-cars", &strata_scene::SearchPath::default())
            .expect("built-in scene");
        Arc::new(scene)
    }

    /// Frames until the SC has rendered the newest snapshot (the FC composes with it).
    fn settled(live: &mut Live, composition: Composition) -> FcFrame {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let f = live.frame(composition).expect("frame");
            if f.sc
                .as_ref()
                .is_some_and(|sc| sc.snapshot_id == f.snapshot.id)
            {
                return f;
            }
            assert!(Instant::now() < deadline, "the SC never caught up");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The pixel where object `name` is under the pointer, found by scanning the frame.
    fn pixel_on(live: &Live, name: &str) -> (f32, f32) {
        let scene = &live.scene;
        let index = scene
            .objects
            .iter()
            .position(|o| o.name == name)
            .expect("object");
        let (w, h) = live.size;
        for y in (0..h).step_by(4) {
            for x in (0..w).step_by(4) {
                let (o, d) = live.ray(x as f32 + 0.5, y as f32 + 0.5);
                if live.authority.nearest_hit(o, d) == Some(index) {
                    return (x as f32 + 0.5, y as f32 + 0.5);
                }
            }
        }
        panic!("{name} is nowhere on screen");
    }

    #[test]
    fn a_live_drag_moves_the_object_under_the_pointer_and_deep_composition_stays_exact() {
        let scene = scene();
        let mut live = live(&scene, (160, 90));
        let mut reference = Client::new(160, 90);
        settled(&mut live, Composition::Deep);
        let wheel = scene
            .objects
            .iter()
            .position(|o| o.name == "steering wheel")
            .expect("the scene's interactive object");
        let (x, y) = pixel_on(&live, "steering wheel");
        let (o, d) = live.ray(x, y);
        let (_, t) = live.authority.nearest_hit_at(o, d).expect("on the wheel");
        let grabbed = o + d * t;
        live.pointer(x, y, false).expect("hover");
        assert_eq!(live.advance().objects[wheel].state, ObjectState::Over);
        let f = settled(&mut live, Composition::Deep);
        assert!(
            f.fc_objects.contains(&wheel),
            "pre-selection hands the wheel over"
        );
        live.pointer(x, y, true).expect("press");
        assert_eq!(live.advance().objects[wheel].state, ObjectState::Selected);
        // Six pixels to the right: about 0.14 to the right, behind the windscreen.
        for step in 1..=6 {
            live.pointer(x + step as f32, y, true).expect("drag");
        }
        let moved = live.advance().objects[wheel];
        assert!(moved.offset.length() > 0.0 && moved.version > 0);
        // The grab point stayed under the pointer, in the plane facing the camera.
        let (o, d) = live.ray(x + 6.0, y);
        let normal = (live.shown_view.target - live.shown_view.eye).normalize();
        let under = o + d * ((grabbed - o).dot(normal) / d.dot(normal));
        assert!(
            (moved.offset - (under - grabbed)).length() < 1e-4,
            "{} vs {}",
            moved.offset,
            under - grabbed
        );
        assert!(moved.offset.dot(normal).abs() < 1e-4, "moved in the plane");

        let f = settled(&mut live, Composition::Deep);
        assert!(f.fc_objects.contains(&wheel), "the held object is the FC's");
        let (a, _) = audit_fc_frame(&scene, &mut reference, &f).expect("audit");
        assert!(!a.has_artefact(), "deep composition is exact: {a:?}");
        // Colour-and-depth composition loses the wheel behind the windscreen (fig. 6.6).
        let f = settled(&mut live, Composition::Digital);
        let (a, _) = audit_fc_frame(&scene, &mut reference, &f).expect("audit");
        assert!(
            a.hole_pixels > 0,
            "digital composition shows the artefact: {a:?}"
        );

        live.pointer(x + 6.0, y, false).expect("release");
        let s = live.advance();
        assert_eq!(s.objects[wheel].state, ObjectState::Over);
        assert_eq!(
            s.objects[wheel].offset, moved.offset,
            "released where it was left"
        );
        let f = settled(&mut live, Composition::Deep);
        let (a, _) = audit_fc_frame(&scene, &mut reference, &f).expect("audit");
        assert!(!a.has_artefact(), "{a:?}");
    }

    #[test]
    fn pixels_and_rays_are_inverse_and_the_handle_is_under_its_pixel() {
        let live = live(&scene(), (160, 90));
        let view = live.shown_view();
        for (x, y) in [(0.5, 0.5), (80.0, 45.0), (159.5, 10.25)] {
            let (o, d) = live.pixel_ray(&view, x, y);
            let (px, py) = live.project(&view, o + d * 3.0).expect("in front");
            assert!(
                (px - x).abs() < 1e-3 && (py - y).abs() < 1e-3,
                "{x},{y}: {px},{py}"
            );
        }
        assert_eq!(
            live.project(&view, view.eye * 2.0 - view.target),
            None,
            "behind"
        );
        let (index, point) = live.handle().expect("something to grab");
        assert_eq!(live.scene.objects[index].name, "steering wheel");
        let (x, y) = live.project(&view, point).expect("on screen");
        let (o, d) = live.pixel_ray(&view, x, y);
        assert_eq!(live.authority.nearest_hit(o, d), Some(index));
    }

    #[test]
    fn a_restarted_session_keeps_the_objects_where_they_were_left() {
        let scene = scene();
        let mut live = live(&scene, (160, 90));
        let (index, point) = live.handle().expect("something to grab");
        let (x, y) = live.project(&live.shown_view(), point).expect("on screen");
        live.pointer(x, y, false).expect("hover");
        live.pointer(x, y, true).expect("press");
        live.pointer(x + 5.0, y, true).expect("drag");
        let before = live.advance();
        assert!(before.objects[index].offset.x > 0.0);
        let mut again = Live::start_from(
            scene,
            (320, 180),
            Migration::Naive,
            ScPriority::Normal,
            Some(&before),
        )
        .expect("restart");
        let s = again.advance();
        assert_eq!(s.objects[index].offset, before.objects[index].offset);
        assert_eq!(
            again.handle(),
            Some((index, point)),
            "the handle is at rest"
        );
        assert_eq!(
            s.objects[index].state,
            ObjectState::Inactive,
            "nothing held"
        );
        assert_eq!(s.view, before.view);
        let f = settled(&mut again, Composition::Deep);
        assert_eq!(f.image.width(), 320);
    }

    #[test]
    fn live_input_is_forgotten_once_applied_but_still_counted() {
        let scene = scene();
        let mut authority = Authority::new(&scene, Trace::default());
        let (origin, dir) = (scene.camera.eye, Vec3::NEG_Z);
        for i in 0..3000 {
            let event = TimedEvent {
                t_ms: i as f64,
                event: Event::Pointer { origin, dir },
            };
            authority.push(event).expect("in order");
            if i % 7 == 0 {
                authority.advance_to(i as f64);
            }
        }
        assert_eq!(authority.advance_to(3000.0).events_applied, 3000);
        let late = TimedEvent {
            t_ms: 10.0,
            event: Event::Pointer { origin, dir },
        };
        assert!(authority.push(late).is_err(), "before the newest snapshot");
        let light = TimedEvent {
            t_ms: 4000.0,
            event: Event::Light {
                id: 0,
                motion: crate::trace::LightMotion::At(Vec3::ZERO),
                color: [1.0; 3],
                range: 1.0,
            },
        };
        assert!(authority.push(light).is_err(), "lights are keyed up front");
        let at = |event| TimedEvent {
            t_ms: 5000.0,
            event,
        };
        for bad in [
            Event::Drag {
                by: Vec3::X,
                duration_ms: 0.0,
            },
            Event::Drag {
                by: Vec3::NAN,
                duration_ms: 1.0,
            },
            Event::Pointer {
                origin,
                dir: Vec3::ZERO,
            },
            Event::View {
                eye: origin,
                target: origin,
                up: Vec3::Y,
            },
        ] {
            let e = authority.push(at(bad)).expect_err("refused");
            assert!(e.to_string().starts_with("live input: "), "{e}");
        }
        assert_eq!(
            authority.advance_to(6000.0).events_applied,
            3000,
            "none of them applied"
        );
    }

    #[test]
    fn news_comes_with_input_and_with_sc_buffers_only() {
        let mut live = live(&scene(), (64, 36));
        settled(&mut live, Composition::Deep);
        assert!(!live.has_news(), "nothing changed since the settled frame");
        let s = live.snapshot();
        live.view(s.view.eye + Vec3::X * 0.1, s.view.target, s.view.up)
            .expect("view");
        assert!(live.has_news());
        assert!(
            live.view(Vec3::ONE, Vec3::ONE, Vec3::Y).is_err(),
            "eye at the target"
        );
        // A press that does not move (it selects: the state changes) is news too, though
        // taking it applies it at once.
        settled(&mut live, Composition::Deep);
        let (_, point) = live.handle().expect("something to grab");
        let (x, y) = live.project(&live.shown_view(), point).expect("on screen");
        live.pointer(x, y, false).expect("hover");
        settled(&mut live, Composition::Deep);
        assert!(!live.has_news());
        live.pointer(x, y, true).expect("press");
        assert!(live.has_news(), "the selection is news");
        assert!(live.pointer(f32::NAN, 0.0, false).is_err());
    }

    #[test]
    fn a_paced_sc_is_no_faster_than_asked() {
        let mut live = live(&scene(), (32, 18));
        live.set_sc_interval(Duration::from_millis(200));
        settled(&mut live, Composition::Deep);
        let before = live.sc_status().frames;
        let start = Instant::now();
        // Ten new states in 100 ms: a paced SC renders at most one more of them in that time.
        for i in 0..10 {
            let s = live.snapshot();
            live.view(
                s.view.eye + Vec3::Y * 0.01 * i as f32,
                s.view.target,
                s.view.up,
            )
            .expect("view");
            live.has_news();
            std::thread::sleep(Duration::from_millis(10));
        }
        let done = live.sc_status().frames - before;
        let limit = 1 + (start.elapsed().as_millis() / 200) as u64;
        assert!(done <= limit, "{done} SC frames in {:?}", start.elapsed());
    }
}
