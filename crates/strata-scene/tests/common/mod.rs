//! The fixture the mesh-format tests share: a square pyramid (a quad base and four triangular
//! sides), and the check that a loader produced it.

#![allow(
    dead_code,
    reason = "each test binary uses a different subset of the helpers"
)]

use strata_scene::load::Model;

/// The pyramid's vertices: the unit square at z = 0, then the apex.
pub(crate) const PYRAMID_POSITIONS: [[f32; 3]; 5] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.5, 0.5, 1.0],
];

/// The pyramid's triangles: the base quad `0 3 2 1` fanned into two, then the four sides.
pub(crate) const PYRAMID_TRIANGLES: [[u32; 3]; 6] = [
    [0, 3, 2],
    [0, 2, 1],
    [0, 1, 4],
    [1, 2, 4],
    [2, 3, 4],
    [3, 0, 4],
];

/// Asserts that `m` is the pyramid as one part named `name`, with or without file normals.
#[track_caller]
pub(crate) fn assert_pyramid(m: &Model, name: &str, normals: bool) {
    assert_eq!(m.parts.len(), 1);
    let part = &m.parts[0];
    assert_eq!(part.name, name);
    assert_eq!(part.mesh.positions(), &PYRAMID_POSITIONS);
    assert_eq!(part.mesh.triangles(), &PYRAMID_TRIANGLES);
    assert_eq!(part.mesh.has_file_normals(), normals);
}
