//! The interleaved single-thread mode: every frame exact against the single renderer, SC frames
//! captured in chunks, exported in bands and swapped in, every period's steps recorded and
//! every miss laid on one of them, and the chunking option read as documented.

use strata_mfr::authority::Authority;
use strata_mfr::client::Client;
use strata_mfr::interleaved::{BandedExport, StepKind};
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
            assert_eq!(r.bands, 1, "the fixed mode exports in one step");
        }
        // Every period is recorded; its steps are the chunks and bands counted, and every miss
        // has a cause.
        assert_eq!(stats.periods.len(), 30);
        let steps = stats.periods.iter().flat_map(|p| &p.steps);
        let chunks = steps
            .clone()
            .filter(|s| matches!(s.kind, StepKind::Chunk(_)));
        assert_eq!(chunks.count(), stats.chunk_ms.len());
        let bands: Vec<u32> = steps
            .filter_map(|s| match s.kind {
                StepKind::Band(rows) => Some(rows),
                _ => None,
            })
            .collect();
        assert_eq!(bands, stats.band_rows);
        let swapped_rows = 36 * stats.sc_frames.len() as u32;
        let banded: u32 = bands.iter().sum();
        assert!(
            banded >= swapped_rows && banded < swapped_rows + 36,
            "{banded} rows"
        );
        let missed = stats.fc_frame_ms.len() as u64 - stats.fc_deadlines_hit;
        assert_eq!(stats.misses().total(), missed);
        assert!(stats.periods.iter().all(|p| p.fc_end_ms >= p.fc_start_ms
            && p.steps.windows(2).all(|w| w[0].end_ms <= w[1].end_ms)));
        if chunking == Chunking::Adaptive {
            assert!(
                stats
                    .periods
                    .iter()
                    .flat_map(|p| &p.steps)
                    .filter(|s| !matches!(s.kind, StepKind::Start))
                    .all(|s| s.predicted_ms.is_some_and(|p| p >= 0.0)),
                "every adaptive chunk and band is predicted"
            );
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
    // Fixed chunks of 37 triangles: several per SC frame whatever the machine; adaptive: chunks
    // and bands as the machine's speed makes them.
    for chunking in [Chunking::Fixed(37), Chunking::Adaptive] {
        let (frames, stats, scene) = run(chunking);
        if chunking == Chunking::Fixed(37) {
            assert!(stats.sc_frames.iter().all(|r| r.chunks > 1));
        }
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
            assert!(
                whole == sc.frame,
                "{chunking}: SC frame {} differs",
                sc.sc_frame
            );
            assert!(
                sc.image == whole.resolve(scene.background),
                "{chunking}: SC image {} differs",
                sc.sc_frame
            );
            checked += 1;
        }
        assert!(checked > 0, "{chunking}");
    }
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

#[test]
fn a_frame_exported_in_any_bands_equals_the_one_piece_export() {
    for name in ["mixed", "mfr-cars"] {
        let scene = open_scene(name, &SearchPath::new(Vec::<std::path::PathBuf>::new()))
            .expect("built-in scene");
        let (w, h) = (48, 27);
        let mut authority = Authority::new(&scene, strata_mfr::Trace::default());
        let snapshot = authority.advance_to(0.0);
        let all: Vec<usize> = (0..scene.objects.len()).collect();
        let mut client = Client::new(w, h);
        // Captured in two chunks, as the interleaved SC does.
        let input = client
            .frame_input(&scene, &snapshot, &snapshot.view, &all)
            .expect("input");
        let half = input.triangle_count() / 2;
        client.begin_parts().expect("clear");
        for range in [0..half, half..input.triangle_count()] {
            client
                .capture_part(&input.triangle_range(range))
                .expect("chunk");
        }
        let whole = client.export().expect("one piece");
        assert!(whole.fragment_count() > 0, "{name}");
        let image = whole.resolve(scene.background);
        for bands in [
            vec![h],
            vec![1; h as usize],
            vec![0, 5, 13, 0, 9],
            vec![26, 1],
            vec![7; 4],
        ] {
            let mut export = BandedExport::new(&client, scene.background);
            for &rows in &bands {
                export.step(&client, rows).expect("band");
            }
            assert!(export.is_done(), "{name} {bands:?}");
            let (frame, banded_image) = export.finish().expect("assembled");
            assert!(frame == whole, "{name}: bands {bands:?} give another frame");
            assert!(
                banded_image == image,
                "{name}: bands {bands:?} give another image"
            );
        }
        let mut short = BandedExport::new(&client, scene.background);
        short.step(&client, 10).expect("band");
        let e = short.finish().expect_err("rows are left");
        assert!(e.to_string().contains("stopped at row 10 of 27"), "{e}");
    }
}
