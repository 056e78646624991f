//! Prints the k-buffer quality tables of issue 3 (Tsopouridis 2021 Fig. 4.5 / Table 5.1 style, Jähne 2014
//! Fig. 6.2 style):
//!
//! ```text
//! cargo run --release -p strata-stores --example kbuffer_tables [MODELS_DIR]
//! ```
//!
//! 1. vkbuffer with importance maps vs Optimal-K at budgets of 25/50/75 % of the scene's
//!    fragments: RMSE and bad pixels (a channel off by more than 2/255) against the A-buffer, on
//!    the built-in `slabs`, `spheres`, `mixed` and, when their meshes are found (in MODELS_DIR if
//!    given, else where the tests look: `$STRATA_MODEL_PATH`, `../shared/models` next to the
//!    workspace, the folder `scripts/fetch-models` fills), `bunny` and `dragon`, all at their
//!    scene size (1280×720). A mesh not found is said on stderr.
//! 2. The fixed k-buffer, plain and tail-blended: bad pixels against k = 1…12 on `spheres` and
//!    `dragon`, every object at alpha 0.5.
//!
//! Times are one run's wall clock on a shared machine: compare within a table only.

use std::path::PathBuf;

use strata_core::metrics::{bad_pixels, rmse};
use strata_core::{PassTimings, Rgb8Image};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::{Scene, SearchPath, open_scene};
use strata_stores::kbuffer::{KBuffer, VariableKBuffer};
use strata_stores::{Budget, FrameResult, KFrom, Method, MethodOptions, create, render_frame};

fn ms(t: &PassTimings, name: &str) -> f64 {
    t.get(name).map_or(0.0, |d| d.as_secs_f64() * 1e3)
}

fn run(method: &mut dyn Method, scene: &Scene) -> FrameResult {
    let input = FrameInput::from_scene(scene, 0);
    let mut raster = Rasterizer::default();
    render_frame(method, &mut raster, &input, scene.background).expect("render")
}

fn quality(image: &Rgb8Image, reference: &Rgb8Image) -> (f64, f64) {
    (
        rmse(image, reference).expect("same size"),
        100.0 * bad_pixels(image, reference, 2).expect("same size").share(),
    )
}

fn main() {
    let dirs: Vec<PathBuf> = match std::env::args().nth(1) {
        Some(dir) => vec![PathBuf::from(dir)],
        None => strata_testdata::models::SearchOrder::from_env()
            .places()
            .iter()
            .map(|p| p.dir.clone())
            .collect(),
    };
    let search = SearchPath::new(dirs);
    let mut names = vec!["slabs", "spheres", "mixed"];
    for (scene, file) in [("bunny", "bunny.obj"), ("dragon", "dragon_vrip.ply.gz")] {
        match search.resolve(file, None) {
            Ok(_) => names.push(scene),
            Err(tried) => eprintln!(
                "note: {file} not found (looked in {tried:?}); the {scene} rows are left out \
                 (pass MODELS_DIR, set STRATA_MODEL_PATH or run scripts/fetch-models)"
            ),
        }
    }

    println!(
        "## vkbuffer: importance maps vs Optimal-K (reference: abuffer; bad = channel > 2/255)\n"
    );
    println!(
        "| scene | fragments | budget | Σk | importance RMSE | importance bad % | Optimal-K RMSE | Optimal-K bad % | importance + k ms (rounds) | oracle ms |"
    );
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for name in &names {
        let scene = open_scene(name, &search).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut a = create("abuffer", &MethodOptions::default()).expect("abuffer");
        let reference = run(a.as_mut(), &scene);
        let total = reference.capture.fragments_stored;
        for share in [0.25, 0.5, 0.75] {
            let mut row = Vec::new();
            let mut sum = 0;
            let mut times = (0.0, 0.0);
            let mut rounds = 0;
            for k_from in [KFrom::Importance, KFrom::Optimal] {
                let mut v = VariableKBuffer::new(&MethodOptions {
                    budget: Budget::SceneShare(share),
                    k_from,
                    ..MethodOptions::default()
                });
                let r = run(&mut v, &scene);
                sum = v.allocation().sum;
                row.push(quality(&r.image, &reference.image));
                match k_from {
                    KFrom::Importance => {
                        times.0 =
                            ms(&r.timings, "capture.importance") + ms(&r.timings, "capture.k");
                        rounds = v.allocation().rounds;
                    }
                    KFrom::Optimal => times.1 = ms(&r.timings, "capture.k"),
                    // Not in this table (see docs/learned-k.md).
                    KFrom::Analytic | KFrom::Learned => {}
                }
            }
            println!(
                "| {name} | {total} | {:.0} % | {sum} | {:.4} | {:.2} | {:.4} | {:.2} | {:.1} ({rounds}) | {:.1} |",
                share * 100.0,
                row[0].0,
                row[0].1,
                row[1].0,
                row[1].1,
                times.0,
                times.1
            );
        }
    }

    // Per-pass times on the largest scene available, median of 5 frames.
    let big = *names.last().expect("scenes");
    let scene = open_scene(big, &search).unwrap_or_else(|e| panic!("{big}: {e}"));
    println!(
        "\n## per-pass ms on `{big}` ({}×{}), median of 5 frames\n",
        scene.width, scene.height
    );
    println!("| method | passes (ms) | total ms | memory MiB |");
    println!("| --- | --- | ---: | ---: |");
    let vk = |k_from| {
        VariableKBuffer::new(&MethodOptions {
            budget: Budget::SceneShare(0.5),
            k_from,
            ..MethodOptions::default()
        })
    };
    let methods: Vec<(&str, Box<dyn Method>)> = vec![
        (
            "abuffer",
            create("abuffer", &MethodOptions::default()).expect("abuffer"),
        ),
        ("kbuffer k=4", Box::new(KBuffer::with_k(4, false))),
        ("kbuffer k=4 tail-blend", Box::new(KBuffer::with_k(4, true))),
        ("vkbuffer 50% importance", Box::new(vk(KFrom::Importance))),
        ("vkbuffer 50% optimal", Box::new(vk(KFrom::Optimal))),
    ];
    for (label, mut m) in methods {
        let frames: Vec<FrameResult> = (0..5).map(|_| run(m.as_mut(), &scene)).collect();
        let median = |name: &str| {
            let mut v: Vec<f64> = frames.iter().map(|f| ms(&f.timings, name)).collect();
            v.sort_by(f64::total_cmp);
            v[2]
        };
        let passes: Vec<String> = frames[0]
            .timings
            .iter()
            .filter(|(n, _)| !matches!(*n, "capture.vertex" | "capture.setup"))
            .map(|(n, _)| format!("{n} {:.1}", median(n)))
            .collect();
        let total = median("clear") + median("capture") + median("resolve");
        println!(
            "| {label} | {} | {total:.1} | {:.1} |",
            passes.join(", "),
            frames[0].memory_bytes as f64 / (1u64 << 20) as f64
        );
    }

    println!("\n## kbuffer: bad pixels (% of the image, channel > 2/255) against k, alpha 0.5\n");
    let fixed: Vec<&str> = names
        .iter()
        .copied()
        .filter(|n| matches!(*n, "spheres" | "dragon"))
        .collect();
    print!("| k |");
    for name in &fixed {
        print!(" {name} | {name} tail-blend |");
    }
    println!();
    println!("| ---: |{}", " ---: | ---: |".repeat(fixed.len()));
    let mut scenes = Vec::new();
    for name in &fixed {
        let mut scene = open_scene(name, &search).unwrap_or_else(|e| panic!("{name}: {e}"));
        for o in &mut scene.objects {
            o.material.color[3] = 0.5;
        }
        let mut a = create("abuffer", &MethodOptions::default()).expect("abuffer");
        let reference = run(a.as_mut(), &scene);
        scenes.push((scene, reference));
    }
    for k in 1..=12 {
        print!("| {k} |");
        for (scene, reference) in &scenes {
            for tail_blend in [false, true] {
                let r = run(&mut KBuffer::with_k(k, tail_blend), scene);
                print!(" {:.2} |", quality(&r.image, &reference.image).1);
            }
        }
        println!();
    }
}
