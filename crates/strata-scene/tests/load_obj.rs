//! OBJ loader: every face-corner form, negative indices, polygons, normals handling, ignored
//! statements, and malformed files failing at the exact line.

use std::path::Path;

use strata_scene::load::{Format, LoadError, LoadErrorKind, Location, Model, parse_model};

fn parse(text: &str) -> Result<Model, LoadError> {
    parse_model(text.as_bytes(), Format::Obj, Path::new("dir/shape.obj"))
}

const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

#[test]
fn every_corner_form_negative_indices_and_a_quad() {
    let text = format!(
        "# a comment\nmtllib shape.mtl\no shape\ng group\ns 1\nusemtl red\n{SQUARE}v 0.5 0.5 1.0 1.0\n\
         vt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n\
         f 1 4 3 2\n\
         f 1/1 2/2 5/3\n\
         f 2/1/1 3/2/1 5/3/1\n\
         f 3//1 4//1 5//1\n\
         f -2 -5 -1 # 4 1 5\n\
         l 1 2\np 3\nunknown keyword here\n"
    );
    let m = parse(&text).unwrap();
    assert_eq!(m.parts.len(), 1);
    let part = &m.parts[0];
    assert_eq!(part.name, "shape");
    assert_eq!(
        part.mesh.positions(),
        &[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.5, 0.5, 1.0]
        ]
    );
    assert_eq!(
        part.mesh.triangles(),
        &[
            [0, 3, 2],
            [0, 2, 1],
            [0, 1, 4],
            [1, 2, 4],
            [2, 3, 4],
            [3, 0, 4]
        ]
    );
    // Not every corner has a normal: the file's are ignored and computed ones used.
    assert!(!part.mesh.has_file_normals());
}

#[test]
fn normals_on_every_corner_make_unique_position_normal_vertices() {
    // A square whose two triangles have different normals on the shared edge.
    let text = format!(
        "{SQUARE}vn 0 0 1\nvn 0 0 -1\nf 1//1 2//1 3//1\nf 1//2 3//2 4//2\nf 2//1 3//1 1//1\n"
    );
    let m = parse(&text).unwrap();
    let mesh = &m.parts[0].mesh;
    assert!(mesh.has_file_normals());
    // (1,n1) (2,n1) (3,n1) (1,n2) (3,n2) (4,n2): first-use order; the third face reuses.
    assert_eq!(
        mesh.positions(),
        &[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0]
        ]
    );
    assert_eq!(
        mesh.normals(),
        &[
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.0, 0.0, -1.0],
            [0.0, 0.0, -1.0]
        ]
    );
    assert_eq!(mesh.triangles(), &[[0, 1, 2], [3, 4, 5], [1, 2, 0]]);
}

#[test]
fn forward_references_crlf_and_line_continuation() {
    let text = "f 1 2 \\\n 3\r\nv 0 0 0\r\nv 1 0 \\\r\n 0\r\nv 0 1 0\r\n";
    let m = parse(text).unwrap();
    let mesh = &m.parts[0].mesh;
    assert_eq!(
        mesh.positions(),
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    );
    assert_eq!(mesh.triangles(), &[[0, 1, 2]]);
}

// ---------------------------------------------------------------------------------------------
// Malformed input.

fn at_line(text: &str, line: u64, contains: &str) -> LoadError {
    let e = parse(text).expect_err("malformed input must fail");
    assert_eq!(e.location, Some(Location::Line(line)), "{e}");
    let shown = e.to_string();
    assert!(
        shown.starts_with(&format!("dir/shape.obj: line {line}: ")),
        "{shown}"
    );
    assert!(shown.contains(contains), "{shown}");
    e
}

#[test]
fn errors_give_the_line() {
    let e = at_line(
        &format!("{SQUARE}v 1 2\n"),
        5,
        "expected 3 vertex coordinates, found 2",
    );
    assert!(matches!(e.kind, LoadErrorKind::Syntax(_)));
    at_line(
        &format!("{SQUARE}vn 1 x 2\n"),
        5,
        "expected a number, found 'x'",
    );
    at_line(
        &format!("{SQUARE}vn 1\n"),
        5,
        "expected 3 normal components, found 1",
    );
    at_line(
        &format!("v 0 0 0\nv 1 inf 0\n{SQUARE}"),
        2,
        "vertex 2 has a non-finite coordinate inf",
    );
    let e = at_line(
        &format!("{SQUARE}f 1 2 0\n"),
        5,
        "vertex index 0 is invalid: OBJ indices start at 1",
    );
    assert!(matches!(e.kind, LoadErrorKind::Invalid(_)));
    at_line(
        &format!("{SQUARE}f 1 2 -5\n"),
        5,
        "vertex index -5 is out of range: 4 vertices defined so far",
    );
    at_line(
        &format!("{SQUARE}f 1 2 3\nf 1 2 9\nf 1 2 7\n# end\n"),
        6,
        "vertex index 9 is out of range: the file defines 4 vertices",
    );
    at_line(
        &format!("{SQUARE}f 1 2 x\n"),
        5,
        "expected an integer vertex index, found 'x'",
    );
    at_line(
        &format!("{SQUARE}f 1 2 3/y\n"),
        5,
        "expected an integer texture coordinate index, found 'y'",
    );
    at_line(
        &format!("{SQUARE}vn 0 0 1\nf 1//1 2//1 3//2\n"),
        6,
        "normal index 2 is out of range: the file defines 1 normals",
    );
    at_line(
        &format!("{SQUARE}f 1 2 3/1/1/1\n"),
        5,
        "expected a face corner v, v/vt, v/vt/vn or v//vn, found '3/1/1/1'",
    );
    at_line(
        &format!("{SQUARE}\n\nf 1 2\n"),
        7,
        "a face needs at least 3 vertices, found 2",
    );
    at_line(
        &format!("{SQUARE}f 1 2 99999999999999999999\n"),
        5,
        "expected an integer vertex index",
    );
    // Continued lines are reported at their first line.
    at_line(&format!("{SQUARE}f 1 2 \\\n 0\n"), 5, "vertex index 0");
}

#[test]
fn files_without_faces_are_empty() {
    let e = parse(SQUARE).expect_err("no faces");
    assert!(matches!(e.kind, LoadErrorKind::Empty(_)), "{e}");
    assert_eq!(e.location, None);
    assert!(e.to_string().starts_with("dir/shape.obj: "), "{e}");
    let e = parse("").expect_err("empty file");
    assert!(matches!(e.kind, LoadErrorKind::Empty(_)), "{e}");
}
