//! Load profiles and their injection: CPU load and memory pressure with
//! stress-ng, stalls of a driver with SIGSTOP/SIGCONT, phase by phase on the
//! run's clock.

use super::session::{Received, Role, Session};
use crate::runtime::procs::Managed;
use std::path::{Path, PathBuf};
use std::time::Duration;
use vlsync_common::Nanos;
use vlsync_ipc::{monotonic_ns, termination_requested};

/// What a phase does to the machine.
#[derive(Debug, Clone, PartialEq)]
pub enum Load {
    /// Nothing.
    Idle,
    /// `stress-ng --cpu N` for the whole phase (0: one worker per online CPU).
    Cpu {
        /// Workers.
        workers: u32,
    },
    /// CPU load switched on for `on_s`, off for `off_s`, repeatedly.
    Bursts {
        /// Workers (0: one per online CPU).
        workers: u32,
        /// Seconds on.
        on_s: f64,
        /// Seconds off.
        off_s: f64,
    },
    /// A driver stopped (SIGSTOP) for `stop_ms` then continued, every `every_s`.
    Stall {
        /// Which driver.
        role: Role,
        /// Stall length, ms.
        stop_ms: u64,
        /// Period, seconds.
        every_s: f64,
    },
    /// `stress-ng --vm N --vm-bytes B` for the whole phase (memory pressure).
    Memory {
        /// Workers.
        workers: u32,
        /// Bytes as stress-ng takes them (e.g. `25%`, `2g`): the workers share them
        /// (stress-ng 0.15 divides `--vm-bytes` among its instances; measured: `--vm 2
        /// --vm-bytes 10%` on 24 GB, 1.0 GB resident in each worker).
        bytes: String,
    },
}

impl Load {
    /// Short description for tables.
    pub fn describe(&self) -> String {
        match self {
            Load::Idle => "idle".into(),
            Load::Cpu { workers: 0 } => "cpu, every core".into(),
            Load::Cpu { workers } => format!("cpu x{workers}"),
            Load::Bursts {
                workers,
                on_s,
                off_s,
            } => format!(
                "cpu bursts {on_s} s on / {off_s} s off{}",
                if *workers == 0 {
                    String::new()
                } else {
                    format!(" x{workers}")
                }
            ),
            Load::Stall {
                role,
                stop_ms,
                every_s,
            } => format!("{} stalled {stop_ms} ms every {every_s} s", role.name()),
            Load::Memory { workers, bytes } => format!("memory x{workers} {bytes} in all"),
        }
    }

    /// Steady CPU level (for load steps): `Some(false)` idle, `Some(true)` full
    /// CPU load, `None` for loads that change within the phase.
    pub fn steady_cpu(&self) -> Option<bool> {
        match self {
            Load::Idle => Some(false),
            Load::Cpu { .. } => Some(true),
            _ => None,
        }
    }

    /// True when the phase runs stress-ng.
    pub fn needs_stress_ng(&self) -> bool {
        matches!(
            self,
            Load::Cpu { .. } | Load::Bursts { .. } | Load::Memory { .. }
        )
    }
}

/// One phase of a profile.
#[derive(Debug, Clone, PartialEq)]
pub struct Phase {
    /// Name in tables and the plot.
    pub name: String,
    /// Seconds.
    pub duration_s: f64,
    /// What it does.
    pub load: Load,
}

/// A named sequence of phases.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    /// Name (`--profile`).
    pub name: &'static str,
    /// One line.
    pub about: &'static str,
    /// The phases; the first is the idle warm-up in which the estimator locks.
    pub phases: Vec<Phase>,
}

impl Profile {
    /// Seconds of the whole profile.
    pub fn duration_s(&self) -> f64 {
        self.phases.iter().map(|p| p.duration_s).sum()
    }

    /// True when some phase runs stress-ng.
    pub fn needs_stress_ng(&self) -> bool {
        self.phases.iter().any(|p| p.load.needs_stress_ng())
    }
}

fn phase(name: &str, duration_s: f64, load: Load) -> Phase {
    Phase {
        name: name.into(),
        duration_s,
        load,
    }
}

const WARMUP_S: f64 = 20.0;
const FULL: Load = Load::Cpu { workers: 0 };

/// Every profile, by name.
pub fn profiles() -> Vec<Profile> {
    let warm = || phase("warm-up", WARMUP_S, Load::Idle);
    let cam_stall = Load::Stall {
        role: Role::Cam,
        stop_ms: 40,
        every_s: 2.0,
    };
    let lidar_stall = Load::Stall {
        role: Role::Lidar,
        stop_ms: 40,
        every_s: 2.0,
    };
    let bursts = Load::Bursts {
        workers: 0,
        on_s: 2.0,
        off_s: 3.0,
    };
    let memory = Load::Memory {
        workers: 2,
        bytes: "25%".into(),
    };
    vec![
        Profile {
            name: "idle",
            about: "no load: the reference",
            phases: vec![warm(), phase("idle", 60.0, Load::Idle)],
        },
        Profile {
            name: "full",
            about: "steady full CPU load on every core",
            phases: vec![warm(), phase("full load", 60.0, FULL)],
        },
        Profile {
            name: "steps",
            about: "full CPU load switched on and off in 30 s steps",
            phases: vec![
                warm(),
                phase("load on", 30.0, FULL),
                phase("load off", 30.0, Load::Idle),
                phase("load on 2", 30.0, FULL),
                phase("load off 2", 30.0, Load::Idle),
            ],
        },
        Profile {
            name: "bursts",
            about: "CPU bursts: every core 2 s on, 3 s off",
            phases: vec![
                warm(),
                phase("bursts", 60.0, bursts.clone()),
                phase("after", 15.0, Load::Idle),
            ],
        },
        Profile {
            name: "stalls",
            about: "each driver stopped 40 ms every 2 s (SIGSTOP/SIGCONT)",
            phases: vec![
                warm(),
                phase("camera stalls", 30.0, cam_stall.clone()),
                phase("between", 10.0, Load::Idle),
                phase("LiDAR stalls", 30.0, lidar_stall.clone()),
                phase("after", 10.0, Load::Idle),
            ],
        },
        Profile {
            name: "memory",
            about: "a burst of memory pressure (2 workers, 25 % of memory between them)",
            phases: vec![
                warm(),
                phase("memory", 15.0, memory.clone()),
                phase("after", 25.0, Load::Idle),
            ],
        },
        Profile {
            name: "all",
            about: "every load in turn (about 4 min)",
            phases: vec![
                warm(),
                phase("full load", 40.0, FULL),
                phase("load off", 20.0, Load::Idle),
                phase("bursts", 40.0, bursts),
                phase("quiet", 15.0, Load::Idle),
                phase("camera stalls", 30.0, cam_stall),
                phase("LiDAR stalls", 30.0, lidar_stall),
                phase("memory", 15.0, memory),
                phase("after", 20.0, Load::Idle),
            ],
        },
        Profile {
            name: "short",
            about: "the test suite's profile: warm-up, full load, camera stalls (52 s)",
            phases: vec![
                phase("warm-up", 18.0, Load::Idle),
                phase("full load", 22.0, FULL),
                phase(
                    "camera stalls",
                    12.0,
                    Load::Stall {
                        role: Role::Cam,
                        stop_ms: 40,
                        every_s: 1.5,
                    },
                ),
            ],
        },
    ]
}

/// The profile called `name`; the error lists the names.
pub fn profile(name: &str) -> Result<Profile, String> {
    let all = profiles();
    let names: Vec<&str> = all.iter().map(|p| p.name).collect();
    all.into_iter()
        .find(|p| p.name == name)
        .ok_or_else(|| format!("unknown profile `{name}`; profiles: {}", names.join(", ")))
}

/// Finds stress-ng on `PATH`; the error says how to install it.
pub fn find_stress_ng() -> Result<PathBuf, String> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    for d in std::env::split_paths(&path) {
        let p = d.join("stress-ng");
        // as the shell looks: a file without an execute bit is passed over
        let executable = |m: std::fs::Metadata| {
            use std::os::unix::fs::PermissionsExt;
            m.is_file() && m.permissions().mode() & 0o111 != 0
        };
        if std::fs::metadata(&p).is_ok_and(executable) {
            return Ok(p);
        }
    }
    Err(
        "stress-ng not found on PATH; install it (Debian/Ubuntu: apt-get install -y stress-ng)"
            .into(),
    )
}

/// One stall as injected.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stall {
    /// Which driver.
    pub role: Role,
    /// SIGSTOP delivered (`kill(2)` returned), `CLOCK_MONOTONIC` ns.
    pub stop_ns: Nanos,
    /// SIGCONT delivered, ns.
    pub cont_ns: Nanos,
}

/// What happened in one phase.
#[derive(Debug, Clone, PartialEq)]
pub struct PhaseRecord {
    /// The phase.
    pub phase: Phase,
    /// Start and end on `CLOCK_MONOTONIC`, ns.
    pub start_ns: Nanos,
    /// End, ns: the planned end, or the instant of a Ctrl-C that cut the phase short
    /// (the daemon's CPU share is over the part that ran).
    pub end_ns: Nanos,
    /// Daemon CPU seconds at start and end.
    pub daemon_cpu_s: (f64, f64),
    /// Stalls injected.
    pub stalls: Vec<Stall>,
    /// stress-ng runs started and how many ended with a failure (message of the last one).
    pub stress_runs: u32,
    /// The last stress-ng failure, if any.
    pub stress_failure: Option<String>,
}

/// A stress-ng process with its log.
struct Stress {
    m: Managed,
    log: PathBuf,
}

fn start_stress(bin: &Path, args: &[String], log: &Path) -> Result<Stress, String> {
    let m = Managed::spawn("stress-ng", bin, args, Some(log))?;
    Ok(Stress {
        m,
        log: log.to_path_buf(),
    })
}

/// How long past its phase (or burst) a stress-ng run's own `--timeout` lies: the
/// harness stops it at the phase's end, so the timeout only ends a run the harness
/// could not stop, and an exit seen before the stop is an early one.
const STRESS_MARGIN_S: f64 = 5.0;

/// Stops a stress-ng run; an error text when it had ended on its own: its timeout
/// is [`STRESS_MARGIN_S`] past its phase, so any exit before the phase ends, even
/// with status 0, means the load was not applied throughout.
fn stop_stress(mut s: Stress) -> Option<String> {
    // a stop asked of this harness (Ctrl-C, SIGTERM) ends the load early: its exit
    // is then the user's stop, not a failure of the load
    if termination_requested() {
        s.m.stop(Duration::from_secs(3));
        return None;
    }
    let failed_early = match s.m.child.try_wait() {
        Ok(Some(st)) => Some(st.to_string()),
        _ => None,
    };
    s.m.stop(Duration::from_secs(3));
    failed_early.map(|st| {
        format!(
            "stress-ng ended before its phase did ({st}): {}",
            std::fs::read_to_string(&s.log)
                .unwrap_or_default()
                .trim()
                .lines()
                .last()
                .unwrap_or("")
        )
    })
}

fn cpu_args(workers: u32, seconds: f64) -> Vec<String> {
    vec![
        "--cpu".into(),
        workers.to_string(),
        "--timeout".into(),
        format!("{}s", seconds.ceil().max(1.0) as u64),
        "--quiet".into(),
    ]
}

/// What [`run_profile`] reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum Progress<'a> {
    /// A phase starts (one line), or a warning.
    Line(&'a str),
    /// An estimate arrived.
    Estimate(&'a Received),
}

/// Polls `s` until `until` (`CLOCK_MONOTONIC`) or Ctrl-C, telling `progress` each estimate.
fn poll_until(
    s: &mut Session,
    until: Nanos,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<(), String> {
    loop {
        let now = monotonic_ns();
        if now >= until || termination_requested() {
            return Ok(());
        }
        let wait = Duration::from_nanos((until - now) as u64).min(Duration::from_millis(100));
        for r in s.poll(wait)? {
            progress(Progress::Estimate(&r));
        }
        // a process of the run that died (the daemon killed by the OOM killer in
        // the memory phase, a driver that crashed) ends the profile with its name
        // and log, instead of failing later at a phase boundary on its stale pid
        s.check_children();
        if !s.failures.is_empty() {
            return Err(format!("the run cannot go on: {}", s.failures.join("; ")));
        }
    }
}

/// Runs `profile` against a started session whose drivers start at
/// `session.start_at`: each phase begins at `start_at + Σ previous durations`.
/// Polls the session throughout and tells `progress`. Returns the phase
/// records; stops early (with what it has) on Ctrl-C.
pub fn run_profile(
    session: &mut Session,
    profile: &Profile,
    stress_ng: Option<&Path>,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<Vec<PhaseRecord>, String> {
    let stress_bin =
        || stress_ng.ok_or_else(|| format!("profile `{}` needs stress-ng", profile.name));
    let mut out = vec![];
    let mut t = session.start_at;
    for (k, ph) in profile.phases.iter().enumerate() {
        let start = t;
        let end = start + (ph.duration_s * 1e9) as Nanos;
        t = end;
        poll_until(session, start, progress)?;
        if termination_requested() {
            break;
        }
        let cpu0 = session.cpu_seconds(Role::Daemon)?;
        let line = format!(
            "phase {}/{} `{}`: {} for {} s",
            k + 1,
            profile.phases.len(),
            ph.name,
            ph.load.describe(),
            ph.duration_s
        );
        progress(Progress::Line(&line));
        let mut rec = PhaseRecord {
            phase: ph.clone(),
            start_ns: start,
            end_ns: end,
            daemon_cpu_s: (cpu0, cpu0),
            stalls: vec![],
            stress_runs: 0,
            stress_failure: None,
        };
        let log = session.log_dir.join(format!("stress-ng-{}.log", k + 1));
        match &ph.load {
            Load::Idle => poll_until(session, end, progress)?,
            Load::Cpu { workers } => {
                let s = start_stress(
                    stress_bin()?,
                    &cpu_args(*workers, ph.duration_s + STRESS_MARGIN_S),
                    &log,
                )?;
                rec.stress_runs += 1;
                poll_until(session, end, progress)?;
                rec.stress_failure = stop_stress(s);
            }
            Load::Memory { workers, bytes } => {
                let args = vec![
                    "--vm".into(),
                    workers.to_string(),
                    "--vm-bytes".into(),
                    bytes.clone(),
                    "--timeout".into(),
                    format!("{}s", (ph.duration_s + STRESS_MARGIN_S).ceil() as u64),
                    "--quiet".into(),
                ];
                let s = start_stress(stress_bin()?, &args, &log)?;
                rec.stress_runs += 1;
                poll_until(session, end, progress)?;
                rec.stress_failure = stop_stress(s);
            }
            Load::Bursts {
                workers,
                on_s,
                off_s,
            } => {
                let mut b = start;
                while b < end && !termination_requested() {
                    let on_end = (b + (on_s * 1e9) as Nanos).min(end);
                    poll_until(session, b, progress)?;
                    let s = start_stress(
                        stress_bin()?,
                        &cpu_args(*workers, *on_s + STRESS_MARGIN_S),
                        &log,
                    )?;
                    rec.stress_runs += 1;
                    poll_until(session, on_end, progress)?;
                    if let Some(f) = stop_stress(s) {
                        rec.stress_failure = Some(f);
                    }
                    b = on_end + (off_s * 1e9) as Nanos;
                }
                poll_until(session, end, progress)?;
            }
            Load::Stall {
                role,
                stop_ms,
                every_s,
            } => {
                // first stall half a period in, so stalls do not straddle phases
                let mut next = start + (every_s * 0.5e9) as Nanos;
                while next + (*stop_ms as Nanos) * 1_000_000 < end && !termination_requested() {
                    poll_until(session, next, progress)?;
                    session.signal(*role, "STOP")?;
                    let stop_ns = monotonic_ns();
                    std::thread::sleep(Duration::from_millis(*stop_ms));
                    // the stall as it happened (the sleep may overshoot under load)
                    let r = session.signal(*role, "CONT");
                    let cont_ns = monotonic_ns();
                    r?;
                    rec.stalls.push(Stall {
                        role: *role,
                        stop_ns,
                        cont_ns,
                    });
                    next += (every_s * 1e9) as Nanos;
                }
                poll_until(session, end, progress)?;
            }
        }
        if termination_requested() {
            rec.end_ns = rec.end_ns.min(monotonic_ns());
        }
        rec.daemon_cpu_s.1 = session.cpu_seconds(Role::Daemon)?;
        if let Some(f) = &rec.stress_failure {
            progress(Progress::Line(&format!("  warning: {f}")));
        }
        out.push(rec);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles_are_well_formed() {
        let all = profiles();
        for p in &all {
            assert!(!p.phases.is_empty(), "{}", p.name);
            assert_eq!(p.phases[0].load, Load::Idle, "{}: warm-up first", p.name);
            assert!(p.phases[0].duration_s >= 15.0, "{}", p.name);
            assert!(p.phases.iter().all(|ph| ph.duration_s > 0.0));
        }
        // the test suite's profile fits in a minute with start-up and shutdown
        let short = profile("short").unwrap();
        assert!(short.duration_s() <= 55.0, "{}", short.duration_s());
        assert!(short.needs_stress_ng());
        assert!(!profile("idle").unwrap().needs_stress_ng());
        let e = profile("nope").unwrap_err();
        assert!(e.contains("nope") && e.contains("steps"), "{e}");
        assert_eq!(FULL.describe(), "cpu, every core");
        assert_eq!(FULL.steady_cpu(), Some(true));
        assert_eq!(
            Load::Stall {
                role: Role::Cam,
                stop_ms: 40,
                every_s: 2.0
            }
            .steady_cpu(),
            None
        );
    }

    #[test]
    fn stress_ng_arguments() {
        assert_eq!(cpu_args(0, 20.5).join(" "), "--cpu 0 --timeout 21s --quiet");
    }
}
