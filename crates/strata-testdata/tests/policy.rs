//! The missing-mesh policy end to end, as `cargo test` users see it: this test binary runs itself
//! as a child process on a test that asks for a mesh nobody has, and reads what the child printed.
//!
//! - Without `STRATA_REQUIRE_MODELS`, the child passes and its `SKIPPED:` line is on its stderr
//!   although libtest captured the test's output (a passing test's `eprintln!` would be hidden).
//! - With `STRATA_REQUIRE_MODELS=1`, the child fails and names every place searched.
//! - Any other value fails, naming the accepted ones.

use std::process::{Command, Output};

/// The child: asks for a file that exists nowhere. Run only by the tests below.
#[test]
#[ignore = "run as a child process by the other tests of this file"]
fn child_asks_for_a_missing_mesh() {
    if let Some(path) = strata_testdata::model("no-such-mesh-3f9c.ply") {
        panic!("found a file that should not exist: {}", path.display());
    }
}

/// Runs [`child_asks_for_a_missing_mesh`] in a child process with `require` as
/// `STRATA_REQUIRE_MODELS` (unset for `None`), nothing on the search path but an empty folder.
fn run_child(require: Option<&str>) -> Output {
    let empty = tempfile::tempdir().expect("temp dir");
    let mut cmd = Command::new(std::env::current_exe().expect("this test binary"));
    cmd.args([
        "--ignored",
        "--exact",
        "child_asks_for_a_missing_mesh",
        "--test-threads",
        "1",
    ])
    .env("STRATA_MODEL_PATH", empty.path())
    .env("XDG_DATA_HOME", empty.path())
    .env("HOME", empty.path())
    .env_remove("STRATA_REQUIRE_MODELS");
    if let Some(value) = require {
        cmd.env("STRATA_REQUIRE_MODELS", value);
    }
    cmd.output().expect("the test binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn without_the_variable_a_missing_mesh_is_a_visible_skip() {
    for require in [None, Some("0"), Some("")] {
        let out = run_child(require);
        let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
        assert!(out.status.success(), "{require:?}:\n{stdout}\n{stderr}");
        assert!(
            stdout.contains("1 passed"),
            "{require:?}: the child ran:\n{stdout}"
        );
        assert!(
            stderr.contains(
                "SKIPPED: child_asks_for_a_missing_mesh: no-such-mesh-3f9c.ply not found \
                 (set STRATA_MODEL_PATH or run scripts/fetch-models)"
            ),
            "{require:?}: no SKIPPED line past the capture:\n{stderr}"
        );
    }
}

#[test]
fn with_require_a_missing_mesh_fails_naming_the_places_searched() {
    let out = run_child(Some("1"));
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(!out.status.success(), "the child must fail:\n{stdout}");
    let all = format!("{stdout}{stderr}");
    strata_testdata::assert_mentions(
        &all,
        &[
            "1 failed",
            "child_asks_for_a_missing_mesh: no-such-mesh-3f9c.ply not found, and STRATA_REQUIRE_MODELS=1",
            "(from STRATA_MODEL_PATH)",
            "(next to the workspace)",
            "(filled by scripts/fetch-models)",
        ],
    );
    assert!(!all.contains("SKIPPED:"), "{all}");
}

#[test]
fn an_unknown_require_value_is_an_error() {
    let out = run_child(Some("yes"));
    let all = format!("{}{}", text(&out.stdout), text(&out.stderr));
    assert!(!out.status.success(), "{all}");
    strata_testdata::assert_mentions(
        &all,
        &[
            "STRATA_REQUIRE_MODELS must be 1 (a missing mesh fails the test) or 0 (it is skipped), not \"yes\"",
        ],
    );
}
