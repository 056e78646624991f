//! The ray caster: fixed steps from the ray's entry into the volume box, opacity corrected for
//! the step, front-to-back compositing with early termination, stopping at opaque geometry.
//!
//! For a ray entering the box at distance `t_in` the samples lie at
//! `t_k = t_in + (k + ½)·step`, `k = 0, 1, …`, for every `t_k < min(t_out, t_end)`, where `t_end` is
//! the distance to the opaque surface the ray meets (its depth). The positions depend on the ray
//! and the box only — never on `t_end` or on who casts — so a ray re-cast to a nearer surface
//! takes exactly the first samples of the full cast, and a re-cast with the same inputs is the same
//! computation bit for bit. A camera inside the box keeps the same grid (samples behind the eye are
//! skipped).
//!
//! Compositing, front to back, with premultiplied sample colour `c_k` and corrected opacity `a_k`:
//! `C += T·c_k`, `T *= 1 − a_k`, stopping once the transmittance `T` falls below
//! [`CastParams::termination`]. The pixel is `C + T·geometry colour`.

use glam::{Mat4, Vec3, Vec4};
use rayon::prelude::*;

use crate::transfer::StepTable;
use crate::volume::Volume;

/// A ray: origin and unit direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin (the eye).
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
}

impl Ray {
    /// The point at distance `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// Where the volume sits in the world: an axis-aligned box its [0, 1]³ coordinates fill.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeBox {
    /// Minimum corner (volume coordinate 0).
    pub min: Vec3,
    /// Maximum corner (volume coordinate 1).
    pub max: Vec3,
}

/// Step length, sample cap and early termination.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CastParams {
    /// Distance between samples (world units).
    pub step: f32,
    /// Transmittance below which a ray stops.
    pub termination: f32,
}

impl CastParams {
    /// Steps that put `samples` samples across the box's diagonal.
    pub fn for_samples(placement: &VolumeBox, samples: u32) -> CastParams {
        CastParams {
            step: (placement.max - placement.min).length() / samples.max(1) as f32,
            termination: 1.0 / 512.0,
        }
    }
}

/// Distances where the ray enters and leaves the box, if it meets it in front of the origin.
pub fn slab(ray: &Ray, min: Vec3, max: Vec3) -> Option<(f32, f32)> {
    let inv = ray.dir.recip();
    let a = (min - ray.origin) * inv;
    let b = (max - ray.origin) * inv;
    let t0 = a.min(b).max_element();
    let t1 = a.max(b).min_element();
    (t1 >= t0.max(0.0) && t0.is_finite() && t1.is_finite()).then_some((t0, t1))
}

/// The primary rays of a `width` × `height` image (row 0 at the top) for `view_proj`.
pub fn camera_rays(view_proj: Mat4, width: u32, height: u32) -> Vec<Ray> {
    let inv = view_proj.inverse();
    let unproject = |x: f32, y: f32, z: f32| {
        let p = inv * Vec4::new(x, y, z, 1.0);
        p.truncate() / p.w
    };
    let mut rays = Vec::with_capacity(width as usize * height as usize);
    for py in 0..height {
        for px in 0..width {
            let x = 2.0 * (px as f32 + 0.5) / width as f32 - 1.0;
            let y = 1.0 - 2.0 * (py as f32 + 0.5) / height as f32;
            let near = unproject(x, y, -1.0);
            let far = unproject(x, y, 1.0);
            rays.push(Ray {
                origin: near,
                dir: (far - near).normalize(),
            });
        }
    }
    rays
}

/// A volume ready to cast: the data, where it sits, the baked transfer function, the steps.
#[derive(Clone, Debug)]
pub struct Caster<'a> {
    /// The scalar field.
    pub volume: &'a Volume,
    /// Its placement.
    pub placement: VolumeBox,
    /// The transfer function baked for `params.step`.
    pub table: StepTable,
    /// Steps and termination.
    pub params: CastParams,
}

/// One ray's result: premultiplied colour, transmittance left, samples taken.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RaySample {
    /// Accumulated premultiplied colour.
    pub color: [f32; 3],
    /// Transmittance left at the end of the ray.
    pub transmittance: f32,
    /// Samples taken.
    pub samples: u32,
}

impl Caster<'_> {
    /// Casts one ray up to distance `t_end`.
    pub fn cast(&self, ray: &Ray, t_end: f32) -> RaySample {
        let mut out = RaySample {
            color: [0.0; 3],
            transmittance: 1.0,
            samples: 0,
        };
        let Some((t_in, t_out)) = slab(ray, self.placement.min, self.placement.max) else {
            return out;
        };
        let stop = t_out.min(t_end);
        let size = self.placement.max - self.placement.min;
        let step = self.params.step;
        // Skip samples behind the eye without moving the grid.
        let mut k = if t_in < 0.0 {
            ((-t_in) / step - 0.5).ceil().max(0.0) as u64
        } else {
            0
        };
        loop {
            let t = t_in + (k as f32 + 0.5) * step;
            if t >= stop || out.transmittance < self.params.termination {
                break;
            }
            let u = (ray.at(t) - self.placement.min) / size;
            let s = self.table.lookup(self.volume.sample(u));
            let w = out.transmittance;
            out.color = [0, 1, 2].map(|c| out.color[c] + w * s[c]);
            out.transmittance = w * (1.0 - s[3]);
            out.samples += 1;
            k += 1;
        }
        out
    }

    /// Casts every ray to its depth in parallel and composites over `geometry` colours.
    pub fn cast_image(&self, rays: &[Ray], depth: &[f32], geometry: &[[f32; 3]]) -> CastImage {
        let results: Vec<RaySample> = rays
            .par_iter()
            .zip(depth.par_iter())
            .map(|(r, &d)| self.cast(r, d))
            .collect();
        let samples = results.iter().map(|r| u64::from(r.samples)).sum();
        let pixels = results
            .iter()
            .zip(geometry)
            .map(|(r, g)| over_geometry(r, *g))
            .collect();
        CastImage { pixels, samples }
    }
}

/// The ray's colour with the opaque surface behind it.
pub fn over_geometry(r: &RaySample, geometry: [f32; 3]) -> [f32; 3] {
    [0, 1, 2].map(|c| r.color[c] + r.transmittance * geometry[c])
}

/// A cast image: linear RGB per pixel and the total samples taken.
#[derive(Clone, Debug, PartialEq)]
pub struct CastImage {
    /// Linear RGB, row 0 at the top.
    pub pixels: Vec<[f32; 3]>,
    /// Samples taken over all rays.
    pub samples: u64,
}
