//! Training end to end: a tiny seeded run on generated scenes beats a constant importance on a
//! generated scene it never saw; training is reproducible and independent of the thread count;
//! a dataset that is not one is refused with a reason.

use std::sync::Arc;

use strata_core::metrics::rmse;
use strata_learn::dataset::{Dataset, DatasetSpec};
use strata_learn::procedural::generate;
use strata_learn::train::{ModelSpec, TrainConfig, TrainError, TrainingData, train};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::kbuffer::learned::{Activation, Input, Layer, LearnedModel, Target, Transform};
use strata_stores::{Budget, KFrom, MethodOptions, render_frame};

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

/// A dataset of generated scenes `seeds`, 64 × 48, written to `dir` and read back.
fn dataset(dir: &std::path::Path, seeds: std::ops::Range<u64>) -> TrainingData {
    let mut data = Dataset::new(DatasetSpec {
        views: 2,
        budgets: vec![0.3, 0.5, 0.7],
        pixels_per_frame: None,
        seed: 9,
    })
    .unwrap();
    pool(2).install(|| {
        for seed in seeds {
            data.add_scene(&generate(seed, 64, 48).scene, |_| {})
                .unwrap();
        }
    });
    data.write(dir).unwrap();
    TrainingData::load(dir).unwrap()
}

fn config(seed: u64) -> TrainConfig {
    TrainConfig {
        epochs: 12,
        max_rows: None,
        ..TrainConfig::strata(seed)
    }
}

/// RMSE against the exact image of the variable k-buffer at `budget` with `options`' k.
fn error(scene: &Scene, options: MethodOptions, budget: f64) -> f64 {
    let input = FrameInput::from_scene(scene, 0);
    let mut raster = Rasterizer::default();
    let mut exact = strata_stores::create("abuffer", &MethodOptions::default()).unwrap();
    let reference = render_frame(exact.as_mut(), &mut raster, &input, scene.background)
        .unwrap()
        .image;
    let mut vk = strata_stores::create(
        "vkbuffer",
        &MethodOptions {
            budget: Budget::SceneShare(budget),
            ..options
        },
    )
    .unwrap();
    let image = render_frame(vk.as_mut(), &mut raster, &input, scene.background)
        .unwrap()
        .image;
    rmse(&reference, &image).unwrap()
}

/// A network whose output is ½ everywhere: the same importance for every pixel with a choice.
fn constant() -> LearnedModel {
    LearnedModel {
        inputs: vec![Input {
            feature: 12,
            transform: Transform::Identity,
            mean: 0.0,
            scale: 1.0,
        }],
        layers: vec![Layer::zeros(1, 1)],
        activation: Activation::Relu,
        target: Target::SeedLabel,
        info: Default::default(),
    }
}

#[test]
fn a_tiny_training_run_beats_a_constant_importance_on_unseen_scenes() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), 0..16);
    let spec = ModelSpec::preset("curve").unwrap();
    let (model, report) = pool(2)
        .install(|| train(&data, &spec, &config(1), |_| {}))
        .unwrap();
    assert!(
        report.train_rows > 1000 && report.validation_rows > 0,
        "{report:?}"
    );
    // It learned: the training loss fell from the first epoch to the last.
    assert!(
        (1..=report.epochs.len()).contains(&report.best_epoch),
        "{report:?}"
    );
    let (first, last) = (&report.epochs[0], &report.epochs[report.epochs.len() - 1]);
    assert!(last.train_loss < first.train_loss, "{report:?}");
    let model = Arc::new(model);
    let flat = Arc::new(constant());
    // Scenes 100… were not in the data (which holds 0…15).
    let (mut learned, mut constant) = (0.0, 0.0);
    for seed in 100..104 {
        let unseen = generate(seed, 96, 72).scene;
        for budget in [0.3, 0.5] {
            let with = |weights: &Arc<LearnedModel>| {
                let options = MethodOptions {
                    k_from: KFrom::Learned,
                    weights: Some(weights.clone()),
                    ..MethodOptions::default()
                };
                error(&unseen, options, budget)
            };
            learned += with(&model);
            constant += with(&flat);
        }
    }
    assert!(
        learned < 0.9 * constant,
        "summed RMSE: trained {learned}, constant importance {constant}"
    );
}

#[test]
fn training_is_reproducible_and_independent_of_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), 20..23);
    let cfg = TrainConfig {
        epochs: 2,
        ..config(4)
    };
    for preset in ["curve", "fraction"] {
        let spec = ModelSpec::preset(preset).unwrap();
        let one = pool(1)
            .install(|| train(&data, &spec, &cfg, |_| {}))
            .unwrap()
            .0;
        let two = pool(2)
            .install(|| train(&data, &spec, &cfg, |_| {}))
            .unwrap()
            .0;
        assert_eq!(one, two, "{preset}");
        let other = pool(2)
            .install(|| train(&data, &spec, &config(5), |_| {}))
            .unwrap()
            .0;
        assert_ne!(one, other, "{preset}: another seed, other weights");
    }
}

#[test]
fn what_is_not_a_dataset_is_refused_with_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let err = TrainingData::load(dir.path()).unwrap_err();
    assert!(matches!(err, TrainError::Read { .. }), "{err}");
    assert!(err.to_string().contains("manifest.json"), "{err}");
    let data = dataset(dir.path(), 30..31);
    // Another feature set: made by an older strata.
    let manifest = dir.path().join("manifest.json");
    let text = std::fs::read_to_string(&manifest).unwrap();
    std::fs::write(
        &manifest,
        text.replace("strata-vk-features-2", "strata-vk-features-1"),
    )
    .unwrap();
    let err = TrainingData::load(dir.path()).unwrap_err();
    assert!(err.to_string().contains("strata-vk-features-1"), "{err}");
    std::fs::write(&manifest, &text).unwrap();
    // A non-finite feature.
    let features = dir.path().join("features.npy");
    let good = std::fs::read(&features).unwrap();
    let mut values = data.features.clone();
    values[7] = f32::NAN;
    let bad = strata_core::npy::encode(
        &[data.len(), values.len() / data.len()],
        strata_core::npy::NpyData::F32(&values),
    );
    std::fs::write(&features, bad).unwrap();
    let err = TrainingData::load(dir.path()).unwrap_err();
    assert!(err.to_string().contains("non-finite"), "{err}");
    std::fs::write(&features, good).unwrap();
    // A damaged array.
    std::fs::write(dir.path().join("labels.npy"), b"\x93NUMPY junk").unwrap();
    let err = TrainingData::load(dir.path()).unwrap_err();
    assert!(err.to_string().contains("labels.npy"), "{err}");
    // Holding out every family leaves nothing to train on.
    let cfg = TrainConfig {
        exclude_families: vec!["procedural".into()],
        ..config(1)
    };
    let err = train(&data, &ModelSpec::preset("curve").unwrap(), &cfg, |_| {}).unwrap_err();
    assert!(matches!(err, TrainError::NoRows(_)), "{err}");
}
