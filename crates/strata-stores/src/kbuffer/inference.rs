//! The learned k's importance pass ([`LearnedModel::infer`]): the hot path between the counting
//! pass and the allocation, written like the rasterizer (no allocation per pixel, laid out for
//! SIMD, identical for any thread count).
//!
//! # Passes and data
//!
//! ```text
//! per task of ROWS_PER_TASK rows (rayon), per pixel in row order:
//!   count < 2 → no choice: importance 0; count 1: worth = the analytic model's contrast
//!   count ≥ 2 → its index joins the block; a full block (LANES pixels) is evaluated:
//!     1. features   FeatureAccumulator::block_features → FeatureBlock  [feature][lane] f32
//!     2. inputs     x[u][lane] = (transform(feature[input u]) − mean_u) · scale_u
//!     3. layers     h[o][lane] = act(b_o + Σ_i W_oi · x[i][lane])   ping-pong between two
//!                   [width][lane] buffers; each weight multiplies LANES pixels at once
//!                   (the built-in shape, 20-8-2: compiled with its sizes, in registers)
//!     4. output     error curve: (a, b) → ln d, ln t, ln(1 − t) in the log domain → Worth
//!                   other targets: σ(y) → importance
//! ```
//!
//! Every stage loops over lanes with branch-free `f32` arithmetic ([`super::fast_math`] for the
//! logarithms and exponentials; the layers' sums in fused multiply-adds, [`f32::mul_add`], which
//! round once on every instruction set), so the compiler emits SIMD, and no value crosses lanes: a
//! pixel's result does not depend on its block, its lane or the thread that evaluated it.
//! [`LearnedModel::infer_pixel`] runs one pixel through the same code (the reference the tests
//! hold the pass to), and [`LearnedModel::predict`] is the plain-arithmetic network the trainer
//! uses (the tests bound the difference).
//!
//! # The error curve in the log domain
//!
//! With `d = d₀ e^a` and `t = σ(z)`, `z = ln t₀ − ln(1 − t₀) + b` ([`super::learned::curve`]):
//!
//! ```text
//! ln d = ln d₀ + a,   ln t = −softplus(−z),   ln(1 − t) = −softplus(z)
//! Worth: log_first = ln d + ln(1 − t) + ln t,   log_fall = ln t,   importance = e^(ln d + ln t)
//! ```
//!
//! which never rounds `t` to 1 (a pixel whose `t` is near 1 keeps a falling worth) and costs
//! four logarithms and two exponentials a pixel, all vectorised (the two `softplus` share
//! their `ln(1 + e^−|z|)`).

use rayon::prelude::*;

use super::analytic::Worth;
use super::fast_math::{fast_exp, fast_ln, fast_sigmoid, ln_1p};
use super::features::{
    FEATURE_COUNT, FeatureAccumulator, FeatureBlock, FrameFeatures, LANES, Lanes,
};
use super::learned::{
    ALPHA_SUM, Activation, CONTRAST, COUNT, CURVE_FLOOR, Input, Layer, LearnedModel, MEAN_R,
    Target, Transform,
};

/// Rows per parallel task of the importance pass.
pub const ROWS_PER_TASK: usize = 8;

/// One task's buffers, allocated once per task.
struct Scratch {
    /// The block's pixels (indices into the task's rows) and their count.
    len: usize,
    pixels: [usize; LANES],
    counts: [u32; LANES],
    features: FeatureBlock,
    /// Ping-pong activations, `[width][LANES]`.
    a: Vec<Lanes>,
    b: Vec<Lanes>,
}

impl Scratch {
    fn new(model: &LearnedModel) -> Self {
        Scratch {
            len: 0,
            pixels: [0; LANES],
            counts: [0; LANES],
            features: [[0.0; LANES]; FEATURE_COUNT],
            a: vec![[0.0; LANES]; model.width()],
            b: vec![[0.0; LANES]; model.width()],
        }
    }
}

/// What every task of the pass reads.
struct Pass<'a> {
    model: &'a LearnedModel,
    sums: &'a FeatureAccumulator,
    counts: &'a [u32],
    frame: &'a FrameFeatures,
}

/// One task: the rows whose first pixel is `first`, and their outputs.
struct Rows<'a> {
    pass: &'a Pass<'a>,
    scratch: &'a mut Scratch,
    first: usize,
    importance: &'a mut [f32],
    worth: &'a mut [Worth],
}

impl pulp::WithSimd for Rows<'_> {
    type Output = ();

    /// The task, compiled once per instruction set (everything it calls is inlined).
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let Rows {
            pass,
            scratch: s,
            first,
            importance,
            worth,
        } = self;
        let Pass {
            model,
            sums,
            counts,
            frame,
        } = *pass;
        let curve_target = model.target == Target::ErrorCurve;
        s.len = 0;
        let counts_here = &counts[first..first + importance.len()];
        for (i, &count) in counts_here.iter().enumerate() {
            if count >= 2 {
                s.pixels[s.len] = first + i;
                s.counts[s.len] = count;
                s.len += 1;
                if s.len == LANES {
                    model.run(s, sums, counts, frame, first, (importance, worth));
                }
                continue;
            }
            // No choice to make (the block writes the others' importance).
            importance[i] = 0.0;
            if curve_target && count == 1 {
                let p = first + i;
                let d = Worth::contrast_of(sums.means(p, count).0, frame.background);
                worth[i] = Worth::at_most_one(d);
            }
        }
        // The task's last, partial block.
        if s.len > 0 {
            model.run(s, sums, counts, frame, first, (importance, worth));
        }
    }
}

/// What the pass gives one pixel with a choice.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelOutcome {
    /// Its importance (for the error curve: `ê(1) = d·t`, what keeping only the nearest
    /// fragment would lose).
    pub importance: f32,
    /// Its error curve's worth ([`Target::ErrorCurve`] only).
    pub worth: Option<Worth>,
}

impl LearnedModel {
    /// The importance pass: for every pixel of the frame whose counting pass left `sums` and
    /// `counts` (frame values `frame`), its `importance` and, for [`Target::ErrorCurve`], its
    /// error-curve `worth` for the analytic allocator (a pixel with one fragment gets the
    /// analytic model's; an uncovered pixel's is left as it was, since no allocation reads it;
    /// other targets leave `worth` alone). See the module docs.
    ///
    /// # Panics
    /// If `counts`, `importance` or `worth` do not have one entry per pixel of `sums`' frame.
    pub fn infer(
        &self,
        sums: &FeatureAccumulator,
        counts: &[u32],
        frame: &FrameFeatures,
        importance: &mut [f32],
        worth: &mut [Worth],
    ) {
        let (w, h) = sums.size();
        let n = w as usize * h as usize;
        assert_eq!(counts.len(), n, "one count per pixel");
        assert_eq!(importance.len(), n, "one importance per pixel");
        assert_eq!(worth.len(), n, "one worth per pixel");
        let rows = (ROWS_PER_TASK * w as usize).max(1);
        let pass = Pass {
            model: self,
            sums,
            counts,
            frame,
        };
        // The instruction set (AVX-512 or AVX2 where the CPU has it, else SSE2; NEON) the lane
        // loops are compiled for, found at run time; every set computes the same bits (a fused
        // multiply-add rounds once, as an instruction or as the library's `fmaf` on SSE2).
        let arch = pulp::Arch::new();
        importance
            .par_chunks_mut(rows)
            .zip(worth.par_chunks_mut(rows))
            .enumerate()
            .for_each_init(
                || Scratch::new(self),
                |scratch, (t, (importance, worth))| {
                    arch.dispatch(Rows {
                        pass: &pass,
                        scratch,
                        first: t * rows,
                        importance,
                        worth,
                    })
                },
            );
    }

    /// One pixel `p` with two or more fragments through the importance pass's own code (see
    /// the module docs); `None` for a pixel with no choice to make.
    pub fn infer_pixel(
        &self,
        sums: &FeatureAccumulator,
        counts: &[u32],
        frame: &FrameFeatures,
        p: usize,
    ) -> Option<PixelOutcome> {
        if counts[p] < 2 {
            return None;
        }
        let mut s = Scratch::new(self);
        (s.pixels[0], s.counts[0], s.len) = (p, counts[p], 1);
        let (mut importance, mut worth) = ([0.0], [Worth::at_most_one(0.0)]);
        self.run(
            &mut s,
            sums,
            counts,
            frame,
            p,
            (&mut importance, &mut worth),
        );
        Some(PixelOutcome {
            importance: importance[0],
            worth: (self.target == Target::ErrorCurve).then_some(worth[0]),
        })
    }

    /// Evaluates the block in `s` and writes each pixel's results at its index minus `first`
    /// in `out`; empties the block. Always inlined, like everything it calls, so that it is
    /// compiled for the instruction set the pass dispatches to.
    #[inline(always)]
    fn run(
        &self,
        s: &mut Scratch,
        sums: &FeatureAccumulator,
        counts: &[u32],
        frame: &FrameFeatures,
        first: usize,
        out: (&mut [f32], &mut [Worth]),
    ) {
        let (importance, worth) = out;
        let len = std::mem::take(&mut s.len);
        sums.block_features(counts, frame, &s.pixels[..len], &mut s.features);
        let y = self.network(&s.features, &mut s.a, &mut s.b);
        if self.target == Target::ErrorCurve {
            let curve = CurveBlock::new(&s.features, y[0], y[1], frame.background);
            for l in 0..len {
                let at = s.pixels[l] - first;
                importance[at] = curve.importance[l];
                worth[at] = Worth {
                    log_first: f64::from(curve.log_first[l]),
                    log_fall: f64::from(curve.log_fall[l]),
                    // Which pixels keep a fragment at all, when the budget cannot give every
                    // covered pixel one, stays the analytic model's choice, to its bits (ties
                    // go by pixel index): the curve is fitted to the errors of keeping 1, 2, …
                    // fragments, not of keeping none.
                    contrast: curve.contrast[l],
                };
            }
        } else {
            for l in 0..len {
                let y = fast_sigmoid(y[0][l]);
                importance[s.pixels[l] - first] = self.target.importance(y, s.counts[l]);
            }
        }
    }

    /// The network's raw outputs (before the target's sigmoid) for a block of features, using
    /// `a` and `b` (`[width][LANES]`) as the layers' buffers.
    #[inline(always)]
    fn network(&self, f: &FeatureBlock, a: &mut Vec<Lanes>, b: &mut Vec<Lanes>) -> [Lanes; 2] {
        // The built-in model's shape, compiled with its sizes known.
        if self.is_relu_mlp(20, 8, 2) {
            return self.relu_mlp::<20, 8, 2>(f);
        }
        self.network_in_loops(f, a, b)
    }

    /// [`LearnedModel::network`] for any shape: loops over the layers' sizes.
    #[inline(always)]
    fn network_in_loops(
        &self,
        f: &FeatureBlock,
        a: &mut Vec<Lanes>,
        b: &mut Vec<Lanes>,
    ) -> [Lanes; 2] {
        for (x, input) in a.iter_mut().zip(&self.inputs) {
            *x = input_lanes(input, f);
        }
        let last = self.layers.len() - 1;
        for (li, layer) in self.layers.iter().enumerate() {
            let hidden = li < last;
            // Four outputs at a time: four independent chains of multiply-adds per lane, so the
            // loop is bound by throughput, not by the latency of one accumulator, and each input
            // is loaded once for the four. (Eight at a time compiled to accumulators kept in
            // memory: 1.8 times the pass's instructions.)
            let mut o = 0;
            while o + 4 <= layer.outputs {
                dense::<4>(layer, o, a, b);
                o += 4;
            }
            while o < layer.outputs {
                dense::<1>(layer, o, a, b);
                o += 1;
            }
            if hidden {
                for out in b.iter_mut().take(layer.outputs) {
                    match self.activation {
                        Activation::Relu => out.iter_mut().for_each(|v| *v = v.max(0.0)),
                        Activation::Sigmoid => out.iter_mut().for_each(|v| *v = fast_sigmoid(*v)),
                    }
                }
            }
            std::mem::swap(a, b);
        }
        [a[0], if a.len() > 1 { a[1] } else { [0.0; LANES] }]
    }
}

impl LearnedModel {
    /// True if the model is `inputs` inputs, one hidden ReLU layer of `hidden` units, and
    /// `outputs` outputs: the shape [`LearnedModel::relu_mlp`] evaluates.
    fn is_relu_mlp(&self, inputs: usize, hidden: usize, outputs: usize) -> bool {
        matches!(&self.layers[..], [h, o] if h.inputs == inputs && h.outputs == hidden
            && o.inputs == hidden && o.outputs == outputs)
            && self.inputs.len() == inputs
            && self.activation == Activation::Relu
    }

    /// [`LearnedModel::network`] for a model of `I` inputs, one hidden ReLU layer of `H` units
    /// and `O` ≤ 2 outputs ([`LearnedModel::is_relu_mlp`]). The arithmetic of the general
    /// loops in the same order (each sum starts at its bias and adds the inputs in order), so
    /// the same bits in the `O` outputs (the others are 0); with the sizes known at compile
    /// time, the inputs and the hidden layer stay in registers, each weight is read once a
    /// block, and the hidden units are `H` independent chains of fused multiply-adds. On the built-in model (20, 8, 2) the importance pass
    /// of the full dragon took 17.3 → 14.9 ms on one thread (AMD EPYC with AVX-512). Written
    /// with plain index loops: the same loops as iterator chains (`zip` over rows of weights)
    /// compiled to slower code than the general loops (the pass took 23 ms).
    #[inline(always)]
    fn relu_mlp<const I: usize, const H: usize, const O: usize>(
        &self,
        f: &FeatureBlock,
    ) -> [Lanes; 2] {
        const { assert!(O <= 2, "at most two outputs") };
        let mut x = [[0f32; LANES]; I];
        for (x, input) in x.iter_mut().zip(&self.inputs) {
            *x = input_lanes(input, f);
        }
        let (l0, l1) = (&self.layers[0], &self.layers[1]);
        let (w0, b0) = (&l0.weight[..I * H], &l0.bias[..H]);
        let (w1, b1) = (&l1.weight[..H * O], &l1.bias[..O]);
        let mut h = [[0f32; LANES]; H];
        for o in 0..H {
            h[o] = [b0[o]; LANES];
        }
        for i in 0..I {
            for o in 0..H {
                let w = w0[o * I + i];
                for l in 0..LANES {
                    h[o][l] = w.mul_add(x[i][l], h[o][l]);
                }
            }
        }
        for h in &mut h {
            h.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        // The few outputs one after the other, each its own chain over the hidden units.
        let mut y = [[0f32; LANES]; 2];
        for (o, y) in y.iter_mut().enumerate().take(O) {
            let mut sum = [b1[o]; LANES];
            for (i, h) in h.iter().enumerate() {
                let w = w1[o * H + i];
                for l in 0..LANES {
                    sum[l] = w.mul_add(h[l], sum[l]);
                }
            }
            *y = sum;
        }
        y
    }
}

/// One network input of a block, lane by lane: `(transform(feature) − mean) · scale`. Whole
/// lanes in and out (a copy, not a borrow): the shape the compiler turns into one vector
/// operation per step.
#[inline(always)]
fn input_lanes(input: &Input, f: &FeatureBlock) -> Lanes {
    let v: Lanes = f[input.feature];
    let (mean, scale) = (input.mean, input.scale);
    let mut y = [0.0; LANES];
    match input.transform {
        Transform::Identity => {
            for l in 0..LANES {
                y[l] = (v[l] - mean) * scale;
            }
        }
        Transform::Log1p => {
            for l in 0..LANES {
                y[l] = (fast_ln(1.0 + v[l].max(0.0)) - mean) * scale;
            }
        }
    }
    y
}

/// Outputs `first .. first + G` of `layer` for the block whose inputs are `x`, into `out`:
/// `out[o][lane] = b_o + Σ_i W_oi · x[i][lane]`, summed in input order, one fused multiply-add
/// an input.
#[inline(always)]
fn dense<const G: usize>(layer: &Layer, first: usize, x: &[Lanes], out: &mut [Lanes]) {
    let inputs = layer.inputs;
    let x = &x[..inputs];
    // The G rows of weights, each sliced to `inputs` once, so the loop below indexes them
    // without bounds checks.
    let rows: [&[f32]; G] = std::array::from_fn(|g| {
        let start = (first + g) * inputs;
        &layer.weight[start..start + inputs]
    });
    let mut acc: [Lanes; G] = std::array::from_fn(|g| [layer.bias[first + g]; LANES]);
    for (i, x) in x.iter().enumerate() {
        for (acc, row) in acc.iter_mut().zip(&rows) {
            let w = row[i];
            for (a, &x) in acc.iter_mut().zip(x) {
                *a = w.mul_add(x, *a);
            }
        }
    }
    out[first..first + G].copy_from_slice(&acc);
}

/// The error curve of a block, in the log domain (module docs).
struct CurveBlock {
    /// The analytic model's contrast, `‖mean − background‖` in f64.
    contrast: [f64; LANES],
    log_first: Lanes,
    log_fall: Lanes,
    importance: Lanes,
}

impl CurveBlock {
    /// From the block's features (for the analytic base `(d₀, t₀)`), the network's
    /// corrections `(a, b)` and the frame's background.
    #[inline(always)]
    fn new(f: &FeatureBlock, a: Lanes, b: Lanes, background: [f32; 3]) -> CurveBlock {
        let mut c = CurveBlock {
            contrast: [0.0; LANES],
            log_first: [0.0; LANES],
            log_fall: [0.0; LANES],
            importance: [0.0; LANES],
        };
        for l in 0..LANES {
            let count = f[COUNT][l].max(1.0);
            let d0 = f[CONTRAST][l].max(CURVE_FLOOR);
            let t0 = (1.0 - f[ALPHA_SUM][l] / count).clamp(CURVE_FLOOR, 1.0 - CURVE_FLOOR);
            let ln_d = fast_ln(d0) + a[l];
            let z = fast_ln(t0) - fast_ln(1.0 - t0) + b[l];
            // `ln t = −softplus(−z)` and `ln(1 − t) = −softplus(z)`, whose logarithmic
            // terms are one: `ln(1 + e^−|z|)`.
            let tail = ln_1p(fast_exp(-z.abs()));
            let ln_t = -((-z).max(0.0) + tail);
            let ln_not_t = -(z.max(0.0) + tail);
            c.log_first[l] = ln_d + ln_not_t + ln_t;
            c.log_fall[l] = ln_t;
            c.importance[l] = fast_exp(ln_d + ln_t);
            let mean = [f[MEAN_R][l], f[MEAN_R + 1][l], f[MEAN_R + 2][l]];
            c.contrast[l] = Worth::contrast_of(mean, background);
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in shape's network, compiled with its sizes known, gives the bits of the
    /// general loops, for random weights and inputs of every scale.
    #[test]
    fn the_built_in_shape_is_the_general_loops_bit_for_bit() {
        let mut x = 0x2545_f491u32;
        let mut next = move |scale: f32| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            ((x % 20_001) as f32 / 10_000.0 - 1.0) * scale
        };
        let mut model = LearnedModel::builtin().as_ref().clone();
        assert!(model.is_relu_mlp(20, 8, 2), "the built-in model's shape");
        let (mut a, mut b) = (
            vec![[0.0; LANES]; model.width()],
            vec![[0.0; LANES]; model.width()],
        );
        for round in 0..200 {
            for layer in &mut model.layers {
                layer.weight.iter_mut().for_each(|w| *w = next(2.0));
                layer.bias.iter_mut().for_each(|w| *w = next(1.0));
            }
            for input in &mut model.inputs {
                (input.mean, input.scale) = (next(1.0), next(3.0));
            }
            let scale = [1e-3, 1.0, 1e3][round % 3];
            let f: FeatureBlock = std::array::from_fn(|_| std::array::from_fn(|_| next(scale)));
            let fixed = model.network(&f, &mut a, &mut b);
            let general = model.network_in_loops(&f, &mut a, &mut b);
            let bits = |y: [Lanes; 2]| y.map(|l| l.map(f32::to_bits));
            assert_eq!(bits(fixed), bits(general), "round {round}");
            // Models of another activation or output count are not of the built-in shape:
            // they run the general loops (were they taken for it, they would differ, or panic).
            let mut sigmoid = model.clone();
            sigmoid.activation = Activation::Sigmoid;
            let mut one = model.clone();
            one.layers[1] = Layer {
                inputs: 8,
                outputs: 1,
                weight: one.layers[1].weight[..8].to_vec(),
                bias: one.layers[1].bias[..1].to_vec(),
            };
            for other in [&sigmoid, &one] {
                assert!(!other.is_relu_mlp(20, 8, 2));
                let y = other.network(&f, &mut a, &mut b);
                let general = other.network_in_loops(&f, &mut a, &mut b);
                assert_eq!(bits(y), bits(general), "round {round}");
            }
        }
    }
}
