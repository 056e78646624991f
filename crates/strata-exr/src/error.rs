//! `ExrError`: every way reading, writing or combining OpenEXR images can fail.
//!
//! Reader errors name where the file is wrong — the byte offset, the attribute, the chunk — so that
//! a person holding a broken file can find the damage with a hex dump, and they never echo
//! megabytes of input back.

use std::path::PathBuf;

/// Why an OpenEXR file could not be read or written, or deep images could not be combined.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExrError {
    /// The operating system refused to read or write a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A reader (not a file) failed.
    #[error("reading the image failed: {0}")]
    Read(#[source] std::io::Error),
    /// The bytes do not start with the OpenEXR magic number.
    #[error("not an OpenEXR file: the first 4 bytes are not 76 2f 31 01")]
    NotExr,
    /// The file ends before a structure it announces.
    #[error(
        "the file is truncated: {what} at byte {offset} needs {needed} bytes, {available} remain"
    )]
    Truncated {
        /// What was being read.
        what: String,
        /// Where it starts.
        offset: u64,
        /// Bytes it needs.
        needed: u64,
        /// Bytes left in the file from `offset`.
        available: u64,
    },
    /// A header attribute is missing, has the wrong type or an impossible value.
    #[error("attribute `{name}`: {problem}")]
    BadAttribute {
        /// The attribute name.
        name: String,
        /// What is wrong with it.
        problem: String,
    },
    /// The header is malformed outside any single attribute.
    #[error("header at byte {offset}: {problem}")]
    BadHeader {
        /// Where the problem was found.
        offset: u64,
        /// What is wrong.
        problem: String,
    },
    /// A pixel-data chunk is malformed.
    #[error("chunk {chunk} (at byte {offset}): {problem}")]
    BadChunk {
        /// The chunk index in the offset table.
        chunk: usize,
        /// Where the chunk starts in the file.
        offset: u64,
        /// What is wrong.
        problem: String,
    },
    /// A flat file where a deep one was expected, or the reverse.
    #[error("the file holds a {found} image, expected a {expected} one")]
    WrongKind {
        /// What the caller asked for (`deep` or `flat`).
        expected: &'static str,
        /// What the file holds.
        found: &'static str,
    },
    /// The file uses an OpenEXR feature strata does not read or write.
    #[error("not supported: {0}")]
    Unsupported(String),
    /// The file is valid but larger than the caller's [`crate::Limits`] allow.
    #[error("{what} ({value}) exceeds the reader's limit of {limit}")]
    LimitExceeded {
        /// The quantity that is too large.
        what: &'static str,
        /// Its value in the file.
        value: u64,
        /// The limit.
        limit: u64,
    },
    /// An image given to the writer or to a deep operation is inconsistent.
    #[error("invalid image: {0}")]
    InvalidImage(String),
    /// Images given to one operation do not fit together (channels, windows).
    #[error("images do not match: {0}")]
    Mismatch(String),
    /// A deep image cannot become a strata DeepFrame.
    #[error("cannot convert to a DeepFrame: {0}")]
    Frame(String),
}

/// Result with [`ExrError`].
pub type Result<T> = std::result::Result<T, ExrError>;
