//! Built-in shapes, usable as `builtin = "<name>"` objects: tessellated analytically, with exact
//! normals, each centred on the origin with its largest extent 1.
//!
//! | name     | shape                                                         | triangles |
//! | -------- | ------------------------------------------------------------- | --------- |
//! | `quad`   | unit square in the xy plane, facing +z                          | 2         |
//! | `cube`   | unit cube, flat faces                                           | 12        |
//! | `slab`   | 1 × 1 × 0.08 box (a thick pane: two fragments per covered pixel) | 12        |
//! | `sphere` | UV sphere of radius 0.5, 64 segments × 32 rings                  | 3 968     |
//! | `torus`  | ring radius 0.35, tube radius 0.15, axis +z, 96 × 32             | 6 144     |
//! | `grid`   | unit square in the xy plane as 64 × 64 quads sharing vertices    | 8 192     |

use std::f32::consts::{PI, TAU};

use crate::mesh::Mesh;

/// The names accepted by [`shape`].
pub const SHAPE_NAMES: &[&str] = &["quad", "cube", "slab", "sphere", "torus", "grid"];

/// The built-in shape called `name`, or `None`.
pub fn shape(name: &str) -> Option<Mesh> {
    Some(match name {
        "quad" => grid(1, 1),
        "cube" => cuboid([0.5, 0.5, 0.5]),
        "slab" => cuboid([0.5, 0.5, 0.04]),
        "sphere" => sphere(0.5, 64, 32),
        "torus" => torus(0.35, 0.15, 96, 32),
        "grid" => grid(64, 64),
        _ => return None,
    })
}

fn build(positions: Vec<[f32; 3]>, normals: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Mesh {
    // The generators below only produce in-range indices and finite values.
    Mesh::new(positions, Some(normals), triangles).expect("built-in shapes are valid meshes")
}

/// `nx` × `ny` quads covering `[-0.5, 0.5]²` at z = 0, normal +z, vertices shared.
pub fn grid(nx: u32, ny: u32) -> Mesh {
    let mut positions = Vec::new();
    for j in 0..=ny {
        for i in 0..=nx {
            positions.push([i as f32 / nx as f32 - 0.5, j as f32 / ny as f32 - 0.5, 0.0]);
        }
    }
    let normals = vec![[0.0, 0.0, 1.0]; positions.len()];
    let mut triangles = Vec::new();
    let row = nx + 1;
    for j in 0..ny {
        for i in 0..nx {
            let a = j * row + i;
            let (b, c, d) = (a + 1, a + row + 1, a + row);
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    build(positions, normals, triangles)
}

/// An axis-aligned box with half extents `h`, four vertices per face for flat normals.
fn cuboid(h: [f32; 3]) -> Mesh {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut triangles = Vec::new();
    for axis in 0..3 {
        for sign in [1.0f32, -1.0] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = positions.len() as u32;
            let mut n = [0.0; 3];
            n[axis] = sign;
            for (su, sv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let mut p = [0.0; 3];
                p[axis] = sign * h[axis];
                p[u] = su * h[u];
                p[v] = sv * h[v];
                positions.push(p);
                normals.push(n);
            }
            // Wind counter-clockwise seen from outside (not needed without culling, but tidy).
            if sign > 0.0 {
                triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
            } else {
                triangles.extend([[base, base + 2, base + 1], [base, base + 3, base + 2]]);
            }
        }
    }
    build(positions, normals, triangles)
}

/// A UV sphere: `segments` around the y axis, `rings` from pole to pole, one vertex per pole.
fn sphere(radius: f32, segments: u32, rings: u32) -> Mesh {
    let mut positions = vec![[0.0, radius, 0.0]];
    let mut normals = vec![[0.0, 1.0, 0.0]];
    for r in 1..rings {
        let phi = PI * r as f32 / rings as f32;
        for s in 0..segments {
            let theta = TAU * s as f32 / segments as f32;
            let n = [phi.sin() * theta.cos(), phi.cos(), -phi.sin() * theta.sin()];
            positions.push(n.map(|c| c * radius));
            normals.push(n);
        }
    }
    positions.push([0.0, -radius, 0.0]);
    normals.push([0.0, -1.0, 0.0]);
    let south = positions.len() as u32 - 1;
    let ring = |r: u32, s: u32| 1 + (r - 1) * segments + s % segments;
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        triangles.push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b) = (ring(r, s), ring(r, s + 1));
            let (c, d) = (ring(r + 1, s + 1), ring(r + 1, s));
            triangles.push([a, d, c]);
            triangles.push([a, c, b]);
        }
    }
    build(positions, normals, triangles)
}

/// A torus around the z axis: `major` segments along the ring, `minor` around the tube.
fn torus(ring_radius: f32, tube_radius: f32, major: u32, minor: u32) -> Mesh {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for i in 0..major {
        let u = TAU * i as f32 / major as f32;
        for j in 0..minor {
            let v = TAU * j as f32 / minor as f32;
            let n = [v.cos() * u.cos(), v.cos() * u.sin(), v.sin()];
            let r = ring_radius + tube_radius * v.cos();
            positions.push([r * u.cos(), r * u.sin(), tube_radius * v.sin()]);
            normals.push(n);
        }
    }
    let idx = |i: u32, j: u32| (i % major) * minor + j % minor;
    let mut triangles = Vec::new();
    for i in 0..major {
        for j in 0..minor {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    build(positions, normals, triangles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn every_shape_is_centred_with_unit_largest_extent() {
        for name in SHAPE_NAMES {
            let m = shape(name).unwrap();
            let b = m.bounds();
            assert!(b.center().length() < 1e-5, "{name}: centre {}", b.center());
            assert!(
                (b.extent().max_element() - 1.0).abs() < 1e-5,
                "{name}: extent {}",
                b.extent()
            );
        }
        assert!(shape("teapot").is_none());
    }

    #[test]
    fn triangle_counts_match_the_table() {
        let counts: Vec<usize> = SHAPE_NAMES
            .iter()
            .map(|n| shape(n).unwrap().triangles().len())
            .collect();
        assert_eq!(counts, [2, 12, 12, 3968, 6144, 8192]);
    }

    #[test]
    fn normals_are_unit_and_point_outwards() {
        for name in ["cube", "slab", "sphere"] {
            let m = shape(name).unwrap();
            for (p, n) in m.positions().iter().zip(m.normals()) {
                let (p, n) = (Vec3::from(*p), Vec3::from(*n));
                assert!((n.length() - 1.0).abs() < 1e-5);
                assert!(p.dot(n) > 0.0, "{name}: inward normal at {p}");
            }
        }
        // Torus normals point away from the ring's centre line.
        let m = shape("torus").unwrap();
        for (p, n) in m.positions().iter().zip(m.normals()) {
            let p = Vec3::from(*p);
            let on_ring = Vec3::new(p.x, p.y, 0.0).normalize() * 0.35;
            let out = (p - on_ring).normalize();
            assert!(out.dot(Vec3::from(*n)) > 0.999);
        }
    }

    #[test]
    fn closed_shapes_have_every_edge_shared_by_two_triangles() {
        use std::collections::HashMap;
        for name in ["sphere", "torus"] {
            let m = shape(name).unwrap();
            let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
            for t in m.triangles() {
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    *edges.entry((a.min(b), a.max(b))).or_default() += 1;
                }
            }
            assert!(edges.values().all(|&c| c == 2), "{name} is not closed");
        }
    }
}
