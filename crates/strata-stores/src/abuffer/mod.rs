//! A-buffers: stores that keep every fragment of every pixel (seed 001 §3.1).

pub mod fixed_array;
pub mod linked_list;
pub mod sbuffer;
