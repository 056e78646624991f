//! The weight-factor (WF) resolve: every fragment's contribution computed from the fragments in
//! front of it, without sorting (Lin 2007 §2.5.2, Eq. 2–4; Amor et al. 2006).
//!
//! # What it computes
//!
//! Breaking the recursion of the OVER operator, a pixel with fragments `i` (colour `c_i`, alpha
//! `α_i`) over an opaque background `b` is
//!
//! ```text
//! c = Σ_i w_i α_i c_i + w_b b          (Eq. 2, with the background as the last, opaque term)
//! w_i = Π_j a_j,  a_j = 1 − α_j if j is in front of i, else 1          (Eq. 3–4)
//! w_b = Π_j (1 − α_j)                   (every fragment is in front of the background)
//! ```
//!
//! Each fragment is compared with every other fragment of its pixel (the thesis's `i(i−1)/2`
//! comparisons), so the cost is quadratic in the depth complexity but needs no sort.
//!
//! "In front" is a strict total order: `j` is in front of `i` iff
//! `order_key(j) < order_key(i)`, and for equal keys (identical fragments: same depth, object
//! and colour) iff `j` was stored before `i`. The thesis's `Z_j < Z_i` alone would give two
//! fragments at equal depth the same weight — neither attenuates the other — which differs from
//! any OVER order; with the total order equal-depth fragments blend exactly as the sorted OVER
//! does.
//!
//! # Storage and passes
//!
//! The thesis stores each pixel's transparent fragments "sequentially and connectedly" in the
//! M-buffer. The S-buffer's contiguous exactly-sized regions are that layout, so capture is the
//! [`SBuffer`]'s: **clear**, **count** (`capture.count`), **prefix sum** (`capture.prefix_sum`),
//! **capture** (`capture.capture`). The thesis's phase 2 (discard transparent fragments behind the
//! nearest opaque one) is applied in the resolve: those fragments get a weight of exactly 0
//! anyway, so skipping them changes nothing but the time.
//!
//! # Exactness
//!
//! Eq. 2–4 equal OVER in exact arithmetic, but the products and the sum are formed in a different
//! order than the front-to-back loop of [`strata_core::composite`], so the f32 results differ in
//! the last bits and an 8-bit channel can differ by one step where the exact value lies close to a
//! rounding boundary. Tests hold the difference to at most one step on the built-in scenes; the
//! largest difference measured is one step, on a few channels per frame at most (11 channels over
//! 24 frames of `spheres` at 320×180, one on the full dragon at 1280×720), and none where every
//! fragment has the same alpha. The DeepFrame is the S-buffer's and is identical to the
//! A-buffer's.

use strata_core::fragment::unorm8;
use strata_core::{
    DeepFrame, DeepFrameError, DepthStats, Fragment, PassTimings, Rgb8Image, composite,
};
use strata_raster::{FrameInput, Rasterizer};

use crate::abuffer::sbuffer::SBuffer;
use crate::method::{CaptureReport, Method, StoreError};
use crate::options::MethodOptions;
use crate::resolve::resolve_pixels;

/// The name the method is selected by.
pub const NAME: &str = "wf";

/// The weight-factor resolve over an S-buffer; see the module docs.
#[derive(Debug, Default)]
pub struct WeightFactor {
    store: SBuffer,
    depth: Option<DepthStats>,
}

impl WeightFactor {
    /// An empty store (it reads no option).
    pub fn new(_options: &MethodOptions) -> Self {
        Self::default()
    }

    /// The S-buffer holding the fragments (the thesis's M-buffer).
    pub fn store(&self) -> &SBuffer {
        &self.store
    }
}

/// Composites one pixel's fragments, in any order, with Eq. 2–4 (see the module docs).
///
/// The result is the un-quantised colour in `[0, 1]`.
pub fn weight_factor_pixel(run: &[Fragment], background: [f32; 3]) -> [f32; 3] {
    // Phase 2: the nearest opaque fragment hides everything behind it.
    let opaque = run
        .iter()
        .filter(|f| f.color.alpha() == u8::MAX)
        .map(Fragment::order_key)
        .min();
    let visible = |f: &Fragment| opaque.is_none_or(|k| f.order_key() <= k);
    let mut acc = [0.0f32; 3];
    let mut background_weight = 1.0f32;
    for (i, fi) in run.iter().enumerate() {
        if !visible(fi) {
            continue;
        }
        let [r, g, b, a] = fi.color.to_unorm();
        background_weight *= 1.0 - a;
        let ki = fi.order_key();
        let mut w = 1.0f32;
        for (j, fj) in run.iter().enumerate() {
            let kj = fj.order_key();
            if kj < ki || (kj == ki && j < i) {
                w *= 1.0 - fj.color.to_unorm()[3];
            }
        }
        let wa = w * a;
        acc[0] += wa * r;
        acc[1] += wa * g;
        acc[2] += wa * b;
    }
    [
        acc[0] + background_weight * background[0],
        acc[1] + background_weight * background[1],
        acc[2] + background_weight * background[2],
    ]
}

impl Method for WeightFactor {
    fn name(&self) -> &'static str {
        NAME
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        self.depth = None;
        self.store.clear_counts(width, height)
    }

    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        self.store.capture_exact(raster, input, timings)
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        let regions = self.store.regions();
        let bg = composite::background_pixel(background);
        let (image, depth) = resolve_pixels(regions.width(), regions.height(), |p| {
            let run = regions.stored(p);
            if run.is_empty() {
                return (bg, 0);
            }
            let c = weight_factor_pixel(run, background);
            ([unorm8(c[0]), unorm8(c[1]), unorm8(c[2])], run.len() as u32)
        });
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    fn memory_bytes(&self) -> u64 {
        self.store.memory()
    }

    fn captures_in_chunks(&self) -> bool {
        true
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        Some(self.store.regions().deep_frame())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{ObjectId, Rgba8};

    fn frag(depth: f32, rgba: [u8; 4], o: u32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8(rgba),
            object: ObjectId(o),
        }
    }

    fn close(a: [f32; 3], b: [f32; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6)
    }

    #[test]
    fn seed_000_worked_example_in_any_order() {
        let red = frag(0.3, [255, 0, 0, 128], 0);
        let blue = frag(0.7, [0, 0, 255, 128], 1);
        let want = composite::over_front_to_back([red.color, blue.color], [1.0; 3]);
        for run in [[red, blue], [blue, red]] {
            let c = weight_factor_pixel(&run, [1.0; 3]);
            assert!(close(c, want), "{c:?} vs {want:?}");
        }
    }

    #[test]
    fn equal_depths_blend_like_sorted_over() {
        // Same depth, different objects: the lower object id is in front.
        let a = frag(0.5, [255, 0, 0, 200], 1);
        let b = frag(0.5, [0, 255, 0, 100], 2);
        let want = composite::over_front_to_back([a.color, b.color], [0.0; 3]);
        // Identical fragments: storage order decides, and both count.
        let twice = composite::over_front_to_back([a.color, a.color], [0.0; 3]);
        for (run, want) in [([a, b], want), ([b, a], want), ([a, a], twice)] {
            let c = weight_factor_pixel(&run, [0.0; 3]);
            assert!(close(c, want), "{c:?} vs {want:?}");
        }
    }

    #[test]
    fn opaque_fragment_hides_what_is_behind() {
        let glass = frag(0.2, [0, 0, 255, 128], 0);
        let wall = frag(0.5, [10, 20, 30, 255], 1);
        let hidden = frag(0.8, [255, 255, 255, 128], 2);
        let c = weight_factor_pixel(&[hidden, wall, glass], [0.0, 1.0, 0.0]);
        let want = composite::over_front_to_back([glass.color, wall.color], [0.0, 1.0, 0.0]);
        assert!(close(c, want), "{c:?} vs {want:?}");
    }
}
