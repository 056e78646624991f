//! `strata scenes`: list the built-in scenes or print one.

use anyhow::{Result, bail};
use strata_scene::builtin;

use crate::options::search_path;

/// List the built-in scenes, or print one as a scene file to start your own from.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Print this built-in scene's scene file instead of listing.
    #[arg(long, value_name = "NAME")]
    pub(crate) print: Option<String>,
}

/// Runs `strata scenes`.
pub(crate) fn run(args: Args) -> Result<()> {
    if let Some(name) = args.print {
        match builtin::find(&name) {
            Some(s) => out!("{}", s.source)?,
            None => bail!(
                "no built-in scene named '{name}' (known: {})",
                builtin::names().join(", ")
            ),
        }
        return Ok(());
    }
    let search = search_path(&[]);
    for s in builtin::SCENES {
        let status = if s.available(&search) {
            ""
        } else {
            " [mesh not found: set STRATA_MODEL_PATH or run scripts/fetch-models]"
        };
        outln!("{:<12} {}{}", s.name, s.description, status)?;
    }
    Ok(())
}
