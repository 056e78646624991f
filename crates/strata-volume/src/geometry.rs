//! Opaque geometry for the volume scenes, ray-traced analytically: boxes (static) and tubes
//! (capsules; a polyline of them is the interactive "well path").
//!
//! A [`GeometryLayer`] holds, per pixel, the distance along the pixel's ray to the nearest opaque
//! surface (`f32::INFINITY` where there is none) and that surface's shaded colour. The ray caster
//! stops each ray at this distance: it is the depth buffer the seed's slow client keeps before
//! its volume pass.

use glam::Vec3;

use crate::cast::Ray;

/// An opaque surface: an axis-aligned box or a capsule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// An axis-aligned box.
    Cuboid {
        /// Minimum corner.
        min: Vec3,
        /// Maximum corner.
        max: Vec3,
    },
    /// A capsule around the segment `a`–`b`.
    Tube {
        /// One end.
        a: Vec3,
        /// The other end.
        b: Vec3,
        /// Radius.
        radius: f32,
    },
}

/// A coloured opaque object.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Solid {
    /// Its shape.
    pub shape: Shape,
    /// Linear RGB.
    pub color: [f32; 3],
}

/// A polyline of tubes of one radius and colour: the seed's well path.
pub fn well_path(points: &[Vec3], radius: f32, color: [f32; 3]) -> Vec<Solid> {
    points
        .windows(2)
        .map(|w| Solid {
            shape: Shape::Tube {
                a: w[0],
                b: w[1],
                radius,
            },
            color,
        })
        .collect()
}

/// Per-pixel nearest opaque hit: distance along the ray and shaded colour.
#[derive(Clone, Debug, PartialEq)]
pub struct GeometryLayer {
    /// Distance along each pixel's ray, `INFINITY` where nothing is hit.
    pub depth: Vec<f32>,
    /// Shaded colour (the background where nothing is hit).
    pub color: Vec<[f32; 3]>,
}

/// The colour behind everything.
pub const BACKGROUND: [f32; 3] = [0.0, 0.0, 0.0];

impl Solid {
    /// The nearest hit in front of the ray's origin: distance and colour (headlight shading).
    pub fn hit(&self, ray: &Ray) -> Option<(f32, [f32; 3])> {
        let (t, normal) = match self.shape {
            Shape::Cuboid { min, max } => hit_box(ray, min, max)?,
            Shape::Tube { a, b, radius } => hit_capsule(ray, a, b, radius)?,
        };
        let light = 0.25 + 0.75 * normal.dot(ray.dir).abs();
        Some((t, self.color.map(|c| c * light)))
    }
}

/// The nearest hit among `solids` along each ray; `solids` earlier in the list win exact ties.
pub fn trace_layer(rays: &[Ray], solids: &[Solid]) -> GeometryLayer {
    let mut depth = vec![f32::INFINITY; rays.len()];
    let mut color = vec![BACKGROUND; rays.len()];
    for (i, ray) in rays.iter().enumerate() {
        for s in solids {
            if let Some((t, c)) = s.hit(ray)
                && t < depth[i]
            {
                depth[i] = t;
                color[i] = c;
            }
        }
    }
    GeometryLayer { depth, color }
}

fn hit_box(ray: &Ray, min: Vec3, max: Vec3) -> Option<(f32, Vec3)> {
    let (t0, t1) = crate::cast::slab(ray, min, max)?;
    let t = if t0 > 0.0 { t0 } else { t1 };
    if t <= 0.0 {
        return None;
    }
    let p = ray.at(t);
    let c = (min + max) * 0.5;
    let d = (p - c) / ((max - min) * 0.5).max(Vec3::splat(1e-12));
    let a = d.abs();
    let n = if a.x >= a.y && a.x >= a.z {
        Vec3::X
    } else if a.y >= a.z {
        Vec3::Y
    } else {
        Vec3::Z
    };
    Some((t, n))
}

fn hit_capsule(ray: &Ray, a: Vec3, b: Vec3, r: f32) -> Option<(f32, Vec3)> {
    // Inigo Quilez's capsule intersection.
    let ba = b - a;
    let oa = ray.origin - a;
    let baba = ba.dot(ba);
    let bard = ba.dot(ray.dir);
    let baoa = ba.dot(oa);
    let rdoa = ray.dir.dot(oa);
    let oaoa = oa.dot(oa);
    let qa = baba - bard * bard;
    let qb = baba * rdoa - baoa * bard;
    let qc = baba * oaoa - baoa * baoa - r * r * baba;
    let h = qb * qb - qa * qc;
    if qa > 0.0 && h >= 0.0 {
        let t = (-qb - h.sqrt()) / qa;
        let y = baoa + t * bard;
        if y > 0.0 && y < baba && t > 0.0 {
            let p = ray.at(t);
            let n = (p - (a + ba * (y / baba))).normalize_or_zero();
            return Some((t, n));
        }
    }
    // The end caps.
    [a, b]
        .iter()
        .filter_map(|&c| {
            let oc = ray.origin - c;
            let bq = ray.dir.dot(oc);
            let cq = oc.dot(oc) - r * r;
            let hq = bq * bq - cq;
            (hq >= 0.0).then(|| (-bq - hq.sqrt(), c))
        })
        .filter(|&(t, _)| t > 0.0)
        .min_by(|x, y| x.0.total_cmp(&y.0))
        .map(|(t, c)| (t, (ray.at(t) - c).normalize_or_zero()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tube_across_the_ray_is_hit_at_its_radius() {
        let ray = Ray {
            origin: Vec3::new(0.0, 0.0, 5.0),
            dir: Vec3::NEG_Z,
        };
        let tube = Solid {
            shape: Shape::Tube {
                a: Vec3::new(-1.0, 0.0, 0.0),
                b: Vec3::new(1.0, 0.0, 0.0),
                radius: 0.25,
            },
            color: [1.0; 3],
        };
        let (t, _) = tube.hit(&ray).expect("hit");
        assert!((t - 4.75).abs() < 1e-5);
        let (t, _) = tube
            .hit(&Ray {
                origin: Vec3::new(3.0, 0.0, 0.0),
                dir: Vec3::NEG_X,
            })
            .expect("cap hit");
        assert!((t - 1.75).abs() < 1e-5);
    }
}
