//! `vlsyncd record` beside a live daemon: the recorded streams are exactly what
//! the drivers published, the recorded estimates exactly what the daemon
//! published, and `vlsyncd replay` of the recording reproduces those estimates
//! byte for byte (and says so with `--compare`), in the order the daemon read the
//! samples even when a driver restarts its clock. A second recording into the same
//! directory is refused.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};
use vlsync_common::Stream;
use vlsync_ipc::{monotonic_ns, StatusClient};
use vlsync_tests::{
    assert_nothing_left, assert_serving, bin, ipc_resources, output_within, write_daemon_config,
    Managed, Rig,
};

/// A daemon that never degrades, and a recorder into `<logs>/rec`, both running.
struct Recording {
    daemon: Managed,
    recorder: Managed,
    status: StatusClient,
    dir: PathBuf,
    args: Vec<String>,
}

impl Recording {
    /// Starts both, then sets the rig's start instant 1 s ahead: the drivers start
    /// once the recorder listens, so it sees every sample.
    fn start(rig: &mut Rig) -> Self {
        // a budget no sample overruns: the daemon never narrows its lags (degraded
        // mode), so it runs exactly the estimator replay runs
        let cfg = write_daemon_config(
            &rig.logs,
            &rig.prefix,
            "latency_budget_us = 1000000.0\nstatus_period_s = 0.2",
        );
        let dlog = rig.logs.join("vlsyncd-0.log");
        let mut daemon = Managed::spawn(
            "vlsyncd",
            &bin("vlsyncd"),
            &["run".into(), "--config".into(), cfg.display().to_string()],
            Some(&dlog),
        )
        .unwrap();
        assert_serving(&mut daemon, &dlog);
        let status = StatusClient::open(&rig.prefix).unwrap();
        let dir = rig.logs.join("rec");
        let args: Vec<String> = vec![
            "record".into(),
            "--prefix".into(),
            rig.prefix.clone(),
            "--out".into(),
            dir.display().to_string(),
            "--progress-every".into(),
            "1".into(),
        ];
        let rlog = rig.logs.join("record.log");
        let mut recorder = Managed::spawn("vlsyncd", &bin("vlsyncd"), &args, Some(&rlog)).unwrap();
        match recorder.wait_for_log(&rlog, "Ctrl-C stops", Duration::from_secs(20)) {
            Ok(true) => {}
            other => panic!("the recorder did not start: {other:?}"),
        }
        rig.start_at = monotonic_ns() + 1_000_000_000;
        Self {
            daemon,
            recorder,
            status,
            dir,
            args,
        }
    }

    /// Waits (up to 15 s) until the daemon has taken every sample (two statuses in a
    /// row count the same), by which time it has published every estimate (the
    /// real-time loop publishes as it pushes), then stops the recorder and checks it
    /// wrote as many samples as the daemon received. Returns the recorder's log.
    fn stop(&mut self, rig: &Rig) -> String {
        let t0 = Instant::now();
        let mut first: Option<([u64; 2], i64)> = None;
        let received = loop {
            if let Ok(Some(st)) = self.status.latest() {
                match first {
                    Some((rx, at)) if rx == st.received && st.publish_ns > at => break rx,
                    Some((rx, _)) if rx == st.received => {}
                    _ => first = Some((st.received, st.publish_ns)),
                }
            }
            assert!(
                t0.elapsed() < Duration::from_secs(15),
                "the daemon's counts did not settle: {first:?}\n{}",
                rig.log("vlsyncd-0.log")
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        // the recorder reads an estimate within 20 ms of its publication
        std::thread::sleep(Duration::from_millis(300));
        assert!(
            self.recorder.stop(Duration::from_secs(6)),
            "{}",
            rig.log("record.log")
        );
        let rows = |f: &str| self.read(f).lines().count() as u64 - 1;
        assert_eq!(
            [rows("cam.csv"), rows("lidar.csv")],
            received,
            "the recorder wrote other counts than the daemon received"
        );
        rig.log("record.log")
    }

    /// `vlsyncd replay` of the recording, with `--compare` against its estimates.
    fn replay(&self, out: &str, extra: &[&str]) -> Output {
        let f = |name: &str| self.dir.join(name);
        let out = Command::new(bin("vlsyncd"))
            .arg("replay")
            .arg("--cam")
            .arg(f("cam.csv"))
            .arg("--lidar")
            .arg(f("lidar.csv"))
            .arg("--out")
            .arg(f(out))
            .arg("--compare")
            .arg(f("est.csv"))
            .args(extra)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        out
    }

    fn read(&self, name: &str) -> String {
        std::fs::read_to_string(self.dir.join(name)).unwrap()
    }

    fn finish(mut self, rig: &Rig, before: &[String]) {
        drop(self.status);
        assert!(
            self.daemon.stop(Duration::from_secs(3)),
            "{}",
            rig.log("vlsyncd-0.log")
        );
        assert_nothing_left(before);
    }
}

/// Panics, naming the first row that differs, unless `a` and `b` are the same text.
fn assert_same_rows(a: &str, b: &str, what: &str, log: &Path) {
    if a != b {
        let first = a.lines().zip(b.lines()).position(|(x, y)| x != y);
        panic!(
            "{what}: {} against {} rows, first difference at row {first:?}:\n{}",
            a.lines().count(),
            b.lines().count(),
            std::fs::read_to_string(log).unwrap_or_default()
        );
    }
}

/// Held by each test of this file for its whole run: both end by checking that
/// no shared-memory resource is left on the machine, which the other test's
/// processes, still running, would fail.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn a_recording_replays_to_the_live_estimates_byte_for_byte() {
    let _alone = one_at_a_time();
    let before = ipc_resources();
    // 40 simulated seconds at 8x: 5 s of wall time
    let mut rig = Rig::new("record", "robot", 4, 40.0, 8.0);
    let mut r = Recording::start(&mut rig);
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let limit = rig.remaining() + Duration::from_secs(20);
    for (d, log) in [
        (&mut cam, "vlsync-cam-0.log"),
        (&mut lidar, "vlsync-lidar-0.log"),
    ] {
        let st = d.wait_up_to(limit).expect("the driver finishes its run");
        assert!(st.success(), "{log}:\n{}", rig.log(log));
    }
    let log = r.stop(&rig);
    assert!(log.contains("s: cam "), "no progress line:\n{log}");
    for (name, n) in [("cam", rig.sim.cam.len()), ("lidar", rig.sim.lidar.len())] {
        let want =
            format!("{name}: {n} samples, 0 lost (sequence gaps), 0 published before the first recorded, 0 driver restarts, 0 malformed");
        assert!(log.contains(&want), "`{want}` missing:\n{log}");
    }
    assert!(log.contains("replay it: vlsyncd replay --cam "), "{log}");
    assert!(!log.contains("before this recording read any"), "{log}");

    // the streams: every sample as published, stamps and values exact
    for (file, sent) in [("cam.csv", &rig.sim.cam), ("lidar.csv", &rig.sim.lidar)] {
        let (got, _) = vlsync_sim::io::read_signature_csv(r.dir.join(file)).unwrap();
        assert_eq!(&got, sent, "{file} differs from what the driver published");
    }

    // the estimates: the daemon's, and replay's of the recording, the same bytes
    let out = r.replay("replayed.csv", &[]);
    let live = r.read("est.csv");
    let rows = live.lines().count() - 1;
    assert!(rows >= 60, "only {rows} estimates recorded:\n{log}");
    assert!(
        live.lines().any(|l| l.contains(",tracking,")),
        "no tracking estimate:\n{live}"
    );
    let dlog = rig.logs.join("vlsyncd-0.log");
    assert_same_rows(&r.read("replayed.csv"), &live, "replay", &dlog);
    // and replay says so itself
    let said = String::from_utf8_lossy(&out.stderr);
    let want = format!("{rows} of {rows} estimates at reference times it has ({rows} rows); {rows} identical, 0 in another state");
    assert!(said.contains(&want), "`{want}` missing:\n{said}");
    assert!(said.contains("merged by publish time"), "{said}");

    // a second recording into the same directory is refused, and names the file
    // (a regression would record until stopped: bounded)
    let again = output_within(
        Command::new(bin("vlsyncd")).args(&r.args),
        Duration::from_secs(20),
    );
    assert_eq!(again.status.code(), Some(2));
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(
        err.contains("cam.csv exists: refusing to overwrite a recording (--force overwrites it)"),
        "{err}"
    );
    r.finish(&rig, &before);
}

#[test]
fn a_driver_restarting_its_clock_replays_right_in_the_order_the_daemon_read() {
    let _alone = one_at_a_time();
    let before = ipc_resources();
    // 60 simulated seconds at 8x; the camera driver is restarted after about 25 s,
    // its new session stamped from the start of its run again, 25 s behind the LiDAR
    let mut rig = Rig::new("record-restart", "robot", 5, 60.0, 8.0);
    let mut r = Recording::start(&mut rig);
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    std::thread::sleep(Duration::from_millis(1000 + 25_000 / 8));
    assert!(
        cam.stop(Duration::from_secs(3)),
        "{}",
        rig.log("vlsync-cam-0.log")
    );
    let restart_at = monotonic_ns() + 200_000_000;
    let mut cam2 = rig.session_driver(Stream::Cam, rig.seed, rig.duration, restart_at, "1");
    let st = lidar
        .wait_up_to(rig.remaining() + Duration::from_secs(20))
        .expect("the LiDAR driver finishes its run");
    assert!(st.success(), "{}", rig.log("vlsync-lidar-0.log"));
    assert!(
        cam2.stop(Duration::from_secs(3)),
        "{}",
        rig.log("vlsync-cam-1.log")
    );
    let log = r.stop(&rig);
    assert!(
        log.contains("cam: ") && log.contains(" 1 driver restarts"),
        "{log}"
    );
    let (cam_rows, _) = vlsync_sim::io::read_signature_csv(r.dir.join("cam.csv")).unwrap();
    assert!(
        cam_rows
            .windows(2)
            .any(|w| w[1].t_ns < w[0].t_ns - 10_000_000_000),
        "the restart should have set the camera's stamps back by more than 10 s"
    );

    let live = r.read("est.csv");
    let dlog = rig.logs.join("vlsyncd-0.log");
    // by publish time (what `auto` picks for a recording): the daemon's estimates
    r.replay("by-publish.csv", &["--order", "publish"]);
    assert_same_rows(
        &r.read("by-publish.csv"),
        &live,
        "replay in publish order",
        &dlog,
    );
    // by stamp, the restarted camera's samples all come before the LiDAR's that were
    // read beside them: another run (which is why a recording keeps the publish times)
    let out = r.replay("by-stamp.csv", &["--order", "stamp"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("merged by stamp"));
    assert_ne!(
        r.read("by-stamp.csv"),
        live,
        "stamp order gave the live run"
    );
    r.finish(&rig, &before);
}
