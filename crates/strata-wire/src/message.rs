//! Message framing: the 20-byte prefix every message starts with, and the frame message.
//!
//! All integers and floats are little-endian. Offsets below are from the first byte of the
//! message; `docs/wire-format.md` is the full specification with a worked example.
//!
//! # Prefix (20 bytes, every message type)
//!
//! ```text
//!  0  magic        [u8; 4]  "STRW"
//!  4  version      u16      6 (version 5 laid a reprojection frame's inserts out over the
//!                           whole frame; earlier versions: `docs/wire-format.md` §2)
//!  6  type         u8       1 frame, 2 request, 4 error, 5 hello, 6 stats (3: reserved),
//!                           7–9 multi-frame rendering (see `mfr.rs`)
//!  7  flags        u8       0 (reserved)
//!  8  body_len     u64      bytes after the prefix
//! 16  body_crc32   u32      CRC-32 (ISO-HDLC, as zlib) of those bytes
//! ```
//!
//! A stream reader reads the prefix ([`parse_prefix`]), checks `body_len` against its limit, then
//! reads exactly `body_len` more bytes.
//!
//! # Frame body (type 1)
//!
//! ```text
//!  20  frame_number       u64
//!  28  node_id            u32
//!  32  width              u32      ≤ 16384 by default
//!  36  height             u32      ≤ 16384 by default
//!  40  fragment_count     u32
//!  44  transfer           u8       0 full, 1 depth-limited, 2 difference, 3 reprojection
//!  45  transfer_flags     u8       bit 0: opacity threshold present (depth-limited only)
//!                                  bit 1: fixup reply (difference only)
//!  46  codec              u8       0 raw, 1 lz4, 2 zstd, 3 deep-lz4, 4 deep-zstd
//!  47  codec_param        i8       zstd level (zstd, deep-zstd), else 0
//!  48  layers             u32      depth-limited: N ≥ 1, else 0
//!  52  opacity_threshold  f32      depth-limited with threshold: in (0, 1], else 0
//!  56  view               [f32; 16] column-major, world → eye
//! 120  projection         [f32; 16] column-major, eye → clip
//! 184  section_count      u16      the codec's section count
//! 186  reserved           u16      0
//! 188  section table      section_count × 20 bytes:
//!        +0 tag u8 | +1 compression u8 | +2 reserved u16 | +4 encoded_len u64 | +12 decoded_len u64
//! 188 + 20·section_count  the payloads, in table order, back to back
//! ```
//!
//! A `difference` frame has two more sections before the codec's, both [`PixelMask`]s compressed
//! like the others: `mask` (tag 32), the pixels whose runs the message replaces — its frame holds
//! no fragments elsewhere, and a masked pixel with no fragments is a deletion — and `stale`
//! (tag 33), pixels not replaced whose runs changed in depth but not in resolved colour, so the
//! display's copy is stale there if another node's fragments interleave with it.
//!
//! A `reprojection` frame has two sections before the codec's: `mask` (tag 32), the pixels it
//! touches, and `removals` (tag 34, [`Removals`]), the positions each touched pixel loses from the
//! display's reprojected run. Its frame holds the inserted *normal* fragments (their colour bytes
//! are [`strata_core::PackedNormal`]s) **compacted**: run `i` is the inserts of the mask's `i`-th
//! pixel, the runs laid out `width` to a row over `⌈touched / width⌉` rows, the last row padded
//! with empty runs ([`compact_height`]). The header's `width` and `height` are the view's; the
//! codec's sections hold the compacted frame (its `counts` one per touched pixel, not one per
//! pixel of the view). Version 5 laid the inserts out over the whole view, where two thirds
//! of a turning dragon's pixels were empty runs the codec walked, counted and coded: compacted,
//! a render node's wire encode takes a fifth less time (`docs/wire-format.md` §3.4).

use strata_core::DeepFrame;

use crate::bytes::Reader;
use crate::codec::{self, Codec, Compression, EncodedSection, SectionInfo, SectionRef, SectionTag};
use crate::error::WireError;
use crate::mask::PixelMask;
use crate::removals::Removals;

/// The four bytes every message starts with.
pub const MAGIC: [u8; 4] = *b"STRW";
/// The format version this crate writes and reads.
pub const VERSION: u16 = 6;
/// Bytes in the prefix.
pub const PREFIX_LEN: usize = 20;
/// Offset of the prefix's `type` byte.
pub const TYPE_OFFSET: usize = 6;
/// Bytes of a frame message before its section table.
pub const FRAME_HEADER_LEN: usize = 188;
/// Bytes per section-table entry.
pub const SECTION_ENTRY_LEN: usize = 20;

/// What a message carries (the prefix's `type` byte).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
#[non_exhaustive]
pub enum MessageType {
    /// A DeepFrame rendered by a node.
    Frame = 1,
    /// The display asks a node for a frame ([`crate::Request`]).
    Request = 2,
    /// Something went wrong; the sender closes the connection ([`crate::encode_error_into`]).
    Error = 4,
    /// A node introduces itself ([`crate::Hello`]).
    Hello = 5,
    /// A node's figures for the frame message it just sent ([`crate::NodeStats`]).
    Stats = 6,
    /// Multi-frame rendering: a client introduces itself ([`crate::mfr::MfrHello`]).
    MfrHello = 7,
    /// Multi-frame rendering: a state snapshot, fast → slow client ([`crate::mfr::MfrSnapshot`]).
    MfrSnapshot = 8,
    /// Multi-frame rendering: a slow client's buffer header; a frame message follows
    /// ([`crate::mfr::MfrBuffer`]).
    MfrBuffer = 9,
}

impl MessageType {
    /// The type byte's meaning, or the error a decoder reports for it.
    pub fn from_byte(b: u8) -> Result<Self, WireError> {
        let what = match b {
            1 => return Ok(MessageType::Frame),
            2 => return Ok(MessageType::Request),
            4 => return Ok(MessageType::Error),
            5 => return Ok(MessageType::Hello),
            6 => return Ok(MessageType::Stats),
            7 => return Ok(MessageType::MfrHello),
            8 => return Ok(MessageType::MfrSnapshot),
            9 => return Ok(MessageType::MfrBuffer),
            3 => "reserved for reprojection deltas",
            _ => "unknown",
        };
        Err(WireError::UnsupportedMessageType { found: b, what })
    }
}

/// The type of the message `bytes` starts with, read from its prefix's `type` byte without
/// checking anything else (`None` for a short prefix or an unknown type): what a writer that
/// queued the message needs to know, not a decoder.
pub fn message_type(bytes: &[u8]) -> Option<MessageType> {
    bytes
        .get(TYPE_OFFSET)
        .and_then(|&b| MessageType::from_byte(b).ok())
}

/// What a decoder accepts; every limit is checked before the allocation it guards.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodeOptions {
    /// Largest `width` (default 16384).
    pub max_width: u32,
    /// Largest `height` (default 16384).
    pub max_height: u32,
    /// Largest `width · height` (default 2^26 = 64 Mi pixels, e.g. 8192 × 8192).
    pub max_pixels: u64,
    /// Largest `fragment_count` (default 2^28 = 256 Mi fragments, 3 GiB of columns).
    pub max_fragments: u64,
    /// Largest `body_len` (default 2^32 bytes).
    pub max_body_bytes: u64,
    /// Check the body's CRC-32 (default true; fuzzing turns it off to reach the fields).
    pub verify_checksum: bool,
}

impl Default for DecodeOptions {
    fn default() -> Self {
        DecodeOptions {
            max_width: 16_384,
            max_height: 16_384,
            max_pixels: 1 << 26,
            max_fragments: 1 << 28,
            max_body_bytes: 1 << 32,
            verify_checksum: true,
        }
    }
}

/// The parsed prefix.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Prefix {
    /// The message type.
    pub kind: MessageType,
    /// Bytes after the prefix.
    pub body_len: u64,
    /// CRC-32 of the body.
    pub body_crc32: u32,
}

/// How the node chose the fragments it sent (Jähne 2014 ch. 3–5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TransferMethod {
    /// Every fragment.
    Full,
    /// The `layers` nearest fragments per pixel, stopping early once the accumulated opacity
    /// reaches `opacity_threshold` when there is one (Jähne 2014 ch. 3).
    DepthLimited {
        /// N ≥ 1.
        layers: u32,
        /// In (0, 1].
        opacity_threshold: Option<f32>,
    },
    /// Only pixels whose fragment list changed (Jähne 2014 ch. 4).
    Difference,
    /// Inserts and removals against the reprojected previous frame (Jähne 2014 ch. 5).
    Reprojection,
}

impl TransferMethod {
    /// `(transfer, transfer_flags, layers, opacity_threshold)` as written.
    pub(crate) fn to_fields(self) -> (u8, u8, u32, f32) {
        match self {
            TransferMethod::Full => (0, 0, 0, 0.0),
            TransferMethod::DepthLimited {
                layers,
                opacity_threshold,
            } => match opacity_threshold {
                Some(t) => (1, 1, layers, t),
                None => (1, 0, layers, 0.0),
            },
            TransferMethod::Difference => (2, 0, 0, 0.0),
            TransferMethod::Reprojection => (3, 0, 0, 0.0),
        }
    }

    pub(crate) fn check(self) -> Result<(), String> {
        if let TransferMethod::DepthLimited {
            layers,
            opacity_threshold,
        } = self
        {
            if layers == 0 {
                return Err("depth-limited transfer needs at least 1 layer".into());
            }
            if let Some(t) = opacity_threshold
                && !(t > 0.0 && t <= 1.0)
            {
                return Err(format!("opacity threshold {t} is outside (0, 1]"));
            }
        }
        Ok(())
    }
}

/// Everything about a frame except its fragments.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameHeader {
    /// The animation frame (display's numbering).
    pub frame_number: u64,
    /// The render node that sent it.
    pub node_id: u32,
    /// World → eye matrix the frame was rendered with, column-major (`glam::Mat4::to_cols_array`).
    pub view: [f32; 16],
    /// Eye → clip matrix, column-major.
    pub projection: [f32; 16],
    /// How the fragments were chosen.
    pub transfer: TransferMethod,
    /// Difference transfer only: this message answers the display's request for exact copies of
    /// some pixels of frame `frame_number` (the display's fixup round), rather than being the
    /// frame's delta.
    pub fixup: bool,
}

impl Default for FrameHeader {
    /// Frame 0 of node 0, identity matrices, full transfer.
    fn default() -> Self {
        const IDENTITY: [f32; 16] = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        FrameHeader {
            frame_number: 0,
            node_id: 0,
            view: IDENTITY,
            projection: IDENTITY,
            transfer: TransferMethod::Full,
            fixup: false,
        }
    }
}

/// A decoded frame message.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMessage {
    /// Its header.
    pub header: FrameHeader,
    /// The codec it was encoded with.
    pub codec: Codec,
    /// The fragments: in a reprojection frame, its inserts compacted ([`compact_height`]).
    pub frame: DeepFrame,
    /// Difference transfer: the pixels whose runs `frame` replaces (runs outside it are empty).
    pub changed: Option<PixelMask>,
    /// Difference transfer: pixels whose held copy became depth-stale.
    pub stale: Option<PixelMask>,
    /// Reprojection transfer: the positions each pixel of `changed` loses.
    pub removals: Option<Removals>,
    /// The view's width and height in pixels: `frame`'s, except in a reprojection frame, whose
    /// `frame` holds its inserts compacted ([`compact_height`]).
    pub size: (u32, u32),
}

/// The height of a reprojection frame's compacted inserts: `touched` runs (one a touched pixel,
/// in mask order) laid out `width` to a row, the last row padded with empty runs. Zero when
/// `width` is.
pub fn compact_height(touched: u32, width: u32) -> u32 {
    touched
        .checked_div(width)
        .map_or(0, |_| touched.div_ceil(width))
}

/// A frame message's header and section table, without decoding its payloads.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameInfo {
    /// Its header.
    pub header: FrameHeader,
    /// The codec.
    pub codec: Codec,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Fragments the frame holds.
    pub fragment_count: u32,
    /// The section table (the mask first in a difference frame).
    pub sections: Vec<SectionInfo>,
}

/// Any decoded message.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Message {
    /// A frame.
    Frame(FrameMessage),
    /// A request for a frame.
    Request(crate::Request),
    /// An error text.
    Error(String),
    /// A node's introduction.
    Hello(crate::Hello),
    /// A node's statistics.
    Stats(crate::NodeStats),
    /// A multi-frame-rate client's introduction.
    MfrHello(crate::mfr::MfrHello),
    /// A multi-frame-rate state snapshot.
    MfrSnapshot(crate::mfr::MfrSnapshot),
    /// A slow client's buffer header.
    MfrBuffer(crate::mfr::MfrBuffer),
}

// ----- encoding -----------------------------------------------------------------------------

/// Encodes `frame` as one frame message. A producer of a stream of frames encodes faster with
/// a [`FrameEncoder`], which keeps its buffers between frames.
pub fn encode_frame(
    header: &FrameHeader,
    frame: &DeepFrame,
    codec: Codec,
) -> Result<Vec<u8>, WireError> {
    let mut out = Vec::new();
    encode_frame_into(&mut out, header, frame, codec)?;
    Ok(out)
}

/// Encodes `frame` as one frame message, replacing the contents of `out` (whose capacity is
/// reused); see [`FrameEncoder::encode_frame_into`].
pub fn encode_frame_into(
    out: &mut Vec<u8>,
    header: &FrameHeader,
    frame: &DeepFrame,
    codec: Codec,
) -> Result<(), WireError> {
    FrameEncoder::new().encode_frame_into(out, header, frame, codec)
}

/// Encodes a `difference` frame into `out`; see [`FrameEncoder::encode_delta_into`].
pub fn encode_delta_into(
    out: &mut Vec<u8>,
    header: &FrameHeader,
    changed: &PixelMask,
    stale: &PixelMask,
    frame: &DeepFrame,
    codec: Codec,
) -> Result<(), WireError> {
    FrameEncoder::new().encode_delta_into(out, header, changed, stale, frame, codec)
}

/// Encodes a `reprojection` frame into `out`; see [`FrameEncoder::encode_reprojection_into`].
pub fn encode_reprojection_into(
    out: &mut Vec<u8>,
    header: &FrameHeader,
    touched: &PixelMask,
    removals: &Removals,
    inserts: &DeepFrame,
    codec: Codec,
) -> Result<(), WireError> {
    FrameEncoder::new().encode_reprojection_into(out, header, touched, removals, inserts, codec)
}

/// Encodes a stream of frame messages, keeping its buffers between them: each section's bytes
/// before compression (the deep layout's planes of residuals, a mask) and its compressed
/// payload. The messages are byte for byte those of [`encode_frame_into`] and the other free
/// functions (tested); what changes is that a steady stream lays out and compresses its frames
/// in memory it already has, instead of about four bytes of fresh, kernel-zeroed pages a
/// fragment per frame.
#[derive(Debug, Default)]
pub struct FrameEncoder {
    scratch: codec::EncodeScratch,
}

impl FrameEncoder {
    /// An encoder with no buffers yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Encodes `frame` as one frame message, replacing the contents of `out` (whose capacity is
    /// reused).
    pub fn encode_frame_into(
        &mut self,
        out: &mut Vec<u8>,
        header: &FrameHeader,
        frame: &DeepFrame,
        codec: Codec,
    ) -> Result<(), WireError> {
        if header.fixup {
            return Err(WireError::Encode(
                "only a difference frame can be a fixup reply".into(),
            ));
        }
        if header.transfer == TransferMethod::Difference {
            return Err(WireError::Encode(
                "a difference frame needs its pixel mask: use encode_delta_into".into(),
            ));
        }
        if header.transfer == TransferMethod::Reprojection {
            return Err(WireError::Encode(
                "a reprojection frame needs its mask and removals: use encode_reprojection_into"
                    .into(),
            ));
        }
        header.transfer.check().map_err(WireError::Encode)?;
        let size = (frame.width(), frame.height());
        self.write_message(out, header, size, frame, codec, |_| {})
    }

    /// Encodes a `difference` frame: the runs of `frame` at the pixels of `changed` replace the
    /// display's copies (an empty run deletes). `frame` must hold no fragments outside
    /// `changed`.
    pub fn encode_delta_into(
        &mut self,
        out: &mut Vec<u8>,
        header: &FrameHeader,
        changed: &PixelMask,
        stale: &PixelMask,
        frame: &DeepFrame,
        codec: Codec,
    ) -> Result<(), WireError> {
        if header.transfer != TransferMethod::Difference {
            return Err(WireError::Encode(
                "only a difference frame carries a pixel mask".into(),
            ));
        }
        masks_fit(frame, &[changed, stale])?;
        all_inside(frame, changed)?;
        let size = (frame.width(), frame.height());
        self.write_message(out, header, size, frame, codec, |scratch| {
            for (tag, m) in [(SectionTag::Mask, changed), (SectionTag::Stale, stale)] {
                scratch.push_with(tag, |raw| m.encode(raw));
            }
        })
    }

    /// Encodes a `reprojection` frame: at the pixels of `touched`, the display removes the
    /// positions `removals` lists (one entry per touched pixel, in order) from its reprojected
    /// runs and inserts the normal fragments of `inserts`, the touched pixels' runs compacted:
    /// run `i` is the `i`-th touched pixel's, `inserts.width()` (the view's width) to a row over
    /// [`compact_height`] rows, its padding empty. The view's height is `touched`'s pixel count
    /// over that width.
    pub fn encode_reprojection_into(
        &mut self,
        out: &mut Vec<u8>,
        header: &FrameHeader,
        touched: &PixelMask,
        removals: &Removals,
        inserts: &DeepFrame,
        codec: Codec,
    ) -> Result<(), WireError> {
        if header.transfer != TransferMethod::Reprojection || header.fixup {
            return Err(WireError::Encode(
                "encode_reprojection_into writes reprojection frames only".into(),
            ));
        }
        let (width, view_pixels) = (inserts.width(), touched.frame_pixels());
        if (width == 0 && view_pixels != 0)
            || view_pixels.checked_rem(width).is_some_and(|r| r != 0)
        {
            return Err(WireError::Encode(format!(
                "a mask covers {view_pixels} pixels, not a whole number of {width}-pixel rows"
            )));
        }
        let height = view_pixels.checked_div(width).unwrap_or(0);
        if removals.pixel_count() != touched.len() as usize {
            return Err(WireError::Encode(format!(
                "{} removal entries for {} touched pixels",
                removals.pixel_count(),
                touched.len()
            )));
        }
        let rows = compact_height(touched.len(), width);
        if inserts.height() != rows {
            return Err(WireError::Encode(format!(
                "the inserts of {} touched pixels take {rows} rows of {width}, not {}",
                touched.len(),
                inserts.height()
            )));
        }
        let padding = past_touched(inserts, touched.len());
        if padding > 0 {
            return Err(WireError::Encode(format!(
                "{padding} inserted fragments lie past the touched pixels' runs"
            )));
        }
        self.write_message(out, header, (width, height), inserts, codec, |scratch| {
            scratch.push_with(SectionTag::Mask, |raw| touched.encode(raw));
            scratch.push_with(SectionTag::Removals, |raw| removals.encode(raw));
        })
    }

    /// Lays out the sections `extra` appends, then `frame`'s in `codec`'s layout, compresses
    /// them all and writes the message into `out`, for a view of `size` (`frame`'s, except a
    /// reprojection frame's compacted inserts).
    fn write_message(
        &mut self,
        out: &mut Vec<u8>,
        header: &FrameHeader,
        size: (u32, u32),
        frame: &DeepFrame,
        codec: Codec,
        extra: impl FnOnce(&mut codec::EncodeScratch),
    ) -> Result<(), WireError> {
        codec.validate()?;
        self.scratch.clear();
        extra(&mut self.scratch);
        self.scratch.push_frame(frame, codec);
        let size = (size.0, size.1, frame.fragment_count());
        write_frame(out, header, size, codec, &self.scratch.sections(codec)?);
        Ok(())
    }
}

/// An encoder's check that every mask of a message is a mask of `frame`'s pixels.
fn masks_fit(frame: &DeepFrame, masks: &[&PixelMask]) -> Result<(), WireError> {
    let pixels = u64::from(frame.width()) * u64::from(frame.height());
    match masks.iter().find(|m| u64::from(m.frame_pixels()) != pixels) {
        Some(m) => Err(WireError::Encode(format!(
            "a mask covers {} pixels, the frame has {pixels}",
            m.frame_pixels()
        ))),
        None => Ok(()),
    }
}

/// An encoder's check that `frame` holds fragments only at pixels of `mask`.
fn all_inside(frame: &DeepFrame, mask: &PixelMask) -> Result<(), WireError> {
    match outside_mask(frame, mask) {
        0 => Ok(()),
        outside => Err(WireError::Encode(format!(
            "{outside} fragments lie outside the pixel mask"
        ))),
    }
}

/// Fragments of a reprojection frame's compacted inserts past the runs of its `touched` pixels
/// (in the padding of the last row).
fn past_touched(inserts: &DeepFrame, touched: u32) -> u64 {
    let offsets = inserts.offsets();
    offsets
        .get(touched as usize)
        .map_or(0, |&o| inserts.fragment_count() as u64 - u64::from(o))
}

/// Fragments of `frame` at pixels outside `mask`.
fn outside_mask(frame: &DeepFrame, mask: &PixelMask) -> u64 {
    let offsets = frame.offsets();
    let total = frame.fragment_count() as u64;
    let inside: u64 = mask
        .runs()
        .iter()
        .map(|&(s, l)| u64::from(offsets[(s + l) as usize] - offsets[s as usize]))
        .sum();
    total - inside
}

/// Writes a frame message: `size` is the view's width and height and the fragments sent.
fn write_frame(
    out: &mut Vec<u8>,
    header: &FrameHeader,
    size: (u32, u32, usize),
    codec: Codec,
    sections: &[EncodedSection<'_>],
) {
    let payload: usize = sections.iter().map(|s| s.payload.len()).sum();
    out.clear();
    out.reserve(FRAME_HEADER_LEN + SECTION_ENTRY_LEN * sections.len() + payload);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.push(MessageType::Frame as u8);
    out.push(0); // flags
    out.extend_from_slice(&[0; 12]); // body_len and crc, patched below
    out.extend_from_slice(&header.frame_number.to_le_bytes());
    out.extend_from_slice(&header.node_id.to_le_bytes());
    let (width, height, fragments) = size;
    out.extend_from_slice(&width.to_le_bytes());
    out.extend_from_slice(&height.to_le_bytes());
    out.extend_from_slice(&(fragments as u32).to_le_bytes());
    let (transfer, mut flags, layers, threshold) = header.transfer.to_fields();
    if header.fixup {
        flags |= 2;
    }
    out.extend_from_slice(&[transfer, flags, codec.id(), codec.param()]);
    out.extend_from_slice(&layers.to_le_bytes());
    out.extend_from_slice(&threshold.to_le_bytes());
    for v in header.view.iter().chain(&header.projection) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&(sections.len() as u16).to_le_bytes());
    out.extend_from_slice(&[0, 0]);
    debug_assert_eq!(out.len(), FRAME_HEADER_LEN);
    for s in sections {
        out.extend_from_slice(&[s.info.tag as u8, s.info.compression as u8, 0, 0]);
        out.extend_from_slice(&s.info.encoded_len.to_le_bytes());
        out.extend_from_slice(&s.info.decoded_len.to_le_bytes());
    }
    for s in sections {
        out.extend_from_slice(s.payload);
    }
    let body_len = (out.len() - PREFIX_LEN) as u64;
    let crc = crc32fast::hash(&out[PREFIX_LEN..]);
    out[8..16].copy_from_slice(&body_len.to_le_bytes());
    out[16..20].copy_from_slice(&crc.to_le_bytes());
}

// ----- decoding -----------------------------------------------------------------------------

/// Parses and checks the 20-byte prefix (magic, version, type, flags, `body_len` against
/// `options.max_body_bytes`). `bytes` may be longer than the prefix.
pub fn parse_prefix(bytes: &[u8], options: &DecodeOptions) -> Result<Prefix, WireError> {
    let mut r = Reader::new(bytes, 0);
    let magic = r.bytes4("magic")?;
    if magic != MAGIC {
        return Err(WireError::BadMagic { found: magic });
    }
    let version = r.u16("version")?;
    if version != VERSION {
        return Err(WireError::UnsupportedVersion {
            found: version,
            supported: VERSION,
        });
    }
    let kind = MessageType::from_byte(r.u8("type")?)?;
    let flags = r.u8("flags")?;
    if flags != 0 {
        return Err(WireError::invalid(
            "flags",
            7,
            format!("{flags:#04x}"),
            "no flags are defined in version 6",
        ));
    }
    let body_len = r.u64("body_len")?;
    if body_len > options.max_body_bytes {
        return Err(WireError::Limit {
            field: "body_len",
            offset: 8,
            value: body_len,
            limit: options.max_body_bytes,
        });
    }
    let body_crc32 = r.u32("body_crc32")?;
    Ok(Prefix {
        kind,
        body_len,
        body_crc32,
    })
}

/// Decodes one complete message (exactly one: trailing bytes are an error).
pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Message, WireError> {
    let prefix = parse_prefix(bytes, options)?;
    match prefix.kind {
        MessageType::Frame => decode_frame(bytes, options).map(Message::Frame),
        MessageType::Request => crate::Request::decode(bytes, options).map(Message::Request),
        MessageType::Error => crate::control::decode_error(bytes, options).map(Message::Error),
        MessageType::Hello => crate::Hello::decode(bytes, options).map(Message::Hello),
        MessageType::Stats => crate::NodeStats::decode(bytes, options).map(Message::Stats),
        MessageType::MfrHello => {
            crate::mfr::MfrHello::decode(bytes, options).map(Message::MfrHello)
        }
        MessageType::MfrSnapshot => {
            crate::mfr::MfrSnapshot::decode(bytes, options).map(Message::MfrSnapshot)
        }
        MessageType::MfrBuffer => {
            crate::mfr::MfrBuffer::decode(bytes, options).map(Message::MfrBuffer)
        }
    }
}

/// Decodes one complete frame message. A consumer of a stream of frames decodes faster with a
/// [`FrameDecoder`], which keeps its buffers between frames.
pub fn decode_frame(bytes: &[u8], options: &DecodeOptions) -> Result<FrameMessage, WireError> {
    FrameDecoder::new().decode_frame(bytes, options)
}

/// Decodes a stream of frame messages, keeping its buffers between them: the decompressed
/// sections always, and the columns of a frame handed back with [`FrameDecoder::recycle`] once
/// its holder is done with it. The messages decode exactly as with [`decode_frame`] (tested);
/// what changes is that a steady stream touches memory it already has, instead of pages the
/// kernel must zero (2–5 % of a fresh decode's time on 1280×720 frames of the meshes in
/// `strata codecs`, AMD EPYC; more where the allocator hands every frame fresh pages).
#[derive(Debug, Default)]
pub struct FrameDecoder {
    scratch: codec::Scratch,
}

impl FrameDecoder {
    /// A decoder with no buffers yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decodes one complete frame message (as [`decode_frame`]). After an error the decoder
    /// is still usable.
    pub fn decode_frame(
        &mut self,
        bytes: &[u8],
        options: &DecodeOptions,
    ) -> Result<FrameMessage, WireError> {
        let parsed = parse_frame(bytes, options)?;
        let scratch = &mut self.scratch;
        let (width, height) = (parsed.info.width, parsed.info.height);
        let fragments = parsed.info.fragment_count as usize;
        // Below the decode limits; u32 because masks index pixels with u32.
        let pixels = u32::try_from(u64::from(width) * u64::from(height)).map_err(|_| {
            WireError::invalid(
                "width·height",
                32,
                u64::from(width) * u64::from(height),
                "a frame holds at most 2^32 - 1 pixels (its masks index them with u32)",
            )
        })?;
        let reprojection = parsed.info.header.transfer == TransferMethod::Reprojection;
        // Every section at once, except in a reprojection frame: there the codec's sections
        // hold one run a touched pixel, so its mask is decoded first.
        let (side, first, rows, decoded) = if reprojection {
            if width == 0 && height != 0 {
                // Its view's height would be lost: a reprojection frame tells it by the
                // mask's pixels over the width.
                return Err(WireError::invalid(
                    "height",
                    36,
                    height,
                    "a reprojection frame of width 0 has height 0",
                ));
            }
            codec::decompress_sections(&parsed.sections[..1], scratch, 0, fragments)?;
            let mask = PixelMask::decode(&scratch.sections[0], parsed.sections[0].offset, pixels)?;
            let rows = compact_height(mask.len(), width);
            check_compacted(&parsed, 2, rows)?;
            // The removals with the codec's sections, the counts read for the compacted
            // frame's pixels (below the view's).
            codec::decompress_sections(
                &parsed.sections[1..],
                scratch,
                width as usize * rows as usize,
                fragments,
            )?;
            let removals =
                Removals::decode(&scratch.sections[0], parsed.sections[1].offset, mask.len())?;
            let side = SideSections {
                changed: Some(mask),
                stale: None,
                removals: Some(removals),
            };
            (
                side,
                2,
                rows,
                &scratch.sections[1..parsed.sections.len() - 1],
            )
        } else {
            // Below the decode limits, which bound width·height and the fragments.
            codec::decompress_sections(&parsed.sections, scratch, pixels as usize, fragments)?;
            let decoded = &scratch.sections[..parsed.sections.len()];
            let (side, first) = decode_side_sections(&parsed, decoded, pixels)?;
            (side, first, height, &decoded[first..])
        };
        let SideSections {
            changed,
            stale,
            removals,
        } = side;
        let frame = codec::decode_sections(
            parsed.info.codec,
            width,
            rows,
            parsed.info.fragment_count,
            &parsed.sections[first..],
            decoded,
            &mut scratch.columns,
        )?;
        if let (Some(mask), true) = (&changed, reprojection) {
            let past = past_touched(&frame, mask.len());
            if past > 0 {
                return Err(WireError::section(
                    "mask",
                    parsed.sections[0].offset,
                    format!("{past} inserted fragments lie past the touched pixels' runs"),
                ));
            }
        } else if let Some(mask) = &changed {
            let outside = outside_mask(&frame, mask);
            if outside > 0 {
                return Err(WireError::section(
                    "mask",
                    parsed.sections[0].offset,
                    format!("{outside} fragments lie outside the pixel mask"),
                ));
            }
        }
        Ok(FrameMessage {
            header: parsed.info.header,
            codec: parsed.info.codec,
            frame,
            changed,
            stale,
            removals,
            size: (width, height),
        })
    }

    /// Hands a frame's allocations back for the next decode (a frame this decoder made, or any
    /// other: only its capacity is kept).
    pub fn recycle(&mut self, frame: DeepFrame) {
        self.scratch.recycle(frame);
    }
}

/// What a difference or reprojection frame carries before the codec's sections.
#[derive(Default)]
struct SideSections {
    changed: Option<PixelMask>,
    stale: Option<PixelMask>,
    removals: Option<Removals>,
}

/// Decodes the difference transfer's `mask` and `stale` from the front of `decoded`; returns
/// them with the index of the codec's first section. (A reprojection frame's `mask` and
/// `removals` are decoded in [`FrameDecoder::decode_frame`], between its two decompressions.)
fn decode_side_sections(
    parsed: &ParsedFrame<'_>,
    decoded: &[Vec<u8>],
    pixels: u32,
) -> Result<(SideSections, usize), WireError> {
    let at = |i: usize| parsed.sections[i].offset;
    match parsed.info.header.transfer {
        TransferMethod::Difference => {
            let mask = PixelMask::decode(&decoded[0], at(0), pixels)?;
            let stale = PixelMask::decode(&decoded[1], at(1), pixels)?;
            let side = SideSections {
                changed: Some(mask),
                stale: Some(stale),
                removals: None,
            };
            Ok((side, 2))
        }
        _ => Ok((SideSections::default(), 0)),
    }
}

/// Parses and validates a frame message's header and section table without decompressing
/// anything (what `strata codecs` reports per section).
pub fn inspect_frame(bytes: &[u8], options: &DecodeOptions) -> Result<FrameInfo, WireError> {
    parse_frame(bytes, options).map(|p| p.info)
}

struct ParsedFrame<'a> {
    info: FrameInfo,
    sections: Vec<SectionRef<'a>>,
}

/// Everything that can be checked without decompressing, in message order: the prefix and
/// body, the header fields, the section table, then the payloads' places.
fn parse_frame<'a>(bytes: &'a [u8], options: &DecodeOptions) -> Result<ParsedFrame<'a>, WireError> {
    let body = checked_frame_body(bytes, options)?;
    let mut r = Reader::new(body, PREFIX_LEN as u64);
    let fields = read_frame_fields(&mut r, options)?;
    let expected = expected_sections(fields.header.transfer, fields.codec);
    read_section_count(&mut r, &fields, &expected)?;
    let infos = read_section_table(&mut r, &fields, &expected, options)?;
    let sections = payloads(&mut r, &infos)?;
    Ok(ParsedFrame {
        info: FrameInfo {
            header: fields.header,
            codec: fields.codec,
            width: fields.width,
            height: fields.height,
            fragment_count: fields.fragment_count,
            sections: infos,
        },
        sections,
    })
}

/// A frame message's fixed-size header, read and checked.
struct FrameFields {
    header: FrameHeader,
    codec: Codec,
    width: u32,
    height: u32,
    fragment_count: u32,
}

/// The body of a frame message: the prefix is a frame's, its length is the message's, and (when
/// `options` asks) its checksum matches.
fn checked_frame_body<'a>(bytes: &'a [u8], options: &DecodeOptions) -> Result<&'a [u8], WireError> {
    let prefix = parse_prefix(bytes, options)?;
    if prefix.kind != MessageType::Frame {
        return Err(WireError::invalid(
            "type",
            TYPE_OFFSET as u64,
            prefix.kind as u8,
            "not a frame message",
        ));
    }
    let available = (bytes.len() - PREFIX_LEN) as u64;
    if prefix.body_len != available {
        return Err(if prefix.body_len > available {
            WireError::Truncated {
                field: "body",
                offset: PREFIX_LEN as u64,
                needed: prefix.body_len,
                available,
            }
        } else {
            WireError::invalid(
                "body_len",
                8,
                prefix.body_len,
                format!("the message has {available} bytes after the prefix"),
            )
        });
    }
    let body = &bytes[PREFIX_LEN..];
    if options.verify_checksum {
        let computed = crc32fast::hash(body);
        if computed != prefix.body_crc32 {
            return Err(WireError::Checksum {
                expected: prefix.body_crc32,
                computed,
            });
        }
    }
    Ok(body)
}

/// Bytes 20–183: frame number, node, size against the limits, fragment count, transfer, codec
/// and the two matrices.
fn read_frame_fields(
    r: &mut Reader<'_>,
    options: &DecodeOptions,
) -> Result<FrameFields, WireError> {
    let frame_number = r.u64("frame_number")?;
    let node_id = r.u32("node_id")?;
    let width = limited(r, "width", u64::from(options.max_width))?;
    let height = limited(r, "height", u64::from(options.max_height))?;
    let pixels = u64::from(width) * u64::from(height);
    if pixels > options.max_pixels {
        return Err(WireError::Limit {
            field: "width·height",
            offset: 32,
            value: pixels,
            limit: options.max_pixels,
        });
    }
    let fragment_count = limited(r, "fragment_count", options.max_fragments)?;
    let transfer_kind = r.u8("transfer")?;
    let transfer_flags = r.u8("transfer_flags")?;
    let codec_id = r.u8("codec")?;
    let codec_param = r.u8("codec_param")?;
    let layers = r.u32("layers")?;
    let threshold = r.f32("opacity_threshold")?;
    let codec = codec_from_fields(codec_id, codec_param)?;
    let fixup = transfer_kind == 2 && transfer_flags & 2 != 0;
    let transfer = transfer_from_fields(
        transfer_kind,
        transfer_flags & !(u8::from(fixup) << 1),
        layers,
        threshold,
    )?;
    let view = read_matrix(r, "view")?;
    let projection = read_matrix(r, "projection")?;
    Ok(FrameFields {
        header: FrameHeader {
            frame_number,
            node_id,
            view,
            projection,
            transfer,
            fixup,
        },
        codec,
        width,
        height,
        fragment_count,
    })
}

/// The codec from bytes 46–47 (`codec`, `codec_param`).
fn codec_from_fields(codec_id: u8, codec_param: u8) -> Result<Codec, WireError> {
    Codec::from_bytes(codec_id, codec_param).ok_or_else(|| {
        if codec_id <= 4 {
            WireError::invalid(
                "codec_param",
                47,
                codec_param,
                "zstd codecs take a level in -128..=22, the others 0",
            )
        } else {
            WireError::invalid("codec", 46, codec_id, "unknown codec (0–4 are defined)")
        }
    })
}

/// Sixteen floats, column-major.
fn read_matrix(r: &mut Reader<'_>, field: &'static str) -> Result<[f32; 16], WireError> {
    let mut m = [0f32; 16];
    for v in &mut m {
        *v = r.f32(field)?;
    }
    Ok(m)
}

/// The sections a frame of `transfer` encoded with `codec` has, in order: the difference and
/// reprojection transfers' two sections, then the codec's.
fn expected_sections(transfer: TransferMethod, codec: Codec) -> Vec<SectionTag> {
    let before: &[SectionTag] = match transfer {
        TransferMethod::Difference => &[SectionTag::Mask, SectionTag::Stale],
        TransferMethod::Reprojection => &[SectionTag::Mask, SectionTag::Removals],
        _ => &[],
    };
    before.iter().chain(codec.sections()).copied().collect()
}

/// Bytes 184–187: `section_count`, which must be `expected`'s length, and 2 reserved bytes.
fn read_section_count(
    r: &mut Reader<'_>,
    fields: &FrameFields,
    expected: &[SectionTag],
) -> Result<(), WireError> {
    let count_at = r.offset();
    let section_count = r.u16("section_count")?;
    if usize::from(section_count) != expected.len() {
        return Err(WireError::invalid(
            "section_count",
            count_at,
            section_count,
            format!(
                "codec {} with this transfer has {} sections",
                fields.codec.name(),
                expected.len()
            ),
        ));
    }
    reserved(r, 2, "reserved")
}

/// The section table: every length checked against the header before anything is allocated,
/// and the payloads' lengths against the bytes that follow the table.
fn read_section_table(
    r: &mut Reader<'_>,
    fields: &FrameFields,
    expected: &[SectionTag],
    options: &DecodeOptions,
) -> Result<Vec<SectionInfo>, WireError> {
    // Everything after the prefix: no payload can be longer.
    let available = (r.offset() - PREFIX_LEN as u64) + r.remaining() as u64;
    let mut infos = Vec::with_capacity(expected.len());
    let mut payload_total: u64 = 0;
    for &want in expected {
        let entry_at = r.offset();
        let info = read_section_entry(r, want, fields, options)?;
        payload_total = payload_total.saturating_add(info.encoded_len);
        if payload_total > available {
            return Err(WireError::invalid(
                "encoded_len",
                entry_at + 4,
                info.encoded_len,
                format!(
                    "the {} section does not fit in the {available}-byte body",
                    want.name()
                ),
            ));
        }
        infos.push(info);
    }
    if payload_total != r.remaining() as u64 {
        return Err(WireError::invalid(
            "encoded_len",
            r.offset(),
            payload_total,
            format!(
                "the sections add up to {payload_total} bytes, {} follow the table",
                r.remaining()
            ),
        ));
    }
    Ok(infos)
}

/// One 20-byte table entry, which must describe section `want`: its tag, a compression the
/// codec allows, and a decoded length the frame's size and fragment count allow and the
/// compression can reach from the encoded length.
fn read_section_entry(
    r: &mut Reader<'_>,
    want: SectionTag,
    fields: &FrameFields,
    options: &DecodeOptions,
) -> Result<SectionInfo, WireError> {
    let codec = fields.codec;
    let entry_at = r.offset();
    let tag_byte = r.u8("section tag")?;
    if SectionTag::from_byte(tag_byte) != Some(want) {
        return Err(WireError::invalid(
            "section tag",
            entry_at,
            tag_byte,
            format!(
                "codec {} expects the {} section ({}) here",
                codec.name(),
                want.name(),
                want as u8
            ),
        ));
    }
    let comp_byte = r.u8("section compression")?;
    let compression = match Compression::from_byte(comp_byte) {
        Some(c) if c == Compression::None || c == codec.compression() => c,
        _ => {
            return Err(WireError::invalid(
                "section compression",
                entry_at + 1,
                comp_byte,
                format!(
                    "codec {} allows {} ({}) or none (0)",
                    codec.name(),
                    codec.compression().name(),
                    codec.compression() as u8
                ),
            ));
        }
    };
    reserved(r, 2, "section reserved")?;
    let encoded_len = r.u64("encoded_len")?;
    let decoded_at = r.offset();
    let decoded_len = r.u64("decoded_len")?;
    check_decoded_len(want, fields, options, decoded_at, decoded_len)?;
    if decoded_len > compression.max_decoded(encoded_len) {
        return Err(WireError::invalid(
            "decoded_len",
            decoded_at,
            decoded_len,
            format!(
                "{} cannot expand {encoded_len} bytes that far (at most {})",
                compression.name(),
                compression.max_decoded(encoded_len)
            ),
        ));
    }
    Ok(SectionInfo {
        tag: want,
        compression,
        encoded_len,
        decoded_len,
    })
}

/// A section's decoded length must lie in the range its tag allows for the frame's pixels and
/// fragments (removals: for at most `options.max_fragments` removed positions).
fn check_decoded_len(
    want: SectionTag,
    fields: &FrameFields,
    options: &DecodeOptions,
    decoded_at: u64,
    decoded_len: u64,
) -> Result<(), WireError> {
    let (width, height, fragment_count) = (fields.width, fields.height, fields.fragment_count);
    let pixels = u64::from(width) * u64::from(height);
    let (mut lo, hi) = if want == SectionTag::Removals {
        want.decoded_range(pixels, options.max_fragments)
    } else {
        want.decoded_range(pixels, u64::from(fragment_count))
    };
    if fields.header.transfer == TransferMethod::Reprojection
        && !matches!(want, SectionTag::Mask | SectionTag::Removals)
    {
        // The codec's sections hold the compacted inserts: as few pixels as none, as many as
        // the view's (checked exactly once the mask is decoded: `check_compacted`).
        lo = want.decoded_range(0, u64::from(fragment_count)).0;
    }
    decoded_len_within(decoded_len, (lo, hi), decoded_at, |need| {
        format!(
            "the {} section of a {width}x{height} frame of {fragment_count} fragments decodes to {need} bytes",
            want.name()
        )
    })
}

/// `decoded_len` (the table entry's field at byte `at`) within `lo..=hi`, or an error that
/// says what the section must decode to (`what`, given "exactly N" or "N to M").
fn decoded_len_within(
    decoded_len: u64,
    (lo, hi): (u64, u64),
    at: u64,
    what: impl FnOnce(String) -> String,
) -> Result<(), WireError> {
    if (lo..=hi).contains(&decoded_len) {
        return Ok(());
    }
    let need = if lo == hi {
        format!("exactly {lo}")
    } else {
        format!("{lo} to {hi}")
    };
    Err(WireError::invalid(
        "decoded_len",
        at,
        decoded_len,
        what(need),
    ))
}

/// A reprojection frame's codec sections (from `first` on), whose decoded lengths were
/// checked against the view's pixels when the table was read, checked again against the
/// `rows` rows of compacted inserts its mask makes.
fn check_compacted(parsed: &ParsedFrame<'_>, first: usize, rows: u32) -> Result<(), WireError> {
    let info = &parsed.info;
    let pixels = u64::from(info.width) * u64::from(rows);
    let fragments = u64::from(info.fragment_count);
    for (i, s) in parsed.sections.iter().enumerate().skip(first) {
        let range = s.info.tag.decoded_range(pixels, fragments);
        // The entry's `decoded_len` field.
        let at = (FRAME_HEADER_LEN + SECTION_ENTRY_LEN * i + 12) as u64;
        decoded_len_within(s.info.decoded_len, range, at, |need| {
            format!(
                "the {} section of the {}x{rows} compacted inserts of a reprojection frame of \
                 {fragments} fragments decodes to {need} bytes",
                s.info.tag.name(),
                info.width
            )
        })?;
    }
    Ok(())
}

/// The payloads after the table, one per entry, back to back.
fn payloads<'a>(
    r: &mut Reader<'a>,
    infos: &[SectionInfo],
) -> Result<Vec<SectionRef<'a>>, WireError> {
    let mut sections = Vec::with_capacity(infos.len());
    for info in infos {
        let offset = r.offset();
        let payload = r.take(info.encoded_len as usize, "section payload")?;
        sections.push(SectionRef {
            info: *info,
            payload,
            offset,
        });
    }
    Ok(sections)
}

fn limited(r: &mut Reader<'_>, field: &'static str, limit: u64) -> Result<u32, WireError> {
    let offset = r.offset();
    let v = r.u32(field)?;
    if u64::from(v) > limit {
        return Err(WireError::Limit {
            field,
            offset,
            value: u64::from(v),
            limit,
        });
    }
    Ok(v)
}

fn reserved(r: &mut Reader<'_>, n: usize, field: &'static str) -> Result<(), WireError> {
    let offset = r.offset();
    let b = r.take(n, field)?;
    if b.iter().any(|&x| x != 0) {
        return Err(WireError::invalid(
            field,
            offset,
            format!("{b:02x?}"),
            "reserved bytes must be 0",
        ));
    }
    Ok(())
}

/// The transfer method from bytes 44–45 (`transfer`, `transfer_flags`) and 48–55 (`layers`,
/// `opacity_threshold`).
pub(crate) fn transfer_from_fields(
    kind: u8,
    flags: u8,
    layers: u32,
    threshold: f32,
) -> Result<TransferMethod, WireError> {
    if kind > 3 {
        return Err(WireError::invalid(
            "transfer",
            44,
            kind,
            "unknown transfer method (0–3 are defined)",
        ));
    }
    let allowed = if kind == 1 { 0x01 } else { 0x00 };
    if flags & !allowed != 0 {
        return Err(WireError::invalid(
            "transfer_flags",
            45,
            format!("{flags:#04x}"),
            "undefined flag bits for this transfer method",
        ));
    }
    if kind != 1 && (layers != 0 || threshold.to_bits() != 0) {
        return Err(WireError::invalid(
            "layers",
            48,
            format!("layers {layers}, threshold {threshold}"),
            "only a depth-limited transfer has layers and a threshold",
        ));
    }
    let t = match kind {
        0 => TransferMethod::Full,
        1 => {
            let opacity_threshold = if flags & 1 != 0 {
                Some(threshold)
            } else if threshold.to_bits() != 0 {
                return Err(WireError::invalid(
                    "opacity_threshold",
                    52,
                    threshold,
                    "must be 0 when the threshold flag is clear",
                ));
            } else {
                None
            };
            TransferMethod::DepthLimited {
                layers,
                opacity_threshold,
            }
        }
        2 => TransferMethod::Difference,
        _ => TransferMethod::Reprojection,
    };
    t.check()
        .map_err(|reason| WireError::invalid("layers", 48, layers, reason))?;
    Ok(t)
}
