//! strata's shared data model: the fragment, the DeepFrame, OVER compositing, images and metrics.
//!
//! Every other strata crate speaks these types. The pipeline (the pipeline design) is
//!
//! ```text
//! scene ─► rasterizer ─► fragment store ─► DeepFrame ─► resolve / encode / merge / compose
//! ```
//!
//! and this crate owns the plain data that flows between the stages:
//!
//! - [`Fragment`]: depth, straight-alpha RGBA8 and the id of the object that made it — the
//!   12-byte colour node of Jähne 2014 §2.1 plus the object id;
//! - [`DeepFrame`]: every pixel's fragments as one sorted run, in one contiguous layout
//!   (`offsets[w*h+1]` + fragment columns) — the exchange format of the whole engine;
//! - [`composite`]: the OVER operator (Jähne 2014 eq. 1.1) applied front to back, shared by every
//!   resolve so that exact methods agree to the bit;
//! - [`Rgb8Image`], [`metrics`] (RMSE, bad pixels) and [`DepthStats`] (depth complexity);
//! - [`PassTimings`]: per-pass wall-clock times, in the order the passes ran.
//!
//! The worked example of Jähne 2014 §1 — half-transparent red over half-transparent blue over white:
//!
//! ```
//! use strata_core::composite::over_front_to_back_f32;
//! let red = [1.0, 0.0, 0.0, 0.5];
//! let blue = [0.0, 0.0, 1.0, 0.5];
//! let out = over_front_to_back_f32([red, blue], [1.0, 1.0, 1.0]);
//! assert_eq!(out, [0.75, 0.25, 0.5]);
//! ```

pub mod composite;
pub mod deep_frame;
pub mod fragment;
pub mod image;
pub mod material;
pub mod metrics;
pub mod normal;
pub mod npy;
pub mod rect;
pub mod rgba_image;
pub mod run_limit;
pub mod stats;
pub mod timings;

pub use deep_frame::{DeepFrame, DeepFrameError, FillBand, GatherWriter, GatheredPixels, Run};
pub use fragment::{Fragment, ObjectId, Rgba8};
pub use image::{ImageError, Rgb8Image};
pub use material::{Material, Shading};
pub use normal::PackedNormal;
pub use rect::PixelRect;
pub use rgba_image::{PngAlpha, PngDepth, RgbaF32Image};
pub use run_limit::RunLimit;
pub use stats::DepthStats;
pub use timings::PassTimings;
