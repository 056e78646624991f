//! The DeepFrame-aware layout: per-pixel counts, then each fragment column replaced by what a
//! predictor from already-sent neighbours got wrong, laid out for a byte-oriented compressor.
//!
//! A DeepFrame is not an arbitrary byte string: most pixels hold 0 or a few fragments and their
//! neighbours hold about as many; each run is sorted; a surface seen at layer `k` of one pixel is
//! usually seen at layer `k` of the next pixel too, and there its window depth is an affine function
//! of the screen position (planar triangles) and its shaded colour varies slowly; the object id
//! hardly ever changes. The thesis layout hides all of that from LZ4. This layout exposes it.
//!
//! # Bands and neighbourhood
//!
//! The frame's rows are cut into prediction bands of [`BAND_ROWS`] rows, and prediction never
//! leaves its band, so bands encode and decode independently, in parallel.
//!
//! Fragments are visited in DeepFrame order (pixels row-major, each run front to back). Fragment
//! `k` of pixel `(x, y)` is predicted from fragment `k` (the same *layer*) of its left `L = (x-1, y)`,
//! upper `U = (x, y-1)` and upper-left `UL = (x-1, y-1)` neighbours where those pixels are in its
//! band and hold more than `k` fragments, else from the previous fragment `P` of its own run
//! (`k > 0`), else from the first fragment of the last non-empty run visited in the band (`F`),
//! else from zero. All of these precede it, so the decoder, which visits in the same order, has
//! them. One function, `walk`, visits a band and names each fragment's source for both
//! directions.
//!
//! # Sections (in this order)
//!
//! | tag | bytes before compression | what |
//! | --- | --- | --- |
//! | `counts` (16) | `w·h` varints | fragments per pixel, unsigned LEB128 (one byte below 128) |
//! | `depth` (17) | `4·n`: four planes of `n` bytes | zigzag(depth bits − prediction), byte `j` of every residual in plane `j` (little end first) |
//! | `color` (18) | `4·n`: four planes of `n` bytes | (channel − prediction) mod 256, plane 0 red … plane 3 alpha |
//! | `object` (19) | varints | object id XOR prediction, zero-run coded |
//!
//! **Depth** is predicted on its IEEE bits (a non-negative `f32` orders like its bits, and bits
//! make the arithmetic exact): `L + U − UL` (the plane through the three neighbours, exact for a
//! planar surface up to the rasteriser's rounding) when all three exist, else `L`, `U`, `P`, `F`,
//! 0. Arithmetic is modulo 2^32 and the residual is read as an `i32` before zigzag coding, so any
//! bits round-trip. The four bytes of a residual go to four planes, so the compressor sees the
//! mostly-zero high bytes as long runs and the noisy low bytes together.
//!
//! **Colour** is predicted per channel with the median edge detector of LOCO-I / JPEG-LS
//! (`min(L, U)` if `UL >= max(L, U)`, `max(L, U)` if `UL <= min(L, U)`, else `L + U − UL`) when all
//! three exist, else `L`, `U`, `P`, `F`, 0. A constant alpha becomes a plane of zeros.
//!
//! **Object ids** are predicted by `L`, `U`, `P`, `F`, 0 (no arithmetic: ids are labels) and the
//! residual is `id XOR prediction`, mostly 0. The stream is `run, value, run, value, …, run` as
//! varints: `run` zero residuals, then one residual `value` (non-zero), …, ending with the run that
//! reaches `n` fragments.
//!
//! Why each transform is there, measured on 1280×720 frames, is in `docs/wire-format.md`.
//!
//! # Decoding
//!
//! The counts come first: they must add up to the header's fragment count before any fragment
//! column is allocated. The object stream is read next, into its non-zero residuals, and must
//! cover exactly the fragments. Every check is done before the bands replay their predictors in
//! parallel, so that replay cannot fail. The bands replay through `DeepFrame::fill_bands`, which
//! checks each band's depth range and sorted runs as soon as the band is written (while it is
//! in the cache), so a well-formed message with nonsense residuals is an error, not a frame.
//!
//! # Implementation (the layout above is the contract; this is how it is met fast)
//!
//! One function, `walk`, visits a band row by row and hands each non-empty pixel to the encoder
//! or the decoder:
//!
//! - a span of pixels holding as many fragments as their left and upper neighbours (their
//!   fragments, and those above, are contiguous) as one `surface` call over the span's
//!   fragments;
//! - any other pixel whose every layer has `L`, `U` and `UL` as one `surface` call that slices
//!   the neighbours' runs once;
//! - any other fragment with its named source (`visit`).
//!
//! Per fragment, the residuals live as one `u32` each (zigzagged depth, packed colour) in a row
//! buffer that stays in cache; the encoder spreads a finished row over the byte planes in one
//! pass, the decoder gathers a row from them before replaying it (sixteen fragments at a time
//! in SSE2 registers, `Lanes::gather`), so the predictor loop touches three columns instead of
//! eight planes. In a span, an object id with no residual there is its left neighbour's, copied
//! without looking for residuals fragment by fragment. In a decoded span of pixels of 1 to 4
//! fragments, each fragment depends on the one `c` before it (its left neighbour's layer), so
//! the row is a chain of predictions: the left values are carried in registers (colours in
//! vector registers) from pixel to pixel instead of being stored and loaded again, which took a
//! store-to-load round trip on every step. The colour predictor runs on the four channels at
//! once in the byte lanes of an SSE2 register (`Lanes`, through pulp; every x86_64 CPU has
//! SSE2; one channel at a time elsewhere), with the residual's byte add or subtract in the same
//! register. The bytes are those of the first, per-fragment implementation; a test pins them.

use std::ops::Range;

use rayon::prelude::*;
use strata_core::{DeepFrame, FillBand, ObjectId, Rgba8};

use crate::bytes::{Reader, put_varint, unzigzag, zigzag};
use crate::codec::{Columns, SectionTag};
use crate::error::WireError;

/// Rows of pixels in a prediction band. Prediction never reads a pixel of an earlier band (a
/// band's first row has no `U` or `UL`, and `F` starts empty in every band), so the bands of a
/// frame encode and decode independently, in parallel. Part of the format (since version 2).
pub const BAND_ROWS: usize = 64;

/// The pixel ranges of the prediction bands of a frame of `pixels` pixels, `width` to a row.
fn bands(pixels: usize, width: usize) -> Vec<Range<usize>> {
    let step = BAND_ROWS.saturating_mul(width).max(1);
    (0..pixels)
        .step_by(step)
        .map(|p0| p0..(p0 + step).min(pixels))
        .collect()
}

/// The run of a neighbouring pixel: where it starts (from the band's first fragment) and how
/// many fragments it holds (0 when the neighbour is outside the band).
#[derive(Clone, Copy)]
struct Nb {
    start: usize,
    len: usize,
}

const NONE: Nb = Nb { start: 0, len: 0 };

/// Which earlier fragment(s) of its band a fragment is predicted from (indices from the band's
/// first fragment).
#[derive(Clone, Copy)]
enum Source {
    /// `L`, `U` and `UL` all hold the fragment's layer: the three.
    Plane(usize, usize, usize),
    /// One earlier fragment: `L`, `U`, `P` or `F`.
    One(usize),
    /// Nothing precedes it in the band: predicted as zero.
    Zero,
}

#[inline(always)]
fn source(k: usize, start: usize, l: Nb, u: Nb, ul: Nb, first: Option<usize>) -> Source {
    let (hl, hu) = (k < l.len, k < u.len);
    if hl && hu && k < ul.len {
        Source::Plane(l.start + k, u.start + k, ul.start + k)
    } else if hl {
        Source::One(l.start + k)
    } else if hu {
        Source::One(u.start + k)
    } else if k > 0 {
        Source::One(start + k - 1)
    } else {
        match first {
            Some(f) => Source::One(f),
            None => Source::Zero,
        }
    }
}

/// What [`walk`] hands the fragments of a band to: the encoder computes their residuals, the
/// decoder their values. Indices count from the band's first fragment.
trait Visit {
    /// The row whose fragments are `frags` is about to be visited.
    fn row_start(&mut self, frags: Range<usize>);
    /// The fragments `frags` of the row just visited are done.
    fn row_end(&mut self, frags: Range<usize>);
    /// The `len` fragments from `me`, fragment `me + k` predicted from `l + k`, `u + k` and
    /// `ul + k`: one pixel inside a surface, or a span of pixels of equal counts (then
    /// `l = me − c` and the left neighbours are the span's own fragments, so `l + len` may pass
    /// `me`: a decoder reads what it has just written). `u + len` and `ul + len` stay before
    /// `l`: the row above ends before this row starts.
    fn surface(&mut self, me: usize, l: usize, u: usize, ul: usize, len: usize);
    /// Fragment `i`, predicted from `s` (a pixel at an edge of its neighbours' layers).
    fn visit(&mut self, i: usize, s: Source);
}

/// Visits the fragments of `band` in wire order with the source each is predicted from; every
/// index counts from the band's first fragment. The encoder and the decoder both walk with it,
/// so they cannot disagree on a neighbourhood.
#[inline(always)]
fn walk(offsets: &[u32], width: usize, band: Range<usize>, v: &mut impl Visit) {
    if width == 0 {
        return;
    }
    let base = offsets[band.start];
    // The first fragment of the last non-empty run visited in the band (`F`).
    let mut first: Option<usize> = None;
    for row in band.clone().step_by(width) {
        // This row's run offsets and the row above's (if it is in the band), from the band's
        // first fragment.
        let cur = &offsets[row..=row + width];
        let up = if row >= band.start + width {
            &offsets[row - width..=row]
        } else {
            &[][..]
        };
        let frags = (cur[0] - base) as usize..(cur[width] - base) as usize;
        if frags.is_empty() {
            continue;
        }
        v.row_start(frags.clone());
        let run = |o: &[u32], x: usize| Nb {
            start: (o[x] - base) as usize,
            len: (o[x + 1] - o[x]) as usize,
        };
        let mut x = 0;
        while x < width {
            if cur[x] == cur[x + 1] {
                // A span of empty pixels: offsets never decrease, so it ends at the pixel
                // before the first offset above this one (sparse frames are mostly such
                // spans).
                x += empty_span(&cur[x..]);
                continue;
            }
            let me = run(cur, x);
            let l = if x > 0 { run(cur, x - 1) } else { NONE };
            let (u, ul) = match (up.is_empty(), x > 0) {
                (false, true) => (run(up, x), run(up, x - 1)),
                (false, false) => (run(up, x), NONE),
                (true, _) => (NONE, NONE),
            };
            let c = me.len;
            if c == l.len && c == u.len && c == ul.len {
                // A span of pixels that, like their left and upper neighbours, all hold `c`
                // fragments: their fragments and those of the row above are contiguous, so
                // fragment `j` of the span is predicted from `j − c`, the `j`-th above and
                // `j − c` above — one `surface` call for the span.
                let count = |o: &[u32], x: usize| o[x + 1] - o[x];
                let mut end = x + 1;
                while end < width && count(cur, end) as usize == c && count(up, end) as usize == c {
                    end += 1;
                }
                v.surface(me.start, l.start, u.start, ul.start, c * (end - x));
                first = Some(me.start + c * (end - x - 1));
                x = end;
                continue;
            }
            if c <= l.len.min(u.len).min(ul.len) {
                v.surface(me.start, l.start, u.start, ul.start, c);
            } else {
                for k in 0..c {
                    v.visit(me.start + k, source(k, me.start, l, u, ul, first));
                }
            }
            first = Some(me.start);
            x += 1;
        }
        v.row_end(frags);
    }
}

/// How many offsets after `o[0]` equal it, in non-decreasing `o`: the pixels of an empty span
/// starting at `o`'s pixel. Short spans (most of those between the inserted runs of a sparse
/// frame) are counted by looking at the next few offsets; a span longer than that is bisected.
/// Bisection alone took a sixth of a sparse frame's encode, its steps unpredictable.
#[inline(always)]
fn empty_span(o: &[u32]) -> usize {
    const LOOK: usize = 8;
    let rest = &o[1..];
    let near = &rest[..rest.len().min(LOOK)];
    match near.iter().position(|&v| v != o[0]) {
        Some(n) => n,
        None => near.len() + rest[near.len()..].partition_point(|&v| v == o[0]),
    }
}

/// The depth prediction from the neighbours' bits: the plane `L + U − UL` (mod 2^32).
#[inline(always)]
fn plane(l: u32, u: u32, ul: u32) -> u32 {
    l.wrapping_add(u).wrapping_sub(ul)
}

#[inline(always)]
fn predict_depth(bits: impl Fn(usize) -> u32, s: Source) -> u32 {
    match s {
        Source::Plane(l, u, ul) => plane(bits(l), bits(u), bits(ul)),
        Source::One(i) => bits(i),
        Source::Zero => 0,
    }
}

/// LOCO-I's median edge detector on one channel: `min(a, b)` if `c ≥ max(a, b)`, `max(a, b)` if
/// `c ≤ min(a, b)`, else `a + b − c`. That is `a + b − c` clamped to `[min(a, b), max(a, b)]`.
/// The reference for [`med4`].
#[cfg(test)]
fn med(a: u8, b: u8, c: u8) -> u8 {
    let (a, b, c) = (i16::from(a), i16::from(b), i16::from(c));
    (a + b - c).clamp(a.min(b), a.max(b)) as u8
}

/// [`med`] on the four channels of three colours, packed little end first (red in the low
/// byte), one channel at a time: where SSE2 is missing, and the reference for [`Lanes::med4`].
#[inline(always)]
fn med4_bytes(a: u32, b: u32, c: u32) -> u32 {
    let (a, b, c) = (a.to_le_bytes(), b.to_le_bytes(), c.to_le_bytes());
    u32::from_le_bytes(std::array::from_fn(|ch| {
        let (a, b, c) = (a[ch], b[ch], c[ch]);
        let (lo, hi) = (a.min(b), a.max(b));
        if c >= hi {
            lo
        } else if c <= lo {
            hi
        } else {
            a.wrapping_add(b).wrapping_sub(c)
        }
    }))
}

/// Where the colour predictor computes: the four channels of a colour in the byte lanes of
/// one SSE2 register on x86_64 (pulp's `V1`; SSE2 is part of every x86_64 CPU), else one
/// channel at a time. Taken once a band.
#[derive(Clone, Copy)]
struct Lanes {
    #[cfg(target_arch = "x86_64")]
    sse2: Option<pulp::x86::V1>,
}

impl Lanes {
    fn new() -> Self {
        Lanes {
            #[cfg(target_arch = "x86_64")]
            sse2: pulp::x86::V1::try_new(),
        }
    }

    /// [`med`] on the four channels of three packed colours at once. Where `c` lies between
    /// `a` and `b`, `a + b − c` lies there too, so wrapping byte arithmetic gives it exactly;
    /// the other two cases are byte compares (`c ≥ max` is `max(c, max) = c`) and selects.
    #[inline(always)]
    fn med4(self, a: u32, b: u32, c: u32) -> u32 {
        self.med4_then(a, b, c, 0, Then::Add)
    }

    /// `value − med4(a, b, c)` in every byte: the encoder's colour residual.
    #[inline(always)]
    fn med4_sub(self, a: u32, b: u32, c: u32, value: u32) -> u32 {
        self.med4_then(a, b, c, value, Then::SubFrom)
    }

    /// `med4(a, b, c) + residual` in every byte: the decoder's colour.
    #[inline(always)]
    fn med4_add(self, a: u32, b: u32, c: u32, residual: u32) -> u32 {
        self.med4_then(a, b, c, residual, Then::Add)
    }

    #[inline(always)]
    fn med4_then(self, a: u32, b: u32, c: u32, x: u32, then: Then) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if let Some(s) = self.sse2 {
            let (a, b, c, x) = (to_lanes(a), to_lanes(b), to_lanes(c), to_lanes(x));
            return from_lanes(med4_in_lanes(s, a, b, c, x, then));
        }
        let m = med4_bytes(a, b, c);
        match then {
            Then::Add => add_bytes(m, x),
            Then::SubFrom => sub_bytes(x, m),
        }
    }
}

/// A packed colour in the low four bytes of an SSE2 register.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn to_lanes(x: u32) -> pulp::u8x16 {
    pulp::bytemuck::cast::<[u32; 4], pulp::u8x16>([x, 0, 0, 0])
}

/// The packed colour in the low four bytes of `v`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn from_lanes(v: pulp::u8x16) -> u32 {
    pulp::bytemuck::cast::<pulp::u8x16, [u32; 4]>(v)[0]
}

/// [`Lanes::med4_then`] on colours held in SSE2 registers (their low four bytes), so that a
/// dependency chain of predictions stays in the vector registers.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn med4_in_lanes(
    s: pulp::x86::V1,
    a: pulp::u8x16,
    b: pulp::u8x16,
    c: pulp::u8x16,
    x: pulp::u8x16,
    then: Then,
) -> pulp::u8x16 {
    use pulp::bytemuck::cast;
    use pulp::{m8x16, u8x16};
    let (lo, hi) = (s.min_u8x16(a, b), s.max_u8x16(a, b));
    let between = s.wrapping_sub_u8x16(s.wrapping_add_u8x16(a, b), c);
    let mask = |m: m8x16| cast::<m8x16, u8x16>(m);
    let above = mask(s.cmp_eq_u8x16(s.max_u8x16(c, hi), c));
    let below = mask(s.cmp_eq_u8x16(s.min_u8x16(c, lo), c));
    let pick = s.or_u8x16(s.and_u8x16(below, hi), s.andnot_u8x16(below, between));
    let pick = s.or_u8x16(s.and_u8x16(above, lo), s.andnot_u8x16(above, pick));
    match then {
        Then::Add => s.wrapping_add_u8x16(pick, x),
        Then::SubFrom => s.wrapping_sub_u8x16(x, pick),
    }
}

/// What [`Lanes::med4_then`] does with the prediction.
#[derive(Clone, Copy)]
enum Then {
    /// Adds the residual (decoding).
    Add,
    /// Subtracts it from the value (encoding).
    SubFrom,
}

/// The high bit of every byte.
const HIGH: u32 = 0x8080_8080;

/// `a + b` in each byte, wrapping, with no carry between bytes.
#[inline(always)]
fn add_bytes(a: u32, b: u32) -> u32 {
    ((a & !HIGH) + (b & !HIGH)) ^ ((a ^ b) & HIGH)
}

/// `a − b` in each byte, wrapping, with no borrow between bytes.
#[inline(always)]
fn sub_bytes(a: u32, b: u32) -> u32 {
    ((a | HIGH) - (b & !HIGH)) ^ ((a ^ !b) & HIGH)
}

/// A colour packed little end first: red in the low byte, as the colour planes order it.
#[inline(always)]
fn packed(c: [u8; 4]) -> u32 {
    u32::from_le_bytes(c)
}

#[inline(always)]
fn predict_color(lanes: Lanes, colors: impl Fn(usize) -> u32, s: Source) -> u32 {
    match s {
        Source::Plane(l, u, ul) => lanes.med4(colors(l), colors(u), colors(ul)),
        Source::One(i) => colors(i),
        Source::Zero => 0,
    }
}

#[inline(always)]
fn predict_object(objects: impl Fn(usize) -> u32, s: Source) -> u32 {
    match s {
        // Ids are labels: the left neighbour, not an average.
        Source::Plane(l, _, _) | Source::One(l) => objects(l),
        Source::Zero => 0,
    }
}

/// Zero-run coder of the object residuals, fed with the non-zero ones in fragment order.
struct ZeroRuns<'a> {
    out: &'a mut Vec<u8>,
    /// The fragment after the last non-zero residual.
    next: u64,
}

impl ZeroRuns<'_> {
    /// The non-zero residual `value` of fragment `at`, after every earlier one.
    fn nonzero(&mut self, at: u64, value: u32) {
        put_varint(self.out, (at - self.next) as u32);
        put_varint(self.out, value);
        self.next = at + 1;
    }

    /// Ends the stream of `n` fragments' residuals with the final run.
    fn finish(self, n: u64) {
        put_varint(self.out, (n - self.next) as u32);
    }
}

/// One band's residuals: a contiguous range of every plane, and its non-zero object residuals
/// (band fragment index, residual), in order — ids hardly ever change, so these are few.
struct BandOut<'a> {
    depth: [&'a mut [u8]; 4],
    color: [&'a mut [u8]; 4],
    object: Vec<(u32, u32)>,
}

/// The layout's sections, in wire order.
pub(crate) const SECTIONS: [SectionTag; 4] = [
    SectionTag::Counts,
    SectionTag::Depth,
    SectionTag::Color,
    SectionTag::Object,
];

/// The four uncompressed sections, in wire order ([`SECTIONS`]), into `counts`, `depth`,
/// `color` and `object`, whatever they held: their capacity is reused, and the two planes are
/// not zeroed where they were long enough already, as every byte of them is a residual written
/// here (tested with buffers left over from a larger frame). The
/// bands are predicted in parallel, beside the counts' varints; the bytes are the same for any
/// thread count (tested). The object stream is written from the bands' few non-zero residuals.
pub(crate) fn encode_into(frame: &DeepFrame, [counts, depth, color, object]: [&mut Vec<u8>; 4]) {
    let offsets = frame.offsets();
    let width = frame.width() as usize;
    let pixels = offsets.len() - 1;
    let n = frame.fragment_count();

    let write_counts = || {
        counts.clear();
        counts.reserve(pixels + pixels / 8);
        // Counts below 128 are one varint byte each: a block of pixels whose counts all are
        // is appended as its bytes, one append instead of a varint a pixel.
        const BLOCK: usize = 64;
        let mut bytes = [0u8; BLOCK];
        for o in offsets.chunks(BLOCK).zip(offsets[1..].chunks(BLOCK)) {
            let (from, to) = o;
            let mut long = false;
            for ((b, &a), &z) in bytes.iter_mut().zip(from).zip(to) {
                let c = z - a;
                long |= c >= 0x80;
                *b = c as u8;
            }
            if long {
                for (&a, &z) in from.iter().zip(to) {
                    put_varint(counts, z - a);
                }
            } else {
                counts.extend_from_slice(&bytes[..to.len()]);
            }
        }
    };
    // Not zeroed where a frame before used them: every byte is a residual written below.
    depth.resize(4 * n, 0);
    color.resize(4 * n, 0);
    let residuals = || {
        let (mut d, mut c) = (planes(depth, n), planes(color, n));
        let tasks: Vec<(Range<usize>, BandOut<'_>)> = bands(pixels, width)
            .into_iter()
            .map(|band| {
                let len = (offsets[band.end] - offsets[band.start]) as usize;
                let out = BandOut {
                    depth: d.each_mut().map(|plane| take_front(plane, len)),
                    color: c.each_mut().map(|plane| take_front(plane, len)),
                    object: Vec::new(),
                };
                (band, out)
            })
            .collect();
        let objects: Vec<(u64, Vec<(u32, u32)>)> = tasks
            .into_par_iter()
            .map(|(band, mut out)| {
                let first = u64::from(offsets[band.start]);
                encode_band(frame, band, &mut out);
                (first, out.object)
            })
            .collect();
        object.clear();
        let mut zero_runs = ZeroRuns {
            out: object,
            next: 0,
        };
        for (first, nonzero) in objects {
            for (i, r) in nonzero {
                zero_runs.nonzero(first + u64::from(i), r);
            }
        }
        zero_runs.finish(n as u64);
    };
    rayon::join(write_counts, residuals);
}

/// The four planes of `n` bytes of `v`.
fn planes<T>(v: &mut [T], n: usize) -> [&mut [T]; 4] {
    let (a, rest) = v.split_at_mut(n);
    let (b, rest) = rest.split_at_mut(n);
    let (c, d) = rest.split_at_mut(n);
    [a, b, c, d]
}

/// The first `len` items of `slice`, which keeps the rest.
fn take_front<'a, T>(slice: &mut &'a mut [T], len: usize) -> &'a mut [T] {
    let (head, tail) = std::mem::take(slice).split_at_mut(len);
    *slice = tail;
    head
}

/// The residuals of the fragments of the pixels in `band` into `out`. Never inlined: one call
/// a band, and profiles name it.
#[inline(never)]
fn encode_band(frame: &DeepFrame, band: Range<usize>, out: &mut BandOut<'_>) {
    let offsets = frame.offsets();
    let (lo, hi) = (offsets[band.start] as usize, offsets[band.end] as usize);
    let mut encoder = BandEncoder {
        depths: &frame.depths()[lo..hi],
        colors: &frame.colors()[lo..hi],
        objects: &frame.objects()[lo..hi],
        lanes: Lanes::new(),
        row: 0,
        depth: Vec::new(),
        color: Vec::new(),
        out,
    };
    walk(offsets, frame.width() as usize, band, &mut encoder);
}

/// A band's fragments, and where their residuals go: a row's depth and colour residuals are
/// computed into `depth` and `color` (one `u32` a fragment, indexed from the row's first
/// fragment `row`; small enough to stay in cache), then spread over the byte planes in one
/// pass per row.
struct BandEncoder<'a, 'b> {
    depths: &'a [f32],
    colors: &'a [Rgba8],
    objects: &'a [ObjectId],
    lanes: Lanes,
    row: usize,
    depth: Vec<u32>,
    color: Vec<u32>,
    out: &'a mut BandOut<'b>,
}

impl Visit for BandEncoder<'_, '_> {
    #[inline(always)]
    fn row_start(&mut self, frags: Range<usize>) {
        self.row = frags.start;
        if self.depth.len() < frags.len() {
            self.depth.resize(frags.len(), 0);
            self.color.resize(frags.len(), 0);
        }
    }

    #[inline(always)]
    fn row_end(&mut self, frags: Range<usize>) {
        let n = frags.len();
        let out = &mut *self.out;
        spread_bytes(
            &self.depth[..n],
            out.depth.each_mut().map(|p| &mut p[frags.clone()]),
        );
        spread_bytes(
            &self.color[..n],
            out.color.each_mut().map(|p| &mut p[frags.clone()]),
        );
    }

    #[inline(always)]
    fn surface(&mut self, me: usize, l: usize, u: usize, ul: usize, len: usize) {
        // Spelled out rather than mapped over `[me, l, u, ul]`: the mapped form ran 22 % more
        // instructions in this loop (callgrind, dragon).
        let d = &self.depths;
        let (dm, dl, du, dul) = (
            &d[me..me + len],
            &d[l..l + len],
            &d[u..u + len],
            &d[ul..ul + len],
        );
        let c = &self.colors;
        let (cm, cl, cu, cul) = (
            &c[me..me + len],
            &c[l..l + len],
            &c[u..u + len],
            &c[ul..ul + len],
        );
        let (om, ol) = (&self.objects[me..me + len], &self.objects[l..l + len]);
        let at = me - self.row;
        let dr = &mut self.depth[at..at + len];
        let cr = &mut self.color[at..at + len];
        for k in 0..len {
            let guess = plane(dl[k].to_bits(), du[k].to_bits(), dul[k].to_bits());
            dr[k] = zigzag(dm[k].to_bits().wrapping_sub(guess) as i32);
            let [l, u, ul, m] = [cl[k], cu[k], cul[k], cm[k]].map(|c| packed(c.0));
            cr[k] = self.lanes.med4_sub(l, u, ul, m);
            let r = om[k].0 ^ ol[k].0;
            if r != 0 {
                self.out.object.push(((me + k) as u32, r));
            }
        }
    }

    #[inline(always)]
    fn visit(&mut self, i: usize, s: Source) {
        // The columns read as the decoder holds them: bits, packed colours, u32 ids.
        let bits = |q: usize| self.depths[q].to_bits();
        let color = |q: usize| packed(self.colors[q].0);
        let object = |q: usize| self.objects[q].0;
        let at = i - self.row;
        self.depth[at] = zigzag(bits(i).wrapping_sub(predict_depth(bits, s)) as i32);
        self.color[at] = sub_bytes(color(i), predict_color(self.lanes, color, s));
        let r = object(i) ^ predict_object(object, s);
        if r != 0 {
            self.out.object.push((i as u32, r));
        }
    }
}

/// Byte `j` of every value of `values` (little end first) into `planes[j]`, which are as long.
#[inline(always)]
fn spread_bytes(values: &[u32], planes: [&mut [u8]; 4]) {
    let [p0, p1, p2, p3] = planes;
    let n = values.len();
    let (p0, p1, p2, p3) = (&mut p0[..n], &mut p1[..n], &mut p2[..n], &mut p3[..n]);
    for (j, &v) in values.iter().enumerate() {
        let [b0, b1, b2, b3] = v.to_le_bytes();
        p0[j] = b0;
        p1[j] = b1;
        p2[j] = b2;
        p3[j] = b3;
    }
}

/// The inverse of [`spread_bytes`]: `values[i]` from byte `i` of each plane, then `map`ped.
/// The reference for [`Lanes::gather`].
#[inline(always)]
fn gather_bytes(planes: [&[u8]; 4], values: &mut [u32], map: impl Fn(u32) -> u32) {
    let [p0, p1, p2, p3] = planes;
    let n = values.len();
    let (p0, p1, p2, p3) = (&p0[..n], &p1[..n], &p2[..n], &p3[..n]);
    for (j, v) in values.iter_mut().enumerate() {
        *v = map(u32::from_le_bytes([p0[j], p1[j], p2[j], p3[j]]));
    }
}

/// What [`Lanes::gather`] does to each gathered `u32`.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Gathered {
    /// Keep it (colour residuals).
    AsIs,
    /// Undo the zigzag coding (depth residuals).
    Unzigzag,
}

impl Lanes {
    /// [`gather_bytes`] sixteen values at a time: the four planes' bytes interleaved by two
    /// rounds of unpacking in SSE2 registers (bytes, then byte pairs), the rest one at a time.
    #[inline(always)]
    fn gather(self, planes: [&[u8]; 4], values: &mut [u32], what: Gathered) {
        let n = values.len();
        let planes = planes.map(|p| &p[..n]);
        #[allow(unused_mut, reason = "only x86_64 gathers in lanes first")]
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if let Some(s) = self.sse2 {
            use pulp::bytemuck::cast;
            use std::arch::x86_64::__m128i;
            let e = s.sse2;
            let load = |p: &[u8], at: usize| {
                let mut b = [0u8; 16];
                b.copy_from_slice(&p[at..at + 16]);
                cast::<[u8; 16], __m128i>(b)
            };
            let one = e._mm_set1_epi32(1);
            let zero = e._mm_setzero_si128();
            for (k, out) in values.chunks_exact_mut(16).enumerate() {
                let at = 16 * k;
                let [a, b, c, d] = planes.map(|p| load(p, at));
                let (ab_lo, ab_hi) = (e._mm_unpacklo_epi8(a, b), e._mm_unpackhi_epi8(a, b));
                let (cd_lo, cd_hi) = (e._mm_unpacklo_epi8(c, d), e._mm_unpackhi_epi8(c, d));
                let mut v = [
                    e._mm_unpacklo_epi16(ab_lo, cd_lo),
                    e._mm_unpackhi_epi16(ab_lo, cd_lo),
                    e._mm_unpacklo_epi16(ab_hi, cd_hi),
                    e._mm_unpackhi_epi16(ab_hi, cd_hi),
                ];
                if what == Gathered::Unzigzag {
                    // (v >> 1) ^ −(v & 1)
                    v = v.map(|x| {
                        let sign = e._mm_sub_epi32(zero, e._mm_and_si128(x, one));
                        e._mm_xor_si128(e._mm_srli_epi32::<1>(x), sign)
                    });
                }
                out.copy_from_slice(&cast::<[__m128i; 4], [u32; 16]>(v));
            }
            done = n / 16 * 16;
        }
        let rest = planes.map(|p| &p[done..]);
        match what {
            Gathered::AsIs => gather_bytes(rest, &mut values[done..], |r| r),
            Gathered::Unzigzag => gather_bytes(rest, &mut values[done..], |r| unzigzag(r) as u32),
        }
    }
}

/// Rebuilds the frame from the four decompressed sections (`section_offsets`: where each payload
/// starts in the message, for errors). Lengths were checked against
/// [`SectionTag::decoded_range`] before decompressing.
///
/// The counts (in parallel chunks) and the object stream (in one pass) are read first and
/// checked; then the bands replay their predictors in parallel into the frame's columns, which
/// cannot fail.
pub(crate) fn decode(
    width: u32,
    height: u32,
    fragments: u32,
    sections: &[Vec<u8>],
    section_offsets: &[u64],
    spare: &mut Columns,
) -> Result<DeepFrame, WireError> {
    let [counts, depth, color, object] = sections else {
        return Err(WireError::section(
            "counts",
            section_offsets.first().copied().unwrap_or(0),
            format!("the deep layout has 4 sections, found {}", sections.len()),
        ));
    };
    let at = |i: usize| section_offsets.get(i).copied().unwrap_or(0);
    let pixels = width as usize * height as usize;
    let n = fragments as usize;
    let w = width as usize;

    // Counts first: nothing per fragment is allocated before they add up. They may have been
    // read into `spare.offsets` already (`spare.counted`), while the other sections
    // decompressed.
    let mut offsets = std::mem::take(&mut spare.offsets);
    match spare.counted.take() {
        Some(read) => read?,
        None => decode_counts(counts, pixels, n, at(0), &mut offsets)?,
    }
    if depth.len() != 4 * n || color.len() != 4 * n {
        return Err(WireError::section(
            "depth",
            at(1),
            format!(
                "depth and colour need {} bytes each, found {} and {}",
                4 * n,
                depth.len(),
                color.len()
            ),
        ));
    }
    let nonzero = object_residuals(object, n, at(3))?;

    let (d, c) = (split4(depth, n), split4(color, n));
    let bands = bands(pixels, w);
    // Each band's residuals: its slice of every plane and its non-zero object residuals.
    let mut nonzero = &nonzero[..];
    let residuals: Vec<BandResiduals<'_>> = bands
        .iter()
        .map(|band| {
            let (lo, hi) = (offsets[band.start] as usize, offsets[band.end] as usize);
            let (mine, rest) =
                nonzero.split_at(nonzero.partition_point(|&(i, _)| (i as usize) < hi));
            nonzero = rest;
            BandResiduals {
                depth: d.map(|plane| &plane[lo..hi]),
                color: c.map(|plane| &plane[lo..hi]),
                object: mine,
                first: lo,
            }
        })
        .collect();
    // The bands replay in parallel into the frame's columns (reused ones are only resized:
    // every item is overwritten), each checked by strata-core as soon as it is written.
    let columns = (
        std::mem::take(&mut spare.depth),
        std::mem::take(&mut spare.color),
        std::mem::take(&mut spare.object),
    );
    Ok(DeepFrame::fill_bands(
        width,
        height,
        offsets,
        &bands,
        columns,
        |i, band| decode_band(band, w, &residuals[i]),
    )?)
}

/// The four planes of `n` bytes of `v` (whose length the caller checked).
fn split4(v: &[u8], n: usize) -> [&[u8]; 4] {
    let (a, rest) = v.split_at(n);
    let (b, rest) = rest.split_at(n);
    let (c, d) = rest.split_at(n);
    [a, b, c, d]
}

/// Bytes of the counts section per parallel task.
const COUNTS_CHUNK: usize = 64 * 1024;

/// The run offsets of the `pixels` counts in `bytes` into `offsets`, checked to add up to `n`
/// exactly and to fill the section.
pub(crate) fn decode_counts(
    bytes: &[u8],
    pixels: usize,
    n: usize,
    at: u64,
    offsets: &mut Vec<u32>,
) -> Result<(), WireError> {
    if counts_in_chunks(bytes, pixels, n, offsets, COUNTS_CHUNK) {
        Ok(())
    } else {
        decode_counts_in_order(bytes, pixels, n, at, offsets)
    }
}

/// [`decode_counts`] in parallel over chunks of `chunk` bytes, for a valid section; `false`
/// (and `offsets` in any state) for anything else. A chunk owns the varints that
/// start after the last varint end (a byte below `0x80`) before it, up to where the next
/// chunk's start; a varint has at most four bytes before its last, so looking back five bytes
/// finds it. A first pass counts each chunk's varints and sums its counts; a second, knowing
/// every chunk's first pixel and first offset, writes the offsets. Anything unusual (a
/// malformed varint, counts that do not add up) is left to the one-pass reader, which names
/// the pixel.
fn counts_in_chunks(
    bytes: &[u8],
    pixels: usize,
    n: usize,
    offsets: &mut Vec<u32>,
    chunk: usize,
) -> bool {
    // The section must end with the end of a varint; stray continuation bytes after the last
    // one would otherwise fall between the chunks unread.
    if bytes.last().is_some_and(|&b| b >= 0x80) {
        return false;
    }
    let chunks = bytes.len().div_ceil(chunk);
    // Where the first varint chunk `c` owns starts (`None`: no varint ends in the five bytes
    // before it, which no valid stream has).
    let first = |c: usize| -> Option<usize> {
        let lo = (c * chunk).min(bytes.len());
        let from = lo.saturating_sub(5);
        match bytes[from..lo].iter().rposition(|&b| b < 0x80) {
            Some(i) => Some(from + i + 1),
            None if from == 0 => Some(0),
            None => None,
        }
    };
    let owned = |c: usize| -> Option<Range<usize>> { Some(first(c)?..first(c + 1)?) };
    // Each chunk's (varints, sum of counts), or `None` where the one-pass reader must look.
    let totals: Option<Vec<(usize, u64)>> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let r = owned(c)?;
            let owned = &bytes[r.start..r.end.max(r.start)];
            if let Some(sum) = single_byte_sum(owned) {
                return Some((owned.len(), sum));
            }
            let (mut varints, mut sum) = (0usize, 0u64);
            let ok = varints_of(owned, |v| {
                varints += 1;
                sum += u64::from(v);
            });
            ok.then_some((varints, sum))
        })
        .collect();
    let fits = totals.as_ref().is_some_and(|t| {
        let (varints, sum) = t.iter().fold((0, 0), |(v, s), &(cv, cs)| (v + cv, s + cs));
        varints == pixels && sum == n as u64
    });
    let Some(totals) = totals.filter(|_| fits) else {
        return false;
    };
    // Every offset is written below: a reused buffer is only resized, not zeroed again.
    offsets.resize(pixels + 1, 0);
    offsets[0] = 0;
    let mut rest = &mut offsets[1..];
    let mut base = 0u64;
    let mut tasks = Vec::with_capacity(chunks);
    for (c, &(varints, sum)) in totals.iter().enumerate() {
        tasks.push((c, base, take_front(&mut rest, varints)));
        base += sum;
    }
    tasks.into_par_iter().for_each(|(c, base, out)| {
        // The first pass read exactly `out.len()` varints here without error.
        let Some(r) = owned(c) else { return };
        let owned = &bytes[r.start..r.end.max(r.start)];
        if owned.len() == out.len() {
            // Every count of the chunk is one byte: a plain running sum. The offsets fit a
            // `u32`: they end at the header's fragment count.
            let mut total = base as u32;
            for (o, &b) in out.iter_mut().zip(owned) {
                total = total.wrapping_add(u32::from(b));
                *o = total;
            }
            return;
        }
        let mut total = base;
        let mut o = out.iter_mut();
        varints_of(owned, |v| {
            total += u64::from(v);
            if let Some(o) = o.next() {
                *o = total as u32;
            }
        });
    });
    true
}

/// The sum of `bytes` if every one of them is a whole varint (below `0x80`: almost every
/// count section is made of such), in two passes the compiler turns into vector code; `None`
/// otherwise.
fn single_byte_sum(bytes: &[u8]) -> Option<u64> {
    // Slices of at most 2^24 bytes below 128 sum within a `u32`.
    let mut sum = 0u64;
    for part in bytes.chunks(1 << 24) {
        if part.iter().fold(0u8, |m, &b| m | b) >= 0x80 {
            return None;
        }
        sum += u64::from(part.iter().map(|&b| u32::from(b)).sum::<u32>());
    }
    Some(sum)
}

/// Calls `each` with every varint of `bytes`, which must hold whole varints of at most 32
/// bits; `false` if it does not (what was passed on before then is unspecified).
#[inline(always)]
fn varints_of(bytes: &[u8], mut each: impl FnMut(u32)) -> bool {
    let (mut value, mut shift) = (0u32, 0u32);
    for &b in bytes {
        if shift == 0 && b < 0x80 {
            // Almost every count is one byte.
            each(u32::from(b));
            continue;
        }
        if shift == 28 && b > 0x0f {
            return false;
        }
        value |= u32::from(b & 0x7f) << shift;
        if b < 0x80 {
            each(value);
            (value, shift) = (0, 0);
        } else {
            shift += 7;
        }
    }
    shift == 0
}

/// [`decode_counts`] in one pass, naming the pixel of the first problem.
fn decode_counts_in_order(
    bytes: &[u8],
    pixels: usize,
    n: usize,
    at: u64,
    offsets: &mut Vec<u32>,
) -> Result<(), WireError> {
    offsets.clear();
    offsets.reserve(pixels + 1);
    offsets.push(0u32);
    let mut total: u64 = 0;
    let mut pos = 0usize;
    for p in 0..pixels {
        let c = match bytes.get(pos) {
            // Almost every count fits one byte.
            Some(&b) if b < 0x80 => {
                pos += 1;
                u32::from(b)
            }
            _ => {
                let mut reader = Reader::new(&bytes[pos..], 0);
                let c = reader
                    .varint("count")
                    .map_err(|e| WireError::section("counts", at, format!("pixel {p}: {e}")))?;
                pos += reader.offset() as usize;
                c
            }
        };
        total += u64::from(c);
        if total > n as u64 {
            return Err(WireError::section(
                "counts",
                at,
                format!(
                    "the counts up to pixel {p} add up to {total}, more than the {n} fragments the header announces"
                ),
            ));
        }
        offsets.push(total as u32);
    }
    if total != n as u64 {
        return Err(WireError::section(
            "counts",
            at,
            format!("the counts add up to {total}, the header announces {n} fragments"),
        ));
    }
    if pos != bytes.len() {
        return Err(WireError::section(
            "counts",
            at,
            format!("{} bytes left after the {pixels} counts", bytes.len() - pos),
        ));
    }
    Ok(())
}

/// The non-zero object residuals of the zero-run stream, as (fragment index, residual) in
/// fragment order, checked to cover exactly `n` fragments.
fn object_residuals(stream: &[u8], n: usize, at: u64) -> Result<Vec<(u32, u32)>, WireError> {
    let error = |e: WireError| WireError::section("object", at, format!("zero-run stream: {e}"));
    let mut ids = Reader::new(stream, 0);
    let mut nonzero = Vec::new();
    let mut next: u64 = 0;
    loop {
        next += u64::from(ids.varint("run").map_err(error)?);
        if next >= n as u64 {
            break;
        }
        nonzero.push((next as u32, ids.varint("value").map_err(error)?));
        next += 1;
    }
    if next != n as u64 {
        return Err(WireError::section(
            "object",
            at,
            format!(
                "the zero-run stream covers more than the {n} fragments ({} zeros too many)",
                next - n as u64
            ),
        ));
    }
    if ids.remaining() != 0 {
        return Err(WireError::section(
            "object",
            at,
            format!(
                "{} bytes left after the zero-run stream of the {n} fragments",
                ids.remaining()
            ),
        ));
    }
    Ok(nonzero)
}

/// What one band decodes from: its range of every residual plane and its non-zero object
/// residuals (indexed from the frame's first fragment; `first` is the band's).
struct BandResiduals<'a> {
    depth: [&'a [u8]; 4],
    color: [&'a [u8]; 4],
    object: &'a [(u32, u32)],
    first: usize,
}

/// Replays the predictors of `band` into its columns. Never inlined: one call a band, and
/// profiles name it.
#[inline(never)]
fn decode_band(band: FillBand<'_>, width: usize, r: &BandResiduals<'_>) {
    let mut decoder = BandDecoder {
        depth: r.depth,
        color: r.color,
        nonzero: r.object,
        first: r.first,
        lanes: Lanes::new(),
        row: 0,
        depth_residuals: Vec::new(),
        color_residuals: Vec::new(),
        bits: band.depth,
        colors: band.color,
        objects: band.object,
    };
    walk(band.offsets, width, band.pixels, &mut decoder);
}

/// A band's residuals, and its columns being rebuilt. A row's depth and colour residuals are
/// gathered from the byte planes first, in one pass, into `depth_residuals` and
/// `color_residuals` (indexed from the row's first fragment `row`). Depths are handled as
/// their bits and colours as packed `u32`s: the column types convert for free.
struct BandDecoder<'a> {
    depth: [&'a [u8]; 4],
    color: [&'a [u8]; 4],
    /// The band's non-zero object residuals not used yet (fragment indices from the frame's
    /// first fragment; `first` is the band's).
    nonzero: &'a [(u32, u32)],
    first: usize,
    lanes: Lanes,
    row: usize,
    /// Signed (unzigzagged) depth residuals of the row, as `u32`.
    depth_residuals: Vec<u32>,
    /// Packed colour residuals of the row.
    color_residuals: Vec<u32>,
    bits: &'a mut [f32],
    colors: &'a mut [Rgba8],
    objects: &'a mut [ObjectId],
}

impl BandDecoder<'_> {
    /// The object residual of fragment `i` (the next non-zero one, or 0).
    #[inline(always)]
    fn object_residual(&mut self, i: usize) -> u32 {
        match self.nonzero.first() {
            Some(&(at, v)) if at as usize - self.first == i => {
                self.nonzero = &self.nonzero[1..];
                v
            }
            _ => 0,
        }
    }
}

impl BandDecoder<'_> {
    /// [`Visit::surface`] for fragments `me..me + len` that are pixels of `C` fragments each
    /// (`len` a multiple of `C`), whose left neighbours are the `C` fragments before each:
    /// layer `j` of a pixel is predicted from layer `j` of the pixel before it, held in
    /// `left[j]`. The same arithmetic as the general loop, so the same values.
    #[inline(always)]
    fn span<const C: usize>(&mut self, me: usize, u: usize, ul: usize, len: usize) {
        let at = me - self.row;
        let dr = &self.depth_residuals[at..at + len];
        let cr = &self.color_residuals[at..at + len];
        // The row above ends before the left neighbours start.
        let (done, w) = self.bits.split_at_mut(me);
        let (du, dul, w) = (&done[u..u + len], &done[ul..ul + len], &mut w[..len]);
        let mut left: [u32; C] = std::array::from_fn(|j| done[me - C + j].to_bits());
        for (((out, up), up_left), r) in w
            .chunks_exact_mut(C)
            .zip(du.chunks_exact(C))
            .zip(dul.chunks_exact(C))
            .zip(dr.chunks_exact(C))
        {
            for j in 0..C {
                left[j] = plane(left[j], up[j].to_bits(), up_left[j].to_bits()).wrapping_add(r[j]);
                out[j] = f32::from_bits(left[j]);
            }
        }
        let (done, w) = self.colors.split_at_mut(me);
        let (cu, cul, w) = (&done[u..u + len], &done[ul..ul + len], &mut w[..len]);
        let chunks = w
            .chunks_exact_mut(C)
            .zip(cu.chunks_exact(C))
            .zip(cul.chunks_exact(C))
            .zip(cr.chunks_exact(C));
        let left: [u32; C] = std::array::from_fn(|j| packed(done[me - C + j].0));
        #[cfg(target_arch = "x86_64")]
        if let Some(s) = self.lanes.sse2 {
            // The left colours stay in vector registers from one pixel to the next.
            let mut left = left.map(to_lanes);
            for (((out, up), up_left), r) in chunks {
                for j in 0..C {
                    let (u, ul) = (to_lanes(packed(up[j].0)), to_lanes(packed(up_left[j].0)));
                    left[j] = med4_in_lanes(s, left[j], u, ul, to_lanes(r[j]), Then::Add);
                    out[j] = Rgba8(from_lanes(left[j]).to_le_bytes());
                }
            }
            return self.surface_objects(me, me - C, len);
        }
        let mut left = left;
        for (((out, up), up_left), r) in chunks {
            for j in 0..C {
                left[j] = self
                    .lanes
                    .med4_add(left[j], packed(up[j].0), packed(up_left[j].0), r[j]);
                out[j] = Rgba8(left[j].to_le_bytes());
            }
        }
        self.surface_objects(me, me - C, len);
    }

    /// The object ids of the fragments `me..me + len`, fragment `me + k` predicted from
    /// `l + k` (its left neighbour's layer; in a span, a fragment of this call).
    #[inline(always)]
    fn surface_objects(&mut self, me: usize, l: usize, len: usize) {
        let off = me - l;
        let w = &mut self.objects[l..me + len];
        if self
            .nonzero
            .first()
            .is_none_or(|&(at, _)| at as usize - self.first >= me + len)
        {
            // No object changes in the span (the common case): each id is its left one's.
            for k in 0..len {
                w[off + k] = w[k];
            }
        } else {
            for k in 0..len {
                let r = self.object_residual(me + k);
                self.objects[me + k] = ObjectId(self.objects[l + k].0 ^ r);
            }
        }
    }
}

impl Visit for BandDecoder<'_> {
    #[inline(always)]
    fn row_start(&mut self, frags: Range<usize>) {
        self.row = frags.start;
        let n = frags.len();
        if self.depth_residuals.len() < n {
            self.depth_residuals.resize(n, 0);
            self.color_residuals.resize(n, 0);
        }
        self.lanes.gather(
            self.depth.map(|p| &p[frags.clone()]),
            &mut self.depth_residuals[..n],
            Gathered::Unzigzag,
        );
        self.lanes.gather(
            self.color.map(|p| &p[frags.clone()]),
            &mut self.color_residuals[..n],
            Gathered::AsIs,
        );
    }

    #[inline(always)]
    fn row_end(&mut self, _frags: Range<usize>) {}

    #[inline(always)]
    fn surface(&mut self, me: usize, l: usize, u: usize, ul: usize, len: usize) {
        // A span of pixels of 1 to 4 fragments each: the left neighbours' values are carried
        // in registers, fragment to fragment of a layer, instead of being stored and loaded
        // again (a store-to-load round trip on every step of the row's dependency chain).
        match me - l {
            1 => return self.span::<1>(me, u, ul, len),
            2 if len.is_multiple_of(2) => return self.span::<2>(me, u, ul, len),
            3 if len.is_multiple_of(3) => return self.span::<3>(me, u, ul, len),
            4 if len.is_multiple_of(4) => return self.span::<4>(me, u, ul, len),
            _ => {}
        }
        // `w` runs from the left neighbour of the first fragment to the last: fragment `k` is
        // `w[me − l + k]`, its left neighbour `w[k]` (written by this loop already, in a span).
        // The row above lies before `l`.
        let (at, off) = (me - self.row, me - l);
        let dr = &self.depth_residuals[at..at + len];
        let cr = &self.color_residuals[at..at + len];
        let (done, w) = self.bits.split_at_mut(l);
        let (du, dul, w) = (&done[u..u + len], &done[ul..ul + len], &mut w[..off + len]);
        for k in 0..len {
            let [left, up, up_left] = [w[k], du[k], dul[k]].map(f32::to_bits);
            w[off + k] = f32::from_bits(plane(left, up, up_left).wrapping_add(dr[k]));
        }
        let (done, w) = self.colors.split_at_mut(l);
        let (cu, cul, w) = (&done[u..u + len], &done[ul..ul + len], &mut w[..off + len]);
        for k in 0..len {
            let [left, up, up_left] = [w[k], cu[k], cul[k]].map(|c| packed(c.0));
            w[off + k] = Rgba8(self.lanes.med4_add(left, up, up_left, cr[k]).to_le_bytes());
        }
        self.surface_objects(me, l, len);
    }

    #[inline(always)]
    fn visit(&mut self, i: usize, s: Source) {
        let at = i - self.row;
        let bits = &mut *self.bits;
        let guess = predict_depth(|q| bits[q].to_bits(), s);
        bits[i] = f32::from_bits(guess.wrapping_add(self.depth_residuals[at]));
        let colors = &mut *self.colors;
        let guess = predict_color(self.lanes, |q| packed(colors[q].0), s);
        colors[i] = Rgba8(add_bytes(guess, self.color_residuals[at]).to_le_bytes());
        let residual = self.object_residual(i);
        let objects = &mut *self.objects;
        objects[i] = ObjectId(predict_object(|q| objects[q].0, s) ^ residual);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `empty_span` against bisection of the whole rest, on spans shorter than, as long as and
    /// longer than the offsets it looks at before bisecting, ending inside the slice and at its
    /// end.
    #[test]
    fn empty_spans_are_counted_as_bisection_counts_them() {
        for span in 1..20usize {
            for tail in 0..3usize {
                let mut o = vec![5u32; span + 1];
                o.extend((0..tail as u32).map(|i| 6 + i));
                let bisected = o[1..].partition_point(|&v| v == o[0]);
                assert_eq!(empty_span(&o), bisected, "span {span}, tail {tail}");
                assert_eq!(bisected, span);
            }
        }
    }

    /// The four sections of `frame`, in fresh buffers.
    fn encode(frame: &DeepFrame) -> Vec<(SectionTag, Vec<u8>)> {
        let mut raw: [Vec<u8>; 4] = Default::default();
        let [a, b, c, d] = &mut raw;
        encode_into(frame, [a, b, c, d]);
        SECTIONS.into_iter().zip(raw).collect()
    }

    #[test]
    fn med4_is_med_in_every_channel() {
        let lanes = Lanes::new();
        #[cfg(target_arch = "x86_64")]
        assert!(lanes.sse2.is_some(), "SSE2 is part of x86_64");
        // Every (a, b, c) of one channel, in each of the four lanes, with the other lanes
        // holding other values.
        for a in 0..=255u8 {
            for b in 0..=255u8 {
                for c in (0..=255u8).step_by(3).chain([254, 255]) {
                    let pack = |x: u8, ch: usize| {
                        let mut v = [a ^ 0x5a, b.wrapping_mul(3), c ^ 0xa5, 77];
                        v[ch] = x;
                        u32::from_le_bytes(v)
                    };
                    for ch in 0..4 {
                        let (a4, b4, c4) = (pack(a, ch), pack(b, ch), pack(c, ch));
                        let want = med(a, b, c);
                        assert_eq!(med4_bytes(a4, b4, c4).to_le_bytes()[ch], want);
                        let got = lanes.med4(a4, b4, c4).to_le_bytes()[ch];
                        assert_eq!(got, want, "{a} {b} {c} in lane {ch}");
                    }
                }
            }
        }
    }

    #[test]
    fn gathering_in_lanes_equals_gathering_byte_by_byte() {
        // Lengths around the 16-value blocks, planes of other lengths, both maps, with the
        // lanes the CPU has and with the one-at-a-time fallback.
        let mut x = 0x0123_4567u32;
        let mut byte = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        };
        let planes: Vec<Vec<u8>> = (0..4).map(|_| (0..80).map(|_| byte()).collect()).collect();
        let planes = [
            &planes[0][..],
            &planes[1][..],
            &planes[2][..],
            &planes[3][..],
        ];
        let fallback = Lanes {
            #[cfg(target_arch = "x86_64")]
            sse2: None,
        };
        for lanes in [Lanes::new(), fallback] {
            for n in [0, 1, 15, 16, 17, 31, 32, 33, 63, 64, 79] {
                for (what, map) in [
                    (Gathered::AsIs, (|r| r) as fn(u32) -> u32),
                    (Gathered::Unzigzag, |r| unzigzag(r) as u32),
                ] {
                    let mut want = vec![0u32; n];
                    gather_bytes(planes, &mut want, map);
                    let mut got = vec![7u32; n];
                    lanes.gather(planes, &mut got, what);
                    assert_eq!(got, want, "{n} values, {what:?}");
                }
            }
        }
    }

    #[test]
    fn byte_lanes_add_and_subtract_without_carries() {
        let mut x = 0x1234_5678u32;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let (a, b) = (x, x.rotate_left(11) ^ 0x8080_7f01);
            let (ab, bb) = (a.to_le_bytes(), b.to_le_bytes());
            let sum: [u8; 4] = std::array::from_fn(|i| ab[i].wrapping_add(bb[i]));
            let diff: [u8; 4] = std::array::from_fn(|i| ab[i].wrapping_sub(bb[i]));
            assert_eq!(add_bytes(a, b).to_le_bytes(), sum, "{a:08x} + {b:08x}");
            assert_eq!(sub_bytes(a, b).to_le_bytes(), diff, "{a:08x} - {b:08x}");
        }
        for (a, b) in [
            (0, 0xffff_ffff),
            (0xffff_ffff, 0xffff_ffff),
            (0x8080_8080, 0x8080_8080),
        ] {
            assert_eq!(sub_bytes(add_bytes(a, b), b), a);
        }
    }

    #[test]
    fn med_is_the_loco_i_predictor() {
        assert_eq!(med(10, 20, 25), 10); // UL above both: the smaller
        assert_eq!(med(10, 20, 5), 20); // UL below both: the larger
        assert_eq!(med(10, 20, 12), 18); // in between: the plane
        assert_eq!(med(255, 255, 0), 255);
        assert_eq!(med(0, 255, 254), 1);
    }

    /// A frame with empty rows, empty pixels inside bands, deep runs and several objects.
    fn patchy_frame(width: u32, height: u32) -> DeepFrame {
        let lists: Vec<Vec<strata_core::Fragment>> = (0..width * height)
            .map(|p| {
                let (x, y) = (p % width, p / width);
                let count = if y % 5 == 2 || (x + y) % 7 == 0 {
                    0
                } else {
                    (x * 3 + y) % 4
                };
                (0..count)
                    .map(|k| strata_core::Fragment {
                        depth: 0.1 + 0.2 * k as f32 + 0.001 * x as f32 + 0.0007 * y as f32,
                        color: Rgba8([(x * 7) as u8, (y * 5) as u8, (k * 60) as u8, 128]),
                        object: ObjectId(1 + (x / 9 + k) % 3),
                    })
                    .collect()
            })
            .collect();
        DeepFrame::from_pixel_lists(width, height, &lists).expect("a valid frame")
    }

    /// Planar layers over most of the frame (the decoders' fast path: every layer has all
    /// three neighbours) with hashed colours and a few objects, and ragged edges.
    fn surfaces_frame(width: u32, height: u32) -> DeepFrame {
        let hash = |v: u32| v.wrapping_mul(0x9e37_79b9).rotate_left(13) ^ v;
        let lists: Vec<Vec<strata_core::Fragment>> = (0..width * height)
            .map(|p| {
                let (x, y) = (p % width, p / width);
                let count = match (x + 2 * y) % 29 {
                    0 => 0,
                    1 | 2 => 5,
                    _ if x > width / 2 => 3,
                    _ => 2,
                };
                (0..count)
                    .map(|k| {
                        let h = hash(p * 8 + k);
                        strata_core::Fragment {
                            depth: 0.05 + 0.15 * k as f32 + 0.0011 * x as f32 + 0.0005 * y as f32,
                            color: Rgba8([
                                (x * 2 + k * 40) as u8,
                                (y * 3) as u8 ^ (h & 3) as u8,
                                (h >> 8) as u8,
                                if k == 0 {
                                    255
                                } else {
                                    100 + (h >> 24) as u8 % 50
                                },
                            ]),
                            object: ObjectId(1 + k + u32::from(x > width / 3)),
                        }
                    })
                    .collect()
            })
            .collect();
        DeepFrame::from_pixel_lists(width, height, &lists).expect("a valid frame")
    }

    fn decode_sections(
        frame: &DeepFrame,
        sections: Vec<(SectionTag, Vec<u8>)>,
    ) -> Result<DeepFrame, WireError> {
        let sections: Vec<Vec<u8>> = sections.into_iter().map(|(_, bytes)| bytes).collect();
        decode(
            frame.width(),
            frame.height(),
            frame.fragment_count() as u32,
            &sections,
            &[0; 4],
            &mut Columns::default(),
        )
    }

    #[test]
    fn any_thread_count_gives_the_same_bytes_and_frame() {
        // Two full bands and a partial one.
        let frame = patchy_frame(37, 2 * BAND_ROWS as u32 + 9);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("a pool")
            .install(|| encode(&frame));
        for threads in [2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a pool");
            assert_eq!(pool.install(|| encode(&frame)), one, "{threads} threads");
            let decoded = pool
                .install(|| decode_sections(&frame, one.clone()))
                .expect("decodes");
            assert_eq!(decoded, frame, "{threads} threads");
        }
    }

    #[test]
    fn a_band_is_predicted_from_its_own_pixels_only() {
        // Changing every fragment of the first band (but not the counts) leaves every residual
        // of the second band as it was: its first row has no upper neighbours and its first
        // fragment no earlier run to fall back on.
        let (w, h) = (37u32, 2 * BAND_ROWS as u32);
        let frame = patchy_frame(w, h);
        let lists: Vec<Vec<strata_core::Fragment>> = (0..(w * h) as usize)
            .map(|p| {
                let mut run: Vec<strata_core::Fragment> = frame.run(p).iter().collect();
                if p < BAND_ROWS * w as usize {
                    for f in &mut run {
                        f.depth = f.depth * 0.61 + 0.013;
                        f.color = Rgba8([1, 2, 3, 4]);
                        f.object = ObjectId(77);
                    }
                }
                run
            })
            .collect();
        let changed = DeepFrame::from_pixel_lists(w, h, &lists).expect("a valid frame");
        let split = frame.offsets()[BAND_ROWS * w as usize] as usize;
        let n = frame.fragment_count();
        assert!(split > 0 && split < n, "both bands hold fragments");
        let (a, b) = (encode(&frame), encode(&changed));
        for plane in 0..4 {
            let band2 = plane * n + split..(plane + 1) * n;
            assert_eq!(
                a[1].1[band2.clone()],
                b[1].1[band2.clone()],
                "depth plane {plane}"
            );
            assert_eq!(a[2].1[band2.clone()], b[2].1[band2], "colour plane {plane}");
        }
        let band1 = |s: &[u8]| {
            (0..4)
                .flat_map(|p| s[p * n..p * n + split].to_vec())
                .collect::<Vec<u8>>()
        };
        assert_ne!(
            band1(&a[1].1),
            band1(&b[1].1),
            "the first band's depths changed"
        );
        assert_ne!(
            band1(&a[2].1),
            band1(&b[2].1),
            "the first band's colours changed"
        );
        assert_eq!(decode_sections(&changed, b).expect("decodes"), changed);
    }

    #[test]
    fn counts_read_in_chunks_equal_counts_read_in_order() {
        // Counts of 1 to 5 varint bytes, so that chunk boundaries fall inside varints.
        let counts: Vec<u32> = (0..997u32)
            .map(|i| match i % 7 {
                0 => 0,
                1 => 127,
                2 => 128,
                3 => 20_000,
                4 => 3_000_000,
                5 => 1 << 29,
                _ => i,
            })
            .collect();
        let mut bytes = Vec::new();
        for &c in &counts {
            put_varint(&mut bytes, c);
        }
        let n = counts.iter().map(|&c| u64::from(c)).sum::<u64>() as usize;
        let mut expected = Vec::new();
        decode_counts_in_order(&bytes, counts.len(), n, 0, &mut expected).expect("valid");
        assert_eq!(expected.len(), counts.len() + 1);
        for chunk in [1, 2, 3, 4, 5, 6, 7, 64, 1 << 20] {
            let mut got = vec![9; 3];
            assert!(
                counts_in_chunks(&bytes, counts.len(), n, &mut got, chunk),
                "{chunk}"
            );
            assert_eq!(got, expected, "chunks of {chunk} bytes");
        }
        // And the errors are the one-pass reader's, wherever the chunks fall.
        // A varint's last byte made a continuation byte: two varints become one.
        let mut bad = bytes.clone();
        let end = (500..bytes.len())
            .find(|&i| bytes[i] < 0x80)
            .expect("a varint end");
        bad[end] |= 0x80;
        for chunk in [1, 3, 64] {
            assert!(!counts_in_chunks(
                &bad,
                counts.len(),
                n,
                &mut Vec::new(),
                chunk
            ));
        }
        assert!(decode_counts(&bad, counts.len(), n, 0, &mut Vec::new()).is_err());
        assert!(!counts_in_chunks(
            &bytes,
            counts.len(),
            n + 1,
            &mut Vec::new(),
            3
        ));
        assert!(!counts_in_chunks(
            &bytes,
            counts.len() - 1,
            n,
            &mut Vec::new(),
            3
        ));
    }

    #[test]
    fn malformed_counts_and_object_streams_are_errors() {
        let frame = patchy_frame(37, 29);
        let good = encode(&frame);
        let n = frame.fragment_count();
        let with = |i: usize, bytes: Vec<u8>| {
            let mut s = good.clone();
            s[i].1 = bytes;
            decode_sections(&frame, s)
                .expect_err("malformed")
                .to_string()
        };
        // A count too many, one too few, a truncated varint, a byte left over.
        let mut more = good[0].1.clone();
        more[0] += 1;
        assert!(with(0, more).contains("more than the"), "count too many");
        let mut fewer = good[0].1.clone();
        let last = fewer
            .iter()
            .rposition(|&b| b > 0)
            .expect("a non-zero count");
        fewer[last] -= 1;
        assert!(with(0, fewer).contains("add up to"), "count too few");
        let mut truncated = good[0].1.clone();
        *truncated.last_mut().expect("counts") = 0x80;
        assert!(with(0, truncated).contains("pixel"), "truncated varint");
        let mut extra = good[0].1.clone();
        extra.push(0);
        assert!(with(0, extra).contains("bytes left"), "trailing byte");
        let mut unfinished = good[0].1.clone();
        unfinished.push(0x80);
        assert!(
            with(0, unfinished).contains("bytes left"),
            "trailing continuation byte"
        );
        // Object streams: a final run past the end, a missing final run, trailing bytes.
        let mut long = Vec::new();
        put_varint(&mut long, n as u32 + 1);
        assert!(
            with(3, long).contains("covers more than"),
            "run past the end"
        );
        let mut short = Vec::new();
        put_varint(&mut short, 0);
        put_varint(&mut short, 5);
        assert!(with(3, short).contains("object"), "no final run");
        let mut trailing = good[3].1.clone();
        trailing.push(0);
        assert!(with(3, trailing).contains("bytes left"), "trailing byte");
    }

    #[test]
    fn the_counts_section_is_a_varint_a_pixel_in_blocks_with_long_counts_too() {
        // Long counts (two varint bytes) in some blocks of 64 pixels, at a block's first and
        // last pixel and inside one, and none in others; a last block that is not full.
        let (width, height) = (67u32, 3u32);
        let long = [0usize, 63, 64 + 17, 128 + 63];
        let lists: Vec<Vec<strata_core::Fragment>> = (0..(width * height) as usize)
            .map(|p| {
                let count = if long.contains(&p) { 130 + p } else { p % 3 };
                (0..count)
                    .map(|k| strata_core::Fragment {
                        depth: 0.5 + 0.001 * k as f32,
                        color: Rgba8([p as u8, k as u8, 3, 255]),
                        object: ObjectId(1),
                    })
                    .collect()
            })
            .collect();
        let frame = DeepFrame::from_pixel_lists(width, height, &lists).expect("a valid frame");
        let mut expected = Vec::new();
        for c in frame.counts() {
            put_varint(&mut expected, c);
        }
        let sections = encode(&frame);
        assert_eq!(sections[0].0, SectionTag::Counts);
        assert_eq!(sections[0].1, expected);
        assert_eq!(&decode_sections(&frame, sections).expect("decodes"), &frame);
    }

    /// FNV-1a over every section's tag and bytes.
    fn fingerprint(sections: &[(SectionTag, Vec<u8>)]) -> u64 {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for (tag, bytes) in sections {
            for &b in std::iter::once(&(*tag as u8)).chain(bytes) {
                h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
        }
        h
    }

    #[test]
    fn the_layout_is_pinned() {
        // The deep layout is a wire format: any change to its bytes is a new version. These
        // fingerprints were taken from the first implementation (per-fragment sources, byte
        // planes written in place); a faster predictor must give the same bytes.
        let frames = [
            (
                patchy_frame(37, 2 * BAND_ROWS as u32 + 9),
                0xf7cd68cb4d3b595c,
            ),
            (patchy_frame(1, 5), 0xdcbd504ce76ddceb),
            (patchy_frame(130, 3), 0xfd262f37642182ef),
            (
                surfaces_frame(83, BAND_ROWS as u32 + 21),
                0x06f0ee37cbb48266,
            ),
        ];
        for (frame, pinned) in &frames {
            let sections = encode(frame);
            assert_eq!(
                fingerprint(&sections),
                *pinned,
                "{}x{}",
                frame.width(),
                frame.height()
            );
            assert_eq!(&decode_sections(frame, sections).expect("decodes"), frame);
        }
    }

    #[test]
    fn zero_runs_end_with_the_final_run() {
        // Residuals 0, 0, 5, 0, 300, 0, 0, 0.
        let mut out = Vec::new();
        let mut z = ZeroRuns {
            out: &mut out,
            next: 0,
        };
        z.nonzero(2, 5);
        z.nonzero(4, 300);
        z.finish(8);
        assert_eq!(out, [2, 5, 1, 0xac, 0x02, 3]);
    }
}
