//! Reading an MCAP file from its start, record by record, for files without a
//! usable summary (a recording that was cut off, or one written without chunk
//! indexes).
//!
//! This crate walks the file itself rather than through the `mcap` crate's
//! linear reader, because a recording is hostile input and every length in it
//! is checked against what holds it:
//!
//! * a top-level record may claim at most the bytes the file has left (a longer
//!   claim is the cut of a truncated file, or corruption when the file ends with
//!   the magic as a whole recording does; never a buffer of that size) and at
//!   most [`crate::ReaderOptions::max_record_bytes`];
//! * the walk ends only at a footer of a footer's 20 bytes followed by the magic
//!   (a record whose opcode was flipped to the footer's is corruption, a cut in
//!   the last bytes is a truncation);
//! * a chunk is decoded whole ([`crate::decompress`]); a compressed one must hold
//!   exactly the uncompressed size its header declares (an uncompressed one is
//!   what it holds, its buffer no bigger), and its CRC (when not 0) is checked
//!   before any of its records is used;
//! * a record inside a chunk may claim at most what its chunk has left: a longer
//!   claim is an error naming the record's place in the chunk (the `mcap` crate's
//!   walk overflows a counter there);
//! * a chunk cut by the end of the file yields the complete records it holds
//!   (uncompressed), or that its frames' complete blocks hold (zstd, lz4: a
//!   recorder killed by a power cut leaves its last chunk so), then the file's
//!   truncation is reported (their CRC cannot be checked: it covers the whole
//!   chunk).
//!
//! The walk yields records in file order, those inside chunks in place of their
//! chunk; the chunk records themselves are not yielded.

use crate::decompress::{self, ChunkError};
use mcap::records::op;
use mcap::McapError;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};

/// opcode and length of a record
pub(crate) const HEAD: usize = 9;
/// a footer's body: summary start, summary offset start, summary CRC
const FOOTER_BODY: usize = 8 + 8 + 4;
/// a chunk record's fixed fields before its compression string: start and end
/// time, uncompressed size, CRC
const CHUNK_FIXED: usize = 8 + 8 + 8 + 4;

/// Why the walk stopped.
#[derive(Debug)]
pub(crate) enum Fault {
    /// The `mcap` crate's error (a record's body, the file's magic, a truncation).
    Mcap(McapError),
    /// A chunk compression this crate does not decode.
    Unsupported(String),
    /// A chunk whose content is inconsistent.
    Corrupt(String),
    /// Reading the file failed.
    Io(std::io::Error),
}

impl From<McapError> for Fault {
    fn from(e: McapError) -> Self {
        Fault::Mcap(e)
    }
}

impl From<ChunkError> for Fault {
    fn from(e: ChunkError) -> Self {
        match e {
            ChunkError::Unsupported(c) => Fault::Unsupported(c),
            ChunkError::Corrupt(r) => Fault::Corrupt(r),
        }
    }
}

impl From<std::io::Error> for Fault {
    fn from(e: std::io::Error) -> Self {
        Fault::Io(e)
    }
}

/// The decoded records of one chunk.
#[derive(Debug, Default)]
struct Chunk {
    content: Vec<u8>,
    pos: usize,
    /// where the record last yielded starts in `content`
    last: usize,
}

impl Chunk {
    fn has_more(&self) -> bool {
        self.pos < self.content.len()
    }

    /// The next record (opcode, body); call only while [`Chunk::has_more`].
    fn next_record(&mut self) -> Result<(u8, &[u8]), Fault> {
        let at = self.pos;
        let rest = self.content.get(at..).unwrap_or_default();
        match split_record(rest) {
            Ok((opcode, body)) => {
                self.last = at;
                self.pos = at + HEAD + body.len();
                Ok((opcode, body))
            }
            Err(reason) => {
                self.pos = self.content.len();
                Err(Fault::Corrupt(format!(
                    "the record at byte {at} of the chunk's records {reason}"
                )))
            }
        }
    }
}

/// Splits the record at the start of `rest`: opcode and body, or what is wrong.
pub(crate) fn split_record(rest: &[u8]) -> Result<(u8, &[u8]), String> {
    let Some((head, tail)) = rest.split_first_chunk::<HEAD>() else {
        return Err(format!(
            "is cut off in its header ({} of {HEAD} bytes)",
            rest.len()
        ));
    };
    let opcode = head[0];
    let len = u64::from_le_bytes(le8(&head[1..]));
    match usize::try_from(len).ok().and_then(|n| tail.get(..n)) {
        Some(body) => Ok((opcode, body)),
        None => Err(format!(
            "(opcode {opcode:#04x}) claims {len} bytes, its chunk holds {} more",
            tail.len()
        )),
    }
}

fn le8(b: &[u8]) -> [u8; 8] {
    let mut a = [0u8; 8];
    let n = b.len().min(8);
    a[..n].copy_from_slice(&b[..n]);
    a
}

/// See [`LinearWalk::place`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Place {
    InChunk(u64),
    AfterChunk(u64),
}

/// The walk over one file (see the module docs).
#[derive(Debug)]
pub(crate) struct LinearWalk {
    limit: usize,
    /// offset of the next top-level record; 0 before the magic is checked
    pos: u64,
    /// offset of the last top-level record read (a chunk's, while its records
    /// are yielded)
    top_at: u64,
    ended: bool,
    body: Vec<u8>,
    chunk: Chunk,
    /// chunks met so far (1-based number of the current one)
    chunks: u64,
    /// set when the current chunk is cut by the end of the file: reported after
    /// its complete records
    cut: bool,
    /// whether the last record or fault came from inside chunk `chunks`
    inside: bool,
    /// whether the file ends with the magic (`None`: not read yet)
    ends_with_magic: Option<bool>,
    ahead: Ahead,
}

/// Bytes read ahead at once: a file of small records (an unchunked recording) is
/// read in a few large reads instead of two small ones per record.
const AHEAD: usize = 64 * 1024;

/// A read-ahead window over the file (allocated once, with the walk).
#[derive(Debug)]
struct Ahead {
    start: u64,
    len: usize,
    buf: Box<[u8]>,
}

impl Ahead {
    fn new() -> Self {
        Self {
            start: 0,
            len: 0,
            buf: vec![0; AHEAD].into_boxed_slice(),
        }
    }

    /// Fills `out` with the file's bytes at `pos`: from the window when it holds
    /// them, else a large request directly, else the window refilled from `pos`.
    fn read(
        &mut self,
        file: &mut File,
        file_len: u64,
        pos: u64,
        out: &mut [u8],
    ) -> Result<(), Fault> {
        let want = out.len() as u64;
        let held = pos >= self.start && pos - self.start + want <= self.len as u64;
        if !held {
            if out.len() > AHEAD / 2 {
                return read_at(file, pos, out);
            }
            let n =
                usize::try_from(file_len.saturating_sub(pos).min(AHEAD as u64)).unwrap_or(AHEAD);
            if n < out.len() {
                return Err(Fault::Mcap(McapError::UnexpectedEof));
            }
            self.len = 0;
            read_at(file, pos, &mut self.buf[..n])?;
            self.start = pos;
            self.len = n;
        }
        let off = (pos - self.start) as usize;
        out.copy_from_slice(&self.buf[off..off + out.len()]);
        Ok(())
    }
}

impl LinearWalk {
    /// A walk from the start of the file, records at most `limit` bytes.
    pub(crate) fn new(limit: usize) -> Self {
        Self {
            limit,
            pos: 0,
            top_at: 0,
            ended: false,
            body: Vec::new(),
            chunk: Chunk::default(),
            chunks: 0,
            cut: false,
            inside: false,
            ends_with_magic: None,
            ahead: Ahead::new(),
        }
    }

    /// Where the last record came from, or the last fault happened: inside chunk
    /// N (1-based, in file order), or after chunk N at the top level (N = 0:
    /// before the first chunk).
    pub(crate) fn place(&self) -> Place {
        if self.inside {
            Place::InChunk(self.chunks)
        } else {
            Place::AfterChunk(self.chunks)
        }
    }

    /// Where the record last yielded starts, for an error about its content: "at
    /// byte N" of the file, or "at byte K of the records of the chunk at byte N".
    pub(crate) fn record_at(&self) -> String {
        if self.inside {
            format!(
                "at byte {} of the records of the chunk at byte {}",
                self.chunk.last, self.top_at
            )
        } else {
            format!("at byte {}", self.top_at)
        }
    }

    /// The next record, `Ok(None)` after the footer. After a fault the walk ends.
    pub(crate) fn next(
        &mut self,
        file: &mut File,
        file_len: u64,
    ) -> Result<Option<(u8, &[u8])>, Fault> {
        let r = self.advance(file, file_len);
        match r {
            Ok(true) => {}
            Ok(false) => return Ok(None),
            Err(e) => {
                self.ended = true;
                self.chunk = Chunk::default();
                return Err(e);
            }
        }
        if self.chunk.has_more() {
            return self.chunk.next_record().map(Some).inspect_err(|_| {
                self.ended = true;
            });
        }
        Ok(Some((self.body_opcode(), &self.body[HEAD..])))
    }

    /// The opcode of the top-level record in `body`.
    fn body_opcode(&self) -> u8 {
        self.body.first().copied().unwrap_or_default()
    }

    /// Moves to the next record: `Ok(true)` when one is ready (in the chunk, else
    /// in `body`), `Ok(false)` at the end.
    fn advance(&mut self, file: &mut File, file_len: u64) -> Result<bool, Fault> {
        loop {
            if self.ended {
                return Ok(false);
            }
            self.inside = true;
            if self.chunk.has_more() {
                return Ok(true);
            }
            if self.cut {
                // the complete records of the cut chunk are done
                self.cut = false;
                return Err(Fault::Mcap(McapError::UnexpectedEof));
            }
            self.inside = false;
            if self.pos == 0 {
                let mut magic = [0u8; 8];
                if file_len < 8 {
                    return Err(Fault::Mcap(McapError::UnexpectedEof));
                }
                read_at(file, 0, &mut magic)?;
                if magic[..] != *mcap::MAGIC {
                    return Err(Fault::Mcap(McapError::BadMagic));
                }
                self.pos = 8;
            }
            let left = file_len.saturating_sub(self.pos);
            if left < HEAD as u64 {
                // no footer: the file was cut (at or inside a record's header)
                return Err(Fault::Mcap(McapError::UnexpectedEof));
            }
            let mut head = [0u8; HEAD];
            self.ahead.read(file, file_len, self.pos, &mut head)?;
            let opcode = head[0];
            let len = u64::from_le_bytes(le8(&head[1..]));
            let body_left = left - HEAD as u64;
            if opcode == op::FOOTER {
                // the footer is 20 bytes and the magic follows it: anything else is a
                // corrupt record (say, a chunk's opcode flipped) or a cut in the last bytes
                let end = self.pos + (HEAD + FOOTER_BODY + 8) as u64;
                if len != FOOTER_BODY as u64 {
                    return Err(Fault::Corrupt(format!(
                        "the footer at byte {} claims {len} bytes, a footer has {FOOTER_BODY}",
                        self.pos
                    )));
                }
                if end > file_len {
                    return Err(Fault::Mcap(McapError::UnexpectedEof));
                }
                let mut magic = [0u8; 8];
                read_at(file, end - 8, &mut magic)?;
                if magic[..] != *mcap::MAGIC {
                    return Err(Fault::Mcap(McapError::BadMagic));
                }
                self.ended = true;
                return Ok(false);
            }
            if opcode == op::CHUNK {
                // numbered before any check, so a fault names this chunk
                self.chunks += 1;
                self.inside = true;
            }
            if len > body_left {
                if opcode == op::CHUNK && !self.complete(file, file_len)? {
                    // a chunk cut by the end of the file: its complete records first
                    let n = usize::try_from(body_left)
                        .unwrap_or(usize::MAX)
                        .min(self.limit);
                    self.read_body(file, file_len, head, n)?;
                    self.top_at = self.pos;
                    self.load_cut_chunk();
                    self.cut = true;
                    self.pos = file_len;
                    continue;
                }
                if self.complete(file, file_len)? {
                    // the file ends as a whole recording does: this length is corrupt
                    return Err(Fault::Corrupt(format!(
                        "the record at byte {} (opcode {opcode:#04x}) claims {len} bytes, the \
                         file has {body_left} more",
                        self.pos
                    )));
                }
                return Err(Fault::Mcap(McapError::UnexpectedEof));
            }
            // a record no reader here uses (an attachment, metadata, an index, the
            // summary) is stepped over, not read: a large attachment before the
            // data ended the walk (over the limit) and lost every message after it
            if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE | op::CHUNK) {
                self.pos += HEAD as u64 + len;
                continue;
            }
            if len > self.limit as u64 {
                return Err(Fault::Mcap(McapError::RecordTooLarge { opcode, len }));
            }
            // len <= body_left and <= limit: fits in usize
            let n = len as usize;
            self.read_body(file, file_len, head, n)?;
            self.top_at = self.pos;
            self.pos += HEAD as u64 + len;
            if opcode == op::CHUNK {
                self.load_chunk()?;
                continue;
            }
            return Ok(true);
        }
    }

    /// Whether the file ends with the magic, as a whole recording does (read once).
    fn complete(&mut self, file: &mut File, file_len: u64) -> Result<bool, Fault> {
        if self.ends_with_magic.is_none() {
            let mut tail = [0u8; 8];
            let ok = file_len >= 16 && {
                read_at(file, file_len - 8, &mut tail)?;
                tail[..] == *mcap::MAGIC
            };
            self.ends_with_magic = Some(ok);
        }
        Ok(self.ends_with_magic == Some(true))
    }

    /// Reads a record's header and `n` bytes of its body into `body`.
    fn read_body(
        &mut self,
        file: &mut File,
        file_len: u64,
        head: [u8; HEAD],
        n: usize,
    ) -> Result<(), Fault> {
        self.body.clear();
        self.body.extend_from_slice(&head);
        self.body.resize(HEAD + n, 0);
        let at = self.pos + HEAD as u64;
        self.ahead.read(file, file_len, at, &mut self.body[HEAD..])
    }

    /// Decodes the complete chunk record in `body`.
    fn load_chunk(&mut self) -> Result<(), Fault> {
        self.chunk.pos = 0;
        self.chunk.content.clear();
        // checked before the `mcap` crate parses it: a compression string claiming
        // 4 GiB made its parser reserve 4 GiB
        let (header, data) = match crate::lengths::parse_record(op::CHUNK, &self.body[HEAD..]) {
            Ok(mcap::records::Record::Chunk { header, data }) => (header, data),
            Ok(_) => return Err(Fault::Mcap(McapError::BadIndex)),
            Err(reason) => {
                return Err(Fault::Corrupt(format!(
                    "the chunk record at byte {} {reason}",
                    self.top_at
                )))
            }
        };
        decompress::decode_chunk(
            &header.compression,
            &data,
            header.uncompressed_size,
            self.limit,
            &mut self.chunk.content,
        )?;
        if header.uncompressed_crc != 0 {
            let calculated = crc32fast::hash(&self.chunk.content);
            if calculated != header.uncompressed_crc {
                self.chunk.content.clear();
                return Err(Fault::Mcap(McapError::BadChunkCrc {
                    saved: header.uncompressed_crc,
                    calculated,
                }));
            }
        }
        Ok(())
    }

    /// The complete records of the cut chunk in `body`: those it holds when it is
    /// uncompressed, those its frames' complete blocks hold when it is compressed.
    fn load_cut_chunk(&mut self) {
        self.chunk.content.clear();
        self.chunk.pos = 0;
        let b = &self.body[HEAD..];
        let Some(uncompressed_size) = b.get(16..24).map(|s| u64::from_le_bytes(le8(s))) else {
            return;
        };
        let Some(name_len) = b.get(CHUNK_FIXED..CHUNK_FIXED + 4) else {
            return;
        };
        let name_len = u32::from_le_bytes([name_len[0], name_len[1], name_len[2], name_len[3]]);
        let name_at = CHUNK_FIXED + 4;
        let Some(size_at) = usize::try_from(name_len)
            .ok()
            .and_then(|n| name_at.checked_add(n))
        else {
            return;
        };
        let Some(Ok(compression)) = b.get(name_at..size_at).map(std::str::from_utf8) else {
            return;
        };
        // the compressed size, then the records
        let records_at = size_at + 8;
        let (Some(size), Some(rest)) = (b.get(size_at..records_at), b.get(records_at..)) else {
            return;
        };
        let size = usize::try_from(u64::from_le_bytes(le8(size))).unwrap_or(usize::MAX);
        let data = &rest[..size.min(rest.len())];
        if compression.is_empty() {
            self.chunk.content.extend_from_slice(data);
        } else {
            decompress::decode_cut_chunk(
                compression,
                data,
                uncompressed_size,
                self.limit,
                &mut self.chunk.content,
            );
        }
        let records = &self.chunk.content;
        let mut complete = 0;
        while let Some(Ok((_, body))) = records.get(complete..).map(split_record) {
            complete += HEAD + body.len();
        }
        self.chunk.content.truncate(complete);
    }
}

fn read_at(file: &mut File, pos: u64, buf: &mut [u8]) -> Result<(), Fault> {
    file.seek(SeekFrom::Start(pos))?;
    file.read_exact(buf).map_err(|e| match e.kind() {
        std::io::ErrorKind::UnexpectedEof => Fault::Mcap(McapError::UnexpectedEof),
        _ => Fault::Io(e),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
        let mut r = vec![opcode];
        r.extend_from_slice(&(body.len() as u64).to_le_bytes());
        r.extend_from_slice(body);
        r
    }

    /// A chunk record around `records`, uncompressed, with this CRC and declared size.
    fn chunk(records: &[u8], crc: u32, uncompressed_size: u64) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(&0u64.to_le_bytes());
        b.extend_from_slice(&0u64.to_le_bytes());
        b.extend_from_slice(&uncompressed_size.to_le_bytes());
        b.extend_from_slice(&crc.to_le_bytes());
        b.extend_from_slice(&0u32.to_le_bytes()); // compression ""
        b.extend_from_slice(&(records.len() as u64).to_le_bytes());
        b.extend_from_slice(records);
        record(op::CHUNK, &b)
    }

    /// Removes its file when dropped.
    struct TmpPath(std::path::PathBuf);

    impl Drop for TmpPath {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn file(parts: &[&[u8]]) -> (TmpPath, File, u64) {
        use std::sync::atomic::{AtomicU32, Ordering};
        static N: AtomicU32 = AtomicU32::new(0);
        let path = std::env::temp_dir().join(format!(
            "vlsync-mcap-linear-{}-{}.mcap",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let mut bytes = mcap::MAGIC.to_vec();
        for p in parts {
            bytes.extend_from_slice(p);
        }
        std::fs::write(&path, &bytes).unwrap();
        let file = File::open(&path).unwrap();
        (TmpPath(path), file, bytes.len() as u64)
    }

    fn walk_all(w: &mut LinearWalk, f: &mut File, len: u64) -> (Vec<(u8, Vec<u8>)>, Option<Fault>) {
        let mut out = vec![];
        loop {
            match w.next(f, len) {
                Ok(Some((op, b))) => out.push((op, b.to_vec())),
                Ok(None) => return (out, None),
                Err(e) => return (out, Some(e)),
            }
        }
    }

    fn footer() -> Vec<u8> {
        let mut f = record(op::FOOTER, &[0u8; 20]);
        f.extend_from_slice(mcap::MAGIC);
        f
    }

    #[test]
    fn records_in_and_out_of_chunks_in_file_order() {
        let inner = [record(op::MESSAGE, b"one"), record(op::MESSAGE, b"two")].concat();
        let crc = crc32fast::hash(&inner);
        let c = chunk(&inner, crc, inner.len() as u64);
        let (_p, mut f, len) = file(&[
            &record(op::SCHEMA, b"s"),
            &c,
            &record(op::MESSAGE, b"3"),
            &footer(),
        ]);
        let mut w = LinearWalk::new(1 << 20);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        assert!(fault.is_none(), "{fault:?}");
        let bodies: Vec<&[u8]> = recs.iter().map(|(_, b)| b.as_slice()).collect();
        assert_eq!(bodies, [&b"s"[..], b"one", b"two", b"3"]);
    }

    /// The `mcap` crate's own walk overflows a counter on this chunk (CRC 0: not checked).
    #[test]
    fn a_record_overrunning_its_chunk_is_an_error_after_the_good_ones() {
        let mut inner = record(op::MESSAGE, b"good");
        let mut bad = record(op::MESSAGE, b"short");
        bad[1..9].copy_from_slice(&55u64.to_le_bytes());
        inner.extend_from_slice(&bad);
        let c = chunk(&inner, 0, inner.len() as u64);
        let (_p, mut f, len) = file(&[&c, &record(op::MESSAGE, b"after"), &footer()]);
        let mut w = LinearWalk::new(1 << 20);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        assert_eq!(recs.len(), 1);
        match fault {
            Some(Fault::Corrupt(r)) => assert_eq!(
                r,
                "the record at byte 13 of the chunk's records (opcode 0x05) claims 55 bytes, \
                 its chunk holds 5 more"
            ),
            other => panic!("{other:?}"),
        }
        assert_eq!(w.place(), Place::InChunk(1));
        // the walk has ended
        assert!(matches!(w.next(&mut f, len), Ok(None)));
    }

    #[test]
    fn a_length_beyond_the_file_is_its_cut_without_a_buffer_of_that_size() {
        let mut huge = record(op::MESSAGE, b"x");
        huge[1..9].copy_from_slice(&((1u64 << 30) - 16).to_le_bytes());
        let (_p, mut f, len) = file(&[&record(op::SCHEMA, b"s"), &huge]);
        let mut w = LinearWalk::new(1 << 30);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        assert_eq!(recs.len(), 1);
        assert!(
            matches!(fault, Some(Fault::Mcap(McapError::UnexpectedEof))),
            "{fault:?}"
        );
        assert!(w.body.capacity() < 4096, "{}", w.body.capacity());
        assert_eq!(w.place(), Place::AfterChunk(0));
    }

    #[test]
    fn a_record_over_the_limit_is_refused() {
        let (_p, mut f, len) = file(&[&record(op::MESSAGE, &[0u8; 100]), &footer()]);
        let mut w = LinearWalk::new(50);
        let (_, fault) = walk_all(&mut w, &mut f, len);
        assert!(
            matches!(
                fault,
                Some(Fault::Mcap(McapError::RecordTooLarge {
                    opcode: op::MESSAGE,
                    len: 100
                }))
            ),
            "{fault:?}"
        );
    }

    /// An attachment (or metadata, an index) over the limit before the data is
    /// stepped over unread: the messages after it are read.
    #[test]
    fn a_large_record_no_reader_uses_is_stepped_over() {
        const ATTACHMENT: u8 = 0x09;
        let (_p, mut f, len) = file(&[
            &record(op::SCHEMA, b"s"),
            &record(ATTACHMENT, &[7u8; 100]),
            &record(op::MESSAGE, b"after"),
            &footer(),
        ]);
        let mut w = LinearWalk::new(50);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        assert!(fault.is_none(), "{fault:?}");
        let bodies: Vec<&[u8]> = recs.iter().map(|(_, b)| b.as_slice()).collect();
        assert_eq!(bodies, [&b"s"[..], b"after"]);
        assert!(w.body.capacity() < 100, "{}", w.body.capacity());
    }

    #[test]
    fn a_cut_chunk_yields_its_complete_records_then_the_cut() {
        let inner = [
            record(op::MESSAGE, b"one"),
            record(op::MESSAGE, b"two"),
            record(op::MESSAGE, b"three"),
        ]
        .concat();
        let c = chunk(&inner, crc32fast::hash(&inner), inner.len() as u64);
        // cut inside the third record
        let cut = &c[..c.len() - 3];
        let (_p, mut f, len) = file(&[cut]);
        let mut w = LinearWalk::new(1 << 20);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        let bodies: Vec<&[u8]> = recs.iter().map(|(_, b)| b.as_slice()).collect();
        assert_eq!(bodies, [&b"one"[..], b"two"]);
        assert!(
            matches!(fault, Some(Fault::Mcap(McapError::UnexpectedEof))),
            "{fault:?}"
        );
        assert_eq!(w.place(), Place::InChunk(1));
    }

    /// A chunk record around `compressed`, the frames of `records` in `compression`.
    fn compressed_chunk(compression: &str, records: &[u8], compressed: &[u8]) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(&[0u8; 16]); // start, end time
        b.extend_from_slice(&(records.len() as u64).to_le_bytes());
        b.extend_from_slice(&crc32fast::hash(records).to_le_bytes());
        b.extend_from_slice(&(compression.len() as u32).to_le_bytes());
        b.extend_from_slice(compression.as_bytes());
        b.extend_from_slice(&(compressed.len() as u64).to_le_bytes());
        b.extend_from_slice(compressed);
        record(op::CHUNK, &b)
    }

    #[test]
    fn a_cut_compressed_chunk_yields_the_records_of_its_complete_blocks() {
        // 3,000 messages of 200 bytes (600 kB: several blocks of either codec),
        // incompressible enough that the blocks are not tiny
        let mut x = 0x9e37_79b9_7f4a_7c15_u64;
        let inner: Vec<u8> = (0..3000u32)
            .flat_map(|i| {
                let body: Vec<u8> = (0..200)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 7;
                        x ^= x << 17;
                        // a few distinct bytes: compressible, not trivially
                        b"abcdefgh"[(x % 8) as usize]
                    })
                    .chain(i.to_le_bytes())
                    .collect();
                record(op::MESSAGE, &body)
            })
            .collect();
        // lz4 in 64 KiB blocks, as the C library writes them by default (rosbag2's
        // recorder); lz4_flex's own default sizes the block by its first write
        fn lz4_64k(data: &[u8]) -> Vec<u8> {
            use std::io::Write;
            let info =
                lz4_flex::frame::FrameInfo::new().block_size(lz4_flex::frame::BlockSize::Max64KB);
            let mut e = lz4_flex::frame::FrameEncoder::with_frame_info(info, Vec::new());
            e.write_all(data).unwrap();
            e.finish().unwrap()
        }
        type Encode = fn(&[u8]) -> Vec<u8>;
        let encoders: [(&str, Encode); 2] =
            [("zstd", crate::decompress::tests::zstd), ("lz4", lz4_64k)];
        for (name, encode) in encoders {
            let c = compressed_chunk(name, &inner, &encode(&inner));
            // whole: every message
            let (_p, mut f, len) = file(&[&c, &footer()]);
            let mut w = LinearWalk::new(1 << 22);
            let (recs, fault) = walk_all(&mut w, &mut f, len);
            assert!(fault.is_none(), "{name}: {fault:?}");
            assert_eq!(recs.len(), 3000, "{name}");
            // cut at three quarters of its frames: the messages of the complete blocks
            // before the cut, each whole and in order, then the cut
            let cut = &c[..c.len() * 3 / 4];
            let (_p, mut f, len) = file(&[cut]);
            let mut w = LinearWalk::new(1 << 22);
            let (recs, fault) = walk_all(&mut w, &mut f, len);
            assert!(
                matches!(fault, Some(Fault::Mcap(McapError::UnexpectedEof))),
                "{name}: {fault:?}"
            );
            assert!(
                recs.len() > 1000 && recs.len() < 3000,
                "{name}: {} messages",
                recs.len()
            );
            for (i, (op, body)) in recs.iter().enumerate() {
                assert_eq!(*op, op::MESSAGE);
                assert_eq!(body[200..], (i as u32).to_le_bytes(), "{name}: message {i}");
            }
            // cut inside its header: nothing, then the cut
            let (_p, mut f, len) = file(&[&c[..40]]);
            let mut w = LinearWalk::new(1 << 22);
            let (recs, fault) = walk_all(&mut w, &mut f, len);
            assert!(recs.is_empty() && fault.is_some(), "{name}");
        }
        // an unknown compression cut: nothing, then the cut
        let c = compressed_chunk("brotli", &inner, &inner);
        let (_p, mut f, len) = file(&[&c[..c.len() / 2]]);
        let mut w = LinearWalk::new(1 << 22);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        assert!(recs.is_empty(), "{}", recs.len());
        assert!(matches!(fault, Some(Fault::Mcap(McapError::UnexpectedEof))));
    }

    #[test]
    fn a_chunk_whose_size_or_crc_disagrees_is_refused_before_its_records() {
        let inner = record(op::MESSAGE, b"one");
        let c = chunk(&inner, crc32fast::hash(&inner) ^ 1, inner.len() as u64);
        let (_p, mut f, len) = file(&[&c, &footer()]);
        let (recs, fault) = walk_all(&mut LinearWalk::new(1 << 20), &mut f, len);
        assert!(recs.is_empty());
        assert!(
            matches!(fault, Some(Fault::Mcap(McapError::BadChunkCrc { .. }))),
            "{fault:?}"
        );
        // uncompressed, the records are what the chunk holds, whatever its header's
        // uncompressed size says (the buffer is never bigger than they are)
        let c = chunk(&inner, 0, 1 << 29);
        let (_p, mut f, len) = file(&[&c, &footer()]);
        let mut w = LinearWalk::new(1 << 30);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        assert_eq!(recs.len(), 1);
        assert!(fault.is_none(), "{fault:?}");
        assert!(w.chunk.content.capacity() < 4096);
    }

    #[test]
    fn the_end_is_a_whole_footer_and_the_magic() {
        let one = record(op::MESSAGE, b"one");
        let whole = footer();
        // a flipped opcode that reads as a footer: its length is not a footer's
        let mut flipped = chunk(&one, 0, one.len() as u64);
        flipped[0] = op::FOOTER;
        let (_p, mut f, len) = file(&[&one, &flipped, &one, &whole]);
        let (recs, fault) = walk_all(&mut LinearWalk::new(1 << 20), &mut f, len);
        assert_eq!(recs.len(), 1);
        match fault {
            Some(Fault::Corrupt(r)) => assert!(r.contains("a footer has 20"), "{r}"),
            other => panic!("{other:?}"),
        }
        // cut anywhere in the footer or the magic after it
        for cut in 1..whole.len() {
            let (_p, mut f, len) = file(&[&one, &whole[..cut]]);
            let (recs, fault) = walk_all(&mut LinearWalk::new(1 << 20), &mut f, len);
            assert_eq!(recs.len(), 1);
            assert!(
                matches!(fault, Some(Fault::Mcap(McapError::UnexpectedEof))),
                "{cut}: {fault:?}"
            );
        }
        // the magic replaced
        let mut bad = whole.clone();
        let n = bad.len();
        bad[n - 1] ^= 1;
        let (_p, mut f, len) = file(&[&one, &bad]);
        let (_, fault) = walk_all(&mut LinearWalk::new(1 << 20), &mut f, len);
        assert!(
            matches!(fault, Some(Fault::Mcap(McapError::BadMagic))),
            "{fault:?}"
        );
    }

    /// In a file that ends as a whole recording does, a length past its end is
    /// corruption, not a cut: no records of that chunk are used.
    #[test]
    fn a_length_past_the_end_of_a_whole_file_is_corrupt() {
        let inner = record(op::MESSAGE, b"one");
        let mut c = chunk(&inner, 0, inner.len() as u64);
        c[1..9].copy_from_slice(&(1u64 << 20).to_le_bytes());
        let (_p, mut f, len) = file(&[&c, &footer()]);
        let mut w = LinearWalk::new(1 << 30);
        let (recs, fault) = walk_all(&mut w, &mut f, len);
        assert!(recs.is_empty());
        match fault {
            Some(Fault::Corrupt(r)) => assert!(
                r.contains("(opcode 0x06) claims 1048576 bytes, the file has"),
                "{r}"
            ),
            other => panic!("{other:?}"),
        }
        assert_eq!(w.place(), Place::InChunk(1));
    }

    proptest! {
        /// Any bytes after the magic: no panic, no buffer beyond the file, and the
        /// walk ends.
        #[test]
        fn arbitrary_files_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..400),
                                       chunked in any::<bool>()) {
            let bytes = if chunked { chunk(&tail, 0, tail.len() as u64) } else { tail.clone() };
            let (_p, mut f, len) = file(&[&bytes]);
            let mut w = LinearWalk::new(1 << 30);
            for _ in 0..1000 {
                match w.next(&mut f, len) {
                    Ok(Some(_)) => {}
                    Ok(None) | Err(_) => break,
                }
            }
            prop_assert!(w.body.capacity() <= (len as usize).max(64) + HEAD);
            prop_assert!(w.chunk.content.capacity() <= (len as usize).max(64));
        }
    }
}
