//! glTF loader: a hand-built `.glb` with instanced meshes under a transformed parent, a `.gltf`
//! with a `data:` URI, strips and fans, external buffers, and malformed files.

use std::path::Path;

use base64::Engine as _;
use glam::{Mat4, Vec3};
use strata_scene::load::{
    Format, LoadError, LoadErrorKind, Location, Model, load_model, parse_model,
};

const QUAD: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
];

fn f32s(values: &[[f32; 3]]) -> Vec<u8> {
    values
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

/// A GLB container holding `json` and `bin`.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut json = json.as_bytes().to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// The binary buffer of [`engine_json`]: quad positions (48 bytes), then u16 indices (12).
fn engine_bin() -> Vec<u8> {
    let mut bin = f32s(&QUAD);
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    bin
}

/// A parent node translated by (10, 0, 0) whose children instance the quad mesh (one moved up,
/// one scaled), a points-only mesh that yields no part, and a node outside the scene.
const ENGINE: &str = r#"{
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0]}],
  "nodes": [
    {"name": "parent", "translation": [10, 0, 0], "children": [1, 2, 3]},
    {"name": "left", "translation": [0, 1, 0], "mesh": 0},
    {"scale": [2, 2, 2], "mesh": 0},
    {"mesh": 1},
    {"name": "outside", "mesh": 0}
  ],
  "meshes": [
    {"name": "quad", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]},
    {"name": "points", "primitives": [{"attributes": {"POSITION": 0}, "mode": 0}]}
  ],
  "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1.0, 0.75]}}],
  "accessors": [
    {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
     "min": [0, 0, 0], "max": [1, 1, 0]},
    {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
  ],
  "bufferViews": [
    {"buffer": 0, "byteOffset": 0, "byteLength": 48},
    {"buffer": 0, "byteOffset": 48, "byteLength": 12}
  ],
  "buffers": [{"byteLength": 60}]
}"#;

fn parse_glb(bytes: &[u8]) -> Result<Model, LoadError> {
    parse_model(bytes, Format::Glb, Path::new("engine.glb"))
}

fn assert_close(a: Mat4, b: Mat4) {
    assert!(a.abs_diff_eq(b, 1e-6), "{a} != {b}");
}

#[test]
fn glb_parts_names_and_world_transforms() {
    let m = parse_glb(&glb(ENGINE, &engine_bin())).unwrap();
    let names: Vec<&str> = m.parts.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["left", "quad"]);
    assert_close(
        m.parts[0].transform,
        Mat4::from_translation(Vec3::new(10.0, 1.0, 0.0)),
    );
    assert_close(
        m.parts[1].transform,
        Mat4::from_translation(Vec3::new(10.0, 0.0, 0.0)) * Mat4::from_scale(Vec3::splat(2.0)),
    );
    for p in &m.parts {
        assert_eq!(p.mesh.positions(), &QUAD);
        assert_eq!(p.mesh.triangles(), &[[0, 1, 2], [0, 2, 3]]);
        assert!(!p.mesh.has_file_normals());
        assert_eq!(p.base_color, Some([0.5, 0.25, 1.0, 0.75]));
    }
    // The same file through load_model, named .glb or sniffed without an extension.
    let dir = tempfile::tempdir().unwrap();
    for name in ["engine.glb", "engine"] {
        let path = dir.path().join(name);
        std::fs::write(&path, glb(ENGINE, &engine_bin())).unwrap();
        assert_eq!(load_model(&path).unwrap(), m);
    }
}

/// Quad positions, +z normals and u8 indices 0 1 2 3, as one buffer of 100 bytes.
fn strip_bin() -> Vec<u8> {
    let mut bin = f32s(&QUAD);
    bin.extend(f32s(&[[0.0, 0.0, 1.0]; 4]));
    bin.extend_from_slice(&[0, 1, 2, 3]);
    bin
}

/// No scene: every root node is walked. Node 0 (a strip and a fan, both with normals) has
/// child node 1 (placed by a matrix; a mesh where one primitive lacks normals); node 2 uses an
/// unnamed mesh.
fn strip_json(uri: &str) -> String {
    format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "nodes": [
    {{"name": "a", "mesh": 0, "children": [1]}},
    {{"mesh": 1, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 5,6,7,1]}},
    {{"mesh": 2, "rotation": [0, 0, 0.7071068, 0.7071068]}}
  ],
  "meshes": [
    {{"name": "strip", "primitives": [
      {{"attributes": {{"POSITION": 0, "NORMAL": 1}}, "mode": 5}},
      {{"attributes": {{"POSITION": 0, "NORMAL": 1}}, "indices": 2, "mode": 6}},
      {{"attributes": {{"POSITION": 0}}, "mode": 1}}
    ]}},
    {{"name": "mixed", "primitives": [
      {{"attributes": {{"POSITION": 0, "NORMAL": 1}}, "indices": 3}},
      {{"attributes": {{"POSITION": 0}}, "indices": 3}}
    ]}},
    {{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 3}}]}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"}},
    {{"bufferView": 2, "componentType": 5121, "count": 4, "type": "SCALAR"}},
    {{"bufferView": 2, "componentType": 5121, "count": 3, "type": "SCALAR"}}
  ],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 48, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 96, "byteLength": 4}}
  ],
  "buffers": [{{"byteLength": 100, "uri": "{uri}"}}]
}}"#
    )
}

fn data_uri(bytes: &[u8]) -> String {
    format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

fn check_strip_model(m: &Model) {
    let names: Vec<&str> = m.parts.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["a", "mixed", "node2"]);
    let strip = &m.parts[0].mesh;
    assert_eq!(strip.positions().len(), 8);
    assert_eq!(&strip.positions()[4..], &QUAD);
    // Strip 0 1 2 3 → (0 1 2) (1 3 2); fan 0 1 2 3 (+4) → (5 6 4) (6 7 4).
    assert_eq!(
        strip.triangles(),
        &[[0, 1, 2], [1, 3, 2], [5, 6, 4], [6, 7, 4]]
    );
    assert!(strip.has_file_normals());
    assert_eq!(strip.normals(), &[[0.0, 0.0, 1.0]; 8]);
    assert_eq!(m.parts[0].transform, Mat4::IDENTITY);
    assert_eq!(m.parts[0].base_color, None);

    let mixed = &m.parts[1].mesh;
    assert_eq!(mixed.triangles(), &[[0, 1, 2], [4, 5, 6]]);
    assert!(!mixed.has_file_normals(), "one primitive lacks NORMAL");
    assert_close(
        m.parts[1].transform,
        Mat4::from_translation(Vec3::new(5.0, 6.0, 7.0)),
    );

    assert_close(
        m.parts[2].transform,
        Mat4::from_rotation_z(std::f32::consts::FRAC_PI_2),
    );
    assert_eq!(m.parts[2].mesh.triangles(), &[[0, 1, 2]]);
}

#[test]
fn gltf_with_data_uri_strips_fans_and_root_nodes() {
    let json = strip_json(&data_uri(&strip_bin()));
    let m = parse_model(json.as_bytes(), Format::Gltf, Path::new("strip.gltf")).unwrap();
    check_strip_model(&m);
}

#[test]
fn gltf_with_an_external_buffer_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("bin data")).unwrap();
    std::fs::write(dir.path().join("bin data/strip.bin"), strip_bin()).unwrap();
    let path = dir.path().join("strip.gltf");
    std::fs::write(&path, strip_json("bin%20data/strip.bin")).unwrap();
    check_strip_model(&load_model(&path).unwrap());

    std::fs::write(&path, strip_json("missing.bin")).unwrap();
    let e = load_model(&path).unwrap_err();
    assert!(matches!(e.kind, LoadErrorKind::Io(_)), "{e}");
    assert!(e.to_string().contains("buffer 0 file"), "{e}");
    assert!(e.to_string().contains("missing.bin"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Malformed input.

fn glb_error(json: &str, bin: &[u8]) -> LoadError {
    let e = parse_glb(&glb(json, bin)).expect_err("malformed input must fail");
    assert!(e.to_string().starts_with("engine.glb: "), "{e}");
    e
}

fn gltf_error(json: &str) -> LoadError {
    let e = parse_model(json.as_bytes(), Format::Gltf, Path::new("dir/bad.gltf"))
        .expect_err("malformed input must fail");
    assert!(e.to_string().starts_with("dir/bad.gltf: "), "{e}");
    e
}

#[test]
fn buffer_view_and_accessor_ranges_are_checked() {
    let bin = engine_bin();
    let e = glb_error(
        &ENGINE.replace(
            r#""byteOffset": 48, "byteLength": 12"#,
            r#""byteOffset": 48, "byteLength": 4096"#,
        ),
        &bin,
    );
    assert_eq!(
        e.to_string(),
        "engine.glb: buffer 0 is 60 bytes but buffer view 1 needs 4144"
    );
    assert!(matches!(e.kind, LoadErrorKind::Invalid(_)));
    assert_eq!(e.location, None);

    let e = glb_error(
        &ENGINE.replace(
            r#""count": 4, "type": "VEC3""#,
            r#""count": 5, "type": "VEC3""#,
        ),
        &bin,
    );
    assert_eq!(
        e.to_string(),
        "engine.glb: buffer view 0 is 48 bytes but accessor 0 needs 60"
    );

    let e = glb_error(
        &ENGINE.replace(
            r#""componentType": 5123, "count": 6"#,
            r#""componentType": 5123, "count": 6, "byteOffset": 2"#,
        ),
        &bin,
    );
    assert_eq!(
        e.to_string(),
        "engine.glb: buffer view 1 is 12 bytes but accessor 1 needs 14"
    );

    let e = glb_error(
        &ENGINE.replace(
            r#""byteOffset": 0, "byteLength": 48}"#,
            r#""byteOffset": 0, "byteLength": 48, "byteStride": 8}"#,
        ),
        &bin,
    );
    assert!(
        e.to_string().contains(
            "buffer view 0 has a byteStride of 8, less than the 12-byte elements of accessor 0"
        ),
        "{e}"
    );

    let e = glb_error(
        &ENGINE.replace(r#""byteLength": 60}"#, r#""byteLength": 64}"#),
        &bin,
    );
    assert_eq!(
        e.to_string(),
        "engine.glb: buffer 0 is 60 bytes but its byteLength is 64"
    );

    let e = glb_error(
        &ENGINE.replace(r#""type": "VEC3""#, r#""type": "VEC2""#),
        &bin,
    );
    assert!(
        e.to_string()
            .contains("accessor 0 (POSITION) is VEC2; expected VEC3"),
        "{e}"
    );

    let e = glb_error(
        &ENGINE.replace(
            r#""componentType": 5123, "count": 6"#,
            r#""componentType": 5126, "count": 3"#,
        ),
        &bin,
    );
    assert!(
        e.to_string()
            .contains("accessor 1 (indices) has component type F32"),
        "{e}"
    );

    let mut bad = bin.clone();
    bad[48 + 4..48 + 6].copy_from_slice(&7u16.to_le_bytes());
    let e = glb_error(ENGINE, &bad);
    assert_eq!(
        e.to_string(),
        "engine.glb: mesh 0 primitive 0: index 7 is out of range for 4 vertices"
    );

    let mut bad = bin.clone();
    bad[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = glb_error(ENGINE, &bad);
    assert!(
        e.to_string()
            .contains("mesh 0: vertex 0 has a non-finite coordinate NaN"),
        "{e}"
    );
}

#[test]
fn glb_container_errors_give_the_byte_offset() {
    let good = glb(ENGINE, &engine_bin());
    let e = parse_glb(&good[..good.len() - 1]).unwrap_err();
    assert_eq!(e.location, Some(Location::Byte(8)), "{e}");
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)));
    assert!(
        e.to_string()
            .starts_with("engine.glb: byte 8: the GLB header declares"),
        "{e}"
    );

    // The JSON chunk claims more than there is.
    let mut bad = good.clone();
    bad[12..16].copy_from_slice(&100_000u32.to_le_bytes());
    let e = parse_glb(&bad).unwrap_err();
    assert_eq!(e.location, Some(Location::Byte(12)), "{e}");
    assert!(
        e.to_string().contains("GLB chunk 0 declares 100000 bytes"),
        "{e}"
    );

    // A header length below the header size, a wrong version, a too-short file.
    let mut bad = good.clone();
    bad[8..12].copy_from_slice(&3u32.to_le_bytes());
    let e = parse_glb(&bad).unwrap_err();
    assert!(e.to_string().contains("no JSON chunk"), "{e}");
    let mut bad = good.clone();
    bad[4] = 1;
    let e = parse_glb(&bad).unwrap_err();
    assert_eq!(e.location, Some(Location::Byte(4)));
    assert!(matches!(e.kind, LoadErrorKind::Unsupported(_)), "{e}");
    let e = parse_glb(b"glTF\x02\0").unwrap_err();
    assert!(matches!(e.kind, LoadErrorKind::Truncated(_)), "{e}");

    // BIN chunk missing while a buffer has no uri.
    let json = glb(ENGINE, &[]);
    let cut = json.len() - 8;
    let mut bad = json[..cut].to_vec();
    bad[8..12].copy_from_slice(&(cut as u32).to_le_bytes());
    let e = parse_glb(&bad).unwrap_err();
    assert!(
        e.to_string()
            .contains("buffer 0 has no uri and the file has no GLB BIN chunk"),
        "{e}"
    );
}

#[test]
fn json_and_structure_errors() {
    // A JSON syntax error in a .gltf file carries its line.
    let e = gltf_error("{\n  \"asset\": {\"version\": \"2.0\"},\n  \"nodes\": [,]\n}");
    assert_eq!(e.location, Some(Location::Line(3)), "{e}");
    assert!(matches!(e.kind, LoadErrorKind::Gltf(_)));
    assert!(
        e.to_string()
            .starts_with("dir/bad.gltf: line 3: invalid glTF JSON"),
        "{e}"
    );

    // References to missing objects fail validation (a POSITION one before it could panic).
    let e = glb_error(
        &ENGINE.replace(r#""mesh": 1}"#, r#""mesh": 9}"#),
        &engine_bin(),
    );
    assert!(matches!(e.kind, LoadErrorKind::Gltf(_)), "{e}");
    let e = glb_error(
        &ENGINE.replace(r#""POSITION": 0}, "mode""#, r#""POSITION": 9}, "mode""#),
        &engine_bin(),
    );
    assert!(
        e.to_string().contains(
            "mesh 1 primitive 0: POSITION refers to accessor 9, but there are only 2 accessors"
        ),
        "{e}"
    );

    // A cycle, and a node reached twice.
    let e = glb_error(
        &ENGINE.replace(r#""children": [1, 2, 3]"#, r#""children": [1, 2, 3, 0]"#),
        &engine_bin(),
    );
    assert!(
        e.to_string()
            .contains("node 0 appears more than once in the node hierarchy"),
        "{e}"
    );
    let e = glb_error(
        &ENGINE.replace(r#""nodes": [0]"#, r#""nodes": [0, 2]"#),
        &engine_bin(),
    );
    assert!(
        e.to_string().contains("node 2 appears more than once"),
        "{e}"
    );

    // Nothing triangular.
    let e = glb_error(
        &ENGINE.replace(r#""children": [1, 2, 3]"#, r#""children": [3]"#),
        &engine_bin(),
    );
    assert!(matches!(e.kind, LoadErrorKind::Empty(_)), "{e}");
    assert_eq!(e.to_string(), "engine.glb: the scene contains no triangles");

    // URIs.
    for (uri, what) in [
        ("http://example.com/a.bin", "buffer 0 has a 'http:' URI"),
        ("/etc/a.bin", "buffer 0 has an absolute path"),
        ("data:application/octet-stream,abc", "not base64-encoded"),
    ] {
        let e = gltf_error(&strip_json(uri));
        assert!(matches!(e.kind, LoadErrorKind::Unsupported(_)), "{e}");
        assert!(e.to_string().contains(what), "{e}");
    }
    let e = gltf_error(&strip_json("data:application/octet-stream;base64,!!!!"));
    assert!(
        e.to_string().contains("buffer 0 has invalid base64 data"),
        "{e}"
    );
    let e = gltf_error(&strip_json(&data_uri(&strip_bin()[..90])));
    assert_eq!(
        e.to_string(),
        "dir/bad.gltf: buffer 0 is 90 bytes but its byteLength is 100"
    );
    let e = gltf_error(&strip_json(&data_uri(&strip_bin())).replace(r#", "uri": "#, r#", "x": "#));
    assert!(
        e.to_string()
            .contains("buffer 0 has no uri and the file has no GLB BIN chunk"),
        "{e}"
    );

    // A bad rotation.
    let e = gltf_error(
        &strip_json(&data_uri(&strip_bin()))
            .replace("[0, 0, 0.7071068, 0.7071068]", "[0, 0, 0, 0]"),
    );
    assert!(
        e.to_string().contains("node 2 has an invalid rotation"),
        "{e}"
    );
}

#[test]
fn sparse_accessors_are_applied() {
    // Replace vertex 2 of the quad by (5, 5, 5) through a sparse accessor.
    let mut bin = engine_bin();
    bin.extend_from_slice(&2u16.to_le_bytes());
    bin.extend_from_slice(&[0, 0]);
    bin.extend(f32s(&[[5.0, 5.0, 5.0]]));
    let json = ENGINE
        .replace(
            r#""min": [0, 0, 0], "max": [1, 1, 0]}"#,
            r#""min": [0, 0, 0], "max": [5, 5, 5], "sparse": {"count": 1,
               "indices": {"bufferView": 2, "componentType": 5123},
               "values": {"bufferView": 3}}}"#,
        )
        .replace(
            r#"{"buffer": 0, "byteOffset": 48, "byteLength": 12}"#,
            r#"{"buffer": 0, "byteOffset": 48, "byteLength": 12},
               {"buffer": 0, "byteOffset": 60, "byteLength": 2},
               {"buffer": 0, "byteOffset": 64, "byteLength": 12}"#,
        )
        .replace(r#""byteLength": 60}"#, r#""byteLength": 76}"#);
    let m = parse_glb(&glb(&json, &bin)).unwrap();
    assert_eq!(
        m.parts[0].mesh.positions(),
        &[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [5.0, 5.0, 5.0],
            [0.0, 1.0, 0.0]
        ]
    );
    // A sparse index past the accessor's count.
    let mut bad = bin.clone();
    bad[60..62].copy_from_slice(&4u16.to_le_bytes());
    let e = glb_error(&json, &bad);
    assert!(
        e.to_string()
            .contains("sparse index 4 of accessor 0 is out of range for 4 elements"),
        "{e}"
    );
}
