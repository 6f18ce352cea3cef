//! Chunk decompression.
//!
//! The `mcap` crate's built-in `zstd` and `lz4` decoders bind the C libraries
//! (`zstd-sys`, `lz4-sys`); this crate builds `mcap` without them, so only
//! uncompressed chunks are read. A compressed chunk is an error naming its
//! compression. rosbag2's MCAP storage can compress chunks (zstd, depending on
//! its storage preset and version); convert such a file first, e.g. with the
//! `mcap` CLI (`mcap compress --compression none`) or `ros2 bag convert`.

use mcap::sans_io::indexed_reader::IndexedReader;
use mcap::sans_io::linear_reader::LinearReader;
use mcap::McapResult;

/// Appended to an "unsupported compression" error.
pub const UNSUPPORTED_HINT: &str =
    " (this build reads uncompressed chunks only; decompress the file first, e.g. `mcap compress --compression none`)";

/// Registers this crate's decompressors on a linear reader.
pub(crate) fn register_linear(_reader: &mut LinearReader) -> McapResult<()> {
    Ok(())
}

/// Registers this crate's decompressors on an indexed reader.
pub(crate) fn register_indexed(_reader: &mut IndexedReader) -> McapResult<()> {
    Ok(())
}
