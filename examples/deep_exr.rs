//! strata as a library: scene → fragment store → DeepFrame → deep OpenEXR → image.
//!
//! ```sh
//! cargo run --release -p strata-examples --example deep_exr -- OUT_DIR [SCENE] [METHOD]
//! ```
//!
//! Renders a built-in scene (default `spheres`) with a fragment store (default `abuffer`, the
//! linked-list A-buffer), takes the sorted fragments of every pixel (the DeepFrame), writes them
//! as `OUT_DIR/SCENE.exr` (an OpenEXR deep scanline image any compositing tool reads), reads the
//! file back and checks that nothing was lost, and resolves the frame onto the scene's background
//! as `OUT_DIR/SCENE.png`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use strata_exr::{DepthMapping, FrameOptions, Limits, WriteOptions};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::SearchPath;
use strata_stores::{MethodOptions, render_frame};

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let Some(out_dir) = args.next().map(PathBuf::from) else {
        bail!("usage: deep_exr OUT_DIR [SCENE] [METHOD]");
    };
    let scene_name = args.next().unwrap_or_else(|| "spheres".to_owned());
    let method_name = args.next().unwrap_or_else(|| "abuffer".to_owned());
    std::fs::create_dir_all(&out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;

    // 1. The scene: a built-in name or a TOML file; meshes are looked up on the search path.
    let scene = strata_scene::open_scene(&scene_name, &SearchPath::from_env())?;

    // 2. Render one frame with a fragment store chosen by name.
    let mut method = strata_stores::create(&method_name, &MethodOptions::default())?;
    let mut raster = Rasterizer::default();
    let input = FrameInput::from_scene(&scene, 0);
    let result = render_frame(method.as_mut(), &mut raster, &input, scene.background)?;

    // 3. The DeepFrame: every pixel's fragments, sorted front to back.
    let Some(frame) = method.deep_frame() else {
        bail!("{method_name} keeps no fragments, so it has no DeepFrame");
    };
    let frame = frame?;

    // 4. As an OpenEXR deep image: premultiplied RGBA, Z as distance from the eye.
    let camera = &scene.camera;
    let depth = DepthMapping::new(f64::from(camera.near), f64::from(camera.far))?;
    let deep = strata_exr::deep_from_frame(&frame, depth, &FrameOptions::default())?;
    let exr_path = out_dir.join(format!("{scene_name}.exr"));
    strata_exr::write_deep_file(&exr_path, &deep, &WriteOptions::default())?;

    // 5. Read it back: with float channels the round trip is exact.
    let back = strata_exr::read_deep_file(&exr_path, &Limits::default())?;
    let again = strata_exr::frame_from_deep(&back, None)?;
    if again != frame {
        bail!(
            "the DeepFrame read back from {} differs",
            exr_path.display()
        );
    }

    // 6. Resolve: composite every run onto the background; the same image the store resolved.
    let image = frame.resolve(scene.background);
    if image != result.image {
        bail!("the DeepFrame's resolve differs from the store's");
    }
    let png_path = out_dir.join(format!("{scene_name}.png"));
    image.write_png(&png_path)?;

    println!(
        "{scene_name} with {method_name}: {}x{} pixels, {} fragments (at most {} in a pixel)",
        frame.width(),
        frame.height(),
        frame.fragment_count(),
        frame.depth_stats().max_depth_complexity()
    );
    println!("wrote {} and {}", exr_path.display(), png_path.display());
    Ok(())
}
