//! A learned k for the variable k-buffer (Tsopouridis 2021 ch. 4): a small multilayer perceptron
//! over each pixel's features ([`super::features`]). strata's model (target `error_curve`)
//! corrects the analytic model's truncation-error curve, whose worths the analytic allocator
//! ([`super::analytic`]) water-fills; the thesis's kind of model (targets `kept_fraction`,
//! `seed_label`) gives an importance that the importance allocator ([`super::allocate`]) shares
//! out. Either way `Σk = min(M, N)` and `k(p) ≤ count(p)` hold whatever the network says.
//!
//! # The model
//!
//! ```text
//! x_i  = (t_i(feature[input_i]) − mean_i) · scale_i       t_i: identity or ln(1 + x)
//! h_1  = act(W_1 x + b_1)   …   h_L−1 = act(W_L−1 h_L−2 + b_L−1)     act: ReLU or sigmoid
//! error_curve:   (a, b) = W_L h_L−1 + b_L;  d = d₀ e^a,  t = σ(logit t₀ + b);  ê(k) = d t^k
//!                (d₀ = contrast, t₀ = 1 − mean α: the analytic model; see [`curve`])
//! kept_fraction: y = σ(W_L h_L−1 + b_L) predicts (k_opt − 1)/(count − 1);  I(p) = y (count − 1)
//! seed_label:    y = σ(…) predicts k_opt / N (the thesis's label);  I(p) = y
//! ```
//!
//! With the kept fraction, a perfect prediction gives back the Optimal-K oracle's `k` through the
//! allocator (its water level is then 1); with the error curve, a perfect curve gives back the
//! oracle's greedy choice. Only pixels with a choice to make are evaluated: a pixel with fewer
//! than two fragments has no headroom.
//!
//! # The weights file
//!
//! A [safetensors](https://huggingface.co/docs/safetensors) file, all tensors `F32`:
//!
//! | tensor | shape | holds |
//! | --- | --- | --- |
//! | `input.mean`, `input.scale` | `[inputs]` | the normalisation of each input |
//! | `layer{i}.weight` | `[outputs, inputs]` | layer `i`'s weights, row-major |
//! | `layer{i}.bias` | `[outputs]` | its biases |
//!
//! and string metadata: `format` ([`WEIGHTS_FORMAT`]), `feature_set` (must equal
//! [`super::FEATURE_SET`]), `inputs` (feature names, comma-separated, in input order),
//! `transforms` (`identity` or `log1p` per input), `activation` (`relu` or `sigmoid`), `target`
//! (`error_curve`, `kept_fraction` or `seed_label`), `layers` (how many). Anything else in the metadata (the
//! training command, the dataset's hash, the families trained on) is kept and shown, not checked.
//!
//! # Inference
//!
//! [`LearnedModel::infer`] is the frame's importance pass, in [`super::inference`]: the
//! decision pixels (count ≥ 2) in blocks of [`super::features::LANES`], features, network and
//! curve evaluated lane by lane. [`LearnedModel::predict`] is the plain-arithmetic network of
//! one pixel that the trainer uses.

use std::collections::BTreeMap;

use safetensors::{Dtype, SafeTensors};

use super::fast_math::fast_ln;
use super::features::{FEATURE_COUNT, FEATURE_SET, feature_index};

/// Name and version of the weights layout; see the module docs.
pub const WEIGHTS_FORMAT: &str = "strata-learned-k-1";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_base_reads_the_features_it_names() {
        assert_eq!(feature_index("mean_r"), Some(MEAN_R));
        assert_eq!(feature_index("mean_b"), Some(MEAN_R + 2));
        assert_eq!(feature_index("count"), Some(COUNT));
        assert_eq!(feature_index("alpha_sum"), Some(ALPHA_SUM));
        assert_eq!(feature_index("contrast"), Some(CONTRAST));
    }
}

/// Largest layer width a weights file may ask for.
pub const MAX_WIDTH: usize = 512;

/// Most layers a weights file may have.
pub const MAX_LAYERS: usize = 6;

/// The model shipped with strata, trained by the command in its metadata (`strata learn info`).
const BUILTIN: &[u8] = include_bytes!("../../weights/learned-k.safetensors");

/// Why a weights file was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WeightsError {
    /// Not a safetensors file, a damaged one, or one that cannot be read.
    #[error("not a readable safetensors file: {0}")]
    Format(String),
    /// A required metadata entry is missing.
    #[error("the weights have no `{0}` metadata entry; were they written by `strata learn train`?")]
    MissingMetadata(&'static str),
    /// Made for another layout or feature list.
    #[error(
        "the weights were made for {what} `{found}`, but this build of strata uses `{expected}`; retrain them with `strata learn train`"
    )]
    Version {
        /// What does not match.
        what: &'static str,
        /// What the file says.
        found: String,
        /// What this build uses.
        expected: &'static str,
    },
    /// A metadata value that cannot be used.
    #[error("bad `{key}` in the weights' metadata: {reason}")]
    BadMetadata {
        /// The entry.
        key: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A tensor is missing, has the wrong type or shape, or holds a non-finite value.
    #[error("bad tensor `{name}`: {reason}")]
    BadTensor {
        /// The tensor.
        name: String,
        /// What is wrong with it.
        reason: String,
    },
}

/// How a feature is transformed before normalisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transform {
    /// The feature as it is.
    Identity,
    /// `ln(1 + max(x, 0))`, for counts with a long tail.
    Log1p,
}

impl Transform {
    /// The name used in the weights' metadata.
    pub fn name(self) -> &'static str {
        match self {
            Transform::Identity => "identity",
            Transform::Log1p => "log1p",
        }
    }

    /// Applies the transform (`log1p` through [`fast_ln`], so training and inference compute
    /// the very same bits on every machine; in code not compiled for an instruction set with
    /// fused multiply-adds, such as the trainer's, its polynomial's are library calls).
    #[inline]
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Transform::Identity => x,
            Transform::Log1p => fast_ln(1.0 + x.max(0.0)),
        }
    }
}

/// The hidden layers' activation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// `max(0, x)`.
    Relu,
    /// `1 / (1 + e^−x)`.
    Sigmoid,
}

impl Activation {
    /// The name used in the weights' metadata.
    pub fn name(self) -> &'static str {
        match self {
            Activation::Relu => "relu",
            Activation::Sigmoid => "sigmoid",
        }
    }

    /// Applies the activation.
    #[inline]
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Activation::Relu => x.max(0.0),
            Activation::Sigmoid => sigmoid(x),
        }
    }
}

/// The logistic function.
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// What the network's output predicts, and so how it becomes k.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// `(k_opt − 1)/(count − 1)` (a sigmoid output); importance is `y · (count − 1)`, shared out
    /// by the importance allocator.
    KeptFraction,
    /// The thesis's `k_opt / N` (a sigmoid output); importance is `y`.
    SeedLabel,
    /// The pixel's truncation-error curve `ê(k) = d · t^k` as two corrections `(a, b)` (linear
    /// outputs) of the analytic model's `d₀ = contrast`, `t₀ = 1 − mean α`:
    /// `d = d₀ · e^a`, `t = σ(logit t₀ + b)` ([`curve`]); k is water-filled on the curve's
    /// worths by the analytic allocator ([`super::analytic`]). Zero outputs are the analytic model.
    ErrorCurve,
}

impl Target {
    /// The name used in the weights' metadata (and, but for `error_curve`, the dataset's label
    /// column).
    pub fn name(self) -> &'static str {
        match self {
            Target::KeptFraction => "kept_fraction",
            Target::SeedLabel => "seed_label",
            Target::ErrorCurve => "error_curve",
        }
    }

    /// Outputs of the network.
    pub fn outputs(self) -> usize {
        match self {
            Target::ErrorCurve => 2,
            _ => 1,
        }
    }

    /// Whether the outputs go through a sigmoid.
    pub fn sigmoid(self) -> bool {
        self != Target::ErrorCurve
    }

    /// The importance of a pixel with `count` fragments whose output is `y`.
    #[inline]
    pub fn importance(self, y: f32, count: u32) -> f32 {
        match self {
            Target::KeptFraction => y * count.saturating_sub(1) as f32,
            Target::SeedLabel | Target::ErrorCurve => y,
        }
    }
}

/// Columns of the features the error curve's base reads (checked against the names by a test).
pub(super) const MEAN_R: usize = 6;
pub(super) const COUNT: usize = 12;
pub(super) const ALPHA_SUM: usize = 14;
pub(super) const CONTRAST: usize = 23;

/// Smallest `d₀` and distance of `t₀` from 0 and 1 in [`curve`] (the analytic model's `d` and
/// `t` can be 0 or 1, where the corrections would have no effect).
pub const CURVE_FLOOR: f32 = 1e-3;

/// The analytic model's `(d₀, t₀)` of a pixel's features: its contrast against the background
/// and `1 −` its mean opacity, kept [`CURVE_FLOOR`] away from 0 (and `t₀` from 1).
#[inline]
pub fn curve_base(f: &[f32; FEATURE_COUNT]) -> (f32, f32) {
    let count = f[COUNT].max(1.0);
    let d0 = f[CONTRAST].max(CURVE_FLOOR);
    let t0 = (1.0 - f[ALPHA_SUM] / count).clamp(CURVE_FLOOR, 1.0 - CURVE_FLOOR);
    (d0, t0)
}

/// The error curve `(d, t)` of base `(d₀, t₀)` corrected by the network's `(a, b)`:
/// `d = d₀ · e^a`, `t = σ(ln(t₀ / (1 − t₀)) + b)`.
#[inline]
pub fn curve(base: (f32, f32), a: f32, b: f32) -> (f32, f32) {
    let (d0, t0) = base;
    (d0 * a.exp(), sigmoid((t0 / (1.0 - t0)).ln() + b))
}

/// One input of the network: a feature, transformed and normalised.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Input {
    /// Index into [`super::FEATURES`].
    pub feature: usize,
    /// Applied first.
    pub transform: Transform,
    /// Subtracted after the transform.
    pub mean: f32,
    /// Multiplied last (1 / standard deviation).
    pub scale: f32,
}

impl Input {
    /// The network's input value for feature value `x`.
    #[inline]
    pub fn normalise(&self, x: f32) -> f32 {
        (self.transform.apply(x) - self.mean) * self.scale
    }
}

/// A dense layer: `y = W x + b`, `W` row-major `[outputs][inputs]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// Input width.
    pub inputs: usize,
    /// Output width.
    pub outputs: usize,
    /// `outputs × inputs` weights.
    pub weight: Vec<f32>,
    /// `outputs` biases.
    pub bias: Vec<f32>,
}

impl Layer {
    /// A layer of zeros.
    pub fn zeros(inputs: usize, outputs: usize) -> Self {
        Layer {
            inputs,
            outputs,
            weight: vec![0.0; inputs * outputs],
            bias: vec![0.0; outputs],
        }
    }
}

/// A learned importance model; see the module docs.
#[derive(Clone, Debug, PartialEq)]
pub struct LearnedModel {
    /// The inputs, in order.
    pub inputs: Vec<Input>,
    /// Hidden layers then the output layer ([`Target::outputs`] outputs).
    pub layers: Vec<Layer>,
    /// The hidden layers' activation (the output's is the target's: [`Target::sigmoid`]).
    pub activation: Activation,
    /// What the output predicts.
    pub target: Target,
    /// Free-form metadata (training command, data hash, …), kept as read.
    pub info: BTreeMap<String, String>,
}

impl LearnedModel {
    /// The model shipped with strata (loaded once, shared).
    pub fn builtin() -> std::sync::Arc<LearnedModel> {
        static MODEL: std::sync::OnceLock<std::sync::Arc<LearnedModel>> =
            std::sync::OnceLock::new();
        MODEL
            .get_or_init(|| {
                std::sync::Arc::new(
                    LearnedModel::from_safetensors(BUILTIN)
                        .expect("the built-in weights are checked by a test"),
                )
            })
            .clone()
    }

    /// Multiply-adds per evaluated pixel.
    pub fn macs(&self) -> usize {
        self.layers.iter().map(|l| l.inputs * l.outputs).sum()
    }

    /// Number of parameters.
    pub fn parameters(&self) -> usize {
        self.layers
            .iter()
            .map(|l| l.weight.len() + l.bias.len())
            .sum()
    }

    /// Widest layer (including the input).
    pub fn width(&self) -> usize {
        self.layers
            .iter()
            .map(|l| l.outputs)
            .chain([self.inputs.len()])
            .max()
            .unwrap_or(0)
    }

    /// Checks that the layers chain from the inputs to the target's outputs and every value is
    /// finite.
    pub fn validate(&self) -> Result<(), WeightsError> {
        let bad = |name: String, reason: String| WeightsError::BadTensor { name, reason };
        if self.inputs.is_empty() || self.inputs.len() > FEATURE_COUNT {
            return Err(WeightsError::BadMetadata {
                key: "inputs",
                reason: format!(
                    "{} inputs; a model takes 1 to {FEATURE_COUNT}",
                    self.inputs.len()
                ),
            });
        }
        if self.layers.is_empty() || self.layers.len() > MAX_LAYERS {
            return Err(WeightsError::BadMetadata {
                key: "layers",
                reason: format!(
                    "{} layers; a model has 1 to {MAX_LAYERS}",
                    self.layers.len()
                ),
            });
        }
        for (i, input) in self.inputs.iter().enumerate() {
            if input.feature >= FEATURE_COUNT {
                return Err(bad(
                    "input".into(),
                    format!("input {i}: no feature {}", input.feature),
                ));
            }
            if !input.mean.is_finite() || !input.scale.is_finite() {
                return Err(bad(
                    "input.mean/input.scale".into(),
                    format!("input {i} has a non-finite normalisation"),
                ));
            }
        }
        let mut width = self.inputs.len();
        let last = self.layers.len() - 1;
        for (i, l) in self.layers.iter().enumerate() {
            let name = format!("layer{i}.weight");
            if l.inputs != width {
                return Err(bad(
                    name,
                    format!(
                        "takes {} inputs but the layer before gives {width}",
                        l.inputs
                    ),
                ));
            }
            if l.outputs == 0 || l.outputs > MAX_WIDTH {
                return Err(bad(
                    name,
                    format!("{} outputs; a layer has 1 to {MAX_WIDTH}", l.outputs),
                ));
            }
            if i == last && l.outputs != self.target.outputs() {
                return Err(bad(
                    name,
                    format!(
                        "a model predicting {} has {} output(s), not {}",
                        self.target.name(),
                        self.target.outputs(),
                        l.outputs
                    ),
                ));
            }
            if l.weight.len() != l.inputs * l.outputs || l.bias.len() != l.outputs {
                return Err(bad(
                    name,
                    "weights and biases do not match the shape".into(),
                ));
            }
            if l.weight.iter().chain(&l.bias).any(|v| !v.is_finite()) {
                return Err(bad(name, "holds a non-finite value".into()));
            }
            width = l.outputs;
        }
        Ok(())
    }

    /// The network's outputs for one pixel's full feature vector (the second is 0 for
    /// one-output targets): the reference the block evaluation of [`LearnedModel::infer`] is
    /// tested against.
    pub fn predict(&self, features: &[f32; FEATURE_COUNT]) -> [f32; 2] {
        let mut x: Vec<f32> = self
            .inputs
            .iter()
            .map(|i| i.normalise(features[i.feature]))
            .collect();
        let last = self.layers.len() - 1;
        for (li, l) in self.layers.iter().enumerate() {
            let y: Vec<f32> = (0..l.outputs)
                .map(|o| {
                    let row = &l.weight[o * l.inputs..(o + 1) * l.inputs];
                    let z = row.iter().zip(&x).fold(l.bias[o], |a, (w, x)| a + w * x);
                    if li < last {
                        self.activation.apply(z)
                    } else if self.target.sigmoid() {
                        sigmoid(z)
                    } else {
                        z
                    }
                })
                .collect();
            x = y;
        }
        [x[0], x.get(1).copied().unwrap_or(0.0)]
    }

    /// Reads a weights file from disk; see [`LearnedModel::from_safetensors`].
    pub fn read(path: &std::path::Path) -> Result<Self, WeightsError> {
        let bytes = std::fs::read(path)
            .map_err(|e| WeightsError::Format(format!("cannot read {}: {e}", path.display())))?;
        Self::from_safetensors(&bytes)
    }

    /// Reads a weights file; see the module docs for what it must hold.
    pub fn from_safetensors(bytes: &[u8]) -> Result<Self, WeightsError> {
        let (_, header) =
            SafeTensors::read_metadata(bytes).map_err(|e| WeightsError::Format(e.to_string()))?;
        let tensors =
            SafeTensors::deserialize(bytes).map_err(|e| WeightsError::Format(e.to_string()))?;
        let meta = header.metadata().clone().unwrap_or_default();
        let get = |key: &'static str| {
            meta.get(key)
                .map(String::as_str)
                .ok_or(WeightsError::MissingMetadata(key))
        };
        let format = get("format")?;
        if format != WEIGHTS_FORMAT {
            return Err(WeightsError::Version {
                what: "the weights format",
                found: format.into(),
                expected: WEIGHTS_FORMAT,
            });
        }
        let feature_set = get("feature_set")?;
        if feature_set != FEATURE_SET {
            return Err(WeightsError::Version {
                what: "the feature set",
                found: feature_set.into(),
                expected: FEATURE_SET,
            });
        }
        let names: Vec<&str> = get("inputs")?.split(',').map(str::trim).collect();
        let transforms: Vec<&str> = get("transforms")?.split(',').map(str::trim).collect();
        if transforms.len() != names.len() {
            return Err(WeightsError::BadMetadata {
                key: "transforms",
                reason: format!("{} transforms for {} inputs", transforms.len(), names.len()),
            });
        }
        let activation = match get("activation")? {
            "relu" => Activation::Relu,
            "sigmoid" => Activation::Sigmoid,
            other => {
                return Err(WeightsError::BadMetadata {
                    key: "activation",
                    reason: format!("`{other}` is not relu or sigmoid"),
                });
            }
        };
        let target = match get("target")? {
            "kept_fraction" => Target::KeptFraction,
            "seed_label" => Target::SeedLabel,
            "error_curve" => Target::ErrorCurve,
            other => {
                return Err(WeightsError::BadMetadata {
                    key: "target",
                    reason: format!("`{other}` is not kept_fraction, seed_label or error_curve"),
                });
            }
        };
        let layer_count: usize = get("layers")?
            .parse()
            .ok()
            .filter(|&n| (1..=MAX_LAYERS).contains(&n))
            .ok_or_else(|| WeightsError::BadMetadata {
                key: "layers",
                reason: format!("not a number from 1 to {MAX_LAYERS}"),
            })?;
        let tensor = |name: &str, rank: usize| -> Result<(Vec<usize>, Vec<f32>), WeightsError> {
            let bad = |reason: String| WeightsError::BadTensor {
                name: name.to_owned(),
                reason,
            };
            let t = tensors.tensor(name).map_err(|_| bad("missing".into()))?;
            if t.dtype() != Dtype::F32 {
                return Err(bad(format!("is {:?}, not F32", t.dtype())));
            }
            if t.shape().len() != rank {
                return Err(bad(format!(
                    "has shape {:?}, expected rank {rank}",
                    t.shape()
                )));
            }
            let values = t
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            Ok((t.shape().to_vec(), values))
        };
        let (mean_shape, mean) = tensor("input.mean", 1)?;
        let (scale_shape, scale) = tensor("input.scale", 1)?;
        if mean_shape[0] != names.len() || scale_shape[0] != names.len() {
            return Err(WeightsError::BadTensor {
                name: "input.mean/input.scale".into(),
                reason: format!(
                    "{} and {} values for {} inputs",
                    mean_shape[0],
                    scale_shape[0],
                    names.len()
                ),
            });
        }
        let mut inputs = Vec::with_capacity(names.len());
        for (i, (name, transform)) in names.iter().zip(&transforms).enumerate() {
            let feature = feature_index(name).ok_or_else(|| WeightsError::BadMetadata {
                key: "inputs",
                reason: format!("`{name}` is not a feature of {FEATURE_SET}"),
            })?;
            let transform = match *transform {
                "identity" => Transform::Identity,
                "log1p" => Transform::Log1p,
                other => {
                    return Err(WeightsError::BadMetadata {
                        key: "transforms",
                        reason: format!("`{other}` is not identity or log1p"),
                    });
                }
            };
            inputs.push(Input {
                feature,
                transform,
                mean: mean[i],
                scale: scale[i],
            });
        }
        let mut layers = Vec::with_capacity(layer_count);
        for i in 0..layer_count {
            let (shape, weight) = tensor(&format!("layer{i}.weight"), 2)?;
            let (bshape, bias) = tensor(&format!("layer{i}.bias"), 1)?;
            if bshape[0] != shape[0] {
                return Err(WeightsError::BadTensor {
                    name: format!("layer{i}.bias"),
                    reason: format!("{} biases for {} outputs", bshape[0], shape[0]),
                });
            }
            layers.push(Layer {
                inputs: shape[1],
                outputs: shape[0],
                weight,
                bias,
            });
        }
        let info = meta
            .iter()
            .filter(|(k, _)| !RESERVED.contains(&k.as_str()))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        let model = LearnedModel {
            inputs,
            layers,
            activation,
            target,
            info,
        };
        model.validate()?;
        Ok(model)
    }

    /// Writes the model as a weights file (see the module docs), with its `info` as metadata.
    pub fn to_safetensors(&self) -> Vec<u8> {
        let mut meta: std::collections::HashMap<String, String> =
            self.info.clone().into_iter().collect();
        let names: Vec<&str> = self
            .inputs
            .iter()
            .map(|i| super::features::FEATURES[i.feature].name)
            .collect();
        let transforms: Vec<&str> = self.inputs.iter().map(|i| i.transform.name()).collect();
        for (k, v) in [
            ("format", WEIGHTS_FORMAT.to_owned()),
            ("feature_set", FEATURE_SET.to_owned()),
            ("inputs", names.join(",")),
            ("transforms", transforms.join(",")),
            ("activation", self.activation.name().to_owned()),
            ("target", self.target.name().to_owned()),
            ("layers", self.layers.len().to_string()),
        ] {
            meta.insert(k.to_owned(), v);
        }
        let bytes = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let mut data: Vec<(String, Vec<usize>, Vec<u8>)> = vec![
            (
                "input.mean".into(),
                vec![self.inputs.len()],
                bytes(&self.inputs.iter().map(|i| i.mean).collect::<Vec<_>>()),
            ),
            (
                "input.scale".into(),
                vec![self.inputs.len()],
                bytes(&self.inputs.iter().map(|i| i.scale).collect::<Vec<_>>()),
            ),
        ];
        for (i, l) in self.layers.iter().enumerate() {
            data.push((
                format!("layer{i}.weight"),
                vec![l.outputs, l.inputs],
                bytes(&l.weight),
            ));
            data.push((format!("layer{i}.bias"), vec![l.outputs], bytes(&l.bias)));
        }
        let views = data.iter().map(|(name, shape, b)| {
            (
                name.clone(),
                safetensors::tensor::TensorView::new(Dtype::F32, shape.clone(), b)
                    .expect("the shape matches the bytes"),
            )
        });
        safetensors::serialize(views, Some(meta)).expect("f32 tensors always serialise")
    }
}

/// Metadata keys the loader interprets (the rest is `info`).
const RESERVED: [&str; 7] = [
    "format",
    "feature_set",
    "inputs",
    "transforms",
    "activation",
    "target",
    "layers",
];
