//! Fragments from strata's rasterizer: window depths made into ray distances that agree with the
//! analytic surfaces, and the FC's stencil re-cast over rasterized fragments — a translucent static
//! sheet, a translucent interactive tube and the opaque path — against the single renderer.

mod common;

use common::{glass_tube, ramp, well};

use glam::{Mat4, Vec3};
use strata_volume::cast::{CastParams, VolumeBox};
use strata_volume::geometry::{Glass, Shape, Solid, fragment_layer};
use strata_volume::raster::{FragmentRaster, meshes};
use strata_volume::stencil::{Renderer, VolumeScene};
use strata_volume::volume::Volume;

const W: u32 = 64;
const H: u32 = 48;

fn view() -> Mat4 {
    Mat4::look_at_rh(Vec3::new(0.6, 0.4, 2.2), Vec3::ZERO, Vec3::Y)
}

fn projection() -> Mat4 {
    Mat4::perspective_rh_gl(0.9, W as f32 / H as f32, 0.1, 20.0)
}

fn sheet() -> Glass {
    Glass {
        shape: Shape::Cuboid {
            min: Vec3::new(-0.7, -0.5, -0.02),
            max: Vec3::new(0.7, 0.6, 0.02),
        },
        color: [0.3, 0.7, 0.9],
        alpha: 0.3,
    }
}

fn scene() -> VolumeScene {
    VolumeScene {
        volume: Volume::procedural_head(24),
        transfer: ramp(),
        placement: VolumeBox {
            min: Vec3::splat(-0.5),
            max: Vec3::splat(0.5),
        },
        width: W,
        height: H,
        view_proj: projection() * view(),
        statics: vec![Solid {
            shape: Shape::Cuboid {
                min: Vec3::new(-1.0, -0.7, -1.0),
                max: Vec3::new(1.0, -0.55, 1.0),
            },
            color: [0.5, 0.5, 0.45],
        }],
        static_glass: vec![sheet()],
        interactive: well(),
        interactive_glass: vec![glass_tube()],
    }
}

#[test]
fn rasterized_depths_become_the_distances_of_the_analytic_surfaces() {
    let scene = scene();
    let r = Renderer::new(&scene, CastParams::for_samples(&scene.placement, 64));
    let mut raster = FragmentRaster::new(W, H, view(), projection());
    let rasterized = raster
        .layer(r.rays(), &meshes(&[], &[sheet()]))
        .expect("rasterized");
    let analytic = fragment_layer(r.rays(), &[], &[sheet()]);
    let (mut both, mut pairs, mut close) = (0, 0, 0);
    for p in 0..rasterized.pixels() {
        let (a, b) = (rasterized.run(p), analytic.run(p));
        if a.len() == 2 && b.len() == 2 {
            both += 1;
            for (x, y) in a.iter().zip(b) {
                // At the rim a pixel may see a side face in one and a broad face in the other:
                // never farther apart than the sheet is thick.
                assert!(
                    (x.t - y.t).abs() < 0.04,
                    "pixel {p}: {} against {}",
                    x.t,
                    y.t
                );
                assert!((x.alpha - 0.3).abs() < 1.0 / 255.0);
                pairs += 1;
                close += usize::from((x.t - y.t).abs() < 1e-4);
            }
        }
    }
    assert!(close * 100 >= pairs * 98, "{close} of {pairs} within 1e-4");
    // The sheet covers a good part of the image, two surfaces in nearly every covered pixel.
    let covered = (0..analytic.pixels())
        .filter(|&p| !analytic.run(p).is_empty())
        .count();
    assert!(covered > 200, "{covered}");
    assert!(both * 10 >= covered * 9, "{both} of {covered}");
}

#[test]
fn the_stencil_recast_over_rasterized_fragments_equals_the_single_renderer_bit_for_bit() {
    let scene = scene();
    let r = Renderer::new(&scene, CastParams::for_samples(&scene.placement, 128));
    let mut raster = FragmentRaster::new(W, H, view(), projection());
    let statics = meshes(&scene.statics, &scene.static_glass);
    let interactive = meshes(&scene.interactive, &scene.interactive_glass);
    let sc = r.slow_from(raster.layer(r.rays(), &statics).expect("SC"));
    let fc_layer = raster.layer(r.rays(), &interactive).expect("FC");
    let fc = r.fast_from(&sc, &fc_layer);
    let all: Vec<_> = statics.iter().chain(&interactive).cloned().collect();
    let single = r.single_from(&raster.layer(r.rays(), &all).expect("single"));
    let pixels = (W * H) as usize;
    assert!(
        fc.recast > 0 && fc.recast < pixels / 2,
        "{} re-cast",
        fc.recast
    );
    for (i, (got, want)) in fc.image.iter().zip(&single).enumerate() {
        assert_eq!(
            got.map(f32::to_bits),
            want.map(f32::to_bits),
            "pixel {i} (stencil {})",
            fc.stencil[i]
        );
    }
    // Translucent fragments on both sides: the sheet in the SC's runs, the tube in the FC's.
    assert!(sc.fragments.fragment_count() > 0);
    let translucent = |l: &strata_volume::fragments::FragmentLayer| {
        (0..l.pixels())
            .filter(|&p| l.run(p).iter().any(|f| f.alpha < 1.0))
            .count()
    };
    assert!(translucent(&sc.fragments) > 100);
    assert!(translucent(&fc_layer) > 20);
    // The SC frame alone misses the interactive objects.
    assert!((0..pixels).any(|i| sc.image[i] != single[i]));
}

#[test]
fn the_footprint_export_keeps_every_fragment_the_whole_frame_export_does() {
    let scene = scene();
    let r = Renderer::new(&scene, CastParams::for_samples(&scene.placement, 64));
    let mut raster = FragmentRaster::new(W, H, view(), projection());
    let objects = meshes(&scene.interactive, &scene.interactive_glass);
    let windowed = raster.layer(r.rays(), &objects).expect("footprint");
    // A box behind the eye has no projected footprint, so the whole frame is exported; it adds
    // no fragment of its own.
    let behind = Solid {
        shape: Shape::Cuboid {
            min: Vec3::new(0.5, 0.3, 3.0),
            max: Vec3::new(0.7, 0.5, 3.2),
        },
        color: [1.0; 3],
    };
    let mut with_behind = objects.clone();
    with_behind.extend(meshes(&[behind], &[]));
    let whole = raster.layer(r.rays(), &with_behind).expect("whole frame");
    assert!(windowed.fragment_count() > 100);
    assert_eq!(windowed, whole);
}
