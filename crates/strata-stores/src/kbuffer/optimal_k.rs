//! The Optimal-K oracle (Tsopouridis 2021 §4.2.2, Algorithm 23): the per-pixel k that a greedy search
//! finds closest to the A-buffer under a budget of M fragments.
//!
//! # Algorithm
//!
//! Start from every pixel's full count (`currentMemory = totalMemory`). The cost of pixel `p` at
//! `k` kept fragments is
//!
//! ```text
//! cd(p) = ‖ F(p) − C(p, k − 1) ‖₂      over RGB
//! ```
//!
//! the Euclidean distance between the pixel's full A-buffer colour `F` and its colour with one
//! more fragment removed, `C(p, j)` = OVER of its `j` nearest fragments onto the background — the
//! error the pixel would have against the A-buffer if it lost one more fragment. A min-heap holds
//! one entry `(cd, p)` per pixel that can still lose a fragment; repeatedly the cheapest pixel
//! loses its farthest fragment, its `cd` is recomputed and it goes back into the heap, until
//! `Σ k` reaches the budget.
//!
//! - **Floor of one.** As in the thesis ("eligible ... if it has more than one fragment left") no
//!   pixel drops below one fragment in the greedy phase — the same guarantee the importance-map
//!   allocation gives ([`super::allocate`]). If the budget is below the number of covered pixels
//!   `C`, a second phase (beyond the thesis, which would stop above the budget) takes the last
//!   fragment from the `C − M` pixels whose single fragment matters least
//!   (`‖F − background‖`, ties to the higher pixel index), as the importance allocation keeps the
//!   `M` most important ones. So `Σ k = min(M, N)` always, and `k(p) ≥ 1` for every covered pixel
//!   when `M ≥ C`.
//! - **Colours in float.** `F` and `C` are the resolve's `f32` colours before the 8-bit
//!   quantisation (the exact values [`composite::over_front_to_back`] returns, so `C(p, count)` is
//!   bit-identical to what the resolve composites). The thesis compares with the A-buffer's exported
//!   8-bit colour; quantising both sides would make most removals cost exactly 0 and hide the
//!   differences in contribution below half a step, which are what the ranking needs (and what a
//!   learned model regresses). The choice costs nothing in quality: removals the float cost ranks
//!   first are the ones that move the colour least, quantised or not.
//! - **Ties** break on the pixel index (heap keys are `cd` bits then pixel), so the result is
//!   deterministic.
//!
//! # Cost
//!
//! One parallel pass computes `F` and the first `cd` of every pixel and heapifies in O(P). Each
//! removal is a heap pop and push (O(log P)) plus one recomputation of `C(p, k − 1)`, O(k) over
//! the pixel's own run. The full dragon (≈ 946k fragments at 1280×720) takes well under a second.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::prelude::*;
use strata_core::{DeepFrame, Rgba8, composite};

use crate::regions::Regions;

/// Per-pixel fragment runs sorted front to back: what the oracle reads.
pub trait SortedRuns: Sync {
    /// Number of pixels.
    fn pixel_count(&self) -> usize;
    /// Fragments of pixel `p`.
    fn run_len(&self, p: usize) -> usize;
    /// The colour of the `i`-th nearest fragment of pixel `p`.
    fn color(&self, p: usize, i: usize) -> Rgba8;
}

impl SortedRuns for DeepFrame {
    fn pixel_count(&self) -> usize {
        self.offsets().len() - 1
    }

    fn run_len(&self, p: usize) -> usize {
        (self.offsets()[p + 1] - self.offsets()[p]) as usize
    }

    fn color(&self, p: usize, i: usize) -> Rgba8 {
        self.colors()[self.offsets()[p] as usize + i]
    }
}

/// Regions whose runs are sorted ([`Regions::sort_runs`], or KeepNearest regions).
impl SortedRuns for Regions {
    fn pixel_count(&self) -> usize {
        self.fill().len()
    }

    fn run_len(&self, p: usize) -> usize {
        self.fill()[p] as usize
    }

    fn color(&self, p: usize, i: usize) -> Rgba8 {
        self.stored(p)[i].color
    }
}

/// Colour of pixel `p` with its `j` nearest fragments, before quantisation.
fn partial<R: SortedRuns + ?Sized>(runs: &R, p: usize, j: usize, background: [f32; 3]) -> [f32; 3] {
    composite::over_front_to_back((0..j).map(|i| runs.color(p, i)), background)
}

fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    let (dr, dg, db) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    (dr * dr + dg * dg + db * db).sqrt()
}

/// Heap key: `cd` bits (non-negative, so they order like the value) then the pixel.
fn key(cd: f32, p: usize) -> u64 {
    (u64::from(cd.to_bits()) << 32) | p as u64
}

/// The Optimal-K of every pixel (row-major) for sorted `runs` composited onto `background`,
/// under a budget of `budget` fragments; see the module docs. `Σ k = min(budget, N)`.
pub fn optimal_k<R: SortedRuns + ?Sized>(runs: &R, background: [f32; 3], budget: u64) -> Vec<u32> {
    let mut k = Vec::new();
    optimal_k_into(runs, background, budget, &mut k);
    k
}

/// [`optimal_k`] into a reused vector.
pub fn optimal_k_into<R: SortedRuns + ?Sized>(
    runs: &R,
    background: [f32; 3],
    budget: u64,
    k: &mut Vec<u32>,
) {
    let pixels = runs.pixel_count();
    k.clear();
    k.par_extend((0..pixels).into_par_iter().map(|p| runs.run_len(p) as u32));
    let total: u64 = k.par_iter().map(|&c| u64::from(c)).sum();
    if budget >= total {
        return;
    }
    // F(p) for every pixel, and the first heap entry of every pixel that can lose a fragment.
    let full: Vec<[f32; 3]> = (0..pixels)
        .into_par_iter()
        .map(|p| {
            let n = runs.run_len(p);
            if n == 0 {
                background
            } else {
                partial(runs, p, n, background)
            }
        })
        .collect();
    let covered = k.par_iter().filter(|&&c| c > 0).count() as u64;
    let entries: Vec<Reverse<u64>> = (0..pixels)
        .into_par_iter()
        .filter(|&p| k[p] >= 2)
        .map(|p| {
            let cd = distance(full[p], partial(runs, p, k[p] as usize - 1, background));
            Reverse(key(cd, p))
        })
        .collect();
    let mut heap = BinaryHeap::from(entries);
    let mut current = total;
    let floor = budget.max(covered);
    while current > floor {
        let Some(Reverse(top)) = heap.pop() else {
            break;
        };
        let p = (top & u64::from(u32::MAX)) as usize;
        k[p] -= 1;
        current -= 1;
        if k[p] >= 2 {
            let cd = distance(full[p], partial(runs, p, k[p] as usize - 1, background));
            heap.push(Reverse(key(cd, p)));
        }
    }
    if budget < covered {
        // Below one fragment per covered pixel: empty the pixels whose last fragment matters least.
        let mut last: Vec<u64> = (0..pixels)
            .into_par_iter()
            .filter(|&p| k[p] > 0)
            .map(|p| {
                let cd = distance(full[p], background);
                // Ascending cd, ties to the higher index.
                (u64::from(cd.to_bits()) << 32) | u64::from(u32::MAX - p as u32)
            })
            .collect();
        let remove = (covered - budget) as usize;
        if remove < last.len() {
            last.select_nth_unstable(remove - 1);
        }
        for &key in &last[..remove] {
            k[(u32::MAX - (key & u64::from(u32::MAX)) as u32) as usize] = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{Fragment, ObjectId};

    fn frame(pixels: &[&[[u8; 4]]]) -> DeepFrame {
        let counts: Vec<u32> = pixels.iter().map(|p| p.len() as u32).collect();
        DeepFrame::build(pixels.len() as u32, 1, &counts, |p, out| {
            for (i, &c) in pixels[p].iter().enumerate() {
                out.push(Fragment {
                    depth: 0.1 * (i + 1) as f32,
                    color: Rgba8(c),
                    object: ObjectId(0),
                });
            }
        })
        .unwrap()
    }

    #[test]
    fn greedy_choices_by_hand() {
        // Over black. Pixel 0: white 50% then white 50% → F = 0.75 (all channels);
        //   dropping the 2nd gives 0.5: cd = 0.25·√3 = 0.433.
        // Pixel 1: white 50% then red 10% (alpha 26/255 ≈ 0.102): F = (0.551, 0.5, 0.5);
        //   dropping the red one gives 0.5: cd = 0.051.
        // Pixel 2: opaque white then anything → dropping the hidden 2nd costs 0.
        // Pixel 3: one fragment: never in the greedy phase.
        let white = [255, 255, 255, 128];
        let red = [255, 0, 0, 26];
        let df = frame(&[
            &[white, white],
            &[white, red],
            &[[255, 255, 255, 255], white],
            &[white],
        ]);
        let bg = [0.0; 3];
        // Total 7, budget 6: the free removal (pixel 2) goes first.
        assert_eq!(optimal_k(&df, bg, 6), [2, 2, 1, 1]);
        // Budget 5: then pixel 1 (cd 0.051 < 0.433).
        assert_eq!(optimal_k(&df, bg, 5), [2, 1, 1, 1]);
        // Budget 4 = covered pixels: pixel 0 too.
        assert_eq!(optimal_k(&df, bg, 4), [1, 1, 1, 1]);
        // Budget 7 = total: nothing removed.
        assert_eq!(optimal_k(&df, bg, 7), [2, 2, 2, 1]);
        assert_eq!(optimal_k(&df, bg, 100), [2, 2, 2, 1]);
        // Budget 3 < covered: the pixel whose one fragment is closest to the background loses it.
        // One white 50% over black: ‖(0.502,)*3‖ = 0.869 for pixels 0, 1 and 3; opaque white:
        // 1.732 for pixel 2. Ties go to the higher index: pixel 3 is emptied.
        assert_eq!(optimal_k(&df, bg, 3), [1, 1, 1, 0]);
        assert_eq!(optimal_k(&df, bg, 0), [0, 0, 0, 0]);
    }

    #[test]
    fn cost_is_against_the_full_colour_not_the_previous_one() {
        // Over black, a = 128/255 = 0.50196. Pixel 0: three 50% whites, F = 1 − (1 − a)³ =
        // 0.87647; with two: 0.75196 (cd 0.1245·√3 = 0.216); with one: 0.50196 (cd against F
        // 0.3745·√3 = 0.649, but only 0.25·√3 = 0.433 against the two-fragment colour).
        // Pixel 1: a 50% white then a 60% white (153/255): F = 0.80078; with one: cd = 0.2988·√3
        // = 0.518 — between the two readings of pixel 0's second removal.
        let w50 = [255, 255, 255, 128];
        let df = frame(&[&[w50, w50, w50], &[w50, [255, 255, 255, 153]]]);
        assert_eq!(optimal_k(&df, [0.0; 3], 4), [2, 2]);
        // Against the full colour pixel 1 (0.518) is cheaper than pixel 0 (0.649); an incremental
        // cost would have taken pixel 0 (0.433).
        assert_eq!(optimal_k(&df, [0.0; 3], 3), [2, 1]);
        assert_eq!(optimal_k(&df, [0.0; 3], 2), [1, 1]);
    }
}
