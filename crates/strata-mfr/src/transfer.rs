//! The transfer buffer: what the slow client hands the fast client (Springer 2008 §4.3), and the
//! triple buffer it travels through (§8.1).
//!
//! # The transfer buffer
//!
//! ```text
//! TransferBuffer ── sc_frame      the SC's frame counter
//!                ── snapshot_id   the state snapshot it rendered (view, transforms, versions)
//!                ── view          the camera the SC rendered with (size: the frame's)
//!                ── rendered      (object id, version) of every object the SC rendered, sorted
//!                ── excluded      ids of the objects it left out, sorted (the seed's list)
//!                ── frame         the DeepFrame of what it rendered
//!                └─ image         that frame resolved (the FC's starting image)
//! ```
//!
//! The seed's buffer carried a frame counter, the view, the sizes, a buffer id and the ids of the
//! objects left out. strata adds the snapshot id (for latency and audit) and the *versions* of
//! the objects rendered, so the FC can tell an object the buffer shows where it is from one it
//! shows at an old place ([`TransferBuffer::contains`]).
//!
//! # The triple buffer
//!
//! [`exchange`] makes a single-producer, single-consumer triple buffer of `Arc`s (the maintained
//! `triple_buffer` crate): publishing and reading are wait-free, the reader always gets the newest
//! complete value (latest wins, older ones are skipped) and never a torn one, and handing over a
//! frame moves a pointer, never the frame.

use std::sync::Arc;

use strata_core::{DeepFrame, ObjectId, Rgb8Image};

/// What the slow client hands over with each frame.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferBuffer {
    /// The slow client's frame counter.
    pub sc_frame: u64,
    /// The snapshot it rendered.
    pub snapshot_id: u64,
    /// That snapshot's time (ms): the buffer's age at an FC frame is that frame's time minus this.
    pub snapshot_t_ms: f64,
    /// The camera of that snapshot (the FC renders through it to compose exactly). The size is
    /// the frame's; the projection is the scene camera's at that size.
    pub view: crate::authority::ViewPose,
    /// `(id, version)` of every object rendered, sorted by id.
    pub rendered: Vec<(ObjectId, u64)>,
    /// Ids of the objects left out, sorted.
    pub excluded: Vec<ObjectId>,
    /// Every fragment of the objects rendered.
    pub frame: DeepFrame,
    /// `frame` resolved onto the scene's background: the FC starts every frame from it.
    pub image: Rgb8Image,
}

impl TransferBuffer {
    /// True if the buffer holds object `id` at `version` — contained in the sense of Table 6.1,
    /// and where the FC's snapshot puts it.
    pub fn contains(&self, id: ObjectId, version: u64) -> bool {
        self.rendered
            .binary_search_by_key(&id, |&(i, _)| i)
            .is_ok_and(|k| self.rendered[k].1 == version)
    }
}

/// The writing end of a triple buffer of `Arc<T>`.
pub struct Publisher<T: Send + Sync> {
    input: triple_buffer::Input<Option<Arc<T>>>,
}

/// The reading end: the newest value published so far.
pub struct Latest<T: Send + Sync> {
    output: triple_buffer::Output<Option<Arc<T>>>,
}

/// A wait-free single-producer, single-consumer exchange of `Arc<T>`, initially empty.
pub fn exchange<T: Send + Sync>() -> (Publisher<T>, Latest<T>) {
    let (input, output) = triple_buffer::triple_buffer(&None);
    (Publisher { input }, Latest { output })
}

impl<T: Send + Sync> Publisher<T> {
    /// Publishes `value`; the reader's next [`Latest::latest`] returns it unless a newer one is
    /// published first. Never blocks. Returns the value the slot held before (one the reader no
    /// longer uses), so the caller chooses when to drop it: freeing a large frame takes far longer
    /// than the hand-over itself.
    #[must_use = "the old value is dropped where the caller drops it; bind it to time the swap alone"]
    pub fn publish(&mut self, value: Arc<T>) -> Option<Arc<T>> {
        let old = self.input.input_buffer_mut().replace(value);
        self.input.publish();
        old
    }
}

impl<T: Send + Sync> Latest<T> {
    /// The newest value published, or `None` before the first. Never blocks.
    pub fn latest(&mut self) -> Option<&Arc<T>> {
        self.output.read().as_ref()
    }

    /// True if something newer than what [`Latest::latest`] last returned has been published.
    pub fn updated(&self) -> bool {
        self.output.updated()
    }
}
