//! A-buffers: stores that keep every fragment of every pixel (seed 001 §3.1).

pub mod linked_list;
