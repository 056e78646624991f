//! The thesis layout (Jähne 2014 §2.1, ch. 3): a 4-byte header per pixel, then 12-byte nodes.
//!
//! The baseline every other codec is measured against, and what `raw`, `lz4` and `zstd` compress.
//! One section, `seed`, of exactly `4·w·h + 12·n` bytes:
//!
//! ```text
//! counts: [u32 LE; w*h]      fragments of pixel p, row-major, row 0 at the top
//! nodes:  [node; n]          pixel 0's run front to back, then pixel 1's, …
//!   node = depth f32 LE (4) | r g b a u8 (4) | object id u32 LE (4)
//! ```
//!
//! The thesis's header holds a pointer into the node buffer and its nodes a `next` pointer (the GPU
//! linked list as captured); a DeepFrame is already compacted and sorted, so the header holds the
//! count and the node's third word carries the object id instead of the link — the same 4 + 12
//! bytes the thesis sends (before its driver pads nodes to 16).

use strata_core::{DeepFrame, ObjectId, Rgba8};

use crate::codec::Columns;
use crate::error::WireError;

/// Bytes per node.
pub const NODE_BYTES: usize = 12;

/// The section's bytes, into `out` (replaced; its capacity reused).
pub(crate) fn encode_into(frame: &DeepFrame, out: &mut Vec<u8>) {
    let pixels = frame.offsets().len() - 1;
    let n = frame.fragment_count();
    out.clear();
    out.reserve(4 * pixels + NODE_BYTES * n);
    for c in frame.counts() {
        out.extend_from_slice(&c.to_le_bytes());
    }
    for ((d, c), o) in frame
        .depths()
        .iter()
        .zip(frame.colors())
        .zip(frame.objects())
    {
        out.extend_from_slice(&d.to_le_bytes());
        out.extend_from_slice(&c.0);
        out.extend_from_slice(&o.0.to_le_bytes());
    }
}

/// Rebuilds the frame from the section's bytes, into `spare`'s allocations; `bytes.len() ==
/// 4·w·h + 12·n` was checked against the header before decompressing.
pub(crate) fn decode(
    width: u32,
    height: u32,
    fragments: u32,
    bytes: &[u8],
    offset: u64,
    spare: &mut Columns,
) -> Result<DeepFrame, WireError> {
    let pixels = width as usize * height as usize;
    let n = fragments as usize;
    if bytes.len() != 4 * pixels + NODE_BYTES * n {
        return Err(WireError::section(
            "lists",
            offset,
            format!(
                "{} bytes, a {width}x{height} frame of {n} fragments needs {}",
                bytes.len(),
                4 * pixels + NODE_BYTES * n
            ),
        ));
    }
    let (head, nodes) = bytes.split_at(4 * pixels);
    let mut offsets = std::mem::take(&mut spare.offsets);
    offsets.clear();
    offsets.reserve(pixels + 1);
    offsets.push(0u32);
    let mut total: u64 = 0;
    for (p, c) in head.chunks_exact(4).enumerate() {
        let c = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        total += u64::from(c);
        if total > n as u64 {
            return Err(WireError::section(
                "lists",
                offset + 4 * p as u64,
                format!(
                    "the counts up to pixel {p} add up to {total}, more than the {n} fragments the header announces"
                ),
            ));
        }
        offsets.push(total as u32);
    }
    if total != n as u64 {
        return Err(WireError::section(
            "lists",
            offset,
            format!("the counts add up to {total}, the header announces {n} fragments"),
        ));
    }
    let (mut depth, mut color, mut object) = (
        std::mem::take(&mut spare.depth),
        std::mem::take(&mut spare.color),
        std::mem::take(&mut spare.object),
    );
    depth.clear();
    color.clear();
    object.clear();
    depth.reserve(n);
    color.reserve(n);
    object.reserve(n);
    for node in nodes.chunks_exact(NODE_BYTES) {
        depth.push(f32::from_bits(u32::from_le_bytes([
            node[0], node[1], node[2], node[3],
        ])));
        color.push(Rgba8([node[4], node[5], node[6], node[7]]));
        object.push(ObjectId(u32::from_le_bytes([
            node[8], node[9], node[10], node[11],
        ])));
    }
    // The allocations become the frame's columns.
    Columns {
        offsets,
        depth,
        color,
        object,
        counted: None,
    }
    .into_frame(width, height)
}
