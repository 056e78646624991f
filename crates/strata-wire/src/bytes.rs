//! Little-endian reading and writing with offsets: the reader names the field and the byte offset
//! of everything it fails to read, so every decoding error says where it happened.
//!
//! Varints are unsigned LEB128 (7 bits per byte, low group first, high bit = "more follows"), at
//! most 5 bytes for a `u32`; a fifth byte above `0x0f` (bits beyond 32) is an error, so every value
//! has exactly one accepted encoding length range and none overflows.

use crate::error::WireError;

/// A cursor over a byte slice that knows its absolute offset in the message.
#[derive(Debug, Clone)]
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// Absolute offset of `bytes[0]` in the message, for error messages.
    base: u64,
}

impl<'a> Reader<'a> {
    /// A reader over `bytes`, whose first byte sits at `base` in the message.
    pub(crate) fn new(bytes: &'a [u8], base: u64) -> Self {
        Reader {
            bytes,
            pos: 0,
            base,
        }
    }

    /// Absolute offset of the next byte.
    pub(crate) fn offset(&self) -> u64 {
        self.base + self.pos as u64
    }

    /// Bytes not read yet.
    pub(crate) fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }

    /// The next `n` bytes, or a truncation error naming `field`.
    pub(crate) fn take(&mut self, n: usize, field: &'static str) -> Result<&'a [u8], WireError> {
        if self.remaining() < n {
            return Err(WireError::Truncated {
                field,
                offset: self.offset(),
                needed: n as u64,
                available: self.remaining() as u64,
            });
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn array<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], WireError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N, field)?);
        Ok(a)
    }

    pub(crate) fn u8(&mut self, field: &'static str) -> Result<u8, WireError> {
        Ok(self.array::<1>(field)?[0])
    }

    pub(crate) fn u16(&mut self, field: &'static str) -> Result<u16, WireError> {
        Ok(u16::from_le_bytes(self.array(field)?))
    }

    pub(crate) fn u32(&mut self, field: &'static str) -> Result<u32, WireError> {
        Ok(u32::from_le_bytes(self.array(field)?))
    }

    pub(crate) fn u64(&mut self, field: &'static str) -> Result<u64, WireError> {
        Ok(u64::from_le_bytes(self.array(field)?))
    }

    pub(crate) fn f32(&mut self, field: &'static str) -> Result<f32, WireError> {
        Ok(f32::from_le_bytes(self.array(field)?))
    }

    pub(crate) fn f64(&mut self, field: &'static str) -> Result<f64, WireError> {
        Ok(f64::from_le_bytes(self.array(field)?))
    }

    pub(crate) fn bytes4(&mut self, field: &'static str) -> Result<[u8; 4], WireError> {
        self.array(field)
    }

    /// An unsigned LEB128 varint of at most 32 bits.
    #[inline]
    pub(crate) fn varint(&mut self, field: &'static str) -> Result<u32, WireError> {
        // Most varints on the wire are one byte (removal gaps, small counts): that case is
        // inlined at the caller, the rest takes the loop.
        if let Some(&b) = self.bytes.get(self.pos)
            && b < 0x80
        {
            self.pos += 1;
            return Ok(u32::from(b));
        }
        self.varint_long(field)
    }

    #[inline(never)]
    fn varint_long(&mut self, field: &'static str) -> Result<u32, WireError> {
        let start = self.offset();
        let mut value: u32 = 0;
        for i in 0..5 {
            let Some(&b) = self.bytes.get(self.pos) else {
                return Err(WireError::Truncated {
                    field,
                    offset: self.offset(),
                    needed: 1,
                    available: 0,
                });
            };
            self.pos += 1;
            if i == 4 && b > 0x0f {
                return Err(WireError::invalid(
                    field,
                    start,
                    format!("varint byte {b:#04x}"),
                    "a varint longer than 32 bits",
                ));
            }
            value |= u32::from(b & 0x7f) << (7 * i);
            if b & 0x80 == 0 {
                return Ok(value);
            }
        }
        unreachable!("the fifth byte either ends the varint or is rejected")
    }
}

/// Appends an unsigned LEB128 varint.
#[inline]
pub(crate) fn put_varint(out: &mut Vec<u8>, mut v: u32) {
    while v >= 0x80 {
        out.push(v as u8 | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Maps a signed residual to an unsigned one, small magnitudes to small values
/// (0, -1, 1, -2, … → 0, 1, 2, 3, …).
#[inline]
pub(crate) fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

/// Inverse of [`zigzag`].
#[inline]
pub(crate) fn unzigzag(v: u32) -> i32 {
    ((v >> 1) as i32) ^ -((v & 1) as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn varints_round_trip_at_every_length_boundary() {
        for v in [
            0,
            1,
            127,
            128,
            16_383,
            16_384,
            (1 << 21) - 1,
            1 << 21,
            1 << 28,
            u32::MAX,
        ] {
            let mut out = Vec::new();
            put_varint(&mut out, v);
            let mut r = Reader::new(&out, 0);
            assert_eq!(r.varint("v").unwrap(), v);
            assert_eq!(r.remaining(), 0);
        }
    }

    #[test]
    fn overlong_and_truncated_varints_are_errors() {
        let mut r = Reader::new(&[0xff, 0xff, 0xff, 0xff, 0x10], 7);
        assert!(matches!(
            r.varint("v"),
            Err(WireError::Invalid { offset: 7, .. })
        ));
        let mut r = Reader::new(&[0x80, 0x80], 3);
        assert!(matches!(
            r.varint("v"),
            Err(WireError::Truncated { offset: 5, .. })
        ));
    }

    #[test]
    fn zigzag_is_a_bijection_on_small_and_extreme_values() {
        for v in [0, -1, 1, -2, 2, i32::MAX, i32::MIN, 12345, -12345] {
            assert_eq!(unzigzag(zigzag(v)), v);
        }
        assert_eq!([zigzag(0), zigzag(-1), zigzag(1), zigzag(-2)], [0, 1, 2, 3]);
    }

    #[test]
    fn truncation_names_the_field_and_offset() {
        let mut r = Reader::new(&[1, 2, 3], 100);
        r.u16("a").unwrap();
        let e = r.u32("width").unwrap_err();
        assert_eq!(
            e.to_string(),
            "truncated message: width at byte 102 needs 4 bytes, only 1 left"
        );
    }
}
