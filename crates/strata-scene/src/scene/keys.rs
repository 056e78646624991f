//! Where each key of a scene text is, so that errors can name both the key and its line.
//!
//! The schema is deserialized with serde: its errors carry a byte span of the offending value but
//! no key, and the values it produces carry no position at all. [`KeyIndex`] parses the text a
//! second time into toml's spanned tree and lists every key path with the byte ranges of its key
//! and of its value:
//!
//! ```text
//! path               key span            value span
//! width              `width`             `1280`
//! camera             `camera` in header  the `[camera]` header
//! camera.eye         `eye`               `[0, 0, 3]`
//! objects            `objects`           the first `[[objects]]` header
//! objects[2]         the 3rd header      the 3rd header (or the inline table)
//! objects[2].color   `color`             `[1, 0, 0, 0.5]`
//! ```
//!
//! An error's span is mapped to the innermost entry containing it ([`KeyIndex::key_at`]); a key
//! path is mapped to its line, or to the line of the nearest enclosing key the text has, for a
//! key left at its default ([`KeyIndex::position_of`]). The index is built only when an error is
//! reported, so valid files are parsed once.

use std::ops::Range;

use toml::Spanned;
use toml::de::{DeTable, DeValue};

use super::TextPosition;

/// One key of the text.
struct Entry {
    path: String,
    key: Range<usize>,
    value: Range<usize>,
}

/// Every key path of a scene text with its spans; see the module docs.
pub(super) struct KeyIndex<'t> {
    text: &'t str,
    entries: Vec<Entry>,
}

impl<'t> KeyIndex<'t> {
    /// Indexes `text`; a text that is not valid TOML gives an index without keys.
    pub(super) fn new(text: &'t str) -> Self {
        let mut entries = Vec::new();
        if let Ok(root) = DeTable::parse(text) {
            collect_table(root.get_ref(), "", &mut entries);
        }
        KeyIndex { text, entries }
    }

    /// The innermost key whose key or value contains `span`.
    pub(super) fn key_at(&self, span: &Range<usize>) -> Option<&str> {
        let inside = |r: &Range<usize>| r.start <= span.start && span.end <= r.end;
        self.entries
            .iter()
            .filter(|e| inside(&e.key) || inside(&e.value))
            .min_by_key(|e| (e.value.len(), usize::MAX - e.path.len()))
            .map(|e| e.path.as_str())
    }

    /// The line of `path`'s key, or of the nearest enclosing key the text has.
    pub(super) fn position_of(&self, path: &str) -> Option<TextPosition> {
        let mut path = path;
        loop {
            if let Some(e) = self.entries.iter().find(|e| e.path == path) {
                let mut at = self.position(e.key.start);
                at.column = None;
                return Some(at);
            }
            path = parent(path)?;
        }
    }

    /// The line and column of byte `offset`.
    pub(super) fn position(&self, offset: usize) -> TextPosition {
        let mut end = offset.min(self.text.len());
        while !self.text.is_char_boundary(end) {
            end -= 1;
        }
        let before = &self.text[..end];
        let line_start = before.rfind('\n').map_or(0, |i| i + 1);
        let saturate = |n: usize| u32::try_from(n).unwrap_or(u32::MAX).saturating_add(1);
        TextPosition {
            line: saturate(before.matches('\n').count()),
            column: Some(saturate(before[line_start..].chars().count())),
        }
    }
}

/// `objects[2].color` → `objects[2]` → `objects` → `None`.
fn parent(path: &str) -> Option<&str> {
    let cut = path.rfind(['.', '['])?;
    Some(&path[..cut])
}

fn collect_table(table: &DeTable<'_>, prefix: &str, out: &mut Vec<Entry>) {
    for (key, value) in table.iter() {
        let path = if prefix.is_empty() {
            key.get_ref().to_string()
        } else {
            format!("{prefix}.{}", key.get_ref())
        };
        out.push(Entry {
            path: path.clone(),
            key: key.span(),
            value: value.span(),
        });
        collect_value(value, &path, out);
    }
}

fn collect_value(value: &Spanned<DeValue<'_>>, path: &str, out: &mut Vec<Entry>) {
    match value.get_ref() {
        DeValue::Table(t) => collect_table(t, path, out),
        DeValue::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                // Only tables inside arrays are keys of their own; numbers are part of their array.
                if let DeValue::Table(t) = item.get_ref() {
                    let path = format!("{path}[{i}]");
                    out.push(Entry {
                        path: path.clone(),
                        key: item.span(),
                        value: item.span(),
                    });
                    collect_table(t, &path, out);
                }
            }
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "width = 10\n[camera]\neye = [0, 0, 3]\n\n[[objects]]\nbuiltin = \"quad\"\n\
                        [[objects]]\ncolor = [1, 0, 0, 1]\n";

    #[test]
    fn spans_map_to_the_innermost_key() {
        let k = KeyIndex::new(TEXT);
        let at = |needle: &str| {
            let start = TEXT.find(needle).expect("needle in text");
            k.key_at(&(start..start + needle.len()))
        };
        assert_eq!(at("10"), Some("width"));
        assert_eq!(at("[0, 0, 3]"), Some("camera.eye"));
        assert_eq!(at("0, 3"), Some("camera.eye"));
        assert_eq!(at("\"quad\""), Some("objects[0].builtin"));
        assert_eq!(at("[1, 0, 0, 1]"), Some("objects[1].color"));
        assert_eq!(at("color"), Some("objects[1].color"));
    }

    #[test]
    fn paths_map_to_their_line_or_their_parents() {
        let k = KeyIndex::new(TEXT);
        let line = |p: &str| k.position_of(p).map(|p| p.line);
        assert_eq!(line("width"), Some(1));
        assert_eq!(line("camera.eye"), Some(3));
        assert_eq!(
            line("camera.up"),
            Some(2),
            "a default falls back to its table"
        );
        assert_eq!(line("objects[1]"), Some(7));
        assert_eq!(line("objects[1].color"), Some(8));
        assert_eq!(line("objects[1].scale"), Some(7));
        assert_eq!(line("height"), None);
        assert_eq!(line("animation.frames"), None);
    }

    #[test]
    fn positions_count_lines_and_characters_from_one() {
        let k = KeyIndex::new("a = 1\nb = \"é\" x\n");
        let p = k.position(13);
        assert_eq!((p.line, p.column), (2, Some(7)));
        assert_eq!(
            k.position(12).column,
            Some(6),
            "inside a character: its start"
        );
        assert_eq!(k.position(0).line, 1);
        assert_eq!(k.position(1000).line, 3, "past the end: the last line");
    }
}
