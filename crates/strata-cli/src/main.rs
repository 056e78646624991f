//! `strata`: render scenes with any fragment store, benchmark them, run the demo.

mod cmd;
mod options;
mod report;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// strata keeps every fragment of every pixel, so transparency is correct in any draw order.
///
/// SCENE arguments are a scene file (TOML, see `strata scenes --print slabs` for an example) or
/// the name of a built-in scene (`strata scenes` lists them). Mesh files named by a scene are
/// found next to the scene file, then in the directories of STRATA_MODEL_PATH (colon-separated),
/// then in ~/.local/share/strata/models (where scripts/fetch-models puts them).
#[derive(Parser, Debug)]
#[command(name = "strata", version, about, long_about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render one frame of a scene to a PNG, optionally with statistics.
    Render(cmd::render::Args),
    /// Render every built-in scene (and the real meshes when found) into a folder with a report.
    Demo(cmd::demo::Args),
    /// Time each pass of a method on a scene over repeated runs: median, min, max.
    Bench(cmd::bench::Args),
    /// List the built-in scenes, or print one as a scene file.
    Scenes(cmd::scenes::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(a) => cmd::render::run(a),
        Command::Demo(a) => cmd::demo::run(a),
        Command::Bench(a) => cmd::bench::run(a),
        Command::Scenes(a) => cmd::scenes::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strata: error: {e}");
            for cause in e.chain().skip(1) {
                eprintln!("  caused by: {cause}");
            }
            ExitCode::from(2)
        }
    }
}
