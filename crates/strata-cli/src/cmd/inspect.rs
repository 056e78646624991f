//! `strata inspect`: what an OpenEXR file holds — header, sample statistics, one pixel's samples.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use serde_json::json;
use strata_exr::{Attribute, Box2i, Column, DeepImage, FileInfo, FlatImage, Limits, LineOrder};

/// Print what an OpenEXR file (deep or flat scanline) holds.
///
/// The header (windows, channels with their types, compression, line order, every attribute),
/// for a deep file the sample statistics (total, empty pixels, mean and most per pixel, a
/// histogram), and with --pixel every sample of one pixel, front to back, with every channel.
#[derive(clap::Args, Debug)]
pub(crate) struct Args {
    /// The OpenEXR file.
    pub(crate) file: PathBuf,

    /// Also list the samples (deep) or values (flat) of the pixel at `x,y` (the file's pixel
    /// coordinates: the data window's origin is not subtracted).
    #[arg(long, value_parser = parse_pixel, value_name = "X,Y")]
    pub(crate) pixel: Option<(i64, i64)>,

    /// Print JSON instead of text.
    #[arg(long)]
    pub(crate) json: bool,
}

fn parse_pixel(s: &str) -> Result<(i64, i64), String> {
    let bad = || format!("'{s}': expected pixel coordinates x,y such as 320,180");
    let (x, y) = s.split_once(',').ok_or_else(bad)?;
    let x = x.trim().parse::<i64>().map_err(|_| bad())?;
    let y = y.trim().parse::<i64>().map_err(|_| bad())?;
    Ok((x, y))
}

/// Runs `strata inspect`.
pub(crate) fn run(args: Args) -> Result<()> {
    let limits = Limits::default();
    let bytes = strata_exr::read_file_bytes(&args.file, &limits)
        .with_context(|| format!("cannot read {}", args.file.display()))?;
    let info = strata_exr::read_info(&bytes)
        .with_context(|| format!("{} is not a readable OpenEXR file", args.file.display()))?;
    let pixels = if info.deep {
        let image = strata_exr::read_deep(&bytes, &limits)
            .with_context(|| format!("cannot read the deep image {}", args.file.display()))?;
        Pixels::Deep(image)
    } else {
        let image = strata_exr::read_flat(&bytes, &limits)
            .with_context(|| format!("cannot read the image {}", args.file.display()))?;
        Pixels::Flat(image)
    };
    if let Some((x, y)) = args.pixel
        && !info.data_window.contains(x, y)
    {
        bail!(
            "--pixel {x},{y} is outside the data window {}",
            window_text(&info.data_window)
        );
    }
    let text = if args.json {
        serde_json::to_string_pretty(&report_json(&args, &info, &pixels))? + "\n"
    } else {
        report_text(&args, &info, &pixels)
    };
    out!("{text}")?;
    Ok(())
}

/// The decoded pixels.
enum Pixels {
    Deep(DeepImage),
    Flat(FlatImage),
}

fn window_text(w: &Box2i) -> String {
    format!(
        "({},{})–({},{}), {}×{}",
        w.x_min,
        w.y_min,
        w.x_max,
        w.y_max,
        w.width(),
        w.height()
    )
}

fn line_order_name(order: LineOrder) -> &'static str {
    match order {
        LineOrder::IncreasingY => "increasing y",
        LineOrder::DecreasingY => "decreasing y",
    }
}

/// The attributes not already shown as windows, channels, compression or line order.
fn other_attributes(info: &FileInfo) -> impl Iterator<Item = &Attribute> {
    const SHOWN: [&str; 5] = [
        "channels",
        "compression",
        "dataWindow",
        "displayWindow",
        "lineOrder",
    ];
    info.attributes
        .iter()
        .filter(|a| !SHOWN.contains(&a.name.as_str()))
}

fn report_text(args: &Args, info: &FileInfo, pixels: &Pixels) -> String {
    let mut s = String::new();
    let kind = if info.deep {
        "deep scanline"
    } else {
        "flat scanline"
    };
    let _ = writeln!(s, "{}: OpenEXR {kind}", args.file.display());
    let _ = writeln!(s, "data window:    {}", window_text(&info.data_window));
    let _ = writeln!(s, "display window: {}", window_text(&info.display_window));
    let _ = writeln!(
        s,
        "compression: {}, line order: {}",
        info.compression.name(),
        line_order_name(info.line_order)
    );
    let channels: Vec<String> = info
        .channels
        .iter()
        .map(|c| format!("{} ({})", c.name, c.sample_type.name()))
        .collect();
    let _ = writeln!(s, "channels ({}): {}", channels.len(), channels.join(", "));
    let others: Vec<&Attribute> = other_attributes(info).collect();
    if !others.is_empty() {
        let _ = writeln!(s, "attributes:");
        for a in others {
            let _ = writeln!(s, "  {} ({}) = {}", a.name, a.type_name, a);
        }
    }
    match pixels {
        Pixels::Deep(image) => {
            let st = strata_exr::stats(image);
            let _ = writeln!(
                s,
                "samples: {} in {} pixels ({} empty); mean {:.3} per pixel, {:.3} per non-empty pixel; \
                 most {} at ({},{})",
                st.samples,
                st.pixels,
                st.empty_pixels,
                st.mean_per_pixel,
                per_covered(st.samples, st.pixels - st.empty_pixels),
                st.max_per_pixel,
                st.max_at.0,
                st.max_at.1
            );
            let _ = writeln!(s, "samples per pixel: {}", histogram_text(&st.histogram));
            if let Some((x, y)) = args.pixel {
                deep_pixel_text(&mut s, image, x, y);
            }
        }
        Pixels::Flat(image) => {
            if let Some((x, y)) = args.pixel {
                let p = flat_index(image, x, y);
                let _ = writeln!(s, "pixel ({x},{y}):");
                for (k, c) in image.channels().iter().enumerate() {
                    let _ = writeln!(s, "  {} = {}", c.name, value_text(image.column(k), p));
                }
            }
        }
    }
    s
}

/// Value `i` of a column as the file stores it: shortest `f32` text, or the integer.
fn value_text(column: &Column, i: usize) -> String {
    if let Some(v) = column.as_f32().and_then(|v| v.get(i)) {
        format!("{v}")
    } else if let Some(v) = column.as_u32().and_then(|v| v.get(i)) {
        format!("{v}")
    } else {
        "?".to_owned()
    }
}

fn per_covered(samples: u64, covered: u64) -> f64 {
    if covered == 0 {
        0.0
    } else {
        samples as f64 / covered as f64
    }
}

/// "0: 12, 1: 40, 2–3: 7, …" from the power-of-two histogram of [`strata_exr::stats`].
fn histogram_text(histogram: &[u64]) -> String {
    histogram
        .iter()
        .enumerate()
        .filter(|&(_, &n)| n > 0)
        .map(|(i, n)| match i {
            0 => format!("0: {n}"),
            1 => format!("1: {n}"),
            _ => format!("{}–{}: {n}", 1u64 << (i - 1), (1u64 << i) - 1),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn flat_index(image: &FlatImage, x: i64, y: i64) -> usize {
    let w = image.data_window();
    (y - i64::from(w.y_min)) as usize * image.width() + (x - i64::from(w.x_min)) as usize
}

fn deep_pixel_text(s: &mut String, image: &DeepImage, x: i64, y: i64) {
    let range = image.pixel_at(x, y).unwrap_or(0..0);
    let n = range.len();
    let _ = writeln!(
        s,
        "pixel ({x},{y}): {n} sample{}",
        if n == 1 { "" } else { "s" }
    );
    if range.is_empty() {
        return;
    }
    let names: Vec<&str> = image.channels().iter().map(|c| c.name.as_str()).collect();
    let _ = writeln!(s, "  {:>4}  {}", "#", names.join("  "));
    for (k, i) in range.enumerate() {
        let values: Vec<String> = (0..names.len())
            .map(|c| value_text(image.column(c), i))
            .collect();
        let _ = writeln!(s, "  {k:>4}  {}", values.join("  "));
    }
}

fn report_json(args: &Args, info: &FileInfo, pixels: &Pixels) -> serde_json::Value {
    let window =
        |w: &Box2i| json!({"x_min": w.x_min, "y_min": w.y_min, "x_max": w.x_max, "y_max": w.y_max});
    let mut v = json!({
        "file": args.file.display().to_string(),
        "deep": info.deep,
        "data_window": window(&info.data_window),
        "display_window": window(&info.display_window),
        "compression": info.compression.name(),
        "line_order": line_order_name(info.line_order),
        "channels": info.channels.iter().map(|c| json!({"name": c.name, "type": c.sample_type.name()})).collect::<Vec<_>>(),
        "attributes": other_attributes(info).map(|a| json!({"name": a.name, "type": a.type_name, "value": a.to_string()})).collect::<Vec<_>>(),
    });
    match pixels {
        Pixels::Deep(image) => {
            let st = strata_exr::stats(image);
            v["samples"] = json!({
                "total": st.samples,
                "pixels": st.pixels,
                "empty_pixels": st.empty_pixels,
                "mean_per_pixel": st.mean_per_pixel,
                "max_per_pixel": st.max_per_pixel,
                "max_at": [st.max_at.0, st.max_at.1],
                "histogram_pow2": st.histogram,
            });
            if let Some((x, y)) = args.pixel {
                let range = image.pixel_at(x, y).unwrap_or(0..0);
                let samples: Vec<serde_json::Value> = range
                    .map(|i| {
                        let mut m = serde_json::Map::new();
                        for (c, ch) in image.channels().iter().enumerate() {
                            m.insert(ch.name.clone(), json!(image.column(c).get_f64(i)));
                        }
                        serde_json::Value::Object(m)
                    })
                    .collect();
                v["pixel"] = json!({"x": x, "y": y, "samples": samples});
            }
        }
        Pixels::Flat(image) => {
            if let Some((x, y)) = args.pixel {
                let p = flat_index(image, x, y);
                let mut m = serde_json::Map::new();
                for c in image.channels() {
                    m.insert(c.name.clone(), json!(image.value(&c.name, p)));
                }
                v["pixel"] = json!({"x": x, "y": y, "values": m});
            }
        }
    }
    v
}
