//! `vlsync-render --raw-stdout`'s `--start-at` out of range: an error at once, not a
//! stream that sleeps for decades (an instant on CLOCK_REALTIME instead of
//! CLOCK_MONOTONIC) or wraps around `i64`; in the past (a restarted camera
//! program): the frames already due are skipped, not written at once.

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

fn monotonic_ns() -> i64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    #[allow(clippy::useless_conversion)]
    (t.tv_sec * 1_000_000_000 + i64::from(t.tv_nsec))
}

/// Started 20 s after its --start-at, a 22 s stream skips the frames due by then
/// (says how many) and writes the rest in real time: about 2 s, not a burst of
/// 20 s of frames followed by the rest, nor the rest 20 s late (on its own start
/// instead of --start-at: 22 s).
#[test]
fn a_start_instant_in_the_past_skips_the_frames_already_due() {
    let mut cfg = vlsync_render::RenderConfig::from_seed(4, 22.0);
    cfg.camera.width = 16;
    cfg.camera.height = 16;
    let n = vlsync_render::Renderer::new(cfg)
        .unwrap()
        .frame_schedule()
        .len();
    let start = (monotonic_ns() - 20_000_000_000).to_string();
    let t0 = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_vlsync-render"))
        .args([
            "--raw-stdout",
            "gray",
            "--seed",
            "4",
            "--duration",
            "22",
            "--width",
            "16",
            "--height",
            "16",
            "--start-at",
            &start,
        ])
        .output()
        .unwrap();
    let took = t0.elapsed();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let skipped: usize = err
        .split_once("skipping the ")
        .and_then(|(_, rest)| rest.split_once(' '))
        .map(|(k, _)| k.parse().unwrap())
        .unwrap_or_else(|| panic!("no skip said: {err}"));
    let written = out.stdout.len() / (16 * 16);
    assert_eq!(out.stdout.len() % (16 * 16), 0);
    assert_eq!(skipped + written, n, "{err}");
    assert!(
        err.contains(&format!(
            "{written} frames written to stdout, {skipped} skipped (due before the stream started)"
        )),
        "{err}"
    );
    // 20 s and more of the 22 s run were due: roughly the last 2 s are written
    assert!(
        skipped > n / 2 && written > 10,
        "{skipped} skipped, {written} written"
    );
    // in real time, on --start-at's clock: the last frames were due about 2 s after
    // the start (a lower bound no load can break); written on the stream's own start
    // they would end 22 s after it at the earliest (its own report would not tell:
    // it measures lateness on the clock it paces by). The bound leaves a busy
    // machine 18 s for its start-up and the 2 s of frames, and still fails that.
    assert!(
        took >= Duration::from_secs(1) && took < Duration::from_secs(20),
        "{took:?}"
    );
}
