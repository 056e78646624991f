//! Triangle setup and binning: cull, clip, and sort triangles into the strips they touch.
//!
//! Work is cut into [`Chunk`]s of consecutive triangles of one object (at most
//! [`crate::RasterConfig::chunk_triangles`]); chunks are set up in parallel, each by one worker
//! that owns the chunk's bins. A chunk's output:
//!
//! ```text
//! bins[s]   : Vec<u32>                 triangle references for strip s, in primitive order
//!             r < CLIPPED              → triangle `triangles.start + r` of the object, vertices from
//!                                        the frame's vertex array
//!             r & CLIPPED != 0         → clipped[r & !CLIPPED], a piece made by the clipper
//! clipped   : Vec<ClippedTriangle>     projected pieces of triangles that crossed the near plane or
//!                                      the guard band, in primitive order
//! ```
//!
//! A triangle is culled when its three vertices lie outside the same view-volume plane, when its
//! fixed-point area is zero, or when its bounding box contains no pixel centre. Nothing here
//! allocates per triangle: bins and the clipped list keep their capacity from frame to frame.

use std::ops::Range;

use glam::{Mat4, Vec3};

use crate::clip::{ClipVertex, Polygon};
use crate::frame::DrawObject;
use crate::vertex::{Attrs, HALF, ONE, SUBPIXEL_BITS, ScreenPos, Viewport, outcode};

/// Tag of a bin entry that refers to a clipped piece.
pub const CLIPPED: u32 = 1 << 31;

/// What setup did with the frame's triangles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SetupStats {
    /// Triangles submitted.
    pub triangles: u64,
    /// Culled: all three vertices outside one plane of the view volume.
    pub culled_outside: u64,
    /// Culled: zero area in fixed point, or no pixel centre inside the bounding box.
    pub culled_empty: u64,
    /// Sent through the clipper (crossing the near plane or the guard band).
    pub clipped: u64,
    /// Triangles (or clipped pieces) binned; one per strip they touch.
    pub bin_entries: u64,
}

impl SetupStats {
    /// Adds another chunk's counts.
    pub fn add(&mut self, o: &SetupStats) {
        self.triangles += o.triangles;
        self.culled_outside += o.culled_outside;
        self.culled_empty += o.culled_empty;
        self.clipped += o.clipped;
        self.bin_entries += o.bin_entries;
    }
}

/// A piece of a clipped triangle, with its own (new) vertices.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClippedTriangle {
    /// Window positions.
    pub pos: [ScreenPos; 3],
    /// Interpolated attributes.
    pub attrs: [Attrs; 3],
}

/// A run of consecutive triangles of one object and its per-strip bins.
#[derive(Debug, Default)]
pub struct Chunk {
    /// Index of the object in the frame.
    pub object: usize,
    /// The object's triangles this chunk covers.
    pub triangles: Range<usize>,
    /// Per-strip triangle references; see the module docs.
    pub bins: Vec<Vec<u32>>,
    /// Clipped pieces.
    pub clipped: Vec<ClippedTriangle>,
    /// What setup did.
    pub stats: SetupStats,
}

impl Chunk {
    /// Prepares the chunk for a new frame, keeping its allocations.
    pub fn reset(&mut self, object: usize, triangles: Range<usize>, strips: usize) {
        self.object = object;
        self.triangles = triangles;
        self.bins.resize_with(strips, Vec::new);
        self.bins.truncate(strips);
        for b in &mut self.bins {
            b.clear();
        }
        self.clipped.clear();
        self.stats = SetupStats::default();
    }
}

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

/// The frame-wide inputs of setup.
#[derive(Clone, Copy, Debug)]
pub struct SetupContext<'a> {
    /// Eye → clip, to rebuild clip positions for clipping.
    pub projection: &'a Mat4,
    /// Image size and guard band.
    pub viewport: &'a Viewport,
    /// `log2` of the strip height.
    pub strip_shift: u32,
}

/// Culls, clips and bins one chunk.
///
/// `screen`, `codes` and `attrs` are the chunk's object's slices of the frame's vertex arrays.
pub fn setup_chunk(
    chunk: &mut Chunk,
    draw: &DrawObject<'_>,
    screen: &[ScreenPos],
    codes: &[u8],
    attrs: &[Attrs],
    cx: &SetupContext<'_>,
) {
    let vp = cx.viewport;
    let (w, h) = (vp.width as i32, vp.height as i32);
    let shift = cx.strip_shift;
    let mut stats = SetupStats {
        triangles: chunk.triangles.len() as u64,
        ..SetupStats::default()
    };
    let bins = &mut chunk.bins;
    let mut bin = |r: u32, y0: i32, y1: i32, stats: &mut SetupStats| {
        for s in (y0 >> shift)..=(y1 >> shift) {
            bins[s as usize].push(r);
            stats.bin_entries += 1;
        }
    };
    for (t, tri) in draw.triangles[chunk.triangles.clone()].iter().enumerate() {
        let [i0, i1, i2] = tri.map(|i| i as usize);
        let (o0, o1, o2) = (codes[i0], codes[i1], codes[i2]);
        if o0 & o1 & o2 & outcode::VIEW != 0 {
            stats.culled_outside += 1;
            continue;
        }
        if (o0 | o1 | o2) & outcode::CLIP != 0 {
            stats.clipped += 1;
            let cv = |i: usize| {
                let p = Vec3::from(attrs[i].p);
                ClipVertex {
                    c: *cx.projection * p.extend(1.0),
                    p,
                    n: Vec3::from(attrs[i].n),
                }
            };
            let poly = Polygon::triangle([cv(i0), cv(i1), cv(i2)]).clip_near_and_guard(vp.guard);
            for piece in poly.fan() {
                let mut clipped = ClippedTriangle::default();
                for (k, q) in piece.iter().enumerate() {
                    let (x, y, z, iw) = vp.project(q.c);
                    clipped.pos[k] = ScreenPos { x, y };
                    clipped.attrs[k] = Attrs {
                        z,
                        iw,
                        p: q.p.to_array(),
                        n: q.n.to_array(),
                    };
                }
                let [a, b, c] = clipped.pos;
                if orient(a, b, c) == 0 {
                    continue;
                }
                if let Some([_, _, y0, y1]) = pixel_bounds(a, b, c, w, h) {
                    let r = CLIPPED | chunk.clipped.len() as u32;
                    chunk.clipped.push(clipped);
                    bin(r, y0, y1, &mut stats);
                }
            }
            continue;
        }
        let (a, b, c) = (screen[i0], screen[i1], screen[i2]);
        if orient(a, b, c) == 0 {
            stats.culled_empty += 1;
            continue;
        }
        match pixel_bounds(a, b, c, w, h) {
            Some([_, _, y0, y1]) => bin(t as u32, y0, y1, &mut stats),
            None => stats.culled_empty += 1,
        }
    }
    chunk.stats = stats;
}
