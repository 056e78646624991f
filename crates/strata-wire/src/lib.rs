//! strata's wire format: self-describing, versioned messages that carry DeepFrames between
//! processes and machines, with lossless codecs and a decoder that is safe on hostile input.
//!
//! DeepFrame is the exchange format of the engine (the pipeline design); this crate is how it crosses a
//! socket. The remote-rendering services of Jähne 2014 (render nodes, a display node) build on the
//! message types here. `docs/wire-format.md` is the byte-by-byte specification.
//!
//! - [`message`]: the 20-byte prefix every message starts with (magic `STRW`, version, type, body
//!   length, CRC-32), and the frame message: frame number, node id, the view and projection
//!   matrices, size, fragment count, transfer method, codec, and a section table giving each
//!   section's encoded and decoded length so a reader validates before it allocates;
//! - [`codec`]: the codecs — `raw` (Jähne 2014's 4-byte header + 12-byte nodes), `lz4` and `zstd`
//!   over that layout, and `deep-lz4` / `deep-zstd`, a DeepFrame-aware layout (varint counts,
//!   depth and colour predicted from neighbouring pixels' same layer, byte planes, zero-run object
//!   ids) under LZ4 or zstd;
//! - [`mask`]: sets of pixels as runs (what a `difference` frame replaces);
//! - [`control`]: the services' small messages — request, hello, stats, error;
//! - [`mfr`]: the multi-frame-rate messages between a fast and a slow client (hello, state
//!   snapshot, buffer header), and [`stream`]: whole messages from a blocking socket;
//! - [`WireError`]: every failure, naming the field and its byte offset; decoding never panics.
//!
//! ```
//! use strata_core::{DeepFrame, Fragment, ObjectId, Rgba8};
//! use strata_wire::{Codec, DecodeOptions, FrameHeader, decode_frame, encode_frame};
//!
//! let frag = |depth, object| Fragment { depth, color: Rgba8([255, 0, 0, 128]), object: ObjectId(object) };
//! let frame = DeepFrame::from_pixel_lists(2, 1, &[vec![frag(0.5, 1), frag(0.25, 2)], vec![]]).unwrap();
//! let header = FrameHeader { frame_number: 7, ..FrameHeader::default() };
//! for codec in Codec::ALL {
//!     let bytes = encode_frame(&header, &frame, codec).unwrap();
//!     let back = decode_frame(&bytes, &DecodeOptions::default()).unwrap();
//!     assert_eq!((back.header, back.codec, &back.frame), (header, codec, &frame));
//! }
//! ```

mod bytes;
pub mod codec;
pub mod control;
mod error;
pub mod mask;
pub mod message;
pub mod mfr;
pub mod removals;
pub mod stream;

pub use codec::{Codec, Compression, SectionInfo, SectionTag, UnknownCodec};
pub use control::{
    Hello, NodeStats, Request, RequestKind, decode_error, encode_error_into, seed_layout_bytes,
};
pub use error::WireError;
pub use mask::{MaskBuilder, PixelMask};
pub use message::{
    DecodeOptions, FrameDecoder, FrameEncoder, FrameHeader, FrameInfo, FrameMessage, MAGIC,
    Message, MessageType, PREFIX_LEN, Prefix, TYPE_OFFSET, TransferMethod, VERSION, compact_height,
    decode, decode_frame, encode_delta_into, encode_frame, encode_frame_into,
    encode_reprojection_into, inspect_frame, message_type, parse_prefix,
};
pub use removals::Removals;
