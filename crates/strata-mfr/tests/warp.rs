//! Depth-image warping on the virtual clock: with no view change, warping is the identity (every
//! frame equals the unwarped run's, bit for bit); under an orbit, the forward warp opens holes,
//! the splat fills some, and the warped frames are closer to the exact render at the current view
//! than the unwarped frames (which show the SC buffer's older view).

use strata_core::ObjectId;
use strata_mfr::client::Client;
use strata_mfr::simulate::FcFrame;
use strata_mfr::trace::{GrabParams, Trace, grab, orbit};
use strata_mfr::warp::{run_virtual_warped, warp_audit, warp_frame};
use strata_mfr::{Composition, Migration, VirtualClock, run_virtual};
use strata_scene::{Scene, SearchPath, open_scene};

const SIZE: (u32, u32) = (96, 54);

const CLOCK: VirtualClock = VirtualClock {
    sc_ms: 300.0,
    fc_ms: 30.0,
    transfer_ms: 0.0,
};

fn mixed() -> Scene {
    open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new())).expect("built-in scene")
}

/// Every frame of a run, warped or not.
fn frames(scene: &Scene, trace: &Trace, warped: bool, count: u64) -> Vec<FcFrame> {
    let mut out = Vec::new();
    let keep = |f: &FcFrame| out.push(f.clone());
    let run = if warped {
        run_virtual_warped(
            scene,
            trace.clone(),
            CLOCK,
            Migration::Predictive,
            Composition::Deep,
            SIZE,
            count,
            keep,
        )
    } else {
        run_virtual(
            scene,
            trace.clone(),
            CLOCK,
            Migration::Predictive,
            Composition::Deep,
            SIZE,
            count,
            keep,
        )
    };
    run.expect("the run completes");
    out
}

#[test]
fn without_a_view_change_warping_is_the_identity() {
    let scene = mixed();
    let params = GrabParams {
        object: Some("glass sphere".into()),
        start_ms: 30.0,
        over_lead_ms: 200.0,
        hold_ms: 300.0,
        distance: 0.3,
        linger_ms: 50.0,
    };
    let trace = grab(&scene, &params).expect("trace");
    let plain = frames(&scene, &trace, false, 30);
    let warped = frames(&scene, &trace, true, 30);
    assert_eq!(plain.len(), warped.len());
    let mut with_sc = 0;
    for (a, b) in plain.iter().zip(&warped) {
        assert_eq!(a.image, b.image, "frame {} differs", a.index);
        assert_eq!(
            a.composed().expect("composes"),
            b.composed().expect("composes"),
            "frame {} fragments differ",
            a.index
        );
        if let Some(info) = &b.warp {
            with_sc += 1;
            assert_eq!(
                info.filled, 0,
                "frame {}: filled with no view change",
                a.index
            );
            assert_eq!(info.lost, 0, "frame {}: fragments lost", a.index);
        }
    }
    assert!(with_sc >= 15, "only {with_sc} frames had an SC buffer");
}

#[test]
fn warping_a_frame_to_its_own_view_changes_nothing() {
    let scene = mixed();
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let trace = orbit(&scene, 4000.0, 100.0, 33.0).expect("trace");
    let mut authority = strata_mfr::Authority::new(&scene, trace);
    let snapshot = authority.advance_to(0.0);
    let frame = Client::new(SIZE.0, SIZE.1)
        .render(&scene, &snapshot, &snapshot.view, &all)
        .expect("renders");
    let (warped, info) = warp_frame(&scene, &frame, &snapshot.view, &snapshot.view).expect("warps");
    assert_eq!(warped, frame);
    let empty = (0..SIZE.0 * SIZE.1)
        .filter(|&p| frame.run(p as usize).is_empty())
        .count();
    assert_eq!(info.empty.len(), empty);
    assert_eq!(info.filled, 0);
}

/// Totals over an orbit run: (hole pixels, holes left after filling, bad pixels against the
/// exact render at the current view).
fn orbit_totals(scene: &Scene, warped: bool) -> (u64, u64, u64) {
    let trace = orbit(scene, 2000.0, 900.0, 33.0).expect("trace");
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let mut reference = Client::new(SIZE.0, SIZE.1);
    let (mut holes, mut left, mut bad) = (0, 0, 0);
    for f in frames(scene, &trace, warped, 32) {
        let exact = reference
            .render(scene, &f.snapshot, &f.snapshot.view, &all)
            .expect("reference");
        let composed = f.composed().expect("composes");
        bad += strata_mfr::audit(&composed, &exact, scene.background).bad_pixels;
        if let (Some(info), Some(sc)) = (&f.warp, &f.sc) {
            let ids: Vec<ObjectId> = sc.rendered.iter().map(|&(id, _)| id).collect();
            let a = warp_audit(&sc.frame, info, &exact, &ids);
            holes += a.hole_pixels;
            left += a.holes_left;
        }
    }
    (holes, left, bad)
}

#[test]
fn under_an_orbit_holes_are_counted_and_warped_frames_are_closer_to_the_current_view() {
    let scene = mixed();
    let (holes, left, warped_bad) = orbit_totals(&scene, true);
    let (_, _, plain_bad) = orbit_totals(&scene, false);
    assert!(holes > 0, "an orbit opened no hole");
    assert!(
        left < holes,
        "filling closed no hole ({left} of {holes} left)"
    );
    assert!(
        warped_bad < plain_bad,
        "bad pixels: warped {warped_bad}, unwarped {plain_bad}"
    );
}
