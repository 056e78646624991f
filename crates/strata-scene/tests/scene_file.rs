//! The scene file of strata's shared conventions end to end: every key and its default, the transform order
//! `M = T · A(k) · R · S · F · N`, errors (with the key they name and the origin they report),
//! mesh resolution and sharing, glTF expansion into objects, and the built-in scenes.
//!
//! Mesh-dependent built-in scenes find the meshes through `strata-testdata` (skipped visibly when
//! absent, a failure with `STRATA_REQUIRE_MODELS=1`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use base64::Engine as _;
use glam::{Mat4, Vec3};
use strata_core::{Material, ObjectId, Shading};
use strata_scene::load::{LoadErrorKind, Location};
use strata_scene::scene::file::{self, MAX_IMAGE_SIDE, SceneOrigin};
use strata_scene::{
    Aabb, Animation, Camera, Scene, SceneError, SceneErrorKind, SceneObject, SearchPath, builtin,
    open_scene,
};

// ---------------------------------------------------------------------------------------------
// Helpers.

/// The origin the in-memory scenes below claim to come from.
const ORIGIN: &str = "scenes/test.toml";

/// A unit-size built-in object, for scenes that only test the other keys.
const QUAD: &str = "[[objects]]\nbuiltin = \"quad\"\n";

/// A triangle with bounds x ∈ [2, 6], y ∈ [0, 1], z ∈ [-1, 1]: centre (4, 0.5, 0), largest
/// extent 4 (along x).
const BOX_OBJ: &str = "v 2 0 -1\nv 6 1 1\nv 2 1 1\nf 1 2 3\n";

/// One triangle as ASCII PLY.
const TRIANGLE_PLY: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                            property float y\nproperty float z\nelement face 1\n\
                            property list uchar int vertex_indices\nend_header\n\
                            0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";

/// Parses `text` as if read from [`ORIGIN`], with an empty search path.
fn parse(text: &str) -> Result<Scene, SceneError> {
    file::parse(
        text,
        SceneOrigin::File(Path::new(ORIGIN)),
        &SearchPath::default(),
    )
}

/// Parses `text`, failing the test with the error's message.
fn scene(text: &str) -> Scene {
    parse(text).unwrap_or_else(|e| panic!("scene should parse: {e}\n---\n{text}"))
}

/// Parses `text`, which must fail; checks that the message starts with the origin.
fn error(text: &str) -> SceneError {
    match parse(text) {
        Ok(_) => panic!("scene should not parse:\n{text}"),
        Err(e) => {
            assert_eq!(e.origin, ORIGIN, "{e}");
            assert!(e.to_string().starts_with(&format!("{ORIGIN}: ")), "{e}");
            e
        }
    }
}

/// A range or consistency error at `key` whose message contains `contains`; also checks that
/// `Display` reads `"{origin}: line {n}: {key}: {message}"` (without the line when the key is
/// not in the text, nor any table around it).
#[track_caller]
fn invalid(text: &str, key: &str, contains: &str) -> SceneError {
    let e = error(text);
    assert_eq!(e.key.as_deref(), Some(key), "{e}");
    let SceneErrorKind::Invalid(msg) = &e.kind else {
        panic!("expected SceneErrorKind::Invalid, got {:?}", e.kind)
    };
    assert!(msg.contains(contains), "{msg:?} lacks {contains:?}");
    match e.at {
        Some(at) => {
            assert_eq!(at.column, None, "{e}");
            assert_eq!(e.to_string(), format!("{ORIGIN}: {at}: {key}: {msg}"));
        }
        None => assert_eq!(e.to_string(), format!("{ORIGIN}: {key}: {msg}")),
    }
    e
}

/// A TOML syntax or schema error at `line` whose message contains each of `contains`; the
/// message reads `"{origin}: line {n}, column {c}: [{key}: ]{message}"`.
#[track_caller]
fn toml_error(text: &str, line: u32, contains: &[&str]) -> SceneError {
    let e = error(text);
    let SceneErrorKind::Toml(msg) = &e.kind else {
        panic!("expected SceneErrorKind::Toml, got {:?}", e.kind)
    };
    assert_eq!(e.at.map(|a| a.line), Some(line), "{e}");
    assert!(
        e.to_string()
            .starts_with(&format!("{ORIGIN}: line {line}, column ")),
        "{e}"
    );
    for c in contains {
        assert!(msg.contains(c), "{msg:?} lacks {c:?}");
    }
    e
}

/// Writes `contents` to `dir/name` (creating parent folders) and returns the path.
fn write(dir: &Path, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).expect("create a folder in the temp dir");
    }
    std::fs::write(&path, contents).expect("write into the temp dir");
    path
}

fn temp_dir() -> tempfile::TempDir {
    tempfile::tempdir().expect("create a temp dir")
}

/// Loads the scene file at `path` with `search`, failing the test with the error's message.
fn load(path: &Path, search: &SearchPath) -> Scene {
    file::load(path, search).unwrap_or_else(|e| panic!("scene should load: {e}"))
}

/// Asserts that `m` maps the point `from` to `to`.
#[track_caller]
fn assert_maps(m: Mat4, from: [f32; 3], to: [f32; 3], what: &str) {
    let got = m.transform_point3(Vec3::from(from));
    assert!(
        got.abs_diff_eq(Vec3::from(to), 1e-5),
        "{what}: {from:?} maps to {got}, expected {to:?}"
    );
}

/// The static model matrix of the only object of a one-quad scene with `keys` added.
fn quad_matrix(keys: &str) -> Mat4 {
    let s = scene(&format!("{QUAD}{keys}\n"));
    assert_eq!(s.objects.len(), 1);
    s.objects[0].model_matrix(None, 0)
}

fn ids(s: &Scene) -> Vec<u32> {
    s.objects.iter().map(|o| o.id.0).collect()
}

fn names(s: &Scene) -> Vec<&str> {
    s.objects.iter().map(|o| o.name.as_str()).collect()
}

/// The bounding box of every object's mesh under its `base` (fit and glTF node) transform.
fn base_bounds(objects: &[SceneObject]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for o in objects {
        for p in o.mesh.positions() {
            b.include(o.base.transform_point3(Vec3::from(*p)));
        }
    }
    b
}

// ---------------------------------------------------------------------------------------------
// Every key, and the defaults.

/// Every key of strata's shared conventions, with values unlike the defaults.
const COMPLETE: &str = r#"
width = 800
height = 600
background = [0.25, 0.5, 0.75]

[camera]
eye = [1.0, 2.0, 3.0]
target = [0.5, -0.5, 0.25]
up = [0.0, 0.0, 1.0]
fovy_deg = 60.0
near = 0.5
far = 250.0

[[objects]]
name = "the box"
mesh = "box.obj"
fit = true
color = [0.2, 0.6, 1.0, 0.5]
shading = "unlit"
translate = [1.0, -2.0, 3.5]
rotate_deg = [10.0, 20.0, 30.0]
scale = 2.5

[[objects]]
name = "slab"
builtin = "slab"
fit = false
color = [1.0, 0.0, 0.25, 1.0]
shading = "headlight"
translate = [0.0, 0.0, -1.0]
rotate_deg = [0.0, 0.0, 0.0]
scale = [1.0, 2.0, 3.0]

[animation]
frames = 36
rotate_deg_per_frame = [1.0, 5.0, -2.0]
"#;

#[test]
fn a_complete_file_parses_to_exactly_its_values() {
    let dir = temp_dir();
    write(dir.path(), "box.obj", BOX_OBJ);
    let path = write(dir.path(), "complete.toml", COMPLETE);
    let s = load(&path, &SearchPath::default());

    assert_eq!(s.name, "complete");
    assert_eq!((s.width, s.height), (800, 600));
    assert_eq!(s.background, [0.25, 0.5, 0.75]);
    assert_eq!(
        s.camera,
        Camera {
            eye: Vec3::new(1.0, 2.0, 3.0),
            target: Vec3::new(0.5, -0.5, 0.25),
            up: Vec3::Z,
            fovy_deg: 60.0,
            near: 0.5,
            far: 250.0,
        }
    );
    assert_eq!(
        s.animation,
        Some(Animation {
            frames: 36,
            rotate_deg_per_frame: Vec3::new(1.0, 5.0, -2.0),
        })
    );
    assert_eq!(s.frame_count(), 36);
    assert_eq!(s.objects.len(), 2);
    assert_eq!(s.triangle_count(), 1 + 12);

    let boxed = &s.objects[0];
    assert_eq!(boxed.name, "the box");
    assert_eq!(boxed.id, ObjectId(0));
    assert_eq!(
        boxed.mesh.positions(),
        &[[2.0, 0.0, -1.0], [6.0, 1.0, 1.0], [2.0, 1.0, 1.0]]
    );
    assert_eq!(
        boxed.material,
        Material {
            color: [0.2, 0.6, 1.0, 0.5],
            shading: Shading::Unlit,
        }
    );
    assert_eq!(boxed.translate, Vec3::new(1.0, -2.0, 3.5));
    assert_eq!(boxed.rotate_deg, Vec3::new(10.0, 20.0, 30.0));
    assert_eq!(
        boxed.scale,
        Vec3::splat(2.5),
        "a scalar scale applies to every axis"
    );
    // fit = true: recentred on (4, 0.5, 0), largest extent 4 scaled to 1.
    assert!(
        boxed.base.abs_diff_eq(
            Mat4::from_scale(Vec3::splat(0.25)) * Mat4::from_translation(-Vec3::new(4.0, 0.5, 0.0)),
            1e-6
        ),
        "fit matrix {}",
        boxed.base
    );

    let slab = &s.objects[1];
    assert_eq!(slab.name, "slab");
    assert_eq!(slab.id, ObjectId(1));
    assert_eq!(slab.mesh.triangles().len(), 12);
    assert_eq!(
        slab.material,
        Material {
            color: [1.0, 0.0, 0.25, 1.0],
            shading: Shading::Headlight,
        }
    );
    assert_eq!(slab.translate, Vec3::new(0.0, 0.0, -1.0));
    assert_eq!(slab.rotate_deg, Vec3::ZERO);
    assert_eq!(slab.scale, Vec3::new(1.0, 2.0, 3.0));
    assert_eq!(
        slab.base,
        Mat4::IDENTITY,
        "fit = false leaves the mesh as it is"
    );
}

#[test]
fn design_example_values_survive_exactly() {
    // The strata's shared conventions block, with a built-in shape in place of the dragon.
    let s = scene(
        r#"
width = 1280
height = 720
background = [1.0, 1.0, 1.0]
[camera]
eye = [0.0, 0.0, 1.6]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fovy_deg = 45.0
near = 0.01
far = 100.0
[[objects]]
name = "dragon"
builtin = "sphere"
fit = true
color = [0.2, 0.6, 1.0, 0.5]
shading = "headlight"
translate = [0.0, 0.0, 0.0]
rotate_deg = [0.0, 0.0, 0.0]
scale = 1.0
[animation]
frames = 72
rotate_deg_per_frame = [0.0, 5.0, 0.0]
"#,
    );
    assert_eq!(s.camera.near, 0.01f32);
    assert_eq!(s.camera.eye, Vec3::new(0.0, 0.0, 1.6));
    assert_eq!(s.objects[0].material.color, [0.2, 0.6, 1.0, 0.5]);
    assert_eq!(s.frame_count(), 72);
}

#[test]
fn left_out_keys_take_the_documented_defaults() {
    let s = scene(QUAD);
    assert_eq!(s.name, "test", "a file's scene is named after its stem");
    assert_eq!((s.width, s.height), (1280, 720));
    assert_eq!(s.background, [1.0, 1.0, 1.0]);
    assert_eq!(
        s.camera,
        Camera {
            eye: Vec3::new(0.0, 0.0, 1.6),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fovy_deg: 45.0,
            near: 0.01,
            far: 100.0,
        }
    );
    assert_eq!(s.camera, Camera::default());
    assert_eq!(s.animation, None);
    assert_eq!(s.frame_count(), 1);

    let o = &s.objects[0];
    assert_eq!(o.name, "quad", "default name: the built-in shape's name");
    assert_eq!(o.id, ObjectId(0));
    assert_eq!(o.material.color, [0.8, 0.8, 0.8, 1.0]);
    assert_eq!(o.material.shading, Shading::Headlight);
    assert_eq!(o.material, Material::default());
    assert_eq!(o.translate, Vec3::ZERO);
    assert_eq!(o.rotate_deg, Vec3::ZERO);
    assert_eq!(o.scale, Vec3::ONE);
    assert_eq!(o.base, Mat4::IDENTITY, "fit defaults to false");
    assert_eq!(o.model_matrix(None, 0), Mat4::IDENTITY);
}

#[test]
fn a_partial_camera_keeps_the_other_defaults() {
    let s = scene(&format!(
        "[camera]\neye = [0.0, 3.0, 4.0]\nfar = 7.5\n{QUAD}"
    ));
    let d = Camera::default();
    assert_eq!(
        s.camera,
        Camera {
            eye: Vec3::new(0.0, 3.0, 4.0),
            far: 7.5,
            ..d
        }
    );
    // Integers are accepted where floats are expected.
    let s = scene(&format!(
        "width = 64\nheight = 48\nbackground = [0, 1, 0]\n[camera]\nfovy_deg = 90\n{QUAD}scale = 2\n"
    ));
    assert_eq!(s.background, [0.0, 1.0, 0.0]);
    assert_eq!(s.camera.fovy_deg, 90.0);
    assert_eq!(s.objects[0].scale, Vec3::splat(2.0));
}

#[test]
fn the_animation_rate_defaults_to_zero() {
    let s = scene(&format!("{QUAD}[animation]\nframes = 3\n"));
    assert_eq!(
        s.animation,
        Some(Animation {
            frames: 3,
            rotate_deg_per_frame: Vec3::ZERO,
        })
    );
}

#[test]
fn default_names_come_from_the_shape_or_the_mesh_file_stem() {
    let dir = temp_dir();
    write(dir.path(), "box.obj", BOX_OBJ);
    write(
        dir.path(),
        "models/dragon.ply.gz",
        gzip(TRIANGLE_PLY.as_bytes()),
    );
    write(dir.path(), "model.v2.obj", BOX_OBJ);
    let path = write(
        dir.path(),
        "names.toml",
        r#"
[[objects]]
builtin = "torus"
[[objects]]
mesh = "box.obj"
[[objects]]
mesh = "models/dragon.ply.gz"
[[objects]]
mesh = "model.v2.obj"
[[objects]]
name = "given"
mesh = "box.obj"
"#,
    );
    let s = load(&path, &SearchPath::default());
    assert_eq!(names(&s), ["torus", "box", "dragon", "model.v2", "given"]);
    assert_eq!(ids(&s), [0, 1, 2, 3, 4]);
    assert_eq!(
        s.objects[2].mesh.triangles().len(),
        1,
        "the .gz mesh was read"
    );
}

// ---------------------------------------------------------------------------------------------
// Transforms: M(k) = T · A(k) · R · S · F · N with R = Rz · Ry · Rx.

#[test]
fn rotate_deg_turns_about_each_axis() {
    // Rx(90): y → z, z → -y.
    let m = quad_matrix("rotate_deg = [90.0, 0.0, 0.0]");
    assert_maps(m, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], "Rx(90)");
    assert_maps(m, [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], "Rx(90)");
    assert_maps(m, [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], "Rx(90)");
    // Ry(90): x → -z, z → x.
    let m = quad_matrix("rotate_deg = [0.0, 90.0, 0.0]");
    assert_maps(m, [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], "Ry(90)");
    assert_maps(m, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], "Ry(90)");
    // Rz(90): x → y, y → -x.
    let m = quad_matrix("rotate_deg = [0.0, 0.0, 90.0]");
    assert_maps(m, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], "Rz(90)");
    assert_maps(m, [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], "Rz(90)");
}

#[test]
fn rotations_compose_as_rz_ry_rx() {
    // Rz(90) · Rx(90): z → -y (Rx) → x (Rz). Rx · Rz would give -y.
    let m = quad_matrix("rotate_deg = [90.0, 0.0, 90.0]");
    assert_maps(m, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], "Rz(90)·Rx(90)");
    assert_maps(m, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], "Rz(90)·Rx(90)");
    assert_maps(m, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], "Rz(90)·Rx(90)");
    // Rz(90) · Ry(90) · Rx(90): y → z (Rx) → x (Ry) → y (Rz).
    let m = quad_matrix("rotate_deg = [90.0, 90.0, 90.0]");
    assert_maps(m, [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], "Rz·Ry·Rx");
    // x → x (Rx) → -z (Ry) → -z (Rz).
    assert_maps(m, [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], "Rz·Ry·Rx");
    // z → -y (Rx) → -y (Ry) → x (Rz).
    assert_maps(m, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], "Rz·Ry·Rx");
}

#[test]
fn translate_moves_the_origin() {
    let m = quad_matrix("translate = [1.0, -2.0, 3.0]");
    assert_maps(m, [0.0, 0.0, 0.0], [1.0, -2.0, 3.0], "T");
    assert_maps(m, [0.5, 0.5, 0.0], [1.5, -1.5, 3.0], "T");
}

#[test]
fn scale_is_per_axis_or_uniform() {
    let m = quad_matrix("scale = [1.0, 2.0, 3.0]");
    assert_maps(m, [1.0, 1.0, 1.0], [1.0, 2.0, 3.0], "S = [1, 2, 3]");
    let m = quad_matrix("scale = 0.5");
    assert_maps(m, [1.0, -2.0, 4.0], [0.5, -1.0, 2.0], "S = 0.5");
}

#[test]
fn scale_then_rotate_then_translate() {
    // (1, 1, 1) → S (1, 2, 3) → Rz(90) (-2, 1, 3) → T (8, 1, 3).
    // R before S would give (9, 2, 3); T before R would give (-1, 11, 3).
    let m = quad_matrix(
        "scale = [1.0, 2.0, 3.0]\nrotate_deg = [0.0, 0.0, 90.0]\ntranslate = [10.0, 0.0, 0.0]",
    );
    assert_maps(m, [1.0, 1.0, 1.0], [8.0, 1.0, 3.0], "T·R·S");
    assert_maps(
        m,
        [0.0, 0.0, 0.0],
        [10.0, 0.0, 0.0],
        "T·R·S keeps the origin at translate",
    );
}

#[test]
fn fit_recentres_and_scales_before_scale_rotate_translate() {
    let dir = temp_dir();
    write(dir.path(), "box.obj", BOX_OBJ);
    let path = write(
        dir.path(),
        "fit.toml",
        r#"
[[objects]]
mesh = "box.obj"
fit = true
[[objects]]
name = "placed"
mesh = "box.obj"
fit = true
scale = [2.0, 4.0, 1.0]
rotate_deg = [0.0, 0.0, 90.0]
translate = [0.0, 0.0, 5.0]
[[objects]]
name = "raw"
mesh = "box.obj"
"#,
    );
    let s = load(&path, &SearchPath::default());
    let [fitted, placed, raw] = &s.objects[..] else {
        panic!("expected 3 objects, got {}", s.objects.len())
    };

    // Bounds [2,6]×[0,1]×[-1,1] → centred on 0, largest extent 1.
    let b = base_bounds(std::slice::from_ref(fitted));
    assert!(
        b.center().abs_diff_eq(Vec3::ZERO, 1e-6),
        "centre {}",
        b.center()
    );
    assert!(
        b.extent().abs_diff_eq(Vec3::new(1.0, 0.25, 0.5), 1e-6),
        "extent {}",
        b.extent()
    );
    let m = fitted.model_matrix(None, 0);
    assert_maps(m, [6.0, 1.0, 1.0], [0.5, 0.125, 0.25], "F");
    assert_maps(
        m,
        [4.0, 0.5, 0.0],
        [0.0, 0.0, 0.0],
        "F moves the centre to the origin",
    );

    // (6, 1, 1) → F (0.5, 0.125, 0.25) → S (1, 0.5, 0.25) → Rz(90) (-0.5, 1, 0.25) → T (…, 5.25).
    let m = placed.model_matrix(None, 0);
    assert_maps(m, [6.0, 1.0, 1.0], [-0.5, 1.0, 5.25], "T·R·S·F");
    assert_maps(m, [4.0, 0.5, 0.0], [0.0, 0.0, 5.0], "T·R·S·F");

    assert_eq!(raw.base, Mat4::IDENTITY);
    assert_maps(
        raw.model_matrix(None, 0),
        [6.0, 1.0, 1.0],
        [6.0, 1.0, 1.0],
        "no fit",
    );
}

#[test]
fn fit_needs_an_extent() {
    let dir = temp_dir();
    write(
        dir.path(),
        "point.obj",
        "v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n",
    );
    let path = write(
        dir.path(),
        "point.toml",
        "[[objects]]\nbuiltin = \"cube\"\n[[objects]]\nmesh = \"point.obj\"\nfit = true\n",
    );
    let e = file::load(&path, &SearchPath::default()).expect_err("a point cannot be fitted");
    assert_eq!(e.key.as_deref(), Some("objects[1].fit"), "{e}");
    assert!(matches!(e.kind, SceneErrorKind::Invalid(_)), "{e}");
    assert!(
        e.to_string().starts_with(&path.display().to_string()),
        "{e}"
    );
}

#[test]
fn animation_turns_each_object_about_its_own_origin() {
    let s = scene(&format!(
        "{QUAD}translate = [2.0, 0.0, 0.0]\n{QUAD}name = \"b\"\ntranslate = [0.0, 0.0, -3.0]\n\
         rotate_deg = [0.0, 0.0, 90.0]\n\
         [animation]\nframes = 72\nrotate_deg_per_frame = [0.0, 5.0, 0.0]\n"
    ));
    let anim = s.animation.as_ref();
    let (a, b) = (&s.objects[0], &s.objects[1]);
    // Frame 0 is the static placement.
    assert_eq!(a.model_matrix(anim, 0), a.model_matrix(None, 0));
    assert_eq!(
        a.model_matrix(None, 18),
        a.model_matrix(None, 0),
        "no animation, no spin"
    );
    for k in [0, 1, 18, 71] {
        assert_maps(
            a.model_matrix(anim, k),
            [0.0; 3],
            [2.0, 0.0, 0.0],
            "origin stays put",
        );
        assert_maps(
            b.model_matrix(anim, k),
            [0.0; 3],
            [0.0, 0.0, -3.0],
            "origin stays put",
        );
    }
    // Frame 18: 90° about y through the object's origin: (1, 0, 0) → (0, 0, -1), + T.
    assert_maps(
        a.model_matrix(anim, 18),
        [1.0, 0.0, 0.0],
        [2.0, 0.0, -1.0],
        "A(18)",
    );
    assert_maps(
        a.model_matrix(anim, 36),
        [1.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        "A(36)",
    );
    // Frame 1: 5°.
    let (sin, cos) = 5f32.to_radians().sin_cos();
    assert_maps(
        a.model_matrix(anim, 1),
        [1.0, 0.0, 0.0],
        [2.0 + cos, 0.0, -sin],
        "A(1)",
    );
    // A turns about the world axes after R: x → y (Rz 90) → y (Ry 90). R · A would give -z.
    assert_maps(
        b.model_matrix(anim, 18),
        [1.0, 0.0, 0.0],
        [0.0, 1.0, -3.0],
        "T·A·R",
    );
    assert_maps(
        b.model_matrix(anim, 18),
        [0.0, 1.0, 0.0],
        [0.0, 0.0, -2.0],
        "T·A·R",
    );
}

#[test]
fn animation_angles_compose_as_rz_ry_rx() {
    let s = scene(&format!(
        "{QUAD}[animation]\nframes = 10\nrotate_deg_per_frame = [45.0, 0.0, 45.0]\n"
    ));
    // Frame 2: Rz(90) · Rx(90), z → -y → x.
    let m = s.objects[0].model_matrix(s.animation.as_ref(), 2);
    assert_maps(m, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], "A(2)");
}

// ---------------------------------------------------------------------------------------------
// Errors: TOML syntax and schema.

#[test]
fn an_unknown_key_is_an_error_not_a_default() {
    let e = toml_error(
        &format!("{QUAD}{QUAD}colr = [1.0, 0.0, 0.0, 1.0]\n"),
        5,
        &["colr", "unknown field"],
    );
    assert!(
        e.to_string().contains("color"),
        "the message lists the known keys: {e}"
    );
    toml_error(
        "widht = 10\n[[objects]]\nbuiltin = \"quad\"\n",
        1,
        &["widht"],
    );
    toml_error(&format!("[camera]\nfov = 30.0\n{QUAD}"), 2, &["fov"]);
    toml_error(
        &format!("{QUAD}[animation]\nframes = 2\nspin = 1\n"),
        5,
        &["spin"],
    );
}

#[test]
fn a_wrong_type_is_an_error() {
    toml_error(&format!("width = \"wide\"\n{QUAD}"), 1, &["invalid type"]);
    invalid(
        &format!("width = -5\n{QUAD}"),
        "width",
        "-5 is outside 1..=16384 pixels",
    );
    toml_error(&format!("background = [1.0, 1.0]\n{QUAD}"), 1, &[]);
    toml_error(&format!("{QUAD}color = \"red\"\n"), 3, &["invalid type"]);
    toml_error(&format!("{QUAD}fit = 1\n"), 3, &["invalid type"]);
    toml_error(&format!("{QUAD}shading = \"phong\"\n"), 3, &["phong"]);
    toml_error(&format!("{QUAD}scale = [1.0, 2.0]\n"), 3, &[]);
    toml_error(&format!("{QUAD}scale = [1.0, 2.0, 3.0, 4.0]\n"), 3, &[]);
    toml_error(
        &format!("{QUAD}scale = \"big\"\n"),
        3,
        &["a number or an array of 3 numbers"],
    );
    toml_error(
        &format!("{QUAD}[animation]\nrotate_deg_per_frame = [0, 5, 0]\n"),
        3,
        &["frames"],
    );
    invalid(
        &format!("{QUAD}[animation]\nframes = -1\n"),
        "animation.frames",
        "-1 is outside 1..=4294967295",
    );
    invalid(
        &format!("{QUAD}[animation]\nframes = 4294967296\n"),
        "animation.frames",
        "4294967296 is outside",
    );
    toml_error(
        &format!("{QUAD}[animation]\nframes = 2.5\n"),
        4,
        &["invalid type"],
    );
    toml_error(&format!("height = 7.5\n{QUAD}"), 1, &["invalid type"]);
    toml_error("objects = 3\n", 1, &["invalid type"]);
}

#[test]
fn a_syntax_error_gives_the_line() {
    toml_error(&format!("width = 1280\nheight = \n{QUAD}"), 2, &[]);
    toml_error(&format!("{QUAD}color = [0.1, 0.2\n"), 3, &[]);
    toml_error(&format!("{QUAD}[[objects]\n"), 3, &[]);
}

// ---------------------------------------------------------------------------------------------
// Errors: ranges, named by key.

#[test]
fn image_size_is_checked() {
    invalid(
        &format!("width = 0\n{QUAD}"),
        "width",
        "0 is outside 1..=16384 pixels",
    );
    invalid(
        &format!("height = 0\n{QUAD}"),
        "height",
        "outside 1..=16384",
    );
    invalid(
        &format!("width = 20000\n{QUAD}"),
        "width",
        "20000 is outside",
    );
    invalid(
        &format!("height = 16385\n{QUAD}"),
        "height",
        "16385 is outside",
    );
    let s = scene(&format!("width = {MAX_IMAGE_SIDE}\nheight = 1\n{QUAD}"));
    assert_eq!((s.width, s.height), (16384, 1));
}

#[test]
fn background_must_be_in_unit_range() {
    invalid(
        &format!("background = [1.0, 1.5, 0.0]\n{QUAD}"),
        "background",
        "1.5 is outside [0, 1]",
    );
    invalid(
        &format!("background = [-0.25, 0.0, 0.0]\n{QUAD}"),
        "background",
        "-0.25",
    );
    invalid(
        &format!("background = [nan, 0.0, 0.0]\n{QUAD}"),
        "background",
        "NaN",
    );
}

#[test]
fn the_camera_must_look_somewhere_sensible() {
    let cam = |keys: &str| format!("[camera]\n{keys}\n{QUAD}");
    invalid(
        &cam("eye = [1.0, 2.0, 3.0]\ntarget = [1.0, 2.0, 3.0]"),
        "camera.target",
        "equals camera.eye",
    );
    // The default eye looks down -z: up along ±z is parallel to it.
    invalid(&cam("up = [0.0, 0.0, 1.0]"), "camera.up", "parallel");
    invalid(&cam("up = [0.0, 0.0, -2.0]"), "camera.up", "parallel");
    invalid(&cam("up = [0.0, 0.0, 0.0]"), "camera.up", "zero");
    invalid(
        &cam("eye = [2.0, 2.0, 2.0]\nup = [1.0, 1.0, 1.0]"),
        "camera.up",
        "parallel",
    );
    invalid(
        &cam("fovy_deg = 0.0"),
        "camera.fovy_deg",
        "0 is outside (0, 180) degrees",
    );
    invalid(
        &cam("fovy_deg = 180.0"),
        "camera.fovy_deg",
        "180 is outside",
    );
    invalid(&cam("fovy_deg = -10.0"), "camera.fovy_deg", "outside");
    invalid(&cam("fovy_deg = nan"), "camera.fovy_deg", "outside");
    invalid(
        &cam("near = 0.0"),
        "camera.near",
        "must be a finite distance greater than 0",
    );
    invalid(&cam("near = -1.0"), "camera.near", "greater than 0");
    invalid(
        &cam("near = 2.0\nfar = 2.0"),
        "camera.far",
        "greater than near (2)",
    );
    invalid(
        &cam("near = 2.0\nfar = 1.0"),
        "camera.far",
        "greater than near",
    );
    invalid(&cam("far = inf"), "camera.far", "finite");
    invalid(
        &cam("eye = [nan, 0.0, 1.0]"),
        "camera.eye",
        "not a finite number",
    );
    invalid(
        &cam("target = [0.0, inf, 0.0]"),
        "camera.target",
        "not a finite number",
    );
    // Extremes just inside the ranges are fine.
    let s = scene(&cam(
        "fovy_deg = 179.0\nnear = 1e-6\nfar = 1e-5\nup = [0.0, 0.001, 1.0]",
    ));
    assert_eq!(s.camera.fovy_deg, 179.0);
}

#[test]
fn a_scene_needs_objects() {
    invalid("width = 10\n", "objects", "no [[objects]]");
    invalid("objects = []\n", "objects", "no [[objects]]");
}

#[test]
fn an_object_names_exactly_one_of_mesh_and_builtin() {
    invalid(
        &format!("{QUAD}[[objects]]\nmesh = \"m.obj\"\nbuiltin = \"cube\"\n"),
        "objects[1]",
        "has both `mesh` and `builtin`",
    );
    invalid(
        &format!("{QUAD}[[objects]]\nbuiltin = \"cube\"\n[[objects]]\nname = \"nothing\"\n"),
        "objects[2]",
        "needs `mesh",
    );
}

#[test]
fn an_unknown_shape_lists_the_known_ones() {
    let e = error(&format!("{QUAD}[[objects]]\nbuiltin = \"teapot\"\n"));
    assert_eq!(e.key.as_deref(), Some("objects[1].builtin"), "{e}");
    let SceneErrorKind::UnknownBuiltin { what, name, known } = &e.kind else {
        panic!("expected UnknownBuiltin, got {:?}", e.kind)
    };
    assert_eq!((*what, name.as_str()), ("shape", "teapot"));
    assert_eq!(**known, ["quad", "cube", "slab", "sphere", "torus", "grid"]);
    assert_eq!(
        e.to_string(),
        "scenes/test.toml: line 4: objects[1].builtin: no built-in shape named 'teapot' \
         (known: quad, cube, slab, sphere, torus, grid)"
    );
}

#[test]
fn colours_must_be_in_unit_range() {
    let with = |c: &str| format!("{QUAD}{QUAD}name = \"b\"\ncolor = {c}\n");
    invalid(
        &with("[1.5, 0.0, 0.0, 1.0]"),
        "objects[1].color",
        "1.5 is outside [0, 1]",
    );
    invalid(&with("[0.0, 0.0, 0.0, 1.01]"), "objects[1].color", "1.01");
    invalid(&with("[0.0, -0.5, 0.0, 1.0]"), "objects[1].color", "-0.5");
    invalid(&with("[nan, 0.0, 0.0, 1.0]"), "objects[1].color", "NaN");
    invalid(&with("[0.0, 0.0, inf, 1.0]"), "objects[1].color", "inf");
    let s = scene(&with("[0.0, 1.0, 0.0, 0.0]"));
    assert_eq!(
        s.objects[1].material.color,
        [0.0, 1.0, 0.0, 0.0],
        "the bounds are inclusive"
    );
}

#[test]
fn placement_must_be_finite_and_scale_non_zero() {
    invalid(
        &format!("{QUAD}scale = 0\n"),
        "objects[0].scale",
        "must be a finite, non-zero factor",
    );
    invalid(
        &format!("{QUAD}scale = 0.0\n"),
        "objects[0].scale",
        "non-zero",
    );
    invalid(
        &format!("{QUAD}scale = [1.0, 0.0, 1.0]\n"),
        "objects[0].scale",
        "0 must be",
    );
    invalid(
        &format!("{QUAD}scale = nan\n"),
        "objects[0].scale",
        "finite",
    );
    invalid(
        &format!("{QUAD}scale = [1.0, 1.0, inf]\n"),
        "objects[0].scale",
        "finite",
    );
    invalid(
        &format!("{QUAD}translate = [0.0, inf, 0.0]\n"),
        "objects[0].translate",
        "finite",
    );
    invalid(
        &format!("{QUAD}rotate_deg = [nan, 0.0, 0.0]\n"),
        "objects[0].rotate_deg",
        "finite",
    );
}

#[test]
fn the_animation_is_checked() {
    invalid(
        &format!("{QUAD}[animation]\nframes = 0\n"),
        "animation.frames",
        "0 is outside 1..=4294967295",
    );
    invalid(
        &format!("{QUAD}[animation]\nframes = 2\nrotate_deg_per_frame = [0.0, inf, 0.0]\n"),
        "animation.rotate_deg_per_frame",
        "finite",
    );
}

#[test]
fn check_frame_accepts_existing_frames_only() {
    let s = scene(&format!("{QUAD}[animation]\nframes = 72\n"));
    for k in [0, 1, 71] {
        assert!(s.check_frame(k).is_ok(), "frame {k} exists");
    }
    let e = s.check_frame(72).expect_err("frame 72 of 0..71");
    assert_eq!(e.key.as_deref(), Some("animation.frames"), "{e}");
    assert!(matches!(e.kind, SceneErrorKind::Invalid(_)), "{e}");
    assert!(e.to_string().contains("frame 72 does not exist"), "{e}");
    assert!(e.to_string().contains("0..71"), "{e}");
    assert!(s.check_frame(u32::MAX).is_err());

    let s = scene(QUAD);
    assert!(s.check_frame(0).is_ok(), "a still scene has frame 0");
    let e = s
        .check_frame(1)
        .expect_err("a still scene has only frame 0");
    assert_eq!(e.key.as_deref(), Some("animation.frames"), "{e}");
    assert!(e.to_string().contains("no [animation]"), "{e}");
}

/// Every other scene error names its origin as the file path or `built-in scene 'x'`;
/// `Scene::check_frame` uses the scene's short name instead.
#[test]
fn check_frame_errors_name_the_scene_origin() {
    let dir = temp_dir();
    let path = write(
        dir.path(),
        "frames.toml",
        format!("{QUAD}[animation]\nframes = 2\n"),
    );
    let s = load(&path, &SearchPath::default());
    let e = s.check_frame(2).expect_err("frame 2 of 0..1");
    assert_eq!(e.origin, path.display().to_string(), "{e}");

    let s = builtin::load("slabs", &SearchPath::default()).unwrap_or_else(|e| panic!("{e}"));
    let e = s.check_frame(1000).expect_err("frame 1000 of 0..71");
    assert_eq!(e.origin, "built-in scene 'slabs'", "{e}");
}

#[test]
fn key_indices_count_file_objects_not_expanded_parts() {
    let dir = temp_dir();
    write(dir.path(), "pair.gltf", pair_gltf());
    let path = write(
        dir.path(),
        "index.toml",
        "[[objects]]\nmesh = \"pair.gltf\"\n[[objects]]\nbuiltin = \"cube\"\ncolor = [2.0, 0.0, 0.0, 1.0]\n",
    );
    let e = file::load(&path, &SearchPath::default()).expect_err("bad colour");
    assert_eq!(e.key.as_deref(), Some("objects[1].color"), "{e}");
}

#[test]
fn errors_name_built_in_scenes() {
    let e = file::parse(
        "width = 0\n",
        SceneOrigin::Builtin("demo"),
        &SearchPath::default(),
    )
    .expect_err("width 0");
    assert_eq!(e.origin, "built-in scene 'demo'");
    assert_eq!(
        e.to_string(),
        "built-in scene 'demo': line 1: width: 0 is outside 1..=16384 pixels"
    );
    let e = file::parse("nope", SceneOrigin::Builtin("demo"), &SearchPath::default())
        .expect_err("syntax");
    assert!(e.to_string().starts_with("built-in scene 'demo': "), "{e}");
    assert!(e.to_string().contains("line 1"), "{e}");
}

#[test]
fn an_unreadable_scene_file_is_an_io_error() {
    let dir = temp_dir();
    let path = dir.path().join("absent.toml");
    let e = file::load(&path, &SearchPath::default()).expect_err("no such file");
    assert!(matches!(e.kind, SceneErrorKind::Io(_)), "{e}");
    assert_eq!(e.key, None);
    assert_eq!(e.origin, path.display().to_string());
}

// ---------------------------------------------------------------------------------------------
// Mesh resolution and sharing.

#[test]
fn a_mesh_is_found_next_to_the_scene_file_first() {
    let scene_dir = temp_dir();
    let search_dir = temp_dir();
    write(scene_dir.path(), "m.obj", BOX_OBJ);
    write(
        search_dir.path(),
        "m.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    );
    let path = write(
        scene_dir.path(),
        "s.toml",
        "[[objects]]\nmesh = \"m.obj\"\n",
    );
    let search = SearchPath::new([search_dir.path().to_owned()]);
    let s = load(&path, &search);
    assert_eq!(
        s.objects[0].mesh.positions().len(),
        3,
        "the scene's own m.obj wins"
    );
    assert_eq!(s.objects[0].name, "m");
}

#[test]
fn a_mesh_is_found_along_the_search_path() {
    let scene_dir = temp_dir();
    let empty = temp_dir();
    let models = temp_dir();
    write(
        models.path(),
        "sub/quad.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    );
    let path = write(
        scene_dir.path(),
        "s.toml",
        "[[objects]]\nmesh = \"sub/quad.obj\"\n",
    );
    let search = SearchPath::new([empty.path().to_owned(), models.path().to_owned()]);
    let s = load(&path, &search);
    assert_eq!(s.objects[0].mesh.triangles().len(), 2);
    assert_eq!(s.objects[0].name, "quad");

    // An absolute path is used as it is.
    let abs = models.path().join("sub/quad.obj");
    let text = format!("[[objects]]\nmesh = {:?}\n", abs.display().to_string());
    let path = write(scene_dir.path(), "abs.toml", text);
    let s = load(&path, &SearchPath::default());
    assert_eq!(s.objects[0].mesh.triangles().len(), 2);
}

#[test]
fn a_missing_mesh_lists_every_place_tried() {
    let scene_dir = temp_dir();
    let a = temp_dir();
    let b = temp_dir();
    let path = write(
        scene_dir.path(),
        "s.toml",
        format!("{QUAD}[[objects]]\nmesh = \"gone.ply\"\n"),
    );
    let search = SearchPath::new([a.path().to_owned(), b.path().to_owned()]);
    let e = file::load(&path, &search).expect_err("gone.ply is nowhere");
    assert_eq!(e.key.as_deref(), Some("objects[1].mesh"), "{e}");
    assert_eq!(e.origin, path.display().to_string());
    let SceneErrorKind::MeshNotFound { name, tried } = &e.kind else {
        panic!("expected MeshNotFound, got {:?}", e.kind)
    };
    assert_eq!(name, "gone.ply");
    let expected = [
        scene_dir.path().join("gone.ply"),
        a.path().join("gone.ply"),
        b.path().join("gone.ply"),
    ];
    assert_eq!(tried, &expected);
    let shown = e.to_string();
    assert!(
        shown.starts_with(&format!(
            "{}: line 4: objects[1].mesh: cannot find mesh 'gone.ply'",
            path.display()
        )),
        "{shown}"
    );
    for p in &expected {
        assert!(
            shown.contains(&p.display().to_string()),
            "{shown} lacks {}",
            p.display()
        );
    }
    assert!(shown.contains("STRATA_MODEL_PATH"), "{shown}");
    assert!(shown.contains("scripts/fetch-models"), "{shown}");
}

#[test]
fn a_built_in_scene_without_a_search_path_looks_nowhere() {
    let e = file::parse(
        "[[objects]]\nmesh = \"bunny.obj\"\n",
        SceneOrigin::Builtin("b"),
        &SearchPath::default(),
    )
    .expect_err("no scene dir, empty search path");
    let SceneErrorKind::MeshNotFound { tried, .. } = &e.kind else {
        panic!("expected MeshNotFound, got {:?}", e.kind)
    };
    assert!(tried.is_empty(), "{tried:?}");
    assert!(
        e.to_string()
            .starts_with("built-in scene 'b': line 2: objects[0].mesh: "),
        "{e}"
    );
    assert!(e.to_string().contains("nowhere"), "{e}");
}

#[test]
fn a_malformed_mesh_names_the_file_and_line() {
    let dir = temp_dir();
    write(dir.path(), "bad.obj", "v 0 0 0\nv 1 0 0\nv 1 0\nf 1 2 3\n");
    let path = write(
        dir.path(),
        "s.toml",
        format!("{QUAD}[[objects]]\nmesh = \"bad.obj\"\n"),
    );
    let e = file::load(&path, &SearchPath::default()).expect_err("bad.obj is malformed");
    assert_eq!(e.key.as_deref(), Some("objects[1].mesh"), "{e}");
    let SceneErrorKind::Load(load) = &e.kind else {
        panic!("expected SceneErrorKind::Load, got {:?}", e.kind)
    };
    assert_eq!(load.location, Some(Location::Line(3)), "{e}");
    assert_eq!(load.path.file_name(), Some("bad.obj".as_ref()), "{e}");
    let shown = e.to_string();
    assert!(
        shown.starts_with(&format!("{}: line 4: objects[1].mesh: ", path.display())),
        "{shown}"
    );
    assert!(shown.contains("bad.obj: line 3: "), "{shown}");
}

#[test]
fn objects_naming_the_same_file_share_one_mesh() {
    let dir = temp_dir();
    write(dir.path(), "m.obj", BOX_OBJ);
    write(dir.path(), "other.obj", BOX_OBJ);
    let path = write(
        dir.path(),
        "s.toml",
        r#"
[[objects]]
mesh = "m.obj"
[[objects]]
name = "m fitted"
mesh = "m.obj"
fit = true
color = [1.0, 0.0, 0.0, 1.0]
[[objects]]
name = "m again"
mesh = "./m.obj"
[[objects]]
mesh = "other.obj"
[[objects]]
builtin = "sphere"
[[objects]]
name = "sphere 2"
builtin = "sphere"
"#,
    );
    let s = load(&path, &SearchPath::default());
    let o = &s.objects;
    assert!(Arc::ptr_eq(&o[0].mesh, &o[1].mesh), "same name, same mesh");
    assert!(
        Arc::ptr_eq(&o[0].mesh, &o[2].mesh),
        "same file by another path"
    );
    assert!(
        !Arc::ptr_eq(&o[0].mesh, &o[3].mesh),
        "another file with equal content"
    );
    assert_eq!(*o[0].mesh, *o[3].mesh);
    assert!(
        Arc::ptr_eq(&o[4].mesh, &o[5].mesh),
        "built-in shapes are shared too"
    );
    // Sharing the mesh does not share the per-object settings.
    assert_eq!(o[0].base, Mat4::IDENTITY);
    assert_ne!(o[1].base, Mat4::IDENTITY);
    assert_eq!(o[0].material.color, [0.8, 0.8, 0.8, 1.0]);
    assert_eq!(ids(&s), [0, 1, 2, 3, 4, 5]);
}

// ---------------------------------------------------------------------------------------------
// glTF: one object per mesh node.

fn f32s(values: &[[f32; 3]]) -> Vec<u8> {
    values
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

fn data_uri(bytes: &[u8]) -> String {
    format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// The unit quad `[0, 1]² × {0}` as positions (48 bytes) and u16 indices (12 bytes).
fn quad_bin() -> Vec<u8> {
    let mut bin = f32s(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ]);
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    bin
}

/// Two mesh nodes: "left" at the origin, its material's base colour (0.5, 0.25, 1, 0.75); and
/// "right" translated by (3, 0, 0), no material. Together they span [0, 4] × [0, 1] × {0}.
fn pair_gltf() -> String {
    let uri = data_uri(&quad_bin());
    format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0, 1]}}],
  "nodes": [
    {{"name": "left", "mesh": 0}},
    {{"name": "right", "translation": [3, 0, 0], "mesh": 1}}
  ],
  "meshes": [
    {{"name": "coloured", "primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1, "material": 0}}]}},
    {{"name": "plain", "primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1}}]}}
  ],
  "materials": [{{"pbrMetallicRoughness": {{"baseColorFactor": [0.5, 0.25, 1.0, 0.75]}}}}],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}},
    {{"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}}
  ],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 48, "byteLength": 12}}
  ],
  "buffers": [{{"byteLength": 60, "uri": "{uri}"}}]
}}"#
    )
}

/// Loads a scene (in a temp dir that holds `pair.gltf`) from `text`.
fn gltf_scene(text: &str) -> Scene {
    let dir = temp_dir();
    write(dir.path(), "pair.gltf", pair_gltf());
    let path = write(dir.path(), "g.toml", text);
    load(&path, &SearchPath::default())
}

#[test]
fn each_gltf_mesh_node_becomes_an_object() {
    let s = gltf_scene(
        r#"
[[objects]]
builtin = "cube"
[[objects]]
name = "pair"
mesh = "pair.gltf"
shading = "unlit"
translate = [0.0, 1.0, 0.0]
[[objects]]
name = "pair 2"
mesh = "pair.gltf"
color = [0.1, 0.2, 0.3, 0.4]
"#,
    );
    assert_eq!(
        ids(&s),
        [0, 1, 2, 3, 4],
        "consecutive ids over the expanded parts"
    );
    assert_eq!(
        names(&s),
        [
            "cube",
            "pair/left",
            "pair/right",
            "pair 2/left",
            "pair 2/right"
        ],
        "<name>/<node name>"
    );
    // The glTF base colour where the scene gives none; the default where the node has no
    // material; the scene colour over both.
    let colors: Vec<[f32; 4]> = s.objects.iter().map(|o| o.material.color).collect();
    assert_eq!(
        colors,
        [
            [0.8, 0.8, 0.8, 1.0],
            [0.5, 0.25, 1.0, 0.75],
            [0.8, 0.8, 0.8, 1.0],
            [0.1, 0.2, 0.3, 0.4],
            [0.1, 0.2, 0.3, 0.4],
        ]
    );
    // Every part carries the object's settings.
    for o in &s.objects[1..3] {
        assert_eq!(o.material.shading, Shading::Unlit, "{}", o.name);
        assert_eq!(o.translate, Vec3::Y, "{}", o.name);
    }
    // N: the node transform goes into `base`.
    assert_eq!(s.objects[1].base, Mat4::IDENTITY);
    assert_maps(s.objects[2].base, [0.0; 3], [3.0, 0.0, 0.0], "node 'right'");
    assert_maps(
        s.objects[2].model_matrix(None, 0),
        [1.0, 1.0, 0.0],
        [4.0, 2.0, 0.0],
        "T·N",
    );
    // Parts are shared between the two objects naming the file.
    assert!(Arc::ptr_eq(&s.objects[1].mesh, &s.objects[3].mesh));
    assert!(Arc::ptr_eq(&s.objects[2].mesh, &s.objects[4].mesh));
}

#[test]
fn fit_spans_all_gltf_nodes_together() {
    let s = gltf_scene("[[objects]]\nmesh = \"pair.gltf\"\nfit = true\nscale = 2.0\n");
    assert_eq!(
        names(&s),
        ["pair/left", "pair/right"],
        "the name defaults to the file stem"
    );
    let b = base_bounds(&s.objects);
    assert!(
        b.center().abs_diff_eq(Vec3::ZERO, 1e-6),
        "centre {}",
        b.center()
    );
    assert!(
        b.extent().abs_diff_eq(Vec3::new(1.0, 0.25, 0.0), 1e-6),
        "extent {}",
        b.extent()
    );
    // F · N: the whole model's box [0, 4] × [0, 1] is centred on (2, 0.5) and scaled by 1/4.
    let (left, right) = (&s.objects[0], &s.objects[1]);
    assert_maps(left.base, [0.0; 3], [-0.5, -0.125, 0.0], "F·N left");
    assert_maps(right.base, [1.0, 1.0, 0.0], [0.5, 0.125, 0.0], "F·N right");
    // S after F: doubled.
    assert_maps(
        right.model_matrix(None, 0),
        [1.0, 1.0, 0.0],
        [1.0, 0.25, 0.0],
        "S·F·N right",
    );
}

#[test]
fn a_single_node_gltf_keeps_the_plain_name() {
    let dir = temp_dir();
    let one = pair_gltf().replace(r#""nodes": [0, 1]"#, r#""nodes": [1]"#);
    write(dir.path(), "one.gltf", one);
    let path = write(dir.path(), "g.toml", "[[objects]]\nmesh = \"one.gltf\"\n");
    let s = load(&path, &SearchPath::default());
    assert_eq!(names(&s), ["one"]);
    assert_maps(
        s.objects[0].base,
        [0.0; 3],
        [3.0, 0.0, 0.0],
        "node transform kept",
    );
}

// ---------------------------------------------------------------------------------------------
// Built-in scenes and open_scene.

#[test]
fn built_in_scene_names_are_unique_and_found() {
    let mut seen = Vec::new();
    for b in builtin::SCENES {
        assert!(!seen.contains(&b.name), "{} twice", b.name);
        seen.push(b.name);
        let found = builtin::find(b.name).map(|f| f.name);
        assert_eq!(found, Some(b.name));
        assert!(!b.description.is_empty(), "{}", b.name);
    }
    assert!(builtin::find("no-such-scene").is_none());
    // Self-contained scenes come first.
    let first_mesh = builtin::SCENES.iter().position(|b| !b.meshes.is_empty());
    if let Some(i) = first_mesh {
        assert!(builtin::SCENES[i..].iter().all(|b| !b.meshes.is_empty()));
    }
}

/// Checks what every built-in scene must satisfy once loaded.
fn check_builtin(b: &builtin::BuiltinScene, s: &Scene) {
    assert_eq!(s.name, b.name);
    if s.volume.is_some() {
        // A volume scene draws its volume, floor and well path, not meshes.
        assert!(s.objects.is_empty(), "{}", b.name);
        return;
    }
    assert!(!s.objects.is_empty(), "{}", b.name);
    let expected: Vec<u32> = (0..s.objects.len() as u32).collect();
    assert_eq!(ids(s), expected, "{}: consecutive ids", b.name);
    assert!(s.triangle_count() > 0, "{}", b.name);
    for o in &s.objects {
        assert!(
            o.model_matrix(s.animation.as_ref(), s.frame_count() - 1)
                .is_finite(),
            "{}",
            o.name
        );
    }
}

#[test]
fn self_contained_built_in_scenes_parse() {
    let nothing = SearchPath::default();
    let mut count = 0;
    for b in builtin::SCENES.iter().filter(|b| b.meshes.is_empty()) {
        assert!(b.available(&nothing), "{}", b.name);
        let s = b.load(&nothing).unwrap_or_else(|e| panic!("{e}"));
        check_builtin(b, &s);
        count += 1;
    }
    assert!(
        count >= 5,
        "slabs, spheres, mixed, overlap, mfr-cars: {count}"
    );
    // Spot checks against the scene texts.
    let s = builtin::load("overlap", &nothing).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((s.width, s.height), (640, 480));
    assert_eq!(names(&s), ["red", "blue"]);
    assert_eq!(s.objects[0].material.color, [1.0, 0.0, 0.0, 0.5]);
    assert_eq!(s.objects[0].material.shading, Shading::Unlit);
    assert_eq!(s.animation, None);
    let s = builtin::load("spheres", &nothing).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.objects.len(), 6);
}

#[test]
fn mesh_built_in_scenes_need_their_meshes() {
    let nothing = SearchPath::default();
    for b in builtin::SCENES.iter().filter(|b| !b.meshes.is_empty()) {
        assert!(!b.available(&nothing), "{}", b.name);
        let e = b.load(&nothing).expect_err("no meshes anywhere");
        assert!(matches!(e.kind, SceneErrorKind::MeshNotFound { .. }), "{e}");
        let key = if b.name.starts_with("volume-") {
            "volume.file"
        } else {
            "objects[0].mesh"
        };
        assert_eq!(e.key.as_deref(), Some(key), "{e}");
        assert_eq!(e.origin, format!("built-in scene '{}'", b.name));
    }
}

#[test]
fn mesh_built_in_scenes_parse_with_the_shared_models() {
    let meshes: Vec<&str> = builtin::SCENES
        .iter()
        .flat_map(|b| b.meshes.iter().copied())
        .collect();
    // Every mesh every built-in scene needs: missing ones skip visibly, or fail in CI.
    let Some(models) = strata_testdata::models(&meshes) else {
        return;
    };
    let search = SearchPath::new(models.dirs());
    for b in builtin::SCENES.iter().filter(|b| !b.meshes.is_empty()) {
        assert!(b.available(&search), "{} needs {:?}", b.name, b.meshes);
        let s = b.load(&search).unwrap_or_else(|e| panic!("{e}"));
        check_builtin(b, &s);
        if s.volume.is_some() {
            continue;
        }
        // Every mesh scene fits its model: centred, largest extent 1, over all its parts.
        let bounds = base_bounds(&s.objects);
        assert!(
            bounds.center().abs_diff_eq(Vec3::ZERO, 1e-4),
            "{}: centre {}",
            b.name,
            bounds.center()
        );
        assert!(
            (bounds.extent().max_element() - 1.0).abs() < 1e-4,
            "{}: extent {}",
            b.name,
            bounds.extent()
        );
        if b.name == "engine" || b.name == "mfr-engine" {
            assert_eq!(s.objects.len(), 67, "one object per mesh node");
            assert!(
                s.objects.iter().all(|o| o.name.starts_with("engine/")),
                "{:?}",
                names(&s)
            );
            assert!(
                s.objects
                    .iter()
                    .all(|o| o.material.color == [0.85, 0.65, 0.3, 0.5])
            );
        } else {
            assert_eq!(names(&s), [b.name]);
        }
    }
}

#[test]
fn open_scene_picks_built_ins_by_name() {
    let s = open_scene("slabs", &SearchPath::default()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.name, "slabs");
    assert_eq!(names(&s), ["red", "green", "blue", "yellow"]);
    assert_eq!(s.frame_count(), 72);

    let e = open_scene("no-such-scene", &SearchPath::default()).expect_err("unknown name");
    assert_eq!(e.key, None);
    let SceneErrorKind::UnknownBuiltin { what, name, known } = &e.kind else {
        panic!("expected UnknownBuiltin, got {:?}", e.kind)
    };
    assert_eq!((*what, name.as_str()), ("scene", "no-such-scene"));
    let all: Vec<&str> = builtin::SCENES.iter().map(|b| b.name).collect();
    assert_eq!(**known, *all);
    for n in &all {
        assert!(e.to_string().contains(n), "{e} lacks {n}");
    }
}

#[test]
fn open_scene_treats_paths_as_files() {
    for spec in ["missing/file.toml", "missing.toml", "slabs.toml"] {
        let e = open_scene(spec, &SearchPath::default()).expect_err("no such file");
        assert!(matches!(e.kind, SceneErrorKind::Io(_)), "{spec}: {e}");
        assert_eq!(e.origin, spec, "{e}");
        assert!(e.to_string().starts_with(&format!("{spec}: ")), "{e}");
    }
    let dir = temp_dir();
    let path = write(
        dir.path(),
        "mine.toml",
        format!("width = 32\nheight = 16\n{QUAD}"),
    );
    let spec = path.to_str().expect("a UTF-8 temp path");
    let s = open_scene(spec, &SearchPath::default()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((s.name.as_str(), s.width, s.height), ("mine", 32, 16));
}

// ---------------------------------------------------------------------------------------------

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut gz, bytes).expect("gzip into memory");
    gz.finish().expect("gzip into memory")
}

// ---------------------------------------------------------------------------------------------
// Errors: arrays are counted whole, and every error has its line.

/// A TOML-level error at `key` on `line`, whose message contains `contains`; checks how it reads.
#[track_caller]
fn toml_error_at(text: &str, line: u32, key: &str, contains: &str) -> SceneError {
    let e = toml_error(text, line, &[contains]);
    assert_eq!(e.key.as_deref(), Some(key), "{e}");
    let SceneErrorKind::Toml(msg) = &e.kind else {
        unreachable!("toml_error checked the kind")
    };
    let at = e.at.expect("a TOML error has a position");
    assert!(at.column.is_some(), "{e}");
    assert_eq!(e.to_string(), format!("{ORIGIN}: {at}: {key}: {msg}"));
    e
}

/// Every array-valued key: a scene text with `value` at the key, the key's line and the
/// number of elements the key takes.
fn array_keys(value: &str) -> [(String, u32, &'static str, usize); 9] {
    let camera = |k: &str| format!("[camera]\n{k} = {value}\n{QUAD}");
    let object = |k: &str| format!("{QUAD}{k} = {value}\n");
    [
        (format!("background = {value}\n{QUAD}"), 1, "background", 3),
        (camera("eye"), 2, "camera.eye", 3),
        (camera("target"), 2, "camera.target", 3),
        (camera("up"), 2, "camera.up", 3),
        (object("color"), 3, "objects[0].color", 4),
        (object("translate"), 3, "objects[0].translate", 3),
        (object("rotate_deg"), 3, "objects[0].rotate_deg", 3),
        (object("scale"), 3, "objects[0].scale", 3),
        (
            format!("{QUAD}[animation]\nframes = 2\nrotate_deg_per_frame = {value}\n"),
            5,
            "animation.rotate_deg_per_frame",
            3,
        ),
    ]
}

#[test]
fn the_reported_overlong_arrays_are_errors() {
    toml_error_at(
        &format!("background = [1.0, 1.0, 1.0, 0.5]\n{QUAD}"),
        1,
        "background",
        "expected an array of 3 numbers, found 4 values",
    );
    toml_error_at(
        &format!("{QUAD}color = [1, 0, 0, 0.5, 7]\n"),
        3,
        "objects[0].color",
        "expected an array of 4 numbers, found 5 values",
    );
    toml_error_at(
        &format!("[camera]\neye = [0, 0, 3, 99]\n{QUAD}"),
        2,
        "camera.eye",
        "expected an array of 3 numbers, found 4 values",
    );
    let e = toml_error_at(
        &format!("{QUAD}translate = [0.5, 0, 0, \"junk\"]\n"),
        3,
        "objects[0].translate",
        "expected an array of 3 numbers, found 4 values",
    );
    assert_eq!(
        e.to_string(),
        "scenes/test.toml: line 3, column 13: objects[0].translate: \
         expected an array of 3 numbers, found 4 values"
    );
}

#[test]
fn every_array_key_takes_exactly_its_length() {
    for n in 0..=5usize {
        let value = format!("[{}]", vec!["0.5"; n].join(", "));
        for (text, line, key, len) in array_keys(&value) {
            if n == len {
                scene(&text);
            } else {
                let plural = if n == 1 { "" } else { "s" };
                toml_error_at(
                    &text,
                    line,
                    key,
                    &format!("expected an array of {len} numbers, found {n} value{plural}"),
                );
            }
        }
    }
    // A wrong type inside the length names the key too; one past it is counted, whatever it is.
    for (text, line, key, _) in array_keys("[0.5, \"x\", 0.5]") {
        toml_error_at(&text, line, key, "invalid type: string \"x\"");
    }
    for (text, line, key, len) in array_keys("[0.5, 0.5, 0.5, 0.5, [1, 2]]") {
        toml_error_at(&text, line, key, &format!("{len} numbers, found 5 values"));
    }
}

#[test]
fn an_unknown_key_names_itself_and_its_line() {
    let e = toml_error(
        &format!("{QUAD}{QUAD}colr = [1.0, 0.0, 0.0, 1.0]\n"),
        5,
        &["colr"],
    );
    assert_eq!(e.at.map(|a| a.line), Some(5), "{e}");
    assert_eq!(e.key.as_deref(), Some("objects[1].colr"), "{e}");
    let e = toml_error(
        "[camera]\nfovy = 30.0\n[[objects]]\nbuiltin = \"quad\"\n",
        2,
        &["fovy"],
    );
    assert_eq!(e.key.as_deref(), Some("camera.fovy"), "{e}");
    let e = toml_error(
        &format!("{QUAD}[animations]\nframes = 2\n"),
        3,
        &["animations"],
    );
    assert_eq!(e.key.as_deref(), Some("animations"), "{e}");
}

#[test]
fn range_errors_give_the_line_of_their_key() {
    let e = invalid(
        &format!("width = 64\n\n{QUAD}{QUAD}name = \"b\"\ncolor = [0.5, 1.5, 0.0, 1.0]\n"),
        "objects[1].color",
        "1.5 is outside [0, 1]",
    );
    assert_eq!(e.at.map(|a| (a.line, a.column)), Some((8, None)), "{e}");
    assert_eq!(
        e.to_string(),
        "scenes/test.toml: line 8: objects[1].color: 1.5 is outside [0, 1]"
    );
    // A default that is wrong only with another key: the line of its table.
    let e = invalid(
        &format!("\n[camera]\neye = [0.0, 5.0, 0.0]\n{QUAD}"),
        "camera.up",
        "parallel",
    );
    assert_eq!(e.at.map(|a| a.line), Some(2), "{e}");
    // A key of the whole file that is absent: no line.
    let e = invalid("width = 10\n", "objects", "no [[objects]]");
    assert_eq!(e.at, None, "{e}");
}

// ---------------------------------------------------------------------------------------------
// Object names.

#[test]
fn object_names_are_unique_and_both_places_are_named() {
    let e = invalid(
        "[[objects]]\nname = \"a\"\nbuiltin = \"quad\"\n[[objects]]\nname = \"b\"\n\
         builtin = \"cube\"\n[[objects]]\nbuiltin = \"cube\"\nname = \"a\"\n",
        "objects[2].name",
        "'a' is already the name of objects[0] (line 2); objects are selected by name",
    );
    assert_eq!(e.at.map(|a| a.line), Some(9), "{e}");

    // Default names count: two objects of one shape or file need names.
    let e = invalid(
        &format!("{QUAD}{QUAD}"),
        "objects[1]",
        "'quad' (the default name, from `mesh` or `builtin`) is already the name of objects[0] \
         (line 1); objects are selected by name, so set `name` to tell them apart",
    );
    assert_eq!(e.at.map(|a| a.line), Some(3), "{e}");
    invalid(
        "[[objects]]\nname = \"cube\"\nbuiltin = \"quad\"\n[[objects]]\nbuiltin = \"cube\"\n",
        "objects[1]",
        "'cube' (the default name",
    );
    // Names are compared exactly; distinct names for one shape are fine.
    let s = scene(&format!(
        "{QUAD}{QUAD}name = \"Quad\"\n{QUAD}name = \"quad 2\"\n"
    ));
    assert_eq!(names(&s), ["quad", "Quad", "quad 2"]);
}

#[test]
fn object_names_are_not_empty_and_not_numbers() {
    invalid(
        "[[objects]]\nname = \" \"\nbuiltin = \"quad\"\n",
        "objects[0].name",
        "is empty",
    );
    invalid(
        "[[objects]]\nname = \"2\"\nbuiltin = \"quad\"\n",
        "objects[0].name",
        "'2' is a number, which would read as an object's position",
    );
    let dir = temp_dir();
    write(dir.path(), "7.obj", BOX_OBJ);
    let path = write(dir.path(), "s.toml", "[[objects]]\nmesh = \"7.obj\"\n");
    let e = file::load(&path, &SearchPath::default()).expect_err("a numeric default name");
    assert_eq!(e.key.as_deref(), Some("objects[0]"), "{e}");
    assert!(e.to_string().contains("'7' (the default name"), "{e}");
    assert!(e.to_string().contains("set `name`"), "{e}");
    // Digits among letters are a name.
    scene("[[objects]]\nname = \"7b\"\nbuiltin = \"quad\"\n");
}

#[test]
fn gltf_parts_that_share_a_node_name_are_numbered() {
    let dir = temp_dir();
    write(
        dir.path(),
        "twins.gltf",
        pair_gltf().replace("\"right\"", "\"left\""),
    );
    let path = write(dir.path(), "s.toml", "[[objects]]\nmesh = \"twins.gltf\"\n");
    let s = load(&path, &SearchPath::default());
    assert_eq!(names(&s), ["twins/left", "twins/left#2"]);
    // A part's name that another object already has is an error naming both.
    let path = write(
        dir.path(),
        "clash.toml",
        "[[objects]]\nname = \"twins/left#2\"\nbuiltin = \"quad\"\n\n[[objects]]\nmesh = \"twins.gltf\"\n",
    );
    let e = file::load(&path, &SearchPath::default()).expect_err("a clash with a part name");
    assert_eq!(e.key.as_deref(), Some("objects[1]"), "{e}");
    assert_eq!(e.at.map(|a| a.line), Some(5), "{e}");
    assert!(
        e.to_string().contains(
            "makes an object named 'twins/left#2', a name objects[0] (line 2) already gave"
        ),
        "{e}"
    );
}

// ---------------------------------------------------------------------------------------------
// Negative scale.

#[test]
fn a_negative_scale_mirrors() {
    let s = scene(&format!(
        "{QUAD}scale = [-1.0, 1.0, 1.0]\ntranslate = [0.0, 0.0, -1.0]\n"
    ));
    let m = s.objects[0].model_matrix(None, 0);
    assert_maps(m, [0.5, 0.25, 0.0], [-0.5, 0.25, -1.0], "mirrored in x");
    assert!(m.determinant() < 0.0, "a reflection");
    let s = scene(&format!("{QUAD}scale = -2\n"));
    assert_eq!(s.objects[0].scale, Vec3::splat(-2.0));
    // Zero is still refused, with the range in the message.
    invalid(
        &format!("{QUAD}scale = [1.0, -0.0, 1.0]\n"),
        "objects[0].scale",
        "must be a finite, non-zero factor (a negative one mirrors)",
    );
}

// ---------------------------------------------------------------------------------------------
// Mesh files named by a scene.

#[test]
fn a_mesh_that_is_a_directory_says_so() {
    let dir = temp_dir();
    std::fs::create_dir(dir.path().join("bunny.ply")).expect("mkdir");
    let path = write(dir.path(), "s.toml", "[[objects]]\nmesh = \"bunny.ply\"\n");
    let e = file::load(&path, &SearchPath::default()).expect_err("a directory");
    assert_eq!(e.key.as_deref(), Some("objects[0].mesh"), "{e}");
    assert_eq!(e.at.map(|a| a.line), Some(2), "{e}");
    let SceneErrorKind::Load(load) = &e.kind else {
        panic!("expected SceneErrorKind::Load, got {:?}", e.kind)
    };
    assert!(matches!(load.kind, LoadErrorKind::IsDirectory), "{e}");
    assert!(
        e.to_string()
            .ends_with("bunny.ply: is a directory, not a mesh file"),
        "{e}"
    );
}

#[test]
fn a_mesh_with_an_unknown_extension_lists_the_formats() {
    let dir = temp_dir();
    write(dir.path(), "part.step", BOX_OBJ);
    let path = write(dir.path(), "s.toml", "[[objects]]\nmesh = \"part.step\"\n");
    let e = file::load(&path, &SearchPath::default()).expect_err("an unknown format");
    let SceneErrorKind::Load(load) = &e.kind else {
        panic!("expected SceneErrorKind::Load, got {:?}", e.kind)
    };
    assert!(
        matches!(&load.kind, LoadErrorKind::UnknownFormat(x) if x == "step"),
        "{e}"
    );
    assert!(
        e.to_string()
            .contains("unknown mesh format '.step': strata reads .ply"),
        "{e}"
    );
}

#[test]
fn an_stl_mesh_loads_in_a_scene() {
    let dir = temp_dir();
    let stl = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 2 0 -1\nvertex 6 1 1\nvertex 2 1 1\n\
               endloop\nendfacet\nendsolid t\n";
    write(dir.path(), "t.stl.gz", gzip(stl.as_bytes()));
    let path = write(
        dir.path(),
        "s.toml",
        "[[objects]]\nmesh = \"t.stl.gz\"\nfit = true\n",
    );
    let s = load(&path, &SearchPath::default());
    assert_eq!(names(&s), ["t"]);
    assert_eq!(s.objects[0].mesh.triangles().len(), 1);
    let b = base_bounds(&s.objects);
    assert!(
        b.extent().abs_diff_eq(Vec3::new(1.0, 0.25, 0.5), 1e-6),
        "{b:?}"
    );
}
