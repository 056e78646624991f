//! strata's fragment stores: every multi-fragment method behind one [`Method`] trait.
//!
//! A method is a module with the same shape as its siblings — the habit of nvpro's OIT sample,
//! so a diff between two methods shows only what differs between the algorithms:
//!
//! ```text
//! clear    reset the per-pixel state for a width × height frame
//! capture  drive the rasterizer (one or more passes) and store fragments
//! resolve  sort and composite each pixel onto the background
//! ```
//!
//! plus its real buffer sizes ([`Method::memory_bytes`]) and, for exact methods, a
//! [`strata_core::DeepFrame`] export. [`render_frame`] runs the passes in order and times each
//! one; [`create`] builds a method from its name. Adding a method touches its own module and one
//! line of [`METHODS`].
//!
//! | name | module | seed |
//! | --- | --- | --- |
//! | `abuffer` | [`abuffer::linked_list`] | 000 §2, 001 Alg. 4–6 |
//! | `tfss` | [`tfss`] (and its memory/access model, [`tfss::model`]) | 002 ch. 3–4 |

pub mod abuffer;
mod alloc;
pub mod count;
pub mod method;
pub mod options;
pub mod regions;
pub mod registry;
pub mod tfss;

pub use method::{CaptureReport, FrameResult, Method, StoreError, render_frame};
pub use options::{Budget, ImportanceParams, KFrom, MethodOptions, PoolCapacity};
pub use registry::{METHODS, UnknownMethod, create};
