//! The S-buffer: count, prefix-sum, then capture into exactly-sized contiguous regions (Tsopouridis 2021
//! §3.1.3, Algorithms 7–12; Vasilakis & Fudos 2012).
//!
//! # Layout
//!
//! ```text
//! counts:  [u32; w*h]        the thesis's counterTexture: fragments of pixel p (counting pass)
//! offsets: [u32; w*h + 1]    exclusive prefix sum of counts: pixel p owns offsets[p] .. offsets[p+1]
//! fill:    [u32; w*h]        the thesis's addressTexture, as a count: slots pixel p has written
//! slots:   [Fragment; n]     the thesis's data buffer, n = Σ counts exactly, 12 bytes a fragment
//! ```
//!
//! `offsets`, `fill` and `slots` are a [`Regions`] sized with [`Regions::with_capacities`]; that
//! layout *is* the DeepFrame's (prefix-summed counts plus contiguous runs).
//!
//! # Passes
//!
//! - **clear** (Alg. 7): every counter to 0.
//! - **count** (Alg. 8, `capture.count`): a geometry pass that only counts fragments per pixel
//!   ([`FragmentCounts`]).
//! - **prefix sum** (Alg. 9–10, `capture.prefix_sum`): `offsets = exclusive_prefix_sum(counts)`.
//!   The thesis hashes pixels into `S` groups with one atomic counter each, prefix-sums the group
//!   totals and adds a pixel's offset within its group: a device against atomic contention on a
//!   GPU. A CPU has no such contention, so [`exclusive_prefix_sum`] replaces the hashed group
//!   counters with a plain two-level parallel scan (block sums, then per-block scans); regions come
//!   out in row-major order, which is also what the DeepFrame wants.
//! - **capture** (Alg. 11, `capture.capture`): a second geometry pass writes each fragment at
//!   `offsets[p] + fill[p]++`. Each rasterizer strip owns its rows' counters and slots, so the
//!   seed's atomic address increment is a plain one.
//! - **resolve** (Alg. 12): per pixel, sort the region front to back and composite with OVER.
//!
//! Regions hold exactly the fragments counted: no slot is wasted and nothing can overflow
//! (`dropped` is always 0), at the price of rasterising twice. The result is always exact:
//! image and DeepFrame identical to the linked-list A-buffer's.

use std::time::Instant;

use strata_core::{DeepFrame, DeepFrameError, DepthStats, PassTimings, Rgb8Image};
use strata_raster::{FrameInput, Rasterizer};

use crate::count::FragmentCounts;
use crate::method::{CaptureReport, Method, StoreError};
use crate::options::MethodOptions;
#[cfg(doc)]
use crate::regions::exclusive_prefix_sum;
use crate::regions::{Policy, RegionCapture, Regions};

/// The name the method is selected by.
pub const NAME: &str = "sbuffer";

/// The S-buffer; see the module docs.
#[derive(Debug, Default)]
pub struct SBuffer {
    counts: FragmentCounts,
    regions: Regions,
    /// The layout of the chunks captured so far while a later chunk is laid out (see
    /// [`SBuffer::capture_exact`]); empty unless frames are captured in chunks.
    previous: Regions,
    /// Whether a capture has run since the last clear.
    holding: bool,
    depth: Option<DepthStats>,
}

impl SBuffer {
    /// An empty S-buffer (it reads no option); buffers are sized per frame.
    pub fn new(_options: &MethodOptions) -> Self {
        Self::default()
    }

    /// The per-pixel fragment counts of the last counting pass.
    pub fn counts(&self) -> &FragmentCounts {
        &self.counts
    }

    /// The exactly-sized regions of the last capture.
    pub fn regions(&self) -> &Regions {
        &self.regions
    }

    /// Runs the count, prefix-sum and capture passes (shared with the weight-factor resolve,
    /// whose M-buffer is this layout).
    ///
    /// Captures accumulate (see [`Method`]): the counts of a later chunk add to the earlier
    /// ones', the regions are laid out again for the total, and the fragments already stored are
    /// copied to the front of their new regions before the chunk is captured behind them — in
    /// arrival order, as one capture would have stored them. Each later chunk thus copies what
    /// the store holds: chunks suit the linked-list A-buffer better.
    pub(crate) fn capture_exact(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());

        let start = Instant::now();
        let counted = prepared.rasterize(&mut self.counts);
        timings.add("capture.count", start.elapsed());

        let start = Instant::now();
        if self.holding {
            std::mem::swap(&mut self.regions, &mut self.previous);
        }
        self.regions
            .with_capacities(input.width, input.height, self.counts.counts())?;
        timings.add("capture.prefix_sum", start.elapsed());
        if self.holding {
            let start = Instant::now();
            self.regions.refill_from(&self.previous);
            timings.add("capture.carry_over", start.elapsed());
        }
        self.holding = true;

        let start = Instant::now();
        let captured = prepared.rasterize(&mut RegionCapture::new(
            &mut self.regions,
            Policy::Append,
            None,
        ));
        timings.add("capture.capture", start.elapsed());

        let dropped = self.regions.lost();
        Ok(CaptureReport {
            fragments_rasterized: counted.fragments + captured.fragments,
            fragments_stored: self.regions.stored_count(),
            dropped,
            regrows: 0,
            raster_passes: 2,
            setup: prepared.setup_stats(),
            ..CaptureReport::default()
        })
    }

    pub(crate) fn clear_counts(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        self.depth = None;
        self.holding = false;
        self.counts.clear(width, height)
    }

    pub(crate) fn memory(&self) -> u64 {
        self.counts.memory_bytes() + self.regions.memory_bytes() + self.previous.memory_bytes()
    }
}

impl Method for SBuffer {
    fn name(&self) -> &'static str {
        NAME
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        self.clear_counts(width, height)
    }

    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        self.capture_exact(raster, input, timings)
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        let (image, depth) = self.regions.resolve(background, true);
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    /// Counters, offsets, fill counters and exactly `Σ counts` slots: allocated equals used.
    fn memory_bytes(&self) -> u64 {
        self.memory()
    }

    fn captures_in_chunks(&self) -> bool {
        true
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        Some(self.regions.deep_frame())
    }
}
