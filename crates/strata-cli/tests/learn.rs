//! `strata learn` end to end: train on a small dataset, describe the weights, render with them,
//! evaluate on a held-out family; and the errors for bad weights and bad options.

mod common;

use common::{read_json, run_err, run_ok, strata};
use tempfile::TempDir;

/// A dataset of two generated scenes and the built-in `mixed` and `slabs`, 64 × 36.
fn dataset(dir: &std::path::Path) -> std::path::PathBuf {
    let out = dir.join("data");
    run_ok(
        strata()
            .args(["dataset", "--procedural", "2", "--scenes", "mixed,slabs"])
            .args(["--views", "2", "--budgets", "30,60", "--size", "64x36"])
            .args(["--seed", "4", "-j", "2", "--out"])
            .arg(&out),
    );
    out
}

#[test]
fn train_info_render_and_eval() {
    let dir = TempDir::new().unwrap();
    let data = dataset(dir.path());
    let weights = dir.path().join("w.safetensors");
    let ran = run_ok(
        strata()
            .args([
                "learn",
                "train",
                "--epochs",
                "2",
                "--exclude",
                "slabs",
                "--data",
            ])
            .arg(&data)
            .arg("--out")
            .arg(&weights),
    );
    assert!(ran.stdout.contains("trained curve"), "{}", ran.stdout);
    assert!(ran.stderr.contains("epoch   2"), "{}", ran.stderr);
    let info = run_ok(strata().args(["learn", "info"]).arg(&weights)).stdout;
    for says in [
        "network: 20-8-2",
        "predicts: error_curve",
        "held_out_families: slabs",
        "training_command:",
        "contrast",
    ] {
        assert!(info.contains(says), "`{says}` not in:\n{info}");
    }
    assert!(
        run_ok(strata().args(["learn", "info"]))
            .stdout
            .contains("built-in weights")
    );
    // Rendering with the file, and with the built-in weights.
    let png = dir.path().join("mixed.png");
    let stats = dir.path().join("mixed.json");
    run_ok(
        strata()
            .args(["render", "mixed", "--method", "vkbuffer"])
            .args(["--k-from", "learned", "--budget", "40%", "--weights"])
            .arg(&weights)
            .arg("--out")
            .arg(&png)
            .arg("--stats")
            .arg(&stats),
    );
    let s = read_json(&stats);
    // Stored Σk = M = ⌊40 % of every fragment⌋; the rest are counted as dropped.
    let kept = s["fragments"].as_u64().unwrap();
    let dropped = s["dropped_fragments"].as_u64().unwrap();
    assert_eq!(
        kept,
        ((kept + dropped) as f64 * 0.4).floor() as u64,
        "Σk = M"
    );
    run_ok(
        strata()
            .args([
                "compare",
                "mixed",
                "--runs",
                "1",
                "--warmup",
                "0",
                "--out-dir",
            ])
            .arg(dir.path().join("cmp"))
            .arg("--methods")
            .arg(format!(
                "vkbuffer:k-from=learned,vkbuffer:k-from=learned:weights={}",
                weights.display()
            )),
    );
    // The evaluation, held out: slabs (its test scene is `slabs`).
    let eval = dir.path().join("eval");
    let ran = run_ok(
        strata()
            .args(["learn", "eval", "--families", "slabs", "--views", "2"])
            .args(["--seeds", "1", "--budgets", "30,60", "--orbit", "3"])
            .args(["--no-seed-networks", "--size", "64x36", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(&eval),
    );
    assert!(
        ran.stdout.contains("## slabs (held out of training)"),
        "{}",
        ran.stdout
    );
    let table = std::fs::read_to_string(eval.join("table.md")).unwrap();
    for column in [
        "importance",
        "analytic",
        "learned",
        "fraction",
        "optimal",
        "exact",
    ] {
        assert!(table.contains(column), "no {column} in\n{table}");
    }
    assert!(
        !table.contains("differs"),
        "Σk differs between methods:\n{table}"
    );
    let results = read_json(&eval.join("results.json"));
    let cells = &results["families"][0]["budgets"];
    assert_eq!(cells.as_array().unwrap().len(), 2);
    for cell in cells.as_array().unwrap() {
        let m = &cell["methods"];
        let sum_k = m["importance"]["sum_k_view0"].as_u64().unwrap();
        for method in ["analytic", "learned", "fraction", "optimal"] {
            assert_eq!(
                m[method]["sum_k_view0"].as_u64().unwrap(),
                sum_k,
                "{method}"
            );
        }
        // The oracle is the best any allocation of this Σk can do on its own cost (RMSE-like).
        let rmse = |name: &str| m[name]["rmse"].as_f64().unwrap();
        assert!(rmse("optimal") <= rmse("importance") + 1e-9, "{cell}");
    }
    assert!(eval.join("sheet-slabs.png").is_file());
}

#[test]
fn bad_weights_and_options_are_refused_before_rendering() {
    let dir = TempDir::new().unwrap();
    let junk = dir.path().join("junk.safetensors");
    std::fs::write(&junk, b"not weights at all").unwrap();
    let err = run_err(
        strata()
            .args([
                "render", "mixed", "--method", "vkbuffer", "--k-from", "learned",
            ])
            .arg("--weights")
            .arg(&junk),
    );
    assert!(
        err.contains("junk.safetensors") && err.contains("safetensors"),
        "{err}"
    );
    // --weights only means something with --k-from learned.
    let err = run_err(
        strata()
            .args(["render", "mixed", "--method", "vkbuffer", "--weights"])
            .arg(
                std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                    .join("../strata-stores/weights/learned-k.safetensors"),
            ),
    );
    assert!(err.contains("--weights"), "{err}");
    let err = run_err(strata().args(["learn", "info"]).arg(&junk));
    assert!(err.contains("safetensors"), "{err}");
    let data = dataset(dir.path());
    // `strata learn train ARGS --data DATA --out x.safetensors`: what it says on refusing.
    let train_err = |args: &[&str]| {
        run_err(
            strata()
                .args(["learn", "train"])
                .args(args)
                .arg("--data")
                .arg(&data)
                .args(["--out", "x.safetensors"]),
        )
    };
    let err = train_err(&["--exclude", "bunny"]);
    assert!(err.contains("bunny") && err.contains("procedural"), "{err}");
    let err = train_err(&["--inputs", "count,nope"]);
    assert!(err.contains("`nope`"), "{err}");
    let err = train_err(&["--hidden", "0"]);
    assert!(err.contains("--hidden"), "{err}");
    let err = run_err(
        strata()
            .args(["learn", "eval", "--families", "dragon", "--data"])
            .arg(&data),
    );
    assert!(err.contains("no such family"), "{err}");
}
