//! A set of pixels of a frame, as sorted disjoint runs of row-major pixel indices.
//!
//! The `difference` transfer (Jähne 2014 ch. 4) sends only the pixels whose fragment list changed;
//! the display asks a node for exact copies of pixels it shares with other nodes. Both name a set
//! of pixels, and changed regions are spatially coherent (a silhouette, a moving object), so runs
//! are the natural layout: memory and wire size follow the number of run boundaries, not the
//! frame size.
//!
//! # Wire encoding
//!
//! `run_count` as a varint, then per run `gap, len` as varints: `gap` pixels not in the set
//! (counted from the end of the previous run, or from pixel 0), then `len ≥ 1` pixels in it. The
//! decoder checks every run lies inside the frame, so a decoded mask is always valid for it.

use crate::bytes::{Reader, put_varint};
use crate::error::WireError;

/// Sorted, disjoint, non-adjacent runs of pixels of a `pixels`-pixel frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PixelMask {
    pixels: u32,
    /// `(start, len)`, sorted by start, `len ≥ 1`, separated by at least one pixel.
    runs: Vec<(u32, u32)>,
    /// Pixels in the set.
    count: u32,
}

impl PixelMask {
    /// The empty set of a `pixels`-pixel frame.
    pub fn empty(pixels: u32) -> Self {
        PixelMask {
            pixels,
            runs: Vec::new(),
            count: 0,
        }
    }

    /// Every pixel of a `pixels`-pixel frame.
    pub fn full(pixels: u32) -> Self {
        let runs = if pixels == 0 {
            Vec::new()
        } else {
            vec![(0, pixels)]
        };
        PixelMask {
            pixels,
            runs,
            count: pixels,
        }
    }

    /// The pixels `p` of a `pixels`-pixel frame for which `set(p)` is true.
    pub fn from_fn(pixels: u32, mut set: impl FnMut(u32) -> bool) -> Self {
        let mut b = MaskBuilder::new(pixels);
        for p in 0..pixels {
            if set(p) {
                b.push(p);
            }
        }
        b.finish()
    }

    /// The set given as a flag per pixel.
    pub fn from_flags(flags: &[bool]) -> Self {
        Self::from_fn(flags.len() as u32, |p| flags[p as usize])
    }

    /// Pixels in the frame this mask belongs to.
    pub fn frame_pixels(&self) -> u32 {
        self.pixels
    }

    /// Pixels in the set.
    pub fn len(&self) -> u32 {
        self.count
    }

    /// True when no pixel is in the set.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The runs as `(start, len)`, sorted.
    pub fn runs(&self) -> &[(u32, u32)] {
        &self.runs
    }

    /// The pixels in the set, ascending.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.runs.iter().flat_map(|&(s, l)| s..s + l)
    }

    /// One flag per pixel of the frame.
    pub fn to_flags(&self) -> Vec<bool> {
        let mut flags = vec![false; self.pixels as usize];
        for &(s, l) in &self.runs {
            flags[s as usize..(s + l) as usize].fill(true);
        }
        flags
    }

    /// Appends the wire encoding (see the module docs).
    pub fn encode(&self, out: &mut Vec<u8>) {
        put_varint(out, self.runs.len() as u32);
        let mut end = 0;
        for &(s, l) in &self.runs {
            put_varint(out, s - end);
            put_varint(out, l);
            end = s + l;
        }
    }

    /// Decodes a mask of a `pixels`-pixel frame; every byte of `bytes` must be used.
    pub fn decode(bytes: &[u8], base: u64, pixels: u32) -> Result<Self, WireError> {
        let mut r = Reader::new(bytes, base);
        let count_at = r.offset();
        let run_count = r.varint("mask run_count")?;
        // Every run takes at least two bytes: bound the count before allocating.
        if u64::from(run_count) * 2 > r.remaining() as u64 || run_count > pixels.div_ceil(2) {
            return Err(WireError::invalid(
                "mask run_count",
                count_at,
                run_count,
                format!(
                    "{} bytes cannot hold that many runs of a {pixels}-pixel frame",
                    r.remaining()
                ),
            ));
        }
        let mut runs = Vec::with_capacity(run_count as usize);
        let mut end: u64 = 0;
        let mut count: u64 = 0;
        for i in 0..run_count {
            let at = r.offset();
            let gap = r.varint("mask gap")?;
            let len = r.varint("mask len")?;
            if len == 0 || (i > 0 && gap == 0) {
                return Err(WireError::invalid(
                    "mask run",
                    at,
                    format!("gap {gap}, len {len}"),
                    "runs are non-empty and separated by at least one pixel",
                ));
            }
            let start = end + u64::from(gap);
            let stop = start + u64::from(len);
            if stop > u64::from(pixels) {
                return Err(WireError::invalid(
                    "mask run",
                    at,
                    format!("pixels {start}..{stop}"),
                    format!("the frame has {pixels} pixels"),
                ));
            }
            runs.push((start as u32, len));
            count += u64::from(len);
            end = stop;
        }
        if r.remaining() != 0 {
            return Err(WireError::invalid(
                "mask",
                r.offset(),
                r.remaining(),
                "bytes left after the last run",
            ));
        }
        Ok(PixelMask {
            pixels,
            runs,
            count: count as u32,
        })
    }
}

/// Builds a [`PixelMask`] from ascending pixel indices.
#[derive(Debug)]
pub struct MaskBuilder {
    mask: PixelMask,
}

impl MaskBuilder {
    /// An empty mask of a `pixels`-pixel frame.
    pub fn new(pixels: u32) -> Self {
        MaskBuilder {
            mask: PixelMask::empty(pixels),
        }
    }

    /// An empty mask of a `pixels`-pixel frame in the memory of `mask`, a mask no longer needed.
    pub fn reusing(mut mask: PixelMask, pixels: u32) -> Self {
        mask.pixels = pixels;
        mask.runs.clear();
        mask.count = 0;
        MaskBuilder { mask }
    }

    /// Adds pixel `p`, which must be above every pixel added before and inside the frame.
    ///
    /// # Panics
    /// When `p` is out of order or outside the frame: a programming error, not input.
    pub fn push(&mut self, p: u32) {
        assert!(p < self.mask.pixels, "pixel {p} outside the mask's frame");
        match self.mask.runs.last_mut() {
            Some((s, l)) if *s + *l == p => *l += 1,
            Some((s, l)) => {
                assert!(p > *s + *l, "pixels must be pushed in ascending order");
                self.mask.runs.push((p, 1));
            }
            None => self.mask.runs.push((p, 1)),
        }
        self.mask.count += 1;
    }

    /// The mask.
    pub fn finish(self) -> PixelMask {
        self.mask
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_round_trip_and_merge_neighbours() {
        let m = PixelMask::from_fn(20, |p| matches!(p, 0..=2 | 5 | 6 | 19));
        assert_eq!(m.runs(), &[(0, 3), (5, 2), (19, 1)]);
        assert_eq!(m.len(), 6);
        assert_eq!(m.iter().collect::<Vec<_>>(), vec![0, 1, 2, 5, 6, 19]);
        let mut bytes = Vec::new();
        m.encode(&mut bytes);
        assert_eq!(bytes, vec![3, 0, 3, 2, 2, 12, 1]);
        assert_eq!(PixelMask::decode(&bytes, 0, 20).unwrap(), m);
        assert_eq!(PixelMask::from_flags(&m.to_flags()), m);
    }

    #[test]
    fn a_builder_in_an_old_masks_memory_builds_what_a_fresh_one_does() {
        let old = PixelMask::from_fn(40, |p| p % 3 == 0);
        let mut b = MaskBuilder::reusing(old, 20);
        for p in [1, 2, 7] {
            b.push(p);
        }
        let want = PixelMask::from_fn(20, |p| matches!(p, 1 | 2 | 7));
        assert_eq!(b.finish(), want);
    }

    #[test]
    fn empty_and_full() {
        for pixels in [0, 1, 7] {
            for m in [PixelMask::empty(pixels), PixelMask::full(pixels)] {
                let mut bytes = Vec::new();
                m.encode(&mut bytes);
                assert_eq!(PixelMask::decode(&bytes, 0, pixels).unwrap(), m);
            }
        }
    }

    #[test]
    fn malformed_masks_are_errors() {
        let cases: &[(&[u8], &str)] = &[
            (&[1, 0, 21], "mask run"),      // past the end
            (&[1, 0, 0], "mask run"),       // empty run
            (&[2, 0, 1, 0, 1], "mask run"), // adjacent runs
            (&[1, 0, 1, 9], "mask"),        // trailing byte
            (&[200, 1], "mask run_count"),  // more runs than bytes
            (&[1, 0], "mask run_count"),    // truncated: caught by the size bound
        ];
        for (bytes, field) in cases {
            let e = PixelMask::decode(bytes, 100, 20).unwrap_err();
            assert!(e.to_string().contains(field), "{bytes:?}: {e}");
        }
    }
}
