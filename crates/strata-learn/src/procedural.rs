//! A seeded procedural scene generator: random translucent and opaque spheres, cubes and slabs,
//! 2 to 40 layers deep, for training data that needs no files and no licence.
//!
//! # Construction
//!
//! A seed fixes everything (a splitmix64 stream, [`Rng`]); the same seed gives the same scene bit
//! for bit on every machine. The scene draws a layer count `L = 2n`, `n` in `1..=20`, and places
//! `n` **convex** closed objects (spheres, cubes, slabs), each of which a ray crosses at most
//! twice (front and back face). Every object is placed so that it contains the camera's axis (the
//! ray through the image centre): its centre lies near the axis, closer than its inscribed radius.
//! So from the scene's own camera the pixels at the image centre hold exactly `L` fragments and no
//! pixel holds more — the frame's depth complexity is exactly [`ProceduralScene::layers`]
//! (tested). Off the axis the objects overlap in every other number of layers down to 1.
//!
//! - Alpha: one object in five is opaque; the others draw α uniformly in `[0.15, 0.9]`.
//! - Colours: uniform RGB; the background a uniform grey in `[0, 1]`.
//! - Sizes: spheres and cubes 0.35–1.1 across, slabs 0.6–1.6 wide, turned at most 35° from
//!   facing the camera; depths spread over `[-0.9, 0.9]` along the axis.

use std::sync::Arc;

use glam::{Mat4, Vec3};
use strata_core::{Material, ObjectId, Shading};
use strata_scene::builtin::shapes;
use strata_scene::{Camera, Mesh, Scene, SceneObject};

/// Fewest layers a procedural scene has.
pub const MIN_LAYERS: u32 = 2;
/// Most layers a procedural scene has.
pub const MAX_LAYERS: u32 = 40;

/// A small deterministic random stream (splitmix64).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A stream started from `seed`.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.0)
    }

    /// Uniform in `[0, 1)`, 24 bits.
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in `lo..=hi`.
    pub fn int(&mut self, lo: u32, hi: u32) -> u32 {
        lo + (self.next_u64() % u64::from(hi - lo + 1)) as u32
    }
}

/// The splitmix64 finaliser: a 64-bit hash of `z`.
pub fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A generated scene and what it was generated to be.
#[derive(Clone, Debug)]
pub struct ProceduralScene {
    /// The scene, named `procedural-<seed>`.
    pub scene: Scene,
    /// The seed it came from.
    pub seed: u64,
    /// Its depth complexity from its own camera: the fragments of the image centre's pixels.
    pub layers: u32,
}

/// The three shapes the generator uses, built once per scene.
struct Shapes {
    sphere: Arc<Mesh>,
    cube: Arc<Mesh>,
    slab: Arc<Mesh>,
}

impl Shapes {
    fn new() -> Self {
        let get = |name| Arc::new(shapes::shape(name).unwrap_or_else(|| shapes::grid(1, 1)));
        Shapes {
            sphere: get("sphere"),
            cube: get("cube"),
            slab: get("slab"),
        }
    }
}

/// Generates the scene of `seed`, `width` × `height` pixels; see the module docs.
pub fn generate(seed: u64, width: u32, height: u32) -> ProceduralScene {
    let mut rng = Rng::new(mix(seed ^ 0x5354_5241_5441_4C4B));
    let shapes = Shapes::new();
    let n = rng.int(MIN_LAYERS / 2, MAX_LAYERS / 2);
    let grey = rng.unit();
    let objects = (0..n)
        .map(|i| object(&mut rng, &shapes, i, n))
        .collect::<Vec<_>>();
    let scene = Scene {
        name: format!("procedural-{seed}"),
        origin: format!("procedural scene {seed}"),
        width,
        height,
        background: [grey; 3],
        camera: Camera {
            eye: Vec3::new(0.0, 0.0, 2.6),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fovy_deg: 45.0,
            near: 0.05,
            far: 20.0,
        },
        objects,
        animation: None,
        volume: None,
    };
    ProceduralScene {
        scene,
        seed,
        layers: 2 * n,
    }
}

/// Object `i` of `n`: a convex shape containing the z axis (the camera's axis).
fn object(rng: &mut Rng, shapes: &Shapes, i: u32, n: u32) -> SceneObject {
    // Spread along the axis: evenly spaced slots, jittered within each.
    let slot = (i as f32 + rng.range(0.2, 0.8)) / n as f32;
    let z = -0.9 + 1.8 * slot;
    let kind = rng.int(0, 2);
    let (mesh, name, size, rotate, inscribed) = match kind {
        0 => {
            let d = rng.range(0.35, 1.1);
            (
                shapes.sphere.clone(),
                "sphere",
                Vec3::splat(d),
                Vec3::ZERO,
                0.45 * d,
            )
        }
        1 => {
            let d = rng.range(0.35, 1.1);
            let rot = Vec3::new(
                rng.range(0.0, 90.0),
                rng.range(0.0, 90.0),
                rng.range(0.0, 90.0),
            );
            (shapes.cube.clone(), "cube", Vec3::splat(d), rot, 0.5 * d)
        }
        _ => {
            // A pane facing the camera, turned at most 35°: the axis crosses it within its
            // face as long as the centre is off the axis by less than a quarter of its width.
            let d = rng.range(0.6, 1.6);
            let rot = Vec3::new(rng.range(-35.0, 35.0), rng.range(-35.0, 35.0), 0.0);
            (shapes.slab.clone(), "slab", Vec3::splat(d), rot, 0.25 * d)
        }
    };
    // Off the axis by at most half the inscribed radius, in a random direction.
    let angle = rng.range(0.0, std::f32::consts::TAU);
    let off = 0.5 * inscribed * rng.unit();
    let translate = Vec3::new(off * angle.cos(), off * angle.sin(), z);
    let opaque = rng.unit() < 0.2;
    let alpha = if opaque { 1.0 } else { rng.range(0.15, 0.9) };
    let color = [rng.unit(), rng.unit(), rng.unit(), alpha];
    SceneObject {
        name: format!("{name} {i}"),
        id: ObjectId(i),
        mesh,
        base: Mat4::IDENTITY,
        translate,
        rotate_deg: rotate,
        scale: size,
        material: Material {
            color,
            shading: Shading::Headlight,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rng_ranges() {
        let mut rng = Rng::new(3);
        for _ in 0..1000 {
            let u = rng.unit();
            assert!((0.0..1.0).contains(&u));
            assert!((5..=7).contains(&rng.int(5, 7)));
        }
    }
}
