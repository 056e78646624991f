//! `strata mfr --interleaved`: both clients on one thread, the SC in chunks between FC frames —
//! the option read, the run's figures turned into the real clock's statistics, and the
//! `interleaved` part of `summary.json` and of the text summary.

use anyhow::{Result, bail};
use serde_json::json;
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
    })
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
    format!(
        "\ninterleaved ({}): FC deadlines hit {} %, SC frame every {} FC frames ({} SC frames, {} \
         chunks each, {} triangles a chunk), SC work {} % over one-shot ({} ms one-shot)",
        v["chunking"].as_str().unwrap_or("-"),
        v["fc_deadline_hit_rate"]
            .as_f64()
            .map_or_else(|| "-".to_owned(), |x| format!("{:.1}", x * 100.0)),
        num("sc_period_fc_frames_mean", 1),
        v["sc_frames"],
        num("sc_chunks_mean", 1),
        num("chunk_triangles_mean", 0),
        v["chunking_overhead"]
            .as_f64()
            .map_or_else(|| "-".to_owned(), |x| format!("{:.1}", x * 100.0)),
        num("sc_one_shot_ms", 1),
    )
}
