//! Export fused with the capture: each strip of rows gathers its pixels' sorted fragments into
//! columns of its own ([`GatheredPixels`]) on the thread that scanned it, as its scan ends and
//! while what it stored is in that core's cache; the frame is then assembled from the strips in
//! order ([`DeepFrame::from_gathered`]). The linked list and the k-buffer export this way in
//! [`crate::Method::capture_and_export`], what a render node runs; the other stores export
//! after the capture.
//!
//! ```text
//! slots: [StripSlot; strips]   each: the export's RunLimit, and None until strip s finishes,
//!                              then its gathered pixels (or the error that stopped them: a
//!                              depth outside [0, 1])
//! ```
//!
//! A depth-limited export ([`RunLimit`]) keeps only each sorted run's prefix as the strip is
//! gathered, so a render node serving the depth-limited transfer needs no selection pass after
//! the export, and the strips' columns hold only what is sent.

use strata_core::{DeepFrame, DeepFrameError, GatherWriter, GatheredPixels, RunLimit};
use strata_raster::StripLayout;

/// One strip's export: what to keep of each run, and the gathered pixels its sink's `finish`
/// leaves.
#[derive(Debug)]
pub(crate) struct StripSlot {
    limit: RunLimit,
    gathered: Option<Result<GatheredPixels, DeepFrameError>>,
}

impl StripSlot {
    /// A writer for the strip's `pixels` pixels and about `fragments` fragments, with the
    /// export's limit.
    pub(crate) fn writer(&self, pixels: usize, fragments: usize) -> GatherWriter {
        GatherWriter::new(pixels, fragments).with_limit(self.limit)
    }

    /// The strip's gathered pixels (or why they could not be).
    pub(crate) fn fill(&mut self, gathered: Result<GatheredPixels, DeepFrameError>) {
        self.gathered = Some(gathered);
    }
}

/// One empty slot per strip of `layout`, each keeping what `limit` keeps of a run.
pub(crate) fn slots(layout: &StripLayout, limit: RunLimit) -> Vec<StripSlot> {
    (0..layout.count())
        .map(|_| StripSlot {
            limit,
            gathered: None,
        })
        .collect()
}

/// The frame of `width × height` pixels from the strips' slots, in order, in the buffers of
/// `reuse` if there is one ([`DeepFrame::from_gathered_reusing`]).
///
/// # Panics
/// If a strip did not finish (a capture always finishes every sink).
pub(crate) fn assemble(
    width: u32,
    height: u32,
    slots: Vec<StripSlot>,
    reuse: Option<DeepFrame>,
) -> Result<DeepFrame, DeepFrameError> {
    let strips: Vec<GatheredPixels> = slots
        .into_iter()
        .map(|s| s.gathered.expect("every strip finished"))
        .collect::<Result<_, _>>()?;
    DeepFrame::from_gathered_reusing(width, height, strips, reuse)
}
