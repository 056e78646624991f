//! `strata mfr --warp` end to end: under an orbit the warped run shows camera moves one FC frame
//! after they happen (the unwarped run at the SC's pace), reports the holes it filled, and is
//! closer to the exact render at the current view; `--warp` on the real clock is refused.

mod common;

use common::{assert_mentions, read_json, run_err, run_ok, strata};

fn orbit(dir: &std::path::Path, warp: bool) -> serde_json::Value {
    let mut cmd = strata();
    cmd.args(["mfr", "mixed", "--size", "96x54"])
        .args(["--trace", "orbit:period_ms=2000,duration_ms=600"])
        .args(["--clock", "virtual:sc_ms=300,fc_ms=30", "--out-dir"])
        .arg(dir);
    if warp {
        cmd.arg("--warp");
    }
    let ran = run_ok(&mut cmd);
    assert_mentions(&ran.stdout, &["bad pixels vs current view", "view latency"]);
    read_json(&dir.join("summary.json"))
}

#[test]
fn warping_shows_camera_moves_at_the_fc_rate_and_fills_holes() {
    let (a, b) = (
        tempfile::tempdir().expect("temp dir"),
        tempfile::tempdir().expect("temp dir"),
    );
    let plain = &orbit(a.path(), false)["view"];
    let warped = &orbit(b.path(), true)["view"];
    let f = |v: &serde_json::Value, path: &[&str]| {
        path.iter()
            .fold(v, |v, k| &v[*k])
            .as_f64()
            .unwrap_or_else(|| panic!("{path:?} missing in {v}"))
    };
    // Within two FC periods (an event waits for the next frame, which is on screen one period
    // later), against at least one SC frame.
    assert!(f(warped, &["view_latency_ms", "max"]) < 60.0);
    assert!(f(plain, &["view_latency_ms", "median"]) >= 300.0);
    assert!(f(warped, &["hole_pixels_per_frame"]) > 0.0);
    assert!(f(warped, &["holes_left_per_frame"]) < f(warped, &["hole_pixels_per_frame"]));
    assert_eq!(f(plain, &["hole_pixels_per_frame"]), 0.0);
    assert!(f(warped, &["rmse_vs_current_view"]) < f(plain, &["rmse_vs_current_view"]));
}

#[test]
fn warp_needs_the_virtual_clock() {
    let mut cmd = strata();
    cmd.args(["mfr", "mixed", "--clock", "real", "--warp"]);
    assert_mentions(&run_err(&mut cmd), &["--warp", "virtual clock"]);
}
