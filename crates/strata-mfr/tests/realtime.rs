//! Slow and fast clients on real threads: whatever the timing turned out to be, every FC frame of
//! deep composition with predictive migration equals the single renderer's.

use std::sync::Arc;

use strata_mfr::client::Client;
use strata_mfr::trace::{GrabParams, grab};
use strata_mfr::{FcFrame, RealConfig, ScLoad, ScPriority, run_real};
use strata_scene::{SearchPath, open_scene};

#[test]
fn real_threads_compose_exactly_in_every_frame() {
    let scene = Arc::new(
        open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new()))
            .expect("built-in scene"),
    );
    let params = GrabParams {
        object: Some("glass sphere".into()),
        start_ms: 20.0,
        over_lead_ms: 0.0,
        hold_ms: 250.0,
        distance: -0.3,
        linger_ms: 60.0,
    };
    let trace = grab(&scene, &params).expect("trace");
    let size = (64, 36);
    let mut frames: Vec<FcFrame> = Vec::new();
    let config = RealConfig {
        fc_hz: 60.0,
        ..RealConfig::new(size, 30)
    };
    let stats = run_real(Arc::clone(&scene), trace, &config, |f| {
        frames.push(f.clone())
    })
    .expect("the run completes");
    assert_eq!(frames.len(), 30);
    assert_eq!(stats.fc_frame_ms.len(), 30);
    assert_eq!(stats.read_us.len(), 30);
    assert!(
        !stats.sc_frame_ms.is_empty(),
        "the SC rendered at least once"
    );
    // The snapshots the FC showed never go back, and it composed with SC buffers once they came.
    assert!(
        frames
            .windows(2)
            .all(|w| w[1].snapshot.id >= w[0].snapshot.id)
    );
    assert!(frames.iter().any(|f| f.sc.is_some()));
    let mut reference = Client::new(size.0, size.1);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    for f in &frames {
        let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view);
        let r = reference
            .render(&scene, &f.snapshot, &view, &all)
            .expect("reference");
        let composed = f.composed().expect("composes");
        assert_eq!(
            f.image,
            composed.resolve(scene.background),
            "frame {}",
            f.index
        );
        assert!(
            composed == r,
            "FC frame {} differs from the single renderer",
            f.index
        );
    }
}

#[test]
fn a_bad_rate_is_refused() {
    let scene = Arc::new(
        open_scene(
            "overlap",
            &SearchPath::new(Vec::<std::path::PathBuf>::new()),
        )
        .expect("built-in scene"),
    );
    let config = RealConfig {
        fc_hz: 0.0,
        ..RealConfig::new((8, 8), 1)
    };
    let err = run_real(scene, strata_mfr::Trace::default(), &config, |_| {}).expect_err("0 Hz");
    assert!(err.to_string().contains("fc_hz 0"), "{err}");
}

#[test]
fn without_a_slow_client_the_fc_draws_every_object_every_frame() {
    let scene = Arc::new(
        open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new()))
            .expect("built-in scene"),
    );
    let trace = grab(&scene, &GrabParams::default()).expect("trace");
    let config = RealConfig {
        fc_hz: 120.0,
        sc_load: ScLoad::Off,
        ..RealConfig::new((48, 27), 12)
    };
    let mut frames: Vec<FcFrame> = Vec::new();
    let stats = run_real(Arc::clone(&scene), trace, &config, |f| {
        frames.push(f.clone())
    })
    .expect("the run completes");
    assert!(stats.sc_frame_ms.is_empty(), "no SC frame");
    assert_eq!(frames.len(), 12);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    for f in &frames {
        assert!(
            f.sc.is_none(),
            "frame {} composed with an SC buffer",
            f.index
        );
        assert_eq!(f.fc_objects, all, "frame {}", f.index);
    }
}

#[test]
fn an_idle_slow_client_renders_the_first_state_only_at_low_priority() {
    let scene = Arc::new(
        open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new()))
            .expect("built-in scene"),
    );
    let trace = grab(&scene, &GrabParams::default()).expect("trace");
    let config = RealConfig {
        fc_hz: 120.0,
        sc_load: ScLoad::Idle,
        sc_priority: ScPriority::Low,
        ..RealConfig::new((48, 27), 24)
    };
    let mut frames: Vec<FcFrame> = Vec::new();
    let stats = run_real(Arc::clone(&scene), trace, &config, |f| {
        frames.push(f.clone())
    })
    .expect("the run completes");
    assert!(
        stats.sc_frame_ms.len() <= 1,
        "{} SC frames",
        stats.sc_frame_ms.len()
    );
    assert!(stats.incidents.is_empty(), "{:?}", stats.incidents);
    // The one buffer is of the snapshot of the FC's first frame.
    let first = frames[0].snapshot.id;
    for f in frames.iter().filter_map(|f| f.sc.as_ref()) {
        assert_eq!((f.sc_frame, f.snapshot_id), (0, first));
    }
}
