//! The three processes (daemon, camera driver, LiDAR driver) converge to the
//! simulated truth, `vlsync-echo` prints the estimates and (`--status`) the daemon's
//! counters, a client that opens when the daemon is idle gets the last estimate, and
//! a clean shutdown leaves no shared-memory resource behind.

use std::time::Duration;
use vlsync_common::Stream;
use vlsync_ipc::{OffsetClient, StatusClient};
use vlsync_tests::{
    assert_nothing_left, bin, collect, ipc_resources, locked_errors, status_when, Piped, Rig,
};

#[test]
fn three_processes_converge_to_the_truth_and_clean_up() {
    let before = ipc_resources();
    // 60 simulated seconds at 6x: 10 s of wall time
    let rig = Rig::new("converge", "robot", 2, 60.0, 6.0);
    // summaries every 2 s instead of 10 min: the log's periodic lines show up
    let mut daemon = rig.daemon_with(0, "summary_period_s = 2.0");
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let mut status = StatusClient::open(&rig.prefix).unwrap();
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    // an operator's view of the running daemon: two statuses, as JSON and as text,
    // and two estimates
    // (run beside the collection, so the client's buffer never has to hold more;
    // stopped when dropped, should the test fail before they end)
    let echo = |json: bool, status: bool| {
        let mut cmd = std::process::Command::new(bin("vlsync-echo"));
        cmd.args(["--prefix", &rig.prefix, "--count", "2", "--duration", "8"]);
        if json {
            cmd.arg("--json");
        }
        if status {
            cmd.arg("--status");
        }
        Piped::spawn(cmd.stdin(std::process::Stdio::null()))
    };
    let (json_echo, text_echo) = (echo(true, true), echo(false, true));
    let est_echo = echo(true, false);
    let est = collect(&mut client, rig.remaining() + Duration::from_millis(1500));
    // each ends by itself within its --duration of 8 s: the limit is for a hung one
    let limit = Duration::from_secs(60);
    let json_out = json_echo.output_within(limit);
    let text_out = text_echo.output_within(limit);
    let est_out = est_echo.output_within(limit);
    // the status that counts the last samples (it may come a period later)
    let all = [rig.sim.cam.len() as u64, rig.sim.lidar.len() as u64];
    let st = status_when(&mut status, Duration::from_secs(10), |st| {
        st.received == all
    })
    .expect("a status from the daemon");
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    // a client that opens now, the drivers gone and the daemon publishing nothing,
    // gets the last estimate (history 1) from the daemon's next idle wake-up, not
    // never; a conversion with it says which estimate it used
    let mut late = OffsetClient::open(&rig.prefix).unwrap();
    let last = late
        .wait_next(Duration::from_secs(3))
        .unwrap()
        .expect("a late subscriber of an idle daemon gets its last estimate");
    let newest = client.latest().expect("estimates before");
    assert_eq!(last.seq, newest.seq);
    let conv = late.camera_to_lidar(newest.t_ref_ns).unwrap();
    assert_eq!(conv.estimate.seq, newest.seq);
    assert!(conv.std_s >= newest.offset_std_s);
    drop(late);
    // and the first that every-estimate reading hands out: open takes nothing, so it is
    // that last estimate whenever the history arrives (during the open or after it)
    let mut late_one = OffsetClient::open(&rig.prefix).unwrap();
    let (first, _) = late_one
        .wait_one(Duration::from_secs(3))
        .unwrap()
        .expect("wait_one hands out the daemon's last estimate before the open");
    assert_eq!(first.seq, newest.seq);
    drop(late_one);
    assert!(
        daemon.stop(Duration::from_secs(3)),
        "daemon did not exit cleanly:\n{}",
        rig.log("vlsyncd-0.log")
    );

    assert!(
        est.len() >= 90,
        "only {} estimates:\n{}",
        est.len(),
        rig.log("vlsyncd-0.log")
    );
    let errs = locked_errors(&est, &rig.sim);
    assert!(errs.len() >= 60, "only {} locked estimates", errs.len());
    // the last 20 locked estimates are within 15 ms of the truth (demo MAE: 3-10 ms)
    let tail = &errs[errs.len() - 20..];
    let worst = tail.iter().cloned().fold(0.0, f64::max);
    assert!(worst < 0.015, "late errors up to {:.1} ms", worst * 1e3);
    // the simulator's samples are flagged, and the daemon says its offset is not the
    // robot's (once per stream: the flag does not change)
    let log = rig.log("vlsyncd-0.log");
    for stream in ["cam", "lidar"] {
        let said = format!("{stream}: samples from a simulator (a driver's --sim or --render)");
        assert_eq!(log.matches(&said).count(), 1, "{stream}:\n{log}");
    }
    // every sample arrived, none lost or rejected
    assert_eq!(st.received, all);
    assert_eq!(st.lost, [0, 0]);
    assert_eq!(st.rejected_total(0) + st.rejected_total(1), 0);
    assert!(st.estimates_published >= est.len() as u64);
    // vlsync-echo --status: two statuses each, counters growing while the drivers run
    for out in [&json_out, &text_out] {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&json_out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2, "{lines:?}");
    let received = |v: &serde_json::Value| v["cam"]["received"].as_u64().unwrap();
    assert!(received(&lines[1]) > received(&lines[0]), "{lines:?}");
    assert_eq!(lines[1]["lidar"]["lost"], 0);
    assert_eq!(lines[1]["cam"]["rejected"]["backwards"], 0);
    assert!(lines[1]["processing_ns"]["p50"].as_u64().unwrap() > 0);
    // and the estimates themselves, one JSON object each
    assert!(est_out.status.success());
    let est_lines: Vec<serde_json::Value> = String::from_utf8_lossy(&est_out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(est_lines.len(), 2, "{est_lines:?}");
    assert!(est_lines[1]["seq"].as_u64() > est_lines[0]["seq"].as_u64());
    assert!(est_lines
        .iter()
        .all(|e| e["offset_s"].is_f64() && e["state"].is_string()));
    let text = String::from_utf8_lossy(&text_out.stdout);
    assert_eq!(text.lines().count(), 2, "{text}");
    assert!(
        text.lines()
            .all(|l| l.starts_with("up ") && l.contains(" received, ")),
        "{text}"
    );

    // the log's periodic summaries: the estimates and counters of each stretch, and
    // its latency (which the status's whole-run percentiles would hide after months)
    let log = rig.log("vlsyncd-0.log");
    let stretch = |l: &str, what: &str| {
        l.split_once(what).is_some_and(|(_, rest)| {
            rest.split_once(" s: ")
                .is_some_and(|(n, _)| n.parse::<u32>().is_ok_and(|n| (1..=4).contains(&n)))
        })
    };
    let latency: Vec<&str> = log
        .lines()
        .filter(|l| stretch(l, "latency, last "))
        .collect();
    assert!(latency.len() >= 3, "{log}");
    assert!(
        latency
            .iter()
            .all(|l| l.contains(" samples, processing p50 ")
                && l.contains(" µs budget; driver publish to done p50 ")),
        "{log}"
    );
    let summaries = log
        .lines()
        .filter(|l| stretch(l, "runtime: last ") && l.contains(" estimates"))
        .count();
    assert!(summaries >= 3, "{log}");
    // and the stretch since the last of them, once, at the stop
    let at_stop: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("runtime: at stop, last "))
        .collect();
    assert!(
        at_stop.len() == 1 && at_stop[0].contains(" estimates") && at_stop[0].contains(" received"),
        "{log}"
    );

    drop((client, status));
    assert_nothing_left(&before);
}
