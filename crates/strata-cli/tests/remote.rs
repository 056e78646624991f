//! End-to-end tests of `strata node` and `strata display` on loopback: two node processes
//! holding complementary objects, a display that merges them, its summary, its errors and its
//! exit statuses (0 complete, 1 nothing delivered, 2 usage, 3 degraded).

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::process::Output;

use assert_cmd::Command;
use serde_json::Value;
use strata_wire::{DecodeOptions, MessageType, PREFIX_LEN, Request, inspect_frame, parse_prefix};
use tempfile::TempDir;

mod common;

use common::Service;

/// `strata node --listen 127.0.0.1:0 --scene SCENE --objects OBJECTS`, killed when dropped.
fn node(scene: &str, objects: &str) -> Service {
    node_with(&["--scene", scene, "--objects", objects])
}

/// `strata node --listen 127.0.0.1:0 ARGS`, killed when dropped.
fn node_with(args: &[&str]) -> Service {
    let all: Vec<&str> = ["node", "--listen", "127.0.0.1:0"]
        .into_iter()
        .chain(args.iter().copied())
        .collect();
    Service::start(&all)
}

fn strata() -> Command {
    Command::cargo_bin("strata").unwrap()
}

#[test]
fn two_node_processes_merge_into_the_exact_image() {
    let a = node("mixed", "opaque cube,glass slab");
    let b = node("mixed", "1,2,4");
    let dir = TempDir::new().unwrap();
    for transfer in [
        vec!["--transfer", "full"],
        vec!["--transfer", "depth-limited", "--layers", "32"],
        vec!["--transfer", "difference"],
        // Within 2 steps of the exact render: no bad pixels at the default threshold.
        vec!["--transfer", "reprojection"],
    ] {
        let out = strata()
            .args([
                "display", "--scene", "mixed", "--frames", "3", "--size", "160x90",
            ])
            .args(["--nodes", &format!("{},{}", a.addr, b.addr)])
            .args(&transfer)
            .arg("--out-dir")
            .arg(dir.path())
            .arg("--save-frames")
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{transfer:?}: {stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(stdout.contains("display rate"), "{stdout}");
        assert!(
            stdout.contains("0 of 3 checked frame(s) with bad pixels"),
            "{transfer:?} must be exact: {stdout}"
        );
        let json: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("summary.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(json["frames"], 3);
        assert_eq!(json["frames_with_bad_pixels"], 0);
        assert!(json["bytes_per_frame"].as_f64().unwrap() > 0.0);
        assert_eq!(json["per_frame"].as_array().unwrap().len(), 3);
        assert!(dir.path().join("frame-0002.png").exists());
    }
}

/// `--save-deep` writes each composed frame's merged fragments as a deep EXR that resolves to
/// the PNG `--save-frames` wrote for it, and that holds both nodes' objects.
#[test]
fn display_saves_merged_deep_frames() {
    let a = node("mixed", "opaque cube,glass slab");
    let b = node("mixed", "1,2,4");
    let dir = TempDir::new().unwrap();
    let out = strata()
        .args([
            "display", "--scene", "mixed", "--frames", "2", "--size", "160x90",
        ])
        .args(["--nodes", &format!("{},{}", a.addr, b.addr)])
        .arg("--out-dir")
        .arg(dir.path())
        .args(["--save-frames", "--save-deep"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for t in 0..2 {
        let exr = dir.path().join(format!("frame-{t:04}.exr"));
        let image = strata_exr::read_deep_file(&exr, &strata_exr::Limits::default())
            .unwrap_or_else(|e| panic!("{}: {e}", exr.display()));
        let frame = strata_exr::frame_from_deep(&image, None).expect("a DeepFrame");
        let objects: std::collections::BTreeSet<u32> =
            frame.objects().iter().map(|o| o.0).collect();
        assert_eq!(
            objects.into_iter().collect::<Vec<_>>(),
            vec![0, 1, 2, 3, 4],
            "frame {t} holds every object of both nodes"
        );
        let png = strata_core::Rgb8Image::read_png(dir.path().join(format!("frame-{t:04}.png")))
            .expect("the saved PNG");
        assert_eq!(frame.resolve([0.92, 0.92, 0.95]), png, "frame {t}");
    }
}

#[test]
fn display_errors_are_clear() {
    let cases: &[(&[&str], &str)] = &[
        (&["--transfer", "bilateral"], "unknown transfer 'bilateral'"),
        (&["--transfer", "depth-limited"], "needs --layers"),
        (
            &["--transfer", "full", "--layers", "3"],
            "--layers and --opacity-threshold apply",
        ),
        (
            &["--tolerance", "2"],
            "--tolerance applies to --transfer difference and reprojection",
        ),
        (&["--size", "0x10"], "each side 1 to 16384"),
        (&["--frames", "0"], "--frames must be at least 1"),
        (&["--codec", "gzip"], "unknown codec"),
        (&["--timeout", "0"], "--timeout"),
        (
            &["--first-frame", "4294967295", "--frames", "2"],
            "frame 4294967296 is beyond the last animation frame",
        ),
    ];
    for (args, want) in cases {
        let out = strata()
            .args(["display", "--scene", "spheres", "--nodes", "127.0.0.1:9"])
            .args(*args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.starts_with("strata: "), "{args:?}: {stderr}");
        assert!(stderr.contains(want), "{args:?}: want {want:?} in {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

#[test]
fn node_errors_are_clear() {
    let cases: &[(&[&str], &str)] = &[
        (
            &["--scene", "mixed", "--objects", "teapot"],
            "has no object 'teapot'",
        ),
        (
            &["--scene", "mixed", "--method", "wboit"],
            "cannot feed a display",
        ),
        (&["--scene", "no-such-scene"], "no-such-scene"),
    ];
    for (args, want) in cases {
        assert_node_refuses(args, want);
    }
    let out = strata()
        .args(["node", "--listen", "not-an-address", "--scene", "spheres"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot listen on not-an-address"));
}

/// `strata node --listen 127.0.0.1:0 ARGS` exits with status 2 and says `want`.
fn assert_node_refuses(args: &[&str], want: &str) {
    let out = strata()
        .args(["node", "--listen", "127.0.0.1:0"])
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    assert!(stderr.contains(want), "{args:?}: want {want:?} in {stderr}");
}

#[test]
fn recording_and_replay_errors_are_clear() {
    let dir = TempDir::new().unwrap();
    let garbage = dir.path().join("garbage.rec");
    std::fs::write(&garbage, b"these are not the bytes you are looking for").unwrap();
    let missing = dir.path().join("missing.rec");
    let unwritable = dir.path().join("no-such-folder").join("out.rec");
    let (garbage, missing, unwritable) = (
        garbage.display().to_string(),
        missing.display().to_string(),
        unwritable.display().to_string(),
    );
    let cases: &[(&[&str], &str)] = &[
        (&[], "--scene"),
        (&["--replay", &missing], "reading"),
        (&["--replay", &garbage], "is not a strata recording"),
        (
            &["--scene", "mixed", "--replay", &garbage],
            "cannot be used with",
        ),
        (&["--scene", "mixed", "--record", &unwritable], "creating"),
    ];
    for (args, want) in cases {
        assert_node_refuses(args, want);
    }
    let out = strata()
        .args(["display", "--scene", "mixed", "--nodes", "127.0.0.1:9"])
        .args(["--discard", "--save-frames", "--out-dir"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot be used with"));
}

#[test]
fn a_recorded_node_replays_to_a_display_and_serves_a_discarding_one() {
    let dir = TempDir::new().unwrap();
    let rec = dir.path().join("mixed.rec");
    let rec_arg = rec.display().to_string();
    let run = |node: &Service, extra: &[&str], out: &str| {
        let out_dir = dir.path().join(out);
        let o = strata()
            .args(["display", "--scene", "mixed", "--nodes", &node.addr])
            .args(["--frames", "3", "--size", "64x36", "--timeout", "20"])
            .args(extra)
            .arg("--out-dir")
            .arg(&out_dir)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout).to_string();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{extra:?}: {stdout}{stderr}");
        let json: Value =
            serde_json::from_slice(&std::fs::read(out_dir.join("summary.json")).unwrap()).unwrap();
        (stdout, json)
    };
    let (_, live) = {
        let node = node_with(&["--scene", "mixed", "--record", &rec_arg]);
        run(&node, &[], "live")
    };
    let replay = node_with(&["--replay", &rec_arg]);
    let (_, replayed) = run(&replay, &[], "replayed");
    // The same frames, bytes and exactness as when the node rendered them.
    for key in [
        "bytes_per_frame",
        "frames_with_bad_pixels",
        "checked_frames",
    ] {
        assert_eq!(live[key], replayed[key], "{key}");
    }
    assert_eq!(replayed["checked_frames"], 3);
    assert_eq!(replayed["frames_with_bad_pixels"], 0);
    let (stdout, discarded) = run(&replay, &["--discard"], "discarded");
    assert_eq!(discarded["discarded"], true);
    assert_eq!(discarded["bytes_per_frame"], live["bytes_per_frame"]);
    assert_eq!(discarded["decode_ms"], 0.0);
    assert!(stdout.contains("node rate"), "{stdout}");
    assert_eq!(live["discarded"], false);
}

/// `strata display --scene SCENE --nodes NODES --frames FRAMES --size 64x36 --timeout
/// TIMEOUT`, writing its summary into `dir`. Nothing here waits for the timeout but a node that
/// never connects; real nodes get a long one, so a slow machine does not stall them.
fn display(scene: &str, nodes: &str, frames: &str, timeout: &str, dir: &TempDir) -> Output {
    strata()
        .args(["display", "--scene", scene, "--nodes", nodes])
        .args(["--frames", frames, "--size", "64x36", "--timeout", timeout])
        .arg("--out-dir")
        .arg(dir.path())
        .output()
        .unwrap()
}

fn summary_json(dir: &TempDir) -> Value {
    serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap())
        .unwrap()
}

/// The run's figures are absent: no rate or byte count of empty frames anywhere.
fn assert_no_figures(stdout: &str, json: &Value) {
    for absent in ["display rate", "fps", "bytes per frame", "MB"] {
        assert!(!stdout.contains(absent), "{absent:?} in {stdout}");
    }
    for absent in ["display_fps", "bytes_per_frame", "raw_bytes_per_frame"] {
        assert!(json.get(absent).is_none(), "{absent} in {json}");
    }
}

#[test]
fn no_node_listening_is_a_failed_run() {
    // A port that was free a moment ago: nothing listens on it.
    let nobody = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .to_string();
    let dir = TempDir::new().unwrap();
    let out = display("spheres", &nobody, "2", "0.5", &dir);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("strata: error: no node delivered a frame, so nothing was displayed"),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!("{nobody}: frame 0: down: cannot connect")),
        "{stderr}"
    );
    assert!(
        stdout.contains("FAILED: no node delivered any of the 2 frame(s)"),
        "{stdout}"
    );
    let json = summary_json(&dir);
    assert_eq!(json["outcome"], "nothing-delivered");
    assert_eq!(json["delivered_frames"], 0);
    assert_no_figures(&stdout, &json);
    // Nothing to compare against the exact render either.
    assert_eq!(json["checked_frames"], 0);
}

#[test]
fn a_node_serving_another_scene_is_a_failed_run() {
    let node = node("mixed", "0");
    let dir = TempDir::new().unwrap();
    let out = display("spheres", &node.addr, "2", "10", &dir);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("no node delivered a frame"), "{stderr}");
    assert!(
        stderr.contains("serves scene 'mixed', not 'spheres'"),
        "{stderr}"
    );
    assert_no_figures(&stdout, &summary_json(&dir));
}

#[test]
fn a_malformed_address_is_a_usage_error_before_any_connection() {
    // A listener that would see the display's connection, if it tried one.
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let good = listener.local_addr().unwrap().to_string();
    for (bad, want) in [
        ("not-an-address", "is not HOST:PORT"),
        ("127.0.0.1:0", "the port '0' is not a number in 1..=65535"),
        ("127.0.0.1:99999", "the port '99999'"),
        ("::1:7400", "IPv6 goes in brackets"),
    ] {
        let dir = TempDir::new().unwrap();
        let out = display("spheres", &format!("{good},{bad}"), "2", "0.5", &dir);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{bad}: {stderr}");
        assert!(stderr.starts_with("strata: "), "{bad}: {stderr}");
        assert!(stderr.contains(want), "{bad}: want {want:?} in {stderr}");
        assert!(!dir.path().join("summary.json").exists(), "{bad}");
    }
    let accepted = listener.accept();
    assert!(
        matches!(&accepted, Err(e) if e.kind() == std::io::ErrorKind::WouldBlock),
        "the display connected before checking its arguments: {accepted:?}"
    );
}

/// Reads one whole message from `from`: its prefix and its body.
fn read_msg(from: &mut TcpStream) -> Option<(MessageType, Vec<u8>)> {
    let mut msg = vec![0u8; PREFIX_LEN];
    from.read_exact(&mut msg).ok()?;
    let prefix = parse_prefix(&msg, &DecodeOptions::default()).ok()?;
    let mut body = vec![0u8; usize::try_from(prefix.body_len).ok()?];
    from.read_exact(&mut body).ok()?;
    msg.extend_from_slice(&body);
    Some((prefix.kind, msg))
}

/// A proxy in front of `node` that passes its first connection's frames `0..frames` (each a
/// frame and a stats message) and no later one, closes the connection when the display asks
/// for frame `frames + 1` (so frame `frames` is missing by then), and refuses any other
/// connection: a node lost for good in the middle of a run.
fn dying_proxy(node: String, frames: u64) -> String {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        let Ok((display, _)) = listener.accept() else {
            return;
        };
        drop(listener);
        let Ok(upstream) = TcpStream::connect(&node) else {
            return;
        };
        let (mut from_display, mut to_node) =
            (display.try_clone().unwrap(), upstream.try_clone().unwrap());
        let (display_end, node_end) = (display.try_clone().unwrap(), upstream.try_clone().unwrap());
        std::thread::spawn(move || {
            while let Some((_, msg)) = read_msg(&mut from_display) {
                let asked = Request::decode(&msg, &DecodeOptions::default()).unwrap();
                if asked.frame_number > frames {
                    break;
                }
                if to_node.write_all(&msg).is_err() {
                    break;
                }
            }
            display_end.shutdown(Shutdown::Both).ok();
            node_end.shutdown(Shutdown::Both).ok();
        });
        let (mut from_node, mut to_display) = (upstream, display);
        let mut passing = true;
        while let Some((kind, msg)) = read_msg(&mut from_node) {
            if kind == MessageType::Frame {
                let info = inspect_frame(&msg, &DecodeOptions::default()).unwrap();
                passing = info.header.frame_number < frames;
            }
            if passing && to_display.write_all(&msg).is_err() {
                break;
            }
        }
    });
    addr
}

#[test]
fn a_lost_node_makes_a_degraded_run() {
    let a = node("mixed", "0,1");
    let b = node("mixed", "2,3,4");
    let lost = dying_proxy(b.addr.clone(), 2);
    let dir = TempDir::new().unwrap();
    let out = display("mixed", &format!("{},{lost}", a.addr), "6", "10", &dir);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stdout}\n{stderr}");
    assert!(
        stderr.contains(&format!(
            "strata: error: the run was degraded: {lost} delivered 2 of 6 frames"
        )),
        "{stderr}"
    );
    assert!(
        stdout.contains("DEGRADED: 1 of 2 node(s) missed frames"),
        "{stdout}"
    );
    assert!(
        stdout.contains(&format!(
            "node {lost}: delivered 2 of 6 frame(s); missed 4 from frame 2 \
             (its last good frame, 1, was held)"
        )),
        "{stdout}"
    );
    // The live node's frames are real: the run still has its figures.
    assert!(stdout.contains("display rate"), "{stdout}");
    let json = summary_json(&dir);
    assert_eq!(json["outcome"], "degraded");
    assert_eq!(json["delivered_frames"], 6);
    assert_eq!(json["shortfalls"][0]["node"], lost.as_str());
    assert_eq!(json["shortfalls"][0]["missed"], 4);
    assert_eq!(json["per_frame"][5]["nodes"][1]["status"], "held");
    assert!(json["bytes_per_frame"].as_f64().unwrap() > 0.0);
    let summary_txt = std::fs::read_to_string(dir.path().join("summary.txt")).unwrap();
    assert!(summary_txt.contains("DEGRADED"), "{summary_txt}");
}
