//! What a client renders: some of the scene's objects, posed as a snapshot says, seen through a
//! view, into a store that keeps every fragment, handed over as a DeepFrame.
//!
//! Both clients use this. The slow client renders the objects it is assigned at its snapshot's
//! view; the fast client renders the objects it draws at the view of the SC buffer it composites
//! with, so that the two DeepFrames' depths and shading agree to the bit (the headlight depends on
//! the eye) and merging their runs is exact.

use glam::Mat4;
use strata_core::DeepFrame;
use strata_raster::{DrawObject, FragmentOutput, FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::{Method, MethodOptions, StoreError};

use crate::authority::{Snapshot, ViewPose};

/// Why a client could not render.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    /// The fragment store failed (out of memory, or a frame it cannot hold).
    #[error("the slow/fast client's store failed: {0}")]
    Store(#[from] StoreError),
    /// The store keeps no fragments or exported an invalid frame.
    #[error("the store gave no valid DeepFrame: {0}")]
    DeepFrame(String),
    /// An object index is not in the scene.
    #[error("object {index} is not in the scene ({count} objects)")]
    NoSuchObject {
        /// The index asked for.
        index: usize,
        /// Objects in the scene.
        count: usize,
    },
}

/// One client's rasterizer and store, reused frame to frame.
pub struct Client {
    raster: Rasterizer,
    store: Box<dyn Method>,
    width: u32,
    height: u32,
}

impl Client {
    /// A client rendering `width × height` frames into a linked-list A-buffer with a growing
    /// pool: every fragment is kept, which exact composition needs.
    pub fn new(width: u32, height: u32) -> Self {
        let store = strata_stores::create("abuffer", &MethodOptions::default())
            .expect("the A-buffer is always registered");
        Client {
            raster: Rasterizer::default(),
            store,
            width,
            height,
        }
    }

    /// The projection every client uses for this scene and size.
    fn projection(&self, scene: &Scene) -> Mat4 {
        scene.camera.projection(self.width, self.height)
    }

    /// Renders the objects at `indices` (in scene order), posed as `snapshot` says, through
    /// `view`; returns every fragment as a DeepFrame.
    pub fn render(
        &mut self,
        scene: &Scene,
        snapshot: &Snapshot,
        view: &ViewPose,
        indices: &[usize],
    ) -> Result<DeepFrame, ClientError> {
        let count = scene.objects.len();
        let mut objects = Vec::with_capacity(indices.len());
        for &index in indices {
            let o = scene
                .objects
                .get(index)
                .ok_or(ClientError::NoSuchObject { index, count })?;
            objects.push(DrawObject {
                positions: o.mesh.positions(),
                normals: o.mesh.normals(),
                triangles: o.mesh.triangles(),
                model: snapshot.model(scene, index),
                material: o.material,
                id: o.id,
            });
        }
        let input = FrameInput {
            width: self.width,
            height: self.height,
            view: view.matrix(),
            projection: self.projection(scene),
            background: scene.background,
            objects,
            output: FragmentOutput::Shaded,
        };
        strata_stores::render_frame(
            self.store.as_mut(),
            &mut self.raster,
            &input,
            scene.background,
        )?;
        match self.store.deep_frame() {
            Some(Ok(frame)) => Ok(frame),
            Some(Err(e)) => Err(ClientError::DeepFrame(e.to_string())),
            None => Err(ClientError::DeepFrame(
                "the store keeps no fragments".into(),
            )),
        }
    }
}
