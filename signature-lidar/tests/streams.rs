//! End to end: synthesised LD06 and RPLIDAR byte streams of a wall moving with
//! known motion, damaged (flipped bytes, truncated packets, garbage), parsed
//! and turned into the signature, compared with the true distance rate.

use std::f64::consts::PI;
use vlsync_common::{nanos_to_secs, Sample};
use vlsync_signature_lidar::ld06::{Ld06Clock, Ld06Config, Ld06Encoder, Ld06Parser, POINT_RATE_HZ};
use vlsync_signature_lidar::rplidar::{RplidarConfig, RplidarNode, RplidarParser, SCAN_DESCRIPTOR};
use vlsync_signature_lidar::{SignatureConfig, SignatureProcessor, Stamping};

/// Wall distance (m, perpendicular) at time t (s): 2 m +- 0.3 m at 0.5 Hz.
fn wall(t: f64) -> f64 {
    2.0 + 0.3 * (PI * t).sin()
}

fn wall_rate(t: f64) -> f64 {
    0.3 * PI * (PI * t).cos()
}

/// Tiny deterministic generator for the damage.
struct XorShift(u64);
impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// Damages ~`rate` of the packets of `len` bytes in `stream`.
fn damage(stream: &[u8], len: usize, rate_per_mille: u64, rng: &mut XorShift) -> (Vec<u8>, usize) {
    let mut out = Vec::with_capacity(stream.len() + stream.len() / 10);
    let mut damaged = 0;
    for p in stream.chunks(len) {
        match (rng.below(1000) < rate_per_mille, rng.below(3)) {
            (false, _) => out.extend_from_slice(p),
            (true, 0) => {
                // flipped byte
                let mut q = p.to_vec();
                let i = rng.below(q.len() as u64) as usize;
                q[i] ^= 1 << rng.below(8);
                out.extend_from_slice(&q);
                damaged += 1;
            }
            (true, 1) => {
                // truncated
                let keep = rng.below(p.len() as u64) as usize;
                out.extend_from_slice(&p[..keep]);
                damaged += 1;
            }
            (true, _) => {
                // garbage before an intact packet
                for _ in 0..rng.below(40) {
                    out.push(rng.next() as u8);
                }
                out.extend_from_slice(p);
            }
        }
    }
    (out, damaged)
}

fn errors(samples: &[Sample], skip_first: usize) -> (f64, f64) {
    let e: Vec<f64> = samples
        .iter()
        .skip(skip_first)
        .map(|s| s.value - wall_rate(nanos_to_secs(s.t_ns)))
        .collect();
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    let max = e.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    (rms, max)
}

fn ld06_stream(seconds: f64) -> Vec<u8> {
    // device clock starts at 25 s, so it wraps (30 s) during the run
    let start_ms = 25_000u32;
    let mut enc = Ld06Encoder::new(3600, start_ms);
    let packets = (seconds * POINT_RATE_HZ as f64 / 12.0) as usize;
    let mut v = Vec::with_capacity(packets * 47);
    for _ in 0..packets {
        let t0 = enc.next_point_time_s() - start_ms as f64 / 1000.0;
        let mut i = 0;
        v.extend_from_slice(&enc.next_packet(|a| {
            let t = t0 + i as f64 / POINT_RATE_HZ as f64;
            i += 1;
            // a flat wall on the left, its normal at clockwise device angle 270 deg
            // (bearing +90 deg): the range at angle a is wall / cos(a - 270)
            if (a - 270.0).abs() < 20.0 {
                (wall(t) * 1000.0 / (a - 270.0).to_radians().cos()).round() as u16
            } else {
                5000
            }
        }));
    }
    v
}

fn ld06_signature(
    bytes: &[u8],
    stamping: Stamping,
) -> (Vec<Sample>, Ld06Parser, SignatureProcessor) {
    let mut parser = Ld06Parser::new(Ld06Config {
        clock: Ld06Clock::Device,
        ..Default::default()
    });
    let mut sig = SignatureProcessor::new(SignatureConfig {
        window_centre_rad: PI / 2.0,
        window_half_width_rad: 4f64.to_radians(),
        max_gap_ns: 250_000_000,
        stamping,
        ..Default::default()
    })
    .unwrap();
    let mut out = Vec::new();
    for chunk in bytes.chunks(500) {
        parser.push(chunk, 0, |scan| {
            sig.push_scan(scan, |s| {
                // device clock started at 25 s: shift to the wall's time axis
                out.push(Sample::new(s.t_ns - 25_000_000_000, s.value))
            });
        });
    }
    (out, parser, sig)
}

#[test]
fn ld06_clean_stream_recovers_wall_rate_and_midpoint_beats_end() {
    let bytes = ld06_stream(12.0);
    let (mid, parser, sig) = ld06_signature(&bytes, Stamping::Midpoint);
    assert_eq!(parser.stats().crc_errors, 0);
    assert!(
        mid.len() >= 115,
        "{} samples, {:?}",
        mid.len(),
        sig.counters()
    );
    let (rms, max) = errors(&mid, 0);
    // range quantisation 1 mm over 0.1 s gives ~0.01 m/s; finite difference bias < 0.5 %
    assert!(rms < 0.02 && max < 0.05, "midpoint rms {rms} max {max}");

    let (end, _, _) = ld06_signature(&bytes, Stamping::End);
    let (rms_end, _) = errors(&end, 0);
    eprintln!(
        "ld06 clean: {} samples, midpoint rms {rms:.4} max {max:.4}, end rms {rms_end:.4}",
        mid.len()
    );
    // stamping at the end is 50 ms late: error ~ 0.3 pi^2 * 0.05 / sqrt 2 ~ 0.1 m/s
    assert!(
        rms_end > 4.0 * rms,
        "end rms {rms_end} vs midpoint rms {rms}"
    );
}

#[test]
fn ld06_damaged_stream_resyncs_and_stays_accurate() {
    let clean = ld06_stream(12.0);
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15);
    let (bytes, damaged) = damage(&clean, 47, 30, &mut rng);
    assert!(damaged > 20);
    let (samples, parser, sig) = ld06_signature(&bytes, Stamping::Midpoint);
    let st = parser.stats();
    assert!(st.crc_errors > 0 && st.skipped_bytes > 0, "{st:?}");
    // most packets survive: a damaged packet costs itself and rarely its neighbour
    let total = clean.len() / 47;
    assert!(
        st.packets as usize >= total - 2 * damaged,
        "{st:?} damaged {damaged}"
    );
    assert!(
        samples.len() >= 90,
        "{} samples {:?}",
        samples.len(),
        sig.counters()
    );
    let (rms, max) = errors(&samples, 0);
    eprintln!(
        "ld06 damaged: {} samples, rms {rms:.4} max {max:.4}, {st:?}",
        samples.len()
    );
    assert!(
        rms < 0.03 && max < 0.1,
        "rms {rms} max {max} {:?}",
        sig.counters()
    );
}

/// RPLIDAR at 5.5 Hz, 360 nodes per revolution; nodes leave the device as
/// they are measured, chunks of `chunk_nodes` nodes reach the host stamped
/// with the arrival of their last byte: the true time of their last node plus
/// its 5 bytes' wire time at 115200 baud (10 bits a byte), which the parser
/// takes off.
fn rplidar_stream(revs: usize, chunk_nodes: usize) -> (Vec<(Vec<u8>, i64)>, RplidarConfig) {
    let period_ns = 181_818_182i64;
    let n = 360usize;
    let node_dt = period_ns as f64 / n as f64;
    let mut chunks = vec![(SCAN_DESCRIPTOR.to_vec(), 0)];
    let mut cur = Vec::new();
    for k in 0..revs {
        for i in 0..n {
            let t_ns = k as f64 * period_ns as f64 + i as f64 * node_dt;
            let angle = i as f64;
            // a flat wall, normal at device angle 270 deg (bearing +90 deg)
            let d_mm = if (angle - 270.0).abs() < 20.0 {
                wall(t_ns * 1e-9) * 1000.0 / (angle - 270.0).to_radians().cos()
            } else {
                4000.0
            };
            let node = RplidarNode {
                start: i == 0,
                quality: 40,
                angle_q6: (angle * 64.0) as u16,
                distance_q2: (d_mm * 4.0).round() as u16,
            };
            cur.extend_from_slice(&node.encode());
            if cur.len() == chunk_nodes * 5 {
                let wire_ns = 5.0 * 10.0 * 1e9 / 115_200.0;
                chunks.push((std::mem::take(&mut cur), (t_ns + wire_ns).round() as i64));
            }
        }
    }
    let cfg = RplidarConfig {
        sample_rate_hz: (n as f64 / (period_ns as f64 * 1e-9)).round() as u32,
        ..Default::default()
    };
    (chunks, cfg)
}

#[test]
fn rplidar_stream_with_host_times_recovers_wall_rate() {
    let (chunks, cfg) = rplidar_stream(66, 40);
    let mut parser = RplidarParser::new(cfg);
    let mut sig = SignatureProcessor::new(SignatureConfig {
        window_centre_rad: PI / 2.0,
        max_gap_ns: 400_000_000,
        ..Default::default()
    })
    .unwrap();
    let mut rng = XorShift(42);
    let mut out = Vec::new();
    let mut flipped = 0;
    for (mut bytes, t) in chunks {
        if rng.below(100) < 5 && !bytes.is_empty() {
            let i = rng.below(bytes.len() as u64) as usize;
            bytes[i] ^= 1 << rng.below(8);
            flipped += 1;
        }
        parser.push(&bytes, t, |scan| {
            sig.push_scan(scan, |s| out.push(s));
        });
    }
    assert!(flipped > 10);
    assert_eq!(parser.stats().descriptors, 1);
    assert!(
        out.len() >= 55,
        "{} samples {:?} {:?}",
        out.len(),
        sig.counters(),
        parser.stats()
    );
    // a flipped distance byte is not detectable (no checksum) and the wall fit
    // leaves it out; a flipped flag byte loses a node or a revolution start
    let (rms, max) = errors(&out, 0);
    eprintln!(
        "rplidar: {} samples, rms {rms:.4} max {max:.4}, {:?}",
        out.len(),
        parser.stats()
    );
    assert!(rms < 0.02 && max < 0.05, "rms {rms} max {max}");
    assert_eq!(parser.stats().scans, 65);
}
