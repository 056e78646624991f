//! Every registered method against the linked-list A-buffer, driven by the registry.
//!
//! Each method is classified here; a method added to the registry without a classification fails
//! `every_registered_method_is_classified`, so nothing escapes this comparison.

mod common;

use common::{SCENES, pool, scene};
use strata_core::metrics::max_channel_difference;
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::{Budget, METHODS, MethodOptions, create, render_frame};

/// How close a method's image comes to the A-buffer's when given enough memory or passes.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Image {
    /// The same image, bit for bit.
    Identical,
    /// Within one 8-bit step per channel, because the method blends in another order (weight
    /// factors, back-to-front halves).
    WithinOneStep,
    /// An approximation: only its size is checked.
    Approximate,
}

/// What a method must hand out as its DeepFrame.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Deep {
    /// Exactly the A-buffer's DeepFrame: the method keeps every fragment.
    SameAsABuffer,
    /// Nothing: the method keeps no fragments (exporting some would be a bug).
    None,
}

fn expectation(name: &str) -> Option<(Image, Deep)> {
    Some(match name {
        "abuffer" | "abuffer-array" | "sbuffer" | "kbuffer" | "vkbuffer" | "tfss"
        | "depth-peeling" => (Image::Identical, Deep::SameAsABuffer),
        "wf" | "dual-depth-peeling" => (Image::WithinOneStep, Deep::SameAsABuffer),
        "wboit" => (Image::Approximate, Deep::None),
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
    let pool = pool(2);
    for scene_name in SCENES {
        let s = scene(scene_name, 160, 90);
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
            let (image, expected_deep) = expectation(m.name).expect("classified");
            match image {
                Image::Identical => {
                    assert_eq!(r.image, reference.image, "{what}: image differs");
                }
                Image::WithinOneStep => {
                    let d = max_channel_difference(&r.image, &reference.image).unwrap();
                    assert!(d <= 1, "{what}: off by {d} steps");
                }
                Image::Approximate => {}
            }
            match expected_deep {
                Deep::SameAsABuffer => {
                    let deep = deep.unwrap_or_else(|| {
                        panic!("{what}: keeps every fragment but exports no DeepFrame")
                    });
                    assert_eq!(deep, reference_deep, "{what}: DeepFrame differs");
                    assert_eq!(
                        r.capture.dropped, 0,
                        "{what}: dropped fragments with room to spare"
                    );
                }
                Deep::None => assert!(
                    deep.is_none(),
                    "{what}: an approximation exporting fragments?"
                ),
            }
        }
    }
}

#[test]
fn every_method_is_deterministic_across_thread_counts() {
    let s = scene("spheres", 160, 90);
    let input = FrameInput::from_scene(&s, 2);
    for m in METHODS {
        let images: Vec<_> = [1, 3]
            .into_iter()
            .map(|threads| {
                let pool = pool(threads);
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
