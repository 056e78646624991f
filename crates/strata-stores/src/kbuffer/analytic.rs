//! k(p) from an analytic error model, without learning: the bar a learned k has to clear.
//!
//! # Model
//!
//! A pixel of `c` fragments with mean colour `m` (over its fragments, not composited) and mean
//! opacity `ᾱ` is modelled as `c` layers of colour `m`, each letting `t = 1 − ᾱ` through. Keeping
//! its `k` nearest fragments leaves out what the layers behind them add, at most their weight
//! against the background:
//!
//! ```text
//! ê(k) = d · t^k,   d = ‖m − background‖ (RGB, Euclidean)
//! g(j) = ê(j − 1) − ê(j) = d · (1 − t) · t^(j − 1)       what the j-th fragment is worth
//! ```
//!
//! The worth of the next fragment falls geometrically, so the best way to spend `M` slots on the
//! model is to give them to the largest `g` over all pixels (water-filling): one threshold `λ`,
//! and every pixel keeps the fragments worth more than it. The mean opacity is used rather than
//! the product `Π(1 − α)`: one opaque layer at the back makes the product 0, which would say that
//! only the nearest fragment counts.
//!
//! # Allocation
//!
//! The same rules as the importance allocation ([`super::allocate`]): `M' = min(M, N)`; below one
//! fragment per covered pixel (`M' < C`) the `M'` pixels with the largest `ê(0) = d` get one
//! (ties to the lower pixel index); otherwise every covered pixel gets one and the `R = M' − C`
//! others go by worth:
//!
//! 1. in log space, `ln g(j) = ln(d (1 − t)) + (j − 1) ln t`; for a level `Λ` a pixel keeps
//!    `1 + n(Λ)` fragments, `n(Λ)` = the `j ≥ 2` with `ln g(j) > Λ`, at most `c − 1`;
//! 2. bisect `Λ` (sums over fixed chunks of the candidate pixels — those with room whose
//!    fragments are worth something — added in order) for a level at which `Σ n ≤ R`: until
//!    `Σ n = R` exactly, or the bracket is narrower than the smallest `|ln t|` (then no pixel has
//!    two fragments worth between its ends), or 64 rounds;
//! 3. the units left go to the pixels whose next fragment is worth most (ties to the lower pixel
//!    index), one each — with the bracket of step 2, exactly the greedy choice;
//! 4. pixels whose fragments are worth nothing (`d = 0`, `t = 0` or `t = 1`) take what is still
//!    left, in pixel order, up to their counts, so `Σ k = M'` whenever fragments remain.
//!
//! The result depends only on the counts, the sums and `M`: the same for any thread count.

use rayon::prelude::*;

use super::allocate::{Allocation, TotalF64, base_k, one_each_to_the_most};

/// Pixels per parallel work item.
const PIXELS_PER_TASK: usize = 8 * 1024;

/// Bisection rounds on the level.
const ROUNDS: u32 = 64;

/// One pixel's model: `ln g(2) = ln(d (1 − t) t)` and `ln t` (`-inf` where a fragment beyond
/// the first is worth nothing).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Worth {
    /// `ln(d · (1 − t) · t)`: the worth of the second fragment.
    pub log_first: f64,
    /// `ln t`, the worth's fall per fragment (≤ 0).
    pub log_fall: f64,
    /// `d`: what the pixel shows against the background (the worth of its first fragment).
    pub contrast: f64,
}

impl Worth {
    /// The model of a pixel of mean colour `mean`, mean opacity `mean_alpha`, on `background`.
    pub fn new(mean: [f32; 3], mean_alpha: f32, background: [f32; 3]) -> Worth {
        let d = Worth::contrast_of(mean, background);
        Worth::from_curve(d, f64::from(1.0 - mean_alpha.clamp(0.0, 1.0)))
    }

    /// `d = ‖mean − background‖`, as [`Worth::new`] computes it.
    #[inline(always)]
    pub fn contrast_of(mean: [f32; 3], background: [f32; 3]) -> f64 {
        (0..3)
            .map(|c| f64::from(mean[c] - background[c]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// The model of a pixel with at most one fragment, of contrast `d`: nothing beyond its
    /// first fragment to weigh, so only `d` is kept (it decides which pixels keep one when the
    /// budget cannot give every covered pixel one). [`analytic_k`] gives such a pixel the same
    /// `k` as [`Worth::new`]'s model, without its logarithms.
    pub fn at_most_one(d: f64) -> Worth {
        Worth {
            log_first: f64::NEG_INFINITY,
            log_fall: f64::NEG_INFINITY,
            contrast: d,
        }
    }

    /// The model of a pixel whose error curve is `ê(k) = d · t^k` (`d ≥ 0`, `t` in `[0, 1]`).
    pub fn from_curve(d: f64, t: f64) -> Worth {
        let t = t.clamp(0.0, 1.0);
        Worth {
            log_first: (d * (1.0 - t)).ln() + t.ln(),
            log_fall: t.ln(),
            contrast: d,
        }
    }

    /// Whether fragments beyond the first are worth anything.
    fn worthwhile(&self) -> bool {
        self.log_first.is_finite() && self.log_fall.is_finite() && self.log_fall < 0.0
    }

    /// `ln g(j)` of the `(extra + 2)`-th fragment.
    fn log_worth(&self, extra: u32) -> f64 {
        self.log_first + f64::from(extra) * self.log_fall
    }

    /// Fragments beyond the first worth more than `level` (`ln`), at most `room`, for a
    /// [`Worth::worthwhile`] model (only [`Candidate`]s, which are, ask: this runs once per
    /// candidate per bisection round, and checking again cost more than the rest of it).
    fn extra_above(&self, level: f64, room: u32) -> u32 {
        debug_assert!(self.worthwhile(), "only a worthwhile model is asked");
        if self.log_first <= level {
            return 0;
        }
        // j − 1 = 1 + i for i = 0, 1, …: ln g = log_first + i·log_fall > level; the
        // ⌈(level − log_first) / log_fall⌉ fragments i = 0 … ⌈·⌉ − 1 are above the level.
        let x = (level - self.log_first) / self.log_fall;
        if !x.is_finite() {
            return 0;
        }
        // The ceiling of x clamped to [0, room], by truncation (`f64::ceil` is a library call
        // on x86-64 without SSE4.1, and this runs once per candidate per bisection round).
        let x = x.clamp(0.0, f64::from(room));
        let whole = x as u32;
        whole + u32::from(f64::from(whole) < x)
    }
}

/// Computes `k` (resized to `counts.len()`) from the fragment `counts`, each pixel's [`Worth`]
/// and a `budget` of fragments; see the module docs.
///
/// # Panics
/// If `worth` does not hold one model per pixel of `counts` (a caller's bug, not an input).
pub fn analytic_k(counts: &[u32], worth: &[Worth], budget: u64, k: &mut Vec<u32>) -> Allocation {
    assert_eq!(counts.len(), worth.len(), "one worth per pixel");
    let pixels = counts.len();
    let (total, covered) = base_k(counts, k);
    let target = budget.min(total);
    let mut allocation = Allocation {
        budget,
        total,
        covered,
        sum: target,
        rounds: 0,
    };
    if target == total {
        k.copy_from_slice(counts);
        return allocation;
    }
    if target < covered {
        // The pixels that show most against the background get one.
        k.par_iter_mut().for_each(|k| *k = 0);
        one_each_to_the_most(counts, target, k, |p| worth[p].contrast);
        return allocation;
    }
    let mut rest = target - covered;
    // The candidates: pixels with room for more whose fragments are worth something, one list
    // per chunk of PIXELS_PER_TASK pixels, in pixel order (the same for any thread count).
    // With them, in the same pass, the level's range: every candidate's second fragment is
    // worth at most `hi`, and below `lo` every fragment of every candidate is in; and the
    // smallest fall of a worth per fragment.
    let (chunks, ranges): (Vec<Vec<Candidate>>, Vec<Range>) = counts
        .par_chunks(PIXELS_PER_TASK)
        .zip(worth.par_chunks(PIXELS_PER_TASK))
        .enumerate()
        .map(|(chunk, (c, w))| {
            let first = chunk * PIXELS_PER_TASK;
            let mut range = Range::EMPTY;
            let candidates = c
                .iter()
                .zip(w)
                .enumerate()
                .filter_map(|(i, (&c, &w))| {
                    let candidate = Candidate::new(w, c, (first + i) as u32)?;
                    range = range.with(&candidate);
                    Some(candidate)
                })
                .collect();
            (candidates, range)
        })
        .unzip();
    let range = ranges.iter().fold(Range::EMPTY, Range::join);
    let extra_at = |level: f64| -> u64 {
        chunks
            .par_iter()
            .map(|c| {
                c.iter()
                    .map(|c| u64::from(c.extra_above(level)))
                    .sum::<u64>()
            })
            .collect::<Vec<u64>>()
            .iter()
            .sum()
    };
    let (mut lo, mut hi) = (range.lo, range.hi);
    if hi.is_finite() {
        lo -= 1.0;
        if extra_at(lo) <= rest {
            hi = lo;
        } else {
            // Invariant: extra_at(hi) ≤ rest < extra_at(lo). A level with exactly `rest`
            // fragments above it ends the search: those are the `rest` worth most. So does a
            // bracket narrower than the smallest fall: then no pixel has two fragments worth
            // between `lo` and `hi`, and giving the units left one each to the pixels whose
            // next fragment is worth most (below) is the greedy choice.
            let narrowest = range.narrowest;
            for _ in 0..ROUNDS {
                if hi - lo < narrowest {
                    break;
                }
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                allocation.rounds += 1;
                let above = extra_at(mid);
                if above <= rest {
                    hi = mid;
                    if above == rest {
                        break;
                    }
                } else {
                    lo = mid;
                }
            }
        }
        let level = hi;
        // Each chunk of candidates covers its own chunk of pixels, so k is written in parallel.
        let given: u64 = k
            .par_chunks_mut(PIXELS_PER_TASK)
            .zip(&chunks)
            .enumerate()
            .map(|(chunk, (k, candidates))| {
                let first = chunk * PIXELS_PER_TASK;
                candidates
                    .iter()
                    .map(|c| {
                        let n = c.extra_above(level);
                        k[c.pixel as usize - first] += n;
                        u64::from(n)
                    })
                    .sum::<u64>()
            })
            .collect::<Vec<u64>>()
            .iter()
            .sum();
        rest -= given;
        // The units left: to the pixels whose next fragment is worth most. Those lie above `lo`
        // (more fragments than `rest` do, at most one per pixel), so only they are sorted; the
        // whole list serves if the rounds ran out first.
        if rest > 0 {
            let next_worths = |above: f64| -> Vec<(TotalF64, usize)> {
                chunks
                    .par_iter()
                    .map(|candidates| {
                        candidates
                            .iter()
                            .map(|c| c.pixel as usize)
                            .filter(|&p| k[p] < counts[p])
                            .map(|p| (TotalF64(worth[p].log_worth(k[p] - 1)), p))
                            .filter(|(w, _)| w.0 > above)
                            .collect::<Vec<_>>()
                    })
                    .collect::<Vec<_>>()
                    .concat()
            };
            let mut next = next_worths(lo);
            if (next.len() as u64) < rest {
                next = next_worths(f64::NEG_INFINITY);
            }
            let n = (rest as usize).min(next.len());
            let key = |e: &(TotalF64, usize)| (std::cmp::Reverse(e.0), e.1);
            if n > 0 && n < next.len() {
                next.select_nth_unstable_by_key(n - 1, key);
            }
            for &(_, p) in next.iter().take(n) {
                k[p] += 1;
            }
            rest -= n as u64;
        }
    }
    // Fragments worth nothing on the model fill what is left, in pixel order.
    for p in 0..pixels {
        if rest == 0 {
            break;
        }
        let room = u64::from(counts[p] - k[p]);
        let n = room.min(rest);
        k[p] += n as u32;
        rest -= n;
    }
    allocation
}

/// The least and largest worth of a set of candidates (the last fragment of each, and the
/// second), and their smallest fall `−ln t`.
#[derive(Clone, Copy, Debug)]
struct Range {
    lo: f64,
    hi: f64,
    narrowest: f64,
}

impl Range {
    const EMPTY: Range = Range {
        lo: f64::INFINITY,
        hi: f64::NEG_INFINITY,
        narrowest: f64::INFINITY,
    };

    fn with(self, c: &Candidate) -> Range {
        Range {
            lo: self.lo.min(c.worth.log_worth(c.room - 1)),
            hi: self.hi.max(c.worth.log_first),
            narrowest: self.narrowest.min(-c.worth.log_fall),
        }
    }

    fn join(self, other: &Range) -> Range {
        Range {
            lo: self.lo.min(other.lo),
            hi: self.hi.max(other.hi),
            narrowest: self.narrowest.min(other.narrowest),
        }
    }
}

/// A pixel with room for fragments beyond its first that are worth something.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    worth: Worth,
    room: u32,
    pixel: u32,
}

impl Candidate {
    /// Pixel `pixel` of `count` fragments and model `worth`, if it has a choice the model can
    /// make: more than one fragment, and fragments beyond the first worth something.
    #[inline]
    fn new(worth: Worth, count: u32, pixel: u32) -> Option<Candidate> {
        (count > 1 && worth.worthwhile()).then(|| Candidate {
            worth,
            room: count - 1,
            pixel,
        })
    }

    #[inline]
    fn extra_above(&self, level: f64) -> u32 {
        self.worth.extra_above(level, self.room)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn worth(d: f64, t: f64) -> Worth {
        Worth {
            log_first: (d * (1.0 - t)).ln() + t.ln(),
            log_fall: t.ln(),
            contrast: d,
        }
    }

    /// The greedy answer by brute force: hand out the slots one at a time to the largest worth.
    fn greedy(counts: &[u32], w: &[Worth], rest: u64) -> Vec<u32> {
        let mut k: Vec<u32> = counts.iter().map(|&c| u32::from(c > 0)).collect();
        for _ in 0..rest {
            let best = (0..counts.len())
                .filter(|&p| k[p] > 0 && k[p] < counts[p] && w[p].worthwhile())
                .max_by(|&a, &b| {
                    w[a].log_worth(k[a] - 1)
                        .total_cmp(&w[b].log_worth(k[b] - 1))
                        .then(b.cmp(&a))
                });
            match best {
                Some(p) => k[p] += 1,
                None => {
                    if let Some(p) = (0..counts.len()).find(|&p| k[p] < counts[p]) {
                        k[p] += 1;
                    }
                }
            }
        }
        k
    }

    #[test]
    fn fragments_go_where_they_are_worth_most() {
        // Pixel 0: faint glass (t = 0.9), pixel 1: dense layers (t = 0.2), same contrast.
        let counts = [6, 6];
        let w = [worth(1.0, 0.9), worth(1.0, 0.2)];
        let mut k = Vec::new();
        let a = analytic_k(&counts, &w, 6, &mut k);
        assert_eq!(a.sum, 6);
        assert_eq!(k.iter().sum::<u32>(), 6);
        // g(2), g(3), … for t = 0.2: 0.16, 0.032, …; for t = 0.9: 0.09, 0.081, 0.0729, … — the
        // dense pixel takes its second (0.16), the faint one the next three before the dense
        // pixel's third (0.032).
        assert_eq!(k, vec![4, 2]);
        assert_eq!(k, greedy(&counts, &w, 4));
    }

    #[test]
    fn below_one_per_covered_pixel_the_most_visible_pixels_win() {
        let counts = [3, 0, 2, 5];
        let w = [
            worth(0.2, 0.5),
            worth(0.0, 0.5),
            worth(0.9, 0.5),
            worth(0.5, 0.5),
        ];
        let mut k = Vec::new();
        analytic_k(&counts, &w, 2, &mut k);
        assert_eq!(k, vec![0, 0, 1, 1]);
    }

    #[test]
    fn worthless_fragments_still_use_the_budget() {
        // Opaque layers (t = 0) and an empty-contrast pixel: nothing beyond the first is worth
        // anything, but Σk must reach min(M, N).
        let counts = [3, 4];
        let w = [worth(1.0, 0.0), worth(0.0, 0.5)];
        let mut k = Vec::new();
        let a = analytic_k(&counts, &w, 5, &mut k);
        assert_eq!((a.sum, k.iter().sum::<u32>()), (5, 5));
        assert_eq!(k, vec![3, 2]);
    }

    /// The greedy answer with a heap: the same choice as [`greedy`] (largest worth first, ties
    /// to the lower pixel), fast enough for frames of several parallel chunks.
    fn heap_greedy(counts: &[u32], w: &[Worth], mut rest: u64) -> Vec<u32> {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let mut k: Vec<u32> = counts.iter().map(|&c| u32::from(c > 0)).collect();
        let mut heap: BinaryHeap<(TotalF64, Reverse<usize>)> = (0..counts.len())
            .filter(|&p| counts[p] > 1 && w[p].worthwhile())
            .map(|p| (TotalF64(w[p].log_worth(0)), Reverse(p)))
            .collect();
        while rest > 0 {
            let Some((_, Reverse(p))) = heap.pop() else {
                break;
            };
            k[p] += 1;
            rest -= 1;
            if k[p] < counts[p] {
                heap.push((TotalF64(w[p].log_worth(k[p] - 1)), Reverse(p)));
            }
        }
        for p in 0..counts.len() {
            let n = u64::from(counts[p] - k[p]).min(rest);
            k[p] += n as u32;
            rest -= n;
        }
        k
    }

    #[test]
    fn frames_of_many_chunks_give_the_greedy_result() {
        // 3.5 chunks of pixels, a handful of models (ties across chunks), depths up to 9.
        let pixels = 3 * PIXELS_PER_TASK + PIXELS_PER_TASK / 2;
        let mut x = 0x2545_f491u32;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        let counts: Vec<u32> = (0..pixels).map(|_| next() % 10).collect();
        let w: Vec<Worth> = (0..pixels)
            .map(|_| {
                worth(
                    [0.3, 0.8, 1.2][(next() % 3) as usize],
                    [0.2, 0.5, 0.9, 0.99][(next() % 4) as usize],
                )
            })
            .collect();
        let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        let covered = counts.iter().filter(|&&c| c > 0).count() as u64;
        for share in [0.35, 0.5, 0.7, 0.9] {
            let budget = (share * total as f64) as u64;
            assert!(budget > covered);
            let mut k = Vec::new();
            analytic_k(&counts, &w, budget, &mut k);
            assert_eq!(
                k,
                heap_greedy(&counts, &w, budget - covered),
                "share {share}"
            );
        }
    }

    proptest! {
        /// Few distinct models, so many pixels tie (one material over a whole mesh).
        #[test]
        fn ties_give_the_greedy_result_too(
            pixels in prop::collection::vec((0u32..9, 0usize..2, 0usize..3), 1..60),
            share in 0.0f64..1.0,
        ) {
            let counts: Vec<u32> = pixels.iter().map(|p| p.0).collect();
            let w: Vec<Worth> = pixels
                .iter()
                .map(|p| worth([0.5, 1.0][p.1], [0.3, 0.6, 0.95][p.2]))
                .collect();
            let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
            let covered = counts.iter().filter(|&&c| c > 0).count() as u64;
            let budget = (share * total as f64) as u64;
            let mut k = Vec::new();
            analytic_k(&counts, &w, budget, &mut k);
            if budget >= covered && budget < total {
                prop_assert_eq!(&k, &greedy(&counts, &w, budget - covered));
            }
        }

        #[test]
        fn the_rules_hold_and_the_result_is_the_greedy_one(
            pixels in prop::collection::vec((0u32..7, 0.0f64..1.5, 0.0f64..1.0), 1..40),
            share in 0.0f64..1.2,
        ) {
            let counts: Vec<u32> = pixels.iter().map(|p| p.0).collect();
            let w: Vec<Worth> = pixels.iter().map(|p| worth(p.1, p.2)).collect();
            let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
            let covered = counts.iter().filter(|&&c| c > 0).count() as u64;
            let budget = (share * total as f64) as u64;
            let mut k = Vec::new();
            let a = analytic_k(&counts, &w, budget, &mut k);
            let sum: u64 = k.iter().map(|&x| u64::from(x)).sum();
            prop_assert_eq!(sum, budget.min(total));
            prop_assert_eq!(a.sum, budget.min(total));
            for p in 0..counts.len() {
                prop_assert!(k[p] <= counts[p]);
                if budget.min(total) >= covered && counts[p] > 0 {
                    prop_assert!(k[p] >= 1);
                }
            }
            if budget.min(total) >= covered && budget < total {
                prop_assert_eq!(&k, &greedy(&counts, &w, budget - covered));
            }
        }
    }
}
