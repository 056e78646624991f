//! Remote rendering (Jähne 2014): render nodes render some objects of a scene, choose fragments
//! with a transfer method, encode them with `strata-wire` and stream them over TCP; a display
//! node drives the animation, receives from every node concurrently, merges the nodes' runs per
//! pixel and resolves.
//!
//! Plain data flows between explicit stages:
//!
//! ```text
//! node:    request ─► render (clear, capture, DeepFrame cut to the depth limit)
//!                     ─► select (difference | reprojection) ─► encode ─► socket
//! display: socket ─► decode ─► apply to the node's copy ─► [fixup round] ─► merge + resolve ─► stats
//! ```
//!
//! - [`select`]: the depth-limited choice (N nearest, optional opacity threshold) for a whole
//!   frame (a node makes it as its store exports, `strata_core::RunLimit`), `restrict`;
//! - [`difference`]: the exact difference transfer — node keys, display copies, fixups;
//! - [`merge`]: per-pixel k-way merge of sorted runs and resolve;
//! - [`node`] and [`display`]: the services (tokio for sockets, threads for CPU stages);
//! - [`report`]: per-frame statistics and the run's summary;
//! - [`sink`] and [`recording`]: each side measured alone — a display that drops frames on
//!   arrival, and a node that replays a recorded stream from memory.

pub mod difference;
pub mod display;
pub mod merge;
pub mod node;
pub mod recording;
pub mod reference;
pub mod report;
pub mod reprojection;
pub mod select;
pub mod sink;
mod stream;
pub mod transfer;

pub use transfer::Transfer;

/// The animation frame that frame number `frame` poses a scene at. Frame numbers travel as
/// `u64`, scenes are posed with `u32` frames: a larger number is refused, never clamped.
pub fn animation_frame(frame: u64) -> Result<u32, FrameOutOfRange> {
    u32::try_from(frame).map_err(|_| FrameOutOfRange(frame))
}

/// A frame number beyond the last frame a scene can be posed at (2^32 - 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("frame {0} is beyond the last animation frame a scene can be posed at ({max})", max = u32::MAX)]
pub struct FrameOutOfRange(pub u64);
