//! `vlsync-demo` interrupted with Ctrl-C (SIGINT) stops every child and leaves
//! no shared-memory resource behind, on the signature simulator and on its
//! default source, rendered frames and scans through the front-ends.

use std::time::{Duration, Instant};
use vlsync_tests::{bin, ipc_resources, Managed};

/// Runs the demo with `args` for `run_for`, interrupts it, checks the clean
/// stop; returns its output.
fn interrupt_demo(tag: &str, args: &[&str], run_for: Duration) -> String {
    let demo = bin("vlsync-demo");
    let before = ipc_resources();
    let dir = std::env::temp_dir().join(format!("vlsync-demo-test-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("demo.log");
    let mut args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
    args.extend([
        "--log-dir".to_string(),
        dir.join("children").display().to_string(),
    ]);
    let mut m = Managed::spawn("vlsync-demo", &demo, &args, Some(&log)).unwrap();
    std::thread::sleep(run_for);
    assert!(
        m.running(),
        "demo ended early:\n{}",
        std::fs::read_to_string(&log).unwrap_or_default()
    );
    m.signal("INT").unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Ok(Some(s)) = m.child.try_wait() {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "demo did not stop on SIGINT"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(status.success(), "demo exit {status}:\n{out}");
    assert!(out.contains("=== summary (interrupted) ==="), "{out}");
    assert!(out.contains("children stopped cleanly"), "{out}");
    let t0 = Instant::now();
    let mut after = ipc_resources();
    while after != before && t0.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(100));
        after = ipc_resources();
    }
    let leaked: Vec<_> = after.iter().filter(|p| !before.contains(p)).collect();
    assert!(leaked.is_empty(), "left behind: {leaked:?}");
    let _ = std::fs::remove_dir_all(&dir);
    out
}

#[test]
fn demo_ctrl_c_stops_children_and_leaves_nothing() {
    // one after the other: a second demo would show up in the first one's resources
    let out = interrupt_demo(
        "sim",
        &["--family", "robot", "--duration", "60", "--speed", "2"],
        Duration::from_secs(6),
    );
    assert!(out.contains("signature simulator `robot`"), "{out}");
    // the default source: rendered frames and scans, scored against the render's truth;
    // long enough for the first locked estimates (about 5 s after the start)
    let out = interrupt_demo("render", &["--duration", "60"], Duration::from_secs(12));
    assert!(
        out.contains("rendered run seed 1 through the front-ends"),
        "{out}"
    );
    assert!(
        out.contains("convergence (wall time after the drivers' start)"),
        "{out}"
    );
    assert!(
        out.lines()
            .any(|l| l.contains("tracking") || l.contains("holding")),
        "no locked estimate in 12 s:\n{out}"
    );
}
