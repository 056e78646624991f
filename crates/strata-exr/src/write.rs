//! The writers: a [`DeepImage`] as a deep scanline file, a [`FlatImage`] as a scanline file.
//!
//! ```text
//! header                       see header.rs; deep adds type/version/chunkCount/maxSamplesPerPixel
//! u64 offsets[chunk_count]     byte offset of each chunk, ordered by increasing y
//! chunks, in line order:
//!   deep:  i32 y, u64 packed count-table size, u64 packed sample size, u64 unpacked sample size,
//!          count table, sample data
//!   flat:  i32 y, i32 packed size, pixel data
//! ```
//!
//! A chunk covers `lines_per_chunk` scanlines (16 for ZIP, else 1) starting at the data window's
//! top. Unpacked, a deep chunk's count table holds, per scanline, one i32 per pixel: the
//! cumulative sample count from the left edge of that scanline; its sample data holds, per
//! scanline, per channel (sorted by name), every sample of every pixel left to right. A flat
//! chunk's data is the same without the count table, one value per pixel. Both blocks go through
//! the chunk's compression separately and are stored raw when it does not shrink them.

use std::io::Write;
use std::path::Path;

use crate::compress::{Compression, compress};
use crate::error::{ExrError, Result};
use crate::header::{self, Header, LineOrder};
use crate::image::{Column, DeepImage, FlatImage, SampleType};

/// How to write a file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// Compression of the pixel data (default ZIPS: zlib, one scanline per chunk, which every
    /// OpenEXR reader accepts for deep and flat files).
    pub compression: Compression,
    /// The order of the chunks in the file (default increasing y).
    pub line_order: LineOrder,
}

/// Serialises a deep image as a deep scanline OpenEXR file.
///
/// Deep files take NONE, RLE or ZIPS compression. The file-layout specification also lists ZIP
/// (16 scanlines per chunk) for deep data, and [`crate::read_deep`] reads such files, but the
/// OpenEXR library itself (3.1 to at least 3.4) refuses to open them, so strata does not write
/// them.
///
/// # Errors
/// [`ExrError::Unsupported`] for ZIP compression; [`ExrError::InvalidImage`] if a scanline holds
/// more than 2^31 − 1 samples or an attribute cannot be stored.
pub fn write_deep(image: &DeepImage, options: &WriteOptions) -> Result<Vec<u8>> {
    if options.compression == Compression::Zip {
        return Err(ExrError::Unsupported(
            "ZIP (16-scanline) compression for deep files: OpenEXR's library cannot read them; \
             use ZIPS, which compresses deep data as well"
                .into(),
        ));
    }
    write_deep_unchecked(image, options)
}

/// [`write_deep`] without the compression check (the reader's tests use it for deep ZIP).
pub(crate) fn write_deep_unchecked(image: &DeepImage, options: &WriteOptions) -> Result<Vec<u8>> {
    let header = header_of(
        true,
        &image.channels,
        (image.data_window, image.display_window),
        &image.attributes,
        options,
    );
    let chunks = chunk_rows(image.height(), options.compression);
    let mut out = Vec::new();
    header::write(
        &mut out,
        &header,
        Some(image.max_samples_per_pixel()),
        chunks.len(),
    )?;
    write_chunks(&mut out, &chunks, options.line_order, |rows, out| {
        deep_chunk(image, rows, options.compression, out)
    })?;
    Ok(out)
}

/// Serialises a flat image as a scanline OpenEXR file.
///
/// # Errors
/// [`ExrError::InvalidImage`] if an attribute cannot be stored.
pub fn write_flat(image: &FlatImage, options: &WriteOptions) -> Result<Vec<u8>> {
    let header = header_of(
        false,
        &image.channels,
        (image.data_window, image.display_window),
        &image.attributes,
        options,
    );
    let chunks = chunk_rows(image.height(), options.compression);
    let mut out = Vec::new();
    header::write(&mut out, &header, None, chunks.len())?;
    write_chunks(&mut out, &chunks, options.line_order, |rows, out| {
        flat_chunk(image, rows, options.compression, out)
    })?;
    Ok(out)
}

/// The header of a deep or flat image written with `options`.
fn header_of(
    deep: bool,
    channels: &[crate::image::Channel],
    (data_window, display_window): (crate::image::Box2i, crate::image::Box2i),
    attributes: &[crate::image::Attribute],
    options: &WriteOptions,
) -> Header {
    Header {
        deep,
        channels: channels.to_vec(),
        compression: options.compression,
        data_window,
        display_window,
        line_order: options.line_order,
        chunk_count: None,
        attributes: attributes.to_vec(),
        all_attributes: Vec::new(),
    }
}

/// Writes a deep image to a file (see [`write_deep`]).
///
/// # Errors
/// As [`write_deep`], and [`ExrError::Io`] if the file cannot be written.
pub fn write_deep_file(path: &Path, image: &DeepImage, options: &WriteOptions) -> Result<()> {
    let bytes = write_deep(image, options)?;
    save(path, &bytes)
}

/// Writes a flat image to a file (see [`write_flat`]).
///
/// # Errors
/// As [`write_flat`], and [`ExrError::Io`] if the file cannot be written.
pub fn write_flat_file(path: &Path, image: &FlatImage, options: &WriteOptions) -> Result<()> {
    let bytes = write_flat(image, options)?;
    save(path, &bytes)
}

fn save(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |source| ExrError::Io {
        path: path.to_owned(),
        source,
    };
    let mut file = std::fs::File::create(path).map_err(io)?;
    file.write_all(bytes).map_err(io)?;
    file.flush().map_err(io)
}

/// Row ranges (relative to the data window's top) of each chunk.
fn chunk_rows(height: usize, compression: Compression) -> Vec<std::ops::Range<usize>> {
    let n = compression.lines_per_chunk();
    (0..height.div_ceil(n))
        .map(|i| i * n..((i + 1) * n).min(height))
        .collect()
}

/// Appends the offset table and the chunks, filling the table as chunks are placed.
fn write_chunks<F>(
    out: &mut Vec<u8>,
    chunks: &[std::ops::Range<usize>],
    line_order: LineOrder,
    mut chunk: F,
) -> Result<()>
where
    F: FnMut(std::ops::Range<usize>, &mut Vec<u8>) -> Result<()>,
{
    let table = out.len();
    out.resize(table + 8 * chunks.len(), 0);
    let order: Vec<usize> = match line_order {
        LineOrder::IncreasingY => (0..chunks.len()).collect(),
        LineOrder::DecreasingY => (0..chunks.len()).rev().collect(),
    };
    for i in order {
        let at = out.len() as u64;
        out[table + 8 * i..table + 8 * i + 8].copy_from_slice(&at.to_le_bytes());
        chunk(chunks[i].clone(), out)?;
    }
    Ok(())
}

fn absolute_y(window_top: i32, row: usize) -> i32 {
    // Rows are within a valid data window, whose bottom fits in i32.
    (i64::from(window_top) + row as i64) as i32
}

fn deep_chunk(
    image: &DeepImage,
    rows: std::ops::Range<usize>,
    compression: Compression,
    out: &mut Vec<u8>,
) -> Result<()> {
    let w = image.width();
    let mut counts = Vec::with_capacity(rows.len() * w * 4);
    let mut samples = Vec::new();
    for row in rows.clone() {
        let first = image.offsets[row * w];
        for x in 0..w {
            let cumulative = image.offsets[row * w + x + 1] - first;
            let cumulative = i32::try_from(cumulative).map_err(|_| {
                ExrError::InvalidImage(format!("scanline {row} holds over 2^31 - 1 samples"))
            })?;
            counts.extend_from_slice(&cumulative.to_le_bytes());
        }
        let range = first as usize..image.offsets[(row + 1) * w] as usize;
        for (channel, column) in image.channels.iter().zip(&image.columns) {
            encode_values(column, channel.sample_type, range.clone(), &mut samples);
        }
    }
    let packed_counts = compress(compression, &counts);
    let packed_samples = if samples.is_empty() {
        Vec::new()
    } else {
        compress(compression, &samples)
    };
    out.extend_from_slice(&absolute_y(image.data_window.y_min, rows.start).to_le_bytes());
    out.extend_from_slice(&(packed_counts.len() as u64).to_le_bytes());
    out.extend_from_slice(&(packed_samples.len() as u64).to_le_bytes());
    out.extend_from_slice(&(samples.len() as u64).to_le_bytes());
    out.extend_from_slice(&packed_counts);
    out.extend_from_slice(&packed_samples);
    Ok(())
}

fn flat_chunk(
    image: &FlatImage,
    rows: std::ops::Range<usize>,
    compression: Compression,
    out: &mut Vec<u8>,
) -> Result<()> {
    let w = image.width();
    let mut data = Vec::new();
    for row in rows.clone() {
        for (channel, column) in image.channels.iter().zip(&image.columns) {
            encode_values(
                column,
                channel.sample_type,
                row * w..(row + 1) * w,
                &mut data,
            );
        }
    }
    let packed = compress(compression, &data);
    let size = i32::try_from(packed.len())
        .map_err(|_| ExrError::InvalidImage("a flat chunk exceeds 2 GiB".into()))?;
    out.extend_from_slice(&absolute_y(image.data_window.y_min, rows.start).to_le_bytes());
    out.extend_from_slice(&size.to_le_bytes());
    out.extend_from_slice(&packed);
    Ok(())
}

fn encode_values(
    column: &Column,
    sample_type: SampleType,
    range: std::ops::Range<usize>,
    out: &mut Vec<u8>,
) {
    match (column, sample_type) {
        (Column::U32(v), _) => v[range]
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes())),
        (Column::F32(v), SampleType::Half) => v[range]
            .iter()
            .for_each(|&x| out.extend_from_slice(&half::f16::from_f32(x).to_bits().to_le_bytes())),
        (Column::F32(v), _) => v[range]
            .iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes())),
    }
}
