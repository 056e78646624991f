//! The codecs: how a DeepFrame becomes a list of sections and back, all lossless.
//!
//! A codec is a *layout* (which sections, what bytes each holds before compression) plus the
//! general-purpose compressor applied to every section:
//!
//! | codec | id | layout | compressor |
//! | --- | --- | --- | --- |
//! | `raw` | 0 | [`seed`]: one section, the thesis's header + 12-byte nodes | none |
//! | `lz4` | 1 | [`seed`] | LZ4 block — Jähne 2014's comparison (Table A.1) |
//! | `zstd` | 2 | [`seed`] | zstd, level configurable (default 3) |
//! | `deep-lz4` | 3 | [`deep`]: counts, depth, colour, object sections after prediction | LZ4 block |
//! | `deep-zstd` | 4 | [`deep`] | zstd (default level 1) |
//! | `deep-huff` | 5 | [`deep`] | blocks: Huffman, LZ4, fill or stored, the smallest, per block of at most 128 KiB |
//!
//! Sections are compressed independently (and in parallel); a section that would not shrink is
//! stored (`compression = none`), which the decoder accepts for any codec.

pub(crate) mod blocks;
pub mod compress;
pub mod deep;
pub(crate) mod huffman;
pub(crate) mod lz4_block;
pub mod seed;

use std::fmt;
use std::str::FromStr;

use rayon::prelude::*;
use strata_core::DeepFrame;

pub use compress::Compression;

use crate::error::WireError;

/// Default zstd level of the `zstd` codec (the zstd library's own default).
pub const DEFAULT_ZSTD_LEVEL: i32 = 3;
/// Default zstd level of the `deep-zstd` codec: on prediction residuals level 1 compresses as
/// well as level 3 at a third of the time (measured on the built-in scenes and meshes).
pub const DEFAULT_DEEP_ZSTD_LEVEL: i32 = 1;

/// A lossless DeepFrame codec; see the module docs for the table of codecs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Codec {
    /// List layout, uncompressed: the baseline.
    Raw,
    /// List layout under LZ4.
    Lz4,
    /// List layout under zstd.
    Zstd {
        /// zstd level, -128..=22.
        level: i32,
    },
    /// DeepFrame-aware layout under LZ4.
    DeepLz4,
    /// DeepFrame-aware layout under zstd.
    DeepZstd {
        /// zstd level, -128..=22.
        level: i32,
    },
    /// DeepFrame-aware layout in blocks, each Huffman-coded, LZ4, one repeated byte or stored
    /// (whichever is smallest).
    DeepHuff,
}

impl Codec {
    /// Every codec at its default settings, baseline first.
    pub const ALL: [Codec; 6] = [
        Codec::Raw,
        Codec::Lz4,
        Codec::Zstd {
            level: DEFAULT_ZSTD_LEVEL,
        },
        Codec::DeepLz4,
        Codec::DeepZstd {
            level: DEFAULT_DEEP_ZSTD_LEVEL,
        },
        Codec::DeepHuff,
    ];

    /// The name used on the command line and in reports (`raw`, `lz4`, `zstd`, `deep-lz4`,
    /// `deep-zstd`, `deep-huff`).
    pub fn name(self) -> &'static str {
        match self {
            Codec::Raw => "raw",
            Codec::Lz4 => "lz4",
            Codec::Zstd { .. } => "zstd",
            Codec::DeepLz4 => "deep-lz4",
            Codec::DeepZstd { .. } => "deep-zstd",
            Codec::DeepHuff => "deep-huff",
        }
    }

    /// The `codec` byte.
    pub fn id(self) -> u8 {
        match self {
            Codec::Raw => 0,
            Codec::Lz4 => 1,
            Codec::Zstd { .. } => 2,
            Codec::DeepLz4 => 3,
            Codec::DeepZstd { .. } => 4,
            Codec::DeepHuff => 5,
        }
    }

    /// The `codec_param` byte: the zstd level as an `i8`, 0 for the others.
    pub fn param(self) -> u8 {
        match self {
            Codec::Zstd { level } | Codec::DeepZstd { level } => level as i8 as u8,
            _ => 0,
        }
    }

    /// The codec a `codec` and `codec_param` byte pair names, if any: `codec_param` must be 0
    /// for the codecs without a parameter and a level the encoder accepts (-128..=22) for the
    /// zstd ones, so that every decoded codec can be written again and every message has one
    /// header.
    pub fn from_bytes(id: u8, param: u8) -> Option<Self> {
        let level = i32::from(param as i8);
        let codec = match (id, param) {
            (0, 0) => Codec::Raw,
            (1, 0) => Codec::Lz4,
            (2, _) => Codec::Zstd { level },
            (3, 0) => Codec::DeepLz4,
            (4, _) => Codec::DeepZstd { level },
            (5, 0) => Codec::DeepHuff,
            _ => return None,
        };
        codec.validate().ok().map(|()| codec)
    }

    /// The compressor applied to each section.
    pub fn compression(self) -> Compression {
        match self {
            Codec::Raw => Compression::None,
            Codec::Lz4 | Codec::DeepLz4 => Compression::Lz4,
            Codec::Zstd { .. } | Codec::DeepZstd { .. } => Compression::Zstd,
            Codec::DeepHuff => Compression::Blocks,
        }
    }

    pub(crate) fn level(self) -> i32 {
        match self {
            Codec::Zstd { level } | Codec::DeepZstd { level } => level,
            _ => 0,
        }
    }

    /// The sections this codec's layout has, in wire order.
    pub fn sections(self) -> &'static [SectionTag] {
        match self {
            Codec::Raw | Codec::Lz4 | Codec::Zstd { .. } => &[SectionTag::Seed],
            Codec::DeepLz4 | Codec::DeepZstd { .. } | Codec::DeepHuff => &[
                SectionTag::Counts,
                SectionTag::Depth,
                SectionTag::Color,
                SectionTag::Object,
            ],
        }
    }

    /// Checks the settings an encoder would write.
    pub fn validate(self) -> Result<(), WireError> {
        let level = self.level();
        if !(-128..=22).contains(&level) {
            return Err(WireError::Encode(format!(
                "zstd level {level} is outside -128..=22"
            )));
        }
        Ok(())
    }
}

impl fmt::Display for Codec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Codec::Zstd { level } if *level != DEFAULT_ZSTD_LEVEL => write!(f, "zstd:{level}"),
            Codec::DeepZstd { level } if *level != DEFAULT_DEEP_ZSTD_LEVEL => {
                write!(f, "deep-zstd:{level}")
            }
            c => f.write_str(c.name()),
        }
    }
}

/// A codec name that does not parse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown codec '{0}': expected raw, lz4, zstd[:LEVEL], deep-lz4, deep-zstd[:LEVEL] or deep-huff"
)]
pub struct UnknownCodec(pub String);

impl FromStr for Codec {
    type Err = UnknownCodec;

    /// Parses `raw`, `lz4`, `zstd`, `zstd:LEVEL`, `deep-lz4`, `deep-zstd`, `deep-zstd:LEVEL`,
    /// `deep-huff` (`deep` is short for `deep-zstd`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || UnknownCodec(s.to_owned());
        let (name, level) = match s.split_once(':') {
            Some((n, l)) => (n, Some(l.parse::<i32>().map_err(|_| bad())?)),
            None => (s, None),
        };
        let codec = match (name, level) {
            ("raw", None) => Codec::Raw,
            ("lz4", None) => Codec::Lz4,
            ("deep-lz4", None) => Codec::DeepLz4,
            ("deep-huff", None) => Codec::DeepHuff,
            ("zstd", l) => Codec::Zstd {
                level: l.unwrap_or(DEFAULT_ZSTD_LEVEL),
            },
            ("deep-zstd" | "deep", l) => Codec::DeepZstd {
                level: l.unwrap_or(DEFAULT_DEEP_ZSTD_LEVEL),
            },
            _ => return Err(bad()),
        };
        codec.validate().map_err(|_| bad())?;
        Ok(codec)
    }
}

/// What a section holds (the section table's `tag` byte).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum SectionTag {
    /// The thesis layout: per-pixel u32 counts, then 12-byte nodes.
    Seed = 1,
    /// Deep layout: per-pixel fragment counts as varints.
    Counts = 16,
    /// Deep layout: depth prediction residuals, four byte planes.
    Depth = 17,
    /// Deep layout: colour prediction residuals, four channel planes.
    Color = 18,
    /// Deep layout: object-id prediction residuals, zero-run coded.
    Object = 19,
    /// Difference transfer: the pixels the message replaces ([`crate::PixelMask`]), before the
    /// codec's sections.
    Mask = 32,
    /// Difference transfer: pixels not replaced whose runs changed depth but not colour, so the
    /// display's copy is stale there (see `strata-remote`'s difference module).
    Stale = 33,
    /// Reprojection transfer: the positions each touched pixel loses ([`crate::Removals`]),
    /// after the mask and before the codec's sections.
    Removals = 34,
}

impl SectionTag {
    /// The wire byte's meaning, if any.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            1 => Some(SectionTag::Seed),
            16 => Some(SectionTag::Counts),
            17 => Some(SectionTag::Depth),
            18 => Some(SectionTag::Color),
            19 => Some(SectionTag::Object),
            32 => Some(SectionTag::Mask),
            33 => Some(SectionTag::Stale),
            34 => Some(SectionTag::Removals),
            _ => None,
        }
    }

    /// Lower-case name, as in error messages.
    pub fn name(self) -> &'static str {
        match self {
            SectionTag::Seed => "lists",
            SectionTag::Counts => "counts",
            SectionTag::Depth => "depth",
            SectionTag::Color => "color",
            SectionTag::Object => "object",
            SectionTag::Mask => "mask",
            SectionTag::Stale => "stale",
            SectionTag::Removals => "removals",
        }
    }

    /// The decoded lengths this section may announce for `pixels` pixels and `fragments`
    /// fragments, as an inclusive range; checked before anything is allocated. The bounds
    /// saturate at `u64::MAX` (a decoder whose limits allow `u32::MAX × u32::MAX` pixels must get
    /// an error from the check, not an overflow).
    pub fn decoded_range(self, pixels: u64, fragments: u64) -> (u64, u64) {
        match self {
            SectionTag::Seed => {
                let n = pixels
                    .saturating_mul(4)
                    .saturating_add(fragments.saturating_mul(12));
                (n, n)
            }
            SectionTag::Counts => (pixels, pixels.saturating_mul(5)),
            SectionTag::Depth | SectionTag::Color => {
                let n = fragments.saturating_mul(4);
                (n, n)
            }
            // Zero-run pairs: at most one 5-byte run and one 5-byte value per fragment, plus the
            // final run.
            SectionTag::Object => (1, fragments.saturating_mul(10).saturating_add(5)),
            // A run count, then at most one (gap, len) pair of two 5-byte varints per two pixels.
            SectionTag::Mask | SectionTag::Stale => {
                (1, pixels.saturating_mul(5).saturating_add(15))
            }
            // The checksum, a count per pixel, a varint per removed position; `fragments` is the
            // most the receiver holds (its `max_fragments`), not the message's count.
            SectionTag::Removals => (
                12,
                pixels
                    .saturating_add(fragments)
                    .saturating_mul(5)
                    .saturating_add(12),
            ),
        }
    }
}

/// One section's entry in the section table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SectionInfo {
    /// What it holds.
    pub tag: SectionTag,
    /// How its payload is compressed.
    pub compression: Compression,
    /// Payload bytes on the wire.
    pub encoded_len: u64,
    /// Bytes after decompression.
    pub decoded_len: u64,
}

/// A section ready to be written: its table entry and payload (in an [`EncodeScratch`]).
#[derive(Debug)]
pub(crate) struct EncodedSection<'a> {
    pub(crate) info: SectionInfo,
    pub(crate) payload: &'a [u8],
}

/// One section an encoder is building: its bytes before compression, and the compressor that
/// keeps its output.
#[derive(Debug)]
struct SectionSlot {
    tag: SectionTag,
    raw: Vec<u8>,
    packer: compress::Packer,
}

/// Buffers an encoder keeps between frames, one slot a section of a message: each section's
/// bytes are laid out, then compressed with LZ4, into memory the previous frame used (`strata
/// codecs`'s encode and a render node's encode thread); zstd allocates its output each time. A
/// fresh scratch gives the same bytes.
///
/// ```text
/// slots[i]: tag, raw bytes (the layout's, before compression), packer (the payload)
/// used:     slots of the message being encoded, in section order
/// ```
#[derive(Debug, Default)]
pub(crate) struct EncodeScratch {
    slots: Vec<SectionSlot>,
    used: usize,
}

impl EncodeScratch {
    /// Starts a message: no sections yet.
    pub(crate) fn clear(&mut self) {
        self.used = 0;
    }

    /// Appends sections tagged `tags` and returns their raw buffers as an earlier message left
    /// them, for the caller to empty or overwrite (their capacity kept).
    fn push<const N: usize>(&mut self, tags: [SectionTag; N]) -> [&mut Vec<u8>; N] {
        let start = self.used;
        for (i, tag) in tags.into_iter().enumerate() {
            match self.slots.get_mut(start + i) {
                Some(slot) => slot.tag = tag,
                None => self.slots.push(SectionSlot {
                    tag,
                    raw: Vec::new(),
                    packer: compress::Packer::default(),
                }),
            }
        }
        self.used += N;
        let mut raws = self.slots[start..start + N].iter_mut().map(|s| &mut s.raw);
        std::array::from_fn(|_| raws.next().expect("N slots"))
    }

    /// Appends one section tagged `tag`, its raw bytes written by `fill` into an empty buffer.
    pub(crate) fn push_with(&mut self, tag: SectionTag, fill: impl FnOnce(&mut Vec<u8>)) {
        let [raw] = self.push([tag]);
        raw.clear();
        fill(raw);
    }

    /// Appends `frame`'s sections in `codec`'s layout.
    pub(crate) fn push_frame(&mut self, frame: &DeepFrame, codec: Codec) {
        match codec {
            Codec::Raw | Codec::Lz4 | Codec::Zstd { .. } => {
                let [raw] = self.push([SectionTag::Seed]);
                seed::encode_into(frame, raw);
            }
            Codec::DeepLz4 | Codec::DeepZstd { .. } | Codec::DeepHuff => {
                deep::encode_into(frame, self.push(deep::SECTIONS));
            }
        }
    }

    /// Compresses every section appended since [`EncodeScratch::clear`] with `codec`'s
    /// compressor (in parallel), each stored instead where that would not shrink it.
    pub(crate) fn sections(&mut self, codec: Codec) -> Result<Vec<EncodedSection<'_>>, WireError> {
        codec.validate()?;
        let (method, level) = (codec.compression(), codec.level());
        self.slots[..self.used]
            .par_iter_mut()
            .map(|slot| {
                // The deep layout's byte planes.
                let planes = match slot.tag {
                    SectionTag::Depth | SectionTag::Color => 4,
                    _ => 1,
                };
                let (compression, payload) = slot.packer.pack(&slot.raw, method, level, planes)?;
                Ok(EncodedSection {
                    info: SectionInfo {
                        tag: slot.tag,
                        compression,
                        encoded_len: payload.len() as u64,
                        decoded_len: slot.raw.len() as u64,
                    },
                    payload,
                })
            })
            .collect()
    }
}

/// A section as found in a message: its table entry, payload, and where the payload starts.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SectionRef<'a> {
    pub(crate) info: SectionInfo,
    pub(crate) payload: &'a [u8],
    pub(crate) offset: u64,
}

/// Buffers a decoder keeps between frames, so that a stream of frames decodes into memory it
/// already has instead of fresh pages, which the kernel zeroes on first touch (`strata codecs`:
/// 2–5 % less time than a fresh decoder on 1280×720 frames of the meshes, AMD EPYC; more
/// where the allocator hands every frame fresh pages).
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    /// One decompression buffer per section slot.
    pub(crate) sections: Vec<Vec<u8>>,
    /// The columns of a frame handed back ([`Scratch::recycle`]), as the decoders fill them.
    pub(crate) columns: Columns,
}

/// A frame's columns, as [`DeepFrame::into_parts`] gives them back and the decoders fill them.
#[derive(Debug, Default)]
pub(crate) struct Columns {
    pub(crate) offsets: Vec<u32>,
    pub(crate) depth: Vec<f32>,
    pub(crate) color: Vec<strata_core::Rgba8>,
    pub(crate) object: Vec<strata_core::ObjectId>,
    /// Whether `offsets` hold the frame's run offsets already, read from a deep layout's
    /// counts section while the other sections were decompressed (`Some`), and what the
    /// reading found; `None` before a decode and for other layouts.
    pub(crate) counted: Option<Result<(), WireError>>,
}

impl Columns {
    /// The frame these columns hold, its invariants checked (the allocations become the
    /// frame's columns).
    pub(crate) fn into_frame(self, width: u32, height: u32) -> Result<DeepFrame, WireError> {
        Ok(DeepFrame::from_parts(
            width,
            height,
            self.offsets,
            self.depth,
            self.color,
            self.object,
        )?)
    }
}

impl Scratch {
    /// Keeps `frame`'s allocations for the next decode.
    pub(crate) fn recycle(&mut self, frame: DeepFrame) {
        let (_, _, offsets, depth, color, object) = frame.into_parts();
        self.columns = Columns {
            offsets,
            depth,
            color,
            object,
            counted: None,
        };
    }
}

/// Decompresses every section (in parallel) after the caller validated the table, into the
/// first `sections.len()` buffers of `scratch.sections`, for a frame of `pixels` pixels and
/// `fragments` fragments.
///
/// A deep layout's counts section is read into run offsets (`scratch.columns.offsets`) as
/// soon as it is decompressed, beside the decompression of the larger sections: the counts
/// take about as long to read as a small frame's depths take to decompress, and otherwise ran
/// alone between the two stages. What the reading found waits in `scratch.columns.counted` for
/// [`decode_sections`], so errors are reported in the same order as when it read them there.
///
/// The jobs are started largest first (by compressed bytes, plus the decompressed bytes of
/// the counts for their reading), each idle thread taking the next: with two threads the
/// colour section runs on one while the depths, the counts and the object ids run on the
/// other. Decompression errors are reported for the first failing section in message order.
pub(crate) fn decompress_sections(
    sections: &[SectionRef<'_>],
    scratch: &mut Scratch,
    pixels: usize,
    fragments: usize,
) -> Result<(), WireError> {
    /// One section to decompress, and for the counts, the offsets to read them into.
    struct Job<'a> {
        section: &'a SectionRef<'a>,
        out: &'a mut Vec<u8>,
        offsets: Option<&'a mut Vec<u32>>,
        decompressed: Result<(), WireError>,
        counted: Option<Result<(), WireError>>,
    }
    let Scratch {
        sections: buffers,
        columns,
    } = scratch;
    columns.counted = None;
    if buffers.len() < sections.len() {
        buffers.resize_with(sections.len(), Vec::new);
    }
    let mut offsets = Some(&mut columns.offsets);
    let mut jobs: Vec<Job<'_>> = sections
        .iter()
        .zip(buffers.iter_mut())
        .map(|(section, out)| Job {
            section,
            out,
            offsets: if section.info.tag == SectionTag::Counts {
                offsets.take()
            } else {
                None
            },
            decompressed: Ok(()),
            counted: None,
        })
        .collect();
    let cost = |j: &Job<'_>| {
        let reading = if j.offsets.is_some() {
            j.section.info.decoded_len
        } else {
            0
        };
        j.section.info.encoded_len + reading
    };
    let mut order: Vec<&mut Job<'_>> = jobs.iter_mut().collect();
    order.sort_by_key(|j| std::cmp::Reverse(cost(j)));
    rayon::scope_fifo(|scope| {
        for job in order {
            scope.spawn_fifo(move |_| {
                let s = job.section;
                job.decompressed = compress::decompress_into(
                    s.payload,
                    s.info.compression,
                    s.info.decoded_len as usize,
                    s.info.tag.name(),
                    s.offset,
                    job.out,
                );
                if let (Ok(()), Some(offsets)) = (&job.decompressed, job.offsets.as_deref_mut()) {
                    job.counted = Some(deep::decode_counts(
                        job.out, pixels, fragments, s.offset, offsets,
                    ));
                }
            });
        }
    });
    for job in &mut jobs {
        std::mem::replace(&mut job.decompressed, Ok(()))?;
        if job.counted.is_some() {
            columns.counted = job.counted.take();
        }
    }
    Ok(())
}

/// Rebuilds the frame from decompressed sections (in the codec's order), into `columns`'
/// allocations.
pub(crate) fn decode_sections(
    codec: Codec,
    width: u32,
    height: u32,
    fragments: u32,
    sections: &[SectionRef<'_>],
    decoded: &[Vec<u8>],
    columns: &mut Columns,
) -> Result<DeepFrame, WireError> {
    match codec {
        Codec::Raw | Codec::Lz4 | Codec::Zstd { .. } => seed::decode(
            width,
            height,
            fragments,
            &decoded[0],
            sections[0].offset,
            columns,
        ),
        Codec::DeepLz4 | Codec::DeepZstd { .. } | Codec::DeepHuff => {
            let offsets: Vec<u64> = sections.iter().map(|s| s.offset).collect();
            deep::decode(width, height, fragments, decoded, &offsets, columns)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codec_bytes_and_names_round_trip() {
        for c in Codec::ALL
            .into_iter()
            .chain([Codec::Zstd { level: -7 }, Codec::DeepZstd { level: 19 }])
        {
            assert_eq!(Codec::from_bytes(c.id(), c.param()), Some(c));
            assert_eq!(c.to_string().parse::<Codec>(), Ok(c));
        }
        assert_eq!("deep".parse::<Codec>(), Ok(Codec::ALL[4]));
        assert!("zstd:99".parse::<Codec>().is_err());
        assert!("lz4:3".parse::<Codec>().is_err());
        assert!("gzip".parse::<Codec>().is_err());
        assert_eq!(Codec::from_bytes(6, 0), None);
        assert_eq!(Codec::from_bytes(5, 1), None);
        // A parameter where none is defined, or a level the encoder refuses, names no codec.
        assert_eq!(Codec::from_bytes(0, 1), None);
        assert_eq!(Codec::from_bytes(3, 0xff), None);
        assert_eq!(Codec::from_bytes(2, 23), None);
        assert_eq!(Codec::from_bytes(4, 127), None);
        assert_eq!(Codec::from_bytes(2, 22), Some(Codec::Zstd { level: 22 }));
        assert_eq!(
            Codec::from_bytes(4, 0x80),
            Some(Codec::DeepZstd { level: -128 })
        );
    }

    #[test]
    fn decoded_ranges_saturate_instead_of_overflowing() {
        let max = u64::from(u32::MAX);
        assert_eq!(SectionTag::Seed.decoded_range(max * max, max).0, u64::MAX);
        assert_eq!(SectionTag::Counts.decoded_range(max * max, 0).1, u64::MAX);
        assert_eq!(SectionTag::Depth.decoded_range(0, u64::MAX).0, u64::MAX);
        assert_eq!(SectionTag::Object.decoded_range(0, u64::MAX).1, u64::MAX);
        assert_eq!(SectionTag::Mask.decoded_range(max * max, 0).1, u64::MAX);
        assert_eq!(SectionTag::Stale.decoded_range(max * max, 0).1, u64::MAX);
        assert_eq!(SectionTag::Seed.decoded_range(6, 7), (108, 108));
    }
}
