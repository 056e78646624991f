//! External programs a test runs as an oracle (`oiiotool`, `exrheader`, `python3 -c 'import
//! OpenEXR'`), with the same policy as the real meshes.
//!
//! Policy for a missing tool, read from `STRATA_REQUIRE_TOOLS`:
//!
//! | value | a missing or broken tool |
//! | --- | --- |
//! | unset, empty or `0` | the test prints a visible `SKIPPED: <test>: …` line and returns |
//! | `1` (CI) | the test fails, naming the package to install |
//!
//! Any other value fails the test, so a typo cannot turn the checks off.

use std::process::Command;

/// The variable that turns a missing tool into a failure.
pub const REQUIRE_VAR: &str = "STRATA_REQUIRE_TOOLS";

/// True if `program args…` runs and succeeds. Otherwise, with `STRATA_REQUIRE_TOOLS=1` the test
/// panics naming `package`; without it a `SKIPPED:` line is printed (past the test harness's
/// output capture) and `false` returned, and the caller returns.
#[track_caller]
pub fn tool(program: &str, args: &[&str], package: &str) -> bool {
    let works = Command::new(program)
        .args(args)
        .output()
        .is_ok_and(|o| o.status.success());
    works || missing(program, package)
}

/// True if `program` can be started at all (for tools with no argument that exits 0).
#[track_caller]
pub fn present(program: &str, package: &str) -> bool {
    Command::new(program).output().is_ok() || missing(program, package)
}

/// The policy for a missing tool: panic when required, else say SKIPPED and return false.
#[track_caller]
fn missing(program: &str, package: &str) -> bool {
    let test = crate::current_test();
    match std::env::var(REQUIRE_VAR).as_deref() {
        Ok("1") => panic!(
            "{test}: `{program}` is missing or does not run; install {package} \
             ({REQUIRE_VAR}=1 requires it)"
        ),
        Ok("" | "0") | Err(std::env::VarError::NotPresent) => {
            crate::say(&format!(
                "SKIPPED: {test}: `{program}` not found (install {package})"
            ));
            false
        }
        Ok(other) => panic!("{REQUIRE_VAR} must be 1 or 0, not {other:?}"),
        Err(e) => panic!("{REQUIRE_VAR}: {e}"),
    }
}

/// `oiiotool` (Debian: openimageio-tools).
#[track_caller]
pub fn oiiotool() -> bool {
    tool("oiiotool", &["--version"], "openimageio-tools (oiiotool)")
}

/// `iinfo` (Debian: openimageio-tools).
#[track_caller]
pub fn iinfo() -> bool {
    tool("iinfo", &["--help"], "openimageio-tools (iinfo)")
}

/// `exrheader` (Debian: openexr).
#[track_caller]
pub fn exrheader() -> bool {
    // exrheader has no option that exits 0 in every version: only check that it starts.
    present("exrheader", "openexr (exrheader)")
}

/// Python 3 with the `OpenEXR` module (PyPI: OpenEXR).
#[track_caller]
pub fn python_openexr() -> bool {
    tool(
        "python3",
        &["-c", "import OpenEXR"],
        "Python's OpenEXR module (python3 -m pip install OpenEXR)",
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_program_that_runs_is_found() {
        // `sh` is on every machine these tests run on.
        assert!(tool("sh", &["-c", "exit 0"], "a POSIX shell"));
    }

    #[test]
    fn a_failing_program_is_not_a_working_tool() {
        // Under STRATA_REQUIRE_TOOLS=1 this panics, which is what CI must do for a broken tool;
        // so only check the skip path when the variable does not require tools.
        if std::env::var(REQUIRE_VAR).as_deref() == Ok("1") {
            let r = std::panic::catch_unwind(|| tool("sh", &["-c", "exit 3"], "x"));
            assert!(
                r.is_err(),
                "a failing tool must fail the test when required"
            );
        } else {
            assert!(!tool("sh", &["-c", "exit 3"], "x"));
        }
    }
}
