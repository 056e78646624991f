//! Fuzzes `strata_wire::decode` on arbitrary bytes, with checksum verification off (so that the
//! fuzzer reaches the header, the section table and the codecs) and on.
//!
//! The decoder must never panic, and whatever it accepts must be a message the encoder writes
//! back: re-encoding a decoded frame (a difference frame with its masks) and decoding that gives
//! the same frame, header, codec and masks, and encoding is deterministic. `decode_frame` and
//! `inspect_frame` (which never decompresses) must accept every frame `decode` accepts. The
//! services' small messages (request, hello, stats, error) that `decode` also reads must
//! re-encode to what was decoded.

#![no_main]

use libfuzzer_sys::fuzz_target;
use strata_wire::{
    DecodeOptions, FrameHeader, FrameMessage, Message, Request, decode, decode_error, decode_frame,
    encode_delta_into, encode_error_into, encode_reprojection_into, encode_frame_into, inspect_frame, parse_prefix,
};

/// The header without its matrices, which are compared as bits (a NaN is not equal to itself).
fn without_matrices(h: &FrameHeader) -> FrameHeader {
    FrameHeader {
        view: [0.0; 16],
        projection: [0.0; 16],
        ..*h
    }
}

fn assert_same(a: &FrameMessage, b: &FrameMessage) {
    assert_eq!(a.codec, b.codec);
    assert!(a.frame == b.frame, "the frame changed on re-encoding");
    assert_eq!(
        a.header.view.map(f32::to_bits),
        b.header.view.map(f32::to_bits)
    );
    assert_eq!(
        a.header.projection.map(f32::to_bits),
        b.header.projection.map(f32::to_bits)
    );
    assert_eq!(without_matrices(&a.header), without_matrices(&b.header));
    assert_eq!((&a.changed, &a.stale), (&b.changed, &b.stale));
    assert_eq!((&a.removals, a.size), (&b.removals, b.size));
}

/// Encodes a decoded frame message again, as a relay would.
fn encode(m: &FrameMessage) -> Vec<u8> {
    let mut out = Vec::new();
    let written = match (&m.changed, &m.stale, &m.removals) {
        (Some(changed), Some(stale), _) => {
            encode_delta_into(&mut out, &m.header, changed, stale, &m.frame, m.codec)
        }
        (Some(touched), None, Some(removals)) => {
            encode_reprojection_into(&mut out, &m.header, touched, removals, &m.frame, m.codec)
        }
        _ => encode_frame_into(&mut out, &m.header, &m.frame, m.codec),
    };
    if let Err(e) = written {
        panic!("the decoder accepted a frame the encoder cannot write: {e}");
    }
    out
}

fn check_frame(data: &[u8], options: &DecodeOptions, message: &FrameMessage) {
    let direct = decode_frame(data, options).expect("decode_frame accepts what decode accepts");
    assert_same(&direct, message);
    let info = inspect_frame(data, options).expect("inspect_frame accepts what decode accepts");
    assert_eq!(info.fragment_count as usize, message.frame.fragment_count());

    let bytes = encode(message);
    let again =
        decode_frame(&bytes, &DecodeOptions::default()).expect("a re-encoded frame decodes");
    assert_same(&again, message);
    assert!(encode(&again) == bytes, "encoding is not deterministic");
}

/// A request with its matrices zeroed, and the matrices' bits.
fn request_parts(r: &Request) -> (Request, [u32; 16], [u32; 16]) {
    let stripped = Request {
        view: [0.0; 16],
        projection: [0.0; 16],
        ..r.clone()
    };
    (
        stripped,
        r.view.map(f32::to_bits),
        r.projection.map(f32::to_bits),
    )
}

fuzz_target!(|data: &[u8]| {
    for verify_checksum in [false, true] {
        let options = DecodeOptions {
            verify_checksum,
            ..DecodeOptions::default()
        };
        let _ = parse_prefix(data, &options);
        let Ok(message) = decode(data, &options) else {
            continue;
        };
        let strict = DecodeOptions::default();
        let mut out = Vec::new();
        match message {
            Message::Frame(frame) => check_frame(data, &options, &frame),
            Message::Request(request) => {
                request
                    .encode_into(&mut out)
                    .expect("a decoded request re-encodes");
                let again = Request::decode(&out, &strict).expect("a re-encoded request decodes");
                assert_eq!(request_parts(&again), request_parts(&request));
            }
            Message::Hello(hello) => {
                hello
                    .encode_into(&mut out)
                    .expect("a decoded hello re-encodes");
                let again = strata_wire::Hello::decode(&out, &strict).expect("hello decodes");
                assert_eq!(again, hello);
            }
            Message::Stats(stats) => {
                stats.encode_into(&mut out);
                let again = strata_wire::NodeStats::decode(&out, &strict).expect("stats decode");
                assert_eq!(again, stats);
            }
            Message::Error(text) => {
                encode_error_into(&mut out, &text);
                assert_eq!(decode_error(&out, &strict).expect("error decodes"), text);
            }
            _ => {}
        }
    }
});
