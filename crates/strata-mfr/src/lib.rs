//! strata-mfr: multi-frame-rate rendering (Springer 2008) on strata's DeepFrames.
//!
//! A *slow client* (SC) renders the heavy, static part of a scene at whatever rate it manages; a
//! *fast client* (FC) renders the objects the user manipulates at its own rate and composites
//! every frame with the newest SC buffer. Both follow one **state authority**, which replays what
//! the user does and publishes what the scene looks like as numbered, immutable snapshots.
//!
//! ```text
//! interaction trace ─► Authority ──Arc<Snapshot>──► SC loop (latest wins) ─┐ transfer buffer
//! (view, pointer,       Fig. 6.5 states,            FC loop (own rate) ◄───┘ (triple buffer)
//!  button, drag)        transforms + versions                │
//!                                                            ▼ composite (deep / digital / optical)
//! ```
//!
//! This crate holds the interaction side, the part every client shares:
//!
//! - [`trace`]: interaction traces — view changes, pointer rays, button presses, drags, with times
//!   in milliseconds — read from TOML or JSON-lines files (format in `docs/mfr.md`) or made by the
//!   built-in generators `grab` and `orbit`;
//! - [`state`]: the per-object selection states of Springer's Fig. 6.5 (INACTIVE → OVER →
//!   SELECTED → OVER → INACTIVE) and the rule of his Table 6.1 deciding which objects the FC draws;
//! - [`authority`]: replays a trace against a scene (ray picking against the objects' world
//!   bounding boxes, drags moving the selected object) and publishes [`authority::Snapshot`]s:
//!   view, per-object transforms with versions, states.
//!
//! - [`transfer`]: the transfer buffer the SC hands the FC (frame counter, snapshot, view, the
//!   objects rendered with their versions and the objects left out, the DeepFrame) and the
//!   wait-free triple buffer it travels through in one process.
//!
//! - [`client`], [`compose`], [`simulate`]: the clients' rendering (every fragment kept), deep
//!   composition (the SC's runs minus the objects the FC draws, merged with the FC's), and both
//!   clients on a virtual clock with naive or predictive migration.
//!
//! - [`audit`](mod@audit): a composed frame against the single renderer — bad pixels, and ghost, hole and
//!   blend pixels from the objects visible in each pixel.
//!
//! - [`timeline`]: per-frame records of a run, the latency of each input on the FC and SC paths,
//!   and each select and release with the artefacts that followed it.
//!
//! - [`realtime`]: the same clients on their own threads in real time, handing over through
//!   triple buffers; the FC never waits for the SC.
//!
//! - [`interleaved`]: both clients on one thread — each FC frame first, then the SC's frame in
//!   chunks of geometry and its export in bands of rows, sized by a fitted cost model to the time
//!   left before the FC's next deadline.
//!
//! - [`live`]: the same clients following a person's input as it comes (`strata view --mfr`):
//!   pointer positions become rays, presses select, moves drag the selected object.
//!
//! - [`tcp`]: the SC in another process or on another machine (`strata mfr-slow`), over
//!   strata-wire messages; network threads feed the same triple buffers.
//!
//! - [`lighting`], [`deferred`]: point lights moving along paths, one Blinn-Phong shader for
//!   normal fragments, and deferred shading: the SC renders a deep G-buffer, the FC lights it with
//!   the current lights (the seed's §7.1).
//! - [`warp`](mod@warp): depth-image warping — the SC's deep frame moved to the FC's current view
//!   every FC frame, holes filled, so navigation follows the FC's rate.
//!
//! Composition is deep (exact), digital (the seed's colour + depth) or optical (the FC's image
//! over the SC's, the seed's projectors), the last two kept to show their artefacts.

pub mod audit;
pub mod authority;
pub mod client;
pub mod compose;
pub mod deferred;
pub mod interleaved;
pub mod lighting;
pub mod live;
pub mod realtime;
pub mod simulate;
pub mod state;
pub mod tcp;
pub mod timeline;
pub mod trace;
pub mod transfer;
pub mod warp;
pub mod window;

pub use audit::{FrameAudit, audit};
pub use authority::{Authority, ObjectPose, Snapshot, ViewPose};
pub use compose::Composition;
pub use interleaved::{Chunking, InterleavedStats, ScFrameRecord, run_interleaved};
pub use live::{Live, ScStatus};
pub use realtime::{Incident, RealConfig, RealStats, ScLoad, ScPriority, Transport, run_real};
pub use simulate::{FcFrame, Migration, VirtualClock, run_virtual};
pub use state::{Input, ObjectState, fc_renders, table_6_1_row};
pub use timeline::{EventKind, EventLatency, EventReport, FrameRecord, Latency, events, latency};
pub use trace::{Button, Event, TimedEvent, Trace, TraceError};
pub use transfer::{Latest, Publisher, TransferBuffer, exchange};
pub use window::DeepWindow;
