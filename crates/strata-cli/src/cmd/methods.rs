//! `strata methods`: the fragment stores and what each is.

use anyhow::Result;

/// List the fragment stores `--method` accepts.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {}

/// Runs `strata methods`.
pub(crate) fn run(_args: Args) -> Result<()> {
    for m in strata_stores::METHODS {
        outln!("{:<20} {}", m.name, m.summary)?;
    }
    Ok(())
}
