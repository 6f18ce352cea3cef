//! `vlsync-render --raw-stdout`'s `--start-at` out of range: an error at once, not a
//! stream that sleeps for decades (an instant on CLOCK_REALTIME instead of
//! CLOCK_MONOTONIC) or wraps around `i64`.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_start_instant_off_the_monotonic_clock_is_refused_at_once() {
    let realtime_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos()
        .to_string();
    for start in ["9223372036854775807", "-1", realtime_ns.as_str()] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_vlsync-render"))
            .args([
                "--raw-stdout",
                "gray",
                "--duration",
                "5",
                "--start-at",
                start,
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if t0.elapsed() > Duration::from_secs(30) {
                let _ = child.kill();
                let _ = child.wait();
                panic!("--start-at {start}: still running after 30 s");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(status.code(), Some(2), "--start-at {start}: {err}");
        assert!(
            err.starts_with(&format!(
                "vlsync-render: error: --start-at {start} is out of range: allowed 0 ..= "
            )) && err.contains("(CLOCK_MONOTONIC ns, at most a day from now)"),
            "{err}"
        );
        assert!(out.stdout.is_empty(), "--start-at {start}: frames written");
    }
}
