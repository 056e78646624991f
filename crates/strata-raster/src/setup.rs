//! Triangle setup and binning: cull, clip, rasterise micro-triangles, bin the rest.
//!
//! Work is cut into [`Chunk`]s of consecutive triangles of one object (at most
//! [`crate::RasterConfig::chunk_triangles`]); chunks are set up in parallel, each by one worker
//! that owns the chunk's output:
//!
//! ```text
//! frags[s]  : Vec<PixelFragment>       fragments of micro-triangles in strip s, primitive order
//!                                      (pixel, depth, colour: 12 bytes; the object is the chunk's)
//! bins[s]   : Vec<u64>                 triangles for the scan of strip s, primitive order:
//!             low 32 bits r            binned[r]
//!             high 32 bits             how many of frags[s] precede this triangle
//! binned    : Vec<BinnedTriangle>      every binned triangle with its own copy of its vertices'
//!                                      window positions and attributes (120 bytes), in primitive
//!                                      order: larger triangles, and the projected pieces of
//!                                      triangles that crossed the near plane or the guard band
//! ```
//!
//! A binned triangle carries copies of its vertices because setup has them at hand, in primitive
//! order, while a strip's scan would fetch them from the frame's vertex arrays out of order: one
//! cache miss for its indices and more for its vertices, about a fifth of the scan's time on the
//! full dragon before the copies (the same copies the clipper's pieces always had).
//!
//! A triangle is culled when its three vertices lie outside the same view-volume plane, when its
//! fixed-point area is zero, or when it covers no pixel centre.
//!
//! **Micro-triangles** — bounding box of at most [`crate::coverage::MICRO_W`] ×
//! [`crate::coverage::MICRO_H`] pixel centres (8 × 4, *wide*) or 4 × 8 (*tall*), vertices
//! within 9 × 5 (or 5 × 9) pixels of each other ([`crate::coverage::MICRO_SPREAD_LONG`],
//! [`crate::coverage::MICRO_SPREAD_SHORT`]): most triangles of a dense mesh, and nearly all of
//! the full dragon's slivers — are finished here, in `i32`: their exact coverage is one
//! bitmask computed in SIMD lanes ([`crate::coverage::Batch::classify`]), a third of the full dragon's cover nothing and stop there, and the rest
//! are shaded at once, the batch's micro-triangles together in lanes ([`crate::shade_lanes`]),
//! their fragments appended to the strip lists as 12-byte records (pixel index, depth, colour). Setup has
//! their vertices in registers already; binning them instead would make the scan load and set up
//! every one again. The scan of a strip replays the records into the store, interleaved with the
//! binned triangles by the cursor in each bin entry, so every pixel still receives its fragments
//! in primitive order.
//!
//! # Batches of a register's width
//!
//! A dense mesh's triangles are mostly tiny, and which of them are culled, empty or covered is
//! close to random from one to the next, so a triangle-at-a-time setup spends its time in
//! mispredicted branches and scalar arithmetic. Setup therefore takes triangles `L` at a time,
//! `L` the number of 32-bit lanes of the instruction set it runs on (16 with AVX-512, else 8;
//! [`crate::lanes`]): it gathers their window positions and outcodes into a [`Batch`] (structure of arrays),
//! which classifies all of them — outside, to clip, large, micro with its coverage mask, empty —
//! in lane-parallel arithmetic without branches. Only the lanes with work left (micro-triangles
//! that cover something, large triangles, triangles to clip) are then visited, in primitive
//! order. A batch's positions and outcodes are gathered a lane at a time (scalar stores), one
//! batch ahead of the batch being classified, so that those stores have drained by the time
//! `classify` reads them back as vectors. The whole chunk is compiled once per instruction set
//! and lane width and chosen at run time ([`crate::lanes::dispatch`]), so a batch quantity is
//! one register. Sixteen lanes on AVX-512 instead of eight took the full dragon's setup from 20
//! to 15 ms on one thread (Intel Xeon): the batch's vector work is about the same number of
//! instructions for twice the triangles.
//!
//! Nothing here allocates per triangle: all lists keep their capacity from frame to frame.

use crate::clip::{ClipVertex, Polygon};
use crate::frame::DrawObject;
use std::ops::Range;

use strata_core::{Fragment, ObjectId, Rgba8};

use crate::coverage::{Batch, Setup, orient, pixel_bounds};
use crate::lanes::{LaneJob, Permute};
use crate::scan::Shade;
use crate::shade_lanes::MicroShader;
use crate::vertex::{Attrs, ObjectTransform, ScreenPos, Viewport, outcode};

/// A bin entry: triangle reference and fragment-record cursor (see the module docs).
#[inline(always)]
pub fn bin_entry(reference: u32, cursor: usize) -> u64 {
    u64::from(reference) | ((cursor as u64) << 32)
}

/// A micro-triangle's fragment as setup hands it to the scan: its row-major pixel index, depth
/// and colour, 12 bytes. The object is the chunk's, so it is not stored: these records are
/// written once and read once per frame, and at a fragment per triangle they are a large share
/// of the frame's memory traffic.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct PixelFragment {
    /// Row-major pixel index.
    pub pixel: u32,
    /// Window depth.
    pub depth: f32,
    /// Shaded colour.
    pub color: Rgba8,
}

impl PixelFragment {
    /// The record of `fragment` at `pixel`.
    #[inline(always)]
    pub fn new(pixel: u32, fragment: Fragment) -> Self {
        PixelFragment {
            pixel,
            depth: fragment.depth,
            color: fragment.color,
        }
    }

    /// The fragment again, made by `object`.
    #[inline(always)]
    pub fn fragment(&self, object: ObjectId) -> Fragment {
        Fragment {
            depth: self.depth,
            color: self.color,
            object,
        }
    }
}

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
    /// Micro-triangles rasterised in setup.
    pub micro_triangles: u64,
    /// Fragments of micro-triangles.
    pub micro_fragments: u64,
    /// Triangles (or clipped pieces) binned for the scan; one per strip they touch.
    pub bin_entries: u64,
}

impl SetupStats {
    /// Adds another chunk's counts.
    pub fn add(&mut self, o: &SetupStats) {
        self.triangles += o.triangles;
        self.culled_outside += o.culled_outside;
        self.culled_empty += o.culled_empty;
        self.clipped += o.clipped;
        self.micro_triangles += o.micro_triangles;
        self.micro_fragments += o.micro_fragments;
        self.bin_entries += o.bin_entries;
    }
}

/// A binned triangle (or a piece of a clipped one) with its own copy of its vertices.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BinnedTriangle {
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
    /// Per-strip bin entries; see the module docs.
    pub bins: Vec<Vec<u64>>,
    /// Per-strip micro-triangle fragments.
    pub frags: Vec<Vec<PixelFragment>>,
    /// Binned triangles and clipped pieces, with copies of their vertices; bin entries index
    /// it.
    pub binned: Vec<BinnedTriangle>,
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
        self.frags.resize_with(strips, Vec::new);
        self.frags.truncate(strips);
        for f in &mut self.frags {
            f.clear();
        }
        self.binned.clear();
        self.stats = SetupStats::default();
    }
}

/// The inputs of setup besides the vertex arrays.
#[derive(Clone, Copy, Debug)]
pub struct SetupContext<'a> {
    /// The chunk's object's matrices, to recompute eye-space vertices for clipping.
    pub transform: &'a ObjectTransform,
    /// True if the object is lit (its normals matter).
    pub lit: bool,
    /// The object's shading constants.
    pub shade: &'a Shade,
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
    // Compiled once per instruction set (AVX-512 or AVX2 where the CPU has it, else SSE2; NEON)
    // and chosen at run time with its lane width (`crate::lanes`), so a batch quantity is one
    // register. Integer lanes and the fragments' float arithmetic (no fused multiply-adds) give
    // the same bits on every set and at every width.
    crate::lanes::dispatch(SetupJob {
        chunk,
        draw,
        screen,
        codes,
        attrs,
        cx,
    });
}

/// [`setup_chunk`]'s arguments, for [`crate::lanes::dispatch`].
struct SetupJob<'j, 'd> {
    chunk: &'j mut Chunk,
    draw: &'j DrawObject<'d>,
    screen: &'j [ScreenPos],
    codes: &'j [u8],
    attrs: &'j [Attrs],
    cx: &'j SetupContext<'j>,
}

impl LaneJob for SetupJob<'_, '_> {
    type Output = ();

    #[inline(always)]
    fn run<const L: usize, P: Permute<L>>(self, permute: P) {
        let SetupJob {
            chunk,
            draw,
            screen,
            codes,
            attrs,
            cx,
        } = self;
        if cx.lit {
            setup_chunk_impl::<true, L, P>(chunk, draw, screen, codes, attrs, cx, permute);
        } else {
            setup_chunk_impl::<false, L, P>(chunk, draw, screen, codes, attrs, cx, permute);
        }
    }
}

#[inline(always)]
fn setup_chunk_impl<const LIT: bool, const L: usize, P: Permute<L>>(
    chunk: &mut Chunk,
    draw: &DrawObject<'_>,
    screen: &[ScreenPos],
    codes: &[u8],
    attrs: &[Attrs],
    cx: &SetupContext<'_>,
    permute: P,
) {
    let vp = cx.viewport;
    let (w, h) = (vp.width as i32, vp.height as i32);
    let shift = cx.strip_shift;
    let mut stats = SetupStats {
        triangles: chunk.triangles.len() as u64,
        ..SetupStats::default()
    };
    let (bins, frags) = (&mut chunk.bins, &mut chunk.frags);
    let mut bin =
        |r: u32, y0: i32, y1: i32, frags: &[Vec<PixelFragment>], stats: &mut SetupStats| {
            for s in (y0 >> shift)..=(y1 >> shift) {
                bins[s as usize].push(bin_entry(r, frags[s as usize].len()));
                stats.bin_entries += 1;
            }
        };
    let tris = &draw.triangles[chunk.triangles.clone()];
    let fill = |batch: &mut Batch<L>, group: &[[u32; 3]]| {
        for (l, tri) in group.iter().enumerate() {
            let [i0, i1, i2] = tri.map(|i| i as usize);
            batch.set(
                l,
                [screen[i0], screen[i1], screen[i2]],
                [codes[i0], codes[i1], codes[i2]],
            );
        }
    };
    // The next group is filled (a scalar store a lane and vertex into the lane arrays of
    // `pending`) while this one is shaded, and copied into `batch` (whole arrays) when its turn
    // comes: by then its stores have drained. Filled right before `classify` reads them back
    // as vectors, the loads waited for the stores (a failed store-to-load forward; `perf`:
    // 5.7 % of setup at that one load on the Intel Xeon).
    let mut batch = Batch::<L>::default();
    let mut pending = Batch::<L>::default();
    let mut shader = MicroShader::new(permute);
    let mut groups = tris.chunks(L);
    let mut current = groups.next();
    if let Some(group) = current {
        fill(&mut pending, group);
    }
    while let Some(group) = current {
        batch.take_input(&pending);
        let verdict = batch.classify(group.len(), w, h, outcode::VIEW, outcode::CLIP);
        current = groups.next();
        if let Some(next) = current {
            fill(&mut pending, next);
        }
        let batch = &batch;
        stats.culled_outside += u64::from(verdict.outside.count_ones());
        stats.culled_empty += u64::from(verdict.empty(group.len()).count_ones());
        stats.clipped += u64::from(verdict.clip.count_ones());
        stats.micro_triangles += u64::from(verdict.micro.count_ones());
        // The lanes with work left, in primitive order.
        let mut todo = verdict.micro | verdict.large | verdict.clip;
        if verdict.micro != 0 {
            let vertices = |l: usize| group[l].map(|i| &attrs[i as usize]);
            shader.shade::<LIT>(batch, verdict.micro, vertices, w, cx.shade);
            // Only micro-triangles: their fragments in one loop, in primitive order.
            if todo == verdict.micro {
                shader.for_each_fragment(|row, fragment| {
                    frags[(row >> shift) as usize].push(fragment);
                });
                todo = 0;
            }
        }
        while todo != 0 {
            let l = todo.trailing_zeros() as usize;
            todo &= todo - 1;
            let [i0, i1, i2] = group[l].map(|i| i as usize);
            if verdict.micro >> l & 1 != 0 {
                for (row, fragment) in shader.fragments(l) {
                    frags[(row >> shift) as usize].push(fragment);
                }
            } else if verdict.large >> l & 1 != 0 {
                match Setup::new([screen[i0], screen[i1], screen[i2]], w, h) {
                    Some(tri) => {
                        let r = chunk.binned.len() as u32;
                        chunk.binned.push(BinnedTriangle {
                            pos: [screen[i0], screen[i1], screen[i2]],
                            attrs: [attrs[i0], attrs[i1], attrs[i2]],
                        });
                        bin(r, tri.bounds[2], tri.bounds[3], frags, &mut stats);
                    }
                    None => stats.culled_empty += 1,
                }
            } else {
                let cv = |i: usize| {
                    let (p, n) = cx.transform.eye(draw.positions[i], draw.normals[i], cx.lit);
                    ClipVertex {
                        c: cx.transform.projection * p.extend(1.0),
                        p,
                        n,
                    }
                };
                let poly =
                    Polygon::triangle([cv(i0), cv(i1), cv(i2)]).clip_near_and_guard(vp.guard);
                for piece in poly.fan() {
                    let mut clipped = BinnedTriangle::default();
                    for (k, q) in piece.iter().enumerate() {
                        let (x, y, z, iw) = vp.project(q.c);
                        clipped.pos[k] = ScreenPos { x, y };
                        clipped.attrs[k] = Attrs::new(z, iw, q.p, q.n);
                    }
                    let [a, b, c] = clipped.pos;
                    if orient(a, b, c) == 0 {
                        continue;
                    }
                    if let Some([_, _, y0, y1]) = pixel_bounds(a, b, c, w, h) {
                        let r = chunk.binned.len() as u32;
                        chunk.binned.push(clipped);
                        bin(r, y0, y1, frags, &mut stats);
                    }
                }
            }
        }
    }
    stats.micro_fragments = chunk.frags.iter().map(|f| f.len() as u64).sum();
    chunk.stats = stats;
}
