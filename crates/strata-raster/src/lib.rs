//! strata's CPU rasterizer: scene geometry in, fragments out, in parallel and deterministically.
//!
//! The rasterizer turns a [`FrameInput`] (meshes, model matrices, materials, camera) into
//! fragments pushed into a [`CaptureTarget`] — a fragment store. It follows the conventions of
//! strata's shared conventions exactly: GL projection, pixel centres at `(x + ½, y + ½)`, the top-left fill rule,
//! exact near-plane clipping, perspective-correct interpolation, no culling, headlight and unlit
//! shading, RGBA8 rounding.
//!
//! # Stages
//!
//! ```text
//! FrameInput ──► vertex ──────► setup + bin ─────────────► scan (per strip) ──► FragmentSink
//!               (par. over     (par. over triangle         (par. over           (one per strip)
//!                vertices)      chunks; micro-triangles     strips)
//!                               rasterised here)
//! ```
//!
//! 1. **vertex** ([`vertex`]): every vertex to eye space and clip space, an outcode against the
//!    view volume and a guard band, and — for vertices in front of the near plane — 24.8
//!    fixed-point window coordinates, window depth and the perspective-weighted attributes,
//!    eight vertices at a time in SIMD lanes with the bits of one at a time. Three flat arrays
//!    (positions, outcodes, attributes) for all objects of the frame.
//! 2. **setup + bin** ([`setup`]): triangles in chunks of consecutive primitives of one object.
//!    A triangle entirely outside one view plane, with zero area, or covering no pixel centre is
//!    culled; one that crosses the near plane or the guard band is clipped exactly in clip space
//!    ([`clip`]). Triangles are classified in SIMD lanes, 16 at a time on AVX-512 and 8
//!    elsewhere ([`lanes`], [`coverage::Batch`]). *Micro-triangles* (bounding box of at most
//!    8 × 4 or 4 × 8 pixel centres, vertices within 9 × 5 or 5 × 9 pixels) are finished here: exact coverage as a bitmask computed in the
//!    same lanes, shading in lanes too ([`shade_lanes`]), and 12-byte fragment records appended to per-strip lists. Larger
//!    triangles and clipped pieces are copied with their vertices and appended to the bin of
//!    every *strip* their rows touch, with a cursor into the strip's record list.
//! 3. **scan** ([`scan`]): strips are rasterised in parallel. A strip walks the chunks in order,
//!    and in each chunk replays the micro-triangle records and scans the binned triangles,
//!    interleaved by the cursors — so every pixel receives its fragments in primitive order, from
//!    one thread, whatever the thread count. Large triangles are scanned row by row over exact
//!    spans, their samples shaded 16 or 8 at a time in lanes ([`shade_lanes::SpanShader`]); depth
//!    is affine in screen space; normals and eye positions are interpolated
//!    perspective-correctly for the headlight. Setup and the scan are compiled once per
//!    instruction set and lane width and chosen at run time (AVX-512 at 16 lanes, AVX2 or SSE2
//!    at 8 on x86-64), with the same bits on every one (no fused multiply-adds).
//!
//! # Why strips
//!
//! A strip is a band of `strip_height` full-width rows, so every per-pixel buffer of a store
//! (row-major) splits into disjoint contiguous slices, one per strip — the CPU analogue of pixel
//! synchronisation, with no per-fragment atomics and no read-modify-write hazards, and with plain
//! `chunks_mut` instead of unsafe sharing. Bins are per (chunk, strip) vectors filled without
//! synchronisation by the chunk's worker and read by the strip's worker.
//!
//! # Determinism
//!
//! Every fragment's value is a function of its triangle and pixel alone, and a pixel's fragments
//! arrive in primitive order; neither depends on the number of threads. Reordering triangles
//! changes only the arrival order, which the stores' front-to-back sort removes.
//!
//! # Allocation
//!
//! [`Rasterizer`] owns its buffers (vertices, chunks, bins, fragment records) and reuses their
//! capacity from frame to frame; nothing is allocated per triangle or per fragment once the
//! buffers have grown to the scene's needs.

pub mod clip;
pub mod coverage;
pub mod frame;
pub mod lanes;
pub mod rasterizer;
pub mod scan;
pub mod setup;
pub mod shade_lanes;
pub mod sink;
pub mod vertex;

#[cfg(test)]
mod test_rand;

pub use frame::{DrawObject, FragmentOutput, FrameInput};
pub use rasterizer::{Prepared, RasterConfig, RasterStats, Rasterizer, SetupStats};
pub use sink::{CaptureTarget, FragmentSink, FragmentVec, StripLayout};
