//! A-buffers: stores that keep every fragment of every pixel (Tsopouridis 2021 §3.1).

pub mod fixed_array;
pub mod linked_list;
pub mod sbuffer;
