//! The node's side of the reprojection transfer: match each pixel's rendered run against the
//! reprojected one, keep what shades within the tolerance, remove the rest by position, insert
//! what is missing, and check the merged run (see the module docs of `reprojection`).

use rayon::prelude::*;
use strata_core::{DeepFrame, Fragment, GatheredPixels};
use strata_wire::removals::MAX_REMOVALS_PER_PIXEL;
use strata_wire::{MaskBuilder, PixelMask, Removals};

use super::held::{Entry, Held, Scratch, band_digest, frame_digest};
use super::view::View;
use super::{BAND_ROWS, DEPTH_SLACK, close, merge_pixel, sort_stably_by_key};

/// What a node sends for one frame.
#[derive(Clone, Debug)]
pub struct ReprojDelta {
    /// Pixels with removals or inserts.
    pub touched: PixelMask,
    /// Per touched pixel, the projected positions removed; with the digest of the new state.
    pub removals: Removals,
    /// The inserted normal fragments (none outside `touched`).
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
    /// Buffers reused from frame to frame.
    scratch: Scratch,
    bands: Vec<BandOut>,
}

/// One band's share of a node frame.
#[derive(Clone, Debug, Default)]
struct BandOut {
    entries: Vec<Entry>,
    counts: Vec<u32>,
    touched: Vec<u32>,
    /// Per touched pixel, how many of `removed` are its.
    removed_counts: Vec<u32>,
    removed: Vec<u32>,
    /// Inserted normal fragments, per touched pixel in order.
    insert_counts: Vec<u32>,
    inserts: Vec<Fragment>,
    /// Largest |kept depth − rendered depth|.
    depth_error: f32,
    /// The band's share of the new state's digest ([`band_digest`]).
    digest: u64,
    /// `inserts` as the band's share of the inserts frame ([`DeepFrame::from_gathered`]).
    gathered: GatheredPixels,
}

impl ReprojEncoder {
    /// A node-side state that lets colours differ by at most `tolerance` 8-bit steps.
    pub fn new(tolerance: u8) -> Self {
        ReprojEncoder {
            tolerance,
            held: None,
            scratch: Scratch::default(),
            bands: Vec::new(),
        }
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
        self.bands.par_iter_mut().enumerate().for_each(|(b, out)| {
            moved.sort_band(b, |projected| {
                out.entries.clear();
                out.counts.clear();
                out.touched.clear();
                out.removed_counts.clear();
                out.removed.clear();
                out.insert_counts.clear();
                out.inserts.clear();
                out.depth_error = 0.0;
                let mut truth: Vec<(Entry, Fragment)> = Vec::new();
                let mut removed: Vec<u32> = Vec::new();
                let mut inserts: Vec<Entry> = Vec::new();
                let mut inserted_wire: Vec<Fragment> = Vec::new();
                let (mut row_entries, mut known) = (Vec::new(), Vec::new());
                let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(height as usize);
                let band_pixels = rows.start * w..rows.end * w;
                let offsets = rendered.offsets();
                // Pixel by pixel, with each row's entries made first (in lanes).
                let pixels = rows.flat_map(|row| (0..w).map(move |x| (row, x)));
                let mut row_first = 0;
                for (row, x) in pixels {
                    let p = row * w + x;
                    if x == 0 {
                        view.row_entries(rendered, row, &mut row_entries, &mut known);
                        row_first = offsets[p] as usize;
                    }
                    if offsets[p] == offsets[p + 1] && projected.run(p).is_empty() {
                        // Nothing rendered, nothing held: nothing to say.
                        out.counts.push(0);
                        continue;
                    }
                    truth.clear();
                    for (k, f) in (offsets[p] as usize..).zip(rendered.run(p).iter()) {
                        if known[k - row_first] {
                            truth.push((row_entries[k - row_first], f));
                        }
                    }
                    sort_truth(&mut truth);
                    let held = projected.run(p);
                    removed.clear();
                    inserts.clear();
                    inserted_wire.clear();
                    let mut j = 0;
                    for (n, f) in &truth {
                        let z = view.eye_depth(n.fragment.depth);
                        match held[j..].iter().position(|h| {
                            close(&h.fragment, &n.fragment, tolerance)
                                && (view.eye_depth(h.fragment.depth) - z).abs() <= DEPTH_SLACK * z
                        }) {
                            Some(k) => {
                                removed.extend(j as u32..(j + k) as u32);
                                j += k + 1;
                            }
                            None => {
                                inserts.push(*n);
                                inserted_wire.push(*f);
                            }
                        }
                    }
                    removed.extend(j as u32..held.len() as u32);
                    let start = out.entries.len();
                    merge_pixel(held, &removed, &inserts, &mut out.entries);
                    let merged = &out.entries[start..];
                    let ok = merged.len() == truth.len()
                        && merged
                            .iter()
                            .zip(&truth)
                            .all(|(m, (n, _))| close(&m.fragment, &n.fragment, tolerance));
                    if ok {
                        for (m, (n, _)) in merged.iter().zip(&truth) {
                            let e = (m.fragment.depth - n.fragment.depth).abs();
                            out.depth_error = out.depth_error.max(e);
                        }
                    } else {
                        out.entries.truncate(start);
                        removed.clear();
                        removed.extend(0..held.len() as u32);
                        inserts.clear();
                        inserted_wire.clear();
                        for (n, f) in &truth {
                            inserts.push(*n);
                            inserted_wire.push(*f);
                        }
                        merge_pixel(held, &removed, &inserts, &mut out.entries);
                    }
                    out.counts.push((out.entries.len() - start) as u32);
                    if !removed.is_empty() || !inserts.is_empty() {
                        out.touched.push(p as u32);
                        out.removed_counts.push(removed.len() as u32);
                        out.removed.extend_from_slice(&removed);
                        out.insert_counts.push(inserted_wire.len() as u32);
                        out.inserts.extend_from_slice(&inserted_wire);
                    }
                }
                out.digest = band_digest(b, &out.entries, &out.counts);
                // The band's inserts, each pixel's run sorted in the wire's order (the truth is in
                // the entries' order, which differs where depths tie).
                let (mut t, mut at) = (0, 0);
                let (touched, counts, list) = (&out.touched, &out.insert_counts, &out.inserts);
                let gathered = GatheredPixels::gather(band_pixels, &mut inserted_wire, |p, run| {
                    if touched.get(t) == Some(&(p as u32)) {
                        let n = counts[t] as usize;
                        run.extend_from_slice(&list[at..at + n]);
                        (t, at) = (t + 1, at + n);
                    }
                });
                // Rendered fragments are in range: gathering them cannot fail.
                out.gathered = gathered.unwrap_or_default();
            });
        });

        // Assemble the new state (in the old state's buffers), the mask, the removals and the
        // inserts, band by band.
        let pixels = w * height as usize;
        let mut held = old;
        held.assemble(view, &self.bands, |o| {
            (o.entries.as_slice(), o.counts.as_slice())
        });
        let mut mask = MaskBuilder::new(pixels as u32);
        let mut removals = Removals::new(0);
        let mut depth_error = 0f32;
        if let Some(&n) = self.bands.iter().flat_map(|o| &o.removed_counts).max()
            && n > MAX_REMOVALS_PER_PIXEL
        {
            self.held = None;
            return Err(TooDeep { removals: n });
        }
        for o in &self.bands {
            depth_error = depth_error.max(o.depth_error);
            let mut at = 0;
            for (k, &p) in o.touched.iter().enumerate() {
                mask.push(p);
                let n = o.removed_counts[k] as usize;
                removals.push_pixel(o.removed[at..at + n].iter().copied());
                at += n;
            }
        }
        removals.set_checksum(frame_digest(
            width,
            height,
            self.bands.iter().map(|o| o.digest),
        ));
        removals.set_depth_error(depth_error);
        // The bands' inserts, assembled in parallel. They are rendered fragments of this frame's
        // size, so this cannot fail; were it to, the empty frame would make the display's
        // digest differ and the link reset, not lose fragments silently.
        let gathered = self
            .bands
            .iter_mut()
            .map(|o| std::mem::take(&mut o.gathered));
        let inserts = DeepFrame::from_gathered(width, height, gathered.collect())
            .unwrap_or_else(|_| DeepFrame::empty(width, height));
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

/// Sorts (entry, wire fragment) pairs by the entry's order, stably.
fn sort_truth(run: &mut [(Entry, Fragment)]) {
    sort_stably_by_key(run, |(e, _)| e.fragment.order_key());
}
