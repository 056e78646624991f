//! What both ends hold for one node: per pixel a run of entries (surfel + the fragment it shades
//! to now), sorted front to back; how it moves to a new view; its digest.
//!
//! Layout: one [`HeldBand`] per band of [`BAND_ROWS`] rows, each like a DeepFrame of its rows:
//! `offsets[pixels + 1]` into its own `entries` array, with the 36-byte [`Entry`] (12-byte
//! fragment, 24-byte surfel) as the column. Both ends build the next state band by band, in
//! parallel, and each band task writes its band's runs straight into that band's vectors
//! ([`Held::build_bands`]), kept from frame to frame; one array for the whole list would need
//! every band copied into it (32 MB a dragon frame, on each end).

use rayon::prelude::*;
use strata_core::{DeepFrame, Fragment, ObjectId};

use super::lanes::{Flush, LANES, Pending, RowTests};
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
    /// One per band of [`BAND_ROWS`] rows, top to bottom.
    bands: Vec<HeldBand>,
    /// The view the entries are shaded and bucketed for (none when empty).
    view: Option<View>,
}

/// One band's runs: `offsets[k]..offsets[k + 1]` indexes `entries` for the band's `k`-th pixel.
#[derive(Clone, Debug, Default, PartialEq)]
struct HeldBand {
    offsets: Vec<u32>,
    entries: Vec<Entry>,
}

impl HeldBand {
    /// Run lengths, pixel by pixel.
    fn counts(&self) -> impl Iterator<Item = u32> + '_ {
        self.offsets.windows(2).map(|o| o[1] - o[0])
    }
}

/// The pixels of band `b` of a `width` × `height` frame, row-major indices.
fn band_pixels(b: usize, width: usize, height: usize) -> std::ops::Range<usize> {
    let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(height);
    rows.start * width..rows.end * width
}

impl Held {
    /// Nothing held.
    pub fn empty(width: u32, height: u32) -> Self {
        let (w, h) = (width as usize, height as usize);
        let bands = (0..h.div_ceil(BAND_ROWS))
            .map(|b| HeldBand {
                offsets: vec![0; band_pixels(b, w, h).len() + 1],
                entries: Vec::new(),
            })
            .collect();
        Held {
            width,
            height,
            bands,
            view: None,
        }
    }

    /// Fragments held.
    pub fn len(&self) -> usize {
        self.bands.iter().map(|b| b.entries.len()).sum()
    }

    /// True if nothing is held.
    pub fn is_empty(&self) -> bool {
        self.bands.iter().all(|b| b.entries.is_empty())
    }

    /// Pixel `p`'s run.
    pub fn run(&self, p: usize) -> &[Entry] {
        let band_size = self.width as usize * BAND_ROWS;
        let band = &self.bands[p / band_size];
        let k = p % band_size;
        &band.entries[band.offsets[k] as usize..band.offsets[k + 1] as usize]
    }

    /// Each band's first entry in the order of the whole list (the bands' entries one after
    /// another), and the list's length after them.
    fn band_starts(&self) -> Vec<usize> {
        let mut starts = Vec::with_capacity(self.bands.len() + 1);
        let mut at = 0;
        for band in &self.bands {
            starts.push(at);
            at += band.entries.len();
        }
        starts.push(at);
        starts
    }

    /// Every held surfel moved to `view` (eq. 5.9), shaded, bucketed by the pixel it lands in and
    /// sorted front to back (stably: equal keys keep the order of this list). Objects whose
    /// matrices did not change keep their pixel and fragment bit for bit.
    pub fn reproject(&self, view: &View) -> Held {
        let mut out = Held::empty(0, 0);
        self.reproject_into(view, &mut out, &mut Scratch::default());
        out
    }

    /// [`Held::reproject`] into `out`, reusing its buffers and `scratch`'s (once they have grown
    /// to the scene's needs, a call allocates only a few vectors per band, none per entry). The
    /// node and the display do not build this whole list: each sorts a band at a time in the
    /// task that consumes it, with the same passes, so their runs are this list's.
    ///
    /// The list is moved and bucketed by destination band in parallel passes (`Held::move_to`),
    /// then each band is sorted in parallel straight into its band of `out`: a counting sort
    /// by pixel, then each run front to back. Buckets keep the list's order and the counting
    /// sort is stable, so the result is the stable sort of the whole list by pixel, then by
    /// fragment order, whatever the thread count.
    pub fn reproject_into(&self, view: &View, out: &mut Held, scratch: &mut Scratch) {
        let moved = self.move_to(view, scratch);
        out.bands.resize_with(moved.band_count(), HeldBand::default);
        out.bands.par_iter_mut().enumerate().for_each(|(d, band)| {
            let pixels = moved.band_pixels(d).len();
            // Every entry and offset is written below: no need to clear what the last frame
            // left.
            band.offsets.resize(pixels + 1, 0);
            band.offsets[pixels] = moved.band_len(d) as u32;
            band.entries.resize(moved.band_len(d), Entry::default());
            moved.sort_band_into(d, 0, &mut band.offsets[..pixels], &mut band.entries);
        });
        (out.width, out.height) = view.size();
        out.view = Some(view.clone());
    }

    /// Every held entry moved to `view` and bucketed by the band of [`BAND_ROWS`] rows it lands
    /// in, in `scratch`'s buffers; the bands are then sorted one by one, by whoever consumes
    /// them ([`Moved::sort_band`]), so the sorted runs need not pass through memory as a whole
    /// list. One parallel pass and a small serial one, none over the whole list on one thread:
    ///
    /// 1. per source band (of 16 rows): every entry moved to `view`
    ///    (`View::project_batch`: `LANES` consecutive entries of one moving object as they lie,
    ///    any other entry in batches of one object's entries gathered by `lanes::Pending`),
    ///    then, while the band's moved entries are still in cache, the indices of those that
    ///    stay in view grouped by destination band in the source band's own stretch of the
    ///    bucket list (a counting sort by destination band, so each group keeps source order);
    /// 2. (serial, over bands × bands) how many entries land in each destination band;
    /// 3. (per destination band, by [`Moved::sort_band_into`]) a counting sort of its groups,
    ///    source band by source band, by pixel, then each run sorted front to back.
    ///
    /// Groups keep source order and the counting sort is stable, so the result is the stable
    /// sort of the whole list by pixel, then by fragment order, whatever the thread count.
    /// (The groups used to be gathered by destination band in a pass of their own over the
    /// whole moved list, reading it back from memory.)
    pub(super) fn move_to<'a>(&'a self, view: &View, scratch: &'a mut Scratch) -> Moved<'a> {
        let (width, height) = view.size();
        let (new_w, new_h) = (width as usize, height as usize);
        let unchanged: Vec<bool> = match &self.view {
            Some(old) => (0..view.object_slots())
                .map(|o| view.unchanged(old, o))
                .collect(),
            None => Vec::new(),
        };
        let dst_bands = new_h.div_ceil(BAND_ROWS);
        let band_size = new_w * BAND_ROWS;
        let Scratch {
            moved,
            bucket,
            groups,
            sorted,
        } = scratch;
        // Every element is written in pass 1 (the bucket's up to each band's entries in view,
        // and only those are read): no need to clear what the last frame left.
        moved.resize(self.len(), (u32::MAX, Fragment::default()));
        bucket.resize(self.len(), 0);
        let (w, h) = (self.width as usize, self.height as usize);
        let src_bands = self.bands.len();
        groups.resize_with(src_bands, Vec::new);
        let src_starts = self.band_starts();

        // 1. Move every entry; group the indices of those in view by destination band.
        {
            let lens = || self.bands.iter().map(|b| b.entries.len());
            split_lens(moved, lens())
                .into_par_iter()
                .zip(split_lens(bucket, lens()))
                .zip(self.bands.par_iter().enumerate())
                .zip(groups.par_iter_mut())
                .for_each(|(((band, grouped), (s, src)), group)| {
                    let first = band_pixels(s, w, h).start;
                    let (entries, offsets) = (&src.entries, &src.offsets);
                    let unchanged = |o: ObjectId| unchanged.get(o.0 as usize) == Some(&true);
                    let mut pending = Pending::default();
                    let mut flush = MoveFlush { view, band };
                    // Where the next `LANES` entries are all of one moving (not unchanged)
                    // object — nearly all of a band, where one object fills the view — they go
                    // through the lanes straight from the list into their places. Every other
                    // entry goes one at a time: through `Pending`, or kept as it is for an
                    // unchanged object, with its pixel found by a cursor `k` that only walks
                    // forward (it catches up with `i` there). After a failed test the next
                    // entries go one at a time (`RowTests`), so that runs through several
                    // objects are not tested at every entry.
                    let (mut i, mut k, mut tests) = (0, 0, RowTests::from(0));
                    while i < entries.len() {
                        if tests.due(i)
                            && let Some(row) = entries.get(i..i + LANES)
                            && let Ok(row) = <&[Entry; LANES]>::try_from(row)
                        {
                            let object = row[0].fragment.object;
                            if row.iter().all(|e| e.fragment.object == object)
                                && !unchanged(object)
                                && let Ok(out) = <&mut [(u32, Fragment); LANES]>::try_from(
                                    &mut flush.band[i..i + LANES],
                                )
                            {
                                view.project_batch(object, row, out);
                                i += LANES;
                                tests.passed();
                                continue;
                            }
                            tests.failed(i);
                        }
                        while offsets[k + 1] as usize <= i {
                            k += 1;
                        }
                        let e = &entries[i];
                        let object = e.fragment.object;
                        if unchanged(object) {
                            flush.band[i] = ((first + k) as u32, e.fragment);
                        } else {
                            pending.push(object, i, e.surfel, &mut flush);
                        }
                        i += 1;
                    }
                    pending.finish(&mut flush);
                    // Counts per destination band, then their starts (`group[d]`), then the
                    // indices placed, each group's start stepping to its end (which is the
                    // next group's start), so a shift leaves the starts again. Neighbouring
                    // entries mostly land in one band: its count or cursor stays in a register
                    // until an entry lands elsewhere (a counter stepped in memory made every
                    // entry wait for the last one's store), and the band is found by a
                    // division only then.
                    group.clear();
                    group.resize(dst_bands + 1, 0);
                    // In 64 bits, so that no frame size can wrap the band's bounds.
                    let bs = band_size as u64;
                    let (mut cur, mut lo, mut n) = (None, 0u64, 0u32);
                    for &(p, _) in band.iter() {
                        if p == u32::MAX {
                            continue;
                        }
                        let p = u64::from(p);
                        if cur.is_none() || p.wrapping_sub(lo) >= bs {
                            if let Some(d) = cur {
                                group[d + 1] += n;
                            }
                            let d = (p / bs) as usize;
                            (cur, lo, n) = (Some(d), d as u64 * bs, 0);
                        }
                        n += 1;
                    }
                    if let Some(d) = cur {
                        group[d + 1] += n;
                    }
                    for d in 0..dst_bands {
                        group[d + 1] += group[d];
                    }
                    let index = src_starts[s] as u32;
                    let (mut cur, mut lo, mut at) = (None, 0u64, 0u32);
                    for (k, &(p, _)) in band.iter().enumerate() {
                        if p == u32::MAX {
                            continue;
                        }
                        let p = u64::from(p);
                        if cur.is_none() || p.wrapping_sub(lo) >= bs {
                            if let Some(d) = cur {
                                group[d] = at;
                            }
                            let d = (p / bs) as usize;
                            (cur, lo, at) = (Some(d), d as u64 * bs, group[d]);
                        }
                        grouped[at as usize] = index + k as u32;
                        at += 1;
                    }
                    if let Some(d) = cur {
                        group[d] = at;
                    }
                    group.copy_within(..dst_bands, 1);
                    group[0] = 0;
                });
        }

        // 2. How many entries land in each destination band.
        let band_lens = (0..dst_bands)
            .map(|d| groups.iter().map(|g| (g[d + 1] - g[d]) as usize).sum())
            .collect();
        Moved {
            held: self,
            moved,
            bucket,
            band_lens,
            src_starts,
            groups,
            sorted,
            width: new_w,
            height: new_h,
        }
    }

    /// Rebuilds this list for `view` band by band in parallel, each band in its own buffers
    /// from the frame before: `fill(d, &mut state[d], entries, counts)` leaves band `d`'s
    /// entries (of [`BAND_ROWS`] rows) in `entries` and one run length per pixel of the band in
    /// `counts`, both emptied for it. Returns each band's result, and whether its run lengths
    /// added up to its entries: if one did not, the list is not a valid state.
    ///
    /// # Panics
    /// If `state` does not have one item per band of the view.
    pub(super) fn build_bands<S: Send, R: Send>(
        &mut self,
        view: &View,
        state: &mut [S],
        fill: impl Fn(usize, &mut S, &mut Vec<Entry>, &mut Vec<u32>) -> R + Sync,
    ) -> Vec<(R, bool)> {
        (self.width, self.height) = view.size();
        self.view = Some(view.clone());
        let (w, h) = (self.width as usize, self.height as usize);
        let bands = h.div_ceil(BAND_ROWS);
        assert_eq!(state.len(), bands, "one state per band");
        self.bands.resize_with(bands, HeldBand::default);
        let built: Vec<(R, bool)> = self
            .bands
            .par_iter_mut()
            .zip(state.par_iter_mut())
            .enumerate()
            .map(|(d, (band, s))| {
                band.entries.clear();
                band.offsets.clear();
                let r = fill(d, s, &mut band.entries, &mut band.offsets);
                let pixels = band_pixels(d, w, h).len();
                // The counts become each pixel's first entry, and the band's length follows.
                let mut end = 0u64;
                for o in band.offsets.iter_mut() {
                    let n = u64::from(*o);
                    *o = end as u32;
                    end += n;
                }
                band.offsets.push(end as u32);
                let fits = band.offsets.len() == pixels + 1
                    && end == band.entries.len() as u64
                    && u32::try_from(end).is_ok();
                (r, fits)
            })
            .collect();
        built
    }

    /// The colour DeepFrame the display resolves.
    pub fn to_frame(&self) -> DeepFrame {
        self.frame_into(DeepFrame::empty(0, 0))
    }

    /// [`Held::to_frame`] into `reuse`'s buffers (any frame: its size does not matter), filled
    /// band by band in parallel. A display converts its held list every frame; reusing the last
    /// frame's columns spares it 1280×720 offsets and three columns of fresh pages a frame.
    pub fn frame_into(&self, reuse: DeepFrame) -> DeepFrame {
        let (width, height) = (self.width, self.height);
        let (_, _, mut offsets, depth, color, object) = reuse.into_parts();
        // Each band's offsets, moved by the entries of the bands above it. A list past u32
        // entries (which no wire frame can fill) gives the empty frame below.
        let starts = self.band_starts();
        let pixels = width as usize * height as usize;
        offsets.resize(pixels + 1, 0);
        offsets[pixels] = starts[self.bands.len()] as u32;
        let w = width as usize;
        let lens = (0..self.bands.len()).map(|b| band_pixels(b, w, height as usize).len());
        split_lens(&mut offsets[..pixels], lens)
            .into_par_iter()
            .zip(self.bands.par_iter().zip(&starts[..self.bands.len()]))
            .for_each(|(out, (band, &start))| {
                for (o, &k) in out.iter_mut().zip(&band.offsets) {
                    *o = (start + k as usize) as u32;
                }
            });
        let bands: Vec<std::ops::Range<usize>> = (0..height as usize)
            .step_by(BAND_ROWS)
            .map(|row| row * w..(row + BAND_ROWS).min(height as usize) * w)
            .collect();
        // Runs are sorted by the fragment order, so this cannot fail.
        DeepFrame::fill_bands(
            width,
            height,
            offsets,
            &bands,
            (depth, color, object),
            |i, band| {
                let from = &self.bands[i].entries;
                for (((e, d), c), o) in from
                    .iter()
                    .zip(band.depth.iter_mut())
                    .zip(band.color.iter_mut())
                    .zip(band.object.iter_mut())
                {
                    (*d, *c, *o) = (e.fragment.depth, e.fragment.color, e.fragment.object);
                }
            },
        )
        .unwrap_or_else(|e| {
            if cfg!(debug_assertions) {
                panic!("a held list is always a valid frame: {e}");
            }
            DeepFrame::empty(width, height)
        })
    }

    /// A 64-bit digest of what is held — run lengths, fragments and surfel positions, in order —
    /// computed over fixed bands (`band_digest`, combined by `frame_digest`), so it does not
    /// depend on the thread count.
    pub fn digest(&self) -> u64 {
        let parts: Vec<u64> = (self.bands.par_iter().enumerate())
            .map(|(b, band)| {
                let counts: Vec<u32> = band.counts().collect();
                band_digest(b, &band.entries, &counts)
            })
            .collect();
        frame_digest(self.width, self.height, parts)
    }
}

/// The digest of band `b` (rows `b · BAND_ROWS` on) of a held list: its pixels' run lengths
/// `counts` and their `entries`, in order. The ends compute it in their band tasks, while the
/// band is in cache; [`Held::digest`] computes the same from a whole list.
///
/// Seven independent chains, so that their multiplies overlap instead of waiting for one
/// another (one chain took three dependent multiplies an entry and one a pixel): the run
/// lengths of pixels `p ≡ k (mod 4)` in chain `k`, and each entry's three words in chains 4, 5
/// and 6. The chains' values are then hashed in order. Where the entries of a band fall between
/// its pixels is fixed by the run lengths, so the digest still changes with any run length,
/// fragment or position, and with their order.
pub(super) fn band_digest(b: usize, entries: &[Entry], counts: &[u32]) -> u64 {
    let seed = (b as u64) << 3;
    let mut runs = [0, 1, 2, 3].map(|k| Digest::new(seed | k));
    let mut blocks = counts.chunks_exact(4);
    for block in &mut blocks {
        for (h, &n) in runs.iter_mut().zip(block) {
            h.word(u64::from(n));
        }
    }
    for (h, &n) in runs.iter_mut().zip(blocks.remainder()) {
        h.word(u64::from(n));
    }
    let [mut first, mut second, mut third] = [4, 5, 6].map(|k| Digest::new(seed | k));
    for e in entries {
        // The fragment and the position: two ends that differ anywhere upstream (matrices,
        // trigonometry) differ here. Normals are left out to keep the digest cheap; a
        // difference in one shows once it changes a colour.
        let (f, q) = (&e.fragment, &e.surfel.position);
        // NaN is hashed as one value: IEEE arithmetic fixes values on every instruction set,
        // not NaN payloads (a point unprojected at w = 0 is NaN).
        let bits = |x: f32| u64::from(if x.is_nan() { f32::NAN } else { x }.to_bits());
        first.word(bits(f.depth) << 32 | u64::from(f.color.to_bits()));
        second.word(u64::from(f.object.0) << 32 | bits(q[0]));
        third.word(bits(q[1]) << 32 | bits(q[2]));
    }
    let mut h = Digest::new(b as u64);
    for chain in runs.iter().chain([&first, &second, &third]) {
        h.word(chain.0);
    }
    h.word(entries.len() as u64);
    h.finish()
}

/// The digest of a `width` × `height` held list from its bands' [`band_digest`]s, in order.
pub(super) fn frame_digest(width: u32, height: u32, bands: impl IntoIterator<Item = u64>) -> u64 {
    let mut h = Digest::new(u64::from(width) << 32 | u64::from(height));
    for p in bands {
        h.word(p);
    }
    h.finish()
}

/// Cuts `items` into consecutive pieces of `lens` items each.
fn split_lens<T>(items: &mut [T], lens: impl Iterator<Item = usize>) -> Vec<&mut [T]> {
    let mut rest = items;
    lens.map(|n| {
        let (piece, tail) = std::mem::take(&mut rest).split_at_mut(n);
        rest = tail;
        piece
    })
    .collect()
}

/// Buffers the reprojection reuses from frame to frame: [`Held::reproject_into`], and the two
/// ends, which move the list (`Held::move_to`) and sort it band by band in their band tasks.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    /// Per held entry, its pixel and fragment in the new view (`u32::MAX`: out of view).
    moved: Vec<(u32, Fragment)>,
    /// Indices of the entries that stay in view: each source band's in its own stretch (from
    /// its first entry on), grouped by destination band.
    bucket: Vec<u32>,
    /// Per source band, where its group for each destination band starts in its stretch of
    /// `bucket`, and where the last ends (one more than the destination bands).
    groups: Vec<Vec<u32>>,
    /// Sorted bands' buffers, lent to band tasks ([`Moved::sort_band`]).
    sorted: BandPool,
}

/// Buffers for sorted bands, one taken by each band task while it runs and given back after,
/// so a frame's band tasks reuse as many as there are threads, warm in their caches.
#[derive(Debug, Default)]
struct BandPool(std::sync::Mutex<Vec<SortedBand>>);

impl Clone for BandPool {
    /// A fresh pool: the buffers are only capacity.
    fn clone(&self) -> Self {
        BandPool::default()
    }
}

/// One destination band's runs, sorted: `offsets[k]..offsets[k + 1]` indexes `entries` for the
/// band's `k`-th pixel.
#[derive(Clone, Debug, Default)]
pub(super) struct SortedBand {
    first_pixel: usize,
    offsets: Vec<u32>,
    entries: Vec<Entry>,
}

impl SortedBand {
    /// Pixel `p`'s run (`p` indexes the whole frame and lies in the band).
    #[inline]
    pub(super) fn run(&self, p: usize) -> &[Entry] {
        let k = p - self.first_pixel;
        &self.entries[self.offsets[k] as usize..self.offsets[k + 1] as usize]
    }

    /// The runs of the band's consecutive pixels `pixels` (indexing the whole frame): their
    /// entries, and the offsets of their runs (`pixels.len() + 1`, into the band's entries).
    #[inline]
    pub(super) fn span(&self, pixels: std::ops::Range<usize>) -> (&[Entry], &[u32]) {
        let (a, b) = (
            pixels.start - self.first_pixel,
            pixels.end - self.first_pixel,
        );
        let offsets = &self.offsets[a..b + 1];
        (
            &self.entries[offsets[0] as usize..offsets[b - a] as usize],
            offsets,
        )
    }
}

/// A held list moved to a new view and bucketed by destination band ([`Held::move_to`]), each
/// band still to be sorted.
pub(super) struct Moved<'a> {
    held: &'a Held,
    moved: &'a [(u32, Fragment)],
    bucket: &'a [u32],
    /// Entries landing in each destination band.
    band_lens: Vec<usize>,
    /// Each source band's first entry in `moved` (and in the bucket's indices), and the
    /// list's length after them.
    src_starts: Vec<usize>,
    /// Per source band, its groups in `bucket` by destination band ([`Scratch::groups`]).
    groups: &'a [Vec<u32>],
    sorted: &'a BandPool,
    width: usize,
    height: usize,
}

impl Moved<'_> {
    /// Destination bands.
    pub(super) fn band_count(&self) -> usize {
        self.band_lens.len()
    }

    /// Fragments landing in band `d`.
    pub(super) fn band_len(&self, d: usize) -> usize {
        self.band_lens[d]
    }

    /// Band `d`'s pixels, row-major indices into the new view.
    pub(super) fn band_pixels(&self, d: usize) -> std::ops::Range<usize> {
        let rows = d * BAND_ROWS..((d + 1) * BAND_ROWS).min(self.height);
        rows.start * self.width..rows.end * self.width
    }

    /// Band `d` sorted into a buffer lent from the pool for the duration of `f`.
    pub(super) fn sort_band<R>(&self, d: usize, f: impl FnOnce(&SortedBand) -> R) -> R {
        let lock = || self.sorted.0.lock().unwrap_or_else(|e| e.into_inner());
        let mut band = lock().pop().unwrap_or_default();
        let pixels = self.band_pixels(d);
        band.first_pixel = pixels.start;
        // Every entry and offset is written below.
        band.offsets.resize(pixels.len() + 1, 0);
        band.offsets[pixels.len()] = self.band_len(d) as u32;
        band.entries.resize(self.band_len(d), Entry::default());
        let SortedBand {
            offsets, entries, ..
        } = &mut band;
        self.sort_band_into(d, 0, &mut offsets[..pixels.len()], entries);
        let r = f(&band);
        lock().push(band);
        r
    }

    /// Band `d`'s entries into `entries` (`band_len(d)` of them) and each pixel's first
    /// entry, plus `base`, into `offs` (one per pixel of the band): a counting sort by pixel of
    /// its groups, source band by source band, then each run sorted front to back.
    fn sort_band_into(&self, d: usize, base: u32, offs: &mut [u32], entries: &mut [Entry]) {
        let first_pixel = self.band_pixels(d).start;
        let (moved, held) = (self.moved, self.held);
        // Source band `s`'s group for this band: indices into `moved`, in source order.
        let group = |s: usize| {
            let (g, at) = (&self.groups[s], self.src_starts[s]);
            &self.bucket[at + g[d] as usize..at + g[d + 1] as usize]
        };
        // Counts, then each pixel's end; filling backwards leaves each pixel's start.
        offs.fill(0);
        for s in 0..self.groups.len() {
            for &i in group(s) {
                offs[moved[i as usize].0 as usize - first_pixel] += 1;
            }
        }
        let mut end = base;
        for o in offs.iter_mut() {
            end += *o;
            *o = end;
        }
        // Walked backwards, group by group, each entry's surfel is found in its source band.
        for s in (0..self.groups.len()).rev() {
            let (source, start) = (&held.bands[s].entries, self.src_starts[s]);
            for &i in group(s).iter().rev() {
                let (p, f) = moved[i as usize];
                let o = &mut offs[p as usize - first_pixel];
                *o -= 1;
                // Field by field: an `Entry` built first went through the stack, and its
                // wide reloads waited for the narrower stores that built it.
                let e = &mut entries[(*o - base) as usize];
                e.fragment = f;
                e.surfel = source[i as usize - start].surfel;
            }
        }
        for (k, &start) in offs.iter().enumerate() {
            let stop = offs
                .get(k + 1)
                .map_or(entries.len(), |&s| (s - base) as usize);
            // Most pixels hold one fragment or none: nothing to sort.
            if stop > (start - base) as usize + 1 {
                sort_entries(&mut entries[(start - base) as usize..stop]);
            }
        }
    }
}

/// [`Held::move_to`]'s batches: each moved to `view` into `band`, its source band's share of the
/// moved list; an item goes to `band[i]`.
struct MoveFlush<'a> {
    view: &'a View,
    band: &'a mut [(u32, Fragment)],
}

impl Flush<usize, Surfel> for MoveFlush<'_> {
    #[inline(always)]
    fn flush(
        &mut self,
        object: ObjectId,
        to: &[usize; LANES],
        surfels: &[Surfel; LANES],
        len: usize,
    ) {
        let mut moved = [(u32::MAX, Fragment::default()); LANES];
        // Lanes past `len` hold earlier surfels: moved, and not written back.
        self.view.project_batch(object, surfels, &mut moved);
        for (&i, m) in to[..len].iter().zip(moved) {
            self.band[i] = m;
        }
    }
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
