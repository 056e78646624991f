//! What each FC period of an interleaved run held, and for an FC frame that missed its deadline,
//! which step made it miss.
//!
//! ```text
//! scheduled k                                    scheduled k+1
//! ├─late─┤─ FC frame k ─┤─ caller ─┤─ step ─┤─ step ─┤─ step ─┤       FC frame k+1 …
//!                                                    ▲
//!                           the first step of period k ending after scheduled k+1 is
//!                           what made FC frame k+1 late
//! ```
//!
//! An FC frame meets its deadline when it is composed within one period of its scheduled start.
//! A miss is laid on the first thing of the period before that ran past this frame's scheduled
//! start — the previous FC frame itself, the caller's handling of it, starting an SC frame, a
//! chunk or an export band — or, when nothing did, on the FC frame itself (it was longer than a
//! period). When the thing that ran past is the previous FC frame and that frame missed too, the
//! miss is a knock-on of the same cause: an SC step far longer than a period makes the next FC
//! frames start late one after the other, until they catch up with their schedule
//! ([`miss_causes`]).

/// One thing the SC did in a period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum StepKind {
    /// Starting an SC frame: its draw list, and clearing the store.
    Start,
    /// Capturing a chunk of this many triangles.
    Chunk(u64),
    /// Exporting and resolving a band of this many rows (in the fixed mode, the whole frame).
    Band(u32),
}

/// One step of the SC's share of a period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// What it did.
    pub kind: StepKind,
    /// What the adaptive model predicted it would take (ms), margin not included.
    pub predicted_ms: Option<f64>,
    /// What it took (ms).
    pub ms: f64,
    /// When it ended (ms since the run's start).
    pub end_ms: f64,
}

/// One FC period: the FC frame, then the SC's steps (times in ms since the run's start).
#[derive(Clone, Debug, PartialEq)]
pub struct PeriodRecord {
    /// The FC frame.
    pub fc_frame: u64,
    /// When it was due to start.
    pub scheduled_ms: f64,
    /// When it started.
    pub fc_start_ms: f64,
    /// When it was composed.
    pub fc_end_ms: f64,
    /// When the caller was done with it (the run's `on_frame`).
    pub handed_ms: f64,
    /// Whether it was composed within one period of `scheduled_ms`.
    pub hit: bool,
    /// The SC's steps after it, in order.
    pub steps: Vec<Step>,
}

/// What made an FC frame miss its deadline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum MissCause {
    /// An FC frame: this one, longer than its late start left, or the one before, longer than
    /// a period.
    FcFrame,
    /// The caller's handling of the FC frame before (keeping it for the audit, writing it).
    Caller,
    /// Starting an SC frame.
    ScStart,
    /// A chunk of the SC's triangles.
    Chunk,
    /// A band of the SC's export (the whole export in the fixed mode).
    ExportBand,
}

/// Misses counted by cause.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MissCounts {
    /// [`MissCause::FcFrame`].
    pub fc_frame: u64,
    /// [`MissCause::Caller`].
    pub caller: u64,
    /// [`MissCause::ScStart`].
    pub sc_start: u64,
    /// [`MissCause::Chunk`].
    pub chunk: u64,
    /// [`MissCause::ExportBand`].
    pub export_band: u64,
}

impl MissCounts {
    /// Counts the cause of every missed frame of `periods` (in order, see [`miss_causes`]).
    pub fn of(periods: &[PeriodRecord]) -> Self {
        let mut counts = MissCounts::default();
        for cause in miss_causes(periods) {
            match cause {
                Some(MissCause::FcFrame) => counts.fc_frame += 1,
                Some(MissCause::Caller) => counts.caller += 1,
                Some(MissCause::ScStart) => counts.sc_start += 1,
                Some(MissCause::Chunk) => counts.chunk += 1,
                Some(MissCause::ExportBand) => counts.export_band += 1,
                None => {}
            }
        }
        counts
    }

    /// Every miss counted.
    pub fn total(&self) -> u64 {
        self.fc_frame + self.caller + self.sc_start + self.chunk + self.export_band
    }
}

/// Why each frame of `periods` (in order) missed its deadline, `None` for those that did not:
/// [`miss_cause`], with a miss after a previous FC frame that ran late because it missed itself
/// laid on that frame's cause.
pub fn miss_causes(periods: &[PeriodRecord]) -> Vec<Option<MissCause>> {
    let mut causes: Vec<Option<MissCause>> = Vec::with_capacity(periods.len());
    for (k, this) in periods.iter().enumerate() {
        let before = k.checked_sub(1).and_then(|j| periods.get(j));
        let cause = match (miss_cause(before, this), before) {
            (Some(MissCause::FcFrame), Some(b)) if !b.hit && b.fc_end_ms > this.scheduled_ms => {
                causes.last().copied().flatten()
            }
            (cause, _) => cause,
        };
        causes.push(cause);
    }
    causes
}

/// Why `this` missed its deadline, given the period `before` it; `None` when it did not miss.
pub fn miss_cause(before: Option<&PeriodRecord>, this: &PeriodRecord) -> Option<MissCause> {
    if this.hit {
        return None;
    }
    let Some(before) = before else {
        return Some(MissCause::FcFrame);
    };
    let due = this.scheduled_ms;
    if before.fc_end_ms > due {
        return Some(MissCause::FcFrame);
    }
    if before.handed_ms > due {
        return Some(MissCause::Caller);
    }
    let step = before.steps.iter().find(|s| s.end_ms > due);
    Some(match step.map(|s| s.kind) {
        Some(StepKind::Start) => MissCause::ScStart,
        Some(StepKind::Chunk(_)) => MissCause::Chunk,
        Some(StepKind::Band(_)) => MissCause::ExportBand,
        None => MissCause::FcFrame,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn period(k: u64, fc: (f64, f64), steps: &[(StepKind, f64)], hit: bool) -> PeriodRecord {
        PeriodRecord {
            fc_frame: k,
            scheduled_ms: k as f64 * 10.0,
            fc_start_ms: fc.0,
            fc_end_ms: fc.1,
            handed_ms: fc.1,
            hit,
            steps: steps
                .iter()
                .map(|&(kind, end_ms)| Step {
                    kind,
                    predicted_ms: None,
                    ms: 1.0,
                    end_ms,
                })
                .collect(),
        }
    }

    #[test]
    fn a_miss_is_laid_on_the_step_that_crossed_the_next_start() {
        // Period 10 ms. Frame 1's period ends with a band crossing 20 ms by 12 ms: frame 2 misses.
        // Frame 2's own FC frame ends past 30 ms: frame 3 misses, on the FC frame.
        // Frame 4 starts on time but is longer than a period: the FC frame again.
        let periods = vec![
            period(0, (0.0, 2.0), &[(StepKind::Chunk(10), 9.0)], true),
            period(
                1,
                (10.0, 12.0),
                &[
                    (StepKind::Chunk(10), 18.0),
                    (StepKind::Band(8), 32.0),
                    (StepKind::Start, 33.0),
                ],
                true,
            ),
            period(2, (33.0, 35.0), &[], false),
            period(3, (35.0, 37.0), &[(StepKind::Chunk(5), 39.0)], true),
            period(4, (40.0, 51.0), &[], false),
        ];
        assert_eq!(
            miss_cause(Some(&periods[1]), &periods[2]),
            Some(MissCause::ExportBand)
        );
        assert_eq!(miss_cause(Some(&periods[0]), &periods[1]), None);
        assert_eq!(
            miss_cause(Some(&periods[3]), &periods[4]),
            Some(MissCause::FcFrame)
        );
        let counts = MissCounts::of(&periods);
        assert_eq!(
            counts,
            MissCounts {
                export_band: 1,
                fc_frame: 1,
                ..MissCounts::default()
            }
        );
        assert_eq!(counts.total(), 2);
    }

    #[test]
    fn frames_late_one_after_the_other_share_the_first_cause() {
        // A 40 ms chunk in period 0 makes frames 1, 2 and 3 start late; frame 4 is on time.
        let periods = vec![
            period(0, (0.0, 2.0), &[(StepKind::Chunk(900), 42.0)], true),
            period(1, (42.0, 44.0), &[], false),
            period(2, (44.0, 46.0), &[], false),
            period(3, (46.0, 48.0), &[], true),
            period(4, (40.0, 52.0), &[], false),
        ];
        let causes = miss_causes(&periods);
        let chunk = Some(MissCause::Chunk);
        assert_eq!(
            causes,
            vec![None, chunk, chunk, None, Some(MissCause::FcFrame)]
        );
        assert_eq!(MissCounts::of(&periods).chunk, 2);
    }

    #[test]
    fn a_miss_after_a_long_chunk_or_start_names_it() {
        let before = period(
            0,
            (0.0, 2.0),
            &[(StepKind::Start, 3.0), (StepKind::Chunk(900), 15.0)],
            true,
        );
        let this = period(1, (15.0, 27.0), &[], false);
        assert_eq!(miss_cause(Some(&before), &this), Some(MissCause::Chunk));
        let before = period(0, (0.0, 2.0), &[(StepKind::Start, 12.0)], true);
        assert_eq!(miss_cause(Some(&before), &this), Some(MissCause::ScStart));
        let mut before = period(0, (0.0, 2.0), &[], true);
        before.handed_ms = 14.0;
        assert_eq!(miss_cause(Some(&before), &this), Some(MissCause::Caller));
    }
}
