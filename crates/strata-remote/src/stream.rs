//! Whole messages over a byte stream: read the 20-byte prefix, check its length against the
//! limits, read exactly the body. The checksum and fields are checked by the decoders.

use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncReadExt};

use strata_wire::{DecodeOptions, MessageType, PREFIX_LEN, parse_prefix};

pub(crate) use strata_wire::stream::ReadError;

/// One message: its type, all its bytes (prefix included), and how long its body took to
/// arrive after the prefix did (the transfer time the display reports).
pub(crate) struct Incoming {
    pub(crate) kind: MessageType,
    pub(crate) bytes: Vec<u8>,
    pub(crate) body_time: Duration,
}

pub(crate) async fn read_message(
    r: &mut (impl AsyncRead + Unpin),
    limits: &DecodeOptions,
) -> Result<Incoming, ReadError> {
    read_message_into(r, limits, Vec::new()).await
}

/// [`read_message`] into `bytes` (cleared first), whose capacity is reused: a reader of a stream
/// of large messages hands back each buffer once done with it, so no message lands in fresh
/// pages.
pub(crate) async fn read_message_into(
    r: &mut (impl AsyncRead + Unpin),
    limits: &DecodeOptions,
    mut bytes: Vec<u8>,
) -> Result<Incoming, ReadError> {
    let mut prefix = [0u8; PREFIX_LEN];
    let n = r.read(&mut prefix).await?;
    if n == 0 {
        return Err(ReadError::Closed);
    }
    r.read_exact(&mut prefix[n..]).await?;
    let start = Instant::now();
    let p = parse_prefix(&prefix, limits)?;
    let len = PREFIX_LEN + p.body_len as usize;
    // Grow with what arrives rather than trusting the announced length with an allocation.
    bytes.clear();
    bytes.reserve(len.min(1 << 20));
    bytes.extend_from_slice(&prefix);
    r.take(p.body_len).read_to_end(&mut bytes).await?;
    if bytes.len() != len {
        return Err(ReadError::Io(std::io::Error::new(
            std::io::ErrorKind::UnexpectedEof,
            format!(
                "connection closed {} bytes into a {}-byte message",
                bytes.len(),
                len
            ),
        )));
    }
    Ok(Incoming {
        kind: p.kind,
        bytes,
        body_time: start.elapsed(),
    })
}
