//! Training a learned importance model ([`LearnedModel`]) on a dataset written by
//! [`crate::Dataset::write`]: a hand-written multilayer perceptron trainer (backpropagation,
//! Adam or plain SGD, mean squared error or cross-entropy), reproducible from a seed.
//!
//! # Why not a framework
//!
//! The models are tiny (hundreds to ten thousand parameters) and the inference is hand-written
//! anyway (it is the frame's hot path, [`strata_stores::kbuffer::learned`]). candle 0.11 would
//! add about 4 min 21 s to a cold release build on 2 cores (measured 2026-12-01 for the reading
//! notes), and its forward pass was 3–4× slower than a hand-written one on these shapes. The
//! trainer shares the model type, and so the exact forward arithmetic, with inference.
//!
//! # Data flow
//!
//! ```text
//! TrainingData::load(dir)      features [rows × F] f32, labels [rows × 3], frame, scene, families
//!   → rows(): decision pixels (count ≥ 2), families held out, a seeded subsample
//!   → split by view: every (scene, view) whose hash with the seed is 0 mod 10 validates (all
//!     its budgets' frames), the rest train
//!   → normalise: per-input mean and 1/std of the transformed feature over the training rows
//!   → epochs: seeded shuffle, mini-batches; each batch's gradient is the sum of GRAD_PARTS fixed
//!     parts, computed in parallel and added in order, so a run is bit-identical on any number of
//!     threads
//!   → the weights of the epoch with the lowest validation loss
//! ```

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use strata_core::npy::{self, NpyValues};
use strata_stores::kbuffer::features::{FEATURE_COUNT, FEATURE_SET, feature_index};
use strata_stores::kbuffer::learned::{
    Activation, Input, Layer, LearnedModel, Target, Transform, curve, curve_base, sigmoid,
};

use crate::dataset::{CURVE_LEN, DATASET_FORMAT, LABELS, fnv1a64_hex};
use crate::procedural::{Rng, mix};

/// Parts a mini-batch's gradient is split into (fixed, so the sum's order never changes).
const GRAD_PARTS: usize = 4;

/// Why training could not start.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A file could not be read.
    #[error("cannot read {path}: {reason}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The dataset is not what `strata dataset` writes.
    #[error("{path} is not a strata dataset: {reason}")]
    Dataset {
        /// The dataset directory.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Nothing left to train on.
    #[error("no rows to train on: {0}")]
    NoRows(String),
    /// A bad model or training option.
    #[error("{0}")]
    Option(String),
}

/// A dataset in memory.
#[derive(Clone, Debug)]
pub struct TrainingData {
    /// `rows × FEATURE_COUNT` features.
    pub features: Vec<f32>,
    /// `rows × LABELS.len()` labels.
    pub labels: Vec<f32>,
    /// Each row's frame id.
    pub frame: Vec<u32>,
    /// Each row's scene id.
    pub scene: Vec<u32>,
    /// Each scene's name.
    pub scene_names: Vec<String>,
    /// Each scene's family.
    pub families: Vec<String>,
    /// Each frame's view (its camera within its scene); frames of one view at several budgets
    /// share it, so the split keeps them together.
    pub frame_views: Vec<u32>,
    /// FNV-1a 64 of `manifest.json`, for the weights' metadata.
    pub manifest_hash: String,
}

impl TrainingData {
    /// Reads a dataset directory written by `strata dataset`, checking its format, feature set
    /// and array shapes.
    pub fn load(dir: &Path) -> Result<Self, TrainError> {
        let bad = |reason: String| TrainError::Dataset {
            path: dir.to_owned(),
            reason,
        };
        let manifest_path = dir.join("manifest.json");
        let text = std::fs::read(&manifest_path).map_err(|e| TrainError::Read {
            path: manifest_path.clone(),
            reason: e.to_string(),
        })?;
        let manifest: serde_json::Value = serde_json::from_slice(&text)
            .map_err(|e| bad(format!("manifest.json is not JSON: {e}")))?;
        let field = |k: &str| manifest.get(k).and_then(|v| v.as_str()).unwrap_or("");
        if field("format") != DATASET_FORMAT {
            return Err(bad(format!(
                "format `{}`, expected `{DATASET_FORMAT}`",
                field("format")
            )));
        }
        if field("feature_set") != FEATURE_SET {
            return Err(bad(format!(
                "its features are `{}`, but this build computes `{FEATURE_SET}`; make it again with `strata dataset`",
                field("feature_set")
            )));
        }
        let mut scene_names = Vec::new();
        let mut families = Vec::new();
        for s in manifest
            .get("scenes")
            .and_then(|v| v.as_array())
            .ok_or_else(|| bad("manifest.json has no `scenes`".into()))?
        {
            scene_names.push(
                s.get("name")
                    .and_then(|v| v.as_str())
                    .unwrap_or("")
                    .to_owned(),
            );
            families.push(
                s.get("family")
                    .and_then(|v| v.as_str())
                    .unwrap_or("")
                    .to_owned(),
            );
        }
        let mut frame_views = Vec::new();
        for (i, f) in manifest
            .get("frames")
            .and_then(|v| v.as_array())
            .ok_or_else(|| bad("manifest.json has no `frames`".into()))?
            .iter()
            .enumerate()
        {
            let id = f.get("id").and_then(|v| v.as_u64());
            let view = f.get("view").and_then(|v| v.as_u64());
            match (id, view) {
                (Some(id), Some(view)) if id == i as u64 => frame_views.push(view as u32),
                _ => {
                    return Err(bad(format!(
                        "frame {i} of manifest.json has no id {i} or no view"
                    )));
                }
            }
        }
        let read = |name: &str| {
            let path = dir.join(name);
            npy::read(&path).map_err(|e| TrainError::Read {
                path,
                reason: e.to_string(),
            })
        };
        let f32s = |name: &str, cols: usize| -> Result<Vec<f32>, TrainError> {
            let a = read(name)?;
            match a.values {
                NpyValues::F32(v) if a.shape.len() == 2 && a.shape[1] == cols => Ok(v),
                _ => Err(bad(format!(
                    "{name} has shape {:?}, expected float32 [rows, {cols}]",
                    a.shape
                ))),
            }
        };
        let u32s = |name: &str| -> Result<Vec<u32>, TrainError> {
            let a = read(name)?;
            match a.values {
                NpyValues::U32(v) if a.shape.len() == 1 => Ok(v),
                _ => Err(bad(format!(
                    "{name} has shape {:?}, expected uint32 [rows]",
                    a.shape
                ))),
            }
        };
        let features = f32s("features.npy", FEATURE_COUNT)?;
        let labels = f32s("labels.npy", LABELS.len())?;
        let frame = u32s("frame.npy")?;
        let scene = u32s("scene.npy")?;
        let rows = frame.len();
        if features.len() != rows * FEATURE_COUNT
            || labels.len() != rows * LABELS.len()
            || scene.len() != rows
        {
            return Err(bad("the arrays disagree on the number of rows".into()));
        }
        if let Some(&s) = scene.iter().find(|&&s| s as usize >= families.len()) {
            return Err(bad(format!("scene id {s} is not in the manifest")));
        }
        if let Some(&f) = frame.iter().find(|&&f| f as usize >= frame_views.len()) {
            return Err(bad(format!("frame id {f} is not in the manifest")));
        }
        if let Some(i) = features.iter().chain(&labels).position(|v| !v.is_finite()) {
            let (file, at) = if i < features.len() {
                ("features.npy", i)
            } else {
                ("labels.npy", i - features.len())
            };
            return Err(bad(format!(
                "{file} holds a non-finite value (element {at})"
            )));
        }
        Ok(TrainingData {
            features,
            labels,
            frame,
            scene,
            scene_names,
            families,
            frame_views,
            manifest_hash: fnv1a64_hex(&text),
        })
    }

    /// Rows in the dataset.
    pub fn len(&self) -> usize {
        self.frame.len()
    }

    /// Whether it has no rows.
    pub fn is_empty(&self) -> bool {
        self.frame.is_empty()
    }

    /// The features of row `r`.
    pub fn row(&self, r: usize) -> &[f32; FEATURE_COUNT] {
        self.features[r * FEATURE_COUNT..(r + 1) * FEATURE_COUNT]
            .try_into()
            .expect("FEATURE_COUNT values")
    }

    /// The family of row `r`.
    pub fn family(&self, r: usize) -> &str {
        &self.families[self.scene[r] as usize]
    }

    /// Label column `name` of row `r` (0 for a name that is not a column).
    pub fn label(&self, r: usize, name: &str) -> f32 {
        LABELS
            .iter()
            .position(|&l| l == name)
            .map_or(0.0, |col| self.labels[r * LABELS.len() + col])
    }

    /// The truncation-error curve `e(1) … e(CURVE_LEN)` of row `r`.
    pub fn curve(&self, r: usize) -> &[f32] {
        &self.labels[r * LABELS.len() + 3..(r + 1) * LABELS.len()]
    }
}

/// The shape of a model to train.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelSpec {
    /// Input features and their transforms.
    pub inputs: Vec<(usize, Transform)>,
    /// Hidden layer widths.
    pub hidden: Vec<usize>,
    /// Hidden activation.
    pub activation: Activation,
    /// What the output predicts.
    pub target: Target,
}

/// The model presets of `strata learn train --model`.
pub const PRESETS: [&str; 4] = ["curve", "fraction", "seed", "seed-literal"];

impl ModelSpec {
    /// Replaces the inputs with the features called `names`, transformed as the presets do
    /// (`log1p` for the counts and sums of many fragments).
    pub fn with_inputs(mut self, names: &[&str]) -> Result<ModelSpec, TrainError> {
        self.inputs = names
            .iter()
            .map(|n| {
                let f = feature_index(n.trim()).ok_or_else(|| {
                    TrainError::Option(format!("`{n}` is not a feature of {FEATURE_SET}"))
                })?;
                Ok((f, default_transform(f)))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut seen = std::collections::HashSet::new();
        if let Some((f, _)) = self.inputs.iter().find(|(f, _)| !seen.insert(*f)) {
            return Err(TrainError::Option(format!(
                "`{}` is named twice in the inputs",
                strata_stores::kbuffer::features::FEATURES[*f].name
            )));
        }
        if self.inputs.is_empty() {
            return Err(TrainError::Option(
                "a model needs at least one input".into(),
            ));
        }
        Ok(self)
    }

    /// A preset: `curve` (strata's: 20 inputs, 8 ReLU, corrections of the analytic error curve;
    /// the budget is no input), `fraction` (22 inputs with the budget, 16-8 ReLU, on the kept
    /// fraction), `seed` (the thesis's
    /// 12 features and 12-128-64-1 ReLU network, on the kept fraction) or `seed-literal` (the
    /// same network on the thesis's own label, `k_opt / N`).
    pub fn preset(name: &str) -> Option<ModelSpec> {
        let seed_inputs = || (0..12).map(|f| (f, Transform::Identity)).collect();
        match name {
            "curve" | "fraction" => {
                // The error curve is the same at every budget: the budget is no input of it.
                let mut skip = vec!["count_share", "scene_depth_min", "scene_depth_max"];
                if name == "curve" {
                    skip.extend(["budget_share", "budget_per_covered"]);
                }
                let skip: Vec<usize> = skip.iter().filter_map(|n| feature_index(n)).collect();
                let inputs = (0..FEATURE_COUNT)
                    .filter(|f| !skip.contains(f))
                    .map(|f| (f, default_transform(f)))
                    .collect();
                Some(ModelSpec {
                    inputs,
                    hidden: if name == "curve" {
                        vec![8]
                    } else {
                        vec![16, 8]
                    },
                    activation: Activation::Relu,
                    target: if name == "curve" {
                        Target::ErrorCurve
                    } else {
                        Target::KeptFraction
                    },
                })
            }
            "seed" => Some(ModelSpec {
                inputs: seed_inputs(),
                hidden: vec![128, 64],
                activation: Activation::Relu,
                target: Target::KeptFraction,
            }),
            "seed-literal" => Some(ModelSpec {
                inputs: seed_inputs(),
                hidden: vec![128, 64],
                activation: Activation::Relu,
                target: Target::SeedLabel,
            }),
            _ => None,
        }
    }
}

/// `log1p` for the features that count fragments or sum over them (long tails), identity for
/// the rest.
pub fn default_transform(feature: usize) -> Transform {
    const LOG: [&str; 6] = [
        "count",
        "budget_per_covered",
        "alpha_sum",
        "opaque_count",
        "count_mean_3x3",
        "count_max_3x3",
    ];
    if LOG.iter().any(|n| feature_index(n) == Some(feature)) {
        Transform::Log1p
    } else {
        Transform::Identity
    }
}

/// The optimiser.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Optimizer {
    /// Adam (β₁ 0.9, β₂ 0.999, ε 1e-8).
    Adam,
    /// Plain stochastic gradient descent, no momentum (the thesis's).
    Sgd,
}

/// The loss.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Loss {
    /// Mean squared error of the sigmoid output (the thesis's).
    Mse,
    /// Binary cross-entropy of the sigmoid output against a label in [0, 1].
    CrossEntropy,
}

/// How to train.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainConfig {
    /// Passes over the training rows.
    pub epochs: usize,
    /// Rows per mini-batch.
    pub batch: usize,
    /// Learning rate.
    pub learning_rate: f32,
    /// The optimiser.
    pub optimizer: Optimizer,
    /// The loss.
    pub loss: Loss,
    /// L1 penalty per hidden layer (missing entries are 0).
    pub l1: Vec<f32>,
    /// L2 penalty per hidden layer (missing entries are 0).
    pub l2: Vec<f32>,
    /// Seeds the initial weights, the subsample, the split and the shuffles.
    pub seed: u64,
    /// Train on at most this many rows (a seeded sample); `None` uses all.
    pub max_rows: Option<usize>,
    /// Families left out of training.
    pub exclude_families: Vec<String>,
}

impl TrainConfig {
    /// strata's defaults: Adam 3e-3, cross-entropy, batch 256, 12 epochs, no penalties.
    pub fn strata(seed: u64) -> Self {
        TrainConfig {
            epochs: 12,
            batch: 256,
            learning_rate: 3e-3,
            optimizer: Optimizer::Adam,
            loss: Loss::CrossEntropy,
            l1: Vec::new(),
            l2: Vec::new(),
            seed,
            max_rows: Some(400_000),
            exclude_families: Vec::new(),
        }
    }

    /// The thesis's recipe as written (§4.3): SGD 0.001, MSE, batch 512, L1 0.3 on the first
    /// hidden layer and L2 0.35 on the second.
    pub fn seed_literal(seed: u64) -> Self {
        TrainConfig {
            epochs: 4,
            batch: 512,
            learning_rate: 1e-3,
            optimizer: Optimizer::Sgd,
            loss: Loss::Mse,
            l1: vec![0.3],
            l2: vec![0.0, 0.35],
            seed,
            max_rows: Some(100_000),
            exclude_families: Vec::new(),
        }
    }
}

/// One epoch's losses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpochReport {
    /// 1-based.
    pub epoch: usize,
    /// Mean data loss over the training rows (penalties not included).
    pub train_loss: f64,
    /// Mean data loss over the validation rows.
    pub validation_loss: f64,
}

/// What a training run did.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainReport {
    /// Rows trained on.
    pub train_rows: usize,
    /// Rows validated on.
    pub validation_rows: usize,
    /// Every epoch.
    pub epochs: Vec<EpochReport>,
    /// The epoch whose weights were kept (lowest validation loss).
    pub best_epoch: usize,
}

/// The rows a run uses: decision pixels (count ≥ 2) of families not held out, a seeded sample
/// of at most `max_rows`, split into (train, validation) by view: all the frames of one view of
/// one scene (one per budget, holding the same pixels) fall on the same side.
pub fn split_rows(data: &TrainingData, config: &TrainConfig) -> (Vec<usize>, Vec<usize>) {
    let count = feature_index("count").expect("count is a feature");
    let mut rows: Vec<usize> = (0..data.len())
        .filter(|&r| data.row(r)[count] >= 2.0)
        .filter(|&r| !config.exclude_families.iter().any(|f| f == data.family(r)))
        .collect();
    if let Some(max) = config.max_rows
        && rows.len() > max
    {
        let key = |r: usize| mix(config.seed ^ mix(r as u64 ^ 0x726f_7773));
        rows.sort_by_key(|&r| key(r));
        rows.truncate(max);
        rows.sort_unstable();
    }
    rows.into_iter().partition(|&r| {
        let view = u64::from(data.frame_views[data.frame[r] as usize]);
        let scene = u64::from(data.scene[r]);
        !mix(config.seed.wrapping_mul(31) ^ mix((scene << 32 | view) ^ 0x7661_6c69))
            .is_multiple_of(10)
    })
}

/// Trains a model of shape `spec` on `data`; `progress` sees each epoch. See the module docs.
pub fn train(
    data: &TrainingData,
    spec: &ModelSpec,
    config: &TrainConfig,
    mut progress: impl FnMut(&EpochReport),
) -> Result<(LearnedModel, TrainReport), TrainError> {
    if spec.inputs.is_empty() {
        return Err(TrainError::Option(
            "a model needs at least one input".into(),
        ));
    }
    if config.batch == 0 || config.epochs == 0 {
        return Err(TrainError::Option(
            "batch and epochs must be at least 1".into(),
        ));
    }
    if !(config.learning_rate > 0.0 && config.learning_rate.is_finite()) {
        return Err(TrainError::Option(
            "the learning rate must be positive".into(),
        ));
    }
    let (train_rows, mut val_rows) = split_rows(data, config);
    if train_rows.is_empty() {
        return Err(TrainError::NoRows(format!(
            "{} rows, none with two or more fragments outside the held-out families {:?}",
            data.len(),
            config.exclude_families
        )));
    }
    if val_rows.is_empty() {
        val_rows = train_rows.clone();
    }
    let mut model = init_model(data, &train_rows, spec, config.seed);
    let mut adam = AdamState::new(&model);
    let mut rng = Rng::new(mix(config.seed ^ 0x7368_7566));
    let mut order = train_rows.clone();
    let mut best = (f64::INFINITY, model.clone(), 0);
    let mut epochs = Vec::new();
    let mut grads = Grads::zeros(&model);
    for epoch in 1..=config.epochs {
        for i in (1..order.len()).rev() {
            order.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
        }
        let mut train_loss = 0.0;
        for batch in order.chunks(config.batch) {
            let part = batch.len().div_ceil(GRAD_PARTS);
            let parts: Vec<(Grads, f64)> = batch
                .par_chunks(part)
                .map(|rows| {
                    let mut g = Grads::zeros(&model);
                    let mut scratch = Scratch::new(&model);
                    let mut loss = 0.0;
                    for &r in rows {
                        loss += backprop(&model, data, r, config.loss, &mut scratch, &mut g);
                    }
                    (g, loss)
                })
                .collect();
            grads.clear();
            for (g, loss) in &parts {
                grads.add(g);
                train_loss += loss;
            }
            let scale = 1.0 / batch.len() as f32;
            step(&mut model, &mut adam, &grads, scale, config);
        }
        let report = EpochReport {
            epoch,
            train_loss: train_loss / order.len() as f64,
            validation_loss: mean_loss(&model, data, &val_rows, config.loss),
        };
        progress(&report);
        if report.validation_loss < best.0 {
            best = (report.validation_loss, model.clone(), epoch);
        }
        epochs.push(report);
    }
    let (_, model, best_epoch) = best;
    if best_epoch == 0 {
        return Err(TrainError::Option(
            "the validation loss was never finite: lower the learning rate".into(),
        ));
    }
    Ok((
        model,
        TrainReport {
            train_rows: train_rows.len(),
            validation_rows: val_rows.len(),
            epochs,
            best_epoch,
        },
    ))
}

/// Mean data loss of `model` over `rows`.
pub fn mean_loss(model: &LearnedModel, data: &TrainingData, rows: &[usize], loss: Loss) -> f64 {
    if rows.is_empty() {
        return 0.0;
    }
    let sum: f64 = rows
        .par_chunks(4096)
        .map(|rows| {
            rows.iter()
                .map(|&r| {
                    let y = model.predict(data.row(r));
                    output_loss(model.target, data, r, y, loss).0
                })
                .sum::<f64>()
        })
        .collect::<Vec<_>>()
        .iter()
        .sum();
    sum / rows.len() as f64
}

/// The loss of row `r`'s outputs `y` (the second unused for one-output targets), and its
/// derivatives with respect to the outputs' pre-activations. For the kept fraction and the
/// seed's label: `loss` of the sigmoid output against the label. For the error curve: the
/// squared error of `ê(k) = d · t^k` against the row's `e(k)` summed over the `k` the pixel can
/// choose (`1 … min(count − 1, CURVE_LEN)`), whatever `loss` says.
fn output_loss(
    target: Target,
    data: &TrainingData,
    r: usize,
    y: [f32; 2],
    loss: Loss,
) -> (f64, [f32; 2]) {
    if target == Target::ErrorCurve {
        let f = data.row(r);
        let (d, t) = curve(curve_base(f), y[0], y[1]);
        let points = (f[12] as usize).saturating_sub(1).min(CURVE_LEN);
        let (mut l, mut da, mut db) = (0.0f64, 0.0f32, 0.0f32);
        let mut tk = 1.0f32;
        for (k, &e) in data.curve(r)[..points].iter().enumerate() {
            tk *= t;
            let e_hat = d * tk;
            let diff = e_hat - e;
            l += f64::from(diff * diff);
            da += 2.0 * diff * e_hat;
            db += 2.0 * diff * e_hat * (k + 1) as f32 * (1.0 - t);
        }
        return (l, [da, db]);
    }
    let (y, label) = (y[0], data.label(r, target.name()));
    let (y64, t) = (f64::from(y), f64::from(label));
    match loss {
        Loss::Mse => ((y64 - t).powi(2), [2.0 * (y - label) * y * (1.0 - y), 0.0]),
        Loss::CrossEntropy => {
            let e = 1e-7;
            let l = -(t * (y64 + e).ln() + (1.0 - t) * (1.0 - y64 + e).ln());
            (l, [y - label, 0.0])
        }
    }
}

/// A model with normalisation from `rows` and seeded initial weights (He-uniform for ReLU,
/// Glorot-uniform for sigmoid layers), zero biases.
fn init_model(data: &TrainingData, rows: &[usize], spec: &ModelSpec, seed: u64) -> LearnedModel {
    let inputs = spec
        .inputs
        .iter()
        .map(|&(feature, transform)| {
            let (mut s, mut s2) = (0.0f64, 0.0f64);
            for &r in rows {
                let x = f64::from(transform.apply(data.row(r)[feature]));
                s += x;
                s2 += x * x;
            }
            let n = rows.len().max(1) as f64;
            let mean = s / n;
            let var = (s2 / n - mean * mean).max(0.0);
            let scale = if var > 1e-12 { 1.0 / var.sqrt() } else { 1.0 };
            Input {
                feature,
                transform,
                mean: mean as f32,
                scale: scale as f32,
            }
        })
        .collect::<Vec<_>>();
    let mut rng = Rng::new(mix(seed ^ 0x696e_6974));
    let mut width = inputs.len();
    let mut layers = Vec::new();
    let outputs = spec.target.outputs();
    for (i, &out) in spec.hidden.iter().chain(&[outputs]).enumerate() {
        let mut l = Layer::zeros(width, out);
        let relu = i < spec.hidden.len() && spec.activation == Activation::Relu;
        let limit = if relu {
            (6.0 / width as f32).sqrt()
        } else if i == spec.hidden.len() && spec.target == Target::ErrorCurve {
            // Start close to the analytic model (zero corrections).
            0.1 * (6.0 / (width + out) as f32).sqrt()
        } else {
            (6.0 / (width + out) as f32).sqrt()
        };
        for w in &mut l.weight {
            *w = rng.range(-limit, limit);
        }
        layers.push(l);
        width = out;
    }
    LearnedModel {
        inputs,
        layers,
        activation: spec.activation,
        target: spec.target,
        info: Default::default(),
    }
}

/// Gradients (or Adam moments) shaped like a model's layers.
#[derive(Clone, Debug)]
struct Grads {
    layers: Vec<(Vec<f32>, Vec<f32>)>,
}

impl Grads {
    fn zeros(model: &LearnedModel) -> Self {
        Grads {
            layers: model
                .layers
                .iter()
                .map(|l| (vec![0.0; l.weight.len()], vec![0.0; l.bias.len()]))
                .collect(),
        }
    }

    fn clear(&mut self) {
        for (w, b) in &mut self.layers {
            w.fill(0.0);
            b.fill(0.0);
        }
    }

    fn add(&mut self, other: &Grads) {
        for ((w, b), (ow, ob)) in self.layers.iter_mut().zip(&other.layers) {
            w.iter_mut().zip(ow).for_each(|(a, b)| *a += b);
            b.iter_mut().zip(ob).for_each(|(a, b)| *a += b);
        }
    }
}

/// Per-row activations and deltas.
struct Scratch {
    /// `acts[0]` the inputs, `acts[i + 1]` layer i's outputs.
    acts: Vec<Vec<f32>>,
    delta: Vec<f32>,
    next: Vec<f32>,
}

impl Scratch {
    fn new(model: &LearnedModel) -> Self {
        let mut acts = vec![vec![0.0; model.inputs.len()]];
        acts.extend(model.layers.iter().map(|l| vec![0.0; l.outputs]));
        let w = model.width();
        Scratch {
            acts,
            delta: vec![0.0; w],
            next: vec![0.0; w],
        }
    }
}

/// Forward and backward for row `r`, adding its gradient into `g`; returns its data loss.
fn backprop(
    model: &LearnedModel,
    data: &TrainingData,
    r: usize,
    loss: Loss,
    s: &mut Scratch,
    g: &mut Grads,
) -> f64 {
    let f = data.row(r);
    for (x, input) in s.acts[0].iter_mut().zip(&model.inputs) {
        *x = input.normalise(f[input.feature]);
    }
    let last = model.layers.len() - 1;
    for (li, l) in model.layers.iter().enumerate() {
        let (before, after) = s.acts.split_at_mut(li + 1);
        let (x, y) = (&before[li], &mut after[0]);
        for (o, y) in y.iter_mut().enumerate() {
            let row = &l.weight[o * l.inputs..(o + 1) * l.inputs];
            let z = row
                .iter()
                .zip(x.iter())
                .fold(l.bias[o], |a, (w, x)| a + w * x);
            *y = if li < last {
                model.activation.apply(z)
            } else if model.target.sigmoid() {
                sigmoid(z)
            } else {
                z
            };
        }
    }
    let out = &s.acts[last + 1];
    let y = [out[0], out.get(1).copied().unwrap_or(0.0)];
    let (l, dz) = output_loss(model.target, data, r, y, loss);
    s.delta[..out.len()].copy_from_slice(&dz[..out.len()]);
    for li in (0..=last).rev() {
        let layer = &model.layers[li];
        let x = &s.acts[li];
        let (gw, gb) = &mut g.layers[li];
        s.next[..layer.inputs].fill(0.0);
        for o in 0..layer.outputs {
            let d = s.delta[o];
            gb[o] += d;
            let row = &layer.weight[o * layer.inputs..(o + 1) * layer.inputs];
            let grow = &mut gw[o * layer.inputs..(o + 1) * layer.inputs];
            for i in 0..layer.inputs {
                grow[i] += d * x[i];
                s.next[i] += d * row[i];
            }
        }
        if li > 0 {
            // Through the hidden activation of layer li − 1, whose outputs are x.
            for ((delta, &next), &a) in s.delta.iter_mut().zip(&s.next).zip(x.iter()) {
                let da = match model.activation {
                    Activation::Relu => f32::from(a > 0.0),
                    Activation::Sigmoid => a * (1.0 - a),
                };
                *delta = next * da;
            }
        }
    }
    l
}

/// Adam's moments and step count.
struct AdamState {
    m: Grads,
    v: Grads,
    t: i32,
}

impl AdamState {
    fn new(model: &LearnedModel) -> Self {
        AdamState {
            m: Grads::zeros(model),
            v: Grads::zeros(model),
            t: 0,
        }
    }
}

/// One optimiser step with the batch gradient `grads · scale`, plus the penalties.
fn step(
    model: &mut LearnedModel,
    adam: &mut AdamState,
    grads: &Grads,
    scale: f32,
    config: &TrainConfig,
) {
    adam.t += 1;
    let (b1, b2, eps) = (0.9f32, 0.999f32, 1e-8f32);
    let c1 = 1.0 - b1.powi(adam.t);
    let c2 = 1.0 - b2.powi(adam.t);
    let lr = config.learning_rate;
    let hidden = model.layers.len() - 1;
    for (li, layer) in model.layers.iter_mut().enumerate() {
        let l1 = if li < hidden {
            config.l1.get(li).copied().unwrap_or(0.0)
        } else {
            0.0
        };
        let l2 = if li < hidden {
            config.l2.get(li).copied().unwrap_or(0.0)
        } else {
            0.0
        };
        let (gw, gb) = &grads.layers[li];
        let (mw, mb) = &mut adam.m.layers[li];
        let (vw, vb) = &mut adam.v.layers[li];
        let params = layer
            .weight
            .iter_mut()
            .zip(gw)
            .zip(mw.iter_mut().zip(vw.iter_mut()));
        let biases = layer
            .bias
            .iter_mut()
            .zip(gb)
            .zip(mb.iter_mut().zip(vb.iter_mut()));
        for (is_weight, ((p, &g), (m, v))) in
            params.map(|x| (true, x)).chain(biases.map(|x| (false, x)))
        {
            let mut g = g * scale;
            if is_weight {
                g += l1 * p.signum() + 2.0 * l2 * *p;
            }
            match config.optimizer {
                Optimizer::Sgd => *p -= lr * g,
                Optimizer::Adam => {
                    *m = b1 * *m + (1.0 - b1) * g;
                    *v = b2 * *v + (1.0 - b2) * g * g;
                    *p -= lr * (*m / c1) / ((*v / c2).sqrt() + eps);
                }
            }
        }
    }
}

/// Fills `model.info` with what a weights file should say about how it was made.
pub fn describe(
    model: &mut LearnedModel,
    data: &TrainingData,
    config: &TrainConfig,
    report: &TrainReport,
    command: &str,
) {
    let mut trained: Vec<&str> = data
        .families
        .iter()
        .map(String::as_str)
        .filter(|f| !config.exclude_families.iter().any(|e| e == f))
        .collect();
    trained.sort_unstable();
    trained.dedup();
    for (k, v) in [
        ("training_command", command.to_owned()),
        ("dataset_manifest_fnv1a64", data.manifest_hash.clone()),
        ("trained_families", trained.join(",")),
        ("held_out_families", config.exclude_families.join(",")),
        ("seed", config.seed.to_string()),
        ("train_rows", report.train_rows.to_string()),
        ("validation_rows", report.validation_rows.to_string()),
        ("best_epoch", report.best_epoch.to_string()),
        (
            "validation_loss",
            report
                .epochs
                .get(report.best_epoch.saturating_sub(1))
                .map_or(String::new(), |e| format!("{:.6}", e.validation_loss)),
        ),
    ] {
        model.info.insert(k.to_owned(), v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two rows of made-up features and labels: a deep pixel and a shallow one.
    fn data() -> TrainingData {
        let mut features = vec![0.0f32; 2 * FEATURE_COUNT];
        for (r, row) in features.chunks_mut(FEATURE_COUNT).enumerate() {
            for (i, v) in row.iter_mut().enumerate() {
                *v = 0.1 + 0.37 * ((i * 7 + r * 3) % 11) as f32 / 11.0;
            }
            row[12] = [9.0, 3.0][r]; // count
            row[14] = [4.5, 1.2][r]; // alpha sum
            row[23] = [0.6, 0.3][r]; // contrast
        }
        let mut labels = vec![0.0f32; 2 * LABELS.len()];
        for (r, row) in labels.chunks_mut(LABELS.len()).enumerate() {
            row[1] = [0.4, 1.0][r]; // kept fraction
            for (k, e) in row[3..].iter_mut().enumerate() {
                *e = [0.5, 0.2][r] * 0.6f32.powi(k as i32 + 1);
            }
        }
        TrainingData {
            features,
            labels,
            frame: vec![0, 0],
            scene: vec![0, 0],
            scene_names: vec!["test".into()],
            families: vec!["test".into()],
            frame_views: vec![0],
            manifest_hash: String::new(),
        }
    }

    /// Backpropagation's gradient equals central finite differences of the loss, for every
    /// parameter of a small network, for the error curve and the kept fraction.
    #[test]
    fn gradients_match_finite_differences() {
        let data = data();
        for (preset, loss) in [("curve", Loss::Mse), ("fraction", Loss::CrossEntropy)] {
            let mut spec = ModelSpec::preset(preset).unwrap();
            spec.hidden = vec![5];
            let mut model = init_model(&data, &[0, 1], &spec, 3);
            // Non-zero output biases, so every path carries gradient; one hidden unit switched
            // off (ReLU at 0), whose weights must then get no gradient.
            for (i, b) in model.layers[1].bias.iter_mut().enumerate() {
                *b = 0.1 * (i as f32 + 1.0);
            }
            model.layers[0].bias[0] = -50.0;
            let loss_of = |m: &LearnedModel| -> f64 {
                (0..2)
                    .map(|r| output_loss(m.target, &data, r, m.predict(data.row(r)), loss).0)
                    .sum()
            };
            let mut grads = Grads::zeros(&model);
            let mut scratch = Scratch::new(&model);
            for r in 0..2 {
                backprop(&model, &data, r, loss, &mut scratch, &mut grads);
            }
            let h = 1e-3f32;
            for li in 0..model.layers.len() {
                let n = model.layers[li].weight.len() + model.layers[li].bias.len();
                for j in 0..n {
                    let mut plus = model.clone();
                    let mut minus = model.clone();
                    let set = |m: &mut LearnedModel, d: f32| {
                        let l = &mut m.layers[li];
                        let nw = l.weight.len();
                        if j < nw {
                            l.weight[j] += d;
                        } else {
                            l.bias[j - nw] += d;
                        }
                    };
                    set(&mut plus, h);
                    set(&mut minus, -h);
                    let numeric = (loss_of(&plus) - loss_of(&minus)) / (2.0 * f64::from(h));
                    let (gw, gb) = &grads.layers[li];
                    let nw = gw.len();
                    let analytic = f64::from(if j < nw { gw[j] } else { gb[j - nw] });
                    let tolerance = 1e-2 * numeric.abs().max(analytic.abs()).max(1e-3);
                    assert!(
                        (numeric - analytic).abs() <= tolerance,
                        "{preset}: layer {li} parameter {j}: backprop {analytic}, finite differences {numeric}"
                    );
                }
            }
        }
    }
}
