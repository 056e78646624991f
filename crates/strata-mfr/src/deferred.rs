//! MFR deferred shading (Springer 2008 §7.1): the slow client renders a deep G-buffer, the fast
//! client lights it with the current lights at its own rate.
//!
//! ```text
//! SC: normal fragments of its objects ─► deep G-buffer (DeepFrame: per pixel, every fragment's
//!     (Client in PackedNormal mode)       window depth f32, packed normal u32, object id u32)
//! FC: normal fragments of its objects ─┐
//!                                      ├─ compose_deep (the SC's stale copies of FC objects dropped)
//!     current lights ──► Shader ───────┴─► shaded DeepFrame ─► resolve ─► image
//! ```
//!
//! The G-buffer holds every fragment of every pixel, translucent layers included, so a moving
//! light lights them all; the seed's holds one opaque surface per pixel. The material is not
//! transferred: the object id indexes the palette ([`crate::lighting::Shader`]). Both clients'
//! fragments go through the same shader after composition (the seed's "unified lighting
//! shader"), so the result equals the whole scene's normal fragments shaded at once, bit for
//! bit. Size: 4 bytes of offset per pixel plus 12 bytes per fragment (the seed: 16 bytes per
//! pixel, one surface).

use std::sync::Arc;
use std::time::Instant;

use strata_core::{DeepFrame, ObjectId, Rgb8Image};
use strata_raster::FragmentOutput;
use strata_scene::Scene;

use crate::authority::{Authority, Snapshot};
use crate::client::{Client, ClientError};
use crate::compose::compose_deep;
use crate::lighting::{LightingError, LightingModel, PointLight, Shader};
use crate::simulate::{
    Migration, SimulateError, VirtualClock, VirtualTimeline, fc_draws, sc_render,
};
use crate::timeline::{FrameRecord, latency};
use crate::trace::{Event, Trace};
use crate::transfer::TransferBuffer;

/// Bytes one pixel's run offset takes in a DeepFrame.
pub const OFFSET_BYTES: u64 = 4;
/// Bytes one normal fragment takes (depth, packed normal, object id).
pub const FRAGMENT_BYTES: u64 = 12;

/// Why a deferred frame failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DeferredError {
    /// The two clients' G-buffers could not be composed.
    #[error("the slow and fast clients' G-buffers do not compose: {0}")]
    Compose(#[from] strata_core::DeepFrameError),
    /// Shading failed.
    #[error(transparent)]
    Lighting(#[from] LightingError),
    /// A client could not render.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// The run could not go on.
    #[error(transparent)]
    Run(#[from] SimulateError),
    /// The trace keys no light.
    #[error("the trace has no `light` events: deferred shading needs at least one light")]
    NoLights,
}

/// The FC's deferred frame: the SC's G-buffer `sc` minus the objects in `fc_objects` (sorted
/// ids), merged with the FC's normal fragments `fc`, every fragment that can show shaded by
/// `shader` ([`Shader::shade_shown`]: those behind a pixel's first opaque fragment are dropped).
///
/// # Errors
/// When the frames differ in size or hold an object the shader does not know.
pub fn deferred_frame(
    sc: &DeepFrame,
    fc: &DeepFrame,
    fc_objects: &[ObjectId],
    shader: &Shader,
) -> Result<DeepFrame, DeferredError> {
    let normals = compose_deep(sc, fc, fc_objects)?;
    Ok(shader.shade_shown(&normals)?)
}

/// [`deferred_frame`] resolved onto `background`.
///
/// # Errors
/// As [`deferred_frame`].
pub fn deferred_image(
    sc: &DeepFrame,
    fc: &DeepFrame,
    fc_objects: &[ObjectId],
    shader: &Shader,
    background: [f32; 3],
) -> Result<Rgb8Image, DeferredError> {
    Ok(deferred_frame(sc, fc, fc_objects, shader)?.resolve(background))
}

/// Bytes of a deep G-buffer holding `fragments` fragments over `pixels` pixels.
pub fn gbuffer_bytes(pixels: u64, fragments: u64) -> u64 {
    pixels * OFFSET_BYTES + fragments * FRAGMENT_BYTES
}

/// One FC frame of a deferred run.
#[derive(Clone, Debug)]
pub struct DeferredFrame {
    /// FC frame number, from 0.
    pub index: u64,
    /// Its time on the virtual clock (ms).
    pub t_ms: f64,
    /// The state it shows.
    pub snapshot: Arc<Snapshot>,
    /// The SC G-buffer it composed with (`None` before the first arrives).
    pub sc: Option<Arc<TransferBuffer>>,
    /// The objects the FC drew, as sorted ids.
    pub fc_ids: Vec<ObjectId>,
    /// The lights it was lit with (world space).
    pub lights: Vec<PointLight>,
    /// The shader it was lit with (the view of the SC buffer, or the snapshot's before one).
    pub shader: Shader,
    /// The lit fragments.
    pub shaded: DeepFrame,
    /// The image shown.
    pub image: Rgb8Image,
    /// Wall-clock milliseconds the FC spent composing, lighting and resolving.
    pub fc_shading_ms: f64,
    /// Of those, composing the two G-buffers (0 before the first SC buffer).
    pub fc_compose_ms: f64,
    /// Of those, lighting.
    pub fc_light_ms: f64,
}

/// Wall-clock cost of the SC's G-buffer frames of a deferred run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScCost {
    /// SC frames rendered.
    pub frames: u64,
    /// Their total wall-clock time (ms).
    pub total_ms: f64,
    /// Fragments in the largest G-buffer.
    pub max_fragments: u64,
}

/// Where the lights are applied.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ShadeOn {
    /// Deferred shading: the SC sends its deep G-buffer, the FC lights every fragment with the
    /// lights of its own frame time, so lights move at the FC's rate.
    #[default]
    Fc,
    /// Forward, for comparison: the SC lights its G-buffer with the lights of the state it
    /// renders and sends lit fragments; the FC lights only its own objects' fragments, with the
    /// current lights, and composes. Lights on the SC's objects move at the SC's rate.
    Sc,
}

/// The lights of `snapshot` (those the trace keyed at or before its time).
fn snapshot_lights(snapshot: &Snapshot) -> Vec<PointLight> {
    snapshot.lights.iter().map(|l| l.light).collect()
}

/// Deferred shading on the virtual clock: as [`crate::simulate::run_virtual`] with deep
/// composition, but the SC renders a deep G-buffer (normal fragments) and the lights are the
/// trace's `light` events. With [`ShadeOn::Fc`] the FC composes normal fragments and lights
/// every one with the lights of its own frame time; with [`ShadeOn::Sc`] the SC lights its
/// G-buffer with the lights of the state it renders and the FC lights only its own fragments.
/// Calls `on_frame` with each FC frame; returns the SC's cost.
///
/// # Errors
/// When the trace keys no light, a client fails, the clock is not valid, or a fragment's object
/// is unknown.
#[allow(
    clippy::too_many_arguments,
    reason = "the run's parameters, each documented"
)]
pub fn run_deferred_virtual(
    scene: &Scene,
    trace: Trace,
    clock: VirtualClock,
    migration: Migration,
    shade_on: ShadeOn,
    model: LightingModel,
    (width, height): (u32, u32),
    fc_frames: u64,
    mut on_frame: impl FnMut(&DeferredFrame),
) -> Result<ScCost, DeferredError> {
    if !trace.has_lights() {
        return Err(DeferredError::NoLights);
    }
    let mut timeline = VirtualTimeline::new(clock)?;
    let mut authority = Authority::new(scene, trace);
    let client = || Client::new(width, height).with_output(FragmentOutput::PackedNormal);
    let (mut sc_client, mut fc_client) = (client(), client());
    let projection = scene.camera.projection(width, height);
    let shader_for = |view: &crate::authority::ViewPose, lights: &[PointLight]| {
        Shader::new(
            scene,
            (width, height),
            view.matrix(),
            projection,
            lights,
            model,
        )
    };
    let mut cost = ScCost::default();
    for index in 0..fc_frames {
        let t = index as f64 * clock.fc_ms;
        let delivered = timeline.tick(t, |start_ms, sc_frame| {
            let snapshot = authority.advance_to(start_ms);
            let started = Instant::now();
            let mut buffer = sc_render(scene, &mut sc_client, &snapshot, migration, sc_frame)?;
            cost.max_fragments = cost.max_fragments.max(buffer.frame.fragment_count() as u64);
            if shade_on == ShadeOn::Sc {
                let shader = shader_for(&snapshot.view, &snapshot_lights(&snapshot));
                buffer.frame = shader.shade_frame(&buffer.frame)?;
                buffer.image = buffer.frame.resolve(scene.background);
            }
            cost.total_ms += started.elapsed().as_secs_f64() * 1e3;
            cost.frames += 1;
            Ok::<_, DeferredError>(buffer)
        })?;
        let snapshot = authority.advance_to(t);
        let fc_objects = fc_draws(scene, &snapshot, delivered.as_deref(), migration);
        let mut fc_ids: Vec<ObjectId> = fc_objects.iter().map(|&i| scene.objects[i].id).collect();
        fc_ids.sort_unstable();
        let view = delivered.as_ref().map_or(snapshot.view, |sc| sc.view);
        let lights = snapshot_lights(&snapshot);
        let shader = shader_for(&view, &lights);
        let fc = fc_client
            .render_footprint(scene, &snapshot, &view, &fc_objects)?
            .to_full()?;
        let started = Instant::now();
        let ms = |from: Instant| from.elapsed().as_secs_f64() * 1e3;
        // The same steps as `deferred_frame`, timed one by one.
        let (shaded, fc_compose_ms, fc_light_ms) = match (&delivered, shade_on) {
            (Some(sc), ShadeOn::Fc) => {
                let normals = compose_deep(&sc.frame, &fc, &fc_ids)?;
                let composed = ms(started);
                let lit = Instant::now();
                (shader.shade_shown(&normals)?, composed, ms(lit))
            }
            (Some(sc), ShadeOn::Sc) => {
                let own = shader.shade_frame(&fc)?;
                let light = ms(started);
                let composing = Instant::now();
                (
                    compose_deep(&sc.frame, &own, &fc_ids)?,
                    ms(composing),
                    light,
                )
            }
            (None, _) => (shader.shade_shown(&fc)?, 0.0, ms(started)),
        };
        let image = shaded.resolve(scene.background);
        let fc_shading_ms = ms(started);
        on_frame(&DeferredFrame {
            index,
            t_ms: t,
            snapshot,
            sc: delivered,
            fc_ids,
            lights,
            shader,
            shaded,
            image,
            fc_shading_ms,
            fc_compose_ms,
            fc_light_ms,
        });
    }
    Ok(cost)
}

/// The whole scene of `frame`'s state rendered at once as normal fragments through the view it
/// composed with, lit by the same shader (the frame's lights), its fragments that can show: what
/// a deferred frame must equal, bit for bit. A forward frame ([`ShadeOn::Sc`]) keeps its hidden
/// fragments, so compare its resolved image: it differs where the SC's lights are older.
///
/// # Errors
/// When the client fails or a fragment's object is unknown.
pub fn deferred_reference(
    scene: &Scene,
    client: &mut Client,
    frame: &DeferredFrame,
) -> Result<DeepFrame, DeferredError> {
    let view = frame.sc.as_ref().map_or(frame.snapshot.view, |sc| sc.view);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let normals = client.render(scene, &frame.snapshot, &view, &all)?;
    Ok(frame.shader.shade_shown(&normals)?)
}

/// The light-to-screen lag of a run (ms).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LightLag {
    /// Per `light` event, from the event to the first frame showing the SC's objects lit by it.
    pub shown_ms: Vec<f64>,
    /// `light` events the run ended before showing.
    pub not_shown: usize,
}

/// The light-to-screen lag of every `light` event of `trace` in `frames` (frame order): to the
/// first frame that lights the SC's objects with the lights at or after the event — the first
/// frame whose state includes the event with [`ShadeOn::Fc`] (the FC path), the first frame
/// composed with an SC buffer rendered from a state at or after it with [`ShadeOn::Sc`] (the SC
/// path; the FC's own objects follow the lights at the FC's rate in both).
pub fn light_lag(trace: &Trace, frames: &[FrameRecord], shade_on: ShadeOn) -> LightLag {
    let all = latency(trace, frames);
    let mut out = LightLag::default();
    for (event, lag) in trace.events().iter().zip(&all.per_event) {
        if !matches!(event.event, Event::Light { .. }) {
            continue;
        }
        let ms = match shade_on {
            ShadeOn::Fc => lag.fc_path_ms,
            ShadeOn::Sc => lag.sc_path_ms,
        };
        match ms {
            Some(ms) => out.shown_ms.push(ms),
            None => out.not_shown += 1,
        }
    }
    out
}
