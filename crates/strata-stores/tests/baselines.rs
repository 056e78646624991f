//! Depth peeling, dual depth peeling and weighted blended OIT, end to end, against the
//! linked-list A-buffer.

mod common;

use common::{
    SCENES, check_exact, difference_over_frames, differing_channels, max_diff, pool, reference,
    render_with, scene, scrambled, select, varied_alphas,
};
use strata_core::metrics;
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::baselines::depth_peeling::{self, DepthPeeling};
use strata_stores::baselines::dual_depth_peeling::{self, DualDepthPeeling};
use strata_stores::baselines::wboit::{self, DepthWeight, Wboit};
use strata_stores::{Method, MethodOptions, render_frame};

fn layers(max_layers: u32) -> MethodOptions {
    MethodOptions {
        max_layers,
        ..MethodOptions::default()
    }
}

/// Peeled layers and passes of a depth peeling render of `scene`.
fn peel(
    scene: &strata_scene::Scene,
    max_layers: u32,
) -> (strata_stores::FrameResult, strata_core::DeepFrame, u32, u32) {
    let mut m = DepthPeeling::new(&layers(max_layers));
    let (r, deep) = render_with(&mut m, scene, 0, 2);
    (r, deep.expect("deep frame"), m.layers(), m.passes())
}

// ----- depth peeling ---------------------------------------------------------------------------

#[test]
fn depth_peeling_with_every_layer_equals_the_abuffer_bit_for_bit() {
    let worst = check_exact(&|_| Box::new(DepthPeeling::new(&layers(0))), 192, 108, 0);
    assert_eq!(worst, 0);
}

#[test]
fn depth_peeling_takes_one_pass_per_layer() {
    let s = scene("spheres", 192, 108);
    let (want, _) = reference(&s, 0);
    let max = want.depth.expect("depth").max_depth_complexity();
    let (r, _, layers, passes) = peel(&s, 0);
    assert_eq!(layers, max);
    assert_eq!(
        passes,
        max + 1,
        "one pass per layer and one that finds nothing"
    );
    let n = want.capture.fragments_stored;
    assert_eq!(r.capture.fragments_rasterized, u64::from(passes) * n);
    assert!(r.timings.get("capture.peel").is_some());
    assert!(r.timings.get("capture.blend").is_some());
    // Enough layers is as good as unlimited, and stops without the empty pass.
    let (r2, _, layers2, passes2) = peel(&s, max);
    assert_eq!((layers2, passes2), (max, max));
    assert_eq!(r2.image, r.image);
    assert_eq!(r2.capture.dropped, 0);
}

#[test]
fn depth_peeling_with_l_layers_keeps_the_l_nearest() {
    for name in ["spheres", "slabs"] {
        let s = scene(name, 192, 108);
        let (want, want_deep) = reference(&s, 0);
        let total = want.capture.fragments_stored;
        for l in [1u32, 2, 3] {
            let (r, deep, layers, passes) = peel(&s, l);
            let nearest = select(&want_deep, |i, _| i < l as usize);
            assert_eq!(deep, nearest, "{name}, {l} layers");
            let kept = nearest.fragment_count() as u64;
            assert_eq!(r.capture.fragments_stored, kept);
            assert_eq!(r.capture.dropped, total - kept, "{name}, {l} layers");
            assert_eq!((layers, passes), (l, l));
            // The image is the truncated runs composited.
            assert_eq!(r.image, nearest.resolve(s.background), "{name}, {l} layers");
        }
    }
}

#[test]
fn depth_peeling_memory_without_and_with_layers() {
    let s = scene("overlap", 64, 48);
    let (want, _) = reference(&s, 0);
    let pixels = 64 * 48u64;
    let mut m = DepthPeeling::new(&layers(0)).keep_layers(false);
    let (r, deep) = render_with(&mut m, &s, 0, 1);
    assert!(deep.is_none());
    // 36 bytes of peeling state and a 16-byte accumulator a pixel
    assert_eq!(r.memory_bytes, pixels * (36 + 16));
    let (r, _, _, _) = peel(&s, 0);
    // plus 16 bytes (pixel index + fragment) for every peeled fragment
    assert_eq!(
        r.memory_bytes,
        pixels * (36 + 16) + want.capture.fragments_stored * 16
    );
    assert_eq!(m.name(), depth_peeling::NAME);
}

// ----- dual depth peeling ----------------------------------------------------------------------

#[test]
fn dual_depth_peeling_equals_the_abuffer_within_one_step() {
    let worst = check_exact(
        &|_| Box::new(DualDepthPeeling::new(&layers(0))),
        192,
        108,
        1,
    );
    println!("dual-depth-peeling: largest difference from abuffer: {worst} step(s)");
}

#[test]
fn dual_depth_peeling_difference_per_scene_at_a_larger_size() {
    for name in SCENES {
        let s = scene(name, 320, 180);
        let (want, _) = reference(&s, 0);
        let mut m = DualDepthPeeling::new(&layers(0));
        let (r, _) = render_with(&mut m, &s, 0, 2);
        let d = max_diff(&r.image, &want.image);
        let differing = differing_channels(&r.image, &want.image);
        let max = want.depth.expect("depth").max_depth_complexity();
        println!(
            "dual-depth-peeling {name} 320x180: max {d} step(s), {differing} channel(s) differ, \
             {} passes for depth {max}",
            m.passes()
        );
        assert!(d <= 1, "{name}: {d}");
        assert_eq!(m.passes(), max.div_ceil(2) + 1, "{name}");
    }
}

#[test]
fn dual_depth_peeling_with_varied_alphas_stays_within_one_step() {
    for name in ["slabs", "spheres", "mixed"] {
        let s = varied_alphas(scene(name, 160, 90));
        let (worst, differing) = difference_over_frames(
            &|| Box::new(DualDepthPeeling::new(&layers(0))),
            &s,
            (0..72).step_by(8),
        );
        println!(
            "dual-depth-peeling {name} varied alphas, 9 frames 160x90: max {worst} step(s), \
             {differing} channel(s) differ"
        );
        assert!(worst <= 1, "{name}: {worst}");
    }
}

#[test]
fn dual_depth_peeling_with_l_layers_keeps_both_ends() {
    let s = scene("spheres", 192, 108);
    let (want, want_deep) = reference(&s, 0);
    for l in [1u32, 2, 4] {
        let mut m = DualDepthPeeling::new(&layers(l));
        let (r, deep) = render_with(&mut m, &s, 0, 2);
        // ⌈l/2⌉ peel passes after the initial one, each taking the nearest and the farthest.
        let h = l.div_ceil(2) as usize;
        let ends = select(&want_deep, |i, n| i < h || i + h >= n);
        assert_eq!(deep.expect("deep frame"), ends, "{l} layers");
        let kept = ends.fragment_count() as u64;
        assert_eq!(r.capture.fragments_stored, kept);
        assert_eq!(r.capture.dropped, want.capture.fragments_stored - kept);
        assert_eq!(m.passes(), l.div_ceil(2) + 1);
    }
}

#[test]
fn dual_depth_peeling_memory() {
    let s = scene("overlap", 64, 48);
    let (want, _) = reference(&s, 0);
    let mut m = DualDepthPeeling::new(&layers(0));
    let (r, _) = render_with(&mut m, &s, 0, 2);
    // 92 bytes of state a pixel, 16 per kept fragment
    assert_eq!(
        r.memory_bytes,
        64 * 48 * 92 + want.capture.fragments_stored * 16
    );
    let mut m = DualDepthPeeling::new(&layers(0)).keep_layers(false);
    let (r, deep) = render_with(&mut m, &s, 0, 2);
    assert!(deep.is_none());
    assert_eq!(r.memory_bytes, 64 * 48 * 92);
    assert_eq!(m.name(), dual_depth_peeling::NAME);
}

// ----- weighted blended OIT --------------------------------------------------------------------

#[test]
fn wboit_single_layer_is_exact_over() {
    // `overlap` with the blue quad removed: one half-transparent red layer over white.
    let mut s = scene("overlap", 160, 120);
    s.objects.truncate(1);
    let (want, _) = reference(&s, 0);
    let (r, deep) = render_with(&mut Wboit::new(&MethodOptions::default()), &s, 0, 2);
    assert!(deep.is_none(), "WBOIT keeps no fragments");
    assert_eq!(r.image, want.image);
    assert_eq!(r.image.pixel(80, 60), [255, 127, 127]);
}

#[test]
fn wboit_layers_of_one_colour_give_the_exact_coverage() {
    // Both quads red, with alphas 0.5 and 0.3: where they overlap the colour average is red
    // whatever the weights, and the coverage must be 1 − (1 − α₁)(1 − α₂).
    let mut s = scene("overlap", 160, 120);
    s.objects[0].material.color = [1.0, 0.0, 0.0, 0.5];
    s.objects[1].material.color = [1.0, 0.0, 0.0, 0.3];
    let (want, _) = reference(&s, 0);
    let mut m = Wboit::new(&MethodOptions::default());
    let (r, _) = render_with(&mut m, &s, 0, 2);
    assert_eq!(r.image, want.image);
    let (a1, a2) = (128.0 / 255.0, 77.0 / 255.0); // the 8-bit alphas
    let acc = m.accum(60 * 160 + 80);
    assert_eq!(acc.fragments, 2);
    let revealage = (1.0 - a1) * (1.0 - a2);
    assert!((acc.revealage() - revealage).abs() < 1e-9);
    let c = acc.composite([1.0, 1.0, 1.0]);
    assert!((c[0] - 1.0).abs() < 1e-9);
    assert!((c[1] - revealage).abs() < 1e-9);
    assert!((c[2] - revealage).abs() < 1e-9);
}

#[test]
fn wboit_is_order_and_thread_independent() {
    for name in ["slabs", "spheres", "mixed"] {
        let s = scene(name, 192, 108);
        let (a, _) = render_with(&mut Wboit::new(&MethodOptions::default()), &s, 0, 2);
        let (one, _) = render_with(&mut Wboit::new(&MethodOptions::default()), &s, 0, 1);
        assert_eq!(a.image, one.image, "{name}: thread count");
        for seed in [3, 0xfeed] {
            let (b, _) = render_with(
                &mut Wboit::new(&MethodOptions::default()),
                &scrambled(&s, seed),
                0,
                2,
            );
            assert_eq!(a.image, b.image, "{name}: triangle order");
        }
    }
}

#[test]
fn wboit_approximates_the_abuffer() {
    // The figures the report quotes: RMSE against the exact A-buffer per scene and weight.
    for name in SCENES {
        let s = scene(name, 320, 180);
        let (want, _) = reference(&s, 0);
        let mut line = format!("wboit {name} 320x180 RMSE:");
        for weight in [
            DepthWeight::Eq7,
            DepthWeight::Eq8,
            DepthWeight::Eq9,
            DepthWeight::Eq10,
        ] {
            let mut m = Wboit::with_weight(weight);
            let (r, _) = render_with(&mut m, &s, 0, 2);
            let rmse = metrics::rmse(&r.image, &want.image).expect("same size");
            line += &format!(" {weight:?} {rmse:.4}");
            assert!(rmse < 0.1, "{name} {weight:?}: RMSE {rmse}");
            assert_eq!(r.depth, want.depth, "{name}: it counts every fragment");
            assert_eq!(
                r.capture.fragments_rasterized,
                want.capture.fragments_stored
            );
        }
        println!("{line}");
    }
    assert_eq!(Wboit::new(&MethodOptions::default()).name(), wboit::NAME);
}

#[test]
fn wboit_memory_is_its_accumulators() {
    let s = scene("overlap", 64, 48);
    let (r, _) = render_with(&mut Wboit::new(&MethodOptions::default()), &s, 0, 1);
    assert_eq!(r.memory_bytes, 64 * 48 * 48);
}

// ----- all methods reuse the rasterizer's prepared frame ---------------------------------------

#[test]
fn peeling_methods_are_reusable_across_frames_and_sizes() {
    let mut methods: Vec<Box<dyn Method>> = vec![
        Box::new(DepthPeeling::new(&layers(0))),
        Box::new(DualDepthPeeling::new(&layers(0))),
    ];
    let mut raster = Rasterizer::default();
    for (name, w, h) in [("slabs", 160, 90), ("overlap", 64, 48), ("slabs", 160, 90)] {
        let s = scene(name, w, h);
        let (want, want_deep) = reference(&s, 0);
        let input = FrameInput::from_scene(&s, 0);
        for m in &mut methods {
            let r = pool(2)
                .install(|| render_frame(m.as_mut(), &mut raster, &input, s.background))
                .expect("render");
            assert!(max_diff(&r.image, &want.image) <= 1, "{} {name}", m.name());
            let deep = m.deep_frame().expect("kept").expect("valid");
            assert_eq!(deep, want_deep, "{} {name} {w}x{h}", m.name());
        }
    }
}
