//! The shared tokenizer of the text loaders: lines, whitespace-separated tokens and numbers.
//!
//! Works on borrowed slices of the whole (decompressed) file: nothing allocates per line or per
//! token. Lines end at `\n`; a `\r` before it (CRLF) counts as whitespace. Line numbers are
//! 1-based, as every text-format error reports them.

/// A cursor over the lines of a text buffer.
pub(super) struct Lines<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// Number of the line most recently returned (0 before the first).
    line: u64,
}

impl<'a> Lines<'a> {
    /// A cursor at the start of `bytes`.
    pub(super) fn new(bytes: &'a [u8]) -> Self {
        Lines {
            bytes,
            pos: 0,
            line: 0,
        }
    }

    /// The next line without its terminator, or `None` at the end of the buffer.
    #[inline]
    pub(super) fn next_line(&mut self) -> Option<&'a [u8]> {
        let rest = self.bytes.get(self.pos..).filter(|r| !r.is_empty())?;
        self.line += 1;
        match rest.iter().position(|&b| b == b'\n') {
            Some(n) => {
                self.pos += n + 1;
                Some(&rest[..n])
            }
            None => {
                self.pos = self.bytes.len();
                Some(rest)
            }
        }
    }

    /// The next line that holds a token, as tokens; `None` at the end of the buffer.
    #[inline]
    pub(super) fn next_nonblank(&mut self) -> Option<Tokens<'a>> {
        while let Some(line) = self.next_line() {
            let mut t = Tokens::new(line);
            if t.skip_space() {
                return Some(t);
            }
        }
        None
    }

    /// Number of the line most recently returned (0 before the first).
    pub(super) fn line(&self) -> u64 {
        self.line
    }

    /// Byte offset of the start of the next line.
    pub(super) fn offset(&self) -> usize {
        self.pos
    }

    /// Bytes not yet returned.
    pub(super) fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }
}

/// True for the bytes that separate tokens.
#[inline]
pub(super) fn is_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | 0x0b | 0x0c)
}

/// The whitespace-separated tokens of one line.
#[derive(Clone)]
pub(super) struct Tokens<'a> {
    rest: &'a [u8],
}

impl<'a> Tokens<'a> {
    /// The tokens of `line`.
    #[inline]
    pub(super) fn new(line: &'a [u8]) -> Self {
        Tokens { rest: line }
    }

    /// Skips leading whitespace; true if a token follows.
    #[inline]
    fn skip_space(&mut self) -> bool {
        let n = self
            .rest
            .iter()
            .position(|&b| !is_space(b))
            .unwrap_or(self.rest.len());
        self.rest = &self.rest[n..];
        !self.rest.is_empty()
    }

    /// The unread rest of the line, starting at the next token.
    pub(super) fn rest(&mut self) -> &'a [u8] {
        self.skip_space();
        self.rest
    }
}

impl<'a> Iterator for Tokens<'a> {
    type Item = &'a [u8];

    #[inline]
    fn next(&mut self) -> Option<&'a [u8]> {
        if !self.skip_space() {
            return None;
        }
        let n = self
            .rest
            .iter()
            .position(|&b| is_space(b))
            .unwrap_or(self.rest.len());
        let (token, rest) = self.rest.split_at(n);
        self.rest = rest;
        Some(token)
    }
}

/// `line` up to its first `#`.
#[inline]
pub(super) fn strip_comment(line: &[u8]) -> &[u8] {
    match line.iter().position(|&b| b == b'#') {
        Some(n) => &line[..n],
        None => line,
    }
}

/// A float token (decimal or exponent notation; also `inf` and `nan`, which callers reject
/// where they need finite values).
#[inline]
pub(super) fn parse_f32(token: &[u8]) -> Option<f32> {
    fast_float2::parse::<f32, _>(token).ok()
}

/// A decimal integer token with an optional sign; `None` on any other byte or on overflow.
#[inline]
pub(super) fn parse_i64(token: &[u8]) -> Option<i64> {
    let (negative, digits) = match token.split_first() {
        Some((b'-', d)) => (true, d),
        Some((b'+', d)) => (false, d),
        _ => (false, token),
    };
    if digits.is_empty() {
        return None;
    }
    let mut value: i64 = 0;
    for &b in digits {
        let d = b.wrapping_sub(b'0');
        if d > 9 {
            return None;
        }
        value = value.checked_mul(10)?;
        value = if negative {
            value.checked_sub(i64::from(d))?
        } else {
            value.checked_add(i64::from(d))?
        };
    }
    Some(value)
}

/// A decimal integer token that is `>= 0` (an optional `+` sign, digits); `None` on overflow.
#[inline]
pub(super) fn parse_u64(token: &[u8]) -> Option<u64> {
    let digits = token.strip_prefix(b"+").unwrap_or(token);
    if digits.is_empty() {
        return None;
    }
    let mut value: u64 = 0;
    for &b in digits {
        let d = b.wrapping_sub(b'0');
        if d > 9 {
            return None;
        }
        value = value.checked_mul(10)?.checked_add(u64::from(d))?;
    }
    Some(value)
}

/// A token quoted for an error message, shortened if long.
pub(super) fn show(token: &[u8]) -> String {
    const MAX: usize = 40;
    let s = String::from_utf8_lossy(&token[..token.len().min(MAX)]);
    if token.len() > MAX {
        format!("'{s}…'")
    } else {
        format!("'{s}'")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_and_tokens() {
        let mut l = Lines::new(b"a b\r\n\n  \t\nc  d e \n f");
        assert_eq!(l.next_line(), Some(&b"a b\r"[..]));
        let t = l.next_nonblank().map(|t| t.collect::<Vec<_>>());
        assert_eq!(t, Some(vec![&b"c"[..], b"d", b"e"]));
        assert_eq!(l.line(), 4);
        assert_eq!(l.next_line(), Some(&b" f"[..]));
        assert_eq!(l.next_line(), None);
        assert_eq!(l.line(), 5);
        assert_eq!(Tokens::new(b"x\r").collect::<Vec<_>>(), vec![&b"x"[..]]);
    }

    #[test]
    fn integers() {
        assert_eq!(parse_i64(b"-12"), Some(-12));
        assert_eq!(parse_i64(b"+7"), Some(7));
        assert_eq!(parse_i64(b"9223372036854775807"), Some(i64::MAX));
        assert_eq!(parse_i64(b"-9223372036854775808"), Some(i64::MIN));
        assert_eq!(parse_i64(b"9223372036854775808"), None);
        assert_eq!(parse_i64(b"1.5"), None);
        assert_eq!(parse_i64(b"-"), None);
        assert_eq!(parse_i64(b""), None);
        assert_eq!(parse_u64(b"-1"), None);
        assert_eq!(parse_u64(b"18446744073709551615"), Some(u64::MAX));
        assert_eq!(parse_u64(b"18446744073709551616"), None);
        assert_eq!(parse_u64(b"+3"), Some(3));
    }

    #[test]
    fn floats() {
        assert_eq!(parse_f32(b"1.5e2"), Some(150.0));
        assert_eq!(parse_f32(b"-0.25"), Some(-0.25));
        assert_eq!(parse_f32(b"1.5x"), None);
        assert_eq!(parse_f32(b""), None);
    }
}
