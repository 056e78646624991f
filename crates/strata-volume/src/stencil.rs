//! The multi-frame-rate split of volume rendering (Springer's §7.2): the slow client casts the
//! whole image, the fast client re-casts only the rays its interactive object shortens.
//!
//! ```text
//! SC:  static solids ─► depth + colour (kept, before the volume pass) ─► cast every ray ─► image
//! FC:  interactive solids ─► depth test against the SC depth ─► stencil (its visible pixels)
//!      stencil pixels: re-cast to the object's (nearer) depth, composite over its colour
//!      other pixels:   the SC image as it is
//! ```
//!
//! Because the caster's sample positions depend only on the ray and the volume box, a re-cast
//! ray to the object's depth is the same computation the single renderer does for that pixel, and
//! the FC's frame equals the single renderer's bit for bit. The FC's object wins a pixel only when
//! it is strictly nearer than the SC's surface, the same rule the single renderer applies when it
//! traces static solids first.

use crate::cast::{CastParams, Caster, Ray, VolumeBox, camera_rays, over_geometry};
use crate::geometry::{GeometryLayer, Solid, trace_layer};
use crate::transfer::{StepTable, TransferFunction};
use crate::volume::Volume;

/// A volume scene: the volume and its transfer function, the camera's rays, the solids.
#[derive(Clone, Debug)]
pub struct VolumeScene {
    /// The scalar field.
    pub volume: Volume,
    /// Its transfer function.
    pub transfer: TransferFunction,
    /// Where it sits.
    pub placement: VolumeBox,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// World → clip.
    pub view_proj: glam::Mat4,
    /// Static opaque solids (the SC's).
    pub statics: Vec<Solid>,
    /// The interactive opaque solids (the FC's well path).
    pub interactive: Vec<Solid>,
}

/// A prepared renderer: rays and the baked transfer function for one step length.
#[derive(Clone, Debug)]
pub struct Renderer<'a> {
    scene: &'a VolumeScene,
    rays: Vec<Ray>,
    caster: Caster<'a>,
}

/// The SC's output: its geometry layer (depth kept from before the volume pass) and its image.
#[derive(Clone, Debug)]
pub struct ScFrame {
    /// The static solids' depth and colour.
    pub geometry: GeometryLayer,
    /// The composited image.
    pub image: Vec<[f32; 3]>,
    /// Volume samples taken.
    pub samples: u64,
}

/// The FC's output.
#[derive(Clone, Debug)]
pub struct FcFrame {
    /// The composited image.
    pub image: Vec<[f32; 3]>,
    /// Pixels where the interactive solids are visible (re-cast).
    pub stencil: Vec<bool>,
    /// How many rays were re-cast.
    pub recast: usize,
    /// Volume samples taken by the re-cast.
    pub samples: u64,
}

impl<'a> Renderer<'a> {
    /// Prepares `scene` for casting with `params`.
    pub fn new(scene: &'a VolumeScene, params: CastParams) -> Renderer<'a> {
        Renderer {
            scene,
            rays: camera_rays(scene.view_proj, scene.width, scene.height),
            caster: Caster {
                volume: &scene.volume,
                placement: scene.placement,
                table: StepTable::new(&scene.transfer, params.step),
                params,
            },
        }
    }

    /// The primary rays, row by row.
    pub fn rays(&self) -> &[Ray] {
        &self.rays
    }

    /// The SC frame: static solids, then every ray cast to their depth.
    pub fn slow(&self) -> ScFrame {
        let geometry = trace_layer(&self.rays, &self.scene.statics);
        let cast = self
            .caster
            .cast_image(&self.rays, &geometry.depth, &geometry.color);
        ScFrame {
            geometry,
            image: cast.pixels,
            samples: cast.samples,
        }
    }

    /// The FC frame over `sc`: the interactive solids against the SC depth, stencil re-cast.
    pub fn fast(&self, sc: &ScFrame) -> FcFrame {
        self.fast_with(sc, &self.scene.interactive)
    }

    /// [`Renderer::fast`] with the interactive solids where the user has moved them.
    pub fn fast_with(&self, sc: &ScFrame, interactive: &[Solid]) -> FcFrame {
        let objects = trace_layer(&self.rays, interactive);
        let stencil = visible_pixels(&objects.depth, &sc.geometry.depth);
        let mut image = sc.image.clone();
        let recast: Vec<usize> = (0..stencil.len()).filter(|&i| stencil[i]).collect();
        let results: Vec<_> = {
            use rayon::prelude::*;
            recast
                .par_iter()
                .map(|&i| self.caster.cast(&self.rays[i], objects.depth[i]))
                .collect()
        };
        let mut samples = 0;
        for (&i, r) in recast.iter().zip(&results) {
            image[i] = over_geometry(r, objects.color[i]);
            samples += u64::from(r.samples);
        }
        FcFrame {
            image,
            stencil,
            recast: recast.len(),
            samples,
        }
    }

    /// The single renderer: all solids (static first), every ray cast.
    pub fn single(&self) -> Vec<[f32; 3]> {
        self.single_with(&self.scene.interactive)
    }

    /// [`Renderer::single`] with the interactive solids where the user has moved them.
    pub fn single_with(&self, interactive: &[Solid]) -> Vec<[f32; 3]> {
        let solids: Vec<Solid> = self
            .scene
            .statics
            .iter()
            .chain(interactive)
            .copied()
            .collect();
        let geometry = trace_layer(&self.rays, &solids);
        self.caster
            .cast_image(&self.rays, &geometry.depth, &geometry.color)
            .pixels
    }
}

/// The stencil: pixels where the object is strictly nearer than the SC's surface.
pub fn visible_pixels(object_depth: &[f32], sc_depth: &[f32]) -> Vec<bool> {
    object_depth
        .iter()
        .zip(sc_depth)
        .map(|(&o, &s)| o < s)
        .collect()
}
