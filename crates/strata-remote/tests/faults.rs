//! Nodes that misbehave: the display reports them, keeps composing with the others, never
//! panics and never waits longer than its timeout — checked by counting what it did (frames
//! composed, incidents, timeouts waited), not with a clock.

use std::io::{Read, Write};
use std::net::TcpListener;
use std::sync::Arc;
use std::time::Duration;

use strata_core::DeepFrame;
use strata_remote::Transfer;
use strata_remote::display::{self, AddressError, DisplayConfig, DisplayError, OnFault};
use strata_remote::node::{NodeConfig, serve};
use strata_remote::reference::exact_image;
use strata_remote::report::NodeStatus;
use strata_scene::{Animation, Scene, SearchPath, open_scene};
use strata_stores::MethodOptions;
use strata_wire::{
    Codec, DecodeOptions, FrameHeader, Hello, MessageType, PREFIX_LEN, Request, RequestKind,
    decode_error, decode_frame, encode_frame, encode_reprojection_into, parse_prefix,
};

mod common;

use common::{mixed as scene, node_config, serve_at};

/// A real node for objects 0 and 1 on a loopback port.
fn real_node(scene: &Arc<Scene>) -> (String, tokio::runtime::Runtime) {
    real_node_for(scene, &[0, 1])
}

/// A real node for `objects` (indices) of `scene` on a loopback port.
fn real_node_for(scene: &Arc<Scene>, objects: &[usize]) -> (String, tokio::runtime::Runtime) {
    let config = node_config(scene, objects);
    serve_at("127.0.0.1:0", move |l| serve(l, config, |_| {}))
}

/// A fake node: greets every connection properly, then does `then` with the socket.
fn fake_node(then: fn(std::net::TcpStream)) -> String {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        for s in l.incoming() {
            let Ok(mut s) = s else { return };
            let mut hello = Vec::new();
            Hello {
                triangles: 1,
                scene: "mixed".into(),
                objects: vec![(2, "fake".into())],
            }
            .encode_into(&mut hello)
            .unwrap();
            if s.write_all(&hello).is_err() {
                continue;
            }
            std::thread::spawn(move || then(s));
        }
    });
    addr
}

fn config(scene: &Arc<Scene>, nodes: Vec<String>, on_fault: OnFault) -> DisplayConfig {
    DisplayConfig {
        scene: scene.clone(),
        nodes,
        transfer: Transfer::Full,
        codec: Codec::Lz4,
        tolerance: 0,
        first_frame: 0,
        frames: 3,
        width: 64,
        height: 36,
        in_flight: 2,
        timeout: Duration::from_millis(700),
        on_fault,
        limits: DecodeOptions::default(),
    }
}

/// Runs the display against a real node and `bad`; returns the incidents' texts.
///
/// The display must not hang on a bad node: every frame is composed once, in order, and the bad
/// node costs at most one wait of the timeout per frame (one "stalled" incident at most per
/// frame), so the run's length is bounded by frames × timeout whatever the node does.
fn run_against(bad: String, on_fault: OnFault) -> Vec<String> {
    let s = scene();
    let (good, _rt) = real_node(&s);
    let c = config(&s, vec![good, bad.clone()], on_fault);
    let r = display::run(c.clone(), &mut ()).unwrap();
    let frames: Vec<u64> = r.per_frame.iter().map(|f| f.frame).collect();
    assert_eq!(frames, [0, 1, 2], "every frame is composed once, in order");
    let missing = match on_fault {
        OnFault::Hold => NodeStatus::Held,
        OnFault::Drop => NodeStatus::Dropped,
    };
    for f in &r.per_frame {
        assert_eq!(
            f.nodes[0].status,
            NodeStatus::Ok,
            "the good node keeps contributing"
        );
        assert!(f.nodes[0].fragments_sent > 0);
        assert_eq!(f.nodes[1].status, missing);
    }
    for t in 0..c.frames {
        let waits = r
            .incidents
            .iter()
            .filter(|i| i.frame == t && i.what.contains("stalled"))
            .count();
        assert!(
            waits <= 1,
            "frame {t}: waited {waits} times: {:?}",
            r.incidents
        );
    }
    assert!(
        r.incidents.iter().all(|i| i.node == bad),
        "only the bad node has incidents: {:?}",
        r.incidents
    );
    r.incidents.iter().map(|i| i.what.clone()).collect()
}

#[test]
fn a_stalled_node_times_out() {
    let bad = fake_node(|mut s| {
        // Read requests forever, answer none.
        let mut buf = [0u8; 4096];
        while matches!(s.read(&mut buf), Ok(n) if n > 0) {}
    });
    let what = run_against(bad, OnFault::Hold);
    assert!(what.iter().any(|w| w.contains("stalled")), "{what:?}");
}

#[test]
fn garbage_mid_stream_is_reported() {
    let bad = fake_node(|mut s| {
        let mut buf = [0u8; 4096];
        let _ = s.read(&mut buf);
        // A real frame message whose body is then spoiled: its prefix is fine, its checksum
        // no longer matches.
        let header = FrameHeader {
            node_id: 1,
            ..FrameHeader::default()
        };
        let mut msg = encode_frame(&header, &DeepFrame::empty(64, 36), Codec::Lz4).unwrap();
        for b in &mut msg[PREFIX_LEN..] {
            *b ^= 0xAB;
        }
        let _ = s.write_all(&msg);
        // A stats message follows so the frame is decoded (and fails its checksum).
        let mut stats = Vec::new();
        strata_wire::NodeStats::default().encode_into(&mut stats);
        let _ = s.write_all(&stats);
        std::thread::sleep(Duration::from_secs(5));
    });
    let what = run_against(bad, OnFault::Drop);
    assert!(
        what.iter()
            .any(|w| w.contains("does not decode") || w.contains("checksum")),
        "{what:?}"
    );
}

#[test]
fn random_bytes_instead_of_messages_are_reported() {
    let bad = fake_node(|mut s| {
        let mut buf = [0u8; 4096];
        let _ = s.read(&mut buf);
        let _ = s.write_all(&[0x5A; 100]);
        std::thread::sleep(Duration::from_secs(5));
    });
    let what = run_against(bad, OnFault::Drop);
    assert!(what.iter().any(|w| w.contains("magic")), "{what:?}");
}

#[test]
fn a_node_that_hangs_up_is_reported() {
    let bad = fake_node(drop);
    let what = run_against(bad, OnFault::Hold);
    // Depending on timing the display sees the close, a reset, or a broken pipe.
    assert!(what.iter().any(|w| w.starts_with("down:")), "{what:?}");
}

#[test]
fn an_unreachable_node_is_reported_once() {
    // A port nothing listens on.
    let addr = {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().to_string()
    };
    let what = run_against(addr, OnFault::Drop);
    let connects = what.iter().filter(|w| w.contains("cannot connect")).count();
    assert_eq!(connects, 1, "{what:?}");
}

#[test]
fn a_node_serving_another_scene_is_left_out() {
    let other = fake_node(|mut s| {
        let mut buf = [0u8; 4096];
        while matches!(s.read(&mut buf), Ok(n) if n > 0) {}
    });
    // fake_node greets as scene "mixed"; the display shows "spheres".
    let s = Arc::new(open_scene("spheres", &SearchPath::new([])).unwrap());
    let r = display::run(config(&s, vec![other], OnFault::Drop), &mut ()).unwrap();
    assert_eq!(r.per_frame.len(), 3);
    assert!(
        r.incidents
            .iter()
            .any(|i| i.what.contains("serves scene 'mixed', not 'spheres'")),
        "{:?}",
        r.incidents
    );
    assert!(r.per_frame.iter().all(|f| f.fragments_displayed == 0));
}

#[test]
fn bad_configurations_are_errors() {
    let s = scene();
    let mut c = config(&s, vec![], OnFault::Hold);
    let run = |c: &DisplayConfig| display::run(c.clone(), &mut ()).map(|_| ());
    assert!(matches!(run(&c), Err(DisplayError::NoNodes)));
    c.nodes = vec!["127.0.0.1:1".into(), "127.0.0.1".into()];
    assert!(matches!(
        run(&c),
        Err(DisplayError::Address(AddressError::NoPort(a))) if a == "127.0.0.1"
    ));
    c.nodes = vec!["127.0.0.1:1".into()];
    c.width = 0;
    assert!(matches!(run(&c), Err(DisplayError::EmptyFrame)));
    c.width = 64;
    c.in_flight = 0;
    assert!(matches!(run(&c), Err(DisplayError::InFlight)));
    c.in_flight = 2;
    // Frames 2^32 - 1 and 2^32: the second cannot pose the scene, and is refused, not clamped.
    c.first_frame = u64::from(u32::MAX);
    c.frames = 2;
    let e = run(&c).unwrap_err();
    assert!(
        matches!(&e, DisplayError::FrameRange { source, .. } if source.0 == 1 << 32),
        "{e}"
    );
    c.frames = 1;
    assert!(
        !matches!(run(&c), Err(DisplayError::FrameRange { .. })),
        "the last frame that poses the scene is fine"
    );
    let bad = NodeConfig {
        scene: s.clone(),
        objects: vec![],
        method: "wboit".into(),
        method_options: MethodOptions::default(),
        limits: DecodeOptions::default(),
        record: None,
    };
    let e = bad.check().unwrap_err().to_string();
    assert!(e.contains("wboit"), "{e}");
    let e = NodeConfig::select_objects(&s, &["no such thing".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("glass torus"), "lists the objects: {e}");
}

/// A proxy in front of `node` that, on the first connection only, rewrites the reprojection frame
/// numbered `bad` with a wrong state digest; everything else passes through untouched.
fn digest_corrupting_proxy(node: String, bad: u64) -> String {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        let mut first = true;
        for display in l.incoming() {
            let Ok(display) = display else { return };
            let Ok(upstream) = std::net::TcpStream::connect(&node) else {
                return;
            };
            let (mut from_display, mut to_node) =
                (display.try_clone().unwrap(), upstream.try_clone().unwrap());
            std::thread::spawn(move || {
                std::io::copy(&mut from_display, &mut to_node).ok();
                to_node.shutdown(std::net::Shutdown::Both).ok();
            });
            let corrupt = std::mem::take(&mut first);
            let (mut from_node, mut to_display) = (upstream, display);
            std::thread::spawn(move || {
                let limits = DecodeOptions::default();
                loop {
                    let mut msg = vec![0u8; PREFIX_LEN];
                    if from_node.read_exact(&mut msg).is_err() {
                        break;
                    }
                    let Ok(prefix) = parse_prefix(&msg, &limits) else {
                        break;
                    };
                    let mut body = vec![0u8; prefix.body_len as usize];
                    if from_node.read_exact(&mut body).is_err() {
                        break;
                    }
                    msg.extend_from_slice(&body);
                    if corrupt
                        && prefix.kind == MessageType::Frame
                        && let Ok(m) = decode_frame(&msg, &limits)
                        && m.header.frame_number == bad
                        && let (Some(touched), Some(removals)) = (&m.changed, &m.removals)
                    {
                        let mut wrong = removals.clone();
                        wrong.set_checksum(removals.checksum() ^ 1);
                        encode_reprojection_into(
                            &mut msg, &m.header, touched, &wrong, &m.frame, m.codec,
                        )
                        .unwrap();
                    }
                    if to_display.write_all(&msg).is_err() {
                        break;
                    }
                }
                to_display.shutdown(std::net::Shutdown::Both).ok();
            });
        }
    });
    addr
}

#[test]
fn a_diverged_reprojection_state_is_reported_and_the_node_starts_over_cleanly() {
    let mut s = open_scene("mixed", &SearchPath::new([])).unwrap();
    s.animation = Some(Animation {
        frames: 72,
        rotate_deg_per_frame: glam::Vec3::new(0.0, 5.0, 0.0),
    });
    let s = Arc::new(s);
    // The proxied node draws the cube and the torus; a second, honest node draws the rest and
    // keeps the display's pace while the first reconnects.
    let (node, _rt) = real_node_for(&s, &[0, 1]);
    let (other, _rt2) = real_node_for(&s, &[2, 3, 4]);
    let proxy = digest_corrupting_proxy(node, 3);
    let mut c = config(&s, vec![proxy, other], OnFault::Hold);
    c.transfer = Transfer::Reprojection;
    c.tolerance = 1;
    c.frames = 48;
    (c.width, c.height) = (320, 180);
    // Frames 4 and 5 are already on their way when frame 3 turns out wrong: what the old
    // connection sent must not be applied to the new one's state.
    c.in_flight = 3;
    c.timeout = Duration::from_secs(10);
    struct Keep(Vec<(u64, strata_core::Rgb8Image)>);
    impl display::Observer for Keep {
        fn frame(&mut self, f: &strata_remote::report::FrameStats, i: &strata_core::Rgb8Image) {
            self.0.push((f.frame, i.clone()));
        }
    }
    let mut keep = Keep(Vec::new());
    let r = display::run(c.clone(), &mut keep).unwrap();
    let whats: Vec<&str> = r.incidents.iter().map(|i| i.what.as_str()).collect();
    // The divergence, the link dropping the connection, the node coming back — and nothing
    // after: no stale frame of the old connection is applied to the new state.
    assert!(whats[0].contains("diverged"), "{whats:?}");
    assert!(
        whats.last().unwrap().starts_with("reconnected"),
        "{whats:?}"
    );
    assert!(
        whats[1..whats.len() - 1]
            .iter()
            .all(|w| w.starts_with("down: disconnected by the display")),
        "{whats:?}"
    );
    let back = r
        .per_frame
        .iter()
        .rposition(|f| f.nodes[0].status != NodeStatus::Ok)
        .expect("frame 3 was held")
        + 1;
    assert!(back < 48, "the node came back");
    let mut raster = strata_raster::Rasterizer::default();
    for (f, image) in &keep.0[back..] {
        let want = exact_image(&s, *f, c.width, c.height, &mut raster).unwrap();
        let worst = image
            .as_bytes()
            .iter()
            .zip(want.as_bytes())
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap_or(0);
        assert!(worst <= 2, "frame {f}: off by {worst}");
    }
}

#[test]
fn a_node_refuses_a_frame_number_it_cannot_pose_instead_of_clamping_it() {
    let s = scene();
    let (addr, _rt) = real_node(&s);
    let mut c = std::net::TcpStream::connect(&addr).unwrap();
    let limits = DecodeOptions::default();
    let read = |c: &mut std::net::TcpStream| {
        let mut msg = vec![0u8; PREFIX_LEN];
        c.read_exact(&mut msg).unwrap();
        let prefix = parse_prefix(&msg, &limits).unwrap();
        let mut body = vec![0u8; prefix.body_len as usize];
        c.read_exact(&mut body).unwrap();
        msg.extend_from_slice(&body);
        (prefix.kind, msg)
    };
    assert_eq!(read(&mut c).0, MessageType::Hello);
    let request = Request {
        frame_number: 1 << 32,
        node_id: 0,
        width: 16,
        height: 9,
        view: s.camera.view().to_cols_array(),
        projection: s.camera.projection(16, 9).to_cols_array(),
        transfer: Transfer::Full,
        codec: Codec::Lz4,
        kind: RequestKind::Render { reset: true },
        tolerance: 0,
    };
    let mut bytes = Vec::new();
    request.encode_into(&mut bytes).unwrap();
    c.write_all(&bytes).unwrap();
    let (kind, msg) = read(&mut c);
    assert_eq!(kind, MessageType::Error, "no frame for 2^32");
    let text = decode_error(&msg, &limits).unwrap();
    assert!(
        text.contains("frame 4294967296 is beyond the last animation frame"),
        "{text}"
    );
}
