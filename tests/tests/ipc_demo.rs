//! `vlsync-demo` interrupted with Ctrl-C (SIGINT) stops every child and leaves
//! no shared-memory resource behind, on the signature simulator and on its
//! default source, rendered frames and scans through the front-ends; and so it
//! does when its reader goes away (`vlsync-demo | head`); killed with SIGKILL, its
//! children stop on their own and clean up. Every stop is given
//! [`HARNESS_GRACE`], the time the demo's own clean stop may take (it stops its
//! daemon, drivers and recorder one after the other, each with seconds of grace).

use std::time::{Duration, Instant};
use vlsync_tests::{assert_nothing_left, bin, ipc_resources, Harness, Managed, HARNESS_GRACE};

/// Runs the demo with `args` for at least `run_for` and until its output satisfies
/// `until` (at most `deadline`: a slow machine's first lock comes later, and a
/// fixed wait judged it too early), interrupts it, checks the clean stop; returns
/// its output.
fn interrupt_demo(
    tag: &str,
    args: &[&str],
    run_for: Duration,
    until: impl Fn(&str) -> bool,
    deadline: Duration,
) -> String {
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
    // stopped with its grace when dropped: a failing assertion leaves no run behind
    let mut m = Harness(Managed::spawn("vlsync-demo", &demo, &args, Some(&log)).unwrap());
    let started = Instant::now();
    std::thread::sleep(run_for);
    while started.elapsed() < deadline
        && m.0.running()
        && !until(&std::fs::read_to_string(&log).unwrap_or_default())
    {
        std::thread::sleep(Duration::from_millis(200));
    }
    assert!(
        m.0.running(),
        "demo ended early:\n{}",
        std::fs::read_to_string(&log).unwrap_or_default()
    );
    m.0.signal("INT").unwrap();
    let status = m.0.wait_up_to(HARNESS_GRACE).unwrap_or_else(|| {
        panic!(
            "demo did not stop within {HARNESS_GRACE:?} of SIGINT:\n{}",
            std::fs::read_to_string(&log).unwrap_or_default()
        )
    });
    let out = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(status.success(), "demo exit {status}:\n{out}");
    assert!(out.contains("=== summary (interrupted) ==="), "{out}");
    assert!(out.contains("children stopped cleanly"), "{out}");
    // the daemon's real-time thread as the kernel reports it: SCHED_FIFO 50 (the demo's
    // default) where the machine grants it, else the normal scheduler and why
    let rt = out
        .lines()
        .find_map(|l| l.strip_prefix("daemon's real-time thread: "))
        .unwrap_or_else(|| panic!("no real-time thread line:\n{out}"));
    assert!(
        rt.starts_with("SCHED_FIFO priority 50, ")
            || rt.contains("SCHED_FIFO priority 50 refused: "),
        "{rt}"
    );
    // an interrupted run still gets its plot, by default in the log directory
    let plot = dir.join("children").join("demo.svg");
    let svg = std::fs::read_to_string(&plot).unwrap_or_default();
    assert!(
        svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"),
        "{}: {svg}",
        plot.display()
    );
    assert!(out.contains(&format!("plot: {}", plot.display())), "{out}");
    if out.lines().any(|l| l.contains(" tracking ")) {
        assert!(
            svg.contains("<polyline"),
            "locked estimates, but no curve: {svg}"
        );
    }
    assert_nothing_left(&before);
    let _ = std::fs::remove_dir_all(&dir);
    out
}

/// `vlsync-demo | head -3`: the demo reads a closed pipe as the end of its run,
/// stops its children and exits 0 instead of panicking on its next line.
fn close_the_reader() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    let before = ipc_resources();
    let dir = std::env::temp_dir().join(format!("vlsync-demo-test-pipe-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let err = dir.join("stderr.log");
    // stopped when dropped: a failing assertion leaves no 30 s run behind
    let mut demo = Harness(Managed {
        name: "vlsync-demo".into(),
        child: Command::new(bin("vlsync-demo"))
            .args([
                "--family",
                "robot",
                "--duration",
                "60",
                "--speed",
                "2",
                "--log-dir",
            ])
            .arg(dir.join("children"))
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap(),
    });
    let mut lines = BufReader::new(demo.0.child.stdout.take().unwrap()).lines();
    for _ in 0..3 {
        assert!(
            lines.next().is_some_and(|l| l.is_ok()),
            "fewer than 3 lines"
        );
    }
    drop(lines);
    // (a failure drops `demo`, which interrupts it: Ctrl-C first, so that its
    // children stop too)
    let status = demo.0.wait_up_to(HARNESS_GRACE).unwrap_or_else(|| {
        panic!("demo still running {HARNESS_GRACE:?} after its reader went away")
    });
    let stderr = std::fs::read_to_string(&err).unwrap_or_default();
    assert!(status.success(), "demo exit {status}:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_nothing_left(&before);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn demo_ctrl_c_stops_children_and_leaves_nothing() {
    // one after the other: a second demo would show up in the first one's resources
    let rec = std::env::temp_dir().join(format!("vlsync-demo-test-rec-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&rec);
    let rows = |f: &str| {
        std::fs::read_to_string(rec.join(f))
            .unwrap_or_default()
            .lines()
            .count()
    };
    let stretches = |out: &str| {
        out.lines()
            .filter(|l| l.starts_with("--- ") && l.contains(" estimate(s) ("))
            .count()
    };
    // a locked estimate recorded: the replay below scores against the truth only
    // the locked ones, and its estimates are the recorded ones (`--compare`)
    let locked_recorded = || {
        std::fs::read_to_string(rec.join("est.csv"))
            .is_ok_and(|t| t.contains(",tracking,") || t.contains(",holding,"))
    };
    // until two 2 s stretch lines are out and the recording (flushed every second)
    // holds what is checked below: how long that takes is the machine's, so it is
    // waited for (up to 45 s of the run's 60 s) rather than assumed from a fixed run
    let enough = |out: &str| {
        stretches(out) >= 2
            && rows("cam.csv") > 100
            && rows("lidar.csv") > 30
            && rows("est.csv") > 5
            && locked_recorded()
    };
    let out = interrupt_demo(
        "sim",
        &[
            "--family",
            "robot",
            "--duration",
            "120",
            "--speed",
            "2",
            "--summary-every",
            "2",
            "--record",
            rec.to_str().unwrap(),
        ],
        Duration::ZERO,
        enough,
        Duration::from_secs(45),
    );
    assert!(out.contains("signature simulator `robot`"), "{out}");
    // --record: the streams, the estimates and the truth, which replay reads back
    let r = rec.display();
    assert!(
        out.contains(&format!("recorded: {r}/{{cam,lidar,est,truth}}.csv")),
        "{out}"
    );
    assert!(rows("cam.csv") > 100 && rows("lidar.csv") > 30, "{out}");
    assert!(rows("est.csv") > 5 && rows("truth.csv") > 100, "{out}");
    let mut replay = std::process::Command::new(bin("vlsyncd"));
    replay.arg("replay");
    for (flag, file) in [
        ("--cam", "cam.csv"),
        ("--lidar", "lidar.csv"),
        ("--out", "replayed.csv"),
        ("--truth", "truth.csv"),
        ("--compare", "est.csv"),
    ] {
        replay.arg(flag).arg(rec.join(file));
    }
    let replay = replay.output().unwrap();
    let said = String::from_utf8_lossy(&replay.stderr);
    assert!(replay.status.success(), "{said}");
    assert!(
        said.contains("error vs truth over ") && said.contains(&format!("against {r}/est.csv: ")),
        "{said}"
    );
    std::fs::remove_dir_all(&rec).unwrap();
    // stretch lines of 2 s as the run goes (and the last one when it is interrupted)
    let stretches = stretches(&out);
    assert!(stretches >= 2, "{stretches} stretch line(s):\n{out}");
    // the default source: rendered frames and scans, scored against the render's truth;
    // until the first locked estimate (about 6 s after the drivers' start on an idle
    // machine; up to 45 s of the 60 s run on a loaded one)
    let locked = |out: &str| {
        out.lines()
            .any(|l| l.contains("tracking") || l.contains("holding"))
    };
    let out = interrupt_demo(
        "render",
        &["--duration", "60"],
        Duration::from_secs(3),
        locked,
        Duration::from_secs(45),
    );
    assert!(
        out.contains("rendered run seed 1 through the front-ends"),
        "{out}"
    );
    assert!(
        out.contains("convergence (wall time after the drivers' start)"),
        "{out}"
    );
    assert!(locked(&out), "no locked estimate in 45 s:\n{out}");
    close_the_reader();
    a_killed_demo_takes_its_children_with_it();
    // last: the daemon it kills leaves its files to the next daemon's clean-up
    a_child_killed_mid_run_is_a_failure();
}

/// The pids of the running processes whose command line names `prefix` as an
/// argument (the demo's daemon, drivers and recorder; a zombie has no command line).
fn pids_with(prefix: &str) -> Vec<u32> {
    let want = format!("\0{prefix}\0");
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.flatten()
        .filter_map(|e| {
            let pid: u32 = e.file_name().to_str()?.parse().ok()?;
            let cmd = std::fs::read(e.path().join("cmdline")).ok()?;
            String::from_utf8_lossy(&cmd).contains(&want).then_some(pid)
        })
        .collect()
}

/// `kill -9` of the demo (or the OOM killer): no clean-up of its own runs, but its
/// daemon, drivers and recorder stop as on SIGTERM (each asked the kernel for a
/// signal at its parent's death) and leave no shared memory and no lock behind,
/// where they used to run on (the daemon and recorder forever).
fn a_killed_demo_takes_its_children_with_it() {
    let before = ipc_resources();
    let prefix = format!("vlsync-test/demo-kill9-{}", std::process::id());
    let dir = std::env::temp_dir().join(format!("vlsync-demo-kill9-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut demo = Harness(Managed {
        name: "vlsync-demo".into(),
        child: std::process::Command::new(bin("vlsync-demo"))
            .args(["--family", "robot", "--duration", "120", "--speed", "2"])
            .args(["--quiet", "--prefix", &prefix, "--log-dir"])
            .arg(dir.join("logs"))
            .arg("--record")
            .arg(dir.join("rec"))
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    });
    // the daemon, both drivers and the recorder (the demo names the prefix too)
    let demo_pid = demo.0.pid();
    let children = || {
        let mut p = pids_with(&prefix);
        p.retain(|&pid| pid != demo_pid);
        p
    };
    let t0 = Instant::now();
    while children().len() < 4 {
        assert!(
            t0.elapsed() < Duration::from_secs(30) && demo.0.running(),
            "the demo's four children never ran: {:?}",
            children()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_secs(2));
    demo.0.signal("KILL").unwrap();
    assert!(demo.0.wait_up_to(Duration::from_secs(5)).is_some());
    let t0 = Instant::now();
    while !children().is_empty() && t0.elapsed() < HARNESS_GRACE {
        std::thread::sleep(Duration::from_millis(100));
    }
    let left = children();
    let log = std::fs::read_to_string(dir.join("logs").join("vlsyncd.log")).unwrap_or_default();
    assert!(
        left.is_empty(),
        "still running {HARNESS_GRACE:?} after the demo's SIGKILL: {left:?}\n{log}"
    );
    // stopped as on SIGTERM: its summary and its own clean-up
    assert!(
        log.contains("at stop, ") && log.contains("stopped"),
        "{log}"
    );
    assert!(
        !vlsyncd::runtime::lock_path(&prefix).exists(),
        "the daemon's lock is left"
    );
    assert_nothing_left(&before);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The pid of the running `vlsyncd run --prefix <prefix>`, from `/proc/*/cmdline`.
fn daemon_pid(prefix: &str) -> Option<u32> {
    let want = format!("run\0--prefix\0{prefix}\0");
    std::fs::read_dir("/proc").ok()?.flatten().find_map(|e| {
        let pid: u32 = e.file_name().to_str()?.parse().ok()?;
        let cmd = std::fs::read(e.path().join("cmdline")).ok()?;
        String::from_utf8_lossy(&cmd).contains(&want).then_some(pid)
    })
}

/// A daemon killed during the run (a crash, someone's `kill -9`) is reported as such,
/// with its log, and the demo fails (exit 2) instead of saying its children stopped
/// cleanly.
fn a_child_killed_mid_run_is_a_failure() {
    let prefix = format!("vlsync-test/demo-crash-{}", std::process::id());
    let dir = std::env::temp_dir().join(format!("vlsync-demo-crash-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (out_file, err_file) = (dir.with_extension("stdout"), dir.with_extension("stderr"));
    // stopped when dropped, so a failing assertion does not leave a 60 s run behind
    let mut demo = Harness(Managed {
        name: "vlsync-demo".into(),
        child: std::process::Command::new(bin("vlsync-demo"))
            .args([
                "--family",
                "robot",
                "--duration",
                "120",
                "--speed",
                "2",
                "--quiet",
            ])
            .args(["--prefix", &prefix, "--log-dir"])
            .arg(dir.join("logs"))
            .arg("--record")
            .arg(dir.join("rec"))
            .stdout(std::fs::File::create(&out_file).unwrap())
            .stderr(std::fs::File::create(&err_file).unwrap())
            .spawn()
            .unwrap(),
    });
    let t0 = Instant::now();
    let pid = loop {
        if let Some(pid) = daemon_pid(&prefix) {
            break pid;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "no daemon on {prefix}"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    std::thread::sleep(Duration::from_secs(2));
    vlsyncd::runtime::procs::send_signal(pid, "KILL").unwrap();
    // the run would last 120 s (60 s at --speed 2): ending within the grace of its own
    // stop is at once (its stop waits for each driver and the recorder in turn, and
    // 3 s for a status that a dead daemon never publishes)
    let status = demo.0.wait_up_to(HARNESS_GRACE);
    let (stdout, stderr) = (
        std::fs::read_to_string(&out_file).unwrap_or_default(),
        std::fs::read_to_string(&err_file).unwrap_or_default(),
    );
    let status = status.unwrap_or_else(|| {
        panic!("the demo ran on for {HARNESS_GRACE:?} after its daemon died:\n{stdout}\n{stderr}")
    });
    assert_eq!(status.code(), Some(2), "{stdout}\n{stderr}");
    let log = dir.join("logs").join("vlsyncd.log");
    let said = format!(
        "vlsyncd: killed by signal 9 (SIGKILL) (log: {})",
        log.display()
    );
    assert!(
        stdout.contains(&format!("ended with a failure: {said}")),
        "{stdout}"
    );
    assert!(stderr.contains(&said), "{stderr}");
    assert!(!stdout.contains("children stopped cleanly"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_file(&out_file);
    let _ = std::fs::remove_file(&err_file);
    // the killed daemon's lock file, on a prefix no other run uses
    let _ = std::fs::remove_file(vlsyncd::runtime::lock_path(&prefix));
}
