//! The real-time thread allocates nothing per sample in steady state:
//! `vlsyncd::runtime::run` runs in this process while both drivers publish
//! from their own processes, and a counting global allocator attributes heap
//! allocations to the thread named `vlsync-rt`.
//!
//! The one allocation left is inside iceoryx2 0.10 itself: every
//! `Publisher::loan_uninit` creates a small shared-state object on the heap
//! (`ChunkMutSharedState::new`), i.e. one allocation per *published estimate*
//! (2/s at the default hop), none per received sample. The test pins exactly
//! that bound. `VLSYNC_ALLOC_BT=1` prints a backtrace for each allocation.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use vlsync_common::Stream;
use vlsync_tests::Rig;

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);
static RT_ALLOCS: AtomicU64 = AtomicU64::new(0);
static ARMED: AtomicBool = AtomicBool::new(false);

thread_local! {
    static IN_HOOK: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Counts an allocation, attributing it to the real-time thread by name.
fn count() {
    ALLOCS.fetch_add(1, Ordering::Relaxed);
    if !ARMED.load(Ordering::Relaxed) {
        return;
    }
    let _ = IN_HOOK.try_with(|h| {
        if !h.get() {
            h.set(true);
            if std::thread::current().name() == Some("vlsync-rt") {
                RT_ALLOCS.fetch_add(1, Ordering::Relaxed);
                if std::env::var_os("VLSYNC_ALLOC_BT").is_some() {
                    eprintln!("{}", std::backtrace::Backtrace::force_capture());
                }
            }
            h.set(false);
        }
    });
}

// SAFETY: forwards every call unchanged to the system allocator; the counter is
// an atomic that never allocates.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as ours.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: `p` came from `System.alloc` with layout `l`.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as ours.
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn daemon_allocates_nothing_in_steady_state() {
    let rig = Rig::new("alloc", "robot", 6, 80.0, 5.0);
    let mut cfg = vlsync_config::Config::default();
    cfg.services.prefix = rig.prefix.clone();
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let daemon = std::thread::spawn(move || vlsyncd::runtime::run(cfg, stop2));
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    // warm-up: services connected, estimator locked, degraded mode settled
    std::thread::sleep(Duration::from_secs(5));
    let mut status = vlsync_ipc::StatusClient::open(&rig.prefix).unwrap();
    std::thread::sleep(Duration::from_millis(1200));
    let s0 = status.latest().unwrap().expect("status");
    ARMED.store(true, Ordering::Relaxed);
    std::thread::sleep(Duration::from_secs(4));
    ARMED.store(false, Ordering::Relaxed);
    let rt = RT_ALLOCS.load(Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(1200));
    let s1 = status.latest().unwrap().expect("status");
    let samples = s1.received.iter().sum::<u64>() - s0.received.iter().sum::<u64>();
    let estimates = s1.estimates_published - s0.estimates_published;
    let running = cam.running() && lidar.running();
    stop.store(true, Ordering::Relaxed);
    daemon.join().unwrap().unwrap();
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(running, "drivers ended before the measurement window");
    let _ = &ALLOCS;
    // the status window (~6.4 s) contains the 4 s allocation window
    assert!(samples > 500, "only {samples} samples in the window");
    assert!(
        rt <= estimates,
        "{rt} allocations on the real-time thread for {samples} samples and {estimates} estimates"
    );
}
