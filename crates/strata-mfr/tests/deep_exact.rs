//! Deep composition with predictive migration equals the single renderer in every FC frame, under
//! any timing; naive migration leaves holes after a release.

use proptest::prelude::*;
use strata_core::DeepFrame;
use strata_mfr::client::Client;
use strata_mfr::trace::{GrabParams, grab};
use strata_mfr::{Composition, FcFrame, Migration, VirtualClock, run_virtual};
use strata_scene::{Scene, SearchPath, open_scene};

const SIZE: (u32, u32) = (48, 36);

fn mixed() -> Scene {
    open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new())).expect("built-in scene")
}

/// The whole scene rendered at once, at the frame's snapshot, through the view it composed with.
fn reference(scene: &Scene, client: &mut Client, f: &FcFrame) -> DeepFrame {
    let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    client
        .render(scene, &f.snapshot, &view, &all)
        .expect("reference renders")
}

/// FC frames enough to see the whole trace and the SC catch up after it.
fn frames_for(duration_ms: f64, clock: &VirtualClock) -> u64 {
    ((duration_ms + 3.0 * clock.sc_ms + clock.transfer_ms) / clock.fc_ms).ceil() as u64 + 1
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 10, ..ProptestConfig::default() })]

    /// Any object of the translucent, interpenetrating scene grabbed with any lead (0 included:
    /// grabbed and dragged at once), held and dragged any time, at SC:FC ratios from 1:2 to 1:60
    /// and any transfer delay: every FC frame's DeepFrame equals the single renderer's.
    #[test]
    fn deep_predictive_equals_the_single_renderer_in_every_frame(
        object in 0usize..5,
        lead in 0.0f64..300.0,
        hold in 20.0f64..600.0,
        distance in -0.4f32..0.4,
        ratio in 2u32..=60,
        transfer in 0.0f64..40.0,
    ) {
        let scene = mixed();
        let params = GrabParams {
            object: Some(scene.objects[object].name.clone()),
            start_ms: 30.0,
            over_lead_ms: lead,
            hold_ms: hold,
            distance,
            linger_ms: 50.0,
        };
        let Ok(trace) = grab(&scene, &params) else {
            // The object is hidden from the eye: nothing to grab.
            return Ok(());
        };
        let clock = VirtualClock { sc_ms: 10.0 * f64::from(ratio), fc_ms: 10.0, transfer_ms: transfer };
        let frames = frames_for(trace.duration_ms(), &clock).min(400);
        let mut refs = Client::new(SIZE.0, SIZE.1);
        let mut bad = Vec::new();
        run_virtual(&scene, trace, clock, Migration::Predictive, Composition::Deep, SIZE, frames, |f| {
            let composed = f.composed().expect("composes");
            // The FC's footprint-only image is the composed frame's resolve, pixel for pixel.
            assert_eq!(f.image, composed.resolve(scene.background), "frame {}", f.index);
            if composed != reference(&scene, &mut refs, f) {
                bad.push(f.index);
            }
        })
        .expect("the run completes");
        prop_assert!(bad.is_empty(), "frames differing from the single renderer: {bad:?}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4, ..ProptestConfig::default() })]

    /// The same on the heavy `mfr-cars` (a few cases: each frame's reference renders 400,000
    /// triangles): any object of the car or the field in front of it, grabbed with any lead, at
    /// any ratio and delay, passing behind or in front of the transparent windscreen.
    #[test]
    fn deep_predictive_equals_the_single_renderer_on_mfr_cars(
        object in 0usize..40,
        lead in 0.0f64..300.0,
        hold in 20.0f64..400.0,
        distance in -0.5f32..0.5,
        ratio in 2u32..=60,
        transfer in 0.0f64..40.0,
    ) {
        let scene = open_scene("mfr-cars", &SearchPath::new(Vec::<std::path::PathBuf>::new()))
            .expect("built-in scene");
        let params = GrabParams {
            object: Some(scene.objects[object].name.clone()),
            start_ms: 30.0,
            over_lead_ms: lead,
            hold_ms: hold,
            distance,
            linger_ms: 50.0,
        };
        let Ok(trace) = grab(&scene, &params) else {
            // The object is hidden from the eye: nothing to grab.
            return Ok(());
        };
        // A coarser FC tick than on `mixed`, so a case stays short.
        let clock = VirtualClock { sc_ms: 20.0 * f64::from(ratio), fc_ms: 20.0, transfer_ms: transfer };
        let frames = frames_for(trace.duration_ms(), &clock).min(120);
        let mut refs = Client::new(SIZE.0, SIZE.1);
        let mut bad = Vec::new();
        run_virtual(&scene, trace, clock, Migration::Predictive, Composition::Deep, SIZE, frames, |f| {
            if f.composed().expect("composes") != reference(&scene, &mut refs, f) {
                bad.push(f.index);
            }
        })
        .expect("the run completes");
        prop_assert!(bad.is_empty(), "frames differing from the single renderer: {bad:?}");
    }
}

#[test]
fn naive_migration_leaves_holes_after_a_release() {
    let scene = mixed();
    let params = GrabParams {
        object: Some("glass sphere".into()),
        start_ms: 30.0,
        over_lead_ms: 0.0,
        hold_ms: 200.0,
        distance: -0.3,
        linger_ms: 400.0,
    };
    let trace = grab(&scene, &params).expect("trace");
    let clock = VirtualClock {
        sc_ms: 100.0,
        fc_ms: 10.0,
        transfer_ms: 0.0,
    };
    let id = scene
        .objects
        .iter()
        .find(|o| o.name == "glass sphere")
        .map(|o| o.id)
        .expect("object");
    let released_at = params.start_ms + params.over_lead_ms + params.hold_ms;
    let mut refs = Client::new(SIZE.0, SIZE.1);
    let (mut holes, mut after_release) = (Vec::new(), 0);
    let frames = frames_for(trace.duration_ms(), &clock);
    run_virtual(
        &scene,
        trace,
        clock,
        Migration::Naive,
        Composition::Deep,
        SIZE,
        frames,
        |f| {
            let count = |d: &DeepFrame| d.objects().iter().filter(|&&o| o == id).count();
            let r = reference(&scene, &mut refs, f);
            if f.t_ms >= released_at {
                after_release += 1;
            }
            if count(&f.composed().expect("composes")) < count(&r) {
                holes.push(f.t_ms);
            }
        },
    )
    .expect("the run completes");
    assert!(after_release > 0);
    // The object vanished right after the release, until an SC frame started after it arrived.
    assert!(
        !holes.is_empty(),
        "no hole: naive migration should show one"
    );
    assert!(
        holes.iter().all(|&t| t >= released_at),
        "holes before the release: {holes:?}"
    );
    assert!(
        holes
            .iter()
            .all(|&t| t < released_at + 2.0 * clock.sc_ms + clock.transfer_ms),
        "a hole lasts less than two SC frames: {holes:?}"
    );
}

/// Springer 2008 fig. 6.6: with colour + depth composition an FC object behind a transparent SC
/// object is lost (the SC's front depth hides it) — even with predictive migration and a lead long
/// enough that every SC buffer used after the grab has left the object out. Deep composition
/// shows none of it.
#[test]
fn digital_composition_loses_fc_objects_behind_transparent_sc_objects_and_deep_does_not() {
    let scene = mixed();
    let params = GrabParams {
        object: Some("opaque cube".into()),
        start_ms: 30.0,
        over_lead_ms: 700.0,
        hold_ms: 300.0,
        distance: 0.2,
        linger_ms: 50.0,
    };
    let cube = scene
        .objects
        .iter()
        .find(|o| o.name == "opaque cube")
        .map(|o| o.id)
        .expect("object");
    let clock = VirtualClock {
        sc_ms: 300.0,
        fc_ms: 30.0,
        transfer_ms: 0.0,
    };
    let selected_at = params.start_ms + params.over_lead_ms;
    for (composition, expect_artefacts) in
        [(Composition::Digital, true), (Composition::Deep, false)]
    {
        let trace = grab(&scene, &params).expect("trace");
        let frames = frames_for(trace.duration_ms(), &clock);
        let mut refs = Client::new(SIZE.0, SIZE.1);
        let mut artefacts = 0u64;
        run_virtual(
            &scene,
            trace,
            clock,
            Migration::Predictive,
            composition,
            SIZE,
            frames,
            |f| {
                if f.t_ms < selected_at || f.t_ms > selected_at + params.hold_ms {
                    return;
                }
                // No stale copy: the SC buffer in use left the cube out.
                let sc = f.sc.as_ref().expect("an SC buffer by then");
                assert!(sc.excluded.contains(&cube), "frame {}", f.index);
                let a = strata_mfr::audit(
                    &f.composed().expect("composes"),
                    &reference(&scene, &mut refs, f),
                    scene.background,
                );
                artefacts += a.bad_pixels + a.ghost_pixels + a.hole_pixels + a.blend_pixels;
            },
        )
        .expect("the run completes");
        assert_eq!(
            artefacts > 0,
            expect_artefacts,
            "{composition:?}: {artefacts}"
        );
    }
}
