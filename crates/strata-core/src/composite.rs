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
#[inline]
pub fn resolve_pixel(colors: impl IntoIterator<Item = Rgba8>, background: [f32; 3]) -> [u8; 3] {
    let c = over_front_to_back(colors, background);
    [unorm8(c[0]), unorm8(c[1]), unorm8(c[2])]
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

    #[test]
    fn fully_transparent_fragments_change_nothing() {
        let clear = Rgba8([255, 0, 0, 0]);
        assert_eq!(resolve_pixel([clear, clear], [0.5; 3]), [128, 128, 128]);
    }
}
