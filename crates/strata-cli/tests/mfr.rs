//! `strata mfr` end to end: predictive deep composition shows no artefact, naive shows release
//! holes, the summary and per-frame log hold what they say, bad input is refused clearly.

mod common;

use common::{assert_mentions, read_json, run_err, run_ok, strata};

const GRAB: &str = "grab:object=glass sphere,over_lead_ms=0,hold_ms=600,distance=-0.3";

fn mfr(dir: &std::path::Path, migration: &str) -> serde_json::Value {
    let mut cmd = strata();
    cmd.args(["mfr", "mixed", "--size", "96x54", "--trace", GRAB])
        .args(["--clock", "virtual:sc_ms=300,fc_ms=30,transfer_ms=20"])
        .args(["--migration", migration, "--contact-sheets", "--out-dir"])
        .arg(dir);
    let ran = run_ok(&mut cmd);
    assert_mentions(
        &ran.stdout,
        &["strata mfr: mixed", "FC frames", "ghost / hole / blend"],
    );
    read_json(&dir.join("summary.json"))
}

#[test]
fn predictive_deep_composition_equals_the_single_renderer_and_naive_leaves_holes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let predictive = mfr(&dir.path().join("p"), "predictive");
    assert!(predictive["fc_frames"].as_u64().expect("frames") > 30);
    for key in [
        "frames_with_bad_pixels",
        "ghost_pixel_frames",
        "hole_pixel_frames",
        "blend_pixel_frames",
    ] {
        assert_eq!(predictive[key], 0, "{key}");
    }
    let naive = mfr(&dir.path().join("n"), "naive");
    assert!(naive["hole_pixel_frames"].as_u64().expect("holes") > 0);
    assert_eq!(
        naive["ghost_pixel_frames"], 0,
        "deep composition drops the stale copy"
    );
    // The per-frame log has one line per FC frame with the Table 6.1 row of each FC object.
    let log = std::fs::read_to_string(dir.path().join("p/frames.jsonl")).expect("log");
    let lines: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON line"))
        .collect();
    assert_eq!(
        lines.len() as u64,
        predictive["fc_frames"].as_u64().expect("frames")
    );
    let rows: Vec<u64> = lines
        .iter()
        .flat_map(|l| l["fc_objects"].as_array().cloned().unwrap_or_default())
        .filter_map(|o| o["table_6_1_row"].as_u64())
        .collect();
    assert!(
        rows.contains(&3) || rows.contains(&6),
        "the selected object: {rows:?}"
    );
    assert!(rows.iter().all(|r| (1..=6).contains(r)));

    // One select and one release of the sphere; only naive's release leaves artefacts, and every
    // hole frame belongs to it.
    for (s, release_artefacts) in [
        (&predictive, serde_json::json!(0)),
        (&naive, naive["hole_pixel_frames"].clone()),
    ] {
        let events = s["events"].as_array().expect("events");
        let kinds: Vec<&str> = events.iter().filter_map(|e| e["kind"].as_str()).collect();
        assert_eq!(kinds, ["select", "release"]);
        assert!(events.iter().all(|e| e["object"] == "glass sphere"), "{s}");
        assert_eq!(events[0]["artefact_frames"], 0);
        assert_eq!(events[1]["artefact_frames"], release_artefacts);
    }
    assert!(naive["events"][1]["artefact_ms"].as_f64().expect("ms") >= 30.0);
    // On the virtual clock an input waits for the next FC frame (under 30 ms) and is on screen one
    // period later; the SC path adds an SC frame and the transfer (at least 320 ms) and at most
    // two SC frames, the transfer and two FC periods.
    for q in ["median", "p95"] {
        let fc = predictive["latency_ms"]["fc_path"][q]
            .as_f64()
            .expect("FC latency");
        assert!(fc > 30.0 && fc <= 60.0, "FC path {q}: {fc}");
        let sc = predictive["latency_ms"]["sc_path"][q]
            .as_f64()
            .expect("SC latency");
        assert!((320.0..=680.0).contains(&sc), "SC path {q}: {sc}");
    }

    // Contact sheets: one per event; a red strip marks a frame with artefacts.
    let red = |path: std::path::PathBuf| {
        let sheet = strata_core::Rgb8Image::read_png(&path).expect("contact sheet");
        assert_eq!(sheet.height(), 6 + 2 * 54 + 4, "{}", path.display());
        (0..sheet.width()).any(|x| sheet.pixel(x, 0) == [220, 30, 30])
    };
    assert!(!red(dir.path().join("p/event-01-select.png")));
    assert!(!red(dir.path().join("p/event-02-release.png")));
    assert!(!red(dir.path().join("n/event-01-select.png")));
    assert!(red(dir.path().join("n/event-02-release.png")));
}

#[test]
fn save_deep_writes_frames_that_resolve_to_the_saved_pngs() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut cmd = strata();
    cmd.args([
        "mfr", "mixed", "--size", "64x36", "--trace", GRAB, "--frames", "12",
    ])
    .args(["--clock", "virtual:sc_ms=90,fc_ms=30", "--out-dir"])
    .arg(dir.path())
    .args(["--save-frames", "--save-deep"]);
    run_ok(&mut cmd);
    for t in [0, 5, 11] {
        let exr = dir.path().join(format!("frame-{t:04}.exr"));
        let image = strata_exr::read_deep_file(&exr, &strata_exr::Limits::default())
            .unwrap_or_else(|e| panic!("{}: {e}", exr.display()));
        let frame = strata_exr::frame_from_deep(&image, None).expect("a DeepFrame");
        let png = common::read_png(&dir.path().join(format!("frame-{t:04}.png")));
        assert_eq!(frame.resolve([0.92, 0.92, 0.95]), png, "frame {t}");
    }
}

#[test]
fn bad_mfr_input_is_refused_clearly() {
    let dir = tempfile::tempdir().expect("temp dir");
    let bad_trace = dir.path().join("t.toml");
    std::fs::write(&bad_trace, "[[event]]\nt_ms = 0\nbutton = \"sideways\"\n").expect("write");
    let cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (
            vec!["--trace".into(), "grab:object=nothing".into()],
            vec!["no object 'nothing'", "glass torus"],
        ),
        (
            vec!["--clock".into(), "wall".into()],
            vec!["--clock wall", "virtual:sc_ms", "real"],
        ),
        (
            vec!["--clock".into(), "real:fc_hz=5000".into()],
            vec!["fc_hz=5000", "1000"],
        ),
        (
            vec!["--clock".into(), "virtual:sc_ms=0".into()],
            vec!["more than 0"],
        ),
        (
            vec!["--trace".into(), bad_trace.display().to_string()],
            vec!["t.toml", "line 3", "sideways"],
        ),
        (vec!["--size".into(), "0x5".into()], vec!["0x5", "16384"]),
        (
            vec!["--trace".into(), dir.path().display().to_string()],
            vec!["not a regular file"],
        ),
    ];
    for (args, words) in cases {
        let mut cmd = strata();
        cmd.args(["mfr", "mixed"]).args(&args);
        let err = run_err(&mut cmd);
        assert_mentions(&err, &words);
    }
}

#[test]
fn digital_mode_shows_the_transparency_artefact_deep_mode_does_not() {
    let dir = tempfile::tempdir().expect("temp dir");
    let run = |mode: &str| {
        let out = dir.path().join(mode);
        let mut cmd = strata();
        cmd.args(["mfr", "mixed", "--size", "96x54", "--mode", mode])
            .args([
                "--trace",
                "grab:object=glass torus,over_lead_ms=700,hold_ms=300",
            ])
            .args(["--clock", "virtual:sc_ms=300,fc_ms=30", "--out-dir"])
            .arg(&out);
        let ran = run_ok(&mut cmd);
        assert_mentions(&ran.stdout, &[&format!("{mode} composition")]);
        read_json(&out.join("summary.json"))
    };
    let digital = run("digital");
    assert_eq!(digital["mode"], "digital");
    assert!(digital["frames_with_bad_pixels"].as_u64().expect("count") > 0);
    assert!(digital["blend_pixel_frames"].as_u64().expect("count") > 0);
    let deep = run("deep");
    assert_eq!(deep["frames_with_bad_pixels"], 0);
}

#[test]
fn real_time_clients_compose_exactly_and_report_their_times() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut cmd = strata();
    cmd.args([
        "mfr", "mixed", "--size", "64x36", "--trace", GRAB, "--frames", "24",
    ])
    .args(["--clock", "real:fc_hz=60", "--out-dir"])
    .arg(dir.path());
    let ran = run_ok(&mut cmd);
    assert_mentions(&ran.stdout, &["clock real", "FC at 60", "hand-over"]);
    let s = read_json(&dir.path().join("summary.json"));
    assert_eq!(s["clock"]["kind"], "real");
    assert_eq!(s["fc_frames"], 24);
    assert_eq!(s["frames_with_bad_pixels"], 0, "exact whatever the timing");
    for key in ["fc_frame_ms", "sc_frame_ms"] {
        assert!(
            s[key]["median"].as_f64().is_some_and(|v| v > 0.0),
            "{key}: {s}"
        );
    }
    assert!(s["swap_us"]["max"].as_f64().is_some(), "{s}");
    // Inputs reach the screen on the FC path in real time too: after at least one FC frame.
    let fc = s["latency_ms"]["fc_path"]["median"]
        .as_f64()
        .expect("latency");
    assert!(fc > 0.0, "{s}");
    assert!(s["cpu"].as_str().is_some_and(|c| !c.is_empty()));
}

#[test]
fn interleaved_runs_are_exact_and_report_their_chunking() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut cmd = strata();
    cmd.args([
        "mfr", "mixed", "--size", "64x36", "--trace", GRAB, "--frames", "24",
    ])
    .args([
        "--clock",
        "real:fc_hz=30",
        "--interleaved",
        "fixed:40",
        "--out-dir",
    ])
    .arg(dir.path());
    let ran = run_ok(&mut cmd);
    assert_mentions(&ran.stdout, &["interleaved (fixed:40)", "FC deadlines hit"]);
    let s = read_json(&dir.path().join("summary.json"));
    assert_eq!(s["frames_with_bad_pixels"], 0, "exact whatever the timing");
    let i = &s["interleaved"];
    assert_eq!(i["chunking"], "fixed:40");
    let rate = i["fc_deadline_hit_rate"].as_f64().expect("hit rate");
    assert!((0.0..=1.0).contains(&rate), "{i}");
    assert!(i["sc_frames"].as_u64().is_some(), "{i}");
    assert!(i["sc_one_shot_ms"].as_f64().is_some_and(|v| v > 0.0), "{i}");
    // Every period recorded, every miss laid on a cause.
    let periods = i["periods"].as_array().expect("periods");
    assert_eq!(periods.len(), 24, "{i}");
    let hit = periods.iter().filter(|p| p["hit"] == true).count() as f64;
    assert!((hit / 24.0 - rate).abs() < 1e-9, "{i}");
    let missed = &i["fc_deadlines_missed"];
    let causes = ["fc_frame", "caller", "sc_start", "chunk", "export_band"];
    let by_cause: u64 = causes
        .iter()
        .map(|c| missed[c].as_u64().expect("count"))
        .sum();
    assert_eq!(missed["total"].as_u64(), Some(by_cause), "{i}");
    assert_eq!(by_cause as f64, 24.0 - hit, "{i}");
    assert_mentions(&ran.stdout, &["deadlines missed after"]);
    assert!(
        i["chunk_estimate_ratio"].is_null(),
        "the fixed mode predicts nothing: {i}"
    );
    // Not with a slow client elsewhere.
    let mut cmd = strata();
    cmd.args([
        "mfr",
        "mixed",
        "--clock",
        "real",
        "--interleaved",
        "--sc-load",
        "idle",
    ]);
    assert_mentions(&run_err(&mut cmd), &["--interleaved", "--sc-load"]);
}
