//! The Python subscriber (official iceoryx2 package) reads the live daemon's
//! estimates through the same type name and layout as the Rust side.

use std::path::Path;
use std::process::Command;
use std::time::Duration;
use vlsync_common::Stream;
use vlsync_tests::Rig;

/// The interpreter: `VLSYNC_PYTHON` (`scripts/test.sh` sets it when it installed the
/// package into a virtual environment), else `python3`.
fn python() -> String {
    std::env::var("VLSYNC_PYTHON").unwrap_or_else(|_| "python3".to_string())
}

fn python_has_iceoryx2() -> bool {
    Command::new(python())
        .args(["-c", "import iceoryx2"])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// The subscriber script, or `None` (the test skips) when the interpreter lacks the
/// iceoryx2 package outside `scripts/test.sh`; under it (`VLSYNC_REQUIRE_PYTHON`),
/// which installed the package, a missing one fails the test.
fn subscriber_or_skip(test: &str) -> Option<std::path::PathBuf> {
    if !python_has_iceoryx2() {
        assert!(
            std::env::var_os("VLSYNC_REQUIRE_PYTHON").is_none(),
            "{} cannot import iceoryx2, although scripts/test.sh installed it",
            python()
        );
        eprintln!(
            "SKIPPED {test}: {} cannot import iceoryx2 \
             (pip install -r examples/python/requirements.txt)",
            python()
        );
        return None;
    }
    Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/python/vlsync_subscriber.py"))
}

#[test]
fn python_subscriber_reads_live_estimates() {
    let Some(script) = subscriber_or_skip("python_subscriber_reads_live_estimates") else {
        return;
    };
    let rig = Rig::new("python", "robot", 3, 40.0, 5.0);
    let mut daemon = rig.daemon(0);
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let out = Command::new("timeout")
        .arg("30")
        .arg(python())
        .arg(&script)
        .args([
            "--prefix",
            &rig.prefix,
            "--count",
            "5",
            "--timeout",
            "10",
            "--json",
        ])
        .output()
        .expect("run the Python interpreter");
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(daemon.stop(Duration::from_secs(3)));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "python subscriber failed ({}):\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 5, "{stdout}");
    let mut last_seq = None;
    for l in lines {
        let v: serde_json::Value =
            serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}"));
        assert!(v["offset_s"].is_f64() && v["state"].is_string(), "{l}");
        // every field the Rust side validates is reported; JSON has no NaN: null
        for key in ["peak_ratio", "measured_offset_s"] {
            assert!(v[key].is_f64() || v[key].is_null(), "{key} in {l}");
        }
        let seq = v["seq"].as_u64().unwrap_or_else(|| panic!("no seq in {l}"));
        if let Some(p) = last_seq {
            assert!(seq > p, "sequence not increasing: {p} then {seq}");
        }
        last_seq = Some(seq);
    }
}

/// An iceoryx2 failure (here a service name beyond its maximum length) is exit
/// status 2 with one line naming the service, not a traceback.
#[test]
fn python_subscriber_reports_an_iceoryx2_error() {
    let Some(script) = subscriber_or_skip("python_subscriber_reports_an_iceoryx2_error") else {
        return;
    };
    let prefix = "x".repeat(300);
    let out = Command::new("timeout")
        .arg("30")
        .arg(python())
        .arg(&script)
        .args(["--prefix", &prefix, "--count", "1"])
        .output()
        .expect("run the Python interpreter");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.starts_with("vlsync_subscriber: error: ") && stderr.contains(&prefix),
        "{stderr}"
    );
    assert!(!stderr.contains("Traceback"), "{stderr}");
}
