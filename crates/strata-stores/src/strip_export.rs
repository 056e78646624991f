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
//!
//! The strips' columns are kept by the store from frame to frame ([`SpareColumns`]): made
//! fresh each frame, they were new memory every time (about 10 MB a 1280×720 dragon frame,
//! each strip's columns large enough for the allocator to map and unmap them), and a render
//! node's kernel time went to zeroing pages on first touch and unmapping them after: 2,200
//! page faults a frame, in `perf`.

use strata_core::{DeepFrame, DeepFrameError, GatherWriter, GatheredPixels, RunLimit};
use strata_raster::StripLayout;

/// One strip's export: what to keep of each run, the columns it gathers into (last frame's,
/// emptied), and the gathered pixels its sink's `finish` leaves.
#[derive(Debug)]
pub(crate) struct StripSlot {
    limit: RunLimit,
    columns: GatheredPixels,
    gathered: Option<Result<GatheredPixels, DeepFrameError>>,
}

impl StripSlot {
    /// A writer for the strip's `pixels` pixels and about `fragments` fragments, with the
    /// export's limit, into the slot's columns.
    pub(crate) fn writer(&mut self, pixels: usize, fragments: usize) -> GatherWriter {
        let mut w = GatherWriter::reusing(std::mem::take(&mut self.columns)).with_limit(self.limit);
        w.reserve(pixels, fragments);
        w
    }

    /// The strip's gathered pixels (or why they could not be).
    pub(crate) fn fill(&mut self, gathered: Result<GatheredPixels, DeepFrameError>) {
        self.gathered = Some(gathered);
    }
}

/// Strips' columns a store keeps from one export to the next.
#[derive(Debug, Default)]
pub(crate) struct SpareColumns(Vec<GatheredPixels>);

/// One empty slot per strip of `layout`, each keeping what `limit` keeps of a run and
/// gathering into columns from `spare` (fresh ones where it has too few).
pub(crate) fn slots(
    layout: &StripLayout,
    limit: RunLimit,
    spare: &mut SpareColumns,
) -> Vec<StripSlot> {
    (0..layout.count())
        .map(|_| StripSlot {
            limit,
            columns: spare.0.pop().unwrap_or_default(),
            gathered: None,
        })
        .collect()
}

/// The frame of `width × height` pixels from the strips' slots, in order, in the buffers of
/// `reuse` if there is one ([`DeepFrame::from_gathered_reusing`]); the strips' columns go back
/// to `spare` for the next export.
///
/// # Panics
/// If a strip did not finish (a capture always finishes every sink).
pub(crate) fn assemble(
    width: u32,
    height: u32,
    slots: Vec<StripSlot>,
    reuse: Option<DeepFrame>,
    spare: &mut SpareColumns,
) -> Result<DeepFrame, DeepFrameError> {
    let strips: Vec<GatheredPixels> = slots
        .into_iter()
        .map(|s| s.gathered.expect("every strip finished"))
        .collect::<Result<_, _>>()?;
    let frame = DeepFrame::from_gathered_reusing(width, height, strips.iter().collect(), reuse);
    spare.0.extend(strips);
    frame
}
