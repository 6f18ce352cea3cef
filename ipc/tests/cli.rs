//! `vlsync-echo` describes itself and refuses a bad command line (exit code 2)
//! naming what was wrong. (This file also makes `cargo test` build it, which
//! the multi-process tests in `tests/` then run.)

use std::process::Command;

#[test]
fn echo_has_help_and_rejects_an_unknown_argument() {
    let bin = env!("CARGO_BIN_EXE_vlsync-echo");
    let out = Command::new(bin).arg("--help").output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(
        help.contains("--prefix") && help.contains("--json") && help.contains("--status"),
        "{help}"
    );
    let out = Command::new(bin).arg("--bogus").output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--bogus"));
    // a prefix no service can be named with is a bad argument too, named once
    let out = Command::new(bin)
        .args(["--prefix", "bad!!"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.starts_with(
            "vlsync-echo: error: service prefix (--prefix): `services.prefix` = \"bad!!\" is invalid"
        ),
        "{err}"
    );
}

/// The state letter of process `pid` (`R`, `S`, `T` stopped, ...) from /proc.
fn proc_state(pid: &str) -> Option<char> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // "pid (comm) S ...": the state follows the last ')'
    stat.rsplit_once(')')?.1.trim_start().chars().next()
}

/// Whether process `pid` has a handler on SIGINT (`SigCgt` of its status).
fn catches_sigint(pid: &str) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|st| {
            st.lines()
                .find_map(|l| l.strip_prefix("SigCgt:"))
                .and_then(|h| u64::from_str_radix(h.trim(), 16).ok())
        })
        .is_some_and(|mask| mask & (1 << (2 - 1)) != 0)
}

/// A child process stopped when dropped, so that a failing assertion leaves no echo
/// behind: resumed (it may be stopped) and interrupted, which ends it cleanly with its
/// iceoryx2 resources removed, else killed after 5 s; reaped either way.
struct Stopped(std::process::Child);

impl Drop for Stopped {
    fn drop(&mut self) {
        use rustix::process::{kill_process, Pid, Signal};
        use std::time::{Duration, Instant};
        if let (Ok(None), Some(pid)) = (
            self.0.try_wait(),
            i32::try_from(self.0.id()).ok().and_then(Pid::from_raw),
        ) {
            let _ = kill_process(pid, Signal::CONT);
            let _ = kill_process(pid, Signal::INT);
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(5) {
                if let Ok(Some(_)) = self.0.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Job control works on the echo: Ctrl-Z (SIGTSTP) stops it and SIGCONT resumes
/// it, and it goes on waiting. iceoryx2's handlers used to catch both: SIGTSTP did
/// not stop it, and the interrupted wait ended it with exit 1 ("wait on offset
/// event: InterruptSignal"). SIGINT then ends it with 0.
#[test]
fn echo_survives_job_control_and_stops_on_sigint() {
    use std::io::Read;
    use std::time::{Duration, Instant};
    use vlsync_common::wire::OffsetEstimate;
    use vlsync_ipc::iceoryx2::service::port_factory::PortFactory as _;
    use vlsync_ipc::{create_node, open_or_create_pubsub, Qos, ServiceNames};
    let bin = env!("CARGO_BIN_EXE_vlsync-echo");
    let names = ServiceNames::new(&format!("vlsync-test/echo-sig-{}", std::process::id())).unwrap();
    // the offset service, to see the echo's subscriber on it
    let node = create_node("test-observer", false).unwrap();
    let svc =
        open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest()).unwrap();
    // its own process group, whose parent (this test) is in the same session: the
    // kernel ignores SIGTSTP in an orphaned group, which the test binary's may be
    // under a CI runner without job control; stopped when dropped, and ending by itself
    // within a minute whatever happens to this test
    use std::os::unix::process::CommandExt;
    let mut child = Stopped(
        Command::new(bin)
            .args(["--prefix", &names.prefix, "--duration", "60"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .process_group(0)
            .spawn()
            .unwrap(),
    );
    let pid = child.0.id().to_string();
    // kill(2) itself: procps's `kill` is not on every minimal system
    let kill = |sig: &str| {
        use rustix::process::{kill_process, Pid, Signal};
        let signal = match sig {
            "-TSTP" => Signal::TSTP,
            "-CONT" => Signal::CONT,
            "-INT" => Signal::INT,
            other => panic!("no signal {other}"),
        };
        let raw = Pid::from_raw(pid.parse().unwrap()).unwrap();
        kill_process(raw, signal).unwrap_or_else(|e| panic!("kill {sig} {pid}: {e}"));
    };
    let wait_state = |want: char| {
        let t0 = Instant::now();
        while proc_state(&pid) != Some(want) && t0.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(10));
        }
        proc_state(&pid)
    };
    let stderr = |child: &mut Stopped| {
        let mut text = String::new();
        if let Some(mut e) = child.0.stderr.take() {
            let _ = e.read_to_string(&mut text);
        }
        text
    };
    // its own SIGINT handler is installed first thing, then the iceoryx2 nodes (whose
    // set-up used to take over SIGTSTP), then its subscriber: a SIGTSTP before them
    // would prove nothing, and a loaded machine's start-up may outlast a fixed wait
    let t0 = Instant::now();
    while svc.dynamic_config().number_of_subscribers() == 0 {
        if let Some(st) = child.0.try_wait().unwrap() {
            panic!(
                "the echo ended at its start: {st:?}, stderr: {}",
                stderr(&mut child)
            );
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "vlsync-echo never subscribed"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(catches_sigint(&pid), "no SIGINT handler once subscribed");
    kill("-TSTP");
    let stopped = wait_state('T');
    kill("-CONT");
    std::thread::sleep(Duration::from_millis(300));
    if let Some(st) = child.0.try_wait().unwrap() {
        panic!(
            "the echo ended on SIGTSTP/SIGCONT: {st:?}, stderr: {}",
            stderr(&mut child)
        );
    }
    assert_eq!(stopped, Some('T'), "SIGTSTP did not stop the echo");
    kill("-INT");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.0.try_wait().unwrap() {
            break s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "no exit after SIGINT"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(0), "stderr: {}", stderr(&mut child));
}

/// A publisher of estimates on a prefix of its own (`tag`), standing in for the
/// daemon, and a `vlsync-echo` with `args` subscribed to it.
struct FakeDaemon {
    prefix: String,
    publ: vlsync_ipc::iceoryx2::port::publisher::Publisher<
        vlsync_ipc::Svc,
        vlsync_common::wire::OffsetEstimate,
        (),
    >,
    noti: vlsync_ipc::iceoryx2::port::notifier::Notifier<vlsync_ipc::Svc>,
    _node: vlsync_ipc::iceoryx2::node::Node<vlsync_ipc::Svc>,
}

impl FakeDaemon {
    /// The publisher, and an echo run with `args` once it has subscribed.
    fn with_echo(tag: &str, args: &[&str]) -> (Self, Stopped) {
        use vlsync_common::wire::OffsetEstimate;
        use vlsync_ipc::iceoryx2::service::port_factory::PortFactory as _;
        use vlsync_ipc::{
            create_node, notifier, open_or_create_event, open_or_create_pubsub, publisher, Qos,
            ServiceNames,
        };
        let names = ServiceNames::new(&format!("vlsync-it/{tag}-{}", std::process::id())).unwrap();
        let node = create_node("test-publisher", false).unwrap();
        let svc =
            open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest()).unwrap();
        let ev = open_or_create_event(&node, &names.offset()).unwrap();
        let (publ, noti) = (
            publisher(&svc, "offset").unwrap(),
            notifier(&ev, "offset").unwrap(),
        );
        // stopped when dropped: a test failing before it ends leaves no echo behind
        let echo = Stopped(
            Command::new(env!("CARGO_BIN_EXE_vlsync-echo"))
                .args(["--prefix", &names.prefix])
                .args(args)
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap(),
        );
        let t0 = std::time::Instant::now();
        while svc.dynamic_config().number_of_subscribers() == 0 {
            assert!(t0.elapsed().as_secs() < 15, "vlsync-echo never subscribed");
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        let prefix = names.prefix.clone();
        (
            Self {
                prefix,
                publ,
                noti,
                _node: node,
            },
            echo,
        )
    }
}

/// A tracking estimate numbered `seq`, at `seq` half-seconds.
fn estimate(seq: u64) -> vlsync_common::Estimate {
    use vlsync_common::{Estimate, EstimatorState, Polarity};
    Estimate {
        seq,
        t_ref_ns: seq as i64 * 500_000_000,
        offset_s: 0.02,
        drift: 0.0,
        offset_std_s: 0.001,
        drift_std: 0.0,
        state: EstimatorState::Tracking,
        polarity: Polarity::Positive,
        peak_score: 0.8,
        peak_ratio: 2.0,
        measured_offset_s: 0.02,
    }
}

/// The echo's exit, its stdout and stderr; it must have succeeded. (Its pipes are read
/// to their end, both at once, then it is reaped; a failure drops it, stopped.)
fn finished(mut echo: Stopped) -> (String, String) {
    use std::io::Read;
    let err = echo.0.stderr.take().map(|mut e| {
        std::thread::spawn(move || {
            let mut text = Vec::new();
            let _ = e.read_to_end(&mut text);
            text
        })
    });
    let mut out = Vec::new();
    if let Some(mut o) = echo.0.stdout.take() {
        let _ = o.read_to_end(&mut out);
    }
    let err = err.and_then(|t| t.join().ok()).unwrap_or_default();
    let status = echo.0.wait().unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out).into_owned(),
        String::from_utf8_lossy(&err).into_owned(),
    );
    assert!(status.success(), "{stdout}\n{stderr}");
    (stdout, stderr)
}

/// An estimate payload the client refuses is not printed but said on stderr, with
/// the count (a hostile or mismatched second publisher on the offset service).
#[test]
fn echo_says_when_it_skips_invalid_estimates() {
    use vlsync_common::wire::OffsetEstimate;
    let (d, echo) = FakeDaemon::with_echo("echoinvalid", &["--count", "1", "--duration", "20"]);
    // a payload with an unknown state, then a good estimate
    let e = estimate(3);
    let mut bad = OffsetEstimate::from_estimate(&e, 1).unwrap();
    bad.state = 77;
    d.publ.send_copy(bad).unwrap();
    d.publ
        .send_copy(OffsetEstimate::from_estimate(&e, 2).unwrap())
        .unwrap();
    d.noti.notify().unwrap();
    let (stdout, stderr) = finished(echo);
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    assert!(stdout.contains("tracking"), "{stdout}");
    assert!(
        stderr.contains(&format!(
            "vlsync-echo: skipped 1 invalid estimate payload(s) on `{}/offset` (1 in all)",
            d.prefix
        )),
        "{stderr}"
    );
}

/// Estimates that arrive together (a reader stopped by Ctrl-Z, a slow pipe) are all
/// printed, in order, one line each, and `--count` counts them; estimates lost before
/// the echo read them are said on stderr (it used to print only the newest of those
/// pending, silently).
#[test]
fn echo_prints_every_pending_estimate_in_order() {
    use vlsync_common::wire::OffsetEstimate;
    let (d, echo) =
        FakeDaemon::with_echo("echoall", &["--json", "--count", "5", "--duration", "10"]);
    // five estimates at once, one missing between them (#4), then one wake-up
    for seq in [1u64, 2, 3, 5, 6] {
        d.publ
            .send_copy(OffsetEstimate::from_estimate(&estimate(seq), seq as i64).unwrap())
            .unwrap();
    }
    d.noti.notify().unwrap();
    let (stdout, stderr) = finished(echo);
    let seqs: Vec<u64> = stdout
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["seq"]
                .as_u64()
                .unwrap()
        })
        .collect();
    assert_eq!(seqs, [1, 2, 3, 5, 6], "{stdout}\n{stderr}");
    assert!(
        stderr.contains("vlsync-echo: 1 estimate(s) missed before #5"),
        "{stderr}"
    );
}
