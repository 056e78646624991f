//! The learned variable k-buffer: the shipped weights load and match the code's feature list;
//! malformed and mismatched weights are refused with a clear error; the block evaluation of the
//! importance pass equals the one-pixel reference; inference does not depend on the thread count.

use std::collections::BTreeMap;
use std::sync::Arc;

use strata_raster::{FrameInput, Rasterizer};
use strata_scene::{Scene, SearchPath, open_scene};
use strata_stores::kbuffer::VariableKBuffer;
use strata_stores::kbuffer::features::{FEATURE_COUNT, FEATURE_SET, FEATURES};
use strata_stores::kbuffer::learned::{
    Activation, Input, Layer, LearnedModel, Target, Transform, WEIGHTS_FORMAT, WeightsError,
};
use strata_stores::{Budget, KFrom, Method, MethodOptions, render_frame};

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

#[test]
fn inference_is_the_one_pixel_reference_and_the_same_on_any_thread_count() {
    let s = scene("spheres", 160, 90);
    for target in [Target::KeptFraction, Target::ErrorCurve] {
        let m = Arc::new(model(target));
        let options = MethodOptions {
            budget: Budget::SceneShare(0.5),
            k_from: KFrom::Learned,
            weights: Some(m.clone()),
            features: true,
            ..MethodOptions::default()
        };
        let one = render(&s, &options, 1);
        let two = render(&s, &options, 2);
        assert_eq!(one.importance_map(), two.importance_map(), "{target:?}");
        assert_eq!(one.k_map(), two.k_map(), "{target:?}");
        // The block evaluation equals the network run on each pixel's full feature vector.
        let maps = one.feature_maps().expect("features were asked for");
        let mut decided = 0;
        for (p, (&c, &imp)) in one.counts().iter().zip(one.importance_map()).enumerate() {
            if c < 2 {
                assert_eq!(imp, 0.0);
                continue;
            }
            decided += 1;
            let f: [f32; FEATURE_COUNT] = maps.pixel(p);
            let y = m.predict(&f);
            let want = match target {
                Target::ErrorCurve => {
                    let (d, t) = strata_stores::kbuffer::learned::curve(
                        strata_stores::kbuffer::learned::curve_base(&f),
                        y[0],
                        y[1],
                    );
                    d * t
                }
                _ => target.importance(y[0], c),
            };
            assert_eq!(imp, want, "{target:?} pixel {p}");
        }
        assert!(decided > 1000, "{decided} pixels with a choice");
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
