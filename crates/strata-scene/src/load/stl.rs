//! STL (stereolithography) loader: binary and ascii, welded into an indexed mesh.
//!
//! Binary layout, little endian:
//!
//! ```text
//! byte 0    header      80 bytes of free text (which may itself begin with "solid")
//! byte 80   n           u32, the number of triangles
//! byte 84   triangle 0  50 bytes: normal f32×3, corners f32×3 ×3, attribute u16 (ignored)
//! …         triangle n-1
//! ```
//!
//! The file must be exactly `84 + 50·n` bytes: fewer is truncation, more is data the loader would
//! ignore, and both are errors located by byte.
//!
//! Ascii: `solid [name]`, then per triangle `facet normal nx ny nz`, `outer loop`, three
//! `vertex x y z`, `endloop`, `endfacet`, and finally `endsolid [name]`; several solids may follow
//! each other. Tokens are separated by any whitespace (line breaks included); the name runs to the
//! end of its line. Errors give the line; missing data is reported at the line after the last.
//!
//! Which one: a file whose size is exactly `84 + 50·n` for the count at byte 80 is binary, even
//! when its header starts with `solid` (many exporters write that); otherwise a file whose first
//! word is `solid` is ascii; anything else is read as binary, and fails on its size.
//!
//! STL repeats each corner in every triangle that uses it. Corners with bit-identical
//! coordinates (`-0` counting as `0`) are welded into one vertex, so the mesh is indexed like
//! the other formats' and shades smoothly; the facet normals are read but not used, and vertex
//! normals are computed (area-weighted) as for any file without normals. Coordinates must be
//! finite. Memory grows with the bytes actually read, never with a count the file claims.

use std::collections::HashMap;

use super::text::{self, Lines, Tokens, show};
use super::{Fail, LoadErrorKind, bounded, no_triangles};
use crate::mesh::Mesh;

/// The binary header before the triangle count.
const HEADER: usize = 80;
/// Header plus the triangle count.
const PREAMBLE: usize = HEADER + 4;
/// One binary triangle: 12 `f32` and a `u16`.
const TRIANGLE: usize = 50;
/// Bytes of the shortest ascii facet (`facet normal 0 0 0 outer loop vertex 0 0 0` …), to bound
/// reservations.
const MIN_ASCII_FACET: usize = 80;

/// Parses a binary or ascii STL file.
pub(super) fn parse(bytes: &[u8]) -> Result<Mesh, Fail> {
    if declares_its_size(bytes) || !starts_with_solid(bytes) {
        parse_binary(bytes)
    } else {
        parse_ascii(bytes)
    }
}

/// True for content that looks like STL of either kind (for format sniffing).
pub(super) fn is_stl(bytes: &[u8]) -> bool {
    declares_its_size(bytes) || starts_with_solid(bytes)
}

/// The triangle count of a binary file, if it has the 84-byte preamble.
fn binary_count(bytes: &[u8]) -> Option<u32> {
    let count = bytes.get(HEADER..PREAMBLE)?;
    Some(u32::from_le_bytes(count.try_into().ok()?))
}

/// True if the file is exactly as long as its binary triangle count says.
fn declares_its_size(bytes: &[u8]) -> bool {
    binary_count(bytes)
        .is_some_and(|n| PREAMBLE as u64 + u64::from(n) * TRIANGLE as u64 == bytes.len() as u64)
}

/// True if the first word (after a byte-order mark and whitespace) is `solid`.
fn starts_with_solid(bytes: &[u8]) -> bool {
    let bytes = bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes);
    Lines::new(bytes)
        .next_nonblank()
        .and_then(|mut t| t.next())
        .is_some_and(|w| w == b"solid")
}

// ----- binary ---------------------------------------------------------------------------------

fn parse_binary(bytes: &[u8]) -> Result<Mesh, Fail> {
    let Some(n) = binary_count(bytes) else {
        return Err(Fail::byte(
            bytes.len(),
            LoadErrorKind::Truncated(format!(
                "a binary STL starts with an {HEADER}-byte header and a triangle count \
                 ({PREAMBLE} bytes), but the file has {} bytes (an ascii STL starts with `solid`)",
                bytes.len()
            )),
        ));
    };
    let body = &bytes[PREAMBLE..];
    let needed = u64::from(n) * TRIANGLE as u64;
    let have = body.len() as u64;
    if have < needed {
        let complete = body.len() / TRIANGLE;
        return Err(Fail::byte(
            PREAMBLE + complete * TRIANGLE,
            LoadErrorKind::Truncated(format!(
                "the file ends in triangle {complete}: it declares {n} triangles \
                 ({needed} bytes after the header) but has {have}"
            )),
        ));
    }
    if have > needed {
        return Err(Fail::byte(
            PREAMBLE + needed as usize,
            LoadErrorKind::Invalid(format!(
                "{} bytes follow the {n} triangles the header declares",
                have - needed
            )),
        ));
    }
    let mut weld = Welder::with_capacity(n as usize);
    for (i, t) in body.chunks_exact(TRIANGLE).enumerate() {
        let at = PREAMBLE + i * TRIANGLE;
        let mut corners = [[0.0f32; 3]; 3];
        for (k, corner) in corners.iter_mut().enumerate() {
            for (c, value) in corner.iter_mut().enumerate() {
                let offset = 12 + 12 * k + 4 * c;
                let v =
                    f32::from_le_bytes([t[offset], t[offset + 1], t[offset + 2], t[offset + 3]]);
                if !v.is_finite() {
                    return Err(Fail::byte(
                        at + offset,
                        LoadErrorKind::Invalid(format!(
                            "corner {k} of triangle {i} has a non-finite coordinate {v}"
                        )),
                    ));
                }
                *value = v;
            }
        }
        weld.triangle(corners).map_err(|k| Fail::byte(at, k))?;
    }
    weld.finish()
}

// ----- ascii ----------------------------------------------------------------------------------

/// The words of an ascii file, across line breaks, with the line of each.
struct Words<'a> {
    lines: Lines<'a>,
    current: Tokens<'a>,
}

impl<'a> Words<'a> {
    fn new(bytes: &'a [u8]) -> Self {
        let bytes = bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes);
        Words {
            lines: Lines::new(bytes),
            current: Tokens::new(b""),
        }
    }

    fn next(&mut self) -> Option<&'a [u8]> {
        loop {
            if let Some(w) = self.current.next() {
                return Some(w);
            }
            self.current = Tokens::new(self.lines.next_line()?);
        }
    }

    /// Drops the rest of the current line (a solid's name).
    fn skip_line(&mut self) {
        self.current = Tokens::new(b"");
    }

    /// The line of the word most recently returned.
    fn line(&self) -> u64 {
        self.lines.line()
    }

    /// The next word, or an error naming what was expected.
    fn expect_any(&mut self, what: &str) -> Result<&'a [u8], Fail> {
        self.next().ok_or_else(|| {
            Fail::line(
                self.line() + 1,
                LoadErrorKind::Truncated(format!("unexpected end of file: expected {what}")),
            )
        })
    }

    /// The keyword `word`.
    fn keyword(&mut self, word: &str) -> Result<(), Fail> {
        let w = self.expect_any(&format!("`{word}`"))?;
        if w == word.as_bytes() {
            Ok(())
        } else {
            Err(self.syntax(format!("expected `{word}`, found {}", show(w))))
        }
    }

    /// A number; `finite` refuses infinities and NaN.
    fn number(&mut self, what: &str, finite: bool) -> Result<f32, Fail> {
        let w = self.expect_any(what)?;
        match text::parse_f32(w) {
            Some(v) if v.is_finite() || !finite => Ok(v),
            Some(v) => Err(Fail::line(
                self.line(),
                LoadErrorKind::Invalid(format!("{what} is {v}, not a finite number")),
            )),
            None => Err(self.syntax(format!("expected {what}, found {}", show(w)))),
        }
    }

    fn syntax(&self, msg: String) -> Fail {
        Fail::line(self.line(), LoadErrorKind::Syntax(msg))
    }
}

fn parse_ascii(bytes: &[u8]) -> Result<Mesh, Fail> {
    let mut words = Words::new(bytes);
    let mut weld = Welder::with_capacity(bounded(u64::MAX, bytes.len(), MIN_ASCII_FACET));
    let mut solids = 0u64;
    while let Some(w) = words.next() {
        if w != b"solid" {
            let expected = if solids == 0 {
                "`solid`"
            } else {
                "`solid` or the end of the file"
            };
            return Err(words.syntax(format!("expected {expected}, found {}", show(w))));
        }
        words.skip_line();
        solids += 1;
        solid(&mut words, &mut weld)?;
    }
    if solids == 0 {
        return Err(Fail::line(
            1,
            LoadErrorKind::Truncated("the file is empty: expected `solid`".to_owned()),
        ));
    }
    weld.finish()
}

/// The facets of one solid, up to and including its `endsolid` line.
fn solid(words: &mut Words<'_>, weld: &mut Welder) -> Result<(), Fail> {
    loop {
        let w = words.expect_any("`facet` or `endsolid`")?;
        match w {
            b"endsolid" => {
                words.skip_line();
                return Ok(());
            }
            b"facet" => facet(words, weld)?,
            _ => {
                return Err(
                    words.syntax(format!("expected `facet` or `endsolid`, found {}", show(w)))
                );
            }
        }
    }
}

/// One facet after its `facet` keyword.
fn facet(words: &mut Words<'_>, weld: &mut Welder) -> Result<(), Fail> {
    words.keyword("normal")?;
    for _ in 0..3 {
        // Read for the syntax, not used: normals are computed from the welded mesh.
        words.number("a facet normal component", false)?;
    }
    words.keyword("outer")?;
    words.keyword("loop")?;
    let line = words.line();
    let mut corners = [[0.0f32; 3]; 3];
    for corner in &mut corners {
        words.keyword("vertex")?;
        for c in corner.iter_mut() {
            *c = words.number("a vertex coordinate", true)?;
        }
    }
    let w = words.expect_any("`endloop`")?;
    if w != b"endloop" {
        let hint = if w == b"vertex" {
            " (STL facets are triangles: exactly three vertices)"
        } else {
            ""
        };
        return Err(words.syntax(format!("expected `endloop`, found {}{hint}", show(w))));
    }
    words.keyword("endfacet")?;
    weld.triangle(corners).map_err(|k| Fail::line(line, k))
}

// ----- welding --------------------------------------------------------------------------------

/// Builds an indexed mesh from triangle corners, one vertex per distinct position.
struct Welder {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    index: HashMap<[u32; 3], u32>,
}

impl Welder {
    /// Room for `triangles` triangles (callers bound it by the bytes present).
    fn with_capacity(triangles: usize) -> Self {
        Welder {
            positions: Vec::with_capacity(triangles / 2),
            triangles: Vec::with_capacity(triangles),
            index: HashMap::with_capacity(triangles / 2),
        }
    }

    fn triangle(&mut self, corners: [[f32; 3]; 3]) -> Result<(), LoadErrorKind> {
        let mut t = [0u32; 3];
        for (slot, p) in t.iter_mut().zip(corners) {
            *slot = self.vertex(p)?;
        }
        self.triangles.push(t);
        Ok(())
    }

    fn vertex(&mut self, p: [f32; 3]) -> Result<u32, LoadErrorKind> {
        // `+ 0.0` turns -0 into +0, so the two weld.
        let key = p.map(|c| (c + 0.0).to_bits());
        if let Some(&i) = self.index.get(&key) {
            return Ok(i);
        }
        let i = u32::try_from(self.positions.len()).map_err(|_| {
            LoadErrorKind::Unsupported("more than 2^32 distinct vertices".to_owned())
        })?;
        self.positions.push(p);
        self.index.insert(key, i);
        Ok(i)
    }

    fn finish(self) -> Result<Mesh, Fail> {
        if self.triangles.is_empty() {
            return Err(no_triangles());
        }
        Ok(Mesh::new(self.positions, None, self.triangles)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn negative_zero_welds_with_zero() {
        let mut w = Welder::with_capacity(2);
        w.triangle([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
            .expect("weld");
        w.triangle([[-0.0, 0.0, -0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
            .expect("weld");
        let m = w.finish().expect("mesh");
        assert_eq!(m.positions().len(), 4);
        assert_eq!(m.triangles(), &[[0, 1, 2], [0, 2, 3]]);
    }

    #[test]
    fn detection_prefers_a_matching_binary_size() {
        let mut b = b"solid exported by a CAD tool".to_vec();
        b.resize(HEADER, b' ');
        b.extend_from_slice(&0u32.to_le_bytes());
        assert!(declares_its_size(&b) && starts_with_solid(&b));
        b.push(0);
        assert!(!declares_its_size(&b));
        assert!(starts_with_solid(b"\xef\xbb\xbf\n  solid\n"));
        assert!(!starts_with_solid(b"solidify"));
        assert!(!is_stl(b"v 0 0 0\n"));
    }
}
