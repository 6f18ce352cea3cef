//! Encoders producing device byte streams, for simulators and tests.
//!
//! The world is described by a function `range_m(t_s, bearing_rad)` giving
//! the range seen at time `t_s` (seconds) in the direction `bearing_rad`
//! (CCW positive, the crate's convention); a non-finite or non-positive range
//! encodes "no return".
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

use crate::ld06::POINT_RATE_HZ;
use crate::rplidar::MAX_ANGLE_Q6;
use crate::scan::cw_degrees_to_bearing;

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
        let mut p = RplidarParser::new(RplidarConfig::default());
        let mut scans = Vec::new();
        p.push(&bytes, 0, |s| scans.push(s.clone()));
        assert_eq!(scans.len(), 2);
        let valid = scans[0].rays().iter().filter(|r| r.valid).count();
        assert!((98..=101).contains(&valid), "{valid}");
    }

    #[test]
    fn ld06_stream_length() {
        assert_eq!(ld06_stream(3600, 0, 1.0, |_, _| 1.0).len(), 375 * 47);
        assert!(ld06_stream(3600, 0, f64::NAN, |_, _| 1.0).is_empty());
    }
}
