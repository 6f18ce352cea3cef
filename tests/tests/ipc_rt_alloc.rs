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

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use vlsync_common::Stream;
use vlsync_tests::{status_when, Rig};
use vlsyncd::runtime::RT_THREAD_NAME;

#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

/// `vlsyncd::runtime::run` on a thread of this test, stopped and joined when dropped:
/// a test that fails before its end still stops the daemon, which removes its
/// iceoryx2 files and its lock file (left behind, they would fail the suite's later
/// checks that a run leaves none).
struct InProcessDaemon {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<(), String>>>,
}

impl InProcessDaemon {
    fn start(cfg: vlsync_config::Config) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::spawn(move || vlsyncd::runtime::run(cfg, stop2));
        Self {
            stop,
            thread: Some(thread),
        }
    }

    /// Stops the daemon and returns how its run ended.
    fn stop(mut self) -> Result<(), String> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err("the daemon thread panicked".into()),
            None => Ok(()),
        }
    }
}

impl Drop for InProcessDaemon {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[test]
fn daemon_allocates_nothing_in_steady_state() {
    // 150 simulated seconds at 5x: 30 s of drivers, room for a slow lock before the
    // window
    let rig = Rig::new("alloc", "robot", 6, 150.0, 5.0);
    let mut cfg = vlsync_config::Config::default();
    cfg.services.prefix = rig.prefix.clone();
    // a summary period within the window: the ends of the latency stretches (their
    // percentiles and the event that carries them) are measured too
    cfg.daemon.summary_period_s = 1.0;
    // statuses every 0.1 s: the estimates counted around the window are about its
    // own (2/s), not 2.4 s more of them, which would hide an allocation per stretch
    cfg.daemon.status_period_s = 0.1;
    // declared before the drivers: on a panic they are stopped first, then the daemon
    let daemon = InProcessDaemon::start(cfg);
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    // warm-up: services connected, estimator locked, degraded mode settled (at least
    // 5 s, and until a status says tracking: up to 20 s more, the drivers' 30 s
    // leaving the window and its statuses room after that)
    std::thread::sleep(Duration::from_secs(5));
    let mut status = vlsync_ipc::StatusClient::open(&rig.prefix).unwrap();
    let s0 = status_when(&mut status, Duration::from_secs(20), |st| {
        st.state == vlsync_common::EstimatorState::Tracking as u8
    })
    .expect("status");
    assert_eq!(
        s0.state,
        vlsync_common::EstimatorState::Tracking as u8,
        "not tracking after the warm-up: {s0:?}"
    );
    vlsync_alloc_count::assert_counting();
    // the thread the watch counts is there, under that name (else nothing is counted)
    let names: Vec<String> = std::fs::read_dir("/proc/self/task")
        .unwrap()
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
        .map(|n| n.trim().to_string())
        .collect();
    assert!(
        names.iter().any(|n| n == RT_THREAD_NAME),
        "no thread named {RT_THREAD_NAME}: {names:?}"
    );
    let rt0 = vlsync_alloc_count::watched();
    vlsync_alloc_count::watch_thread(
        RT_THREAD_NAME,
        std::env::var_os("VLSYNC_ALLOC_BT").is_some(),
    );
    std::thread::sleep(Duration::from_secs(4));
    vlsync_alloc_count::unwatch_thread();
    let rt = vlsync_alloc_count::watched() - rt0;
    // a status made after the window, so that its counts cover all of it
    let t_end = vlsync_ipc::monotonic_ns();
    let s1 = status_when(&mut status, Duration::from_secs(10), |st| {
        st.publish_ns > t_end
    })
    .expect("status");
    let samples = s1.received.iter().sum::<u64>() - s0.received.iter().sum::<u64>();
    let estimates = s1.estimates_published - s0.estimates_published;
    let running = cam.running() && lidar.running();
    daemon.stop().unwrap();
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(running, "drivers ended before the measurement window");
    // the status window (~4.1 s) contains the 4 s allocation window
    assert!(samples > 500, "only {samples} samples in the window");
    assert!(
        rt <= estimates,
        "{rt} allocations on the real-time thread for {samples} samples and {estimates} estimates"
    );
}
