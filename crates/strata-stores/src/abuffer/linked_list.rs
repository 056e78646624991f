//! The per-pixel linked-list A-buffer (Jähne 2014 §2.1–2.2; Tsopouridis 2021 §3.1.2, Algorithms 4–6).
//!
//! # Layout
//!
//! ```text
//! heads: [u32; w*h]        index of the newest node of each pixel, EMPTY (u32::MAX) if none
//! nodes: [Node; capacity]  the node pool, 16 bytes a node:
//!                            word 0 = depth bits | rgba << 32
//!                            word 1 = object id  | next << 32     (next: older node or EMPTY)
//! next_free: AtomicU32     the allocation counter (Jähne 2014's atomic counter)
//! ```
//!
//! The thesis's colour node is 12 bytes (colour, depth, next); strata adds the object id.
//!
//! # Passes
//!
//! - **clear** (Alg. 4): every head to EMPTY, the counter to 0.
//! - **capture** (Alg. 5): for each fragment take a node from the pool, write it, link it in front
//!   of the pixel's list (`next = head; head = node`), so lists are built in reverse.
//!   On the GPU both steps are atomics. Here the rasterizer hands each strip of rows to one thread,
//!   so the head update is a plain store into that strip's `chunks_mut` slice of `heads`; and nodes
//!   are reserved from the shared counter in blocks of up to 1,024 (`crate::alloc`, shared with
//!   TFSS: `block_size`), so the counter is touched once per block rather than once per
//!   fragment, and two threads' writes seldom meet (with blocks of 64 they met often enough to
//!   make the two-thread scan a fifth slower).
//!   A block is written only by the thread that
//!   reserved it; nodes are pairs of `AtomicU64` written with `Relaxed` stores (plain moves on
//!   x86-64 and AArch64), which keeps the pool shareable without `unsafe`. The end of the parallel
//!   pass is the synchronisation point before anything reads the pool.
//! - **resolve** (Alg. 6): per pixel, walk the list into a local array (on the stack up to
//!   `LOCAL` fragments), sort it front to back (insertion sort for short lists, as Jähne 2014
//!   Alg. A.1 does with bubble sort), composite with OVER onto the background with early exit at
//!   full opacity. Walking a list is a chain of dependent loads, so lists are gathered over
//!   batches of [`GATHER_BATCH`] pixels: the first node of every list in the
//!   batch in one round, whose loads are independent, so the memory system serves them in
//!   parallel; then each pixel's remaining nodes. (Rounds over the whole batch until its longest
//!   list ended cost 6 % more instructions for no measurable gain; a second round for the
//!   second nodes alone moved the export's stalls without shortening them, though on the full
//!   dragon, a closed surface, 87 % of covered pixels hold 2 fragments and none holds 1; sixteen
//!   walkers that each take a new pixel when their list ends, keeping 16 loads in flight,
//!   measured no faster either.)
//!
//!   **Fused with the capture** when a frame is captured and resolved in one call
//!   ([`Method::capture_and_resolve`], what `render_frame` runs): each strip's sink resolves the
//!   strip's pixels in `finish`, on the thread that scanned it, as soon as its scan ends, while
//!   the nodes it just wrote (about 340 KB a strip on the dragon) are in that core's L2. Resolved
//!   after the whole capture, the first node of a list was a cache miss: two loads took 47 % of
//!   the resolve's time in `perf` on the dragon. A frame captured in several calls is resolved by
//!   [`Method::resolve`], rows in parallel, with the same per-pixel code (`resolve_pixels`).
//!   A render node's export is fused the same way ([`Method::capture_and_export`]): each strip
//!   walks its rows' lists in the same batches and writes their sorted fragments into columns
//!   of its own ([`strata_core::GatherWriter`], sized by the fragments the strip stored, so they
//!   do not grow when the frame is captured in one call, and kept by the store for the next
//!   export, so that a stream of frames maps no fresh pages) as its scan ends, and the frame is
//!   assembled from them.
//!
//! # Overflow
//!
//! When the counter passes the capacity, Alg. 5's check drops the fragment. Drops are counted and
//! reported, never silent. A thread may hold up to `block_size − 1` reserved but unused nodes when
//! its strip ends, so with a fixed capacity a frame can drop fragments while at most
//! `strips × (block_size − 1)` nodes stay unused: a sixteenth of the pool, or `strips × 63` for
//! a small one. With [`PoolCapacity::Auto`] (the default) an
//! overflowing frame grows the pool to fit and is captured again, reported as a regrow.
//!
//! # Determinism
//!
//! A pixel's list holds its fragments in primitive order whatever the thread count (each strip is
//! scanned by one thread in primitive order); only node indices depend on scheduling. Sorting by
//! [`strata_core::Fragment::order_key`] makes the resolved image and the DeepFrame independent of
//! both. Under overflow *which* fragments are dropped depends on scheduling, as on a GPU.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};

use rayon::prelude::*;
use strata_core::fragment::sort_front_to_back;
use strata_core::{
    DeepFrame, DeepFrameError, DepthStats, Fragment, GatherWriter, GatheredPixels, ObjectId,
    PassTimings, PixelRect, Rgb8Image, Rgba8, RunLimit, composite,
};
use strata_raster::setup::PixelFragment;
use strata_raster::{CaptureTarget, FragmentSink, FrameInput, Prepared, Rasterizer, StripLayout};

use crate::alloc::{BlockCursor, block_size, capacity_for};
use crate::method::{CaptureReport, Method, StoreError, try_alloc};
use crate::options::PoolCapacity;
use crate::resolve::resolve_chunks;
use crate::strip_export::{self, SpareColumns, StripSlot};

/// The name `--method` selects it by.
pub const NAME: &str = "abuffer";

/// The end of a list.
pub const EMPTY: u32 = u32::MAX;

/// The largest pool: leaves room above the capacity for the counter to overshoot by up to one
/// block a strip in a capture without wrapping (each capture of a frame starts its blocks at
/// the capacity again: `capture_prepared`), and keeps every index below [`EMPTY`].
pub const MAX_CAPACITY: u64 = 1 << 31;

/// Initial pool size for [`PoolCapacity::Auto`], as a multiple of the pixel count.
const AUTO_INITIAL_PER_PIXEL: u64 = 2;

/// Pixels whose lists are walked together, one node of each per round.
pub const GATHER_BATCH: usize = 16;

/// Fragments of a list the resolve walks into an array on the stack; a longer list continues in
/// a vector.
const LOCAL: usize = 32;

/// One pool node; see the module docs for the bit layout.
#[derive(Debug, Default)]
pub struct Node {
    w0: AtomicU64,
    w1: AtomicU64,
}

impl Node {
    #[inline(always)]
    fn store(&self, f: Fragment, next: u32) {
        self.w0.store(
            u64::from(f.depth.to_bits()) | (u64::from(f.color.to_bits()) << 32),
            Relaxed,
        );
        self.w1
            .store(u64::from(f.object.0) | (u64::from(next) << 32), Relaxed);
    }

    #[inline(always)]
    fn load(&self) -> (Fragment, u32) {
        let (w0, w1) = (self.w0.load(Relaxed), self.w1.load(Relaxed));
        (
            Fragment {
                depth: f32::from_bits(w0 as u32),
                color: Rgba8::from_bits((w0 >> 32) as u32),
                object: ObjectId(w1 as u32),
            },
            (w1 >> 32) as u32,
        )
    }
}

/// The linked-list A-buffer; see the module docs.
#[derive(Debug)]
pub struct LinkedListABuffer {
    capacity: PoolCapacity,
    width: u32,
    height: u32,
    heads: Vec<u32>,
    nodes: Vec<Node>,
    next_free: AtomicU32,
    stored: AtomicU64,
    dropped: AtomicU64,
    depth: Option<DepthStats>,
    /// The fused export's strip columns, kept for the next export.
    spare_columns: SpareColumns,
}

impl LinkedListABuffer {
    /// An empty A-buffer; buffers are sized at the first [`Method::clear`].
    pub fn new(capacity: PoolCapacity) -> Self {
        LinkedListABuffer {
            capacity,
            width: 0,
            height: 0,
            heads: Vec::new(),
            nodes: Vec::new(),
            next_free: AtomicU32::new(0),
            stored: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            depth: None,
            spare_columns: SpareColumns::default(),
        }
    }

    /// The fragments of the pixels in `rect`, as a frame of the rectangle's size — or `None` when
    /// the rectangle does not fit the frame or some stored fragment lies outside it, so that a
    /// caller guessing a footprint can never lose a fragment (it exports the whole frame then).
    /// Costs what the rectangle holds, not what the frame does.
    pub fn deep_frame_in(&self, rect: PixelRect) -> Option<Result<DeepFrame, DeepFrameError>> {
        if !rect.fits(self.width, self.height) {
            return None;
        }
        match self.export(rect) {
            Ok(f) if f.fragment_count() as u64 == self.stored.load(Relaxed) => Some(Ok(f)),
            // Fragments outside: the caller exports the whole frame.
            Ok(_) => None,
            // A bad fragment inside is the frame's error only when the rectangle is the frame;
            // otherwise the whole export reports it, with the frame's pixel index.
            Err(e) => (rect == PixelRect::full(self.width, self.height)).then_some(Err(e)),
        }
    }

    /// The fragments of rows `rows` (full width), as a frame of the band's size, whatever the
    /// store holds in other rows — one band of an export in bands: the bands of any split of
    /// `0..height`, appended in order ([`DeepFrame::append_rows`]), equal [`Method::deep_frame`].
    /// `None` when the rows are not inside the frame. Costs what the band holds.
    pub fn deep_frame_rows(
        &self,
        rows: std::ops::Range<u32>,
    ) -> Option<Result<DeepFrame, DeepFrameError>> {
        let rect = PixelRect {
            x: 0,
            y: rows.start,
            width: self.width,
            height: rows.end.checked_sub(rows.start)?,
        };
        rect.fits(self.width, self.height)
            .then(|| self.export(rect))
    }

    /// The pixels of `rect` as a frame of the rectangle's size: one walk of each list
    /// ([`DeepFrame::gather`]) — walking them once to count and again to copy cost as much as
    /// the capture's scan on the dragon.
    fn export(&self, rect: PixelRect) -> Result<DeepFrame, DeepFrameError> {
        let width = self.width;
        DeepFrame::gather(rect.width, rect.height, |q, out| {
            out.extend(self.list(rect.frame_index(q, width)));
        })
    }

    /// Nodes in the pool.
    pub fn capacity(&self) -> usize {
        self.nodes.len()
    }

    /// The pool size this frame asks for.
    fn wanted_capacity(&self) -> u64 {
        let pixels = u64::from(self.width) * u64::from(self.height);
        let n = match self.capacity {
            PoolCapacity::Auto => (pixels * AUTO_INITIAL_PER_PIXEL).max(self.nodes.len() as u64),
            PoolCapacity::PerPixel(k) => (pixels as f64 * k).ceil() as u64,
            PoolCapacity::Fragments(n) => n,
        };
        n.clamp(1, MAX_CAPACITY)
    }

    fn resize_pool(&mut self, n: u64) -> Result<(), StoreError> {
        let n = n.clamp(1, MAX_CAPACITY) as usize;
        if self.nodes.len() != n {
            self.nodes = Vec::new(); // free the old pool before allocating the new one
            self.nodes = try_alloc(
                n,
                || format!("a node pool of {n} fragments"),
                "give a smaller --pool (a multiple of the pixel count like 4x), or auto",
            )?;
        }
        Ok(())
    }

    /// Where this capture starts: the first node it may take and the fragments stored before.
    fn chunk_mark(&self) -> (u32, u64) {
        let next = self.next_free.load(Relaxed).min(self.nodes.len() as u32);
        (next, self.stored.load(Relaxed))
    }

    /// Undoes a capture that started at `mark`: lists are newest first, so the nodes it took
    /// (indices from `mark.0` on) are at the front of each list and are unlinked there; what
    /// earlier captures of the frame stored stays.
    fn roll_back_to(&mut self, (first, stored): (u32, u64)) {
        let nodes = &self.nodes;
        self.heads.par_iter_mut().for_each(|h| {
            while *h != EMPTY && *h >= first {
                *h = nodes[*h as usize].load().1;
            }
        });
        self.next_free.store(first, Relaxed);
        self.stored.store(stored, Relaxed);
        self.dropped.store(0, Relaxed);
    }

    /// Grows the pool to `n` nodes, keeping the first `keep` (the frame's earlier captures).
    fn grow_pool_keeping(&mut self, n: u64, keep: u32) -> Result<(), StoreError> {
        if keep == 0 {
            return self.resize_pool(n);
        }
        let n = n.clamp(1, MAX_CAPACITY) as usize;
        let grown: Vec<Node> = try_alloc(
            n,
            || format!("a node pool of {n} fragments"),
            "give a smaller --pool (a multiple of the pixel count like 4x), or auto",
        )?;
        grown[..keep as usize]
            .par_iter()
            .zip(&self.nodes[..keep as usize])
            .for_each(|(to, from)| {
                let (f, next) = from.load();
                to.store(f, next);
            });
        self.nodes = grown;
        Ok(())
    }

    fn reset_lists(&mut self) {
        self.heads.par_iter_mut().for_each(|h| *h = EMPTY);
        self.next_free.store(0, Relaxed);
        self.stored.store(0, Relaxed);
        self.dropped.store(0, Relaxed);
    }

    /// Walks pixel `p`'s list, newest first.
    #[inline]
    fn list(&self, p: usize) -> impl Iterator<Item = Fragment> + '_ {
        walk(self.heads[p], &self.nodes)
    }
}

/// Capture into one strip of rows.
#[derive(Debug)]
pub struct LinkedListSink<'a> {
    heads: &'a mut [u32],
    first_pixel: u32,
    nodes: &'a [Node],
    next_free: &'a AtomicU32,
    stored: &'a AtomicU64,
    dropped: &'a AtomicU64,
    block: BlockCursor,
    /// Nodes reserved at a time (`crate::alloc::block_size`).
    block_size: u32,
    n_stored: u64,
    n_dropped: u64,
    work: Option<StripWork<'a>>,
}

/// What a sink does with its strip when its scan ends, in a fused pass.
#[derive(Debug)]
enum StripWork<'a> {
    /// Resolve the strip into its rows of the image; its depth statistics and resolve time go
    /// to `report`.
    Resolve {
        out: &'a mut [u8],
        background: [f32; 3],
        report: &'a mut StripReport,
    },
    /// Gather the strip's fragments for the frame's DeepFrame.
    Export(&'a mut StripSlot),
}

/// What resolving one strip found and took.
#[derive(Clone, Debug, Default)]
struct StripReport {
    depth: DepthStats,
    time: Duration,
}

/// Puts `fragment` in pool node `index` and makes it the head of the strip's pixel `local`'s
/// list, in front of the old head.
#[inline(always)]
fn link(heads: &mut [u32], nodes: &[Node], local: u32, index: u32, fragment: Fragment) {
    let head = &mut heads[local as usize];
    nodes[index as usize].store(fragment, *head);
    *head = index;
}

impl FragmentSink for LinkedListSink<'_> {
    #[inline(always)]
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        let Some(index) = self
            .block
            .next(self.next_free, self.nodes.len() as u32, self.block_size)
        else {
            self.n_dropped += 1;
            return;
        };
        link(
            self.heads,
            self.nodes,
            pixel - self.first_pixel,
            index,
            fragment,
        );
        self.n_stored += 1;
    }

    /// [`FragmentSink::push`] for a run of records, with the block cursor and the counts in
    /// locals: pushed one at a time, each reloads and stores them, since the node stores might
    /// alias them.
    #[inline(always)]
    fn push_records(&mut self, records: &[PixelFragment], object: ObjectId) {
        let (heads, nodes, first) = (&mut *self.heads, self.nodes, self.first_pixel);
        let capacity = nodes.len() as u32;
        let (mut cur, mut end) = self.block.bounds();
        let mut stored = 0u64;
        for r in records {
            let index = if cur != end {
                cur += 1;
                cur - 1
            } else {
                // A new block (rare): through the cursor itself.
                self.block.set_bounds(cur, end);
                let Some(index) = self.block.next(self.next_free, capacity, self.block_size) else {
                    continue;
                };
                (cur, end) = self.block.bounds();
                index
            };
            link(heads, nodes, r.pixel - first, index, r.fragment(object));
            stored += 1;
        }
        self.block.set_bounds(cur, end);
        self.n_stored += stored;
        self.n_dropped += records.len() as u64 - stored;
    }

    /// Ends the strip; in a fused pass, resolves or gathers its pixels now, on this thread,
    /// while the nodes it just wrote are in this core's cache.
    fn finish(&mut self) {
        match self.work.take() {
            None => {}
            Some(StripWork::Resolve {
                out,
                background,
                report,
            }) => {
                let start = Instant::now();
                // A fresh report: a pass captured again after a regrow resolves every strip
                // anew.
                let mut depth = DepthStats::default();
                resolve_pixels(
                    self.heads,
                    self.nodes,
                    out,
                    background,
                    &mut depth,
                    &mut Vec::new(),
                );
                *report = StripReport {
                    depth,
                    time: start.elapsed(),
                };
            }
            Some(StripWork::Export(slot)) => {
                let first = self.first_pixel as usize;
                let writer = slot.writer(self.heads.len(), self.n_stored as usize);
                slot.fill(gather_strip(self.heads, self.nodes, first, writer));
            }
        }
        self.stored.fetch_add(self.n_stored, Relaxed);
        self.dropped.fetch_add(self.n_dropped, Relaxed);
    }
}

impl CaptureTarget for LinkedListABuffer {
    type Sink<'s> = LinkedListSink<'s>;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<LinkedListSink<'_>> {
        self.sinks_working(layout, None)
    }
}

/// What a fused pass does with each strip as its scan ends.
enum Fused<'a> {
    /// Resolve into `image` (RGB bytes), each strip's report into `reports`.
    Resolve {
        image: &'a mut [u8],
        background: [f32; 3],
        reports: &'a mut [StripReport],
    },
    /// Gather each strip's fragments into its slot.
    Export(&'a mut [StripSlot]),
}

/// The linked list as the target of a fused pass: each sink resolves or gathers its strip when
/// the strip's scan ends.
struct FusedTarget<'a, 'f> {
    store: &'a mut LinkedListABuffer,
    fused: &'a mut Fused<'f>,
}

impl CaptureTarget for FusedTarget<'_, '_> {
    type Sink<'s>
        = LinkedListSink<'s>
    where
        Self: 's;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<LinkedListSink<'_>> {
        let work: Vec<StripWork<'_>> = match self.fused {
            Fused::Resolve {
                image,
                background,
                reports,
            } => image
                .chunks_mut(layout.pixels_per_strip() * 3)
                .zip(reports.iter_mut())
                .map(|(out, report)| StripWork::Resolve {
                    out,
                    background: *background,
                    report,
                })
                .collect(),
            Fused::Export(slots) => slots.iter_mut().map(StripWork::Export).collect(),
        };
        self.store.sinks_working(layout, Some(work))
    }
}

impl LinkedListABuffer {
    /// One sink a strip; with `work`, one item a strip, each sink does its item when it
    /// finishes.
    fn sinks_working<'s>(
        &'s mut self,
        layout: &StripLayout,
        work: Option<Vec<StripWork<'s>>>,
    ) -> Vec<LinkedListSink<'s>> {
        if let Some(w) = &work {
            assert_eq!(w.len(), layout.count(), "one work item a strip");
        }
        assert_eq!(
            (layout.width, layout.height),
            (self.width, self.height),
            "clear before capture"
        );
        let (nodes, next_free, stored, dropped) = (
            &self.nodes[..],
            &self.next_free,
            &self.stored,
            &self.dropped,
        );
        let mut work = work.map(Vec::into_iter);
        let block_size = block_size(nodes.len(), layout.count());
        let sinks: Vec<LinkedListSink<'s>> = layout
            .split_mut(&mut self.heads)
            .enumerate()
            .map(|(s, heads)| LinkedListSink {
                heads,
                first_pixel: layout.pixels(s).start as u32,
                nodes,
                next_free,
                stored,
                dropped,
                block: BlockCursor::default(),
                block_size,
                n_stored: 0,
                n_dropped: 0,
                work: work.as_mut().and_then(Iterator::next),
            })
            .collect();
        sinks
    }

    /// Captures a prepared frame, growing the pool and capturing again while an automatic pool
    /// overflows; with `fused`, resolves or gathers each strip as its scan ends (see
    /// [`Method::capture_and_resolve`]). Returns the report and the wall time of the final scan.
    fn capture_prepared(
        &mut self,
        prepared: &Prepared<'_, '_>,
        timings: &mut PassTimings,
        mut fused: Option<Fused<'_>>,
    ) -> Result<(CaptureReport, Duration), StoreError> {
        let mut regrows = 0;
        // What earlier captures of this frame hold (captures accumulate, see `Method`).
        let mark = self.chunk_mark();
        // An earlier capture that exhausted the pool left the counter past the capacity, by up
        // to a block a strip; start this one's blocks at the capacity again, so that chunk after
        // chunk cannot carry the counter round past `u32::MAX`.
        self.next_free.store(mark.0, Relaxed);
        loop {
            let start = Instant::now();
            let stats = match fused.as_mut() {
                Some(fused) => prepared.rasterize(&mut FusedTarget { store: self, fused }),
                None => prepared.rasterize(self),
            };
            let scan = start.elapsed();
            let dropped = self.dropped.load(Relaxed);
            if dropped == 0
                || self.capacity != PoolCapacity::Auto
                || self.nodes.len() as u64 >= MAX_CAPACITY
            {
                let report = CaptureReport {
                    fragments_rasterized: stats.fragments,
                    fragments_stored: self.stored.load(Relaxed),
                    dropped,
                    regrows,
                    raster_passes: 1 + regrows,
                    setup: prepared.setup_stats(),
                    ..CaptureReport::default()
                };
                return Ok((report, scan));
            }
            timings.add("capture.raster", scan);
            // Grow to hold every fragment plus each strip's unused block tail, with headroom
            // for the next frames, and capture again.
            let start = Instant::now();
            let strips = prepared.layout().count();
            self.roll_back_to(mark);
            self.grow_pool_keeping(
                capacity_for(u64::from(mark.0) + stats.fragments, strips) * 5 / 4,
                mark.0,
            )?;
            regrows += 1;
            timings.add("capture.regrow", start.elapsed());
        }
    }
}

/// The first node of each list of a batch of [`GATHER_BATCH`] consecutive pixels, loaded in
/// one round over the batch whose loads are independent (see the module docs); each pixel's
/// remaining nodes are then walked one pixel at a time.
struct FirstNodes([(Fragment, u32); GATHER_BATCH]);

impl FirstNodes {
    /// Loads the first nodes of the lists whose heads are `heads` (at most [`GATHER_BATCH`]);
    /// a pixel without a list gets `(Fragment::default(), EMPTY)`.
    #[inline]
    fn load(heads: &[u32], nodes: &[Node]) -> Self {
        debug_assert!(heads.len() <= GATHER_BATCH);
        let mut first = [(Fragment::default(), EMPTY); GATHER_BATCH];
        for (f, &head) in first.iter_mut().zip(heads) {
            if head != EMPTY {
                *f = nodes[head as usize].load();
            }
        }
        FirstNodes(first)
    }

    /// Walks the list of the batch's pixel `i`, which must have one, into `local` (the first
    /// [`LOCAL`] fragments) and on into `long` (reused, so no allocation once it has grown) if
    /// it is longer; returns the run, in list order.
    #[inline]
    fn walk_into<'a>(
        &self,
        i: usize,
        nodes: &[Node],
        local: &'a mut [Fragment; LOCAL],
        long: &'a mut Vec<Fragment>,
    ) -> &'a mut [Fragment] {
        let mut next;
        (local[0], next) = self.0[i];
        let mut n = 1;
        while next != EMPTY && n < LOCAL {
            (local[n], next) = nodes[next as usize].load();
            n += 1;
        }
        if next == EMPTY {
            return &mut local[..n];
        }
        long.clear();
        long.extend_from_slice(&local[..]);
        long.extend(walk(next, nodes));
        &mut long[..]
    }
}

/// Gathers a strip's lists (`heads` of the frame pixels from `first_pixel` on) into columns
/// with `g` (sized for what the strip stored, and cutting runs to its export's limit), each
/// run sorted front to back, in batches of [`GATHER_BATCH`] pixels as the resolve walks them.
fn gather_strip(
    heads: &[u32],
    nodes: &[Node],
    first_pixel: usize,
    mut g: GatherWriter,
) -> Result<GatheredPixels, DeepFrameError> {
    let mut local = [Fragment::default(); LOCAL];
    let mut long = Vec::new();
    for (b, heads) in heads.chunks(GATHER_BATCH).enumerate() {
        if heads.iter().all(|&h| h == EMPTY) {
            g.push_empty(heads.len());
            continue;
        }
        let first = FirstNodes::load(heads, nodes);
        for (i, &head) in heads.iter().enumerate() {
            if head == EMPTY {
                g.push_empty(1);
            } else {
                let run = first.walk_into(i, nodes, &mut local, &mut long);
                g.push_run(first_pixel + b * GATHER_BATCH + i, run)?;
            }
        }
    }
    Ok(g.finish())
}

/// The list starting at node `head`, newest first.
#[inline]
fn walk(head: u32, nodes: &[Node]) -> impl Iterator<Item = Fragment> + '_ {
    let mut i = head;
    std::iter::from_fn(move || {
        if i == EMPTY {
            return None;
        }
        let (f, next) = nodes[i as usize].load();
        i = next;
        Some(f)
    })
}

/// Resolves the pixels whose list heads are `heads` into `out` (3 bytes a pixel), recording
/// each pixel's fragment count in `stats`, in batches of [`GATHER_BATCH`] pixels (see the module
/// docs): a batch without a fragment is filled with the background at once; otherwise the first
/// node of every list in the batch is loaded in one round, whose loads are independent, then
/// each pixel in turn is finished. A list of one fragment is composited as it is; a longer one
/// is walked into `list` (reused, so no allocation once it has grown), sorted front to back and
/// composited onto `background`.
fn resolve_pixels(
    heads: &[u32],
    nodes: &[Node],
    out: &mut [u8],
    background: [f32; 3],
    stats: &mut DepthStats,
    list: &mut Vec<Fragment>,
) {
    debug_assert_eq!(heads.len() * 3, out.len());
    let resolver = composite::PixelResolver::new(background);
    let bg = composite::background_pixel(background);
    // Pixels by fragment count up to LOCAL, recorded once at the end.
    let mut counts = [0u64; LOCAL + 1];
    // Lists up to LOCAL fragments are walked into `local`; longer ones continue in `list`.
    let mut local = [Fragment::default(); LOCAL];
    for (heads, batch) in heads
        .chunks(GATHER_BATCH)
        .zip(out.chunks_mut(GATHER_BATCH * 3))
    {
        if heads.iter().all(|&h| h == EMPTY) {
            for px in batch.chunks_exact_mut(3) {
                px.copy_from_slice(&bg);
            }
            counts[0] += heads.len() as u64;
            continue;
        }
        // The batch's first nodes, loaded and walked here rather than through `FirstNodes` as
        // the export does: this loop is the one callgrind counted at 343.0 M instructions for
        // four dragon frames, and a walk shared with the export (with a second round of loads)
        // counted 346-358 M. A shared one-round walk was not measured on its own.
        let mut first = [(Fragment::default(), EMPTY); GATHER_BATCH];
        for (f, &head) in first.iter_mut().zip(heads) {
            if head != EMPTY {
                *f = nodes[head as usize].load();
            }
        }
        for (i, px) in batch.chunks_exact_mut(3).enumerate() {
            let (f, mut next) = first[i];
            let rgb = if heads[i] == EMPTY {
                counts[0] += 1;
                bg
            } else if next == EMPTY {
                counts[1] += 1;
                resolver.resolve([f.color])
            } else {
                local[0] = f;
                let mut n = 1;
                while next != EMPTY && n < LOCAL {
                    (local[n], next) = nodes[next as usize].load();
                    n += 1;
                }
                let run = if next == EMPTY {
                    counts[n] += 1;
                    &mut local[..n]
                } else {
                    list.clear();
                    list.extend_from_slice(&local);
                    while next != EMPTY {
                        let (g, after) = nodes[next as usize].load();
                        list.push(g);
                        next = after;
                    }
                    stats.record(list.len() as u32);
                    &mut list[..]
                };
                sort_front_to_back(run);
                resolver.resolve(run.iter().map(|f| f.color))
            };
            px.copy_from_slice(&rgb);
        }
    }
    for (n, &c) in counts.iter().enumerate() {
        if c != 0 {
            stats.record_many(n as u32, c);
        }
    }
}

impl Method for LinkedListABuffer {
    fn name(&self) -> &'static str {
        "abuffer"
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        let pixels = width as usize * height as usize;
        assert!(
            (pixels as u64) < u64::from(EMPTY),
            "image too large for u32 pixel indices"
        );
        (self.width, self.height) = (width, height);
        if self.heads.len() != pixels {
            self.heads = Vec::new();
            self.heads = try_alloc::<u32>(
                pixels,
                || format!("{pixels} list heads"),
                "render a smaller image",
            )?;
        }
        self.resize_pool(self.wanted_capacity())?;
        self.reset_lists();
        self.depth = None;
        Ok(())
    }

    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());
        let (report, scan) = self.capture_prepared(&prepared, timings, None)?;
        timings.add("capture.raster", scan);
        Ok(report)
    }

    /// Fused: every strip is resolved by the thread that scanned it, as the scan ends (see
    /// [`Method::capture_and_resolve`]). The fused pass's wall time is split by thread time: its
    /// resolve share is the strips' summed resolve time over the threads that ran them (at most
    /// the pass's wall time), the rest is `capture.raster`.
    fn capture_and_resolve(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        background: [f32; 3],
        timings: &mut PassTimings,
    ) -> Result<(CaptureReport, Rgb8Image), StoreError> {
        let start = Instant::now();
        let prepared = raster.prepare(input);
        let mut stages = PassTimings::new();
        stages.extend(prepared.timings());
        let layout = *prepared.layout();
        let mut image = Rgb8Image::filled(self.width, self.height, [0; 3]);
        let mut reports = vec![StripReport::default(); layout.count()];
        let (report, scan) = self.capture_prepared(
            &prepared,
            &mut stages,
            Some(Fused::Resolve {
                image: image.as_bytes_mut(),
                background,
                reports: &mut reports,
            }),
        )?;
        let threads = rayon::current_num_threads().clamp(1, layout.count()) as u32;
        let resolve = (reports.iter().map(|r| r.time).sum::<Duration>() / threads).min(scan);
        stages.add("capture.raster", scan - resolve);
        let mut depth = DepthStats::default();
        for r in &reports {
            depth.merge(&r.depth);
        }
        self.depth = Some(depth);
        timings.add("capture", start.elapsed().saturating_sub(resolve));
        timings.extend(&stages);
        timings.add("resolve", resolve);
        Ok((report, image))
    }

    /// Fused: every strip gathers its rows' fragments as its scan ends, and the frame is
    /// assembled from the strips' columns (see [`Method::capture_and_export`]).
    fn capture_and_export(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        limit: RunLimit,
        timings: &mut PassTimings,
        reuse: Option<DeepFrame>,
    ) -> Result<(CaptureReport, Option<Result<DeepFrame, DeepFrameError>>), StoreError> {
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());
        let mut slots = strip_export::slots(prepared.layout(), limit, &mut self.spare_columns);
        let (report, scan) =
            self.capture_prepared(&prepared, timings, Some(Fused::Export(&mut slots)))?;
        timings.add("capture.raster", scan);
        let start = Instant::now();
        let (width, height) = (self.width, self.height);
        let frame = strip_export::assemble(width, height, slots, reuse, &mut self.spare_columns);
        timings.add("capture.export", start.elapsed());
        Ok((report, Some(frame)))
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        let (heads, nodes) = (&self.heads, &self.nodes);
        let (image, depth) = resolve_chunks(
            self.width,
            self.height,
            Vec::new,
            |list, first, out, stats| {
                let heads = &heads[first..first + out.len() / 3];
                resolve_pixels(heads, nodes, out, background, stats, list);
            },
        );
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    fn used_memory_bytes(&self) -> u64 {
        (self.heads.len() * size_of::<u32>()) as u64
            + self.stored.load(Relaxed) * size_of::<Node>() as u64
            + size_of::<AtomicU32>() as u64
    }

    fn memory_bytes(&self) -> u64 {
        (self.heads.len() * size_of::<u32>()
            + self.nodes.len() * size_of::<Node>()
            + size_of::<AtomicU32>()) as u64
    }

    fn captures_in_chunks(&self) -> bool {
        true
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        let all = PixelRect::full(self.width, self.height);
        Some(self.export(all))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frag(depth: f32, o: u32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([o as u8, 0, 0, 255]),
            object: ObjectId(o),
        }
    }

    /// Pushes fragments through the sinks directly, bypassing the rasterizer.
    fn capture(ab: &mut LinkedListABuffer, layout: &StripLayout, frags: &[(u32, Fragment)]) {
        let mut sinks = ab.sinks(layout);
        for &(p, f) in frags {
            let s = p as usize / layout.pixels_per_strip();
            sinks[s].push(p, f);
        }
        for s in &mut sinks {
            s.finish();
        }
    }

    #[test]
    fn lists_are_built_in_reverse_and_resolve_sorted() {
        let layout = StripLayout {
            width: 4,
            height: 4,
            strip_height: 2,
        };
        let mut ab = LinkedListABuffer::new(PoolCapacity::Fragments(100));
        ab.clear(4, 4).unwrap();
        capture(
            &mut ab,
            &layout,
            &[(5, frag(0.5, 1)), (5, frag(0.2, 2)), (13, frag(0.9, 3))],
        );
        assert_eq!(
            ab.list(5).collect::<Vec<_>>(),
            vec![frag(0.2, 2), frag(0.5, 1)]
        );
        assert_eq!(ab.list(0).count(), 0);
        let df = ab.deep_frame().unwrap().unwrap();
        assert_eq!(df.pixel(1, 1).depth, &[0.2, 0.5]);
        let img = ab.resolve([1.0; 3], &mut PassTimings::new());
        assert_eq!(img.pixel(1, 1), [2, 0, 0]); // opaque fragment of object 2 in front
        assert_eq!(img, df.resolve([1.0; 3]));
        let s = ab.depth_stats().unwrap();
        assert_eq!(
            (s.fragments(), s.max_depth_complexity(), s.covered_pixels()),
            (3, 2, 2)
        );
    }

    /// Lists of every length from 0 to past the resolve's stack array (`LOCAL`), each with
    /// translucent fragments pushed in no depth order, resolve as their DeepFrame does, one
    /// pixel and one depth count each; the fused passes (resolve and export) give the same.
    #[test]
    fn lists_longer_than_the_stack_array_resolve_like_short_ones() {
        let lengths: Vec<usize> = (0..=LOCAL + 3).chain([2 * LOCAL + 1]).collect();
        let width = lengths.len() as u32;
        let layout = StripLayout {
            width,
            height: 1,
            strip_height: 1,
        };
        let mut frags = Vec::new();
        for (p, &n) in lengths.iter().enumerate() {
            for i in 0..n {
                // A scrambled depth order, distinct colours, alpha 0.1.
                let depth = ((i * 7919) % 101) as f32 / 101.0;
                let color = Rgba8([(i * 37) as u8, (p * 11) as u8, (i * 5) as u8, 26]);
                frags.push((
                    p as u32,
                    Fragment {
                        depth,
                        color,
                        object: ObjectId(i as u32),
                    },
                ));
            }
        }
        let background = [0.25, 0.5, 1.0];
        let mut ab = LinkedListABuffer::new(PoolCapacity::Fragments(10_000));
        ab.clear(width, 1).unwrap();
        capture(&mut ab, &layout, &frags);
        let want = ab.deep_frame().unwrap().unwrap();
        let img = ab.resolve(background, &mut PassTimings::new());
        assert_eq!(img, want.resolve(background));
        let stats = ab.depth_stats().unwrap();
        assert_eq!(stats.max_depth_complexity(), 2 * LOCAL as u32 + 1);
        let mut histogram = vec![0u64; 2 * LOCAL + 2];
        for &n in &lengths {
            histogram[n] += 1;
        }
        assert_eq!(stats.histogram(), &histogram[..]);

        // The same lists resolved strip by strip, as the fused pass does.
        let mut image = Rgb8Image::filled(width, 1, [0; 3]);
        let mut reports = vec![StripReport::default(); 1];
        let mut fused = Fused::Resolve {
            image: image.as_bytes_mut(),
            background,
            reports: &mut reports,
        };
        let mut target = FusedTarget {
            store: &mut ab,
            fused: &mut fused,
        };
        for mut s in target.sinks(&layout) {
            s.finish();
        }
        assert_eq!(image, img);
        assert_eq!(reports[0].depth, stats);

        // And gathered strip by strip, as the fused export does (its batches of lists' fronts
        // end mid-strip and hold an empty pixel).
        let mut spare = SpareColumns::default();
        let mut slots = strip_export::slots(&layout, RunLimit::NONE, &mut spare);
        let mut fused = Fused::Export(&mut slots);
        let mut target = FusedTarget {
            store: &mut ab,
            fused: &mut fused,
        };
        for mut s in target.sinks(&layout) {
            s.finish();
        }
        let frame =
            strip_export::assemble(width, 1, slots, None, &mut spare).expect("valid depths");
        assert_eq!(frame, want);
    }

    #[test]
    fn a_window_exports_its_pixels_only_if_it_holds_every_fragment() {
        let layout = StripLayout {
            width: 4,
            height: 4,
            strip_height: 2,
        };
        let mut ab = LinkedListABuffer::new(PoolCapacity::Fragments(100));
        ab.clear(4, 4).unwrap();
        // Pixels (1, 1) and (2, 2).
        capture(
            &mut ab,
            &layout,
            &[(5, frag(0.5, 1)), (5, frag(0.2, 2)), (10, frag(0.9, 3))],
        );
        let rect = |x, y, width, height| PixelRect {
            x,
            y,
            width,
            height,
        };
        let w = ab.deep_frame_in(rect(1, 1, 2, 2)).unwrap().unwrap();
        assert_eq!((w.width(), w.height()), (2, 2));
        assert_eq!(w.pixel(0, 0).depth, &[0.2, 0.5]);
        assert_eq!(w.pixel(1, 1).depth, &[0.9]);
        assert_eq!(w.fragment_count(), 3);
        // A window that misses a fragment, or does not fit the frame, exports nothing.
        assert!(ab.deep_frame_in(rect(1, 1, 1, 1)).is_none());
        assert!(ab.deep_frame_in(rect(2, 2, 3, 1)).is_none());
        assert_eq!(
            ab.deep_frame_in(PixelRect::full(4, 4)).unwrap().unwrap(),
            ab.deep_frame().unwrap().unwrap()
        );
    }

    #[test]
    fn bands_of_rows_export_what_the_whole_frame_does() {
        let layout = StripLayout {
            width: 4,
            height: 4,
            strip_height: 2,
        };
        let mut ab = LinkedListABuffer::new(PoolCapacity::Fragments(100));
        ab.clear(4, 4).unwrap();
        let frags = [
            (1, frag(0.5, 1)),
            (5, frag(0.2, 2)),
            (5, frag(0.7, 3)),
            (14, frag(0.9, 4)),
        ];
        capture(&mut ab, &layout, &frags);
        let whole = ab.deep_frame().unwrap().unwrap();
        for cuts in [
            vec![0, 4],
            vec![0, 1, 2, 3, 4],
            vec![0, 3, 4],
            vec![0, 2, 2, 4],
        ] {
            let mut assembled = DeepFrame::empty(4, 0);
            for w in cuts.windows(2) {
                let band = ab.deep_frame_rows(w[0]..w[1]).unwrap().unwrap();
                assert_eq!((band.width(), band.height()), (4, w[1] - w[0]));
                assembled.append_rows(&band).unwrap();
            }
            assert_eq!(assembled, whole, "{cuts:?}");
        }
        assert!(ab.deep_frame_rows(3..5).is_none());
        let (hi, lo) = (3, 2);
        assert!(ab.deep_frame_rows(hi..lo).is_none(), "a reversed range");
    }

    #[test]
    fn overflow_is_counted_not_silent() {
        let layout = StripLayout {
            width: 2,
            height: 2,
            strip_height: 2,
        };
        let mut ab = LinkedListABuffer::new(PoolCapacity::Fragments(10));
        ab.clear(2, 2).unwrap();
        let frags: Vec<_> = (0..25).map(|i| (i % 4, frag(i as f32 / 25.0, i))).collect();
        capture(&mut ab, &layout, &frags);
        assert_eq!(ab.stored.load(Relaxed), 10);
        assert_eq!(ab.dropped.load(Relaxed), 15);
        // The first ten fragments made it (one strip, one block).
        let kept: usize = (0..4).map(|p| ab.list(p).count()).sum();
        assert_eq!(kept, 10);
    }

    #[test]
    fn clear_empties_every_list() {
        let layout = StripLayout {
            width: 2,
            height: 1,
            strip_height: 1,
        };
        let mut ab = LinkedListABuffer::new(PoolCapacity::PerPixel(4.0));
        ab.clear(2, 1).unwrap();
        assert_eq!(ab.capacity(), 8);
        capture(&mut ab, &layout, &[(0, frag(0.1, 0)), (1, frag(0.2, 1))]);
        ab.clear(2, 1).unwrap();
        assert_eq!(ab.list(0).count() + ab.list(1).count(), 0);
        assert_eq!(
            ab.resolve([0.0, 0.0, 1.0], &mut PassTimings::new())
                .pixel(0, 0),
            [0, 0, 255]
        );
    }

    #[test]
    fn memory_is_heads_plus_pool() {
        let mut ab = LinkedListABuffer::new(PoolCapacity::Fragments(1000));
        ab.clear(10, 10).unwrap();
        assert_eq!(ab.memory_bytes(), 100 * 4 + 1000 * 16 + 4);
        assert_eq!(size_of::<Node>(), 16);
    }
}
