//! The Python subscriber (official iceoryx2 package) reads the live daemon's
//! estimates through the same type name and layout as the Rust side.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};
use vlsync_common::wire::OffsetEstimate;
use vlsync_common::{Estimate, EstimatorState, Polarity, Stream};
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
    // 60 s of the run (12 s of wall time): the 24 estimates read below take 12 s of
    // it, the lock within their first 6 s (as the C client's test)
    let rig = Rig::new("python", "robot", 3, 60.0, 5.0);
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
            "24",
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
    assert_eq!(lines.len(), 24, "{stdout}");
    let mut last_seq = None;
    let mut locked = 0;
    for l in lines {
        let v: serde_json::Value =
            serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}"));
        assert!(v["offset_s"].is_f64() && v["state"].is_string(), "{l}");
        // every field the Rust side validates is reported; JSON has no NaN: null
        for key in ["peak_ratio", "measured_offset_s"] {
            assert!(v[key].is_f64() || v[key].is_null(), "{key} in {l}");
        }
        // the age is measured on the daemon's CLOCK_MONOTONIC: a live estimate is
        // seconds old at most (on the wall clock's scale it would be 1.7e9 s)
        let age = v["age_s"]
            .as_f64()
            .unwrap_or_else(|| panic!("no age_s in {l}"));
        assert!((0.0..30.0).contains(&age), "age {age} s: {l}");
        assert!(v["stale"].is_boolean(), "{l}");
        let seq = v["seq"].as_u64().unwrap_or_else(|| panic!("no seq in {l}"));
        if let Some(p) = last_seq {
            assert!(seq > p, "sequence not increasing: {p} then {seq}");
        }
        last_seq = Some(seq);
        // a locked estimate is the simulator's offset at its reference time, as the
        // C client's test checks (tests/tests/ipc_capi.rs)
        if ["tracking", "holding"].contains(&v["state"].as_str().unwrap()) {
            locked += 1;
            let t_ref = v["t_ref_ns"]
                .as_i64()
                .unwrap_or_else(|| panic!("no t_ref_ns in {l}"));
            let offset_ms = v["offset_s"].as_f64().unwrap() * 1e3;
            let truth_ms = rig.sim.truth.offset_at(t_ref) * 1e3;
            assert!(
                (offset_ms - truth_ms).abs() < 20.0,
                "Python client: {offset_ms} ms against the truth {truth_ms} ms at {t_ref} ns:\n{stdout}"
            );
        }
    }
    assert!(locked >= 6, "only {locked} locked estimates:\n{stdout}");
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
        (["--max-age", "0"], "--max-age 0.0 must be seconds > 0"),
        (["--max-age", "nan"], "--max-age nan must be seconds > 0"),
        (
            ["--max-age", "1e7"],
            "--max-age 10000000.0 must be seconds > 0 (at most 1000000)",
        ),
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
    // the binaries first: built after the subscriber started (a first run, or sources
    // changed since), the build could outlast its --timeout of 60 s
    vlsync_tests::bin("vlsyncd");
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

/// Publishes `estimates` on `prefix`'s offset service (as a daemon would: its
/// settings, a notification after them) and waits up to 20 s for the subscriber `py`
/// to exit, the publisher kept alive meanwhile: its exit code.
fn publish_then_wait(py: &mut Managed, prefix: &str, estimates: &[OffsetEstimate]) -> Option<i32> {
    use vlsync_ipc::{notifier, open_or_create_event, open_or_create_pubsub, publisher};
    let node = create_node("python-fields-publisher", false).unwrap();
    let name = format!("{prefix}/offset");
    let svc = open_or_create_pubsub::<OffsetEstimate>(&node, &name, Qos::latest()).unwrap();
    let ev = open_or_create_event(&node, &name).unwrap();
    let publ = publisher(&svc, "offset").unwrap();
    let note = notifier(&ev, "offset").unwrap();
    for e in estimates {
        publ.send_copy(*e).unwrap();
    }
    note.notify().unwrap();
    exit_code_within(py, Duration::from_secs(20))
}

/// An estimate with a distinct value in every field (none zero: a swap of two fields
/// of the same type in the script's ctypes struct or its dict shows), each exactly
/// representable in the few decimals JSON carries it in.
fn distinct_estimate(seq: u64) -> Estimate {
    Estimate {
        seq,
        t_ref_ns: 987_654_321_012,
        offset_s: 0.0421,
        drift: 3.7e-5,
        offset_std_s: 0.00125,
        drift_std: 2.5e-7,
        state: EstimatorState::Holding,
        polarity: Polarity::Negative,
        peak_score: 0.83,
        peak_ratio: 2.75,
        measured_offset_s: 0.0433,
    }
}

/// Every JSON key of a known estimate, compared exactly, and an estimate published
/// 600 s ago (a daemon that stopped long since: the service hands its last estimate
/// to a late subscriber, still `holding`) marked stale, by its age on
/// `CLOCK_MONOTONIC`, in JSON and in text.
#[test]
fn python_subscriber_reports_every_field_exactly_and_marks_old_estimates_stale() {
    let Some(script) = subscriber_or_skip(
        "python_subscriber_reports_every_field_exactly_and_marks_old_estimates_stale",
    ) else {
        return;
    };
    let (mut json_py, json_prefix, json_log) =
        spawn_subscriber(&script, "python-fields-json", 2, &["--json"]);
    let (mut text_py, text_prefix, text_log) =
        spawn_subscriber(&script, "python-fields-text", 2, &[]);
    // both in their wait loops, subscribed
    wait_for_quiet_notice(&mut json_py, &json_log);
    wait_for_quiet_notice(&mut text_py, &text_log);
    let fresh_ns = vlsync_ipc::monotonic_ns();
    let old_ns = fresh_ns - 600_000_000_000;
    let estimates = [
        OffsetEstimate::from_estimate(&distinct_estimate(424_242), fresh_ns).unwrap(),
        OffsetEstimate::from_estimate(&distinct_estimate(424_243), old_ns).unwrap(),
    ];
    let json_code = publish_then_wait(&mut json_py, &json_prefix, &estimates);
    let text_code = publish_then_wait(&mut text_py, &text_prefix, &estimates);
    let json_out = std::fs::read_to_string(&json_log).unwrap_or_default();
    let text_out = std::fs::read_to_string(&text_log).unwrap_or_default();
    assert_eq!(json_code, Some(0), "{json_out}");
    assert_eq!(text_code, Some(0), "{text_out}");

    let objects: Vec<serde_json::Value> = json_out
        .lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
        .collect();
    assert_eq!(objects.len(), 2, "{json_out}");
    for (v, seq, publish_ns, stale, ages) in [
        (&objects[0], 424_242u64, fresh_ns, false, 0.0..30.0),
        (&objects[1], 424_243, old_ns, true, 600.0..630.0),
    ] {
        let mut got = v.as_object().unwrap_or_else(|| panic!("{v}")).clone();
        // the age runs on: a range, the rest exactly
        let age = got.remove("age_s").and_then(|a| a.as_f64());
        assert!(age.is_some_and(|a| ages.contains(&a)), "age_s {age:?}: {v}");
        let want = serde_json::json!({
            "seq": seq,
            "t_ref_ns": 987_654_321_012i64,
            "offset_s": 0.0421,
            "drift": 3.7e-5,
            "offset_std_s": 0.00125,
            "drift_std": 2.5e-7,
            "state": "holding",
            "polarity": "negative",
            "peak_score": 0.83,
            "peak_ratio": 2.75,
            "measured_offset_s": 0.0433,
            "publish_ns": publish_ns,
            "stale": stale,
        });
        assert_eq!(serde_json::Value::Object(got), want, "{json_out}");
    }

    let lines: Vec<&str> = text_out.lines().filter(|l| l.starts_with('#')).collect();
    assert_eq!(lines.len(), 2, "{text_out}");
    assert_eq!(
        lines[0],
        "#424242 t_ref      987.654 s  offset   +42.100 ms ±   1.250 ms  drift   +37.00 ppm  holding",
        "{text_out}"
    );
    let (head, tail) = lines[1]
        .split_once("  stale (")
        .unwrap_or_else(|| panic!("not marked stale: {text_out}"));
    assert_eq!(
        head, "#424243 t_ref      987.654 s  offset   +42.100 ms ±   1.250 ms  drift   +37.00 ppm",
        "{text_out}"
    );
    let (age, rest) = tail
        .split_once(" s old; ")
        .unwrap_or_else(|| panic!("{text_out}"));
    let age: f64 = age.parse().unwrap_or_else(|_| panic!("{text_out}"));
    assert!((600.0..630.0).contains(&age), "{text_out}");
    assert_eq!(rest, "holding when published)", "{text_out}");
    let _ = std::fs::remove_file(&json_log);
    let _ = std::fs::remove_file(&text_log);
}

/// Runs the Python snippet `code` with the script's directory as its first argument
/// (so it can `import vlsync_subscriber`) and `extra` after it: optimised (`-O`, which
/// strips `assert`s: the script must not rely on them), no bytecode written.
fn python_snippet(script: &Path, code: &str, extra: &[&str]) -> std::process::Output {
    Command::new("timeout")
        .arg("30")
        .arg(python())
        .args(["-O", "-B", "-c", code])
        .arg(script.parent().unwrap())
        .args(extra)
        .output()
        .expect("run the Python interpreter")
}

/// The script's `camera_to_lidar` helper gives the Rust client's LiDAR time and σ bit
/// for bit (`OffsetClient::camera_to_lidar`: `Estimate::camera_to_lidar`, and
/// `offset_std_with_walk` at the shipped walk of the estimate's state), for drifts
/// that matter and stamps 10 s to an hour from t_ref, before and after it.
#[test]
fn python_camera_to_lidar_matches_the_rust_conversion() {
    let Some(script) = subscriber_or_skip("python_camera_to_lidar_matches_the_rust_conversion")
    else {
        return;
    };
    let walks = vlsync_config::EstimatorConfig::default();
    let base = Estimate {
        t_ref_ns: 1_234_567_890_123,
        offset_s: 0.1 / 3.0,
        drift: 4.2e-5,
        offset_std_s: 0.0011,
        drift_std: 3.3e-7,
        ..distinct_estimate(1)
    };
    let cases: Vec<(Estimate, i64)> = [
        (EstimatorState::Tracking, 4.2e-5, -0.4),
        (EstimatorState::Holding, -2.75e-4, 0.0421),
        (EstimatorState::Lost, 1e-3, 1.0 / 7.0),
        (EstimatorState::Acquiring, -3.1e-6, -0.0005),
    ]
    .into_iter()
    .flat_map(|(state, drift, offset_s)| {
        let e = Estimate {
            state,
            drift,
            offset_s,
            ..base
        };
        [12_345_678_901, -15_000_000_001, 3_600_000_000_000]
            .map(|from_ref| (e, e.t_ref_ns + from_ref))
    })
    .collect();
    let input = serde_json::Value::Array(
        cases
            .iter()
            .map(|(e, t_cam)| {
                serde_json::json!([{
                    "seq": e.seq, "t_ref_ns": e.t_ref_ns, "offset_s": e.offset_s,
                    "drift": e.drift, "offset_std_s": e.offset_std_s, "drift_std": e.drift_std,
                    "state": e.state.name(), "polarity": e.polarity.name(),
                    "peak_score": e.peak_score, "peak_ratio": e.peak_ratio,
                    "measured_offset_s": e.measured_offset_s, "publish_ns": 1,
                }, t_cam])
            })
            .collect(),
    );
    let code = "import json, sys\n\
        sys.path.insert(0, sys.argv[1])\n\
        import vlsync_subscriber as v\n\
        for e, t_cam in json.loads(sys.argv[2]):\n    \
            t_lidar, std = v.camera_to_lidar(e, t_cam)\n    \
            print(t_lidar, repr(std))\n";
    let out = python_snippet(&script, code, &[&input.to_string()]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows: Vec<&str> = stdout.lines().collect();
    assert_eq!(rows.len(), cases.len(), "{stdout}");
    for ((e, t_cam), row) in cases.iter().zip(rows) {
        let (t_lidar, std) = row.split_once(' ').unwrap_or_else(|| panic!("{row}"));
        let (t_lidar, std): (i64, f64) = (t_lidar.parse().unwrap(), std.parse().unwrap());
        let walk = if e.state == EstimatorState::Tracking {
            walks.offset_process_noise
        } else {
            walks.hold_process_noise
        };
        let want_t = e.camera_to_lidar(*t_cam);
        let want_std = e.offset_std_with_walk(want_t, walk);
        assert_eq!(
            (t_lidar, std.to_bits()),
            (want_t, want_std.to_bits()),
            "{:?} at {t_cam}: Python {t_lidar} ± {std}, Rust {want_t} ± {want_std}",
            e.state
        );
        // the drift and the grown σ matter here: a conversion with the offset at
        // t_ref alone, or the σ at t_ref, would fail the comparison above
        assert_ne!(want_t, t_cam + vlsync_common::secs_to_nanos(e.offset_s));
        assert!(want_std > 1.01 * e.offset_std_s, "{want_std}");
    }
}

/// The layout guard is a check of its own, not an `assert` (`python3 -O` strips
/// those; and its exit status 1 was a timeout's): an `OffsetEstimate` with two fields
/// swapped exits 3, each difference named, before any service is opened.
#[test]
fn python_layout_guard_names_the_mismatch_and_exits_3() {
    let Some(script) = subscriber_or_skip("python_layout_guard_names_the_mismatch_and_exits_3")
    else {
        return;
    };
    let code = "import ctypes, sys\n\
        sys.path.insert(0, sys.argv[1])\n\
        import vlsync_subscriber as v\n\
        fields = list(v.OffsetEstimate._fields_)\n\
        fields[2], fields[3] = fields[3], fields[2]\n\
        class Swapped(ctypes.Structure):\n    \
            _fields_ = fields\n\
        v.OffsetEstimate = Swapped\n\
        sys.argv = ['vlsync_subscriber.py', '--prefix', 'vlsync-it/never-opened']\n\
        sys.exit(v.main())\n";
    let out = python_snippet(&script, code, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    for said in [
        "OffsetEstimate differs from the Rust layout: field 2: drift (c_double) at 16, expected offset_s (c_double) at 16",
        "field 3: offset_s (c_double) at 24, expected drift (c_double) at 24",
    ] {
        assert!(stderr.contains(said), "{said:?} not in {stderr}");
    }
    assert!(!stderr.contains("Traceback"), "{stderr}");
}
