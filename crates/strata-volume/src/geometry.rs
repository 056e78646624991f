//! Geometry for the volume scenes, ray-traced analytically: boxes (static) and tubes (capsules; a
//! polyline of them is the interactive "well path"), opaque ([`Solid`]) or translucent
//! ([`Glass`]).
//!
//! [`fragment_layer`] turns them into every pixel's deep fragments ([`crate::fragments`]): an
//! opaque solid gives its nearest hit, a translucent one both surfaces the ray crosses (its entry
//! and exit; shapes are convex), all shaded by a headlight.
//!
//! A [`GeometryLayer`] is the opaque-only view of the same solids: per pixel, the distance along
//! the pixel's ray to the nearest opaque surface (`f32::INFINITY` where there is none) and that
//! surface's shaded colour — the seed's depth buffer, which [`crate::cast::Caster::cast_image`]
//! stops each ray at. The clients use fragment layers; a layer of opaque solids alone casts the
//! same image bit for bit (tested).

use glam::Vec3;
use rayon::prelude::*;

use crate::cast::Ray;
use crate::fragments::{FragmentLayer, RayFragment};

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

/// A coloured translucent object: both of its surfaces along a ray are fragments.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Glass {
    /// Its shape.
    pub shape: Shape,
    /// Linear RGB, straight.
    pub color: [f32; 3],
    /// Opacity of each surface, in [0, 1).
    pub alpha: f32,
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
        let light = headlight(normal, ray.dir);
        Some((t, self.color.map(|c| c * light)))
    }
}

/// The light a headlight gives a surface with `normal` seen along `dir`.
fn headlight(normal: Vec3, dir: Vec3) -> f32 {
    0.25 + 0.75 * normal.dot(dir).abs()
}

impl Glass {
    /// Where the ray crosses its surfaces in front of the origin, front to back, shaded: the
    /// entry and the exit, or only the exit when the origin is inside.
    pub fn fragments(&self, ray: &Ray) -> impl Iterator<Item = RayFragment> + use<> {
        let (entry, exit) = match self.shape {
            Shape::Cuboid { min, max } => (hit_box(ray, min, max), exit_box(ray, min, max)),
            Shape::Tube { a, b, radius } => (
                hit_capsule(ray, a, b, radius),
                exit_capsule(ray, a, b, radius),
            ),
        };
        let entry = entry.filter(|e| exit.is_some_and(|x| e.0 < x.0));
        let (color, alpha, dir) = (self.color, self.alpha.min(1.0), ray.dir);
        entry
            .into_iter()
            .chain(exit)
            .map(move |(t, n)| RayFragment {
                t,
                color: color.map(|c| c * headlight(n, dir)),
                alpha,
            })
    }
}

/// Every pixel's fragments: each opaque solid's nearest hit and each glass's surfaces along the
/// pixel's ray, settled (sorted, cut at the first opaque one).
pub fn fragment_layer(rays: &[Ray], solids: &[Solid], glass: &[Glass]) -> FragmentLayer {
    let lists = rays
        .par_iter()
        .map(|ray| {
            let opaque = solids.iter().filter_map(|s| {
                s.hit(ray).map(|(t, color)| RayFragment {
                    t,
                    color,
                    alpha: 1.0,
                })
            });
            opaque
                .chain(glass.iter().flat_map(|g| g.fragments(ray)))
                .collect()
        })
        .collect();
    FragmentLayer::from_lists(lists)
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
    Some((t, box_normal(ray.at(t), min, max)))
}

fn exit_box(ray: &Ray, min: Vec3, max: Vec3) -> Option<(f32, Vec3)> {
    let (_, t1) = crate::cast::slab(ray, min, max)?;
    (t1 > 0.0).then(|| (t1, box_normal(ray.at(t1), min, max)))
}

/// The normal of the box face nearest `p`.
fn box_normal(p: Vec3, min: Vec3, max: Vec3) -> Vec3 {
    let c = (min + max) * 0.5;
    let d = (p - c) / ((max - min) * 0.5).max(Vec3::splat(1e-12));
    let a = d.abs();
    if a.x >= a.y && a.x >= a.z {
        Vec3::X
    } else if a.y >= a.z {
        Vec3::Y
    } else {
        Vec3::Z
    }
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

/// Where the ray leaves the capsule: the farthest exit among its two end spheres and its
/// cylinder's side (the capsule is their union and convex, so the union's exit is the last one).
fn exit_capsule(ray: &Ray, a: Vec3, b: Vec3, r: f32) -> Option<(f32, Vec3)> {
    let ba = b - a;
    let oa = ray.origin - a;
    let baba = ba.dot(ba);
    let bard = ba.dot(ray.dir);
    let baoa = ba.dot(oa);
    let qa = baba - bard * bard;
    let qb = baba * ray.dir.dot(oa) - baoa * bard;
    let qc = baba * oa.dot(oa) - baoa * baoa - r * r * baba;
    let h = qb * qb - qa * qc;
    let side = (qa > 0.0 && h >= 0.0)
        .then(|| (-qb + h.sqrt()) / qa)
        .filter(|&t| {
            let y = baoa + t * bard;
            y > 0.0 && y < baba
        });
    let caps = [a, b].into_iter().filter_map(|c| {
        let oc = ray.origin - c;
        let bq = ray.dir.dot(oc);
        let hq = bq * bq - (oc.dot(oc) - r * r);
        (hq >= 0.0).then(|| -bq + hq.sqrt())
    });
    let t = side
        .into_iter()
        .chain(caps)
        .filter(|&t| t > 0.0)
        .max_by(f32::total_cmp)?;
    let p = ray.at(t);
    let y = ((p - a).dot(ba) / baba.max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
    Some((t, (p - (a + ba * y)).normalize_or_zero()))
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

    #[test]
    fn glass_gives_its_entry_and_exit_or_only_the_exit_from_inside() {
        let ray = Ray {
            origin: Vec3::new(0.0, 0.0, 5.0),
            dir: Vec3::NEG_Z,
        };
        let tube = Glass {
            shape: Shape::Tube {
                a: Vec3::new(-1.0, 0.0, 0.0),
                b: Vec3::new(1.0, 0.0, 0.0),
                radius: 0.25,
            },
            color: [1.0; 3],
            alpha: 0.5,
        };
        let ts: Vec<f32> = tube.fragments(&ray).map(|f| f.t).collect();
        assert_eq!(ts.len(), 2);
        assert!(
            (ts[0] - 4.75).abs() < 1e-5 && (ts[1] - 5.25).abs() < 1e-5,
            "{ts:?}"
        );
        // Along the axis: in through one cap, out through the other.
        let along = Ray {
            origin: Vec3::new(3.0, 0.0, 0.0),
            dir: Vec3::NEG_X,
        };
        let ts: Vec<f32> = tube.fragments(&along).map(|f| f.t).collect();
        assert!(
            (ts[0] - 1.75).abs() < 1e-5 && (ts[1] - 4.25).abs() < 1e-5,
            "{ts:?}"
        );
        let sheet = Glass {
            shape: Shape::Cuboid {
                min: Vec3::new(-1.0, -1.0, -0.1),
                max: Vec3::new(1.0, 1.0, 0.1),
            },
            color: [0.5; 3],
            alpha: 0.25,
        };
        let inside = Ray {
            origin: Vec3::ZERO,
            dir: Vec3::NEG_Z,
        };
        let fs: Vec<RayFragment> = sheet.fragments(&inside).collect();
        assert_eq!(fs.len(), 1);
        assert!((fs[0].t - 0.1).abs() < 1e-6);
        // Facing the headlight: full colour.
        assert_eq!(fs[0].color, [0.5; 3]);
        assert_eq!(fs[0].alpha, 0.25);
    }
}
