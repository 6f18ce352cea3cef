//! Hand-built recordings with one hostile record each: lengths inside records
//! that claim gigabytes, a chunk in the summary, chunk indexes given twice, a
//! chunk with a fault after good messages, a channel record that does not parse.

use std::path::{Path, PathBuf};
use vlsync_mcap::{McapReader, Select, IMAGE_SCHEMAS};

/// A temporary file removed on drop.
struct Tmp(PathBuf);

impl Tmp {
    fn new(name: &str, bytes: &[u8]) -> Self {
        let path = std::env::temp_dir().join(format!(
            "vlsync-mcap-hostile-{}-{name}.mcap",
            std::process::id()
        ));
        std::fs::write(&path, bytes).unwrap();
        Self(path)
    }
}

impl Drop for Tmp {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

const SCHEMA: u8 = 0x03;
const CHANNEL: u8 = 0x04;
const MESSAGE: u8 = 0x05;
const CHUNK: u8 = 0x06;
const CHUNK_INDEX: u8 = 0x08;
const FOOTER: u8 = 0x02;
const IMAGE: &str = "sensor_msgs/msg/Image";

fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
    let mut r = vec![opcode];
    r.extend((body.len() as u64).to_le_bytes());
    r.extend(body);
    r
}

fn string(s: &str) -> Vec<u8> {
    let mut b = (s.len() as u32).to_le_bytes().to_vec();
    b.extend(s.as_bytes());
    b
}

fn schema(id: u16) -> Vec<u8> {
    let body = [
        id.to_le_bytes().to_vec(),
        string(IMAGE),
        string("ros2msg"),
        0u32.to_le_bytes().to_vec(),
    ]
    .concat();
    record(SCHEMA, &body)
}

fn channel(id: u16, schema: u16, topic: &str) -> Vec<u8> {
    let body = [
        id.to_le_bytes().to_vec(),
        schema.to_le_bytes().to_vec(),
        string(topic),
        string("cdr"),
        0u32.to_le_bytes().to_vec(), // no metadata
    ]
    .concat();
    record(CHANNEL, &body)
}

/// A message on `channel` at log time `t`, its data `t` as 8 bytes.
fn message(channel: u16, t: u64) -> Vec<u8> {
    let mut body = channel.to_le_bytes().to_vec();
    body.extend(0u32.to_le_bytes());
    body.extend(t.to_le_bytes());
    body.extend(t.to_le_bytes());
    body.extend(t.to_le_bytes());
    record(MESSAGE, &body)
}

/// An uncompressed chunk record around `records`, with their CRC.
fn chunk(records: &[u8]) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend(0u64.to_le_bytes());
    b.extend(100u64.to_le_bytes());
    b.extend((records.len() as u64).to_le_bytes());
    b.extend(crc32fast::hash(records).to_le_bytes());
    b.extend(string(""));
    b.extend((records.len() as u64).to_le_bytes());
    b.extend(records);
    record(CHUNK, &b)
}

/// The index of the uncompressed `chunk` record at byte `start`.
fn chunk_index(start: u64, chunk: &[u8]) -> Vec<u8> {
    // the records: the record's length less the fixed fields, "" and its size
    let records = (chunk.len() - 9 - 8 - 8 - 8 - 4 - 4 - 8) as u64;
    let mut b = Vec::new();
    b.extend(0u64.to_le_bytes());
    b.extend(100u64.to_le_bytes());
    b.extend(start.to_le_bytes());
    b.extend((chunk.len() as u64).to_le_bytes());
    b.extend(0u32.to_le_bytes()); // no message indexes
    b.extend(0u64.to_le_bytes());
    b.extend(string(""));
    b.extend(records.to_le_bytes());
    b.extend(records.to_le_bytes());
    record(CHUNK_INDEX, &b)
}

/// A whole recording: the magic, `data`, a summary of `summary` (none when
/// empty), the footer and the magic.
fn mcap(data: &[Vec<u8>], summary: &[Vec<u8>]) -> Vec<u8> {
    let mut b = mcap_magic();
    for r in data {
        b.extend(r);
    }
    let summary_start = if summary.is_empty() {
        0
    } else {
        b.len() as u64
    };
    for r in summary {
        b.extend(r);
    }
    let mut footer = summary_start.to_le_bytes().to_vec();
    footer.extend([0u8; 12]);
    b.extend(record(FOOTER, &footer));
    b.extend(mcap_magic());
    b
}

fn mcap_magic() -> Vec<u8> {
    b"\x89MCAP0\r\n".to_vec()
}

/// An indexed recording of schema 1, channel 1 `/cam` and `chunks` (records each),
/// each chunk indexed `copies` times.
fn indexed(chunks: &[Vec<u8>], copies: usize) -> Vec<u8> {
    let mut data = vec![schema(1), channel(1, 1, "/cam")];
    let mut at = 8 + data.iter().map(Vec::len).sum::<usize>() as u64;
    let mut summary = vec![schema(1), channel(1, 1, "/cam")];
    for records in chunks {
        let c = chunk(records);
        for _ in 0..copies {
            summary.push(chunk_index(at, &c));
        }
        at += c.len() as u64;
        data.push(c);
    }
    mcap(&data, &summary)
}

fn open(path: &Path) -> Result<McapReader, vlsync_mcap::Error> {
    McapReader::open(
        path,
        &Select::Topic("/cam".into()),
        &IMAGE_SCHEMAS,
        Default::default(),
    )
}

/// The log times of the messages read, and the error that ended the read.
fn read_all(r: &mut McapReader) -> (Vec<u64>, Option<String>) {
    let mut times = vec![];
    loop {
        match r.next_message() {
            Ok(Some(m)) => {
                assert_eq!(m.data, m.log_time.to_le_bytes());
                times.push(m.log_time);
            }
            Ok(None) => return (times, None),
            Err(e) => return (times, Some(e.to_string())),
        }
    }
}

/// Runs this test again in a child process whose address space is limited to
/// 2 GiB, as on a small robot computer: an allocation of 4 GiB aborts it there
/// (this machine would grant one and never touch it). `true` in the child.
fn in_limited_child(test: &str) -> bool {
    const CHILD: &str = "VLSYNC_MCAP_LIMITED_CHILD";
    if std::env::var_os(CHILD).is_some() {
        return true;
    }
    let exe = std::env::current_exe().unwrap();
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 2097152 && exec \"$0\" \"$@\"")
        .arg(exe)
        .args(["--exact", test, "--nocapture", "--test-threads=1"])
        .env(CHILD, "1")
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "the child failed: {text}");
    assert!(text.contains("1 passed"), "{text}");
    false
}

/// A string length in a record is checked against the record before the `mcap`
/// crate parses it: its parser reserved what the length said, 4 GiB for the
/// review's 25-byte file, which aborts a process that cannot have it.
#[test]
fn a_string_length_of_4_gib_is_refused_without_reserving_it() {
    if !in_limited_child("a_string_length_of_4_gib_is_refused_without_reserving_it") {
        return;
    }
    // the review's trigger: a Channel record whose topic claims 0xFFFFFFFF bytes
    let mut b = mcap_magic();
    b.extend(record(CHANNEL, &[1, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF]));
    assert_eq!(b.len(), 25);
    let t = Tmp::new("topic-4gib", &b);
    let want = "the channel record at byte 8 has a topic claiming 4294967295 bytes";
    let e = McapReader::topics(&t.0).unwrap_err().to_string();
    assert!(e.contains(want), "{e}");
    let e = open(&t.0).unwrap_err().to_string();
    eprintln!("4 GiB topic: {e}");
    assert!(e.contains(want) && e.contains("no topic `/cam`"), "{e}");

    // the same record in the summary of an indexed file: the summary is not used,
    // the file is read from its start, and the listing names the record
    let mut bad = channel(9, 1, "/other");
    bad[9 + 4..9 + 8].copy_from_slice(&u32::MAX.to_le_bytes());
    let records = [message(1, 1), message(1, 2)].concat();
    let mut b = indexed(&[records], 1);
    let summary_start = {
        let n = b.len();
        u64::from_le_bytes(b[n - 8 - 20..n - 8 - 12].try_into().unwrap()) as usize
    };
    b.splice(summary_start..summary_start, bad.iter().copied());
    let n = b.len();
    b[n - 8 - 20..n - 8 - 12].copy_from_slice(&(summary_start as u64).to_le_bytes());
    let t = Tmp::new("summary-4gib", &b);
    let mut r = open(&t.0).unwrap();
    assert!(!r.is_indexed());
    assert_eq!(read_all(&mut r), (vec![1, 2], None));
    let e = McapReader::topics(&t.0).unwrap_err().to_string();
    assert!(
        e.contains(&format!(
            "the channel record at byte {summary_start} has a topic claiming 4294967295 bytes"
        )),
        "{e}"
    );

    // a chunk whose compression claims 4 GiB, read from the start
    let mut c = chunk(&message(1, 1));
    c[9 + 28..9 + 32].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    let data = [schema(1), channel(1, 1, "/cam")];
    let at = 8 + data.iter().map(Vec::len).sum::<usize>();
    let t = Tmp::new(
        "compression-4gib",
        &mcap(&[data[0].clone(), data[1].clone(), c], &[]),
    );
    let mut r = open(&t.0).unwrap();
    let (times, e) = read_all(&mut r);
    assert!(times.is_empty());
    let e = e.unwrap();
    assert!(
        e.contains(&format!(
            "the chunk record at byte {at} has a compression claiming 4294967280 bytes"
        )),
        "{e}"
    );
}

/// The review's trigger: a summary that is a chunk whose one record overruns
/// it. The `mcap` crate's summary reader underflowed a counter on it (a panic with
/// overflow checks, as in debug and fuzzing builds); the summary is now refused
/// before that reader sees it, and the walk from the start says what is wrong.
#[test]
fn a_chunk_in_the_summary_is_not_handed_to_the_summary_reader() {
    let inner = [5u8, 10, 0, 0, 0, 0, 0, 0, 0];
    let mut body = vec![0u8; 16];
    body.extend(9u64.to_le_bytes());
    body.extend(0u32.to_le_bytes());
    body.extend(string(""));
    body.extend(9u64.to_le_bytes());
    body.extend(inner);
    let c = record(CHUNK, &body);
    assert_eq!(c.len(), 9 + 49);
    let mut b = mcap_magic();
    b.extend(c);
    let mut footer = 8u64.to_le_bytes().to_vec();
    footer.extend([0u8; 12]);
    b.extend(record(FOOTER, &footer));
    b.extend(mcap_magic());
    assert_eq!(b.len(), 103);
    let t = Tmp::new("summary-chunk", &b);
    let want = "the record at byte 0 of the chunk's records (opcode 0x05) claims 10 bytes";
    let e = McapReader::topics(&t.0).unwrap_err().to_string();
    assert!(e.contains(want), "{e}");
    let e = open(&t.0).unwrap_err().to_string();
    assert!(e.contains(want), "{e}");
}

/// Two identical indexes of one chunk made the index's reader read it, and yield
/// its messages, twice.
#[test]
fn identical_duplicate_chunk_indexes_yield_each_message_once() {
    let chunks = [
        [message(1, 1), message(1, 2)].concat(),
        [message(1, 3)].concat(),
    ];
    for copies in [1, 2, 3] {
        let t = Tmp::new(&format!("dup-index-{copies}"), &indexed(&chunks, copies));
        let mut r = open(&t.0).unwrap();
        assert!(r.is_indexed());
        assert_eq!(read_all(&mut r), (vec![1, 2, 3], None), "{copies}");
    }
}

/// Through the index, a chunk whose last record overruns it yields the messages
/// before that record, then the error, as the walk from the start does (the
/// index's reader refuses the whole chunk before yielding any); the error names
/// the chunk record's start, not its data's.
#[test]
fn a_chunk_with_a_fault_yields_its_messages_before_it_through_the_index() {
    let mut bad = message(1, 9);
    bad[1..9].copy_from_slice(&99u64.to_le_bytes());
    let first = [message(1, 1)].concat();
    let second = [message(1, 2), message(1, 3), bad.clone()].concat();
    let b = indexed(&[first.clone(), second], 1);
    // the second chunk's record starts after the first's
    let start = 8 + schema(1).len() + channel(1, 1, "/cam").len() + chunk(&first).len();
    let t = Tmp::new("chunk-fault", &b);
    let mut r = open(&t.0).unwrap();
    assert!(r.is_indexed());
    let (times, e) = read_all(&mut r);
    assert_eq!(times, [1, 2, 3]);
    let e = e.unwrap();
    eprintln!("chunk fault through the index: {e}");
    let overrun = format!(
        "the record at byte {} of the chunk's records (opcode 0x05) claims 99 bytes",
        2 * message(1, 0).len()
    );
    assert!(
        e.contains(&format!(
            "after message #2 of topic `/cam` (log time 3 ns), chunk at byte {start}"
        )) && e.contains(&overrun),
        "{e}"
    );
    // the same without the summary, read from the start
    let mut cut = b.clone();
    let n = cut.len();
    cut[n - 8 - 20..n - 8 - 12].fill(0);
    let t = Tmp::new("chunk-fault-linear", &cut);
    let mut r = open(&t.0).unwrap();
    assert!(!r.is_indexed());
    let (times, e) = read_all(&mut r);
    assert_eq!(times, [1, 2, 3]);
    assert!(e.unwrap().contains(&overrun));
}

/// A message too short for its header on another topic: read from the start it is
/// stepped over (its channel is read first; it ended the read of this topic);
/// through the index the messages of this topic in its chunk come first, then the
/// error names it (the index's reader refuses such a chunk whole).
#[test]
fn a_short_message_of_another_topic_does_not_hide_this_topics_messages() {
    let mut short = 2u16.to_le_bytes().to_vec();
    short.extend([0u8; 8]);
    let short = record(MESSAGE, &short);
    let records = [message(1, 1), short, message(1, 2)].concat();
    let data = [schema(1), channel(1, 1, "/cam"), channel(2, 1, "/other")];
    let linear = mcap(
        &[
            data[0].clone(),
            data[1].clone(),
            data[2].clone(),
            chunk(&records),
        ],
        &[],
    );
    let t = Tmp::new("short-linear", &linear);
    let mut r = open(&t.0).unwrap();
    assert!(!r.is_indexed());
    assert_eq!(read_all(&mut r), (vec![1, 2], None));
    // a short message on this topic is an error, after the messages before it
    let mut mine = 1u16.to_le_bytes().to_vec();
    mine.extend([0u8; 8]);
    let records = [message(1, 1), record(MESSAGE, &mine), message(1, 2)].concat();
    let t = Tmp::new(
        "short-mine",
        &mcap(&[data[0].clone(), data[1].clone(), chunk(&records)], &[]),
    );
    let (times, e) = read_all(&mut open(&t.0).unwrap());
    assert_eq!(times, [1]);
    let e = e.unwrap();
    assert!(
        e.contains(&format!(
            "the message record at byte {} of the records of the chunk at byte",
            message(1, 0).len()
        )) && e.contains("is 10 bytes, shorter than a message's 22-byte header"),
        "{e}"
    );
    // through the index
    let records = [
        message(1, 1),
        {
            let mut s = 2u16.to_le_bytes().to_vec();
            s.extend([0u8; 8]);
            record(MESSAGE, &s)
        },
        message(1, 2),
    ]
    .concat();
    let t = Tmp::new("short-indexed", &indexed(&[records], 1));
    let mut r = open(&t.0).unwrap();
    assert!(r.is_indexed());
    let (times, e) = read_all(&mut r);
    assert_eq!(times, [1, 2]);
    let e = e.unwrap();
    eprintln!("short message through the index: {e}");
    assert!(
        e.contains(&format!(
            "the message record at byte {} of the chunk's records is 10 bytes",
            message(1, 0).len()
        )),
        "{e}"
    );
}

/// A file without a summary whose first channel record does not parse: the scan
/// for channels went no further, so the topic's channel after it was not seen and
/// `open` said "the file has no channels". Now the channels after it are seen, and
/// when the topic is not found the record is named with its place.
#[test]
fn an_unreadable_channel_record_is_named_and_the_channels_after_it_are_seen() {
    let mut bad = channel(5, 1, "/broken");
    // its topic claims 100 bytes, more than the record holds
    bad[9 + 4..9 + 8].copy_from_slice(&100u32.to_le_bytes());
    let at = 8 + schema(1).len();
    let records = [message(1, 1), message(1, 2)].concat();
    let b = mcap(
        &[
            schema(1),
            bad.clone(),
            channel(1, 1, "/cam"),
            chunk(&records),
        ],
        &[],
    );
    let t = Tmp::new("bad-channel", &b);
    let mut r = open(&t.0).unwrap();
    assert_eq!(read_all(&mut r), (vec![1, 2], None));
    let want = format!("the channel record at byte {at} has a topic claiming 100 bytes");
    let e = McapReader::topics(&t.0).unwrap_err().to_string();
    assert!(e.contains(&want), "{e}");
    // the topic missing: the record is named, it may have been the topic's
    let b = mcap(&[schema(1), bad, chunk(&records)], &[]);
    let t = Tmp::new("bad-channel-only", &b);
    let e = open(&t.0).unwrap_err().to_string();
    assert!(
        e.contains(&want) && e.contains("without it: no topic `/cam`; the file has no channels"),
        "{e}"
    );
}
