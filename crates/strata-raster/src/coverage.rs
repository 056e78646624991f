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
//! [`MICRO_W`] × [`MICRO_H`] pixel centres or [`MICRO_H`] × [`MICRO_W`] (most triangles of a
//! dense mesh, and the slivers among the rest) get their coverage as one bitmask, computed once
//! in setup; the others are scanned row by row, each row's covered span found exactly with one
//! integer division per edge.

use crate::vertex::{HALF, ONE, SUBPIXEL_BITS, ScreenPos};

/// Bounding boxes of at most `MICRO_W × MICRO_H` pixel centres (*wide* micro-triangles) or
/// `MICRO_H × MICRO_W` (*tall* ones) are covered by a bitmask of `MICRO_W · MICRO_H` = 32
/// bits, bit `r · MICRO_W + c` for offset `c` along the block's long side and `r` across it:
/// pixel offset `(c, r)` in a wide block, `(r, c)` in a tall one ([`Micro::offset`]). Eight
/// long rather than four (the block was 4 × 4 before): on the full dragon, 37,500 of the 40,000
/// triangles that missed a 4 × 4 block were slivers five to eight pixel centres long and at
/// most four across, and scanning each as a larger triangle cost about 130 ns.
pub const MICRO_W: i32 = 8;

/// See [`MICRO_W`].
pub const MICRO_H: i32 = 4;

/// Samples of a micro-triangle's block.
pub const MICRO_SAMPLES: usize = (MICRO_W * MICRO_H) as usize;

const _: () = assert!(MICRO_SAMPLES <= 32, "a micro-triangle's coverage is a u32");

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
    /// Bounding box of at most [`MICRO_W`] × [`MICRO_H`] or [`MICRO_H`] × [`MICRO_W`] pixel
    /// centres.
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
        if let Some(tall) = micro_block(x1 - x0, y1 - y0, spreads(a, b, c)) {
            Micro::new(pos, bounds, tall).map(Triangle::Micro)
        } else {
            Setup::new(pos, width, height).map(Triangle::Large)
        }
    }
}

/// Largest vertex spread (fixed point) of a micro-triangle along its block's long side:
/// [`MICRO_W`] + 1 pixels less one step. Every triangle whose bounding box holds at most
/// [`MICRO_W`] × [`MICRO_H`] pixel centres spreads less than 9 × 5 pixels; one whose box was
/// cut to that size by the image's edges may spread up to the guard band, and its edge
/// functions would overflow `i32`, so it is set up as a large triangle instead.
pub const MICRO_SPREAD_LONG: i32 = (MICRO_W + 1) * ONE - 1;

/// Largest vertex spread across a micro-triangle's block; see [`MICRO_SPREAD_LONG`].
pub const MICRO_SPREAD_SHORT: i32 = (MICRO_H + 1) * ONE - 1;

/// The vertices' spread in x and in y.
#[inline(always)]
fn spreads(a: ScreenPos, b: ScreenPos, c: ScreenPos) -> (i32, i32) {
    let spread = |p: i32, q: i32, r: i32| p.max(q).max(r) - p.min(q).min(r);
    (spread(a.x, b.x, c.x), spread(a.y, b.y, c.y))
}

/// Which block a triangle with a box of `(last_x + 1) × (last_y + 1)` pixel centres and vertex
/// spreads `(sx, sy)` is covered in: `Some(false)` wide (preferred), `Some(true)` tall, `None`
/// if it is not a micro-triangle. [`Batch::classify`] decides the same lane by lane.
#[inline(always)]
fn micro_block(last_x: i32, last_y: i32, (sx, sy): (i32, i32)) -> Option<bool> {
    let fits = |last_long: i32, last_short: i32, s_long: i32, s_short: i32| {
        last_long < MICRO_W
            && last_short < MICRO_H
            && s_long <= MICRO_SPREAD_LONG
            && s_short <= MICRO_SPREAD_SHORT
    };
    if fits(last_x, last_y, sx, sy) {
        Some(false)
    } else if fits(last_y, last_x, sy, sx) {
        Some(true)
    } else {
        None
    }
}

/// A micro-triangle set up in `i32`: its vertices lie within 9 × 5 pixels (or 5 × 9) of each
/// other ([`MICRO_SPREAD_LONG`], [`MICRO_SPREAD_SHORT`]) and of every sample of its box, so a
/// covered sample's edge value lies between 0 and twice the area (< 9 · 5 · 256² < 2^22) and
/// converts to `f32` exactly. The block's samples outside the box are evaluated too (then
/// masked off); the first sample lies within the vertices' span, so every sample of the block
/// is within 16 × 8 pixels of every vertex and `|E|` stays below 2^24: far from `i32`'s range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Micro {
    /// Which input vertex is vertex 0, 1, 2 after orientation.
    pub order: [usize; 3],
    /// Twice the area, > 0.
    pub area: i32,
    /// Pixel bounds `[x0, x1, y0, y1]`, inclusive.
    pub bounds: [i32; 4],
    /// Covered in a tall block (long side vertical) rather than a wide one; see [`MICRO_W`].
    pub tall: bool,
    /// Biased edge values at the centre of pixel `(x0, y0)`.
    e: [i32; 3],
    dx: [i32; 3],
    dy: [i32; 3],
    bias: [i32; 3],
}

impl Micro {
    #[inline(always)]
    fn new(pos: [ScreenPos; 3], bounds: [i32; 4], tall: bool) -> Option<Micro> {
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
            tall,
            e: [e0, e1, e2],
            dx: [dx0, dx1, dx2],
            dy: [dy0, dy1, dy2],
            bias: [b0, b1, b2],
        })
    }

    /// The pixel offset `(i, j)` from the box's first pixel of the sample of bit `bit`.
    #[inline(always)]
    pub fn offset(&self, bit: i32) -> (i32, i32) {
        let (c, r) = (bit % MICRO_W, bit / MICRO_W);
        if self.tall { (r, c) } else { (c, r) }
    }

    /// The coverage bitmask, bit `r * MICRO_W + c` for the sample at [`Micro::offset`].
    ///
    /// All 32 samples of the block are evaluated branch-free, then masked to the bounding box.
    /// (Setup covers micro-triangles in its lanes, [`Batch::classify`]; this serves the scan's
    /// clipped pieces and the tests.)
    #[inline(always)]
    pub fn coverage(&self) -> u32 {
        let mut mask = 0u32;
        for bit in 0..MICRO_SAMPLES as i32 {
            // A sample is outside if any biased edge value is negative.
            let (i, j) = self.offset(bit);
            let v = |k: usize| self.e[k] + self.dx[k] * i + self.dy[k] * j;
            mask |= u32::from((v(0) | v(1) | v(2)) >= 0) << bit;
        }
        let [x0, x1, y0, y1] = self.bounds;
        let (along, across) = if self.tall {
            (y1 - y0, x1 - x0)
        } else {
            (x1 - x0, y1 - y0)
        };
        mask & box_mask(along, across)
    }

    /// The bits of `mask` whose samples lie in the box's rows `j0..=j1` (offsets from its first).
    pub fn rows(&self, mask: u32, j0: i32, j1: i32) -> u32 {
        (0..MICRO_SAMPLES as i32)
            .filter(|&bit| (j0..=j1).contains(&self.offset(bit).1))
            .fold(0, |m, bit| m | 1 << bit)
            & mask
    }

    /// Barycentric numerators `E_k` of the sample at pixel offset `(i, j)`.
    #[inline(always)]
    pub fn weights(&self, i: i32, j: i32) -> [f32; 3] {
        std::array::from_fn(|k| (self.e[k] + self.bias[k] + self.dx[k] * i + self.dy[k] * j) as f32)
    }
}

/// What [`Batch::classify`] decided for each lane, as lane bitmasks (bit `l` for lane `l`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Verdict {
    /// All three vertices outside one plane of the view volume.
    pub outside: u32,
    /// Not outside, but a vertex crosses the near plane or the guard band: to be clipped.
    pub clip: u32,
    /// Neither, and fits neither micro-triangle block (a box of more than [`MICRO_W`] ×
    /// [`MICRO_H`] pixel centres or [`MICRO_H`] × [`MICRO_W`], or vertices spread too far): to be
    /// set up in `i64` by [`Triangle::new`] and binned.
    pub large: u32,
    /// Micro-triangles that cover at least one sample; [`Batch::micro`] gives each one.
    pub micro: u32,
}

impl Verdict {
    /// Lanes that are none of the above: zero area, or no covered pixel centre.
    pub fn empty(&self, lanes: usize) -> u32 {
        let valid = if lanes >= 32 { !0 } else { (1u32 << lanes) - 1 };
        valid & !(self.outside | self.clip | self.large | self.micro)
    }
}

/// Up to `L` consecutive triangles, classified and — for micro-triangles — set up and
/// covered together, lane by lane, without branches. `L` is the lane width of the instruction
/// set setup runs on ([`crate::lanes`]: 16 with AVX-512, else 8), at most 32 (a [`Verdict`]
/// holds a bit a lane).
///
/// Layout: structure of arrays, one `[_; L]` per quantity, so every step of
/// `Micro::new` and [`Micro::coverage`] is one vector operation over the batch (LLVM
/// vectorises the lane loops; a lane array is one register of the instruction set). Lanes whose
/// triangles turn out not to be micro-triangles compute garbage with wrapping arithmetic, and
/// their results are never read. A micro-triangle's values are exactly those of `Micro::new`,
/// so which setup ran is invisible downstream (tested against it below).
#[derive(Clone, Copy, Debug)]
pub struct Batch<const L: usize> {
    x: [[i32; L]; 3],
    y: [[i32; L]; 3],
    code_and: [u32; L],
    code_or: [u32; L],
    // Micro-triangle set-up, valid in `Verdict::micro` lanes.
    swapped: [bool; L],
    /// 1 for a tall block, 0 for a wide one ([`Micro::tall`]).
    tall: [u32; L],
    area: [i32; L],
    bounds: [[i32; L]; 4],
    e: [[i32; L]; 3],
    dx: [[i32; L]; 3],
    dy: [[i32; L]; 3],
    bias: [[i32; L]; 3],
    /// `e + bias`: the edge values themselves, from which a sample's weights are stepped.
    e_unbiased: [[i32; L]; 3],
    mask: [u32; L],
}

impl<const L: usize> Default for Batch<L> {
    fn default() -> Self {
        const { assert!(L > 0 && L <= 32, "a Verdict holds a bit a lane") };
        Batch {
            x: [[0; L]; 3],
            y: [[0; L]; 3],
            code_and: [0; L],
            code_or: [0; L],
            swapped: [false; L],
            tall: [0; L],
            area: [0; L],
            bounds: [[0; L]; 4],
            e: [[0; L]; 3],
            dx: [[0; L]; 3],
            dy: [[0; L]; 3],
            bias: [[0; L]; 3],
            e_unbiased: [[0; L]; 3],
            mask: [0; L],
        }
    }
}

impl<const L: usize> Batch<L> {
    /// Puts a triangle's window positions and vertex outcodes in `lane`.
    #[inline(always)]
    pub fn set(&mut self, lane: usize, pos: [ScreenPos; 3], codes: [u8; 3]) {
        for (k, p) in pos.iter().enumerate() {
            self.x[k][lane] = p.x;
            self.y[k][lane] = p.y;
        }
        self.code_and[lane] = u32::from(codes[0] & codes[1] & codes[2]);
        self.code_or[lane] = u32::from(codes[0] | codes[1] | codes[2]);
    }

    /// Copies the positions and outcodes [`Batch::set`] put in `from`'s lanes.
    #[inline(always)]
    pub fn take_input(&mut self, from: &Batch<L>) {
        self.x = from.x;
        self.y = from.y;
        self.code_and = from.code_and;
        self.code_or = from.code_or;
    }

    /// Classifies the first `lanes` lanes for a `width` × `height` image, given the outcode bits
    /// `view` (culled if all three vertices share one) and `clip` (clipped if any vertex has
    /// one); see [`Verdict`].
    #[inline(always)]
    pub fn classify(
        &mut self,
        lanes: usize,
        width: i32,
        height: i32,
        view: u8,
        clip: u8,
    ) -> Verdict {
        let mut outside = [false; L];
        let mut clipped = [false; L];
        let mut large = [false; L];
        let mut micro = [false; L];
        let [[ax, bx0, cx0], [ay, by0, cy0]] = [self.x, self.y];
        for l in 0..L {
            outside[l] = self.code_and[l] & u32::from(view) != 0;
            clipped[l] = !outside[l] && self.code_or[l] & u32::from(clip) != 0;
            // pixel_bounds, lane by lane.
            let min_x = ax[l].min(bx0[l]).min(cx0[l]);
            let max_x = ax[l].max(bx0[l]).max(cx0[l]);
            let min_y = ay[l].min(by0[l]).min(cy0[l]);
            let max_y = ay[l].max(by0[l]).max(cy0[l]);
            let x0 = (min_x.wrapping_add(ONE - 1 - HALF) >> SUBPIXEL_BITS).max(0);
            let x1 = (max_x.wrapping_sub(HALF) >> SUBPIXEL_BITS).min(width - 1);
            let y0 = (min_y.wrapping_add(ONE - 1 - HALF) >> SUBPIXEL_BITS).max(0);
            let y1 = (max_y.wrapping_sub(HALF) >> SUBPIXEL_BITS).min(height - 1);
            let some = x0 <= x1 && y0 <= y1;
            let (last_x, last_y) = (x1.wrapping_sub(x0), y1.wrapping_sub(y0));
            // Micro-sized, wide or tall, with the vertices close together (`micro_block`: a box
            // cut small by the image's edges may hide vertices far outside it, too far for
            // `i32`).
            let (sx_, sy_) = (max_x.wrapping_sub(min_x), max_y.wrapping_sub(min_y));
            let fits = |last_long: i32, last_short: i32, s_long: i32, s_short: i32| {
                last_long < MICRO_W
                    && last_short < MICRO_H
                    && s_long <= MICRO_SPREAD_LONG
                    && s_short <= MICRO_SPREAD_SHORT
            };
            let wide = fits(last_x, last_y, sx_, sy_);
            let tall = !wide && fits(last_y, last_x, sy_, sx_);
            let small = wide || tall;
            let candidate = !outside[l] && !clipped[l] && some;
            large[l] = candidate && !small;
            // Micro::new, lane by lane, in wrapping i32 (exact for micro-triangles).
            let (bx, by, cx, cy) = (bx0[l], by0[l], cx0[l], cy0[l]);
            let (ax, ay) = (ax[l], ay[l]);
            let area = (bx.wrapping_sub(ax))
                .wrapping_mul(cy.wrapping_sub(ay))
                .wrapping_sub((cx.wrapping_sub(ax)).wrapping_mul(by.wrapping_sub(ay)));
            let swap = area < 0;
            let (bx, by, cx, cy) = if swap {
                (cx, cy, bx, by)
            } else {
                (bx, by, cx, cy)
            };
            let sx = x0.wrapping_mul(ONE).wrapping_add(HALF);
            let sy = y0.wrapping_mul(ONE).wrapping_add(HALF);
            let edge = |px: i32, py: i32, qx: i32, qy: i32| {
                let (ex, ey) = (qx.wrapping_sub(px), qy.wrapping_sub(py));
                let bias = i32::from(!(ey < 0 || (ey == 0 && ex > 0)));
                let e = ex
                    .wrapping_mul(sy.wrapping_sub(py))
                    .wrapping_sub(ey.wrapping_mul(sx.wrapping_sub(px)))
                    .wrapping_sub(bias);
                (
                    e,
                    ey.wrapping_neg().wrapping_mul(ONE),
                    ex.wrapping_mul(ONE),
                    bias,
                )
            };
            let edges = [
                edge(bx, by, cx, cy),
                edge(cx, cy, ax, ay),
                edge(ax, ay, bx, by),
            ];
            // Coverage of the block, 8 samples along its long side (x if wide, y if tall) by 4
            // across, then masked to the bounding box (`box_mask`, with the box clamped so that
            // lanes that are not micro-triangles shift in range). The steps along and across
            // are chosen per lane, so the loop is the same for both shapes.
            let step = |k: usize| {
                let (_, dx, dy, _) = edges[k];
                if tall { (dy, dx) } else { (dx, dy) }
            };
            let steps = [step(0), step(1), step(2)];
            let mut mask = 0u32;
            for r in 0..MICRO_H {
                for c in 0..MICRO_W {
                    let v = |k: usize| {
                        let (along, across) = steps[k];
                        edges[k]
                            .0
                            .wrapping_add(along.wrapping_mul(c))
                            .wrapping_add(across.wrapping_mul(r))
                    };
                    let inside = (v(0) | v(1) | v(2)) >= 0;
                    mask |= u32::from(inside) << (r * MICRO_W + c);
                }
            }
            let (last_long, last_short) = if tall {
                (last_y, last_x)
            } else {
                (last_x, last_y)
            };
            let (bx, by) = (
                last_long.clamp(0, MICRO_W - 1),
                last_short.clamp(0, MICRO_H - 1),
            );
            mask &= ((2u32 << bx) - 1) * (0x0101_0101 >> (MICRO_W * (MICRO_H - 1 - by)));
            micro[l] = candidate && small && area != 0 && mask != 0;
            self.swapped[l] = swap;
            self.tall[l] = u32::from(tall);
            self.area[l] = area.wrapping_abs();
            self.bounds[0][l] = x0;
            self.bounds[1][l] = x1;
            self.bounds[2][l] = y0;
            self.bounds[3][l] = y1;
            for (k, &(e, dx, dy, bias)) in edges.iter().enumerate() {
                self.e[k][l] = e;
                self.dx[k][l] = dx;
                self.dy[k][l] = dy;
                self.bias[k][l] = bias;
                self.e_unbiased[k][l] = e.wrapping_add(bias);
            }
            self.mask[l] = mask;
        }
        // Every lane's flag, then only the batch's lanes: no iterator bound to test each lane.
        let valid = if lanes >= 32 { !0 } else { (1u32 << lanes) - 1 };
        let bits = |flags: [bool; L]| {
            let mut m = 0u32;
            for (l, &f) in flags.iter().enumerate() {
                m |= u32::from(f) << l;
            }
            m & valid
        };
        Verdict {
            outside: bits(outside),
            clip: bits(clipped),
            large: bits(large),
            micro: bits(micro),
        }
    }

    /// The micro-triangle set-up of every lane, read in place by
    /// [`crate::shade_lanes::MicroShader`] (valid in [`Verdict::micro`] lanes).
    #[inline(always)]
    pub(crate) fn micro_lanes(&self) -> MicroLanes<'_, L> {
        MicroLanes {
            swapped: &self.swapped,
            tall: &self.tall,
            area: &self.area,
            x0: &self.bounds[0],
            y0: &self.bounds[2],
            e: &self.e_unbiased,
            dx: &self.dx,
            dy: &self.dy,
            mask: &self.mask,
        }
    }

    /// The micro-triangle in `lane` (a lane of [`Verdict::micro`]) and its coverage mask, as
    /// `Micro::new` and [`Micro::coverage`] would give them: copied out. Setup shades its lanes
    /// in place with [`crate::shade_lanes::MicroShader`]; this is the reference the tests hold
    /// the batch and the lanes to.
    #[inline(always)]
    pub fn micro(&self, lane: usize) -> (Micro, u32) {
        let l = lane;
        (
            Micro {
                order: if self.swapped[l] {
                    [0, 2, 1]
                } else {
                    [0, 1, 2]
                },
                area: self.area[l],
                bounds: [
                    self.bounds[0][l],
                    self.bounds[1][l],
                    self.bounds[2][l],
                    self.bounds[3][l],
                ],
                tall: self.tall[l] != 0,
                e: [self.e[0][l], self.e[1][l], self.e[2][l]],
                dx: [self.dx[0][l], self.dx[1][l], self.dx[2][l]],
                dy: [self.dy[0][l], self.dy[1][l], self.dy[2][l]],
                bias: [self.bias[0][l], self.bias[1][l], self.bias[2][l]],
            },
            self.mask[l],
        )
    }
}

/// A [`Batch`]'s micro-triangle set-up, lane arrays borrowed in place
/// ([`Batch::micro_lanes`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct MicroLanes<'a, const L: usize> {
    /// Vertices 1 and 2 exchanged to orient the triangle ([`Micro::order`] is `[0, 2, 1]`).
    pub swapped: &'a [bool; L],
    /// 1 where the block is tall: a sample's offset along the block is its `y` offset.
    pub tall: &'a [u32; L],
    /// Twice the area, > 0.
    pub area: &'a [i32; L],
    /// The first pixel of the bounding box.
    pub x0: &'a [i32; L],
    pub y0: &'a [i32; L],
    /// Edge values at the first pixel's centre (without the top-left bias) and their steps.
    pub e: &'a [[i32; L]; 3],
    pub dx: &'a [[i32; L]; 3],
    pub dy: &'a [[i32; L]; 3],
    /// Coverage within the block.
    pub mask: &'a [u32; L],
}

/// Bits of the samples inside a box of `last_long + 1` samples along a block and
/// `last_short + 1` across it (at most [`MICRO_W`] × [`MICRO_H`]).
#[inline(always)]
fn box_mask(last_long: i32, last_short: i32) -> u32 {
    let row = (2u32 << last_long) - 1;
    let rows = [row, row * 0x101, row * 0x1_0101, row * 0x101_0101];
    rows[last_short as usize]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rand::Rand;

    fn pos(x: f32, y: f32) -> ScreenPos {
        ScreenPos {
            x: (x * ONE as f32).round() as i32,
            y: (y * ONE as f32).round() as i32,
        }
    }

    /// A random triangle near the image's corner whose vertices spread up to 9 pixels along y
    /// (`tall`) or x and 5 across, on exact half-pixel positions if `snap` (to hit the tie
    /// rule): mostly micro-triangles of either block shape.
    fn sliver(r: &mut Rand, tall: bool, snap: bool) -> [ScreenPos; 3] {
        let base = (r.unit() * 20.0, r.unit() * 20.0);
        let (sx, sy) = if tall { (5.0, 9.0) } else { (9.0, 5.0) };
        let snap = |v: f32| if snap { (v * 2.0).round() / 2.0 } else { v };
        std::array::from_fn(|_| {
            let (x, y) = (base.0 + r.unit() * sx, base.1 + r.unit() * sy);
            pos(snap(x), snap(y))
        })
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

    /// What the per-triangle path makes of lane `l` of a batch: outside, clip, large (with
    /// `Setup`), micro with coverage, or empty.
    #[derive(Debug, PartialEq)]
    enum Kind {
        Outside,
        Clip,
        Large,
        Micro(Micro, u32),
        Empty,
    }

    fn one_by_one(t: [ScreenPos; 3], codes: [u8; 3], w: i32, h: i32) -> Kind {
        use crate::vertex::outcode;
        if codes[0] & codes[1] & codes[2] & outcode::VIEW != 0 {
            return Kind::Outside;
        }
        if (codes[0] | codes[1] | codes[2]) & outcode::CLIP != 0 {
            return Kind::Clip;
        }
        match Triangle::new(t, w, h) {
            None => Kind::Empty,
            Some(Triangle::Large(_)) => Kind::Large,
            Some(Triangle::Micro(m)) => match m.coverage() {
                0 => Kind::Empty,
                mask => Kind::Micro(m, mask),
            },
        }
    }

    #[test]
    fn batch_classifies_and_covers_exactly_like_one_triangle_at_a_time() {
        // Both widths setup runs at (crate::lanes), whatever this CPU has.
        classify_like_one_at_a_time::<8>();
        classify_like_one_at_a_time::<16>();
    }

    fn classify_like_one_at_a_time<const L: usize>() {
        use crate::vertex::outcode;
        let mut r = Rand(0x2545_f491_4f6c_dd1d);
        let mut rand = |n: u32| r.below(n) as u32;
        let (w, h) = (40, 30);
        let mut counts = [0usize; 5];
        let mut batch = Batch::<L>::default();
        for _ in 0..4000 {
            let lanes = 1 + rand(L as u32) as usize;
            let mut expected = Vec::new();
            for l in 0..lanes {
                // Mostly micro-sized triangles near the image (some off its edges, some between
                // pixel centres, some degenerate), and now and then a large one, one far outside
                // the image or one with clip and view outcodes; spreads in x and y drawn apart,
                // so that wide and tall slivers occur.
                let spreads = [2, 5, 9, 60, 3000];
                let sx = spreads[rand(5) as usize] * 256;
                let sy = if rand(2) == 0 {
                    sx
                } else {
                    spreads[rand(5) as usize] * 256
                };
                let (bx, by) = (
                    rand(50 * 256) as i32 - 5 * 256,
                    rand(40 * 256) as i32 - 5 * 256,
                );
                let mut v = || ScreenPos {
                    x: bx + rand(sx) as i32 - sx as i32 / 2,
                    y: by + rand(sy) as i32 - sy as i32 / 2,
                };
                let mut t = [v(), v(), v()];
                if rand(10) == 0 {
                    t[2] = t[rand(2) as usize]; // zero area
                }
                let code = |r: u32| match r {
                    0 => outcode::LEFT,
                    1 => outcode::NEAR,
                    2 => outcode::GUARD | outcode::TOP,
                    _ => 0,
                };
                let mut codes = [code(rand(40)), code(rand(40)), code(rand(40))];
                if rand(12) == 0 {
                    codes = [outcode::LEFT, outcode::LEFT | outcode::NEAR, outcode::LEFT];
                }
                batch.set(l, t, codes);
                expected.push((t, one_by_one(t, codes, w, h)));
            }
            let v = batch.classify(lanes, w, h, outcode::VIEW, outcode::CLIP);
            for (l, (t, want)) in expected.iter().enumerate() {
                let bit = |m: u32| m >> l & 1 == 1;
                let got = if bit(v.outside) {
                    Kind::Outside
                } else if bit(v.clip) {
                    Kind::Clip
                } else if bit(v.large) {
                    // Large lanes are set up in i64 by the caller, which may still find zero area.
                    match Setup::new(*t, w, h) {
                        Some(_) => Kind::Large,
                        None => Kind::Empty,
                    }
                } else if bit(v.micro) {
                    let (m, mask) = batch.micro(l);
                    Kind::Micro(m, mask)
                } else {
                    Kind::Empty
                };
                counts[match want {
                    Kind::Outside => 0,
                    Kind::Clip => 1,
                    Kind::Large => 2,
                    Kind::Micro(..) => 3,
                    Kind::Empty => 4,
                }] += 1;
                assert_eq!(&got, want, "lane {l} of {lanes}");
            }
            // Lanes past the batch's length are never reported.
            let all = v.outside | v.clip | v.large | v.micro | v.empty(lanes);
            assert_eq!(all, (1u32 << lanes) - 1);
        }
        // Every kind was exercised.
        assert!(counts.iter().all(|&c| c > 300), "{counts:?}");
    }

    #[test]
    fn small_coverage_mask_matches_brute_force() {
        let mut r = Rand(0x9e37_79b9_7f4a_7c15);
        let (mut tested, mut tall) = (0, 0);
        for case in 0..30_000 {
            // Vertices on exact half-pixel positions now and then; tall blocks every third case.
            let snap = r.unit() < 0.3;
            let t = sliver(&mut r, case % 3 == 0, snap);
            let Some(Triangle::Micro(micro)) = Triangle::new(t, 32, 32) else {
                continue;
            };
            let [x0, x1, y0, y1] = micro.bounds;
            let mask = micro.coverage();
            let mut inside = 0u32;
            for bit in 0..MICRO_SAMPLES as i32 {
                let (i, j) = micro.offset(bit);
                let (x, y) = (x0 + i, y0 + j);
                if x > x1 || y > y1 {
                    continue;
                }
                inside |= 1 << bit;
                assert_eq!(
                    mask >> bit & 1 == 1,
                    covered(t, x, y),
                    "{t:?} at ({x}, {y})"
                );
            }
            // Every pixel of the box has its bit, and no bit lies outside the box.
            assert_eq!(inside.count_ones() as i32, (x1 - x0 + 1) * (y1 - y0 + 1));
            assert_eq!(mask & !inside, 0);
            tested += 1;
            tall += usize::from(micro.tall);
        }
        assert!(tested > 5_000, "{tested}");
        assert!(tall > 1_000, "{tall} tall blocks");
    }

    #[test]
    fn a_box_cut_small_by_the_image_edge_is_covered_exactly() {
        use crate::vertex::outcode;
        // Thin triangles entering a 40 × 30 image at its left edge (or, transposed, a 30 × 40
        // image at its top edge, for tall blocks) from up to 60,000 pixels away, so their boxes
        // of pixel centres in the image are at most 4 × 4 (or, from 6 pixels away, within a
        // micro-triangle's 9-pixel spread) while their edge functions are far beyond i32 (they
        // once overflowed as micro-triangles).
        let mut tested = 0;
        for (far, transpose) in [6.0f32, 100.0, 1000.0, 10_000.0, 60_000.0]
            .into_iter()
            .flat_map(|far| [(far, false), (far, true)])
        {
            let (w, h) = if transpose { (30, 40) } else { (40, 30) };
            let at = |x: f32, y: f32| if transpose { pos(y, x) } else { pos(x, y) };
            for (k, top) in [0.2f32, 7.6, 25.9].into_iter().enumerate() {
                for height in [0.7f32, 1.3, 2.9, 3.6] {
                    let t = [
                        at(-far, top),
                        at(2.7, top - 0.1 * k as f32),
                        at(2.9 + 0.3 * k as f32, top + height),
                    ];
                    let mut batch = Batch::<8>::default();
                    batch.set(0, t, [0; 3]);
                    let v = batch.classify(1, w, h, outcode::VIEW, outcode::CLIP);
                    // One triangle at a time: coverage from whichever setup it gets.
                    let mut one = Vec::new();
                    match Triangle::new(t, w, h) {
                        Some(Triangle::Micro(m)) => {
                            let [x0, _, y0, _] = m.bounds;
                            let mask = m.coverage();
                            for bit in (0..MICRO_SAMPLES as i32).filter(|b| mask >> b & 1 == 1) {
                                let (i, j) = m.offset(bit);
                                one.push((x0 + i, y0 + j));
                            }
                            assert_eq!(v.micro != 0, mask != 0, "far {far}: batch and one differ");
                        }
                        Some(Triangle::Large(s)) => {
                            let [x0, x1, y0, y1] = s.bounds;
                            for y in y0..=y1 {
                                let row = s.edges.at(0, y - y0);
                                if let Some((lo, hi)) = s.edges.span(row, x1 - x0) {
                                    one.extend((lo..=hi).map(|i| (x0 + i, y)));
                                }
                            }
                            assert_eq!(v.micro, 0, "far {far}: micro in the batch only");
                        }
                        None => {}
                    }
                    let mut want = Vec::new();
                    for y in 0..h {
                        for x in 0..w {
                            if covered(t, x, y) {
                                want.push((x, y));
                            }
                        }
                    }
                    // Row by row, as `want` is (a tall block's bits run down its columns).
                    one.sort_by_key(|&(x, y)| (y, x));
                    assert_eq!(one, want, "far {far}, top {top}, height {height}");
                    tested += usize::from(!want.is_empty());
                }
            }
        }
        assert!(tested > 60, "{tested}");
    }

    /// `Micro::rows`, which keeps a clipped piece's samples in a strip's rows, against brute
    /// force, for wide and tall blocks and every range of rows.
    #[test]
    fn a_micro_triangles_rows_are_selected_exactly() {
        let mut r = Rand(0x2545_f491_4f6c_dd1d);
        let (mut tested, mut tall) = (0, 0);
        for case in 0..4000 {
            let t = sliver(&mut r, case % 2 == 0, false);
            let Some(Triangle::Micro(m)) = Triangle::new(t, 32, 32) else {
                continue;
            };
            let [x0, x1, y0, y1] = m.bounds;
            let mask = m.coverage();
            for j0 in 0..=y1 - y0 {
                for j1 in j0..=y1 - y0 {
                    let kept = m.rows(mask, j0, j1);
                    let mut got: Vec<_> = (0..MICRO_SAMPLES as i32)
                        .filter(|b| kept >> b & 1 == 1)
                        .map(|b| m.offset(b))
                        .map(|(i, j)| (x0 + i, y0 + j))
                        .collect();
                    got.sort_by_key(|&(x, y)| (y, x));
                    let mut want = Vec::new();
                    for y in y0 + j0..=y0 + j1 {
                        for x in x0..=x1 {
                            if covered(t, x, y) {
                                want.push((x, y));
                            }
                        }
                    }
                    assert_eq!(got, want, "{t:?}, rows {j0}..={j1}");
                }
            }
            tested += 1;
            tall += usize::from(m.tall && y1 - y0 >= MICRO_H);
        }
        assert!(tested > 1000, "{tested}");
        assert!(tall > 300, "{tall} tall blocks more than four rows high");
    }
}
