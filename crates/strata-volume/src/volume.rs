//! A scalar volume: a dense grid of values in [0, 1], sampled trilinearly.
//!
//! Layout: `values[x + nx * (y + ny * z)]`, x fastest — the order NIfTI-1 stores voxels in. A
//! voxel's value sits at its centre; in the volume's own coordinates `u ∈ [0, 1]³` voxel `i` along
//! an axis of `n` voxels has its centre at `(i + 0.5) / n`. Sampling clamps to the outermost
//! centres, so the box's faces repeat the edge voxels.

/// A dense scalar grid with values normalised to [0, 1].
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    dims: [usize; 3],
    values: Vec<f32>,
}

impl Volume {
    /// A volume from values in x-fastest order; `None` when the count does not match `dims` or a
    /// dimension is 0.
    pub fn from_values(dims: [usize; 3], values: Vec<f32>) -> Option<Volume> {
        let count = dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))?;
        (count > 0 && count == values.len()).then_some(Volume { dims, values })
    }

    /// A procedural volume: `f` is evaluated at each voxel centre in [0, 1]³ and clamped to [0, 1].
    pub fn from_fn(dims: [usize; 3], f: impl Fn(glam::Vec3) -> f32) -> Volume {
        let [nx, ny, nz] = dims.map(|d| d.max(1));
        let mut values = Vec::with_capacity(nx * ny * nz);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let u = glam::Vec3::new(
                        (x as f32 + 0.5) / nx as f32,
                        (y as f32 + 0.5) / ny as f32,
                        (z as f32 + 0.5) / nz as f32,
                    );
                    values.push(f(u).clamp(0.0, 1.0));
                }
            }
        }
        Volume {
            dims: [nx, ny, nz],
            values,
        }
    }

    /// A constant volume (the analytic slab of the tests).
    pub fn constant(dims: [usize; 3], value: f32) -> Volume {
        Volume::from_fn(dims, |_| value)
    }

    /// A built-in test volume: a soft sphere shell with a denser core, in a faint haze.
    pub fn procedural_head(n: usize) -> Volume {
        Volume::from_fn([n, n, n], |u| {
            let r = (u - glam::Vec3::splat(0.5)).length() * 2.0;
            let shell = (1.0 - ((r - 0.8) / 0.08).powi(2)).max(0.0) * 0.9;
            let core = (1.0 - (r / 0.35).powi(2)).max(0.0) * 0.6;
            let haze = if r < 1.0 { 0.15 } else { 0.0 };
            shell.max(core).max(haze)
        })
    }

    /// Voxels along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The values, x fastest.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        self.values[x + self.dims[0] * (y + self.dims[1] * z)]
    }

    /// The trilinearly interpolated value at `u` in the volume's [0, 1]³ coordinates.
    pub fn sample(&self, u: glam::Vec3) -> f32 {
        let (x0, x1, fx) = axis(u.x, self.dims[0]);
        let (y0, y1, fy) = axis(u.y, self.dims[1]);
        let (z0, z1, fz) = axis(u.z, self.dims[2]);
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(self.at(x0, y0, z0), self.at(x1, y0, z0), fx);
        let c10 = lerp(self.at(x0, y1, z0), self.at(x1, y1, z0), fx);
        let c01 = lerp(self.at(x0, y0, z1), self.at(x1, y0, z1), fx);
        let c11 = lerp(self.at(x0, y1, z1), self.at(x1, y1, z1), fx);
        lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz)
    }
}

/// The two neighbouring voxel indices along one axis and the weight of the second.
fn axis(u: f32, n: usize) -> (usize, usize, f32) {
    let p = (u * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
    let i0 = (p.floor() as usize).min(n - 1);
    let i1 = (i0 + 1).min(n - 1);
    (i0, i1, p - i0 as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampling_at_voxel_centres_returns_the_voxel() {
        let v = Volume::from_values([2, 1, 1], vec![0.25, 0.75]).expect("sizes match");
        assert_eq!(v.sample(glam::Vec3::new(0.25, 0.5, 0.5)), 0.25);
        assert_eq!(v.sample(glam::Vec3::new(0.75, 0.5, 0.5)), 0.75);
        assert_eq!(v.sample(glam::Vec3::new(0.5, 0.5, 0.5)), 0.5);
        // Outside the centres the edge voxel repeats.
        assert_eq!(v.sample(glam::Vec3::new(0.0, 0.5, 0.5)), 0.25);
    }

    #[test]
    fn from_values_rejects_a_wrong_count() {
        assert!(Volume::from_values([2, 2, 2], vec![0.0; 7]).is_none());
        assert!(Volume::from_values([0, 2, 2], vec![]).is_none());
    }
}
