//! The reprojection transfer (Jähne 2014 ch. 5, the "bilateral transformation"), without drift and
//! without the thesis's merge artefacts.
//!
//! # What both ends hold
//!
//! For every node, a [`Held`] list: per pixel a run of [`Entry`]s sorted front to back. An entry
//! is a *surfel* — the object, the object-space position and the object-space normal of a
//! fragment — and the colour fragment that surfel shades to at the current frame. The node
//! renders **normal fragments** ([`strata_raster::FragmentOutput::PackedNormal`]: window depth, a
//! [`strata_core::PackedNormal`] in the colour bytes, the object), and the wire carries them unchanged; the
//! eye-space position is the unprojection of the pixel centre at that depth (the thesis stores eye
//! x, y, z per fragment — 24 bytes — strata derives x and y from the pixel, so a normal fragment
//! costs what a colour fragment does).
//!
//! When a normal fragment arrives, [`View::entry`] applies eq. 5.10 once — eye space to object
//! space with the inverse model-view of the frame it was rendered in — and every later frame
//! applies eq. 5.9 to that fixed object-space point with the current matrices ([`Held::reproject`]).
//! The thesis re-derived eye positions from the previous frame's eye positions every frame, so
//! rounding accumulated and its difference lists grew over time (fig. 6.3); a surfel here is
//! transformed from the same object-space coordinates every frame and cannot drift.
//!
//! # One frame
//!
//! ```text
//! both ends:  held(t-1) ──move (eq. 5.9, P, viewport; shade), bucket by band──► moved(t)
//!             per band of 16 rows, in parallel: sort the band's moved entries ──► projected(t)
//! node:       render normal fragments(t) ──► entries(t)   ─┐
//!             projected(t) ──match per pixel─────────────────┴─► removals + inserts (+ digest)
//! both ends:  projected(t) ── merge_pixel(removals, inserts) ──► held(t) ──► colour DeepFrame
//! ```
//!
//! `projected(t)` never exists as a whole list: each band is sorted into a small buffer by the
//! task that then matches it (node) or merges it (display), writing the band's runs of `held(t)`
//! straight into that band's own buffers (`held(t)` is kept band by band).
//!
//! **Matching** (node, per pixel): the rendered run, converted to entries exactly as the display
//! will convert them, is walked in order; a projected entry survives as the next rendered
//! fragment if it belongs to the same object and shades to a colour within `tolerance` 8-bit
//! steps of it (alpha equal). Projected entries skipped over are removed, rendered fragments
//! without a survivor are inserted. The node then merges survivors and inserts with the same
//! [`merge_pixel`] the display runs and checks the result against the rendered run — same length,
//! same object at every position, colours within `tolerance`; where it does not hold (a
//! reprojected depth out of order, say) the pixel is replaced whole. So each node's list on the
//! display shades, in order, to its own render within `tolerance`.
//!
//! **Removal by identity.** Both ends run the same code on the same inputs, so their projected
//! runs are bit-identical and a removal names an entry by its position in the run. The thesis
//! removed "the nearest fragment by depth" within a threshold, which deleted the wrong fragments
//! when the threshold was large and kept stale ones when it was small (fig. 5.8, 5.9). To catch
//! the case where the two ends' arithmetic differs (different platforms, a bug), the node sends a
//! digest of its new state ([`Held::digest`]) with every frame and the display compares.
//!
//! # Modules
//!
//! - `view`: one frame's matrices and materials; eq. 5.9 (project a surfel), eq. 5.10 (a
//!   rendered normal fragment to a surfel), shading;
//! - `lanes`: eq. 5.9 and 5.10 with their shading for eight fragments of one object at a time,
//!   the same bits as `view`'s one-fragment forms (what both ends run);
//! - `held`: the per-pixel runs both ends hold, reprojection (in parallel: move each source
//!   band and group its entries by destination band while they are in cache, then a counting
//!   sort per destination band in the task that consumes it), the digest;
//! - `encoder`: the node's side — matching, removals and inserts;
//! - `copy`: the display's side — applying a frame, and which pixels need a fixup.

mod copy;
mod encoder;
mod held;
mod lanes;
mod view;

pub use copy::{ApplyError, ReprojCopy, ambiguous};
pub use encoder::{ReprojDelta, ReprojEncoder, TooDeep};
pub use held::{Entry, Held, Scratch, Surfel};
pub use view::View;

use strata_core::Fragment;

/// Rows per parallel band: fixed, so the digest and every result are the same at any thread count.
pub(crate) const BAND_ROWS: usize = 16;

/// How far (relative eye depth) a projected entry may lie from the rendered fragment it stands
/// for. Only an efficiency hint — the merged run is checked anyway — that keeps a fragment from
/// being matched to another surface of its object further back (which would remove everything
/// between them).
pub(crate) const DEPTH_SLACK: f32 = 0.01;

/// Sorts a run by the fragments' order, stably.
pub(crate) fn sort_entries(run: &mut [Entry]) {
    sort_stably_by_key(run, |e| e.fragment.order_key());
}

/// Stable sort by `key`: insertion sort for a pixel's usual handful, the standard library's
/// stable sort beyond 32 (a hostile node could otherwise make a display sort quadratically).
/// Stable either way, so the result is the same and both ends of a link agree.
pub(crate) fn sort_stably_by_key<T: Copy, K: Ord>(run: &mut [T], key: impl Fn(&T) -> K) {
    if run.len() > 32 {
        run.sort_by_key(key);
        return;
    }
    for i in 1..run.len() {
        let item = run[i];
        let k = key(&item);
        let mut j = i;
        while j > 0 && key(&run[j - 1]) > k {
            run[j] = run[j - 1];
            j -= 1;
        }
        run[j] = item;
    }
}

/// One pixel's new run: `projected` without the positions in `removed` (strictly increasing),
/// merged with the sorted `inserts`; on equal keys the projected entry comes first. Both ends
/// call exactly this, so their runs agree bit for bit.
pub fn merge_pixel(projected: &[Entry], removed: &[u32], inserts: &[Entry], out: &mut Vec<Entry>) {
    // Plain indices, not peekable iterators: this runs for every touched pixel on both ends.
    let (mut r, mut n) = (0, 0);
    for (i, e) in projected.iter().enumerate() {
        if removed.get(r) == Some(&(i as u32)) {
            r += 1;
            continue;
        }
        let key = e.fragment.order_key();
        while let Some(next) = inserts.get(n)
            && next.fragment.order_key() < key
        {
            out.push(*next);
            n += 1;
        }
        out.push(*e);
    }
    out.extend_from_slice(&inserts[n..]);
}

/// True if `a` stands for `b`: same object, same alpha, RGB within `tolerance` steps. The five
/// tests are combined without branches: this runs for every pair a pixel's matching compares.
#[inline(always)]
pub(crate) fn close(a: &Fragment, b: &Fragment, tolerance: u8) -> bool {
    let (x, y) = (a.color.0, b.color.0);
    (a.object == b.object)
        & (x[3] == y[3])
        & (x[0].abs_diff(y[0]) <= tolerance)
        & (x[1].abs_diff(y[1]) <= tolerance)
        & (x[2].abs_diff(y[2]) <= tolerance)
}

#[cfg(test)]
mod tests;
