//! The learned variable k-buffer: the shipped weights load and match the code's feature list;
//! malformed and mismatched weights are refused with a clear error; the block evaluation of the
//! importance pass equals one pixel's evaluation and the plain-arithmetic network; inference does
//! not depend on the thread count.

use std::collections::BTreeMap;
use std::sync::Arc;

use strata_raster::{FrameInput, Rasterizer};
use strata_scene::{Scene, SearchPath, open_scene};
use strata_stores::count::FragmentCounts;
use strata_stores::kbuffer::VariableKBuffer;
use strata_stores::kbuffer::analytic::Worth;
use strata_stores::kbuffer::features::{
    FEATURE_SET, FEATURES, FeatureAccumulator, FeatureCapture, FrameFeatures,
};
use strata_stores::kbuffer::learned::{
    Activation, Input, Layer, LearnedModel, Target, Transform, WEIGHTS_FORMAT, WeightsError, curve,
    curve_base,
};
use strata_stores::{KFrom, MethodOptions, render_frame};

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

fn scene(name: &str, w: u32, h: u32) -> Scene {
    let mut s = open_scene(name, &SearchPath::default()).expect("built-in scene");
    (s.width, s.height) = (w, h);
    s
}

/// A small model with seeded pseudo-random weights, so every unit matters.
fn model(target: Target) -> LearnedModel {
    let mut x = 0x9e37_79b9u32;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        (x % 2001) as f32 / 1000.0 - 1.0
    };
    let inputs: Vec<Input> = [12usize, 14, 16, 20, 23, 6]
        .iter()
        .map(|&feature| Input {
            feature,
            transform: if feature == 12 {
                Transform::Log1p
            } else {
                Transform::Identity
            },
            mean: 0.25,
            scale: 1.5,
        })
        .collect();
    let mut layers = Vec::new();
    for (i, o) in [(inputs.len(), 5), (5, 3), (3, target.outputs())] {
        let mut l = Layer::zeros(i, o);
        l.weight.iter_mut().for_each(|w| *w = next());
        l.bias.iter_mut().for_each(|b| *b = 0.5 * next());
        layers.push(l);
    }
    LearnedModel {
        inputs,
        layers,
        activation: Activation::Relu,
        target,
        info: BTreeMap::from([("note".to_owned(), "test".to_owned())]),
    }
}

fn render(s: &Scene, options: &MethodOptions, threads: usize) -> VariableKBuffer {
    let mut vk = VariableKBuffer::new(options);
    let input = FrameInput::from_scene(s, 0);
    pool(threads)
        .install(|| render_frame(&mut vk, &mut Rasterizer::default(), &input, s.background))
        .expect("render");
    vk
}

#[test]
fn the_built_in_weights_load_and_match_the_feature_list() {
    let bytes = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/weights/learned-k.safetensors"
    ))
    .expect("the weights are in the repository");
    let model = LearnedModel::from_safetensors(&bytes).expect("the built-in weights load");
    assert_eq!(*LearnedModel::builtin(), model);
    // How it was made is recorded, and the inputs are features of this build, by name.
    for key in ["training_command", "dataset_manifest_fnv1a64", "seed"] {
        assert!(model.info.contains_key(key), "metadata has no {key}");
    }
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    let meta = &header["__metadata__"];
    assert_eq!(meta["feature_set"], FEATURE_SET);
    assert_eq!(meta["format"], WEIGHTS_FORMAT);
    let names: Vec<&str> = meta["inputs"].as_str().unwrap().split(',').collect();
    assert_eq!(names.len(), model.inputs.len());
    for (name, input) in names.iter().zip(&model.inputs) {
        assert_eq!(*name, FEATURES[input.feature].name);
    }
    assert!(
        bytes.len() < 16 * 1024,
        "the weights stay small: {} bytes",
        bytes.len()
    );
}

#[test]
fn weights_round_trip_through_safetensors() {
    for target in [Target::KeptFraction, Target::SeedLabel, Target::ErrorCurve] {
        let m = model(target);
        let back = LearnedModel::from_safetensors(&m.to_safetensors()).expect("reads back");
        assert_eq!(back, m, "{target:?}");
    }
}

/// Rewrites the JSON header of a weights file with `edit`.
fn with_header(bytes: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    edit(&mut header);
    let mut text = serde_json::to_vec(&header).unwrap();
    while !text.len().is_multiple_of(8) {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend(&bytes[8 + n..]);
    out
}

#[test]
fn malformed_and_mismatched_weights_are_refused_with_a_reason() {
    let good = model(Target::ErrorCurve).to_safetensors();
    let meta = |key: &'static str, value: &'static str| {
        with_header(&good, move |h| h["__metadata__"][key] = value.into())
    };
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty file", Vec::new(), "not a readable safetensors"),
        (
            "truncated",
            good[..good.len() - 7].to_vec(),
            "not a readable safetensors",
        ),
        (
            "text",
            b"hello, I am not weights".to_vec(),
            "not a readable safetensors",
        ),
        (
            "old feature set",
            meta("feature_set", "strata-vk-features-1"),
            "strata-vk-features-1",
        ),
        ("other format", meta("format", "keras-h5"), "keras-h5"),
        (
            "unknown feature",
            meta("inputs", "count,alpha_sum,nope,periphery,contrast,mean_r"),
            "`nope`",
        ),
        ("too few inputs", meta("inputs", "count"), "transforms"),
        (
            "bad transform",
            meta(
                "transforms",
                "log1p,identity,identity,identity,identity,cube",
            ),
            "`cube`",
        ),
        ("bad activation", meta("activation", "tanh"), "`tanh`"),
        ("bad target", meta("target", "everything"), "`everything`"),
        (
            "two outputs for one",
            meta("target", "kept_fraction"),
            "output",
        ),
        ("layer count", meta("layers", "2"), "layer"),
        ("layer count not a number", meta("layers", "many"), "layers"),
        (
            "missing entry",
            with_header(&good, |h| {
                h["__metadata__"].as_object_mut().unwrap().remove("target");
            }),
            "`target`",
        ),
        (
            "wrong dtype",
            with_header(&good, |h| h["layer0.bias"]["dtype"] = "I32".into()),
            "layer0.bias",
        ),
        (
            "shapes that do not chain",
            with_header(&good, |h| {
                // layer1 claims 3 inputs × 5 outputs instead of 5 × 3 (same byte count).
                h["layer1.weight"]["shape"] = serde_json::json!([5, 3]);
            }),
            "layer1",
        ),
    ];
    for (what, bytes, says) in cases {
        let err = LearnedModel::from_safetensors(&bytes).expect_err(what);
        let text = err.to_string();
        assert!(text.contains(says), "{what}: `{text}` does not say {says}");
    }
    // A non-finite weight.
    let mut m = model(Target::KeptFraction);
    m.layers[1].weight[2] = f32::NAN;
    let err = LearnedModel::from_safetensors(&m.to_safetensors()).unwrap_err();
    assert!(matches!(err, WeightsError::BadTensor { .. }), "{err}");
    // Through the method options: the file's name and the reason.
    let mut o = MethodOptions::default();
    let e = o
        .set("weights", Some("/no/such/weights.safetensors"))
        .unwrap_err();
    assert!(
        e.to_string().contains("/no/such/weights.safetensors"),
        "{e}"
    );
}

/// The counting pass's sums of a scene, and its frame values at half its fragments.
fn counted(s: &Scene) -> (FragmentCounts, FeatureAccumulator, FrameFeatures) {
    let (mut counts, mut sums) = (FragmentCounts::new(), FeatureAccumulator::new());
    counts.clear(s.width, s.height).expect("counts");
    sums.clear(s.width, s.height).expect("sums");
    let input = FrameInput::from_scene(s, 0);
    let total = Rasterizer::default()
        .prepare(&input)
        .rasterize(&mut FeatureCapture {
            counts: &mut counts,
            sums: &mut sums,
        })
        .fragments;
    let frame = FrameFeatures::of(&sums, total / 2, s.background);
    (counts, sums, frame)
}

#[test]
fn inference_is_the_one_pixel_evaluation_and_the_same_on_any_thread_count() {
    let s = scene("spheres", 160, 90);
    let (counts, sums, frame) = counted(&s);
    let counts = counts.counts();
    let n = counts.len();
    for target in [Target::KeptFraction, Target::ErrorCurve] {
        let m = model(target);
        let infer = |threads: usize| {
            let mut importance = vec![f32::NAN; n];
            let mut worth = vec![Worth::at_most_one(-1.0); n];
            pool(threads).install(|| m.infer(&sums, counts, &frame, &mut importance, &mut worth));
            (importance, worth)
        };
        let (importance, worth) = infer(1);
        let two = infer(2);
        assert_eq!((&importance, &worth), (&two.0, &two.1), "{target:?}");
        let mut decided = 0;
        for p in 0..n {
            let Some(one) = m.infer_pixel(&sums, counts, &frame, p) else {
                assert!(counts[p] < 2);
                assert_eq!(importance[p], 0.0, "{target:?} pixel {p} has no choice");
                continue;
            };
            decided += 1;
            // A pixel's result does not depend on its block or lane.
            assert_eq!(importance[p], one.importance, "{target:?} pixel {p}");
            if target == Target::ErrorCurve {
                assert_eq!(Some(worth[p]), one.worth, "pixel {p}");
            }
            // And it is the plain-arithmetic network's (the trainer's) up to the fast logarithms
            // and exponentials.
            let f = sums.pixel_features(counts, &frame, p % 160, p / 160);
            let y = m.predict(&f);
            let want = match target {
                Target::ErrorCurve => {
                    let (d, t) = curve(curve_base(&f), y[0], y[1]);
                    d * t
                }
                _ => target.importance(y[0], counts[p]),
            };
            let err = (one.importance - want).abs() / want.abs().max(1e-3);
            assert!(
                err < 1e-4,
                "{target:?} pixel {p}: {} vs {want}",
                one.importance
            );
        }
        assert!(decided > 1000, "{decided} pixels with a choice");
        // The pixels with one fragment keep the analytic model's contrast; with the error
        // curve every decided pixel has a falling worth.
        if target == Target::ErrorCurve {
            for p in 0..n {
                // Which pixels keep a fragment at all stays the analytic model's choice: every
                // covered pixel's contrast is that model's, to its bits.
                if counts[p] > 0 {
                    let analytic = Worth::contrast_of(sums.means(p, counts[p]).0, frame.background);
                    assert_eq!(worth[p].contrast.to_bits(), analytic.to_bits(), "pixel {p}");
                }
                match counts[p] {
                    0 => assert_eq!(worth[p], Worth::at_most_one(-1.0), "untouched"),
                    1 => assert_eq!(worth[p].log_fall, f64::NEG_INFINITY, "pixel {p}"),
                    _ => assert!(worth[p].log_fall < 0.0 && worth[p].log_first.is_finite()),
                }
            }
        }
    }
}

#[test]
fn a_network_of_zero_corrections_is_the_analytic_model() {
    // Zero weights and biases: d = d₀, t = t₀, the analytic model (up to its floors).
    let mut m = model(Target::ErrorCurve);
    for l in &mut m.layers {
        l.weight.fill(0.0);
        l.bias.fill(0.0);
    }
    let s = scene("mixed", 160, 90);
    let learned = render(
        &s,
        &MethodOptions {
            k_from: KFrom::Learned,
            weights: Some(Arc::new(m)),
            ..MethodOptions::default()
        },
        2,
    );
    let analytic = render(
        &s,
        &MethodOptions {
            k_from: KFrom::Analytic,
            ..MethodOptions::default()
        },
        2,
    );
    let differ = learned
        .k_map()
        .iter()
        .zip(analytic.k_map())
        .filter(|(a, b)| a != b)
        .count();
    let decided = learned.counts().iter().filter(|&&c| c > 1).count();
    assert!(
        differ * 100 <= decided,
        "{differ} of {decided} pixels differ from the analytic model"
    );
    assert_eq!(learned.allocation().sum, analytic.allocation().sum);
}
