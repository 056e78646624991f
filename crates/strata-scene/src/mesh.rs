//! Indexed triangle meshes: the geometry every loader and built-in shape produces.
//!
//! Layout (plain arrays, as the rasterizer's vertex stage reads them):
//!
//! ```text
//! positions: [[f32; 3]; v]     object-space positions
//! normals:   [[f32; 3]; v]     per-vertex normals (from the file, or computed; see below)
//! triangles: [[u32; 3]; t]     vertex indices, every index < v
//! ```
//!
//! Normals come from the file where it has them. Otherwise each vertex normal is the normalised
//! sum of the *unnormalised* normals (cross products, so area-weighted) of the faces that use it
//! (DESIGN §2). A vertex used by no face, or only by degenerate faces, gets a zero normal; the
//! headlight shading treats that as `N·L = 0`.

use glam::Vec3;

/// Why a set of arrays is not a valid mesh.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// A triangle refers to a vertex that does not exist.
    #[error("triangle {triangle} refers to vertex {index}, but there are only {vertices} vertices")]
    IndexOutOfRange {
        /// Triangle number.
        triangle: usize,
        /// The bad index.
        index: u32,
        /// Number of vertices.
        vertices: usize,
    },
    /// A position is NaN or infinite.
    #[error("vertex {vertex} has a non-finite coordinate {value}")]
    NonFinite {
        /// Vertex number.
        vertex: usize,
        /// The bad value.
        value: f32,
    },
    /// Normals were given but not one per vertex.
    #[error("{normals} normals given for {vertices} vertices")]
    NormalCount {
        /// Normals given.
        normals: usize,
        /// Vertices.
        vertices: usize,
    },
    /// More vertices than a `u32` index can address.
    #[error("{0} vertices exceed the limit of 2^32")]
    TooManyVertices(usize),
}

/// An axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (min = +inf, max = -inf), the identity of [`Aabb::union`].
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// True if no point was added.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }

    /// Grows the box to contain `p`.
    pub fn include(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// The smallest box containing both.
    pub fn union(self, other: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// Centre of the box.
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Edge lengths.
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }
}

/// A validated indexed triangle mesh with per-vertex normals; see the module docs.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    file_normals: bool,
}

impl Mesh {
    /// Validates the arrays and, when `normals` is `None`, computes area-weighted vertex normals.
    pub fn new(
        positions: Vec<[f32; 3]>,
        normals: Option<Vec<[f32; 3]>>,
        triangles: Vec<[u32; 3]>,
    ) -> Result<Self, MeshError> {
        let v = positions.len();
        if u32::try_from(v).is_err() {
            return Err(MeshError::TooManyVertices(v));
        }
        for (vertex, p) in positions.iter().enumerate() {
            if let Some(&value) = p.iter().find(|c| !c.is_finite()) {
                return Err(MeshError::NonFinite { vertex, value });
            }
        }
        for (triangle, t) in triangles.iter().enumerate() {
            if let Some(&index) = t.iter().find(|&&i| i as usize >= v) {
                return Err(MeshError::IndexOutOfRange {
                    triangle,
                    index,
                    vertices: v,
                });
            }
        }
        let file_normals = normals.is_some();
        let normals = match normals {
            Some(n) if n.len() != v => {
                return Err(MeshError::NormalCount {
                    normals: n.len(),
                    vertices: v,
                });
            }
            Some(n) => n
                .into_iter()
                .map(|n| {
                    if n.iter().all(|c| c.is_finite()) {
                        n
                    } else {
                        [0.0; 3]
                    }
                })
                .collect(),
            None => area_weighted_normals(&positions, &triangles),
        };
        Ok(Mesh {
            positions,
            normals,
            triangles,
            file_normals,
        })
    }

    /// Object-space positions.
    pub fn positions(&self) -> &[[f32; 3]] {
        &self.positions
    }

    /// Per-vertex normals, one per position.
    pub fn normals(&self) -> &[[f32; 3]] {
        &self.normals
    }

    /// Triangles as vertex-index triples.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// True if the normals came from the file rather than being computed.
    pub fn has_file_normals(&self) -> bool {
        self.file_normals
    }

    /// Bounding box of the positions.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for p in &self.positions {
            b.include(Vec3::from(*p));
        }
        b
    }

    /// The same mesh with its triangles listed in another order (`order[i]` is the old index of
    /// new triangle `i`). Used to show that results do not depend on draw order.
    ///
    /// # Panics
    /// If `order` is not a permutation of the triangle indices.
    pub fn reorder_triangles(&self, order: &[usize]) -> Mesh {
        assert_eq!(order.len(), self.triangles.len(), "not a permutation");
        let mut seen = vec![false; order.len()];
        for &i in order {
            assert!(!std::mem::replace(&mut seen[i], true), "not a permutation");
        }
        Mesh {
            triangles: order.iter().map(|&i| self.triangles[i]).collect(),
            ..self.clone()
        }
    }
}

/// Normalised sum of the unnormalised face normals around each vertex.
fn area_weighted_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut sum = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| Vec3::from(positions[i as usize]));
        let n = (b - a).cross(c - a);
        for &i in t {
            sum[i as usize] += n;
        }
    }
    sum.into_iter()
        .map(|n| n.normalize_or_zero().to_array())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> Mesh {
        Mesh::new(
            vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            None,
            vec![[0, 1, 2], [0, 2, 3]],
        )
        .unwrap()
    }

    #[test]
    fn computed_normals_are_area_weighted_face_normals() {
        let m = quad();
        assert!(!m.has_file_normals());
        for n in m.normals() {
            assert_eq!(*n, [0.0, 0.0, 1.0]);
        }
        // A vertex shared by a big and a small face leans towards the big one.
        let m = Mesh::new(
            vec![
                [0.0; 3],
                [10.0, 0.0, 0.0],
                [0.0, 10.0, 0.0],
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
            ],
            None,
            vec![[0, 1, 2], [0, 3, 4]],
        )
        .unwrap();
        let n = Vec3::from(m.normals()[0]);
        assert!(n.z > 0.99 && (n.length() - 1.0).abs() < 1e-6, "{n}");
    }

    #[test]
    fn invalid_meshes_are_rejected() {
        assert_eq!(
            Mesh::new(vec![[0.0; 3]], None, vec![[0, 0, 1]]),
            Err(MeshError::IndexOutOfRange {
                triangle: 0,
                index: 1,
                vertices: 1
            })
        );
        assert!(matches!(
            Mesh::new(vec![[0.0, f32::NAN, 0.0]], None, vec![]),
            Err(MeshError::NonFinite { vertex: 0, .. })
        ));
        assert!(matches!(
            Mesh::new(vec![[0.0; 3]], Some(vec![]), vec![]),
            Err(MeshError::NormalCount { .. })
        ));
    }

    #[test]
    fn bounds_and_reorder() {
        let m = quad();
        let b = m.bounds();
        assert_eq!((b.min, b.max), (Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0)));
        let r = m.reorder_triangles(&[1, 0]);
        assert_eq!(r.triangles(), &[[0, 2, 3], [0, 1, 2]]);
    }
}
