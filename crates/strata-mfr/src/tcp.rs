//! The TCP transport: the slow client in another process (or on another machine), the fast client
//! never touching the socket and never waiting for it.
//!
//! ```text
//! FC process                                                  SC process (strata mfr-slow)
//!  FC thread ─► snapshots triple buffer ─► sender thread ══ MfrSnapshot ══► reader thread
//!                                           (newest only)                     │ triple buffer
//!  FC thread ◄─ buffers triple buffer ◄─── link thread  ◄══ MfrBuffer ════ render loop: newest
//!               (Arc<TransferBuffer>)      decode, resolve     + Frame        snapshot → DeepFrame
//!                                          the SC image                       → codec → (paced) send
//! ```
//!
//! The messages are strata-wire's (`strata_wire::mfr`, documented in `docs/wire-format.md`): a
//! handshake in both directions (protocol, the scene's name and [`scene_fingerprint`], the frame
//! size), state snapshots FC → SC, and SC → FC a buffer header (frame counter, snapshot id and
//! time, view, the `(id, version)` of every object rendered, the ids left out, the SC's render
//! time) followed by an ordinary frame message carrying the DeepFrame (any codec; `deep-lz4` by
//! default). The FC's link thread decodes the frame, resolves the SC image (the FC's starting
//! image) and publishes the [`TransferBuffer`] into the same triple buffer the in-process SC uses,
//! so the FC loop cannot tell the transports apart.
//!
//! # Failures
//!
//! Reaching the SC and the first handshake happen before the run starts: an unreachable SC or
//! one serving another scene or size is an error ([`TcpError`]) with a message that says so.
//! Everything after that — the SC dies (end of stream, reset), sends bytes that are not a strata
//! message, a message that fails its checksum or announces more than the limits, a frame of the
//! wrong size, an object list out of order — is an [`Incident`](crate::realtime::Incident): the
//! link is dropped, the FC goes on composing with the last good buffer, and the link thread
//! reconnects every 250 ms until the run ends. Ending the run shuts the socket down, which wakes
//! any blocked read or write: it never waits on a dead peer. The FC repeats its newest snapshot
//! at least every second; an SC that hears nothing for 10 s ([`ScServer::peer_silence`]) takes
//! the FC for gone (a machine that
//! vanished without closing its connection) and serves the next one.
//!
//! # Link emulation
//!
//! The SC can pace what it sends ([`ScServer::link_bytes_per_s`]) to emulate a slower network on
//! loopback, e.g. [`GIGABIT_BYTES_PER_S`], what gigabit Ethernet delivers to an application.

use std::io::Write;
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use glam::{Mat4, Vec3};
use strata_core::ObjectId;
use strata_scene::Scene;
use strata_wire::mfr::{MFR_PROTOCOL, MfrBuffer, MfrHello, MfrObject, MfrRole, MfrSnapshot};
use strata_wire::stream::{ReadError, read_message};
use strata_wire::{
    Codec, DecodeOptions, FrameHeader, MessageType, TransferMethod, WireError, decode_error,
    decode_frame, encode_error_into, encode_frame_into,
};

use crate::authority::{ObjectPose, Snapshot, ViewPose};
use crate::client::Client;
use crate::realtime::{Incidents, RealConfig, ScPriority, lower_thread_priority};
use crate::simulate::{Migration, SimulateError, sc_render};
use crate::state::ObjectState;
use crate::transfer::{Latest, Publisher, TransferBuffer, exchange};

/// What gigabit Ethernet delivers to an application, bytes per second (≈ 90 MB/s).
pub const GIGABIT_BYTES_PER_S: f64 = 90e6;

/// The FC sends its newest snapshot again after this long without a new one, so the SC can tell
/// a quiet FC from a vanished one.
const HEARTBEAT: Duration = Duration::from_secs(1);

/// How the FC reaches a slow client over TCP.
#[derive(Clone, Debug, PartialEq)]
pub struct TcpOptions {
    /// `HOST:PORT` of `strata mfr-slow --listen`.
    pub addr: String,
    /// Longest wait to connect, and for the handshake's reply.
    pub connect_timeout: Duration,
    /// Reconnect when the link fails during the run.
    pub reconnect: bool,
    /// Largest message accepted (bytes).
    pub max_message_bytes: u64,
}

impl TcpOptions {
    /// `addr` with a 5 s timeout, reconnecting, messages up to 1 GiB.
    pub fn new(addr: impl Into<String>) -> Self {
        TcpOptions {
            addr: addr.into(),
            connect_timeout: Duration::from_secs(5),
            reconnect: true,
            max_message_bytes: 1 << 30,
        }
    }
}

/// Why the TCP transport failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TcpError {
    /// The SC's address does not resolve or nothing answers there.
    #[error("cannot reach the slow client at {addr}: {reason}")]
    Connect {
        /// The address asked for.
        addr: String,
        /// Why.
        reason: String,
    },
    /// The peer sent an error message instead of the handshake (another scene, another size).
    #[error("the {peer} refused the connection: {reason}")]
    Refused {
        /// "slow client" or "fast client".
        peer: &'static str,
        /// Its message.
        reason: String,
    },
    /// The peer's handshake does not match ours.
    #[error("handshake failed: {0}")]
    Handshake(String),
    /// The socket failed.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// No whole message could be read.
    #[error("{0}")]
    Read(#[from] ReadError),
    /// A message is malformed.
    #[error("{0}")]
    Wire(#[from] WireError),
    /// A well-formed message that makes no sense here (wrong type, sizes, objects).
    #[error("{0}")]
    Protocol(String),
    /// The slow client could not render.
    #[error("{0}")]
    Render(Box<SimulateError>),
}

// ----- the scene both sides render ------------------------------------------------------------

/// A 64-bit FNV-1a hash of what decides a scene's pixels: camera, background, and per object its
/// id, material, model matrix and mesh (positions, normals, triangles). Both clients must agree.
pub fn scene_fingerprint(scene: &Scene) -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    let cam = &scene.camera;
    for v in [cam.eye, cam.target, cam.up] {
        h.f32s(&v.to_array());
    }
    h.f32s(&[cam.fovy_deg, cam.near, cam.far]);
    h.f32s(&scene.background);
    h.bytes(&(scene.objects.len() as u64).to_le_bytes());
    for o in &scene.objects {
        h.bytes(&o.id.0.to_le_bytes());
        h.f32s(&o.material.color);
        h.bytes(o.material.shading.name().as_bytes());
        h.f32s(&o.model_matrix(None, 0).to_cols_array());
        for p in o.mesh.positions().iter().chain(o.mesh.normals()) {
            h.f32s(p);
        }
        for t in o.mesh.triangles() {
            for i in t {
                h.bytes(&i.to_le_bytes());
            }
        }
    }
    h.0
}

struct Fnv(u64);

impl Fnv {
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ u64::from(x)).wrapping_mul(0x0100_0000_01b3);
        }
    }

    fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.bytes(&x.to_bits().to_le_bytes());
        }
    }
}

/// Our side's hello for `scene` at `size`.
fn hello(scene: &Scene, role: MfrRole, (width, height): (u32, u32)) -> MfrHello {
    MfrHello {
        protocol: MFR_PROTOCOL,
        role,
        width,
        height,
        fingerprint: scene_fingerprint(scene),
        scene: scene.name.clone(),
    }
}

/// Why `theirs` cannot talk to `ours` (`None`: it can). `size_must_match`: the SC was given a size.
fn mismatch(ours: &MfrHello, theirs: &MfrHello, size_must_match: bool) -> Option<String> {
    if theirs.protocol != ours.protocol {
        return Some(format!(
            "protocol version {} against {}: update both sides to the same strata",
            theirs.protocol, ours.protocol
        ));
    }
    if theirs.role == ours.role {
        return Some("both sides are the same kind of client".into());
    }
    let (fc, sc) = match ours.role {
        MfrRole::Fast => (ours, theirs),
        MfrRole::Slow => (theirs, ours),
    };
    if theirs.fingerprint != ours.fingerprint {
        return Some(format!(
            "the fast client renders scene '{}', the slow client '{}' (or a different version of \
             it): give both the same scene",
            fc.scene, sc.scene
        ));
    }
    if size_must_match && (theirs.width, theirs.height) != (ours.width, ours.height) {
        return Some(format!(
            "the fast client composes {}x{} frames, the slow client renders {}x{}: give both the \
             same --size",
            fc.width, fc.height, sc.width, sc.height
        ));
    }
    None
}

// ----- messages ---------------------------------------------------------------------------------

fn view_to_wire(v: &ViewPose) -> [f32; 9] {
    let mut out = [0f32; 9];
    out[..3].copy_from_slice(&v.eye.to_array());
    out[3..6].copy_from_slice(&v.target.to_array());
    out[6..].copy_from_slice(&v.up.to_array());
    out
}

fn view_from_wire(v: &[f32; 9]) -> ViewPose {
    ViewPose {
        eye: Vec3::new(v[0], v[1], v[2]),
        target: Vec3::new(v[3], v[4], v[5]),
        up: Vec3::new(v[6], v[7], v[8]),
    }
}

fn state_to_wire(s: ObjectState) -> u8 {
    match s {
        ObjectState::Inactive => 0,
        ObjectState::Over => 1,
        ObjectState::Selected => 2,
    }
}

fn state_from_wire(b: u8) -> ObjectState {
    match b {
        1 => ObjectState::Over,
        2 => ObjectState::Selected,
        _ => ObjectState::Inactive,
    }
}

/// The snapshot message for `s` under `migration`.
pub fn snapshot_to_wire(s: &Snapshot, migration: Migration) -> MfrSnapshot {
    MfrSnapshot {
        id: s.id,
        t_ms: s.t_ms,
        events_applied: s.events_applied as u64,
        migration: match migration {
            Migration::Naive => 0,
            Migration::Predictive => 1,
        },
        view: view_to_wire(&s.view),
        objects: s
            .objects
            .iter()
            .map(|o| MfrObject {
                id: o.id.0,
                offset: o.offset.to_array(),
                version: o.version,
                state: state_to_wire(o.state),
            })
            .collect(),
    }
}

/// The snapshot and migration a message carries, checked against `scene` (the same objects in
/// the same order, finite numbers).
pub fn snapshot_from_wire(
    m: &MfrSnapshot,
    scene: &Scene,
) -> Result<(Snapshot, Migration), TcpError> {
    if m.objects.len() != scene.objects.len() {
        return Err(TcpError::Protocol(format!(
            "a snapshot of {} objects for a scene of {}",
            m.objects.len(),
            scene.objects.len()
        )));
    }
    let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
    if !finite(&m.view) || !m.t_ms.is_finite() {
        return Err(TcpError::Protocol(
            "a snapshot with a view or time that is not finite".into(),
        ));
    }
    let mut objects = Vec::with_capacity(m.objects.len());
    for (o, s) in m.objects.iter().zip(&scene.objects) {
        if o.id != s.id.0 || !finite(&o.offset) {
            return Err(TcpError::Protocol(format!(
                "snapshot object {} does not match the scene's object {} ('{}')",
                o.id, s.id.0, s.name
            )));
        }
        objects.push(ObjectPose {
            id: ObjectId(o.id),
            offset: Vec3::from_array(o.offset),
            version: o.version,
            state: state_from_wire(o.state),
        });
    }
    let migration = if m.migration == 0 {
        Migration::Naive
    } else {
        Migration::Predictive
    };
    let snapshot = Snapshot {
        id: m.id,
        t_ms: m.t_ms,
        view: view_from_wire(&m.view),
        objects,
        events_applied: usize::try_from(m.events_applied).unwrap_or(usize::MAX),
        // The SC renders no lights (it makes shaded fragments or a G-buffer): none travel.
        lights: Vec::new(),
    };
    Ok((snapshot, migration))
}

/// Encodes an SC buffer as its two messages, header into `header`, DeepFrame into `frame` (both
/// replaced), with `codec`; `projection` is written into the frame message for other readers.
pub fn encode_buffer(
    buffer: &TransferBuffer,
    render_ms: f64,
    projection: Mat4,
    codec: Codec,
    header: &mut Vec<u8>,
    frame: &mut Vec<u8>,
) -> Result<(), TcpError> {
    MfrBuffer {
        sc_frame: buffer.sc_frame,
        snapshot_id: buffer.snapshot_id,
        snapshot_t_ms: buffer.snapshot_t_ms,
        render_ms,
        view: view_to_wire(&buffer.view),
        rendered: buffer.rendered.iter().map(|&(id, v)| (id.0, v)).collect(),
        excluded: buffer.excluded.iter().map(|id| id.0).collect(),
    }
    .encode_into(header)?;
    let frame_header = FrameHeader {
        frame_number: buffer.sc_frame,
        view: buffer.view.matrix().to_cols_array(),
        projection: projection.to_cols_array(),
        ..FrameHeader::default()
    };
    encode_frame_into(frame, &frame_header, &buffer.frame, codec)?;
    Ok(())
}

/// Strictly increasing, and every id one of `scene`'s.
fn plausible_ids(ids: impl Iterator<Item = u32> + Clone, scene: &Scene) -> bool {
    let increasing = ids.clone().zip(ids.clone().skip(1)).all(|(a, b)| a < b);
    increasing
        && ids
            .into_iter()
            .all(|id| scene.objects.iter().any(|o| o.id.0 == id))
}

/// Decodes an SC buffer from its two messages, checks it against `scene` and `size`, and
/// resolves its image. Returns the buffer and the SC's render time (ms).
pub fn decode_buffer(
    header: &[u8],
    frame: &[u8],
    scene: &Scene,
    size: (u32, u32),
    limits: &DecodeOptions,
) -> Result<(TransferBuffer, f64), TcpError> {
    let h = MfrBuffer::decode(header, limits)?;
    let f = decode_frame(frame, limits)?;
    if f.header.frame_number != h.sc_frame {
        return Err(TcpError::Protocol(format!(
            "buffer header of SC frame {} followed by the frame of SC frame {}",
            h.sc_frame, f.header.frame_number
        )));
    }
    // Full frames only: a difference or reprojection frame is a delta against a state an SC
    // frame does not have (and a reprojection frame's inserts are compacted, not the view).
    if f.header.transfer != TransferMethod::Full {
        return Err(TcpError::Protocol(format!(
            "an SC frame sent as a {:?} transfer, not as a full frame",
            f.header.transfer
        )));
    }
    if (f.frame.width(), f.frame.height()) != size {
        return Err(TcpError::Protocol(format!(
            "an SC frame of {}x{} for {}x{} frames",
            f.frame.width(),
            f.frame.height(),
            size.0,
            size.1
        )));
    }
    let rendered_ok = plausible_ids(h.rendered.iter().map(|r| r.0), scene);
    if !rendered_ok || !plausible_ids(h.excluded.iter().copied(), scene) {
        return Err(TcpError::Protocol(
            "an SC buffer whose object lists are out of order or name objects not in the scene"
                .into(),
        ));
    }
    if !h.view.iter().all(|x| x.is_finite()) || !h.snapshot_t_ms.is_finite() {
        return Err(TcpError::Protocol(
            "an SC buffer whose view or time is not finite".into(),
        ));
    }
    let image = f.frame.resolve(scene.background);
    let buffer = TransferBuffer {
        sc_frame: h.sc_frame,
        snapshot_id: h.snapshot_id,
        snapshot_t_ms: h.snapshot_t_ms,
        view: view_from_wire(&h.view),
        rendered: h
            .rendered
            .iter()
            .map(|&(id, v)| (ObjectId(id), v))
            .collect(),
        excluded: h.excluded.iter().map(|&id| ObjectId(id)).collect(),
        frame: f.frame,
        image,
    };
    Ok((buffer, h.render_ms))
}

/// Writes `parts` back to back, at most `bytes_per_s` on average when given: each 16 KiB is
/// released when a link of that rate would have finished carrying it, so the last byte arrives
/// `total / bytes_per_s` after the first is sent.
fn send_paced(
    w: &mut impl Write,
    parts: &[&[u8]],
    bytes_per_s: Option<f64>,
) -> std::io::Result<()> {
    let Some(rate) = bytes_per_s.filter(|r| r.is_finite() && *r > 0.0) else {
        for p in parts {
            w.write_all(p)?;
        }
        return w.flush();
    };
    let start = Instant::now();
    let mut sent = 0usize;
    for chunk in parts.iter().flat_map(|p| p.chunks(1 << 14)) {
        sent += chunk.len();
        let due = Duration::from_secs_f64(sent as f64 / rate);
        if let Some(wait) = due.checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
        w.write_all(chunk)?;
    }
    w.flush()
}

/// Reads the peer's hello (or its error message) on `stream` and checks it against `ours`.
fn read_hello(
    stream: &mut TcpStream,
    ours: &MfrHello,
    limits: &DecodeOptions,
    size_must_match: bool,
) -> Result<MfrHello, TcpError> {
    let peer = match ours.role {
        MfrRole::Fast => "slow client",
        MfrRole::Slow => "fast client",
    };
    let (kind, bytes) = read_message(stream, limits).map_err(|e| match e {
        ReadError::Closed => TcpError::Handshake(format!("the {peer} closed the connection")),
        ReadError::Wire(w) => {
            TcpError::Handshake(format!("the {peer} is not speaking strata: {w}"))
        }
        other => TcpError::Handshake(format!("no hello from the {peer}: {other}")),
    })?;
    match kind {
        MessageType::MfrHello => {}
        MessageType::Error => {
            return Err(TcpError::Refused {
                peer,
                reason: decode_error(&bytes, limits)?,
            });
        }
        other => {
            return Err(TcpError::Handshake(format!(
                "the {peer} sent a {other:?} message instead of its hello (is it a strata {}?)",
                if ours.role == MfrRole::Fast {
                    "mfr-slow"
                } else {
                    "mfr"
                }
            )));
        }
    }
    let theirs = MfrHello::decode(&bytes, limits)?;
    if let Some(why) = mismatch(ours, &theirs, size_must_match) {
        return Err(TcpError::Handshake(why));
    }
    Ok(theirs)
}

// ----- the FC side ------------------------------------------------------------------------------

/// Resolves `addr` and connects within `timeout`.
fn open(addr: &str, timeout: Duration) -> Result<TcpStream, TcpError> {
    let fail = |reason: String| TcpError::Connect {
        addr: addr.to_owned(),
        reason,
    };
    let addrs: Vec<SocketAddr> = addr
        .to_socket_addrs()
        .map_err(|e| fail(format!("not a HOST:PORT address ({e})")))?
        .collect();
    let mut last = "the name has no address".to_owned();
    for a in addrs {
        match TcpStream::connect_timeout(&a, timeout) {
            Ok(s) => {
                s.set_nodelay(true)?;
                return Ok(s);
            }
            Err(e) => last = e.to_string(),
        }
    }
    Err(fail(last))
}

/// The FC's handshake on a connected stream: its hello out, the SC's checked.
fn fc_handshake(
    stream: &mut TcpStream,
    ours: &MfrHello,
    timeout: Duration,
) -> Result<(), TcpError> {
    stream.set_read_timeout(Some(timeout))?;
    stream.set_write_timeout(Some(timeout))?;
    let mut out = Vec::new();
    ours.encode_into(&mut out);
    stream.write_all(&out)?;
    read_hello(stream, ours, &DecodeOptions::default(), true)?;
    stream.set_read_timeout(None)?;
    Ok(())
}

/// What the FC's link measured.
#[derive(Debug, Default)]
pub(crate) struct LinkReport {
    pub(crate) sc_frame_ms: Vec<f64>,
    pub(crate) sc_bytes: Vec<u64>,
    pub(crate) transfer_ms: Vec<f64>,
    pub(crate) decode_ms: Vec<f64>,
    pub(crate) publish_us: Vec<f64>,
}

/// What every thread of the FC's link shares.
#[derive(Clone)]
struct LinkContext {
    scene: Arc<Scene>,
    size: (u32, u32),
    migration: Migration,
    options: TcpOptions,
    /// Run the link threads at low priority.
    low_priority: bool,
    hello: MfrHello,
    limits: DecodeOptions,
    stop: Arc<AtomicBool>,
    /// The connection in use, so that ending the run can shut it down.
    current: Arc<Mutex<Option<TcpStream>>>,
    incidents: Incidents,
}

impl LinkContext {
    fn stopped(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }

    /// Makes `stream` the one [`FcLink::finish`] shuts down; false if the run already ended.
    fn register(&self, stream: &TcpStream) -> bool {
        let mut current = self.current.lock().unwrap_or_else(PoisonError::into_inner);
        if self.stopped() {
            return false;
        }
        *current = stream.try_clone().ok();
        true
    }

    /// Lowers the calling link thread's priority if asked to (a failure is an incident).
    fn lower_priority(&self) {
        if self.low_priority
            && let Err(e) = lower_thread_priority()
        {
            self.incidents.record(e);
        }
    }

    /// Sleeps `d` in small steps; false if the run ended meanwhile.
    fn pause(&self, d: Duration) -> bool {
        let end = Instant::now() + d;
        while Instant::now() < end {
            if self.stopped() {
                return false;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        !self.stopped()
    }

    /// Connects within `timeout` and shakes hands (registered first, so the run's end can
    /// interrupt the handshake).
    fn connect(&self, timeout: Duration) -> Result<TcpStream, TcpError> {
        let mut stream = open(&self.options.addr, timeout)?;
        if !self.register(&stream) {
            return Err(TcpError::Protocol("the run ended".into()));
        }
        fc_handshake(&mut stream, &self.hello, self.options.connect_timeout)?;
        Ok(stream)
    }
}

/// The FC's end of a TCP link to a slow client: a link thread receiving buffers (and
/// reconnecting), and per connection a sender thread sending snapshots.
pub(crate) struct FcLink {
    context: LinkContext,
    thread: std::thread::JoinHandle<LinkReport>,
}

impl FcLink {
    /// Connects to the SC, shakes hands, and starts the link's threads.
    pub(crate) fn start(
        scene: &Arc<Scene>,
        config: &RealConfig,
        options: &TcpOptions,
        snapshots: Latest<Snapshot>,
        buffers: Publisher<TransferBuffer>,
        incidents: Incidents,
    ) -> Result<Self, SimulateError> {
        let context = LinkContext {
            scene: Arc::clone(scene),
            size: config.size,
            migration: config.migration,
            options: options.clone(),
            low_priority: config.sc_priority == ScPriority::Low,
            hello: hello(scene, MfrRole::Fast, config.size),
            limits: DecodeOptions {
                max_body_bytes: options.max_message_bytes,
                ..DecodeOptions::default()
            },
            stop: Arc::new(AtomicBool::new(false)),
            current: Arc::new(Mutex::new(None)),
            incidents,
        };
        let stream = context
            .connect(options.connect_timeout)
            .map_err(SimulateError::from)?;
        let thread = {
            let context = context.clone();
            std::thread::Builder::new()
                .name("strata-mfr-link".into())
                .spawn(move || {
                    context.lower_priority();
                    supervise(&context, Some(stream), snapshots, buffers)
                })
                .map_err(|e| SimulateError::Thread(e.to_string()))?
        };
        Ok(FcLink { context, thread })
    }

    /// Ends the link: shuts the connection down (waking any blocked read or write) and joins.
    pub(crate) fn finish(self) -> LinkReport {
        {
            let current = self
                .context
                .current
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            self.context.stop.store(true, Ordering::Release);
            if let Some(s) = current.as_ref() {
                let _ = s.shutdown(Shutdown::Both);
            }
        }
        self.thread.join().unwrap_or_else(|_| {
            self.context
                .incidents
                .record("the slow client's link thread panicked");
            LinkReport::default()
        })
    }
}

/// The link thread: runs connections one after the other until the run ends.
fn supervise(
    context: &LinkContext,
    mut stream: Option<TcpStream>,
    mut snapshots: Latest<Snapshot>,
    mut buffers: Publisher<TransferBuffer>,
) -> LinkReport {
    let mut report = LinkReport::default();
    loop {
        if let Some(s) = stream.take() {
            let (back, outcome) = session(context, s, snapshots, &mut buffers, &mut report);
            if context.stopped() {
                break;
            }
            context.incidents.record(format!(
                "the slow client's link failed ({outcome}); composing with the last good buffer"
            ));
            match back {
                Some(s) if context.options.reconnect => snapshots = s,
                _ => break,
            }
        }
        if !context.pause(Duration::from_millis(250)) {
            break;
        }
        // At most a second per attempt: ending the run waits for an attempt in progress.
        match context.connect(context.options.connect_timeout.min(Duration::from_secs(1))) {
            Ok(s) => {
                context.incidents.record("reconnected to the slow client");
                stream = Some(s);
            }
            Err(_) if context.stopped() => break,
            Err(e) => context.incidents.record(format!("reconnecting: {e}")),
        }
    }
    report
}

/// One connection: a sender thread for snapshots, buffers received on this thread. Returns the
/// snapshot reader (for the next connection; `None` if the sender panicked) and why it ended.
fn session(
    context: &LinkContext,
    mut stream: TcpStream,
    snapshots: Latest<Snapshot>,
    buffers: &mut Publisher<TransferBuffer>,
    report: &mut LinkReport,
) -> (Option<Latest<Snapshot>>, String) {
    let writer = match stream.try_clone() {
        Ok(w) => w,
        Err(e) => return (Some(snapshots), e.to_string()),
    };
    let ended = Arc::new(AtomicBool::new(false));
    let sender = {
        let (context, ended) = (context.clone(), Arc::clone(&ended));
        std::thread::Builder::new()
            .name("strata-mfr-send".into())
            .spawn(move || {
                context.lower_priority();
                send_snapshots(&context, writer, snapshots, &ended)
            })
    };
    let sender = match sender {
        Ok(s) => s,
        Err(e) => return (None, format!("cannot start the sending thread: {e}")),
    };
    let received = receive_buffers(context, &mut stream, buffers, report);
    ended.store(true, Ordering::Release);
    let _ = stream.shutdown(Shutdown::Both);
    match sender.join() {
        Ok((snapshots, Some(send_error))) => (Some(snapshots), send_error),
        Ok((snapshots, None)) => (Some(snapshots), received.to_string()),
        Err(_) => (None, "the sending thread panicked".into()),
    }
}

/// Sends every new snapshot (the newest at the time) until the connection or the run ends;
/// returns the snapshot reader and the write error, if one ended it.
fn send_snapshots(
    context: &LinkContext,
    mut writer: TcpStream,
    mut snapshots: Latest<Snapshot>,
    ended: &AtomicBool,
) -> (Latest<Snapshot>, Option<String>) {
    let mut last_sent: Option<(u64, Instant)> = None;
    let mut out = Vec::new();
    while !ended.load(Ordering::Acquire) && !context.stopped() {
        // A new snapshot, or the same one again as a heartbeat after a quiet second.
        let due = |s: &Arc<Snapshot>| {
            last_sent.is_none_or(|(id, at)| id != s.id || at.elapsed() >= HEARTBEAT)
        };
        let newest = snapshots.latest().filter(|s| due(s)).cloned();
        let Some(s) = newest else {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        };
        let sent = snapshot_to_wire(&s, context.migration)
            .encode_into(&mut out)
            .map_err(|e| e.to_string())
            .and_then(|()| writer.write_all(&out).map_err(|e| e.to_string()));
        if let Err(e) = sent {
            // Wakes the receiving side, which is blocked in a read.
            let _ = writer.shutdown(Shutdown::Both);
            return (snapshots, Some(format!("sending a snapshot: {e}")));
        }
        last_sent = Some((s.id, Instant::now()));
    }
    (snapshots, None)
}

/// Receives buffers until the connection fails; returns why.
fn receive_buffers(
    context: &LinkContext,
    stream: &mut TcpStream,
    buffers: &mut Publisher<TransferBuffer>,
    report: &mut LinkReport,
) -> TcpError {
    loop {
        match receive_buffer(context, stream) {
            Ok(r) => {
                report.sc_frame_ms.push(r.render_ms);
                report.sc_bytes.push(r.bytes);
                report.transfer_ms.push(r.transfer_ms);
                report.decode_ms.push(r.decode_ms);
                let start = Instant::now();
                let old = buffers.publish(Arc::new(r.buffer));
                report.publish_us.push(start.elapsed().as_secs_f64() * 1e6);
                drop(old);
            }
            Err(e) => return e,
        }
    }
}

/// One buffer received, with its figures.
struct Received {
    buffer: TransferBuffer,
    render_ms: f64,
    bytes: u64,
    transfer_ms: f64,
    decode_ms: f64,
}

fn receive_buffer(context: &LinkContext, stream: &mut TcpStream) -> Result<Received, TcpError> {
    let (kind, header) = read_message(stream, &context.limits).map_err(|e| match e {
        ReadError::Closed => TcpError::Protocol("the slow client closed the connection".into()),
        other => TcpError::Read(other),
    })?;
    match kind {
        MessageType::MfrBuffer => {}
        MessageType::Error => {
            return Err(TcpError::Refused {
                peer: "slow client",
                reason: decode_error(&header, &context.limits)?,
            });
        }
        other => {
            return Err(TcpError::Protocol(format!(
                "a {other:?} message where an SC buffer was expected"
            )));
        }
    }
    let start = Instant::now();
    let (kind, frame) = read_message(stream, &context.limits)?;
    let transfer_ms = start.elapsed().as_secs_f64() * 1e3;
    if kind != MessageType::Frame {
        return Err(TcpError::Protocol(format!(
            "a {kind:?} message where the SC buffer's frame was expected"
        )));
    }
    let start = Instant::now();
    let (buffer, render_ms) = decode_buffer(
        &header,
        &frame,
        &context.scene,
        context.size,
        &context.limits,
    )?;
    Ok(Received {
        buffer,
        render_ms,
        bytes: (header.len() + frame.len()) as u64,
        transfer_ms,
        decode_ms: start.elapsed().as_secs_f64() * 1e3,
    })
}

// ----- the SC side ------------------------------------------------------------------------------

/// A slow client serving fast clients over TCP, one connection at a time.
#[derive(Clone, Debug)]
pub struct ScServer {
    /// The scene (the FC must load the same one).
    pub scene: Arc<Scene>,
    /// The frame size the SC insists on (`None`: the FC's).
    pub size: Option<(u32, u32)>,
    /// How DeepFrames are encoded.
    pub codec: Codec,
    /// Pace sending to this many bytes per second (`None`: as fast as the socket takes them).
    pub link_bytes_per_s: Option<f64>,
    /// Rendering threads (0: one per core).
    pub threads: usize,
    /// The rendering threads' priority.
    pub priority: ScPriority,
    /// How long the FC may stay silent (it repeats its newest snapshot every second) before the
    /// SC takes it for gone, drops the connection and serves the next.
    pub peer_silence: Duration,
}

/// What happened on a slow client's connection (for its log).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum ScEvent {
    /// A fast client connected and its handshake was accepted.
    Connected {
        /// Its address.
        peer: SocketAddr,
        /// The frame size.
        size: (u32, u32),
    },
    /// A buffer was rendered and sent.
    Sent {
        /// SC frame counter.
        sc_frame: u64,
        /// Render time (ms).
        render_ms: f64,
        /// Bytes sent (header and frame message).
        bytes: u64,
        /// Time to encode and send (ms).
        send_ms: f64,
    },
}

impl ScServer {
    /// An SC for `scene`: the FC's size, `deep-huff`, no pacing, one thread per core, normal
    /// priority, an FC silent for 10 s taken for gone.
    pub fn new(scene: Arc<Scene>) -> Self {
        ScServer {
            scene,
            size: None,
            codec: Codec::DeepHuff,
            link_bytes_per_s: None,
            threads: 0,
            priority: ScPriority::Normal,
            peer_silence: Duration::from_secs(10),
        }
    }

    /// Serves fast clients on `listener`, one after the other, forever; a failed connection is
    /// reported to `on_end` and the next one is accepted.
    pub fn serve(
        &self,
        listener: &TcpListener,
        mut on_event: impl FnMut(&ScEvent),
        mut on_end: impl FnMut(SocketAddr, Result<u64, TcpError>),
    ) -> Result<(), TcpError> {
        let pool = self.pool()?;
        loop {
            let (stream, peer) = listener.accept()?;
            let result = self.serve_connection_in(&pool, stream, &mut on_event);
            on_end(peer, result);
        }
    }

    /// Serves one fast client until it disconnects; returns the buffers sent. The end of the
    /// FC's connection between messages is a normal end.
    pub fn serve_connection(
        &self,
        stream: TcpStream,
        mut on_event: impl FnMut(&ScEvent),
    ) -> Result<u64, TcpError> {
        let pool = self.pool()?;
        self.serve_connection_in(&pool, stream, &mut on_event)
    }

    fn pool(&self) -> Result<rayon::ThreadPool, TcpError> {
        let low = self.priority == ScPriority::Low;
        rayon::ThreadPoolBuilder::new()
            .num_threads(self.threads)
            .thread_name(|i| format!("strata-mfr-sc-{i}"))
            .start_handler(move |_| {
                if low {
                    // Best effort: a thread left at normal priority only competes harder.
                    let _ = lower_thread_priority();
                }
            })
            .build()
            .map_err(|e| TcpError::Render(Box::new(SimulateError::Thread(e.to_string()))))
    }

    fn serve_connection_in(
        &self,
        pool: &rayon::ThreadPool,
        mut stream: TcpStream,
        on_event: &mut dyn FnMut(&ScEvent),
    ) -> Result<u64, TcpError> {
        let peer = stream.peer_addr()?;
        stream.set_nodelay(true)?;
        let size = self.handshake(&mut stream)?;
        on_event(&ScEvent::Connected { peer, size });
        let (jobs_out, mut jobs_in) = exchange::<(Snapshot, Migration)>();
        let reader = {
            let (reader_stream, scene) = (stream.try_clone()?, Arc::clone(&self.scene));
            let silence = self.peer_silence;
            std::thread::Builder::new()
                .name("strata-mfr-sc-read".into())
                .spawn(move || read_snapshots(reader_stream, &scene, silence, jobs_out))?
        };
        let mut sent = 0;
        let rendered = self.render_loop(
            pool,
            &mut stream,
            size,
            &mut jobs_in,
            &reader,
            &mut sent,
            on_event,
        );
        let _ = stream.shutdown(Shutdown::Both);
        let read = reader
            .join()
            .unwrap_or_else(|_| Err(TcpError::Protocol("the reading thread panicked".into())));
        match (rendered, read) {
            // The FC closing its end is how a run ends; a write it cut short is no failure.
            (Ok(()) | Err(TcpError::Io(_)), Ok(())) => Ok(sent),
            (Err(e), _) | (_, Err(e)) => Err(e),
        }
    }

    /// Reads and checks the FC's hello, answers with ours or an error; the frame size agreed.
    fn handshake(&self, stream: &mut TcpStream) -> Result<(u32, u32), TcpError> {
        let timeout = Some(Duration::from_secs(10));
        stream.set_read_timeout(timeout)?;
        stream.set_write_timeout(timeout)?;
        let limits = DecodeOptions::default();
        // Our size is checked only if one was given: learn the FC's first.
        let (kind, bytes) = read_message(stream, &limits)?;
        let theirs = match kind {
            MessageType::MfrHello => MfrHello::decode(&bytes, &limits)?,
            other => {
                let why = format!("expected a multi-frame-rate hello, got a {other:?} message");
                let mut out = Vec::new();
                encode_error_into(&mut out, &why);
                let _ = stream.write_all(&out);
                return Err(TcpError::Handshake(why));
            }
        };
        let size = self.size.unwrap_or((theirs.width, theirs.height));
        let ours = hello(&self.scene, MfrRole::Slow, size);
        let mut out = Vec::new();
        if let Some(why) = mismatch(&ours, &theirs, true) {
            encode_error_into(&mut out, &why);
            let _ = stream.write_all(&out);
            return Err(TcpError::Handshake(why));
        }
        ours.encode_into(&mut out);
        stream.write_all(&out)?;
        stream.set_read_timeout(None)?;
        stream.set_write_timeout(None)?;
        Ok(size)
    }

    /// Renders the newest snapshot whenever free and sends it, until the reader ends.
    #[allow(
        clippy::too_many_arguments,
        reason = "one connection's parts, each documented at the caller"
    )]
    fn render_loop(
        &self,
        pool: &rayon::ThreadPool,
        stream: &mut TcpStream,
        (width, height): (u32, u32),
        jobs: &mut Latest<(Snapshot, Migration)>,
        reader: &std::thread::JoinHandle<Result<(), TcpError>>,
        sent: &mut u64,
        on_event: &mut dyn FnMut(&ScEvent),
    ) -> Result<(), TcpError> {
        let mut client = Client::new(width, height);
        let projection = self.scene.camera.projection(width, height);
        let (mut header, mut frame) = (Vec::new(), Vec::new());
        let (mut last, mut sc_frame) = (None, 0u64);
        while !reader.is_finished() {
            let job = jobs.latest().filter(|j| Some(j.0.id) != last).cloned();
            let Some(job) = job else {
                std::thread::sleep(Duration::from_millis(1));
                continue;
            };
            let (snapshot, migration) = &*job;
            let start = Instant::now();
            let buffer = pool
                .install(|| sc_render(&self.scene, &mut client, snapshot, *migration, sc_frame))
                .map_err(|e| TcpError::Render(Box::new(e)))?;
            let render_ms = start.elapsed().as_secs_f64() * 1e3;
            let start = Instant::now();
            encode_buffer(
                &buffer,
                render_ms,
                projection,
                self.codec,
                &mut header,
                &mut frame,
            )?;
            send_paced(stream, &[&header, &frame], self.link_bytes_per_s)?;
            on_event(&ScEvent::Sent {
                sc_frame,
                render_ms,
                bytes: (header.len() + frame.len()) as u64,
                send_ms: start.elapsed().as_secs_f64() * 1e3,
            });
            last = Some(snapshot.id);
            sc_frame += 1;
            *sent += 1;
        }
        Ok(())
    }
}

/// The SC's reading thread: every snapshot received is published (latest wins) until the FC
/// closes the connection (`Ok`) or sends something wrong.
fn read_snapshots(
    mut stream: TcpStream,
    scene: &Scene,
    silence: Duration,
    mut jobs: Publisher<(Snapshot, Migration)>,
) -> Result<(), TcpError> {
    let limits = DecodeOptions {
        max_body_bytes: 1 << 28,
        ..DecodeOptions::default()
    };
    if let Err(e) = stream.set_read_timeout(Some(silence)) {
        return Err(e.into());
    }
    let result = loop {
        let (kind, bytes) = match read_message(&mut stream, &limits) {
            Ok(m) => m,
            Err(ReadError::Closed) => break Ok(()),
            Err(ReadError::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                break Err(TcpError::Protocol(format!(
                    "no message from the fast client for {:.1} s: taking it for gone",
                    silence.as_secs_f64()
                )));
            }
            Err(e) => break Err(e.into()),
        };
        if kind != MessageType::MfrSnapshot {
            break Err(TcpError::Protocol(format!(
                "a {kind:?} message where a snapshot was expected"
            )));
        }
        match MfrSnapshot::decode(&bytes, &limits)
            .map_err(TcpError::from)
            .and_then(|m| snapshot_from_wire(&m, scene))
        {
            Ok(job) => drop(jobs.publish(Arc::new(job))),
            Err(e) => break Err(e),
        }
    };
    // Wakes the render loop's next write, if the FC is gone.
    let _ = stream.shutdown(Shutdown::Both);
    result
}
