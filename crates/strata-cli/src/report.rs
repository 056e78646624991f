//! Statistics JSON, human-readable summaries of rendered frames, and the pieces of the HTML
//! reports: escaping, and colour-bar legends for heat maps.

use std::fmt::Write as _;

use serde_json::{Value, json};
use strata_scene::Scene;
use strata_stores::FrameResult;
use strata_stores::kbuffer::maps::hot;

/// Milliseconds of a duration, for printing.
pub(crate) fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Bytes a stored fragment costs: the memory holding this frame's data (per-pixel buffers
/// included) over the fragments stored. Allocated but unused capacity is reported apart.
pub(crate) fn bytes_per_fragment(used_memory_bytes: u64, fragments_stored: u64) -> f64 {
    if fragments_stored == 0 {
        0.0
    } else {
        used_memory_bytes as f64 / fragments_stored as f64
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
        "bytes_per_fragment": bytes_per_fragment(r.used_memory_bytes, r.capture.fragments_stored),
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
    let c = &r.capture;
    // A store that blends instead of storing (weighted blended OIT) keeps none: say so rather
    // than print "0 fragments".
    let fragments = if c.fragments_stored == 0 && c.fragments_rasterized > 0 {
        format!("{} fragments blended, none kept", c.fragments_rasterized)
    } else {
        format!("{} fragments", c.fragments_stored)
    };
    let mut line = format!(
        "{}: {}x{}, {} triangles, {fragments}, {} covered pixels, depth max {} mean {:.2}; ",
        scene.name,
        scene.width,
        scene.height,
        scene.triangle_count(),
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
        bytes_per_fragment(r.used_memory_bytes, r.capture.fragments_stored)
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

/// The CPU model this runs on, from /proc/cpuinfo (`model name`, or what ARM and RISC-V kernels
/// write instead), with the number of cores available to this process; "unknown CPU" where the
/// file is missing or names none.
pub(crate) fn cpu_model() -> String {
    let cores = crate::options::default_threads();
    let text = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpu_model_in(&text).unwrap_or("unknown CPU");
    format!("{model}, {cores} core(s) available")
}

/// The CPU model named in the text of /proc/cpuinfo.
fn cpu_model_in(cpuinfo: &str) -> Option<&str> {
    [
        "model name",
        "Hardware",
        "Model",
        "uarch",
        "cpu model",
        "cpu",
    ]
    .iter()
    .find_map(|key| {
        cpuinfo.lines().find_map(|line| {
            let (k, v) = line.split_once(':')?;
            (k.trim() == *key && !v.trim().is_empty()).then(|| v.trim())
        })
    })
}

/// `s` with the characters HTML gives a meaning escaped, safe in text and in quoted attributes.
pub(crate) fn html_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// A number for a legend tick: whole numbers as such, others with three significant digits.
fn tick(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e9 {
        format!("{v:.0}")
    } else {
        let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
        format!("{v:.digits$}")
    }
}

/// A horizontal colour bar for a heat map: `stops` spread evenly from left to right as a CSS
/// gradient, labelled below with `ticks` spread evenly over the same width, and a caption.
pub(crate) fn colour_bar_html(caption: &str, stops: &[[u8; 3]], ticks: &[f64]) -> String {
    let n = stops.len().saturating_sub(1).max(1);
    let gradient: Vec<String> = stops
        .iter()
        .enumerate()
        .map(|(i, [r, g, b])| format!("rgb({r},{g},{b}) {:.1}%", 100.0 * i as f64 / n as f64))
        .collect();
    let mut h = String::new();
    let _ = write!(
        h,
        "<div class=\"legend\" style=\"max-width:360px;font-size:.8em\"><div style=\"height:12px;border:1px solid #999;background:linear-gradient(to right,{})\"></div><div style=\"display:flex;justify-content:space-between\">",
        gradient.join(",")
    );
    for &t in ticks {
        let _ = write!(h, "<span>{}</span>", tick(t));
    }
    let _ = write!(h, "</div><div>{}</div></div>", html_escape(caption));
    h
}

/// The legend of the hot ramp of `strata_stores::kbuffer::maps` over `[0, max]`: black, red at a
/// third, yellow at two thirds, white at `max` (the ramp is linear between these stops).
pub(crate) fn hot_legend_html(caption: &str, max: f64) -> String {
    let stops = [0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0].map(|t| hot(t as f32));
    let ticks = [0.0, max / 3.0, 2.0 * max / 3.0, max];
    colour_bar_html(caption, &stops, &ticks)
}

/// What a per-pixel map of `strata render --maps` shows.
fn map_caption(name: &str) -> &'static str {
    match name {
        "k" => "k: fragments kept at each pixel",
        "importance" => {
            "importance of each pixel: I(p), or with --k-from optimal k(p) over the pixel's fragments"
        }
        _ => "value at each pixel",
    }
}

/// `maps.html` of `strata render --maps`: each map's heat map with its colour scale, given each
/// map's name and largest value (the top of its scale).
pub(crate) fn maps_page(method: &str, maps: &[(&str, f32)]) -> String {
    let mut h = String::new();
    let _ = writeln!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>strata: per-pixel maps of {0}</title></head><body style=\"font-family:system-ui,sans-serif;margin:2em\"><h1>Per-pixel maps of {0}</h1><p>Each map as a heat map over [0, its largest value]; the values themselves are in the .npy file of the same name (float32, rows from the top).</p>",
        html_escape(method)
    );
    for &(name, max) in maps {
        let name = html_escape(name);
        let _ = writeln!(
            h,
            "<figure style=\"margin:1em 0\"><img src=\"{name}.png\" alt=\"{name}\" style=\"max-width:100%;border:1px solid #ccc\"><figcaption>{}</figcaption></figure>",
            hot_legend_html(map_caption(&name), f64::from(max))
        );
    }
    h.push_str("</body></html>\n");
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_model_from_x86_and_arm_cpuinfo() {
        let x86 = "processor\t: 0\nvendor_id\t: GenuineIntel\nmodel\t\t: 85\nmodel name\t: Intel(R) Xeon(R) CPU @ 2.20GHz\n";
        assert_eq!(cpu_model_in(x86), Some("Intel(R) Xeon(R) CPU @ 2.20GHz"));
        let arm = "processor\t: 0\nBogoMIPS\t: 48.00\n\nHardware\t: BCM2835\nModel\t\t: Raspberry Pi 4 Model B\n";
        assert_eq!(cpu_model_in(arm), Some("BCM2835"));
        assert_eq!(cpu_model_in(""), None);
        assert!(cpu_model().contains("core(s) available"));
    }

    #[test]
    fn escapes_every_special_character() {
        assert_eq!(
            html_escape(r#"a<b>&"c"'d'"#),
            "a&lt;b&gt;&amp;&quot;c&quot;&#39;d&#39;"
        );
    }

    #[test]
    fn hot_legend_spans_zero_to_the_maximum() {
        let h = hot_legend_html("k", 12.0);
        assert!(
            h.contains("rgb(0,0,0) 0.0%") && h.contains("rgb(255,255,255) 100.0%"),
            "{h}"
        );
        assert!(h.contains("rgb(255,0,0) 33.3%"), "{h}");
        for t in [
            "<span>0</span>",
            "<span>4</span>",
            "<span>8</span>",
            "<span>12</span>",
        ] {
            assert!(h.contains(t), "{t} in {h}");
        }
        assert!(hot_legend_html("importance", 1.0).contains("<span>0.333</span>"));
    }
}
