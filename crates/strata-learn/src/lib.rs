//! strata-learn: the data side of a learned variable k-buffer (Tsopouridis 2021 ch. 4–5).
//!
//! | module | what |
//! | --- | --- |
//! | [`procedural`] | a seeded generator of translucent and opaque scenes, 2 to 40 layers deep |
//! | [`dataset`] | per-pixel features labelled by the Optimal-K oracle over views and budgets, written as `.npy` |
//! | [`train`] | a reproducible trainer for the learned importance network |
//!
//! The features themselves are gathered by the variable k-buffer's counting pass
//! ([`strata_stores::kbuffer::features`]); this crate renders, labels, samples and writes them.
//! Training and inference build on the files described in [`dataset`].

pub mod dataset;
pub mod procedural;
pub mod train;

pub use dataset::{Dataset, DatasetError, DatasetSpec, LABELS};
pub use procedural::{ProceduralScene, generate};
