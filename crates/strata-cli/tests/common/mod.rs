//! Helpers shared by the `strata` command's test files: running the binary with or without mesh
//! directories, checking that a run succeeded or failed the documented way, reading what it wrote.

#![allow(
    dead_code,
    unused_imports,
    reason = "each test binary uses a different subset of the helpers"
)]

use std::path::{Path, PathBuf};

use assert_cmd::Command;
use serde_json::Value;
use strata_core::Rgb8Image;

pub(crate) use strata_testdata::assert_mentions;

/// The `strata` binary, with the caller's environment (see [`strata_without_models`] to isolate it).
pub(crate) fn strata() -> Command {
    Command::cargo_bin("strata").expect("the strata binary is built for integration tests")
}

/// `strata` with no mesh directories at all: `STRATA_MODEL_PATH`, `HOME` and `XDG_DATA_HOME` all
/// point at `empty` (an empty directory).
pub(crate) fn strata_without_models(empty: &Path) -> Command {
    let mut c = strata();
    c.env("STRATA_MODEL_PATH", empty)
        .env("HOME", empty)
        .env("XDG_DATA_HOME", empty);
    c
}

/// `strata` that finds meshes only in `models` (a `STRATA_MODEL_PATH` value), not in the user's
/// own model folder: `HOME` and `XDG_DATA_HOME` point at `empty`.
pub(crate) fn strata_with_models(models: &std::ffi::OsStr, empty: &Path) -> Command {
    let mut c = strata();
    c.env("STRATA_MODEL_PATH", models)
        .env("HOME", empty)
        .env("XDG_DATA_HOME", empty);
    c
}

/// Output of a command that succeeded.
pub(crate) struct Ran {
    /// Its standard output.
    pub(crate) stdout: String,
    /// Its standard error.
    pub(crate) stderr: String,
}

/// Runs a command that must succeed without panicking.
pub(crate) fn run_ok(cmd: &mut Command) -> Ran {
    let out = cmd.output().expect("strata runs");
    let ran = Ran {
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    };
    assert!(
        out.status.success(),
        "expected success, got {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status.code(),
        ran.stdout,
        ran.stderr
    );
    assert_no_panic(&ran.stderr);
    ran
}

/// Runs a command that must fail the documented way (exit 2, `strata: error: …`, no panic) and
/// returns its stderr.
pub(crate) fn run_err(cmd: &mut Command) -> String {
    let out = cmd.output().expect("strata runs");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(
        out.status.code(),
        Some(2),
        "expected exit code 2\nstdout:\n{}\nstderr:\n{stderr}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert_no_panic(&stderr);
    assert!(
        stderr.contains("strata: error:"),
        "no 'strata: error:' in stderr:\n{stderr}"
    );
    stderr
}

/// Fails if `stderr` shows a Rust panic.
pub(crate) fn assert_no_panic(stderr: &str) {
    assert!(
        !stderr.contains("panicked at"),
        "strata panicked:\n{stderr}"
    );
}

/// The JSON file at `path`.
pub(crate) fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: bad JSON: {e}", path.display()))
}

/// The 8-bit RGB or RGBA PNG at `path`.
pub(crate) fn read_png(path: &Path) -> Rgb8Image {
    Rgb8Image::read_png(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

/// Writes `text` to `dir/name` and returns the path.
pub(crate) fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// The bytes of the file at `path`.
pub(crate) fn bytes(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

/// A `strata` service process (`node`, `mfr-slow`) that prints `listening on ADDR` first on its
/// standard output; killed when dropped.
pub(crate) struct Service {
    child: std::process::Child,
    /// The address it listens on.
    pub(crate) addr: String,
}

impl Service {
    /// Runs `strata ARGS` and waits for the line that names its address.
    pub(crate) fn start(args: &[&str]) -> Service {
        use std::io::{BufRead, BufReader};
        let mut child = std::process::Command::new(assert_cmd::cargo::cargo_bin("strata"))
            .args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("strata {args:?} starts: {e}"));
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("a first line");
        let addr = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| {
                panic!("strata {args:?}: the first line names the address: {line:?}")
            })
            .to_owned();
        Service { child, addr }
    }

    /// Kills the process now.
    pub(crate) fn kill(&mut self) {
        self.child.kill().ok();
        self.child.wait().ok();
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        self.kill();
    }
}
