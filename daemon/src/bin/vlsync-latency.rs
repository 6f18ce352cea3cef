//! `vlsync-latency`: latency and cost benchmark of the full path
//! (driver process -> iceoryx2 -> `vlsyncd run` -> estimate published).
//!
//! Phase 1 replays the simulated robot at 100x real time (3000 cam + 1000
//! LiDAR samples per second; 10,000+ samples) on a fresh daemon and reads the
//! daemon's own latency histograms and loss counters from the status service.
//! Phase 2 runs the nominal rates (30 Hz cam + 10 Hz LiDAR) and measures the
//! daemon's CPU use from `/proc`. Finally the daemon's resident memory.
//! Prints each figure beside its target and exits non-zero when one is missed
//! (with `--check`).
#![forbid(unsafe_code)]

use clap::Parser;
use std::process::ExitCode;
use std::time::{Duration, Instant};
use vlsync_ipc::{create_node, monotonic_ns, termination_requested, StatusClient};
use vlsync_sim::families::{MAX_DURATION_S, MIN_DURATION_S};
use vlsyncd::harness::{check_arg, MAX_SPEED, MIN_SPEED};
use vlsyncd::runtime::procs::{
    cpu_seconds, describe_rt_thread, rss_kb, sibling_binary, thread_sched, Managed,
};
use vlsyncd::runtime::RT_THREAD_NAME;

#[derive(Parser)]
#[command(
    name = "vlsync-latency",
    version,
    about = "Latency, loss, CPU and memory of the vlsync path"
)]
struct Args {
    /// Simulated seconds replayed at 100x (300 s = 12,000 samples).
    #[arg(long, allow_negative_numbers = true, default_value_t = 300.0)]
    fast_sim_s: f64,
    /// Speed factor of the fast phase.
    #[arg(long, allow_negative_numbers = true, default_value_t = 100.0)]
    speed: f64,
    /// Wall seconds of the nominal-rate phase.
    #[arg(long, allow_negative_numbers = true, default_value_t = 20.0)]
    nominal_s: f64,
    /// Daemon configuration file (e.g. with `daemon.fifo_priority` set).
    #[arg(long)]
    config: Option<std::path::PathBuf>,
    /// Exit with status 1 when a target is missed.
    #[arg(long)]
    check: bool,
}

struct Targets;
impl Targets {
    const P99_NS: u64 = 50_000;
    const CPU_NOMINAL_PCT: f64 = 1.0;
    const RSS_KB: u64 = 20 * 1024;
}

fn spawn_drivers(
    prefix: &str,
    seed: u64,
    duration: f64,
    speed: f64,
) -> Result<(Managed, Managed), String> {
    let start_at = monotonic_ns() + 300_000_000;
    let args = |_: &str| -> Vec<String> {
        vec![
            "--prefix".into(),
            prefix.into(),
            "--sim".into(),
            "robot".into(),
            "--seed".into(),
            seed.to_string(),
            "--duration".into(),
            duration.to_string(),
            "--speed".into(),
            speed.to_string(),
            "--start-at".into(),
            start_at.to_string(),
        ]
    };
    let null = std::path::Path::new("/dev/null");
    let cam = Managed::spawn(
        "vlsync-cam",
        &sibling_binary("vlsync-cam")?,
        &args("cam"),
        Some(null),
    )?;
    let lidar = Managed::spawn(
        "vlsync-lidar",
        &sibling_binary("vlsync-lidar")?,
        &args("lidar"),
        Some(null),
    )?;
    Ok((cam, lidar))
}

/// Waits until both drivers have ended; an error when the daemon ends first (its
/// status then never comes: the cause is its exit, and its log).
fn wait_drivers(
    cam: &mut Managed,
    lidar: &mut Managed,
    daemon: &mut Managed,
    limit: Duration,
) -> Result<(), String> {
    let t0 = Instant::now();
    while cam.running() || lidar.running() {
        if termination_requested() {
            return Err("interrupted".into());
        }
        if let Some(st) = daemon.wait_up_to(Duration::ZERO) {
            return Err(format!(
                "vlsyncd ended during the run ({})",
                vlsyncd::runtime::procs::describe_exit(st)
            ));
        }
        if t0.elapsed() > limit {
            return Err(format!("drivers still running after {limit:?}"));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

/// A status published after the first one seen: the counters of every sample sent
/// so far. The daemon publishes one every `period_s` (`daemon.status_period_s`).
fn latest_status(
    c: &mut StatusClient,
    period_s: f64,
) -> Result<vlsync_common::wire::Status, String> {
    let limit = Duration::from_secs_f64((2.0 * period_s + 1.0).max(3.0));
    let t0 = Instant::now();
    let mut first = None;
    while t0.elapsed() < limit {
        if let Some(s) = c.latest().map_err(|e| e.to_string())? {
            match first {
                None => first = Some(s.publish_ns),
                Some(p) if s.publish_ns > p => return Ok(s),
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Err(format!(
        "no fresh status from the daemon within {:.0} s (daemon.status_period_s = {period_s} s)",
        limit.as_secs_f64()
    ))
}

fn us(ns: u64) -> String {
    format!("{:.1} µs", ns as f64 / 1e3)
}

/// Checks the arguments before any process is started or file written: the
/// durations are the drivers' `--duration` of the signature simulator.
fn check_args(a: &Args) -> Result<(), String> {
    check_arg("--fast-sim-s", a.fast_sim_s, MIN_DURATION_S, MAX_DURATION_S)?;
    check_arg("--speed", a.speed, MIN_SPEED, MAX_SPEED)?;
    check_arg("--nominal-s", a.nominal_s, MIN_DURATION_S, MAX_DURATION_S)?;
    if let Some(c) = &a.config {
        let cfg = vlsync_config::Config::load(c).map_err(|e| format!("--config: {e}"))?;
        // the percentiles are read from one status after the fast phase: per period,
        // they would cover only the last period (often no sample at all, 0 µs)
        if cfg.daemon.latency_per_period {
            return Err(format!(
                "--config {}: daemon.latency_per_period = true: the benchmark reads the latency percentiles over the whole run from the daemon's status; set it to false",
                c.display()
            ));
        }
    }
    Ok(())
}

fn run(a: &Args) -> Result<bool, String> {
    check_args(a)?;
    let _node = create_node("vlsync-latency", true).map_err(|e| e.to_string())?;
    let prefix = format!("vlsync-latency/{}", std::process::id());
    let mut dargs = vec!["run".to_string(), "--prefix".into(), prefix.clone()];
    if let Some(c) = &a.config {
        dargs.push("--config".into());
        dargs.push(c.display().to_string());
    }
    let daemon_bin = sibling_binary("vlsyncd")?;
    let log = std::env::temp_dir().join(format!("vlsync-latency-{}.log", std::process::id()));
    // the daemon is stopped by now (`Managed`'s drop); its log stays for an error
    measure(a, &prefix, &daemon_bin, &dargs, &log)
        .map_err(|e| format!("{e} (daemon log: {})", log.display()))
}

/// Both phases on a daemon logging to `log` (removed after a clean run, kept
/// otherwise).
fn measure(
    a: &Args,
    prefix: &str,
    daemon_bin: &std::path::Path,
    dargs: &[String],
    log: &std::path::Path,
) -> Result<bool, String> {
    // stdout through `Out`: a reader that went away (`| head`) ends the output, not the run
    let mut out = vlsyncd::harness::console::Out::new();
    let mut daemon = Managed::spawn("vlsyncd", daemon_bin, dargs, Some(log))?;
    let mut status = StatusClient::open(prefix).map_err(|e| e.to_string())?;
    match daemon.wait_for_log(log, "serving prefix", Duration::from_secs(10)) {
        Ok(true) => {}
        Ok(false) => return Err("vlsyncd did not serve within 10 s".into()),
        Err(said) => return Err(format!("vlsyncd exited at start: {}", said.trim())),
    }

    // what the daemon was asked for: the configuration `vlsyncd run` computes
    let asked = vlsyncd::runtime::load_config(&vlsyncd::runtime::RunArgs {
        config: a.config.clone(),
        ..Default::default()
    })
    .map_err(|e| format!("--config: {e}"))?
    .daemon;

    // ---- phase 1: 100x ----
    let cpu0 = cpu_seconds(daemon.pid())?;
    let t0 = Instant::now();
    let (mut cam, mut lidar) = spawn_drivers(prefix, 1, a.fast_sim_s, a.speed)?;
    wait_drivers(
        &mut cam,
        &mut lidar,
        &mut daemon,
        Duration::from_secs_f64(a.fast_sim_s / a.speed + 20.0),
    )?;
    let fast_wall = t0.elapsed().as_secs_f64();
    // the real-time thread serves by now: what the kernel gave it
    let rt = describe_rt_thread(
        &thread_sched(daemon.pid(), RT_THREAD_NAME),
        asked.fifo_priority,
        asked.core,
        log,
    );
    let fast_cpu = cpu_seconds(daemon.pid())? - cpu0;
    let s1 = latest_status(&mut status, asked.status_period_s)?;
    let received = s1.received[0].saturating_add(s1.received[1]);
    let lost = s1.lost[0].saturating_add(s1.lost[1]);
    out.line(format_args!("daemon's real-time thread: {rt}"));
    out.line(format_args!(
        "phase 1: {}x real time, {received} samples through driver -> daemon -> estimate",
        a.speed
    ));
    out.line(format_args!(
        "  end-to-end (driver publish -> daemon done, estimate published when due): p50 {} p99 {} max {}",
        us(s1.end_to_end_ns[0]),
        us(s1.end_to_end_ns[1]),
        us(s1.end_to_end_ns[2])
    ));
    out.line(format_args!(
        "  processing in the daemon: p50 {} p99 {} max {}; {} budget overruns; {} estimates",
        us(s1.processing_ns[0]),
        us(s1.processing_ns[1]),
        us(s1.processing_ns[2]),
        s1.budget_overruns,
        s1.estimates_published
    ));
    out.line(format_args!(
        "  lost {lost} (cam {} lidar {}), rejected {}; daemon CPU {:.1} % of a core over {:.1} s",
        s1.lost[0],
        s1.lost[1],
        s1.rejected_total(0).saturating_add(s1.rejected_total(1)),
        100.0 * fast_cpu / fast_wall,
        fast_wall
    ));

    // ---- phase 2: nominal rates ----
    let cpu0 = cpu_seconds(daemon.pid())?;
    let t0 = Instant::now();
    let (mut cam, mut lidar) = spawn_drivers(prefix, 2, a.nominal_s, 1.0)?;
    wait_drivers(
        &mut cam,
        &mut lidar,
        &mut daemon,
        Duration::from_secs_f64(a.nominal_s + 20.0),
    )?;
    let nom_wall = t0.elapsed().as_secs_f64();
    let nom_cpu = cpu_seconds(daemon.pid())? - cpu0;
    let nom_pct = 100.0 * nom_cpu / nom_wall;
    let rss = rss_kb(daemon.pid())?;
    out.line(format_args!(
        "phase 2: nominal 30 Hz + 10 Hz for {nom_wall:.1} s: daemon CPU {nom_cpu:.3} s = {nom_pct:.2} % of a core"
    ));
    out.line(format_args!(
        "daemon resident memory (VmRSS): {:.1} MB",
        rss as f64 / 1024.0
    ));
    let clean = daemon.stop(Duration::from_secs(3));
    if clean {
        let _ = std::fs::remove_file(log);
    } else {
        out.line(format_args!("daemon log kept in {}", log.display()));
    }

    let checks = [
        (
            "p99 end-to-end <= 50 µs",
            // over the samples of the run: an empty histogram's percentiles are 0
            s1.latency_count >= 10_000 && s1.end_to_end_ns[1] <= Targets::P99_NS,
        ),
        ("zero lost at 100x", lost == 0),
        ("10,000+ samples", received >= 10_000),
        (
            "CPU < 1 % of a core at nominal",
            nom_pct < Targets::CPU_NOMINAL_PCT,
        ),
        ("RSS <= 20 MB", rss <= Targets::RSS_KB),
        ("daemon stopped cleanly", clean),
    ];
    let mut ok = true;
    for (what, pass) in checks {
        out.line(format_args!(
            "  [{}] {what}",
            if pass { "PASS" } else { "MISS" }
        ));
        ok &= pass;
    }
    Ok(ok)
}

fn main() -> ExitCode {
    let a = Args::parse();
    match run(&a) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) if a.check => ExitCode::from(1),
        Ok(false) => ExitCode::SUCCESS,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-latency: error: {e}\n"));
            ExitCode::from(2)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(extra: &[&str]) -> Result<Args, clap::Error> {
        Args::try_parse_from(["vlsync-latency"].iter().chain(extra))
    }

    #[test]
    fn bad_numbers_are_refused_naming_the_flag() {
        assert!(check_args(&args(&[]).unwrap()).is_ok());
        for (argv, flag) in [
            (&["--speed", "0"][..], "--speed"),
            (&["--speed=-1"][..], "--speed"),
            (&["--speed", "inf"][..], "--speed"),
            (&["--fast-sim-s", "nan"][..], "--fast-sim-s"),
            (&["--fast-sim-s", "1e9"][..], "--fast-sim-s"),
            (&["--nominal-s=-30"][..], "--nominal-s"),
            (&["--nominal-s", "0"][..], "--nominal-s"),
        ] {
            let e = check_args(&args(argv).unwrap()).unwrap_err();
            assert!(e.starts_with(&format!("{flag} ")), "{argv:?}: {e}");
            assert!(e.contains("out of range"), "{e}");
        }
        // a configuration whose status percentiles cover only the last period
        let dir = std::env::temp_dir().join(format!("vlsync-latency-args-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let per_period = dir.join("per-period.toml");
        std::fs::write(&per_period, "[daemon]\nlatency_per_period = true\n").unwrap();
        let e =
            check_args(&args(&["--config", per_period.to_str().unwrap()]).unwrap()).unwrap_err();
        assert!(
            e.starts_with("--config ") && e.contains("daemon.latency_per_period = true"),
            "{e}"
        );
        std::fs::write(&per_period, "[daemon]\nlatency_per_period = false\n").unwrap();
        assert!(check_args(&args(&["--config", per_period.to_str().unwrap()]).unwrap()).is_ok());
        let _ = std::fs::remove_dir_all(&dir);
        let e = check_args(&args(&["--config", "/nonexistent/vlsync.toml"]).unwrap()).unwrap_err();
        assert!(
            e.contains("--config") && e.contains("/nonexistent/vlsync.toml"),
            "{e}"
        );
    }
}
