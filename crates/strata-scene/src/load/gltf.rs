//! glTF 2.0 loader (`.gltf` JSON and `.glb`): one [`ModelPart`] per mesh-carrying node.
//!
//! The JSON is parsed and validated by the `gltf` crate (built without its importer); the GLB
//! container, buffers and accessors are handled here, reading the validated JSON structures
//! directly rather than through the crate's wrappers and accessor reader. Buffers come from the
//! GLB `BIN` chunk, base64 `data:` URIs, or files named by relative URIs next to the glTF file;
//! other URI schemes and absolute paths are rejected. The default scene (else scene 0, else
//! every root node) is walked depth first with world = parent × local; a node reached twice (a
//! cycle, or a node with two parents) is an error. Every node with a mesh becomes a part whose
//! mesh merges the mesh's `TRIANGLES`, `TRIANGLE_STRIP` and `TRIANGLE_FAN` primitives (strips and
//! fans converted to triangle lists); point and line primitives are skipped, and a file without
//! any triangle is an error. The part's base colour is the `baseColorFactor` of the material of
//! the mesh's first triangle primitive, `None` when that primitive has no material.
//! Non-indexed primitives use vertices `0..n`. File normals are used only when every triangle
//! primitive of the mesh has `NORMAL`. Positions and normals may be float or (normalized)
//! integer accessors; sparse accessors are applied; accessors without a buffer view are
//! unsupported. Skins, morph targets and textures are ignored.
//!
//! Every buffer view and accessor range is checked against the data before anything is read,
//! and all reads here are bounds-checked slices, so malformed files give errors, never panics
//! (the `gltf` crate's own GLB parser and accessor reader, which can panic on bad lengths and
//! ranges, are not used; the one unchecked index in its validation is checked beforehand). Errors
//! name the glTF object (`buffer 0 is 120 bytes but buffer view 3 needs 4096`); only JSON syntax
//! errors of a `.gltf` file carry a location, the line. GLB container errors give the byte offset.

use std::collections::HashMap;
use std::path::Path;

use ::gltf::json::accessor::{ComponentType, GenericComponentType, IndexComponentType, Type};
use ::gltf::json::mesh::{Mode, Semantic};
use ::gltf::json::validation::Checked;
use ::gltf::json::{self, Root};
use base64::Engine as _;
use glam::{Mat4, Quat, Vec3};

use super::{Fail, LoadErrorKind, Location, Model, ModelPart};
use crate::mesh::Mesh;

/// The most accessor elements a file may make the loader read and copy, all meshes and parts
/// together (2^26, about a GiB of vertices and triangles): primitives and nodes reusing a large
/// accessor many times would otherwise turn a small file into an absurd allocation.
const MAX_OUTPUT: u64 = 1 << 26;

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

fn invalid(msg: String) -> Fail {
    Fail::nowhere(LoadErrorKind::Invalid(msg))
}

fn unsupported(msg: String) -> Fail {
    Fail::nowhere(LoadErrorKind::Unsupported(msg))
}

/// Parses a `.gltf` or `.glb` file (told apart by the GLB magic, whatever the extension).
pub(super) fn parse(bytes: &[u8], path: &Path) -> Result<Model, Fail> {
    parse_limited(bytes, path, MAX_OUTPUT)
}

/// [`parse`] with a custom element budget (see [`MAX_OUTPUT`]).
fn parse_limited(bytes: &[u8], path: &Path, limit: u64) -> Result<Model, Fail> {
    let (json_bytes, bin, is_glb) = if bytes.starts_with(GLB_MAGIC) {
        let (json, bin) = split_glb(bytes)?;
        (json, bin, true)
    } else {
        (bytes, None, false)
    };
    let root: Root = json::deserialize::from_slice(json_bytes).map_err(|e| {
        let location = (!is_glb && e.line() > 0).then(|| Location::Line(e.line() as u64));
        Fail::new(
            location,
            LoadErrorKind::Gltf(format!("invalid glTF JSON: {e}")),
        )
    })?;
    // gltf-json 1.4.1's validation indexes `accessors[POSITION]` without a bounds check (in
    // `primitive_validate_hook`), so a bad POSITION index would panic inside `validate`: rule
    // it out first. Everything else the validation reads is bounds-checked.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            if let Some(a) = prim.attributes.get(&Checked::Valid(Semantic::Positions))
                && a.value() >= root.accessors.len()
            {
                return Err(invalid(format!(
                    "mesh {m} primitive {pi}: POSITION refers to accessor {}, but there are only {} accessors",
                    a.value(),
                    root.accessors.len()
                )));
            }
        }
    }
    let root = ::gltf::Document::from_json(root)
        .map_err(|e| Fail::nowhere(LoadErrorKind::Gltf(e.to_string())))?
        .into_json();
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut loader = Loader {
        root: &root,
        buffers: Buffers {
            root: &root,
            bin,
            dir,
            data: vec![None; root.buffers.len()],
        },
        meshes: HashMap::new(),
        budget: Budget { spent: 0, limit },
    };
    let parts = loader.walk()?;
    if parts.is_empty() {
        return Err(Fail::nowhere(LoadErrorKind::Empty(
            "the scene contains no triangles".to_owned(),
        )));
    }
    Ok(Model { parts })
}

/// Reads a little-endian u32 at `at`.
fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes(b.try_into().ok()?))
}

/// Splits a GLB container into its JSON chunk and optional BIN chunk.
fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), Fail> {
    let truncated = |at: usize, msg: String| Fail::byte(at, LoadErrorKind::Truncated(msg));
    let version = u32_at(bytes, 4).ok_or_else(|| {
        truncated(
            bytes.len(),
            "unexpected end of file in the GLB header".to_owned(),
        )
    })?;
    if version != 2 {
        return Err(Fail::byte(
            4,
            LoadErrorKind::Unsupported(format!("GLB version {version}; expected 2")),
        ));
    }
    let length = u32_at(bytes, 8).ok_or_else(|| {
        truncated(
            bytes.len(),
            "unexpected end of file in the GLB header".to_owned(),
        )
    })? as usize;
    if length > bytes.len() {
        return Err(truncated(
            8,
            format!(
                "the GLB header declares {length} bytes but the file has {}",
                bytes.len()
            ),
        ));
    }
    let bytes = &bytes[..length];
    let mut at = 12;
    let mut json = None;
    let mut bin = None;
    let mut index = 0;
    while at < bytes.len() {
        let (Some(len), Some(ty)) = (u32_at(bytes, at), u32_at(bytes, at + 4)) else {
            return Err(truncated(
                at,
                format!("unexpected end of file in GLB chunk {index} header"),
            ));
        };
        let start = at + 8;
        let data = start
            .checked_add(len as usize)
            .and_then(|end| bytes.get(start..end))
            .ok_or_else(|| {
                truncated(
                    at,
                    format!(
                        "GLB chunk {index} declares {len} bytes but only {} remain",
                        bytes.len() - start.min(bytes.len())
                    ),
                )
            })?;
        match (index, ty) {
            (0, CHUNK_JSON) => json = Some(data),
            (0, _) => {
                return Err(Fail::byte(
                    at + 4,
                    LoadErrorKind::Invalid(format!(
                        "expected the JSON chunk first, found chunk type {ty:#010x}"
                    )),
                ));
            }
            (1, CHUNK_BIN) => bin = Some(data),
            // Unknown chunks are to be ignored.
            _ => {}
        }
        at = start + data.len();
        index += 1;
    }
    let json = json.ok_or_else(|| truncated(12, "the GLB file has no JSON chunk".to_owned()))?;
    Ok((json, bin))
}

/// Buffers, loaded when first needed.
struct Buffers<'a> {
    root: &'a Root,
    bin: Option<&'a [u8]>,
    dir: &'a Path,
    /// Loaded data of each buffer: `Some(None)` is the BIN chunk, `Some(Some(v))` owned bytes.
    data: Vec<Option<Option<Vec<u8>>>>,
}

impl Buffers<'_> {
    /// Makes buffer `b`'s data available to [`Buffers::get`].
    fn load(&mut self, b: usize) -> Result<(), Fail> {
        if self.data.get(b).is_some_and(Option::is_some) {
            return Ok(());
        }
        let buffer = self
            .root
            .buffers
            .get(b)
            .ok_or_else(|| invalid(format!("buffer {b} does not exist")))?;
        let loaded = match &buffer.uri {
            None if self.bin.is_some() => None,
            None => {
                return Err(invalid(format!(
                    "buffer {b} has no uri and the file has no GLB BIN chunk"
                )));
            }
            Some(uri) => Some(self.fetch(b, uri)?),
        };
        let declared = buffer.byte_length.0;
        let actual = match &loaded {
            Some(v) => v.len(),
            None => self.bin.map_or(0, <[u8]>::len),
        };
        if (actual as u64) < declared {
            return Err(invalid(format!(
                "buffer {b} is {actual} bytes but its byteLength is {declared}"
            )));
        }
        if let Some(slot) = self.data.get_mut(b) {
            *slot = Some(loaded);
        }
        Ok(())
    }

    /// Bytes of a `data:` URI or of a file next to the glTF file.
    fn fetch(&self, b: usize, uri: &str) -> Result<Vec<u8>, Fail> {
        if let Some(rest) = uri.strip_prefix("data:") {
            let (header, payload) = rest.split_once(',').ok_or_else(|| {
                invalid(format!(
                    "buffer {b} has a data URI without a ',' before its data"
                ))
            })?;
            if !header.ends_with(";base64") {
                return Err(unsupported(format!(
                    "buffer {b} has a data URI that is not base64-encoded"
                )));
            }
            let engine = base64::engine::GeneralPurpose::new(
                &base64::alphabet::STANDARD,
                base64::engine::GeneralPurposeConfig::new()
                    .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
            );
            return engine
                .decode(payload.trim_ascii())
                .map_err(|e| invalid(format!("buffer {b} has invalid base64 data: {e}")));
        }
        if let Some(scheme) = uri_scheme(uri) {
            return Err(unsupported(format!(
                "buffer {b} has a '{scheme}:' URI; only data: URIs and relative file paths are supported"
            )));
        }
        if uri.starts_with('/') || uri.starts_with('\\') {
            return Err(unsupported(format!(
                "buffer {b} has an absolute path '{uri}'; only relative paths are supported"
            )));
        }
        let file = self.dir.join(percent_decode(uri));
        std::fs::read(&file).map_err(|e| {
            Fail::nowhere(LoadErrorKind::Io(std::io::Error::new(
                e.kind(),
                format!("buffer {b} file {}: {e}", file.display()),
            )))
        })
    }

    /// The data of a buffer passed to [`Buffers::load`], cut to its declared byteLength.
    fn get(&self, b: usize) -> &[u8] {
        let data = match self.data.get(b) {
            Some(Some(Some(v))) => &v[..],
            Some(Some(None)) => self.bin.unwrap_or_default(),
            _ => &[],
        };
        let declared = self.root.buffers.get(b).map_or(0, |buf| {
            usize::try_from(buf.byte_length.0).unwrap_or(usize::MAX)
        });
        &data[..data.len().min(declared)]
    }
}

/// The scheme of an absolute URI (`http` in `http://…`), if it has one.
fn uri_scheme(uri: &str) -> Option<&str> {
    let (scheme, _) = uri.split_once(':')?;
    let mut chars = scheme.chars();
    let first = chars.next()?;
    (first.is_ascii_alphabetic()
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.')))
    .then_some(scheme)
}

/// Decodes `%XX` escapes (invalid ones are kept as they are).
fn percent_decode(uri: &str) -> String {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%'
            && let (Some(h), Some(l)) = (
                b.get(i + 1).copied().and_then(hex),
                b.get(i + 2).copied().and_then(hex),
            )
        {
            out.push((h * 16 + l) as u8);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// A validated accessor's elements: `count` elements of `size` bytes, `stride` apart.
struct Elements<'d> {
    data: &'d [u8],
    count: usize,
    stride: usize,
    component: ComponentType,
    normalized: bool,
}

fn component_size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

fn type_name(t: Type) -> &'static str {
    match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

/// One component at the start of `b` (which holds at least its size), as f32.
#[inline]
fn component_f32(c: ComponentType, normalized: bool, b: &[u8]) -> Option<f32> {
    Some(match (c, normalized) {
        (ComponentType::F32, _) => f32::from_le_bytes(b.get(..4)?.try_into().ok()?),
        (ComponentType::I8, false) => f32::from(i8::from_le_bytes([*b.first()?])),
        (ComponentType::U8, false) => f32::from(*b.first()?),
        (ComponentType::I16, false) => f32::from(i16::from_le_bytes(b.get(..2)?.try_into().ok()?)),
        (ComponentType::U16, false) => f32::from(u16::from_le_bytes(b.get(..2)?.try_into().ok()?)),
        (ComponentType::U32, _) => u32::from_le_bytes(b.get(..4)?.try_into().ok()?) as f32,
        (ComponentType::I8, true) => {
            (f32::from(i8::from_le_bytes([*b.first()?])) / 127.0).max(-1.0)
        }
        (ComponentType::U8, true) => f32::from(*b.first()?) / 255.0,
        (ComponentType::I16, true) => {
            (f32::from(i16::from_le_bytes(b.get(..2)?.try_into().ok()?)) / 32767.0).max(-1.0)
        }
        (ComponentType::U16, true) => {
            f32::from(u16::from_le_bytes(b.get(..2)?.try_into().ok()?)) / 65535.0
        }
    })
}

/// One unsigned integer component at the start of `b`.
#[inline]
fn component_u32(c: ComponentType, b: &[u8]) -> Option<u32> {
    Some(match c {
        ComponentType::U8 => u32::from(*b.first()?),
        ComponentType::U16 => u32::from(u16::from_le_bytes(b.get(..2)?.try_into().ok()?)),
        ComponentType::U32 => u32::from_le_bytes(b.get(..4)?.try_into().ok()?),
        _ => return None,
    })
}

/// Where an accessor's (or its sparse part's) elements lie: `count` elements of `elem` bytes,
/// `stride` apart, starting `offset` bytes into buffer view `view`.
struct Span {
    view: usize,
    offset: u64,
    count: u64,
    elem: usize,
    stride: usize,
}

/// The bytes of a [`Span`]: checks the view against its buffer and the span against the view.
/// `who` names the reader in errors.
fn view_range<'d>(
    root: &Root,
    buffers: &'d Buffers<'_>,
    span: &Span,
    who: &str,
) -> Result<&'d [u8], Fail> {
    let &Span {
        view: v,
        offset,
        count,
        elem,
        stride,
    } = span;
    let view = root
        .buffer_views
        .get(v)
        .ok_or_else(|| invalid(format!("buffer view {v} does not exist")))?;
    let b = view.buffer.value();
    let data = buffers.get(b);
    let start = view.byte_offset.map_or(0, |o| o.0);
    let len = view.byte_length.0;
    let end = start.saturating_add(len);
    if end > data.len() as u64 {
        return Err(invalid(format!(
            "buffer {b} is {} bytes but buffer view {v} needs {end}",
            data.len()
        )));
    }
    let need = if count == 0 {
        Some(offset)
    } else {
        (count - 1)
            .checked_mul(stride as u64)
            .and_then(|n| n.checked_add(elem as u64))
            .and_then(|n| n.checked_add(offset))
    };
    match need {
        Some(need) if need <= len => {
            // Both fit in the buffer's length, a usize.
            let lo = (start + offset.min(need)) as usize;
            Ok(&data[lo..(start + need) as usize])
        }
        _ => Err(invalid(format!(
            "buffer view {v} is {len} bytes but {who} needs {}",
            need.map_or_else(|| "more than 2^64".to_owned(), |n| n.to_string())
        ))),
    }
}

/// Elements read or copied so far, against a limit ([`MAX_OUTPUT`]).
struct Budget {
    spent: u64,
    limit: u64,
}

impl Budget {
    /// Counts `n` more elements.
    fn charge(&mut self, n: u64) -> Result<(), Fail> {
        self.spent = self.spent.saturating_add(n);
        if self.spent > self.limit {
            return Err(unsupported(format!(
                "the model needs more than {} vertices, normals and indices in all",
                self.limit
            )));
        }
        Ok(())
    }
}

/// A glTF mesh's merged triangles and base colour; `None` when it has no triangles.
type Built = Option<(Mesh, Option<[f32; 4]>)>;

struct Loader<'a> {
    root: &'a Root,
    buffers: Buffers<'a>,
    /// Built meshes by glTF mesh index (`None`: no triangles), shared by instancing nodes.
    meshes: HashMap<usize, Built>,
    /// Elements read or copied so far, see [`MAX_OUTPUT`].
    budget: Budget,
}

impl Loader<'_> {
    /// Loads the buffers an accessor reads and checks its ranges.
    fn elements(&mut self, a: usize, want: Type, role: &str) -> Result<Elements<'_>, Fail> {
        let root = self.root;
        let acc = root
            .accessors
            .get(a)
            .ok_or_else(|| invalid(format!("accessor {a} does not exist")))?;
        let component = match acc.component_type {
            Checked::Valid(GenericComponentType(c)) => c,
            Checked::Invalid => {
                return Err(invalid(format!(
                    "accessor {a} has an invalid componentType"
                )));
            }
        };
        let ty = match acc.type_ {
            Checked::Valid(t) => t,
            Checked::Invalid => return Err(invalid(format!("accessor {a} has an invalid type"))),
        };
        if ty != want {
            return Err(invalid(format!(
                "accessor {a} ({role}) is {}; expected {}",
                type_name(ty),
                type_name(want)
            )));
        }
        let Some(v) = acc.buffer_view else {
            return Err(unsupported(format!(
                "accessor {a} ({role}) has no buffer view"
            )));
        };
        let v = v.value();
        let elem = component_size(component) * ty.multiplicity();
        let view = root
            .buffer_views
            .get(v)
            .ok_or_else(|| invalid(format!("buffer view {v} does not exist")))?;
        let stride = view.byte_stride.map_or(0, |s| s.0);
        let stride = if stride == 0 { elem } else { stride };
        if stride < elem {
            return Err(invalid(format!(
                "buffer view {v} has a byteStride of {stride}, less than the {elem}-byte elements of accessor {a}"
            )));
        }
        self.buffers.load(view.buffer.value())?;
        if let Some(s) = &acc.sparse {
            for sv in [s.indices.buffer_view.value(), s.values.buffer_view.value()] {
                let b = root
                    .buffer_views
                    .get(sv)
                    .ok_or_else(|| invalid(format!("buffer view {sv} does not exist")))?
                    .buffer
                    .value();
                self.buffers.load(b)?;
            }
        }
        let count = acc.count.0;
        let span = Span {
            view: v,
            offset: acc.byte_offset.map_or(0, |o| o.0),
            count,
            elem,
            stride,
        };
        let data = view_range(root, &self.buffers, &span, &format!("accessor {a}"))?;
        self.budget.charge(count)?;
        Ok(Elements {
            data,
            // The range check bounds it by the data length.
            count: count as usize,
            stride,
            component,
            normalized: acc.normalized,
        })
    }

    /// A VEC3 accessor as f32 triples, sparse substitutions applied.
    fn read_vec3(&mut self, a: usize, role: &str) -> Result<Vec<[f32; 3]>, Fail> {
        let e = self.elements(a, Type::Vec3, role)?;
        let size = component_size(e.component);
        let mut out = Vec::with_capacity(e.count);
        for i in 0..e.count {
            let el = e.data.get(i * e.stride..).unwrap_or_default();
            let mut p = [0.0; 3];
            for (k, c) in p.iter_mut().enumerate() {
                *c = el
                    .get(k * size..)
                    .and_then(|b| component_f32(e.component, e.normalized, b))
                    .ok_or_else(|| invalid(format!("accessor {a} is shorter than its count")))?;
            }
            out.push(p);
        }
        let (component, normalized) = (e.component, e.normalized);
        self.apply_sparse(a, &mut out, |b| {
            let mut p = [0.0; 3];
            for (k, c) in p.iter_mut().enumerate() {
                *c = component_f32(component, normalized, b.get(k * size..)?)?;
            }
            Some(p)
        })?;
        Ok(out)
    }

    /// A SCALAR unsigned integer accessor (vertex indices), sparse substitutions applied.
    fn read_indices(&mut self, a: usize) -> Result<Vec<u32>, Fail> {
        let e = self.elements(a, Type::Scalar, "indices")?;
        if !matches!(
            e.component,
            ComponentType::U8 | ComponentType::U16 | ComponentType::U32
        ) {
            return Err(invalid(format!(
                "accessor {a} (indices) has component type {:?}; expected an unsigned integer type",
                e.component
            )));
        }
        let size = component_size(e.component);
        let component = e.component;
        let mut out = Vec::with_capacity(e.count);
        for i in 0..e.count {
            let v = e
                .data
                .get(i * e.stride..)
                .and_then(|b| component_u32(component, b))
                .ok_or_else(|| invalid(format!("accessor {a} is shorter than its count")))?;
            out.push(v);
        }
        let _ = size;
        self.apply_sparse(a, &mut out, |b| component_u32(component, b))?;
        Ok(out)
    }

    /// Replaces the elements named by accessor `a`'s sparse indices with its sparse values.
    fn apply_sparse<T>(
        &self,
        a: usize,
        out: &mut [T],
        value: impl Fn(&[u8]) -> Option<T>,
    ) -> Result<(), Fail> {
        let root = self.root;
        let Some(acc) = root.accessors.get(a) else {
            return Ok(());
        };
        let Some(s) = &acc.sparse else {
            return Ok(());
        };
        let (Checked::Valid(GenericComponentType(component)), Checked::Valid(ty)) =
            (acc.component_type, acc.type_)
        else {
            return Err(invalid(format!("accessor {a} has an invalid type")));
        };
        let elem = component_size(component) * ty.multiplicity();
        let index_type = match s.indices.component_type {
            Checked::Valid(IndexComponentType(c)) => c,
            Checked::Invalid => {
                return Err(invalid(format!(
                    "accessor {a} has an invalid sparse index type"
                )));
            }
        };
        let isize = component_size(index_type);
        let n = s.count.0;
        let who = format!("the sparse data of accessor {a}");
        let indices = Span {
            view: s.indices.buffer_view.value(),
            offset: s.indices.byte_offset.0,
            count: n,
            elem: isize,
            stride: isize,
        };
        let indices = view_range(root, &self.buffers, &indices, &who)?;
        let values = Span {
            view: s.values.buffer_view.value(),
            offset: s.values.byte_offset.0,
            count: n,
            elem,
            stride: elem,
        };
        let values = view_range(root, &self.buffers, &values, &who)?;
        let bad = || invalid(format!("{who} is malformed"));
        for (ib, vb) in indices.chunks_exact(isize).zip(values.chunks_exact(elem)) {
            let i = component_u32(index_type, ib).ok_or_else(bad)? as usize;
            let slot = out.get_mut(i).ok_or_else(|| {
                invalid(format!(
                    "sparse index {i} of accessor {a} is out of range for {} elements",
                    acc.count.0
                ))
            })?;
            *slot = value(vb).ok_or_else(bad)?;
        }
        Ok(())
    }

    /// Builds (once) the merged triangle mesh of glTF mesh `m` and its first material's colour.
    fn mesh(&mut self, m: usize) -> Result<Built, Fail> {
        if let Some(built) = self.meshes.get(&m) {
            return Ok(built.clone());
        }
        let root = self.root;
        let mesh = root
            .meshes
            .get(m)
            .ok_or_else(|| invalid(format!("mesh {m} does not exist")))?;
        let mut positions: Vec<[f32; 3]> = Vec::new();
        let mut normals: Option<Vec<[f32; 3]>> = Some(Vec::new());
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        let mut colour = None;
        let mut any = false;
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let mode = match prim.mode {
                Checked::Valid(mode) => mode,
                Checked::Invalid => {
                    return Err(invalid(format!(
                        "mesh {m} primitive {pi} has an invalid mode"
                    )));
                }
            };
            if !matches!(
                mode,
                Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
            ) {
                continue;
            }
            let pos = prim
                .attributes
                .get(&Checked::Valid(Semantic::Positions))
                .ok_or_else(|| {
                    invalid(format!("mesh {m} primitive {pi} has no POSITION attribute"))
                })?;
            let p = self.read_vec3(pos.value(), "POSITION")?;
            let base = positions.len();
            let n = p.len();
            if base as u64 + n as u64 > u64::from(u32::MAX) + 1 {
                return Err(unsupported(format!("mesh {m} has more than 2^32 vertices")));
            }
            positions.extend_from_slice(&p);
            match (
                &mut normals,
                prim.attributes.get(&Checked::Valid(Semantic::Normals)),
            ) {
                (Some(ns), Some(acc)) => {
                    let v = self.read_vec3(acc.value(), "NORMAL")?;
                    if v.len() != n {
                        return Err(invalid(format!(
                            "mesh {m} primitive {pi} has {} normals for {n} positions",
                            v.len()
                        )));
                    }
                    ns.extend_from_slice(&v);
                }
                (slot, None) => *slot = None,
                (None, Some(_)) => {}
            }
            let indices = match prim.indices {
                Some(i) => Some(self.read_indices(i.value())?),
                None => None,
            };
            let count = indices.as_ref().map_or(n, Vec::len);
            let at = |k: usize| -> Result<u32, Fail> {
                let v = match &indices {
                    Some(ix) => ix.get(k).copied().unwrap_or(u32::MAX),
                    None => k as u32,
                };
                if v as usize >= n {
                    return Err(invalid(format!(
                        "mesh {m} primitive {pi}: index {v} is out of range for {n} vertices"
                    )));
                }
                Ok(v + base as u32)
            };
            match mode {
                Mode::Triangles => {
                    triangles.reserve(count / 3);
                    for t in 0..count / 3 {
                        triangles.push([at(3 * t)?, at(3 * t + 1)?, at(3 * t + 2)?]);
                    }
                }
                Mode::TriangleStrip => {
                    triangles.reserve(count.saturating_sub(2));
                    for i in 0..count.saturating_sub(2) {
                        let (b, c) = if i % 2 == 0 {
                            (i + 1, i + 2)
                        } else {
                            (i + 2, i + 1)
                        };
                        triangles.push([at(i)?, at(b)?, at(c)?]);
                    }
                }
                _ => {
                    triangles.reserve(count.saturating_sub(2));
                    for i in 0..count.saturating_sub(2) {
                        triangles.push([at(i + 1)?, at(i + 2)?, at(0)?]);
                    }
                }
            }
            if !any {
                any = true;
                colour = prim.material.and_then(|mi| {
                    root.materials
                        .get(mi.value())
                        .map(|mat| mat.pbr_metallic_roughness.base_color_factor.0)
                });
            }
        }
        let built = if triangles.is_empty() {
            None
        } else {
            let mesh = Mesh::new(positions, normals, triangles)
                .map_err(|e| invalid(format!("mesh {m}: {e}")))?;
            Some((mesh, colour))
        };
        self.meshes.insert(m, built.clone());
        Ok(built)
    }

    /// Walks the scene and collects one part per mesh-carrying node.
    fn walk(&mut self) -> Result<Vec<ModelPart>, Fail> {
        let root = self.root;
        let nodes = &root.nodes;
        let scene = root
            .scene
            .and_then(|s| root.scenes.get(s.value()))
            .or_else(|| root.scenes.first());
        let roots: Vec<usize> = match scene {
            Some(s) => s.nodes.iter().map(|n| n.value()).collect(),
            None => {
                let mut is_child = vec![false; nodes.len()];
                for c in nodes.iter().flat_map(|n| n.children.iter().flatten()) {
                    if let Some(slot) = is_child.get_mut(c.value()) {
                        *slot = true;
                    }
                }
                (0..nodes.len()).filter(|&i| !is_child[i]).collect()
            }
        };
        let mut visited = vec![false; nodes.len()];
        let mut stack: Vec<(usize, Mat4)> =
            roots.iter().rev().map(|&n| (n, Mat4::IDENTITY)).collect();
        let mut parts = Vec::new();
        while let Some((ni, parent)) = stack.pop() {
            let node = nodes
                .get(ni)
                .ok_or_else(|| invalid(format!("node {ni} does not exist")))?;
            if std::mem::replace(&mut visited[ni], true) {
                return Err(invalid(format!(
                    "node {ni} appears more than once in the node hierarchy"
                )));
            }
            let world = parent * local_transform(node, ni)?;
            if !world.is_finite() {
                return Err(invalid(format!(
                    "node {ni} has a non-finite world transform"
                )));
            }
            if let Some(mi) = node.mesh {
                let m = mi.value();
                if let Some((mesh, base_color)) = self.mesh(m)? {
                    let n = mesh.positions().len() + mesh.triangles().len();
                    self.budget.charge(n as u64)?;
                    let name = node
                        .name
                        .as_deref()
                        .filter(|n| !n.is_empty())
                        .or(root
                            .meshes
                            .get(m)
                            .and_then(|x| x.name.as_deref())
                            .filter(|n| !n.is_empty()))
                        .map_or_else(|| format!("node{ni}"), str::to_owned);
                    parts.push(ModelPart {
                        name,
                        mesh,
                        transform: world,
                        base_color,
                    });
                }
            }
            for c in node.children.iter().flatten().rev() {
                stack.push((c.value(), world));
            }
        }
        Ok(parts)
    }
}

/// A node's local transform: its matrix, else translation × rotation × scale.
fn local_transform(node: &json::Node, ni: usize) -> Result<Mat4, Fail> {
    if let Some(m) = node.matrix {
        return Ok(Mat4::from_cols_array(&m));
    }
    let t = Vec3::from(node.translation.unwrap_or([0.0; 3]));
    let s = Vec3::from(node.scale.unwrap_or([1.0; 3]));
    let r = Quat::from_array(node.rotation.unwrap_or_default().0);
    let len = r.length();
    if !(len.is_finite() && len > 0.0) {
        return Err(invalid(format!("node {ni} has an invalid rotation {r}")));
    }
    Ok(Mat4::from_scale_rotation_translation(s, r / len, t))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mesh of `primitives` primitives all reading the same 3-vertex accessor, used by
    /// `nodes` nodes.
    fn reuse(primitives: usize, nodes: usize) -> String {
        let prims = vec![r#"{"attributes":{"POSITION":0}}"#; primitives].join(",");
        let nodes = vec![r#"{"mesh":0}"#; nodes].join(",");
        let data = "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA";
        format!(
            r#"{{"asset":{{"version":"2.0"}},"nodes":[{nodes}],"meshes":[{{"primitives":[{prims}]}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
            "bufferViews":[{{"buffer":0,"byteLength":36}}],
            "buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,{data}"}}]}}"#
        )
    }

    #[test]
    fn reusing_data_is_bounded() {
        let path = Path::new("reuse.gltf");
        // 10 primitives × 3 positions = 30 read, then 2 nodes × (30 + 10) copied = 110.
        let m = parse_limited(reuse(10, 2).as_bytes(), path, 110).map_err(|f| f.kind);
        let m = m.unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m.parts.len(), 2);
        assert_eq!(m.parts[0].mesh.positions().len(), 30);
        assert_eq!(m.parts[0].mesh.triangles().len(), 10);
        let e = parse_limited(reuse(10, 2).as_bytes(), path, 109).map(|_| ());
        assert!(matches!(
            e,
            Err(Fail {
                kind: LoadErrorKind::Unsupported(_),
                ..
            })
        ));
        let e = parse_limited(reuse(40, 1).as_bytes(), path, 110).map(|_| ());
        assert!(matches!(
            e,
            Err(Fail {
                kind: LoadErrorKind::Unsupported(_),
                ..
            })
        ));
    }
}
