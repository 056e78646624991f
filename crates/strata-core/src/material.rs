//! What an object looks like: its straight-alpha colour and how it is shaded (strata's shared conventions).

use crate::fragment::{Rgba8, unorm8};

/// How a fragment's colour is computed from the object's colour.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Shading {
    /// `rgb = color.rgb * (0.25 + 0.75 * |N·L|)`, `alpha = color.a`, with `N` the perspective-
    /// correctly interpolated eye-space normal and `L` the unit vector from the fragment to the eye.
    #[default]
    Headlight,
    /// `rgb = color.rgb`: every fragment of the object has the object's colour.
    Unlit,
}

impl Shading {
    /// The name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Shading::Headlight => "headlight",
            Shading::Unlit => "unlit",
        }
    }
}

/// An object's material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Straight (not premultiplied) RGBA in `[0, 1]`.
    pub color: [f32; 4],
    /// The shading model.
    pub shading: Shading,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            color: [0.8, 0.8, 0.8, 1.0],
            shading: Shading::Headlight,
        }
    }
}

/// The headlight factor `0.25 + 0.75 * |N·L|` from an unnormalised normal `n` and an unnormalised
/// eye-space position `p` (the eye is the origin, so `L = -p / |p|`).
///
/// Both vectors may carry any common positive scale (for instance the `1/w` of perspective-
/// correct interpolation): it cancels. A zero-length `n` or `p` counts as `N·L = 0`.
#[inline]
pub fn headlight_factor(n: [f32; 3], p: [f32; 3]) -> f32 {
    let nn = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
    let pp = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
    let np = n[0] * p[0] + n[1] * p[1] + n[2] * p[2];
    let denom = (nn * pp).sqrt();
    let cos = if denom > 0.0 {
        (np.abs() / denom).min(1.0)
    } else {
        0.0
    };
    0.25 + 0.75 * cos
}

/// The headlight colour of an object of colour `rgb` and quantised alpha `alpha` at headlight
/// factor `factor` ([`headlight_factor`]): `rgb · factor` quantised as GLSL `packUnorm4x8`.
///
/// The rasterizer shades with it and the reprojection transfer re-shades with it, so the two
/// agree by construction.
///
/// Runs once a shaded fragment, so on x86_64 the three channels are multiplied and quantised
/// in one SSE2 register, the same bits as [`unorm8`] a channel at a time (tested).
#[inline]
pub fn headlight_rgba(rgb: [f32; 3], alpha: u8, factor: f32) -> Rgba8 {
    #[cfg(target_arch = "x86_64")]
    if let Some(simd) = pulp::x86::V1::try_new() {
        let f = simd.sse;
        let lit = f._mm_mul_ps(
            f._mm_set_ps(0.0, rgb[2], rgb[1], rgb[0]),
            f._mm_set1_ps(factor),
        );
        let [r, g, b] = crate::fragment::unorm8_rgb_in_lanes(simd, lit);
        return Rgba8([r, g, b, alpha]);
    }
    headlight_rgba_one_channel_at_a_time(rgb, alpha, factor)
}

/// [`headlight_rgba`] a channel at a time: the definition the vector form must equal.
#[inline]
fn headlight_rgba_one_channel_at_a_time(rgb: [f32; 3], alpha: u8, factor: f32) -> Rgba8 {
    Rgba8([
        unorm8(rgb[0] * factor),
        unorm8(rgb[1] * factor),
        unorm8(rgb[2] * factor),
        alpha,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headlight_colours_in_lanes_are_a_channel_at_a_time() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for k in 0..200_000 {
            // Colours in [0, 1] and a little beyond, factors in [0.25, 1] and the ends.
            let rgb = [next() * 1.2, next(), next() * 1.1 - 0.05];
            let factor = match k % 5 {
                0 => 0.25,
                1 => 1.0,
                _ => 0.25 + 0.75 * next(),
            };
            let alpha = (k % 256) as u8;
            assert_eq!(
                headlight_rgba(rgb, alpha, factor),
                headlight_rgba_one_channel_at_a_time(rgb, alpha, factor),
                "{rgb:?} × {factor}"
            );
        }
    }

    #[test]
    fn headlight_is_full_when_facing_and_a_quarter_when_grazing() {
        // Normal towards the eye, fragment straight ahead.
        assert_eq!(headlight_factor([0.0, 0.0, 1.0], [0.0, 0.0, -2.0]), 1.0);
        // Back faces are lit the same (|N·L|): no culling, two-sided lighting.
        assert_eq!(headlight_factor([0.0, 0.0, -3.0], [0.0, 0.0, -2.0]), 1.0);
        // Normal perpendicular to the view ray.
        assert_eq!(headlight_factor([1.0, 0.0, 0.0], [0.0, 0.0, -2.0]), 0.25);
        // 60 degrees: cos = 0.5.
        let n = [60f32.to_radians().sin(), 0.0, 60f32.to_radians().cos()];
        assert!((headlight_factor(n, [0.0, 0.0, -1.0]) - 0.625).abs() < 1e-6);
        // Common scale cancels.
        let a = headlight_factor([0.3, 0.4, 0.5], [0.1, -0.2, -1.0]);
        let b = headlight_factor([3.0, 4.0, 5.0], [0.05, -0.1, -0.5]);
        assert!((a - b).abs() < 1e-6);
        // Degenerate normal.
        assert_eq!(headlight_factor([0.0; 3], [0.0, 0.0, -1.0]), 0.25);
    }
}
