//! End-to-end tests of `strata node` and `strata display` on loopback: two node processes
//! holding complementary objects, a display that merges them, its summary and its errors.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command as StdCommand, Stdio};

use assert_cmd::Command;
use assert_cmd::cargo::cargo_bin;
use serde_json::Value;
use tempfile::TempDir;

/// A `strata node` process, killed when dropped.
struct NodeProcess {
    child: Child,
    addr: String,
}

impl NodeProcess {
    fn start(scene: &str, objects: &str) -> NodeProcess {
        let mut child = StdCommand::new(cargo_bin("strata"))
            .args([
                "node",
                "--listen",
                "127.0.0.1:0",
                "--scene",
                scene,
                "--objects",
                objects,
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("strata node starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let addr = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("first line names the address: {line:?}"))
            .to_string();
        NodeProcess { child, addr }
    }
}

impl Drop for NodeProcess {
    fn drop(&mut self) {
        self.child.kill().ok();
        self.child.wait().ok();
    }
}

fn strata() -> Command {
    Command::cargo_bin("strata").unwrap()
}

#[test]
fn two_node_processes_merge_into_the_exact_image() {
    let a = NodeProcess::start("mixed", "opaque cube,glass slab");
    let b = NodeProcess::start("mixed", "1,2,4");
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
        (&["--size", "0x10"], "width and height"),
        (&["--frames", "0"], "--frames must be at least 1"),
        (&["--codec", "gzip"], "unknown codec"),
        (&["--timeout", "0"], "--timeout"),
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
        let out = strata()
            .args(["node", "--listen", "127.0.0.1:0"])
            .args(*args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(want), "{args:?}: want {want:?} in {stderr}");
    }
    let out = strata()
        .args(["node", "--listen", "not-an-address", "--scene", "spheres"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot listen on not-an-address"));
}

#[test]
fn an_absent_node_is_reported_and_the_display_still_finishes() {
    let out = strata()
        .args([
            "display",
            "--scene",
            "spheres",
            "--nodes",
            "127.0.0.1:9",
            "--frames",
            "2",
        ])
        .args(["--size", "64x36", "--timeout", "0.5"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("cannot connect"), "{stdout}");
}
