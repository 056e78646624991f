//! Shading a batch's micro-triangles together, `L` samples at a time (16 with AVX-512, else 8).
//!
//! [`Batch::classify`](crate::coverage::Batch::classify) leaves each micro-triangle's coverage
//! mask in its lane. Shading those samples one at a time ([`crate::scan::shade_small`]) took
//! about a hundred scalar instructions a fragment, the largest part of setup on a dense mesh
//! (callgrind: 100 M of the 255 M setup instructions of a full-dragon frame). Setup therefore
//! shades a batch's covered samples `L` at a time, in **passes** of the same arithmetic, where
//! `L` is the lane width of the instruction set setup runs on ([`crate::lanes`]: a batch of `L`
//! triangles, a lane array one register), and a sample's lane is filled in one of two ways:
//!
//! - **Packed** (where the CPU has a one-instruction lane permute: AVX2 at 8 lanes, AVX-512 at
//!   16): the batch's samples one after the other in primitive order — every sample of lane 0's
//!   triangle, then of lane 1's, … — `L` a pass. Each pass finds every output's triangle and
//!   sample without a branch (the number of lanes whose samples end at or before it; its rank
//!   within them) and moves each triangle value into the output's lane with one
//!   `vpermd`/`vpermps` ([`Permute`]; 35 for a lit object, 17 for an unlit one). On the full
//!   dragon a batch of eight has 7.6 covered samples on average, 4.4 covering micro-triangles
//!   and a most-covered lane of 2.5 samples, so a batch takes 1–2 passes where rounds took 2.5,
//!   each mostly empty; a batch of sixteen has twice the samples in passes twice as wide.
//! - **Rounds** (elsewhere): round `r` takes the `r`-th covered sample of every lane (its lowest
//!   remaining mask bit), so a batch needs as many rounds as its most-covered lane has samples;
//!   lanes with fewer samples, or no micro-triangle, compute values that are marked not kept.
//!
//! Packed, a batch's outputs are its fragments in primitive order, so a batch of micro-triangles
//! alone hands them to the strips in one loop ([`MicroShader::for_each_fragment`]). Measured
//! against rounds on the full dragon (one thread, AMD EPYC with AVX-512), setup took 8 % less
//! time with packed passes and another 4 % less with the one loop; building the list of samples
//! with a branch on each lane's count had cost more than the passes saved (mispredictions), and
//! so did a permuted vertex block built in memory (store-to-load stalls).
//!
//! # Layout
//!
//! Structure of arrays, one `[_; L]` per quantity, so each step of a pass is one vector
//! operation (LLVM vectorises the lane loops; setup is compiled per instruction set with its
//! width, so a lane array is one register):
//!
//! ```text
//! inputs, per lane: the triangle's vertices in orientation order (Micro::order)
//!   inv_area           1 / twice the area
//!   z[k]               window depth of vertex k
//!   n[k][c], p[k][c]   component c of n_w and p_w of vertex k (lit objects)
//! outputs, per pass r < 32 and lane (output s is lane s % L of pass s / L):
//!   pixel, row, depth, colour, kept (a covered sample in front of the far plane)
//!   sample r of lane l is output first[l] + r·stride: packed, first[l] is the number of
//!   samples of the lanes before it and stride 1; in rounds, first[l] = l and stride L
//! ```
//!
//! # Same bits as one at a time
//!
//! Every lane evaluates exactly the expressions of the scalar path, in the same order and
//! without fused multiply-adds: barycentric numerators from the edge values, `λ = E · 1/area`,
//! `z = (λ₀z₀ + λ₁z₁) + λ₂z₂`, the headlight's dot products as `(x·x' + y·y') + z·z'`, the
//! quantisation of [`unorm8`](strata_core::fragment::unorm8). IEEE arithmetic is exact per lane,
//! so the fragments are bit for bit those of [`crate::scan::shade_small`] on every instruction
//! set and at every width (tested below against it, at 8 and 16 lanes, packed and in rounds).
//!
//! The scan shades a larger triangle's spans the same way ([`SpanShader`]): its vertices are
//! broadcast to every lane, and each lane takes the next covered sample of its rows, so `L`
//! consecutive samples share one pass of the same arithmetic (`shade_weighted`).
//!
//! Each pass is a function that writes only its own return value, in small loops of one kind
//! of work each: written in place into the shader's arrays, LLVM feared aliasing and left some
//! lane loops scalar.

// Lane loops index several lane arrays by the same `l`, the shape LLVM vectorises.
#![allow(
    clippy::needless_range_loop,
    reason = "lane loops index many arrays by one lane"
)]

use strata_core::{Fragment, PackedNormal, Rgba8};

use crate::coverage::{Batch, MICRO_SAMPLES, MICRO_W, MicroLanes};
use crate::lanes::Permute;
use crate::scan::Shade;
use crate::setup::PixelFragment;
use crate::sink::FragmentSink;
use crate::vertex::Attrs;

/// The most samples a micro-triangle covers: its 8 × 4 block.
const ROUNDS: usize = MICRO_SAMPLES;

// Sample `bit` of a block is `bit & 7` along it and `bit >> 3` across (`sample_offset`).
const _: () = assert!(MICRO_W == 8);

/// The pixel offset `(i, j)` in its box of the sample whose bit is `low` (a single set bit, or 0
/// for no sample, which gives a value never used), in a tall block if `tall` is 1
/// ([`crate::coverage::Micro::offset`]): the bit's index read off the exponent of `low` as an
/// `f32` (exact for a power of two; the sign of bit 31 masked off), a form LLVM vectorises.
#[inline(always)]
fn sample_offset(low: u32, tall: u32) -> (i32, i32) {
    let bit = (((low as i32 as f32).to_bits() >> 23) & 0xff) as i32 - 127;
    let (c, r) = (bit & (MICRO_W - 1), bit >> 3);
    if tall != 0 { (r, c) } else { (c, r) }
}

/// One pass's results (a round's or a packed pass's), a lane a sample.
#[derive(Clone, Copy, Debug)]
struct Round<const L: usize> {
    pixel: [u32; L],
    row: [i32; L],
    depth: [f32; L],
    color: [u32; L],
    /// 1 for a covered sample in front of the far plane, else 0.
    kept: [u32; L],
}

impl<const L: usize> Default for Round<L> {
    fn default() -> Self {
        Round {
            pixel: [0; L],
            row: [0; L],
            depth: [0.0; L],
            color: [0; L],
            kept: [0; L],
        }
    }
}

/// The triangles' vertex attributes, a lane a triangle, in orientation order.
#[derive(Clone, Copy, Debug)]
struct Vertices<const L: usize> {
    z: [[f32; L]; 3],
    /// `n[k][c]`: component `c` of vertex `k`'s `n_w`; likewise `p`.
    n: [[[f32; L]; 3]; 3],
    p: [[[f32; L]; 3]; 3],
}

impl<const L: usize> Default for Vertices<L> {
    fn default() -> Self {
        Vertices {
            z: [[0.0; L]; 3],
            n: [[[0.0; L]; 3]; 3],
            p: [[[0.0; L]; 3]; 3],
        }
    }
}

/// What every pass of a batch shares, a lane a triangle.
#[derive(Clone, Copy, Debug)]
struct Constants<'a, const L: usize> {
    lanes: MicroLanes<'a, L>,
    vertices: &'a Vertices<L>,
    inv_area: [f32; L],
    /// Row-major index of the box's first pixel.
    first: [u32; L],
    width: i32,
}

/// A batch's micro-triangles shaded in lanes, `L` samples a pass, their triangles' values moved
/// into the samples' lanes by `P`; see the module docs. Reused from batch to batch.
#[derive(Clone, Copy, Debug)]
pub struct MicroShader<const L: usize, P> {
    vertices: Vertices<L>,
    /// Covered samples of each lane (0 for lanes without a micro-triangle).
    counts: [u32; L],
    /// The output of each lane's first sample, and the step from one of its samples to the
    /// next: `(l, L)` in rounds, `(first sample, 1)` packed.
    first: [u32; L],
    stride: u32,
    /// Covered samples of all lanes.
    samples: u32,
    /// The outputs, `L` a pass: output `s` is lane `s % L` of pass `s / L`. A batch covers
    /// at most `32 · L` samples (32 a micro-triangle).
    passes: [Round<L>; ROUNDS],
    permute: P,
}

impl<const L: usize, P: Permute<L>> MicroShader<L, P> {
    /// A shader that packs its samples if `P` does ([`Permute::PACKED`]), else shades in rounds.
    pub fn new(permute: P) -> Self {
        MicroShader {
            vertices: Vertices::default(),
            counts: [0; L],
            first: [0; L],
            stride: 0,
            samples: 0,
            passes: [Round::default(); ROUNDS],
            permute,
        }
    }
}

impl<const L: usize> Vertices<L> {
    /// Loads the lanes of `micro`, a lane at a time. (Loading all eight lanes with AVX2 and
    /// transposing them in registers took fewer instructions but more time on the full dragon:
    /// it also loads the vertices of the third of the triangles that cover nothing. Tried again
    /// with packed passes, lanes without a micro-triangle loading a covered lane's vertices
    /// instead, it made setup 22 % slower.)
    #[inline(always)]
    fn load<'v, const LIT: bool>(
        &mut self,
        micro: u32,
        swapped: &[bool; L],
        vertices: &impl Fn(usize) -> [&'v Attrs; 3],
    ) {
        let mut todo = micro;
        while todo != 0 {
            let l = todo.trailing_zeros() as usize;
            todo &= todo - 1;
            let [a, b, c] = vertices(l);
            let ordered = if swapped[l] { [a, c, b] } else { [a, b, c] };
            for (k, v) in ordered.into_iter().enumerate() {
                self.z[k][l] = v.z;
                if LIT {
                    for c in 0..3 {
                        self.n[k][c][l] = v.n_w[c];
                        self.p[k][c][l] = v.p_w[c];
                    }
                }
            }
        }
    }
}

impl<const L: usize, P: Permute<L>> MicroShader<L, P> {
    /// Shades every covered sample of the micro-triangles in the lanes of `micro` (a subset of
    /// [`crate::coverage::Verdict::micro`]); `vertices(l)` gives lane `l`'s vertex attributes
    /// in input order. Read the results with [`MicroShader::fragments`] or
    /// [`MicroShader::for_each_fragment`].
    #[inline(always)]
    pub fn shade<'v, const LIT: bool>(
        &mut self,
        batch: &Batch<L>,
        micro: u32,
        vertices: impl Fn(usize) -> [&'v Attrs; 3],
        width: i32,
        shade: &Shade,
    ) {
        let lanes = batch.micro_lanes();
        // Inputs: the covered lanes' vertices in orientation order.
        self.vertices.load::<LIT>(micro, lanes.swapped, &vertices);
        let mut mask = [0u32; L];
        let mut cx = Constants {
            lanes,
            vertices: &self.vertices,
            inv_area: [0.0; L],
            first: [0; L],
            width,
        };
        // Small loops of one kind each, on local arrays, so that each is one vector operation
        // (with the count in the loop below, LLVM stored the counts a lane at a time and the
        // packed passes stalled reading them back as a vector).
        for l in 0..L {
            mask[l] = if micro >> l & 1 != 0 {
                lanes.mask[l]
            } else {
                0
            };
        }
        let mut counts = [0u32; L];
        for l in 0..L {
            counts[l] = mask[l].count_ones();
        }
        self.counts = counts;
        for l in 0..L {
            cx.inv_area[l] = 1.0 / lanes.area[l] as f32;
            cx.first[l] = (lanes.y0[l] as u32)
                .wrapping_mul(width as u32)
                .wrapping_add(lanes.x0[l] as u32);
        }
        if !P::PACKED {
            let rounds = *self.counts.iter().max().unwrap_or(&0) as usize;
            for r in 0..rounds {
                self.passes[r] = round::<L, LIT>(&cx, &mut mask, shade);
            }
            self.first = std::array::from_fn(|l| l as u32);
            self.stride = L as u32;
            self.samples = self.counts.iter().sum();
            return;
        }
        // The samples in primitive order: every sample of lane 0, then of lane 1, …; lane `l`'s
        // are outputs `first[l]..end[l]`.
        let end = prefix_sum(&counts);
        let mut first = [0u32; L];
        for l in 0..L {
            first[l] = end[l] - counts[l];
        }
        self.first = first;
        let n = end[L - 1];
        self.stride = 1;
        self.samples = n;
        let rounds = counts.into_iter().max().unwrap_or(0);
        let packing = Packed {
            mask: &mask,
            first: &self.first,
            end: &end,
            samples: n,
            rounds,
        };
        for r in 0..(n as usize).div_ceil(L) {
            self.passes[r] = packed_pass::<L, P, LIT>(self.permute, &cx, &packing, r, shade);
        }
    }

    /// Lane `l`'s fragments from the last [`MicroShader::shade`], in sample order, each with its
    /// image row.
    #[inline(always)]
    pub fn fragments(&self, l: usize) -> impl Iterator<Item = (i32, PixelFragment)> + '_ {
        let (first, stride) = (self.first[l] as usize, self.stride as usize);
        (0..self.counts[l] as usize).filter_map(move |r| self.output(first + r * stride))
    }

    /// Every fragment of the last [`MicroShader::shade`] with its image row, lane after lane,
    /// each in sample order: [`MicroShader::fragments`] of every lane in turn, in one loop
    /// where the samples are packed.
    #[inline(always)]
    pub fn for_each_fragment(&self, mut f: impl FnMut(i32, PixelFragment)) {
        if self.stride == 1 {
            for s in 0..self.samples as usize {
                if let Some((row, fragment)) = self.output(s) {
                    f(row, fragment);
                }
            }
        } else {
            for l in 0..L {
                for (row, fragment) in self.fragments(l) {
                    f(row, fragment);
                }
            }
        }
    }

    /// Output `s` with its image row, if it is kept.
    #[inline(always)]
    fn output(&self, s: usize) -> Option<(i32, PixelFragment)> {
        let (pass, k) = (&self.passes[s / L], s % L);
        (pass.kept[k] != 0).then(|| {
            (
                pass.row[k],
                PixelFragment {
                    pixel: pass.pixel[k],
                    depth: pass.depth[k],
                    color: Rgba8::from_bits(pass.color[k]),
                },
            )
        })
    }
}

/// Shades a larger triangle's covered samples `L` at a time, in the order they are added: what
/// [`crate::scan::scan_triangle`] does with the spans of a triangle too large for setup's
/// micro-triangle lanes. The triangle's vertices are broadcast to every lane once
/// ([`SpanShader::begin`]); each sample brings its pixel and its barycentric numerators, and a
/// full set of lanes is shaded by the same arithmetic as a micro-triangle's round (so the same
/// bits as one at a time) and pushed into the sink in order. Reused from triangle to triangle.
#[derive(Clone, Copy, Debug)]
pub struct SpanShader<const L: usize> {
    vertices: Vertices<L>,
    inv_area: f32,
    /// Barycentric numerators `E_k` of the pending samples, a lane a sample.
    e: [[f32; L]; 3],
    pixel: [u32; L],
    /// Pending samples, `< L`.
    len: usize,
}

impl<const L: usize> Default for SpanShader<L> {
    fn default() -> Self {
        SpanShader {
            vertices: Vertices::default(),
            inv_area: 0.0,
            e: [[0.0; L]; 3],
            pixel: [0; L],
            len: 0,
        }
    }
}

impl<const L: usize> SpanShader<L> {
    /// Starts a triangle of twice the area `area` whose vertices, in orientation order, are
    /// `attrs`. Any pending samples of the previous triangle must have been flushed.
    #[inline(always)]
    pub fn begin<const LIT: bool>(&mut self, attrs: [&Attrs; 3], area: f32) {
        debug_assert_eq!(self.len, 0, "a triangle's samples were left unshaded");
        self.len = 0;
        self.inv_area = 1.0 / area;
        for (k, a) in attrs.into_iter().enumerate() {
            self.vertices.z[k] = [a.z; L];
            if LIT {
                for c in 0..3 {
                    self.vertices.n[k][c] = [a.n_w[c]; L];
                    self.vertices.p[k][c] = [a.p_w[c]; L];
                }
            }
        }
    }

    /// Adds the sample at `pixel` with barycentric numerators `e`; shades and pushes the pending
    /// samples into `sink` when the lanes are full. Returns the fragments pushed.
    #[inline(always)]
    pub fn add<S: FragmentSink, const LIT: bool>(
        &mut self,
        pixel: u32,
        e: [f32; 3],
        shade: &Shade,
        sink: &mut S,
    ) -> u32 {
        let l = self.len;
        self.pixel[l] = pixel;
        for k in 0..3 {
            self.e[k][l] = e[k];
        }
        self.len = l + 1;
        if self.len == L {
            self.flush::<S, LIT>(shade, sink)
        } else {
            0
        }
    }

    /// Shades the pending samples and pushes those in front of the far plane into `sink`, in
    /// order. Returns the fragments pushed.
    #[inline(always)]
    pub fn flush<S: FragmentSink, const LIT: bool>(&mut self, shade: &Shade, sink: &mut S) -> u32 {
        let len = self.len;
        if len == 0 {
            return 0;
        }
        self.len = 0;
        let mut weight = [[0f32; L]; 3];
        let mut covered = [0u32; L];
        for l in 0..L {
            for k in 0..3 {
                weight[k][l] = self.e[k][l] * self.inv_area;
            }
            covered[l] = u32::from(l < len);
        }
        let out = shade_weighted::<L, LIT>(&self.vertices, &weight, &covered, shade);
        let mut pushed = 0;
        for l in 0..len {
            if out.kept[l] != 0 {
                sink.push(
                    self.pixel[l],
                    Fragment {
                        depth: out.depth[l],
                        color: Rgba8::from_bits(out.color[l]),
                        object: shade.id,
                    },
                );
                pushed += 1;
            }
        }
        pushed
    }
}

/// The inclusive prefix sum of `counts`.
#[inline(always)]
fn prefix_sum<const L: usize>(counts: &[u32; L]) -> [u32; L] {
    let mut sum = *counts;
    let mut step = 1;
    while step < L {
        let before = sum;
        for l in 0..L {
            sum[l] = before[l] + if l >= step { before[l - step] } else { 0 };
        }
        step *= 2;
    }
    sum
}

/// The next round of a batch: the lowest remaining sample of every lane of `mask` (which loses
/// it), shaded. Writes only its own value, so LLVM need not fear aliasing and vectorises every
/// lane loop.
#[inline(always)]
fn round<const L: usize, const LIT: bool>(
    cx: &Constants<'_, L>,
    mask: &mut [u32; L],
    shade: &Shade,
) -> Round<L> {
    let v = cx.vertices;
    // The lowest remaining sample of each lane: its bit index from the exponent of the
    // isolated bit (exact in f32 for any power of two). Small loops of one kind of work each,
    // so that LLVM vectorises every one.
    let mut low = [0u32; L];
    let mut i = [0i32; L];
    let mut j = [0i32; L];
    for l in 0..L {
        low[l] = mask[l] & mask[l].wrapping_neg();
        mask[l] &= mask[l].wrapping_sub(1);
        (i[l], j[l]) = sample_offset(low[l], cx.lanes.tall[l]);
    }
    // Barycentric weights: the edge values stepped to the sample, times 1 / area.
    let mut weight = [[0f32; L]; 3];
    for k in 0..3 {
        for l in 0..L {
            let e = cx.lanes.e[k][l]
                .wrapping_add(cx.lanes.dx[k][l].wrapping_mul(i[l]))
                .wrapping_add(cx.lanes.dy[k][l].wrapping_mul(j[l]));
            weight[k][l] = e as f32 * cx.inv_area[l];
        }
    }
    let mut covered = [0u32; L];
    for l in 0..L {
        covered[l] = u32::from(low[l] != 0);
    }
    let mut out = shade_weighted::<L, LIT>(v, &weight, &covered, shade);
    for l in 0..L {
        out.pixel[l] = cx.first[l]
            .wrapping_add((j[l] as u32).wrapping_mul(cx.width as u32))
            .wrapping_add(i[l] as u32);
        out.row[l] = cx.lanes.y0[l].wrapping_add(j[l]);
    }
    out
}

/// Where a batch's samples are packed: lane `l`'s samples (the bits of `mask[l]`) are outputs
/// `first[l]..end[l]` of `samples`; no lane has more than `rounds`.
#[derive(Clone, Copy, Debug)]
struct Packed<'a, const L: usize> {
    mask: &'a [u32; L],
    first: &'a [u32; L],
    end: &'a [u32; L],
    samples: u32,
    rounds: u32,
}

/// Pass `pass` of packed samples: outputs `pass · L ..` shaded, a lane an output. Output `s`
/// belongs to the lane `t` with `first[t] ≤ s < end[t]` (the number of lanes that end at or
/// before it) and is that lane's sample `s − first[t]`; its triangle's values are moved into
/// the output's lane with one permute each, and the arithmetic is then [`round`]'s, so the same
/// bits. Outputs past the last sample are marked not kept. Branch-free: every step is a lane
/// loop.
#[inline(always)]
fn packed_pass<const L: usize, P: Permute<L>, const LIT: bool>(
    permute: P,
    cx: &Constants<'_, L>,
    packed: &Packed<'_, L>,
    pass: usize,
    shade: &Shade,
) -> Round<L> {
    let mut slot = [0u32; L];
    let mut source = [0u32; L];
    let mut covered = [0u32; L];
    for l in 0..L {
        slot[l] = (pass * L + l) as u32;
        covered[l] = u32::from(slot[l] < packed.samples);
    }
    for t in 0..L {
        for l in 0..L {
            source[l] += u32::from(packed.end[t] <= slot[l]);
        }
    }
    let idx = source;
    // The output's sample: drop the lowest `s − first` bits of its lane's mask, take the
    // lowest left (its index from the exponent of the isolated bit, as in `round`).
    let (first, mut mask) = (
        permute.u32s(*packed.first, idx),
        permute.u32s(*packed.mask, idx),
    );
    let mut rank = [0u32; L];
    for l in 0..L {
        rank[l] = slot[l].wrapping_sub(first[l]);
    }
    for r in 1..packed.rounds {
        for l in 0..L {
            let drop = mask[l] & mask[l].wrapping_sub(1);
            mask[l] = if r <= rank[l] { drop } else { mask[l] };
        }
    }
    let tall = permute.u32s(*cx.lanes.tall, idx);
    let mut i = [0i32; L];
    let mut j = [0i32; L];
    for l in 0..L {
        let low = mask[l] & mask[l].wrapping_neg();
        (i[l], j[l]) = sample_offset(low, tall[l]);
    }
    let inv_area = permute.f32s(cx.inv_area, idx);
    let mut weight = [[0f32; L]; 3];
    for k in 0..3 {
        let e = permute.i32s(cx.lanes.e[k], idx);
        let dx = permute.i32s(cx.lanes.dx[k], idx);
        let dy = permute.i32s(cx.lanes.dy[k], idx);
        for l in 0..L {
            let e = e[l]
                .wrapping_add(dx[l].wrapping_mul(i[l]))
                .wrapping_add(dy[l].wrapping_mul(j[l]));
            weight[k][l] = e as f32 * inv_area[l];
        }
    }
    let v = Permuted {
        permute,
        idx,
        vertices: cx.vertices,
    };
    let mut out = shade_weighted::<L, LIT>(v, &weight, &covered, shade);
    let first = permute.u32s(cx.first, idx);
    let y0 = permute.i32s(*cx.lanes.y0, idx);
    for l in 0..L {
        out.pixel[l] = first[l]
            .wrapping_add((j[l] as u32).wrapping_mul(cx.width as u32))
            .wrapping_add(i[l] as u32);
        out.row[l] = y0[l].wrapping_add(j[l]);
    }
    out
}

/// The vertex attributes of [`shade_weighted`]'s samples, a lane a sample: read as they lie
/// ([`Vertices`]), or moved into the sample lanes as they are read ([`Permuted`]).
trait VertexLanes<const L: usize>: Copy {
    /// Window depth of vertex `k`.
    fn z(self, k: usize) -> [f32; L];
    /// Component `c` of vertex `k`'s `n_w`.
    fn n(self, k: usize, c: usize) -> [f32; L];
    /// Component `c` of vertex `k`'s `p_w`.
    fn p(self, k: usize, c: usize) -> [f32; L];
}

impl<const L: usize> VertexLanes<L> for &Vertices<L> {
    #[inline(always)]
    fn z(self, k: usize) -> [f32; L] {
        self.z[k]
    }
    #[inline(always)]
    fn n(self, k: usize, c: usize) -> [f32; L] {
        self.n[k][c]
    }
    #[inline(always)]
    fn p(self, k: usize, c: usize) -> [f32; L] {
        self.p[k][c]
    }
}

/// A batch's vertices (a lane a triangle) read into sample lanes: lane `s` gets triangle lane
/// `idx[s]`, one permute an attribute.
#[derive(Clone, Copy)]
struct Permuted<'a, const L: usize, P> {
    permute: P,
    idx: [u32; L],
    vertices: &'a Vertices<L>,
}

impl<const L: usize, P: Permute<L>> VertexLanes<L> for Permuted<'_, L, P> {
    #[inline(always)]
    fn z(self, k: usize) -> [f32; L] {
        self.permute.f32s(self.vertices.z[k], self.idx)
    }
    #[inline(always)]
    fn n(self, k: usize, c: usize) -> [f32; L] {
        self.permute.f32s(self.vertices.n[k][c], self.idx)
    }
    #[inline(always)]
    fn p(self, k: usize, c: usize) -> [f32; L] {
        self.permute.f32s(self.vertices.p[k][c], self.idx)
    }
}

/// Depth and colour of `L` samples from their barycentric weights `weight[k]` (the edge
/// values times `1 / area`), a lane a sample, with lane `l`'s vertices in `v`'s lane `l`;
/// `covered[l]` is 1 for a sample to keep if it lies in front of the far plane. The arithmetic
/// of [`crate::scan`]'s one-at-a-time shading, in the same order, so the same bits. Leaves
/// `pixel` and `row` at zero.
#[inline(always)]
fn shade_weighted<const L: usize, const LIT: bool>(
    v: impl VertexLanes<L>,
    weight: &[[f32; L]; 3],
    covered: &[u32; L],
    shade: &Shade,
) -> Round<L> {
    let mut out = Round::default();
    let [l0, l1, l2] = weight;
    let z = [v.z(0), v.z(1), v.z(2)];
    for l in 0..L {
        let z = l0[l] * z[0][l] + l1[l] * z[1][l] + l2[l] * z[2][l];
        // Covered, and not beyond the far plane (nor NaN); rounding below 0 gives +0.
        out.kept[l] = covered[l] & u32::from(z <= 1.0);
        out.depth[l] = if z > 0.0 { z } else { 0.0 };
    }
    if !LIT {
        out.color = [shade.flat.to_bits(); L];
        return out;
    }
    // The perspective-correct normal and position, up to a common factor.
    let mut n = [[0f32; L]; 3];
    let mut p = [[0f32; L]; 3];
    for c in 0..3 {
        let vn = [v.n(0, c), v.n(1, c), v.n(2, c)];
        let vp = [v.p(0, c), v.p(1, c), v.p(2, c)];
        for l in 0..L {
            n[c][l] = vn[0][l] * l0[l] + vn[1][l] * l1[l] + vn[2][l] * l2[l];
            p[c][l] = vp[0][l] * l0[l] + vp[1][l] * l1[l] + vp[2][l] * l2[l];
        }
    }
    if shade.packed {
        out.color = PackedNormal::pack_lanes(&n[0], &n[1], &n[2]);
        return out;
    }
    let alpha = u32::from(shade.alpha) << 24;
    for l in 0..L {
        let (nx, ny, nz) = (n[0][l], n[1][l], n[2][l]);
        let (px, py, pz) = (p[0][l], p[1][l], p[2][l]);
        let nn = nx * nx + ny * ny + nz * nz;
        let pp = px * px + py * py + pz * pz;
        let np = nx * px + ny * py + nz * pz;
        let denom = (nn * pp).sqrt();
        let cos = if denom > 0.0 {
            (np.abs() / denom).min(1.0)
        } else {
            0.0
        };
        let factor = 0.25 + 0.75 * cos;
        let r = quantise(shade.rgb[0] * factor);
        let g = quantise(shade.rgb[1] * factor);
        let b = quantise(shade.rgb[2] * factor);
        out.color[l] = r | g << 8 | b << 16 | alpha;
    }
    out
}

/// [`unorm8`](strata_core::fragment::unorm8) in a form LLVM vectorises. The clamped
/// `x = v · 255 + ½` lies in `[0.5, 255.5]`, where truncation is `floor` (one `vroundps` for
/// eight lanes), and adding 2²³ to the integer `floor(x)` leaves it in the low mantissa bits.
/// Rust's saturating float-to-integer casts are converted a lane at a time instead (about eight
/// instructions a channel). The same bits (tested).
#[inline(always)]
fn quantise(v: f32) -> u32 {
    const MAGIC: f32 = (1u32 << 23) as f32;
    let v = if v > 0.0 { v } else { 0.0 };
    let v = if v < 1.0 { v } else { 1.0 };
    ((v * 255.0 + 0.5).floor() + MAGIC).to_bits() - MAGIC.to_bits()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coverage::Batch;
    use crate::scan::shade_small;
    use crate::vertex::{ScreenPos, outcode};
    use strata_core::ObjectId;

    /// A tiny xorshift generator, so the cases are the same on every run.
    use crate::test_rand::Rand;

    fn attrs(rand: &mut Rand) -> Attrs {
        let mut v = || rand.unit() * 4.0 - 2.0;
        // Depths sometimes beyond the far plane or below the near one, to exercise both cuts.
        Attrs {
            z: v() * 0.75 + 0.5,
            iw: 1.0,
            p_w: [v(), v(), v() - 3.0],
            n_w: [v(), v(), v()],
        }
    }

    #[test]
    fn quantise_is_unorm8() {
        use strata_core::fragment::unorm8;
        let specials = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            0.0,
            1.0,
            2.0,
            -1.0,
        ];
        for v in specials {
            assert_eq!(quantise(v), u32::from(unorm8(v)), "{v}");
        }
        // The floats around every quantisation step (where `v · 255 + ½` crosses an integer), and
        // around 0 and 1.
        for k in 0..=256 {
            let step = (k as f32 - 0.5) / 255.0;
            for d in -200i32..=200 {
                let v = f32::from_bits(step.abs().to_bits().wrapping_add_signed(d));
                for v in [v, -v] {
                    assert_eq!(quantise(v), u32::from(unorm8(v)), "{v}");
                }
            }
        }
    }

    /// [`MicroShader::shade`]'s arguments, for [`pulp::Arch::dispatch`] (a closure would be
    /// called out of line, compiled for the baseline instruction set).
    struct ShadeJob<'a, F, const L: usize, P> {
        shader: &'a mut MicroShader<L, P>,
        batch: &'a Batch<L>,
        micro: u32,
        vertices: F,
        width: i32,
        shade: &'a Shade,
        lit: bool,
    }

    impl<'v, F: Fn(usize) -> [&'v Attrs; 3], const L: usize, P: Permute<L>> pulp::WithSimd
        for ShadeJob<'_, F, L, P>
    {
        type Output = ();

        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _: S) {
            let ShadeJob {
                shader,
                batch,
                micro,
                vertices,
                width,
                shade,
                lit,
            } = self;
            if lit {
                shader.shade::<true>(batch, micro, vertices, width, shade);
            } else {
                shader.shade::<false>(batch, micro, vertices, width, shade);
            }
        }
    }

    /// A sink that keeps what it is given.
    struct Collect(Vec<(u32, strata_core::Fragment)>);
    impl FragmentSink for Collect {
        fn push(&mut self, pixel: u32, fragment: strata_core::Fragment) {
            self.0.push((pixel, fragment));
        }
    }

    /// [`crate::scan::scan_triangle`]'s arguments for a larger triangle, for
    /// [`pulp::Arch::dispatch`], so the lanes run under the instruction set the scan picks.
    struct SpanJob<'a, const L: usize> {
        pos: [ScreenPos; 3],
        attrs: [&'a Attrs; 3],
        rows: (i32, i32),
        size: (i32, i32),
        shade: &'a Shade,
        lanes: &'a mut SpanShader<L>,
        sink: &'a mut Collect,
        lit: bool,
    }

    impl<const L: usize> pulp::WithSimd for SpanJob<'_, L> {
        type Output = u32;

        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _: S) -> u32 {
            let SpanJob {
                pos,
                attrs,
                rows,
                size: (w, h),
                shade,
                lanes,
                sink,
                lit,
            } = self;
            if lit {
                crate::scan::scan_triangle::<_, true, L>(pos, attrs, rows, w, h, shade, lanes, sink)
            } else {
                crate::scan::scan_triangle::<_, false, L>(
                    pos, attrs, rows, w, h, shade, lanes, sink,
                )
            }
        }
    }

    /// Larger triangles (boxes of 5 to 40 pixels, some cut by the image's edges and the strip's
    /// rows; the micro-sized among the 6,000 random ones are skipped), their spans shaded eight
    /// and sixteen samples at a time (the two lane widths of [`crate::lanes`]), against one
    /// sample at a time, in every shading mode: the same fragments, bit for bit, in the same
    /// order, whatever number of samples a triangle leaves pending in the lanes.
    #[test]
    fn span_lanes_shade_exactly_like_one_sample_at_a_time() {
        span_lanes_like_one_sample_at_a_time::<8>();
        span_lanes_like_one_sample_at_a_time::<16>();
    }

    fn span_lanes_like_one_sample_at_a_time<const L: usize>() {
        use crate::scan::shade_large_one_at_a_time;
        let mut rand = Rand(0x2545_f491_4f6c_dd1d);
        let (w, h) = (61, 47);
        // One shader reused across triangles, as a strip's scan does.
        let mut lanes = SpanShader::<L>::default();
        let (mut compared, mut large, mut far, mut tail) = (0usize, 0usize, 0usize, 0usize);
        for case in 0..6000 {
            let (lit, packed) = [(false, false), (true, false), (true, true)][case % 3];
            let shade = Shade {
                rgb: [rand.unit(), rand.unit() * 1.5, rand.unit()],
                alpha: rand.below(256) as u8,
                flat: Rgba8([1, 2, 3, 4]),
                id: strata_core::ObjectId(1),
                packed,
            };
            let size = 5 + rand.below(36);
            let (bx, by) = (
                rand.below(w as u32 + 20) - 10,
                rand.below(h as u32 + 20) - 10,
            );
            let mut v = || ScreenPos {
                x: (bx + rand.below(size as u32)) * 256 + rand.below(256),
                y: (by + rand.below(size as u32)) * 256 + rand.below(256),
            };
            let pos = [v(), v(), v()];
            let verts = [attrs(&mut rand), attrs(&mut rand), attrs(&mut rand)];
            let vref = [&verts[0], &verts[1], &verts[2]];
            let first = rand.below(h as u32);
            let rows = (first, first + rand.below(h as u32));
            // Only larger triangles are this test's subject; the samples their rows cover,
            // before the far plane drops any.
            let Some(crate::coverage::Triangle::Large(t)) =
                crate::coverage::Triangle::new(pos, w, h)
            else {
                continue;
            };
            let mut samples = 0usize;
            crate::scan::for_each_sample(&t, rows, w, |_, _| samples += 1);
            let mut got = Collect(Vec::new());
            let n = pulp::Arch::new().dispatch(SpanJob {
                pos,
                attrs: vref,
                rows,
                size: (w, h),
                shade: &shade,
                lanes: &mut lanes,
                sink: &mut got,
                lit,
            });
            let mut want = Collect(Vec::new());
            let m = if lit {
                shade_large_one_at_a_time::<_, true>(&t, vref, (rows, w), &shade, &mut want)
            } else {
                shade_large_one_at_a_time::<_, false>(&t, vref, (rows, w), &shade, &mut want)
            };
            let bits = |v: &[(u32, strata_core::Fragment)]| -> Vec<(u32, u32, u32, u32)> {
                v.iter()
                    .map(|(p, f)| (*p, f.depth.to_bits(), f.color.to_bits(), f.object.0))
                    .collect()
            };
            assert_eq!(bits(&got.0), bits(&want.0), "case {case}");
            assert_eq!(
                (n, m),
                (got.0.len() as u32, want.0.len() as u32),
                "case {case}"
            );
            compared += want.0.len();
            large += 1;
            tail += usize::from(!samples.is_multiple_of(L));
            // Covered samples beyond the far plane, which both dropped.
            far += samples - want.0.len();
        }
        // The cases must have exercised what they claim to.
        assert!(compared > 30_000, "{compared} fragments compared");
        assert!(large > 2_500, "{large} larger triangles compared");
        assert!(
            tail > 1_000,
            "{tail} triangles ending with a partial set of lanes"
        );
        assert!(far > 5_000, "{far} covered samples beyond the far plane");
    }

    /// Every micro-triangle of many random batches, shaded in lanes and one at a time, in every
    /// shading mode: the same fragments, bit for bit, in the same order. The lanes run under
    /// setup's instruction-set dispatch, the reference one at a time for the baseline. Both
    /// widths, packed and in rounds, with a lane-by-lane permute on any CPU; then with the
    /// permutes setup itself uses, where this CPU has them.
    #[test]
    fn lanes_shade_exactly_like_one_triangle_at_a_time() {
        struct Shades;
        impl crate::lanes::EveryPermute for Shades {
            fn run<const L: usize, P: Permute<L>>(&mut self, permute: P) {
                lanes_shade_like_one_at_a_time::<L, P>(permute);
            }
        }
        crate::lanes::with_every_permute(&mut Shades);
    }

    /// The test above with the samples put in `L` lanes by `permute`; also checks that
    /// [`MicroShader::for_each_fragment`] gives every lane's fragments in lane order.
    fn lanes_shade_like_one_at_a_time<const L: usize, P: Permute<L>>(permute: P) {
        let mut rand = Rand(0x9e37_79b9_7f4a_7c15);
        let (w, h) = (37, 23);
        let mut batch = Batch::<L>::default();
        let mut shader = MicroShader::new(permute);
        let shades = [
            (false, false),
            (true, false), // headlight
            (true, true),  // packed normals
        ];
        let (mut compared, mut far, mut passes, mut many) = (0usize, 0usize, 0usize, 0usize);
        let (mut tall, mut last_bit) = (0usize, 0usize);
        for case in 0..3000 {
            let (lit, packed) = shades[case % 3];
            let shade = Shade {
                rgb: [rand.unit(), rand.unit() * 1.5, rand.unit()],
                alpha: rand.below(256) as u8,
                flat: Rgba8([1, 2, 3, 4]),
                id: ObjectId(1),
                packed,
            };
            let mut verts = Vec::new();
            for l in 0..L {
                let (bx, by) = (rand.below(w as u32 * 256), rand.below(h as u32 * 256));
                // Vertices up to 4 pixels apart, or up to 9 in x and 5 in y, or 5 and 9, the
                // most a micro-triangle spreads: these cover up to the whole block, wide or tall.
                let (sx, sy) = match case / 3 % 3 {
                    0 => (4 * 256, 4 * 256),
                    1 => (9 * 256 - 1, 5 * 256 - 1),
                    _ => (5 * 256 - 1, 9 * 256 - 1),
                };
                let mut v = || ScreenPos {
                    x: bx + rand.below(sx) - sx as i32 / 2,
                    y: by + rand.below(sy) - sy as i32 / 2,
                };
                let pos = [v(), v(), v()];
                batch.set(l, pos, [0; 3]);
                verts.push([attrs(&mut rand), attrs(&mut rand), attrs(&mut rand)]);
            }
            let verdict = batch.classify(L, w, h, outcode::VIEW, outcode::CLIP);
            let vertices = |l: usize| [&verts[l][0], &verts[l][1], &verts[l][2]];
            // Shaded under the same run-time choice of instruction set as setup (AVX2 where the
            // CPU has it), so the vector code the renderer runs is the code tested.
            pulp::Arch::new().dispatch(ShadeJob {
                shader: &mut shader,
                batch: &batch,
                micro: verdict.micro,
                vertices,
                width: w,
                shade: &shade,
                lit,
            });
            passes += usize::from(shader.samples as usize > L);
            many += usize::from(shader.counts.iter().any(|&c| c > 12));
            let mut all = Vec::new();
            shader.for_each_fragment(|row, f| all.push((row, f)));
            let by_lane: Vec<_> = (0..L).flat_map(|l| shader.fragments(l)).collect();
            assert_eq!(all, by_lane, "case {case}");
            for l in 0..L {
                let lanes: Vec<_> = shader.fragments(l).collect();
                if verdict.micro >> l & 1 == 0 {
                    assert!(lanes.is_empty(), "lane {l} is not a micro-triangle");
                    continue;
                }
                let (tri, mask) = batch.micro(l);
                tall += usize::from(tri.tall);
                last_bit += (mask >> 31) as usize;
                let mut one = Vec::new();
                let mut push = |row, pixel, f: strata_core::Fragment| {
                    one.push((row, PixelFragment::new(pixel, f)));
                };
                if lit {
                    shade_small::<true>(&tri, vertices(l), mask, w, &shade, &mut push);
                } else {
                    shade_small::<false>(&tri, vertices(l), mask, w, &shade, &mut push);
                }
                far += mask.count_ones() as usize - one.len();
                let bits = |v: &[(i32, PixelFragment)]| -> Vec<(i32, u32, u32, u32)> {
                    v.iter()
                        .map(|(r, f)| (*r, f.pixel, f.depth.to_bits(), f.color.to_bits()))
                        .collect()
                };
                assert_eq!(bits(&lanes), bits(&one), "case {case}, lane {l}");
                compared += one.len();
            }
        }
        // The cases must have exercised what they claim to.
        assert!(compared > 20_000, "{compared} fragments compared");
        assert!(tall > 1_000, "{tall} micro-triangles in tall blocks");
        // Bit 31, whose f32 is negative, was shaded (and compared) too.
        assert!(
            last_bit > 10,
            "{last_bit} micro-triangles covering their block's last sample"
        );
        assert!(far > 500, "{far} samples beyond the far plane");
        // Batches of several packed passes, and triangles covering more than half their block.
        assert!(passes > 1000, "{passes} batches of more than {L} samples");
        assert!(
            many > 10,
            "{many} batches with a triangle of more than 12 samples"
        );
    }
}
