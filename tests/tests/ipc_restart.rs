//! Killing (SIGKILL) and restarting a driver, then the daemon, mid-run
//! recovers without any manual clean-up.

use std::time::{Duration, Instant};
use vlsync_common::Stream;
use vlsync_ipc::{OffsetClient, StatusClient};
use vlsync_tests::{collect, locked_errors, status_when, Rig};

#[test]
fn sigkill_of_a_driver_and_of_the_daemon_recovers() {
    // 120 simulated seconds at 5x: 24 s of wall time
    let rig = Rig::new("restart", "robot", 4, 120.0, 5.0);
    let mut daemon = rig.daemon(0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let mut status = StatusClient::open(&rig.prefix).unwrap();
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let before_kill = collect(&mut client, Duration::from_secs(6));
    assert!(
        !locked_errors(&before_kill, &rig.sim).is_empty(),
        "no lock before the kills"
    );

    // driver crash and restart on the same schedule
    let before = status_when(&mut status, Duration::from_secs(5), |_| true).expect("a status");
    cam.signal("KILL").unwrap();
    let _ = cam.child.wait();
    std::thread::sleep(Duration::from_millis(500));
    let mut cam = rig.driver(Stream::Cam, 1);
    let after_driver = collect(&mut client, Duration::from_secs(4));
    assert!(
        after_driver.len() >= 4,
        "estimates stopped after the driver restart"
    );
    // the daemon reads the new camera driver (its estimates alone would go on from the
    // LiDAR's hops, predicted), and stays locked near the truth
    let t_window = vlsync_ipc::monotonic_ns();
    let mid = status_when(&mut status, Duration::from_secs(5), |st| {
        st.publish_ns > t_window
    })
    .expect("a status");
    assert!(
        mid.received[0] > before.received[0] + 200,
        "the daemon received {} camera samples before the kill and {} after the restart's 4 s",
        before.received[0],
        mid.received[0]
    );
    let errs = locked_errors(&after_driver, &rig.sim);
    assert!(
        !errs.is_empty() && errs.iter().all(|e| *e < 0.02),
        "locked errors after the driver restart: {errs:?}"
    );

    // daemon crash: SIGKILL leaves its iceoryx2 resources and lock behind the kernel's back
    daemon.signal("KILL").unwrap();
    let _ = daemon.child.wait();
    let mut daemon = rig.daemon(1);
    let t0 = Instant::now();
    let mut running = true;
    while t0.elapsed() < Duration::from_secs(1) {
        running = daemon.running();
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        running,
        "restarted daemon exited:\n{}",
        rig.log("vlsyncd-1.log")
    );
    let after_daemon = collect(&mut client, rig.remaining() + Duration::from_millis(1000));
    // a status published after the run, so the restarted daemon's (the client keeps
    // the killed daemon's last one, whose counts would pass the check below too)
    let t_after = vlsync_ipc::monotonic_ns();
    let st = status_when(&mut status, Duration::from_secs(5), |st| {
        st.publish_ns > t_after
    })
    .filter(|st| st.publish_ns > t_after)
    .expect("a status of the restarted daemon");
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(
        daemon.stop(Duration::from_secs(3)),
        "{}",
        rig.log("vlsyncd-1.log")
    );
    // the crashed daemon's resources were found and said (the node's creation used
    // to remove them first, and the count said nothing)
    let log = rig.log("vlsyncd-1.log");
    assert!(
        log.contains("removed the iceoryx2 resources of ") && log.contains(" dead process(es)"),
        "{log}"
    );

    // the new daemon received both streams and relocked near the truth
    assert!(st.received[0] > 100 && st.received[1] > 30, "{st:?}");
    let errs = locked_errors(&after_daemon, &rig.sim);
    assert!(
        errs.len() >= 10,
        "only {} locked estimates after the daemon restart:\n{}",
        errs.len(),
        rig.log("vlsyncd-1.log")
    );
    let tail = &errs[errs.len() - 5..];
    assert!(
        tail.iter().all(|e| *e < 0.02),
        "errors after restart: {tail:?}"
    );
}
