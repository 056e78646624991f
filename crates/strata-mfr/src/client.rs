//! What a client renders: some of the scene's objects, posed as a snapshot says, seen through a
//! view, into a store that keeps every fragment, handed over as a DeepFrame.
//!
//! Both clients use this. The slow client renders the objects it is assigned at its snapshot's
//! view; the fast client renders the objects it draws at the view of the SC buffer it composites
//! with, so that the two DeepFrames' depths and shading agree to the bit (the headlight depends on
//! the eye) and merging their runs is exact.

use glam::{Mat4, Vec3};
use strata_core::{DeepFrame, PixelRect};
use strata_raster::{DrawObject, FragmentOutput, FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::abuffer::linked_list::LinkedListABuffer;
use strata_stores::{Method, PoolCapacity, StoreError};

use crate::authority::{Snapshot, ViewPose};
use crate::window::DeepWindow;

/// Pixels added around a footprint's projected box (rounding, and the rasterizer's fill rule).
const FOOTPRINT_MARGIN: f32 = 2.0;

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
    store: LinkedListABuffer,
    width: u32,
    height: u32,
    output: FragmentOutput,
}

impl Client {
    /// A client rendering `width × height` frames into a linked-list A-buffer with a growing
    /// pool: every fragment is kept, which exact composition needs.
    pub fn new(width: u32, height: u32) -> Self {
        Client {
            raster: Rasterizer::default(),
            store: LinkedListABuffer::new(PoolCapacity::Auto),
            width,
            height,
            output: FragmentOutput::Shaded,
        }
    }

    /// The same client, making fragments of `output`: [`FragmentOutput::PackedNormal`] gives the
    /// normal fragments of a deep G-buffer ([`crate::deferred`]).
    pub fn with_output(mut self, output: FragmentOutput) -> Self {
        self.output = output;
        self
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
        self.capture(scene, snapshot, view, indices)?;
        self.export()
    }

    /// Empties the store for a frame captured in parts with [`Client::capture_part`].
    pub fn begin_parts(&mut self) -> Result<(), ClientError> {
        Ok(self.store.clear(self.width, self.height)?)
    }

    /// Adds `part` (a chunk of [`Client::frame_input`], see
    /// [`FrameInput::triangle_range`]) to what the store holds since [`Client::begin_parts`]:
    /// the store's captures accumulate, so the parts give the frame one capture would.
    pub fn capture_part(&mut self, part: &FrameInput<'_>) -> Result<(), ClientError> {
        let mut timings = strata_core::PassTimings::new();
        self.store.capture(&mut self.raster, part, &mut timings)?;
        Ok(())
    }

    /// Everything the store holds, as a DeepFrame.
    pub fn export(&self) -> Result<DeepFrame, ClientError> {
        match self.store.deep_frame() {
            Some(Ok(frame)) => Ok(frame),
            Some(Err(e)) => Err(ClientError::DeepFrame(e.to_string())),
            None => Err(ClientError::DeepFrame(
                "the store keeps no fragments".into(),
            )),
        }
    }

    /// The rows `rows` of what the store holds, as a DeepFrame of the band's size: one band of
    /// an export in bands, which appended in order ([`DeepFrame::append_rows`]) give
    /// [`Client::export`]'s frame.
    pub fn export_rows(&self, rows: std::ops::Range<u32>) -> Result<DeepFrame, ClientError> {
        let (start, end) = (rows.start, rows.end);
        match self.store.deep_frame_rows(rows) {
            Some(frame) => frame.map_err(|e| ClientError::DeepFrame(e.to_string())),
            None => Err(ClientError::DeepFrame(format!(
                "rows {start}..{end} are not inside the {}x{} frame",
                self.width, self.height
            ))),
        }
    }

    /// The frame size, `(width, height)`.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Like [`Client::render`], keeping only the rectangle the objects' projected bounding boxes
    /// cover — what the fast client hands to composition, at a cost that follows its footprint.
    /// Exact: when a fragment falls outside the guessed rectangle (an object behind the eye, or
    /// crossing the near plane), the whole frame is kept.
    pub fn render_footprint(
        &mut self,
        scene: &Scene,
        snapshot: &Snapshot,
        view: &ViewPose,
        indices: &[usize],
    ) -> Result<DeepWindow, ClientError> {
        self.capture(scene, snapshot, view, indices)?;
        let to_client = |e: strata_core::DeepFrameError| ClientError::DeepFrame(e.to_string());
        let size = (self.width, self.height);
        if let Some(rect) = self.footprint(scene, snapshot, view, indices)
            && let Some(window) = self.store.deep_frame_in(rect)
        {
            return DeepWindow::new(rect, size, window.map_err(to_client)?).map_err(to_client);
        }
        let whole = PixelRect::full(self.width, self.height);
        match self.store.deep_frame_in(whole) {
            Some(frame) => {
                Ok(DeepWindow::new(whole, size, frame.map_err(to_client)?).map_err(to_client)?)
            }
            None => Err(ClientError::DeepFrame(
                "the store holds fragments outside the frame".into(),
            )),
        }
    }

    /// The pixel rectangle the objects' world bounding boxes project to, with a margin; `None`
    /// when a box reaches behind the eye (its projection is unbounded).
    fn footprint(
        &self,
        scene: &Scene,
        snapshot: &Snapshot,
        view: &ViewPose,
        indices: &[usize],
    ) -> Option<PixelRect> {
        let clip = self.projection(scene) * view.matrix();
        let mut corners = Vec::with_capacity(8 * indices.len());
        for &i in indices {
            let b = scene.objects.get(i)?.mesh.bounds();
            if b.is_empty() {
                continue;
            }
            let to_clip = clip * snapshot.model(scene, i);
            corners.extend((0..8).map(|k| {
                let corner = Vec3::new(
                    if k & 1 == 0 { b.min.x } else { b.max.x },
                    if k & 2 == 0 { b.min.y } else { b.max.y },
                    if k & 4 == 0 { b.min.z } else { b.max.z },
                );
                (to_clip * corner.extend(1.0)).to_array()
            }));
        }
        PixelRect::around_clip_points(corners, self.width, self.height, FOOTPRINT_MARGIN)
    }

    /// Rasterises the objects at `indices` into the store.
    fn capture(
        &mut self,
        scene: &Scene,
        snapshot: &Snapshot,
        view: &ViewPose,
        indices: &[usize],
    ) -> Result<(), ClientError> {
        let input = self.frame_input(scene, snapshot, view, indices)?;
        // Clear and capture only: the store's own resolve would composite every pixel, and a
        // client hands over fragments (the FC re-resolves only its footprint).
        self.begin_parts()?;
        self.capture_part(&input)
    }

    /// What the rasterizer draws for the objects at `indices`, posed as `snapshot` says, seen
    /// through `view`.
    pub fn frame_input<'s>(
        &self,
        scene: &'s Scene,
        snapshot: &Snapshot,
        view: &ViewPose,
        indices: &[usize],
    ) -> Result<FrameInput<'s>, ClientError> {
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
        Ok(FrameInput {
            width: self.width,
            height: self.height,
            view: view.matrix(),
            projection: self.projection(scene),
            background: scene.background,
            objects,
            output: self.output,
        })
    }
}
