//! Test support shared by strata's own test suites (a dev-dependency only, never published).
//!
//! - [`models`](mod@models): finds the real meshes (Stanford dragon, bunny, armadillo; the Khronos engine)
//!   in one documented search order, and applies one policy when a mesh is missing: a visible
//!   `SKIPPED:` line on stderr, or — with `STRATA_REQUIRE_MODELS=1`, as CI sets it — a test
//!   failure that names every place searched.
//! - [`reference`](mod@reference): exact comparison of a rendered RGB image against a PNG stored in the
//!   repository, `STRATA_BLESS=1` to rewrite it, and an actual and a diff image written next to
//!   the reference when they differ.
//! - [`tools`]: external programs used as oracles (OpenImageIO, OpenEXR), with the same
//!   visible-skip or fail policy, through `STRATA_REQUIRE_TOOLS=1`.
//! - [`assert_mentions`]: the "this message names these things" check the CLI tests share.
//!
//! The crate depends on no strata crate, so every strata crate can use it in its tests without a
//! dependency cycle.

pub mod models;
pub mod reference;
pub mod tools;

pub use models::{Models, model, models};
pub use reference::{Rgb8, assert_matches_reference};

/// Asserts that `text` contains every one of `needles`, showing the whole text when one is missing.
#[track_caller]
pub fn assert_mentions(text: &str, needles: &[&str]) {
    let missing: Vec<&str> = needles
        .iter()
        .copied()
        .filter(|n| !text.contains(n))
        .collect();
    assert!(missing.is_empty(), "expected {missing:?} in:\n{text}");
}

/// Writes one line straight to the process's stderr, past libtest's output capture, so that it
/// shows in `cargo test` output even when the test passes. (`eprintln!` is captured and only
/// shown for failing tests.)
pub fn say(line: &str) {
    use std::io::Write as _;
    // Nothing useful can be done if stderr is closed; the test itself still runs its checks.
    let _ = writeln!(std::io::stderr().lock(), "{line}");
}

/// The name of the running test: libtest names each test's thread after the test.
pub fn current_test() -> String {
    std::thread::current()
        .name()
        .filter(|n| *n != "main")
        .unwrap_or("(unnamed test)")
        .to_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assert_mentions_accepts_present_words() {
        assert_mentions("cannot find mesh 'bunny.obj'", &["bunny.obj", "mesh"]);
    }

    #[test]
    #[should_panic(expected = "expected [\"STRATA_MODEL_PATH\"] in:\ncannot find mesh")]
    fn assert_mentions_names_the_missing_word() {
        assert_mentions("cannot find mesh", &["mesh", "STRATA_MODEL_PATH"]);
    }

    #[test]
    fn current_test_is_the_test_name() {
        assert_eq!(current_test(), "tests::current_test_is_the_test_name");
    }
}
