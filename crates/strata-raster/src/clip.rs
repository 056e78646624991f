//! Exact clipping in homogeneous clip space against the near plane and the guard band.
//!
//! Only triangles with a vertex in front of the near plane or outside the guard band come here
//! (a small minority); all others are projected directly. The triangle is clipped as a polygon
//! (Sutherland–Hodgman) against the five planes, each as a half-space `d(v) ≥ 0`:
//!
//! ```text
//! near:        z + w ≥ 0              (GL: z_ndc ≥ -1)
//! guard left:  x + g_x·w ≥ 0          guard right:  g_x·w − x ≥ 0
//! guard bottom: y + g_y·w ≥ 0         guard top:    g_y·w − y ≥ 0
//! ```
//!
//! Clip-space position, eye-space position and eye-space normal are all affine in object space,
//! so interpolating them linearly along an edge is exact. Each intersection is computed from the
//! inside endpoint towards the outside one, so two triangles sharing a clipped edge compute the
//! bit-identical new vertex. The result (at most 8 vertices) is fanned into triangles. The far
//! plane is not clipped: fragments beyond it are discarded one by one, which selects the same
//! samples because depth is affine in screen space.

use glam::{Vec3, Vec4};

/// A vertex during clipping.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClipVertex {
    /// Clip-space position.
    pub c: Vec4,
    /// Eye-space position.
    pub p: Vec3,
    /// Eye-space normal.
    pub n: Vec3,
}

impl ClipVertex {
    fn lerp(self, other: ClipVertex, t: f32) -> ClipVertex {
        ClipVertex {
            c: self.c + (other.c - self.c) * t,
            p: self.p + (other.p - self.p) * t,
            n: self.n + (other.n - self.n) * t,
        }
    }
}

/// Most vertices a triangle can have after clipping against five planes.
pub const MAX_CLIPPED: usize = 8;

/// A clipped polygon, stored inline.
#[derive(Clone, Copy, Debug)]
pub struct Polygon {
    verts: [ClipVertex; MAX_CLIPPED],
    len: usize,
}

impl Polygon {
    /// The triangle as a polygon.
    pub fn triangle(v: [ClipVertex; 3]) -> Self {
        let mut verts = [ClipVertex::default(); MAX_CLIPPED];
        verts[..3].copy_from_slice(&v);
        Polygon { verts, len: 3 }
    }

    /// The vertices.
    pub fn vertices(&self) -> &[ClipVertex] {
        &self.verts[..self.len]
    }

    /// Clips against `d(v) ≥ 0`.
    fn clip(&self, d: impl Fn(&ClipVertex) -> f32) -> Polygon {
        let mut out = Polygon {
            verts: [ClipVertex::default(); MAX_CLIPPED],
            len: 0,
        };
        let n = self.len;
        for i in 0..n {
            let (a, b) = (self.verts[i], self.verts[(i + 1) % n]);
            let (da, db) = (d(&a), d(&b));
            let (a_in, b_in) = (da >= 0.0, db >= 0.0);
            if a_in {
                out.push(a);
            }
            if a_in != b_in {
                // From the inside endpoint towards the outside one: symmetric for shared edges.
                let (inside, outside, di, dout) =
                    if a_in { (a, b, da, db) } else { (b, a, db, da) };
                let t = di / (di - dout);
                out.push(inside.lerp(outside, t));
            }
        }
        out
    }

    fn push(&mut self, v: ClipVertex) {
        // Clipping a convex polygon against one plane adds at most one vertex; three vertices
        // and five planes cannot exceed MAX_CLIPPED.
        if self.len < MAX_CLIPPED {
            self.verts[self.len] = v;
            self.len += 1;
        }
    }

    /// Clips against the near plane and the guard band `guard = [g_x, g_y]` (NDC units).
    pub fn clip_near_and_guard(&self, guard: [f32; 2]) -> Polygon {
        let [gx, gy] = guard;
        self.clip(|v| v.c.z + v.c.w)
            .clip(|v| v.c.x + gx * v.c.w)
            .clip(|v| gx * v.c.w - v.c.x)
            .clip(|v| v.c.y + gy * v.c.w)
            .clip(|v| gy * v.c.w - v.c.y)
    }

    /// The polygon as a triangle fan `(0, i, i + 1)`.
    pub fn fan(&self) -> impl Iterator<Item = [ClipVertex; 3]> + '_ {
        (1..self.len.saturating_sub(1))
            .map(move |i| [self.verts[0], self.verts[i], self.verts[i + 1]])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32, y: f32, z: f32, w: f32) -> ClipVertex {
        ClipVertex {
            c: Vec4::new(x, y, z, w),
            p: Vec3::new(x, y, -w),
            n: Vec3::Z,
        }
    }

    #[test]
    fn triangle_inside_is_untouched() {
        let t = [
            v(0.0, 0.0, 0.0, 1.0),
            v(0.5, 0.0, 0.0, 1.0),
            v(0.0, 0.5, 0.0, 1.0),
        ];
        let p = Polygon::triangle(t).clip_near_and_guard([10.0, 10.0]);
        assert_eq!(p.vertices(), &t);
        assert_eq!(p.fan().count(), 1);
    }

    #[test]
    fn one_vertex_behind_the_near_plane_gives_a_quad_on_the_plane() {
        // Vertex 0 has z + w = -1 (outside), the others +1.
        let t = [
            v(0.0, 0.0, -2.0, 1.0),
            v(1.0, 0.0, 0.0, 1.0),
            v(0.0, 1.0, 0.0, 1.0),
        ];
        let p = Polygon::triangle(t).clip_near_and_guard([10.0, 10.0]);
        assert_eq!(p.vertices().len(), 4);
        assert_eq!(p.fan().count(), 2);
        for q in p.vertices() {
            assert!(q.c.z + q.c.w >= -1e-6, "{q:?} in front of the near plane");
        }
        // The new vertices are the edge midpoints (d = -1 and +1).
        assert!(
            p.vertices()
                .iter()
                .any(|q| (q.c - Vec4::new(0.5, 0.0, -1.0, 1.0)).length() < 1e-6)
        );
    }

    #[test]
    fn two_vertices_behind_give_a_smaller_triangle() {
        let t = [
            v(0.0, 0.0, 0.0, 1.0),
            v(1.0, 0.0, -3.0, 1.0),
            v(0.0, 1.0, -3.0, 1.0),
        ];
        let p = Polygon::triangle(t).clip_near_and_guard([10.0, 10.0]);
        assert_eq!(p.vertices().len(), 3);
    }

    #[test]
    fn entirely_behind_vanishes() {
        let t = [
            v(0.0, 0.0, -2.0, 1.0),
            v(1.0, 0.0, -3.0, 1.0),
            v(0.0, 1.0, -3.0, 1.0),
        ];
        let p = Polygon::triangle(t).clip_near_and_guard([10.0, 10.0]);
        assert_eq!(p.fan().count(), 0);
    }

    #[test]
    fn shared_edge_clips_to_the_same_point_from_both_sides() {
        let (a, b) = (v(0.3, 0.1, -2.5, 1.0), v(0.7, -0.2, 0.4, 1.0));
        let t1 = Polygon::triangle([a, b, v(0.0, 1.0, 0.0, 1.0)]).clip_near_and_guard([10.0, 10.0]);
        let t2 = Polygon::triangle([b, a, v(1.0, 1.0, 0.0, 1.0)]).clip_near_and_guard([10.0, 10.0]);
        let on_plane = |p: &Polygon| {
            p.vertices()
                .iter()
                .copied()
                .filter(|q| q.c.z + q.c.w == 0.0 || (q.c.z + q.c.w).abs() < 1e-7)
                .collect::<Vec<_>>()
        };
        let s1 = on_plane(&t1);
        let s2 = on_plane(&t2);
        assert!(s1.iter().any(|q| s2.contains(q)), "{s1:?} vs {s2:?}");
    }

    #[test]
    fn guard_band_bounds_the_result() {
        let t = [
            v(-1e6, 0.0, 0.0, 1.0),
            v(1e6, 0.0, 0.0, 1.0),
            v(0.0, 1e6, 0.0, 1.0),
        ];
        let p = Polygon::triangle(t).clip_near_and_guard([100.0, 50.0]);
        assert!(p.fan().count() >= 1);
        for q in p.vertices() {
            assert!(q.c.x.abs() <= 100.0 * q.c.w * 1.0001 && q.c.y.abs() <= 50.0 * q.c.w * 1.0001);
        }
    }
}
