//! OFF loader: the OFF, COFF, NOFF, CNOFF and NCOFF variants, comments anywhere, face colours,
//! polygons, and malformed files failing at the exact line.

mod common;

use std::path::Path;

use common::{PYRAMID_POSITIONS, assert_pyramid};

use strata_scene::load::{Format, LoadError, LoadErrorKind, Location, Model, parse_model};

fn parse(text: &str) -> Result<Model, LoadError> {
    parse_model(text.as_bytes(), Format::Off, Path::new("box.off"))
}

fn check(m: &Model, normals: bool) {
    assert_pyramid(m, "box", normals);
}

#[test]
fn plain_off_with_comments_and_a_quad() {
    let text = "# leading comment\n\nOFF # keyword\n# counts next\n5 5 8\n\
                0 0 0\n1 0 0 # trailing\n1 1 0\n\n0 1 0\n0.5 0.5 1\n\
                4 0 3 2 1\n3 0 1 4\n3 1 2 4\n# between faces\n3 2 3 4\n3 3 0 4\n\
                trailing edges or junk are ignored\n";
    check(&parse(text).unwrap(), false);
}

#[test]
fn counts_on_the_keyword_line_and_crlf() {
    let text = "OFF 5 5 0\r\n0 0 0\r\n1 0 0\r\n1 1 0\r\n0 1 0\r\n0.5 0.5 1\r\n\
                4 0 3 2 1\r\n3 0 1 4\r\n3 1 2 4\r\n3 2 3 4\r\n3 3 0 4";
    check(&parse(text).unwrap(), false);
}

#[test]
fn colour_and_normal_variants() {
    let coff = "COFF\n5 5 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n1 1 0 0 0 255 255\n\
                0 1 0 9 9 9 9\n0.5 0.5 1 1 1 1 1\n\
                4 0 3 2 1 255 0 0\n3 0 1 4 0.5 0.5 0.5 1\n3 1 2 4 7\n3 2 3 4\n3 3 0 4\n";
    check(&parse(coff).unwrap(), false);

    let normals = [
        [0.0, 0.0, -1.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let mut vertices = String::new();
    for (p, n) in PYRAMID_POSITIONS.iter().zip(normals) {
        vertices += &format!("{} {} {} {} {} {}", p[0], p[1], p[2], n[0], n[1], n[2]);
        vertices += " 0.1 0.2 0.3 1\n"; // a colour, read only by C files, ignored anyway
    }
    let faces = "4 0 3 2 1\n3 0 1 4\n3 1 2 4\n3 2 3 4\n3 3 0 4\n";
    for keyword in ["NOFF", "CNOFF", "NCOFF"] {
        let m = parse(&format!("{keyword}\n5 5 0\n{vertices}{faces}")).unwrap();
        check(&m, true);
        assert_eq!(m.parts[0].mesh.normals(), &normals, "{keyword}");
    }
}

// ---------------------------------------------------------------------------------------------
// Malformed input.

fn at_line(text: &str, line: u64, contains: &str) -> LoadError {
    let e = parse(text).expect_err("malformed input must fail");
    assert_eq!(e.location, Some(Location::Line(line)), "{e}");
    let shown = e.to_string();
    assert!(
        shown.starts_with(&format!("box.off: line {line}: ")),
        "{shown}"
    );
    assert!(shown.contains(contains), "{shown}");
    e
}

const HEAD: &str = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n";

#[test]
fn unsupported_variants() {
    for (text, what) in [
        (
            "4OFF\n1 0 0\n0 0 0 1\n",
            "'4OFF': only 3D vertices are supported",
        ),
        ("# x\nnOFF\n4\n", "'nOFF': only 3D vertices are supported"),
        ("OFF BINARY\n", "binary OFF"),
    ] {
        let line = if text.starts_with('#') { 2 } else { 1 };
        let e = at_line(text, line, what);
        assert!(matches!(e.kind, LoadErrorKind::Unsupported(_)), "{e}");
    }
}

#[test]
fn errors_give_the_line() {
    at_line(
        "OFX\n3 1 0\n",
        1,
        "expected an OFF keyword (OFF, COFF, NOFF, CNOFF, …), found 'OFX'",
    );
    at_line("OFF\n3 x 0\n", 2, "expected the number of faces, found 'x'");
    at_line(
        "OFF\n3\n",
        2,
        "expected the number of faces, found end of line",
    );
    at_line(
        "OFF\n-3 1 0\n",
        2,
        "expected the number of vertices, found '-3'",
    );
    at_line(
        "OFF\n3 1 0\n0 0 0\n1 0\n",
        4,
        "expected 3 numbers for vertex 1, found 2",
    );
    at_line(
        "NOFF\n3 1 0\n0 0 0 0 0 1\n1 0 0 0 0\n",
        4,
        "expected 6 numbers for vertex 1, found 5",
    );
    at_line(
        "OFF\n3 1 0\n0 0 0\n1 0 z\n",
        4,
        "expected a number in vertex 1, found 'z'",
    );
    at_line(
        "OFF\n3 1 0\n0 0 0\n1 0 nan\n0 1 0\n3 0 1 2\n",
        4,
        "vertex 1 has a non-finite coordinate NaN",
    );
    let e = at_line(
        &format!("{HEAD}3 0 1 3\n"),
        6,
        "face 0 refers to vertex 3, but there are only 3 vertices",
    );
    assert!(matches!(e.kind, LoadErrorKind::Invalid(_)));
    at_line(
        &format!("{HEAD}3 0 -1 2\n"),
        6,
        "face 0 refers to vertex -1",
    );
    at_line(
        &format!("{HEAD}2 0 1\n"),
        6,
        "face 0 has 2 vertices; a face needs at least 3",
    );
    at_line(
        &format!("{HEAD}4 0 1 2\n"),
        6,
        "expected 4 vertex indices in face 0, found 3",
    );
    at_line(
        &format!("{HEAD}3 0 1 2.5\n"),
        6,
        "expected an integer vertex index in face 0, found '2.5'",
    );
    at_line(
        &format!("{HEAD}x 0 1 2\n"),
        6,
        "expected the vertex count of face 0, found 'x'",
    );
    let e = at_line(
        "OFF\n3 1 0\n0 0 0\n# comment\n",
        5,
        "unexpected end of file in vertex 1",
    );
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)));
    at_line(HEAD, 6, "unexpected end of file in face 0");
    at_line(
        "# only a comment\n",
        2,
        "unexpected end of file before the OFF keyword",
    );
    at_line(
        "OFF\n",
        2,
        "unexpected end of file before the vertex and face counts",
    );
    let e = at_line(
        "OFF\n5000000000 1 0\n",
        2,
        "5000000000 vertices exceed the limit of 2^32",
    );
    assert!(matches!(e.kind, LoadErrorKind::Unsupported(_)));
    let e = parse("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n").expect_err("no faces");
    assert!(matches!(e.kind, LoadErrorKind::Empty(_)), "{e}");
}
