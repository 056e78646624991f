//! Unit normals packed into 32 bits by the octahedral map (Cigolle et al. 2014, "A Survey of
//! Efficient Representations for Independent Unit Vectors", §3.1).
//!
//! A normal fragment (Jähne 2014 Table 2.1) replaces the colour by the surface normal so that a
//! receiver can re-shade it after moving it (the reprojection transfer, ch. 5). strata keeps the
//! 12-byte fragment layout and puts the packed normal in the colour's four bytes: a
//! [`crate::Fragment`] whose `color` holds [`PackedNormal::to_bits`] travels through every store,
//! DeepFrame and codec unchanged.
//!
//! # Layout
//!
//! ```text
//! n / (|x| + |y| + |z|) lies on the octahedron |x| + |y| + |z| = 1; its upper half projects
//! onto the square |u| + |v| ≤ 1 and the lower half is folded out into the square's corners:
//!   (u, v) = (x, y) / (|x| + |y| + |z|)                  if z ≥ 0
//!   (u, v) = ((1 − |v|) · sign u, (1 − |u|) · sign v)   if z < 0 (of the unfolded u, v)
//! bits  0..16   u as unorm16 over [-1, 1]
//! bits 16..32   v as unorm16 over [-1, 1]
//! ```
//!
//! Jähne (2014, eq. 2.1–2.2) stores spherical angles as half floats. strata used to store the
//! two angles as unorm16 (steps of 9.6·10⁻⁵ rad), but packing needed two `atan2` a fragment and
//! unpacking a `sin` and a `cos` of each angle (through `libm`, so that both ends of a link
//! agree): a fifth of a reprojection node's time on the full dragon. The octahedral map needs
//! only additions, multiplications, a division and (to unpack) a square root, which IEEE
//! arithmetic makes exact, so both ends agree on every platform without a portable maths
//! library. Its codes cover the sphere evenly: the round trip stays within 1.2·10⁻⁴ rad, like the
//! angles' (tested).
//!
//! The south pole `(0, 0, −1)` has four codes, the square's corners; packing always gives the
//! corner `u = 1, v = −1`, so that [`PackedNormal::NONE`] (all ones, the corner `u = v = 1`,
//! which packing never produces) can stand for "no normal": a degenerate interpolated normal, or
//! an unlit object. It shades as `N·L = 0`, like a zero normal in
//! [`crate::material::headlight_factor`].

/// A unit normal in 32 bits; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(transparent)]
pub struct PackedNormal(pub u32);

const SCALE: f32 = 65535.0;

impl PackedNormal {
    /// No normal (zero-length, or the object is unlit).
    pub const NONE: PackedNormal = PackedNormal(u32::MAX);

    /// Packs a normal of any positive length; zero, non-finite or tiny vectors pack as
    /// [`PackedNormal::NONE`].
    #[inline]
    pub fn pack(n: [f32; 3]) -> PackedNormal {
        let len2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
        if !(len2 > 1e-30 && len2.is_finite()) {
            return PackedNormal::NONE;
        }
        let (x, y, z) = (n[0], n[1], n[2]);
        let l1 = x.abs() + y.abs() + z.abs();
        let (u, v) = fold(x / l1, y / l1, z);
        let (u, v) = (quantise(u), quantise(v));
        // The four corners are the south pole: one canonical code, u = 1, v = -1 (u = v = 1
        // is NONE).
        let edge = |q: u16| q == 0 || q == u16::MAX;
        if edge(u) && edge(v) {
            return PackedNormal(0xFFFF);
        }
        PackedNormal(u32::from(u) | (u32::from(v) << 16))
    }

    /// [`PackedNormal::pack`] of `N` normals given as their x, y and z in lanes, as bits: the
    /// same bits, from arithmetic without branches that the compiler vectorises. A rasteriser
    /// packs a normal a fragment; one at a time, each took two dependent divisions and a
    /// mispredicted branch or two, and made a normal render slower than a shaded one.
    #[inline(always)]
    pub fn pack_lanes<const N: usize>(x: &[f32; N], y: &[f32; N], z: &[f32; N]) -> [u32; N] {
        // `quantise` without the saturating cast, which runs a lane at a time: after the clamp
        // the value lies in [0.5, 65535.5], whose truncation is exact in f32 and reads off the
        // low bits of `t + 2²³`. NaN (a lane that is NONE anyway) gives some code.
        let quantise = |s: f32| {
            let c = (s * 0.5 + 0.5).clamp(0.0, 1.0);
            ((c * SCALE + 0.5).trunc() + 8_388_608.0).to_bits() & 0xFFFF
        };
        std::array::from_fn(|l| {
            let (x, y, z) = (x[l], y[l], z[l]);
            let len2 = x * x + y * y + z * z;
            let valid = len2 > 1e-30 && len2 < f32::INFINITY;
            let l1 = x.abs() + y.abs() + z.abs();
            let (u, v) = (x / l1, y / l1);
            let sign = |a: f32| if a >= 0.0 { 1.0 } else { -1.0 };
            let (fu, fv) = ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v));
            let upper = z >= 0.0;
            let (u, v) = (if upper { u } else { fu }, if upper { v } else { fv });
            let (qu, qv) = (quantise(u), quantise(v));
            let edge = |q: u32| q == 0 || q == 0xFFFF;
            let code = if edge(qu) && edge(qv) {
                0xFFFF
            } else {
                qu | (qv << 16)
            };
            if valid { code } else { PackedNormal::NONE.0 }
        })
    }

    /// The unit normal, or `None` for [`PackedNormal::NONE`].
    #[inline]
    pub fn unpack(self) -> Option<[f32; 3]> {
        if self == PackedNormal::NONE {
            return None;
        }
        let u = f32::from(self.0 as u16) / SCALE * 2.0 - 1.0;
        let v = f32::from((self.0 >> 16) as u16) / SCALE * 2.0 - 1.0;
        let z = 1.0 - u.abs() - v.abs();
        let (x, y) = fold(u, v, z);
        let inv = 1.0 / (x * x + y * y + z * z).sqrt();
        Some([x * inv, y * inv, z * inv])
    }

    /// The four bytes as stored in a fragment's colour slot.
    #[inline]
    pub fn to_bits(self) -> u32 {
        self.0
    }

    /// Inverse of [`PackedNormal::to_bits`]; every `u32` is a valid packed normal.
    #[inline]
    pub fn from_bits(bits: u32) -> PackedNormal {
        PackedNormal(bits)
    }
}

/// The octahedral fold: `(u, v)` unchanged on the upper half (`z ≥ 0`), the lower half's
/// reflected into the square's corners. It is its own inverse on the square's corners.
#[inline]
fn fold(u: f32, v: f32, z: f32) -> (f32, f32) {
    if z >= 0.0 {
        return (u, v);
    }
    let sign = |a: f32| if a >= 0.0 { 1.0 } else { -1.0 };
    ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v))
}

/// `[-1, 1]` as unorm16.
#[inline]
fn quantise(signed: f32) -> u16 {
    ((signed * 0.5 + 0.5).clamp(0.0, 1.0) * SCALE + 0.5) as u16
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The angle between two vectors, in f64 as atan2(|a×b|, a·b) (acos of an f32 dot product
    /// cannot resolve angles below ~3·10⁻⁴).
    fn angle_between(a: [f32; 3], b: [f32; 3]) -> f32 {
        let a = a.map(f64::from);
        let b = b.map(f64::from);
        let cross = [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ];
        let c = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
        let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        c.atan2(d) as f32
    }

    #[test]
    fn axes_and_poles() {
        for n in [
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.0, 0.0, 5.0],
        ] {
            let u = PackedNormal::pack(n).unpack().expect("a normal");
            assert!(angle_between(n, u) < 2e-4, "{n:?} -> {u:?}");
        }
        // The south pole has one code, and it is not NONE, however it is approached.
        let south = PackedNormal::pack([0.0, 0.0, -1.0]);
        assert_ne!(south, PackedNormal::NONE);
        for n in [
            [1e-9, 1e-9, -1.0],
            [-1e-9, 1e-9, -1.0],
            [1e-9, -1e-9, -1.0],
            [-1e-9, -1e-9, -1.0],
        ] {
            assert_eq!(PackedNormal::pack(n), south, "{n:?}");
        }
        // Every corner of the square decodes to the south pole, NONE aside.
        for bits in [0x0000_0000, 0x0000_FFFF, 0xFFFF_0000] {
            assert_eq!(
                PackedNormal(bits).unpack(),
                Some([0.0, 0.0, -1.0]),
                "{bits:#x}"
            );
        }
        // The fold's seam (z = 0) packs to one code from either side.
        let code = |z: f32| PackedNormal::pack([0.6, -0.8, z]).0;
        assert_eq!(code(0.0), code(-0.0));
        assert!(code(1e-7).abs_diff(code(-1e-7)) <= 0x1_0001);
    }

    #[test]
    fn packing_in_lanes_gives_the_bits_of_packing_one_at_a_time_at_the_edges() {
        // Poles from every side, the seam, axes, the corners' neighbourhood, degenerate and
        // overflowing normals.
        let tiny = 1e-9;
        let cases: Vec<[f32; 3]> = vec![
            [0.0, 0.0, -1.0],
            [tiny, tiny, -1.0],
            [-tiny, tiny, -1.0],
            [tiny, -tiny, -1.0],
            [-tiny, -tiny, -1.0],
            [0.0, 0.0, 1.0],
            [0.6, -0.8, 0.0],
            [0.6, -0.8, -0.0],
            [0.6, -0.8, 1e-7],
            [0.6, -0.8, -1e-7],
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0; 3],
            [f32::NAN, 0.0, 1.0],
            [f32::INFINITY, 0.0, 0.0],
            [3e19, 3e19, 3e19],
            [1e-16, 0.0, 0.0],
        ];
        for chunk in cases.chunks(4) {
            let pick =
                |c: usize| -> [f32; 4] { std::array::from_fn(|l| chunk[l % chunk.len()][c]) };
            let lanes = PackedNormal::pack_lanes(&pick(0), &pick(1), &pick(2));
            for (l, &bits) in lanes.iter().enumerate() {
                let n = chunk[l % chunk.len()];
                assert_eq!(bits, PackedNormal::pack(n).to_bits(), "{n:?}");
            }
        }
    }

    #[test]
    fn degenerate_normals_pack_as_none() {
        for n in [[0.0; 3], [f32::NAN, 0.0, 1.0], [f32::INFINITY, 0.0, 0.0]] {
            assert_eq!(PackedNormal::pack(n), PackedNormal::NONE, "{n:?}");
        }
        assert_eq!(PackedNormal::NONE.unpack(), None);
    }

    #[test]
    fn round_trip_error_over_a_dense_sample_of_the_sphere() {
        // A Fibonacci sphere of 200 000 normals: evenly spread, both hemispheres and the seam.
        let count = 200_000;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let mut worst = 0f32;
        for k in 0..count {
            let z = 1.0 - 2.0 * (k as f64 + 0.5) / count as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * k as f64;
            let n = [(r * a.cos()) as f32, (r * a.sin()) as f32, z as f32];
            let u = PackedNormal::pack(n).unpack().expect("a normal");
            worst = worst.max(angle_between(n, u));
        }
        assert!(worst < 1.2e-4, "worst round-trip error {worst} rad");
        // And not far below: the test would catch a map that wastes bits.
        assert!(worst > 2e-5, "worst round-trip error {worst} rad");
    }

    proptest! {
        #[test]
        fn round_trip_error_is_below_a_ten_thousandth_of_a_radian(
            x in -1.0f32..1.0, y in -1.0f32..1.0, z in -1.0f32..1.0, scale in 1e-3f32..1e3,
        ) {
            let n = [x * scale, y * scale, z * scale];
            prop_assume!(x * x + y * y + z * z > 1e-4);
            let u = PackedNormal::pack(n).unpack().expect("a normal");
            prop_assert!((u[0] * u[0] + u[1] * u[1] + u[2] * u[2] - 1.0).abs() < 1e-5);
            prop_assert!(angle_between(n, u) < 1.2e-4, "{:?} -> {:?}", n, u);
        }

        #[test]
        fn packing_in_lanes_gives_the_bits_of_packing_one_at_a_time(
            n in proptest::array::uniform24(prop_oneof![
                4 => -2.0f32..2.0,
                1 => -1e-15f32..1e-15,
                1 => Just(0.0f32),
                1 => Just(-0.0f32),
                1 => Just(1.0f32),
                1 => Just(-1.0f32),
                1 => Just(f32::NAN),
                1 => Just(f32::INFINITY),
                1 => Just(f32::NEG_INFINITY),
                1 => Just(3e19f32),
                1 => any::<f32>(),
            ])
        ) {
            let x: [f32; 8] = std::array::from_fn(|l| n[l]);
            let y: [f32; 8] = std::array::from_fn(|l| n[8 + l]);
            let z: [f32; 8] = std::array::from_fn(|l| n[16 + l]);
            let lanes = PackedNormal::pack_lanes(&x, &y, &z);
            for l in 0..8 {
                let one = PackedNormal::pack([x[l], y[l], z[l]]).to_bits();
                prop_assert_eq!(lanes[l], one, "{:?}", [x[l], y[l], z[l]]);
            }
        }

        #[test]
        fn packing_an_unpacked_normal_is_stable(bits in any::<u32>()) {
            // Decoding then re-encoding lands on the same code or a neighbour (rounding), never
            // far away: the codes are a faithful grid.
            let p = PackedNormal::from_bits(bits);
            if let Some(u) = p.unpack() {
                let again = PackedNormal::pack(u).unpack().expect("a normal");
                prop_assert!(angle_between(u, again) < 1.2e-4);
            }
        }
    }
}
