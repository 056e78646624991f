//! The small messages of the remote-rendering services (Jähne 2014 ch. 3–5): what the display asks
//! of a node, how a node introduces itself, its per-frame statistics, and errors.
//!
//! Every message starts with the 20-byte prefix of [`crate::message`]; offsets below are from the
//! first byte of the body (prefix offset + 20). Integers and floats little-endian.
//!
//! # Request (type 2, display → node)
//!
//! ```text
//!   0  frame_number       u64     the animation frame to render (or whose pixels to resend)
//!   8  node_id            u32     the id the node writes into its frames
//!  12  width              u32     ≤ DecodeOptions limits
//!  16  height             u32
//!  20  kind               u8      0 render, 1 fixup
//!  21  flags              u8      bit 0: reset (difference: the display holds nothing of this node)
//!  22  codec              u8      as in the frame header
//!  23  codec_param        u8
//!  24  transfer           u8      as in the frame header (fixup: 2 or 3)
//!  25  transfer_flags     u8
//!  26  tolerance          u8      difference, reprojection: largest colour error (8-bit steps)
//!                                  a held fragment may keep; 0 for the other transfers
//!  27  reserved           u8      0
//!  28  layers             u32
//!  32  opacity_threshold  f32
//!  36  view               [f32; 16]
//! 100  projection         [f32; 16]
//! 164  mask_len           u32     fixup: bytes of the pixel mask that follows; render: 0
//! 168  mask               PixelMask encoding (see `mask.rs`)
//! ```
//!
//! A *render* request asks for frame `frame_number` seen through `view`/`projection`, chosen by
//! `transfer`, encoded with `codec`. A *fixup* request (difference and reprojection transfers)
//! asks for exact copies of the node's runs at the masked pixels of an already-sent frame
//! `frame_number`: pixels the display shares with another node, where the depths it holds may be
//! stale although the colour was not (difference), or are reprojected and too close to another
//! node's to order (reprojection). The reply is a difference frame with the fixup flag, its runs
//! as the node rendered them (normal fragments under reprojection); it changes no held state.
//!
//! # Error (type 4, either direction)
//!
//! `len` varint, then `len ≤ 65536` bytes of UTF-8: a message for a person. The sender closes the
//! connection after it.
//!
//! # Hello (type 5, node → display, first message on a connection)
//!
//! ```text
//!   0  triangles     u64     triangles the node renders per frame
//!   8  scene         string  varint length ≤ 4096, UTF-8
//!      object_count  varint  ≤ 65536
//!      objects       object_count × (id u32, name string)
//! ```
//!
//! # Stats (type 6, node → display, right after each frame message)
//!
//! ```text
//!   0  frame_number        u64
//!   8  fragments_rendered  u64    the node's whole frame (before a depth limit)
//!  16  fragments_sent      u64    after the transfer method chose
//!  24  raw_bytes           u64    the sent frame in the thesis layout (4 per pixel + 12 per fragment)
//!  32  render_us           u64    clear + capture + export to a DeepFrame
//!  40  select_us           u64    the transfer method's choice (difference, reprojection;
//!                                 strata's nodes cut a depth-limited frame in the render)
//!  48  encode_us           u64
//!  56  flags               u8     bit 0: fixup reply
//!  57  reserved            [u8; 7]
//! ```

use crate::bytes::{Reader, put_varint};
use crate::error::WireError;
use crate::mask::PixelMask;
use crate::message::{
    DecodeOptions, MAGIC, MessageType, PREFIX_LEN, TransferMethod, VERSION, parse_prefix,
    transfer_from_fields,
};
use crate::{Codec, codec};

/// Longest error text.
pub const MAX_ERROR_TEXT: usize = 65_536;
/// Longest scene or object name.
pub const MAX_NAME: usize = 4096;
/// Most objects a Hello may list.
pub const MAX_OBJECTS: u32 = 65_536;

/// What the display asks of a node.
#[derive(Clone, Debug, PartialEq)]
pub enum RequestKind {
    /// Render the frame and send it with the request's transfer method.
    Render {
        /// Difference transfer: the display holds nothing of this node; send every pixel.
        reset: bool,
    },
    /// Send exact copies of the runs at these pixels of the already-sent frame.
    Fixup(PixelMask),
}

/// A request (type 2).
#[derive(Clone, Debug, PartialEq)]
pub struct Request {
    /// The animation frame.
    pub frame_number: u64,
    /// The id the node writes into its frames.
    pub node_id: u32,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// World → eye, column-major.
    pub view: [f32; 16],
    /// Eye → clip, column-major.
    pub projection: [f32; 16],
    /// How to choose fragments.
    pub transfer: TransferMethod,
    /// How to encode them.
    pub codec: Codec,
    /// Render or fixup.
    pub kind: RequestKind,
    /// Difference transfer: a pixel whose resolved colour moved by at most this many 8-bit steps
    /// in every channel from what the display shows is not sent (0: any change is sent).
    pub tolerance: u8,
}

/// A node's introduction (type 5).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Hello {
    /// Triangles per frame.
    pub triangles: u64,
    /// The scene's name.
    pub scene: String,
    /// `(object id, name)` of every object the node renders.
    pub objects: Vec<(u32, String)>,
}

/// A node's figures for one frame message (type 6).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NodeStats {
    /// The frame.
    pub frame_number: u64,
    /// Fragments of the node's whole frame.
    pub fragments_rendered: u64,
    /// Fragments in the message.
    pub fragments_sent: u64,
    /// The message's frame in the thesis layout.
    pub raw_bytes: u64,
    /// Clear + capture + DeepFrame export, µs.
    pub render_us: u64,
    /// The transfer method's selection, µs.
    pub select_us: u64,
    /// Encoding, µs.
    pub encode_us: u64,
    /// The message was a fixup reply.
    pub fixup: bool,
}

/// Writes a complete message of type `kind` whose body `body` appends, replacing `out`.
pub(crate) fn write_message(out: &mut Vec<u8>, kind: MessageType, body: impl FnOnce(&mut Vec<u8>)) {
    out.clear();
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.push(kind as u8);
    out.push(0);
    out.extend_from_slice(&[0; 12]);
    body(out);
    let body_len = (out.len() - PREFIX_LEN) as u64;
    let crc = crc32fast::hash(&out[PREFIX_LEN..]);
    out[8..16].copy_from_slice(&body_len.to_le_bytes());
    out[16..20].copy_from_slice(&crc.to_le_bytes());
}

pub(crate) fn put_string(out: &mut Vec<u8>, s: &str) {
    put_varint(out, s.len() as u32);
    out.extend_from_slice(s.as_bytes());
}

/// The body of a complete message of the expected type, prefix and checksum verified.
pub(crate) fn body_of<'a>(
    bytes: &'a [u8],
    want: MessageType,
    options: &DecodeOptions,
) -> Result<Reader<'a>, WireError> {
    let prefix = parse_prefix(bytes, options)?;
    if prefix.kind != want {
        return Err(WireError::invalid(
            "type",
            6,
            prefix.kind as u8,
            format!("expected a {want:?} message"),
        ));
    }
    let available = (bytes.len() - PREFIX_LEN) as u64;
    if prefix.body_len != available {
        return Err(WireError::invalid(
            "body_len",
            8,
            prefix.body_len,
            format!("the message has {available} bytes after the prefix"),
        ));
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
    Ok(Reader::new(body, PREFIX_LEN as u64))
}

pub(crate) fn string(
    r: &mut Reader<'_>,
    field: &'static str,
    max: usize,
) -> Result<String, WireError> {
    let at = r.offset();
    let len = r.varint(field)? as usize;
    if len > max {
        return Err(WireError::Limit {
            field,
            offset: at,
            value: len as u64,
            limit: max as u64,
        });
    }
    let b = r.take(len, field)?;
    String::from_utf8(b.to_vec()).map_err(|_| WireError::invalid(field, at, "bytes", "not UTF-8"))
}

pub(crate) fn finish(r: &Reader<'_>, what: &'static str) -> Result<(), WireError> {
    if r.remaining() != 0 {
        return Err(WireError::invalid(
            what,
            r.offset(),
            r.remaining(),
            "bytes left after the message's last field",
        ));
    }
    Ok(())
}

impl Request {
    /// Encodes the request, replacing `out`.
    pub fn encode_into(&self, out: &mut Vec<u8>) -> Result<(), WireError> {
        self.transfer.check().map_err(WireError::Encode)?;
        self.codec.validate()?;
        let (transfer, flags, layers, threshold) = self.transfer.to_fields();
        write_message(out, MessageType::Request, |b| {
            b.extend_from_slice(&self.frame_number.to_le_bytes());
            b.extend_from_slice(&self.node_id.to_le_bytes());
            b.extend_from_slice(&self.width.to_le_bytes());
            b.extend_from_slice(&self.height.to_le_bytes());
            let (kind, rflags) = match &self.kind {
                RequestKind::Render { reset } => (0u8, u8::from(*reset)),
                RequestKind::Fixup(_) => (1, 0),
            };
            b.extend_from_slice(&[kind, rflags, self.codec.id(), self.codec.param()]);
            b.extend_from_slice(&[transfer, flags, self.tolerance, 0]);
            b.extend_from_slice(&layers.to_le_bytes());
            b.extend_from_slice(&threshold.to_le_bytes());
            for v in self.view.iter().chain(&self.projection) {
                b.extend_from_slice(&v.to_le_bytes());
            }
            let mut mask = Vec::new();
            if let RequestKind::Fixup(m) = &self.kind {
                m.encode(&mut mask);
            }
            b.extend_from_slice(&(mask.len() as u32).to_le_bytes());
            b.extend_from_slice(&mask);
        });
        Ok(())
    }

    /// Decodes a complete request message.
    pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Self, WireError> {
        let mut r = body_of(bytes, MessageType::Request, options)?;
        let frame_number = r.u64("frame_number")?;
        let node_id = r.u32("node_id")?;
        let w_at = r.offset();
        let width = r.u32("width")?;
        let height = r.u32("height")?;
        let pixels = u64::from(width) * u64::from(height);
        if width > options.max_width || height > options.max_height || pixels > options.max_pixels {
            return Err(WireError::Limit {
                field: "width·height",
                offset: w_at,
                value: pixels,
                limit: options.max_pixels,
            });
        }
        let kind_at = r.offset();
        let kind = r.u8("kind")?;
        let rflags = r.u8("flags")?;
        let codec_id = r.u8("codec")?;
        let codec_param = r.u8("codec_param")?;
        let codec = Codec::from_bytes(codec_id, codec_param).ok_or_else(|| {
            WireError::invalid(
                "codec",
                kind_at + 2,
                codec_id,
                "unknown codec (0–4 are defined)",
            )
        })?;
        codec.validate()?;
        let transfer_kind = r.u8("transfer")?;
        let transfer_flags = r.u8("transfer_flags")?;
        let tol_at = r.offset();
        let tolerance = r.u8("tolerance")?;
        if r.u8("reserved")? != 0 {
            return Err(WireError::invalid("reserved", tol_at + 1, "", "must be 0"));
        }
        let layers = r.u32("layers")?;
        let threshold = r.f32("opacity_threshold")?;
        let transfer = transfer_from_fields(transfer_kind, transfer_flags, layers, threshold)?;
        if tolerance != 0
            && transfer != TransferMethod::Difference
            && transfer != TransferMethod::Reprojection
        {
            return Err(WireError::invalid(
                "tolerance",
                tol_at,
                tolerance,
                "only the difference and reprojection transfers have a tolerance",
            ));
        }
        let mut view = [0f32; 16];
        for v in &mut view {
            *v = r.f32("view")?;
        }
        let mut projection = [0f32; 16];
        for v in &mut projection {
            *v = r.f32("projection")?;
        }
        let len_at = r.offset();
        let mask_len = r.u32("mask_len")? as usize;
        let kind = match (kind, rflags) {
            (0, f) if f <= 1 && mask_len == 0 => RequestKind::Render { reset: f == 1 },
            (1, 0)
                if transfer == TransferMethod::Difference
                    || transfer == TransferMethod::Reprojection =>
            {
                let m = r.take(mask_len, "mask")?;
                let pixels = u32::try_from(pixels).map_err(|_| {
                    WireError::invalid("width·height", w_at, pixels, "too many pixels")
                })?;
                RequestKind::Fixup(PixelMask::decode(m, len_at + 4, pixels)?)
            }
            _ => {
                return Err(WireError::invalid(
                    "kind",
                    kind_at,
                    format!("kind {kind}, flags {rflags:#04x}, mask_len {mask_len}"),
                    "a render request (0, flags ≤ 1, no mask) or a difference or reprojection fixup (1, flags 0)",
                ));
            }
        };
        finish(&r, "request")?;
        Ok(Request {
            frame_number,
            node_id,
            width,
            height,
            view,
            projection,
            transfer,
            codec,
            kind,
            tolerance,
        })
    }
}

impl Hello {
    /// Encodes the hello, replacing `out`.
    pub fn encode_into(&self, out: &mut Vec<u8>) -> Result<(), WireError> {
        if self.scene.len() > MAX_NAME || self.objects.iter().any(|(_, n)| n.len() > MAX_NAME) {
            return Err(WireError::Encode(format!(
                "names are limited to {MAX_NAME} bytes"
            )));
        }
        if self.objects.len() > MAX_OBJECTS as usize {
            return Err(WireError::Encode(format!(
                "a hello lists at most {MAX_OBJECTS} objects"
            )));
        }
        write_message(out, MessageType::Hello, |b| {
            b.extend_from_slice(&self.triangles.to_le_bytes());
            put_string(b, &self.scene);
            put_varint(b, self.objects.len() as u32);
            for (id, name) in &self.objects {
                b.extend_from_slice(&id.to_le_bytes());
                put_string(b, name);
            }
        });
        Ok(())
    }

    /// Decodes a complete hello message.
    pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Self, WireError> {
        let mut r = body_of(bytes, MessageType::Hello, options)?;
        let triangles = r.u64("triangles")?;
        let scene = string(&mut r, "scene", MAX_NAME)?;
        let at = r.offset();
        let count = r.varint("object_count")?;
        // Each object takes at least 5 bytes.
        if count > MAX_OBJECTS || count as usize * 5 > r.remaining() {
            return Err(WireError::Limit {
                field: "object_count",
                offset: at,
                value: u64::from(count),
                limit: u64::from(MAX_OBJECTS.min((r.remaining() / 5) as u32)),
            });
        }
        let mut objects = Vec::with_capacity(count as usize);
        for _ in 0..count {
            let id = r.u32("object id")?;
            objects.push((id, string(&mut r, "object name", MAX_NAME)?));
        }
        finish(&r, "hello")?;
        Ok(Hello {
            triangles,
            scene,
            objects,
        })
    }
}

/// Encodes an error message, replacing `out` (the text is cut at [`MAX_ERROR_TEXT`] bytes, on a
/// character boundary).
pub fn encode_error_into(out: &mut Vec<u8>, text: &str) {
    let mut end = text.len().min(MAX_ERROR_TEXT);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    write_message(out, MessageType::Error, |b| put_string(b, &text[..end]));
}

/// Decodes a complete error message's text.
pub fn decode_error(bytes: &[u8], options: &DecodeOptions) -> Result<String, WireError> {
    let mut r = body_of(bytes, MessageType::Error, options)?;
    let text = string(&mut r, "error text", MAX_ERROR_TEXT)?;
    finish(&r, "error")?;
    Ok(text)
}

impl NodeStats {
    /// Encodes the statistics, replacing `out`.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        write_message(out, MessageType::Stats, |b| {
            for v in [
                self.frame_number,
                self.fragments_rendered,
                self.fragments_sent,
                self.raw_bytes,
                self.render_us,
                self.select_us,
                self.encode_us,
            ] {
                b.extend_from_slice(&v.to_le_bytes());
            }
            b.push(u8::from(self.fixup));
            b.extend_from_slice(&[0; 7]);
        });
    }

    /// Decodes a complete stats message.
    pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Self, WireError> {
        let mut r = body_of(bytes, MessageType::Stats, options)?;
        let mut v = [0u64; 7];
        for (x, name) in v.iter_mut().zip([
            "frame_number",
            "fragments_rendered",
            "fragments_sent",
            "raw_bytes",
            "render_us",
            "select_us",
            "encode_us",
        ]) {
            *x = r.u64(name)?;
        }
        let at = r.offset();
        let flags = r.u8("flags")?;
        let reserved = r.take(7, "reserved")?;
        if flags > 1 || reserved.iter().any(|&b| b != 0) {
            return Err(WireError::invalid(
                "flags",
                at,
                format!("{flags:#04x}"),
                "only bit 0 (fixup) is defined; reserved bytes are 0",
            ));
        }
        finish(&r, "stats")?;
        Ok(NodeStats {
            frame_number: v[0],
            fragments_rendered: v[1],
            fragments_sent: v[2],
            raw_bytes: v[3],
            render_us: v[4],
            select_us: v[5],
            encode_us: v[6],
            fixup: flags == 1,
        })
    }
}

/// Bytes of `frame` in the thesis layout (4 per pixel + 12 per fragment): the `raw` codec's
/// section, the denominator of Jähne 2014's comparisons.
pub fn seed_layout_bytes(pixels: u64, fragments: u64) -> u64 {
    codec::SectionTag::Seed.decoded_range(pixels, fragments).0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(kind: RequestKind, transfer: TransferMethod) -> Request {
        Request {
            frame_number: 41,
            node_id: 3,
            width: 8,
            height: 4,
            view: std::array::from_fn(|i| i as f32),
            projection: std::array::from_fn(|i| -(i as f32)),
            transfer,
            codec: Codec::DeepLz4,
            kind,
            tolerance: 0,
        }
    }

    #[test]
    fn every_message_round_trips() {
        let o = DecodeOptions::default();
        let mut b = Vec::new();
        for r in [
            request(
                RequestKind::Render { reset: true },
                TransferMethod::Difference,
            ),
            request(
                RequestKind::Render { reset: false },
                TransferMethod::DepthLimited {
                    layers: 6,
                    opacity_threshold: Some(0.95),
                },
            ),
            request(
                RequestKind::Fixup(PixelMask::from_fn(32, |p| p % 5 == 0)),
                TransferMethod::Difference,
            ),
            Request {
                tolerance: 2,
                ..request(
                    RequestKind::Render { reset: false },
                    TransferMethod::Difference,
                )
            },
        ] {
            r.encode_into(&mut b).unwrap();
            assert_eq!(Request::decode(&b, &o).unwrap(), r);
            // Every truncation and every single-bit flip is an error, never a panic.
            for n in 0..b.len() {
                assert!(Request::decode(&b[..n], &o).is_err());
            }
            for bit in 0..b.len() * 8 {
                let mut c = b.clone();
                c[bit / 8] ^= 1 << (bit % 8);
                assert!(Request::decode(&c, &o).is_err(), "bit {bit}");
            }
        }
        let h = Hello {
            triangles: 871_414,
            scene: "dragon".into(),
            objects: vec![(0, "dragon".into()), (7, "glass sphere".into())],
        };
        h.encode_into(&mut b).unwrap();
        assert_eq!(Hello::decode(&b, &o).unwrap(), h);
        encode_error_into(&mut b, "scene 'x' not found");
        assert_eq!(decode_error(&b, &o).unwrap(), "scene 'x' not found");
        let s = NodeStats {
            frame_number: 9,
            fragments_rendered: 10,
            fragments_sent: 5,
            raw_bytes: 3,
            render_us: 4,
            select_us: 5,
            encode_us: 6,
            fixup: true,
        };
        s.encode_into(&mut b);
        assert_eq!(NodeStats::decode(&b, &o).unwrap(), s);
        assert!(Hello::decode(&b, &o).is_err(), "type is checked");
    }

    #[test]
    fn a_fixup_needs_the_difference_or_reprojection_transfer() {
        let r = request(
            RequestKind::Fixup(PixelMask::full(32)),
            TransferMethod::Full,
        );
        let mut b = Vec::new();
        r.encode_into(&mut b).unwrap();
        let e = Request::decode(&b, &DecodeOptions::default()).unwrap_err();
        assert!(e.to_string().contains("kind"), "{e}");
    }
}
