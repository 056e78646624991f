//! Per-pixel features for a learned variable k-buffer (Tsopouridis 2021 §4.2), gathered in the
//! counting pass the variable k-buffer already runs — no extra geometry pass.
//!
//! # Two stages
//!
//! 1. **Accumulate** ([`FeatureAccumulator`], filled through [`FeatureCapture`] together with the
//!    fragment counts): order-independent per-pixel sums, strip-owned like the counters, so no
//!    atomics. Layout: one [`PixelSums`] per pixel, row-major (56 bytes with padding), so a
//!    fragment updates one or two cache lines rather than one per sum:
//!
//!    ```text
//!    nearest:       u64   (depth bits << 32) | rgba8 bits of the nearest fragment; the minimum
//!                         key wins, so ties between equal depths break on the colour bits
//!    sum_sq:        u64   Σ (r² + g² + b²), 8-bit channels
//!    log_t:         u64   Σ −ln(1 − α) over the non-opaque fragments, fixed point (2⁻²⁰)
//!    depth_max:     f32   farthest window depth
//!    alpha_max:     f32   max α
//!    sum:           [u32; 4]  Σ straight-alpha r, g, b and α, 8-bit channels
//!    opaque:        u32   fragments with α = 1 (255)
//!    ```
//!
//!    Fragments of a pixel arrive in primitive order from the one thread that owns the pixel's
//!    strip, so the float sums are the same for any thread count.
//!
//! 2. **Finish** ([`FeatureMaps::compute`]): per-pixel features from the sums, the frame's counts
//!    and the budget `M`, into [`FeatureMaps`], a struct of arrays: one plane of `w·h` `f32` per
//!    feature, in the order of [`FEATURES`]. The budget features are the only ones that depend on
//!    `M`, so one accumulation serves any number of budgets (the dataset renders each view once).
//!
//! # The feature list
//!
//! [`FEATURES`] names every feature, its unit and definition, in order; [`FEATURE_SET`] names the
//! list with a version. A weights file stores both and is checked against them before use, so a
//! change of order, meaning or scaling must bump the version. Features 0–11 are the seed's twelve
//! (Tsopouridis 2021 §4.2, L810–819: count ratio, budget ratio, local and scene min/max depth,
//! mean and nearest colour); 12–22 are additions the seed lacks (alpha and transmittance, colour
//! spread, neighbourhood counts, periphery, budget per covered pixel, contrast against the
//! background). Uncovered pixels have 0 in every per-pixel feature; the frame features (1, 4, 5,
//! 13) are the same in every pixel.

use rayon::prelude::*;
use strata_core::{Fragment, Rgba8};
use strata_raster::{CaptureTarget, FragmentSink, StripLayout};

use crate::count::FragmentCounts;
use crate::method::{StoreError, try_alloc};

/// Name and version of the feature list ([`FEATURES`]); bump it whenever the list changes.
pub const FEATURE_SET: &str = "strata-vk-features-2";

/// One feature: what a column of the feature maps holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FeatureInfo {
    /// Short identifier, as stored in weights and dataset manifests.
    pub name: &'static str,
    /// Unit or range.
    pub unit: &'static str,
    /// Definition, in words.
    pub definition: &'static str,
}

const fn info(name: &'static str, unit: &'static str, definition: &'static str) -> FeatureInfo {
    FeatureInfo {
        name,
        unit,
        definition,
    }
}

/// Every feature, in column order; see the module docs.
pub const FEATURES: [FeatureInfo; FEATURE_COUNT] = [
    info(
        "count_share",
        "ratio",
        "fragments of the pixel / fragments of the frame N (the thesis's feature 1)",
    ),
    info(
        "budget_share",
        "ratio",
        "budget M / N, the same in every pixel (the thesis's feature 2)",
    ),
    info(
        "depth_min",
        "window depth [0, 1]",
        "depth of the pixel's nearest fragment (the thesis's feature 3)",
    ),
    info(
        "depth_max",
        "window depth [0, 1]",
        "depth of the pixel's farthest fragment (the thesis's feature 4)",
    ),
    info(
        "scene_depth_min",
        "window depth [0, 1]",
        "nearest fragment depth of the frame (the thesis's feature 5)",
    ),
    info(
        "scene_depth_max",
        "window depth [0, 1]",
        "farthest fragment depth of the frame (the thesis's feature 6)",
    ),
    info(
        "mean_r",
        "[0, 1]",
        "Σ red / count over the pixel's fragments (the thesis's feature 7, not composited)",
    ),
    info(
        "mean_g",
        "[0, 1]",
        "Σ green / count (the thesis's feature 7)",
    ),
    info(
        "mean_b",
        "[0, 1]",
        "Σ blue / count (the thesis's feature 7)",
    ),
    info(
        "nearest_r",
        "[0, 1]",
        "red of the nearest fragment (the thesis's feature 8)",
    ),
    info(
        "nearest_g",
        "[0, 1]",
        "green of the nearest fragment (the thesis's feature 8)",
    ),
    info(
        "nearest_b",
        "[0, 1]",
        "blue of the nearest fragment (the thesis's feature 8)",
    ),
    info("count", "fragments", "fragments of the pixel"),
    info(
        "budget_per_covered",
        "fragments",
        "M / covered pixels C: the average k a covered pixel can have",
    ),
    info("alpha_sum", "[0, count]", "Σ α over the pixel's fragments"),
    info("alpha_max", "[0, 1]", "largest α of the pixel's fragments"),
    info(
        "transmittance",
        "[0, 1]",
        "Π (1 − α): the light that passes every fragment",
    ),
    info("nearest_alpha", "[0, 1]", "α of the nearest fragment"),
    info("opaque_count", "fragments", "fragments with α = 1"),
    info(
        "color_variance",
        "[0, 1]",
        "mean over r, g, b of E[c²] − E[c]² over the fragments",
    ),
    info(
        "count_mean_3x3",
        "fragments",
        "mean count over the 3 × 3 pixels around (those inside the image)",
    ),
    info(
        "count_max_3x3",
        "fragments",
        "largest count over the 3 × 3 pixels around",
    ),
    info(
        "periphery",
        "[0, 1]",
        "distance of the pixel centre from the image centre / half the diagonal",
    ),
    info(
        "contrast",
        "[0, √3]",
        "‖mean colour − background‖ (RGB, Euclidean): what the layers show against the background",
    ),
    info(
        "nearest_contrast",
        "[0, √3]",
        "‖nearest fragment's colour − background‖",
    ),
];

/// Number of features ([`FEATURES`]`.len()`).
pub const FEATURE_COUNT: usize = 25;

/// The names of [`FEATURES`], in order.
pub fn feature_names() -> Vec<&'static str> {
    FEATURES.iter().map(|f| f.name).collect()
}

/// Column of the feature called `name`.
pub fn feature_index(name: &str) -> Option<usize> {
    FEATURES.iter().position(|f| f.name == name)
}

/// Rows per parallel work item of the finishing pass.
const ROWS_PER_TASK: usize = 8;

/// One pixel's order-independent sums; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelSums {
    nearest: u64,
    sum_sq: u64,
    log_t: u64,
    depth_max: f32,
    alpha_max: f32,
    sum: [u32; 4],
    opaque: u32,
}

impl Default for PixelSums {
    fn default() -> Self {
        PixelSums {
            nearest: NO_FRAGMENT,
            sum_sq: 0,
            log_t: 0,
            depth_max: 0.0,
            alpha_max: 0.0,
            sum: [0; 4],
            opaque: 0,
        }
    }
}

/// Per-pixel order-independent sums of one frame's fragments; see the module docs.
#[derive(Debug, Default)]
pub struct FeatureAccumulator {
    width: u32,
    height: u32,
    sums: Vec<PixelSums>,
}

/// Fixed-point scale of [`FeatureAccumulator`]'s `log_t`.
const LOG_T_SCALE: f64 = (1u64 << 20) as f64;

/// `round(−ln(1 − a/255) · 2²⁰)` for every 8-bit alpha `a` below 255 (0 for 255: an opaque
/// fragment is counted, not summed). Integer sums are the same in any order, which float sums
/// and products are not: the features must not depend on the order the triangles are drawn in.
fn log_t_table() -> &'static [u64; 256] {
    static TABLE: std::sync::OnceLock<[u64; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|a| {
            if a == 255 {
                0
            } else {
                (-(1.0 - a as f64 / 255.0).ln() * LOG_T_SCALE).round() as u64
            }
        })
    })
}

/// The `nearest` key of an empty pixel.
const NO_FRAGMENT: u64 = u64::MAX;

/// Resets `v` to `n` copies of `value`, allocating on first use or a size change.
fn reset<T: Copy + Default + Send + Sync>(
    v: &mut Vec<T>,
    n: usize,
    value: T,
) -> Result<(), StoreError> {
    if v.len() != n {
        *v = Vec::new();
        *v = try_alloc(
            n,
            || format!("{n} per-pixel feature sums"),
            "render a smaller image",
        )?;
    }
    v.par_iter_mut().for_each(|x| *x = value);
    Ok(())
}

impl FeatureAccumulator {
    /// Empty sums.
    pub fn new() -> Self {
        Self::default()
    }

    /// Resets the sums of a `width` × `height` frame, allocating them on first use.
    pub fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        let n = width as usize * height as usize;
        (self.width, self.height) = (width, height);
        reset(&mut self.sums, n, PixelSums::default())
    }

    /// Width and height of the frame the sums are for.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The mean colour and mean alpha of pixel `p`'s `count` fragments (zeros when it has none).
    pub fn means(&self, p: usize, count: u32) -> ([f32; 3], f32) {
        if count == 0 {
            return ([0.0; 3], 0.0);
        }
        let unit = |sum: u32| (f64::from(sum) / 255.0 / f64::from(count)) as f32;
        let [r, g, b, a] = self.sums[p].sum;
        ([unit(r), unit(g), unit(b)], unit(a))
    }

    /// Bytes of the sums.
    pub fn memory_bytes(&self) -> u64 {
        (self.sums.len() * std::mem::size_of::<PixelSums>()) as u64
    }
}

/// The nearest-fragment key: depth bits (non-negative, so they order like the depth) above the
/// colour bits.
fn nearest_key(fragment: &Fragment) -> u64 {
    let depth = if fragment.depth > 0.0 {
        fragment.depth.to_bits()
    } else {
        0
    };
    (u64::from(depth) << 32) | u64::from(fragment.color.to_bits())
}

/// Counts and accumulates the features of one frame: the counting pass of a variable k-buffer
/// that also gathers [`FeatureAccumulator`] sums. Clear both before rasterizing into it.
#[derive(Debug)]
pub struct FeatureCapture<'a> {
    /// The fragment counters (as [`FragmentCounts`] alone would count).
    pub counts: &'a mut FragmentCounts,
    /// The feature sums.
    pub sums: &'a mut FeatureAccumulator,
}

/// One strip's counters and sums.
#[derive(Debug)]
pub struct FeatureSink<'a> {
    first_pixel: usize,
    counts: &'a mut [u32],
    sums: &'a mut [PixelSums],
}

impl FragmentSink for FeatureSink<'_> {
    #[inline]
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        let i = pixel as usize - self.first_pixel;
        let [r, g, b, a] = fragment.color.0.map(u32::from);
        self.counts[i] += 1;
        let s = &mut self.sums[i];
        s.nearest = s.nearest.min(nearest_key(&fragment));
        s.depth_max = s.depth_max.max(fragment.depth);
        s.sum[0] += r;
        s.sum[1] += g;
        s.sum[2] += b;
        s.sum[3] += a;
        s.sum_sq += u64::from(r * r + g * g + b * b);
        s.alpha_max = s.alpha_max.max(a as f32 / 255.0);
        s.log_t += log_t_table()[a as usize];
        s.opaque += u32::from(a == 255);
    }
}

impl CaptureTarget for FeatureCapture<'_> {
    type Sink<'s>
        = FeatureSink<'s>
    where
        Self: 's;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<FeatureSink<'_>> {
        let s = &mut *self.sums;
        assert_eq!(
            (layout.width, layout.height),
            (s.width, s.height),
            "clear the feature sums before counting"
        );
        let mut counts = layout.split_mut(self.counts.counts_mut());
        let mut sums = layout.split_mut(&mut s.sums);
        (0..layout.count())
            .filter_map(|strip| {
                Some(FeatureSink {
                    first_pixel: layout.pixels(strip).start,
                    counts: counts.next()?,
                    sums: sums.next()?,
                })
            })
            .collect()
    }
}

/// The frame-level values every pixel's features share.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameFeatures {
    /// `N`, fragments of the frame.
    pub total: u64,
    /// `C`, covered pixels.
    pub covered: u64,
    /// `M`, the budget in fragments.
    pub budget: u64,
    /// Nearest fragment depth of the frame (0 if the frame is empty).
    pub depth_min: f32,
    /// Farthest fragment depth of the frame (0 if the frame is empty).
    pub depth_max: f32,
    /// The background the frame is composited over (linear RGB in [0, 1]).
    pub background: [f32; 3],
}

/// The features of one frame as a struct of arrays: plane `f` holds feature [`FEATURES`]`[f]`
/// of every pixel, row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FeatureMaps {
    width: u32,
    height: u32,
    planes: Vec<f32>,
    frame: Option<FrameFeatures>,
}

impl FeatureMaps {
    /// Empty maps.
    pub fn new() -> Self {
        Self::default()
    }

    /// Width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The frame-level values of the last [`FeatureMaps::compute`].
    pub fn frame(&self) -> Option<FrameFeatures> {
        self.frame
    }

    /// Feature `f` of every pixel, row-major.
    ///
    /// # Panics
    /// If `f` is not below [`FEATURE_COUNT`].
    pub fn plane(&self, f: usize) -> &[f32] {
        let n = self.width as usize * self.height as usize;
        &self.planes[f * n..(f + 1) * n]
    }

    /// The features of pixel `p`, in [`FEATURES`] order.
    pub fn pixel(&self, p: usize) -> [f32; FEATURE_COUNT] {
        let n = self.width as usize * self.height as usize;
        std::array::from_fn(|f| self.planes[f * n + p])
    }

    /// Every pixel's features interleaved, `[height, width, FEATURE_COUNT]` row-major (the layout
    /// of the exported `.npy`).
    pub fn interleaved(&self) -> Vec<f32> {
        let n = self.width as usize * self.height as usize;
        let mut out = vec![0.0; n * FEATURE_COUNT];
        out.par_chunks_mut(FEATURE_COUNT)
            .enumerate()
            .for_each(|(p, row)| {
                for (f, v) in row.iter_mut().enumerate() {
                    *v = self.planes[f * n + p];
                }
            });
        out
    }

    /// Bytes of the planes.
    pub fn memory_bytes(&self) -> u64 {
        (self.planes.len() * 4) as u64
    }

    /// Computes every feature from the accumulated `sums`, the per-pixel fragment `counts` of the
    /// same frame, the `budget` `M` in fragments and the `background`; returns the frame-level
    /// values.
    ///
    /// # Panics
    /// If `counts` does not have one entry per pixel of `sums`' frame.
    pub fn compute(
        &mut self,
        sums: &FeatureAccumulator,
        counts: &[u32],
        budget: u64,
        background: [f32; 3],
    ) -> FrameFeatures {
        let (w, h) = (sums.width as usize, sums.height as usize);
        let n = w * h;
        assert_eq!(counts.len(), n, "one count per pixel");
        (self.width, self.height) = (sums.width, sums.height);
        self.planes.clear();
        self.planes.resize(n * FEATURE_COUNT, 0.0);
        let frame = FrameFeatures::of(sums, counts, budget, background);
        let mut planes: Vec<&mut [f32]> = self.planes.chunks_mut(n.max(1)).collect();
        // Per task: ROWS_PER_TASK rows of every plane.
        let rows = ROWS_PER_TASK * w;
        let mut tasks: Vec<Vec<&mut [f32]>> =
            (0..n.div_ceil(rows.max(1))).map(|_| Vec::new()).collect();
        for plane in planes.iter_mut() {
            for (t, part) in plane.chunks_mut(rows.max(1)).enumerate() {
                tasks[t].push(part);
            }
        }
        tasks.into_par_iter().enumerate().for_each(|(t, mut out)| {
            let first_row = t * ROWS_PER_TASK;
            let mut i = 0;
            for y in first_row..(first_row + ROWS_PER_TASK).min(h) {
                for x in 0..w {
                    let row = sums.pixel_features(counts, &frame, x, y);
                    for (plane, v) in out.iter_mut().zip(row) {
                        plane[i] = v;
                    }
                    i += 1;
                }
            }
        });
        self.frame = Some(frame);
        frame
    }
}

impl FrameFeatures {
    /// `N`, `C` and the depth range of the frame whose feature `sums` and per-pixel `counts` are
    /// given, with budget `M` = `budget` and its `background`: sums over fixed chunks, the same
    /// for any thread count.
    pub fn of(
        sums: &FeatureAccumulator,
        counts: &[u32],
        budget: u64,
        background: [f32; 3],
    ) -> FrameFeatures {
        let (total, covered, lo, hi) = counts
            .par_chunks(8 * 1024)
            .zip(sums.sums.par_chunks(8 * 1024))
            .map(|(c, s)| {
                let (mut total, mut covered) = (0u64, 0u64);
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for (&c, s) in c.iter().zip(s) {
                    if c > 0 {
                        total += u64::from(c);
                        covered += 1;
                        lo = lo.min(f32::from_bits((s.nearest >> 32) as u32));
                        hi = hi.max(s.depth_max);
                    }
                }
                (total, covered, lo, hi)
            })
            .reduce(
                || (0, 0, f32::INFINITY, f32::NEG_INFINITY),
                |a, b| (a.0 + b.0, a.1 + b.1, a.2.min(b.2), a.3.max(b.3)),
            );
        let empty = covered == 0;
        FrameFeatures {
            total,
            covered,
            budget,
            depth_min: if empty { 0.0 } else { lo },
            depth_max: if empty { 0.0 } else { hi },
            background,
        }
    }
}

/// Mean and maximum count over the 3 × 3 pixels around `(x, y)` that lie inside the image.
fn neighbourhood(counts: &[u32], width: usize, height: usize, x: usize, y: usize) -> (f32, f32) {
    let (mut sum, mut max, mut n) = (0u32, 0u32, 0u32);
    for yy in y.saturating_sub(1)..(y + 2).min(height) {
        for xx in x.saturating_sub(1)..(x + 2).min(width) {
            let c = counts[yy * width + xx];
            sum += c;
            max = max.max(c);
            n += 1;
        }
    }
    (sum as f32 / n as f32, max as f32)
}

/// Distance of pixel `(x, y)`'s centre from the image centre over half the diagonal.
fn periphery(width: usize, height: usize, x: usize, y: usize) -> f32 {
    let (w, h) = (width as f32, height as f32);
    let dx = x as f32 + 0.5 - 0.5 * w;
    let dy = y as f32 + 0.5 - 0.5 * h;
    ((dx * dx + dy * dy) / (0.25 * (w * w + h * h))).sqrt()
}

impl FeatureAccumulator {
    /// Every feature of pixel `(x, y)`, in [`FEATURES`] order, from these sums, the frame's
    /// per-pixel `counts` and its `frame` values ([`FrameFeatures::of`]): what
    /// [`FeatureMaps::compute`] stores, for a pass that wants one pixel at a time.
    ///
    /// # Panics
    /// If `(x, y)` is outside the frame or `counts` does not cover it.
    pub fn pixel_features(
        &self,
        counts: &[u32],
        frame: &FrameFeatures,
        x: usize,
        y: usize,
    ) -> [f32; FEATURE_COUNT] {
        let (w, h) = (self.width as usize, self.height as usize);
        let total = frame.total.max(1) as f32;
        let mut out = [0.0; FEATURE_COUNT];
        out[1] = frame.budget as f32 / total;
        out[4] = frame.depth_min;
        out[5] = frame.depth_max;
        out[13] = frame.budget as f32 / frame.covered.max(1) as f32;
        let (mean3, max3) = neighbourhood(counts, w, h, x, y);
        out[20] = mean3;
        out[21] = max3;
        out[22] = periphery(w, h, x, y);
        let p = y * w + x;
        let count = counts[p];
        if count == 0 {
            return out;
        }
        let c = count as f32;
        let sums = &self.sums[p];
        let near = sums.nearest;
        let [nr, ng, nb, na] = Rgba8::from_bits(near as u32).to_unorm();
        let unit = |sum: u32| (f64::from(sum) / 255.0 / f64::from(count)) as f32;
        let [sum_r, sum_g, sum_b, alpha_sum] = sums.sum;
        let mean = [unit(sum_r), unit(sum_g), unit(sum_b)];
        out[0] = c / total;
        out[2] = f32::from_bits((near >> 32) as u32);
        out[3] = sums.depth_max;
        out[6..9].copy_from_slice(&mean);
        out[9..12].copy_from_slice(&[nr, ng, nb]);
        out[12] = c;
        out[14] = (f64::from(alpha_sum) / 255.0) as f32;
        out[15] = sums.alpha_max;
        out[16] = if sums.opaque > 0 {
            0.0
        } else {
            (-(sums.log_t as f64) / LOG_T_SCALE).exp() as f32
        };
        out[17] = na;
        out[18] = sums.opaque as f32;
        let mean_sq: f64 = [sum_r, sum_g, sum_b]
            .iter()
            .map(|&s| (f64::from(s) / 255.0 / f64::from(count)).powi(2))
            .sum();
        let sq = sums.sum_sq as f64 / (255.0 * 255.0) / f64::from(count);
        out[19] = ((sq - mean_sq) / 3.0).max(0.0) as f32;
        let bg = frame.background;
        let dist = |c: [f32; 3]| {
            ((c[0] - bg[0]).powi(2) + (c[1] - bg[1]).powi(2) + (c[2] - bg[2]).powi(2)).sqrt()
        };
        out[23] = dist(mean);
        out[24] = dist([nr, ng, nb]);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_counted() {
        let names = feature_names();
        assert_eq!(names.len(), FEATURE_COUNT);
        let set: std::collections::HashSet<_> = names.iter().collect();
        assert_eq!(set.len(), FEATURE_COUNT);
        assert_eq!(feature_index("count"), Some(12));
        assert_eq!(feature_index("nope"), None);
    }

    #[test]
    fn periphery_and_neighbourhood_by_hand() {
        // 4 × 2: centre (2, 1), half diagonal √(16 + 4)/2 = √5. Pixel 0's centre (0.5, 0.5):
        // distance √(2.25 + 0.25) = √2.5 → √2.5/√5 = √0.5.
        assert!((periphery(4, 2, 0, 0) - 0.5f32.sqrt()).abs() < 1e-6);
        let counts = [1, 2, 3, 4, 5, 6, 7, 8];
        // Pixel 0: neighbours 1, 2, 5, 6 → mean 3.5, max 6.
        assert_eq!(neighbourhood(&counts, 4, 2, 0, 0), (3.5, 6.0));
        // Pixel 5 (x 1, y 1): 1, 2, 3, 5, 6, 7 → mean 4, max 7.
        assert_eq!(neighbourhood(&counts, 4, 2, 1, 1), (4.0, 7.0));
    }
}
