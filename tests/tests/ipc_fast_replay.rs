//! A driver replaying as fast as it can (`--fast`) hands every sample to a running
//! daemon when they fit its subscriber buffer: the driver keeps its publisher (whose
//! shared memory holds the samples) until the daemon has had time to take them,
//! where it used to exit right after the last send and take them all away (the
//! daemon received none of them). Without a daemon, the driver says that nobody
//! received its samples instead of reporting them as published and nothing else.

use std::process::Command;
use std::time::{Duration, Instant};
use vlsync_ipc::StatusClient;
use vlsync_tests::{bin, output_within, status_when, Rig};

fn fast_cam(prefix: &str, duration_s: &str) -> (Option<i32>, String) {
    // bounded: a driver that hung instead of ending fails the test, stopped
    let out = output_within(
        Command::new(bin("vlsync-cam")).args([
            "--prefix",
            prefix,
            "--sim",
            "robot",
            "--seed",
            "2",
            "--duration",
            duration_s,
            "--fast",
        ]),
        Duration::from_secs(120),
    );
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The numbers of the daemon's "first sample read from a publisher is its number N"
/// lines in `log`, in order: one per driver run whose first samples it never read.
fn joined_counts(log: &str) -> Vec<u64> {
    log.lines()
        .filter_map(|l| {
            let n = l
                .split("the first sample read from a publisher is its number ")
                .nth(1)?;
            n.split(':').next()?.parse().ok()
        })
        .collect()
}

#[test]
fn a_fast_replay_reaches_the_daemon_and_an_unheard_one_says_so() {
    let rig = Rig::new("fast", "robot", 2, 6.0, 1.0);
    let mut daemon = rig.daemon(0);
    let mut status = StatusClient::open(&rig.prefix).unwrap();
    // the daemon is serving once it publishes a status
    let t0 = Instant::now();
    while status.latest().unwrap().is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "no status from the daemon:\n{}",
            rig.log("vlsyncd-0.log")
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // 6 s at 30 Hz: fewer samples than the daemon's 256-sample buffer holds
    let (code, err) = fast_cam(&rig.prefix, "6");
    assert_eq!(code, Some(0), "{err}");
    let published: u64 = err
        .lines()
        .find_map(|l| {
            let n = l
                .strip_prefix("vlsync-cam: ")?
                .split(" published,")
                .next()?;
            n.parse().ok()
        })
        .unwrap_or_else(|| panic!("no summary line:\n{err}"));
    assert!((150..256).contains(&published), "{err}");
    assert!(!err.contains("reached no subscriber"), "{err}");
    // the driver has ended (after lingering 0.5 s for the daemon to take its
    // samples): a status published a second later counts all the daemon read of it.
    // Every sample is received, lost in a sequence gap or, before the first one the
    // daemon read, said in its log; with fewer samples than the buffer holds the
    // last two are normally none, but how they split is the daemon's timing. Samples
    // the publisher took away with it unread are in none of them (the bug: a driver
    // that left right after its last send took them all, and received was 0).
    let t_end = vlsync_ipc::monotonic_ns();
    let st = status_when(&mut status, Duration::from_secs(10), |st| {
        st.publish_ns > t_end + 1_000_000_000
    })
    .filter(|st| st.publish_ns > t_end + 1_000_000_000)
    .expect("a status a second after the driver ended");
    let log = rig.log("vlsyncd-0.log");
    let joined = joined_counts(&log);
    let before_first: u64 = joined.iter().sum();
    assert!(st.received[0] > 0, "{st:?}\n{log}");
    assert_eq!(
        st.received[0] + st.lost[0] + before_first,
        published,
        "received {} + lost {} + before the first read {before_first}\n{log}",
        st.received[0],
        st.lost[0]
    );

    // 30 s at 30 Hz, more than the buffer holds: every sample is received, lost in a
    // sequence gap, or, before the first one the daemon read of this driver, said in
    // its log (`... is its number N`); how they split depends on when the daemon woke
    let (code, err) = fast_cam(&rig.prefix, "30");
    assert_eq!(code, Some(0), "{err}");
    let burst: u64 = err
        .lines()
        .find_map(|l| {
            l.strip_prefix("vlsync-cam: ")?
                .split(" published,")
                .next()?
                .parse()
                .ok()
        })
        .unwrap_or_else(|| panic!("no summary line:\n{err}"));
    assert!(burst > 800, "{err}");
    // the driver has ended (it lingers 0.5 s for the daemon to drain its buffer): a
    // status published a second later counts all of the burst
    let t_burst = vlsync_ipc::monotonic_ns();
    let st2 = status_when(&mut status, Duration::from_secs(10), |st| {
        st.publish_ns > t_burst + 1_000_000_000
    })
    .filter(|st| st.publish_ns > t_burst + 1_000_000_000)
    .expect("a status a second after the burst");
    assert!(daemon.stop(Duration::from_secs(3)));
    let log = rig.log("vlsyncd-0.log");
    // this burst's line, after the first run's (if it had one)
    let before_first: u64 = joined_counts(&log).iter().skip(joined.len()).sum();
    let received = st2.received[0] - st.received[0];
    let lost = st2.lost[0] - st.lost[0];
    assert!(received >= 256, "{st2:?}\n{log}");
    assert_eq!(
        received + lost + before_first,
        burst,
        "received {received} + lost {lost} + before the first read {before_first}\n{log}"
    );

    // no daemon on this prefix: published, and said to have reached nobody
    let (code, err) = fast_cam(&format!("{}-nobody", rig.prefix), "2");
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("reached no subscriber"), "{err}");
}
