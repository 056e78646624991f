//! Each side of remote rendering measured alone: a display that discards frames on arrival
//! (`sink`), and a node that replays a recorded stream (`recording`). Both must behave exactly
//! as the real thing on the wire: the discarding display sees the node's real frames, and a
//! display fed a recording composes the very frames it composed when the node rendered them.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use strata_core::Rgb8Image;
use strata_raster::Rasterizer;
use strata_remote::Transfer;
use strata_remote::display::{self, DisplayConfig, Observer};
use strata_remote::node::serve;
use strata_remote::recording::{Recorder, Recording, RecordingError, serve_recording};
use strata_remote::reference::{exact_frame, exact_image};
use strata_remote::report::{FrameStats, NodeStatus};
use strata_remote::sink;
use strata_scene::Scene;
use strata_wire::DecodeOptions;

const W: u32 = 192;
const H: u32 = 108;

mod common;

use common::{display_config, node_config, serve_at, turning_mixed as scene};

/// A service on a loopback port, alive until dropped.
struct Service {
    addr: String,
    runtime: Option<tokio::runtime::Runtime>,
}

impl Service {
    fn start<F, Fut>(serve_on: F) -> Service
    where
        F: FnOnce(tokio::net::TcpListener) -> Fut,
        Fut: std::future::Future<Output = std::io::Result<()>> + Send + 'static,
    {
        let (addr, runtime) = serve_at("127.0.0.1:0", serve_on);
        Service {
            addr,
            runtime: Some(runtime),
        }
    }

    /// A render node serving `objects` (indices) of the scene, recording into `record`.
    fn node(scene: &Arc<Scene>, objects: &[usize], record: Option<&Path>) -> Service {
        let mut config = node_config(scene, objects);
        if let Some(path) = record {
            config.record = Some(Arc::new(Recorder::create(path, &config.hello()).unwrap()));
        }
        Self::start(move |l| serve(l, config, |_| {}))
    }

    /// A node replaying the recording at `path`.
    fn replay(path: &Path) -> Service {
        let limits = DecodeOptions::default();
        let recording = Arc::new(Recording::load(path, &limits).unwrap());
        Self::start(move |l| serve_recording(l, recording, limits, |_| {}))
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        // Nothing to wait for: the connections go with the runtime.
        if let Some(r) = self.runtime.take() {
            r.shutdown_background();
        }
    }
}

fn config(
    scene: &Arc<Scene>,
    nodes: &[&Service],
    transfer: Transfer,
    frames: u64,
) -> DisplayConfig {
    let nodes = nodes.iter().map(|n| n.addr.clone()).collect();
    display_config(scene, nodes, transfer, frames, (W, H))
}

/// Keeps every frame's image.
#[derive(Default)]
struct Keep {
    images: Vec<(u64, Rgb8Image)>,
}

impl Observer for Keep {
    fn frame(&mut self, stats: &FrameStats, image: &Rgb8Image) {
        self.images.push((stats.frame, image.clone()));
    }
}

/// A temporary folder, removed when dropped, and a path in it.
fn temp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::TempDir::new().unwrap();
    let path = dir.path().join(name);
    (dir, path)
}

#[test]
fn a_discarding_display_receives_every_frame_of_every_node_in_order() {
    let s = scene();
    let (a, b) = (
        Service::node(&s, &[0, 2], None),
        Service::node(&s, &[1, 3, 4], None),
    );
    let frames = 5;
    let r = sink::discard(config(&s, &[&a, &b], Transfer::Full, frames)).unwrap();
    assert!(r.incidents.is_empty(), "{:?}", r.incidents);
    assert_eq!(r.per_frame.len(), frames as usize);
    let mut raster = Rasterizer::default();
    for (t, f) in r.per_frame.iter().enumerate() {
        assert_eq!(f.frame, t as u64);
        // What the nodes rendered is the whole scene, split between them.
        let exact = exact_frame(&s, f.frame, W, H, &mut raster).unwrap();
        assert_eq!(f.fragments_rendered(), exact.fragment_count() as u64);
        for n in &f.nodes {
            assert_eq!(n.status, NodeStatus::Ok);
            assert!(n.bytes > 0 && n.render_ms > 0.0);
            assert_eq!(n.fragments_sent, n.fragments_rendered);
        }
    }
    assert!(r.per_frame[1..].iter().all(|f| f.interval_ms > 0.0));
    assert!(r.elapsed_s > 0.0);
}

#[test]
fn a_discarding_display_reports_a_node_that_is_not_there_and_keeps_the_others() {
    let s = scene();
    let a = Service::node(&s, &[0, 1, 2, 3, 4], None);
    let gone = Service::node(&s, &[0], None);
    let gone_addr = gone.addr.clone();
    drop(gone);
    let mut c = config(&s, &[&a], Transfer::Full, 3);
    c.nodes.push(gone_addr.clone());
    c.timeout = Duration::from_secs(2);
    let r = sink::discard(c).unwrap();
    assert_eq!(r.incidents.len(), 1, "{:?}", r.incidents);
    assert_eq!(r.incidents[0].node, gone_addr);
    assert!(
        r.incidents[0].what.starts_with("down:"),
        "{:?}",
        r.incidents
    );
    for f in &r.per_frame {
        assert_eq!(f.nodes[0].status, NodeStatus::Ok);
        assert_eq!(f.nodes[1].status, NodeStatus::Dropped);
    }
}

/// Runs a display against two recording nodes, then against their replays: the replayed run
/// must compose the same frames from the same bytes.
fn record_then_replay(transfer: Transfer, frames: u64, tag: &str) {
    let s = scene();
    let (_dir, a) = temp(&format!("{tag}-a.rec"));
    let paths = [a.clone(), a.with_file_name(format!("{tag}-b.rec"))];
    // The torus (1) pierces the cube (0) and the glass sphere (4): the nodes overlap.
    let live = (
        Service::node(&s, &[0, 3], Some(&paths[0])),
        Service::node(&s, &[1, 2, 4], Some(&paths[1])),
    );
    let mut first = Keep::default();
    let recorded = display::run(
        config(&s, &[&live.0, &live.1], transfer, frames),
        &mut first,
    )
    .unwrap();
    assert!(recorded.incidents.is_empty(), "{:?}", recorded.incidents);
    drop(live);
    let replay = (Service::replay(&paths[0]), Service::replay(&paths[1]));
    let mut second = Keep::default();
    let replayed = display::run(
        config(&s, &[&replay.0, &replay.1], transfer, frames),
        &mut second,
    )
    .unwrap();
    assert!(replayed.incidents.is_empty(), "{:?}", replayed.incidents);
    assert_eq!(first.images.len(), frames as usize);
    assert!(
        first.images == second.images,
        "the replay composed other frames"
    );
    let mut raster = Rasterizer::default();
    for (f, image) in &second.images {
        assert!(image == &exact_image(&s, *f, W, H, &mut raster).unwrap());
    }
    for (a, b) in recorded.per_frame.iter().zip(&replayed.per_frame) {
        assert_eq!(a.bytes(), b.bytes(), "frame {}", a.frame);
        assert_eq!(a.fragments_sent(), b.fragments_sent(), "frame {}", a.frame);
        let fixups = |f: &FrameStats| f.nodes.iter().map(|n| n.fixup_pixels).collect::<Vec<_>>();
        assert_eq!(fixups(a), fixups(b), "frame {}", a.frame);
    }
    if transfer == Transfer::Difference {
        assert!(
            replayed.per_frame[1..]
                .iter()
                .any(|f| f.nodes.iter().any(|n| n.fixup_pixels > 0)),
            "overlapping nodes need fixups, and the replay must answer them"
        );
    }
}

#[test]
fn a_replayed_full_transfer_composes_the_recorded_frames() {
    record_then_replay(Transfer::Full, 4, "full");
}

#[test]
fn a_replayed_difference_transfer_with_fixups_composes_the_recorded_frames() {
    record_then_replay(Transfer::Difference, 6, "difference");
}

#[test]
fn a_replaying_node_answers_what_it_did_not_record_with_an_error_that_says_so() {
    let s = scene();
    let (_dir, path) = temp("short.rec");
    {
        let live = Service::node(&s, &[0, 1, 2, 3, 4], Some(&path));
        let r = display::run(config(&s, &[&live], Transfer::Full, 2), &mut ()).unwrap();
        assert!(r.incidents.is_empty());
    }
    let replay = Service::replay(&path);
    // Frame 2 was never recorded, and neither was any frame at another size.
    let r = display::run(config(&s, &[&replay], Transfer::Full, 3), &mut ()).unwrap();
    assert_eq!(r.per_frame[1].nodes[0].status, NodeStatus::Ok);
    assert_ne!(r.per_frame[2].nodes[0].status, NodeStatus::Ok);
    let what = &r.incidents.first().expect("an incident").what;
    assert!(
        what.contains("holds no answer to the request for frame 2"),
        "{what}"
    );
    let mut other_size = config(&s, &[&replay], Transfer::Full, 1);
    other_size.width = W + 1;
    let r = display::run(other_size, &mut ()).unwrap();
    assert_ne!(r.per_frame[0].nodes[0].status, NodeStatus::Ok);
    let what = &r.incidents.first().expect("an incident").what;
    assert!(
        what.contains(&format!("holds no answer to the request for frame 0 (render (reset), Full, codec deep-huff, {}x{H}", W + 1)),
        "{what}"
    );
}

/// A recording of two frames of the full transfer, as bytes.
fn small_recording() -> Vec<u8> {
    let s = scene();
    let (_dir, path) = temp("small.rec");
    {
        let live = Service::node(&s, &[0, 1], Some(&path));
        let r = display::run(config(&s, &[&live], Transfer::Full, 2), &mut ()).unwrap();
        assert!(r.incidents.is_empty());
    }
    std::fs::read(&path).unwrap()
}

#[test]
fn a_malformed_recording_is_refused_with_the_place_it_goes_wrong() {
    let good = small_recording();
    let limits = DecodeOptions::default();
    let p = Path::new("test.rec");
    let parse = |b: &[u8]| Recording::parse(p, b.to_vec(), &limits);
    let ok = parse(&good).unwrap();
    assert_eq!((ok.exchanges(), ok.requests()), (2, 2));
    assert_eq!(ok.hello().objects.len(), 2);

    assert!(matches!(
        parse(b"not a recording at all"),
        Err(RecordingError::NotARecording { .. })
    ));
    assert!(matches!(
        parse(b""),
        Err(RecordingError::NotARecording { .. })
    ));
    let mut v2 = good.clone();
    v2[16] = 2;
    assert!(matches!(
        parse(&v2),
        Err(RecordingError::Version { found: 2, .. })
    ));
    // Every cut refuses the file (the hello and each exchange are whole or absent) except at an
    // exchange's end, where the file holds fewer exchanges.
    let mut whole_cuts = 0;
    for cut in 0..good.len() {
        match parse(&good[..cut]) {
            Ok(r) => {
                whole_cuts += 1;
                assert!(r.exchanges() < 2);
            }
            Err(e) => {
                let text = e.to_string();
                assert!(text.starts_with("test.rec"), "{text}");
            }
        }
    }
    assert_eq!(
        whole_cuts, 2,
        "the cuts after the hello and after the first exchange"
    );
    // A stats message where the frame should be.
    let hello_end = 20 + hello_len(&good[20..]);
    let request_len = hello_len(&good[hello_end..]);
    let frame_at = hello_end + request_len;
    let mut swapped = good.clone();
    swapped[frame_at + 6] = good[frame_at + 6] + 1; // the type byte: frame -> the next type
    match parse(&swapped) {
        Err(RecordingError::Malformed { offset, what, .. }) => {
            assert_eq!(offset, frame_at);
            assert!(what.contains("frame message"), "{what}");
        }
        other => panic!("{other:?}"),
    }
    // Trailing garbage is not a request.
    let mut trailing = good.clone();
    trailing.extend_from_slice(b"garbage");
    match parse(&trailing) {
        Err(RecordingError::Malformed { offset, .. }) => assert_eq!(offset, good.len()),
        other => panic!("{other:?}"),
    }
}

/// The length of the wire message at the start of `bytes` (its prefix's body length + 20).
fn hello_len(bytes: &[u8]) -> usize {
    let body = u64::from_le_bytes(bytes[8..16].try_into().unwrap());
    20 + body as usize
}
