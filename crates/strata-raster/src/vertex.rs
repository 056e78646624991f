//! The vertex stage: eye space, clip space, outcodes, fixed-point window coordinates.
//!
//! Per vertex, in three parallel arrays for all objects of the frame (structure of arrays, so
//! setup and coverage — which touch every triangle — read 9 bytes a vertex, and only covered
//! pixels pay for the attributes):
//!
//! ```text
//! ScreenPos  x, y : i32    window position in 24.8 fixed point (1/256 pixel), y down, row 0 on top
//! outcode    u8            which clip planes and guard band the vertex lies outside of
//! Attrs      z    : f32    window depth 0.5·z_ndc + 0.5
//!            iw   : f32    1 / w_clip
//!            p_w  : f32×3  eye-space position / w_clip   (headlight: L = -p/|p|)
//!            n_w  : f32×3  eye-space normal / w_clip, unnormalised (inverse-transpose of the
//!                          model-view)
//! ```
//!
//! Position and normal are stored divided by `w`: perspective-correct interpolation weights each
//! vertex's attribute by `1/w`, and these two are only ever used that way.
//!
//! Screen position and attributes are meaningful only
//! for vertices in front of the near plane and inside the guard band; triangles touching any other
//! vertex go through the clipper, which recomputes eye-space values from the object-space vertex
//! and projects its own vertices with the same [`Viewport::project`].
//!
//! Snapping to 1/256 pixel *per vertex* is what makes the rasterizer watertight: two triangles
//! sharing a vertex share its exact integer position, so their common edge has one integer edge
//! function and the top-left rule gives every sample on it to exactly one of them.

use glam::{Mat3, Mat4, Vec3, Vec4};

/// Fractional bits of the fixed-point window coordinates.
pub const SUBPIXEL_BITS: u32 = 8;
/// One pixel in fixed point.
pub const ONE: i32 = 1 << SUBPIXEL_BITS;
/// Half a pixel in fixed point: the offset of a pixel centre.
pub const HALF: i32 = ONE / 2;

/// How far outside the image (in pixels) vertices may lie before triangles are clipped against
/// the guard band. At 2^16 pixels f32 window coordinates still resolve 1/256 pixel, and
/// fixed-point values stay far inside `i32`.
pub const GUARD_PIXELS: f32 = 65536.0;

/// Outcode bits: which clip-space half-spaces a vertex lies outside of.
pub mod outcode {
    /// `x < -w`
    pub const LEFT: u8 = 1;
    /// `x > w`
    pub const RIGHT: u8 = 2;
    /// `y < -w`
    pub const BOTTOM: u8 = 4;
    /// `y > w`
    pub const TOP: u8 = 8;
    /// `z < -w`: in front of the near plane (or behind the eye).
    pub const NEAR: u8 = 16;
    /// `z > w`: beyond the far plane.
    pub const FAR: u8 = 32;
    /// Outside the guard band: window coordinates would be too large for fixed point.
    pub const GUARD: u8 = 64;
    /// The six planes of the view volume: a triangle with all three vertices outside the same one
    /// is invisible.
    pub const VIEW: u8 = LEFT | RIGHT | BOTTOM | TOP | NEAR | FAR;
    /// A triangle with any vertex outside these must be clipped before it can be projected.
    pub const CLIP: u8 = NEAR | GUARD;
}

/// A vertex's window position in 24.8 fixed point; see the module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C)]
pub struct ScreenPos {
    /// Window x.
    pub x: i32,
    /// Window y (down).
    pub y: i32,
}

/// What is interpolated across a triangle; see the module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C)]
pub struct Attrs {
    /// Window depth.
    pub z: f32,
    /// `1 / w_clip`.
    pub iw: f32,
    /// Eye-space position divided by `w_clip`.
    pub p_w: [f32; 3],
    /// Eye-space normal (unnormalised) divided by `w_clip`.
    pub n_w: [f32; 3],
}

impl Attrs {
    /// The attributes of an eye-space position `p` and normal `n` projected to `z` and `iw`.
    #[inline]
    pub fn new(z: f32, iw: f32, p: Vec3, n: Vec3) -> Attrs {
        Attrs {
            z,
            iw,
            p_w: (p * iw).to_array(),
            n_w: (n * iw).to_array(),
        }
    }
}

/// Image size and the guard band, in the units the stages need.
#[derive(Clone, Copy, Debug)]
pub struct Viewport {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    w: f32,
    h: f32,
    /// Guard band half-width in NDC units, x and y.
    pub guard: [f32; 2],
}

impl Viewport {
    /// The viewport of a `width` × `height` image.
    pub fn new(width: u32, height: u32) -> Self {
        let (w, h) = (width as f32, height as f32);
        Viewport {
            width,
            height,
            w,
            h,
            guard: [2.0 * GUARD_PIXELS / w + 1.0, 2.0 * GUARD_PIXELS / h + 1.0],
        }
    }

    /// The outcode of a clip-space position.
    #[inline]
    pub fn outcode(&self, c: Vec4) -> u8 {
        let mut o = 0;
        if c.x < -c.w {
            o |= outcode::LEFT;
        }
        if c.x > c.w {
            o |= outcode::RIGHT;
        }
        if c.y < -c.w {
            o |= outcode::BOTTOM;
        }
        if c.y > c.w {
            o |= outcode::TOP;
        }
        if c.z < -c.w {
            o |= outcode::NEAR;
        }
        if c.z > c.w {
            o |= outcode::FAR;
        }
        // Written so that NaN coordinates count as outside the guard band.
        if !(c.x.abs() <= self.guard[0] * c.w && c.y.abs() <= self.guard[1] * c.w) {
            o |= outcode::GUARD;
        }
        o
    }

    /// Fixed-point window position, window depth and `1/w` of a clip-space position that lies in
    /// front of the near plane and inside the guard band.
    #[inline]
    pub fn project(&self, c: Vec4) -> (i32, i32, f32, f32) {
        let iw = 1.0 / c.w;
        let (xn, yn, zn) = (c.x * iw, c.y * iw, c.z * iw);
        let xw = (xn * 0.5 + 0.5) * self.w;
        let yw = (0.5 - yn * 0.5) * self.h;
        (snap(xw), snap(yw), zn * 0.5 + 0.5, iw)
    }
}

/// Rounds a window coordinate to 24.8 fixed point, ties to even.
///
/// Adding and subtracting 1.5·2^52 in f64 rounds to an integer in the current (round-to-nearest-
/// even) mode without a libm call; valid for |v| < 2^51, far beyond the guard band.
#[inline]
fn snap(window: f32) -> i32 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 * 2^52
    let v = f64::from(window) * f64::from(ONE);
    ((v + MAGIC) - MAGIC) as i32
}

/// Per-object matrices of the vertex stage.
#[derive(Clone, Copy, Debug)]
pub struct ObjectTransform {
    /// Object → eye.
    pub model_view: Mat4,
    /// Normal matrix: inverse-transpose of the model-view's upper 3×3.
    pub normal: Mat3,
    /// Eye → clip.
    pub projection: Mat4,
}

impl ObjectTransform {
    /// Eye-space position and normal of an object-space vertex.
    #[inline]
    pub fn eye(&self, position: [f32; 3], normal: [f32; 3], with_normals: bool) -> (Vec3, Vec3) {
        let p = self.model_view.transform_point3(Vec3::from(position));
        let n = if with_normals {
            self.normal * Vec3::from(normal)
        } else {
            Vec3::ZERO
        };
        (p, n)
    }

    /// Matrices for one object.
    pub fn new(view: Mat4, model: Mat4, projection: Mat4) -> Self {
        let model_view = view * model;
        ObjectTransform {
            model_view,
            normal: Mat3::from_mat4(model_view).inverse().transpose(),
            projection,
        }
    }
}

/// Runs the vertex stage over one slice of an object's vertices.
///
/// `with_normals` is false for unlit objects, whose normals are never read.
#[allow(
    clippy::too_many_arguments,
    reason = "one output slice per vertex array"
)]
pub fn transform_vertices(
    t: &ObjectTransform,
    vp: &Viewport,
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    with_normals: bool,
    screen: &mut [ScreenPos],
    codes: &mut [u8],
    attrs: &mut [Attrs],
) {
    debug_assert_eq!(positions.len(), screen.len());
    debug_assert_eq!(positions.len(), codes.len());
    debug_assert_eq!(positions.len(), attrs.len());
    for i in 0..positions.len() {
        let (p, n) = t.eye(positions[i], normals[i], with_normals);
        let c = t.projection * p.extend(1.0);
        let o = vp.outcode(c);
        codes[i] = o;
        if o & outcode::CLIP == 0 {
            let (x, y, z, iw) = vp.project(c);
            screen[i] = ScreenPos { x, y };
            attrs[i] = Attrs::new(z, iw, p, n);
        } else {
            screen[i] = ScreenPos::default();
            attrs[i] = Attrs::default();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ndc_corners_map_to_image_corners_row_zero_on_top() {
        let vp = Viewport::new(64, 32);
        // NDC (-1, +1) is the top-left corner of the image.
        assert_eq!(vp.project(Vec4::new(-1.0, 1.0, 0.0, 1.0)), (0, 0, 0.5, 1.0));
        assert_eq!(
            vp.project(Vec4::new(1.0, -1.0, 1.0, 1.0)),
            (64 * ONE, 32 * ONE, 1.0, 1.0)
        );
        // The centre of pixel (0, 0) is at (0.5, 0.5) pixels.
        let (x, y, _, _) = vp.project(Vec4::new(-1.0 + 1.0 / 64.0, 1.0 - 1.0 / 32.0, 0.0, 1.0));
        assert_eq!((x, y), (HALF, HALF));
        // w divides.
        let (x, _, z, iw) = vp.project(Vec4::new(0.0, 0.0, -2.0, 2.0));
        assert_eq!((x, z, iw), (32 * ONE, 0.0, 0.5));
    }

    #[test]
    fn snapping_rounds_to_the_nearest_256th() {
        assert_eq!(snap(1.0), 256);
        assert_eq!(snap(1.0 + 1.0 / 512.0 + 1e-5), 257);
        assert_eq!(snap(1.0 + 1.0 / 512.0 - 1e-5), 256);
        assert_eq!(snap(-0.4 / 256.0), 0);
        assert_eq!(snap(-0.6 / 256.0), -1);
    }

    #[test]
    fn outcodes() {
        let vp = Viewport::new(100, 100);
        assert_eq!(vp.outcode(Vec4::new(0.0, 0.0, 0.0, 1.0)), 0);
        assert_eq!(vp.outcode(Vec4::new(-2.0, 0.0, 0.0, 1.0)), outcode::LEFT);
        assert_eq!(vp.outcode(Vec4::new(0.0, 0.0, -2.0, 1.0)), outcode::NEAR);
        // Behind the eye: w < 0 puts it outside near (z > -w fails) and the guard band.
        let behind = vp.outcode(Vec4::new(0.0, 0.0, 0.5, -0.5));
        assert!(behind & outcode::NEAR == 0 || behind & outcode::GUARD != 0);
        assert_ne!(behind & outcode::CLIP, 0);
        assert_ne!(
            vp.outcode(Vec4::new(1e6, 0.0, 0.0, 1.0)) & outcode::GUARD,
            0
        );
        assert_ne!(
            vp.outcode(Vec4::new(f32::NAN, 0.0, 0.0, 1.0)) & outcode::GUARD,
            0
        );
    }
}
