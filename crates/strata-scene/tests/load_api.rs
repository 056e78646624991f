//! The loader API: format detection by extension and content, gzip, part names, and how errors
//! read.

use std::path::{Path, PathBuf};

use strata_scene::load::{Format, LoadError, LoadErrorKind, Location, load_model, parse_model};

const OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
const OFF: &str = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                   property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                   end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut gz, bytes).unwrap();
    gz.finish().unwrap()
}

#[test]
fn format_from_path() {
    let cases = [
        ("dragon.ply", Some(Format::Ply)),
        ("dir.v2/Dragon.PLY.GZ", Some(Format::Ply)),
        ("bunny.obj.gz", Some(Format::Obj)),
        ("a.Off", Some(Format::Off)),
        ("scene.gltf", Some(Format::Gltf)),
        ("engine.GLB", Some(Format::Glb)),
        ("mesh.stl", Some(Format::Stl)),
        ("mesh.xyz", None),
        ("mesh.", None),
        ("mesh", None),
        ("mesh.gz", None),
        (".ply", Some(Format::Ply)),
        ("", None),
    ];
    for (path, format) in cases {
        assert_eq!(Format::from_path(Path::new(path)), format, "{path}");
    }
}

#[test]
fn format_sniffing() {
    let cases: [(&[u8], Format); 10] = [
        (b"ply\nformat ascii 1.0\n", Format::Ply),
        (b"ply\r\nformat ascii 1.0\r\n", Format::Ply),
        (b"OFF\n3 1 0\n", Format::Off),
        (b"NCOFF 3 1 0\n", Format::Off),
        (b"COFF#c\n", Format::Off),
        (b"# made by hand\n\n  # more\nOFF\n", Format::Off),
        (b"glTF\x02\0\0\0", Format::Glb),
        (b"\xef\xbb\xbf  \n{\"asset\": {}}", Format::Gltf),
        (b"# a comment\nv 0 0 0\n", Format::Obj),
        (b"", Format::Obj),
    ];
    for (bytes, format) in cases {
        assert_eq!(
            Format::sniff(bytes),
            format,
            "{}",
            String::from_utf8_lossy(bytes)
        );
    }
}

#[test]
fn load_model_gunzips_detects_and_names_parts() {
    let dir = tempfile::tempdir().unwrap();
    let files: [(&str, Vec<u8>); 8] = [
        ("tri.obj", OBJ.into()),
        ("tri.off", OFF.into()),
        ("tri.ply", PLY.into()),
        ("tri.ply.gz", gzip(PLY.as_bytes())),
        ("tri.OFF.GZ", gzip(OFF.as_bytes())),
        // No extension: sniffed, after gunzipping.
        ("tri.gz", gzip(OFF.as_bytes())),
        ("tri", OBJ.into()),
        ("tri.", PLY.into()),
    ];
    for (name, bytes) in files {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let m = load_model(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m.parts.len(), 1);
        let stem = name.split('.').next().unwrap();
        assert_eq!(m.parts[0].name, stem, "{name}");
        assert_eq!(m.parts[0].mesh.triangles(), &[[0, 1, 2]], "{name}");
        assert_eq!(m.parts[0].mesh.positions()[1], [1.0, 0.0, 0.0], "{name}");
    }
    // A multi-member gzip stream is read whole.
    let mut two = gzip(&PLY.as_bytes()[..40]);
    two.extend(gzip(&PLY.as_bytes()[40..]));
    let path = dir.path().join("two.ply.gz");
    std::fs::write(&path, two).unwrap();
    assert_eq!(load_model(&path).unwrap().parts[0].name, "two");
}

#[test]
fn an_unknown_extension_is_an_error_listing_the_formats() {
    let dir = tempfile::tempdir().unwrap();
    // Valid OBJ content does not help: the name promises another format, and guessing would
    // turn, say, an unsupported format into "no triangles".
    for (name, ext) in [
        ("tri.mesh", "mesh"),
        ("tri.DAT.gz", "dat"),
        ("scan.3mf", "3mf"),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, OBJ).unwrap();
        let e = load_model(&path).unwrap_err();
        assert!(
            matches!(&e.kind, LoadErrorKind::UnknownFormat(x) if x == ext),
            "{name}: {e:?}"
        );
        assert_eq!(e.location, None);
        let shown = e.to_string();
        assert!(
            shown.starts_with(&format!(
                "{}: unknown mesh format '.{ext}': strata reads ",
                path.display()
            )),
            "{shown}"
        );
        for known in [".ply", ".obj", ".off", ".stl", ".gltf", ".glb", ".gz"] {
            assert!(shown.contains(known), "{shown} lacks {known}");
        }
    }
    // Checked before reading: a missing file with an unknown extension says the same.
    let e = load_model(&dir.path().join("absent.xyz")).unwrap_err();
    assert!(matches!(e.kind, LoadErrorKind::UnknownFormat(_)), "{e}");
}

#[test]
fn a_directory_is_not_a_mesh() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["models", "looks_like.ply"] {
        let path = dir.path().join(name);
        std::fs::create_dir(&path).unwrap();
        let e = load_model(&path).unwrap_err();
        assert!(matches!(e.kind, LoadErrorKind::IsDirectory), "{e:?}");
        assert_eq!(
            e.to_string(),
            format!("{}: is a directory, not a mesh file", path.display())
        );
    }
}

#[test]
fn read_and_gzip_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.ply");
    let e = load_model(&missing).unwrap_err();
    assert!(matches!(e.kind, LoadErrorKind::Io(_)), "{e}");
    assert_eq!(e.location, None);
    assert!(
        e.to_string()
            .starts_with(&format!("{}: cannot read: ", missing.display())),
        "{e}"
    );

    let path = dir.path().join("broken.ply.gz");
    let mut gz = gzip(PLY.as_bytes());
    gz.truncate(gz.len() / 2);
    std::fs::write(&path, &gz).unwrap();
    let e = load_model(&path).unwrap_err();
    assert!(matches!(e.kind, LoadErrorKind::Gzip(_)), "{e}");
    assert!(
        e.to_string().contains("broken.ply.gz: invalid gzip data: "),
        "{e}"
    );

    std::fs::write(&path, [0x1f, 0x8b, 8, 0, 0, 0]).unwrap();
    assert!(matches!(
        load_model(&path).unwrap_err().kind,
        LoadErrorKind::Gzip(_)
    ));
}

#[test]
fn errors_read_path_location_message() {
    let e = LoadError {
        path: PathBuf::from("dragon.ply.gz"),
        location: Some(Location::Line(12)),
        kind: LoadErrorKind::Syntax("expected 3 vertex coordinates, found 2".into()),
    };
    assert_eq!(
        e.to_string(),
        "dragon.ply.gz: line 12: expected 3 vertex coordinates, found 2"
    );
    let e = LoadError {
        path: PathBuf::from("model.ply"),
        location: Some(Location::Byte(4711)),
        kind: LoadErrorKind::Truncated("unexpected end of file in face 1234".into()),
    };
    assert_eq!(
        e.to_string(),
        "model.ply: byte 4711: unexpected end of file in face 1234"
    );

    // The same through a parser: ascii PLY, line 11.
    let bad = PLY.replace("1 0 0\n", "1 0\n");
    let e = parse_model(bad.as_bytes(), Format::Ply, Path::new("dragon.ply.gz")).unwrap_err();
    assert_eq!(
        e.to_string(),
        "dragon.ply.gz: line 11: expected 3 values in vertex 1, found 2"
    );
    let e = parse_model(b"v 1 2\n", Format::Obj, Path::new("a.obj")).unwrap_err();
    assert_eq!(
        e.to_string(),
        "a.obj: line 1: expected 3 vertex coordinates, found 2"
    );
    // A std error, usable with `?` and boxed.
    let boxed: Box<dyn std::error::Error> = Box::new(e);
    assert!(boxed.to_string().starts_with("a.obj: "));
}

#[test]
fn a_format_mismatch_is_an_error_not_a_panic() {
    for format in [
        Format::Ply,
        Format::Obj,
        Format::Off,
        Format::Gltf,
        Format::Glb,
    ] {
        for bytes in [
            PLY.as_bytes(),
            OFF.as_bytes(),
            b"glTF\x02\0\0\0\xff\xff\xff\xff",
            b"{",
            b"",
        ] {
            let r = parse_model(bytes, format, Path::new("x"));
            if let Err(e) = r {
                assert!(e.to_string().starts_with("x: "), "{e}");
            }
        }
    }
}
