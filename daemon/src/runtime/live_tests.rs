//! The daemon run in this process ([`run`]), fed by publishers of the test: what its
//! real-time thread counts, publishes and hands to the log, seen from outside.

use super::tests::Sink;
use super::*;
use std::sync::Mutex;
use std::time::Instant;
use vlsync_ipc::{OffsetClient, SignaturePublisher, StatusClient};

/// A daemon running on a thread of this test, its log in memory.
struct Daemon {
    names: ServiceNames,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<(), String>>>,
    log: Arc<Mutex<Vec<u8>>>,
}

impl Daemon {
    /// Starts a daemon on a prefix of its own (`tag`), unpinned, with statuses every
    /// 0.1 s and `edit` applied to its configuration; returns once it publishes its
    /// status (its real-time thread runs, its subscribers exist).
    fn start(tag: &str, edit: impl FnOnce(&mut Config)) -> Self {
        let mut cfg = Config::default();
        cfg.services.prefix = format!("vlsync-test/live-{tag}-{}", std::process::id());
        cfg.daemon.core = -1;
        cfg.daemon.status_period_s = 0.1;
        edit(&mut cfg);
        cfg.validate("test").unwrap();
        let names = ServiceNames::new(&cfg.services.prefix).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let log = Arc::new(Mutex::new(Vec::new()));
        let (stop2, sink) = (stop.clone(), log.clone());
        let thread = std::thread::spawn(move || {
            let sub = tracing_subscriber::fmt()
                .with_writer(move || Sink(sink.clone()))
                .with_ansi(false)
                .with_max_level(tracing::Level::INFO)
                .finish();
            tracing::subscriber::with_default(sub, || run(cfg, stop2))
        });
        let d = Self {
            names,
            stop,
            thread: Some(thread),
            log,
        };
        let mut status = StatusClient::open(&d.names.prefix).unwrap();
        d.status_when(&mut status, |_| true);
        d
    }

    /// The first status that `done` accepts (panics after 10 s without one).
    fn status_when(&self, status: &mut StatusClient, done: impl Fn(&Status) -> bool) -> Status {
        let t0 = Instant::now();
        loop {
            if let Some(st) = status.latest().ok().flatten().filter(|st| done(st)) {
                return st;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(10),
                "no such status in 10 s; the last: {:?}\n{}",
                status.latest().ok().flatten(),
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn log(&self) -> String {
        String::from_utf8_lossy(&self.log.lock().unwrap()).into_owned()
    }

    /// Waits up to 10 s for `text` in the daemon's log.
    fn wait_for_log(&self, text: &str) {
        let t0 = Instant::now();
        while !self.log().contains(text) {
            assert!(
                t0.elapsed() < Duration::from_secs(10),
                "no {text:?} in 10 s:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Stops the daemon and returns its log (panics when it ended with an error).
    fn stop(mut self) -> String {
        self.stop.store(true, Ordering::Relaxed);
        let end = self.thread.take().unwrap().join().unwrap();
        let log = self.log();
        assert!(end.is_ok(), "{end:?}\n{log}");
        log
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A malformed sample (unknown flags, non-zero padding) between good ones of its
/// publisher is rejected and counted once: the next sample is its successor, no
/// lost sample (its sequence number used to be skipped, so each was counted lost
/// as well); one whose number jumps is not followed.
#[test]
fn a_malformed_sample_is_rejected_not_also_lost() {
    let d = Daemon::start("malformed", |_| {});
    let node = create_node("live-test", false).unwrap();
    let cam = SignaturePublisher::open(&node, &d.names, Stream::Cam).unwrap();
    let mut status = StatusClient::open(&d.names.prefix).unwrap();
    for seq in 0..7u64 {
        let mut w = SignatureSample::new(
            1_000_000_000 + seq as i64 * 33_000_000,
            0.5,
            seq,
            monotonic_ns(),
        );
        match seq {
            0 => w.flags |= vlsync_common::wire::FLAG_FIRST,
            2 => w.reserved = 7,
            4 => w.flags = 0x8000_0000,
            _ => {}
        }
        assert_eq!(cam.publish_raw(w).unwrap(), 1, "the daemon is subscribed");
    }
    let st = d.status_when(&mut status, |st| st.received[0] == 7);
    assert_eq!(st.rejected[0][REJECT_MALFORMED], 2, "{st:?}");
    assert_eq!(st.lost, [0, 0], "{st:?}");
    // a malformed sample that is not the next number moves nothing (its sequence
    // number may be as garbled as the rest: followed, 100, 0, 101 counted 100 lost);
    // the gap before it is counted at the publisher's next good sample, which the
    // malformed one is part of
    let mut w = SignatureSample::new(2_000_000_000, 0.5, 9, monotonic_ns());
    w.reserved = 1;
    cam.publish_raw(w).unwrap();
    let st = d.status_when(&mut status, |st| st.received[0] == 8);
    assert_eq!(st.rejected[0][REJECT_MALFORMED], 3, "{st:?}");
    assert_eq!(st.lost, [0, 0], "{st:?}");
    let w = SignatureSample::new(2_033_000_000, 0.5, 10, monotonic_ns());
    cam.publish_raw(w).unwrap();
    let st = d.status_when(&mut status, |st| st.received[0] == 9);
    assert_eq!(st.lost, [3, 0], "{st:?}");
    d.stop();
}

/// A stream silent for longer than `estimator.max_gap_s` is said in the log, with
/// both durations: a sensor slower than the limit would otherwise leave the daemon
/// estimating nothing with a clean log.
#[test]
fn a_silence_longer_than_the_gap_limit_is_said() {
    let d = Daemon::start("silence", |_| {});
    let node = create_node("live-test", false).unwrap();
    let mut lidar = SignaturePublisher::open(&node, &d.names, Stream::Lidar).unwrap();
    let mut status = StatusClient::open(&d.names.prefix).unwrap();
    // 0.1 s apart, then 1.4 s without a sample (stamps on the LiDAR's clock)
    for t_ms in [1000i64, 1100, 1200, 2600, 2700] {
        lidar.publish(t_ms * 1_000_000, 0.5).unwrap();
    }
    d.status_when(&mut status, |st| st.received[1] == 5);
    d.wait_for_log(
        "lidar: 1.400 s without a sample (or its stamps jumped), longer than estimator.max_gap_s = 0.75 s",
    );
    let log = d.stop();
    assert_eq!(log.matches("without a sample").count(), 1, "{log}");
}

/// A stream whose samples carry `FLAG_SIMULATED` is said to be a simulator's (a
/// warning) and in the summary line; once unflagged samples come, a sensor's again.
#[test]
fn simulated_samples_are_said() {
    let d = Daemon::start("simulated", |cfg| cfg.daemon.summary_period_s = 1.0);
    let node = create_node("live-test", false).unwrap();
    let mut cam = SignaturePublisher::open(&node, &d.names, Stream::Cam).unwrap();
    let mut status = StatusClient::open(&d.names.prefix).unwrap();
    cam.set_simulated(true);
    for k in 0..3i64 {
        cam.publish(1_000_000_000 + k * 33_000_000, 0.5).unwrap();
    }
    d.status_when(&mut status, |st| st.received[0] == 3);
    d.wait_for_log("cam: samples from a simulator (a driver's --sim or --render), not a sensor");
    d.wait_for_log("; SIMULATED samples (cam): not the robot's offset");
    cam.set_simulated(false);
    for k in 3..6i64 {
        cam.publish(1_000_000_000 + k * 33_000_000, 0.5).unwrap();
    }
    d.wait_for_log("cam: samples from a sensor again");
    let log = d.stop();
    assert_eq!(log.matches("samples from a simulator").count(), 1, "{log}");
    assert!(!log.contains("lidar: samples from a simulator"), "{log}");
}

/// Publishes a simulated run's two streams in real time (each sample notified, as
/// the drivers do) on a thread, until the run ends or the returned flag is set.
fn drive(names: &ServiceNames, seed: u64) -> (Arc<AtomicBool>, std::thread::JoinHandle<()>) {
    let run = vlsync_sim::generate("robot".parse().unwrap(), seed, Some(60.0));
    let names = names.clone();
    let done = Arc::new(AtomicBool::new(false));
    let done2 = done.clone();
    let t = std::thread::spawn(move || {
        let node = create_node("live-driver", false).unwrap();
        let mut pubs = [
            SignaturePublisher::open(&node, &names, Stream::Cam).unwrap(),
            SignaturePublisher::open(&node, &names, Stream::Lidar).unwrap(),
        ];
        let t0 = run.cam[0].t_ns.min(run.lidar[0].t_ns);
        let start = Instant::now();
        let (mut i, mut j) = (0, 0);
        while !done2.load(Ordering::Relaxed) && (i < run.cam.len() || j < run.lidar.len()) {
            let cam_next =
                j >= run.lidar.len() || (i < run.cam.len() && run.cam[i].t_ns <= run.lidar[j].t_ns);
            let (k, s) = if cam_next {
                i += 1;
                (0, run.cam[i - 1])
            } else {
                j += 1;
                (1, run.lidar[j - 1])
            };
            let due = Duration::from_nanos((s.t_ns - t0).max(0) as u64);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
            pubs[k].publish(s.t_ns, s.value).unwrap();
        }
    });
    (done, t)
}

/// A client that opens while drivers publish at their usual rates (every wake-up of
/// the daemon notified: it never times out) gets the last estimate (history 1) at
/// the daemon's next update of its connections, within about 0.1 s, not at the next
/// estimate a hop later (5 s here).
#[test]
fn a_new_client_gets_the_last_estimate_long_before_the_next_hop() {
    // (the step test's window is at least one hop: a configuration rule)
    let d = Daemon::start("history", |cfg| {
        cfg.estimator.hop_s = 5.0;
        cfg.estimator.step_window_s = 5.0;
    });
    let mut first = OffsetClient::open(&d.names.prefix).unwrap();
    let (done, driver) = drive(&d.names, 3);
    let (e, _) = first
        .wait_one(Duration::from_secs(30))
        .unwrap()
        .unwrap_or_else(|| panic!("no estimate in 30 s:\n{}", d.log()));
    let mut late = OffsetClient::open(&d.names.prefix).unwrap();
    let t0 = Instant::now();
    let got = loop {
        if let Some(x) = late.latest() {
            break x;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(8),
            "no estimate for the late client in 8 s"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    let waited = t0.elapsed();
    done.store(true, Ordering::Relaxed);
    driver.join().unwrap();
    // the history, not the next estimate: so it came before the next hop, 5 s after
    // the last one (a bound on the wait itself would judge the machine's load)
    assert_eq!(
        got.seq, e.seq,
        "the next estimate came first (after {waited:?})"
    );
    d.stop();
}

/// The stretch since the last summary period's end is logged at the stop: the "at
/// stop" summary once, and its latency line (it used to be dropped: a daemon stopped
/// within its first summary period, 10 minutes by default, never logged a latency).
#[test]
fn the_last_stretch_is_logged_at_the_stop() {
    let d = Daemon::start("stretch", |_| {});
    let node = create_node("live-test", false).unwrap();
    let cam = SignaturePublisher::open(&node, &d.names, Stream::Cam).unwrap();
    let mut status = StatusClient::open(&d.names.prefix).unwrap();
    for seq in 0..3u64 {
        let w = SignatureSample::new(1_000_000_000 + seq as i64 * 33_000_000, 0.5, seq, 0);
        cam.publish_raw(w).unwrap();
    }
    d.status_when(&mut status, |st| st.received[0] == 3);
    let log = d.stop();
    let lines = |what: &str| log.lines().filter(|l| l.contains(what)).count();
    assert_eq!(lines("at stop, last "), 1, "{log}");
    assert_eq!(lines("at stop, latency, last "), 1, "{log}");
    assert!(log.contains(": 3 samples, processing p50 "), "{log}");
    // the summary comes first, as at the end of every period
    let at = |what: &str| log.find(what).unwrap();
    assert!(
        at("at stop, last ") < at("at stop, latency, last "),
        "{log}"
    );
}
