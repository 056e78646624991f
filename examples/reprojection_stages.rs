//! The reprojection node's stages timed alone, one frame after another: the render of normal
//! fragments (rasteriser, linked-list A-buffer, export), the encode of the delta against what
//! the display holds (`ReprojEncoder::encode`: move, sort, match, merge, digest, inserts), and
//! the wire encode of that delta into one message (`FrameEncoder::encode_reprojection_into`:
//! mask, removals and the inserts' sections in `CODEC`'s layout).
//!
//! ```sh
//! cargo run --release -p strata-examples --example reprojection_stages -- [THREADS] [FRAMES] [SCENE] [CODEC]
//! ```
//!
//! Renders `FRAMES` (default 24) frames of `SCENE` (default `dragon`, whose meshes are looked up
//! on `STRATA_MODEL_PATH`) at 1280×720 through the scene's camera and animation on `THREADS`
//! worker threads (default 1), encoding the inserts with `CODEC` (default `deep-lz4`; `strata
//! node` serves what the display asks for, `deep-huff` in `scripts/remote-stages`), as a render node serving the reprojection transfer does, but
//! without sockets or a second thread: the stages run one after the other, so each is timed
//! alone. Prints the median of each stage over the frames after the first (which sends
//! everything), the fragments held and inserted and the message's bytes in the last frame, and
//! a hash of every frame's message (the same for any thread count, and across builds that
//! change only speed).
//! `strata node` runs the stages side by side on the same worker threads.

use std::time::Instant;

use anyhow::{Context, Result, bail};
use strata_core::RunLimit;
use strata_raster::{FragmentOutput, FrameInput, Rasterizer};
use strata_remote::reprojection::{ReprojEncoder, View};
use strata_scene::SearchPath;
use strata_stores::{MethodOptions, export_frame};
use strata_wire::{Codec, FrameEncoder, FrameHeader, TransferMethod};

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let number = |arg: Option<String>, default: usize, what: &str| -> Result<usize> {
        match arg {
            None => Ok(default),
            Some(s) => match s.parse() {
                Ok(n) if n > 0 => Ok(n),
                _ => bail!("{what} must be a positive whole number, not '{s}'"),
            },
        }
    };
    let threads = number(args.next(), 1, "THREADS")?;
    let frames = number(args.next(), 24, "FRAMES")?;
    if frames < 2 {
        bail!("FRAMES must be at least 2: the first frame is not timed");
    }
    let scene_name = args.next().unwrap_or_else(|| "dragon".to_owned());
    let codec: Codec = match args.next() {
        None => Codec::DeepLz4,
        Some(s) => s.parse().map_err(|e| anyhow::anyhow!("CODEC: {e}"))?,
    };
    let scene = strata_scene::open_scene(&scene_name, &SearchPath::from_env())?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("cannot start the worker threads")?;
    let (width, height) = (1280, 720);
    let objects: Vec<_> = scene.objects.iter().map(|o| o.id).collect();
    let mut method = strata_stores::create("abuffer", &MethodOptions::default())?;
    let mut raster = Rasterizer::default();
    let mut encoder = ReprojEncoder::new(1);
    let mut wire = FrameEncoder::new();
    let mut message = Vec::new();
    let (mut render_ms, mut encode_ms, mut wire_ms) = (Vec::new(), Vec::new(), Vec::new());
    let (mut held, mut inserted) = (0, 0);
    // FNV-1a over every message, in order.
    let mut messages_hash = 0xcbf2_9ce4_8422_2325u64;
    let mut reuse = None;
    pool.install(|| -> Result<()> {
        for frame in 0..frames as u32 {
            let mut input = FrameInput::from_scene(&scene, frame);
            input.width = width;
            input.height = height;
            input.projection = scene.camera.projection(width, height);
            input.output = FragmentOutput::PackedNormal;
            let start = Instant::now();
            let exported = export_frame(
                method.as_mut(),
                &mut raster,
                &input,
                RunLimit::NONE,
                reuse.take(),
            )?;
            render_ms.push(start.elapsed().as_secs_f64() * 1e3);
            let view = View::new(
                &scene,
                &objects,
                frame,
                (width, height),
                input.view,
                input.projection,
            );
            let start = Instant::now();
            let delta = encoder.encode(&view, &exported.frame)?;
            encode_ms.push(start.elapsed().as_secs_f64() * 1e3);
            let header = FrameHeader {
                frame_number: u64::from(frame),
                view: input.view.to_cols_array(),
                projection: input.projection.to_cols_array(),
                transfer: TransferMethod::Reprojection,
                ..FrameHeader::default()
            };
            let start = Instant::now();
            wire.encode_reprojection_into(
                &mut message,
                &header,
                &delta.touched,
                &delta.removals,
                &delta.inserts,
                codec,
            )?;
            wire_ms.push(start.elapsed().as_secs_f64() * 1e3);
            for &b in &message {
                messages_hash = (messages_hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
            (held, inserted) = (delta.held, delta.inserts.fragment_count());
            // As the node does: the next frame is exported into this one's buffers, and the
            // next delta built in this one's.
            reuse = Some(exported.frame);
            encoder.recycle(delta);
        }
        Ok(())
    })?;
    let median = |v: &[f64]| {
        let mut s = v[1..].to_vec();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    };
    println!(
        "{scene_name} {width}x{height}, {threads} thread(s), median of {} frames: render {:.2} ms, \
         encode {:.2} ms, wire {:.2} ms; last frame held {held} fragments, inserted {inserted}, \
         {} bytes on the wire ({codec}); messages' hash {messages_hash:016x}",
        frames - 1,
        median(&render_ms),
        median(&encode_ms),
        median(&wire_ms),
        message.len(),
    );
    Ok(())
}
