//! `daemon.load_hints` end to end: the daemon reads a pressure file (here one
//! the test writes, in the kernel's PSI format, through
//! `daemon.load_hint_source`), sees the CPU pressure jump, and tells the
//! estimator on its real-time thread, dated on the LiDAR clock near the
//! simulated time of the jump, even with refused LiDAR samples stamped far in the
//! future arriving around it. A pressure file that goes bad is named in the log
//! and turns the hints off without stopping the daemon.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vlsync_common::Stream;
use vlsync_ipc::monotonic_ns;
use vlsync_tests::{assert_serving, bin, write_daemon_config, Managed, Rig};

fn config(dir: &Path, prefix: &str, source: &Path) -> PathBuf {
    let keys = format!(
        "load_hints = true\nload_hint_source = \"{}\"\n",
        source.display()
    );
    write_daemon_config(dir, prefix, &keys)
}

/// Writes `some ... total=` into `path` (atomically: write and rename).
fn write_total(path: &Path, total_us: u64) {
    let tmp = path.with_extension("tmp");
    std::fs::write(
        &tmp,
        format!(
            "some avg10=0.00 avg60=0.00 avg300=0.00 total={total_us}\nfull avg10=0.00 avg60=0.00 avg300=0.00 total=0\n"
        ),
    )
    .unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

#[test]
fn a_pressure_jump_becomes_a_dated_change_of_the_estimator() {
    let rig = Rig::new("hints", "robot", 4, 40.0, 1.0);
    let source = rig.logs.join("cpu.pressure");
    write_total(&source, 0);
    // the pressure: none, then half of the time from `jump_at` (CLOCK_MONOTONIC) on
    let jump_at = rig.start_at + 8_000_000_000;
    let stop = Arc::new(AtomicBool::new(false));
    let writer = {
        let (stop, source) = (stop.clone(), source.clone());
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                let busy_ns = (monotonic_ns() - jump_at).max(0);
                write_total(&source, (busy_ns / 2 / 1000) as u64);
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };
    let cfg = config(&rig.logs, &rig.prefix, &source);
    let log = rig.logs.join("vlsyncd-0.log");
    let mut d = Managed::spawn(
        "vlsyncd",
        &bin("vlsyncd"),
        &["run".into(), "--config".into(), cfg.display().to_string()],
        Some(&log),
    )
    .expect("spawn vlsyncd");
    assert_serving(&mut d, &log);
    let _cam = rig.driver(Stream::Cam, 0);
    let _lidar = rig.driver(Stream::Lidar, 0);
    // around the jump, a hostile LiDAR publisher every 5 ms: stamps far in the
    // future with values the estimator refuses (too large). They must not date the
    // hint: it used to take the newest LiDAR stamp whether or not the estimator
    // took the sample, and declared the step at LiDAR t=9000000000 s
    let hostile = {
        let prefix = rig.prefix.clone();
        std::thread::spawn(move || {
            use vlsync_common::wire::SignatureSample;
            let node = vlsync_ipc::create_node("hostile-lidar", false).unwrap();
            let names = vlsync_ipc::ServiceNames::new(&prefix).unwrap();
            let name = names.signature(Stream::Lidar);
            let f = vlsync_ipc::open_or_create_pubsub::<SignatureSample>(
                &node,
                &name,
                vlsync_ipc::Qos::signature(256),
            )
            .unwrap();
            let p = vlsync_ipc::publisher(&f, &name).unwrap();
            let mut seq = 0;
            while monotonic_ns() < jump_at + 1_500_000_000 {
                if monotonic_ns() > jump_at - 500_000_000 {
                    let w =
                        SignatureSample::new(9_000_000_000_000_000_000, 1e300, seq, monotonic_ns());
                    if let Ok(s) = p.loan_uninit() {
                        let _ = s.write_payload(w).send();
                    }
                    seq += 1;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            seq
        })
    };
    // the simulated LiDAR time at the jump
    let sim_at_jump = {
        let anchor = rig.sim.cam[0].t_ns.min(rig.sim.lidar[0].t_ns);
        (anchor + (jump_at - rig.start_at)) as f64 * 1e-9
    };

    let read = || std::fs::read_to_string(&log).unwrap_or_default();
    let t0 = Instant::now();
    let declared = loop {
        let text = read();
        if let Some(t) = text.lines().find_map(|l| {
            l.split_once("stepped at LiDAR t=")?
                .1
                .trim_end_matches(" s")
                .parse::<f64>()
                .ok()
        }) {
            break t;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(25),
            "no load hint declared\n{text}"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(
        hostile.join().unwrap() > 100,
        "the hostile publisher sent too little"
    );
    let text = read();
    assert!(
        text.contains("load hints on") && text.contains("CPU pressure 0 % -> "),
        "{text}"
    );
    // dated where the pressure jumped (the readings are 250 ms apart, the writer's
    // 50 ms, and the LiDAR stamp-to-publish delay of the simulated driver is small:
    // about 0.3 s nominal; 1 s leaves a loaded machine's scheduling room and still
    // catches a hint dated by a refused far-future stamp, at 9e9 s)
    assert!(
        (declared - sim_at_jump).abs() < 1.0,
        "declared at {declared:.3} s, the jump was at {sim_at_jump:.3} s\n{text}"
    );

    // a pressure file that goes bad: named, hints off, the daemon keeps serving
    stop.store(true, Ordering::Relaxed);
    writer.join().unwrap();
    std::fs::write(&source, "garbage\n").unwrap();
    let t1 = Instant::now();
    while !read().contains("load hints off from now on") {
        assert!(
            t1.elapsed() < Duration::from_secs(5),
            "bad pressure file not reported\n{}",
            read()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let text = read();
    assert!(text.contains(&source.display().to_string()), "{text}");
    assert!(d.running(), "the daemon must keep running\n{text}");
    assert!(d.stop(Duration::from_secs(5)), "{}", read());
}
