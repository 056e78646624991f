//! `strata methods`: the fragment stores, what each is, how faithful it is and which options it
//! reads.

use anyhow::Result;
use strata_stores::{Fidelity, MethodInfo, MethodOptions, PoolCapacity};

/// List the fragment stores `--method` accepts, with how faithful each image is and the method
/// options each one reads (giving a method an option it does not read is an error).
#[derive(clap::Args, Debug)]
pub(crate) struct Args {}

/// The first word of a fidelity's description: exact, bounded or approximate.
fn fidelity_word(f: Fidelity) -> &'static str {
    match f {
        Fidelity::Exact => "exact",
        Fidelity::Bounded => "bounded",
        Fidelity::Approximate => "approximate",
    }
}

/// How faithful `m` is by default, and which option settings make it less so.
fn fidelity_line(m: &MethodInfo) -> String {
    let default = m.fidelity(&MethodOptions::default());
    let fixed_pool = MethodOptions {
        pool: PoolCapacity::PerPixel(4.0),
        ..MethodOptions::default()
    };
    let layer_limit = MethodOptions {
        max_layers: 1,
        ..MethodOptions::default()
    };
    let mut line = default.describe().to_owned();
    for (options, setting) in [
        (fixed_pool, "a fixed --pool"),
        (layer_limit, "--max-layers above 0"),
    ] {
        let f = m.fidelity(&options);
        if f != default {
            line.push_str(&format!("; {} with {setting}", fidelity_word(f)));
        }
    }
    line
}

/// Runs `strata methods`.
pub(crate) fn run(_args: Args) -> Result<()> {
    for m in strata_stores::METHODS {
        outln!("{:<20} {}", m.name, m.summary)?;
        let options: Vec<String> = m.options.iter().map(|o| format!("--{o}")).collect();
        let options = if options.is_empty() {
            "none".to_owned()
        } else {
            options.join(" ")
        };
        outln!("{:<20} {}; options: {options}", "", fidelity_line(m))?;
    }
    Ok(())
}
