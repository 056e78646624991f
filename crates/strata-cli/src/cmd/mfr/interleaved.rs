//! `strata mfr --interleaved`: both clients on one thread, the SC in chunks between FC frames —
//! the option read, the run's figures turned into the real clock's statistics, and the
//! `interleaved` part of `summary.json` and of the text summary.

use anyhow::{Result, bail};
use serde_json::json;
use strata_mfr::interleaved::{MissCounts, PeriodRecord, StepKind};
use strata_mfr::{Chunking, InterleavedStats, RealStats};

/// `--interleaved [adaptive|fixed:N]`, checked against the other real-clock options.
pub(super) fn parse_interleaved(value: &str, only_defaults: bool) -> Result<Chunking> {
    if !only_defaults {
        bail!(
            "--interleaved runs both clients on one thread: it takes neither --transport, \
             --sc-load nor --sc-priority"
        );
    }
    Ok(value.parse::<Chunking>()?)
}

/// The real clock's statistics of an interleaved run: FC frame times and misses, each SC frame's
/// work (its chunks and export) as its frame time.
pub(super) fn real_stats(stats: &InterleavedStats) -> RealStats {
    RealStats {
        fc_frame_ms: stats.fc_frame_ms.clone(),
        sc_frame_ms: stats
            .sc_frames
            .iter()
            .map(|r| r.capture_ms + r.export_ms)
            .collect(),
        fc_deadlines_missed: stats.fc_frame_ms.len() as u64 - stats.fc_deadlines_hit,
        ..RealStats::default()
    }
}

/// The `interleaved` object of `summary.json`.
pub(super) fn interleaved_json(chunking: Chunking, stats: &InterleavedStats) -> serde_json::Value {
    let chunks: Vec<f64> = stats
        .sc_frames
        .iter()
        .map(|r| f64::from(r.chunks))
        .collect();
    let per_chunk_us: Vec<f64> = stats
        .chunk_ms
        .iter()
        .zip(&stats.chunk_triangles)
        .map(|(ms, &n)| ms * 1e3 / n as f64)
        .collect();
    json!({
        "chunking": chunking.to_string(),
        "fc_deadline_hit_rate": stats.deadline_hit_rate(),
        "fc_start_late_ms_max": stats.fc_start_late_ms.iter().copied().fold(0.0, f64::max),
        "sc_frames": stats.sc_frames.len(),
        "sc_period_fc_frames_mean": stats.mean_sc_fc_frames(),
        "sc_chunks_mean": mean(&chunks),
        "chunk_triangles_mean": mean(&stats.chunk_triangles.iter().map(|&n| n as f64).collect::<Vec<_>>()),
        "chunk_us_per_triangle_mean": mean(&per_chunk_us),
        "sc_export_ms_mean": mean(&stats.sc_frames.iter().map(|r| r.export_ms).collect::<Vec<_>>()),
        "sc_one_shot_ms": stats.one_shot_sc_ms,
        "chunking_overhead": stats.chunking_overhead(),
        "sc_bands_mean": mean(&stats.sc_frames.iter().map(|r| f64::from(r.bands)).collect::<Vec<_>>()),
        "band_rows_mean": mean(&stats.band_rows.iter().map(|&n| f64::from(n)).collect::<Vec<_>>()),
        "band_ms_max": stats.band_ms.iter().copied().reduce(f64::max),
        "chunk_ms_max": stats.chunk_ms.iter().copied().reduce(f64::max),
        "fc_deadlines_missed": misses_json(&stats.misses()),
        "chunk_estimate_ratio": ratios_json(&stats.estimate_ratios(true)),
        "band_estimate_ratio": ratios_json(&stats.estimate_ratios(false)),
        "chunk_model_ms": {
            "per_call_measured": stats.chunk_model[0],
            "per_1k_triangles": stats.chunk_model[1],
            "per_10k_fragments": stats.chunk_model[2],
        },
        "band_model_ms": {
            "per_band_measured": stats.band_model[0],
            "per_100_rows": stats.band_model[1],
            "per_10k_fragments": stats.band_model[2],
        },
        "periods": stats.periods.iter().map(period_json).collect::<Vec<_>>(),
    })
}

/// One period: how late its FC frame started and how long it took (ms), and each SC step after
/// it as `[kind, size, ms, predicted ms or null, end]`, the end in ms from the period's scheduled
/// start (past the period: the next FC frame starts late).
fn period_json(p: &PeriodRecord) -> serde_json::Value {
    let steps: Vec<serde_json::Value> = p
        .steps
        .iter()
        .map(|s| {
            let (kind, size) = match s.kind {
                StepKind::Start => ("start", 0),
                StepKind::Chunk(n) => ("chunk", n),
                StepKind::Band(rows) => ("band", u64::from(rows)),
                _ => ("other", 0),
            };
            json!([
                kind,
                size,
                round(s.ms),
                s.predicted_ms.map(round),
                round(s.end_ms - p.scheduled_ms)
            ])
        })
        .collect();
    json!({
        "fc_frame": p.fc_frame,
        "hit": p.hit,
        "start_late_ms": round(p.fc_start_ms - p.scheduled_ms),
        "fc_ms": round(p.fc_end_ms - p.fc_start_ms),
        "steps": steps,
    })
}

fn round(ms: f64) -> f64 {
    (ms * 1000.0).round() / 1000.0
}

/// The missed FC deadlines by what ran past the next FC frame's start.
fn misses_json(m: &MissCounts) -> serde_json::Value {
    json!({
        "total": m.total(),
        "fc_frame": m.fc_frame,
        "caller": m.caller,
        "sc_start": m.sc_start,
        "chunk": m.chunk,
        "export_band": m.export_band,
    })
}

/// The adaptive model's measured-over-predicted ratios: median, 90th percentile and maximum
/// (`null` in the fixed mode, which predicts nothing).
fn ratios_json(ratios: &[f64]) -> serde_json::Value {
    let mut sorted = ratios.to_vec();
    sorted.sort_by(f64::total_cmp);
    let at = |q: f64| {
        (!sorted.is_empty()).then(|| sorted[((sorted.len() - 1) as f64 * q).round() as usize])
    };
    if sorted.is_empty() {
        return serde_json::Value::Null;
    }
    json!({ "median": at(0.5), "p90": at(0.9), "max": at(1.0) })
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The text summary's line for an interleaved run.
pub(super) fn interleaved_text(v: &serde_json::Value) -> String {
    let num = |key: &str, digits: usize| {
        v[key]
            .as_f64()
            .map_or_else(|| "-".to_owned(), |x| format!("{x:.digits$}"))
    };
    let m = &v["fc_deadlines_missed"];
    let missed = |key: &str| m[key].as_u64().unwrap_or(0);
    format!(
        "\ninterleaved ({}): FC deadlines hit {} %, SC frame every {} FC frames ({} SC frames, {} \
         chunks and {} export bands each, {} triangles a chunk), SC work {} % over one-shot ({} \
         ms one-shot); deadlines missed after: {} chunk, {} export band, {} FC frame, {} SC \
         start, {} frame handling",
        v["chunking"].as_str().unwrap_or("-"),
        v["fc_deadline_hit_rate"]
            .as_f64()
            .map_or_else(|| "-".to_owned(), |x| format!("{:.1}", x * 100.0)),
        num("sc_period_fc_frames_mean", 1),
        v["sc_frames"],
        num("sc_chunks_mean", 1),
        num("sc_bands_mean", 1),
        num("chunk_triangles_mean", 0),
        v["chunking_overhead"]
            .as_f64()
            .map_or_else(|| "-".to_owned(), |x| format!("{:.1}", x * 100.0)),
        num("sc_one_shot_ms", 1),
        missed("chunk"),
        missed("export_band"),
        missed("fc_frame"),
        missed("sc_start"),
        missed("caller"),
    )
}
