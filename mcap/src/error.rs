//! The one error type of this crate. Every variant names the file, and where a
//! message is involved the topic, the message's index on that topic (0-based)
//! and its log time.

use std::fmt;
use std::path::PathBuf;

/// Where in a recording a message is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MessageAt {
    /// Topic.
    pub topic: String,
    /// 0-based index of the message among this reader's messages on the topic.
    pub index: u64,
    /// MCAP log time, ns.
    pub log_time: u64,
}

impl fmt::Display for MessageAt {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "topic `{}` message #{} (log time {} ns)",
            vlsync_common::text::clip(&self.topic),
            self.index,
            self.log_time
        )
    }
}

/// Everything that can go wrong reading or writing a recording.
#[derive(Debug)]
#[non_exhaustive]
pub enum Error {
    /// An I/O error on a file.
    Io {
        /// The file.
        path: PathBuf,
        /// What was being done.
        doing: String,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The MCAP container is malformed, truncated or uses something unsupported.
    Mcap {
        /// The file.
        path: PathBuf,
        /// Where: e.g. `reading the summary`, or after which message of which topic.
        at: String,
        /// The `mcap` crate's error.
        source: mcap::McapError,
    },
    /// The requested topic does not exist, is ambiguous or has the wrong schema.
    Topic {
        /// The file.
        path: PathBuf,
        /// What is wrong, with the topics the file does have.
        reason: String,
    },
    /// One message cannot be used (bad CDR, unknown encoding, bad image, bad scan).
    Message {
        /// The file.
        path: PathBuf,
        /// Topic, index and log time.
        at: MessageAt,
        /// What is wrong.
        reason: String,
    },
    /// A value cannot be written (e.g. a negative time for a log time).
    Write {
        /// The file (or a description of the sink).
        path: PathBuf,
        /// Topic written to.
        topic: String,
        /// What is wrong.
        reason: String,
    },
    /// The file's content is inconsistent (a chunk's records overrun it, its
    /// declared size is not what it holds, ...) or beyond this reader's bounds (a
    /// chunk larger than `ReaderOptions::max_record_bytes`).
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Where in the file (the topic's position and the chunk).
        at: String,
        /// What is wrong.
        reason: String,
    },
}

impl Error {
    /// The message without the leading file name (for wrapping into another
    /// crate's error that names the file itself).
    pub fn detail(&self) -> String {
        match self {
            Error::Io { doing, source, .. } => format!("{doing}: {source}"),
            Error::Mcap { at, source, .. } => {
                let hint = match source {
                    mcap::McapError::UnsupportedCompression(_) => {
                        crate::decompress::UNSUPPORTED_HINT
                    }
                    mcap::McapError::UnexpectedEof => " (the file is truncated)",
                    _ => "",
                };
                format!("MCAP error {at}: {source}{hint}")
            }
            Error::Topic { reason, .. } => reason.clone(),
            Error::Message { at, reason, .. } => format!("{at}: {reason}"),
            Error::Write { topic, reason, .. } => format!("writing topic `{topic}`: {reason}"),
            Error::Corrupt { at, reason, .. } => format!("unusable MCAP {at}: {reason}"),
        }
    }

    /// The file the error is about.
    pub fn path(&self) -> &std::path::Path {
        match self {
            Error::Io { path, .. }
            | Error::Mcap { path, .. }
            | Error::Topic { path, .. }
            | Error::Message { path, .. }
            | Error::Write { path, .. }
            | Error::Corrupt { path, .. } => path,
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path().display(), self.detail())
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Io { source, .. } => Some(source),
            Error::Mcap { source, .. } => Some(source),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_file_topic_index_and_time() {
        let e = Error::Message {
            path: "run.mcap".into(),
            at: MessageAt {
                topic: "/cam".into(),
                index: 7,
                log_time: 42,
            },
            reason: "unsupported encoding `bayer_rggb8`".into(),
        };
        assert_eq!(
            e.to_string(),
            "run.mcap: topic `/cam` message #7 (log time 42 ns): unsupported encoding `bayer_rggb8`"
        );
        let e = Error::Mcap {
            path: "x.mcap".into(),
            at: "reading the summary".into(),
            source: mcap::McapError::UnsupportedCompression("brotli".into()),
        };
        assert!(e
            .to_string()
            .starts_with("x.mcap: MCAP error reading the summary"));
        assert!(e.to_string().contains("brotli"), "{e}");
    }
}
