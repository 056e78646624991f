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
//!
//! [`Caster::cast_through`] walks the same grid together with a pixel's sorted deep fragments,
//! compositing each fragment where it lies between the samples (translucent geometry inside the
//! volume; [`crate::fragments`] describes the walk).

use glam::{Mat4, Vec3, Vec4};
use rayon::prelude::*;

use crate::fragments::{FragmentLayer, RayFragment};
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

/// The NDC position of pixel `(px, py)`'s centre in a `width` × `height` image (row 0 at the
/// top): where its primary ray passes.
#[inline]
pub fn pixel_ndc(px: u32, py: u32, width: u32, height: u32) -> (f32, f32) {
    (
        2.0 * (px as f32 + 0.5) / width as f32 - 1.0,
        1.0 - 2.0 * (py as f32 + 0.5) / height as f32,
    )
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
            let (x, y) = pixel_ndc(px, py, width, height);
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

impl RaySample {
    /// Nothing composited yet: no colour, full transmittance.
    pub const CLEAR: RaySample = RaySample {
        color: [0.0; 3],
        transmittance: 1.0,
        samples: 0,
    };
}

/// Where a ray's sample grid lies: the box's entry and exit distances and the first sample in
/// front of the eye.
#[derive(Clone, Copy, Debug)]
struct Grid {
    t_in: f32,
    t_out: f32,
    k: u64,
}

impl Caster<'_> {
    /// The ray's grid, `None` when it misses the box.
    fn grid(&self, ray: &Ray) -> Option<Grid> {
        let (t_in, t_out) = slab(ray, self.placement.min, self.placement.max)?;
        // Skip samples behind the eye without moving the grid.
        let k = if t_in < 0.0 {
            ((-t_in) / self.params.step - 0.5).ceil().max(0.0) as u64
        } else {
            0
        };
        Some(Grid { t_in, t_out, k })
    }

    /// Composites the grid's samples from `grid.k` on while they lie before `stop` and the ray
    /// is not yet opaque; `grid.k` is left at the first sample not taken.
    fn march(&self, ray: &Ray, grid: &mut Grid, stop: f32, out: &mut RaySample) {
        let size = self.placement.max - self.placement.min;
        let step = self.params.step;
        loop {
            let t = grid.t_in + (grid.k as f32 + 0.5) * step;
            if t >= stop || out.transmittance < self.params.termination {
                break;
            }
            let u = (ray.at(t) - self.placement.min) / size;
            let s = self.table.lookup(self.volume.sample(u));
            let w = out.transmittance;
            out.color = [0, 1, 2].map(|c| out.color[c] + w * s[c]);
            out.transmittance = w * (1.0 - s[3]);
            out.samples += 1;
            grid.k += 1;
        }
    }

    /// Casts one ray up to distance `t_end`.
    pub fn cast(&self, ray: &Ray, t_end: f32) -> RaySample {
        let mut out = RaySample::CLEAR;
        if let Some(mut grid) = self.grid(ray) {
            let stop = grid.t_out.min(t_end);
            self.march(ray, &mut grid, stop, &mut out);
        }
        out
    }

    /// Casts one ray through its settled fragment run ([`crate::fragments`]): the samples
    /// before each fragment, the fragment, and on to the box's exit or the opaque fragment. The
    /// result's colour includes the fragments; an opaque fragment leaves no transmittance, so
    /// [`over_geometry`] with the background gives the pixel either way. Early termination
    /// stops the samples, never the fragments.
    pub fn cast_through(&self, ray: &Ray, run: &[RayFragment]) -> RaySample {
        let mut out = RaySample::CLEAR;
        let mut grid = self.grid(ray);
        for f in run {
            if let Some(g) = grid.as_mut() {
                let stop = g.t_out.min(f.t);
                self.march(ray, g, stop, &mut out);
            }
            let w = out.transmittance;
            out.color = [0, 1, 2].map(|c| out.color[c] + w * f.alpha * f.color[c]);
            out.transmittance = w * (1.0 - f.alpha);
            if f.is_opaque() {
                return out;
            }
        }
        if let Some(g) = grid.as_mut() {
            let stop = g.t_out;
            self.march(ray, g, stop, &mut out);
        }
        out
    }

    /// Casts every pixel's ray through its run of `layer` in parallel, over `background`.
    pub fn cast_layer(
        &self,
        rays: &[Ray],
        layer: &FragmentLayer,
        background: [f32; 3],
    ) -> CastImage {
        let results: Vec<RaySample> = rays
            .par_iter()
            .enumerate()
            .map(|(p, r)| self.cast_through(r, layer.run(p)))
            .collect();
        let samples = results.iter().map(|r| u64::from(r.samples)).sum();
        let pixels = results
            .iter()
            .map(|r| over_geometry(r, background))
            .collect();
        CastImage { pixels, samples }
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
