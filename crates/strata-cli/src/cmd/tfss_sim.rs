//! `strata tfss-sim`: Lin 2007's evaluation (ch. 4) on our frames — the transparent-fragment
//! distribution, the memory of R-buffer, WF and TFSS, the access/time model — beside strata's own
//! layouts and its real TFSS store.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_stores::tfss::Tfss;
use strata_stores::tfss::model::{
    self, ColourTrace, Distribution, Evaluation, Memory, Sizes, Time, Transparency,
};
use strata_stores::{Method, MethodOptions, render_frame};

use crate::options::{check_output, open_scene, search_path, thread_pool};

/// The long `--help` of `strata tfss-sim`: what every column means, with the thesis's sections.
pub(crate) const LONG_ABOUT: &str =
    "Reproduce the TFSS evaluation of Lin 2007 (ch. 4) on a scene's frames.

Each frame is rendered with the exact linked-list A-buffer; its DeepFrame gives each pixel's
fragments, which feed the thesis's models (every fragment counts as transparent unless
--opaque-split). Printed per frame:

DISTRIBUTION (Table 4-1): `fragments` all fragments of the frame; `transparent` transparent
fragments N_f; `per pixel` transparent fragments per pixel that has any; `density` transparent
pixels over W·H; `N=i` pixels holding exactly i transparent fragments. Below it, `colour bits`:
fragments whose colour keeps len = 0..8 bits per component after leading-zeros elimination
(§3.3, our Figure 3-10), lossless and after the thesis's lossy alpha shift.

MEMORY (Table 4-2, Figures 4-3 to 4-6): `bytes` and `MiB` of each technique, `vs R-buffer` and
`vs WF` the reduction rate 1 − bytes / theirs (positive: smaller), as Figures 4-4 and 4-6
print them. Rows: R-buffer = N_f·S_f + second z-buffer W·H·Z + 3-bit state memory; WF(D) =
(W·H + N_A)·(8·D + S_A) with D = D_avg (fragments per transparent pixel, rounded); TFSS(L) =
8·L·N_S + S_A·(W·H + N_S) with N_S = Σ⌈n_p/L⌉; TFSS(L, M) LZ = sections of M bytes holding L
fragments with leading-zeros-eliminated colours, packed exactly as the store packs them from
this frame's colours, M chosen as the cheapest, plus a 4-bit Length-table entry per slot;
the `LZ+shift` rows add the thesis's alpha shift, which is LOSSY — strata's store never applies
it, it changes colours. Then strata's layouts: DeepFrame (offsets + 12-byte fragments), S-buffer
regions (offsets + fill + 12-byte slots), linked list (heads + 16-byte nodes), compact runs
(1-byte counts + an offset per 64 pixels + 8-byte fragments: no NSA, no half-empty sections;
it needs a counting pass first), compact runs LZ (the same, colours leading-zeros-eliminated,
bit-packed). Last, strata's real TFSS store (12-byte fragments with the object id) rendering
the frame: the bytes it uses (SSA + used sections + NSA + Length table), the sections, the
bytes allocated, and for LZ the colour budget b (bits per component) it fitted; its DeepFrame
is checked against the A-buffer's. With --no-store, `TFSS store(L)` rows give the same bytes
from the model instead.

TIME (§4.3.2, Figure 4-7): one cycle per memory access. `accesses`: R-buffer reads what is
left on every pass (Σ N_i·i(i+1)/2), the same for the second z-buffer, plus one frame-buffer
access per fragment; WF and TFSS read each fragment once, TFSS plus one SSA read per pixel
holding fragments. `computation`: Σ N_i·i(i+1)/2 for R-buffer, Σ N_i·(i(i−1)/2 + 1) for WF and
TFSS. `cycles` = accesses + computation, with reduction rates. `store accesses`: the TFSS store
flow's reads and writes per L (beyond the thesis).

Sizes (bytes): S_f = 12 (x, y, z, RGBA), fragment 8 (z, RGBA), Z = 4, S_A = --address-bytes
(4; the thesis's own figures fit 2), state 3 bits, Length entry 4 bits. With --frames N, the
averages over the frames follow (Figures 4-4, 4-6, 4-7 print averages).";

/// Reproduce the TFSS evaluation of Lin 2007 on a scene's frames (see [`LONG_ABOUT`]).
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// Scene file (TOML) or built-in scene name.
    pub(crate) scene: String,

    /// Evaluate N frames spread evenly over the animation (0, F/N, 2F/N, … of F frames), as the
    /// thesis dumps every 60th frame.
    #[arg(long, conflicts_with = "frame", value_parser = clap::value_parser!(u32).range(1..))]
    pub(crate) frames: Option<u32>,

    /// Evaluate this one animation frame.
    #[arg(long, default_value_t = 0)]
    pub(crate) frame: u32,

    /// Evaluate TFSS with L_num = 1 ..= this (the thesis evaluates 1 to 4).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub(crate) l_num_max: u32,

    /// S_A: bytes of a section address in the thesis's models (2 reproduces the thesis's averages on
    /// its own frames; our 1280×720 frames need 4).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=8))]
    pub(crate) address_bytes: u64,

    /// Count fragments with alpha 255 as opaque: the transparent ones are those in front of each
    /// pixel's nearest opaque fragment (what R-buffer and WF keep after phase 2).
    #[arg(long)]
    pub(crate) opaque_split: bool,

    /// Skip rendering with strata's real TFSS store (model figures only).
    #[arg(long)]
    pub(crate) no_store: bool,

    /// Also write every figure as JSON to this file.
    #[arg(long)]
    pub(crate) json: Option<PathBuf>,

    /// Extra directory to look for mesh files in (repeatable).
    #[arg(long = "models", value_name = "DIR")]
    pub(crate) model_dirs: Vec<PathBuf>,

    /// Worker threads (default: every available core).
    #[arg(long, short = 'j')]
    pub(crate) threads: Option<usize>,
}

/// What strata's real TFSS store used on a frame.
struct StoreRun {
    l_num: u32,
    leading_zeros: bool,
    rgb_bits: Option<u32>,
    sections: u64,
    used: u64,
    allocated: u64,
}

/// One frame's figures.
struct FrameFigures {
    frame: u32,
    eval: Evaluation,
    trace: ColourTrace,
    store: Vec<StoreRun>,
}

/// A memory row: stable key for averaging, the group it is printed under, the memory.
struct Row<'a> {
    key: String,
    group: &'static str,
    memory: &'a Memory,
}

const SEED: &str = "Lin 2007 techniques (Table 4-2)";
const SEED_LZ: &str =
    "TFSS(L_num, M_section) with leading-zeros elimination, colour lengths measured";
const LOSSY: &str =
    "  ... plus the thesis's alpha shift (LOSSY: changes colours; never used by the store)";
const STRATA: &str = "strata's layouts (12-byte fragments with object id)";
const STRATA_TFSS: &str = "strata's TFSS store, by the model (used bytes)";
const BETTER: &str = "a layout that beats TFSS (8-byte fragments, needs a counting pass)";

fn memory_rows(e: &Evaluation) -> Vec<Row<'_>> {
    let row = |key: String, group, memory| Row { key, group, memory };
    let mut rows = vec![
        row("R-buffer".into(), SEED, &e.rbuffer),
        row("WF".into(), SEED, &e.wf),
    ];
    for t in &e.tfss {
        rows.push(row(format!("TFSS({})", t.l_num), SEED, &t.plain));
    }
    for t in &e.tfss {
        if let Some((_, m)) = &t.lz {
            rows.push(row(format!("TFSS({}) LZ", t.l_num), SEED_LZ, m));
        }
    }
    for t in &e.tfss {
        if let Some((_, m)) = &t.lz_lossy {
            rows.push(row(format!("TFSS({}) LZ lossy", t.l_num), LOSSY, m));
        }
    }
    let l = &e.layouts;
    for m in [&l.deep_frame, &l.sbuffer, &l.linked_list] {
        rows.push(row(m.name.clone(), STRATA, m));
    }
    for t in &e.tfss {
        rows.push(row(t.store.name.clone(), STRATA_TFSS, &t.store));
    }
    rows.push(row(l.compact.name.clone(), BETTER, &l.compact));
    if let Some(m) = &l.compact_lz {
        rows.push(row(m.name.clone(), BETTER, m));
    }
    rows
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 20) as f64
}

fn pct(x: f64) -> String {
    format!("{:+.1}%", 100.0 * x)
}

/// The frames to evaluate.
fn frame_list(args: &Args, scene: &Scene) -> Result<Vec<u32>> {
    let count = scene.frame_count();
    match args.frames {
        Some(n) if n > count => bail!(
            "--frames {n}: {} has only {count} frame(s); give at most {count}",
            scene.name
        ),
        Some(n) => Ok((0..n)
            .map(|i| (u64::from(i) * u64::from(count) / u64::from(n)) as u32)
            .collect()),
        None => {
            scene.check_frame(args.frame)?;
            Ok(vec![args.frame])
        }
    }
}

/// Renders `frame` with `method` and returns its DeepFrame.
fn render_deep(
    method: &mut dyn Method,
    raster: &mut Rasterizer,
    scene: &Scene,
    frame: u32,
    pool: &rayon::ThreadPool,
) -> Result<strata_core::DeepFrame> {
    let input = FrameInput::from_scene(scene, frame);
    let result = pool.install(|| render_frame(method, raster, &input, scene.background))?;
    if result.capture.dropped > 0 {
        bail!(
            "{} dropped {} fragments on frame {frame}",
            method.name(),
            result.capture.dropped
        );
    }
    Ok(method
        .deep_frame()
        .context("an exact method exports a DeepFrame")??)
}

/// Runs `strata tfss-sim`.
pub(crate) fn run(args: Args) -> Result<()> {
    if let Some(path) = &args.json {
        check_output(path)?;
    }
    let pool = thread_pool(args.threads)?;
    let scene = open_scene(&args.scene, &search_path(&args.model_dirs))?;
    let frames = frame_list(&args, &scene)?;
    let sizes = Sizes {
        address: args.address_bytes,
        ..Sizes::default()
    };
    let transparency = if args.opaque_split {
        Transparency::OpaqueSplit
    } else {
        Transparency::All
    };
    outln!(
        "strata tfss-sim: {} ({}x{}, {} triangles), frame(s) {:?}, L_num 1..={}, S_A {} B, {} (Lin 2007, ch. 4)",
        scene.name,
        scene.width,
        scene.height,
        scene.triangle_count(),
        frames,
        args.l_num_max,
        sizes.address,
        if args.opaque_split {
            "alpha-255 fragments opaque"
        } else {
            "every fragment transparent"
        },
    )?;
    let mut raster = Rasterizer::default();
    let mut abuffer = strata_stores::create("abuffer", &MethodOptions::default())?;
    let mut figures = Vec::new();
    for &frame in &frames {
        let deep = render_deep(abuffer.as_mut(), &mut raster, &scene, frame, &pool)?;
        let (d, trace) = model::frame_model(&deep, transparency);
        let eval = model::evaluate(&d, Some(&trace), &sizes, args.l_num_max);
        let mut store = Vec::new();
        if !args.no_store {
            for l_num in 1..=args.l_num_max {
                for leading_zeros in [false, true] {
                    let mut t = Tfss::new(&MethodOptions {
                        l_num,
                        leading_zeros,
                        ..MethodOptions::default()
                    });
                    let got = render_deep(&mut t, &mut raster, &scene, frame, &pool)?;
                    if got != deep {
                        bail!(
                            "TFSS (L_num {l_num}, leading zeros {leading_zeros}) captured a different DeepFrame than the A-buffer on frame {frame}"
                        );
                    }
                    let m = t.memory();
                    store.push(StoreRun {
                        l_num,
                        leading_zeros,
                        rgb_bits: m.rgb_bits,
                        sections: m.sections_used,
                        used: m.used(),
                        allocated: m.allocated(),
                    });
                }
            }
        }
        print_frame(frame, &eval, &trace, &store)?;
        figures.push(FrameFigures {
            frame,
            eval,
            trace,
            store,
        });
    }
    let averages = averages(&figures);
    if figures.len() > 1 {
        print_averages(&figures, &averages)?;
    }
    if let Some(path) = &args.json {
        let doc = json!({
            "scene": scene.name,
            "width": scene.width,
            "height": scene.height,
            "triangles": scene.triangle_count(),
            "transparency": if args.opaque_split { "opaque-split" } else { "all" },
            "sizes": {
                "rbuffer_fragment": sizes.rbuffer_fragment,
                "fragment": sizes.fragment,
                "z": sizes.z,
                "address": sizes.address,
                "state_bits": sizes.state_bits,
                "length_bits": sizes.length_bits,
            },
            "l_num_max": args.l_num_max,
            "frames": figures.iter().map(frame_json).collect::<Vec<_>>(),
            "averages": averages_json(&averages),
        });
        std::fs::write(path, serde_json::to_string_pretty(&doc)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn print_frame(frame: u32, e: &Evaluation, trace: &ColourTrace, store: &[StoreRun]) -> Result<()> {
    let d = &e.distribution;
    outln!("\n== frame {frame} ==")?;
    outln!("distribution (Table 4-1)")?;
    let max = d.max_fragments() as usize;
    let mut head = format!(
        "  {:>10} {:>11} {:>9} {:>8}",
        "fragments", "transparent", "per pixel", "density"
    );
    let mut line = format!(
        "  {:>10} {:>11} {:>9.2} {:>7.1}%",
        d.fragments,
        d.transparent_fragments(),
        d.fragments_per_transparent_pixel(),
        100.0 * d.transparency_density()
    );
    for i in 1..=max {
        head.push_str(&format!(" {:>8}", format!("N={i}")));
        line.push_str(&format!(" {:>8}", d.histogram[i]));
    }
    outln!("{head}\n{line}")?;
    for (label, lossy) in [("lossless", false), ("alpha shift (lossy)", true)] {
        let h = trace.length_histogram(lossy);
        let n: u64 = h.iter().sum::<u64>().max(1);
        let mean: f64 = h
            .iter()
            .enumerate()
            .map(|(l, &c)| l as f64 * c as f64)
            .sum::<f64>()
            / n as f64;
        let cells: Vec<String> = h.iter().map(|c| c.to_string()).collect();
        outln!(
            "  colour bits 0..8, {label}: [{}], mean {mean:.2}",
            cells.join(", ")
        )?;
    }

    outln!(
        "memory (Table 4-2; reduction = 1 - bytes/theirs, Figures 4-4/4-6), D_avg {}",
        d.d_avg()
    )?;
    outln!(
        "  {:<28} {:>12} {:>9} {:>11} {:>9}",
        "technique",
        "bytes",
        "MiB",
        "vs R-buffer",
        "vs WF"
    )?;
    let (rb, wf) = (e.rbuffer.total(), e.wf.total());
    let mut group = "";
    for r in memory_rows(e) {
        if r.group == STRATA_TFSS && !store.is_empty() {
            continue; // the real store's rows below say the same, measured
        }
        if r.group != group {
            group = r.group;
            outln!("  {group}")?;
        }
        let bytes = r.memory.total();
        let name = r
            .memory
            .name
            .replace(" LZ+alpha shift (lossy)", " LZ+shift");
        outln!(
            "    {:<26} {:>12} {:>9.2} {:>11} {:>9}",
            name,
            bytes,
            mib(bytes),
            pct(model::reduction(bytes, rb)),
            pct(model::reduction(bytes, wf))
        )?;
    }
    if !store.is_empty() {
        outln!(
            "  strata's TFSS store, rendered (used bytes; DeepFrame checked against the A-buffer)"
        )?;
    }
    for s in store {
        let name = format!(
            "TFSS store({}){}",
            s.l_num,
            match s.rgb_bits {
                Some(b) => format!(" LZ b={b}"),
                None => String::new(),
            }
        );
        outln!(
            "    {:<26} {:>12} {:>9.2} {:>11} {:>9}   {} sections, {} B allocated",
            name,
            s.used,
            mib(s.used),
            pct(model::reduction(s.used, rb)),
            pct(model::reduction(s.used, wf)),
            s.sections,
            s.allocated,
        )?;
    }

    outln!("time (§4.3.2, Figure 4-7; one cycle per access)")?;
    outln!(
        "  {:<10} {:>12} {:>12} {:>12} {:>11} {:>9}",
        "technique",
        "accesses",
        "computation",
        "cycles",
        "vs R-buffer",
        "vs WF"
    )?;
    let [r, w, _] = &e.time;
    for t in &e.time {
        print_time(t, r, w)?;
    }
    let accesses: Vec<String> = e
        .tfss
        .iter()
        .map(|t| format!("L{} {}", t.l_num, t.store_accesses))
        .collect();
    outln!(
        "  TFSS store-flow accesses (beyond the thesis): {}",
        accesses.join(", ")
    )?;
    Ok(())
}

fn print_time(t: &Time, r: &Time, w: &Time) -> Result<()> {
    outln!(
        "  {:<10} {:>12} {:>12} {:>12} {:>11} {:>9}",
        t.name,
        t.access_total(),
        t.computation,
        t.cycles(),
        pct(model::reduction(t.cycles(), r.cycles())),
        pct(model::reduction(t.cycles(), w.cycles()))
    )?;
    Ok(())
}

/// Mean reduction rates over the frames: per memory row key `(vs R-buffer, vs WF)`, and TFSS
/// time against R-buffer and WF.
struct Averages {
    memory: Vec<(String, f64, f64)>,
    time: (f64, f64),
}

fn averages(figures: &[FrameFigures]) -> Averages {
    let mut sums: BTreeMap<String, (f64, f64, usize)> = BTreeMap::new();
    let mut order = Vec::new();
    let (mut tr, mut tw) = (0.0, 0.0);
    for f in figures {
        let e = &f.eval;
        let (rb, wf) = (e.rbuffer.total(), e.wf.total());
        let mut add = |key: String, bytes: u64| {
            if !sums.contains_key(&key) {
                order.push(key.clone());
            }
            let s = sums.entry(key).or_default();
            s.0 += model::reduction(bytes, rb);
            s.1 += model::reduction(bytes, wf);
            s.2 += 1;
        };
        for r in memory_rows(e) {
            if r.group == STRATA_TFSS && !f.store.is_empty() {
                continue; // measured below
            }
            add(r.key, r.memory.total());
        }
        for s in &f.store {
            add(
                format!(
                    "TFSS store({}){} rendered",
                    s.l_num,
                    if s.leading_zeros { " LZ" } else { "" }
                ),
                s.used,
            );
        }
        let [r, w, t] = &e.time;
        tr += model::reduction(t.cycles(), r.cycles());
        tw += model::reduction(t.cycles(), w.cycles());
    }
    let n = figures.len().max(1) as f64;
    Averages {
        memory: order
            .into_iter()
            .map(|k| {
                let (r, w, c) = sums[&k];
                (k, r / c as f64, w / c as f64)
            })
            .collect(),
        time: (tr / n, tw / n),
    }
}

fn print_averages(figures: &[FrameFigures], a: &Averages) -> Result<()> {
    outln!(
        "\n== averages over {} frames (Figures 4-4, 4-6: memory reduction rates; 4-7: time) ==",
        figures.len()
    )?;
    outln!("  {:<30} {:>11} {:>9}", "technique", "vs R-buffer", "vs WF")?;
    for (k, r, w) in &a.memory {
        outln!("  {:<30} {:>11} {:>9}", k, pct(*r), pct(*w))?;
    }
    outln!(
        "  TFSS time: {} vs R-buffer, {} vs WF",
        pct(a.time.0),
        pct(a.time.1)
    )?;
    Ok(())
}

fn memory_json(m: &Memory, rb: u64, wf: u64) -> Value {
    let parts: serde_json::Map<String, Value> = m
        .parts
        .iter()
        .map(|(k, v)| ((*k).to_owned(), json!(v)))
        .collect();
    json!({
        "technique": m.name,
        "bytes": m.total(),
        "parts": parts,
        "reduction_vs_rbuffer": model::reduction(m.total(), rb),
        "reduction_vs_wf": model::reduction(m.total(), wf),
    })
}

fn time_json(t: &Time, r: &Time, w: &Time) -> Value {
    let accesses: serde_json::Map<String, Value> = t
        .accesses
        .iter()
        .map(|(k, v)| ((*k).to_owned(), json!(v)))
        .collect();
    json!({
        "technique": t.name,
        "accesses": accesses,
        "access_total": t.access_total(),
        "computation": t.computation,
        "cycles": t.cycles(),
        "reduction_vs_rbuffer": model::reduction(t.cycles(), r.cycles()),
        "reduction_vs_wf": model::reduction(t.cycles(), w.cycles()),
    })
}

fn distribution_json(d: &Distribution) -> Value {
    json!({
        "fragments": d.fragments,
        "transparent_fragments": d.transparent_fragments(),
        "transparent_pixels": d.transparent_pixels(),
        "fragments_per_transparent_pixel": d.fragments_per_transparent_pixel(),
        "transparency_density": d.transparency_density(),
        "max_fragments": d.max_fragments(),
        "d_avg": d.d_avg(),
        "pixels_with_n": &d.histogram[1..],
    })
}

fn frame_json(f: &FrameFigures) -> Value {
    let e = &f.eval;
    let (rb, wf) = (e.rbuffer.total(), e.wf.total());
    let [r, w, _] = &e.time;
    let tfss: Vec<Value> = e
        .tfss
        .iter()
        .map(|t| {
            json!({
                "l_num": t.l_num,
                "plain": memory_json(&t.plain, rb, wf),
                "lz": t.lz.as_ref().map(|(b, m)| {
                    let mut v = memory_json(m, rb, wf);
                    v["rgb_bits"] = json!(b);
                    v
                }),
                "lz_alpha_shift_lossy": t.lz_lossy.as_ref().map(|(b, m)| {
                    let mut v = memory_json(m, rb, wf);
                    v["rgb_bits"] = json!(b);
                    v
                }),
                "strata_store_model": memory_json(&t.store, rb, wf),
                "store_flow_accesses": t.store_accesses,
            })
        })
        .collect();
    let l = &e.layouts;
    json!({
        "frame": f.frame,
        "distribution": distribution_json(&e.distribution),
        "colour_bits": {
            "lossless": f.trace.length_histogram(false),
            "alpha_shift_lossy": f.trace.length_histogram(true),
        },
        "memory": {
            "rbuffer": memory_json(&e.rbuffer, rb, wf),
            "wf": memory_json(&e.wf, rb, wf),
            "tfss": tfss,
            "layouts": {
                "deep_frame": memory_json(&l.deep_frame, rb, wf),
                "sbuffer": memory_json(&l.sbuffer, rb, wf),
                "linked_list": memory_json(&l.linked_list, rb, wf),
                "compact_runs": memory_json(&l.compact, rb, wf),
                "compact_runs_lz": l.compact_lz.as_ref().map(|m| memory_json(m, rb, wf)),
            },
        },
        "store": f.store.iter().map(|s| json!({
            "l_num": s.l_num,
            "leading_zeros": s.leading_zeros,
            "rgb_bits": s.rgb_bits,
            "sections": s.sections,
            "used_bytes": s.used,
            "allocated_bytes": s.allocated,
            "reduction_vs_rbuffer": model::reduction(s.used, rb),
            "reduction_vs_wf": model::reduction(s.used, wf),
        })).collect::<Vec<_>>(),
        "time": e.time.iter().map(|t| time_json(t, r, w)).collect::<Vec<_>>(),
    })
}

fn averages_json(a: &Averages) -> Value {
    json!({
        "memory": a.memory.iter().map(|(k, r, w)| json!({
            "technique": k,
            "reduction_vs_rbuffer": r,
            "reduction_vs_wf": w,
        })).collect::<Vec<_>>(),
        "time": {
            "tfss_reduction_vs_rbuffer": a.time.0,
            "tfss_reduction_vs_wf": a.time.1,
        },
    })
}
