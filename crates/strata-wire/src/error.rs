//! The one error type of the wire format: every failure says which field, at which byte offset.

use strata_core::DeepFrameError;

/// Why a message could not be encoded or decoded.
///
/// Offsets are absolute byte offsets from the first byte of the message (the magic); fields are
/// named as in `docs/wire-format.md`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum WireError {
    /// The message ends before a field does.
    #[error(
        "truncated message: {field} at byte {offset} needs {needed} bytes, only {available} left"
    )]
    Truncated {
        /// The field being read.
        field: &'static str,
        /// Where it starts.
        offset: u64,
        /// Bytes it needs.
        needed: u64,
        /// Bytes the message still had.
        available: u64,
    },
    /// The first four bytes are not `STRW`.
    #[error("not a strata wire message: magic at byte 0 is {found:02x?}, expected \"STRW\"")]
    BadMagic {
        /// The four bytes found.
        found: [u8; 4],
    },
    /// A format version this decoder does not read.
    #[error(
        "format version {found} at byte 4 is not supported (this decoder reads version {supported})"
    )]
    UnsupportedVersion {
        /// The version in the message.
        found: u16,
        /// The version this crate reads and writes.
        supported: u16,
    },
    /// A message type that is reserved or unknown.
    #[error("message type {found} at byte 6 is {what}")]
    UnsupportedMessageType {
        /// The type byte.
        found: u8,
        /// "reserved for …" or "unknown".
        what: &'static str,
    },
    /// A field holds a value the format does not allow.
    #[error("byte {offset} ({field}): {value} is invalid: {reason}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// Where it starts.
        offset: u64,
        /// The value found, as text.
        value: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A field exceeds a decoder limit ([`crate::DecodeOptions`]); checked before allocating.
    #[error("byte {offset} ({field}): {value} exceeds the limit of {limit}")]
    Limit {
        /// The field.
        field: &'static str,
        /// Where it starts.
        offset: u64,
        /// The value found.
        value: u64,
        /// The limit in force.
        limit: u64,
    },
    /// The body does not match its CRC-32.
    #[error(
        "checksum mismatch: byte 16 says {expected:#010x}, the body hashes to {computed:#010x}"
    )]
    Checksum {
        /// The checksum in the prefix.
        expected: u32,
        /// The checksum of the body as received.
        computed: u32,
    },
    /// A section's payload could not be decompressed or parsed.
    #[error("section {section} at byte {offset}: {reason}")]
    Section {
        /// The section's name.
        section: &'static str,
        /// Where its payload starts.
        offset: u64,
        /// What went wrong.
        reason: String,
    },
    /// The decoded fragments violate a DeepFrame invariant (unsorted runs, depths outside
    /// `[0, 1]`, …): strata-core checks everything a decoder produces (`DeepFrame::from_parts`,
    /// or `DeepFrame::fill_bands` band by band).
    #[error("the decoded fragments are not a valid DeepFrame: {0}")]
    Frame(#[from] DeepFrameError),
    /// The encoder was asked for something the format cannot carry.
    #[error("cannot encode: {0}")]
    Encode(String),
}

impl WireError {
    /// An [`WireError::Invalid`] error.
    pub(crate) fn invalid(
        field: &'static str,
        offset: u64,
        value: impl ToString,
        reason: impl Into<String>,
    ) -> Self {
        WireError::Invalid {
            field,
            offset,
            value: value.to_string(),
            reason: reason.into(),
        }
    }

    /// A [`WireError::Section`] error.
    pub(crate) fn section(section: &'static str, offset: u64, reason: impl Into<String>) -> Self {
        WireError::Section {
            section,
            offset,
            reason: reason.into(),
        }
    }
}
