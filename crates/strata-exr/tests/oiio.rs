//! The oracle: tools nobody here wrote (OpenImageIO's `oiiotool` and `iinfo`, OpenEXR's
//! `exrheader`, Python `OpenEXR`) read strata's deep files, agree with strata's flatten and merge,
//! and write deep files strata reads.
//!
//! A missing tool fails the test when `STRATA_REQUIRE_TOOLS=1` (CI sets it) and otherwise prints
//! a `SKIPPED:` line and returns.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{assert_same_pixels, render, synthetic};
use strata_exr::{
    Box2i, Channel, Column, Compression, DeepImage, FlatImage, FrameOptions, Limits, LineOrder,
    SampleType, WriteOptions, deep_from_frame, flatten, merge, read_deep_file, read_flat_file,
    stats, write_deep_file, write_flat_file,
};

/// Deep compressions OpenEXR's library accepts (it refuses deep ZIP).
const DEEP_COMPRESSIONS: [Compression; 3] =
    [Compression::None, Compression::Rle, Compression::Zips];

/// True if `program` can be started (and, with `need_success`, `args` succeed); otherwise
/// fails the test (tools required) or prints a SKIPPED line.
/// True if the tool is there; otherwise a visible `SKIPPED:` line, or a failure with
/// `STRATA_REQUIRE_TOOLS=1` (the one policy in `strata_testdata::tools`).
#[track_caller]
fn have(program: &str, args: &[&str], package: &str, need_success: bool) -> bool {
    if need_success {
        strata_testdata::tools::tool(program, args, package)
    } else {
        // `exrheader` exits 1 even for `-h`: that it starts at all is what counts.
        strata_testdata::tools::present(program, package)
    }
}

fn have_oiiotool() -> bool {
    have("oiiotool", &["--version"], "openimageio-tools", true)
}

/// Runs a tool and returns its standard output; panics with its output if it fails.
fn run(program: &str, args: &[&str]) -> String {
    let out = Command::new(program)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("{program}: {e}"));
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{program} {args:?} failed:\n{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    text
}

fn path_str(p: &Path) -> &str {
    p.to_str().expect("temporary paths are UTF-8")
}

fn write(dir: &Path, name: &str, image: &DeepImage, compression: Compression) -> PathBuf {
    let path = dir.join(name);
    let options = WriteOptions {
        compression,
        ..WriteOptions::default()
    };
    write_deep_file(&path, image, &options).expect("our image writes");
    path
}

fn offset_window() -> Box2i {
    Box2i::from_origin(-5, 7, 23, 19).expect("a valid window")
}

/// Largest |ours − theirs| over R, G, B, A and every pixel.
fn max_rgba_difference(ours: &FlatImage, theirs: &FlatImage) -> f64 {
    assert_eq!(
        ours.data_window(),
        theirs.data_window(),
        "flat data windows"
    );
    let pixels = ours.width() * ours.height();
    let mut worst = 0f64;
    for name in ["R", "G", "B", "A"] {
        for p in 0..pixels {
            let a = ours
                .value(name, p)
                .unwrap_or_else(|| panic!("ours lacks {name}"));
            let b = theirs
                .value(name, p)
                .unwrap_or_else(|| panic!("oiiotool's lacks {name}"));
            worst = worst.max((a - b).abs());
        }
    }
    worst
}

fn oiio_flatten(dir: &Path, inputs: &[&Path], merge_ops: usize, out: &str) -> FlatImage {
    let out = dir.join(out);
    let mut args: Vec<&str> = vec![path_str(inputs[0])];
    for input in &inputs[1..] {
        args.push(path_str(input));
        args.push("--deepmerge");
    }
    assert_eq!(merge_ops, inputs.len() - 1);
    args.extend([
        "--flatten",
        "-d",
        "float",
        "--compression",
        "zip",
        "-o",
        path_str(&out),
    ]);
    run("oiiotool", &args);
    read_flat_file(&out, &Limits::default()).expect("we read oiiotool's flat file")
}

#[test]
fn exrheader_reads_our_headers() {
    if !have("exrheader", &["-h"], "openexr", false) {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let image = synthetic(offset_window(), SampleType::Half, 5, 1);
    for compression in DEEP_COMPRESSIONS {
        let path = write(dir.path(), "h.exr", &image, compression);
        let text = run("exrheader", &[path_str(&path)]);
        let w = offset_window();
        for expected in [
            "type (type string): \"deepscanline\"".to_owned(),
            "objectid, 32-bit unsigned integer".to_owned(),
            "ZBack, 32-bit floating-point".to_owned(),
            "R, 16-bit floating-point".to_owned(),
            format!(
                "maxSamplesPerPixel (type int): {}",
                image.max_samples_per_pixel()
            ),
            format!(
                "dataWindow (type box2i): ({} {}) - ({} {})",
                w.x_min, w.y_min, w.x_max, w.y_max
            ),
            format!("chunkCount (type int): {}", w.height()),
            "version (type int): 1".to_owned(),
        ] {
            assert!(
                text.contains(&expected),
                "{compression:?}: no `{expected}` in\n{text}"
            );
        }
    }
}

/// The number after `key` on the line that contains it.
fn number_after(text: &str, key: &str) -> f64 {
    let line = text
        .lines()
        .find(|l| l.contains(key))
        .unwrap_or_else(|| panic!("no `{key}` in\n{text}"));
    let rest = &line[line.find(key).map_or(0, |i| i + key.len())..];
    rest.trim_start_matches([' ', ':'])
        .split_whitespace()
        .next()
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no number after `{key}` in `{line}`"))
}

#[test]
fn iinfo_reports_our_sample_counts() {
    if !have("iinfo", &["--help"], "openimageio-tools", true) {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let rendered = render("mixed", 96, 54);
    let frame_image = deep_from_frame(&rendered.frame, rendered.depth, &FrameOptions::default())
        .expect("converts");
    let images = [
        (
            "synthetic",
            synthetic(offset_window(), SampleType::Float, 9, 2),
        ),
        ("mixed", frame_image),
    ];
    for (what, image) in &images {
        for compression in DEEP_COMPRESSIONS {
            let path = write(dir.path(), "s.exr", image, compression);
            let text = run("iinfo", &["-v", "--stats", path_str(&path)]);
            let ours = stats(image);
            assert!(ours.samples > 0, "{what}: the test image has samples");
            assert_eq!(
                number_after(&text, "Min deep samples in any pixel") as u32,
                ours.min_per_pixel,
                "{what}"
            );
            assert_eq!(
                number_after(&text, "Max deep samples in any pixel") as u32,
                ours.max_per_pixel,
                "{what}"
            );
            let mean = number_after(&text, "Average deep samples per pixel");
            assert!(
                (mean - ours.mean_per_pixel).abs() <= 0.005,
                "{what}: mean {mean} vs {}",
                ours.mean_per_pixel
            );
            let count = image
                .offsets()
                .windows(2)
                .filter(|o| o[1] - o[0] == ours.max_per_pixel)
                .count();
            assert!(
                text.contains(&format!(
                    "{count} pixels had the max of {}",
                    ours.max_per_pixel
                )) || (count == 1 && text.contains("1 pixel had the max")),
                "{what}: {count} pixels at the max\n{text}"
            );
        }
    }
}

#[test]
fn oiiotool_flatten_matches_ours() {
    if !have_oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let rendered = render("spheres", 96, 54);
    let half = FrameOptions {
        color: SampleType::Half,
        ..FrameOptions::default()
    };
    let images = [
        (
            "synthetic half",
            synthetic(offset_window(), SampleType::Half, 6, 3),
        ),
        (
            "synthetic float",
            synthetic(offset_window(), SampleType::Float, 6, 4),
        ),
        (
            "spheres",
            deep_from_frame(&rendered.frame, rendered.depth, &FrameOptions::default())
                .expect("converts"),
        ),
        (
            "spheres half",
            deep_from_frame(&rendered.frame, rendered.depth, &half).expect("converts"),
        ),
    ];
    for (what, image) in &images {
        for compression in DEEP_COMPRESSIONS {
            let path = write(dir.path(), "in.exr", image, compression);
            let theirs = oiio_flatten(dir.path(), &[&path], 0, "flat.exr");
            let ours = flatten(image).expect("flattens");
            let worst = max_rgba_difference(&ours, &theirs);
            assert!(
                worst <= 1.0 / 255.0,
                "{what} {compression:?}: differs by {worst}"
            );
            let alpha_sum: f64 = (0..ours.width() * ours.height())
                .map(|p| ours.value("A", p).unwrap_or(0.0))
                .sum();
            assert!(alpha_sum > 1.0, "{what}: the flattened image is not empty");
        }
    }
}

#[test]
fn oiiotool_deepmerge_flatten_matches_our_merge() {
    if !have_oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    // Volumetric samples (ZBack > Z) that overlap across the images, so samples are split.
    let a = synthetic(offset_window(), SampleType::Float, 4, 5);
    let b = synthetic(offset_window(), SampleType::Float, 4, 6);
    let c = synthetic(offset_window(), SampleType::Half, 3, 7);
    let (pa, pb, pc) = (
        write(dir.path(), "a.exr", &a, Compression::Zips),
        write(dir.path(), "b.exr", &b, Compression::Rle),
        write(dir.path(), "c.exr", &c, Compression::None),
    );
    let two = merge(&[a.clone(), b.clone()]).expect("merges");
    assert!(
        two.sample_count() > a.sample_count().max(b.sample_count()),
        "the merge keeps samples of both images"
    );
    let worst = max_rgba_difference(
        &flatten(&two).expect("flattens"),
        &oiio_flatten(dir.path(), &[&pa, &pb], 1, "ab.exr"),
    );
    assert!(worst <= 1.0 / 255.0, "A+B differs by {worst}");
    let three = merge(&[a, b, c]).expect("merges");
    let worst = max_rgba_difference(
        &flatten(&three).expect("flattens"),
        &oiio_flatten(dir.path(), &[&pa, &pb, &pc], 2, "abc.exr"),
    );
    assert!(worst <= 1.0 / 255.0, "A+B+C differs by {worst}");

    // Two rendered scenes, point samples with the same camera.
    let spheres = render("spheres", 64, 36);
    let mixed = render("mixed", 64, 36);
    let opts = FrameOptions::default();
    let s = deep_from_frame(&spheres.frame, spheres.depth, &opts).expect("converts");
    let m = deep_from_frame(&mixed.frame, mixed.depth, &opts).expect("converts");
    let (ps, pm) = (
        write(dir.path(), "s.exr", &s, Compression::Zips),
        write(dir.path(), "m.exr", &m, Compression::Zips),
    );
    let ours = flatten(&merge(&[s, m]).expect("merges")).expect("flattens");
    let worst = max_rgba_difference(&ours, &oiio_flatten(dir.path(), &[&ps, &pm], 1, "sm.exr"));
    assert!(worst <= 1.0 / 255.0, "spheres+mixed differs by {worst}");
}

#[test]
fn we_read_deep_files_oiiotool_writes() {
    if !have_oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let image = synthetic(offset_window(), SampleType::Half, 5, 8);
    let ours = write(dir.path(), "ours.exr", &image, Compression::None);
    for compression in ["none", "rle", "zips"] {
        let theirs = dir.path().join(format!("theirs-{compression}.exr"));
        run(
            "oiiotool",
            &[
                path_str(&ours),
                // Keep each channel's type (oiiotool otherwise writes one type for all).
                "-d",
                "half",
                "-d",
                "Z=float",
                "-d",
                "ZBack=float",
                "-d",
                "objectid=uint",
                "--compression",
                compression,
                "-o",
                path_str(&theirs),
            ],
        );
        let back = read_deep_file(&theirs, &Limits::default())
            .unwrap_or_else(|e| panic!("{compression}: {e}"));
        assert_same_pixels(
            &back,
            &image,
            &format!("oiiotool --compression {compression}"),
        );
    }

    // --deepen of a flat RGBA image we wrote: one sample where any channel is non-zero.
    let flattened = flatten(&image).expect("flattens");
    let pixels: Vec<[f32; 4]> = (0..flattened.width() * flattened.height())
        .map(|p| ["R", "G", "B", "A"].map(|c| flattened.value(c, p).unwrap_or(0.0) as f32))
        .collect();
    // oiiotool's --deepen needs a Z channel; a pixel whose channels are all 0 gets no sample, so
    // empty pixels keep Z = 0 and covered ones get a depth.
    let w = offset_window();
    let column = |i: usize| Column::F32(pixels.iter().map(|p| p[i]).collect());
    let z = Column::F32(
        pixels
            .iter()
            .enumerate()
            .map(|(p, px)| {
                if px.iter().all(|&v| v == 0.0) {
                    0.0
                } else {
                    1.0 + p as f32 / 64.0
                }
            })
            .collect(),
    );
    let flat = FlatImage::new(
        w,
        ["A", "B", "G", "R", "Z"]
            .iter()
            .map(|n| Channel::new(*n, SampleType::Float))
            .collect(),
        vec![column(3), column(2), column(1), column(0), z],
    )
    .expect("a flat image");
    let flat_path = dir.path().join("flat.exr");
    write_flat_file(&flat_path, &flat, &WriteOptions::default()).expect("writes");
    let deepened = dir.path().join("deepened.exr");
    run(
        "oiiotool",
        &[path_str(&flat_path), "--deepen", "-o", path_str(&deepened)],
    );
    check_deepened(
        &flat,
        &read_deep_file(&deepened, &Limits::default()).expect("we read --deepen output"),
    );

    // --deepmerge output: the same samples as our merge (counts exact, values within half).
    let other = synthetic(offset_window(), SampleType::Half, 5, 9);
    let pb = write(dir.path(), "b.exr", &other, Compression::Zips);
    let merged = dir.path().join("merged.exr");
    run(
        "oiiotool",
        &[
            path_str(&ours),
            path_str(&pb),
            "--deepmerge",
            "-o",
            path_str(&merged),
        ],
    );
    let theirs = read_deep_file(&merged, &Limits::default()).expect("we read --deepmerge output");
    let mine = merge(&[image, other]).expect("merges");
    assert_eq!(theirs.offsets(), mine.offsets(), "merged sample counts");
    assert_eq!(theirs.channels().len(), mine.channels().len());
    for (c, channel) in mine.channels().iter().enumerate() {
        if channel.sample_type == SampleType::Uint {
            // OpenImageIO 2.4 writes merged UINT samples as garbage floats; not comparable.
            continue;
        }
        let t = theirs.channel_index(&channel.name).expect("same channels");
        for s in 0..mine.sample_count() {
            let (x, y) = (
                mine.column(c).get_f64(s).unwrap_or(f64::NAN),
                theirs.column(t).get_f64(s).unwrap_or(f64::NAN),
            );
            let tolerance = 1e-3 * x.abs().max(1.0);
            assert!(
                (x - y).abs() <= tolerance,
                "{} sample {s}: {x} vs {y}",
                channel.name
            );
        }
    }
}

/// `deep` is `flat` deepened: one sample where any channel is non-zero, with its values.
fn check_deepened(flat: &FlatImage, deep: &DeepImage) {
    assert_eq!(deep.data_window(), flat.data_window());
    for p in 0..flat.width() * flat.height() {
        let covered = ["A", "B", "G", "R"]
            .iter()
            .any(|c| flat.value(c, p) != Some(0.0));
        let range = deep.pixel_range(p);
        assert_eq!(range.len(), usize::from(covered), "pixel {p}");
        if covered {
            let r = deep.channel_index("R").expect("deepened R");
            let got = deep.column(r).get_f64(range.start).expect("a value");
            let want = flat.value("R", p).expect("flat R");
            assert!((got - want).abs() <= 1e-3, "pixel {p}: R {got} vs {want}");
        }
    }
}

fn have_python_openexr() -> bool {
    have(
        "python3",
        &["-c", "import OpenEXR"],
        "Python OpenEXR: pip install OpenEXR",
        true,
    )
}

/// Deep files written by OpenEXR's own library (through Python `OpenEXR`), in every deep
/// compression it writes and both line orders.
#[test]
fn we_read_deep_files_python_openexr_writes() {
    if !have_python_openexr() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let script = r#"
import sys, OpenEXR, numpy as np
path, compression, order = sys.argv[1], sys.argv[2], sys.argv[3]
h, w = 5, 7
def column(dtype, f):
    a = np.empty((h, w), dtype=object)
    for y in range(h):
        for x in range(w):
            a[y, x] = np.array([f(x, y, i) for i in range((x + 2 * y) % 4)], dtype=dtype)
    return a
channels = {
    "A": column(np.float16, lambda x, y, i: 0.5),
    "R": column(np.float16, lambda x, y, i: 0.125 * i),
    "Z": column(np.float32, lambda x, y, i: 1.0 + i + x / 4),
    "objectid": column(np.uint32, lambda x, y, i: x * 100 + y * 10 + i),
}
header = {
    "compression": getattr(OpenEXR, compression),
    "type": OpenEXR.deepscanline,
    "lineOrder": getattr(OpenEXR, order),
}
with OpenEXR.File(header, channels) as f:
    f.write(path)
"#;
    for compression in ["NO_COMPRESSION", "RLE_COMPRESSION", "ZIPS_COMPRESSION"] {
        for order in ["INCREASING_Y", "DECREASING_Y"] {
            let path = dir.path().join("py.exr");
            run(
                "python3",
                &["-c", script, path_str(&path), compression, order],
            );
            let what = format!("{compression} {order}");
            let image =
                read_deep_file(&path, &Limits::default()).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert_eq!((image.width(), image.height()), (7, 5), "{what}");
            let [a, r, z, id] =
                ["A", "R", "Z", "objectid"].map(|n| image.channel_index(n).expect("channel"));
            for y in 0..5usize {
                for x in 0..7usize {
                    let range = image.pixel_at(x as i64, y as i64).expect("inside");
                    assert_eq!(range.len(), (x + 2 * y) % 4, "{what}: pixel ({x}, {y})");
                    for (i, s) in range.enumerate() {
                        let v = |c: usize| image.column(c).get_f64(s).expect("a value");
                        assert_eq!(v(a), 0.5, "{what}");
                        assert_eq!(v(r), 0.125 * i as f64, "{what}");
                        assert_eq!(v(z), f64::from(1.0 + i as f32 + x as f32 / 4.0), "{what}");
                        assert_eq!(v(id), (x * 100 + y * 10 + i) as f64, "{what}");
                    }
                }
            }
        }
    }
}

#[test]
fn we_read_decreasing_y_files_oiiotool_writes() {
    if !have_oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let image = synthetic(offset_window(), SampleType::Float, 4, 10);
    let ours = write(dir.path(), "ours.exr", &image, Compression::Zips);
    let theirs = dir.path().join("decreasing.exr");
    run(
        "oiiotool",
        &[
            path_str(&ours),
            "-d",
            "float",
            "-d",
            "objectid=uint",
            "--attrib",
            "openexr:lineOrder",
            "decreasingY",
            "-o",
            path_str(&theirs),
        ],
    );
    let info = strata_exr::read_info(&std::fs::read(&theirs).expect("reads")).expect("header");
    if info.line_order != LineOrder::DecreasingY {
        eprintln!("note: this oiiotool ignores openexr:lineOrder; checked increasing order only");
    }
    let back = read_deep_file(&theirs, &Limits::default()).expect("reads");
    assert_same_pixels(&back, &image, "oiiotool rewrite");
    // And our own decreasing-y files are read by OpenImageIO.
    let mine = dir.path().join("mine-decreasing.exr");
    let options = WriteOptions {
        compression: Compression::Rle,
        line_order: LineOrder::DecreasingY,
    };
    write_deep_file(&mine, &image, &options).expect("writes");
    let text = run("iinfo", &["-v", "--stats", path_str(&mine)]);
    assert!(
        text.contains("decreasing"),
        "line order not reported:\n{text}"
    );
    let max = stats(&image).max_per_pixel;
    assert_eq!(
        number_after(&text, "Max deep samples in any pixel") as u32,
        max
    );
}

#[test]
fn python_openexr_reads_our_file() {
    if !have_python_openexr() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let image = synthetic(offset_window(), SampleType::Float, 4, 11);
    let script = r#"
import sys, OpenEXR
part = OpenEXR.File(sys.argv[1]).parts[0]
h = part.header
print("type", h["type"])
ch = part.channels
# R, G, B, A are grouped as one RGBA layer; an empty deep pixel is None.
z = ch["Z"].pixels
ids = ch["objectid"].pixels
def samples(a):
    return [a[y, x] if a[y, x] is not None else [] for y in range(a.shape[0]) for x in range(a.shape[1])]
total = sum(len(p) for p in samples(z))
zsum = sum(float(v) for p in samples(z) for v in p)
idsum = sum(int(v) for p in samples(ids) for v in p)
print("total", total)
print("zsum", repr(zsum))
print("idsum", idsum)
print("shape", z.shape[1], z.shape[0])
"#;
    for compression in DEEP_COMPRESSIONS {
        let path = write(dir.path(), "py.exr", &image, compression);
        let text = run("python3", &["-c", script, path_str(&path)]);
        assert!(text.contains("deepscanline"), "{text}");
        assert_eq!(
            number_after(&text, "total") as usize,
            image.sample_count(),
            "{text}"
        );
        let z = image
            .column(image.channel_index("Z").expect("Z"))
            .as_f32()
            .expect("floats");
        let zsum: f64 = z.iter().map(|&v| f64::from(v)).sum();
        assert!(
            (number_after(&text, "zsum") - zsum).abs() <= 1e-6 * zsum,
            "{text}"
        );
        let ids = image
            .column(image.channel_index("objectid").expect("id"))
            .as_u32()
            .expect("ints");
        let idsum: u64 = ids.iter().map(|&v| u64::from(v)).sum();
        assert_eq!(number_after(&text, "idsum") as u64, idsum, "{text}");
        let w = offset_window();
        assert!(
            text.contains(&format!("shape {} {}", w.width(), w.height())),
            "{text}"
        );
    }
}

/// A rendered frame rewritten by oiiotool (channel types kept) converts back to the same
/// DeepFrame: the samples, the exact-depth channel and the clip-plane attributes survive.
#[test]
fn frames_survive_a_rewrite_by_oiiotool() {
    if !have_oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let r = render("mixed", 64, 36);
    let options = FrameOptions {
        camera: Some(r.camera),
        ..FrameOptions::default()
    };
    let image = deep_from_frame(&r.frame, r.depth, &options).expect("converts");
    let ours = write(dir.path(), "frame.exr", &image, Compression::Zips);
    let theirs = dir.path().join("rewritten.exr");
    run(
        "oiiotool",
        &[
            path_str(&ours),
            "-d",
            "float",
            "-d",
            "objectid=uint",
            "--compression",
            "rle",
            "-o",
            path_str(&theirs),
        ],
    );
    let back = read_deep_file(&theirs, &Limits::default()).expect("reads");
    let frame = strata_exr::frame_from_deep(&back, None).expect("the clip planes survived");
    common::assert_same_frame(&frame, &r.frame, "oiiotool rewrite");
}

/// OpenImageIO reads our flat files, in every compression, to the values we wrote.
#[test]
fn oiiotool_reads_our_flat_files() {
    if !have_oiiotool() {
        return;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let deep = synthetic(offset_window(), SampleType::Half, 5, 12);
    let flat = flatten(&deep).expect("flattens");
    for sample_type in [SampleType::Half, SampleType::Float] {
        for compression in Compression::ALL {
            let w = offset_window();
            let pixels: Vec<[f32; 4]> = (0..flat.width() * flat.height())
                .map(|p| ["R", "G", "B", "A"].map(|c| flat.value(c, p).unwrap_or(0.0) as f32))
                .collect();
            let image =
                FlatImage::from_rgba(w.width() as u32, w.height() as u32, &pixels, sample_type)
                    .expect("a flat image");
            let ours = dir.path().join("ours-flat.exr");
            let options = WriteOptions {
                compression,
                ..WriteOptions::default()
            };
            write_flat_file(&ours, &image, &options).expect("writes");
            let theirs = dir.path().join("theirs-flat.exr");
            run(
                "oiiotool",
                &[
                    path_str(&ours),
                    "-d",
                    "float",
                    "--compression",
                    "none",
                    "-o",
                    path_str(&theirs),
                ],
            );
            let back = read_flat_file(&theirs, &Limits::default()).expect("reads");
            // What we stored (half-rounded for half channels) is exactly what OpenImageIO sees.
            let stored = read_flat_file(&ours, &Limits::default()).expect("reads ours");
            let worst = max_rgba_difference(&stored, &back);
            assert!(
                worst == 0.0,
                "{sample_type:?} {compression:?}: differs by {worst}"
            );
        }
    }
}
