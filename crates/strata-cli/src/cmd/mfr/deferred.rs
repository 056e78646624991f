//! `strata mfr --deferred`: the slow client renders a deep G-buffer, the lights are the trace's
//! `light` events (a ring of `--lights` lights when it has none); the fast client lights every
//! fragment at its own rate (`--shade-on fc`, deferred) or only its own objects' while the slow
//! client lights the rest at its rate (`--shade-on sc`, forward, for comparison). Every frame is
//! compared with the whole scene lit by the frame's lights; the light-to-screen lag is measured
//! from the timeline.

use anyhow::{Context, Result, bail};
use serde_json::json;
use strata_mfr::client::Client;
use strata_mfr::deferred::{
    DeferredFrame, ShadeOn, deferred_reference, gbuffer_bytes, light_lag, run_deferred_virtual,
};
use strata_mfr::lighting::LightingModel;
use strata_mfr::simulate::Migration;
use strata_mfr::timeline::FrameRecord;
use strata_mfr::trace::{LightRingParams, Trace, light_ring};
use strata_mfr::{audit, trace::Event};
use strata_raster::FragmentOutput;
use strata_scene::Scene;

use super::{Args, Clock};

/// `--shade-on`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum ShadeOnArg {
    /// The FC lights every fragment with the current lights (deferred shading).
    Fc,
    /// The SC lights its objects with the lights of the state it renders (forward).
    Sc,
}

impl ShadeOnArg {
    fn mode(self) -> ShadeOn {
        match self {
            ShadeOnArg::Fc => ShadeOn::Fc,
            ShadeOnArg::Sc => ShadeOn::Sc,
        }
    }
}

/// `trace`, with a ring of `count` lights keyed over it (at least one turn) when it keys none.
pub(super) fn with_lights(trace: Trace, scene: &Scene, count: u32) -> Result<Trace> {
    if count == 0 {
        bail!("--lights 0: deferred shading needs at least one light");
    }
    if count > 64 {
        bail!("--lights {count}: at most 64");
    }
    if trace.has_lights() {
        return Ok(trace);
    }
    let p = LightRingParams {
        count,
        duration_ms: trace
            .duration_ms()
            .max(LightRingParams::default().period_ms),
        ..LightRingParams::default()
    };
    Ok(trace.merged(&light_ring(scene, &p)?))
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
    let Clock::Virtual(clock) = clock else {
        bail!("--deferred runs on the virtual clock (--clock virtual:sc_ms=…,fc_ms=…)");
    };
    let shade_on = args.shade_on.mode();
    let mut reference = Client::new(size.0, size.1).with_output(FragmentOutput::PackedNormal);
    let (mut exact, mut bad_pixels, mut failure) = (0u64, 0u64, None);
    // Per FC frame: the whole step, composing, lighting (ms).
    let (mut step_ms, mut compose_ms, mut light_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut records = Vec::new();
    let mut light_counts = (usize::MAX, 0usize);
    let mut on_frame = |f: &DeferredFrame| {
        if failure.is_some() {
            return;
        }
        let checked = deferred_reference(scene, &mut reference, f)
            .map_err(anyhow::Error::from)
            .and_then(|expected| {
                let a = audit(&f.shaded, &expected, scene.background);
                // Images: a forward frame keeps the fragments hidden behind opaque ones.
                exact += u64::from(expected.resolve(scene.background) == f.image);
                bad_pixels += a.bad_pixels;
                step_ms.push(f.fc_shading_ms);
                compose_ms.push(f.fc_compose_ms);
                light_ms.push(f.fc_light_ms);
                light_counts = (
                    light_counts.0.min(f.lights.len()),
                    light_counts.1.max(f.lights.len()),
                );
                records.push(FrameRecord::from_parts(
                    f.index,
                    f.t_ms,
                    f.t_ms + clock.fc_ms,
                    &f.snapshot,
                    f.sc.as_deref(),
                    Some(a),
                ));
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
        trace.clone(),
        clock,
        migration,
        shade_on,
        LightingModel::default(),
        size,
        frames,
        &mut on_frame,
    )?;
    if let Some(e) = failure {
        return Err(e);
    }
    let (step, compose, light) = (
        median(&mut step_ms),
        median(&mut compose_ms),
        median(&mut light_ms),
    );
    let lag = light_lag(&trace, &records, shade_on);
    let mut lags = lag.shown_ms.clone();
    lags.sort_by(f64::total_cmp);
    let quantile =
        |q: f64| (!lags.is_empty()).then(|| lags[((lags.len() - 1) as f64 * q).round() as usize]);
    let pixels = u64::from(size.0) * u64::from(size.1);
    let bytes = gbuffer_bytes(pixels, cost.max_fragments);
    let light_events = trace
        .events()
        .iter()
        .filter(|e| matches!(e.event, Event::Light { .. }))
        .count();
    let summary = json!({
        "scene": args.scene,
        "size": [size.0, size.1],
        "clock": {"kind": "virtual", "sc_ms": clock.sc_ms, "fc_ms": clock.fc_ms, "transfer_ms": clock.transfer_ms},
        "fc_frames": frames,
        "deferred": {
            "shade_on": match shade_on { ShadeOn::Fc => "fc", ShadeOn::Sc => "sc" },
            "lights": {"min": light_counts.0.min(light_counts.1), "max": light_counts.1},
            "light_events": light_events,
            "frames_equal_to_reference": exact,
            "bad_pixels_per_frame": bad_pixels as f64 / frames.max(1) as f64,
            "light_lag_ms": {
                "median": quantile(0.5),
                "max": quantile(1.0),
                "not_shown": lag.not_shown,
            },
            "sc_gbuffer_frames": cost.frames,
            "sc_gbuffer_ms_mean": cost.total_ms / cost.frames.max(1) as f64,
            "fc_step_ms_median": step,
            "fc_compose_ms_median": compose,
            "fc_light_ms_median": light,
            "gbuffer_max_fragments": cost.max_fragments,
            "gbuffer_bytes_per_pixel": bytes as f64 / pixels.max(1) as f64,
        },
    });
    let ms = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.0}"));
    outln!(
        "deferred shading ({mode}), {w}x{h}, {frames} FC frames: {exact} equal to the whole scene \
         lit by the frame's lights, {bad:.1} bad pixels a frame\n\
         lights: {lights} ({events} `light` events); light-to-screen lag median {med} ms, max {max} ms \
         ({path} path)\n\
         SC G-buffer frames: {sc}, {sc_ms:.2} ms each (wall clock, this machine)\n\
         FC compose + light + resolve: {step:.2} ms per frame (median; compose {compose:.2}, \
         light {light:.2})\n\
         largest G-buffer: {frags} fragments, {bpp:.1} bytes per pixel",
        mode = match shade_on {
            ShadeOn::Fc => "lit by the fast client",
            ShadeOn::Sc => "slow client's objects lit by the slow client",
        },
        w = size.0,
        h = size.1,
        bad = bad_pixels as f64 / frames.max(1) as f64,
        lights = light_counts.1,
        events = light_events,
        med = ms(quantile(0.5)),
        max = ms(quantile(1.0)),
        path = match shade_on {
            ShadeOn::Fc => "FC",
            ShadeOn::Sc => "SC",
        },
        sc = cost.frames,
        sc_ms = cost.total_ms / cost.frames.max(1) as f64,
        frags = cost.max_fragments,
        bpp = bytes as f64 / pixels.max(1) as f64,
    )?;
    if let Some(dir) = &args.out_dir {
        let path = dir.join("summary.json");
        std::fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// The median of `v` (0 for none).
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}
