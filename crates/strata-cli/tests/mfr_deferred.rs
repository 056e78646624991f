//! `strata mfr --deferred` end to end: every frame equals the whole scene lit at once, frames
//! are written, and bad light counts are refused clearly.

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
            "deferred shading, 64x48, 8 FC frames: 8 equal",
            "2 circling",
            "bytes per pixel",
        ],
    );
    let first = strata_core::Rgb8Image::read_png(dir.path().join("frame-0000.png")).expect("png");
    let last = strata_core::Rgb8Image::read_png(dir.path().join("frame-0007.png")).expect("png");
    assert_ne!(first, last, "the lights moved");
}

#[test]
fn bad_deferred_input_is_refused_clearly() {
    let cases: [(&[&str], &[&str]); 2] = [
        (
            &["--deferred", "--lights", "0"],
            &["--lights 0", "at least one light"],
        ),
        (
            &["--deferred", "--clock", "real"],
            &["--deferred", "virtual clock"],
        ),
    ];
    for (args, words) in cases {
        let mut cmd = strata();
        cmd.args(["mfr", "mixed", "--frames", "2"]).args(args);
        let err = run_err(&mut cmd);
        assert_mentions(&err, words);
    }
}
