//! Every registered method against the linked-list A-buffer, driven by the registry.
//!
//! Each method is classified here; a method added to the registry without a classification fails
//! `every_registered_method_is_classified`, so nothing escapes this comparison.

use strata_core::metrics::max_channel_difference;
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::{Scene, SearchPath, open_scene};
use strata_stores::{Budget, METHODS, MethodOptions, create, render_frame};

/// How close a method comes to the A-buffer when given enough memory or passes.
#[derive(Debug, PartialEq)]
enum Expect {
    /// The same image and the same DeepFrame, bit for bit.
    Exact,
    /// Same fragments (DeepFrame); the image within one 8-bit step per channel, because the
    /// method blends in another order (weight factors, back-to-front halves).
    WithinOneStep,
    /// An approximation: only sanity is checked (image of the right size, nothing panics).
    Approximate,
}

fn expectation(name: &str) -> Option<Expect> {
    Some(match name {
        "abuffer" | "abuffer-array" | "sbuffer" | "kbuffer" | "vkbuffer" | "tfss"
        | "depth-peeling" => Expect::Exact,
        "wf" | "dual-depth-peeling" => Expect::WithinOneStep,
        "wboit" => Expect::Approximate,
        _ => return None,
    })
}

/// Options that give every method enough room to keep every fragment.
fn generous() -> MethodOptions {
    MethodOptions {
        array_size: 64,
        k: 64,
        budget: Budget::SceneShare(1.0),
        max_layers: 0,
        ..MethodOptions::default()
    }
}

fn scene(name: &str) -> Scene {
    let mut s = open_scene(name, &SearchPath::default()).expect("built-in scene");
    (s.width, s.height) = (160, 90);
    s
}

#[test]
fn every_registered_method_is_classified() {
    for m in METHODS {
        assert!(
            expectation(m.name).is_some(),
            "method '{}' is registered but not classified in tests/every_method.rs",
            m.name
        );
    }
}

#[test]
fn every_method_with_enough_room_matches_the_a_buffer() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    for scene_name in ["slabs", "spheres", "mixed", "overlap"] {
        let s = scene(scene_name);
        let input = FrameInput::from_scene(&s, 4);
        let mut raster = Rasterizer::default();
        let render = |name: &str, raster: &mut Rasterizer| {
            let mut m = create(name, &generous()).expect("registered");
            let r = pool
                .install(|| render_frame(m.as_mut(), raster, &input, s.background))
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            (r, m.deep_frame().map(|d| d.expect("valid DeepFrame")))
        };
        let (reference, reference_deep) = render("abuffer", &mut raster);
        let reference_deep = reference_deep.expect("the A-buffer exports a DeepFrame");
        for m in METHODS {
            let what = format!("{} on {scene_name}", m.name);
            let (r, deep) = render(m.name, &mut raster);
            assert_eq!((r.image.width(), r.image.height()), (160, 90), "{what}");
            match expectation(m.name).expect("classified") {
                Expect::Exact => {
                    assert_eq!(r.image, reference.image, "{what}: image differs");
                    assert_eq!(
                        deep.as_ref(),
                        Some(&reference_deep),
                        "{what}: DeepFrame differs"
                    );
                    assert_eq!(
                        r.capture.dropped, 0,
                        "{what}: dropped fragments with room to spare"
                    );
                }
                Expect::WithinOneStep => {
                    let d = max_channel_difference(&r.image, &reference.image).unwrap();
                    assert!(d <= 1, "{what}: off by {d} steps");
                    if let Some(deep) = deep {
                        assert_eq!(deep, reference_deep, "{what}: DeepFrame differs");
                    }
                }
                Expect::Approximate => assert!(
                    deep.is_none(),
                    "{what}: an approximation exporting fragments?"
                ),
            }
        }
    }
}

#[test]
fn every_method_is_deterministic_across_thread_counts() {
    let s = scene("spheres");
    let input = FrameInput::from_scene(&s, 2);
    for m in METHODS {
        let images: Vec<_> = [1, 3]
            .into_iter()
            .map(|threads| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                // Tight settings, so that what each method drops or evicts matters too.
                let options = MethodOptions {
                    array_size: 3,
                    k: 3,
                    budget: Budget::SceneShare(0.4),
                    max_layers: 3,
                    ..MethodOptions::default()
                };
                let mut method = create(m.name, &options).expect("registered");
                let mut raster = Rasterizer::default();
                pool.install(|| render_frame(method.as_mut(), &mut raster, &input, s.background))
                    .expect("render")
                    .image
            })
            .collect();
        assert_eq!(images[0], images[1], "{}: 1 vs 3 threads", m.name);
    }
}
