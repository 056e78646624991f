//! Hostile input: random bytes, every truncation, every single bit flip, random insertions and
//! deletions, and header fields set to extremes or lies, for every codec, for full, depth-limited
//! and difference frames (with their pixel masks), with and without the checksum. The decoder
//! must never panic; it must return an error that names the field (and its byte offset), or —
//! where a corruption happens to yield a well-formed message and the checksum is off — a frame
//! that the encoder writes back and reads again identically. Claims of huge sizes must fail on the
//! section table, before anything is allocated for them.
//!
//! Every test decodes messages of a few hundred bytes, so the exhaustive ones stay fast. The
//! `fuzz_seed_corpus_decodes` test also writes the fuzzing corpus (`fuzz/README.md`).

use proptest::prelude::*;
use strata_core::{DeepFrame, Fragment, ObjectId, Rgba8};
use strata_wire::{
    Codec, DecodeOptions, FrameHeader, FrameMessage, Hello, Message, NodeStats, PREFIX_LEN,
    PixelMask, Removals, Request, RequestKind, TransferMethod, VERSION, WireError, decode,
    decode_frame, encode_delta_into, encode_error_into, encode_frame, encode_frame_into,
    encode_reprojection_into, inspect_frame, parse_prefix,
};

// ---------------------------------------------------------------------------------------------
// Helpers

/// Bytes of a frame message before its section table.
const FRAME_HEADER_LEN: usize = 188;
/// Bytes per section-table entry.
const SECTION_ENTRY_LEN: usize = 20;

fn frag(depth: f32, rgba: [u8; 4], object: u32) -> Fragment {
    Fragment {
        depth,
        color: Rgba8(rgba),
        object: ObjectId(object),
    }
}

/// A 3×2 frame of 7 fragments: runs of 2, 0, 1, 3, 1 and 0.
fn small_frame() -> DeepFrame {
    DeepFrame::from_pixel_lists(
        3,
        2,
        &[
            vec![
                frag(0.25, [255, 0, 0, 128], 1),
                frag(0.5, [0, 0, 255, 255], 2),
            ],
            vec![],
            vec![frag(0.5, [0, 0, 255, 255], 2)],
            vec![
                frag(0.125, [0, 255, 0, 64], 3),
                frag(0.25, [255, 0, 0, 128], 1),
                frag(1.0, [9, 9, 9, 9], 4),
            ],
            vec![frag(0.0, [1, 2, 3, 4], u32::MAX)],
            vec![],
        ],
    )
    .unwrap()
}

/// A header with every field non-trivial: a depth-limited transfer with a threshold.
fn limited_header() -> FrameHeader {
    FrameHeader {
        frame_number: 42,
        node_id: 5,
        transfer: TransferMethod::DepthLimited {
            layers: 3,
            opacity_threshold: Some(0.75),
        },
        ..FrameHeader::default()
    }
}

/// The small frame under `codec`, with a full transfer or [`limited_header`].
fn message(codec: Codec, limited: bool) -> Vec<u8> {
    let header = if limited {
        limited_header()
    } else {
        FrameHeader::default()
    };
    encode_frame(&header, &small_frame(), codec).unwrap()
}

/// The small frame as a difference frame answering a fixup: pixels 0 to 4 replaced (pixel 1,
/// empty, is a deletion), pixel 5 stale.
fn delta_message(codec: Codec) -> Vec<u8> {
    let header = FrameHeader {
        frame_number: 43,
        node_id: 5,
        transfer: TransferMethod::Difference,
        fixup: true,
        ..FrameHeader::default()
    };
    let changed = PixelMask::from_fn(6, |p| p < 5);
    let stale = PixelMask::from_fn(6, |p| p == 5);
    let mut out = Vec::new();
    encode_delta_into(&mut out, &header, &changed, &stale, &small_frame(), codec).unwrap();
    out
}

/// The small frame as the compacted inserts of a reprojection frame of a 3×4 view: five
/// pixels touched (0, 2, 5, 6 and 11), their runs the small frame's first five (its sixth, empty,
/// pads the second row), removals at the second and the fourth.
fn reprojection_message(codec: Codec) -> Vec<u8> {
    let header = FrameHeader {
        frame_number: 44,
        node_id: 6,
        transfer: TransferMethod::Reprojection,
        ..FrameHeader::default()
    };
    let touched = PixelMask::from_fn(12, |p| [0, 2, 5, 6, 11].contains(&p));
    let mut removals = Removals::new(0xdead_beef);
    removals.set_depth_error(1e-4);
    for p in 0..5u32 {
        match p {
            1 => removals.push_pixel([0, 2, 9]),
            3 => removals.push_pixel([4]),
            _ => removals.push_pixel([]),
        }
    }
    let mut out = Vec::new();
    encode_reprojection_into(
        &mut out,
        &header,
        &touched,
        &removals,
        &small_frame(),
        codec,
    )
    .unwrap();
    out
}

/// Which message of the small frame a test starts from.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Full,
    Limited,
    Delta,
    Reprojection,
}

fn message_of(codec: Codec, kind: Kind) -> Vec<u8> {
    match kind {
        Kind::Full => message(codec, false),
        Kind::Limited => message(codec, true),
        Kind::Delta => delta_message(codec),
        Kind::Reprojection => reprojection_message(codec),
    }
}

/// Encodes a decoded frame message again, as a relay would.
fn reencode(m: &FrameMessage) -> Result<Vec<u8>, WireError> {
    let mut out = Vec::new();
    match (&m.changed, &m.stale, &m.removals) {
        (Some(changed), Some(stale), _) => {
            encode_delta_into(&mut out, &m.header, changed, stale, &m.frame, m.codec)?
        }
        (Some(touched), None, Some(removals)) => {
            encode_reprojection_into(&mut out, &m.header, touched, removals, &m.frame, m.codec)?
        }
        _ => encode_frame_into(&mut out, &m.header, &m.frame, m.codec)?,
    }
    Ok(out)
}

/// Sections in a message (its `section_count`).
fn section_count(bytes: &[u8]) -> usize {
    usize::from(u16::from_le_bytes([bytes[184], bytes[185]]))
}

fn options(verify_checksum: bool) -> DecodeOptions {
    DecodeOptions {
        verify_checksum,
        ..DecodeOptions::default()
    }
}

/// Makes `body_len` and `body_crc32` agree with the bytes after the prefix, as a sender that lies
/// consistently would, so that checksum verification does not stop the decoder early.
fn reseal(bytes: &mut [u8]) {
    if bytes.len() >= PREFIX_LEN {
        let body_len = (bytes.len() - PREFIX_LEN) as u64;
        let crc = crc32fast::hash(&bytes[PREFIX_LEN..]);
        bytes[8..16].copy_from_slice(&body_len.to_le_bytes());
        bytes[16..20].copy_from_slice(&crc.to_le_bytes());
    }
}

fn put_u32(bytes: &mut [u8], at: usize, v: u32) {
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

fn put_u64(bytes: &mut [u8], at: usize, v: u64) {
    bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

fn get_u64(bytes: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap())
}

/// Offset of section `i`'s table entry.
fn entry(i: usize) -> usize {
    FRAME_HEADER_LEN + SECTION_ENTRY_LEN * i
}

/// Two decoded messages are the same, matrices compared as bits (a flip can make a NaN).
#[track_caller]
fn assert_same_message(a: &FrameMessage, b: &FrameMessage) {
    assert_eq!(a.codec, b.codec);
    assert!(a.frame == b.frame, "frames differ");
    let bits = |m: &[f32; 16]| m.map(f32::to_bits);
    assert_eq!(bits(&a.header.view), bits(&b.header.view));
    assert_eq!(bits(&a.header.projection), bits(&b.header.projection));
    let strip = |h: &FrameHeader| FrameHeader {
        view: [0.0; 16],
        projection: [0.0; 16],
        ..*h
    };
    assert_eq!(strip(&a.header), strip(&b.header));
    assert_eq!((&a.changed, &a.stale), (&b.changed, &b.stale));
    assert_eq!((&a.removals, a.size), (&b.removals, b.size));
}

/// Every decoding error says where: a byte offset, or (for fragments that decoded but do not
/// form a DeepFrame) which invariant failed.
#[track_caller]
fn assert_located(e: &WireError) {
    let text = e.to_string();
    match e {
        WireError::Frame(_) => assert!(
            text.starts_with("the decoded fragments are not a valid DeepFrame: "),
            "{text}"
        ),
        WireError::Encode(_) => panic!("the decoder returned an encoder error: {text}"),
        _ => assert!(text.contains("byte "), "no byte offset in: {text}"),
    }
}

/// Decodes hostile `bytes`. It must not panic, `decode` and `decode_frame` must agree on frame
/// messages (`decode` answers for the other types), an error must be located, and an accepted
/// frame must be one the encoder writes back and reads again identically (what a relay that
/// re-encodes would do).
#[track_caller]
fn decode_hostile(bytes: &[u8], verify_checksum: bool) -> Result<FrameMessage, WireError> {
    let opts = options(verify_checksum);
    let result = decode_frame(bytes, &opts);
    let frame_type = bytes.get(6) == Some(&1);
    match (&result, decode(bytes, &opts)) {
        (Ok(a), Ok(Message::Frame(b))) => assert_same_message(a, &b),
        // As text: an error carrying a NaN is not equal to itself.
        (Err(a), Err(b)) if frame_type => assert_eq!(a.to_string(), b.to_string()),
        (Err(_), Ok(Message::Frame(_))) | (Ok(_), _) => {
            panic!("decode_frame and decode disagree on {bytes:02x?}")
        }
        // Another message type: decode_frame refuses it, decode gives its own answer.
        (Err(_), _) => {}
    }
    match &result {
        Ok(m) => {
            let info = inspect_frame(bytes, &opts).expect("inspect accepts what decode accepts");
            assert_eq!(
                (info.width, info.height, info.fragment_count as usize),
                (m.size.0, m.size.1, m.frame.fragment_count())
            );
            let again = reencode(m).unwrap_or_else(|e| {
                panic!("the decoder accepted a message the encoder cannot write: {e}")
            });
            let back = decode_frame(&again, &options(true)).expect("a re-encoded message decodes");
            assert_same_message(&back, m);
        }
        Err(e) => assert_located(e),
    }
    result
}

/// Every codec at its default settings, plus a negative zstd level.
fn codecs() -> Vec<Codec> {
    let mut all = Codec::ALL.to_vec();
    all.push(Codec::Zstd { level: -5 });
    all
}

// ---------------------------------------------------------------------------------------------
// Random bytes and mutations

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn random_bytes_are_rejected(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        for verify in [false, true] {
            prop_assert!(decode_hostile(&bytes, verify).is_err());
        }
    }

    #[test]
    fn random_bodies_behind_a_valid_prefix_never_panic(
        body in prop::collection::vec(any::<u8>(), 0..600),
    ) {
        let mut bytes = b"STRW".to_vec();
        bytes.extend_from_slice(&VERSION.to_le_bytes());
        bytes.extend_from_slice(&[1, 0]);
        bytes.extend_from_slice(&[0; 12]);
        bytes.extend_from_slice(&body);
        reseal(&mut bytes);
        for verify in [false, true] {
            let _ = decode_hostile(&bytes, verify);
        }
    }

    #[test]
    fn random_headers_over_real_section_tables_never_panic(
        codec in prop::sample::select(codecs()),
        header in prop::collection::vec(any::<u8>(), 164),
        small in prop::collection::vec(0u8..4, 164),
    ) {
        // Replace the fields from frame_number to section_count with random bytes, half of them
        // small numbers (so widths, counts and enums are often plausible).
        let mut bytes = message(codec, false);
        for (i, (&r, &s)) in header.iter().zip(&small).enumerate() {
            bytes[20 + i] = if i % 2 == 0 { r } else { s };
        }
        bytes[184..186].copy_from_slice(&(codec.sections().len() as u16).to_le_bytes());
        reseal(&mut bytes);
        for verify in [false, true] {
            let _ = decode_hostile(&bytes, verify);
        }
    }
}

/// One edit of a message.
#[derive(Clone, Debug)]
enum Edit {
    Overwrite(prop::sample::Index, u8),
    Xor(prop::sample::Index, u8),
    Insert(prop::sample::Index, u8),
    Delete(prop::sample::Index),
    Truncate(prop::sample::Index),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<prop::sample::Index>(), any::<u8>()).prop_map(|(i, b)| Edit::Overwrite(i, b)),
        (any::<prop::sample::Index>(), 1u8..=255).prop_map(|(i, b)| Edit::Xor(i, b)),
        (any::<prop::sample::Index>(), any::<u8>()).prop_map(|(i, b)| Edit::Insert(i, b)),
        any::<prop::sample::Index>().prop_map(Edit::Delete),
        any::<prop::sample::Index>().prop_map(Edit::Truncate),
    ]
}

fn apply(bytes: &mut Vec<u8>, e: &Edit) {
    match e {
        Edit::Overwrite(i, b) if !bytes.is_empty() => {
            let i = i.index(bytes.len());
            bytes[i] = *b;
        }
        Edit::Xor(i, b) if !bytes.is_empty() => {
            let i = i.index(bytes.len());
            bytes[i] ^= *b;
        }
        Edit::Insert(i, b) => {
            let i = i.index(bytes.len() + 1);
            bytes.insert(i, *b);
        }
        Edit::Delete(i) if !bytes.is_empty() => {
            let i = i.index(bytes.len());
            bytes.remove(i);
        }
        Edit::Truncate(i) => {
            let i = i.index(bytes.len() + 1);
            bytes.truncate(i);
        }
        _ => {}
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Random overwrites, insertions, deletions and truncations of valid messages. Without
    /// resealing, any change is caught by the checksum; resealed, the decoder must reach and
    /// reject (or consistently accept) whatever the edits made of the fields.
    #[test]
    fn edited_messages_are_rejected_or_consistent(
        codec in prop::sample::select(codecs()),
        kind in prop::sample::select(vec![Kind::Full, Kind::Limited, Kind::Delta, Kind::Reprojection]),
        edits in prop::collection::vec(edit(), 1..6),
        resealed in any::<bool>(),
    ) {
        let original = message_of(codec, kind);
        let mut bytes = original.clone();
        for e in &edits {
            apply(&mut bytes, e);
        }
        if resealed {
            reseal(&mut bytes);
        }
        let unverified = decode_hostile(&bytes, false);
        let verified = decode_hostile(&bytes, true);
        if bytes == original {
            prop_assert!(verified.is_ok() && unverified.is_ok());
        } else if !resealed {
            prop_assert!(verified.is_err(), "an edit went unnoticed with the checksum on");
        }
        if let (Ok(a), Ok(b)) = (&verified, &unverified) {
            assert_same_message(a, b);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Exhaustive truncations and bit flips

#[test]
fn every_truncation_is_an_error_that_names_the_field() {
    let prefix_fields = [
        (0, "magic"),
        (4, "version"),
        (6, "type"),
        (7, "flags"),
        (8, "body_len"),
        (16, "body_crc32"),
    ];
    for (codec, kind) in codecs().into_iter().flat_map(|c| {
        [
            (c, Kind::Limited),
            (c, Kind::Delta),
            (c, Kind::Reprojection),
        ]
    }) {
        let full = message_of(codec, kind);
        let table_end = FRAME_HEADER_LEN + SECTION_ENTRY_LEN * section_count(&full);
        for len in 0..full.len() {
            let cut = &full[..len];
            for verify in [false, true] {
                let e = decode_hostile(cut, verify).unwrap_err();
                let text = e.to_string();
                if len < PREFIX_LEN {
                    // The prefix field the cut falls into.
                    let &(at, field) = prefix_fields
                        .iter()
                        .rev()
                        .find(|(at, _)| *at <= len)
                        .unwrap();
                    assert!(
                        matches!(e, WireError::Truncated { field: f, offset, .. } if f == field && offset == at as u64),
                        "{codec} {kind:?}, {len} bytes: {e:?}"
                    );
                    assert!(
                        text.starts_with("truncated message: ") && text.contains(field),
                        "{text}"
                    );
                } else {
                    // The prefix announces more body than there is.
                    assert_eq!(
                        e,
                        WireError::Truncated {
                            field: "body",
                            offset: PREFIX_LEN as u64,
                            needed: (full.len() - PREFIX_LEN) as u64,
                            available: (len - PREFIX_LEN) as u64,
                        },
                        "{codec} {kind:?}, {len} bytes"
                    );
                }
            }
            // A sender that shortens the body and fixes the prefix to match gets past the
            // checksum; the header, the section table or a section still catch it.
            if len >= PREFIX_LEN {
                let mut lying = cut.to_vec();
                reseal(&mut lying);
                for verify in [false, true] {
                    let e = decode_hostile(&lying, verify).unwrap_err();
                    let text = e.to_string();
                    if len < table_end {
                        assert!(
                            matches!(e, WireError::Truncated { .. }),
                            "{codec} {kind:?}, {len}: {text}"
                        );
                    } else {
                        assert!(
                            text.contains("encoded_len") && text.contains("follow the table"),
                            "{codec} {kind:?}, {len} bytes: {text}"
                        );
                    }
                }
            }
        }
    }
}

/// What a single bit flip in byte `at` of the prefix must produce, checksum on or off.
fn assert_prefix_flip_error(e: &WireError, at: usize, verify: bool, what: &str) {
    let ok = match at {
        0..4 => matches!(e, WireError::BadMagic { .. }),
        4..6 => {
            matches!(e, WireError::UnsupportedVersion { found, supported } if *supported == VERSION && *found != VERSION)
        }
        // Reserved or unknown, or another message type, which is not a frame.
        6 => matches!(
            e,
            WireError::UnsupportedMessageType { .. }
                | WireError::Invalid {
                    field: "type",
                    offset: 6,
                    ..
                }
        ),
        7 => matches!(
            e,
            WireError::Invalid {
                field: "flags",
                offset: 7,
                ..
            }
        ),
        8..16 => matches!(
            e,
            WireError::Truncated { field: "body", .. }
                | WireError::Invalid {
                    field: "body_len",
                    offset: 8,
                    ..
                }
                | WireError::Limit {
                    field: "body_len",
                    offset: 8,
                    ..
                }
        ),
        16..20 => verify && matches!(e, WireError::Checksum { .. }),
        _ => unreachable!(),
    };
    assert!(ok, "{what}: {e:?}");
}

#[test]
fn every_single_bit_flip_is_caught_or_decodes_consistently() {
    // Both header kinds with every codec; difference frames (their masks) with the codecs that
    // store so small a frame's sections as they are.
    let messages = Codec::ALL
        .into_iter()
        .flat_map(|c| [(c, Kind::Full), (c, Kind::Limited)])
        .chain([(Codec::Raw, Kind::Delta), (Codec::DeepLz4, Kind::Delta)]);
    for (codec, kind) in messages {
        let original = message_of(codec, kind);
        let expected = decode_frame(&original, &options(true)).unwrap();
        let mut accepted = 0;
        // The matrices (bytes 56..184) are read the same way whatever the codec: every bit
        // of them with the raw codec, only their sign and exponent bits with the others.
        let matrix_bits = |bit: usize| (56 * 8..184 * 8).contains(&bit);
        let cheap = |bit: usize| codec == Codec::Raw || !matrix_bits(bit) || bit % 32 >= 23;
        for bit in (0..original.len() * 8).filter(|&b| cheap(b)) {
            let at = bit / 8;
            let mut flipped = original.clone();
            flipped[at] ^= 1 << (bit % 8);
            let what = format!("{codec}, {kind:?}, byte {at} bit {}", bit % 8);

            // With the checksum every flip is an error: CRC-32 detects every single-bit
            // error in the body, and the prefix is checked field by field.
            let e = decode_hostile(&flipped, true).unwrap_err();
            if at < PREFIX_LEN {
                assert_prefix_flip_error(&e, at, true, &what);
            } else {
                assert!(matches!(e, WireError::Checksum { .. }), "{what}: {e:?}");
                assert!(
                    e.to_string()
                        .starts_with("checksum mismatch: byte 16 says ")
                );
            }

            // Without it, the decoder sees the corrupted fields.
            let result = decode_hostile(&flipped, false);
            if let Ok(m) = &result {
                accepted += 1;
                if m.codec == Codec::Raw {
                    // The raw layout has one encoding per frame: an accepted raw message is
                    // exactly what the encoder writes for what it decoded to. (A raw message
                    // whose codec byte now says lz4 or zstd is a valid one with its sections
                    // stored, which an encoder would compress.)
                    let again = reencode(m).unwrap();
                    assert!(again[20..] == flipped[20..], "{what}: not canonical");
                }
            }
            match at {
                16..20 => {
                    // Only the checksum changed, and nobody checked it.
                    assert_same_message(result.as_ref().expect(&what), &expected);
                }
                0..PREFIX_LEN => assert_prefix_flip_error(&result.unwrap_err(), at, false, &what),
                20..32 | 56..184 => {
                    // frame_number, node_id and the matrices are carried, not interpreted.
                    let m = result.expect(&what);
                    assert!(m.frame == expected.frame, "{what}");
                    assert_eq!(&reencode(&m).unwrap()[20..], &flipped[20..], "{what}");
                }
                _ => {}
            }
        }
        let carried = (0..original.len() * 8)
            .filter(|&b| cheap(b) && ((160..256).contains(&b) || matrix_bits(b)))
            .count();
        assert!(
            accepted >= carried + 32,
            "{codec}: only {accepted} flips decoded, {carried} carried fields and the checksum should"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Extreme and lying header fields

/// A corruption of a valid message and what the error must name.
struct Case {
    what: &'static str,
    edit: fn(&mut Vec<u8>),
    needles: &'static [&'static str],
}

fn cases() -> Vec<Case> {
    vec![
        Case {
            what: "magic",
            edit: |b| b[0..4].copy_from_slice(b"STRX"),
            needles: &["magic", "byte 0", "STRW"],
        },
        Case {
            what: "version 5 (the previous format)",
            edit: |b| b[4] = 5,
            needles: &["version 5", "byte 4", "reads version 6"],
        },
        Case {
            what: "version 1",
            edit: |b| b[4] = 1,
            needles: &["version 1", "byte 4", "reads version 6"],
        },
        Case {
            what: "version 7",
            edit: |b| b[4] = 7,
            needles: &["version 7", "byte 4"],
        },
        Case {
            what: "version u16::MAX",
            edit: |b| b[4..6].copy_from_slice(&[0xff, 0xff]),
            needles: &["version 65535", "byte 4"],
        },
        Case {
            what: "request message type",
            edit: |b| b[6] = 2,
            needles: &["byte 6 (type): 2 is invalid: not a frame message"],
        },
        Case {
            what: "reserved message type",
            edit: |b| b[6] = 3,
            needles: &["message type 3 at byte 6 is reserved"],
        },
        Case {
            what: "error message type",
            edit: |b| b[6] = 4,
            needles: &["byte 6 (type): 4 is invalid: not a frame message"],
        },
        Case {
            what: "stats message type",
            edit: |b| b[6] = 6,
            needles: &["byte 6 (type): 6 is invalid: not a frame message"],
        },
        Case {
            what: "unknown message type",
            edit: |b| b[6] = 255,
            needles: &["message type 255", "unknown"],
        },
        Case {
            what: "flags",
            edit: |b| b[7] = 0x80,
            needles: &["flags", "byte 7"],
        },
        Case {
            what: "body_len u64::MAX",
            edit: |b| put_u64(b, 8, u64::MAX),
            needles: &["body_len", "byte 8", "exceeds the limit of 4294967296"],
        },
        Case {
            what: "body_len one too many",
            edit: |b| {
                let n = get_u64(b, 8);
                put_u64(b, 8, n + 1)
            },
            needles: &["truncated message: body at byte 20"],
        },
        Case {
            what: "body_len one too few",
            edit: |b| {
                let n = get_u64(b, 8);
                put_u64(b, 8, n - 1)
            },
            needles: &["body_len", "byte 8"],
        },
        Case {
            what: "width u32::MAX",
            edit: |b| put_u32(b, 32, u32::MAX),
            needles: &["width", "byte 32", "4294967295", "limit of 16384"],
        },
        Case {
            what: "height u32::MAX",
            edit: |b| put_u32(b, 36, u32::MAX),
            needles: &["height", "byte 36", "limit of 16384"],
        },
        Case {
            what: "16384 × 16384 pixels",
            edit: |b| {
                put_u32(b, 32, 16_384);
                put_u32(b, 36, 16_384)
            },
            needles: &["width·height", "268435456", "limit of 67108864"],
        },
        Case {
            what: "width 0",
            edit: |b| put_u32(b, 32, 0),
            needles: &["decoded_len", "0x2 frame"],
        },
        Case {
            what: "fragment_count u32::MAX",
            edit: |b| put_u32(b, 40, u32::MAX),
            needles: &["fragment_count", "byte 40", "limit of 268435456"],
        },
        Case {
            what: "fragment_count 2^28",
            edit: |b| put_u32(b, 40, 1 << 28),
            needles: &["decoded_len", "268435456 fragments"],
        },
        Case {
            what: "one fragment more",
            edit: |b| put_u32(b, 40, 8),
            needles: &["decoded_len", "of 8 fragments"],
        },
        Case {
            what: "no fragments",
            edit: |b| put_u32(b, 40, 0),
            needles: &["decoded_len", "of 0 fragments"],
        },
        Case {
            what: "transfer 4",
            edit: |b| b[44] = 4,
            needles: &["transfer", "byte 44", "unknown transfer method"],
        },
        Case {
            what: "transfer_flags",
            edit: |b| b[45] = 0x80,
            needles: &["transfer_flags", "byte 45"],
        },
        Case {
            what: "codec 6",
            edit: |b| b[46] = 6,
            needles: &["codec", "byte 46", "unknown codec"],
        },
        Case {
            what: "codec 255",
            edit: |b| b[46] = 255,
            needles: &["codec", "byte 46"],
        },
        Case {
            what: "layers on a full transfer",
            edit: |b| put_u32(b, 48, 3),
            needles: &["layers", "byte 48", "only a depth-limited transfer"],
        },
        Case {
            what: "threshold on a full transfer",
            edit: |b| b[52..56].copy_from_slice(&0.5f32.to_le_bytes()),
            needles: &["threshold 0.5", "byte 48"],
        },
        Case {
            what: "section_count 0",
            edit: |b| b[184..186].copy_from_slice(&[0, 0]),
            needles: &["section_count", "byte 184"],
        },
        Case {
            what: "section_count u16::MAX",
            edit: |b| b[184..186].copy_from_slice(&[0xff, 0xff]),
            needles: &["section_count", "byte 184", "65535"],
        },
        Case {
            what: "reserved",
            edit: |b| b[187] = 1,
            needles: &["reserved", "byte 186", "must be 0"],
        },
        Case {
            what: "section tag",
            edit: |b| b[188] = 99,
            needles: &["section tag", "byte 188", "99"],
        },
        Case {
            what: "section compression",
            edit: |b| b[189] = 7,
            needles: &["section compression", "byte 189"],
        },
        Case {
            what: "section reserved",
            edit: |b| b[191] = 1,
            needles: &["section reserved", "byte 190"],
        },
        Case {
            what: "encoded_len u64::MAX",
            edit: |b| put_u64(b, 192, u64::MAX),
            needles: &["encoded_len", "byte 192", "does not fit"],
        },
        Case {
            what: "decoded_len u64::MAX",
            edit: |b| put_u64(b, 200, u64::MAX),
            needles: &["decoded_len", "byte 200", "18446744073709551615"],
        },
        Case {
            what: "last section's decoded_len u64::MAX",
            edit: |b| {
                let last = entry(b[184] as usize - 1);
                put_u64(b, last + 12, u64::MAX)
            },
            needles: &["decoded_len", "18446744073709551615"],
        },
        Case {
            what: "last section's encoded_len one more",
            edit: |b| {
                let last = entry(b[184] as usize - 1);
                let n = get_u64(b, last + 4);
                put_u64(b, last + 4, n + 1)
            },
            needles: &["encoded_len", "follow the table"],
        },
        Case {
            what: "encoded_len larger than the body",
            edit: |b| {
                let body = b.len() as u64 - 20;
                put_u64(b, 192, body + 1)
            },
            needles: &["encoded_len", "byte 192", "does not fit"],
        },
        Case {
            what: "a trailing byte",
            edit: |b| b.push(0),
            needles: &["encoded_len", "follow the table"],
        },
    ]
}

#[test]
fn extreme_and_lying_header_fields_are_rejected_naming_the_field() {
    for codec in codecs() {
        for case in cases() {
            let mut bytes = message(codec, false);
            (case.edit)(&mut bytes);
            // Resealed, so that the checksum does not stop the decoder before the field (except
            // for edits of the prefix's own body_len, which resealing would undo).
            if !case.what.starts_with("body_len") {
                reseal(&mut bytes);
            }
            for verify in [false, true] {
                let e = decode_hostile(&bytes, verify)
                    .err()
                    .unwrap_or_else(|| panic!("{codec}, {}: accepted", case.what));
                let text = e.to_string();
                for needle in case.needles {
                    assert!(
                        text.contains(needle),
                        "{codec}, {}: expected {needle:?} in: {text}",
                        case.what
                    );
                }
            }
        }
    }
}

/// `a` with its first `k` sections (table entries and payloads) taken from `b`, resealed.
fn splice(a: &[u8], b: &[u8], k: usize) -> Vec<u8> {
    let n = section_count(a);
    assert_eq!(n, section_count(b));
    // Each section's table entry and payload.
    let sections = |m: &[u8]| -> Vec<(Vec<u8>, Vec<u8>)> {
        let mut at = entry(n);
        (0..n)
            .map(|i| {
                let e = m[entry(i)..entry(i + 1)].to_vec();
                let len = get_u64(m, entry(i) + 4) as usize;
                at += len;
                (e, m[at - len..at].to_vec())
            })
            .collect()
    };
    let (sa, sb) = (sections(a), sections(b));
    let parts: Vec<&(Vec<u8>, Vec<u8>)> = (0..n)
        .map(|i| if i < k { &sb[i] } else { &sa[i] })
        .collect();
    let mut out = a[..FRAME_HEADER_LEN].to_vec();
    for (e, _) in &parts {
        out.extend_from_slice(e);
    }
    for (_, payload) in &parts {
        out.extend_from_slice(payload);
    }
    reseal(&mut out);
    out
}

#[test]
fn inserts_past_the_touched_pixels_are_rejected() {
    // A 3×2 view. Message `a` touches pixels 0 to 2 and inserts at the first and the third; `b`
    // touches pixel 0 only. Both compact their inserts into one row of 3 runs, so `a`'s
    // inserts under `b`'s mask and removals put a fragment in the padding, which no encoder
    // writes: the display would have no pixel to put it at.
    let header = FrameHeader {
        transfer: TransferMethod::Reprojection,
        ..FrameHeader::default()
    };
    let f = frag(0.5, [1, 2, 3, 4], 1);
    let message = |touched: u32, runs: &[Vec<Fragment>]| {
        let mut removals = Removals::new(7);
        for _ in 0..touched {
            removals.push_pixel([]);
        }
        let inserts = DeepFrame::from_pixel_lists(3, 1, runs).unwrap();
        let mask = PixelMask::from_fn(6, |p| p < touched);
        move |codec| {
            let mut out = Vec::new();
            encode_reprojection_into(&mut out, &header, &mask, &removals, &inserts, codec).unwrap();
            out
        }
    };
    let a = message(3, &[vec![f], vec![], vec![f]]);
    let b = message(1, &[vec![f], vec![], vec![]]);
    for codec in codecs() {
        let (a, b) = (a(codec), b(codec));
        assert_eq!(
            decode_frame(&a, &options(true))
                .unwrap()
                .frame
                .fragment_count(),
            2
        );
        let spliced = splice(&a, &b, 2);
        let e = decode_hostile(&spliced, true).unwrap_err();
        assert!(
            e.to_string()
                .contains("1 inserted fragments lie past the touched pixels' runs"),
            "{codec}: {e}"
        );
    }
}

#[test]
fn codec_sections_sized_for_the_view_not_the_compacted_inserts_are_rejected() {
    // The reprojection message's inserts are 3×2 (six pixels) in a 3×4 view (twelve). Its
    // lists section (`lz4`: the list layout, whose length is exact) claiming the view's length
    // passes the table's check, which cannot know the compacted size before the mask is
    // decoded, and is caught once it is.
    let mut bytes = reprojection_message(Codec::Lz4);
    let at = entry(2) + 12;
    let (compacted, view) = (4 * 6 + 12 * 7, 4 * 12 + 12 * 7);
    assert_eq!(get_u64(&bytes, at), compacted);
    put_u64(&mut bytes, at, view);
    reseal(&mut bytes);
    let e = decode_hostile(&bytes, true).unwrap_err();
    assert!(
        e.to_string().contains(&format!(
            "byte {at} (decoded_len): {view} is invalid: the lists section of the 3x2 compacted \
             inserts of a reprojection frame of 7 fragments decodes to exactly {compacted} bytes"
        )),
        "{e}"
    );
}

#[test]
fn lying_decoded_lengths_are_caught_for_every_section() {
    for codec in codecs() {
        let original = message(codec, false);
        for i in 0..codec.sections().len() {
            let at = entry(i) + 12;
            let real = get_u64(&original, at);
            let name = codec.sections()[i].name();
            for lie in [0, 1, real - 1, real + 1, real * 2, real * 300, 1 << 40] {
                if lie == real {
                    continue;
                }
                let mut bytes = original.clone();
                put_u64(&mut bytes, at, lie);
                reseal(&mut bytes);
                let e = decode_hostile(&bytes, true)
                    .err()
                    .unwrap_or_else(|| panic!("{codec}: {name} decoded_len {lie} accepted"));
                let text = e.to_string();
                // Either the table check (impossible length) or the section itself (the payload
                // does not produce that many bytes) names it.
                assert!(
                    text.contains(&format!("byte {at} (decoded_len)"))
                        || text.starts_with(&format!("section {name} at byte ")),
                    "{codec}: {name} decoded_len {lie}: {text}"
                );
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Huge claims in small messages

/// The small frame's message under `codec` with `fragment_count` set to `n` and every section's
/// decoded length set to the smallest the header then allows: the most plausible lie.
fn claiming(codec: Codec, n: u32) -> Vec<u8> {
    let mut bytes = message(codec, false);
    put_u32(&mut bytes, 40, n);
    let pixels = 6;
    for (i, tag) in codec.sections().iter().enumerate() {
        let (lo, _) = tag.decoded_range(pixels, u64::from(n));
        put_u64(&mut bytes, entry(i) + 12, lo);
    }
    reseal(&mut bytes);
    bytes
}

#[test]
fn a_small_message_claiming_2_pow_28_fragments_fails_on_the_section_table() {
    for codec in codecs() {
        let bytes = claiming(codec, 1 << 28);
        assert!(bytes.len() < 400, "{codec}: {} bytes", bytes.len());
        for verify in [false, true] {
            let e = decode_hostile(&bytes, verify).unwrap_err();
            // Rejected before decompressing: no compressor turns a few hundred bytes into
            // gigabytes, and the table says so.
            assert!(
                matches!(
                    e,
                    WireError::Invalid {
                        field: "decoded_len",
                        ..
                    }
                ),
                "{codec}: {e}"
            );
            assert!(e.to_string().contains("cannot expand"), "{codec}: {e}");
            // inspect_frame, which never decompresses, already refuses it.
            assert!(inspect_frame(&bytes, &options(verify)).is_err());
        }
        // Above the limit the header alone is refused.
        let e = decode_hostile(&claiming(codec, (1 << 28) + 1), true).unwrap_err();
        assert!(
            matches!(
                e,
                WireError::Limit {
                    field: "fragment_count",
                    offset: 40,
                    ..
                }
            ),
            "{codec}: {e}"
        );
    }
}

#[test]
fn permissive_limits_do_not_make_huge_claims_overflow() {
    // A decoder configured to accept anything the fields can express.
    let anything = DecodeOptions {
        max_width: u32::MAX,
        max_height: u32::MAX,
        max_pixels: u64::MAX,
        max_fragments: u64::MAX,
        max_body_bytes: u64::MAX,
        verify_checksum: true,
    };
    for (codec, kind) in codecs()
        .into_iter()
        .flat_map(|c| [(c, Kind::Full), (c, Kind::Delta)])
    {
        for (w, h, n) in [
            (u32::MAX, u32::MAX, u32::MAX),
            (u32::MAX, u32::MAX, 0),
            (u32::MAX, 1, u32::MAX),
            (1 << 31, 1 << 31, 7),
            (u32::MAX, 0, 7),
        ] {
            let mut bytes = message_of(codec, kind);
            put_u32(&mut bytes, 32, w);
            put_u32(&mut bytes, 36, h);
            put_u32(&mut bytes, 40, n);
            reseal(&mut bytes);
            let e = decode_frame(&bytes, &anything)
                .expect_err("a 300-byte message cannot hold such a frame");
            assert_located(&e);
            assert!(
                e.to_string().contains("decoded_len"),
                "{codec} {w}x{h}, {n} fragments: {e}"
            );
            let e = decode_frame(&bytes, &DecodeOptions::default()).unwrap_err();
            assert_located(&e);
        }
    }
}

#[test]
fn decoder_limits_hold_at_their_boundary() {
    let frame = small_frame();
    for codec in codecs() {
        let bytes = message(codec, false);
        let body = (bytes.len() - PREFIX_LEN) as u64;
        let exact = DecodeOptions {
            max_width: 3,
            max_height: 2,
            max_pixels: 6,
            max_fragments: 7,
            max_body_bytes: body,
            verify_checksum: true,
        };
        assert!(
            decode_frame(&bytes, &exact).unwrap().frame == frame,
            "{codec}"
        );
        let tighter = [
            (
                DecodeOptions {
                    max_width: 2,
                    ..exact.clone()
                },
                "width",
                32,
            ),
            (
                DecodeOptions {
                    max_height: 1,
                    ..exact.clone()
                },
                "height",
                36,
            ),
            (
                DecodeOptions {
                    max_pixels: 5,
                    ..exact.clone()
                },
                "width·height",
                32,
            ),
            (
                DecodeOptions {
                    max_fragments: 6,
                    ..exact.clone()
                },
                "fragment_count",
                40,
            ),
            (
                DecodeOptions {
                    max_body_bytes: body - 1,
                    ..exact.clone()
                },
                "body_len",
                8,
            ),
        ];
        for (opts, field, offset) in tighter {
            let e = decode_frame(&bytes, &opts).unwrap_err();
            assert!(
                matches!(e, WireError::Limit { field: f, offset: o, .. } if f == field && o == offset),
                "{codec}, {field}: {e:?}"
            );
            // A stream reader sees the body_len limit in the prefix alone.
            if field == "body_len" {
                assert_eq!(parse_prefix(&bytes[..PREFIX_LEN], &opts).unwrap_err(), e);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Sections that decompress but do not describe a frame

#[test]
fn nonsense_payloads_of_the_right_length_are_rejected() {
    // Raw: the payload is the thesis layout itself; corrupt the counts and the nodes in place.
    let original = message(Codec::Raw, false);
    // The thesis section's payload starts after the one table entry: 6 counts, then 7 nodes.
    const P: usize = FRAME_HEADER_LEN + SECTION_ENTRY_LEN;
    let cases = [
        Case {
            what: "counts add up to more",
            edit: |b| b[P] = 3,
            needles: &["up to pixel 4 add up to 8, more than the 7 fragments"],
        },
        Case {
            what: "counts add up to less",
            edit: |b| b[P] = 1,
            needles: &["the counts add up to 6, the header announces 7"],
        },
        Case {
            what: "a count of u32::MAX",
            edit: |b| put_u32(b, P + 4, u32::MAX),
            needles: &["more than the 7 fragments"],
        },
        Case {
            what: "depth 2.0",
            edit: |b| put_u32(b, P + 24, 2.0f32.to_bits()),
            needles: &["fragment 0: depth 2 is outside [0, 1]"],
        },
        Case {
            // Pixel 0's two depths swapped.
            what: "unsorted run",
            edit: |b| {
                put_u32(b, P + 24, 0.5f32.to_bits());
                put_u32(b, P + 36, 0.25f32.to_bits());
            },
            needles: &["pixel 0: fragments are not sorted"],
        },
    ];
    assert_eq!(original[P], 2, "pixel 0 holds 2 fragments");
    for case in cases {
        let mut bytes = original.clone();
        (case.edit)(&mut bytes);
        reseal(&mut bytes);
        let e = decode_hostile(&bytes, true).unwrap_err();
        for needle in case.needles {
            assert!(e.to_string().contains(needle), "{}: {e}", case.what);
        }
    }
    // A negative zero and a NaN are not depths either.
    for bits in [0x8000_0000u32, 0x7fc0_0000, 0x7f80_0000] {
        let mut bytes = original.clone();
        put_u32(&mut bytes, P + 24 + 12 * 6, bits);
        reseal(&mut bytes);
        let e = decode_hostile(&bytes, true).unwrap_err();
        assert!(matches!(e, WireError::Frame(_)), "{bits:#x}: {e}");
    }
}

#[test]
fn deep_sections_with_nonsense_residuals_are_rejected_or_consistent() {
    // deep-lz4 stores the tiny frame's sections as they are: overwrite each byte of each
    // section with a few telling values (zero, one, varint boundaries, all ones) and decode
    // with the checksum resealed; whatever is accepted must re-encode consistently.
    let original = message(Codec::DeepLz4, false);
    let start = entry(4);
    let mut rejected = 0;
    for at in start..original.len() {
        for v in [0x00, 0x01, 0x7f, 0x80, 0xff] {
            if original[at] == v {
                continue;
            }
            let mut bytes = original.clone();
            bytes[at] = v;
            reseal(&mut bytes);
            if decode_hostile(&bytes, true).is_err() {
                rejected += 1;
            }
        }
    }
    assert!(rejected > 0);
}

// ---------------------------------------------------------------------------------------------
// The fuzzing corpus

/// The messages the fuzz target starts from (`fuzz/README.md`): every codec, every header kind
/// (a difference frame among them), a few edge frames, and one of each of the services' small
/// messages. Written to `$STRATA_FUZZ_CORPUS` when it is set.
#[test]
fn fuzz_seed_corpus_decodes() {
    let mut seeds: Vec<(String, Vec<u8>)> = Vec::new();
    let frames = [
        ("small", small_frame()),
        ("empty", DeepFrame::empty(4, 3)),
        ("none", DeepFrame::empty(0, 0)),
    ];
    for (name, frame) in &frames {
        for codec in codecs() {
            let pixels = frame.width() * frame.height();
            let delta = FrameHeader {
                transfer: TransferMethod::Difference,
                ..FrameHeader::default()
            };
            let reprojection = FrameHeader {
                transfer: TransferMethod::Reprojection,
                ..FrameHeader::default()
            };
            for (kind, header) in [
                ("full", FrameHeader::default()),
                ("limited", limited_header()),
                ("delta", delta),
                ("reprojection", reprojection),
            ] {
                let mut bytes = Vec::new();
                match header.transfer {
                    TransferMethod::Difference => {
                        let (changed, stale) = (PixelMask::full(pixels), PixelMask::empty(pixels));
                        encode_delta_into(&mut bytes, &header, &changed, &stale, frame, codec)
                            .unwrap();
                    }
                    TransferMethod::Reprojection => {
                        let mut removals = Removals::new(7);
                        for p in 0..pixels {
                            removals.push_pixel((0..p % 3).map(|i| i * 2));
                        }
                        let touched = PixelMask::full(pixels);
                        encode_reprojection_into(
                            &mut bytes, &header, &touched, &removals, frame, codec,
                        )
                        .unwrap();
                    }
                    _ => encode_frame_into(&mut bytes, &header, frame, codec).unwrap(),
                }
                let back = decode_frame(&bytes, &options(true)).unwrap();
                assert!(back.frame == *frame);
                let codec_name = codec.to_string().replace(':', "_");
                seeds.push((format!("{name}-{kind}-{codec_name}"), bytes));
            }
        }
    }
    // The services' small messages, which `decode` reads too.
    let request = |kind| Request {
        frame_number: 12,
        node_id: 3,
        width: 3,
        height: 2,
        view: [0.5; 16],
        projection: [-2.0; 16],
        transfer: TransferMethod::Difference,
        codec: Codec::DeepLz4,
        kind,
        tolerance: 2,
    };
    for (name, r) in [
        (
            "request-render",
            request(RequestKind::Render { reset: true }),
        ),
        (
            "request-fixup",
            request(RequestKind::Fixup(PixelMask::from_fn(6, |p| p % 2 == 1))),
        ),
    ] {
        let mut bytes = Vec::new();
        r.encode_into(&mut bytes).unwrap();
        assert!(matches!(decode(&bytes, &options(true)), Ok(Message::Request(back)) if back == r));
        seeds.push((name.to_owned(), bytes));
    }
    let hello = Hello {
        triangles: 30_336,
        scene: "spheres".into(),
        objects: vec![(0, "outer".into()), (4, "torus".into())],
    };
    let mut bytes = Vec::new();
    hello.encode_into(&mut bytes).unwrap();
    assert!(matches!(decode(&bytes, &options(true)), Ok(Message::Hello(back)) if back == hello));
    seeds.push(("hello".to_owned(), bytes));
    let stats = NodeStats {
        frame_number: 12,
        fragments_rendered: 7,
        fragments_sent: 5,
        raw_bytes: 84,
        render_us: 1000,
        select_us: 10,
        encode_us: 20,
        fixup: true,
    };
    let mut bytes = Vec::new();
    stats.encode_into(&mut bytes);
    assert!(matches!(decode(&bytes, &options(true)), Ok(Message::Stats(back)) if back == stats));
    seeds.push(("stats".to_owned(), bytes));
    let mut bytes = Vec::new();
    encode_error_into(&mut bytes, "node 3: no such object «torus»");
    assert!(
        matches!(decode(&bytes, &options(true)), Ok(Message::Error(text)) if text.contains("torus"))
    );
    seeds.push(("error".to_owned(), bytes));

    if let Some(dir) = std::env::var_os("STRATA_FUZZ_CORPUS") {
        let dir = std::path::PathBuf::from(dir);
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes) in &seeds {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
        eprintln!("wrote {} seed messages to {}", seeds.len(), dir.display());
    }
}
