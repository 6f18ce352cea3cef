//! `vlsyncd record` beside a live daemon: the recorded streams are exactly what
//! the drivers published, the recorded estimates exactly what the daemon
//! published, and `vlsyncd replay` of the recording reproduces those estimates
//! byte for byte (and says so with `--compare`). A second recording into the same
//! directory is refused.

use std::process::Command;
use std::time::Duration;
use vlsync_common::Stream;
use vlsync_ipc::{monotonic_ns, StatusClient};
use vlsync_tests::{
    assert_nothing_left, assert_serving, bin, ipc_resources, status_when, write_daemon_config,
    Managed, Rig,
};

#[test]
fn a_recording_replays_to_the_live_estimates_byte_for_byte() {
    let before = ipc_resources();
    // 40 simulated seconds at 8x: 5 s of wall time
    let mut rig = Rig::new("record", "robot", 4, 40.0, 8.0);
    // a budget no sample overruns: the daemon never narrows its lags (degraded
    // mode), so it runs exactly the estimator replay runs
    let cfg = write_daemon_config(&rig.logs, &rig.prefix, "latency_budget_us = 1000000.0");
    let dlog = rig.logs.join("vlsyncd-0.log");
    let mut daemon = Managed::spawn(
        "vlsyncd",
        &bin("vlsyncd"),
        &["run".into(), "--config".into(), cfg.display().to_string()],
        Some(&dlog),
    )
    .unwrap();
    assert_serving(&mut daemon, &dlog);
    let mut status = StatusClient::open(&rig.prefix).unwrap();

    let dir = rig.logs.join("rec");
    let rlog = rig.logs.join("record.log");
    let record_args = || -> Vec<String> {
        vec![
            "record".into(),
            "--prefix".into(),
            rig.prefix.clone(),
            "--out".into(),
            dir.display().to_string(),
            "--progress-every".into(),
            "1".into(),
        ]
    };
    let mut rec = Managed::spawn("vlsyncd", &bin("vlsyncd"), &record_args(), Some(&rlog)).unwrap();
    match rec.wait_for_log(&rlog, "Ctrl-C stops", Duration::from_secs(20)) {
        Ok(true) => {}
        other => panic!("the recorder did not start: {other:?}"),
    }
    // the drivers start once the recorder listens, so it sees every sample
    rig.start_at = monotonic_ns() + 1_000_000_000;
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let limit = rig.remaining() + Duration::from_secs(20);
    for d in [&mut cam, &mut lidar] {
        let st = d.wait_up_to(limit).expect("the driver finishes its run");
        assert!(st.success(), "{}", rig.log("vlsync-cam-0.log"));
    }
    // once the daemon has taken every sample it has published every estimate (the
    // real-time loop publishes as it pushes); the recorder reads them within 20 ms
    let all = [rig.sim.cam.len() as u64, rig.sim.lidar.len() as u64];
    let st = status_when(&mut status, Duration::from_secs(10), |st| {
        st.received == all
    });
    assert_eq!(
        st.map(|s| s.received),
        Some(all),
        "{}",
        rig.log("vlsyncd-0.log")
    );
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        rec.stop(Duration::from_secs(6)),
        "{}",
        rig.log("record.log")
    );
    let log = rig.log("record.log");
    assert!(log.contains("s: cam "), "no progress line:\n{log}");
    for (name, n) in [("cam", rig.sim.cam.len()), ("lidar", rig.sim.lidar.len())] {
        let want =
            format!("{name}: {n} samples, 0 lost (sequence gaps), 0 driver restarts, 0 malformed");
        assert!(log.contains(&want), "`{want}` missing:\n{log}");
    }
    assert!(log.contains("replay it: vlsyncd replay --cam "), "{log}");

    // the streams: every sample as published, stamps and values exact
    for (file, sent) in [("cam.csv", &rig.sim.cam), ("lidar.csv", &rig.sim.lidar)] {
        let (got, _) = vlsync_sim::io::read_signature_csv(dir.join(file)).unwrap();
        assert_eq!(&got, sent, "{file} differs from what the driver published");
    }

    // the estimates: the daemon's, and replay's of the recording, the same bytes
    let out = Command::new(bin("vlsyncd"))
        .arg("replay")
        .arg("--cam")
        .arg(dir.join("cam.csv"))
        .arg("--lidar")
        .arg(dir.join("lidar.csv"))
        .arg("--out")
        .arg(dir.join("replayed.csv"))
        .arg("--compare")
        .arg(dir.join("est.csv"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let live = std::fs::read_to_string(dir.join("est.csv")).unwrap();
    let replayed = std::fs::read_to_string(dir.join("replayed.csv")).unwrap();
    let rows = live.lines().count() - 1;
    assert!(rows >= 60, "only {rows} estimates recorded:\n{log}");
    assert!(
        live.lines().any(|l| l.contains(",tracking,")),
        "no tracking estimate:\n{live}"
    );
    if live != replayed {
        let first = live.lines().zip(replayed.lines()).position(|(a, b)| a != b);
        panic!(
            "replay differs from the live estimates ({} against {} rows), first at row {first:?}:\n{}",
            rows,
            replayed.lines().count() - 1,
            rig.log("vlsyncd-0.log")
        );
    }

    // and replay says so itself
    let said = String::from_utf8_lossy(&out.stderr);
    let want = format!("{rows} of {rows} estimates at reference times it has ({rows} rows); {rows} identical, 0 in another state");
    assert!(said.contains(&want), "`{want}` missing:\n{said}");

    // a second recording into the same directory is refused, and names the file
    let again = Command::new(bin("vlsyncd"))
        .args(record_args())
        .output()
        .unwrap();
    assert_eq!(again.status.code(), Some(2));
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(
        err.contains("cam.csv exists: refusing to overwrite a recording (--force overwrites it)"),
        "{err}"
    );

    drop(status);
    assert!(
        daemon.stop(Duration::from_secs(3)),
        "{}",
        rig.log("vlsyncd-0.log")
    );
    assert_nothing_left(&before);
}
