//! Selection artefacts (Springer 2008 §6.1, figs. 6.1–6.2) at SC:FC 1:10: with the seed's
//! colour + depth composition, naive migration grabbing and dragging at once shows the object
//! twice — its stale copy in the SC buffer and the FC's moving one (ghost pixels) — and
//! predictive migration with an OVER lead longer than the SC's latency shows no ghost in any
//! frame. Deep composition drops stale copies, so even naive migration shows no ghost there.

use strata_mfr::client::Client;
use strata_mfr::trace::{GrabParams, grab};
use strata_mfr::{Composition, Migration, VirtualClock, run_virtual};
use strata_scene::{Scene, SearchPath, open_scene};

const SIZE: (u32, u32) = (96, 54);

fn mixed() -> Scene {
    open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new())).expect("built-in scene")
}

/// FC frames with ghost pixels in a grab of the glass sphere.
fn ghost_frames(migration: Migration, composition: Composition, over_lead_ms: f64) -> Vec<u64> {
    let scene = mixed();
    let params = GrabParams {
        object: Some("glass sphere".into()),
        start_ms: 30.0,
        over_lead_ms,
        hold_ms: 600.0,
        distance: 0.3,
        linger_ms: 50.0,
    };
    let trace = grab(&scene, &params).expect("trace");
    let clock = VirtualClock {
        sc_ms: 300.0,
        fc_ms: 30.0,
        transfer_ms: 0.0,
    };
    let frames = ((trace.duration_ms() + 3.0 * clock.sc_ms) / clock.fc_ms).ceil() as u64;
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let mut reference = Client::new(SIZE.0, SIZE.1);
    let mut ghosts = Vec::new();
    run_virtual(
        &scene,
        trace,
        clock,
        migration,
        composition,
        SIZE,
        frames,
        |f| {
            let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view);
            let r = reference
                .render(&scene, &f.snapshot, &view, &all)
                .expect("reference");
            let a = strata_mfr::audit(&f.composed().expect("composes"), &r, scene.background);
            if a.ghost_pixels > 0 {
                ghosts.push(f.index);
            }
        },
    )
    .expect("the run completes");
    ghosts
}

#[test]
fn naive_immediate_drag_shows_ghosts_predictive_with_lead_does_not() {
    let naive = ghost_frames(Migration::Naive, Composition::Digital, 0.0);
    assert!(!naive.is_empty(), "naive digital: no ghost");
    // The lead (700 ms) exceeds an SC frame plus its hand-over, so by the select the SC buffer in
    // use has left the sphere out.
    let predictive = ghost_frames(Migration::Predictive, Composition::Digital, 700.0);
    assert!(
        predictive.is_empty(),
        "predictive digital: ghosts in {predictive:?}"
    );
    let deep = ghost_frames(Migration::Naive, Composition::Deep, 0.0);
    assert!(deep.is_empty(), "naive deep: ghosts in {deep:?}");
}
