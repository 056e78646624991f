//! DeepFrame: every pixel's fragments as one sorted run, in one contiguous layout.
//!
//! DeepFrame is strata's lingua franca (the pipeline design): whatever a fragment store captured, it hands
//! over a DeepFrame, and resolve, comparison, encoding, merging and composition all work on it.
//!
//! # Layout
//!
//! The S-buffer layout of Tsopouridis 2021 §3.1.3 — prefix-summed per-pixel counts and contiguous
//! fragments — with the fragment fields split into columns:
//!
//! ```text
//! offsets: [u32; w*h + 1]     pixel p (row-major, row 0 at the top) owns fragments
//!                             offsets[p] .. offsets[p+1]
//! depth:   [f32; n]           window depth in [0, 1]         ┐
//! color:   [Rgba8; n]         straight-alpha RGBA8           ├ one entry per fragment
//! object:  [ObjectId; n]      the object that made it        ┘
//! ```
//!
//! Columns rather than an array of structs because every consumer reads them separately: the
//! resolve reads colours only after the order is known, statistics read only the offsets, and the
//! wire codecs of the remote-rendering path compress each column with its own model.
//!
//! # Invariants (checked by every constructor)
//!
//! - `offsets` has `w*h + 1` entries, starts at 0, never decreases, and ends at the column length;
//! - every depth is finite, in `[0, 1]`, and `-0.0` never appears;
//! - every run is sorted front to back by [`Fragment::order_key`] (depth, then object, then
//!   colour), so two DeepFrames of the same fragments are equal whatever order they were captured in.

use rayon::prelude::*;
use std::borrow::Borrow;

use crate::composite;
use crate::fragment::{Fragment, ObjectId, Rgba8, sort_front_to_back};
use crate::image::Rgb8Image;
use crate::run_limit::RunLimit;
use crate::stats::DepthStats;

/// Why fragments could not form a DeepFrame.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DeepFrameError {
    /// `width * height` overflows or is inconsistent with the per-pixel data given.
    #[error("a {width}x{height} frame needs {expected} per-pixel entries, got {found}")]
    PixelCount {
        /// Frame width.
        width: u32,
        /// Frame height.
        height: u32,
        /// `width * height` (+1 for offsets).
        expected: u64,
        /// What was given.
        found: u64,
    },
    /// More fragments than a `u32` offset can address.
    #[error("{0} fragments exceed the DeepFrame limit of 2^32 - 1")]
    TooManyFragments(u64),
    /// A pixel's fill produced a different number of fragments than its count announced.
    #[error("pixel {pixel}: expected {expected} fragments, the store produced {found}")]
    CountMismatch {
        /// Row-major pixel index.
        pixel: usize,
        /// The announced count.
        expected: u32,
        /// The fragments produced.
        found: usize,
    },
    /// The offsets do not start at 0, decrease, or do not end at the column length.
    #[error("offsets are not a prefix sum of the fragment columns (at pixel {pixel})")]
    BadOffsets {
        /// The first pixel where the offsets are wrong.
        pixel: usize,
    },
    /// The columns have different lengths.
    #[error(
        "fragment columns differ in length: {depth} depths, {color} colours, {object} object ids"
    )]
    ColumnLengths {
        /// Depth column length.
        depth: usize,
        /// Colour column length.
        color: usize,
        /// Object column length.
        object: usize,
    },
    /// A depth is NaN, infinite, negative (including -0.0) or above 1.
    #[error("fragment {index}: depth {depth} is outside [0, 1]")]
    BadDepth {
        /// Fragment index.
        index: usize,
        /// The offending value.
        depth: f32,
    },
    /// A run is not in front-to-back order.
    #[error("pixel {pixel}: fragments are not sorted front to back")]
    Unsorted {
        /// Row-major pixel index.
        pixel: usize,
    },
    /// Rows appended below a frame are not as wide as the frame.
    #[error("cannot append rows {found} pixels wide below a frame {width} pixels wide")]
    WidthMismatch {
        /// The frame's width.
        width: u32,
        /// The appended rows' width.
        found: u32,
    },
}

/// One pixel's fragments, front to back.
#[derive(Clone, Copy, Debug)]
pub struct Run<'a> {
    /// Depths, ascending.
    pub depth: &'a [f32],
    /// Colours, in the same order.
    pub color: &'a [Rgba8],
    /// Object ids, in the same order.
    pub object: &'a [ObjectId],
}

impl<'a> Run<'a> {
    /// Number of fragments.
    #[inline]
    pub fn len(&self) -> usize {
        self.depth.len()
    }

    /// True if the pixel holds no fragment.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.depth.is_empty()
    }

    /// The `i`-th fragment from the front.
    #[inline]
    pub fn get(&self, i: usize) -> Option<Fragment> {
        Some(Fragment {
            depth: *self.depth.get(i)?,
            color: self.color[i],
            object: self.object[i],
        })
    }

    /// The fragments front to back.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = Fragment> + 'a {
        let (depth, color, object) = (self.depth, self.color, self.object);
        (0..depth.len()).map(move |i| Fragment {
            depth: depth[i],
            color: color[i],
            object: object[i],
        })
    }
}

/// Per-pixel sorted fragment runs of one frame; see the module docs for layout and invariants.
#[derive(Clone, Debug, PartialEq)]
pub struct DeepFrame {
    width: u32,
    height: u32,
    offsets: Vec<u32>,
    depth: Vec<f32>,
    color: Vec<Rgba8>,
    object: Vec<ObjectId>,
}

/// One band of a frame being built by [`DeepFrame::fill_bands`]: the band's pixels, the
/// frame's offsets, and the band's fragments to write — those of pixel `p` (in `pixels`) are
/// `offsets[p] - offsets[pixels.start] .. offsets[p + 1] - offsets[pixels.start]` of each column.
#[derive(Debug)]
pub struct FillBand<'a> {
    /// The band's pixels (row-major indices into the frame).
    pub pixels: std::ops::Range<usize>,
    /// The frame's offsets, all `w·h + 1`; they rise over `pixels`.
    pub offsets: &'a [u32],
    /// The band's depths.
    pub depth: &'a mut [f32],
    /// The band's colours.
    pub color: &'a mut [Rgba8],
    /// The band's object ids.
    pub object: &'a mut [ObjectId],
}

/// Pixels per parallel work item when building or resolving.
const PIXELS_PER_TASK: usize = 8 * 1024;

fn pixel_count(width: u32, height: u32) -> usize {
    width as usize * height as usize
}

impl DeepFrame {
    /// A frame with no fragments.
    pub fn empty(width: u32, height: u32) -> Self {
        DeepFrame {
            width,
            height,
            offsets: vec![0; pixel_count(width, height) + 1],
            depth: Vec::new(),
            color: Vec::new(),
            object: Vec::new(),
        }
    }

    /// Builds a frame in parallel from per-pixel counts and a fill callback.
    ///
    /// `counts[p]` is the number of fragments pixel `p` (row-major) holds; `fill(p, out)` must push
    /// exactly that many fragments into the empty `out` (in any order: runs are sorted here). It is
    /// not called for pixels whose count is 0. This
    /// is how a fragment store exports: count, prefix-sum, then gather — the S-buffer's passes.
    pub fn build<F>(
        width: u32,
        height: u32,
        counts: &[u32],
        fill: F,
    ) -> Result<Self, DeepFrameError>
    where
        F: Fn(usize, &mut Vec<Fragment>) + Sync,
    {
        let pixels = pixel_count(width, height);
        if counts.len() != pixels {
            return Err(DeepFrameError::PixelCount {
                width,
                height,
                expected: pixels as u64,
                found: counts.len() as u64,
            });
        }
        let offsets = offsets_of(counts.iter().copied(), pixels)?;
        let (mut depth, mut color, mut object) = columns(offsets[pixels] as usize);
        // Cut the columns at pixel-chunk boundaries so every task owns disjoint slices.
        let chunks: Vec<std::ops::Range<usize>> = (0..pixels)
            .step_by(PIXELS_PER_TASK)
            .map(|p0| p0..(p0 + PIXELS_PER_TASK).min(pixels))
            .collect();
        let lens = chunks
            .iter()
            .map(|r| (offsets[r.end] - offsets[r.start]) as usize);
        let slices = split_columns((&mut depth, &mut color, &mut object), lens);
        let tasks: Vec<_> = chunks
            .into_iter()
            .zip(slices)
            .map(|(r, (d, c, o))| (r, d, c, o))
            .collect();
        let offsets_ref = &offsets;
        tasks.into_par_iter().try_for_each_init(
            || Vec::with_capacity(64),
            |scratch, (pixels, d, c, o)| {
                let base = offsets_ref[pixels.start] as usize;
                for p in pixels {
                    let expected = counts[p];
                    // Most pixels of a sparse frame (a fast client's few objects) are empty:
                    // they cost one compare.
                    if expected == 0 {
                        continue;
                    }
                    scratch.clear();
                    fill(p, scratch);
                    if scratch.len() != expected as usize {
                        return Err(DeepFrameError::CountMismatch {
                            pixel: p,
                            expected,
                            found: scratch.len(),
                        });
                    }
                    check_and_sort(scratch, p)?;
                    let start = offsets_ref[p] as usize - base;
                    for (i, f) in scratch.iter().enumerate() {
                        d[start + i] = f.depth;
                        c[start + i] = f.color;
                        o[start + i] = f.object;
                    }
                }
                Ok(())
            },
        )?;
        Ok(DeepFrame {
            width,
            height,
            offsets,
            depth,
            color,
            object,
        })
    }

    /// Builds a frame in one pass over the pixels, for stores whose per-pixel counts cost as much
    /// as their fragments (a linked list walks a list to count it): `fill(p, out)` pushes pixel
    /// `p`'s fragments into the empty `out`, in any order (runs are sorted here), for every
    /// pixel. The result equals [`DeepFrame::build`]'s with the counts `fill` implies.
    ///
    /// Tasks of consecutive pixels gather into columns of their own in parallel; the offsets are
    /// then summed over the tasks' counts and the columns copied into place — one streaming copy
    /// instead of a second walk over the store.
    pub fn gather<F>(width: u32, height: u32, fill: F) -> Result<Self, DeepFrameError>
    where
        F: Fn(usize, &mut Vec<Fragment>) + Sync,
    {
        let pixels = pixel_count(width, height);
        let bands: Vec<GatheredPixels> = (0..pixels.div_ceil(PIXELS_PER_TASK))
            .into_par_iter()
            .map_init(
                || Vec::with_capacity(64),
                |scratch, task| {
                    let first = task * PIXELS_PER_TASK;
                    GatheredPixels::gather(
                        first..(first + PIXELS_PER_TASK).min(pixels),
                        scratch,
                        &fill,
                    )
                },
            )
            .collect::<Result<_, DeepFrameError>>()?;
        Self::from_gathered(width, height, bands)
    }

    /// Assembles a frame from the gathered fragments of consecutive runs of its pixels, in
    /// order: the offsets are summed over the runs' counts and each run's columns are copied
    /// into place in parallel. An error if the runs do not hold `width × height` pixels, or more
    /// than `u32::MAX` fragments in all.
    pub fn from_gathered(
        width: u32,
        height: u32,
        bands: Vec<GatheredPixels>,
    ) -> Result<Self, DeepFrameError> {
        Self::from_gathered_reusing(width, height, bands, None)
    }

    /// [`DeepFrame::from_gathered`] into the buffers of `reuse`, a frame no longer needed, when
    /// there is one: a stream of frames is then assembled in memory it already has, with no
    /// fresh pages for the kernel to fault in and zero, and nothing zeroed here but what the
    /// new frame holds beyond the old one's lengths.
    ///
    /// The runs may be owned (each freed once its columns are in place) or borrowed, by a
    /// caller that gathers into the same buffers frame after frame ([`GatherWriter::reusing`]).
    pub fn from_gathered_reusing<G: Borrow<GatheredPixels> + Send>(
        width: u32,
        height: u32,
        bands: Vec<G>,
        reuse: Option<DeepFrame>,
    ) -> Result<Self, DeepFrameError> {
        let pixels = pixel_count(width, height);
        let found: usize = bands.iter().map(|g| g.borrow().counts.len()).sum();
        if found != pixels {
            return Err(DeepFrameError::PixelCount {
                width,
                height,
                expected: pixels as u64,
                found: found as u64,
            });
        }
        // Each run's first offset, from the runs' totals; the offsets within a run are then
        // summed by the task that copies its columns.
        let mut bases = Vec::with_capacity(bands.len());
        let mut total = 0u64;
        for g in &bands {
            bases.push(total as u32);
            total += g.borrow().depth.len() as u64;
            u32::try_from(total).map_err(|_| DeepFrameError::TooManyFragments(total))?;
        }
        // Every entry is written below: the offsets past the first by their runs' tasks, the
        // columns by the copies.
        let (mut offsets, mut depth, mut color, mut object) = match reuse {
            Some(f) => {
                let (mut offsets, mut depth, mut color, mut object) =
                    (f.offsets, f.depth, f.color, f.object);
                offsets.resize(pixels + 1, 0);
                offsets[0] = 0;
                let n = total as usize;
                depth.resize(n, 0.0);
                color.resize(n, Rgba8::default());
                object.resize(n, ObjectId::default());
                (offsets, depth, color, object)
            }
            None => {
                let (depth, color, object) = columns(total as usize);
                (vec![0u32; pixels + 1], depth, color, object)
            }
        };
        // Each run's offsets and columns go to the disjoint slices its pixels own.
        let offset_slices = split_lens(
            &mut offsets[1..],
            bands.iter().map(|g| g.borrow().counts.len()),
        );
        let lens = bands.iter().map(|g| g.borrow().depth.len());
        let slices = split_columns((&mut depth, &mut color, &mut object), lens);
        // Owned runs are consumed, so each one's columns are freed as soon as they are in place.
        let places: Vec<_> = bands
            .into_iter()
            .zip(bases)
            .zip(offset_slices.into_iter().zip(slices))
            .collect();
        places
            .into_par_iter()
            .for_each(|((g, base), (offsets, (d, c, o)))| {
                let g = g.borrow();
                let mut end = base;
                for (o, &n) in offsets.iter_mut().zip(&g.counts) {
                    end += n;
                    *o = end;
                }
                d.copy_from_slice(&g.depth);
                c.copy_from_slice(&g.color);
                o.copy_from_slice(&g.object);
            });
        Ok(DeepFrame {
            width,
            height,
            offsets,
            depth,
            color,
            object,
        })
    }

    /// Builds a frame from one fragment list per pixel (row-major), sorting each. For tests and
    /// small tools; stores use [`DeepFrame::build`].
    pub fn from_pixel_lists(
        width: u32,
        height: u32,
        lists: &[Vec<Fragment>],
    ) -> Result<Self, DeepFrameError> {
        let counts: Vec<u32> = lists
            .iter()
            .map(|l| {
                u32::try_from(l.len()).map_err(|_| DeepFrameError::TooManyFragments(l.len() as u64))
            })
            .collect::<Result<_, _>>()?;
        Self::build(width, height, &counts, |p, out| {
            out.extend_from_slice(&lists[p])
        })
    }

    /// Assembles a frame from its raw parts (for decoders), checking every invariant.
    pub fn from_parts(
        width: u32,
        height: u32,
        offsets: Vec<u32>,
        depth: Vec<f32>,
        color: Vec<Rgba8>,
        object: Vec<ObjectId>,
    ) -> Result<Self, DeepFrameError> {
        let pixels = offsets_shape(width, height, &offsets)?;
        if depth.len() != color.len() || depth.len() != object.len() {
            return Err(DeepFrameError::ColumnLengths {
                depth: depth.len(),
                color: color.len(),
                object: object.len(),
            });
        }
        // Every check below runs over chunks in parallel, without a branch per item inside a
        // chunk (decoders call this on every frame they receive); a chunk that fails is
        // searched again for the first offender, so the error names the same item as a
        // serial scan would.
        if let Some(p) = first_failing(offsets.len().saturating_sub(1), CHECK_CHUNK, |r| {
            offsets_rise(&offsets, r)
        }) {
            return Err(DeepFrameError::BadOffsets { pixel: p });
        }
        if offsets[pixels] as usize != depth.len() {
            return Err(DeepFrameError::BadOffsets { pixel: pixels });
        }
        if let Some(index) = first_failing(depth.len(), CHECK_CHUNK, |r| depths_valid(&depth[r])) {
            return Err(DeepFrameError::BadDepth {
                index,
                depth: depth[index],
            });
        }
        let columns = (&depth[..], &color[..], &object[..]);
        if let Some(pixel) = first_failing(pixels, CHECK_CHUNK, |r| {
            runs_sorted(&offsets, 0, columns, r)
        }) {
            return Err(DeepFrameError::Unsorted { pixel });
        }
        let frame = DeepFrame {
            width,
            height,
            offsets,
            depth,
            color,
            object,
        };
        Ok(frame)
    }

    /// Builds a frame band by band in parallel, for decoders that write every fragment
    /// themselves: `fill(i, band)` writes the fragments of the pixels `bands[i]` into `band`'s
    /// column slices, and each band is checked right after its fill, while it is still in the
    /// cache, against the invariants [`DeepFrame::from_parts`] checks in separate passes over
    /// the whole frame afterwards. Errors name the same item as `from_parts` would.
    ///
    /// `offsets` are the frame's run offsets (`w·h + 1`, checked here: a band whose offsets
    /// decrease is not filled); `columns` are allocations to reuse (any lengths: they are
    /// resized to `offsets[w·h]` fragments, which zeroes only what they grow by). That total
    /// is allocated as given, so a caller decoding untrusted input bounds it first (the wire
    /// decoders check the counts against the header's fragment count and its limit). A band's
    /// fill sees the frame's offsets and its own fragments, indexed from its first pixel's
    /// offset.
    ///
    /// # Panics
    /// If `bands` are not consecutive ranges covering the pixels `0..w·h` in order.
    pub fn fill_bands<F>(
        width: u32,
        height: u32,
        offsets: Vec<u32>,
        bands: &[std::ops::Range<usize>],
        columns: (Vec<f32>, Vec<Rgba8>, Vec<ObjectId>),
        fill: F,
    ) -> Result<Self, DeepFrameError>
    where
        F: Fn(usize, FillBand<'_>) + Sync,
    {
        let pixels = pixel_count(width, height);
        let mut next = 0;
        for b in bands {
            assert!(
                b.start == next && b.end >= b.start,
                "bands must tile the pixels in order"
            );
            next = b.end;
        }
        assert_eq!(next, pixels, "bands must cover every pixel");
        offsets_shape(width, height, &offsets)?;
        // The bands' slices need rising offsets at the band ends; when they do not, some pixel
        // inside fails, and the whole-frame check names the first.
        if bands.iter().any(|b| offsets[b.start] > offsets[b.end]) {
            let first = first_failing(pixels, CHECK_CHUNK, |r| offsets_rise(&offsets, r));
            return Err(DeepFrameError::BadOffsets {
                pixel: first.unwrap_or(0),
            });
        }
        let n = offsets[pixels] as usize;
        let (mut depth, mut color, mut object) = columns;
        depth.resize(n, 0.0);
        color.resize(n, Rgba8::default());
        object.resize(n, ObjectId::default());
        /// What a band's check found first. The derived order is from_parts' order of checks
        /// (offsets, then depths, then runs), and within a kind the first item.
        #[derive(PartialEq, Eq, PartialOrd, Ord)]
        enum Failure {
            Offsets(usize),
            Depth(usize),
            Unsorted(usize),
        }
        let lens = bands
            .iter()
            .map(|b| (offsets[b.end] - offsets[b.start]) as usize);
        let slices = split_columns((&mut depth, &mut color, &mut object), lens);
        let offsets_ref = &offsets[..];
        let first_failure = slices
            .into_par_iter()
            .zip(bands.par_iter())
            .enumerate()
            .with_max_len(1)
            .filter_map(|(i, ((d, c, o), band))| {
                if let Some(p) =
                    first_failing_in(band.clone(), CHECK_CHUNK, |r| offsets_rise(offsets_ref, r))
                {
                    return Some(Failure::Offsets(p));
                }
                fill(
                    i,
                    FillBand {
                        pixels: band.clone(),
                        offsets: offsets_ref,
                        depth: &mut *d,
                        color: &mut *c,
                        object: &mut *o,
                    },
                );
                let base = offsets_ref[band.start] as usize;
                if let Some(k) = first_failing_in(0..d.len(), CHECK_CHUNK, |r| depths_valid(&d[r]))
                {
                    return Some(Failure::Depth(base + k));
                }
                let columns = (&d[..], &c[..], &o[..]);
                first_failing_in(band.clone(), CHECK_CHUNK, |r| {
                    runs_sorted(offsets_ref, base, columns, r)
                })
                .map(Failure::Unsorted)
            })
            .min();
        match first_failure {
            Some(Failure::Offsets(pixel)) => Err(DeepFrameError::BadOffsets { pixel }),
            Some(Failure::Depth(index)) => Err(DeepFrameError::BadDepth {
                index,
                depth: depth[index],
            }),
            Some(Failure::Unsorted(pixel)) => Err(DeepFrameError::Unsorted { pixel }),
            None => Ok(DeepFrame {
                width,
                height,
                offsets,
                depth,
                color,
                object,
            }),
        }
    }

    /// Makes room for `fragments` more fragments and `pixels` more pixels, so that appending
    /// bands ([`DeepFrame::append_rows`]) up to that size does not move the columns.
    pub fn reserve(&mut self, fragments: usize, pixels: usize) {
        self.offsets.reserve(pixels);
        self.depth.reserve(fragments);
        self.color.reserve(fragments);
        self.object.reserve(fragments);
    }

    /// Appends `band`'s rows below this frame's (a frame exported in bands of rows, assembled
    /// band by band): offsets are shifted by the fragments already held and the columns extended,
    /// so the result equals the frame exported in one piece, and no run is sorted or checked
    /// again (`band` holds the invariants already). Start from [`DeepFrame::empty`]`(width, 0)`.
    ///
    /// # Errors
    /// `band` has another width, or the frame would hold more fragments than a `u32` offset
    /// addresses; the frame is unchanged then.
    pub fn append_rows(&mut self, band: &DeepFrame) -> Result<(), DeepFrameError> {
        if band.width != self.width {
            return Err(DeepFrameError::WidthMismatch {
                width: self.width,
                found: band.width,
            });
        }
        let base = self.depth.len() as u64;
        let total = base + band.depth.len() as u64;
        let base = u32::try_from(base).map_err(|_| DeepFrameError::TooManyFragments(total))?;
        u32::try_from(total).map_err(|_| DeepFrameError::TooManyFragments(total))?;
        let height = self
            .height
            .checked_add(band.height)
            .ok_or(DeepFrameError::PixelCount {
                width: self.width,
                height: self.height,
                expected: u64::from(self.height) + u64::from(band.height),
                found: u64::from(u32::MAX),
            })?;
        self.offsets
            .extend(band.offsets[1..].iter().map(|&o| base + o));
        self.depth.extend_from_slice(&band.depth);
        self.color.extend_from_slice(&band.color);
        self.object.extend_from_slice(&band.object);
        self.height = height;
        Ok(())
    }

    /// Width in pixels.
    #[inline]
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    #[inline]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Total fragments.
    #[inline]
    pub fn fragment_count(&self) -> usize {
        self.depth.len()
    }

    /// The prefix-summed offsets, `w*h + 1` entries.
    #[inline]
    pub fn offsets(&self) -> &[u32] {
        &self.offsets
    }

    /// The depth column.
    #[inline]
    pub fn depths(&self) -> &[f32] {
        &self.depth
    }

    /// The colour column.
    #[inline]
    pub fn colors(&self) -> &[Rgba8] {
        &self.color
    }

    /// The object-id column.
    #[inline]
    pub fn objects(&self) -> &[ObjectId] {
        &self.object
    }

    /// The run of row-major pixel `p`.
    ///
    /// # Panics
    /// If `p >= width * height`.
    #[inline]
    pub fn run(&self, p: usize) -> Run<'_> {
        let (a, b) = (self.offsets[p] as usize, self.offsets[p + 1] as usize);
        Run {
            depth: &self.depth[a..b],
            color: &self.color[a..b],
            object: &self.object[a..b],
        }
    }

    /// The run of pixel `(x, y)`, row 0 at the top.
    ///
    /// # Panics
    /// If `(x, y)` is outside the frame.
    pub fn pixel(&self, x: u32, y: u32) -> Run<'_> {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside the frame"
        );
        self.run(y as usize * self.width as usize + x as usize)
    }

    /// Number of fragments in each pixel, row-major.
    pub fn counts(&self) -> impl ExactSizeIterator<Item = u32> + '_ {
        self.offsets.windows(2).map(|w| w[1] - w[0])
    }

    /// Depth-complexity statistics.
    pub fn depth_stats(&self) -> DepthStats {
        DepthStats::from_counts(self.counts())
    }

    /// Bytes held: offsets plus 12 bytes per fragment (depth, colour, object id).
    pub fn memory_bytes(&self) -> u64 {
        (self.offsets.len() * 4 + self.depth.len() * 12) as u64
    }

    /// Composites every run front to back onto `background` (strata's shared conventions resolve).
    pub fn resolve(&self, background: [f32; 3]) -> Rgb8Image {
        let mut image = Rgb8Image::filled(self.width, self.height, [0; 3]);
        self.resolve_into(background, &mut image);
        image
    }

    /// [`DeepFrame::resolve`] into an image of the frame's size that the caller keeps from frame
    /// to frame (no fresh pages). In parallel over chunks of pixels; each chunk walks its
    /// offsets once, so a pixel costs its run's slice and its composite, nothing more.
    ///
    /// # Panics
    /// If `image` is not the frame's size.
    pub fn resolve_into(&self, background: [f32; 3], image: &mut Rgb8Image) {
        assert!(
            image.width() == self.width && image.height() == self.height,
            "a {}x{} frame resolves into an image of its size",
            self.width,
            self.height
        );
        let bg = composite::background_pixel(background);
        image
            .as_bytes_mut()
            .par_chunks_mut(PIXELS_PER_TASK * 3)
            .enumerate()
            .for_each(|(chunk, out)| {
                let p0 = chunk * PIXELS_PER_TASK;
                let offsets = &self.offsets[p0..=p0 + out.len() / 3];
                for (w, px) in offsets.windows(2).zip(out.chunks_exact_mut(3)) {
                    let (a, b) = (w[0] as usize, w[1] as usize);
                    let rgb = if a == b {
                        bg
                    } else {
                        composite::resolve_pixel(self.color[a..b].iter().copied(), background)
                    };
                    px.copy_from_slice(&rgb);
                }
            });
    }

    /// Keeps only the prefix of each run that `limit` keeps ([`RunLimit`]), in place: the
    /// columns keep their allocations, and nothing is sorted or checked again (a prefix of a
    /// sorted run is sorted). A frame that `limit` does not cut is returned as it is.
    pub fn limit_runs(mut self, limit: RunLimit) -> DeepFrame {
        if limit.is_none() {
            return self;
        }
        let mut kept = 0usize;
        for p in 0..self.offsets.len() - 1 {
            let (start, end) = (self.offsets[p] as usize, self.offsets[p + 1] as usize);
            let colors = &self.color[start..end];
            let keep = limit.keep(end - start, |i| colors[i].0[3]);
            // `kept <= start`: the runs only move towards the front.
            if kept != start {
                self.depth.copy_within(start..start + keep, kept);
                self.color.copy_within(start..start + keep, kept);
                self.object.copy_within(start..start + keep, kept);
            }
            self.offsets[p] = kept as u32;
            kept += keep;
        }
        *self.offsets.last_mut().expect("w·h + 1 offsets") = kept as u32;
        self.depth.truncate(kept);
        self.color.truncate(kept);
        self.object.truncate(kept);
        self
    }

    /// Takes the frame apart: `(width, height, offsets, depth, color, object)`.
    #[allow(
        clippy::type_complexity,
        reason = "the parts are documented by from_parts"
    )]
    pub fn into_parts(self) -> (u32, u32, Vec<u32>, Vec<f32>, Vec<Rgba8>, Vec<ObjectId>) {
        (
            self.width,
            self.height,
            self.offsets,
            self.depth,
            self.color,
            self.object,
        )
    }
}

/// Items per parallel chunk of [`DeepFrame::from_parts`]' checks.
const CHECK_CHUNK: usize = 16 * 1024;

/// The first `i < len` that fails, where `ok(range)` says whether every item of `range` passes:
/// chunks of `chunk` items are checked in parallel, and the first failing chunk item by item.
fn first_failing(
    len: usize,
    chunk: usize,
    ok: impl Fn(std::ops::Range<usize>) -> bool + Sync,
) -> Option<usize> {
    let failing = (0..len.div_ceil(chunk))
        .into_par_iter()
        .find_first(|&c| !ok(c * chunk..((c + 1) * chunk).min(len)))?;
    (failing * chunk..((failing + 1) * chunk).min(len)).find(|&i| !ok(i..i + 1))
}

/// The pixel count of a `width` × `height` frame, once `offsets` has one entry a pixel and one
/// more, starting at 0: the shape [`DeepFrame::from_parts`] and [`DeepFrame::fill_bands`] check
/// before anything else.
fn offsets_shape(width: u32, height: u32, offsets: &[u32]) -> Result<usize, DeepFrameError> {
    let pixels = pixel_count(width, height);
    if offsets.len() != pixels + 1 {
        return Err(DeepFrameError::PixelCount {
            width,
            height,
            expected: pixels as u64 + 1,
            found: offsets.len() as u64,
        });
    }
    if offsets[0] != 0 {
        return Err(DeepFrameError::BadOffsets { pixel: 0 });
    }
    Ok(pixels)
}

/// [`first_failing`] over `range`, serially (inside a task that is parallel already).
fn first_failing_in(
    range: std::ops::Range<usize>,
    chunk: usize,
    ok: impl Fn(std::ops::Range<usize>) -> bool,
) -> Option<usize> {
    let mut at = range.start;
    while at < range.end {
        let end = (at + chunk).min(range.end);
        if !ok(at..end) {
            return (at..end).find(|&i| !ok(i..i + 1));
        }
        at = end;
    }
    None
}

/// Whether the offsets of the pixels `r` never decrease: `offsets[p] <= offsets[p + 1]` for
/// every `p` in `r`. No branch per pixel.
#[inline]
fn offsets_rise(offsets: &[u32], r: std::ops::Range<usize>) -> bool {
    offsets[r.start..r.end + 1]
        .windows(2)
        .fold(true, |ok, w| ok & (w[0] <= w[1]))
}

/// Whether every depth is valid: a non-negative float at most 1 and not −0, exactly the bit
/// patterns up to 1.0's (negative numbers, −0 and NaNs all have larger ones). No branch per
/// depth.
#[inline]
fn depths_valid(depth: &[f32]) -> bool {
    depth.iter().fold(0, |m, d| m.max(d.to_bits())) <= 1.0f32.to_bits()
}

/// Whether the runs of the pixels `r` are sorted: each fragment's order key (depth bits, then
/// object, then colour) is at least its predecessor's. `columns` hold the fragments from
/// `base` on (`offsets` are the frame's); the offsets of `r` must rise and lie in them.
///
/// Pixels are taken eight at a time, and a block whose pixels all hold at most one fragment
/// (empty space, single surfaces) is passed over after one vectorised test of its counts:
/// without that, a sparse frame spent most of the check stepping through empty pixels.
#[inline]
fn runs_sorted(
    offsets: &[u32],
    base: usize,
    (depth, color, object): (&[f32], &[Rgba8], &[ObjectId]),
    r: std::ops::Range<usize>,
) -> bool {
    const BLOCK: usize = 8;
    let offsets = &offsets[r.start..r.end + 1];
    let mut ok = true;
    let mut runs = |o: &[u32]| {
        for w in o.windows(2) {
            let (a, b) = (w[0] as usize - base, w[1] as usize - base);
            if b > a + 1 {
                // One bounds check a run, none a fragment.
                let (d, o, c) = (&depth[a..b], &object[a..b], &color[a..b]);
                let key = |k: usize| {
                    (
                        (u64::from(d[k].to_bits()) << 32) | u64::from(o[k].0),
                        c[k].to_bits(),
                    )
                };
                for k in 1..d.len() {
                    ok &= key(k - 1) <= key(k);
                }
            }
        }
    };
    let blocks = (offsets.len() - 1) / BLOCK;
    for i in 0..blocks {
        // The block's nine offsets bound its eight runs.
        let o = &offsets[i * BLOCK..i * BLOCK + BLOCK + 1];
        let deep = (0..BLOCK).fold(false, |m, k| m | (o[k + 1].wrapping_sub(o[k]) > 1));
        if deep {
            runs(o);
        }
    }
    runs(&offsets[blocks * BLOCK..]);
    ok
}

/// The fragments of a run of consecutive pixels, sorted front to back, column by column: what
/// one task of [`DeepFrame::gather`] collects, or one strip of a store that exports each strip
/// as it is captured; [`DeepFrame::from_gathered`] assembles runs into a frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GatheredPixels {
    counts: Vec<u32>,
    depth: Vec<f32>,
    color: Vec<Rgba8>,
    object: Vec<ObjectId>,
}

impl GatheredPixels {
    /// Gathers the row-major frame pixels `pixels`: `fill(p, out)` pushes pixel `p`'s fragments
    /// into the empty `out` (`scratch`, reused), in any order; each run is checked and sorted as
    /// [`DeepFrame::build`] does (−0 depths become +0; a depth outside `[0, 1]` or NaN is an
    /// error naming its pixel).
    pub fn gather(
        pixels: std::ops::Range<usize>,
        scratch: &mut Vec<Fragment>,
        mut fill: impl FnMut(usize, &mut Vec<Fragment>),
    ) -> Result<Self, DeepFrameError> {
        // Room for a fragment a pixel; only denser runs grow.
        let mut w = GatherWriter::new(pixels.len(), pixels.len());
        for p in pixels {
            scratch.clear();
            fill(p, scratch);
            w.push_run(p, scratch)?;
        }
        Ok(w.finish())
    }

    /// Pixels gathered.
    pub fn pixels(&self) -> usize {
        self.counts.len()
    }
}

/// Fills a [`GatheredPixels`] run by run, pixel after pixel: a store that knows how many
/// fragments it holds sizes the columns with it, so they never grow while it gathers.
#[derive(Debug)]
pub struct GatherWriter {
    gathered: GatheredPixels,
    limit: RunLimit,
}

impl GatherWriter {
    /// Room for `pixels` pixels and `fragments` fragments (more still fit; the columns then
    /// grow).
    pub fn new(pixels: usize, fragments: usize) -> Self {
        GatherWriter {
            gathered: GatheredPixels {
                counts: Vec::with_capacity(pixels),
                depth: Vec::with_capacity(fragments),
                color: Vec::with_capacity(fragments),
                object: Vec::with_capacity(fragments),
            },
            limit: RunLimit::NONE,
        }
    }

    /// A writer into `gathered`'s buffers, emptied: a caller that gathers frame after frame
    /// keeps its columns' memory.
    pub fn reusing(mut gathered: GatheredPixels) -> Self {
        gathered.counts.clear();
        gathered.depth.clear();
        gathered.color.clear();
        gathered.object.clear();
        GatherWriter {
            gathered,
            limit: RunLimit::NONE,
        }
    }

    /// Room for `pixels` more pixels and `fragments` more fragments, so that the columns do
    /// not grow while they are filled (a writer made [`GatherWriter::reusing`] a buffer that
    /// is already large enough allocates nothing).
    pub fn reserve(&mut self, pixels: usize, fragments: usize) {
        let g = &mut self.gathered;
        g.counts.reserve(pixels);
        g.depth.reserve(fragments);
        g.color.reserve(fragments);
        g.object.reserve(fragments);
    }

    /// Keeps only the prefix of each sorted run that `limit` keeps (a render node's
    /// depth-limited export, [`RunLimit`]); every fragment of the run is still checked.
    pub fn with_limit(mut self, limit: RunLimit) -> Self {
        self.limit = limit;
        self
    }

    /// Appends `n` pixels without fragments.
    #[inline]
    pub fn push_empty(&mut self, n: usize) {
        let counts = &mut self.gathered.counts;
        counts.resize(counts.len() + n, 0);
    }

    /// Appends the frame pixel `pixel`'s fragments `run`, in any order: checked and sorted as
    /// [`DeepFrame::build`] does (−0 depths become +0; a depth outside `[0, 1]` or NaN is an
    /// error naming `pixel`), then cut to the writer's limit.
    #[inline(always)]
    pub fn push_run(&mut self, pixel: usize, run: &mut [Fragment]) -> Result<(), DeepFrameError> {
        check_and_sort(run, pixel)?;
        let run = &run[..self.limit.keep(run.len(), |i| run[i].color.0[3])];
        let n = u32::try_from(run.len())
            .map_err(|_| DeepFrameError::TooManyFragments(run.len() as u64))?;
        let g = &mut self.gathered;
        g.counts.push(n);
        for f in run.iter() {
            g.depth.push(f.depth);
            g.color.push(f.color);
            g.object.push(f.object);
        }
        Ok(())
    }

    /// Appends pixel `pixel` of `frame` with only the fragments at positions `keep` of its run
    /// (ascending; positions past the run are ignored): what [`GatherWriter::push_run`]
    /// appends for those fragments, cut to the writer's limit, without checking or sorting
    /// them again. A frame's depths are valid and its runs sorted, and a subsequence of a
    /// sorted run is sorted. A reprojection node sends some of the fragments it rendered at a
    /// pixel this way.
    ///
    /// # Panics
    /// If `pixel` is not a pixel of `frame`, or `keep` is not ascending (the run would not be
    /// sorted).
    #[inline]
    pub fn push_from_frame(&mut self, frame: &DeepFrame, pixel: usize, keep: &[u32]) {
        assert!(keep.is_sorted(), "positions to keep must be ascending");
        let run = frame.offsets[pixel] as usize..frame.offsets[pixel + 1] as usize;
        let (depth, color, object) = (
            &frame.depth[run.clone()],
            &frame.color[run.clone()],
            &frame.object[run.clone()],
        );
        // Ascending, so the positions in the run are a prefix of `keep`.
        let keep = &keep[..keep.partition_point(|&k| (k as usize) < run.len())];
        let keep = &keep[..self
            .limit
            .keep(keep.len(), |i| color[keep[i] as usize].0[3])];
        let g = &mut self.gathered;
        // At most the run's length, which fits a `u32` as the frame's offsets do.
        g.counts.push(keep.len() as u32);
        for &k in keep {
            let k = k as usize;
            g.depth.push(depth[k]);
            g.color.push(color[k]);
            g.object.push(object[k]);
        }
    }

    /// The pixels and fragments pushed.
    pub fn finish(self) -> GatheredPixels {
        self.gathered
    }
}

fn valid_depth(d: f32) -> bool {
    (0.0..=1.0).contains(&d) && !(d == 0.0 && d.is_sign_negative())
}

/// The offsets of runs of `counts` fragments (`pixels` of them): `[0, c0, c0 + c1, …]`, refusing
/// a total beyond `u32`.
fn offsets_of(
    counts: impl Iterator<Item = u32>,
    pixels: usize,
) -> Result<Vec<u32>, DeepFrameError> {
    let mut offsets = Vec::with_capacity(pixels + 1);
    let mut total: u64 = 0;
    offsets.push(0u32);
    for c in counts {
        total += u64::from(c);
        let t = u32::try_from(total).map_err(|_| DeepFrameError::TooManyFragments(total))?;
        offsets.push(t);
    }
    Ok(offsets)
}

/// The three columns of `n` fragments, zeroed.
fn columns(n: usize) -> (Vec<f32>, Vec<Rgba8>, Vec<ObjectId>) {
    (
        vec![0f32; n],
        vec![Rgba8::default(); n],
        vec![ObjectId::default(); n],
    )
}

/// Cuts `buf` into consecutive disjoint pieces of `lens` items each.
fn split_lens<T>(buf: &mut [T], lens: impl Iterator<Item = usize>) -> Vec<&mut [T]> {
    let mut rest = buf;
    lens.map(|len| {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(len);
        rest = tail;
        head
    })
    .collect()
}

/// Mutable column slices to fill in parallel: consecutive pieces of `lens` fragments each.
type ColumnSlices<'a> = (&'a mut [f32], &'a mut [Rgba8], &'a mut [ObjectId]);

/// Cuts the columns into consecutive disjoint pieces of `lens` fragments.
fn split_columns<'a>(
    (depth, color, object): (&'a mut [f32], &'a mut [Rgba8], &'a mut [ObjectId]),
    lens: impl Iterator<Item = usize>,
) -> Vec<ColumnSlices<'a>> {
    let (mut d, mut c, mut o) = (depth, color, object);
    lens.map(|len| {
        let (dh, dt) = std::mem::take(&mut d).split_at_mut(len);
        let (ch, ct) = std::mem::take(&mut c).split_at_mut(len);
        let (oh, ot) = std::mem::take(&mut o).split_at_mut(len);
        (d, c, o) = (dt, ct, ot);
        (dh, ch, oh)
    })
    .collect()
}

/// Checks and sorts the run of frame pixel `pixel` as every frame builder does: −0 depths become
/// +0, a depth outside `[0, 1]` or NaN is an error naming `pixel`, and the run is sorted front to
/// back. (−0 + 0 is +0 and every other depth, NaN included, stays what it was, so the depths are
/// normalised and checked with one branch for the run.)
#[inline(always)]
fn check_and_sort(run: &mut [Fragment], pixel: usize) -> Result<(), DeepFrameError> {
    let mut valid = true;
    for f in run.iter_mut() {
        f.depth += 0.0;
        valid &= (0.0..=1.0).contains(&f.depth);
    }
    if !valid {
        let bad = run
            .iter()
            .find(|f| !valid_depth(f.depth))
            .map_or(0.0, |f| f.depth);
        return Err(DeepFrameError::BadDepth {
            index: pixel,
            depth: bad,
        });
    }
    sort_front_to_back(run);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gather_equals_build_across_tasks_and_refuses_what_build_refuses() {
        // More pixels than one task holds, unsorted runs, empty pixels, -0.0 depths.
        let (w, h) = (150u32, 120u32);
        let lists: Vec<Vec<Fragment>> = (0..(w * h) as usize)
            .map(|p| {
                (0..(p * 7 + p / 13) % 5)
                    .map(|k| Fragment {
                        depth: if k == 0 && p % 3 == 0 {
                            -0.0
                        } else {
                            ((p * 31 + k * 17) % 97) as f32 / 97.0
                        },
                        color: Rgba8([k as u8, p as u8, (p >> 8) as u8, 200]),
                        object: ObjectId((p % 4) as u32),
                    })
                    .collect()
            })
            .collect();
        let built = DeepFrame::from_pixel_lists(w, h, &lists).unwrap();
        let gathered = DeepFrame::gather(w, h, |p, out| out.extend_from_slice(&lists[p])).unwrap();
        assert_eq!(gathered, built);
        assert!(gathered.fragment_count() > 20_000);
        let nan = DeepFrame::gather(w, h, |p, out| {
            out.extend_from_slice(&lists[p]);
            if p == 12_345 {
                out.push(Fragment {
                    depth: f32::NAN,
                    ..lists[1][0]
                });
            }
        });
        assert!(
            matches!(nan, Err(DeepFrameError::BadDepth { index: 12_345, .. })),
            "{nan:?}"
        );

        // Runs of any lengths, as a store's strips gather them, assemble to the same frame; runs
        // that miss or add a pixel are refused.
        let mut scratch = Vec::new();
        let mut runs = |cuts: &[usize]| -> Vec<GatheredPixels> {
            cuts.windows(2)
                .map(|c| {
                    GatheredPixels::gather(c[0]..c[1], &mut scratch, |p, out| {
                        // Past the frame's last pixel: an empty pixel too many.
                        if let Some(list) = lists.get(p) {
                            out.extend_from_slice(list);
                        }
                    })
                    .unwrap()
                })
                .collect()
        };
        let n = (w * h) as usize;
        let strips = runs(&[0, 0, 1, 4_800, 9_000, n]);
        assert_eq!(strips.iter().map(GatheredPixels::pixels).sum::<usize>(), n);
        assert_eq!(DeepFrame::from_gathered(w, h, strips).unwrap(), built);
        // In the buffers of a frame no longer needed, larger (every entry overwritten) or
        // smaller (grown) than the new one, or of another size: the same frame.
        let larger = DeepFrame::gather(w, h, |p, out| {
            out.extend_from_slice(&lists[p]);
            out.extend_from_slice(&lists[p]);
        })
        .unwrap();
        let smaller =
            DeepFrame::gather(w, h / 2, |p, out| out.extend_from_slice(&lists[p])).unwrap();
        assert!(larger.fragment_count() > built.fragment_count());
        let taller = DeepFrame::gather(w, 2 * h, |p, out| {
            out.extend_from_slice(&lists[p % lists.len()]);
        })
        .unwrap();
        let mut lent = 0;
        for old in [larger, taller, smaller, DeepFrame::empty(3, 2)] {
            // An old frame at least as large in every buffer lends them as they are.
            let roomy = old.offsets().len() > built.offsets().len()
                && old.fragment_count() >= built.fragment_count();
            let pointers = (old.offsets().as_ptr(), old.depths().as_ptr());
            let strips = runs(&[0, 4_800, 9_000, n]);
            let reused = DeepFrame::from_gathered_reusing(w, h, strips, Some(old)).unwrap();
            assert_eq!(reused, built);
            if roomy {
                assert_eq!(
                    (reused.offsets().as_ptr(), reused.depths().as_ptr()),
                    pointers
                );
                lent += 1;
            }
        }
        assert_eq!(lent, 1, "the taller frame lends its buffers");
        // Borrowed runs, gathered again into their own buffers (as a caller that keeps its runs
        // from frame to frame does), each pixel's run reversed so that nothing of the first
        // gather survives by chance: the same frame.
        let mut kept = runs(&[0, 4_800, 9_000, n]);
        for (i, g) in kept.iter_mut().enumerate() {
            let first = [0, 4_800, 9_000, n][i];
            let last = [0, 4_800, 9_000, n][i + 1];
            let mut writer = GatherWriter::reusing(std::mem::take(g));
            for (p, list) in lists.iter().enumerate().take(last).skip(first) {
                let mut run: Vec<Fragment> = list.iter().rev().copied().collect();
                writer.push_run(p, &mut run).unwrap();
            }
            *g = writer.finish();
        }
        let borrowed: Vec<&GatheredPixels> = kept.iter().collect();
        assert_eq!(
            DeepFrame::from_gathered_reusing(w, h, borrowed, None).unwrap(),
            built
        );
        for cuts in [&[0, 4_800, n - 1][..], &[0, n, n + 1]] {
            let short = DeepFrame::from_gathered(w, h, runs(cuts));
            assert!(
                matches!(short, Err(DeepFrameError::PixelCount { .. })),
                "{cuts:?}: {short:?}"
            );
        }
    }

    fn frag(depth: f32, rgba: [u8; 4], object: u32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8(rgba),
            object: ObjectId(object),
        }
    }

    fn sample() -> Vec<Vec<Fragment>> {
        vec![
            vec![],
            vec![
                frag(0.7, [0, 0, 255, 128], 1),
                frag(0.3, [255, 0, 0, 128], 0),
            ],
            vec![frag(0.5, [0, 255, 0, 255], 2)],
            vec![
                frag(0.9, [1, 1, 1, 1], 0),
                frag(0.1, [2, 2, 2, 2], 0),
                frag(0.5, [3, 3, 3, 3], 0),
            ],
        ]
    }

    #[test]
    fn pushing_some_of_a_frames_run_equals_pushing_those_fragments_as_a_run() {
        // Runs of up to five fragments, with ties in depth between objects and colours.
        let mut lists = sample();
        lists.push(vec![
            frag(0.4, [9, 9, 9, 200], 1),
            frag(0.4, [9, 9, 9, 200], 0),
            frag(0.4, [8, 9, 9, 60], 0),
            frag(0.2, [7, 7, 7, 255], 3),
            frag(0.8, [6, 6, 6, 100], 2),
        ]);
        lists.push(vec![frag(1.0, [5, 5, 5, 5], 0), frag(0.0, [4, 4, 4, 4], 0)]);
        let frame = DeepFrame::from_pixel_lists(3, 2, &lists).unwrap();
        for limit in [
            RunLimit::NONE,
            RunLimit::new(2, None),
            RunLimit::new(4, Some(0.7)),
        ] {
            for p in 0..6 {
                let run = frame.run(p);
                let n = run.len() as u32;
                // Every subset of the run's positions, ascending, and positions past it.
                for subset in 0..1u32 << n {
                    let mut keep: Vec<u32> = (0..n).filter(|k| subset >> k & 1 == 1).collect();
                    keep.extend([n, n + 2]);
                    let mut direct = GatherWriter::new(1, 8).with_limit(limit);
                    direct.push_from_frame(&frame, p, &keep);
                    let mut chosen: Vec<Fragment> =
                        keep.iter().filter_map(|&k| run.get(k as usize)).collect();
                    let mut checked = GatherWriter::new(1, 8).with_limit(limit);
                    checked.push_run(p, &mut chosen).unwrap();
                    assert_eq!(
                        direct.finish(),
                        checked.finish(),
                        "pixel {p}, {keep:?}, {limit:?}"
                    );
                }
            }
        }
        // Positions out of order would make a run out of order: refused.
        let out_of_order = std::panic::catch_unwind(|| {
            GatherWriter::new(1, 8).push_from_frame(&frame, 4, &[2, 0]);
        });
        assert!(out_of_order.is_err());
    }

    #[test]
    fn limited_runs_are_the_sorted_prefixes_the_limit_keeps() {
        let lists = sample();
        let frame = DeepFrame::from_pixel_lists(2, 2, &lists).unwrap();
        assert_eq!(frame.clone().limit_runs(RunLimit::NONE), frame);
        for limit in [
            RunLimit::new(1, None),
            RunLimit::new(2, None),
            RunLimit::new(5, None),
            RunLimit::new(3, Some(0.6)),
            RunLimit::new(3, Some(1.0)),
            RunLimit::new(0, None),
        ] {
            // Each pixel's list sorted, then cut by the rule, then built again.
            let want: Vec<Vec<Fragment>> = lists
                .iter()
                .map(|l| {
                    let mut l = l.clone();
                    sort_front_to_back(&mut l);
                    let keep = limit.keep(l.len(), |i| l[i].color.0[3]);
                    l[..keep].to_vec()
                })
                .collect();
            let want = DeepFrame::from_pixel_lists(2, 2, &want).unwrap();
            assert_eq!(frame.clone().limit_runs(limit), want, "{limit:?}");
        }
        // The opacity threshold: pixel 1 is two fragments of alpha 128 (≈ 0.50, then 0.75).
        let cut = frame.clone().limit_runs(RunLimit::new(3, Some(0.6)));
        assert_eq!(cut.counts().collect::<Vec<_>>(), [0, 2, 1, 3]);
        let cut = frame.limit_runs(RunLimit::new(3, Some(0.4)));
        assert_eq!(cut.counts().collect::<Vec<_>>(), [0, 1, 1, 3]);
    }

    #[test]
    fn frames_assembled_from_bands_of_rows_equal_the_whole() {
        // A 2×3 frame: sample() and two more pixels.
        let mut lists = sample();
        lists.push(vec![frag(0.2, [9, 9, 9, 9], 4)]);
        lists.push(vec![]);
        let whole = DeepFrame::from_pixel_lists(2, 3, &lists).unwrap();
        for cuts in [
            vec![0, 3],
            vec![0, 1, 3],
            vec![0, 2, 3],
            vec![0, 1, 2, 3],
            vec![0, 0, 3],
        ] {
            let mut assembled = DeepFrame::empty(2, 0);
            for w in cuts.windows(2) {
                let rows = &lists[w[0] * 2..w[1] * 2];
                let band = DeepFrame::from_pixel_lists(2, (w[1] - w[0]) as u32, rows).unwrap();
                assembled.append_rows(&band).unwrap();
            }
            assert_eq!(assembled, whole, "{cuts:?}");
            assert_eq!(assembled.resolve([1.0; 3]), whole.resolve([1.0; 3]));
        }
        let mut reserved = DeepFrame::empty(2, 0);
        reserved.reserve(whole.fragment_count(), 6);
        for y in 0..3 {
            let band = DeepFrame::from_pixel_lists(2, 1, &lists[y * 2..y * 2 + 2]).unwrap();
            reserved.append_rows(&band).unwrap();
        }
        assert_eq!(reserved, whole);
        let mut narrow = DeepFrame::empty(2, 0);
        let e = narrow.append_rows(&DeepFrame::empty(3, 1)).unwrap_err();
        assert_eq!(e, DeepFrameError::WidthMismatch { width: 2, found: 3 });
        assert!(
            e.to_string()
                .contains("3 pixels wide below a frame 2 pixels wide"),
            "{e}"
        );
        assert_eq!(narrow, DeepFrame::empty(2, 0));
    }

    #[test]
    fn build_sorts_runs_and_prefix_sums_counts() {
        let f = DeepFrame::from_pixel_lists(2, 2, &sample()).unwrap();
        assert_eq!(f.offsets(), &[0, 0, 2, 3, 6]);
        assert_eq!(f.pixel(1, 0).depth, &[0.3, 0.7]);
        assert_eq!(f.pixel(1, 1).depth, &[0.1, 0.5, 0.9]);
        assert_eq!(f.fragment_count(), 6);
        let s = f.depth_stats();
        assert_eq!((s.covered_pixels(), s.max_depth_complexity()), (3, 3));
    }

    #[test]
    fn resolve_is_the_worked_example() {
        let f = DeepFrame::from_pixel_lists(2, 2, &sample()).unwrap();
        let img = f.resolve([1.0, 1.0, 1.0]);
        assert_eq!(img.pixel(0, 0), [255, 255, 255]);
        assert_eq!(img.pixel(1, 0), [191, 63, 127]); // red over blue over white, alpha 128/255
        assert_eq!(img.pixel(0, 1), [0, 255, 0]);
    }

    #[test]
    fn capture_order_does_not_matter() {
        let mut lists = sample();
        let a = DeepFrame::from_pixel_lists(2, 2, &lists).unwrap();
        for l in &mut lists {
            l.reverse();
        }
        let b = DeepFrame::from_pixel_lists(2, 2, &lists).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn from_parts_names_the_first_offender_across_parallel_chunks() {
        // Three fragments a pixel over more pixels and fragments than several check chunks.
        let (w, h) = (256u32, 3 * CHECK_CHUNK as u32 / 256);
        let pixels = (w * h) as usize;
        let offsets: Vec<u32> = (0..=pixels as u32).map(|p| 3 * p).collect();
        let n = 3 * pixels;
        let depth: Vec<f32> = (0..n).map(|i| (i % 3) as f32 * 0.25).collect();
        let color = vec![Rgba8([1, 2, 3, 4]); n];
        let object = vec![ObjectId(1); n];
        let parts = |depth: Vec<f32>| {
            DeepFrame::from_parts(w, h, offsets.clone(), depth, color.clone(), object.clone())
        };
        assert!(parts(depth.clone()).is_ok());
        // Two bad depths in different chunks: the first is named, whatever the threads do.
        let (early, late) = (CHECK_CHUNK + 7, 2 * CHECK_CHUNK + 1);
        let mut bad = depth.clone();
        bad[late] = -0.0;
        bad[early] = 1.5;
        assert_eq!(
            parts(bad),
            Err(DeepFrameError::BadDepth {
                index: early,
                depth: 1.5
            })
        );
        let mut nan = depth.clone();
        nan[late] = f32::NAN;
        assert!(matches!(parts(nan), Err(DeepFrameError::BadDepth { index, .. }) if index == late));
        let mut negative_zero = depth.clone();
        negative_zero[early] = -0.0;
        assert!(matches!(
            parts(negative_zero),
            Err(DeepFrameError::BadDepth { index, .. }) if index == early
        ));
        // Two unsorted pixels far apart: the first.
        let mut unsorted = depth.clone();
        unsorted.swap(3 * 20_000, 3 * 20_000 + 1);
        unsorted.swap(3 * 2, 3 * 2 + 2);
        assert_eq!(parts(unsorted), Err(DeepFrameError::Unsorted { pixel: 2 }));
        // A decreasing offset past the first chunk.
        let mut broken = offsets.clone();
        broken[CHECK_CHUNK + 3] = 0;
        assert_eq!(
            DeepFrame::from_parts(w, h, broken, depth, color.clone(), object.clone()),
            Err(DeepFrameError::BadOffsets {
                pixel: CHECK_CHUNK + 2
            })
        );
    }

    /// A small xorshift generator: `next(m)` is uniform enough in `0..m` for tests.
    fn xorshift(seed: u64) -> impl FnMut(u64) -> u64 {
        let mut x = seed;
        move |m: u64| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x % m
        }
    }

    /// The parts of a valid `w`×`h` frame with runs of 0 to 4 fragments whose keys tie in
    /// depth (then object, then colour) as often as not.
    #[allow(
        clippy::type_complexity,
        reason = "the parts, as from_parts takes them"
    )]
    /// A `w`×`h` frame whose runs hold 0 to `most` fragments, with keys that tie often.
    fn tied_parts(
        next: &mut impl FnMut(u64) -> u64,
        w: u32,
        h: u32,
        most: u64,
    ) -> (Vec<u32>, Vec<f32>, Vec<Rgba8>, Vec<ObjectId>) {
        let mut offsets = vec![0u32];
        let (mut depth, mut color, mut object) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..w * h {
            let count = next(most + 1) as u32;
            let mut keys: Vec<(u32, u32, [u8; 4])> = (0..count)
                .map(|_| {
                    let d = 0.25f32 + 0.25 * next(3) as f32;
                    let c = [next(2) as u8, 0, 0, next(2) as u8];
                    (d.to_bits(), next(2) as u32, c)
                })
                .collect();
            keys.sort_by_key(|&(d, o, c)| {
                ((u64::from(d) << 32) | u64::from(o), u32::from_le_bytes(c))
            });
            for (d, o, c) in keys {
                depth.push(f32::from_bits(d));
                object.push(ObjectId(o));
                color.push(Rgba8(c));
            }
            offsets.push(depth.len() as u32);
        }
        (offsets, depth, color, object)
    }

    #[test]
    fn filling_bands_checks_each_band_as_from_parts_checks_the_frame() {
        // Valid frames, and frames broken in one place of each kind (a decreasing offset inside
        // a band or at a band's end, a depth out of range, a disordered run), built band by
        // band for several tilings (including empty bands) into reused columns of other
        // lengths: the frame, or the error, is the one from_parts gives.
        let mut next = xorshift(0x9e37_79b9_7f4a_7c15);
        let (w, h) = (150u32, 140u32);
        let pixels = (w * h) as usize;
        for round in 0..24 {
            let (mut offsets, mut depth, mut color, mut object) = tied_parts(&mut next, w, h, 4);
            let n = depth.len();
            match round % 6 {
                0 => {}
                1 => {
                    // Offsets decrease after pixel p (somewhere inside).
                    let p = 1 + next(pixels as u64 - 2) as usize;
                    offsets[p] = offsets[p + 1] + 1;
                }
                2 => {
                    // ... at the end of a band of 16 rows.
                    let p = (16 * w) as usize;
                    offsets[p] = offsets[p + 1] + 1;
                }
                3 => {
                    let i = next(n as u64) as usize;
                    depth[i] = [f32::NAN, -0.0, 1.5, -0.25][round / 6 % 4];
                }
                4 => {
                    for _ in 0..3 {
                        let i = next(n as u64 - 1) as usize;
                        depth.swap(i, i + 1);
                        object.swap(i, i + 1);
                        color.swap(i, i + 1);
                    }
                }
                _ => {
                    // Two faults: the depth's is named first, as from_parts names it.
                    let i = next(n as u64 - 1) as usize;
                    depth.swap(i, i + 1);
                    object.swap(i, i + 1);
                    let j = next(n as u64) as usize;
                    depth[j] = f32::INFINITY;
                }
            }
            let want = DeepFrame::from_parts(
                w,
                h,
                offsets.clone(),
                depth.clone(),
                color.clone(),
                object.clone(),
            );
            let row = w as usize;
            let tilings: [Vec<std::ops::Range<usize>>; 3] = [
                std::iter::once(0..pixels).collect(),
                (0..pixels)
                    .step_by(16 * row)
                    .map(|p| p..(p + 16 * row).min(pixels))
                    .collect(),
                vec![
                    0..0,
                    0..3 * row + 7,
                    3 * row + 7..3 * row + 7,
                    3 * row + 7..pixels,
                ],
            ];
            for bands in &tilings {
                let reused = (
                    vec![0.5f32; n / 2 + round],
                    vec![Rgba8([9; 4]); n + 100],
                    vec![ObjectId(7); 3],
                );
                let got = DeepFrame::fill_bands(w, h, offsets.clone(), bands, reused, |i, b| {
                    let band = &bands[i];
                    assert_eq!(b.pixels, *band);
                    let lo = offsets[band.start] as usize;
                    let len = b.depth.len();
                    b.depth.copy_from_slice(&depth[lo..lo + len]);
                    b.color.copy_from_slice(&color[lo..lo + len]);
                    b.object.copy_from_slice(&object[lo..lo + len]);
                });
                // Errors by their text: a NaN depth is not equal to itself.
                let same = match (&got, &want) {
                    (Ok(a), Ok(b)) => a == b,
                    (Err(a), Err(b)) => a.to_string() == b.to_string(),
                    _ => false,
                };
                assert!(
                    same,
                    "round {round}, {} bands: {:?} vs {:?}",
                    bands.len(),
                    got.err(),
                    want.err()
                );
            }
        }
    }

    #[test]
    #[should_panic(expected = "bands must cover every pixel")]
    fn filling_bands_that_miss_pixels_is_a_bug() {
        let _ = DeepFrame::fill_bands(
            2,
            2,
            vec![0; 5],
            &[0..2, 2..3],
            Default::default(),
            |_, _| (),
        );
    }

    #[test]
    fn the_sorted_check_names_the_first_unsorted_run_like_a_run_by_run_scan() {
        // Frames over several check chunks, with runs of 0 to 4 fragments (or 0 to 2, where
        // many blocks of pixels hold no run to check) whose keys tie in depth (then object,
        // then colour) as often as not, each disordered in a few runs.
        let mut next = xorshift(0x2545_f491_4f6c_dd1d);
        let (w, h) = (300u32, 130u32);
        for round in 0..24 {
            let most = if round < 12 { 4 } else { 2 };
            let (offsets, mut depth, mut color, mut object) = tied_parts(&mut next, w, h, most);
            for _ in 0..round % 4 {
                let i = next(depth.len() as u64 - 1) as usize;
                depth.swap(i, i + 1);
                object.swap(i, i + 1);
                if round % 3 == 0 {
                    color.swap(i, i + 1);
                }
            }
            let key = |i: usize| {
                (
                    (u64::from(depth[i].to_bits()) << 32) | u64::from(object[i].0),
                    u32::from_le_bytes(color[i].0),
                )
            };
            let first = (0..(w * h) as usize).find(|&p| {
                let (a, b) = (offsets[p] as usize, offsets[p + 1] as usize);
                (a + 1..b).any(|i| key(i - 1) > key(i))
            });
            let got =
                DeepFrame::from_parts(w, h, offsets, depth.clone(), color.clone(), object.clone())
                    .map(|_| ());
            match first {
                Some(pixel) => assert_eq!(
                    got,
                    Err(DeepFrameError::Unsorted { pixel }),
                    "round {round}"
                ),
                None => assert_eq!(got, Ok(()), "round {round}"),
            }
        }
    }

    #[test]
    fn from_parts_round_trips_and_rejects_broken_parts() {
        let f = DeepFrame::from_pixel_lists(2, 2, &sample()).unwrap();
        let (w, h, o, d, c, ob) = f.clone().into_parts();
        assert_eq!(
            DeepFrame::from_parts(w, h, o.clone(), d.clone(), c.clone(), ob.clone()).unwrap(),
            f
        );
        let mut bad = o.clone();
        bad[2] = 7;
        assert!(matches!(
            DeepFrame::from_parts(w, h, bad, d.clone(), c.clone(), ob.clone()),
            Err(DeepFrameError::BadOffsets { .. })
        ));
        let mut swapped = d.clone();
        swapped.swap(0, 1);
        assert_eq!(
            DeepFrame::from_parts(w, h, o.clone(), swapped, c.clone(), ob.clone()),
            Err(DeepFrameError::Unsorted { pixel: 1 })
        );
        let mut nan = d.clone();
        nan[5] = f32::NAN;
        assert!(matches!(
            DeepFrame::from_parts(w, h, o.clone(), nan, c.clone(), ob.clone()),
            Err(DeepFrameError::BadDepth { index: 5, .. })
        ));
        assert!(matches!(
            DeepFrame::from_parts(w, h, o[..4].to_vec(), d.clone(), c.clone(), ob.clone()),
            Err(DeepFrameError::PixelCount { .. })
        ));
        assert!(matches!(
            DeepFrame::from_parts(w, h, o, d, c[..5].to_vec(), ob),
            Err(DeepFrameError::ColumnLengths { .. })
        ));
    }

    #[test]
    fn build_rejects_a_fill_that_disagrees_with_its_count() {
        let err = DeepFrame::build(2, 1, &[1, 0], |_, out| {
            out.push(frag(0.5, [0; 4], 0));
            out.push(frag(0.6, [0; 4], 0));
        });
        assert!(matches!(
            err,
            Err(DeepFrameError::CountMismatch { pixel: 0, .. })
        ));
    }

    #[test]
    fn negative_zero_depth_is_normalised() {
        let f = DeepFrame::from_pixel_lists(1, 1, &[vec![frag(-0.0, [0; 4], 0)]]).unwrap();
        assert!(f.depths()[0].is_sign_positive());
    }

    #[test]
    fn resolving_into_a_kept_image_composites_every_run_across_tasks() {
        // Over several parallel tasks, runs of 0 to 4 fragments of varying alpha, resolved into
        // a fresh image and into one holding another frame's pixels: both are the per-pixel
        // composite of each run.
        let (w, h) = (300u32, 100u32);
        let lists: Vec<Vec<Fragment>> = (0..w * h)
            .map(|p| {
                (0..(p * 7 + p / 300) % 5)
                    .map(|k| {
                        let c = [
                            (p % 251) as u8,
                            (k * 60) as u8,
                            (p / 97) as u8,
                            30 + (p % 220) as u8,
                        ];
                        frag(0.1 + 0.2 * k as f32, c, k)
                    })
                    .collect()
            })
            .collect();
        let f = DeepFrame::from_pixel_lists(w, h, &lists).unwrap();
        let background = [0.2, 0.5, 0.9];
        let bg = composite::background_pixel(background);
        let want: Vec<u8> = (0..(w * h) as usize)
            .flat_map(|p| {
                let run = f.run(p);
                if run.is_empty() {
                    bg
                } else {
                    composite::resolve_pixel(run.color.iter().copied(), background)
                }
            })
            .collect();
        assert_eq!(f.resolve(background).as_bytes(), &want[..]);
        let mut kept = Rgb8Image::filled(w, h, [9, 8, 7]);
        f.resolve_into(background, &mut kept);
        assert_eq!(kept.as_bytes(), &want[..]);
    }

    #[test]
    fn large_frames_cross_task_boundaries() {
        // More pixels than one parallel task, with varying counts.
        let (w, h) = (300u32, 100u32);
        let lists: Vec<Vec<Fragment>> = (0..(w * h) as usize)
            .map(|p| {
                (0..(p % 4))
                    .map(|k| frag(1.0 / (k as f32 + 2.0), [k as u8; 4], p as u32))
                    .collect()
            })
            .collect();
        let f = DeepFrame::from_pixel_lists(w, h, &lists).unwrap();
        for p in [0, 1, 8191, 8192, 8193, 29_999] {
            let mut expected = lists[p].clone();
            sort_front_to_back(&mut expected);
            assert_eq!(f.run(p).iter().collect::<Vec<_>>(), expected);
        }
    }
}
