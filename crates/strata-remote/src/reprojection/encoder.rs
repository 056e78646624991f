//! The node's side of the reprojection transfer: match each pixel's rendered run against the
//! reprojected one, keep what shades within the tolerance, remove the rest by position, insert
//! what is missing, and check the merged run (see the module docs of `reprojection`).

use strata_core::{DeepFrame, GatherWriter, GatheredPixels};
use strata_wire::removals::MAX_REMOVALS_PER_PIXEL;
use strata_wire::{MaskBuilder, PixelMask, Removals, compact_height};

use super::held::{Entry, Held, Scratch, SortedBand, band_digest, frame_digest};
use super::lanes::FrameRows;
use super::view::View;
use super::{BAND_ROWS, DEPTH_SLACK, close, merge_pixel, sort_stably_by_key};

/// What a node sends for one frame.
#[derive(Clone, Debug)]
pub struct ReprojDelta {
    /// Pixels with removals or inserts.
    pub touched: PixelMask,
    /// Per touched pixel, the projected positions removed; with the digest of the new state.
    pub removals: Removals,
    /// The inserted normal fragments, compacted as the wire sends them: run `i` is the `i`-th
    /// touched pixel's, laid out the view's width to a row over
    /// [`strata_wire::compact_height`] rows, the last row padded with empty runs.
    pub inserts: DeepFrame,
    /// Fragments the display will hold after applying it.
    pub held: u64,
}

/// A pixel would lose more fragments in one frame than a removal list can name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "a pixel would lose {removals} fragments in one frame; a reprojection frame can remove at most \
     {MAX_REMOVALS_PER_PIXEL} per pixel"
)]
pub struct TooDeep {
    /// The removals the pixel needed.
    pub removals: u32,
}

/// The node's side: its copy of what the display holds, and the matching.
#[derive(Clone, Debug)]
pub struct ReprojEncoder {
    tolerance: u8,
    held: Option<Held>,
    /// The state before the last, whose buffers the next state is built in.
    spare_held: Option<Held>,
    /// Buffers reused from frame to frame.
    scratch: Scratch,
    bands: Vec<BandOut>,
    /// A delta given back ([`ReprojEncoder::recycle`]), whose buffers the next frame's delta
    /// reuses.
    spare: Option<ReprojDelta>,
    /// The empty runs that pad the compacted inserts' last row.
    padding: GatheredPixels,
}

/// One band's share of a node frame (beside its new state, which it writes into the next held
/// list's band), and the buffers its task reuses from frame to frame.
#[derive(Clone, Debug, Default)]
struct BandOut {
    /// Pixels with removals or inserts, ascending.
    touched: Vec<u32>,
    /// Per touched pixel, how many of `removed` are its.
    removed_counts: Vec<u32>,
    removed: Vec<u32>,
    /// Largest |kept depth − rendered depth|.
    depth_error: f32,
    /// The band's share of the new state's digest ([`band_digest`]).
    digest: u64,
    /// The band's inserted normal fragments, one run a touched pixel (in `touched`'s order),
    /// each in the wire's order, as the band's share of the compacted inserts frame
    /// ([`DeepFrame::from_gathered_reusing`]); its buffers serve frame after frame.
    gathered: GatheredPixels,
    /// One pixel's work: what was rendered there, and what matching decided.
    pixel: PixelScratch,
    /// One row's rendered fragments as entries ([`View::row_entries`]).
    row_entries: Vec<Entry>,
    known: Vec<bool>,
}

/// One pixel's matching, in buffers reused from pixel to pixel.
#[derive(Clone, Debug, Default)]
struct PixelScratch {
    /// The rendered fragments of known objects, in the entries' order: indices into the row's
    /// entries ([`View::row_entries`]).
    truth: Vec<u32>,
    /// Projected positions removed, ascending.
    removed: Vec<u32>,
    /// Entries inserted, in the entries' order.
    inserts: Vec<Entry>,
    /// The inserted fragments, as indices into the row's entries (which follow the rendered
    /// run's order); once the pixel is decided, turned in place into their positions in its
    /// rendered run, ascending, for [`GatherWriter::push_from_frame`].
    inserted: Vec<u32>,
}

impl ReprojEncoder {
    /// A node-side state that lets colours differ by at most `tolerance` 8-bit steps.
    pub fn new(tolerance: u8) -> Self {
        ReprojEncoder {
            tolerance,
            held: None,
            spare_held: None,
            scratch: Scratch::default(),
            bands: Vec::new(),
            spare: None,
            padding: GatheredPixels::default(),
        }
    }

    /// Gives back a delta once it is sent: the next frame's delta is built in its buffers
    /// instead of fresh memory (about 10 MB a 1280×720 dragon frame).
    pub fn recycle(&mut self, delta: ReprojDelta) {
        self.spare = Some(delta);
    }

    /// Forgets the display's state (a reset request): the next frame is sent whole.
    pub fn reset(&mut self) {
        self.held = None;
    }

    /// The delta that takes the display from the previous frame's state to `rendered` (normal
    /// fragments rendered at `view`), and the new state kept for the next frame.
    ///
    /// Fails (leaving the state as after a reset) if a pixel would lose more than
    /// [`MAX_REMOVALS_PER_PIXEL`] fragments in one frame, which the wire cannot say.
    pub fn encode(&mut self, view: &View, rendered: &DeepFrame) -> Result<ReprojDelta, TooDeep> {
        let (width, height) = view.size();
        // The old state moved to the view; each band task sorts its band of it.
        let old = self
            .held
            .take()
            .unwrap_or_else(|| Held::empty(width, height));
        let moved = old.move_to(view, &mut self.scratch);
        let w = width as usize;
        let bands = (height as usize).div_ceil(BAND_ROWS);
        let tolerance = self.tolerance;
        self.bands.resize_with(bands, BandOut::default);
        // The new state, each band written by its task into the buffers of the state before
        // the last.
        let mut held = self.spare_held.take().unwrap_or_else(|| Held::empty(0, 0));
        let built = held.build_bands(view, &mut self.bands, |b, out, entries, counts| {
            moved.sort_band(b, |projected| {
                out.match_band(b, view, rendered, projected, tolerance, entries, counts);
            });
        });
        // `match_band` pushes one run length a pixel with that pixel's entries, and a pixel's
        // new run is at most as long as its rendered run, so a band's lengths always add up
        // (and stay below 2^32, as the rendered frame's fragments do): unlike the display's,
        // which merges what a node sent, this cannot fail.
        debug_assert!(built.iter().all(|&(_, fits)| fits), "run lengths add up");
        self.spare_held = Some(old);
        if let Some(&n) = self.bands.iter().flat_map(|o| &o.removed_counts).max()
            && n > MAX_REMOVALS_PER_PIXEL
        {
            // The state is as after a reset; the new list's buffers serve the next frame.
            self.held = None;
            self.spare_held = Some(held);
            return Err(TooDeep { removals: n });
        }

        // The mask, the removals and the inserts, band by band.
        let pixels = w * height as usize;
        let (mut mask, mut removals, reuse) = match self.spare.take() {
            Some(d) => {
                let mut removals = d.removals;
                removals.clear(0);
                let mask = MaskBuilder::reusing(d.touched, pixels as u32);
                (mask, removals, Some(d.inserts))
            }
            None => (MaskBuilder::new(pixels as u32), Removals::new(0), None),
        };
        let mut depth_error = 0f32;
        for o in &self.bands {
            depth_error = depth_error.max(o.depth_error);
            for &p in &o.touched {
                mask.push(p);
            }
        }
        let pieces: Vec<(&[u32], &[u32])> = (self.bands.iter())
            .map(|o| (&o.removed_counts[..], &o.removed[..]))
            .collect();
        removals.push_pieces(&pieces);
        removals.set_checksum(frame_digest(
            width,
            height,
            self.bands.iter().map(|o| o.digest),
        ));
        removals.set_depth_error(depth_error);
        // The bands' inserts, one run a touched pixel, assembled in parallel and padded to
        // whole rows. They are rendered fragments of this frame, so this cannot fail; were it
        // to, the empty frame would make the display's digest differ and the link reset, not
        // lose fragments silently.
        let touched: usize = self.bands.iter().map(|o| o.touched.len()).sum();
        // At most the view's pixels, which a mask counts in a `u32`.
        let rows = compact_height(touched as u32, width);
        let mut padding = GatherWriter::reusing(std::mem::take(&mut self.padding));
        padding.push_empty(rows as usize * w - touched);
        self.padding = padding.finish();
        let gathered: Vec<&GatheredPixels> = (self.bands.iter().map(|o| &o.gathered))
            .chain([&self.padding])
            .collect();
        let inserts = DeepFrame::from_gathered_reusing(width, rows, gathered, reuse)
            .unwrap_or_else(|_| DeepFrame::empty(width, rows));
        let count = held.len() as u64;
        self.held = Some(held);
        Ok(ReprojDelta {
            touched: mask.finish(),
            removals,
            inserts,
            held: count,
        })
    }
}

impl BandOut {
    /// Matches band `b` (rows `b · BAND_ROWS` on) of `rendered` against `projected`, the same
    /// band of the state before moved to `view`: the band's new state (its entries and each
    /// pixel's run length, appended to the empty `entries` and `counts`), its touched pixels
    /// with their removals, its inserts, its digest and its largest depth error.
    #[allow(clippy::too_many_arguments)]
    fn match_band(
        &mut self,
        b: usize,
        view: &View,
        rendered: &DeepFrame,
        projected: &SortedBand,
        tolerance: u8,
        entries: &mut Vec<Entry>,
        counts: &mut Vec<u32>,
    ) {
        let (width, height) = view.size();
        let w = width as usize;
        let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(height as usize);
        self.touched.clear();
        self.removed_counts.clear();
        self.removed.clear();
        self.depth_error = 0.0;
        let offsets = rendered.offsets();
        let frame_rows = FrameRows::of(rendered);
        // The inserts go into the last frame's buffers.
        let mut inserts = GatherWriter::reusing(std::mem::take(&mut self.gathered));
        for row in rows {
            // Each row's entries are made first, in lanes.
            view.row_entries(&frame_rows, row, &mut self.row_entries, &mut self.known);
            let row_first = offsets[row * w] as usize;
            for p in row * w..(row + 1) * w {
                let run = offsets[p] as usize..offsets[p + 1] as usize;
                let held = projected.run(p);
                if run.is_empty() && held.is_empty() {
                    // Nothing rendered, nothing held: nothing to say.
                    counts.push(0);
                    continue;
                }
                let s = &mut self.pixel;
                s.truth.clear();
                let row_run = run.start - row_first..run.end - row_first;
                for k in row_run.clone() {
                    if self.known[k] {
                        s.truth.push(k as u32);
                    }
                }
                let row = &self.row_entries;
                // The rendered run is in depth order, and its entries mostly in theirs.
                let key = |k: &u32| row[*k as usize].fragment.order_key();
                if !s.truth.is_sorted_by_key(key) {
                    sort_stably_by_key(&mut s.truth, key);
                }
                let start = entries.len();
                let e = match_pixel(view, tolerance, held, row, s, entries);
                self.depth_error = self.depth_error.max(e);
                counts.push((entries.len() - start) as u32);
                if s.removed.is_empty() && s.inserted.is_empty() {
                    continue;
                }
                self.touched.push(p as u32);
                self.removed_counts.push(s.removed.len() as u32);
                self.removed.extend_from_slice(&s.removed);
                // The inserted fragments as rendered, in the rendered run's order, which is
                // the wire's (the truth is in the entries' order, which differs where depths
                // tie): their positions in the run, ascending.
                if !s.inserted.is_sorted() {
                    s.inserted.sort_unstable();
                }
                for k in &mut s.inserted {
                    *k -= row_run.start as u32;
                }
                inserts.push_from_frame(rendered, p, &s.inserted);
            }
        }
        self.digest = band_digest(b, entries, counts);
        self.gathered = inserts.finish();
    }
}

/// One pixel's matching (see the module docs of `reprojection`): `s.truth`, the rendered run
/// as entries of `row` in their order, against `held`, the projected run. Appends the pixel's
/// new run to `out` and leaves in `s` the projected positions removed and the entries inserted
/// (as indices into `row`); returns the largest |kept depth − rendered depth|.
#[inline]
fn match_pixel(
    view: &View,
    tolerance: u8,
    held: &[Entry],
    row: &[Entry],
    s: &mut PixelScratch,
    out: &mut Vec<Entry>,
) -> f32 {
    s.removed.clear();
    s.inserts.clear();
    s.inserted.clear();
    // Most often each rendered fragment is the projected entry at its own position: the
    // search below would match them one to one, and the run stays as it was projected.
    let mut depth_error = 0f32;
    // The colours first: they are what differs where a pixel changes.
    if held.len() == s.truth.len()
        && held.iter().zip(&s.truth).all(|(h, &k)| {
            let n = &row[k as usize];
            if !close(&h.fragment, &n.fragment, tolerance) {
                return false;
            }
            let z = view.eye_depth(n.fragment.depth);
            depth_error = depth_error.max((h.fragment.depth - n.fragment.depth).abs());
            (view.eye_depth(h.fragment.depth) - z).abs() <= DEPTH_SLACK * z
        })
    {
        out.extend_from_slice(held);
        return depth_error;
    }
    depth_error = 0.0;
    let mut j = 0;
    for &k in &s.truth {
        let n = &row[k as usize];
        let z = view.eye_depth(n.fragment.depth);
        match held[j..].iter().position(|h| {
            close(&h.fragment, &n.fragment, tolerance)
                && (view.eye_depth(h.fragment.depth) - z).abs() <= DEPTH_SLACK * z
        }) {
            Some(k) => {
                s.removed.extend(j as u32..(j + k) as u32);
                depth_error =
                    depth_error.max((held[j + k].fragment.depth - n.fragment.depth).abs());
                j += k + 1;
            }
            None => {
                s.inserts.push(*n);
                s.inserted.push(k);
            }
        }
    }
    s.removed.extend(j as u32..held.len() as u32);
    let start = out.len();
    merge_pixel(held, &s.removed, &s.inserts, out);
    // Without inserts the merged run is the matched entries in the truth's order, each close to
    // its rendered fragment: it holds. With inserts, the merge may order them otherwise.
    if s.inserts.is_empty() {
        return depth_error;
    }
    let merged = &out[start..];
    let ok = merged.len() == s.truth.len()
        && merged
            .iter()
            .zip(&s.truth)
            .all(|(m, &k)| close(&m.fragment, &row[k as usize].fragment, tolerance));
    if ok {
        return merged.iter().zip(&s.truth).fold(0f32, |e, (m, &k)| {
            e.max((m.fragment.depth - row[k as usize].fragment.depth).abs())
        });
    }
    // The pixel is replaced whole.
    out.truncate(start);
    s.removed.clear();
    s.removed.extend(0..held.len() as u32);
    s.inserts.clear();
    s.inserted.clear();
    for &k in &s.truth {
        s.inserts.push(row[k as usize]);
        s.inserted.push(k);
    }
    merge_pixel(held, &s.removed, &s.inserts, out);
    0.0
}
