//! Mesh loaders (being written).
