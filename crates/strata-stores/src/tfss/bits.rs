//! A shareable array of bits in 64-bit words: the packed T-buffer and the Length table of TFSS
//! with leading-zeros elimination.
//!
//! Fields of up to 64 bits sit at any bit offset and may straddle two words. Words are
//! `AtomicU64` accessed with `Relaxed` loads and stores (plain moves on x86-64 and AArch64), which
//! keeps the array shareable between the capture threads without `unsafe`.
//!
//! Writes are *not* atomic read-modify-writes: [`BitArray::or`] loads a word, ors the field in
//! and stores it back. That is correct because every word has one writer: TFSS reserves sections
//! in blocks of a multiple of 64 sections (`crate::alloc::block_size`), so a block spans a whole number of
//! words whatever the section's bit size, blocks start on word boundaries, and a block is written
//! only by the strip thread that reserved it.

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

use crate::method::{StoreError, try_alloc};

/// Bits in 64-bit words; see the module docs.
#[derive(Debug, Default)]
pub(crate) struct BitArray {
    words: Vec<AtomicU64>,
}

impl BitArray {
    /// Resizes to hold `bits` bits (contents unspecified: zero ranges before use).
    pub(crate) fn resize(&mut self, bits: u64, what: &'static str) -> Result<(), StoreError> {
        let words = usize::try_from(bits.div_ceil(64)).map_err(|_| StoreError::OutOfMemory {
            what: what.to_owned(),
            bytes: bits / 8,
            hint: "lower L_num or render a smaller image",
        })?;
        if self.words.len() != words {
            self.words = Vec::new();
            self.words = try_alloc(
                words,
                || format!("{what} of {bits} bits"),
                "lower L_num or render a smaller image",
            )?;
        }
        Ok(())
    }

    /// Bytes allocated.
    pub(crate) fn bytes(&self) -> u64 {
        self.words.len() as u64 * 8
    }

    /// The `n`-bit field (`1 ≤ n ≤ 64`) at bit offset `bit`.
    #[inline(always)]
    pub(crate) fn read(&self, bit: u64, n: u32) -> u64 {
        let (w, o) = ((bit / 64) as usize, (bit % 64) as u32);
        let mut v = self.words[w].load(Relaxed) >> o;
        if o + n > 64 {
            v |= self.words[w + 1].load(Relaxed) << (64 - o);
        }
        if n == 64 { v } else { v & ((1u64 << n) - 1) }
    }

    /// Ors `value` (below `2^n`, `n ≤ 64`) into the field at bit offset `bit`; the field must be
    /// zero for this to write `value`. See the module docs for why load + store is enough.
    #[inline(always)]
    pub(crate) fn or(&self, bit: u64, n: u32, value: u64) {
        debug_assert!(n == 64 || value >> n == 0, "value wider than its field");
        if n == 0 {
            return;
        }
        let (w, o) = ((bit / 64) as usize, (bit % 64) as u32);
        let word = &self.words[w];
        word.store(word.load(Relaxed) | (value << o), Relaxed);
        if o + n > 64 {
            let next = &self.words[w + 1];
            next.store(next.load(Relaxed) | (value >> (64 - o)), Relaxed);
        }
    }

    /// Zeroes the words holding bits `start .. end`; `start` must be word-aligned (a block start),
    /// and the last word is zeroed whole (it belongs to the same block, or is the array's end).
    pub(crate) fn zero_words(&self, start: u64, end: u64) {
        debug_assert_eq!(start % 64, 0, "blocks start on word boundaries");
        let (a, b) = (
            (start / 64) as usize,
            (end.div_ceil(64) as usize).min(self.words.len()),
        );
        for w in &self.words[a..b] {
            w.store(0, Relaxed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_straddle_words() {
        let mut a = BitArray::default();
        a.resize(200, "test").unwrap();
        a.zero_words(0, 200);
        a.or(60, 10, 0b11_0110_1011);
        a.or(0, 3, 0b101);
        a.or(70, 64, u64::MAX - 1);
        assert_eq!(a.read(60, 10), 0b11_0110_1011);
        assert_eq!(a.read(0, 3), 0b101);
        assert_eq!(a.read(70, 64), u64::MAX - 1);
        assert_eq!(a.read(3, 57), 0, "untouched bits stay zero");
        assert_eq!(a.bytes(), 4 * 8);
        a.zero_words(64, 128);
        assert_eq!(a.read(60, 4), 0b1011, "the first word keeps its bits");
        assert_eq!(a.read(64, 64), 0);
    }
}
