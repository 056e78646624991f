//! Coverage: which pixel centres a triangle covers, exactly, with the top-left rule.
//!
//! For an edge `p → q` and a sample `s` (all in 24.8 fixed point) the edge function
//!
//! ```text
//! E(s) = (q.x − p.x)(s.y − p.y) − (q.y − p.y)(s.x − p.x)
//! ```
//!
//! is evaluated exactly in `i64`. A triangle is put in the orientation where the interior has all
//! three `E > 0` (swapping two vertices if needed: there is no culling). A sample exactly on an
//! edge belongs to the triangle only if the edge is a *top* edge (horizontal, interior below) or a
//! *left* edge (interior to the right) — with y pointing down and this orientation, that is
//! `dy < 0 || (dy == 0 && dx > 0)`. Such edges test `E ≥ 0`, the others `E ≥ 1`; two triangles
//! sharing an edge see it with opposite directions, so exactly one of them owns each sample on it.
//! Edge values are kept with that bias subtracted, so "covered" is a sign test of the three values
//! OR-ed together.
//!
//! Pixel centres are at `(x + ½, y + ½)`. Triangles whose bounding box spans at most
//! [`SMALL`] × [`SMALL`] pixel centres (most triangles of a dense mesh) get their coverage as one
//! bitmask, computed once in setup; larger ones are scanned row by row, each row's covered span
//! found exactly with one integer division per edge.

use wide::i32x4;

use crate::vertex::{HALF, ONE, SUBPIXEL_BITS, ScreenPos};

/// Bounding boxes of at most `SMALL × SMALL` pixel centres are covered by a bitmask.
pub const SMALL: i32 = 4;

/// Twice the signed area of `abc` in fixed point (y down: positive for clockwise on screen).
#[inline(always)]
pub fn orient(a: ScreenPos, b: ScreenPos, c: ScreenPos) -> i64 {
    i64::from(b.x - a.x) * i64::from(c.y - a.y) - i64::from(c.x - a.x) * i64::from(b.y - a.y)
}

/// The pixels whose centres the triangle's bounding box contains, clamped to the image:
/// `[x0, x1, y0, y1]` inclusive, or `None` if there are none.
#[inline(always)]
pub fn pixel_bounds(
    a: ScreenPos,
    b: ScreenPos,
    c: ScreenPos,
    width: i32,
    height: i32,
) -> Option<[i32; 4]> {
    let min_x = a.x.min(b.x).min(c.x);
    let max_x = a.x.max(b.x).max(c.x);
    let min_y = a.y.min(b.y).min(c.y);
    let max_y = a.y.max(b.y).max(c.y);
    // First centre at or after the minimum (ceil), last at or before the maximum (floor);
    // arithmetic shifts floor for negative values too.
    let x0 = ((min_x - HALF + ONE - 1) >> SUBPIXEL_BITS).max(0);
    let x1 = ((max_x - HALF) >> SUBPIXEL_BITS).min(width - 1);
    let y0 = ((min_y - HALF + ONE - 1) >> SUBPIXEL_BITS).max(0);
    let y1 = ((max_y - HALF) >> SUBPIXEL_BITS).min(height - 1);
    (x0 <= x1 && y0 <= y1).then_some([x0, x1, y0, y1])
}

/// The three edge functions of a positively oriented triangle, evaluated incrementally.
///
/// Edge `k` is opposite vertex `k`, so `E_k / area` is vertex `k`'s barycentric weight. Values
/// are stored with the top-left bias subtracted; [`Edges::weights`] adds it back.
#[derive(Clone, Copy, Debug)]
pub struct Edges {
    /// Biased edge values at the centre of the first pixel of the bounding box.
    pub e: [i64; 3],
    /// Change per pixel step in x.
    pub dx: [i64; 3],
    /// Change per pixel step in y.
    pub dy: [i64; 3],
    /// 0 for top and left edges, 1 otherwise.
    pub bias: [i64; 3],
}

impl Edges {
    /// Edges of the positively oriented triangle `abc`, evaluated at the centre of pixel `(x0, y0)`.
    #[inline(always)]
    pub fn new(a: ScreenPos, b: ScreenPos, c: ScreenPos, x0: i32, y0: i32) -> Edges {
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
    pub fn inside(e: [i64; 3]) -> bool {
        (e[0] | e[1] | e[2]) >= 0
    }

    /// Barycentric numerators `E_k` of the sample with biased values `e`.
    #[inline(always)]
    pub fn weights(&self, e: [i64; 3]) -> [f32; 3] {
        std::array::from_fn(|k| (e[k] + self.bias[k]) as f32)
    }

    /// `e + d·n` per edge.
    #[inline(always)]
    pub fn step(e: [i64; 3], d: [i64; 3], n: i64) -> [i64; 3] {
        [e[0] + d[0] * n, e[1] + d[1] * n, e[2] + d[2] * n]
    }

    /// Biased values at pixel offset `(i, j)` from the first pixel.
    #[inline(always)]
    pub fn at(&self, i: i32, j: i32) -> [i64; 3] {
        Self::step(
            Self::step(self.e, self.dx, i64::from(i)),
            self.dy,
            i64::from(j),
        )
    }

    /// The covered pixel offsets `lo..=hi` (relative to the first column, within `0..=last`) of a
    /// row whose biased edge values at the first column are `row`: the `i` with
    /// `row[k] + dx[k]·i ≥ 0` for every edge.
    #[inline(always)]
    pub fn span(&self, row: [i64; 3], last: i32) -> Option<(i32, i32)> {
        let (mut lo, mut hi) = (0i64, i64::from(last));
        for (&e, &s) in row.iter().zip(&self.dx) {
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
}

/// A large triangle ready to scan: positively oriented, bounded, with its `i64` edge functions.
#[derive(Clone, Copy, Debug)]
pub struct Setup {
    /// Which input vertex is vertex 0, 1, 2 after orientation (`[0, 1, 2]` or `[0, 2, 1]`).
    pub order: [usize; 3],
    /// Twice the area, > 0.
    pub area: i64,
    /// Pixel bounds `[x0, x1, y0, y1]`, inclusive.
    pub bounds: [i32; 4],
    /// Edge functions at the centre of pixel `(x0, y0)`.
    pub edges: Edges,
}

impl Setup {
    /// Orients and bounds a triangle; `None` if it has zero area or no pixel centre in its box.
    #[inline(always)]
    pub fn new(pos: [ScreenPos; 3], width: i32, height: i32) -> Option<Setup> {
        let [a, b, c] = pos;
        let area = orient(a, b, c);
        if area == 0 {
            return None;
        }
        let bounds = pixel_bounds(a, b, c, width, height)?;
        let (order, b, c, area) = if area > 0 {
            ([0, 1, 2], b, c, area)
        } else {
            ([0, 2, 1], c, b, -area)
        };
        Some(Setup {
            order,
            area,
            bounds,
            edges: Edges::new(a, b, c, bounds[0], bounds[2]),
        })
    }
}

/// What setup makes of a triangle.
#[derive(Clone, Copy, Debug)]
pub enum Triangle {
    /// Bounding box of at most [`SMALL`] × [`SMALL`] pixel centres.
    Micro(Micro),
    /// Anything larger.
    Large(Setup),
}

impl Triangle {
    /// Orients, bounds and sets up a triangle; `None` if it has zero area or no pixel centre in
    /// its box.
    #[inline(always)]
    pub fn new(pos: [ScreenPos; 3], width: i32, height: i32) -> Option<Triangle> {
        let [a, b, c] = pos;
        let bounds = pixel_bounds(a, b, c, width, height)?;
        let [x0, x1, y0, y1] = bounds;
        if x1 - x0 < SMALL && y1 - y0 < SMALL {
            Micro::new(pos, bounds).map(Triangle::Micro)
        } else {
            Setup::new(pos, width, height).map(Triangle::Large)
        }
    }
}

/// A micro-triangle set up in `i32`: its vertices lie within 5 pixels of each other and of every
/// sample of its 4 × 4 block, so twice its area stays below 2^21 and every edge value below 2^23.
#[derive(Clone, Copy, Debug)]
pub struct Micro {
    /// Which input vertex is vertex 0, 1, 2 after orientation.
    pub order: [usize; 3],
    /// Twice the area, > 0.
    pub area: i32,
    /// Pixel bounds `[x0, x1, y0, y1]`, inclusive.
    pub bounds: [i32; 4],
    /// Biased edge values at the centre of pixel `(x0, y0)`.
    e: [i32; 3],
    dx: [i32; 3],
    dy: [i32; 3],
    bias: [i32; 3],
}

impl Micro {
    #[inline(always)]
    fn new(pos: [ScreenPos; 3], bounds: [i32; 4]) -> Option<Micro> {
        let [a, b, c] = pos;
        let area = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if area == 0 {
            return None;
        }
        let (order, b, c, area) = if area > 0 {
            ([0, 1, 2], b, c, area)
        } else {
            ([0, 2, 1], c, b, -area)
        };
        let sx = bounds[0] * ONE + HALF;
        let sy = bounds[2] * ONE + HALF;
        let edge = |p: ScreenPos, q: ScreenPos| {
            let (ex, ey) = (q.x - p.x, q.y - p.y);
            let bias = i32::from(!(ey < 0 || (ey == 0 && ex > 0)));
            (
                ex * (sy - p.y) - ey * (sx - p.x) - bias,
                -ey * ONE,
                ex * ONE,
                bias,
            )
        };
        let (e0, dx0, dy0, b0) = edge(b, c);
        let (e1, dx1, dy1, b1) = edge(c, a);
        let (e2, dx2, dy2, b2) = edge(a, b);
        Some(Micro {
            order,
            area,
            bounds,
            e: [e0, e1, e2],
            dx: [dx0, dx1, dx2],
            dy: [dy0, dy1, dy2],
            bias: [b0, b1, b2],
        })
    }

    /// The coverage bitmask, bit `j * SMALL + i` for pixel offset `(i, j)`.
    ///
    /// All 16 samples of the 4 × 4 block are evaluated branch-free, a row of four at a time in
    /// `i32x4` lanes (SSE2 through the `wide` crate), then masked to the bounding box.
    #[inline(always)]
    pub fn coverage(&self) -> u32 {
        let lanes = |k: usize| {
            let (e, d) = (self.e[k], self.dx[k]);
            i32x4::new([e, e + d, e + 2 * d, e + 3 * d])
        };
        let mut rows = [lanes(0), lanes(1), lanes(2)];
        let steps = self.dy.map(i32x4::splat);
        let mut outside = 0u32;
        for j in 0..4 {
            // A sample is outside if any biased edge value is negative: OR the sign bits.
            outside |= ((rows[0] | rows[1] | rows[2]).to_bitmask() & 0xf) << (4 * j);
            for k in 0..3 {
                rows[k] += steps[k];
            }
        }
        let [x0, x1, y0, y1] = self.bounds;
        !outside & box_mask(x1 - x0, y1 - y0)
    }

    /// Barycentric numerators `E_k` of the sample at pixel offset `(i, j)`.
    #[inline(always)]
    pub fn weights(&self, i: i32, j: i32) -> [f32; 3] {
        std::array::from_fn(|k| (self.e[k] + self.bias[k] + self.dx[k] * i + self.dy[k] * j) as f32)
    }
}

/// Bits of the samples inside a box of `(last_x + 1) × (last_y + 1)` pixels.
#[inline(always)]
fn box_mask(last_x: i32, last_y: i32) -> u32 {
    let row = (1u32 << (last_x + 1)) - 1;
    let rows = [row, row * 0x11, row * 0x111, row * 0x1111];
    rows[last_y as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pos(x: f32, y: f32) -> ScreenPos {
        ScreenPos {
            x: (x * ONE as f32).round() as i32,
            y: (y * ONE as f32).round() as i32,
        }
    }

    /// Brute-force coverage of one sample with i64 edge functions and the top-left rule.
    fn covered(t: [ScreenPos; 3], x: i32, y: i32) -> bool {
        let [a, mut b, mut c] = t;
        if orient(a, b, c) < 0 {
            std::mem::swap(&mut b, &mut c);
        }
        let s = (i64::from(x) * 256 + 128, i64::from(y) * 256 + 128);
        [(b, c), (c, a), (a, b)].iter().all(|&(p, q)| {
            let (ex, ey) = (i64::from(q.x - p.x), i64::from(q.y - p.y));
            let e = ex * (s.1 - i64::from(p.y)) - ey * (s.0 - i64::from(p.x));
            e > 0 || (e == 0 && (ey < 0 || (ey == 0 && ex > 0)))
        })
    }

    #[test]
    fn small_coverage_mask_matches_brute_force() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut rand = |scale: f32| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32 * scale
        };
        let mut tested = 0;
        for _ in 0..20_000 {
            let base = (rand(20.0), rand(20.0));
            // Vertices on exact half-pixel positions now and then, to hit the tie rule.
            let snap = |v: f32, on: bool| if on { (v * 2.0).round() / 2.0 } else { v };
            let on = rand(1.0) < 0.3;
            let t = [
                pos(snap(base.0 + rand(5.0), on), snap(base.1 + rand(5.0), on)),
                pos(snap(base.0 + rand(5.0), on), snap(base.1 + rand(5.0), on)),
                pos(snap(base.0 + rand(5.0), on), snap(base.1 + rand(5.0), on)),
            ];
            let Some(Triangle::Micro(micro)) = Triangle::new(t, 32, 32) else {
                continue;
            };
            let [x0, x1, y0, y1] = micro.bounds;
            let mask = micro.coverage();
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let bit = (y - y0) * SMALL + (x - x0);
                    assert_eq!(
                        mask >> bit & 1 == 1,
                        covered(t, x, y),
                        "{t:?} at ({x}, {y})"
                    );
                }
            }
            assert_eq!(mask & !box_mask(x1 - x0, y1 - y0), 0);
            tested += 1;
        }
        assert!(tested > 5_000, "{tested}");
    }
}
