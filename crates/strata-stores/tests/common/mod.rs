//! Helpers shared by the method test files: scenes, thread pools, rendering with any method, the
//! linked-list A-buffer as the reference.

#![allow(
    dead_code,
    reason = "each test binary uses a different subset of the helpers"
)]

use std::sync::Arc;

use strata_core::{DeepFrame, Fragment, Rgb8Image, metrics};
use strata_raster::{FragmentVec, FrameInput, Rasterizer};
use strata_scene::{Scene, SearchPath, open_scene};
use strata_stores::{FrameResult, Method, MethodOptions, create, render_frame};

/// The built-in scenes every exact method is checked on.
pub(crate) const SCENES: [&str; 4] = ["slabs", "spheres", "mixed", "overlap"];

/// Built-in scene `name` resized to `width` × `height`.
pub(crate) fn scene(name: &str, width: u32, height: u32) -> Scene {
    let mut s = open_scene(name, &SearchPath::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
    (s.width, s.height) = (width, height);
    s
}

/// A rayon pool of `threads` threads.
pub(crate) fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

/// Renders frame `frame` of `scene` with `method` on `threads` threads; returns the frame and the
/// method's DeepFrame, if it has one.
pub(crate) fn render_with(
    method: &mut dyn Method,
    scene: &Scene,
    frame: u32,
    threads: usize,
) -> (FrameResult, Option<DeepFrame>) {
    let input = FrameInput::from_scene(scene, frame);
    let mut raster = Rasterizer::default();
    let result = pool(threads)
        .install(|| render_frame(method, &mut raster, &input, scene.background))
        .expect("render");
    let deep = method.deep_frame().map(|d| d.expect("valid DeepFrame"));
    (result, deep)
}

/// [`render_with`] for a method that must export a DeepFrame.
pub(crate) fn render_exact(
    method: &mut dyn Method,
    scene: &Scene,
    frame: u32,
    threads: usize,
) -> (FrameResult, DeepFrame) {
    let name = method.name();
    let (result, deep) = render_with(method, scene, frame, threads);
    let deep = deep.unwrap_or_else(|| panic!("{name} keeps fragments but exports no DeepFrame"));
    (result, deep)
}

/// The linked-list A-buffer's frame and DeepFrame: the reference every method is checked against.
pub(crate) fn reference(scene: &Scene, frame: u32) -> (FrameResult, DeepFrame) {
    let mut abuffer = create("abuffer", &MethodOptions::default()).expect("abuffer exists");
    render_exact(abuffer.as_mut(), scene, frame, 2)
}

/// Every fragment the rasterizer emits, per pixel, in arrival (primitive) order.
pub(crate) fn arrivals(scene: &Scene, frame: u32) -> Vec<Vec<Fragment>> {
    let input = FrameInput::from_scene(scene, frame);
    let mut raster = Rasterizer::default();
    let mut all = FragmentVec::new();
    raster.prepare(&input).rasterize(&mut all);
    all.per_pixel(input.pixel_count())
}

/// `deep` with each pixel's run cut to the fragments `keep(run_len)` selects by index.
pub(crate) fn select(deep: &DeepFrame, keep: impl Fn(usize, usize) -> bool) -> DeepFrame {
    let lists: Vec<Vec<Fragment>> = (0..deep.offsets().len() - 1)
        .map(|p| {
            let run: Vec<Fragment> = deep.run(p).iter().collect();
            let n = run.len();
            run.into_iter()
                .enumerate()
                .filter(|&(i, _)| keep(i, n))
                .map(|(_, f)| f)
                .collect()
        })
        .collect();
    DeepFrame::from_pixel_lists(deep.width(), deep.height(), &lists).expect("valid")
}

/// A copy of `scene` with every object's triangles in a scrambled order and the objects drawn in
/// reverse order.
pub(crate) fn scrambled(scene: &Scene, seed: u64) -> Scene {
    let mut s = scene.clone();
    let mut state = seed | 1;
    for o in &mut s.objects {
        let n = o.mesh.triangles().len();
        let mut order: Vec<usize> = (0..n).collect();
        for i in (1..n).rev() {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            order.swap(i, (state % (i as u64 + 1)) as usize);
        }
        o.mesh = Arc::new(o.mesh.reorder_triangles(&order));
    }
    s.objects.reverse();
    s
}

/// The largest channel difference between two images, in 8-bit steps.
pub(crate) fn max_diff(a: &Rgb8Image, b: &Rgb8Image) -> u8 {
    metrics::max_channel_difference(a, b).expect("same size")
}

/// How many 8-bit channels differ between two images of the same size.
pub(crate) fn differing_channels(a: &Rgb8Image, b: &Rgb8Image) -> usize {
    a.as_bytes()
        .iter()
        .zip(b.as_bytes())
        .filter(|(x, y)| x != y)
        .count()
}

/// Checks that a method is exact: for every built-in scene, on 1 and 2 threads and with
/// scrambled triangles, its DeepFrame equals the A-buffer's and its image differs by at most
/// `tolerance` steps (0: bit-identical). Returns the largest image difference seen.
pub(crate) fn check_exact(
    make: &dyn Fn(&FrameResult) -> Box<dyn Method>,
    width: u32,
    height: u32,
    tolerance: u8,
) -> u8 {
    let mut worst = 0;
    for name in SCENES {
        let base = scene(name, width, height);
        for (label, s) in [("", base.clone()), (" (scrambled)", scrambled(&base, 11))] {
            let (want, want_deep) = reference(&s, 2);
            for threads in [1, 2] {
                let mut method = make(&want);
                let (got, deep) = render_with(method.as_mut(), &s, 2, threads);
                let what = format!("{} on {name}{label}, {threads} threads", method.name());
                let d = max_diff(&got.image, &want.image);
                assert!(d <= tolerance, "{what}: image differs by {d} steps");
                worst = worst.max(d);
                assert_eq!(deep.as_ref(), Some(&want_deep), "{what}: DeepFrame differs");
                assert_eq!(got.capture.dropped, 0, "{what}: dropped fragments");
                assert_eq!(
                    got.capture.fragments_stored, want.capture.fragments_stored,
                    "{what}"
                );
                assert_eq!(got.depth, want.depth, "{what}: depth statistics differ");
            }
        }
    }
    worst
}

/// `scene` with its objects' alphas set to a spread of values, so that products of `1 − α`
/// formed in different orders round differently (with one alpha everywhere they cannot).
pub(crate) fn varied_alphas(mut scene: Scene) -> Scene {
    for (i, o) in scene.objects.iter_mut().enumerate() {
        o.material.color[3] = [0.23, 0.41, 0.67, 0.85, 0.12, 0.55][i % 6];
    }
    scene
}

/// Renders frames `frames` of `scene` with a fresh method from `make` and the A-buffer; asserts
/// equal DeepFrames and returns the largest image difference and how many channels differ.
pub(crate) fn difference_over_frames(
    make: &dyn Fn() -> Box<dyn Method>,
    scene: &Scene,
    frames: impl IntoIterator<Item = u32>,
) -> (u8, usize) {
    let (mut worst, mut differing) = (0, 0);
    for frame in frames {
        let (want, want_deep) = reference(scene, frame);
        let mut m = make();
        let (got, deep) = render_with(m.as_mut(), scene, frame, 2);
        assert_eq!(deep.as_ref(), Some(&want_deep), "frame {frame}");
        worst = worst.max(max_diff(&got.image, &want.image));
        differing += differing_channels(&got.image, &want.image);
    }
    (worst, differing)
}
