//! `strata mfr` on the built-in `mfr-cars`: the default grab takes the steering wheel into the
//! cabin behind the transparent windscreen; deep composition shows it exactly, digital and optical
//! composition do not.

mod common;

use common::{assert_mentions, read_json, run_ok, strata};

#[test]
fn mfr_cars_default_grab_is_exact_only_in_deep_mode() {
    let dir = tempfile::tempdir().expect("temp dir");
    let run = |mode: &str| {
        let out = dir.path().join(mode);
        let mut cmd = strata();
        cmd.args(["mfr", "mfr-cars", "--size", "96x54", "--mode", mode])
            .args(["--trace", "grab:over_lead_ms=450,hold_ms=500,linger_ms=100"])
            .args(["--clock", "virtual:sc_ms=200,fc_ms=25", "--out-dir"])
            .arg(&out);
        let ran = run_ok(&mut cmd);
        assert_mentions(
            &ran.stdout,
            &["strata mfr: mfr-cars", &format!("{mode} composition")],
        );
        let log = std::fs::read_to_string(out.join("frames.jsonl")).expect("log");
        assert!(
            log.lines().any(|l| {
                let v: serde_json::Value = serde_json::from_str(l).expect("JSON line");
                v["fc_objects"].as_array().is_some_and(|objects| {
                    objects
                        .iter()
                        .any(|o| o["object"] == "steering wheel" && o["state"] == "selected")
                })
            }),
            "{mode}: the FC never drew the selected steering wheel"
        );
        read_json(&out.join("summary.json"))
    };
    let deep = run("deep");
    assert_eq!(deep["frames_with_bad_pixels"], 0, "{deep}");
    for mode in ["digital", "optical"] {
        let s = run(mode);
        assert_eq!(s["mode"], mode);
        assert!(
            s["frames_with_bad_pixels"].as_u64().expect("count") > 0,
            "{mode}: {s}"
        );
    }
}

#[test]
fn mode_help_says_what_optical_composition_gets_wrong() {
    let ran = run_ok(strata().args(["mfr", "--help"]));
    assert_mentions(
        &ran.stdout,
        &["optical", "always drawn over", "digital", "deep"],
    );
}
