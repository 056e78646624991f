//! `strata compare` end to end: the table, report.json, images and heat maps.

mod common;

use common::strata;
use tempfile::TempDir;

#[test]
fn compare_writes_a_report_with_metrics_against_the_reference() {
    let dir = TempDir::new().unwrap();
    let out = strata()
        .args([
            "compare", "overlap", "--runs", "2", "--warmup", "0", "-j", "2",
        ])
        .args(["--methods", "abuffer,abuffer:pool=60000"])
        .arg("--out-dir")
        .arg(dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("RMSE") && stdout.contains("mean FLIP"),
        "{stdout}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let methods = report["methods"].as_array().unwrap();
    assert_eq!(methods.len(), 2);
    // The reference compared with itself: no error at all.
    let exact = &methods[0];
    assert_eq!(exact["label"], "abuffer");
    assert_eq!(exact["rmse"], 0.0);
    assert_eq!(exact["mean_flip"], 0.0);
    assert_eq!(exact["bad_pixels"]["count"], 0);
    assert_eq!(exact["fragments_lost"], 0);
    assert!(exact["passes_ms"]["capture"].as_f64().unwrap() > 0.0);
    // A pool of 60,000 nodes cannot hold overlap's 100,913 fragments: errors and losses show.
    let small = &methods[1];
    assert_eq!(
        small["fragments_stored"].as_u64().unwrap() + small["fragments_lost"].as_u64().unwrap(),
        100_913
    );
    assert!(small["rmse"].as_f64().unwrap() > 0.0);
    assert!(small["mean_flip"].as_f64().unwrap() > 0.0);
    assert!(small["bad_pixels"]["count"].as_u64().unwrap() > 0);
    assert_eq!(report["bad_pixel_threshold"], 2);
    for f in [
        "reference.png",
        "abuffer.png",
        "abuffer-flip.png",
        "abuffer_pool_60000.png",
        "abuffer_pool_60000-flip.png",
        "report.md",
        "report.html",
    ] {
        assert!(dir.path().join(f).is_file(), "{f} missing");
    }
    let html = std::fs::read_to_string(dir.path().join("report.html")).unwrap();
    assert!(html.contains("abuffer:pool=60000") && html.contains("abuffer_pool_60000-flip.png"));
}

#[test]
fn compare_rejects_bad_specs_before_rendering() {
    let dir = TempDir::new().unwrap();
    for (methods, needle) in [
        ("abuffer,nosuch", "unknown method 'nosuch'"),
        ("abuffer:k", "k needs a value"),
        ("abuffer:colour=red", "unknown option 'colour'"),
        ("abuffer,abuffer", "listed twice"),
    ] {
        let out = strata()
            .args(["compare", "overlap", "--methods", methods, "--out-dir"])
            .arg(dir.path())
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "{methods}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("strata: error:") && err.contains(needle),
            "{methods}: {err}"
        );
        assert!(!err.contains("panicked"));
        assert!(
            !dir.path().join("report.json").exists(),
            "{methods}: rendered before failing"
        );
    }
}

/// Options of other methods, out-of-range values, a reference that is not exact and a bad `--ppd`
/// fail before the report folder is made.
#[test]
fn compare_refuses_foreign_options_bad_values_and_inexact_references() {
    let dir = TempDir::new().unwrap();
    let out_dir = dir.path().join("report");
    let cases: [(&[&str], &[&str]); 10] = [
        (
            &[
                "--methods",
                "kbuffer",
                "--reference",
                "abuffer",
                "--pool",
                "4x",
            ],
            &[
                "--reference abuffer",
                "bounded",
                "apply to the reference too",
            ],
        ),
        (
            &["--methods", "kbuffer:pool=4x"],
            &[
                "'kbuffer:pool=4x'",
                "method kbuffer",
                "pool",
                "abuffer, tfss",
            ],
        ),
        (
            &["--methods", "vkbuffer:k-from=optimal:range-bias=0.5"],
            &["method vkbuffer with k-from optimal", "range-bias"],
        ),
        (
            &["--methods", "vkbuffer:range-bias=2"],
            &["range-bias=2", "[0, 1]"],
        ),
        (
            &["--methods", "vkbuffer:point-of-interest=5,5"],
            &["point-of-interest", "[0, 1]"],
        ),
        (&["--methods", "kbuffer:k=0"], &["k=0", "from 1 to 1024"]),
        (
            &["--methods", "kbuffer,abuffer", "--budget", "20%"],
            &[
                "--budget",
                "not an option of any method compared",
                "vkbuffer",
            ],
        ),
        (
            &["--methods", "abuffer", "--reference", "kbuffer"],
            &[
                "--reference kbuffer",
                "exact",
                "bounded",
                "abuffer, sbuffer",
            ],
        ),
        (
            &["--methods", "abuffer", "--reference", "wboit"],
            &[
                "--reference wboit",
                "approximate (weighted blend; keeps no fragments)",
            ],
        ),
        (
            &["--methods", "abuffer", "--ppd", "0"],
            &["--ppd", "positive"],
        ),
    ];
    for (args, needles) in cases {
        let out = strata()
            .args(["compare", "overlap", "--runs", "1", "--warmup", "0"])
            .args(args)
            .arg("--out-dir")
            .arg(&out_dir)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains("strata: error:") && !err.contains("panicked"),
            "{err}"
        );
        for n in needles {
            assert!(err.contains(n), "{args:?}: expected {n:?} in {err}");
        }
        assert!(!out_dir.exists(), "{args:?}: wrote the report folder");
    }
}

/// The report's FLIP heat maps come with a colour bar from 0 to 1, an approximate method is
/// described as such, and the JSON says how faithful each method is.
#[test]
fn compare_report_has_a_flip_legend_and_describes_approximate_methods() {
    let dir = TempDir::new().unwrap();
    let out = strata()
        .args([
            "compare", "overlap", "--runs", "1", "--warmup", "0", "-j", "2",
        ])
        .args(["--methods", "wboit,kbuffer:k=1", "--reference", "sbuffer"])
        .arg("--out-dir")
        .arg(dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("none (blended)"), "{stdout}");
    let html = std::fs::read_to_string(dir.path().join("report.html")).unwrap();
    assert!(html.contains("linear-gradient"), "no colour bar");
    for tick in ["<span>0</span>", "<span>0.500</span>", "<span>1</span>"] {
        assert!(html.contains(tick), "{tick} missing from the FLIP legend");
    }
    assert!(html.contains("approximate (weighted blend; keeps no fragments)"));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let m = &report["methods"];
    assert_eq!(
        m[0]["fidelity"],
        "approximate (weighted blend; keeps no fragments)"
    );
    assert!(m[1]["fidelity"].as_str().unwrap().starts_with("bounded"));
    assert!(report["cpu"].as_str().is_some_and(|c| !c.is_empty()));
}
