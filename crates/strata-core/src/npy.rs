//! NumPy `.npy` files (format 1.0) of `f32` grids: how per-pixel maps leave strata for training
//! code and notebooks (`numpy.load("k.npy")` gives an `H × W` float32 array).
//!
//! Layout: the magic `\x93NUMPY`, version `1 0`, a little-endian `u16` header length, an ASCII
//! Python dict `{'descr': '<f4', 'fortran_order': False, 'shape': (H, W), }` padded with spaces and
//! a newline so the data starts on a 64-byte boundary, then the values, row-major, little-endian.

use std::io::Write;
use std::path::Path;

use crate::image::ImageError;

/// Encodes a `height × width` row-major grid of `f32` as `.npy` bytes.
///
/// # Panics
/// If `values` does not hold `width * height` entries.
pub fn encode_f32(width: u32, height: u32, values: &[f32]) -> Vec<u8> {
    assert_eq!(
        values.len(),
        width as usize * height as usize,
        "one value per cell"
    );
    let mut header =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({height}, {width}), }}");
    let unpadded = 6 + 2 + 2 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + values.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Writes a `height × width` grid of `f32` as a `.npy` file.
pub fn write_f32(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    values: &[f32],
) -> Result<(), ImageError> {
    let path = path.as_ref();
    let io = |source| ImageError::Io {
        path: path.to_owned(),
        source,
    };
    let mut file = std::fs::File::create(path).map_err(io)?;
    file.write_all(&encode_f32(width, height, values))
        .map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_is_numpy_1_0_aligned_to_64_bytes() {
        let bytes = encode_f32(3, 2, &[0.0, 1.0, 2.0, 3.0, 4.0, 5.5]);
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + header_len) % 64, 0);
        let header = std::str::from_utf8(&bytes[10..10 + header_len]).unwrap();
        assert!(header.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }"));
        assert!(header.ends_with('\n'));
        let data = &bytes[10 + header_len..];
        assert_eq!(data.len(), 24);
        assert_eq!(f32::from_le_bytes(data[20..24].try_into().unwrap()), 5.5);
    }
}
