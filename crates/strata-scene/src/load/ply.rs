//! PLY (Stanford polygon file) loader: ascii 1.0, binary_little_endian 1.0, binary_big_endian 1.0.
//!
//! Supported: every scalar type (`char uchar short ushort int uint float double` and
//! `int8 uint8 int16 uint16 int32 uint32 float32 float64`), list properties with any integer count
//! type, `comment` and `obj_info` lines, CRLF line ends. The `vertex` element must have scalar
//! `x y z` properties; `nx ny nz` are used only when all three are present. The `face` element
//! needs an integer list property `vertex_indices` (or `vertex_index`); polygons are
//! fan-triangulated and a face with fewer than 3 vertices is an error. Every other element and
//! property (lists included) is skipped, and anything after the last element is ignored.
//!
//! In an ascii body each element instance is one line (blank lines are skipped). Errors in the
//! header and in an ascii body give the 1-based line; missing ascii data is reported at the line
//! after the last one. Errors in a binary body give the 0-based byte offset of the value concerned
//! (for missing data, where the value should have started).

use super::text::{self, Lines, Tokens, show};
use super::{Fail, LoadErrorKind, bounded, no_triangles};
use crate::mesh::Mesh;

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn from_name(name: &[u8]) -> Option<Scalar> {
        Some(match name {
            b"char" | b"int8" => Scalar::I8,
            b"uchar" | b"uint8" => Scalar::U8,
            b"short" | b"int16" => Scalar::I16,
            b"ushort" | b"uint16" => Scalar::U16,
            b"int" | b"int32" => Scalar::I32,
            b"uint" | b"uint32" => Scalar::U32,
            b"float" | b"float32" => Scalar::F32,
            b"double" | b"float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

/// A property's type.
#[derive(Clone, Copy, Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
    /// Header line that declared it.
    line: u64,
}

impl Element {
    /// The fewest bytes one instance takes in a binary body.
    fn min_binary_size(&self) -> usize {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => s.size(),
                Kind::List { count, .. } => count.size(),
            })
            .sum()
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

/// What a property contributes to the mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Skip,
    /// x y z nx ny nz → 0..6.
    Coord(usize),
    /// The face's vertex index list.
    Indices,
}

/// How the mesh is assembled while the body is read.
struct Build {
    /// Declared number of vertices (indices are checked against it).
    vertex_count: u64,
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    triangles: Vec<[u32; 3]>,
}

/// Parses a whole PLY file.
pub(super) fn parse(bytes: &[u8]) -> Result<Mesh, Fail> {
    let mut lines = Lines::new(bytes);
    let (encoding, elements) = header(&mut lines)?;
    let plans = plan(&elements)?;
    let vertex_count = elements
        .iter()
        .zip(&plans)
        .find(|(_, p)| p.what == What::Vertex)
        .map_or(0, |(e, _)| e.count);
    let mut build = Build {
        vertex_count,
        positions: Vec::new(),
        normals: None,
        triangles: Vec::new(),
    };
    match encoding {
        Encoding::Ascii => ascii_body(&mut lines, &elements, &plans, &mut build)?,
        Encoding::Little | Encoding::Big => {
            let mut r = Reader {
                bytes,
                pos: lines.offset(),
                big: encoding == Encoding::Big,
            };
            binary_body(&mut r, &elements, &plans, &mut build)?;
        }
    }
    if build.triangles.is_empty() {
        return Err(no_triangles());
    }
    Ok(Mesh::new(build.positions, build.normals, build.triangles)?)
}

fn syntax(line: u64, msg: String) -> Fail {
    Fail::line(line, LoadErrorKind::Syntax(msg))
}

/// Reads the header up to and including `end_header`; `lines` is left at the first body line.
fn header(lines: &mut Lines<'_>) -> Result<(Encoding, Vec<Element>), Fail> {
    match lines.next_line() {
        Some(l) if Tokens::new(l).eq([&b"ply"[..]]) && l.starts_with(b"ply") => {}
        Some(l) => {
            return Err(syntax(
                1,
                format!(
                    "expected 'ply' as the first line, found {}",
                    show(l.trim_ascii_end())
                ),
            ));
        }
        None => return Err(syntax(1, "expected 'ply', found an empty file".to_owned())),
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let Some(l) = lines.next_line() else {
            return Err(Fail::line(
                lines.line() + 1,
                LoadErrorKind::Truncated("unexpected end of file in the header".to_owned()),
            ));
        };
        let line = lines.line();
        let mut t = Tokens::new(l);
        let Some(keyword) = t.next() else { continue };
        match keyword {
            b"comment" | b"obj_info" => continue,
            b"end_header" => break,
            b"format" => {
                if encoding.is_some() {
                    return Err(syntax(line, "a second 'format' line".to_owned()));
                }
                let e = match t.next() {
                    Some(b"ascii") => Encoding::Ascii,
                    Some(b"binary_little_endian") => Encoding::Little,
                    Some(b"binary_big_endian") => Encoding::Big,
                    Some(other) => {
                        return Err(Fail::line(
                            line,
                            LoadErrorKind::Unsupported(format!(
                                "format {}; expected ascii, binary_little_endian or binary_big_endian",
                                show(other)
                            )),
                        ));
                    }
                    None => {
                        return Err(syntax(line, "expected a format after 'format'".to_owned()));
                    }
                };
                match t.next() {
                    Some(b"1.0" | b"1") => {}
                    Some(v) => {
                        return Err(Fail::line(
                            line,
                            LoadErrorKind::Unsupported(format!("PLY version {}", show(v))),
                        ));
                    }
                    None => {
                        return Err(syntax(
                            line,
                            "expected a version after the format".to_owned(),
                        ));
                    }
                }
                expect_end(&mut t, line)?;
                encoding = Some(e);
            }
            b"element" => {
                let name = t
                    .next()
                    .ok_or_else(|| syntax(line, "expected an element name".to_owned()))?;
                let count = t.next().ok_or_else(|| {
                    syntax(line, "expected an element count after the name".to_owned())
                })?;
                let count = text::parse_u64(count).ok_or_else(|| {
                    syntax(
                        line,
                        format!("expected an element count, found {}", show(count)),
                    )
                })?;
                expect_end(&mut t, line)?;
                elements.push(Element {
                    name: String::from_utf8_lossy(name).into_owned(),
                    count,
                    props: Vec::new(),
                    line,
                });
            }
            b"property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(syntax(line, "a property before any element".to_owned()));
                };
                let ty = t
                    .next()
                    .ok_or_else(|| syntax(line, "expected a property type".to_owned()))?;
                let kind = if ty == b"list" {
                    let name = t.next();
                    let count = scalar_type(name, line)?;
                    if !count.is_integer() {
                        return Err(syntax(
                            line,
                            format!(
                                "expected an integer list count type, found {}",
                                show(name.unwrap_or_default())
                            ),
                        ));
                    }
                    let item = scalar_type(t.next(), line)?;
                    Kind::List { count, item }
                } else {
                    Kind::Scalar(scalar_type(Some(ty), line)?)
                };
                let name = t
                    .next()
                    .ok_or_else(|| syntax(line, "expected a property name".to_owned()))?;
                expect_end(&mut t, line)?;
                element.props.push(Property {
                    name: String::from_utf8_lossy(name).into_owned(),
                    kind,
                });
            }
            other => {
                return Err(syntax(
                    line,
                    format!(
                        "expected a header keyword (format, element, property, comment, obj_info, end_header), found {}",
                        show(other)
                    ),
                ));
            }
        }
    }
    let encoding = encoding.ok_or_else(|| {
        syntax(
            lines.line(),
            "the header ends without a 'format' line".to_owned(),
        )
    })?;
    Ok((encoding, elements))
}

fn scalar_type(token: Option<&[u8]>, line: u64) -> Result<Scalar, Fail> {
    let token = token.ok_or_else(|| syntax(line, "expected a property type".to_owned()))?;
    Scalar::from_name(token).ok_or_else(|| {
        syntax(
            line,
            format!("expected a scalar type (char, uchar, short, ushort, int, uint, float, double, int8, …, float64), found {}", show(token)),
        )
    })
}

fn expect_end(t: &mut Tokens<'_>, line: u64) -> Result<(), Fail> {
    match t.next() {
        None => Ok(()),
        Some(extra) => Err(syntax(
            line,
            format!("unexpected {} at the end of the line", show(extra)),
        )),
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum What {
    Vertex,
    Face,
    Other,
}

/// What to do with each element and property.
struct Plan {
    what: What,
    roles: Vec<Role>,
    /// Whether nx ny nz are all present (vertex element).
    normals: bool,
}

fn plan(elements: &[Element]) -> Result<Vec<Plan>, Fail> {
    let mut plans: Vec<Plan> = Vec::with_capacity(elements.len());
    for e in elements {
        let what = match e.name.as_str() {
            "vertex" => What::Vertex,
            "face" => What::Face,
            _ => What::Other,
        };
        if what != What::Other && plans.iter().any(|p| p.what == what) {
            return Err(Fail::line(
                e.line,
                LoadErrorKind::Invalid(format!("a second '{}' element", e.name)),
            ));
        }
        let mut roles = vec![Role::Skip; e.props.len()];
        let mut normals = false;
        match what {
            What::Vertex => {
                if e.count > u64::from(u32::MAX) + 1 {
                    return Err(Fail::line(
                        e.line,
                        LoadErrorKind::Unsupported(format!(
                            "{} vertices exceed the limit of 2^32",
                            e.count
                        )),
                    ));
                }
                for (k, name) in ["x", "y", "z", "nx", "ny", "nz"].into_iter().enumerate() {
                    let found = e.props.iter().position(|p| p.name == name);
                    match (found, k < 3) {
                        (Some(i), _) => {
                            if let Kind::List { .. } = e.props[i].kind {
                                return Err(Fail::line(
                                    e.line,
                                    LoadErrorKind::Invalid(format!(
                                        "vertex property '{name}' is a list; expected a scalar"
                                    )),
                                ));
                            }
                            roles[i] = Role::Coord(k);
                        }
                        (None, true) => {
                            return Err(Fail::line(
                                e.line,
                                LoadErrorKind::Invalid(format!(
                                    "the vertex element has no '{name}' property"
                                )),
                            ));
                        }
                        (None, false) => {}
                    }
                }
                normals = roles
                    .iter()
                    .filter(|r| matches!(r, Role::Coord(3..)))
                    .count()
                    == 3;
                if !normals {
                    for r in &mut roles {
                        if matches!(r, Role::Coord(3..)) {
                            *r = Role::Skip;
                        }
                    }
                }
            }
            What::Face => {
                let i = e
                    .props
                    .iter()
                    .position(|p| p.name == "vertex_indices" || p.name == "vertex_index")
                    .ok_or_else(|| {
                        Fail::line(
                            e.line,
                            LoadErrorKind::Invalid(
                                "the face element has no 'vertex_indices' property".to_owned(),
                            ),
                        )
                    })?;
                match e.props[i].kind {
                    Kind::List { item, .. } if item.is_integer() => roles[i] = Role::Indices,
                    Kind::List { .. } => {
                        return Err(Fail::line(
                            e.line,
                            LoadErrorKind::Invalid(format!(
                                "face property '{}' has a float type; expected an integer list",
                                e.props[i].name
                            )),
                        ));
                    }
                    Kind::Scalar(_) => {
                        return Err(Fail::line(
                            e.line,
                            LoadErrorKind::Invalid(format!(
                                "face property '{}' is a scalar; expected a list",
                                e.props[i].name
                            )),
                        ));
                    }
                }
            }
            What::Other => {}
        }
        plans.push(Plan {
            what,
            roles,
            normals,
        });
    }
    if !plans.iter().any(|p| p.what == What::Vertex) {
        return Err(Fail::nowhere(LoadErrorKind::Invalid(
            "the header declares no 'vertex' element".to_owned(),
        )));
    }
    Ok(plans)
}

/// The message for an index outside `0..vertex_count`.
/// `index` as a vertex index of a mesh with `vertex_count` vertices, or the error for face `i`.
fn vertex_index(
    element: &str,
    i: u64,
    index: i64,
    vertex_count: u64,
) -> Result<u32, LoadErrorKind> {
    match u32::try_from(index) {
        Ok(v) if u64::from(v) < vertex_count => Ok(v),
        _ => Err(bad_index(element, i, index, vertex_count)),
    }
}

fn bad_index(element: &str, i: u64, index: i64, vertex_count: u64) -> LoadErrorKind {
    LoadErrorKind::Invalid(if index < 0 {
        format!("{element} {i} has a negative vertex index {index}")
    } else {
        format!(
            "{element} {i} refers to vertex {index}, but there are only {vertex_count} vertices"
        )
    })
}

fn too_few(element: &str, i: u64, n: u64) -> LoadErrorKind {
    LoadErrorKind::Invalid(format!(
        "{element} {i} has {n} vertices; a face needs at least 3"
    ))
}

/// Fan triangulation, fed one index at a time.
#[derive(Default)]
struct Fan {
    first: u32,
    prev: u32,
    k: u64,
}

impl Fan {
    #[inline]
    fn push(&mut self, index: u32, triangles: &mut Vec<[u32; 3]>) {
        match self.k {
            0 => self.first = index,
            1 => {}
            _ => triangles.push([self.first, self.prev, index]),
        }
        self.prev = index;
        self.k += 1;
    }
}

fn start_element(e: &Element, p: &Plan, build: &mut Build, remaining: usize, min_bytes: usize) {
    match p.what {
        What::Vertex => {
            let n = bounded(e.count, remaining, min_bytes);
            build.positions.reserve_exact(n);
            if p.normals {
                build.normals = Some(Vec::with_capacity(n));
            }
        }
        What::Face => build
            .triangles
            .reserve(bounded(e.count, remaining, min_bytes)),
        What::Other => {}
    }
}

#[inline]
fn finish_vertex(c: &[f32; 6], build: &mut Build) {
    build.positions.push([c[0], c[1], c[2]]);
    if let Some(n) = &mut build.normals {
        n.push([c[3], c[4], c[5]]);
    }
}

fn ascii_body(
    lines: &mut Lines<'_>,
    elements: &[Element],
    plans: &[Plan],
    build: &mut Build,
) -> Result<(), Fail> {
    for (e, p) in elements.iter().zip(plans) {
        if e.props.is_empty() {
            continue;
        }
        // An instance is at least one character and a separator per property.
        start_element(e, p, build, lines.remaining(), 2 * e.props.len());
        let only_scalars = e.props.iter().all(|p| matches!(p.kind, Kind::Scalar(_)));
        let mut i = 0;
        while i < e.count {
            let Some(tokens) = lines.next_nonblank() else {
                return Err(Fail::line(
                    lines.line() + 1,
                    LoadErrorKind::Truncated(format!("unexpected end of file in {} {i}", e.name)),
                ));
            };
            ascii_instance(tokens, e, p, i, only_scalars, lines.line(), build)?;
            i += 1;
        }
    }
    Ok(())
}

/// Reads one element instance from the tokens of its line.
#[inline]
fn ascii_instance(
    line_tokens: Tokens<'_>,
    e: &Element,
    p: &Plan,
    i: u64,
    only_scalars: bool,
    line: u64,
    build: &mut Build,
) -> Result<(), Fail> {
    let mut t = line_tokens.clone();
    let count_error = |at: &str| {
        let found = line_tokens.clone().count();
        let msg = if only_scalars {
            format!(
                "expected {} values in {} {i}, found {found}",
                e.props.len(),
                e.name
            )
        } else {
            format!("{} {i} {at}", e.name)
        };
        Fail::line(line, LoadErrorKind::Syntax(msg))
    };
    let mut c = [0.0f32; 6];
    for (prop, role) in e.props.iter().zip(&p.roles) {
        match prop.kind {
            Kind::Scalar(s) => {
                let tok = t.next().ok_or_else(|| {
                    count_error(&format!("ends before its property '{}'", prop.name))
                })?;
                if let Role::Coord(k) = *role {
                    c[k] = ascii_value(tok, s).ok_or_else(|| {
                        Fail::line(
                            line,
                            LoadErrorKind::Syntax(format!(
                                "expected a number for '{}' of {} {i}, found {}",
                                prop.name,
                                e.name,
                                show(tok)
                            )),
                        )
                    })?;
                    if k < 3 && !c[k].is_finite() {
                        return Err(Fail::line(
                            line,
                            LoadErrorKind::Invalid(format!(
                                "{} {i} has a non-finite coordinate {}",
                                e.name,
                                show(tok)
                            )),
                        ));
                    }
                }
            }
            Kind::List { .. } => {
                let tok = t
                    .next()
                    .ok_or_else(|| count_error(&format!("ends before its list '{}'", prop.name)))?;
                let n = text::parse_u64(tok).ok_or_else(|| {
                    Fail::line(
                        line,
                        LoadErrorKind::Syntax(format!(
                            "expected a list length for '{}' of {} {i}, found {}",
                            prop.name,
                            e.name,
                            show(tok)
                        )),
                    )
                })?;
                if *role == Role::Indices {
                    if n < 3 {
                        return Err(Fail::line(line, too_few(&e.name, i, n)));
                    }
                    let mut fan = Fan::default();
                    for _ in 0..n {
                        let tok = t.next().ok_or_else(|| {
                            Fail::line(
                                line,
                                LoadErrorKind::Syntax(format!(
                                    "{} {i} ends within its list of {n} vertex indices",
                                    e.name
                                )),
                            )
                        })?;
                        let index = text::parse_i64(tok).ok_or_else(|| {
                            Fail::line(
                                line,
                                LoadErrorKind::Syntax(format!(
                                    "expected an integer vertex index in {} {i}, found {}",
                                    e.name,
                                    show(tok)
                                )),
                            )
                        })?;
                        let v = vertex_index(&e.name, i, index, build.vertex_count)
                            .map_err(|k| Fail::line(line, k))?;
                        fan.push(v, &mut build.triangles);
                    }
                } else {
                    for _ in 0..n {
                        t.next().ok_or_else(|| {
                            Fail::line(
                                line,
                                LoadErrorKind::Syntax(format!(
                                    "{} {i} ends within its list '{}' of {n} values",
                                    e.name, prop.name
                                )),
                            )
                        })?;
                    }
                }
            }
        }
    }
    if let Some(extra) = t.next() {
        return Err(if only_scalars {
            count_error("")
        } else {
            Fail::line(
                line,
                LoadErrorKind::Syntax(format!(
                    "unexpected {} after the last property of {} {i}",
                    show(extra),
                    e.name
                )),
            )
        });
    }
    if p.what == What::Vertex {
        finish_vertex(&c, build);
    }
    Ok(())
}

/// An ascii scalar as f32: floats parsed as floats, integer types as integers.
#[inline]
fn ascii_value(token: &[u8], s: Scalar) -> Option<f32> {
    if s.is_integer() {
        text::parse_i64(token).map(|v| v as f32)
    } else {
        text::parse_f32(token)
    }
}

/// A cursor over a binary body.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    big: bool,
}

impl Reader<'_> {
    #[inline]
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let end = self.pos.checked_add(N)?;
        let b = self.bytes.get(self.pos..end)?;
        self.pos = end;
        b.try_into().ok()
    }

    /// One scalar, widened to f64 (exact for every PLY type).
    #[inline]
    fn read(&mut self, s: Scalar) -> Option<f64> {
        macro_rules! get {
            ($t:ty, $n:literal) => {{
                let b = self.take::<$n>()?;
                f64::from(if self.big {
                    <$t>::from_be_bytes(b)
                } else {
                    <$t>::from_le_bytes(b)
                })
            }};
        }
        Some(match s {
            Scalar::I8 => get!(i8, 1),
            Scalar::U8 => get!(u8, 1),
            Scalar::I16 => get!(i16, 2),
            Scalar::U16 => get!(u16, 2),
            Scalar::I32 => get!(i32, 4),
            Scalar::U32 => get!(u32, 4),
            Scalar::F32 => get!(f32, 4),
            Scalar::F64 => get!(f64, 8),
        })
    }

    #[inline]
    fn skip(&mut self, n: usize) -> Option<()> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len())?;
        self.pos = end;
        Some(())
    }
}

fn binary_body(
    r: &mut Reader<'_>,
    elements: &[Element],
    plans: &[Plan],
    build: &mut Build,
) -> Result<(), Fail> {
    for (e, p) in elements.iter().zip(plans) {
        if e.props.is_empty() {
            continue;
        }
        let min = e.min_binary_size();
        let remaining = r.bytes.len().saturating_sub(r.pos);
        start_element(e, p, build, remaining, min);
        // Bounded by the data: every instance consumes at least one byte or fails.
        read_binary_instances(r, e, p, e.count, build)?;
    }
    Ok(())
}

/// Reads instances `0..count` of element `e`.
fn read_binary_instances(
    r: &mut Reader<'_>,
    e: &Element,
    p: &Plan,
    count: u64,
    build: &mut Build,
) -> Result<(), Fail> {
    let truncated = |at: usize, i: u64| {
        Fail::byte(
            at,
            LoadErrorKind::Truncated(format!("unexpected end of file in {} {i}", e.name)),
        )
    };
    let mut c = [0.0f32; 6];
    for i in 0..count {
        for (prop, role) in e.props.iter().zip(&p.roles) {
            let at = r.pos;
            match (prop.kind, *role) {
                (Kind::Scalar(s), Role::Coord(k)) => {
                    let v = r.read(s).ok_or_else(|| truncated(at, i))? as f32;
                    if k < 3 && !v.is_finite() {
                        return Err(Fail::byte(
                            at,
                            LoadErrorKind::Invalid(format!(
                                "{} {i} has a non-finite coordinate {v}",
                                e.name
                            )),
                        ));
                    }
                    c[k] = v;
                }
                (Kind::Scalar(s), _) => r.skip(s.size()).ok_or_else(|| truncated(at, i))?,
                (Kind::List { count, item }, role) => {
                    let n = r.read(count).ok_or_else(|| truncated(at, i))?;
                    if n < 0.0 {
                        return Err(Fail::byte(
                            at,
                            LoadErrorKind::Invalid(format!(
                                "{} {i} has a negative list length {n} for '{}'",
                                e.name, prop.name
                            )),
                        ));
                    }
                    // An integer type's value, at most u32::MAX: exact.
                    let n = n as u64;
                    if role == Role::Indices {
                        if n < 3 {
                            return Err(Fail::byte(at, too_few(&e.name, i, n)));
                        }
                        let mut fan = Fan::default();
                        for _ in 0..n {
                            let at = r.pos;
                            let v = r.read(item).ok_or_else(|| truncated(at, i))?;
                            // Integer types only (checked in `plan`): exact in i64.
                            let index = v as i64;
                            let v = vertex_index(&e.name, i, index, build.vertex_count)
                                .map_err(|k| Fail::byte(at, k))?;
                            fan.push(v, &mut build.triangles);
                        }
                    } else {
                        let bytes = usize::try_from(n)
                            .ok()
                            .and_then(|n| n.checked_mul(item.size()));
                        match bytes {
                            Some(b) if r.skip(b).is_some() => {}
                            // Report where the first missing item would start.
                            _ => {
                                let have = (r.bytes.len() - r.pos) / item.size();
                                return Err(truncated(r.pos + have * item.size(), i));
                            }
                        }
                    }
                }
            }
        }
        if p.what == What::Vertex {
            finish_vertex(&c, build);
        }
    }
    Ok(())
}
