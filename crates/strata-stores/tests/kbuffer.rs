//! The k-buffers end to end: the fixed k-buffer (with and without tail blend) and the variable
//! k-buffer (importance maps and Optimal-K) against the A-buffer.
//!
//! What would catch a wrong k-buffer: kept fragments that are not exactly the k(p) nearest of the
//! A-buffer's, evictions that are not counted, a budget that is exceeded or wasted, a tail blend
//! that touches pixels it should not, an oracle that loses to the heuristic it is meant to bound,
//! and results that depend on thread count or triangle order.

mod common;

use common::{reference, render_exact, scene, scrambled};
use strata_core::metrics::rmse;
use strata_core::{DeepFrame, Rgb8Image};
use strata_scene::Scene;
use strata_stores::kbuffer::maps::{heat_map, k_heat_map, write_heat_map};
use strata_stores::kbuffer::{KBuffer, VariableKBuffer, optimal_k};
use strata_stores::{Budget, FrameResult, KFrom, Method, MethodOptions};

// ----- helpers ----------------------------------------------------------------------------------

/// Renders frame 0 of `scene` with `method` on `threads` threads; returns the result and the
/// method's DeepFrame.
fn render(method: &mut dyn Method, scene: &Scene, threads: usize) -> (FrameResult, DeepFrame) {
    render_exact(method, scene, 0, threads)
}

fn abuffer(scene: &Scene) -> (FrameResult, DeepFrame) {
    reference(scene, 0)
}

fn kbuffer(scene: &Scene, k: u32, tail_blend: bool, threads: usize) -> (FrameResult, DeepFrame) {
    render(&mut KBuffer::with_k(k, tail_blend), scene, threads)
}

fn vkbuffer(
    scene: &Scene,
    budget: Budget,
    k_from: KFrom,
    threads: usize,
) -> (FrameResult, DeepFrame, VariableKBuffer) {
    let mut v = VariableKBuffer::new(&MethodOptions {
        budget,
        k_from,
        ..MethodOptions::default()
    });
    let (r, deep) = render(&mut v, scene, threads);
    (r, deep, v)
}

/// The A-buffer's DeepFrame with each pixel cut to its `keep(p)` nearest fragments.
fn truncated(deep: &DeepFrame, keep: impl Fn(usize) -> u32) -> DeepFrame {
    let counts: Vec<u32> = deep
        .counts()
        .enumerate()
        .map(|(p, c)| c.min(keep(p)))
        .collect();
    DeepFrame::build(deep.width(), deep.height(), &counts, |p, out| {
        out.extend(deep.run(p).iter().take(counts[p] as usize))
    })
    .expect("valid")
}

// ----- fixed k ----------------------------------------------------------------------------------

#[test]
fn kbuffer_keeps_exactly_the_k_nearest() {
    for name in ["spheres", "slabs"] {
        let s = scene(name, 160, 90);
        let (a, deep_a) = abuffer(&s);
        let total = a.capture.fragments_stored;
        for k in 1..=8u32 {
            let (r, deep) = kbuffer(&s, k, false, 2);
            let want = truncated(&deep_a, |_| k);
            assert_eq!(deep, want, "{name} k={k}: not the k nearest");
            assert_eq!(r.image, want.resolve(s.background), "{name} k={k}");
            assert_eq!(r.capture.fragments_rasterized, total);
            assert_eq!(r.capture.fragments_stored, want.fragment_count() as u64);
            assert_eq!(
                r.capture.dropped,
                total - r.capture.fragments_stored,
                "{name} k={k}: every eviction is counted"
            );
            assert_eq!(r.capture.tail_blended, 0);
            // k slots a pixel, 12 bytes each, plus offsets and fill counters.
            let pixels = 160 * 90u64;
            assert_eq!(
                r.memory_bytes,
                (pixels + 1) * 4 + pixels * 4 + pixels * u64::from(k) * 12
            );
        }
    }
}

#[test]
fn kbuffer_with_k_at_max_depth_is_the_abuffer() {
    for name in ["spheres", "slabs", "mixed"] {
        let s = scene(name, 200, 120);
        let (a, deep_a) = abuffer(&s);
        let max = a.depth.as_ref().expect("stats").max_depth_complexity();
        for tail_blend in [false, true] {
            for k in [max, max + 3] {
                let (r, deep) = kbuffer(&s, k, tail_blend, 2);
                assert_eq!(r.image, a.image, "{name} k={k} tail={tail_blend}");
                assert_eq!(deep, deep_a, "{name} k={k}");
                assert_eq!((r.capture.dropped, r.capture.tail_blended), (0, 0));
            }
        }
        // One less and something must go.
        let (r, _) = kbuffer(&s, max - 1, false, 2);
        assert!(r.capture.dropped > 0, "{name}");
    }
}

#[test]
fn tail_blend_touches_only_pixels_with_more_than_k_fragments() {
    for name in ["spheres", "mixed"] {
        let s = scene(name, 200, 120);
        let (a, deep_a) = abuffer(&s);
        let counts: Vec<u32> = deep_a.counts().collect();
        for k in [1u32, 2, 4] {
            let (plain, deep_plain) = kbuffer(&s, k, false, 2);
            let (tail, deep_tail) = kbuffer(&s, k, true, 2);
            let excess: u64 = counts.iter().map(|&c| u64::from(c.saturating_sub(k))).sum();
            assert_eq!(
                tail.capture.tail_blended, excess,
                "{name} k={k}: tail count"
            );
            assert_eq!(tail.capture.dropped, 0);
            assert_eq!(plain.capture.dropped, excess);
            assert_eq!(
                deep_tail, deep_plain,
                "the tail does not change what is stored"
            );
            let mut differ = 0;
            for (p, &c) in counts.iter().enumerate() {
                let (x, y) = ((p % 200) as u32, (p / 200) as u32);
                if c <= k {
                    assert_eq!(
                        tail.image.pixel(x, y),
                        plain.image.pixel(x, y),
                        "{name} k={k}: pixel ({x}, {y}) has {c} fragments"
                    );
                } else {
                    differ += usize::from(tail.image.pixel(x, y) != plain.image.pixel(x, y));
                }
            }
            assert!(differ > 0, "{name} k={k}: the tail shows nowhere");
            // Blending the tail is closer to the A-buffer than dropping it.
            let (e_tail, e_plain) = (
                rmse(&tail.image, &a.image).unwrap(),
                rmse(&plain.image, &a.image).unwrap(),
            );
            assert!(
                e_tail < e_plain,
                "{name} k={k}: tail {e_tail} vs plain {e_plain}"
            );
            // Separate memory, reported: 20 bytes a pixel.
            assert_eq!(tail.memory_bytes - plain.memory_bytes, 200 * 120 * 20);
        }
    }
}

#[test]
fn tail_blend_does_not_depend_on_triangle_order_or_threads() {
    let s = scene("spheres", 160, 90);
    let (one, _) = kbuffer(&s, 2, true, 1);
    let (two, _) = kbuffer(&s, 2, true, 2);
    let (shuffled, _) = kbuffer(&scrambled(&s, 11), 2, true, 2);
    assert_eq!(one.image, two.image);
    assert_eq!(one.image, shuffled.image);
}

// ----- variable k -------------------------------------------------------------------------------

fn budgets(total: u64) -> Vec<Budget> {
    vec![
        Budget::SceneShare(0.10),
        Budget::SceneShare(0.25),
        Budget::SceneShare(0.50),
        Budget::SceneShare(0.75),
        Budget::SceneShare(1.00),
        Budget::Fragments(1_000),
        Budget::Fragments(total / 3 + 7),
        Budget::Fragments(total + 100),
        Budget::PerPixel(0.5),
        Budget::Bytes(120_000),
    ]
}

#[test]
fn vkbuffer_honours_its_budget() {
    for name in ["slabs", "spheres", "mixed"] {
        let s = scene(name, 160, 90);
        let (a, deep_a) = abuffer(&s);
        let total = a.capture.fragments_stored;
        let counts: Vec<u32> = deep_a.counts().collect();
        let covered = counts.iter().filter(|&&c| c > 0).count() as u64;
        for budget in budgets(total) {
            let m = budget.fragments(160 * 90, total);
            for k_from in [
                KFrom::Importance,
                KFrom::Optimal,
                KFrom::Analytic,
                KFrom::Learned,
            ] {
                let what = format!("{name} {budget:?} {k_from:?}");
                let (r, deep, v) = vkbuffer(&s, budget, k_from, 2);
                let k = v.k_map();
                let sum: u64 = k.iter().map(|&x| u64::from(x)).sum();
                assert_eq!(sum, m.min(total), "{what}: Σk");
                assert_eq!(v.allocation().sum, sum, "{what}");
                assert_eq!((v.allocation().budget, v.allocation().total), (m, total));
                assert_eq!(v.counts(), &counts[..], "{what}: counting pass");
                for (p, (&k, &c)) in k.iter().zip(&counts).enumerate() {
                    assert!(k <= c, "{what}: pixel {p} k {k} > count {c}");
                    if m >= covered && c > 0 {
                        assert!(k >= 1, "{what}: covered pixel {p} got nothing");
                    }
                }
                // What is kept is exactly the k(p) nearest of the A-buffer's fragments.
                let want = truncated(&deep_a, |p| k[p]);
                assert_eq!(deep, want, "{what}: not the k(p) nearest");
                assert_eq!(r.image, want.resolve(s.background), "{what}");
                assert!(deep.fragment_count() as u64 <= m, "{what}: stored above M");
                assert_eq!(v.regions().lost(), total - sum, "{what}: drops counted");
                // Both sources keep Σk fragments and count the rest as dropped.
                assert_eq!(r.capture.fragments_stored, sum, "{what}");
                assert_eq!(r.capture.dropped, total - sum, "{what}");
                match k_from {
                    KFrom::Importance => {
                        assert_eq!(r.capture.fragments_rasterized, 2 * total);
                        // Importance is 0 exactly on uncovered pixels (default parameters).
                        for (&i, &c) in v.importance_map().iter().zip(&counts) {
                            assert_eq!(i == 0.0, c == 0, "{what}");
                        }
                    }
                    KFrom::Analytic | KFrom::Learned => {
                        assert_eq!(r.capture.fragments_rasterized, 2 * total);
                        // Nothing to choose where a pixel holds one fragment or none.
                        for (&i, &c) in v.importance_map().iter().zip(&counts) {
                            assert!(i >= 0.0, "{what}");
                            if c <= 1 {
                                assert_eq!(i, 0.0, "{what}");
                            }
                        }
                    }
                    KFrom::Optimal => {
                        // The oracle's label: k(p) / N.
                        for (&i, &k) in v.importance_map().iter().zip(k) {
                            assert_eq!(i, k as f32 / total as f32, "{what}: label k/N");
                        }
                        // The exported oracle gives the same k.
                        assert_eq!(optimal_k(&deep_a, s.background, m), k, "{what}");
                    }
                }
                if m >= total {
                    assert_eq!(r.image, a.image, "{what}: full budget is the A-buffer");
                    assert_eq!(k, &counts[..], "{what}");
                }
            }
        }
    }
}

#[test]
fn vkbuffer_passes_are_timed_under_the_seed_names() {
    let s = scene("spheres", 96, 64);
    let (r, _, _) = vkbuffer(&s, Budget::SceneShare(0.5), KFrom::Importance, 2);
    for pass in [
        "capture.count",
        "capture.importance",
        "capture.k",
        "capture.prefix_sum",
        "capture.capture",
        "resolve",
    ] {
        assert!(r.timings.get(pass).is_some(), "missing {pass}");
    }
    let (r, _, _) = vkbuffer(&s, Budget::SceneShare(0.5), KFrom::Optimal, 2);
    for pass in [
        "capture.count",
        "capture.prefix_sum",
        "capture.capture",
        "capture.sort",
        "capture.k",
    ] {
        assert!(r.timings.get(pass).is_some(), "missing {pass}");
    }
}

#[test]
fn optimal_k_never_does_worse_than_importance_maps() {
    for name in ["slabs", "spheres", "mixed"] {
        let s = scene(name, 200, 120);
        let (a, _) = abuffer(&s);
        for share in [0.25, 0.5, 0.75] {
            let budget = Budget::SceneShare(share);
            let (imp, _, vi) = vkbuffer(&s, budget, KFrom::Importance, 2);
            let (opt, _, vo) = vkbuffer(&s, budget, KFrom::Optimal, 2);
            assert_eq!(vi.allocation().sum, vo.allocation().sum, "same memory");
            let (e_imp, e_opt) = (
                rmse(&imp.image, &a.image).unwrap(),
                rmse(&opt.image, &a.image).unwrap(),
            );
            assert!(
                e_opt <= e_imp,
                "{name} {share}: Optimal-K RMSE {e_opt} > importance maps {e_imp}"
            );
        }
    }
}

#[test]
fn budget_below_the_covered_pixels_keeps_one_fragment_on_the_most_important() {
    let s = scene("spheres", 160, 90);
    let (_, deep_a) = abuffer(&s);
    let counts: Vec<u32> = deep_a.counts().collect();
    let covered = counts.iter().filter(|&&c| c > 0).count() as u64;
    let m = covered / 2;
    for k_from in [
        KFrom::Importance,
        KFrom::Optimal,
        KFrom::Analytic,
        KFrom::Learned,
    ] {
        let (_, deep, v) = vkbuffer(&s, Budget::Fragments(m), k_from, 2);
        assert_eq!(deep.fragment_count() as u64, m);
        assert!(v.k_map().iter().all(|&k| k <= 1));
        if k_from == KFrom::Importance {
            // Every kept pixel is at least as important as every emptied covered one.
            let imp = v.importance_map();
            let kept_min = (0..counts.len())
                .filter(|&p| v.k_map()[p] == 1)
                .map(|p| imp[p])
                .fold(f32::INFINITY, f32::min);
            let dropped_max = (0..counts.len())
                .filter(|&p| counts[p] > 0 && v.k_map()[p] == 0)
                .map(|p| imp[p])
                .fold(0.0, f32::max);
            assert!(kept_min >= dropped_max);
        }
    }
}

// ----- determinism ------------------------------------------------------------------------------

#[test]
fn threads_and_triangle_order_change_nothing() {
    for name in ["spheres", "mixed"] {
        let s = scene(name, 160, 90);
        for k_from in [
            KFrom::Importance,
            KFrom::Optimal,
            KFrom::Analytic,
            KFrom::Learned,
        ] {
            let (one, deep_one, v_one) = vkbuffer(&s, Budget::SceneShare(0.4), k_from, 1);
            let runs = [
                vkbuffer(&s, Budget::SceneShare(0.4), k_from, 2),
                vkbuffer(&s, Budget::SceneShare(0.4), k_from, 8),
                vkbuffer(&scrambled(&s, 3), Budget::SceneShare(0.4), k_from, 2),
            ];
            for (i, (r, deep, v)) in runs.iter().enumerate() {
                let what = format!("{name} {k_from:?} run {i}");
                assert_eq!(r.image, one.image, "{what}");
                assert_eq!(deep, &deep_one, "{what}");
                assert_eq!(v.k_map(), v_one.k_map(), "{what}");
                assert_eq!(v.importance_map(), v_one.importance_map(), "{what}");
            }
        }
        let (one, deep_one) = kbuffer(&s, 3, false, 1);
        let (two, deep_two) = kbuffer(&scrambled(&s, 5), 3, false, 2);
        assert_eq!(
            (one.image, deep_one),
            (two.image, deep_two),
            "{name} kbuffer"
        );
    }
}

#[test]
fn methods_are_reusable_across_frames_and_sizes() {
    let mut k = KBuffer::new(&MethodOptions {
        k: 3,
        tail_blend: true,
        ..MethodOptions::default()
    });
    let mut v = VariableKBuffer::new(&MethodOptions {
        budget: Budget::SceneShare(0.5),
        ..MethodOptions::default()
    });
    for (name, w, h) in [("slabs", 160, 90), ("overlap", 64, 48), ("slabs", 160, 90)] {
        let s = scene(name, w, h);
        let fresh_k = kbuffer(&s, 3, true, 2).0.image;
        assert_eq!(render(&mut k, &s, 2).0.image, fresh_k, "{name} {w}x{h}");
        let fresh_v = vkbuffer(&s, Budget::SceneShare(0.5), KFrom::Importance, 2)
            .0
            .image;
        assert_eq!(render(&mut v, &s, 2).0.image, fresh_v, "{name} {w}x{h}");
        assert_eq!(v.k_map().len(), (w * h) as usize);
    }
    assert_eq!((k.name(), v.name()), ("kbuffer", "vkbuffer"));
}

#[test]
fn maps_render_as_heat_map_pngs() {
    let s = scene("spheres", 96, 64);
    let (_, _, v) = vkbuffer(&s, Budget::SceneShare(0.5), KFrom::Importance, 2);
    let dir = std::env::temp_dir().join(format!("strata-kbuffer-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join("importance.png");
    write_heat_map(&path, v.importance_map(), 96, 64, None).expect("write");
    let back = Rgb8Image::read_png(&path).expect("read");
    assert_eq!(back, heat_map(v.importance_map(), 96, 64, None));
    let k = k_heat_map(v.k_map(), 96, 64);
    let kmax = *v.k_map().iter().max().unwrap();
    let p = v.k_map().iter().position(|&x| x == kmax).unwrap();
    assert_eq!(k.pixel((p % 96) as u32, (p / 96) as u32), [255, 255, 255]);
    std::fs::remove_dir_all(&dir).ok();
}
