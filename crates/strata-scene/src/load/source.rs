//! Reading a mesh file into one buffer, gunzipping it when it starts with `1f 8b`.
//!
//! Read errors carry no location; decompression is capped at [`MAX_DECOMPRESSED`] bytes so a
//! gzip bomb fails with an error instead of exhausting memory.

use std::io::Read;
use std::path::Path;

use super::{Fail, LoadErrorKind};

/// The most bytes a gzipped mesh may decompress to (2 GiB).
pub(super) const MAX_DECOMPRESSED: u64 = 1 << 31;

/// The gzip magic number.
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// The whole file, decompressed if it is gzip data.
pub(super) fn read(path: &Path) -> Result<Vec<u8>, Fail> {
    let raw = std::fs::read(path).map_err(|e| Fail::nowhere(LoadErrorKind::Io(e)))?;
    if raw.starts_with(&GZIP_MAGIC) {
        gunzip(&raw, MAX_DECOMPRESSED)
    } else {
        Ok(raw)
    }
}

/// Decompresses every gzip member of `raw` into one buffer of at most `limit` bytes.
pub(super) fn gunzip(raw: &[u8], limit: u64) -> Result<Vec<u8>, Fail> {
    // The trailer's ISIZE is the last member's size mod 2^32: a good first guess for the usual
    // single-member file, bounded by deflate's best ratio (about 1032:1) and by the limit.
    let hint = raw
        .len()
        .checked_sub(4)
        .and_then(|at| raw.get(at..))
        .and_then(|t| <[u8; 4]>::try_from(t).ok())
        .map_or(0, |t| u64::from(u32::from_le_bytes(t)));
    let ceiling = (raw.len() as u64).saturating_mul(1032).min(limit);
    let mut out = Vec::with_capacity(usize::try_from(hint.min(ceiling)).unwrap_or(0));
    let decoder = flate2::read::MultiGzDecoder::new(raw);
    decoder
        .take(limit.saturating_add(1))
        .read_to_end(&mut out)
        .map_err(|e| Fail::nowhere(LoadErrorKind::Gzip(e)))?;
    if out.len() as u64 > limit {
        return Err(Fail::nowhere(LoadErrorKind::Unsupported(format!(
            "the data decompresses to more than {limit} bytes"
        ))));
    }
    Ok(out)
}
