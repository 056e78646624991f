//! The loaders on the real meshes (Stanford dragon, bunny, armadillo; the Khronos engine).
//!
//! The meshes are found by `strata_testdata::model` (`$STRATA_MODEL_PATH`, then
//! `../shared/models` next to the workspace, then the folder `scripts/fetch-models` fills); a
//! missing one is a visible `SKIPPED:` line, or a failure with `STRATA_REQUIRE_MODELS=1`.
//! Expected counts are those of the models' README.

use std::path::Path;
use std::time::Instant;

use strata_scene::load::{Format, Model, load_model};
use strata_testdata::models;

fn counts(m: &Model) -> (usize, usize) {
    m.parts.iter().fold((0, 0), |(v, t), p| {
        (v + p.mesh.positions().len(), t + p.mesh.triangles().len())
    })
}

/// Loads `path` (the model file `name`) and checks it is one part with these counts.
fn check(name: &str, path: &Path, vertices: usize, triangles: usize) {
    let m = load_model(path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.parts.len(), 1, "{name}");
    let part = &m.parts[0];
    assert_eq!(
        (part.mesh.positions().len(), part.mesh.triangles().len()),
        (vertices, triangles),
        "{name}"
    );
    assert!(!part.mesh.has_file_normals(), "{name} has no normals");
    assert_eq!(part.transform, glam::Mat4::IDENTITY);
    assert_eq!(part.base_color, None);
    let stem = name.split('.').next().unwrap_or_default();
    assert_eq!(part.name, stem);
}

/// [`check`] on the model file `name`, found by `strata_testdata`.
fn check_one(name: &str, vertices: usize, triangles: usize) {
    if let Some(path) = strata_testdata::model(name) {
        check(name, &path, vertices, triangles);
    }
}

#[test]
fn dragon_full_resolution() {
    check_one("dragon_vrip.ply.gz", 437_645, 871_414);
}

#[test]
fn dragon_decimated() {
    let expected = [
        ("dragon_vrip_res2.ply.gz", 100_250, 202_520),
        ("dragon_vrip_res3.ply.gz", 22_998, 47_794),
        ("dragon_vrip_res4.ply.gz", 5_205, 11_102),
    ];
    let Some(found) = models(&expected.map(|(name, ..)| name)) else {
        return;
    };
    for ((name, v, t), path) in expected.iter().zip(found.files()) {
        check(name, path, *v, *t);
    }
}

#[test]
fn bunny_obj() {
    check_one("bunny.obj", 34_835, 69_666);
}

#[test]
fn armadillo_off() {
    check_one("armadillo.off", 26_002, 52_000);
}

/// 2CylinderEngine: 82 nodes, 67 of them with a mesh, instancing 29 distinct meshes. The parts
/// add up to 84,657 vertices and 121,496 triangles; the distinct meshes to the README's 55,843
/// and 75,730.
#[test]
fn engine_glb() {
    let Some(path) = strata_testdata::model("2CylinderEngine.glb") else {
        return;
    };
    let m = load_model(&path).unwrap_or_else(|e| panic!("{e}"));
    let (v, t) = counts(&m);
    assert_eq!((m.parts.len(), v, t), (67, 84_657, 121_496));
    let mut distinct: Vec<&strata_scene::Mesh> = Vec::new();
    for p in &m.parts {
        if !distinct.iter().any(|d| **d == p.mesh) {
            distinct.push(&p.mesh);
        }
    }
    let v: usize = distinct.iter().map(|d| d.positions().len()).sum();
    let t: usize = distinct.iter().map(|d| d.triangles().len()).sum();
    assert_eq!((distinct.len(), v, t), (29, 55_843, 75_730));
    for p in &m.parts {
        assert!(p.transform.is_finite(), "{}", p.name);
        assert!(p.base_color.is_some(), "{} has a material", p.name);
        assert!(p.mesh.has_file_normals(), "{} has NORMAL", p.name);
    }
}

/// Same meshes through the sniffer: the content, not the extension, picks the parser.
#[test]
fn sniffing_matches_extensions() {
    let names = [
        "bunny.obj",
        "armadillo.off",
        "2CylinderEngine.glb",
        "dragon_vrip_res4.ply.gz",
    ];
    let Some(found) = models(&names) else { return };
    for (name, path) in names.iter().zip(found.files()) {
        let raw = std::fs::read(path).unwrap();
        let bytes = if name.ends_with(".gz") {
            let mut out = Vec::new();
            std::io::Read::read_to_end(&mut flate2_reader(&raw), &mut out).unwrap();
            out
        } else {
            raw
        };
        assert_eq!(
            Some(Format::sniff(&bytes)),
            Format::from_path(path),
            "{name}"
        );
    }
}

fn flate2_reader(raw: &[u8]) -> impl std::io::Read + '_ {
    flate2::read::MultiGzDecoder::new(raw)
}

/// Release-mode timings (not an assertion):
/// `cargo test --release -p strata-scene --test load_real -- --ignored --nocapture`.
#[test]
#[ignore = "timing report; run in release"]
fn timings() {
    let names = [
        "dragon_vrip.ply.gz",
        "dragon_vrip_res2.ply.gz",
        "bunny.obj",
        "armadillo.off",
        "2CylinderEngine.glb",
    ];
    let Some(found) = models(&names) else { return };
    for (name, path) in names.iter().zip(found.files()) {
        let mut best = f64::INFINITY;
        let mut what = (0, 0, 0);
        for _ in 0..5 {
            let t0 = Instant::now();
            let m = load_model(path).unwrap_or_else(|e| panic!("{e}"));
            best = best.min(t0.elapsed().as_secs_f64());
            let (v, t) = counts(&m);
            what = (m.parts.len(), v, t);
        }
        println!(
            "{name}: {:.1} ms (best of 5), {} parts, {} vertices, {} triangles",
            best * 1e3,
            what.0,
            what.1,
            what.2
        );
    }
}
