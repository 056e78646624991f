//! Interaction traces: what the user does, when, as data the state authority replays.
//!
//! A trace is a list of events in time order, times in milliseconds from the start:
//!
//! | event | fields | meaning |
//! | --- | --- | --- |
//! | `view` | `eye`, `target`, optional `up` (default `[0, 1, 0]`) | the camera moves there |
//! | `pointer` | `origin`, `dir` (any non-zero length) | the pointer ray (a 6-DOF wand or a mouse ray) |
//! | `button` | `"down"` or `"up"` | select the object under the pointer / release it |
//! | `drag` | `by` (world units), `duration_ms` | the selected object, and the pointer holding it, move by `by`, linearly over `duration_ms` |
//! | `light` | `id`, then `position` or `circle = { center, radius, period_ms }`; optional `color` (default `[1, 1, 1]`), `range` (default 2) | point light `id` appears or moves: from a `position` it moves linearly to the position of its next `light` event, or stays; on a `circle` it turns in the xz plane from the circle's +x point until its next event |
//!
//! Two file forms carry the same events (`docs/mfr.md`):
//!
//! ```toml
//! [[event]]
//! t_ms = 0
//! view = { eye = [0.0, 0.5, 3.0], target = [0.0, 0.0, 0.0] }
//!
//! [[event]]
//! t_ms = 400
//! pointer = { origin = [0.0, 0.5, 3.0], dir = [0.0, -0.1, -1.0] }
//!
//! [[event]]
//! t_ms = 700
//! button = "down"
//! ```
//!
//! or JSON lines, one event a line: `{"t_ms": 700, "button": "down"}`. Each event has `t_ms` and
//! exactly one kind; unknown keys, a second kind, times out of order, non-finite numbers and
//! zero-length directions are errors naming the file and the event (and its line).
//!
//! Generators make the traces the evaluation sweeps: [`grab`] (approach an object, pre-select
//! it, grab, drag, release, leave; Springer 2008 §6.1), [`orbit`] (the camera circles the
//! target) and [`light_ring`] (point lights keyed around the target, for deferred shading);
//! [`Trace::merged`] runs two traces at once.

use std::path::Path;

use glam::Vec3;
use serde::Deserialize;
use strata_scene::Scene;

/// The pointer button's two events.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Button {
    /// Pressed: selects the object under the pointer.
    Down,
    /// Released: releases the selected object.
    Up,
}

/// One thing the user does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// The camera moves.
    View {
        /// Eye position.
        eye: Vec3,
        /// The point looked at.
        target: Vec3,
        /// Up direction.
        up: Vec3,
    },
    /// The pointer ray.
    Pointer {
        /// Where the ray starts.
        origin: Vec3,
        /// Its direction (normalised).
        dir: Vec3,
    },
    /// The button.
    Button(Button),
    /// The selected object moves by `by` over `duration_ms`.
    Drag {
        /// World-space displacement.
        by: Vec3,
        /// How long the move takes (> 0).
        duration_ms: f64,
    },
    /// Point light `id` is keyed here (deferred shading).
    Light {
        /// Which light.
        id: u32,
        /// Where it is, or how it moves from now on.
        motion: LightMotion,
        /// RGB intensity.
        color: [f32; 3],
        /// Distance at which it falls to half.
        range: f32,
    },
}

/// How a `light` event places its light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightMotion {
    /// At this position; linear from here to the position of the light's next event.
    At(Vec3),
    /// Turning around a horizontal circle in the xz plane, starting at `center + (radius, 0, 0)`.
    Circle {
        /// Centre.
        center: Vec3,
        /// Radius (> 0).
        radius: f32,
        /// Milliseconds per turn (> 0).
        period_ms: f64,
    },
}

/// The default `range` of a trace's light.
pub const DEFAULT_LIGHT_RANGE: f32 = 2.0;

/// An event and when it happens.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedEvent {
    /// Milliseconds from the start of the trace.
    pub t_ms: f64,
    /// What happens.
    pub event: Event,
}

/// A list of events in time order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trace {
    events: Vec<TimedEvent>,
}

/// Why a trace could not be read or made.
#[derive(Debug, thiserror::Error)]
#[error("{origin}: {what}")]
pub struct TraceError {
    /// The file or generator the trace came from.
    pub origin: String,
    /// What is wrong, with the event and line where known.
    pub what: String,
}

impl TraceError {
    pub(crate) fn new(origin: &str, what: impl Into<String>) -> Self {
        TraceError {
            origin: origin.to_owned(),
            what: what.into(),
        }
    }
}

/// The events as written in a file, before checking.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEvent {
    t_ms: f64,
    view: Option<RawView>,
    pointer: Option<RawPointer>,
    button: Option<Button>,
    drag: Option<RawDrag>,
    light: Option<RawLight>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLight {
    id: u32,
    position: Option<Vec<f64>>,
    circle: Option<RawCircle>,
    color: Option<Vec<f64>>,
    range: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCircle {
    center: Vec<f64>,
    radius: f64,
    period_ms: f64,
}

impl RawLight {
    fn check(self) -> Result<Event, String> {
        let motion = match (self.position, self.circle) {
            (Some(p), None) => LightMotion::At(vec3(p, "light.position")?),
            (None, Some(c)) => {
                if !(c.radius.is_finite() && c.radius > 0.0 && c.radius < f64::from(f32::MAX)) {
                    return Err(format!(
                        "light.circle.radius {} must be more than 0",
                        c.radius
                    ));
                }
                if !(c.period_ms.is_finite() && c.period_ms > 0.0) {
                    return Err(format!(
                        "light.circle.period_ms {} must be more than 0",
                        c.period_ms
                    ));
                }
                LightMotion::Circle {
                    center: vec3(c.center, "light.circle.center")?,
                    radius: c.radius as f32,
                    period_ms: c.period_ms,
                }
            }
            _ => return Err("light needs exactly one of position, circle".into()),
        };
        let color = match self.color {
            Some(c) => {
                let c = vec3(c, "light.color")?;
                if c.min_element() < 0.0 {
                    return Err(format!("light.color {c} must not be negative"));
                }
                c.to_array()
            }
            None => [1.0; 3],
        };
        let range = match self.range {
            Some(r) if r.is_finite() && r > 0.0 && r < f64::from(f32::MAX) => r as f32,
            Some(r) => return Err(format!("light.range {r} must be more than 0")),
            None => DEFAULT_LIGHT_RANGE,
        };
        Ok(Event::Light {
            id: self.id,
            motion,
            color,
            range,
        })
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawView {
    eye: Vec<f64>,
    target: Vec<f64>,
    up: Option<Vec<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPointer {
    origin: Vec<f64>,
    dir: Vec<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDrag {
    by: Vec<f64>,
    duration_ms: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    #[serde(default)]
    event: Vec<RawEvent>,
}

/// A finite vector from a file's numbers (read as a list so that a wrong length is an error:
/// TOML readers drop the extra elements of a fixed-size array).
fn vec3(v: Vec<f64>, what: &str) -> Result<Vec3, String> {
    let Ok(v) = <[f64; 3]>::try_from(v.as_slice()) else {
        return Err(format!("{what} needs 3 numbers, found {}", v.len()));
    };
    if v.iter()
        .any(|x| !x.is_finite() || x.abs() > f64::from(f32::MAX))
    {
        return Err(format!("{what} {v:?} is not a finite vector"));
    }
    Ok(Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32))
}

fn unit(v: Vec3, what: &str) -> Result<Vec3, String> {
    let n = v
        .try_normalize()
        .ok_or_else(|| format!("{what} has zero length"))?;
    Ok(n)
}

/// The rules a trace file's events follow, for an event made in code.
fn check_event(event: &Event) -> Result<(), String> {
    let finite = |v: Vec3, what: &str| {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("{what} {v} is not a finite vector"))
        }
    };
    match *event {
        Event::View { eye, target, up } => {
            let (eye, target) = (finite(eye, "view.eye")?, finite(target, "view.target")?);
            unit(target - eye, "view: target - eye")?;
            unit(finite(up, "view.up")?, "view.up")?;
        }
        Event::Pointer { origin, dir } => {
            finite(origin, "pointer.origin")?;
            unit(finite(dir, "pointer.dir")?, "pointer.dir")?;
        }
        Event::Drag { by, duration_ms } => {
            finite(by, "drag.by")?;
            if !(duration_ms.is_finite() && duration_ms > 0.0) {
                return Err(format!(
                    "drag.duration_ms {duration_ms} must be more than 0"
                ));
            }
        }
        Event::Button(_) | Event::Light { .. } => {}
    }
    Ok(())
}

impl RawEvent {
    fn check(self) -> Result<TimedEvent, String> {
        if !(self.t_ms.is_finite() && self.t_ms >= 0.0) {
            return Err(format!(
                "t_ms {} must be a time in milliseconds, 0 or more",
                self.t_ms
            ));
        }
        let kinds = [
            self.view.is_some(),
            self.pointer.is_some(),
            self.button.is_some(),
            self.drag.is_some(),
            self.light.is_some(),
        ];
        let count = kinds.iter().filter(|&&k| k).count();
        if count != 1 {
            return Err(format!(
                "has {count} kinds of event; give exactly one of view, pointer, button, drag, light"
            ));
        }
        let event = if let Some(v) = self.view {
            let eye = vec3(v.eye, "view.eye")?;
            let target = vec3(v.target, "view.target")?;
            unit(target - eye, "view: target - eye")?;
            let up = unit(
                vec3(v.up.unwrap_or(vec![0.0, 1.0, 0.0]), "view.up")?,
                "view.up",
            )?;
            Event::View { eye, target, up }
        } else if let Some(p) = self.pointer {
            Event::Pointer {
                origin: vec3(p.origin, "pointer.origin")?,
                dir: unit(vec3(p.dir, "pointer.dir")?, "pointer.dir")?,
            }
        } else if let Some(b) = self.button {
            Event::Button(b)
        } else if let Some(d) = self.drag {
            if !(d.duration_ms.is_finite() && d.duration_ms > 0.0) {
                return Err(format!(
                    "drag.duration_ms {} must be more than 0",
                    d.duration_ms
                ));
            }
            Event::Drag {
                by: vec3(d.by, "drag.by")?,
                duration_ms: d.duration_ms,
            }
        } else if let Some(l) = self.light {
            l.check()?
        } else {
            unreachable!("exactly one kind was counted")
        };
        Ok(TimedEvent {
            t_ms: self.t_ms,
            event,
        })
    }
}

impl Trace {
    /// A trace of `events`, which must be in time order.
    pub fn new(events: Vec<TimedEvent>) -> Result<Self, TraceError> {
        Self::ordered("trace", events, |i| format!("event {i}"))
    }

    fn ordered(
        origin: &str,
        events: Vec<TimedEvent>,
        name: impl Fn(usize) -> String,
    ) -> Result<Self, TraceError> {
        for (i, w) in events.windows(2).enumerate() {
            if w[1].t_ms < w[0].t_ms {
                return Err(TraceError::new(
                    origin,
                    format!(
                        "{} at {} ms comes before {} at {} ms; list events in time order",
                        name(i + 1),
                        w[1].t_ms,
                        name(i),
                        w[0].t_ms
                    ),
                ));
            }
        }
        Ok(Trace { events })
    }

    /// Appends `event`, which must come at or after the last event (a live session's input)
    /// and hold what a trace file's event may: finite vectors, a view's target away from its
    /// eye and a non-zero up, a pointer's non-zero direction, a drag's positive duration.
    pub fn push(&mut self, event: TimedEvent) -> Result<(), TraceError> {
        check_event(&event.event).map_err(|what| TraceError::new("live input", what))?;
        let last = self.duration_ms();
        if !(event.t_ms.is_finite() && event.t_ms >= last) {
            return Err(TraceError::new(
                "live input",
                format!(
                    "an event at {} ms comes before the last one, at {last} ms",
                    event.t_ms
                ),
            ));
        }
        self.events.push(event);
        Ok(())
    }

    /// Drops the first `count` events (those a live session has applied), keeping the rest.
    pub(crate) fn drop_front(&mut self, count: usize) {
        self.events.drain(..count.min(self.events.len()));
    }

    /// This trace's events and `other`'s, in time order (at equal times this trace's first):
    /// both traces played at once, e.g. a grab while lights move.
    pub fn merged(&self, other: &Trace) -> Trace {
        let mut events = Vec::with_capacity(self.events.len() + other.events.len());
        let (mut a, mut b) = (
            self.events.iter().peekable(),
            other.events.iter().peekable(),
        );
        loop {
            let next = match (a.peek(), b.peek()) {
                (Some(x), Some(y)) if y.t_ms < x.t_ms => b.next(),
                (Some(_), _) => a.next(),
                (None, _) => b.next(),
            };
            match next {
                Some(e) => events.push(*e),
                None => break,
            }
        }
        Trace { events }
    }

    /// True when some event is a `light` event.
    pub fn has_lights(&self) -> bool {
        self.events
            .iter()
            .any(|e| matches!(e.event, Event::Light { .. }))
    }

    /// The events, in time order.
    pub fn events(&self) -> &[TimedEvent] {
        &self.events
    }

    /// The time of the last event (0 for an empty trace).
    pub fn duration_ms(&self) -> f64 {
        self.events.last().map_or(0.0, |e| e.t_ms)
    }

    /// Reads a trace file: `.toml`, or JSON lines (`.jsonl`, `.json`).
    pub fn read(path: &Path) -> Result<Self, TraceError> {
        /// Larger trace files are refused rather than read into memory.
        const MAX_BYTES: u64 = 64 << 20;
        let origin = path.display().to_string();
        let meta = std::fs::metadata(path)
            .map_err(|e| TraceError::new(&origin, format!("cannot read: {e}")))?;
        if !meta.is_file() {
            return Err(TraceError::new(&origin, "not a regular file"));
        }
        if meta.len() > MAX_BYTES {
            return Err(TraceError::new(
                &origin,
                format!("{} bytes; trace files are at most {MAX_BYTES}", meta.len()),
            ));
        }
        let text = std::fs::read_to_string(path)
            .map_err(|e| TraceError::new(&origin, format!("cannot read: {e}")))?;
        match path.extension().and_then(|e| e.to_str()) {
            Some("toml") => Self::from_toml(&origin, &text),
            Some("jsonl" | "json") => Self::from_json_lines(&origin, &text),
            _ => Err(TraceError::new(
                &origin,
                "name a trace file .toml or .jsonl (JSON lines)",
            )),
        }
    }

    /// Parses the TOML form: `[[event]]` tables.
    pub fn from_toml(origin: &str, text: &str) -> Result<Self, TraceError> {
        let raw: RawFile = toml::from_str(text).map_err(|e| {
            let at = e
                .span()
                .map(|s| format!("line {}: ", line_of(text, s.start)))
                .unwrap_or_default();
            TraceError::new(origin, format!("{at}{}", e.message()))
        })?;
        let lines = event_lines(text);
        let name = |i: usize| match lines.get(i) {
            Some(line) => format!("event {} (line {line})", i + 1),
            None => format!("event {}", i + 1),
        };
        let events = raw
            .event
            .into_iter()
            .enumerate()
            .map(|(i, e)| {
                e.check()
                    .map_err(|w| TraceError::new(origin, format!("{}: {w}", name(i))))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Self::ordered(origin, events, name)
    }

    /// Parses JSON lines: one event object a line; blank lines and lines starting with `#` are
    /// skipped.
    pub fn from_json_lines(origin: &str, text: &str) -> Result<Self, TraceError> {
        let mut events = Vec::new();
        let mut lines = Vec::new();
        for (n, line) in text.lines().enumerate() {
            let trimmed = line.trim();
            if trimmed.is_empty() || trimmed.starts_with('#') {
                continue;
            }
            let at = n + 1;
            let raw: RawEvent = serde_json::from_str(trimmed)
                .map_err(|e| TraceError::new(origin, format!("line {at}: {e}")))?;
            events.push(
                raw.check()
                    .map_err(|w| TraceError::new(origin, format!("line {at}: {w}")))?,
            );
            lines.push(at);
        }
        Self::ordered(origin, events, |i| {
            format!("the event on line {}", lines[i])
        })
    }
}

/// The 1-based line of byte `at`.
fn line_of(text: &str, at: usize) -> usize {
    text.as_bytes()[..at.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// The lines of the `[[event]]` headers, in order.
fn event_lines(text: &str) -> Vec<usize> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.trim_start().starts_with("[[event]]"))
        .map(|(i, _)| i + 1)
        .collect()
}

/// Parameters of the [`grab`] generator.
#[derive(Clone, Debug, PartialEq)]
pub struct GrabParams {
    /// The object to grab, by name (default: the first object, in scene order, that a ray from
    /// the eye reaches before any other; a scene puts its interactive part first to make it the
    /// default).
    pub object: Option<String>,
    /// When the pointer reaches the object (ms).
    pub start_ms: f64,
    /// How long the object is OVER before the button goes down: the lead the seed's
    /// pre-selection gives the clients (0 = grab at once).
    pub over_lead_ms: f64,
    /// How long the object stays selected, moving.
    pub hold_ms: f64,
    /// How far it moves while held (world units, along the camera's right).
    pub distance: f32,
    /// How long the pointer stays on the object after the release before leaving.
    pub linger_ms: f64,
}

impl Default for GrabParams {
    fn default() -> Self {
        GrabParams {
            object: None,
            start_ms: 100.0,
            over_lead_ms: 300.0,
            hold_ms: 1000.0,
            distance: 0.3,
            linger_ms: 300.0,
        }
    }
}

impl GrabParams {
    /// Parses `key=value,…` (`object`, `start_ms`, `over_lead_ms`, `hold_ms`, `distance`,
    /// `linger_ms`) over the defaults.
    pub fn parse(spec: &str) -> Result<Self, TraceError> {
        let mut p = GrabParams::default();
        let origin = format!("grab:{spec}");
        for item in spec.split(',').filter(|s| !s.trim().is_empty()) {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| TraceError::new(&origin, format!("'{item}': expected key=value")))?;
            let (key, value) = (key.trim(), value.trim());
            let ms = |v: &str| -> Result<f64, TraceError> {
                v.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite() && *x >= 0.0)
                    .ok_or_else(|| {
                        TraceError::new(
                            &origin,
                            format!("{key}={v}: expected milliseconds, 0 or more"),
                        )
                    })
            };
            match key {
                "object" => p.object = Some(value.to_owned()),
                "start_ms" => p.start_ms = ms(value)?,
                "over_lead_ms" => p.over_lead_ms = ms(value)?,
                "hold_ms" => p.hold_ms = ms(value)?,
                "linger_ms" => p.linger_ms = ms(value)?,
                "distance" => {
                    p.distance = value
                        .parse::<f32>()
                        .ok()
                        .filter(|d| d.is_finite() && d.abs() <= 1e6)
                        .ok_or_else(|| {
                            TraceError::new(&origin, format!("distance={value}: expected a number"))
                        })?
                }
                _ => {
                    return Err(TraceError::new(
                        &origin,
                        format!(
                            "unknown parameter '{key}' (grab takes object, start_ms, over_lead_ms, \
                             hold_ms, distance, linger_ms)"
                        ),
                    ));
                }
            }
        }
        Ok(p)
    }
}

/// The trace of grabbing one object: the pointer (from the eye) reaches the object's centre at
/// `start_ms` (OVER), the button goes down `over_lead_ms` later (SELECTED) and the object moves
/// by `distance` along the camera's right over `hold_ms`, the button goes up (OVER), and
/// `linger_ms` later the pointer turns away (INACTIVE). The camera stays where the scene puts it.
pub fn grab(scene: &Scene, p: &GrabParams) -> Result<Trace, TraceError> {
    let origin = "grab";
    let cam = &scene.camera;
    let toward = match &p.object {
        Some(name) => {
            let index = scene
                .objects
                .iter()
                .position(|o| &o.name == name)
                .ok_or_else(|| {
                    let names: Vec<&str> = scene.objects.iter().map(|o| o.name.as_str()).collect();
                    TraceError::new(
                        origin,
                        format!(
                            "no object '{name}' in {} (objects: {})",
                            scene.name,
                            names.join(", ")
                        ),
                    )
                })?;
            aim_at(scene, index, cam.eye).ok_or_else(|| {
                TraceError::new(
                    origin,
                    format!(
                        "object '{name}' is hidden from the eye: no ray from the eye reaches it \
                         before the other objects"
                    ),
                )
            })?
        }
        None => (0..scene.objects.len())
            .find_map(|i| aim_at(scene, i, cam.eye))
            .ok_or_else(|| {
                TraceError::new(
                    origin,
                    format!(
                        "no object of {} can be reached by a ray from the eye",
                        scene.name
                    ),
                )
            })?,
    };
    let right = (cam.target - cam.eye).cross(cam.up).normalize_or(Vec3::X);
    let away = -toward;
    let mut t = p.start_ms;
    let mut events = vec![TimedEvent {
        t_ms: 0.0,
        event: Event::View {
            eye: cam.eye,
            target: cam.target,
            up: cam.up,
        },
    }];
    let mut at = |t_ms: f64, event: Event| events.push(TimedEvent { t_ms, event });
    at(
        t,
        Event::Pointer {
            origin: cam.eye,
            dir: toward,
        },
    );
    t += p.over_lead_ms;
    at(t, Event::Button(Button::Down));
    if p.hold_ms > 0.0 {
        at(
            t,
            Event::Drag {
                by: right * p.distance,
                duration_ms: p.hold_ms,
            },
        );
    }
    t += p.hold_ms;
    at(t, Event::Button(Button::Up));
    t += p.linger_ms;
    at(
        t,
        Event::Pointer {
            origin: cam.eye,
            dir: away,
        },
    );
    Trace::ordered(origin, events, |i| format!("event {i}"))
}

/// A direction from `eye` whose ray meets object `index` before any other: toward its centre if
/// that works, else toward the first of up to 512 of its vertices (pulled a little toward the
/// centre, to hit the surface rather than graze an edge) that does.
pub(crate) fn aim_at(scene: &Scene, index: usize, eye: Vec3) -> Option<Vec3> {
    let picker = crate::Authority::new(scene, Trace::default());
    let object = &scene.objects[index];
    let model = object.model_matrix(None, 0);
    let centre = object.mesh.bounds().center();
    let positions = object.mesh.positions();
    let stride = (positions.len() / 512).max(1);
    std::iter::once(centre)
        .chain(
            positions
                .iter()
                .step_by(stride)
                .map(|p| Vec3::from(*p).lerp(centre, 0.05)),
        )
        .filter_map(|p| (model.transform_point3(p) - eye).try_normalize())
        .find(|&dir| picker.nearest_hit(eye, dir) == Some(index))
}

/// The camera circling its target about the scene's up axis: a view event every `step_ms` for
/// `duration_ms`, one turn every `period_ms`, at the scene camera's distance and height.
pub fn orbit(
    scene: &Scene,
    period_ms: f64,
    duration_ms: f64,
    step_ms: f64,
) -> Result<Trace, TraceError> {
    let origin = "orbit";
    for (name, v) in [
        ("period_ms", period_ms),
        ("duration_ms", duration_ms),
        ("step_ms", step_ms),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(TraceError::new(
                origin,
                format!("{name}={v}: must be more than 0"),
            ));
        }
    }
    let cam = &scene.camera;
    let up = cam.up.normalize_or(Vec3::Y);
    let offset = cam.eye - cam.target;
    let along = up * offset.dot(up);
    let radial = offset - along;
    let side = up.cross(radial);
    let steps = (duration_ms / step_ms).floor() as usize;
    if steps > 1_000_000 {
        return Err(TraceError::new(
            origin,
            format!("{steps} steps of {step_ms} ms: at most a million; shorten duration_ms"),
        ));
    }
    let events = (0..=steps)
        .map(|i| {
            let t_ms = i as f64 * step_ms;
            let angle = (std::f64::consts::TAU * t_ms / period_ms) as f32;
            let (s, c) = angle.sin_cos();
            TimedEvent {
                t_ms,
                event: Event::View {
                    eye: cam.target + along + radial * c + side * s,
                    target: cam.target,
                    up,
                },
            }
        })
        .collect();
    Trace::ordered(origin, events, |i| format!("step {i}"))
}

/// Parameters of [`light_ring`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightRingParams {
    /// Lights, evenly spaced around the ring (1 or more).
    pub count: u32,
    /// Milliseconds per turn.
    pub period_ms: f64,
    /// How long the lights are keyed; they stay at their last keys afterwards.
    pub duration_ms: f64,
    /// Milliseconds between two keys of a light.
    pub step_ms: f64,
}

impl Default for LightRingParams {
    fn default() -> Self {
        LightRingParams {
            count: 4,
            period_ms: 4000.0,
            duration_ms: 4000.0,
            step_ms: 100.0,
        }
    }
}

impl LightRingParams {
    /// Parses `key=value,…` (`count`, `period_ms`, `duration_ms`, `step_ms`) over the defaults.
    pub fn parse(spec: &str) -> Result<Self, TraceError> {
        let mut p = LightRingParams::default();
        let origin = format!("lights:{spec}");
        for item in spec.split(',').filter(|s| !s.trim().is_empty()) {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| TraceError::new(&origin, format!("'{item}': expected key=value")))?;
            let (key, value) = (key.trim(), value.trim());
            let bad = |what: &str| TraceError::new(&origin, format!("{key}={value}: {what}"));
            let ms = || {
                value
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite() && *x > 0.0)
                    .ok_or_else(|| bad("expected milliseconds, more than 0"))
            };
            match key {
                "count" => {
                    p.count = value
                        .parse::<u32>()
                        .ok()
                        .filter(|n| (1..=64).contains(n))
                        .ok_or_else(|| bad("expected 1 to 64 lights"))?
                }
                "period_ms" => p.period_ms = ms()?,
                "duration_ms" => p.duration_ms = ms()?,
                "step_ms" => p.step_ms = ms()?,
                _ => {
                    return Err(TraceError::new(
                        &origin,
                        format!(
                            "unknown parameter '{key}' (lights takes count, period_ms, \
                             duration_ms, step_ms)"
                        ),
                    ));
                }
            }
        }
        Ok(p)
    }
}

/// Colours of the ring's lights, cycled.
const RING_COLORS: [[f32; 3]; 4] = [
    [1.0, 0.85, 0.7],
    [0.6, 0.7, 1.0],
    [0.9, 0.5, 0.5],
    [0.5, 0.9, 0.6],
];

/// `p.count` point lights (ids 0, 1, …) circling above the camera's target, evenly spaced, one
/// turn per `p.period_ms`: a `light` event with its position for every light every `p.step_ms`
/// for `p.duration_ms`, so each light moves in straight steps between keys. The ring's radius is
/// 0.6 of the camera's distance to its target, its height half the radius above the target, and
/// each light's range is the radius.
///
/// # Errors
/// No lights, a time that is not more than 0, or more than a million keys.
pub fn light_ring(scene: &Scene, p: &LightRingParams) -> Result<Trace, TraceError> {
    let origin = "lights";
    if p.count == 0 {
        return Err(TraceError::new(origin, "count=0: give 1 light or more"));
    }
    for (name, v) in [
        ("period_ms", p.period_ms),
        ("duration_ms", p.duration_ms),
        ("step_ms", p.step_ms),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(TraceError::new(
                origin,
                format!("{name}={v}: must be more than 0"),
            ));
        }
    }
    let steps = (p.duration_ms / p.step_ms).floor() as u64;
    if (steps + 1) * u64::from(p.count) > 1_000_000 {
        return Err(TraceError::new(
            origin,
            format!(
                "{} keys: at most a million; lengthen step_ms or shorten duration_ms",
                (steps + 1) * u64::from(p.count)
            ),
        ));
    }
    let cam = &scene.camera;
    let radius = (cam.eye - cam.target).length().max(1e-3) * 0.6;
    let center = cam.target + Vec3::Y * radius * 0.5;
    let mut events = Vec::with_capacity(((steps + 1) * u64::from(p.count)) as usize);
    for step in 0..=steps {
        let t_ms = step as f64 * p.step_ms;
        let turns = (t_ms / p.period_ms).fract();
        for id in 0..p.count {
            let a = (turns + f64::from(id) / f64::from(p.count)) * std::f64::consts::TAU;
            let (s, c) = (a as f32).sin_cos();
            events.push(TimedEvent {
                t_ms,
                event: Event::Light {
                    id,
                    motion: LightMotion::At(center + Vec3::new(c, 0.0, s) * radius),
                    color: RING_COLORS[id as usize % RING_COLORS.len()],
                    range: radius,
                },
            });
        }
    }
    Trace::ordered(origin, events, |i| format!("key {i}"))
}
