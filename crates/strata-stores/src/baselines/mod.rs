//! The methods people use instead of storing fragments: multi-pass peeling and single-pass
//! weighted blending.
//!
//! | name | module | source |
//! | --- | --- | --- |
//! | `depth-peeling` | [`depth_peeling`] | Everitt 2001 (Tsopouridis 2021 §1.1, Jähne 2014 §1.1) |
//! | `dual-depth-peeling` | [`dual_depth_peeling`] | Bavoil & Myers 2008, as VTK's `vtkDualDepthPeelingPass` |
//! | `wboit` | [`wboit`] | McGuire & Bavoil 2013 (JCGT 2(2)) |
//!
//! The peeling methods are exact given enough passes (and hand out a DeepFrame); weighted blended
//! OIT is an approximation and keeps no fragments.

pub mod depth_peeling;
pub mod dual_depth_peeling;
mod peeled;
pub mod wboit;
