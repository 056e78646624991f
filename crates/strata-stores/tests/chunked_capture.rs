//! The capture contract of [`strata_stores::Method`]: several capture calls between clear and
//! export accumulate. Every exact store must give the same DeepFrame, bit for bit, whether a
//! frame is captured in one call or in chunks — split by object, by triangle ranges crossing
//! objects, with empty chunks, and with a later chunk that outgrows the buffers the earlier ones
//! sized.

mod common;

use common::{pool, scene};
use strata_core::DeepFrame;
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::{Method, MethodOptions, create, exact_methods};

/// Clears `method` and captures `chunks` one after the other; its DeepFrame and the reports'
/// dropped fragments and regrows after the first chunk.
fn capture_chunks(method: &mut dyn Method, chunks: &[FrameInput<'_>]) -> (DeepFrame, u64, u32) {
    let (width, height) = (chunks[0].width, chunks[0].height);
    let mut raster = Rasterizer::default();
    let mut timings = strata_core::PassTimings::new();
    let name = method.name();
    pool(2).install(|| {
        method.clear(width, height).expect("clear");
        let (mut dropped, mut later_regrows) = (0, 0);
        for (k, chunk) in chunks.iter().enumerate() {
            let report = method
                .capture(&mut raster, chunk, &mut timings)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            dropped += report.dropped;
            if k > 0 {
                later_regrows += report.regrows;
            }
        }
        let deep = method
            .deep_frame()
            .unwrap_or_else(|| panic!("{name} is exact but exports no DeepFrame"))
            .expect("valid DeepFrame");
        (deep, dropped, later_regrows)
    })
}

/// Splits of `input` into chunks: by object, into `n` equal triangle ranges, and uneven ranges
/// with an empty chunk.
fn splits<'a>(input: &FrameInput<'a>) -> Vec<(String, Vec<FrameInput<'a>>)> {
    let total = input.triangle_count();
    let by_object = input
        .objects
        .iter()
        .map(|o| FrameInput {
            objects: vec![*o],
            ..input.clone()
        })
        .collect();
    let equal = |n: u64| {
        (0..n)
            .map(|k| input.triangle_range(total * k / n..total * (k + 1) / n))
            .collect()
    };
    let uneven = [0, 1, 1, total / 3, total - 2, total]
        .windows(2)
        .map(|w| input.triangle_range(w[0]..w[1]))
        .collect();
    vec![
        ("by object".into(), by_object),
        ("3 equal ranges".into(), equal(3)),
        ("7 equal ranges".into(), equal(7)),
        ("uneven ranges with an empty one".into(), uneven),
    ]
}

/// `input` with its objects drawn `times` times over: deep enough that a later chunk needs more
/// room than the first chunks made.
fn repeated<'a>(input: &FrameInput<'a>, times: usize) -> FrameInput<'a> {
    FrameInput {
        objects: (0..times).flat_map(|_| input.objects.clone()).collect(),
        ..input.clone()
    }
}

#[test]
fn every_exact_store_captures_a_frame_in_chunks_as_in_one_call() {
    let names = exact_methods(&MethodOptions::default());
    let mut failures = Vec::new();
    let mut later_chunk_regrows = 0u64;
    let whole_geometry_only: Vec<_> = names
        .iter()
        .filter(|name| {
            !create(name, &MethodOptions::default())
                .expect("registered")
                .captures_in_chunks()
        })
        .collect();
    // Peeling needs all the geometry in every pass; TFSS's regrow starts the frame over (it
    // would lose earlier chunks: not fixed yet). Every other exact store must accumulate.
    assert_eq!(
        whole_geometry_only,
        [&"tfss", &"depth-peeling", &"dual-depth-peeling"],
        "exact stores that do not capture in chunks"
    );
    for scene_name in ["mixed", "overlap"] {
        let s = scene(scene_name, 96, 64);
        let plain = FrameInput::from_scene(&s, 3);
        for (what, input) in [("", plain.clone()), (" drawn 6 times", repeated(&plain, 6))] {
            for name in &names {
                let mut method = create(name, &MethodOptions::default()).expect("registered");
                if !method.captures_in_chunks() {
                    continue;
                }
                let (whole, dropped, _) =
                    capture_chunks(method.as_mut(), std::slice::from_ref(&input));
                assert_eq!(dropped, 0, "{name}: an exact store dropped fragments");
                assert!(whole.fragment_count() > 0, "{scene_name}: nothing drawn");
                for (split, chunks) in splits(&input) {
                    // A fresh store, so that later chunks outgrow what the first ones sized,
                    // then the same store again, reused as in a run.
                    let mut fresh = create(name, &MethodOptions::default()).expect("registered");
                    let (chunked, dropped, regrows) = capture_chunks(fresh.as_mut(), &chunks);
                    later_chunk_regrows += u64::from(regrows);
                    let (again, _, _) = capture_chunks(fresh.as_mut(), &chunks);
                    if again != chunked {
                        failures.push(format!(
                            "{name} on {scene_name}{what}, {split}: a reused store differs"
                        ));
                    }
                    let at = format!("{name} on {scene_name}{what}, {split}");
                    if dropped != 0 {
                        failures.push(format!("{at}: dropped {dropped} fragments"));
                    }
                    if chunked != whole {
                        failures.push(format!(
                            "{at}: DeepFrame differs from one capture ({} fragments, not {})",
                            chunked.fragment_count(),
                            whole.fragment_count()
                        ));
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(
        later_chunk_regrows > 0,
        "no later chunk outgrew its store: the regrow path went untested"
    );
}

/// A store that cannot capture in chunks still survives a second capture call between clear and
/// export (it may start over or refuse), and its export is a valid frame: no store panics when a
/// caller breaks the contract.
#[test]
fn a_second_capture_never_panics_any_store() {
    let s = scene("mixed", 48, 32);
    let input = FrameInput::from_scene(&s, 3);
    let half = input.triangle_range(0..input.triangle_count() / 2);
    for info in strata_stores::METHODS {
        let mut method = create(info.name, &MethodOptions::default()).expect("registered");
        let mut raster = Rasterizer::default();
        let mut timings = strata_core::PassTimings::new();
        pool(2).install(|| {
            method.clear(48, 32).expect("clear");
            for chunk in [&half, &input] {
                // An error is an acceptable answer; a panic is not.
                let _ = method.capture(&mut raster, chunk, &mut timings);
            }
            if let Some(frame) = method.deep_frame() {
                frame.unwrap_or_else(|e| panic!("{}: invalid DeepFrame: {e}", info.name));
            }
            let image = method.resolve(s.background, &mut timings);
            assert_eq!((image.width(), image.height()), (48, 32), "{}", info.name);
        });
    }
}
