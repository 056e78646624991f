//! The counting pass: fragments per pixel, without storing them (Tsopouridis 2021 Alg. 8, the S-buffer's
//! "accumulation" pass).
//!
//! Each strip owns its rows' counters, so counting needs no atomics. The S-buffer sizes its
//! regions from the counts, the variable k-buffer feeds them to its importance function.

use rayon::prelude::*;
use strata_core::Fragment;
use strata_raster::{CaptureTarget, FragmentSink, StripLayout};

use crate::method::{StoreError, try_alloc};

/// Per-pixel fragment counts of one frame, row-major.
#[derive(Debug, Default)]
pub struct FragmentCounts {
    width: u32,
    height: u32,
    counts: Vec<u32>,
}

impl FragmentCounts {
    /// Empty counters.
    pub fn new() -> Self {
        Self::default()
    }

    /// Zeroes the counters of a `width` × `height` frame, allocating them on first use.
    pub fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        let pixels = width as usize * height as usize;
        (self.width, self.height) = (width, height);
        if self.counts.len() == pixels {
            self.counts.par_iter_mut().for_each(|c| *c = 0);
        } else {
            self.counts = Vec::new();
            self.counts = try_alloc(
                pixels,
                || format!("{pixels} fragment counters"),
                "render a smaller image",
            )?;
        }
        Ok(())
    }

    /// The counts, row-major.
    pub fn counts(&self) -> &[u32] {
        &self.counts
    }

    /// The counts, row-major, for a capture target that counts alongside other work
    /// ([`crate::kbuffer::features::FeatureCapture`]).
    pub(crate) fn counts_mut(&mut self) -> &mut [u32] {
        &mut self.counts
    }

    /// Total fragments counted.
    pub fn total(&self) -> u64 {
        self.counts.par_iter().map(|&c| u64::from(c)).sum()
    }

    /// The largest count.
    pub fn max(&self) -> u32 {
        self.counts.par_iter().copied().max().unwrap_or(0)
    }

    /// Bytes of the counters.
    pub fn memory_bytes(&self) -> u64 {
        (self.counts.len() * size_of::<u32>()) as u64
    }
}

/// Counts one strip's fragments.
#[derive(Debug)]
pub struct CountSink<'a> {
    first_pixel: usize,
    counts: &'a mut [u32],
}

impl FragmentSink for CountSink<'_> {
    #[inline(always)]
    fn push(&mut self, pixel: u32, _fragment: Fragment) {
        self.counts[pixel as usize - self.first_pixel] += 1;
    }
}

impl CaptureTarget for FragmentCounts {
    type Sink<'s> = CountSink<'s>;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<CountSink<'_>> {
        assert_eq!(
            (layout.width, layout.height),
            (self.width, self.height),
            "clear before counting"
        );
        layout
            .split_mut(&mut self.counts)
            .enumerate()
            .map(|(s, counts)| CountSink {
                first_pixel: layout.pixels(s).start,
                counts,
            })
            .collect()
    }
}
