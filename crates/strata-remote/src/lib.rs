//! Remote rendering (seed 000): render nodes render some objects of a scene, choose fragments
//! with a transfer method, encode them with `strata-wire` and stream them over TCP; a display
//! node drives the animation, receives from every node concurrently, merges the nodes' runs per
//! pixel and resolves.
//!
//! Plain data flows between explicit stages:
//!
//! ```text
//! node:    request ─► render (clear, capture, DeepFrame) ─► select (full | depth-limited | difference)
//!                     ─► encode ─► socket
//! display: socket ─► decode ─► apply to the node's copy ─► [fixup round] ─► merge + resolve ─► stats
//! ```
//!
//! - [`select`]: the depth-limited choice (N nearest, optional opacity threshold), `restrict`;
//! - [`difference`]: the exact difference transfer — node keys, display copies, fixups;
//! - [`merge`]: per-pixel k-way merge of sorted runs and resolve;
//! - [`node`] and [`display`]: the services (tokio for sockets, threads for CPU stages);
//! - [`report`]: per-frame statistics and the run's summary.

pub mod difference;
pub mod display;
pub mod merge;
pub mod node;
pub mod reference;
pub mod report;
pub mod reprojection;
pub mod select;
mod stream;
pub mod transfer;

pub use transfer::Transfer;
