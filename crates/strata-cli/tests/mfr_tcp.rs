//! `strata mfr-slow` and `strata mfr --transport tcp:…` as two processes on loopback: a clean
//! run audits to zero artefacts with its transfer figures in the summary; a slow client serving
//! another scene is refused before the run with a message that says so; TCP without the real
//! clock is a usage error.

use assert_cmd::Command;
use serde_json::Value;
use tempfile::TempDir;

mod common;

use common::Service;

/// `strata mfr-slow SCENE` on a free loopback port (one thread), killed when dropped.
fn slow_client(scene: &str) -> Service {
    Service::start(&[
        "mfr-slow",
        scene,
        "--listen",
        "127.0.0.1:0",
        "--threads",
        "1",
    ])
}

fn strata() -> Command {
    Command::cargo_bin("strata").expect("the strata binary")
}

#[test]
fn a_tcp_run_is_exact_and_reports_its_transfers() {
    let sc = slow_client("mixed");
    let dir = TempDir::new().expect("temp dir");
    let out = strata()
        .args(["mfr", "mixed", "--clock", "real:fc_hz=60", "--frames", "30"])
        .args(["--size", "64x36", "--transport"])
        .arg(format!("tcp:{}", sc.addr))
        .arg("--out-dir")
        .arg(dir.path())
        .output()
        .expect("strata mfr runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.path().join("summary.json")).expect("summary");
    let s: Value = serde_json::from_str(&text).expect("JSON");
    assert_eq!(s["transport"], format!("tcp:{}", sc.addr));
    assert_eq!(s["fc_frames"], 30);
    assert_eq!(s["audited_frames"], 30);
    assert_eq!(s["frames_with_bad_pixels"], 0);
    assert_eq!(s["incidents"], Value::Array(vec![]), "{text}");
    // The SC rendered at least its first state, and the FC received it over the socket.
    assert!(s["sc_frames"].as_u64().is_some_and(|n| n >= 1), "{text}");
    assert!(
        s["sc_bytes"]["median"].as_f64().is_some_and(|b| b > 0.0),
        "{text}"
    );
    assert!(s["transfer_ms"]["median"].is_number(), "{text}");
}

#[test]
fn a_slow_client_with_another_scene_is_refused() {
    let sc = slow_client("overlap");
    let out = strata()
        .args([
            "mfr",
            "mixed",
            "--clock",
            "real",
            "--frames",
            "3",
            "--transport",
        ])
        .arg(format!("tcp:{}", sc.addr))
        .output()
        .expect("strata mfr runs");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("the slow client refused the connection")
            && err.contains("the fast client renders scene 'mixed', the slow client 'overlap'"),
        "{err}"
    );
    assert!(
        out.stdout.is_empty(),
        "no summary for a run that did not start"
    );
}

#[test]
fn tcp_needs_the_real_clock_and_an_address() {
    let out = strata()
        .args(["mfr", "mixed", "--transport", "tcp:127.0.0.1:1"])
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("need the real clock (--clock real)"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = strata()
        .args(["mfr", "mixed", "--clock", "real", "--transport", "udp:x"])
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("expected thread or tcp:HOST:PORT"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
