//! Slamtec RPLIDAR standard scan protocol (A1/A2/C1, command `SCAN`):
//! request bytes, streaming resynchronising node parser, scan assembly, encoder.
//!
//! # Protocol
//!
//! * Requests: `A5 20` starts a standard scan ([`SCAN_REQUEST`]), `A5 25`
//!   stops it ([`STOP_REQUEST`]).
//! * The device answers with the response descriptor
//!   `A5 5A 05 00 00 40 81` ([`SCAN_DESCRIPTOR`]: 5-byte nodes, multiple
//!   response, type 0x81), then streams 5-byte nodes:
//!
//! | byte | content |
//! |---|---|
//! | 0 | `quality << 2 \| !S << 1 \| S` — S = 1 on the first node of a new revolution |
//! | 1 | `angle_q6[6:0] << 1 \| C`, check bit C = 1 |
//! | 2 | `angle_q6[14:7]` |
//! | 3, 4 | `distance_q2`, little-endian |
//!
//! angle = `angle_q6 / 64` degrees (clockwise), distance = `distance_q2 / 4`
//! mm (0 = no return).
//!
//! Sources checked (no code copied): Slamtec's SDK
//! (`sl_lidar_driver.cpp`, the standard-scan node wait: byte 0 must have
//! `S != !S`, byte 1 must have the check bit set, otherwise the parser drops
//! back and continues), the node layout and constants as in
//! `cnwzhjs/rplidar.rs` (`rplidar_drv/src/answers.rs`:
//! `RPLIDAR_RESP_MEASUREMENT_SYNCBIT`, `..._CHECKBIT`, `..._ANGLE_SHIFT = 1`,
//! `..._QUALITY_SHIFT = 2`, answer type 0x81), and the RPLIDAR interface
//! protocol description.
//!
//! # What the parser validates
//!
//! For every node: `S` and `!S` differ, `C` is 1, `angle_q6 ≤ 360·64`. A node
//! failing a check is dropped by one byte and the stream is rescanned from the
//! next byte (as the SDK does), so a corrupted or truncated node costs at
//! most itself and garbage costs nothing but its own bytes. The checks are
//! weak (two bits and a range; there is no checksum), so a start flag is
//! only honoured after more than half a turn, back near the angle the
//! revolution began at; [`RplidarStats::false_starts`] counts the others.
//! A lost flagged node is made up for: a valid node (one with a return: the
//! SDK does not trust the angles of the others) that falls more than half a
//! turn behind the last valid one starts the next revolution
//! ([`RplidarStats::implicit_starts`]), unless that one had jumped far beyond
//! every node before it: a misread angle, forgotten
//! ([`RplidarStats::stray_nodes`]); a revolution so started ends at the next
//! flag after half a turn, wherever it began.
//!
//! A turn that cannot be split is dropped, never timed as one. Every node, with
//! a return or not, counts towards the angle the revolution swept (the steps
//! between consecutive nodes, each taken the short way round, up to the next
//! revolution's first node: 360° for one turn, whatever angle it began at; a
//! single misread angle in it adds nothing). A revolution that swept more than
//! one and a half turns (two turns whose start could not be found), or less
//! than half a turn (one begun at a misread angle, which its rays' times would
//! be interpolated from), is dropped ([`RplidarStats::wrong_turns`]), as is one
//! whose nodes reached more than [`MAX_ONE_TURN_DEG`] (a turn and 20°) along
//! their path, a jump counting only once the node after it follows (a turn and
//! the part of the next before a start made up late, where the nodes after a
//! lost flag have no return). A revolution whose period (scaled to a whole
//! turn) is over 1.5 times, or under two thirds of, the last good period is
//! dropped too, as is one over [`RplidarConfig::max_period_ns`] or not above 0
//! ([`RplidarStats::implausible_periods`]); the first is checked against
//! [`RplidarConfig::nominal_period_ns`], and the last good period is kept across
//! a drop: it is replaced by one outside those bounds only when two consecutive
//! revolutions agree on it (within a fifth), the second of which is then
//! kept (a motor that changed speed, or a nominal period that is not the
//! device's, costs one revolution). A response
//! descriptor anywhere in the stream is recognised (it can never pass as a
//! node: its byte 1 `0x5A` has C = 0) and restarts scan assembly. Every
//! failure is counted in [`RplidarStats`]; the latest is kept as an
//! [`RplidarError`] with its stream byte offset.
//!
//! # Timing
//!
//! Nodes carry no time: each revolution's first node (`S = 1`) is dated on the
//! host clock, from the `rx_ns` given with the chunk (the arrival of its last
//! byte). The device sends a node right after measuring it, 10 bits a byte
//! (start, 8 data, stop) at [`RplidarConfig::baud`], one node every
//! `1 / sample_rate_hz` s ([`RplidarConfig::sample_rate_hz`]; never faster than
//! the line carries them). So the node was measured at the arrival of its own
//! last byte less its own wire time (`5 · 10 / baud`, 0.43 ms at 115200 baud),
//! and the bytes after it in the chunk date that arrival: `n` whole nodes after
//! it put it `n` node intervals before the chunk's end; a trailing part of a
//! node (`m` bytes) arrived at 10 bits a byte after that node began to leave,
//! one node interval after the last whole one was measured. Only the host's
//! reading latency (scheduling, USB) is left, which no byte count can see. A
//! revolution is emitted when the next one starts: its period is the time
//! between the two starts, and each ray's time is interpolated from its
//! angle (`Δangle / 360 · period`, clockwise from the first node's angle).
//!
//! ```
//! use vlsync_signature_lidar::rplidar::{RplidarConfig, RplidarEncoder, RplidarParser, SCAN_DESCRIPTOR};
//! let mut enc = RplidarEncoder::new(360);
//! let mut bytes = SCAN_DESCRIPTOR.to_vec();
//! for _ in 0..3 { bytes.extend(enc.revolution(|_deg| 1500.0)); }
//! let mut parser = RplidarParser::new(RplidarConfig::default());
//! let mut scans = Vec::new();
//! parser.push(&bytes, 1_000_000_000, |s| scans.push(s.len()));
//! assert_eq!(scans, vec![360, 360]); // the third revolution ends when a fourth starts
//! assert_eq!(parser.stats().descriptors, 1);
//! ```

use crate::scan::{bearing_to_cw_degrees, cw_degrees_to_bearing, Ray, Rotation, Scan, ScanTiming};
use crate::serial::BITS_PER_BYTE;
use std::fmt;
use vlsync_common::Nanos;

/// Start-scan request.
pub const SCAN_REQUEST: [u8; 2] = [0xA5, 0x20];
/// Stop request.
pub const STOP_REQUEST: [u8; 2] = [0xA5, 0x25];
/// Response descriptor of the standard scan.
pub const SCAN_DESCRIPTOR: [u8; 7] = [0xA5, 0x5A, 0x05, 0x00, 0x00, 0x40, 0x81];
/// Node length in bytes.
pub const NODE_LEN: usize = 5;
/// Largest valid `angle_q6` (360°).
pub const MAX_ANGLE_Q6: u16 = 360 * 64;

/// Bytes of the start-scan request.
pub fn scan_request() -> [u8; 2] {
    SCAN_REQUEST
}

/// Bytes of the stop request.
pub fn stop_request() -> [u8; 2] {
    STOP_REQUEST
}

/// One measurement node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RplidarNode {
    /// First node of a new revolution.
    pub start: bool,
    /// Quality, 0-63 (0 = no return).
    pub quality: u8,
    /// Angle, 1/64 degree, clockwise.
    pub angle_q6: u16,
    /// Distance, 1/4 mm (0 = no return).
    pub distance_q2: u16,
}

/// Why bytes were rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RplidarErrorKind {
    /// Byte 0 of a node has `S == !S`.
    SyncBits {
        /// The byte.
        byte: u8,
    },
    /// Byte 1 of a node has the check bit clear.
    CheckBit {
        /// The byte.
        byte: u8,
    },
    /// `angle_q6` above 360°.
    AngleOutOfRange {
        /// The angle, 1/64 degree.
        angle_q6: u16,
    },
    /// Bytes `A5 5A` not followed by the rest of the scan descriptor.
    BadDescriptor {
        /// Index in the descriptor of the mismatch.
        index: usize,
        /// Byte found there.
        found: u8,
    },
}

impl fmt::Display for RplidarErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            RplidarErrorKind::SyncBits { byte } => write!(
                f,
                "node byte 0 = 0x{byte:02x}: start bit and inverted start bit agree"
            ),
            RplidarErrorKind::CheckBit { byte } => {
                write!(f, "node byte 1 = 0x{byte:02x}: check bit is 0")
            }
            RplidarErrorKind::AngleOutOfRange { angle_q6 } => {
                write!(f, "node angle {angle_q6}/64 deg is above 360 deg")
            }
            RplidarErrorKind::BadDescriptor { index, found } => write!(
                f,
                "response descriptor byte {index} is 0x{found:02x}, expected 0x{:02x}",
                SCAN_DESCRIPTOR[index.min(6)]
            ),
        }
    }
}

/// A rejection, located in the byte stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RplidarError {
    /// Offset in the stream of the first byte of the rejected node or descriptor.
    pub offset: u64,
    /// What was wrong.
    pub kind: RplidarErrorKind,
}

impl fmt::Display for RplidarError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "RPLIDAR stream, byte offset {}: {}",
            self.offset, self.kind
        )
    }
}

impl std::error::Error for RplidarError {}

impl RplidarNode {
    /// Decodes and validates 5 bytes.
    pub fn decode(b: &[u8; NODE_LEN]) -> Result<Self, RplidarErrorKind> {
        if (b[0] ^ (b[0] >> 1)) & 1 == 0 {
            return Err(RplidarErrorKind::SyncBits { byte: b[0] });
        }
        if b[1] & 1 == 0 {
            return Err(RplidarErrorKind::CheckBit { byte: b[1] });
        }
        let angle_q6 = ((b[2] as u16) << 7) | (b[1] as u16 >> 1);
        if angle_q6 > MAX_ANGLE_Q6 {
            return Err(RplidarErrorKind::AngleOutOfRange { angle_q6 });
        }
        Ok(Self {
            start: b[0] & 1 == 1,
            quality: b[0] >> 2,
            angle_q6,
            distance_q2: u16::from_le_bytes([b[3], b[4]]),
        })
    }

    /// Encodes the node (quality is truncated to 6 bits, angle to 15 bits).
    pub fn encode(&self) -> [u8; NODE_LEN] {
        let s = self.start as u8;
        let d = self.distance_q2.to_le_bytes();
        [
            (self.quality << 2) | ((1 - s) << 1) | s,
            ((self.angle_q6 & 0x7F) << 1) as u8 | 1,
            ((self.angle_q6 >> 7) & 0xFF) as u8,
            d[0],
            d[1],
        ]
    }

    /// Angle, degrees clockwise.
    pub fn angle_deg(&self) -> f64 {
        self.angle_q6 as f64 / 64.0
    }

    /// Distance, mm.
    pub fn distance_mm(&self) -> f64 {
        self.distance_q2 as f64 / 4.0
    }
}

/// Parser counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RplidarStats {
    /// Bytes pushed.
    pub bytes: u64,
    /// Valid nodes.
    pub nodes: u64,
    /// Bytes dropped while resynchronising.
    pub skipped_bytes: u64,
    /// Nodes rejected for their S / !S bits.
    pub sync_bit_errors: u64,
    /// Nodes rejected for their check bit.
    pub check_bit_errors: u64,
    /// Nodes rejected for their angle.
    pub angle_errors: u64,
    /// Response descriptors seen.
    pub descriptors: u64,
    /// Incomplete descriptors.
    pub descriptor_errors: u64,
    /// Valid nodes dropped because no revolution start had been seen yet.
    pub nodes_before_start: u64,
    /// Start flags ignored because the revolution before had not swept more
    /// than half a turn beyond the flagged node's angle (a corrupted or
    /// misframed node).
    pub false_starts: u64,
    /// Revolutions started without a start flag: a valid node fell more than
    /// half a turn behind the last valid one, so the flagged node was lost
    /// (without this the two revolutions would be timed as one).
    pub implicit_starts: u64,
    /// Valid nodes whose angle jumped over [`STRAY_JUMP_DEG`] beyond every node
    /// before them, the next valid node falling half a turn behind (a misread
    /// angle): forgotten by the revolution's bookkeeping, which would otherwise
    /// have started a revolution at the next node.
    pub stray_nodes: u64,
    /// Revolutions dropped because the time between their start and the next
    /// (scaled to a whole turn) was over 1.5 times the last good period (the
    /// nominal period before the first), or under two thirds of it (not a
    /// revolution of this motor), and the revolution before did not agree on it;
    /// or was over [`RplidarConfig::max_period_ns`] or not above 0 (the host's
    /// clock stepped back), whatever the revolution before.
    pub implausible_periods: u64,
    /// Revolutions dropped because their nodes (with a return or not) did not
    /// sweep one turn: more than one and a half (two turns whose start could not
    /// be found, the flagged node lost where no node has a return), never timed
    /// as one; or less than a half (a revolution begun at a misread angle); or
    /// reached more than [`MAX_ONE_TURN_DEG`] past the first node along their path
    /// (a turn and the part of the next before a start made up late: the flagged
    /// node lost where the nodes after it have no return).
    pub wrong_turns: u64,
    /// Scans emitted.
    pub scans: u64,
}

/// Parser settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RplidarConfig {
    /// Serial speed (A1/A2: 115200, A2M12/A3: 256000, C1: 460800): a node's
    /// own wire time and that of a trailing part of a node (10 bits a byte).
    pub baud: u32,
    /// Nodes per second sent in standard scan mode (A1 ≈ 2000, C1 5000): the
    /// node interval, the time between nodes on a line that idles between them,
    /// for the whole nodes after a revolution's first in a chunk.
    pub sample_rate_hz: u32,
    /// Longest plausible rotation period: a revolution whose start is followed by
    /// the next one's later than this is dropped
    /// ([`RplidarStats::implausible_periods`]), not timed with another period.
    pub max_period_ns: Nanos,
    /// Period used before a good one has been measured, and the one the first
    /// revolution's is checked against (a first revolution whose period is not
    /// within 2/3 to 1.5 times this is dropped, as is the second unless the two
    /// agree).
    pub nominal_period_ns: Nanos,
    /// A scan is emitted early if it reaches this many rays. The parser reserves
    /// room for them twice when it is made (the revolution's nodes and the scan
    /// made of them, 32 bytes a ray: 512 KiB for the default 8192), so a long
    /// revolution (a slow motor, a fast sample rate, two turns merged) never
    /// allocates after start-up.
    pub max_scan_rays: usize,
}

impl Default for RplidarConfig {
    fn default() -> Self {
        Self {
            baud: 115_200,
            sample_rate_hz: 2000,
            max_period_ns: 1_000_000_000,
            nominal_period_ns: 181_818_182, // 5.5 Hz
            max_scan_rays: 8192,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Node,
    Descriptor,
}

/// Bytes → nodes → scans.
#[derive(Debug, Clone)]
pub struct RplidarParser {
    cfg: RplidarConfig,
    state: State,
    buf: [u8; 8],
    len: usize,
    buf_offset: u64,
    offset: u64,
    stats: RplidarStats,
    last_error: Option<RplidarError>,
    rays: Vec<Ray>,
    scan: Scan,
    scan_start: Option<(Nanos, f64)>,
    /// Largest angle swept from the revolution's first node by any node.
    swept_max_deg: f64,
    /// Angle swept by the revolution's last valid node (distance > 0).
    last_valid_swept: Option<f64>,
    /// Angle swept by the valid node before it.
    prev_valid_swept: Option<f64>,
    /// `swept_max_deg` as it was before the last valid node.
    swept_max_before_last_valid: f64,
    /// Whether the last valid node lay over [`STRAY_JUMP_DEG`] beyond every node
    /// before it.
    last_valid_jumped: bool,
    /// Whether the revolution under way began without a start flag.
    implicit_revolution: bool,
    /// Angle swept by the revolution's nodes so far (with a return or not): the
    /// sum of the steps between consecutive nodes, each in (-180°, 180°].
    turn_deg: f64,
    /// The step from the revolution's last node to the next revolution's first,
    /// when one has started (to be added to `turn_deg` for the whole turn).
    end_step_deg: f64,
    /// The farthest swept by the revolution's nodes, a node that jumped over
    /// [`STRAY_JUMP_DEG`] beyond it counting only once the node after it confirms
    /// it (the revolution's extent, for one cut short: a stray adds nothing).
    extent_deg: f64,
    /// A node's swept angle that jumped, awaiting the next node.
    extent_jump: Option<f64>,
    /// The farthest the revolution's nodes reached along their path (`turn_deg`
    /// after each), a node that jumped over [`STRAY_JUMP_DEG`] beyond it counting
    /// only once the node after it confirms it: the extent unwrapped, over 360° for
    /// nodes past a whole turn (a misread angle at the end, which the sweep counts
    /// and the next start may follow, adds nothing).
    reach_deg: f64,
    /// A node's `turn_deg` that jumped, awaiting the next node.
    reach_jump: Option<f64>,
    /// The angle of the revolution's last node.
    last_angle_deg: f64,
    /// The last good period.
    last_period: Option<Nanos>,
    /// The period of the revolution before, if it was dropped as implausible.
    dropped_period: Option<Nanos>,
}

/// A node this far (degrees) behind its revolution's first node, before the
/// revolution has swept half a turn, counts as swept at the start rather than a
/// whole turn later: the first nodes' angles jitter.
pub const START_JITTER_DEG: f64 = 5.0;

/// A valid node this far (degrees) beyond every node before it in its revolution
/// has jumped: nodes come about a degree apart, so a jump is a misread angle or
/// lost bytes (a 64-byte USB packet is about 13 nodes). A node after it that falls
/// half a turn behind it shows it misread ([`RplidarStats::stray_nodes`]).
pub const STRAY_JUMP_DEG: f64 = 30.0;

/// How far (degrees) a revolution's nodes may reach beyond or short of a whole
/// turn and still be timed as one, without scaling (its period up to 5.6 % off):
/// the angles of the nodes that start two revolutions jitter by a node's step
/// (about a degree), and a lost flag made up a few nodes late stretches the turn
/// by those few nodes.
pub const TURN_SLACK_DEG: f64 = 20.0;

/// A revolution whose nodes swept more than this (degrees) is two turns.
pub const MAX_TURN_DEG: f64 = 540.0;

/// A revolution whose nodes swept less than this (degrees) began at a misread
/// angle: a real one, even cut short by a made-up start, sweeps about a turn
/// up to the node that starts the next.
pub const MIN_TURN_DEG: f64 = 180.0;

/// A revolution whose nodes reached more than this (degrees) past its first node,
/// along their path (see [`RplidarStats::wrong_turns`]), is more than one turn: a
/// turn and the part of the next before a start made up late (the flagged node lost
/// among nodes without a return, the start made up at the first node with one). Its
/// period would be that much too long (1.11 times for 40° more), and the extent of
/// its nodes, whose angles wrap at 360°, cannot show it.
pub const MAX_ONE_TURN_DEG: f64 = 360.0 + TURN_SLACK_DEG;

/// The step from `from` to `to` (degrees clockwise) the short way round, in
/// `(-180, 180]`.
fn step_deg(from: f64, to: f64) -> f64 {
    let d = (to - from).rem_euclid(360.0);
    if d > 180.0 {
        d - 360.0
    } else {
        d
    }
}

/// Angle swept clockwise from `angle0` to `angle`, in `[0, 360)`, given the
/// farthest the revolution has swept so far (`swept_max`): early in the
/// revolution, a node up to [`START_JITTER_DEG`] behind `angle0` counts as 0.
fn swept_deg(angle0: f64, angle: f64, swept_max: f64) -> f64 {
    let d = (angle - angle0).rem_euclid(360.0);
    if d > 360.0 - START_JITTER_DEG && swept_max < 180.0 {
        0.0
    } else {
        d
    }
}

impl RplidarParser {
    /// A parser at stream offset 0.
    pub fn new(cfg: RplidarConfig) -> Self {
        Self {
            cfg,
            state: State::Node,
            buf: [0; 8],
            len: 0,
            buf_offset: 0,
            offset: 0,
            stats: RplidarStats::default(),
            last_error: None,
            // every ray a revolution can hold (it is emitted on reaching the limit)
            rays: Vec::with_capacity(cfg.max_scan_rays.max(1)),
            scan: Scan::with_capacity(cfg.max_scan_rays.max(1)),
            scan_start: None,
            swept_max_deg: 0.0,
            last_valid_swept: None,
            prev_valid_swept: None,
            swept_max_before_last_valid: 0.0,
            last_valid_jumped: false,
            implicit_revolution: false,
            turn_deg: 0.0,
            end_step_deg: 0.0,
            extent_deg: 0.0,
            extent_jump: None,
            reach_deg: 0.0,
            reach_jump: None,
            last_angle_deg: 0.0,
            last_period: None,
            dropped_period: None,
        }
    }

    /// Counters.
    pub fn stats(&self) -> &RplidarStats {
        &self.stats
    }

    /// The latest error.
    pub fn last_error(&self) -> Option<RplidarError> {
        self.last_error
    }

    /// Pushes a chunk received at host time `rx_ns` (time of its last byte);
    /// `on_scan` is called for each completed revolution.
    pub fn push(&mut self, bytes: &[u8], rx_ns: Nanos, mut on_scan: impl FnMut(&Scan)) {
        for (i, &b) in bytes.iter().enumerate() {
            let off = self.offset;
            self.offset += 1;
            self.stats.bytes += 1;
            if let Some(node) = self.step(b, off) {
                let after = bytes.len() - 1 - i;
                self.node(node, rx_ns, after, &mut on_scan);
            }
        }
    }

    /// Pushes a chunk and returns the valid nodes instead of assembling scans
    /// (for tools that want raw nodes).
    pub fn push_nodes(&mut self, bytes: &[u8], mut on_node: impl FnMut(&RplidarNode)) {
        for &b in bytes {
            let off = self.offset;
            self.offset += 1;
            self.stats.bytes += 1;
            if let Some(node) = self.step(b, off) {
                on_node(&node);
            }
        }
    }

    /// Emits the revolution in progress using the last measured period
    /// (e.g. at the end of a recording).
    pub fn finish(&mut self, mut on_scan: impl FnMut(&Scan)) {
        if let Some((start, _)) = self.scan_start {
            let period = self.last_period.unwrap_or(self.cfg.nominal_period_ns);
            self.emit(start.saturating_add(period), false, &mut on_scan);
        }
        self.scan_start = None;
    }

    fn error(&mut self, offset: u64, kind: RplidarErrorKind) {
        self.last_error = Some(RplidarError { offset, kind });
    }

    /// Drops the first buffered byte and replays the rest.
    fn resync(&mut self) -> Option<RplidarNode> {
        self.stats.skipped_bytes += 1;
        let (tail, n, start) = (self.buf, self.len, self.buf_offset + 1);
        self.len = 0;
        self.state = State::Node;
        let mut out = None;
        for (j, &x) in tail[1..n].iter().enumerate() {
            // at most six bytes are replayed (a descriptor that mismatches at its
            // last byte, 6; a node rejected at its byte 1, for the check bit, or
            // once complete, for the angle, replays one or four): fewer than two
            // nodes' ten, so at most one node completes here, the bytes after it
            // only beginning the next
            if let Some(node) = self.step(x, start + j as u64) {
                out = Some(node);
            }
        }
        out
    }

    fn step(&mut self, b: u8, off: u64) -> Option<RplidarNode> {
        if self.len == 0 {
            self.buf_offset = off;
        }
        self.buf[self.len] = b;
        self.len += 1;
        match self.state {
            State::Descriptor => {
                let i = self.len - 1;
                if b != SCAN_DESCRIPTOR[i] {
                    self.stats.descriptor_errors += 1;
                    self.error(
                        self.buf_offset,
                        RplidarErrorKind::BadDescriptor { index: i, found: b },
                    );
                    return self.resync();
                }
                if self.len == SCAN_DESCRIPTOR.len() {
                    self.stats.descriptors += 1;
                    self.len = 0;
                    self.state = State::Node;
                    // a new response: the revolution in progress is abandoned
                    self.rays.clear();
                    self.scan_start = None;
                }
                None
            }
            State::Node => match self.len {
                1 => {
                    if (b ^ (b >> 1)) & 1 == 0 {
                        self.stats.sync_bit_errors += 1;
                        self.error(off, RplidarErrorKind::SyncBits { byte: b });
                        self.len = 0;
                        self.stats.skipped_bytes += 1;
                    }
                    None
                }
                2 => {
                    if self.buf[0] == SCAN_DESCRIPTOR[0] && b == SCAN_DESCRIPTOR[1] {
                        self.state = State::Descriptor;
                        return None;
                    }
                    if b & 1 == 0 {
                        self.stats.check_bit_errors += 1;
                        self.error(self.buf_offset, RplidarErrorKind::CheckBit { byte: b });
                        return self.resync();
                    }
                    None
                }
                NODE_LEN => {
                    let mut nb = [0u8; NODE_LEN];
                    nb.copy_from_slice(&self.buf[..NODE_LEN]);
                    match RplidarNode::decode(&nb) {
                        Ok(node) => {
                            self.len = 0;
                            self.stats.nodes += 1;
                            Some(node)
                        }
                        Err(kind) => {
                            self.stats.angle_errors += 1;
                            self.error(self.buf_offset, kind);
                            self.resync()
                        }
                    }
                }
                _ => None,
            },
        }
    }

    fn node(
        &mut self,
        node: RplidarNode,
        rx_ns: Nanos,
        bytes_after: usize,
        on_scan: &mut impl FnMut(&Scan),
    ) {
        let angle = node.angle_deg();
        let valid = node.distance_q2 > 0;
        let mut start = node.start;
        if let Some((_, angle0)) = self.scan_start {
            // a real start comes after more than half a turn, back near the angle the
            // revolution began at (e.g. 359.5 -> 0.2 deg): its angle lies over 180 deg
            // behind the farthest swept, or just short of a whole turn
            let here = swept_deg(angle0, angle, self.swept_max_deg);
            // a revolution started without a flag began where a node said, which may
            // have been misread: any flag after half a turn ends it, so that one bad
            // made-up start cannot shift every later revolution
            let back_near_start = self.swept_max_deg >= 180.0
                && (self.swept_max_deg - here > 180.0
                    || here >= 360.0 - START_JITTER_DEG
                    || self.implicit_revolution);
            if start && !back_near_start {
                self.stats.false_starts += 1;
                start = false;
            }
            if !start
                && !node.start
                && valid
                && self.last_valid_swept.is_some_and(|l| l - here > 180.0)
            {
                if !self.last_valid_jumped {
                    // the flagged node was lost when a valid node falls half a turn
                    // behind the last valid one: without a start here the next flag
                    // would make one scan of two revolutions, timed as one. (Only
                    // valid nodes: the SDK treats the angles of nodes without a return
                    // as unreliable.)
                    self.stats.implicit_starts += 1;
                    start = true;
                } else {
                    // the last valid node had jumped far ahead of every node before
                    // it, and this one is back: its angle was misread. Forgotten, or
                    // this node would start a revolution here
                    self.stats.stray_nodes += 1;
                    self.swept_max_deg = self.swept_max_before_last_valid;
                    self.last_valid_swept = self.prev_valid_swept.take();
                    self.last_valid_jumped = false;
                }
            }
        }
        if self.scan_start.is_some() {
            // every node counts towards the turn, up to the next revolution's first
            let step = step_deg(self.last_angle_deg, angle);
            if start {
                self.end_step_deg = step;
            } else {
                self.turn_deg += step;
                // as the extent below, a jump counting once the next node follows it
                if let Some(j) = self.reach_jump.take() {
                    if (self.turn_deg - j).abs() <= STRAY_JUMP_DEG {
                        self.reach_deg = self.reach_deg.max(j);
                    }
                }
                if self.turn_deg > self.reach_deg + STRAY_JUMP_DEG {
                    self.reach_jump = Some(self.turn_deg);
                } else {
                    self.reach_deg = self.reach_deg.max(self.turn_deg);
                }
            }
            self.last_angle_deg = angle;
        }
        if start {
            let t = rx_ns.saturating_sub(self.host_shift_ns(bytes_after));
            if self.scan_start.is_some() {
                self.emit(t, true, on_scan);
            }
            self.scan_start = Some((t, angle));
            self.turn_deg = 0.0;
            self.last_angle_deg = angle;
            self.extent_deg = 0.0;
            self.extent_jump = None;
            self.reach_deg = 0.0;
            self.reach_jump = None;
            self.implicit_revolution = !node.start;
            self.swept_max_deg = 0.0;
            self.last_valid_swept = None;
            self.prev_valid_swept = None;
            self.swept_max_before_last_valid = 0.0;
            self.last_valid_jumped = false;
        } else if self.scan_start.is_none() {
            self.stats.nodes_before_start += 1;
            return;
        }
        if let Some((_, angle0)) = self.scan_start {
            let here = swept_deg(angle0, angle, self.swept_max_deg);
            if valid {
                self.prev_valid_swept = self.last_valid_swept;
                self.swept_max_before_last_valid = self.swept_max_deg;
                self.last_valid_swept = Some(here);
                self.last_valid_jumped = here > self.swept_max_deg + STRAY_JUMP_DEG;
            }
            self.swept_max_deg = self.swept_max_deg.max(here);
            // a jump counts towards the extent once the next node follows it
            if let Some(j) = self.extent_jump.take() {
                if (here - j).abs() <= STRAY_JUMP_DEG {
                    self.extent_deg = self.extent_deg.max(j);
                }
            }
            if here > self.extent_deg + STRAY_JUMP_DEG {
                self.extent_jump = Some(here);
            } else {
                self.extent_deg = self.extent_deg.max(here);
            }
        }
        let mm = node.distance_mm();
        self.rays.push(Ray::new(
            cw_degrees_to_bearing(angle),
            mm / 1000.0,
            node.quality as f32,
            node.quality > 0 && node.distance_q2 > 0,
        ));
        if self.rays.len() >= self.cfg.max_scan_rays {
            // no revolution start for too long: emit and wait for the next start
            let (start, _) = self.scan_start.unwrap_or((rx_ns, 0.0));
            let period = self.last_period.unwrap_or(self.cfg.nominal_period_ns);
            self.emit(start.saturating_add(period), false, on_scan);
            self.scan_start = None;
        }
    }

    /// The time from a node's measurement to the arrival of the last byte of its
    /// chunk, `bytes_after` bytes later (see the module docs).
    fn host_shift_ns(&self, bytes_after: usize) -> i64 {
        let byte_ns = BITS_PER_BYTE as f64 * 1e9 / self.cfg.baud.max(1) as f64;
        let paced_ns = 1e9 / self.cfg.sample_rate_hz.max(1) as f64;
        let interval_ns = paced_ns.max(NODE_LEN as f64 * byte_ns);
        crate::serial::wire_shift_ns(bytes_after, NODE_LEN, interval_ns, byte_ns)
    }

    /// Emits the revolution started at `scan_start`, ending at `end_ns`.
    ///
    /// `measured_end`: the end is the next revolution's start, so the time between
    /// is measured, for the part of a turn the revolution's nodes covered (a
    /// revolution cut short by a made-up start covers less than a turn; its period
    /// is scaled to a whole one). Otherwise the end is the last period's.
    fn emit(&mut self, end_ns: Nanos, measured_end: bool, on_scan: &mut impl FnMut(&Scan)) {
        let Some((start, angle0)) = self.scan_start else {
            return;
        };
        let whole_turn = self.turn_deg + self.end_step_deg;
        if measured_end && !(MIN_TURN_DEG..=MAX_TURN_DEG).contains(&whole_turn) {
            // two turns (or more) whose start could not be found, or nodes
            // timed from a misread first angle: their rays' times would be wrong
            // by up to a turn
            self.stats.wrong_turns += 1;
            self.dropped_period = None;
            self.rays.clear();
            return;
        }
        // the nodes' reach (or extent) plus one node's step: 360° for a whole turn
        let n = self.rays.len() as f64;
        let per_node = if n >= 2.0 { n / (n - 1.0) } else { 1.0 };
        if measured_end && self.reach_deg * per_node > MAX_ONE_TURN_DEG {
            // a turn and the part of the next before a start made up late: its time
            // is more than a period, and its extent, wrapped at 360°, says one turn,
            // so nothing would scale it. Not rescaled by 360° / reach either: the
            // period would be right, but the part's nodes, a turn later than the
            // ones at the same angles, would be dated with them. It happens only
            // where a lost flag is followed by nodes without a return; dropping it
            // costs one revolution, and keeps the last good period
            self.stats.wrong_turns += 1;
            self.dropped_period = None;
            self.rays.clear();
            return;
        }
        let mut measured = end_ns.saturating_sub(start);
        if measured_end && n >= 2.0 {
            let turn = self.extent_deg * per_node;
            if turn > 0.0 && (turn - 360.0).abs() > TURN_SLACK_DEG {
                measured = (measured as f64 * 360.0 / turn).round() as Nanos;
            }
        }
        let good = self.last_period.unwrap_or(self.cfg.nominal_period_ns);
        let within = |p: Nanos, of: Nanos| p <= of.saturating_add(of / 2) && p >= of - of / 3;
        let measured_ok = measured > 0 && measured <= self.cfg.max_period_ns;
        if measured_end && !measured_ok {
            // no turn of this motor lasts that long (a stall, the host not reading)
            // or the next start is dated before this one (the host's clock stepped
            // back): timed with the last good period instead, its rays would be
            // squeezed into a turn they did not take. No period to agree on either
            self.stats.implausible_periods += 1;
            self.dropped_period = None;
            self.rays.clear();
            return;
        }
        if measured_end && !within(measured, good) {
            let dropped = self.dropped_period.take();
            if dropped.is_none_or(|d| (measured - d).abs() > d / 5) {
                // not one revolution of this motor (two merged, a stall, or a start
                // made up at a misread angle): its rays' times would be wrong by up
                // to a turn. The last good period stays the reference; a motor that
                // really changed speed gives two revolutions that agree, and loses
                // one scan, not all.
                self.stats.implausible_periods += 1;
                self.dropped_period = Some(measured);
                self.rays.clear();
                return;
            }
        }
        if measured_end {
            // the revolution before this one is no longer the one before the next
            self.dropped_period = None;
        }
        let period = if measured_ok {
            if measured_end {
                self.last_period = Some(measured);
            }
            measured
        } else {
            good
        };
        let timing = ScanTiming {
            start_ns: start,
            period_ns: period,
            rotation: Rotation::Cw,
            start_bearing_rad: cw_degrees_to_bearing(angle0),
        };
        self.scan.clear();
        self.scan.set_timing(timing);
        let mut swept_max = 0.0f64;
        for r in self.rays.drain(..) {
            // a first node jittered a little behind the start is measured at the
            // start, not a turn later
            let swept = swept_deg(angle0, bearing_to_cw_degrees(r.bearing_rad), swept_max);
            swept_max = swept_max.max(swept);
            let t_ns = if swept == 0.0 {
                start
            } else {
                timing.time_at_bearing(r.bearing_rad)
            };
            self.scan.push(Ray { t_ns, ..r });
        }
        if !self.scan.is_empty() {
            self.stats.scans += 1;
            on_scan(&self.scan);
        }
    }
}

/// Produces RPLIDAR standard-scan node bytes for a simulated scanner.
#[derive(Debug, Clone)]
pub struct RplidarEncoder {
    nodes_per_rev: usize,
}

impl RplidarEncoder {
    /// `nodes_per_rev` nodes evenly spaced over each revolution (at least 1).
    pub fn new(nodes_per_rev: usize) -> Self {
        Self {
            nodes_per_rev: nodes_per_rev.max(1),
        }
    }

    /// One revolution of nodes starting at 0°; `range_mm(angle_deg)` gives the
    /// distance at a clockwise angle (0 or negative encodes "no return").
    pub fn revolution(&mut self, mut range_mm: impl FnMut(f64) -> f64) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.nodes_per_rev * NODE_LEN);
        for i in 0..self.nodes_per_rev {
            let q6 = ((i as u64 * MAX_ANGLE_Q6 as u64) / self.nodes_per_rev as u64) as u16;
            let d = range_mm(q6 as f64 / 64.0);
            let q2 = if d.is_finite() && d > 0.0 {
                (d * 4.0).round().min(u16::MAX as f64) as u16
            } else {
                0
            };
            let node = RplidarNode {
                start: i == 0,
                quality: if q2 > 0 { 47 } else { 0 },
                angle_q6: q6,
                distance_q2: q2,
            };
            out.extend_from_slice(&node.encode());
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn node_roundtrip_and_layout() {
        let n = RplidarNode {
            start: true,
            quality: 15,
            angle_q6: 90 * 64 + 5,
            distance_q2: 4000,
        };
        let b = n.encode();
        assert_eq!(b[0], (15 << 2) | 0b01);
        assert_eq!(b[1] & 1, 1);
        assert_eq!(RplidarNode::decode(&b).unwrap(), n);
        assert_eq!(n.distance_mm(), 1000.0);
        assert!((n.angle_deg() - (90.0 + 5.0 / 64.0)).abs() < 1e-12);
    }

    #[test]
    fn descriptor_never_passes_as_node() {
        let mut b = [0u8; 5];
        b.copy_from_slice(&SCAN_DESCRIPTOR[..5]);
        assert!(RplidarNode::decode(&b).is_err());
    }

    fn revs(n: usize, per: usize) -> Vec<u8> {
        let mut e = RplidarEncoder::new(per);
        let mut v = SCAN_DESCRIPTOR.to_vec();
        for _ in 0..n {
            v.extend(e.revolution(|a| 1000.0 + a));
        }
        v
    }

    #[test]
    fn scan_times_interpolate_between_starts() {
        let per = 360;
        let revolution = revs(1, per)[7..].to_vec();
        let mut p = RplidarParser::new(RplidarConfig::default());
        let mut scans = Vec::new();
        // each revolution arrives as one chunk, 200 ms apart; its start node
        // is followed by 359 nodes = 1795 bytes
        for k in 0..4i64 {
            p.push(&revolution, 1_000_000_000 + k * 200_000_000, |s| {
                scans.push(s.clone())
            });
        }
        assert_eq!(scans.len(), 3);
        let s = &scans[1];
        assert_eq!(s.timing().period_ns, 200_000_000);
        let r = s.rays();
        assert_eq!(r.len(), 360);
        assert_eq!(r[90].t_ns - r[0].t_ns, 50_000_000);
        assert!((r[90].bearing_rad + std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert!((r[90].range_m - 1.09).abs() < 1e-9);
    }

    /// Revolutions of [`crate::encode::rplidar_revolution`] read in chunks of 1 to
    /// 120 bytes, each dated at its last byte's arrival (a node leaves as it is
    /// measured, 10 bits a byte): each revolution starts at its first node's
    /// measurement, and every ray is dated at its node's.
    #[test]
    fn host_stamps_are_the_nodes_measurement_times() {
        use crate::encode::{rplidar_byte_arrival_s, rplidar_revolution};
        let (per, period_s) = (360, 0.2);
        for baud in [115_200, 460_800] {
            let mut p = RplidarParser::new(RplidarConfig {
                baud,
                sample_rate_hz: (per as f64 / period_s) as u32,
                ..RplidarConfig::default()
            });
            p.push(&SCAN_DESCRIPTOR, 0, |_| {});
            let mut scans = Vec::new();
            let mut rng = 99u64;
            for k in 0..5 {
                let t0 = 1.0 + k as f64 * period_s;
                let rev = rplidar_revolution(per, t0, period_s, |_, _| 2.0);
                let mut at = 0;
                while at < rev.len() {
                    rng = rng
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let n = (1 + (rng >> 33) as usize % 120).min(rev.len() - at);
                    let rx = rplidar_byte_arrival_s(at + n - 1, per, t0, period_s, baud);
                    p.push(&rev[at..at + n], (rx * 1e9).round() as Nanos, |s| {
                        scans.push(s.clone())
                    });
                    at += n;
                }
            }
            assert_eq!(scans.len(), 4, "{:?}", p.stats());
            for (k, s) in scans.iter().enumerate() {
                let t0 = ((1.0 + k as f64 * period_s) * 1e9).round() as Nanos;
                assert!(
                    (s.timing().start_ns - t0).abs() <= 2,
                    "{baud} baud: {:?}",
                    s.timing()
                );
                assert!((s.timing().period_ns - 200_000_000).abs() <= 2);
                for (i, r) in s.rays().iter().enumerate() {
                    let truth = t0 + (i as f64 * period_s / per as f64 * 1e9).round() as Nanos;
                    assert!(
                        (r.t_ns - truth).abs() <= 3,
                        "{baud} baud, ray {i}: {}",
                        r.t_ns
                    );
                }
            }
        }
    }

    /// One revolution of `per` nodes from 0° as nodes: a return (1 m) where
    /// `valid(angle)`, the start flag on the first.
    fn rev_nodes(per: usize, valid: impl Fn(f64) -> bool) -> Vec<RplidarNode> {
        (0..per)
            .map(|i| {
                let angle_q6 = (i * MAX_ANGLE_Q6 as usize / per) as u16;
                let v = valid(angle_q6 as f64 / 64.0);
                RplidarNode {
                    start: i == 0,
                    quality: if v { 40 } else { 0 },
                    angle_q6,
                    distance_q2: if v { 4000 } else { 0 },
                }
            })
            .collect()
    }

    fn bytes_of(nodes: &[RplidarNode]) -> Vec<u8> {
        nodes.iter().flat_map(|n| n.encode()).collect()
    }

    /// Pushes each revolution as one chunk, 200 ms apart; returns the scans.
    fn scans_of(revolutions: &[Vec<RplidarNode>]) -> (Vec<Scan>, RplidarStats) {
        let mut p = RplidarParser::new(RplidarConfig::default());
        let mut scans = Vec::new();
        for (k, r) in revolutions.iter().enumerate() {
            p.push(&bytes_of(r), 1_000_000_000 + k as i64 * 200_000_000, |s| {
                scans.push(s.clone())
            });
        }
        (scans, *p.stats())
    }

    #[test]
    fn a_start_after_a_node_without_return_that_already_wrapped_is_kept() {
        // the SDK does not trust the angles of nodes without a return: here the last
        // node of each revolution has none and an angle already past 0°
        let revs: Vec<_> = (0..4)
            .map(|_| {
                let mut r = rev_nodes(360, |_| true);
                let last = r.last_mut().unwrap();
                (last.angle_q6, last.distance_q2, last.quality) = (2 * 64, 0, 0);
                r
            })
            .collect();
        let (scans, stats) = scans_of(&revs);
        assert_eq!(stats.false_starts, 0, "{stats:?}");
        assert_eq!(scans.len(), 3, "{stats:?}");
        assert!(scans.iter().all(|s| s.len() == 360));
        assert_eq!(scans[1].timing().period_ns, 200_000_000);
    }

    #[test]
    fn a_lost_start_node_splits_at_the_wrap_instead_of_merging_two_turns() {
        let mut revs: Vec<_> = (0..4).map(|_| rev_nodes(360, |_| true)).collect();
        revs[2].remove(0); // the third revolution's flagged node is lost
        let (scans, stats) = scans_of(&revs);
        assert_eq!(stats.implicit_starts, 1, "{stats:?}");
        assert_eq!(scans.len(), 3, "{stats:?}");
        // the third scan starts at its first node (1°); no scan spans two turns
        for s in &scans {
            let span = s.rays().last().unwrap().t_ns - s.rays()[0].t_ns;
            assert!(span < 200_000_000, "{span} ns: {:?}", s.timing());
            assert!((180_000_000..=220_000_000).contains(&s.timing().period_ns));
        }
        assert!((scans[2].rays()[0].bearing_deg() + 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_stray_node_half_a_turn_ahead_is_forgotten_not_a_revolution_start() {
        // one valid node of the second revolution reads 200° where its neighbours
        // read 10° and 11°
        let mut revs: Vec<_> = (0..6).map(|_| rev_nodes(360, |_| true)).collect();
        revs[1][10].angle_q6 = 200 * 64;
        let (scans, stats) = scans_of(&revs);
        assert_eq!(
            (stats.stray_nodes, stats.implicit_starts, stats.false_starts),
            (1, 0, 0),
            "{stats:?}"
        );
        // every revolution is whole, starting at its flagged node
        assert_eq!(scans.len(), 5, "{stats:?}");
        for s in &scans {
            assert_eq!(s.len(), 360);
            assert_eq!(s.rays()[0].bearing_deg(), 0.0);
            assert_eq!(s.timing().period_ns, 200_000_000);
        }
        // and a lost flag after it is still made up for at the wrap
        let mut revs: Vec<_> = (0..5).map(|_| rev_nodes(360, |_| true)).collect();
        revs[1][10].angle_q6 = 200 * 64;
        revs[3].remove(0);
        let (scans, stats) = scans_of(&revs);
        assert_eq!(
            (stats.stray_nodes, stats.implicit_starts),
            (1, 1),
            "{stats:?}"
        );
        assert_eq!(scans.len(), 4, "{stats:?}");
    }

    #[test]
    fn a_lone_return_half_a_turn_on_still_makes_up_a_lost_flag() {
        // returns at 0-150° and one at 250° (the gap swept by nodes without a
        // return), and the third revolution's flag lost
        let sparse = |a: f64| a <= 150.0 || (a - 250.0).abs() < 0.5;
        let mut revs: Vec<_> = (0..5).map(|_| rev_nodes(360, sparse)).collect();
        revs[2].remove(0);
        let (scans, stats) = scans_of(&revs);
        assert_eq!(
            (
                stats.implicit_starts,
                stats.stray_nodes,
                stats.implausible_periods
            ),
            (1, 0, 0),
            "{stats:?}"
        );
        assert_eq!(scans.len(), 4, "{stats:?}");
    }

    #[test]
    fn a_misread_angle_behind_costs_one_revolution_not_the_run() {
        // the node at 300° of the second revolution reads 10°: a made-up start there
        let mut revs: Vec<_> = (0..7).map(|_| rev_nodes(360, |_| true)).collect();
        revs[1][300].angle_q6 = 10 * 64;
        let (scans, stats) = scans_of(&revs);
        assert_eq!(
            (stats.implicit_starts, stats.false_starts),
            (1, 0),
            "{stats:?}"
        );
        // the revolution cut at the misread node is timed as 300° of a whole turn;
        // the one made up there (60 nodes read as 350° from the misread 10°, but
        // whose nodes swept -10°: 10° back to 301°, on to 360°) is dropped for its
        // turn (it was dropped for its period, too short a turn, before the turn
        // was counted); the next flag ends it and every later revolution is whole
        assert_eq!(
            (stats.wrong_turns, stats.implausible_periods),
            (1, 0),
            "{stats:?}"
        );
        let lens: Vec<usize> = scans.iter().map(|s| s.len()).collect();
        assert_eq!(lens, [360, 300, 360, 360, 360, 360], "{stats:?}");
        // (within one pushed chunk the nodes are dated 0.5 ms apart, the assumed
        // 2000 nodes/s: the cut revolution's 300 nodes span 150 ms, a whole turn
        // 180 ms, and its last ray lies 149.5 ms after its first, where an unscaled
        // 150 ms "turn" would put it at 124.6 ms)
        let cut = scans[1].rays();
        assert_eq!(scans[1].timing().period_ns, 180_000_000);
        assert!(
            (cut[299].t_ns - cut[0].t_ns - 149_500_000).abs() < 100_000,
            "{} ns",
            cut[299].t_ns - cut[0].t_ns
        );
        for s in &scans[2..] {
            assert_eq!(s.rays()[0].bearing_deg(), 0.0);
            assert_eq!(s.timing().period_ns, 200_000_000);
        }
    }

    #[test]
    fn two_turns_that_cannot_be_split_are_dropped_not_timed_as_one() {
        // returns in a quarter turn only (an open space), and the third
        // revolution's flag lost: no valid node falls half a turn behind another
        let quarter = |a: f64| (45.0..135.0).contains(&a);
        let mut revs: Vec<_> = (0..5).map(|_| rev_nodes(360, quarter)).collect();
        revs[2].remove(0);
        let (scans, stats) = scans_of(&revs);
        assert_eq!(stats.implicit_starts, 0, "{stats:?}");
        // the nodes without a return still sweep two turns: dropped for that
        // (this test expected one implausible period before the turn was
        // counted: the period check no longer sees the revolution)
        assert_eq!(
            (stats.wrong_turns, stats.implausible_periods),
            (1, 0),
            "{stats:?}"
        );
        assert_eq!(scans.len(), 2, "{stats:?}");
        assert!(scans
            .iter()
            .all(|s| s.timing().period_ns == 200_000_000 && s.len() == 360));
    }

    #[test]
    fn a_lost_flag_before_nodes_without_a_return_does_not_stretch_the_turn_before() {
        // the third revolution's flag is lost and its nodes up to 40 deg have no
        // return: the start is made up at 40 deg, so the second revolution's nodes
        // sweep 400 deg (its extent one turn, wrapped) in 1.11 periods
        let mut revs: Vec<_> = (0..6).map(|_| rev_nodes(360, |_| true)).collect();
        revs[2] = rev_nodes(360, |a| a >= 40.0);
        revs[2].remove(0);
        let (scans, stats) = scans_of(&revs);
        assert_eq!(
            (
                stats.implicit_starts,
                stats.wrong_turns,
                stats.implausible_periods
            ),
            (1, 1, 0),
            "{stats:?}"
        );
        // the first revolution, the third cut short from 40 deg (320 nodes; with
        // nodes dated 0.5 ms apart within a chunk, 180 ms from its made-up start to
        // the next flag, scaled from its extent, 320 deg, to a whole turn), and the
        // fourth and fifth, whole; the second, which would have been timed with a
        // period 11 % long (220 ms, then the last good one), is dropped
        let lens: Vec<usize> = scans.iter().map(|s| s.len()).collect();
        assert_eq!(lens, [360, 320, 360, 360], "{stats:?}");
        let periods: Vec<Nanos> = scans.iter().map(|s| s.timing().period_ns).collect();
        assert_eq!(
            periods,
            [200_000_000, 202_500_000, 200_000_000, 200_000_000],
            "{stats:?}"
        );
        assert!((scans[1].rays()[0].bearing_deg() + 40.0).abs() < 1e-9);
    }

    #[test]
    fn misread_angles_before_a_start_do_not_make_its_turn_too_long() {
        // the second revolution's last node (no return) reads 74.5 deg and the third's
        // flagged node 151 deg (line noise): the second's nodes sweep 511 deg up to
        // that start, but along their path they reach 359 deg only (a jump counts
        // once the next node follows it): it is one turn, timed as one
        let mut revs: Vec<_> = (0..5).map(|_| rev_nodes(360, |_| true)).collect();
        let last = &mut revs[1][359];
        (last.angle_q6, last.distance_q2, last.quality) = (74 * 64 + 32, 0, 0);
        revs[2][0].angle_q6 = 151 * 64;
        let (scans, stats) = scans_of(&revs);
        assert_eq!(scans.len(), 4, "{stats:?}");
        assert_eq!(scans[1].len(), 360);
        assert_eq!(scans[1].timing().period_ns, 200_000_000);
        // the third, begun at the misread 151 deg, is dropped for its sweep (-1 deg
        // up to the start made up at the real 151 deg), as before
        assert_eq!(
            (
                stats.wrong_turns,
                stats.implicit_starts,
                stats.implausible_periods
            ),
            (1, 1, 0),
            "{stats:?}"
        );
    }

    #[test]
    fn a_revolution_longer_than_the_longest_period_is_dropped_not_squeezed() {
        // 1.2 s between two starts, over `max_period_ns` (1 s): not a turn to time
        // with the last good period, which would squeeze its rays into 200 ms
        let (periods, stats) = periods_at(&[1.0, 1.2, 1.4, 2.6, 2.8, 3.0]);
        assert_eq!(periods, [200, 200, 200, 200], "{stats:?}");
        assert_eq!((stats.implausible_periods, stats.wrong_turns), (1, 0));
        // the same for a start dated before the one before (the host's clock
        // stepped back): a period below 0
        let (periods, stats) = periods_at(&[1.0, 1.2, 1.4, 1.3, 1.5, 1.7]);
        assert_eq!(periods, [200, 200, 200, 200], "{stats:?}");
        assert_eq!((stats.implausible_periods, stats.wrong_turns), (1, 0));
    }

    /// Pushes each revolution (360 nodes, all with a return) as one chunk at the
    /// given times (s); returns the scans' periods (ms) and the stats.
    fn periods_at(times_s: &[f64]) -> (Vec<i64>, RplidarStats) {
        let mut p = RplidarParser::new(RplidarConfig::default());
        let mut periods = Vec::new();
        for &t in times_s {
            let rev = bytes_of(&rev_nodes(360, |_| true));
            p.push(&rev, (t * 1e9).round() as Nanos, |s| {
                assert_eq!(s.len(), 360);
                periods.push((s.timing().period_ns as f64 / 1e6).round() as i64)
            });
        }
        (periods, *p.stats())
    }

    #[test]
    fn a_revolution_is_checked_against_a_period_from_the_first_to_the_last() {
        // the first revolution against the nominal period (181.8 ms): 400 ms is
        // not one turn
        let (periods, stats) = periods_at(&[1.0, 1.4, 1.6, 1.8, 2.0]);
        assert_eq!(periods, [200, 200, 200], "{stats:?}");
        assert_eq!(stats.implausible_periods, 1);
        // after a drop (350 ms) the last good period stays the reference: the
        // 100 ms revolution after it is dropped too, not taken blindly
        let (periods, stats) = periods_at(&[1.0, 1.2, 1.4, 1.75, 1.85, 2.05, 2.25]);
        assert_eq!(periods, [200, 200, 200, 200], "{stats:?}");
        assert_eq!(stats.implausible_periods, 2);
        // a motor that changed speed: two revolutions agree on the new period,
        // and the second of them is kept
        let (periods, stats) = periods_at(&[1.0, 1.2, 1.4, 1.52, 1.64, 1.76, 1.88]);
        assert_eq!(periods, [200, 200, 120, 120, 120], "{stats:?}");
        assert_eq!(stats.implausible_periods, 1);
    }

    #[test]
    fn a_first_revolution_of_two_turns_is_dropped_for_its_nodes_sweep() {
        // the second turn's flag is lost and none of its nodes has a return: no
        // start can be made up, and there is no period yet to find it by
        let mut revs: Vec<_> = (0..4).map(|_| rev_nodes(360, |_| true)).collect();
        revs[1] = rev_nodes(360, |_| false);
        revs[1][0].start = false;
        let (scans, stats) = scans_of(&revs);
        assert_eq!(
            (stats.wrong_turns, stats.implausible_periods),
            (1, 0),
            "{stats:?}"
        );
        assert_eq!(scans.len(), 1, "{stats:?}");
        assert_eq!(scans[0].len(), 360);
        assert_eq!(scans[0].timing().period_ns, 200_000_000);
    }

    #[test]
    fn a_stray_angle_does_not_stretch_a_revolution_cut_short() {
        // the second revolution's node at 264° reads 328° (a stray, 64° ahead),
        // and its node at 272° reads 16°: a start is made up there, cutting the
        // revolution at 272 nodes, 272° of a turn
        let mut revs: Vec<_> = (0..5).map(|_| rev_nodes(360, |_| true)).collect();
        revs[1][264].angle_q6 = 328 * 64;
        revs[1][272].angle_q6 = 16 * 64;
        let (scans, stats) = scans_of(&revs);
        assert_eq!(
            (stats.implicit_starts, stats.wrong_turns),
            (1, 1),
            "{stats:?}"
        );
        let lens: Vec<usize> = scans.iter().map(|s| s.len()).collect();
        assert_eq!(lens, [360, 272, 360, 360], "{stats:?}");
        // (nodes dated 0.5 ms apart within a chunk: 272 of them span 136 ms of a
        // 180 ms turn; the stray's 328° would have made it 149 ms)
        assert_eq!(scans[1].timing().period_ns, 180_000_000);
        let r = scans[1].rays();
        let at_271 = r
            .iter()
            .find(|r| (bearing_to_cw_degrees(r.bearing_rad) - 271.0).abs() < 1e-9)
            .unwrap();
        assert!(
            (at_271.t_ns - r[0].t_ns - 135_500_000).abs() < 100_000,
            "{at_271:?}"
        );
    }

    #[test]
    fn a_node_just_behind_the_start_is_timed_at_the_start() {
        let revs: Vec<_> = (0..3)
            .map(|_| {
                let mut r = rev_nodes(360, |_| true);
                r[0].angle_q6 = 64; // the flagged node at 1°
                r[1].angle_q6 = 32; // the next jittered back to 0.5°
                r
            })
            .collect();
        let (scans, stats) = scans_of(&revs);
        assert_eq!((scans.len(), stats.false_starts), (2, 0), "{stats:?}");
        let r = scans[0].rays();
        assert_eq!(r[1].t_ns, r[0].t_ns, "a turn late: {:?}", &r[..3]);
        // and the revolution's end is still its end
        assert!(r[359].t_ns - r[0].t_ns > 190_000_000);
    }

    #[test]
    fn corrupted_nodes_resync() {
        let mut v = revs(3, 100);
        // flip the check bit of node 10 of revolution 0
        v[7 + 5 * 10 + 1] &= !1;
        // insert garbage between nodes of revolution 1
        let at = 7 + 5 * 150;
        v.splice(at..at, [0x00, 0xFF, 0x12]);
        let mut p = RplidarParser::new(RplidarConfig::default());
        let mut nodes = 0;
        p.push_nodes(&v, |_| nodes += 1);
        // node 10 is lost; a misframed alignment can pass the weak checks
        // (2 bits + angle range) for a node or two before realigning
        assert!((295..=299).contains(&nodes), "{nodes} {:?}", p.stats());
        assert_eq!(p.stats().descriptors, 1);
        assert!(p.stats().check_bit_errors >= 1);
        let e = p.last_error().unwrap();
        assert!(e.to_string().starts_with("RPLIDAR stream, byte offset"));
    }

    #[test]
    fn truncated_node_costs_itself() {
        let v = revs(2, 50);
        let mut cut = v.clone();
        cut.drain(7 + 5 * 20..7 + 5 * 20 + 3); // truncate node 20
        let mut p = RplidarParser::new(RplidarConfig::default());
        let mut nodes = 0;
        p.push_nodes(&cut, |_| nodes += 1);
        // node 20 lost; its 2 remaining bytes may still mis-frame a node or two
        assert!((97..=99).contains(&nodes), "{nodes} {:?}", p.stats());
        let mut tail_nodes = 0;
        let mut p2 = RplidarParser::new(RplidarConfig::default());
        p2.push_nodes(&cut[cut.len() - 5 * 20..], |_| tail_nodes += 1);
        assert_eq!(tail_nodes, 20);
    }

    #[test]
    fn nodes_before_first_start_are_counted() {
        let v = revs(2, 10);
        let mut p = RplidarParser::new(RplidarConfig::default());
        p.push(&v[7 + 5 * 3..], 0, |_| {});
        assert_eq!(p.stats().nodes_before_start, 7);
        let mut n = 0;
        p.finish(|s| n = s.len());
        assert_eq!(n, 10);
    }

    #[test]
    fn bad_angle_rejected() {
        let n = RplidarNode {
            start: false,
            quality: 1,
            angle_q6: MAX_ANGLE_Q6 + 1,
            distance_q2: 1,
        };
        assert_eq!(
            RplidarNode::decode(&n.encode()),
            Err(RplidarErrorKind::AngleOutOfRange {
                angle_q6: MAX_ANGLE_Q6 + 1
            })
        );
    }

    #[test]
    fn requests() {
        assert_eq!(scan_request(), [0xA5, 0x20]);
        assert_eq!(stop_request(), [0xA5, 0x25]);
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(chunks in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..300), 0..20)) {
            let mut p = RplidarParser::new(RplidarConfig::default());
            let mut t = 0;
            for c in &chunks {
                t += 1_000_000;
                p.push(c, t, |s| assert!(!s.is_empty()));
            }
            p.finish(|_| {});
            prop_assert_eq!(p.stats().bytes, chunks.iter().map(|c| c.len() as u64).sum::<u64>());
        }

        #[test]
        fn chunking_does_not_change_nodes(cuts in proptest::collection::vec(0usize..1000, 0..12)) {
            let v = revs(2, 100);
            let mut whole = Vec::new();
            RplidarParser::new(RplidarConfig::default()).push_nodes(&v, |n| whole.push(*n));
            let mut cuts = cuts;
            cuts.sort_unstable();
            let mut parts = Vec::new();
            let mut p = RplidarParser::new(RplidarConfig::default());
            let mut prev = 0;
            for c in cuts.into_iter().chain(std::iter::once(v.len())) {
                let c = c.min(v.len());
                p.push_nodes(&v[prev..c], |n| parts.push(*n));
                prev = c;
            }
            prop_assert_eq!(whole.len(), 200);
            prop_assert_eq!(whole, parts);
        }

        #[test]
        fn node_roundtrip(start in any::<bool>(), quality in 0u8..64, angle_q6 in 0u16..=MAX_ANGLE_Q6, distance_q2 in any::<u16>()) {
            let n = RplidarNode { start, quality, angle_q6, distance_q2 };
            prop_assert_eq!(RplidarNode::decode(&n.encode()), Ok(n));
        }
    }
}
