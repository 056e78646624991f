//! The adaptive mode's cost model: what a chunk of triangles or a band of rows will take, fitted
//! to what the steps before it took, with a safety margin from the fit's observed error.
//!
//! # Model
//!
//! ```text
//! chunk of triangles  t ≈ c + a₁·triangles + a₂·fragments      (ms, a₁, a₂ ≥ 0)
//!                          │   │              └ the fragments the chunk's objects made in the
//!                          │   │                previous SC frame, pro rata to its share of each
//!                          │   └ vertex stage, setup and binning
//!                          └ per capture call, measured on an empty chunk before the run
//! band of rows        t ≈ c + b₁·rows + b₂·fragments           (ms, b₁, b₂ ≥ 0)
//!                          │              └ the band's fragments in the previous SC frame
//!                          └ per band, measured on an empty band before the run
//! ```
//!
//! A triangle's cost is not a constant: on `mfr-cars` at 1280×720 the car body's 12 triangles
//! make 273,000 fragments and take 3.2 ms to capture, a sphere's 3,968 triangles make 30,000 and
//! take 0.8 ms. Measured on that scene (one thread, optimised build), a capture costs about
//! 1.1 ms per 100,000 fragments plus 0.07 ms per 1,000 triangles, and a call next to nothing
//! (4 µs); an export band about 3.5 ms per 100,000 fragments (count, gather, sort, resolve), so
//! the export is the larger part of an SC frame. Fragments carry the difference between
//! triangles, and the SC's frames repeat (the same static objects, seen from nearly the same
//! view), so the previous SC frame's fragments per object and per row predict the next frame's;
//! every feature is known before the step runs.
//!
//! The fixed cost per step is measured, not fitted: the adaptive steps are sized to fill the
//! time left, so they all take about as long, and a fit with a free constant explains them best
//! by the constant alone — then predicts a step ten times larger to cost the same (it did: a
//! 598-row band predicted at 4 ms took 238). The proportional coefficients (`LinearCost`) are
//! a weighted non-negative least-squares fit over the last [`FIT_WINDOW`] steps, a step `k`
//! steps back weighing [`FORGETTING`]`^k`: every subset of the features is fitted by the normal
//! equations and the best fit whose coefficients are all ≥ 0 is kept, so the model never trades
//! a negative cost against a positive one (a prediction never decreases with a larger step,
//! which the sizing's binary search relies on). Before [`FIT_MIN_STEPS`] steps the prior — the
//! one-shot reference frame's time spread over its fragments — is scaled to the steps seen. A
//! step measured at more than [`OUTLIER_RATIO`] times its prediction (the thread preempted, the
//! store's pool grown) enters the fit at that ratio.
//!
//! `Margin` keeps the ratio of measured to predicted time of the last [`MARGIN_WINDOW`] steps;
//! a step is sized so that its prediction times the ratios' 90th percentile fits in the time left.

/// How fast old steps fade from the fit (the weight of a step `k` steps back is `FORGETTING^k`).
pub const FORGETTING: f64 = 0.97;

/// Steps the fit remembers.
pub const FIT_WINDOW: usize = 64;

/// Steps before the fit replaces the scaled prior.
pub const FIT_MIN_STEPS: usize = 6;

/// A step measured at more than this times its prediction enters the fit at this ratio.
pub const OUTLIER_RATIO: f64 = 4.0;

/// Steps whose prediction error sets the margin.
pub const MARGIN_WINDOW: usize = 48;

/// The margin before [`MARGIN_MIN_SAMPLES`] steps were measured.
const MARGIN_DEFAULT: f64 = 1.5;

/// Steps measured before the margin follows them.
const MARGIN_MIN_SAMPLES: usize = 4;

/// The largest margin: a fit worse than this is not trusted further (the step just stays small).
const MARGIN_MAX: f64 = 4.0;

/// A proportional cost `θ·x` with `θ ≥ 0`, fitted to the recent steps (see the module docs).
#[derive(Clone, Debug)]
pub(crate) struct LinearCost<const K: usize> {
    prior: [f64; K],
    theta: [f64; K],
    /// The remembered steps, newest last: features and measured time.
    steps: std::collections::VecDeque<([f64; K], f64)>,
}

impl<const K: usize> LinearCost<K> {
    /// A fit starting at `prior` (negative entries count as 0).
    pub(crate) fn new(prior: [f64; K]) -> Self {
        let prior = prior.map(|p| if p.is_finite() { p.max(0.0) } else { 0.0 });
        LinearCost {
            prior,
            theta: prior,
            steps: std::collections::VecDeque::with_capacity(FIT_WINDOW),
        }
    }

    /// The coefficients as fitted.
    pub(crate) fn coefficients(&self) -> [f64; K] {
        self.theta
    }

    /// The predicted cost of a step with features `x` (non-negative): never negative, never
    /// smaller for larger features.
    pub(crate) fn predict(&self, x: &[f64; K]) -> f64 {
        dot(&self.theta, x)
    }

    /// Takes a measured step into the fit.
    pub(crate) fn update(&mut self, x: &[f64; K], measured: f64) {
        if !measured.is_finite() || measured < 0.0 || x.iter().any(|v| !v.is_finite()) {
            return;
        }
        let predicted = self.predict(x);
        let measured = if self.steps.len() >= FIT_MIN_STEPS && predicted > 0.0 {
            measured.min(predicted * OUTLIER_RATIO)
        } else {
            measured
        };
        if self.steps.len() == FIT_WINDOW {
            self.steps.pop_front();
        }
        self.steps.push_back((*x, measured));
        self.theta = if self.steps.len() < FIT_MIN_STEPS {
            self.scaled_prior()
        } else {
            self.non_negative_fit()
                .unwrap_or_else(|| self.scaled_prior())
        };
    }

    /// The weights of the remembered steps, oldest first.
    fn weights(&self) -> impl Iterator<Item = f64> + '_ {
        let n = self.steps.len() as i32;
        (0..n).map(move |i| FORGETTING.powi(n - 1 - i))
    }

    /// The prior times the ratio of the steps' measured to prior-predicted time.
    fn scaled_prior(&self) -> [f64; K] {
        let (mut measured, mut predicted) = (0.0, 0.0);
        for ((x, y), w) in self.steps.iter().zip(self.weights()) {
            measured += w * y;
            predicted += w * dot(&self.prior, x);
        }
        if predicted > 0.0 {
            self.prior.map(|p| p * measured / predicted)
        } else {
            self.prior
        }
    }

    /// The best weighted least-squares fit with every coefficient ≥ 0: each subset of the
    /// features fitted alone, the feasible fit of least error kept. `None` when no subset has
    /// a solvable system.
    fn non_negative_fit(&self) -> Option<[f64; K]> {
        let mut best: Option<([f64; K], f64)> = None;
        for mask in 1u32..(1 << K) {
            let Some(theta) = self.fit_subset(mask) else {
                continue;
            };
            if theta.iter().any(|&t| t < 0.0) {
                continue;
            }
            let error: f64 = self
                .steps
                .iter()
                .zip(self.weights())
                .map(|((x, y), w)| w * (y - dot(&theta, x)).powi(2))
                .sum();
            if best.is_none_or(|(_, e)| error < e) {
                best = Some((theta, error));
            }
        }
        best.map(|(theta, _)| theta)
    }

    /// The weighted least-squares fit on the features in `mask` (the others 0), by the normal
    /// equations; `None` when they are singular.
    fn fit_subset(&self, mask: u32) -> Option<[f64; K]> {
        let used: Vec<usize> = (0..K).filter(|i| mask & (1 << i) != 0).collect();
        let m = used.len();
        // [A | b] for A = Σ w·xₛxₛᵀ, b = Σ w·xₛ·y.
        let mut a = vec![vec![0.0; m + 1]; m];
        for ((x, y), w) in self.steps.iter().zip(self.weights()) {
            for (r, &i) in used.iter().enumerate() {
                for (c, &j) in used.iter().enumerate() {
                    a[r][c] += w * x[i] * x[j];
                }
                a[r][m] += w * x[i] * y;
            }
        }
        let solved = solve(a)?;
        let mut theta = [0.0; K];
        for (&i, v) in used.iter().zip(solved) {
            theta[i] = v;
        }
        Some(theta)
    }
}

fn dot<const K: usize>(a: &[f64; K], b: &[f64; K]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

/// Solves the augmented system `[A | b]` by Gaussian elimination with partial pivoting; `None`
/// when `A` is (nearly) singular.
fn solve(mut a: Vec<Vec<f64>>) -> Option<Vec<f64>> {
    let m = a.len();
    let scale = a
        .iter()
        .enumerate()
        .map(|(i, row)| row[i].abs())
        .fold(0.0, f64::max);
    for col in 0..m {
        let pivot = (col..m).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() <= scale * 1e-12 || a[pivot][col] == 0.0 {
            return None;
        }
        a.swap(col, pivot);
        let (top, below) = a.split_at_mut(col + 1);
        let pivot_row = &top[col];
        for row in below {
            let f = row[col] / pivot_row[col];
            for (v, p) in row.iter_mut().zip(pivot_row).skip(col) {
                *v -= f * p;
            }
        }
    }
    let mut x = vec![0.0; m];
    for r in (0..m).rev() {
        let tail: f64 = (r + 1..m).map(|c| a[r][c] * x[c]).sum();
        x[r] = (a[r][m] - tail) / a[r][r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// One kind of step's cost: a measured fixed cost per step, a fitted proportional cost, and the
/// margin from the fit's recent error.
#[derive(Clone, Debug)]
pub(crate) struct StepCost<const K: usize> {
    fixed_ms: f64,
    fit: LinearCost<K>,
    margin: Margin,
}

impl<const K: usize> StepCost<K> {
    /// A cost of `fixed_ms` per step plus one fitted from `prior`.
    pub(crate) fn new(fixed_ms: f64, prior: [f64; K]) -> Self {
        StepCost {
            fixed_ms: if fixed_ms.is_finite() {
                fixed_ms.max(0.0)
            } else {
                0.0
            },
            fit: LinearCost::new(prior),
            margin: Margin::default(),
        }
    }

    /// The predicted time of a step with features `x` (ms), margin not included.
    pub(crate) fn predict(&self, x: &[f64; K]) -> f64 {
        self.fixed_ms + self.fit.predict(x)
    }

    /// What to multiply a prediction by before comparing it with the time left.
    pub(crate) fn margin(&self) -> f64 {
        self.margin.factor()
    }

    /// Takes a step with features `x` that took `measured` ms into the fit, and, when it was
    /// `predicted`, into the margin.
    pub(crate) fn observe(&mut self, x: &[f64; K], predicted: Option<f64>, measured: f64) {
        self.fit.update(x, (measured - self.fixed_ms).max(0.0));
        if let Some(p) = predicted {
            self.margin.observe(p, measured);
        }
    }

    /// The fixed cost followed by the fitted coefficients.
    pub(crate) fn model(&self) -> [f64; 3] {
        let c = self.fit.coefficients();
        [
            self.fixed_ms,
            c.first().copied().unwrap_or(0.0),
            c.get(1).copied().unwrap_or(0.0),
        ]
    }
}

/// The safety margin: the 90th percentile of recent measured-over-predicted ratios.
#[derive(Clone, Debug, Default)]
pub(crate) struct Margin {
    ratios: std::collections::VecDeque<f64>,
}

impl Margin {
    /// Records a step that took `measured` where `predicted` was expected.
    pub(crate) fn observe(&mut self, predicted: f64, measured: f64) {
        if predicted > 0.0 && measured.is_finite() {
            if self.ratios.len() == MARGIN_WINDOW {
                self.ratios.pop_front();
            }
            self.ratios.push_back(measured / predicted);
        }
    }

    /// What to multiply a prediction by before comparing it with the time left.
    pub(crate) fn factor(&self) -> f64 {
        if self.ratios.len() < MARGIN_MIN_SAMPLES {
            return MARGIN_DEFAULT;
        }
        let mut sorted: Vec<f64> = self.ratios.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        let k = ((sorted.len() - 1) as f64 * 0.9).round() as usize;
        sorted[k].clamp(1.0, MARGIN_MAX)
    }
}

/// The largest `n` in `1..=max` whose `cost(n)` is at most `budget`, for a `cost` that never
/// decreases with `n`; 0 when not even `cost(1)` fits (or `max` is 0).
pub(crate) fn largest_fitting(max: u64, budget: f64, cost: impl Fn(u64) -> f64) -> u64 {
    if max == 0 || cost(1) > budget {
        return 0;
    }
    let (mut lo, mut hi) = (1, max); // cost(lo) fits; the answer is in lo..=hi
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if cost(mid) <= budget {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    lo
}

/// One object of an SC frame's draw list, for the chunk features.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct ObjectCost {
    /// Its triangles.
    pub(crate) triangles: u64,
    /// The fragments it is expected to make.
    pub(crate) fragments: f64,
}

/// The chunk features of the objects of one SC frame, in draw order.
#[derive(Clone, Debug, Default)]
pub(crate) struct ChunkFeatures {
    objects: Vec<ObjectCost>,
    /// The first triangle of each object, and the total at the end.
    first: Vec<u64>,
}

/// The chunk model's features: thousands of triangles, ten thousands of fragments.
pub(crate) type ChunkX = [f64; 2];

impl ChunkFeatures {
    pub(crate) fn new(objects: Vec<ObjectCost>) -> Self {
        let mut first = Vec::with_capacity(objects.len() + 1);
        let mut total = 0;
        for o in &objects {
            first.push(total);
            total += o.triangles;
        }
        first.push(total);
        ChunkFeatures { objects, first }
    }

    /// Triangles in the frame.
    pub(crate) fn total(&self) -> u64 {
        self.first.last().copied().unwrap_or(0)
    }

    /// The features of the chunk of triangles `start .. start + n`.
    pub(crate) fn features(&self, start: u64, n: u64) -> ChunkX {
        let end = start + n;
        // The first object the chunk reaches: the last one starting at or before `start`.
        let from = self
            .first
            .partition_point(|&f| f <= start)
            .saturating_sub(1);
        let mut fragments = 0.0;
        for (o, &first) in self.objects.iter().zip(&self.first).skip(from) {
            if first >= end {
                break;
            }
            let overlap = end
                .min(first + o.triangles)
                .saturating_sub(start.max(first));
            if overlap > 0 {
                fragments += o.fragments * overlap as f64 / o.triangles as f64;
            }
        }
        [n as f64 / 1e3, fragments / 1e4]
    }
}

/// The band model's features: hundreds of rows, ten thousands of fragments.
pub(crate) type BandX = [f64; 2];

/// The fragments before each row of the previous SC frame (`rows + 1` entries), for the band
/// features.
#[derive(Clone, Debug, Default)]
pub(crate) struct BandFeatures {
    before_row: Vec<u64>,
}

impl BandFeatures {
    /// From a frame's per-pixel offsets (`width·height + 1` entries).
    pub(crate) fn from_offsets(width: u32, height: u32, offsets: &[u32]) -> Self {
        let w = width as usize;
        let before_row = (0..=height as usize)
            .map(|y| offsets.get(y * w).map_or(0, |&o| u64::from(o)))
            .collect();
        BandFeatures { before_row }
    }

    /// Fragments in the frame.
    pub(crate) fn total(&self) -> u64 {
        self.before_row.last().copied().unwrap_or(0)
    }

    /// The features of rows `start .. start + rows`.
    pub(crate) fn features(&self, start: u32, rows: u32) -> BandX {
        let at = |y: u32| {
            self.before_row
                .get(y as usize)
                .or(self.before_row.last())
                .copied()
                .unwrap_or(0)
        };
        let fragments = at(start + rows).saturating_sub(at(start));
        [f64::from(rows) / 100.0, fragments as f64 / 1e4]
    }
}

/// Fragments per object id of a frame, counted as its bands are exported.
#[derive(Clone, Debug, Default)]
pub(crate) struct ObjectFragments {
    counts: Vec<u64>,
}

/// Object ids above this are not counted (their objects are predicted from the average).
const MAX_COUNTED_ID: usize = 1 << 20;

impl ObjectFragments {
    /// Counts `objects` (a frame's object column).
    pub(crate) fn add(&mut self, objects: &[strata_core::ObjectId]) {
        for id in objects {
            let i = id.0 as usize;
            if i >= MAX_COUNTED_ID {
                continue;
            }
            if i >= self.counts.len() {
                self.counts.resize(i + 1, 0);
            }
            self.counts[i] += 1;
        }
    }

    /// Fragments object `id` made, if it made any.
    pub(crate) fn get(&self, id: strata_core::ObjectId) -> Option<u64> {
        self.counts.get(id.0 as usize).copied().filter(|&c| c > 0)
    }

    /// Fragments counted.
    pub(crate) fn total(&self) -> u64 {
        self.counts.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fit_finds_the_cost_of_each_feature() {
        // Synthetic steps costing 2·x₀ + 0.5·x₁ + 0·x₂, the features varying independently.
        let mut fit = LinearCost::new([1.0, 1.0, 1.0]);
        for k in 0..60 {
            let x = [
                f64::from(k % 7) + 0.5,
                f64::from((k * 3) % 5),
                f64::from(k % 4),
            ];
            fit.update(&x, 2.0 * x[0] + 0.5 * x[1]);
        }
        let [a, b, c] = fit.coefficients();
        assert!(
            (a - 2.0).abs() < 1e-9 && (b - 0.5).abs() < 1e-9 && c == 0.0,
            "{a} {b} {c}"
        );
        assert!((fit.predict(&[10.0, 4.0, 3.0]) - 22.0).abs() < 1e-9);
    }

    #[test]
    fn no_coefficient_goes_negative() {
        // Steps that a negative cost per x₁ would fit best: 2·x₀ − 0.5·x₁.
        let mut fit = LinearCost::new([1.0, 1.0]);
        for k in 1..40 {
            let x = [f64::from(k % 6 + 1), f64::from(k % 3)];
            fit.update(&x, 2.0 * x[0] - 0.5 * x[1]);
        }
        let [a, b] = fit.coefficients();
        assert_eq!(b, 0.0);
        assert!(a > 1.6 && a < 2.0, "{a}");
        assert!(fit.predict(&[2.0, 1.0]) <= fit.predict(&[2.0, 2.0]));
    }

    #[test]
    fn the_fit_follows_a_cost_that_changes() {
        let mut fit = LinearCost::new([1.0, 1.0]);
        let x = |k: u32| [f64::from(k % 5 + 1), f64::from(k % 2)];
        for k in 0..50 {
            fit.update(&x(k), x(k)[0]);
        }
        for k in 0..FIT_WINDOW as u32 {
            fit.update(&x(k), 3.0 * x(k)[0]);
        }
        assert!(
            (fit.predict(&[2.0, 1.0]) - 6.0).abs() < 1e-9,
            "{:?}",
            fit.coefficients()
        );
    }

    #[test]
    fn the_prior_is_scaled_until_enough_steps_are_seen() {
        let mut fit = LinearCost::new([0.0, 1.0]);
        assert_eq!(fit.predict(&[5.0, 2.0]), 2.0);
        // Steps twice as slow as the prior says.
        fit.update(&[1.0, 3.0], 6.0);
        assert_eq!(fit.coefficients(), [0.0, 2.0]);
        fit.update(&[1.0, 3.0], f64::NAN);
        assert_eq!(
            fit.coefficients(),
            [0.0, 2.0],
            "a bad measurement is ignored"
        );
    }

    #[test]
    fn an_outlier_enters_the_fit_capped() {
        let mut fit = LinearCost::new([1.0]);
        for k in 0..FIT_MIN_STEPS as u32 + 4 {
            fit.update(&[f64::from(k % 3 + 1)], f64::from(k % 3 + 1));
        }
        // A preempted step, 100 times its cost: enters as 4 times.
        fit.update(&[1.0], 100.0);
        assert!(fit.predict(&[1.0]) < 1.2, "{:?}", fit.coefficients());
    }

    #[test]
    fn the_margin_is_the_ninetieth_percentile_of_the_ratios() {
        let mut m = Margin::default();
        assert_eq!(m.factor(), MARGIN_DEFAULT);
        for k in 0..MARGIN_WINDOW {
            // ratios 1.00, 1.01, … 1.47
            m.observe(10.0, 10.0 + k as f64 * 0.1);
        }
        assert!((m.factor() - 1.42).abs() < 1e-9, "{}", m.factor());
        for _ in 0..MARGIN_WINDOW {
            m.observe(1.0, 0.5);
        }
        assert_eq!(m.factor(), 1.0, "never below the prediction");
        for _ in 0..MARGIN_WINDOW {
            m.observe(1.0, 100.0);
        }
        assert_eq!(m.factor(), MARGIN_MAX);
    }

    #[test]
    fn the_largest_fitting_step_is_found() {
        let cost = |n: u64| 0.5 + 0.01 * n as f64;
        assert_eq!(largest_fitting(10_000, 10.5, cost), 1000);
        assert_eq!(largest_fitting(300, 10.5, cost), 300);
        assert_eq!(largest_fitting(300, 0.505, cost), 0);
        assert_eq!(largest_fitting(0, 10.0, cost), 0);
        assert_eq!(largest_fitting(7, 0.51, cost), 1);
    }

    #[test]
    fn chunk_features_share_objects_pro_rata() {
        let f = ChunkFeatures::new(vec![
            ObjectCost {
                triangles: 100,
                fragments: 1000.0,
            },
            ObjectCost {
                triangles: 12,
                fragments: 50_000.0,
            },
            ObjectCost {
                triangles: 200,
                fragments: 2000.0,
            },
        ]);
        assert_eq!(f.total(), 312);
        // Half the first object: half its fragments.
        assert_eq!(f.features(0, 50), [0.05, 0.05]);
        // The end of the first, all of the second, the start of the third.
        let x = f.features(90, 32);
        assert!(
            (x[1] - (100.0 + 50_000.0 + 100.0) / 1e4).abs() < 1e-12,
            "{x:?}"
        );
        // The last object only.
        assert_eq!(f.features(112, 200), [0.2, 0.2]);
    }

    #[test]
    fn band_features_count_the_rows_fragments() {
        // 2×3: rows hold 1, 0 and 4 fragments.
        let b = BandFeatures::from_offsets(2, 3, &[0, 1, 1, 1, 1, 3, 5]);
        assert_eq!(b.features(0, 3), [0.03, 5e-4]);
        assert_eq!(b.features(1, 1), [0.01, 0.0]);
        assert_eq!(b.features(2, 1), [0.01, 4e-4]);
        let mut o = ObjectFragments::default();
        let id = strata_core::ObjectId;
        o.add(&[id(3), id(3), id(0)]);
        assert_eq!(o.get(id(3)), Some(2));
        assert_eq!(o.get(id(1)), None);
        assert_eq!(o.total(), 3);
    }
}
