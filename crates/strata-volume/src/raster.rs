//! The volume scenes' objects as triangle meshes, rasterized by strata's rasterizer into a
//! linked-list A-buffer (as the multi-frame-rate clients do), every fragment's window depth made
//! into the distance along its pixel's ray: a [`FragmentLayer`] the ray caster walks.
//!
//! ```text
//! Solid / Glass ─► TriangleMesh (world space; boxes flat-faced, tubes as capsules)
//!               ─► strata-raster + LinkedListABuffer ─► DeepFrame (window depth, RGBA8)
//!               ─► ray_distance(pixel centre, depth) ─► FragmentLayer (t, colour, alpha)
//! ```
//!
//! [`ray_distance`] is the one conversion every path uses — the slow client's static fragments,
//! the fast client's interactive ones, the single renderer's all-in-one — so a fragment has the
//! same `t` wherever it is rasterized, and the stencil re-cast stays bit for bit the single
//! renderer's. It unprojects the pixel's centre (the ray's own NDC position, [`pixel_ndc`]) at
//! the fragment's window depth and measures the distance from the ray's origin along its
//! direction. Colours are the rasterizer's headlight-shaded straight RGBA8; alpha 255 is opaque.
//!
//! Only the rectangle the meshes project to is exported and converted (the fast client's path
//! covers a few percent of the image), with the whole frame as the fallback whenever a fragment
//! lies outside that guess, so no fragment is ever lost.

use glam::{Mat4, Vec3, Vec4};
use strata_core::material::{Material, Shading};
use strata_core::{ObjectId, PassTimings, PixelRect};
use strata_raster::frame::{DrawObject, FragmentOutput, FrameInput};
use strata_raster::rasterizer::Rasterizer;
use strata_stores::abuffer::linked_list::LinkedListABuffer;
use strata_stores::method::Method;
use strata_stores::{PoolCapacity, StoreError};

use crate::cast::{Ray, pixel_ndc};
use crate::fragments::{FragmentLayer, RayFragment};
use crate::geometry::{Glass, Shape, Solid};

/// Pixels added around a footprint's projected box (rounding, and the rasterizer's fill rule).
const FOOTPRINT_MARGIN: f32 = 2.0;
/// Sides of a tube's cross-section.
const TUBE_SIDES: u32 = 16;
/// Latitude rings of each of a tube's hemispherical ends.
const CAP_RINGS: u32 = 4;

/// Why the objects could not be rasterized.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RasterError {
    /// The fragment store failed (out of memory, or a frame it cannot hold).
    #[error("the fragment store failed while rasterizing the volume's objects: {0}")]
    Store(#[from] StoreError),
    /// The store exported no valid DeepFrame.
    #[error("the fragment store gave no valid deep frame: {0}")]
    DeepFrame(String),
}

/// A world-space triangle mesh with per-vertex normals and one straight RGBA colour.
#[derive(Clone, Debug, PartialEq)]
pub struct TriangleMesh {
    /// Vertex positions (world space).
    pub positions: Vec<[f32; 3]>,
    /// Vertex normals.
    pub normals: Vec<[f32; 3]>,
    /// Vertex indices, three per triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Straight RGBA; alpha 1 is opaque.
    pub color: [f32; 4],
}

impl TriangleMesh {
    /// An opaque solid's mesh.
    pub fn of_solid(solid: &Solid) -> TriangleMesh {
        let [r, g, b] = solid.color;
        tessellate(&solid.shape, [r, g, b, 1.0])
    }

    /// A translucent object's mesh.
    pub fn of_glass(glass: &Glass) -> TriangleMesh {
        let [r, g, b] = glass.color;
        tessellate(&glass.shape, [r, g, b, glass.alpha.clamp(0.0, 1.0)])
    }
}

/// The meshes of `solids` and `glass`, in that order.
pub fn meshes(solids: &[Solid], glass: &[Glass]) -> Vec<TriangleMesh> {
    solids
        .iter()
        .map(TriangleMesh::of_solid)
        .chain(glass.iter().map(TriangleMesh::of_glass))
        .collect()
}

fn tessellate(shape: &Shape, color: [f32; 4]) -> TriangleMesh {
    match *shape {
        Shape::Cuboid { min, max } => box_mesh(min, max, color),
        Shape::Tube { a, b, radius } => capsule_mesh(a, b, radius, color),
    }
}

/// An axis-aligned box, four vertices per face so the faces are flat-shaded.
fn box_mesh(min: Vec3, max: Vec3, color: [f32; 4]) -> TriangleMesh {
    let mut m = TriangleMesh {
        positions: Vec::with_capacity(24),
        normals: Vec::with_capacity(24),
        triangles: Vec::with_capacity(12),
        color,
    };
    let corner = |x: bool, y: bool, z: bool| {
        Vec3::new(
            if x { max.x } else { min.x },
            if y { max.y } else { min.y },
            if z { max.z } else { min.z },
        )
    };
    for axis in 0..3 {
        for high in [false, true] {
            let mut normal = Vec3::ZERO;
            normal[axis] = if high { 1.0 } else { -1.0 };
            let base = m.positions.len() as u32;
            for (u, v) in [(false, false), (true, false), (true, true), (false, true)] {
                let p = match axis {
                    0 => corner(high, u, v),
                    1 => corner(u, high, v),
                    _ => corner(u, v, high),
                };
                m.positions.push(p.to_array());
                m.normals.push(normal.to_array());
            }
            m.triangles.push([base, base + 1, base + 2]);
            m.triangles.push([base, base + 2, base + 3]);
        }
    }
    m
}

/// A capsule around `a`–`b`: a hemisphere at each end joined by the cylinder between them, as
/// rows of [`TUBE_SIDES`] vertices from the pole beyond `a` to the pole beyond `b`.
fn capsule_mesh(a: Vec3, b: Vec3, radius: f32, color: [f32; 4]) -> TriangleMesh {
    let axis = (b - a).normalize_or(Vec3::Y);
    let (u, v) = axis.any_orthonormal_pair();
    let mut m = TriangleMesh {
        positions: Vec::new(),
        normals: Vec::new(),
        triangles: Vec::new(),
        color,
    };
    // Latitudes from −90° to 0° around `a`, then 0° to 90° around `b`.
    let rows = (0..=CAP_RINGS)
        .map(|i| (a, -1.0 + i as f32 / CAP_RINGS as f32))
        .chain((0..=CAP_RINGS).map(|i| (b, i as f32 / CAP_RINGS as f32)));
    for (centre, lat) in rows {
        let phi = lat * std::f32::consts::FRAC_PI_2;
        for k in 0..TUBE_SIDES {
            let theta = std::f32::consts::TAU * k as f32 / TUBE_SIDES as f32;
            let n = phi.cos() * (theta.cos() * u + theta.sin() * v) + phi.sin() * axis;
            m.positions.push((centre + radius * n).to_array());
            m.normals.push(n.to_array());
        }
    }
    let row_count = 2 * (CAP_RINGS + 1);
    for r in 0..row_count - 1 {
        for k in 0..TUBE_SIDES {
            let k1 = (k + 1) % TUBE_SIDES;
            let (p, q) = (r * TUBE_SIDES, (r + 1) * TUBE_SIDES);
            m.triangles.push([p + k, p + k1, q + k1]);
            m.triangles.push([p + k, q + k1, q + k]);
        }
    }
    m
}

/// Where pixel `(px, py)`'s ray meets the surface at window depth `depth`: the distance along
/// `ray` (unit direction) of the pixel centre unprojected through `inverse_view_proj`. Every path
/// turns depths into distances with this function.
pub fn ray_distance(inverse_view_proj: &Mat4, ray: &Ray, ndc: (f32, f32), depth: f32) -> f32 {
    let p = *inverse_view_proj * Vec4::new(ndc.0, ndc.1, 2.0 * depth - 1.0, 1.0);
    (p.truncate() / p.w - ray.origin).dot(ray.dir)
}

/// A rasterizer and a linked-list A-buffer for one image size and camera, reused frame to frame.
pub struct FragmentRaster {
    raster: Rasterizer,
    store: LinkedListABuffer,
    width: u32,
    height: u32,
    view: Mat4,
    projection: Mat4,
    inverse_view_proj: Mat4,
}

impl FragmentRaster {
    /// A `width` × `height` rasterizer seeing through `view` and `projection` (their product
    /// is the view-projection the rays were made from).
    pub fn new(width: u32, height: u32, view: Mat4, projection: Mat4) -> FragmentRaster {
        FragmentRaster {
            raster: Rasterizer::default(),
            store: LinkedListABuffer::new(PoolCapacity::Auto),
            width,
            height,
            view,
            projection,
            inverse_view_proj: (projection * view).inverse(),
        }
    }

    /// Rasterizes `meshes` and turns every fragment into a [`RayFragment`] on its pixel's ray
    /// (`rays` row by row, one per pixel).
    pub fn layer(
        &mut self,
        rays: &[Ray],
        meshes: &[TriangleMesh],
    ) -> Result<FragmentLayer, RasterError> {
        let objects = meshes
            .iter()
            .enumerate()
            .map(|(i, m)| DrawObject {
                positions: &m.positions,
                normals: &m.normals,
                triangles: &m.triangles,
                model: Mat4::IDENTITY,
                material: Material {
                    color: m.color,
                    shading: Shading::Headlight,
                },
                id: ObjectId(u32::try_from(i).unwrap_or(u32::MAX)),
            })
            .collect();
        let input = FrameInput {
            width: self.width,
            height: self.height,
            view: self.view,
            projection: self.projection,
            background: [0.0; 3],
            objects,
            output: FragmentOutput::Shaded,
        };
        self.store.clear(self.width, self.height)?;
        self.store
            .capture(&mut self.raster, &input, &mut PassTimings::new())?;
        let full = PixelRect::full(self.width, self.height);
        let guess = footprint(
            &(self.projection * self.view),
            meshes,
            self.width,
            self.height,
        );
        // The footprint's fragments, or the whole frame's when some fragment lies outside it.
        let (rect, frame) = match guess.and_then(|r| self.store.deep_frame_in(r).map(|f| (r, f))) {
            Some((rect, frame)) => (rect, frame),
            None => match self.store.deep_frame_in(full) {
                Some(frame) => (full, frame),
                None => {
                    return Err(RasterError::DeepFrame(
                        "the store holds fragments outside the frame".into(),
                    ));
                }
            },
        };
        let frame = frame.map_err(|e| RasterError::DeepFrame(e.to_string()))?;
        let (w, h) = (self.width, self.height);
        let inverse = self.inverse_view_proj;
        Ok(FragmentLayer::from_window(
            w as usize * h as usize,
            w,
            rect.x..rect.x + rect.width,
            rect.y..rect.y + rect.height,
            |p, out| {
                let Some(ray) = rays.get(p) else {
                    return;
                };
                let (px, py) = (p as u32 % w, p as u32 / w);
                let q = (py - rect.y) as usize * rect.width as usize + (px - rect.x) as usize;
                let ndc = pixel_ndc(px, py, w, h);
                out.extend(frame.run(q).iter().map(|f| {
                    let [r, g, b, alpha] = f.color.to_unorm();
                    RayFragment {
                        t: ray_distance(&inverse, ray, ndc, f.depth),
                        color: [r, g, b],
                        alpha,
                    }
                }));
            },
        ))
    }
}

/// The pixel rectangle the meshes' vertices project to, with a margin; `None` when a vertex
/// lies behind the eye (its projection is unbounded) or nothing is drawn there.
fn footprint(
    view_proj: &Mat4,
    meshes: &[TriangleMesh],
    width: u32,
    height: u32,
) -> Option<PixelRect> {
    let points = meshes
        .iter()
        .flat_map(|m| &m.positions)
        .map(|p| (*view_proj * Vec3::from(*p).extend(1.0)).to_array());
    PixelRect::around_clip_points(points, width, height, FOOTPRINT_MARGIN)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_capsule_mesh_lies_on_the_capsule() {
        let (a, b, r) = (Vec3::new(-0.3, 0.1, 0.0), Vec3::new(0.4, 0.2, 0.3), 0.05);
        let m = capsule_mesh(a, b, r, [1.0; 4]);
        assert_eq!(
            m.triangles.len() as u32,
            2 * TUBE_SIDES * (2 * CAP_RINGS + 1)
        );
        for p in &m.positions {
            let p = Vec3::from(*p);
            let s = ((p - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
            let d = (p - (a + s * (b - a))).length();
            assert!((d - r).abs() < 1e-5, "{p} is {d} from the axis");
        }
        assert!(
            m.triangles
                .iter()
                .flatten()
                .all(|&i| (i as usize) < m.positions.len())
        );
    }
}
