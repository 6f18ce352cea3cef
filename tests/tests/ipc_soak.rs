//! `vlsync-soak`: one daemon over consecutive driver sessions (new seed, new
//! offset, both clocks back to 0 each time) relocks in every session, loses no
//! sample, keeps its memory, stops every child and leaves nothing in shared memory.

use std::time::Duration;
use vlsync_tests::{assert_nothing_left, bin, ipc_resources, output_within};

#[test]
fn three_sessions_against_one_daemon_pass_the_check() {
    let before = ipc_resources();
    let dir = std::env::temp_dir().join(format!("vlsync-soak-test-{}", std::process::id()));
    // 3 sessions of 60 s at 15x: 12 s of runs; a hung harness fails after 5 min
    let out = output_within(
        std::process::Command::new(bin("vlsync-soak"))
            .args([
                "--family",
                "robot",
                "--sessions",
                "3",
                "--session-s",
                "60",
                "--speed",
                "15",
                "--check",
                "--log-dir",
            ])
            .arg(&dir),
        Duration::from_secs(300),
    );
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "exit {}:\n{text}\n{err}", out.status);
    for i in 1..=3 {
        let line = text
            .lines()
            .find(|l| l.starts_with(&format!("session {i}/3 ")))
            .unwrap_or_else(|| panic!("no session {i} line:\n{text}"));
        assert!(line.contains("locked at"), "{line}");
    }
    assert!(text.contains("3 of 3 sessions locked"), "{text}");
    assert!(text.contains("lost cam 0 lidar 0"), "{text}");
    assert!(text.contains("children stopped cleanly"), "{text}");
    assert!(text.contains("check: passed"), "{text}");
    // the accuracy over the three sessions: the robot family scores about 1 ms
    let mae: f64 = text
        .lines()
        .find(|l| l.starts_with("accuracy over 3 sessions"))
        .and_then(|l| l.split("MAE ").nth(1))
        .and_then(|r| r.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no accuracy line:\n{text}"));
    assert!(mae < 5.0, "MAE {mae} ms:\n{text}");
    // each session's drivers logged on their own
    for f in ["vlsync-cam.log", "vlsync-cam-1.log", "vlsync-lidar-2.log"] {
        assert!(dir.join(f).exists(), "{f} missing in {}", dir.display());
    }
    assert_nothing_left(&before);
    let _ = std::fs::remove_dir_all(&dir);
}
