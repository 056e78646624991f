//! What both ends hold for one node: per pixel a run of entries (surfel + the fragment it shades
//! to now), sorted front to back; how it moves to a new view; its digest.
//!
//! Layout: `offsets[w·h + 1]` into one `entries` array, like a DeepFrame, with the 40-byte
//! [`Entry`] (12-byte fragment, 24-byte surfel, padding) as the column.

use rayon::prelude::*;
use strata_core::{DeepFrame, Fragment};

use super::view::View;
use super::{BAND_ROWS, sort_entries};

/// A fragment's surface point: object-space position and normal (zero: no normal).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Surfel {
    /// Object-space position.
    pub position: [f32; 3],
    /// Object-space normal (not normalised; zero when the fragment had none).
    pub normal: [f32; 3],
}

/// A held fragment: its surfel and what it shades to at the current frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Entry {
    /// Window depth, shaded colour and object at the current frame.
    pub fragment: Fragment,
    /// Where it is on its object.
    pub surfel: Surfel,
}

/// Per pixel, a sorted run of entries: what one node's fragments are on both ends.
#[derive(Clone, Debug, PartialEq)]
pub struct Held {
    width: u32,
    height: u32,
    /// `offsets[p]..offsets[p + 1]` indexes `entries` for pixel `p`.
    offsets: Vec<u32>,
    entries: Vec<Entry>,
    /// The view the entries are shaded and bucketed for (none when empty).
    view: Option<View>,
}

impl Held {
    /// Nothing held.
    pub fn empty(width: u32, height: u32) -> Self {
        Held {
            width,
            height,
            offsets: vec![0; width as usize * height as usize + 1],
            entries: Vec::new(),
            view: None,
        }
    }

    /// Fragments held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True if nothing is held.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Pixel `p`'s run.
    pub fn run(&self, p: usize) -> &[Entry] {
        &self.entries[self.offsets[p] as usize..self.offsets[p + 1] as usize]
    }

    /// Every held surfel moved to `view` (eq. 5.9), shaded, bucketed by the pixel it lands in and
    /// sorted front to back (stably: equal keys keep the order of this list). Objects whose
    /// matrices did not change keep their pixel and fragment bit for bit.
    pub fn reproject(&self, view: &View) -> Held {
        let mut out = Held::empty(0, 0);
        self.reproject_into(view, &mut out, &mut Scratch::default());
        out
    }

    /// [`Held::reproject`] into `out`, reusing its buffers and `scratch`'s (no allocation once
    /// they have grown to the scene's needs).
    pub fn reproject_into(&self, view: &View, out: &mut Held, scratch: &mut Scratch) {
        let (width, height) = view.size();
        let pixels = width as usize * height as usize;
        let unchanged: Vec<bool> = match &self.view {
            Some(old) => (0..view.object_slots())
                .map(|o| view.unchanged(old, o))
                .collect(),
            None => Vec::new(),
        };
        let moved = &mut scratch.moved;
        moved.clear();
        moved.resize(self.entries.len(), (u32::MAX, Fragment::default()));
        {
            let w = self.width as usize;
            let offsets = &self.offsets;
            split_bands(moved, offsets, w, self.height as usize)
                .into_par_iter()
                .for_each(|(row, band)| {
                    let base = offsets[row * w] as usize;
                    let end = (row + BAND_ROWS).min(self.height as usize);
                    for p in row * w..end * w {
                        for i in offsets[p] as usize..offsets[p + 1] as usize {
                            let e = &self.entries[i];
                            let o = e.fragment.object.0 as usize;
                            band[i - base] = if unchanged.get(o) == Some(&true) {
                                (p as u32, e.fragment)
                            } else {
                                view.project(e.fragment.object, &e.surfel)
                                    .unwrap_or((u32::MAX, Fragment::default()))
                            };
                        }
                    }
                });
        }
        let offsets = &mut out.offsets;
        offsets.clear();
        offsets.resize(pixels + 1, 0);
        for &(p, _) in moved.iter() {
            if p != u32::MAX {
                offsets[p as usize + 1] += 1;
            }
        }
        for p in 0..pixels {
            offsets[p + 1] += offsets[p];
        }
        let total = offsets[pixels] as usize;
        out.entries.clear();
        out.entries.resize(total, Entry::default());
        let cursor = &mut scratch.cursor;
        cursor.clear();
        cursor.extend_from_slice(&offsets[..pixels]);
        for (e, &(p, f)) in self.entries.iter().zip(moved.iter()) {
            if p != u32::MAX {
                let c = &mut cursor[p as usize];
                out.entries[*c as usize] = Entry {
                    fragment: f,
                    surfel: e.surfel,
                };
                *c += 1;
            }
        }
        out.width = width;
        out.height = height;
        out.view = Some(view.clone());
        out.sort_runs();
    }

    /// Rebuilds this list for `view` from bands of consecutive pixels, each its entries and its
    /// pixels' run lengths, in order; keeps the buffers.
    pub(super) fn assemble<'a>(
        &mut self,
        view: &View,
        bands: impl Iterator<Item = (&'a [Entry], &'a [u32])>,
    ) {
        (self.width, self.height) = view.size();
        self.view = Some(view.clone());
        self.offsets.clear();
        self.offsets.push(0);
        self.entries.clear();
        let mut last = 0u32;
        for (entries, counts) in bands {
            for &c in counts {
                last += c;
                self.offsets.push(last);
            }
            self.entries.extend_from_slice(entries);
        }
        debug_assert_eq!(last as usize, self.entries.len());
    }

    /// Empties this list for a `width` × `height` frame, keeping its buffers.
    pub(super) fn clear_to(&mut self, width: u32, height: u32) {
        self.width = width;
        self.height = height;
        self.offsets.clear();
        self.offsets.resize(width as usize * height as usize + 1, 0);
        self.entries.clear();
        self.view = None;
    }

    /// Sorts every run front to back, stably, in parallel bands.
    fn sort_runs(&mut self) {
        let width = self.width as usize;
        let offsets = &self.offsets;
        split_bands(&mut self.entries, offsets, width, self.height as usize)
            .into_par_iter()
            .for_each(|(row, band)| {
                let base = offsets[row * width] as usize;
                let end = (row + BAND_ROWS).min(self.height as usize);
                for p in row * width..end * width {
                    let run = &mut band[offsets[p] as usize - base..offsets[p + 1] as usize - base];
                    sort_entries(run);
                }
            });
    }

    /// The colour DeepFrame the display resolves.
    pub fn to_frame(&self) -> DeepFrame {
        let depth = self.entries.iter().map(|e| e.fragment.depth).collect();
        let color = self.entries.iter().map(|e| e.fragment.color).collect();
        let object = self.entries.iter().map(|e| e.fragment.object).collect();
        // Runs are sorted by the fragment order, so this cannot fail.
        DeepFrame::from_parts(
            self.width,
            self.height,
            self.offsets.clone(),
            depth,
            color,
            object,
        )
        .unwrap_or_else(|_| DeepFrame::empty(self.width, self.height))
    }

    /// A 64-bit digest of what is held — run lengths, fragments and surfel positions, in order —
    /// computed over fixed bands, so it does not depend on the thread count.
    pub fn digest(&self) -> u64 {
        let width = self.width as usize;
        let bands = (self.height as usize).div_ceil(BAND_ROWS);
        let parts: Vec<u64> = (0..bands)
            .into_par_iter()
            .map(|b| {
                let mut h = Digest::new(b as u64);
                let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(self.height as usize);
                for p in rows.start * width..rows.end * width {
                    let run = self.run(p);
                    h.word(run.len() as u64);
                    for e in run {
                        // The fragment and the position: two ends that differ anywhere upstream
                        // (matrices, trigonometry) differ here. Normals are left out to keep the
                        // digest cheap; a difference in one shows once it changes a colour.
                        let (f, q) = (&e.fragment, &e.surfel.position);
                        h.word(u64::from(f.depth.to_bits()) << 32 | u64::from(f.color.to_bits()));
                        h.word(u64::from(f.object.0) << 32 | u64::from(q[0].to_bits()));
                        h.word(u64::from(q[1].to_bits()) << 32 | u64::from(q[2].to_bits()));
                    }
                }
                h.finish()
            })
            .collect();
        let mut h = Digest::new(u64::from(self.width) << 32 | u64::from(self.height));
        for p in parts {
            h.word(p);
        }
        h.finish()
    }
}

/// Cuts `items`, one per fragment of a list laid out by `offsets` over `height` rows of `width`
/// pixels, into bands of [`BAND_ROWS`] rows: `(first row, the band's items)`.
fn split_bands<'a, T>(
    items: &'a mut [T],
    offsets: &[u32],
    width: usize,
    height: usize,
) -> Vec<(usize, &'a mut [T])> {
    let mut bands = Vec::with_capacity(height.div_ceil(BAND_ROWS));
    let mut rest = items;
    let mut row = 0;
    while row < height {
        let end = (row + BAND_ROWS).min(height);
        let n = (offsets[end * width] - offsets[row * width]) as usize;
        let (band, tail) = std::mem::take(&mut rest).split_at_mut(n);
        bands.push((row, band));
        rest = tail;
        row = end;
    }
    bands
}

/// Buffers [`Held::reproject_into`] reuses from frame to frame.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    moved: Vec<(u32, Fragment)>,
    cursor: Vec<u32>,
}

/// A small multiply-rotate hash (not cryptographic: it detects divergence, not tampering).
struct Digest(u64);

impl Digest {
    fn new(seed: u64) -> Self {
        Digest(seed ^ 0x9E37_79B9_7F4A_7C15)
    }
    #[inline]
    fn word(&mut self, w: u64) {
        self.0 = (self.0 ^ w)
            .wrapping_mul(0xBF58_476D_1CE4_E5B9)
            .rotate_left(29);
    }
    fn finish(&self) -> u64 {
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}
