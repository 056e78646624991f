//! The importance map of the variable k-buffer (Tsopouridis 2021 §3.2.2, Algorithm 16): periphery and
//! depth-complexity heuristics with a noise bias.
//!
//! ```text
//! I_per(p) = 1 − (‖p − o‖ / √(w² + h²))^d          periphery: falls off away from the point o
//! I_d(p)   = α + (1 − α) · min(1, N_layers / N_limit)   depth complexity
//! I(p)     = max(0, I_per · I_d + λ (ρ − ½))             ρ uniform in [0, 1), one draw per pixel
//! ```
//!
//! - `p` is the pixel's centre `(x + ½, y + ½)` in pixels, `o` the point of interest
//!   ([`ImportanceParams::point_of_interest`], a fraction of the image size) in pixels;
//! - `N_layers` is the pixel's fragment count from the counting pass, `N_limit` the configured
//!   limit or, by default, the frame's largest count ("roughly the maximum", as the thesis says);
//! - `ρ` comes from a hash of the pixel's `(x, y)` and [`ImportanceParams::seed`] ([`noise`]), so a
//!   frame's map is reproducible and independent of the thread count and of the image width;
//! - a pixel without fragments has importance 0 (Algorithm 17, line 3: such a pixel gets no k).
//!
//! The map is stored as `f32`, one per pixel, row-major: the values the k pass reads are exactly
//! those exported. The pass is per-pixel parallel; the thesis's `importanceSum` atomic counter is a
//! sum over fixed chunks of pixels added in order, so it too is the same for any thread count.

use rayon::prelude::*;

use crate::options::ImportanceParams;

/// Pixels per parallel work item.
const PIXELS_PER_TASK: usize = 8 * 1024;

/// The periphery heuristic `I_per = 1 − (‖p − o‖ / √(w² + h²))^d` of pixel `(x, y)` of a
/// `width` × `height` image, `o` = `point_of_interest` × (w, h), `p` the pixel centre.
pub fn periphery(
    x: u32,
    y: u32,
    width: u32,
    height: u32,
    point_of_interest: [f64; 2],
    d: f64,
) -> f64 {
    let (w, h) = (f64::from(width), f64::from(height));
    let dx = f64::from(x) + 0.5 - point_of_interest[0] * w;
    let dy = f64::from(y) + 0.5 - point_of_interest[1] * h;
    // (‖p − o‖ / √(w² + h²))^d = (‖p − o‖² / (w² + h²))^(d/2): one power, no square roots, and
    // an integer power when d is even (the thesis's d = 2 needs none at all).
    let q = (dx * dx + dy * dy) / (w * w + h * h);
    let half = 0.5 * d;
    let falloff = if half == half.trunc() && half.abs() <= 64.0 {
        q.powi(half as i32)
    } else {
        q.powf(half)
    };
    1.0 - falloff
}

/// The depth-complexity heuristic `I_d = α + (1 − α) · min(1, N_layers / N_limit)`.
///
/// An `n_limit` of 0 counts as 1 (any covered pixel reaches the limit).
pub fn depth_complexity(n_layers: u32, n_limit: u32, alpha: f64) -> f64 {
    let ratio = f64::from(n_layers) / f64::from(n_limit.max(1));
    alpha + (1.0 - alpha) * ratio.min(1.0)
}

/// `ρ` of pixel `(x, y)`: uniform in `[0, 1)`, a pure function of the pixel and `seed`
/// (two rounds of the splitmix64 finaliser; 53 random bits).
pub fn noise(x: u32, y: u32, seed: u64) -> f64 {
    let h = splitmix64(splitmix64(seed) ^ ((u64::from(y) << 32) | u64::from(x)));
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The per-pixel importance `I = max(0, I_per · I_d + λ (ρ − ½))`.
pub fn combine(periphery: f64, depth_complexity: f64, rho: f64, lambda: f64) -> f64 {
    (periphery * depth_complexity + lambda * (rho - 0.5)).max(0.0)
}

/// The importance of pixel `(x, y)` holding `n_layers` fragments; 0 if it holds none.
pub fn pixel_importance(
    x: u32,
    y: u32,
    width: u32,
    height: u32,
    n_layers: u32,
    n_limit: u32,
    params: &ImportanceParams,
) -> f64 {
    if n_layers == 0 {
        return 0.0;
    }
    combine(
        periphery(
            x,
            y,
            width,
            height,
            params.point_of_interest,
            params.periphery_exponent,
        ),
        depth_complexity(n_layers, n_limit, params.alpha),
        noise(x, y, params.seed),
        params.noise,
    )
}

/// The importance pass: fills `out` (one `f32` per pixel, row-major) from the per-pixel fragment
/// `counts` of a `width` × `height` frame and returns the total importance `I_tot`.
///
/// # Panics
/// If `counts` or `out` does not have one entry per pixel.
pub fn importance_map(
    counts: &[u32],
    width: u32,
    height: u32,
    params: &ImportanceParams,
    out: &mut [f32],
) -> f64 {
    let pixels = width as usize * height as usize;
    assert_eq!(counts.len(), pixels, "one count per pixel");
    assert_eq!(out.len(), pixels, "one importance per pixel");
    let n_limit = params
        .n_limit
        .unwrap_or_else(|| counts.par_iter().copied().max().unwrap_or(0));
    let chunk_sums: Vec<f64> = out
        .par_chunks_mut(PIXELS_PER_TASK)
        .zip(counts.par_chunks(PIXELS_PER_TASK))
        .enumerate()
        .map(|(t, (out, counts))| {
            let mut sum = 0.0f64;
            for (i, (o, &n)) in out.iter_mut().zip(counts).enumerate() {
                if n == 0 {
                    *o = 0.0;
                    continue;
                }
                let p = t * PIXELS_PER_TASK + i;
                let (x, y) = ((p % width as usize) as u32, (p / width as usize) as u32);
                *o = pixel_importance(x, y, width, height, n, n_limit, params) as f32;
                sum += f64::from(*o);
            }
            sum
        })
        .collect();
    chunk_sums.iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn periphery_by_hand() {
        // 100 × 100, o at the centre (50, 50); diagonal √20000 = 141.421356…
        // Pixel (49, 49) has its centre at (49.5, 49.5): distance √0.5, ratio 0.005, d = 2 →
        // 1 − 0.000025.
        assert!(close(
            periphery(49, 49, 100, 100, [0.5, 0.5], 2.0),
            1.0 - 0.000025
        ));
        // Pixel (0, 0): centre (0.5, 0.5), distance 49.5·√2 = 70.0036, ratio 0.495, d = 2 →
        // 1 − 0.245025 = 0.754975.
        assert!(close(periphery(0, 0, 100, 100, [0.5, 0.5], 2.0), 0.754975));
        // o at the top-left corner, pixel (99, 99): ratio 99.5/100, d = 1 → 0.005.
        assert!(close(periphery(99, 99, 100, 100, [0.0, 0.0], 1.0), 0.005));
        // 4 × 3 image (diagonal 5), o = (0, 0), pixel (1, 1): centre (1.5, 1.5), distance
        // 1.5·√2, ratio 0.3·√2, d = 3 → 1 − 0.027·2√2 = 1 − 0.054·√2.
        assert!(close(
            periphery(1, 1, 4, 3, [0.0, 0.0], 3.0),
            1.0 - 0.054 * 2f64.sqrt()
        ));
    }

    #[test]
    fn depth_complexity_by_hand() {
        // α = 0.1, N_limit = 8: 2 layers → 0.1 + 0.9 · 0.25 = 0.325.
        assert!(close(depth_complexity(2, 8, 0.1), 0.325));
        // At and beyond the limit → 1.
        assert!(close(depth_complexity(8, 8, 0.1), 1.0));
        assert!(close(depth_complexity(20, 8, 0.1), 1.0));
        // No layers → α.
        assert!(close(depth_complexity(0, 8, 0.3), 0.3));
        // α = 0.5, 3 of 4 layers → 0.5 + 0.5 · 0.75 = 0.875.
        assert!(close(depth_complexity(3, 4, 0.5), 0.875));
        // N_limit 0 counts as 1.
        assert!(close(depth_complexity(1, 0, 0.1), 1.0));
    }

    #[test]
    fn combine_by_hand_and_clamps_at_zero() {
        // 0.8 · 0.5 + 0.1 · (0.75 − 0.5) = 0.4 + 0.025 = 0.425.
        assert!(close(combine(0.8, 0.5, 0.75, 0.1), 0.425));
        // λ = 0: no noise.
        assert!(close(combine(0.8, 0.5, 0.99, 0.0), 0.4));
        // 0.01 · 0.1 + 1 · (0 − 0.5) < 0 → 0.
        assert_eq!(combine(0.01, 0.1, 0.0, 1.0), 0.0);
    }

    #[test]
    fn pixel_importance_by_hand() {
        let params = ImportanceParams {
            periphery_exponent: 2.0,
            alpha: 0.1,
            n_limit: Some(8),
            noise: 0.0,
            point_of_interest: [0.5, 0.5],
            seed: 0,
        };
        // (0, 0) of 100 × 100 with 2 layers: 0.754975 · 0.325.
        assert!(close(
            pixel_importance(0, 0, 100, 100, 2, 8, &params),
            0.754975 * 0.325
        ));
        // Uncovered pixels have importance 0, whatever the heuristics say.
        assert_eq!(pixel_importance(50, 50, 100, 100, 0, 8, &params), 0.0);
        // With noise: the same plus λ(ρ − ½) for this pixel's ρ.
        let noisy = ImportanceParams {
            noise: 0.1,
            seed: 42,
            ..params
        };
        let rho = noise(0, 0, 42);
        assert!(close(
            pixel_importance(0, 0, 100, 100, 2, 8, &noisy),
            (0.754975 * 0.325 + 0.1 * (rho - 0.5)).max(0.0)
        ));
    }

    #[test]
    fn splitmix64_is_the_published_generator() {
        // The first three outputs of SplitMix64 started from state 0 (Steele, Lea & Flood 2014;
        // Vigna's reference `splitmix64.c`): each output is the finaliser of the state advanced
        // by the golden gamma, so the finaliser of k·gamma is output k+1.
        const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;
        assert_eq!(splitmix64(0), 0xE220_A839_7B1D_CDAF);
        assert_eq!(splitmix64(GAMMA), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(splitmix64(GAMMA.wrapping_mul(2)), 0x06C4_5D18_8009_454F);
    }

    /// Pearson correlation of `noise` over a 200×200 grid between two ways of indexing it.
    fn correlation(a: impl Fn(u32, u32) -> f64, b: impl Fn(u32, u32) -> f64) -> f64 {
        let pairs: Vec<(f64, f64)> = (0..200u32)
            .flat_map(|y| (0..200u32).map(move |x| (x, y)))
            .map(|(x, y)| (a(x, y), b(x, y)))
            .collect();
        let n = pairs.len() as f64;
        let (ma, mb) = pairs
            .iter()
            .fold((0.0, 0.0), |(sa, sb), (p, q)| (sa + p / n, sb + q / n));
        let (mut cov, mut va, mut vb) = (0.0, 0.0, 0.0);
        for (p, q) in &pairs {
            cov += (p - ma) * (q - mb);
            va += (p - ma) * (p - ma);
            vb += (q - mb) * (q - mb);
        }
        cov / (va * vb).sqrt()
    }

    #[test]
    fn noise_fields_of_other_seeds_and_transposed_pixels_are_unrelated() {
        // ρ is a pure function of (x, y, seed), so a frame's dither pattern does not depend on
        // which thread shades which pixel; a different seed or the transposed pixel must give
        // an unrelated value, not a shifted or mirrored copy of the same field.
        let same = correlation(|x, y| noise(x, y, 1), |x, y| noise(x, y, 1));
        assert!((same - 1.0).abs() < 1e-12, "{same}");
        for (what, r) in [
            (
                "seed 1 vs 2",
                correlation(|x, y| noise(x, y, 1), |x, y| noise(x, y, 2)),
            ),
            (
                "(x, y) vs (y, x)",
                correlation(|x, y| noise(x, y, 1), |x, y| noise(y, x, 1)),
            ),
            (
                "(x, y) vs (x + 1, y)",
                correlation(|x, y| noise(x, y, 1), |x, y| noise(x + 1, y, 1)),
            ),
        ] {
            // 40,000 independent pairs: |r| has a standard deviation of 0.005.
            assert!(r.abs() < 0.025, "{what}: correlation {r}");
        }
        let (mut seen, mut repeats) = (std::collections::HashSet::new(), 0);
        for y in 0..200 {
            for x in 0..200 {
                repeats += usize::from(!seen.insert(noise(x, y, 1).to_bits()));
            }
        }
        assert_eq!(
            repeats, 0,
            "53-bit values should not repeat in 40,000 pixels"
        );
    }

    #[test]
    fn noise_is_uniform() {
        let n = 100_000u32;
        let (mut sum, mut lo, mut hi) = (0.0, 1.0f64, 0.0f64);
        let mut buckets = [0u32; 10];
        for i in 0..n {
            let r = noise(i % 400, i / 400, 9);
            assert!((0.0..1.0).contains(&r));
            sum += r;
            lo = lo.min(r);
            hi = hi.max(r);
            buckets[(r * 10.0) as usize] += 1;
        }
        assert!(
            (sum / f64::from(n) - 0.5).abs() < 0.005,
            "mean {}",
            sum / f64::from(n)
        );
        assert!(lo < 0.001 && hi > 0.999);
        for b in buckets {
            assert!((9_500..10_500).contains(&b), "bucket {b}");
        }
    }

    #[test]
    fn map_matches_the_per_pixel_function_for_any_thread_count() {
        let (w, h) = (300u32, 200u32);
        let counts: Vec<u32> = (0..w * h).map(|p| (p * 7 + p / 13) % 11).collect();
        let params = ImportanceParams::default();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut out = vec![0.0f32; (w * h) as usize];
            let total = pool.install(|| importance_map(&counts, w, h, &params, &mut out));
            (out, total)
        };
        let (one, total_one) = run(1);
        for threads in [2, 3, 8] {
            let (map, total) = run(threads);
            assert_eq!(map, one, "{threads} threads");
            assert_eq!(total.to_bits(), total_one.to_bits(), "{threads} threads");
        }
        let max = *counts.iter().max().unwrap();
        for p in [0usize, 1, 301, 59_999] {
            let (x, y) = ((p % 300) as u32, (p / 300) as u32);
            assert_eq!(
                one[p],
                pixel_importance(x, y, w, h, counts[p], max, &params) as f32
            );
        }
        // Uncovered pixels are 0; with the default parameters every covered pixel is positive
        // (I_per ≥ 0.75 at the centre's farthest corner, I_d ≥ α = 0.1, noise ≥ −0.05).
        for (&i, &c) in one.iter().zip(&counts) {
            assert_eq!(c == 0, i == 0.0);
        }
    }
}
