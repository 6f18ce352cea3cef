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
        // also with --wait-device: a build without V4L2 does not wait for a camera
        for extra in [&[][..], &["--wait-device"][..]] {
            let mut a = vec!["--v4l2", "/dev/video-vlsync-none"];
            a.extend_from_slice(extra);
            let err = run_failing_quickly(env!("CARGO_BIN_EXE_vlsync-cam"), &a);
            assert!(
                err.contains("rebuild with --features vlsync-driver/v4l2"),
                "{err}"
            );
        }
    }
}

/// Runs a driver that must fail at once; a driver still running after 20 s
/// (blocked opening a named pipe) is killed and fails the test.
fn run_failing_quickly(bin: &str, args: &[&str]) -> String {
    let mut child = Command::new(bin)
        .args(args)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn driver");
    wait_exit(&mut child, &format!("{bin} {args:?}"));
    let out = child.wait_with_output().unwrap();
    assert!(!out.status.success(), "{bin} {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn named_pipes_are_refused_not_waited_for() {
    let dir = std::env::temp_dir().join(format!("vlsync-driver-fifo-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("f");
    let made = Command::new("mkfifo").arg(&fifo).status();
    assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    assert!(Command::new("mkfifo")
        .arg(dir.join("frames/frames.csv"))
        .status()
        .unwrap()
        .success());
    let f = fifo.to_str().unwrap();
    let frames = dir.join("frames");
    let prefix = format!("vlsync-test/driver-fifo-{}", std::process::id());
    let (cam, lidar) = (
        env!("CARGO_BIN_EXE_vlsync-cam"),
        env!("CARGO_BIN_EXE_vlsync-lidar"),
    );
    for (bin, args) in [
        (cam, vec!["--csv", f]),
        (cam, vec!["--mcap", f]),
        (cam, vec!["--frames", frames.to_str().unwrap()]),
        (lidar, vec!["--scans", f]),
        (lidar, vec!["--mcap", f]),
        (lidar, vec!["--render", "1", "--config", f]),
    ] {
        let mut argv = args.clone();
        argv.extend(["--fast", "--prefix", &prefix]);
        let err = run_failing_quickly(bin, &argv);
        assert!(err.contains("not a regular file"), "{args:?}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn truth_files_have_one_row_per_published_sample() {
    let prefix = format!("vlsync-test/driver-truth-{}", std::process::id());
    let dir = std::env::temp_dir().join(format!("vlsync-driver-truth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (bin, stamp) in [
        (env!("CARGO_BIN_EXE_vlsync-cam"), "software"),
        (env!("CARGO_BIN_EXE_vlsync-lidar"), "mono"),
    ] {
        let file = dir.join(format!("{stamp}.csv"));
        let (ok, err) = run(
            bin,
            &[
                "--render",
                "5",
                "--duration",
                "2",
                "--stamp",
                stamp,
                "--truth-out",
                file.to_str().unwrap(),
                "--prefix",
                &prefix,
            ],
        );
        assert!(ok, "{err}");
        let published: usize = err
            .lines()
            .find_map(|l| {
                l.split_once(" published,")?
                    .0
                    .rsplit(' ')
                    .next()?
                    .parse()
                    .ok()
            })
            .unwrap_or_else(|| panic!("no published count in {err}"));
        let text = std::fs::read_to_string(&file).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some(vlsync_driver::TRUTH_HEADER));
        let rows: Vec<Vec<i64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), published, "{err}");
        assert!(published > 10, "{err}");
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(r.len(), 7);
            assert_eq!(r[0], i as i64, "sequence numbers in order");
            // published on CLOCK_MONOTONIC when the event happened (the LiDAR
            // is paced by its stamps, which carry 0.3 ms of jitter) or after it
            assert!(r[1] >= r[2] - 2_000_000, "{r:?}");
            assert!(r[1] - r[2] < 1_000_000_000, "{r:?}");
        }
        assert!(
            err.contains(&format!("{published} truth rows written")),
            "{err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_heavier_camera_front_end_delays_the_software_stamps() {
    // --frame-cpu-ms 8: each frame costs 8 ms of CPU before its stamp, so its
    // processing (truth column process_ns) takes at least that long in wall time
    let prefix = format!("vlsync-test/driver-cpu-{}", std::process::id());
    let file = std::env::temp_dir().join(format!("vlsync-driver-cpu-{}.csv", std::process::id()));
    let (ok, err) = run(
        env!("CARGO_BIN_EXE_vlsync-cam"),
        &[
            "--render",
            "5",
            "--duration",
            "2",
            "--stamp",
            "software",
            "--frame-cpu-ms",
            "8",
            "--truth-out",
            file.to_str().unwrap(),
            "--prefix",
            &prefix,
        ],
    );
    assert!(ok, "{err}");
    let text = std::fs::read_to_string(&file).unwrap();
    let process_ns: Vec<i64> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(5).unwrap().parse().unwrap())
        .collect();
    assert!(process_ns.len() > 10, "{err}");
    assert!(
        process_ns.iter().all(|&p| p >= 8_000_000),
        "processing times {process_ns:?}"
    );
    std::fs::remove_file(&file).unwrap();
}

/// Reads `child`'s stderr on a thread into a shared string.
fn collect_stderr(child: &mut std::process::Child) -> std::sync::Arc<std::sync::Mutex<String>> {
    use std::io::Read;
    let out = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let mut pipe = child.stderr.take().unwrap();
    let o = out.clone();
    std::thread::spawn(move || {
        let mut buf = [0u8; 512];
        while let Ok(n) = pipe.read(&mut buf) {
            if n == 0 {
                break;
            }
            o.lock()
                .unwrap()
                .push_str(&String::from_utf8_lossy(&buf[..n]));
        }
    });
    out
}

fn wait_for_text(text: &std::sync::Mutex<String>, what: &str) {
    let t0 = std::time::Instant::now();
    while !text.lock().unwrap().contains(what) {
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(20),
            "no `{what}` in: {}",
            text.lock().unwrap()
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// Waits up to 20 s for `child` (`what`) to exit; kills it and fails the test after that.
fn wait_exit(child: &mut std::process::Child, what: &str) -> std::process::ExitStatus {
    let t0 = std::time::Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if t0.elapsed() > std::time::Duration::from_secs(20) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} still running after 20 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

#[test]
fn wait_device_waits_for_the_node_then_opens_it_and_stops_cleanly_meanwhile() {
    let dir = std::env::temp_dir().join(format!("vlsync-driver-wait-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let dev = dir.join("ttyUSB9");
    let d = dev.to_str().unwrap();
    let prefix = format!("vlsync-test/driver-wait-{}", std::process::id());
    let spawn = || {
        Command::new(env!("CARGO_BIN_EXE_vlsync-lidar"))
            .args(["--ld06", d, "--wait-device", "--prefix", &prefix])
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("spawn driver")
    };
    // without the flag a missing device fails at once
    let err = run_failing_quickly(env!("CARGO_BIN_EXE_vlsync-lidar"), &["--ld06", d]);
    assert!(err.contains(d), "{err}");
    // with it the driver waits, and SIGTERM meanwhile is a clean stop
    let mut child = spawn();
    let err = collect_stderr(&mut child);
    wait_for_text(&err, &format!("waiting for {d} to appear"));
    std::thread::sleep(std::time::Duration::from_millis(600));
    assert!(
        child.try_wait().unwrap().is_none(),
        "{}",
        err.lock().unwrap()
    );
    // kill(2) itself: procps's `kill` is not on every minimal system
    let pid = rustix::process::Pid::from_raw(child.id() as i32).unwrap();
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).unwrap();
    let status = wait_exit(&mut child, "vlsync-lidar --wait-device");
    assert!(status.success(), "{status}: {}", err.lock().unwrap());
    // it says so, and stops before it makes its iceoryx2 node and publisher (the
    // reader thread may still be taking the last lines: waited for)
    wait_for_text(&err, &format!("stopped while waiting for {d}"));
    wait_for_text(&err, ", interrupted");
    let text = err.lock().unwrap().clone();
    assert!(!text.contains("publishing"), "{text}");
    // the node appears (a regular file here, not a tty): the driver goes on to open it
    let mut child = spawn();
    let err = collect_stderr(&mut child);
    wait_for_text(&err, &format!("waiting for {d} to appear"));
    std::fs::write(&dev, b"").unwrap();
    let status = wait_exit(&mut child, "vlsync-lidar --wait-device");
    let text = err.lock().unwrap().clone();
    assert!(text.contains(&format!("{d} appeared after")), "{text}");
    assert!(
        !status.success(),
        "a regular file is no serial port: {text}"
    );
    assert!(text.contains("error:") && text.contains(d), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Wrong options, a configuration file that does not load and a command line that
/// cannot be parsed exit 78 (EX_CONFIG), which the driver units do not restart; a
/// source that fails (here a missing file) exits 2 and is restarted. `--help` exits 0.
#[test]
fn option_and_configuration_errors_exit_78_source_errors_2() {
    let code = |bin: &str, args: &[&str]| {
        let out = Command::new(bin).args(args).output().expect("spawn driver");
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let dir = std::env::temp_dir().join(format!("vlsync-driver-exit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "[lidar]\nwindow_half_width_deg = 400\n").unwrap();
    let (cam, lidar) = (
        env!("CARGO_BIN_EXE_vlsync-cam"),
        env!("CARGO_BIN_EXE_vlsync-lidar"),
    );
    for (bin, args, want, names) in [
        (lidar, vec!["--frames", "/tmp"], 78, "--frames"),
        (cam, vec!["--no-such-flag"], 78, "--no-such-flag"),
        // checked before any source is opened, each naming its flag
        (
            cam,
            vec!["--render", "1", "--duration", "nan"],
            78,
            "--duration",
        ),
        (
            cam,
            vec!["--csv", "/nonexistent/c.csv", "--speed", "0"],
            78,
            "--speed",
        ),
        // a negative number is the flag's value, refused by its range check (clap
        // used to call it an unexpected argument, naming no flag)
        (
            cam,
            vec!["--csv", "/nonexistent/c.csv", "--speed", "-2"],
            78,
            "--speed -2",
        ),
        (
            cam,
            vec!["--csv", "/nonexistent/c.csv", "--duration", "5"],
            78,
            "--duration",
        ),
        // a prefix iceoryx2 cannot name services with, on the command line (it used to
        // exit 2, so a mistyped prefix in the unit's environment was restarted forever)
        (
            cam,
            vec!["--sim", "robot", "--prefix", "/bad//x"],
            78,
            "--prefix",
        ),
        (
            lidar,
            vec!["--sim", "robot", "--config", bad.to_str().unwrap()],
            78,
            "window_half_width_deg",
        ),
        // a camera mode asked of the LiDAR: wrong options (it exited 2 from the
        // source's opening, and the unit would have restarted it forever)
        (
            lidar,
            vec!["--render", "1", "--stamp", "software"],
            78,
            "--stamp software is a camera mode",
        ),
        (
            lidar,
            vec!["--scans", "/nonexistent/vlsync/s.csv"],
            2,
            "/nonexistent/vlsync/s.csv",
        ),
        (cam, vec!["--help"], 0, ""),
    ] {
        let (c, err) = code(bin, &args);
        assert_eq!(c, Some(want), "{bin} {args:?}: {err}");
        assert!(err.contains(names), "{bin} {args:?}: {err}");
    }
    // a build without V4L2 asked for a camera: the options are wrong for this binary
    // (it exited 2, and the unit restarted it every 2 s forever), even when told to
    // wait for the device
    if !cfg!(feature = "v4l2") {
        for args in [
            vec!["--v4l2", "/dev/video0"],
            vec!["--v4l2", "/dev/video-vlsync-missing", "--wait-device"],
        ] {
            let (c, err) = code(cam, &args);
            assert_eq!(c, Some(78), "{args:?}: {err}");
            assert!(
                err.contains("built without V4L2 support"),
                "{args:?}: {err}"
            );
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
