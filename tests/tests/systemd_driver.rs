//! A driver under a simulated systemd (the units run them with `WatchdogSec=`): the
//! test plays the service manager's notification socket and checks `READY=1` once
//! the driver publishes, `WATCHDOG=1` at half of `WATCHDOG_USEC` while its loop runs
//! (counted against its own progress lines' `STATUS=`, one a second), and
//! `STOPPING=1` plus a clean exit on SIGTERM: for a simulated source (petted for by a
//! helper thread and by the loop) and for a device source, a camera program that
//! gives no frame (petted by the loop's stop checks alone, as it waits).

use std::os::unix::net::UnixDatagram;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use vlsync_tests::{bin, Managed};

/// WATCHDOG_USEC here, s: a pet every 0.25 s, four per progress line.
const WATCHDOG_S: f64 = 0.5;

/// The `N` of a progress line's "last N s:" (the time since the previous one).
fn last_s(line: &str) -> Option<f64> {
    line.split("last ")
        .nth(1)?
        .split(" s:")
        .next()?
        .parse()
        .ok()
}

/// Receives the next datagram within `within`.
fn next(sock: &UnixDatagram, within: Duration) -> Option<String> {
    let t0 = Instant::now();
    let mut buf = [0u8; 4096];
    while t0.elapsed() < within {
        if let Ok(n) = sock.recv(&mut buf) {
            return Some(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
    }
    None
}

#[test]
fn a_simulated_lidar_pets_the_watchdog_and_says_when_it_stops() {
    // a progress line a second (--report-every 1); five counted. A simulated
    // source is petted for by a helper thread too (READY, STATUS and STOPPING are
    // what this case checks; the loop's own pets are the camera case's)
    under_systemd(
        "vlsync-lidar",
        "sdlidar",
        &["--sim", "robot", "--duration", "600"],
        5,
        None,
    );
}

#[test]
fn a_camera_waiting_for_frames_pets_the_watchdog_from_its_loop() {
    // a device source: no helper thread pets for it; the program writes nothing,
    // so the driver's loop only waits for a frame, checking the stop as it waits,
    // and reports at each stall (10 s: the program is restarted); one counted
    under_systemd(
        "vlsync-cam",
        "sdcam",
        &["--pipe-cmd", "exec sleep 600", "--size", "64x48"],
        1,
        // at most one pet per half period from one petting thread, with a margin for
        // the progress lines' rounding: a helper thread petting as well gives 8
        Some(6.0),
    );
}

/// Runs `driver` with `source` under the test's notification socket and checks
/// READY, the pets' pace from READY over its first `lines` progress lines (STATUS=,
/// whose spans on the driver's own clock are the measure), and STOPPING.
fn under_systemd(
    driver_bin: &str,
    tag: &str,
    source: &[&str],
    lines: usize,
    most_per_s: Option<f64>,
) {
    let dir = std::env::temp_dir().join(format!("vlsync-it-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let prefix = format!("vlsync-it/{tag}-{}", std::process::id());
    let sock_path = dir.join("notify.sock");
    let sock = UnixDatagram::bind(&sock_path).unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    let log = dir.join(format!("{driver_bin}.log"));
    let out = std::fs::File::create(&log).unwrap();
    let child = Command::new(bin(driver_bin))
        .args(["--prefix", &prefix, "--report-every", "1"])
        .args(source)
        .env("NOTIFY_SOCKET", &sock_path)
        .env("WATCHDOG_USEC", format!("{}", (WATCHDOG_S * 1e6) as u64))
        .env_remove("WATCHDOG_PID")
        .stdin(Stdio::null())
        .stdout(out.try_clone().unwrap())
        .stderr(out)
        .spawn()
        .unwrap();
    let mut driver = Managed {
        name: driver_bin.into(),
        child,
    };
    let logtext = || std::fs::read_to_string(&log).unwrap_or_default();

    // READY=1 with the publishing line, then pets and progress STATUS lines
    let mut seen = vec![];
    let deadline = Instant::now() + Duration::from_secs(90);
    let (mut statuses, mut pets, mut ready) = (0usize, 0usize, false);
    // the progress lines' spacing, as the driver's own lines say it ("last 10 s:")
    let mut span_s = 0.0;
    while statuses < lines {
        assert!(
            Instant::now() < deadline && driver.running(),
            "{statuses} progress lines before 90 s passed or the driver exited: {seen:?}\n{}",
            logtext()
        );
        let Some(msg) = next(&sock, Duration::from_millis(200)) else {
            continue;
        };
        if msg.starts_with("READY=1") {
            assert!(!ready, "READY=1 twice: {seen:?}");
            assert!(
                msg.contains(&format!("STATUS={driver_bin}: publishing")) && msg.contains(&prefix),
                "READY=1 without the publishing line: {msg:?}"
            );
            ready = true;
        } else if msg == "WATCHDOG=1" {
            // pets before READY=1 are fine (systemd's watchdog runs from the start
            // of a Type=simple unit); counted from READY=1, where the run and its
            // first progress line's span begin
            if ready {
                pets += 1;
            }
        } else if msg.starts_with(&format!("STATUS={driver_bin}:")) {
            assert!(ready, "a progress STATUS before READY=1: {seen:?}");
            span_s += last_s(&msg).unwrap_or_else(|| panic!("no 'last N s': {msg:?}"));
            statuses += 1;
        }
        seen.push(msg);
    }
    // 4 pets a second when half of WATCHDOG_USEC is kept; 2 when the driver pets at
    // WATCHDOG_USEC (too late for systemd); none when the stop checks do not pet.
    // Two and a half of four leaves a loaded machine room (a late wake-up delays a
    // pet and a progress line alike).
    let per_s = pets as f64 / span_s;
    assert!(
        per_s >= 2.5 && most_per_s.is_none_or(|m| per_s <= m),
        "{pets} pets over {span_s} s of progress lines (at most {most_per_s:?} a second): {seen:?}\n{}",
        logtext()
    );
    assert!(
        logtext().contains("systemd watchdog on"),
        "the driver did not say the watchdog is on:\n{}",
        logtext()
    );

    // SIGTERM: STOPPING=1 and exit 0
    driver.signal("TERM").unwrap();
    let mut stopping = None;
    let t0 = Instant::now();
    while stopping.is_none() && t0.elapsed() < Duration::from_secs(20) {
        if let Some(msg) = next(&sock, Duration::from_millis(200)) {
            if msg.starts_with("STOPPING=1") {
                stopping = Some(msg);
            }
        }
    }
    let stopping = stopping.unwrap_or_else(|| panic!("no STOPPING=1\n{}", logtext()));
    assert!(
        stopping.contains("published") && stopping.contains("interrupted"),
        "STOPPING=1 without the summary: {stopping:?}"
    );
    let status = driver
        .wait_up_to(Duration::from_secs(20))
        .unwrap_or_else(|| panic!("the driver did not exit on SIGTERM\n{}", logtext()));
    assert!(status.success(), "{status:?}\n{}", logtext());
    let _ = std::fs::remove_dir_all(&dir);
}
