//! The run's record: totals over the frames, the per-frame JSON line, the summary (JSON and text).

use serde_json::json;
use strata_mfr::simulate::FcFrame;
use strata_mfr::{FrameAudit, RealStats, table_6_1_row};

use super::{Args, Clock};

/// Totals over a run.
#[derive(Default)]
pub(super) struct Totals {
    pub(super) frames: u64,
    pub(super) sc_frames_used: std::collections::BTreeSet<u64>,
    pub(super) frames_with_bad_pixels: u64,
    pub(super) max_bad_pixels: u64,
    pub(super) ghost_pixel_frames: u64,
    pub(super) hole_pixel_frames: u64,
    pub(super) blend_pixel_frames: u64,
    pub(super) sc_age_ms: Vec<f64>,
}

pub(super) fn record(t: &mut Totals, f: &FcFrame, a: &FrameAudit) {
    t.frames += 1;
    if let Some(sc) = &f.sc {
        t.sc_frames_used.insert(sc.sc_frame);
        t.sc_age_ms.push(f.t_ms - sc.snapshot_t_ms);
    }
    t.frames_with_bad_pixels += u64::from(a.bad_pixels > 0);
    t.max_bad_pixels = t.max_bad_pixels.max(a.bad_pixels);
    t.ghost_pixel_frames += u64::from(a.ghost_pixels > 0);
    t.hole_pixel_frames += u64::from(a.hole_pixels > 0);
    t.blend_pixel_frames += u64::from(a.blend_pixels > 0);
}

pub(super) fn frame_json(
    scene: &strata_scene::Scene,
    f: &FcFrame,
    a: &FrameAudit,
) -> serde_json::Value {
    let objects: Vec<serde_json::Value> = f
        .fc_objects
        .iter()
        .map(|&i| {
            let pose = &f.snapshot.objects[i];
            let contained =
                f.sc.as_ref()
                    .is_some_and(|sc| sc.contains(pose.id, pose.version));
            json!({
                "object": scene.objects[i].name,
                "state": pose.state,
                "table_6_1_row": table_6_1_row(pose.state, contained),
            })
        })
        .collect();
    json!({
        "fc_frame": f.index,
        "t_ms": f.t_ms,
        "snapshot": f.snapshot.id,
        "sc_frame": f.sc.as_ref().map(|s| s.sc_frame),
        "sc_age_ms": f.sc.as_ref().map(|s| f.t_ms - s.snapshot_t_ms),
        "fc_objects": objects,
        "fc_fragments": f.fc.fragment_count(),
        "audit": a,
    })
}

fn median_p95(v: &mut [f64]) -> serde_json::Value {
    if v.is_empty() {
        return serde_json::Value::Null;
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    json!({"median": at(0.5), "p95": at(0.95)})
}

pub(super) fn summary_json(
    args: &Args,
    scene: &strata_scene::Scene,
    clock: Clock,
    size: (u32, u32),
    t: &mut Totals,
    real: Option<RealStats>,
) -> serde_json::Value {
    let clock_json = match clock {
        Clock::Virtual(c) => {
            json!({"kind": "virtual", "sc_ms": c.sc_ms, "fc_ms": c.fc_ms, "transfer_ms": c.transfer_ms})
        }
        Clock::Real { fc_hz } => json!({"kind": "real", "fc_hz": fc_hz}),
    };
    let mut v = json!({
        "scene": scene.name,
        "trace": args.trace,
        "migration": format!("{:?}", args.migration).to_lowercase(),
        "mode": format!("{:?}", args.mode).to_lowercase(),
        "clock": clock_json,
        "width": size.0,
        "height": size.1,
        "fc_frames": real.as_ref().map_or(t.frames, |r| r.fc_frame_ms.len() as u64),
        "audited_frames": t.frames,
        "sc_frames_used": t.sc_frames_used.len(),
        "sc_age_ms": median_p95(&mut t.sc_age_ms),
        "frames_with_bad_pixels": t.frames_with_bad_pixels,
        "max_bad_pixels": t.max_bad_pixels,
        "ghost_pixel_frames": t.ghost_pixel_frames,
        "hole_pixel_frames": t.hole_pixel_frames,
        "blend_pixel_frames": t.blend_pixel_frames,
    });
    if let Some(mut r) = real {
        let mut swap: Vec<f64> = r.publish_us.iter().chain(&r.read_us).copied().collect();
        let max = swap.iter().copied().fold(0.0, f64::max);
        v["cpu"] = json!(crate::report::cpu_model());
        v["fc_frame_ms"] = median_p95(&mut r.fc_frame_ms);
        v["sc_frame_ms"] = median_p95(&mut r.sc_frame_ms);
        v["sc_frames"] = json!(r.sc_frame_ms.len());
        v["swap_us"] = json!({"median": median_p95(&mut swap)["median"], "max": max});
        v["fc_deadlines_missed"] = json!(r.fc_deadlines_missed);
        transport_json(&mut v, args, &mut r);
    }
    v
}

/// The real clock's transport, SC load and incidents; over TCP, the bytes and times of the SC
/// buffers received.
fn transport_json(v: &mut serde_json::Value, args: &Args, r: &mut RealStats) {
    v["transport"] = json!(args.transport);
    v["sc_load"] = json!(format!("{:?}", args.sc_load).to_lowercase());
    v["sc_priority"] = json!(format!("{:?}", args.sc_priority).to_lowercase());
    let incidents: Vec<serde_json::Value> = r
        .incidents
        .iter()
        .map(|i| json!({"t_ms": i.t_ms, "what": i.what}))
        .collect();
    v["incidents"] = json!(incidents);
    if !r.sc_bytes.is_empty() {
        let mut bytes: Vec<f64> = r.sc_bytes.iter().map(|&b| b as f64).collect();
        v["sc_bytes"] = median_p95(&mut bytes);
        v["transfer_ms"] = median_p95(&mut r.transfer_ms);
        v["decode_ms"] = median_p95(&mut r.decode_ms);
    }
}

/// A line per incident of a real-time run (empty without any).
pub(super) fn incidents_text(s: &serde_json::Value) -> String {
    let Some(list) = s["incidents"].as_array().filter(|l| !l.is_empty()) else {
        return String::new();
    };
    let mut text = format!("\n  {} incident(s) beside the FC loop:", list.len());
    for i in list {
        text.push_str(&format!(
            "\n    at {} ms: {}",
            fmt(&i["t_ms"]),
            i["what"].as_str().unwrap_or("?")
        ));
    }
    text
}

fn clock_text(s: &serde_json::Value) -> String {
    let c = &s["clock"];
    if c["kind"] == "real" {
        format!(
            "real, FC at {} Hz: FC frame {} ms median / {} p95, SC frame {} ms median ({} SC frames), \
             hand-over {} µs median / {} max, {} FC deadlines missed ({})",
            c["fc_hz"],
            fmt(&s["fc_frame_ms"]["median"]),
            fmt(&s["fc_frame_ms"]["p95"]),
            fmt(&s["sc_frame_ms"]["median"]),
            s["sc_frames"],
            fmt(&s["swap_us"]["median"]),
            fmt(&s["swap_us"]["max"]),
            s["fc_deadlines_missed"],
            s["cpu"].as_str().unwrap_or("?"),
        )
    } else {
        format!(
            "virtual, SC {} ms / FC {} ms / transfer {} ms",
            c["sc_ms"], c["fc_ms"], c["transfer_ms"]
        )
    }
}

fn fmt(v: &serde_json::Value) -> String {
    v.as_f64()
        .map_or_else(|| "-".to_owned(), |x| format!("{x:.2}"))
}

pub(super) fn summary_text(s: &serde_json::Value) -> String {
    let head = format!(
        "strata mfr: {} ({}x{}), {} migration, {} composition, clock {}",
        s["scene"].as_str().unwrap_or("?"),
        s["width"],
        s["height"],
        s["migration"].as_str().unwrap_or("?"),
        s["mode"].as_str().unwrap_or("?"),
        clock_text(s),
    );
    if s["audited_frames"] == 0 {
        return format!(
            "{head}\n  {} FC frames, not audited (--no-audit)",
            s["fc_frames"]
        );
    }
    format!(
        "{head}\n  {} FC frames with {} SC buffers; age of the state in the SC buffer, median {} ms\n  \
         audited {} of them against the single renderer: {} frame(s) with bad pixels (> 2/255, at \
         most {} in a frame); frames with ghost / hole / blend pixels: {} / {} / {}",
        s["fc_frames"],
        s["sc_frames_used"],
        fmt(&s["sc_age_ms"]["median"]),
        s["audited_frames"],
        s["frames_with_bad_pixels"],
        s["max_bad_pixels"],
        s["ghost_pixel_frames"],
        s["hole_pixel_frames"],
        s["blend_pixel_frames"],
    )
}
