//! `strata mfr --volume`: the slow client rasterizes its static objects (the floor, static glass)
//! into deep fragments and ray-casts the scene's volume through them once; the fast client moves
//! the well path (and any moving glass) every frame, rasterizes it, re-casts only the rays whose
//! fragments it changes (the stencil) and is audited against the single renderer, bit for bit.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use glam::Vec3;
use strata_core::Rgb8Image;
use strata_volume::raster::{FragmentRaster, TriangleMesh, meshes};
use strata_volume::spec::{camera, glass, path, volume_scene};
use strata_volume::stencil::Renderer;

use super::Args;
use crate::options::{open_scene, search_path};

/// One FC frame's figures.
struct Frame {
    ms: f64,
    raster_ms: f64,
    recast: usize,
    samples: u64,
    bad: usize,
}

/// Runs the volume variant of `strata mfr`.
pub(crate) fn run(args: &Args) -> Result<()> {
    let scene = open_scene(&args.scene, &search_path(&args.model_dirs))?;
    let (width, height) = args.size.unwrap_or((scene.width, scene.height));
    let (vs, params) = volume_scene(&scene, width, height, args.volume_samples)
        .with_context(|| format!("cannot set up the volume of {}", args.scene))?;
    let Some(spec) = scene.volume.as_ref() else {
        bail!("scene {} has no [volume] table", args.scene);
    };
    let frames = args.frames.unwrap_or(8);
    if !(1..=10_000).contains(&frames) {
        bail!("--frames must be 1 to 10000 with --volume");
    }
    if let Some(dir) = &args.out_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let renderer = Renderer::new(&vs, params);
    let (view, projection) = camera(&scene, width, height);
    let mut raster = FragmentRaster::new(width, height, view, projection);
    let statics = meshes(&vs.statics, &vs.static_glass);
    let start = Instant::now();
    let sc = renderer.slow_from(raster.layer(renderer.rays(), &statics)?);
    let sc_ms = start.elapsed().as_secs_f64() * 1e3;
    save(args, "sc.png", width, height, &sc.image)?;
    let size = vs.placement.max - vs.placement.min;
    let mut records = Vec::new();
    for k in 0..frames {
        // The user drags the path (and the glass that moves with it) to and fro across the volume.
        let phase = std::f32::consts::TAU * k as f32 / frames as f32;
        let offset = Vec3::new(0.15 * size.x * phase.sin(), 0.0, 0.0);
        let interactive = meshes(&path(spec, offset), &glass(spec, true, offset));
        let start = Instant::now();
        let fc_fragments = raster.layer(renderer.rays(), &interactive)?;
        let raster_ms = start.elapsed().as_secs_f64() * 1e3;
        let fc = renderer.fast_from(&sc, &fc_fragments);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let bad = if args.no_audit {
            0
        } else {
            let all: Vec<TriangleMesh> = statics.iter().chain(&interactive).cloned().collect();
            let single = renderer.single_from(&raster.layer(renderer.rays(), &all)?);
            fc.image
                .iter()
                .zip(&single)
                .filter(|(a, b)| a.map(f32::to_bits) != b.map(f32::to_bits))
                .count()
        };
        save(args, &format!("frame-{k:04}.png"), width, height, &fc.image)?;
        records.push(Frame {
            ms,
            raster_ms,
            recast: fc.recast,
            samples: fc.samples,
            bad,
        });
    }
    let pixels = (width as usize * height as usize) as f64;
    let n = records.len() as f64;
    let fc_ms = records.iter().map(|r| r.ms).sum::<f64>() / n;
    let fc_raster_ms = records.iter().map(|r| r.raster_ms).sum::<f64>() / n;
    let share = records.iter().map(|r| r.recast as f64).sum::<f64>() / n / pixels;
    let fc_samples = records.iter().map(|r| r.samples).sum::<u64>() / records.len() as u64;
    let bad: usize = records.iter().map(|r| r.bad).sum();
    let dims = vs.volume.dims();
    let summary = serde_json::json!({
        "scene": scene.name,
        "width": width,
        "height": height,
        "volume": dims,
        "samples_per_diagonal": args.volume_samples.unwrap_or(spec.samples),
        "glass_boxes": spec.glass.len(),
        "step": params.step,
        "threads": rayon::current_num_threads(),
        "sc_full_cast_ms": sc_ms,
        "sc_samples": sc.samples,
        "fc_frames": records.len(),
        "fc_recast_ms_mean": fc_ms,
        "fc_recast_ms": records.iter().map(|r| r.ms).collect::<Vec<_>>(),
        "fc_raster_ms_mean": fc_raster_ms,
        "fc_recast_share": share,
        "fc_samples_mean": fc_samples,
        "audited": !args.no_audit,
        "bad_pixels": bad,
    });
    println!(
        "{}: {width}x{height}, volume {}x{}x{}, step {:.5} ({} samples along the diagonal), {} threads\n\
         SC full cast: {sc_ms:.1} ms, {} samples\n\
         FC stencil re-cast: {fc_ms:.2} ms a frame (mean of {}), {:.2}% of rays re-cast, {fc_samples} samples\n\
         {}",
        scene.name,
        dims[0],
        dims[1],
        dims[2],
        params.step,
        args.volume_samples.unwrap_or(spec.samples),
        rayon::current_num_threads(),
        sc.samples,
        records.len(),
        100.0 * share,
        if args.no_audit {
            "not audited (--no-audit)".to_owned()
        } else {
            format!("against the single renderer: {bad} pixels differ")
        }
    );
    if let Some(dir) = &args.out_dir {
        let path = dir.join("summary.json");
        std::fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// Writes `pixels` as an 8-bit PNG into `--out-dir` when `--save-frames` is given.
fn save(args: &Args, name: &str, width: u32, height: u32, pixels: &[[f32; 3]]) -> Result<()> {
    let (Some(dir), true) = (&args.out_dir, args.save_frames) else {
        return Ok(());
    };
    let bytes = pixels
        .iter()
        .flat_map(|p| p.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8))
        .collect();
    let path = Path::new(dir).join(name);
    Rgb8Image::from_raw(width, height, bytes)
        .context("image size does not match its pixels")?
        .write_png(&path)
        .with_context(|| format!("cannot write {}", path.display()))
}
