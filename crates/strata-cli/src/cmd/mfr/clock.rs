//! `--clock` and `--trace`: parsing what the user asked for.

use anyhow::{Context, Result, bail};
use strata_mfr::simulate::VirtualClock;
use strata_mfr::trace::{GrabParams, LightRingParams, Trace, grab, light_ring, orbit};

use super::Clock;

/// `virtual:sc_ms=N,fc_ms=N[,transfer_ms=N]` or `real[:fc_hz=N]`.
pub(super) fn parse_clock(s: &str) -> Result<Clock> {
    if s == "real" || s.starts_with("real:") {
        let mut fc_hz = 30.0;
        for item in s
            .trim_start_matches("real")
            .trim_start_matches(':')
            .split(',')
        {
            if item.trim().is_empty() {
                continue;
            }
            match item.split_once('=') {
                Some(("fc_hz", v)) => {
                    fc_hz = v
                        .trim()
                        .parse()
                        .ok()
                        .filter(|v: &f64| v.is_finite() && *v > 0.0 && *v <= 1000.0)
                        .with_context(|| {
                            format!("--clock: {item}: expected a rate in (0, 1000] Hz")
                        })?;
                }
                _ => bail!("--clock real: '{item}': expected fc_hz=N"),
            }
        }
        return Ok(Clock::Real { fc_hz });
    }
    let Some(params) = s.strip_prefix("virtual:") else {
        bail!("--clock {s}: expected virtual:sc_ms=N,fc_ms=N[,transfer_ms=N] or real[:fc_hz=N]");
    };
    let mut clock = VirtualClock {
        sc_ms: 300.0,
        fc_ms: 33.0,
        transfer_ms: 0.0,
    };
    for item in params.split(',').filter(|i| !i.trim().is_empty()) {
        let (key, value) = item
            .split_once('=')
            .with_context(|| format!("--clock: '{item}': expected key=value"))?;
        let v: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && *v >= 0.0 && *v <= 3.6e6)
            .with_context(|| format!("--clock: {item}: expected milliseconds, 0 to 3600000"))?;
        match key.trim() {
            "sc_ms" => clock.sc_ms = v,
            "fc_ms" => clock.fc_ms = v,
            "transfer_ms" => clock.transfer_ms = v,
            other => bail!("--clock: unknown '{other}' (sc_ms, fc_ms, transfer_ms)"),
        }
    }
    if clock.sc_ms <= 0.0 || clock.fc_ms <= 0.0 {
        bail!("--clock: sc_ms and fc_ms must be more than 0");
    }
    Ok(Clock::Virtual(clock))
}

/// The trace `spec` names for `scene`.
pub(super) fn make_trace(spec: &str, scene: &strata_scene::Scene) -> Result<Trace> {
    if let Some(params) = spec.strip_prefix("grab:") {
        return Ok(grab(scene, &GrabParams::parse(params)?)?);
    }
    if let Some(params) = spec.strip_prefix("lights:") {
        return Ok(light_ring(scene, &LightRingParams::parse(params)?)?);
    }
    if let Some(params) = spec.strip_prefix("orbit:") {
        let (mut period, mut duration) = (4000.0, 4000.0);
        for item in params.split(',').filter(|i| !i.trim().is_empty()) {
            let (key, value) = item
                .split_once('=')
                .with_context(|| format!("--trace orbit: '{item}': expected key=value"))?;
            let v: f64 = value
                .trim()
                .parse()
                .with_context(|| format!("--trace orbit: {item}: expected milliseconds"))?;
            match key.trim() {
                "period_ms" => period = v,
                "duration_ms" => duration = v,
                other => bail!("--trace orbit: unknown '{other}' (period_ms, duration_ms)"),
            }
        }
        return Ok(orbit(scene, period, duration, 33.0)?);
    }
    Ok(Trace::read(std::path::Path::new(spec))?)
}
