//! Translucent geometry inside the volume: the walker that samples the volume between a pixel's
//! sorted fragments, against the analytic slab and against the opaque-only cast, and the FC's
//! stencil re-cast with translucent objects on both clients against the single renderer.

mod common;

use common::{UNIT_BOX, down_z, glass_tube, ramp, uniform, well};

use glam::{Mat4, Vec3};
use strata_volume::cast::{CastParams, Caster, camera_rays, over_geometry};
use strata_volume::fragments::{FragmentLayer, RayFragment};
use strata_volume::geometry::{BACKGROUND, Glass, Shape, Solid, fragment_layer, trace_layer};
use strata_volume::stencil::{Interactive, Renderer, VolumeScene};
use strata_volume::transfer::StepTable;
use strata_volume::volume::Volume;

fn frag(t: f32, color: [f32; 3], alpha: f32) -> RayFragment {
    RayFragment { t, color, alpha }
}

/// Walks `run` (given in any order) through a constant white medium of unit opacity
/// `medium_alpha`, 64 steps across the unit box; returns the pixel and the samples taken.
fn walk(medium_alpha: f32, run: &[RayFragment]) -> ([f32; 3], u32) {
    let volume = Volume::constant([4, 4, 4], 0.5);
    let step = 1.0 / 64.0;
    let caster = Caster {
        volume: &volume,
        placement: UNIT_BOX,
        table: StepTable::new(&uniform(medium_alpha), step),
        params: CastParams {
            step,
            termination: 0.0,
        },
    };
    let layer = FragmentLayer::from_lists(vec![run.to_vec()]);
    let r = caster.cast_through(&down_z(), layer.run(0));
    (over_geometry(&r, BACKGROUND), r.samples)
}

fn close(got: [f32; 3], want: [f32; 3]) {
    for c in 0..3 {
        assert!((got[c] - want[c]).abs() < 1e-4, "{got:?} against {want:?}");
    }
}

#[test]
fn a_translucent_plane_in_a_constant_slab_composites_between_the_two_halves() {
    let medium = 0.6f32;
    let sigma = -(1.0 - medium).ln();
    let half = (-sigma * 0.5).exp();
    let (alpha, color) = (0.3f32, [0.9f32, 0.2, 0.1]);
    let (got, samples) = walk(medium, &[frag(3.0, color, alpha)]);
    assert_eq!(samples, 64, "the plane does not move the grid");
    // Front half of white medium, the plane behind it, the back half behind both, black beyond.
    let want = color.map(|c| (1.0 - half) + half * alpha * c + half * (1.0 - alpha) * (1.0 - half));
    close(got, want);
    // What is left for the background: exp(−σ d1)·(1−α)·exp(−σ d2).
    let volume_only = walk(medium, &[]).0;
    close(volume_only, [1.0 - half * half; 3]);
    let behind = walk(medium, &[frag(3.0, color, alpha), frag(3.6, [1.0; 3], 1.0)]).0;
    let t_left = half * (1.0 - alpha) * half;
    close(behind, want.map(|w| w + t_left));
}

#[test]
fn the_first_opaque_fragment_ends_the_ray() {
    let medium = 0.5f32;
    let quarter = (-(-(1.0 - medium).ln()) * 0.25).exp();
    let (a1, c1) = (0.4f32, [0.2f32, 0.6, 0.9]);
    let g = [0.3f32, 0.3, 0.8];
    let run = [
        frag(3.25, [1.0, 0.0, 0.0], 0.5),
        frag(3.0, g, 1.0),
        frag(2.75, c1, a1),
    ];
    let (got, samples) = walk(medium, &run);
    assert_eq!(samples, 32, "samples stop at the opaque fragment");
    let t1 = quarter * (1.0 - a1);
    let want = [0, 1, 2].map(|c| {
        (1.0 - quarter) + quarter * a1 * c1[c] + t1 * (1.0 - quarter) + t1 * quarter * g[c]
    });
    close(got, want);
}

#[test]
fn fragments_given_in_any_order_give_the_same_pixel_bit_for_bit() {
    let volume = Volume::procedural_head(16);
    let params = CastParams::for_samples(&UNIT_BOX, 150);
    let caster = Caster {
        volume: &volume,
        placement: UNIT_BOX,
        table: StepTable::new(&uniform(0.7), params.step),
        params,
    };
    let ray = down_z();
    let mut run = vec![
        frag(2.9, [0.1, 0.9, 0.3], 0.35),
        frag(3.1, [0.8, 0.8, 0.1], 0.5),
        frag(2.6, [0.5, 0.1, 0.7], 0.2),
        frag(3.1, [0.2, 0.3, 0.4], 0.5),
        frag(3.3, [1.0, 1.0, 1.0], 1.0),
        frag(3.4, [0.0, 1.0, 0.0], 0.9),
    ];
    let reference = {
        let layer = FragmentLayer::from_lists(vec![run.clone()]);
        over_geometry(&caster.cast_through(&ray, layer.run(0)), BACKGROUND)
    };
    for turn in 0..run.len() {
        run.rotate_left(1);
        if turn % 2 == 1 {
            run.reverse();
        }
        let pairs: Vec<(u32, RayFragment)> = run.iter().map(|&f| (0, f)).collect();
        let layer = FragmentLayer::from_pairs(1, &pairs);
        let got = over_geometry(&caster.cast_through(&ray, layer.run(0)), BACKGROUND);
        assert_eq!(
            got.map(f32::to_bits),
            reference.map(f32::to_bits),
            "{run:?}"
        );
    }
    // The fragments matter: without the translucent ones the pixel differs.
    let opaque = FragmentLayer::from_lists(vec![vec![frag(3.3, [1.0; 3], 1.0)]]);
    let without = over_geometry(&caster.cast_through(&ray, opaque.run(0)), BACKGROUND);
    assert_ne!(without, reference);
}

fn floor() -> Solid {
    Solid {
        shape: Shape::Cuboid {
            min: Vec3::new(-1.0, -0.7, -1.0),
            max: Vec3::new(1.0, -0.55, 1.0),
        },
        color: [0.5, 0.5, 0.45],
    }
}

fn view_proj() -> Mat4 {
    Mat4::perspective_rh_gl(0.9, 64.0 / 48.0, 0.1, 20.0)
        * Mat4::look_at_rh(Vec3::new(0.6, 0.4, 2.2), Vec3::ZERO, Vec3::Y)
}

#[test]
fn opaque_fragments_alone_give_exactly_the_opaque_geometry_cast() {
    let volume = Volume::procedural_head(24);
    let params = CastParams::for_samples(&UNIT_BOX, 128);
    let caster = Caster {
        volume: &volume,
        placement: UNIT_BOX,
        table: StepTable::new(&ramp(), params.step),
        params,
    };
    let rays = camera_rays(view_proj(), 64, 48);
    let solids: Vec<Solid> = std::iter::once(floor()).chain(well()).collect();
    let depth_buffer = trace_layer(&rays, &solids);
    let before = caster.cast_image(&rays, &depth_buffer.depth, &depth_buffer.color);
    let layer = fragment_layer(&rays, &solids, &[]);
    let after = caster.cast_layer(&rays, &layer, BACKGROUND);
    assert!(layer.fragment_count() > 0);
    assert_eq!(after.samples, before.samples);
    for (i, (a, b)) in after.pixels.iter().zip(&before.pixels).enumerate() {
        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "pixel {i}");
    }
}

fn glass_scene() -> VolumeScene {
    VolumeScene {
        volume: Volume::procedural_head(24),
        transfer: ramp(),
        placement: UNIT_BOX,
        width: 64,
        height: 48,
        view_proj: view_proj(),
        statics: vec![floor()],
        // A static glass sheet across the volume's middle.
        static_glass: vec![Glass {
            shape: Shape::Cuboid {
                min: Vec3::new(-0.7, -0.5, -0.02),
                max: Vec3::new(0.7, 0.6, 0.02),
            },
            color: [0.3, 0.7, 0.9],
            alpha: 0.3,
        }],
        interactive: well(),
        // An interactive translucent tube beside the path, crossing the sheet.
        interactive_glass: vec![glass_tube()],
    }
}

#[test]
fn the_stencil_recast_with_translucent_objects_equals_the_single_renderer_bit_for_bit() {
    let scene = glass_scene();
    let r = Renderer::new(&scene, CastParams::for_samples(&scene.placement, 128));
    let sc = r.slow();
    let pixels = (scene.width * scene.height) as usize;
    for offset in [0.0f32, 0.2] {
        let moved: Vec<Glass> = scene
            .interactive_glass
            .iter()
            .map(|g| match g.shape {
                Shape::Tube { a, b, radius } => Glass {
                    shape: Shape::Tube {
                        a: a + Vec3::X * offset,
                        b: b + Vec3::X * offset,
                        radius,
                    },
                    ..*g
                },
                Shape::Cuboid { .. } => *g,
            })
            .collect();
        let objects = Interactive {
            solids: &scene.interactive,
            glass: &moved,
        };
        let fc = r.fast_with(&sc, objects);
        let single = r.single_with(objects);
        assert!(
            fc.recast > 0 && fc.recast < pixels / 2,
            "{} re-cast",
            fc.recast
        );
        for (i, (got, want)) in fc.image.iter().zip(&single).enumerate() {
            assert_eq!(
                got.map(f32::to_bits),
                want.map(f32::to_bits),
                "offset {offset}, pixel {i} (stencil {})",
                fc.stencil[i]
            );
        }
        // Outside the stencil the SC's pixel is already the single renderer's.
        assert!((0..pixels).all(|i| fc.stencil[i] || sc.image[i] == single[i]));
        // The translucent tube shows: the frame differs from one with the path alone.
        let path_only = r.single_with(Interactive {
            solids: &scene.interactive,
            glass: &[],
        });
        let tinted = (0..pixels).filter(|&i| single[i] != path_only[i]).count();
        assert!(tinted > 20, "{tinted} pixels show the tube");
    }
}

#[test]
fn an_interactive_object_behind_static_glass_is_recast_and_one_behind_the_floor_is_not() {
    let scene = glass_scene();
    let r = Renderer::new(&scene, CastParams::for_samples(&scene.placement, 64));
    let sc = r.slow();
    // The sheet's own fragments are translucent: behind them, the SC has no opaque surface in
    // the way, so an FC object seen through the sheet is in the stencil.
    let through_sheet = (0..sc.fragments.pixels())
        .filter(|&p| sc.fragments.run(p).iter().any(|f| f.alpha < 1.0))
        .count();
    assert!(through_sheet > 0);
    let fc_layer = r.fragments_of(r.interactive());
    let fc = r.fast_from(&sc, &fc_layer);
    let behind_glass = (0..fc.stencil.len())
        .filter(|&p| {
            fc.stencil[p]
                && sc.fragments.nearest_t(p) < fc_layer.nearest_t(p)
                && sc.fragments.opaque_t(p) > fc_layer.nearest_t(p)
        })
        .count();
    assert!(
        behind_glass > 0,
        "no FC pixel seen through the static sheet"
    );
    // FC fragments strictly behind the SC's opaque fragment never enter the stencil.
    for p in 0..fc.stencil.len() {
        if fc_layer.nearest_t(p) > sc.fragments.opaque_t(p) {
            assert!(!fc.stencil[p], "pixel {p}");
        }
    }
}
