//! Statistics JSON and human-readable summaries of rendered frames.

use serde_json::{Value, json};
use strata_scene::Scene;
use strata_stores::FrameResult;

/// Milliseconds of a duration, for printing.
pub(crate) fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Bytes a stored fragment costs: the memory holding this frame's data (per-pixel buffers
/// included) over the fragments stored. Allocated but unused capacity is reported apart.
pub(crate) fn bytes_per_fragment(r: &FrameResult) -> f64 {
    let stored = r.capture.fragments_stored;
    if stored == 0 {
        0.0
    } else {
        r.used_memory_bytes as f64 / stored as f64
    }
}

/// The statistics of one rendered frame, as written by `render --stats` and `demo`.
pub(crate) fn stats_json(
    scene: &Scene,
    method: &str,
    frame: u32,
    threads: usize,
    r: &FrameResult,
) -> Value {
    let depth = r.depth.clone().unwrap_or_default();
    let stored = r.capture.fragments_stored;
    let passes: serde_json::Map<String, Value> = r
        .timings
        .passes()
        .map(|(n, d)| (n.to_owned(), json!(ms(d))))
        .collect();
    let stages: serde_json::Map<String, Value> = r
        .timings
        .iter()
        .filter(|(n, _)| n.contains('.'))
        .map(|(n, d)| (n.to_owned(), json!(ms(d))))
        .collect();
    let s = r.capture.setup;
    json!({
        "scene": scene.name,
        "method": method,
        "frame": frame,
        "threads": threads,
        "width": scene.width,
        "height": scene.height,
        "triangles": scene.triangle_count(),
        "fragments": stored,
        "fragments_rasterized": r.capture.fragments_rasterized,
        "covered_pixels": depth.covered_pixels(),
        "max_depth_complexity": depth.max_depth_complexity(),
        "mean_depth_complexity": depth.mean_depth_complexity(),
        "depth_histogram": depth.trimmed_histogram(),
        "dropped_fragments": r.capture.dropped,
        "memory_bytes": r.memory_bytes,
        "used_memory_bytes": r.used_memory_bytes,
        "bytes_per_fragment": bytes_per_fragment(r),
        "pool_regrows": r.capture.regrows,
        "setup": {
            "triangles": s.triangles,
            "culled_outside": s.culled_outside,
            "culled_empty": s.culled_empty,
            "clipped": s.clipped,
            "bin_entries": s.bin_entries,
        },
        "timings_ms": Value::Object(passes),
        "stage_timings_ms": Value::Object(stages),
    })
}

/// One line describing a rendered frame.
pub(crate) fn summary_line(scene: &Scene, r: &FrameResult) -> String {
    let depth = r.depth.clone().unwrap_or_default();
    let mut line = format!(
        "{}: {}x{}, {} triangles, {} fragments, {} covered pixels, depth max {} mean {:.2}; ",
        scene.name,
        scene.width,
        scene.height,
        scene.triangle_count(),
        r.capture.fragments_stored,
        depth.covered_pixels(),
        depth.max_depth_complexity(),
        depth.mean_depth_complexity(),
    );
    let passes: Vec<String> = r
        .timings
        .passes()
        .map(|(n, d)| format!("{n} {:.2} ms", ms(d)))
        .collect();
    line.push_str(&passes.join(", "));
    line.push_str(&format!(
        "; memory {:.1} MiB used of {:.1} MiB allocated ({:.1} B/fragment)",
        r.used_memory_bytes as f64 / (1 << 20) as f64,
        r.memory_bytes as f64 / (1 << 20) as f64,
        bytes_per_fragment(r)
    ));
    if r.capture.dropped > 0 {
        line.push_str(&format!(
            "; DROPPED {} fragments: the store was full or over its budget (sizes: --pool, --array-size, -k, --budget)",
            r.capture.dropped
        ));
    }
    if r.capture.regrows > 0 {
        line.push_str(&format!(
            "; pool grew {} time(s) and the frame was captured again",
            r.capture.regrows
        ));
    }
    line
}
