//! The NIfTI-1 reader on good files (8/16-bit, gzip, big-endian), hostile ones, and the real ch2 scan.

use std::io::Write as _;
use std::path::Path;

use strata_volume::nifti::{MAX_VOXELS, NiftiError, encode_nifti, parse_nifti, read_nifti};

fn parse(bytes: &[u8]) -> Result<strata_volume::NiftiVolume, NiftiError> {
    parse_nifti(Path::new("test.nii"), bytes)
}

fn header_err(bytes: &[u8]) -> String {
    match parse(bytes) {
        Err(e @ NiftiError::Header { .. }) => e.to_string(),
        other => panic!("expected a header error, got {other:?}"),
    }
}

fn set_i16(b: &mut [u8], at: usize, v: i16) {
    b[at..at + 2].copy_from_slice(&v.to_le_bytes());
}

fn small() -> Vec<u8> {
    encode_nifti(
        [3, 2, 2],
        &[0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110],
        8,
    )
}

#[test]
fn an_8_bit_file_reads_normalised_in_x_fastest_order() {
    let v = parse(&small()).expect("valid");
    assert_eq!(v.volume.dims(), [3, 2, 2]);
    assert_eq!(v.bits, 8);
    let vals = v.volume.values();
    assert_eq!(vals[0], 0.0);
    assert_eq!(vals[11], 1.0);
    assert!((vals[1] - 10.0 / 110.0).abs() < 1e-6);
}

#[test]
fn a_16_bit_big_endian_file_reads_the_same_values() {
    let vals: Vec<u16> = (0..8).map(|i| i * 1000).collect();
    let le = encode_nifti([2, 2, 2], &vals, 16);
    // Swap every field this reader uses to big-endian.
    let mut be = le.clone();
    be[0..4].copy_from_slice(&348i32.to_be_bytes());
    for at in (40..56).step_by(2).chain([70, 72]) {
        be.swap(at, at + 1);
    }
    for at in (76..108).step_by(4).chain([108]) {
        be[at..at + 4].reverse();
    }
    for at in (352..368).step_by(2) {
        be.swap(at, at + 1);
    }
    let a = parse(&le).expect("little-endian");
    let b = parse(&be).expect("big-endian");
    assert_eq!(a.bits, 16);
    assert_eq!(a.volume, b.volume);
    assert!((a.volume.values()[1] - 1.0 / 7.0).abs() < 1e-6);
}

#[test]
fn gzip_files_are_read_by_their_magic() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("v.nii.gz");
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    gz.write_all(&small()).expect("compress");
    let bytes = gz.finish().expect("compress");
    std::fs::write(&path, &bytes).expect("write");
    let v = read_nifti(&path).expect("gzip file");
    assert_eq!(v.volume.dims(), [3, 2, 2]);
    // A cut gzip stream is an error that names the file.
    std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("write");
    let e = read_nifti(&path).expect_err("truncated gzip");
    assert!(e.to_string().contains("v.nii.gz"), "{e}");
}

#[test]
fn truncated_files_say_what_is_missing() {
    let full = small();
    let e = parse(&full[..100]).expect_err("short header");
    assert!(matches!(e, NiftiError::Truncated { .. }));
    assert!(e.to_string().contains("348-byte header"), "{e}");
    let e = parse(&full[..full.len() - 3]).expect_err("short data");
    assert!(e.to_string().contains("9 of 12 voxel bytes"), "{e}");
    let missing = read_nifti(Path::new("/nonexistent/ch.nii")).expect_err("no file");
    assert!(matches!(missing, NiftiError::Io { .. }));
}

#[test]
fn a_wrong_header_size_is_not_nifti() {
    let mut b = small();
    b[0..4].copy_from_slice(&540i32.to_le_bytes());
    assert!(header_err(&b).contains("348"));
}

#[test]
fn bad_dimensions_are_refused() {
    let mut b = small();
    set_i16(&mut b, 40, 2);
    assert!(header_err(&b).contains("3 dimensions"));
    let mut b = small();
    set_i16(&mut b, 44, 0);
    assert!(header_err(&b).contains("at least 1"));
    let mut b = small();
    set_i16(&mut b, 42, -5);
    assert!(header_err(&b).contains("-5"));
    let mut b = small();
    set_i16(&mut b, 40, 4);
    set_i16(&mut b, 48, 2);
    assert!(header_err(&b).contains("single 3D volume"));
}

#[test]
fn unsupported_datatypes_and_mismatched_bitpix_are_refused() {
    let mut b = small();
    set_i16(&mut b, 70, 16); // float32
    assert!(header_err(&b).contains("datatype 16"));
    let mut b = small();
    set_i16(&mut b, 72, 16);
    assert!(header_err(&b).contains("bitpix 16"));
}

#[test]
fn huge_sizes_fail_before_allocating() {
    let mut b = small();
    for at in [42, 44, 46] {
        set_i16(&mut b, at, i16::MAX);
    }
    let e = header_err(&b);
    assert!(e.contains(&MAX_VOXELS.to_string()), "{e}");
    // Under the cap but far larger than the file: truncated, with the buffer grown only by the
    // bytes present.
    let mut b = small();
    set_i16(&mut b, 42, 1000);
    set_i16(&mut b, 44, 1000);
    set_i16(&mut b, 46, 200);
    let e = parse(&b).expect_err("tiny file");
    assert!(e.to_string().contains("12 of 200000000 voxel bytes"), "{e}");
}

#[test]
fn other_magics_and_offsets_are_refused() {
    let mut b = small();
    b[344..348].copy_from_slice(b"ni1\0");
    assert!(header_err(&b).contains(".hdr/.img"));
    let mut b = small();
    b[344..348].copy_from_slice(b"n+2\0");
    assert!(header_err(&b).contains("magic"));
    let mut b = small();
    b[108..112].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(header_err(&b).contains("vox_offset"));
    let mut b = small();
    b[108..112].copy_from_slice(&1e12f32.to_le_bytes());
    assert!(header_err(&b).contains("vox_offset"));
}

#[test]
fn the_ch2_head_scan_loads() {
    let Some(path) = strata_testdata::model("ch2.nii.gz") else {
        return;
    };
    let v = read_nifti(&path).expect("ch2 reads");
    assert_eq!(v.volume.dims(), [181, 217, 181]);
    assert_eq!(v.bits, 8);
    let vals = v.volume.values();
    assert!(vals.iter().all(|x| (0.0..=1.0).contains(x)));
    // A head: background at the corner, tissue at the centre.
    assert_eq!(vals[0], 0.0);
    assert!(v.volume.sample(glam::Vec3::splat(0.5)) > 0.1);
    assert!(v.extent().iter().all(|&e| e > 150.0));
}
