//! Export fused with the capture: each strip of rows gathers its pixels' sorted fragments into
//! columns of its own ([`GatheredPixels`]) on the thread that scanned it, as its scan ends and
//! while what it stored is in that core's cache; the frame is then assembled from the strips in
//! order ([`DeepFrame::from_gathered`]). The linked list and the k-buffer export this way in
//! [`crate::Method::capture_and_export`], what a render node runs; the other stores export
//! after the capture.
//!
//! ```text
//! slots: [StripSlot; strips]   each: the export's RunLimit; the columns it gathers into (the
//!                              last export's for that strip, emptied); and None until strip s
//!                              finishes, then its gathered pixels (or the error that stopped
//!                              them: a depth outside [0, 1])
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
        // A strip gathered again (a linked list whose pool grew captures the frame again)
        // reuses what it gathered the first time.
        let columns = match self.gathered.take() {
            Some(Ok(g)) => g,
            _ => std::mem::take(&mut self.columns),
        };
        let mut w = GatherWriter::reusing(columns).with_limit(self.limit);
        w.reserve(pixels, fragments);
        w
    }

    /// The strip's gathered pixels (or why they could not be).
    pub(crate) fn fill(&mut self, gathered: Result<GatheredPixels, DeepFrameError>) {
        self.gathered = Some(gathered);
    }
}

/// Strips' columns a store keeps from one export to the next, strip `s`'s last, so that each
/// strip gets back the columns it filled (their capacity is what it needed). They hold at most
/// one frame's fragments, as the frame exported from them does; the store's `memory_bytes`
/// (what a capture holds) leaves them out.
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
    let gathered: Vec<Result<GatheredPixels, DeepFrameError>> = slots
        .into_iter()
        .map(|s| s.gathered.expect("every strip finished"))
        .collect();
    let mut strips = Vec::with_capacity(gathered.len());
    let mut failed = None;
    for g in gathered {
        match g {
            Ok(g) => strips.push(g),
            Err(e) => failed = failed.or(Some(e)),
        }
    }
    let frame = match failed {
        Some(e) => Err(e),
        None => DeepFrame::from_gathered_reusing(width, height, strips.iter().collect(), reuse),
    };
    // Popped from the end by `slots`: strip 0's columns last.
    spare.0.extend(strips.into_iter().rev());
    frame
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{Fragment, ObjectId, Rgba8};

    /// Gathers strip `s` of `layout` as a sink would: pixel `p` holds `(p + s + round) % 3`
    /// fragments, so every strip and round gathers something different.
    fn gather(layout: &StripLayout, s: usize, round: usize, slot: &mut StripSlot) {
        let rows = layout.rows(s);
        let first = rows.start as usize * layout.width as usize;
        let pixels = rows.len() * layout.width as usize;
        let mut w = slot.writer(pixels, 2 * pixels);
        for p in first..first + pixels {
            let n = (p + s + round) % 3;
            let mut run: Vec<Fragment> = (0..n)
                .map(|k| Fragment {
                    depth: 0.25 * k as f32,
                    color: Rgba8([p as u8, s as u8, round as u8, 255]),
                    object: ObjectId(k as u32),
                })
                .collect();
            w.push_run(p, &mut run).expect("valid depths");
        }
        slot.fill(Ok(w.finish()));
    }

    /// Every strip gathers into the columns it filled the export before (kept in the spare
    /// pool in strip order, not another strip's), frame after frame, and the frames are what
    /// fresh columns give; a strip that failed fails the frame and the others' columns are
    /// still kept.
    #[test]
    fn each_strip_gets_back_the_columns_it_filled() {
        let layout = StripLayout {
            width: 5,
            height: 7,
            strip_height: 2,
        };
        let mut spare = SpareColumns::default();
        let mut last: Option<Vec<GatheredPixels>> = None;
        for round in 0..3 {
            let mut slots = slots(&layout, RunLimit::NONE, &mut spare);
            assert!(
                spare.0.is_empty(),
                "round {round}: every spare column was handed out"
            );
            if let Some(last) = &last {
                for (s, (slot, filled)) in slots.iter().zip(last).enumerate() {
                    assert_eq!(&slot.columns, filled, "round {round}: strip {s}'s columns");
                }
            }
            let mut fresh = super::slots(&layout, RunLimit::NONE, &mut SpareColumns::default());
            for (s, (slot, f)) in slots.iter_mut().zip(&mut fresh).enumerate() {
                gather(&layout, s, round, slot);
                gather(&layout, s, round, f);
            }
            let filled: Vec<GatheredPixels> = slots
                .iter()
                .map(|s| s.gathered.clone().expect("filled").expect("valid"))
                .collect();
            let got = assemble(5, 7, slots, None, &mut spare).expect("a frame");
            let want = assemble(5, 7, fresh, None, &mut SpareColumns::default()).expect("a frame");
            assert_eq!(got, want, "round {round}");
            assert_eq!(spare.0.len(), layout.count());
            last = Some(filled);
        }
        let mut slots = slots(&layout, RunLimit::NONE, &mut spare);
        for (s, slot) in slots.iter_mut().enumerate() {
            gather(&layout, s, 0, slot);
        }
        slots[1].fill(Err(DeepFrameError::BadDepth {
            index: 12,
            depth: 2.0,
        }));
        let result = assemble(5, 7, slots, None, &mut spare);
        assert!(matches!(
            result,
            Err(DeepFrameError::BadDepth { index: 12, .. })
        ));
        assert_eq!(
            spare.0.len(),
            layout.count() - 1,
            "the other strips' columns are kept"
        );
    }
}
