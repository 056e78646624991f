//! Slow and fast clients on a virtual clock: rendering is real, time is simulated, so every run is
//! reproducible and any SC:FC ratio can be tested on any machine.
//!
//! # Timeline
//!
//! ```text
//! SC:  start s0=0 ──render── s1=sc_ms ──render── s2 …      each start takes the newest snapshot
//!                    └─ delivered at s0 + sc_ms + transfer_ms (then latest wins)
//! FC:  t = 0, fc_ms, 2·fc_ms …  newest snapshot + newest delivered SC buffer → compose
//! ```
//!
//! The authority is advanced in time order across both clients. At an SC start the SC renders
//! the objects its migration policy leaves it (naive: all but the SELECTED; predictive: all but
//! the OVER and SELECTED) at that snapshot. At an FC tick the FC decides which objects it draws,
//! `F`, renders them at the current snapshot through the SC buffer's view and composes
//! ([`crate::compose::compose_deep`]):
//!
//! - **predictive** (Springer 2008 §6.1, Table 6.1, plus versions): `F` = every object not
//!   INACTIVE, and every object the SC buffer does not hold at its current version;
//! - **naive**: `F` = the SELECTED objects — so an object released before an SC buffer holds it
//!   again is missing (a *hole*), and one moved while the SC buffer still shows it elsewhere is
//!   drawn twice (a *ghost*) unless the SC buffer is deep and its copy is dropped, as here.
//!
//! Before the first SC buffer arrives the FC draws every object itself.

use std::sync::Arc;

use strata_core::{DeepFrame, ObjectId};
use strata_scene::Scene;

use crate::authority::{Authority, Snapshot};
use crate::client::{Client, ClientError};
use crate::compose::{
    Composition, compose_deep, compose_digital, compose_image, compose_optical,
    compose_optical_image,
};
use crate::state::ObjectState;
use crate::trace::Trace;
use crate::transfer::TransferBuffer;
use crate::window::DeepWindow;

/// How objects move between the clients.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Migration {
    /// The SC drops an object when it is selected and takes it back when it is released; the FC
    /// draws the selected objects only.
    Naive,
    /// Pre-selection (OVER) hands objects over early; the FC follows Table 6.1 with versions.
    Predictive,
}

/// The simulated periods (milliseconds).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VirtualClock {
    /// Time the SC takes for a frame.
    pub sc_ms: f64,
    /// Time between FC frames.
    pub fc_ms: f64,
    /// Time from an SC frame's end until the FC can use it.
    pub transfer_ms: f64,
}

/// One FC frame of a run.
#[derive(Clone, Debug)]
pub struct FcFrame {
    /// FC frame number.
    pub index: u64,
    /// Its time (ms).
    pub t_ms: f64,
    /// The snapshot it shows.
    pub snapshot: Arc<Snapshot>,
    /// The SC buffer it composed with (`None` before the first arrived).
    pub sc: Option<Arc<TransferBuffer>>,
    /// Indices of the objects the FC drew.
    pub fc_objects: Vec<usize>,
    /// Their ids, sorted.
    pub fc_ids: Vec<ObjectId>,
    /// The FC's own fragments, in the rectangle its objects cover.
    pub fc: DeepWindow,
    /// How it composed.
    pub composition: Composition,
    /// The frame shown.
    pub image: strata_core::Rgb8Image,
    /// With warping ([`crate::warp`]): what warping the SC buffer to this frame's view did (`sc`
    /// is then the warped buffer).
    pub warp: Option<Arc<crate::warp::WarpInfo>>,
}

impl FcFrame {
    /// The composed fragments of this frame (what its image resolves): rebuilt from the SC
    /// buffer and the FC's fragments, for the audit and for saving — the FC itself only makes the
    /// image.
    pub fn composed(&self) -> Result<DeepFrame, strata_core::DeepFrameError> {
        match (&self.sc, self.composition) {
            (None, _) => self.fc.to_full(),
            (Some(sc), Composition::Deep) => {
                compose_deep(&sc.frame, &self.fc.to_full()?, &self.fc_ids)
            }
            (Some(sc), Composition::Digital) => compose_digital(&sc.frame, &self.fc.to_full()?),
            (Some(sc), Composition::Optical) => compose_optical(&sc.frame, &self.fc.to_full()?),
        }
    }
}

/// The FC's work for one frame: which objects it draws, its fragments, and the image shown.
pub(crate) struct FcWork {
    pub(crate) fc_objects: Vec<usize>,
    pub(crate) fc_ids: Vec<ObjectId>,
    pub(crate) fc: DeepWindow,
    pub(crate) image: strata_core::Rgb8Image,
}

impl FcWork {
    /// The frame record of this work.
    pub(crate) fn into_frame(
        self,
        index: u64,
        t_ms: f64,
        snapshot: Arc<Snapshot>,
        sc: Option<Arc<TransferBuffer>>,
        composition: Composition,
    ) -> FcFrame {
        FcFrame {
            index,
            t_ms,
            snapshot,
            sc,
            fc_objects: self.fc_objects,
            fc_ids: self.fc_ids,
            fc: self.fc,
            composition,
            image: self.image,
            warp: None,
        }
    }
}

/// Renders the FC's objects at `snapshot` through the SC buffer's view and makes the image.
pub(crate) fn fc_frame(
    scene: &Scene,
    client: &mut Client,
    snapshot: &Snapshot,
    sc: Option<&TransferBuffer>,
    migration: Migration,
    composition: Composition,
) -> Result<FcWork, SimulateError> {
    let fc_objects = fc_draws(scene, snapshot, sc, migration);
    let mut fc_ids: Vec<ObjectId> = fc_objects.iter().map(|&i| scene.objects[i].id).collect();
    fc_ids.sort_unstable();
    let view = sc.map_or(snapshot.view, |sc| sc.view);
    let fc = client.render_footprint(scene, snapshot, &view, &fc_objects)?;
    let image = match (sc, composition) {
        (None, _) => fc.resolve(scene.background),
        (Some(sc), Composition::Deep) => {
            let holds = fc_ids
                .iter()
                .any(|id| sc.rendered.binary_search_by_key(id, |&(i, _)| i).is_ok());
            compose_image(&sc.frame, &sc.image, &fc, &fc_ids, holds, scene.background)
        }
        (Some(sc), Composition::Digital) => {
            compose_digital(&sc.frame, &fc.to_full()?)?.resolve(scene.background)
        }
        (Some(sc), Composition::Optical) => {
            compose_optical_image(&sc.frame, &sc.image, &fc, scene.background)
        }
    };
    Ok(FcWork {
        fc_objects,
        fc_ids,
        fc,
        image,
    })
}

/// Why a run stopped.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimulateError {
    /// A client could not render.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// Composition failed.
    #[error("cannot compose: {0}")]
    Compose(#[from] strata_core::DeepFrameError),
    /// The clock's periods are not positive, finite numbers.
    #[error("sc_ms, fc_ms must be more than 0 and transfer_ms 0 or more (got {0:?})")]
    Clock(VirtualClock),
    /// A real-time FC rate outside (0, 1000] Hz.
    #[error("fc_hz {0} must be more than 0 and at most 1000")]
    Rate(f64),
    /// A client thread could not start, or panicked.
    #[error("client thread: {0}")]
    Thread(String),
    /// The TCP slow client could not be reached, or refused the handshake.
    #[error(transparent)]
    Tcp(Box<crate::tcp::TcpError>),
}

impl From<crate::tcp::TcpError> for SimulateError {
    fn from(e: crate::tcp::TcpError) -> Self {
        SimulateError::Tcp(Box::new(e))
    }
}

/// Runs `fc_frames` FC frames of `trace` on `scene` at `width × height`, composing with
/// `composition`; calls `on_frame` with each as it is composed.
#[allow(
    clippy::too_many_arguments,
    reason = "the run's parameters, each documented"
)]
pub fn run_virtual(
    scene: &Scene,
    trace: Trace,
    clock: VirtualClock,
    migration: Migration,
    composition: Composition,
    (width, height): (u32, u32),
    fc_frames: u64,
    on_frame: impl FnMut(&FcFrame),
) -> Result<(), SimulateError> {
    run_clients(
        scene,
        trace,
        clock,
        (migration, composition),
        (width, height),
        fc_frames,
        false,
        on_frame,
    )
}

/// [`run_virtual`], with `warp`: each FC frame warps the SC buffer to its own view first.
#[allow(
    clippy::too_many_arguments,
    reason = "the run's parameters, each documented"
)]
pub(crate) fn run_clients(
    scene: &Scene,
    trace: Trace,
    clock: VirtualClock,
    (migration, composition): (Migration, Composition),
    (width, height): (u32, u32),
    fc_frames: u64,
    warp: bool,
    mut on_frame: impl FnMut(&FcFrame),
) -> Result<(), SimulateError> {
    let mut timeline = VirtualTimeline::new(clock)?;
    let mut authority = Authority::new(scene, trace);
    let (mut sc_client, mut fc_client) = (Client::new(width, height), Client::new(width, height));
    for index in 0..fc_frames {
        let t = index as f64 * clock.fc_ms;
        let delivered = timeline.tick(t, |start_ms, sc_frame| {
            let snapshot = authority.advance_to(start_ms);
            sc_render(scene, &mut sc_client, &snapshot, migration, sc_frame)
        })?;
        let snapshot = authority.advance_to(t);
        let (shown, warped) = match &delivered {
            Some(sc) if warp => {
                let (buffer, info) = crate::warp::warp_buffer(scene, sc, &snapshot.view)?;
                (Some(Arc::new(buffer)), Some(Arc::new(info)))
            }
            _ => (delivered.clone(), None),
        };
        let work = fc_frame(
            scene,
            &mut fc_client,
            &snapshot,
            shown.as_deref(),
            migration,
            composition,
        )?;
        let mut frame = work.into_frame(index, t, snapshot, shown, composition);
        frame.warp = warped;
        on_frame(&frame);
    }
    Ok(())
}

/// The virtual clock's schedule: the SC starts a frame every `sc_ms` with the newest snapshot,
/// its buffer is usable `sc_ms + transfer_ms` later, and at each FC tick the newest buffer
/// delivered by then wins. Shared by every virtual-clock run (plain, warped, deferred).
pub(crate) struct VirtualTimeline {
    clock: VirtualClock,
    next_sc_start: f64,
    sc_frame: u64,
    /// Buffers rendered but not yet delivered: (delivery time, buffer), in delivery order.
    in_flight: std::collections::VecDeque<(f64, Arc<TransferBuffer>)>,
    delivered: Option<Arc<TransferBuffer>>,
}

impl VirtualTimeline {
    /// The schedule of `clock`, whose periods must be positive and finite (transfer 0 or more).
    pub(crate) fn new(clock: VirtualClock) -> Result<Self, SimulateError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !(ok(clock.sc_ms)
            && ok(clock.fc_ms)
            && clock.transfer_ms.is_finite()
            && clock.transfer_ms >= 0.0)
        {
            return Err(SimulateError::Clock(clock));
        }
        Ok(VirtualTimeline {
            clock,
            next_sc_start: 0.0,
            sc_frame: 0,
            in_flight: std::collections::VecDeque::new(),
            delivered: None,
        })
    }

    /// Moves to FC tick `t_ms`: renders, in time order, every SC frame that starts by then
    /// (`render(start_ms, sc_frame)`), and returns the newest buffer delivered by then.
    pub(crate) fn tick<E>(
        &mut self,
        t_ms: f64,
        mut render: impl FnMut(f64, u64) -> Result<TransferBuffer, E>,
    ) -> Result<Option<Arc<TransferBuffer>>, E> {
        while self.next_sc_start <= t_ms {
            let buffer = render(self.next_sc_start, self.sc_frame)?;
            let at = self.next_sc_start + self.clock.sc_ms + self.clock.transfer_ms;
            self.in_flight.push_back((at, Arc::new(buffer)));
            self.sc_frame += 1;
            self.next_sc_start += self.clock.sc_ms;
        }
        while self.in_flight.front().is_some_and(|(at, _)| *at <= t_ms) {
            self.delivered = self.in_flight.pop_front().map(|(_, b)| b);
        }
        Ok(self.delivered.clone())
    }
}

/// The SC's frame: the objects its policy leaves it, at `snapshot`.
pub(crate) fn sc_render(
    scene: &Scene,
    client: &mut Client,
    snapshot: &Snapshot,
    migration: Migration,
    sc_frame: u64,
) -> Result<TransferBuffer, SimulateError> {
    let (rendered, excluded, indices) = sc_share(snapshot, migration);
    let frame = client.render(scene, snapshot, &snapshot.view, &indices)?;
    let image = frame.resolve(scene.background);
    Ok(TransferBuffer {
        sc_frame,
        snapshot_id: snapshot.id,
        snapshot_t_ms: snapshot.t_ms,
        view: snapshot.view,
        rendered,
        excluded,
        frame,
        image,
    })
}

/// The objects `migration` leaves the SC at `snapshot`: (id, version) of those it renders and
/// the ids of those it leaves out, both sorted, and the indices it renders in scene order.
pub(crate) fn sc_share(
    snapshot: &Snapshot,
    migration: Migration,
) -> (Vec<(ObjectId, u64)>, Vec<ObjectId>, Vec<usize>) {
    let keeps = |state: ObjectState| match migration {
        Migration::Naive => state != ObjectState::Selected,
        Migration::Predictive => state == ObjectState::Inactive,
    };
    let (mut rendered, mut excluded, mut indices) = (Vec::new(), Vec::new(), Vec::new());
    for (i, pose) in snapshot.objects.iter().enumerate() {
        if keeps(pose.state) {
            rendered.push((pose.id, pose.version));
            indices.push(i);
        } else {
            excluded.push(pose.id);
        }
    }
    rendered.sort_unstable();
    excluded.sort_unstable();
    (rendered, excluded, indices)
}

/// The objects the FC draws (indices, scene order).
pub(crate) fn fc_draws(
    scene: &Scene,
    snapshot: &Snapshot,
    sc: Option<&TransferBuffer>,
    migration: Migration,
) -> Vec<usize> {
    let Some(sc) = sc else {
        return (0..scene.objects.len()).collect();
    };
    snapshot
        .objects
        .iter()
        .enumerate()
        .filter(|(_, o)| match migration {
            Migration::Naive => o.state == ObjectState::Selected,
            Migration::Predictive => {
                crate::state::fc_renders(o.state, sc.contains(o.id, o.version))
            }
        })
        .map(|(i, _)| i)
        .collect()
}
