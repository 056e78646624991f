//! The fixed-size array A-buffer (Tsopouridis 2021 §3.1.1, Algorithms 1–3).
//!
//! # Layout
//!
//! ```text
//! offsets: [u32; w*h + 1]   p · A: pixel p owns slots p·A .. (p+1)·A      (Regions, uniform)
//! fill:    [u32; w*h]       the thesis's counterTexture: fragments stored in pixel p
//! slots:   [Fragment; w*h*A] the thesis's bufferTexture, 12 bytes a slot (depth, RGBA8, object)
//! ```
//!
//! The storage is [`Regions::uniform`]: every pixel gets the same `A` slots
//! ([`MethodOptions::array_size`]) whether it needs them or not, which is the method's memory cost
//! (Tsopouridis 2021 Table 3.1: three times the linked list's memory on the same scene). The offsets are
//! kept although they are `p · A`, so the fixed array shares its capture and resolve with the
//! S-buffer and the k-buffers; they cost 4 bytes a pixel and are reported.
//!
//! # Passes
//!
//! - **clear** (Alg. 1): every counter to 0.
//! - **capture** (Alg. 2, `capture.capture`): each fragment goes to slot `counter` of its pixel and
//!   the counter is incremented — in arrival (primitive) order, so a pixel keeps its *first* `A`
//!   fragments. The thesis's atomic increment is a plain one here: each rasterizer strip owns its
//!   rows' counters and slots ([`Policy::Append`]). A fragment arriving at a full array is dropped
//!   and counted ([`CaptureReport::dropped`]), never silently.
//! - **resolve** (Alg. 3): per pixel, sort the stored fragments front to back and composite them
//!   with OVER ([`strata_core::composite::resolve_pixel`], the resolve every exact method shares).
//!
//! # Exactness
//!
//! With `A` at least the frame's largest depth complexity nothing is dropped, and the image and
//! the DeepFrame are identical to the linked-list A-buffer's. With a smaller `A`, which fragments
//! survive depends on primitive order (the thesis's flickering), but not on the thread count.

use std::time::Instant;

use strata_core::{DeepFrame, DeepFrameError, DepthStats, PassTimings, Rgb8Image};
use strata_raster::{FrameInput, Rasterizer};

use crate::method::{CaptureReport, Method, StoreError};
use crate::options::MethodOptions;
use crate::regions::{Policy, RegionCapture, Regions};

/// The name the method is selected by.
pub const NAME: &str = "abuffer-array";

/// The fixed-size array A-buffer; see the module docs.
#[derive(Debug)]
pub struct FixedArrayABuffer {
    array_size: u32,
    regions: Regions,
    depth: Option<DepthStats>,
}

impl FixedArrayABuffer {
    /// An A-buffer of [`MethodOptions::array_size`] slots a pixel; buffers are sized at the first
    /// [`Method::clear`].
    pub fn new(options: &MethodOptions) -> Self {
        Self::with_array_size(options.array_size)
    }

    /// An A-buffer of `array_size` (`A`) slots a pixel.
    pub fn with_array_size(array_size: u32) -> Self {
        FixedArrayABuffer {
            array_size,
            regions: Regions::new(),
            depth: None,
        }
    }

    /// `A`, the slots of every pixel.
    pub fn array_size(&self) -> u32 {
        self.array_size
    }

    /// The per-pixel arrays.
    pub fn regions(&self) -> &Regions {
        &self.regions
    }
}

impl Method for FixedArrayABuffer {
    fn name(&self) -> &'static str {
        NAME
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        self.depth = None;
        if (self.regions.width(), self.regions.height()) == (width, height)
            && self.regions.total_capacity()
                == u64::from(width) * u64::from(height) * u64::from(self.array_size)
        {
            self.regions.clear();
            Ok(())
        } else {
            self.regions.uniform(width, height, self.array_size)
        }
    }

    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());
        let start = Instant::now();
        let stats = prepared.rasterize(&mut RegionCapture::new(
            &mut self.regions,
            Policy::Append,
            None,
        ));
        timings.add("capture.capture", start.elapsed());
        let dropped = self.regions.lost();
        Ok(CaptureReport {
            fragments_rasterized: stats.fragments,
            fragments_stored: stats.fragments - dropped,
            dropped,
            regrows: 0,
            raster_passes: 1,
            setup: prepared.setup_stats(),
            ..CaptureReport::default()
        })
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        let (image, depth) = self.regions.resolve(background, true);
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    fn memory_bytes(&self) -> u64 {
        self.regions.memory_bytes()
    }

    fn used_memory_bytes(&self) -> u64 {
        self.regions.used_memory_bytes()
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        Some(self.regions.deep_frame())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{Fragment, ObjectId, Rgba8};
    use strata_raster::{CaptureTarget, FragmentSink, StripLayout};

    fn frag(depth: f32, o: u32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([o as u8, 0, 0, 255]),
            object: ObjectId(o),
        }
    }

    #[test]
    fn keeps_the_first_a_arrivals_and_counts_the_rest() {
        let layout = StripLayout {
            width: 2,
            height: 2,
            strip_height: 1,
        };
        let mut ab = FixedArrayABuffer::with_array_size(2);
        ab.clear(2, 2).unwrap();
        {
            let mut target = RegionCapture::new(&mut ab.regions, Policy::Append, None);
            let mut sinks = target.sinks(&layout);
            // Pixel 3: 0.9 then 0.1 then 0.5 arrive; the first two stay.
            for (p, f) in [(3, frag(0.9, 1)), (3, frag(0.1, 2)), (3, frag(0.5, 3))] {
                sinks[1].push(p, f);
            }
            sinks[0].push(0, frag(0.4, 4));
            for s in &mut sinks {
                s.finish();
            }
        }
        assert_eq!(ab.regions.lost(), 1);
        let df = ab.deep_frame().unwrap().unwrap();
        assert_eq!(df.pixel(1, 1).depth, &[0.1, 0.9]);
        assert_eq!(df.pixel(0, 0).depth, &[0.4]);
        let img = ab.resolve([1.0; 3], &mut PassTimings::new());
        assert_eq!(img.pixel(1, 1), [2, 0, 0]);
        // offsets (5) + counters (4) + 4 pixels × 2 slots × 12 bytes
        assert_eq!(ab.memory_bytes(), 5 * 4 + 4 * 4 + 8 * 12);
        assert_eq!(ab.used_memory_bytes(), 5 * 4 + 4 * 4 + 3 * 12);
    }

    #[test]
    fn clear_empties_and_resizes() {
        let mut ab = FixedArrayABuffer::with_array_size(3);
        ab.clear(4, 2).unwrap();
        assert_eq!(ab.regions.total_capacity(), 24);
        ab.clear(2, 2).unwrap();
        assert_eq!(ab.regions.total_capacity(), 12);
        assert_eq!(ab.regions.stored_count(), 0);
    }
}
