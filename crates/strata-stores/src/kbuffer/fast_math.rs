//! Branch-free `f32` logarithm, exponential and their kin for the lane-wise code of the learned
//! k ([`super::features`]' feature blocks, [`super::inference`]): `f32` arithmetic in a fixed
//! order, its polynomials in fused multiply-adds ([`f32::mul_add`]), and simple enough that the
//! compiler vectorises a loop over lanes that calls them (a library `ln` or `exp` is a call per
//! value). Accuracy is stated on each and tested against `std`.
//!
//! A fused multiply-add rounds once, by definition, so these give the same bits on every machine
//! and for every vector width: the FMA instruction where the code is compiled for an instruction
//! set that has one (pulp's AVX2 and AVX-512 sets, NEON; the lane loops that call these are
//! dispatched to them), a correctly rounded library `fmaf` (Rust's compiler-builtins)
//! elsewhere (an SSE2-only CPU, the trainer's scalar code), which is exact and slower. On the full dragon's importance pass the fused
//! polynomials and network took 14.4–14.7 → 13.1–13.3 ms on one thread (AMD EPYC with
//! AVX-512, alternated runs).

use std::f32::consts::{LN_2, LOG2_E};

/// `ln y` for any positive normal `y`, within 1e-5 absolute (and within 1e-6 relative near 1):
/// the exponent from the bits, then `ln m = 2 atanh((m − 1)/(m + 1))` to five terms for the
/// mantissa `m` in `[1, 2)`.
#[inline(always)]
pub fn fast_ln(y: f32) -> f32 {
    let bits = y.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let series = s2.mul_add(s2.mul_add(1.0 / 9.0, 1.0 / 7.0), 1.0 / 5.0);
    let ln_m = (2.0 * s) * s2.mul_add(s2.mul_add(series, 1.0 / 3.0), 1.0);
    (exponent as f32).mul_add(LN_2, ln_m)
}

/// Adding and subtracting this rounds an `f32` of magnitude below 2²² to the nearest integer.
const ROUND: f32 = 12_582_912.0;

/// `e^x` within 3e-7 relative for `x` in `[−87, 88]` (clamped to it, so never 0, infinite or
/// subnormal): `x = n ln 2 + r` with `|r| ≤ ln 2 / 2`, a degree-6 Taylor polynomial for `e^r`,
/// and `2^n` from the bits.
#[inline(always)]
pub fn fast_exp(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    let rounded = x.mul_add(LOG2_E, ROUND);
    let n = rounded - ROUND;
    let p = exp_polynomial(reduced(x, n));
    // `rounded` is `ROUND + n` exactly, and `ROUND`'s ulp is 1, so its low mantissa bits are
    // `n` as an integer: the bits of `2ⁿ` without a float-to-int conversion (whose saturating
    // Rust semantics cost a compare and a blend a lane), the same bits as `(n as i32 + 127) << 23`
    // for every `n` the clamp allows.
    let n_bits = rounded.to_bits().wrapping_sub(ROUND.to_bits());
    p * f32::from_bits(n_bits.wrapping_add(127) << 23)
}

/// `r = x − n ln 2`, with `ln 2` split so that `n · LN_2_HI` is exact for `|n| < 2⁸`.
#[inline(always)]
fn reduced(x: f32, n: f32) -> f32 {
    const LN_2_HI: f32 = 0.693_359_4;
    const LN_2_LO: f32 = -2.121_944_4e-4;
    n.mul_add(-LN_2_LO, n.mul_add(-LN_2_HI, x))
}

/// `e^r` for `|r| ≤ ln 2 / 2`: its Taylor polynomial of degree 6, by Horner in fused steps.
#[inline(always)]
fn exp_polynomial(r: f32) -> f32 {
    let p = r.mul_add(1.0 / 720.0, 1.0 / 120.0);
    let p = r.mul_add(p, 1.0 / 24.0);
    let p = r.mul_add(p, 1.0 / 6.0);
    let p = r.mul_add(p, 1.0 / 2.0);
    let p = r.mul_add(p, 1.0);
    r.mul_add(p, 1.0)
}

/// `ln(1 + u)` for `u ≥ 0`, accurate (relative) down to the smallest `u`, where `ln(1 + u)`
/// through [`fast_ln`] would lose `u` to the rounding of `1 + u`: the rounding is undone by
/// `u / ((1 + u) − 1)`.
#[inline(always)]
pub fn ln_1p(u: f32) -> f32 {
    let v = 1.0 + u;
    let d = v - 1.0;
    let scaled = fast_ln(v) * (u / d.max(f32::MIN_POSITIVE));
    if d == 0.0 { u } else { scaled }
}

/// `ln(1 + e^x)`, without overflow for large `x` or loss for very negative `x`.
#[inline(always)]
pub fn softplus(x: f32) -> f32 {
    x.max(0.0) + ln_1p(fast_exp(-x.abs()))
}

/// The logistic function `1 / (1 + e^−x)` through [`fast_exp`].
#[inline(always)]
pub fn fast_sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + fast_exp(-x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `count` values spread geometrically over `[lo, hi)`.
    fn geometric(lo: f32, hi: f32, count: usize) -> impl Iterator<Item = f32> {
        let (lo, hi) = (f64::from(lo), f64::from(hi));
        let step = (hi / lo).powf(1.0 / count as f64);
        (0..count).map(move |i| (lo * step.powi(i as i32)) as f32)
    }

    #[test]
    fn fast_ln_is_close_to_ln() {
        let worst = geometric(1e-30, 1e30, 200_000)
            .map(|y| (f64::from(fast_ln(y)) - f64::from(y).ln()).abs() as f32)
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "worst error {worst}");
        assert_eq!(fast_ln(1.0), 0.0);
        assert!((fast_ln(0.25) - 0.25f32.ln()).abs() < 1e-5);
    }

    #[test]
    fn fast_exp_is_close_to_exp_and_clamped() {
        let mut x = -87.0f32;
        let mut worst = 0.0f32;
        while x <= 88.0 {
            let want = f64::from(x).exp();
            worst = worst.max(((f64::from(fast_exp(x)) - want) / want).abs() as f32);
            x += 0.001_3;
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
        assert_eq!(fast_exp(0.0), 1.0);
        assert!(fast_exp(-1000.0) > 0.0 && fast_exp(-1000.0) < 1e-37);
        assert!(fast_exp(1000.0).is_finite());
    }

    #[test]
    fn fast_exp_is_bit_for_bit_the_version_with_a_float_to_int_conversion() {
        // `fast_exp` as it was before `2ⁿ` came from the rounding's bits: through `n as i32`.
        fn by_conversion(x: f32) -> f32 {
            let x = x.clamp(-87.0, 88.0);
            let n = x.mul_add(LOG2_E, ROUND) - ROUND;
            let p = exp_polynomial(reduced(x, n));
            p * f32::from_bits(((n as i32 + 127) as u32) << 23)
        }
        // Past both ends of the clamp, and every integer n it allows with the values around
        // the roundings' ties.
        let mut x = -100.0f32;
        while x <= 100.0 {
            assert_eq!(fast_exp(x).to_bits(), by_conversion(x).to_bits(), "x = {x}");
            x += 0.000_7;
        }
        for n in -127..=128 {
            let tie = (n as f32 + 0.5) * std::f32::consts::LN_2;
            for x in [
                tie,
                f32::from_bits(tie.to_bits() + 1),
                f32::from_bits(tie.to_bits().wrapping_sub(1)),
            ] {
                assert_eq!(fast_exp(x).to_bits(), by_conversion(x).to_bits(), "x = {x}");
            }
        }
        for x in [
            f32::NEG_INFINITY,
            f32::INFINITY,
            f32::MIN,
            f32::MAX,
            -0.0,
            0.0,
        ] {
            assert_eq!(fast_exp(x).to_bits(), by_conversion(x).to_bits(), "x = {x}");
        }
    }

    #[test]
    fn ln_1p_and_softplus_keep_small_values() {
        for u in geometric(1e-30, 10.0, 50_000) {
            let want = f64::from(u).ln_1p();
            let err = ((f64::from(ln_1p(u)) - want) / want).abs();
            assert!(err < 2e-6, "ln_1p({u}): relative error {err}");
        }
        assert_eq!(ln_1p(0.0), 0.0);
        for x in [-80.0f32, -30.0, -5.0, -0.5, 0.0, 0.5, 5.0, 30.0, 80.0] {
            let want = f64::from(x).exp().ln_1p();
            let err = ((f64::from(softplus(x)) - want) / want).abs();
            assert!(err < 2e-6, "softplus({x}): relative error {err}");
        }
        assert!((fast_sigmoid(0.0) - 0.5).abs() < 1e-7);
        assert!((fast_sigmoid(3.0) - 1.0 / (1.0 + (-3.0f32).exp())).abs() < 1e-7);
    }
}
