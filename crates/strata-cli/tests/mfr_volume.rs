//! `strata mfr --volume`: the FC's stencil re-cast equals the single renderer on the built-in
//! volume scene, and bad volume scenes are clear errors.

mod common;

use common::{assert_mentions, read_json, run_err, run_ok, strata, write};

#[test]
fn the_built_in_volume_scene_recasts_only_the_path_and_matches_the_single_renderer() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("out");
    let mut cmd = strata();
    cmd.args(["mfr", "volume-head", "--volume", "--frames", "2"])
        .args(["--size", "96x54", "--volume-samples", "64", "--out-dir"])
        .arg(&out);
    let ran = run_ok(&mut cmd);
    assert_mentions(
        &ran.stdout,
        &["SC full cast", "FC stencil re-cast", "0 pixels differ"],
    );
    let s = read_json(&out.join("summary.json"));
    assert_eq!(s["bad_pixels"], 0, "{s}");
    assert_eq!(s["fc_frames"], 2, "{s}");
    let share = s["fc_recast_share"].as_f64().expect("share");
    assert!(share > 0.0 && share < 0.2, "{s}");
    assert!(
        s["fc_samples_mean"].as_u64() < s["sc_samples"].as_u64(),
        "{s}"
    );
    // The built-in scene's glass sheet is drawn by the SC.
    assert_eq!(s["glass_boxes"], 1, "{s}");
}

#[test]
fn static_and_moving_glass_inside_the_volume_match_the_single_renderer() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = write(
        dir.path(),
        "glass.toml",
        "[camera]\neye = [1.2, 0.7, 2.0]\ntarget = [0, 0, 0]\n\n\
         [volume]\nprocedural = \"head\"\nsize = 16\nsamples = 64\n\
         path = [[0, 0.8, 0.1], [0.1, -0.2, 0.1], [0.5, -0.4, 0.2]]\npath_radius = 0.04\n\n\
         [[volume.points]]\nvalue = 0.1\ncolor = [0.9, 0.6, 0.4]\nalpha = 0.0\n\n\
         [[volume.points]]\nvalue = 0.9\ncolor = [1, 1, 0.9]\nalpha = 0.8\n\n\
         [[volume.glass]]\nmin = [-0.5, -0.3, 0.0]\nmax = [0.4, 0.5, 0.02]\nalpha = 0.3\n\n\
         [[volume.glass]]\nmin = [-0.3, -0.2, -0.2]\nmax = [0.0, 0.2, 0.3]\ncolor = [1, 0.9, 0.2]\nalpha = 0.4\nmoves = true\n",
    );
    let out = dir.path().join("out");
    let mut cmd = strata();
    cmd.args([
        "mfr",
        "--volume",
        "--frames",
        "3",
        "--size",
        "80x45",
        "--out-dir",
    ])
    .arg(&out)
    .arg(&scene);
    let ran = run_ok(&mut cmd);
    assert_mentions(&ran.stdout, &["0 pixels differ"]);
    let s = read_json(&out.join("summary.json"));
    assert_eq!(
        (s["bad_pixels"].as_u64(), s["glass_boxes"].as_u64()),
        (Some(0), Some(2)),
        "{s}"
    );
    // The moving box widens the stencil beyond the thin path.
    let share = s["fc_recast_share"].as_f64().expect("share");
    assert!(share > 0.03 && share < 0.6, "{s}");
}

#[test]
fn volume_scenes_without_points_or_with_a_truncated_file_are_errors() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = write(
        dir.path(),
        "empty.toml",
        "[volume]\nprocedural = \"head\"\n",
    );
    let e = run_err(strata().args(["mfr", "--volume"]).arg(&scene));
    assert_mentions(&e, &["volume.points", "no points"]);
    // A volume file cut off inside its header.
    std::fs::write(dir.path().join("cut.nii"), [0u8; 100]).expect("write");
    let scene = write(
        dir.path(),
        "cut.toml",
        "[volume]\nfile = \"cut.nii\"\n[[volume.points]]\nvalue = 0.5\ncolor = [1, 1, 1]\nalpha = 0.5\n",
    );
    let e = run_err(strata().args(["mfr", "--volume"]).arg(&scene));
    assert_mentions(&e, &["cut.nii", "truncated"]);
    // A scene without a volume.
    let e = run_err(strata().args(["mfr", "spheres", "--volume"]));
    assert_mentions(&e, &["no [volume] table"]);
    // A volume scene without --volume.
    let e = run_err(strata().args(["mfr", "volume-head"]));
    assert_mentions(&e, &["volume scene", "--volume"]);
    // Options a volume run does not follow are refused, not ignored.
    for extra in [
        ["--trace", "grab:"],
        ["--mode", "digital"],
        ["--clock", "real"],
    ] {
        let e = run_err(
            strata()
                .args(["mfr", "volume-head", "--volume"])
                .args(extra),
        );
        assert_mentions(&e, &["cannot be used with"]);
    }
}
