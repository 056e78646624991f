//! Eq. 5.9 ([`View::project`]) and eq. 5.10 ([`View::entry`]) with their shading, eight
//! fragments of one object at a time.
//!
//! A reprojection frame moves every held surfel and converts every rendered fragment on the node,
//! and moves every held surfel again on the display: about three million of these a dragon frame.
//! One at a time, each is a chain of dependent divisions and square roots (the perspective
//! divide, the headlight's `|n·p| / √(n²p²)`, the octahedral normal's normalisation) that the
//! processor cannot overlap across fragments; `perf` put the shading alone at 19 % of a
//! reprojection node's CPU time, and 28 % of a node's encode and a display's apply run together.
//!
//! # Layout
//!
//! A batch is up to [`LANES`] fragments of **one object**, so its matrices and material are
//! broadcast and only the fragments' own values are lanes: `[f32; LANES]` arrays (structure of
//! arrays), filled from the entries, computed, and written back. Lanes past the batch's length
//! are padding and are not written back. The loops are compiled once per instruction set and
//! chosen at run time ([`pulp::Arch::dispatch`]): on AVX2 a lane array is one register.
//!
//! Where a list's walk finds [`LANES`] consecutive items of one object (for the move, one that
//! moved) — nearly every stretch of a held band or a rendered row where one object fills the
//! view — they are a batch as they lie:
//! the lanes read them from the list (the held entries, the frame's depth and colour columns)
//! and write their results straight into their places. Every other item is gathered by
//! [`Pending`]: up to eight batches fill at once, one per object, so that a pixel's run
//! through several objects (the back and front of a transparent sphere behind another's)
//! still fills whole batches. Each gathered item carries where its result goes. Gathering
//! every item, one object or not, cost a copy of it in and of its result out: taking items as
//! they lie cut a reprojection node's select by 8–10 % (dragon, one thread, Intel Xeon).
//!
//! # Same bits
//!
//! Every lane performs, operation for operation, what the one-fragment definitions perform:
//! glam's matrix products in glam's order of additions, the same divisions (not reciprocals where
//! the definition divides), no fused multiply-adds. IEEE arithmetic gives the same bits on every
//! instruction set, so a node and a display on different machines still agree, and the lanes
//! equal [`View::project`] and [`View::entry`] bit for bit (tested, NaN, infinities and pixels
//! behind the eye included, in `reprojection::tests`). The one-fragment forms stay the
//! definitions.

use glam::{Mat3, Mat4};
use strata_core::{DeepFrame, Fragment, ObjectId, PackedNormal, Rgba8};

use super::held::{Entry, Surfel};
use super::view::{ObjectView, View};

/// Fragments in one batch.
pub(crate) const LANES: usize = 8;

type Lane = [f32; LANES];

/// `f(i)` for every lane: a plain loop the compiler unrolls and vectorises (the closures below
/// have no branches on the lane, only selects).
#[inline(always)]
fn lanes(f: impl Fn(usize) -> f32) -> Lane {
    let mut out = [0.0; LANES];
    for (i, o) in out.iter_mut().enumerate() {
        *o = f(i);
    }
    out
}

/// Most items a list's walk takes one at a time (through [`Pending`]) before it tests again
/// whether the next [`LANES`] are of one object, after a stretch where they were not
/// ([`RowTests`]).
const MAX_SKIP: usize = 16 * LANES;

/// When a list's walk (the move of a held band, the conversion of a rendered row) next tests
/// whether the [`LANES`] items from its position are of one object, to take them through the
/// lanes as they lie: at every position while tests pass; after a failed test, `LANES` items
/// later, then twice as many after each further failure, up to [`MAX_SKIP`]. So a list of
/// several objects' alternating runs (`spheres`) pays for about one test in `MAX_SKIP` items.
pub(crate) struct RowTests {
    next: usize,
    skip: usize,
}

impl RowTests {
    /// Tests due from position `start` on.
    pub(crate) fn from(start: usize) -> Self {
        RowTests {
            next: start,
            skip: LANES,
        }
    }

    /// Whether the walk tests at position `i`.
    #[inline(always)]
    pub(crate) fn due(&self, i: usize) -> bool {
        i >= self.next
    }

    /// The test at the walk's position passed.
    #[inline(always)]
    pub(crate) fn passed(&mut self) {
        self.skip = LANES;
    }

    /// The test at position `i` failed.
    #[inline(always)]
    pub(crate) fn failed(&mut self, i: usize) {
        self.next = i + self.skip;
        self.skip = (2 * self.skip).min(MAX_SKIP);
    }
}

/// Batches open at once, one object each.
const OPEN: usize = 8;

/// Items waiting to go through the lanes in batches of [`LANES`] of one object. A pixel's run
/// through several transparent objects alternates between them (the `spheres` scene: six
/// objects, seven fragments a pixel on average), so batching only consecutive items of one
/// object sent most batches through the lanes with one or two lanes used. Here up to [`OPEN`]
/// batches fill at once, one per object; when all hold items, one is flushed in turn (round
/// robin) to make room for a new object's.
/// Lanes are independent (each lane's result depends on its own input and its object's
/// constants only) and every item carries where its result goes (`to`), so the order batches
/// are computed in changes no result.
///
/// A batch keeps its items as two arrays, where they go and what the lanes read, so that the
/// lanes read the second as it is. An item of the last item's object goes straight to that
/// batch.
///
/// **A full batch waits for the next.** Items are stored one at a time, and the lanes read a
/// batch back as whole arrays: read at once, the last items' stores are still on their way to
/// the cache, and a wide load cannot take its data from several narrower stores in flight, so
/// it waits for them to drain (`perf` put about a tenth of each lane function on that first
/// load). So each open batch has two buffers: when one fills, the batch that filled before it
/// (of any object) is handed over, and this one waits in its place while the other buffer
/// fills.
pub(crate) struct Pending<To, In> {
    /// Two buffers per open batch: batch `k` fills `buffers[2k + side[k]]`.
    buffers: [Batch<To, In>; 2 * OPEN],
    side: [usize; OPEN],
    /// Batches in use, `0..open`.
    open: usize,
    /// The batch of the last item's object.
    current: usize,
    /// The batch to flush and give to a new object when all are in use.
    evict: usize,
    /// The buffer that filled last and is not yet handed over.
    full: Option<usize>,
}

/// Up to [`LANES`] items of one object.
#[derive(Clone, Copy)]
struct Batch<To, In> {
    object: ObjectId,
    len: usize,
    to: [To; LANES],
    input: [In; LANES],
}

impl<To: Copy + Default, In: Copy + Default> Default for Pending<To, In> {
    fn default() -> Self {
        let batch = Batch {
            object: ObjectId::default(),
            len: 0,
            to: [To::default(); LANES],
            input: [In::default(); LANES],
        };
        Pending {
            buffers: [batch; 2 * OPEN],
            side: [0; OPEN],
            open: 1,
            current: 0,
            evict: 0,
            full: None,
        }
    }
}

/// What a batch is handed to: its object, where each item's result goes, the lanes' input and
/// how many items it holds (the lanes past them hold earlier items, possibly of another object,
/// to be computed and not written back).
pub(crate) trait Flush<To, In> {
    fn flush(&mut self, object: ObjectId, to: &[To; LANES], input: &[In; LANES], len: usize);
}

impl<To: Copy, In: Copy> Pending<To, In> {
    /// The buffer batch `k` fills.
    #[inline(always)]
    fn filling(&self, k: usize) -> usize {
        2 * k + self.side[k]
    }

    /// Adds an item of `object`; `f` gets every batch that fills (one fill later), and every
    /// batch flushed to make room.
    #[inline(always)]
    pub(crate) fn push(&mut self, object: ObjectId, to: To, input: In, f: &mut impl Flush<To, In>) {
        if self.buffers[self.filling(self.current)].object != object {
            self.switch(object, f);
        }
        let k = self.current;
        let i = self.filling(k);
        let b = &mut self.buffers[i];
        b.to[b.len] = to;
        b.input[b.len] = input;
        b.len += 1;
        if b.len == LANES {
            self.filled(k, i, f);
        }
    }

    /// Buffer `i` of batch `k` is full: the one full before it is handed over (its stores
    /// have long drained), and `k` goes on in its other buffer, which is empty (a batch's two
    /// buffers are never both full: the older is handed over when the newer fills).
    #[inline(always)]
    fn filled(&mut self, k: usize, i: usize, f: &mut impl Flush<To, In>) {
        if let Some(j) = self.full.replace(i) {
            let b = &mut self.buffers[j];
            f.flush(b.object, &b.to, &b.input, LANES);
            b.len = 0;
        }
        self.side[k] ^= 1;
        let object = self.buffers[i].object;
        self.buffers[self.filling(k)].object = object;
    }

    /// Makes `object`'s batch the current one: the one open for it, an empty or unused one, or
    /// the next in turn, flushed.
    #[inline(never)]
    fn switch(&mut self, object: ObjectId, f: &mut impl Flush<To, In>) {
        let open = 0..self.open;
        let k = match open
            .clone()
            .find(|&k| self.buffers[self.filling(k)].object == object)
        {
            Some(k) => k,
            None => {
                let k = match open
                    .clone()
                    .find(|&k| self.buffers[self.filling(k)].len == 0)
                {
                    Some(k) => k,
                    None if self.open < OPEN => {
                        self.open += 1;
                        self.open - 1
                    }
                    None => {
                        let k = self.evict;
                        self.evict = (k + 1) % OPEN;
                        let b = &mut self.buffers[self.filling(k)];
                        f.flush(b.object, &b.to, &b.input, b.len);
                        b.len = 0;
                        k
                    }
                };
                let i = self.filling(k);
                self.buffers[i].object = object;
                k
            }
        };
        self.current = k;
    }

    /// Hands over the full batch waiting, then every batch with items left.
    #[inline(always)]
    pub(crate) fn finish(&mut self, f: &mut impl Flush<To, In>) {
        if let Some(j) = self.full.take() {
            let b = &mut self.buffers[j];
            f.flush(b.object, &b.to, &b.input, LANES);
            b.len = 0;
        }
        for k in 0..self.open {
            let b = &mut self.buffers[2 * k + self.side[k]];
            if b.len > 0 {
                f.flush(b.object, &b.to, &b.input, b.len);
            }
            b.len = 0;
        }
    }
}

/// `m · (x, y, z, 1)` in lanes, as glam's `Mat4::transform_point3` adds: x, then y, z, w.
#[inline(always)]
fn transform_point(m: &Mat4, [x, y, z]: &[Lane; 3]) -> [Lane; 3] {
    let (c0, c1, c2, c3) = (m.x_axis, m.y_axis, m.z_axis, m.w_axis);
    let row = |a: f32, b: f32, c: f32, d: f32| lanes(|i| d + (c * z[i] + (b * y[i] + a * x[i])));
    [
        row(c0.x, c1.x, c2.x, c3.x),
        row(c0.y, c1.y, c2.y, c3.y),
        row(c0.z, c1.z, c2.z, c3.z),
    ]
}

/// `m · (x, y, z, 1)` in lanes, as glam's `Mat4 * Vec4` adds: x, y, z, then w: the x, y, z
/// and w rows. Written as [`transform_point`] is, with a fourth row: IEEE addition is
/// commutative, so `d + (c·z + (b·y + a·x))` is `((a·x + b·y) + c·z) + d·1` bit for bit.
#[inline(always)]
fn mul_point4(m: &Mat4, p: &[Lane; 3]) -> [Lane; 4] {
    let [x, y, z] = transform_point(m, p);
    let (c0, c1, c2, c3) = (m.x_axis, m.y_axis, m.z_axis, m.w_axis);
    let [px, py, pz] = p;
    let w = lanes(|i| c3.w + (c2.w * pz[i] + (c1.w * py[i] + c0.w * px[i])));
    [x, y, z, w]
}

/// `m · (x, y, z)` in lanes, as glam's `Mat3 * Vec3` adds: x, then y, then z.
#[inline(always)]
fn mul_mat3(m: &Mat3, [x, y, z]: &[Lane; 3]) -> [Lane; 3] {
    let (c0, c1, c2) = (m.x_axis, m.y_axis, m.z_axis);
    let row = |a: f32, b: f32, c: f32| lanes(|i| a * x[i] + b * y[i] + c * z[i]);
    [
        row(c0.x, c1.x, c2.x),
        row(c0.y, c1.y, c2.y),
        row(c0.z, c1.z, c2.z),
    ]
}

/// [`unorm8`] in lanes, the same bits: after the clamp, `v · 255 + 0.5` lies in
/// `[0.5, 255.5]`, whose truncation is exact in `f32` and reads off the low bits of
/// `t + 2²³` (Rust's saturating `as u8` would run a lane at a time).
#[inline(always)]
fn unorm8_lanes(v: &Lane) -> [u8; LANES] {
    let t = lanes(|i| {
        let c = if v[i] > 0.0 { v[i] } else { 0.0 };
        let c = if c < 1.0 { c } else { 1.0 };
        (c * 255.0 + 0.5).trunc() + 8_388_608.0
    });
    std::array::from_fn(|i| t[i].to_bits() as u8)
}

/// The headlight colour of object `o` for eye-space normals `n` at eye-space points `p`
/// (`View::shade` with `strata_core::material`'s `headlight_factor` and `headlight_rgba`).
#[inline(always)]
fn shade(o: &ObjectView, n: &[Lane; 3], p: &[Lane; 3]) -> [Rgba8; LANES] {
    if !o.lit {
        return [o.flat; LANES];
    }
    let dot = |a: &[Lane; 3], b: &[Lane; 3]| {
        lanes(|i| a[0][i] * b[0][i] + a[1][i] * b[1][i] + a[2][i] * b[2][i])
    };
    let (nn, pp, np) = (dot(n, n), dot(p, p), dot(n, p));
    let factor = lanes(|i| {
        let denom = (nn[i] * pp[i]).sqrt();
        let ratio = np[i].abs() / denom;
        // `f32::min(ratio, 1.0)`, NaN included: the compare fails and 1 is taken.
        let ratio = if ratio < 1.0 { ratio } else { 1.0 };
        let cos = if denom > 0.0 { ratio } else { 0.0 };
        0.25 + 0.75 * cos
    });
    let channel = |c: usize| unorm8_lanes(&lanes(|i| o.rgb[c] * factor[i]));
    let (r, g, b) = (channel(0), channel(1), channel(2));
    std::array::from_fn(|i| Rgba8([r[i], g[i], b[i], o.alpha]))
}

/// What [`View::project_batch`] reads a surfel from: a surfel gathered by [`Pending`], or a
/// held entry read where it lies.
pub(crate) trait HasSurfel: Copy {
    fn surfel(&self) -> &Surfel;
}

impl HasSurfel for Surfel {
    #[inline(always)]
    fn surfel(&self) -> &Surfel {
        self
    }
}

impl HasSurfel for Entry {
    #[inline(always)]
    fn surfel(&self) -> &Surfel {
        &self.surfel
    }
}

/// One batch of [`View::project_batch`].
struct ProjectJob<'a, T> {
    view: &'a View,
    o: &'a ObjectView,
    object: ObjectId,
    surfels: &'a [T; LANES],
    out: &'a mut [(u32, Fragment); LANES],
}

impl<T: HasSurfel> pulp::WithSimd for ProjectJob<'_, T> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let (view, o, s) = (self.view, self.o, self.surfels);
        let column = |f: fn(&Surfel) -> [f32; 3]| -> [Lane; 3] {
            let mut out = [[0.0; LANES]; 3];
            for (i, s) in s.iter().enumerate() {
                let v = f(s.surfel());
                (out[0][i], out[1][i], out[2][i]) = (v[0], v[1], v[2]);
            }
            out
        };
        let eye = transform_point(&o.model_view, &column(|s| s.position));
        let [cx, cy, cz, cw] = mul_point4(&view.projection, &eye);
        let (width, height) = (view.width as f32, view.height as f32);
        let iw = lanes(|i| 1.0 / cw[i]);
        let wx = lanes(|i| (cx[i] * iw[i] * 0.5 + 0.5) * width);
        let wy = lanes(|i| (0.5 - cy[i] * iw[i] * 0.5) * height);
        let wz = lanes(|i| cz[i] * iw[i] * 0.5 + 0.5);
        let colour = shade(o, &mul_mat3(&o.normal, &column(|s| s.normal)), &eye);
        // `View::project`'s tests, written so that NaN fails every one. Every lane computes
        // them and its pixel, and the result is selected without a branch: with a branch a
        // lane, LLVM sank the lanes' arithmetic above into it, one lane at a time.
        let inside: [bool; LANES] = std::array::from_fn(|i| {
            let (x, y, z) = (wx[i], wy[i], wz[i]);
            (cw[i] > 0.0)
                & (x >= 0.0)
                & (x < width)
                & (y >= 0.0)
                & (y < height)
                & (0.0..=1.0).contains(&z)
        });
        // Saturating casts: meaningless outside, and exact inside (`0 ≤ x < width`). Every lane
        // runs this, in a view of no pixels too (where no lane is inside).
        let pixel: [u32; LANES] = std::array::from_fn(|i| {
            let px = (wx[i] as u32).min(view.width.saturating_sub(1));
            let py = (wy[i] as u32).min(view.height.saturating_sub(1));
            py.wrapping_mul(view.width).wrapping_add(px)
        });
        let outside = Fragment::default();
        for (i, out) in self.out.iter_mut().enumerate() {
            let z = wz[i];
            let moved = Fragment {
                depth: if z > 0.0 { z } else { 0.0 },
                color: colour[i],
                object: self.object,
            };
            *out = if inside[i] {
                (pixel[i], moved)
            } else {
                (u32::MAX, outside)
            };
        }
    }
}

/// One batch of [`View::entry_batch`]: the fragments' depths and colour bytes (packed
/// normals), all taken as fragments of `object`.
struct EntryJob<'a> {
    view: &'a View,
    o: &'a ObjectView,
    object: ObjectId,
    at: &'a [[u32; 2]; LANES],
    depths: &'a [f32; LANES],
    colors: &'a [Rgba8; LANES],
    out: &'a mut [Entry; LANES],
}

impl pulp::WithSimd for EntryJob<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let (view, o, at) = (self.view, self.o, self.at);
        let (depths, colors) = (self.depths, self.colors);
        let (width, height) = (view.width as f32, view.height as f32);
        // The pixel centre and the depth in normalised device coordinates.
        let ndc = [
            lanes(|i| (at[i][0] as f32 + 0.5) / width * 2.0 - 1.0),
            lanes(|i| 1.0 - (at[i][1] as f32 + 0.5) / height * 2.0),
            lanes(|i| depths[i] * 2.0 - 1.0),
        ];
        // P⁻¹ · ndc, then the division by w.
        let [ex, ey, ez, ew] = mul_point4(&view.inverse_projection, &ndc);
        let eye = [ex, ey, ez].map(|e| lanes(|i| e[i] / ew[i]));
        // The octahedral normal (`PackedNormal::unpack`), then to object space.
        let bits: [u32; LANES] = std::array::from_fn(|i| colors[i].to_bits());
        const SCALE: f32 = 65535.0;
        let u = lanes(|i| f32::from(bits[i] as u16) / SCALE * 2.0 - 1.0);
        let v = lanes(|i| f32::from((bits[i] >> 16) as u16) / SCALE * 2.0 - 1.0);
        let z = lanes(|i| 1.0 - u[i].abs() - v[i].abs());
        let sign = |a: f32| if a >= 0.0 { 1.0 } else { -1.0 };
        let x = lanes(|i| {
            let folded = (1.0 - v[i].abs()) * sign(u[i]);
            if z[i] >= 0.0 { u[i] } else { folded }
        });
        let y = lanes(|i| {
            let folded = (1.0 - u[i].abs()) * sign(v[i]);
            if z[i] >= 0.0 { v[i] } else { folded }
        });
        let inv = lanes(|i| 1.0 / (x[i] * x[i] + y[i] * y[i] + z[i] * z[i]).sqrt());
        let unit = [x, y, z].map(|c| lanes(|i| c[i] * inv[i]));
        let none = PackedNormal::NONE.to_bits();
        let object_normal = mul_mat3(&o.to_object_normal, &unit)
            .map(|c| lanes(|i| if o.lit && bits[i] != none { c[i] } else { 0.0 }));
        let position = transform_point(&o.inverse_model_view, &eye);
        let colour = shade(o, &mul_mat3(&o.normal, &object_normal), &eye);
        for (i, out) in self.out.iter_mut().enumerate() {
            *out = Entry {
                fragment: Fragment {
                    depth: depths[i],
                    color: colour[i],
                    object: self.object,
                },
                surfel: Surfel {
                    position: [position[0][i], position[1][i], position[2][i]],
                    normal: [
                        object_normal[0][i],
                        object_normal[1][i],
                        object_normal[2][i],
                    ],
                },
            };
        }
    }
}

impl View {
    /// [`View::project`] of [`LANES`] surfels of `object` (or of held entries' surfels), into
    /// `out`: `(pixel, fragment)`, or `(u32::MAX, Fragment::default())` where `project` gives
    /// `None` (so also for every lane when `object` is unknown).
    #[inline]
    pub(crate) fn project_batch<T: HasSurfel>(
        &self,
        object: ObjectId,
        surfels: &[T; LANES],
        out: &mut [(u32, Fragment); LANES],
    ) {
        match self.object(object) {
            Some(o) => pulp::Arch::new().dispatch(ProjectJob {
                view: self,
                o,
                object,
                surfels,
                out,
            }),
            None => out.fill((u32::MAX, Fragment::default())),
        }
    }

    /// [`View::entry`] of [`LANES`] normal fragments of `object` rendered at pixel columns and
    /// rows `at`, into `out`; `false` (and `out` untouched) if `object` is unknown, where
    /// `entry` gives `None`. Every fragment is converted as one of `object`: a lane holding a
    /// fragment of another object (padding past a batch's items) gives a meaningless entry.
    #[inline]
    pub(crate) fn entry_batch(
        &self,
        object: ObjectId,
        at: &[[u32; 2]; LANES],
        fragments: &[Fragment; LANES],
        out: &mut [Entry; LANES],
    ) -> bool {
        let Some(o) = self.object(object) else {
            return false;
        };
        pulp::Arch::new().dispatch(EntryJob {
            view: self,
            o,
            object,
            at,
            depths: &fragments.map(|f| f.depth),
            colors: &fragments.map(|f| f.color),
            out,
        });
        true
    }
}

/// Runs laid out as a frame's, row by row, with the fragment columns they index: what
/// [`View::row_entries`] reads. A node's rendered frame ([`FrameRows::of`]), or a display's
/// compacted inserts spread back over the view's pixels.
pub(crate) struct FrameRows<'a> {
    /// Pixels a row.
    pub width: usize,
    /// `offsets[p]..offsets[p + 1]` indexes the columns for pixel `p`.
    pub offsets: &'a [u32],
    pub depths: &'a [f32],
    pub colors: &'a [Rgba8],
    pub objects: &'a [ObjectId],
}

impl<'a> FrameRows<'a> {
    /// The rows of `frame`.
    pub(crate) fn of(frame: &'a DeepFrame) -> Self {
        FrameRows {
            width: frame.width() as usize,
            offsets: frame.offsets(),
            depths: frame.depths(),
            colors: frame.colors(),
            objects: frame.objects(),
        }
    }
}

/// [`View::row_entries`]' batches: each through the lanes, into the row's entries.
struct RowFlush<'a> {
    view: &'a View,
    row: u32,
    out: &'a mut [Entry],
    known: &'a mut [bool],
}

impl Flush<[u32; 2], Fragment> for RowFlush<'_> {
    #[inline(always)]
    fn flush(
        &mut self,
        object: ObjectId,
        to: &[[u32; 2]; LANES],
        fragments: &[Fragment; LANES],
        len: usize,
    ) {
        // `to`: each fragment's index in the row's fragments, and its column.
        let at = to.map(|[_, x]| [x, self.row]);
        debug_assert!(fragments[..len].iter().all(|f| f.object == object));
        let mut entries = [Entry::default(); LANES];
        if !self.view.entry_batch(object, &at, fragments, &mut entries) {
            return;
        }
        let first = to[0][0] as usize;
        if to[len - 1][0] as usize == first + len - 1 {
            // Consecutive fragments (always, where the row shows one object).
            self.out[first..first + len].copy_from_slice(&entries[..len]);
            self.known[first..first + len].fill(true);
        } else {
            for (&[k, _], e) in to[..len].iter().zip(&entries) {
                self.out[k as usize] = *e;
                self.known[k as usize] = true;
            }
        }
    }
}

impl View {
    /// [`View::entry`] of every normal fragment of row `row` of `frame` (rendered at this
    /// view), in the frame's order: `out[k]` is fragment `first + k`'s entry, where `first` is
    /// the row's first fragment, and `known[k]` says whether its object is known (`entry`
    /// gives `Some`); `out[k]` is meaningless where it is not. Fragments of one object go
    /// through the lanes together: a row of them as they lie, the others gathered
    /// ([`Pending`]).
    pub(crate) fn row_entries(
        &self,
        frame: &FrameRows<'_>,
        row: usize,
        out: &mut Vec<Entry>,
        known: &mut Vec<bool>,
    ) {
        let w = frame.width;
        let offsets = frame.offsets;
        let (first, last) = (offsets[row * w] as usize, offsets[(row + 1) * w] as usize);
        // Only `known` is cleared: an entry is written wherever its flag is set, and the
        // others are meaningless, so the last row's entries may stay (clearing them was a
        // memset of 36 bytes a fragment, 34 MB a dragon frame).
        out.resize(last - first, Entry::default());
        known.clear();
        known.resize(last - first, false);
        let (depths, colors, objects) = (frame.depths, frame.colors, frame.objects);
        let mut flush = RowFlush {
            view: self,
            row: row as u32,
            out,
            known,
        };
        // Where a fragment's entry goes: its index in the row's fragments, with its column; the
        // lanes' input: the fragment.
        let mut pending = Pending::<[u32; 2], Fragment>::default();
        // `LANES` consecutive fragments of one object (nearly all of an image row, where one
        // object fills the view) go through the lanes straight from the frame's columns into
        // their places; any other fragment through `Pending`. As in `Held::move_to`, after a
        // failed test the next fragments go one at a time ([`RowTests`]). `x` is the column of
        // fragment `k`, found by a cursor that only walks forward.
        let ends = &offsets[row * w + 1..(row + 1) * w + 1];
        let (mut k, mut x, mut tests) = (first, 0, RowTests::from(first));
        while k < last {
            if tests.due(k) && k + LANES <= last {
                let object = objects[k];
                if objects[k..k + LANES].iter().all(|&o| o == object) {
                    let mut at = [[0u32; 2]; LANES];
                    for (j, at) in at.iter_mut().enumerate() {
                        while ends[x] as usize <= k + j {
                            x += 1;
                        }
                        *at = [x as u32, row as u32];
                    }
                    let out = &mut flush.out[k - first..k - first + LANES];
                    if let Some(o) = self.object(object)
                        && let (Ok(depths), Ok(colors), Ok(out)) = (
                            depths[k..k + LANES].try_into(),
                            colors[k..k + LANES].try_into(),
                            out.try_into(),
                        )
                    {
                        pulp::Arch::new().dispatch(EntryJob {
                            view: self,
                            o,
                            object,
                            at: &at,
                            depths,
                            colors,
                            out,
                        });
                        flush.known[k - first..k - first + LANES].fill(true);
                    }
                    k += LANES;
                    tests.passed();
                    continue;
                }
                tests.failed(k);
            }
            while ends[x] as usize <= k {
                x += 1;
            }
            let f = Fragment {
                depth: depths[k],
                color: colors[k],
                object: objects[k],
            };
            pending.push(f.object, [(k - first) as u32, x as u32], f, &mut flush);
            k += 1;
        }
        pending.finish(&mut flush);
    }
}
