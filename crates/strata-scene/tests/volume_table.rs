//! The scene file's `[volume]` table: a valid table is read, every malformed one is a clear error
//! naming its key and line.

use strata_scene::SearchPath;
use strata_scene::scene::file::{SceneOrigin, parse};
use strata_scene::scene::volume::VolumeSource;

const HEAD: &str = r#"
[volume]
procedural = "head"
size = 32
min = [-1, -1, -1]
max = [1, 1, 1]
samples = 256
path = [[0, 1, 0], [0.2, 0, 0], [0.5, -0.5, 0]]

[[volume.points]]
value = 0.1
color = [0.5, 0.5, 0.5]
alpha = 0.0

[[volume.points]]
value = 0.8
color = [1, 0.9, 0.8]
alpha = 0.6
"#;

fn load(text: &str) -> Result<strata_scene::Scene, String> {
    parse(text, SceneOrigin::Builtin("test"), &SearchPath::new([])).map_err(|e| e.to_string())
}

#[test]
fn a_volume_scene_needs_no_objects() {
    let scene = load(HEAD).expect("valid");
    assert!(scene.objects.is_empty());
    let v = scene.volume.expect("volume table");
    assert_eq!(
        v.source,
        VolumeSource::Procedural {
            name: "head".into(),
            size: 32
        }
    );
    assert_eq!((v.samples, v.points.len(), v.path.len()), (256, 2, 3));
    assert_eq!(v.points[1].alpha, 0.6);
    assert_eq!(v.min, glam::Vec3::splat(-1.0));
}

#[test]
fn a_transfer_function_without_points_is_refused() {
    let text = "[volume]\nprocedural = \"head\"\n";
    let e = load(text).expect_err("no points");
    assert!(
        e.contains("volume.points") && e.contains("no points"),
        "{e}"
    );
}

#[test]
fn malformed_tables_name_the_key() {
    let cases = [
        (HEAD.replace("procedural = \"head\"", ""), "exactly one of"),
        (HEAD.replace("\"head\"", "\"teapot\""), "teapot"),
        (
            HEAD.replace("samples = 256", "samples = 0"),
            "volume.samples",
        ),
        (
            HEAD.replace("max = [1, 1, 1]", "max = [1, -2, 1]"),
            "volume.max",
        ),
        (
            HEAD.replace("max = [1, 1, 1]", "max = [1, 1, 1, 1]"),
            "3 numbers",
        ),
        (
            HEAD.replace("value = 0.8", "value = 0.05"),
            "volume.points[1]",
        ),
        (
            HEAD.replace("alpha = 0.6", "alpha = 1.6"),
            "volume.points[1]",
        ),
        (
            HEAD.replace(
                "path = [[0, 1, 0], [0.2, 0, 0], [0.5, -0.5, 0]]",
                "path = [[0, 1, 0]]",
            ),
            "at least 2",
        ),
        (HEAD.replace("size = 32", "size = 100000"), "volume.size"),
        (HEAD.replace("samples = 256", "sample = 256"), "sample"),
    ];
    for (text, needle) in cases {
        let e = load(&text).expect_err(needle);
        assert!(e.contains(needle), "expected {needle:?} in {e}");
    }
}

#[test]
fn a_missing_volume_file_lists_where_it_was_looked_for() {
    let text = HEAD.replace("procedural = \"head\"", "file = \"no-such-volume.nii.gz\"");
    let e = load(&text).expect_err("missing");
    assert!(e.contains("no-such-volume.nii.gz"), "{e}");
}

#[test]
fn glass_boxes_are_read_and_bad_ones_name_their_entry() {
    let text = format!(
        "{HEAD}\n[[volume.glass]]\nmin = [0, -1, -1]\nmax = [0.02, 1, 1]\nalpha = 0.3\n\n\
         [[volume.glass]]\nmin = [-0.5, 0, 0]\nmax = [-0.4, 0.1, 0.1]\ncolor = [1, 0, 0]\nalpha = 0.5\nmoves = true\n"
    );
    let v = load(&text).expect("valid").volume.expect("volume table");
    assert_eq!(v.glass.len(), 2);
    assert!(!v.glass[0].moves && v.glass[1].moves);
    assert_eq!(v.glass[0].alpha, 0.3);
    assert_eq!(v.glass[1].color, [1.0, 0.0, 0.0]);
    assert_eq!(v.glass[0].max, glam::Vec3::new(0.02, 1.0, 1.0));
    let flat = format!("{HEAD}\n[[volume.glass]]\nmin = [0, 0, 0]\nmax = [0, 1, 1]\nalpha = 0.3\n");
    let e = load(&flat).expect_err("flat box");
    assert!(
        e.contains("volume.glass[0]") && e.contains("max above min"),
        "{e}"
    );
    let opaque =
        format!("{HEAD}\n[[volume.glass]]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\nalpha = 1.5\n");
    let e = load(&opaque).expect_err("alpha out of range");
    assert!(e.contains("volume.glass[0]") && e.contains("[0, 1]"), "{e}");
}
