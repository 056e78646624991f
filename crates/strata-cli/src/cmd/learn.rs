//! `strata learn`: train, describe and evaluate the learned variable k-buffer's network.

use std::path::PathBuf;

use anyhow::{Context, Result};
use strata_learn::train::{ModelSpec, PRESETS, TrainConfig, TrainingData};
use strata_stores::kbuffer::LearnedModel;
use strata_stores::kbuffer::features::FEATURES;

use crate::options::thread_pool;

/// Train, describe and evaluate the network behind `--k-from learned`.
///
/// The learned variable k-buffer predicts, for every pixel with two or more fragments, how much
/// its colour would change if only its k nearest fragments were kept (a correction of the
/// analytic model's error curve), from features the counting pass gathers; the budget is then
/// shared out to the fragments worth most. `strata dataset` writes the training data,
/// `strata learn train` fits a network to it, `strata learn eval` measures it against
/// importance maps, the analytic model and the Optimal-K oracle on families of scenes it was
/// not trained on.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    #[command(subcommand)]
    command: Sub,
}

#[derive(clap::Subcommand, Debug)]
enum Sub {
    Train(TrainArgs),
    Info(InfoArgs),
    Eval(super::learn_eval::Args),
}

/// Fit a network to a dataset from `strata dataset` and write its weights.
///
/// Trains on the rows with two or more fragments (the pixels with a choice to make), leaving
/// out the --exclude families, and keeps the weights of the epoch with the lowest loss on a
/// validation tenth of the frames. The run is reproducible from --seed, on any number of
/// threads. The weights file (safetensors) records the feature list, the normalisation, this
/// command, the dataset's hash and the families trained on; use it with
/// `strata render --method vkbuffer --k-from learned --weights FILE`.
#[derive(clap::Args, Debug)]
struct TrainArgs {
    /// The dataset folder (written by `strata dataset`).
    #[arg(long, value_name = "DIR")]
    data: PathBuf,

    /// Where to write the weights (.safetensors).
    #[arg(long, short, value_name = "FILE")]
    out: PathBuf,

    /// The network: `curve` (strata's: 20 features, 8 ReLU, correcting the analytic model's
    /// per-pixel error curve, whose worths are water-filled to the budget), `fraction` (22
    /// features with the budget, 16-8 ReLU, predicting the kept fraction (k − 1)/(count − 1)),
    /// `seed` (the thesis's 12
    /// features and 12-128-64-1 network, on the kept fraction) or `seed-literal` (that network,
    /// trained as the thesis writes it: its label k/N, SGD 0.001, MSE, L1/L2).
    #[arg(long, default_value = "curve", value_parser = clap::builder::PossibleValuesParser::new(PRESETS))]
    model: String,

    /// Families to leave out of training, comma-separated (bunny, dragon, procedural, ...).
    #[arg(long, value_delimiter = ',', value_name = "FAMILIES")]
    exclude: Vec<String>,

    /// Seed of the initial weights, sampling, split and shuffles.
    #[arg(long, default_value_t = 1)]
    seed: u64,

    /// Passes over the data (default: 12, or 4 for seed-literal).
    #[arg(long)]
    epochs: Option<usize>,

    /// Rows to train on at most, a seeded sample (default: 400000, or 100000 for seed-literal).
    #[arg(long)]
    max_rows: Option<usize>,

    /// Input features, names comma-separated (`strata render --maps` lists them in
    /// features.json); default: the model's.
    #[arg(long, value_delimiter = ',', value_name = "FEATURES")]
    inputs: Vec<String>,

    /// Hidden layer widths, comma-separated (`none`: no hidden layer); default: the model's.
    #[arg(long, value_parser = parse_hidden)]
    hidden: Option<Hidden>,

    /// Worker threads (default: every available core). The weights do not depend on it.
    #[arg(long, short = 'j')]
    threads: Option<usize>,
}

/// Hidden layer widths.
#[derive(Clone, Debug)]
pub(crate) struct Hidden(pub(crate) Vec<usize>);

/// `16,8`, or `none` for no hidden layer; each width from 1 to 512, at most 5 layers.
pub(crate) fn parse_hidden(s: &str) -> Result<Hidden, String> {
    if s.trim() == "none" {
        return Ok(Hidden(Vec::new()));
    }
    let widths = s
        .split(',')
        .map(|w| {
            w.trim()
                .parse::<usize>()
                .ok()
                .filter(|w| (1..=512).contains(w))
        })
        .collect::<Option<Vec<_>>>()
        .filter(|v| v.len() <= 5)
        .ok_or_else(|| {
            format!("{s}: expected widths from 1 to 512, comma-separated (at most 5), or none")
        })?;
    Ok(Hidden(widths))
}

/// Describe a weights file (default: the built-in weights).
#[derive(clap::Args, Debug)]
struct InfoArgs {
    /// The weights file.
    weights: Option<PathBuf>,
}

pub(crate) fn run(args: Args) -> Result<()> {
    match args.command {
        Sub::Train(a) => train(a),
        Sub::Info(a) => info(a),
        Sub::Eval(a) => super::learn_eval::run(a),
    }
}

/// The model and recipe of a preset.
pub(crate) fn preset(name: &str, seed: u64) -> Result<(ModelSpec, TrainConfig)> {
    let spec = ModelSpec::preset(name)
        .with_context(|| format!("unknown model `{name}` (known: {})", PRESETS.join(", ")))?;
    let config = if name == "seed-literal" {
        TrainConfig::seed_literal(seed)
    } else {
        TrainConfig::strata(seed)
    };
    Ok((spec, config))
}

fn train(a: TrainArgs) -> Result<()> {
    let pool = thread_pool(a.threads)?;
    let data = TrainingData::load(&a.data)?;
    let (mut spec, mut config) = preset(&a.model, a.seed)?;
    if let Some(h) = &a.hidden {
        spec.hidden = h.0.clone();
    }
    if !a.inputs.is_empty() {
        let names: Vec<&str> = a.inputs.iter().map(String::as_str).collect();
        spec = spec.with_inputs(&names)?;
    }
    if let Some(e) = a.epochs {
        anyhow::ensure!(e > 0, "--epochs must be at least 1");
        config.epochs = e;
    }
    if let Some(m) = a.max_rows {
        anyhow::ensure!(m > 0, "--max-rows must be at least 1");
        config.max_rows = Some(m);
    }
    for f in &a.exclude {
        anyhow::ensure!(
            data.families.iter().any(|g| g == f),
            "--exclude {f}: no such family in {} (it has {})",
            a.data.display(),
            unique(&data.families).join(", ")
        );
    }
    config.exclude_families = a.exclude.clone();
    let start = std::time::Instant::now();
    let (mut model, report) = pool.install(|| {
        strata_learn::train::train(&data, &spec, &config, |e| {
            eprintln!(
                "epoch {:>3}: train loss {:.5}, validation loss {:.5}",
                e.epoch, e.train_loss, e.validation_loss
            );
        })
    })?;
    let command: Vec<String> = std::env::args().collect();
    strata_learn::train::describe(&mut model, &data, &config, &report, &command.join(" "));
    let bytes = model.to_safetensors();
    std::fs::write(&a.out, &bytes).with_context(|| format!("cannot write {}", a.out.display()))?;
    println!(
        "trained {} on {} rows ({} validation) in {:.1} s; kept epoch {} of {}; wrote {} ({} bytes, {} parameters, {} multiply-adds a pixel)",
        a.model,
        report.train_rows,
        report.validation_rows,
        start.elapsed().as_secs_f64(),
        report.best_epoch,
        config.epochs,
        a.out.display(),
        bytes.len(),
        model.parameters(),
        model.macs()
    );
    Ok(())
}

fn unique(v: &[String]) -> Vec<String> {
    let mut u = v.to_vec();
    u.sort();
    u.dedup();
    u
}

fn info(a: InfoArgs) -> Result<()> {
    let model = match &a.weights {
        Some(path) => LearnedModel::read(path)?,
        None => (*LearnedModel::builtin()).clone(),
    };
    let source = a
        .weights
        .as_ref()
        .map_or("built-in weights".to_owned(), |p| p.display().to_string());
    println!("{source}");
    let widths: Vec<String> = std::iter::once(model.inputs.len())
        .chain(model.layers.iter().map(|l| l.outputs))
        .map(|w| w.to_string())
        .collect();
    println!(
        "  network: {} ({} hidden, {} output), {} parameters, {} multiply-adds a pixel",
        widths.join("-"),
        model.activation.name(),
        if model.target.sigmoid() {
            "sigmoid"
        } else {
            "linear"
        },
        model.parameters(),
        model.macs()
    );
    println!("  predicts: {}", model.target.name());
    println!("  inputs:");
    for i in &model.inputs {
        println!(
            "    {:<20} {:<8} mean {:>10.4} scale {:>10.4}",
            FEATURES[i.feature].name,
            i.transform.name(),
            i.mean,
            i.scale
        );
    }
    for (k, v) in &model.info {
        println!("  {k}: {v}");
    }
    Ok(())
}
