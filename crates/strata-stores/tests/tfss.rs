//! TFSS end to end: every built-in scene captured through the rasterizer gives the A-buffer's
//! DeepFrame and image for any L_num, with and without leading-zeros elimination, on one or two
//! threads; its memory is what the model of Lin 2007 predicts; leading-zeros elimination saves
//! memory where colours have leading zeros to drop.

mod common;

use common::{reference, render_exact, scene};
use strata_core::DeepFrame;
use strata_scene::Scene;
use strata_stores::tfss::model::{self, ColourTrace, Transparency};
use strata_stores::tfss::{LzBudget, Tfss};
use strata_stores::{FrameResult, Method, MethodOptions, PoolCapacity};

fn render(method: &mut dyn Method, scene: &Scene, threads: usize) -> (FrameResult, DeepFrame) {
    render_exact(method, scene, 0, threads)
}

fn abuffer(scene: &Scene) -> (FrameResult, DeepFrame) {
    reference(scene, 0)
}

fn tfss(l_num: u32, leading_zeros: bool) -> Tfss {
    Tfss::new(&MethodOptions {
        l_num,
        leading_zeros,
        ..MethodOptions::default()
    })
}

#[test]
fn tfss_equals_the_abuffer_on_every_builtin_scene() {
    for name in ["slabs", "spheres", "mixed", "overlap"] {
        let s = scene(name, 160, 90);
        let (want, want_deep) = abuffer(&s);
        for l_num in [1, 2, 3, 4, 7] {
            for lz in [false, true] {
                let mut sections = None;
                for threads in [1, 2] {
                    let mut t = tfss(l_num, lz);
                    let (r, deep) = render(&mut t, &s, threads);
                    let what = format!("{name} L {l_num} lz {lz} threads {threads}");
                    assert_eq!(r.capture.dropped, 0, "{what}");
                    assert_eq!(deep, want_deep, "{what}: DeepFrame");
                    assert_eq!(r.image, want.image, "{what}: image");
                    assert_eq!(r.depth, want.depth, "{what}: statistics");
                    let used = t.memory().sections_used;
                    assert_eq!(*sections.get_or_insert(used), used, "{what}: sections");
                }
            }
        }
    }
}

#[test]
fn plain_memory_is_the_models_tfss_store() {
    for name in ["slabs", "spheres", "mixed"] {
        let s = scene(name, 256, 144);
        let (_, deep) = abuffer(&s);
        let (d, _) = model::frame_model(&deep, Transparency::All);
        for l_num in 1..=4 {
            let mut t = tfss(l_num, false);
            let (r, _) = render(&mut t, &s, 2);
            let m = t.memory();
            assert_eq!(m.sections_used, d.sections(l_num), "{name} L {l_num}");
            assert_eq!(
                r.used_memory_bytes,
                model::tfss_store(&d, l_num).total(),
                "{name} L {l_num}"
            );
            assert_eq!(r.memory_bytes, m.allocated());
            assert!(m.allocated() >= m.used());
        }
    }
}

/// Each pixel's colours in the store's own (arrival) order.
fn store_trace(t: &Tfss, pixels: usize) -> ColourTrace {
    let runs: Vec<Vec<strata_core::Rgba8>> = (0..pixels)
        .map(|p| t.fragments(p).iter().map(|f| f.color).collect())
        .collect();
    ColourTrace::from_runs(runs.iter().map(Vec::as_slice))
}

#[test]
fn packed_sections_are_the_models_packing_at_every_budget() {
    let s = scene("spheres", 200, 112);
    let (_, want_deep) = abuffer(&s);
    for l_num in [1, 3] {
        for b in [0, 4, 6, 8] {
            let mut t = tfss(l_num, true).with_lz_budget(LzBudget::Bits(b));
            let (r, deep) = render(&mut t, &s, 2);
            assert_eq!(deep, want_deep);
            assert_eq!(t.refits(), 0, "a fixed budget is not refitted");
            let trace = store_trace(&t, 200 * 112);
            let m = t.memory();
            assert_eq!(m.rgb_bits, Some(b));
            assert_eq!(
                m.sections_used,
                model::packed_sections(&trace, l_num, b, false),
                "L {l_num} b {b}"
            );
            assert_eq!(r.used_memory_bytes, m.used());
        }
    }
}

/// Every object of `scene` in the same colour, as dark as `scale` makes it.
fn dark(mut s: Scene, scale: f32) -> Scene {
    for o in &mut s.objects {
        let c = o.material.color;
        o.material.color = [c[0] * scale, c[1] * scale, c[2] * scale, c[3]];
    }
    s
}

#[test]
fn leading_zeros_save_memory_on_dark_frames_and_never_cost_t_buffer_space() {
    // Dark colours (components below 64) keep at most six bits: the auto budget refits the
    // section and the whole store, Length table included, takes less memory than without.
    let s = dark(scene("spheres", 200, 112), 0.2);
    let (want, want_deep) = abuffer(&s);
    for l_num in [2, 3, 4] {
        let mut plain = tfss(l_num, false);
        let (p, _) = render(&mut plain, &s, 2);
        let mut packed = tfss(l_num, true);
        let (r, deep) = render(&mut packed, &s, 2);
        assert_eq!(deep, want_deep);
        assert_eq!(r.image, want.image);
        assert_eq!(packed.refits(), 1, "L {l_num}: refitted once");
        let m = packed.memory();
        assert!(m.rgb_bits < Some(8));
        assert!(
            r.used_memory_bytes < p.used_memory_bytes,
            "L {l_num}: {} with LZ, {} without",
            r.used_memory_bytes,
            p.used_memory_bytes
        );
        // The refit picked the cheapest budget for this frame.
        let trace = store_trace(&packed, 200 * 112);
        let cost = |b: u32| {
            let bits = 64 * u64::from(l_num) + u64::from(model::colour_area_bits(l_num, b));
            model::packed_sections(&trace, l_num, b, false) * (bits + 4 * u64::from(l_num) + 32)
        };
        let best = (0..=8).map(cost).min().unwrap();
        assert_eq!(cost(m.rgb_bits.unwrap()), best);
    }
    // On the bright built-in scenes colours keep 7–8 bits: the T-buffer and NSA never grow with
    // leading-zeros elimination, and the Length table is its cost.
    for name in ["slabs", "spheres", "mixed"] {
        let s = scene(name, 200, 112);
        for l_num in [1, 2, 3, 4] {
            let mut plain = tfss(l_num, false);
            render(&mut plain, &s, 2);
            let mut packed = tfss(l_num, true);
            render(&mut packed, &s, 2);
            let (p, m) = (plain.memory(), packed.memory());
            assert!(
                m.t_buffer_used + m.nsa_used <= p.t_buffer_used + p.nsa_used,
                "{name} L {l_num}"
            );
            assert!(m.used() <= p.used() + m.length_used, "{name} L {l_num}");
        }
    }
}

#[test]
fn auto_pool_grows_and_captures_again() {
    // Close to the nested spheres: ~7 fragments a pixel, more than the initial 2 per pixel.
    let mut s = scene("spheres", 160, 90);
    s.camera.eye = glam::Vec3::new(0.0, 0.1, 0.75);
    let (want, want_deep) = abuffer(&s);
    for lz in [false, true] {
        let mut t = tfss(2, lz);
        let (r, deep) = render(&mut t, &s, 2);
        assert!(r.capture.regrows >= 1, "lz {lz}: expected a regrow");
        assert_eq!(r.capture.dropped, 0);
        assert_eq!(deep, want_deep);
        assert_eq!(r.image, want.image);
    }
    // A fixed pool drops and counts.
    let mut t = Tfss::new(&MethodOptions {
        l_num: 2,
        pool: PoolCapacity::PerPixel(1.0),
        ..MethodOptions::default()
    });
    let (r, deep) = render(&mut t, &s, 2);
    assert!(r.capture.dropped > 0);
    assert_eq!(
        r.capture.fragments_stored + r.capture.dropped,
        r.capture.fragments_rasterized
    );
    assert_eq!(deep.fragment_count() as u64, r.capture.fragments_stored);
}

#[test]
fn method_is_reusable_across_frames_and_sizes() {
    let mut t = tfss(3, true);
    for (name, w, h) in [("slabs", 160, 90), ("overlap", 64, 48), ("slabs", 160, 90)] {
        let s = scene(name, w, h);
        let (want, _) = abuffer(&s);
        let (r, _) = render(&mut t, &s, 2);
        assert_eq!(r.image, want.image, "{name} {w}x{h}");
    }
}
