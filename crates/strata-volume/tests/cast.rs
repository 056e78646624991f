//! The ray caster against the analytic slab, and the FC's stencil re-cast against the single
//! renderer.

mod common;

use common::{UNIT_BOX, down_z, ramp, uniform, well};

use glam::{Mat4, Vec3};
use strata_volume::cast::{CastParams, Caster};
use strata_volume::geometry::{Shape, Solid, well_path};
use strata_volume::stencil::{Renderer, VolumeScene};
use strata_volume::transfer::StepTable;
use strata_volume::volume::Volume;

fn transmittance(alpha: f32, step: f32, t_end: f32) -> (f32, u32) {
    let volume = Volume::constant([4, 4, 4], 0.7);
    let tf = uniform(alpha);
    let params = CastParams {
        step,
        termination: 0.0,
    };
    let caster = Caster {
        volume: &volume,
        placement: UNIT_BOX,
        table: StepTable::new(&tf, step),
        params,
    };
    let r = caster.cast(&down_z(), t_end);
    (r.transmittance, r.samples)
}

#[test]
fn a_constant_slab_transmits_exp_minus_sigma_d() {
    let alpha = 0.6f32;
    let sigma = -(1.0 - alpha).ln();
    // The ray crosses the whole unit slab (d = 1), then only half of it (an opaque surface at
    // the slab's middle, d = 0.5). Steps divide both lengths, so the sampled length is exact.
    for (t_end, d) in [(f32::INFINITY, 1.0f32), (3.0, 0.5)] {
        let (t, n) = transmittance(alpha, 1.0 / 64.0, t_end);
        assert_eq!(n, (64.0 * d) as u32);
        let want = (-sigma * d).exp();
        assert!((t - want).abs() < 1e-4, "d {d}: {t} against {want}");
    }
    // A step that does not divide the slab: the sampled length is within one step of d, so
    // |ln T + σ·d| ≤ σ·step.
    let step = 0.03;
    let (t, _) = transmittance(alpha, step, f32::INFINITY);
    assert!((t.ln() + sigma).abs() <= sigma * step + 1e-4, "{t}");
}

#[test]
fn opacity_correction_makes_the_result_independent_of_the_step() {
    let (coarse, _) = transmittance(0.8, 1.0 / 16.0, f32::INFINITY);
    let (fine, _) = transmittance(0.8, 1.0 / 256.0, f32::INFINITY);
    assert!((coarse - fine).abs() < 1e-4, "{coarse} against {fine}");
    assert!((coarse - 0.2).abs() < 1e-4);
}

#[test]
fn early_termination_stops_once_the_ray_is_opaque() {
    let volume = Volume::constant([4, 4, 4], 0.5);
    let tf = uniform(0.9999);
    let params = CastParams {
        step: 1.0 / 128.0,
        termination: 0.01,
    };
    let caster = Caster {
        volume: &volume,
        placement: UNIT_BOX,
        table: StepTable::new(&tf, params.step),
        params,
    };
    let r = caster.cast(&down_z(), f32::INFINITY);
    assert!(r.samples < 80, "{} samples", r.samples);
    assert!(r.transmittance < 0.01);
    // One sample fewer would still be above the threshold.
    let a = 1.0 - 0.0001f32.powf(params.step);
    assert!((1.0 - a).powi(r.samples as i32 - 1) >= 0.01 - 1e-4);
}

#[test]
fn a_shortened_ray_takes_exactly_the_first_samples_of_the_full_ray() {
    let volume = Volume::procedural_head(16);
    let tf = ramp();
    let params = CastParams::for_samples(&UNIT_BOX, 200);
    let caster = Caster {
        volume: &volume,
        placement: UNIT_BOX,
        table: StepTable::new(&tf, params.step),
        params,
    };
    let ray = down_z();
    let full = caster.cast(&ray, f32::INFINITY);
    let short = caster.cast(&ray, 3.0);
    assert!(short.samples > 0 && short.samples < full.samples);
    // The shortened ray, continued by hand with the same positions, reaches the full result:
    // the same samples in the same order.
    let mut t = short.transmittance;
    let mut c = short.color;
    let t_in = 2.5;
    for k in short.samples..full.samples {
        let p = ray.at(t_in + (k as f32 + 0.5) * params.step);
        let s = caster.table.lookup(volume.sample(p - UNIT_BOX.min));
        c = [0, 1, 2].map(|i| c[i] + t * s[i]);
        t *= 1.0 - s[3];
    }
    assert_eq!(t.to_bits(), full.transmittance.to_bits());
    assert_eq!(c.map(f32::to_bits), full.color.map(f32::to_bits));
}

fn scene() -> VolumeScene {
    let view_proj = Mat4::perspective_rh_gl(0.9, 64.0 / 48.0, 0.1, 20.0)
        * Mat4::look_at_rh(Vec3::new(0.6, 0.4, 2.2), Vec3::ZERO, Vec3::Y);
    VolumeScene {
        volume: Volume::procedural_head(24),
        transfer: ramp(),
        placement: UNIT_BOX,
        width: 64,
        height: 48,
        view_proj,
        statics: vec![Solid {
            shape: Shape::Cuboid {
                min: Vec3::new(-1.0, -0.7, -1.0),
                max: Vec3::new(1.0, -0.55, 1.0),
            },
            color: [0.5, 0.5, 0.45],
        }],
        static_glass: vec![],
        interactive_glass: vec![],
        interactive: well(),
    }
}

#[test]
fn the_stencil_recast_equals_the_single_renderer_bit_for_bit() {
    let scene = scene();
    let r = Renderer::new(&scene, CastParams::for_samples(&scene.placement, 128));
    let sc = r.slow();
    let fc = r.fast(&sc);
    let single = r.single();
    let pixels = (scene.width * scene.height) as usize;
    assert!(
        fc.recast > 0 && fc.recast < pixels / 4,
        "{} re-cast",
        fc.recast
    );
    assert_eq!(fc.stencil.iter().filter(|&&s| s).count(), fc.recast);
    for (i, (got, want)) in fc.image.iter().zip(&single).enumerate() {
        assert_eq!(
            got.map(f32::to_bits),
            want.map(f32::to_bits),
            "pixel {i} (stencil {})",
            fc.stencil[i]
        );
    }
    // The SC frame alone misses the path: the stencil pixels are the ones that changed.
    let changed = (0..pixels).filter(|&i| sc.image[i] != single[i]).count();
    assert!(changed > 0);
    assert!((0..pixels).all(|i| fc.stencil[i] || sc.image[i] == single[i]));
    // The re-cast rays stop at the path, so they take fewer samples than the full cast.
    assert!(fc.samples < sc.samples);
}

#[test]
fn the_stencil_marks_only_pixels_where_the_path_is_in_front() {
    let mut scene = scene();
    // Move the path wholly behind the floor box as seen from above: no pixel is visible.
    scene.view_proj = Mat4::perspective_rh_gl(0.9, 64.0 / 48.0, 0.1, 20.0)
        * Mat4::look_at_rh(Vec3::new(0.0, 4.0, 0.01), Vec3::ZERO, Vec3::Y);
    scene.interactive = well_path(
        &[Vec3::new(-0.3, -0.9, 0.0), Vec3::new(0.3, -0.9, 0.0)],
        0.05,
        [1.0, 0.0, 0.0],
    );
    let r = Renderer::new(&scene, CastParams::for_samples(&scene.placement, 64));
    let sc = r.slow();
    let fc = r.fast(&sc);
    assert_eq!(fc.recast, 0);
    assert_eq!(fc.image, sc.image);
}
