//! End-to-end tests of the `strata` command: help, render, frames, pools, errors, scenes, demo,
//! bench, and the real meshes (found by `strata_testdata`; a missing one is a visible `SKIPPED:`
//! line, or a failure with `STRATA_REQUIRE_MODELS=1`).
//!
//! Inputs are small: the built-in `overlap` scene (640×480, 4 triangles) and tiny scene files
//! (64×48) written into temp dirs. Tests that must not find real meshes point `STRATA_MODEL_PATH`,
//! `HOME` and `XDG_DATA_HOME` at an empty temp dir.

mod common;

use std::path::{Path, PathBuf};
use std::time::Instant;

use assert_cmd::Command;
use common::{
    Ran, assert_mentions, assert_no_panic, bytes, read_json, read_png, run_err, run_ok, strata,
    strata_with_models, strata_without_models, write,
};
use serde_json::Value;
use tempfile::TempDir;

// ---------------------------------------------------------------------------------------------
// Helpers

fn u64_field(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("{key} is not an unsigned integer in {v}"))
}

fn f64_field(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} is not a number in {v}"))
}

/// Renders `scene` with extra `args` into `dir/out`, returning the stats JSON.
fn render(dir: &Path, scene: &str, out: &str, args: &[&str]) -> (PathBuf, Value, Ran) {
    let png = dir.join(out);
    let stats = dir.join(format!("{out}.json"));
    let ran = run_ok(
        strata()
            .arg("render")
            .arg(scene)
            .arg("--out")
            .arg(&png)
            .arg("--stats")
            .arg(&stats)
            .args(args),
    );
    (png, read_json(&stats), ran)
}

/// A 64×48 scene: four full-screen unlit quads stacked in depth, so every pixel has four
/// fragments (more than the auto pool's initial two per pixel).
const STACK: &str = r#"
width = 64
height = 48
background = [1.0, 1.0, 1.0]

[camera]
eye = [0.0, 0.0, 2.0]
target = [0.0, 0.0, 0.0]

[[objects]]
name = "a"
builtin = "quad"
color = [1.0, 0.0, 0.0, 0.3]
shading = "unlit"
scale = 4.0

[[objects]]
name = "b"
builtin = "quad"
color = [0.0, 1.0, 0.0, 0.3]
shading = "unlit"
translate = [0.0, 0.0, 0.1]
scale = 4.0

[[objects]]
name = "c"
builtin = "quad"
color = [0.0, 0.0, 1.0, 0.3]
shading = "unlit"
translate = [0.0, 0.0, 0.2]
scale = 4.0

[[objects]]
name = "d"
builtin = "quad"
color = [1.0, 1.0, 0.0, 0.3]
shading = "unlit"
translate = [0.0, 0.0, 0.3]
scale = 4.0
"#;

/// A 64×48 scene with a 4-frame animation turning a thin slab 90° about y per frame: face-on at
/// frame 0, edge-on at frame 1.
const ANIMATED: &str = r#"
width = 64
height = 48
background = [1.0, 1.0, 1.0]

[camera]
eye = [0.0, 0.0, 2.0]
target = [0.0, 0.0, 0.0]

[[objects]]
name = "pane"
builtin = "slab"
color = [0.9, 0.3, 0.2, 0.6]
shading = "headlight"

[animation]
frames = 4
rotate_deg_per_frame = [0.0, 90.0, 0.0]
"#;

/// A 64×48 scene with one cube and no animation.
const STILL: &str = r#"
width = 64
height = 48

[[objects]]
builtin = "cube"
color = [0.2, 0.6, 1.0, 0.5]
"#;

// ---------------------------------------------------------------------------------------------
// Help

#[test]
fn help_names_every_subcommand() {
    let ran = run_ok(strata().arg("--help"));
    assert_mentions(
        &ran.stdout,
        &["render", "demo", "bench", "scenes", "STRATA_MODEL_PATH"],
    );
    let ran = run_ok(strata().arg("--version"));
    assert!(
        ran.stdout.contains(env!("CARGO_PKG_VERSION")),
        "{}",
        ran.stdout
    );
    // No subcommand: a usage error (clap's), exit 2, no panic.
    let out = strata().output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert_no_panic(&String::from_utf8_lossy(&out.stderr));
}

#[test]
fn help_of_each_subcommand_lists_its_options() {
    let cases: &[(&str, &[&str])] = &[
        (
            "render",
            &[
                "SCENE",
                "--out",
                "--stats",
                "--frame",
                "--method",
                "--pool",
                "--threads",
                "-j",
                "--models",
            ],
        ),
        (
            "demo",
            &["--out-dir", "--method", "--pool", "--threads", "--models"],
        ),
        (
            "bench",
            &[
                "SCENE",
                "--runs",
                "--warmup",
                "--threads",
                "--json",
                "--frame",
                "--method",
                "--pool",
                "--models",
            ],
        ),
        ("scenes", &["--print"]),
    ];
    for (sub, options) in cases {
        for flag in ["--help", "-h"] {
            let ran = run_ok(strata().args([sub, flag]));
            assert_mentions(&ran.stdout, options);
        }
        // `strata help <sub>` says the same as `strata <sub> --help`.
        let ran = run_ok(strata().args(["help", sub]));
        assert_mentions(&ran.stdout, options);
    }
}

// ---------------------------------------------------------------------------------------------
// render

/// The overlap scene: red quad x ∈ [-0.45, 0.15], y ∈ [-0.2, 0.4] at z = 0.1 (1.5 from the eye);
/// blue quad x ∈ [-0.15, 0.45], y ∈ [-0.4, 0.2] at z = 0 (1.6 from the eye). With fovy 45° and
/// aspect 4/3 they project to columns 146.2..377.9, rows 85.5..317.3 (red) and columns
/// 265.7..483.0, rows 167.6..384.9 (blue). Pixel (320, 240) is in both, (200, 120) only in red,
/// (430, 350) only in blue, (10, 10) and (600, 450) in neither.
#[test]
fn render_overlap_writes_the_seed_colours_and_full_statistics() {
    let dir = TempDir::new().unwrap();
    let (png, s, ran) = render(dir.path(), "overlap", "x.png", &["-j", "2"]);
    assert_mentions(&ran.stderr, &["overlap", "wrote"]);

    let img = read_png(&png);
    assert_eq!((img.width(), img.height()), (640, 480));
    // Jähne 2014 §1: red over blue over white, alpha 128/255 each.
    assert_eq!(
        img.pixel(320, 240),
        [191, 63, 127],
        "red over blue over white"
    );
    assert_eq!(img.pixel(200, 120), [255, 127, 127], "red over white");
    assert_eq!(img.pixel(430, 350), [127, 127, 255], "blue over white");
    assert_eq!(img.pixel(10, 10), [255, 255, 255], "background");
    assert_eq!(img.pixel(600, 450), [255, 255, 255], "background");

    // Statistics.
    assert_eq!(s["scene"], "overlap");
    assert_eq!(s["method"], "abuffer");
    assert_eq!(u64_field(&s, "frame"), 0);
    assert_eq!(u64_field(&s, "threads"), 2);
    let (w, h) = (u64_field(&s, "width"), u64_field(&s, "height"));
    assert_eq!((w, h), (640, 480));
    assert_eq!(u64_field(&s, "triangles"), 4);
    let fragments = u64_field(&s, "fragments");
    let covered = u64_field(&s, "covered_pixels");
    assert!(fragments > 0 && covered > 0 && covered <= fragments);
    assert_eq!(u64_field(&s, "max_depth_complexity"), 2);
    let mean = f64_field(&s, "mean_depth_complexity");
    assert!(
        (mean - fragments as f64 / covered as f64).abs() < 1e-9,
        "mean depth {mean} vs {fragments}/{covered}"
    );
    assert!(mean > 1.0 && mean < 2.0, "mean depth {mean}");
    let hist: Vec<u64> = s["depth_histogram"]
        .as_array()
        .expect("depth_histogram is an array")
        .iter()
        .map(|v| v.as_u64().expect("histogram counts are integers"))
        .collect();
    assert_eq!(hist.len(), 3, "depths 0, 1 and 2: {hist:?}");
    assert_eq!(
        hist.iter().sum::<u64>(),
        w * h,
        "histogram covers every pixel"
    );
    assert_eq!(hist[0], w * h - covered, "uncovered pixels");
    let weighted: u64 = hist.iter().enumerate().map(|(n, c)| n as u64 * c).sum();
    assert_eq!(weighted, fragments, "Σ n·h[n] == fragments");
    assert!(hist[2] > 0, "the overlap has depth 2");
    assert_eq!(u64_field(&s, "dropped_fragments"), 0);
    assert_eq!(u64_field(&s, "fragments_rasterized"), fragments);
    assert!(u64_field(&s, "memory_bytes") > 0);
    let timings = s["timings_ms"].as_object().expect("timings_ms object");
    for pass in ["capture", "resolve"] {
        let t = timings[pass]
            .as_f64()
            .unwrap_or_else(|| panic!("timings_ms.{pass} missing: {timings:?}"));
        assert!(t >= 0.0 && t.is_finite(), "{pass}: {t}");
    }

    // The overlap region in the image agrees with the statistics: every depth-2 pixel is the
    // red-over-blue colour, every depth-0 pixel is white.
    let mut counts = [0u64; 3];
    for y in 0..480 {
        for x in 0..640 {
            match img.pixel(x, y) {
                [255, 255, 255] => counts[0] += 1,
                [255, 127, 127] | [127, 127, 255] => counts[1] += 1,
                [191, 63, 127] => counts[2] += 1,
                other => panic!("unexpected colour {other:?} at ({x}, {y})"),
            }
        }
    }
    assert_eq!(counts.to_vec(), hist, "pixel colours by depth");
}

#[test]
fn render_without_out_writes_scene_name_png_in_the_current_directory() {
    let dir = TempDir::new().unwrap();
    let ran = run_ok(strata().current_dir(dir.path()).args(["render", "overlap"]));
    assert_mentions(&ran.stderr, &["overlap.png"]);
    let img = read_png(&dir.path().join("overlap.png"));
    assert_eq!((img.width(), img.height()), (640, 480));
}

#[test]
fn render_is_identical_for_any_thread_count() {
    let dir = TempDir::new().unwrap();
    let (a, sa, _) = render(dir.path(), "overlap", "j1.png", &["-j", "1"]);
    let (b, sb, _) = render(dir.path(), "overlap", "j4.png", &["--threads", "4"]);
    assert_eq!(bytes(&a), bytes(&b), "-j 1 and -j 4 give different PNGs");
    assert_eq!(u64_field(&sa, "threads"), 1);
    assert_eq!(u64_field(&sb, "threads"), 4);
    for key in ["fragments", "covered_pixels", "max_depth_complexity"] {
        assert_eq!(sa[key], sb[key], "{key}");
    }
    assert_eq!(sa["depth_histogram"], sb["depth_histogram"]);

    // A scene with four layers everywhere, on an odd thread count.
    let stack = write(dir.path(), "stack.toml", STACK);
    let stack = stack.to_str().unwrap();
    let (a, _, _) = render(dir.path(), stack, "s1.png", &["-j", "1"]);
    let (b, _, _) = render(dir.path(), stack, "s3.png", &["-j", "3"]);
    assert_eq!(
        bytes(&a),
        bytes(&b),
        "-j 1 and -j 3 differ on the stack scene"
    );
}

/// `STRATA_LANES=8` runs the rasteriser 8 lanes wide where the CPU has AVX-512 (16 by default):
/// the same image and deep file. A value it does not know is refused before anything runs.
#[test]
fn the_lane_width_changes_nothing_and_a_bad_one_is_refused() {
    let dir = TempDir::new().unwrap();
    let mut deep = Vec::new();
    for lanes in ["16", "8"] {
        let (png, exr) = (format!("l{lanes}.png"), format!("l{lanes}.exr"));
        run_ok(
            strata()
                .current_dir(dir.path())
                .env("STRATA_LANES", lanes)
                .args(["render", "mixed", "-o", &png, "--deep", &exr]),
        );
        deep.push((bytes(&dir.path().join(png)), bytes(&dir.path().join(exr))));
    }
    assert!(deep[0] == deep[1], "8 and 16 lanes render differently");
    for bad in ["4", "sixteen", ""] {
        let err = run_err(
            strata()
                .current_dir(dir.path())
                .env("STRATA_LANES", bad)
                .args(["render", "mixed", "-o", "bad.png"]),
        );
        assert_mentions(&err, &["STRATA_LANES", "not a lane width"]);
        assert!(
            !dir.path().join("bad.png").exists(),
            "{bad:?} rendered anyway"
        );
    }
}

#[test]
fn fixed_pool_that_fits_gives_the_auto_image() {
    let dir = TempDir::new().unwrap();
    let (auto, sa, _) = render(dir.path(), "overlap", "auto.png", &["--pool", "auto"]);
    let (fixed, sf, ran) = render(dir.path(), "overlap", "2x.png", &["--pool", "2x"]);
    assert_eq!(bytes(&auto), bytes(&fixed), "--pool 2x vs --pool auto");
    assert_eq!(u64_field(&sf, "dropped_fragments"), 0);
    assert_eq!(sa["fragments"], sf["fragments"]);
    assert!(!ran.stderr.contains("DROPPED"), "{}", ran.stderr);
    // A plain fragment count that fits behaves the same.
    let (count, sc, _) = render(dir.path(), "overlap", "n.png", &["--pool", "1000000"]);
    assert_eq!(bytes(&auto), bytes(&count), "--pool 1000000 vs --pool auto");
    assert_eq!(u64_field(&sc, "dropped_fragments"), 0);
}

#[test]
fn tiny_pool_drops_and_counts_what_overflows() {
    let dir = TempDir::new().unwrap();
    let (_, full, _) = render(dir.path(), "overlap", "full.png", &[]);
    let all = u64_field(&full, "fragments");
    let (png, s, ran) = render(dir.path(), "overlap", "tiny.png", &["--pool", "10"]);
    let stored = u64_field(&s, "fragments");
    let dropped = u64_field(&s, "dropped_fragments");
    assert!(dropped > 0, "nothing dropped with a 10-fragment pool");
    assert!(
        stored <= 10,
        "stored {stored} fragments in a 10-fragment pool"
    );
    assert_eq!(stored + dropped, all, "stored + dropped == all fragments");
    assert_eq!(u64_field(&s, "fragments_rasterized"), all);
    assert_mentions(&ran.stderr, &["DROPPED", &dropped.to_string(), "--pool"]);
    // Still a full-size image, mostly background.
    let img = read_png(&png);
    assert_eq!((img.width(), img.height()), (640, 480));
    assert_eq!(img.pixel(320, 240), [255, 255, 255]);
}

#[test]
fn auto_pool_grows_instead_of_dropping() {
    let dir = TempDir::new().unwrap();
    let stack = write(dir.path(), "stack.toml", STACK);
    let stack = stack.to_str().unwrap();
    let (auto, s, ran) = render(dir.path(), stack, "auto.png", &[]);
    assert_eq!(u64_field(&s, "max_depth_complexity"), 4);
    assert_eq!(u64_field(&s, "fragments"), 4 * 64 * 48);
    assert_eq!(u64_field(&s, "dropped_fragments"), 0);
    assert!(
        u64_field(&s, "pool_regrows") > 0,
        "4 layers should outgrow the initial auto pool"
    );
    assert!(!ran.stderr.contains("DROPPED"), "{}", ran.stderr);
    let (big, _, _) = render(dir.path(), stack, "8x.png", &["--pool", "8x"]);
    assert_eq!(
        bytes(&auto),
        bytes(&big),
        "auto after regrowing vs --pool 8x"
    );
    // A fixed 3x pool cannot hold 4 layers: it drops exactly the overflow and the image changes.
    let (small, s3, _) = render(dir.path(), stack, "3x.png", &["--pool", "3x"]);
    assert_eq!(
        u64_field(&s3, "fragments") + u64_field(&s3, "dropped_fragments"),
        4 * 64 * 48
    );
    assert!(u64_field(&s3, "dropped_fragments") > 0);
    assert_ne!(bytes(&auto), bytes(&small));
}

// ---------------------------------------------------------------------------------------------
// Animation frames

#[test]
fn frames_pose_the_animation() {
    let dir = TempDir::new().unwrap();
    let scene = write(dir.path(), "turn.toml", ANIMATED);
    let scene = scene.to_str().unwrap();
    let (f0, s0, _) = render(dir.path(), scene, "f0.png", &["--frame", "0"]);
    let (f1, s1, _) = render(dir.path(), scene, "f1.png", &["--frame", "1"]);
    let (_, s3, _) = render(dir.path(), scene, "f3.png", &["--frame", "3"]);
    assert_eq!(u64_field(&s0, "frame"), 0);
    assert_eq!(u64_field(&s1, "frame"), 1);
    assert_eq!(u64_field(&s3, "frame"), 3);
    let (i0, i1) = (read_png(&f0), read_png(&f1));
    assert_eq!((i0.width(), i0.height()), (64, 48));
    assert_ne!(
        i0.as_bytes(),
        i1.as_bytes(),
        "frame 0 and frame 1 look the same"
    );
    // Face-on the pane covers far more pixels than edge-on.
    assert!(
        u64_field(&s0, "covered_pixels") > 2 * u64_field(&s1, "covered_pixels"),
        "frame 0 covers {} px, frame 1 {} px",
        s0["covered_pixels"],
        s1["covered_pixels"]
    );
}

#[test]
fn frame_past_the_animation_is_an_error() {
    let dir = TempDir::new().unwrap();
    let scene = write(dir.path(), "turn.toml", ANIMATED);
    let out = dir.path().join("f4.png");
    let err = run_err(
        strata()
            .arg("render")
            .arg(&scene)
            .args(["--frame", "4", "--out"])
            .arg(&out),
    );
    assert_mentions(&err, &["frame 4", "animation", "0..3"]);
    assert!(!out.exists(), "an image was written for a bad frame");

    let err = run_err(
        strata()
            .arg("bench")
            .arg(&scene)
            .args(["--frame", "4", "--runs", "1", "--warmup", "0"]),
    );
    assert_mentions(&err, &["frame 4", "animation"]);
}

#[test]
fn frame_of_a_scene_without_animation_is_an_error() {
    let dir = TempDir::new().unwrap();
    let still = write(dir.path(), "still.toml", STILL);
    let err = run_err(
        strata()
            .arg("render")
            .arg(&still)
            .args(["--frame", "1", "--out"])
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(&err, &["frame 1", "animation"]);
    let err = run_err(
        strata()
            .args(["render", "overlap", "--frame", "1", "--out"])
            .arg(dir.path().join("b.png")),
    );
    assert_mentions(&err, &["overlap", "frame 1", "animation"]);
}

// ---------------------------------------------------------------------------------------------
// Errors

#[test]
fn unknown_builtin_scene_lists_the_known_ones() {
    let dir = TempDir::new().unwrap();
    let err = run_err(
        strata()
            .args(["render", "no-such-scene", "--out"])
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(
        &err,
        &["no-such-scene", "slabs", "spheres", "mixed", "overlap"],
    );
    let err = run_err(strata().args(["bench", "no-such-scene", "--runs", "1"]));
    assert_mentions(&err, &["no-such-scene", "overlap"]);
    let err = run_err(strata().args(["scenes", "--print", "no-such-scene"]));
    assert_mentions(&err, &["no-such-scene", "slabs", "overlap"]);
}

#[test]
fn missing_scene_file_names_the_path() {
    let dir = TempDir::new().unwrap();
    let missing = dir.path().join("missing.toml");
    let err = run_err(
        strata()
            .arg("render")
            .arg(&missing)
            .arg("--out")
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(&err, &[missing.to_str().unwrap()]);
    // A bare `something.toml` is a path, not a built-in name.
    let err = run_err(
        strata()
            .current_dir(dir.path())
            .args(["render", "missing.toml"]),
    );
    assert_mentions(&err, &["missing.toml"]);
    assert!(!err.contains("built-in"), "{err}");
}

#[test]
fn malformed_toml_names_the_file_and_line() {
    let dir = TempDir::new().unwrap();
    let bad = write(
        dir.path(),
        "broken_scene.toml",
        "width = 64\nheight = 48\n[camera\neye = [0.0, 0.0, 2.0]\n",
    );
    let err = run_err(
        strata()
            .arg("render")
            .arg(&bad)
            .arg("--out")
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(&err, &["broken_scene.toml", "line 3"]);
}

#[test]
fn unknown_keys_are_errors_naming_the_key() {
    let dir = TempDir::new().unwrap();
    let top = write(
        dir.path(),
        "top.toml",
        "width = 64\nheight = 48\ncolour_depth = 3\n[[objects]]\nbuiltin = \"cube\"\n",
    );
    let err = run_err(
        strata()
            .arg("render")
            .arg(&top)
            .arg("--out")
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(&err, &["top.toml", "colour_depth", "line 3"]);

    let object = write(
        dir.path(),
        "object.toml",
        "width = 64\nheight = 48\n[[objects]]\nbuiltin = \"cube\"\ncolr = [1.0, 0.0, 0.0, 0.5]\n",
    );
    let err = run_err(
        strata()
            .arg("render")
            .arg(&object)
            .arg("--out")
            .arg(dir.path().join("b.png")),
    );
    assert_mentions(&err, &["object.toml", "colr", "line 5", "color"]);
}

#[test]
fn invalid_values_in_a_scene_are_errors_naming_the_key() {
    let dir = TempDir::new().unwrap();
    let cases = [
        (
            "width = 0\nheight = 48\n[[objects]]\nbuiltin = \"cube\"\n",
            "width",
        ),
        ("width = 64\nheight = 48\n", "objects"),
        (
            "width = 64\nheight = 48\n[[objects]]\nbuiltin = \"teapot\"\n",
            "teapot",
        ),
        (
            "width = 64\nheight = 48\n[[objects]]\nbuiltin = \"cube\"\ncolor = [2.0, 0.0, 0.0, 0.5]\n",
            "color",
        ),
        (
            "width = 64\nheight = 48\n[camera]\neye = [0.0, 0.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\n[[objects]]\nbuiltin = \"cube\"\n",
            "camera",
        ),
    ];
    for (i, (text, key)) in cases.iter().enumerate() {
        let scene = write(dir.path(), &format!("case{i}.toml"), text);
        let err = run_err(
            strata()
                .arg("render")
                .arg(&scene)
                .arg("--out")
                .arg(dir.path().join("a.png")),
        );
        assert_mentions(&err, &[&format!("case{i}.toml"), key]);
    }
}

#[test]
fn missing_mesh_names_the_mesh_and_the_search_path_variable() {
    let dir = TempDir::new().unwrap();
    let empty = TempDir::new().unwrap();
    let scene = write(
        dir.path(),
        "needs_mesh.toml",
        "width = 64\nheight = 48\n[[objects]]\nmesh = \"no_such_mesh.ply\"\n",
    );
    let err = run_err(
        strata_without_models(empty.path())
            .arg("render")
            .arg(&scene)
            .arg("--out")
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(
        &err,
        &["needs_mesh.toml", "no_such_mesh.ply", "STRATA_MODEL_PATH"],
    );
    // A built-in mesh scene without its mesh fails the same way.
    let err = run_err(
        strata_without_models(empty.path())
            .args(["render", "bunny", "--out"])
            .arg(dir.path().join("b.png")),
    );
    assert_mentions(&err, &["bunny.obj", "STRATA_MODEL_PATH"]);
}

#[test]
fn malformed_mesh_names_the_mesh_file_and_line() {
    let dir = TempDir::new().unwrap();
    let empty = TempDir::new().unwrap();
    write(
        dir.path(),
        "broken.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
         property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
         0 0 0\n1 0 zz\n0 1 0\n3 0 1 2\n",
    );
    let scene = write(
        dir.path(),
        "ply_scene.toml",
        "width = 64\nheight = 48\n[[objects]]\nmesh = \"broken.ply\"\n",
    );
    let err = run_err(
        strata_without_models(empty.path())
            .arg("render")
            .arg(&scene)
            .arg("--out")
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(&err, &["ply_scene.toml", "broken.ply", "line 11", "zz"]);

    write(
        dir.path(),
        "broken.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n",
    );
    let scene = write(
        dir.path(),
        "obj_scene.toml",
        "width = 64\nheight = 48\n[[objects]]\nmesh = \"broken.obj\"\n",
    );
    let err = run_err(
        strata_without_models(empty.path())
            .arg("render")
            .arg(&scene)
            .arg("--out")
            .arg(dir.path().join("b.png")),
    );
    assert_mentions(&err, &["broken.obj", "line 4"]);
}

#[test]
fn unknown_method_lists_abuffer() {
    let dir = TempDir::new().unwrap();
    let err = run_err(
        strata()
            .args(["render", "overlap", "--method", "nope", "--out"])
            .arg(dir.path().join("a.png")),
    );
    assert_mentions(&err, &["nope", "abuffer"]);
    let err = run_err(strata().args(["bench", "overlap", "-m", "nope", "--runs", "1"]));
    assert_mentions(&err, &["nope", "abuffer"]);
    let err = run_err(
        strata_without_models(dir.path())
            .args(["demo", "--method", "nope", "--out-dir"])
            .arg(dir.path().join("demo")),
    );
    assert_mentions(&err, &["nope", "abuffer"]);
}

/// Bad `--pool` values are rejected by the argument parser: exit 2, the value and the accepted
/// forms named. (The `strata: error:` prefix is missing here: see
/// `usage_errors_use_the_strata_error_prefix`.)
#[test]
fn bad_pool_values_are_rejected() {
    let dir = TempDir::new().unwrap();
    for bad in ["abc", "0", "-3", "0x", "-2x", "x"] {
        let out = strata()
            .args(["render", "overlap", "--out"])
            .arg(dir.path().join("a.png"))
            .arg(format!("--pool={bad}"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "--pool {bad}: {stderr}");
        assert_no_panic(&stderr);
        assert_mentions(&stderr, &["--pool", &format!("'{bad}'")]);
        assert!(!dir.path().join("a.png").exists());
    }
    let out = strata()
        .args(["render", "overlap", "--pool", "lots", "--out"])
        .arg(dir.path().join("a.png"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_mentions(&stderr, &["auto", "4x", "number of fragments"]);
}

#[test]
fn zero_threads_is_an_error() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("a.png");
    let err = run_err(
        strata()
            .args(["render", "overlap", "-j", "0", "--out"])
            .arg(&out),
    );
    assert_mentions(&err, &["--threads", "at least 1"]);
    assert!(!out.exists());
    let err = run_err(strata().args(["bench", "overlap", "-j", "0", "--runs", "1"]));
    assert_mentions(&err, &["--threads", "at least 1"]);
    let err = run_err(
        strata_without_models(dir.path())
            .args(["demo", "-j", "0", "--out-dir"])
            .arg(dir.path().join("demo")),
    );
    assert_mentions(&err, &["--threads", "at least 1"]);
}

#[test]
fn output_in_a_missing_directory_is_an_error_naming_it() {
    let dir = TempDir::new().unwrap();
    let png = dir.path().join("no/such/dir/x.png");
    let err = run_err(strata().args(["render", "overlap", "--out"]).arg(&png));
    assert_mentions(&err, &[png.to_str().unwrap()]);

    let stats = dir.path().join("no/such/dir/s.json");
    let err = run_err(
        strata()
            .args(["render", "overlap", "--out"])
            .arg(dir.path().join("ok.png"))
            .arg("--stats")
            .arg(&stats),
    );
    assert_mentions(&err, &[stats.to_str().unwrap()]);

    let json = dir.path().join("no/such/dir/b.json");
    let err = run_err(
        strata()
            .args([
                "bench", "overlap", "--runs", "1", "--warmup", "0", "-j", "1", "--json",
            ])
            .arg(&json),
    );
    assert_mentions(&err, &[json.to_str().unwrap()]);

    // demo creates its folder, but not where a file stands in the way.
    let blocker = write(dir.path(), "file", "not a directory");
    let err = run_err(
        strata_without_models(dir.path())
            .args(["demo", "--out-dir"])
            .arg(blocker.join("demo")),
    );
    assert_mentions(&err, &["file/demo"]);
}

// ---------------------------------------------------------------------------------------------
// scenes

#[test]
fn scenes_lists_every_builtin_scene() {
    let empty = TempDir::new().unwrap();
    let ran = run_ok(strata_without_models(empty.path()).arg("scenes"));
    let names: Vec<&str> = ran
        .stdout
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    for name in [
        "slabs",
        "spheres",
        "mixed",
        "overlap",
        "mfr-cars",
        "bunny",
        "dragon",
        "dragon-res2",
        "armadillo",
        "engine",
        "mfr-engine",
    ] {
        assert!(names.contains(&name), "{name} not listed:\n{}", ran.stdout);
    }
    // Without models, the mesh scenes say so; the self-contained ones do not.
    for line in ran.stdout.lines() {
        let name = line.split_whitespace().next().unwrap_or("");
        let flagged = line.contains("mesh not found");
        match name {
            "slabs" | "spheres" | "mixed" | "overlap" | "mfr-cars" | "volume-head" => {
                assert!(!flagged, "{line}")
            }
            _ => assert!(flagged, "{line}"),
        }
    }
    // With the real models on the path, bunny is available.
    if let Some(models) = strata_testdata::models(&["bunny.obj"]) {
        let ran = run_ok(strata_with_models(&models.path_var(), empty.path()).arg("scenes"));
        let bunny = ran
            .stdout
            .lines()
            .find(|l| l.starts_with("bunny "))
            .expect("bunny listed");
        assert!(!bunny.contains("mesh not found"), "{bunny}");
    }
}

#[test]
fn printed_scene_renders_like_the_builtin() {
    let dir = TempDir::new().unwrap();
    let ran = run_ok(strata().args(["scenes", "--print", "overlap"]));
    assert_mentions(
        &ran.stdout,
        &["width = 640", "height = 480", "[camera]", "[[objects]]"],
    );
    let file = write(dir.path(), "my_overlap.toml", &ran.stdout);
    let (a, sa, _) = render(dir.path(), "overlap", "builtin.png", &[]);
    let (b, sb, _) = render(dir.path(), file.to_str().unwrap(), "file.png", &[]);
    assert_eq!(bytes(&a), bytes(&b), "printed scene renders differently");
    assert_eq!(sa["fragments"], sb["fragments"]);
    assert_eq!(
        sb["scene"], "my_overlap",
        "a scene file is named after its file"
    );

    // Every built-in scene prints as a scene file.
    for name in [
        "slabs",
        "spheres",
        "mixed",
        "bunny",
        "dragon",
        "dragon-res2",
        "armadillo",
        "engine",
        "mfr-cars",
        "mfr-engine",
    ] {
        let ran = run_ok(strata().args(["scenes", "--print", name]));
        assert_mentions(&ran.stdout, &["width", "[[objects]]"]);
    }
}

// ---------------------------------------------------------------------------------------------
// demo

#[test]
fn demo_renders_every_available_scene_with_a_report() {
    let dir = TempDir::new().unwrap();
    let empty = TempDir::new().unwrap();
    let out = dir.path().join("demo");
    let start = Instant::now();
    let ran = run_ok(
        strata_without_models(empty.path())
            .arg("demo")
            .arg("--out-dir")
            .arg(&out),
    );
    let elapsed = start.elapsed();
    eprintln!("demo took {:.2} s", elapsed.as_secs_f64());
    assert_mentions(&ran.stderr, &["rendered 5 scenes", "skipped", "bunny"]);

    let rendered = ["slabs", "spheres", "mixed", "overlap", "mfr-cars"];
    let skipped = [
        "bunny",
        "dragon",
        "dragon-res2",
        "armadillo",
        "engine",
        "mfr-engine",
    ];
    for name in rendered {
        let json = read_json(&out.join(format!("{name}.json")));
        let img = read_png(&out.join(format!("{name}.png")));
        assert_eq!(json["scene"], name);
        assert_eq!(
            (u64::from(img.width()), u64::from(img.height())),
            (u64_field(&json, "width"), u64_field(&json, "height")),
            "{name}: PNG size vs stats"
        );
        assert!(u64_field(&json, "fragments") > 0, "{name}");
        assert_eq!(u64_field(&json, "dropped_fragments"), 0, "{name}");
        let hist_sum: u64 = json["depth_histogram"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .sum();
        assert_eq!(
            hist_sum,
            u64_field(&json, "width") * u64_field(&json, "height"),
            "{name}"
        );
    }
    for name in skipped {
        assert!(
            !out.join(format!("{name}.png")).exists(),
            "{name} rendered without its mesh"
        );
    }
    let spheres = read_json(&out.join("spheres.json"));
    assert!(
        u64_field(&spheres, "max_depth_complexity") >= 8,
        "spheres depth {}",
        spheres["max_depth_complexity"]
    );

    // report.md: a table row per rendered scene with "yes" under "DeepFrame = image", a section
    // and image per scene, and the skipped scenes listed.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let header = md
        .lines()
        .find(|l| l.starts_with("| scene"))
        .expect("report.md has a table");
    let columns: Vec<&str> = header.split('|').map(str::trim).collect();
    let deep = columns
        .iter()
        .position(|c| *c == "DeepFrame = image")
        .expect("DeepFrame = image column");
    for name in rendered {
        let row = md
            .lines()
            .find(|l| l.starts_with(&format!("| {name} |")))
            .unwrap_or_else(|| panic!("no table row for {name}:\n{md}"));
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        assert_eq!(cells[deep], "yes", "{name}: {row}");
        assert_mentions(&md, &[&format!("## {name}"), &format!("({name}.png)")]);
    }
    let skipped_line = md
        .lines()
        .find(|l| l.contains("Skipped"))
        .expect("report.md lists skipped scenes");
    assert_mentions(skipped_line, &skipped);
    for name in skipped {
        assert!(!md.contains(&format!("| {name} |")), "{name} in the table");
    }

    // report.html: the same.
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    for name in rendered {
        assert_mentions(
            &html,
            &[&format!("<td>{name}</td>"), &format!("src=\"{name}.png\"")],
        );
    }
    assert_eq!(
        html.matches("<td>yes</td>").count(),
        rendered.len(),
        "{html}"
    );
    assert!(!html.contains("<td>NO</td>"));
    assert_mentions(&html, &["Skipped"]);
    assert_mentions(&html, &skipped);

    // The demo's overlap image is the one `render` makes.
    let (png, _, _) = render(dir.path(), "overlap", "render.png", &[]);
    assert_eq!(bytes(&png), bytes(&out.join("overlap.png")));
}

// ---------------------------------------------------------------------------------------------
// bench

#[test]
fn bench_prints_medians_scaling_and_json() {
    let dir = TempDir::new().unwrap();
    let json = dir.path().join("b.json");
    let ran = run_ok(
        strata()
            .args([
                "bench", "overlap", "--runs", "2", "--warmup", "0", "-j", "1,2", "--json",
            ])
            .arg(&json),
    );
    assert_mentions(
        &ran.stdout,
        &[
            "overlap",
            "median",
            "threads 1:",
            "threads 2:",
            "capture",
            "resolve",
            "total",
        ],
    );
    assert!(
        ran.stdout.lines().any(|l| l.starts_with("scaling")),
        "no scaling line:\n{}",
        ran.stdout
    );

    let (_, stats, _) = render(dir.path(), "overlap", "r.png", &[]);
    let b = read_json(&json);
    assert_eq!(b["scene"], "overlap");
    assert_eq!(b["method"], "abuffer");
    assert_eq!(u64_field(&b, "runs"), 2);
    assert_eq!(u64_field(&b, "warmup"), 0);
    assert_eq!(u64_field(&b, "triangles"), 4);
    let results = b["results"].as_array().expect("results array");
    let threads: Vec<u64> = results.iter().map(|r| u64_field(r, "threads")).collect();
    assert_eq!(threads, [1, 2]);
    for r in results {
        for pass in ["capture", "resolve"] {
            let p = &r["passes_ms"][pass];
            let (med, min, max) = (
                f64_field(p, "median"),
                f64_field(p, "min"),
                f64_field(p, "max"),
            );
            assert!(0.0 <= min && min <= med && med <= max, "{pass}: {p}");
        }
        let t = &r["total_ms"];
        assert!(f64_field(t, "min") <= f64_field(t, "median"));
        assert_eq!(r["fragments"], stats["fragments"]);
        assert_eq!(u64_field(r, "dropped_fragments"), 0);
        assert!(u64_field(r, "memory_bytes") > 0);
    }
}

#[test]
fn bench_single_thread_count_has_no_scaling_line() {
    let ran = run_ok(strata().args([
        "bench", "overlap", "--runs", "1", "--warmup", "1", "-j", "1",
    ]));
    assert_mentions(&ran.stdout, &["median", "threads 1:"]);
    assert!(!ran.stdout.contains("scaling"), "{}", ran.stdout);
}

#[test]
fn bench_zero_runs_is_an_error() {
    let err = run_err(strata().args(["bench", "overlap", "--runs", "0"]));
    assert_mentions(&err, &["--runs"]);
}

// ---------------------------------------------------------------------------------------------
// Real meshes

#[test]
fn renders_the_real_bunny() {
    let Some(models) = strata_testdata::models(&["bunny.obj"]) else {
        return;
    };
    let dir = TempDir::new().unwrap();
    let empty = TempDir::new().unwrap();
    let model_dir = models.dirs().remove(0);
    let (png, s, _) = render(
        dir.path(),
        "bunny",
        "bunny.png",
        &["--models", model_dir.to_str().expect("a UTF-8 model path")],
    );
    assert_eq!(u64_field(&s, "triangles"), 69666);
    assert!(u64_field(&s, "fragments") > 0);
    assert_eq!(u64_field(&s, "dropped_fragments"), 0);
    let img = read_png(&png);
    assert_eq!((img.width(), img.height()), (1280, 720));

    // The same through STRATA_MODEL_PATH.
    let out = dir.path().join("env.png");
    run_ok(
        strata_with_models(&models.path_var(), empty.path())
            .args(["render", "bunny", "--out"])
            .arg(&out),
    );
    assert_eq!(bytes(&png), bytes(&out));
}

// ---------------------------------------------------------------------------------------------
// Regressions: bugs found while writing these tests, fixed since.

#[test]
fn usage_errors_use_the_strata_error_prefix() {
    let dir = TempDir::new().unwrap();
    run_err(
        strata()
            .args(["render", "overlap", "--pool", "abc", "--out"])
            .arg(dir.path().join("a.png")),
    );
    run_err(strata().arg("render"));
}

#[test]
fn unknown_scene_error_is_prefixed_once() {
    let err = run_err(strata().args(["render", "no-such-scene"]));
    assert!(!err.contains("strata: error: strata:"), "{err}");
}

#[test]
fn png_write_error_states_its_cause_once() {
    // A missing directory, and an output path that is a directory, are both caught before
    // rendering, each said once (not again as a `caused by:` line).
    let dir = TempDir::new().unwrap();
    let err = run_err(
        strata()
            .args(["render", "overlap", "--out"])
            .arg(dir.path().join("missing/x.png")),
    );
    assert_eq!(err.matches("does not exist").count(), 1, "{err}");
    let taken = dir.path().join("x.png");
    std::fs::create_dir(&taken).unwrap();
    let err = run_err(strata().args(["render", "overlap", "--out"]).arg(&taken));
    assert_eq!(err.matches("is a directory").count(), 1, "{err}");
    assert!(!err.contains("caused by"), "{err}");
}

#[test]
fn bench_checks_every_thread_count_before_measuring() {
    let out = strata()
        .args([
            "bench", "overlap", "--runs", "1", "--warmup", "0", "-j", "1,0",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        !stdout.contains("threads 1:"),
        "measured before failing:\n{stdout}"
    );
}

/// A pool too large for memory must fail like any other error, not abort. The command runs under
/// `ulimit -v` (2 GiB) so the test never really allocates much.
#[cfg(unix)]
#[test]
fn pool_too_large_for_memory_fails_cleanly() {
    let dir = TempDir::new().unwrap();
    let bin = assert_cmd::cargo::cargo_bin("strata");
    let script = format!(
        "ulimit -v 2097152 && exec '{}' render overlap -j 1 --pool 2000000000 --out '{}'",
        bin.display(),
        dir.path().join("a.png").display()
    );
    let err = run_err(Command::new("sh").args(["-c", &script]));
    assert_mentions(&err, &["pool"]);
}

/// `strata methods | head -0`: the reader closes the pipe before strata writes. `println!`
/// panicked there (exit 101); strata must end quietly and successfully, as `head` users expect.
#[cfg(unix)]
#[test]
fn closed_stdout_is_not_a_crash() {
    for args in [
        &["methods"][..],
        &["scenes"],
        &["scenes", "--print", "spheres"],
    ] {
        let mut child = std::process::Command::new(assert_cmd::cargo::cargo_bin("strata"))
            .args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take()); // close the read end at once
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?}: {:?} {err}", out.status);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn render_exports_the_variable_k_buffers_maps() {
    let dir = TempDir::new().unwrap();
    let maps = dir.path().join("maps");
    run_ok(
        strata()
            .args([
                "render", "overlap", "--method", "vkbuffer", "--budget", "60000", "--maps",
            ])
            .arg(&maps)
            .arg("--out")
            .arg(dir.path().join("vk.png")),
    );
    for name in ["k", "importance"] {
        let png = strata_core::Rgb8Image::read_png(maps.join(format!("{name}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (640, 480));
        let npy = std::fs::read(maps.join(format!("{name}.npy"))).unwrap();
        assert!(npy.starts_with(b"\x93NUMPY\x01\x00"), "{name}.npy");
        let header_len = u16::from_le_bytes([npy[8], npy[9]]) as usize;
        assert!(String::from_utf8_lossy(&npy[10..10 + header_len]).contains("'shape': (480, 640)"));
        assert_eq!(npy.len() - 10 - header_len, 640 * 480 * 4);
        if name == "k" {
            // The budget of 60,000 fragments is spent exactly.
            let sum: f32 = npy[10 + header_len..]
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                .sum();
            assert_eq!(sum, 60_000.0);
        }
    }
    let err = run_err(
        strata()
            .args(["render", "overlap", "--maps"])
            .arg(dir.path().join("none"))
            .arg("--out")
            .arg(dir.path().join("a.png")),
    );
    assert!(err.contains("computes no per-pixel maps"), "{err}");
}

// ---------------------------------------------------------------------------------------------
// Strict method options: another method's option, out-of-range values, nothing written first

/// Every file and folder directly in `dir`, by name (to show that a failed command wrote nothing).
fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// An option that only another method reads is an error naming the method, the option and the
/// methods that take it, for every subcommand that renders with one method; nothing is written.
#[test]
fn option_of_another_method_is_refused_before_anything_is_written() {
    let dir = TempDir::new().unwrap();
    let cases: [(&[&str], &[&str]); 6] = [
        (
            &[
                "render", "overlap", "--method", "kbuffer", "--budget", "25%",
            ],
            &["method kbuffer", "--budget", "only vkbuffer takes it"],
        ),
        (
            &["render", "overlap", "--method", "sbuffer", "--pool", "4x"],
            &["method sbuffer", "--pool", "abuffer, tfss"],
        ),
        (
            &[
                "render",
                "overlap",
                "-m",
                "vkbuffer",
                "--k-from",
                "optimal",
                "--range-bias",
                "0.5",
            ],
            &[
                "vkbuffer with k-from optimal",
                "--range-bias",
                "only with k-from importance",
            ],
        ),
        (
            &["render", "overlap", "--tail-blend"],
            &["method abuffer", "--tail-blend", "only kbuffer takes it"],
        ),
        (
            &[
                "bench",
                "overlap",
                "--method",
                "wboit",
                "--max-layers",
                "3",
                "--runs",
                "1",
            ],
            &[
                "method wboit",
                "--max-layers",
                "depth-peeling, dual-depth-peeling",
            ],
        ),
        (
            &["demo", "-m", "abuffer", "-k", "8"],
            &["method abuffer", "--k", "only kbuffer takes it"],
        ),
    ];
    for (args, needles) in cases {
        let err = run_err(
            strata_without_models(dir.path())
                .current_dir(dir.path())
                .args(args)
                .arg(if args[0] == "demo" {
                    "--out-dir"
                } else {
                    "--models"
                })
                .arg(dir.path().join("out")),
        );
        assert_mentions(&err, needles);
        assert_eq!(
            entries(dir.path()),
            Vec::<String>::new(),
            "{args:?} wrote a file"
        );
    }
    // The options a method does read are accepted, and an option left at its default is not
    // "given": the default --pool auto does not stop kbuffer.
    let (_, stats, _) = render(
        dir.path(),
        "overlap",
        "k.png",
        &["--method", "kbuffer", "-k", "2", "--tail-blend"],
    );
    assert_eq!(stats["method"], "kbuffer");
}

/// Checks that fail (threads, frame, scene) leave no report folder behind.
#[test]
fn failed_checks_leave_no_report_folder() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("out");
    let err = run_err(
        strata_without_models(dir.path())
            .args(["demo", "-j", "0", "--out-dir"])
            .arg(&out),
    );
    assert_mentions(&err, &["--threads"]);
    for args in [
        &["compare", "overlap", "--methods", "kbuffer", "-j", "0"][..],
        &["compare", "overlap", "--methods", "kbuffer", "--frame", "3"],
        &["compare", "no-such-scene", "--methods", "kbuffer"],
    ] {
        run_err(
            strata_without_models(dir.path())
                .args(args)
                .arg("--out-dir")
                .arg(&out),
        );
    }
    assert!(!out.exists(), "a failed command created its report folder");
}

/// A render node refuses another method's option before it starts listening.
#[test]
fn node_refuses_an_option_of_another_method() {
    let err = run_err(strata().args([
        "node",
        "--listen",
        "127.0.0.1:0",
        "--scene",
        "overlap",
        "--method",
        "kbuffer",
        "--budget",
        "20%",
    ]));
    assert_mentions(&err, &["method kbuffer", "--budget", "vkbuffer"]);
}

/// Every method option is range-checked as its help says, by the argument parser (exit 2, the
/// option, the value and the accepted range named), before any file is written.
#[test]
fn out_of_range_method_options_are_refused() {
    let dir = TempDir::new().unwrap();
    let png = dir.path().join("a.png");
    for (method, option, value, expected) in [
        ("vkbuffer", "--range-bias", "2", "[0, 1]"),
        ("vkbuffer", "--range-bias", "-0.5", "[0, 1]"),
        ("vkbuffer", "--noise", "-1", "[0, 1]"),
        ("vkbuffer", "--noise", "NaN", "[0, 1]"),
        ("vkbuffer", "--point-of-interest", "5,5", "each in [0, 1]"),
        ("vkbuffer", "--point-of-interest", "0.5", "each in [0, 1]"),
        ("vkbuffer", "--n-limit", "0", "at least 1"),
        ("vkbuffer", "--periphery-exponent", "0", "greater than 0"),
        ("vkbuffer", "--periphery-exponent", "-2", "greater than 0"),
        ("vkbuffer", "--budget", "150%", "up to 100 %"),
        ("kbuffer", "--k", "0", "from 1 to 1024"),
        ("abuffer-array", "--array-size", "2000", "from 1 to 1024"),
        ("tfss", "--l-num", "65", "from 1 to 64"),
        ("depth-peeling", "--max-layers", "-1", "whole number"),
    ] {
        let out = strata()
            .args(["render", "overlap", "--method", method, "--out"])
            .arg(&png)
            .arg(format!("{option}={value}"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{option} {value}: {stderr}");
        assert_no_panic(&stderr);
        assert_mentions(
            &stderr,
            &[
                "strata: error:",
                option.trim_start_matches('-'),
                &format!("'{value}'"),
                expected,
            ],
        );
        assert!(!png.exists(), "{option} {value}: wrote the image");
    }
    // The ends of each range are accepted.
    for args in [
        ["--range-bias", "1", "--noise", "0"],
        ["--point-of-interest", "0,1", "--n-limit", "1"],
        ["--budget", "100%", "--seed", "7"],
    ] {
        let args = [&["--method", "vkbuffer"][..], &args[..]].concat();
        render(dir.path(), "overlap", "ok.png", &args);
    }
}

/// `--maps` with a method that computes none fails before the image, the statistics or the
/// folder are written.
#[test]
fn maps_for_a_method_without_maps_writes_nothing() {
    let dir = TempDir::new().unwrap();
    let err = run_err(
        strata()
            .args(["render", "overlap", "--method", "sbuffer", "--out"])
            .arg(dir.path().join("a.png"))
            .arg("--stats")
            .arg(dir.path().join("a.json"))
            .arg("--maps")
            .arg(dir.path().join("maps")),
    );
    assert_mentions(
        &err,
        &[
            "--maps",
            "sbuffer",
            "computes no per-pixel maps",
            "vkbuffer",
        ],
    );
    assert_eq!(entries(dir.path()), Vec::<String>::new());
}

/// The maps of the variable k-buffer come with maps.html, where each heat map has a colour bar
/// labelled from 0 to the map's largest value.
#[test]
fn render_maps_page_shows_each_maps_colour_scale() {
    let dir = TempDir::new().unwrap();
    let maps = dir.path().join("maps");
    run_ok(
        strata()
            .args([
                "render", "overlap", "--method", "vkbuffer", "--budget", "2x", "--maps",
            ])
            .arg(&maps)
            .arg("--out")
            .arg(dir.path().join("vk.png")),
    );
    let npy = std::fs::read(maps.join("k.npy")).unwrap();
    let header_len = u16::from_le_bytes([npy[8], npy[9]]) as usize;
    let max_k = npy[10 + header_len..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .fold(0.0f32, f32::max);
    assert!(
        max_k >= 2.0,
        "a budget of 2 per pixel gives some pixel k ≥ 2: {max_k}"
    );
    let html = std::fs::read_to_string(maps.join("maps.html")).unwrap();
    assert_eq!(
        html.matches("linear-gradient").count(),
        2,
        "one colour bar per map"
    );
    assert_mentions(
        &html,
        &[
            "src=\"k.png\"",
            "src=\"importance.png\"",
            "rgb(0,0,0) 0.0%",
            "rgb(255,255,255) 100.0%",
            "<span>0</span>",
            &format!("<span>{max_k}</span>"),
            "fragments kept",
        ],
    );
}

/// The demo of an approximate method says what it is, instead of claiming every fragment is kept
/// and marking a DeepFrame check it cannot have as failed.
#[test]
fn demo_describes_an_approximate_method_as_such() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("demo");
    run_ok(
        strata_without_models(dir.path())
            .args(["demo", "-m", "wboit", "-j", "2", "--out-dir"])
            .arg(&out),
    );
    for page in ["report.md", "report.html"] {
        let text = std::fs::read_to_string(out.join(page)).unwrap();
        assert_mentions(
            &text,
            &[
                "approximate (weighted blend; keeps no fragments)",
                "none (blended)",
                "n/a (no DeepFrame)",
            ],
        );
        assert!(!text.contains("keeps all its fragments"), "{page}: {text}");
        assert!(
            !text.contains("| NO |") && !text.contains("<td>NO</td>"),
            "{page}"
        );
    }
    // An exact method still says it keeps every fragment, and checks its DeepFrame.
    let exact = dir.path().join("exact");
    run_ok(
        strata_without_models(dir.path())
            .args(["demo", "-m", "sbuffer", "-j", "2", "--out-dir"])
            .arg(&exact),
    );
    let md = std::fs::read_to_string(exact.join("report.md")).unwrap();
    assert_mentions(
        &md,
        &[
            "exact (keeps every fragment",
            "keeps all its fragments",
            "| yes |",
        ],
    );
    assert!(!md.contains("n/a"));
}

/// `strata bench` names the CPU it measured on, beside its figures and in its JSON, and shows no
/// figure from elsewhere for a scene that has none.
#[test]
fn bench_names_the_cpu_it_measured_on() {
    let dir = TempDir::new().unwrap();
    let json = dir.path().join("b.json");
    let ran = run_ok(
        strata()
            .args([
                "bench", "overlap", "--runs", "1", "--warmup", "0", "-j", "1", "--json",
            ])
            .arg(&json),
    );
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpuinfo.lines().find_map(|l| {
        l.strip_prefix("model name")?
            .split_once(':')
            .map(|(_, m)| m.trim())
    });
    let doc = read_json(&json);
    let cpu = doc["cpu"].as_str().expect("cpu in the JSON");
    if let Some(model) = model {
        assert!(cpu.starts_with(model), "{cpu} vs {model}");
    }
    assert!(ran.stdout.matches(cpu).count() >= 2, "{}", ran.stdout);
    assert_eq!(doc["reference_figures"], serde_json::json!([]));
    assert!(!ran.stdout.contains("reference figures"), "{}", ran.stdout);
}

/// `strata methods` says how faithful each method is and which options it reads.
#[test]
fn methods_lists_fidelity_and_options() {
    let ran = run_ok(strata().arg("methods"));
    let lines: Vec<&str> = ran.stdout.lines().collect();
    let about = |name: &str| {
        let i = lines
            .iter()
            .position(|l| l.split_whitespace().next() == Some(name))
            .unwrap_or_else(|| panic!("{name} not listed:\n{}", ran.stdout));
        lines[i + 1]
    };
    assert_mentions(
        about("abuffer"),
        &["exact", "bounded with a fixed --pool", "options: --pool"],
    );
    assert_mentions(about("kbuffer"), &["bounded", "options: --k --tail-blend"]);
    assert_mentions(
        about("wboit"),
        &[
            "approximate (weighted blend; keeps no fragments)",
            "options: none",
        ],
    );
    assert_mentions(
        about("depth-peeling"),
        &["exact", "bounded with --max-layers above 0"],
    );
    assert_mentions(
        about("vkbuffer"),
        &[
            "--budget",
            "--k-from",
            "--range-bias",
            "--point-of-interest",
        ],
    );
    // Sources are cited by author and year, not by internal shorthand.
    let tfss = lines
        .iter()
        .find(|l| l.starts_with("tfss "))
        .expect("tfss listed");
    assert_mentions(tfss, &["Lin 2007"]);
    assert!(
        !ran.stdout.to_lowercase().contains("seed 0"),
        "{}",
        ran.stdout
    );
}

/// `bench --export` times a render node's frame: it says so, records it in the JSON, prints no
/// reference figures of a resolved frame, and refuses a store without DeepFrames before
/// measuring anything.
#[test]
fn bench_export_times_a_node_frame_and_refuses_a_store_without_deep_frames() {
    let dir = TempDir::new().unwrap();
    let json = dir.path().join("b.json");
    let ran = run_ok(
        strata()
            .args([
                "bench", "overlap", "--export", "--runs", "2", "--warmup", "1", "-j", "1",
            ])
            .arg("--json")
            .arg(&json),
    );
    assert!(ran.stdout.contains("export a DeepFrame"), "{}", ran.stdout);
    // The pass table has the export's own row, beside the capture's.
    assert!(
        ran.stdout
            .lines()
            .any(|l| l.trim_start().starts_with("export ")),
        "no export row in the pass table:\n{}",
        ran.stdout
    );
    assert!(!ran.stdout.contains("reference figures"), "{}", ran.stdout);
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(doc["export"], serde_json::Value::Bool(true));
    let fragments = doc["results"][0]["fragments"].as_u64().unwrap();
    assert!(fragments > 0, "{doc}");

    let err =
        run_err(strata().args(["bench", "overlap", "-m", "wboit", "--export", "--runs", "1"]));
    assert_mentions(&err, &["--export", "wboit", "exports no DeepFrame"]);
}

/// `bench --export --export-layers N` times a depth-limited node's frame: no pixel of the
/// exported frame holds more than N fragments, though the scene has deeper pixels; the option
/// needs `--export` and at least one layer.
#[test]
fn bench_export_layers_cuts_the_exported_runs() {
    let dir = TempDir::new().unwrap();
    let depth = |layers: Option<&str>| {
        let json = dir.path().join("b.json");
        let mut cmd = strata();
        cmd.args(["bench", "mixed", "--export", "--runs", "1", "--warmup", "0"]);
        if let Some(n) = layers {
            cmd.args(["--export-layers", n]);
        }
        let ran = run_ok(cmd.arg("--json").arg(&json));
        let doc: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        let r = &doc["results"][0];
        let counts = (r["fragments"].as_u64(), r["exported_fragments"].as_u64());
        (ran.stdout, r["max_depth_complexity"].as_u64(), counts)
    };
    let (_, whole, (held, exported)) = depth(None);
    assert!(whole > Some(2), "the scene is deeper than 2: {whole:?}");
    assert_eq!(
        held, exported,
        "an export without a limit keeps every fragment"
    );
    let (stdout, cut, (held_too, exported)) = depth(Some("2"));
    assert_eq!(cut, Some(2), "{stdout}");
    assert_eq!(held_too, held, "the store holds the same fragments");
    assert!(exported < held, "the export kept {exported:?} of {held:?}");
    assert!(stdout.contains("at most 2 fragments a pixel"), "{stdout}");
    assert!(stdout.contains(" exported), "), "{stdout}");

    let err = run_err(strata().args(["bench", "mixed", "--export-layers", "2"]));
    assert_mentions(&err, &["--export"]);
    let err = run_err(strata().args(["bench", "mixed", "--export", "--export-layers", "0"]));
    assert_mentions(&err, &["--export-layers", "0"]);
}
