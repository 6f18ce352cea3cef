//! Reading the messages of one topic from an MCAP file, in file order.
//!
//! [`McapReader::open`] reads the file's summary. When the file is indexed
//! (chunk indexes in the summary, as `ros2 bag record` writes), messages come
//! through the `mcap` crate's indexed reader, only the chunks holding the topic are
//! read, and each chunk's CRC is checked before its messages are used. When the
//! summary is missing (a recording that was cut off) or has no chunk indexes, the
//! file is read linearly (chunk CRCs checked too); [`McapReader::is_indexed`] tells
//! which. Either way messages come in **file order**, the order a recorder wrote
//! them in (`ros2 bag record` writes them as they arrive), and
//! [`McapReader::out_of_order`] counts those whose log time went backwards. Not in
//! log-time order: to sort, the indexed reader holds every chunk whose declared
//! time range has begun, and a few hundred bytes of indexes declaring overlapping
//! ranges (or messages outside them) made it hold forty 250 MiB chunks at once; in
//! file order it holds one. A truncated file then yields its messages up to the cut and
//! then an error saying so.
//!
//! Topic selection: by name ([`Select::Topic`]; its schema must be one the
//! caller accepts), or by schema ([`Select::Schema`]): the single topic whose
//! schema is one of the given names; none or several is an error listing the
//! topics of the file. Messages must be `cdr`-encoded.
//!
//! A recording is hostile input: record lengths are bounded by the file size and
//! [`ReaderOptions::max_record_bytes`], a chunk must hold exactly the size it
//! declares before any buffer is sized by it, the records inside a chunk are
//! bounded by the chunk (the linear walk is this crate's own, `linear.rs`), the
//! lengths inside a record by the record before the `mcap` crate parses it
//! (`lengths.rs`; the summary section's records are checked so before its summary
//! reader sees them), and every error names the file and, past the start, the
//! topic, message index and log time, and the chunk.
//!
//! Chunk compression: see [`crate::decompress`]; an unsupported compression is
//! an error naming it.

use crate::decompress;
use crate::error::Error;
use crate::linear::{split_record, Fault, LinearWalk, Place, HEAD};
use mcap::records::op;
use mcap::sans_io::indexed_reader::{
    IndexedReadEvent, IndexedReader, IndexedReaderOptions, ReadOrder,
};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use mcap::{McapError, Summary};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Which topic to read.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum Select {
    /// This topic; its schema must be one of the accepted ones.
    Topic(String),
    /// The one topic whose schema is one of the accepted ones (default).
    #[default]
    Schema,
}

/// Reader limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReaderOptions {
    /// Largest record (and decompressed chunk) accepted, bytes. Default 256 MiB:
    /// recorders write chunks of a few MiB (a chunk holds at least one message, and a
    /// raw 8K frame is about 100 MB), and a few KB of compressed chunk can declare
    /// any size, which a robot's computer should not have to hold.
    pub max_record_bytes: usize,
}

impl Default for ReaderOptions {
    fn default() -> Self {
        Self {
            max_record_bytes: 256 << 20,
        }
    }
}

/// One channel of a recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicInfo {
    /// Topic name.
    pub topic: String,
    /// Schema name, e.g. `sensor_msgs/msg/Image` (empty without a schema).
    pub schema_name: String,
    /// Message encoding, `cdr` for ROS 2.
    pub message_encoding: String,
    /// Messages on the channel, when the file's statistics say.
    pub message_count: Option<u64>,
}

/// One message of the selected topic, borrowed from the reader's buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageRef<'a> {
    /// 0-based index among this reader's messages.
    pub index: u64,
    /// MCAP log time (the recorder's receive time), ns.
    pub log_time: u64,
    /// MCAP publish time, ns.
    pub publish_time: u64,
    /// Publisher sequence number (0 when unknown).
    pub sequence: u32,
    /// The serialized message (CDR with its encapsulation header).
    pub data: &'a [u8],
}

enum Mode {
    Indexed {
        reader: Box<IndexedReader>,
        /// compressed-data offset -> (chunk start, compression, declared uncompressed size)
        chunks: BTreeMap<u64, (u64, String, u64)>,
        limit: usize,
        /// a chunk the reader refused, whose messages before the fault are yielded
        salvage: Option<Box<Salvage>>,
    },
    Linear {
        walk: Box<LinearWalk>,
    },
}

/// A chunk the indexed reader refused after this crate's checks of it passed: a
/// record in it overruns it, or a message is too short for its header. The reader
/// indexes a whole chunk before it yields any of its messages, so it would lose
/// those before the fault; they are yielded from here as the linear walk yields
/// them, then the fault. The fault ends the read even when it is a short message of
/// another topic, which a read from the start steps over: the indexed reader cannot
/// be moved past a chunk it refused, so this topic's messages in later chunks are
/// not reached (the error names the chunk and the record).
struct Salvage {
    /// the chunk's records
    records: Vec<u8>,
    /// the next record in `records`
    pos: usize,
    /// the chunk record's start in the file
    start: u64,
    /// the reader's refusal, said when the walk here finds no fault of its own
    refused: Option<McapError>,
    /// a message too short for its header on another channel, which the walk here
    /// steps over and the reader refuses: what is wrong, and where
    short: Option<String>,
}

/// Messages of one topic of an MCAP file (see the module docs).
pub struct McapReader {
    path: PathBuf,
    file: File,
    file_len: u64,
    topic: TopicInfo,
    channel_ids: Vec<u16>,
    mode: Mode,
    chunk_buf: Vec<u8>,
    msg_buf: Vec<u8>,
    next_index: u64,
    last_log_time: Option<u64>,
    out_of_order: u64,
    done: bool,
}

impl std::fmt::Debug for McapReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapReader")
            .field("path", &self.path)
            .field("topic", &self.topic)
            .field("indexed", &self.is_indexed())
            .field("next_index", &self.next_index)
            .finish_non_exhaustive()
    }
}

fn io_err(path: &Path, doing: &str, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        doing: doing.to_string(),
        source,
    }
}

fn mcap_err(path: &Path, at: impl Into<String>, source: McapError) -> Error {
    Error::Mcap {
        path: path.to_path_buf(),
        at: at.into(),
        source,
    }
}

/// Opens a recording: a regular file only (a named pipe would block the open, and
/// the reader seeks).
fn open_file(path: &Path) -> Result<File, Error> {
    let f = vlsync_common::file::open_regular(path).map_err(|e| io_err(path, "opening", e))?;
    // said as it is: a 0-byte file read as a recording would be "truncated"
    if f.metadata().is_ok_and(|m| m.len() == 0) {
        return Err(io_err(
            path,
            "reading",
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                "the file is empty (0 bytes), not an MCAP recording",
            ),
        ));
    }
    Ok(f)
}

/// `e` with "the file ends at byte N before its footer: truncated?" added to a topic
/// error when the file does not end with the MCAP magic (the last bytes of a
/// complete recording).
fn with_truncation(e: Error, file: &mut File, file_len: u64) -> Error {
    let mut tail = [0u8; 8];
    let complete = file_len >= 16
        && file.seek(SeekFrom::Start(file_len - 8)).is_ok()
        && file.read_exact(&mut tail).is_ok()
        && tail[..] == *mcap::MAGIC;
    match e {
        Error::Topic { path, reason } if !complete => Error::Topic {
            path,
            reason: format!(
                "{reason}; the file ends at byte {file_len} before its footer: truncated?"
            ),
        },
        e => e,
    }
}

/// A footer record and the magic after it: opcode, length, summary start, summary
/// offset start, summary CRC, magic.
const FOOTER_AND_MAGIC: u64 = 1 + 8 + 8 + 8 + 4 + 8;

/// Checks the records of the summary section before the `mcap` crate's summary
/// reader parses them, which it does with no checks of its own: a string length of
/// 4 GiB in a Channel or Schema record makes its parser reserve 4 GiB (which aborts
/// the process on a computer without that memory), an attachment cut after its
/// data length makes it slice backwards, and a chunk in the summary whose records
/// overrun it underflows a counter of its linear reader (a panic wherever overflow
/// is checked). So the section must be whole records ending at the footer, none of
/// them a chunk or a footer (a summary holds neither), each within `limit`, and
/// the length prefixes inside them within their record ([`crate::lengths`]).
/// `Ok` when there is no summary or no footer: the summary reader finds that.
fn check_summary(file: &mut File, file_len: u64, limit: usize) -> Result<(), String> {
    let Some(footer_at) = file_len.checked_sub(FOOTER_AND_MAGIC).filter(|&at| at >= 8) else {
        return Ok(());
    };
    let mut footer = [0u8; FOOTER_AND_MAGIC as usize];
    file.seek(SeekFrom::Start(footer_at))
        .and_then(|_| file.read_exact(&mut footer))
        .map_err(|e| format!("reading the footer: {e}"))?;
    let mut start = [0u8; 8];
    start.copy_from_slice(&footer[9..17]);
    let summary_start = u64::from_le_bytes(start);
    if footer[0] != op::FOOTER || summary_start == 0 {
        return Ok(());
    }
    if summary_start < 8 || summary_start > footer_at {
        return Err(format!(
            "the footer's summary start, byte {summary_start}, is not between the magic and \
             the footer at byte {footer_at}"
        ));
    }
    let mut r = std::io::BufReader::new(&mut *file);
    r.seek(SeekFrom::Start(summary_start))
        .map_err(|e| format!("reading the summary: {e}"))?;
    let mut pos = summary_start;
    let mut body = Vec::new();
    while pos < footer_at {
        let left = footer_at - pos;
        let mut head = [0u8; 9];
        if left < head.len() as u64 {
            return Err(format!(
                "the record at byte {pos} of the summary is cut by the footer at byte {footer_at}"
            ));
        }
        r.read_exact(&mut head)
            .map_err(|e| format!("reading the summary: {e}"))?;
        let opcode = head[0];
        let mut n = [0u8; 8];
        n.copy_from_slice(&head[1..]);
        let len = u64::from_le_bytes(n);
        let room = left - head.len() as u64;
        let what = format!("the record at byte {pos} of the summary (opcode {opcode:#04x})");
        if len > room {
            return Err(format!(
                "{what} claims {len} bytes, {room} are left before the footer at byte {footer_at}"
            ));
        }
        if opcode == op::CHUNK || opcode == op::FOOTER {
            return Err(format!(
                "{what} is a chunk or a footer, which a summary does not hold"
            ));
        }
        if len > limit as u64 {
            return Err(format!(
                "{what} claims {len} bytes, over the limit of {limit}"
            ));
        }
        if crate::lengths::has_prefixes(opcode) {
            // len <= limit: fits in usize
            body.resize(len as usize, 0);
            r.read_exact(&mut body)
                .map_err(|e| format!("reading the summary: {e}"))?;
            crate::lengths::check(opcode, &body).map_err(|reason| format!("{what} {reason}"))?;
        } else {
            r.seek_relative(len as i64)
                .map_err(|e| format!("reading the summary: {e}"))?;
        }
        pos += head.len() as u64 + len;
    }
    Ok(())
}

/// Reads the summary section; `Ok(None)` when the file has none. An error (a
/// summary [`check_summary`] refuses, or one the `mcap` crate does) makes the
/// callers read the file from its start instead.
fn read_summary(
    file: &mut File,
    file_len: u64,
    opts: ReaderOptions,
) -> Result<Option<Summary>, String> {
    check_summary(file, file_len, opts.max_record_bytes)?;
    read_checked_summary(file, file_len, opts).map_err(|e| e.to_string())
}

/// The summary through the `mcap` crate's reader, once [`check_summary`] passed.
fn read_checked_summary(
    file: &mut File,
    file_len: u64,
    opts: ReaderOptions,
) -> Result<Option<Summary>, McapError> {
    let mut reader = SummaryReader::new_with_options(
        SummaryReaderOptions::default()
            .with_file_size(file_len)
            .with_record_length_limit(opts.max_record_bytes),
    );
    while let Some(event) = reader.next_event() {
        match event? {
            SummaryReadEvent::ReadRequest(need) => {
                let n = file.read(reader.insert(need))?;
                reader.notify_read(n);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let pos = file.seek(to)?;
                reader.notify_seeked(pos);
            }
        }
    }
    Ok(reader.finish())
}

/// A fault of the linear walk as this crate's error, `at` completed with the
/// walk's place in the file.
fn fault_err(path: &Path, at: String, walk: &LinearWalk, fault: Fault) -> Error {
    let at = match walk.place() {
        Place::InChunk(n) => format!("{at}, in chunk #{n} (file order)"),
        Place::AfterChunk(0) => at,
        Place::AfterChunk(n) => format!("{at}, after chunk #{n} (file order)"),
    };
    chunk_err(path, at, fault)
}

/// A fault (of the linear walk, or of a chunk's checks through the index) as this
/// crate's error at `at`.
fn chunk_err(path: &Path, at: String, fault: Fault) -> Error {
    match fault {
        Fault::Mcap(source) => mcap_err(path, at, source),
        Fault::Unsupported(c) => mcap_err(path, at, McapError::UnsupportedCompression(c)),
        Fault::Corrupt(reason) => Error::Corrupt {
            path: path.to_path_buf(),
            at,
            reason,
        },
        Fault::Io(e) => io_err(path, "reading", e),
    }
}

/// Channels found by reading the file from the start (for files without a
/// summary), and the first Schema or Channel record that does not parse, said with
/// its place. A fault of the walk (a cut, a bad chunk) ends the scan quietly: the
/// main pass reports it after the messages before it. A record that does not parse
/// is stepped over, so that the channels after it are seen; the caller reports it
/// when the topic is not found (it may have been the topic's channel), since
/// refusing the file for it would lose the messages of a topic that is there.
fn scan_channels(
    file: &mut File,
    file_len: u64,
    opts: ReaderOptions,
) -> (Vec<(u16, TopicInfo)>, Option<String>) {
    use mcap::records::Record;
    let mut out: Vec<(u16, TopicInfo)> = Vec::new();
    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    let mut unreadable = None;
    let mut walk = LinearWalk::new(opts.max_record_bytes);
    while let Ok(Some((opcode, data))) = walk.next(file, file_len) {
        if opcode != op::SCHEMA && opcode != op::CHANNEL {
            continue;
        }
        // the lengths inside are checked first: the `mcap` crate's parser reserves
        // what a string's length says, 4 GiB for a 12-byte record
        match crate::lengths::parse_record(opcode, data) {
            Ok(Record::Schema { header, .. }) => {
                schemas.insert(header.id, header.name);
            }
            Ok(Record::Channel(c)) => {
                if !out.iter().any(|(id, _)| *id == c.id) {
                    out.push((
                        c.id,
                        TopicInfo {
                            topic: c.topic,
                            schema_name: schemas.get(&c.schema_id).cloned().unwrap_or_default(),
                            message_encoding: c.message_encoding,
                            message_count: None,
                        },
                    ));
                }
            }
            Ok(_) => {}
            Err(reason) => {
                if unreadable.is_none() {
                    let kind = if opcode == op::SCHEMA {
                        "schema"
                    } else {
                        "channel"
                    };
                    unreadable = Some(format!("the {kind} record {} {reason}", walk.record_at()));
                }
            }
        }
    }
    (out, unreadable)
}

/// The error for a file read from its start whose topic was not found (`e`) when a
/// Schema or Channel record of it does not parse (`unreadable`, from
/// [`scan_channels`]): that record, which may be the topic's.
fn unreadable_err(path: &Path, unreadable: String, e: &Error) -> Error {
    Error::Corrupt {
        path: path.to_path_buf(),
        at: "reading the channels from the start of the file".into(),
        reason: format!("{unreadable}; without it: {}", e.detail()),
    }
}

fn summary_channels(s: &Summary) -> Vec<(u16, TopicInfo)> {
    let counts = s.stats.as_ref().map(|st| &st.channel_message_counts);
    let mut out: Vec<_> = s
        .channels
        .values()
        .map(|c| {
            (
                c.id,
                TopicInfo {
                    topic: c.topic.clone(),
                    schema_name: c
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    message_encoding: c.message_encoding.clone(),
                    message_count: counts.and_then(|m| m.get(&c.id).copied()),
                },
            )
        })
        .collect();
    out.sort_by_key(|(id, _)| *id);
    out
}

/// Most topics an error lists (a hostile file may declare thousands).
const MAX_LISTED: usize = 20;

fn list(channels: &[(u16, TopicInfo)]) -> String {
    use vlsync_common::text::clip;
    if channels.is_empty() {
        return "the file has no channels".into();
    }
    let items: Vec<String> = channels
        .iter()
        .take(MAX_LISTED)
        .map(|(_, t)| format!("`{}` ({})", clip(&t.topic), clip(&t.schema_name)))
        .collect();
    let more = match channels.len().saturating_sub(MAX_LISTED) {
        0 => String::new(),
        n => format!(" and {n} more"),
    };
    format!("the file has {}{more}", items.join(", "))
}

/// Picks the channels of the selected topic.
fn resolve(
    path: &Path,
    channels: &[(u16, TopicInfo)],
    select: &Select,
    schemas: &[&str],
) -> Result<(TopicInfo, Vec<u16>), Error> {
    let topic_err = |reason: String| Error::Topic {
        path: path.to_path_buf(),
        reason,
    };
    let name = match select {
        Select::Topic(t) => t.clone(),
        Select::Schema => {
            let mut names: Vec<&str> = channels
                .iter()
                .filter(|(_, t)| schemas.contains(&t.schema_name.as_str()))
                .map(|(_, t)| t.topic.as_str())
                .collect();
            names.sort_unstable();
            names.dedup();
            match names.as_slice() {
                [one] => one.to_string(),
                [] => {
                    return Err(topic_err(format!(
                        "no topic with schema {}; {}",
                        schemas.join(" or "),
                        list(channels)
                    )))
                }
                many => {
                    let shown: Vec<String> = many
                        .iter()
                        .take(MAX_LISTED)
                        .map(|n| vlsync_common::text::clip(n))
                        .collect();
                    let more = many.len().saturating_sub(MAX_LISTED);
                    return Err(topic_err(format!(
                        "several topics with schema {}: {}{}; name one",
                        schemas.join(" or "),
                        shown.join(", "),
                        if more > 0 {
                            format!(" and {more} more")
                        } else {
                            String::new()
                        }
                    )));
                }
            }
        }
    };
    let mine: Vec<&(u16, TopicInfo)> = channels.iter().filter(|(_, t)| t.topic == name).collect();
    let Some((_, first)) = mine.first() else {
        return Err(topic_err(format!(
            "no topic `{}`; {}",
            vlsync_common::text::clip(&name),
            list(channels)
        )));
    };
    for (_, t) in &mine {
        if !schemas.contains(&t.schema_name.as_str()) {
            return Err(topic_err(format!(
                "topic `{}` has schema `{}`, expected {}",
                vlsync_common::text::clip(&name),
                vlsync_common::text::clip(&t.schema_name),
                schemas.join(" or ")
            )));
        }
        if t.message_encoding != "cdr" {
            return Err(topic_err(format!(
                "topic `{}` has message encoding `{}`, expected `cdr`",
                vlsync_common::text::clip(&name),
                vlsync_common::text::clip(&t.message_encoding)
            )));
        }
        // one message type per topic: the messages are decoded as the first
        // channel's type (a merged file with `Image` and `CompressedImage` on one
        // topic would fail message by message)
        if t.schema_name != first.schema_name {
            return Err(topic_err(format!(
                "topic `{}` has channels of two schemas, `{}` and `{}`: name one topic of one type",
                vlsync_common::text::clip(&name),
                vlsync_common::text::clip(&first.schema_name),
                vlsync_common::text::clip(&t.schema_name)
            )));
        }
    }
    let mut info = (*first).clone();
    info.message_count = mine
        .iter()
        .map(|(_, t)| t.message_count)
        .try_fold(0u64, |a, c| c.map(|c| a.saturating_add(c)));
    Ok((info, mine.iter().map(|(id, _)| *id).collect()))
}

impl McapReader {
    /// The channels of a recording (from its summary, or by reading it when it has none).
    pub fn topics(path: impl AsRef<Path>) -> Result<Vec<TopicInfo>, Error> {
        let path = path.as_ref();
        let mut file = open_file(path)?;
        let len = file
            .metadata()
            .map_err(|e| io_err(path, "reading metadata", e))?
            .len();
        let opts = ReaderOptions::default();
        let ch = match read_summary(&mut file, len, opts) {
            Ok(Some(s)) => summary_channels(&s),
            _ => {
                let (ch, unreadable) = scan_channels(&mut file, len, opts);
                if let Some(reason) = unreadable {
                    // a listing without that record's channel would pass it over
                    // in silence
                    return Err(Error::Corrupt {
                        path: path.to_path_buf(),
                        at: "reading the channels from the start of the file".into(),
                        reason,
                    });
                }
                if ch.is_empty() {
                    // no channel at all: a fault of the file (a bad CRC, a cut) is
                    // said, as `open` says it, rather than an empty list
                    let mut walk = LinearWalk::new(opts.max_record_bytes);
                    loop {
                        match walk.next(&mut file, len) {
                            Ok(Some(_)) => {}
                            Ok(None) => break,
                            Err(f) => {
                                let at = "reading the file from the start".to_string();
                                return Err(fault_err(path, at, &walk, f));
                            }
                        }
                    }
                }
                ch
            }
        };
        Ok(ch.into_iter().map(|(_, t)| t).collect())
    }

    /// Opens `path` and selects a topic whose schema is one of `schemas`.
    pub fn open(
        path: impl AsRef<Path>,
        select: &Select,
        schemas: &[&str],
        opts: ReaderOptions,
    ) -> Result<Self, Error> {
        let path = path.as_ref().to_path_buf();
        let mut file = open_file(&path)?;
        let file_len = file
            .metadata()
            .map_err(|e| io_err(&path, "reading metadata", e))?
            .len();
        // a file without a valid summary is read linearly; a broken start shows up there
        let summary = read_summary(&mut file, file_len, opts).ok().flatten();
        let (channels, unreadable) = match &summary {
            Some(s) => (summary_channels(s), None),
            None => scan_channels(&mut file, file_len, opts),
        };
        let (topic, channel_ids) = match resolve(&path, &channels, select, schemas) {
            Ok(t) => t,
            // the topic may be that of a channel record that does not parse
            Err(e) if unreadable.is_some() => {
                let unreadable = unreadable.unwrap_or_default();
                return Err(unreadable_err(&path, unreadable, &e));
            }
            Err(e) if channels.is_empty() && summary.is_none() => {
                // nothing readable at all: report why, from the start of the file
                let mut walk = LinearWalk::new(opts.max_record_bytes);
                loop {
                    match walk.next(&mut file, file_len) {
                        Ok(Some(_)) => {}
                        Err(f) => {
                            let at = "reading the file from the start".to_string();
                            return Err(fault_err(&path, at, &walk, f));
                        }
                        Ok(None) => return Err(with_truncation(e, &mut file, file_len)),
                    }
                }
            }
            // without a summary the channels come from reading the file: a cut
            // one may lack those recorded after the cut
            Err(e) if summary.is_none() => return Err(with_truncation(e, &mut file, file_len)),
            Err(e) => return Err(e),
        };
        let mode = match summary {
            Some(mut s) if !s.chunk_indexes.is_empty() => {
                let options = IndexedReaderOptions::new()
                    .include_topics([topic.topic.clone()])
                    // one chunk held at a time (the module's doc)
                    .with_order(ReadOrder::File)
                    .with_record_length_limit(opts.max_record_bytes);
                // the checks before a chunk is handed to the reader use these entries: two
                // indexes of one chunk that disagree would let one pass the check and the
                // other size the reader's buffer
                let mut chunks: BTreeMap<u64, (u64, String, u64)> = BTreeMap::new();
                // the indexes the reader gets: one per chunk (see below)
                let mut kept = Vec::with_capacity(s.chunk_indexes.len());
                for c in std::mem::take(&mut s.chunk_indexes) {
                    // before the reader is built: its own refusal names neither the
                    // chunk nor the size declared. Only the chunks it would read: those
                    // holding the topic (or not saying which they hold), as it filters
                    // them; a large chunk of another topic (a point cloud) is no matter
                    let ours = c.message_index_offsets.is_empty()
                        || channel_ids
                            .iter()
                            .any(|id| c.message_index_offsets.contains_key(id));
                    let limit = opts.max_record_bytes as u64;
                    if ours && (c.uncompressed_size > limit || c.compressed_size > limit) {
                        return Err(Error::Corrupt {
                            path,
                            at: "in the summary's chunk indexes".into(),
                            reason: format!(
                                "the chunk at byte {} declares {} bytes compressed, {} \
                                 uncompressed, over the limit of {limit} a record may have \
                                 here (a bound of this reader, not of the format: a \
                                 recording written with smaller chunks reads)",
                                c.chunk_start_offset, c.compressed_size, c.uncompressed_size
                            ),
                        });
                    }
                    let Ok(off) = c.compressed_data_offset() else {
                        // the reader refuses it if it holds the topic
                        kept.push(c);
                        continue;
                    };
                    let entry = (
                        c.chunk_start_offset,
                        c.compression.clone(),
                        c.uncompressed_size,
                    );
                    match chunks.get(&off) {
                        Some(seen) if *seen != entry => {
                            return Err(Error::Corrupt {
                                path,
                                at: "in the summary's chunk indexes".into(),
                                reason: format!(
                                    "two indexes of the chunk at byte {} disagree \
                                     (uncompressed size {} and {}, compression `{}` and `{}`)",
                                    c.chunk_start_offset,
                                    seen.2,
                                    entry.2,
                                    vlsync_common::text::clip(&seen.1),
                                    vlsync_common::text::clip(&entry.1)
                                ),
                            })
                        }
                        // the same chunk indexed twice alike: the reader would read it,
                        // and yield its messages, once per index
                        Some(_) => {}
                        None => {
                            chunks.insert(off, entry);
                            kept.push(c);
                        }
                    }
                }
                s.chunk_indexes = kept;
                let mut reader = IndexedReader::new_with_options(&s, options)
                    .map_err(|e| mcap_err(&path, "indexing the chunks", e))?;
                decompress::register_indexed(&mut reader, opts.max_record_bytes)
                    .map_err(|e| mcap_err(&path, "opening", e))?;
                Mode::Indexed {
                    reader: Box::new(reader),
                    chunks,
                    limit: opts.max_record_bytes,
                    salvage: None,
                }
            }
            _ => Mode::Linear {
                walk: Box::new(LinearWalk::new(opts.max_record_bytes)),
            },
        };
        Ok(Self {
            path,
            file,
            file_len,
            topic,
            channel_ids,
            mode,
            chunk_buf: Vec::new(),
            msg_buf: Vec::new(),
            next_index: 0,
            last_log_time: None,
            out_of_order: 0,
            done: false,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The selected topic.
    pub fn topic(&self) -> &TopicInfo {
        &self.topic
    }

    /// True when messages come through the file's index; false when the file is read
    /// linearly. File order both ways.
    pub fn is_indexed(&self) -> bool {
        matches!(self.mode, Mode::Indexed { .. })
    }

    /// Messages yielded so far.
    pub fn messages_read(&self) -> u64 {
        self.next_index
    }

    /// Messages (so far) whose log time is earlier than the previous one's (they are
    /// yielded in file order all the same).
    pub fn out_of_order(&self) -> u64 {
        self.out_of_order
    }

    /// The next message of the topic, `Ok(None)` at the end. After an error the
    /// reader yields `Ok(None)`.
    pub fn next_message(&mut self) -> Result<Option<MessageRef<'_>>, Error> {
        if self.done {
            return Ok(None);
        }
        match self.advance() {
            Ok(Some((log_time, publish_time, sequence))) => {
                if self.last_log_time.is_some_and(|t| log_time < t) {
                    self.out_of_order += 1;
                }
                self.last_log_time = Some(log_time);
                let index = self.next_index;
                self.next_index += 1;
                Ok(Some(MessageRef {
                    index,
                    log_time,
                    publish_time,
                    sequence,
                    data: &self.msg_buf,
                }))
            }
            Ok(None) => {
                self.done = true;
                Ok(None)
            }
            Err(e) => {
                self.done = true;
                Err(e)
            }
        }
    }

    /// Loads the next message of the topic into `msg_buf`.
    fn advance(&mut self) -> Result<Option<(u64, u64, u32)>, Error> {
        let Self {
            path,
            file,
            file_len,
            channel_ids,
            mode,
            chunk_buf,
            msg_buf,
            ..
        } = self;
        match mode {
            Mode::Indexed {
                reader,
                chunks,
                limit,
                salvage,
            } => loop {
                if let Some(sv) = salvage {
                    let at = self_position(&self.topic, self.next_index, self.last_log_time);
                    return salvage_next(sv, path, at, channel_ids, msg_buf);
                }
                let event = match reader.next_event() {
                    None => return Ok(None),
                    Some(Ok(e)) => e,
                    Some(Err(e)) => {
                        return Err(mcap_err(
                            path,
                            self_position(&self.topic, self.next_index, self.last_log_time),
                            e,
                        ))
                    }
                };
                match event {
                    IndexedReadEvent::ReadChunkRequest { offset, length } => {
                        let at = self_position(&self.topic, self.next_index, self.last_log_time);
                        // every index the reader has is in `chunks` by this offset
                        // (`open`): errors name the chunk record's start, not its data's
                        let Some((start, compression, size)) = chunks.get(&offset) else {
                            return Err(Error::Corrupt {
                                path: path.clone(),
                                at,
                                reason: format!(
                                    "the index asked for chunk data at byte {offset}, which no \
                                     chunk index names"
                                ),
                            });
                        };
                        let start = *start;
                        read_chunk(file, *file_len, offset, length, chunk_buf).map_err(|e| {
                            mcap_err(path, format!("{at}, reading the chunk at byte {start}"), e)
                        })?;
                        // the reader sizes its buffer by the declared size and checks no
                        // CRC: both are checked here first
                        let at = format!("{at}, chunk at byte {start}");
                        let crc = decompress::check_size(compression, chunk_buf, *size, *limit)
                            .map_err(|f| chunk_err(path, at.clone(), f.into()))?;
                        check_chunk_crc(file, start, crc)
                            .map_err(|e| mcap_err(path, at.clone(), e))?;
                        if let Err(refused) = reader.insert_chunk_record_data(offset, chunk_buf) {
                            let mut records = Vec::new();
                            decompress::decode_chunk(
                                compression,
                                chunk_buf,
                                *size,
                                *limit,
                                &mut records,
                            )
                            .map_err(|f| chunk_err(path, at.clone(), f.into()))?;
                            *salvage = Some(Box::new(Salvage {
                                records,
                                pos: 0,
                                start,
                                refused: Some(refused),
                                short: None,
                            }));
                        }
                    }
                    IndexedReadEvent::Message { header, data } => {
                        if channel_ids.contains(&header.channel_id) {
                            msg_buf.clear();
                            msg_buf.extend_from_slice(data);
                            return Ok(Some((
                                header.log_time,
                                header.publish_time,
                                header.sequence,
                            )));
                        }
                    }
                }
            },
            Mode::Linear { walk } => loop {
                let at = || self_position(&self.topic, self.next_index, self.last_log_time);
                let (opcode, data) = match walk.next(file, *file_len) {
                    Ok(Some(r)) => r,
                    Ok(None) => return Ok(None),
                    Err(f) => return Err(fault_err(path, at(), walk, f)),
                };
                match linear_record(opcode, data, &self.topic, channel_ids, msg_buf) {
                    Ok(Some(found)) => return Ok(Some(found)),
                    Ok(None) => {}
                    Err(reason) => {
                        let f = Fault::Corrupt(format!(
                            "the message record {} {reason}",
                            walk.record_at()
                        ));
                        return Err(fault_err(path, at(), walk, f));
                    }
                }
            },
        }
    }
}

/// One record read linearly (outside a chunk or inside one): a channel of the
/// topic is added to `channel_ids`; a message on one of them is copied to
/// `msg_buf` and its times returned. The error is what is wrong with a message.
fn linear_record(
    opcode: u8,
    data: &[u8],
    topic: &TopicInfo,
    channel_ids: &mut Vec<u16>,
    msg_buf: &mut Vec<u8>,
) -> Result<Option<(u64, u64, u32)>, String> {
    match opcode {
        op::CHANNEL => {
            // one that does not parse is passed over: `scan_channels` reported it at
            // `open` if the topic was not found without it (its lengths are checked
            // first: the `mcap` crate's parser reserves what a string's length says)
            if let Ok(mcap::records::Record::Channel(c)) =
                crate::lengths::parse_record(opcode, data)
            {
                if c.topic == topic.topic && !channel_ids.contains(&c.id) {
                    channel_ids.push(c.id);
                }
            }
        }
        op::MESSAGE => return message_of(data, channel_ids, msg_buf),
        _ => {}
    }
    Ok(None)
}

/// A message record (`body`): copied to `msg_buf`, its times returned, when it is
/// on one of `channel_ids`. Its channel is read first: a malformed message of
/// another topic is not this reader's to refuse (it ended the read of the topic).
fn message_of(
    body: &[u8],
    channel_ids: &[u16],
    msg_buf: &mut Vec<u8>,
) -> Result<Option<(u64, u64, u32)>, String> {
    let Some(channel) = crate::lengths::message_channel(body) else {
        return Err(format!(
            "is {} bytes, too short to say its channel",
            body.len()
        ));
    };
    if !channel_ids.contains(&channel) {
        return Ok(None);
    }
    let (header, data) = crate::lengths::parse_message(body)?;
    msg_buf.clear();
    msg_buf.extend_from_slice(data);
    Ok(Some((
        header.log_time,
        header.publish_time,
        header.sequence,
    )))
}

/// The next message of the topic from a chunk the indexed reader refused (see
/// [`Salvage`]), or the fault that ends it: the walk's own, the short message of
/// another channel it stepped over, or else the reader's refusal.
fn salvage_next(
    sv: &mut Salvage,
    path: &Path,
    at: String,
    channel_ids: &[u16],
    msg_buf: &mut Vec<u8>,
) -> Result<Option<(u64, u64, u32)>, Error> {
    let at = format!("{at}, chunk at byte {}", sv.start);
    let corrupt = |reason: String| Error::Corrupt {
        path: path.to_path_buf(),
        at: at.clone(),
        reason,
    };
    while let Some(rest) = sv.records.get(sv.pos..).filter(|r| !r.is_empty()) {
        let here = sv.pos;
        let (opcode, body) = split_record(rest).map_err(|reason| {
            corrupt(format!(
                "the record at byte {here} of the chunk's records {reason}"
            ))
        })?;
        sv.pos += HEAD + body.len();
        if opcode != op::MESSAGE {
            continue;
        }
        let described =
            |reason| format!("the message record at byte {here} of the chunk's records {reason}");
        match message_of(body, channel_ids, msg_buf) {
            Ok(Some(found)) => return Ok(Some(found)),
            Err(reason) => return Err(corrupt(described(reason))),
            Ok(None) => {
                if sv.short.is_none() {
                    if let Err(reason) = crate::lengths::parse_message(body) {
                        sv.short = Some(described(reason));
                    }
                }
            }
        }
    }
    if let Some(reason) = sv.short.take() {
        return Err(corrupt(format!(
            "{reason} (read through the index, such a chunk is refused after its \
             messages of the topic)"
        )));
    }
    match sv.refused.take() {
        Some(e) => Err(mcap_err(path, at, e)),
        None => Ok(None),
    }
}

fn self_position(topic: &TopicInfo, next_index: u64, last: Option<u64>) -> String {
    let name = vlsync_common::text::clip(&topic.topic);
    match (next_index, last) {
        (0, _) | (_, None) => format!("before the first message of topic `{name}`"),
        (n, Some(t)) => format!(
            "after message #{} of topic `{name}` (log time {t} ns)",
            n - 1
        ),
    }
}

/// Reads `length` bytes at `offset` into `buf`, checking the range against the file first.
fn read_chunk(
    file: &mut File,
    file_len: u64,
    offset: u64,
    length: usize,
    buf: &mut Vec<u8>,
) -> Result<(), McapError> {
    let end = offset.checked_add(length as u64);
    if end.is_none_or(|e| e > file_len) {
        return Err(McapError::BadChunkLength {
            header: length as u64,
            available: file_len.saturating_sub(offset),
        });
    }
    file.seek(SeekFrom::Start(offset))?;
    buf.resize(length, 0);
    file.read_exact(buf)?;
    Ok(())
}

/// Checks a chunk's records (their CRC-32, `calculated`) against the CRC in its
/// record header, which the indexed reader does not see. A CRC of 0 means "not
/// computed".
fn check_chunk_crc(file: &mut File, chunk_start: u64, calculated: u32) -> Result<(), McapError> {
    // opcode, record length, start time, end time, uncompressed size, CRC
    let mut head = [0u8; 1 + 8 + 8 + 8 + 8 + 4];
    file.seek(SeekFrom::Start(chunk_start))?;
    file.read_exact(&mut head)?;
    if head[0] != op::CHUNK {
        return Err(McapError::BadIndex);
    }
    let saved = u32::from_le_bytes([head[33], head[34], head[35], head[36]]);
    if saved != 0 && calculated != saved {
        return Err(McapError::BadChunkCrc { saved, calculated });
    }
    Ok(())
}
