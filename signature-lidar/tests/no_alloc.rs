//! Steady-state signature processing allocates nothing: a counting global
//! allocator (thread-local counts, so the test harness's other threads do not
//! interfere) watches every scan after construction, for the wall fit and the
//! median, through passes, corners, drops and gaps.
//!
//! This file is its own crate: installing a `#[global_allocator]` needs one
//! `unsafe impl GlobalAlloc`, which only delegates to the system allocator.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::f64::consts::{FRAC_PI_2, TAU};
use vlsync_signature_lidar::signature::Distance;
use vlsync_signature_lidar::{
    Ray, Rotation, Scan, ScanTiming, SignatureConfig, SignatureProcessor,
};

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

struct Counting;

#[allow(unsafe_code)]
// SAFETY: every method forwards its arguments unchanged to `System`, which upholds
// the `GlobalAlloc` contract; the counter is a const-initialised thread-local
// `Cell` without destructor, so touching it never allocates or recurses.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocs() -> u64 {
    ALLOCS.with(|c| c.get())
}

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
        let before = allocs();
        for s in &scans {
            p.push_scan(s, |_| samples += 1);
        }
        let n = allocs() - before;
        assert_eq!(n, 0, "{distance:?} at {centre}: {n} allocations");
        let c = p.counters();
        eprintln!("{distance:?} at {centre}: {samples} samples, {c:?}");
        assert!(samples > 30 && c.measurements > 40, "{distance:?}: {c:?}");
    }
}
