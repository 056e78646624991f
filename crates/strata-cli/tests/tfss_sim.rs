//! `strata tfss-sim` end to end on the built-in `overlap` scene (640×480, two quads): the tables,
//! the JSON figures and the Lin 2007 formulas behind them, and the errors.

use std::path::Path;

use assert_cmd::Command;
use serde_json::Value;
use tempfile::TempDir;

fn strata() -> Command {
    Command::cargo_bin("strata").expect("the strata binary is built for integration tests")
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().expect("strata runs");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "expected success\nstdout:\n{stdout}\nstderr:\n{stderr}"
    );
    assert!(!stderr.contains("panicked at"), "{stderr}");
    stdout
}

fn run_err(cmd: &mut Command) -> String {
    let out = cmd.output().expect("strata runs");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(!stderr.contains("panicked at"), "{stderr}");
    assert!(stderr.contains("strata: error:"), "{stderr}");
    stderr
}

fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).expect("json written");
    serde_json::from_str(&text).expect("valid JSON")
}

fn u(v: &Value) -> u64 {
    v.as_u64()
        .unwrap_or_else(|| panic!("not an unsigned integer: {v}"))
}

#[test]
fn tfss_sim_prints_the_seeds_tables_and_writes_consistent_json() {
    let dir = TempDir::new().unwrap();
    let json = dir.path().join("tfss.json");
    let stdout = run_ok(
        strata()
            .args(["tfss-sim", "overlap", "--l-num-max", "3", "--json"])
            .arg(&json),
    );
    for needle in [
        "distribution (Table 4-1)",
        "N=1",
        "N=2",
        "R-buffer",
        "WF(1)",
        "TFSS(3)",
        "TFSS(2, 12) LZ",
        "LOSSY",
        "DeepFrame",
        "compact runs",
        "TFSS store(3) LZ b=",
        "time (§4.3.2",
    ] {
        assert!(stdout.contains(needle), "expected {needle:?} in:\n{stdout}");
    }

    let doc = read_json(&json);
    assert_eq!(doc["scene"], "overlap");
    assert_eq!((u(&doc["width"]), u(&doc["height"])), (640, 480));
    assert_eq!(u(&doc["sizes"]["address"]), 4);
    let f = &doc["frames"][0];
    assert_eq!(u(&f["frame"]), 0);

    // Table 4-1: the two quads overlap in a band; every fragment is transparent (alpha 128).
    let d = &f["distribution"];
    let n: Vec<u64> = d["pixels_with_n"]
        .as_array()
        .unwrap()
        .iter()
        .map(u)
        .collect();
    assert_eq!(n, [67_537, 16_688]);
    let fragments = 67_537 + 2 * 16_688;
    assert_eq!(u(&d["fragments"]), fragments);
    assert_eq!(u(&d["transparent_fragments"]), fragments);
    assert_eq!(u(&d["transparent_pixels"]), 67_537 + 16_688);
    assert_eq!(u(&d["d_avg"]), 1);
    // Every colour is full-width red or blue: eight bits, seven after the alpha shift.
    assert_eq!(u(&f["colour_bits"]["lossless"][8]), fragments);
    assert_eq!(u(&f["colour_bits"]["alpha_shift_lossy"][7]), fragments);

    // Table 4-2 with S_A = 4: R-buffer 12·N_f + 4·W·H + 3·W·H/8.
    let pixels = 640 * 480;
    let m = &f["memory"];
    assert_eq!(
        u(&m["rbuffer"]["bytes"]),
        12 * fragments + 4 * pixels + 3 * pixels / 8
    );
    // WF(1): every pixel one section of 8 B, plus one per second fragment, 4-byte pointers.
    assert_eq!(u(&m["wf"]["bytes"]), (pixels + 16_688) * (8 + 4));
    // TFSS(1): N_S = N_f sections of 8 B, SSA, NSA.
    let tfss = m["tfss"].as_array().unwrap();
    assert_eq!(tfss.len(), 3);
    assert_eq!(
        u(&tfss[0]["plain"]["bytes"]),
        8 * fragments + 4 * pixels + 4 * fragments
    );
    // TFSS(2): one section per covered pixel.
    let covered = 67_537 + 16_688;
    assert_eq!(
        u(&tfss[1]["plain"]["bytes"]),
        16 * covered + 4 * pixels + 4 * covered
    );
    // Full-width colours leave nothing to eliminate, but most pixels hold one fragment: the
    // cheapest budget is b = 2 (the widest of 0..=2, whose colour area 2·(8 + 3b) is raised to
    // the 32 bits of one full-width record): a 12-byte section (two depths, 64 bits, and one
    // record) that takes one fragment, so every fragment gets a section, with its NSA entry and
    // a 1-byte Length entry.
    assert_eq!(u(&tfss[1]["lz"]["rgb_bits"]), 2);
    assert_eq!(tfss[1]["lz"]["technique"], "TFSS(2, 12) LZ");
    assert_eq!(
        u(&tfss[1]["lz"]["bytes"]),
        12 * fragments + 4 * pixels + 4 * fragments + fragments
    );
    let r = tfss[0]["plain"]["reduction_vs_rbuffer"].as_f64().unwrap();
    let want = 1.0 - u(&tfss[0]["plain"]["bytes"]) as f64 / u(&m["rbuffer"]["bytes"]) as f64;
    assert!((r - want).abs() < 1e-12);

    // The real store rendered every L_num with and without elimination, and uses what the model
    // says strata's TFSS store uses.
    let store = f["store"].as_array().unwrap();
    assert_eq!(store.len(), 6);
    for (i, s) in store.iter().enumerate() {
        let l = i / 2 + 1;
        assert_eq!(u(&s["l_num"]), l as u64);
        assert_eq!(s["leading_zeros"].as_bool(), Some(i % 2 == 1));
        if i % 2 == 0 {
            assert_eq!(
                u(&s["used_bytes"]),
                u(&tfss[l - 1]["strata_store_model"]["bytes"])
            );
            assert!(s["rgb_bits"].is_null());
        } else {
            assert!(u(&s["rgb_bits"]) <= 8);
        }
        assert!(u(&s["allocated_bytes"]) >= u(&s["used_bytes"]));
    }

    // §4.3.2: R-buffer 2·Σ N_i·i(i+1)/2 + N_f accesses, Σ N_i·i(i+1)/2 computation.
    let tri = 67_537 + 3 * 16_688;
    let t = f["time"].as_array().unwrap();
    assert_eq!(t[0]["technique"], "R-buffer");
    assert_eq!(u(&t[0]["cycles"]), 3 * tri + fragments);
    assert_eq!(u(&t[1]["cycles"]), fragments + 67_537 + 2 * 16_688);
    assert_eq!(
        u(&t[2]["cycles"]),
        fragments + covered + 67_537 + 2 * 16_688
    );
    let avg = &doc["averages"]["time"]["tfss_reduction_vs_rbuffer"];
    assert_eq!(avg, &t[2]["reduction_vs_rbuffer"]);
}

#[test]
fn help_explains_the_columns_and_cites_the_seed() {
    let out = run_ok(strata().args(["tfss-sim", "--help"]));
    for needle in [
        "Table 4-1",
        "Table 4-2",
        "Figures 4-4 and 4-6",
        "§4.3.2",
        "density",
        "vs R-buffer",
        "D_avg",
        "LOSSY",
        "compact runs",
        "--address-bytes",
    ] {
        assert!(out.contains(needle), "expected {needle:?} in help:\n{out}");
    }
}

#[test]
fn bad_arguments_fail_before_rendering() {
    let dir = TempDir::new().unwrap();
    let err = run_err(strata().args(["tfss-sim", "overlap", "--frames", "2"]));
    assert!(err.contains("only 1 frame"), "{err}");
    let err = run_err(strata().args(["tfss-sim", "overlap", "--frame", "3"]));
    assert!(err.contains("frame 3 does not exist"), "{err}");
    let missing = dir.path().join("no/such/dir/out.json");
    let err = run_err(
        strata()
            .args(["tfss-sim", "overlap", "--json"])
            .arg(&missing),
    );
    assert!(err.contains("does not exist"), "{err}");
}
