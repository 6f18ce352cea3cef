//! The Python subscriber (official iceoryx2 package) reads the live daemon's
//! estimates through the same type name and layout as the Rust side.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};
use vlsync_common::wire::OffsetEstimate;
use vlsync_common::Stream;
use vlsync_ipc::iceoryx2::prelude::ServiceName;
use vlsync_ipc::iceoryx2::service::port_factory::PortFactory as _;
use vlsync_ipc::{create_node, Qos};
use vlsync_tests::{Managed, Rig};

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
        vlsync_tests::skipped(
            test,
            &format!(
                "{} cannot import iceoryx2 (pip install -r examples/python/requirements.txt)",
                python()
            ),
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
    // beside it, a reader that goes away after one line (`| head -1`): exit 0, no
    // traceback (it used to die on BrokenPipeError with exit 1, the code of a
    // timeout); started first, so its lines wait in the pipe while the run lasts
    let mut piped = Managed {
        name: "vlsync_subscriber.py".into(),
        child: Command::new(python())
            .arg(&script)
            .args(["--prefix", &rig.prefix, "--timeout", "10", "--json"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("run the Python interpreter"),
    };
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
    let mut first = String::new();
    {
        use std::io::BufRead;
        let mut reader = std::io::BufReader::new(piped.child.stdout.take().unwrap());
        reader.read_line(&mut first).unwrap();
    } // the read end closes here
    let piped_code = exit_code_within(&mut piped, Duration::from_secs(15));
    let _ = piped.child.kill();
    let piped_err = {
        use std::io::Read;
        let mut e = String::new();
        let _ = piped.child.stderr.take().unwrap().read_to_string(&mut e);
        e
    };
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(daemon.stop(Duration::from_secs(3)));
    assert!(first.starts_with('{'), "first line {first:?}: {piped_err}");
    assert_eq!(
        piped_code,
        Some(0),
        "after its reader went away: {piped_err}"
    );
    assert!(!piped_err.contains("Traceback"), "{piped_err}");
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

/// A bad argument is exit status 2 with a line naming it, not a traceback: a prefix
/// the daemon would refuse (it used to create `/bad/offset` and wait there forever),
/// a negative count (it used to exit 0 at once) or timeout.
#[test]
fn python_subscriber_refuses_bad_arguments() {
    let Some(script) = subscriber_or_skip("python_subscriber_refuses_bad_arguments") else {
        return;
    };
    let long = "x".repeat(300);
    for (args, names) in [
        (["--prefix", long.as_str()], "--prefix"),
        (["--prefix", "/bad"], "--prefix '/bad' is invalid"),
        (["--prefix", "robot/"], "--prefix 'robot/' is invalid"),
        (["--count", "-1"], "--count -1"),
        (["--timeout", "-1"], "--timeout -1"),
    ] {
        let out = Command::new("timeout")
            .arg("30")
            .arg(python())
            .arg(&script)
            .args(args)
            .output()
            .expect("run the Python interpreter");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(names), "{args:?}: {stderr}");
        assert!(!stderr.contains("Traceback"), "{args:?}: {stderr}");
    }
}

/// Waits up to `limit` for `p` to exit; its exit code (None: still running, killed).
fn exit_code_within(p: &mut Managed, limit: Duration) -> Option<i32> {
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        if let Ok(Some(st)) = p.child.try_wait() {
            return st.code();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    None
}

/// Waits until the subscriber logging to `log` gives its 5 s notice of waiting (it is
/// then in its wait loop, its services opened and its signal handlers installed);
/// returns the log so far. Fails if it exits first or gives none within 20 s.
fn wait_for_quiet_notice(py: &mut Managed, log: &Path) -> String {
    let t0 = Instant::now();
    loop {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        if text.contains("nothing received") {
            return text;
        }
        assert!(py.running(), "the subscriber exited:\n{text}");
        assert!(t0.elapsed() < Duration::from_secs(20), "no notice:\n{text}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Started before any daemon, the subscriber says what it waits for after 5 s, and
/// has created the offset services with the daemon's settings (it used to create
/// them with iceoryx2's defaults, which a daemon started later adopts: no estimate
/// kept for late subscribers, every client's buffer cut to 2). The daemon and the
/// drivers then start and it receives their estimates.
/// Starts the Python subscriber on the prefix `vlsync-it/<tag>-<pid>` for `count`
/// estimates (60 s at most), with `extra` arguments, its output in a log file of its
/// own: the process, the prefix and the log's path.
fn spawn_subscriber(
    script: &Path,
    tag: &str,
    count: u32,
    extra: &[&str],
) -> (Managed, String, std::path::PathBuf) {
    let prefix = format!("vlsync-it/{tag}-{}", std::process::id());
    let log = std::env::temp_dir().join(format!("vlsync-it-{tag}-{}.log", std::process::id()));
    let mut args = vec![
        script.display().to_string(),
        "--prefix".into(),
        prefix.clone(),
        "--count".into(),
        count.to_string(),
        "--timeout".into(),
        "60".into(),
    ];
    args.extend(extra.iter().map(|a| a.to_string()));
    let py = Managed::spawn("python subscriber", Path::new(&python()), &args, Some(&log))
        .expect("spawn the Python subscriber");
    (py, prefix, log)
}

#[test]
fn python_subscriber_started_first_creates_the_services_as_the_daemon_would() {
    let Some(script) = subscriber_or_skip(
        "python_subscriber_started_first_creates_the_services_as_the_daemon_would",
    ) else {
        return;
    };
    let tag = "python-first";
    // the prefix Rig::new will choose, needed before the rig's schedule starts
    let (mut py, prefix, log) = spawn_subscriber(&script, tag, 3, &["--json"]);
    let notice = wait_for_quiet_notice(&mut py, &log);
    assert!(notice.contains(&format!("`{prefix}/offset`")), "{notice}");
    {
        // the services exist by now (the notice comes after they were opened): this only
        // opens them, so a subscriber that did not create them fails here rather than
        // having this check create them with the very settings it compares
        let node = create_node("python-first-check", false).unwrap();
        let name = format!("{prefix}/offset");
        let sn = ServiceName::new(&name).unwrap();
        let svc = node
            .service_builder(&sn)
            .publish_subscribe::<OffsetEstimate>()
            .open()
            .unwrap_or_else(|e| panic!("{name} not created by the Python subscriber: {e:?}"));
        let c = svc.static_config();
        let want = Qos::latest();
        assert_eq!(
            (
                c.history_size(),
                c.subscriber_max_buffer_size(),
                c.max_publishers(),
                c.max_subscribers(),
                c.max_nodes()
            ),
            (
                want.history,
                want.max_buffer,
                want.max_publishers,
                want.max_subscribers,
                want.max_nodes
            ),
            "the Python subscriber created {name} with other settings than the daemon's"
        );
        let ev = node
            .service_builder(&sn)
            .event()
            .open()
            .unwrap_or_else(|e| {
                panic!("{name}'s event not created by the Python subscriber: {e:?}")
            });
        let e = ev.static_config();
        assert_eq!(
            (e.max_nodes(), e.max_notifiers(), e.max_listeners()),
            (48, 16, 16)
        );
    }
    let rig = Rig::new(tag, "robot", 3, 40.0, 5.0);
    assert_eq!(rig.prefix, prefix);
    let mut daemon = rig.daemon(0);
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let code = exit_code_within(&mut py, Duration::from_secs(40));
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(daemon.stop(Duration::from_secs(3)));
    let out = std::fs::read_to_string(&log).unwrap_or_default();
    assert_eq!(code, Some(0), "{out}\n{}", rig.log("vlsyncd-0.log"));
    let estimates = out.lines().filter(|l| l.starts_with('{')).count();
    assert_eq!(estimates, 3, "{out}");
    let _ = std::fs::remove_file(&log);
}

/// Ctrl-C (SIGINT) and SIGTERM end the subscriber with exit status 0 and no
/// traceback (iceoryx2's wait raised its own error on the signal, which escaped the
/// `KeyboardInterrupt` handler: exit 1 and a traceback, 143 on SIGTERM).
#[test]
fn python_subscriber_stops_cleanly_on_sigint_and_sigterm() {
    let Some(script) = subscriber_or_skip("python_subscriber_stops_cleanly_on_sigint_and_sigterm")
    else {
        return;
    };
    for sig in ["INT", "TERM"] {
        let prefix = format!("vlsync-it/python-{sig}-{}", std::process::id());
        let log =
            std::env::temp_dir().join(format!("vlsync-it-python-{sig}-{}.log", std::process::id()));
        let mut py = Managed::spawn(
            "python subscriber",
            Path::new(&python()),
            &[script.display().to_string(), "--prefix".into(), prefix],
            Some(&log),
        )
        .expect("spawn the Python subscriber");
        // a signal before its handlers are installed would be Python's default
        // KeyboardInterrupt: wait until it is in its wait loop
        wait_for_quiet_notice(&mut py, &log);
        py.signal(sig).unwrap();
        let code = exit_code_within(&mut py, Duration::from_secs(10));
        let out = std::fs::read_to_string(&log).unwrap_or_default();
        assert_eq!(code, Some(0), "SIG{sig}: {out}");
        assert!(
            !out.contains("Traceback") && !out.contains("KeyboardInterrupt"),
            "SIG{sig}: {out}"
        );
        let _ = std::fs::remove_file(&log);
    }
}

/// A publisher of broken estimates (NaN offsets): the subscriber skips them, says the
/// first on stderr and counts the rest (at most a line per 10 s: it used to print a
/// line per payload), and still prints the valid estimate that follows.
#[test]
fn python_subscriber_skips_invalid_estimates_without_flooding_stderr() {
    let Some(script) =
        subscriber_or_skip("python_subscriber_skips_invalid_estimates_without_flooding_stderr")
    else {
        return;
    };
    use vlsync_ipc::{notifier, open_or_create_event, open_or_create_pubsub, publisher};
    let (mut py, prefix, log) = spawn_subscriber(&script, "python-invalid", 1, &[]);
    // in its wait loop, subscribed
    wait_for_quiet_notice(&mut py, &log);
    let node = create_node("python-invalid-publisher", false).unwrap();
    let name = format!("{prefix}/offset");
    let svc = open_or_create_pubsub::<OffsetEstimate>(&node, &name, Qos::latest()).unwrap();
    let ev = open_or_create_event(&node, &name).unwrap();
    let publ = publisher(&svc, "offset").unwrap();
    let note = notifier(&ev, "offset").unwrap();
    let e = vlsync_tests::tracking_estimate(7);
    let mut bad = OffsetEstimate::from_estimate(&e, 1).unwrap();
    bad.offset_s = f64::NAN;
    // in batches of half the subscriber's buffer of 16: a reader one batch late
    // still reads every payload
    for _ in 0..6 {
        for _ in 0..8 {
            publ.send_copy(bad).unwrap();
        }
        note.notify().unwrap();
        std::thread::sleep(Duration::from_millis(400));
    }
    publ.send_copy(OffsetEstimate::from_estimate(&e, 2).unwrap())
        .unwrap();
    note.notify().unwrap();
    let code = exit_code_within(&mut py, Duration::from_secs(20));
    let out = std::fs::read_to_string(&log).unwrap_or_default();
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(
        out.matches("skipped invalid estimate: ").count(),
        1,
        "{out}"
    );
    // every payload it read is counted: all 48 when it kept up; a reader held up
    // past its buffer of 16 (two batches: a busy machine's Python) lost the oldest
    // (the publisher never blocks), and still read at least the 15 the buffer held
    // beside the valid one. Counted per wake-up it would say 6, twice each 96.
    let skipped: u64 = out
        .split_once("1 estimates received, ")
        .and_then(|(_, rest)| rest.split_once(" invalid ones skipped"))
        .and_then(|(n, _)| n.parse().ok())
        .unwrap_or_else(|| panic!("no count of the skipped payloads:\n{out}"));
    assert!((15..=48).contains(&skipped), "{skipped} skipped:\n{out}");
    assert!(out.lines().any(|l| l.starts_with("#7 ")), "{out}");
    let _ = std::fs::remove_file(&log);
}
