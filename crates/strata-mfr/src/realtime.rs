//! Slow and fast clients on their own threads in real time: the FC never waits for the SC.
//!
//! ```text
//! FC thread (calling thread, its own 1-thread pool)        SC thread (its own 1-thread pool)
//!   every 1/fc_hz:                                           loop until stopped:
//!     snapshot = authority.advance_to(now)                     s = newest snapshot (latest wins)
//!     publish snapshot ──────── triple buffer ───────────────► if s is new: render its objects
//!       and wake the SC                                          publish TransferBuffer
//!     sc = newest SC buffer ◄── triple buffer ────────────────┘
//!     render F through sc's view, compose                      else: sleep until woken
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
//!
//! # Variants ([`RealConfig`])
//!
//! - **transport**: the SC on a thread of this process ([`Transport::Thread`]), or in another
//!   process behind a TCP connection ([`Transport::Tcp`], see [`crate::tcp`]): network threads
//!   then carry snapshots out and buffers in, publishing into the same triple buffers, so the FC
//!   loop is the same;
//! - **SC load** ([`ScLoad`]): `Busy` (the SC renders every new snapshot), `Idle` (it renders
//!   the first snapshot only: the FC's time with the SC idle, the baseline of "the FC never
//!   waits"), `Off` (no SC: the FC draws every object every frame, the conventional single
//!   renderer);
//! - **SC priority** ([`ScPriority`]): `Low` raises the SC threads' nice value to 19 (Linux), so
//!   on a machine with fewer cores than busy threads the FC is scheduled first; over TCP it
//!   applies to the FC process's link threads, which decode and resolve the SC's buffers.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use strata_scene::Scene;

use crate::authority::{Authority, Snapshot};
use crate::client::Client;
use crate::compose::Composition;
use crate::simulate::{FcFrame, Migration, SimulateError, fc_frame, sc_render};
use crate::tcp::{FcLink, TcpOptions};
use crate::trace::Trace;
use crate::transfer::{Latest, Publisher, TransferBuffer, exchange};

/// How the SC reaches the FC.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Transport {
    /// A thread of this process; buffers are handed over as pointers.
    #[default]
    Thread,
    /// A slow client in another process (`strata mfr-slow --listen ADDR`), over TCP.
    Tcp(TcpOptions),
}

/// How much the SC works during a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ScLoad {
    /// The SC renders every new snapshot, as fast as it can.
    #[default]
    Busy,
    /// The SC renders the first snapshot once and then does nothing.
    Idle,
    /// No SC: the FC draws every object every frame (the conventional single renderer).
    Off,
}

/// The scheduling priority of the SC's threads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ScPriority {
    /// As the FC's.
    #[default]
    Normal,
    /// Nice 19 (Linux): the SC gets the cores the FC leaves.
    Low,
}

/// A real-time run's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct RealConfig {
    /// FC frames per second, in (0, 1000].
    pub fc_hz: f64,
    /// How objects move between the clients.
    pub migration: Migration,
    /// How the FC composes.
    pub composition: Composition,
    /// Frame size, width × height.
    pub size: (u32, u32),
    /// FC frames to run.
    pub fc_frames: u64,
    /// Where the SC runs.
    pub transport: Transport,
    /// How much the SC works.
    pub sc_load: ScLoad,
    /// The SC threads' priority: the in-process SC's, or over TCP the FC's link threads
    /// (receiving, decoding and resolving SC buffers); `strata mfr-slow` has its own option.
    pub sc_priority: ScPriority,
}

impl RealConfig {
    /// `fc_frames` FC frames of `size` at 30 Hz: predictive migration, deep composition, the SC
    /// busy on a thread of normal priority.
    pub fn new(size: (u32, u32), fc_frames: u64) -> Self {
        RealConfig {
            fc_hz: 30.0,
            migration: Migration::Predictive,
            composition: Composition::Deep,
            size,
            fc_frames,
            transport: Transport::Thread,
            sc_load: ScLoad::Busy,
            sc_priority: ScPriority::Normal,
        }
    }
}

/// Something that went wrong beside the FC loop without stopping it: the SC link failed, sent
/// garbage, a priority could not be set. The FC keeps composing with its last good buffer.
#[derive(Clone, Debug, PartialEq)]
pub struct Incident {
    /// Milliseconds since the run started.
    pub t_ms: f64,
    /// What happened, for a person.
    pub what: String,
}

impl std::fmt::Display for Incident {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "at {:.0} ms: {}", self.t_ms, self.what)
    }
}

/// A shared, append-only list of incidents with the run's time origin.
#[derive(Clone, Debug)]
pub(crate) struct Incidents {
    origin: Instant,
    list: Arc<Mutex<Vec<Incident>>>,
}

impl Incidents {
    pub(crate) fn new(origin: Instant) -> Self {
        Incidents {
            origin,
            list: Arc::new(Mutex::new(Vec::new())),
        }
    }

    /// Records `what` now, unless it repeats the last incident word for word (a link that keeps
    /// failing the same way is one incident).
    pub(crate) fn record(&self, what: impl Into<String>) {
        let what = what.into();
        let t_ms = self.origin.elapsed().as_secs_f64() * 1e3;
        let mut list = self
            .list
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if list.last().is_none_or(|last| last.what != what) {
            list.push(Incident { t_ms, what });
        }
    }

    pub(crate) fn take(&self) -> Vec<Incident> {
        std::mem::take(
            &mut *self
                .list
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        )
    }
}

/// What a real-time run measured (milliseconds unless named).
#[derive(Clone, Debug, Default)]
pub struct RealStats {
    /// Each FC frame's time from its start to its composed frame.
    pub fc_frame_ms: Vec<f64>,
    /// Each SC frame's render time (over TCP: as the SC reported it).
    pub sc_frame_ms: Vec<f64>,
    /// Microseconds to publish a snapshot or an SC buffer into a triple buffer.
    pub publish_us: Vec<f64>,
    /// Microseconds to take the newest value out of a triple buffer.
    pub read_us: Vec<f64>,
    /// FC deadlines missed (the frame took longer than 1/fc_hz).
    pub fc_deadlines_missed: u64,
    /// Trouble beside the FC loop (TCP: the link died, garbage, a refused handshake), in order.
    pub incidents: Vec<Incident>,
    /// TCP: bytes of each SC buffer received (header and frame message).
    pub sc_bytes: Vec<u64>,
    /// TCP: each SC buffer's frame message from its first to its last byte received (ms).
    pub transfer_ms: Vec<f64>,
    /// TCP: each SC buffer's decoding and resolving on the receiving thread (ms).
    pub decode_ms: Vec<f64>,
}

/// Raises the calling thread's nice value to 19 (Linux), so the scheduler runs it only when the
/// FC does not need the core.
pub fn lower_thread_priority() -> Result<(), String> {
    #[cfg(target_os = "linux")]
    {
        rustix::process::setpriority_process(Some(rustix::thread::gettid()), 19)
            .map_err(|e| format!("cannot lower the thread's priority: {e}"))
    }
    #[cfg(not(target_os = "linux"))]
    {
        Err("lowering a thread's priority is supported on Linux only".into())
    }
}

/// A one-thread rayon pool named `name`; `low` lowers its worker's priority (failures recorded).
fn pool(name: &str, low: bool, incidents: &Incidents) -> Result<rayon::ThreadPool, SimulateError> {
    let incidents = incidents.clone();
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .thread_name({
            let name = name.to_owned();
            move |_| name.clone()
        })
        .start_handler(move |_| {
            if low && let Err(e) = lower_thread_priority() {
                incidents.record(e);
            }
        })
        .build()
        .map_err(|e| SimulateError::Thread(e.to_string()))
}

/// The in-process SC's figures: each frame's render time (ms), each publish's time (µs).
type ScTimes = (Vec<f64>, Vec<f64>);

/// What the in-process SC shows while it runs, and how it is paced: read and set from other
/// threads without waiting.
#[derive(Debug, Default)]
pub(crate) struct ScGauge {
    /// Frames published so far.
    frames: AtomicU64,
    /// The last frame's render time, in microseconds.
    last_us: AtomicU64,
    /// The shortest time from one frame's start to the next's, in microseconds (0: none). A
    /// live session sets it to make a light scene's SC as slow as a heavy one's.
    min_interval_us: AtomicU64,
    /// Why the SC stopped, if it failed.
    failure: Mutex<Option<String>>,
}

impl ScGauge {
    /// Frames published so far and the last one's render time (ms).
    pub(crate) fn read(&self) -> (u64, f64) {
        (
            self.frames.load(Ordering::Acquire),
            self.last_us.load(Ordering::Acquire) as f64 / 1e3,
        )
    }

    /// Holds the SC to at most one frame every `interval` (zero: as fast as it can).
    pub(crate) fn set_min_interval(&self, interval: Duration) {
        let us = u64::try_from(interval.as_micros()).unwrap_or(u64::MAX);
        self.min_interval_us.store(us, Ordering::Release);
    }

    /// Why the SC stopped, if it failed.
    pub(crate) fn failure(&self) -> Option<String> {
        self.failure
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    fn fail(&self, why: String) {
        *self
            .failure
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(why);
    }

    fn min_interval(&self) -> Duration {
        Duration::from_micros(self.min_interval_us.load(Ordering::Acquire))
    }
}

/// The longest an idle SC sleeps before it looks for a snapshot again by itself; it is woken
/// at once by [`ScThread::wake`] when one is published, so this only bounds the cost of a
/// publisher that forgets to wake it.
const SC_IDLE_WAIT: Duration = Duration::from_millis(100);

/// The in-process SC: renders the newest snapshot whenever it is free, until `stop`. Between
/// frames it sleeps until woken ([`ScThread::wake`], after each snapshot published and at the
/// stop) or until its pacing lets it render again: an idle SC costs nothing.
pub(crate) struct ScThread {
    handle: std::thread::JoinHandle<Result<ScTimes, SimulateError>>,
}

impl ScThread {
    /// Starts the SC; with `keep_times`, it records every frame's render and publish times
    /// (returned by [`ScThread::join`]; a live session, which never reads them, does not keep
    /// them, so it does not grow with every frame).
    #[allow(
        clippy::too_many_arguments,
        reason = "the SC's channels, each its own type"
    )]
    pub(crate) fn spawn(
        scene: Arc<Scene>,
        config: &RealConfig,
        mut snapshots_in: Latest<Snapshot>,
        mut buffers_out: Publisher<TransferBuffer>,
        stop: Arc<AtomicBool>,
        incidents: &Incidents,
        gauge: Arc<ScGauge>,
        keep_times: bool,
    ) -> Result<Self, SimulateError> {
        let low = config.sc_priority == ScPriority::Low;
        let sc_pool = pool("strata-mfr-sc", low, incidents)?;
        let (migration, (width, height)) = (config.migration, config.size);
        let incidents = incidents.clone();
        let handle = std::thread::Builder::new()
            .name("strata-mfr-sc".into())
            .spawn(move || -> Result<ScTimes, SimulateError> {
                if low && let Err(e) = lower_thread_priority() {
                    incidents.record(e);
                }
                let mut client = Client::new(width, height);
                let (mut frame_ms, mut publish_us) = (Vec::new(), Vec::new());
                let mut last: Option<u64> = None;
                let mut sc_frame = 0;
                let mut last_start: Option<Instant> = None;
                while !stop.load(Ordering::Acquire) {
                    let paced = last_start.is_some_and(|t| t.elapsed() < gauge.min_interval());
                    let newest = snapshots_in.latest().cloned();
                    let Some(snapshot) = newest.filter(|s| !paced && Some(s.id) != last) else {
                        let wait = match last_start {
                            Some(t) if paced => gauge.min_interval().saturating_sub(t.elapsed()),
                            _ => SC_IDLE_WAIT,
                        };
                        std::thread::park_timeout(wait.min(SC_IDLE_WAIT));
                        continue;
                    };
                    let start = Instant::now();
                    last_start = Some(start);
                    let buffer = sc_pool
                        .install(|| sc_render(&scene, &mut client, &snapshot, migration, sc_frame))
                        .inspect_err(|e| gauge.fail(e.to_string()))?;
                    let took = start.elapsed();
                    if keep_times {
                        frame_ms.push(took.as_secs_f64() * 1e3);
                    }
                    let took_us = u64::try_from(took.as_micros()).unwrap_or(u64::MAX);
                    gauge.last_us.store(took_us, Ordering::Release);
                    let buffer = Arc::new(buffer);
                    let start = Instant::now();
                    let old = buffers_out.publish(buffer);
                    if keep_times {
                        publish_us.push(start.elapsed().as_secs_f64() * 1e6);
                    }
                    drop(old);
                    gauge.frames.fetch_add(1, Ordering::AcqRel);
                    last = Some(snapshot.id);
                    sc_frame += 1;
                }
                Ok((frame_ms, publish_us))
            })
            .map_err(|e| SimulateError::Thread(e.to_string()))?;
        Ok(ScThread { handle })
    }

    /// Wakes the SC if it sleeps: a snapshot was published, or `stop` was set.
    pub(crate) fn wake(&self) {
        self.handle.thread().unpark();
    }

    /// Joins the thread (after `stop` was set); its frame times and publish times.
    pub(crate) fn join(self) -> Result<ScTimes, SimulateError> {
        self.wake();
        self.handle
            .join()
            .map_err(|_| SimulateError::Thread("the slow client's thread panicked".into()))?
    }
}

/// Where the SC is during a run.
enum Sc {
    None,
    Thread(ScThread),
    Tcp(Box<FcLink>),
}

/// Runs `config.fc_frames` FC frames at `config.fc_hz` with an SC as `config` says; calls
/// `on_frame` on the FC thread after each frame's time is taken (its own time is not counted in
/// the frame, but it delays the next one, so keep it cheap: collect, audit afterwards).
///
/// # Errors
/// A bad rate, a thread that cannot start, a client that cannot render, or — before the first
/// frame — a TCP slow client that cannot be reached or refuses the handshake. Trouble with the
/// TCP link after that is an [`Incident`], not an error.
pub fn run_real(
    scene: Arc<Scene>,
    trace: Trace,
    config: &RealConfig,
    mut on_frame: impl FnMut(&FcFrame),
) -> Result<RealStats, SimulateError> {
    let fc_hz = config.fc_hz;
    if !(fc_hz.is_finite() && fc_hz > 0.0 && fc_hz <= 1000.0) {
        return Err(SimulateError::Rate(fc_hz));
    }
    let period = Duration::from_secs_f64(1.0 / fc_hz);
    let (mut snapshots_out, snapshots_in) = exchange::<Snapshot>();
    let (buffers_out, mut buffers_in) = exchange::<TransferBuffer>();
    let stop = Arc::new(AtomicBool::new(false));
    let origin = Instant::now();
    let incidents = Incidents::new(origin);
    let fc_pool = pool("strata-mfr-fc", false, &incidents)?;
    let sc = match (&config.transport, config.sc_load) {
        (_, ScLoad::Off) => Sc::None,
        (Transport::Thread, _) => Sc::Thread(ScThread::spawn(
            Arc::clone(&scene),
            config,
            snapshots_in,
            buffers_out,
            Arc::clone(&stop),
            &incidents,
            Arc::default(),
            true,
        )?),
        (Transport::Tcp(options), _) => Sc::Tcp(Box::new(FcLink::start(
            &scene,
            config,
            options,
            snapshots_in,
            buffers_out,
            incidents.clone(),
        )?)),
    };

    let mut stats = RealStats::default();
    let result = (|| -> Result<(), SimulateError> {
        let mut authority = Authority::new(&scene, trace);
        let mut fc_client = Client::new(config.size.0, config.size.1);
        for index in 0..config.fc_frames {
            let deadline = origin + period.mul_f64(index as f64);
            if let Some(wait) = deadline.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
            let start = Instant::now();
            let t_ms = start.duration_since(origin).as_secs_f64() * 1e3;
            let snapshot = authority.advance_to(t_ms);
            // An idle SC is given the first snapshot only.
            if config.sc_load == ScLoad::Busy || index == 0 {
                let shared = Arc::clone(&snapshot);
                let p = Instant::now();
                let old = snapshots_out.publish(shared);
                stats.publish_us.push(p.elapsed().as_secs_f64() * 1e6);
                drop(old);
                if let Sc::Thread(thread) = &sc {
                    thread.wake();
                }
            }
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
                    config.migration,
                    config.composition,
                )
            })?;
            let took = start.elapsed();
            stats.fc_frame_ms.push(took.as_secs_f64() * 1e3);
            stats.fc_deadlines_missed += u64::from(took > period);
            on_frame(&work.into_frame(index, t_ms, snapshot, sc, config.composition));
        }
        Ok(())
    })();
    stop.store(true, Ordering::Release);
    let sc_result = match sc {
        Sc::None => Ok(()),
        Sc::Thread(thread) => thread.join().map(|(sc_frame_ms, sc_publish_us)| {
            stats.sc_frame_ms = sc_frame_ms;
            stats.publish_us.extend(sc_publish_us);
        }),
        Sc::Tcp(link) => {
            let report = link.finish();
            stats.sc_frame_ms = report.sc_frame_ms;
            stats.sc_bytes = report.sc_bytes;
            stats.transfer_ms = report.transfer_ms;
            stats.decode_ms = report.decode_ms;
            stats.publish_us.extend(report.publish_us);
            Ok(())
        }
    };
    result?;
    sc_result?;
    stats.incidents = incidents.take();
    Ok(stats)
}
