//! Steady-state signature processing allocates nothing: a counting global
//! allocator (thread-local counts, so the test harness's other threads do not
//! interfere) watches every scan after construction, for the wall fit and the
//! median, through passes, corners, drops and gaps.
//!
//! This file is its own crate: it installs `vlsync-alloc-count`'s allocator.

use std::f64::consts::{FRAC_PI_2, TAU};
use vlsync_signature_lidar::signature::Distance;
use vlsync_signature_lidar::{
    Ray, Rotation, Scan, ScanTiming, SignatureConfig, SignatureProcessor,
};

#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

use vlsync_alloc_count::this_thread as allocs;

#[path = "no_alloc/serial.rs"]
mod serial;

/// Scan `k` of a robot turning in place 7° per scan in a 4x6 m room, 450 rays
/// clockwise from the front, every 13th return lost, scan 20 missing (a gap).
fn scan(k: i64) -> Scan {
    let yaw = 0.12 * k as f64;
    let rays = (0..450)
        .map(|i| {
            let b = -(i as f64) * TAU / 450.0;
            let (s, c) = (yaw + b).sin_cos();
            // from (1.5, 2.0) in a room [0, 4] x [0, 6]
            let tx = if c > 0.0 {
                2.5 / c
            } else if c < 0.0 {
                -1.5 / c
            } else {
                f64::INFINITY
            };
            let ty = if s > 0.0 {
                4.0 / s
            } else if s < 0.0 {
                -2.0 / s
            } else {
                f64::INFINITY
            };
            let r = if i % 13 == 0 { 0.0 } else { tx.min(ty) };
            Ray::new(b, r, 50.0, r > 0.0)
        })
        .collect();
    let timing = ScanTiming {
        start_ns: k * 100_000_000,
        period_ns: 100_000_000,
        rotation: Rotation::Cw,
        start_bearing_rad: 0.0,
    };
    Scan::from_uniform(timing, rays)
}

/// Allocations `f` makes on this thread.
fn allocations(f: impl FnOnce()) -> u64 {
    let before = allocs();
    f();
    let n = allocs() - before;
    // a zero means none only if the allocator counts
    vlsync_alloc_count::assert_counting();
    n
}

#[test]
fn steady_state_processing_allocates_nothing() {
    let scans: Vec<Scan> = (0..60).filter(|&k| k != 20).map(scan).collect();
    for (distance, centre) in [
        (Distance::Wall, 0.0),
        (Distance::Wall, FRAC_PI_2),
        (Distance::Median, 0.0),
    ] {
        let mut p = SignatureProcessor::new(SignatureConfig {
            distance,
            window_centre_rad: centre,
            ..SignatureConfig::default()
        })
        .unwrap();
        let mut samples = 0u64;
        let n = allocations(|| {
            for s in &scans {
                p.push_scan(s, |_| samples += 1);
            }
        });
        assert_eq!(n, 0, "{distance:?} at {centre}: {n} allocations");
        let c = p.counters();
        eprintln!("{distance:?} at {centre}: {samples} samples, {c:?}");
        assert!(samples > 30 && c.measurements > 40, "{distance:?}: {c:?}");
    }
}

#[test]
fn opposite_windows_allocate_nothing() {
    let scans: Vec<Scan> = (0..60).filter(|&k| k != 20).map(scan).collect();
    let mut w = vlsync_signature_lidar::OppositeWindows::new(SignatureConfig::default()).unwrap();
    let mut samples = 0u64;
    let n = allocations(|| {
        for s in &scans {
            w.push_scan(s, |_| samples += 1);
        }
    });
    assert_eq!(n, 0, "{n} allocations");
    let both = w.ahead().counters().samples + w.behind().counters().samples;
    assert!(samples > 60, "{samples}");
    assert_eq!(samples + w.out_of_order(), both);
}
