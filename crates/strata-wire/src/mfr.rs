//! The multi-frame-rate messages: a fast client (FC) and a slow client (SC) in two processes.
//!
//! The FC owns the state authority; it sends the SC every new state snapshot, and the SC sends
//! back what it rendered: a buffer header followed by an ordinary frame message (type 1) carrying
//! the DeepFrame. Every message starts with the 20-byte prefix of [`crate::message`]; offsets
//! below are from the first byte of the body. Integers and floats little-endian.
//!
//! ```text
//! FC                                             SC (strata mfr-slow --listen ADDR)
//!  ── MfrHello (role 0: fast) ─────────────────►  checks protocol, scene fingerprint, size
//!  ◄─────────────────────────── MfrHello (role 1) or Error, then closes
//!  ── MfrSnapshot (newest state; latest wins) ─►  renders the newest one when free
//!  ◄──────────── MfrBuffer + Frame (same sc_frame)
//! ```
//!
//! # MfrHello (type 7, both directions, first message on a connection)
//!
//! ```text
//!   0  protocol     u16     1
//!   2  role         u8      0 fast client, 1 slow client
//!   3  reserved     u8      0
//!   4  width        u32     the frame size the FC composes at
//!   8  height       u32
//!  12  fingerprint  u64     a hash of the scene's geometry, materials, placement and camera
//!  20  scene        string  varint length ≤ 4096, UTF-8: the scene's name
//! ```
//!
//! # MfrSnapshot (type 8, FC → SC)
//!
//! ```text
//!   0  id              u64      snapshot number (0 at the start, one more per change)
//!   8  t_ms            f64      trace time it shows
//!  16  events_applied  u64      trace events it includes
//!  24  migration       u8       0 naive, 1 predictive
//!  25  reserved        [u8; 3]  0
//!  28  view            [f32; 9] eye, target, up
//!  64  object_count    u32      ≤ 2^20
//!  68  objects         object_count × 28 bytes:
//!        +0 id u32 | +4 offset [f32; 3] | +16 version u64 | +24 state u8
//!        (0 inactive, 1 over, 2 selected) | +25 reserved [u8; 3]
//! ```
//!
//! # MfrBuffer (type 9, SC → FC, followed by a frame message with `frame_number = sc_frame`)
//!
//! ```text
//!   0  sc_frame        u64      the SC's frame counter
//!   8  snapshot_id     u64      the snapshot it rendered
//!  16  snapshot_t_ms   f64      that snapshot's time
//!  24  render_ms       f64      the SC's time to render it
//!  32  view            [f32; 9] eye, target, up of that snapshot
//!  68  rendered_count  u32      ≤ 2^20
//!  72  excluded_count  u32      ≤ 2^20
//!  76  rendered        rendered_count × (id u32, version u64), sorted by id
//!      excluded        excluded_count × id u32, sorted
//! ```

use crate::bytes::Reader;
use crate::control::{body_of, finish, put_string, string, write_message};
use crate::error::WireError;
use crate::message::{DecodeOptions, MessageType};

/// The multi-frame-rate protocol version [`MfrHello::protocol`] carries.
pub const MFR_PROTOCOL: u16 = 1;
/// Most objects a snapshot or buffer may list.
pub const MAX_MFR_OBJECTS: u32 = 1 << 20;
/// Longest scene name in a hello.
const MAX_SCENE_NAME: usize = 4096;

/// Which side of the link sent a hello.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MfrRole {
    /// The fast client (it connects).
    Fast,
    /// The slow client (it listens).
    Slow,
}

/// The first message on a connection, in both directions (type 7).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MfrHello {
    /// [`MFR_PROTOCOL`] of the sender.
    pub protocol: u16,
    /// The sender's role.
    pub role: MfrRole,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// A hash of the scene: both sides must render the same one.
    pub fingerprint: u64,
    /// The scene's name (for messages).
    pub scene: String,
}

/// One object of a snapshot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MfrObject {
    /// Object id.
    pub id: u32,
    /// Translation the user added.
    pub offset: [f32; 3],
    /// Changes of its transform so far.
    pub version: u64,
    /// Selection state: 0 inactive, 1 over, 2 selected.
    pub state: u8,
}

/// A state snapshot the FC sends (type 8).
#[derive(Clone, Debug, PartialEq)]
pub struct MfrSnapshot {
    /// Snapshot number.
    pub id: u64,
    /// Trace time (ms).
    pub t_ms: f64,
    /// Trace events applied.
    pub events_applied: u64,
    /// 0 naive, 1 predictive.
    pub migration: u8,
    /// Eye, target, up.
    pub view: [f32; 9],
    /// Every object, in scene order.
    pub objects: Vec<MfrObject>,
}

/// The header of an SC buffer (type 9); the DeepFrame follows as a frame message.
#[derive(Clone, Debug, PartialEq)]
pub struct MfrBuffer {
    /// The SC's frame counter.
    pub sc_frame: u64,
    /// The snapshot it rendered.
    pub snapshot_id: u64,
    /// That snapshot's time (ms).
    pub snapshot_t_ms: f64,
    /// The SC's render time (ms).
    pub render_ms: f64,
    /// Eye, target, up.
    pub view: [f32; 9],
    /// `(id, version)` of every object rendered, sorted by id.
    pub rendered: Vec<(u32, u64)>,
    /// Ids of the objects left out, sorted.
    pub excluded: Vec<u32>,
}

fn put_f32s(out: &mut Vec<u8>, v: &[f32]) {
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

fn read_view(r: &mut Reader<'_>) -> Result<[f32; 9], WireError> {
    let mut view = [0f32; 9];
    for v in &mut view {
        *v = r.f32("view")?;
    }
    Ok(view)
}

/// A count checked against [`MAX_MFR_OBJECTS`] and against the bytes left (`each` per item), so
/// no allocation trusts it.
fn count(r: &mut Reader<'_>, field: &'static str, each: usize) -> Result<usize, WireError> {
    let at = r.offset();
    let n = r.u32(field)?;
    if n > MAX_MFR_OBJECTS {
        return Err(WireError::Limit {
            field,
            offset: at,
            value: u64::from(n),
            limit: u64::from(MAX_MFR_OBJECTS),
        });
    }
    let n = n as usize;
    if n.saturating_mul(each) > r.remaining() {
        return Err(WireError::Truncated {
            field,
            offset: r.offset(),
            needed: (n * each) as u64,
            available: r.remaining() as u64,
        });
    }
    Ok(n)
}

impl MfrHello {
    /// Encodes the hello, replacing `out`.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        write_message(out, MessageType::MfrHello, |b| {
            b.extend_from_slice(&self.protocol.to_le_bytes());
            b.push(match self.role {
                MfrRole::Fast => 0,
                MfrRole::Slow => 1,
            });
            b.push(0);
            b.extend_from_slice(&self.width.to_le_bytes());
            b.extend_from_slice(&self.height.to_le_bytes());
            b.extend_from_slice(&self.fingerprint.to_le_bytes());
            let end = self.scene.len().min(MAX_SCENE_NAME);
            let end = (0..=end)
                .rev()
                .find(|&i| self.scene.is_char_boundary(i))
                .unwrap_or(0);
            put_string(b, &self.scene[..end]);
        });
    }

    /// Decodes a complete hello message.
    pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Self, WireError> {
        let mut r = body_of(bytes, MessageType::MfrHello, options)?;
        let protocol = r.u16("protocol")?;
        let at = r.offset();
        let role = match r.u8("role")? {
            0 => MfrRole::Fast,
            1 => MfrRole::Slow,
            other => return Err(WireError::invalid("role", at, other, "0 fast or 1 slow")),
        };
        if r.u8("reserved")? != 0 {
            return Err(WireError::invalid("reserved", at + 1, "", "must be 0"));
        }
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
        let fingerprint = r.u64("fingerprint")?;
        let scene = string(&mut r, "scene", MAX_SCENE_NAME)?;
        finish(&r, "hello")?;
        Ok(MfrHello {
            protocol,
            role,
            width,
            height,
            fingerprint,
            scene,
        })
    }
}

impl MfrSnapshot {
    /// Encodes the snapshot, replacing `out`.
    ///
    /// # Errors
    /// With more than [`MAX_MFR_OBJECTS`] objects.
    pub fn encode_into(&self, out: &mut Vec<u8>) -> Result<(), WireError> {
        if self.objects.len() > MAX_MFR_OBJECTS as usize {
            return Err(WireError::Encode(format!(
                "{} objects in a snapshot, at most {MAX_MFR_OBJECTS}",
                self.objects.len()
            )));
        }
        write_message(out, MessageType::MfrSnapshot, |b| {
            b.extend_from_slice(&self.id.to_le_bytes());
            b.extend_from_slice(&self.t_ms.to_le_bytes());
            b.extend_from_slice(&self.events_applied.to_le_bytes());
            b.extend_from_slice(&[self.migration, 0, 0, 0]);
            put_f32s(b, &self.view);
            b.extend_from_slice(&(self.objects.len() as u32).to_le_bytes());
            for o in &self.objects {
                b.extend_from_slice(&o.id.to_le_bytes());
                put_f32s(b, &o.offset);
                b.extend_from_slice(&o.version.to_le_bytes());
                b.extend_from_slice(&[o.state, 0, 0, 0]);
            }
        });
        Ok(())
    }

    /// Decodes a complete snapshot message.
    pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Self, WireError> {
        let mut r = body_of(bytes, MessageType::MfrSnapshot, options)?;
        let id = r.u64("id")?;
        let t_ms = r.f64("t_ms")?;
        let events_applied = r.u64("events_applied")?;
        let at = r.offset();
        let migration = r.u8("migration")?;
        if migration > 1 {
            return Err(WireError::invalid(
                "migration",
                at,
                migration,
                "0 naive or 1 predictive",
            ));
        }
        if r.take(3, "reserved")? != [0, 0, 0] {
            return Err(WireError::invalid("reserved", at + 1, "", "must be 0"));
        }
        let view = read_view(&mut r)?;
        let n = count(&mut r, "object_count", 28)?;
        let mut objects = Vec::with_capacity(n);
        for _ in 0..n {
            let id = r.u32("object id")?;
            let offset = [r.f32("offset")?, r.f32("offset")?, r.f32("offset")?];
            let version = r.u64("version")?;
            let at = r.offset();
            let state = r.u8("state")?;
            if state > 2 {
                return Err(WireError::invalid(
                    "state",
                    at,
                    state,
                    "0 inactive, 1 over or 2 selected",
                ));
            }
            if r.take(3, "reserved")? != [0, 0, 0] {
                return Err(WireError::invalid("reserved", at + 1, "", "must be 0"));
            }
            objects.push(MfrObject {
                id,
                offset,
                version,
                state,
            });
        }
        finish(&r, "snapshot")?;
        Ok(MfrSnapshot {
            id,
            t_ms,
            events_applied,
            migration,
            view,
            objects,
        })
    }
}

impl MfrBuffer {
    /// Encodes the buffer header, replacing `out`.
    ///
    /// # Errors
    /// With more than [`MAX_MFR_OBJECTS`] objects in either list.
    pub fn encode_into(&self, out: &mut Vec<u8>) -> Result<(), WireError> {
        let most = self.rendered.len().max(self.excluded.len());
        if most > MAX_MFR_OBJECTS as usize {
            return Err(WireError::Encode(format!(
                "{most} objects in a buffer's list, at most {MAX_MFR_OBJECTS}"
            )));
        }
        write_message(out, MessageType::MfrBuffer, |b| {
            b.extend_from_slice(&self.sc_frame.to_le_bytes());
            b.extend_from_slice(&self.snapshot_id.to_le_bytes());
            b.extend_from_slice(&self.snapshot_t_ms.to_le_bytes());
            b.extend_from_slice(&self.render_ms.to_le_bytes());
            put_f32s(b, &self.view);
            b.extend_from_slice(&(self.rendered.len() as u32).to_le_bytes());
            b.extend_from_slice(&(self.excluded.len() as u32).to_le_bytes());
            for (id, version) in &self.rendered {
                b.extend_from_slice(&id.to_le_bytes());
                b.extend_from_slice(&version.to_le_bytes());
            }
            for id in &self.excluded {
                b.extend_from_slice(&id.to_le_bytes());
            }
        });
        Ok(())
    }

    /// Decodes a complete buffer header.
    pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Self, WireError> {
        let mut r = body_of(bytes, MessageType::MfrBuffer, options)?;
        let sc_frame = r.u64("sc_frame")?;
        let snapshot_id = r.u64("snapshot_id")?;
        let snapshot_t_ms = r.f64("snapshot_t_ms")?;
        let render_ms = r.f64("render_ms")?;
        let view = read_view(&mut r)?;
        let rendered_count = count(&mut r, "rendered_count", 0)?;
        let excluded_count = count(&mut r, "excluded_count", 0)?;
        let need = rendered_count * 12 + excluded_count * 4;
        if need > r.remaining() {
            return Err(WireError::Truncated {
                field: "rendered",
                offset: r.offset(),
                needed: need as u64,
                available: r.remaining() as u64,
            });
        }
        let mut rendered = Vec::with_capacity(rendered_count);
        for _ in 0..rendered_count {
            rendered.push((r.u32("rendered id")?, r.u64("rendered version")?));
        }
        let mut excluded = Vec::with_capacity(excluded_count);
        for _ in 0..excluded_count {
            excluded.push(r.u32("excluded id")?);
        }
        finish(&r, "buffer")?;
        Ok(MfrBuffer {
            sc_frame,
            snapshot_id,
            snapshot_t_ms,
            render_ms,
            view,
            rendered,
            excluded,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_mfr_message_round_trips() {
        let options = DecodeOptions::default();
        let mut out = Vec::new();
        let hello = MfrHello {
            protocol: MFR_PROTOCOL,
            role: MfrRole::Slow,
            width: 640,
            height: 360,
            fingerprint: 0x0123_4567_89ab_cdef,
            scene: "mixed".into(),
        };
        hello.encode_into(&mut out);
        assert_eq!(MfrHello::decode(&out, &options).unwrap(), hello);
        let snapshot = MfrSnapshot {
            id: 9,
            t_ms: 123.25,
            events_applied: 4,
            migration: 1,
            view: [1.0, 2.0, 3.0, 0.0, 0.5, 0.0, 0.0, 1.0, 0.0],
            objects: vec![
                MfrObject {
                    id: 3,
                    offset: [0.1, -0.2, 0.3],
                    version: 7,
                    state: 2,
                },
                MfrObject {
                    id: 4,
                    offset: [0.0; 3],
                    version: 0,
                    state: 0,
                },
            ],
        };
        snapshot.encode_into(&mut out).unwrap();
        assert_eq!(MfrSnapshot::decode(&out, &options).unwrap(), snapshot);
        let buffer = MfrBuffer {
            sc_frame: 12,
            snapshot_id: 9,
            snapshot_t_ms: 123.25,
            render_ms: 88.5,
            view: snapshot.view,
            rendered: vec![(4, 0), (5, 2)],
            excluded: vec![3],
        };
        buffer.encode_into(&mut out).unwrap();
        assert_eq!(MfrBuffer::decode(&out, &options).unwrap(), buffer);
    }

    #[test]
    fn a_count_larger_than_the_message_is_refused_before_allocating() {
        let options = DecodeOptions::default();
        let mut out = Vec::new();
        let buffer = MfrBuffer {
            sc_frame: 1,
            snapshot_id: 1,
            snapshot_t_ms: 0.0,
            render_ms: 0.0,
            view: [0.0; 9],
            rendered: vec![(1, 1)],
            excluded: vec![],
        };
        buffer.encode_into(&mut out).unwrap();
        // rendered_count at body offset 68: claim 2^20 entries.
        let at = crate::PREFIX_LEN + 68;
        out[at..at + 4].copy_from_slice(&(1u32 << 20).to_le_bytes());
        let unchecked = DecodeOptions {
            verify_checksum: false,
            ..options
        };
        let e = MfrBuffer::decode(&out, &unchecked).unwrap_err();
        assert!(
            matches!(
                e,
                WireError::Truncated {
                    field: "rendered",
                    ..
                }
            ),
            "{e}"
        );
    }
}
