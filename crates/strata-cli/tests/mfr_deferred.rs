//! `strata mfr --deferred` end to end: every frame equals the whole scene lit at once, frames
//! are written, the forward comparison (`--shade-on sc`) lags and says so in summary.json, and
//! bad light counts are refused clearly.

mod common;

use common::{assert_mentions, run_err, run_ok, strata};

#[test]
fn deferred_frames_equal_the_whole_scene_lit_at_once() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut cmd = strata();
    cmd.args([
        "mfr",
        "mixed",
        "--deferred",
        "--lights",
        "2",
        "--size",
        "64x48",
    ])
    .args([
        "--trace",
        "grab:over_lead_ms=0,hold_ms=200",
        "--frames",
        "8",
    ])
    .args([
        "--clock",
        "virtual:sc_ms=90,fc_ms=30",
        "--save-frames",
        "--out-dir",
    ])
    .arg(dir.path());
    let ran = run_ok(&mut cmd);
    assert_mentions(
        &ran.stdout,
        &[
            "deferred shading (lit by the fast client), 64x48, 8 FC frames: 8 equal",
            "0.0 bad pixels a frame",
            "lights: 2",
            "(FC path)",
            "bytes per pixel",
        ],
    );
    let first = strata_core::Rgb8Image::read_png(dir.path().join("frame-0000.png")).expect("png");
    let last = strata_core::Rgb8Image::read_png(dir.path().join("frame-0007.png")).expect("png");
    assert_ne!(first, last, "the lights moved");
}

/// The same lights, shaded on the SC: its objects' lighting lags by the SC path, and frames
/// differ from the whole scene lit by the frame's lights while the lights move.
#[test]
fn forward_shading_lags_and_summary_json_says_by_how_much() {
    let mut lags = Vec::new();
    for shade_on in ["fc", "sc"] {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut cmd = strata();
        cmd.args(["mfr", "mixed", "--deferred", "--shade-on", shade_on])
            .args([
                "--trace",
                "lights:count=3,period_ms=600,duration_ms=400,step_ms=50",
            ])
            .args(["--size", "64x48", "--frames", "16"])
            .args(["--clock", "virtual:sc_ms=100,fc_ms=25", "--out-dir"])
            .arg(dir.path());
        run_ok(&mut cmd);
        let text = std::fs::read_to_string(dir.path().join("summary.json")).expect("summary");
        let v: serde_json::Value = serde_json::from_str(&text).expect("json");
        let d = &v["deferred"];
        assert_eq!(d["shade_on"], shade_on);
        assert_eq!(d["lights"]["max"], 3);
        assert_eq!(d["light_events"], 27, "3 lights keyed at 0, 50, …, 400 ms");
        let bad = d["bad_pixels_per_frame"].as_f64().expect("a number");
        let equal = d["frames_equal_to_reference"].as_u64().expect("a count");
        if shade_on == "fc" {
            assert_eq!((bad, equal), (0.0, 16), "deferred is exact");
        } else {
            assert!(
                bad > 0.0 && equal < 16,
                "forward lags: {bad} bad px, {equal} equal"
            );
        }
        lags.push(d["light_lag_ms"]["median"].as_f64().expect("a lag"));
    }
    // One FC frame (or two, waiting for the next frame) against an SC frame and more.
    assert!(lags[0] <= 50.0 && lags[1] >= 125.0, "{lags:?}");
}

#[test]
fn bad_deferred_input_is_refused_clearly() {
    let cases: [(&[&str], &[&str]); 4] = [
        (
            &["--deferred", "--lights", "0"],
            &["--lights 0", "at least one light"],
        ),
        (
            &["--deferred", "--clock", "real"],
            &["--deferred", "virtual clock"],
        ),
        (
            &["--deferred", "--trace", "lights:count=0"],
            &["count=0", "1 to 64 lights"],
        ),
        (&["--shade-on", "sc"], &["--deferred"]),
    ];
    for (args, words) in cases {
        let mut cmd = strata();
        cmd.args(["mfr", "mixed", "--frames", "2"]).args(args);
        let err = run_err(&mut cmd);
        assert_mentions(&err, words);
    }
}
