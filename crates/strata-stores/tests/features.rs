//! The learning features of the variable k-buffer's counting pass: exact on a frame of known
//! layers, the same for any thread count, gathered only when asked for, and changing nothing else.
//!
//! What would catch a wrong feature pass: a nearest colour taken in draw order instead of depth
//! order, sums that miss or double a fragment, a transmittance that ignores a layer, frame values
//! computed over uncovered pixels, a column order that differs from the published list, and
//! results that depend on how strips are spread over threads.

mod common;

use std::sync::Arc;

use common::{pool, scene};
use glam::{Vec3, Vec4};
use strata_core::{Material, ObjectId, Shading};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::builtin::shapes;
use strata_scene::{Camera, Scene, SceneObject};
use strata_stores::kbuffer::VariableKBuffer;
use strata_stores::kbuffer::features::{FEATURE_COUNT, FeatureMaps, feature_index};
use strata_stores::{Budget, Method, MethodOptions, render_frame};

/// A screen-filling unlit quad at world `z` with straight-alpha colour `rgba8`.
fn quad(z: f32, rgba8: [u8; 4], id: u32) -> SceneObject {
    let c = rgba8.map(|v| f32::from(v) / 255.0);
    SceneObject {
        name: format!("quad {id}"),
        id: ObjectId(id),
        mesh: Arc::new(shapes::shape("quad").unwrap()),
        base: glam::Mat4::IDENTITY,
        translate: Vec3::new(0.0, 0.0, z),
        rotate_deg: Vec3::ZERO,
        scale: Vec3::splat(20.0),
        material: Material {
            color: c,
            shading: Shading::Unlit,
        },
    }
}

/// Three full-screen quads, drawn farthest first, 8 × 6 pixels.
fn layers(alphas: [u8; 3]) -> Scene {
    Scene {
        name: "layers".into(),
        origin: "test".into(),
        width: 8,
        height: 6,
        background: [0.0; 3],
        camera: Camera::default(),
        objects: vec![
            quad(-1.0, [0, 0, 255, alphas[2]], 0),
            quad(-0.5, [0, 255, 0, alphas[1]], 1),
            quad(0.0, [255, 0, 0, alphas[0]], 2),
        ],
        animation: None,
        volume: None,
    }
}

/// Renders `scene` with the variable k-buffer at `budget`, features on, on `threads` threads.
fn features(scene: &Scene, budget: Budget, threads: usize) -> (VariableKBuffer, FeatureMaps) {
    let mut vk = VariableKBuffer::new(&MethodOptions {
        budget,
        features: true,
        ..MethodOptions::default()
    });
    let input = FrameInput::from_scene(scene, 0);
    pool(threads)
        .install(|| {
            render_frame(
                &mut vk,
                &mut Rasterizer::default(),
                &input,
                scene.background,
            )
        })
        .expect("render");
    let maps = vk.feature_maps().expect("features were asked for").clone();
    (vk, maps)
}

/// Window depth of a point `d` in front of the default camera.
fn window_depth(d: f32) -> f32 {
    let clip = Camera::default().projection(8, 6) * Vec4::new(0.0, 0.0, -d, 1.0);
    0.5 * clip.z / clip.w + 0.5
}

fn feature(maps: &FeatureMaps, p: usize, name: &str) -> f32 {
    maps.pixel(p)[feature_index(name).unwrap_or_else(|| panic!("no feature {name}"))]
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-5 * b.abs().max(1.0)
}

#[test]
fn features_of_known_layers_by_hand() {
    let (a0, a1, a2) = (128.0 / 255.0, 64.0 / 255.0, 204.0 / 255.0);
    let (_, maps) = features(&layers([128, 64, 204]), Budget::SceneShare(0.5), 1);
    // 48 pixels × 3 fragments = 144; M = 72; every pixel covered.
    let frame = maps.frame().unwrap();
    assert_eq!((frame.total, frame.covered, frame.budget), (144, 48, 72));
    let (near, far) = (window_depth(1.6), window_depth(2.6));
    for p in [0usize, 7, 21, 47] {
        let want = [
            ("count", 3.0),
            ("count_share", 3.0 / 144.0),
            ("budget_share", 0.5),
            ("budget_per_covered", 1.5),
            ("depth_min", near),
            ("depth_max", far),
            ("scene_depth_min", near),
            ("scene_depth_max", far),
            ("mean_r", 1.0 / 3.0),
            ("mean_g", 1.0 / 3.0),
            ("mean_b", 1.0 / 3.0),
            // The nearest quad is drawn last: depth, not draw order, picks it.
            ("nearest_r", 1.0),
            ("nearest_g", 0.0),
            ("nearest_b", 0.0),
            ("nearest_alpha", a0),
            ("alpha_sum", a0 + a1 + a2),
            ("alpha_max", a2),
            ("transmittance", (1.0 - a0) * (1.0 - a1) * (1.0 - a2)),
            ("opaque_count", 0.0),
            // Each channel is 1 in one fragment of three: E[c²] − E[c]² = 1/3 − 1/9 = 2/9.
            ("color_variance", 2.0 / 9.0),
            ("count_mean_3x3", 3.0),
            ("count_max_3x3", 3.0),
            // On black: the mean (1/3, 1/3, 1/3) is √3/3 away, the red nearest 1.
            ("contrast", 3f32.sqrt() / 3.0),
            ("nearest_contrast", 1.0),
        ];
        for (name, value) in want {
            let got = feature(&maps, p, name);
            assert!(
                close(got, value),
                "pixel {p} {name}: {got}, expected {value}"
            );
        }
    }
    // Periphery: pixel 0's centre (0.5, 0.5) is √(3.5² + 2.5²) from the centre (4, 3); half the
    // diagonal is 5.
    assert!(close(feature(&maps, 0, "periphery"), 18.5f32.sqrt() / 5.0));

    // An opaque middle layer: one opaque fragment, nothing gets through.
    let (_, maps) = features(&layers([128, 255, 204]), Budget::SceneShare(0.5), 1);
    assert_eq!(feature(&maps, 5, "opaque_count"), 1.0);
    assert_eq!(feature(&maps, 5, "transmittance"), 0.0);
    assert_eq!(feature(&maps, 5, "alpha_max"), 1.0);
}

/// Pixels of one and of two fragments, whose features the counting pass forms from the
/// fragments' keys rather than from running sums: by hand, like three.
#[test]
fn features_of_one_and_two_layers_by_hand() {
    let (a0, a1) = (128.0 / 255.0, 64.0 / 255.0);
    let (near, mid) = (window_depth(1.6), window_depth(2.1));
    let nearest = |scene: Scene, n: usize| Scene {
        objects: scene.objects[3 - n..].to_vec(),
        ..scene
    };
    // The red quad in front of the green one (drawn first).
    let (_, maps) = features(
        &nearest(layers([128, 64, 204]), 2),
        Budget::SceneShare(0.5),
        1,
    );
    let frame = maps.frame().unwrap();
    assert_eq!((frame.total, frame.covered), (96, 48));
    for p in [0usize, 7, 21, 47] {
        let want = [
            ("count", 2.0),
            ("depth_min", near),
            ("depth_max", mid),
            ("scene_depth_min", near),
            ("scene_depth_max", mid),
            ("mean_r", 0.5),
            ("mean_g", 0.5),
            ("mean_b", 0.0),
            ("nearest_r", 1.0),
            ("nearest_g", 0.0),
            ("nearest_alpha", a0),
            ("alpha_sum", a0 + a1),
            ("alpha_max", a0),
            ("transmittance", (1.0 - a0) * (1.0 - a1)),
            ("opaque_count", 0.0),
            // Red and green are each 1 in one fragment of two (1/2 − 1/4), blue is 0.
            ("color_variance", (0.25 + 0.25) / 3.0),
            ("count_mean_3x3", 2.0),
            ("count_max_3x3", 2.0),
            ("contrast", 0.5f32.sqrt()),
            ("nearest_contrast", 1.0),
        ];
        for (name, value) in want {
            let got = feature(&maps, p, name);
            assert!(
                close(got, value),
                "two layers, pixel {p} {name}: {got}, expected {value}"
            );
        }
    }
    // An opaque far layer.
    let (_, maps) = features(
        &nearest(layers([128, 255, 204]), 2),
        Budget::SceneShare(0.5),
        1,
    );
    assert_eq!(feature(&maps, 5, "opaque_count"), 1.0);
    assert_eq!(feature(&maps, 5, "transmittance"), 0.0);
    assert_eq!(feature(&maps, 5, "alpha_max"), 1.0);
    // The red quad alone.
    let (_, maps) = features(
        &nearest(layers([128, 64, 204]), 1),
        Budget::SceneShare(0.5),
        1,
    );
    for p in [0usize, 47] {
        let want = [
            ("count", 1.0),
            ("depth_min", near),
            ("depth_max", near),
            ("mean_r", 1.0),
            ("mean_g", 0.0),
            ("nearest_r", 1.0),
            ("nearest_alpha", a0),
            ("alpha_sum", a0),
            ("alpha_max", a0),
            ("transmittance", 1.0 - a0),
            ("opaque_count", 0.0),
            ("color_variance", 0.0),
            ("contrast", 1.0),
        ];
        for (name, value) in want {
            let got = feature(&maps, p, name);
            assert!(
                close(got, value),
                "one layer, pixel {p} {name}: {got}, expected {value}"
            );
        }
    }
}

#[test]
fn uncovered_pixels_and_invariants_on_a_built_in_scene() {
    let s = scene("mixed", 96, 54);
    let (vk, maps) = features(&s, Budget::SceneShare(0.3), 2);
    let counts = vk.counts();
    let frame = maps.frame().unwrap();
    assert_eq!(
        frame.total,
        counts.iter().map(|&c| u64::from(c)).sum::<u64>()
    );
    assert_eq!(
        frame.covered,
        counts.iter().filter(|&&c| c > 0).count() as u64
    );
    let count_col = feature_index("count").unwrap();
    let per_pixel_zero = [
        "count_share",
        "depth_min",
        "depth_max",
        "mean_r",
        "nearest_g",
        "alpha_sum",
        "opaque_count",
    ];
    let (mut covered, mut empty) = (0, 0);
    for (p, &c) in counts.iter().enumerate() {
        let row = maps.pixel(p);
        assert_eq!(row[count_col], c as f32);
        if c == 0 {
            empty += 1;
            for name in per_pixel_zero {
                assert_eq!(feature(&maps, p, name), 0.0, "pixel {p} {name}");
            }
            continue;
        }
        covered += 1;
        let f = |name| feature(&maps, p, name);
        assert!(f("depth_min") <= f("depth_max"));
        assert!(f("scene_depth_min") <= f("depth_min") && f("depth_max") <= f("scene_depth_max"));
        assert!(f("alpha_sum") <= c as f32 + 1e-4 && f("alpha_max") <= 1.0);
        assert!((0.0..=1.0).contains(&f("transmittance")));
        assert!(f("opaque_count") <= c as f32);
        assert!(f("count_max_3x3") >= c as f32);
    }
    assert!(
        covered > 0 && empty > 0,
        "the scene should cover part of the frame"
    );
    // [H, W, F] interleaving keeps each pixel's row together.
    let flat = maps.interleaved();
    assert_eq!(flat.len(), 96 * 54 * FEATURE_COUNT);
    let p = 54 / 2 * 96 + 40;
    assert_eq!(
        &flat[p * FEATURE_COUNT..(p + 1) * FEATURE_COUNT],
        &maps.pixel(p)
    );
}

#[test]
fn features_are_the_same_for_any_thread_count() {
    for name in ["spheres", "mixed", "slabs"] {
        let s = scene(name, 120, 68);
        let (_, one) = features(&s, Budget::SceneShare(0.5), 1);
        for threads in [2, 3] {
            let (_, many) = features(&s, Budget::SceneShare(0.5), threads);
            let same = (0..FEATURE_COUNT).all(|f| {
                one.plane(f)
                    .iter()
                    .zip(many.plane(f))
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            });
            assert!(same, "{name}: features differ on {threads} threads");
        }
    }
}

#[test]
fn features_are_gathered_only_when_asked_and_change_nothing_else() {
    let s = scene("spheres", 120, 68);
    let mut plain = VariableKBuffer::new(&MethodOptions::default());
    let input = FrameInput::from_scene(&s, 0);
    let image = render_frame(&mut plain, &mut Rasterizer::default(), &input, s.background)
        .expect("render")
        .image;
    assert!(plain.feature_maps().is_none());
    let (with, _) = features(&s, Budget::SceneShare(0.5), 1);
    assert_eq!(with.k_map(), plain.k_map());
    assert_eq!(with.importance_map(), plain.importance_map());
    let mut again = with;
    let image2 = render_frame(&mut again, &mut Rasterizer::default(), &input, s.background)
        .expect("render")
        .image;
    assert_eq!(image, image2);
    assert!(
        again.memory_bytes() > plain.memory_bytes(),
        "the features' memory is counted"
    );
}

/// Counts `s` into `counts` and `sums` (cleared first) on `threads` threads; returns `N`.
fn count_into(
    s: &Scene,
    counts: &mut strata_stores::count::FragmentCounts,
    sums: &mut strata_stores::kbuffer::features::FeatureAccumulator,
    threads: usize,
) -> u64 {
    counts.clear(s.width, s.height).unwrap();
    sums.clear(s.width, s.height).unwrap();
    count_more(&FrameInput::from_scene(s, 0), counts, sums, threads)
}

/// Counts `input` into `counts` and `sums` as they are (one call of a chunked capture);
/// returns the fragments it added.
fn count_more(
    input: &FrameInput<'_>,
    counts: &mut strata_stores::count::FragmentCounts,
    sums: &mut strata_stores::kbuffer::features::FeatureAccumulator,
    threads: usize,
) -> u64 {
    use strata_stores::kbuffer::features::FeatureCapture;
    pool(threads).install(|| {
        Rasterizer::default()
            .prepare(input)
            .rasterize(&mut FeatureCapture { counts, sums })
            .fragments
    })
}

#[test]
fn one_pixel_at_a_time_matches_the_maps_and_the_frame_values_the_pixels() {
    use strata_stores::count::FragmentCounts;
    use strata_stores::kbuffer::features::{FeatureAccumulator, FrameFeatures};
    // 83 wide: the maps' blocks of 8 pixels run across the ends of rows.
    let s = scene("spheres", 83, 45);
    let (mut counts, mut sums) = (FragmentCounts::new(), FeatureAccumulator::new());
    let total = count_into(&s, &mut counts, &mut sums, 2);
    let mut maps = FeatureMaps::new();
    let frame = maps.compute(&sums, counts.counts(), total / 2, s.background);
    for (x, y) in (0..45).flat_map(|y| (0..83).map(move |x| (x, y))) {
        let one = sums.pixel_features(counts.counts(), &frame, x, y);
        assert_eq!(one, maps.pixel(y * 83 + x), "pixel ({x}, {y})");
    }
    // The frame values kept by the counting pass's strips are those of the pixels.
    let covered: Vec<usize> = (0..counts.counts().len())
        .filter(|&p| counts.counts()[p] > 0)
        .collect();
    let near = feature_index("depth_min").unwrap();
    let far = feature_index("depth_max").unwrap();
    let plane_min = |f: usize| {
        covered
            .iter()
            .map(|&p| maps.plane(f)[p])
            .fold(f32::INFINITY, f32::min)
    };
    let plane_max = |f: usize| {
        covered
            .iter()
            .map(|&p| maps.plane(f)[p])
            .fold(0.0, f32::max)
    };
    assert_eq!(
        frame,
        FrameFeatures {
            total: counts.counts().iter().map(|&c| u64::from(c)).sum(),
            covered: covered.len() as u64,
            budget: total / 2,
            depth_min: plane_min(near),
            depth_max: plane_max(far),
            background: s.background,
        }
    );
    assert_eq!(frame.total, total);
    assert!(
        frame.covered > 100 && frame.covered < 80 * 45,
        "{}",
        frame.covered
    );
}

/// A frame counted in several calls (a chunked capture: the counts and sums carry over from
/// call to call) gives the frame values and the features of one call. Each strip's `N` and `C`
/// are taken from its counts when the strip ends, so they must be the frame's so far, not the
/// last call's alone.
#[test]
fn a_frame_counted_in_several_calls_is_counted_once() {
    use strata_stores::count::FragmentCounts;
    use strata_stores::kbuffer::features::FeatureAccumulator;
    let s = scene("mixed", 80, 45);
    let (mut counts, mut sums) = (FragmentCounts::new(), FeatureAccumulator::new());
    let whole = count_into(&s, &mut counts, &mut sums, 2);
    let mut once = FeatureMaps::new();
    let frame_once = once.compute(&sums, counts.counts(), whole / 2, s.background);
    let input = FrameInput::from_scene(&s, 0);
    let total = input.triangle_count();
    for parts in [2, 5] {
        let (mut counts, mut sums) = (FragmentCounts::new(), FeatureAccumulator::new());
        counts.clear(s.width, s.height).unwrap();
        sums.clear(s.width, s.height).unwrap();
        let (mut n, mut spanning) = (0, 0);
        for k in 0..parts {
            let before: Vec<u32> = counts.counts().to_vec();
            let part = input.triangle_range(total * k / parts..total * (k + 1) / parts);
            n += count_more(&part, &mut counts, &mut sums, 2);
            // Pixels this call added to after an earlier one: their sums carry over.
            spanning += before
                .iter()
                .zip(counts.counts())
                .filter(|&(&b, &a)| b > 0 && a > b)
                .count();
        }
        assert!(
            spanning > 100,
            "{parts} calls: {spanning} pixels span calls"
        );
        assert_eq!(n, whole, "{parts} calls");
        let mut maps = FeatureMaps::new();
        let frame = maps.compute(&sums, counts.counts(), whole / 2, s.background);
        assert_eq!(frame, frame_once, "{parts} calls");
        assert!(maps == once, "{parts} calls: the features differ");
    }
}

/// The sums are never cleared: a pixel's start afresh at its first fragment. Counting a frame
/// that covers few pixels after one that covers many, with the same sums, gives the features of
/// fresh sums, and so do 1 and 2 threads.
#[test]
fn reused_sums_give_the_features_of_fresh_ones() {
    use strata_stores::count::FragmentCounts;
    use strata_stores::kbuffer::features::FeatureAccumulator;
    let many = scene("mixed", 80, 45);
    let few = layers([128, 64, 204]);
    let few = Scene {
        width: 80,
        height: 45,
        objects: vec![SceneObject {
            scale: Vec3::splat(0.3),
            ..few.objects[2].clone()
        }],
        ..few
    };
    let (mut counts, mut reused) = (FragmentCounts::new(), FeatureAccumulator::new());
    let maps = |counts: &FragmentCounts, sums: &FeatureAccumulator, total: u64| {
        let mut m = FeatureMaps::new();
        m.compute(sums, counts.counts(), total, [0.0; 3]);
        m
    };
    let n_many = count_into(&many, &mut counts, &mut reused, 2);
    let covered_before: Vec<bool> = counts.counts().iter().map(|&c| c > 0).collect();
    let covered_many = covered_before.iter().filter(|&&c| c).count();
    let n_few = count_into(&few, &mut counts, &mut reused, 2);
    let covered_few = counts.counts().iter().filter(|&&c| c > 0).count();
    assert!(n_many > n_few && covered_few > 0 && covered_few * 4 < covered_many);
    // The second frame covers pixels whose sums the first left behind: stale sums are there to
    // be reset.
    let overlap = counts
        .counts()
        .iter()
        .zip(&covered_before)
        .filter(|&(&c, &before)| c > 0 && before)
        .count();
    assert!(
        overlap * 2 > covered_few,
        "{overlap} of {covered_few} pixels overlap"
    );
    let after = maps(&counts, &reused, n_few);
    for threads in [1, 2] {
        let (mut fresh_counts, mut fresh) = (FragmentCounts::new(), FeatureAccumulator::new());
        count_into(&few, &mut fresh_counts, &mut fresh, threads);
        assert_eq!(
            after,
            maps(&fresh_counts, &fresh, n_few),
            "{threads} thread(s)"
        );
    }
}

/// The features are the same whatever order the layers are drawn in: sums are integer sums of
/// the 8-bit channels and of a fixed-point −ln(1 − α), which float sums and products are not.
#[test]
fn draw_order_changes_no_feature() {
    let scene = layers([128, 64, 204]);
    let (_, drawn) = features(&scene, Budget::SceneShare(0.5), 2);
    let mut objects = scene.objects.clone();
    for order in [[2, 1, 0], [1, 2, 0], [0, 2, 1]] {
        let reordered = Scene {
            objects: order.iter().map(|&i| objects[i].clone()).collect(),
            ..scene.clone()
        };
        let (_, maps) = features(&reordered, Budget::SceneShare(0.5), 2);
        assert_eq!(maps, drawn, "drawn in order {order:?}");
    }
    // And with one layer opaque, the transmittance is 0 in any order.
    objects[1].material.color[3] = 1.0;
    let opaque = Scene {
        objects: objects.clone(),
        ..scene.clone()
    };
    let (_, maps) = features(&opaque, Budget::SceneShare(0.5), 1);
    assert_eq!(feature(&maps, 3, "transmittance"), 0.0);
    assert_eq!(feature(&maps, 3, "opaque_count"), 1.0);
}
