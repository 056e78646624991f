//! The removal list of a `reprojection` frame (Jähne 2014 ch. 5, fig. 5.10's orange fragments).
//!
//! Both ends of a reprojection link hold the same per-pixel lists of normal fragments and move
//! them to the new camera with the same arithmetic, so they agree on every pixel's reprojected,
//! sorted run. A removal therefore names a fragment by its **position in that run** — an exact
//! identity — instead of by a depth to be matched within a threshold, the merge the thesis found
//! ambiguous (fig. 5.8, 5.9).
//!
//! The list has one entry per pixel of the frame's `mask` (the touched pixels), in mask order:
//! the positions that pixel loses, strictly increasing. A touched pixel may lose nothing and only
//! gain inserts. `checksum` is a digest of the state the sender holds after the frame is applied;
//! a receiver whose own digest differs has diverged (a different floating-point platform, a lost
//! message) and must ask for a reset. `depth_error` bounds how far (in window depth) any fragment
//! the receiver keeps lies from the depth the sender rendered at that pixel: a receiver merging
//! several senders treats fragments of different senders closer than that as unordered.
//!
//! # Wire encoding (section tag 34)
//!
//! ```text
//! checksum     u64
//! depth_error  f32      in [0, 1]
//! per touched pixel, in mask order:
//!   count    varint        positions removed at this pixel (≤ 65 536)
//!   first    varint        the first position
//!   gaps     varint × (count − 1)   each next position minus the previous, minus one
//! ```

use rayon::prelude::*;

use crate::bytes::{Reader, put_varint};
use crate::error::WireError;

/// Touched pixels encoded by one task of [`Removals::encode`].
const ENCODE_CHUNK: usize = 4096;

/// Most positions one pixel may lose in one frame (a pixel's run is shorter in practice; the
/// limit keeps a hostile count from promising more work than its bytes could describe).
pub const MAX_REMOVALS_PER_PIXEL: u32 = 1 << 16;

/// The positions each touched pixel loses, and the sender's state digest.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Removals {
    checksum: u64,
    depth_error: f32,
    /// `offsets[k]..offsets[k + 1]` indexes `positions` for touched pixel `k`.
    offsets: Vec<u32>,
    positions: Vec<u32>,
}

impl Removals {
    /// An empty list with the sender's state digest.
    pub fn new(checksum: u64) -> Self {
        Removals {
            checksum,
            depth_error: 0.0,
            offsets: vec![0],
            positions: Vec::new(),
        }
    }

    /// Empties the list, keeping its capacity.
    pub fn clear(&mut self, checksum: u64) {
        self.checksum = checksum;
        self.offsets.clear();
        self.offsets.push(0);
        self.positions.clear();
    }

    /// Sets the state digest.
    pub fn set_checksum(&mut self, checksum: u64) {
        self.checksum = checksum;
    }

    /// Sets the bound on kept fragments' depth error (window depth, so clamped to `[0, 1]`).
    pub fn set_depth_error(&mut self, e: f32) {
        self.depth_error = if e.is_nan() { 1.0 } else { e.clamp(0.0, 1.0) };
    }

    /// The bound on kept fragments' depth error, in window depth.
    pub fn depth_error(&self) -> f32 {
        self.depth_error
    }

    /// Appends the next touched pixel's positions, which must be strictly increasing.
    ///
    /// # Panics
    /// If they are not, or if there are more than [`MAX_REMOVALS_PER_PIXEL`] (a sender's bug).
    pub fn push_pixel(&mut self, positions: impl IntoIterator<Item = u32>) {
        let start = self.positions.len();
        self.positions.extend(positions);
        let new = &self.positions[start..];
        assert!(
            new.windows(2).all(|w| w[0] < w[1]),
            "removal positions must be strictly increasing"
        );
        assert!(new.len() <= MAX_REMOVALS_PER_PIXEL as usize);
        self.offsets.push(self.positions.len() as u32);
    }

    /// Appends touched pixels' positions at once, as [`Removals::push_pixel`] for each: the
    /// `k`-th pixel's are the next `counts[k]` of `positions`.
    ///
    /// # Panics
    /// If the counts do not add up to `positions.len()`, or as `push_pixel` panics.
    pub fn push_pixels(&mut self, counts: &[u32], positions: &[u32]) {
        self.push_pieces(&[(counts, positions)]);
    }

    /// Appends several pieces of touched pixels in order, each `(counts, positions)` as
    /// [`Removals::push_pixels`] takes it, checking and copying the pieces in parallel (a
    /// reprojection node appends its bands' removals at once: one after another, on one thread,
    /// they held up the node's other stages for about 1.5 ms a dragon frame). Everything is
    /// checked before anything is appended.
    ///
    /// # Panics
    /// As `push_pixels` panics, for any piece.
    pub fn push_pieces(&mut self, pieces: &[(&[u32], &[u32])]) {
        pieces.par_iter().for_each(|&(counts, positions)| {
            let total: u64 = counts.iter().map(|&n| u64::from(n)).sum();
            assert_eq!(
                total,
                positions.len() as u64,
                "the counts must add up to the positions"
            );
            let mut at = 0;
            for &n in counts {
                assert!(n <= MAX_REMOVALS_PER_PIXEL);
                let new = &positions[at..at + n as usize];
                assert!(
                    new.windows(2).all(|w| w[0] < w[1]),
                    "removal positions must be strictly increasing"
                );
                at += n as usize;
            }
        });
        // Each piece's share of the offsets and positions, filled in parallel: its offsets
        // continue from the positions of the pieces before it.
        let (old_pixels, old_positions) = (self.offsets.len(), self.positions.len());
        let added: usize = pieces.iter().map(|(c, _)| c.len()).sum();
        let added_positions: usize = pieces.iter().map(|(_, p)| p.len()).sum();
        self.offsets.resize(old_pixels + added, 0);
        self.positions.resize(old_positions + added_positions, 0);
        let mut offsets = &mut self.offsets[old_pixels..];
        let mut positions = &mut self.positions[old_positions..];
        let mut base = old_positions;
        let mut jobs = Vec::with_capacity(pieces.len());
        for &(counts, from) in pieces {
            let (o, rest) = std::mem::take(&mut offsets).split_at_mut(counts.len());
            let (p, rest_p) = std::mem::take(&mut positions).split_at_mut(from.len());
            (offsets, positions) = (rest, rest_p);
            jobs.push((o, p, counts, from, base));
            base += from.len();
        }
        jobs.into_par_iter().for_each(|(o, p, counts, from, base)| {
            let mut end = base;
            for (o, &n) in o.iter_mut().zip(counts) {
                end += n as usize;
                *o = end as u32;
            }
            p.copy_from_slice(from);
        });
    }

    /// The state digest.
    pub fn checksum(&self) -> u64 {
        self.checksum
    }

    /// Touched pixels described.
    pub fn pixel_count(&self) -> usize {
        self.offsets.len() - 1
    }

    /// The positions touched pixel `k` loses.
    pub fn pixel(&self, k: usize) -> &[u32] {
        &self.positions[self.offsets[k] as usize..self.offsets[k + 1] as usize]
    }

    /// Positions removed over the touched pixels `pixels` (indices in mask order).
    ///
    /// # Panics
    /// If `pixels` reaches past the last touched pixel.
    pub fn count_in(&self, pixels: std::ops::Range<usize>) -> usize {
        (self.offsets[pixels.end] - self.offsets[pixels.start]) as usize
    }

    /// Positions removed over all pixels.
    pub fn total(&self) -> usize {
        self.positions.len()
    }

    /// Appends the wire encoding. Pixels are encoded 4,096 at a time in parallel,
    /// and the chunks' bytes appended in order: the same bytes as one pixel after another (a
    /// pixel's record does not depend on the others), which held up a reprojection node's other
    /// stages for about 1.7 ms a dragon frame.
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.checksum.to_le_bytes());
        out.extend_from_slice(&self.depth_error.to_le_bytes());
        let pixels = self.pixel_count();
        let chunks: Vec<Vec<u8>> = (0..pixels.div_ceil(ENCODE_CHUNK))
            .into_par_iter()
            .map(|c| {
                let range = c * ENCODE_CHUNK..((c + 1) * ENCODE_CHUNK).min(pixels);
                let offsets = &self.offsets[range.start..range.end + 1];
                let (first, last) = (offsets[0] as usize, offsets[offsets.len() - 1] as usize);
                // At least a byte a count and a position; most take one.
                let mut bytes = Vec::with_capacity(range.len() + last - first);
                for w in offsets.windows(2) {
                    let p = &self.positions[w[0] as usize..w[1] as usize];
                    put_varint(&mut bytes, p.len() as u32);
                    // The first position as it is, then each one's gap after the one before.
                    let mut next = 0u32;
                    for &i in p {
                        put_varint(&mut bytes, i - next);
                        next = i.wrapping_add(1);
                    }
                }
                bytes
            })
            .collect();
        out.reserve(chunks.iter().map(Vec::len).sum());
        for bytes in &chunks {
            out.extend_from_slice(bytes);
        }
    }

    /// Decodes a list for `touched` pixels from `bytes`, which start at message offset `base`.
    pub fn decode(bytes: &[u8], base: u64, touched: u32) -> Result<Self, WireError> {
        let mut r = Reader::new(bytes, base);
        let checksum = r.u64("removals checksum")?;
        let at = r.offset();
        let depth_error = r.f32("depth_error")?;
        if !(0.0..=1.0).contains(&depth_error) {
            return Err(WireError::invalid(
                "depth_error",
                at,
                depth_error,
                "a window-depth error in [0, 1]",
            ));
        }
        // Every pixel costs at least one byte: the allocation is bounded by the input.
        if u64::from(touched) > r.remaining() as u64 {
            return Err(WireError::section(
                "removals",
                r.offset(),
                format!(
                    "{touched} touched pixels need at least {touched} bytes, {} remain",
                    r.remaining()
                ),
            ));
        }
        let mut out = Removals::new(checksum);
        out.depth_error = depth_error;
        out.offsets.reserve(touched as usize);
        for _ in 0..touched {
            let at = r.offset();
            let count = r.varint("removal count")?;
            if count > MAX_REMOVALS_PER_PIXEL || count as usize > r.remaining() {
                return Err(WireError::invalid(
                    "removal count",
                    at,
                    count,
                    format!(
                        "at most {MAX_REMOVALS_PER_PIXEL} per pixel, one byte each ({} remain)",
                        r.remaining()
                    ),
                ));
            }
            let mut next: u64 = 0;
            for _ in 0..count {
                let at = r.offset();
                let v = u64::from(r.varint("removal position")?) + next;
                let position = u32::try_from(v).map_err(|_| {
                    WireError::invalid("removal position", at, v, "positions are u32")
                })?;
                out.positions.push(position);
                next = v + 1;
            }
            out.offsets.push(out.positions.len() as u32);
        }
        if r.remaining() != 0 {
            return Err(WireError::section(
                "removals",
                r.offset(),
                format!("{} bytes follow the last touched pixel", r.remaining()),
            ));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn round_trip_and_layout() {
        let mut r = Removals::new(0x0102_0304_0506_0708);
        r.set_depth_error(0.5);
        r.push_pixel([]);
        r.push_pixel([0, 1, 5]);
        r.push_pixel([300]);
        let mut bytes = Vec::new();
        r.encode(&mut bytes);
        assert_eq!(&bytes[..8], &0x0102_0304_0506_0708u64.to_le_bytes());
        assert_eq!(&bytes[8..12], &0.5f32.to_le_bytes());
        assert_eq!(&bytes[12..], &[0, 3, 0, 0, 3, 1, 0xAC, 0x02]);
        assert_eq!(Removals::decode(&bytes, 0, 3).unwrap(), r);
        assert_eq!(r.pixel(1), &[0, 1, 5]);
        assert_eq!(r.total(), 4);
    }

    #[test]
    fn pixels_pushed_at_once_are_pixels_pushed_one_by_one() {
        let pixels: [&[u32]; 5] = [&[], &[0, 1, 5], &[300], &[], &[2, 9]];
        let mut one_by_one = Removals::new(9);
        let mut at_once = Removals::new(9);
        for p in &pixels[..2] {
            one_by_one.push_pixel(p.iter().copied());
            at_once.push_pixel(p.iter().copied());
        }
        for p in &pixels[2..] {
            one_by_one.push_pixel(p.iter().copied());
        }
        let counts: Vec<u32> = pixels[2..].iter().map(|p| p.len() as u32).collect();
        at_once.push_pixels(&counts, &pixels[2..].concat());
        assert_eq!(at_once, one_by_one);
        assert_eq!(at_once.pixel(4), &[2, 9]);
        for (counts, positions) in [(&[1u32, 2][..], &[3u32, 3, 3][..]), (&[1, 1], &[1, 2, 3])] {
            let mut r = at_once.clone();
            let bad = std::panic::catch_unwind(move || {
                r.push_pixels(counts, positions);
                r
            });
            assert!(bad.is_err(), "{counts:?} {positions:?} accepted");
        }
    }

    /// Several pieces appended at once (empty ones among them) are the pieces appended one
    /// after another; a bad piece anywhere panics before anything is appended.
    #[test]
    fn pieces_pushed_at_once_are_pieces_pushed_one_by_one() {
        let pieces: [(&[u32], &[u32]); 5] = [
            (&[2, 0, 1], &[4, 9, 0]),
            (&[], &[]),
            (&[3], &[1, 2, 70_000]),
            (&[0, 0], &[]),
            (&[1, 1, 2], &[5, 0, 3, 8]),
        ];
        let mut one_by_one = Removals::new(3);
        one_by_one.push_pixel([7]);
        let mut at_once = one_by_one.clone();
        for &(counts, positions) in &pieces {
            one_by_one.push_pixels(counts, positions);
        }
        at_once.push_pieces(&pieces);
        assert_eq!(at_once, one_by_one);
        assert_eq!(at_once.pixel(4), &[1, 2, 70_000]);
        assert_eq!(at_once.total(), 11);
        for bad in [(&[2u32][..], &[3u32, 3][..]), (&[1], &[1, 2])] {
            let mut r = at_once.clone();
            let before = r.clone();
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                r.push_pieces(&[pieces[0], bad, pieces[2]]);
            }));
            assert!(result.is_err(), "{bad:?} accepted");
            assert_eq!(r, before, "{bad:?}: something was appended");
        }
    }

    /// More touched pixels than one task encodes: the chunks' bytes are one pixel's record
    /// after another, as a single loop writes them.
    #[test]
    fn a_long_list_encodes_as_one_pixel_after_another() {
        let mut r = Removals::new(0xABCD);
        let mut want = Vec::new();
        want.extend_from_slice(&0xABCDu64.to_le_bytes());
        want.extend_from_slice(&0f32.to_le_bytes());
        for k in 0..3 * ENCODE_CHUNK as u32 + 17 {
            let positions: Vec<u32> = (0..k % 4).map(|i| i * (k % 300) + i).collect();
            put_varint(&mut want, positions.len() as u32);
            let mut next = 0;
            for &i in &positions {
                put_varint(&mut want, i - next);
                next = i + 1;
            }
            r.push_pixel(positions);
        }
        let mut got = Vec::new();
        r.encode(&mut got);
        assert_eq!(got, want);
        let n = r.pixel_count() as u32;
        assert_eq!(Removals::decode(&got, 0, n).expect("decodes"), r);
    }

    #[test]
    fn hostile_lists_are_errors() {
        let mut ok = Vec::new();
        Removals::new(7).encode(&mut ok);
        for (bytes, touched) in [
            (vec![0u8; 11], 0), // short header
            ([vec![0u8; 8], f32::NAN.to_le_bytes().to_vec()].concat(), 0),
            ([vec![0u8; 8], (-1f32).to_le_bytes().to_vec()].concat(), 0),
            ([vec![0u8; 8], f32::MAX.to_le_bytes().to_vec()].concat(), 0),
            (ok.clone(), 1),                        // a pixel missing
            ([ok.clone(), vec![0, 0]].concat(), 1), // trailing bytes
            ([ok.clone(), vec![5, 1]].concat(), 1), // count beyond the bytes
            ([ok.clone(), vec![0xFF; 5]].concat(), 1),
            (
                [ok.clone(), vec![2, 0xFF, 0xFF, 0xFF, 0xFF, 0x0F, 1]].concat(),
                1,
            ), // position overflow
            (ok.clone(), u32::MAX),
        ] {
            assert!(Removals::decode(&bytes, 0, touched).is_err(), "{bytes:?}");
        }
    }

    proptest! {
        #[test]
        fn any_list_round_trips(pixels in proptest::collection::vec(
            proptest::collection::btree_set(0u32..5000, 0..20), 0..50), checksum in any::<u64>()) {
            let mut r = Removals::new(checksum);
            r.set_depth_error(1e-4);
            for p in &pixels {
                r.push_pixel(p.iter().copied());
            }
            let mut bytes = Vec::new();
            r.encode(&mut bytes);
            prop_assert_eq!(Removals::decode(&bytes, 0, pixels.len() as u32).unwrap(), r);
        }

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..64), n in 0u32..40) {
            let _ = Removals::decode(&bytes, 0, n);
        }
    }
}
