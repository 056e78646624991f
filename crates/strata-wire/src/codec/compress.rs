//! The general-purpose compressors under the codecs — none, LZ4, zstd — with decompression that
//! never produces, or allocates for, more than the section table announced.
//!
//! # Formats
//!
//! - **none**: the section's payload is its decoded bytes.
//! - **lz4**: one LZ4 *block*: no frame header, no checksum, no size prefix — the section table
//!   already carries the decoded length, which the decoder needs to size its output. Encoded by
//!   lz4_flex's `block` module. A section that is mostly runs of one byte (it decodes to three
//!   or more bytes a payload byte: the deep layout's counts and depths) is decoded by
//!   `codec/lz4_block.rs`, which copies a run at a time instead of a byte at a time; the
//!   others by lz4_flex.
//! - **zstd**: one standard zstd frame (`zstd::bulk::compress`, content size recorded).
//! - **blocks**: blocks of at most 128 KiB, each coded with a canonical Huffman code, LZ4, as one
//!   repeated byte or stored, whichever is smallest of those tried (`codec/blocks.rs`); blocks
//!   are coded and decoded in parallel.
//!
//! # Expansion bounds
//!
//! Before decompressing, the decoder checks that the announced decoded length is one the
//! compressor could have produced from the announced payload:
//!
//! - LZ4 cannot expand more than 255:1 — a match costs 3 bytes (token, offset) for up to 19 bytes
//!   and one more byte per further 255 — so `decoded <= 255 * encoded + 255`;
//! - zstd cannot expand more than 32768:1 — a block yields at most 128 KiB and costs at least
//!   4 bytes (3-byte block header plus one RLE byte) — so `decoded <= 32768 * encoded`;
//! - blocks cannot expand more than 13,108:1 — a block yields at most 128 KiB and costs at least
//!   10 bytes (its 9-byte header and the byte of a fill) — so `decoded <= 13108 * encoded`.
//!
//! LZ4 then decompresses into an exact-size buffer (at most 256× the payload). Blocks read every
//! block header first and size the buffer only once the headers add up to the announced length,
//! so a payload whose headers do not add up costs no memory. zstd, whose bound
//! is loose, decompresses into a buffer sized from the payload (at most 64×) and, past that, grows
//! the buffer only as real output arrives, up to the announced length: an announced length that the
//! payload does not actually produce costs no memory.

use std::io::Read;

use super::lz4_block::Lz4Error;
use crate::error::WireError;

/// How a section's payload is compressed (the section table's `compression` byte).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Compression {
    /// Stored as is.
    None = 0,
    /// One LZ4 block.
    Lz4 = 1,
    /// One zstd frame.
    Zstd = 2,
    /// Blocks of at most 128 KiB, each Huffman-coded, LZ4, a repeated byte or stored
    /// (`codec/blocks.rs`, docs/wire-format.md §5).
    Blocks = 3,
}

impl Compression {
    /// The wire byte's meaning, if any.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(Compression::None),
            1 => Some(Compression::Lz4),
            2 => Some(Compression::Zstd),
            3 => Some(Compression::Blocks),
            _ => None,
        }
    }

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Compression::None => "none",
            Compression::Lz4 => "lz4",
            Compression::Zstd => "zstd",
            Compression::Blocks => "blocks",
        }
    }

    /// The largest decoded length `encoded` payload bytes can produce; see the module docs.
    pub fn max_decoded(self, encoded: u64) -> u64 {
        match self {
            Compression::None => encoded,
            Compression::Lz4 => encoded.saturating_mul(255).saturating_add(255),
            Compression::Zstd => encoded.saturating_mul(32_768),
            Compression::Blocks => encoded.saturating_mul(super::blocks::MAX_EXPANSION),
        }
    }
}

/// A compressor's output buffer, kept from section to section and frame to frame, so that a
/// stream of frames compresses into memory it already has: no fresh pages for the kernel to
/// zero, and no copy into an exact-size vector.
#[derive(Debug, Default)]
pub(crate) struct Packer {
    /// LZ4's worst-case output for the largest section so far; zstd's last output; the blocks'
    /// payload.
    out: Vec<u8>,
    /// The blocks' own outputs.
    blocks: super::blocks::BlockPacker,
}

impl Packer {
    /// Compresses `data` with `method` (`level` is zstd's), or stores it when compression would
    /// not make it smaller. Returns the method actually used and the payload: this packer's
    /// output, or `data` itself when stored. The bytes are those of lz4_flex's and zstd's
    /// one-shot `compress`.
    ///
    /// `planes` is how many planes of equal length `data` holds (the deep layout's depths and
    /// colours: 4; else 1); the blocks compression keeps each block within one plane.
    pub(crate) fn pack<'a>(
        &'a mut self,
        data: &'a [u8],
        method: Compression,
        level: i32,
        planes: usize,
    ) -> Result<(Compression, &'a [u8]), WireError> {
        let packed = match method {
            Compression::None => None,
            Compression::Lz4 => {
                let max = lz4_flex::block::get_maximum_output_size(data.len());
                if self.out.len() < max {
                    // Zeroes only the part never used before.
                    self.out.resize(max, 0);
                }
                let n = lz4_flex::block::compress_into(data, &mut self.out)
                    .map_err(|e| WireError::Encode(format!("lz4: {e}")))?;
                Some(n)
            }
            Compression::Zstd => {
                self.out = zstd::bulk::compress(data, level)
                    .map_err(|e| WireError::Encode(format!("zstd level {level}: {e}")))?;
                Some(self.out.len())
            }
            Compression::Blocks => {
                self.blocks.pack(data, planes, &mut self.out);
                Some(self.out.len())
            }
        };
        Ok(match packed {
            Some(n) if n < data.len() => (method, &self.out[..n]),
            _ => (Compression::None, data),
        })
    }
}

/// [`Packer::pack`] into a fresh packer, the payload copied out.
#[cfg(test)]
pub(crate) fn compress(
    data: &[u8],
    method: Compression,
    level: i32,
) -> Result<(Compression, Vec<u8>), WireError> {
    let mut packer = Packer::default();
    let (used, payload) = packer.pack(data, method, level, 1)?;
    Ok((used, payload.to_vec()))
}

/// LZ4 sections that decode to at least this many bytes per payload byte are mostly runs of
/// one byte, and go to [`super::lz4_block`], which copies a run at a time; the others to
/// lz4_flex's decoder, whose unchecked 16-byte copies are faster on short sequences. Measured
/// on the deep layout's sections of 1280×720 dragon and armadillo frames (AMD EPYC, one core
/// each): counts (20–40 : 1) 0.65–0.70 → 0.20–0.36 ms, depths (3.4 : 1) 0.61–2.66 →
/// 0.33–1.06 ms, colours (1.9 : 1) 0.62–3.05 ms with lz4_flex against 0.82–3.27 with
/// `lz4_block`.
const RUNS_RATIO: usize = 3;

/// Why an LZ4 block did not decode to its announced length.
pub(crate) enum Lz4Failure {
    /// It ended after this many bytes.
    Short(usize),
    /// It went on past them.
    Long,
    /// It is not LZ4.
    Broken(String),
}

/// Decodes one LZ4 block into exactly `out.len()` bytes, by the decoder that is faster for its
/// ratio ([`RUNS_RATIO`]).
pub(crate) fn decompress_lz4(payload: &[u8], out: &mut [u8]) -> Result<(), Lz4Failure> {
    if out.len() >= RUNS_RATIO * payload.len() {
        return super::lz4_block::decompress_into(payload, out).map_err(|e| match e {
            Lz4Error::TooShort { produced } => Lz4Failure::Short(produced),
            Lz4Error::TooLong => Lz4Failure::Long,
            e => Lz4Failure::Broken(e.to_string()),
        });
    }
    let n = lz4_flex::block::decompress_into(payload, out).map_err(|e| match e {
        lz4_flex::block::DecompressError::OutputTooSmall { .. } => Lz4Failure::Long,
        e => Lz4Failure::Broken(e.to_string()),
    })?;
    if n != out.len() {
        return Err(Lz4Failure::Short(n));
    }
    Ok(())
}

/// Initial output buffer of a zstd section, as a multiple of its payload.
const ZSTD_PREALLOC_RATIO: usize = 64;

/// Decompresses one section payload into exactly `decoded_len` bytes.
///
/// The caller has checked `decoded_len <= method.max_decoded(payload.len())` and the decoder
/// limits; this checks that the payload really produces `decoded_len` bytes, no more, no fewer.
#[cfg(test)]
pub(crate) fn decompress(
    payload: &[u8],
    method: Compression,
    decoded_len: usize,
    section: &'static str,
    offset: u64,
) -> Result<Vec<u8>, WireError> {
    let mut out = Vec::new();
    decompress_into(payload, method, decoded_len, section, offset, &mut out)?;
    Ok(out)
}

/// [`decompress`] into `out`, whose allocation (and, for LZ4, whose bytes: every one is
/// overwritten) is reused: a decoder keeps one such buffer per section between frames.
pub(crate) fn decompress_into(
    payload: &[u8],
    method: Compression,
    decoded_len: usize,
    section: &'static str,
    offset: u64,
    out: &mut Vec<u8>,
) -> Result<(), WireError> {
    let wrong_length = |got: &dyn std::fmt::Display| {
        WireError::section(
            section,
            offset,
            format!("decompresses to {got} bytes, the section table says {decoded_len}"),
        )
    };
    match method {
        Compression::None => {
            if payload.len() != decoded_len {
                return Err(wrong_length(&payload.len()));
            }
            out.clear();
            out.extend_from_slice(payload);
            Ok(())
        }
        Compression::Lz4 => {
            // Zeroes only what the buffer grows by; LZ4 writes every byte it reports.
            out.resize(decoded_len, 0);
            decompress_lz4(payload, out).map_err(|e| match e {
                Lz4Failure::Short(n) => wrong_length(&n),
                Lz4Failure::Long => wrong_length(&format!("more than {decoded_len}")),
                Lz4Failure::Broken(m) => WireError::section(section, offset, format!("lz4: {m}")),
            })
        }
        Compression::Blocks => super::blocks::decode_into(payload, decoded_len, out, &|m| {
            WireError::section(section, offset, m)
        }),
        Compression::Zstd => {
            let initial = decoded_len.min(payload.len().saturating_mul(ZSTD_PREALLOC_RATIO));
            if initial == decoded_len {
                // Small enough to trust: one call into a slice of exactly `decoded_len` bytes
                // (whatever the buffer held before), which bounds the output.
                out.resize(decoded_len, 0);
                let n = zstd::bulk::Decompressor::new()
                    .and_then(|mut d| d.decompress_to_buffer(payload, &mut out[..]))
                    .map_err(|e| {
                        WireError::section(
                            section,
                            offset,
                            format!("zstd: {e} (or more than {decoded_len} bytes)"),
                        )
                    })?;
                if n != decoded_len {
                    return Err(wrong_length(&n));
                }
                return Ok(());
            }
            out.clear();
            // A large announced expansion: let the buffer grow only with real output.
            let decoder = zstd::stream::read::Decoder::with_buffer(payload)
                .map_err(|e| WireError::section(section, offset, format!("zstd: {e}")))?;
            let mut limited = decoder.take(decoded_len as u64 + 1);
            limited
                .read_to_end(out)
                .map_err(|e| WireError::section(section, offset, format!("zstd: {e}")))?;
            if out.len() > decoded_len {
                return Err(wrong_length(&format!("more than {decoded_len}")));
            }
            if out.len() != decoded_len {
                return Err(wrong_length(&out.len()));
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<u8> {
        (0..100_000u32).map(|i| (i / 7 % 13) as u8).collect()
    }

    /// Noise with every other 8-byte group repeating the one before: LZ4 halves it, below
    /// the ratio at which `lz4_block` takes over, so lz4_flex decodes it.
    fn noisy() -> Vec<u8> {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut v: Vec<u8> = Vec::with_capacity(100_000);
        while v.len() < 100_000 {
            let group: Vec<u8> = (0..8)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    x as u8
                })
                .collect();
            v.extend(&group);
            v.extend(&group);
        }
        v
    }

    #[test]
    fn both_lz4_decoders_are_used_and_agree_on_lengths() {
        for (data, runs) in [(sample(), true), (noisy(), false)] {
            let (used, p) = compress(&data, Compression::Lz4, 0).expect("compresses");
            assert_eq!(used, Compression::Lz4);
            assert_eq!(
                data.len() >= RUNS_RATIO * p.len(),
                runs,
                "{} -> {}",
                data.len(),
                p.len()
            );
            assert_eq!(
                decompress(&p, used, data.len(), "t", 0).expect("decodes"),
                data
            );
            for len in [data.len() - 1, data.len() + 1] {
                let e = decompress(&p, used, len, "t", 0).expect_err("wrong length");
                assert!(e.to_string().contains("the section table says"), "{e}");
            }
        }
    }

    #[test]
    fn a_reused_buffer_decodes_like_a_fresh_one() {
        // A buffer left longer and dirtier by an earlier section: the same bytes, the same
        // errors, for every method.
        let data = sample();
        for method in [Compression::None, Compression::Lz4, Compression::Zstd] {
            let (used, payload) = compress(&data, method, 3).expect("compresses");
            let mut reused = vec![0xee; 3 * data.len()];
            decompress_into(&payload, used, data.len(), "s", 0, &mut reused).expect("decodes");
            assert_eq!(reused, data, "{method:?}");
            for wrong in [data.len() - 1, data.len() + 1] {
                let mut reused = vec![0xee; 3 * data.len()];
                let fresh = decompress(&payload, used, wrong, "s", 0).map(|_| ());
                let again = decompress_into(&payload, used, wrong, "s", 0, &mut reused);
                assert!(fresh.is_err(), "{method:?}, {wrong}");
                assert_eq!(again, fresh, "{method:?}, {wrong}");
            }
        }
    }

    #[test]
    fn a_reused_packer_writes_what_the_one_shot_compressors_write() {
        // Sections that shrink and grow through one packer: its buffer holds longer, older
        // output past each payload, which must not leak into it.
        let (big, small) = (noisy(), sample());
        let mut packer = Packer::default();
        for data in [&big, &small, &big[..1000].to_vec(), &small, &big] {
            let (used, payload) = packer.pack(data, Compression::Lz4, 0, 1).unwrap();
            assert_eq!(used, Compression::Lz4);
            assert_eq!(payload, lz4_flex::block::compress(data));
            let (used, payload) = packer.pack(data, Compression::Zstd, 3, 1).unwrap();
            assert_eq!(used, Compression::Zstd);
            assert_eq!(payload, zstd::bulk::compress(data, 3).unwrap());
            let mut fresh = Vec::new();
            super::super::blocks::BlockPacker::default().pack(data, 1, &mut fresh);
            let (used, payload) = packer.pack(data, Compression::Blocks, 0, 1).unwrap();
            if fresh.len() < data.len() {
                assert_eq!((used, payload), (Compression::Blocks, &fresh[..]));
            } else {
                assert_eq!((used, payload), (Compression::None, &data[..]));
            }
        }
        // Stored: the payload is the data itself.
        let tiny = [1u8, 2, 3];
        let (used, payload) = packer.pack(&tiny, Compression::Lz4, 0, 1).unwrap();
        assert_eq!((used, payload), (Compression::None, &tiny[..]));
    }

    #[test]
    fn every_method_round_trips() {
        let data = sample();
        for m in [Compression::None, Compression::Lz4, Compression::Zstd] {
            let (used, p) = compress(&data, m, 3).unwrap();
            assert_eq!(used, m);
            assert!(used.max_decoded(p.len() as u64) >= data.len() as u64);
            assert_eq!(decompress(&p, used, data.len(), "t", 0).unwrap(), data);
        }
    }

    #[test]
    fn incompressible_data_is_stored() {
        let data = [7u8; 3];
        let (used, p) = compress(&data, Compression::Zstd, 3).unwrap();
        assert_eq!((used, p.as_slice()), (Compression::None, &data[..]));
    }

    #[test]
    fn a_wrong_decoded_length_is_an_error_either_way() {
        let data = sample();
        for m in [Compression::Lz4, Compression::Zstd] {
            let (_, p) = compress(&data, m, 3).unwrap();
            for len in [data.len() - 1, data.len() + 1, 0] {
                assert!(
                    decompress(&p, m, len, "t", 0).is_err(),
                    "{m:?} with {len} bytes announced"
                );
            }
        }
    }

    #[test]
    fn a_zstd_bomb_is_cut_at_the_announced_length() {
        let data = vec![0u8; 4 << 20];
        let (_, p) = compress(&data, Compression::Zstd, 3).unwrap();
        assert!(
            p.len() * ZSTD_PREALLOC_RATIO < data.len(),
            "takes the streaming path"
        );
        assert!(decompress(&p, Compression::Zstd, 1 << 20, "t", 0).is_err());
        assert_eq!(
            decompress(&p, Compression::Zstd, data.len(), "t", 0).unwrap(),
            data
        );
    }

    #[test]
    fn garbage_is_an_error() {
        let junk: Vec<u8> = (0..64).map(|i| (i * 37 + 11) as u8).collect();
        assert!(decompress(&junk, Compression::Zstd, 1000, "t", 0).is_err());
        assert!(decompress(&junk, Compression::Lz4, 1000, "t", 0).is_err());
    }
}
