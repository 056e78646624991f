//! The state authority: replays a trace against a scene and publishes numbered snapshots.
//!
//! # Data
//!
//! ```text
//! Authority ── scene objects: world bounds at rest (object-space AABB through the scene's model)
//!           ── cursor into the trace, the current view, the pointer ray, the active drag
//!           ── per object: offset (translation the user added), version, state (Fig. 6.5)
//!           ── the trace's `light` keys (TraceLights)
//!           └─► Snapshot { id, t_ms, view, objects: [ObjectPose; n], events_applied, lights }
//!               behind an Arc
//! ```
//!
//! A [`Snapshot`] is immutable and numbered: clients hold an `Arc` to the one they render, compare
//! ids to know whether anything changed, and never see a half-applied event. [`Authority::advance_to`]
//! applies every event up to a time (a drag in progress is interpolated to that time) and returns a
//! new snapshot only when something changed, so ids count changes, not calls.
//!
//! # Picking
//!
//! The pointer ray is tested against each object's triangles (after a test against its
//! world-space bounding box, the enclosure Springer 2008 §9.1 allows on its own); the object with
//! the nearest hit is intersected, every other object is not. The ray is carried into each
//! object's space (the inverse of its current world matrix), so no triangle is copied and hit
//! distances stay comparable across objects. The test runs on every pointer event and after every
//! drag step. A selected object keeps its state whatever the ray does (Fig. 6.5): it is being
//! dragged.
//!
//! # Versions
//!
//! An object's version counts the changes of its transform. The slow client reports the versions
//! it rendered, so the fast client can tell an object the SC buffer holds at an old place from one
//! it holds where it is — the gap in the seed's Table 6.1 bookkeeping when an object is moved and
//! released within one SC frame.

use std::sync::Arc;

use glam::{Mat4, Vec3};
use strata_core::ObjectId;
use strata_scene::{Aabb, Mesh, Scene};

use crate::lighting::{LightPose, TraceLights};
use crate::state::{Input, ObjectState};
use crate::trace::{Button, Event, TimedEvent, Trace, TraceError};

/// Applied live events kept before they are dropped from the trace.
const FORGET_AFTER: usize = 1024;

/// The camera of a snapshot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewPose {
    /// Eye position.
    pub eye: Vec3,
    /// The point looked at.
    pub target: Vec3,
    /// Up direction.
    pub up: Vec3,
}

impl ViewPose {
    /// The view matrix (`look_at_rh`, as the scene camera).
    pub fn matrix(&self) -> Mat4 {
        Mat4::look_at_rh(self.eye, self.target, self.up)
    }
}

/// One object in a snapshot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjectPose {
    /// The object's id (its fragments carry it).
    pub id: ObjectId,
    /// Translation the user added, applied after the scene's model matrix.
    pub offset: Vec3,
    /// Changes of the transform so far (0 = where the scene put it).
    pub version: u64,
    /// Selection state (Fig. 6.5).
    pub state: ObjectState,
}

/// What the scene looks like at one moment: immutable, numbered.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// Number of the snapshot: 0 for the start, one more for each change.
    pub id: u64,
    /// The trace time it shows (ms).
    pub t_ms: f64,
    /// The camera.
    pub view: ViewPose,
    /// Every object of the scene, in the scene's order.
    pub objects: Vec<ObjectPose>,
    /// How many trace events it includes (for latency: the newest input it shows).
    pub events_applied: usize,
    /// The point lights the trace has keyed so far, by id, where they are at `t_ms` (deferred
    /// shading; empty without `light` events).
    pub lights: Vec<LightPose>,
}

impl Snapshot {
    /// The world matrix of object `index`: the scene's model matrix (animation frame 0) moved by
    /// the object's offset.
    pub fn model(&self, scene: &Scene, index: usize) -> Mat4 {
        Mat4::from_translation(self.objects[index].offset)
            * scene.objects[index].model_matrix(None, 0)
    }
}

/// A drag in progress.
#[derive(Clone, Copy, Debug)]
struct Drag {
    object: usize,
    start_ms: f64,
    from: Vec3,
    by: Vec3,
    duration_ms: f64,
    /// The pointer ray when the drag began: it moves with the object (the wand carries it).
    pointer_from: Option<(Vec3, Vec3)>,
}

/// Replays a trace against a scene; see the module docs.
#[derive(Debug)]
pub struct Authority {
    trace: Trace,
    next_event: usize,
    /// Applied events dropped from the front of `trace` (live input, see [`Authority::push`]).
    forgotten: usize,
    /// Each object's mesh and world matrix at rest (without the user's offset).
    meshes: Vec<(Arc<Mesh>, Mat4)>,
    /// World bounds of each object at rest.
    rest_bounds: Vec<Aabb>,
    pointer: Option<(Vec3, Vec3)>,
    drag: Option<Drag>,
    lights: TraceLights,
    current: Arc<Snapshot>,
}

impl Authority {
    /// An authority at time 0 with the scene's camera, every object where the scene puts it and
    /// INACTIVE; no event applied yet.
    pub fn new(scene: &Scene, trace: Trace) -> Self {
        let meshes: Vec<(Arc<Mesh>, Mat4)> = scene
            .objects
            .iter()
            .map(|o| (Arc::clone(&o.mesh), o.model_matrix(None, 0)))
            .collect();
        let rest_bounds = meshes
            .iter()
            .map(|(mesh, model)| world_bounds(mesh.bounds(), *model))
            .collect();
        let cam = &scene.camera;
        let first = Snapshot {
            id: 0,
            t_ms: 0.0,
            view: ViewPose {
                eye: cam.eye,
                target: cam.target,
                up: cam.up,
            },
            objects: scene
                .objects
                .iter()
                .map(|o| ObjectPose {
                    id: o.id,
                    offset: Vec3::ZERO,
                    version: 0,
                    state: ObjectState::Inactive,
                })
                .collect(),
            events_applied: 0,
            lights: Vec::new(),
        };
        let lights = TraceLights::new(&trace);
        Authority {
            trace,
            next_event: 0,
            forgotten: 0,
            meshes,
            rest_bounds,
            pointer: None,
            drag: None,
            lights,
            current: Arc::new(first),
        }
    }

    /// An authority that goes on from `snapshot` (a live session restarted at another size):
    /// the view and every object where the snapshot has them, every object INACTIVE (nothing
    /// stays held across a restart), time 0, snapshot ids going on from the snapshot's. A
    /// snapshot of another scene (another object count) is ignored.
    pub fn resume(scene: &Scene, trace: Trace, snapshot: &Snapshot) -> Self {
        let mut authority = Authority::new(scene, trace);
        if snapshot.objects.len() == authority.current.objects.len() {
            let mut s = snapshot.clone();
            for o in &mut s.objects {
                o.state = ObjectState::Inactive;
            }
            s.t_ms = 0.0;
            s.events_applied = 0;
            s.lights.clear();
            authority.current = Arc::new(s);
        }
        authority
    }

    /// The newest snapshot.
    pub fn current(&self) -> Arc<Snapshot> {
        Arc::clone(&self.current)
    }

    /// True when every event has been applied and no drag is in progress.
    pub fn finished(&self) -> bool {
        self.next_event == self.trace.events().len() && self.drag.is_none()
    }

    /// Applies every event at or before `t_ms` and a drag in progress up to `t_ms`; returns the
    /// newest snapshot (a new one, with the next id, if anything changed). Time never goes back:
    /// an earlier `t_ms` than the current snapshot's is taken as the current time.
    pub fn advance_to(&mut self, t_ms: f64) -> Arc<Snapshot> {
        let t_ms = if t_ms.is_finite() {
            t_ms.max(self.current.t_ms)
        } else {
            self.current.t_ms
        };
        let mut next = (*self.current).clone();
        next.t_ms = t_ms;
        while let Some(e) = self.trace.events().get(self.next_event).copied() {
            if e.t_ms > t_ms {
                break;
            }
            // A drag in progress reaches the event's time first.
            self.step_drag(&mut next, e.t_ms);
            self.apply(&mut next, e.t_ms, e.event);
            self.next_event += 1;
            next.events_applied = self.forgotten + self.next_event;
        }
        self.step_drag(&mut next, t_ms);
        if !self.lights.is_empty() {
            next.lights = self.lights.at(t_ms);
        }
        let changed = next.lights != self.current.lights
            || next.view != self.current.view
            || next.objects != self.current.objects
            || next.events_applied != self.current.events_applied;
        if changed {
            next.id = self.current.id + 1;
            self.current = Arc::new(next);
        }
        Arc::clone(&self.current)
    }

    /// Appends a live input — what a person does, as they do it — to the trace being replayed.
    /// It must not come before the newest snapshot's time or the last event; it is applied by the
    /// next [`Authority::advance_to`] that reaches its time. Lights are keyed by the trace the
    /// authority starts with and cannot be added. Applied events are forgotten as input goes on
    /// (a session can last hours); [`Snapshot::events_applied`] goes on counting them.
    pub fn push(&mut self, event: TimedEvent) -> Result<(), TraceError> {
        if matches!(event.event, Event::Light { .. }) {
            return Err(TraceError::new(
                "live input",
                "lights are keyed by the trace the authority starts with",
            ));
        }
        if event.t_ms.is_nan() || event.t_ms < self.current.t_ms {
            return Err(TraceError::new(
                "live input",
                format!(
                    "an event at {} ms comes before the newest snapshot, at {} ms",
                    event.t_ms, self.current.t_ms
                ),
            ));
        }
        self.trace.push(event)?;
        if self.next_event >= FORGET_AFTER {
            self.trace.drop_front(self.next_event);
            self.forgotten += self.next_event;
            self.next_event = 0;
        }
        Ok(())
    }

    fn apply(&mut self, s: &mut Snapshot, t_ms: f64, event: Event) {
        match event {
            Event::View { eye, target, up } => s.view = ViewPose { eye, target, up },
            Event::Pointer { origin, dir } => {
                self.pointer = Some((origin, dir));
                self.pick(s);
            }
            Event::Button(Button::Down) => {
                let over = s.objects.iter().position(|o| o.state == ObjectState::Over);
                if let Some(i) = over {
                    s.objects[i].state = s.objects[i].state.next(Input::Select);
                }
            }
            Event::Button(Button::Up) => {
                self.drag = None;
                for o in &mut s.objects {
                    o.state = o.state.next(Input::Release);
                }
                self.pick(s);
            }
            // Lights follow their keys continuously: posed in `advance_to`.
            Event::Light { .. } => {}
            Event::Drag { by, duration_ms } => {
                if let Some(i) = s
                    .objects
                    .iter()
                    .position(|o| o.state == ObjectState::Selected)
                {
                    self.drag = Some(Drag {
                        object: i,
                        start_ms: t_ms,
                        from: s.objects[i].offset,
                        by,
                        duration_ms,
                        pointer_from: self.pointer,
                    });
                }
            }
        }
    }

    /// Moves the dragged object to where the drag puts it at `t_ms`; ends a finished drag.
    fn step_drag(&mut self, s: &mut Snapshot, t_ms: f64) {
        let Some(d) = self.drag else { return };
        let f = ((t_ms - d.start_ms) / d.duration_ms).clamp(0.0, 1.0) as f32;
        let offset = d.from + d.by * f;
        if let Some((origin, dir)) = d.pointer_from {
            self.pointer = Some((origin + d.by * f, dir));
        }
        let pose = &mut s.objects[d.object];
        if pose.offset != offset {
            pose.offset = offset;
            pose.version += 1;
        }
        if f >= 1.0 {
            self.drag = None;
        }
        self.pick(s);
    }

    /// Intersects the pointer ray with every object's current world bounds: the nearest hit gets
    /// Intersect, the others No Intersect.
    fn pick(&self, s: &mut Snapshot) {
        let Some((origin, dir)) = self.pointer else {
            return;
        };
        let nearest = s
            .objects
            .iter()
            .enumerate()
            .filter_map(|(i, o)| self.hit(i, o.offset, origin, dir).map(|t| (i, t)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i);
        for (i, o) in s.objects.iter_mut().enumerate() {
            let input = if Some(i) == nearest {
                Input::Intersect
            } else {
                Input::NoIntersect
            };
            o.state = o.state.next(input);
        }
    }
}

impl Authority {
    /// The object whose triangles the ray from `origin` along `dir` hits first, with every object
    /// where the current snapshot puts it.
    pub fn nearest_hit(&self, origin: Vec3, dir: Vec3) -> Option<usize> {
        self.nearest_hit_at(origin, dir).map(|(i, _)| i)
    }

    /// [`Authority::nearest_hit`] with the ray parameter of the hit (`origin + t · dir`).
    pub fn nearest_hit_at(&self, origin: Vec3, dir: Vec3) -> Option<(usize, f32)> {
        self.current
            .objects
            .iter()
            .enumerate()
            .filter_map(|(i, o)| self.hit(i, o.offset, origin, dir).map(|t| (i, t)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// The distance along the ray to the nearest triangle of object `i` moved by `offset`.
    fn hit(&self, i: usize, offset: Vec3, origin: Vec3, dir: Vec3) -> Option<f32> {
        let b = self.rest_bounds[i];
        let moved = Aabb {
            min: b.min + offset,
            max: b.max + offset,
        };
        ray_box(origin, dir, &moved)?;
        let (mesh, rest) = &self.meshes[i];
        let inverse = (Mat4::from_translation(offset) * *rest).inverse();
        let (o, d) = (
            inverse.transform_point3(origin),
            inverse.transform_vector3(dir),
        );
        if !(o.is_finite() && d.is_finite()) {
            return None;
        }
        let positions = mesh.positions();
        mesh.triangles()
            .iter()
            .filter_map(|tri| {
                let [a, b, c] = tri.map(|v| Vec3::from(positions[v as usize]));
                ray_triangle(o, d, a, b, c)
            })
            .min_by(f32::total_cmp)
    }
}

/// Möller–Trumbore: the ray parameter where it crosses triangle `abc` (either side), if ≥ 0.
fn ray_triangle(o: Vec3, d: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Option<f32> {
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() <= f32::EPSILON * e1.length() * e2.length() * d.length() {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t >= 0.0).then_some(t)
}

/// The world-space box around `b` transformed by `m` (its eight corners).
fn world_bounds(b: Aabb, m: Mat4) -> Aabb {
    let mut out = Aabb::EMPTY;
    for i in 0..8 {
        let corner = Vec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        );
        out.include(m.transform_point3(corner));
    }
    out
}

/// The distance along the ray to where it enters `b` (0 if it starts inside), if it hits.
fn ray_box(origin: Vec3, dir: Vec3, b: &Aabb) -> Option<f32> {
    if b.is_empty() {
        return None;
    }
    let mut near = 0.0f32;
    let mut far = f32::INFINITY;
    for axis in 0..3 {
        let (o, d) = (origin[axis], dir[axis]);
        let (lo, hi) = (b.min[axis], b.max[axis]);
        if d == 0.0 {
            if o < lo || o > hi {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((lo - o) / d, (hi - o) / d);
        let (t0, t1) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
        near = near.max(t0);
        far = far.min(t1);
        if near > far {
            return None;
        }
    }
    Some(near)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_triangle_hits_inside_and_misses_outside() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let o = Vec3::new(0.25, 0.25, 2.0);
        assert_eq!(ray_triangle(o, -Vec3::Z, a, b, c), Some(2.0));
        assert_eq!(ray_triangle(o, Vec3::Z, a, b, c), None, "behind the origin");
        let outside = Vec3::new(0.75, 0.75, 2.0);
        assert_eq!(ray_triangle(outside, -Vec3::Z, a, b, c), None);
        assert_eq!(ray_triangle(o, Vec3::X, a, b, c), None, "parallel");
    }

    #[test]
    fn ray_box_hits_misses_and_starts_inside() {
        let b = Aabb {
            min: Vec3::splat(-1.0),
            max: Vec3::splat(1.0),
        };
        assert_eq!(ray_box(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z, &b), Some(4.0));
        assert_eq!(ray_box(Vec3::new(0.0, 3.0, 5.0), -Vec3::Z, &b), None);
        assert_eq!(ray_box(Vec3::new(0.0, 0.0, 5.0), Vec3::Z, &b), None);
        assert_eq!(ray_box(Vec3::ZERO, Vec3::X, &b), Some(0.0));
    }
}
