//! Runnable examples of strata used as a library (this package has no API of its own).
//!
//! - `deep_exr`: load a built-in scene, render it with a fragment store, take the DeepFrame,
//!   write it as an OpenEXR deep image, read it back, and resolve it to a PNG:
//!   `cargo run --release -p strata-examples --example deep_exr -- OUT_DIR`.
