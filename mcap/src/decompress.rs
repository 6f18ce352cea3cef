//! Chunk decompression, pure Rust.
//!
//! The `mcap` crate's built-in `zstd` and `lz4` decoders bind the C libraries
//! (`zstd-sys`, `lz4-sys`); this crate builds `mcap` without them and registers
//! its own decoders for the two compressions the MCAP specification names:
//!
//! * `zstd`: Zstandard frames (skippable frames skipped), decoded by `ruzstd`;
//! * `lz4`: LZ4 frames (skippable frames skipped), decoded by `lz4_flex`; frames
//!   whose declared block buffers add up to far more than the chunk's size
//!   (`lz4_buffer_budget`) are refused, as each costs a clear of its buffer;
//! * `""`: uncompressed.
//!
//! rosbag2's MCAP storage compresses chunks with zstd by default in several
//! releases, so both matter for real recordings. Any other compression string
//! is an error naming it. A chunk decodes to at most
//! [`crate::ReaderOptions::max_record_bytes`].
//!
//! Each decoder takes a whole chunk at once, and its output grows with what the
//! frames hold, never with a size a header claims. Through the index, the
//! `mcap` crate's reader sizes its buffer by the chunk index's uncompressed
//! size, so `check_size` first decodes the chunk into nothing and refuses it
//! unless it holds exactly that (a lie costs a decode, not the memory); the
//! decoders registered on that reader then decode it for real. Reading
//! linearly (`linear.rs`), `decode_chunk` decodes each chunk once, with
//! the same check.

use mcap::sans_io::decompressor::{DecompressResult, Decompressor};
use mcap::sans_io::indexed_reader::IndexedReader;
use mcap::{McapError, McapResult};
use std::io::{Read, Write};

/// Magic numbers of LZ4 skippable frames (LZ4 frame format, "Skippable frames").
const LZ4_SKIPPABLE_MAGIC: std::ops::RangeInclusive<u32> = 0x184D_2A50..=0x184D_2A5F;

/// The most the LZ4 frames of a chunk of `src_len` bytes that may hold `limit`
/// bytes may declare in block buffers (see [`lz4_block_buffer`]). The decoder
/// zeroes a frame's block buffer (up to 4 MiB, 8 MiB for a legacy frame) as the
/// frame's first block starts, so a chunk of tiny frames declaring big blocks
/// costs 4 MiB of work per 17 bytes. The budget is one frame of any block size
/// (8 MiB: a chunk is one frame as the MCAP writers write it, and its cost is
/// that of reading the chunk at all) plus 8 bytes a byte of the chunk's size,
/// compressed or declared, whichever is larger: any frames that fill an eighth of
/// their blocks. It was 1 GiB plus that, granted afresh to every chunk, so a file
/// of small chunks of tiny frames cost 1 GiB of clearing per 4 KB chunk. A chunk
/// that declares more than it holds is refused after its frames, and the read
/// ends there: only one chunk's declared size can be a lie.
fn lz4_buffer_budget(src_len: u64, limit: u64) -> u64 {
    (8u64 << 20).saturating_add(src_len.max(limit).saturating_mul(8))
}

/// The block buffer the LZ4 decoder clears for the frame at the start of `rest`:
/// the maximum block size its descriptor declares (8 MiB for a legacy frame), 0
/// where no frame starts (the decoder refuses it).
fn lz4_block_buffer(rest: &[u8]) -> u64 {
    match rest
        .get(..4)
        .map(|m| u32::from_le_bytes([m[0], m[1], m[2], m[3]]))
    {
        // magic, FLG, then BD: the block maximum size in bits 4-6
        Some(0x184D_2204) => match rest.get(5).map(|bd| (bd >> 4) & 7) {
            Some(4) => 64 << 10,
            Some(5) => 256 << 10,
            Some(6) => 1 << 20,
            Some(7) => 4 << 20,
            _ => 0,
        },
        Some(0x184C_2102) => 8 << 20,
        _ => 0,
    }
}

/// Appended to an "unsupported compression" error.
pub const UNSUPPORTED_HINT: &str = " (supported chunk compressions: none, zstd, lz4)";

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Codec {
    Zstd,
    Lz4,
}

/// Why frames did not decode.
#[derive(Debug, Clone, PartialEq, Eq)]
enum DecodeError {
    /// They hold more than the limit.
    TooBig,
    /// They are not valid frames of the codec (the decoder's message).
    Invalid(String),
}

impl From<String> for DecodeError {
    fn from(e: String) -> Self {
        DecodeError::Invalid(e)
    }
}

impl From<&str> for DecodeError {
    fn from(e: &str) -> Self {
        DecodeError::Invalid(e.to_string())
    }
}

/// Decodes all frames of `src`, appending to `out`; at most `limit` bytes in all.
/// The output grows with what the frames actually hold, never with a size a
/// header claims. Returns the bytes written.
fn decode_all<W: Write>(
    codec: Codec,
    src: &[u8],
    out: &mut W,
    limit: u64,
) -> Result<u64, DecodeError> {
    let mut written = 0u64;
    // copies at most one byte beyond the room left, which tells "too big" from "exact"
    let mut copy = |r: &mut dyn Read, written: &mut u64| -> Result<(), DecodeError> {
        let room = limit.saturating_sub(*written);
        let n =
            std::io::copy(&mut r.take(room.saturating_add(1)), out).map_err(|e| e.to_string())?;
        *written += n;
        if *written > limit {
            return Err(DecodeError::TooBig);
        }
        Ok(())
    };
    match codec {
        Codec::Lz4 => {
            // `FrameDecoder` ends quietly at each frame's end mark and starts the next
            // frame when read again: one decoder for them all keeps its buffers (a
            // new one per frame would allocate and fault in up to 12 MiB each)
            let mut s = src;
            let mut d = lz4_flex::frame::FrameDecoder::new(&mut s);
            let budget = lz4_buffer_budget(src.len() as u64, limit);
            let mut buffers = 0u64;
            loop {
                // between frames: the decoder holds nothing of the next one yet
                let rest: &[u8] = d.get_ref();
                if rest.is_empty() {
                    break;
                }
                let magic = rest
                    .get(..4)
                    .map(|m| u32::from_le_bytes([m[0], m[1], m[2], m[3]]));
                if magic.is_some_and(|m| LZ4_SKIPPABLE_MAGIC.contains(&m)) {
                    // magic, little-endian length, then `length` bytes
                    let length = rest
                        .get(4..8)
                        .map(|l| u32::from_le_bytes([l[0], l[1], l[2], l[3]]))
                        .ok_or("skippable lz4 frame is truncated")?;
                    let n = usize::try_from(length).unwrap_or(usize::MAX);
                    **d.get_mut() = rest
                        .get(n.saturating_add(8)..)
                        .ok_or("skippable lz4 frame runs past the chunk")?;
                    continue;
                }
                buffers = buffers.saturating_add(lz4_block_buffer(rest));
                if buffers > budget {
                    return Err(format!(
                        "its frames declare {buffers} bytes of block buffers, over the {budget} \
                         a chunk of {} bytes holding at most {limit} may (8 MiB, one frame's \
                         largest, plus 8 times the larger size: the decoder clears each \
                         frame's buffer as the frame starts)",
                        src.len()
                    )
                    .into());
                }
                copy(&mut d, &mut written)?;
                // a frame read is a frame consumed: stop rather than spin if not
                if d.get_ref().len() == rest.len() {
                    return Err("lz4 decoder made no progress".into());
                }
            }
        }
        Codec::Zstd => {
            use ruzstd::decoding::errors::{FrameDecoderError, ReadFrameHeaderError};
            let mut s = src;
            while !s.is_empty() {
                let frame_start = s;
                match ruzstd::decoding::StreamingDecoder::new(&mut s) {
                    Ok(mut d) => {
                        copy(&mut d, &mut written)?;
                        // ruzstd ends quietly at the end of its input
                        if !d.decoder.is_finished() {
                            return Err("zstd frame is truncated".into());
                        }
                    }
                    Err(FrameDecoderError::ReadFrameHeaderError(
                        ReadFrameHeaderError::SkipFrame { length, .. },
                    )) => {
                        // magic, length, then `length` bytes
                        let n = usize::try_from(length).unwrap_or(usize::MAX);
                        s = frame_start
                            .get(n.saturating_add(8)..)
                            .ok_or("skippable zstd frame runs past the chunk")?;
                    }
                    Err(e) => return Err(e.to_string().into()),
                }
            }
        }
    }
    Ok(written)
}

fn codec(compression: &str) -> Option<Codec> {
    match compression {
        "zstd" => Some(Codec::Zstd),
        "lz4" => Some(Codec::Lz4),
        _ => None,
    }
}

/// Why a chunk's content cannot be used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum ChunkError {
    /// A compression this crate does not decode (the name).
    Unsupported(String),
    /// The content is corrupt or disagrees with the chunk's header.
    Corrupt(String),
}

/// Checks that a compressed chunk decodes to exactly the `uncompressed_size` its
/// header (or chunk index) declares, at most `limit`, without keeping the output:
/// the indexed reader sizes its buffer by that declaration, so it is checked
/// before the reader sees the chunk (a lie costs one decode, not the memory).
/// Returns the CRC-32 of the decoded records, for the chunk header's CRC.
pub(crate) fn check_size(
    compression: &str,
    src: &[u8],
    uncompressed_size: u64,
    limit: usize,
) -> Result<u32, ChunkError> {
    const BY: &str = "its chunk index";
    if compression.is_empty() {
        exact(src.len() as u64, uncompressed_size, "uncompressed", BY)?;
        return Ok(crc32fast::hash(src));
    }
    let c = codec(compression).ok_or_else(|| ChunkError::Unsupported(compression.to_string()))?;
    let cap = declared_within(uncompressed_size, limit, BY)?;
    let mut crc = CrcSink(crc32fast::Hasher::new());
    let n = decode_all(c, src, &mut crc, cap).map_err(|e| declared_err(e, compression, cap, BY))?;
    exact(n, uncompressed_size, compression, BY)?;
    Ok(crc.0.finalize())
}

/// A writer that keeps only the CRC of what it is given.
struct CrcSink(crc32fast::Hasher);

impl Write for CrcSink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.update(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The records of a chunk, decoded into `out` (cleared first): a copy of `src` when
/// uncompressed (whatever its header's uncompressed size says: the records are
/// there, and the buffer is no bigger than they are), else its frames, which must
/// hold exactly `uncompressed_size` bytes (at most `limit`).
pub(crate) fn decode_chunk(
    compression: &str,
    src: &[u8],
    uncompressed_size: u64,
    limit: usize,
    out: &mut Vec<u8>,
) -> Result<(), ChunkError> {
    const BY: &str = "its header";
    out.clear();
    if compression.is_empty() {
        out.extend_from_slice(src);
        return Ok(());
    }
    let c = codec(compression).ok_or_else(|| ChunkError::Unsupported(compression.to_string()))?;
    let cap = declared_within(uncompressed_size, limit, BY)?;
    let r = decode_all(c, src, out, cap).map_err(|e| declared_err(e, compression, cap, BY));
    let n = match r {
        Ok(n) => n,
        Err(e) => {
            out.clear();
            return Err(e);
        }
    };
    exact(n, uncompressed_size, compression, BY)
}

/// What a compressed chunk cut by the end of the file decodes to before the cut, into
/// `out` (cleared first): its frames' complete blocks, at most `uncompressed_size`
/// and `limit` bytes; nothing for a compression this crate does not decode. The
/// caller keeps only the complete records of it (their CRC cannot be checked: it
/// covers the whole chunk).
pub(crate) fn decode_cut_chunk(
    compression: &str,
    src: &[u8],
    uncompressed_size: u64,
    limit: usize,
    out: &mut Vec<u8>,
) {
    out.clear();
    let Some(c) = codec(compression) else {
        return;
    };
    let cap = uncompressed_size.min(limit as u64);
    // the decoders write each block as they finish it, so the error at the cut
    // leaves the blocks before it in `out`
    if decode_all(c, src, out, cap).is_err() {
        out.truncate(usize::try_from(cap).unwrap_or(usize::MAX));
    }
}

fn declared_within(uncompressed_size: u64, limit: usize, by: &str) -> Result<u64, ChunkError> {
    if uncompressed_size > limit as u64 {
        return Err(ChunkError::Corrupt(format!(
            "{by} declares {uncompressed_size} uncompressed bytes, over the limit of {limit} \
             a record may have here (a bound of this reader, not of the format: a recording \
             written with smaller chunks reads)"
        )));
    }
    Ok(uncompressed_size)
}

fn declared_err(e: DecodeError, compression: &str, cap: u64, by: &str) -> ChunkError {
    ChunkError::Corrupt(match e {
        DecodeError::TooBig => {
            format!("the {compression} chunk decodes to more than the {cap} bytes {by} declares")
        }
        DecodeError::Invalid(e) => format!("{compression}: {e}"),
    })
}

fn exact(n: u64, declared: u64, what: &str, by: &str) -> Result<(), ChunkError> {
    if n != declared {
        return Err(ChunkError::Corrupt(format!(
            "the {what} chunk holds {n} bytes, {by} declares {declared}"
        )));
    }
    Ok(())
}

/// A whole-chunk decoder for one codec (see the module docs).
struct WholeChunk {
    codec: Codec,
    limit: u64,
    out: Vec<u8>,
    pos: usize,
}

impl WholeChunk {
    fn new(codec: Codec, limit: usize) -> Self {
        Self {
            codec,
            limit: limit as u64,
            out: Vec::new(),
            pos: 0,
        }
    }
}

impl Decompressor for WholeChunk {
    fn next_read_size(&self) -> usize {
        if self.pos == self.out.len() {
            // all of the chunk (the reader caps this at what the chunk has left)
            usize::MAX
        } else {
            0
        }
    }

    fn decompress(&mut self, src: &[u8], dst: &mut [u8]) -> McapResult<DecompressResult> {
        let mut consumed = 0;
        if self.pos == self.out.len() && !src.is_empty() {
            self.out.clear();
            self.pos = 0;
            match decode_all(self.codec, src, &mut self.out, self.limit) {
                Ok(_) => consumed = src.len(),
                Err(e) => {
                    self.out.clear();
                    let e = match e {
                        DecodeError::TooBig => {
                            format!(
                                "decompressed chunk exceeds the limit of {} bytes",
                                self.limit
                            )
                        }
                        DecodeError::Invalid(e) => e,
                    };
                    return Err(McapError::DecompressionError(format!(
                        "{}: {e}",
                        self.name()
                    )));
                }
            }
        }
        let n = dst.len().min(self.out.len() - self.pos);
        dst[..n].copy_from_slice(&self.out[self.pos..self.pos + n]);
        self.pos += n;
        Ok(DecompressResult { consumed, wrote: n })
    }

    fn reset(&mut self) -> McapResult<()> {
        self.out.clear();
        self.pos = 0;
        Ok(())
    }

    fn name(&self) -> &'static str {
        match self.codec {
            Codec::Zstd => "zstd",
            Codec::Lz4 => "lz4",
        }
    }
}

/// Registers this crate's decompressors on an indexed reader.
pub(crate) fn register_indexed(reader: &mut IndexedReader, limit: usize) -> McapResult<()> {
    reader.add_decompressor(WholeChunk::new(Codec::Zstd, limit))?;
    reader.add_decompressor(WholeChunk::new(Codec::Lz4, limit))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::io::Write;

    pub(crate) fn zstd(data: &[u8]) -> Vec<u8> {
        ruzstd::encoding::compress_to_vec(data, ruzstd::encoding::CompressionLevel::Fastest)
    }

    pub(crate) fn lz4(data: &[u8]) -> Vec<u8> {
        let mut e = lz4_flex::frame::FrameEncoder::new(Vec::new());
        e.write_all(data).unwrap();
        e.finish().unwrap()
    }

    /// Feeds the whole chunk, then takes the output in small pieces, like the readers.
    fn drive(d: &mut WholeChunk, src: &[u8], size: usize) -> McapResult<Vec<u8>> {
        assert_eq!(d.next_read_size(), usize::MAX);
        let mut out = vec![0u8; size];
        let mut o = 0;
        let mut src = src;
        while o < size {
            let r = d.decompress(src, &mut out[o..(o + 1000).min(size)])?;
            if r.consumed == 0 && r.wrote == 0 {
                return Err(McapError::DecompressionError("no progress".into()));
            }
            src = &src[r.consumed..];
            o += r.wrote;
        }
        d.reset()?;
        Ok(out)
    }

    #[test]
    fn both_codecs() {
        let data: Vec<u8> = (0..5000u32).map(|i| (i * 7 % 251) as u8).collect();
        // two zstd frames with a skippable frame between them, like a chunk may hold
        let mut z = zstd(&data[..3000]);
        z.extend_from_slice(&0x184D_2A50u32.to_le_bytes());
        z.extend_from_slice(&3u32.to_le_bytes());
        z.extend_from_slice(&[1, 2, 3]);
        z.extend_from_slice(&zstd(&data[3000..]));
        let l = lz4(&data);
        for (codec, src) in [(Codec::Zstd, &z), (Codec::Lz4, &l)] {
            let mut d = WholeChunk::new(codec, 1 << 20);
            assert_eq!(drive(&mut d, src, data.len()).unwrap(), data, "{codec:?}");
            // the same instance decodes the next chunk after reset
            assert_eq!(drive(&mut d, src, data.len()).unwrap(), data);
        }
    }

    #[test]
    fn errors_and_limits() {
        let data = vec![7u8; 10_000];
        let mut d = WholeChunk::new(Codec::Zstd, 1000);
        let e = d.decompress(&zstd(&data), &mut [0; 10]).unwrap_err();
        assert!(
            e.to_string().contains("exceeds the limit of 1000 bytes"),
            "{e}"
        );
        let mut d = WholeChunk::new(Codec::Lz4, 1 << 20);
        let e = d.decompress(b"not lz4 at all", &mut [0; 10]).unwrap_err();
        assert!(e.to_string().contains("lz4"), "{e}");
        // truncated frames never yield the whole chunk (a cut inside lz4's 4-byte
        // end mark loses no data and is not an error)
        let mut x = 1u32;
        let data: Vec<u8> = (0..10_000)
            .map(|_| {
                x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (x >> 24) as u8
            })
            .collect();
        for (codec, c) in [(Codec::Zstd, zstd(&data)), (Codec::Lz4, lz4(&data))] {
            for cut in [5, 9, 20] {
                let mut d = WholeChunk::new(codec, 1 << 20);
                assert!(
                    drive(&mut d, &c[..c.len() - cut], data.len()).is_err(),
                    "{codec:?} {cut}"
                );
            }
        }
    }

    /// An LZ4 skippable frame with magic `0x184D2A50 + nibble` and `len` bytes.
    fn lz4_skippable(nibble: u32, len: usize) -> Vec<u8> {
        let mut f = (0x184D_2A50 + nibble).to_le_bytes().to_vec();
        f.extend_from_slice(&(len as u32).to_le_bytes());
        f.extend((0..len).map(|i| i as u8));
        f
    }

    #[test]
    fn an_lz4_chunk_of_several_frames_or_with_skippable_frames_decodes_whole() {
        let data: Vec<u8> = (0..5000u32).map(|i| (i * 7 % 251) as u8).collect();
        let two = [lz4(&data[..3000]), lz4(&data[3000..])].concat();
        let skip_first = [lz4_skippable(0, 12), lz4(&data)].concat();
        let mixed = [
            lz4_skippable(0xF, 0),
            lz4(&data[..1]),
            lz4(&[]),
            lz4_skippable(7, 300),
            lz4(&data[1..4000]),
            lz4(&data[4000..]),
            lz4_skippable(3, 5),
        ]
        .concat();
        for (what, src) in [
            ("two", &two),
            ("skip_first", &skip_first),
            ("mixed", &mixed),
        ] {
            let n = data.len() as u64;
            assert_eq!(
                check_size("lz4", src, n, 1 << 20),
                Ok(crc32fast::hash(&data)),
                "{what}"
            );
            let mut out = Vec::new();
            assert_eq!(
                decode_chunk("lz4", src, n, 1 << 20, &mut out),
                Ok(()),
                "{what}"
            );
            assert_eq!(out, data, "{what}");
            let mut d = WholeChunk::new(Codec::Lz4, 1 << 20);
            assert_eq!(drive(&mut d, src, data.len()).unwrap(), data, "{what}");
        }
        // a skippable frame cut short is corrupt, as in zstd
        for (cut, want) in [
            (
                lz4_skippable(0, 10)[..6].to_vec(),
                "skippable lz4 frame is truncated",
            ),
            (
                lz4_skippable(0, 10)[..17].to_vec(),
                "skippable lz4 frame runs past the chunk",
            ),
        ] {
            let src = [lz4(&data), cut].concat();
            assert_eq!(
                check_size("lz4", &src, 5000, 1 << 20),
                Err(ChunkError::Corrupt(format!("lz4: {want}")))
            );
        }
    }

    #[test]
    fn lz4_frames_after_the_first_are_held_to_the_declared_size_and_the_limit() {
        let data = vec![7u8; 1000];
        // the first frame holds exactly what is declared, the second 64 MiB more
        let bomb = [lz4(&data), lz4(&vec![0u8; 64 << 20])].concat();
        assert!(bomb.len() < 1 << 20, "{}", bomb.len());
        let want = "the lz4 chunk decodes to more than the 1000 bytes BY declares";
        assert_eq!(
            check_size("lz4", &bomb, 1000, 256 << 20),
            Err(ChunkError::Corrupt(want.replace("BY", "its chunk index")))
        );
        let mut out = Vec::new();
        assert_eq!(
            decode_chunk("lz4", &bomb, 1000, 256 << 20, &mut out),
            Err(ChunkError::Corrupt(want.replace("BY", "its header")))
        );
        // the output never grew toward what the frames hold
        assert!(out.capacity() < 1 << 20, "{}", out.capacity());
        let mut d = WholeChunk::new(Codec::Lz4, 4096);
        let e = d.decompress(&bomb, &mut [0; 10]).unwrap_err();
        assert!(
            e.to_string()
                .contains("lz4: decompressed chunk exceeds the limit of 4096 bytes"),
            "{e}"
        );
        // and behind a skippable frame
        let bomb = [lz4_skippable(0, 3), bomb].concat();
        let e = d.decompress(&bomb, &mut [0; 10]).unwrap_err();
        assert!(
            e.to_string().contains("exceeds the limit of 4096 bytes"),
            "{e}"
        );
    }

    /// `n` LZ4 frames of 100 zero bytes each (a compressed block) with `block_size`.
    fn tiny_lz4_frames(block_size: lz4_flex::frame::BlockSize, n: usize) -> Vec<u8> {
        let mut info = lz4_flex::frame::FrameInfo::new();
        info.block_size = block_size;
        let mut e = lz4_flex::frame::FrameEncoder::with_frame_info(info, Vec::new());
        e.write_all(&[0u8; 100]).unwrap();
        e.finish().unwrap().repeat(n)
    }

    #[test]
    fn tiny_lz4_frames_declaring_big_blocks_are_refused_before_they_cost_seconds() {
        use lz4_flex::frame::BlockSize;
        // each of these costs the decoder a 4 MiB clear: 10 000 took over 2 s
        let n = 10_000;
        let src = tiny_lz4_frames(BlockSize::Max4MB, n);
        assert!(src.len() < 1 << 20, "{}", src.len());
        let declared = 100 * n as u64;
        let e = check_size("lz4", &src, declared, 256 << 20).unwrap_err();
        let ChunkError::Corrupt(e) = e else {
            panic!("{e:?}")
        };
        assert_eq!(
            e,
            format!(
                "lz4: its frames declare 16777216 bytes of block buffers, over the 16388608 a \
                 chunk of {} bytes holding at most 1000000 may (8 MiB, one frame's largest, \
                 plus 8 times the larger size: the decoder clears each frame's buffer as the \
                 frame starts)",
                src.len()
            )
        );
        // (refused at the 4th frame, after 12 MiB of clearing)
        // frames with 64 KiB blocks, the common default, that fill an eighth of them
        let frames: Vec<u8> = (0..100).flat_map(|_| lz4(&[5u8; 8 << 10])).collect();
        let mut out = Vec::new();
        assert_eq!(
            decode_chunk("lz4", &frames, 100 * (8 << 10), 256 << 20, &mut out),
            Ok(())
        );
        assert_eq!(out, vec![5u8; 100 * (8 << 10)]);
        // and big blocks that frames fill an eighth of
        let chunk: Vec<u8> = (0..4).flat_map(|_| lz4(&vec![1u8; 512 << 10])).collect();
        assert_eq!(lz4_block_buffer(&chunk), 4 << 20);
        assert_eq!(
            check_size("lz4", &chunk, 2 << 20, 256 << 20),
            Ok(crc32fast::hash(&vec![1u8; 2 << 20]))
        );
    }

    /// The budget scales with the chunk: 1 GiB was granted afresh to every chunk, so
    /// a file of small chunks of tiny frames cost 1 GiB of clearing per chunk of a
    /// few KB (these 200 frames, 800 MiB of buffers, were read).
    #[test]
    fn a_small_chunk_gets_the_clearing_of_its_size_not_a_gib() {
        use lz4_flex::frame::BlockSize;
        let src = tiny_lz4_frames(BlockSize::Max4MB, 200);
        assert!(src.len() < 8 << 10, "{}", src.len());
        let e = check_size("lz4", &src, 200 * 100, 256 << 20).unwrap_err();
        assert!(
            matches!(&e, ChunkError::Corrupt(r) if r.contains("declare 12582912 bytes of block buffers")),
            "{e:?}"
        );
        let mut out = Vec::new();
        assert!(decode_chunk("lz4", &src, 200 * 100, 256 << 20, &mut out).is_err());
        // however small the chunk, one or two frames of the largest blocks read (the
        // MCAP writers write a chunk as one frame; Go's lz4 writes 4 MiB blocks)
        for n in [1, 2] {
            let src = tiny_lz4_frames(BlockSize::Max4MB, n);
            assert_eq!(
                check_size("lz4", &src, 100 * n as u64, 256 << 20),
                Ok(crc32fast::hash(&vec![0u8; 100 * n])),
                "{n}"
            );
        }
    }

    #[test]
    fn a_chunk_must_hold_what_its_header_declares() {
        let data: Vec<u8> = (0..5000u32).map(|i| (i % 7) as u8).collect();
        for (name, src) in [("zstd", zstd(&data)), ("lz4", lz4(&data))] {
            let n = data.len() as u64;
            assert_eq!(
                check_size(name, &src, n, 1 << 20),
                Ok(crc32fast::hash(&data))
            );
            let mut out = Vec::new();
            assert_eq!(decode_chunk(name, &src, n, 1 << 20, &mut out), Ok(()));
            assert_eq!(out, data);
            // a header (or chunk index) that lies either way, or declares more than the limit
            for (declared, limit, want) in [
                (
                    n + 1,
                    1 << 20,
                    format!("the {name} chunk holds 5000 bytes, BY declares 5001"),
                ),
                (
                    n - 1,
                    1 << 20,
                    format!("the {name} chunk decodes to more than the 4999 bytes BY declares"),
                ),
                (
                    (1 << 30) - 1,
                    1 << 30,
                    format!("the {name} chunk holds 5000 bytes, BY declares 1073741823"),
                ),
                (
                    n,
                    100,
                    "BY declares 5000 uncompressed bytes, over the limit of 100 a record may have \
                     here (a bound of this reader, not of the format: a recording written with \
                     smaller chunks reads)"
                        .to_string(),
                ),
            ] {
                assert_eq!(
                    check_size(name, &src, declared, limit),
                    Err(ChunkError::Corrupt(want.replace("BY", "its chunk index")))
                );
                assert_eq!(
                    decode_chunk(name, &src, declared, limit, &mut out),
                    Err(ChunkError::Corrupt(want.replace("BY", "its header")))
                );
                assert!(out.is_empty() || out.len() as u64 == n.min(declared));
                // the output never grew toward the declared size
                assert!(out.capacity() < 1 << 20, "{}", out.capacity());
            }
        }
        let mut out = Vec::new();
        assert_eq!(decode_chunk("", b"abc", 3, 10, &mut out), Ok(()));
        assert_eq!(check_size("", b"abc", 3, 10), Ok(crc32fast::hash(b"abc")));
        // uncompressed: the records are what the chunk holds, whatever its header says
        assert_eq!(decode_chunk("", b"abc", 4, 10, &mut out), Ok(()));
        assert_eq!(out, b"abc");
        assert_eq!(
            check_size("", b"abc", 4, 10),
            Err(ChunkError::Corrupt(
                "the uncompressed chunk holds 3 bytes, its chunk index declares 4".into()
            ))
        );
        assert_eq!(
            check_size("bz2", b"abc", 3, 10),
            Err(ChunkError::Unsupported("bz2".into()))
        );
    }

    proptest! {
        #[test]
        fn arbitrary_input_never_panics(src in proptest::collection::vec(any::<u8>(), 0..300),
                                        zstd_magic in any::<bool>()) {
            let mut s = if zstd_magic { vec![0x28, 0xB5, 0x2F, 0xFD] } else { vec![0x04, 0x22, 0x4D, 0x18] };
            s.extend_from_slice(&src);
            for codec in [Codec::Zstd, Codec::Lz4] {
                let mut d = WholeChunk::new(codec, 1 << 16);
                let _ = d.decompress(&s, &mut [0u8; 64]);
                let _ = d.decompress(&src, &mut [0u8; 64]);
                let _ = d.reset();
            }
        }

        #[test]
        fn round_trips(data in proptest::collection::vec(any::<u8>(), 1..2000)) {
            for (codec, src) in [(Codec::Zstd, zstd(&data)), (Codec::Lz4, lz4(&data))] {
                let mut d = WholeChunk::new(codec, 1 << 20);
                prop_assert_eq!(drive(&mut d, &src, data.len()).unwrap(), data.clone());
            }
        }
    }
}
