//! A NIfTI-1 reader for single scalar volumes (`.nii`, and `.nii.gz` by its gzip magic).
//!
//! A NIfTI-1 single file is a 348-byte header, padding up to `vox_offset`, then the voxels,
//! x fastest. The fields read here (byte offsets in the header):
//!
//! ```text
//!   0  i32   sizeof_hdr  = 348; its byte order gives the file's byte order
//!  40  i16×8 dim         dim[0] = rank, dim[1..=3] = nx, ny, nz, dim[4..] = 1 (one volume)
//!  70  i16   datatype    2 uint8, 256 int8, 4 int16, 512 uint16 (others refused)
//!  72  i16   bitpix      8 or 16, must agree with datatype
//!  76  f32×8 pixdim      pixdim[1..=3] = voxel size (mm)
//! 108  f32   vox_offset  ≥ 352, where the voxels start
//! 344  [u8;4] magic      "n+1\0" (the ".hdr/.img" pair "ni1\0" is refused)
//! ```
//!
//! Values are normalised to [0, 1] over the data's own range (minimum → 0, maximum → 1), so a
//! transfer function's points mean the same for 8- and 16-bit scans. `scl_slope`/`scl_inter` are
//! not applied: a positive linear rescale does not change that normalisation.
//!
//! Hostile input: every size is checked before anything is allocated, the voxel count is capped
//! at [`MAX_VOXELS`], and voxels are read through a bounded reader whose buffer grows only with
//! data that actually arrives, so a tiny file claiming a huge volume fails as truncated without a
//! huge allocation.

use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use crate::volume::Volume;

/// The most voxels a volume may have (256 Mi: 1 GiB as f32).
pub const MAX_VOXELS: usize = 1 << 28;

const HEADER_LEN: usize = 348;

/// Why a NIfTI-1 file could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NiftiError {
    /// The file could not be opened or read.
    #[error("cannot read volume {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file ends before the header or the voxels do.
    #[error("volume {path} is truncated: {what}")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// What was cut short.
        what: String,
    },
    /// The header is not a NIfTI-1 single-file header, or describes something unsupported.
    #[error("volume {path} is not a supported NIfTI-1 file: {reason}")]
    Header {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// A volume read from a NIfTI-1 file.
#[derive(Clone, Debug)]
pub struct NiftiVolume {
    /// The voxels, normalised to [0, 1].
    pub volume: Volume,
    /// Voxel size along x, y, z (the file's `pixdim`, 1 where it is missing or not positive).
    pub spacing: [f32; 3],
    /// Bits per voxel in the file (8 or 16).
    pub bits: u32,
}

impl NiftiVolume {
    /// The volume's extent, voxels × spacing, for placing it with its true proportions.
    pub fn extent(&self) -> [f32; 3] {
        let d = self.volume.dims();
        [0, 1, 2].map(|i| d[i] as f32 * self.spacing[i])
    }
}

/// The scalar types read.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    U8,
    I8,
    I16,
    U16,
}

impl Scalar {
    fn from_code(code: i16) -> Option<Scalar> {
        match code {
            2 => Some(Scalar::U8),
            256 => Some(Scalar::I8),
            4 => Some(Scalar::I16),
            512 => Some(Scalar::U16),
            _ => None,
        }
    }

    fn bytes(self) -> usize {
        match self {
            Scalar::U8 | Scalar::I8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
        }
    }
}

/// The header fields this reader uses.
#[derive(Debug)]
struct Header {
    big_endian: bool,
    dims: [usize; 3],
    scalar: Scalar,
    spacing: [f32; 3],
    vox_offset: usize,
}

/// Reads a `.nii` or `.nii.gz` file.
pub fn read_nifti(path: &Path) -> Result<NiftiVolume, NiftiError> {
    let io = |source| NiftiError::Io {
        path: path.to_owned(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let mut reader = BufReader::new(file);
    let mut magic = [0u8; 2];
    let gz = {
        use std::io::BufRead as _;
        let head = reader.fill_buf().map_err(io)?;
        magic.iter_mut().zip(head).for_each(|(m, h)| *m = *h);
        head.len() >= 2 && magic == [0x1f, 0x8b]
    };
    if gz {
        parse_nifti(path, flate2::read::GzDecoder::new(reader))
    } else {
        parse_nifti(path, reader)
    }
}

/// Reads a NIfTI-1 volume from `reader` (already decompressed); `path` names it in errors.
pub fn parse_nifti(path: &Path, mut reader: impl Read) -> Result<NiftiVolume, NiftiError> {
    let mut header = [0u8; HEADER_LEN];
    read_full(path, &mut reader, &mut header, "the 348-byte header")?;
    let header = parse_header(path, &header)?;
    let mut padding = vec![0u8; header.vox_offset - HEADER_LEN];
    read_full(path, &mut reader, &mut padding, "the header extension")?;
    let count = header.dims.iter().product::<usize>();
    let bytes = count * header.scalar.bytes();
    let mut data = Vec::new();
    reader
        .take(bytes as u64)
        .read_to_end(&mut data)
        .map_err(|e| read_error(path, e, "the voxels"))?;
    if data.len() < bytes {
        return Err(NiftiError::Truncated {
            path: path.to_owned(),
            what: format!(
                "{} of {bytes} voxel bytes present for {}x{}x{} voxels",
                data.len(),
                header.dims[0],
                header.dims[1],
                header.dims[2]
            ),
        });
    }
    let raw = decode(&data, header.scalar, header.big_endian);
    let volume = Volume::from_values(header.dims, normalise(raw)).ok_or_else(|| {
        header_error(path, "voxel count does not match the dimensions".to_owned())
    })?;
    Ok(NiftiVolume {
        volume,
        spacing: header.spacing,
        bits: 8 * header.scalar.bytes() as u32,
    })
}

fn read_full(
    path: &Path,
    reader: &mut impl Read,
    buf: &mut [u8],
    what: &str,
) -> Result<(), NiftiError> {
    reader
        .read_exact(buf)
        .map_err(|e| read_error(path, e, what))
}

fn read_error(path: &Path, e: std::io::Error, what: &str) -> NiftiError {
    if e.kind() == std::io::ErrorKind::UnexpectedEof {
        NiftiError::Truncated {
            path: path.to_owned(),
            what: format!("the file ends inside {what}"),
        }
    } else {
        NiftiError::Io {
            path: path.to_owned(),
            source: e,
        }
    }
}

fn header_error(path: &Path, reason: String) -> NiftiError {
    NiftiError::Header {
        path: path.to_owned(),
        reason,
    }
}

fn parse_header(path: &Path, h: &[u8; HEADER_LEN]) -> Result<Header, NiftiError> {
    let big_endian = byte_order(path, h)?;
    let i16_at = |o: usize| {
        let b = [h[o], h[o + 1]];
        if big_endian {
            i16::from_be_bytes(b)
        } else {
            i16::from_le_bytes(b)
        }
    };
    let f32_at = |o: usize| {
        let b = [h[o], h[o + 1], h[o + 2], h[o + 3]];
        if big_endian {
            f32::from_be_bytes(b)
        } else {
            f32::from_le_bytes(b)
        }
    };
    check_magic(path, &h[344..348])?;
    let dim: [i16; 8] = std::array::from_fn(|i| i16_at(40 + 2 * i));
    let dims = check_dims(path, &dim)?;
    let code = i16_at(70);
    let scalar = Scalar::from_code(code).ok_or_else(|| {
        header_error(
            path,
            format!(
                "datatype {code} is not a supported scalar type (supported: 2 uint8, 256 int8, 4 int16, 512 uint16)"
            ),
        )
    })?;
    let bitpix = i16_at(72);
    if bitpix as usize != 8 * scalar.bytes() {
        return Err(header_error(
            path,
            format!("bitpix {bitpix} does not match datatype {code}"),
        ));
    }
    let spacing = [1, 2, 3].map(|i| {
        let s = f32_at(76 + 4 * i);
        if s.is_finite() && s > 0.0 { s } else { 1.0 }
    });
    let vox_offset = check_vox_offset(path, f32_at(108))?;
    Ok(Header {
        big_endian,
        dims,
        scalar,
        spacing,
        vox_offset,
    })
}

fn byte_order(path: &Path, h: &[u8]) -> Result<bool, NiftiError> {
    let b = [h[0], h[1], h[2], h[3]];
    if i32::from_le_bytes(b) == HEADER_LEN as i32 {
        Ok(false)
    } else if i32::from_be_bytes(b) == HEADER_LEN as i32 {
        Ok(true)
    } else {
        Err(header_error(
            path,
            format!(
                "header size field is {} (a NIfTI-1 header says 348)",
                i32::from_le_bytes(b)
            ),
        ))
    }
}

fn check_magic(path: &Path, magic: &[u8]) -> Result<(), NiftiError> {
    match magic {
        b"n+1\0" => Ok(()),
        b"ni1\0" => Err(header_error(
            path,
            "it is the header of a .hdr/.img pair; convert it to a single .nii file".to_owned(),
        )),
        other => Err(header_error(
            path,
            format!("magic is {other:?}, not \"n+1\" (NIfTI-2 and Analyze files are not read)"),
        )),
    }
}

fn check_dims(path: &Path, dim: &[i16; 8]) -> Result<[usize; 3], NiftiError> {
    let rank = dim[0];
    if !(3..=7).contains(&rank) {
        return Err(header_error(
            path,
            format!("dim[0] is {rank}; a volume needs 3 dimensions"),
        ));
    }
    if let Some(extra) = (4..=rank as usize).find(|&i| dim[i] > 1) {
        return Err(header_error(
            path,
            format!(
                "dimension {extra} has {} entries; only a single 3D volume is read",
                dim[extra]
            ),
        ));
    }
    let dims = [dim[1], dim[2], dim[3]];
    if let Some(bad) = dims.iter().find(|&&d| d < 1) {
        return Err(header_error(
            path,
            format!(
                "dimensions {}x{}x{} include {bad}; each must be at least 1",
                dims[0], dims[1], dims[2]
            ),
        ));
    }
    let dims = dims.map(|d| d as usize);
    let count = dims.iter().product::<usize>();
    if count > MAX_VOXELS {
        return Err(header_error(
            path,
            format!(
                "{}x{}x{} = {count} voxels is more than the {MAX_VOXELS} this reader accepts",
                dims[0], dims[1], dims[2]
            ),
        ));
    }
    Ok(dims)
}

fn check_vox_offset(path: &Path, offset: f32) -> Result<usize, NiftiError> {
    const MAX_EXTENSION: f32 = (1 << 24) as f32;
    if !(352.0..=MAX_EXTENSION).contains(&offset) || offset.fract() != 0.0 {
        return Err(header_error(
            path,
            format!(
                "vox_offset {offset} is not a whole number of bytes between 352 and {MAX_EXTENSION}"
            ),
        ));
    }
    Ok(offset as usize)
}

fn decode(data: &[u8], scalar: Scalar, big_endian: bool) -> Vec<f32> {
    let pair = |c: &[u8]| {
        let b = [c[0], c[1]];
        if big_endian { b } else { [b[1], b[0]] }
    };
    match scalar {
        Scalar::U8 => data.iter().map(|&v| f32::from(v)).collect(),
        Scalar::I8 => data.iter().map(|&v| f32::from(v as i8)).collect(),
        Scalar::U16 => data
            .chunks_exact(2)
            .map(|c| f32::from(u16::from_be_bytes(pair(c))))
            .collect(),
        Scalar::I16 => data
            .chunks_exact(2)
            .map(|c| f32::from(i16::from_be_bytes(pair(c))))
            .collect(),
    }
}

/// Maps the data's range onto [0, 1]; a constant volume becomes all zeros.
fn normalise(mut raw: Vec<f32>) -> Vec<f32> {
    let (lo, hi) = raw
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let span = hi - lo;
    for v in &mut raw {
        *v = if span > 0.0 { (*v - lo) / span } else { 0.0 };
    }
    raw
}

/// Writes a minimal little-endian NIfTI-1 file for `values` (the tests' and benchmarks' fixture
/// writer; 8-bit when `bits` is 8, else 16-bit unsigned).
pub fn encode_nifti(dims: [usize; 3], values: &[u16], bits: u32) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&(HEADER_LEN as i32).to_le_bytes());
    let dim = [
        3i16,
        dims[0] as i16,
        dims[1] as i16,
        dims[2] as i16,
        1,
        1,
        1,
        1,
    ];
    for (i, d) in dim.iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    let (code, bitpix) = if bits == 8 { (2i16, 8i16) } else { (512, 16) };
    h[70..72].copy_from_slice(&code.to_le_bytes());
    h[72..74].copy_from_slice(&bitpix.to_le_bytes());
    for i in 0..4 {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&1f32.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[344..348].copy_from_slice(b"n+1\0");
    for &v in values {
        if bits == 8 {
            h.push(v.min(255) as u8);
        } else {
            h.extend_from_slice(&v.to_le_bytes());
        }
    }
    h
}
