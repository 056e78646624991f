//! strata-exr: OpenEXR deep and flat scanline files, read and written by strata itself.

mod compress;
mod error;
mod header;
mod image;
mod read;
mod write;

pub use compress::Compression;
pub use error::{ExrError, Result};
pub use header::LineOrder;
pub use image::{Attribute, Box2i, Channel, Column, DeepImage, FlatImage, SampleType};
pub use read::{
    FileInfo, Limits, read_all, read_deep, read_deep_file, read_file_bytes, read_flat,
    read_flat_file, read_info,
};
pub use write::{WriteOptions, write_deep, write_deep_file, write_flat, write_flat_file};
