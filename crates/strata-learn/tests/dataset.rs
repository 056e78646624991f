//! The procedural scenes and the dataset end to end: generated scenes are reproducible and as
//! deep as they say; labels respect the oracle's guarantees; files round-trip and match the
//! manifest; nothing depends on the thread count.

use strata_core::npy::{self, NpyValues};
use strata_learn::dataset::{Dataset, DatasetError, DatasetSpec, LABELS, fnv1a64_hex};
use strata_learn::procedural::{MAX_LAYERS, MIN_LAYERS, generate};
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::count::FragmentCounts;
use strata_stores::kbuffer::features::{FEATURE_COUNT, FEATURE_SET, feature_index, feature_names};

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

/// Per-pixel fragment counts of `scene` from its own camera.
fn counts(scene: &strata_scene::Scene) -> Vec<u32> {
    let input = FrameInput::from_scene(scene, 0);
    let mut raster = Rasterizer::default();
    let mut counts = FragmentCounts::new();
    counts.clear(scene.width, scene.height).unwrap();
    raster.prepare(&input).rasterize(&mut counts);
    counts.counts().to_vec()
}

#[test]
fn procedural_scenes_are_reproducible_from_their_seed() {
    let describe = |seed| {
        let s = generate(seed, 64, 48).scene;
        s.objects
            .iter()
            .map(|o| {
                format!(
                    "{:?} {:?} {:?} {:?}",
                    o.translate, o.rotate_deg, o.scale, o.material
                )
            })
            .collect::<Vec<_>>()
            .join("\n")
            + &format!("{:?}", s.background)
    };
    assert_eq!(describe(11), describe(11));
    assert_ne!(describe(11), describe(12));
    let a = generate(11, 64, 48);
    assert_eq!(counts(&a.scene), counts(&generate(11, 64, 48).scene));
}

#[test]
fn procedural_scenes_are_exactly_as_deep_as_advertised() {
    let mut seen = Vec::new();
    for seed in 0..16 {
        let p = generate(seed, 64, 48);
        assert!(
            (MIN_LAYERS..=MAX_LAYERS).contains(&p.layers),
            "seed {seed}: {} layers",
            p.layers
        );
        let c = counts(&p.scene);
        let max = *c.iter().max().unwrap();
        assert_eq!(max, p.layers, "seed {seed}: deepest pixel");
        // The image centre's pixels hold every layer.
        assert_eq!(c[24 * 64 + 32], p.layers, "seed {seed}: centre pixel");
        // Not everything is one depth: the objects overlap in other numbers of layers too.
        if p.layers > 2 {
            assert!(c.iter().any(|&n| n > 0 && n < p.layers), "seed {seed}");
        }
        seen.push(p.layers);
    }
    seen.sort_unstable();
    seen.dedup();
    assert!(seen.len() >= 6, "16 seeds gave only the depths {seen:?}");
}

fn small_spec(pixels_per_frame: Option<usize>) -> DatasetSpec {
    DatasetSpec {
        views: 2,
        budgets: vec![0.3, 0.7],
        pixels_per_frame,
        seed: 5,
    }
}

fn build(spec: DatasetSpec, threads: usize) -> Dataset {
    let mut data = Dataset::new(spec).unwrap();
    pool(threads).install(|| {
        for seed in [3, 4] {
            data.add_scene(&generate(seed, 48, 36).scene, |_| {})
                .unwrap();
        }
        let mut mixed =
            strata_scene::open_scene("mixed", &strata_scene::SearchPath::default()).unwrap();
        (mixed.width, mixed.height) = (64, 36);
        data.add_scene(&mixed, |_| {}).unwrap();
    });
    data
}

#[test]
fn labels_keep_the_oracles_guarantees() {
    let data = build(small_spec(None), 2);
    assert_eq!(data.frames.len(), 3 * 2 * 2);
    let count = feature_index("count").unwrap();
    let share = feature_index("budget_share").unwrap();
    let mut sum_k = vec![0u64; data.frames.len()];
    for r in 0..data.rows() {
        let f = &data.features[r * FEATURE_COUNT..(r + 1) * FEATURE_COUNT];
        let l = &data.labels[r * LABELS.len()..(r + 1) * LABELS.len()];
        let frame = &data.frames[data.frame[r] as usize];
        let (c, k) = (f[count], l[0]);
        assert!(c >= 1.0, "only covered pixels are rows");
        assert!(k <= c, "k {k} above count {c}");
        assert!((0.0..=1.0).contains(&l[1]), "kept fraction {}", l[1]);
        assert_eq!(l[2], k / frame.fragments as f32);
        assert_eq!(f[share], frame.budget as f32 / frame.fragments as f32);
        // The truncation-error curve: a colour distance, 0 once every fragment is kept.
        for (i, &e) in l[3..].iter().enumerate() {
            let kept = (i + 1) as f32;
            assert!((0.0..=3f32.sqrt() + 1e-5).contains(&e), "e({kept}) = {e}");
            if kept >= c {
                assert_eq!(e, 0.0, "e({kept}) of a pixel of {c} fragments");
            }
        }
        sum_k[frame.id as usize] += k as u64;
    }
    for f in &data.frames {
        // Every covered pixel is a row, so the rows hold the whole Σk, which is min(M, N).
        assert_eq!(f.sum_k, f.budget.min(f.fragments), "frame {}", f.id);
        assert_eq!(sum_k[f.id as usize], f.sum_k, "frame {}", f.id);
        assert_eq!(f.rows, f.covered);
    }
    assert_eq!(data.scenes[2].family, "mixed");
    assert_eq!(data.scenes[0].family, "procedural");
}

#[test]
fn dataset_files_round_trip_and_match_the_manifest() {
    let data = build(small_spec(Some(40)), 1);
    assert!(data.frames.iter().all(|f| f.rows <= 40));
    let dir = tempfile::tempdir().unwrap();
    let manifest = data.write(dir.path()).unwrap();
    let on_disk: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(on_disk, manifest);
    assert_eq!(manifest["feature_set"], FEATURE_SET);
    assert_eq!(manifest["features"], serde_json::json!(feature_names()));
    assert_eq!(manifest["labels"], serde_json::json!(LABELS));
    assert_eq!(manifest["rows"], data.rows());
    assert_eq!(
        manifest["frames"].as_array().unwrap().len(),
        data.frames.len()
    );
    let n = data.rows();
    let expect: [(&str, Vec<usize>, NpyValues); 5] = [
        (
            "features.npy",
            vec![n, FEATURE_COUNT],
            NpyValues::F32(data.features.clone()),
        ),
        (
            "labels.npy",
            vec![n, LABELS.len()],
            NpyValues::F32(data.labels.clone()),
        ),
        ("frame.npy", vec![n], NpyValues::U32(data.frame.clone())),
        ("scene.npy", vec![n], NpyValues::U32(data.scene.clone())),
        ("pixel.npy", vec![n], NpyValues::U32(data.pixel.clone())),
    ];
    for (name, shape, values) in expect {
        let path = dir.path().join(name);
        let bytes = std::fs::read(&path).unwrap();
        let entry = &manifest["files"][name];
        assert_eq!(entry["fnv1a64"], fnv1a64_hex(&bytes), "{name}");
        assert_eq!(entry["shape"], serde_json::json!(shape), "{name}");
        let array = npy::read(&path).unwrap();
        assert_eq!(array.shape, shape, "{name}");
        assert_eq!(array.values, values, "{name}");
    }
    // The per-frame row counts add up to the rows, frame by frame.
    for f in &data.frames {
        let rows = data.frame.iter().filter(|&&id| id == f.id).count() as u64;
        assert_eq!(rows, f.rows);
    }
}

#[test]
fn dataset_is_the_same_for_any_thread_count() {
    let one = build(small_spec(Some(30)), 1);
    let two = build(small_spec(Some(30)), 2);
    assert_eq!(one.pixel, two.pixel);
    assert_eq!(one.labels, two.labels);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one.features), bits(&two.features));
    assert_eq!(one.frames, two.frames);
}

#[test]
fn bad_specs_are_refused_with_a_reason() {
    let e = Dataset::new(DatasetSpec {
        budgets: vec![0.5, 1.5],
        ..DatasetSpec::default()
    })
    .unwrap_err();
    assert!(matches!(e, DatasetError::BadBudget(_)), "{e}");
    assert!(e.to_string().contains("150"), "{e}");
    let e = Dataset::new(DatasetSpec {
        views: 0,
        ..DatasetSpec::default()
    })
    .unwrap_err();
    assert!(matches!(e, DatasetError::NoViews), "{e}");
}

#[test]
fn a_real_mesh_family_when_its_file_is_present() {
    // The Stanford bunny is fetched by scripts/fetch-models; without it this test checks only
    // that the family name of its resolutions is one.
    assert_eq!(strata_learn::dataset::family_of("dragon-res3"), "dragon");
    let Some(models) = strata_testdata::models(&["bunny.obj"]) else {
        return;
    };
    let mut search = strata_scene::SearchPath::default();
    for d in models.dirs() {
        search.prepend(d);
    }
    let mut bunny = strata_scene::open_scene("bunny", &search).unwrap();
    (bunny.width, bunny.height) = (80, 45);
    let mut data = Dataset::new(DatasetSpec {
        views: 1,
        budgets: vec![0.5],
        pixels_per_frame: None,
        seed: 0,
    })
    .unwrap();
    data.add_scene(&bunny, |_| {}).unwrap();
    let f = &data.frames[0];
    assert_eq!(data.scenes[0].family, "bunny");
    assert_eq!(f.sum_k, f.budget.min(f.fragments));
    assert!(data.rows() > 0);
}
