//! The two driver binaries on raw sources, without a daemon (publishing never waits for one).

use std::process::Command;

fn run(bin: &str, args: &[&str]) -> (bool, String) {
    let out = Command::new(bin).args(args).output().expect("spawn driver");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn both_drivers_publish_a_rendered_run_and_report_their_drops() {
    let prefix = format!("vlsync-test/driver-bins-{}", std::process::id());
    let common = [
        "--render",
        "5",
        "--duration",
        "2",
        "--fast",
        "--prefix",
        &prefix,
    ];
    let (ok, err) = run(env!("CARGO_BIN_EXE_vlsync-cam"), &common);
    assert!(ok, "{err}");
    assert!(
        err.contains("render seed 5") && err.contains("low texture"),
        "{err}"
    );
    assert!(err.contains(" published, 0 skipped"), "{err}");
    let (ok, err) = run(env!("CARGO_BIN_EXE_vlsync-lidar"), &common);
    assert!(ok, "{err}");
    assert!(
        err.contains("too_few_valid") && err.contains(" published"),
        "{err}"
    );
}

#[test]
fn wrong_sources_fail_with_a_message() {
    let (ok, err) = run(env!("CARGO_BIN_EXE_vlsync-lidar"), &["--frames", "/tmp"]);
    assert!(!ok);
    assert!(
        err.contains("--frames is not a source of vlsync-lidar"),
        "{err}"
    );
    let (ok, err) = run(
        env!("CARGO_BIN_EXE_vlsync-lidar"),
        &["--scans", "/nonexistent/vlsync/scans.csv"],
    );
    assert!(!ok);
    assert!(err.contains("/nonexistent/vlsync/scans.csv"), "{err}");
    if !cfg!(feature = "v4l2") {
        let (ok, err) = run(env!("CARGO_BIN_EXE_vlsync-cam"), &["--v4l2", "/dev/video0"]);
        assert!(!ok);
        assert!(err.contains("rebuild with --features v4l2"), "{err}");
    }
}
