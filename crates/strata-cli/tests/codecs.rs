//! `strata codecs` end to end: the table and the JSON figures on the built-in `spheres` scene,
//! codec selection on a small copy of it, and the errors (exit code 2, `strata: error: …`, no
//! panic).

mod common;

use std::path::Path;

use common::{assert_mentions, read_json, run_err, run_ok, strata, strata_without_models};
use serde_json::Value;
use tempfile::TempDir;

fn u(v: &Value) -> u64 {
    v.as_u64()
        .unwrap_or_else(|| panic!("not an unsigned integer: {v}"))
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn u64s(v: &Value) -> Vec<u64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(u)
        .collect()
}

/// The table row of `codec`: its whitespace-separated columns.
fn row<'a>(stdout: &'a str, codec: &str) -> Vec<&'a str> {
    stdout
        .lines()
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        .find(|cols| cols.first() == Some(&codec))
        .unwrap_or_else(|| panic!("no row for {codec} in:\n{stdout}"))
}

/// Bytes of a frame message before its section table, and per table entry.
const HEADER: u64 = 188;
const ENTRY: u64 = 20;

#[test]
fn codecs_on_spheres_prints_every_codec_and_writes_consistent_json() {
    let dir = TempDir::new().unwrap();
    let json = dir.path().join("codecs.json");
    let stdout = run_ok(
        strata()
            .args([
                "codecs", "spheres", "--frames", "2", "--runs", "1", "-j", "2", "--json",
            ])
            .arg(&json),
    )
    .stdout;
    assert_mentions(
        &stdout,
        &[
            "strata codecs: spheres",
            "1280x720",
            "2 frame(s) [0, 36]",
            "every decode round-tripped bit-exactly",
            "% of 16N",
            "enc MB/s",
            "dec MB/s",
            "reused MB/s",
            "for scale: LZ4 on the plain layout",
        ],
    );
    let names = ["raw", "lz4", "zstd", "deep-lz4", "deep-zstd", "deep-huff"];
    for name in names {
        let cols = row(&stdout, name);
        assert!(cols.len() >= 12, "{name}: {cols:?}");
    }
    // The deep rows break their bytes down by section.
    for name in ["deep-lz4", "deep-zstd", "deep-huff"] {
        assert_mentions(
            &row(&stdout, name).join(" "),
            &["counts", "depth", "color", "object"],
        );
    }

    let doc = read_json(&json);
    assert_eq!(doc["scene"], "spheres");
    assert_eq!((u(&doc["width"]), u(&doc["height"])), (1280, 720));
    assert_eq!(u64s(&doc["frames"]), vec![0, 36]);
    assert_eq!(u(&doc["runs"]), 1);
    assert_eq!(u(&doc["threads"]), 2);
    let fragments = u64s(&doc["fragments_per_frame"]);
    assert_eq!(fragments.len(), 2);
    assert!(fragments.iter().all(|&n| n > 100_000), "{fragments:?}");
    let codecs = doc["codecs"].as_array().expect("codecs array");
    let listed: Vec<&str> = codecs
        .iter()
        .map(|c| c["codec"].as_str().unwrap())
        .collect();
    assert_eq!(listed, names);
    let bytes = |name: &str| -> Vec<u64> {
        let c = codecs.iter().find(|c| c["codec"] == name).unwrap();
        u64s(&c["bytes_per_frame"])
    };
    let (raw, lz4, deep_zstd) = (bytes("raw"), bytes("lz4"), bytes("deep-zstd"));
    let (deep_lz4, deep_huff) = (bytes("deep-lz4"), bytes("deep-huff"));
    for i in 0..2 {
        // Huffman blocks take the noisy residual planes below what LZ4 keeps of them.
        assert!(
            deep_huff[i] < deep_lz4[i],
            "frame {i}: deep-huff {} deep-lz4 {}",
            deep_huff[i],
            deep_lz4[i]
        );
        assert!(
            deep_zstd[i] < lz4[i] && lz4[i] < raw[i],
            "frame {i}: deep-zstd {} lz4 {} raw {}",
            deep_zstd[i],
            lz4[i],
            raw[i]
        );
        // Raw is the thesis layout: 4 bytes a pixel, 12 a fragment, after one table entry.
        assert_eq!(raw[i], HEADER + ENTRY + 4 * 1280 * 720 + 12 * fragments[i]);
    }
    // The LZ4 reference is the lz4 codec itself.
    assert_eq!(u64s(&doc["list_lz4_bytes_per_frame"]), lz4);

    let total_fragments: u64 = fragments.iter().sum();
    for c in codecs {
        let name = c["codec"].as_str().unwrap();
        let per_frame = u64s(&c["bytes_per_frame"]);
        assert_eq!(per_frame.len(), 2, "{name}");
        let total: u64 = per_frame.iter().sum();
        let mean = f(&c["mean_bytes_per_frame"]);
        assert!((mean - total as f64 / 2.0).abs() < 1e-6, "{name}");
        let of_16n = 100.0 * total as f64 / (16 * total_fragments) as f64;
        assert!((f(&c["percent_of_16n"]) - of_16n).abs() < 1e-9, "{name}");
        let of_lz4 = 100.0 * total as f64 / lz4.iter().sum::<u64>() as f64;
        assert!(
            (f(&c["percent_of_list_lz4"]) - of_lz4).abs() < 1e-9,
            "{name}"
        );
        assert!(f(&c["encode_ms_median"]) >= 0.0 && f(&c["decode_ms_median"]) >= 0.0);
        // Throughput is the DeepFrame's 16 bytes a fragment over the median time.
        let raw_mb = 16.0 * total_fragments as f64 / 2.0 / 1e6;
        for (mb_s, ms) in [
            ("encode_mb_per_s", "encode_ms_median"),
            ("decode_mb_per_s", "decode_ms_median"),
            ("decode_reused_mb_per_s", "decode_reused_ms_median"),
            ("encode_reused_mb_per_s", "encode_reused_ms_median"),
        ] {
            let expected = if f(&c[ms]) > 0.0 {
                raw_mb / (f(&c[ms]) / 1e3)
            } else {
                0.0
            };
            assert!(
                (f(&c[mb_s]) - expected).abs() <= 1e-6 * expected.max(1.0),
                "{name} {mb_s}"
            );
        }
        // Sections plus header and table are the message.
        let sections = c["section_bytes_per_frame"].as_object().expect("sections");
        let keys: Vec<&str> = sections.keys().map(String::as_str).collect();
        let expected: &[&str] = if name.starts_with("deep") {
            &["counts", "depth", "color", "object"]
        } else {
            &["lists"]
        };
        assert_eq!(keys, expected, "{name}");
        let payload: f64 = sections.values().map(f).sum();
        let overhead = (HEADER + ENTRY * expected.len() as u64) as f64;
        assert!(
            (payload + overhead - mean).abs() < 1e-6,
            "{name}: {payload} + {overhead} != {mean}"
        );
        // The table prints the same mean.
        let printed: f64 = row(&stdout, name)[1].parse().expect("bytes/frame column");
        assert!(
            (printed - mean).abs() <= 0.5,
            "{name}: printed {printed}, JSON {mean}"
        );
        if name == "lz4" {
            assert!((f(&c["percent_of_list_lz4"]) - 100.0).abs() < 1e-9);
        }
    }
}

/// `spheres` as a scene file at 160×90 (`strata scenes --print`, resized), in `dir`.
fn small_spheres(dir: &Path) -> std::path::PathBuf {
    let text = run_ok(strata().args(["scenes", "--print", "spheres"])).stdout;
    assert!(
        text.contains("width = 1280") && text.contains("height = 720"),
        "{text}"
    );
    let small = text
        .replace("width = 1280", "width = 160")
        .replace("height = 720", "height = 90");
    let path = dir.join("small-spheres.toml");
    std::fs::write(&path, small).unwrap();
    path
}

#[test]
fn codecs_measures_only_the_codecs_asked_for_at_their_levels() {
    let dir = TempDir::new().unwrap();
    let scene = small_spheres(dir.path());
    let json = dir.path().join("c.json");
    let stdout = run_ok(
        strata()
            .arg("codecs")
            .arg(&scene)
            .args([
                "--frames",
                "3",
                "--runs",
                "2",
                "--codecs",
                "zstd:19,deep-zstd:-3,deep",
                "--json",
            ])
            .arg(&json),
    )
    .stdout;
    assert_mentions(&stdout, &["160x90", "3 frame(s) [0, 24, 48]"]);
    for name in ["zstd:19", "deep-zstd:-3", "deep-zstd"] {
        row(&stdout, name);
    }
    for absent in ["raw", "lz4", "deep-lz4"] {
        assert!(
            !stdout
                .lines()
                .any(|l| l.split_whitespace().next() == Some(absent)),
            "{absent} listed:\n{stdout}"
        );
    }
    let doc = read_json(&json);
    let listed: Vec<&str> = doc["codecs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["codec"].as_str().unwrap())
        .collect();
    assert_eq!(listed, ["zstd:19", "deep-zstd:-3", "deep-zstd"]);
    assert_eq!(u(&doc["runs"]), 2);
    // The LZ4 reference is measured even when lz4 is not listed.
    assert_eq!(u64s(&doc["list_lz4_bytes_per_frame"]).len(), 3);
    // A scene without animation has one frame, however many are asked for.
    let still = dir.path().join("still.toml");
    std::fs::write(
        &still,
        "width = 32\nheight = 24\n[[objects]]\nbuiltin = \"sphere\"\ncolor = [1.0, 0.0, 0.0, 0.5]\n",
    )
    .unwrap();
    let stdout = run_ok(
        strata()
            .arg("codecs")
            .arg(&still)
            .args(["--frames", "8", "--runs", "1"]),
    )
    .stdout;
    assert_mentions(&stdout, &["1 frame(s) [0]", "every decode round-tripped"]);
}

#[test]
fn codecs_rejects_bad_arguments_with_a_message() {
    let dir = TempDir::new().unwrap();
    let scene = small_spheres(dir.path());
    let scene = scene.to_str().unwrap();

    let err = run_err(strata().args(["codecs", scene, "--codecs", "gzip"]));
    assert_mentions(
        &err,
        &["gzip", "unknown codec", "raw, lz4, zstd[:LEVEL], deep-lz4"],
    );
    let err = run_err(strata().args(["codecs", scene, "--codecs", "lz4,zstd:99"]));
    assert_mentions(&err, &["zstd:99", "unknown codec"]);
    let err = run_err(strata().args(["codecs", scene, "--codecs", "lz4:3"]));
    assert_mentions(&err, &["lz4:3"]);

    let err = run_err(strata().args(["codecs", scene, "--frames", "0"]));
    assert_mentions(&err, &["--frames must be at least 1"]);
    let err = run_err(strata().args(["codecs", scene, "--runs", "0"]));
    assert_mentions(&err, &["--runs must be at least 1"]);
    let err = run_err(strata().args(["codecs", scene, "-j", "0"]));
    assert_mentions(&err, &["--threads must be at least 1"]);
    let err = run_err(strata().args(["codecs", scene, "--frames=-1"]));
    assert_mentions(&err, &["'-1'", "--frames"]);
    let err = run_err(strata().args(["codecs", scene, "--frames", "many"]));
    assert_mentions(&err, &["many", "--frames"]);

    let missing_dir = dir.path().join("no-such-dir").join("c.json");
    let err = run_err(strata().args(["codecs", scene, "--json"]).arg(&missing_dir));
    assert_mentions(&err, &["no-such-dir", "does not exist"]);
    assert!(!missing_dir.exists());

    let err = run_err(strata().args(["codecs", "no-such-scene"]));
    assert_mentions(&err, &["no-such-scene", "spheres", "slabs"]);
    let missing = dir.path().join("missing.toml");
    let err = run_err(strata().arg("codecs").arg(&missing));
    assert_mentions(&err, &[missing.to_str().unwrap()]);

    // A built-in mesh scene without its mesh says which file and where to put it.
    let empty = TempDir::new().unwrap();
    let err = run_err(strata_without_models(empty.path()).args(["codecs", "bunny"]));
    assert_mentions(&err, &["bunny.obj", "STRATA_MODEL_PATH"]);

    // No scene at all: clap's own message, in strata's form.
    let err = run_err(strata().arg("codecs"));
    assert_mentions(&err, &["SCENE"]);
}
