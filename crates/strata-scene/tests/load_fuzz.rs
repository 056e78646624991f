//! Property tests: for a valid sample of every format, truncation at any offset, random byte
//! flips, random insertions and absurd numbers give `Ok` or `Err` from `parse_model`, never a
//! panic, and every error names the file.
//!
//! Nothing here measures time: a loader that trusted a huge claimed count would abort on the
//! allocation or run the suite into its time limit, and the exact refusals of huge counts (before
//! anything is reserved) are asserted by each format's own tests.

use std::path::Path;

use base64::Engine as _;
use proptest::prelude::*;
use proptest::sample::Index;
use strata_scene::load::{Format, parse_model};

const PLY_ASCII: &str = "ply\nformat ascii 1.0\ncomment c\nelement vertex 4\nproperty float x\n\
    property float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
    element face 2\nproperty list uchar int vertex_indices\nproperty list uchar float tex\n\
    element extra 1\nproperty list int short data\nend_header\n\
    0 0 0 0 0 1\n1 0 0 0 0 1\n1 1 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2 2 0.5 0.5\n4 0 1 2 3 0\n2 7 8\n";

/// A binary PLY with skipped scalars and lists around the needed properties.
fn ply_binary(big: bool) -> Vec<u8> {
    let format = if big {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut out = format!(
        "ply\nformat {format} 1.0\nelement vertex 4\nproperty double x\nproperty uchar flag\n\
         property float y\nproperty list ushort int8 junk\nproperty int z\n\
         element face 2\nproperty list uint8 uint32 vertex_indices\nproperty char f\n\
         end_header\n"
    )
    .into_bytes();
    macro_rules! put {
        ($v:expr) => {
            out.extend_from_slice(&if big {
                $v.to_be_bytes()
            } else {
                $v.to_le_bytes()
            })
        };
    }
    for (i, p) in [
        [0.0f64, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ]
    .iter()
    .enumerate()
    {
        put!(p[0]);
        put!(7u8);
        put!(p[1] as f32);
        put!(i as u16);
        out.extend(std::iter::repeat_n(3u8, i));
        put!(p[2] as i32);
    }
    for f in [&[0u32, 1, 2][..], &[0, 1, 2, 3]] {
        put!(f.len() as u8);
        for &i in f {
            put!(i);
        }
        put!(-1i8);
    }
    out
}

const OBJ: &str = "# c\nv 0 0 0\nv 1 0 0 1\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n\
    f 1/1/1 2/1/1 3/1/1\nf -4//1 -2//1 -1//1\ng x\nf 1 2 3 4\nl 1 2\n";

const OFF: &str = "# c\nCNOFF\n4 2 0\n0 0 0 0 0 1 1 0 0 1\n1 0 0 0 0 1 1 0 0 1\n\
    1 1 0 0 0 1 1 0 0 1\n0 1 0 0 0 1 1 0 0 1\n3 0 1 2 255 0 0\n4 0 1 2 3\n";

fn bin() -> Vec<u8> {
    let mut b: Vec<u8> = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ]
    .iter()
    .flatten()
    .flat_map(|v| v.to_le_bytes())
    .collect();
    for i in [0u16, 1, 2, 0, 2, 3] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    b
}

fn json(uri: &str) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
"nodes":[{{"children":[1,2],"translation":[1,2,3]}},{{"mesh":0}},{{"mesh":0,"scale":[2,2,2]}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}},
{{"attributes":{{"POSITION":0}},"mode":5}}]}}],
"materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[1,0,0,1]}}}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
{{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48,"byteStride":12}},{{"buffer":0,"byteOffset":48,"byteLength":12}}],
"buffers":[{{"byteLength":60{uri}}}]}}"#
    )
}

fn gltf_text() -> String {
    let uri = base64::engine::general_purpose::STANDARD.encode(bin());
    json(&format!(
        r#","uri":"data:application/octet-stream;base64,{uri}""#
    ))
}

fn glb_from(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let mut j = json.to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let total = 12 + 8 + j.len() + 8 + bin.len();
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out
}

fn glb() -> Vec<u8> {
    glb_from(json("").as_bytes(), &bin())
}

/// A unit square and a triangle above it, as STL stores them (corners repeated).
const STL_TRIANGLES: [[[f32; 3]; 3]; 3] = [
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
    [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
    [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0]],
];

/// A binary STL whose header starts with `solid`, as many exporters write it.
fn stl_binary() -> Vec<u8> {
    let mut out = b"solid square".to_vec();
    out.resize(80, b' ');
    out.extend_from_slice(&(STL_TRIANGLES.len() as u32).to_le_bytes());
    for t in STL_TRIANGLES {
        let normal = [0.0f32, 0.0, 1.0];
        for v in normal.iter().chain(t.iter().flatten()) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&0u16.to_le_bytes());
    }
    out
}

const STL_ASCII: &str = "solid square\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n\
    vertex 1 1 0\nendloop\nendfacet\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n\
    vertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid square\n\
    solid again\nfacet normal 0 0 1 outer loop vertex 0 0 1 vertex 1 0 1 vertex 1 1 1\n\
    endloop endfacet\nendsolid\n";

/// Every sample, its format, and a file name.
fn samples() -> Vec<(Format, Vec<u8>)> {
    vec![
        (Format::Ply, PLY_ASCII.as_bytes().to_vec()),
        (Format::Ply, ply_binary(false)),
        (Format::Ply, ply_binary(true)),
        (Format::Obj, OBJ.as_bytes().to_vec()),
        (Format::Off, OFF.as_bytes().to_vec()),
        (Format::Gltf, gltf_text().into_bytes()),
        (Format::Glb, glb()),
        (Format::Stl, stl_binary()),
        (Format::Stl, STL_ASCII.as_bytes().to_vec()),
    ]
}

/// How many [`samples`] there are (proptest ranges need a constant).
const SAMPLES: usize = 9;

/// Parses `bytes`; an error must name the file. Panics propagate and fail the property.
fn survive(format: Format, bytes: &[u8]) {
    let r = parse_model(bytes, format, Path::new("fuzz.bin"));
    if let Err(e) = r {
        assert!(e.to_string().starts_with("fuzz.bin: "), "{e}");
    }
}

#[test]
fn samples_are_valid() {
    assert_eq!(samples().len(), SAMPLES);
    for (format, bytes) in samples() {
        let m = parse_model(&bytes, format, Path::new("fuzz.bin"))
            .unwrap_or_else(|e| panic!("{format}: {e}"));
        let triangles: usize = m.parts.iter().map(|p| p.mesh.triangles().len()).sum();
        assert!(triangles >= 3, "{format}");
    }
}

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: 256,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// Numbers worth substituting: zero, negatives, limits, huge and fractional values.
const ODD_NUMBERS: [&str; 12] = [
    "0",
    "-1",
    "1",
    "3",
    "255",
    "65536",
    "2147483648",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "1e30",
    "0.5",
];

/// `bytes` with the `which`-th run of ASCII digits replaced by `number`.
fn replace_number(bytes: &[u8], which: Index, number: &str) -> Vec<u8> {
    let mut runs = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit() {
            let start = i;
            while i < bytes.len() && bytes[i].is_ascii_digit() {
                i += 1;
            }
            runs.push(start..i);
        } else {
            i += 1;
        }
    }
    if runs.is_empty() {
        return bytes.to_vec();
    }
    let r = runs[which.index(runs.len())].clone();
    let mut out = bytes[..r.start].to_vec();
    out.extend_from_slice(number.as_bytes());
    out.extend_from_slice(&bytes[r.end..]);
    out
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn truncation_at_any_offset(sample in 0..SAMPLES, cut in any::<Index>()) {
        let (format, bytes) = &samples()[sample];
        let at = cut.index(bytes.len() + 1);
        survive(*format, &bytes[..at]);
    }

    #[test]
    fn random_byte_flips(
        sample in 0..SAMPLES,
        flips in prop::collection::vec((any::<Index>(), 1..=255u8), 1..8),
    ) {
        let (format, mut bytes) = samples().swap_remove(sample);
        for (at, x) in flips {
            let i = at.index(bytes.len());
            bytes[i] ^= x;
        }
        survive(format, &bytes);
    }

    #[test]
    fn random_insertions(
        sample in 0..SAMPLES,
        inserts in prop::collection::vec(
            (any::<Index>(), prop::collection::vec(prop_oneof![
                any::<u8>(),
                Just(b'\n'),
                Just(b' '),
                Just(b'-'),
                Just(b'/'),
                Just(b'#'),
                Just(b'9'),
            ], 1..6)),
            1..5,
        ),
    ) {
        let (format, mut bytes) = samples().swap_remove(sample);
        for (at, ins) in inserts {
            let i = at.index(bytes.len() + 1);
            bytes.splice(i..i, ins);
        }
        survive(format, &bytes);
    }

    /// Any number in a text sample (counts, indices, offsets, lengths) replaced by an odd one.
    #[test]
    fn odd_numbers_in_text(
        sample in prop::sample::select(vec![0usize, 3, 4, 5, 8]),
        which in any::<Index>(),
        number in prop::sample::select(ODD_NUMBERS.to_vec()),
    ) {
        let (format, bytes) = &samples()[sample];
        survive(*format, &replace_number(bytes, which, number));
    }

    /// The same inside a GLB's JSON chunk, with flips in its BIN chunk.
    #[test]
    fn odd_numbers_in_glb(
        which in any::<Index>(),
        number in prop::sample::select(ODD_NUMBERS.to_vec()),
        flips in prop::collection::vec((any::<Index>(), any::<u8>()), 0..4),
    ) {
        let json = replace_number(json("").as_bytes(), which, number);
        let mut b = bin();
        for (at, x) in flips {
            let i = at.index(b.len());
            b[i] ^= x;
        }
        survive(Format::Glb, &glb_from(&json, &b));
    }

    /// Headers claiming up to 2^64 - 1 items in a tiny file are survived.
    #[test]
    fn huge_claimed_counts(
        n in prop_oneof![any::<u64>(), 1_000_000u64..u64::from(u32::MAX) + 2],
        m in any::<u64>(),
        list in any::<u32>(),
        enc in 0..3usize,
    ) {
        let format = ["ascii", "binary_little_endian", "binary_big_endian"][enc];
        let mut ply = format!(
            "ply\nformat {format} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n\
             property float z\nelement face {m}\nproperty list uint uint vertex_indices\nend_header\n"
        )
        .into_bytes();
        ply.extend_from_slice(&[0; 24]);
        ply.extend_from_slice(&list.to_le_bytes());
        ply.extend_from_slice(b"0 0 0\n1 1 1\n3 0 1 2\n");
        survive(Format::Ply, &ply);
        survive(Format::Off, format!("OFF\n{n} {m} 0\n0 0 0\n1 0 0\n{list} 0 1\n").as_bytes());
        let gltf = gltf_text().replace(r#""count":4"#, &format!(r#""count":{n}"#));
        survive(Format::Gltf, gltf.as_bytes());
        let mut stl = stl_binary();
        stl[80..84].copy_from_slice(&(n as u32).to_le_bytes());
        survive(Format::Stl, &stl);
    }
}
