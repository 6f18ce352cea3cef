//! `vlsync-demo` interrupted with Ctrl-C (SIGINT) stops every child and leaves
//! no shared-memory resource behind.

use std::time::{Duration, Instant};
use vlsync_tests::{bin, ipc_resources, Managed};

#[test]
fn demo_ctrl_c_stops_children_and_leaves_nothing() {
    let demo = bin("vlsync-demo");
    let before = ipc_resources();
    let log = std::env::temp_dir().join(format!("vlsync-demo-test-{}.log", std::process::id()));
    let mut m = Managed::spawn(
        "vlsync-demo",
        &demo,
        &[
            "--family".into(),
            "robot".into(),
            "--duration".into(),
            "60".into(),
            "--speed".into(),
            "2".into(),
        ],
        Some(&log),
    )
    .unwrap();
    std::thread::sleep(Duration::from_secs(6));
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
}
