//! Render nodes and a display on loopback: the display's image must equal the exact local render
//! of the whole scene, frame after frame, for every transfer that promises it.

use std::sync::Arc;
use std::time::Duration;

use strata_core::Rgb8Image;
use strata_raster::Rasterizer;
use strata_remote::Transfer;
use strata_remote::display::{self, DisplayConfig, Observer, OnFault};
use strata_remote::merge::merge_resolve;
use strata_remote::node::{NodeConfig, serve};
use strata_remote::reference::{exact_frame, exact_image};
use strata_remote::report::{FrameStats, NodeIncident, NodeStatus};
use strata_remote::select::depth_limit;
use strata_scene::{Scene, SearchPath, open_scene};
use strata_stores::MethodOptions;
use strata_wire::DecodeOptions;

const W: u32 = 256;
const H: u32 = 144;

mod common;

use common::{display_config, node_config, serve_at, turning_mixed as scene};

/// A node serving `objects` (indices) of the scene on a loopback port, alive until dropped.
struct Node {
    addr: String,
    runtime: Option<tokio::runtime::Runtime>,
}

impl Node {
    fn start(scene: &Arc<Scene>, objects: &[usize]) -> Node {
        Self::start_at(scene, objects, "127.0.0.1:0")
    }

    fn start_at(scene: &Arc<Scene>, objects: &[usize], addr: &str) -> Node {
        let config = node_config(scene, objects);
        let (addr, runtime) = serve_at(addr, move |l| serve(l, config, |_| {}));
        Node {
            addr,
            runtime: Some(runtime),
        }
    }

    /// Kills the node: its runtime and every connection go.
    fn kill(&mut self) {
        if let Some(r) = self.runtime.take() {
            r.shutdown_background();
        }
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        self.kill();
    }
}

fn config(scene: &Arc<Scene>, nodes: &[&Node], transfer: Transfer, frames: u64) -> DisplayConfig {
    let nodes = nodes.iter().map(|n| n.addr.clone()).collect();
    display_config(scene, nodes, transfer, frames, (W, H))
}

/// Keeps every frame's image.
#[derive(Default)]
struct Keep {
    images: Vec<(u64, Rgb8Image)>,
    incidents: Vec<NodeIncident>,
}

impl Observer for Keep {
    fn frame(&mut self, stats: &FrameStats, image: &Rgb8Image) {
        self.images.push((stats.frame, image.clone()));
    }
    fn incident(&mut self, i: &NodeIncident) {
        self.incidents.push(i.clone());
    }
}

fn assert_exact(scene: &Scene, keep: &Keep) {
    let mut raster = Rasterizer::default();
    for (f, image) in &keep.images {
        let want = exact_image(scene, *f, W, H, &mut raster).unwrap();
        assert!(
            image == &want,
            "frame {f}: the display differs from the exact render in {} pixels",
            strata_core::metrics::bad_pixels(image, &want, 0)
                .unwrap()
                .count
        );
    }
}

#[test]
fn two_nodes_full_transfer_equal_the_exact_render() {
    let s = scene();
    let (a, b) = (Node::start(&s, &[0, 2]), Node::start(&s, &[1, 3, 4]));
    let mut keep = Keep::default();
    // A full-transfer frame goes back to its node's render thread once encoded: the later
    // frames are exported into the buffers of earlier ones.
    let r = display::run(config(&s, &[&a, &b], Transfer::Full, 16), &mut keep).unwrap();
    assert_eq!(r.per_frame.len(), 16);
    assert!(r.incidents.is_empty(), "{:?}", r.incidents);
    assert_exact(&s, &keep);
    for f in &r.per_frame {
        assert_eq!(f.fragments_sent(), f.fragments_rendered());
        assert!(f.fragments_rendered() > 10_000);
        assert!(
            f.nodes
                .iter()
                .all(|n| n.status == NodeStatus::Ok && n.bytes > 0)
        );
    }
}

#[test]
fn depth_limited_with_enough_layers_is_exact_and_with_few_sends_less() {
    let s = scene();
    let (a, b) = (Node::start(&s, &[0, 1]), Node::start(&s, &[2, 3, 4]));
    let mut keep = Keep::default();
    let deep = Transfer::DepthLimited {
        layers: 64,
        opacity_threshold: None,
    };
    display::run(config(&s, &[&a, &b], deep, 3), &mut keep).unwrap();
    assert_exact(&s, &keep);

    let shallow = Transfer::DepthLimited {
        layers: 1,
        opacity_threshold: None,
    };
    let r = display::run(config(&s, &[&a, &b], shallow, 2), &mut ()).unwrap();
    for f in &r.per_frame {
        assert!(f.fragments_sent() < f.fragments_rendered());
        for n in &f.nodes {
            // One layer per node: at most one fragment per pixel.
            assert!(n.fragments_sent <= u64::from(W * H));
        }
    }
}

/// The nodes cut each run as they export it (layers, then opacity): the display shows the
/// merge of each node's exact frame cut by the same rule, and the nodes report what they
/// rendered before the cut.
#[test]
fn depth_limited_nodes_send_each_runs_prefix_up_to_the_opacity_threshold() {
    let s = scene();
    let objects: [&[usize]; 2] = [&[0, 1], &[2, 3, 4]];
    let (a, b) = (Node::start(&s, objects[0]), Node::start(&s, objects[1]));
    let (layers, opacity) = (4, 0.6);
    let limited = Transfer::DepthLimited {
        layers,
        opacity_threshold: Some(opacity),
    };
    let mut keep = Keep::default();
    let r = display::run(config(&s, &[&a, &b], limited, 3), &mut keep).unwrap();
    assert!(r.incidents.is_empty(), "{:?}", r.incidents);
    for ((f, image), stats) in keep.images.iter().zip(&r.per_frame) {
        let whole: Vec<_> = objects.iter().map(|o| frame_of(&s, o, *f)).collect();
        let cut: Vec<_> = whole
            .iter()
            .map(|w| depth_limit(w, layers, Some(opacity)).into_owned())
            .collect();
        let want = merge_resolve(&[&cut[0], &cut[1]], W, H, s.background);
        assert!(image == &want, "frame {f}: not the merge of the cut frames");
        let count = |frames: &[strata_core::DeepFrame]| {
            frames
                .iter()
                .map(|f| f.fragment_count() as u64)
                .sum::<u64>()
        };
        assert_eq!(stats.fragments_sent(), count(&cut), "frame {f}");
        assert_eq!(stats.fragments_rendered(), count(&whole), "frame {f}");
        assert!(count(&cut) < count(&whole), "frame {f}: nothing was cut");
    }
}

#[test]
fn difference_is_exact_on_every_frame_with_overlapping_nodes() {
    let s = scene();
    // The torus (1) pierces the cube (0) and the glass sphere (4): the nodes overlap on screen.
    let (a, b) = (Node::start(&s, &[0, 3]), Node::start(&s, &[1, 2, 4]));
    let mut keep = Keep::default();
    let r = display::run(config(&s, &[&a, &b], Transfer::Difference, 8), &mut keep).unwrap();
    assert!(r.incidents.is_empty(), "{:?}", r.incidents);
    assert_exact(&s, &keep);
    let first = &r.per_frame[0];
    assert_eq!(first.fragments_sent(), first.fragments_rendered());
    let later: u64 = r.per_frame[1..]
        .iter()
        .map(FrameStats::fragments_sent)
        .sum();
    let rendered: u64 = r.per_frame[1..]
        .iter()
        .map(FrameStats::fragments_rendered)
        .sum();
    assert!(
        later < rendered,
        "difference sends less after the first frame"
    );
    assert!(
        r.per_frame[1..]
            .iter()
            .any(|f| f.nodes.iter().any(|n| n.fixup_pixels > 0)),
        "overlapping nodes need fixups"
    );
}

#[test]
fn a_difference_tolerance_of_two_steps_leaves_no_bad_pixels_and_sends_less() {
    // One node: the bound holds where nodes do not overlap (see the difference module).
    let s = scene();
    let a = Node::start(&s, &[0, 1, 2, 3, 4]);
    let exact = display::run(config(&s, &[&a], Transfer::Difference, 8), &mut ()).unwrap();
    let mut keep = Keep::default();
    let mut cfg = config(&s, &[&a], Transfer::Difference, 8);
    cfg.tolerance = 2;
    let r = display::run(cfg, &mut keep).unwrap();
    let mut raster = Rasterizer::default();
    for (f, image) in &keep.images {
        let want = exact_image(&s, *f, W, H, &mut raster).unwrap();
        let bad = strata_core::metrics::bad_pixels(image, &want, 2).unwrap();
        assert_eq!(bad.count, 0, "frame {f}");
    }
    let sent = |r: &display::RunResult| -> u64 {
        r.per_frame.iter().map(FrameStats::fragments_sent).sum()
    };
    assert!(sent(&r) < sent(&exact), "{} vs {}", sent(&r), sent(&exact));
}

#[test]
fn a_static_scene_sends_nothing_after_the_first_frame_under_difference() {
    let mut s = open_scene("mixed", &SearchPath::new([])).unwrap();
    s.animation = None;
    let s = Arc::new(s);
    let (a, b) = (Node::start(&s, &[0, 1]), Node::start(&s, &[2, 3, 4]));
    let mut keep = Keep::default();
    let r = display::run(config(&s, &[&a, &b], Transfer::Difference, 4), &mut keep).unwrap();
    assert_exact(&s, &keep);
    assert!(r.per_frame[0].fragments_sent() > 0);
    for f in &r.per_frame[1..] {
        assert_eq!(f.fragments_sent(), 0, "frame {}", f.frame);
    }
}

#[test]
fn a_dead_node_is_reported_held_and_reconnected() {
    let s = scene();
    let a = Node::start(&s, &[0, 1, 2]);
    let mut b = Node::start(&s, &[3, 4]);
    let addr_b = b.addr.clone();
    let mut cfg = config(&s, &[&a, &b], Transfer::Difference, 60);
    cfg.timeout = Duration::from_secs(2);

    // Kill b after a few frames and bring it back on the same port a little later.
    struct Chaos {
        keep: Keep,
        b: Option<Node>,
        scene: Arc<Scene>,
        addr_b: String,
    }
    impl Observer for Chaos {
        fn frame(&mut self, stats: &FrameStats, image: &Rgb8Image) {
            self.keep.frame(stats, image);
            if stats.frame == 3 {
                self.b.as_mut().unwrap().kill();
            }
            if stats.frame == 6 {
                self.b = Some(Node::start_at(&self.scene, &[3, 4], &self.addr_b));
            }
        }
        fn incident(&mut self, i: &NodeIncident) {
            self.keep.incident(i);
        }
    }
    let mut chaos = Chaos {
        keep: Keep::default(),
        b: Some(std::mem::replace(
            &mut b,
            Node {
                addr: String::new(),
                runtime: None,
            },
        )),
        scene: s.clone(),
        addr_b,
    };
    let r = display::run(cfg, &mut chaos).unwrap();
    assert_eq!(r.per_frame.len(), 60, "the display kept composing");
    let whats: Vec<&str> = r.incidents.iter().map(|i| i.what.as_str()).collect();
    assert!(whats.iter().any(|w| w.starts_with("down")), "{whats:?}");
    assert!(
        whats.iter().any(|w| w.starts_with("reconnected")),
        "{whats:?}"
    );
    assert!(
        r.per_frame
            .iter()
            .any(|f| f.nodes[1].status == NodeStatus::Held),
        "the dead node's last frame was held"
    );
    // Once back (the link retries with a growing delay), the display is exact again.
    let back = r
        .per_frame
        .iter()
        .rposition(|f| f.nodes.iter().any(|n| n.status != NodeStatus::Ok))
        .expect("some frame was composed without the dead node")
        + 1;
    assert!(back < 60, "the node came back before the end");
    let keep = Keep {
        images: chaos.keep.images.split_off(back),
        incidents: Vec::new(),
    };
    assert_exact(&s, &keep);
}

/// The exact DeepFrame of the objects `objects` (indices) of `scene` alone at frame `frame`:
/// what a node serving them renders.
fn frame_of(scene: &Scene, objects: &[usize], frame: u64) -> strata_core::DeepFrame {
    let mut only = scene.clone();
    only.objects = objects.iter().map(|&i| scene.objects[i].clone()).collect();
    exact_frame(&only, frame, W, H, &mut Rasterizer::default()).unwrap()
}

/// Two nodes, the second killed for good once frame 2 is composed; returns the run, the
/// displayed images, and the last frame the dead node delivered.
fn run_with_a_dying_node(
    s: &Arc<Scene>,
    on_fault: OnFault,
) -> (display::RunResult, Vec<(u64, Rgb8Image)>, usize) {
    let a = Node::start(s, &[0, 1, 2]);
    let b = Node::start(s, &[3, 4]);
    let mut cfg = config(s, &[&a, &b], Transfer::Full, 8);
    cfg.on_fault = on_fault;
    struct KillAfter {
        images: Vec<(u64, Rgb8Image)>,
        b: Node,
    }
    impl Observer for KillAfter {
        fn frame(&mut self, stats: &FrameStats, image: &Rgb8Image) {
            self.images.push((stats.frame, image.clone()));
            if stats.frame == 2 {
                self.b.kill();
            }
        }
    }
    let mut killer = KillAfter {
        images: Vec::new(),
        b,
    };
    let r = display::run(cfg, &mut killer).unwrap();
    assert_eq!(r.per_frame.len(), 8);
    // Frames already on their way may still arrive after the kill; after that, nothing.
    let last_good = r
        .per_frame
        .iter()
        .rposition(|f| f.nodes[1].status == NodeStatus::Ok)
        .expect("the node delivered frames before it died");
    assert!(last_good >= 2, "frames 0-2 were delivered");
    assert!(last_good < 7, "the dead node missed the last frames");
    assert!(
        r.per_frame[..=last_good]
            .iter()
            .all(|f| f.nodes.iter().all(|n| n.status == NodeStatus::Ok))
    );
    (r, killer.images, last_good)
}

#[test]
fn on_fault_hold_composes_the_last_good_frame_of_a_node_that_died() {
    let s = scene();
    let (r, images, last_good) = run_with_a_dying_node(&s, OnFault::Hold);
    let held_frame = frame_of(&s, &[3, 4], r.per_frame[last_good].frame);
    assert!(
        held_frame.fragment_count() > 0,
        "the dead node's objects are on screen"
    );
    for (k, f) in r.per_frame.iter().enumerate().skip(last_good + 1) {
        assert_eq!(f.nodes[1].status, NodeStatus::Held, "frame {}", f.frame);
        assert_eq!(f.nodes[0].status, NodeStatus::Ok, "frame {}", f.frame);
        let live = frame_of(&s, &[0, 1, 2], f.frame);
        let want = merge_resolve(&[&live, &held_frame], W, H, s.background);
        let (t, image) = &images[k];
        assert_eq!(*t, f.frame);
        assert!(
            image == &want,
            "frame {t}: the display differs in {} pixels from the live node's frame merged with \
             the dead node's last frame",
            strata_core::metrics::bad_pixels(image, &want, 0)
                .unwrap()
                .count
        );
        // Not the live node alone: the held objects are there ...
        let alone = merge_resolve(&[&live], W, H, s.background);
        assert!(
            image != &alone,
            "frame {t}: the held node's objects are missing"
        );
        // ... and they are the old pose, not the current one (the scene turns every frame).
        let now = exact_image(&s, f.frame, W, H, &mut Rasterizer::default()).unwrap();
        assert!(image != &now, "frame {t}: the held objects moved");
    }
}

#[test]
fn on_fault_drop_composes_without_a_node_that_died() {
    let s = scene();
    let (r, images, last_good) = run_with_a_dying_node(&s, OnFault::Drop);
    for (k, f) in r.per_frame.iter().enumerate().skip(last_good + 1) {
        assert_eq!(f.nodes[1].status, NodeStatus::Dropped, "frame {}", f.frame);
        let live = frame_of(&s, &[0, 1, 2], f.frame);
        let want = merge_resolve(&[&live], W, H, s.background);
        assert!(
            images[k].1 == want,
            "frame {}: only the live node's objects",
            f.frame
        );
    }
}

/// Largest channel difference between the display's frames and the exact render.
fn max_error(scene: &Scene, keep: &Keep) -> Vec<u8> {
    let mut raster = Rasterizer::default();
    keep.images
        .iter()
        .map(|(f, image)| {
            let want = exact_image(scene, *f, W, H, &mut raster).unwrap();
            image
                .as_bytes()
                .iter()
                .zip(want.as_bytes())
                .map(|(a, b)| a.abs_diff(*b))
                .max()
                .unwrap_or(0)
        })
        .collect()
}

#[test]
fn reprojection_with_overlapping_nodes_stays_within_its_bound_over_a_long_sequence() {
    // The torus (1) pierces the cube (0) and the glass sphere (4); 36 frames turn the scene by
    // 180°. Every frame must stay within tolerance + 1 steps (the +1 is the normal packing) of
    // the exact render: no drift, and no misordering where the nodes' objects intersect.
    let s = scene();
    let (a, b) = (Node::start(&s, &[0, 3]), Node::start(&s, &[1, 2, 4]));
    let mut keep = Keep::default();
    let mut cfg = config(&s, &[&a, &b], Transfer::Reprojection, 36);
    cfg.tolerance = 1;
    let r = display::run(cfg, &mut keep).unwrap();
    assert!(r.incidents.is_empty(), "{:?}", r.incidents);
    assert_eq!(keep.images.len(), 36);
    let errors = max_error(&s, &keep);
    assert!(errors.iter().all(|&e| e <= 2), "{errors:?}");
    let first = &r.per_frame[0];
    assert_eq!(first.fragments_sent(), first.fragments_rendered());
    for f in &r.per_frame[1..] {
        assert!(
            f.fragments_sent() < f.fragments_rendered(),
            "frame {}: {} of {}",
            f.frame,
            f.fragments_sent(),
            f.fragments_rendered()
        );
        // A turning scene loses held fragments every frame, and the display counts them.
        assert!(f.removals() > 0, "frame {}", f.frame);
    }
    assert_eq!(r.per_frame[0].removals(), 0);
    assert!(
        r.per_frame
            .iter()
            .any(|f| f.nodes.iter().any(|n| n.fixup_pixels > 0)),
        "intersecting objects on two nodes need fixups"
    );
}

#[test]
fn reprojection_with_zero_tolerance_is_within_the_normal_packing() {
    let s = scene();
    let (a, b) = (Node::start(&s, &[0, 1]), Node::start(&s, &[2, 3, 4]));
    let mut keep = Keep::default();
    let r = display::run(config(&s, &[&a, &b], Transfer::Reprojection, 6), &mut keep).unwrap();
    assert!(r.incidents.is_empty(), "{:?}", r.incidents);
    let errors = max_error(&s, &keep);
    assert!(errors.iter().all(|&e| e <= 1), "{errors:?}");
}

#[test]
fn a_static_scene_sends_nothing_after_the_first_frame_under_reprojection() {
    let mut s = open_scene("mixed", &SearchPath::new([])).unwrap();
    s.animation = None;
    let s = Arc::new(s);
    let (a, b) = (Node::start(&s, &[0, 1]), Node::start(&s, &[2, 3, 4]));
    let mut keep = Keep::default();
    let mut cfg = config(&s, &[&a, &b], Transfer::Reprojection, 4);
    cfg.tolerance = 1;
    let r = display::run(cfg, &mut keep).unwrap();
    assert!(r.per_frame[0].fragments_sent() > 0);
    for f in &r.per_frame[1..] {
        assert_eq!(f.fragments_sent(), 0, "frame {}", f.frame);
    }
    let errors = max_error(&s, &keep);
    assert!(errors.iter().all(|&e| e <= 1), "{errors:?}");
}

#[test]
fn a_node_whose_store_drops_fragments_refuses_reprojection() {
    let s = scene();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let listener = runtime
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let config = NodeConfig {
        scene: s.clone(),
        objects: s.objects.iter().map(|o| o.id).collect(),
        method: "kbuffer".into(),
        method_options: MethodOptions::default(),
        limits: DecodeOptions::default(),
        record: None,
    };
    runtime.spawn(serve(listener, config, |_| {}));
    let mut cfg = config_for(&s, vec![addr], Transfer::Reprojection, 2);
    cfg.timeout = Duration::from_secs(2);
    let r = display::run(cfg, &mut ()).unwrap();
    assert!(
        r.incidents
            .iter()
            .any(|i| i.what.contains("needs every fragment") && i.what.contains("kbuffer")),
        "{:?}",
        r.incidents
    );
    runtime.shutdown_background();
}

fn config_for(
    scene: &Arc<Scene>,
    nodes: Vec<String>,
    transfer: Transfer,
    frames: u64,
) -> DisplayConfig {
    DisplayConfig {
        nodes,
        ..config(scene, &[], transfer, frames)
    }
}

/// Steers a run as `strata view --nodes` does: a camera of its own per frame (orbiting the
/// scene's target), a stop after `stop_after` frames; keeps each frame with the camera it was
/// asked for.
struct Steer {
    scene: Arc<Scene>,
    stop_after: usize,
    asked: std::collections::BTreeMap<u64, strata_scene::Camera>,
    images: Vec<(u64, Rgb8Image)>,
}

impl Steer {
    fn camera(scene: &Scene, frame: u64) -> strata_scene::Camera {
        let mut c = scene.camera;
        let turn = glam::Quat::from_rotation_y(0.2 * frame as f32);
        c.eye = c.target + turn * (c.eye - c.target);
        c
    }
}

impl Observer for Steer {
    fn camera(&mut self, frame: u64) -> Option<strata_scene::Camera> {
        assert!(
            !self.asked.contains_key(&frame),
            "frame {frame}: asked twice"
        );
        let c = Self::camera(&self.scene, frame);
        self.asked.insert(frame, c);
        Some(c)
    }
    fn stop(&mut self) -> bool {
        self.images.len() >= self.stop_after
    }
    fn frame(&mut self, stats: &FrameStats, image: &Rgb8Image) {
        self.images.push((stats.frame, image.clone()));
    }
}

#[test]
fn a_steered_run_renders_every_frame_through_the_observers_camera_and_stops_when_told() {
    // The still scene: only the camera moves, and every transfer must follow it — difference
    // and reprojection with overlapping nodes, whose fixups must use the frame's camera too.
    let mut still = open_scene("mixed", &SearchPath::new([])).unwrap();
    still.animation = None;
    let s = Arc::new(still);
    let (a, b) = (Node::start(&s, &[0, 3]), Node::start(&s, &[1, 2, 4]));
    let mut raster = Rasterizer::default();
    for (transfer, tolerance, max_error) in [
        (Transfer::Full, 0, 0),
        (Transfer::Difference, 0, 0),
        (Transfer::Reprojection, 1, 2),
    ] {
        let mut steer = Steer {
            scene: s.clone(),
            stop_after: 5,
            asked: Default::default(),
            images: Vec::new(),
        };
        // Far more frames than it will run: the observer ends it.
        let mut cfg = config(&s, &[&a, &b], transfer, 1000);
        cfg.tolerance = tolerance;
        let r = display::run(cfg, &mut steer).unwrap();
        assert!(r.incidents.is_empty(), "{transfer:?}: {:?}", r.incidents);
        assert_eq!(steer.images.len(), 5, "{transfer:?}");
        let mut previous: Option<&Rgb8Image> = None;
        for (f, image) in &steer.images {
            let mut posed = (*s).clone();
            posed.camera = steer.asked[f];
            let want = exact_image(&posed, *f, W, H, &mut raster).unwrap();
            let error = image
                .as_bytes()
                .iter()
                .zip(want.as_bytes())
                .map(|(x, y)| x.abs_diff(*y))
                .max()
                .unwrap_or(0);
            assert!(error <= max_error, "{transfer:?} frame {f}: off by {error}");
            assert!(
                previous != Some(image),
                "{transfer:?} frame {f}: did not move"
            );
            previous = Some(image);
        }
    }
}

#[test]
fn the_only_node_that_dies_and_comes_back_rejoins() {
    // While no node is up nobody awaits a frame: the driver must still notice the node's
    // return. The run is endless; the observer stops it once the node delivers again.
    let s = scene();
    let node = Node::start(&s, &[0, 1, 2, 3, 4]);
    let addr = node.addr.clone();
    struct Phoenix {
        scene: Arc<Scene>,
        addr: String,
        node: Option<Node>,
        composed: u64,
        statuses: Vec<NodeStatus>,
        since: std::time::Instant,
    }
    impl Observer for Phoenix {
        fn frame(&mut self, stats: &FrameStats, _: &Rgb8Image) {
            self.composed += 1;
            self.statuses.push(stats.nodes[0].status);
            if self.composed == 3 {
                self.node.as_mut().unwrap().kill();
            }
            if self.composed == 6 {
                self.node = Some(Node::start_at(&self.scene, &[0, 1, 2, 3, 4], &self.addr));
            }
            // Paced as a viewer is: the link retries with a growing delay meanwhile.
            std::thread::sleep(Duration::from_millis(10));
        }
        fn stop(&mut self) -> bool {
            let back = self.composed > 6 && self.statuses.last() == Some(&NodeStatus::Ok);
            back || self.since.elapsed() > Duration::from_secs(60)
        }
        fn keep_history(&self) -> bool {
            false
        }
    }
    let mut phoenix = Phoenix {
        scene: s.clone(),
        addr,
        node: Some(node),
        composed: 0,
        statuses: Vec::new(),
        since: std::time::Instant::now(),
    };
    let mut cfg = display_config(
        &s,
        vec![phoenix.addr.clone()],
        Transfer::Full,
        1 << 32,
        (W, H),
    );
    cfg.timeout = Duration::from_secs(2);
    let r = display::run(cfg, &mut phoenix).unwrap();
    assert!(
        r.per_frame.is_empty() && r.incidents.is_empty(),
        "no history kept"
    );
    let held = phoenix.statuses.iter().position(|s| *s == NodeStatus::Held);
    assert!(held.is_some(), "{:?}", phoenix.statuses);
    assert_eq!(
        phoenix.statuses.last(),
        Some(&NodeStatus::Ok),
        "the node came back: {:?}",
        phoenix.statuses
    );
}

#[test]
fn a_stop_is_honoured_while_a_node_is_silent() {
    // A "node" that accepts and says nothing: the driver waits for its hello (up to the
    // timeout, an hour here); the observer's stop must end the run long before.
    let silent = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = silent.local_addr().unwrap().to_string();
    let held = std::thread::spawn(move || {
        let kept: Vec<_> = silent.incoming().take(4).collect();
        std::thread::sleep(Duration::from_secs(120));
        drop(kept);
    });
    struct StopSoon(std::time::Instant);
    impl Observer for StopSoon {
        fn stop(&mut self) -> bool {
            self.0.elapsed() > Duration::from_millis(300)
        }
    }
    let s = scene();
    let mut cfg = display_config(&s, vec![addr], Transfer::Full, 1 << 32, (W, H));
    cfg.timeout = Duration::from_secs(3600);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let r = display::run(cfg, &mut StopSoon(std::time::Instant::now()));
        let _ = tx.send(r.map(|r| r.per_frame.len()));
    });
    // A bound for a hung run (the timeout is an hour), not a measure of speed.
    let composed = rx
        .recv_timeout(Duration::from_secs(60))
        .expect("the run stopped while the node was silent")
        .unwrap();
    assert_eq!(composed, 0, "stopped before the first frame");
    drop(held);
}
