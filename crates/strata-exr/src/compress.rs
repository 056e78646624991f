//! The four compressions deep scanline files allow: NONE, RLE, ZIPS and ZIP.
//!
//! RLE, ZIPS and ZIP share OpenEXR's byte preconditioner before the entropy stage:
//!
//! ```text
//! raw:        b0 b1 b2 b3 b4 b5 …
//! interleave: b0 b2 b4 … | b1 b3 b5 …     (even bytes, then odd bytes: the low and high bytes
//!                                          of little-endian halves end up in separate runs)
//! predict:    t0, t1-t0+128, t2-t1+128 …  (wrapping u8 deltas)
//! then        RLE: runs of (count-1, byte) for ≥3 equal bytes, (-count, bytes…) otherwise
//!             ZIP/ZIPS: zlib (RFC 1950)
//! ```
//!
//! ZIPS and ZIP differ only in how many scanlines a chunk holds (1 and 16). A block whose
//! compressed form is not smaller than the raw bytes is stored raw; a reader recognises that by
//! `packed size == unpacked size`. Decompression writes into a buffer of exactly the announced
//! size and fails if the stream would produce more or fewer bytes, so a hostile chunk can never
//! make it allocate more than the size the caller already checked against its limits.

use flate2::{Decompress, FlushDecompress, Status};

/// Compression of the pixel data, the header's `compression` attribute.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Compression {
    /// Raw bytes.
    None,
    /// Run-length encoding, one scanline per chunk.
    Rle,
    /// zlib, one scanline per chunk (the default).
    #[default]
    Zips,
    /// zlib, 16 scanlines per chunk (flat files; see [`crate::write_deep`] for deep files).
    Zip,
}

impl Compression {
    /// All four, in OpenEXR's code order.
    pub const ALL: [Compression; 4] = [
        Compression::None,
        Compression::Rle,
        Compression::Zips,
        Compression::Zip,
    ];

    /// The code stored in the `compression` attribute.
    pub fn code(self) -> u8 {
        match self {
            Compression::None => 0,
            Compression::Rle => 1,
            Compression::Zips => 2,
            Compression::Zip => 3,
        }
    }

    /// Scanlines per chunk.
    pub fn lines_per_chunk(self) -> usize {
        match self {
            Compression::Zip => 16,
            _ => 1,
        }
    }

    /// The name OpenEXR tools print (`none`, `rle`, `zips`, `zip`).
    pub fn name(self) -> &'static str {
        match self {
            Compression::None => "none",
            Compression::Rle => "rle",
            Compression::Zips => "zips",
            Compression::Zip => "zip",
        }
    }
}

/// OpenEXR's names for the compression codes strata cannot decode, for error messages.
pub(crate) fn unsupported_name(code: u8) -> &'static str {
    match code {
        4 => "PIZ",
        5 => "PXR24",
        6 => "B44",
        7 => "B44A",
        8 => "DWAA",
        9 => "DWAB",
        10 => "HTJ2K256",
        11 => "HTJ2K32",
        _ => "unknown",
    }
}

/// zlib level: OpenEXR's default.
const ZLIB_LEVEL: u32 = 4;
const MIN_RUN: usize = 3;
const MAX_RUN: usize = 127;

/// Compresses one block; returns the raw bytes when compression does not make them smaller.
pub(crate) fn compress(compression: Compression, raw: &[u8]) -> Vec<u8> {
    let packed = match compression {
        Compression::None => return raw.to_vec(),
        Compression::Rle => rle_encode(&predict(raw)),
        Compression::Zips | Compression::Zip => zlib_encode(&predict(raw)),
    };
    if packed.len() >= raw.len() {
        raw.to_vec()
    } else {
        packed
    }
}

/// Why a block did not decompress (the caller adds the chunk and the block's name).
#[derive(Debug)]
pub(crate) struct DecodeError(pub(crate) String);

/// Decompresses one block of exactly `unpacked` bytes (already checked against the limits).
pub(crate) fn decompress(
    compression: Compression,
    packed: &[u8],
    unpacked: usize,
) -> Result<Vec<u8>, DecodeError> {
    if packed.len() == unpacked || unpacked == 0 {
        return Ok(packed[..unpacked.min(packed.len())].to_vec());
    }
    let mut out = vec![0u8; unpacked];
    match compression {
        Compression::None => {
            return Err(DecodeError(format!(
                "uncompressed block is {} bytes, expected {unpacked}",
                packed.len()
            )));
        }
        Compression::Rle => rle_decode(packed, &mut out)?,
        Compression::Zips | Compression::Zip => zlib_decode(packed, &mut out)?,
    }
    Ok(unpredict(&out))
}

fn predict(raw: &[u8]) -> Vec<u8> {
    let half = raw.len().div_ceil(2);
    let mut t = vec![0u8; raw.len()];
    for (i, &b) in raw.iter().enumerate() {
        let j = if i % 2 == 0 { i / 2 } else { half + i / 2 };
        t[j] = b;
    }
    let mut prev = t.first().copied().unwrap_or(0);
    for b in t.iter_mut().skip(1) {
        let cur = *b;
        *b = cur.wrapping_sub(prev).wrapping_add(128);
        prev = cur;
    }
    t
}

fn unpredict(t: &[u8]) -> Vec<u8> {
    let mut d = t.to_vec();
    for i in 1..d.len() {
        d[i] = d[i - 1].wrapping_add(d[i]).wrapping_sub(128);
    }
    let half = d.len().div_ceil(2);
    (0..d.len())
        .map(|i| {
            if i % 2 == 0 {
                d[i / 2]
            } else {
                d[half + i / 2]
            }
        })
        .collect()
}

fn rle_encode(src: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(src.len() / 2 + 16);
    let mut i = 0;
    while i < src.len() {
        let run = run_length(&src[i..]);
        if run >= MIN_RUN {
            out.push((run - 1) as u8);
            out.push(src[i]);
            i += run;
        } else {
            let start = i;
            while i < src.len() && i - start < MAX_RUN && run_length(&src[i..]) < MIN_RUN {
                i += 1;
            }
            out.push((-((i - start) as i32)) as i8 as u8);
            out.extend_from_slice(&src[start..i]);
        }
    }
    out
}

/// Length of the run of equal bytes at the start of `s`, at most [`MAX_RUN`] + 1.
fn run_length(s: &[u8]) -> usize {
    let first = s[0];
    s.iter()
        .take(MAX_RUN + 1)
        .take_while(|&&b| b == first)
        .count()
}

fn rle_decode(packed: &[u8], out: &mut [u8]) -> Result<(), DecodeError> {
    let (mut i, mut o) = (0usize, 0usize);
    while i < packed.len() {
        let n = packed[i] as i8;
        i += 1;
        if n < 0 {
            let count = usize::from(n.unsigned_abs());
            let src = packed.get(i..i + count).ok_or_else(|| {
                DecodeError(format!(
                    "RLE literal run at byte {} passes the block's end",
                    i - 1
                ))
            })?;
            let dst = out.get_mut(o..o + count).ok_or_else(|| {
                DecodeError("RLE data expands past the announced size".to_owned())
            })?;
            dst.copy_from_slice(src);
            i += count;
            o += count;
        } else {
            let count = n as usize + 1;
            let &value = packed.get(i).ok_or_else(|| {
                DecodeError(format!("RLE repeat at byte {} has no value byte", i - 1))
            })?;
            let dst = out.get_mut(o..o + count).ok_or_else(|| {
                DecodeError("RLE data expands past the announced size".to_owned())
            })?;
            dst.fill(value);
            i += 1;
            o += count;
        }
    }
    if o != out.len() {
        return Err(DecodeError(format!(
            "RLE data expands to {o} bytes, expected {}",
            out.len()
        )));
    }
    Ok(())
}

fn zlib_encode(src: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut enc = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(src.len() / 2 + 64),
        flate2::Compression::new(ZLIB_LEVEL),
    );
    // Writing into a Vec cannot fail.
    let _ = enc.write_all(src);
    enc.finish().unwrap_or_default()
}

fn zlib_decode(packed: &[u8], out: &mut [u8]) -> Result<(), DecodeError> {
    let mut z = Decompress::new(true);
    let status = z
        .decompress(packed, out, FlushDecompress::Finish)
        .map_err(|e| DecodeError(format!("zlib data is corrupt: {e}")))?;
    if status != Status::StreamEnd || z.total_out() != out.len() as u64 {
        return Err(DecodeError(format!(
            "zlib data does not expand to exactly the announced {} bytes",
            out.len()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_bytes() -> Vec<u8> {
        let mut v: Vec<u8> = (0..300u32).flat_map(|i| (i / 7).to_le_bytes()).collect();
        v.extend(std::iter::repeat_n(9u8, 400));
        v.extend((0..77u8).map(|i| i.wrapping_mul(37)));
        v
    }

    #[test]
    fn predictor_inverts() {
        for len in [0, 1, 2, 3, 10, 11] {
            let raw: Vec<u8> = (0..len as u8).map(|i| i.wrapping_mul(91)).collect();
            assert_eq!(unpredict(&predict(&raw)), raw);
        }
    }

    #[test]
    fn every_compression_round_trips() {
        let raw = sample_bytes();
        for c in Compression::ALL {
            let packed = compress(c, &raw);
            if c != Compression::None {
                assert!(
                    packed.len() < raw.len(),
                    "{c:?} did not shrink compressible data"
                );
            }
            assert_eq!(decompress(c, &packed, raw.len()).unwrap(), raw, "{c:?}");
        }
    }

    #[test]
    fn incompressible_blocks_are_stored_raw() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let raw: Vec<u8> = (0..64)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 24) as u8
            })
            .collect();
        for c in [Compression::Rle, Compression::Zip] {
            assert_eq!(compress(c, &raw), raw);
        }
    }

    #[test]
    fn rle_rejects_overlong_runs() {
        // A repeat of 128 bytes where 4 were announced.
        let err = rle_decode(&[127, 1], &mut [0u8; 4]).unwrap_err();
        assert!(err.0.contains("past the announced size"), "{}", err.0);
        let err = rle_decode(&[(-5i8) as u8, 1, 2], &mut [0u8; 5]).unwrap_err();
        assert!(err.0.contains("passes the block's end"), "{}", err.0);
    }

    #[test]
    fn zlib_rejects_wrong_sizes() {
        let raw = sample_bytes();
        let packed = compress(Compression::Zip, &raw);
        assert!(decompress(Compression::Zip, &packed, raw.len() - 1).is_err());
        assert!(decompress(Compression::Zip, &packed, raw.len() + 1).is_err());
    }
}
