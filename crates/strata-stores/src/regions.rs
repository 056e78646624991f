//! Per-pixel regions in one fragment array: the storage shared by the fixed-array A-buffer, the
//! S-buffer and the k-buffers.
//!
//! # Layout (the S-buffer layout of Tsopouridis 2021 §3.1.3)
//!
//! ```text
//! offsets: [u32; w*h + 1]   pixel p (row-major) owns slots offsets[p] .. offsets[p+1]
//! fill:    [u32; w*h]       how many of its slots pixel p has used
//! slots:   [Fragment; n]    12 bytes each (depth, RGBA8, object id)
//! ```
//!
//! The methods differ only in how they size the regions and what a full region does:
//!
//! | method | capacity of pixel `p` | a fragment arriving at a full region |
//! | --- | --- | --- |
//! | fixed-array A-buffer (Tsopouridis 2021 Alg. 1–3) | `A` for every pixel | is dropped and counted ([`Policy::Append`]) |
//! | S-buffer (Alg. 7–12) | its exact fragment count (a counting pass) | cannot happen |
//! | k-buffer (Alg. 13–15) | `k` for every pixel | replaces the farthest kept one if nearer ([`Policy::KeepNearest`]) |
//! | variable k-buffer (Alg. 16–21) | `k(p)` from an importance map | as the k-buffer |
//!
//! Under [`Policy::KeepNearest`] a region is kept sorted front to back by insertion (Tsopouridis 2021
//! Alg. 14); the fragment that falls off the end — the new one or the farthest kept — is *evicted*
//! and reported to an optional [`Evicted`] callback, or returned to a store that wraps the sink
//! with per-strip state of its own ([`RegionSink::insert_nearest`]: the k-buffer's tail blend).
//! [`Regions::sort_runs`] and [`Regions::truncate`] turn exact Append regions into the k(p)
//! nearest of each pixel (the Optimal-K oracle's S-buffer).
//!
//! When every region has the same capacity `k` (the fixed-array A-buffer and the k-buffer,
//! [`Regions::uniform`]), a strip's sinks find pixel `p`'s region at `p·k` instead of loading
//! `offsets[p]` and `offsets[p + 1]`: one dependent load less a fragment, and the offsets stay
//! out of the cache. On the full dragon, one thread, this took the k-buffer's capture from 15.7
//! to 13.2 ms and the fixed-array A-buffer's from 15.9 to 13.8 (`scripts/bench-side-by-side`,
//! 2-core AMD EPYC).
//!
//! Regions are row-major and contiguous, so a strip of rows owns one contiguous range of `fill`
//! and of `slots`: [`Regions::strips`] hands each rasterizer strip its own `&mut` slices, and
//! capture needs no atomics (the CPU analogue of the thesis's pixel synchronisation).

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

use rayon::prelude::*;
use strata_core::fragment::sort_front_to_back;
use strata_core::{
    DeepFrame, DeepFrameError, DepthStats, Fragment, GatheredPixels, Rgb8Image, composite,
};
use strata_raster::{CaptureTarget, FragmentSink, StripLayout};

use crate::method::{StoreError, try_alloc};
use crate::strip_export::StripSlot;

/// What a full region does with one more fragment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Policy {
    /// Keep the first fragments to arrive; drop later ones (A-buffer arrays, S-buffer).
    Append,
    /// Keep the nearest fragments, sorted front to back by insertion (k-buffers).
    KeepNearest,
}

/// Receives fragments a [`Policy::KeepNearest`] region evicts, with their pixel.
pub trait Evicted: Send + Sync {
    /// `fragment` at row-major pixel `pixel` fell off the region.
    fn evicted(&self, pixel: usize, fragment: Fragment);
}

/// Per-pixel regions; see the module docs.
#[derive(Debug, Default)]
pub struct Regions {
    width: u32,
    height: u32,
    offsets: Vec<u32>,
    /// The capacity of every region when all are equal ([`Regions::uniform`]): a sink then
    /// computes a pixel's region instead of loading its offsets.
    uniform: Option<u32>,
    fill: Vec<u32>,
    slots: Vec<Fragment>,
    /// Fragments dropped (Append) or evicted (KeepNearest) since the last clear; strips add
    /// theirs when they finish.
    lost: AtomicU64,
}

/// Pixels per parallel work item in per-pixel passes.
const PIXELS_PER_TASK: usize = 8 * 1024;

impl Regions {
    /// Empty regions; size them with [`Regions::with_capacities`] or [`Regions::uniform`].
    pub fn new() -> Self {
        Self::default()
    }

    /// Sizes the regions of a `width` × `height` frame from per-pixel capacities (row-major),
    /// reusing the allocations where they suffice, and empties them.
    pub fn with_capacities(
        &mut self,
        width: u32,
        height: u32,
        capacity: &[u32],
    ) -> Result<(), StoreError> {
        let pixels = width as usize * height as usize;
        assert_eq!(capacity.len(), pixels, "one capacity per pixel");
        let (offsets, total) = exclusive_prefix_sum(capacity);
        let total = usize::try_from(total)
            .ok()
            .filter(|&t| u32::try_from(t).is_ok())
            .ok_or(StoreError::OutOfMemory {
                what: format!("{total} fragment slots"),
                bytes: total.saturating_mul(size_of::<Fragment>() as u64),
                hint: "lower the per-pixel capacity or the budget",
            })?;
        self.resize(width, height, total)?;
        self.offsets = offsets;
        self.uniform = None;
        Ok(())
    }

    /// Sizes every region of a `width` × `height` frame to `capacity` fragments.
    pub fn uniform(&mut self, width: u32, height: u32, capacity: u32) -> Result<(), StoreError> {
        let pixels = width as usize * height as usize;
        let total = pixels as u64 * u64::from(capacity);
        if total > u64::from(u32::MAX) {
            return Err(StoreError::OutOfMemory {
                what: format!("{pixels} pixels × {capacity} fragment slots"),
                bytes: total.saturating_mul(size_of::<Fragment>() as u64),
                hint: "lower the per-pixel capacity",
            });
        }
        self.resize(width, height, total as usize)?;
        self.uniform = Some(capacity);
        self.offsets.clear();
        self.offsets
            .extend((0..=pixels as u64).map(|p| (p * u64::from(capacity)) as u32));
        Ok(())
    }

    fn resize(&mut self, width: u32, height: u32, slots: usize) -> Result<(), StoreError> {
        let pixels = width as usize * height as usize;
        (self.width, self.height) = (width, height);
        if self.fill.len() != pixels {
            self.fill = Vec::new();
            self.fill = try_alloc(
                pixels,
                || format!("{pixels} region counters"),
                "render a smaller image",
            )?;
        }
        if self.slots.len() < slots || self.slots.len() > 2 * slots.max(1 << 16) {
            self.slots = Vec::new();
            self.slots = try_alloc(
                slots,
                || format!("{slots} fragment slots"),
                "lower the per-pixel capacity or the budget",
            )?;
        }
        self.clear();
        Ok(())
    }

    /// Copies what each pixel of `old` holds to the front of its region here, as if those
    /// fragments had been captured first. Used when a frame captured in chunks outgrows the
    /// layout its earlier chunks sized: both must be of one frame size, and every region here at
    /// least as large as `old`'s fill.
    pub(crate) fn refill_from(&mut self, old: &Regions) {
        assert_eq!(
            (old.width, old.height),
            (self.width, self.height),
            "refill from regions of the same frame"
        );
        for (p, fill) in self.fill.iter_mut().enumerate() {
            let run = old.stored(p);
            let start = self.offsets[p] as usize;
            self.slots[start..start + run.len()].copy_from_slice(run);
            *fill = run.len() as u32;
        }
        self.lost.store(old.lost.load(Relaxed), Relaxed);
    }

    /// Empties every region (keeps the sizes).
    pub fn clear(&mut self) {
        self.fill.par_iter_mut().for_each(|f| *f = 0);
        self.lost.store(0, Relaxed);
    }

    /// Width of the frame.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height of the frame.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Slots of pixel `p`.
    pub fn capacity(&self, p: usize) -> u32 {
        self.offsets[p + 1] - self.offsets[p]
    }

    /// Total slots.
    pub fn total_capacity(&self) -> u64 {
        u64::from(self.offsets.last().copied().unwrap_or(0))
    }

    /// Fragments stored in pixel `p`'s region (sorted front to back under KeepNearest, in arrival
    /// order under Append).
    pub fn stored(&self, p: usize) -> &[Fragment] {
        let start = self.offsets[p] as usize;
        &self.slots[start..start + self.fill[p] as usize]
    }

    /// Fragments stored in all regions.
    pub fn stored_count(&self) -> u64 {
        self.fill.par_iter().map(|&f| u64::from(f)).sum()
    }

    /// Fragments dropped or evicted since the last clear.
    pub fn lost(&self) -> u64 {
        self.lost.load(Relaxed)
    }

    /// Bytes allocated: offsets, fill counters and all slots of this frame.
    pub fn memory_bytes(&self) -> u64 {
        (self.offsets.len() * 4 + self.fill.len() * 4) as u64
            + self.total_capacity() * size_of::<Fragment>() as u64
    }

    /// Bytes holding this frame's data: offsets, fill counters and the used slots.
    pub fn used_memory_bytes(&self) -> u64 {
        (self.offsets.len() * 4 + self.fill.len() * 4) as u64
            + self.stored_count() * size_of::<Fragment>() as u64
    }

    /// One sink per strip of `layout`, each owning its rows' counters and slots.
    pub fn strips<'a>(
        &'a mut self,
        layout: &StripLayout,
        policy: Policy,
        evicted: Option<&'a dyn Evicted>,
    ) -> Vec<RegionSink<'a>> {
        self.strips_exporting(layout, policy, evicted, None)
    }

    /// [`Regions::strips`], each sink gathering its strip's regions into its slot of `export`
    /// (one a strip) as it finishes, when there is one ([`crate::strip_export`]).
    pub(crate) fn strips_exporting<'a>(
        &'a mut self,
        layout: &StripLayout,
        policy: Policy,
        evicted: Option<&'a dyn Evicted>,
        export: Option<&'a mut [StripSlot]>,
    ) -> Vec<RegionSink<'a>> {
        let mut export = export.map(|e| {
            assert_eq!(e.len(), layout.count(), "one export slot a strip");
            e.iter_mut()
        });
        assert_eq!(
            (layout.width, layout.height),
            (self.width, self.height),
            "size the regions before capture"
        );
        let (offsets, lost_total) = (&self.offsets, &self.lost);
        let uniform = self.uniform.map(|k| k as usize);
        let mut slots = &mut self.slots[..];
        let mut fill = &mut self.fill[..];
        let mut consumed = 0usize;
        let mut sinks = Vec::with_capacity(layout.count());
        for s in 0..layout.count() {
            let pixels = layout.pixels(s);
            let (f, rest) = std::mem::take(&mut fill).split_at_mut(pixels.len());
            fill = rest;
            let end = offsets[pixels.end] as usize;
            let (sl, rest) = std::mem::take(&mut slots).split_at_mut(end - consumed);
            slots = rest;
            sinks.push(RegionSink {
                first_pixel: pixels.start,
                base: consumed,
                offsets,
                uniform,
                fill: f,
                slots: sl,
                policy,
                evicted,
                lost: 0,
                lost_total,
                export: export.as_mut().and_then(|e| e.next()),
            });
            consumed = end;
        }
        sinks
    }

    /// Sorts every region front to back (Append regions arrive unsorted) and composites it onto
    /// `background`; returns the image and the depth statistics of what the regions hold.
    pub fn resolve(&mut self, background: [f32; 3], sort: bool) -> (Rgb8Image, DepthStats) {
        let mut image = Rgb8Image::filled(self.width, self.height, [0; 3]);
        let bg = composite::background_pixel(background);
        let (offsets, fill) = (&self.offsets, &self.fill);
        // Regions are disjoint and row-major: cut the slots at task boundaries.
        let pixels = fill.len();
        let mut tasks = Vec::new();
        let mut slots = &mut self.slots[..];
        let mut consumed = 0usize;
        for (t, out) in image
            .as_bytes_mut()
            .chunks_mut(PIXELS_PER_TASK * 3)
            .enumerate()
        {
            let first = t * PIXELS_PER_TASK;
            let last = (first + PIXELS_PER_TASK).min(pixels);
            let end = offsets[last] as usize;
            let (sl, rest) = std::mem::take(&mut slots).split_at_mut(end - consumed);
            slots = rest;
            tasks.push((first, consumed, sl, out));
            consumed = end;
        }
        let stats = tasks
            .into_par_iter()
            .with_max_len(1)
            .map(|(first, base, slots, out)| {
                let mut stats = DepthStats::default();
                for (i, px) in out.chunks_exact_mut(3).enumerate() {
                    let p = first + i;
                    let start = offsets[p] as usize - base;
                    let run = &mut slots[start..start + fill[p] as usize];
                    stats.record(run.len() as u32);
                    let rgb = if run.is_empty() {
                        bg
                    } else {
                        if sort {
                            sort_front_to_back(run);
                        }
                        composite::resolve_pixel(run.iter().map(|f| f.color), background)
                    };
                    px.copy_from_slice(&rgb);
                }
                stats
            })
            .reduce(DepthStats::default, |mut a, b| {
                a.merge(&b);
                a
            });
        (image, stats)
    }

    /// Fragments stored per pixel, row-major.
    pub fn fill(&self) -> &[u32] {
        &self.fill
    }

    /// Sorts every region front to back in parallel (what Append regions need before a
    /// truncation or an ordered read).
    pub fn sort_runs(&mut self) {
        self.for_each_run(|_, run| sort_front_to_back(run));
    }

    /// Keeps at most `keep[p]` fragments of each pixel `p` — the first ones, so the nearest after
    /// [`Regions::sort_runs`] — and counts the others as lost. Returns how many were removed.
    pub fn truncate(&mut self, keep: &[u32]) -> u64 {
        assert_eq!(keep.len(), self.fill.len(), "one count per pixel");
        let removed: u64 = self
            .fill
            .par_chunks_mut(PIXELS_PER_TASK)
            .zip(keep.par_chunks(PIXELS_PER_TASK))
            .map(|(fill, keep)| {
                let mut removed = 0u64;
                for (f, &k) in fill.iter_mut().zip(keep) {
                    removed += u64::from(f.saturating_sub(k));
                    *f = (*f).min(k);
                }
                removed
            })
            .sum();
        self.lost.fetch_add(removed, Relaxed);
        removed
    }

    /// Runs `f(pixel, stored fragments)` on every region, in parallel over row-major pixel ranges.
    fn for_each_run(&mut self, f: impl Fn(usize, &mut [Fragment]) + Sync) {
        let (offsets, fill) = (&self.offsets, &self.fill);
        let pixels = fill.len();
        let mut tasks = Vec::with_capacity(pixels.div_ceil(PIXELS_PER_TASK));
        let mut slots = &mut self.slots[..];
        let mut consumed = 0usize;
        for first in (0..pixels).step_by(PIXELS_PER_TASK) {
            let last = (first + PIXELS_PER_TASK).min(pixels);
            let end = offsets[last] as usize;
            let (sl, rest) = std::mem::take(&mut slots).split_at_mut(end - consumed);
            slots = rest;
            tasks.push((first, last, consumed, sl));
            consumed = end;
        }
        tasks
            .into_par_iter()
            .with_max_len(1)
            .for_each(|(first, last, base, slots)| {
                for p in first..last {
                    let start = offsets[p] as usize - base;
                    f(p, &mut slots[start..start + fill[p] as usize]);
                }
            });
    }

    /// The stored fragments as a DeepFrame.
    pub fn deep_frame(&self) -> Result<DeepFrame, DeepFrameError> {
        let counts: Vec<u32> = self.fill.clone();
        DeepFrame::build(self.width, self.height, &counts, |p, out| {
            out.extend_from_slice(self.stored(p))
        })
    }
}

/// Regions as a capture target with a given policy: what a method hands to
/// [`strata_raster::Prepared::rasterize`].
pub struct RegionCapture<'a> {
    /// The regions to fill.
    pub regions: &'a mut Regions,
    /// What a full region does.
    pub policy: Policy,
    /// Where evicted fragments go, if anywhere.
    pub evicted: Option<&'a dyn Evicted>,
    /// One slot a strip to gather the strip's regions into as it finishes (a fused export), if
    /// any.
    pub(crate) export: Option<&'a mut [StripSlot]>,
}

impl<'a> RegionCapture<'a> {
    /// Capture into `regions` with `policy`, evicted fragments to `evicted` if anywhere.
    pub fn new(regions: &'a mut Regions, policy: Policy, evicted: Option<&'a dyn Evicted>) -> Self {
        RegionCapture {
            regions,
            policy,
            evicted,
            export: None,
        }
    }

    /// Each strip also gathers its regions into its slot of `export` as it finishes.
    pub(crate) fn exporting(mut self, export: &'a mut [StripSlot]) -> Self {
        self.export = Some(export);
        self
    }
}

impl CaptureTarget for RegionCapture<'_> {
    type Sink<'s>
        = RegionSink<'s>
    where
        Self: 's;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<RegionSink<'_>> {
        self.regions.strips_exporting(
            layout,
            self.policy,
            self.evicted,
            self.export.as_deref_mut(),
        )
    }
}

/// Capture into the regions of one strip of rows.
pub struct RegionSink<'a> {
    first_pixel: usize,
    /// Index of this strip's first slot in the whole slot array.
    base: usize,
    offsets: &'a [u32],
    /// Every region's capacity when all are equal: then pixel `first_pixel + i`'s region starts
    /// at slot `i·k` of `slots`, with no offset to load.
    uniform: Option<usize>,
    fill: &'a mut [u32],
    slots: &'a mut [Fragment],
    policy: Policy,
    evicted: Option<&'a dyn Evicted>,
    lost: u64,
    lost_total: &'a AtomicU64,
    /// Where `finish` gathers the strip's regions, if anywhere.
    export: Option<&'a mut StripSlot>,
}

impl std::fmt::Debug for RegionSink<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RegionSink")
            .field("first_pixel", &self.first_pixel)
            .field("lost", &self.lost)
            .finish()
    }
}

impl RegionSink<'_> {
    /// Where pixel `p` (the strip's `local`-th) has its region in this strip's slots, and its
    /// capacity.
    #[inline(always)]
    fn region(&self, p: usize, local: usize) -> (usize, usize) {
        match self.uniform {
            Some(k) => (local * k, k),
            None => (
                self.offsets[p] as usize - self.base,
                (self.offsets[p + 1] - self.offsets[p]) as usize,
            ),
        }
    }

    /// [`Policy::KeepNearest`] insertion of one fragment (Tsopouridis 2021 Alg. 14), whatever this sink's
    /// policy: keeps the region sorted front to back and returns the fragment that fell off the
    /// end — the new one or the farthest kept — counting it as lost.
    ///
    /// For stores that handle evictions themselves, per strip and without the shared [`Evicted`]
    /// callback (the k-buffer's tail blend).
    #[inline(always)]
    pub fn insert_nearest(&mut self, pixel: u32, fragment: Fragment) -> Option<Fragment> {
        let p = pixel as usize;
        let local = p - self.first_pixel;
        let (start, capacity) = self.region(p, local);
        let n = self.fill[local] as usize;
        let region = &mut self.slots[start..start + capacity];
        let key = fragment.order_key();
        let mut out = None;
        if n == capacity {
            // Full: the new fragment enters only if nearer than the farthest kept one.
            self.lost += 1;
            if capacity == 0 || region[n - 1].order_key() <= key {
                return Some(fragment);
            }
            out = Some(region[n - 1]);
        } else {
            self.fill[local] += 1;
        }
        // Insertion: shift farther fragments back by one.
        let mut j = n.min(capacity - 1);
        while j > 0 && region[j - 1].order_key() > key {
            region[j] = region[j - 1];
            j -= 1;
        }
        region[j] = fragment;
        out
    }
}

impl FragmentSink for RegionSink<'_> {
    #[inline(always)]
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        let p = pixel as usize;
        match self.policy {
            Policy::Append => {
                let local = p - self.first_pixel;
                let (start, capacity) = self.region(p, local);
                let n = self.fill[local] as usize;
                if n < capacity {
                    self.slots[start + n] = fragment;
                    self.fill[local] += 1;
                } else {
                    self.lost += 1;
                }
            }
            Policy::KeepNearest => {
                if let (Some(out), Some(e)) = (self.insert_nearest(pixel, fragment), self.evicted) {
                    e.evicted(p, out);
                }
            }
        }
    }

    fn finish(&mut self) {
        self.lost_total.fetch_add(self.lost, Relaxed);
        if let Some(slot) = self.export.take() {
            let gathered = self.gather(slot);
            slot.fill(gathered);
        }
    }
}

impl RegionSink<'_> {
    /// The strip's regions gathered into columns for `slot`, each run checked and sorted front
    /// to back in a copy ([`GatherWriter::push_run`]), so the regions themselves stay as
    /// captured, and cut to the slot's limit.
    fn gather(&self, slot: &mut StripSlot) -> Result<GatheredPixels, DeepFrameError> {
        let stored = self.fill.iter().map(|&n| n as usize).sum();
        let mut w = slot.writer(self.fill.len(), stored);
        let mut run = Vec::new();
        for (local, &n) in self.fill.iter().enumerate() {
            if n == 0 {
                w.push_empty(1);
                continue;
            }
            let p = self.first_pixel + local;
            let (start, _) = self.region(p, local);
            run.clear();
            run.extend_from_slice(&self.slots[start..start + n as usize]);
            w.push_run(p, &mut run)?;
        }
        Ok(w.finish())
    }
}

/// Exclusive prefix sum of per-pixel counts, in parallel: `offsets[p] = Σ counts[..p]`, plus the
/// total as `offsets[n]`. Replaces the thesis S-buffer's hashed group counters (a GPU device for
/// atomic contention) with the plain two-level parallel scan a CPU wants.
pub fn exclusive_prefix_sum(counts: &[u32]) -> (Vec<u32>, u64) {
    const BLOCK: usize = 64 * 1024;
    let block_sums: Vec<u64> = counts
        .par_chunks(BLOCK)
        .map(|b| b.iter().map(|&c| u64::from(c)).sum())
        .collect();
    let mut starts = Vec::with_capacity(block_sums.len());
    let mut total = 0u64;
    for s in &block_sums {
        starts.push(total);
        total += s;
    }
    let mut offsets = vec![0u32; counts.len() + 1];
    if total <= u64::from(u32::MAX) {
        offsets[..counts.len()]
            .par_chunks_mut(BLOCK)
            .zip(counts.par_chunks(BLOCK))
            .zip(starts.par_iter())
            .for_each(|((out, c), &start)| {
                let mut acc = start as u32;
                for (o, &v) in out.iter_mut().zip(c) {
                    *o = acc;
                    acc += v;
                }
            });
        offsets[counts.len()] = total as u32;
    }
    (offsets, total)
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{ObjectId, Rgba8};

    fn frag(depth: f32, o: u32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([o as u8, 0, 0, 128]),
            object: ObjectId(o),
        }
    }

    fn push_all(
        r: &mut Regions,
        layout: &StripLayout,
        policy: Policy,
        frags: &[(u32, Fragment)],
        ev: Option<&dyn Evicted>,
    ) {
        let mut sinks = r.strips(layout, policy, ev);
        for &(p, f) in frags {
            sinks[p as usize / layout.pixels_per_strip()].push(p, f);
        }
        for s in &mut sinks {
            s.finish();
        }
    }

    /// The strips of a `width` × `height` frame, one row each.
    fn one_row_strips(width: u32, height: u32) -> StripLayout {
        StripLayout {
            width,
            height,
            strip_height: 1,
        }
    }

    #[test]
    fn prefix_sum_matches_sequential() {
        let counts: Vec<u32> = (0..200_000u32).map(|i| i % 7).collect();
        let (offsets, total) = exclusive_prefix_sum(&counts);
        let mut acc = 0u32;
        for (p, &c) in counts.iter().enumerate() {
            assert_eq!(offsets[p], acc);
            acc += c;
        }
        assert_eq!((offsets[counts.len()], total), (acc, u64::from(acc)));
    }

    #[test]
    fn regions_sized_again_by_capacities_forget_their_uniform_size() {
        // Uniform regions of 3, then per-pixel capacities 0, 1, 4, 2 on the same buffers: the
        // sinks must find each region from its offsets again, not at p·3.
        let layout = one_row_strips(2, 2);
        let mut r = Regions::new();
        r.uniform(2, 2, 3).unwrap();
        push_all(&mut r, &layout, Policy::Append, &[(3, frag(0.4, 9))], None);
        assert_eq!(r.stored(3), &[frag(0.4, 9)]);
        r.with_capacities(2, 2, &[0, 1, 4, 2]).unwrap();
        let frags: Vec<(u32, Fragment)> = (0..4)
            .flat_map(|p| (0..3).map(move |i| (p, frag(0.1 * (i + 1) as f32, p * 10 + i))))
            .collect();
        push_all(&mut r, &layout, Policy::Append, &frags, None);
        assert!(r.stored(0).is_empty());
        assert_eq!(r.stored(1), &[frag(0.1, 10)]);
        assert_eq!(r.stored(2), &[frag(0.1, 20), frag(0.2, 21), frag(0.3, 22)]);
        assert_eq!(r.stored(3), &[frag(0.1, 30), frag(0.2, 31)]);
        assert_eq!((r.lost(), r.stored_count()), (6, 6));
    }

    #[test]
    fn append_keeps_the_first_and_counts_the_rest() {
        let layout = one_row_strips(2, 2);
        let mut r = Regions::new();
        r.uniform(2, 2, 2).unwrap();
        push_all(
            &mut r,
            &layout,
            Policy::Append,
            &[
                (3, frag(0.9, 1)),
                (3, frag(0.1, 2)),
                (3, frag(0.5, 3)),
                (0, frag(0.2, 4)),
            ],
            None,
        );
        assert_eq!(r.stored(3), &[frag(0.9, 1), frag(0.1, 2)]);
        assert_eq!(r.stored(0), &[frag(0.2, 4)]);
        assert_eq!((r.lost(), r.stored_count()), (1, 3));
    }

    #[test]
    fn keep_nearest_keeps_the_k_nearest_sorted_and_reports_evictions() {
        use std::sync::Mutex;
        struct Log(Mutex<Vec<(usize, f32)>>);
        impl Evicted for Log {
            fn evicted(&self, pixel: usize, f: Fragment) {
                self.0.lock().unwrap().push((pixel, f.depth));
            }
        }
        let log = Log(Mutex::new(Vec::new()));
        let layout = one_row_strips(1, 1);
        let mut r = Regions::new();
        r.uniform(1, 1, 3).unwrap();
        let depths = [0.5, 0.9, 0.1, 0.7, 0.3, 0.95, 0.2];
        let frags: Vec<_> = depths
            .iter()
            .enumerate()
            .map(|(i, &d)| (0, frag(d, i as u32)))
            .collect();
        push_all(&mut r, &layout, Policy::KeepNearest, &frags, Some(&log));
        let kept: Vec<f32> = r.stored(0).iter().map(|f| f.depth).collect();
        assert_eq!(kept, [0.1, 0.2, 0.3]);
        assert_eq!(r.lost(), 4);
        let mut evicted: Vec<f32> = log.0.lock().unwrap().iter().map(|e| e.1).collect();
        evicted.sort_by(f32::total_cmp);
        assert_eq!(evicted, [0.5, 0.7, 0.9, 0.95]);
    }

    #[test]
    fn variable_capacities_and_zero_capacity_regions() {
        let layout = one_row_strips(3, 1);
        let mut r = Regions::new();
        r.with_capacities(3, 1, &[0, 1, 2]).unwrap();
        push_all(
            &mut r,
            &layout,
            Policy::KeepNearest,
            &[
                (0, frag(0.5, 0)),
                (1, frag(0.5, 1)),
                (1, frag(0.4, 2)),
                (2, frag(0.3, 3)),
            ],
            None,
        );
        assert!(r.stored(0).is_empty());
        assert_eq!(r.stored(1), &[frag(0.4, 2)]);
        assert_eq!(r.stored(2), &[frag(0.3, 3)]);
        assert_eq!(r.lost(), 2);
        let (img, stats) = r.resolve([1.0; 3], false);
        assert_eq!(img.pixel(0, 0), [255, 255, 255]);
        assert_eq!(stats.fragments(), 2);
        assert_eq!(r.deep_frame().unwrap().fragment_count(), 2);
        assert_eq!(r.memory_bytes(), 4 * 4 + 3 * 4 + 3 * 12);
    }

    #[test]
    fn sort_then_truncate_keeps_the_nearest_and_counts_the_rest() {
        let layout = one_row_strips(3, 1);
        let mut r = Regions::new();
        r.with_capacities(3, 1, &[3, 0, 2]).unwrap();
        push_all(
            &mut r,
            &layout,
            Policy::Append,
            &[
                (0, frag(0.9, 1)),
                (0, frag(0.1, 2)),
                (0, frag(0.5, 3)),
                (2, frag(0.7, 4)),
                (2, frag(0.3, 5)),
            ],
            None,
        );
        r.sort_runs();
        assert_eq!(r.stored(0), &[frag(0.1, 2), frag(0.5, 3), frag(0.9, 1)]);
        assert_eq!(r.truncate(&[2, 0, 5]), 1);
        assert_eq!(r.stored(0), &[frag(0.1, 2), frag(0.5, 3)]);
        assert_eq!(r.stored(2), &[frag(0.3, 5), frag(0.7, 4)]);
        assert_eq!(r.fill(), &[2, 0, 2]);
        assert_eq!((r.lost(), r.stored_count()), (1, 4));
    }

    #[test]
    fn insert_nearest_returns_what_falls_off() {
        let layout = one_row_strips(1, 1);
        let mut r = Regions::new();
        r.uniform(1, 1, 2).unwrap();
        let mut sinks = r.strips(&layout, Policy::Append, None);
        let s = &mut sinks[0];
        assert_eq!(s.insert_nearest(0, frag(0.5, 1)), None);
        assert_eq!(s.insert_nearest(0, frag(0.7, 2)), None);
        assert_eq!(s.insert_nearest(0, frag(0.9, 3)), Some(frag(0.9, 3)));
        assert_eq!(s.insert_nearest(0, frag(0.1, 4)), Some(frag(0.7, 2)));
        s.finish();
        drop(sinks);
        assert_eq!(r.stored(0), &[frag(0.1, 4), frag(0.5, 1)]);
        assert_eq!(r.lost(), 2);
    }
}
