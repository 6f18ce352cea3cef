//! `vlsync-demo`: the whole system live. Starts `vlsyncd run` and both drivers
//! as separate processes on a unique prefix (by default on the rendering
//! simulator: rendered frames and scans through the real front-ends; with
//! `--family` on the signature simulator), prints offset and drift beside the
//! truth as estimates arrive, then a summary: error statistics, convergence,
//! latency percentiles from the status service, CPU use and memory of each
//! process, and a plot of the estimates against the truth (`--plot`, by default
//! `demo.svg` in the log directory). Ctrl-C or the end of `--duration` stops every
//! child; nothing is left in shared memory. The orchestration is
//! `vlsyncd::harness::session`.
#![forbid(unsafe_code)]

use clap::Parser;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;
use vlsync_common::{Estimate, EstimatorState, Nanos};
use vlsync_ipc::termination_requested;
use vlsyncd::harness::console::Out;
use vlsyncd::harness::session::{
    counters_line, stop_words, ProcessArgs, Received, Role, Session, Source, Stamping,
};
use vlsyncd::harness::stats::{ErrorStats, Periods};
use vlsyncd::harness::{check_arg, MAX_SPEED, MIN_SPEED};
use vlsyncd::runtime::procs::describe_rt_thread;

#[derive(Parser)]
#[command(
    name = "vlsync-demo",
    version,
    about = "Live vlsync demo: daemon and both drivers on rendered frames and scans (or the signature simulator)"
)]
struct Args {
    /// Run the signature-level simulator of this family instead of the
    /// rendering simulator (see `vlsync-sim --list`).
    #[arg(long)]
    family: Option<String>,
    /// Seed of the run.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed: u64,
    /// Run length, seconds.
    #[arg(long, allow_negative_numbers = true, default_value_t = 60.0)]
    duration: f64,
    /// Real-time speed factor (1 = real time).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.0)]
    speed: f64,
    #[command(flatten)]
    procs: ProcessArgs,
    /// SCHED_FIFO priority of the daemon's real-time thread, 0-99 (0: the normal
    /// scheduler). Default: 50 (a robot's daemon runs under SCHED_FIFO too, see
    /// deploy/vlsync.toml), unless --config is given, whose `daemon.fifo_priority` then
    /// holds. Where the system refuses it, the daemon runs on the normal scheduler; the
    /// summary says which it got.
    #[arg(long, allow_negative_numbers = true, value_parser = clap::value_parser!(i64).range(0..=99))]
    fifo: Option<i64>,
    /// Print only the summary.
    #[arg(long)]
    quiet: bool,
    /// Rendered run: the LiDAR front-end fits only the wall ahead. By default the demo
    /// also fits the wall behind (`lidar.opposite_window`: the rendered room has a wall
    /// at each end), which halves the LiDAR signature's noise variance.
    #[arg(long)]
    front_wall_only: bool,
    /// Rendered run: the camera's frame rate, Hz (default 30). 2.67 <= HZ < 125: frames
    /// at most half the estimator's `max_gap_s` (0.75 s) apart, and the frame's 8 ms
    /// exposure within its period.
    #[arg(long, allow_negative_numbers = true, value_name = "HZ")]
    render_fps: Option<f64>,
    /// Rendered run: the LiDAR's revolutions a second, Hz (default 10, an LD06's).
    /// 2.67 ..= 100.
    #[arg(long, allow_negative_numbers = true, value_name = "HZ")]
    render_lidar_hz: Option<f64>,
    /// On long runs, a summary line every this many seconds of reference time (error,
    /// states, the σ's honesty, drift against the truth), with `--quiet` too; 0: none.
    #[arg(long, allow_negative_numbers = true, default_value_t = 300.0)]
    summary_every: f64,
    /// Where to write the plot of the estimates (±2σ, raw measurements) against the
    /// truth, SVG (default: `demo.svg` in the log directory).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Record the run into this directory as `vlsyncd record` does (cam.csv, lidar.csv,
    /// est.csv), with the truth (truth.csv), for `vlsyncd replay --truth --compare`.
    #[arg(long)]
    record: Option<PathBuf>,
    /// With `--record`: write over a recording already in that directory.
    #[arg(long, requires = "record")]
    force: bool,
}

/// The daemon's SCHED_FIFO priority when neither --fifo nor --config is given: the
/// real-time thread preempts the renderer and the drivers as on a robot, where the
/// rendered camera's 15-20 % of a core would otherwise delay a sample by up to a
/// scheduler slice (driver to daemon done on this 2-core machine: max 4.8-5.5 ms, p99 up
/// to 4.7 ms; with it 0.28-0.48 ms and 0.20-0.21 ms; README, "The two commands").
const DEMO_FIFO_PRIORITY: i64 = 50;

/// The truth file `--record` adds to the recording.
const TRUTH_FILE: &str = "truth.csv";

/// Error bound of the convergence figure (issue 3: within 3 ms in 15 s).
const CONVERGED_S: f64 = 0.003;

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-demo: error: {e}\n"));
            ExitCode::from(2)
        }
    }
}

/// The `vlsyncd run --fifo-priority` of the demo: `--fifo`'s, else [`DEMO_FIFO_PRIORITY`]
/// without --config; `None` leaves it to the configuration.
fn daemon_fifo(a: &Args) -> Option<i64> {
    a.fifo
        .or(a.procs.config.is_none().then_some(DEMO_FIFO_PRIORITY))
}

fn locked(r: &Received) -> bool {
    matches!(
        r.est.state,
        EstimatorState::Tracking | EstimatorState::Holding
    )
}

/// When the run converged, in wall seconds after the drivers' start.
#[derive(Debug, PartialEq)]
struct Convergence {
    /// The first locked estimate.
    first_lock: Option<f64>,
    /// The first locked estimate within [`CONVERGED_S`] of the truth.
    first_within: Option<f64>,
    /// The first estimate from which every later one is locked and within
    /// [`CONVERGED_S`]: an estimate that is not locked after the first lock (a lock
    /// lost, acquiring again) breaks it as one off the truth does.
    stays: Option<f64>,
}

impl Convergence {
    /// From `(seconds, locked and within CONVERGED_S, locked)` of every estimate in
    /// publish order.
    fn of(estimates: impl Iterator<Item = (f64, bool, bool)>) -> Self {
        let after_lock: Vec<(f64, bool, bool)> = estimates.skip_while(|e| !e.2).collect();
        let first_lock = after_lock.first().map(|e| e.0);
        let first_within = after_lock.iter().find(|e| e.1).map(|e| e.0);
        let stays = after_lock
            .iter()
            .rposition(|e| !e.1)
            .map_or(first_lock, |i| after_lock.get(i + 1).map(|e| e.0));
        Self {
            first_lock,
            first_within,
            stays,
        }
    }
}

/// The rendered sensors' rates the command line asks for.
fn render_rates(a: &Args) -> vlsync_driver::raw::RenderRates {
    vlsync_driver::raw::RenderRates {
        cam_fps: a.render_fps,
        lidar_hz: a.render_lidar_hz,
    }
}

/// Checks the numeric arguments before anything is started or created.
fn check_args(a: &Args) -> Result<(), String> {
    // the signature simulator runs 2 s at least, the rendering simulator 1 s
    let min_s = if a.family.is_some() {
        vlsync_sim::families::MIN_DURATION_S
    } else {
        1.0
    };
    check_arg(
        "--duration",
        a.duration,
        min_s,
        vlsync_sim::families::MAX_DURATION_S,
    )?;
    check_arg("--speed", a.speed, MIN_SPEED, MAX_SPEED)?;
    let rendered_only = [
        ("--front-wall-only", a.front_wall_only),
        ("--render-fps", a.render_fps.is_some()),
        ("--render-lidar-hz", a.render_lidar_hz.is_some()),
    ];
    if let (Some(f), Some((name, _))) = (&a.family, rendered_only.iter().find(|o| o.1)) {
        return Err(format!(
            "{name} applies to the rendered run only, not to --family {f} (the signature \
             simulator has no front-ends and its family sets its rates)"
        ));
    }
    // as the drivers will check them (they run without --config)
    render_rates(a).check(
        vlsync_config::Config::default().estimator.max_gap_s,
        "the drivers' default",
    )?;
    if a.summary_every != 0.0 {
        check_arg(
            "--summary-every",
            a.summary_every,
            1.0,
            vlsync_sim::families::MAX_DURATION_S,
        )
        .map_err(|e| format!("{e} (or 0: no summary lines)"))?;
    }
    if let Some(p) = &a.plot {
        // before the run, so that a typo does not cost it
        vlsync_common::file::check_writable("--plot", p)?;
    }
    if let Some(dir) = a.record.as_ref().filter(|_| !a.force) {
        let files = vlsyncd::record::FILES.iter().chain([&TRUTH_FILE]);
        if let Some(f) = files.map(|f| dir.join(f)).find(|f| f.exists()) {
            return Err(format!(
                "--record {}: {} exists: refusing to overwrite a recording (give another directory, or --force)",
                dir.display(),
                f.display()
            ));
        }
    }
    Ok(())
}

/// Truth sampled every 50 ms over the run, for the plot.
fn truth_points(truth: &vlsync_sim::Truth) -> Vec<(Nanos, f64)> {
    (0..)
        .map(|i: i64| i * 50_000_000)
        .take_while(|t| *t <= truth.end_ns)
        .map(|t| (t, truth.offset_at(t)))
        .collect()
}

/// Adds the truth to the recording in `dir` and says how to replay it.
fn record_truth(
    dir: &Path,
    truth: &vlsync_sim::Truth,
    config: Option<&Path>,
    recorder_log: &Path,
    out: &mut Out,
) -> Result<(), String> {
    let path = dir.join(TRUTH_FILE);
    vlsync_sim::io::write_truth_csv(&path, truth).map_err(|e| e.to_string())?;
    let d = dir.display();
    out.line(format_args!(
        "recorded: {d}/{{cam,lidar,est,truth}}.csv (the recorder's summary: {}); replay it: \
         vlsyncd replay --cam {d}/cam.csv --lidar {d}/lidar.csv --out {d}/replayed.csv \
         --truth {d}/truth.csv --compare {d}/est.csv{}",
        recorder_log.display(),
        config.map_or(String::new(), |c| format!(" --config {}", c.display()))
    ));
    Ok(())
}

fn run(a: Args) -> Result<(), String> {
    check_args(&a)?;
    if let (Some(dir), true) = (&a.record, a.force) {
        // the recorder writes over cam, lidar and est; an earlier run's truth must not
        // stay beside them if this run ends before it writes its own
        let truth = dir.join(TRUTH_FILE);
        match std::fs::remove_file(&truth) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(format!(
                    "--record --force: cannot remove {}: {e}",
                    truth.display()
                ))
            }
            _ => {}
        }
    }
    let mut out = Out::new();
    let source = match &a.family {
        Some(f) => Source::Sim {
            family: f.parse().map_err(|e| format!("--family: {e}"))?,
            seed: a.seed,
            duration_s: a.duration,
            speed: a.speed,
        },
        None => Source::Render {
            seed: a.seed,
            duration_s: a.duration,
            speed: a.speed,
            stamping: Stamping::Sensor,
            opposite_window: !a.front_wall_only,
            rates: render_rates(&a),
        },
    };
    let truth = source
        .known_truth()?
        .ok_or("the demo's sources have a known truth")?;
    let mut options = a
        .procs
        .session_options("vlsync-demo", source, Duration::from_millis(1500));
    options.record = a.record.clone();
    options.record_force = a.force;
    options.daemon_fifo_priority = daemon_fifo(&a);
    // what the daemon was asked for: the configuration `vlsyncd run` computes
    let daemon_cfg = vlsyncd::runtime::load_config(&vlsyncd::runtime::RunArgs {
        config: a.procs.config.clone(),
        prefix: None,
        fifo_priority: options.daemon_fifo_priority,
    })
    .map_err(|e| format!("--config: {e}"))?;
    if a.procs.config.is_some() && a.family.is_none() {
        // the daemon's estimator must be able to use the rendered streams too
        render_rates(&a).check(daemon_cfg.estimator.max_gap_s, "as --config sets it")?;
    }
    let mut s = Session::start(options)?;
    out.line(format_args!(
        "vlsync-demo: {} on prefix `{}` (logs in {})",
        s.source.describe(),
        s.prefix,
        s.log_dir.display()
    ));
    if !a.quiet {
        out.line(format_args!(
            "{:>8} {:>10} {:>11} {:>11} {:>9} {:>10} {:>10} {:>10}",
            "t_ref s",
            "state",
            "offset ms",
            "truth ms",
            "err ms",
            "±1σ ms",
            "drift ppm",
            "truth ppm"
        ));
    }
    let mut periods = (a.summary_every > 0.0).then(|| Periods::new(a.summary_every));
    let mut period_lines = 0usize;
    let end = s.end_ns() + 1_500_000_000;
    let mut interrupted = false;
    while vlsync_ipc::monotonic_ns() < end {
        // Ctrl-C, or nobody reads the output any more (`| head`): stop the run
        if termination_requested() || out.closed() {
            interrupted = true;
            break;
        }
        for r in s.poll(Duration::from_millis(200))? {
            let e = &r.est;
            let t = truth.offset_at(e.t_ref_ns);
            if !a.quiet {
                out.line(format_args!(
                    "{:>8.2} {:>10} {:>+11.2} {:>+11.2} {:>+9.2} {:>10.2} {:>+10.1} {:>+10.1}",
                    e.t_ref_ns as f64 * 1e-9,
                    e.state.name(),
                    e.offset_s * 1e3,
                    t * 1e3,
                    (e.offset_s - t) * 1e3,
                    e.offset_std_s * 1e3,
                    e.drift * 1e6,
                    truth.drift * 1e6
                ));
            }
            if let Some(done) = periods.as_mut().and_then(|p| p.add(e, t)) {
                out.line(format_args!("{}", done.describe(truth.drift)));
                period_lines += 1;
            }
        }
        if s.check_children() || !s.failures.is_empty() {
            // a process of the run died (a crash, someone's kill): the run cannot
            // show what it was for; say so and stop the others
            for f in &s.failures {
                out.line(format_args!("ended during the run: {f}"));
            }
            break;
        }
        if s.drivers_done() {
            // both drivers finished their run: the last estimates follow shortly
            s.poll(Duration::from_millis(300))?;
            break;
        }
    }
    // the last period too, unless it would repeat the summary below
    if let Some(last) = periods.as_mut().and_then(Periods::finish) {
        if period_lines > 0 {
            out.line(format_args!("{}", last.describe(truth.drift)));
        }
    }
    let clean = s.stop()?;
    interrupted |= termination_requested();

    let errs: Vec<f64> = s
        .estimates
        .iter()
        .filter(|r| locked(r))
        .map(|r| r.est.offset_s - truth.offset_at(r.est.t_ref_ns))
        .collect();
    out.line(format_args!(
        "\n=== summary{} ===",
        if interrupted { " (interrupted)" } else { "" }
    ));
    out.line(format_args!(
        "accuracy: {}",
        ErrorStats::of(&errs).describe()
    ));
    let conv = Convergence::of(s.estimates.iter().map(|r| {
        (
            (r.publish_ns - s.start_at) as f64 * 1e-9,
            locked(r) && (r.est.offset_s - truth.offset_at(r.est.t_ref_ns)).abs() <= CONVERGED_S,
            locked(r),
        )
    }));
    let (first_lock, first_within, stays) = (conv.first_lock, conv.first_within, conv.stays);
    let secs = |v: Option<f64>| v.map_or("never".to_string(), |v| format!("{v:.1} s"));
    out.line(format_args!(
        "convergence (wall time after the drivers' start): first lock {}, first estimate within {:.0} ms {}, within {:.0} ms from then on {}",
        secs(first_lock),
        CONVERGED_S * 1e3,
        secs(first_within),
        CONVERGED_S * 1e3,
        secs(stays)
    ));
    out.line(format_args!(
        "truth: offset {:.2} ms at start, drift {:.1} ppm, {} step(s)",
        truth.offset_at(0) * 1e3,
        truth.drift * 1e6,
        truth.steps.len()
    ));
    match s.last_status() {
        Some(st) => {
            out.line(format_args!("{}", counters_line(st)));
            // with `daemon.latency_per_period` (a --config's) the daemon's status
            // holds the last status period's percentiles, not the run's
            let over = if daemon_cfg.daemon.latency_per_period {
                "the last status period's"
            } else {
                "the whole run's"
            };
            out.line(format_args!(
                "latency ({over}): processing p50 {:.1} µs p99 {:.1} µs max {:.1} µs; driver->daemon done p50 {:.1} µs p99 {:.1} µs max {:.1} µs ({} samples)",
                st.processing_ns[0] as f64 / 1e3, st.processing_ns[1] as f64 / 1e3, st.processing_ns[2] as f64 / 1e3,
                st.end_to_end_ns[0] as f64 / 1e3, st.end_to_end_ns[1] as f64 / 1e3, st.end_to_end_ns[2] as f64 / 1e3,
                st.latency_count
            ));
        }
        None => {
            out.line(format_args!("daemon: no status received"));
        }
    }
    out.line(format_args!(
        "daemon's real-time thread: {}",
        describe_rt_thread(
            &s.daemon_rt,
            daemon_cfg.daemon.fifo_priority,
            daemon_cfg.daemon.core,
            &s.log_dir.join("vlsyncd.log")
        )
    ));
    for r in Role::ALL {
        out.line(format_args!("{:>12}: {}", r.name(), s.usage(r).describe()));
    }
    if let Some(l) = vlsyncd::harness::session::missed_line(&s) {
        out.line(format_args!("{l}"));
    }
    if s.implausible > 0 {
        out.line(format_args!(
            "left out: {} estimate(s) with times no daemon publishes (another publisher on `{}`?)",
            s.implausible, s.prefix
        ));
    }
    for f in &s.failures {
        out.line(format_args!("ended with a failure: {f}"));
    }
    out.line(format_args!("children stopped {}", stop_words(clean)));
    if let Some(dir) = &a.record {
        let log = s.log_dir.join(vlsyncd::harness::session::RECORDER_LOG);
        if s.recorder_failed() {
            out.line(format_args!(
                "the recording in {} is incomplete: vlsyncd record failed (see its log, {})",
                dir.display(),
                log.display()
            ));
        } else {
            record_truth(dir, &truth, a.procs.config.as_deref(), &log, &mut out)?;
        }
    }
    // the plot last: everything above is printed even if it cannot be written
    let plot = a.plot.unwrap_or_else(|| s.log_dir.join("demo.svg"));
    let ests: Vec<Estimate> = s.estimates.iter().map(|r| r.est).collect();
    let run = match &a.family {
        Some(f) => format!("simulated `{f}`"),
        None => "rendered".to_string(),
    };
    let title = format!(
        "vlsync-demo, {run} seed {}: MAE {:.2} ms, within {:.0} ms from {} on",
        a.seed,
        ErrorStats::of(&errs).mae * 1e3,
        CONVERGED_S * 1e3,
        secs(stays)
    );
    let svg = vlsyncd::plot::offset_svg(&title, &ests, Some(&truth_points(&truth)), &[]);
    vlsync_common::file::write_atomically(&plot, svg.as_bytes())?;
    out.line(format_args!(
        "plot: {} (estimate ±2σ, raw measurements and truth against LiDAR time)",
        plot.display()
    ));
    match s.failures.len() {
        // a child that needed SIGKILL is a failure too: a daemon killed that way
        // leaves its shared memory to the next one's clean-up
        0 if !clean => Err(
            "a process of the run did not stop within its grace and was killed (SIGKILL)"
                .to_string(),
        ),
        0 => Ok(()),
        n => Err(format!(
            "{n} process(es) of the run ended with a failure: {}",
            s.failures.join("; ")
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(extra: &[&str]) -> Args {
        Args::try_parse_from(["vlsync-demo"].iter().chain(extra)).unwrap()
    }

    #[test]
    fn a_lock_lost_after_convergence_breaks_it_as_an_error_does() {
        // (seconds, locked and within, locked)
        let c = |v: &[(f64, bool, bool)]| Convergence::of(v.iter().copied());
        let acq = |t| (t, false, false);
        let good = |t| (t, true, true);
        let off = |t| (t, false, true);
        assert_eq!(
            c(&[acq(1.0), off(2.0), good(3.0), good(4.0)]),
            Convergence {
                first_lock: Some(2.0),
                first_within: Some(3.0),
                stays: Some(3.0)
            }
        );
        // acquiring again after the first lock: converged only after it
        let v = c(&[acq(1.0), good(2.0), acq(3.0), good(4.0), good(5.0)]);
        assert_eq!(v.stays, Some(4.0));
        assert_eq!(v.first_within, Some(2.0));
        // every estimate good from the first lock on
        assert_eq!(c(&[acq(1.0), good(2.0), good(3.0)]).stays, Some(2.0));
        // the last estimate off or unlocked: never converged
        assert_eq!(c(&[good(1.0), off(2.0)]).stays, None);
        assert_eq!(c(&[good(1.0), acq(2.0)]).stays, None);
        // never locked
        assert_eq!(
            c(&[acq(1.0), acq(2.0)]),
            Convergence {
                first_lock: None,
                first_within: None,
                stays: None
            }
        );
    }

    #[test]
    fn the_daemon_runs_under_sched_fifo_unless_told_otherwise() {
        let fifo = |argv: &[&str]| daemon_fifo(&args(argv));
        assert_eq!(fifo(&[]), Some(50));
        assert_eq!(fifo(&["--fifo", "0"]), Some(0));
        assert_eq!(fifo(&["--config", "x.toml"]), None);
        assert_eq!(fifo(&["--config", "x.toml", "--fifo", "20"]), Some(20));
        assert!(Args::try_parse_from(["vlsync-demo", "--fifo", "100"]).is_err());
    }

    #[test]
    fn bad_numbers_are_refused_naming_the_flag() {
        assert!(check_args(&args(&[])).is_ok());
        assert!(check_args(&args(&["--family", "robot", "--speed", "10"])).is_ok());
        assert!(check_args(&args(&["--summary-every", "0"])).is_ok());
        assert!(check_args(&args(&["--summary-every", "60"])).is_ok());
        for (argv, flag) in [
            (&["--speed", "0"][..], "--speed"),
            (&["--speed=-1"][..], "--speed"),
            (&["--speed", "nan"][..], "--speed"),
            (&["--duration", "0"][..], "--duration"),
            (&["--duration", "inf"][..], "--duration"),
            (&["--summary-every", "0.5"][..], "--summary-every"),
            (&["--summary-every", "nan"][..], "--summary-every"),
            (&["--summary-every=-60"][..], "--summary-every"),
            (
                &["--family", "robot", "--duration", "1.5"][..],
                "--duration",
            ),
            (&["--render-fps", "0.5"][..], "--render-fps"),
            (&["--render-fps", "125"][..], "--render-fps"),
            (&["--render-lidar-hz", "2.6"][..], "--render-lidar-hz"),
            (&["--render-lidar-hz", "nan"][..], "--render-lidar-hz"),
        ] {
            let e = check_args(&args(argv)).unwrap_err();
            assert!(e.starts_with(&format!("{flag} ")), "{argv:?}: {e}");
        }
    }

    #[test]
    fn the_rendered_runs_options_are_refused_with_a_family() {
        assert!(check_args(&args(&["--render-fps", "15", "--render-lidar-hz", "5.5"])).is_ok());
        for flag in [
            "--front-wall-only",
            "--render-fps=15",
            "--render-lidar-hz=5",
        ] {
            let e = check_args(&args(&["--family", "robot", flag])).unwrap_err();
            let name = flag.split('=').next().unwrap();
            assert!(
                e.starts_with(&format!(
                    "{name} applies to the rendered run only, not to --family robot"
                )),
                "{e}"
            );
        }
        // the rates the session passes on (its test checks that both drivers get both)
        let a = args(&["--render-fps", "15"]);
        assert_eq!(render_rates(&a).resolved(), (15.0, 10.0));
    }

    #[test]
    fn a_recording_is_not_written_over() {
        let dir = std::env::temp_dir().join(format!("vlsync-demo-record-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let d = dir.to_str().unwrap();
        assert!(check_args(&args(&["--record", d])).is_ok());
        for f in ["est.csv", TRUTH_FILE] {
            std::fs::write(dir.join(f), "t\n").unwrap();
            let e = check_args(&args(&["--record", d])).unwrap_err();
            assert!(
                e.starts_with("--record ")
                    && e.ends_with(&format!("{f} exists: refusing to overwrite a recording (give another directory, or --force)")),
                "{e}"
            );
            // --force writes over it
            assert!(check_args(&args(&["--record", d, "--force"])).is_ok());
            std::fs::remove_file(dir.join(f)).unwrap();
        }
        // --force alone is refused: it goes with --record
        assert!(Args::try_parse_from(["vlsync-demo", "--force"]).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_plot_path_that_cannot_be_written_is_refused_before_the_run() {
        let dir = std::env::temp_dir().join(format!("vlsync-demo-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ok = dir.join("p.svg");
        assert!(check_args(&args(&["--plot", ok.to_str().unwrap()])).is_ok());
        assert!(
            check_args(&args(&["--plot", "p.svg"])).is_ok(),
            "the current directory"
        );
        let missing = dir.join("no-such-dir").join("p.svg");
        let e = check_args(&args(&["--plot", missing.to_str().unwrap()])).unwrap_err();
        assert!(
            e.starts_with("--plot ") && e.contains("does not exist"),
            "{e}"
        );
        let e = check_args(&args(&["--plot", dir.to_str().unwrap()])).unwrap_err();
        assert!(e.contains("is a directory"), "{e}");
        // a directory no file can be created in
        let e = check_args(&args(&["--plot", "/proc/vlsync-demo.svg"])).unwrap_err();
        assert!(e.contains("cannot be created"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
