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
//! | `abuffer-array` | [`abuffer::fixed_array`] | 001 §3.1.1, Alg. 1–3 |
//! | `sbuffer` | [`abuffer::sbuffer`] | 001 §3.1.3, Alg. 7–12 |
//! | `wf` | [`wf`] | 002 §2.5.2, Eq. 2–4 |
//! | `kbuffer` | [`kbuffer::fixed`] | 001 §3.2.1, Alg. 13–15 |
//! | `vkbuffer` | [`kbuffer::variable`] | 001 §3.2.2, Alg. 16–21; §4.2.2, Alg. 23 |
//! | `tfss` | [`tfss`] (and its memory/access model, [`tfss::model`]) | 002 ch. 3–4 |
//! | `depth-peeling` | [`baselines::depth_peeling`] | Everitt 2001 (001 §1.1) |
//! | `dual-depth-peeling` | [`baselines::dual_depth_peeling`] | Bavoil & Myers 2008 (000 §1.1) |
//! | `wboit` | [`baselines::wboit`] | McGuire & Bavoil 2013 |

pub mod abuffer;
mod alloc;
pub mod baselines;
pub mod count;
pub mod kbuffer;
pub mod method;
pub mod options;
pub mod regions;
pub mod registry;
mod resolve;
mod strip_export;
pub mod tfss;
pub mod wf;

pub use method::{
    CaptureReport, ExportError, ExportResult, FrameResult, Method, PixelMap, StoreError,
    check_exports, export_frame, render_frame,
};
pub use options::{
    BadValue, Budget, ImportanceParams, KFrom, MethodOptions, OptionError, PoolCapacity,
};
pub use registry::{
    CheckError, Fidelity, METHODS, MethodInfo, OptionNotTaken, UnknownMethod, check_option, create,
    exact_methods, find, methods_taking,
};
