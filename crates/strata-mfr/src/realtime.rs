//! Slow and fast clients on their own threads in real time: the FC never waits for the SC.
//!
//! ```text
//! FC thread (calling thread, its own 1-thread pool)        SC thread (its own 1-thread pool)
//!   every 1/fc_hz:                                           loop until stopped:
//!     snapshot = authority.advance_to(now)                     s = newest snapshot (latest wins)
//!     publish snapshot ──────── triple buffer ───────────────► if s is new: render its objects
//!     sc = newest SC buffer ◄── triple buffer ──────────────── publish TransferBuffer
//!     render F through sc's view, compose                      else: sleep 1 ms
//!     sleep to the next deadline
//! ```
//!
//! Both hand-overs are wait-free triple buffers of `Arc`s ([`crate::transfer::exchange`]), so the
//! FC's frame time does not depend on what the SC is doing, beyond sharing the machine. The FC
//! owns the state authority (as the seed's FC process hosted the master state): the SC renders
//! whatever snapshot is newest when it becomes free.
//!
//! Deep composition with predictive migration is exact for *any* timing (see `simulate.rs` and
//! `docs/mfr.md`), so a real-time run audits to zero artefacts too; the times it records are the
//! benchmark figures: FC frame time, SC frame time, and the time to publish and to read a buffer.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use strata_scene::Scene;

use crate::authority::{Authority, Snapshot};
use crate::client::Client;
use crate::compose::Composition;
use crate::simulate::{FcFrame, Migration, SimulateError, fc_frame, sc_render};
use crate::trace::Trace;
use crate::transfer::{TransferBuffer, exchange};

/// What a real-time run measured (milliseconds unless named).
#[derive(Clone, Debug, Default)]
pub struct RealStats {
    /// Each FC frame's time from its start to its composed frame.
    pub fc_frame_ms: Vec<f64>,
    /// Each SC frame's render time.
    pub sc_frame_ms: Vec<f64>,
    /// Microseconds to publish a snapshot or an SC buffer into a triple buffer.
    pub publish_us: Vec<f64>,
    /// Microseconds to take the newest value out of a triple buffer.
    pub read_us: Vec<f64>,
    /// FC deadlines missed (the frame took longer than 1/fc_hz).
    pub fc_deadlines_missed: u64,
}

/// Runs `fc_frames` FC frames at `fc_hz` with an SC thread; calls `on_frame` on the FC thread
/// after each frame's time is taken (its own time is not counted in the frame, but it delays the
/// next one, so keep it cheap: collect, audit afterwards).
#[allow(
    clippy::too_many_arguments,
    reason = "the run's parameters, each documented"
)]
pub fn run_real(
    scene: Arc<Scene>,
    trace: Trace,
    fc_hz: f64,
    migration: Migration,
    composition: Composition,
    (width, height): (u32, u32),
    fc_frames: u64,
    mut on_frame: impl FnMut(&FcFrame),
) -> Result<RealStats, SimulateError> {
    if !(fc_hz.is_finite() && fc_hz > 0.0 && fc_hz <= 1000.0) {
        return Err(SimulateError::Rate(fc_hz));
    }
    let period = Duration::from_secs_f64(1.0 / fc_hz);
    let (mut snapshots_out, mut snapshots_in) = exchange::<Snapshot>();
    let (mut buffers_out, mut buffers_in) = exchange::<TransferBuffer>();
    let stop = Arc::new(AtomicBool::new(false));
    let pool = |name: &str| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .thread_name({
                let name = name.to_owned();
                move |_| name.clone()
            })
            .build()
            .map_err(|e| SimulateError::Thread(e.to_string()))
    };
    let (fc_pool, sc_pool) = (pool("strata-mfr-fc")?, pool("strata-mfr-sc")?);

    let sc_thread = {
        let (scene, stop) = (Arc::clone(&scene), Arc::clone(&stop));
        std::thread::Builder::new()
            .name("strata-mfr-sc".into())
            .spawn(move || -> Result<(Vec<f64>, Vec<f64>), SimulateError> {
                let mut client = Client::new(width, height);
                let (mut frame_ms, mut publish_us) = (Vec::new(), Vec::new());
                let mut last: Option<u64> = None;
                let mut sc_frame = 0;
                while !stop.load(Ordering::Acquire) {
                    let newest = snapshots_in.latest().cloned();
                    let Some(snapshot) = newest.filter(|s| Some(s.id) != last) else {
                        std::thread::sleep(Duration::from_millis(1));
                        continue;
                    };
                    let start = Instant::now();
                    let buffer = sc_pool.install(|| {
                        sc_render(&scene, &mut client, &snapshot, migration, sc_frame)
                    })?;
                    frame_ms.push(start.elapsed().as_secs_f64() * 1e3);
                    let buffer = Arc::new(buffer);
                    let start = Instant::now();
                    let old = buffers_out.publish(buffer);
                    publish_us.push(start.elapsed().as_secs_f64() * 1e6);
                    drop(old);
                    last = Some(snapshot.id);
                    sc_frame += 1;
                }
                Ok((frame_ms, publish_us))
            })
            .map_err(|e| SimulateError::Thread(e.to_string()))?
    };

    let mut stats = RealStats::default();
    let result = (|| -> Result<(), SimulateError> {
        let mut authority = Authority::new(&scene, trace);
        let mut fc_client = Client::new(width, height);
        let origin = Instant::now();
        for index in 0..fc_frames {
            let deadline = origin + period.mul_f64(index as f64);
            if let Some(wait) = deadline.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
            let start = Instant::now();
            let t_ms = start.duration_since(origin).as_secs_f64() * 1e3;
            let snapshot = authority.advance_to(t_ms);
            let shared = Arc::clone(&snapshot);
            let p = Instant::now();
            let old = snapshots_out.publish(shared);
            stats.publish_us.push(p.elapsed().as_secs_f64() * 1e6);
            drop(old);
            let r = Instant::now();
            let sc = buffers_in.latest().cloned();
            stats.read_us.push(r.elapsed().as_secs_f64() * 1e6);
            // Reading moves pointers only: an SC buffer the FC stops using is freed when its last
            // `Arc` goes (the frame record below, or the SC's next publish), outside these timings.
            let work = fc_pool.install(|| {
                fc_frame(
                    &scene,
                    &mut fc_client,
                    &snapshot,
                    sc.as_deref(),
                    migration,
                    composition,
                )
            })?;
            let took = start.elapsed();
            stats.fc_frame_ms.push(took.as_secs_f64() * 1e3);
            stats.fc_deadlines_missed += u64::from(took > period);
            on_frame(&work.into_frame(index, t_ms, snapshot, sc, composition));
        }
        Ok(())
    })();
    stop.store(true, Ordering::Release);
    let sc = sc_thread
        .join()
        .map_err(|_| SimulateError::Thread("the slow client's thread panicked".into()))?;
    result?;
    let (sc_frame_ms, sc_publish_us) = sc?;
    stats.sc_frame_ms = sc_frame_ms;
    stats.publish_us.extend(sc_publish_us);
    Ok(stats)
}
