//! `strata compare`: every method on one scene, timed and measured against a reference.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use strata_core::metrics::{self, BadPixels};
use strata_core::stats::median;
use strata_raster::{FrameInput, Rasterizer};
use strata_stores::{Fidelity, FrameResult, MethodOptions, render_frame};

use crate::flip;
use crate::options::{MethodParams, open_scene, search_path, thread_pool};
use crate::report::{colour_bar_html, html_escape, ms};

/// Render a scene with several methods and compare them with a reference: per-pass times, memory, fragments kept and lost, RMSE, mean FLIP and
/// bad pixels, side by side with FLIP heat maps.
///
/// A method may carry its own options after colons, overriding the method options given on the
/// command line: `kbuffer:k=8`, `vkbuffer:budget=25%:k-from=optimal`, `kbuffer:k=2:tail-blend`.
/// The values are checked as on the command line, and an option the method does not read is an
/// error; a method option given on the command line applies to every method that reads it, and
/// must be read by at least one of them.
/// Writes OUT_DIR/report.json, report.md, report.html, one PNG per method and one FLIP heat map
/// per method (`<name>-flip.png`), and prints the table.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name.
    pub(crate) scene: String,

    /// Methods to compare, comma-separated, each optionally with `:key=value` options.
    #[arg(long, value_delimiter = ',', required = true)]
    pub(crate) methods: Vec<String>,

    /// The method whose image the others are measured against: an exact one (abuffer, sbuffer,
    /// wf, tfss, depth-peeling, dual-depth-peeling; not with a fixed --pool or --max-layers).
    #[arg(long, default_value = "abuffer")]
    pub(crate) reference: String,

    /// Folder to write the report, images and heat maps into.
    #[arg(long, default_value = "strata-compare")]
    pub(crate) out_dir: PathBuf,

    /// Timed runs per method (the table shows medians).
    #[arg(long, default_value_t = 5)]
    pub(crate) runs: usize,

    /// Untimed runs first.
    #[arg(long, default_value_t = 1)]
    pub(crate) warmup: usize,

    /// Animation frame to pose the scene at.
    #[arg(long, default_value_t = 0)]
    pub(crate) frame: u32,

    /// Worker threads (default: every available core).
    #[arg(long, short = 'j')]
    pub(crate) threads: Option<usize>,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,

    /// FLIP's pixels per degree (viewing distance and screen density), a positive number.
    #[arg(long, default_value_t = flip::DEFAULT_PIXELS_PER_DEGREE, value_parser = parse_ppd)]
    pub(crate) ppd: f32,

    /// A pixel is bad if some channel differs from the reference by more than this many 8-bit
    /// steps.
    #[arg(long, default_value_t = metrics::DEFAULT_BAD_PIXEL_THRESHOLD)]
    pub(crate) threshold: u8,

    #[command(flatten)]
    pub(crate) params: MethodParams,
}

/// One entry of `--methods`: the method, its options and how the report names it.
struct Spec {
    label: String,
    method: String,
    options: MethodOptions,
    fidelity: Fidelity,
    file: String,
}

/// `--ppd`: a positive, finite number.
fn parse_ppd(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err("expected a positive number of pixels per degree, such as 67".to_owned()),
    }
}

/// `name[:key=value[:key]…]` on top of the command line's options; every option it sets must be
/// one the method reads.
fn parse_spec(spec: &str, base: &MethodOptions) -> Result<Spec> {
    let (method, settings) = crate::options::split_spec(spec);
    let method = method.to_owned();
    if method.is_empty() {
        bail!("'{spec}': a method spec starts with the method's name (strata methods lists them)");
    }
    let info = strata_stores::find(&method)?;
    let options = crate::options::configure(&method, base, settings)
        .map_err(|e| anyhow::anyhow!("'{spec}': {e}"))?;
    let file: String = spec
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    Ok(Spec {
        label: spec.trim().to_owned(),
        fidelity: info.fidelity(&options),
        method,
        options,
        file,
    })
}

/// Refuses a method option the command line set that none of the compared methods (the
/// reference included) reads under its own options.
fn check_given_options(args: &Args, specs: &[Spec], base: &MethodOptions) -> Result<()> {
    for &option in &args.params.given {
        let read = |method: &str, options: &MethodOptions| {
            strata_stores::check_option(method, option, option, options).is_ok()
        };
        if read(&args.reference, base) || specs.iter().any(|s| read(&s.method, &s.options)) {
            continue;
        }
        let compared: Vec<&str> = specs.iter().map(|s| s.method.as_str()).collect();
        bail!(
            "--{option} is not an option of any method compared ({}, and the reference {}); the methods that take it: {}",
            compared.join(", "),
            args.reference,
            strata_stores::methods_taking(option).join(", ")
        );
    }
    Ok(())
}

/// Refuses a reference that is not exact under the command line's options, naming the exact ones.
fn check_reference(args: &Args, base: &MethodOptions) -> Result<()> {
    let info = strata_stores::find(&args.reference)?;
    let fidelity = info.fidelity(base);
    if fidelity != Fidelity::Exact {
        // Exact by default: the command line's options made it bounded (a fixed --pool, say).
        let hint = if info.fidelity(&MethodOptions::default()) == Fidelity::Exact {
            " (method options on the command line apply to the reference too; give them to a \
             compared method in its spec instead, such as abuffer:pool=4x)"
                .to_owned()
        } else {
            String::new()
        };
        bail!(
            "--reference {}: the reference must be an exact method, and {} is {}; exact methods: {}{hint}",
            info.name,
            info.name,
            fidelity.describe(),
            strata_stores::exact_methods(base).join(", ")
        );
    }
    Ok(())
}

/// What one method measured.
struct Measured {
    spec_index: usize,
    passes: Vec<(&'static str, f64)>,
    total_ms: f64,
    last: FrameResult,
    rmse: f64,
    flip: f64,
    bad: BadPixels,
}

/// Runs `strata compare`.
pub(crate) fn run(args: Args) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let base = args.params.method_options();
    let specs: Vec<Spec> = args
        .methods
        .iter()
        .filter(|m| !m.trim().is_empty())
        .map(|m| parse_spec(m, &base))
        .collect::<Result<_>>()?;
    if specs.is_empty() {
        bail!("--methods names no method");
    }
    let mut seen = std::collections::HashSet::new();
    for s in &specs {
        if !seen.insert(s.file.clone()) {
            bail!("'{}' is listed twice", s.label);
        }
    }
    check_reference(&args, &base)?;
    check_given_options(&args, &specs, &base)?;
    let scene = open_scene(&args.scene, &search_path(&args.model_dirs))?;
    scene.check_frame(args.frame)?;
    let input = FrameInput::from_scene(&scene, args.frame);
    let pool = thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    // Everything is checked; create the output folder before the (long) measuring, so a bad
    // path fails at once.
    let dir = &args.out_dir;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut raster = Rasterizer::default();

    eprintln!("reference: {} …", args.reference);
    let mut reference = strata_stores::create(&args.reference, &base)?;
    let reference_result =
        pool.install(|| render_frame(reference.as_mut(), &mut raster, &input, scene.background))?;
    let reference_image = reference_result.image;
    drop(reference);
    reference_image.write_png(dir.join("reference.png"))?;

    let mut measured = Vec::new();
    for (i, spec) in specs.iter().enumerate() {
        eprintln!(
            "[{}/{}] {}: {} warm-up + {} timed runs …",
            i + 1,
            specs.len(),
            spec.label,
            args.warmup,
            args.runs
        );
        let mut method = strata_stores::create(&spec.method, &spec.options)?;
        let mut per_pass: Vec<(&'static str, Vec<f64>)> = Vec::new();
        let mut totals = Vec::new();
        let mut last = None;
        for run in 0..args.warmup + args.runs {
            let r = pool
                .install(|| render_frame(method.as_mut(), &mut raster, &input, scene.background))?;
            if run >= args.warmup {
                for (name, d) in r.timings.iter() {
                    match per_pass.iter_mut().find(|(n, _)| *n == name) {
                        Some((_, v)) => v.push(ms(d)),
                        None => per_pass.push((name, vec![ms(d)])),
                    }
                }
                totals.push(ms(r.timings.total()));
            }
            last = Some(r);
        }
        let last = last.context("no run")?;
        let rmse = metrics::rmse(&reference_image, &last.image)?;
        let flip = flip::flip(&reference_image, &last.image, args.ppd)?;
        let bad = metrics::bad_pixels(&reference_image, &last.image, args.threshold)?;
        last.image
            .write_png(dir.join(format!("{}.png", spec.file)))?;
        flip.heatmap
            .write_png(dir.join(format!("{}-flip.png", spec.file)))?;
        measured.push(Measured {
            spec_index: i,
            passes: per_pass
                .into_iter()
                .map(|(n, v)| (n, median(v).unwrap_or(0.0)))
                .collect(),
            total_ms: median(totals).unwrap_or(0.0),
            last,
            rmse,
            flip: flip.mean,
            bad,
        });
    }

    print_table(&args, &specs, &measured, &scene.name, threads)?;
    let report = report_json(&args, &specs, &measured, &scene, threads);
    std::fs::write(
        dir.join("report.json"),
        serde_json::to_string_pretty(&report)? + "\n",
    )
    .with_context(|| format!("cannot write {}", dir.join("report.json").display()))?;
    write_pages(dir, &args, &specs, &measured, &scene.name, threads)?;
    eprintln!("wrote {}", dir.join("report.html").display());
    Ok(())
}

fn mib(b: u64) -> f64 {
    b as f64 / (1 << 20) as f64
}

fn pass(m: &Measured, name: &str) -> f64 {
    m.passes
        .iter()
        .find(|(n, _)| *n == name)
        .map_or(0.0, |(_, v)| *v)
}

/// Column titles and cells of the comparison table (stdout, markdown and HTML share them).
const COLUMNS: [&str; 11] = [
    "method",
    "total ms",
    "capture ms",
    "resolve ms",
    "memory MiB",
    "used MiB",
    "fragments",
    "lost",
    "RMSE",
    "mean FLIP",
    "bad pixels",
];

fn cells(spec: &Spec, m: &Measured) -> [String; 11] {
    let c = &m.last.capture;
    [
        spec.label.clone(),
        format!("{:.2}", m.total_ms),
        format!("{:.2}", pass(m, "capture")),
        format!("{:.2}", pass(m, "resolve")),
        format!("{:.1}", mib(m.last.memory_bytes)),
        format!("{:.1}", mib(m.last.used_memory_bytes)),
        if spec.fidelity == Fidelity::Approximate {
            "none (blended)".to_owned()
        } else {
            c.fragments_stored.to_string()
        },
        c.dropped.to_string(),
        format!("{:.5}", m.rmse),
        format!("{:.5}", m.flip),
        format!("{:.3} %", 100.0 * m.bad.share()),
    ]
}

fn print_table(
    args: &Args,
    specs: &[Spec],
    measured: &[Measured],
    scene: &str,
    threads: usize,
) -> Result<()> {
    outln!(
        "strata compare: {scene}, frame {}, {threads} thread(s) on {}, medians of {} runs; reference {}; \
         bad pixels: a channel off by more than {}/255; FLIP at {} pixels per degree",
        args.frame,
        crate::report::cpu_model(),
        args.runs,
        args.reference,
        args.threshold,
        args.ppd
    )?;
    let rows: Vec<[String; 11]> = measured
        .iter()
        .map(|m| cells(&specs[m.spec_index], m))
        .collect();
    let widths: Vec<usize> = (0..COLUMNS.len())
        .map(|i| {
            rows.iter()
                .map(|r| r[i].len())
                .chain([COLUMNS[i].len()])
                .max()
                .unwrap_or(0)
        })
        .collect();
    let line = |cells: &[String]| {
        cells
            .iter()
            .enumerate()
            .map(|(i, c)| {
                if i == 0 {
                    format!("{c:<w$}", w = widths[i])
                } else {
                    format!("{c:>w$}", w = widths[i])
                }
            })
            .collect::<Vec<_>>()
            .join("  ")
    };
    outln!("{}", line(&COLUMNS.map(str::to_owned)))?;
    for r in &rows {
        outln!("{}", line(r))?;
    }
    Ok(())
}

fn report_json(
    args: &Args,
    specs: &[Spec],
    measured: &[Measured],
    scene: &strata_scene::Scene,
    threads: usize,
) -> Value {
    let methods: Vec<Value> = measured
        .iter()
        .map(|m| {
            let spec = &specs[m.spec_index];
            let c = &m.last.capture;
            let passes: serde_json::Map<String, Value> = m
                .passes
                .iter()
                .map(|(n, v)| ((*n).to_owned(), json!(v)))
                .collect();
            json!({
                "label": spec.label,
                "method": spec.method,
                "fidelity": spec.fidelity.describe(),
                "passes_ms": Value::Object(passes),
                "total_ms": m.total_ms,
                "memory_bytes": m.last.memory_bytes,
                "used_memory_bytes": m.last.used_memory_bytes,
                "fragments_rasterized": c.fragments_rasterized,
                "fragments_stored": c.fragments_stored,
                "fragments_lost": c.dropped,
                "fragments_tail_blended": c.tail_blended,
                "raster_passes": c.raster_passes,
                "rmse": m.rmse,
                "mean_flip": m.flip,
                "bad_pixels": {
                    "count": m.bad.count,
                    "share": m.bad.share(),
                    "threshold": m.bad.threshold,
                },
                "image": format!("{}.png", spec.file),
                "flip_heatmap": format!("{}-flip.png", spec.file),
            })
        })
        .collect();
    json!({
        "scene": scene.name,
        "width": scene.width,
        "height": scene.height,
        "frame": args.frame,
        "triangles": scene.triangle_count(),
        "threads": threads,
        "cpu": crate::report::cpu_model(),
        "runs": args.runs,
        "warmup": args.warmup,
        "reference": args.reference,
        "bad_pixel_threshold": args.threshold,
        "pixels_per_degree": args.ppd,
        "methods": methods,
    })
}

fn write_pages(
    dir: &Path,
    args: &Args,
    specs: &[Spec],
    measured: &[Measured],
    scene: &str,
    threads: usize,
) -> Result<()> {
    let intro = format!(
        "Scene {scene}, frame {}, {threads} thread(s) on {}, medians of {} timed runs after {} warm-up. \
         Errors against {} (reference.png): RMSE over RGB in [0, 1], mean FLIP at {} pixels per degree, \
         bad pixels = a channel off by more than {}/255. \"lost\" counts fragments a method dropped or evicted; \
         an approximate method (weighted blending) keeps no fragments, so it has none to count.",
        args.frame,
        crate::report::cpu_model(),
        args.runs,
        args.warmup,
        args.reference,
        args.ppd,
        args.threshold
    );
    let mut md = String::new();
    writeln!(md, "# strata compare: {scene}\n\n{intro}\n")?;
    writeln!(md, "| {} |", COLUMNS.join(" | "))?;
    writeln!(md, "| --- |{}", " ---: |".repeat(COLUMNS.len() - 1))?;
    for m in measured {
        writeln!(md, "| {} |", cells(&specs[m.spec_index], m).join(" | "))?;
    }
    writeln!(
        md,
        "\nFLIP heat maps use FLIP's magma colour map: black for no error, through purple and orange, \
         to pale yellow for the largest error (1); report.html shows the colour bar.\n"
    )?;
    for m in measured {
        let s = &specs[m.spec_index];
        writeln!(
            md,
            "## {}\n\n![{0}]({}.png) ![FLIP]({1}-flip.png)\n",
            s.label, s.file
        )?;
    }
    std::fs::write(dir.join("report.md"), md)
        .with_context(|| format!("cannot write {}", dir.join("report.md").display()))?;

    let mut h = String::new();
    writeln!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>strata compare: {}</title><style>",
        html_escape(scene)
    )?;
    writeln!(
        h,
        "body{{font-family:system-ui,sans-serif;margin:2em}}table{{border-collapse:collapse}}td,th{{padding:.3em .6em;border-bottom:1px solid #ddd;text-align:right}}td:first-child,th:first-child{{text-align:left}}.grid{{display:grid;grid-template-columns:repeat(auto-fill,minmax(360px,1fr));gap:1.2em;margin-top:1.5em}}figure{{margin:0}}img{{width:100%;border:1px solid #ccc}}figcaption{{font-size:.9em}}"
    )?;
    writeln!(
        h,
        "</style></head><body><h1>strata compare: {}</h1><p>{}</p>",
        html_escape(scene),
        html_escape(&intro)
    )?;
    writeln!(h, "<table><tr><th>{}</th></tr>", COLUMNS.join("</th><th>"))?;
    for m in measured {
        let c = cells(&specs[m.spec_index], m).map(|c| html_escape(&c));
        writeln!(h, "<tr><td>{}</td></tr>", c.join("</td><td>"))?;
    }
    writeln!(
        h,
        "</table><p>FLIP heat maps (right of each image):</p>{}",
        colour_bar_html(
            "per-pixel FLIP error against the reference: 0 (identical) to 1 (most different)",
            &flip::magma_stops(17),
            &[0.0, 0.25, 0.5, 0.75, 1.0]
        )
    )?;
    writeln!(
        h,
        "<div class=\"grid\"><figure><img src=\"reference.png\" alt=\"reference\"><figcaption><b>reference</b>: {}</figcaption></figure>",
        html_escape(&args.reference)
    )?;
    for m in measured {
        let s = &specs[m.spec_index];
        writeln!(
            h,
            "<figure><img src=\"{f}.png\" alt=\"{l}\"><img src=\"{f}-flip.png\" alt=\"FLIP of {l}\"><figcaption><b>{l}</b>, {}: RMSE {:.5}, mean FLIP {:.5}, {:.3} % bad pixels</figcaption></figure>",
            s.fidelity.describe(),
            m.rmse,
            m.flip,
            100.0 * m.bad.share(),
            f = html_escape(&s.file),
            l = html_escape(&s.label)
        )?;
    }
    writeln!(h, "</div></body></html>")?;
    std::fs::write(dir.join("report.html"), h)
        .with_context(|| format!("cannot write {}", dir.join("report.html").display()))
}
