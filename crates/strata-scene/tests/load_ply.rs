//! PLY loader: ascii and binary encodings agree, extra elements and properties are skipped,
//! every scalar type reads, and malformed files fail with the exact line or byte offset.

mod common;

use std::path::Path;

use common::{PYRAMID_POSITIONS, assert_pyramid};

use strata_scene::load::{Format, LoadError, LoadErrorKind, Location, Model, parse_model};

/// One PLY scalar value, tagged with its type.
#[derive(Clone, Copy, Debug)]
enum S {
    I8(i8),
    U8(u8),
    I16(i16),
    U16(u16),
    I32(i32),
    U32(u32),
    F32(f32),
    F64(f64),
}

/// A property value: a scalar, or a list with its count type (given as a constructor).
enum V {
    S(S),
    L(fn(usize) -> S, Vec<S>),
}

#[derive(Clone, Copy)]
enum Enc {
    Ascii,
    Le,
    Be,
}

impl S {
    fn ascii(self) -> String {
        match self {
            S::I8(v) => v.to_string(),
            S::U8(v) => v.to_string(),
            S::I16(v) => v.to_string(),
            S::U16(v) => v.to_string(),
            S::I32(v) => v.to_string(),
            S::U32(v) => v.to_string(),
            S::F32(v) => v.to_string(),
            S::F64(v) => v.to_string(),
        }
    }

    fn binary(self, big: bool, out: &mut Vec<u8>) {
        macro_rules! put {
            ($v:expr) => {
                out.extend_from_slice(&if big {
                    $v.to_be_bytes()
                } else {
                    $v.to_le_bytes()
                })
            };
        }
        match self {
            S::I8(v) => put!(v),
            S::U8(v) => put!(v),
            S::I16(v) => put!(v),
            S::U16(v) => put!(v),
            S::I32(v) => put!(v),
            S::U32(v) => put!(v),
            S::F32(v) => put!(v),
            S::F64(v) => put!(v),
        }
    }
}

/// A PLY file: `decl` holds the element and property lines, `rows` the instances in order.
fn encode(decl: &str, rows: &[Vec<V>], enc: Enc) -> Vec<u8> {
    let format = match enc {
        Enc::Ascii => "ascii",
        Enc::Le => "binary_little_endian",
        Enc::Be => "binary_big_endian",
    };
    let mut out =
        format!("ply\nformat {format} 1.0\ncomment hand-made\n{decl}end_header\n").into_bytes();
    for row in rows {
        match enc {
            Enc::Ascii => {
                let mut tokens = Vec::new();
                for v in row {
                    match v {
                        V::S(s) => tokens.push(s.ascii()),
                        V::L(count, items) => {
                            tokens.push(count(items.len()).ascii());
                            tokens.extend(items.iter().map(|s| s.ascii()));
                        }
                    }
                }
                out.extend_from_slice(tokens.join(" ").as_bytes());
                out.push(b'\n');
            }
            Enc::Le | Enc::Be => {
                let big = matches!(enc, Enc::Be);
                for v in row {
                    match v {
                        V::S(s) => s.binary(big, &mut out),
                        V::L(count, items) => {
                            count(items.len()).binary(big, &mut out);
                            for s in items {
                                s.binary(big, &mut out);
                            }
                        }
                    }
                }
            }
        }
    }
    out
}

const FACES: [&[u32]; 5] = [
    &[0, 3, 2, 1],
    &[0, 1, 4],
    &[1, 2, 4],
    &[2, 3, 4],
    &[3, 0, 4],
];
/// The pyramid with only what the loader needs.
fn plain(enc: Enc) -> Vec<u8> {
    let decl = "element vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
                element face 5\nproperty list uchar int vertex_indices\n";
    let mut rows: Vec<Vec<V>> = PYRAMID_POSITIONS
        .iter()
        .map(|p| p.iter().map(|&c| V::S(S::F32(c))).collect())
        .collect();
    for f in FACES {
        rows.push(vec![V::L(
            |n| S::U8(n as u8),
            f.iter().map(|&i| S::I32(i as i32)).collect(),
        )]);
    }
    encode(decl, &rows, enc)
}

/// The same pyramid among extra elements and properties of every kind, lists included.
fn cluttered(enc: Enc) -> Vec<u8> {
    let decl = "element material 2\nproperty list ushort float32 ambient\nproperty uchar id\n\
                element vertex 5\nproperty uchar red\nproperty double x\nproperty int16 flags\n\
                property float32 y\nproperty list int uint8 texcoord\nproperty float z\n\
                property float confidence\n\
                element face 5\nproperty uint8 flags\nproperty list uint short vertex_index\n\
                property list char double texcoord\n\
                element edge 1\nproperty int vertex1\nproperty list uint16 uint32 more\n";
    let mut rows: Vec<Vec<V>> = vec![
        vec![
            V::L(
                |n| S::U16(n as u16),
                vec![S::F32(0.25), S::F32(-1.0), S::F32(3.5)],
            ),
            V::S(S::U8(7)),
        ],
        vec![V::L(|n| S::U16(n as u16), vec![]), V::S(S::U8(8))],
    ];
    for (i, p) in PYRAMID_POSITIONS.iter().enumerate() {
        rows.push(vec![
            V::S(S::U8(200)),
            V::S(S::F64(f64::from(p[0]))),
            V::S(S::I16(-3)),
            V::S(S::F32(p[1])),
            V::L(|n| S::I32(n as i32), (0..i as u8).map(S::U8).collect()),
            V::S(S::F32(p[2])),
            V::S(S::F32(0.75)),
        ]);
    }
    for f in FACES {
        rows.push(vec![
            V::S(S::U8(1)),
            V::L(
                |n| S::U32(n as u32),
                f.iter().map(|&i| S::I16(i as i16)).collect(),
            ),
            V::L(|n| S::I8(n as i8), vec![S::F64(0.5); 2 * f.len()]),
        ]);
    }
    rows.push(vec![
        V::S(S::I32(4)),
        V::L(|n| S::U16(n as u16), vec![S::U32(1), S::U32(2)]),
    ]);
    let mut bytes = encode(decl, &rows, enc);
    bytes.extend_from_slice(b"trailing data after the last element is ignored");
    bytes
}

fn parse(bytes: &[u8]) -> Result<Model, LoadError> {
    parse_model(bytes, Format::Ply, Path::new("pyramid.ply"))
}

fn check_pyramid(m: &Model) {
    assert_pyramid(m, "pyramid", false);
}

#[test]
fn ascii_binary_le_be_and_gzip_agree() {
    let ascii = parse(&plain(Enc::Ascii)).unwrap();
    check_pyramid(&ascii);
    assert_eq!(parse(&plain(Enc::Le)).unwrap(), ascii);
    assert_eq!(parse(&plain(Enc::Be)).unwrap(), ascii);

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pyramid.ply.gz");
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut gz, &plain(Enc::Be)).unwrap();
    std::fs::write(&path, gz.finish().unwrap()).unwrap();
    let loaded = strata_scene::load::load_model(&path).unwrap();
    assert_eq!(loaded, ascii);
}

#[test]
fn extra_elements_and_properties_are_skipped() {
    let expected = parse(&plain(Enc::Ascii)).unwrap();
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        let m = parse(&cluttered(enc)).unwrap();
        assert_eq!(m, expected);
    }
}

/// A PLY type's two names and how to make a value of it.
type TypeCase = (&'static str, &'static str, fn(i8) -> S);

#[test]
fn every_scalar_type_reads_as_a_coordinate_and_index() {
    let types: [TypeCase; 8] = [
        ("char", "int8", S::I8),
        ("uchar", "uint8", |v| S::U8(v as u8)),
        ("short", "int16", |v| S::I16(i16::from(v))),
        ("ushort", "uint16", |v| S::U16(v as u16)),
        ("int", "int32", |v| S::I32(i32::from(v))),
        ("uint", "uint32", |v| S::U32(v as u32)),
        ("float", "float32", |v| S::F32(f32::from(v))),
        ("double", "float64", |v| S::F64(f64::from(v))),
    ];
    let counts: [fn(usize) -> S; 6] = [
        |n| S::I8(n as i8),
        |n| S::U8(n as u8),
        |n| S::I16(n as i16),
        |n| S::U16(n as u16),
        |n| S::I32(n as i32),
        |n| S::U32(n as u32),
    ];
    let count_names = ["char", "uchar", "int16", "ushort", "int32", "uint"];
    for (k, (old, new, make)) in types.into_iter().enumerate() {
        for name in [old, new] {
            // Indices and list counts take the integer types in turn.
            let (index_name, _, index) = types[k % 6];
            let count_name = count_names[k % 6];
            let decl = format!(
                "element vertex 3\nproperty {name} x\nproperty {name} y\nproperty {name} z\n\
                 element face 1\nproperty list {count_name} {index_name} vertex_indices\n"
            );
            let rows: Vec<Vec<V>> = vec![
                vec![V::S(make(0)), V::S(make(0)), V::S(make(0))],
                vec![V::S(make(2)), V::S(make(-1)), V::S(make(1))],
                vec![V::S(make(0)), V::S(make(3)), V::S(make(1))],
                vec![V::L(counts[k % 6], vec![index(0), index(1), index(2)])],
            ];
            let y1 = if matches!(make(-1), S::U8(_) | S::U16(_) | S::U32(_)) {
                match make(-1) {
                    S::U8(_) => 255.0,
                    S::U16(_) => 65535.0,
                    _ => 4294967295.0,
                }
            } else {
                -1.0
            };
            for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
                let m = parse(&encode(&decl, &rows, enc)).unwrap_or_else(|e| panic!("{name}: {e}"));
                let mesh = &m.parts[0].mesh;
                assert_eq!(
                    mesh.positions(),
                    &[[0.0, 0.0, 0.0], [2.0, y1, 1.0], [0.0, 3.0, 1.0]],
                    "{name}"
                );
                assert_eq!(mesh.triangles(), &[[0, 1, 2]], "{name}");
            }
        }
    }
}

#[test]
fn normals_are_used_only_when_all_three_are_present() {
    let with = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
                element face 1\nproperty list uchar uint vertex_indices\nend_header\n\
                0 0 0 0 0 -1\n1 0 0 0 0 -1\n0 1 0 0 0 -1\n3 0 1 2\n";
    let m = parse(with.as_bytes()).unwrap();
    assert!(m.parts[0].mesh.has_file_normals());
    assert_eq!(m.parts[0].mesh.normals(), &[[0.0, 0.0, -1.0]; 3]);

    let partial = with.replace("property float nz\n", "property float nw\n");
    let m = parse(partial.as_bytes()).unwrap();
    assert!(!m.parts[0].mesh.has_file_normals());
    assert_eq!(m.parts[0].mesh.normals(), &[[0.0, 0.0, 1.0]; 3]);
}

#[test]
fn crlf_comments_obj_info_and_blank_lines() {
    let text = "ply\r\nformat ascii 1.0\r\ncomment a comment\r\nobj_info some info\r\n\
                element vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\n\
                element face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n\
                0 0 0\r\n\r\n1 0 0 \r\n0 1 0\r\n3 0 1 2\r\n";
    let m = parse(text.as_bytes()).unwrap();
    assert_eq!(
        m.parts[0].mesh.positions(),
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    );
    assert_eq!(m.parts[0].mesh.triangles(), &[[0, 1, 2]]);
}

// ---------------------------------------------------------------------------------------------
// Malformed input.

const HEADER: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                      property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                      end_header\n";

/// The error of parsing `bytes`, checked to name the file.
fn error(bytes: &[u8]) -> LoadError {
    let e = parse(bytes).expect_err("malformed input must fail");
    let text = e.to_string();
    assert!(text.starts_with("pyramid.ply: "), "{text}");
    e
}

fn at_line(bytes: &[u8], line: u64, contains: &str) -> LoadError {
    let e = error(bytes);
    assert_eq!(e.location, Some(Location::Line(line)), "{e}");
    assert!(e.to_string().contains(contains), "{e}");
    assert!(e.to_string().contains(&format!(": line {line}: ")), "{e}");
    e
}

fn at_byte(bytes: &[u8], offset: u64, contains: &str) -> LoadError {
    let e = error(bytes);
    assert_eq!(e.location, Some(Location::Byte(offset)), "{e}");
    assert!(e.to_string().contains(contains), "{e}");
    e
}

#[test]
fn ascii_errors_give_the_line() {
    // Header lines 1-9, body from line 10.
    let e = at_line(
        format!("{HEADER}0 0 0\n1 0\n0 1 0\n3 0 1 2\n").as_bytes(),
        11,
        "expected 3 values in vertex 1, found 2",
    );
    assert!(matches!(e.kind, LoadErrorKind::Syntax(_)));
    at_line(
        format!("{HEADER}0 0 0\n1 0 0 7\n0 1 0\n3 0 1 2\n").as_bytes(),
        11,
        "expected 3 values in vertex 1, found 4",
    );
    at_line(
        format!("{HEADER}0 0 0\n1 0 0\n0 1e 0\n3 0 1 2\n").as_bytes(),
        12,
        "expected a number for 'y' of vertex 2, found '1e'",
    );
    at_line(
        format!("{HEADER}0 0 0\n1 0 nan\n0 1 0\n3 0 1 2\n").as_bytes(),
        11,
        "vertex 1 has a non-finite coordinate 'nan'",
    );
    let e = at_line(
        format!("{HEADER}0 0 0\n1 0 0\n0 1 0\n2 0 1\n").as_bytes(),
        13,
        "face 0 has 2 vertices; a face needs at least 3",
    );
    assert!(matches!(e.kind, LoadErrorKind::Invalid(_)));
    at_line(
        format!("{HEADER}0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n").as_bytes(),
        13,
        "face 0 refers to vertex 3, but there are only 3 vertices",
    );
    at_line(
        format!("{HEADER}0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n").as_bytes(),
        13,
        "face 0 has a negative vertex index -1",
    );
    at_line(
        format!("{HEADER}0 0 0\n1 0 0\n0 1 0\n3 0 1.0 2\n").as_bytes(),
        13,
        "expected an integer vertex index in face 0, found '1.0'",
    );
    at_line(
        format!("{HEADER}0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n").as_bytes(),
        13,
        "face 0 ends within its list of 4 vertex indices",
    );
    // Missing data: reported at the line after the last one.
    let e = at_line(
        format!("{HEADER}0 0 0\n1 0 0\n0 1 0\n").as_bytes(),
        13,
        "unexpected end of file in face 0",
    );
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)));
    at_line(
        format!("{HEADER}0 0 0\n").as_bytes(),
        11,
        "unexpected end of file in vertex 1",
    );
}

#[test]
fn header_errors_give_the_line() {
    at_line(
        b"plyx\nformat ascii 1.0\n",
        1,
        "expected 'ply' as the first line, found 'plyx'",
    );
    at_line(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty flaot x\n",
        4,
        "found 'flaot'",
    );
    at_line(
        b"ply\nformat ascii 1.0\nelement vertex three\n",
        3,
        "expected an element count, found 'three'",
    );
    at_line(
        b"ply\nformat ascii 1.0\nproperty float x\n",
        3,
        "a property before any element",
    );
    at_line(
        b"ply\nformat ascii 1.0\nelements vertex 3\n",
        3,
        "expected a header keyword",
    );
    at_line(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty list float int vertex_indices\n",
        4,
        "expected an integer list count type, found 'float'",
    );
    let e = at_line(
        b"ply\nformat binary_middle_endian 1.0\n",
        2,
        "binary_middle_endian",
    );
    assert!(matches!(e.kind, LoadErrorKind::Unsupported(_)));
    at_line(b"ply\nformat ascii 2.0\n", 2, "PLY version '2.0'");
    at_line(
        b"ply\nformat ascii 1.0\nelement vertex 1\n",
        4,
        "unexpected end of file in the header",
    );
    at_line(
        b"ply\nelement vertex 0\nend_header\n",
        3,
        "the header ends without a 'format' line",
    );
    at_line(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nend_header\n",
        3,
        "the vertex element has no 'z' property",
    );
    at_line(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty int vertex_indices\nend_header\n",
        7,
        "face property 'vertex_indices' is a scalar; expected a list",
    );
    at_line(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar float vertex_indices\nend_header\n",
        7,
        "expected an integer list",
    );
    let e = error(b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n");
    assert_eq!(e.location, None);
    assert!(e.to_string().contains("no 'vertex' element"), "{e}");
    let e = error(b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n");
    assert!(matches!(e.kind, LoadErrorKind::Empty(_)), "{e}");
}

#[test]
fn binary_errors_give_the_byte_offset() {
    let le = plain(Enc::Le);
    let body = le.len() - (5 * 12 + (1 + 16) + 4 * (1 + 12));
    // Truncated in face 4 (the last: 1 + 12 bytes, starting 13 bytes before the end).
    let face4 = le.len() - 13;
    let e = at_byte(
        &le[..le.len() - 2],
        face4 as u64 + 1 + 8,
        "unexpected end of file in face 4",
    );
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)));
    assert!(
        e.to_string()
            .contains(&format!("pyramid.ply: byte {}: ", face4 + 9)),
        "{e}"
    );
    // Cut inside vertex 2's y.
    at_byte(
        &le[..body + 2 * 12 + 6],
        (body + 2 * 12 + 4) as u64,
        "unexpected end of file in vertex 2",
    );
    // Index 9 in face 1 (second index).
    let mut bad = le.clone();
    let face1 = body + 60 + 17;
    bad[face1 + 1 + 4..face1 + 1 + 8].copy_from_slice(&9i32.to_le_bytes());
    at_byte(
        &bad,
        (face1 + 5) as u64,
        "face 1 refers to vertex 9, but there are only 5 vertices",
    );
    bad[face1 + 1 + 4..face1 + 1 + 8].copy_from_slice(&(-2i32).to_le_bytes());
    at_byte(
        &bad,
        (face1 + 5) as u64,
        "face 1 has a negative vertex index -2",
    );
    // A face of 2 vertices.
    let mut bad = le.clone();
    bad[face1] = 2;
    at_byte(
        &bad,
        face1 as u64,
        "face 1 has 2 vertices; a face needs at least 3",
    );
    // Non-finite coordinate.
    let mut bad = le.clone();
    bad[body + 12 + 4..body + 12 + 8].copy_from_slice(&f32::INFINITY.to_le_bytes());
    at_byte(
        &bad,
        (body + 16) as u64,
        "vertex 1 has a non-finite coordinate inf",
    );
}

#[test]
fn skipped_list_running_past_the_end_is_truncated() {
    // material 0: a ushort count then floats; claim more floats than the file holds.
    let decl = "element material 1\nproperty list ushort float ambient\n\
                element vertex 0\nproperty float x\nproperty float y\nproperty float z\n";
    let rows = vec![vec![V::L(
        |n| S::U16(n as u16),
        vec![S::F32(1.0), S::F32(2.0)],
    )]];
    let bytes = encode(decl, &rows, Enc::Le);
    let body = bytes.len() - 10;
    let mut bad = bytes.clone();
    bad[body..body + 2].copy_from_slice(&3u16.to_le_bytes());
    // Two floats present: the third would start at body + 2 + 8 = the end.
    at_byte(
        &bad,
        bytes.len() as u64,
        "unexpected end of file in material 0",
    );
    // A negative count (char count type).
    let decl = "element material 1\nproperty list char float ambient\n\
                element vertex 0\nproperty float x\nproperty float y\nproperty float z\n";
    let rows = vec![vec![V::L(|n| S::I8(n as i8), vec![S::F32(1.0)])]];
    let mut bad = encode(decl, &rows, Enc::Le);
    let body = bad.len() - 5;
    bad[body] = 0xff;
    at_byte(
        &bad,
        body as u64,
        "material 0 has a negative list length -1 for 'ambient'",
    );
}
