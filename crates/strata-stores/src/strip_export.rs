//! Export fused with the capture: each strip of rows gathers its pixels' sorted fragments into
//! columns of its own ([`GatheredPixels`]) on the thread that scanned it, as its scan ends and
//! while what it stored is in that core's cache; the frame is then assembled from the strips in
//! order ([`DeepFrame::from_gathered`]). The linked list and the k-buffer export this way in
//! [`crate::Method::capture_and_export`], what a render node runs; the other stores export
//! after the capture.
//!
//! ```text
//! slots: [StripSlot; strips]   None until strip s finishes, then its gathered pixels (or the
//!                              error that stopped them: a depth outside [0, 1])
//! ```

use strata_core::{DeepFrame, DeepFrameError, GatheredPixels};
use strata_raster::StripLayout;

/// One strip's gathered pixels, filled by its sink's `finish`.
pub(crate) type StripSlot = Option<Result<GatheredPixels, DeepFrameError>>;

/// One empty slot per strip of `layout`.
pub(crate) fn slots(layout: &StripLayout) -> Vec<StripSlot> {
    (0..layout.count()).map(|_| None).collect()
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
        .map(|s| s.expect("every strip finished"))
        .collect::<Result<_, _>>()?;
    DeepFrame::from_gathered_reusing(width, height, strips, reuse)
}
