//! The TCP transport: buffers and snapshots cross the wire exactly, and a slow client that dies,
//! sends garbage or announces an impossible message leaves the fast client running on its last
//! good buffer, with the trouble reported as incidents.
//!
//! The faults are made by a proxy between the FC and a real slow client: it relays whole
//! messages and, when the test says so (after the FC has composed with an SC buffer), cuts the
//! link. It then waits for the FC's reconnection attempt, which proves the FC noticed, so no test
//! depends on timing.

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use strata_core::ObjectId;
use strata_mfr::client::Client;
use strata_mfr::tcp::{
    ScServer, TcpOptions, decode_buffer, encode_buffer, scene_fingerprint, snapshot_from_wire,
    snapshot_to_wire,
};
use strata_mfr::trace::{GrabParams, grab};
use strata_mfr::{
    Authority, FcFrame, Migration, ObjectState, RealConfig, Snapshot, TransferBuffer, Transport,
    run_real,
};
use strata_scene::{Scene, SearchPath, open_scene};
use strata_wire::mfr::{MFR_PROTOCOL, MfrHello, MfrRole, MfrSnapshot};
use strata_wire::stream::read_message;
use strata_wire::{
    Codec, DecodeOptions, FrameHeader, MAGIC, PixelMask, TransferMethod, VERSION, encode_delta_into,
};

const SIZE: (u32, u32) = (64, 36);

fn scene(name: &str) -> Arc<Scene> {
    Arc::new(open_scene(name, &SearchPath::new(Vec::<std::path::PathBuf>::new())).expect(name))
}

fn grab_params() -> GrabParams {
    GrabParams {
        object: Some("glass sphere".into()),
        start_ms: 20.0,
        over_lead_ms: 0.0,
        hold_ms: 250.0,
        distance: -0.3,
        linger_ms: 60.0,
    }
}

/// A snapshot in the middle of a drag: offsets, versions and a selected object.
fn dragging(scene: &Scene) -> Arc<Snapshot> {
    let trace = grab(scene, &grab_params()).expect("trace");
    let mut authority = Authority::new(scene, trace);
    let s = authority.advance_to(150.0);
    assert!(
        s.objects
            .iter()
            .any(|o| o.state == ObjectState::Selected && o.version > 0),
        "the snapshot is mid-drag"
    );
    s
}

/// What the SC would hand over for `snapshot`: every object but the selected one.
fn sc_buffer(scene: &Scene, snapshot: &Snapshot) -> TransferBuffer {
    let (mut rendered, mut excluded, mut indices) = (Vec::new(), Vec::new(), Vec::new());
    for (i, o) in snapshot.objects.iter().enumerate() {
        if o.state == ObjectState::Inactive {
            rendered.push((o.id, o.version));
            indices.push(i);
        } else {
            excluded.push(o.id);
        }
    }
    let frame = Client::new(SIZE.0, SIZE.1)
        .render(scene, snapshot, &snapshot.view, &indices)
        .expect("render");
    let image = frame.resolve(scene.background);
    TransferBuffer {
        sc_frame: 17,
        snapshot_id: snapshot.id,
        snapshot_t_ms: snapshot.t_ms,
        view: snapshot.view,
        rendered,
        excluded,
        frame,
        image,
    }
}

#[test]
fn snapshots_and_buffers_round_trip_exactly_with_every_codec() {
    let scene = scene("mixed");
    let snapshot = dragging(&scene);
    let limits = DecodeOptions::default();
    for migration in [Migration::Naive, Migration::Predictive] {
        let mut bytes = Vec::new();
        snapshot_to_wire(&snapshot, migration)
            .encode_into(&mut bytes)
            .expect("encodes");
        let message = MfrSnapshot::decode(&bytes, &limits).expect("decodes");
        let (back, m) = snapshot_from_wire(&message, &scene).expect("fits the scene");
        assert_eq!((&back, m), (&*snapshot, migration));
    }
    let buffer = sc_buffer(&scene, &snapshot);
    assert!(buffer.frame.fragment_count() > 0 && !buffer.excluded.is_empty());
    let projection = scene.camera.projection(SIZE.0, SIZE.1);
    for codec in Codec::ALL {
        let (mut header, mut frame) = (Vec::new(), Vec::new());
        encode_buffer(&buffer, 12.5, projection, codec, &mut header, &mut frame).expect("encodes");
        let (back, render_ms) =
            decode_buffer(&header, &frame, &scene, SIZE, &limits).expect("decodes");
        assert_eq!(render_ms, 12.5);
        // Every field, the DeepFrame bit for bit, and the image resolved on arrival.
        assert_eq!(back, buffer, "{codec}");
    }
}

#[test]
fn a_buffer_of_the_wrong_size_or_with_unknown_objects_is_refused() {
    let scene = scene("mixed");
    let snapshot = dragging(&scene);
    let mut buffer = sc_buffer(&scene, &snapshot);
    let projection = scene.camera.projection(SIZE.0, SIZE.1);
    let limits = DecodeOptions::default();
    let (mut header, mut frame) = (Vec::new(), Vec::new());
    encode_buffer(
        &buffer,
        1.0,
        projection,
        Codec::DeepLz4,
        &mut header,
        &mut frame,
    )
    .unwrap();
    let e = decode_buffer(&header, &frame, &scene, (32, 18), &limits).unwrap_err();
    assert!(
        e.to_string().contains("an SC frame of 64x36 for 32x18"),
        "{e}"
    );
    // The right size and frame, but sent as a difference frame (every pixel replaced): an SC
    // frame is a full frame, not a delta against a state the FC does not hold.
    let pixels = SIZE.0 * SIZE.1;
    let delta = FrameHeader {
        frame_number: buffer.sc_frame,
        transfer: TransferMethod::Difference,
        ..FrameHeader::default()
    };
    let mut as_delta = Vec::new();
    encode_delta_into(
        &mut as_delta,
        &delta,
        &PixelMask::full(pixels),
        &PixelMask::empty(pixels),
        &buffer.frame,
        Codec::DeepLz4,
    )
    .unwrap();
    let e = decode_buffer(&header, &as_delta, &scene, SIZE, &limits).unwrap_err();
    assert!(e.to_string().contains("not as a full frame"), "{e}");
    buffer.excluded.push(ObjectId(9999));
    encode_buffer(
        &buffer,
        1.0,
        projection,
        Codec::DeepLz4,
        &mut header,
        &mut frame,
    )
    .unwrap();
    let e = decode_buffer(&header, &frame, &scene, SIZE, &limits).unwrap_err();
    assert!(
        e.to_string().contains("name objects not in the scene"),
        "{e}"
    );
}

/// How the proxy breaks the link.
#[derive(Clone, Copy, Debug)]
enum Fault {
    /// Both sockets shut down: the SC died.
    Kill,
    /// Bytes that are not a strata message, the socket left open.
    Garbage,
    /// A valid prefix announcing a 1 TiB body, the socket left open.
    Oversize,
}

/// A relay between the FC and an SC that breaks the link on request.
struct Proxy {
    addr: SocketAddr,
    inject: mpsc::Sender<()>,
    reconnected: mpsc::Receiver<()>,
}

fn proxy(upstream: SocketAddr, fault: Fault) -> Proxy {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    let (inject, inject_rx) = mpsc::channel::<()>();
    let (reconnected_tx, reconnected) = mpsc::channel::<()>();
    std::thread::spawn(move || {
        let (fc, _) = listener.accept().expect("the FC connects");
        let sc = TcpStream::connect(upstream).expect("the SC listens");
        let cut = Arc::new(AtomicBool::new(false));
        let to_fc = Arc::new(Mutex::new(fc.try_clone().expect("clone")));
        // FC → SC: bytes as they come, discarded once cut.
        {
            let (mut from, mut to, cut) = (
                fc.try_clone().expect("clone"),
                sc.try_clone().expect("clone"),
                Arc::clone(&cut),
            );
            std::thread::spawn(move || {
                let mut buf = [0u8; 4096];
                while let Ok(n) = from.read(&mut buf) {
                    if n == 0 || (!cut.load(Ordering::Acquire) && to.write_all(&buf[..n]).is_err())
                    {
                        break;
                    }
                }
            });
        }
        // SC → FC: whole messages, under the lock the fault takes.
        {
            let (mut from, to_fc, cut) = (
                sc.try_clone().expect("clone"),
                Arc::clone(&to_fc),
                Arc::clone(&cut),
            );
            std::thread::spawn(move || {
                while let Ok((_, bytes)) = read_message(&mut from, &DecodeOptions::default()) {
                    let mut fc = to_fc.lock().expect("lock");
                    if cut.load(Ordering::Acquire) || fc.write_all(&bytes).is_err() {
                        break;
                    }
                }
            });
        }
        inject_rx.recv().expect("the test asks for the fault");
        {
            let mut fc = to_fc.lock().expect("lock");
            cut.store(true, Ordering::Release);
            match fault {
                Fault::Kill => {
                    let _ = fc.shutdown(Shutdown::Both);
                    let _ = sc.shutdown(Shutdown::Both);
                }
                Fault::Garbage => {
                    let _ = fc.write_all(b"GET / HTTP/1.1\r\nHost: strata\r\n\r\n");
                }
                Fault::Oversize => {
                    let mut prefix = Vec::new();
                    prefix.extend_from_slice(&MAGIC);
                    prefix.extend_from_slice(&VERSION.to_le_bytes());
                    prefix.extend_from_slice(&[9, 0]);
                    prefix.extend_from_slice(&(1u64 << 40).to_le_bytes());
                    prefix.extend_from_slice(&[0; 4]);
                    let _ = fc.write_all(&prefix);
                }
            }
        }
        // The FC noticed when it tries again; the SC stays gone.
        if let Ok((again, _)) = listener.accept() {
            drop(again);
            let _ = reconnected_tx.send(());
        }
        // Keep the first connection's sockets until the test ends.
        std::thread::sleep(Duration::from_secs(60));
        drop((fc, sc));
    });
    Proxy {
        addr,
        inject,
        reconnected,
    }
}

/// A slow client serving one connection on a free port.
fn slow_client(scene: Arc<Scene>) -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    std::thread::spawn(move || {
        let server = ScServer {
            threads: 1,
            ..ScServer::new(scene)
        };
        if let Ok((stream, _)) = listener.accept() {
            let _ = server.serve_connection(stream, |_| {});
        }
    });
    addr
}

fn fault_leaves_the_fc_on_its_last_good_buffer(fault: Fault, expected: &[&str]) {
    let scene = scene("mixed");
    let trace = grab(&scene, &grab_params()).expect("trace");
    let proxy = proxy(slow_client(Arc::clone(&scene)), fault);
    let config = RealConfig {
        fc_hz: 60.0,
        transport: Transport::Tcp(TcpOptions::new(proxy.addr.to_string())),
        ..RealConfig::new(SIZE, 40)
    };
    let mut frames: Vec<FcFrame> = Vec::new();
    let mut cut_after: Option<u64> = None;
    let mut noticed = false;
    let stats = run_real(Arc::clone(&scene), trace, &config, |f| {
        frames.push(f.clone());
        if cut_after.is_none() && f.sc.is_some() {
            cut_after = Some(f.index);
            proxy.inject.send(()).expect("the proxy runs");
            noticed = proxy
                .reconnected
                .recv_timeout(Duration::from_secs(60))
                .is_ok();
        }
    })
    .expect("the run completes");
    assert_eq!(frames.len(), 40, "every FC frame ran");
    assert_eq!(stats.fc_frame_ms.len(), 40);
    let cut_after = cut_after.expect("an SC buffer arrived before the fault");
    assert!(noticed, "the FC dropped the broken link and tried again");
    assert!(cut_after < 39, "frames ran after the fault");
    let first = stats.incidents.first().expect("the fault is an incident");
    assert!(
        expected.iter().any(|e| first.what.contains(e)) && first.what.contains("last good buffer"),
        "{fault:?}: {:?}",
        stats.incidents
    );
    assert!(
        stats
            .incidents
            .iter()
            .any(|i| i.what.starts_with("reconnecting")),
        "{:?}",
        stats.incidents
    );
    // After the fault every frame composes with the one last good buffer, exactly.
    let after = &frames[cut_after as usize + 1..];
    let last_good = after[0].sc.as_ref().expect("a buffer").sc_frame;
    let mut reference = Client::new(SIZE.0, SIZE.1);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    for f in after {
        let sc = f.sc.as_ref().expect("still composing with an SC buffer");
        assert_eq!(sc.sc_frame, last_good, "frame {}", f.index);
        let r = reference
            .render(&scene, &f.snapshot, &sc.view, &all)
            .expect("reference");
        assert!(f.composed().expect("composes") == r, "frame {}", f.index);
    }
}

#[test]
fn a_killed_slow_client_leaves_the_fc_running() {
    // The FC's reader sees the end of the stream, or its sender the broken pipe, first.
    fault_leaves_the_fc_on_its_last_good_buffer(
        Fault::Kill,
        &["closed the connection", "sending a snapshot"],
    );
}

#[test]
fn a_slow_client_sending_garbage_leaves_the_fc_running() {
    fault_leaves_the_fc_on_its_last_good_buffer(Fault::Garbage, &["not a strata wire message"]);
}

#[test]
fn a_slow_client_announcing_an_oversize_message_leaves_the_fc_running() {
    fault_leaves_the_fc_on_its_last_good_buffer(Fault::Oversize, &["body_len"]);
}

#[test]
fn a_slow_client_with_another_scene_is_refused_before_the_run() {
    let addr = slow_client(scene("overlap"));
    let config = RealConfig {
        transport: Transport::Tcp(TcpOptions::new(addr.to_string())),
        ..RealConfig::new(SIZE, 5)
    };
    let mut frames = 0;
    let e = run_real(scene("mixed"), Default::default(), &config, |_| frames += 1)
        .expect_err("another scene");
    assert!(
        e.to_string()
            .contains("the fast client renders scene 'mixed', the slow client 'overlap'"),
        "{e}"
    );
    assert_eq!(frames, 0, "no frame before the handshake");
}

#[test]
fn nothing_listening_is_a_clear_error() {
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port");
    let config = RealConfig {
        transport: Transport::Tcp(TcpOptions::new(port.to_string())),
        ..RealConfig::new(SIZE, 5)
    };
    let e = run_real(scene("mixed"), Default::default(), &config, |_| {}).expect_err("no SC");
    assert!(
        e.to_string().contains("cannot reach the slow client at"),
        "{e}"
    );
}

#[test]
fn a_fast_client_that_goes_silent_is_dropped_by_the_slow_client() {
    let scene = scene("mixed");
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    let server = ScServer {
        threads: 1,
        peer_silence: Duration::from_millis(200),
        ..ScServer::new(Arc::clone(&scene))
    };
    let (done, served) = mpsc::channel();
    std::thread::spawn(move || {
        let (stream, _) = listener.accept().expect("a connection");
        let _ = done.send(server.serve_connection(stream, |_| {}));
    });
    // A fast client that shakes hands, then neither sends nor closes: a vanished machine.
    let mut fc = TcpStream::connect(addr).expect("connects");
    let mut out = Vec::new();
    MfrHello {
        protocol: MFR_PROTOCOL,
        role: MfrRole::Fast,
        width: SIZE.0,
        height: SIZE.1,
        fingerprint: scene_fingerprint(&scene),
        scene: scene.name.clone(),
    }
    .encode_into(&mut out);
    fc.write_all(&out).expect("hello sent");
    let (kind, _) = read_message(&mut fc, &DecodeOptions::default()).expect("the SC's hello");
    assert_eq!(kind, strata_wire::MessageType::MfrHello);
    let e = served
        .recv_timeout(Duration::from_secs(60))
        .expect("the SC gives up on a silent FC")
        .expect_err("a silent FC ends the connection");
    assert!(
        e.to_string().contains("no message from the fast client"),
        "{e}"
    );
    drop(fc);
}
