//! LDROBOT LD06 / LD19 serial protocol: streaming, resynchronising decoder,
//! scan assembly with per-point times, and an encoder.
//!
//! # Packet (47 bytes, little-endian fields)
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 1 | header `0x54` |
//! | 1 | 1 | ver_len `0x2C` (upper 3 bits: type, lower 5 bits: 12 points) |
//! | 2 | 2 | rotation speed, degrees per second |
//! | 4 | 2 | start angle, 0.01° (clockwise) |
//! | 6 | 36 | 12 × (distance mm `u16`, intensity `u8`) |
//! | 42 | 2 | end angle, 0.01° |
//! | 44 | 2 | timestamp, ms, wraps at 30000 |
//! | 46 | 1 | CRC-8 of bytes 0..46 |
//!
//! The CRC is CRC-8 with polynomial `0x4D`, initial value 0, no reflection
//! and no final xor, computed MSB first: the vendor's 256-entry `CrcTable`
//! (whose entry `i` is the CRC of the single byte `i`, starting
//! `00 4d 9a d7 79 34 e3 ae`) is generated here from the polynomial and
//! checked against that published prefix in the tests.
//! Point angles are interpolated linearly from the start to the end angle,
//! going through 360° when the end is below the start
//! (`span = (end + 36000 - start) mod 36000`, `step = span / 11`).
//!
//! Sources checked (layout, CRC table, interpolation; no code copied): the
//! LDROBOT ROS 2 driver `ldrobotSensorTeam/ldlidar_stl_ros2`
//! (`ldlidar_driver/src/dataprocess/lipkg.cpp`, `CalCRC8`, `LiPkg::Parse`)
//! and the LD06 development manual's field table as reproduced in several
//! public drivers (e.g. `mikeferguson/stm32` `projects/tablebot/ld06.h`).
//!
//! # What the decoder validates
//!
//! Header byte, ver_len byte, CRC. Bytes that do not start a packet are
//! skipped and counted; after a CRC failure the decoder rescans the 46 bytes
//! after the false header for the next header, so a corrupted or truncated
//! packet costs only itself. The scan assembler additionally rejects packets
//! with a zero speed, an angle ≥ 360°, an angle span above
//! [`Ld06Config::max_span_cdeg`] or one their speed cannot sweep in their points'
//! time (over [`MAX_SPAN_OVER_SWEEP`] times it: a speed or an angle the CRC-8
//! missed, which would date the points up to `span / speed` before the last, 45 s
//! at 1°/s); with [`Ld06Clock::Device`] (the only clock
//! that reads the stamp) also a timestamp ≥ [`Ld06Config::timestamp_wrap_ms`],
//! and a timestamp that jumps (see below).
//! Every rejection is counted in [`Ld06Stats`] and the latest one is kept as
//! an [`Ld06Error`] naming the stream byte offset.
//!
//! # Timing
//!
//! Points are measured at a constant angular rate, so point `i` of a packet is
//! `(11 - i) · step / speed` before the last point. The packet's reference time
//! is one of:
//!
//! * [`Ld06Clock::Device`]: the device timestamp, unwrapped across its 30 s
//!   wrap. The CRC-8 misses one corrupted packet in 256 (and a misframed one
//!   can pass it), so a stamp is trusted only where it follows the last one by
//!   0 to [`MAX_STAMP_STEP_MS`] ms (or four packet intervals, if longer). Any
//!   other step (a jump ahead, or a step back, which the wrap would read as
//!   nearly 30 s ahead) rejects the packet ([`Ld06ErrorKind::TimestampJump`],
//!   [`Ld06Stats::timestamp_jumps`]), unless the packet before was rejected for
//!   a jump and this one follows *that* one within the bound: two packets
//!   agreeing on a new count are a real jump (a gap in the stream, a device
//!   restart), taken as the signed step between the two counts (a step ahead
//!   over half the wrap is a step back). One corrupted stamp costs its packet.
//! * [`Ld06Clock::Host`]: the host clock, from the `rx_ns` passed with each
//!   chunk (the arrival of the chunk's last byte). The device sends a packet
//!   right after measuring its last point, 10 bits a byte (start, 8 data, stop)
//!   at [`Ld06Config::baud`], one packet per 12 points (every
//!   `12 / point_rate_hz` s, [`Ld06Config::point_rate_hz`]; never faster than
//!   the line carries them). So the packet's last point was measured at the
//!   arrival of its own last byte less its own wire time
//!   (`47 · 10 / baud`, 2.04 ms at 230400 baud), and the bytes after it in the
//!   chunk date that arrival: `n` whole packets after it put it `n` packet
//!   intervals before the chunk's end; a trailing part of a packet (`m` bytes)
//!   arrived at 10 bits a byte after that packet began to leave, one packet
//!   interval after the last whole one's last point. Only the host's reading
//!   latency (scheduling, USB) is left, which no byte count can see.
//!
//! [`StampRef`] says which point the reference time belongs to
//! ([`StampRef::LastPoint`] for the host clock: the reference is when the
//! packet began to leave, right after its last point). The ray times stored in
//! the scan are therefore per point.
//!
//! ```
//! use vlsync_signature_lidar::ld06::{Ld06Config, Ld06Encoder, Ld06Parser};
//! let mut enc = Ld06Encoder::new(3600, 0); // 10 Hz, timestamps from 0 ms
//! let mut bytes = Vec::new();
//! for _ in 0..400 { bytes.extend_from_slice(&enc.next_packet(|_deg| 2000)); }
//! let mut parser = Ld06Parser::new(Ld06Config::default());
//! let mut scans = 0;
//! parser.push(&bytes, 0, |scan| { scans += 1; assert!(scan.len() > 0); });
//! assert!(scans >= 10);
//! assert_eq!(parser.stats().crc_errors, 0);
//! ```

use crate::scan::{cw_degrees_to_bearing, Ray, Rotation, Scan, ScanTiming};
use crate::serial::BITS_PER_BYTE;
use std::fmt;
use vlsync_common::Nanos;

/// Packet length in bytes.
pub const PACKET_LEN: usize = 47;
/// First byte of every packet.
pub const HEADER: u8 = 0x54;
/// Second byte of every packet (12 points).
pub const VER_LEN: u8 = 0x2C;
/// Points per packet.
pub const POINTS_PER_PACKET: usize = 12;
/// Measurement rate of the LD06/LD19, points per second.
pub const POINT_RATE_HZ: u32 = 4500;
/// Serial speed of the LD06/LD19.
pub const BAUD: u32 = 230_400;
/// With [`Ld06Clock::Device`], the largest step (ms) from one packet's stamp to
/// the next that is taken without a second packet confirming it (or four packet
/// intervals, if longer): packets come every 2.7 ms, and a few lost to line
/// noise make a step of a few of those.
pub const MAX_STAMP_STEP_MS: u16 = 1000;
/// Largest ratio of a packet's span to the angle its speed sweeps in its 11 point
/// intervals (`speed · 11 / point_rate_hz`) that is taken.
///
/// A packet's 12 points are measured `1 / point_rate_hz` apart at the speed it
/// sends, so the ratio is 1 but for rounding: the speed is whole °/s (0.14 % even
/// at 1 Hz), the angles 0.01° (about 1 % of the 0.88° a packet spans at 1 Hz), and
/// the motor's speed does not change by half within a packet's 2.7 ms. LDROBOT's
/// `LiPkg::Parse` takes a packet whose span (whole degrees) is at most 1.5 times
/// what its speed sweeps in 12 point intervals, 1.64 times the 11 its span covers;
/// the bound here is 1.5 times those 11. At the bound the first point is dated
/// 1.2 ms too early (3.7 ms before the last instead of 2.4 ms); beyond it lie the
/// speeds a corruption the CRC-8 missed (1 in 256) makes: at 1 °/s the first point
/// of an 8.8° packet would be dated 8.8 s before its last. (A speed too high for
/// the span is not refused, nor by LDROBOT: it squeezes the packet's points
/// towards its last, within its own 2.4 ms.)
pub const MAX_SPAN_OVER_SWEEP: f64 = 1.5;

const fn crc_table() -> [u8; 256] {
    let mut t = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u8;
        let mut b = 0;
        while b < 8 {
            c = if c & 0x80 != 0 {
                (c << 1) ^ 0x4D
            } else {
                c << 1
            };
            b += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
}

static CRC_TABLE: [u8; 256] = crc_table();

/// CRC-8 (poly 0x4D, init 0, MSB first) as used by LD06/LD19 packets.
pub fn crc8(bytes: &[u8]) -> u8 {
    bytes
        .iter()
        .fold(0u8, |crc, &b| CRC_TABLE[(crc ^ b) as usize])
}

/// One measured point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Ld06Point {
    /// Distance, mm (0 = no return).
    pub distance_mm: u16,
    /// Intensity (confidence), 0-255.
    pub intensity: u8,
}

/// One decoded packet (fields as sent; not range-checked).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Ld06Packet {
    /// Rotation speed, degrees per second.
    pub speed_dps: u16,
    /// Angle of point 0, 0.01° clockwise.
    pub start_angle_cdeg: u16,
    /// The 12 points.
    pub points: [Ld06Point; POINTS_PER_PACKET],
    /// Angle of point 11, 0.01° clockwise.
    pub end_angle_cdeg: u16,
    /// Device timestamp, ms (wraps at 30000).
    pub timestamp_ms: u16,
}

/// Why a packet was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ld06ErrorKind {
    /// Bytes skipped while looking for a header.
    Garbage {
        /// Number of bytes skipped.
        skipped: u64,
    },
    /// Header `0x54` followed by a wrong ver_len byte.
    BadVerLen {
        /// The byte found.
        found: u8,
    },
    /// CRC mismatch.
    Crc {
        /// CRC computed over bytes 0..46.
        computed: u8,
        /// CRC byte in the packet.
        in_packet: u8,
    },
    /// Rotation speed 0: point times cannot be derived.
    ZeroSpeed,
    /// Start or end angle ≥ 360°.
    AngleOutOfRange {
        /// Start angle, 0.01°.
        start_cdeg: u16,
        /// End angle, 0.01°.
        end_cdeg: u16,
    },
    /// Start-to-end span larger than the configured maximum.
    ImplausibleSpan {
        /// Span, 0.01°.
        span_cdeg: u16,
    },
    /// Start-to-end span over [`MAX_SPAN_OVER_SWEEP`] times what the packet's
    /// speed sweeps in its points' time (a corrupted speed or angle).
    SpanOverSpeed {
        /// Span, 0.01°.
        span_cdeg: u16,
        /// Rotation speed, degrees per second.
        speed_dps: u16,
    },
    /// Timestamp at or above the wrap value.
    TimestampOutOfRange {
        /// Timestamp, ms.
        timestamp_ms: u16,
    },
    /// Timestamp that does not follow the last accepted one by 0 to
    /// [`MAX_STAMP_STEP_MS`] ms (device clock only), unconfirmed by the next packet.
    TimestampJump {
        /// Timestamp, ms.
        timestamp_ms: u16,
        /// The last accepted timestamp, ms.
        last_ms: u16,
    },
}

impl fmt::Display for Ld06ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Ld06ErrorKind::Garbage { skipped } => {
                write!(f, "skipped {skipped} bytes that do not start a packet")
            }
            Ld06ErrorKind::BadVerLen { found } => write!(
                f,
                "header 0x54 followed by 0x{found:02x}, expected ver_len 0x2c"
            ),
            Ld06ErrorKind::Crc {
                computed,
                in_packet,
            } => write!(
                f,
                "CRC mismatch: computed 0x{computed:02x}, packet says 0x{in_packet:02x}"
            ),
            Ld06ErrorKind::ZeroSpeed => write!(f, "rotation speed is 0 deg/s"),
            Ld06ErrorKind::AngleOutOfRange {
                start_cdeg,
                end_cdeg,
            } => write!(
                f,
                "angle out of range: start {start_cdeg}, end {end_cdeg} (0.01 deg, must be < 36000)"
            ),
            Ld06ErrorKind::ImplausibleSpan { span_cdeg } => {
                write!(f, "packet spans {span_cdeg} x 0.01 deg, above the limit")
            }
            Ld06ErrorKind::SpanOverSpeed {
                span_cdeg,
                speed_dps,
            } => write!(
                f,
                "packet spans {span_cdeg} x 0.01 deg, over {MAX_SPAN_OVER_SWEEP} times what \
                 its speed, {speed_dps} deg/s, sweeps in its points' time (a corrupted speed \
                 or angle)"
            ),
            Ld06ErrorKind::TimestampOutOfRange { timestamp_ms } => {
                write!(f, "timestamp {timestamp_ms} ms at or above the wrap value")
            }
            Ld06ErrorKind::TimestampJump {
                timestamp_ms,
                last_ms,
            } => write!(
                f,
                "timestamp {timestamp_ms} ms jumps from the last one, {last_ms} ms \
                 (a corrupted stamp, or a jump the next packet must confirm)"
            ),
        }
    }
}

/// A rejected packet (or skipped run), located in the byte stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ld06Error {
    /// Offset in the stream (bytes since the parser was created) of the
    /// first byte concerned (packet header or first skipped byte).
    pub offset: u64,
    /// What was wrong.
    pub kind: Ld06ErrorKind,
}

impl fmt::Display for Ld06Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "LD06 stream, byte offset {}: {}", self.offset, self.kind)
    }
}

impl std::error::Error for Ld06Error {}

impl Ld06Packet {
    /// Decodes 47 bytes, checking header, ver_len and CRC.
    pub fn decode(b: &[u8; PACKET_LEN]) -> Result<Self, Ld06ErrorKind> {
        if b[0] != HEADER {
            return Err(Ld06ErrorKind::Garbage { skipped: 1 });
        }
        if b[1] != VER_LEN {
            return Err(Ld06ErrorKind::BadVerLen { found: b[1] });
        }
        let computed = crc8(&b[..PACKET_LEN - 1]);
        if computed != b[PACKET_LEN - 1] {
            return Err(Ld06ErrorKind::Crc {
                computed,
                in_packet: b[PACKET_LEN - 1],
            });
        }
        let u16_at = |i: usize| u16::from_le_bytes([b[i], b[i + 1]]);
        let mut points = [Ld06Point::default(); POINTS_PER_PACKET];
        for (i, p) in points.iter_mut().enumerate() {
            let o = 6 + 3 * i;
            *p = Ld06Point {
                distance_mm: u16_at(o),
                intensity: b[o + 2],
            };
        }
        Ok(Self {
            speed_dps: u16_at(2),
            start_angle_cdeg: u16_at(4),
            points,
            end_angle_cdeg: u16_at(42),
            timestamp_ms: u16_at(44),
        })
    }

    /// Encodes the packet, computing the CRC.
    pub fn encode(&self) -> [u8; PACKET_LEN] {
        let mut b = [0u8; PACKET_LEN];
        b[0] = HEADER;
        b[1] = VER_LEN;
        b[2..4].copy_from_slice(&self.speed_dps.to_le_bytes());
        b[4..6].copy_from_slice(&self.start_angle_cdeg.to_le_bytes());
        for (i, p) in self.points.iter().enumerate() {
            let o = 6 + 3 * i;
            b[o..o + 2].copy_from_slice(&p.distance_mm.to_le_bytes());
            b[o + 2] = p.intensity;
        }
        b[42..44].copy_from_slice(&self.end_angle_cdeg.to_le_bytes());
        b[44..46].copy_from_slice(&self.timestamp_ms.to_le_bytes());
        b[46] = crc8(&b[..46]);
        b
    }

    /// Angular span from point 0 to point 11, 0.01°, through 360° if needed.
    pub fn span_cdeg(&self) -> u16 {
        ((self.end_angle_cdeg as u32 + 36000 - self.start_angle_cdeg as u32 % 36000) % 36000) as u16
    }

    /// Clockwise angle of point `i` in degrees, in `[0, 360)`.
    pub fn point_angle_deg(&self, i: usize) -> f64 {
        let step = self.span_cdeg() as f64 / (POINTS_PER_PACKET - 1) as f64;
        let a = (self.start_angle_cdeg as f64 + i as f64 * step) / 100.0;
        a % 360.0
    }
}

/// Decoder counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Ld06Stats {
    /// Bytes pushed.
    pub bytes: u64,
    /// Packets that passed the CRC.
    pub packets: u64,
    /// Bytes skipped while searching for a header.
    pub skipped_bytes: u64,
    /// Headers followed by a wrong ver_len.
    pub bad_ver_len: u64,
    /// Packets with a CRC mismatch.
    pub crc_errors: u64,
    /// CRC-valid packets rejected by the scan assembler (speed, angle, span, a span
    /// the speed cannot sweep, timestamp).
    pub invalid_packets: u64,
    /// Of `invalid_packets`, those rejected for a timestamp jump
    /// ([`Ld06ErrorKind::TimestampJump`], device clock only).
    pub timestamp_jumps: u64,
    /// Scans emitted.
    pub scans: u64,
}

/// Streaming, resynchronising packet decoder (no allocation).
#[derive(Debug, Clone)]
pub struct Ld06Decoder {
    buf: [u8; PACKET_LEN],
    len: usize,
    /// stream offset of `buf[0]`
    buf_offset: u64,
    /// stream offset of the next byte pushed
    offset: u64,
    skip_run: u64,
    skip_run_start: u64,
    /// Stream offset just past the last packet that failed its CRC: a 0x54 not
    /// followed by 0x2C, or a skipped run, that starts before it lies in that
    /// packet's bytes, whose CRC error is reported already, and is not counted or
    /// reported again. (A whole header `54 2C` there is followed as a packet, and
    /// its own CRC error counted: it may be a real packet that cut the failed one
    /// short, as a lost run of bytes does.)
    failed_until: u64,
    stats: Ld06Stats,
    last_error: Option<Ld06Error>,
}

impl Default for Ld06Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Ld06Decoder {
    /// A decoder at stream offset 0.
    pub fn new() -> Self {
        Self {
            buf: [0; PACKET_LEN],
            len: 0,
            buf_offset: 0,
            offset: 0,
            skip_run: 0,
            skip_run_start: 0,
            failed_until: 0,
            stats: Ld06Stats::default(),
            last_error: None,
        }
    }

    /// Counters.
    pub fn stats(&self) -> &Ld06Stats {
        &self.stats
    }

    /// The latest error.
    pub fn last_error(&self) -> Option<Ld06Error> {
        self.last_error
    }

    /// Bytes pushed so far (the stream offset of the next byte).
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// Pushes a chunk; `on_packet(packet, header_offset, bytes_after)` is
    /// called for each valid packet, where `bytes_after` is the number of
    /// bytes of this chunk that follow the packet's last byte.
    pub fn push(&mut self, bytes: &[u8], mut on_packet: impl FnMut(&Ld06Packet, u64, usize)) {
        for (i, &b) in bytes.iter().enumerate() {
            let off = self.offset;
            self.offset += 1;
            self.stats.bytes += 1;
            if let Some((p, at)) = self.step(b, off) {
                on_packet(&p, at, bytes.len() - 1 - i);
            }
        }
    }

    fn error(&mut self, offset: u64, kind: Ld06ErrorKind) {
        self.last_error = Some(Ld06Error { offset, kind });
    }

    fn end_skip_run(&mut self) {
        if self.skip_run > 0 {
            let (start, n) = (self.skip_run_start, self.skip_run);
            // a run inside a failed packet is part of its CRC error, already said
            if start >= self.failed_until {
                self.error(start, Ld06ErrorKind::Garbage { skipped: n });
            }
            self.skip_run = 0;
        }
    }

    fn skip(&mut self, off: u64) {
        if self.skip_run == 0 {
            self.skip_run_start = off;
        }
        self.skip_run += 1;
        self.stats.skipped_bytes += 1;
    }

    /// Feeds one byte at stream offset `off`.
    fn step(&mut self, b: u8, off: u64) -> Option<(Ld06Packet, u64)> {
        match self.len {
            0 => {
                if b == HEADER {
                    self.end_skip_run();
                    self.buf[0] = b;
                    self.buf_offset = off;
                    self.len = 1;
                } else {
                    self.skip(off);
                }
                None
            }
            1 => {
                if b == VER_LEN {
                    self.buf[1] = b;
                    self.len = 2;
                } else {
                    // a 0x54 among a failed packet's bytes is data, not a header: the
                    // packet's CRC error stands for it
                    if self.buf_offset >= self.failed_until {
                        self.stats.bad_ver_len += 1;
                        self.error(self.buf_offset, Ld06ErrorKind::BadVerLen { found: b });
                    }
                    self.len = 0;
                    // the false header byte is skipped; `b` may start a packet
                    self.stats.skipped_bytes += 1;
                    return self.step(b, off);
                }
                None
            }
            _ => {
                self.buf[self.len] = b;
                self.len += 1;
                if self.len < PACKET_LEN {
                    return None;
                }
                self.len = 0;
                match Ld06Packet::decode(&self.buf) {
                    Ok(p) => {
                        self.stats.packets += 1;
                        Some((p, self.buf_offset))
                    }
                    Err(kind) => {
                        self.stats.crc_errors += 1;
                        self.error(self.buf_offset, kind);
                        self.failed_until = self.buf_offset + PACKET_LEN as u64;
                        self.stats.skipped_bytes += 1;
                        // rescan the 46 bytes after the false header; they
                        // cannot complete a packet, so no recursion beyond this
                        let tail = self.buf;
                        let start = self.buf_offset + 1;
                        for (j, &x) in tail[1..].iter().enumerate() {
                            let _ = self.step(x, start + j as u64);
                        }
                        // bytes skipped in the rescan belong to the failed
                        // packet, already reported: no separate garbage report
                        self.skip_run = 0;
                        None
                    }
                }
            }
        }
    }
}

/// Which clock stamps the packets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Ld06Clock {
    /// The device's millisecond timestamp, unwrapped (starts at the first
    /// packet's timestamp); a stamp that jumps is refused unless the next
    /// packet confirms it (see the module docs).
    Device,
    /// Host clock: the arrival of the packet's last byte (from the `rx_ns` given
    /// with each chunk, less the bytes after it) less the packet's own wire time,
    /// which is when its last point was measured (see the module docs).
    #[default]
    Host,
}

/// Which point of a packet the packet's reference time belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StampRef {
    /// Point 0.
    FirstPoint,
    /// Point 11 (the packet is sent after its last point is measured: the
    /// setting for [`Ld06Clock::Host`]).
    #[default]
    LastPoint,
}

/// Scan assembly settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ld06Config {
    /// Clock used for ray times.
    pub clock: Ld06Clock,
    /// Point the reference time belongs to.
    pub stamp_ref: StampRef,
    /// Serial speed: with the host clock, a packet's own wire time and that of
    /// a trailing part of a packet after it (10 bits a byte).
    pub baud: u32,
    /// Points per second measured by the device (4500 for LD06/LD19): sets
    /// the packet interval (12 points), the time between packets on a line
    /// that idles between them, for the whole packets after a packet in a
    /// chunk (host clock), and the device clock's largest unconfirmed step.
    pub point_rate_hz: u32,
    /// The device timestamp wraps at this value, ms.
    pub timestamp_wrap_ms: u16,
    /// Largest accepted start-to-end span of one packet, 0.01°.
    pub max_span_cdeg: u16,
    /// A scan is emitted early if it reaches this many rays. The parser reserves
    /// room for them when it is made (32 bytes a ray: 256 KiB for the default
    /// 8192), so a long scan (a motor below 4.4 Hz holds over 1024 rays, a missed
    /// wrap up to this) never allocates after start-up.
    pub max_scan_rays: usize,
}

impl Default for Ld06Config {
    fn default() -> Self {
        Self {
            clock: Ld06Clock::Host,
            stamp_ref: StampRef::LastPoint,
            baud: BAUD,
            point_rate_hz: POINT_RATE_HZ,
            timestamp_wrap_ms: 30000,
            max_span_cdeg: 4500,
            max_scan_rays: 8192,
        }
    }
}

/// Bytes → packets → full 360° scans with per-point times.
#[derive(Debug, Clone)]
pub struct Ld06Parser {
    cfg: Ld06Config,
    decoder: Ld06Decoder,
    scan: Scan,
    last_angle_deg: Option<f64>,
    speed_dps: u16,
    /// last accepted device stamp and its unwrapped count, ms
    dev_clock: Option<(u16, i64)>,
    /// a stamp rejected for a jump, right before: (stamp, signed step from the
    /// last accepted one, ms)
    dev_jump: Option<(u16, i64)>,
    invalid_packets: u64,
    timestamp_jumps: u64,
    scans: u64,
    last_error: Option<Ld06Error>,
}

impl Ld06Parser {
    /// A parser with the given settings.
    pub fn new(cfg: Ld06Config) -> Self {
        Self {
            cfg,
            decoder: Ld06Decoder::new(),
            // every ray a scan can hold (it is emitted on reaching the limit)
            scan: Scan::with_capacity(cfg.max_scan_rays.max(1)),
            last_angle_deg: None,
            speed_dps: 0,
            dev_clock: None,
            dev_jump: None,
            invalid_packets: 0,
            timestamp_jumps: 0,
            scans: 0,
            last_error: None,
        }
    }

    /// Counters (decoder and assembler).
    pub fn stats(&self) -> Ld06Stats {
        Ld06Stats {
            invalid_packets: self.invalid_packets,
            timestamp_jumps: self.timestamp_jumps,
            scans: self.scans,
            ..*self.decoder.stats()
        }
    }

    /// The latest error from the decoder or the assembler.
    pub fn last_error(&self) -> Option<Ld06Error> {
        match (self.decoder.last_error(), self.last_error) {
            (Some(a), Some(b)) => Some(if a.offset >= b.offset { a } else { b }),
            (a, b) => a.or(b),
        }
    }

    /// Pushes a chunk received at host time `rx_ns` (time of its last byte;
    /// ignored with [`Ld06Clock::Device`]); calls `on_scan` for each scan
    /// completed (when the angle wraps through 0°).
    pub fn push(&mut self, bytes: &[u8], rx_ns: Nanos, mut on_scan: impl FnMut(&Scan)) {
        let mut decoder = std::mem::take(&mut self.decoder);
        decoder.push(bytes, |p, at, after| {
            self.packet(p, at, rx_ns, after, &mut on_scan);
        });
        self.decoder = decoder;
    }

    /// Emits the scan in progress (e.g. at the end of a recording), if any.
    pub fn finish(&mut self, mut on_scan: impl FnMut(&Scan)) {
        self.emit(&mut on_scan);
        self.last_angle_deg = None;
    }

    fn reject(&mut self, offset: u64, kind: Ld06ErrorKind) {
        self.invalid_packets += 1;
        self.last_error = Some(Ld06Error { offset, kind });
    }

    fn packet(
        &mut self,
        p: &Ld06Packet,
        offset: u64,
        rx_ns: Nanos,
        bytes_after: usize,
        on_scan: &mut impl FnMut(&Scan),
    ) {
        if p.speed_dps == 0 {
            return self.reject(offset, Ld06ErrorKind::ZeroSpeed);
        }
        if p.start_angle_cdeg >= 36000 || p.end_angle_cdeg >= 36000 {
            return self.reject(
                offset,
                Ld06ErrorKind::AngleOutOfRange {
                    start_cdeg: p.start_angle_cdeg,
                    end_cdeg: p.end_angle_cdeg,
                },
            );
        }
        let span = p.span_cdeg();
        if span > self.cfg.max_span_cdeg {
            return self.reject(offset, Ld06ErrorKind::ImplausibleSpan { span_cdeg: span });
        }
        // the points are dated `span / 11 / speed` apart: a speed the CRC-8 missed
        // (1 °/s) would date the packet's first points seconds before its last, out
        // of place among the scan's other rays (MAX_SPAN_OVER_SWEEP: the bound)
        let sweep_cdeg = f64::from(p.speed_dps) * 100.0 * (POINTS_PER_PACKET - 1) as f64
            / f64::from(self.cfg.point_rate_hz.max(1));
        if f64::from(span) > MAX_SPAN_OVER_SWEEP * sweep_cdeg {
            return self.reject(
                offset,
                Ld06ErrorKind::SpanOverSpeed {
                    span_cdeg: span,
                    speed_dps: p.speed_dps,
                },
            );
        }
        let wrap = self.cfg.timestamp_wrap_ms.max(1);
        // only a device clock reads the stamp: on the host clock a firmware whose
        // stamp wraps elsewhere still gives its scans
        if self.cfg.clock == Ld06Clock::Device && p.timestamp_ms >= wrap {
            return self.reject(
                offset,
                Ld06ErrorKind::TimestampOutOfRange {
                    timestamp_ms: p.timestamp_ms,
                },
            );
        }
        let reference_ns = match self.cfg.clock {
            Ld06Clock::Device => match self.device_count(p.timestamp_ms) {
                Some(ms) => ms.saturating_mul(1_000_000),
                None => {
                    self.timestamp_jumps += 1;
                    let last_ms = self.dev_clock.map_or(0, |(last, _)| last);
                    return self.reject(
                        offset,
                        Ld06ErrorKind::TimestampJump {
                            timestamp_ms: p.timestamp_ms,
                            last_ms,
                        },
                    );
                }
            },
            Ld06Clock::Host => rx_ns.saturating_sub(self.host_shift_ns(bytes_after)),
        };
        self.speed_dps = p.speed_dps;
        // time between consecutive points: (span / 11) / speed
        let step_deg = span as f64 / 100.0 / (POINTS_PER_PACKET - 1) as f64;
        let point_dt_ns = step_deg / p.speed_dps as f64 * 1e9;
        for (i, pt) in p.points.iter().enumerate() {
            let angle = p.point_angle_deg(i);
            if let Some(prev) = self.last_angle_deg {
                if angle < prev - 180.0 {
                    self.emit(on_scan);
                }
            }
            self.last_angle_deg = Some(angle);
            let k = match self.cfg.stamp_ref {
                StampRef::FirstPoint => i as f64,
                StampRef::LastPoint => i as f64 - (POINTS_PER_PACKET - 1) as f64,
            };
            let t_ns = reference_ns.saturating_add((k * point_dt_ns).round() as i64);
            let range_m = pt.distance_mm as f64 / 1000.0;
            self.scan.push(Ray::timed(
                cw_degrees_to_bearing(angle),
                range_m,
                pt.intensity as f32,
                pt.distance_mm > 0,
                t_ns,
            ));
            if self.scan.len() >= self.cfg.max_scan_rays {
                self.emit(on_scan);
            }
        }
    }

    /// Packet interval (12 points) on a line that carries them, and one byte's
    /// wire time, ns.
    fn intervals_ns(&self) -> (f64, f64) {
        let byte_ns = BITS_PER_BYTE as f64 * 1e9 / self.cfg.baud.max(1) as f64;
        let paced_ns = POINTS_PER_PACKET as f64 * 1e9 / self.cfg.point_rate_hz.max(1) as f64;
        (paced_ns.max(PACKET_LEN as f64 * byte_ns), byte_ns)
    }

    /// Host clock: the time from a packet's last point to the arrival of the last
    /// byte of its chunk, `bytes_after` bytes later (see the module docs).
    fn host_shift_ns(&self, bytes_after: usize) -> i64 {
        let (interval_ns, byte_ns) = self.intervals_ns();
        crate::serial::wire_shift_ns(bytes_after, PACKET_LEN, interval_ns, byte_ns)
    }

    /// Device clock: the unwrapped count (ms) of a stamp, or `None` if the stamp
    /// jumps and is refused (see the module docs).
    fn device_count(&mut self, ts: u16) -> Option<i64> {
        let wrap = i64::from(self.cfg.timestamp_wrap_ms.max(1));
        let (interval_ns, _) = self.intervals_ns();
        let bound = i64::from(MAX_STAMP_STEP_MS)
            .max((4.0 * interval_ns / 1e6).ceil() as i64)
            .min((wrap - 1) / 2);
        // the step from `from` to `to`, signed: within (-wrap / 2, wrap / 2]
        let step = |from: u16, to: u16| {
            let d = (i64::from(to) - i64::from(from)).rem_euclid(wrap);
            if d > wrap / 2 {
                d - wrap
            } else {
                d
            }
        };
        let Some((last, acc)) = self.dev_clock else {
            self.dev_clock = Some((ts, i64::from(ts)));
            return Some(i64::from(ts));
        };
        let d = step(last, ts);
        let acc = if (0..=bound).contains(&d) {
            acc + d
        } else {
            match self.dev_jump.take() {
                // the packet before jumped the same way: a real jump
                Some((jumped, d_jump)) if (0..=bound).contains(&step(jumped, ts)) => {
                    acc + d_jump + step(jumped, ts)
                }
                _ => {
                    self.dev_jump = Some((ts, d));
                    return None;
                }
            }
        };
        self.dev_jump = None;
        self.dev_clock = Some((ts, acc));
        Some(acc)
    }

    fn emit(&mut self, on_scan: &mut impl FnMut(&Scan)) {
        if self.scan.is_empty() {
            return;
        }
        let first = self.scan.rays()[0];
        let period_ns = if self.speed_dps > 0 {
            (360.0 / self.speed_dps as f64 * 1e9).round() as i64
        } else {
            0
        };
        self.scan.set_timing(ScanTiming {
            start_ns: first.t_ns,
            period_ns,
            rotation: Rotation::Cw,
            start_bearing_rad: first.bearing_rad,
        });
        self.scans += 1;
        on_scan(&self.scan);
        self.scan.clear();
    }
}

/// Produces an LD06 byte stream for a simulated scanner turning at a
/// constant speed and measuring [`POINT_RATE_HZ`] points per second.
#[derive(Debug, Clone)]
pub struct Ld06Encoder {
    speed_dps: u16,
    /// angle of the next point, degrees (unbounded)
    angle_deg: f64,
    /// device time of the next point, seconds
    t_s: f64,
}

impl Ld06Encoder {
    /// Starts at angle 0 with the device clock at `start_ms`.
    pub fn new(speed_dps: u16, start_ms: u32) -> Self {
        Self {
            speed_dps,
            angle_deg: 0.0,
            t_s: start_ms as f64 / 1000.0,
        }
    }

    /// Device time (seconds, not wrapped) of the next point to be encoded.
    pub fn next_point_time_s(&self) -> f64 {
        self.t_s
    }

    /// Encodes the next packet; `range_mm(angle_deg)` gives the distance of
    /// the point at that clockwise angle in `[0, 360)`. The timestamp is the
    /// device time of the last point ([`StampRef::LastPoint`]).
    pub fn next_packet(&mut self, mut range_mm: impl FnMut(f64) -> u16) -> [u8; PACKET_LEN] {
        self.next_packet_at(|a, _| range_mm(a))
    }

    /// Like [`Ld06Encoder::next_packet`], with `range_mm(angle_deg, t_s)`
    /// also given the device time (seconds, unwrapped) at which the point is measured.
    pub fn next_packet_at(
        &mut self,
        mut range_mm: impl FnMut(f64, f64) -> u16,
    ) -> [u8; PACKET_LEN] {
        let step = self.speed_dps as f64 / POINT_RATE_HZ as f64;
        let start = self.angle_deg.rem_euclid(360.0);
        let start_cdeg = ((start * 100.0).round() as u32 % 36000) as u16;
        let span_cdeg = (step * (POINTS_PER_PACKET - 1) as f64 * 100.0).round() as u32;
        let end_cdeg = ((start_cdeg as u32 + span_cdeg) % 36000) as u16;
        let mut packet = Ld06Packet {
            speed_dps: self.speed_dps,
            start_angle_cdeg: start_cdeg,
            end_angle_cdeg: end_cdeg,
            ..Default::default()
        };
        for i in 0..POINTS_PER_PACKET {
            let a = packet.point_angle_deg(i);
            let t = self.t_s + i as f64 / POINT_RATE_HZ as f64;
            packet.points[i] = Ld06Point {
                distance_mm: range_mm(a, t),
                intensity: 200,
            };
        }
        let last_t = self.t_s + (POINTS_PER_PACKET - 1) as f64 / POINT_RATE_HZ as f64;
        packet.timestamp_ms = ((last_t * 1000.0).round() as u64 % 30000) as u16;
        self.angle_deg += step * POINTS_PER_PACKET as f64;
        self.t_s += POINTS_PER_PACKET as f64 / POINT_RATE_HZ as f64;
        packet.encode()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn crc_table_matches_vendor_prefix() {
        let vendor = [
            0x00, 0x4d, 0x9a, 0xd7, 0x79, 0x34, 0xe3, 0xae, 0xf2, 0xbf, 0x68, 0x25, 0x8b, 0xc6,
            0x11, 0x5c,
        ];
        assert_eq!(&CRC_TABLE[..16], &vendor);
        // last entries of the vendor table
        assert_eq!(&CRC_TABLE[252..], &[0x7f, 0x32, 0xe5, 0xa8]);
    }

    fn stream(n: usize) -> Vec<u8> {
        let mut enc = Ld06Encoder::new(3600, 100);
        let mut v = Vec::new();
        for _ in 0..n {
            v.extend_from_slice(&enc.next_packet(|a| (1000.0 + a) as u16));
        }
        v
    }

    #[test]
    fn encode_decode_roundtrip() {
        let mut enc = Ld06Encoder::new(3600, 0);
        let b = enc.next_packet(|_| 1234);
        let p = Ld06Packet::decode(&b).unwrap();
        assert_eq!(p.encode(), b);
        assert_eq!(p.speed_dps, 3600);
        assert_eq!(p.points[5].distance_mm, 1234);
    }

    #[test]
    fn corrupted_packet_costs_only_itself() {
        let mut s = stream(20);
        s[47 * 5 + 20] ^= 0x10; // corrupt packet 5
        let mut d = Ld06Decoder::new();
        let mut n = 0;
        d.push(&s, |_, _, _| n += 1);
        assert_eq!(n, 19);
        assert_eq!(d.stats().crc_errors, 1);
        let e = d.last_error().unwrap();
        assert_eq!(e.offset, 47 * 5);
        assert!(e.to_string().contains("byte offset 235"), "{e}");
    }

    #[test]
    fn a_corrupted_packet_holding_a_header_byte_is_one_crc_error() {
        // point 8's distance 0x1254 puts `54 12` at bytes 30-31: a 0x54 that the
        // rescan of the failed packet meets, followed by no 0x2C
        let mut s = stream(20);
        let at = 47 * 5;
        let mut p = Ld06Packet::decode(s[at..at + 47].try_into().unwrap()).unwrap();
        p.points[8].distance_mm = 0x1254;
        s[at..at + 47].copy_from_slice(&p.encode());
        assert_eq!(s[at + 30..at + 32], [0x54, 0x12]);
        // a corrupted byte anywhere after the header, before the 0x54 or after it
        for byte in 2..47 {
            let mut bad = s.clone();
            bad[at + byte] ^= 0x10;
            let mut d = Ld06Decoder::new();
            let mut n = 0;
            d.push(&bad, |_, _, _| n += 1);
            assert_eq!(n, 19, "byte {byte}");
            let st = d.stats();
            assert_eq!(
                (st.crc_errors, st.bad_ver_len),
                (1, 0),
                "byte {byte}: {st:?}"
            );
            let e = d.last_error().unwrap();
            assert_eq!(e.offset, at as u64, "byte {byte}: {e}");
            assert!(
                matches!(e.kind, Ld06ErrorKind::Crc { .. }),
                "byte {byte}: {e}"
            );
        }
        // outside a failed packet, the same bytes are an error of their own
        let mut d = Ld06Decoder::new();
        d.push(&[0x54, 0x12], |_, _, _| {});
        assert_eq!(d.stats().bad_ver_len, 1);
    }

    #[test]
    fn truncated_packet_and_garbage_resync() {
        let s = stream(10);
        let mut bad = Vec::new();
        bad.extend_from_slice(&[1, 2, 3, 0x54, 0x00, 9]);
        bad.extend_from_slice(&s[..47 * 3]);
        bad.extend_from_slice(&s[47 * 3..47 * 3 + 30]); // truncated packet 3
        bad.extend_from_slice(&s[47 * 4..]);
        let mut d = Ld06Decoder::new();
        let mut got = Vec::new();
        d.push(&bad, |p, _, _| got.push(p.start_angle_cdeg));
        // packets 0,1,2 and 4..9 survive; the truncated one swallows packet 4's
        // start but the rescan finds packet 4's header again
        assert_eq!(got.len(), 9, "{:?}", d.stats());
        assert_eq!(d.stats().bad_ver_len, 1);
    }

    #[test]
    fn scans_wrap_and_have_point_times() {
        let s = stream(800);
        let mut p = Ld06Parser::new(Ld06Config {
            clock: Ld06Clock::Device,
            ..Default::default()
        });
        let mut scans = Vec::new();
        p.push(&s, 0, |sc| scans.push(sc.clone()));
        assert!(scans.len() >= 20);
        // full scans: 360 deg at 0.8 deg per point = 450 points
        let full = &scans[1];
        assert_eq!(full.len(), 450);
        assert_eq!(full.timing().period_ns, 100_000_000);
        assert_eq!(full.timing().rotation, Rotation::Cw);
        // consecutive points 1/4500 s apart (±1 ms timestamp quantisation)
        let r = full.rays();
        let dt = r[1].t_ns - r[0].t_ns;
        assert!((dt - 222_222).abs() < 2, "{dt}");
        let total = r[449].t_ns - r[0].t_ns;
        assert!((total - 449 * 222_222).abs() < 1_000_000, "{total}");
        assert!((r[0].bearing_rad).abs() < 1e-9);
    }

    #[test]
    fn device_clock_unwraps() {
        let mut enc = Ld06Encoder::new(3600, 29_900);
        let mut s = Vec::new();
        for _ in 0..100 {
            s.extend_from_slice(&enc.next_packet(|_| 500));
        }
        let mut p = Ld06Parser::new(Ld06Config {
            clock: Ld06Clock::Device,
            ..Default::default()
        });
        let mut last = i64::MIN;
        let mut n = 0;
        p.push(&s, 0, |sc| {
            for r in sc.rays() {
                // device stamps are whole ms: neighbouring packets may overlap by < 1 ms
                assert!(
                    r.t_ns > last.saturating_sub(1_000_000),
                    "{} after {last}",
                    r.t_ns
                );
                last = r.t_ns;
                n += 1;
            }
        });
        p.finish(|sc| n += sc.len());
        assert_eq!(n, 1200);
        assert!(last > 30_000_000_000);
    }

    #[test]
    fn host_clock_subtracts_bytes_after() {
        let s = stream(2);
        let mut p = Ld06Parser::new(Ld06Config::default());
        let mut rays = Vec::new();
        p.push(&s, 1_000_000_000, |_| {});
        p.finish(|sc| rays.extend_from_slice(sc.rays()));
        // the chunk ends with packet 1's last byte: its last point was measured
        // when the packet began to leave, its 47 bytes' wire time (2.04 ms at
        // 230400 baud) before; the device sends one packet per 12 points, so
        // packet 0 left one packet interval (12 / 4500 s) before packet 1.
        // (This test used to expect 1 s and 1 s - 2.67 ms: the arrival of the
        // packets' last bytes, 2.04 ms after their last points.)
        // 47 * 10 / 230400 s = 2_039_930.6 ns, 12 / 4500 s = 2_666_666.7 ns
        assert_eq!(rays[23].t_ns, 1_000_000_000 - 2_039_931);
        assert_eq!(rays[11].t_ns, 1_000_000_000 - 4_706_597);
    }

    /// The stream of [`crate::encode::ld06_stream`] read in chunks of 1 to 150
    /// bytes, each dated at its last byte's arrival (the device sends a packet
    /// right after its last point, 10 bits a byte): every ray is dated at the
    /// device time of its point, whatever the chunking.
    #[test]
    fn host_stamps_are_the_points_measurement_times() {
        use crate::encode::{ld06_byte_arrival_s, ld06_stream};
        let bytes = ld06_stream(3600, 0, 0.5, |_, _| 2.0);
        for baud in [BAUD, 921_600] {
            let mut p = Ld06Parser::new(Ld06Config {
                baud,
                ..Ld06Config::default()
            });
            let mut rays = Vec::new();
            let (mut at, mut rng) = (0, 12345u64);
            while at < bytes.len() {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let n = (1 + (rng >> 33) as usize % 150).min(bytes.len() - at);
                let rx = (ld06_byte_arrival_s(at + n - 1, baud) * 1e9).round() as Nanos;
                p.push(&bytes[at..at + n], rx, |sc| {
                    rays.extend_from_slice(sc.rays())
                });
                at += n;
            }
            p.finish(|sc| rays.extend_from_slice(sc.rays()));
            assert_eq!(rays.len(), bytes.len() / PACKET_LEN * POINTS_PER_PACKET);
            for (i, r) in rays.iter().enumerate() {
                // point i measured at i / 4500 s
                let truth = (i as f64 / POINT_RATE_HZ as f64 * 1e9).round() as Nanos;
                assert!(
                    (r.t_ns - truth).abs() <= 2,
                    "{baud} baud, point {i}: {} ns, measured at {truth} ns",
                    r.t_ns
                );
            }
        }
    }

    /// Device-clock packets from `enc`, `n` of them, with packet `k`'s stamp
    /// changed by `bad(k)` (the CRC recomputed: a corruption the CRC-8 misses).
    fn stamped(enc: &mut Ld06Encoder, n: usize, bad: impl Fn(usize) -> Option<u16>) -> Vec<u8> {
        let mut v = Vec::new();
        for k in 0..n {
            let mut b = enc.next_packet(|_| 2000);
            if let Some(ts) = bad(k) {
                let mut p = Ld06Packet::decode(&b).unwrap();
                p.timestamp_ms = ts;
                b = p.encode();
            }
            v.extend_from_slice(&b);
        }
        v
    }

    /// Ray times (ns, sorted: a scan keeps its rays in time order, not the
    /// stream) through a device-clock parser, its stats and last error.
    fn device_times(bytes: &[u8]) -> (Vec<Nanos>, Ld06Stats, Option<Ld06Error>) {
        let mut p = Ld06Parser::new(Ld06Config {
            clock: Ld06Clock::Device,
            ..Default::default()
        });
        let mut t = Vec::new();
        p.push(bytes, 0, |sc| t.extend(sc.rays().iter().map(|r| r.t_ns)));
        p.finish(|sc| t.extend(sc.rays().iter().map(|r| r.t_ns)));
        t.sort_unstable();
        (t, p.stats(), p.last_error())
    }

    /// The stamp of packet `k` of an encoder started at `start_ms` (its last point).
    fn stamp_of(start_ms: u32, k: usize) -> u16 {
        let t = start_ms as f64 + (k * POINTS_PER_PACKET + 11) as f64 * 1000.0 / 4500.0;
        (t.round() as u32 % 30_000) as u16
    }

    /// The ray times of packet `k` of an encoder started at `start_ms`, on the
    /// device clock (its stamp is its last point's time, whole ms): the packet
    /// alone through a parser, whose count starts at the first stamp.
    fn packet_times(start_ms: u32, k: usize) -> Vec<Nanos> {
        let b = stamped(&mut Ld06Encoder::new(3600, start_ms), k + 1, |_| None);
        device_times(&b[k * PACKET_LEN..]).0
    }

    /// Removes one occurrence of each of `xs` from `v` (neighbouring packets'
    /// whole-ms stamps can give two rays the same time).
    fn remove_each(v: &mut Vec<Nanos>, xs: &[Nanos]) {
        for x in xs {
            let i = v.iter().position(|t| t == x).expect("a ray at that time");
            v.remove(i);
        }
    }

    #[test]
    fn one_corrupted_device_stamp_costs_its_packet_not_every_later_time() {
        let truth = device_times(&stamped(&mut Ld06Encoder::new(3600, 1000), 60, |_| None)).0;
        // packet 30's stamp reads 300 ms early (the wrap would take it as 29.7 s
        // late), or 5 s late, or just short of the wrap (a step back over it)
        let ts = stamp_of(1000, 30);
        for bad in [ts - 300, ts + 5000, 29_990] {
            let bytes = stamped(&mut Ld06Encoder::new(3600, 1000), 60, |k| {
                (k == 30).then_some(bad)
            });
            let (got, st, e) = device_times(&bytes);
            assert_eq!((st.invalid_packets, st.timestamp_jumps), (1, 1), "{st:?}");
            assert_eq!(
                e.unwrap().kind,
                Ld06ErrorKind::TimestampJump {
                    timestamp_ms: bad,
                    last_ms: stamp_of(1000, 29)
                }
            );
            // every packet but the bad one, at its own time
            let mut want: Vec<Nanos> = truth.clone();
            remove_each(&mut want, &packet_times(1000, 30));
            assert!(
                got == want,
                "stamp {bad}: {} rays, want {}",
                got.len(),
                want.len()
            );
        }
    }

    /// 10 Hz packets from an encoder started at 1000 ms, `n` of them, with packet
    /// `k`'s speed changed to `speed(k)` (the CRC recomputed: a corruption the CRC-8
    /// misses).
    fn respeeded(n: usize, speed: impl Fn(usize) -> Option<u16>) -> Vec<u8> {
        let mut enc = Ld06Encoder::new(3600, 1000);
        let mut v = Vec::new();
        for k in 0..n {
            let mut b = enc.next_packet(|_| 2000);
            if let Some(dps) = speed(k) {
                let mut p = Ld06Packet::decode(&b).unwrap();
                p.speed_dps = dps;
                b = p.encode();
            }
            v.extend_from_slice(&b);
        }
        v
    }

    #[test]
    fn a_packet_whose_speed_cannot_sweep_its_span_is_refused() {
        let truth = device_times(&respeeded(60, |_| None)).0;
        // packet 30 (8.8 deg, 880 x 0.01 deg, at 3600 deg/s) says 1 deg/s: its first
        // point would be dated 8.8 s before its last; 2000 deg/s, 4.4 ms before
        // (1.8 times its 2.4 ms: the bound, 1.5 times, is 2400 deg/s)
        for bad in [1, 100, 2000] {
            let bytes = respeeded(60, |k| (k == 30).then_some(bad));
            let (got, st, e) = device_times(&bytes);
            assert_eq!((st.invalid_packets, st.crc_errors), (1, 0), "{st:?}");
            let e = e.unwrap();
            assert_eq!(
                (e.offset, e.kind),
                (
                    30 * PACKET_LEN as u64,
                    Ld06ErrorKind::SpanOverSpeed {
                        span_cdeg: 880,
                        speed_dps: bad
                    }
                )
            );
            assert!(e.to_string().contains(&format!(" {bad} deg/s")), "{e}");
            // every packet but the bad one, at its own time
            let mut want = truth.clone();
            remove_each(&mut want, &packet_times(1000, 30));
            assert!(
                got == want,
                "{bad} deg/s: {} rays, want {}",
                got.len(),
                want.len()
            );
            // on the host clock: no ray before the first packet's first point
            let mut p = Ld06Parser::new(Ld06Config::default());
            let rx = 100_000_000_000;
            let mut first = Nanos::MAX;
            p.push(&bytes, rx, |sc| first = first.min(sc.rays()[0].t_ns));
            p.finish(|sc| first = first.min(sc.rays()[0].t_ns));
            assert_eq!(p.stats().invalid_packets, 1);
            // 60 packets 12 / 4500 s apart, the last's last point 2.04 ms (its wire
            // time) before rx, the first's first point 11 / 4500 s before its last
            let earliest = rx
                - 2_039_931
                - (59.0 * 12.0 / 4500.0 * 1e9_f64).round() as Nanos
                - (11.0 / 4500.0 * 1e9_f64).round() as Nanos;
            assert!((first - earliest).abs() <= 2, "{bad} deg/s: {first}");
        }
        // a speed a quarter low (motor ripple far beyond a real one's) is still taken
        let bytes = respeeded(60, |k| (k == 30).then_some(2700));
        assert_eq!(device_times(&bytes).1.invalid_packets, 0);
    }

    #[test]
    fn a_jump_two_packets_agree_on_is_taken_and_the_wrap_still_unwraps() {
        // a gap in the stream: the device clock goes on 4 s later (2 s past its wrap)
        let mut enc = Ld06Encoder::new(3600, 28_000);
        let mut bytes = stamped(&mut enc, 40, |_| None);
        for _ in 0..1500 {
            enc.next_packet(|_| 0); // 4 s not sent
        }
        bytes.extend(stamped(&mut enc, 40, |_| None));
        let (got, st, _) = device_times(&bytes);
        // the first packet after the gap is refused, the second confirms it
        assert_eq!((st.invalid_packets, st.timestamp_jumps), (1, 1), "{st:?}");
        assert_eq!(got.len(), 79 * 12);
        // the last packet (1579) at its stamp, unwrapped past 30 s
        let last = 30_000 + i64::from(stamp_of(28_000, 1579));
        assert_eq!(*got.last().unwrap(), last * 1_000_000);
        // a stamp 0.57 s ahead is taken (within the bound); the next packet, back
        // on time, is refused, and the one after it confirms the step back
        let truth = device_times(&stamped(&mut Ld06Encoder::new(3600, 1000), 40, |_| None)).0;
        let bytes = stamped(&mut Ld06Encoder::new(3600, 1000), 40, |k| {
            (k == 10).then_some(1600)
        });
        let (got, st, _) = device_times(&bytes);
        assert_eq!((st.invalid_packets, st.timestamp_jumps), (1, 1), "{st:?}");
        let ahead = (1600 - i64::from(stamp_of(1000, 10))) * 1_000_000;
        let mut want: Vec<Nanos> = truth.clone();
        let (p10, p11) = (packet_times(1000, 10), packet_times(1000, 11));
        remove_each(&mut want, &p10);
        remove_each(&mut want, &p11);
        want.extend(p10.iter().map(|t| t + ahead));
        want.sort_unstable();
        assert!(got == want, "{} rays, want {}", got.len(), want.len());
    }

    #[test]
    fn invalid_fields_rejected_with_offsets() {
        let mut s = Vec::new();
        let zero = Ld06Packet::default().encode();
        s.extend_from_slice(&zero);
        let bad_angle = Ld06Packet {
            speed_dps: 3600,
            start_angle_cdeg: 40000,
            ..Default::default()
        }
        .encode();
        s.extend_from_slice(&bad_angle);
        let mut p = Ld06Parser::new(Ld06Config::default());
        p.push(&s, 0, |_| panic!("no scan expected"));
        assert_eq!(p.stats().invalid_packets, 2);
        let e = p.last_error().unwrap();
        assert_eq!(e.offset, 47);
        assert!(matches!(e.kind, Ld06ErrorKind::AngleOutOfRange { .. }));
    }

    #[test]
    fn a_stamp_beyond_the_wrap_is_refused_only_where_the_stamp_is_read() {
        let odd = Ld06Packet {
            speed_dps: 3600,
            start_angle_cdeg: 1000,
            end_angle_cdeg: 1100,
            timestamp_ms: 40_000,
            ..Default::default()
        }
        .encode();
        for (clock, refused) in [(Ld06Clock::Device, 1), (Ld06Clock::Host, 0)] {
            let mut p = Ld06Parser::new(Ld06Config {
                clock,
                ..Ld06Config::default()
            });
            p.push(&odd, 1_000_000_000, |_| {});
            assert_eq!(p.stats().invalid_packets, refused, "{clock:?}");
            if refused == 1 {
                assert!(matches!(
                    p.last_error().unwrap().kind,
                    Ld06ErrorKind::TimestampOutOfRange {
                        timestamp_ms: 40_000
                    }
                ));
            }
        }
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(chunks in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..200), 0..20)) {
            let mut p = Ld06Parser::new(Ld06Config::default());
            for c in &chunks {
                p.push(c, 0, |_| {});
            }
            p.finish(|_| {});
            let st = p.stats();
            prop_assert_eq!(st.bytes, chunks.iter().map(|c| c.len() as u64).sum::<u64>());
        }

        #[test]
        fn chunking_does_not_change_decoding(cuts in proptest::collection::vec(0usize..47 * 30, 0..12)) {
            let s = stream(30);
            let mut whole = Vec::new();
            let mut d = Ld06Decoder::new();
            d.push(&s, |p, at, _| whole.push((*p, at)));
            let mut cuts = cuts;
            cuts.sort_unstable();
            let mut parts = Vec::new();
            let mut d2 = Ld06Decoder::new();
            let mut prev = 0;
            for c in cuts.into_iter().chain(std::iter::once(s.len())) {
                d2.push(&s[prev..c], |p, at, _| parts.push((*p, at)));
                prev = c;
            }
            prop_assert_eq!(whole.len(), 30);
            prop_assert_eq!(whole, parts);
        }

        #[test]
        fn device_clock_scans_independent_of_chunking(cuts in proptest::collection::vec(0usize..47 * 120, 0..16)) {
            let s = stream(120);
            let cfg = Ld06Config { clock: Ld06Clock::Device, ..Default::default() };
            let mut whole = Vec::new();
            let mut p = Ld06Parser::new(cfg);
            p.push(&s, 0, |sc| whole.push(sc.clone()));
            p.finish(|sc| whole.push(sc.clone()));
            let mut cuts = cuts;
            cuts.sort_unstable();
            let mut parts = Vec::new();
            let mut p2 = Ld06Parser::new(cfg);
            let mut prev = 0;
            for c in cuts.into_iter().chain(std::iter::once(s.len())) {
                p2.push(&s[prev..c], 0, |sc| parts.push(sc.clone()));
                prev = c;
            }
            p2.finish(|sc| parts.push(sc.clone()));
            prop_assert_eq!(whole.len(), 4); // 1152 deg: 3 full turns and a partial one
            prop_assert_eq!(whole, parts);
        }

        #[test]
        fn garbage_between_packets_keeps_all_packets(gap in proptest::collection::vec(any::<u8>().prop_filter("no header", |b| *b != HEADER), 0..60)) {
            let s = stream(6);
            let mut v = Vec::new();
            for k in 0..6 {
                v.extend_from_slice(&gap);
                v.extend_from_slice(&s[47 * k..47 * (k + 1)]);
            }
            let mut d = Ld06Decoder::new();
            let mut n = 0;
            d.push(&v, |_, _, _| n += 1);
            prop_assert_eq!(n, 6);
            prop_assert_eq!(d.stats().skipped_bytes, 6 * gap.len() as u64);
        }
    }
}
