//! The `blocks` compression: a section cut into blocks of at most 128 KiB, each coded the way
//! that makes it smallest of those tried — a canonical Huffman code ([`super::huffman`]), one
//! LZ4 block, one repeated byte, or stored — and coded and decoded in parallel.
//!
//! The deep layout's sections mix two kinds of bytes: runs (the counts, the high bytes of depth
//! residuals, a constant alpha), which LZ4 shrinks 10 to 250 times, and noise around zero (the
//! colour residuals, the low byte of depth residuals), where LZ4 keeps 53–100 % and takes most
//! of its time, and a byte-wise entropy code keeps 24–75 % at a fixed cost a byte. Choosing per
//! block gets both. A section of the deep layout's byte planes (`planes` = 4) is cut at its
//! plane boundaries first, so that no block mixes two planes' statistics.
//!
//! # Layout
//!
//! ```text
//! payload := block*            (none for an empty section)
//! block   := kind u8 | decoded_len u32 LE | encoded_len u32 LE | encoded_len bytes
//!   kind 0 stored    the bytes themselves (encoded_len = decoded_len)
//!   kind 1 fill      one byte, repeated decoded_len times (encoded_len = 1)
//!   kind 2 lz4       one LZ4 block
//!   kind 3 huffman   a Huffman block (super::huffman's layout)
//! ```
//!
//! `decoded_len` is 1 to [`MAX_BLOCK`]; the blocks' decoded lengths add up to the section
//! table's, and the last block ends where the payload does. A section of `n` bytes has at most
//! `n / MAX_BLOCK + 5` blocks (the encoder cuts at most 4 planes into near-equal blocks), and an
//! LZ4 block has at least 2 coded bytes (a token and a literal), so a payload's headers cannot
//! make the decoder keep more than a few entries a 128 KiB of output. The decoder reads every
//! header before it sizes the output, then decodes the blocks in parallel.
//!
//! # Choosing a block's coding
//!
//! The encoder first counts the bytes that repeat the byte before them (a sum of comparisons
//! in vector lanes). All of them: a `fill`. At least three quarters (runs, which only LZ4 can
//! take below a bit a byte; on a dragon frame's planes the fraction is 0.92–1.0 for the counts
//! and the high depth bytes and 0.04–0.47 for the noisy planes): LZ4 is tried, and kept at once
//! if it is under a bit a byte. Otherwise the block's byte values are counted, a Huffman code
//! built, its size bounded from the counts (exact but for each stream's padding, at most three
//! bytes), and the smallest of LZ4 (if tried), that bound and the bytes themselves is kept.
//! The choice depends only on the block's bytes, so the output is the same for any thread
//! count.

use rayon::prelude::*;

use super::compress::{Lz4Failure, decompress_lz4};
use super::huffman;
use crate::error::WireError;

/// The largest block, in decoded bytes; the encoder cuts each plane into near-equal blocks of
/// at most this size.
pub(crate) const MAX_BLOCK: usize = 128 * 1024;
/// Bytes of a block's header.
const BLOCK_HEADER: usize = 9;
/// The most bytes one payload byte can decode to: a `fill` block of [`MAX_BLOCK`] bytes takes
/// ten payload bytes.
pub(crate) const MAX_EXPANSION: u64 = (MAX_BLOCK / (BLOCK_HEADER + 1) + 1) as u64;

/// How a block is coded (its `kind` byte).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Stored = 0,
    Fill = 1,
    Lz4 = 2,
    Huffman = 3,
}

impl Kind {
    fn from_byte(b: u8) -> Option<Kind> {
        Some(match b {
            0 => Kind::Stored,
            1 => Kind::Fill,
            2 => Kind::Lz4,
            3 => Kind::Huffman,
            _ => return None,
        })
    }
}

/// Per-block output buffers and the length of each one's block, kept from frame to frame (a
/// buffer is only ever grown, so it is zeroed once, not at every frame).
#[derive(Debug, Default)]
pub(crate) struct BlockPacker {
    blocks: Vec<(Vec<u8>, usize)>,
}

impl BlockPacker {
    /// Codes `data`, `planes` planes of equal length (1 if its length is not a multiple), into
    /// `out` (cleared first).
    pub(crate) fn pack(&mut self, data: &[u8], planes: usize, out: &mut Vec<u8>) {
        let cuts = cuts(data.len(), planes);
        if self.blocks.len() < cuts.len() {
            self.blocks.resize_with(cuts.len(), Default::default);
        }
        (cuts.par_iter())
            .zip(self.blocks.par_iter_mut())
            .for_each(|(r, (buf, len))| *len = encode_block(&data[r.clone()], buf));
        out.clear();
        for (b, len) in &self.blocks[..cuts.len()] {
            out.extend_from_slice(&b[..*len]);
        }
    }
}

/// The blocks of `n` bytes in `planes` planes: each plane cut into the fewest near-equal
/// blocks of at most [`MAX_BLOCK`].
fn cuts(n: usize, planes: usize) -> Vec<std::ops::Range<usize>> {
    let planes = if planes > 1 && n.is_multiple_of(planes) {
        planes
    } else {
        1
    };
    let plane = n / planes;
    let mut out = Vec::new();
    if plane == 0 {
        return out;
    }
    let k = plane.div_ceil(MAX_BLOCK);
    for p in 0..planes {
        let base = p * plane;
        for i in 0..k {
            out.push(base + plane * i / k..base + plane * (i + 1) / k);
        }
    }
    out
}

/// The most blocks a section of `n` bytes may have: [`cuts`] makes at most 4 planes of
/// `⌈(n / planes) / MAX_BLOCK⌉` blocks each, fewer than `n / MAX_BLOCK + 5`.
fn max_blocks(n: usize) -> usize {
    n / MAX_BLOCK + 5
}

/// Writes a block header at the start of `buf`.
fn header(buf: &mut [u8], kind: Kind, decoded: usize, encoded: usize) {
    buf[0] = kind as u8;
    buf[1..5].copy_from_slice(&(decoded as u32).to_le_bytes());
    buf[5..BLOCK_HEADER].copy_from_slice(&(encoded as u32).to_le_bytes());
}

/// How many bytes of `src` equal the byte before them (in lanes: a sum of comparisons).
fn repeats(src: &[u8]) -> usize {
    let (a, b) = (&src[1..], &src[..src.len() - 1]);
    (a.chunks(4096).zip(b.chunks(4096)))
        .map(|(x, y)| x.iter().zip(y).map(|(p, q)| u32::from(p == q)).sum::<u32>() as usize)
        .sum()
}

/// Writes one block, header included, at the start of `buf` (grown if it is too small for the
/// largest coding, never shrunk or cleared) and returns its length; see the module docs for
/// the choice.
fn encode_block(src: &[u8], buf: &mut Vec<u8>) -> usize {
    let n = src.len();
    let room =
        BLOCK_HEADER + lz4_flex::block::get_maximum_output_size(n).max(huffman::encode_room(n));
    if buf.len() < room {
        buf.resize(room, 0);
    }
    let repeats = repeats(src);
    if repeats + 1 == n {
        header(buf, Kind::Fill, n, 1);
        buf[BLOCK_HEADER] = src[0];
        return BLOCK_HEADER + 1;
    }
    let mut lz4 = None;
    if repeats * 4 >= (n - 1) * 3 {
        // Cannot fail: the output has LZ4's worst-case size.
        if let Ok(len) = lz4_flex::block::compress_into(src, &mut buf[BLOCK_HEADER..]) {
            // Below a bit a byte, which a Huffman code cannot reach: no need to count.
            if len * 8 < n {
                header(buf, Kind::Lz4, n, len);
                return BLOCK_HEADER + len;
            }
            lz4 = Some(len);
        }
    }
    let counts = huffman::histogram(src);
    let lengths = huffman::code_lengths(&counts);
    let bits = huffman::code_bits(&counts, &lengths);
    let huffman_len = huffman::max_coded_len(bits);
    let (kind, len) = match lz4 {
        Some(len) if len <= huffman_len && len < n => (Kind::Lz4, len),
        _ if huffman_len < n => {
            let len = huffman::encode(src, &lengths, &mut buf[BLOCK_HEADER..]);
            (Kind::Huffman, len)
        }
        _ => {
            buf[BLOCK_HEADER..BLOCK_HEADER + n].copy_from_slice(src);
            (Kind::Stored, n)
        }
    };
    header(buf, kind, n, len);
    BLOCK_HEADER + len
}

/// One block as found in a payload.
struct Found<'a> {
    kind: Kind,
    decoded: usize,
    payload: &'a [u8],
    /// Where the block's header starts in the section payload.
    at: usize,
}

/// Decodes a `blocks` payload into `out`, resized to the section's `decoded_len` once every
/// block header has been read and found to add up to it (so a lying payload costs no memory;
/// only what the buffer grows by is zeroed, and the blocks write every byte). `what` turns a
/// message into the section's error.
pub(crate) fn decode_into(
    payload: &[u8],
    decoded_len: usize,
    out: &mut Vec<u8>,
    what: &(dyn Fn(String) -> WireError + Sync),
) -> Result<(), WireError> {
    let mut found = Vec::new();
    let (mut at, mut total) = (0usize, 0usize);
    let most = max_blocks(decoded_len);
    while at < payload.len() {
        if found.len() == most {
            return Err(what(format!(
                "more than {most} blocks for {decoded_len} bytes (the most a section of that \
                 length is cut into)"
            )));
        }
        let Some(h) = payload.get(at..at + BLOCK_HEADER) else {
            return Err(what(format!(
                "block at byte {at} of the payload: {} bytes left, a block header takes {BLOCK_HEADER}",
                payload.len() - at
            )));
        };
        let u32_at = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]) as usize;
        let (decoded, encoded) = (u32_at(1), u32_at(5));
        let block = |m: String| what(format!("block at byte {at} of the payload: {m}"));
        let kind = Kind::from_byte(h[0])
            .ok_or_else(|| block(format!("unknown block kind {} (0 to 3)", h[0])))?;
        if decoded == 0 || decoded > MAX_BLOCK {
            return Err(block(format!("{decoded} decoded bytes (1 to {MAX_BLOCK})")));
        }
        let body = at + BLOCK_HEADER;
        let Some(bytes) = payload.get(body..body.saturating_add(encoded)) else {
            return Err(block(format!(
                "{encoded} coded bytes announced, {} left",
                payload.len() - body
            )));
        };
        let fits = match kind {
            Kind::Stored => encoded == decoded,
            Kind::Fill => encoded == 1,
            Kind::Lz4 => {
                encoded >= 2
                    && decoded as u64
                        <= super::compress::Compression::Lz4.max_decoded(encoded as u64)
            }
            Kind::Huffman => encoded >= huffman::HEADER,
        };
        if !fits {
            return Err(block(format!(
                "{kind:?} block of {encoded} coded bytes cannot decode to {decoded}"
            )));
        }
        total += decoded;
        if total > decoded_len {
            return Err(what(format!(
                "blocks decode to more than the {decoded_len} bytes the section table says"
            )));
        }
        found.push(Found {
            kind,
            decoded,
            payload: bytes,
            at,
        });
        at = body + encoded;
    }
    if total != decoded_len {
        return Err(what(format!(
            "blocks decode to {total} bytes, the section table says {decoded_len}"
        )));
    }
    out.resize(decoded_len, 0);
    let mut slices = Vec::with_capacity(found.len());
    let mut rest = &mut out[..];
    for f in &found {
        let (head, tail) = rest.split_at_mut(f.decoded);
        slices.push(head);
        rest = tail;
    }
    // Largest coded blocks first would balance better; they are near-equal within a plane.
    let results: Vec<Result<(), WireError>> = (found.par_iter())
        .zip(slices.into_par_iter())
        .map(|(f, dst)| decode_block(f, dst, what))
        .collect();
    results.into_iter().collect()
}

fn decode_block(
    f: &Found<'_>,
    dst: &mut [u8],
    what: &(dyn Fn(String) -> WireError + Sync),
) -> Result<(), WireError> {
    let block = |m: String| what(format!("block at byte {} of the payload: {m}", f.at));
    match f.kind {
        Kind::Stored => dst.copy_from_slice(f.payload),
        Kind::Fill => dst.fill(f.payload[0]),
        Kind::Lz4 => decompress_lz4(f.payload, dst).map_err(|e| {
            block(match e {
                Lz4Failure::Short(n) => format!("lz4 decodes to {n} bytes, not {}", f.decoded),
                Lz4Failure::Long => format!("lz4 decodes to more than {} bytes", f.decoded),
                Lz4Failure::Broken(m) => format!("lz4: {m}"),
            })
        })?,
        Kind::Huffman => huffman::decode(f.payload, dst, &block)?,
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::huffman::tests::noise;
    use super::*;

    fn err(m: String) -> WireError {
        WireError::Encode(m)
    }

    fn round_trip(data: &[u8], planes: usize) -> Vec<u8> {
        let mut packed = Vec::new();
        BlockPacker::default().pack(data, planes, &mut packed);
        let mut out = vec![0x5au8; 3];
        decode_into(&packed, data.len(), &mut out, &err).expect("decodes");
        assert_eq!(out, data);
        packed
    }

    /// Four planes of `n` bytes, one for each block kind: noise (Huffman), runs (LZ4), one
    /// value (fill), uniform bytes (stored); `seed` varies the noise.
    fn one_plane_of_each_kind(n: usize, seed: u64) -> Vec<u8> {
        let mut data = noise(n, seed, 7);
        data.extend((0..n).map(|i| (i / 500 % 3) as u8));
        data.extend(std::iter::repeat_n(9u8, n));
        data.extend(noise(n, seed + 1, 256));
        data
    }

    /// Each block's header (where it lies in `packed`) and kind, in order.
    fn block_headers(packed: &[u8]) -> Vec<(std::ops::Range<usize>, u8)> {
        let mut headers = Vec::new();
        let mut at = 0;
        while at < packed.len() {
            headers.push((at..at + BLOCK_HEADER, packed[at]));
            let len = u32::from_le_bytes(packed[at + 5..at + 9].try_into().expect("4 bytes"));
            at += BLOCK_HEADER + len as usize;
        }
        headers
    }

    #[test]
    fn every_kind_is_chosen_where_it_is_smallest() {
        let packed = round_trip(&one_plane_of_each_kind(40_000, 1), 4);
        let kinds: Vec<u8> = block_headers(&packed).into_iter().map(|(_, k)| k).collect();
        assert_eq!(kinds, [3, 2, 1, 0]);
    }

    #[test]
    fn planes_are_cut_into_near_equal_blocks_at_their_boundaries() {
        assert!(cuts(0, 4).is_empty());
        assert_eq!(cuts(10, 4).len(), 1);
        assert_eq!(cuts(10, 4)[0], 0..10);
        assert_eq!(cuts(12, 4), [0..3, 3..6, 6..9, 9..12]);
        let c = cuts(4 * 300_000, 4);
        assert_eq!(c.len(), 4 * 3);
        assert!(c.iter().all(|r| r.len() <= MAX_BLOCK && r.len() >= 99_999));
        assert!(c.windows(2).all(|w| w[0].end == w[1].start));
        // The decoder's bound on the number of blocks holds for what the encoder cuts.
        for n in [
            0,
            1,
            4,
            5,
            4 * MAX_BLOCK,
            4 * MAX_BLOCK + 4,
            9 * MAX_BLOCK + 3,
            1 << 24,
        ] {
            for planes in [1, 4] {
                assert!(
                    cuts(n, planes).len() <= max_blocks(n),
                    "{n} bytes, {planes} planes"
                );
            }
        }
        assert_eq!(c[3].start, 300_000);
        for n in [
            1,
            7,
            MAX_BLOCK - 1,
            MAX_BLOCK,
            MAX_BLOCK + 1,
            3 * MAX_BLOCK + 5,
        ] {
            round_trip(&noise(n, n as u64, 5), 1);
        }
    }

    #[test]
    fn any_thread_count_gives_the_same_bytes() {
        let mut data = noise(3 * MAX_BLOCK + 77, 4, 11);
        data.extend((0..MAX_BLOCK).map(|i| (i / 300 % 2) as u8));
        let pack = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a pool");
            let mut out = Vec::new();
            pool.install(|| BlockPacker::default().pack(&data, 1, &mut out));
            out
        };
        let one = pack(1);
        assert!(one.len() < data.len());
        for threads in [2, 3] {
            assert_eq!(pack(threads), one, "{threads} threads");
        }
    }

    #[test]
    fn changed_bytes_anywhere_in_a_payload_of_every_kind_are_errors_or_decode_never_panic() {
        // Huffman, LZ4, fill and stored blocks.
        let data = one_plane_of_each_kind(6_000, 5);
        let packed = round_trip(&data, 4);
        let (headers, kinds): (Vec<_>, Vec<u8>) = block_headers(&packed).into_iter().unzip();
        assert_eq!(kinds, [3, 2, 1, 0]);
        let mut out = Vec::new();
        let mut body_errors = 0;
        for at in 0..packed.len() {
            for flip in [0x01u8, 0x80, 0xff] {
                let mut bad = packed.clone();
                bad[at] ^= flip;
                let in_header = headers.iter().any(|h| h.contains(&at));
                match decode_into(&bad, data.len(), &mut out, &err) {
                    Err(_) => body_errors += usize::from(!in_header),
                    // A changed header never passes; a changed body byte may still decode (in
                    // stored bytes, an LZ4 literal, a Huffman code of the same length), to
                    // other bytes of the same length.
                    Ok(()) => {
                        assert!(!in_header, "byte {at} ^ {flip:#x} of a header passed");
                        assert_eq!(out.len(), data.len());
                    }
                }
            }
        }
        // The Huffman and LZ4 bodies do catch changes.
        assert!(body_errors > 100, "{body_errors} body errors");
    }

    #[test]
    fn headers_that_cost_memory_without_bytes_are_refused() {
        // A run of header-only LZ4 blocks claiming 255 bytes each: refused at its first block.
        let mut bad = Vec::new();
        for _ in 0..1000 {
            bad.extend([Kind::Lz4 as u8, 255, 0, 0, 0, 0, 0, 0, 0]);
        }
        let mut out = Vec::new();
        let e = decode_into(&bad, 255_000, &mut out, &err).expect_err("no coded bytes");
        assert!(e.to_string().contains("cannot decode"), "{e}");
        // Fills of one byte each: valid blocks, but more than a section of that length has.
        let mut bad = Vec::new();
        for _ in 0..100 {
            bad.extend([Kind::Fill as u8, 1, 0, 0, 0, 1, 0, 0, 0, 7]);
        }
        let e = decode_into(&bad, 100, &mut out, &err).expect_err("too many blocks");
        assert!(e.to_string().contains("more than 5 blocks"), "{e}");
        assert!(out.is_empty());
        // Five are allowed.
        decode_into(&bad[..50], 5, &mut out, &err).expect("five fills");
        assert_eq!(out, [7; 5]);
    }

    #[test]
    fn broken_payloads_are_errors_not_panics() {
        let mut data = noise(50_000, 3, 9);
        data.extend(std::iter::repeat_n(0u8, 50_000));
        let packed = round_trip(&data, 2);
        let n = data.len();
        let mut out = Vec::new();
        for cut in 0..packed.len() {
            assert!(
                decode_into(&packed[..cut], n, &mut out, &err).is_err(),
                "cut at {cut}"
            );
            // Rejected before the output buffer was sized.
            assert!(out.is_empty());
        }
        for at in 0..packed.len().min(400) {
            let mut bad = packed.clone();
            bad[at] = bad[at].wrapping_add(1);
            // Any outcome but a panic; a header change is always caught.
            let r = decode_into(&bad, n, &mut out, &err);
            assert!(at >= BLOCK_HEADER || r.is_err(), "byte {at}");
        }
        // Too long for the section, and too short.
        assert!(decode_into(&packed, n - 1, &mut out, &err).is_err());
        assert!(decode_into(&packed, n + 1, &mut out, &err).is_err());
    }
}
