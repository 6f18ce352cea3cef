//! `vlsync-demo`: the whole system live on the simulated robot. Starts
//! `vlsyncd run` and both drivers as separate processes on a unique prefix,
//! prints offset and drift beside the truth as estimates arrive, then a
//! summary: error statistics, latency percentiles from the status service, CPU
//! use and memory of each process. Ctrl-C or the end of `--duration` stops
//! every child; nothing is left in shared memory.
#![forbid(unsafe_code)]

use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};
use vlsync_common::EstimatorState;
use vlsync_ipc::{create_node, monotonic_ns, termination_requested, OffsetClient, StatusClient};
use vlsyncd::runtime::procs::{cpu_seconds, rss_kb, sibling_binary, Managed};

#[derive(Parser)]
#[command(
    name = "vlsync-demo",
    version,
    about = "Live vlsync demo on the simulated robot"
)]
struct Args {
    /// Simulated family (see `vlsync-sim --help`).
    #[arg(long, default_value = "clocks")]
    family: String,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run length, seconds.
    #[arg(long, default_value_t = 60.0)]
    duration: f64,
    /// Real-time speed factor (1 = real time).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Daemon configuration file.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Service prefix (default: `vlsync-demo/<pid>`).
    #[arg(long)]
    prefix: Option<String>,
    /// Directory for the children's logs (default: a temporary directory).
    #[arg(long)]
    log_dir: Option<PathBuf>,
    /// Print only the summary.
    #[arg(long)]
    quiet: bool,
}

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vlsync-demo: error: {e}");
            ExitCode::from(2)
        }
    }
}

struct ErrStats {
    errs: Vec<f64>,
}

impl ErrStats {
    fn summary(&self) -> String {
        if self.errs.is_empty() {
            return "no locked estimate to score".into();
        }
        let n = self.errs.len() as f64;
        let mae = self.errs.iter().map(|e| e.abs()).sum::<f64>() / n;
        let rms = (self.errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
        let max = self.errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        format!(
            "{} locked estimates: MAE {:.2} ms, RMS {:.2} ms, max {:.2} ms",
            self.errs.len(),
            mae * 1e3,
            rms * 1e3,
            max * 1e3
        )
    }
}

fn run(a: Args) -> Result<(), String> {
    if !(a.duration.is_finite() && a.duration > 0.0 && a.speed.is_finite() && a.speed > 0.0) {
        return Err("--duration and --speed must be finite numbers > 0".into());
    }
    let family: vlsync_sim::Family = a.family.parse().map_err(|e| format!("--family: {e}"))?;
    let sim = vlsync_sim::try_generate(family, a.seed, Some(a.duration))
        .map_err(|e| format!("--duration: {e}"))?;
    let prefix = a
        .prefix
        .clone()
        .unwrap_or_else(|| format!("vlsync-demo/{}", std::process::id()));
    let log_dir = a.log_dir.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("vlsync-demo-{}", std::process::id()))
    });
    std::fs::create_dir_all(&log_dir)
        .map_err(|e| format!("cannot create {}: {e}", log_dir.display()))?;
    // our own node: handles Ctrl-C for the demo
    let _node = create_node("vlsync-demo", true).map_err(|e| e.to_string())?;

    let mut dargs = vec!["run".to_string(), "--prefix".into(), prefix.clone()];
    if let Some(c) = &a.config {
        dargs.push("--config".into());
        dargs.push(c.display().to_string());
    }
    let mut daemon = Managed::spawn(
        "vlsyncd",
        &sibling_binary("vlsyncd")?,
        &dargs,
        Some(&log_dir.join("vlsyncd.log")),
    )?;
    let mut offsets = OffsetClient::open(&prefix).map_err(|e| e.to_string())?;
    let mut status = StatusClient::open(&prefix).map_err(|e| e.to_string())?;
    std::thread::sleep(Duration::from_millis(300));
    if !daemon.running() {
        return Err(format!(
            "vlsyncd exited at start; see {}",
            log_dir.join("vlsyncd.log").display()
        ));
    }
    let start_at = monotonic_ns() + 500_000_000;
    let common = || -> Vec<String> {
        vec![
            "--prefix".into(),
            prefix.clone(),
            "--sim".into(),
            family.name().into(),
            "--seed".into(),
            a.seed.to_string(),
            "--duration".into(),
            a.duration.to_string(),
            "--speed".into(),
            a.speed.to_string(),
            "--start-at".into(),
            start_at.to_string(),
        ]
    };
    let mut cam = Managed::spawn(
        "vlsync-cam",
        &sibling_binary("vlsync-cam")?,
        &common(),
        Some(&log_dir.join("vlsync-cam.log")),
    )?;
    let mut lidar = Managed::spawn(
        "vlsync-lidar",
        &sibling_binary("vlsync-lidar")?,
        &common(),
        Some(&log_dir.join("vlsync-lidar.log")),
    )?;
    println!(
        "vlsync-demo: {} seed {} for {} s at {}x on prefix `{prefix}` (logs in {})",
        family.name(),
        a.seed,
        a.duration,
        a.speed,
        log_dir.display()
    );
    if !a.quiet {
        println!(
            "{:>8} {:>10} {:>11} {:>11} {:>9} {:>10} {:>10}",
            "t_ref s", "state", "offset ms", "truth ms", "err ms", "±1σ ms", "drift ppm"
        );
    }
    let wall = Duration::from_secs_f64(a.duration / a.speed + 1.5);
    let t0 = Instant::now();
    let mut stats = ErrStats { errs: vec![] };
    let mut interrupted = false;
    // (name, cpu s, rss kB, wall s when read): refreshed while each process lives
    let mut usage: Vec<(String, Option<f64>, Option<u64>, f64)> = [&daemon, &cam, &lidar]
        .iter()
        .map(|m| (m.name.clone(), None, None, 0.0))
        .collect();
    let mut last_usage = Instant::now() - Duration::from_secs(1);
    while t0.elapsed() < wall {
        if last_usage.elapsed() >= Duration::from_millis(500) {
            last_usage = Instant::now();
            for (u, m) in usage.iter_mut().zip([&daemon, &cam, &lidar]) {
                if let (Ok(c), Ok(r)) = (cpu_seconds(m.pid()), rss_kb(m.pid())) {
                    *u = (m.name.clone(), Some(c), Some(r), t0.elapsed().as_secs_f64());
                }
            }
        }
        if termination_requested() {
            interrupted = true;
            break;
        }
        if let Some(e) = offsets
            .wait_next(Duration::from_millis(200))
            .map_err(|e| e.to_string())?
        {
            let truth = sim.truth.offset_at(e.t_ref_ns);
            let err = e.offset_s - truth;
            let locked = matches!(e.state, EstimatorState::Tracking | EstimatorState::Holding);
            if locked {
                stats.errs.push(err);
            }
            if !a.quiet {
                println!(
                    "{:>8.2} {:>10} {:>+11.2} {:>+11.2} {:>+9.2} {:>10.2} {:>+10.1}",
                    e.t_ref_ns as f64 * 1e-9,
                    e.state.name(),
                    e.offset_s * 1e3,
                    truth * 1e3,
                    err * 1e3,
                    e.offset_std_s * 1e3,
                    e.drift * 1e6
                );
            }
        }
        if !cam.running() && !lidar.running() && t0.elapsed() > Duration::from_secs(1) {
            // both drivers finished their run
            std::thread::sleep(Duration::from_millis(300));
            break;
        }
    }
    // measure the daemon once more before stopping
    if let (Ok(c), Ok(r)) = (cpu_seconds(daemon.pid()), rss_kb(daemon.pid())) {
        usage[0] = (
            daemon.name.clone(),
            Some(c),
            Some(r),
            t0.elapsed().as_secs_f64(),
        );
    }
    std::thread::sleep(Duration::from_millis(200));
    let st = status.latest().map_err(|e| e.to_string())?;
    let clean = [
        cam.stop(Duration::from_secs(3)),
        lidar.stop(Duration::from_secs(3)),
        daemon.stop(Duration::from_secs(3)),
    ];

    println!(
        "\n=== summary{} ===",
        if interrupted { " (interrupted)" } else { "" }
    );
    println!("accuracy: {}", stats.summary());
    println!(
        "truth: offset {:.2} ms at start, drift {:.1} ppm, {} step(s); CRB of the run {:.3} ms",
        sim.truth.offset_0_ms(),
        sim.truth.drift * 1e6,
        sim.truth.steps.len(),
        sim.crb_std_s * 1e3
    );
    match st {
        Some(s) => {
            println!(
                "daemon: received cam {} lidar {}, lost cam {} lidar {}, rejected cam {} lidar {}, {} estimates, {} budget overruns",
                s.received[0], s.received[1], s.lost[0], s.lost[1], s.rejected_total(0), s.rejected_total(1),
                s.estimates_published, s.budget_overruns
            );
            println!(
                "latency: processing p50 {:.1} µs p99 {:.1} µs max {:.1} µs; driver->daemon done p50 {:.1} µs p99 {:.1} µs max {:.1} µs ({} samples)",
                s.processing_ns[0] as f64 / 1e3, s.processing_ns[1] as f64 / 1e3, s.processing_ns[2] as f64 / 1e3,
                s.end_to_end_ns[0] as f64 / 1e3, s.end_to_end_ns[1] as f64 / 1e3, s.end_to_end_ns[2] as f64 / 1e3,
                s.latency_count
            );
        }
        None => println!("daemon: no status received"),
    }
    for (name, cpu, rss, elapsed) in usage {
        println!(
            "{name:>12}: CPU {} over {elapsed:.1} s wall, RSS {}",
            cpu.map_or("?".into(), |c| format!(
                "{:.2} s ({:.2} % of a core)",
                c,
                100.0 * c / elapsed.max(1e-3)
            )),
            rss.map_or("?".into(), |r| format!("{:.1} MB", r as f64 / 1024.0))
        );
    }
    println!(
        "children stopped {}",
        if clean.iter().all(|c| *c) {
            "cleanly"
        } else {
            "(some needed SIGKILL)"
        }
    );
    Ok(())
}

trait OffsetMs {
    fn offset_0_ms(&self) -> f64;
}

impl OffsetMs for vlsync_sim::Truth {
    fn offset_0_ms(&self) -> f64 {
        self.offset_at(0) * 1e3
    }
}
