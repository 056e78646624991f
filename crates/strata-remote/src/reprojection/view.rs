//! One frame's view as both ends compute it: the matrices of every object, their materials, and
//! the two transforms of Jähne 2014 ch. 5 — eq. 5.10 once for a rendered normal fragment
//! ([`View::entry`]), eq. 5.9 every frame for a held surfel (`View::project`) — with strata's standard
//! shading of the result.

use glam::{Mat3, Mat4, Vec3, Vec4};
use strata_core::fragment::unorm8;
use strata_core::material::{headlight_factor, headlight_rgba};
use strata_core::{DeepFrame, Fragment, ObjectId, PackedNormal, Rgba8, Shading};
use strata_scene::Scene;

use super::held::{Entry, Surfel};

/// One object's matrices and material at one frame.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct ObjectView {
    pub(super) model_view: Mat4,
    pub(super) inverse_model_view: Mat4,
    /// Object → eye for normals: inverse-transpose of the model-view's 3×3.
    pub(super) normal: Mat3,
    /// Eye → object for normals: the transpose of the model-view's 3×3.
    pub(super) to_object_normal: Mat3,
    pub(super) rgb: [f32; 3],
    pub(super) alpha: u8,
    pub(super) lit: bool,
    pub(super) flat: Rgba8,
}

/// One frame's camera and object placements, as both ends compute them.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) projection: Mat4,
    pub(super) inverse_projection: Mat4,
    /// Indexed by object id (scene ids are dense).
    objects: Vec<Option<ObjectView>>,
}

impl View {
    /// The view of `objects` of `scene` posed at animation frame `frame`, seen with `view` and
    /// `projection` at `width` × `height`. Objects not listed are unknown to it.
    pub fn new(
        scene: &Scene,
        objects: &[ObjectId],
        frame: u32,
        (width, height): (u32, u32),
        view: Mat4,
        projection: Mat4,
    ) -> View {
        let max = scene.objects.iter().map(|o| o.id.0).max().unwrap_or(0) as usize;
        let mut table = vec![None; max + 1];
        for o in scene.objects.iter().filter(|o| objects.contains(&o.id)) {
            let model_view = view * o.model_matrix(scene.animation.as_ref(), frame);
            let m3 = Mat3::from_mat4(model_view);
            let c = o.material.color;
            table[o.id.0 as usize] = Some(ObjectView {
                model_view,
                inverse_model_view: model_view.inverse(),
                normal: m3.inverse().transpose(),
                to_object_normal: m3.transpose(),
                rgb: [c[0], c[1], c[2]],
                alpha: unorm8(c[3]),
                lit: o.material.shading == Shading::Headlight,
                flat: Rgba8::from_unorm(c),
            });
        }
        View {
            width,
            height,
            projection,
            inverse_projection: projection.inverse(),
            objects: table,
        }
    }

    /// Frame size.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// One more than the largest object id it can know (the length of its object table).
    pub(super) fn object_slots(&self) -> usize {
        self.objects.len()
    }

    /// Distance from the eye plane of a fragment at window depth `depth` (for a perspective
    /// projection it does not depend on the pixel).
    #[inline]
    pub(super) fn eye_depth(&self, depth: f32) -> f32 {
        // The z and w rows of P⁻¹ · (0, 0, z_ndc, 1).
        let (c, d) = (
            self.inverse_projection.z_axis,
            self.inverse_projection.w_axis,
        );
        let z = depth * 2.0 - 1.0;
        ((c.z * z + d.z) / (c.w * z + d.w)).abs()
    }

    /// True if `object` is placed and seen exactly as in `other`: reprojecting it from `other`
    /// to `self` is the identity, and is done as one (f32 arithmetic would move it by an ulp).
    pub(super) fn unchanged(&self, other: &View, object: usize) -> bool {
        let (Some(Some(a)), Some(Some(b))) = (self.objects.get(object), other.objects.get(object))
        else {
            return false;
        };
        self.size() == other.size() && self.projection == other.projection && a == b
    }

    #[inline]
    pub(super) fn object(&self, id: ObjectId) -> Option<&ObjectView> {
        self.objects.get(id.0 as usize).and_then(Option::as_ref)
    }

    /// The colour of `surfel` of object `o` at eye-space position `eye` (strata's shared conventions shading).
    #[inline]
    fn shade(o: &ObjectView, surfel: &Surfel, eye: Vec3) -> Rgba8 {
        if !o.lit {
            return o.flat;
        }
        let n = o.normal * Vec3::from(surfel.normal);
        headlight_rgba(
            o.rgb,
            o.alpha,
            headlight_factor(n.to_array(), eye.to_array()),
        )
    }

    /// Eq. 5.9 and the viewport: the pixel `surfel` of `object` lands in and the fragment it
    /// shades to, or `None` if it leaves the view volume (or its object is unknown).
    #[inline]
    pub(super) fn project(&self, object: ObjectId, surfel: &Surfel) -> Option<(u32, Fragment)> {
        let o = self.object(object)?;
        let eye = o.model_view.transform_point3(Vec3::from(surfel.position));
        let c = self.projection * eye.extend(1.0);
        if c.w.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let iw = 1.0 / c.w;
        let (xn, yn, zn) = (c.x * iw, c.y * iw, c.z * iw);
        let x = (xn * 0.5 + 0.5) * self.width as f32;
        let y = (0.5 - yn * 0.5) * self.height as f32;
        let z = zn * 0.5 + 0.5;
        // Written so that NaN fails every test.
        if !(x >= 0.0 && x < self.width as f32 && y >= 0.0 && y < self.height as f32) {
            return None;
        }
        if !((0.0..=1.0).contains(&z)) {
            return None;
        }
        let (px, py) = (
            (x as u32).min(self.width - 1),
            (y as u32).min(self.height - 1),
        );
        let depth = if z > 0.0 { z } else { 0.0 };
        Some((
            py * self.width + px,
            Fragment {
                depth,
                color: Self::shade(o, surfel, eye),
                object,
            },
        ))
    }

    /// Eq. 5.10 once: the entry of the normal fragment `f` rendered at `pixel` in this view —
    /// its surfel in object space and its colour now. `None` if its object is unknown.
    #[inline]
    pub fn entry(&self, pixel: u32, f: Fragment) -> Option<Entry> {
        let o = self.object(f.object)?;
        let (px, py) = (pixel % self.width, pixel / self.width);
        let ndc = Vec4::new(
            (px as f32 + 0.5) / self.width as f32 * 2.0 - 1.0,
            1.0 - (py as f32 + 0.5) / self.height as f32 * 2.0,
            f.depth * 2.0 - 1.0,
            1.0,
        );
        let e = self.inverse_projection * ndc;
        let eye = e.truncate() / e.w;
        let normal = match PackedNormal::from_bits(f.color.to_bits()).unpack() {
            Some(n) if o.lit => o.to_object_normal * Vec3::from(n),
            _ => Vec3::ZERO,
        };
        let surfel = Surfel {
            position: o.inverse_model_view.transform_point3(eye).to_array(),
            normal: normal.to_array(),
        };
        Some(Entry {
            fragment: Fragment {
                depth: f.depth,
                color: Self::shade(o, &surfel, eye),
                object: f.object,
            },
            surfel,
        })
    }
}

impl View {
    /// Forward warping of a **colour** fragment (post-rendering 3D warping, Mark et al. 1997):
    /// `f`, seen at `pixel` in this view, moved to `to` — its surfel by eq. 5.10 here, projected
    /// by eq. 5.9 there — keeping its colour (the shading of this view: only the position moves).
    /// Where the object is placed and seen exactly as in `to`, the fragment stays bit for bit.
    /// `None` if it leaves `to`'s view volume or its object is unknown to either view.
    pub fn warp(&self, to: &View, pixel: u32, f: Fragment) -> Option<(u32, Fragment)> {
        if to.unchanged(self, f.object.0 as usize) {
            return Some((pixel, f));
        }
        // The entry's normal (from colour bits) and shading are not used: only its position.
        let surfel = self.entry(pixel, f)?.surfel;
        let (p, moved) = to.project(f.object, &surfel)?;
        Some((
            p,
            Fragment {
                color: f.color,
                ..moved
            },
        ))
    }
}

impl View {
    /// The colour fragments the normal fragments of `normals` (rendered at this view) shade to,
    /// runs sorted; fragments of unknown objects are left out.
    pub fn shade_frame(&self, normals: &DeepFrame) -> DeepFrame {
        let counts: Vec<u32> = (0..normals.offsets().len() - 1)
            .map(|p| {
                normals
                    .run(p)
                    .iter()
                    .filter(|f| self.object(f.object).is_some())
                    .count() as u32
            })
            .collect();
        DeepFrame::build(normals.width(), normals.height(), &counts, |p, out| {
            out.extend(
                normals
                    .run(p)
                    .iter()
                    .filter_map(|f| self.entry(p as u32, f).map(|e| e.fragment)),
            )
        })
        .unwrap_or_else(|_| DeepFrame::empty(normals.width(), normals.height()))
    }
}
