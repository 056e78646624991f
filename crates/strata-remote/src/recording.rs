//! Recorded node streams: what a render node answered a display, kept in a file so that a
//! display can later be measured alone, fed from memory by a node that renders nothing
//! (`strata node --record FILE`, then `strata node --replay FILE`).
//!
//! # File layout
//!
//! ```text
//! offset 0   16 bytes  b"strata-recording"
//!        16  u32 LE    version (1)
//!        20  strata-wire messages back to back, exactly as they travel:
//!              the node's hello,
//!              then per answered request: the request, the node's frame message, its stats
//! ```
//!
//! The request is stored re-encoded from what the node decoded, and a replaying node looks an
//! incoming request up the same way (decode, encode), so two requests match exactly when they
//! ask for the same thing. A display run that repeats the recorded one (same scene, transfer,
//! codec, size and frames) sends only requests the recording holds, and gets back the recorded
//! bytes; the difference and reprojection transfers, whose replies depend on the frames before,
//! replay correctly because the display asks for the frames in the recorded order. Fixup
//! requests and their replies are recorded like any other exchange.
//!
//! A recording is written as the node answers, one exchange per write, unbuffered, so a node
//! stopped after its display finished leaves a complete file; the loader refuses a file that
//! ends inside an exchange and says where.

use std::collections::HashMap;
use std::fs::File;
use std::io::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use strata_wire::{
    DecodeOptions, Hello, MessageType, NodeStats, PREFIX_LEN, Request, RequestKind, WireError,
    encode_error_into, parse_prefix,
};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};

use crate::node::{ConnectionError, NodeEvent, next_request};

/// The first 16 bytes of a recording.
pub const MAGIC: [u8; 16] = *b"strata-recording";
/// The layout this build writes and reads.
pub const VERSION: u32 = 1;
const HEADER_LEN: usize = MAGIC.len() + 4;

/// Why a recording cannot be written or read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordingError {
    /// The file system refused.
    #[error("{what} {path}: {source}")]
    Io {
        /// What was being done.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file does not start with the recording magic.
    #[error("{path} is not a strata recording (it does not start with \"strata-recording\")")]
    NotARecording {
        /// The file.
        path: PathBuf,
    },
    /// A layout version this build does not read.
    #[error("{path} is a version {found} recording; this build reads version {VERSION}")]
    Version {
        /// The file.
        path: PathBuf,
        /// The version in the file.
        found: u32,
    },
    /// Something in the file is not what the layout says.
    #[error("{path}, byte {offset}: {what}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// Where the problem starts.
        offset: usize,
        /// What is wrong.
        what: String,
    },
    /// A message could not be encoded.
    #[error("recording to {path}: {source}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// Why.
        source: WireError,
    },
}

/// Writes a node's exchanges to a recording file; shared by every connection the node serves.
#[derive(Debug)]
pub struct Recorder {
    path: PathBuf,
    file: Mutex<File>,
}

impl Recorder {
    /// Creates (or truncates) `path` and writes the header and the node's `hello`.
    pub fn create(path: &Path, hello: &Hello) -> Result<Recorder, RecordingError> {
        let io = |what| {
            move |source| RecordingError::Io {
                what,
                path: path.to_path_buf(),
                source,
            }
        };
        let mut bytes = Vec::from(MAGIC);
        bytes.extend_from_slice(&VERSION.to_le_bytes());
        let mut h = Vec::new();
        hello
            .encode_into(&mut h)
            .map_err(|source| RecordingError::Encode {
                path: path.to_path_buf(),
                source,
            })?;
        bytes.extend_from_slice(&h);
        let mut file = File::create(path).map_err(io("creating"))?;
        file.write_all(&bytes).map_err(io("writing"))?;
        Ok(Recorder {
            path: path.to_path_buf(),
            file: Mutex::new(file),
        })
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one exchange: `request` and the `reply` the node sent (its frame message and
    /// stats message).
    pub fn record(&self, request: &Request, reply: &[u8]) -> Result<(), RecordingError> {
        let mut req = Vec::with_capacity(256);
        request
            .encode_into(&mut req)
            .map_err(|source| RecordingError::Encode {
                path: self.path.clone(),
                source,
            })?;
        // A poisoned lock only means another connection panicked mid-write; the file is what
        // it is, and the loader reports a torn exchange.
        let mut file = self.file.lock().unwrap_or_else(|e| e.into_inner());
        // The reply goes straight from the node's buffer to the file, uncopied.
        file.write_all(&req)
            .and_then(|()| file.write_all(reply))
            .map_err(|source| RecordingError::Io {
                what: "writing",
                path: self.path.clone(),
                source,
            })
    }
}

/// A recording loaded into memory, its exchanges indexed by request.
#[derive(Debug)]
pub struct Recording {
    path: PathBuf,
    bytes: Vec<u8>,
    hello: Range<usize>,
    hello_decoded: Hello,
    /// Canonical request bytes → the reply's range in `bytes`.
    replies: HashMap<Vec<u8>, Range<usize>>,
    exchanges: usize,
}

impl Recording {
    /// Reads and checks `path`: the header, the hello, and every exchange (a request, a frame
    /// message, and stats for the requested frame).
    pub fn load(path: &Path, limits: &DecodeOptions) -> Result<Recording, RecordingError> {
        let bytes = std::fs::read(path).map_err(|source| RecordingError::Io {
            what: "reading",
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(path, bytes, limits)
    }

    /// Checks and indexes a recording's bytes; `path` names it in errors.
    pub fn parse(
        path: &Path,
        bytes: Vec<u8>,
        limits: &DecodeOptions,
    ) -> Result<Recording, RecordingError> {
        let malformed = |offset: usize, what: String| RecordingError::Malformed {
            path: path.to_path_buf(),
            offset,
            what,
        };
        if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
            return Err(RecordingError::NotARecording {
                path: path.to_path_buf(),
            });
        }
        let version_bytes = bytes
            .get(MAGIC.len()..HEADER_LEN)
            .ok_or_else(|| malformed(MAGIC.len(), "the file ends inside the header".into()))?;
        let version = u32::from_le_bytes([
            version_bytes[0],
            version_bytes[1],
            version_bytes[2],
            version_bytes[3],
        ]);
        if version != VERSION {
            return Err(RecordingError::Version {
                path: path.to_path_buf(),
                found: version,
            });
        }
        // The message at `at`: its type and range, or why it is not one.
        let message = |at: usize, expected: &str| -> Result<(MessageType, Range<usize>), _> {
            let rest = &bytes[at..];
            if rest.is_empty() {
                return Err(malformed(
                    at,
                    format!("the file ends where {expected} should start"),
                ));
            }
            let prefix = parse_prefix(rest, limits)
                .map_err(|e| malformed(at, format!("{expected}: {e}")))?;
            let len = usize::try_from(prefix.body_len)
                .ok()
                .and_then(|b| b.checked_add(PREFIX_LEN))
                .filter(|&len| len <= rest.len())
                .ok_or_else(|| {
                    malformed(
                        at,
                        format!(
                            "{expected} of {} bytes, but only {} bytes are left (the file was \
                             cut short, perhaps while the node was writing it)",
                            prefix.body_len.saturating_add(PREFIX_LEN as u64),
                            rest.len()
                        ),
                    )
                })?;
            Ok((prefix.kind, at..at + len))
        };
        let expect = |at: usize, kind: MessageType, expected: &str| {
            let (found, range) = message(at, expected)?;
            if found != kind {
                return Err(malformed(
                    at,
                    format!("expected {expected}, found a {found:?} message"),
                ));
            }
            Ok(range)
        };
        let hello = expect(HEADER_LEN, MessageType::Hello, "the node's hello")?;
        let hello_decoded = Hello::decode(&bytes[hello.clone()], limits)
            .map_err(|e| malformed(hello.start, format!("the node's hello: {e}")))?;
        let mut replies = HashMap::new();
        let mut exchanges = 0;
        let mut at = hello.end;
        while at < bytes.len() {
            let req = expect(at, MessageType::Request, "a request")?;
            let request = Request::decode(&bytes[req.clone()], limits)
                .map_err(|e| malformed(req.start, format!("a request: {e}")))?;
            let frame = expect(req.end, MessageType::Frame, "the reply's frame message")?;
            let stats = expect(frame.end, MessageType::Stats, "the reply's stats")?;
            let decoded = NodeStats::decode(&bytes[stats.clone()], limits)
                .map_err(|e| malformed(stats.start, format!("the reply's stats: {e}")))?;
            let fixup = matches!(request.kind, RequestKind::Fixup(_));
            if decoded.frame_number != request.frame_number || decoded.fixup != fixup {
                return Err(malformed(
                    stats.start,
                    format!(
                        "stats of frame {} (fixup: {}) answer a request for frame {} (fixup: {fixup})",
                        decoded.frame_number, decoded.fixup, request.frame_number
                    ),
                ));
            }
            // Keyed as `reply` looks requests up: decoded and encoded again.
            let mut key = Vec::new();
            request
                .encode_into(&mut key)
                .map_err(|e| malformed(req.start, format!("a request: {e}")))?;
            // The first answer to a request stands (a repeated run answers it identically).
            replies.entry(key).or_insert(frame.start..stats.end);
            exchanges += 1;
            at = stats.end;
        }
        Ok(Recording {
            path: path.to_path_buf(),
            bytes,
            hello,
            hello_decoded,
            replies,
            exchanges,
        })
    }

    /// The file it was loaded from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The recorded node's hello.
    pub fn hello(&self) -> &Hello {
        &self.hello_decoded
    }

    /// Exchanges in the file.
    pub fn exchanges(&self) -> usize {
        self.exchanges
    }

    /// Distinct requests it answers.
    pub fn requests(&self) -> usize {
        self.replies.len()
    }

    /// The recorded reply (frame and stats messages) to `request`, if the recording holds one.
    pub fn reply(&self, request: &Request) -> Option<&[u8]> {
        let mut key = Vec::new();
        request.encode_into(&mut key).ok()?;
        self.replies.get(&key).map(|r| &self.bytes[r.clone()])
    }
}

/// Serves displays from `recording` forever, one connection at a time: the recorded hello,
/// then the recorded reply to each request, straight from memory.
pub async fn serve_recording(
    listener: TcpListener,
    recording: Arc<Recording>,
    limits: DecodeOptions,
    log: impl Fn(NodeEvent) + Send + Sync + 'static,
) -> std::io::Result<()> {
    loop {
        let (stream, peer) = listener.accept().await?;
        let peer = peer.to_string();
        log(NodeEvent::Connected(peer.clone()));
        let result = replay_connection(stream, &recording, &limits).await;
        log(NodeEvent::Closed(peer, result.err()));
    }
}

/// Answers one display from the recording until it disconnects.
pub async fn replay_connection(
    stream: TcpStream,
    recording: &Recording,
    limits: &DecodeOptions,
) -> Result<(), ConnectionError> {
    let _ = stream.set_nodelay(true);
    let (mut reader, mut writer) = stream.into_split();
    let io = |what| move |source| ConnectionError::Io { what, source };
    writer
        .write_all(&recording.bytes[recording.hello.clone()])
        .await
        .map_err(io("sending the hello"))?;
    let result = loop {
        let request = match next_request(&mut reader, limits).await {
            Ok(Some(r)) => r,
            Ok(None) => break Ok(()),
            Err(e) => break Err(e),
        };
        match recording.reply(&request) {
            Some(reply) => {
                if let Err(e) = writer.write_all(reply).await {
                    break Err(ConnectionError::Io {
                        what: "sending a frame",
                        source: e,
                    });
                }
            }
            None => {
                break Err(ConnectionError::NotRecorded(not_recorded(
                    recording, &request,
                )));
            }
        }
    };
    if let Err(e) = &result {
        let mut bytes = Vec::new();
        encode_error_into(&mut bytes, &format!("replaying node: {e}"));
        // The display may be gone already; the connection ends either way.
        let _ = writer.write_all(&bytes).await;
    }
    let _ = writer.shutdown().await;
    result
}

/// Why a request has no recorded answer, for a person.
fn not_recorded(recording: &Recording, r: &Request) -> String {
    let kind = match r.kind {
        RequestKind::Render { reset: true } => "render (reset)",
        RequestKind::Render { reset: false } => "render",
        RequestKind::Fixup(_) => "fixup",
    };
    format!(
        "{} holds no answer to the request for frame {} ({kind}, {:?}, codec {}, {}x{}, node \
         {}); it answers {} request(s); replay with the display options of the recorded run",
        recording.path.display(),
        r.frame_number,
        r.transfer,
        r.codec,
        r.width,
        r.height,
        r.node_id,
        recording.requests(),
    )
}
