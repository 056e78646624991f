//! The multi-frame-rate split of volume rendering (Springer's §7.2): the slow client casts the
//! whole image, the fast client re-casts only the rays its interactive objects change.
//!
//! ```text
//! SC:  static objects ─► deep fragments per pixel (kept, before the volume pass)
//!                     ─► cast every ray through its fragments ─► image
//! FC:  interactive objects ─► deep fragments ─► stencil: pixels where an FC fragment lies no
//!                                               farther than the SC's opaque fragment
//!      stencil pixels: re-cast through the SC's and the FC's fragments merged
//!      other pixels:   the SC image as it is
//! ```
//!
//! The seed's FC drew opaque geometry only and re-cast to its nearer depth; here both clients'
//! objects may be translucent, and the caster samples the volume between a pixel's sorted
//! fragments ([`crate::fragments`]). Exactness: a pixel's run is a function of its set of
//! fragments alone (a total order, cut at the first opaque fragment), and the walk's sample
//! positions depend only on the ray and the volume box. Outside the stencil every FC fragment
//! lies strictly behind the SC's opaque fragment, so the merged run is the SC's run and the SC's
//! pixel is the single renderer's; inside it the FC walks the merged run the single renderer
//! walks. The FC's frame therefore equals the single renderer's bit for bit. A tie (an FC
//! fragment at exactly the SC's opaque distance) is re-cast, because the order, not the client,
//! decides which of two fragments at one distance comes first.
//!
//! The fragments may come from the analytic solids of the [`VolumeScene`] ([`Renderer::slow`],
//! [`Renderer::fast_with`], [`Renderer::single_with`]) or from anywhere else — the rasterizer of
//! [`crate::raster`] in `strata mfr --volume` — through [`Renderer::slow_from`],
//! [`Renderer::fast_from`] and [`Renderer::single_from`].

use rayon::prelude::*;

use crate::cast::{CastParams, Caster, Ray, VolumeBox, camera_rays, over_geometry};
use crate::fragments::FragmentLayer;
use crate::geometry::{BACKGROUND, Glass, Solid, fragment_layer};
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
    /// Static translucent objects (the SC's).
    pub static_glass: Vec<Glass>,
    /// The interactive opaque solids (the FC's well path).
    pub interactive: Vec<Solid>,
    /// The interactive translucent objects (the FC's).
    pub interactive_glass: Vec<Glass>,
}

/// Objects the user moves: the FC's opaque solids and translucent objects where they are now.
#[derive(Clone, Copy, Debug)]
pub struct Interactive<'s> {
    /// Opaque solids.
    pub solids: &'s [Solid],
    /// Translucent objects.
    pub glass: &'s [Glass],
}

/// A prepared renderer: rays and the baked transfer function for one step length.
#[derive(Clone, Debug)]
pub struct Renderer<'a> {
    scene: &'a VolumeScene,
    rays: Vec<Ray>,
    caster: Caster<'a>,
}

/// The SC's output: its fragments (kept from before the volume pass) and its image.
#[derive(Clone, Debug)]
pub struct ScFrame {
    /// The static objects' fragments, every pixel's run settled.
    pub fragments: FragmentLayer,
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
    /// Pixels whose run the interactive objects change (re-cast).
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

    /// The scene's interactive objects where the scene places them.
    pub fn interactive(&self) -> Interactive<'a> {
        Interactive {
            solids: &self.scene.interactive,
            glass: &self.scene.interactive_glass,
        }
    }

    /// The fragments of the scene's static objects.
    pub fn static_fragments(&self) -> FragmentLayer {
        fragment_layer(&self.rays, &self.scene.statics, &self.scene.static_glass)
    }

    /// The fragments of `objects`.
    pub fn fragments_of(&self, objects: Interactive<'_>) -> FragmentLayer {
        fragment_layer(&self.rays, objects.solids, objects.glass)
    }

    /// The SC frame: static objects' fragments, then every ray cast through them.
    pub fn slow(&self) -> ScFrame {
        self.slow_from(self.static_fragments())
    }

    /// The SC frame over fragments made elsewhere (one per pixel of this renderer's image).
    pub fn slow_from(&self, fragments: FragmentLayer) -> ScFrame {
        let cast = self.caster.cast_layer(&self.rays, &fragments, BACKGROUND);
        ScFrame {
            fragments,
            image: cast.pixels,
            samples: cast.samples,
        }
    }

    /// The FC frame over `sc` with the scene's interactive objects.
    pub fn fast(&self, sc: &ScFrame) -> FcFrame {
        self.fast_with(sc, self.interactive())
    }

    /// [`Renderer::fast`] with the interactive objects where the user has moved them.
    pub fn fast_with(&self, sc: &ScFrame, objects: Interactive<'_>) -> FcFrame {
        self.fast_from(sc, &self.fragments_of(objects))
    }

    /// The FC frame over `sc` with the interactive fragments `fc`: the stencil, and its pixels
    /// re-cast through both clients' fragments merged.
    pub fn fast_from(&self, sc: &ScFrame, fc: &FragmentLayer) -> FcFrame {
        let stencil = changed_pixels(fc, &sc.fragments);
        let recast: Vec<usize> = (0..stencil.len()).filter(|&i| stencil[i]).collect();
        let results: Vec<_> = recast
            .par_iter()
            .map_init(Vec::new, |run, &i| {
                sc.fragments.merge_into(fc, i, run);
                self.caster.cast_through(&self.rays[i], run)
            })
            .collect();
        let mut image = sc.image.clone();
        let mut samples = 0;
        for (&i, r) in recast.iter().zip(&results) {
            image[i] = over_geometry(r, BACKGROUND);
            samples += u64::from(r.samples);
        }
        FcFrame {
            image,
            stencil,
            recast: recast.len(),
            samples,
        }
    }

    /// The single renderer: all objects' fragments in one layer, every ray cast.
    pub fn single(&self) -> Vec<[f32; 3]> {
        self.single_with(self.interactive())
    }

    /// [`Renderer::single`] with the interactive objects where the user has moved them.
    pub fn single_with(&self, objects: Interactive<'_>) -> Vec<[f32; 3]> {
        let solids: Vec<Solid> = self
            .scene
            .statics
            .iter()
            .chain(objects.solids)
            .copied()
            .collect();
        let glass: Vec<Glass> = (self.scene.static_glass.iter())
            .chain(objects.glass)
            .copied()
            .collect();
        self.single_from(&fragment_layer(&self.rays, &solids, &glass))
    }

    /// The single renderer over one layer holding every object's fragments.
    pub fn single_from(&self, all: &FragmentLayer) -> Vec<[f32; 3]> {
        self.caster.cast_layer(&self.rays, all, BACKGROUND).pixels
    }
}

/// The stencil: pixels where some FC fragment lies no farther than the SC's opaque fragment (or
/// the SC has none there): every pixel whose merged run can differ from the SC's run.
pub fn changed_pixels(fc: &FragmentLayer, sc: &FragmentLayer) -> Vec<bool> {
    (0..fc.pixels())
        .map(|p| !fc.run(p).is_empty() && fc.nearest_t(p) <= sc.opaque_t(p))
        .collect()
}
