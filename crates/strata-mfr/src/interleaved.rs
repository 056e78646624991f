//! Both clients on one thread: each FC frame first, then the SC's frame in chunks of geometry and
//! its export in bands of rows, in the time left before the FC's next deadline (seed 004 §5.3,
//! fig. 5.5: one graphics device serving the fast and the slow client by time slicing).
//!
//! ```text
//! FC period k:   ├─ FC frame ─┤─ chunk ─┤─ chunk ─┤ idle ├   scheduled start of k+1
//! FC period k+1: ├─ FC frame ─┤─ chunk ─┤─ band ─┤─ band ─┤ idle ├
//! FC period k+2: ├─ FC frame ─┤─ band ─┤─ band ─┤ swap ┤─ start ─┤─ chunk ─┤ idle ├
//!
//! FC frame: compose with the newest SC buffer     chunk: capture triangles into the SC's store
//! band: export, resolve and append rows of it     swap: the assembled frame becomes the newest
//! ```
//!
//! The SC renders into its own client (the *back store*, a linked-list A-buffer whose captures
//! accumulate, see [`strata_stores::Method`]). An SC frame is the objects the migration policy
//! leaves it at the snapshot of the FC frame during which it started; its triangles — objects in
//! scene order, each object's triangles in order — are captured in consecutive ranges
//! ([`strata_raster::FrameInput::triangle_range`]). When every range is captured, the store is
//! exported in bands of rows ([`BandedExport`]: each band exported, resolved and appended, the
//! same frame and image as one export, bit for bit); after the last band the new
//! [`TransferBuffer`] replaces the one the FC composes with (an `Arc` swap). The next SC frame
//! starts at the next FC frame whose snapshot is newer than the last one the SC rendered.
//!
//! # Step size ([`Chunking`])
//!
//! - **adaptive**: each chunk and each band is as large as the cost model predicts fits in the
//!   time left before the deadline (the next FC frame's scheduled start), with a safety margin.
//!   The model ([`estimate`]) is a fixed cost per step, measured before the run, plus costs per
//!   triangle (per row) and per fragment — the fragments each object and each row made in the
//!   previous SC frame — fitted by non-negative least squares over the recent steps; the margin
//!   is the 90th percentile of the recent measured-over-predicted ratios. When not even a small
//!   step ([`MIN_TRIANGLES`] triangles, [`MIN_ROWS`] rows) fits, the period's SC work ends —
//!   unless the period before did no SC work either: then one step sized to
//!   [`STARVED_SHARE`] of a period runs, so FC frames longer than their period slow the SC
//!   down (to a quarter of a period every second FC frame) but cannot starve it.
//! - **fixed:N**: chunks of N triangles while the deadline has not passed — a chunk may run past
//!   it — and the export in one step, when its last time fits in the time left or when it was
//!   already put off once; one chunk at least every period. The seed's hand-set chunking, kept
//!   as the baseline.
//!
//! Before the run the SC's first frame is rendered in one call, twice (the second is timed: the
//! one-shot reference the chunking overhead is measured against, and the cost model's prior);
//! the SC keeps that client, whose store's pool has grown to the frame. One FC frame is rendered
//! and dropped, so that neither client's first frame in the run grows its pool.
//!
//! # What each period held ([`periods`])
//!
//! Every period's FC frame and SC steps are recorded with their times and predictions; a missed
//! FC deadline is laid on the step that ran past the next frame's scheduled start
//! ([`MissCounts`]).
//!
//! Deep composition with predictive migration is exact for any SC age, so an interleaved run
//! audits to zero artefacts, as the two-thread run does: the SC buffer is only older.

mod bands;
pub mod estimate;
pub mod periods;

use std::sync::Arc;
use std::time::{Duration, Instant};

use strata_core::ObjectId;
use strata_raster::FrameInput;
use strata_scene::Scene;

pub use self::bands::BandedExport;
use self::estimate::{
    BandFeatures, ChunkFeatures, ObjectCost, ObjectFragments, StepCost, largest_fitting,
};
pub use self::periods::{
    MissCause, MissCounts, PeriodRecord, Step, StepKind, miss_cause, miss_causes,
};
use crate::authority::{Authority, Snapshot};
use crate::client::Client;
use crate::realtime::RealConfig;
use crate::simulate::{FcFrame, SimulateError, fc_frame, sc_share};
use crate::trace::Trace;
use crate::transfer::TransferBuffer;

/// The fewest triangles worth an adaptive chunk (fewer when fewer are left).
pub const MIN_TRIANGLES: u64 = 64;

/// The fewest rows worth an adaptive band (fewer when fewer are left).
pub const MIN_ROWS: u32 = 4;

/// The share of a period an adaptive step is sized to when the SC would otherwise starve: the
/// period before had no time left for it, and this one has none either.
pub const STARVED_SHARE: f64 = 0.25;

/// How the SC's frame is cut into chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Chunking {
    /// Chunks and export bands sized from the cost model to fit the time left.
    Adaptive,
    /// A fixed number of triangles per chunk, more than 0; the export in one step.
    Fixed(u64),
}

/// A `--interleaved` value that is neither `adaptive` nor `fixed:N` with N > 0.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("cannot read chunking '{0}': give adaptive or fixed:N (N triangles per chunk, N > 0)")]
pub struct ChunkingError(String);

impl std::str::FromStr for Chunking {
    type Err = ChunkingError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "adaptive" {
            return Ok(Chunking::Adaptive);
        }
        s.strip_prefix("fixed:")
            .and_then(|n| n.parse::<u64>().ok())
            .filter(|&n| n > 0)
            .map(Chunking::Fixed)
            .ok_or_else(|| ChunkingError(s.to_owned()))
    }
}

impl std::fmt::Display for Chunking {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Chunking::Adaptive => f.write_str("adaptive"),
            Chunking::Fixed(n) => write!(f, "fixed:{n}"),
        }
    }
}

/// One SC frame of an interleaved run.
#[derive(Clone, Debug, PartialEq)]
pub struct ScFrameRecord {
    /// The snapshot it shows.
    pub snapshot_id: u64,
    /// The FC frame after which its first chunk was captured.
    pub started_fc_frame: u64,
    /// The FC frame after which it was swapped in (the next FC frame composes with it).
    pub swapped_fc_frame: u64,
    /// Chunks it was captured in.
    pub chunks: u32,
    /// Bands it was exported in.
    pub bands: u32,
    /// Triangles it drew.
    pub triangles: u64,
    /// Its chunks' capture time, summed (ms).
    pub capture_ms: f64,
    /// Its bands' export and resolve time, summed (ms).
    pub export_ms: f64,
}

impl ScFrameRecord {
    /// FC periods whose leftover time it took: from the one it started in to the one it was
    /// swapped in at, both counted.
    pub fn fc_frames(&self) -> u64 {
        self.swapped_fc_frame - self.started_fc_frame + 1
    }
}

/// What an interleaved run measured (milliseconds unless named).
#[derive(Clone, Debug, Default)]
pub struct InterleavedStats {
    /// Each FC frame's own time, from its start to its composed frame.
    pub fc_frame_ms: Vec<f64>,
    /// How late each FC frame started after its scheduled time (SC work running past it).
    pub fc_start_late_ms: Vec<f64>,
    /// FC frames composed within one period of their scheduled start.
    pub fc_deadlines_hit: u64,
    /// Every SC frame swapped in, in order.
    pub sc_frames: Vec<ScFrameRecord>,
    /// Each chunk's capture time.
    pub chunk_ms: Vec<f64>,
    /// Each chunk's triangles.
    pub chunk_triangles: Vec<u64>,
    /// Each export band's time.
    pub band_ms: Vec<f64>,
    /// Each export band's rows.
    pub band_rows: Vec<u32>,
    /// Every period: its FC frame and SC steps, with times and predictions.
    pub periods: Vec<PeriodRecord>,
    /// The reference: the first snapshot's SC frame rendered in one call before the run, warm.
    pub one_shot_sc_ms: f64,
    /// The chunk model at the end of the run: ms per capture call (measured), per thousand
    /// triangles and per ten thousand fragments (fitted).
    pub chunk_model: [f64; 3],
    /// The band model at the end of the run: ms per band (measured), per hundred rows and per
    /// ten thousand fragments (fitted).
    pub band_model: [f64; 3],
}

impl InterleavedStats {
    /// The share of FC frames that met their deadline, in [0, 1]; 0 for an empty run.
    pub fn deadline_hit_rate(&self) -> f64 {
        match self.fc_frame_ms.len() {
            0 => 0.0,
            n => self.fc_deadlines_hit as f64 / n as f64,
        }
    }

    /// The mean number of FC periods an SC frame took ([`ScFrameRecord::fc_frames`]).
    pub fn mean_sc_fc_frames(&self) -> Option<f64> {
        mean(self.sc_frames.iter().map(|r| r.fc_frames() as f64))
    }

    /// The mean time of an SC frame's chunks and export over the one-shot SC frame's, minus
    /// one: what chunking costs (0.1 = 10 % more work).
    pub fn chunking_overhead(&self) -> Option<f64> {
        let chunked = mean(self.sc_frames.iter().map(|r| r.capture_ms + r.export_ms))?;
        (self.one_shot_sc_ms > 0.0).then(|| chunked / self.one_shot_sc_ms - 1.0)
    }

    /// The missed deadlines by what made them miss.
    pub fn misses(&self) -> MissCounts {
        MissCounts::of(&self.periods)
    }

    /// The measured-over-predicted ratios of the adaptive model's steps of `kind` (chunks when
    /// `chunks`, else bands).
    pub fn estimate_ratios(&self, chunks: bool) -> Vec<f64> {
        self.periods
            .iter()
            .flat_map(|p| &p.steps)
            .filter(|s| matches!(s.kind, StepKind::Chunk(_)) == chunks)
            .filter(|s| !matches!(s.kind, StepKind::Start))
            .filter_map(|s| s.predicted_ms.filter(|&p| p > 0.0).map(|p| s.ms / p))
            .collect()
    }
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0u64), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// Where an SC frame is.
enum Phase {
    /// Capturing chunks; the next triangle to capture.
    Capture(u64),
    /// Exporting bands.
    Export(BandedExport),
}

/// The SC frame in progress.
struct ScJob<'s> {
    snapshot: Arc<Snapshot>,
    rendered: Vec<(ObjectId, u64)>,
    excluded: Vec<ObjectId>,
    input: FrameInput<'s>,
    features: ChunkFeatures,
    phase: Phase,
    record: ScFrameRecord,
    export_put_off: bool,
}

/// The adaptive mode's models and what they are fitted on.
struct Estimates {
    chunk: StepCost<2>,
    band: StepCost<2>,
    /// The previous SC frame's fragments per object.
    objects: ObjectFragments,
    /// The previous SC frame's fragments per row.
    rows: BandFeatures,
    /// The last export's time, for the fixed mode's one-step export (ms).
    last_export_ms: Option<f64>,
}

/// The SC side of the loop: its back store, the job in progress, the newest buffer, estimates.
struct ScSide<'s> {
    scene: &'s Scene,
    config: &'s RealConfig,
    chunking: Chunking,
    client: Client,
    job: Option<ScJob<'s>>,
    newest: Option<Arc<TransferBuffer>>,
    last_snapshot: Option<u64>,
    sc_frames: u64,
    estimates: Estimates,
    /// Whether the last period ran no SC step.
    idle_last_period: bool,
    /// The FC's period (ms).
    period_ms: f64,
    /// The last SC frame start's time (ms).
    start_ms: f64,
}

/// What a period's next SC step is.
enum Next {
    Chunk { n: u64, predicted: Option<f64> },
    Band { rows: u32, predicted: Option<f64> },
    Swap,
    Stop,
}

impl<'s> ScSide<'s> {
    /// Starts an SC frame of `snapshot` unless the SC already rendered it or one is under way;
    /// true if it started one.
    fn start(&mut self, snapshot: &Arc<Snapshot>, fc_index: u64) -> Result<bool, SimulateError> {
        if self.job.is_some() || self.last_snapshot == Some(snapshot.id) {
            return Ok(false);
        }
        let (rendered, excluded, indices) = sc_share(snapshot, self.config.migration);
        let input = self
            .client
            .frame_input(self.scene, snapshot, &snapshot.view, &indices)?;
        self.client.begin_parts()?;
        let total = input.triangle_count();
        let features = self.chunk_features(&input);
        self.job = Some(ScJob {
            snapshot: Arc::clone(snapshot),
            rendered,
            excluded,
            input,
            features,
            phase: Phase::Capture(0),
            record: ScFrameRecord {
                snapshot_id: snapshot.id,
                started_fc_frame: fc_index,
                swapped_fc_frame: fc_index,
                chunks: 0,
                bands: 0,
                triangles: total,
                capture_ms: 0.0,
                export_ms: 0.0,
            },
            export_put_off: false,
        });
        Ok(true)
    }

    /// The chunk features of `input`'s objects: each object's fragments from the previous SC
    /// frame, or (an object it did not draw) the frame's mean fragments per triangle.
    fn chunk_features(&self, input: &FrameInput<'_>) -> ChunkFeatures {
        let known = &self.estimates.objects;
        let drawn: u64 = input
            .objects
            .iter()
            .filter(|o| known.get(o.id).is_some())
            .map(|o| o.triangles.len() as u64)
            .sum();
        let per_triangle = known.total() as f64 / drawn.max(1) as f64;
        ChunkFeatures::new(
            input
                .objects
                .iter()
                .map(|o| {
                    let triangles = o.triangles.len() as u64;
                    ObjectCost {
                        triangles,
                        fragments: known
                            .get(o.id)
                            .map_or(per_triangle * triangles as f64, |f| f as f64),
                    }
                })
                .collect(),
        )
    }

    /// The next step for a period with `left_ms` before its deadline; `progressed` when this
    /// period already ran one.
    fn next_step(&self, left_ms: f64, progressed: bool) -> Next {
        let Some(job) = self.job.as_ref() else {
            return Next::Stop;
        };
        // When the SC would otherwise starve, a step of a share of the period runs, time left
        // or not.
        let starving = !progressed && self.idle_last_period;
        let left_ms = if starving {
            left_ms.max(self.period_ms * STARVED_SHARE)
        } else {
            left_ms
        };
        let e = &self.estimates;
        match (&job.phase, self.chunking) {
            (Phase::Capture(next), Chunking::Fixed(n)) => {
                if left_ms > 0.0 || !progressed {
                    Next::Chunk {
                        n: n.min(job.features.total() - next),
                        predicted: None,
                    }
                } else {
                    Next::Stop
                }
            }
            (Phase::Capture(next), Chunking::Adaptive) => {
                let next = *next;
                let remaining = job.features.total() - next;
                let budget = left_ms / e.chunk.margin();
                let cost = |n| e.chunk.predict(&job.features.features(next, n));
                let fit = largest_fitting(remaining, budget, cost);
                let n = if fit >= MIN_TRIANGLES.min(remaining) {
                    fit
                } else if starving {
                    MIN_TRIANGLES.min(remaining)
                } else {
                    return Next::Stop;
                };
                Next::Chunk {
                    n,
                    predicted: Some(cost(n)),
                }
            }
            (Phase::Export(export), _) if export.is_done() => Next::Swap,
            (Phase::Export(export), Chunking::Fixed(_)) => {
                let fits = e.last_export_ms.is_none_or(|ms| ms <= left_ms);
                if fits || job.export_put_off {
                    Next::Band {
                        rows: export.rows_left(),
                        predicted: None,
                    }
                } else {
                    Next::Stop
                }
            }
            (Phase::Export(export), Chunking::Adaptive) => {
                let (done, left_rows) = (export.rows_done(), export.rows_left());
                let budget = left_ms / e.band.margin();
                let cost = |rows: u64| e.band.predict(&e.rows.features(done, rows as u32));
                let fit = largest_fitting(u64::from(left_rows), budget, cost) as u32;
                let rows = if fit >= MIN_ROWS.min(left_rows) {
                    fit
                } else if starving {
                    MIN_ROWS.min(left_rows)
                } else {
                    return Next::Stop;
                };
                Next::Band {
                    rows,
                    predicted: Some(cost(u64::from(rows))),
                }
            }
        }
    }

    /// Starts, captures, exports and swaps until `deadline` (as [`Chunking`] allows), recording
    /// the steps into `period` and `stats`.
    fn fill(
        &mut self,
        snapshot: &Arc<Snapshot>,
        fc_index: u64,
        deadline: Instant,
        clock: Clock,
        period: &mut PeriodRecord,
        stats: &mut InterleavedStats,
    ) -> Result<(), SimulateError> {
        let mut progressed = false;
        let left_ms = || {
            deadline
                .saturating_duration_since(Instant::now())
                .as_secs_f64()
                * 1e3
        };
        loop {
            // A new SC frame starts when the last start's time fits, or the SC would starve.
            if left_ms() > self.start_ms || (!progressed && self.idle_last_period) {
                let begin = Instant::now();
                if self.start(snapshot, fc_index)? {
                    let step = clock.step(StepKind::Start, None, begin);
                    self.start_ms = step.ms;
                    period.steps.push(step);
                }
            }
            match self.next_step(left_ms(), progressed) {
                Next::Stop => {
                    // The fixed mode's export, put off once.
                    if let Some(job) = self.job.as_mut()
                        && matches!(job.phase, Phase::Export(_))
                    {
                        job.export_put_off = true;
                    }
                    break;
                }
                Next::Swap => self.swap_in(fc_index, stats)?,
                Next::Chunk { n, predicted } => {
                    period
                        .steps
                        .extend(self.capture(n, predicted, clock, stats)?);
                    progressed = true;
                }
                Next::Band { rows, predicted } => {
                    period
                        .steps
                        .extend(self.export_band(rows, predicted, clock, stats)?);
                    progressed = true;
                }
            }
        }
        self.idle_last_period = !progressed;
        Ok(())
    }

    /// Captures the next `n` triangles of the job (nothing when it is not capturing).
    fn capture(
        &mut self,
        n: u64,
        predicted: Option<f64>,
        clock: Clock,
        stats: &mut InterleavedStats,
    ) -> Result<Option<Step>, SimulateError> {
        let Some(job) = self.job.as_mut() else {
            return Ok(None);
        };
        let Phase::Capture(next) = job.phase else {
            return Ok(None);
        };
        let x = job.features.features(next, n);
        let part = job.input.triangle_range(next..next + n);
        let begin = Instant::now();
        self.client.capture_part(&part)?;
        let step = clock.step(StepKind::Chunk(n), predicted, begin);
        job.record.chunks += 1;
        job.record.capture_ms += step.ms;
        stats.chunk_ms.push(step.ms);
        stats.chunk_triangles.push(n);
        let e = &mut self.estimates;
        e.chunk.observe(&x, predicted, step.ms);
        job.phase = if next + n >= job.features.total() {
            let mut export = BandedExport::new(&self.client, self.scene.background);
            // Room for a tenth more than the previous frame held: appending a band then never
            // moves the frame assembled so far (a copy the band model does not expect).
            let expected = e.rows.total() + e.rows.total() / 10;
            export.reserve(usize::try_from(expected).unwrap_or(0));
            Phase::Export(export)
        } else {
            Phase::Capture(next + n)
        };
        Ok(Some(step))
    }

    /// Exports the next `rows` rows of the job (nothing when it is not exporting).
    fn export_band(
        &mut self,
        rows: u32,
        predicted: Option<f64>,
        clock: Clock,
        stats: &mut InterleavedStats,
    ) -> Result<Option<Step>, SimulateError> {
        let Some(job) = self.job.as_mut() else {
            return Ok(None);
        };
        let Phase::Export(export) = &mut job.phase else {
            return Ok(None);
        };
        let e = &mut self.estimates;
        let x = e.rows.features(export.rows_done(), rows);
        let whole = export.rows_done() == 0 && rows >= export.rows_left();
        let begin = Instant::now();
        export.step(&self.client, rows)?;
        let step = clock.step(StepKind::Band(rows), predicted, begin);
        job.record.bands += 1;
        job.record.export_ms += step.ms;
        stats.band_ms.push(step.ms);
        stats.band_rows.push(rows);
        e.band.observe(&x, predicted, step.ms);
        if whole {
            e.last_export_ms = Some(step.ms);
        }
        Ok(Some(step))
    }

    /// Makes the exported job the newest SC buffer (nothing when no job is exporting).
    fn swap_in(
        &mut self,
        fc_index: u64,
        stats: &mut InterleavedStats,
    ) -> Result<(), SimulateError> {
        let Some(mut job) = self.job.take() else {
            return Ok(());
        };
        let Phase::Export(export) = job.phase else {
            self.job = Some(job);
            return Ok(());
        };
        let ((frame, image), objects) = export.finish_counted()?;
        self.estimates.objects = objects;
        self.estimates.rows =
            BandFeatures::from_offsets(frame.width(), frame.height(), frame.offsets());
        let snapshot = &job.snapshot;
        let buffer = TransferBuffer {
            sc_frame: self.sc_frames,
            snapshot_id: snapshot.id,
            snapshot_t_ms: snapshot.t_ms,
            view: snapshot.view,
            rendered: std::mem::take(&mut job.rendered),
            excluded: std::mem::take(&mut job.excluded),
            frame,
            image,
        };
        // The pointer swap; the old buffer goes when its last frame record does.
        self.newest = Some(Arc::new(buffer));
        self.last_snapshot = Some(snapshot.id);
        self.sc_frames += 1;
        job.record.swapped_fc_frame = fc_index;
        stats.sc_frames.push(job.record);
        Ok(())
    }
}

/// The run's time origin, for the period records.
#[derive(Clone, Copy)]
struct Clock(Instant);

impl Clock {
    /// Milliseconds from the origin to `t`.
    fn ms(self, t: Instant) -> f64 {
        t.saturating_duration_since(self.0).as_secs_f64() * 1e3
    }

    /// A step of `kind` that began at `begin` and ends now.
    fn step(self, kind: StepKind, predicted_ms: Option<f64>, begin: Instant) -> Step {
        let end = Instant::now();
        Step {
            kind,
            predicted_ms,
            ms: end.duration_since(begin).as_secs_f64() * 1e3,
            end_ms: self.ms(end),
        }
    }
}

/// The one-shot reference: the SC frame of `snapshot` in one capture and one export, timed the
/// second time (the first grows the store's pool and warms the thread up). Returns the client,
/// whose grown pool the SC keeps (the run's first SC frame does not grow it again), the buffer,
/// the frame's time (ms) and the cost models: their fixed costs measured on an empty chunk and
/// an empty band, their priors the frame's capture and export times spread over its fragments.
fn one_shot_reference(
    scene: &Scene,
    config: &RealConfig,
    snapshot: &Snapshot,
) -> Result<(Client, TransferBuffer, f64, Estimates), SimulateError> {
    let (width, height) = config.size;
    let mut client = Client::new(width, height);
    let (rendered, excluded, indices) = sc_share(snapshot, config.migration);
    let input = client.frame_input(scene, snapshot, &snapshot.view, &indices)?;
    let ms = |a: Instant, b: Instant| b.duration_since(a).as_secs_f64() * 1e3;
    let one_shot = |client: &mut Client| -> Result<_, SimulateError> {
        client.begin_parts()?;
        let begin = Instant::now();
        client.capture_part(&input)?;
        let captured = Instant::now();
        let frame = client.export()?;
        let image = frame.resolve(scene.background);
        Ok((
            frame,
            image,
            ms(begin, captured),
            ms(captured, Instant::now()),
        ))
    };
    one_shot(&mut client)?;
    let (frame, image, capture_ms, export_ms) = one_shot(&mut client)?;
    let (chunk_fixed_ms, band_fixed_ms) = empty_step_ms(&mut client, &input, scene.background)?;
    // Priors: every millisecond on the fragments (per ten thousand of them).
    let per_fragments = 1e4 / frame.fragment_count().max(1) as f64;
    let mut objects = ObjectFragments::default();
    objects.add(frame.objects());
    let estimates = Estimates {
        chunk: StepCost::new(chunk_fixed_ms, [0.0, capture_ms * per_fragments]),
        band: StepCost::new(band_fixed_ms, [0.0, export_ms * per_fragments]),
        objects,
        rows: BandFeatures::from_offsets(width, height, frame.offsets()),
        last_export_ms: Some(export_ms),
    };
    let buffer = TransferBuffer {
        sc_frame: 0,
        snapshot_id: snapshot.id,
        snapshot_t_ms: snapshot.t_ms,
        view: snapshot.view,
        rendered,
        excluded,
        frame,
        image,
    };
    Ok((client, buffer, capture_ms + export_ms, estimates))
}

/// Tries with nothing to capture or export, to time: the least of [`EMPTY_STEP_TRIES`].
const EMPTY_STEP_TRIES: usize = 5;

/// The time (ms) of capturing an empty chunk of `input` and of exporting an empty band: the
/// fixed costs per step.
fn empty_step_ms(
    client: &mut Client,
    input: &FrameInput<'_>,
    background: [f32; 3],
) -> Result<(f64, f64), SimulateError> {
    let (mut chunk, mut band) = (f64::INFINITY, f64::INFINITY);
    let empty = input.triangle_range(0..0);
    for _ in 0..EMPTY_STEP_TRIES {
        let begin = Instant::now();
        client.capture_part(&empty)?;
        chunk = chunk.min(begin.elapsed().as_secs_f64() * 1e3);
        let mut export = BandedExport::new(client, background);
        let begin = Instant::now();
        export.step(client, 0)?;
        band = band.min(begin.elapsed().as_secs_f64() * 1e3);
    }
    Ok((chunk, band))
}

/// Runs `config.fc_frames` FC frames at `config.fc_hz` with the SC interleaved on the same
/// thread (a one-thread pool), its frames cut as `chunking` says; `on_frame` is called after
/// each FC frame, before the SC's share of the period (its time counts against the SC).
/// `config`'s transport, SC load and SC priority do not apply: the SC is busy, on this thread.
///
/// # Errors
/// A bad rate, a pool that cannot start, or a client that cannot render.
pub fn run_interleaved(
    scene: &Scene,
    trace: Trace,
    config: &RealConfig,
    chunking: Chunking,
    mut on_frame: impl FnMut(&FcFrame),
) -> Result<InterleavedStats, SimulateError> {
    let fc_hz = config.fc_hz;
    if !(fc_hz.is_finite() && fc_hz > 0.0 && fc_hz <= 1000.0) {
        return Err(SimulateError::Rate(fc_hz));
    }
    let period = Duration::from_secs_f64(1.0 / fc_hz);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .thread_name(|_| "strata-mfr-interleaved".into())
        .build()
        .map_err(|e| SimulateError::Thread(e.to_string()))?;
    let (width, height) = config.size;
    let mut authority = Authority::new(scene, trace);
    let mut stats = InterleavedStats::default();

    let first = authority.advance_to(0.0);
    let (sc_client, initial, one_shot_ms, estimates) =
        pool.install(|| one_shot_reference(scene, config, &first))?;
    stats.one_shot_sc_ms = one_shot_ms;

    let mut fc_client = Client::new(width, height);
    let mut sc = ScSide {
        scene,
        config,
        chunking,
        client: sc_client,
        job: None,
        // The SC's first frame is ready when the run starts (as an SC that rendered the first
        // state before the FC began): until then the FC would draw everything itself.
        newest: Some(Arc::new(initial)),
        last_snapshot: Some(first.id),
        sc_frames: 1,
        estimates,
        idle_last_period: false,
        period_ms: period.as_secs_f64() * 1e3,
        start_ms: 0.0,
    };
    // One FC frame before the run, discarded: the FC's first frame would otherwise also grow
    // its store's pool and miss its deadline for it, as the SC's first frame would.
    let newest = sc.newest.clone();
    pool.install(|| {
        fc_frame(
            scene,
            &mut fc_client,
            &first,
            newest.as_deref(),
            config.migration,
            config.composition,
        )
    })?;
    let origin = Instant::now();
    let clock = Clock(origin);
    for index in 0..config.fc_frames {
        let scheduled = origin + period.mul_f64(index as f64);
        if let Some(wait) = scheduled.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let start = Instant::now();
        stats
            .fc_start_late_ms
            .push(start.duration_since(scheduled).as_secs_f64() * 1e3);
        let t_ms = start.duration_since(origin).as_secs_f64() * 1e3;
        let snapshot = authority.advance_to(t_ms);
        let newest = sc.newest.clone();
        let work = pool.install(|| {
            fc_frame(
                scene,
                &mut fc_client,
                &snapshot,
                newest.as_deref(),
                config.migration,
                config.composition,
            )
        })?;
        let done = Instant::now();
        stats
            .fc_frame_ms
            .push(done.duration_since(start).as_secs_f64() * 1e3);
        let hit = done.duration_since(scheduled) <= period;
        stats.fc_deadlines_hit += u64::from(hit);
        on_frame(&work.into_frame(
            index,
            t_ms,
            Arc::clone(&snapshot),
            newest,
            config.composition,
        ));
        let mut record = PeriodRecord {
            fc_frame: index,
            scheduled_ms: clock.ms(scheduled),
            fc_start_ms: clock.ms(start),
            fc_end_ms: clock.ms(done),
            handed_ms: clock.ms(Instant::now()),
            hit,
            steps: Vec::new(),
        };
        let deadline = scheduled + period;
        pool.install(|| sc.fill(&snapshot, index, deadline, clock, &mut record, &mut stats))?;
        stats.periods.push(record);
    }
    stats.chunk_model = sc.estimates.chunk.model();
    stats.band_model = sc.estimates.band.model();
    Ok(stats)
}
