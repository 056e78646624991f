//! NumPy `.npy` files (format 1.0) of `f32` and `u32` arrays: how per-pixel maps and training
//! data leave strata for training code and notebooks (`numpy.load("k.npy")` gives an `H × W`
//! float32 array).
//!
//! Layout: the magic `\x93NUMPY`, version `1 0`, a little-endian `u16` header length, an ASCII
//! Python dict `{'descr': '<f4', 'fortran_order': False, 'shape': (H, W), }` padded with spaces and
//! a newline so the data starts on a 64-byte boundary, then the values, row-major, little-endian.
//! [`encode`] writes any shape (`(n,)`, `(n, F)`, `(H, W, F)`) of `<f4` or `<u4`; [`decode`] reads
//! back exactly what [`encode`] writes (C order, little-endian `<f4`/`<u4`) and refuses the rest
//! with a message that says what it found.

use std::io::Write;
use std::path::Path;

use crate::image::ImageError;

/// The values of an array, borrowed for [`encode`].
#[derive(Clone, Copy, Debug)]
pub enum NpyData<'a> {
    /// 32-bit floats (`<f4`).
    F32(&'a [f32]),
    /// 32-bit unsigned integers (`<u4`).
    U32(&'a [u32]),
}

impl NpyData<'_> {
    fn len(&self) -> usize {
        match self {
            NpyData::F32(v) => v.len(),
            NpyData::U32(v) => v.len(),
        }
    }

    fn descr(&self) -> &'static str {
        match self {
            NpyData::F32(_) => "<f4",
            NpyData::U32(_) => "<u4",
        }
    }
}

/// An array read by [`decode`].
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    /// The shape, outermost first.
    pub shape: Vec<usize>,
    /// The values, row-major.
    pub values: NpyValues,
}

/// The values of a decoded array.
#[derive(Clone, Debug, PartialEq)]
pub enum NpyValues {
    /// 32-bit floats.
    F32(Vec<f32>),
    /// 32-bit unsigned integers.
    U32(Vec<u32>),
}

/// Why [`decode`] refused a file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NpyError {
    /// The bytes are not a `.npy` file of a kind this module writes.
    #[error("not a .npy file strata can read: {0}")]
    Format(String),
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
}

/// The header dict for `shape` and `descr`, padded so the data starts on a 64-byte boundary.
fn header(descr: &str, shape: &[usize]) -> String {
    let dims = match shape {
        [n] => format!("{n},"),
        _ => shape
            .iter()
            .map(usize::to_string)
            .collect::<Vec<_>>()
            .join(", "),
    };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({dims}), }}");
    let unpadded = 6 + 2 + 2 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    header
}

/// Encodes an array of `shape` (row-major) as `.npy` bytes.
///
/// # Panics
/// If `data` does not hold the product of `shape` values.
pub fn encode(shape: &[usize], data: NpyData<'_>) -> Vec<u8> {
    assert_eq!(
        data.len(),
        shape.iter().product::<usize>(),
        "one value per cell"
    );
    let header = header(data.descr(), shape);
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    match data {
        NpyData::F32(v) => v
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes())),
        NpyData::U32(v) => v
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes())),
    }
    out
}

/// Writes an array of `shape` as a `.npy` file.
pub fn write(path: impl AsRef<Path>, shape: &[usize], data: NpyData<'_>) -> Result<(), ImageError> {
    let path = path.as_ref();
    std::fs::write(path, encode(shape, data)).map_err(|source| ImageError::Io {
        path: path.to_owned(),
        source,
    })
}

/// The value of `key` in a header dict: the text after `'key': ` up to the next `,` at depth 0.
fn dict_value<'h>(header: &'h str, key: &str) -> Result<&'h str, NpyError> {
    let pattern = format!("'{key}':");
    let start = header
        .find(&pattern)
        .ok_or_else(|| NpyError::Format(format!("the header has no '{key}'")))?
        + pattern.len();
    let rest = header[start..].trim_start();
    let end = if rest.starts_with('(') {
        rest.find(')').map(|e| e + 1)
    } else {
        rest.find([',', '}'])
    };
    Ok(rest[..end.unwrap_or(rest.len())].trim())
}

/// Decodes `.npy` bytes as [`encode`] writes them (format 1.0, C order, `<f4` or `<u4`).
pub fn decode(bytes: &[u8]) -> Result<NpyArray, NpyError> {
    let bad = |what: &str| NpyError::Format(what.to_owned());
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("it does not start with the .npy magic"));
    }
    if bytes[6] != 1 {
        return Err(NpyError::Format(format!(
            "format version {}.{}, expected 1.0",
            bytes[6], bytes[7]
        )));
    }
    let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = bytes
        .get(10..10 + len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| bad("the header is cut short or not text"))?;
    if dict_value(header, "fortran_order")? != "False" {
        return Err(bad("Fortran order; only C order is read"));
    }
    let shape_text = dict_value(header, "shape")?;
    let shape = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|d| !d.is_empty())
        .map(|d| d.parse::<usize>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|_| NpyError::Format(format!("cannot read the shape {shape_text}")))?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| bad("the shape overflows"))?;
    let data = &bytes[10 + len..];
    if Some(data.len()) != count.checked_mul(4) {
        return Err(NpyError::Format(format!(
            "shape {shape_text} needs {count} values of 4 bytes, the file holds {} bytes",
            data.len()
        )));
    }
    let words = data.chunks_exact(4).map(|w| [w[0], w[1], w[2], w[3]]);
    let values = match dict_value(header, "descr")?.trim_matches('\'') {
        "<f4" => NpyValues::F32(words.map(f32::from_le_bytes).collect()),
        "<u4" => NpyValues::U32(words.map(u32::from_le_bytes).collect()),
        other => {
            return Err(NpyError::Format(format!(
                "element type {other}; only <f4 and <u4 are read"
            )));
        }
    };
    Ok(NpyArray { shape, values })
}

/// Reads a `.npy` file written by [`write()`].
pub fn read(path: impl AsRef<Path>) -> Result<NpyArray, NpyError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| NpyError::Io {
        path: path.to_owned(),
        source,
    })?;
    decode(&bytes)
}

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
    encode(&[height as usize, width as usize], NpyData::F32(values))
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

    #[test]
    fn arrays_round_trip() {
        let f: Vec<f32> = (0..24).map(|i| i as f32 * 0.5 - 3.0).collect();
        let back = decode(&encode(&[2, 3, 4], NpyData::F32(&f))).unwrap();
        assert_eq!(back.shape, [2, 3, 4]);
        assert_eq!(back.values, NpyValues::F32(f));
        let u = [7u32, 0, u32::MAX];
        let bytes = encode(&[3], NpyData::U32(&u));
        assert!(
            std::str::from_utf8(&bytes[10..80])
                .unwrap()
                .contains("'shape': (3,)")
        );
        let back = decode(&bytes).unwrap();
        assert_eq!(
            (back.shape, back.values),
            (vec![3], NpyValues::U32(u.to_vec()))
        );
    }

    #[test]
    fn refuses_what_it_cannot_read() {
        let msg = |b: &[u8]| decode(b).unwrap_err().to_string();
        assert!(msg(b"PK\x03\x04 not npy").contains("magic"));
        let mut short = encode(&[2, 2], NpyData::F32(&[1.0; 4]));
        short.truncate(short.len() - 4);
        assert!(msg(&short).contains("needs 4 values"), "{}", msg(&short));
        let mut f8 = encode(&[1], NpyData::F32(&[1.0]));
        let at = f8.windows(3).position(|w| w == b"<f4").unwrap();
        f8[at..at + 3].copy_from_slice(b"<f8");
        assert!(msg(&f8).contains("<f8"), "{}", msg(&f8));
    }
}
