//! The colour fragment: window depth, straight-alpha RGBA8 and the object that made it.
//!
//! Jähne 2014 §2.1 stores a colour fragment as 12 bytes (RGBA8 colour, f32 depth, next pointer);
//! strata replaces the store-specific `next` link by the object id, which every store keeps so that
//! results can be attributed (remote rendering, object migration) and ties broken deterministically.
//!
//! # Depth order
//!
//! Fragments are ordered front to back by [`Fragment::order_key`]: window depth first, then object
//! id, then the colour bits. Depth is a finite, non-negative `f32` in `[0, 1]` (the rasterizer
//! guarantees it, `-0.0` is normalised to `+0.0`), so its IEEE bit pattern orders like the number.
//! Breaking ties by *content* (object, then colour) instead of by primitive order means two
//! fragments that compare equal are identical in everything a resolve reads: the sorted run — and
//! so the image and the DeepFrame — does not depend on the order the triangles were drawn in.

use std::cmp::Ordering;

/// Identifies the scene object (one mesh, or one glTF mesh node) that produced a fragment.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(transparent)]
pub struct ObjectId(pub u32);

/// A straight-alpha (not premultiplied) RGBA colour with 8 bits per channel.
///
/// Channel order in memory is `[r, g, b, a]`; as a `u32` (see [`Rgba8::to_bits`]) red is the
/// least significant byte, like GLSL's `packUnorm4x8`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[repr(transparent)]
pub struct Rgba8(pub [u8; 4]);

impl Rgba8 {
    /// Quantises a straight-alpha colour in `[0, 1]` as GLSL `packUnorm4x8` does:
    /// `round(clamp(c, 0, 1) * 255)` per channel.
    #[inline]
    pub fn from_unorm(c: [f32; 4]) -> Self {
        Rgba8([unorm8(c[0]), unorm8(c[1]), unorm8(c[2]), unorm8(c[3])])
    }

    /// The colour as floats in `[0, 1]` (`c / 255`, correctly rounded, from a table).
    #[inline]
    pub fn to_unorm(self) -> [f32; 4] {
        let [r, g, b, a] = self.0;
        [
            UNORM8_TO_F32[r as usize],
            UNORM8_TO_F32[g as usize],
            UNORM8_TO_F32[b as usize],
            UNORM8_TO_F32[a as usize],
        ]
    }

    /// The packed form, red in the low byte.
    #[inline]
    pub fn to_bits(self) -> u32 {
        u32::from_le_bytes(self.0)
    }

    /// Inverse of [`Rgba8::to_bits`].
    #[inline]
    pub fn from_bits(bits: u32) -> Self {
        Rgba8(bits.to_le_bytes())
    }

    /// The alpha channel.
    #[inline]
    pub fn alpha(self) -> u8 {
        self.0[3]
    }
}

/// `UNORM8_TO_F32[c] == c as f32 / 255.0`: the table the resolve reads instead of dividing.
pub static UNORM8_TO_F32: [f32; 256] = {
    let mut t = [0.0f32; 256];
    let mut i = 0;
    while i < 256 {
        t[i] = i as f32 / 255.0;
        i += 1;
    }
    t
};

/// Quantises one channel: `round(clamp(v, 0, 1) * 255)` with halves rounded up; NaN maps to 0.
///
/// Written as `trunc(x + 0.5)` because `f32::round` is a libm call on baseline x86-64 and this
/// runs once per channel per fragment. For the non-negative `x` here the two agree except where
/// `x + 0.5` itself rounds up in f32 (x within half an ulp below a half-integer), where this rounds
/// up; GLSL leaves halves implementation-defined, and every strata path uses this one function.
#[inline]
pub fn unorm8(v: f32) -> u8 {
    // The same bits as `(v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8` for every f32 (checked
    // exhaustively), in half the instructions: the two compares are one `maxss` and one `minss`
    // and map NaN to 0 on the way in, so the conversion needs no NaN fix-up.
    let v = if v > 0.0 { v } else { 0.0 };
    let v = if v < 1.0 { v } else { 1.0 };
    (v * 255.0 + 0.5) as u8
}

/// [`unorm8`] of the first three lanes of `v` at once (the fourth is ignored), the same bits:
/// `maxps` and `minps` return their second operand when the first is NaN or the compare fails,
/// as `unorm8`'s selects do, and `cvttps` truncates like `as u8` on `[0.5, 255.5]`. For the
/// resolve and the headlight, which quantise a colour a pixel or a fragment.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn unorm8_rgb_in_lanes(simd: pulp::x86::V1, v: std::arch::x86_64::__m128) -> [u8; 3] {
    let (f, i) = (simd.sse, simd.sse2);
    let v = f._mm_max_ps(v, f._mm_setzero_ps());
    let v = f._mm_min_ps(v, f._mm_set1_ps(1.0));
    let v = f._mm_add_ps(f._mm_mul_ps(v, f._mm_set1_ps(255.0)), f._mm_set1_ps(0.5));
    let v = i._mm_cvttps_epi32(v);
    let v = i._mm_packus_epi16(i._mm_packs_epi32(v, v), i._mm_setzero_si128());
    let [r, g, b, _] = i._mm_cvtsi128_si32(v).to_le_bytes();
    [r, g, b]
}

/// One colour fragment: what a fragment store keeps per rasterised sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C)]
pub struct Fragment {
    /// Window-space depth, `0.5 * z_ndc + 0.5`, in `[0, 1]`; smaller is nearer.
    pub depth: f32,
    /// Shaded colour, straight alpha.
    pub color: Rgba8,
    /// The object that produced the fragment.
    pub object: ObjectId,
}

impl Fragment {
    /// The key that orders fragments front to back; see the module docs.
    ///
    /// Depth bits in the high 32 bits of the first word make integer comparison equal to depth
    /// comparison for the non-negative depths strata produces.
    #[inline]
    pub fn order_key(&self) -> (u64, u32) {
        (
            (u64::from(self.depth.to_bits()) << 32) | u64::from(self.object.0),
            self.color.to_bits(),
        )
    }

    /// Front-to-back comparison by [`Fragment::order_key`].
    #[inline]
    pub fn cmp_front_to_back(&self, other: &Self) -> Ordering {
        self.order_key().cmp(&other.order_key())
    }
}

/// Sorts a run of fragments front to back by [`Fragment::order_key`].
///
/// Runs are short (a pixel's depth complexity): insertion sort for up to 32 fragments, where it
/// beats the general sort, and the standard unstable sort beyond. Equal keys mean identical
/// fragments, so stability is irrelevant.
#[inline]
pub fn sort_front_to_back(run: &mut [Fragment]) {
    if run.len() <= 32 {
        for i in 1..run.len() {
            let item = run[i];
            let key = item.order_key();
            let mut j = i;
            while j > 0 && run[j - 1].order_key() > key {
                run[j] = run[j - 1];
                j -= 1;
            }
            run[j] = item;
        }
    } else {
        run.sort_unstable_by_key(Fragment::order_key);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A sweep of `f32` bit patterns (every 65,521st, so each exponent and many mantissas) and
    /// the values where quantisation turns: NaNs, ±0, ±∞, subnormals, the half-integers.
    fn awkward_floats() -> impl Iterator<Item = f32> {
        let sweep = (0..=u32::MAX / 65_521).map(|k| f32::from_bits(k * 65_521));
        let halves = (0..=255).flat_map(|k| {
            let x = (k as f32 + 0.5) / 255.0;
            [
                x,
                f32::from_bits(x.to_bits() - 1),
                f32::from_bits(x.to_bits() + 1),
            ]
        });
        let special = [
            f32::NAN,
            -f32::NAN,
            0.0,
            -0.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE / 2.0,
            1.0,
            f32::from_bits(1.0f32.to_bits() - 1),
            1.0 + f32::EPSILON,
        ];
        sweep.chain(halves).chain(special)
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn lanes_quantise_like_unorm8_everywhere() {
        let simd = pulp::x86::V1::try_new().expect("SSE2 is part of x86_64");
        let f = simd.sse;
        for x in awkward_floats() {
            let rgb = [x, -x, x * 0.5];
            assert_eq!(
                unorm8_rgb_in_lanes(simd, f._mm_set_ps(f32::NAN, rgb[2], rgb[1], rgb[0])),
                rgb.map(unorm8),
                "{x:e} ({:#010x})",
                x.to_bits()
            );
        }
    }

    #[test]
    fn unorm8_matches_pack_unorm4x8() {
        assert_eq!(unorm8(0.0), 0);
        assert_eq!(unorm8(1.0), 255);
        assert_eq!(unorm8(0.5), 128); // 127.5 rounds half away from zero
        assert_eq!(unorm8(-3.0), 0);
        assert_eq!(unorm8(7.0), 255);
        assert_eq!(unorm8(f32::NAN), 0);
        assert_eq!(
            Rgba8::from_unorm([0.2, 0.6, 1.0, 0.5]).0,
            [51, 153, 255, 128]
        );
    }

    #[test]
    fn unorm_table_is_the_division() {
        for c in 0..=255u8 {
            assert_eq!(Rgba8([c, 0, 0, 0]).to_unorm()[0], f32::from(c) / 255.0);
            assert_eq!(unorm8(f32::from(c) / 255.0), c);
        }
    }

    #[test]
    fn rgba_bits_round_trip_red_in_low_byte() {
        let c = Rgba8([1, 2, 3, 4]);
        assert_eq!(c.to_bits(), 0x0403_0201);
        assert_eq!(Rgba8::from_bits(c.to_bits()), c);
    }

    #[test]
    fn ties_break_by_object_then_colour() {
        let f = |d: f32, o: u32, c: u8| Fragment {
            depth: d,
            color: Rgba8([c, 0, 0, 255]),
            object: ObjectId(o),
        };
        let mut run = [f(0.5, 2, 0), f(0.5, 1, 9), f(0.25, 7, 0), f(0.5, 1, 3)];
        sort_front_to_back(&mut run);
        assert_eq!(
            run,
            [f(0.25, 7, 0), f(0.5, 1, 3), f(0.5, 1, 9), f(0.5, 2, 0)]
        );
    }

    proptest! {
        #[test]
        fn sort_orders_by_depth_for_any_input(
            depths in proptest::collection::vec(0.0f32..=1.0, 0..80),
        ) {
            let mut run: Vec<Fragment> = depths
                .iter()
                .enumerate()
                .map(|(i, &d)| Fragment { depth: d, color: Rgba8([i as u8; 4]), object: ObjectId(i as u32 % 3) })
                .collect();
            let mut reference = run.clone();
            reference.sort_by(|a, b| {
                a.depth.total_cmp(&b.depth).then(a.object.cmp(&b.object)).then(a.color.to_bits().cmp(&b.color.to_bits()))
            });
            sort_front_to_back(&mut run);
            prop_assert_eq!(run, reference);
        }
    }
}
