//! The display's side of the reprojection transfer: one node's held fragments, moved to each new
//! view and updated with the node's removals and inserts; and the pixels whose order against
//! another node's fragments needs the node's exact runs (the fixup round).

use rayon::prelude::*;
use strata_core::DeepFrame;
use strata_wire::{MaskBuilder, PixelMask, Removals, compact_height};

use super::held::{Entry, Held, Scratch, SortedBand, band_digest, frame_digest};
use super::lanes::FrameRows;
use super::view::View;
use super::{BAND_ROWS, merge_pixel, sort_entries};

/// Why a display could not apply a reprojection frame.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ApplyError {
    /// The frame does not fit the held state (a removal beyond a run, a size change mid-stream).
    #[error("the reprojection frame does not fit the held fragments: {0}")]
    Mismatch(String),
    /// The states differ after applying: the two ends computed differently.
    #[error(
        "the reprojected state diverged from the node's (digest {ours:016x}, node {theirs:016x})"
    )]
    Diverged {
        /// The display's digest.
        ours: u64,
        /// The node's.
        theirs: u64,
    },
}

/// The display's side: one node's held fragments.
#[derive(Clone, Debug)]
pub struct ReprojCopy {
    held: Held,
    /// Buffers reused from frame to frame: the next state.
    spare: Held,
    scratch: Scratch,
    /// Each band's digest of the next state.
    digests: Vec<u64>,
    /// The inserts' run offsets spread back over the view's pixels ([`spread_offsets`]).
    offsets: Vec<u32>,
}

impl ReprojCopy {
    /// Nothing held (the first frame of a connection is sent whole).
    pub fn empty(width: u32, height: u32) -> Self {
        ReprojCopy {
            held: Held::empty(width, height),
            spare: Held::empty(0, 0),
            scratch: Scratch::default(),
            digests: Vec::new(),
            offsets: Vec::new(),
        }
    }

    /// What is held.
    pub fn held(&self) -> &Held {
        &self.held
    }

    /// Moves the held fragments to `view`, applies the node's removals and inserts, and checks
    /// the digest. `inserts` holds the touched pixels' runs compacted, as the wire sends them
    /// ([`crate::reprojection::ReprojDelta::inserts`]). On error the copy is left as it was.
    pub fn apply(
        &mut self,
        view: &View,
        touched: &PixelMask,
        removals: &Removals,
        inserts: &DeepFrame,
    ) -> Result<(), ApplyError> {
        let (width, height) = view.size();
        let rows = compact_height(touched.len(), width);
        if (inserts.width(), inserts.height()) != (width, rows)
            || touched.frame_pixels() as usize != width as usize * height as usize
            || removals.pixel_count() != touched.len() as usize
        {
            return Err(ApplyError::Mismatch(format!(
                "{}x{} compacted inserts with {} touched pixels and {} removal entries for a \
                 {width}x{height} view",
                inserts.width(),
                inserts.height(),
                touched.len(),
                removals.pixel_count()
            )));
        }
        let pixels = width as usize * height as usize;
        // Every inserted fragment belongs to a touched pixel: the padding holds none.
        let end = inserts.offsets()[touched.len() as usize] as usize;
        if end != inserts.fragment_count() {
            return Err(ApplyError::Mismatch(format!(
                "{} inserted fragments lie past the touched pixels' runs",
                inserts.fragment_count() - end
            )));
        }
        spread_offsets(touched, inserts.offsets(), pixels, &mut self.offsets);
        let inserts = FrameRows {
            width: width as usize,
            offsets: &self.offsets,
            depths: inserts.depths(),
            colors: inserts.colors(),
            objects: inserts.objects(),
        };
        // The held list moved to the view; each band task sorts its band of it and merges it
        // with the node's removals and inserts straight into its band of the next state.
        let moved = self.held.move_to(view, &mut self.scratch);
        let bands = moved.band_count();
        // The touched pixels as the mask's runs, each with the removal entry of its first
        // pixel: each band finds its own with a binary search.
        let touch = Touched::new(touched);
        // Each band's next length: what it holds, less its removals, plus its inserts. The
        // merge checks every removal against its run (a band that would lose more than it
        // holds fails there, with the pixel named), and the band's length against this.
        let offsets = inserts.offsets;
        let lens: Vec<usize> = (0..bands)
            .map(|d| {
                let band = moved.band_pixels(d);
                let removed = removals.count_in(touch.before(band.start)..touch.before(band.end));
                let ins = (offsets[band.end] - offsets[band.start]) as usize;
                (moved.band_len(d) + ins).saturating_sub(removed)
            })
            .collect();
        if lens.iter().sum::<usize>() > u32::MAX as usize {
            return Err(ApplyError::Mismatch(
                "the next state would hold more than 2^32 fragments".into(),
            ));
        }
        self.digests.resize(bands, 0);
        let built =
            self.spare
                .build_bands(view, &mut self.digests, |b, digest, entries, counts| {
                    let taken = moved.sort_band(b, |projected| {
                        merge_band(
                            b, view, projected, &touch, removals, &inserts, entries, counts,
                        )
                    })?;
                    if entries.len() != lens[b] {
                        // Runs that do not add up to the band's length: reported below (not
                        // reached, as said there).
                        return Ok((taken, false));
                    }
                    *digest = band_digest(b, entries, counts);
                    Ok((taken, true))
                });
        let (mut taken, mut all_fit) = (0, true);
        for (result, fits) in built {
            let (t, fit) = result?;
            taken += t;
            all_fit &= fit && fits;
        }
        if taken != end {
            // Not reached: spread over the view, every insert lies at a touched pixel and is
            // taken there. Kept as a check of the spreading and the walk.
            return Err(ApplyError::Mismatch(format!(
                "{} inserted fragments lie outside the touched pixels",
                end - taken
            )));
        }
        if !all_fit {
            // Not reached: with every removal in its run and every insert taken, each band
            // holds the length it was given.
            return Err(ApplyError::Mismatch(
                "a band's runs do not add up to its length".into(),
            ));
        }
        let ours = frame_digest(width, height, self.digests.iter().copied());
        if ours != removals.checksum() {
            return Err(ApplyError::Diverged {
                ours,
                theirs: removals.checksum(),
            });
        }
        std::mem::swap(&mut self.held, &mut self.spare);
        Ok(())
    }
}

/// The offsets of compacted inserts (run `i` the `i`-th touched pixel's; `compact` has an
/// offset past the last touched pixel) spread over the `pixels` pixels of the view, into `out`:
/// `out[p]..out[p + 1]` is pixel `p`'s run, empty where `touched` does not hold `p`. The
/// fragment columns stay as they are: compacted or spread, the runs follow in pixel order.
pub(super) fn spread_offsets(
    touched: &PixelMask,
    compact: &[u32],
    pixels: usize,
    out: &mut Vec<u32>,
) {
    out.clear();
    out.reserve(pixels + 1);
    let mut i = 0;
    for &(start, len) in touched.runs() {
        // The untouched pixels before the run start (and end) where its first run starts.
        out.resize(start as usize, compact[i]);
        out.extend_from_slice(&compact[i..i + len as usize]);
        i += len as usize;
    }
    out.resize(pixels + 1, compact[i]);
}

/// The touched pixels of a frame: the mask's runs, and for each the index (in mask order) of
/// its first pixel, which is also its first entry in the removals.
struct Touched<'m> {
    runs: &'m [(u32, u32)],
    first: Vec<usize>,
}

impl<'m> Touched<'m> {
    fn new(mask: &'m PixelMask) -> Self {
        let runs = mask.runs();
        let mut first = Vec::with_capacity(runs.len());
        let mut k = 0;
        for &(_, len) in runs {
            first.push(k);
            k += len as usize;
        }
        Touched { runs, first }
    }

    /// The first run that ends after pixel `p`.
    fn run_after(&self, p: usize) -> usize {
        self.runs
            .partition_point(|&(s, l)| (s as usize + l as usize) <= p)
    }

    /// Touched pixels before pixel `p`.
    fn before(&self, p: usize) -> usize {
        let r = self.run_after(p);
        match self.runs.get(r) {
            Some(&(s, _)) => self.first[r] + p.saturating_sub(s as usize),
            None => self
                .first
                .last()
                .map_or(0, |&k| k + self.runs.last().map_or(0, |&(_, l)| l as usize)),
        }
    }
}

/// Band `b`'s next runs into `entries` and `counts`: the `projected` runs where no pixel is
/// touched, and elsewhere each touched pixel's run less its removals, merged with its inserts.
/// Returns how many inserts the band took.
#[allow(clippy::too_many_arguments)]
fn merge_band(
    b: usize,
    view: &View,
    projected: &SortedBand,
    touched: &Touched<'_>,
    removals: &Removals,
    inserts: &FrameRows<'_>,
    entries: &mut Vec<Entry>,
    counts: &mut Vec<u32>,
) -> Result<usize, ApplyError> {
    let (width, height) = view.size();
    let w = width as usize;
    entries.clear();
    counts.clear();
    let mut ins: Vec<Entry> = Vec::new();
    // Inserts taken, which `apply` checks against the inserts sent.
    let mut taken = 0;
    let (mut row_entries, mut known) = (Vec::new(), Vec::new());
    let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(height as usize);
    let offsets = inserts.offsets;
    // The run holding or following the pixel the walk is at.
    let mut r = touched.run_after(rows.start * w);
    for row in rows {
        let first = row * w;
        // Each row's inserted entries are made first (in lanes).
        view.row_entries(inserts, row, &mut row_entries, &mut known);
        let row_first = offsets[first] as usize;
        let (mut p, end) = (first, first + w);
        while p < end {
            while touched
                .runs
                .get(r)
                .is_some_and(|&(s, l)| s as usize + l as usize <= p)
            {
                r += 1;
            }
            // A stretch of untouched pixels keeps its runs: one copy for all.
            let stop = touched
                .runs
                .get(r)
                .map_or(end, |&(s, _)| (s as usize).clamp(p, end));
            if stop > p {
                let (held, offs) = projected.span(p..stop);
                entries.extend_from_slice(held);
                counts.extend(offs.windows(2).map(|o| o[1] - o[0]));
                p = stop;
                continue;
            }
            let k = touched.first[r] + (p - touched.runs[r].0 as usize);
            let start = entries.len();
            let held = projected.run(p);
            let removed = removals.pixel(k);
            if let Some(&last) = removed.last()
                && last as usize >= held.len()
            {
                return Err(ApplyError::Mismatch(format!(
                    "pixel {p} holds {} fragments, the node removes position {last}",
                    held.len()
                )));
            }
            ins.clear();
            for k in offsets[p] as usize..offsets[p + 1] as usize {
                if !known[k - row_first] {
                    return Err(ApplyError::Mismatch(format!(
                        "pixel {p}: object {} is not in the scene",
                        inserts.objects[k].0
                    )));
                }
                ins.push(row_entries[k - row_first]);
            }
            taken += ins.len();
            sort_entries(&mut ins);
            merge_pixel(held, removed, &ins, entries);
            counts.push((entries.len() - start) as u32);
            p += 1;
        }
    }
    Ok(taken)
}

/// For each node, the pixels whose order against another node's fragments the display cannot
/// trust: where fragments of two nodes lie within `2 · max(depth_error)` of each other (the bound
/// each node sent with its frame). Every node with fragments at such a pixel is asked for its
/// exact run there (nodes not taking part this frame are asked for nothing).
pub fn ambiguous(
    frames: &[&DeepFrame],
    depth_error: &[f32],
    taking_part: &[bool],
) -> Vec<PixelMask> {
    assert_eq!(frames.len(), taking_part.len());
    assert_eq!(frames.len(), depth_error.len());
    let Some(first) = frames.first() else {
        return Vec::new();
    };
    let pixels = first.offsets().len() - 1;
    let slack = 2.0
        * depth_error
            .iter()
            .zip(taking_part)
            .filter(|&(_, &t)| t)
            .map(|(&e, _)| e)
            .fold(0f32, f32::max);
    if slack <= 0.0 {
        // Every node's depths are exact: the merge orders them as the exact render does.
        return frames
            .iter()
            .map(|_| PixelMask::empty(pixels as u32))
            .collect();
    }
    let flags: Vec<bool> = (0..pixels)
        .into_par_iter()
        .with_min_len(4096)
        .map_init(Vec::new, |depths: &mut Vec<(f32, usize)>, p| {
            // Most pixels are covered by one node or none: nothing to order.
            if frames.iter().filter(|f| !f.run(p).is_empty()).count() < 2 {
                return false;
            }
            depths.clear();
            for (i, f) in frames.iter().enumerate() {
                depths.extend(f.run(p).iter().map(|x| (x.depth, i)));
            }
            depths.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            depths
                .windows(2)
                .any(|w| w[0].1 != w[1].1 && w[1].0 - w[0].0 <= slack)
        })
        .collect();
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let mut b = MaskBuilder::new(pixels as u32);
            if taking_part[i] {
                for (p, &flag) in flags.iter().enumerate() {
                    if flag && !f.run(p).is_empty() {
                        b.push(p as u32);
                    }
                }
            }
            b.finish()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn touched_pixels_before_a_pixel_and_their_removals_count_like_a_walk_of_the_mask() {
        let pixels = 200u32;
        for (m, set) in [
            |_: u32| false,
            |_: u32| true,
            |p: u32| p % 7 < 3,
            |p: u32| (40..90).contains(&p) || p == 150 || p == 199,
            |p: u32| p == 0,
        ]
        .into_iter()
        .enumerate()
        {
            let mask = PixelMask::from_fn(pixels, set);
            let touch = Touched::new(&mask);
            let mut removals = Removals::new(0);
            for (k, _) in mask.iter().enumerate() {
                removals.push_pixel(0..(k % 4) as u32);
            }
            for p in 0..=pixels as usize {
                let want = mask.iter().filter(|&q| (q as usize) < p).count();
                assert_eq!(touch.before(p), want, "mask {m}, pixel {p}");
                let positions: usize = (0..want).map(|k| removals.pixel(k).len()).sum();
                assert_eq!(removals.count_in(0..touch.before(p)), positions);
            }
        }
    }
}
