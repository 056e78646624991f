//! k-buffers: stores that keep the k nearest fragments of each pixel (Tsopouridis 2021 §3.2).
//!
//! | module | what | seed |
//! | --- | --- | --- |
//! | [`fixed`] | `kbuffer`: one k for every pixel, optional tail blend | 001 §3.2.1, Alg. 13–15 |
//! | [`variable`] | `vkbuffer`: k(p) under a budget, from importance maps or Optimal-K | 001 §3.2.2, Alg. 16–21; §4.2.2, Alg. 23 |
//! | [`importance`] | the periphery and depth-complexity heuristics with noise | 001 §3.2.2 |
//! | [`allocate`] | k(p) from the importance map under the budget | 001 Alg. 17 |
//! | [`analytic`] | k(p) by water-filling an analytic error model (no learning) | — |
//! | [`optimal_k`](mod@optimal_k) | the greedy Optimal-K oracle | 001 §4.2.2, Alg. 23 |
//! | [`features`] | per-pixel features for a learned k, gathered in the counting pass | 001 §4.2 |
//! | [`learned`] | a small network over those features, its weights file (`--k-from learned`) | 001 ch. 4 |
//! | [`inference`] | the network in the frame's importance pass, a block of pixels at a time | 001 ch. 4 |
//! | [`fast_math`] | branch-free `f32` logarithms and exponentials for the lane-wise code | — |
//! | [`maps`] | k and importance maps as heat-map images | 001 Fig. 3.9 |

pub mod allocate;
pub mod analytic;
pub mod fast_math;
pub mod features;
pub mod fixed;
pub mod importance;
pub mod inference;
pub mod learned;
pub mod maps;
pub mod optimal_k;
pub mod variable;

pub use allocate::{Allocation, allocate_k};
pub use features::{FEATURE_SET, FEATURES, FeatureMaps};
pub use fixed::KBuffer;
pub use learned::{LearnedModel, WeightsError};
pub use optimal_k::{SortedRuns, optimal_k};
pub use variable::VariableKBuffer;
