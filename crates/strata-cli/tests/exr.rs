//! `strata render` image outputs by extension, `--deep`, `strata composite` and `strata inspect`,
//! checked against strata's own library and against tools nobody here wrote (OpenImageIO's
//! `oiiotool` and `iinfo`, OpenEXR's `exrheader`, Python's `OpenEXR`). A missing tool prints a
//! `SKIPPED:` line, or fails the test with `STRATA_REQUIRE_TOOLS=1` (as CI sets it).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{assert_mentions, run_err, run_ok, strata};
use strata_exr::{Limits, read_deep_file, read_flat_file};
use strata_testdata::tools;

/// Threads for every render (results are identical for any count).
const THREADS: &[&str] = &["-j", "2"];

fn p(path: &Path) -> &str {
    path.to_str().expect("temporary paths are UTF-8")
}

/// A built-in scene as a scene file at 160 pixels wide (`spheres` still holds up to 16
/// fragments a pixel), so these tests stay fast.
fn small_scene(scene: &str, dir: &Path) -> PathBuf {
    let mut cmd = strata();
    cmd.args(["scenes", "--print", scene]);
    let text = run_ok(&mut cmd).stdout;
    let (w, h) = if scene == "overlap" {
        (160, 120)
    } else {
        (160, 90)
    };
    let text: String = text
        .lines()
        .map(|l| {
            if l.starts_with("width =") {
                format!("width = {w}\n")
            } else if l.starts_with("height =") {
                format!("height = {h}\n")
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    let path = dir.join(format!("{scene}-small.toml"));
    std::fs::write(&path, text).expect("scene file written");
    path
}

/// Renders a built-in scene (made small) with `args`, returning the stats JSON's fragment count.
fn render(scene: &str, dir: &Path, args: &[&str]) -> u64 {
    let stats = dir.join(format!("{scene}-stats.json"));
    let file = small_scene(scene, dir);
    let mut cmd = strata();
    cmd.arg("render")
        .arg(&file)
        .args(THREADS)
        .args(args)
        .args(["--stats", p(&stats)]);
    run_ok(&mut cmd);
    common::read_json(&stats)["fragments"]
        .as_u64()
        .expect("fragments in the stats")
}

/// Runs an external tool, returning stdout; fails the test with its output if it fails.
fn tool_output(program: &str, args: &[&str]) -> String {
    let out = Command::new(program)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("{program}: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{program} {args:?} failed\nstdout:\n{stdout}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// `oiiotool A B --diff` over R, G, B, A with a 1/255 failure threshold: true if they agree.
fn oiio_agree(a: &Path, b: &Path, dir: &Path) -> (bool, String) {
    let a4 = dir.join("a-rgba.exr");
    let b4 = dir.join("b-rgba.exr");
    tool_output("oiiotool", &[p(a), "--ch", "R,G,B,A", "-o", p(&a4)]);
    tool_output("oiiotool", &[p(b), "--ch", "R,G,B,A", "-o", p(&b4)]);
    let out = Command::new("oiiotool")
        .args([p(&a4), p(&b4), "--fail", "0.003922", "--diff"])
        .output()
        .expect("oiiotool runs");
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    (out.status.success() && text.contains("PASS"), text)
}

#[test]
fn images_by_extension_png_8_and_16_bit_opaque_and_transparent_and_flat_exr() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    render("overlap", d, &["-o", p(&d.join("o.png"))]);
    render("overlap", d, &["-o", p(&d.join("t.png")), "--alpha"]);
    render(
        "overlap",
        d,
        &["-o", p(&d.join("t16.png")), "--alpha", "--bits", "16"],
    );
    render("overlap", d, &["-o", p(&d.join("o.exr"))]);
    render("overlap", d, &["-o", p(&d.join("t.exr")), "--alpha"]);

    let info = |name: &str| {
        let file = std::fs::File::open(d.join(name)).expect("written");
        let decoder = png::Decoder::new(std::io::BufReader::new(file));
        let reader = decoder.read_info().expect("a PNG");
        (reader.info().color_type, reader.info().bit_depth)
    };
    assert_eq!(info("o.png"), (png::ColorType::Rgb, png::BitDepth::Eight));
    assert_eq!(info("t.png"), (png::ColorType::Rgba, png::BitDepth::Eight));
    assert_eq!(
        info("t16.png"),
        (png::ColorType::Rgba, png::BitDepth::Sixteen)
    );

    // The flat EXRs agree with the 8-bit PNG: over the background within rounding, and without
    // it the background shows through exactly where alpha is below 1.
    let opaque = common::read_png(&d.join("o.png"));
    let over = read_flat_file(&d.join("o.exr"), &Limits::default()).expect("our flat EXR");
    let bare = read_flat_file(&d.join("t.exr"), &Limits::default()).expect("our flat EXR");
    let (over, bare) = (over.rgba(), bare.rgba());
    let w = opaque.width() as usize;
    let mut transparent = 0;
    for (i, (o, t)) in over.iter().zip(&bare).enumerate() {
        let png = opaque.pixel((i % w) as u32, (i / w) as u32);
        for c in 0..3 {
            let v = (o[c] * 255.0).round();
            assert!(
                (v - f32::from(png[c])).abs() <= 1.0,
                "pixel {i} channel {c}: EXR {} vs PNG {}",
                o[c],
                png[c]
            );
        }
        assert_eq!(o[3], 1.0, "the background is composited in");
        if t[3] < 1.0 {
            transparent += 1;
        }
    }
    assert!(
        transparent > 0,
        "the overlap scene leaves background pixels transparent with --alpha"
    );
    // The worked example: half-transparent red over half-transparent blue over white at the
    // image's centre is (191, 63, 127) on the PNG.
    let c = opaque.pixel(opaque.width() / 2, opaque.height() / 2);
    assert_eq!(c, [191, 63, 127]);
}

#[test]
fn bad_outputs_are_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let cases: &[(&[&str], &[&str])] = &[
        (&["-o", "x.jpg"], &["x.jpg", ".png and .exr", "not .jpg"]),
        (&["-o", "noext"], &["noext", "extension"]),
        (&["--deep", "d.png"], &["d.png", "deep images are OpenEXR"]),
        (&["-o", "x.png", "--half"], &["--half", "PNG"]),
        (
            &["-o", "x.png", "--compression", "rle"],
            &["--compression", "PNG"],
        ),
        (&["-o", "x.exr", "--bits", "16"], &["--bits", "EXR"]),
        (&["-o", "x.png", "--bits", "12"], &["12", "8 or 16"]),
        (
            &["--deep", "d.exr", "--compression", "zip"],
            &["zip", "deep"],
        ),
        (
            &["-m", "wboit", "--deep", "d.exr"],
            &["wboit", "deep image"],
        ),
        (
            &["-m", "kbuffer", "--tail-blend", "--deep", "d.exr"],
            &["--tail-blend", "leave the tail out"],
        ),
        (&["-o", "same.exr", "--deep", "same.exr"], &["same file"]),
        (
            &["-m", "wboit", "-o", "x.png", "--alpha"],
            &["wboit", "transparent"],
        ),
    ];
    for (args, words) in cases {
        let mut cmd = strata();
        cmd.current_dir(d).args(["render", "overlap"]).args(*args);
        let err = run_err(&mut cmd);
        assert_mentions(&err, words);
        let left: Vec<PathBuf> = std::fs::read_dir(d)
            .expect("readable")
            .map(|e| e.expect("entry").path())
            .collect();
        assert!(left.is_empty(), "{args:?} wrote {left:?}");
    }
}

#[test]
fn deep_output_holds_every_fragment_and_reads_back_as_the_same_frame() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let deep = d.join("s.exr");
    let half = d.join("s-half.exr");
    let fragments = render(
        "spheres",
        d,
        &["-o", p(&d.join("s.png")), "--deep", p(&deep)],
    );
    render(
        "spheres",
        d,
        &[
            "-o",
            p(&d.join("s2.png")),
            "--deep",
            p(&half),
            "--half",
            "--compression",
            "rle",
        ],
    );
    let image = read_deep_file(&deep, &Limits::default()).expect("our deep EXR");
    assert_eq!(image.sample_count() as u64, fragments);
    let frame = strata_exr::frame_from_deep(&image, None).expect("a DeepFrame");
    // The frame resolves to the PNG the same command wrote.
    let png = common::read_png(&d.join("s.png"));
    assert_eq!(frame.resolve([1.0, 1.0, 1.0]), png);
    // Half colour channels give back every 8-bit colour exactly too.
    let half_frame = strata_exr::frame_from_deep(
        &read_deep_file(&half, &Limits::default()).expect("half EXR"),
        None,
    )
    .expect("a DeepFrame");
    assert_eq!(half_frame, frame);
}

#[test]
fn oiiotool_flatten_equals_strata_flat_image_and_iinfo_counts_our_samples() {
    if !tools::oiiotool() || !tools::iinfo() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let deep = d.join("deep.exr");
    let flat = d.join("flat.exr");
    let fragments = render(
        "spheres",
        d,
        &["-o", p(&flat), "--alpha", "--deep", p(&deep)],
    );
    let theirs = d.join("oiio-flat.exr");
    tool_output("oiiotool", &[p(&deep), "--flatten", "-o", p(&theirs)]);
    let (agree, diff) = oiio_agree(&theirs, &flat, d);
    assert!(agree, "oiiotool --flatten differs from strata:\n{diff}");

    let info = tool_output("iinfo", &["-v", "--stats", p(&deep)]);
    let line = info
        .lines()
        .find(|l| l.contains("Total deep samples in all pixels"))
        .unwrap_or_else(|| panic!("no sample total in iinfo's output:\n{info}"));
    let total: u64 = line
        .rsplit(':')
        .next()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("cannot read the total in {line:?}"));
    assert_eq!(total, fragments);
}

#[test]
fn strata_composite_equals_oiiotool_deepmerge_flatten() {
    if !tools::oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let a = d.join("a.exr");
    let b = d.join("b.exr");
    render("spheres", d, &["-o", p(&d.join("a.png")), "--deep", p(&a)]);
    render(
        "mixed",
        d,
        &[
            "-o",
            p(&d.join("b.png")),
            "--deep",
            p(&b),
            "--frame",
            "5",
            "--half",
        ],
    );
    let ours = d.join("ours.exr");
    let merged = d.join("merged.exr");
    let mut cmd = strata();
    cmd.args(["composite", p(&a), p(&b), "-o", p(&ours), "--deep-out"])
        .arg(p(&merged));
    run_ok(&mut cmd);
    let theirs = d.join("theirs.exr");
    tool_output(
        "oiiotool",
        &[p(&a), p(&b), "--deepmerge", "--flatten", "-o", p(&theirs)],
    );
    let (agree, diff) = oiio_agree(&theirs, &ours, d);
    assert!(
        agree,
        "oiiotool --deepmerge --flatten differs from strata composite:\n{diff}"
    );
    // Our merged deep file is one oiiotool flattens to the same picture.
    let reflat = d.join("reflat.exr");
    tool_output("oiiotool", &[p(&merged), "--flatten", "-o", p(&reflat)]);
    let (agree, diff) = oiio_agree(&reflat, &ours, d);
    assert!(agree, "the merged deep file flattens differently:\n{diff}");
}

#[test]
fn strata_reads_deep_files_oiiotool_wrote() {
    if !tools::oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    // A flat image with a Z channel, made deep by oiiotool.
    let flat = d.join("flat.exr");
    let deep = d.join("deepened.exr");
    tool_output(
        "oiiotool",
        &[
            "--pattern",
            "constant:color=0.25,0.1,0.05,0.5,2.0",
            "16x8",
            "5",
            "--chnames",
            "R,G,B,A,Z",
            "-d",
            "float",
            "-o",
            p(&flat),
        ],
    );
    tool_output("oiiotool", &[p(&flat), "--deepen", "-o", p(&deep)]);
    // Theirs merged with ours (strata's overlap frame is 160×120).
    let ours = d.join("ours.exr");
    render(
        "overlap",
        d,
        &["-o", p(&d.join("o.png")), "--deep", p(&ours)],
    );
    // oiiotool merges only images with the same channels: keep R G B A Z of ours.
    let ours5 = d.join("ours5.exr");
    tool_output(
        "oiiotool",
        &[p(&ours), "--ch", "R,G,B,A,Z", "-o", p(&ours5)],
    );
    let both = d.join("both.exr");
    tool_output(
        "oiiotool",
        &[p(&deep), p(&ours5), "--deepmerge", "-o", p(&both)],
    );

    let mut cmd = strata();
    cmd.args(["inspect", p(&deep), "--pixel", "3,2"]);
    let ran = run_ok(&mut cmd);
    assert_mentions(
        &ran.stdout,
        &[
            "deep scanline",
            "16×8",
            "samples: 128 in 128 pixels",
            "pixel (3,2): 1 sample",
        ],
    );

    let out = d.join("c.png");
    let mut cmd = strata();
    cmd.args(["composite", p(&both), "-o", p(&out)]);
    run_ok(&mut cmd);
    let mut cmd = strata();
    cmd.args(["composite", p(&deep), p(&ours), "-o"])
        .arg(p(&d.join("c2.exr")));
    run_ok(&mut cmd);
    // Pixel (3,2): oiiotool's sample (A 0.5 at Z 2) in front of or behind strata's, merged
    // either way gives the same flat pixel.
    let c1 = read_flat_file(&d.join("c2.exr"), &Limits::default()).expect("flat");
    let both_flat = d.join("both-flat.exr");
    tool_output("oiiotool", &[p(&both), "--flatten", "-o", p(&both_flat)]);
    let (agree, diff) = oiio_agree(&both_flat, &d.join("c2.exr"), d);
    assert!(agree, "{diff}");
    assert!(c1.value("A", 0).is_some_and(|a| a > 0.49));
}

#[test]
fn exrheader_and_python_openexr_read_our_deep_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let deep = d.join("deep.exr");
    let fragments = render(
        "spheres",
        d,
        &["-o", p(&d.join("s.png")), "--deep", p(&deep)],
    );
    if tools::exrheader() {
        let header = tool_output("exrheader", &[p(&deep)]);
        assert_mentions(
            &header,
            &[
                "deepscanline",
                "objectid",
                "32-bit unsigned integer",
                "Z, 32-bit floating-point",
            ],
        );
    }
    if tools::python_openexr() {
        let script = "import sys, OpenEXR\n\
                      f = OpenEXR.File(sys.argv[1], separate_channels=True)\n\
                      ch = f.channels()\n\
                      print(sum(len(v) for v in ch['Z'].pixels.flat if v is not None))\n";
        let out = tool_output("python3", &["-c", script, p(&deep)]);
        let total: u64 = out
            .trim()
            .parse()
            .unwrap_or_else(|_| panic!("python printed {out:?}"));
        assert_eq!(total, fragments);
    }
}

#[test]
fn composite_and_inspect_refuse_bad_inputs_clearly() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let flat = d.join("flat.exr");
    render("overlap", d, &["-o", p(&flat)]);
    let garbage = d.join("garbage.exr");
    std::fs::write(&garbage, b"v/1\x01 this is not an EXR file at all").expect("write");
    let deep = d.join("deep.exr");
    render(
        "overlap",
        d,
        &["-o", p(&d.join("o.png")), "--deep", p(&deep)],
    );

    let out = d.join("out.png");
    let (missing, tiff) = (d.join("missing.exr"), d.join("x.tiff"));
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (
            vec!["composite", p(&flat), "-o", p(&out)],
            vec!["flat.exr", "flat image", "--deepen"],
        ),
        (
            vec!["composite", p(&garbage), "-o", p(&out)],
            vec!["garbage.exr"],
        ),
        (
            vec!["composite", p(&missing), "-o", p(&out)],
            vec!["missing.exr"],
        ),
        (
            vec!["composite", p(&deep), "-o", p(&tiff)],
            vec!["x.tiff", ".png and .exr"],
        ),
        (
            vec!["inspect", p(&deep), "--pixel", "9999,1"],
            vec!["9999,1", "outside the data window"],
        ),
        (vec!["inspect", p(&garbage)], vec!["garbage.exr"]),
        (
            vec![
                "composite",
                p(&deep),
                "-o",
                p(&out),
                "--compression",
                "none",
            ],
            vec!["--compression", "PNG"],
        ),
        (
            vec!["composite", p(&deep), "-o", p(&deep)],
            vec!["both an input and an output"],
        ),
        (vec!["inspect", "/dev/zero"], vec!["not a regular file"]),
        (vec!["inspect", p(d)], vec!["directory"]),
    ];
    for (args, words) in cases {
        let mut cmd = strata();
        cmd.args(&args);
        let err = run_err(&mut cmd);
        assert_mentions(&err, &words);
    }
    assert!(!out.exists(), "a refused composite wrote its output");
}
