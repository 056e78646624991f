//! `strata demo`: every built-in scene (and the real meshes when found) with a report.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::builtin;
use strata_stores::{Fidelity, render_frame};

use crate::options::{RenderOptions, thread_pool};
use crate::report::{html_escape, ms, stats_json, summary_line};

/// Render every built-in scene (and the Stanford/Khronos meshes when they are found) into a
/// folder: one PNG and one statistics JSON per scene, and report.md / report.html showing them.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Folder to write into (created if missing).
    #[arg(long, default_value = "strata-demo")]
    pub(crate) out_dir: PathBuf,

    #[command(flatten)]
    pub(crate) render: RenderOptions,
}

struct Row {
    name: &'static str,
    description: &'static str,
    triangles: u64,
    fragments: u64,
    covered: u64,
    max_depth: u32,
    mean_depth: f64,
    memory: u64,
    capture_ms: f64,
    resolve_ms: f64,
    /// Whether the DeepFrame resolves to the image; `None` for a method that exports none.
    deep_frame_ok: Option<bool>,
}

/// What the report says about the method: how faithful it is, and how it composites.
fn method_sentence(method: &str, fidelity: Fidelity) -> String {
    let how = match fidelity {
        Fidelity::Exact => {
            "every pixel keeps all its fragments, sorted and composited front to back with OVER"
        }
        Fidelity::Bounded => {
            "every pixel keeps a limited number of its fragments, sorted and composited front to \
             back with OVER; the fragments it could not keep are counted as lost"
        }
        Fidelity::Approximate => {
            "every fragment is blended in with a weight instead of being sorted, and none is kept, \
             so the fragments column counts none and there is no DeepFrame to check"
        }
    };
    format!("Method {method}: {}: {how}.", fidelity.describe())
}

/// Runs `strata demo`.
pub(crate) fn run(args: Args) -> Result<()> {
    let options = args.render.checked_method_options()?;
    let fidelity = strata_stores::find(&args.render.method)?.fidelity(&options);
    let pool = thread_pool(args.render.threads)?;
    let dir = &args.out_dir;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let search = args.render.search_path();
    let threads = pool.current_num_threads();
    let mut raster = Rasterizer::default();
    let (available, skipped): (Vec<&builtin::BuiltinScene>, Vec<_>) = builtin::SCENES
        .iter()
        .filter(|s| !s.is_volume())
        .partition(|s| s.available(&search));
    let mut rows = Vec::new();
    let started = Instant::now();
    for (i, b) in available.iter().enumerate() {
        eprint!("[{}/{}] {}: loading… ", i + 1, available.len(), b.name);
        let scene = b.load(&search)?;
        eprint!("rendering… ");
        let mut method = strata_stores::create(&args.render.method, &options)?;
        let input = FrameInput::from_scene(&scene, 0);
        let result =
            pool.install(|| render_frame(method.as_mut(), &mut raster, &input, scene.background))?;
        // Check the exchange format on every demo frame: the DeepFrame must resolve to the same image.
        let deep_frame_ok = match method.deep_frame() {
            Some(df) => Some(df?.resolve(scene.background) == result.image),
            None => None,
        };
        let png = dir.join(format!("{}.png", b.name));
        result.image.write_png(&png)?;
        let json = stats_json(&scene, method.name(), 0, threads, &result);
        std::fs::write(
            dir.join(format!("{}.json", b.name)),
            serde_json::to_string_pretty(&json)? + "\n",
        )?;
        eprintln!("done");
        eprintln!("      {}", summary_line(&scene, &result));
        let depth = result.depth.clone().unwrap_or_default();
        rows.push(Row {
            name: b.name,
            description: b.description,
            triangles: scene.triangle_count(),
            fragments: result.capture.fragments_stored,
            covered: depth.covered_pixels(),
            max_depth: depth.max_depth_complexity(),
            mean_depth: depth.mean_depth_complexity(),
            memory: result.memory_bytes,
            capture_ms: result.timings.get("capture").map_or(0.0, ms),
            resolve_ms: result.timings.get("resolve").map_or(0.0, ms),
            deep_frame_ok,
        });
    }
    let skipped: Vec<String> = skipped
        .iter()
        .map(|s| format!("{} (needs {})", s.name, s.meshes.join(", ")))
        .collect();
    let about = method_sentence(&args.render.method, fidelity);
    write_markdown(dir, &rows, &skipped, &about, threads)?;
    write_html(dir, &rows, &skipped, &about, threads)?;
    eprintln!(
        "rendered {} scenes in {:.1} s into {}; open {}",
        rows.len(),
        started.elapsed().as_secs_f64(),
        dir.display(),
        dir.join("report.html").display()
    );
    if !skipped.is_empty() {
        eprintln!(
            "skipped (meshes not found; set STRATA_MODEL_PATH, pass --models DIR, or run scripts/fetch-models): {}",
            skipped.join(", ")
        );
    }
    Ok(())
}

fn mib(b: u64) -> f64 {
    b as f64 / (1 << 20) as f64
}

/// Column titles of the report table.
const COLUMNS: [&str; 10] = [
    "scene",
    "triangles",
    "fragments",
    "covered px",
    "max depth",
    "mean depth",
    "memory MiB",
    "capture ms",
    "resolve ms",
    "DeepFrame = image",
];

/// The table cells of one scene, in [`COLUMNS`] order, for both report formats.
fn cells(r: &Row) -> [String; 10] {
    [
        r.name.to_owned(),
        r.triangles.to_string(),
        match r.deep_frame_ok {
            None if r.fragments == 0 => "none (blended)".to_owned(),
            _ => r.fragments.to_string(),
        },
        r.covered.to_string(),
        r.max_depth.to_string(),
        format!("{:.2}", r.mean_depth),
        format!("{:.1}", mib(r.memory)),
        format!("{:.2}", r.capture_ms),
        format!("{:.2}", r.resolve_ms),
        match r.deep_frame_ok {
            Some(true) => "yes",
            Some(false) => "NO",
            None => "n/a (no DeepFrame)",
        }
        .to_owned(),
    ]
}

fn write_markdown(
    dir: &std::path::Path,
    rows: &[Row],
    skipped: &[String],
    about: &str,
    threads: usize,
) -> Result<()> {
    let mut md = String::new();
    writeln!(md, "# strata demo\n")?;
    writeln!(
        md,
        "{about} {threads} thread(s), frame 0 of each scene. Times are one run's wall clock (use `strata bench` for medians).\n"
    )?;
    writeln!(md, "| {} |", COLUMNS.join(" | "))?;
    writeln!(
        md,
        "| --- |{}",
        " ---: |".repeat(COLUMNS.len() - 2) + " :---: |"
    )?;
    for r in rows {
        writeln!(md, "| {} |", cells(r).join(" | "))?;
    }
    writeln!(md)?;
    for r in rows {
        writeln!(
            md,
            "## {}\n\n{}\n\n![{}]({}.png)\n",
            r.name, r.description, r.name, r.name
        )?;
    }
    if !skipped.is_empty() {
        writeln!(md, "Skipped, meshes not found: {}.", skipped.join(", "))?;
    }
    std::fs::write(dir.join("report.md"), md)
        .with_context(|| format!("cannot write {}", dir.join("report.md").display()))
}

fn write_html(
    dir: &std::path::Path,
    rows: &[Row],
    skipped: &[String],
    about: &str,
    threads: usize,
) -> Result<()> {
    let mut h = String::new();
    writeln!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>strata demo</title><style>"
    )?;
    writeln!(
        h,
        "body{{font-family:system-ui,sans-serif;margin:2em;max-width:1400px}}table{{border-collapse:collapse}}td,th{{padding:.3em .7em;border-bottom:1px solid #ddd;text-align:right}}td:first-child,th:first-child{{text-align:left}}.grid{{display:grid;grid-template-columns:repeat(auto-fill,minmax(420px,1fr));gap:1.5em}}img{{width:100%;border:1px solid #ccc}}figcaption{{font-size:.9em;color:#444}}"
    )?;
    writeln!(h, "</style></head><body><h1>strata demo</h1>")?;
    writeln!(
        h,
        "<p>{} {threads} thread(s), frame 0 of each scene. Times are one run's wall clock (use <code>strata bench</code> for medians).</p>",
        html_escape(about)
    )?;
    writeln!(h, "<table><tr><th>{}</th></tr>", COLUMNS.join("</th><th>"))?;
    for r in rows {
        let cells = cells(r).map(|c| html_escape(&c));
        writeln!(h, "<tr><td>{}</td></tr>", cells.join("</td><td>"))?;
    }
    writeln!(h, "</table><div class=\"grid\">")?;
    for r in rows {
        writeln!(
            h,
            "<figure><img src=\"{0}.png\" alt=\"{0}\"><figcaption><b>{0}</b>: {1} ({2} fragments, depth up to {3}; <a href=\"{0}.json\">statistics</a>)</figcaption></figure>",
            html_escape(r.name),
            html_escape(r.description),
            cells(r)[2],
            r.max_depth
        )?;
    }
    writeln!(h, "</div>")?;
    if !skipped.is_empty() {
        writeln!(
            h,
            "<p>Skipped, meshes not found: {}.</p>",
            html_escape(&skipped.join(", "))
        )?;
    }
    writeln!(h, "</body></html>")?;
    std::fs::write(dir.join("report.html"), h)
        .with_context(|| format!("cannot write {}", dir.join("report.html").display()))
}
