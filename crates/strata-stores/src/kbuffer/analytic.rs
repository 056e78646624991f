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
//!
//! # Data
//!
//! ```text
//! candidates, one list per chunk of 8,192 pixels, in pixel order (structure of arrays, kept
//! between frames in an AnalyticScratch):
//!   first[i], fall[i]   ln g(2) and ln t of the candidate's model (f64)
//!   room[i]             count − 1 (at least 2), the fragments it may get beyond its first
//!   pixel[i]            its pixel index
//!   given[i]            its share at the level the bisection found (step 3 reads it)
//!   singles             the candidates of room 1 (two fragments): first[i] and pixel[i]
//!                       only; a single keeps its second fragment at a level below its
//!                       first[i], a comparison without the others' division (so its share
//!                       follows from the level and is not stored)
//! ```
//!
//! Most candidates of a closed mesh are singles (the full dragon at 50 %: all but 48,004 of
//! 415,085). Counting them by comparison took this allocation (the `k` stage of `strata bench
//! dragon -m vkbuffer --k-from learned --budget 50% -j 1`, AMD EPYC with AVX-512) from
//! 9.2 to 7.7 ms, with the same `k`.
//!
//! A bisection round counts, per list, every candidate's fragments above the level in lanes
//! (`ExtraAt`, compiled per instruction set), with the division and ceiling of the one-at-a-time
//! count.

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

    /// `ln g(j)` of the `(extra + 2)`-th fragment (the tests' greedy references).
    #[cfg(test)]
    fn log_worth(&self, extra: u32) -> f64 {
        self.curve().log_worth(extra)
    }

    /// The worth curve alone, what the bisection reads.
    #[inline(always)]
    fn curve(&self) -> Curve {
        Curve {
            log_first: self.log_first,
            log_fall: self.log_fall,
        }
    }
}

/// A [`Worth`] without its contrast: the two numbers a candidate's worth per fragment comes
/// from, all the allocation's bisection reads (16 bytes a candidate rather than 24).
#[derive(Clone, Copy, Debug)]
struct Curve {
    /// `ln g(2)`.
    log_first: f64,
    /// `ln t`.
    log_fall: f64,
}

impl Curve {
    /// `ln g(j)` of the `(extra + 2)`-th fragment.
    #[inline(always)]
    fn log_worth(&self, extra: u32) -> f64 {
        self.log_first + f64::from(extra) * self.log_fall
    }

    /// Fragments beyond the first worth more than `level` (`ln`), at most `room` (at least
    /// 1), for a [`Worth::worthwhile`] model (only candidates, which are, ask). The bisection's
    /// rounds count the same values in lanes ([`ExtraAt`]); this gives each candidate its share
    /// once the level is found.
    #[inline(always)]
    fn extra_above(&self, level: f64, room: u32) -> u32 {
        // Not above a NaN level either.
        let above = self.log_first > level;
        if !above {
            return 0;
        }
        // j − 1 = 1 + i for i = 0, 1, …: ln g = log_first + i·log_fall > level; the
        // ⌈(level − log_first) / log_fall⌉ fragments i = 0 … ⌈·⌉ − 1 are above the level.
        // The quotient is positive, or +∞ where it overflows (every fragment is above), or 0
        // where it underflows: at least the first fragment is above (`log_first > level`).
        let x = (level - self.log_first) / self.log_fall;
        // The ceiling of x clamped to [1, room], by truncation (`f64::ceil` is a library call
        // on x86-64 without SSE4.1).
        let x = x.max(1.0).min(f64::from(room));
        let whole = x as u32;
        whole + u32::from(f64::from(whole) < x)
    }
}

/// The lists [`analytic_k_reusing`] keeps between frames: the candidates (pixels with a choice
/// the model can make), one list per chunk of pixels. A frame listed into fresh
/// lists paid for their growth and for fresh pages.
#[derive(Debug, Default)]
pub struct AnalyticScratch {
    chunks: Vec<Candidates>,
}

impl AnalyticScratch {
    /// No lists yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Bytes the lists hold.
    pub fn memory_bytes(&self) -> u64 {
        self.chunks.iter().map(Candidates::memory_bytes).sum()
    }
}

/// One chunk's candidates in pixel order, a structure of arrays: entry `i` is pixel
/// `pixel[i]`, whose fragments beyond the first are worth `ln g = first[i] + j · fall[i]`
/// (`j = 0, 1, …`), with room for `room[i]` of them (at least 2), of which `given[i]` were
/// given at the level the bisection found. The bisection's count reads only `first`, `fall`
/// and `room`, in lanes ([`ExtraAt`]). The candidates with room for one fragment are in
/// `singles`.
#[derive(Debug, Default)]
struct Candidates {
    first: Vec<f64>,
    fall: Vec<f64>,
    room: Vec<u32>,
    pixel: Vec<u32>,
    given: Vec<u32>,
    singles: Singles,
}

/// One chunk's candidates with room for one fragment beyond the first (pixels of two
/// fragments: most of a closed mesh's; all but 48,004 of the full dragon's 415,085), in pixel
/// order: pixel `pixel[i]`'s second fragment is worth `ln g = first[i]`, and it keeps it at a
/// level below that (its share follows from the level, so it is not stored). Their count at a
/// level is a comparison, without the division the others need ([`ExtraAt`]).
#[derive(Debug, Default)]
struct Singles {
    first: Vec<f64>,
    pixel: Vec<u32>,
}

impl Candidates {
    fn clear(&mut self) {
        self.first.clear();
        self.fall.clear();
        self.room.clear();
        self.pixel.clear();
        self.given.clear();
        self.singles.first.clear();
        self.singles.pixel.clear();
    }

    /// Room for `singles` candidates of room 1 and `more` of room 2 or more in every list.
    fn reserve_exact(&mut self, singles: usize, more: usize) {
        self.first.reserve_exact(more);
        self.fall.reserve_exact(more);
        self.room.reserve_exact(more);
        self.pixel.reserve_exact(more);
        self.given.reserve_exact(more);
        self.singles.first.reserve_exact(singles);
        self.singles.pixel.reserve_exact(singles);
    }

    fn push(&mut self, c: Candidate) {
        debug_assert!(c.room >= 1, "a candidate has room for a fragment");
        if c.room == 1 {
            self.singles.first.push(c.curve.log_first);
            self.singles.pixel.push(c.pixel);
            return;
        }
        self.first.push(c.curve.log_first);
        self.fall.push(c.curve.log_fall);
        self.room.push(c.room);
        self.pixel.push(c.pixel);
    }

    /// Candidates of room 2 or more.
    fn len(&self) -> usize {
        self.pixel.len()
    }

    fn curve(&self, i: usize) -> Curve {
        Curve {
            log_first: self.first[i],
            log_fall: self.fall[i],
        }
    }

    fn memory_bytes(&self) -> u64 {
        let singles = &self.singles;
        (self.first.capacity() * 8
            + self.fall.capacity() * 8
            + (self.room.capacity() + self.pixel.capacity() + self.given.capacity()) * 4
            + singles.first.capacity() * 8
            + singles.pixel.capacity() * 4) as u64
    }
}

/// Fragments beyond the first worth more than `level`, summed over a chunk's candidates: a
/// comparison for each single, [`Curve::extra_above`] of every other candidate without a
/// branch, compiled per instruction set ([`pulp::Arch::dispatch`]) so that the divisions and
/// roundings run in vector registers (one candidate at a time, the division alone took most of
/// a bisection round). Each lane computes `extra_above`'s value exactly — the same division,
/// the ceiling of a value in `[1, room]` — and the counts are summed in integers, in lanes (in
/// `f64` they were one chain of additions: the `k` stage above took 7.9 → 6.8 ms).
struct ExtraAt<'a> {
    level: f64,
    candidates: &'a Candidates,
}

impl pulp::WithSimd for ExtraAt<'_> {
    type Output = u64;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> u64 {
        let Candidates {
            first,
            fall,
            room,
            singles,
            ..
        } = self.candidates;
        let level = self.level;
        // Summed in integers, which the compiler adds in lanes (a sum of `f64`s is one chain
        // of additions in order).
        let mut sum = 0u64;
        for &first in &singles.first {
            sum += u64::from(first > level);
        }
        let n = first.len();
        let (first, fall, room) = (&first[..n], &fall[..n], &room[..n]);
        for i in 0..n {
            // `max` and `min`, not `clamp`, whose check of its bounds (a branch to a panic a
            // candidate) kept this loop out of vector registers.
            let x = ((level - first[i]) / fall[i])
                .max(1.0)
                .min(f64::from(room[i]));
            // A whole number in [1, room]: exact as a u32.
            sum += u64::from(if first[i] > level { x.ceil() as u32 } else { 0 });
        }
        sum
    }
}

/// Computes `k` (resized to `counts.len()`) from the fragment `counts`, each pixel's [`Worth`]
/// and a `budget` of fragments; see the module docs.
///
/// # Panics
/// If `worth` does not hold one model per pixel of `counts` (a caller's bug, not an input).
pub fn analytic_k(counts: &[u32], worth: &[Worth], budget: u64, k: &mut Vec<u32>) -> Allocation {
    analytic_k_reusing(&mut AnalyticScratch::new(), counts, worth, budget, k)
}

/// [`analytic_k`], listing the candidates in `scratch`'s lists (kept for the next frame): the
/// same `k`.
///
/// # Panics
/// If `worth` does not hold one model per pixel of `counts` (a caller's bug, not an input).
pub fn analytic_k_reusing(
    scratch: &mut AnalyticScratch,
    counts: &[u32],
    worth: &[Worth],
    budget: u64,
    k: &mut Vec<u32>,
) -> Allocation {
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
    let lists = pixels.div_ceil(PIXELS_PER_TASK);
    scratch.chunks.resize_with(lists, Candidates::default);
    let ranges: Vec<Range> = scratch
        .chunks
        .par_iter_mut()
        .zip(counts.par_chunks(PIXELS_PER_TASK))
        .zip(worth.par_chunks(PIXELS_PER_TASK))
        .enumerate()
        .map(|(chunk, ((candidates, c), w))| {
            let first = chunk * PIXELS_PER_TASK;
            let mut range = Range::EMPTY;
            candidates.clear();
            // At most the pixels with a choice: reserved exactly, so that the lists hold what
            // the largest frame needed rather than up to twice that.
            let singles = c.iter().filter(|&&c| c == 2).count();
            let more = c.iter().filter(|&&c| c > 2).count();
            candidates.reserve_exact(singles, more);
            for (i, (&c, &w)) in c.iter().zip(w).enumerate() {
                if let Some(candidate) = Candidate::new(w, c, (first + i) as u32) {
                    range = range.with(&candidate);
                    candidates.push(candidate);
                }
            }
            range
        })
        .collect();
    let arch = pulp::Arch::new();
    let range = ranges.iter().fold(Range::EMPTY, Range::join);
    let extra_at = |level: f64| -> u64 {
        scratch
            .chunks
            .par_iter()
            .map(|candidates| arch.dispatch(ExtraAt { level, candidates }))
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
        // Each candidate's share is kept beside it for the units left below.
        let given: u64 = k
            .par_chunks_mut(PIXELS_PER_TASK)
            .zip(&mut scratch.chunks)
            .enumerate()
            .map(|(chunk, (k, candidates))| {
                let first = chunk * PIXELS_PER_TASK;
                let mut sum = 0u64;
                let singles = &candidates.singles;
                for (&f, &p) in singles.first.iter().zip(&singles.pixel) {
                    let n = u32::from(f > level);
                    k[p as usize - first] += n;
                    sum += u64::from(n);
                }
                candidates.given.clear();
                for i in 0..candidates.len() {
                    let n = candidates.curve(i).extra_above(level, candidates.room[i]);
                    k[candidates.pixel[i] as usize - first] += n;
                    candidates.given.push(n);
                    sum += u64::from(n);
                }
                sum
            })
            .collect::<Vec<u64>>()
            .iter()
            .sum();
        let chunks = &scratch.chunks;
        rest -= given;
        // The units left: to the pixels whose next fragment is worth most. Those lie above `lo`
        // (more fragments than `rest` do, at most one per pixel), so only they are sorted; the
        // whole list serves if the rounds ran out first.
        if rest > 0 {
            // A candidate has `1 + given` fragments now (every covered pixel has one), room
            // for more while `given < room`, and its next one is worth `ln g` at `given`: what
            // the model's `ln g(k[p] + 1)` gives, read from the candidate's own lists.
            let next_worths = |above: f64| -> Vec<(TotalF64, usize)> {
                chunks
                    .par_iter()
                    .map(|c| {
                        let singles = &c.singles;
                        // A single with room left was given nothing (its second is not above
                        // the level): its next is its second.
                        let singles = (0..singles.first.len())
                            .filter(|&i| singles.first[i] <= level)
                            .map(|i| (TotalF64(singles.first[i]), singles.pixel[i] as usize));
                        (0..c.len())
                            .filter(|&i| c.given[i] < c.room[i])
                            .map(|i| {
                                let w = c.curve(i).log_worth(c.given[i]);
                                (TotalF64(w), c.pixel[i] as usize)
                            })
                            .chain(singles)
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
            lo: self.lo.min(c.curve.log_worth(c.room - 1)),
            hi: self.hi.max(c.curve.log_first),
            narrowest: self.narrowest.min(-c.curve.log_fall),
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
    curve: Curve,
    room: u32,
    pixel: u32,
}

impl Candidate {
    /// Pixel `pixel` of `count` fragments and model `worth`, if it has a choice the model can
    /// make: more than one fragment, and fragments beyond the first worth something.
    #[inline]
    fn new(worth: Worth, count: u32, pixel: u32) -> Option<Candidate> {
        (count > 1 && worth.worthwhile()).then(|| Candidate {
            curve: worth.curve(),
            room: count - 1,
            pixel,
        })
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

    /// Candidates of the models `(ln g(2), −ln t, room)`, pixel by pixel.
    fn candidate_lists(models: &[(f64, f64, u32)]) -> Candidates {
        let mut candidates = Candidates::default();
        for (i, &(first, fall, room)) in models.iter().enumerate() {
            candidates.push(Candidate {
                curve: Curve {
                    log_first: first,
                    log_fall: -fall,
                },
                room,
                pixel: i as u32,
            });
        }
        candidates
    }

    /// The bisection's count in lanes against `extra_above` one candidate at a time.
    fn assert_lanes_count_like_one_at_a_time(candidates: &Candidates, level: f64) {
        let singles = &candidates.singles.first;
        let one_by_one: u64 = (0..candidates.len())
            .map(|i| u64::from(candidates.curve(i).extra_above(level, candidates.room[i])))
            .chain(singles.iter().map(|&first| {
                let curve = Curve {
                    log_first: first,
                    log_fall: -1.0,
                };
                u64::from(curve.extra_above(level, 1))
            }))
            .sum();
        let lanes = pulp::Arch::new().dispatch(ExtraAt { level, candidates });
        assert_eq!(lanes, one_by_one, "level {level}");
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

    /// A candidate's share at a level by hand, and at the ends of `f64`: where the quotient
    /// overflows every fragment is above the level, where it underflows the first still is.
    #[test]
    fn shares_at_a_level_by_hand() {
        // Worths 1, 0.5, 0, −0.5: two above 0 (0 is not above itself), all four far below.
        let c = Curve {
            log_first: 1.0,
            log_fall: -0.5,
        };
        assert_eq!(c.extra_above(0.0, 4), 2);
        assert_eq!(c.extra_above(-0.25, 4), 3);
        assert_eq!(c.extra_above(-10.0, 4), 4);
        assert_eq!(c.extra_above(1.0, 4), 0);
        assert_eq!(c.extra_above(f64::NAN, 4), 0);
        assert_eq!(c.extra_above(0.9, 1), 1);
        let flat = Curve {
            log_first: 1.0,
            log_fall: -1e-300,
        };
        assert_eq!(flat.extra_above(-1e300, 7), 7, "the quotient overflows");
        let steep = Curve {
            log_first: 5e-324,
            log_fall: -50.0,
        };
        assert_eq!(steep.extra_above(0.0, 3), 1, "the quotient underflows");
        // The lanes count the same, singles and others.
        let candidates = candidate_lists(&[(1.0, 1e-300, 7), (5e-324, 50.0, 3), (5e-324, 50.0, 1)]);
        for level in [0.0, -1e300, f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_lanes_count_like_one_at_a_time(&candidates, level);
        }
        let lanes = pulp::Arch::new().dispatch(ExtraAt {
            level: 0.0,
            candidates: &candidates,
        });
        assert_eq!(lanes, 7 + 1 + 1);
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

    /// One scratch serves frames of many chunks, growing and shrinking, at several budgets,
    /// with the `k` of fresh lists and the greedy's where the units left are few enough to
    /// check by brute force (the lists' chunk boundaries included).
    #[test]
    fn lists_kept_between_frames_give_the_fresh_result() {
        let mut scratch = AnalyticScratch::new();
        let mut state = 0x853c_49e6_748f_ea9bu64;
        let mut next = move |n: u64| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 33) % n
        };
        for (frame, pixels) in [30_000usize, 9_000, 17_000, 2_000, 24_577]
            .into_iter()
            .enumerate()
        {
            let counts: Vec<u32> = (0..pixels).map(|_| next(6) as u32).collect();
            let w: Vec<Worth> = (0..pixels)
                .map(|_| worth(0.1 + next(10) as f64 / 10.0, 0.05 + next(90) as f64 / 100.0))
                .collect();
            let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
            let covered = counts.iter().filter(|&&c| c > 0).count() as u64;
            for budget in [covered / 2, covered + 40, (covered + total) / 2, total + 5] {
                let (mut fresh, mut kept) = (Vec::new(), Vec::new());
                let a = analytic_k(&counts, &w, budget, &mut fresh);
                let b = analytic_k_reusing(&mut scratch, &counts, &w, budget, &mut kept);
                assert_eq!(fresh, kept, "frame {frame}, budget {budget}");
                assert_eq!((a.sum, b.sum), (budget.min(total), budget.min(total)));
                if frame == 1 && budget == covered + 40 {
                    assert_eq!(
                        kept,
                        greedy(&counts, &w, 40),
                        "the units left, by brute force"
                    );
                }
            }
        }
        assert!(scratch.memory_bytes() > 0);
    }

    proptest! {
        /// Levels above a candidate's first worth, between its worths, exactly on one, beyond
        /// its room and far below everything, with falls from tiny to huge (a test of the count
        /// in lanes: taking its ceiling away fails it).
        #[test]
        fn the_count_in_lanes_is_the_sum_of_each_candidates_share(
            models in prop::collection::vec((-10.0f64..10.0, 1e-9f64..50.0, 1u32..40), 1..200),
            level in -30.0f64..12.0,
            on in 0usize..200,
            extra in 0u32..4,
        ) {
            let candidates = candidate_lists(&models);
            let (first, fall, _) = models[on % models.len()];
            let exactly = Curve { log_first: first, log_fall: -fall }.log_worth(extra);
            let ends = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
            for level in [level, exactly, -1e300, 1e6].into_iter().chain(ends) {
                assert_lanes_count_like_one_at_a_time(&candidates, level);
            }
        }

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
