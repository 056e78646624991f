//! Unit normals packed into 32 bits as spherical angles (Jähne 2014 §2.1, eq. 2.1–2.2).
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
//! bits  0..16   θ (azimuth, atan2(y, x)) as unorm16 over [-π, π]
//! bits 16..32   φ (inclination, acos(z))  as unorm16 over [0, π], computed as
//!               atan2(√(x² + y²), z), which stays accurate next to the poles
//! ```
//!
//! The thesis stores the two angles as half floats (`packHalf2x16`), whose 10-bit mantissa leaves
//! steps of up to 2⁻⁸ rad near θ = ±π — up to 0.8/255 of headlight shading. Fixed point over the
//! known ranges spends all 16 bits on the angle: steps of 9.6·10⁻⁵ rad in θ and 4.8·10⁻⁵ rad in
//! φ, so a re-shaded normal fragment rounds to the shaded colour but for rare ±1 ties.
//!
//! The poles are canonical (φ = 0 or π stores θ = 0), and [`PackedNormal::NONE`] (all ones, which
//! the canonical form never produces) stands for "no normal": a degenerate interpolated normal,
//! or an unlit object. It shades as `N·L = 0`, like a zero normal in
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
        // φ = atan2(√(x² + y²), z) rather than acos(z): acos cannot resolve angles below ~3·10⁻⁴
        // from an f32 z near ±1, which is where normals facing the camera are. Scale cancels.
        let (x, y, z) = (n[0], n[1], n[2]);
        let phi = quantise((x * x + y * y).sqrt().atan2(z) / std::f32::consts::PI);
        let theta = if phi == 0 || phi == 0xFFFF {
            0
        } else {
            quantise((y.atan2(x) + std::f32::consts::PI) / std::f32::consts::TAU)
        };
        PackedNormal(u32::from(theta) | (u32::from(phi) << 16))
    }

    /// The unit normal, or `None` for [`PackedNormal::NONE`].
    #[inline]
    pub fn unpack(self) -> Option<[f32; 3]> {
        if self == PackedNormal::NONE {
            return None;
        }
        let theta = f32::from(self.0 as u16) / SCALE * std::f32::consts::TAU - std::f32::consts::PI;
        let phi = f32::from((self.0 >> 16) as u16) / SCALE * std::f32::consts::PI;
        // `libm`, not the platform's maths library: both ends of a reprojection link must unpack
        // to the same bits whatever machine they run on.
        let (st, ct) = (libm::sinf(theta), libm::cosf(theta));
        let (sp, cp) = (libm::sinf(phi), libm::cosf(phi));
        Some([sp * ct, sp * st, cp])
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

#[inline]
fn quantise(unit: f32) -> u16 {
    (unit.clamp(0.0, 1.0) * SCALE + 0.5) as u16
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
        // Poles are canonical: any azimuth gives the same code.
        assert_eq!(
            PackedNormal::pack([1e-9, 0.0, 1.0]),
            PackedNormal::pack([0.0, 1e-9, 1.0])
        );
        assert_ne!(PackedNormal::pack([0.0, 0.0, -1.0]), PackedNormal::NONE);
        // Near a pole, where acos(z) of an f32 z cannot tell φ = 1.4·10⁻⁴ from 0 (found by
        // proptest: code φ = 3 came back as the pole).
        let near = PackedNormal(3 << 16).unpack().expect("a normal");
        assert_eq!(PackedNormal::pack(near).0 >> 16, 3);
    }

    #[test]
    fn degenerate_normals_pack_as_none() {
        for n in [[0.0; 3], [f32::NAN, 0.0, 1.0], [f32::INFINITY, 0.0, 0.0]] {
            assert_eq!(PackedNormal::pack(n), PackedNormal::NONE, "{n:?}");
        }
        assert_eq!(PackedNormal::NONE.unpack(), None);
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
