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

/// The widest and tallest image the rasterizer takes: a vertex inside the guard band then lies
/// less than 2^18 pixels from the image, and its fixed-point window coordinates (and those of
/// every sample) stay far inside `i32`.
pub const MAX_SIDE: u32 = 1 << 17;

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
#[inline(always)]
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
///
/// Vertices go through [`VERTEX_LANES`] at a time in SIMD lanes (structure of arrays). Every
/// lane performs, operation for operation, what [`transform_vertex`] (glam's matrix products,
/// then [`Viewport::outcode`] and [`Viewport::project`]) performs for one vertex, with no fused
/// multiply-adds, so both give the same bits (tested below). The lane loops are compiled once per
/// instruction set and chosen at run time ([`pulp::Arch::dispatch`]), so on AVX2 a lane array is
/// one register; IEEE arithmetic gives the same bits on every set.
///
/// # Panics
/// If the slices differ in length.
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
    assert_eq!(positions.len(), normals.len(), "one normal per position");
    assert_eq!(positions.len(), screen.len());
    assert_eq!(positions.len(), codes.len());
    assert_eq!(positions.len(), attrs.len());
    pulp::Arch::new().dispatch(VertexJob {
        t,
        vp,
        positions,
        normals,
        with_normals,
        screen,
        codes,
        attrs,
    });
}

/// [`transform_vertices`]' arguments, for [`pulp::Arch::dispatch`].
struct VertexJob<'a> {
    t: &'a ObjectTransform,
    vp: &'a Viewport,
    positions: &'a [[f32; 3]],
    normals: &'a [[f32; 3]],
    with_normals: bool,
    screen: &'a mut [ScreenPos],
    codes: &'a mut [u8],
    attrs: &'a mut [Attrs],
}

impl pulp::WithSimd for VertexJob<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        const L: usize = VERTEX_LANES;
        let (t, vp, with_normals) = (self.t, self.vp, self.with_normals);
        let (pos, pos_tail) = self.positions.as_chunks::<L>();
        let (nor, nor_tail) = self.normals.as_chunks::<L>();
        let (scr, scr_tail) = self.screen.as_chunks_mut::<L>();
        let (cod, cod_tail) = self.codes.as_chunks_mut::<L>();
        let (att, att_tail) = self.attrs.as_chunks_mut::<L>();
        for b in 0..pos.len() {
            transform_block(
                t,
                vp,
                &pos[b],
                &nor[b],
                with_normals,
                &mut scr[b],
                &mut cod[b],
                &mut att[b],
            );
        }
        // The last partial block, padded with zeros.
        let count = pos_tail.len();
        if count > 0 {
            let (mut p, mut n) = ([[0.0f32; 3]; L], [[0.0f32; 3]; L]);
            p[..count].copy_from_slice(pos_tail);
            n[..count].copy_from_slice(nor_tail);
            let mut s = [ScreenPos::default(); L];
            let mut c = [0u8; L];
            let mut a = [Attrs::default(); L];
            transform_block(t, vp, &p, &n, with_normals, &mut s, &mut c, &mut a);
            scr_tail.copy_from_slice(&s[..count]);
            cod_tail.copy_from_slice(&c[..count]);
            att_tail.copy_from_slice(&a[..count]);
        }
    }
}

/// One vertex through the vertex stage, as glam computes it: the definition the lanes of
/// [`transform_vertices`] follow (the clipper projects its own vertices with the same
/// [`ObjectTransform::eye`] and [`Viewport::project`]).
#[inline]
pub fn transform_vertex(
    t: &ObjectTransform,
    vp: &Viewport,
    position: [f32; 3],
    normal: [f32; 3],
    with_normals: bool,
) -> (ScreenPos, u8, Attrs) {
    let (p, n) = t.eye(position, normal, with_normals);
    let c = t.projection * p.extend(1.0);
    let o = vp.outcode(c);
    if o & outcode::CLIP == 0 {
        let (x, y, z, iw) = vp.project(c);
        (ScreenPos { x, y }, o, Attrs::new(z, iw, p, n))
    } else {
        (ScreenPos::default(), o, Attrs::default())
    }
}

/// Vertices transformed together in lane arrays by [`transform_vertices`].
pub const VERTEX_LANES: usize = 8;

/// [`VERTEX_LANES`] vertices at once; see [`transform_vertices`].
///
/// Lane arrays (`[f32; VERTEX_LANES]`) and loops of one kind of work each, which LLVM
/// vectorises under the caller's instruction set; each sum in the order glam adds:
/// `((a·x + b·y) + c·z) + d`.
#[inline(always)]
#[allow(
    clippy::needless_range_loop,
    reason = "lane loops index several lane arrays by one lane"
)]
#[allow(
    clippy::too_many_arguments,
    reason = "one output block per vertex array"
)]
fn transform_block(
    t: &ObjectTransform,
    vp: &Viewport,
    positions: &[[f32; 3]; VERTEX_LANES],
    normals: &[[f32; 3]; VERTEX_LANES],
    with_normals: bool,
    screen: &mut [ScreenPos; VERTEX_LANES],
    codes: &mut [u8; VERTEX_LANES],
    attrs: &mut [Attrs; VERTEX_LANES],
) {
    const L: usize = VERTEX_LANES;
    type Lanes = [f32; L];
    // Plain loops and explicit lanes throughout: `array::map` and `from_fn` here were left
    // outlined by LLVM, a call per use.
    let mut pin = [[0.0f32; L]; 3];
    let mut nin = [[0.0f32; L]; 3];
    for l in 0..L {
        for k in 0..3 {
            pin[k][l] = positions[l][k];
            nin[k][l] = normals[l][k];
        }
    }
    // `a·x + b·y + c·z` with the column entries `m[0..3][k]`.
    #[inline(always)]
    fn combine(m: &[[f32; 4]; 4], k: usize, v: &[Lanes; 3]) -> Lanes {
        let mut out = [0.0; L];
        for l in 0..L {
            out[l] = m[0][k] * v[0][l] + m[1][k] * v[1][l] + m[2][k] * v[2][l];
        }
        out
    }
    // Eye space: `Mat4::transform_point3` and `Mat3 * Vec3`.
    let mv = t.model_view.to_cols_array_2d();
    let nm = t.normal.to_cols_array_2d();
    let nm = [
        [nm[0][0], nm[0][1], nm[0][2], 0.0],
        [nm[1][0], nm[1][1], nm[1][2], 0.0],
        [nm[2][0], nm[2][1], nm[2][2], 0.0],
        [0.0; 4],
    ];
    let mut p = [[0.0f32; L]; 3];
    let mut n = [[0.0f32; L]; 3];
    for k in 0..3 {
        let e = combine(&mv, k, &pin);
        for l in 0..L {
            p[k][l] = e[l] + mv[3][k];
        }
        if with_normals {
            n[k] = combine(&nm, k, &nin);
        }
    }
    // Clip space: `Mat4 * Vec4` with w = 1.
    let pr = t.projection.to_cols_array_2d();
    let mut c = [[0.0f32; L]; 4];
    for k in 0..4 {
        let e = combine(&pr, k, &p);
        for l in 0..L {
            c[k][l] = e[l] + pr[3][k] * 1.0;
        }
    }
    let [cx, cy, cz, cw] = c;
    // `Viewport::outcode`, lane by lane in 32-bit lanes (NaN fails every comparison: outside
    // the guard band).
    let mut code = [0u32; L];
    for l in 0..L {
        let (x, y, z, w) = (cx[l], cy[l], cz[l], cw[l]);
        let inside = (x.abs() <= vp.guard[0] * w) & (y.abs() <= vp.guard[1] * w);
        let bit = |outside: bool, plane: u8| u32::from(outside) * u32::from(plane);
        code[l] = bit(x < -w, outcode::LEFT)
            | bit(x > w, outcode::RIGHT)
            | bit(y < -w, outcode::BOTTOM)
            | bit(y > w, outcode::TOP)
            | bit(z < -w, outcode::NEAR)
            | bit(z > w, outcode::FAR)
            | bit(!inside, outcode::GUARD);
    }
    // `Viewport::project`, kept where the outcode has no clip bit (zeros elsewhere).
    let mut out = [[0.0f32; L]; 8];
    let mut fixed = [[0i32; L]; 2];
    for l in 0..L {
        let keep = code[l] & u32::from(outcode::CLIP) == 0;
        let iw = 1.0 / cw[l];
        let (xn, yn, zn) = (cx[l] * iw, cy[l] * iw, cz[l] * iw);
        let x = snap_in_guard((xn * 0.5 + 0.5) * vp.w);
        let y = snap_in_guard((0.5 - yn * 0.5) * vp.h);
        fixed[0][l] = if keep { x } else { 0 };
        fixed[1][l] = if keep { y } else { 0 };
        let values = [
            zn * 0.5 + 0.5,
            iw,
            p[0][l] * iw,
            p[1][l] * iw,
            p[2][l] * iw,
            n[0][l] * iw,
            n[1][l] * iw,
            n[2][l] * iw,
        ];
        for (o, v) in out.iter_mut().zip(values) {
            o[l] = if keep { v } else { 0.0 };
        }
    }
    for l in 0..L {
        screen[l] = ScreenPos {
            x: fixed[0][l],
            y: fixed[1][l],
        };
        codes[l] = code[l] as u8;
        attrs[l] = Attrs {
            z: out[0][l],
            iw: out[1][l],
            p_w: [out[2][l], out[3][l], out[4][l]],
            n_w: [out[5][l], out[6][l], out[7][l]],
        };
    }
}

/// [`snap`] for a window coordinate of a vertex inside the guard band, in a form LLVM
/// vectorises: the same `f64` rounding, read from the sum's low mantissa bits instead of through
/// Rust's saturating float-to-integer cast (converted a lane at a time). Equal to [`snap`]
/// wherever `|window| · 256 < 2^31`; every vertex inside the guard band is, since
/// [`crate::Rasterizer::prepare`] bounds the image's sides (tested).
#[inline(always)]
fn snap_in_guard(window: f32) -> i32 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 * 2^52
    let v = f64::from(window) * f64::from(ONE);
    (v + MAGIC).to_bits() as i32
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
    fn snapping_from_the_sum_bits_equals_snapping_through_the_cast() {
        let limit = MAX_SIDE as f32 + GUARD_PIXELS;
        let mut values = vec![
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            1e-40,
            -1e-40,
            limit,
            -limit,
            (2_147_483_520.0 / 256.0f32).next_down(),
            -2_147_483_648.0 / 256.0,
        ];
        // Ties, m + 1/2 in units of 1/256 pixel, across the guard band, and their neighbours
        // one ulp away.
        for m in (-21_000_000i32..21_000_000).step_by(97) {
            let tie = (2 * m + 1) as f32 / 512.0;
            values.extend([tie, tie.next_up(), tie.next_down()]);
        }
        // Every 65,537th f32 whose fixed-point value fits in i32.
        for bits in (0..=u32::MAX).step_by(65_537) {
            let v = f32::from_bits(bits);
            if (v * 256.0).abs() < 2_147_483_648.0 {
                values.push(v);
            }
        }
        let mut tested = 0;
        for v in values {
            assert_eq!(snap_in_guard(v), snap(v), "{v:e}");
            tested += 1;
        }
        assert!(tested > 1_000_000, "{tested}");
        // The widest window coordinate a vertex inside the guard band can have still fits.
        assert!(f64::from(limit) * f64::from(ONE) < 2_147_483_648.0);
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

    /// Bits of everything the vertex stage writes, for exact comparison (NaN included).
    fn bits(s: ScreenPos, o: u8, a: Attrs) -> (i32, i32, u8, [u32; 8]) {
        let f = [
            a.z, a.iw, a.p_w[0], a.p_w[1], a.p_w[2], a.n_w[0], a.n_w[1], a.n_w[2],
        ];
        (s.x, s.y, o, f.map(f32::to_bits))
    }

    #[test]
    fn lanes_give_the_bits_of_one_vertex_at_a_time() {
        use glam::Vec3;
        // A small xorshift, so the test needs no dependency and is the same on every run.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let vp = Viewport::new(1280, 720);
        for case in 0..24 {
            let eye = Vec3::new(next() - 0.5, next() - 0.5, 1.0 + 4.0 * next());
            let view = Mat4::look_at_rh(eye, Vec3::ZERO, Vec3::Y);
            let model = Mat4::from_scale_rotation_translation(
                Vec3::new(0.5 + next(), 0.5 + next(), 0.5 + next()),
                glam::Quat::from_rotation_y(6.0 * next()),
                Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5),
            );
            let projection = Mat4::perspective_rh_gl(0.3 + next(), 16.0 / 9.0, 0.1, 20.0);
            let t = ObjectTransform::new(view, model, projection);
            // Odd lengths leave a partial block; the spread puts vertices behind the eye, across
            // the near plane and far outside the guard band.
            let n = 1 + case * 7;
            let spread = [1.0, 4.0, 1e4, 1e7][case % 4];
            let mut positions: Vec<[f32; 3]> = (0..n)
                .map(|_| [0; 3].map(|_| spread * (next() - 0.5)))
                .collect();
            let normals: Vec<[f32; 3]> = (0..n).map(|_| [0; 3].map(|_| next() - 0.5)).collect();
            if case == 5 {
                positions[0] = [f32::NAN, 0.0, 0.0];
                positions[3] = [f32::INFINITY, 1.0, 0.0];
                positions[4] = eye.to_array();
            }
            for with_normals in [false, true] {
                let mut screen = vec![ScreenPos { x: 7, y: 7 }; n];
                let mut codes = vec![0xff; n];
                let mut attrs = vec![Attrs::new(9.0, 9.0, Vec3::ONE, Vec3::ONE); n];
                transform_vertices(
                    &t,
                    &vp,
                    &positions,
                    &normals,
                    with_normals,
                    &mut screen,
                    &mut codes,
                    &mut attrs,
                );
                for i in 0..n {
                    let (s, o, a) =
                        transform_vertex(&t, &vp, positions[i], normals[i], with_normals);
                    assert_eq!(
                        bits(screen[i], codes[i], attrs[i]),
                        bits(s, o, a),
                        "case {case}, vertex {i} {:?}, normals {with_normals}",
                        positions[i]
                    );
                }
            }
        }
    }
}
