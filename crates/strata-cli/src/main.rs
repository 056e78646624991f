//! `strata`: render scenes with any fragment store, benchmark them, run the demo.

#[macro_use]
mod out;
mod cmd;
mod flip;
mod images;
mod options;
mod report;

use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// An error that ends strata with its own exit status (every other error exits with 2).
#[derive(Debug)]
pub(crate) struct Failed {
    /// The exit status.
    pub(crate) status: u8,
    /// What went wrong, for a person.
    pub(crate) message: String,
}

impl std::fmt::Display for Failed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Failed {}

/// strata keeps every fragment of every pixel, so transparency is correct in any draw order.
///
/// SCENE arguments are a scene file (TOML, see `strata scenes --print slabs` for an example) or
/// the name of a built-in scene (`strata scenes` lists them). Mesh files named by a scene are
/// found next to the scene file, then in --models directories, then in the directories of
/// STRATA_MODEL_PATH (colon-separated), then in $XDG_DATA_HOME/strata/models (by default
/// ~/.local/share/strata/models, where scripts/fetch-models puts them).
///
/// The rasteriser runs 16 SIMD lanes wide where the CPU has AVX-512, else 8; STRATA_LANES=8
/// makes it run 8 wide there too (the same frames), to compare the two on one machine
/// (STRATA_LANES=16 or unset: the widest; any other value is refused).
#[derive(Parser, Debug)]
#[command(name = "strata", version, about, long_about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    // The about text is `cmd::render::Args`'s doc comment (first paragraph in the list).
    Render(cmd::render::Args),
    /// Render every built-in scene (and the real meshes when found) into a folder with a report.
    Demo(cmd::demo::Args),
    /// Time each pass of a method on a scene over repeated runs: median, min, max.
    Bench(cmd::bench::Args),
    // About: `cmd::dataset::Args`'s doc comment.
    Dataset(cmd::dataset::Args),
    // About: `cmd::learn::Args`'s doc comment.
    Learn(cmd::learn::Args),
    /// Compare methods on a scene: per-pass times, memory, RMSE, FLIP, bad pixels, heat maps.
    Compare(cmd::compare::Args),
    /// List the built-in scenes, or print one as a scene file.
    Scenes(cmd::scenes::Args),
    /// List the fragment stores (`--method`).
    Methods(cmd::methods::Args),
    /// The TFSS evaluation of Lin 2007 on a scene: fragment distribution, memory of R-buffer, WF,
    /// TFSS and strata's layouts, access/time model.
    #[command(long_about = cmd::tfss_sim::LONG_ABOUT)]
    TfssSim(cmd::tfss_sim::Args),
    /// Encode a scene's DeepFrames with every wire codec: bytes, ratios against raw and the
    /// plain layout under LZ4, encode and decode times, bit-exact round trips.
    ///
    /// Renders frames spread over the scene's animation with the A-buffer, encodes each
    /// DeepFrame with every codec, decodes it again and checks the round trip is bit-exact.
    /// Sizes are compared with 16 bytes a fragment (a 12-byte fragment node padded to 16) and
    /// with the plain fragment layout under LZ4, the codec the original remote-rendering work
    /// used. Times are medians over frames and runs, wall-clock, on the CPU named in the
    /// output; MB/s are DeepFrame bytes (16 a fragment) per median time. Each message is
    /// decoded twice: by a fresh decoder ("decode"), and by one that keeps its buffers and
    /// gets each decoded frame back, as a consumer of a stream of frames does ("reused": no
    /// fresh memory for the kernel to zero).
    Codecs(cmd::codecs::Args),
    /// Serve a display as a render node: render some objects of a scene, stream the fragments.
    ///
    /// The node listens on ADDR and serves one display connection at a time, for as long as it
    /// runs (stop it with Ctrl-C). For each frame the display asks for, it poses the scene at that
    /// animation frame, renders its objects with the chosen fragment store at the display's camera
    /// and size, keeps the fragments the display's transfer method sends, encodes them with the
    /// display's codec and sends them. Several nodes can hold different objects of one scene; the
    /// display merges them per pixel. The first line on stdout is `listening on HOST:PORT`.
    ///
    /// For the depth-limited transfer, the node keeps only what it sends as it exports each frame:
    /// the abuffer (the default) and the k-buffer cut each pixel's sorted run as they gather it,
    /// so there is no selection pass. `--method kbuffer -k N` also keeps only the N nearest
    /// fragments while capturing; on the full dragon it was the slower of the two. The reprojection
    /// transfer renders normal fragments and needs a store that keeps every fragment: abuffer
    /// (with a growing pool) or sbuffer.
    ///
    /// To measure a display alone, record what a node sends one display run (`--record FILE`),
    /// then serve the recording from memory (`--replay FILE`, no scene or rendering): a display
    /// run with the same options gets the recorded bytes at once, so its rate is its own
    /// (transfer, decode, merge, resolve). Requests the recording does not hold are answered
    /// with an error that says so.
    Node(cmd::node::Args),
    /// Drive render nodes, merge their fragments per pixel, resolve, and measure it all.
    ///
    /// Asks every node (`strata node`) for each frame of the scene's animation, receives from
    /// all of them at once, merges their per-pixel runs, resolves, and prints a summary: bytes
    /// raw and encoded, node render / select / encode and display transfer / decode / merge /
    /// resolve times, fragments sent against rendered, display fps, and bad pixels against the
    /// exact local render of the whole scene (checked after the run, so the check does not slow
    /// the display). A node that fails is reported, composed without (or from its last frame,
    /// `--on-fault hold`) and reconnected when it returns. Rates, bytes and times are figures of
    /// the frames some node delivered.
    ///
    /// `--discard` measures the nodes alone: every frame is dropped as soon as it has arrived,
    /// undecoded, and the rate is the nodes' (render, select, encode, socket).
    ///
    /// Exit status: 0 every node delivered every frame; 1 no node delivered any frame (nothing
    /// listening, every node serving another scene, ...): nothing was displayed; 2 a usage or
    /// setup error (a bad option, a malformed node address, a scene that does not load), found
    /// before any connection is tried; 3 the run finished degraded: some node missed frames
    /// (lost, stalled, failed or left out), and the summary names it.
    Display(cmd::display::Args),
    // About: `cmd::composite::Args`'s doc comment.
    Composite(cmd::composite::Args),
    // About: `cmd::inspect::Args`'s doc comment.
    Inspect(cmd::inspect::Args),
    // About: `cmd::mfr::Args`'s doc comment.
    Mfr(cmd::mfr::Args),
    // About: `cmd::mfr_slow::Args`'s doc comment.
    MfrSlow(cmd::mfr_slow::Args),
    // About: `cmd::view::Args`'s doc comment.
    View(cmd::view::Args),
}

impl Command {
    /// The method options of this subcommand, if it has any.
    fn method_params(&mut self) -> Option<&mut options::MethodParams> {
        match self {
            Command::Render(a) => Some(&mut a.render.params),
            Command::Demo(a) => Some(&mut a.render.params),
            Command::Node(a) => Some(&mut a.render.params),
            Command::Bench(a) => Some(&mut a.params),
            Command::Compare(a) => Some(&mut a.params),
            _ => None,
        }
    }

    /// Refuses a method option the command line set that `node`'s method does not read, before
    /// it starts listening. (`render`, `demo`, `bench` and `compare` check their options
    /// themselves, with everything else, before they render or write anything.)
    fn check_method_options(&self) -> anyhow::Result<()> {
        match self {
            Command::Node(a) => a.render.checked_method_options().map(drop),
            _ => Ok(()),
        }
    }
}

/// Refuses a `STRATA_LANES` the rasteriser would not understand (it would ignore it and run at
/// the widest lanes, so a benchmark of the other width would measure the wrong thing).
fn check_lanes_variable() -> anyhow::Result<()> {
    use strata_raster::lanes::{LANES_VAR, requested_lanes};
    requested_lanes(std::env::var_os(LANES_VAR).as_deref())
        .map(drop)
        .map_err(anyhow::Error::msg)
}

/// Parses the command line, noting which method options it set (as opposed to their defaults).
fn parse() -> Result<Cli, clap::Error> {
    let matches = Cli::command().try_get_matches()?;
    let mut cli = Cli::from_arg_matches(&matches)?;
    if let (Some((_, sub)), Some(params)) = (matches.subcommand(), cli.command.method_params()) {
        params.given = options::given_method_options(sub);
    }
    Ok(cli)
}

fn main() -> ExitCode {
    let cli = match parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) {
                e.exit();
            }
            // clap renders "error: …" plus a usage hint; every strata error starts "strata: ".
            eprint!("strata: {}", e.render());
            return ExitCode::from(2);
        }
    };
    let result = check_lanes_variable()
        .and_then(|()| cli.command.check_method_options())
        .and_then(|()| match cli.command {
            Command::Render(a) => cmd::render::run(a),
            Command::Demo(a) => cmd::demo::run(a),
            Command::Bench(a) => cmd::bench::run(a),
            Command::Compare(a) => cmd::compare::run(a),
            Command::Dataset(a) => cmd::dataset::run(a),
            Command::Learn(a) => cmd::learn::run(a),
            Command::Scenes(a) => cmd::scenes::run(a),
            Command::Methods(a) => cmd::methods::run(a),
            Command::TfssSim(a) => cmd::tfss_sim::run(a),
            Command::Codecs(a) => cmd::codecs::run(a),
            Command::Node(a) => cmd::node::run(a),
            Command::Display(a) => cmd::display::run(a),
            Command::Composite(a) => cmd::composite::run(a),
            Command::Inspect(a) => cmd::inspect::run(a),
            Command::View(a) => cmd::view::run(a),
            Command::Mfr(a) => cmd::mfr::run(a),
            Command::MfrSlow(a) => cmd::mfr_slow::run(a),
        });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if out::is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            let status = e.downcast_ref::<Failed>().map_or(2, |f| f.status);
            let mut shown = e.to_string();
            eprintln!("strata: error: {shown}");
            // Print a cause only if the messages so far do not already say it (library errors
            // often include their source's text).
            for cause in e.chain().skip(1) {
                let text = cause.to_string();
                if !shown.contains(&text) {
                    eprintln!("  caused by: {text}");
                    shown.push_str(&text);
                }
            }
            ExitCode::from(status)
        }
    }
}
