//! Encoders producing device byte streams, for simulators and tests.
//!
//! The world is described by a function `range_m(t_s, bearing_rad)` giving
//! the range seen at time `t_s` (seconds) in the direction `bearing_rad`
//! (CCW positive, the crate's convention); a non-finite or non-positive range
//! encodes "no return".
//!
//! A host reading the bytes sees them arrive as the devices send them: a packet
//! (LD06) or node (RPLIDAR) leaves right after its last point is measured, 10
//! bits a byte (start, 8 data, stop) at the line's baud rate.
//! [`ld06_byte_arrival_s`] and [`rplidar_byte_arrival_s`] give that arrival time
//! for each byte of [`ld06_stream`] and [`rplidar_revolution`], the model the
//! parsers' host clocks undo.
//!
//! ```
//! use vlsync_signature_lidar::encode::ld06_stream;
//! use vlsync_signature_lidar::ld06::{Ld06Clock, Ld06Config, Ld06Parser};
//! let bytes = ld06_stream(3600, 0, 0.5, |_t, _b| 2.0);
//! let mut p = Ld06Parser::new(Ld06Config { clock: Ld06Clock::Device, ..Default::default() });
//! let mut rays = 0;
//! p.push(&bytes, 0, |s| rays += s.len());
//! assert!(rays >= 4 * 450);
//! ```

pub use crate::ld06::{Ld06Encoder, Ld06Packet, Ld06Point};
pub use crate::rplidar::{
    scan_request, stop_request, RplidarEncoder, RplidarNode, SCAN_DESCRIPTOR, SCAN_REQUEST,
    STOP_REQUEST,
};

use crate::ld06::{PACKET_LEN, POINTS_PER_PACKET, POINT_RATE_HZ};
use crate::rplidar::{MAX_ANGLE_Q6, NODE_LEN};
use crate::scan::cw_degrees_to_bearing;
use crate::serial::BITS_PER_BYTE;

fn to_units(range_m: f64, per_m: f64) -> u16 {
    if range_m.is_finite() && range_m > 0.0 {
        (range_m * per_m).round().min(u16::MAX as f64) as u16
    } else {
        0
    }
}

/// `seconds` of LD06/LD19 output at `speed_dps` degrees per second, the
/// device clock starting at `start_ms` (it wraps at 30000 ms). Point `i` is
/// measured at `start_ms / 1000 + i / 4500` s; `range_m` is called with that
/// time measured from the start of the stream (0 for the first point).
pub fn ld06_stream(
    speed_dps: u16,
    start_ms: u32,
    seconds: f64,
    mut range_m: impl FnMut(f64, f64) -> f64,
) -> Vec<u8> {
    let mut enc = Ld06Encoder::new(speed_dps, start_ms);
    let t0 = start_ms as f64 / 1000.0;
    let packets = if seconds.is_finite() && seconds > 0.0 {
        (seconds * POINT_RATE_HZ as f64 / 12.0).ceil() as usize
    } else {
        0
    };
    let mut out = Vec::with_capacity(packets * crate::ld06::PACKET_LEN);
    for _ in 0..packets {
        out.extend_from_slice(&enc.next_packet_at(|deg, t| {
            to_units(range_m(t - t0, cw_degrees_to_bearing(deg)), 1000.0)
        }));
    }
    out
}

/// When (s, on [`ld06_stream`]'s time axis: 0 at the stream's first point) byte
/// `i` of an [`ld06_stream`] has arrived at a host reading a line at `baud`:
/// packet `k` leaves right after its last point, measured at
/// `(12 k + 11) / 4500` s, and its byte `j` has arrived `(j + 1) · 10 / baud`
/// later (a host read returning bytes `..=i` is dated by this).
///
/// ```
/// use vlsync_signature_lidar::encode::ld06_byte_arrival_s;
/// // the last byte of the first packet: its last point, then 47 bytes at 230400 baud
/// let t = ld06_byte_arrival_s(46, 230_400);
/// assert!((t - (11.0 / 4500.0 + 47.0 * 10.0 / 230_400.0)).abs() < 1e-12);
/// ```
pub fn ld06_byte_arrival_s(i: usize, baud: u32) -> f64 {
    let (k, j) = (i / PACKET_LEN, i % PACKET_LEN);
    let last_point_s =
        (k * POINTS_PER_PACKET + POINTS_PER_PACKET - 1) as f64 / POINT_RATE_HZ as f64;
    last_point_s + (j + 1) as f64 * BITS_PER_BYTE as f64 / baud.max(1) as f64
}

/// When (s) byte `i` of the output of [`rplidar_revolution`]`(nodes, t0_s,
/// period_s, ..)` has arrived at a host reading a line at `baud`: node `n`
/// leaves when it is measured, at `t0_s + n · period_s / nodes`, and its byte `j`
/// has arrived `(j + 1) · 10 / baud` later.
pub fn rplidar_byte_arrival_s(i: usize, nodes: usize, t0_s: f64, period_s: f64, baud: u32) -> f64 {
    let (n, j) = (i / NODE_LEN, i % NODE_LEN);
    t0_s + n as f64 * period_s / nodes.max(1) as f64
        + (j + 1) as f64 * BITS_PER_BYTE as f64 / baud.max(1) as f64
}

/// One RPLIDAR revolution of `nodes` evenly spaced nodes starting at 0°
/// (start flag on the first), node `i` measured at `t0_s + i · period_s / nodes`.
pub fn rplidar_revolution(
    nodes: usize,
    t0_s: f64,
    period_s: f64,
    mut range_m: impl FnMut(f64, f64) -> f64,
) -> Vec<u8> {
    let nodes = nodes.max(1);
    let mut out = Vec::with_capacity(nodes * 5);
    for i in 0..nodes {
        let q6 = ((i as u64 * MAX_ANGLE_Q6 as u64) / nodes as u64) as u16;
        let t = t0_s + i as f64 * period_s / nodes as f64;
        let q2 = to_units(range_m(t, cw_degrees_to_bearing(q6 as f64 / 64.0)), 4000.0);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rplidar::{RplidarConfig, RplidarParser};

    #[test]
    fn rplidar_revolutions_decode() {
        let mut bytes = SCAN_DESCRIPTOR.to_vec();
        for k in 0..3 {
            bytes.extend(rplidar_revolution(200, k as f64 * 0.2, 0.2, |t, b| {
                if b > 0.0 {
                    1.0 + t
                } else {
                    f64::NAN
                }
            }));
        }
        // one chunk: the parser dates the nodes at its node rate, which must be
        // the stream's (200 nodes in 0.2 s), else the turns are not of the
        // nominal period and the first is dropped
        let mut p = RplidarParser::new(RplidarConfig {
            sample_rate_hz: 1000,
            nominal_period_ns: 200_000_000,
            ..RplidarConfig::default()
        });
        let mut scans = Vec::new();
        p.push(&bytes, 0, |s| scans.push(s.clone()));
        assert_eq!(scans.len(), 2, "{:?}", p.stats());
        assert_eq!(scans[0].timing().period_ns, 200_000_000);
        let valid = scans[0].rays().iter().filter(|r| r.valid).count();
        assert!((98..=101).contains(&valid), "{valid}");
    }

    #[test]
    fn ld06_stream_length() {
        assert_eq!(ld06_stream(3600, 0, 1.0, |_, _| 1.0).len(), 375 * 47);
        assert!(ld06_stream(3600, 0, f64::NAN, |_, _| 1.0).is_empty());
    }
}
