//! Where strata's tests find the real meshes, and what a test does when one is missing.
//!
//! Search order (first directory that holds the file wins):
//!
//! 1. each directory of `$STRATA_MODEL_PATH` (colon-separated), in order; a relative one is taken
//!    relative to the workspace root, because `cargo test` runs each test binary in its crate's
//!    directory (so `STRATA_MODEL_PATH=../shared/models cargo test` means the same folder from
//!    every crate, the one next to the repository);
//! 2. `<workspace root>/../shared/models`, the folder next to the repository that the project's
//!    own machines keep the meshes in;
//! 3. `$XDG_DATA_HOME/strata/models`, or `~/.local/share/strata/models` without
//!    `XDG_DATA_HOME`: the folder `scripts/fetch-models` fills by default.
//!
//! Policy for a missing mesh, read from `STRATA_REQUIRE_MODELS`:
//!
//! - `1`: the test fails, and its message names the file and every place searched (CI sets this,
//!   so a run without meshes can never pass unnoticed);
//! - unset, empty or `0`: the test prints `SKIPPED: <test>: <file> not found (set
//!   STRATA_MODEL_PATH or run scripts/fetch-models)` straight to stderr — past libtest's capture,
//!   so it shows in `cargo test` output although the test reports `ok` — and returns;
//! - anything else: the test fails, naming the accepted values.
//!
//! The pure part ([`SearchOrder`], [`Policy`], [`resolve`]) takes its inputs as arguments and is
//! tested here; [`models`] and [`model`] read the process environment and act on the outcome.

use std::ffi::{OsStr, OsString};
use std::fmt;
use std::path::{Path, PathBuf};

/// The environment variable listing model directories (colon-separated), searched first.
pub const MODEL_PATH_VAR: &str = "STRATA_MODEL_PATH";
/// The environment variable that turns a missing mesh into a test failure when set to `1`.
pub const REQUIRE_VAR: &str = "STRATA_REQUIRE_MODELS";

/// Why a directory is on the search order (shown in failure messages).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// A directory of `$STRATA_MODEL_PATH`.
    ModelPathVar,
    /// `<workspace root>/../shared/models`.
    NextToWorkspace,
    /// The per-user folder `scripts/fetch-models` fills.
    FetchModels,
}

impl fmt::Display for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Origin::ModelPathVar => "from STRATA_MODEL_PATH",
            Origin::NextToWorkspace => "next to the workspace",
            Origin::FetchModels => "filled by scripts/fetch-models",
        })
    }
}

/// One directory of the search order and why it is there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Place {
    /// The directory (it may not exist).
    pub dir: PathBuf,
    /// Where it comes from.
    pub origin: Origin,
}

/// The directories searched for meshes, in order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SearchOrder {
    places: Vec<Place>,
}

/// The environment a [`SearchOrder`] is built from, as plain values (so it can be tested without
/// touching the process environment).
#[derive(Clone, Debug, Default)]
pub struct EnvVars {
    /// `STRATA_MODEL_PATH`.
    pub model_path: Option<OsString>,
    /// `XDG_DATA_HOME`.
    pub xdg_data_home: Option<OsString>,
    /// `HOME`.
    pub home: Option<OsString>,
}

impl EnvVars {
    /// The values of this process's environment.
    pub fn from_process() -> Self {
        EnvVars {
            model_path: std::env::var_os(MODEL_PATH_VAR),
            xdg_data_home: std::env::var_os("XDG_DATA_HOME"),
            home: std::env::var_os("HOME"),
        }
    }
}

impl SearchOrder {
    /// The search order for `vars`, with `workspace_root` the directory of the workspace's
    /// `Cargo.toml`.
    pub fn new(vars: &EnvVars, workspace_root: &Path) -> Self {
        let mut places: Vec<Place> = vars
            .model_path
            .as_deref()
            .map(|v| {
                std::env::split_paths(v)
                    .filter(|d| !d.as_os_str().is_empty())
                    .map(|dir| Place {
                        dir: workspace_root.join(dir),
                        origin: Origin::ModelPathVar,
                    })
                    .collect()
            })
            .unwrap_or_default();
        if let Some(parent) = workspace_root.parent() {
            places.push(Place {
                dir: parent.join("shared").join("models"),
                origin: Origin::NextToWorkspace,
            });
        }
        if let Some(dir) = fetch_models_dir(vars) {
            places.push(Place {
                dir,
                origin: Origin::FetchModels,
            });
        }
        SearchOrder { places }
    }

    /// The search order of this process's environment and this workspace.
    pub fn from_env() -> Self {
        SearchOrder::new(&EnvVars::from_process(), &workspace_root())
    }

    /// The directories, in search order.
    pub fn places(&self) -> &[Place] {
        &self.places
    }

    /// The first `<dir>/<file>` that is a file.
    pub fn find(&self, file: &str) -> Option<PathBuf> {
        self.places
            .iter()
            .map(|p| p.dir.join(file))
            .find(|candidate| candidate.is_file())
    }
}

/// `$XDG_DATA_HOME/strata/models`, else `$HOME/.local/share/strata/models` (as
/// `scripts/fetch-models` and strata itself compute it).
fn fetch_models_dir(vars: &EnvVars) -> Option<PathBuf> {
    let base = vars
        .xdg_data_home
        .as_deref()
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| {
            vars.home
                .as_deref()
                .filter(|v| !v.is_empty())
                .map(|h| Path::new(h).join(".local").join("share"))
        })?;
    Some(base.join("strata").join("models"))
}

/// The directory of the workspace's `Cargo.toml` (this crate lives in `<root>/crates/<name>`).
pub fn workspace_root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest
        .parent()
        .and_then(Path::parent)
        .unwrap_or(manifest)
        .to_owned()
}

/// What a test does when a mesh is missing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Policy {
    /// Fail (`STRATA_REQUIRE_MODELS=1`).
    Require,
    /// Print a `SKIPPED:` line and return (the variable unset, empty or `0`).
    Skip,
}

/// `STRATA_REQUIRE_MODELS` holds a value other than `1` or `0`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "STRATA_REQUIRE_MODELS must be 1 (a missing mesh fails the test) or 0 (it is skipped), not {0:?}"
)]
pub struct BadPolicy(pub OsString);

impl Policy {
    /// The policy for a value of `STRATA_REQUIRE_MODELS`.
    pub fn from_value(value: Option<&OsStr>) -> Result<Self, BadPolicy> {
        match value.map(|v| v.to_str()) {
            None | Some(Some("" | "0")) => Ok(Policy::Skip),
            Some(Some("1")) => Ok(Policy::Require),
            Some(_) => Err(BadPolicy(value.unwrap_or_default().to_owned())),
        }
    }

    /// The policy of this process's environment.
    pub fn from_env() -> Result<Self, BadPolicy> {
        Policy::from_value(std::env::var_os(REQUIRE_VAR).as_deref())
    }
}

/// Real meshes a test asked for, all found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Models {
    files: Vec<PathBuf>,
}

impl Models {
    /// The path of each requested file, in the order asked for.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// The path of the first requested file.
    pub fn first(&self) -> &Path {
        &self.files[0]
    }

    /// The distinct directories holding the files, in the order the files were asked for: a search
    /// path on which every requested file resolves.
    pub fn dirs(&self) -> Vec<PathBuf> {
        let mut dirs: Vec<PathBuf> = Vec::new();
        for dir in self.files.iter().filter_map(|f| f.parent()) {
            if !dirs.iter().any(|d| d == dir) {
                dirs.push(dir.to_owned());
            }
        }
        dirs
    }

    /// [`Models::dirs`] joined as a value for `STRATA_MODEL_PATH`.
    pub fn path_var(&self) -> OsString {
        std::env::join_paths(self.dirs())
            .unwrap_or_else(|e| panic!("a model directory cannot be put on a search path: {e}"))
    }
}

/// The outcome of looking for a test's meshes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Every file was found.
    Found(Models),
    /// Some file is missing and the test should be skipped: the line to print.
    Skip(String),
    /// Some file is missing and the test must fail: the failure message.
    Fail(String),
}

/// Looks for `files` along `order` for the test named `test`, applying `policy`.
pub fn resolve(order: &SearchOrder, policy: Policy, test: &str, files: &[&str]) -> Outcome {
    assert!(!files.is_empty(), "{test}: ask for at least one model file");
    let mut found = Vec::with_capacity(files.len());
    let mut missing = Vec::new();
    for &file in files {
        match order.find(file) {
            Some(path) => found.push(path),
            None => missing.push(file),
        }
    }
    if missing.is_empty() {
        return Outcome::Found(Models { files: found });
    }
    let missing = missing.join(", ");
    match policy {
        Policy::Skip => Outcome::Skip(format!(
            "SKIPPED: {test}: {missing} not found (set {MODEL_PATH_VAR} or run scripts/fetch-models)"
        )),
        Policy::Require => Outcome::Fail(failure_message(order, test, &missing)),
    }
}

fn failure_message(order: &SearchOrder, test: &str, missing: &str) -> String {
    let mut msg = format!(
        "{test}: {missing} not found, and {REQUIRE_VAR}=1 makes a missing mesh a failure.\nSearched, in order:"
    );
    for place in order.places() {
        msg.push_str(&format!("\n  {} ({})", place.dir.display(), place.origin));
    }
    if !order
        .places()
        .iter()
        .any(|p| p.origin == Origin::ModelPathVar)
    {
        msg.push_str(&format!("\n  ({MODEL_PATH_VAR} is not set)"));
    }
    msg.push_str(&format!(
        "\nSet {MODEL_PATH_VAR} to the folder that holds the meshes, or run scripts/fetch-models."
    ));
    msg
}

/// The real meshes `files` for the running test, found along [`SearchOrder::from_env`].
///
/// `None` after a visible `SKIPPED:` line when one is missing; with `STRATA_REQUIRE_MODELS=1`
/// a missing file panics instead, naming every place searched. Call it first in the test and
/// return on `None`:
///
/// ```no_run
/// let Some(models) = strata_testdata::models(&["bunny.obj", "armadillo.off"]) else {
///     return;
/// };
/// assert_eq!(models.files().len(), 2);
/// ```
#[track_caller]
pub fn models(files: &[&str]) -> Option<Models> {
    let test = crate::current_test();
    let policy = Policy::from_env().unwrap_or_else(|e| panic!("{test}: {e}"));
    match resolve(&SearchOrder::from_env(), policy, &test, files) {
        Outcome::Found(models) => Some(models),
        Outcome::Skip(line) => {
            crate::say(&line);
            None
        }
        Outcome::Fail(message) => panic!("{message}"),
    }
}

/// The real mesh `file` for the running test; see [`models`] for the policy.
#[track_caller]
pub fn model(file: &str) -> Option<PathBuf> {
    models(&[file]).map(|m| m.first().to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vars(model_path: Option<&str>, xdg: Option<&str>, home: Option<&str>) -> EnvVars {
        EnvVars {
            model_path: model_path.map(OsString::from),
            xdg_data_home: xdg.map(OsString::from),
            home: home.map(OsString::from),
        }
    }

    fn dirs(order: &SearchOrder) -> Vec<(PathBuf, Origin)> {
        order
            .places()
            .iter()
            .map(|p| (p.dir.clone(), p.origin))
            .collect()
    }

    #[test]
    fn order_is_model_path_then_shared_then_fetch_models() {
        let order = SearchOrder::new(
            &vars(Some("/a::/b"), Some("/xdg"), Some("/home/u")),
            Path::new("/work/repo"),
        );
        assert_eq!(
            dirs(&order),
            [
                (PathBuf::from("/a"), Origin::ModelPathVar),
                (PathBuf::from("/b"), Origin::ModelPathVar),
                (
                    PathBuf::from("/work/shared/models"),
                    Origin::NextToWorkspace
                ),
                (PathBuf::from("/xdg/strata/models"), Origin::FetchModels),
            ]
        );
    }

    #[test]
    fn relative_model_path_entries_start_at_the_workspace_root() {
        let order = SearchOrder::new(
            &vars(Some("../shared/models:/abs"), None, None),
            Path::new("/work/repo"),
        );
        assert_eq!(
            dirs(&order)[..2],
            [
                (
                    PathBuf::from("/work/repo/../shared/models"),
                    Origin::ModelPathVar
                ),
                (PathBuf::from("/abs"), Origin::ModelPathVar),
            ]
        );
    }

    #[test]
    fn fetch_models_folder_falls_back_to_home() {
        for xdg in [None, Some("")] {
            let order = SearchOrder::new(&vars(None, xdg, Some("/home/u")), Path::new("/r"));
            assert_eq!(
                dirs(&order),
                [
                    (PathBuf::from("/shared/models"), Origin::NextToWorkspace),
                    (
                        PathBuf::from("/home/u/.local/share/strata/models"),
                        Origin::FetchModels
                    ),
                ]
            );
        }
        let order = SearchOrder::new(&vars(None, None, None), Path::new("/r"));
        assert_eq!(order.places().len(), 1, "no HOME, no fetch-models folder");
    }

    #[test]
    fn the_workspace_root_holds_the_workspace_manifest() {
        let manifest = std::fs::read_to_string(workspace_root().join("Cargo.toml")).unwrap();
        assert!(manifest.contains("[workspace]"), "{manifest}");
    }

    #[test]
    fn policy_values() {
        let p = |v: Option<&str>| Policy::from_value(v.map(OsStr::new));
        assert_eq!(p(None), Ok(Policy::Skip));
        assert_eq!(p(Some("")), Ok(Policy::Skip));
        assert_eq!(p(Some("0")), Ok(Policy::Skip));
        assert_eq!(p(Some("1")), Ok(Policy::Require));
        let e = p(Some("yes")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "STRATA_REQUIRE_MODELS must be 1 (a missing mesh fails the test) or 0 (it is skipped), not \"yes\""
        );
    }

    /// Three temp dirs standing for the three kinds of place; `b` and `c` hold files.
    struct Fixture {
        _tmp: tempfile::TempDir,
        order: SearchOrder,
        b: PathBuf,
        c: PathBuf,
    }

    fn fixture() -> Fixture {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("repo");
        let a = tmp.path().join("a");
        let b = tmp.path().join("shared/models");
        let c = tmp.path().join("xdg/strata/models");
        for d in [&root, &a, &b, &c] {
            std::fs::create_dir_all(d).unwrap();
        }
        std::fs::write(b.join("bunny.obj"), "v 0 0 0\n").unwrap();
        std::fs::write(c.join("bunny.obj"), "v 1 1 1\n").unwrap();
        std::fs::write(c.join("armadillo.off"), "OFF\n").unwrap();
        let env = EnvVars {
            model_path: Some(a.clone().into_os_string()),
            xdg_data_home: Some(tmp.path().join("xdg").into_os_string()),
            home: None,
        };
        let order = SearchOrder::new(&env, &root);
        Fixture {
            _tmp: tmp,
            order,
            b,
            c,
        }
    }

    #[test]
    fn first_place_holding_each_file_wins() {
        let f = fixture();
        let Outcome::Found(m) = resolve(
            &f.order,
            Policy::Require,
            "t",
            &["bunny.obj", "armadillo.off"],
        ) else {
            panic!("both files exist");
        };
        assert_eq!(
            m.files(),
            [f.b.join("bunny.obj"), f.c.join("armadillo.off")]
        );
        assert_eq!(m.dirs(), [f.b.clone(), f.c.clone()]);
        assert_eq!(m.path_var(), std::env::join_paths([&f.b, &f.c]).unwrap());
    }

    #[test]
    fn a_directory_named_like_the_file_is_not_found() {
        let f = fixture();
        std::fs::create_dir(f.b.join("dragon_vrip.ply.gz")).unwrap();
        assert!(f.order.find("dragon_vrip.ply.gz").is_none());
    }

    #[test]
    fn missing_file_is_a_visible_skip() {
        let f = fixture();
        assert_eq!(
            resolve(&f.order, Policy::Skip, "mod::t", &["bunny.obj", "dragon_vrip.ply.gz"]),
            Outcome::Skip(
                "SKIPPED: mod::t: dragon_vrip.ply.gz not found (set STRATA_MODEL_PATH or run scripts/fetch-models)"
                    .into()
            )
        );
    }

    #[test]
    fn missing_file_under_require_names_every_place() {
        let f = fixture();
        let Outcome::Fail(msg) =
            resolve(&f.order, Policy::Require, "mod::t", &["dragon_vrip.ply.gz"])
        else {
            panic!("the dragon is missing");
        };
        assert!(
            msg.starts_with("mod::t: dragon_vrip.ply.gz not found, and STRATA_REQUIRE_MODELS=1"),
            "{msg}"
        );
        for place in f.order.places() {
            let line = format!("{} ({})", place.dir.display(), place.origin);
            assert!(msg.contains(&line), "{line} not in:\n{msg}");
        }
        assert!(msg.contains("from STRATA_MODEL_PATH"), "{msg}");
        assert!(!msg.contains("is not set"), "{msg}");
    }

    #[test]
    fn require_without_model_path_says_it_is_unset() {
        let order = SearchOrder::new(
            &vars(None, None, Some("/nonexistent-home")),
            Path::new("/nonexistent/repo"),
        );
        let Outcome::Fail(msg) = resolve(&order, Policy::Require, "t", &["bunny.obj"]) else {
            panic!("nothing exists there");
        };
        assert!(msg.contains("(STRATA_MODEL_PATH is not set)"), "{msg}");
        assert!(
            msg.contains("/nonexistent/shared/models (next to the workspace)"),
            "{msg}"
        );
        assert!(
            msg.contains(
                "/nonexistent-home/.local/share/strata/models (filled by scripts/fetch-models)"
            ),
            "{msg}"
        );
    }
}
