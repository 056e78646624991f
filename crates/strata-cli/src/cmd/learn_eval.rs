//! `strata learn eval`: the learned variable k-buffer on scene families it was not trained on.
//!
//! # Plan
//!
//! ```text
//! for each held-out family F (its test scene is the scene of that name):
//!   train, without F's rows: curve (learned), fraction and seed × seeds, seed-literal × 1
//!   for each view v of --views (orbit around the scene's target, view 0 its own camera):
//!     reference = abuffer (exact)
//!     for each budget b: every method through the variable k-buffer (each allocator keeps
//!       Σk = min(M, N), so Σk is identical): importance, analytic, learned, fraction and
//!       seed (one per seed), seed-literal, optimal → RMSE, mean FLIP, bad pixels, Σk,
//!       importance-pass ms, memory
//!   stability: --orbit frames around the scene at --orbit-budget: mean |k_t − k_{t−1}| and
//!     mean FLIP(image_t, image_{t−1}) per method (the reference's own FLIP between frames is
//!     the motion every method shows; the excess over it is flicker)
//!   sheet: view 0 at --orbit-budget: image, FLIP map and k map of each method, side by side
//! ```
//!
//! Results: a table on stdout (means over views; for a method trained with several seeds, the
//! mean over seeds and their spread), `table.md`, `results.json` and `sheet-F.png` in --out.
//! "Gap closed" is `(importance − method) / (importance − optimal)` of the family-and-budget
//! mean; a cell where Optimal-K is within 2 % of importance maps is marked as having no headroom.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use strata_core::Rgb8Image;
use strata_core::metrics::{self, DEFAULT_BAD_PIXEL_THRESHOLD};
use strata_learn::dataset::{orbit_camera, parse_budget};
use strata_learn::train::{TrainingData, train};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::kbuffer::LearnedModel;
use strata_stores::kbuffer::maps::heat_map;
use strata_stores::{Budget, KFrom, MethodOptions, render_frame};

use crate::flip::{DEFAULT_PIXELS_PER_DEGREE, flip};
use crate::options::{open_scene, search_path, thread_pool};

/// Measure the learned k on families of scenes it was not trained on.
///
/// For each --families entry, networks are trained on the --data dataset without that family
/// (strata's error-curve network `learned`, the kept-fraction network `fraction` and the
/// thesis's 12-128-64-1 network `seed`, once per --seeds entry, and the thesis's recipe taken
/// literally, `seed-literal`, once), then the family's scene is rendered from --views cameras
/// at every --budgets share with each way of choosing k — importance maps, the analytic model,
/// the networks, and the Optimal-K oracle — all under the same budget, whose allocators all
/// keep exactly min(budget, fragments), so every method keeps the same number of fragments
/// (Σk is printed). Each image is compared with the
/// exact one: RMSE, mean FLIP, bad pixels. A --orbit of frames measures how k and the image
/// flicker from frame to frame. Writes table.md, results.json and one sheet-FAMILY.png of
/// images, FLIP maps and k maps into --out.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// The training dataset (written by `strata dataset`); it must hold each held-out family.
    #[arg(long, value_name = "DIR")]
    data: PathBuf,

    /// Families to hold out, one at a time; each is tested on the scene of that name.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "bunny,dragon,armadillo,engine"
    )]
    families: Vec<String>,

    /// Budgets, in percent of each frame's fragments, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "30,50,70,85")]
    budgets: Vec<String>,

    /// Views per scene, on a circle around its target.
    #[arg(long, default_value_t = 8)]
    views: u32,

    /// Training seeds of the learned networks, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    seeds: Vec<u64>,

    /// Render size (WIDTHxHEIGHT).
    #[arg(long, default_value = "640x360", value_parser = parse_size)]
    size: (u32, u32),

    /// Frames of the stability orbit (0 leaves it out).
    #[arg(long, default_value_t = 72)]
    orbit: u32,

    /// Budget of the stability orbit and of the sheets, in percent.
    #[arg(long, default_value = "70")]
    orbit_budget: String,

    /// Leave out the thesis's 12-128-64-1 networks (the slowest to train and run).
    #[arg(long)]
    no_seed_networks: bool,

    /// Hidden layer widths of the learned (curve) network, comma-separated (`none`: a linear
    /// correction of the analytic model).
    #[arg(long, default_value = "8", value_parser = super::learn::parse_hidden)]
    hidden: super::learn::Hidden,

    /// Inputs of the learned (curve) network, feature names comma-separated (default: the
    /// model's 20).
    #[arg(long, value_delimiter = ',', value_name = "FEATURES")]
    inputs: Vec<String>,

    /// Folder for table.md, results.json and the sheets.
    #[arg(long, default_value = "strata-learn-eval")]
    out: PathBuf,

    /// FLIP's pixels per degree.
    #[arg(long, default_value_t = DEFAULT_PIXELS_PER_DEGREE)]
    ppd: f32,

    /// Worker threads (default: every available core). Results do not depend on it.
    #[arg(long, short = 'j')]
    threads: Option<usize>,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    model_dirs: Vec<PathBuf>,
}

/// `WIDTHxHEIGHT`, each from 16 to 8192.
fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("{s}: expected WIDTHxHEIGHT, each from 16 to 8192, such as 640x360");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let dim = |d: &str| {
        d.trim()
            .parse::<u32>()
            .ok()
            .filter(|v| (16..=8192).contains(v))
    };
    Ok((dim(w).ok_or_else(bad)?, dim(h).ok_or_else(bad)?))
}

/// One way of choosing k.
#[derive(Clone)]
struct Entry {
    /// Column name (`learned`, `seed`, …); entries of one name but several seeds are averaged.
    name: &'static str,
    k_from: KFrom,
    model: Option<Arc<LearnedModel>>,
}

/// Metrics of one render.
#[derive(Clone, Copy, Debug, Default)]
struct Metrics {
    rmse: f64,
    flip: f64,
    bad: f64,
    sum_k: u64,
    importance_ms: f64,
    memory_mib: f64,
}

/// The methods in column order.
const COLUMNS: [&str; 7] = [
    "importance",
    "analytic",
    "learned",
    "fraction",
    "seed",
    "seed-literal",
    "optimal",
];

pub(crate) fn run(a: Args) -> Result<()> {
    anyhow::ensure!(a.views > 0, "--views must be at least 1");
    anyhow::ensure!(!a.seeds.is_empty(), "--seeds names no seed");
    let budgets = a
        .budgets
        .iter()
        .map(|b| parse_budget(b).with_context(|| "--budgets".to_owned()))
        .collect::<Result<Vec<_>>>()?;
    let orbit_budget = parse_budget(&a.orbit_budget).context("--orbit-budget")?;
    let pool = thread_pool(a.threads)?;
    let threads = pool.current_num_threads();
    let data = TrainingData::load(&a.data)?;
    let search = search_path(&a.model_dirs);
    let mut scenes = Vec::new();
    for f in &a.families {
        anyhow::ensure!(
            data.families.iter().any(|g| g == f),
            "--families {f}: the dataset {} has no such family; its families are {}",
            a.data.display(),
            {
                let mut u = data.families.clone();
                u.sort();
                u.dedup();
                u.join(", ")
            }
        );
        let mut scene = open_scene(f, &search)
            .with_context(|| format!("--families {f}: its test scene is the scene `{f}`"))?;
        (scene.width, scene.height) = a.size;
        scenes.push(scene);
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let cpu = crate::report::cpu_model();
    let mut results = Vec::new();
    let mut table = String::new();
    for (family, scene) in a.families.iter().zip(&scenes) {
        let entries = pool.install(|| train_entries(&a, &data, family))?;
        let cells = pool.install(|| measure(&a, scene, &entries, &budgets))?;
        let stability = if a.orbit > 0 {
            pool.install(|| stability(&a, scene, &entries, orbit_budget))?
        } else {
            Vec::new()
        };
        pool.install(|| sheet(&a, scene, family, &entries, orbit_budget))?;
        let names: Vec<&'static str> = entries.iter().map(|e| e.name).collect();
        let text = format_family(family, &names, &budgets, &cells, &stability);
        print!("{text}");
        table.push_str(&text);
        results.push(family_json(family, &names, &budgets, &cells, &stability));
    }
    let header = format!(
        "strata learn eval: {} views at {}x{}, training seeds {:?}, {threads} thread(s) on {cpu}; means over views (± half the spread over seeds)\n\n",
        a.views, a.size.0, a.size.1, a.seeds
    );
    std::fs::write(a.out.join("table.md"), header.clone() + &table)?;
    let json = serde_json::json!({
        "views": a.views, "size": [a.size.0, a.size.1], "seeds": a.seeds, "threads": threads,
        "cpu": cpu, "budgets": budgets, "families": results,
    });
    std::fs::write(
        a.out.join("results.json"),
        serde_json::to_string_pretty(&json)? + "\n",
    )?;
    eprintln!("{header}wrote {}", a.out.join("table.md").display());
    Ok(())
}

/// Trains every network of one held-out family.
fn train_entries(a: &Args, data: &TrainingData, family: &str) -> Result<Vec<Entry>> {
    let mut entries = vec![
        Entry {
            name: "importance",
            k_from: KFrom::Importance,
            model: None,
        },
        Entry {
            name: "analytic",
            k_from: KFrom::Analytic,
            model: None,
        },
    ];
    let mut jobs: Vec<(&'static str, &'static str, u64)> =
        a.seeds.iter().map(|&s| ("learned", "curve", s)).collect();
    jobs.extend(a.seeds.iter().map(|&s| ("fraction", "fraction", s)));
    if !a.no_seed_networks {
        jobs.extend(a.seeds.iter().map(|&s| ("seed", "seed", s)));
        jobs.push(("seed-literal", "seed-literal", a.seeds[0]));
    }
    for (name, preset, seed) in jobs {
        let (mut spec, mut config) = super::learn::preset(preset, seed)?;
        if name == "learned" {
            spec.hidden = a.hidden.0.clone();
            if !a.inputs.is_empty() {
                let names: Vec<&str> = a.inputs.iter().map(String::as_str).collect();
                spec = spec.with_inputs(&names)?;
            }
        }
        config.exclude_families = vec![family.to_owned()];
        if preset == "seed" {
            config.max_rows = Some(100_000);
        }
        let start = std::time::Instant::now();
        let (model, report) = train(data, &spec, &config, |_| {})?;
        eprintln!(
            "{family} held out: trained {name} (seed {seed}) on {} rows in {:.1} s, validation loss {:.5}",
            report.train_rows,
            start.elapsed().as_secs_f64(),
            report.epochs[report.best_epoch - 1].validation_loss
        );
        entries.push(Entry {
            name,
            k_from: KFrom::Learned,
            model: Some(Arc::new(model)),
        });
    }
    entries.push(Entry {
        name: "optimal",
        k_from: KFrom::Optimal,
        model: None,
    });
    Ok(entries)
}

fn options(entry: &Entry, budget: f64) -> MethodOptions {
    MethodOptions {
        budget: Budget::SceneShare(budget),
        k_from: entry.k_from,
        weights: entry.model.clone(),
        ..MethodOptions::default()
    }
}

/// The frame input of view `view` of `views`.
fn view_input(scene: &Scene, view: u32, views: u32) -> FrameInput<'_> {
    let camera = orbit_camera(&scene.camera, view, views);
    let mut input = FrameInput::from_scene(scene, 0);
    input.view = camera.view();
    input.projection = camera.projection(scene.width, scene.height);
    input
}

/// Renders `entry` at `budget`: the image, its metrics against `reference` and its k map.
fn render(
    a: &Args,
    raster: &mut Rasterizer,
    input: &FrameInput<'_>,
    background: [f32; 3],
    entry: &Entry,
    budget: f64,
    reference: &Rgb8Image,
) -> Result<(Rgb8Image, Metrics, Vec<f32>, Rgb8Image)> {
    let mut method = strata_stores::create("vkbuffer", &options(entry, budget))?;
    let r = render_frame(method.as_mut(), raster, input, background)?;
    let pass = if entry.k_from == KFrom::Optimal {
        "capture.k"
    } else {
        "capture.importance"
    };
    let importance_ms = r
        .timings
        .iter()
        .find(|(n, _)| *n == pass)
        .map_or(0.0, |(_, d)| d.as_secs_f64() * 1e3);
    let f = flip(reference, &r.image, a.ppd)?;
    let m = Metrics {
        rmse: metrics::rmse(reference, &r.image)?,
        flip: f.mean,
        bad: metrics::bad_pixels(reference, &r.image, DEFAULT_BAD_PIXEL_THRESHOLD)?.share(),
        sum_k: r.capture.fragments_stored,
        importance_ms,
        memory_mib: r.memory_bytes as f64 / (1 << 20) as f64,
    };
    let k = method
        .pixel_maps()
        .into_iter()
        .find(|m| m.name == "k")
        .map(|m| m.values)
        .unwrap_or_default();
    Ok((r.image, m, k, f.heatmap))
}

fn reference(raster: &mut Rasterizer, input: &FrameInput<'_>, scene: &Scene) -> Result<Rgb8Image> {
    let mut exact = strata_stores::create("abuffer", &MethodOptions::default())?;
    Ok(render_frame(exact.as_mut(), raster, input, scene.background)?.image)
}

/// `cells[budget][entry]`: the metrics of every view.
type Cells = Vec<Vec<Vec<Metrics>>>;

fn measure(a: &Args, scene: &Scene, entries: &[Entry], budgets: &[f64]) -> Result<Cells> {
    let mut raster = Rasterizer::default();
    let mut cells: Cells = vec![vec![Vec::new(); entries.len()]; budgets.len()];
    for view in 0..a.views {
        let input = view_input(scene, view, a.views);
        let exact = reference(&mut raster, &input, scene)?;
        for (bi, &b) in budgets.iter().enumerate() {
            for (ei, e) in entries.iter().enumerate() {
                let (_, m, _, _) = render(a, &mut raster, &input, scene.background, e, b, &exact)?;
                cells[bi][ei].push(m);
            }
        }
        eprintln!("{}: view {} of {} measured", scene.name, view + 1, a.views);
    }
    Ok(cells)
}

/// Per entry: mean |k_t − k_{t−1}| over pixels, mean FLIP between frames; plus the reference's.
struct Stability {
    name: &'static str,
    k_change: f64,
    flip_between: f64,
}

fn stability(a: &Args, scene: &Scene, entries: &[Entry], budget: f64) -> Result<Vec<Stability>> {
    let mut raster = Rasterizer::default();
    // One entry per column name (the first seed).
    let mut chosen: Vec<&Entry> = Vec::new();
    for e in entries {
        if !chosen.iter().any(|c| c.name == e.name) {
            chosen.push(e);
        }
    }
    let mut prev: Vec<Option<(Rgb8Image, Vec<f32>)>> = vec![None; chosen.len() + 1];
    let mut sums = vec![(0.0f64, 0.0f64); chosen.len() + 1];
    for t in 0..a.orbit {
        let input = view_input(scene, t, a.orbit);
        let exact = reference(&mut raster, &input, scene)?;
        let mut now = Vec::new();
        for e in &chosen {
            let (img, _, k, _) =
                render(a, &mut raster, &input, scene.background, e, budget, &exact)?;
            now.push((img, k));
        }
        now.push((exact, Vec::new()));
        for (i, (img, k)) in now.into_iter().enumerate() {
            if let Some((pimg, pk)) = &prev[i] {
                let dk = if k.is_empty() {
                    0.0
                } else {
                    k.iter()
                        .zip(pk)
                        .map(|(a, b)| f64::from((a - b).abs()))
                        .sum::<f64>()
                        / k.len() as f64
                };
                sums[i].0 += dk;
                sums[i].1 += flip(pimg, &img, a.ppd)?.mean;
            }
            prev[i] = Some((img, k));
        }
        if (t + 1) % 12 == 0 {
            eprintln!("{}: orbit frame {} of {}", scene.name, t + 1, a.orbit);
        }
    }
    let n = f64::from(a.orbit.saturating_sub(1).max(1));
    Ok(chosen
        .iter()
        .map(|e| e.name)
        .chain(["exact"])
        .zip(sums)
        .map(|(name, (k, f))| Stability {
            name,
            k_change: k / n,
            flip_between: f / n,
        })
        .collect())
}

/// View 0 at `budget`: for each method (first seed), a column of image, FLIP map and k map.
fn sheet(a: &Args, scene: &Scene, family: &str, entries: &[Entry], budget: f64) -> Result<()> {
    let mut raster = Rasterizer::default();
    let input = view_input(scene, 0, 1);
    let exact = reference(&mut raster, &input, scene)?;
    let (w, h) = (scene.width, scene.height);
    let mut columns: Vec<[Rgb8Image; 3]> = vec![[
        exact.clone(),
        Rgb8Image::filled(w, h, [0; 3]),
        Rgb8Image::filled(w, h, [0; 3]),
    ]];
    let mut seen = Vec::new();
    let mut k_maps: Vec<Vec<f32>> = Vec::new();
    for e in entries {
        if seen.contains(&e.name) {
            continue;
        }
        seen.push(e.name);
        let (img, _, k, heat) =
            render(a, &mut raster, &input, scene.background, e, budget, &exact)?;
        columns.push([img, heat, Rgb8Image::filled(w, h, [0; 3])]);
        k_maps.push(k);
    }
    // One scale for every k map: 0 to the largest k of any method.
    let top = k_maps.iter().flatten().copied().fold(0.0f32, f32::max);
    for (column, k) in columns.iter_mut().skip(1).zip(&k_maps) {
        column[2] = heat_map(k, w, h, Some(top.max(1.0)));
    }
    let gap = 4;
    let cols = columns.len() as u32;
    let mut out = Rgb8Image::filled(cols * (w + gap) - gap, 3 * (h + gap) - gap, [255; 3]);
    for (c, column) in columns.iter().enumerate() {
        for (r, img) in column.iter().enumerate() {
            let (x0, y0) = (c as u32 * (w + gap), r as u32 * (h + gap));
            for y in 0..h {
                for x in 0..w {
                    let p = img.pixel(x, y);
                    let i = 3 * ((y0 + y) as usize * out.width() as usize + (x0 + x) as usize);
                    out.as_bytes_mut()[i..i + 3].copy_from_slice(&p);
                }
            }
        }
    }
    let path = a.out.join(format!("sheet-{family}.png"));
    out.write_png(&path)?;
    eprintln!(
        "wrote {} (columns: exact, {}; rows: image, FLIP map, k map on one scale)",
        path.display(),
        seen.join(", ")
    );
    Ok(())
}

/// Mean over views of one entry's metric, then over the entries of one column name: the mean
/// and half the spread of the per-seed means.
fn column_stat(
    entries_cells: &[Vec<Metrics>],
    names: &[&'static str],
    name: &str,
    metric: impl Fn(&Metrics) -> f64,
) -> Option<(f64, f64)> {
    let means: Vec<f64> = entries_cells
        .iter()
        .zip(names)
        .filter(|(_, n)| **n == name)
        .map(|(views, _)| views.iter().map(&metric).sum::<f64>() / views.len().max(1) as f64)
        .collect();
    if means.is_empty() {
        return None;
    }
    let mean = means.iter().sum::<f64>() / means.len() as f64;
    let lo = means.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = means.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    Some((mean, (hi - lo) / 2.0))
}

fn format_family(
    family: &str,
    names: &[&'static str],
    budgets: &[f64],
    cells: &Cells,
    stability: &[Stability],
) -> String {
    let mut s = format!("## {family} (held out of training)\n\n");
    s.push_str("| budget | Σk | metric |");
    let shown: Vec<&str> = COLUMNS
        .iter()
        .copied()
        .filter(|c| names.contains(c))
        .collect();
    for c in &shown {
        s.push_str(&format!(" {c} |"));
    }
    s.push_str(" gap closed: analytic / learned |\n|");
    s.push_str(&"---|".repeat(shown.len() + 4));
    s.push('\n');
    for (bi, &b) in budgets.iter().enumerate() {
        let sum_k = cells[bi][0].iter().map(|m| m.sum_k).sum::<u64>();
        let same = cells[bi]
            .iter()
            .all(|views| views.iter().map(|m| m.sum_k).sum::<u64>() == sum_k);
        type Metric = fn(&Metrics) -> f64;
        let metrics: [(&str, Metric, usize); 5] = [
            ("RMSE", |m| m.rmse, 4),
            ("mean FLIP", |m| m.flip, 4),
            ("bad px %", |m| 100.0 * m.bad, 1),
            ("k pass ms", |m| m.importance_ms, 2),
            ("memory MiB", |m| m.memory_mib, 1),
        ];
        for (mi, (label, metric, digits)) in metrics.iter().enumerate() {
            let first = if mi == 0 {
                format!(
                    "| {:.0} % | {}{} |",
                    100.0 * b,
                    sum_k / cells[bi][0].len().max(1) as u64,
                    if same { "" } else { " (differs!)" }
                )
            } else {
                "| | |".to_owned()
            };
            s.push_str(&first);
            s.push_str(&format!(" {label} |"));
            let stat = |c: &str| column_stat(&cells[bi], names, c, metric);
            for c in &shown {
                match stat(c) {
                    Some((m, spread)) if spread > 0.0 => {
                        s.push_str(&format!(" {m:.digits$} ± {spread:.digits$} |"))
                    }
                    Some((m, _)) => s.push_str(&format!(" {m:.digits$} |")),
                    None => s.push_str(" |"),
                }
            }
            if mi < 2 {
                let imp = stat("importance").map_or(0.0, |v| v.0);
                let opt = stat("optimal").map_or(0.0, |v| v.0);
                let gap = imp - opt;
                if gap <= 0.02 * imp.abs().max(1e-9) {
                    s.push_str(" no headroom |\n");
                } else {
                    let closed = |c: &str| stat(c).map_or(0.0, |v| 100.0 * (imp - v.0) / gap);
                    s.push_str(&format!(
                        " {:.0} % / {:.0} % |\n",
                        closed("analytic"),
                        closed("learned")
                    ));
                }
            } else {
                s.push_str(" |\n");
            }
        }
    }
    if !stability.is_empty() {
        s.push_str("\nStability over the orbit (first seed): mean |k_t − k_{t−1}| a pixel, mean FLIP between consecutive frames\n\n| method | mean abs k change | FLIP between frames |\n|---|---|---|\n");
        for st in stability {
            s.push_str(&format!(
                "| {} | {:.4} | {:.4} |\n",
                st.name, st.k_change, st.flip_between
            ));
        }
    }
    s.push('\n');
    s
}

fn family_json(
    family: &str,
    names: &[&'static str],
    budgets: &[f64],
    cells: &Cells,
    stability: &[Stability],
) -> serde_json::Value {
    let per_budget: Vec<_> = budgets
        .iter()
        .enumerate()
        .map(|(bi, &b)| {
            let methods: serde_json::Map<String, serde_json::Value> = COLUMNS
                .iter()
                .filter(|c| names.contains(c))
                .map(|&c| {
                    let st = |f: fn(&Metrics) -> f64| column_stat(&cells[bi], names, c, f);
                    (
                        c.to_owned(),
                        serde_json::json!({
                            "rmse": st(|m| m.rmse).map(|v| v.0),
                            "mean_flip": st(|m| m.flip).map(|v| v.0),
                            "bad_pixel_share": st(|m| m.bad).map(|v| v.0),
                            "k_pass_ms": st(|m| m.importance_ms).map(|v| v.0),
                            "memory_mib": st(|m| m.memory_mib).map(|v| v.0),
                            "sum_k_view0": cells[bi][names.iter().position(|n| *n == c).unwrap_or(0)][0].sum_k,
                        }),
                    )
                })
                .collect();
            serde_json::json!({"budget": b, "methods": methods})
        })
        .collect();
    let stab: Vec<_> = stability
        .iter()
        .map(|s| serde_json::json!({"method": s.name, "k_change": s.k_change, "flip_between": s.flip_between}))
        .collect();
    serde_json::json!({"family": family, "budgets": per_budget, "stability": stab})
}
