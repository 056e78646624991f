//! What one frame draws: the objects' geometry, placement and material, and the camera.

use glam::Mat4;
use strata_core::{Material, ObjectId};
use strata_scene::Scene;

/// One object to draw: borrowed geometry plus its per-frame placement.
#[derive(Clone, Copy, Debug)]
pub struct DrawObject<'a> {
    /// Object-space positions.
    pub positions: &'a [[f32; 3]],
    /// Per-vertex normals, one per position.
    pub normals: &'a [[f32; 3]],
    /// Triangles; every index must be `< positions.len()` (a validated [`strata_scene::Mesh`]
    /// guarantees it).
    pub triangles: &'a [[u32; 3]],
    /// Object → world.
    pub model: Mat4,
    /// Colour and shading.
    pub material: Material,
    /// The id its fragments carry.
    pub id: ObjectId,
}

/// Everything the rasterizer needs for one frame.
#[derive(Clone, Debug)]
pub struct FrameInput<'a> {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// World → eye.
    pub view: Mat4,
    /// Eye → clip (OpenGL convention).
    pub projection: Mat4,
    /// The opaque background the frame is resolved onto, RGB in `[0, 1]`. The rasterizer does not
    /// read it; stores whose capture depends on the final colours (the Optimal-K oracle) do.
    pub background: [f32; 3],
    /// The objects, in draw order.
    pub objects: Vec<DrawObject<'a>>,
    /// What the fragments' colour bytes hold.
    pub output: FragmentOutput,
}

/// What the four colour bytes of the rasterizer's fragments hold.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum FragmentOutput {
    /// The shaded colour (strata's shared conventions: headlight or unlit, RGBA8).
    #[default]
    Shaded,
    /// Normal fragments (Jähne 2014 §2.1): the perspective-correctly interpolated eye-space normal
    /// of lit objects as a [`strata_core::PackedNormal`]; unlit objects give
    /// [`strata_core::PackedNormal::NONE`]. Depth and object are as for shaded fragments, so the
    /// eye-space position is the unprojection of the pixel centre at the fragment's depth, and a
    /// receiver that knows the materials can shade the fragment exactly as the rasterizer would.
    PackedNormal,
}

impl<'a> FrameInput<'a> {
    /// The scene posed at animation frame `frame` (frames beyond the animation keep turning).
    pub fn from_scene(scene: &'a Scene, frame: u32) -> Self {
        let objects = scene
            .objects
            .iter()
            .map(|o| DrawObject {
                positions: o.mesh.positions(),
                normals: o.mesh.normals(),
                triangles: o.mesh.triangles(),
                model: o.model_matrix(scene.animation.as_ref(), frame),
                material: o.material,
                id: o.id,
            })
            .collect();
        FrameInput {
            width: scene.width,
            height: scene.height,
            view: scene.camera.view(),
            projection: scene.camera.projection(scene.width, scene.height),
            background: scene.background,
            objects,
            output: FragmentOutput::Shaded,
        }
    }

    /// Triangles over all objects.
    pub fn triangle_count(&self) -> u64 {
        self.objects.iter().map(|o| o.triangles.len() as u64).sum()
    }

    /// Pixels in the image.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The same frame drawing only the triangles whose index in the whole frame — objects in
    /// order, each object's triangles in order — falls in `range`: one chunk of the geometry, for
    /// a store that captures a frame over several calls. Objects with no triangle in the range
    /// are left out; the others keep their geometry, placement and id, so the fragments of the
    /// chunks together are exactly those of the whole frame.
    pub fn triangle_range(&self, range: std::ops::Range<u64>) -> FrameInput<'a> {
        let mut objects = Vec::new();
        let mut first = 0u64;
        for o in &self.objects {
            let n = o.triangles.len() as u64;
            let (lo, hi) = (range.start.max(first), range.end.min(first + n));
            if lo < hi {
                objects.push(DrawObject {
                    triangles: &o.triangles[(lo - first) as usize..(hi - first) as usize],
                    ..*o
                });
            }
            first += n;
        }
        FrameInput {
            width: self.width,
            height: self.height,
            view: self.view,
            projection: self.projection,
            background: self.background,
            objects,
            output: self.output,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_ranges_partition_the_frame() {
        let scene = strata_scene::open_scene("mixed", &strata_scene::SearchPath::default())
            .expect("built-in scene");
        let input = FrameInput::from_scene(&scene, 0);
        let total = input.triangle_count();
        assert!(total > 10);
        let cut = [0, 3, total / 2, total - 1, total];
        let mut seen = Vec::new();
        for w in cut.windows(2) {
            let part = input.triangle_range(w[0]..w[1]);
            assert_eq!(part.triangle_count(), w[1] - w[0]);
            for o in &part.objects {
                seen.extend(o.triangles.iter().map(|t| (o.id, *t)));
            }
        }
        let all: Vec<_> = input
            .objects
            .iter()
            .flat_map(|o| o.triangles.iter().map(|t| (o.id, *t)))
            .collect();
        assert_eq!(seen, all);
        assert!(input.triangle_range(total..total + 5).objects.is_empty());
    }
}
