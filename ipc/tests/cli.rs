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

/// Job control works on the echo: Ctrl-Z (SIGTSTP) stops it and SIGCONT resumes
/// it, and it goes on waiting. iceoryx2's handlers used to catch both: SIGTSTP did
/// not stop it, and the interrupted wait ended it with exit 1 ("wait on offset
/// event: InterruptSignal"). SIGINT then ends it with 0.
#[test]
fn echo_survives_job_control_and_stops_on_sigint() {
    use std::time::{Duration, Instant};
    let bin = env!("CARGO_BIN_EXE_vlsync-echo");
    let prefix = format!("vlsync-test/echo-sig-{}", std::process::id());
    // its own process group, whose parent (this test) is in the same session: the
    // kernel ignores SIGTSTP in an orphaned group, which the test binary's may be
    // under a CI runner without job control
    use std::os::unix::process::CommandExt;
    let mut child = Command::new(bin)
        .args(["--prefix", &prefix])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .process_group(0)
        .spawn()
        .unwrap();
    let pid = child.id().to_string();
    let kill = |sig: &str| {
        let ok = Command::new("kill")
            .args([sig, &pid])
            .status()
            .unwrap()
            .success();
        assert!(ok, "kill {sig} {pid}");
    };
    let wait_state = |want: char| {
        let t0 = Instant::now();
        while proc_state(&pid) != Some(want) && t0.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(10));
        }
        proc_state(&pid)
    };
    // its own SIGINT handler is installed first thing, then the iceoryx2 node (whose
    // set-up used to take over SIGTSTP); a loaded machine's start-up may outlast a
    // fixed wait, and a SIGTSTP before the node would prove nothing
    let t0 = Instant::now();
    while !catches_sigint(&pid) && t0.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    kill("-TSTP");
    let stopped = wait_state('T');
    kill("-CONT");
    std::thread::sleep(Duration::from_millis(300));
    if let Some(st) = child.try_wait().unwrap() {
        let out = child.wait_with_output().unwrap();
        panic!(
            "the echo ended on SIGTSTP/SIGCONT: {st:?}, stderr: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    assert_eq!(stopped, Some('T'), "SIGTSTP did not stop the echo");
    kill("-INT");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "no exit after SIGINT"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        status.code(),
        Some(0),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}
