//! The interleaved single-thread mode: every frame exact against the single renderer, SC frames
//! captured in chunks and swapped in, and the chunking option read as documented.

use strata_mfr::client::Client;
use strata_mfr::trace::{GrabParams, grab};
use strata_mfr::{Chunking, FcFrame, RealConfig, audit, run_interleaved};
use strata_scene::{SearchPath, open_scene};

fn run(
    chunking: Chunking,
) -> (
    Vec<FcFrame>,
    strata_mfr::InterleavedStats,
    strata_scene::Scene,
) {
    let scene = open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new()))
        .expect("built-in scene");
    let params = GrabParams {
        object: Some("glass sphere".into()),
        start_ms: 20.0,
        over_lead_ms: 0.0,
        hold_ms: 250.0,
        distance: -0.3,
        linger_ms: 60.0,
    };
    let trace = grab(&scene, &params).expect("trace");
    let config = RealConfig {
        fc_hz: 60.0,
        ..RealConfig::new((64, 36), 30)
    };
    let mut frames = Vec::new();
    let stats = run_interleaved(&scene, trace, &config, chunking, |f| frames.push(f.clone()))
        .expect("the run completes");
    (frames, stats, scene)
}

#[test]
fn interleaved_runs_compose_exactly_in_every_frame() {
    // Fixed chunks of 50 triangles: every SC frame of `mixed` takes several chunks, whatever the
    // machine's speed (the adaptive size depends on it).
    for chunking in [Chunking::Fixed(50), Chunking::Adaptive] {
        let (frames, stats, scene) = run(chunking);
        assert_eq!(frames.len(), 30, "{chunking}");
        assert_eq!(stats.fc_frame_ms.len(), 30);
        assert!(
            !stats.sc_frames.is_empty(),
            "{chunking}: no SC frame was swapped in"
        );
        assert!(frames.iter().any(|f| f.sc.is_some()));
        // Every swapped-in SC frame's triangles were captured (an unfinished one adds more).
        let captured: u64 = stats.chunk_triangles.iter().sum();
        let swapped: u64 = stats.sc_frames.iter().map(|r| r.triangles).sum();
        assert!(captured >= swapped && swapped > 0, "{captured} < {swapped}");
        assert!(stats.sc_frames.iter().all(|r| r.fc_frames() >= 1));
        if chunking == Chunking::Fixed(50) {
            let r = &stats.sc_frames[0];
            assert_eq!(u64::from(r.chunks), r.triangles.div_ceil(50), "{r:?}");
        }
        let mut reference = Client::new(64, 36);
        let all: Vec<usize> = (0..scene.objects.len()).collect();
        for f in &frames {
            let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view);
            let r = reference
                .render(&scene, &f.snapshot, &view, &all)
                .expect("reference");
            let composed = f.composed().expect("composes");
            assert_eq!(f.image, composed.resolve(scene.background));
            let a = audit(&composed, &r, scene.background);
            assert_eq!(
                a.bad_pixels, 0,
                "{chunking}: FC frame {} has bad pixels",
                f.index
            );
            assert!(composed == r, "{chunking}: FC frame {} differs", f.index);
        }
    }
}

#[test]
fn chunked_sc_frames_equal_one_shot_frames() {
    let (frames, stats, scene) = run(Chunking::Fixed(37));
    assert!(stats.sc_frames.iter().all(|r| r.chunks > 1));
    let mut one_shot = Client::new(64, 36);
    let mut checked = 0;
    for f in &frames {
        // Buffer 0 is rendered in one call before the run.
        let Some(sc) = f.sc.as_ref().filter(|sc| sc.sc_frame > 0) else {
            continue;
        };
        let indices: Vec<usize> = scene
            .objects
            .iter()
            .enumerate()
            .filter(|(_, o)| sc.rendered.iter().any(|&(id, _)| id == o.id))
            .map(|(i, _)| i)
            .collect();
        let snapshot_id = sc.snapshot_id;
        let snapshot = frames
            .iter()
            .map(|g| &g.snapshot)
            .find(|s| s.id == snapshot_id)
            .expect("the SC rendered a snapshot some FC frame showed");
        let whole = one_shot
            .render(&scene, snapshot, &sc.view, &indices)
            .expect("one shot");
        assert!(whole == sc.frame, "SC frame {} differs", sc.sc_frame);
        checked += 1;
    }
    assert!(checked > 0);
}

#[test]
fn chunking_reads_adaptive_and_fixed() {
    assert_eq!("adaptive".parse(), Ok(Chunking::Adaptive));
    assert_eq!("fixed:4096".parse(), Ok(Chunking::Fixed(4096)));
    for bad in ["fixed:0", "fixed:", "fixed:x", "auto", ""] {
        let e = bad.parse::<Chunking>().expect_err(bad);
        assert!(e.to_string().contains("adaptive or fixed:N"), "{e}");
    }
    assert_eq!(Chunking::Fixed(8).to_string(), "fixed:8");
}
