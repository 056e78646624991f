//! A run's timeline: what each FC frame showed and when, and what follows from it — the latency
//! of every input on the FC path and on the SC path (Springer 2008 §8.2, Table 8.3), and each
//! select and release event with the artefacts that followed it (§6, figs. 6.1–6.4).
//!
//! # Data
//!
//! One [`FrameRecord`] per FC frame, in frame order: when the frame started (`t_ms`, the state it
//! shows is the authority's at that time), when it was on screen (`shown_ms`: the frame's end —
//! `t_ms` plus the measured frame time in real time, plus one FC period on the virtual clock), how
//! many trace events its snapshot includes, the trace time of the state in its SC buffer, the
//! objects selected, and its audit. Records are small (no pixels), so a run keeps all of them.
//!
//! # Latency
//!
//! For trace event `i` at time `t_i`:
//!
//! - **FC path**: `shown_ms − t_i` of the first frame whose snapshot includes event `i`
//!   (`events_applied > i`): what the user's hand sees on the interactive objects;
//! - **SC path**: `shown_ms − t_i` of the first frame composed with an SC buffer rendered from a
//!   state at or after `t_i`: what the static part shows (a camera move, an object handed back).
//!
//! Events the run ended before showing are counted, not measured. There is no sensor delay: the
//! seed's Table 8.3 adds 40–60 ms of tracking to every path; add it to compare.
//!
//! # Events
//!
//! Each button press is a *select* and each release a *release*. An event's window runs from the
//! first frame that includes it to the frame before the next select or release is included.
//! Frames in the window with a ghost, hole, blend or bad pixel are its *artefact frames*; their
//! screen time (until the next frame replaced them) is its *artefact duration*; peaks are the
//! largest counts in one frame.

use strata_core::ObjectId;

use crate::audit::FrameAudit;
use crate::trace::{Button, Event, Trace};

/// What one FC frame showed and when.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRecord {
    /// FC frame number.
    pub index: u64,
    /// Start of the frame: the trace time of the state it shows (ms).
    pub t_ms: f64,
    /// When the frame was on screen (ms, same clock).
    pub shown_ms: f64,
    /// Trace events its snapshot includes.
    pub events_applied: usize,
    /// Trace time of the state its SC buffer was rendered from (`None` before the first buffer,
    /// or without an SC).
    pub sc_state_ms: Option<f64>,
    /// Objects SELECTED in its snapshot, sorted.
    pub selected: Vec<ObjectId>,
    /// Its audit (`None` when the run was not audited).
    pub audit: Option<FrameAudit>,
}

impl FrameRecord {
    /// The record of FC frame `f`, on screen at `shown_ms`, with its `audit` if it had one.
    pub fn of(f: &crate::simulate::FcFrame, shown_ms: f64, audit: Option<FrameAudit>) -> Self {
        Self::from_parts(
            f.index,
            f.t_ms,
            shown_ms,
            &f.snapshot,
            f.sc.as_deref(),
            audit,
        )
    }

    /// The record of frame `index` started at `t_ms` and on screen at `shown_ms`, showing
    /// `snapshot` over the SC buffer `sc`: what [`FrameRecord::of`] reads from a simulated FC
    /// frame, for the frames of other runs (deferred shading) too.
    pub fn from_parts(
        index: u64,
        t_ms: f64,
        shown_ms: f64,
        snapshot: &crate::authority::Snapshot,
        sc: Option<&crate::transfer::TransferBuffer>,
        audit: Option<FrameAudit>,
    ) -> Self {
        let mut selected: Vec<ObjectId> = snapshot
            .objects
            .iter()
            .filter(|o| o.state == crate::ObjectState::Selected)
            .map(|o| o.id)
            .collect();
        selected.sort_unstable();
        FrameRecord {
            index,
            t_ms,
            shown_ms,
            events_applied: snapshot.events_applied,
            sc_state_ms: sc.map(|sc| sc.snapshot_t_ms),
            selected,
            audit,
        }
    }
}

/// Latencies of a run's inputs (ms).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Latency {
    /// Per event, from the event to the first frame that shows it.
    pub fc_path_ms: Vec<f64>,
    /// Per event, from the event to the first frame whose SC buffer shows it.
    pub sc_path_ms: Vec<f64>,
    /// Events no frame showed before the run ended (FC path).
    pub fc_not_shown: usize,
    /// Events no SC buffer showed before the run ended.
    pub sc_not_shown: usize,
    /// Per event, in trace order: its time and both latencies (`None`: not shown).
    pub per_event: Vec<EventLatency>,
}

/// One event's latencies (ms).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct EventLatency {
    /// Trace time of the event.
    pub t_ms: f64,
    /// To the first frame showing it (`None`: none did).
    pub fc_path_ms: Option<f64>,
    /// To the first frame whose SC buffer shows it (`None`: none did).
    pub sc_path_ms: Option<f64>,
}

/// The latency of every event of `trace` in `frames` (frame order).
pub fn latency(trace: &Trace, frames: &[FrameRecord]) -> Latency {
    let mut out = Latency::default();
    for (i, e) in trace.events().iter().enumerate() {
        let fc = frames
            .iter()
            .find(|f| f.events_applied > i)
            .map(|f| f.shown_ms - e.t_ms);
        let sc = frames
            .iter()
            .find(|f| f.sc_state_ms.is_some_and(|s| s >= e.t_ms))
            .map(|f| f.shown_ms - e.t_ms);
        match fc {
            Some(ms) => out.fc_path_ms.push(ms),
            None => out.fc_not_shown += 1,
        }
        match sc {
            Some(ms) => out.sc_path_ms.push(ms),
            None => out.sc_not_shown += 1,
        }
        out.per_event.push(EventLatency {
            t_ms: e.t_ms,
            fc_path_ms: fc,
            sc_path_ms: sc,
        });
    }
    out
}

/// A select or a release.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum EventKind {
    /// Button pressed.
    Select,
    /// Button released.
    Release,
}

/// One select or release and the artefacts that followed it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct EventReport {
    /// Select or release.
    pub kind: EventKind,
    /// Trace time of the event (ms).
    pub t_ms: f64,
    /// The first FC frame that includes it (`None`: the run ended first).
    pub fc_frame: Option<u64>,
    /// The object it selected or released, if any (not serialised: a report names it).
    #[serde(skip)]
    pub object: Option<ObjectId>,
    /// Frames of its window (see the module doc).
    pub frames: u64,
    /// Frames of its window with an artefact (`None` when not audited).
    pub artefact_frames: Option<u64>,
    /// Their screen time (ms).
    pub artefact_ms: Option<f64>,
    /// Most bad, ghost, hole and blend pixels in one frame of the window.
    pub peak: Option<FrameAudit>,
}

/// Every select and release of `trace`, with its artefacts in `frames` (frame order).
pub fn events(trace: &Trace, frames: &[FrameRecord]) -> Vec<EventReport> {
    let presses: Vec<(usize, EventKind, f64)> = trace
        .events()
        .iter()
        .enumerate()
        .filter_map(|(i, e)| match e.event {
            Event::Button(Button::Down) => Some((i, EventKind::Select, e.t_ms)),
            Event::Button(Button::Up) => Some((i, EventKind::Release, e.t_ms)),
            _ => None,
        })
        .collect();
    let first_with = |i: usize| frames.iter().position(|f| f.events_applied > i);
    presses
        .iter()
        .enumerate()
        .map(|(n, &(i, kind, t_ms))| {
            let start = first_with(i);
            let end = presses
                .get(n + 1)
                .and_then(|&(j, _, _)| first_with(j))
                .unwrap_or(frames.len());
            let window = start.map_or(&frames[..0], |s| &frames[s..end.max(s)]);
            let object = match (kind, start) {
                (EventKind::Select, Some(s)) => frames[s].selected.first().copied(),
                (EventKind::Release, Some(s)) if s > 0 => frames[s - 1].selected.first().copied(),
                _ => None,
            };
            let audited = window.iter().all(|f| f.audit.is_some());
            let (mut count, mut ms, mut peak) = (0, 0.0, FrameAudit::default());
            for (k, f) in window.iter().enumerate() {
                let Some(a) = f.audit else { continue };
                peak.bad_pixels = peak.bad_pixels.max(a.bad_pixels);
                peak.ghost_pixels = peak.ghost_pixels.max(a.ghost_pixels);
                peak.hole_pixels = peak.hole_pixels.max(a.hole_pixels);
                peak.blend_pixels = peak.blend_pixels.max(a.blend_pixels);
                peak.rmse = peak.rmse.max(a.rmse);
                if a.has_artefact() {
                    count += 1;
                    ms += screen_time(frames, start.unwrap_or(0) + k);
                }
            }
            EventReport {
                kind,
                t_ms,
                fc_frame: start.map(|s| frames[s].index),
                object,
                frames: window.len() as u64,
                artefact_frames: audited.then_some(count),
                artefact_ms: audited.then_some(ms),
                peak: audited.then_some(peak),
            }
        })
        .collect()
}

/// How long frame `k` stayed on screen: until the next frame was shown; the last frame counts
/// the run's median frame interval.
fn screen_time(frames: &[FrameRecord], k: usize) -> f64 {
    match frames.get(k + 1) {
        Some(next) => next.shown_ms - frames[k].shown_ms,
        None => {
            let mut gaps: Vec<f64> = frames
                .windows(2)
                .map(|w| w[1].shown_ms - w[0].shown_ms)
                .collect();
            gaps.sort_by(f64::total_cmp);
            gaps.get(gaps.len() / 2).copied().unwrap_or(0.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::TimedEvent;
    use glam::Vec3;

    fn trace() -> Trace {
        let at = |t_ms, event| TimedEvent { t_ms, event };
        let pointer = Event::Pointer {
            origin: Vec3::ZERO,
            dir: Vec3::NEG_Z,
        };
        Trace::new(vec![
            at(0.0, pointer),
            at(100.0, Event::Button(Button::Down)),
            at(300.0, Event::Button(Button::Up)),
        ])
        .expect("trace")
    }

    /// Frames every 50 ms, each shown 10 ms after it starts; the SC buffer shows the state of
    /// 120 ms before the frame.
    fn frames(bad: &[u64]) -> Vec<FrameRecord> {
        (0..10u64)
            .map(|i| {
                let t = i as f64 * 50.0;
                FrameRecord {
                    index: i,
                    t_ms: t,
                    shown_ms: t + 10.0,
                    events_applied: [0.0, 100.0, 300.0].iter().filter(|&&e| e <= t).count(),
                    sc_state_ms: (t >= 120.0).then_some(t - 120.0),
                    selected: if (100.0..300.0).contains(&t) {
                        vec![ObjectId(7)]
                    } else {
                        vec![]
                    },
                    audit: Some(FrameAudit {
                        bad_pixels: bad.get(i as usize).copied().unwrap_or(0),
                        ghost_pixels: bad.get(i as usize).copied().unwrap_or(0),
                        ..FrameAudit::default()
                    }),
                }
            })
            .collect()
    }

    #[test]
    fn latency_counts_to_the_first_frame_showing_the_event() {
        let l = latency(&trace(), &frames(&[]));
        // FC: events at 0, 100, 300 are in the frames starting then, shown 10 ms later.
        assert_eq!(l.fc_path_ms, vec![10.0, 10.0, 10.0]);
        // SC: the buffer of frame t shows state t − 120: event 0 first at t = 150 (state 30),
        // event 100 at t = 250 (state 130), event 300 at t = 450 (state 330).
        assert_eq!(l.sc_path_ms, vec![160.0, 160.0, 160.0]);
        assert_eq!((l.fc_not_shown, l.sc_not_shown), (0, 0));
        let l = latency(&trace(), &frames(&[])[..4]);
        assert_eq!((l.fc_not_shown, l.sc_not_shown), (1, 2));
        let shown: Vec<(f64, Option<f64>, Option<f64>)> = l
            .per_event
            .iter()
            .map(|e| (e.t_ms, e.fc_path_ms, e.sc_path_ms))
            .collect();
        assert_eq!(
            shown,
            [
                (0.0, Some(10.0), Some(160.0)),
                (100.0, Some(10.0), None),
                (300.0, None, None)
            ]
        );
    }

    #[test]
    fn events_own_the_frames_until_the_next_event() {
        // Artefacts in frame 3 (select window: frames 2..6) and frames 6, 7 (release window).
        let e = events(&trace(), &frames(&[0, 0, 0, 5, 0, 0, 9, 2, 0, 0]));
        assert_eq!(e.len(), 2);
        assert_eq!(e[0].kind, EventKind::Select);
        assert_eq!(e[0].fc_frame, Some(2));
        assert_eq!(e[0].object, Some(ObjectId(7)));
        assert_eq!(e[0].frames, 4);
        assert_eq!(e[0].artefact_frames, Some(1));
        assert_eq!(e[0].artefact_ms, Some(50.0));
        assert_eq!(e[0].peak.map(|p| p.bad_pixels), Some(5));
        assert_eq!(e[1].kind, EventKind::Release);
        assert_eq!(e[1].fc_frame, Some(6));
        assert_eq!(e[1].object, Some(ObjectId(7)));
        assert_eq!(e[1].frames, 4);
        assert_eq!(e[1].artefact_frames, Some(2));
        assert_eq!(e[1].peak.map(|p| p.ghost_pixels), Some(9));
    }

    #[test]
    fn unaudited_frames_give_no_artefact_figures() {
        let mut f = frames(&[]);
        f.iter_mut().for_each(|f| f.audit = None);
        let e = events(&trace(), &f);
        assert!(
            e.iter()
                .all(|e| e.artefact_frames.is_none() && e.peak.is_none())
        );
        // An event the run never reached has no frames.
        let e = events(&trace(), &frames(&[])[..3]);
        assert_eq!(e[1].fc_frame, None);
        assert_eq!(e[1].frames, 0);
    }
}
