//! Mesh loaders: PLY, OBJ, OFF, STL and glTF 2.0 files, optionally gzipped, into [`Model`]s.
//!
//! [`load_model`] reads a file, gunzips it when it starts with the gzip magic `1f 8b`, picks the
//! format from the extension (after stripping `.gz`) or, for a file without one, by sniffing the
//! content, and hands the bytes to [`parse_model`]. An extension that names no format strata
//! reads is an error ([`LoadErrorKind::UnknownFormat`]) rather than a guess, and so is a
//! directory. Each format's module states the subset it supports:
//!
//! | format | module | errors located by |
//! | --- | --- | --- |
//! | PLY ascii, binary LE, binary BE | `ply` | line (header, ascii body), byte (binary body) |
//! | Wavefront OBJ | `obj` | line |
//! | OFF, COFF, NOFF, CNOFF, NCOFF (ascii) | `off` | line |
//! | STL binary, STL ascii | `stl` | byte (binary), line (ascii) |
//! | glTF 2.0 (`.gltf`, `.glb`) | `gltf` | the glTF object named (node, accessor, …) |
//!
//! Every error is a [`LoadError`]: the file path, an optional [`Location`] and a
//! [`LoadErrorKind`]; its `Display` reads `dragon.ply.gz: line 12: expected 3 values in vertex 9,
//! found 2`. The loaders never panic on malformed input, and never reserve memory for more items
//! than the remaining bytes could hold, so a header claiming billions of vertices fails fast.
//!
//! A model must contain at least one triangle: a file without any is an error
//! ([`LoadErrorKind::Empty`]), the same for every format.

mod gltf;
mod obj;
mod off;
mod ply;
mod source;
mod stl;
mod text;

use std::fmt;
use std::path::{Path, PathBuf};

use glam::Mat4;

use crate::mesh::{Mesh, MeshError};

/// A mesh file format. More may be added, so matches need a wildcard arm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Format {
    /// Stanford PLY (ascii, binary little or big endian).
    Ply,
    /// Wavefront OBJ.
    Obj,
    /// Object File Format (ascii).
    Off,
    /// glTF 2.0 JSON.
    Gltf,
    /// glTF 2.0 binary container.
    Glb,
    /// STL (stereolithography), binary or ascii.
    Stl,
}

/// The extensions strata reads, for error messages and `--help` texts.
pub const KNOWN_EXTENSIONS: &str = ".ply, .obj, .off, .stl, .gltf, .glb (each optionally gzipped, \
                                    with .gz added)";

impl Format {
    /// The format named by the file extension, ignoring case and a trailing `.gz`
    /// (`dragon.PLY.gz` → [`Format::Ply`]); `None` for an unknown or missing extension.
    pub fn from_path(path: &Path) -> Option<Format> {
        match extension(path)?.as_str() {
            "ply" => Some(Format::Ply),
            "obj" => Some(Format::Obj),
            "off" => Some(Format::Off),
            "stl" => Some(Format::Stl),
            "gltf" => Some(Format::Gltf),
            "glb" => Some(Format::Glb),
            _ => None,
        }
    }

    /// Guesses the format of (decompressed) file content: `ply` followed by a line end, the GLB
    /// magic `glTF`, a JSON object (`{`), a binary STL (its size matches its triangle count) or
    /// `solid` as the first word, an OFF keyword (`OFF`, `COFF`, `NOFF`, …) as the first word
    /// outside `#` comments, else OBJ.
    pub fn sniff(bytes: &[u8]) -> Format {
        if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
            return Format::Ply;
        }
        if bytes.starts_with(b"glTF") {
            return Format::Glb;
        }
        let start = bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes);
        let first = start
            .iter()
            .position(|b| !b.is_ascii_whitespace())
            .map_or(&[][..], |i| &start[i..]);
        if first.starts_with(b"{") {
            return Format::Gltf;
        }
        if stl::is_stl(bytes) {
            return Format::Stl;
        }
        // The first word outside `#` comments decides between OFF and OBJ.
        let mut lines = text::Lines::new(first);
        while let Some(line) = lines.next_line() {
            if let Some(word) = text::Tokens::new(text::strip_comment(line)).next() {
                if off::is_off_keyword(word) {
                    return Format::Off;
                }
                break;
            }
        }
        Format::Obj
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Format::Ply => "PLY",
            Format::Obj => "OBJ",
            Format::Off => "OFF",
            Format::Gltf => "glTF",
            Format::Glb => "GLB",
            Format::Stl => "STL",
        })
    }
}

/// Everything a mesh file contributes to a scene: one or more placed meshes.
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    /// The meshes; exactly one for PLY, OBJ and OFF, one per mesh-carrying node for glTF.
    pub parts: Vec<ModelPart>,
}

/// One mesh of a [`Model`], with its placement and colour.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelPart {
    /// The file stem for PLY/OBJ/OFF (`dragon_vrip.ply.gz` → `dragon_vrip`); for glTF the node
    /// name, else the mesh name, else `node{index}`.
    pub name: String,
    /// The geometry, in the part's own coordinates.
    pub mesh: Mesh,
    /// Model-space placement: the glTF node's world transform; identity for other formats.
    pub transform: Mat4,
    /// The `baseColorFactor` of the material of the node's first triangle primitive (glTF only,
    /// and only when that primitive names a material).
    pub base_color: Option<[f32; 4]>,
}

/// Where in a file an error was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Location {
    /// A 1-based line number (text formats).
    Line(u64),
    /// A 0-based byte offset into the decompressed content (binary data).
    Byte(u64),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(n) => write!(f, "line {n}"),
            Location::Byte(n) => write!(f, "byte {n}"),
        }
    }
}

/// Why a mesh file could not be loaded: the file, where in it, and what went wrong.
#[derive(Debug, thiserror::Error)]
#[error("{}{}: {kind}", path.display(), LocationPrefix(*location))]
pub struct LoadError {
    /// The file, as given to [`load_model`] or [`parse_model`].
    pub path: PathBuf,
    /// Where in the file, when the error concerns one place.
    pub location: Option<Location>,
    /// What went wrong.
    pub kind: LoadErrorKind,
}

/// `": line 12"` or nothing.
struct LocationPrefix(Option<Location>);

impl fmt::Display for LocationPrefix {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Some(l) => write!(f, ": {l}"),
            None => Ok(()),
        }
    }
}

/// The kinds of [`LoadError`]. Messages are lowercase and say what was expected and found.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LoadErrorKind {
    /// The file (or a glTF buffer file) could not be read.
    #[error("cannot read: {0}")]
    Io(std::io::Error),
    /// The path names a directory.
    #[error("is a directory, not a mesh file")]
    IsDirectory,
    /// The file's extension names no format strata reads.
    #[error("unknown mesh format '.{0}': strata reads {KNOWN_EXTENSIONS}")]
    UnknownFormat(String),
    /// The file starts with the gzip magic but does not decompress.
    #[error("invalid gzip data: {0}")]
    Gzip(std::io::Error),
    /// Malformed text: a bad keyword, number or header line.
    #[error("{0}")]
    Syntax(String),
    /// The data ends before everything the file declares.
    #[error("{0}")]
    Truncated(String),
    /// A valid file using a feature the loaders do not support.
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// Well-formed but inconsistent data: an index out of range, a face with too few vertices,
    /// a range past the end of a buffer.
    #[error("{0}")]
    Invalid(String),
    /// The file holds no triangles.
    #[error("{0}")]
    Empty(String),
    /// The arrays read do not form a valid mesh.
    #[error("{0}")]
    Mesh(MeshError),
    /// The glTF JSON does not parse or does not validate (the message says which).
    #[error("{0}")]
    Gltf(String),
}

/// An error before the path is attached: what [`parse_model`]'s format modules return.
#[derive(Debug)]
pub(crate) struct Fail {
    location: Option<Location>,
    kind: LoadErrorKind,
}

impl Fail {
    fn new(location: Option<Location>, kind: LoadErrorKind) -> Fail {
        Fail { location, kind }
    }

    fn line(line: u64, kind: LoadErrorKind) -> Fail {
        Fail::new(Some(Location::Line(line)), kind)
    }

    fn byte(offset: usize, kind: LoadErrorKind) -> Fail {
        Fail::new(Some(Location::Byte(offset as u64)), kind)
    }

    fn nowhere(kind: LoadErrorKind) -> Fail {
        Fail::new(None, kind)
    }

    fn with_path(self, path: &Path) -> LoadError {
        LoadError {
            path: path.to_path_buf(),
            location: self.location,
            kind: self.kind,
        }
    }
}

impl From<MeshError> for Fail {
    fn from(e: MeshError) -> Fail {
        Fail::nowhere(LoadErrorKind::Mesh(e))
    }
}

/// Reads, decompresses, detects and parses a mesh file; see the module docs.
pub fn load_model(path: &Path) -> Result<Model, LoadError> {
    if path.is_dir() {
        return Err(Fail::nowhere(LoadErrorKind::IsDirectory).with_path(path));
    }
    let named = match extension(path) {
        None => None,
        Some(ext) => match Format::from_path(path) {
            Some(format) => Some(format),
            None => return Err(Fail::nowhere(LoadErrorKind::UnknownFormat(ext)).with_path(path)),
        },
    };
    let bytes = source::read(path).map_err(|f| f.with_path(path))?;
    let format = named.unwrap_or_else(|| Format::sniff(&bytes));
    parse_model(&bytes, format, path)
}

/// The lowercase extension after stripping a trailing `.gz` (`Dragon.PLY.gz` → `ply`); `None`
/// without one (`mesh`, `mesh.gz`, `mesh.`).
fn extension(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    let (_, ext) = name.rsplit_once('.')?;
    (!ext.is_empty()).then(|| ext.to_owned())
}

/// Parses already decompressed file content. `path` names the file in errors, gives PLY/OBJ/OFF
/// parts their name and is where relative glTF buffer URIs are resolved from.
pub fn parse_model(bytes: &[u8], format: Format, path: &Path) -> Result<Model, LoadError> {
    let single = |mesh: Result<Mesh, Fail>| -> Result<Model, Fail> {
        Ok(Model {
            parts: vec![ModelPart {
                name: file_stem(path),
                mesh: mesh?,
                transform: Mat4::IDENTITY,
                base_color: None,
            }],
        })
    };
    let model = match format {
        Format::Ply => single(ply::parse(bytes)),
        Format::Obj => single(obj::parse(bytes)),
        Format::Off => single(off::parse(bytes)),
        Format::Stl => single(stl::parse(bytes)),
        Format::Gltf | Format::Glb => gltf::parse(bytes, path),
    };
    model.map_err(|f| f.with_path(path))
}

/// `dir/dragon_vrip.ply.gz` → `dragon_vrip`.
fn file_stem(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = name
        .strip_suffix(".gz")
        .or_else(|| name.strip_suffix(".GZ"))
        .unwrap_or(&name);
    match name.rsplit_once('.') {
        Some((stem, _)) if !stem.is_empty() => stem.to_owned(),
        _ => name.to_owned(),
    }
}

/// How many items to reserve room for when a file declares `declared` items and each needs at
/// least `min_bytes` of the `remaining` bytes: never more than the bytes could hold.
fn bounded(declared: u64, remaining: usize, min_bytes: usize) -> usize {
    let fit = remaining / min_bytes.max(1);
    usize::try_from(declared).map_or(fit, |d| d.min(fit))
}

/// The error for a mesh without triangles.
fn no_triangles() -> Fail {
    Fail::nowhere(LoadErrorKind::Empty(
        "the file contains no triangles".to_owned(),
    ))
}
