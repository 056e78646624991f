//! Per-pixel features for a learned variable k-buffer (Tsopouridis 2021 §4.2), gathered in the
//! counting pass the variable k-buffer already runs — no extra geometry pass.
//!
//! # Two stages
//!
//! 1. **Accumulate** ([`FeatureAccumulator`], filled through [`FeatureCapture`] together with the
//!    fragment counts): order-independent per-pixel sums, strip-owned like the counters, so no
//!    atomics. Layout: a pixel's [`PixelSums`] (56 bytes) in two row-major arrays, its `head`
//!    (16 bytes) in one and the `rest` (40 bytes with padding) in the other:
//!
//!    ```text
//!    heads[p]:      [u64; 2]  three or more fragments: [nearest, sum_sq];
//!                             one or two: the keys of the first and the second fragment
//!      nearest:     u64   key (depth bits << 32) | rgba8 bits of the nearest fragment; the
//!                         minimum key wins, so ties between equal depths break on the colour
//!      sum_sq:      u64   Σ (r² + g² + b²), 8-bit channels
//!    rests[p]:      (three or more fragments; stale below)
//!      log_t:       u64   Σ −ln(1 − α) over the non-opaque fragments, fixed point (2⁻²⁰)
//!      depth_max:   f32   farthest window depth
//!      alpha_max:   u32   max α, 8-bit
//!      sum:         [u32; 4]  Σ straight-alpha r, g, b and α, 8-bit channels
//!      opaque:      u32   fragments with α = 1 (255)
//!    ```
//!
//!    A fragment's key holds all the sums need of it (its depth, clamped to 0 as the sums
//!    clamp it, and its colour). So a pixel's first two fragments are kept as two keys, stored
//!    without reading anything back, and its sums are formed from them at its third
//!    (`PixelSums::settled` forms them for a pixel of one or two, and the importance pass
//!    reads such a pixel's values straight from its keys, in lanes). Most covered pixels of a
//!    closed mesh hold two fragments (the full dragon: all 415,085 hold two or more, 48,004
//!    three or more): their counting writes 16 bytes, four pixels to a cache line, and loads
//!    nothing. The counting pass of the full dragon on one thread, AMD EPYC: 14.0 ms with one
//!    56-byte record a pixel, written whole at the first fragment and added to after; 12.1 ms
//!    with the keys in the record's first 16 bytes; 11.4 ms with them in an array of their own.
//!
//!    Fragments of a pixel arrive in primitive order from the one thread that owns the pixel's
//!    strip, so the float sums are the same for any thread count. The sums are never cleared: a
//!    pixel's entries start afresh with its fragments (its key at the first, its second key at
//!    the second, its `rests` entry at the third), and nothing reads what its count does not
//!    cover. Each strip's sink also keeps the depth range of its
//!    fragments, and sums its counts into its `N` and `C` when the strip ends (not two counters
//!    a fragment); these give the frame values ([`FrameFeatures::of`]) without a pass over the
//!    pixels.
//!
//! 2. **Finish** ([`FeatureAccumulator::block_features`]): the features of a block of [`LANES`]
//!    pixels from their sums, the frame's counts and the budget `M`, as a struct of arrays
//!    computed lane by lane (vectorised); the only definition of the features, used by the
//!    learned k's importance pass ([`super::inference`]), by [`FeatureMaps::compute`] (one plane
//!    of `w·h` `f32` per feature, in the order of [`FEATURES`]: `render --maps` and the dataset)
//!    and by [`FeatureAccumulator::pixel_features`]. The budget features are the only ones that
//!    depend on `M`, so one accumulation serves any number of budgets (the dataset renders each
//!    view once).
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

/// One pixel's order-independent sums, as the accumulator's two arrays hold them: `head` in
/// one, `rest` in the other; see the module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelSums {
    /// Three or more fragments: `[nearest, sum_sq]`. One or two: the fragments' keys, and
    /// `rest` is stale.
    head: [u64; 2],
    rest: PixelRest,
}

/// The sums beside `[nearest, sum_sq]`, valid for a pixel of three or more fragments.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PixelRest {
    log_t: u64,
    depth_max: f32,
    alpha_max: u32,
    sum: [u32; 4],
    opaque: u32,
}

impl Default for PixelRest {
    fn default() -> Self {
        PixelRest {
            log_t: 0,
            depth_max: 0.0,
            alpha_max: 0,
            sum: [0; 4],
            opaque: 0,
        }
    }
}

impl PixelSums {
    /// The sums of a pixel whose one fragment has `key` ([`nearest_key`]).
    #[inline(always)]
    fn of_key(key: u64, log_t: &[u64; 256]) -> PixelSums {
        let [r, g, b, a] = Rgba8::from_bits(key as u32).0.map(u32::from);
        PixelSums {
            head: [key, u64::from(r * r + g * g + b * b)],
            rest: PixelRest {
                log_t: log_t[a as usize],
                // The key's depth: the fragment's, or 0 where that is not above 0 (NaN
                // included).
                depth_max: f32::from_bits((key >> 32) as u32),
                alpha_max: a,
                sum: [r, g, b, a],
                opaque: u32::from(a == 255),
            },
        }
    }

    /// Adds the fragment of `key` to these sums (of one fragment or more).
    #[inline(always)]
    fn add_key(&mut self, key: u64, log_t: &[u64; 256]) {
        let [r, g, b, a] = Rgba8::from_bits(key as u32).0.map(u32::from);
        let depth = f32::from_bits((key >> 32) as u32);
        self.head[0] = self.head[0].min(key);
        self.head[1] += u64::from(r * r + g * g + b * b);
        let rest = &mut self.rest;
        if depth > rest.depth_max {
            rest.depth_max = depth;
        }
        rest.sum[0] += r;
        rest.sum[1] += g;
        rest.sum[2] += b;
        rest.sum[3] += a;
        rest.alpha_max = rest.alpha_max.max(a);
        rest.log_t += log_t[a as usize];
        rest.opaque += u32::from(a == 255);
    }

    /// The sums of a pixel of `count` fragments (at least 1), formed from its keys if it has
    /// one or two.
    #[inline(always)]
    fn settled(&self, count: u32, log_t: &[u64; 256]) -> PixelSums {
        if count > 2 {
            return *self;
        }
        let mut sums = PixelSums::of_key(self.head[0], log_t);
        if count == 2 {
            sums.add_key(self.head[1], log_t);
        }
        sums
    }
}

/// Per-pixel order-independent sums of one frame's fragments; see the module docs.
///
/// A pixel's entries are valid while its count is not 0 (its `heads` entry from its first
/// fragment, its second key from its second, its `rests` entry from its third): the counting
/// pass starts them afresh at
/// the pixel's first fragment, so they are never cleared between frames (the counts are).
#[derive(Debug, Default)]
pub struct FeatureAccumulator {
    width: u32,
    height: u32,
    /// Per pixel, `PixelSums::head`: its first two fragments' keys, or the head of its sums.
    heads: Vec<[u64; 2]>,
    /// Per pixel, `PixelSums::rest`.
    rests: Vec<PixelRest>,
    /// `N`, `C` and the depth range of each strip's fragments, kept by its sink.
    strips: Vec<StripStats>,
}

/// What one strip's sink counts beside the per-pixel sums.
#[derive(Clone, Copy, Debug, PartialEq)]
struct StripStats {
    fragments: u64,
    covered: u64,
    depth_min: f32,
    depth_max: f32,
}

impl Default for StripStats {
    fn default() -> Self {
        StripStats {
            fragments: 0,
            covered: 0,
            depth_min: f32::INFINITY,
            depth_max: f32::NEG_INFINITY,
        }
    }
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

impl FeatureAccumulator {
    /// Empty sums.
    pub fn new() -> Self {
        Self::default()
    }

    /// Readies the sums for a `width` × `height` frame, allocating them on first use or a size
    /// change. Clear the counts with them: a pixel's sums start afresh at its first fragment.
    pub fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        let n = width as usize * height as usize;
        (self.width, self.height) = (width, height);
        self.strips.clear();
        if self.heads.len() != n || self.rests.len() != n {
            // Both or neither: a failed allocation leaves the sums empty, to be tried again.
            (self.heads, self.rests) = (Vec::new(), Vec::new());
            let heads = try_alloc(
                n,
                || format!("{n} per-pixel feature sums (heads)"),
                "render a smaller image",
            )?;
            self.rests = try_alloc(
                n,
                || format!("{n} per-pixel feature sums"),
                "render a smaller image",
            )?;
            self.heads = heads;
        }
        Ok(())
    }

    /// Width and height of the frame the sums are for.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The mean colour and mean alpha of pixel `p`'s `count` fragments (zeros when it has none).
    /// `count` must be the pixel's count from the same counting pass: the sums of a pixel with
    /// none are last frame's, not zeros.
    pub fn means(&self, p: usize, count: u32) -> ([f32; 3], f32) {
        if count == 0 {
            return ([0.0; 3], 0.0);
        }
        let unit = |sum: u32| mean_of(sum as f32, count as f32);
        let [r, g, b, a] = self.pixel_sums(p).settled(count, log_t_table()).rest.sum;
        ([unit(r), unit(g), unit(b)], unit(a))
    }

    /// Pixel `p`'s sums as stored (keys, for a pixel of one or two fragments).
    fn pixel_sums(&self, p: usize) -> PixelSums {
        PixelSums {
            head: self.heads[p],
            rest: self.rests[p],
        }
    }

    /// Bytes of the sums.
    pub fn memory_bytes(&self) -> u64 {
        (self.heads.len() * size_of::<[u64; 2]>() + self.rests.len() * size_of::<PixelRest>())
            as u64
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
/// that also gathers [`FeatureAccumulator`] sums. Clear both before a frame's first call
/// (a frame may be counted in several calls, its counts and sums carried over).
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
    heads: &'a mut [[u64; 2]],
    rests: &'a mut [PixelRest],
    stats: &'a mut StripStats,
    log_t: &'static [u64; 256],
}

impl FragmentSink for FeatureSink<'_> {
    #[inline(always)]
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        let i = pixel as usize - self.first_pixel;
        let key = nearest_key(&fragment);
        let stats = &mut *self.stats;
        // Plain compares, not `f32::min`/`max` (which also test for NaN): the key's depth is
        // never NaN, and a NaN depth fails `>` and is ignored, as `max` ignores it.
        let near = f32::from_bits((key >> 32) as u32);
        if near < stats.depth_min {
            stats.depth_min = near;
        }
        if fragment.depth > stats.depth_max {
            stats.depth_max = fragment.depth;
        }
        let n = self.counts[i];
        self.counts[i] = n + 1;
        let head = &mut self.heads[i];
        if n < 2 {
            // The pixel's first or second fragment this frame (the counts are cleared, the
            // sums are not): kept as its key, stored without loading anything back (the
            // module docs give the counting pass's times).
            head[n as usize & 1] = key;
            return;
        }
        let rest = &mut self.rests[i];
        let mut sums = if n == 2 {
            // The third: the sums of all three, written whole.
            let mut sums = PixelSums::of_key(head[0], self.log_t);
            sums.add_key(head[1], self.log_t);
            sums
        } else {
            PixelSums {
                head: *head,
                rest: *rest,
            }
        };
        sums.add_key(key, self.log_t);
        (*head, *rest) = (sums.head, sums.rest);
    }

    /// The strip's `N` and `C` from its counts, once, rather than two counters a fragment (the
    /// counting pass of the full dragon, one thread, AMD EPYC: 14.80 → 14.51 ms, medians of six
    /// side-by-side rounds).
    fn finish(&mut self) {
        let (mut fragments, mut covered) = (0u64, 0u64);
        for &c in self.counts.iter() {
            fragments += u64::from(c);
            covered += u64::from(c != 0);
        }
        (self.stats.fragments, self.stats.covered) = (fragments, covered);
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
        debug_assert!(
            s.strips.is_empty() || s.strips.len() == layout.count(),
            "one strip layout a frame: clear the sums before counting with another"
        );
        if s.strips.len() != layout.count() {
            s.strips = vec![StripStats::default(); layout.count()];
        }
        let mut counts = layout.split_mut(self.counts.counts_mut());
        let mut heads = layout.split_mut(&mut s.heads);
        let mut rests = layout.split_mut(&mut s.rests);
        let mut stats = s.strips.iter_mut();
        (0..layout.count())
            .filter_map(|strip| {
                Some(FeatureSink {
                    first_pixel: layout.pixels(strip).start,
                    counts: counts.next()?,
                    heads: heads.next()?,
                    rests: rests.next()?,
                    stats: stats.next()?,
                    log_t: log_t_table(),
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
        let frame = FrameFeatures::of(sums, budget, background);
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
        // Dispatched like the importance pass, so the features' lane loops (and their fused
        // multiply-adds) are compiled for the CPU's instruction set.
        let arch = pulp::Arch::new();
        tasks.into_par_iter().enumerate().for_each(|(t, out)| {
            let first = t * ROWS_PER_TASK * w;
            let end = (first + ROWS_PER_TASK * w).min(n);
            arch.dispatch(PlaneRows {
                sums,
                counts,
                frame: &frame,
                pixels: first..end,
                out,
            });
        });
        self.frame = Some(frame);
        frame
    }
}

/// One task of [`FeatureMaps::compute`]: the features of `pixels` into `out`, one slice a plane.
struct PlaneRows<'a> {
    sums: &'a FeatureAccumulator,
    counts: &'a [u32],
    frame: &'a FrameFeatures,
    pixels: std::ops::Range<usize>,
    out: Vec<&'a mut [f32]>,
}

impl pulp::WithSimd for PlaneRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let PlaneRows {
            sums,
            counts,
            frame,
            pixels: range,
            mut out,
        } = self;
        let mut block = [[0.0; LANES]; FEATURE_COUNT];
        let mut pixels = [0; LANES];
        for start in range.clone().step_by(LANES) {
            let lanes = LANES.min(range.end - start);
            for (l, p) in pixels[..lanes].iter_mut().enumerate() {
                *p = start + l;
            }
            sums.block_features(counts, frame, &pixels[..lanes], &mut block);
            let at = start - range.start;
            for (plane, f) in out.iter_mut().zip(&block) {
                plane[at..at + lanes].copy_from_slice(&f[..lanes]);
            }
        }
    }
}

impl FrameFeatures {
    /// `N`, `C` and the depth range of the frame whose counting pass left `sums` (kept per
    /// strip by the pass: no pass over the pixels), with budget `M` = `budget` and its
    /// `background`. Strips are combined in order: the same for any thread count.
    pub fn of(sums: &FeatureAccumulator, budget: u64, background: [f32; 3]) -> FrameFeatures {
        let all = sums
            .strips
            .iter()
            .fold(StripStats::default(), |a, s| StripStats {
                fragments: a.fragments + s.fragments,
                covered: a.covered + s.covered,
                depth_min: a.depth_min.min(s.depth_min),
                depth_max: a.depth_max.max(s.depth_max),
            });
        let empty = all.covered == 0;
        FrameFeatures {
            total: all.fragments,
            covered: all.covered,
            budget,
            depth_min: if empty { 0.0 } else { all.depth_min },
            depth_max: if empty { 0.0 } else { all.depth_max },
            background,
        }
    }
}

/// `sum / (255 · count)` for an 8-bit channel's sum over `count` fragments, both exact in `f32`
/// (below 2²⁴): one correctly rounded division, vectorisable, the mean of
/// [`FeatureAccumulator::means`] and of the feature blocks.
#[inline(always)]
fn mean_of(sum: f32, count: f32) -> f32 {
    sum / (255.0 * count)
}

/// Pixels whose features are computed together ([`FeatureBlock`]).
pub const LANES: usize = 8;

/// One value for each of [`LANES`] pixels.
pub type Lanes = [f32; LANES];

/// The features of [`LANES`] pixels as a struct of arrays: `block[feature][lane]`, features in
/// [`FEATURES`] order. Every feature is computed lane by lane with the same branch-free
/// arithmetic, which the compiler turns into SIMD; a lane's values do not depend on the other
/// lanes, so a pixel's features are the same bits in whichever block or position it lands.
pub type FeatureBlock = [Lanes; FEATURE_COUNT];

/// Sum, maximum and number of the counts over the 3 × 3 pixels around `(x, y)` that lie inside
/// the image (their mean is `sum / number`).
#[inline(always)]
fn neighbourhood(counts: &[u32], width: usize, height: usize, x: usize, y: usize) -> [u32; 3] {
    if x > 0 && y > 0 && x + 1 < width && y + 1 < height {
        // Inside: nine loads from one slice, no bounds to clip.
        let start = (y - 1) * width + x - 1;
        let c = &counts[start..start + 2 * width + 3];
        let (mut sum, mut max) = (0u32, 0u32);
        for row in [0, width, 2 * width] {
            let r = [c[row], c[row + 1], c[row + 2]];
            sum += r[0] + r[1] + r[2];
            max = max.max(r[0]).max(r[1]).max(r[2]);
        }
        return [sum, max, 9];
    }
    let (mut sum, mut max, mut n) = (0u32, 0u32, 0u32);
    for yy in y.saturating_sub(1)..(y + 2).min(height) {
        for xx in x.saturating_sub(1)..(x + 2).min(width) {
            let c = counts[yy * width + xx];
            sum += c;
            max = max.max(c);
            n += 1;
        }
    }
    [sum, max, n]
}

/// Distance of pixel `(x, y)`'s centre from the image centre over half the diagonal.
#[inline]
fn periphery(width: usize, height: usize, x: f32, y: f32) -> f32 {
    let (w, h) = (width as f32, height as f32);
    let dx = x + 0.5 - 0.5 * w;
    let dy = y + 0.5 - 0.5 * h;
    ((dx * dx + dy * dy) / (0.25 * (w * w + h * h))).sqrt()
}

/// `‖c − background‖` (RGB, Euclidean).
#[inline]
fn distance(c: [f32; 3], background: [f32; 3]) -> f32 {
    let d = [
        c[0] - background[0],
        c[1] - background[1],
        c[2] - background[2],
    ];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// `count · Σ c² − Σ_ch (Σ c)²` over r, g, b (`3 · 255² · count² · variance`), exactly, as
/// `f32`. In `u64` while `count · Σ c²` fits, which it does below about ten million fragments a
/// pixel (the densest scenes here hold a few hundred); in `u128` beyond (the `u32` channel sums
/// themselves wrap past 16.8 million fragments of 255 in one pixel). An integer converts to the
/// nearest `f32` whatever its width, so both give the same bits.
#[inline(always)]
fn spread(count: u32, sum_sq: u64, sum: [u32; 4]) -> f32 {
    let squares = |c: u32| u64::from(c) * u64::from(c);
    let narrow = u64::from(count).checked_mul(sum_sq).and_then(|all| {
        let s = squares(sum[0]).checked_add(squares(sum[1]))?;
        Some(all.saturating_sub(s.checked_add(squares(sum[2]))?))
    });
    match narrow {
        Some(spread) => spread as f32,
        None => {
            let squares: u128 = sum[..3]
                .iter()
                .map(|&c| u128::from(c) * u128::from(c))
                .sum();
            (u128::from(count) * u128::from(sum_sq)).saturating_sub(squares) as f32
        }
    }
}

/// The sums of one block's pixels as a struct of arrays, copied one pixel at a time as they
/// are stored (the only scalar stage of [`FeatureAccumulator::block_features`]); the lane loops
/// after it convert them, which the compiler vectorises.
#[derive(Default)]
struct Gathered {
    count: [u32; LANES],
    /// `nearest` split into depth and 8-bit r, g, b, α.
    near_depth: Lanes,
    near: [[u32; LANES]; 4],
    depth_max: Lanes,
    alpha_max: [u32; LANES],
    sum: [[u32; LANES]; 4],
    /// `Σ −ln(1 − α)` over the fragments, fixed point (infinite where one is opaque).
    log_t: Lanes,
    opaque: [u32; LANES],
    /// `3 · 255² · count² · variance`, exactly: `count · Σ c² − Σ_ch (Σ c)²`.
    spread: Lanes,
    /// [`neighbourhood`]'s sum, maximum and number of pixels.
    around: [[u32; LANES]; 3],
    x: [u32; LANES],
    y: [u32; LANES],
    /// A pixel of one or two fragments: the fields above follow from its keys (in lanes,
    /// `PixelSums::settled`'s values); one of three or more has them copied from its settled
    /// sums. Its keys (the first twice for one); zeros elsewhere.
    keys: [[u64; LANES]; 2],
}

// Lane loops index several planes by one lane: the shape the compiler vectorises.
#[allow(clippy::needless_range_loop)]
impl Gathered {
    /// Lane `l` from the settled sums `s` of a pixel of `count` fragments.
    #[inline(always)]
    fn take_settled(&mut self, l: usize, count: u32, s: &PixelSums) {
        let [nearest, sum_sq] = s.head;
        self.count[l] = count;
        self.near_depth[l] = f32::from_bits((nearest >> 32) as u32);
        let near = Rgba8::from_bits(nearest as u32).0;
        for c in 0..4 {
            self.near[c][l] = u32::from(near[c]);
            self.sum[c][l] = s.rest.sum[c];
        }
        self.depth_max[l] = s.rest.depth_max;
        self.alpha_max[l] = s.rest.alpha_max;
        self.log_t[l] = if s.rest.opaque > 0 {
            f32::INFINITY
        } else {
            s.rest.log_t as f32
        };
        self.opaque[l] = s.rest.opaque;
        self.spread[l] = spread(count, sum_sq, s.rest.sum);
    }

    /// Lane `l` from the keys in `head` of a pixel of one or two fragments; its values follow in
    /// [`Gathered::settle_keys`].
    #[inline(always)]
    fn take_keys(&mut self, l: usize, count: u32, head: &[u64; 2]) {
        self.count[l] = count;
        self.keys[0][l] = head[0];
        self.keys[1][l] = if count == 2 { head[1] } else { head[0] };
    }

    /// The lanes of pixels of one or two fragments (most of a closed mesh's) from their keys:
    /// the values [`Gathered::take_settled`] gives for [`PixelSums::settled`]'s sums (a test
    /// holds them equal). A pixel of one has its key twice, where a repeat changes nothing
    /// (the nearest, the maxima, the spread), and counts it once in the sums (`two` is 0).
    /// Lanes without a pixel have zero keys, which give the zeros they hold.
    #[inline(always)]
    fn settle_keys(&mut self, log_t: &[u64; 256]) {
        for l in 0..LANES {
            if self.count[l] > 2 {
                continue;
            }
            let [k0, k1] = [self.keys[0][l], self.keys[1][l]];
            let two = u32::from(self.count[l] == 2);
            let nearest = k0.min(k1);
            self.near_depth[l] = f32::from_bits((nearest >> 32) as u32);
            let channel = |k: u64, c: usize| (k >> (8 * c)) as u32 & 0xff;
            let mut diff = 0;
            for c in 0..4 {
                let (a, b) = (channel(k0, c), channel(k1, c));
                self.near[c][l] = channel(nearest, c);
                self.sum[c][l] = a + two * b;
                if c < 3 {
                    diff += a.abs_diff(b).pow(2);
                }
            }
            let (d0, d1) = (
                f32::from_bits((k0 >> 32) as u32),
                f32::from_bits((k1 >> 32) as u32),
            );
            self.depth_max[l] = if d1 > d0 { d1 } else { d0 };
            let (a0, a1) = (channel(k0, 3), channel(k1, 3));
            self.alpha_max[l] = a0.max(a1);
            let opaque = u32::from(a0 == 255) + two * u32::from(a1 == 255);
            self.opaque[l] = opaque;
            self.log_t[l] = if opaque > 0 {
                f32::INFINITY
            } else {
                (log_t[a0 as usize] + u64::from(two) * log_t[a1 as usize]) as f32
            };
            // count · Σc² − (Σc)² of two fragments is Σ (c₀ − c₁)², and 0 for one.
            self.spread[l] = diff as f32;
        }
    }
}

impl FeatureAccumulator {
    /// The features of the pixels `pixels` (row-major indices in increasing order, at most
    /// [`LANES`]) into the first lanes of `out`, from these sums, the frame's per-pixel `counts` and its `frame`
    /// values ([`FrameFeatures::of`]); the lanes past `pixels.len()` hold values to ignore.
    /// Uncovered pixels have 0 in every per-pixel feature (their sums are not read, so they need
    /// not have been cleared).
    ///
    /// # Panics
    /// If a pixel is outside the frame, `counts` does not cover the frame, or `pixels` holds
    /// more than [`LANES`] pixels; in debug builds, if `pixels` is not increasing.
    // Lane loops index every plane by lane: the shape the compiler vectorises.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    pub fn block_features(
        &self,
        counts: &[u32],
        frame: &FrameFeatures,
        pixels: &[usize],
        out: &mut FeatureBlock,
    ) {
        assert!(pixels.len() <= LANES, "at most {LANES} pixels a block");
        let (w, h) = (self.width as usize, self.height as usize);
        let mut g = Gathered::default();
        // A block of LANES neighbours along one row, away from the image's edges (most blocks
        // of a frame): its 3 × 3 neighbourhoods in lanes, from the sums and maxima of its ten
        // columns, in integers, so the values `neighbourhood` gives one pixel at a time. (The
        // full dragon's importance pass: 15.1 → 14.3 ms on one thread, AMD EPYC.)
        debug_assert!(
            pixels.is_sorted_by(|a, b| a < b),
            "pixels in increasing order"
        );
        // Increasing, eight of them, and seven apart: consecutive. (Checking each step instead
        // cost the pass 0.5 ms.)
        let run = pixels.len() == LANES && pixels[LANES - 1] - pixels[0] == LANES - 1 && {
            let (x0, y0) = (pixels[0] % w, pixels[0] / w);
            x0 > 0 && x0 + LANES < w && y0 > 0 && y0 + 1 < h
        };
        if run {
            let p0 = pixels[0];
            let rows =
                [p0 - w - 1, p0 - 1, p0 + w - 1].map(|start| &counts[start..start + LANES + 2]);
            let mut col_sum = [0u32; LANES + 2];
            let mut col_max = [0u32; LANES + 2];
            for i in 0..LANES + 2 {
                col_sum[i] = rows[0][i] + rows[1][i] + rows[2][i];
                col_max[i] = rows[0][i].max(rows[1][i]).max(rows[2][i]);
            }
            for l in 0..LANES {
                g.around[0][l] = col_sum[l] + col_sum[l + 1] + col_sum[l + 2];
                g.around[1][l] = col_max[l].max(col_max[l + 1]).max(col_max[l + 2]);
                g.around[2][l] = 9;
            }
        }
        // One pixel's sums into lane `l`: copied where they are settled, else its keys, whose
        // values follow in lanes (`Gathered::settle_keys`).
        let take = |g: &mut Gathered, l: usize, count: u32, head: &[u64; 2], rest: &PixelRest| {
            if count > 2 {
                let (head, rest) = (*head, *rest);
                g.take_settled(l, count, &PixelSums { head, rest });
            } else {
                g.take_keys(l, count, head);
            }
        };
        if run {
            // Such a block's columns follow from the first, and its counts and sums are one
            // slice each: no column steps or bounds checks a pixel (the importance pass:
            // 14.1 → 13.7 ms on one thread, AMD EPYC).
            let p0 = pixels[0];
            let (x0, y0) = (p0 % w, p0 / w);
            let row = &counts[p0..p0 + LANES];
            let heads = &self.heads[p0..p0 + LANES];
            let rests = &self.rests[p0..p0 + LANES];
            for l in 0..LANES {
                (g.x[l], g.y[l]) = ((x0 + l) as u32, y0 as u32);
                if row[l] != 0 {
                    take(&mut g, l, row[l], &heads[l], &rests[l]);
                }
            }
        } else {
            // The pixel's column and row: one division for the block's first pixel, then steps
            // along its row (a block is mostly a run of neighbours).
            let (mut x, mut y, mut last) = (0, 0, usize::MAX);
            for (l, &p) in pixels.iter().enumerate() {
                match p.checked_sub(last) {
                    Some(step) if x + step < w => x += step,
                    _ => (x, y) = (p % w, p / w),
                }
                last = p;
                (g.x[l], g.y[l]) = (x as u32, y as u32);
                let [sum, max, n] = neighbourhood(counts, w, h, x, y);
                (g.around[0][l], g.around[1][l], g.around[2][l]) = (sum, max, n);
                if counts[p] != 0 {
                    take(&mut g, l, counts[p], &self.heads[p], &self.rests[p]);
                }
            }
        }
        g.settle_keys(log_t_table());
        // The integers as f32, lane by lane (every one converts to its nearest f32, in lanes
        // as one at a time).
        let f = |v: [u32; LANES]| v.map(|v| v as f32);
        let count_f = f(g.count);
        let near_f = g.near.map(f);
        let sum_f = g.sum.map(f);
        let (alpha_max_f, opaque_f) = (f(g.alpha_max), f(g.opaque));
        let around_f = g.around.map(f);
        let (x_f, y_f) = (f(g.x), f(g.y));
        let total = frame.total.max(1) as f32;
        let budget = frame.budget as f32;
        let per_covered = budget / frame.covered.max(1) as f32;
        let bg = frame.background;
        // The 8-bit values are divided, not multiplied by 1/255: the bits of `means` and of
        // the resolve's unorm table.
        for l in 0..LANES {
            let count = count_f[l];
            let covered = count > 0.0;
            let c = count.max(1.0);
            let mean = [
                mean_of(sum_f[0][l], c),
                mean_of(sum_f[1][l], c),
                mean_of(sum_f[2][l], c),
            ];
            let near = [
                near_f[0][l] / 255.0,
                near_f[1][l] / 255.0,
                near_f[2][l] / 255.0,
            ];
            out[0][l] = count / total;
            out[1][l] = budget / total;
            out[2][l] = g.near_depth[l];
            out[3][l] = g.depth_max[l];
            out[4][l] = frame.depth_min;
            out[5][l] = frame.depth_max;
            out[6][l] = mean[0];
            out[7][l] = mean[1];
            out[8][l] = mean[2];
            out[9][l] = near[0];
            out[10][l] = near[1];
            out[11][l] = near[2];
            out[12][l] = count;
            out[13][l] = per_covered;
            out[14][l] = sum_f[3][l] / 255.0;
            out[15][l] = alpha_max_f[l] / 255.0;
            let t = super::fast_math::fast_exp(-g.log_t[l] * (1.0 / LOG_T_SCALE as f32));
            out[16][l] = if covered && g.log_t[l] < f32::INFINITY {
                t
            } else {
                0.0
            };
            out[17][l] = near_f[3][l] / 255.0;
            out[18][l] = opaque_f[l];
            out[19][l] = g.spread[l] / (3.0 * 255.0 * 255.0 * c * c);
            out[20][l] = around_f[0][l] / around_f[2][l];
            out[21][l] = around_f[1][l];
            out[22][l] = periphery(w, h, x_f[l], y_f[l]);
            out[23][l] = if covered { distance(mean, bg) } else { 0.0 };
            out[24][l] = if covered { distance(near, bg) } else { 0.0 };
        }
    }

    /// Every feature of pixel `(x, y)`, in [`FEATURES`] order: [`FeatureAccumulator::block_features`]
    /// for one pixel.
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
        assert!(
            x < self.width as usize && y < self.height as usize,
            "pixel ({x}, {y}) outside the frame"
        );
        let mut block = [[0.0; LANES]; FEATURE_COUNT];
        self.block_features(counts, frame, &[y * self.width as usize + x], &mut block);
        block.map(|f| f[0])
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

    /// `spread` in `u128` throughout: the definition the `u64` path must equal.
    fn spread_wide(count: u32, sum_sq: u64, sum: [u32; 4]) -> f32 {
        let squares: u128 = sum[..3].iter().map(|&c| u128::from(c).pow(2)).sum();
        (u128::from(count) * u128::from(sum_sq)).saturating_sub(squares) as f32
    }

    /// A pixel of one or two fragments read from its keys in lanes (`settle_keys`) gives the
    /// values its settled sums give (`take_settled` of `PixelSums::settled`): the same nearest
    /// fragment, maxima, sums, transmittance and spread, bit for bit. Dropping the second
    /// key's colour from the sums, or its alpha from the transmittance, fails it.
    #[test]
    fn keys_give_the_values_of_their_settled_sums() {
        let table = log_t_table();
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let key = |r: u64| {
            let depth = match r % 4 {
                0 => 0,
                1 => 1.0f32.to_bits(),
                _ => ((r >> 40) as f32 / (1u64 << 24) as f32).to_bits(),
            };
            let alpha = match (r >> 2) % 4 {
                0 => 0,
                1 => 255,
                _ => (r >> 16) as u8,
            };
            let colour = Rgba8([(r >> 24) as u8, (r >> 32) as u8, (r >> 48) as u8, alpha]);
            (u64::from(depth) << 32) | u64::from(colour.to_bits())
        };
        let bits = |v: &Lanes| v.map(f32::to_bits);
        for round in 0..2000 {
            let (mut from_keys, mut from_sums) = (Gathered::default(), Gathered::default());
            for l in 0..LANES {
                let count = (next() % 3) as u32;
                if count == 0 {
                    continue; // an uncovered lane: nothing taken either way
                }
                let stale = PixelSums {
                    head: [key(next()), key(next())],
                    ..PixelSums::of_key(key(next()), table)
                };
                from_keys.take_keys(l, count, &stale.head);
                from_sums.take_settled(l, count, &stale.settled(count, table));
            }
            from_keys.settle_keys(table);
            let (a, b) = (&from_keys, &from_sums);
            assert_eq!(a.count, b.count, "round {round}");
            assert_eq!(bits(&a.near_depth), bits(&b.near_depth), "round {round}");
            assert_eq!(a.near, b.near, "round {round}");
            assert_eq!(bits(&a.depth_max), bits(&b.depth_max), "round {round}");
            assert_eq!(a.alpha_max, b.alpha_max, "round {round}");
            assert_eq!(a.sum, b.sum, "round {round}");
            assert_eq!(bits(&a.log_t), bits(&b.log_t), "round {round}");
            assert_eq!(a.opaque, b.opaque, "round {round}");
            assert_eq!(bits(&a.spread), bits(&b.spread), "round {round}");
        }
    }

    #[test]
    fn spread_by_hand() {
        // Three fragments (10, 20, 30), (0, 0, 0), (5, 5, 5): Σc² = 1400 + 0 + 75 = 1475,
        // sums (15, 25, 35): 3 · 1475 − (225 + 625 + 1225) = 2350.
        assert_eq!(spread(3, 1475, [15, 25, 35, 0]), 2350.0);
        // Identical fragments have no spread.
        assert_eq!(spread(4, 4 * 3 * 200 * 200, [800, 800, 800, 0]), 0.0);
    }

    proptest::proptest! {
        /// Whichever path it takes — `count · Σc²` within `u64` or past it, the squares of the
        /// sums within it or past it — the spread is the `u128` one's, to the bit.
        #[test]
        fn spread_equals_the_u128_arithmetic(
            count in proptest::prop_oneof![0u32..1000, proptest::num::u32::ANY],
            sum_sq in proptest::prop_oneof![
                0u64..1 << 40,
                (u64::MAX >> 33)..(u64::MAX >> 31),
                proptest::num::u64::ANY
            ],
            sum in proptest::array::uniform4(proptest::prop_oneof![
                0u32..1 << 20,
                proptest::num::u32::ANY
            ]),
        ) {
            proptest::prop_assert_eq!(
                spread(count, sum_sq, sum).to_bits(),
                spread_wide(count, sum_sq, sum).to_bits()
            );
        }
    }

    #[test]
    fn periphery_and_neighbourhood_by_hand() {
        // 4 × 2: centre (2, 1), half diagonal √(16 + 4)/2 = √5. Pixel 0's centre (0.5, 0.5):
        // distance √(2.25 + 0.25) = √2.5 → √2.5/√5 = √0.5.
        assert!((periphery(4, 2, 0.0, 0.0) - 0.5f32.sqrt()).abs() < 1e-6);
        let counts = [1, 2, 3, 4, 5, 6, 7, 8];
        // Pixel 0: neighbours 1, 2, 5, 6 → sum 14 of 4 (mean 3.5), max 6.
        assert_eq!(neighbourhood(&counts, 4, 2, 0, 0), [14, 6, 4]);
        // Pixel 5 (x 1, y 1): 1, 2, 3, 5, 6, 7 → sum 24 of 6 (mean 4), max 7.
        assert_eq!(neighbourhood(&counts, 4, 2, 1, 1), [24, 7, 6]);
        // 4 × 3, inside: pixels (1, 1) and (2, 1) read all nine around them (9 + 1 + 2 +
        // 4 + 5 + 6 + 8 + 0 + 1 = 36, max 9; 1 + 2 + 3 + 5 + 6 + 7 + 0 + 1 + 2 = 27, max 7).
        let counts = [9, 1, 2, 3, 4, 5, 6, 7, 8, 0, 1, 2];
        assert_eq!(neighbourhood(&counts, 4, 3, 1, 1), [36, 9, 9]);
        assert_eq!(neighbourhood(&counts, 4, 3, 2, 1), [27, 7, 9]);
    }
}
