//! Both clients on one thread: each FC frame first, then the SC's frame in chunks of geometry in
//! the time left before the FC's next deadline (seed 004 §5.3, fig. 5.5: one graphics device
//! serving the fast and the slow client by time slicing).
//!
//! ```text
//! FC period k:  ├─ FC frame ─┤─ SC chunk ─┤─ SC chunk ─┤─ (export) ─┤ idle ├  deadline k+1
//!                  compose with            capture into the SC's       pointer swap: the new
//!                  the newest SC buffer    back store (accumulates)    SC buffer is the newest
//! ```
//!
//! The SC renders into its own client (the *back store*, a linked-list A-buffer whose captures
//! accumulate, see [`strata_stores::Method`]). An SC frame is the objects the migration policy
//! leaves it at the snapshot of the FC frame during which it started; its triangles — objects in
//! scene order, each object's triangles in order — are captured in consecutive ranges
//! ([`strata_raster::FrameInput::triangle_range`]). When every range is captured, the store is
//! exported as a DeepFrame, resolved, and the new [`TransferBuffer`] replaces the one the FC
//! composes with (an `Arc` swap). The next SC frame starts at the next FC frame whose snapshot is
//! newer than the last one the SC rendered.
//!
//! # Chunk size ([`Chunking`])
//!
//! - **adaptive**: a running estimate of the capture cost per triangle (an exponential average of
//!   each chunk's time over its triangles, the first chunk a probe of [`PROBE_TRIANGLES`]) sizes
//!   each chunk to fill [`FILL_SHARE`] of the time left before the deadline; less than
//!   [`MIN_TRIANGLES`] worth of time left ends the period's SC work;
//! - **fixed:N**: chunks of N triangles while the deadline has not passed — a chunk may run past
//!   it; kept to compare.
//!
//! Every period captures one chunk at least (adaptive: [`MIN_TRIANGLES`]), even with no time
//! left, so an FC frame longer than its period slows the SC down but cannot starve it. The SC's
//! first frame is rendered in one call before the FC starts (it is also the one-shot reference
//! the chunking overhead is measured against).
//!
//! The export is one step: it runs when its last measured time fits in the time left, or when it
//! was already put off once (so a frame too short for any export still finishes its SC frames).
//!
//! Deep composition with predictive migration is exact for any SC age, so an interleaved run
//! audits to zero artefacts, as the two-thread run does: the SC buffer is only older.

use std::sync::Arc;
use std::time::{Duration, Instant};

use strata_core::ObjectId;
use strata_raster::FrameInput;
use strata_scene::Scene;

use crate::authority::{Authority, Snapshot};
use crate::client::Client;
use crate::realtime::RealConfig;
use crate::simulate::{FcFrame, SimulateError, fc_frame, sc_render, sc_share};
use crate::trace::Trace;
use crate::transfer::TransferBuffer;

/// Triangles in the adaptive mode's first chunk, before any cost is known.
pub const PROBE_TRIANGLES: u64 = 1024;

/// The fewest triangles worth an adaptive chunk.
pub const MIN_TRIANGLES: u64 = 64;

/// The share of the time left before the deadline an adaptive chunk is sized to fill.
pub const FILL_SHARE: f64 = 0.8;

/// Weight of the newest chunk in the running cost estimate.
const COST_WEIGHT: f64 = 0.3;

/// How the SC's frame is cut into chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Chunking {
    /// Sized from the measured cost per triangle to fill the time left.
    Adaptive,
    /// A fixed number of triangles per chunk, more than 0.
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
    /// Triangles it drew.
    pub triangles: u64,
    /// Its chunks' capture time, summed (ms).
    pub capture_ms: f64,
    /// Its export and resolve (ms).
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
    /// The reference: the first snapshot's SC frame rendered in one call before the run, warm.
    pub one_shot_sc_ms: f64,
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
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0u64), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// The SC frame being captured.
struct ScJob<'s> {
    snapshot: Arc<Snapshot>,
    rendered: Vec<(ObjectId, u64)>,
    excluded: Vec<ObjectId>,
    input: FrameInput<'s>,
    total: u64,
    next: u64,
    record: ScFrameRecord,
    export_put_off: bool,
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
    /// Running capture cost per triangle (ms).
    cost_per_triangle: Option<f64>,
    /// The last export's time (ms).
    export_ms: Option<f64>,
}

impl<'s> ScSide<'s> {
    /// Starts an SC frame of `snapshot` unless the SC already rendered it.
    fn start(&mut self, snapshot: &Arc<Snapshot>, fc_index: u64) -> Result<(), SimulateError> {
        if self.job.is_some() || self.last_snapshot == Some(snapshot.id) {
            return Ok(());
        }
        let (rendered, excluded, indices) = sc_share(snapshot, self.config.migration);
        let input = self
            .client
            .frame_input(self.scene, snapshot, &snapshot.view, &indices)?;
        self.client.begin_parts()?;
        let total = input.triangle_count();
        self.job = Some(ScJob {
            snapshot: Arc::clone(snapshot),
            rendered,
            excluded,
            input,
            total,
            next: 0,
            record: ScFrameRecord {
                snapshot_id: snapshot.id,
                started_fc_frame: fc_index,
                swapped_fc_frame: fc_index,
                chunks: 0,
                triangles: total,
                capture_ms: 0.0,
                export_ms: 0.0,
            },
            export_put_off: false,
        });
        Ok(())
    }
}

/// Triangles for the next chunk with `left` before the deadline, given the running cost per
/// triangle; 0 to stop for this period.
fn chunk_size(chunking: Chunking, cost_per_triangle: Option<f64>, left: Duration) -> u64 {
    let left_ms = left.as_secs_f64() * 1e3;
    match (chunking, cost_per_triangle) {
        (Chunking::Fixed(n), _) => {
            if left_ms > 0.0 {
                n
            } else {
                0
            }
        }
        (Chunking::Adaptive, None) => PROBE_TRIANGLES,
        (Chunking::Adaptive, Some(cost)) => {
            let n = (left_ms * FILL_SHARE / cost.max(1e-9)) as u64;
            if n < MIN_TRIANGLES { 0 } else { n }
        }
    }
}

impl<'s> ScSide<'s> {
    /// Captures chunks and exports until `deadline` (as [`Chunking`] allows), recording into
    /// `stats`.
    fn fill(
        &mut self,
        snapshot: &Arc<Snapshot>,
        fc_index: u64,
        deadline: Instant,
        stats: &mut InterleavedStats,
    ) -> Result<(), SimulateError> {
        // One chunk per period at least, even past the deadline, so that an FC frame longer
        // than its period does not starve the SC.
        let mut progressed = false;
        loop {
            self.start(snapshot, fc_index)?;
            let Some(job) = self.job.as_mut() else {
                return Ok(());
            };
            let left = deadline.saturating_duration_since(Instant::now());
            if job.next < job.total {
                let n = match chunk_size(self.chunking, self.cost_per_triangle, left) {
                    0 if progressed => return Ok(()),
                    0 => match self.chunking {
                        Chunking::Fixed(n) => n,
                        Chunking::Adaptive => MIN_TRIANGLES,
                    },
                    n => n,
                }
                .min(job.total - job.next);
                progressed = true;
                let part = job.input.triangle_range(job.next..job.next + n);
                let start = Instant::now();
                self.client.capture_part(&part)?;
                let ms = start.elapsed().as_secs_f64() * 1e3;
                job.next += n;
                job.record.chunks += 1;
                job.record.capture_ms += ms;
                stats.chunk_ms.push(ms);
                stats.chunk_triangles.push(n);
                let cost = ms / n as f64;
                self.cost_per_triangle = Some(match self.cost_per_triangle {
                    None => cost,
                    Some(c) => c + COST_WEIGHT * (cost - c),
                });
                continue;
            }
            let fits = self
                .export_ms
                .is_none_or(|ms| ms <= left.as_secs_f64() * 1e3);
            if !fits && !job.export_put_off {
                job.export_put_off = true;
                return Ok(());
            }
            self.swap_in(fc_index, stats)?;
        }
    }

    /// Exports the finished job and makes it the newest SC buffer.
    fn swap_in(
        &mut self,
        fc_index: u64,
        stats: &mut InterleavedStats,
    ) -> Result<(), SimulateError> {
        let Some(mut job) = self.job.take() else {
            return Ok(());
        };
        let start = Instant::now();
        let frame = self.client.export()?;
        let image = frame.resolve(self.scene.background);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        self.export_ms = Some(ms);
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
        job.record.export_ms = ms;
        job.record.swapped_fc_frame = fc_index;
        stats.sc_frames.push(job.record);
        Ok(())
    }
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

    // The reference: one SC frame in one call, timed the second time (the first grows the
    // store's pool and warms the pool's thread up, as the run's first SC frame does).
    let first = authority.advance_to(0.0);
    let mut one_shot = Client::new(width, height);
    let mut initial = None;
    for _ in 0..2 {
        let start = Instant::now();
        initial =
            Some(pool.install(|| sc_render(scene, &mut one_shot, &first, config.migration, 0))?);
        stats.one_shot_sc_ms = start.elapsed().as_secs_f64() * 1e3;
    }
    drop(one_shot);

    let mut fc_client = Client::new(width, height);
    let mut sc = ScSide {
        scene,
        config,
        chunking,
        client: Client::new(width, height),
        job: None,
        // The SC's first frame is ready when the run starts (as an SC that rendered the first
        // state before the FC began): until then the FC would draw everything itself.
        newest: initial.map(Arc::new),
        last_snapshot: Some(first.id),
        sc_frames: 1,
        cost_per_triangle: None,
        export_ms: None,
    };
    let origin = Instant::now();
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
        stats.fc_deadlines_hit += u64::from(done.duration_since(scheduled) <= period);
        on_frame(&work.into_frame(
            index,
            t_ms,
            Arc::clone(&snapshot),
            newest,
            config.composition,
        ));
        let deadline = scheduled + period;
        pool.install(|| sc.fill(&snapshot, index, deadline, &mut stats))?;
    }
    Ok(stats)
}
