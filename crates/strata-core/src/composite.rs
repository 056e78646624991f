//! The OVER operator, applied front to back (Jähne 2014 eq. 1.1; Tsopouridis 2021 `resolveColor`).
//!
//! Jähne 2014 blends back to front, `c = c_a α_a + c_b α_b (1 − α_a)`. Composited front to back with
//! the transmittance `T` (the product of `1 − α` of everything in front) the same sum reads
//!
//! ```text
//! C ← C + T · α_i · c_i        T ← T · (1 − α_i)        pixel = C + T · background
//! ```
//!
//! which lets the loop stop as soon as nothing behind can contribute. The loop stops only when `T`
//! is exactly zero (an opaque fragment, or underflow), so early exit never changes a result: every
//! exact method that calls these functions on the same sorted run produces the same bits.

use crate::fragment::{Rgba8, unorm8};

/// Composites straight-alpha colours given front to back without a background: the
/// premultiplied sum `C` and the transmittance `T` left for whatever lies behind (`A = 1 − T`).
/// Stops at the first `T` that is exactly zero, then returns `T = 0`.
#[inline]
pub fn front_to_back_f32(colors: impl IntoIterator<Item = [f32; 4]>) -> ([f32; 3], f32) {
    let mut acc = [0.0f32; 3];
    let mut t = 1.0f32;
    for [r, g, b, a] in colors {
        let w = t * a;
        acc[0] += w * r;
        acc[1] += w * g;
        acc[2] += w * b;
        t *= 1.0 - a;
        if t <= 0.0 {
            return (acc, 0.0);
        }
    }
    (acc, t)
}

/// Composites straight-alpha colours given front to back onto an opaque background.
///
/// ```
/// # use strata_core::composite::over_front_to_back_f32;
/// // Half-transparent blue over red over white (Jähne 2014, figure 1.1 (2)).
/// let out = over_front_to_back_f32([[0.0, 0.0, 1.0, 0.5], [1.0, 0.0, 0.0, 0.5]], [1.0; 3]);
/// assert_eq!(out, [0.5, 0.25, 0.75]);
/// ```
#[inline]
pub fn over_front_to_back_f32(
    colors: impl IntoIterator<Item = [f32; 4]>,
    background: [f32; 3],
) -> [f32; 3] {
    let (acc, t) = front_to_back_f32(colors);
    if t == 0.0 {
        // Nothing of the background shows: skip the multiply-add so the result is `acc` to the bit.
        return acc;
    }
    [
        acc[0] + t * background[0],
        acc[1] + t * background[1],
        acc[2] + t * background[2],
    ]
}

/// Composites RGBA8 fragment colours given front to back onto an opaque background.
#[inline]
pub fn over_front_to_back(
    colors: impl IntoIterator<Item = Rgba8>,
    background: [f32; 3],
) -> [f32; 3] {
    over_front_to_back_f32(colors.into_iter().map(Rgba8::to_unorm), background)
}

/// Composites and quantises to the 8-bit output pixel (`round(v * 255)`, no transfer function).
///
/// Every resolve of every store ends here, once a covered pixel, so on x86_64 it computes the
/// three channels at once in one SSE2 register (`resolve_pixel_in_lanes`); the result is the
/// same bits as [`over_front_to_back`] then [`unorm8`] per channel (the same operations on each
/// channel, in the same order: tested against it).
#[inline]
pub fn resolve_pixel(colors: impl IntoIterator<Item = Rgba8>, background: [f32; 3]) -> [u8; 3] {
    PixelResolver::new(background).resolve(colors)
}

/// [`resolve_pixel`] with the background and the CPU's vector unit looked up once, for a resolve
/// that composites many pixels onto one background: the same bits, without the per-pixel check
/// for SSE2.
#[derive(Clone, Copy, Debug)]
pub struct PixelResolver {
    background: [f32; 3],
    #[cfg(target_arch = "x86_64")]
    simd: Option<pulp::x86::V1>,
}

impl PixelResolver {
    /// A resolver onto `background`.
    #[inline]
    pub fn new(background: [f32; 3]) -> Self {
        PixelResolver {
            background,
            #[cfg(target_arch = "x86_64")]
            simd: pulp::x86::V1::try_new(),
        }
    }

    /// [`resolve_pixel`] of `colors`, front to back, onto the background.
    #[inline(always)]
    pub fn resolve(&self, colors: impl IntoIterator<Item = Rgba8>) -> [u8; 3] {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.simd {
            return resolve_pixel_in_lanes(simd, colors, self.background);
        }
        resolve_pixel_one_channel_at_a_time(colors, self.background)
    }
}

/// [`resolve_pixel`] a channel at a time: the definition the vector form must equal.
#[inline]
fn resolve_pixel_one_channel_at_a_time(
    colors: impl IntoIterator<Item = Rgba8>,
    background: [f32; 3],
) -> [u8; 3] {
    let c = over_front_to_back(colors, background);
    [unorm8(c[0]), unorm8(c[1]), unorm8(c[2])]
}

/// [`resolve_pixel`] with `[r, g, b, a]` in the four lanes of an SSE2 register: a fragment's
/// bytes widened and divided by 255 (the exact quotient, as [`Rgba8::to_unorm`]'s table holds
/// it), `C += (T·α)·c` and `T ← T·(1 − α)` as the scalar loop does them, and the quantisation
/// of the three lanes at once (`unorm8_rgb_in_lanes`). SSE2 is part of every x86_64 CPU; only
/// the intrinsics' safe wrappers need the token.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn resolve_pixel_in_lanes(
    simd: pulp::x86::V1,
    colors: impl IntoIterator<Item = Rgba8>,
    background: [f32; 3],
) -> [u8; 3] {
    let (f, i) = (simd.sse, simd.sse2);
    let zero = i._mm_setzero_si128();
    let mut acc = f._mm_setzero_ps();
    let mut t = 1.0f32;
    for c in colors {
        let bytes = i._mm_cvtsi32_si128(c.to_bits() as i32);
        let lanes = i._mm_unpacklo_epi16(i._mm_unpacklo_epi8(bytes, zero), zero);
        let unorm = f._mm_div_ps(i._mm_cvtepi32_ps(lanes), f._mm_set1_ps(255.0));
        let a = f._mm_cvtss_f32(f._mm_shuffle_ps::<0xff>(unorm, unorm));
        let w = f._mm_set1_ps(t * a);
        acc = f._mm_add_ps(acc, f._mm_mul_ps(w, unorm));
        t *= 1.0 - a;
        // T is a product of factors in [0, 1]: at or below 0 it is 0, and stays so.
        if t <= 0.0 {
            break;
        }
    }
    if t != 0.0 {
        let [r, g, b] = background;
        let bg = f._mm_set_ps(0.0, b, g, r);
        acc = f._mm_add_ps(acc, f._mm_mul_ps(f._mm_set1_ps(t), bg));
    }
    crate::fragment::unorm8_rgb_in_lanes(simd, acc)
}

/// The 8-bit background pixel, what an empty pixel resolves to.
#[inline]
pub fn background_pixel(background: [f32; 3]) -> [u8; 3] {
    [
        unorm8(background[0]),
        unorm8(background[1]),
        unorm8(background[2]),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_000_worked_example_exact_in_float() {
        let red = [1.0, 0.0, 0.0, 0.5];
        let blue = [0.0, 0.0, 1.0, 0.5];
        let white = [1.0, 1.0, 1.0];
        // Each alone over white (figure 1.1 A and B).
        assert_eq!(over_front_to_back_f32([red], white), [1.0, 0.5, 0.5]);
        assert_eq!(over_front_to_back_f32([blue], white), [0.5, 0.5, 1.0]);
        // Red over blue (1) and blue over red (2): order matters.
        assert_eq!(
            over_front_to_back_f32([red, blue], white),
            [0.75, 0.25, 0.5]
        );
        assert_eq!(
            over_front_to_back_f32([blue, red], white),
            [0.5, 0.25, 0.75]
        );
    }

    #[test]
    fn seed_000_worked_example_in_rgba8() {
        // Alpha 0.5 quantises to 128/255 = 0.50196: red over blue over white is
        // R = a + (1-a)·a·0 + (1-a)²  = 0.50196 + 0.24804 = 0.75000 → 191
        // G = (1-a)²                  = 0.24804          → 63
        // B = (1-a)·a + (1-a)²         = 0.49804          → 127
        let red = Rgba8::from_unorm([1.0, 0.0, 0.0, 0.5]);
        let blue = Rgba8::from_unorm([0.0, 0.0, 1.0, 0.5]);
        assert_eq!(red.alpha(), 128);
        assert_eq!(resolve_pixel([red, blue], [1.0; 3]), [191, 63, 127]);
    }

    #[test]
    fn opaque_fragment_hides_everything_behind_it() {
        let opaque = Rgba8([10, 20, 30, 255]);
        let behind = Rgba8([255, 255, 255, 128]);
        assert_eq!(
            resolve_pixel([opaque, behind], [0.0, 1.0, 0.0]),
            [10, 20, 30]
        );
        assert_eq!(resolve_pixel([opaque], [0.0, 1.0, 0.0]), [10, 20, 30]);
    }

    #[test]
    fn empty_pixel_is_background() {
        assert_eq!(resolve_pixel([], [0.2, 0.4, 1.0]), [51, 102, 255]);
        assert_eq!(background_pixel([0.2, 0.4, 1.0]), [51, 102, 255]);
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn lanes_composite_like_one_channel_at_a_time() {
        let simd = pulp::x86::V1::try_new().expect("SSE2 is part of x86_64");
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let backgrounds = [[0.0; 3], [1.0; 3], [0.2, 0.4, 1.0], [0.1, 0.7, 0.3]];
        for _ in 0..200_000 {
            let r = next();
            let n = (r % 7) as usize;
            let run: Vec<Rgba8> = (0..n)
                .map(|_| {
                    let b = next().to_le_bytes();
                    // Alphas at the ends often: transparent and opaque fragments.
                    let a = match b[4] % 4 {
                        0 => 0,
                        1 => 255,
                        _ => b[5],
                    };
                    Rgba8([b[0], b[1], b[2], a])
                })
                .collect();
            let bg = backgrounds[(r >> 8) as usize % backgrounds.len()];
            assert_eq!(
                resolve_pixel_in_lanes(simd, run.iter().copied(), bg),
                resolve_pixel_one_channel_at_a_time(run.iter().copied(), bg),
                "{run:?} over {bg:?}"
            );
        }
    }

    #[test]
    fn fully_transparent_fragments_change_nothing() {
        let clear = Rgba8([255, 0, 0, 0]);
        assert_eq!(resolve_pixel([clear, clear], [0.5; 3]), [128, 128, 128]);
    }
}
