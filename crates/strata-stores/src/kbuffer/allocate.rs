//! The k pass of the variable k-buffer (Tsopouridis 2021 Algorithm 17): per-pixel k from an importance
//! map under a budget of M fragments, with guarantees the thesis's formula lacks.
//!
//! The thesis sets `k(p) = ⌊M · I(p) / I_tot⌋`. That loses up to one fragment per pixel to the
//! floor, gives 0 to covered pixels of low importance, and can hand a pixel more slots than it has
//! fragments (wasted memory, since a pixel never fills them). strata allocates instead:
//!
//! 1. `N` = fragments counted, `C` = covered pixels (count > 0), `M' = min(M, N)`.
//! 2. If `M' = N`, every pixel gets its count (the A-buffer).
//! 3. If `M' < C` — not even one fragment for every covered pixel — the `M'` covered pixels of
//!    highest importance get 1 (ties to the lower pixel index), the others 0 and show the
//!    background. Only here can a covered pixel get nothing.
//! 4. Otherwise every covered pixel gets 1, and the remaining `R = M' − C` slots are shared in
//!    proportion to importance, each pixel capped at its headroom `h(p) = count(p) − 1`: find the
//!    water level `s` with `Σ min(h(p), s · I(p)) = R` by iterating
//!    `s ← (R − Σ_capped h) / Σ_uncapped I` (the capped set only grows, and the level is exact
//!    once a round caps nobody new; each round is one parallel pass over the pixels with room),
//!    then give capped pixels `h(p)` and the others `⌊s · I(p)⌋`.
//! 5. If the pixels that still have headroom all have importance 0, they share what is left
//!    equally (step 4 with every importance 1).
//! 6. The units lost to the floors (fewer than the uncapped pixels) go one each to the pixels with
//!    the largest remainders `s · I(p) − ⌊s · I(p)⌋`, ties to the lower pixel index.
//!
//! # Guarantees (held by tests and a property test)
//!
//! - `Σ k = min(M, N)` exactly — never above the budget, and nothing of it wasted while some
//!   pixel still has fragments to store;
//! - `k(p) ≤ count(p)` for every pixel, so no slot is allocated that cannot be filled;
//! - `k(p) ≥ 1` for every covered pixel when `M ≥ C`;
//! - proportionality: a pixel below its cap gets `1 + ⌊s · I(p)⌋` or one more, for one `s`
//!   shared by all pixels;
//! - determinism: the result depends only on the counts, the importance map and `M` — sums over
//!   fixed chunks of pixels, added in order, make it the same for any thread count.

use rayon::prelude::*;

/// Pixels per parallel work item.
const PIXELS_PER_TASK: usize = 8 * 1024;

/// Water-level rounds before giving up on exactness (the floors and largest-remainder step still
/// place every unit; only the proportionality would be approximate). Real frames take a handful.
const MAX_ROUNDS: u32 = 64;

/// What the k pass did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Allocation {
    /// `M`, the budget asked for.
    pub budget: u64,
    /// `N`, fragments counted.
    pub total: u64,
    /// `C`, covered pixels.
    pub covered: u64,
    /// `Σ k`, always `min(M, N)`.
    pub sum: u64,
    /// Water-level rounds (parallel passes) the proportional share took.
    pub rounds: u32,
}

/// Computes `k` (one per pixel, row-major, resized to `counts.len()`) from per-pixel fragment
/// `counts`, an `importance` map and a `budget` of fragments; see the module docs.
///
/// # Panics
/// If `importance` does not have one entry per pixel.
pub fn allocate_k(counts: &[u32], importance: &[f32], budget: u64, k: &mut Vec<u32>) -> Allocation {
    let pixels = counts.len();
    assert_eq!(importance.len(), pixels, "one importance per pixel");
    let (total, covered) = base_k(counts, k);
    let m = budget.min(total);
    let mut report = Allocation {
        budget,
        total,
        covered,
        sum: m,
        rounds: 0,
    };
    if m == total {
        k.par_iter_mut().zip(counts).for_each(|(k, &c)| *k = c);
        return report;
    }
    if m < covered {
        k.par_iter_mut().for_each(|k| *k = 0);
        one_each_to_the_most(counts, m, k, |p| f64::from(importance[p].max(0.0)));
        return report;
    }
    let mut left = m - covered;
    let mut fill = water_fill(k, counts, Some(importance), left);
    left -= fill.placed;
    report.rounds = fill.rounds;
    if left > 0 && left >= fill.remainders.len() as u64 {
        // The pixels of positive importance are full: the others share the rest equally.
        fill = water_fill(k, counts, None, left);
        left -= fill.placed;
        report.rounds += fill.rounds;
    }
    largest_remainders(k, counts, fill.remainders, left);
    debug_assert_eq!(k.par_iter().map(|&x| u64::from(x)).sum::<u64>(), m);
    report
}

/// Resizes `k` to one entry per pixel of `counts` and gives every covered pixel 1 (the others
/// 0), in one parallel pass that also returns `N` (fragments) and `C` (covered pixels): the
/// first step of every allocation.
pub(super) fn base_k(counts: &[u32], k: &mut Vec<u32>) -> (u64, u64) {
    k.resize(counts.len(), 0);
    let parts: Vec<(u64, u64)> = k
        .par_chunks_mut(PIXELS_PER_TASK)
        .zip(counts.par_chunks(PIXELS_PER_TASK))
        .map(|(k, c)| {
            let (mut total, mut covered) = (0u64, 0u64);
            for (k, &c) in k.iter_mut().zip(c) {
                *k = c.min(1);
                total += u64::from(c);
                covered += u64::from(c > 0);
            }
            (total, covered)
        })
        .collect();
    parts.iter().fold((0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
}

/// Below one fragment per covered pixel: gives 1 to the `m` covered pixels of largest `key`
/// (ties to the lower pixel index) and leaves the others as they are (0). Shared by the importance
/// allocator (key: importance) and the analytic one (key: contrast against the background).
pub(super) fn one_each_to_the_most(
    counts: &[u32],
    m: u64,
    k: &mut [u32],
    key: impl Fn(usize) -> f64 + Sync,
) {
    let mut order: Vec<(std::cmp::Reverse<TotalF64>, usize)> = counts
        .par_iter()
        .enumerate()
        .filter(|(_, c)| **c > 0)
        .map(|(p, _)| (std::cmp::Reverse(TotalF64(key(p))), p))
        .collect();
    let m = m as usize;
    if m == 0 {
        return;
    }
    if m < order.len() {
        order.select_nth_unstable(m - 1);
    }
    for &(_, p) in &order[..m.min(order.len())] {
        k[p] = 1;
    }
}

/// An `f64` ordered by `total_cmp` (keys are never NaN here: importance is clamped at 0, and
/// contrasts and worths are distances and their logarithms).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct TotalF64(pub(super) f64);

impl Eq for TotalF64 {}

impl PartialOrd for TotalF64 {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for TotalF64 {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// A pixel that can take more slots: its index, headroom and weight.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    p: u32,
    h: u32,
    w: f64,
}

/// What one [`water_fill`] did.
#[derive(Debug, Default)]
struct Fill {
    /// Slots placed.
    placed: u64,
    /// Water-level rounds.
    rounds: u32,
    /// Largest-remainder keys of the pixels left below their cap (which can take one more):
    /// the remainder's bits inverted (largest first) above the pixel index (lower first).
    remainders: Vec<u64>,
}

/// Step 4: adds to `k` up to `amount` more slots in proportion to `weight` (the importance, or
/// 1 for every pixel if `None`), each pixel capped at its headroom `count − k`.
///
/// The pixels with headroom and positive weight are gathered once into compact lists, one per
/// chunk of pixels; the rounds and the final share run over those lists, chunk by chunk.
fn water_fill(k: &mut [u32], counts: &[u32], weight: Option<&[f32]>, amount: u64) -> Fill {
    let cands: Vec<Vec<Candidate>> = k
        .par_chunks(PIXELS_PER_TASK)
        .zip(counts.par_chunks(PIXELS_PER_TASK))
        .enumerate()
        .map(|(t, (k, c))| {
            let base = t * PIXELS_PER_TASK;
            let mut out = Vec::new();
            for (i, (&k, &c)) in k.iter().zip(c).enumerate() {
                let p = base + i;
                let (h, w) = (c - k, weight.map_or(1.0, |w| f64::from(w[p])));
                if h > 0 && w > 0.0 {
                    out.push(Candidate { p: p as u32, h, w });
                }
            }
            out
        })
        .collect();
    // Per-chunk sums, added in chunk order: the same result for any thread count.
    let sums = |s: f64| -> (u64, f64, u64) {
        let parts: Vec<(u64, f64, u64)> = cands
            .par_iter()
            .map(|chunk| {
                let (mut capped_h, mut free_w, mut n_capped) = (0u64, 0.0f64, 0u64);
                for c in chunk {
                    if s * c.w >= f64::from(c.h) {
                        capped_h += u64::from(c.h);
                        n_capped += 1;
                    } else {
                        free_w += c.w;
                    }
                }
                (capped_h, free_w, n_capped)
            })
            .collect();
        parts
            .iter()
            .fold((0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2))
    };
    // Level 0 caps nobody: its free weight is the total weight of the candidates.
    let (_, total_w, _) = sums(0.0);
    if total_w <= 0.0 || amount == 0 {
        return Fill::default();
    }
    let mut s = amount as f64 / total_w;
    let mut state = sums(s);
    let mut rounds = 1;
    while state.1 > 0.0 && rounds < MAX_ROUNDS {
        let next = ((amount.saturating_sub(state.0)) as f64 / state.1).max(s);
        let next_state = sums(next);
        rounds += 1;
        let settled = next_state.2 == state.2;
        (s, state) = (next, next_state);
        if settled {
            break;
        }
    }
    // Everyone capped (the candidates' headroom fits in `amount`): the level is infinite.
    if state.1 <= 0.0 {
        s = f64::INFINITY;
    }
    // The share of each candidate at level `s`: capped ones take their headroom, the others the
    // floor of `s · w`, keeping the remainder. In the rare case that f64 rounding pushes the floors
    // above `amount`, lower the level a hair and try again (floors only fall as the level falls).
    let share = |s: f64, c: &Candidate| -> (u32, Option<f32>) {
        let x = s * c.w;
        if x >= f64::from(c.h) {
            (c.h, None)
        } else {
            let f = x.floor();
            (f as u32, Some((x - f) as f32))
        }
    };
    let placed = loop {
        let placed: u64 = cands
            .par_iter()
            .map(|chunk| chunk.iter().map(|c| u64::from(share(s, c).0)).sum::<u64>())
            .sum();
        if placed <= amount {
            break placed;
        }
        s = if s.is_finite() {
            s * (1.0 - 1e-12)
        } else {
            amount as f64 / total_w
        };
    };
    let remainders: Vec<Vec<u64>> = k
        .par_chunks_mut(PIXELS_PER_TASK)
        .zip(cands.par_iter())
        .enumerate()
        .map(|(t, (k, chunk))| {
            let base = t * PIXELS_PER_TASK;
            let mut keys = Vec::new();
            for c in chunk {
                let (x, r) = share(s, c);
                k[c.p as usize - base] += x;
                if let Some(r) = r {
                    keys.push((u64::from(!r.max(0.0).to_bits()) << 32) | u64::from(c.p));
                }
            }
            keys
        })
        .collect();
    Fill {
        placed,
        rounds,
        remainders: remainders.concat(),
    }
}

/// Step 6: one more slot each to the `left` pixels below their cap with the largest remainders.
/// (The floors lose fewer units than there are such pixels; should rounding ever leave more, the
/// rest goes one slot a round to the pixels with room, in pixel order.)
fn largest_remainders(k: &mut [u32], counts: &[u32], mut keys: Vec<u64>, mut left: u64) {
    let take = (left as usize).min(keys.len());
    if take > 0 {
        if take < keys.len() {
            keys.select_nth_unstable(take - 1);
        }
        for &key in &keys[..take] {
            k[(key & u64::from(u32::MAX)) as usize] += 1;
        }
        left -= take as u64;
    }
    while left > 0 {
        let before = left;
        for (k, &c) in k.iter_mut().zip(counts) {
            if left > 0 && *k < c {
                *k += 1;
                left -= 1;
            }
        }
        if left == before {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn alloc(counts: &[u32], importance: &[f32], budget: u64) -> (Vec<u32>, Allocation) {
        let mut k = Vec::new();
        let a = allocate_k(counts, importance, budget, &mut k);
        (k, a)
    }

    #[test]
    fn proportional_by_hand() {
        // Four covered pixels with room to spare; 4 base slots, 6 to share by importance 1:2:3:0.
        // Level s = 6 / 6 = 1 → extras 1, 2, 3, 0 → k = 2, 3, 4, 1.
        let (k, a) = alloc(&[10, 10, 10, 10, 0], &[1.0, 2.0, 3.0, 0.0, 0.0], 10);
        assert_eq!(k, [2, 3, 4, 1, 0]);
        assert_eq!((a.sum, a.covered, a.total), (10, 4, 40));
    }

    #[test]
    fn caps_at_the_count_and_redistributes() {
        // Pixel 0 has importance 8 but only 2 fragments: it takes its 1 extra and the other 5
        // extras go to pixels 1 and 2 in the ratio 1:4 → level 5 / 5 = 1 → 1 and 4.
        let (k, _) = alloc(&[2, 10, 10], &[8.0, 1.0, 4.0], 9);
        assert_eq!(k, [2, 2, 5]);
    }

    #[test]
    fn floors_go_to_the_largest_remainders() {
        // 3 extras over equal importances: level 1, each gets exactly 1.
        let (k, _) = alloc(&[5, 5, 5], &[1.0, 1.0, 1.0], 6);
        assert_eq!(k, [2, 2, 2]);
        // 2 extras over equal importances: level 2/3, floors 0, remainders equal → lower index.
        let (k, _) = alloc(&[5, 5, 5], &[1.0, 1.0, 1.0], 5);
        assert_eq!(k, [2, 2, 1]);
        // 2 extras over 1:2:3: level 1/3 → 1/3, 2/3, 1 → floors 0, 0, 1; one left → pixel 1
        // (remainder 2/3 beats 1/3).
        let (k, _) = alloc(&[5, 5, 5], &[1.0, 2.0, 3.0], 5);
        assert_eq!(k, [1, 2, 2]);
    }

    #[test]
    fn budget_below_covered_pixels_keeps_the_most_important() {
        let (k, a) = alloc(&[3, 0, 3, 3, 3], &[0.5, 0.0, 0.9, 0.1, 0.9], 2);
        assert_eq!(k, [0, 0, 1, 0, 1]);
        assert_eq!(a.sum, 2);
        let (k, _) = alloc(&[3, 3], &[0.5, 0.9], 0);
        assert_eq!(k, [0, 0]);
    }

    #[test]
    fn budget_at_or_above_the_total_keeps_everything() {
        for m in [12, 13, 1_000] {
            let (k, a) = alloc(&[3, 0, 4, 5], &[0.1, 0.0, 0.0, 0.3], m);
            assert_eq!(k, [3, 0, 4, 5]);
            assert_eq!(a.sum, 12);
        }
    }

    #[test]
    fn zero_importance_pixels_share_what_the_others_cannot_take() {
        // Pixel 0 (importance 1) can take 1 extra; pixels 1 and 2 (importance 0) share 4 more.
        let (k, _) = alloc(&[2, 9, 9], &[1.0, 0.0, 0.0], 8);
        assert_eq!(k, [2, 3, 3]);
    }

    proptest! {
        #[test]
        fn guarantees_hold_for_any_input(
            px in proptest::collection::vec((0u32..12, 0.0f32..2.0), 1..300),
            share in 0.0f64..1.2,
        ) {
            let counts: Vec<u32> = px.iter().map(|p| p.0).collect();
            let importance: Vec<f32> = px.iter().map(|p| if p.0 == 0 { 0.0 } else { p.1 }).collect();
            let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
            let covered = counts.iter().filter(|&&c| c > 0).count() as u64;
            let m = (total as f64 * share) as u64;
            let (k, a) = alloc(&counts, &importance, m);
            prop_assert_eq!(k.iter().map(|&x| u64::from(x)).sum::<u64>(), m.min(total));
            prop_assert_eq!(a.sum, m.min(total));
            for (&k, &c) in k.iter().zip(&counts) {
                prop_assert!(k <= c);
                if m >= covered && c > 0 {
                    prop_assert!(k >= 1);
                }
            }
        }
    }
}
