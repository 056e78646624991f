//! Canonical Huffman coding of a block of bytes in four interleaved bit streams: the entropy
//! coder of the `blocks` compression ([`super::blocks`]).
//!
//! The deep layout's colour residual planes and the low byte of its depth residuals are noisy
//! bytes around zero: on a full-dragon frame their order-0 entropy is 1.9–3.7 bits a byte
//! (colour) and 6 bits (depth), while LZ4, which looks for repeated strings, keeps 53–80 % of
//! the colour planes and cannot shrink the depth plane at all, and spends most of a frame's
//! compression time trying (its colour section: about 7 of the 10 ms of LZ4 a frame on one
//! core). A byte-wise Huffman code reaches within a few percent of that entropy at a fixed
//! cost a byte.
//!
//! # Layout of a coded block (`n` bytes)
//!
//! ```text
//! lengths   128 bytes   code length of byte value 2i in the low nibble of byte i, of 2i+1
//!                       in the high nibble; 0 = value absent; at most MAX_LEN (11)
//! sizes     3 × u32 LE  bytes of streams 0, 1, 2 (stream 3 takes the rest of the payload)
//! streams   4 bit streams; stream j codes bytes [j·q, (j+1)·q) of the block, q = n / 4, and
//!           stream 3 bytes [3q, n); bits are read from each byte's least significant bit up,
//!           a code's first bit first; a stream's last byte is padded with zero bits
//! ```
//!
//! The code is canonical (deflate's assignment: shorter codes first, values in increasing
//! order within a length), so the lengths are the whole table. A block must use at least two
//! values and its lengths must make a complete code (Kraft sum exactly 1): then every 11-bit
//! pattern decodes to a value, and the decoder needs no check per symbol. A block of one value
//! is a `fill` block instead.
//!
//! # Why four streams
//!
//! Decoding a symbol needs the bit position the previous symbol left, so one stream is one
//! dependency chain of table lookups and shifts. Four streams decoded in one loop are four
//! independent chains the CPU overlaps. Each stream's bit buffer is refilled with one 8-byte
//! load (`Bits::refill_fast`: Giesen's branch-free refill, keeping 56–63 bits), enough for five
//! symbols of at most 11 bits. Near a stream's end the loads read zero bytes past it, and the
//! decoder checks at the end that each stream's codes ended in its last byte and that the bits
//! after them in that byte are zero.
//!
//! Lengths are limited to 11 bits so the decoding table (2,048 entries of two bytes) stays in
//! L1; lengths above that are folded in as deflate encoders do (counting codes by length,
//! moving the excess down, reassigning by frequency), which costs well under 1 % on these
//! planes.

use crate::error::WireError;

/// Longest code, in bits.
pub(crate) const MAX_LEN: u32 = 11;
/// Entries of the decoding table.
const TABLE: usize = 1 << MAX_LEN;
/// Bit streams a block is cut into.
pub(crate) const STREAMS: usize = 4;
/// Bytes before the streams: the lengths' nibbles and the sizes of the first three streams.
pub(crate) const HEADER: usize = 128 + 4 * (STREAMS - 1);

/// Symbols of stream `j` of a block of `n` bytes.
fn stream_range(n: usize, j: usize) -> std::ops::Range<usize> {
    let q = n / STREAMS;
    let end = if j + 1 == STREAMS { n } else { (j + 1) * q };
    j * q..end
}

/// Byte counts of `data`, kept in four histograms (consecutive bytes increment different
/// counters, so the increments do not wait on each other) and added up.
pub(crate) fn histogram(data: &[u8]) -> [u32; 256] {
    let mut sub = [[0u32; 256]; 4];
    let mut quads = data.chunks_exact(4);
    for q in &mut quads {
        sub[0][q[0] as usize] += 1;
        sub[1][q[1] as usize] += 1;
        sub[2][q[2] as usize] += 1;
        sub[3][q[3] as usize] += 1;
    }
    for &b in quads.remainder() {
        sub[0][b as usize] += 1;
    }
    std::array::from_fn(|v| sub[0][v] + sub[1][v] + sub[2][v] + sub[3][v])
}

/// Bits of the codes of a block with byte `counts` coded with `lengths`.
pub(crate) fn code_bits(counts: &[u32; 256], lengths: &[u8; 256]) -> u64 {
    (0..256)
        .map(|v| u64::from(counts[v]) * u64::from(lengths[v]))
        .sum()
}

/// The most bytes a coded block takes whose codes take `bits` bits: the header, and each
/// stream's last byte padded.
pub(crate) fn max_coded_len(bits: u64) -> usize {
    HEADER + bits.div_ceil(8) as usize + STREAMS - 1
}

/// Length-limited Huffman code lengths for byte `counts` with at least two values present: at
/// most [`MAX_LEN`], a complete code, 0 for absent values.
pub(crate) fn code_lengths(counts: &[u32; 256]) -> [u8; 256] {
    // Present values, least frequent first (ties by value, so the code is deterministic).
    let mut order: Vec<(u32, u8)> = (0..=255u8)
        .filter(|&v| counts[v as usize] > 0)
        .map(|v| (counts[v as usize], v))
        .collect();
    order.sort_unstable();
    let n = order.len();
    let mut lengths = [0u8; 256];
    if n < 2 {
        // One value (or none): a code of two one-bit words, the value's and another's, so that
        // what `encode` writes is a complete code `decode` accepts. (Blocks code such input as
        // a fill; this keeps the code valid for any input.)
        let v = order.first().map_or(0, |&(_, v)| v);
        lengths[usize::from(v)] = 1;
        lengths[usize::from(v == 0)] = 1;
        return lengths;
    }
    // Huffman's tree by the two-queue method: leaves in `order`, internal nodes in creation
    // order (their weights never decrease). Nodes 0..n are leaves, n.. internal.
    let mut weight: Vec<u64> = order.iter().map(|&(c, _)| u64::from(c)).collect();
    let mut parent = vec![0usize; 2 * n - 1];
    let (mut leaf, mut inner) = (0usize, n);
    for node in n..2 * n - 1 {
        let mut pick = || {
            let take_leaf = leaf < n && (inner >= node || weight[leaf] <= weight[inner]);
            if take_leaf {
                leaf += 1;
                leaf - 1
            } else {
                inner += 1;
                inner - 1
            }
        };
        let (a, b) = (pick(), pick());
        weight.push(weight[a] + weight[b]);
        parent[a] = node;
        parent[b] = node;
    }
    // Depths from the root (the last node) down; a parent always comes after its children.
    let mut depth = vec![0u32; 2 * n - 1];
    for node in (0..2 * n - 2).rev() {
        depth[node] = depth[parent[node]] + 1;
    }
    // Codes per length, those beyond MAX_LEN folded in (deflate encoders' method): clamping
    // makes the Kraft sum exceed 1; each step takes a code off the longest length and splits a
    // shorter code in two one bit longer, lowering the sum by one unit of 2^-MAX_LEN.
    let max = MAX_LEN as usize;
    let mut per_len = [0u32; 256];
    for &d in &depth[..n] {
        per_len[(d as usize).min(max)] += 1;
    }
    let mut total: u64 = (1..=max).map(|l| u64::from(per_len[l]) << (max - l)).sum();
    while total > 1 << max {
        per_len[max] -= 1;
        if let Some(l) = (1..max).rev().find(|&l| per_len[l] != 0) {
            per_len[l] -= 1;
            per_len[l + 1] += 2;
        }
        total -= 1;
    }
    // The most frequent values take the shortest codes.
    let mut values = order.iter().rev().map(|&(_, v)| v);
    for (l, &count) in per_len.iter().enumerate().take(max + 1).skip(1) {
        for v in values.by_ref().take(count as usize) {
            lengths[v as usize] = l as u8;
        }
    }
    lengths
}

/// Canonical codes of `lengths`, bit-reversed for LSB-first streams, with their lengths.
fn codes(lengths: &[u8; 256]) -> [(u16, u8); 256] {
    let mut per_len = [0u16; MAX_LEN as usize + 1];
    for &l in lengths.iter().filter(|&&l| l > 0) {
        per_len[l as usize] += 1;
    }
    let mut next = [0u16; MAX_LEN as usize + 2];
    let mut code = 0u16;
    for l in 1..=MAX_LEN as usize {
        code = (code + per_len[l - 1]) << 1;
        next[l] = code;
    }
    let mut out = [(0u16, 0u8); 256];
    for (v, &l) in lengths.iter().enumerate() {
        if l > 0 {
            let c = next[l as usize];
            next[l as usize] += 1;
            out[v] = (c.reverse_bits() >> (16 - u32::from(l)), l);
        }
    }
    out
}

/// Room [`encode`] needs for a block of `n` bytes: its longest codes and 8 bytes of slack.
pub(crate) fn encode_room(n: usize) -> usize {
    HEADER + (n * MAX_LEN as usize).div_ceil(8) + STREAMS + 8
}

/// Writes the coded block of `data` (header and streams; see the module docs) at the start of
/// `out`, with `lengths` from [`code_lengths`]; returns its length. `out` must hold at least
/// [`encode_room`]`(data.len())` bytes, whatever they are: each stream is written 8 bytes at a
/// time, and the bytes past its end are overwritten by the next stream or lie past the block.
/// (Coding the four streams in one loop, into separate regions moved together afterwards, was
/// no faster on a dragon frame's planes.)
pub(crate) fn encode(data: &[u8], lengths: &[u8; 256], out: &mut [u8]) -> usize {
    assert!(
        out.len() >= encode_room(data.len()),
        "room for the coded block"
    );
    for (o, pair) in out.iter_mut().zip(lengths.chunks_exact(2)) {
        *o = pair[0] | pair[1] << 4;
    }
    let codes = codes(lengths);
    let mut at = HEADER;
    for j in 0..STREAMS {
        let dst = &mut out[at..];
        let (mut acc, mut pending, mut pos) = (0u64, 0u32, 0usize);
        let mut quads = data[stream_range(data.len(), j)].chunks_exact(4);
        for q in &mut quads {
            // At most 7 bits pending plus 4 × 11 < 64.
            for &b in q {
                let (c, l) = codes[b as usize];
                acc |= u64::from(c) << pending;
                pending += u32::from(l);
            }
            dst[pos..pos + 8].copy_from_slice(&acc.to_le_bytes());
            let whole = pending / 8;
            pos += whole as usize;
            acc >>= whole * 8;
            pending -= whole * 8;
        }
        for &b in quads.remainder() {
            let (c, l) = codes[b as usize];
            acc |= u64::from(c) << pending;
            pending += u32::from(l);
        }
        dst[pos..pos + 8].copy_from_slice(&acc.to_le_bytes());
        pos += pending.div_ceil(8) as usize;
        // Its size, once known, in the header (the last stream's is what is left).
        if j + 1 < STREAMS {
            out[128 + 4 * j..132 + 4 * j].copy_from_slice(&(pos as u32).to_le_bytes());
        }
        at += pos;
    }
    at
}

/// One stream's reader: `buf` holds `cnt` unread bits, the next at bit 0.
struct Bits<'a> {
    src: &'a [u8],
    /// Next byte to load; past `src.len()` when zero bytes were read beyond the stream.
    pos: usize,
    buf: u64,
    cnt: u32,
}

impl<'a> Bits<'a> {
    fn new(src: &'a [u8]) -> Self {
        Bits {
            src,
            pos: 0,
            buf: 0,
            cnt: 0,
        }
    }

    /// True if an 8-byte load at the cursor stays in the stream.
    #[inline(always)]
    fn fast(&self) -> bool {
        self.pos + 8 <= self.src.len()
    }

    /// Tops the buffer up to 56–63 bits with one 8-byte load (needs [`Bits::fast`]).
    #[inline(always)]
    fn refill_fast(&mut self) {
        let mut w = [0u8; 8];
        w.copy_from_slice(&self.src[self.pos..self.pos + 8]);
        self.buf |= u64::from_le_bytes(w) << self.cnt;
        self.pos += ((63 - self.cnt) >> 3) as usize;
        self.cnt |= 56;
    }

    /// Tops the buffer up a byte at a time, reading zeros past the stream.
    #[inline]
    fn refill_slow(&mut self) {
        while self.cnt <= 56 {
            let b = self.src.get(self.pos).copied().unwrap_or(0);
            self.buf |= u64::from(b) << self.cnt;
            self.pos += 1;
            self.cnt += 8;
        }
    }

    #[inline(always)]
    fn decode(&mut self, table: &[u16; TABLE]) -> u8 {
        let e = table[(self.buf & (TABLE as u64 - 1)) as usize];
        let l = u32::from(e & 15);
        self.buf >>= l;
        self.cnt -= l;
        (e >> 8) as u8
    }

    /// Bits consumed so far.
    fn consumed(&self) -> usize {
        self.pos * 8 - self.cnt as usize
    }
}

/// Decodes one coded block (header and streams) into `out`, whose length is the block's
/// decoded length. `what` names the block in errors.
pub(crate) fn decode(
    payload: &[u8],
    out: &mut [u8],
    what: &dyn Fn(String) -> WireError,
) -> Result<(), WireError> {
    if payload.len() < HEADER {
        return Err(what(format!(
            "a Huffman block of {} bytes is shorter than its {HEADER}-byte header",
            payload.len()
        )));
    }
    let mut lengths = [0u8; 256];
    for (i, &b) in payload[..128].iter().enumerate() {
        lengths[2 * i] = b & 15;
        lengths[2 * i + 1] = b >> 4;
    }
    let mut table = [0u16; TABLE];
    fill_table(&lengths, &mut table).map_err(what)?;
    let mut sizes = [0usize; STREAMS];
    let mut rest = payload.len() - HEADER;
    let fields = payload[128..HEADER].chunks_exact(4);
    for (j, (size, field)) in sizes.iter_mut().zip(fields).enumerate() {
        let s = u32::from_le_bytes([field[0], field[1], field[2], field[3]]) as usize;
        if s > rest {
            return Err(what(format!(
                "Huffman stream {j} announces {s} bytes, {rest} are left in the block"
            )));
        }
        *size = s;
        rest -= s;
    }
    sizes[STREAMS - 1] = rest;
    let mut readers: [Bits<'_>; STREAMS] = {
        let mut at = HEADER;
        std::array::from_fn(|j| {
            let r = Bits::new(&payload[at..at + sizes[j]]);
            at += sizes[j];
            r
        })
    };
    let n = out.len();
    let [o0, o1, o2, o3] = split4(out);
    // Five symbols from each stream per refill while every stream can load 8 bytes.
    {
        let [r0, r1, r2, r3] = &mut readers;
        let groups = o0
            .chunks_exact_mut(5)
            .zip(o1.chunks_exact_mut(5))
            .zip(o2.chunks_exact_mut(5))
            .zip(o3.chunks_exact_mut(5));
        let mut done = 0;
        for (((a, b), c), d) in groups {
            if !(r0.fast() && r1.fast() && r2.fast() && r3.fast()) {
                break;
            }
            r0.refill_fast();
            r1.refill_fast();
            r2.refill_fast();
            r3.refill_fast();
            for k in 0..5 {
                a[k] = r0.decode(&table);
                b[k] = r1.decode(&table);
                c[k] = r2.decode(&table);
                d[k] = r3.decode(&table);
            }
            done += 5;
        }
        // The rest of each stream, a symbol at a time.
        for (r, o) in [r0, r1, r2, r3].into_iter().zip([o0, o1, o2, o3]) {
            for x in &mut o[done..] {
                if r.cnt < MAX_LEN {
                    r.refill_slow();
                }
                *x = r.decode(&table);
            }
        }
    }
    for (j, r) in readers.iter().enumerate() {
        let bits = r.consumed();
        let used = bits.div_ceil(8);
        if used != sizes[j] {
            return Err(what(format!(
                "Huffman stream {j} of {} symbols holds {} bytes but its codes take {used}",
                stream_range(n, j).len(),
                sizes[j]
            )));
        }
        // The padding after the last code: zero bits.
        if bits % 8 != 0 && r.src[bits / 8] >> (bits % 8) != 0 {
            return Err(what(format!(
                "Huffman stream {j} has non-zero padding bits after its last code"
            )));
        }
    }
    Ok(())
}

/// `out` cut into the four streams' symbols.
fn split4(out: &mut [u8]) -> [&mut [u8]; STREAMS] {
    let n = out.len();
    let (a, rest) = out.split_at_mut(stream_range(n, 0).len());
    let (b, rest) = rest.split_at_mut(stream_range(n, 1).len());
    let (c, d) = rest.split_at_mut(stream_range(n, 2).len());
    [a, b, c, d]
}

/// The decoding table of `lengths`: entry `p` is the value whose reversed code is a prefix of
/// the 11 bits `p` (value in the high byte, length in the low nibble). Errors unless the
/// lengths make a complete code of two values or more.
fn fill_table(lengths: &[u8; 256], table: &mut [u16; TABLE]) -> Result<(), String> {
    let used = lengths.iter().filter(|&&l| l > 0).count();
    if let Some(&l) = lengths.iter().find(|&&l| u32::from(l) > MAX_LEN) {
        return Err(format!(
            "a Huffman code length of {l} bits (at most {MAX_LEN})"
        ));
    }
    let kraft: u32 = lengths
        .iter()
        .filter(|&&l| l > 0)
        .map(|&l| 1u32 << (MAX_LEN - u32::from(l)))
        .sum();
    if used < 2 || kraft != TABLE as u32 {
        return Err(format!(
            "the Huffman code lengths of {used} values do not make a complete code \
             (Kraft sum {kraft}/{TABLE})"
        ));
    }
    for (v, &(code, l)) in codes(lengths).iter().enumerate() {
        if l == 0 {
            continue;
        }
        let entry = (v as u16) << 8 | u16::from(l);
        let mut p = usize::from(code);
        while p < TABLE {
            table[p] = entry;
            p += 1 << l;
        }
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    fn round_trip(data: &[u8]) -> Vec<u8> {
        let counts = histogram(data);
        let lengths = code_lengths(&counts);
        let bits = code_bits(&counts, &lengths);
        // Garbage in the buffer must not matter.
        let mut coded = vec![0xa5u8; encode_room(data.len())];
        let len = encode(data, &lengths, &mut coded);
        coded.truncate(len);
        assert!(coded.len() <= max_coded_len(bits));
        assert!(coded.len() >= HEADER + bits.div_ceil(8) as usize);
        let mut out = vec![0u8; data.len()];
        decode(&coded, &mut out, &|m| WireError::Encode(m)).expect("decodes");
        assert_eq!(out, data);
        coded
    }

    /// A reproducible byte source: residuals within `spread` of 0, mod 256 (the colour planes'
    /// shape); near-uniform bytes for a spread of 256.
    pub(crate) fn noise(n: usize, seed: u64, spread: u32) -> Vec<u8> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let r = (s >> 33) as u32;
                // Small residuals around 0 (mod 256), like the colour planes.
                let m = r % spread;
                (if r & 1 << 31 != 0 { m } else { 256 - m }) as u8
            })
            .collect()
    }

    #[test]
    fn blocks_round_trip_at_every_stream_split() {
        for n in [
            2usize, 3, 4, 5, 7, 19, 20, 21, 39, 40, 41, 64, 1000, 4099, 131072,
        ] {
            for (seed, spread) in [(1, 2), (2, 5), (3, 40), (4, 256)] {
                let mut data = noise(n, seed, spread);
                // Two values at least.
                data[0] = 0;
                data[n - 1] = 1;
                let coded = round_trip(&data);
                let mut out = vec![0u8; n];
                decode(&coded, &mut out, &|m| WireError::Encode(m)).expect("decodes");
                assert_eq!(out, data, "{n} bytes, spread {spread}");
            }
        }
    }

    #[test]
    fn skewed_counts_are_limited_to_eleven_bits_and_stay_complete() {
        // Fibonacci-like counts make an unlimited Huffman code about as deep as there are values.
        let mut counts = [0u32; 256];
        let (mut a, mut b) = (1u32, 1u32);
        for c in counts.iter_mut().take(40) {
            *c = a;
            (a, b) = (b, (a + b).min(1 << 28));
        }
        let lengths = code_lengths(&counts);
        assert!(lengths.iter().all(|&l| u32::from(l) <= MAX_LEN));
        let kraft: u32 = lengths
            .iter()
            .filter(|&&l| l > 0)
            .map(|&l| 1 << (MAX_LEN - u32::from(l)))
            .sum();
        assert_eq!(kraft, 1 << MAX_LEN);
        assert_eq!(lengths.iter().filter(|&&l| l > 0).count(), 40);
        // More frequent values never get longer codes.
        for v in 1..40 {
            assert!(lengths[v] <= lengths[v - 1], "{v}: {lengths:?}");
        }
    }

    /// Huffman spends at most about `p_max + 0.086` bits a symbol above the entropy; on these
    /// 2.6-bit symbols that is 3 %, and the code is never below the entropy.
    #[test]
    fn a_skewed_plane_codes_near_its_entropy() {
        let data = noise(100_000, 9, 6);
        let coded = round_trip(&data);
        let hist = histogram(&data).map(f64::from);
        let n = data.len() as f64;
        let entropy: f64 = hist
            .iter()
            .filter(|&&c| c > 0.0)
            .map(|&c| -c * (c / n).log2())
            .sum::<f64>()
            / 8.0;
        let payload = (coded.len() - HEADER) as f64;
        assert!(
            payload < entropy * 1.05 + 16.0,
            "{payload} bytes against {entropy:.0}"
        );
        assert!(payload >= entropy - 1.0);
    }

    #[test]
    fn broken_blocks_are_errors_not_panics() {
        let mut data = noise(5000, 5, 12);
        data[0] = 0;
        data[1] = 1;
        let coded = round_trip(&data);
        let mut out = vec![0u8; data.len()];
        let err = |m: String| WireError::Encode(m);
        // Every truncation: an error before the streams; within them, the last stream's codes
        // no longer end in its last byte (zero bits read past a cut decode to other lengths,
        // so a cut can rarely pass this check: the message's checksum is what catches it).
        let mut caught = 0;
        for cut in 0..coded.len() {
            let r = decode(&coded[..cut], &mut out, &err);
            assert!(cut >= HEADER || r.is_err(), "cut at {cut}");
            caught += usize::from(r.is_err());
        }
        assert!(
            caught * 10 >= coded.len() * 9,
            "{caught} of {} cuts",
            coded.len()
        );
        let mut errors = 0;
        for at in (0..coded.len()).step_by(7) {
            let mut bad = coded.clone();
            bad[at] ^= 0x5a;
            if decode(&bad, &mut out, &err).is_err() {
                errors += 1;
            }
        }
        // Changed lengths break the code; a changed stream byte usually changes where its codes end.
        assert!(errors > 0);
        // Padding: two values of one bit each, 17 bytes, so stream 3 codes 5 bytes in 5 bits
        // and its byte ends in 3 padding bits.
        let two: Vec<u8> = (0..17).map(|i| (i % 2) as u8).collect();
        let mut coded = round_trip(&two);
        let last = coded.len() - 1;
        coded[last] ^= 0x80;
        let mut out = vec![0u8; two.len()];
        let e = decode(&coded, &mut out, &err).expect_err("a padding bit set");
        assert!(e.to_string().contains("padding"), "{e}");
        coded[last] ^= 0x80;
        decode(&coded, &mut out, &err).expect("the padding cleared again");
        let mut out = vec![0u8; data.len()];
        let coded = round_trip(&data);
        // Incomplete and over-full codes.
        let mut bad = coded.clone();
        bad[..128].fill(0);
        bad[0] = 0x11;
        bad[1] = 0x02;
        assert!(decode(&bad, &mut out, &err).is_err());
        bad[0] = 0x0c;
        assert!(decode(&bad, &mut out, &err).is_err());
        // Incomplete: two words of two bits; one word; none.
        bad[..128].fill(0);
        bad[0] = 0x22;
        assert!(decode(&bad, &mut out, &err).is_err());
        bad[0] = 0x01;
        assert!(decode(&bad, &mut out, &err).is_err());
        bad[0] = 0;
        assert!(decode(&bad, &mut out, &err).is_err());
    }

    #[test]
    fn one_value_or_none_still_makes_a_complete_code() {
        for v in [0u8, 1, 200] {
            round_trip(&vec![v; 300]);
        }
        let lengths = code_lengths(&histogram(&[]));
        assert_eq!(lengths.iter().filter(|&&l| l == 1).count(), 2);
    }
}
