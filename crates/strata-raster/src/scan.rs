//! Scan conversion of one triangle into one strip: attributes, shading, push.
//!
//! Coverage is decided by [`crate::coverage`]; this module turns covered samples into fragments.
//! With `λ_a = E_bc / area` etc. (screen-space barycentrics, exact integers converted once):
//!
//! - depth `z = λ_a z_a + λ_b z_b + λ_c z_c` — window depth is affine in screen space. Samples with
//!   `z > 1` lie beyond the far plane and are discarded; rounding below 0 is clamped to `+0`.
//! - headlight: `n' = Σ λ_i (n_i / w_i)`, `p' = Σ λ_i (p_i / w_i)` are the perspective-correct
//!   normal and eye position up to the common factor `1 / Σ λ_i/w_i`, which cancels in
//!   `|N·L| = |n'·p'| / (|n'| |p'|)`.
//!
//! A micro-triangle's attributes are loaded only once it is known to cover something (a larger
//! triangle's are broadcast to the lanes before its spans are found). Small triangles are
//! shaded by [`shade_small`] (which the scan calls for small clipped pieces, and which setup's
//! lanes in [`crate::shade_lanes`] are tested against); larger ones are scanned span by span by
//! [`scan_triangle`], their samples shaded `L` at a time (16 or 8, [`crate::lanes`]) by
//! [`crate::shade_lanes::SpanShader`] with the same arithmetic (tested against one at a time).

use glam::Vec3A;
use strata_core::material::headlight_rgba;
use strata_core::{Fragment, ObjectId, PackedNormal, Rgba8};

use crate::coverage::{Edges, Micro, Setup, Triangle};
use crate::shade_lanes::SpanShader;
use crate::sink::FragmentSink;
use crate::vertex::{Attrs, ScreenPos};

/// Per-object shading constants.
#[derive(Clone, Copy, Debug)]
pub struct Shade {
    /// Object colour, RGB in `[0, 1]`.
    pub rgb: [f32; 3],
    /// Alpha, quantised.
    pub alpha: u8,
    /// The quantised colour, for unlit objects.
    pub flat: Rgba8,
    /// Object id.
    pub id: ObjectId,
    /// Emit the packed eye-space normal instead of the shaded colour
    /// ([`crate::FragmentOutput::PackedNormal`]); lit objects only — unlit ones carry
    /// [`PackedNormal::NONE`] in `flat`.
    pub packed: bool,
}

/// A triangle's interpolation constants.
struct Interp {
    inv_area: f32,
    z: [f32; 3],
    /// `n_k / w_k` and `p_k / w_k`: weighting these by screen-space barycentrics gives the
    /// perspective-correct normal and position up to a common positive factor.
    n: [Vec3A; 3],
    p: [Vec3A; 3],
}

impl Interp {
    #[inline(always)]
    fn new<const LIT: bool>(attrs: [&Attrs; 3], area: f32) -> Interp {
        let mut n = [Vec3A::ZERO; 3];
        let mut p = [Vec3A::ZERO; 3];
        if LIT {
            for k in 0..3 {
                n[k] = Vec3A::from(attrs[k].n_w);
                p[k] = Vec3A::from(attrs[k].p_w);
            }
        }
        Interp {
            inv_area: 1.0 / area,
            z: [attrs[0].z, attrs[1].z, attrs[2].z],
            n,
            p,
        }
    }

    /// The fragment at a sample with barycentric numerators `e`, or `None` beyond the far plane.
    #[inline(always)]
    fn fragment<const LIT: bool>(&self, e: [f32; 3], shade: &Shade) -> Option<Fragment> {
        let l = [
            e[0] * self.inv_area,
            e[1] * self.inv_area,
            e[2] * self.inv_area,
        ];
        let z = l[0] * self.z[0] + l[1] * self.z[1] + l[2] * self.z[2];
        if z > 1.0 || z.is_nan() {
            return None; // beyond the far plane
        }
        let depth = if z > 0.0 { z } else { 0.0 };
        let color = if LIT && shade.packed {
            let n = self.n[0] * l[0] + self.n[1] * l[1] + self.n[2] * l[2];
            Rgba8::from_bits(PackedNormal::pack(n.to_array()).to_bits())
        } else if LIT {
            let n = self.n[0] * l[0] + self.n[1] * l[1] + self.n[2] * l[2];
            let p = self.p[0] * l[0] + self.p[1] * l[1] + self.p[2] * l[2];
            headlight_rgba(shade.rgb, shade.alpha, headlight(n, p))
        } else {
            shade.flat
        };
        Some(Fragment {
            depth,
            color,
            object: shade.id,
        })
    }
}

/// [`strata_core::material::headlight_factor`] on SIMD vectors.
#[inline(always)]
fn headlight(n: Vec3A, p: Vec3A) -> f32 {
    let (nn, pp, np) = (n.dot(n), p.dot(p), n.dot(p));
    let denom = (nn * pp).sqrt();
    let cos = if denom > 0.0 {
        (np.abs() / denom).min(1.0)
    } else {
        0.0
    };
    0.25 + 0.75 * cos
}

/// Shades the covered samples of a micro-triangle — `mask` is its coverage within its bounding
/// box (see [`crate::coverage::Micro::coverage`]) — calling `out(row, pixel, fragment)` for each,
/// in sample order. Samples beyond the far plane are skipped.
#[inline(always)]
pub fn shade_small<const LIT: bool>(
    t: &Micro,
    attrs: [&Attrs; 3],
    mut mask: u32,
    width: i32,
    shade: &Shade,
    mut out: impl FnMut(i32, u32, Fragment),
) {
    if mask == 0 {
        return;
    }
    let order = t.order;
    let attrs = [attrs[order[0]], attrs[order[1]], attrs[order[2]]];
    let interp = Interp::new::<LIT>(attrs, t.area as f32);
    let (x0, y0) = (t.bounds[0], t.bounds[2]);
    let first = y0 as u32 * width as u32 + x0 as u32;
    while mask != 0 {
        let bit = mask.trailing_zeros() as i32;
        mask &= mask - 1;
        let (i, j) = t.offset(bit);
        if let Some(f) = interp.fragment::<LIT>(t.weights(i, j), shade) {
            out(y0 + j, first + j as u32 * width as u32 + i as u32, f);
        }
    }
}

/// Rasterises one triangle into the rows `rows.0 ..= rows.1` of a `width` × `height` image,
/// pushing each covered sample into `sink`. Returns the number of fragments pushed. A larger
/// triangle's samples are shaded `L` at a time in `lanes` (see [`SpanShader`]); a micro-sized
/// one (a clipped piece) one at a time.
#[inline(always)]
#[allow(
    clippy::too_many_arguments,
    reason = "the hot loop's inputs, kept as plain values"
)]
pub fn scan_triangle<S: FragmentSink, const LIT: bool, const L: usize>(
    pos: [ScreenPos; 3],
    attrs: [&Attrs; 3],
    rows: (i32, i32),
    width: i32,
    height: i32,
    shade: &Shade,
    lanes: &mut SpanShader<L>,
    sink: &mut S,
) -> u32 {
    let mut count = 0u32;
    let t = match Triangle::new(pos, width, height) {
        None => return 0,
        Some(Triangle::Micro(t)) => {
            let [_, _, by0, by1] = t.bounds;
            let (y0, y1) = (by0.max(rows.0), by1.min(rows.1));
            if y0 > y1 {
                return 0;
            }
            // Keep the samples in this strip's rows.
            shade_small::<LIT>(
                &t,
                attrs,
                t.rows(t.coverage(), y0 - by0, y1 - by0),
                width,
                shade,
                |_, pixel, f| {
                    sink.push(pixel, f);
                    count += 1;
                },
            );
            return count;
        }
        Some(Triangle::Large(t)) => t,
    };
    // Large box: each row's covered span exactly, its samples shaded in lanes.
    let attrs = [attrs[t.order[0]], attrs[t.order[1]], attrs[t.order[2]]];
    lanes.begin::<LIT>(attrs, t.area as f32);
    for_each_sample(&t, rows, width, |pixel, e| {
        count += lanes.add::<S, LIT>(pixel, e, shade, sink);
    });
    count + lanes.flush::<S, LIT>(shade, sink)
}

/// Calls `sample(pixel, E)` with the barycentric numerators `E` of every covered sample of the
/// large triangle `t` in the rows `rows.0 ..= rows.1`, in row-major order: each row's covered
/// span is computed exactly, then stepped through without tests.
#[inline(always)]
pub(crate) fn for_each_sample(
    t: &Setup,
    rows: (i32, i32),
    width: i32,
    mut sample: impl FnMut(u32, [f32; 3]),
) {
    let [x0, x1, by0, by1] = t.bounds;
    let (y0, y1) = (by0.max(rows.0), by1.min(rows.1));
    if y0 > y1 {
        return;
    }
    let edges = &t.edges;
    let last_x = x1 - x0;
    let mut row = edges.at(0, y0 - by0);
    let mut row_first = y0 as u32 * width as u32 + x0 as u32;
    for _ in y0..=y1 {
        if let Some((lo, hi)) = edges.span(row, last_x) {
            let mut e = Edges::step(row, edges.dx, i64::from(lo));
            for i in lo..=hi {
                sample(row_first + i as u32, edges.weights(e));
                e = Edges::step(e, edges.dx, 1);
            }
        }
        row = Edges::step(row, edges.dy, 1);
        row_first += width as u32;
    }
}

/// The larger triangle `t` shaded one sample at a time, in the rows `rows.0 ..= rows.1`,
/// through the scalar arithmetic micro-triangles are tested against: what [`scan_triangle`]'s
/// lanes must equal. `attrs` are its vertices in input order.
#[cfg(test)]
pub(crate) fn shade_large_one_at_a_time<S: FragmentSink, const LIT: bool>(
    t: &Setup,
    attrs: [&Attrs; 3],
    (rows, width): ((i32, i32), i32),
    shade: &Shade,
    sink: &mut S,
) -> u32 {
    let attrs = [attrs[t.order[0]], attrs[t.order[1]], attrs[t.order[2]]];
    let interp = Interp::new::<LIT>(attrs, t.area as f32);
    let mut count = 0;
    for_each_sample(t, rows, width, |pixel, e| {
        if let Some(f) = interp.fragment::<LIT>(e, shade) {
            sink.push(pixel, f);
            count += 1;
        }
    });
    count
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vertex::ONE;

    struct Collect(Vec<(u32, Fragment)>);
    impl FragmentSink for Collect {
        fn push(&mut self, pixel: u32, fragment: Fragment) {
            self.0.push((pixel, fragment));
        }
    }

    /// The fragments `scan_triangle` pushes for `tri` (uniform [`ATTRS`] and [`SHADE`]) in the
    /// rows `rows` of a `w` × `h` image.
    fn scan<const LIT: bool>(tri: [ScreenPos; 3], rows: (i32, i32), w: i32, h: i32) -> Collect {
        let mut sink = Collect(Vec::new());
        let lanes = &mut SpanShader::<8>::default();
        scan_triangle::<_, LIT, 8>(tri, [&ATTRS; 3], rows, w, h, &SHADE, lanes, &mut sink);
        sink
    }

    fn vtx(x: f32, y: f32) -> ScreenPos {
        ScreenPos {
            x: (x * ONE as f32) as i32,
            y: (y * ONE as f32) as i32,
        }
    }

    const ATTRS: Attrs = Attrs {
        z: 0.5,
        iw: 1.0,
        p_w: [0.0, 0.0, -1.0],
        n_w: [0.0, 0.0, 1.0],
    };

    const SHADE: Shade = Shade {
        rgb: [1.0, 0.0, 0.0],
        alpha: 128,
        flat: Rgba8([255, 0, 0, 128]),
        id: ObjectId(3),
        packed: false,
    };

    fn cover(tris: &[[ScreenPos; 3]], w: i32, h: i32) -> Vec<u32> {
        let mut counts = vec![0u32; (w * h) as usize];
        for t in tris {
            let sink = scan::<false>(*t, (0, h - 1), w, h);
            for (p, _) in sink.0 {
                counts[p as usize] += 1;
            }
        }
        counts
    }

    #[test]
    fn square_through_pixel_centres_follows_the_top_left_rule() {
        // A 4x4-pixel square whose edges pass exactly through pixel centres: x = 1.5 .. 5.5,
        // y = 1.5 .. 5.5. The left and top edges own their samples, the right and bottom don't.
        let (p0, p1, p2, p3) = (vtx(1.5, 1.5), vtx(5.5, 1.5), vtx(5.5, 5.5), vtx(1.5, 5.5));
        let counts = cover(&[[p0, p1, p2], [p0, p2, p3]], 8, 8);
        for y in 0..8 {
            for x in 0..8 {
                let expected = u32::from((1..=4).contains(&x) && (1..=4).contains(&y));
                assert_eq!(counts[y * 8 + x], expected, "pixel ({x}, {y})");
            }
        }
    }

    #[test]
    fn winding_does_not_matter() {
        let (a, b, c) = (vtx(0.2, 0.3), vtx(6.7, 1.1), vtx(2.9, 7.4));
        assert_eq!(cover(&[[a, b, c]], 8, 8), cover(&[[a, c, b]], 8, 8));
    }

    #[test]
    fn fan_around_a_pixel_centre_covers_it_exactly_once() {
        // Eight triangles meeting at the centre of pixel (4, 4), edges along axes and diagonals.
        let c = vtx(4.5, 4.5);
        let ring = [
            (1.5, 1.5),
            (4.5, 0.5),
            (7.5, 1.5),
            (7.5, 4.5),
            (7.5, 7.5),
            (4.5, 7.5),
            (1.5, 7.5),
            (1.5, 4.5),
        ];
        let tris: Vec<_> = (0..8)
            .map(|i| {
                let (x0, y0) = ring[i];
                let (x1, y1) = ring[(i + 1) % 8];
                [c, vtx(x0, y0), vtx(x1, y1)]
            })
            .collect();
        let counts = cover(&tris, 9, 9);
        assert_eq!(counts[4 * 9 + 4], 1);
        assert!(counts.iter().all(|&n| n <= 1), "{counts:?}");
    }

    #[test]
    fn span_and_per_pixel_paths_agree() {
        // The same long thin triangle scanned in full (span path, wide box) and as narrow slices
        // of rows; compare against a brute-force edge test.
        let (a, b, c) = (vtx(0.3, 0.2), vtx(30.9, 3.3), vtx(2.2, 9.6));
        let counts = cover(&[[a, b, c]], 32, 12);
        let e = |p: &ScreenPos, q: &ScreenPos, sx: i64, sy: i64| {
            i64::from(q.x - p.x) * (sy - i64::from(p.y))
                - i64::from(q.y - p.y) * (sx - i64::from(p.x))
        };
        for y in 0..12 {
            for x in 0..32 {
                let (sx, sy) = (i64::from(x) * 256 + 128, i64::from(y) * 256 + 128);
                let inside = [(&a, &b), (&b, &c), (&c, &a)]
                    .iter()
                    .all(|(p, q)| e(p, q, sx, sy) > 0);
                // No sample lies exactly on an edge here, so strict inside is the full answer.
                assert_eq!(
                    counts[(y * 32 + x) as usize],
                    u32::from(inside),
                    "({x}, {y})"
                );
            }
        }
    }

    #[test]
    fn rows_outside_the_strip_are_skipped() {
        let (a, b, c) = (vtx(0.0, 0.0), vtx(8.0, 0.0), vtx(0.0, 8.0));
        let sink = scan::<false>([a, b, c], (2, 3), 8, 8);
        assert!(sink.0.iter().all(|(p, _)| (16..32).contains(p)));
        assert_eq!(sink.0.len(), 5 + 4); // x + y < 8 at centres, hypotenuse (a right edge) excluded
    }

    #[test]
    fn simd_headlight_matches_the_reference_formula() {
        use strata_core::material::headlight_factor;
        let cases = [
            ([0.0, 0.0, 1.0], [0.0, 0.0, -2.0]),
            ([0.3, -0.4, 0.5], [0.1, -0.2, -1.0]),
            ([1.0, 0.0, 0.0], [0.0, 0.0, -2.0]),
            ([0.0; 3], [0.0, 0.0, -1.0]),
            ([1e-20, 2e-20, 0.0], [3.0, 4.0, -5.0]),
        ];
        for (n, p) in cases {
            let simd = headlight(Vec3A::from(n), Vec3A::from(p));
            let reference = headlight_factor(n, p);
            assert!(
                (simd - reference).abs() <= 1e-6,
                "{n:?} {p:?}: {simd} vs {reference}"
            );
        }
    }

    #[test]
    fn headlight_shades_facing_surfaces_fully() {
        let (a, b, c) = (vtx(0.0, 0.0), vtx(4.0, 0.0), vtx(0.0, 4.0));
        let sink = scan::<true>([a, b, c], (0, 3), 4, 4);
        assert!(!sink.0.is_empty());
        for (_, f) in sink.0 {
            assert_eq!(f.color, Rgba8([255, 0, 0, 128]));
            assert_eq!(f.object, ObjectId(3));
            assert_eq!(f.depth, 0.5);
        }
    }
}
