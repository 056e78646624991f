//! Whole messages from a blocking byte stream (a `std::net::TcpStream`): read the 20-byte prefix,
//! check its length against the limits, read exactly the body. The checksum and the fields are
//! checked by the decoders. (The async services in strata-remote do the same over tokio.)

use std::io::Read;

use crate::error::WireError;
use crate::message::{DecodeOptions, MessageType, PREFIX_LEN, parse_prefix};

/// Why no message could be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReadError {
    /// The peer closed the connection between messages.
    #[error("connection closed")]
    Closed,
    /// The socket failed (a reset, a timeout), or closed inside a message.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The prefix is not a strata message or announces more than the limits allow.
    #[error("{0}")]
    Wire(#[from] WireError),
}

/// Reads one whole message: its type and all its bytes, prefix included.
///
/// # Errors
/// [`ReadError::Closed`] at a clean end of stream before the first byte; otherwise the socket's
/// error, a stream that ends inside the message, or a prefix that [`parse_prefix`] refuses.
pub fn read_message(
    r: &mut impl Read,
    limits: &DecodeOptions,
) -> Result<(MessageType, Vec<u8>), ReadError> {
    let mut prefix = [0u8; PREFIX_LEN];
    let n = loop {
        match r.read(&mut prefix) {
            Ok(n) => break n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e.into()),
        }
    };
    if n == 0 {
        return Err(ReadError::Closed);
    }
    r.read_exact(&mut prefix[n..])?;
    let p = parse_prefix(&prefix, limits)?;
    let len = PREFIX_LEN as u64 + p.body_len;
    // Grow with what arrives rather than trusting the announced length with an allocation.
    let mut bytes = Vec::with_capacity(len.min(1 << 20) as usize);
    bytes.extend_from_slice(&prefix);
    r.take(p.body_len).read_to_end(&mut bytes)?;
    if bytes.len() as u64 != len {
        return Err(ReadError::Io(std::io::Error::new(
            std::io::ErrorKind::UnexpectedEof,
            format!(
                "connection closed {} bytes into a {len}-byte message",
                bytes.len()
            ),
        )));
    }
    Ok((p.kind, bytes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::encode_error_into;

    #[test]
    fn messages_are_read_one_at_a_time_and_a_cut_one_is_an_error() {
        let mut a = Vec::new();
        encode_error_into(&mut a, "first");
        let mut b = Vec::new();
        encode_error_into(&mut b, "second");
        let mut stream: Vec<u8> = a.iter().chain(&b).copied().collect();
        let limits = DecodeOptions::default();
        let mut r = &stream[..];
        assert_eq!(
            read_message(&mut r, &limits).unwrap(),
            (MessageType::Error, a)
        );
        assert_eq!(read_message(&mut r, &limits).unwrap().1, b);
        assert!(matches!(
            read_message(&mut r, &limits),
            Err(ReadError::Closed)
        ));
        stream.truncate(stream.len() - 2);
        let mut r = &stream[stream.len() - b.len() + 2..];
        assert!(matches!(
            read_message(&mut r, &limits),
            Err(ReadError::Io(_))
        ));
        let garbage = [0x47u8; 40];
        assert!(matches!(
            read_message(&mut &garbage[..], &limits),
            Err(ReadError::Wire(WireError::BadMagic { .. }))
        ));
    }
}
