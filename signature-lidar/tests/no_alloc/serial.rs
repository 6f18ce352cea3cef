//! A serial LiDAR's whole per-scan path allocates nothing after start-up, over
//! thousands of scans: raw LD06 and RPLIDAR bytes, read in chunks of varying size
//! as a serial port hands them over, with line noise (flipped bytes, garbage, a
//! repeated RPLIDAR response descriptor), through the parser and the wall front-end
//! the LiDAR driver runs (`WallFront`, one window or both opposite ones); and a
//! motor that slows after start-up, its scans longer than any before (1500 rays).
//! `no_alloc.rs` covers the front-end alone on sixty prepared scans; this is the
//! byte stream of a long run.
//!
//! A module of `no_alloc.rs`, whose crate installs `vlsync-alloc-count`'s allocator.

use vlsync_common::Nanos;
use vlsync_signature_lidar::encode::{ld06_stream, rplidar_revolution, SCAN_DESCRIPTOR};
use vlsync_signature_lidar::ld06::{Ld06Clock, Ld06Config, Ld06Parser};
use vlsync_signature_lidar::rplidar::{RplidarConfig, RplidarParser};
use vlsync_signature_lidar::{Scan, SignatureConfig, WallFront};

use vlsync_alloc_count::this_thread as allocs;

/// Scans (revolutions) in each stream.
const SCANS: usize = 3000;
/// Of which the first are start-up: buffers may still grow while they pass.
const WARM_UP: usize = 50;

/// A deterministic generator (xorshift64*), for chunk sizes and noise.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// A robot driving back and forth in a 4 m x 6 m room while turning slowly: the
/// range at time `t` (s) along bearing `b` (rad, CCW), every 17th ray lost.
fn room(t: f64, b: f64, ray: &mut u64) -> f64 {
    *ray += 1;
    if (*ray).is_multiple_of(17) {
        return 0.0;
    }
    let (x, y) = (2.0 + 0.8 * (0.35 * t).sin(), 3.0 + 1.5 * (0.21 * t).sin());
    let (s, c) = (0.05 * t + b).sin_cos();
    let tx = if c > 1e-9 {
        (4.0 - x) / c
    } else if c < -1e-9 {
        -x / c
    } else {
        f64::INFINITY
    };
    let ty = if s > 1e-9 {
        (6.0 - y) / s
    } else if s < -1e-9 {
        -y / s
    } else {
        f64::INFINITY
    };
    tx.min(ty)
}

/// `bytes` with line noise: about one byte in `every` flipped, and now and then a
/// burst of garbage inserted; the noise begins after `clean` bytes (start-up).
fn noisy(bytes: &[u8], every: u64, clean: usize, rng: &mut Rng) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len() + bytes.len() / 100);
    for (i, &b) in bytes.iter().enumerate() {
        if i >= clean && rng.below(every) == 0 {
            out.push(b ^ (1 << rng.below(8)));
        } else {
            out.push(b);
        }
        if i >= clean && rng.below(every * 8) == 0 {
            for _ in 0..1 + rng.below(40) {
                out.push(rng.next() as u8);
            }
        }
    }
    out
}

/// What feeding a stream did.
#[derive(Debug, Default)]
struct Fed {
    scans: u64,
    samples: u64,
    /// Allocations from the end of the warm-up to the end of the stream.
    allocations: u64,
    /// Scans after the warm-up.
    counted_scans: u64,
}

/// Feeds `bytes` in chunks of 1 to 600 bytes, each dated at its last byte's arrival
/// at `bytes_per_s`, through `push` (a parser's `push`) into `front`; counts this
/// thread's allocations from the `WARM_UP`th scan on.
fn feed(
    bytes: &[u8],
    bytes_per_s: f64,
    front: &mut WallFront,
    rng: &mut Rng,
    mut push: impl FnMut(&[u8], Nanos, &mut dyn FnMut(&Scan)),
) -> Fed {
    let mut fed = Fed::default();
    let mut warm_at = None;
    let mut at = 0;
    while at < bytes.len() {
        let n = (1 + rng.below(600) as usize).min(bytes.len() - at);
        let chunk = &bytes[at..at + n];
        at += n;
        let rx_ns = 5_000_000_000 + (at as f64 / bytes_per_s * 1e9) as Nanos;
        let (scans, samples) = (&mut fed.scans, &mut fed.samples);
        push(chunk, rx_ns, &mut |scan: &Scan| {
            *scans += 1;
            front.push_scan(scan, |_| *samples += 1);
        });
        if warm_at.is_none() && fed.scans >= WARM_UP as u64 {
            warm_at = Some((allocs(), fed.scans));
        }
    }
    let (before, scans_then) = warm_at.expect("the stream outlasts its warm-up");
    // a zero below means none only if the allocator counts
    vlsync_alloc_count::assert_counting();
    let before = before + 1;
    fed.allocations = allocs() - before;
    fed.counted_scans = fed.scans - scans_then;
    fed
}

/// No allocation after the warm-up, and the stream did run, noise and all: nearly
/// every scan after the warm-up made (over `min_scans`), and samples from them (over
/// `min_samples`). `what` names the parser and front-end in the messages.
fn assert_allocated_nothing_and_ran(
    what: &str,
    fed: &Fed,
    front: &WallFront,
    min_scans: usize,
    min_samples: usize,
) {
    assert_eq!(
        fed.allocations, 0,
        "{what}: {} allocations over {} scans after the warm-up",
        fed.allocations, fed.counted_scans
    );
    assert!(fed.counted_scans as usize > min_scans, "{what}: {fed:?}");
    assert!(
        fed.samples as usize > min_samples,
        "{what}: {fed:?} {:?}",
        front.ahead().counters()
    );
}

/// The driver's front-ends: the default window alone, and with the opposite one.
fn fronts() -> [(&'static str, WallFront); 2] {
    fronts_with(SignatureConfig::default())
}

/// [`fronts`] with the settings `cfg`.
fn fronts_with(cfg: SignatureConfig) -> [(&'static str, WallFront); 2] {
    [
        ("one window", WallFront::new(cfg, false).unwrap()),
        ("opposite windows", WallFront::new(cfg, true).unwrap()),
    ]
}

#[test]
fn ld06_bytes_to_samples_allocate_nothing_after_start_up() {
    // 10 Hz: 3000 scans are 300 s of output, 4500 points a second in 47-byte
    // packets of 12
    let mut ray = 0;
    let clean = ld06_stream(3600, 0, SCANS as f64 / 10.0, |t, b| room(t, b, &mut ray));
    let bytes_per_s = 4500.0 / 12.0 * 47.0;
    let mut rng = Rng(0x5EED_1D06);
    let bytes = noisy(&clean, 20_000, WARM_UP * 1800, &mut rng);
    for clock in [Ld06Clock::Host, Ld06Clock::Device] {
        for (what, mut front) in fronts() {
            // as the driver makes it (`LidarSource::serial`)
            let mut parser = Ld06Parser::new(Ld06Config {
                clock,
                ..Ld06Config::default()
            });
            let fed = feed(&bytes, bytes_per_s, &mut front, &mut rng, |c, t, f| {
                parser.push(c, t, f)
            });
            let st = parser.stats();
            eprintln!("LD06 {clock:?}, {what}: {fed:?}; {st:?}");
            assert_allocated_nothing_and_ran(
                &format!("LD06 {clock:?}, {what}"),
                &fed,
                &front,
                SCANS * 9 / 10,
                SCANS / 4,
            );
            // and the noise's errors were found
            assert!(
                st.crc_errors > 10 && st.skipped_bytes > 100,
                "LD06 noise: {st:?}"
            );
        }
    }
}

#[test]
fn rplidar_bytes_to_samples_allocate_nothing_after_start_up() {
    // an A1 at 5.5 Hz, 360 nodes a revolution in 5-byte nodes; the response
    // descriptor first, and again mid-stream (the scan restarted)
    let period = 1.0 / 5.5;
    let mut clean = SCAN_DESCRIPTOR.to_vec();
    let mut ray = 0;
    for k in 0..SCANS {
        if k == SCANS / 2 {
            clean.extend_from_slice(&SCAN_DESCRIPTOR);
        }
        clean.extend(rplidar_revolution(
            360,
            k as f64 * period,
            period,
            |t, b| room(t, b, &mut ray),
        ));
    }
    let bytes_per_s = 360.0 * 5.5 * 5.0;
    let mut rng = Rng(0x5EED_A1A1);
    let bytes = noisy(&clean, 20_000, WARM_UP * 1800, &mut rng);
    for (what, mut front) in fronts() {
        // as the driver makes it (`LidarSource::serial` at 115200 baud)
        let mut parser = RplidarParser::new(RplidarConfig {
            baud: 115_200,
            sample_rate_hz: 2000,
            ..RplidarConfig::default()
        });
        let fed = feed(&bytes, bytes_per_s, &mut front, &mut rng, |c, t, f| {
            parser.push(c, t, f)
        });
        let st = *parser.stats();
        eprintln!("RPLIDAR, {what}: {fed:?}; {st:?}");
        assert_allocated_nothing_and_ran(
            &format!("RPLIDAR, {what}"),
            &fed,
            &front,
            SCANS * 9 / 10,
            SCANS / 4,
        );
        assert!(
            st.descriptors == 2 && st.skipped_bytes > 100,
            "RPLIDAR noise: {st:?}"
        );
    }
}

/// Scans after a motor slows down past the warm-up: more rays in one than the 1024
/// a parser used to reserve, so its buffers grew (to 2048) long after start-up.
const SLOW_SCANS: usize = 300;

#[test]
fn scans_of_a_slowed_motor_allocate_nothing_after_start_up() {
    // an LD06 at 10 Hz through the warm-up (6 s, 60 scans of 450 rays), then at 3 Hz
    // (1500 rays a scan: the stamps and angles go on from where they were, 6 s being
    // 2250 whole packets and 60 whole turns)
    let mut ray = 0;
    let mut clean = ld06_stream(3600, 0, 6.0, |t, b| room(t, b, &mut ray));
    let slow_s = SLOW_SCANS as f64 / 3.0;
    clean.extend(ld06_stream(1080, 6000, slow_s, |t, b| {
        room(6.0 + t, b, &mut ray)
    }));
    let bytes_per_s = 4500.0 / 12.0 * 47.0;
    let mut rng = Rng(0x5EED_3A3A);
    let bytes = noisy(&clean, 20_000, WARM_UP * 1800, &mut rng);
    // a turn of 333 ms is longer than the default largest gap between a window's
    // measurements (300 ms), which would give no derivative: 1 s here, so the slow
    // scans go all the way to samples
    let cfg = SignatureConfig {
        max_gap_ns: 1_000_000_000,
        ..SignatureConfig::default()
    };
    for clock in [Ld06Clock::Host, Ld06Clock::Device] {
        for (what, mut front) in fronts_with(cfg) {
            let mut parser = Ld06Parser::new(Ld06Config {
                clock,
                ..Ld06Config::default()
            });
            let mut longest = 0;
            let fed = feed(&bytes, bytes_per_s, &mut front, &mut rng, |c, t, f| {
                parser.push(c, t, &mut |s: &Scan| {
                    longest = longest.max(s.len());
                    f(s)
                })
            });
            eprintln!(
                "LD06 slowing, {clock:?}, {what}: {fed:?}; {:?}",
                parser.stats()
            );
            assert!(longest >= 1500, "{longest} rays");
            assert_allocated_nothing_and_ran(
                &format!("LD06 slowing, {clock:?}, {what}"),
                &fed,
                &front,
                SLOW_SCANS * 9 / 10,
                SLOW_SCANS / 4,
            );
        }
    }
    // an RPLIDAR sending 2000 nodes a second, 360 a turn through the warm-up
    // (5.6 Hz), then 1111 (1.8 Hz): the first slow revolution is dropped for its
    // period, the next agrees on it
    let period = 360.0 / 2000.0;
    let slow = 1111.0 / 2000.0;
    let mut clean = SCAN_DESCRIPTOR.to_vec();
    let mut ray = 0;
    for k in 0..WARM_UP + 10 {
        clean.extend(rplidar_revolution(
            360,
            k as f64 * period,
            period,
            |t, b| room(t, b, &mut ray),
        ));
    }
    let t0 = (WARM_UP + 10) as f64 * period;
    for k in 0..SLOW_SCANS {
        clean.extend(rplidar_revolution(
            1111,
            t0 + k as f64 * slow,
            slow,
            |t, b| room(t, b, &mut ray),
        ));
    }
    let mut rng = Rng(0x5EED_A1A2);
    let bytes = noisy(&clean, 20_000, WARM_UP * 1800, &mut rng);
    for (what, mut front) in fronts_with(cfg) {
        let mut parser = RplidarParser::new(RplidarConfig {
            baud: 115_200,
            sample_rate_hz: 2000,
            ..RplidarConfig::default()
        });
        let mut longest = 0;
        let fed = feed(&bytes, 2000.0 * 5.0, &mut front, &mut rng, |c, t, f| {
            parser.push(c, t, &mut |s: &Scan| {
                longest = longest.max(s.len());
                f(s)
            })
        });
        eprintln!("RPLIDAR slowing, {what}: {fed:?}; {:?}", parser.stats());
        assert!(longest >= 1100, "{longest} rays");
        assert_allocated_nothing_and_ran(
            &format!("RPLIDAR slowing, {what}"),
            &fed,
            &front,
            SLOW_SCANS * 9 / 10,
            SLOW_SCANS / 4,
        );
    }
}
