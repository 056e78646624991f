//! Scan conversion of one triangle into one strip: coverage, depth, shading, push.
//!
//! # Coverage
//!
//! For an edge `p → q` and a sample `s` (all in 24.8 fixed point) the edge function
//!
//! ```text
//! E(s) = (q.x − p.x)(s.y − p.y) − (q.y − p.y)(s.x − p.x)
//! ```
//!
//! is evaluated exactly in `i64`. Triangles are put in the orientation where the interior has all
//! three `E > 0` (swapping two vertices if needed: there is no culling). A sample exactly on an
//! edge belongs to the triangle only if the edge is a *top* edge (horizontal, interior below) or a
//! *left* edge (interior to the right) — with y pointing down and this orientation, that is
//! `dy < 0 || (dy == 0 && dx > 0)`. Such edges test `E ≥ 0`, the others `E ≥ 1`; two triangles
//! sharing an edge see it with opposite directions, so exactly one of them owns each sample on it.
//!
//! Pixel centres are at `(x + ½, y + ½)`. Per row, each edge's half-plane is intersected with the
//! bounding box by one integer division, giving the exact span of covered pixels; very narrow
//! bounding boxes (the common case for dense meshes) test each pixel instead. Edge values are kept
//! with the bias subtracted, so the test is a sign check of the three values OR-ed together.
//!
//! # Attributes
//!
//! With `λ_a = E_bc / area` etc. (screen-space barycentrics, exact integers converted once):
//!
//! - depth `z = λ_a z_a + λ_b z_b + λ_c z_c` — window depth is affine in screen space. Samples with
//!   `z > 1` lie beyond the far plane and are discarded; rounding below 0 is clamped to `+0`.
//! - headlight: `n' = Σ λ_i (1/w_i) n_i`, `p' = Σ λ_i (1/w_i) p_i` are the perspective-correct
//!   normal and eye position up to the common factor `1 / Σ λ_i/w_i`, which cancels in
//!   `|N·L| = |n'·p'| / (|n'| |p'|)`.

use glam::Vec3A;
use strata_core::fragment::unorm8;
use strata_core::material::headlight_factor;
use strata_core::{Fragment, ObjectId, Rgba8};

use crate::setup::{orient, pixel_bounds};
use crate::sink::FragmentSink;
use crate::vertex::{Attrs, HALF, ONE, ScreenPos};

/// Bounding boxes of at most `SMALL × SMALL` pixels are scanned as one coverage bitmask; larger
/// ones row by row with exact spans.
const SMALL: i32 = 4;

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
}

/// The three edge functions of a triangle, evaluated incrementally over its bounding box.
///
/// Edge `k` is opposite vertex `k`, so `E_k / area` is vertex `k`'s barycentric weight. Each
/// value is stored with its top-left bias already subtracted, so "inside" is `e ≥ 0` for all
/// three; [`Edges::weights`] adds the bias back for interpolation.
#[derive(Clone, Copy)]
struct Edges {
    /// Biased edge values at the current sample.
    e: [i64; 3],
    /// Change per pixel step in x.
    dx: [i64; 3],
    /// Change per pixel step in y.
    dy: [i64; 3],
    /// 0 for top and left edges, 1 otherwise.
    bias: [i64; 3],
}

impl Edges {
    /// Edges of the positively oriented triangle `abc`, evaluated at the centre of pixel `(x0, y0)`.
    #[inline(always)]
    fn new(a: ScreenPos, b: ScreenPos, c: ScreenPos, x0: i32, y0: i32) -> Edges {
        let sx = i64::from(x0) * i64::from(ONE) + i64::from(HALF);
        let sy = i64::from(y0) * i64::from(ONE) + i64::from(HALF);
        let edge = |p: ScreenPos, q: ScreenPos| {
            let ex = i64::from(q.x - p.x);
            let ey = i64::from(q.y - p.y);
            let bias = i64::from(!(ey < 0 || (ey == 0 && ex > 0)));
            (
                ex * (sy - i64::from(p.y)) - ey * (sx - i64::from(p.x)) - bias,
                -ey * i64::from(ONE),
                ex * i64::from(ONE),
                bias,
            )
        };
        let (e0, dx0, dy0, b0) = edge(b, c);
        let (e1, dx1, dy1, b1) = edge(c, a);
        let (e2, dx2, dy2, b2) = edge(a, b);
        Edges {
            e: [e0, e1, e2],
            dx: [dx0, dx1, dx2],
            dy: [dy0, dy1, dy2],
            bias: [b0, b1, b2],
        }
    }

    /// True if the sample with biased values `e` is covered.
    #[inline(always)]
    fn inside(e: [i64; 3]) -> bool {
        (e[0] | e[1] | e[2]) >= 0
    }

    /// Unbiased edge values (barycentric numerators) of the sample with biased values `e`.
    #[inline(always)]
    fn weights(&self, e: [i64; 3]) -> [i64; 3] {
        [
            e[0] + self.bias[0],
            e[1] + self.bias[1],
            e[2] + self.bias[2],
        ]
    }

    #[inline(always)]
    fn step(e: [i64; 3], d: [i64; 3], n: i64) -> [i64; 3] {
        [e[0] + d[0] * n, e[1] + d[1] * n, e[2] + d[2] * n]
    }

    /// Biased values at pixel offset `(i, j)` from the box's first pixel.
    #[inline(always)]
    fn at(&self, i: i32, j: i32) -> [i64; 3] {
        Self::step(
            Self::step(self.e, self.dx, i64::from(i)),
            self.dy,
            i64::from(j),
        )
    }

    /// Coverage of a box of `(last_x + 1) × (last_y + 1)` ≤ `SMALL × SMALL` pixels as a bitmask,
    /// bit `j * SMALL + i` for pixel offset `(i, j)`.
    #[inline(always)]
    fn coverage(&self, last_x: i32, last_y: i32) -> u32 {
        let mut mask = 0u32;
        let mut row = self.e;
        for j in 0..=last_y {
            let mut e = row;
            for i in 0..=last_x {
                mask |= u32::from(Self::inside(e)) << (j * SMALL + i);
                e = Self::step(e, self.dx, 1);
            }
            row = Self::step(row, self.dy, 1);
        }
        mask
    }
}

/// A triangle's interpolation constants, built at its first covered pixel (most triangles of a
/// dense mesh cover none, and never load their attributes).
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
    fn new<const LIT: bool>(attrs: [&Attrs; 3], area: i64) -> Interp {
        let mut n = [Vec3A::ZERO; 3];
        let mut p = [Vec3A::ZERO; 3];
        if LIT {
            for k in 0..3 {
                n[k] = Vec3A::from(attrs[k].n) * attrs[k].iw;
                p[k] = Vec3A::from(attrs[k].p) * attrs[k].iw;
            }
        }
        Interp {
            inv_area: 1.0 / area as f32,
            z: [attrs[0].z, attrs[1].z, attrs[2].z],
            n,
            p,
        }
    }

    /// The fragment at a sample with edge values `e`, or `None` beyond the far plane.
    #[inline(always)]
    fn fragment<const LIT: bool>(&self, e: [i64; 3], shade: &Shade) -> Option<Fragment> {
        let l = [
            e[0] as f32 * self.inv_area,
            e[1] as f32 * self.inv_area,
            e[2] as f32 * self.inv_area,
        ];
        let z = l[0] * self.z[0] + l[1] * self.z[1] + l[2] * self.z[2];
        if z > 1.0 || z.is_nan() {
            return None; // beyond the far plane
        }
        let depth = if z > 0.0 { z } else { 0.0 };
        let color = if LIT {
            let n = self.n[0] * l[0] + self.n[1] * l[1] + self.n[2] * l[2];
            let p = self.p[0] * l[0] + self.p[1] * l[1] + self.p[2] * l[2];
            let f = headlight_factor(n.to_array(), p.to_array());
            Rgba8([
                unorm8(shade.rgb[0] * f),
                unorm8(shade.rgb[1] * f),
                unorm8(shade.rgb[2] * f),
                shade.alpha,
            ])
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

/// Rasterises one triangle into the rows `rows.0 ..= rows.1` of a `width` × `height` image,
/// pushing each covered sample into `sink`. Returns the number of fragments pushed.
#[inline(always)]
pub fn scan_triangle<S: FragmentSink, const LIT: bool>(
    pos: [ScreenPos; 3],
    attrs: [&Attrs; 3],
    rows: (i32, i32),
    width: i32,
    height: i32,
    shade: &Shade,
    sink: &mut S,
) -> u32 {
    let [a, mut b, mut c] = pos;
    let [aa, mut ab, mut ac] = attrs;
    let mut area = orient(a, b, c);
    if area == 0 {
        return 0;
    }
    if area < 0 {
        std::mem::swap(&mut b, &mut c);
        std::mem::swap(&mut ab, &mut ac);
        area = -area;
    }
    let Some([x0, x1, by0, by1]) = pixel_bounds(a, b, c, width, height) else {
        return 0;
    };
    let (y0, y1) = (by0.max(rows.0), by1.min(rows.1));
    if y0 > y1 {
        return 0;
    }
    let edges = Edges::new(a, b, c, x0, y0);
    let (last_x, last_y) = (x1 - x0, y1 - y0);
    let first = y0 as u32 * width as u32 + x0 as u32;
    let mut count = 0u32;

    if last_x < SMALL && last_y < SMALL {
        // Small box (most triangles of a dense mesh): coverage first, attributes only if needed.
        let mut mask = edges.coverage(last_x, last_y);
        if mask == 0 {
            return 0;
        }
        let interp = Interp::new::<LIT>([aa, ab, ac], area);
        while mask != 0 {
            let bit = mask.trailing_zeros() as i32;
            mask &= mask - 1;
            let (i, j) = (bit % SMALL, bit / SMALL);
            let pixel = first + j as u32 * width as u32 + i as u32;
            count += emit::<S, LIT>(&interp, &edges, edges.at(i, j), pixel, shade, sink);
        }
        return count;
    }

    // Large box: compute each row's covered span exactly, then emit without tests.
    let interp = Interp::new::<LIT>([aa, ab, ac], area);
    let mut row = edges.e;
    let mut row_first = first;
    for _ in 0..=last_y {
        if let Some((lo, hi)) = span(row, edges.dx, last_x) {
            let mut e = Edges::step(row, edges.dx, i64::from(lo));
            for i in lo..=hi {
                count += emit::<S, LIT>(&interp, &edges, e, row_first + i as u32, shade, sink);
                e = Edges::step(e, edges.dx, 1);
            }
        }
        row = Edges::step(row, edges.dy, 1);
        row_first += width as u32;
    }
    count
}

/// Shades the covered sample with biased edge values `e` and pushes it; 1 if pushed, 0 if the
/// sample lies beyond the far plane.
#[inline(always)]
fn emit<S: FragmentSink, const LIT: bool>(
    interp: &Interp,
    edges: &Edges,
    e: [i64; 3],
    pixel: u32,
    shade: &Shade,
    sink: &mut S,
) -> u32 {
    match interp.fragment::<LIT>(edges.weights(e), shade) {
        Some(f) => {
            sink.push(pixel, f);
            1
        }
        None => 0,
    }
}

/// The covered pixel offsets `lo..=hi` (relative to the box's first column, within `0..=last`) of
/// a row whose biased edge values at the first column are `row`: the `i` with
/// `row[k] + dx[k]·i ≥ 0` for every edge.
#[inline(always)]
fn span(row: [i64; 3], dx: [i64; 3], last: i32) -> Option<(i32, i32)> {
    let (mut lo, mut hi) = (0i64, i64::from(last));
    for k in 0..3 {
        let (e, s) = (row[k], dx[k]);
        if s > 0 {
            if e < 0 {
                lo = lo.max((-e + s - 1) / s);
            }
        } else if s < 0 {
            if e < 0 {
                return None;
            }
            hi = hi.min(e / -s);
        } else if e < 0 {
            return None;
        }
    }
    (lo <= hi).then_some((lo as i32, hi as i32))
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Collect(Vec<(u32, Fragment)>);
    impl FragmentSink for Collect {
        fn push(&mut self, pixel: u32, fragment: Fragment) {
            self.0.push((pixel, fragment));
        }
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
        p: [0.0, 0.0, -1.0],
        n: [0.0, 0.0, 1.0],
    };

    const SHADE: Shade = Shade {
        rgb: [1.0, 0.0, 0.0],
        alpha: 128,
        flat: Rgba8([255, 0, 0, 128]),
        id: ObjectId(3),
    };

    fn cover(tris: &[[ScreenPos; 3]], w: i32, h: i32) -> Vec<u32> {
        let mut counts = vec![0u32; (w * h) as usize];
        for t in tris {
            let mut sink = Collect(Vec::new());
            scan_triangle::<_, false>(*t, [&ATTRS; 3], (0, h - 1), w, h, &SHADE, &mut sink);
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
        let mut sink = Collect(Vec::new());
        scan_triangle::<_, false>([a, b, c], [&ATTRS; 3], (2, 3), 8, 8, &SHADE, &mut sink);
        assert!(sink.0.iter().all(|(p, _)| (16..32).contains(p)));
        assert_eq!(sink.0.len(), 5 + 4); // x + y < 8 at centres, hypotenuse (a right edge) excluded
    }

    #[test]
    fn headlight_shades_facing_surfaces_fully() {
        let (a, b, c) = (vtx(0.0, 0.0), vtx(4.0, 0.0), vtx(0.0, 4.0));
        let mut sink = Collect(Vec::new());
        scan_triangle::<_, true>([a, b, c], [&ATTRS; 3], (0, 3), 4, 4, &SHADE, &mut sink);
        assert!(!sink.0.is_empty());
        for (_, f) in sink.0 {
            assert_eq!(f.color, Rgba8([255, 0, 0, 128]));
            assert_eq!(f.object, ObjectId(3));
            assert_eq!(f.depth, 0.5);
        }
    }
}
