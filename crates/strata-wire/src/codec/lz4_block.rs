//! An LZ4 *block* decoder in safe Rust whose matches copy whole runs at a time, for the deep
//! layout's sections, which are mostly long runs of one byte.
//!
//! # Why not lz4_flex's decoder
//!
//! The deep layout's planes hold long runs of zeros: the counts of empty pixels, the high
//! bytes of depth residuals, a constant alpha. LZ4 codes a run as a match at distance 1, and
//! lz4_flex copies an overlapping match one byte at a time (each byte waits for the one before
//! it). `perf` of `strata codecs dragon` put 15 % of its samples (encoding included) in LZ4
//! decompression; the dragon's counts section alone, 42 KB that decode to 921,600 bytes, took
//! 0.65 ms on one core of an AMD EPYC, and its depth section 2.7 ms. Here a match at distance 1
//! is a `fill`, and any other overlapping match is copied a period at a time, doubling: 0.30
//! and 0.92 ms. The encoder is still lz4_flex's (`compress.rs`), which also decodes the
//! sections that are not mostly runs (see `RUNS_RATIO` there); the bytes on the wire are the
//! standard block format, so either decoder reads them.
//!
//! # Format (LZ4 block, as in lz4's `doc/lz4_Block_format.md`)
//!
//! A block is a list of sequences. Each starts with a token byte: its high four bits are the
//! number of literals, its low four the match length minus 4. A field of 15 continues in the
//! following bytes, each added in turn, up to and including the first byte below 255. Then the
//! literals, then a two-byte little-endian offset (1 ..= 65535: how far back the match starts)
//! and the match length's continuation bytes. The last sequence stops after its literals.
//!
//! # Hostile input
//!
//! Every length and offset is checked against what is left of the input and the output before
//! anything is copied: a block that would read past its end, reach before the output's start
//! (or use offset 0), or write past the announced length is an error, never a panic. The output
//! is an exact-size slice, so nothing is written beyond it either way.

/// Why a block does not decode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Lz4Error {
    /// The block ends inside a sequence (at input byte `at`).
    Truncated { at: usize },
    /// A match starts before the output (or has offset 0).
    BadOffset { at: usize, offset: usize },
    /// The block produces more bytes than the output holds.
    TooLong,
    /// The block ends before filling the output: it produced `produced` bytes.
    TooShort { produced: usize },
}

impl std::fmt::Display for Lz4Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Lz4Error::Truncated { at } => write!(f, "the block ends inside a sequence (byte {at})"),
            Lz4Error::BadOffset { at, offset } => write!(
                f,
                "a match at byte {at} reaches {offset} bytes back, before the start of the output"
            ),
            Lz4Error::TooLong => write!(f, "the block holds more bytes than announced"),
            Lz4Error::TooShort { produced } => {
                write!(f, "the block holds only {produced} bytes")
            }
        }
    }
}

/// Bytes copied at once for short literal runs and matches, past their end where the output
/// has room: most sequences of the noisy planes are shorter.
const WIDE: usize = 16;

/// Reads a length field's continuation bytes (after a 15 in the token), adding them to `len`.
#[inline(always)]
fn continued(input: &[u8], at: &mut usize, mut len: usize) -> Result<usize, Lz4Error> {
    loop {
        let &b = input.get(*at).ok_or(Lz4Error::Truncated { at: *at })?;
        *at += 1;
        len += usize::from(b);
        if b != 255 {
            return Ok(len);
        }
    }
}

/// Decodes the block `input` into `out`, which it must fill exactly.
pub(crate) fn decompress_into(input: &[u8], out: &mut [u8]) -> Result<(), Lz4Error> {
    let (mut i, mut o) = (0usize, 0usize);
    loop {
        let &token = input.get(i).ok_or(Lz4Error::Truncated { at: i })?;
        i += 1;
        let mut literals = usize::from(token >> 4);
        if literals == 15 {
            literals = continued(input, &mut i, literals)?;
        }
        if literals <= WIDE && i + WIDE <= input.len() && o + WIDE <= out.len() {
            // A short run of literals as one fixed-size copy (what lies past it is written
            // again by what follows, or the block is an error).
            out[o..o + WIDE].copy_from_slice(&input[i..i + WIDE]);
        } else {
            let source = input
                .get(i..i + literals)
                .ok_or(Lz4Error::Truncated { at: input.len() })?;
            out.get_mut(o..o + literals)
                .ok_or(Lz4Error::TooLong)?
                .copy_from_slice(source);
        }
        i += literals;
        o += literals;
        if i == input.len() {
            // The last sequence has no match.
            return if o == out.len() {
                Ok(())
            } else {
                Err(Lz4Error::TooShort { produced: o })
            };
        }
        let offset = match input.get(i..i + 2) {
            Some(&[a, b]) => usize::from(u16::from_le_bytes([a, b])),
            _ => return Err(Lz4Error::Truncated { at: input.len() }),
        };
        if offset == 0 || offset > o {
            return Err(Lz4Error::BadOffset { at: i, offset });
        }
        i += 2;
        let mut len = usize::from(token & 15);
        if len == 15 {
            len = continued(input, &mut i, len)?;
        }
        len += 4;
        if len > out.len() - o {
            return Err(Lz4Error::TooLong);
        }
        copy_match(out, o, offset, len);
        o += len;
    }
}

/// Copies the match of `len` bytes that starts `offset` bytes before `o` to `o` (both checked
/// to lie in `out`). A match longer than its offset repeats the `offset` bytes before `o`.
#[inline(always)]
fn copy_match(out: &mut [u8], o: usize, offset: usize, len: usize) {
    let start = o - offset;
    if len <= WIDE && offset >= WIDE && o + WIDE <= out.len() {
        // A short match from far enough back as one fixed-size copy (see the literals).
        let mut wide = [0u8; WIDE];
        wide.copy_from_slice(&out[start..start + WIDE]);
        out[o..o + WIDE].copy_from_slice(&wide);
    } else if len <= WIDE && o + WIDE <= out.len() {
        // A short match that overlaps itself (a short period, e.g. alternating residuals):
        // the period repeated into a fixed-size buffer, then one copy.
        let mut wide = [0u8; WIDE];
        for k in 0..WIDE {
            wide[k] = if k < offset {
                out[start + k]
            } else {
                wide[k - offset]
            };
        }
        out[o..o + WIDE].copy_from_slice(&wide);
    } else if offset >= len {
        out.copy_within(start..start + len, o);
    } else if offset == 1 {
        let b = out[start];
        out[o..o + len].fill(b);
    } else {
        // The bytes from `start` repeat with period `offset`: copy whole periods from the
        // start, doubling what is copied, so that each copy reads only bytes already written.
        let mut done = 0;
        while done < len {
            let n = (offset + done).min(len - done);
            out.copy_within(start..start + n, o + done);
            done += n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Data with runs of one byte, short repeats, and noise, as the deep layout's planes have.
    fn planes(seed: u64, n: usize) -> Vec<u8> {
        let mut x = seed | 1;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let mut v = Vec::with_capacity(n);
        while v.len() < n {
            let r = next();
            let len = 1 + (r >> 8) as usize % 300;
            match r % 5 {
                0 => v.extend(std::iter::repeat_n(0u8, len)),
                1 => v.extend(std::iter::repeat_n((r >> 40) as u8, len)),
                2 => {
                    let period = 2 + (r >> 20) as usize % 17;
                    let pattern: Vec<u8> = (0..period).map(|_| next() as u8).collect();
                    v.extend(pattern.iter().cycle().take(len));
                }
                3 => v.extend((0..len.min(20)).map(|_| next() as u8 & 3)),
                _ => v.extend((0..len.min(40)).map(|_| next() as u8)),
            }
        }
        v.truncate(n);
        v
    }

    #[test]
    fn decodes_what_lz4_flex_encodes_like_lz4_flex() {
        for (seed, n) in [
            (1, 0),
            (2, 1),
            (3, 17),
            (4, 1000),
            (5, 70_000),
            (6, 300_000),
        ] {
            let data = planes(seed, n);
            let block = lz4_flex::block::compress(&data);
            let mut out = vec![0xAA; n];
            decompress_into(&block, &mut out).expect("decodes");
            assert_eq!(out, data, "seed {seed}");
            assert_eq!(
                lz4_flex::block::decompress(&block, n).expect("lz4_flex decodes"),
                data
            );
        }
    }

    #[test]
    fn every_overlapping_match_repeats_its_period() {
        // Hand-made blocks: 1 to 20 literals, then one match at every distance up to the
        // literals, 4 to 60 bytes long, then 3 closing literals.
        for lits in 1..=20usize {
            for offset in 1..=lits {
                for len in 4..=60usize {
                    let literal: Vec<u8> = (0..lits as u8).map(|b| b.wrapping_mul(37)).collect();
                    let mut block = Vec::new();
                    let (lt, mt) = (lits.min(15), (len - 4).min(15));
                    block.push((lt << 4 | mt) as u8);
                    if lits >= 15 {
                        block.push((lits - 15) as u8);
                    }
                    block.extend(&literal);
                    block.extend((offset as u16).to_le_bytes());
                    if len - 4 >= 15 {
                        block.push((len - 4 - 15) as u8);
                    }
                    block.extend([0x30, 7, 8, 9]);
                    let mut expected = literal.clone();
                    for _ in 0..len {
                        expected.push(expected[expected.len() - offset]);
                    }
                    expected.extend([7, 8, 9]);
                    let mut out = vec![0; expected.len()];
                    decompress_into(&block, &mut out).expect("decodes");
                    assert_eq!(out, expected, "{lits} literals, offset {offset}, len {len}");
                }
            }
        }
    }

    #[test]
    fn broken_blocks_are_errors_not_panics() {
        let data = planes(9, 5000);
        let block = lz4_flex::block::compress(&data);
        let mut out = vec![0; data.len()];
        // Every truncation, and the wrong output size either way.
        for cut in 0..block.len() {
            assert!(
                decompress_into(&block[..cut], &mut out).is_err(),
                "cut at {cut}"
            );
        }
        let mut short = vec![0; data.len() - 1];
        assert_eq!(decompress_into(&block, &mut short), Err(Lz4Error::TooLong));
        let mut long = vec![0; data.len() + 1];
        assert!(matches!(
            decompress_into(&block, &mut long),
            Err(Lz4Error::TooShort { .. })
        ));
        // Offset 0 and offsets before the output's start.
        assert!(matches!(
            decompress_into(&[0x10, 5, 0, 0, 0x00], &mut [0; 5]),
            Err(Lz4Error::BadOffset { offset: 0, .. })
        ));
        assert!(matches!(
            decompress_into(&[0x10, 5, 2, 0, 0x00], &mut [0; 5]),
            Err(Lz4Error::BadOffset { offset: 2, .. })
        ));
        // Every single-byte change decodes or is an error, and agrees with lz4_flex on which.
        for at in 0..block.len() {
            for flip in [0x01u8, 0x80, 0xff] {
                let mut bad = block.clone();
                bad[at] ^= flip;
                let mine = decompress_into(&bad, &mut out).map(|()| out.clone());
                let theirs = lz4_flex::block::decompress(&bad, data.len())
                    .ok()
                    .filter(|v| v.len() == data.len());
                assert_eq!(mine.ok(), theirs, "byte {at} ^ {flip:#x}");
            }
        }
    }
}
