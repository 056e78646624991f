//! OFF (Object File Format) loader: ascii `OFF`, `COFF`, `NOFF`, `CNOFF`/`NCOFF` (and `ST`).
//!
//! Layout: the keyword (the counts `vertices faces [edges]` may follow on the same line, else
//! on the next line), then one vertex per line `x y z [nx ny nz] [colour] [s t]`, then one face per
//! line `n i0 … i(n-1) [colour]`, polygons fan-triangulated. `#` starts a comment anywhere.
//! Vertex colours and texture coordinates are ignored; `N` files give per-vertex normals. Binary
//! OFF, `4OFF` and `nOFF` are reported as unsupported. Anything after the last face is ignored.
//!
//! Every error gives the 1-based line; missing data is reported at the line after the last one.

use super::text::{self, Lines, Tokens, show};
use super::{Fail, LoadErrorKind, bounded, no_triangles};
use crate::mesh::Mesh;

/// The prefixes a keyword may carry before `OFF`.
#[derive(Default, Debug)]
struct Flags {
    st: bool,
    colour: bool,
    normals: bool,
    four: bool,
    ndim: bool,
}

/// Parses an OFF keyword such as `OFF`, `NCOFF` or `STCNOFF`.
fn keyword(word: &[u8]) -> Option<Flags> {
    let mut prefix = word.strip_suffix(b"OFF")?;
    let mut f = Flags::default();
    while !prefix.is_empty() {
        let (flag, rest): (&mut bool, &[u8]) = if let Some(r) = prefix.strip_prefix(b"ST") {
            (&mut f.st, r)
        } else {
            let (c, r) = prefix.split_first()?;
            let flag = match c {
                b'C' => &mut f.colour,
                b'N' => &mut f.normals,
                b'4' => &mut f.four,
                b'n' => &mut f.ndim,
                _ => return None,
            };
            (flag, r)
        };
        if std::mem::replace(flag, true) {
            return None;
        }
        prefix = rest;
    }
    Some(f)
}

/// True if `word` is an OFF keyword (for format sniffing).
pub(super) fn is_off_keyword(word: &[u8]) -> bool {
    keyword(word).is_some()
}

fn syntax(line: u64, msg: String) -> Fail {
    Fail::line(line, LoadErrorKind::Syntax(msg))
}

/// The next line holding something other than a comment.
#[inline]
fn next_data<'a>(lines: &mut Lines<'a>) -> Option<Tokens<'a>> {
    loop {
        let l = lines.next_line()?;
        let mut t = Tokens::new(text::strip_comment(l));
        if !t.rest().is_empty() {
            return Some(t);
        }
    }
}

fn count(tok: Option<&[u8]>, line: u64, what: &str) -> Result<u64, Fail> {
    let tok = tok.ok_or_else(|| {
        syntax(
            line,
            format!("expected the number of {what}, found end of line"),
        )
    })?;
    text::parse_u64(tok).ok_or_else(|| {
        syntax(
            line,
            format!("expected the number of {what}, found {}", show(tok)),
        )
    })
}

/// Parses a whole OFF file.
pub(super) fn parse(bytes: &[u8]) -> Result<Mesh, Fail> {
    let mut lines = Lines::new(bytes);
    let eof = |lines: &Lines<'_>, what: String| {
        Fail::line(
            lines.line() + 1,
            LoadErrorKind::Truncated(format!("unexpected end of file {what}")),
        )
    };
    let mut t =
        next_data(&mut lines).ok_or_else(|| eof(&lines, "before the OFF keyword".to_owned()))?;
    let line = lines.line();
    let word = t.next().unwrap_or_default();
    let flags = keyword(word).ok_or_else(|| {
        syntax(
            line,
            format!(
                "expected an OFF keyword (OFF, COFF, NOFF, CNOFF, …), found {}",
                show(word)
            ),
        )
    })?;
    if flags.four || flags.ndim {
        return Err(Fail::line(
            line,
            LoadErrorKind::Unsupported(format!("{}: only 3D vertices are supported", show(word))),
        ));
    }
    if t.rest().starts_with(b"BINARY") {
        return Err(Fail::line(
            line,
            LoadErrorKind::Unsupported("binary OFF".to_owned()),
        ));
    }
    if t.rest().is_empty() {
        t = next_data(&mut lines)
            .ok_or_else(|| eof(&lines, "before the vertex and face counts".to_owned()))?;
    }
    let line = lines.line();
    let nv = count(t.next(), line, "vertices")?;
    let nf = count(t.next(), line, "faces")?;
    if nv > u64::from(u32::MAX) + 1 {
        return Err(Fail::line(
            line,
            LoadErrorKind::Unsupported(format!("{nv} vertices exceed the limit of 2^32")),
        ));
    }

    // A vertex line is at least "0 0 0\n", a face line "3 0 0 0\n".
    let mut positions = Vec::with_capacity(bounded(nv, lines.remaining(), 6));
    let mut normals = flags
        .normals
        .then(|| Vec::with_capacity(positions.capacity()));
    let want = if flags.normals { 6 } else { 3 };
    for i in 0..nv {
        let mut t = next_data(&mut lines).ok_or_else(|| eof(&lines, format!("in vertex {i}")))?;
        let line = lines.line();
        let mut c = [0.0f32; 6];
        for (k, slot) in c[..want].iter_mut().enumerate() {
            let tok = t.next().ok_or_else(|| {
                syntax(
                    line,
                    format!("expected {want} numbers for vertex {i}, found {k}"),
                )
            })?;
            *slot = text::parse_f32(tok).ok_or_else(|| {
                syntax(
                    line,
                    format!("expected a number in vertex {i}, found {}", show(tok)),
                )
            })?;
        }
        if let Some(bad) = c[..3].iter().find(|v| !v.is_finite()) {
            return Err(Fail::line(
                line,
                LoadErrorKind::Invalid(format!("vertex {i} has a non-finite coordinate {bad}")),
            ));
        }
        positions.push([c[0], c[1], c[2]]);
        if let Some(n) = &mut normals {
            n.push([c[3], c[4], c[5]]);
        }
    }

    let mut triangles = Vec::with_capacity(bounded(nf, lines.remaining(), 8));
    for i in 0..nf {
        let mut t = next_data(&mut lines).ok_or_else(|| eof(&lines, format!("in face {i}")))?;
        let line = lines.line();
        let tok = t.next().unwrap_or_default();
        let n = text::parse_u64(tok).ok_or_else(|| {
            syntax(
                line,
                format!("expected the vertex count of face {i}, found {}", show(tok)),
            )
        })?;
        if n < 3 {
            return Err(Fail::line(
                line,
                LoadErrorKind::Invalid(format!(
                    "face {i} has {n} vertices; a face needs at least 3"
                )),
            ));
        }
        let (mut first, mut prev) = (0u32, 0u32);
        for k in 0..n {
            let tok = t.next().ok_or_else(|| {
                syntax(
                    line,
                    format!("expected {n} vertex indices in face {i}, found {k}"),
                )
            })?;
            let index = text::parse_i64(tok).ok_or_else(|| {
                syntax(
                    line,
                    format!(
                        "expected an integer vertex index in face {i}, found {}",
                        show(tok)
                    ),
                )
            })?;
            let v = match u32::try_from(index) {
                Ok(v) if u64::from(v) < nv => v,
                _ => {
                    return Err(Fail::line(
                        line,
                        LoadErrorKind::Invalid(format!(
                            "face {i} refers to vertex {index}, but there are only {nv} vertices"
                        )),
                    ));
                }
            };
            match k {
                0 => first = v,
                1 => {}
                _ => triangles.push([first, prev, v]),
            }
            prev = v;
        }
    }
    if triangles.is_empty() {
        return Err(no_triangles());
    }
    Ok(Mesh::new(positions, normals, triangles)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keywords() {
        assert!(keyword(b"OFF").is_some());
        assert!(keyword(b"NCOFF").is_some_and(|f| f.normals && f.colour));
        assert!(keyword(b"STCNOFF").is_some_and(|f| f.st && f.normals && f.colour));
        assert!(keyword(b"4OFF").is_some_and(|f| f.four));
        assert!(keyword(b"CCOFF").is_none());
        assert!(keyword(b"XOFF").is_none());
        assert!(keyword(b"OF").is_none());
    }
}
