//! Wavefront OBJ loader: `v`, `vn` and `f` statements; everything else is ignored.
//!
//! Supported: `v x y z [w]` (w and any trailing vertex colour ignored), `vn x y z`, and `f` with
//! `v`, `v/vt`, `v/vt/vn` and `v//vn` corners, 1-based or negative (relative) indices, polygons
//! fan-triangulated. `vt`, `o`, `g`, `s`, `usemtl`, `mtllib`, `l`, `p` and unknown keywords are
//! ignored; `#` starts a comment; a line ending in a backslash continues on the next line.
//! Normals are used only when every face corner references one: the mesh then gets one vertex per
//! distinct (position, normal) pair, in order of first use. Otherwise the file's normals are
//! ignored and computed ones used. A positive index may refer to a vertex defined later in the
//! file; a negative one counts back from the vertices defined so far.
//!
//! Every error gives the 1-based line (for a continued line, its first physical line); an index
//! past the end of the file's vertices is reported at the line of the largest such index.

use std::collections::HashMap;

use super::text::{self, Lines, Tokens, show};
use super::{Fail, LoadErrorKind, no_triangles};
use crate::mesh::{Mesh, MeshError};

/// The largest positive reference seen, and where, to check forward references at the end.
#[derive(Default)]
struct MaxRef {
    index: u32,
    line: u64,
}

impl MaxRef {
    #[inline]
    fn note(&mut self, index: u32, line: u64) {
        if index >= self.index {
            if index > self.index || self.line == 0 {
                self.line = line;
            }
            self.index = index;
        }
    }
}

#[derive(Default)]
struct State {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    /// Position indices (0-based) of each triangle.
    triangles: Vec<[u32; 3]>,
    /// Normal indices of each triangle, while every corner so far has one.
    triangle_normals: Vec<[u32; 3]>,
    /// False once a corner without a normal is seen.
    all_normals: bool,
    max_v: Option<MaxRef>,
    max_vn: Option<MaxRef>,
}

/// Parses a whole OBJ file.
pub(super) fn parse(bytes: &[u8]) -> Result<Mesh, Fail> {
    let mut lines = Lines::new(bytes);
    let mut s = State {
        all_normals: true,
        ..State::default()
    };
    let mut joined = Vec::new();
    while let Some(raw) = lines.next_line() {
        let line = lines.line();
        let logical = if continues(raw) {
            joined.clear();
            let mut part = raw;
            while continues(part) {
                let body = part.trim_ascii_end();
                joined.extend_from_slice(&body[..body.len() - 1]);
                joined.push(b' ');
                match lines.next_line() {
                    Some(next) => part = next,
                    None => {
                        part = &[];
                        break;
                    }
                }
            }
            joined.extend_from_slice(part);
            &joined[..]
        } else {
            raw
        };
        statement(text::strip_comment(logical), line, &mut s)?;
    }
    finish(s)
}

/// True if the line ends (before trailing whitespace) with a backslash.
#[inline]
fn continues(line: &[u8]) -> bool {
    line.trim_ascii_end().last() == Some(&b'\\')
}

fn syntax(line: u64, msg: String) -> Fail {
    Fail::line(line, LoadErrorKind::Syntax(msg))
}

#[inline]
fn statement(l: &[u8], line: u64, s: &mut State) -> Result<(), Fail> {
    let mut t = Tokens::new(l);
    match t.next() {
        Some(b"v") => {
            let p = three(&mut t, line, "vertex coordinates")?;
            if let Some(bad) = p.iter().find(|c| !c.is_finite()) {
                return Err(Fail::line(
                    line,
                    LoadErrorKind::Invalid(format!(
                        "vertex {} has a non-finite coordinate {bad}",
                        s.positions.len() + 1
                    )),
                ));
            }
            s.positions.push(p);
        }
        Some(b"vn") => {
            let n = three(&mut t, line, "normal components")?;
            s.normals.push(n);
        }
        Some(b"f") => face(t, line, s)?,
        _ => {}
    }
    Ok(())
}

/// Three numbers; anything after them is ignored.
#[inline]
fn three(t: &mut Tokens<'_>, line: u64, what: &str) -> Result<[f32; 3], Fail> {
    let mut out = [0.0; 3];
    for (k, slot) in out.iter_mut().enumerate() {
        let tok = t
            .next()
            .ok_or_else(|| syntax(line, format!("expected 3 {what}, found {k}")))?;
        *slot = text::parse_f32(tok)
            .ok_or_else(|| syntax(line, format!("expected a number, found {}", show(tok))))?;
    }
    Ok(out)
}

/// A 1-based or negative reference to one of `defined` items, as a 0-based index.
#[inline]
fn resolve(
    tok: &[u8],
    defined: usize,
    what: &str,
    line: u64,
    max: &mut Option<MaxRef>,
) -> Result<u32, Fail> {
    let i = text::parse_i64(tok).ok_or_else(|| {
        syntax(
            line,
            format!("expected an integer {what} index, found {}", show(tok)),
        )
    })?;
    let out_of_range = || {
        Fail::line(
            line,
            LoadErrorKind::Invalid(format!(
                "{what} index {i} is out of range: {defined} {} defined so far",
                plural(what)
            )),
        )
    };
    if i > 0 {
        let index = u32::try_from(i - 1).map_err(|_| out_of_range())?;
        max.get_or_insert_with(MaxRef::default).note(index, line);
        Ok(index)
    } else if i < 0 {
        let back = usize::try_from(i.unsigned_abs()).map_err(|_| out_of_range())?;
        let index = defined.checked_sub(back).ok_or_else(out_of_range)?;
        u32::try_from(index).map_err(|_| out_of_range())
    } else {
        Err(Fail::line(
            line,
            LoadErrorKind::Invalid(format!("{what} index 0 is invalid: OBJ indices start at 1")),
        ))
    }
}

/// `vertex` → `vertices`, `normal` → `normals`.
fn plural(what: &str) -> &str {
    match what {
        "vertex" => "vertices",
        _ => "normals",
    }
}

fn face(t: Tokens<'_>, line: u64, s: &mut State) -> Result<(), Fail> {
    let mut first = (0, 0);
    let mut prev = (0, 0);
    let mut k = 0usize;
    for corner in t {
        let mut parts = corner.split(|&b| b == b'/');
        let v = parts.next().unwrap_or_default();
        let vt = parts.next();
        let vn = parts.next();
        if parts.next().is_some() {
            return Err(syntax(
                line,
                format!(
                    "expected a face corner v, v/vt, v/vt/vn or v//vn, found {}",
                    show(corner)
                ),
            ));
        }
        let v = resolve(v, s.positions.len(), "vertex", line, &mut s.max_v)?;
        if let Some(vt) = vt.filter(|vt| !vt.is_empty())
            && text::parse_i64(vt).is_none()
        {
            return Err(syntax(
                line,
                format!(
                    "expected an integer texture coordinate index, found {}",
                    show(vt)
                ),
            ));
        }
        let n = match vn.filter(|vn| !vn.is_empty()) {
            Some(vn) => Some(resolve(vn, s.normals.len(), "normal", line, &mut s.max_vn)?),
            None => None,
        };
        let n = match n {
            Some(n) => n,
            None => {
                if s.all_normals {
                    s.all_normals = false;
                    s.triangle_normals = Vec::new();
                }
                0
            }
        };
        match k {
            0 => first = (v, n),
            1 => {}
            _ => {
                s.triangles.push([first.0, prev.0, v]);
                if s.all_normals {
                    s.triangle_normals.push([first.1, prev.1, n]);
                }
            }
        }
        prev = (v, n);
        k += 1;
    }
    if k < 3 {
        // Undo nothing: fewer than 3 corners pushed no triangle.
        return Err(Fail::line(
            line,
            LoadErrorKind::Invalid(format!("a face needs at least 3 vertices, found {k}")),
        ));
    }
    Ok(())
}

fn check_max(max: &Option<MaxRef>, defined: usize, what: &str) -> Result<(), Fail> {
    match max {
        Some(m) if m.index as usize >= defined => Err(Fail::line(
            m.line,
            LoadErrorKind::Invalid(format!(
                "{what} index {} is out of range: the file defines {defined} {}",
                u64::from(m.index) + 1,
                plural(what)
            )),
        )),
        _ => Ok(()),
    }
}

fn finish(s: State) -> Result<Mesh, Fail> {
    check_max(&s.max_v, s.positions.len(), "vertex")?;
    check_max(&s.max_vn, s.normals.len(), "normal")?;
    if s.triangles.is_empty() {
        return Err(no_triangles());
    }
    if !s.all_normals {
        return Ok(Mesh::new(s.positions, None, s.triangles)?);
    }
    // One vertex per distinct (position, normal) pair, in order of first use.
    let mut ids: HashMap<(u32, u32), u32> = HashMap::with_capacity(s.positions.len());
    let mut positions = Vec::with_capacity(s.positions.len());
    let mut normals = Vec::with_capacity(s.positions.len());
    let mut triangles = s.triangles;
    for (t, tn) in triangles.iter_mut().zip(&s.triangle_normals) {
        for (v, &n) in t.iter_mut().zip(tn) {
            let next = u32::try_from(positions.len())
                .map_err(|_| MeshError::TooManyVertices(positions.len()))?;
            let id = *ids.entry((*v, n)).or_insert(next);
            if id == next {
                positions.push(s.positions[*v as usize]);
                normals.push(s.normals[n as usize]);
            }
            *v = id;
        }
    }
    Ok(Mesh::new(positions, Some(normals), triangles)?)
}
