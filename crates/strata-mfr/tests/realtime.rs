//! Slow and fast clients on real threads: whatever the timing turned out to be, every FC frame of
//! deep composition with predictive migration equals the single renderer's.

use std::sync::Arc;

use strata_mfr::client::Client;
use strata_mfr::trace::{GrabParams, grab};
use strata_mfr::{FcFrame, RealConfig, run_real};
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
