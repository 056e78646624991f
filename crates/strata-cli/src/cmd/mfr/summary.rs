//! The run's record: totals over the frames, the per-frame JSON line, the summary (JSON and text).

use std::collections::BTreeSet;

use serde_json::json;
use strata_mfr::simulate::FcFrame;
use strata_mfr::trace::Trace;
use strata_mfr::{FrameAudit, FrameRecord, RealStats, events, latency, table_6_1_row};

use super::{Args, Clock};

/// What a run recorded, frame by frame.
#[derive(Default)]
pub(super) struct Totals {
    /// Every FC frame, audited or not, in frame order once the run is over.
    records: Vec<FrameRecord>,
    /// The SC buffers the frames composed with.
    sc_frames_used: BTreeSet<u64>,
}

impl Totals {
    /// Records a frame that composed with SC buffer `sc_frame`.
    pub(super) fn add(&mut self, record: FrameRecord, sc_frame: Option<u64>) {
        self.sc_frames_used.extend(sc_frame);
        self.records.push(record);
    }
}

/// Frame `f`'s line in frames.jsonl.
pub(super) fn frame_json(
    scene: &strata_scene::Scene,
    f: &FcFrame,
    r: &FrameRecord,
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
        "shown_ms": r.shown_ms,
        "snapshot": f.snapshot.id,
        "events_applied": f.snapshot.events_applied,
        "sc_frame": f.sc.as_ref().map(|s| s.sc_frame),
        "sc_age_ms": f.sc.as_ref().map(|s| f.t_ms - s.snapshot_t_ms),
        "fc_objects": objects,
        "fc_fragments": f.fc.fragment_count(),
        "audit": r.audit,
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
    trace: &Trace,
    clock: Clock,
    size: (u32, u32),
    t: &mut Totals,
    real: Option<RealStats>,
) -> serde_json::Value {
    t.records.sort_by_key(|r| r.index);
    let clock_json = match clock {
        Clock::Virtual(c) => {
            json!({"kind": "virtual", "sc_ms": c.sc_ms, "fc_ms": c.fc_ms, "transfer_ms": c.transfer_ms})
        }
        Clock::Real { fc_hz } => json!({"kind": "real", "fc_hz": fc_hz}),
    };
    let audits: Vec<&FrameAudit> = t.records.iter().filter_map(|r| r.audit.as_ref()).collect();
    let frames_with = |has: fn(&FrameAudit) -> bool| audits.iter().filter(|a| has(a)).count();
    let mut sc_age: Vec<f64> = t
        .records
        .iter()
        .filter_map(|r| r.sc_state_ms.map(|s| r.t_ms - s))
        .collect();
    let mut rmse: Vec<f64> = audits.iter().map(|a| a.rmse).collect();
    let l = latency(trace, &t.records);
    let (mut fc_path, mut sc_path) = (l.fc_path_ms.clone(), l.sc_path_ms.clone());
    let name = |id: Option<strata_core::ObjectId>| {
        id.and_then(|id| scene.objects.iter().find(|o| o.id == id))
            .map(|o| o.name.clone())
    };
    let event_list: Vec<serde_json::Value> = events(trace, &t.records)
        .iter()
        .map(|e| {
            json!({
                "kind": e.kind,
                "t_ms": e.t_ms,
                "fc_frame": e.fc_frame,
                "object": name(e.object),
                "frames": e.frames,
                "artefact_frames": e.artefact_frames,
                "artefact_ms": e.artefact_ms,
                "peak_bad_pixels": e.peak.map(|p| p.bad_pixels),
                "peak_ghost_pixels": e.peak.map(|p| p.ghost_pixels),
                "peak_hole_pixels": e.peak.map(|p| p.hole_pixels),
                "peak_blend_pixels": e.peak.map(|p| p.blend_pixels),
            })
        })
        .collect();
    let mut v = json!({
        "scene": scene.name,
        "trace": args.trace,
        "migration": format!("{:?}", args.migration).to_lowercase(),
        "mode": format!("{:?}", args.mode).to_lowercase(),
        "clock": clock_json,
        "width": size.0,
        "height": size.1,
        "fc_frames": t.records.len(),
        "audited_frames": audits.len(),
        "sc_frames": t.sc_frames_used.len(),
        "sc_frames_used": t.sc_frames_used.len(),
        "sc_age_ms": median_p95(&mut sc_age),
        "latency_ms": {
            "fc_path": median_p95(&mut fc_path),
            "sc_path": median_p95(&mut sc_path),
            "fc_path_not_shown": l.fc_not_shown,
            "sc_path_not_shown": l.sc_not_shown,
            "per_event": l.per_event,
        },
        "frames_with_bad_pixels": frames_with(|a| a.bad_pixels > 0),
        "max_bad_pixels": audits.iter().map(|a| a.bad_pixels).max().unwrap_or(0),
        "ghost_pixel_frames": frames_with(|a| a.ghost_pixels > 0),
        "hole_pixel_frames": frames_with(|a| a.hole_pixels > 0),
        "blend_pixel_frames": frames_with(|a| a.blend_pixels > 0),
        "rmse": {
            "median": median_p95(&mut rmse)["median"],
            "max": rmse.iter().copied().fold(0.0, f64::max),
        },
        "events": event_list,
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
    let l = &s["latency_ms"];
    let latency = format!(
        "latency from input to the frame showing it: FC path {} ms median / {} p95, SC path {} ms \
         median / {} p95",
        fmt(&l["fc_path"]["median"]),
        fmt(&l["fc_path"]["p95"]),
        fmt(&l["sc_path"]["median"]),
        fmt(&l["sc_path"]["p95"]),
    );
    if s["audited_frames"] == 0 {
        return format!(
            "{head}\n  {} FC frames, not audited (--no-audit)\n  {latency}",
            s["fc_frames"]
        );
    }
    let mut text = format!(
        "{head}\n  {} FC frames with {} SC buffers; age of the state in the SC buffer, median {} ms\n  \
         {latency}\n  \
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
    );
    for e in s["events"].as_array().into_iter().flatten() {
        text += &format!(
            "\n  {} of {} at {} ms (FC frame {}): {} artefact frame(s), {} ms on screen, peak {} \
             bad pixels",
            e["kind"].as_str().unwrap_or("?"),
            e["object"].as_str().unwrap_or("nothing"),
            fmt(&e["t_ms"]),
            e["fc_frame"],
            e["artefact_frames"],
            fmt(&e["artefact_ms"]),
            e["peak_bad_pixels"],
        );
    }
    text
}
