//! Helpers of the multi-process integration tests: the workspace binaries
//! (built once per test run with the same profile as the tests), and a rig
//! that runs `vlsyncd run` and both drivers on a unique prefix.
#![forbid(unsafe_code)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::{Duration, Instant};
use vlsync_common::wire::Status;
use vlsync_common::{Estimate, Stream};
use vlsync_ipc::{monotonic_ns, OffsetClient, StatusClient};
pub use vlsyncd::runtime::procs::{cpu_seconds, Managed};

/// How iceoryx2 names its files in `/dev/shm`: its default `global.prefix`, which
/// vlsync does not change (`iox2_<hash>.dynamic`, `.event_mgmt`, `.data`, ...).
pub const ICEORYX2_SHM_PREFIX: &str = "iox2_";

/// The iceoryx2 resources a clean shutdown must leave as it found them: every file
/// under iceoryx2's directory (`/tmp/iceoryx2`) and its files in `/dev/shm`
/// ([`ICEORYX2_SHM_PREFIX`]), sorted, without the global management segment it keeps
/// by design (`vlsyncd::runtime::procs::ipc_resources`, narrowed). Another program's
/// shared memory coming or going in `/dev/shm` (a browser's, a database's) is none of
/// them and fails no test; another iceoryx2 program's (a second vlsync run) still is.
pub fn ipc_resources() -> Vec<String> {
    vlsyncd::runtime::procs::ipc_resources()
        .into_iter()
        .filter(|p| is_iceoryx2_resource(p))
        .collect()
}

/// Whether `path` (from [`ipc_resources`]'s walk) is iceoryx2's: in `/dev/shm` only
/// its prefixed files are.
fn is_iceoryx2_resource(path: &str) -> bool {
    let p = Path::new(path);
    if !p.starts_with("/dev/shm") {
        return true;
    }
    p.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with(ICEORYX2_SHM_PREFIX))
}

/// Asserts that no iceoryx2 resource beyond `before` ([`ipc_resources`]) is left,
/// after up to 3 s for the clean-up (iceoryx2 removes a service's files when its
/// last user is gone).
pub fn assert_nothing_left(before: &[String]) {
    let t0 = Instant::now();
    let mut after = ipc_resources();
    while after != before && t0.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(100));
        after = ipc_resources();
    }
    let leaked: Vec<_> = after.iter().filter(|p| !before.contains(p)).collect();
    assert!(leaked.is_empty(), "left behind: {leaked:?}");
}

/// `target/<profile>` of the running test executable.
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test>-<hash>
    exe.parent()
        .and_then(Path::parent)
        .expect("test executable lives in target/<profile>/deps")
        .to_path_buf()
}

/// Path of workspace binary `name`, building every vlsync binary once first
/// (with the features in `VLSYNC_CARGO_FEATURES` when set), unless
/// `VLSYNC_PREBUILT_BINS=1` says the test build made them (`scripts/test.sh`).
pub fn bin(name: &str) -> PathBuf {
    static BUILT: OnceLock<Result<(), String>> = OnceLock::new();
    let dir = profile_dir();
    let built = BUILT.get_or_init(|| {
        // `scripts/test.sh` runs `cargo test --workspace`, which builds every
        // binary of the workspace (each package has an integration test) before
        // any test runs: a second build would only compile the workspace again
        if std::env::var_os("VLSYNC_PREBUILT_BINS").is_some_and(|v| v == "1") {
            return Ok(());
        }
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let mut cmd = Command::new(cargo);
        cmd.current_dir(&workspace).args([
            "build",
            "--bins",
            "-p",
            "vlsyncd",
            "-p",
            "vlsync-ipc",
            "-p",
            "vlsync-driver",
            "-p",
            "vlsync-render",
        ]);
        if dir.file_name().is_some_and(|n| n == "release") {
            cmd.arg("--release");
        }
        if let Ok(f) = std::env::var("VLSYNC_CARGO_FEATURES") {
            if !f.trim().is_empty() {
                cmd.args(["--features", f.trim()]);
            }
        }
        // the binaries must land next to this test's profile directory
        if let Some(target) = dir.parent() {
            cmd.env("CARGO_TARGET_DIR", target);
        }
        match cmd.status() {
            Ok(s) if s.success() => Ok(()),
            Ok(s) => Err(format!("cargo build --bins failed: {s}")),
            Err(e) => Err(format!("cannot run cargo: {e}")),
        }
    });
    if let Err(e) = built {
        panic!("{e}");
    }
    let p = dir.join(name);
    assert!(
        p.is_file(),
        "binary {} missing{}",
        p.display(),
        if std::env::var_os("VLSYNC_PREBUILT_BINS").is_some_and(|v| v == "1") {
            " (VLSYNC_PREBUILT_BINS=1 skipped the build: run `cargo test --workspace`, or unset it)"
        } else {
            " after `cargo build --bins`"
        }
    );
    p
}

/// The directory holding `libvlsync_client.so` (the C client library) of this test
/// build: the tests depend on `vlsync-capi`, so building them built it into
/// `target/<profile>/deps` (a `cdylib` has no hash in its name); an explicit
/// `cargo build -p vlsync-capi` puts it one level up.
pub fn capi_lib_dir() -> PathBuf {
    let dir = profile_dir();
    for d in [dir.join("deps"), dir.clone()] {
        if d.join("libvlsync_client.so").is_file() {
            return d;
        }
    }
    panic!(
        "libvlsync_client.so is in neither {0}/deps nor {0}: build the tests with cargo (they depend on vlsync-capi)",
        dir.display()
    );
}

/// Compiles C (`cxx` false: `$CC`, else `cc`, C11) or C++ (`$CXX`, else `c++`, C++17)
/// source `src` into `exe` with every warning an error, headers from `include`, and
/// `extra` arguments after the source (libraries); fails the test with the compiler's
/// output.
pub fn compile(src: &Path, exe: &Path, cxx: bool, include: &Path, extra: &[String]) {
    let (var, default, std) = if cxx {
        ("CXX", "c++", "-std=c++17")
    } else {
        ("CC", "cc", "-std=c11")
    };
    let cc = std::env::var(var).unwrap_or_else(|_| default.into());
    let out = Command::new(&cc)
        .args([std, "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(include)
        .arg(src)
        .args(extra)
        .arg("-o")
        .arg(exe)
        .output()
        .unwrap_or_else(|e| panic!("compiler `{cc}` not runnable: {e}"));
    assert!(
        out.status.success(),
        "{} does not compile:\n{}",
        src.display(),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Longest wait of [`assert_serving`] for a daemon to serve.
pub const DAEMON_READY_WAIT: Duration = Duration::from_secs(20);

/// Waits up to [`DAEMON_READY_WAIT`] for the daemon `m` (log file `log`) to serve:
/// its "serving prefix" line, written once its subscribers exist; panics with its
/// log when it exits first or never serves.
pub fn assert_serving(m: &mut Managed, log: &Path) {
    match m.wait_for_log(log, "serving prefix", DAEMON_READY_WAIT) {
        Ok(true) => {}
        Ok(false) => panic!(
            "vlsyncd did not serve within {DAEMON_READY_WAIT:?}:\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        ),
        Err(text) => panic!("vlsyncd exited before it served:\n{text}"),
    }
}

/// Daemon + drivers on one prefix, with the simulated truth.
pub struct Rig {
    /// Unique prefix.
    pub prefix: String,
    /// Simulated family name.
    pub family: &'static str,
    /// Seed.
    pub seed: u64,
    /// Simulated seconds.
    pub duration: f64,
    /// Speed factor.
    pub speed: f64,
    /// Common driver start instant (CLOCK_MONOTONIC ns).
    pub start_at: i64,
    /// The run the drivers replay.
    pub sim: vlsync_sim::SimRun,
    /// Log directory.
    pub logs: PathBuf,
}

impl Rig {
    /// A rig for `family`/`seed`, `duration` simulated seconds at `speed`x.
    pub fn new(tag: &str, family: &'static str, seed: u64, duration: f64, speed: f64) -> Self {
        let prefix = format!("vlsync-it/{tag}-{}", std::process::id());
        let fam: vlsync_sim::Family = family.parse().expect("family");
        let logs = std::env::temp_dir().join(format!("vlsync-it-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&logs).expect("log dir");
        // build first: the common start instant must lie ahead of the drivers' start
        bin("vlsyncd");
        Self {
            prefix,
            family,
            seed,
            duration,
            speed,
            start_at: monotonic_ns() + 1_500_000_000,
            sim: vlsync_sim::generate(fam, seed, Some(duration)),
            logs,
        }
    }

    /// Starts `vlsyncd run` on the prefix (log file `vlsyncd-<n>.log`) and waits (up
    /// to [`DAEMON_READY_WAIT`]) until it serves: its log's "serving prefix" line,
    /// written once its subscribers exist. Signature services keep no history, so a
    /// sample published before that is lost; on a loaded machine a daemon's start-up
    /// can outlast the drivers' start lead, and waiting here makes that a clear
    /// failure instead of counts that come up short.
    pub fn daemon(&self, n: u32) -> Managed {
        self.spawn_daemon(n, &["run".into(), "--prefix".into(), self.prefix.clone()])
    }

    /// [`Rig::daemon`] with `[daemon]` keys of a configuration (written by
    /// [`write_daemon_config`] as `vlsync-<n>.toml` in the log directory: no pinning).
    pub fn daemon_with(&self, n: u32, daemon_keys: &str) -> Managed {
        let cfg = write_daemon_config(&self.logs, &self.prefix, daemon_keys);
        let own = self.logs.join(format!("vlsync-{n}.toml"));
        std::fs::rename(&cfg, &own).expect("name the daemon configuration");
        self.spawn_daemon(
            n,
            &["run".into(), "--config".into(), own.display().to_string()],
        )
    }

    fn spawn_daemon(&self, n: u32, args: &[String]) -> Managed {
        let log = self.logs.join(format!("vlsyncd-{n}.log"));
        let mut m =
            Managed::spawn("vlsyncd", &bin("vlsyncd"), args, Some(&log)).expect("spawn vlsyncd");
        assert_serving(&mut m, &log);
        if n == 0 && monotonic_ns() > self.start_at {
            eprintln!(
                "note: vlsyncd served {:.1} s after the drivers' start instant (a loaded machine): their first samples may be lost",
                (monotonic_ns() - self.start_at) as f64 * 1e-9
            );
        }
        m
    }

    /// Starts the driver of `stream` on the common schedule.
    pub fn driver(&self, stream: Stream, n: u32) -> Managed {
        self.session_driver(
            stream,
            self.seed,
            self.duration,
            self.start_at,
            &n.to_string(),
        )
    }

    /// Starts the driver of `stream` for a session of its own on the rig's prefix and
    /// speed: `seed`, `duration` simulated seconds from `start_at` (log file
    /// `vlsync-<stream>-<tag>.log`).
    pub fn session_driver(
        &self,
        stream: Stream,
        seed: u64,
        duration: f64,
        start_at: i64,
        tag: &str,
    ) -> Managed {
        let name = format!("vlsync-{stream}");
        let args: Vec<String> = vec![
            "--prefix".into(),
            self.prefix.clone(),
            "--sim".into(),
            self.family.into(),
            "--seed".into(),
            seed.to_string(),
            "--duration".into(),
            duration.to_string(),
            "--speed".into(),
            self.speed.to_string(),
            "--start-at".into(),
            start_at.to_string(),
        ];
        Managed::spawn(
            &name,
            &bin(&name),
            &args,
            Some(&self.logs.join(format!("{name}-{tag}.log"))),
        )
        .expect("spawn driver")
    }

    /// Simulated time the drivers are at now, ns (sensor clock, approximately).
    pub fn sim_now_ns(&self) -> i64 {
        let anchor = self.sim.cam[0].t_ns.min(self.sim.lidar[0].t_ns);
        anchor + ((monotonic_ns() - self.start_at) as f64 * self.speed) as i64
    }

    /// Wall time until the drivers finish, from now.
    pub fn remaining(&self) -> Duration {
        let end = self.start_at + (self.duration / self.speed * 1e9) as i64;
        Duration::from_nanos((end - monotonic_ns()).max(0) as u64)
    }

    /// Contents of a log file, for failure messages.
    pub fn log(&self, file: &str) -> String {
        std::fs::read_to_string(self.logs.join(file)).unwrap_or_default()
    }
}

impl Drop for Rig {
    /// A passing test leaves nothing in the temporary directory; a failing one
    /// keeps its processes' logs and says where.
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("logs kept in {}", self.logs.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.logs);
        }
    }
}

/// Says that `test` skipped its check for `reason` (a tool or a privilege this
/// machine lacks): on stderr, and as a line appended to the file `VLSYNC_SKIP_LOG`
/// names, which `scripts/test.sh` lists after its summary, since cargo counts a
/// skipped test as passed and hides a passing test's output.
pub fn skipped(test: &str, reason: &str) {
    eprintln!("SKIPPED {test}: {reason}");
    if let Some(path) = std::env::var_os("VLSYNC_SKIP_LOG") {
        use std::io::Write;
        let line = format!("{test}: {reason}\n");
        let _ = std::fs::OpenOptions::new()
            .append(true)
            .open(path)
            .and_then(|mut f| f.write_all(line.as_bytes()));
    }
}

/// Writes `dir/vlsync.toml`: a daemon on no fixed core serving `prefix`, with
/// `daemon_keys` (TOML lines) added to its `[daemon]` section. Returns its path.
pub fn write_daemon_config(dir: &Path, prefix: &str, daemon_keys: &str) -> PathBuf {
    let cfg = dir.join("vlsync.toml");
    std::fs::write(
        &cfg,
        format!("[daemon]\ncore = -1\n{daemon_keys}\n[services]\nprefix = \"{prefix}\"\n"),
    )
    .expect("write the daemon configuration");
    cfg
}

/// Collects every estimate arriving within `wall`, in order (all of them: the
/// client's buffer holds 16, so only a burst beyond that while this thread is held
/// up, such as a stalled daemon catching up, loses any), and checks that the client
/// refused none of the daemon's payloads.
pub fn collect(client: &mut OffsetClient, wall: Duration) -> Vec<Estimate> {
    let t0 = Instant::now();
    let mut out = vec![];
    while t0.elapsed() < wall {
        let got = client
            .wait_all(Duration::from_millis(100))
            .expect("read the offset service");
        out.extend(got.into_iter().map(|(e, _)| e));
    }
    assert_eq!(
        client.invalid_count(),
        0,
        "the daemon published estimates the client refused as invalid"
    );
    out
}

/// The newest status once one satisfies `done`, polling every 100 ms for up to
/// `deadline` (statuses come every `daemon.status_period_s`, later on a loaded
/// machine: a fixed wait judged the counters of a status that was not yet out);
/// after the deadline the newest status there is, which the caller's assertion
/// then shows. `None` when no status ever came.
pub fn status_when(
    status: &mut StatusClient,
    deadline: Duration,
    done: impl Fn(&Status) -> bool,
) -> Option<Status> {
    let t0 = Instant::now();
    loop {
        let st = status.latest().ok().flatten();
        if st.as_ref().is_some_and(&done) || t0.elapsed() >= deadline {
            return st;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A harness process (`vlsync-demo`, `vlsync-soak`) stopped when dropped with the
/// grace its own clean stop needs (it stops its daemon, drivers and recorder, one
/// after the other, each with seconds of grace): a failing test that killed it
/// sooner would orphan its daemon, whose iceoryx2 files then fail every later
/// check that a run leaves none.
pub struct Harness(pub Managed);

/// The grace a harness gets to stop its children before it is killed: at most
/// 3 + 3 s for the drivers, 3 s for a last status, 6 s for the recorder and 7 s
/// for the daemon (`Session::stop`), one after the other.
pub const HARNESS_GRACE: Duration = Duration::from_secs(25);

impl Drop for Harness {
    fn drop(&mut self) {
        self.0.stop(HARNESS_GRACE);
    }
}

/// Runs `cmd` to its end as `Command::output` does, but for at most `limit`: a run
/// past it (a refusal that regressed into a recording, a hung harness) is killed
/// and fails the test with what it printed, instead of hanging the suite until CI
/// gives up on it without a summary.
pub fn output_within(cmd: &mut Command, limit: Duration) -> std::process::Output {
    Piped::spawn(cmd.stdin(std::process::Stdio::null())).output_within(limit)
}

/// A child whose stdout and stderr are read beside it (so a chatty child never
/// blocks on a full pipe), started to be waited for later (beside a test's own
/// work), and stopped as a [`Managed`] is when dropped before its end: a test that
/// fails meanwhile leaves no process behind.
pub struct Piped {
    m: Managed,
    what: String,
    out: std::thread::JoinHandle<Vec<u8>>,
    err: std::thread::JoinHandle<Vec<u8>>,
}

impl Piped {
    /// Spawns `cmd` with its stdout and stderr piped (its stdin as `cmd` says).
    pub fn spawn(cmd: &mut Command) -> Self {
        use std::io::Read;
        use std::process::Stdio;
        let what = format!("{cmd:?}");
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {what}: {e}"));
        let drain = |r: Option<Box<dyn Read + Send>>| {
            std::thread::spawn(move || {
                let mut buf = Vec::new();
                if let Some(mut r) = r {
                    let _ = r.read_to_end(&mut buf);
                }
                buf
            })
        };
        let out = drain(
            child
                .stdout
                .take()
                .map(|p| Box::new(p) as Box<dyn Read + Send>),
        );
        let err = drain(
            child
                .stderr
                .take()
                .map(|p| Box::new(p) as Box<dyn Read + Send>),
        );
        Self {
            m: Managed {
                name: what.clone(),
                child,
            },
            what,
            out,
            err,
        }
    }

    /// The child (its stdin, when piped, to write to).
    pub fn child(&mut self) -> &mut std::process::Child {
        &mut self.m.child
    }

    /// Its exit status and output once it ends within `limit`; past it, it is stopped
    /// as a harness is (Ctrl-C, SIGTERM, SIGKILL, with [`HARNESS_GRACE`]) and the test
    /// fails with what it printed.
    pub fn output_within(self, limit: Duration) -> std::process::Output {
        let Self {
            mut m,
            what,
            out,
            err,
        } = self;
        let Some(status) = m.wait_up_to(limit) else {
            m.stop(HARNESS_GRACE);
            let (out, err) = (
                out.join().unwrap_or_default(),
                err.join().unwrap_or_default(),
            );
            panic!(
                "{what} still running after {limit:?}: stopped\n{}\n{}",
                String::from_utf8_lossy(&out),
                String::from_utf8_lossy(&err)
            );
        };
        std::process::Output {
            status,
            stdout: out.join().unwrap_or_default(),
            stderr: err.join().unwrap_or_default(),
        }
    }
}

/// |estimate - truth| of the locked (tracking/holding) estimates, seconds.
pub fn locked_errors(est: &[Estimate], sim: &vlsync_sim::SimRun) -> Vec<f64> {
    est.iter()
        .filter(|e| {
            matches!(
                e.state,
                vlsync_common::EstimatorState::Tracking | vlsync_common::EstimatorState::Holding
            )
        })
        .map(|e| (e.offset_s - sim.truth.offset_at(e.t_ref_ns)).abs())
        .collect()
}

/// A valid estimate in state `tracking` (offset 20 ± 1 ms at t = 10 s, seq `seq`), for
/// tests that publish on the offset service themselves.
pub fn tracking_estimate(seq: u64) -> Estimate {
    Estimate {
        seq,
        t_ref_ns: 10_000_000_000,
        offset_s: 0.02,
        drift: 0.0,
        offset_std_s: 0.001,
        drift_std: 0.0,
        state: vlsync_common::EstimatorState::Tracking,
        polarity: vlsync_common::Polarity::Positive,
        peak_score: 0.8,
        peak_ratio: 2.0,
        measured_offset_s: 0.02,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_iceoryx2_s_files_in_dev_shm_are_its_resources() {
        for (path, ours) in [
            ("/dev/shm/iox2_1124_1584.dynamic", true),
            ("/dev/shm/iox2_33c1_3169.event_mgmt", true),
            ("/dev/shm/pulse-shm-2717", false),
            ("/dev/shm/sem.mp-x1", false),
            ("/dev/shm/other/iox2", false),
            ("/tmp/iceoryx2/nodes/2246/iox2_node.details", true),
            ("/tmp/iceoryx2/services/iox2_833e.service", true),
        ] {
            assert_eq!(is_iceoryx2_resource(path), ours, "{path}");
        }
        // what the walk finds: this machine's iceoryx2 files, and nothing else of /dev/shm
        let other = format!("/dev/shm/vlsync-tests-not-iox2-{}", std::process::id());
        std::fs::write(&other, b"").unwrap();
        let found = ipc_resources();
        std::fs::remove_file(&other).unwrap();
        assert!(!found.contains(&other), "{found:?}");
    }

    #[test]
    fn output_within_gives_what_a_run_printed_and_its_exit() {
        let out = output_within(
            Command::new("sh").args(["-c", "echo out; echo err >&2; exit 3"]),
            Duration::from_secs(20),
        );
        assert_eq!(out.status.code(), Some(3));
        assert_eq!(
            (&out.stdout[..], &out.stderr[..]),
            (&b"out\n"[..], &b"err\n"[..])
        );
    }

    #[test]
    #[should_panic(expected = "still running after 200ms: stopped\nbefore")]
    fn output_within_stops_a_run_past_its_limit_and_fails() {
        output_within(
            Command::new("sh").args(["-c", "echo before; exec sleep 30"]),
            Duration::from_millis(200),
        );
    }
}
