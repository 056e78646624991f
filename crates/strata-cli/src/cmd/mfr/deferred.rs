//! `strata mfr --deferred`: the slow client renders a deep G-buffer, the fast client lights it
//! every frame with the current point lights; every frame checked against the whole scene lit
//! by the same shader.

use anyhow::{Result, bail};
use glam::Vec3;
use strata_mfr::client::Client;
use strata_mfr::deferred::{
    DeferredFrame, deferred_reference, gbuffer_bytes, run_deferred_virtual,
};
use strata_mfr::lighting::{LightRig, LightingModel};
use strata_mfr::simulate::Migration;
use strata_mfr::trace::Trace;
use strata_raster::FragmentOutput;
use strata_scene::Scene;

use super::{Args, Clock};

/// Milliseconds per turn of the built-in lights.
const RING_PERIOD_MS: f64 = 4000.0;

/// `count` lights circling above the scene's target, at 0.6 of the eye's distance.
fn ring(scene: &Scene, count: u32) -> LightRig {
    let cam = &scene.camera;
    let radius = (cam.eye - cam.target).length().max(1e-3) * 0.6;
    let center = cam.target + Vec3::Y * radius * 0.5;
    LightRig::ring(count as usize, center, radius, RING_PERIOD_MS)
}

/// Runs the deferred variant of `strata mfr`.
pub(super) fn run(
    args: &Args,
    scene: &Scene,
    trace: Trace,
    clock: Clock,
    migration: Migration,
    size: (u32, u32),
    frames: u64,
) -> Result<()> {
    if args.lights == 0 {
        bail!("--lights 0: deferred shading needs at least one light");
    }
    let Clock::Virtual(clock) = clock else {
        bail!("--deferred runs on the virtual clock (--clock virtual:sc_ms=…,fc_ms=…)");
    };
    let rig = ring(scene, args.lights);
    let mut reference = Client::new(size.0, size.1).with_output(FragmentOutput::PackedNormal);
    let (mut exact, mut shading_ms, mut failure) = (0u64, 0.0f64, None);
    let mut on_frame = |f: &DeferredFrame| {
        if failure.is_some() {
            return;
        }
        let checked = deferred_reference(scene, &mut reference, f)
            .map_err(anyhow::Error::from)
            .and_then(|expected| {
                exact += u64::from(expected == f.shaded);
                shading_ms += f.fc_shading_ms;
                if args.save_frames
                    && let Some(dir) = &args.out_dir
                {
                    f.image
                        .write_png(dir.join(format!("frame-{:04}.png", f.index)))?;
                }
                Ok(())
            });
        if let Err(e) = checked {
            failure = Some(e);
        }
    };
    let cost = run_deferred_virtual(
        scene,
        trace,
        clock,
        migration,
        &rig,
        LightingModel::default(),
        size,
        frames,
        &mut on_frame,
    )?;
    if let Some(e) = failure {
        return Err(e);
    }
    let pixels = u64::from(size.0) * u64::from(size.1);
    let bytes = gbuffer_bytes(pixels, cost.max_fragments);
    outln!(
        "deferred shading, {w}x{h}, {frames} FC frames: {exact} equal to the whole scene lit at once\n\
         lights: the trace's `light` events, else {n} circling the scene\n\
         SC G-buffer frames: {sc}, {sc_ms:.2} ms each (wall clock, this machine)\n\
         FC compose + light + resolve: {fc_ms:.2} ms per frame\n\
         largest G-buffer: {frags} fragments, {bpp:.1} bytes per pixel",
        w = size.0,
        h = size.1,
        n = args.lights,
        sc = cost.frames,
        sc_ms = cost.total_ms / cost.frames.max(1) as f64,
        fc_ms = shading_ms / frames.max(1) as f64,
        frags = cost.max_fragments,
        bpp = bytes as f64 / pixels.max(1) as f64,
    )?;
    Ok(())
}
