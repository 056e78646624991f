//! Leading-zeros elimination of a fragment's colour (Lin 2007 §3.3), lossless.
//!
//! The thesis drops the leading zero bits the three colour components R, G, B have in common —
//! "eliminate leading zero bits of three color components simultaneously until leading 1 occurs in
//! any one of the three": a fixed length for all three, the *minimum* leading-zero count — and
//! records the remaining length in the Length table. With 8-bit components the remaining length
//! is `len = 8 − min(lz(R), lz(G), lz(B))`, which is the bit length of `R | G | B`, in `0..=8`.
//!
//! # Why decoding is exact
//!
//! Every component `c` satisfies `c ≤ R | G | B < 2^len`, so `c` fits in `len` bits: the bits
//! dropped are zeros, for all three components. [`pack_rgb`] stores `R | G << len | B << 2·len`
//! (`3·len` bits) and the Length table stores `len` itself (a 4-bit code, see
//! [`LengthCode`]), so [`unpack_rgb`] knows where each component starts and ends and restores it
//! bit for bit. Alpha is stored whole (8 bits), depth and object id as their full bit patterns.
//!
//! # The step strata does not take
//!
//! The thesis then shifts RGB right "by several bits based on fragment's alpha value" (Figure 3-14:
//! alpha 0.125, three bits), i.e. premultiplies by alpha and truncates. That throws bits away:
//! the stored colour is no longer the fragment's colour, and the image changes. strata's TFSS must
//! give the A-buffer's image bit for bit, so the store never applies it. [`alpha_shift`] exists
//! only for the *memory model* (`tfss::model`), where the lossy variant is reported apart and
//! labelled lossy, to show what the thesis's full scheme would save on our frames.

/// Bits of the colour components left after elimination: the bit length of `R | G | B`
/// (`8 − the minimum leading-zero count`), in `0..=8`.
#[inline]
pub fn rgb_length(rgb: [u8; 3]) -> u32 {
    u8::BITS - (rgb[0] | rgb[1] | rgb[2]).leading_zeros()
}

/// Eliminates the common leading zeros: `(len, bits)` with `bits = R | G << len | B << 2·len`,
/// `3·len` bits long.
#[inline]
pub fn pack_rgb(rgb: [u8; 3]) -> (u32, u32) {
    let len = rgb_length(rgb);
    let bits = u32::from(rgb[0]) | (u32::from(rgb[1]) << len) | (u32::from(rgb[2]) << (2 * len));
    (len, bits)
}

/// Restores the components [`pack_rgb`] packed with length `len`.
#[inline]
pub fn unpack_rgb(len: u32, bits: u32) -> [u8; 3] {
    let mask = (1u32 << len) - 1;
    [
        (bits & mask) as u8,
        ((bits >> len) & mask) as u8,
        ((bits >> (2 * len)) & mask) as u8,
    ]
}

/// Bits a packed colour record takes in a section: alpha (8) plus `3·len` colour bits.
#[inline]
pub fn record_bits(len: u32) -> u32 {
    8 + 3 * len
}

/// The thesis's alpha shift (lossy; the memory model's "alpha shift" variant only): how many bits
/// multiplying by alpha removes, `floor(log2(256 / a))` — alpha read as a fraction of 256, as
/// Figure 3-14 reads `0010 0000` as 0.125 and shifts by three. 0 for `a ≥ 129`, 8 for `a ≤ 1`.
#[inline]
pub fn alpha_shift(alpha: u8) -> u32 {
    if alpha == 0 {
        8
    } else {
        // 8 − ceil(log2(a)) = 8 − bit length of (a − 1)
        8 - (u8::BITS - (alpha - 1).leading_zeros())
    }
}

/// A slot's entry in the Length table: 4 bits per slot, `L_num` slots per section.
///
/// Codes, chosen so that zeroed memory reads as empty slots: `0` the slot is empty, `1..=9` a
/// stored fragment whose colour length is `code − 1`, `15` the section is sealed (a record did
/// not fit in what was left of its colour area, so the section takes no more fragments).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LengthCode {
    /// Nothing stored in this slot yet.
    Empty,
    /// A fragment with this colour length (0..=8).
    Stored(u32),
    /// The section is closed from this slot on.
    Sealed,
}

/// Bits per Length-table entry.
pub const LENGTH_BITS: u32 = 4;

impl LengthCode {
    /// The 4-bit code.
    #[inline]
    pub fn to_bits(self) -> u64 {
        match self {
            LengthCode::Empty => 0,
            LengthCode::Stored(len) => u64::from(len) + 1,
            LengthCode::Sealed => 15,
        }
    }

    /// Decodes a 4-bit code (codes 10..=14 never occur and read as sealed).
    #[inline]
    pub fn from_bits(bits: u64) -> Self {
        match bits {
            0 => LengthCode::Empty,
            1..=9 => LengthCode::Stored(bits as u32 - 1),
            _ => LengthCode::Sealed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn seed_figure_3_14_without_the_alpha_shift() {
        // R 0000 1111, G 0001 0010, B 0010 0101: the minimum leading-zero count is 2 (B), so six
        // bits per component remain: 00 1111, 01 0010, 10 0101.
        let rgb = [0b0000_1111, 0b0001_0010, 0b0010_0101];
        let (len, bits) = pack_rgb(rgb);
        assert_eq!(len, 6);
        assert_eq!(bits, (0b10_0101 << 12) | (0b01_0010 << 6) | 0b00_1111);
        assert_eq!(record_bits(len), 8 + 18);
        assert_eq!(unpack_rgb(len, bits), rgb);
        // The thesis's lossy step would shift by three more for alpha 0010 0000 (0.125): 3 bits.
        assert_eq!(alpha_shift(0b0010_0000), 3);
        assert_eq!(len - alpha_shift(0b0010_0000), 3);
    }

    #[test]
    fn lengths_at_the_edges() {
        assert_eq!(pack_rgb([0, 0, 0]), (0, 0));
        assert_eq!(unpack_rgb(0, 0), [0, 0, 0]);
        assert_eq!(rgb_length([1, 0, 0]), 1);
        assert_eq!(rgb_length([0, 0, 128]), 8);
        assert_eq!(pack_rgb([255, 255, 255]), (8, 0xFF_FFFF));
    }

    #[test]
    fn alpha_shift_reads_alpha_as_a_fraction_of_256() {
        assert_eq!(alpha_shift(255), 0);
        assert_eq!(alpha_shift(129), 0);
        assert_eq!(alpha_shift(128), 1); // 0.5
        assert_eq!(alpha_shift(65), 1);
        assert_eq!(alpha_shift(64), 2); // 0.25
        assert_eq!(alpha_shift(32), 3); // 0.125
        assert_eq!(alpha_shift(2), 7);
        assert_eq!(alpha_shift(1), 8);
        assert_eq!(alpha_shift(0), 8);
    }

    #[test]
    fn length_codes_round_trip() {
        for code in [
            LengthCode::Empty,
            LengthCode::Sealed,
            LengthCode::Stored(0),
            LengthCode::Stored(8),
        ] {
            assert!(code.to_bits() < 16);
            assert_eq!(LengthCode::from_bits(code.to_bits()), code);
        }
    }

    proptest! {
        #[test]
        fn pack_then_unpack_is_identity(r in any::<u8>(), g in any::<u8>(), b in any::<u8>()) {
            let (len, bits) = pack_rgb([r, g, b]);
            prop_assert!(len <= 8);
            prop_assert!(u64::from(bits) < 1u64 << (3 * len));
            prop_assert_eq!(len, 8 - [r, g, b].iter().map(|c| c.leading_zeros()).min().unwrap());
            prop_assert_eq!(unpack_rgb(len, bits), [r, g, b]);
        }
    }
}
