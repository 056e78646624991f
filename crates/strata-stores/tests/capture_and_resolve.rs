//! [`Method::capture_and_resolve`] does what `capture` then `resolve` does, and
//! [`Method::capture_and_export`] what `capture` then `deep_frame` does (then
//! [`DeepFrame::limit_runs`], for a depth-limited export), for every store — the same image,
//! depth statistics, capture report and DeepFrame — including the linked list's
//! fused passes (each strip resolved or gathered as its scan ends): with a pool that overflows
//! and drops, with an automatic pool that must grow and capture again, after an earlier chunk of
//! the frame was captured on its own, and on one thread or two.

mod common;

use common::{pool, scene};
use strata_core::{DeepFrame, DepthStats, PassTimings, Rgb8Image, RunLimit};
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::{CaptureReport, Method, MethodOptions, PoolCapacity, create};

/// What a frame left behind: image, depth statistics, the report's counts, the DeepFrame.
#[derive(Debug, PartialEq)]
struct Outcome {
    image: Rgb8Image,
    depth: Option<DepthStats>,
    report: (u64, u64, u64, u32, u32),
    deep: Option<DeepFrame>,
}

fn counts(r: &CaptureReport) -> (u64, u64, u64, u32, u32) {
    (
        r.fragments_rasterized,
        r.fragments_stored,
        r.dropped,
        r.regrows,
        r.raster_passes,
    )
}

/// How the last chunk of a frame is captured and the frame read.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    /// `capture`, then `resolve` and `deep_frame`.
    Apart,
    /// `capture_and_resolve`, then `deep_frame`.
    Resolve,
    /// `capture_and_export` with a limit (its frame must equal `deep_frame`'s cut to the
    /// limit), then `resolve`.
    Export(RunLimit),
}

/// Renders `chunks` (all but the last captured alone) with `method` on `threads` threads, the
/// last chunk as `mode` says.
fn run(
    method: &mut dyn Method,
    chunks: &[FrameInput<'_>],
    background: [f32; 3],
    threads: usize,
    mode: Mode,
) -> (Outcome, PassTimings) {
    let (width, height) = (chunks[0].width, chunks[0].height);
    let mut raster = Rasterizer::default();
    let mut timings = PassTimings::new();
    pool(threads).install(|| {
        method.clear(width, height).expect("clear");
        let (last, earlier) = chunks.split_last().expect("a chunk");
        for chunk in earlier {
            method
                .capture(&mut raster, chunk, &mut PassTimings::new())
                .expect("capture");
        }
        let name = method.name();
        let (report, image, exported) = match mode {
            Mode::Resolve => {
                let (report, image) = method
                    .capture_and_resolve(&mut raster, last, background, &mut timings)
                    .expect("capture and resolve");
                (report, image, None)
            }
            Mode::Apart => {
                let report = method
                    .capture(&mut raster, last, &mut timings)
                    .expect("capture");
                (report, method.resolve(background, &mut timings), None)
            }
            Mode::Export(limit) => {
                let (report, frame) = method
                    .capture_and_export(&mut raster, last, limit, &mut timings, None)
                    .expect("capture and export");
                let frame = frame.map(|f| f.expect("valid DeepFrame"));
                (
                    report,
                    method.resolve(background, &mut timings),
                    Some((limit, frame)),
                )
            }
        };
        let deep = method.deep_frame().map(|d| d.expect("valid DeepFrame"));
        if let Some((limit, exported)) = exported {
            let want = deep.clone().map(|d| d.limit_runs(limit));
            assert_eq!(
                exported, want,
                "{name}: the exported frame is not deep_frame's cut to {limit:?}"
            );
        }
        let outcome = Outcome {
            image,
            depth: method.depth_stats(),
            report: counts(&report),
            deep,
        };
        (outcome, timings)
    })
}

/// `input`'s objects drawn `times` over, and that frame cut into two chunks of triangles.
fn drawn_over<'a>(input: &FrameInput<'a>, times: usize) -> (FrameInput<'a>, [FrameInput<'a>; 2]) {
    let deep = FrameInput {
        objects: (0..times).flat_map(|_| input.objects.clone()).collect(),
        ..input.clone()
    };
    let total = deep.triangle_count();
    let halves = [
        deep.triangle_range(0..total / 2),
        deep.triangle_range(total / 2..total),
    ];
    (deep, halves)
}

#[test]
fn fused_calls_equal_capture_then_resolve_or_export_for_every_store() {
    const LIMITS: [RunLimit; 2] = [RunLimit::new(1, None), RunLimit::new(4, Some(0.6))];
    // Fragments the linked list's frames keep under each limit, and hold.
    let mut cuts = [(0, 0); 2];
    let background = [0.2, 0.5, 0.9];
    let mut failures = Vec::new();
    for scene_name in ["mixed", "overlap", "spheres"] {
        // 40 rows: two full strips of 16 and a short one.
        let s = scene(scene_name, 72, 40);
        let input = FrameInput::from_scene(&s, 5);
        // Every store with its default options, and the k-buffer's tail blend too (its strips
        // gather their regions beside the tails).
        let tail_blend = MethodOptions {
            tail_blend: true,
            ..MethodOptions::default()
        };
        let stores = strata_stores::METHODS
            .iter()
            .map(|info| (info.name, MethodOptions::default()))
            .chain([("kbuffer", tail_blend)]);
        for (name, options) in stores {
            for threads in [1, 2] {
                let one = std::slice::from_ref(&input);
                let mut apart = create(name, &options).expect("registered");
                let (want, _) = run(apart.as_mut(), one, background, threads, Mode::Apart);
                if name == "abuffer" && threads == 1 {
                    let deep = want.deep.clone().expect("the linked list exports");
                    for (limit, cut) in LIMITS.iter().zip(&mut cuts) {
                        cut.0 += deep.clone().limit_runs(*limit).fragment_count();
                        cut.1 += deep.fragment_count();
                    }
                }
                let modes = [Mode::Resolve, Mode::Export(RunLimit::NONE)]
                    .into_iter()
                    .chain(LIMITS.map(Mode::Export));
                for mode in modes {
                    let mut m = create(name, &options).expect("registered");
                    let (got, timings) = run(m.as_mut(), one, background, threads, mode);
                    if got != want {
                        failures.push(format!(
                            "{name} (tail blend {}) on {scene_name}, {threads} thread(s), {mode:?}",
                            options.tail_blend
                        ));
                    }
                    let passes: &[&str] = match mode {
                        Mode::Resolve => &["capture", "resolve"],
                        _ => &["capture.setup"],
                    };
                    for pass in passes {
                        if timings.get(pass).is_none() {
                            failures.push(format!("{name}: no '{pass}' recorded"));
                        }
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "differ:\n{}", failures.join("\n"));
    // Each limit cut the scenes' runs, but not all of them.
    for (limit, (kept, of)) in LIMITS.iter().zip(cuts) {
        assert!(kept > 0 && kept < of, "{limit:?} kept {kept} of {of}");
    }
}

/// The linked list's fused pass under its pool's every path: enough room, a fixed pool that
/// drops fragments, an automatic pool too small for the frame (grown, captured and resolved
/// again), and an earlier chunk captured before the fused one.
#[test]
fn the_linked_lists_fused_pass_matches_under_overflow_regrow_and_chunks() {
    let background = [1.0, 1.0, 1.0];
    let s = scene("overlap", 64, 48);
    let plain = FrameInput::from_scene(&s, 2);
    // Drawn 16 times over (about 5 fragments a pixel): deeper than the automatic pool's first
    // size, 2 nodes a pixel.
    let (deep_input, halves) = drawn_over(&plain, 16);
    let cases: [(&str, PoolCapacity, &[FrameInput<'_>]); 5] = [
        (
            "room",
            PoolCapacity::PerPixel(64.0),
            std::slice::from_ref(&plain),
        ),
        (
            "drops",
            PoolCapacity::Fragments(700),
            std::slice::from_ref(&plain),
        ),
        (
            "regrow",
            PoolCapacity::Auto,
            std::slice::from_ref(&deep_input),
        ),
        ("chunks", PoolCapacity::Auto, &halves),
        ("chunks that drop", PoolCapacity::Fragments(3000), &halves),
    ];
    for (what, capacity, chunks) in cases {
        let options = MethodOptions {
            pool: capacity,
            ..MethodOptions::default()
        };
        for threads in [1, 2] {
            let mut a = create("abuffer", &options).expect("registered");
            let (apart, _) = run(a.as_mut(), chunks, background, threads, Mode::Apart);
            for mode in [
                Mode::Resolve,
                Mode::Export(RunLimit::NONE),
                Mode::Export(RunLimit::new(3, Some(0.9))),
            ] {
                let mut b = create("abuffer", &options).expect("registered");
                let (fused, _) = run(b.as_mut(), chunks, background, threads, mode);
                let (_, stored, dropped, regrows, _) = fused.report;
                let at = format!("{what}, {threads} thread(s), {mode:?}");
                assert!(stored > 0, "{at}: nothing stored");
                match what {
                    "drops" | "chunks that drop" => assert!(dropped > 0, "{at}: nothing dropped"),
                    "regrow" => assert!(regrows > 0, "{at}: the pool did not grow"),
                    _ => assert_eq!(dropped, 0, "{at}"),
                }
                if dropped > 0 && threads > 1 {
                    // Which fragments a full pool drops depends on scheduling (module docs), so
                    // only one thread gives the same ones twice; with two, the image is still
                    // what the kept fragments resolve to.
                    let deep = fused.deep.as_ref().expect("a DeepFrame");
                    assert_eq!(fused.image, deep.resolve(background), "{at}");
                } else {
                    assert_eq!(apart, fused, "{at}");
                }
            }
        }
    }
}

/// The k-buffer's fused export after an earlier chunk of the frame was captured on its own: the
/// strips gather what both chunks kept, with and without the tail blend, on one thread or two.
#[test]
fn the_k_buffers_fused_export_gathers_every_chunk() {
    let background = [0.0, 0.0, 0.0];
    let s = scene("overlap", 64, 48);
    let plain = FrameInput::from_scene(&s, 2);
    // Drawn 4 times over: more layers than k = 4 in the overlaps, so fragments are evicted.
    let (_, halves) = drawn_over(&plain, 4);
    for tail_blend in [false, true] {
        let options = MethodOptions {
            tail_blend,
            ..MethodOptions::default()
        };
        for threads in [1, 2] {
            let mut a = create("kbuffer", &options).expect("registered");
            let (apart, _) = run(a.as_mut(), &halves, background, threads, Mode::Apart);
            // `run` checks each export against the captured frame cut to its limit.
            for limit in [
                RunLimit::NONE,
                RunLimit::new(2, None),
                RunLimit::new(3, Some(0.7)),
            ] {
                let mut b = create("kbuffer", &options).expect("registered");
                let (fused, _) = run(
                    b.as_mut(),
                    &halves,
                    background,
                    threads,
                    Mode::Export(limit),
                );
                let at = format!("tail blend {tail_blend}, {threads} thread(s), {limit:?}");
                let (_, stored, dropped, _, _) = fused.report;
                assert!(stored > 0, "{at}: nothing stored");
                assert!(tail_blend || dropped > 0, "{at}: nothing evicted");
                assert_eq!(fused, apart, "{at}");
            }
        }
    }
}

/// A store that exports frame after frame, each into the buffers of the frame before (as a
/// render node does) and each strip into columns the store kept from the export before (stale
/// fragments in them, more or fewer strips): a deep frame, then a shallow one of another size,
/// then the deep one again, each cut or not, must export what a fresh store exports.
#[test]
fn exports_into_the_last_frames_buffers_equal_fresh_exports() {
    let deep_scene = scene("overlap", 64, 48);
    let deep_plain = FrameInput::from_scene(&deep_scene, 2);
    let (deep, _) = drawn_over(&deep_plain, 8);
    // 24 rows against 48: fewer strips, then more again.
    let shallow_scene = scene("mixed", 72, 24);
    let shallow = FrameInput::from_scene(&shallow_scene, 5);
    let limits = [RunLimit::NONE, RunLimit::new(2, None), RunLimit::NONE];
    let frames = [&deep, &shallow, &deep];
    let export = |m: &mut dyn Method, input: &FrameInput<'_>, limit, reuse| {
        let mut raster = Rasterizer::default();
        m.clear(input.width, input.height).expect("clear");
        let (_, frame) = m
            .capture_and_export(&mut raster, input, limit, &mut PassTimings::new(), reuse)
            .expect("capture and export");
        frame.expect("exports").expect("valid DeepFrame")
    };
    for name in ["abuffer", "kbuffer"] {
        for threads in [1, 2] {
            pool(threads).install(|| {
                let options = MethodOptions::default();
                let mut reused = create(name, &options).expect("registered");
                let mut last: Option<DeepFrame> = None;
                for (i, (input, limit)) in frames.iter().zip(limits).enumerate() {
                    let mut fresh = create(name, &options).expect("registered");
                    let want = export(fresh.as_mut(), input, limit, None);
                    let got = export(reused.as_mut(), input, limit, last.take());
                    assert!(want.fragment_count() > 0, "{name}: frame {i} is empty");
                    assert_eq!(got, want, "{name}, {threads} thread(s): frame {i} differs");
                    last = Some(got);
                }
            });
        }
    }
}
