//! Where fragments go: strips of rows, each owned by one sink.
//!
//! A fragment store implements [`CaptureTarget`]: asked for the strips of a [`StripLayout`], it
//! hands out one [`FragmentSink`] per strip, each owning the store's per-pixel state for that
//! strip's rows (typically `chunks_mut` of a row-major buffer). The rasterizer drives the sinks in
//! parallel, one thread per sink at a time, pushing each strip's fragments in primitive order —
//! the push model of ripgrep's `Sink`, with the store deciding what a fragment costs.

use std::ops::Range;

use strata_core::{Fragment, ObjectId};

use crate::setup::PixelFragment;

/// The image cut into bands of full-width rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StripLayout {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Rows per strip (the last strip may have fewer).
    pub strip_height: u32,
}

impl StripLayout {
    /// Number of strips.
    pub fn count(&self) -> usize {
        self.height.div_ceil(self.strip_height) as usize
    }

    /// The rows of strip `s`.
    pub fn rows(&self, s: usize) -> Range<u32> {
        let start = s as u32 * self.strip_height;
        start..(start + self.strip_height).min(self.height)
    }

    /// The row-major pixel indices of strip `s`.
    pub fn pixels(&self, s: usize) -> Range<usize> {
        let r = self.rows(s);
        r.start as usize * self.width as usize..r.end as usize * self.width as usize
    }

    /// Pixels in a full strip: the chunk size that cuts a row-major per-pixel buffer into strips.
    pub fn pixels_per_strip(&self) -> usize {
        self.width as usize * self.strip_height as usize
    }

    /// Cuts a row-major per-pixel buffer into one slice per strip.
    ///
    /// # Panics
    /// If `buf` does not have exactly one entry per pixel.
    pub fn split_mut<'b, T>(&self, buf: &'b mut [T]) -> std::slice::ChunksMut<'b, T> {
        assert_eq!(
            buf.len(),
            self.width as usize * self.height as usize,
            "one entry per pixel"
        );
        buf.chunks_mut(self.pixels_per_strip())
    }
}

/// Receives the fragments of one strip.
pub trait FragmentSink {
    /// One fragment at row-major pixel index `pixel`, which lies in this sink's strip.
    fn push(&mut self, pixel: u32, fragment: Fragment);

    /// Every record of `records` in order, at its pixel, made by `object`: the micro-triangle
    /// fragments setup recorded for this strip. The same as a [`FragmentSink::push`] each (the
    /// default); a sink may instead keep its cursors in registers for the run, where through
    /// `&mut self` each push loads and stores them again (the node stores might alias them).
    #[inline(always)]
    fn push_records(&mut self, records: &[PixelFragment], object: ObjectId) {
        for r in records {
            self.push(r.pixel, r.fragment(object));
        }
    }

    /// Called once after the strip's last fragment (flush counters, release reservations).
    fn finish(&mut self) {}
}

/// A fragment store, as the rasterizer sees it.
pub trait CaptureTarget {
    /// The per-strip sink; it borrows the store.
    type Sink<'s>: FragmentSink + Send
    where
        Self: 's;

    /// One sink per strip of `layout`, in strip order.
    fn sinks(&mut self, layout: &StripLayout) -> Vec<Self::Sink<'_>>;
}

/// A capture target that keeps every fragment with its pixel, in arrival order per strip.
///
/// For tests and tools that want the raw fragment stream; stores use their own layouts.
#[derive(Clone, Debug, Default)]
pub struct FragmentVec {
    strips: Vec<Vec<(u32, Fragment)>>,
}

impl FragmentVec {
    /// An empty collector.
    pub fn new() -> Self {
        Self::default()
    }

    /// All fragments as `(pixel, fragment)`, strip by strip; within a pixel, in primitive order.
    pub fn fragments(&self) -> impl Iterator<Item = &(u32, Fragment)> {
        self.strips.iter().flatten()
    }

    /// Number of fragments.
    pub fn len(&self) -> usize {
        self.strips.iter().map(Vec::len).sum()
    }

    /// True if nothing was captured.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Fragments per pixel, row-major.
    pub fn per_pixel(&self, pixels: usize) -> Vec<Vec<Fragment>> {
        let mut out = vec![Vec::new(); pixels];
        for &(p, f) in self.fragments() {
            out[p as usize].push(f);
        }
        out
    }
}

/// The sink of one [`FragmentVec`] strip.
#[derive(Debug)]
pub struct FragmentVecSink<'a> {
    out: &'a mut Vec<(u32, Fragment)>,
}

impl FragmentSink for FragmentVecSink<'_> {
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        self.out.push((pixel, fragment));
    }
}

impl CaptureTarget for FragmentVec {
    type Sink<'s> = FragmentVecSink<'s>;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<FragmentVecSink<'_>> {
        self.strips.clear();
        self.strips.resize_with(layout.count(), Vec::new);
        self.strips
            .iter_mut()
            .map(|out| FragmentVecSink { out })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_covers_every_row_once() {
        let l = StripLayout {
            width: 10,
            height: 35,
            strip_height: 16,
        };
        assert_eq!(l.count(), 3);
        assert_eq!(l.rows(2), 32..35);
        assert_eq!(l.pixels(1), 160..320);
        let mut buf = vec![0u8; 350];
        let sizes: Vec<usize> = l.split_mut(&mut buf).map(|s| s.len()).collect();
        assert_eq!(sizes, [160, 160, 30]);
    }
}
