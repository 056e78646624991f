//! The readers: deep and flat scanline files into [`DeepImage`] and [`FlatImage`], safe on
//! hostile input.
//!
//! A file is read whole into memory (at most [`Limits::max_file_bytes`]) and then parsed from
//! the slice, in two passes for deep files:
//!
//! 1. the header, the offset table and, for each chunk, its fixed fields and its sample-count
//!    table, which give every pixel's sample count. Each count table is small (four bytes per
//!    pixel, bounded by [`Limits::max_pixels`]); the total sample count is checked against
//!    [`Limits::max_samples`] and the decoded size against [`Limits::max_bytes`];
//! 2. only then are the columns allocated, at their exact final size, and every chunk's sample
//!    data decompressed into them.
//!
//! Every offset and size read from the file is checked against the bytes that are actually
//! there, and every block's announced decompressed size against the most its compression can
//! expand (RLE at most 64×, zlib at most 1032×), before a buffer is allocated. Memory is therefore
//! bounded by the limits and by a constant times the file size, whatever the file claims.

use std::io::Read;
use std::path::Path;

use crate::compress::{Compression, DecodeError, decompress};
use crate::error::{ExrError, Result};
use crate::header::{self, Cursor, Header, LineOrder};
use crate::image::{Attribute, Box2i, Channel, Column, DeepImage, FlatImage, SampleType};

/// Upper bounds a reader enforces before allocating; a file over any of them is refused with
/// [`ExrError::LimitExceeded`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest file read (bytes).
    pub max_file_bytes: u64,
    /// Largest data window (pixels).
    pub max_pixels: u64,
    /// Most deep samples in one image.
    pub max_samples: u64,
    /// Most bytes of decoded pixel data (offsets plus all channels' values).
    pub max_bytes: u64,
}

impl Default for Limits {
    /// 4 GiB files, 2^28 pixels (16384×16384, the largest frame strata renders), 2^28 samples,
    /// 4 GiB of decoded data.
    fn default() -> Self {
        Limits {
            max_file_bytes: 4 << 30,
            max_pixels: 1 << 28,
            max_samples: 1 << 28,
            max_bytes: 4 << 30,
        }
    }
}

impl Limits {
    fn check(&self, what: &'static str, value: u64, limit: u64) -> Result<()> {
        if value > limit {
            return Err(ExrError::LimitExceeded { what, value, limit });
        }
        Ok(())
    }
}

/// What a file's header says, without its pixels (for `inspect`-like tools).
#[derive(Clone, Debug, PartialEq)]
pub struct FileInfo {
    /// True for a deep scanline file, false for a flat scanline file.
    pub deep: bool,
    /// The channels, sorted by name.
    pub channels: Vec<Channel>,
    /// The pixel-data compression.
    pub compression: Compression,
    /// The order of the chunks in the file.
    pub line_order: LineOrder,
    /// The rectangle the pixels cover.
    pub data_window: Box2i,
    /// The rectangle of the whole picture.
    pub display_window: Box2i,
    /// Every attribute in the file (the ones above included), raw, in file order; format a
    /// value for people with `Display` (`attribute.to_string()`).
    pub attributes: Vec<Attribute>,
}

/// Reads a file's header.
///
/// # Errors
/// Any header error [`read_deep`] reports.
pub fn read_info(bytes: &[u8]) -> Result<FileInfo> {
    let (h, _) = header::parse(bytes)?;
    Ok(FileInfo {
        deep: h.deep,
        channels: h.channels,
        compression: h.compression,
        line_order: h.line_order,
        data_window: h.data_window,
        display_window: h.display_window,
        attributes: h.all_attributes,
    })
}

/// Reads a whole file into memory, refusing files over `limits.max_file_bytes`.
///
/// # Errors
/// [`ExrError::Io`] or [`ExrError::LimitExceeded`].
pub fn read_file_bytes(path: &Path, limits: &Limits) -> Result<Vec<u8>> {
    let io = |source| ExrError::Io {
        path: path.to_owned(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(ExrError::Io {
            path: path.to_owned(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                if meta.is_dir() {
                    "it is a directory, not an image file"
                } else {
                    "it is not a regular file (a device, pipe or socket)"
                },
            ),
        });
    }
    let len = meta.len();
    limits.check("the file size", len, limits.max_file_bytes)?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(limits.max_file_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    limits.check("the file size", bytes.len() as u64, limits.max_file_bytes)?;
    Ok(bytes)
}

/// Reads everything from `reader` (at most `limits.max_file_bytes`).
///
/// # Errors
/// [`ExrError::Read`] or [`ExrError::LimitExceeded`].
pub fn read_all(reader: impl Read, limits: &Limits) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    reader
        .take(limits.max_file_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(ExrError::Read)?;
    limits.check("the file size", bytes.len() as u64, limits.max_file_bytes)?;
    Ok(bytes)
}

/// Reads a deep scanline file from its bytes.
///
/// # Errors
/// [`ExrError`] naming what is wrong and where: not OpenEXR, truncated, a bad attribute or chunk,
/// a flat file, an unsupported feature (tiles, multiple parts, PIZ and other compressions), or a
/// size over `limits`.
pub fn read_deep(bytes: &[u8], limits: &Limits) -> Result<DeepImage> {
    let (h, end) = header::parse(bytes)?;
    if !h.deep {
        return Err(ExrError::WrongKind {
            expected: "deep",
            found: "flat",
        });
    }
    let layout = Layout::new(&h, bytes, end, limits)?;
    let (offsets, chunks) = read_sample_counts(&h, &layout, bytes, limits)?;
    let total = u64::from(offsets[layout.pixels]);
    let mut columns: Vec<Column> = h
        .channels
        .iter()
        .map(|c| Column::with_capacity(c.sample_type, total as usize))
        .collect();
    for chunk in &chunks {
        decode_deep_chunk(&h, &layout, bytes, chunk, &offsets, &mut columns)?;
    }
    let mut image = DeepImage::new(h.data_window, h.channels, offsets, columns)?;
    image.display_window = h.display_window;
    image.attributes = h.attributes;
    Ok(image)
}

/// Reads a deep scanline file.
///
/// # Errors
/// As [`read_file_bytes`] and [`read_deep`].
pub fn read_deep_file(path: &Path, limits: &Limits) -> Result<DeepImage> {
    read_deep(&read_file_bytes(path, limits)?, limits)
}

/// Reads a flat scanline file from its bytes.
///
/// # Errors
/// As [`read_deep`], with a deep file being the wrong kind.
pub fn read_flat(bytes: &[u8], limits: &Limits) -> Result<FlatImage> {
    let (h, end) = header::parse(bytes)?;
    if h.deep {
        return Err(ExrError::WrongKind {
            expected: "flat",
            found: "deep",
        });
    }
    let layout = Layout::new(&h, bytes, end, limits)?;
    let bytes_per_pixel: u64 = h
        .channels
        .iter()
        .map(|c| c.sample_type.bytes() as u64)
        .sum();
    // In memory every value is 4 bytes (HALF decodes to f32), whatever the file stores.
    let decoded = (layout.pixels as u64).saturating_mul(4 * h.channels.len() as u64);
    limits.check("the decoded pixel data (bytes)", decoded, limits.max_bytes)?;
    // Grown chunk by chunk (see `read_sample_counts`).
    let mut columns: Vec<Column> = h
        .channels
        .iter()
        .map(|c| Column::with_capacity(c.sample_type, 0))
        .collect();
    for index in 0..layout.chunk_count {
        decode_flat_chunk(&h, &layout, bytes, index, bytes_per_pixel, &mut columns)?;
    }
    let mut image = FlatImage::new(h.data_window, h.channels, columns)?;
    image.display_window = h.display_window;
    image.attributes = h.attributes;
    Ok(image)
}

/// Reads a flat scanline file.
///
/// # Errors
/// As [`read_file_bytes`] and [`read_flat`].
pub fn read_flat_file(path: &Path, limits: &Limits) -> Result<FlatImage> {
    read_flat(&read_file_bytes(path, limits)?, limits)
}

/// The chunk geometry and the offset table.
struct Layout {
    width: usize,
    pixels: usize,
    lines: usize,
    height: usize,
    chunk_count: usize,
    /// Byte offset of each chunk, by increasing y.
    offsets: Vec<u64>,
}

impl Layout {
    fn new(h: &Header, bytes: &[u8], end: usize, limits: &Limits) -> Result<Self> {
        let pixels = h.data_window.pixel_count();
        limits.check("the data window (pixels)", pixels, limits.max_pixels)?;
        let width = h.data_window.width() as usize;
        let height = h.data_window.height() as usize;
        let lines = h.compression.lines_per_chunk();
        let chunk_count = height.div_ceil(lines);
        if let Some(declared) = h.chunk_count
            && i64::from(declared) != chunk_count as i64
        {
            return Err(ExrError::BadAttribute {
                name: "chunkCount".into(),
                problem: format!(
                    "is {declared}, but a {height}-line data window with {} compression has \
                     {chunk_count} chunks",
                    h.compression.name()
                ),
            });
        }
        let mut cur = Cursor::new(bytes, end);
        let table = cur.take(8 * chunk_count as u64, "the chunk offset table")?;
        let table_end = cur.pos as u64;
        let offsets: Vec<u64> = table
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
            .collect();
        for (i, &o) in offsets.iter().enumerate() {
            if o < table_end || o >= bytes.len() as u64 {
                return Err(ExrError::BadChunk {
                    chunk: i,
                    offset: o,
                    problem: format!(
                        "its offset-table entry (at byte {}) points outside the pixel data \
                         (bytes {table_end}..{})",
                        end + 8 * i,
                        bytes.len()
                    ),
                });
            }
        }
        Ok(Layout {
            width,
            pixels: pixels as usize,
            lines,
            height,
            chunk_count,
            offsets,
        })
    }

    /// Rows (relative to the window top) of chunk `i`.
    fn rows(&self, i: usize) -> std::ops::Range<usize> {
        i * self.lines..((i + 1) * self.lines).min(self.height)
    }

    fn chunk_error(&self, chunk: usize, problem: impl Into<String>) -> ExrError {
        ExrError::BadChunk {
            chunk,
            offset: self.offsets[chunk],
            problem: problem.into(),
        }
    }

    /// Reads a chunk's y coordinate and checks it is the one its table slot belongs to.
    fn chunk_start<'a>(&self, h: &Header, bytes: &'a [u8], i: usize) -> Result<Cursor<'a>> {
        let mut cur = Cursor::new(bytes, self.offsets[i] as usize);
        let y = cur.i32("a chunk's y coordinate")?;
        let expected = i64::from(h.data_window.y_min) + self.rows(i).start as i64;
        if i64::from(y) != expected {
            return Err(self.chunk_error(
                i,
                format!("starts at scanline {y}, but its table slot is for scanline {expected}"),
            ));
        }
        Ok(cur)
    }
}

/// Where a deep chunk's sample data is, found in the first pass.
struct DeepChunk {
    index: usize,
    data_at: usize,
    packed: usize,
    unpacked: usize,
}

/// The largest factor a block can grow by when decompressed.
fn max_expansion(compression: Compression) -> u64 {
    match compression {
        Compression::None => 1,
        // A repeat run turns 2 bytes into 128.
        Compression::Rle => 64,
        // Deflate's limit is 1032:1; zlib adds a few header bytes.
        Compression::Zips | Compression::Zip => 1032,
    }
}

fn check_expansion(
    layout: &Layout,
    chunk: usize,
    compression: Compression,
    what: &str,
    packed: u64,
    unpacked: u64,
) -> Result<()> {
    if unpacked == 0 {
        // Nothing to decode; whatever a writer stored for an empty block is ignored.
        return Ok(());
    }
    if packed > unpacked {
        return Err(layout.chunk_error(
            chunk,
            format!(
                "its {what} is stored in {packed} bytes, more than its {unpacked} decoded bytes"
            ),
        ));
    }
    if packed != unpacked && unpacked > packed.saturating_mul(max_expansion(compression)) {
        return Err(layout.chunk_error(
            chunk,
            format!(
                "its {what} claims to expand from {packed} to {unpacked} bytes, more than {} \
                 compression can",
                compression.name()
            ),
        ));
    }
    Ok(())
}

fn decode_block(
    layout: &Layout,
    chunk: usize,
    compression: Compression,
    what: &str,
    packed: &[u8],
    unpacked: usize,
) -> Result<Vec<u8>> {
    check_expansion(
        layout,
        chunk,
        compression,
        what,
        packed.len() as u64,
        unpacked as u64,
    )?;
    decompress(compression, packed, unpacked)
        .map_err(|DecodeError(e)| layout.chunk_error(chunk, format!("its {what}: {e}")))
}

/// First pass over a deep file: every pixel's sample count, as a prefix sum.
fn read_sample_counts(
    h: &Header,
    layout: &Layout,
    bytes: &[u8],
    limits: &Limits,
) -> Result<(Vec<u32>, Vec<DeepChunk>)> {
    let bytes_per_sample: u64 = h
        .channels
        .iter()
        .map(|c| c.sample_type.bytes() as u64)
        .sum();
    // Grown chunk by chunk rather than reserved from the header's claim: each chunk's count
    // table has to be in the file before its pixels are allocated.
    let mut offsets = vec![0u32];
    let mut total: u64 = 0;
    let mut chunks = Vec::new();
    for i in 0..layout.chunk_count {
        let mut cur = layout.chunk_start(h, bytes, i)?;
        let packed_table = cur.u64("a chunk's packed sample-count table size")?;
        let packed_data = cur.u64("a chunk's packed sample data size")?;
        let unpacked_data = cur.u64("a chunk's unpacked sample data size")?;
        let table = cur.take(packed_table, "a chunk's sample-count table")?;
        let data_at = cur.pos;
        cur.take(packed_data, "a chunk's sample data")?;
        let rows = layout.rows(i);
        let table_len = rows.len() * layout.width * 4;
        let table = decode_block(
            layout,
            i,
            h.compression,
            "sample-count table",
            table,
            table_len,
        )?;
        let chunk_samples = append_counts(h, layout, i, &table, &mut offsets, &mut total)?;
        limits.check("the total sample count", total, limits.max_samples)?;
        let expected = chunk_samples * bytes_per_sample;
        if unpacked_data != expected {
            return Err(layout.chunk_error(
                i,
                format!(
                    "its sample data unpacks to {unpacked_data} bytes, but {chunk_samples} samples \
                     of {bytes_per_sample} bytes need {expected}"
                ),
            ));
        }
        check_expansion(
            layout,
            i,
            h.compression,
            "sample data",
            packed_data,
            unpacked_data,
        )?;
        chunks.push(DeepChunk {
            index: i,
            data_at,
            packed: packed_data as usize,
            unpacked: unpacked_data as usize,
        });
    }
    // In memory: 4 bytes a value (HALF decodes to f32) plus the offsets.
    let decoded = total
        .saturating_mul(4 * h.channels.len() as u64)
        .saturating_add(4 * (layout.pixels as u64 + 1));
    limits.check("the decoded pixel data (bytes)", decoded, limits.max_bytes)?;
    Ok((offsets, chunks))
}

/// Appends one chunk's per-pixel counts (its table holds, per scanline, cumulative counts from
/// the left edge) to the prefix sum `offsets`; returns the chunk's sample count.
fn append_counts(
    h: &Header,
    layout: &Layout,
    chunk: usize,
    table: &[u8],
    offsets: &mut Vec<u32>,
    total: &mut u64,
) -> Result<u64> {
    let rows = layout.rows(chunk);
    let mut chunk_samples: u64 = 0;
    for (r, line) in table.chunks_exact(layout.width * 4).enumerate() {
        let mut previous = 0i32;
        for (x, b) in line.chunks_exact(4).enumerate() {
            let cumulative = i32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            if cumulative < previous {
                return Err(layout.chunk_error(
                    chunk,
                    format!(
                        "sample counts decrease at pixel ({}, {}): cumulative count \
                         {cumulative} after {previous}",
                        i64::from(h.data_window.x_min) + x as i64,
                        i64::from(h.data_window.y_min) + (rows.start + r) as i64
                    ),
                ));
            }
            *total += (cumulative - previous) as u64;
            previous = cumulative;
            let offset = u32::try_from(*total).map_err(|_| ExrError::LimitExceeded {
                what: "the total sample count",
                value: *total,
                limit: u64::from(u32::MAX),
            })?;
            offsets.push(offset);
        }
        chunk_samples += previous as u64;
    }
    Ok(chunk_samples)
}

/// Second pass: one chunk's sample data appended to the columns.
fn decode_deep_chunk(
    h: &Header,
    layout: &Layout,
    bytes: &[u8],
    chunk: &DeepChunk,
    offsets: &[u32],
    columns: &mut [Column],
) -> Result<()> {
    let packed = &bytes[chunk.data_at..chunk.data_at + chunk.packed];
    let data = decode_block(
        layout,
        chunk.index,
        h.compression,
        "sample data",
        packed,
        chunk.unpacked,
    )?;
    let mut at = 0usize;
    for row in layout.rows(chunk.index) {
        let line =
            offsets[(row + 1) * layout.width] as usize - offsets[row * layout.width] as usize;
        for (channel, column) in h.channels.iter().zip(columns.iter_mut()) {
            let n = line * channel.sample_type.bytes();
            decode_values(&data[at..at + n], channel.sample_type, column);
            at += n;
        }
    }
    Ok(())
}

fn decode_flat_chunk(
    h: &Header,
    layout: &Layout,
    bytes: &[u8],
    index: usize,
    bytes_per_pixel: u64,
    columns: &mut [Column],
) -> Result<()> {
    let mut cur = layout.chunk_start(h, bytes, index)?;
    let size = cur.i32("a chunk's data size")?;
    let size = u64::try_from(size)
        .map_err(|_| layout.chunk_error(index, format!("its data size {size} is negative")))?;
    let packed = cur.take(size, "a chunk's pixel data")?;
    let rows = layout.rows(index);
    let unpacked = rows.len() * layout.width * bytes_per_pixel as usize;
    let data = decode_block(layout, index, h.compression, "pixel data", packed, unpacked)?;
    let mut at = 0usize;
    for _ in rows {
        for (channel, column) in h.channels.iter().zip(columns.iter_mut()) {
            let n = layout.width * channel.sample_type.bytes();
            decode_values(&data[at..at + n], channel.sample_type, column);
            at += n;
        }
    }
    Ok(())
}

fn decode_values(data: &[u8], sample_type: SampleType, column: &mut Column) {
    match (sample_type, column) {
        (SampleType::Uint, Column::U32(v)) => v.extend(
            data.chunks_exact(4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        ),
        (SampleType::Half, Column::F32(v)) => v.extend(
            data.chunks_exact(2)
                .map(|b| half::f16::from_bits(u16::from_le_bytes([b[0], b[1]])).to_f32()),
        ),
        (SampleType::Float, Column::F32(v)) => v.extend(
            data.chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        ),
        // Columns are created from the channel types above.
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::write::{WriteOptions, write_deep_unchecked};

    fn image() -> DeepImage {
        let window = Box2i::from_origin(-3, 5, 3, 20).unwrap();
        let pixels = 60;
        let mut offsets = vec![0u32];
        for p in 0..pixels {
            offsets.push(offsets[p] + (p as u32 * 7 % 4));
        }
        let n = offsets[pixels] as usize;
        let channels = vec![
            Channel::new("A", SampleType::Half),
            Channel::new("Z", SampleType::Float),
            Channel::new("id", SampleType::Uint),
        ];
        let columns = vec![
            Column::F32((0..n).map(|i| (i % 5) as f32 / 4.0).collect()),
            Column::F32((0..n).map(|i| i as f32 * 0.37).collect()),
            Column::U32((0..n as u32).collect()),
        ];
        DeepImage::new(window, channels, offsets, columns).unwrap()
    }

    /// ZIP deep files are read (the layout specification allows them) though not written.
    #[test]
    fn reads_deep_zip_files() {
        let img = image();
        for line_order in [LineOrder::IncreasingY, LineOrder::DecreasingY] {
            let options = WriteOptions {
                compression: Compression::Zip,
                line_order,
            };
            let bytes = write_deep_unchecked(&img, &options).unwrap();
            let back = read_deep(&bytes, &Limits::default()).unwrap();
            assert_eq!(back.data_window(), img.data_window());
            assert_eq!(back.channels(), img.channels());
            assert_eq!(back.offsets(), img.offsets());
            assert_eq!(back.columns(), img.columns());
        }
    }
}
