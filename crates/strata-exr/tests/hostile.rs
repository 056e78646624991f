//! Hostile input: truncated, bit-flipped and hand-corrupted files are refused with an error that
//! says what is wrong and where, never a panic, and never an allocation the file's claims alone
//! would justify (the limits are checked first; a test that allocated what these files claim,
//! gigabytes, would abort).

mod common;

use common::synthetic;
use proptest::prelude::*;
use strata_exr::{
    Box2i, Channel, Column, Compression, DeepImage, ExrError, Limits, SampleType, WriteOptions,
    flatten, read_deep, read_flat, write_deep, write_flat,
};

fn small_deep(compression: Compression) -> Vec<u8> {
    let image = synthetic(
        Box2i::from_origin(1, 2, 4, 3).unwrap(),
        SampleType::Half,
        3,
        7,
    );
    write_deep(
        &image,
        &WriteOptions {
            compression,
            ..WriteOptions::default()
        },
    )
    .unwrap()
}

/// A 3×2 image with known counts (1, 2, 0 / 3, 0, 1) and channels A (half), Z (float).
fn known() -> DeepImage {
    let n = 7;
    DeepImage::new(
        Box2i::from_origin(0, 0, 3, 2).unwrap(),
        vec![
            Channel::new("A", SampleType::Half),
            Channel::new("Z", SampleType::Float),
        ],
        vec![0, 1, 3, 3, 6, 6, 7],
        vec![
            Column::F32(vec![0.5; n]),
            Column::F32((0..n).map(|i| i as f32).collect()),
        ],
    )
    .unwrap()
}

fn known_bytes() -> Vec<u8> {
    write_deep(
        &known(),
        &WriteOptions {
            compression: Compression::None,
            ..WriteOptions::default()
        },
    )
    .unwrap()
}

/// Where the header ends (after its terminating NUL), walking the attributes.
fn header_end(bytes: &[u8]) -> usize {
    let mut pos = 8;
    loop {
        let name_end = pos + bytes[pos..].iter().position(|&b| b == 0).unwrap();
        if name_end == pos {
            return pos + 1;
        }
        let type_end = name_end + 1 + bytes[name_end + 1..].iter().position(|&b| b == 0).unwrap();
        let size =
            i32::from_le_bytes(bytes[type_end + 1..type_end + 5].try_into().unwrap()) as usize;
        pos = type_end + 5 + size;
    }
}

/// The byte offset of attribute `name`'s size field.
fn attribute_size_at(bytes: &[u8], name: &str) -> usize {
    let mut pattern = name.as_bytes().to_vec();
    pattern.push(0);
    let at = bytes
        .windows(pattern.len())
        .position(|w| w == pattern)
        .expect("attribute present");
    let type_end = at
        + pattern.len()
        + bytes[at + pattern.len()..]
            .iter()
            .position(|&b| b == 0)
            .unwrap();
    type_end + 1
}

fn put_i32(bytes: &mut [u8], at: usize, v: i32) {
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

fn put_u64(bytes: &mut [u8], at: usize, v: u64) {
    bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

/// Offset of chunk `i` from the offset table.
fn chunk_at(bytes: &[u8], i: usize) -> usize {
    let t = header_end(bytes) + 8 * i;
    u64::from_le_bytes(bytes[t..t + 8].try_into().unwrap()) as usize
}

#[track_caller]
fn refused(bytes: &[u8], limits: &Limits) -> ExrError {
    match read_deep(bytes, limits) {
        Ok(_) => panic!("a corrupt file was accepted"),
        Err(e) => e,
    }
}

#[test]
fn every_truncation_is_an_error() {
    for compression in [Compression::None, Compression::Rle, Compression::Zips] {
        let bytes = small_deep(compression);
        assert!(read_deep(&bytes, &Limits::default()).is_ok());
        for len in 0..bytes.len() {
            assert!(
                read_deep(&bytes[..len], &Limits::default()).is_err(),
                "{compression:?}: prefix {len} accepted"
            );
        }
    }
    let flat = flatten(&synthetic(
        Box2i::from_origin(0, 0, 5, 20).unwrap(),
        SampleType::Half,
        3,
        9,
    ))
    .unwrap();
    for compression in Compression::ALL {
        let bytes = write_flat(
            &flat,
            &WriteOptions {
                compression,
                ..WriteOptions::default()
            },
        )
        .unwrap();
        for len in 0..bytes.len() {
            assert!(
                read_flat(&bytes[..len], &Limits::default()).is_err(),
                "flat {compression:?}: prefix {len} accepted"
            );
        }
    }
}

#[test]
fn bit_flips_never_panic() {
    for compression in [Compression::None, Compression::Rle, Compression::Zips] {
        let bytes = small_deep(compression);
        for i in 0..bytes.len() {
            for mask in [0xffu8, 1 << (i % 8), 0x80] {
                let mut b = bytes.clone();
                b[i] ^= mask;
                // Either an error or a valid image; never a panic.
                if let Ok(image) = read_deep(&b, &Limits::default()) {
                    assert_eq!(image.offsets().len(), image.width() * image.height() + 1);
                }
            }
        }
    }
}

#[test]
fn not_exr_unsupported_layouts_and_compressions_are_named() {
    let bytes = known_bytes();
    let err = refused(b"GIF89a....", &Limits::default());
    assert!(matches!(err, ExrError::NotExr), "{err:?}");
    for (flag, word) in [(0x200u32, "tiled"), (0x1000, "multi-part")] {
        let mut b = bytes.clone();
        let v = u32::from_le_bytes(b[4..8].try_into().unwrap()) | flag;
        b[4..8].copy_from_slice(&v.to_le_bytes());
        let err = refused(&b, &Limits::default());
        assert!(
            matches!(err, ExrError::Unsupported(_)) && err.to_string().contains(word),
            "{err}"
        );
    }
    let mut b = bytes.clone();
    let at = attribute_size_at(&b, "compression");
    b[at + 4] = 4; // PIZ
    let err = refused(&b, &Limits::default());
    assert!(
        err.to_string().contains("PIZ") && err.to_string().contains("--compression"),
        "{err}"
    );
    // `type` = "deeptile" (size 8 where "deepscanline" was 12: shrink the attribute in place).
    let at = attribute_size_at(&bytes, "type");
    let mut b = bytes[..at].to_vec();
    b.extend_from_slice(&8i32.to_le_bytes());
    b.extend_from_slice(b"deeptile");
    b.extend_from_slice(&bytes[at + 16..]);
    let err = refused(&b, &Limits::default());
    assert!(
        matches!(err, ExrError::Unsupported(_)) && err.to_string().contains("tiled"),
        "{err}"
    );
}

#[test]
fn attribute_sizes_are_checked_before_reading() {
    let bytes = known_bytes();
    let mut b = bytes.clone();
    put_i32(&mut b, attribute_size_at(&bytes, "channels"), i32::MAX);
    let err = refused(&b, &Limits::default());
    assert!(
        matches!(err, ExrError::Truncated { .. }) && err.to_string().contains("`channels`"),
        "{err}"
    );
    let mut b = bytes.clone();
    put_i32(&mut b, attribute_size_at(&bytes, "chunkCount"), -5);
    let err = refused(&b, &Limits::default());
    assert!(err.to_string().contains("negative size"), "{err}");
    let mut b = bytes.clone();
    put_i32(&mut b, attribute_size_at(&bytes, "dataWindow"), 15);
    let err = refused(&b, &Limits::default());
    // The next attribute is misread from a byte early: some header error, never a panic.
    assert!(
        matches!(
            err,
            ExrError::BadAttribute { .. } | ExrError::BadHeader { .. } | ExrError::Truncated { .. }
        ),
        "{err}"
    );
}

#[test]
fn huge_windows_and_chunk_counts_hit_the_limits_first() {
    let bytes = known_bytes();
    let mut b = bytes.clone();
    let at = attribute_size_at(&bytes, "dataWindow") + 4;
    put_i32(&mut b, at + 8, 1 << 30); // x_max
    put_i32(&mut b, at + 12, 1 << 30); // y_max
    let err = refused(&b, &Limits::default());
    assert!(
        matches!(
            err,
            ExrError::LimitExceeded {
                what: "the data window (pixels)",
                ..
            }
        ),
        "{err}"
    );
    // A tall window within the pixel limit: its offset table would pass the end of the file.
    put_i32(&mut b, at + 8, 0);
    put_i32(&mut b, at + 12, 1 << 24);
    let err = refused(&b, &Limits::default());
    assert!(
        matches!(
            err,
            ExrError::BadAttribute { .. } | ExrError::Truncated { .. }
        ),
        "{err}"
    );
    let mut b = bytes.clone();
    put_i32(&mut b, attribute_size_at(&bytes, "chunkCount") + 4, 3);
    let err = refused(&b, &Limits::default());
    assert!(err.to_string().contains("chunkCount"), "{err}");
    let small = Limits {
        max_pixels: 5,
        ..Limits::default()
    };
    let err = refused(&bytes, &small);
    assert!(
        matches!(
            err,
            ExrError::LimitExceeded {
                value: 6,
                limit: 5,
                ..
            }
        ),
        "{err}"
    );
}

/// A tiny flat file whose header claims one scanline of 2^26 pixels: refused as truncated, after
/// reading its one small chunk, without reserving the pixels first.
#[test]
fn a_tiny_flat_file_cannot_claim_a_huge_scanline() {
    let flat = flatten(&known()).unwrap();
    let bytes = write_flat(
        &flat,
        &WriteOptions {
            compression: Compression::None,
            ..WriteOptions::default()
        },
    )
    .unwrap();
    let mut b = bytes.clone();
    let at = attribute_size_at(&bytes, "dataWindow") + 4;
    put_i32(&mut b, at + 8, (1 << 26) - 1); // x_max
    put_i32(&mut b, at + 12, 0); // y_max: one scanline, one chunk
    let err = read_flat(&b, &Limits::default()).unwrap_err();
    assert!(
        matches!(err, ExrError::Truncated { .. } | ExrError::BadChunk { .. }),
        "{err}"
    );
}

#[test]
fn offset_tables_and_chunk_headers_are_checked() {
    let bytes = known_bytes();
    let table = header_end(&bytes);
    let mut b = bytes.clone();
    put_u64(&mut b, table + 8, u64::MAX);
    let err = refused(&b, &Limits::default());
    assert!(
        matches!(err, ExrError::BadChunk { chunk: 1, .. })
            && err.to_string().contains("offset-table"),
        "{err}"
    );
    let mut b = bytes.clone();
    put_u64(&mut b, table, 3);
    assert!(matches!(
        refused(&b, &Limits::default()),
        ExrError::BadChunk { chunk: 0, .. }
    ));
    // Both slots pointing at the first chunk: the second finds the wrong scanline.
    let mut b = bytes.clone();
    let first = chunk_at(&bytes, 0) as u64;
    put_u64(&mut b, table + 8, first);
    let err = refused(&b, &Limits::default());
    assert!(err.to_string().contains("scanline"), "{err}");
    for (field, offset) in [
        ("packed table", 4),
        ("packed data", 12),
        ("unpacked data", 20),
    ] {
        let mut b = bytes.clone();
        put_u64(&mut b, chunk_at(&bytes, 1) + offset, u64::MAX / 3);
        let err = refused(&b, &Limits::default());
        assert!(
            matches!(err, ExrError::BadChunk { .. } | ExrError::Truncated { .. }),
            "{field}: {err}"
        );
    }
}

#[test]
fn sample_counts_are_checked() {
    let bytes = known_bytes();
    // Row 1's table is [3, 3, 4] at chunk 1 + 28; make it decrease.
    let table = chunk_at(&bytes, 1) + 28;
    let mut b = bytes.clone();
    put_i32(&mut b, table + 4, 2);
    let err = refused(&b, &Limits::default());
    assert!(
        err.to_string().contains("decrease at pixel (1, 1)"),
        "{err}"
    );
    let mut b = bytes.clone();
    put_i32(&mut b, table, -1);
    assert!(
        refused(&b, &Limits::default())
            .to_string()
            .contains("decrease")
    );
    // Huge counts: the unpacked size no longer matches, or the limit is hit.
    let mut b = bytes.clone();
    put_i32(&mut b, table + 8, i32::MAX);
    let err = refused(&b, &Limits::default());
    assert!(
        matches!(
            err,
            ExrError::LimitExceeded { .. } | ExrError::BadChunk { .. }
        ),
        "{err}"
    );
    // Consistent huge claims (counts and unpacked size): the data is not there.
    let mut b = bytes.clone();
    put_i32(&mut b, table + 4, 1 << 30);
    put_i32(&mut b, table + 8, 1 << 30);
    put_u64(&mut b, chunk_at(&bytes, 1) + 20, (1u64 << 30) * 6);
    let err = refused(
        &b,
        &Limits {
            max_samples: u64::MAX,
            max_bytes: u64::MAX,
            ..Limits::default()
        },
    );
    assert!(
        matches!(
            err,
            ExrError::BadChunk { .. } | ExrError::LimitExceeded { .. }
        ),
        "{err}"
    );
    let err = refused(
        &bytes,
        &Limits {
            max_samples: 6,
            ..Limits::default()
        },
    );
    assert!(
        matches!(
            err,
            ExrError::LimitExceeded {
                what: "the total sample count",
                ..
            }
        ),
        "{err}"
    );
    let err = refused(
        &bytes,
        &Limits {
            max_bytes: 20,
            ..Limits::default()
        },
    );
    assert!(matches!(err, ExrError::LimitExceeded { .. }), "{err}");
}

#[test]
fn compressed_blocks_cannot_claim_impossible_expansion() {
    let bytes = small_deep(Compression::Zips);
    // The first chunk's sample data: claim it unpacks to far more than zlib can produce.
    let at = chunk_at(&bytes, 0);
    let packed = u64::from_le_bytes(bytes[at + 12..at + 20].try_into().unwrap());
    if packed > 0 {
        let mut b = bytes.clone();
        put_u64(&mut b, at + 20, packed * 5000);
        let err = refused(&b, &Limits::default());
        assert!(matches!(err, ExrError::BadChunk { chunk: 0, .. }), "{err}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Random overwrites anywhere in a valid file: an error or a valid image, never a panic.
    #[test]
    fn random_corruption_never_panics(
        comp in 0usize..3,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<prop::sample::Index>(), truncate in any::<bool>(),
    ) {
        let mut b = small_deep([Compression::None, Compression::Rle, Compression::Zips][comp]);
        for (i, v) in edits {
            let i = i.index(b.len());
            b[i] = v;
        }
        if truncate {
            let n = cut.index(b.len());
            b.truncate(n);
        }
        let limits = Limits { max_pixels: 1 << 20, max_samples: 1 << 22, max_bytes: 1 << 26, ..Limits::default() };
        if let Ok(image) = read_deep(&b, &limits) {
            prop_assert_eq!(image.offsets().len(), image.width() * image.height() + 1);
        }
        let _ = read_flat(&b, &limits);
    }
}
