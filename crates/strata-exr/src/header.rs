//! The file prologue: magic number, version field and the header's attributes, read and written.
//!
//! ```text
//! 76 2f 31 01                 magic
//! u32 version field           2 | 0x800 (deep, "non-image") | 0x400 (long names)
//! attributes, each:           name\0 type\0 i32 size, `size` bytes of value
//! \0                          end of header
//! ```
//!
//! The attributes strata interprets (channels, compression, windows, line order, the deep
//! part's `type`, `version`, `chunkCount`, `maxSamplesPerPixel`) become fields of [`Header`]; all
//! others are kept as raw [`Attribute`]s. Every size is checked against the bytes that remain
//! before anything is allocated.

use crate::compress::{Compression, unsupported_name};
use crate::error::{ExrError, Result};
use crate::image::{Attribute, Box2i, Channel, SampleType, check_channels};

/// The four bytes every OpenEXR file starts with.
pub(crate) const MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];
/// The file format version in the low byte of the version field.
const FORMAT_VERSION: u32 = 2;
const FLAG_TILED: u32 = 0x200;
const FLAG_LONG_NAMES: u32 = 0x400;
const FLAG_DEEP: u32 = 0x800;
const FLAG_MULTIPART: u32 = 0x1000;
/// Longest name without the long-names flag.
const SHORT_NAME_MAX: usize = 31;
/// Longest attribute, type or channel name OpenEXR allows.
const NAME_MAX: usize = 255;

/// The order in which the chunks of scanlines are stored in the file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum LineOrder {
    /// Top scanline block first (the default).
    #[default]
    IncreasingY,
    /// Bottom scanline block first.
    DecreasingY,
}

/// The attributes strata interprets, plus the rest kept raw.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Header {
    pub(crate) deep: bool,
    pub(crate) channels: Vec<Channel>,
    pub(crate) compression: Compression,
    pub(crate) data_window: Box2i,
    pub(crate) display_window: Box2i,
    pub(crate) line_order: LineOrder,
    pub(crate) chunk_count: Option<i32>,
    /// The attributes strata does not interpret.
    pub(crate) attributes: Vec<Attribute>,
    /// Every attribute, in file order (for `read_info`).
    pub(crate) all_attributes: Vec<Attribute>,
}

/// Attributes the writer generates from the image; never copied from [`Header::attributes`].
const INTERPRETED: [&str; 11] = [
    "channels",
    "compression",
    "dataWindow",
    "displayWindow",
    "lineOrder",
    "chunkCount",
    "maxSamplesPerPixel",
    "type",
    "version",
    "name",
    "tiles",
];

/// A bounds-checked little-endian reader over the file bytes.
pub(crate) struct Cursor<'a> {
    pub(crate) data: &'a [u8],
    pub(crate) pos: usize,
}

impl<'a> Cursor<'a> {
    pub(crate) fn new(data: &'a [u8], pos: usize) -> Self {
        Cursor { data, pos }
    }

    pub(crate) fn take(&mut self, n: u64, what: &str) -> Result<&'a [u8]> {
        let available = (self.data.len() - self.pos.min(self.data.len())) as u64;
        if n > available {
            return Err(ExrError::Truncated {
                what: what.to_owned(),
                offset: self.pos as u64,
                needed: n,
                available,
            });
        }
        let start = self.pos;
        self.pos += n as usize;
        Ok(&self.data[start..self.pos])
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let bytes = self.take(N as u64, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(bytes);
        Ok(a)
    }

    pub(crate) fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    /// A NUL-terminated name of at most `max` bytes (empty if the first byte is NUL).
    fn name(&mut self, max: usize, what: &str) -> Result<String> {
        let start = self.pos;
        let rest = &self.data[start.min(self.data.len())..];
        let Some(len) = rest.iter().take(max + 1).position(|&b| b == 0) else {
            if rest.len() <= max {
                return Err(ExrError::Truncated {
                    what: what.to_owned(),
                    offset: start as u64,
                    needed: rest.len() as u64 + 1,
                    available: rest.len() as u64,
                });
            }
            return Err(ExrError::BadHeader {
                offset: start as u64,
                problem: format!("{what} is longer than {max} bytes"),
            });
        };
        let name = String::from_utf8_lossy(&rest[..len]).into_owned();
        self.pos += len + 1;
        Ok(name)
    }
}

fn bad(name: &str, problem: impl Into<String>) -> ExrError {
    ExrError::BadAttribute {
        name: name.to_owned(),
        problem: problem.into(),
    }
}

/// Parses the prologue; returns the header and the offset of the first byte after it.
pub(crate) fn parse(data: &[u8]) -> Result<(Header, usize)> {
    if data.len() < 4 || data[..4] != MAGIC {
        return Err(ExrError::NotExr);
    }
    let mut cur = Cursor::new(data, 4);
    let version = cur.u32("the version field")?;
    check_version(version)?;
    let mut raw = Vec::new();
    loop {
        let at = cur.pos;
        let name = cur.name(NAME_MAX, "an attribute name")?;
        if name.is_empty() {
            break;
        }
        let type_name = cur.name(NAME_MAX, "an attribute type name")?;
        let size = cur.i32("an attribute size")?;
        let size = u64::try_from(size).map_err(|_| ExrError::BadHeader {
            offset: at as u64,
            problem: format!("attribute `{name}` has a negative size {size}"),
        })?;
        let value = cur.take(size, &format!("the value of attribute `{name}`"))?;
        raw.push(Attribute {
            name,
            type_name,
            value: value.to_vec(),
        });
    }
    let header = interpret(version, raw)?;
    Ok((header, cur.pos))
}

fn check_version(version: u32) -> Result<()> {
    if version & 0xff != FORMAT_VERSION {
        return Err(ExrError::Unsupported(format!(
            "OpenEXR file format version {} (strata reads version 2)",
            version & 0xff
        )));
    }
    if version & FLAG_MULTIPART != 0 {
        return Err(ExrError::Unsupported(
            "multi-part files; extract the part first (e.g. `oiiotool in.exr --subimage 0 -o out.exr`)"
                .into(),
        ));
    }
    if version & FLAG_TILED != 0 {
        return Err(ExrError::Unsupported(
            "tiled files; convert to scanlines first (e.g. `oiiotool in.exr --scanline -o out.exr`)"
                .into(),
        ));
    }
    let known = 0xff | FLAG_TILED | FLAG_LONG_NAMES | FLAG_DEEP | FLAG_MULTIPART;
    if version & !known != 0 {
        return Err(ExrError::Unsupported(format!(
            "unknown version-field flags {:#x}",
            version & !known
        )));
    }
    Ok(())
}

fn expect_type(a: &Attribute, type_name: &str, size: usize) -> Result<()> {
    if a.type_name != type_name {
        return Err(bad(
            &a.name,
            format!("has type `{}`, expected `{type_name}`", a.type_name),
        ));
    }
    if a.value.len() != size {
        return Err(bad(
            &a.name,
            format!("is {} bytes, a {type_name} is {size}", a.value.len()),
        ));
    }
    Ok(())
}

fn le_i32(b: &[u8], i: usize) -> i32 {
    i32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]])
}

fn parse_box(a: &Attribute) -> Result<Box2i> {
    expect_type(a, "box2i", 16)?;
    let b = Box2i {
        x_min: le_i32(&a.value, 0),
        y_min: le_i32(&a.value, 1),
        x_max: le_i32(&a.value, 2),
        y_max: le_i32(&a.value, 3),
    };
    if b.width() == 0 || b.height() == 0 {
        return Err(bad(&a.name, format!("is empty: {b:?}")));
    }
    Ok(b)
}

fn parse_int(a: &Attribute) -> Result<i32> {
    expect_type(a, "int", 4)?;
    Ok(le_i32(&a.value, 0))
}

pub(crate) fn parse_channels(a: &Attribute) -> Result<Vec<Channel>> {
    if a.type_name != "chlist" {
        return Err(bad(
            &a.name,
            format!("has type `{}`, expected `chlist`", a.type_name),
        ));
    }
    let mut cur = Cursor::new(&a.value, 0);
    let mut channels = Vec::new();
    loop {
        let name = cur.name(NAME_MAX, "a channel name")?;
        if name.is_empty() {
            break;
        }
        let code = cur.i32("a channel's pixel type")?;
        let _linear_and_reserved = cur.take(4, "a channel's pLinear and reserved bytes")?;
        let x_sampling = cur.i32("a channel's x sampling")?;
        let y_sampling = cur.i32("a channel's y sampling")?;
        let sample_type = SampleType::from_code(code).ok_or_else(|| {
            bad(
                "channels",
                format!("channel `{name}` has unknown pixel type {code}"),
            )
        })?;
        if (x_sampling, y_sampling) != (1, 1) {
            return Err(ExrError::Unsupported(format!(
                "channel `{name}` is subsampled ({x_sampling}x{y_sampling})"
            )));
        }
        channels.push(Channel { name, sample_type });
    }
    if cur.pos != a.value.len() {
        return Err(bad(
            "channels",
            "has bytes after the list's terminating NUL",
        ));
    }
    if channels.is_empty() {
        return Err(bad("channels", "lists no channel"));
    }
    check_channels(&channels).map_err(|e| bad("channels", e.to_string()))?;
    Ok(channels)
}

fn parse_compression(a: &Attribute) -> Result<Compression> {
    expect_type(a, "compression", 1)?;
    let code = a.value[0];
    Compression::ALL
        .into_iter()
        .find(|c| c.code() == code)
        .ok_or_else(|| {
            ExrError::Unsupported(format!(
                "{} compression (code {code}); strata reads NONE, RLE, ZIPS and ZIP \
                 (convert with `oiiotool in.exr --compression zip -o out.exr`)",
                unsupported_name(code)
            ))
        })
}

fn parse_line_order(a: &Attribute) -> Result<LineOrder> {
    expect_type(a, "lineOrder", 1)?;
    match a.value[0] {
        0 => Ok(LineOrder::IncreasingY),
        1 => Ok(LineOrder::DecreasingY),
        // RANDOM_Y only exists for tiled files; scanline chunks are found via the offset table
        // whatever order they are in.
        2 => Ok(LineOrder::IncreasingY),
        v => Err(bad(&a.name, format!("has unknown value {v}"))),
    }
}

fn find<'a>(raw: &'a [Attribute], name: &str) -> Option<&'a Attribute> {
    raw.iter().find(|a| a.name == name)
}

fn required<'a>(raw: &'a [Attribute], name: &str) -> Result<&'a Attribute> {
    find(raw, name).ok_or_else(|| bad(name, "is required but missing"))
}

fn interpret(version: u32, raw: Vec<Attribute>) -> Result<Header> {
    let part_type = match find(&raw, "type") {
        Some(a) => {
            if a.type_name != "string" {
                return Err(bad(
                    "type",
                    format!("has type `{}`, expected `string`", a.type_name),
                ));
            }
            Some(String::from_utf8_lossy(&a.value).into_owned())
        }
        None => None,
    };
    let deep = match part_type.as_deref() {
        Some("deepscanline") => true,
        Some("scanlineimage") | None => version & FLAG_DEEP != 0,
        Some("tiledimage" | "deeptile") => {
            return Err(ExrError::Unsupported(
                "tiled files; convert to scanlines first (e.g. `oiiotool in.exr --scanline -o out.exr`)"
                    .into(),
            ));
        }
        Some(other) => return Err(bad("type", format!("has unknown value `{other}`"))),
    };
    if deep && part_type.is_none() {
        return Err(bad("type", "is required in a deep file but missing"));
    }
    if let Some(a) = find(&raw, "version") {
        let v = parse_int(a)?;
        if deep && v != 1 {
            return Err(ExrError::Unsupported(format!(
                "deep data version {v} (strata reads 1)"
            )));
        }
    }
    let chunk_count = find(&raw, "chunkCount").map(parse_int).transpose()?;
    if let Some(a) = find(&raw, "maxSamplesPerPixel") {
        parse_int(a)?;
    }
    let header = Header {
        deep,
        channels: parse_channels(required(&raw, "channels")?)?,
        compression: parse_compression(required(&raw, "compression")?)?,
        data_window: parse_box(required(&raw, "dataWindow")?)?,
        display_window: parse_box(required(&raw, "displayWindow")?)?,
        line_order: find(&raw, "lineOrder")
            .map(parse_line_order)
            .transpose()?
            .unwrap_or_default(),
        chunk_count,
        attributes: raw
            .iter()
            .filter(|a| !INTERPRETED.contains(&a.name.as_str()))
            .cloned()
            .collect(),
        all_attributes: raw,
    };
    Ok(header)
}

/// Serialises the prologue (magic, version field, attributes, terminator).
///
/// `extra` are attributes kept from a file or set by the caller; `deep` adds the deep part's
/// attributes (`type`, `version`, `chunkCount`, `maxSamplesPerPixel`).
pub(crate) fn write(
    out: &mut Vec<u8>,
    header: &Header,
    max_samples_per_pixel: Option<u32>,
    chunk_count: usize,
) -> Result<()> {
    let mut attrs: Vec<Attribute> = vec![
        channels_attribute(&header.channels),
        Attribute {
            name: "compression".into(),
            type_name: "compression".into(),
            value: vec![header.compression.code()],
        },
        box_attribute("dataWindow", &header.data_window),
        box_attribute("displayWindow", &header.display_window),
        Attribute {
            name: "lineOrder".into(),
            type_name: "lineOrder".into(),
            value: vec![match header.line_order {
                LineOrder::IncreasingY => 0,
                LineOrder::DecreasingY => 1,
            }],
        },
    ];
    let defaults = [
        Attribute::float("pixelAspectRatio", 1.0),
        Attribute {
            name: "screenWindowCenter".into(),
            type_name: "v2f".into(),
            value: vec![0; 8],
        },
        Attribute::float("screenWindowWidth", 1.0),
    ];
    for d in defaults {
        if !header.attributes.iter().any(|a| a.name == d.name) {
            attrs.push(d);
        }
    }
    if let Some(max) = max_samples_per_pixel {
        let chunk_count = i32::try_from(chunk_count)
            .map_err(|_| ExrError::InvalidImage("too many chunks for one file".into()))?;
        let max = i32::try_from(max)
            .map_err(|_| ExrError::InvalidImage("a pixel holds over 2^31 samples".into()))?;
        attrs.push(int_attribute("chunkCount", chunk_count));
        attrs.push(int_attribute("maxSamplesPerPixel", max));
        attrs.push(Attribute::string("type", "deepscanline"));
        attrs.push(int_attribute("version", 1));
    }
    attrs.extend(
        header
            .attributes
            .iter()
            .filter(|a| !INTERPRETED.contains(&a.name.as_str()))
            .cloned(),
    );
    attrs.sort_by(|a, b| a.name.cmp(&b.name));
    let mut long_names = false;
    for a in &attrs {
        check_name(&a.name)?;
        check_name(&a.type_name)?;
        long_names |= a.name.len() > SHORT_NAME_MAX || a.type_name.len() > SHORT_NAME_MAX;
    }
    long_names |= header
        .channels
        .iter()
        .any(|c| c.name.len() > SHORT_NAME_MAX);
    let mut version = FORMAT_VERSION;
    if max_samples_per_pixel.is_some() {
        version |= FLAG_DEEP;
    }
    if long_names {
        version |= FLAG_LONG_NAMES;
    }
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&version.to_le_bytes());
    for a in &attrs {
        let size = i32::try_from(a.value.len())
            .map_err(|_| ExrError::InvalidImage(format!("attribute `{}` is too large", a.name)))?;
        out.extend_from_slice(a.name.as_bytes());
        out.push(0);
        out.extend_from_slice(a.type_name.as_bytes());
        out.push(0);
        out.extend_from_slice(&size.to_le_bytes());
        out.extend_from_slice(&a.value);
    }
    out.push(0);
    Ok(())
}

fn check_name(name: &str) -> Result<()> {
    if name.is_empty() || name.len() > NAME_MAX || name.contains('\0') {
        return Err(ExrError::InvalidImage(format!(
            "attribute name or type {name:?} must be 1 to {NAME_MAX} bytes without NUL"
        )));
    }
    Ok(())
}

fn int_attribute(name: &str, v: i32) -> Attribute {
    Attribute {
        name: name.into(),
        type_name: "int".into(),
        value: v.to_le_bytes().to_vec(),
    }
}

fn box_attribute(name: &str, b: &Box2i) -> Attribute {
    let value = [b.x_min, b.y_min, b.x_max, b.y_max]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    Attribute {
        name: name.into(),
        type_name: "box2i".into(),
        value,
    }
}

fn channels_attribute(channels: &[Channel]) -> Attribute {
    let mut value = Vec::new();
    for c in channels {
        value.extend_from_slice(c.name.as_bytes());
        value.push(0);
        value.extend_from_slice(&c.sample_type.code().to_le_bytes());
        value.extend_from_slice(&[0, 0, 0, 0]); // pLinear, reserved
        value.extend_from_slice(&1i32.to_le_bytes());
        value.extend_from_slice(&1i32.to_le_bytes());
    }
    value.push(0);
    Attribute {
        name: "channels".into(),
        type_name: "chlist".into(),
        value,
    }
}
