//! A live run of the whole pipeline: `vlsyncd run` and both drivers as separate
//! processes on a unique prefix, their common start instant, every estimate
//! and status the daemon publishes, CPU time and memory of each process, and a
//! clean stop. `vlsync-demo` and `vlsync-loadtest` are thin layers over it.

use super::truth::{read_truth_csv, MeasuredTruth, TruthModel};
use crate::runtime::procs::{
    cpu_seconds, describe_exit, rss_kb, sibling_binary, thread_sched, Managed, ThreadSched,
};
use crate::runtime::RT_THREAD_NAME;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use vlsync_common::wire::Status;
use vlsync_common::{Estimate, Nanos};
use vlsync_ipc::{create_node, monotonic_ns, IpcNode, OffsetClient, StatusClient};

/// What the drivers publish.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// The signature-level simulator (`--sim FAMILY`).
    Sim {
        /// Family.
        family: vlsync_sim::Family,
        /// Seed.
        seed: u64,
        /// Simulated seconds.
        duration_s: f64,
        /// Real-time speed factor.
        speed: f64,
    },
    /// The rendering simulator through the real front-ends (`--render SEED`).
    Render {
        /// Seed (both drivers render the same run).
        seed: u64,
        /// Rendered seconds.
        duration_s: f64,
        /// Real-time speed factor (1 with software stamping).
        speed: f64,
        /// How the drivers stamp.
        stamping: Stamping,
        /// The LiDAR front-end also fits the wall behind (`--opposite-window`; the
        /// rendered room has a wall at each end).
        opposite_window: bool,
        /// The rendered sensors' rates (`--render-fps`, `--render-lidar-hz`; both
        /// drivers are given the same).
        rates: vlsync_driver::raw::RenderRates,
    },
}

/// How rendered data is stamped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stamping {
    /// The rendered sensor clocks (known offset and drift): scored against the
    /// rendering simulator's truth.
    Sensor,
    /// Camera stamped in software after processing, LiDAR with its sensor
    /// stamps, both on `CLOCK_MONOTONIC`; each driver writes a truth file and
    /// the run is scored against the measured truth. `frame_cpu_us` > 0: the camera
    /// front-end costs that much CPU per frame (`vlsync-cam --frame-cpu-ms`).
    Software {
        /// CPU per camera frame before its stamp, µs (0: the front-end's own).
        frame_cpu_us: u32,
    },
}

impl Source {
    /// Wall seconds the drivers run.
    pub fn wall_s(&self) -> f64 {
        match *self {
            Source::Sim {
                duration_s, speed, ..
            }
            | Source::Render {
                duration_s, speed, ..
            } => duration_s / speed,
        }
    }

    /// One line for the user.
    pub fn describe(&self) -> String {
        match self {
            Source::Sim {
                family,
                seed,
                duration_s,
                speed,
            } => format!(
                "signature simulator `{}` seed {seed}, {duration_s} s at {speed}x",
                family.name()
            ),
            Source::Render {
                seed,
                duration_s,
                speed,
                stamping,
                opposite_window,
                rates,
            } => format!(
                "rendered run seed {seed} through the front-ends, {duration_s} s at {speed}x, {}{}{}",
                match stamping {
                    Stamping::Sensor => "sensor clocks",
                    Stamping::Software { .. } =>
                        "camera stamped in software after processing, LiDAR sensor stamps",
                },
                if *opposite_window {
                    ", LiDAR walls ahead and behind"
                } else {
                    ""
                },
                if rates.is_default() {
                    String::new()
                } else {
                    let (c, l) = rates.resolved();
                    format!(", camera {c} Hz, LiDAR {l} Hz")
                }
            ),
        }
    }

    /// The offset model when it is known in advance (simulators on their own clocks).
    pub fn known_truth(&self) -> Result<Option<vlsync_sim::Truth>, String> {
        // a bad option is said as one, not as the simulator's field
        self.check()?;
        match *self {
            Source::Sim {
                family,
                seed,
                duration_s,
                ..
            } => vlsync_sim::try_generate(family, seed, Some(duration_s))
                .map(|r| Some(r.truth))
                .map_err(|e| format!("simulator: {e}")),
            Source::Render {
                seed,
                duration_s,
                stamping: Stamping::Sensor,
                rates,
                ..
            } => vlsync_driver::raw::renderer_at(seed, duration_s, rates)
                .map(|r| Some(r.truth().clone()))
                .map_err(|e| e.to_string()),
            Source::Render {
                stamping: Stamping::Software { .. },
                ..
            } => Ok(None),
        }
    }

    fn check(&self) -> Result<(), String> {
        let (d, s) = match *self {
            Source::Sim {
                duration_s, speed, ..
            }
            | Source::Render {
                duration_s, speed, ..
            } => (duration_s, speed),
        };
        if !(d.is_finite() && d > 0.0 && s.is_finite() && s > 0.0) {
            return Err(format!(
                "duration {d} s and speed {s} must be finite numbers > 0"
            ));
        }
        if let Source::Render { rates, .. } = self {
            // as the drivers will check them (they run without --config)
            rates.check(
                vlsync_config::Config::default().estimator.max_gap_s,
                "the drivers' default",
            )?;
        }
        if let Source::Render {
            stamping: Stamping::Software { .. },
            ..
        } = self
        {
            if s != 1.0 {
                return Err(format!(
                    "software stamping runs in real time only (speed {s})"
                ));
            }
        }
        Ok(())
    }
}

/// How to start a session.
#[derive(Debug, Clone)]
pub struct SessionOptions {
    /// Name of the tool (prefix `<name>/<pid>`, log directory `<tmp>/<name>-<pid>`).
    pub name: String,
    /// Service prefix instead of the default.
    pub prefix: Option<String>,
    /// Log directory instead of the default.
    pub log_dir: Option<PathBuf>,
    /// `vlsyncd run --config`.
    pub daemon_config: Option<PathBuf>,
    /// `vlsyncd run --fifo-priority` (overrides the configuration's).
    pub daemon_fifo_priority: Option<i64>,
    /// What the drivers publish.
    pub source: Source,
    /// From the drivers' spawn to their common start instant.
    pub start_delay: Duration,
    /// Also run `vlsyncd record` into this directory, from before the drivers start
    /// until the daemon has taken their last sample.
    pub record: Option<PathBuf>,
    /// The recorder may write over a recording already in `record` (its `--force`).
    pub record_force: bool,
}

/// The command-line options the live runs share: the daemon's configuration,
/// where the processes serve and where they log (`#[command(flatten)]`).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct ProcessArgs {
    /// Daemon configuration file.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Service prefix (default: `<program name>/<pid>`).
    #[arg(long)]
    pub prefix: Option<String>,
    /// Directory for the processes' logs (default: a temporary directory).
    #[arg(long)]
    pub log_dir: Option<PathBuf>,
}

impl ProcessArgs {
    /// The session options of tool `name` running `source` from `start_delay` on.
    pub fn session_options(
        &self,
        name: &str,
        source: Source,
        start_delay: Duration,
    ) -> SessionOptions {
        SessionOptions {
            name: name.into(),
            prefix: self.prefix.clone(),
            log_dir: self.log_dir.clone(),
            daemon_config: self.config.clone(),
            daemon_fifo_priority: None,
            source,
            start_delay,
            record: None,
            record_force: false,
        }
    }
}

/// The three processes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `vlsyncd run`.
    Daemon,
    /// `vlsync-cam`.
    Cam,
    /// `vlsync-lidar`.
    Lidar,
}

impl Role {
    /// All three, in display order.
    pub const ALL: [Role; 3] = [Role::Daemon, Role::Cam, Role::Lidar];

    /// Process name.
    pub fn name(self) -> &'static str {
        match self {
            Role::Daemon => "vlsyncd",
            Role::Cam => "vlsync-cam",
            Role::Lidar => "vlsync-lidar",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// CPU time and memory of one process, read while it ran.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Usage {
    /// CPU seconds (user + system) at the last reading.
    pub cpu_s: Option<f64>,
    /// Resident memory at the last reading, kB.
    pub rss_kb: Option<u64>,
    /// Seconds since the process started at that reading.
    pub elapsed_s: f64,
}

impl Usage {
    /// "CPU 1.23 s (2.05 % of a core) over 60.0 s wall, RSS 5.1 MB".
    pub fn describe(&self) -> String {
        format!(
            "CPU {} over {:.1} s wall, RSS {}",
            self.cpu_s.map_or("?".into(), |c| format!(
                "{c:.2} s ({:.2} % of a core)",
                100.0 * c / self.elapsed_s.max(1e-3)
            )),
            self.elapsed_s,
            self.rss_kb
                .map_or("?".into(), |r| format!("{:.1} MB", r as f64 / 1024.0))
        )
    }
}

/// One estimate as received.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Received {
    /// The estimate.
    pub est: Estimate,
    /// When the daemon published it, `CLOCK_MONOTONIC` ns.
    pub publish_ns: Nanos,
}

/// The largest |time| (ns) of an estimate the harness scores: 2^62 ns, 146 years. A
/// hostile publisher on the session's prefix could send any i64, and the reports
/// subtract start instants from these times.
pub const MAX_HARNESS_NS: i64 = 1 << 62;

/// Whether the harness scores an estimate of reference time `t_ref_ns` published at
/// `publish_ns` (see [`MAX_HARNESS_NS`]).
fn plausible(t_ref_ns: Nanos, publish_ns: Nanos) -> bool {
    t_ref_ns.unsigned_abs() <= MAX_HARNESS_NS as u64 && (0..=MAX_HARNESS_NS).contains(&publish_ns)
}

/// A running session; dropping it stops every process.
pub struct Session {
    /// Service prefix.
    pub prefix: String,
    /// Where the processes log (and the drivers write their truth files).
    pub log_dir: PathBuf,
    /// The drivers' common start instant, `CLOCK_MONOTONIC` ns.
    pub start_at: Nanos,
    /// What the drivers publish.
    pub source: Source,
    /// Every estimate received, in order.
    pub estimates: Vec<Received>,
    /// Estimates left out of `estimates` because their times are beyond
    /// [`MAX_HARNESS_NS`] (no daemon of ours publishes them; the harness's
    /// arithmetic on them would overflow).
    pub implausible: u64,
    /// Gaps in the sequence numbers of the estimates this harness read: estimates it
    /// read too late (the offset subscriber holds 16; a harness polled too rarely at
    /// a high `--speed` loses the oldest), or that the daemon numbered and did not
    /// publish (dropped, refused as invalid, a failed publish: its status counts
    /// those). The figures cover the rest.
    pub missed: u64,
    /// Sequence number of the last estimate received.
    last_seq: Option<u64>,
    /// Every status received, in order.
    pub statuses: Vec<Status>,
    procs: [Managed; 3],
    driver_bins: [PathBuf; 2],
    /// Suffix of the current driver pair's log and truth files (`""`, then `-<tag>`).
    suffix: String,
    /// False once a replaced driver needed more than SIGINT to stop.
    replaced_clean: bool,
    /// Processes that ended on their own with a failure (a non-zero exit, a signal
    /// such as someone's `kill -9`), each once, with its log: "vlsyncd: killed by
    /// signal 9 (SIGKILL) (log: /tmp/.../vlsyncd.log)". Found by
    /// [`Session::check_children`] and [`Session::stop`].
    pub failures: Vec<String>,
    /// Which of `procs` (then the recorder) already has its entry in `failures`.
    failure_noted: [bool; 4],
    started: [Instant; 3],
    usage: [Usage; 3],
    last_usage: Instant,
    offsets: OffsetClient,
    status: StatusClient,
    /// `vlsyncd record`, when asked for ([`SessionOptions::record`]).
    recorder: Option<Managed>,
    /// The scheduling the kernel gave the daemon's real-time thread, read once the
    /// daemon served (`Ok(None)`: it had no thread of that name).
    pub daemon_rt: Result<Option<ThreadSched>, String>,
    _node: IpcNode,
}

/// Longest wait for the daemon's "serving prefix" log line.
const DAEMON_READY_WAIT: Duration = Duration::from_secs(3);

/// File names of the drivers' truth files in the log directory.
pub const TRUTH_FILES: [&str; 2] = ["vlsync-cam.truth.csv", "vlsync-lidar.truth.csv"];

impl Session {
    /// Starts the daemon, waits until it serves, then both drivers on a common
    /// start instant `start_delay` ahead. Installs the SIGINT/SIGTERM handler of
    /// this process (see [`vlsync_ipc::termination_requested`]).
    pub fn start(o: SessionOptions) -> Result<Self, String> {
        // what can be checked is, before a directory is created or a process started
        o.source.check()?;
        if let Some(c) = &o.daemon_config {
            vlsync_config::Config::load(c).map_err(|e| format!("daemon configuration: {e}"))?;
        }
        let pid = std::process::id();
        let prefix = o
            .prefix
            .clone()
            .unwrap_or_else(|| format!("{}/{pid}", o.name));
        // a prefix no service can be named with fails here, not after the daemon started
        vlsync_ipc::ServiceNames::new(&prefix).map_err(|e| e.to_string())?;
        let bins = Role::ALL.map(|r| sibling_binary(r.name()));
        let [daemon_bin, cam_bin, lidar_bin] = bins;
        let (daemon_bin, driver_bins) = (daemon_bin?, [cam_bin?, lidar_bin?]);
        let log_dir = o
            .log_dir
            .clone()
            .unwrap_or_else(|| std::env::temp_dir().join(format!("{}-{pid}", o.name)));
        vlsync_common::file::create_out_dir("--log-dir", &log_dir)?;
        // our own node: handles Ctrl-C for this process
        let node = create_node(&o.name, true).map_err(|e| e.to_string())?;
        let mut dargs = vec!["run".to_string(), "--prefix".into(), prefix.clone()];
        if let Some(c) = &o.daemon_config {
            dargs.push("--config".into());
            dargs.push(c.display().to_string());
        }
        if let Some(p) = o.daemon_fifo_priority {
            dargs.push("--fifo-priority".into());
            dargs.push(p.to_string());
        }
        let daemon_log = log_dir.join("vlsyncd.log");
        let mut daemon = Managed::spawn("vlsyncd", &daemon_bin, &dargs, Some(&daemon_log))?;
        let daemon_started = Instant::now();
        let offsets = OffsetClient::open(&prefix).map_err(|e| e.to_string())?;
        let status = StatusClient::open(&prefix).map_err(|e| e.to_string())?;
        // the daemon logs "serving prefix" once its real-time thread runs; a
        // quieter RUST_LOG hides the line, so a daemon still running after
        // DAEMON_READY_WAIT is taken as serving
        if let Err(log) = daemon.wait_for_log(&daemon_log, "serving prefix", DAEMON_READY_WAIT) {
            return Err(format!(
                "vlsyncd exited at start; see {}:\n{log}",
                daemon_log.display()
            ));
        }
        // what the kernel gave the real-time thread (it applies its settings before
        // the daemon serves)
        let daemon_rt = thread_sched(daemon.pid(), RT_THREAD_NAME);
        let recorder = match &o.record {
            Some(dir) => Some(spawn_recorder(
                &daemon_bin,
                &prefix,
                dir,
                o.record_force,
                &log_dir,
            )?),
            None => None,
        };
        let start_at = monotonic_ns() + o.start_delay.as_nanos() as Nanos;
        let [(cam, cam_t), (lidar, lidar_t)] =
            spawn_drivers(&driver_bins, &o.source, &prefix, start_at, &log_dir, "")?;
        Ok(Self {
            prefix,
            log_dir,
            start_at,
            source: o.source,
            estimates: vec![],
            implausible: 0,
            missed: 0,
            last_seq: None,
            statuses: vec![],
            procs: [daemon, cam, lidar],
            driver_bins,
            suffix: String::new(),
            replaced_clean: true,
            failures: vec![],
            failure_noted: [false; 4],
            started: [daemon_started, cam_t, lidar_t],
            usage: [Usage::default(); 3],
            last_usage: Instant::now() - Duration::from_secs(1),
            offsets,
            status,
            recorder,
            daemon_rt,
            _node: node,
        })
    }

    /// Replaces the driver pair with a new one publishing `source` on a common
    /// start instant `start_delay` ahead (a driver still running is stopped
    /// first); the daemon runs on, and `estimates` keeps what it published so far.
    /// The new drivers log to `vlsync-cam-<tag>.log` and `vlsync-lidar-<tag>.log`
    /// (and write their truth files, if any, as `vlsync-cam-<tag>.truth.csv`, ...).
    pub fn next_drivers(
        &mut self,
        source: Source,
        start_delay: Duration,
        tag: &str,
    ) -> Result<(), String> {
        source.check()?;
        self.sample_usage(true);
        self.check_children();
        for i in [1, 2] {
            if self.procs[i].running() {
                self.replaced_clean &= self.procs[i].stop(Duration::from_secs(3));
            }
        }
        let start_at = monotonic_ns() + start_delay.as_nanos() as Nanos;
        let suffix = format!("-{tag}");
        let [(cam, cam_t), (lidar, lidar_t)] = spawn_drivers(
            &self.driver_bins,
            &source,
            &self.prefix,
            start_at,
            &self.log_dir,
            &suffix,
        )?;
        let [_, old_cam, old_lidar] = &mut self.procs;
        *old_cam = cam;
        *old_lidar = lidar;
        self.started[1] = cam_t;
        self.started[2] = lidar_t;
        self.usage[1] = Usage::default();
        self.usage[2] = Usage::default();
        self.start_at = start_at;
        self.source = source;
        self.suffix = suffix;
        // the new pair's failures are its own
        self.failure_noted[1] = false;
        self.failure_noted[2] = false;
        Ok(())
    }

    /// Process id of `role`.
    pub fn pid(&self, role: Role) -> u32 {
        self.procs[role.index()].pid()
    }

    /// Sends `signal` (e.g. "STOP", "CONT") to `role`.
    pub fn signal(&mut self, role: Role, signal: &str) -> Result<(), String> {
        self.procs[role.index()].signal(signal)
    }

    /// CPU seconds of `role` so far.
    pub fn cpu_seconds(&self, role: Role) -> Result<f64, String> {
        cpu_seconds(self.pid(role))
    }

    /// True while `role` runs.
    pub fn running(&mut self, role: Role) -> bool {
        self.procs[role.index()].running()
    }

    /// Notes in [`Session::failures`] every process of the session (daemon, drivers,
    /// recorder) that has ended on its own with a failure since it started; returns
    /// whether the daemon is among them (the run cannot go on without it).
    pub fn check_children(&mut self) -> bool {
        self.note_failures(false)
    }

    /// [`Session::check_children`]; `stopped`: the children were just stopped, so a
    /// signal that ended one was ours (a stop that needed SIGKILL is counted as such)
    /// and only an exit status other than 0 is a failure (a recorder whose last
    /// flush failed exits 2 on SIGINT).
    fn note_failures(&mut self, stopped: bool) -> bool {
        let logs = [
            self.log_dir.join("vlsyncd.log"),
            self.log_dir.join(format!("vlsync-cam{}.log", self.suffix)),
            self.log_dir
                .join(format!("vlsync-lidar{}.log", self.suffix)),
            self.log_dir.join(RECORDER_LOG),
        ];
        let names = ["vlsyncd", "vlsync-cam", "vlsync-lidar", "vlsyncd record"];
        let mut found: Vec<(usize, String)> = vec![];
        let counts = |st: &std::process::ExitStatus| !stopped || st.code().is_some();
        let recorder = self.recorder.as_mut();
        let children = self.procs.iter_mut().map(Some).chain([recorder]);
        for (i, m) in children.enumerate() {
            if self.failure_noted[i] {
                continue;
            }
            if let Some(st) = m.and_then(Managed::failed_status).filter(counts) {
                found.push((i, describe_exit(st)));
            }
        }
        for (i, f) in found {
            self.failure_noted[i] = true;
            self.failures
                .push(format!("{}: {f} (log: {})", names[i], logs[i].display()));
        }
        self.failure_noted[0]
    }

    /// Whether `vlsyncd record` (`SessionOptions::record`) ended with a failure.
    pub fn recorder_failed(&self) -> bool {
        self.failure_noted[3]
    }

    /// True once both drivers have exited.
    pub fn drivers_done(&mut self) -> bool {
        !self.running(Role::Cam) && !self.running(Role::Lidar)
    }

    /// `CLOCK_MONOTONIC` instant the drivers' run ends.
    pub fn end_ns(&self) -> Nanos {
        self.start_at + (self.source.wall_s() * 1e9) as Nanos
    }

    /// The truth files of a software-stamped run.
    pub fn truth_paths(&self) -> [PathBuf; 2] {
        TRUTH_FILES.map(|f| self.log_dir.join(truth_file(f, &self.suffix)))
    }

    /// Reads CPU time and memory of every running process (at most every 0.5 s
    /// unless `force`).
    pub fn sample_usage(&mut self, force: bool) {
        if !force && self.last_usage.elapsed() < Duration::from_millis(500) {
            return;
        }
        self.last_usage = Instant::now();
        for r in Role::ALL {
            let i = r.index();
            if !self.procs[i].running() {
                continue;
            }
            if let (Ok(c), Ok(m)) = (cpu_seconds(self.pid(r)), rss_kb(self.pid(r))) {
                self.usage[i] = Usage {
                    cpu_s: Some(c),
                    rss_kb: Some(m),
                    elapsed_s: self.started[i].elapsed().as_secs_f64(),
                };
            }
        }
    }

    /// Usage of `role` at its last reading.
    pub fn usage(&self, role: Role) -> Usage {
        self.usage[role.index()]
    }

    /// Waits up to `timeout` for estimates; records them and every pending
    /// status; reads usage. Returns the new estimates.
    pub fn poll(&mut self, timeout: Duration) -> Result<Vec<Received>, String> {
        let got = self.receive_estimates(timeout)?;
        self.drain_status()?;
        self.sample_usage(false);
        Ok(got)
    }

    /// Waits up to `timeout` for estimates; keeps the plausible ones (recorded and
    /// returned), counts the rest in `implausible`.
    fn receive_estimates(&mut self, timeout: Duration) -> Result<Vec<Received>, String> {
        let all = self.offsets.wait_all(timeout).map_err(|e| e.to_string())?;
        let n = all.len();
        for (est, _) in &all {
            if let Some(last) = self.last_seq {
                // a sequence that goes back is another daemon's, not a loss
                self.missed += est.seq.saturating_sub(last.saturating_add(1));
            }
            self.last_seq = Some(est.seq);
        }
        let got: Vec<Received> = all
            .into_iter()
            .filter(|(est, publish_ns)| plausible(est.t_ref_ns, *publish_ns))
            .map(|(est, publish_ns)| Received { est, publish_ns })
            .collect();
        self.implausible += (n - got.len()) as u64;
        self.estimates.extend_from_slice(&got);
        Ok(got)
    }

    fn drain_status(&mut self) -> Result<(), String> {
        let st = self.status.receive_all().map_err(|e| e.to_string())?;
        self.statuses.extend(st);
        Ok(())
    }

    /// Stops the drivers, waits for the daemon's next status (so the counters
    /// include every sample), stops the daemon. True when every process exited
    /// cleanly.
    pub fn stop(&mut self) -> Result<bool, String> {
        self.sample_usage(true);
        self.check_children();
        let clean_drivers = [
            self.procs[1].stop(Duration::from_secs(3)),
            self.procs[2].stop(Duration::from_secs(3)),
        ];
        // the daemon publishes a final status when it stops; also wait for a
        // periodic one published after the drivers ended, so the counters of a
        // still-running daemon include their last samples (a status still unread in
        // the buffer may be from while they stopped; not from a daemon that has
        // ended: a crash's report would wait 3 s for nothing)
        let drivers_ended = monotonic_ns();
        let t0 = Instant::now();
        self.drain_status()?;
        while t0.elapsed() < Duration::from_secs(3) && self.procs[0].running() {
            self.drain_status()?;
            if self
                .statuses
                .last()
                .is_some_and(|s| s.publish_ns > drivers_ended)
            {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        // the estimates published before the drivers stopped
        self.receive_estimates(Duration::from_millis(10))?;
        self.sample_usage(true);
        // the recorder has read them too (it reads an estimate within 20 ms)
        let clean_recorder = self
            .recorder
            .as_mut()
            .is_none_or(|r| r.stop(Duration::from_secs(6)));
        let clean_daemon = self.procs[0].stop(DAEMON_STOP_GRACE);
        self.note_failures(true);
        Ok(clean_drivers.iter().all(|c| *c)
            && clean_daemon
            && clean_recorder
            && self.replaced_clean
            && self.failures.is_empty())
    }

    /// The truth of this run: the known model, or the measured one from the
    /// drivers' truth files (read now) with the estimator window `window_s`.
    pub fn truth(&self, window_s: f64) -> Result<TruthModel, String> {
        if let Some(t) = self.source.known_truth()? {
            return Ok(TruthModel::Known(t));
        }
        let [c, l] = self.truth_paths();
        let cam = read_truth_csv(&c)?;
        let lidar = read_truth_csv(&l)?;
        MeasuredTruth::new(&cam, &lidar, window_s)
            .map(TruthModel::Measured)
            .map_err(|e| format!("{} and {}: {e}", c.display(), l.display()))
    }

    /// The last status received.
    pub fn last_status(&self) -> Option<&Status> {
        self.statuses.last()
    }

    /// Contents of a log of the log directory (for error messages).
    pub fn log(&self, file: &str) -> String {
        std::fs::read_to_string(self.log_dir.join(file)).unwrap_or_default()
    }
}

/// How long the daemon is given to stop cleanly before SIGKILL: its clean stop may
/// take the final state save's wait and two bounded sends of its last counters.
const DAEMON_STOP_GRACE: Duration =
    Duration::from_secs(crate::state::FINAL_SAVE_WAIT.as_secs() + 4);

/// On an error path (a `?` before [`Session::stop`]) the processes stop in the order
/// and with the grace `stop` uses: the drivers, then the recorder, then the daemon
/// (left to `procs`' own drop, it had 3 s, and a daemon killed mid-save leaves its
/// shared memory behind).
impl Drop for Session {
    fn drop(&mut self) {
        for m in &mut self.procs[1..] {
            m.stop(Duration::from_secs(3));
        }
        if let Some(r) = self.recorder.as_mut() {
            r.stop(Duration::from_secs(6));
        }
        self.procs[0].stop(DAEMON_STOP_GRACE);
    }
}

/// The line a live tool prints when the harness missed estimates
/// ([`Session::missed`]); `None` when it missed none.
pub fn missed_line(s: &Session) -> Option<String> {
    (s.missed > 0).then(|| {
        format!(
            "missed: {} estimate(s), gaps in the daemon's estimate sequence (read too late by the harness, whose subscriber holds 16: a lower --speed avoids it; or never published: the daemon's status counts those): the figures cover the rest",
            s.missed
        )
    })
}

/// The daemon's counters as the live tools' summaries print them: samples
/// received, lost and rejected per stream, estimates, budget overruns.
pub fn counters_line(st: &Status) -> String {
    format!(
        "daemon: received cam {} lidar {}, lost cam {} lidar {}, rejected cam {} lidar {}, {} estimates, {} budget overruns",
        st.received[0],
        st.received[1],
        st.lost[0],
        st.lost[1],
        st.rejected_total(0),
        st.rejected_total(1),
        st.estimates_published,
        st.budget_overruns
    )
}

/// How the children stopped, for the summaries: `cleanly`, or not (a failure or SIGKILL).
pub fn stop_words(clean: bool) -> &'static str {
    if clean {
        "cleanly"
    } else {
        "(not all cleanly: one ended with a failure or needed SIGKILL)"
    }
}

/// Log file of the session's `vlsyncd record`.
pub const RECORDER_LOG: &str = "vlsyncd-record.log";

/// Starts `vlsyncd record` into `dir` and waits (up to [`DAEMON_READY_WAIT`]) until it
/// has subscribed, so that it sees the drivers' first samples.
fn spawn_recorder(
    bin: &Path,
    prefix: &str,
    dir: &Path,
    force: bool,
    log_dir: &Path,
) -> Result<Managed, String> {
    let log = log_dir.join(RECORDER_LOG);
    let mut args = [
        "record",
        "--prefix",
        prefix,
        "--out",
        &dir.display().to_string(),
        "--progress-every",
        "0",
    ]
    .map(String::from)
    .to_vec();
    if force {
        args.push("--force".into());
    }
    let mut r = Managed::spawn("vlsyncd record", bin, &args, Some(&log))?;
    match r.wait_for_log(&log, "Ctrl-C stops", DAEMON_READY_WAIT) {
        Err(text) => Err(format!("vlsyncd record exited at start:\n{text}")),
        // a recorder still starting is left to catch up: it misses the first samples
        Ok(_) => Ok(r),
    }
}

/// Spawns both drivers of `src` (logs `vlsync-<stream><suffix>.log`).
fn spawn_drivers(
    bins: &[PathBuf; 2],
    src: &Source,
    prefix: &str,
    start_at: Nanos,
    log_dir: &Path,
    suffix: &str,
) -> Result<[(Managed, Instant); 2], String> {
    let spawn = |role: Role, stream: &str, bin: &PathBuf| {
        let args = driver_args(src, prefix, start_at, role, log_dir, suffix);
        let log = log_dir.join(format!("vlsync-{stream}{suffix}.log"));
        Managed::spawn(role.name(), bin, &args, Some(&log)).map(|m| (m, Instant::now()))
    };
    let cam = spawn(Role::Cam, "cam", &bins[0])?;
    let lidar = spawn(Role::Lidar, "lidar", &bins[1])?;
    Ok([cam, lidar])
}

/// `vlsync-cam.truth.csv` with `suffix` before its extension.
fn truth_file(name: &str, suffix: &str) -> String {
    match name.split_once('.') {
        Some((stem, ext)) => format!("{stem}{suffix}.{ext}"),
        None => format!("{name}{suffix}"),
    }
}

/// Command line of a driver (`suffix`: of its truth file's name).
fn driver_args(
    src: &Source,
    prefix: &str,
    start_at: Nanos,
    role: Role,
    logs: &Path,
    suffix: &str,
) -> Vec<String> {
    let mut a: Vec<String> = vec!["--prefix".into(), prefix.into()];
    match src {
        Source::Sim {
            family,
            seed,
            duration_s,
            speed,
        } => a.extend([
            "--sim".into(),
            family.name().into(),
            "--seed".into(),
            seed.to_string(),
            "--duration".into(),
            duration_s.to_string(),
            "--speed".into(),
            speed.to_string(),
        ]),
        Source::Render {
            seed,
            duration_s,
            speed,
            stamping,
            opposite_window,
            rates,
        } => {
            a.extend([
                "--render".into(),
                seed.to_string(),
                "--duration".into(),
                duration_s.to_string(),
                "--speed".into(),
                speed.to_string(),
            ]);
            // both drivers: the run's draws depend on both rates
            if let Some(fps) = rates.cam_fps {
                a.extend(["--render-fps".into(), fps.to_string()]);
            }
            if let Some(hz) = rates.lidar_hz {
                a.extend(["--render-lidar-hz".into(), hz.to_string()]);
            }
            if role == Role::Lidar && *opposite_window {
                a.push("--opposite-window".into());
            }
            if let Stamping::Software { frame_cpu_us } = *stamping {
                let stamp = if role == Role::Cam {
                    "software"
                } else {
                    "mono"
                };
                let file = truth_file(TRUTH_FILES[usize::from(role == Role::Lidar)], suffix);
                a.extend([
                    "--stamp".into(),
                    stamp.into(),
                    "--truth-out".into(),
                    logs.join(file).display().to_string(),
                ]);
                if role == Role::Cam && frame_cpu_us > 0 {
                    a.extend([
                        "--frame-cpu-ms".into(),
                        (f64::from(frame_cpu_us) * 1e-3).to_string(),
                    ]);
                }
            }
        }
    }
    a.extend(["--start-at".into(), start_at.to_string()]);
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A prefix no service can be named with is refused before the log directory is
    /// made or a process started (it used to surface from the client's open, after
    /// `vlsyncd` had been spawned into the new directory).
    #[test]
    fn a_bad_prefix_fails_before_anything_starts() {
        let dir =
            std::env::temp_dir().join(format!("vlsync-session-prefix-{}", std::process::id()));
        let e = Session::start(SessionOptions {
            name: "t".into(),
            prefix: Some("a b".into()),
            log_dir: Some(dir.clone()),
            daemon_config: None,
            daemon_fifo_priority: None,
            source: Source::Sim {
                family: vlsync_sim::Family::Robot,
                seed: 1,
                duration_s: 10.0,
                speed: 1.0,
            },
            start_delay: Duration::from_secs(1),
            record: None,
            record_force: false,
        })
        .err()
        .expect("a bad prefix starts no session");
        assert!(e.contains("services.prefix") && e.contains("a b"), "{e}");
        assert!(!dir.exists(), "{e}");
    }

    #[test]
    fn driver_command_lines() {
        let src = Source::Render {
            seed: 3,
            duration_s: 40.0,
            speed: 1.0,
            stamping: Stamping::Software { frame_cpu_us: 0 },
            opposite_window: false,
            rates: Default::default(),
        };
        let cam = driver_args(&src, "p/1", 77, Role::Cam, Path::new("/l"), "").join(" ");
        assert_eq!(
            cam,
            "--prefix p/1 --render 3 --duration 40 --speed 1 --stamp software \
             --truth-out /l/vlsync-cam.truth.csv --start-at 77"
        );
        let lidar = driver_args(&src, "p/1", 77, Role::Lidar, Path::new("/l"), "-2").join(" ");
        // a later session's truth file carries its tag
        assert!(lidar.contains("--stamp mono --truth-out /l/vlsync-lidar-2.truth.csv"));
        // a heavier camera front-end: the camera driver only
        let heavy = Source::Render {
            seed: 3,
            duration_s: 40.0,
            speed: 1.0,
            stamping: Stamping::Software {
                frame_cpu_us: 12_500,
            },
            opposite_window: true,
            rates: Default::default(),
        };
        let cam = driver_args(&heavy, "p/1", 77, Role::Cam, Path::new("/l"), "").join(" ");
        assert!(cam.contains("--frame-cpu-ms 12.5 --start-at 77"), "{cam}");
        let lidar = driver_args(&heavy, "p/1", 77, Role::Lidar, Path::new("/l"), "").join(" ");
        assert!(!lidar.contains("--frame-cpu-ms"), "{lidar}");
        // the wall behind: the LiDAR driver only
        assert!(lidar.contains("--opposite-window"), "{lidar}");
        assert!(!cam.contains("--opposite-window"), "{cam}");
        // the rendered rates: both drivers (the run's draws depend on both)
        let slow = Source::Render {
            seed: 3,
            duration_s: 40.0,
            speed: 1.0,
            stamping: Stamping::Sensor,
            opposite_window: false,
            rates: vlsync_driver::raw::RenderRates {
                cam_fps: Some(15.0),
                lidar_hz: Some(5.5),
            },
        };
        for role in [Role::Cam, Role::Lidar] {
            let line = driver_args(&slow, "p/1", 77, role, Path::new("/l"), "").join(" ");
            assert!(
                line.contains("--render-fps 15 --render-lidar-hz 5.5 --start-at 77"),
                "{line}"
            );
        }
        assert!(
            slow.describe()
                .ends_with("sensor clocks, camera 15 Hz, LiDAR 5.5 Hz"),
            "{}",
            slow.describe()
        );
        assert!(!cam.contains("--render-fps"), "{cam}");
        let sim = Source::Sim {
            family: vlsync_sim::Family::Robot,
            seed: 2,
            duration_s: 10.0,
            speed: 2.0,
        };
        let a = driver_args(&sim, "p", 5, Role::Cam, Path::new("/l"), "").join(" ");
        assert_eq!(
            a,
            "--prefix p --sim robot --seed 2 --duration 10 --speed 2 --start-at 5"
        );
        assert_eq!(sim.wall_s(), 5.0);
    }

    #[test]
    fn summary_lines() {
        let mut st = Status {
            received: [300, 100],
            lost: [0, 2],
            estimates_published: 12,
            ..Status::default()
        };
        st.rejected[0][1] = 3;
        assert_eq!(
            counters_line(&st),
            "daemon: received cam 300 lidar 100, lost cam 0 lidar 2, rejected cam 3 lidar 0, 12 estimates, 0 budget overruns"
        );
        assert_eq!(stop_words(true), "cleanly");
        assert_eq!(
            stop_words(false),
            "(not all cleanly: one ended with a failure or needed SIGKILL)"
        );
    }

    #[test]
    fn sources_are_checked_and_know_their_truth() {
        let bad = Source::Render {
            seed: 1,
            duration_s: 10.0,
            speed: 2.0,
            stamping: Stamping::Software { frame_cpu_us: 0 },
            opposite_window: false,
            rates: Default::default(),
        };
        assert!(bad.check().unwrap_err().contains("real time"));
        let slow = Source::Render {
            seed: 1,
            duration_s: 10.0,
            speed: 1.0,
            stamping: Stamping::Sensor,
            opposite_window: false,
            rates: vlsync_driver::raw::RenderRates {
                cam_fps: None,
                lidar_hz: Some(1.0),
            },
        };
        let e = slow.check().unwrap_err();
        assert!(e.starts_with("--render-lidar-hz 1 is out of range"), "{e}");
        let bad = Source::Sim {
            family: vlsync_sim::Family::Robot,
            seed: 1,
            duration_s: f64::NAN,
            speed: 1.0,
        };
        assert!(bad.check().is_err());
        let sensor = Source::Render {
            seed: 1,
            duration_s: 10.0,
            speed: 1.0,
            stamping: Stamping::Sensor,
            opposite_window: false,
            rates: Default::default(),
        };
        let t = sensor.known_truth().unwrap().unwrap();
        let r = vlsync_driver::raw::renderer(1, 10.0).unwrap();
        assert_eq!(
            t.offset_at(5_000_000_000),
            r.truth().offset_at(5_000_000_000)
        );
        let sw = Source::Render {
            seed: 1,
            duration_s: 10.0,
            speed: 1.0,
            stamping: Stamping::Software { frame_cpu_us: 0 },
            opposite_window: false,
            rates: Default::default(),
        };
        assert!(sw.known_truth().unwrap().is_none());
    }

    #[test]
    fn estimates_with_times_no_daemon_publishes_are_left_out() {
        assert!(plausible(-2_000_000_000, 5_000_000_000));
        assert!(plausible(MAX_HARNESS_NS, MAX_HARNESS_NS));
        assert!(!plausible(i64::MIN, 1));
        assert!(!plausible(0, i64::MIN));
        assert!(!plausible(0, -1));
        assert!(!plausible(i64::MAX, 1));
    }

    #[test]
    fn bad_options_fail_before_the_log_directory_is_made() {
        let dir = std::env::temp_dir().join(format!("vlsync-session-bad-{}", std::process::id()));
        let sim = Source::Sim {
            family: vlsync_sim::Family::Robot,
            seed: 1,
            duration_s: 10.0,
            speed: 1.0,
        };
        let opts = |source: Source, config: &str| SessionOptions {
            name: "vlsync-test".into(),
            prefix: None,
            log_dir: Some(dir.clone()),
            daemon_config: Some(PathBuf::from(config)),
            daemon_fifo_priority: None,
            source,
            start_delay: Duration::ZERO,
            record: None,
            record_force: false,
        };
        let e = Session::start(opts(sim, "/nonexistent/vlsync.toml"))
            .err()
            .unwrap();
        assert!(e.contains("/nonexistent/vlsync.toml"), "{e}");
        let bad_speed = Source::Sim {
            family: vlsync_sim::Family::Robot,
            seed: 1,
            duration_s: 10.0,
            speed: 0.0,
        };
        let e = Session::start(opts(bad_speed, "/nonexistent/vlsync.toml"))
            .err()
            .unwrap();
        assert!(e.contains("speed 0"), "{e}");
        assert!(!dir.exists());
    }
}
