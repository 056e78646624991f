//! strata-exr: OpenEXR deep and flat scanline files, read and written by strata itself.
//!
//! Deep compositing tools (Nuke, Houdini, OpenImageIO) exchange per-pixel sample lists as
//! OpenEXR *deep scanline* files. This crate writes and reads them without C or C++: the file
//! layout follows the OpenEXR "File Layout" and "Interpreting Deep Pixels" documents, and the
//! tests check the result against `exrheader`, `iinfo`, `oiiotool` and Python `OpenEXR`.
//!
//! # Data model
//!
//! - [`DeepImage`]: a data window (any origin) and display window, channels sorted by name
//!   (each [`SampleType::Uint`], [`SampleType::Half`] or [`SampleType::Float`]), per-pixel sample
//!   offsets (a prefix sum of `w*h + 1` entries, like strata's `DeepFrame`) and one [`Column`] per
//!   channel (`f32` values for half and float channels, `u32` for uint channels), plus the
//!   header [`Attribute`]s strata does not interpret, kept so a foreign file's metadata survives.
//! - [`FlatImage`]: the same without offsets, one value per pixel and channel (premultiplied).
//!
//! # Files
//!
//! [`write_deep`] / [`write_flat`] produce the bytes; [`read_deep`] / [`read_flat`] parse them,
//! refusing hostile input before allocating: every length, count, offset and size is checked
//! against the file and against [`Limits`] (see `read.rs`). Deep files are written with NONE,
//! RLE or ZIPS compression ([`WriteOptions`]); the reader also takes ZIP, in increasing or
//! decreasing line order, chunks in any order. Tiled and multi-part files, and the lossy or
//! wavelet compressions, are refused with [`ExrError::Unsupported`] naming the conversion.
//!
//! # Operations
//!
//! [`sort`], [`merge`] and [`flatten`] follow OpenImageIO's `--deepmerge` and `--flatten`
//! (see `ops.rs`); [`stats`] counts samples for inspection.
//!
//! # strata's DeepFrames
//!
//! [`deep_from_frame`] and [`frame_from_deep`] convert with channels `R G B A` (premultiplied),
//! `Z` (eye distance, from the window depth through the camera's [`DepthMapping`]), optional
//! `ZBack`, `objectid` (UINT) and the exact window depth `strata.depth`; the round trip is
//! bit-exact (see `frame.rs`).
//!
//! # Typical uses
//!
//! - save a rendered frame: [`deep_from_frame`] (clip planes as a [`DepthMapping`], camera
//!   matrices in [`FrameOptions`]), then [`write_deep_file`];
//! - composite deep files: [`read_deep_file`] each, [`merge`], [`flatten`], then
//!   [`write_flat_file`] (or [`FlatImage::rgba`] for another format);
//! - inspect a file: [`read_file_bytes`], [`read_info`] (every attribute, printable with
//!   `Display`), [`read_deep`], [`stats`], and one pixel's samples through
//!   [`DeepImage::pixel_at`] and [`Column::get_f64`].
//!
//! ```
//! use strata_exr::*;
//!
//! // A 2×1 image: pixel (0,0) holds two samples, pixel (1,0) none.
//! let window = Box2i::from_origin(0, 0, 2, 1)?;
//! let channels = vec![
//!     Channel::new("A", SampleType::Half),
//!     Channel::new("R", SampleType::Half),
//!     Channel::new("Z", SampleType::Float),
//! ];
//! let columns = vec![
//!     Column::F32(vec![0.5, 1.0]), // A
//!     Column::F32(vec![0.5, 0.25]), // R, premultiplied
//!     Column::F32(vec![1.0, 2.0]), // Z
//! ];
//! let image = DeepImage::new(window, channels, vec![0, 2, 2], columns)?;
//!
//! let bytes = write_deep(&image, &WriteOptions::default())?;
//! let back = read_deep(&bytes, &Limits::default())?;
//! assert_eq!(back.offsets(), image.offsets());
//! assert_eq!(back.columns(), image.columns());
//!
//! // Front-to-back OVER: 0.5 + (1 - 0.5) * 0.25.
//! let flat = flatten(&back)?;
//! assert_eq!(flat.value("R", 0), Some(0.625));
//! assert_eq!(flat.value("A", 1), Some(0.0));
//! # Ok::<(), ExrError>(())
//! ```

mod compress;
mod error;
mod frame;
mod header;
mod image;
mod ops;
mod read;
mod write;

pub use compress::Compression;
pub use error::{ExrError, Result};
pub use frame::{
    CameraMatrices, DepthMapping, FrameOptions, OBJECT_ID_CHANNEL, WINDOW_DEPTH_CHANNEL,
    deep_from_frame, frame_from_deep,
};
pub use header::LineOrder;
pub use image::{Attribute, Box2i, Channel, Column, DeepImage, FlatImage, SampleType};
pub use ops::{DeepStats, MAX_SPLIT_SAMPLES_PER_PIXEL, flatten, merge, sort, stats};
pub use read::{
    FileInfo, Limits, read_all, read_deep, read_deep_file, read_file_bytes, read_flat,
    read_flat_file, read_info,
};
pub use write::{WriteOptions, write_deep, write_deep_file, write_flat, write_flat_file};
