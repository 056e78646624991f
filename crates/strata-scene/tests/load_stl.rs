//! The STL loader: binary and ascii files, welding, detection, and every refusal with its place.

use std::path::Path;

use strata_scene::load::{Format, LoadError, LoadErrorKind, Location, load_model, parse_model};

/// A unit square in z = 0 as two triangles, the way STL stores it: six corners, four distinct.
const SQUARE: [[[f32; 3]; 3]; 2] = [
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
    [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
];

/// A binary STL of `triangles` with the given 80-byte header text.
fn binary(header: &str, triangles: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut out = header.as_bytes().to_vec();
    out.resize(80, 0);
    out.extend_from_slice(&(triangles.len() as u32).to_le_bytes());
    for t in triangles {
        for v in [0.0f32, 0.0, 1.0] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for c in t.iter().flatten() {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&0u16.to_le_bytes());
    }
    out
}

/// An ascii STL of `triangles`, one keyword group per line.
fn ascii(triangles: &[[[f32; 3]; 3]]) -> String {
    let mut s = String::from("solid square\n");
    for t in triangles {
        s.push_str("  facet normal 0 0 1\n    outer loop\n");
        for v in t {
            s.push_str(&format!("      vertex {} {} {}\n", v[0], v[1], v[2]));
        }
        s.push_str("    endloop\n  endfacet\n");
    }
    s.push_str("endsolid square\n");
    s
}

fn parse(bytes: &[u8]) -> Result<strata_scene::Mesh, LoadError> {
    let mut m = parse_model(bytes, Format::Stl, Path::new("part.stl"))?;
    assert_eq!(m.parts.len(), 1);
    let part = m.parts.remove(0);
    assert_eq!(part.name, "part");
    Ok(part.mesh)
}

/// Parses `bytes`, which must fail; checks the location and that the message has `contains`.
#[track_caller]
fn refused(bytes: &[u8], at: Option<Location>, contains: &str) -> LoadError {
    let e = parse(bytes).expect_err("the file must be refused");
    assert_eq!(e.location, at, "{e}");
    assert!(e.to_string().starts_with("part.stl: "), "{e}");
    assert!(e.to_string().contains(contains), "{e} lacks {contains:?}");
    e
}

#[track_caller]
fn assert_square(m: &strata_scene::Mesh) {
    assert_eq!(
        m.positions(),
        &[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0]
        ]
    );
    assert_eq!(m.triangles(), &[[0, 1, 2], [0, 2, 3]]);
    // Computed normals: both triangles face +z.
    for n in m.normals() {
        assert!((n[2] - 1.0).abs() < 1e-6 && n[0].abs() < 1e-6, "{n:?}");
    }
    assert!(!m.has_file_normals());
}

#[test]
fn binary_and_ascii_give_the_same_welded_mesh() {
    assert_square(&parse(&binary("made by a test", &SQUARE)).expect("binary"));
    assert_square(&parse(ascii(&SQUARE).as_bytes()).expect("ascii"));
}

#[test]
fn a_binary_header_starting_with_solid_is_still_binary() {
    let m = parse(&binary("solid part exported by CAD", &SQUARE)).expect("binary");
    assert_square(&m);
}

#[test]
fn ascii_layout_is_free_and_solids_may_repeat() {
    let one_line = "solid facet normal 0 0 1 outer loop vertex 0 0 0 vertex 1 0 0 vertex 1 1 0 \
                    endloop endfacet endsolid\n";
    // The name runs to the end of the line, so this solid is empty and then its keywords are
    // missing: `solid` must be followed by a line break.
    refused(
        one_line.as_bytes(),
        Some(Location::Line(2)),
        "unexpected end of file",
    );

    let spread = "\u{feff}solid\r\nfacet\tnormal 0 0 1\r\nouter loop vertex 0 0 0\r\n\
                  vertex 1 0 0 vertex\r\n1 1 0\r\nendloop endfacet\r\nendsolid\r\n\
                  solid second\nfacet normal -0 -0 1e0\nouter loop\nvertex 0 0 0\nvertex 1 1 0\n\
                  vertex 0 1 0\nendloop\nendfacet\nendsolid second\n";
    assert_square(&parse(spread.as_bytes()).expect("two solids, free layout"));
}

#[test]
fn gzip_and_the_extension_pick_stl() {
    let dir = tempfile::tempdir().expect("temp dir");
    let files: [(&str, Vec<u8>); 4] = [
        ("a.stl", binary("", &SQUARE)),
        ("b.STL", ascii(&SQUARE).into_bytes()),
        ("c.stl.gz", gzip(&binary("solid c", &SQUARE))),
        ("d", ascii(&SQUARE).into_bytes()),
    ];
    for (name, bytes) in files {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).expect("write");
        let m = load_model(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_square(&m.parts[0].mesh);
    }
    assert_eq!(Format::from_path(Path::new("x.Stl.GZ")), Some(Format::Stl));
    assert_eq!(Format::sniff(&binary("", &SQUARE)), Format::Stl);
    assert_eq!(Format::sniff(b"  solid x\n"), Format::Stl);
    assert_eq!(Format::sniff(b"solidify\n"), Format::Obj);
}

#[test]
fn binary_size_must_match_the_count() {
    let good = binary("", &SQUARE);
    refused(&good[..83], Some(Location::Byte(83)), "84 bytes");
    refused(
        &good[..84 + 50 + 20],
        Some(Location::Byte(134)),
        "ends in triangle 1",
    );
    let mut long = good.clone();
    long.extend_from_slice(&[0; 7]);
    let e = refused(
        &long,
        Some(Location::Byte(184)),
        "7 bytes follow the 2 triangles",
    );
    assert!(matches!(e.kind, LoadErrorKind::Invalid(_)), "{e}");
    // A count of 2^32 - 1 in a short file fails on the size, before reserving anything.
    let mut huge = good[..84].to_vec();
    huge[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    let e = refused(
        &huge,
        Some(Location::Byte(84)),
        "declares 4294967295 triangles",
    );
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)), "{e}");
}

#[test]
fn binary_coordinates_must_be_finite() {
    let mut t = SQUARE;
    t[1][2][1] = f32::NAN;
    // Triangle 1 starts at 84 + 50; its corner 2, coordinate 1, at + 12 + 24 + 4.
    refused(
        &binary("", &t),
        Some(Location::Byte(84 + 50 + 40)),
        "corner 2 of triangle 1 has a non-finite coordinate NaN",
    );
}

#[test]
fn no_triangles_is_an_error() {
    let e = refused(&binary("", &[]), None, "no triangles");
    assert!(matches!(e.kind, LoadErrorKind::Empty(_)), "{e}");
    let e = refused(b"solid empty\nendsolid empty\n", None, "no triangles");
    assert!(matches!(e.kind, LoadErrorKind::Empty(_)), "{e}");
}

#[test]
fn ascii_errors_name_the_line() {
    let good = ascii(&SQUARE);
    let cases: [(String, u64, &str); 7] = [
        (
            good.replace("outer loop", "outer lop"),
            3,
            "expected `loop`, found 'lop'",
        ),
        (
            good.replacen("vertex 1 0 0", "vertex 1 0 x", 1),
            5,
            "expected a vertex coordinate, found 'x'",
        ),
        (
            good.replacen("vertex 1 0 0", "vertex 1 inf 0", 1),
            5,
            "a vertex coordinate is inf",
        ),
        (
            good.replacen("facet normal 0 0 1", "facet normal 0 0", 1),
            3,
            "found 'outer'",
        ),
        (
            good.replacen("endloop", "vertex 2 2 2\n    endloop", 1),
            7,
            "exactly three vertices",
        ),
        (
            good.replacen("endfacet", "endfacets", 1),
            8,
            "expected `endfacet`",
        ),
        (
            format!("{good}junk\n"),
            17,
            "expected `solid` or the end of the file, found 'junk'",
        ),
    ];
    for (text, line, contains) in &cases {
        let e = parse(text.as_bytes()).expect_err(contains);
        assert_eq!(e.location, Some(Location::Line(*line)), "{e}");
        assert!(e.to_string().contains(contains), "{e} lacks {contains:?}");
    }
    // Text that does not start with `solid` is taken for binary, and is too short for it.
    refused(
        b"facet normal 0 0 1\n",
        Some(Location::Byte(19)),
        "an ascii STL starts with `solid`",
    );
    // Truncated inside a facet and before `endsolid`.
    let cut = &good[..good.find("    endloop").expect("endloop")];
    let e = refused(
        cut.as_bytes(),
        Some(Location::Line(7)),
        "expected `endloop`",
    );
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)), "{e}");
    let open = good.replace("endsolid square\n", "");
    let e = refused(
        open.as_bytes(),
        Some(Location::Line(16)),
        "`facet` or `endsolid`",
    );
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)), "{e}");
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut gz, bytes).expect("gzip into memory");
    gz.finish().expect("gzip into memory")
}
