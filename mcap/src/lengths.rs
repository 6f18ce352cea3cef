//! The length prefixes inside an MCAP record, checked against the record before
//! the `mcap` crate parses it.
//!
//! `mcap::parse_record` reads each string of a record (a topic, a schema name, a
//! chunk's compression, a metadata key) through its u32 length prefix, and its
//! parser reserves that many bytes before reading any of them: a 12-byte Channel
//! record whose topic claims 4 GiB makes it ask for 4 GiB, and on a computer
//! without that memory (a Raspberry Pi on a robot) the failed allocation aborts
//! the process. [`parse_record`] first walks the record's fields as the MCAP
//! specification lays them out and checks every prefix (strings, byte arrays,
//! maps) against the bytes the record has left, so the parser never reserves
//! more than the record holds; a claim that does not fit is refused naming the
//! field and where in the record it is.
//!
//! An attachment is checked the same way for another reason: one whose body ends
//! right after its data length makes `mcap::parse_record` slice backwards, which
//! panics.

use mcap::records::{op, Record};

/// The record's body, walked field by field.
struct Fields<'a> {
    body: &'a [u8],
    at: usize,
}

/// A field's name in parts ("length of ", "a key of ", "metadata"), joined only
/// for an error: a walk that passes allocates nothing.
type Name<'a> = [&'a str; 3];

impl Fields<'_> {
    fn left(&self) -> usize {
        self.body.len() - self.at
    }

    /// Steps over `n` bytes of fixed fields ending with `what`.
    fn fixed(&mut self, n: usize, what: &str) -> Result<(), String> {
        self.fixed_named(n, ["", "", what])
    }

    fn fixed_named(&mut self, n: usize, name: Name<'_>) -> Result<(), String> {
        if n > self.left() {
            return Err(format!(
                "is {} bytes, cut in its {} (at byte {} of the record)",
                self.body.len(),
                name.concat(),
                self.at
            ));
        }
        self.at += n;
        Ok(())
    }

    /// Steps over `n` bytes that a length prefix of `what` claims.
    fn claimed(&mut self, n: u64, what: &str, prefix_at: usize) -> Result<(), String> {
        self.claimed_named(n, ["", "", what], prefix_at)
    }

    fn claimed_named(&mut self, n: u64, name: Name<'_>, prefix_at: usize) -> Result<(), String> {
        let left = self.left();
        match usize::try_from(n).ok().filter(|&n| n <= left) {
            Some(n) => {
                self.at += n;
                Ok(())
            }
            None => Err(format!(
                "has {} claiming {n} bytes (its length at byte {prefix_at} of the record), \
                 the record has {left} more",
                name.concat()
            )),
        }
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.u32_named(["", "", what])
    }

    /// The u32 length of the field `name` (its "length of " put in front).
    fn u32_named(&mut self, name: Name<'_>) -> Result<u32, String> {
        let at = self.at;
        self.fixed_named(4, ["length of ", name[1], name[2]])?;
        let b = &self.body[at..at + 4];
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self, what: &str) -> Result<u64, String> {
        let at = self.at;
        self.fixed_named(8, ["length of ", "", what])?;
        let mut b = [0u8; 8];
        b.copy_from_slice(&self.body[at..at + 8]);
        Ok(u64::from_le_bytes(b))
    }

    /// A string or byte array: u32 length, then that many bytes.
    fn bytes(&mut self, what: &str) -> Result<(), String> {
        self.bytes_named(["", "", what])
    }

    fn bytes_named(&mut self, name: Name<'_>) -> Result<(), String> {
        let prefix_at = self.at;
        let n = self.u32_named(name)?;
        self.claimed_named(u64::from(n), name, prefix_at)
    }

    /// A map of strings to strings: u32 length in bytes, then key and value
    /// strings while the bytes read are fewer than that (as the `mcap` crate
    /// reads it: a pair may end past the declared length).
    fn string_map(&mut self, what: &str) -> Result<(), String> {
        let prefix_at = self.at;
        let n = self.u32(what)?;
        let start = self.at;
        self.claimed(u64::from(n), what, prefix_at)?;
        self.at = start;
        while self.at - start < n as usize {
            self.bytes_named(["", "a key of ", what])?;
            self.bytes_named(["", "a value of ", what])?;
        }
        Ok(())
    }

    /// A map of fixed-size entries (`entry` bytes each): u32 length in bytes, then
    /// entries while the bytes read are fewer than that.
    fn fixed_map(&mut self, entry: usize, what: &str) -> Result<(), String> {
        let prefix_at = self.at;
        let n = self.u32(what)? as usize;
        let read = n.div_ceil(entry) * entry;
        self.claimed(read as u64, what, prefix_at)
    }
}

/// Whether records with `opcode` have length prefixes that [`check`] looks at.
pub(crate) fn has_prefixes(opcode: u8) -> bool {
    matches!(
        opcode,
        op::HEADER
            | op::SCHEMA
            | op::CHANNEL
            | op::CHUNK
            | op::CHUNK_INDEX
            | op::ATTACHMENT
            | op::ATTACHMENT_INDEX
            | op::METADATA
            | op::METADATA_INDEX
    )
}

/// Checks the length prefixes of a record with `opcode` and `body` (see the
/// module docs); records without any are not looked at.
pub(crate) fn check(opcode: u8, body: &[u8]) -> Result<(), String> {
    let mut f = Fields { body, at: 0 };
    match opcode {
        op::HEADER => {
            f.bytes("a profile")?;
            f.bytes("a library")?;
        }
        op::SCHEMA => {
            f.fixed(2, "id")?;
            f.bytes("a name")?;
            f.bytes("an encoding")?;
            f.bytes("data")?;
        }
        op::CHANNEL => {
            f.fixed(4, "ids")?;
            f.bytes("a topic")?;
            f.bytes("a message encoding")?;
            f.string_map("metadata")?;
        }
        op::CHUNK => {
            // start and end time, uncompressed size, CRC
            f.fixed(8 + 8 + 8 + 4, "header")?;
            f.bytes("a compression")?;
            let prefix_at = f.at;
            let n = f.u64("records")?;
            f.claimed(n, "records", prefix_at)?;
        }
        op::CHUNK_INDEX => {
            // start and end time, chunk start offset, chunk length
            f.fixed(8 + 8 + 8 + 8, "times and offsets")?;
            f.fixed_map(2 + 8, "message index offsets")?;
            f.fixed(8, "message index length")?;
            f.bytes("a compression")?;
        }
        op::ATTACHMENT => {
            // log time, create time
            f.fixed(8 + 8, "times")?;
            f.bytes("a name")?;
            f.bytes("a media type")?;
            let prefix_at = f.at;
            let n = f.u64("data")?;
            f.claimed(n, "data", prefix_at)?;
            f.fixed(4, "CRC")?;
        }
        op::ATTACHMENT_INDEX => {
            // offset, length, log time, create time, data size
            f.fixed(8 * 5, "offsets and times")?;
            f.bytes("a name")?;
            f.bytes("a media type")?;
        }
        op::METADATA => {
            f.bytes("a name")?;
            f.string_map("metadata")?;
        }
        op::METADATA_INDEX => {
            f.fixed(8 + 8, "offset and length")?;
            f.bytes("a name")?;
        }
        _ => {}
    }
    Ok(())
}

/// `mcap::parse_record` after [`check`]: a record's fields, or what is wrong with
/// them.
pub(crate) fn parse_record(opcode: u8, body: &[u8]) -> Result<Record<'_>, String> {
    check(opcode, body)?;
    mcap::parse_record(opcode, body).map_err(|e| match std::error::Error::source(&e) {
        Some(why) => format!("does not parse ({e}: {why})"),
        None => format!("does not parse ({e})"),
    })
}

/// The fixed header of a message record: channel id, sequence, log time, publish
/// time.
pub(crate) const MESSAGE_HEADER: usize = 2 + 4 + 8 + 8;

/// The channel id of a message record, read before the rest so that a malformed
/// message of another channel is not this reader's to refuse; `None` when the
/// record is too short to hold it.
pub(crate) fn message_channel(body: &[u8]) -> Option<u16> {
    body.get(..2).map(|b| u16::from_le_bytes([b[0], b[1]]))
}

/// A message record's header (channel id, sequence, log time, publish time) and
/// data, or what is wrong with it.
pub(crate) fn parse_message(body: &[u8]) -> Result<(mcap::records::MessageHeader, &[u8]), String> {
    let Some((head, data)) = body.split_first_chunk::<MESSAGE_HEADER>() else {
        return Err(format!(
            "is {} bytes, shorter than a message's {MESSAGE_HEADER}-byte header",
            body.len()
        ));
    };
    let u64_at = |at: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&head[at..at + 8]);
        u64::from_le_bytes(b)
    };
    let header = mcap::records::MessageHeader {
        channel_id: u16::from_le_bytes([head[0], head[1]]),
        sequence: u32::from_le_bytes([head[2], head[3], head[4], head[5]]),
        log_time: u64_at(6),
        publish_time: u64_at(14),
    };
    Ok((header, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &[u8]) -> Vec<u8> {
        let mut b = (s.len() as u32).to_le_bytes().to_vec();
        b.extend_from_slice(s);
        b
    }

    fn channel(topic: &[u8], metadata: &[u8]) -> Vec<u8> {
        let mut b = vec![1, 0, 2, 0];
        b.extend(string(topic));
        b.extend(string(b"cdr"));
        b.extend(metadata);
        b
    }

    #[test]
    fn well_formed_records_parse_as_the_mcap_crate_parses_them() {
        let meta = [string(b"k"), string(b"v")].concat();
        let body = channel(b"/cam", &string(&meta));
        match parse_record(op::CHANNEL, &body) {
            Ok(Record::Channel(c)) => {
                assert_eq!((c.id, c.schema_id, c.topic.as_str()), (1, 2, "/cam"));
                assert_eq!(c.metadata.get("k").map(String::as_str), Some("v"));
            }
            other => panic!("{other:?}"),
        }
        // a chunk: the header, compression "", two record bytes
        let mut chunk = vec![0u8; 28];
        chunk.extend(string(b""));
        chunk.extend(2u64.to_le_bytes());
        chunk.extend([7, 8]);
        assert!(matches!(
            parse_record(op::CHUNK, &chunk),
            Ok(Record::Chunk { .. })
        ));
        // records this module does not look into are the crate's to parse
        assert!(check(op::STATISTICS, &[1]).is_ok());
    }

    #[test]
    fn a_length_beyond_the_record_is_refused_naming_the_field() {
        // the review's trigger: a Channel whose topic claims 0xFFFFFFFF bytes
        let body = [1, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF];
        assert_eq!(
            check(op::CHANNEL, &body),
            Err(
                "has a topic claiming 4294967295 bytes (its length at byte 4 of the record), \
                 the record has 0 more"
                    .into()
            )
        );
        // a metadata value, past the topic and encoding
        let meta = [string(b"k"), (1u32 << 31).to_le_bytes().to_vec()].concat();
        let body = channel(b"/cam", &string(&meta));
        let e = check(op::CHANNEL, &body).unwrap_err();
        assert!(
            e.starts_with("has a value of metadata claiming 2147483648"),
            "{e}"
        );
        // a chunk's compression
        let mut chunk = vec![0u8; 28];
        chunk.extend(u32::MAX.to_le_bytes());
        let e = check(op::CHUNK, &chunk).unwrap_err();
        assert!(
            e.starts_with("has a compression claiming 4294967295"),
            "{e}"
        );
        // a schema's name, a chunk index's compression, metadata's name
        let e = check(op::SCHEMA, &[0, 0, 9, 0, 0, 0]).unwrap_err();
        assert!(e.starts_with("has a name claiming 9 bytes"), "{e}");
        let mut index = vec![0u8; 32];
        index.extend(0u32.to_le_bytes());
        index.extend(0u64.to_le_bytes());
        index.extend(5u32.to_le_bytes());
        let e = check(op::CHUNK_INDEX, &index).unwrap_err();
        assert!(e.starts_with("has a compression claiming 5"), "{e}");
        let e = check(op::METADATA, &u32::MAX.to_le_bytes()).unwrap_err();
        assert!(e.starts_with("has a name claiming"), "{e}");
        // a record cut in its fixed fields
        assert_eq!(
            check(op::CHANNEL, &[1, 0, 0]),
            Err("is 3 bytes, cut in its ids (at byte 0 of the record)".into())
        );
    }

    /// An attachment that ends right after its data length: `mcap::parse_record`
    /// slices it backwards and panics.
    #[test]
    fn an_attachment_without_room_for_its_crc_is_refused_not_parsed() {
        let mut body = vec![0u8; 16];
        body.extend(string(b"n"));
        body.extend(string(b"m"));
        body.extend(0u64.to_le_bytes());
        let e = parse_record(op::ATTACHMENT, &body).unwrap_err();
        assert!(e.contains("cut in its CRC"), "{e}");
        body.extend(0u32.to_le_bytes());
        assert!(matches!(
            parse_record(op::ATTACHMENT, &body),
            Ok(Record::Attachment { .. })
        ));
    }

    #[test]
    fn a_message_header_is_read_by_hand() {
        let mut body = vec![3, 0];
        body.extend(7u32.to_le_bytes());
        body.extend(10u64.to_le_bytes());
        body.extend(11u64.to_le_bytes());
        body.extend(b"data");
        let (h, data) = parse_message(&body).unwrap();
        assert_eq!(
            (h.channel_id, h.sequence, h.log_time, h.publish_time, data),
            (3, 7, 10, 11, &b"data"[..])
        );
        assert_eq!(message_channel(&body), Some(3));
        assert_eq!(message_channel(&[1]), None);
        assert_eq!(
            parse_message(&body[..21]).unwrap_err(),
            "is 21 bytes, shorter than a message's 22-byte header"
        );
    }

    proptest::proptest! {
        /// Whatever the bytes, a record that passes the check parses without a
        /// panic, and none reserves more than its body.
        #[test]
        fn checked_records_never_panic(opcode in 1u8..16, body in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..80)) {
            let _ = parse_record(opcode, &body);
        }
    }
}
