//! Child processes of the demo and the latency benchmark: locating the sibling
//! binaries, stopping them gracefully, and reading their CPU time and memory
//! from `/proc`.

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Finds binary `name` next to the running executable (also one directory up,
/// for test executables living in `target/<profile>/deps`).
pub fn sibling_binary(name: &str) -> Result<PathBuf, String> {
    let exe = std::env::current_exe().map_err(|e| format!("cannot locate own executable: {e}"))?;
    let dir = exe
        .parent()
        .ok_or_else(|| format!("executable {} has no directory", exe.display()))?;
    for d in [Some(dir), dir.parent()].into_iter().flatten() {
        let p = d.join(name);
        if p.is_file() {
            return Ok(p);
        }
    }
    Err(format!(
        "binary `{name}` not found next to {} (build the workspace binaries: cargo build --bins)",
        exe.display()
    ))
}

/// A child process that is stopped (SIGINT, SIGTERM halfway through a grace
/// period, SIGKILL at its end) when dropped.
pub struct Managed {
    /// Display name.
    pub name: String,
    /// The child.
    pub child: Child,
}

impl Managed {
    /// Spawns `program args`, stdout/stderr to `log` (or inherited when `None`).
    pub fn spawn(
        name: &str,
        program: &Path,
        args: &[String],
        log: Option<&Path>,
    ) -> Result<Self, String> {
        let mut cmd = Command::new(program);
        // a vlsync child stops if this process dies without stopping it (the
        // kernel's parent-death signal, asked for by the child; it follows the
        // thread that spawned it, so the launchers spawn from their main thread)
        // In a process group of its own: a terminal's Ctrl-C (or SIGHUP) reaches
        // the launcher alone, which stops its children in order (the drivers, a last
        // status, the recorder once it has the last estimates, then the daemon);
        // sent to the whole group, they all stopped at once and a recording lost
        // its last estimates.
        cmd.args(args).stdin(Stdio::null()).process_group(0).env(
            vlsync_ipc::STOP_WITH_PARENT_ENV,
            std::process::id().to_string(),
        );
        if let Some(log) = log {
            let f = std::fs::File::create(log)
                .map_err(|e| format!("cannot create log {}: {e}", log.display()))?;
            let f2 = f
                .try_clone()
                .map_err(|e| format!("cannot duplicate log handle {}: {e}", log.display()))?;
            cmd.stdout(f).stderr(f2);
        }
        let child = cmd
            .spawn()
            .map_err(|e| format!("cannot start {name} ({}): {e}", program.display()))?;
        Ok(Self {
            name: name.to_string(),
            child,
        })
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// True while the process runs.
    pub fn running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    /// Waits up to `within` until the file `log` (this process's log) contains
    /// `needle`, e.g. the daemon's "serving prefix": `Ok(true)` when it does,
    /// `Ok(false)` when the time passed with the process still running, `Err` with
    /// the log's text when the process exited first.
    pub fn wait_for_log(
        &mut self,
        log: &Path,
        needle: &str,
        within: Duration,
    ) -> Result<bool, String> {
        let t0 = Instant::now();
        loop {
            let text = std::fs::read_to_string(log).unwrap_or_default();
            if text.contains(needle) {
                return Ok(true);
            }
            if !self.running() {
                return Err(text);
            }
            if t0.elapsed() >= within {
                return Ok(false);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Sends `signal` (by name: "INT", "TERM", "KILL", "STOP", "CONT", "HUP",
    /// "USR1", "USR2") with kill(2), no process forked (a `kill` process on loaded
    /// cores would shift a stall the load harness times). A process that has ended is
    /// an error naming how, and is not signalled: its pid, once reaped, may be
    /// another process's.
    pub fn signal(&mut self, signal: &str) -> Result<(), String> {
        if let Ok(Some(st)) = self.child.try_wait() {
            return Err(format!(
                "cannot send SIG{signal} to {}: it has ended ({})",
                self.name,
                describe_exit(st)
            ));
        }
        send_signal(self.pid(), signal).map_err(|e| format!("{}: {e}", self.name))
    }

    /// SIGINT; SIGTERM after half of `grace`; SIGKILL after all of it. Returns true
    /// on a clean exit.
    ///
    /// SIGTERM matters when the harness itself was started in the background by a
    /// non-interactive shell (`cmd &`, `nohup`): its children then inherit SIGINT
    /// ignored, and a child that installs no handler of its own would otherwise
    /// only ever stop by SIGKILL.
    ///
    /// A process that had already exited is clean only if it exited with success: one
    /// that failed or was killed on its own (a crash, someone's `kill -9`) is not.
    pub fn stop(&mut self, grace: Duration) -> bool {
        if let Ok(Some(st)) = self.child.try_wait() {
            return st.success();
        }
        let _ = self.signal("INT");
        if let Some(st) = self.wait_up_to(grace / 2) {
            return st.success();
        }
        let _ = self.signal("TERM");
        if let Some(st) = self.wait_up_to(grace - grace / 2) {
            return st.success();
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        false
    }

    /// How the process ended, when it ended on its own with a failure (`None`: still
    /// running, or exited with success): "exit status 3", "killed by signal 9 (SIGKILL)".
    pub fn failure(&mut self) -> Option<String> {
        self.failed_status().map(describe_exit)
    }

    /// The exit status, when the process ended with a failure ([`Managed::failure`]).
    pub fn failed_status(&mut self) -> Option<std::process::ExitStatus> {
        match self.child.try_wait() {
            Ok(Some(st)) if !st.success() => Some(st),
            _ => None,
        }
    }

    /// The exit status, once the process exited within `limit` (`None`: it still runs).
    pub fn wait_up_to(&mut self, limit: Duration) -> Option<std::process::ExitStatus> {
        let t0 = Instant::now();
        loop {
            if let Ok(Some(st)) = self.child.try_wait() {
                return Some(st);
            }
            if t0.elapsed() >= limit {
                return None;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Managed {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(3));
    }
}

/// "exit status 3", "killed by signal 9 (SIGKILL)".
pub fn describe_exit(st: std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (st.code(), st.signal()) {
        (Some(c), _) => format!("exit status {c}"),
        (None, Some(sig)) => {
            let name = match sig {
                2 => " (SIGINT)",
                6 => " (SIGABRT)",
                9 => " (SIGKILL)",
                11 => " (SIGSEGV)",
                15 => " (SIGTERM)",
                _ => "",
            };
            format!("killed by signal {sig}{name}")
        }
        (None, None) => format!("{st}"),
    }
}

/// CPU time (user + system) of process `pid`, seconds, from `/proc/<pid>/stat`.
pub fn cpu_seconds(pid: u32) -> Result<f64, String> {
    let path = format!("/proc/{pid}/stat");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{path}: {e}"))?;
    let ticks = stat_field(&text, 14, "utime", &path)? + stat_field(&text, 15, "stime", &path)?;
    Ok(ticks as f64 / CLOCK_TICKS_PER_SEC)
}

/// Field `n` (1-based, as proc(5) numbers them) of a `/proc/.../stat` line, named
/// `name` in errors about file `what`. The command name (field 2) may contain spaces
/// and ')': the fields are counted after the last ')'.
fn stat_field(text: &str, n: usize, name: &str, what: &str) -> Result<u64, String> {
    let rest = text
        .rfind(')')
        .map(|i| &text[i + 1..])
        .ok_or_else(|| format!("{what}: no ')' in the stat line"))?;
    // after ')' the state is field 3: field n is the (n - 3)th
    n.checked_sub(3)
        .and_then(|i| rest.split_whitespace().nth(i))
        .and_then(|v| v.parse::<u64>().ok())
        .ok_or_else(|| format!("{what}: cannot read {name} (field {n})"))
}

/// `sysconf(_SC_CLK_TCK)`: 100 on every Linux architecture vlsync targets.
const CLOCK_TICKS_PER_SEC: f64 = 100.0;

/// Resident memory of `pid`, kB, from `VmRSS` in `/proc/<pid>/status`.
pub fn rss_kb(pid: u32) -> Result<u64, String> {
    let path = format!("/proc/{pid}/status");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{path}: {e}"))?;
    text.lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .ok_or_else(|| format!("{path}: no VmRSS line"))
}

/// Scheduling of one thread as the kernel reports it (`/proc/<pid>/task/<tid>/stat`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ThreadSched {
    /// Scheduling policy (`SCHED_OTHER` 0, `SCHED_FIFO` 1, `SCHED_RR` 2, ...).
    pub policy: u32,
    /// Real-time priority (1..=99 under `SCHED_FIFO` / `SCHED_RR`, else 0).
    pub rt_priority: u32,
    /// The CPU it last ran on.
    pub cpu: u32,
    /// The one core it may run on, when its affinity allows only one (`None`: more,
    /// or unknown).
    pub pinned: Option<u32>,
}

impl ThreadSched {
    /// `SCHED_FIFO`.
    pub const FIFO: u32 = 1;

    /// "SCHED_FIFO priority 50, pinned to core 1" / "the normal scheduler (SCHED_OTHER),
    /// not pinned (last on core 0)".
    pub fn describe(&self) -> String {
        let policy = match self.policy {
            0 => "the normal scheduler (SCHED_OTHER)".to_string(),
            1 => format!("SCHED_FIFO priority {}", self.rt_priority),
            2 => format!("SCHED_RR priority {}", self.rt_priority),
            3 => "SCHED_BATCH".to_string(),
            5 => "SCHED_IDLE".to_string(),
            6 => "SCHED_DEADLINE".to_string(),
            p => format!("scheduling policy {p}"),
        };
        match self.pinned {
            Some(c) => format!("{policy}, pinned to core {c}"),
            None => format!("{policy}, not pinned (last on core {})", self.cpu),
        }
    }
}

/// The single core of a `Cpus_allowed_list:` line of `/proc/<pid>/task/<tid>/status`
/// (`None` for a list of several, such as `0-3` or `0,2`, or no such line).
pub fn parse_pinned(status: &str) -> Option<u32> {
    let list = status
        .lines()
        .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))?
        .trim();
    list.parse().ok()
}

/// Parses a `/proc/<pid>/task/<tid>/stat` line: the CPU it last ran on (field 39),
/// its real-time priority (40) and policy (41). `what` names the file in errors.
pub fn parse_thread_sched(text: &str, what: &str) -> Result<ThreadSched, String> {
    let get = |n: usize, name: &str| -> Result<u32, String> {
        let v = stat_field(text, n, name, what)?;
        u32::try_from(v).map_err(|_| format!("{what}: {name} (field {n}) is {v}"))
    };
    Ok(ThreadSched {
        cpu: get(39, "processor")?,
        rt_priority: get(40, "rt_priority")?,
        policy: get(41, "policy")?,
        pinned: None,
    })
}

/// The scheduling of the thread named `name` (its `comm`) in process `pid`; `None`
/// when the process has no such thread.
pub fn thread_sched(pid: u32, name: &str) -> Result<Option<ThreadSched>, String> {
    let dir = format!("/proc/{pid}/task");
    let tasks = std::fs::read_dir(&dir).map_err(|e| format!("{dir}: {e}"))?;
    for t in tasks.flatten() {
        let comm = std::fs::read_to_string(t.path().join("comm")).unwrap_or_default();
        if comm.trim_end_matches('\n') != name {
            continue;
        }
        let path = t.path().join("stat");
        let what = path.display().to_string();
        let text = std::fs::read_to_string(&path).map_err(|e| format!("{what}: {e}"))?;
        let status = std::fs::read_to_string(t.path().join("status")).unwrap_or_default();
        return parse_thread_sched(&text, &what).map(|ts| {
            Some(ThreadSched {
                pinned: parse_pinned(&status),
                ..ts
            })
        });
    }
    Ok(None)
}

/// A report's account of the daemon's real-time thread: what the kernel gave it
/// (`got`, from [`thread_sched`]), and what of the daemon's settings it refused: the
/// SCHED_FIFO priority (`fifo`, 0: none asked) and the core (`core`, -1: none asked);
/// `log` is the daemon's log, which says why.
pub fn describe_rt_thread(
    got: &Result<Option<ThreadSched>, String>,
    fifo: i64,
    core: i64,
    log: &Path,
) -> String {
    match got {
        Ok(Some(t)) => {
            let mut refused = vec![];
            if fifo > 0 && t.policy != ThreadSched::FIFO {
                refused.push(format!("SCHED_FIFO priority {fifo}"));
            }
            if core >= 0 && t.pinned.map(i64::from) != Some(core) {
                refused.push(format!("pinning to core {core}"));
            }
            if refused.is_empty() {
                t.describe()
            } else {
                format!(
                    "{} ({} refused: {} says why)",
                    t.describe(),
                    refused.join(" and "),
                    log.display()
                )
            }
        }
        Ok(None) => "not found (no thread named vlsync-rt while the daemon served)".into(),
        Err(e) => format!("unknown ({e})"),
    }
}

/// Files in `/dev/shm` and iceoryx2's directory (`/tmp/iceoryx2`), sorted: what a
/// clean shutdown must leave as it found it. iceoryx2's global management
/// segment (`*.global_mgmt`) is left out: iceoryx2 creates it with the first
/// node on the machine and keeps it by design (it holds no service).
pub fn ipc_resources() -> Vec<String> {
    files_under(&[Path::new("/dev/shm"), Path::new("/tmp/iceoryx2")])
}

/// Every entry under `dirs` that is not a directory (a symbolic link is listed, never
/// followed: two links to `.` in `/dev/shm` made the walk explore 2^40 paths), but
/// iceoryx2's `*.global_mgmt`, sorted.
fn files_under(dirs: &[&Path]) -> Vec<String> {
    let mut out = vec![];
    for dir in dirs {
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            if let Ok(rd) = std::fs::read_dir(&d) {
                for e in rd.flatten() {
                    let p = e.path();
                    if e.file_type().is_ok_and(|t| t.is_dir()) {
                        stack.push(p);
                    } else if !p.to_string_lossy().ends_with(".global_mgmt") {
                        out.push(p.display().to_string());
                    }
                }
            }
        }
    }
    out.sort();
    out
}

/// Sends `signal` (by name: "INT", "TERM", "KILL", "STOP", "CONT", "HUP", "USR1",
/// "USR2") to process `pid` with kill(2): no `kill` program is needed (procps is
/// not on every minimal system) and no process is forked.
pub fn send_signal(pid: u32, signal: &str) -> Result<(), String> {
    use rustix::process::{kill_process, Pid, Signal};
    let sig = match signal {
        "INT" => Signal::INT,
        "TERM" => Signal::TERM,
        "KILL" => Signal::KILL,
        "STOP" => Signal::STOP,
        "CONT" => Signal::CONT,
        "HUP" => Signal::HUP,
        "USR1" => Signal::USR1,
        "USR2" => Signal::USR2,
        other => return Err(format!("no signal named {other:?}")),
    };
    let raw = i32::try_from(pid)
        .ok()
        .and_then(Pid::from_raw)
        .ok_or_else(|| format!("pid {pid} out of range"))?;
    kill_process(raw, sig).map_err(|e| format!("cannot send SIG{signal} to pid {pid}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Links are listed, not followed: a directory holding links to itself is walked
    /// once.
    #[test]
    fn the_resource_walk_follows_no_link() {
        let dir = std::env::temp_dir().join(format!("vlsync-walk-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(dir.join("sub/seg"), "").unwrap();
        std::fs::write(dir.join("x.global_mgmt"), "").unwrap();
        std::os::unix::fs::symlink(".", dir.join("self")).unwrap();
        std::os::unix::fs::symlink("..", dir.join("sub/up")).unwrap();
        let name = |n: &str| dir.join(n).display().to_string();
        assert_eq!(
            files_under(&[&dir]),
            [name("self"), name("sub/seg"), name("sub/up")]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn own_cpu_and_rss_are_readable() {
        let pid = std::process::id();
        // burn a little CPU so the counter moves
        let t0 = Instant::now();
        let mut x = 0u64;
        while t0.elapsed() < Duration::from_millis(50) {
            x = x.wrapping_add(1);
        }
        assert!(x > 0);
        assert!(cpu_seconds(pid).unwrap() > 0.0);
        assert!(rss_kb(pid).unwrap() > 100);
        assert!(cpu_seconds(u32::MAX).is_err());
    }

    #[test]
    fn a_thread_stat_line_gives_its_scheduling() {
        // a thread named with spaces and a ')' (fields from the last ')' on), SCHED_FIFO 50 on CPU 1
        let mut fields: Vec<String> = (3..=52).map(|n| n.to_string()).collect();
        fields[0] = "S".into();
        fields[39 - 3] = "1".into();
        fields[40 - 3] = "50".into();
        fields[41 - 3] = "1".into();
        let line = format!("1234 (a) b) {}\n", fields.join(" "));
        let s = parse_thread_sched(&line, "stat").unwrap();
        assert_eq!(
            s,
            ThreadSched {
                policy: ThreadSched::FIFO,
                rt_priority: 50,
                cpu: 1,
                pinned: None,
            }
        );
        assert_eq!(
            s.describe(),
            "SCHED_FIFO priority 50, not pinned (last on core 1)"
        );
        // the affinity from the status file
        let status = "Name:\tvlsync-rt\nCpus_allowed:\t2\nCpus_allowed_list:\t1\n";
        assert_eq!(parse_pinned(status), Some(1));
        assert_eq!(parse_pinned("Cpus_allowed_list:\t0-3\n"), None);
        assert_eq!(parse_pinned("Cpus_allowed_list:\t0,2\n"), None);
        assert_eq!(parse_pinned(""), None);
        // a line cut short names the field it lacks
        let short = format!("1234 (x) {}", fields[..37].join(" "));
        let e = parse_thread_sched(&short, "/proc/1/task/1/stat").unwrap_err();
        assert!(
            e.contains("/proc/1/task/1/stat") && e.contains("field 40"),
            "{e}"
        );
        assert!(parse_thread_sched("no paren", "stat").is_err());
    }

    #[test]
    fn this_threads_scheduling_is_readable() {
        let name = "vlsync-schedtst";
        let got = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || thread_sched(std::process::id(), name))
            .unwrap()
            .join()
            .unwrap()
            .unwrap()
            .expect("the thread is listed under its name");
        assert_eq!(got.policy, 0, "test threads run under the normal scheduler");
        assert_eq!(got.rt_priority, 0);
        // the thread inherits this process's affinity
        let own = std::fs::read_to_string("/proc/self/status").unwrap();
        assert_eq!(got.pinned, parse_pinned(&own), "{got:?}");
        assert_eq!(thread_sched(std::process::id(), "no-such-thread"), Ok(None));
        assert!(thread_sched(u32::MAX, name).is_err());
    }

    proptest::proptest! {
        /// Any text read from /proc (or elsewhere) gives a value or an error, never a panic.
        #[test]
        fn any_stat_text_parses_or_errs(text in ".{0,400}") {
            let _ = parse_thread_sched(&text, "stat");
            let _ = parse_pinned(&text);
        }
    }

    #[test]
    fn the_summary_says_what_scheduling_the_daemon_got() {
        let log = Path::new("/tmp/x/vlsyncd.log");
        let t = |policy, rt_priority, pinned| {
            Ok(Some(ThreadSched {
                policy,
                rt_priority,
                cpu: 1,
                pinned,
            }))
        };
        assert_eq!(
            describe_rt_thread(&t(1, 50, Some(1)), 50, 1, log),
            "SCHED_FIFO priority 50, pinned to core 1"
        );
        let refused = describe_rt_thread(&t(0, 0, Some(1)), 50, 1, log);
        assert_eq!(
            refused,
            "the normal scheduler (SCHED_OTHER), pinned to core 1 (SCHED_FIFO priority 50 \
             refused: /tmp/x/vlsyncd.log says why)"
        );
        let unpinned = describe_rt_thread(&t(1, 50, None), 50, 1, log);
        assert_eq!(
            unpinned,
            "SCHED_FIFO priority 50, not pinned (last on core 1) (pinning to core 1 refused: \
             /tmp/x/vlsyncd.log says why)"
        );
        // asked for neither: nothing was refused
        assert_eq!(
            describe_rt_thread(&t(0, 0, None), 0, -1, log),
            "the normal scheduler (SCHED_OTHER), not pinned (last on core 1)"
        );
        assert!(describe_rt_thread(&Ok(None), 50, 1, log).starts_with("not found"));
        let gone = describe_rt_thread(&Err("/proc/1/task: gone".into()), 0, -1, log);
        assert!(gone.contains("/proc/1/task"), "{gone}");
    }

    #[test]
    fn a_child_that_failed_on_its_own_is_no_clean_stop() {
        let sh = Path::new("/bin/sh");
        let mut failed = Managed::spawn("sh", sh, &["-c".into(), "exit 3".into()], None).unwrap();
        let _ = failed.wait_up_to(Duration::from_secs(5));
        assert_eq!(failed.failure().as_deref(), Some("exit status 3"));
        assert!(!failed.stop(Duration::from_secs(1)));
        let mut killed =
            Managed::spawn("sh", sh, &["-c".into(), "kill -9 $$".into()], None).unwrap();
        let _ = killed.wait_up_to(Duration::from_secs(5));
        assert_eq!(
            killed.failure().as_deref(),
            Some("killed by signal 9 (SIGKILL)")
        );
        assert!(!killed.stop(Duration::from_secs(1)));
        let mut done = Managed::spawn("sh", sh, &["-c".into(), "exit 0".into()], None).unwrap();
        let _ = done.wait_up_to(Duration::from_secs(5));
        assert_eq!(done.failure(), None);
        assert!(
            done.stop(Duration::from_secs(1)),
            "ended by itself with success"
        );
    }

    /// The signal that ended the (stopped) child.
    fn ended_by(m: &mut Managed) -> Option<i32> {
        use std::os::unix::process::ExitStatusExt;
        m.child.try_wait().ok().flatten().and_then(|st| st.signal())
    }

    #[test]
    fn managed_child_is_stopped_gracefully() {
        // `sleep` installs no handler: SIGINT ends it, unless this test runs under a
        // shell that started it in the background (SIGINT ignored), where SIGTERM does
        let mut m = Managed::spawn("sleep", Path::new("sleep"), &["30".into()], None).unwrap();
        assert!(m.running());
        assert!(
            !m.stop(Duration::from_secs(4)),
            "killed by a signal: no clean exit"
        );
        assert!(!m.running());
        let sig = ended_by(&mut m);
        assert!(
            sig == Some(2) || sig == Some(15),
            "ended by {sig:?}, not SIGINT/SIGTERM"
        );
        assert!(sibling_binary("definitely-not-a-binary")
            .unwrap_err()
            .contains("not found"));
    }

    #[test]
    fn a_child_has_a_process_group_of_its_own() {
        let mut m = Managed::spawn("sleep", Path::new("sleep"), &["30".into()], None).unwrap();
        let stat = std::fs::read_to_string(format!("/proc/{}/stat", m.pid())).unwrap();
        // pid (comm) state ppid pgrp ...
        let pgrp: u32 = stat
            .rsplit(") ")
            .next()
            .and_then(|r| r.split(' ').nth(2))
            .and_then(|g| g.parse().ok())
            .unwrap();
        assert_eq!(pgrp, m.pid(), "{stat}");
        m.stop(Duration::from_secs(4));
    }

    #[test]
    fn a_child_ignoring_sigint_is_stopped_by_sigterm_not_sigkill() {
        // what every child of a harness started with `nohup ... &` looks like
        let args = ["-c".to_string(), "trap '' INT; exec sleep 30".to_string()];
        let mut m = Managed::spawn("sleep", Path::new("sh"), &args, None).unwrap();
        // until the trap is set, SIGINT would still end it: wait for the exec
        let t0 = Instant::now();
        while std::fs::read_to_string(format!("/proc/{}/comm", m.pid()))
            .is_ok_and(|c| c.trim() != "sleep")
            && t0.elapsed() < Duration::from_secs(10)
        {
            std::thread::sleep(Duration::from_millis(5));
        }
        m.stop(Duration::from_secs(4));
        assert!(!m.running());
        assert_eq!(ended_by(&mut m), Some(15));
    }
}
