//! `strata dataset` and the feature maps of `strata render --maps`: what they write, and the
//! errors they give before rendering anything.

mod common;

use common::{read_json, run_err, run_ok, strata};
use strata_core::npy::{self, NpyValues};
use strata_stores::kbuffer::features::{FEATURE_COUNT, FEATURE_SET, feature_names};
use tempfile::TempDir;

/// `strata dataset` of two generated scenes and `overlap`, 64 × 48, into `out` on `threads`.
fn small_dataset(out: &std::path::Path, threads: u32) -> assert_cmd::Command {
    let mut c = strata();
    c.args([
        "dataset",
        "--procedural",
        "2",
        "--scenes",
        "overlap",
        "--views",
        "2",
    ])
    .args([
        "--budgets",
        "40,80",
        "--pixels-per-frame",
        "100",
        "--size",
        "64x48",
    ])
    .args(["--seed", "9", "-j", &threads.to_string(), "--out"])
    .arg(out);
    c
}

#[test]
fn dataset_writes_arrays_that_match_its_manifest() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("data");
    let ran = run_ok(&mut small_dataset(&out, 2));
    assert!(ran.stderr.contains("wrote"), "{}", ran.stderr);
    let m = read_json(&out.join("manifest.json"));
    assert_eq!(m["feature_set"], FEATURE_SET);
    assert_eq!(m["features"], serde_json::json!(feature_names()));
    let scenes = m["scenes"].as_array().unwrap();
    let families: Vec<&str> = scenes
        .iter()
        .map(|s| s["family"].as_str().unwrap())
        .collect();
    assert_eq!(families, ["procedural", "procedural", "overlap"]);
    let frames = m["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 3 * 2 * 2);
    for f in frames {
        let (budget, total) = (
            f["budget"].as_u64().unwrap(),
            f["fragments"].as_u64().unwrap(),
        );
        assert_eq!(f["sum_k"].as_u64().unwrap(), budget.min(total));
        assert!(f["rows"].as_u64().unwrap() <= 100);
    }
    let rows = m["rows"].as_u64().unwrap() as usize;
    assert!(rows > 0);
    let features = npy::read(out.join("features.npy")).unwrap();
    assert_eq!(features.shape, [rows, FEATURE_COUNT]);
    let frame = npy::read(out.join("frame.npy")).unwrap();
    let NpyValues::U32(ids) = frame.values else {
        panic!("frame.npy should hold uint32");
    };
    assert!(ids.iter().all(|&id| (id as usize) < frames.len()));
    // The same command gives the same files.
    let again = dir.path().join("again");
    run_ok(&mut small_dataset(&again, 1));
    assert_eq!(read_json(&again.join("manifest.json")), m);
}

#[test]
fn dataset_refuses_bad_input_before_rendering() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("data");
    let cases: [(&[&str], &str); 5] = [
        (
            &["--procedural", "1", "--budgets", "50,0"],
            "above 0 % and up to 100 %",
        ),
        (
            &["--procedural", "1", "--budgets", "120"],
            "above 0 % and up to 100 %",
        ),
        (&["--scenes", "no-such-scene"], "no-such-scene"),
        (&[], "nothing to render"),
        (&["--procedural", "1", "--size", "0x10"], "WIDTHxHEIGHT"),
    ];
    for (args, says) in cases {
        let err = run_err(strata().arg("dataset").args(args).arg("--out").arg(&out));
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(
            !out.join("manifest.json").exists(),
            "{args:?} wrote a manifest"
        );
    }
    let file = dir.path().join("file");
    std::fs::write(&file, "").unwrap();
    let err = run_err(
        strata()
            .args(["dataset", "--procedural", "1", "--out"])
            .arg(&file),
    );
    assert!(err.contains("not a directory"), "{err}");
    // A folder that cannot be created (its parent is a file) is refused before rendering.
    let err = run_err(
        strata()
            .args(["dataset", "--procedural", "1", "--out"])
            .arg(file.join("sub")),
    );
    assert!(err.contains("cannot create the folder"), "{err}");
    assert!(!err.contains("scene 1/1"), "it rendered first: {err}");
}

#[test]
fn render_maps_include_the_feature_maps() {
    let dir = TempDir::new().unwrap();
    let maps = dir.path().join("maps");
    run_ok(
        strata()
            .args([
                "render", "overlap", "--method", "vkbuffer", "--budget", "50%", "--maps",
            ])
            .arg(&maps)
            .arg("--out")
            .arg(dir.path().join("vk.png")),
    );
    let features = npy::read(maps.join("features.npy")).unwrap();
    assert_eq!(features.shape, [480, 640, FEATURE_COUNT]);
    let json = read_json(&maps.join("features.json"));
    assert_eq!(json["feature_set"], FEATURE_SET);
    let names: Vec<&str> = json["features"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, feature_names());
    // The count column is the k map's own frame: its sum is the frame's fragments.
    let NpyValues::F32(values) = features.values else {
        panic!("features.npy should hold float32");
    };
    let count = names.iter().position(|&n| n == "count").unwrap();
    let total: f64 = values
        .chunks_exact(FEATURE_COUNT)
        .map(|row| f64::from(row[count]))
        .sum();
    assert_eq!(total, json["frame"]["fragments"].as_f64().unwrap());
}

#[test]
fn dataset_help_lists_its_options() {
    let ran = run_ok(strata().args(["dataset", "--help"]));
    strata_testdata::assert_mentions(
        &ran.stdout,
        &[
            "--out",
            "--scenes",
            "--procedural",
            "--views",
            "--budgets",
            "--pixels-per-frame",
            "--seed",
            "--size",
            "--skip-missing",
            "--threads",
            "--models",
        ],
    );
    let ran = run_ok(strata().arg("--help"));
    assert!(ran.stdout.contains("dataset"), "{}", ran.stdout);
}
