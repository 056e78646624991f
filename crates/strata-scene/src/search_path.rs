//! Where mesh files are found: next to the scene file, then along `STRATA_MODEL_PATH`, then in the
//! per-user model folder that `scripts/fetch-models` fills.
//!
//! A scene can say `mesh = "dragon_vrip.ply.gz"` and work on any machine that has the file in one
//! of these places:
//!
//! 1. an absolute path is used as it is;
//! 2. relative to the directory of the scene file (built-in scenes have none);
//! 3. each directory of `STRATA_MODEL_PATH` (colon-separated), in order;
//! 4. `$XDG_DATA_HOME/strata/models`, or `~/.local/share/strata/models` without `XDG_DATA_HOME`.

use std::path::{Path, PathBuf};

/// The environment variable listing extra model directories.
pub const MODEL_PATH_VAR: &str = "STRATA_MODEL_PATH";

/// An ordered list of directories to look for meshes in.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SearchPath {
    dirs: Vec<PathBuf>,
}

impl SearchPath {
    /// Exactly these directories.
    pub fn new(dirs: impl IntoIterator<Item = PathBuf>) -> Self {
        SearchPath {
            dirs: dirs.into_iter().collect(),
        }
    }

    /// `STRATA_MODEL_PATH` followed by the per-user model folder.
    pub fn from_env() -> Self {
        let mut dirs: Vec<PathBuf> = std::env::var_os(MODEL_PATH_VAR)
            .map(|v| {
                std::env::split_paths(&v)
                    .filter(|p| !p.as_os_str().is_empty())
                    .collect()
            })
            .unwrap_or_default();
        if let Some(d) = user_model_dir() {
            dirs.push(d);
        }
        SearchPath { dirs }
    }

    /// Puts `dir` first.
    pub fn prepend(&mut self, dir: PathBuf) {
        self.dirs.insert(0, dir);
    }

    /// The directories, in search order.
    pub fn dirs(&self) -> &[PathBuf] {
        &self.dirs
    }

    /// Finds `name`, first relative to `scene_dir`, then along the path. On failure returns every
    /// place that was tried, for the error message.
    pub fn resolve(&self, name: &str, scene_dir: Option<&Path>) -> Result<PathBuf, Vec<PathBuf>> {
        let rel = Path::new(name);
        if rel.is_absolute() {
            return if rel.is_file() {
                Ok(rel.to_owned())
            } else {
                Err(vec![rel.to_owned()])
            };
        }
        let mut tried = Vec::new();
        for dir in scene_dir
            .into_iter()
            .chain(self.dirs.iter().map(PathBuf::as_path))
        {
            let candidate = dir.join(rel);
            if candidate.is_file() {
                return Ok(candidate);
            }
            tried.push(candidate);
        }
        Err(tried)
    }
}

/// `$XDG_DATA_HOME/strata/models` or `~/.local/share/strata/models`.
pub fn user_model_dir() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_DATA_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share")))?;
    Some(base.join("strata").join("models"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_dir_wins_then_path_order() {
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        let scene = tempfile::tempdir().unwrap();
        std::fs::write(b.path().join("m.obj"), "").unwrap();
        let sp = SearchPath::new([a.path().to_owned(), b.path().to_owned()]);
        assert_eq!(
            sp.resolve("m.obj", Some(scene.path())).unwrap(),
            b.path().join("m.obj")
        );
        std::fs::write(scene.path().join("m.obj"), "").unwrap();
        assert_eq!(
            sp.resolve("m.obj", Some(scene.path())).unwrap(),
            scene.path().join("m.obj")
        );
        let tried = sp.resolve("missing.ply", Some(scene.path())).unwrap_err();
        assert_eq!(tried.len(), 3);
        assert_eq!(tried[1], a.path().join("missing.ply"));
    }
}
