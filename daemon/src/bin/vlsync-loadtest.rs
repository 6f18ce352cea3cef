//! `vlsync-loadtest`: the whole pipeline on the rendering simulator in real
//! time, the camera stamped in software after its processing, under load
//! profiles (idle, steady full CPU load, bursts, steps, driver stalls, memory
//! pressure). Scores the estimates against the offset the drivers measured,
//! per phase, and writes `loadtest.md`, `loadtest.json`, `loadtest.svg` and
//! `estimates.csv`.
//! See the README's "Load test" section.
#![forbid(unsafe_code)]

use clap::Parser;
use serde_json::json;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use vlsync_common::EstimatorState;
use vlsync_ipc::termination_requested;
use vlsyncd::harness::console::Out;
use vlsyncd::harness::load::{find_stress_ng, profile, profiles, run_profile, Progress};
use vlsyncd::harness::report::{analyse, estimates_csv, svg, tables, targets, to_json, RunData};
use vlsyncd::harness::session::{Role, Session, SessionOptions, Source, Stamping};
use vlsyncd::harness::stats::ErrorStats;
use vlsyncd::harness::truth::{read_truth_csv, MeasuredTruth};
use vlsyncd::runtime::journal;

#[derive(Parser)]
#[command(
    name = "vlsync-loadtest",
    version,
    about = "Load-injection harness: the live pipeline under CPU load, stalls and memory pressure"
)]
struct Args {
    /// Load profile (`--list` shows them).
    #[arg(long, default_value = "all")]
    profile: String,
    /// List the profiles and exit.
    #[arg(long)]
    list: bool,
    /// Rendering simulator seed.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed: u64,
    /// Directory for the report and the processes' logs (default: a temporary directory).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Base daemon configuration; the harness sets `daemon.core`,
    /// `daemon.fifo_priority`, `daemon.latency_per_period` and `daemon.load_hints`
    /// (from `--load-hints`) on top.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Core the daemon's real-time thread is pinned to (-1: not pinned), -1..=1023.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    core: i64,
    /// SCHED_FIFO priority of the daemon's real-time thread (0: normal scheduler), 0..=99.
    #[arg(long, allow_negative_numbers = true, default_value_t = 50)]
    fifo: i64,
    /// CPU the camera front-end spends per frame before stamping it, ms
    /// (`vlsync-cam --frame-cpu-ms`): a heavier front-end than this machine's
    /// 320x240 flow (about 1 ms), so that CPU load delays the stamps measurably.
    /// 0: the front-end's own cost. At most 90 % of the frame period (30 ms at 30 Hz).
    #[arg(
        long,
        allow_negative_numbers = true,
        value_name = "MS",
        default_value_t = 0.0
    )]
    cam_frame_cpu_ms: f64,
    /// Run the daemon with `daemon.load_hints` (a change of CPU pressure tells the
    /// estimator that the offset may have stepped); without it, the estimator finds
    /// load steps from the data alone, as the shipped default does.
    #[arg(long)]
    load_hints: bool,
    /// The LiDAR front-end fits only the wall ahead. By default it also fits the
    /// wall behind (`lidar.opposite_window`: the rendered room has a wall at each
    /// end), which halves the LiDAR signature's noise variance, as the demo does.
    #[arg(long, conflicts_with = "opposite_window")]
    front_wall_only: bool,
    /// The camera's frame rate, Hz (default 30). 2.67 <= HZ < 125: frames at most half
    /// the estimator's `max_gap_s` (0.75 s) apart, and the frame's 8 ms exposure within
    /// its period.
    #[arg(long, allow_negative_numbers = true, value_name = "HZ")]
    render_fps: Option<f64>,
    /// The LiDAR's revolutions a second, Hz (default 10, an LD06's). 2.67 ..= 100.
    #[arg(long, allow_negative_numbers = true, value_name = "HZ")]
    render_lidar_hz: Option<f64>,
    /// The wall behind too: the default now (kept for older commands).
    #[arg(long, hide = true)]
    opposite_window: bool,
    /// Exit with status 1 when a target is missed or cannot be judged (stress-ng
    /// failed), a process failed or needed SIGKILL, or the run was interrupted.
    #[arg(long)]
    check: bool,
    /// Do not print each estimate.
    #[arg(long)]
    quiet: bool,
}

fn main() -> ExitCode {
    let a = Args::parse();
    match run(&a) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) if a.check => ExitCode::from(1),
        Ok(false) => ExitCode::SUCCESS,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-loadtest: error: {e}\n"));
            ExitCode::from(2)
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

/// The most CPU `--cam-frame-cpu-ms` may burn per frame at `fps`, ms: 90 % of the
/// frame period (30 ms at 30 Hz), so that the front-end keeps up with its frames.
fn max_frame_cpu_ms(fps: f64) -> f64 {
    (0.9e3 / fps * 100.0).floor() / 100.0
}

/// The daemon's own words about its real-time settings (from its log).
fn rt_lines(log: &str) -> Vec<String> {
    log.lines()
        .filter(|l| l.contains("real-time thread:") || l.contains("could not apply"))
        .map(|l| {
            let i = l
                .find("real-time thread:")
                .or_else(|| l.find("could not apply"));
            l[i.unwrap_or(0)..].to_string()
        })
        .collect()
}

/// The daemon's configuration: `--config` (or the defaults) with the options on top.
fn daemon_config(a: &Args) -> Result<vlsync_config::Config, String> {
    let mut cfg = match &a.config {
        Some(p) => vlsync_config::Config::load(p).map_err(|e| e.to_string())?,
        None => vlsync_config::Config::default(),
    };
    // each option checked on its own, so that its error names it
    cfg.daemon.core = a.core;
    cfg.daemon
        .validate("")
        .map_err(|e| format!("--core {}: {}", a.core, e.message))?;
    cfg.daemon.fifo_priority = a.fifo;
    cfg.daemon
        .validate("")
        .map_err(|e| format!("--fifo {}: {}", a.fifo, e.message))?;
    cfg.daemon.latency_per_period = true;
    cfg.daemon.load_hints = a.load_hints;
    cfg.validate("vlsync-loadtest options")
        .map_err(|e| e.to_string())?;
    Ok(cfg)
}

/// The report files a run writes into `--out`, at its end.
const REPORTS: [&str; 4] = [
    "loadtest.md",
    "loadtest.json",
    "loadtest.svg",
    "estimates.csv",
];

/// Every file a run writes into `--out`: the daemon's configuration, the report, the
/// processes' logs and the drivers' truth files.
const WRITTEN: [&str; 10] = [
    "vlsyncd.toml",
    REPORTS[0],
    REPORTS[1],
    REPORTS[2],
    REPORTS[3],
    "vlsyncd.log",
    "vlsync-cam.log",
    "vlsync-lidar.log",
    vlsyncd::harness::session::TRUTH_FILES[0],
    vlsyncd::harness::session::TRUTH_FILES[1],
];

fn run(a: &Args) -> Result<bool, String> {
    // a reader that goes away stops the printing, not the run: the report files are
    // its result
    let mut con = Out::new();
    if a.list {
        for p in profiles() {
            con.line(format_args!(
                "{:>8}  {:>4.0} s  {}",
                p.name,
                p.duration_s(),
                p.about
            ));
            for ph in &p.phases {
                con.line(format_args!(
                    "{:>16}  {:>4.0} s  {}",
                    ph.name,
                    ph.duration_s,
                    ph.load.describe()
                ));
            }
        }
        return Ok(true);
    }
    let prof = profile(&a.profile)?;
    let rates = render_rates(a);
    // as the drivers will check them (they run without --config)
    rates.check(
        vlsync_config::Config::default().estimator.max_gap_s,
        "the drivers' default",
    )?;
    let (fps, lidar_hz) = rates.resolved();
    let max_cpu_ms = max_frame_cpu_ms(fps);
    if !(a.cam_frame_cpu_ms.is_finite() && (0.0..=max_cpu_ms).contains(&a.cam_frame_cpu_ms)) {
        return Err(format!(
            "--cam-frame-cpu-ms {} is out of range: allowed 0 ..= {max_cpu_ms} (90 % of the \
             camera's {:.1} ms frame period at {fps} Hz)",
            vlsync_common::text::number(a.cam_frame_cpu_ms),
            1e3 / fps
        ));
    }
    let stress = if prof.needs_stress_ng() {
        Some(find_stress_ng()?)
    } else {
        None
    };
    let cfg = daemon_config(a)?;
    if a.config.is_some() {
        // the daemon's estimator must be able to use the rendered streams too
        rates.check(cfg.estimator.max_gap_s, "as --config sets it")?;
    }
    let text = toml::to_string(&cfg).map_err(|e| format!("daemon configuration: {e}"))?;
    let pid = std::process::id();
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| std::env::temp_dir().join(format!("vlsync-loadtest-{pid}")));
    if let Some(c) = &a.config {
        // the harness writes these into --out: one of them must not be the input
        for name in WRITTEN {
            if vlsync_common::file::same_file(c, &out.join(name)) {
                return Err(format!(
                    "--config {} is the {name} this run writes into --out {}: give another --out \
                     (or copy the configuration elsewhere)",
                    c.display(),
                    out.display()
                ));
            }
        }
    }
    for r in Role::ALL {
        vlsyncd::runtime::procs::sibling_binary(r.name())?;
    }
    // every argument is checked: only now is the output directory made
    vlsync_common::file::create_out_dir("--out", &out)?;
    // an earlier run's report must not stand beside this run's logs if this one fails
    for name in REPORTS {
        match std::fs::remove_file(out.join(name)) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(format!(
                    "cannot remove the old {}: {e}",
                    out.join(name).display()
                ))
            }
            _ => {}
        }
    }
    let cfg_path = out.join("vlsyncd.toml");
    std::fs::write(&cfg_path, text).map_err(|e| format!("{}: {e}", cfg_path.display()))?;

    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    con.line(format_args!(
        "vlsync-loadtest: profile `{}` ({:.0} s: {}), rendered seed {}, camera {fps} Hz, LiDAR {lidar_hz} Hz, {cpus} CPUs; report and logs in {}",
        prof.name,
        prof.duration_s(),
        prof.about,
        a.seed,
        out.display()
    ));
    let mut session = Session::start(SessionOptions {
        name: "vlsync-loadtest".into(),
        prefix: None,
        log_dir: Some(out.clone()),
        daemon_config: Some(cfg_path),
        daemon_fifo_priority: None,
        source: Source::Render {
            seed: a.seed,
            duration_s: prof.duration_s() + 1.0,
            speed: 1.0,
            stamping: Stamping::Software {
                frame_cpu_us: (a.cam_frame_cpu_ms * 1e3).round() as u32,
            },
            opposite_window: !a.front_wall_only,
            rates,
        },
        // the camera driver renders ahead meanwhile
        start_delay: Duration::from_secs(2),
        record: None,
        record_force: false,
    })?;
    let rt = rt_lines(&session.log("vlsyncd.log"));
    for l in &rt {
        con.line(format_args!("  daemon: {l}"));
    }
    let start_at = session.start_at;
    let quiet = a.quiet;
    let mut progress = |p: Progress<'_>| match p {
        Progress::Line(l) => {
            con.line(format_args!("{l}"));
        }
        Progress::Estimate(r) if !quiet => {
            let e = &r.est;
            con.line(format_args!(
                "  t {:>6.1} s  {:>9}  offset {:>+8.2} ms ±{:.2}",
                (e.t_ref_ns - start_at) as f64 * 1e-9,
                e.state.name(),
                e.offset_s * 1e3,
                e.offset_std_s * 1e3
            ));
        }
        Progress::Estimate(_) => {}
    };
    let records = run_profile(&mut session, &prof, stress.as_deref(), &mut progress);
    // let the drivers finish their run (the last second), then stop everything
    let t0 = std::time::Instant::now();
    while records.is_ok()
        && !termination_requested()
        && !session.drivers_done()
        && t0.elapsed() < Duration::from_secs(5)
    {
        session.poll(Duration::from_millis(100))?;
    }
    let clean = session.stop()?;
    // an error after a process of the run failed names that failure too (a daemon
    // that died leaves a stale pid and short truth files: the cause is its exit)
    let failures = session.failures.clone();
    let with_failures = |e: String| {
        if failures.is_empty() || e.contains(&failures[0]) {
            e
        } else {
            format!(
                "{e}; {} process(es) of the run failed: {}",
                failures.len(),
                failures.join("; ")
            )
        }
    };
    let records = records.map_err(with_failures)?;
    let interrupted = termination_requested();

    let [cam_p, lidar_p] = session.truth_paths();
    let cam_rows = read_truth_csv(&cam_p).map_err(with_failures)?;
    let lidar_rows = read_truth_csv(&lidar_p).map_err(with_failures)?;
    let truth = MeasuredTruth::new(&cam_rows, &lidar_rows, cfg.estimator.window_s)
        .map_err(with_failures)?;
    let data = RunData {
        phases: &records,
        estimates: &session.estimates,
        statuses: &session.statuses,
        truth: &truth,
        cam_rows: &cam_rows,
        lidar_rows: &lidar_rows,
        start_at,
    };
    let reports = analyse(&data);
    let budget = cfg.daemon.latency_budget_us;
    let tg = targets(&reports, &records, budget, session.statuses.last());
    let stress_failed = records.iter().any(|r| r.stress_failure.is_some());

    // whole run after the warm-up
    let after_warmup = records.get(1).map_or(i64::MAX, |r| r.start_ns);
    let errs: Vec<f64> = session
        .estimates
        .iter()
        .filter(|r| {
            matches!(
                r.est.state,
                EstimatorState::Tracking | EstimatorState::Holding
            )
        })
        .filter(|r| {
            truth
                .event_of_lidar(r.est.t_ref_ns)
                .is_some_and(|e| e >= after_warmup)
        })
        .filter_map(|r| Some(r.est.offset_s - truth.offset_at(r.est.t_ref_ns)?))
        .collect();
    let overall = ErrorStats::of(&errs);
    let cam_report = session
        .log("vlsync-cam.log")
        .lines()
        .find(|l| l.contains("frames delivered"))
        .unwrap_or("")
        .to_string();
    let usage: Vec<(Role, String)> = Role::ALL
        .iter()
        .map(|r| (*r, session.usage(*r).describe()))
        .collect();

    let daemon_log = session.log("vlsyncd.log");
    let hints_declared = daemon_log
        .lines()
        .filter(|l| l.contains("load hint: estimator told"))
        .count();
    let hints = if !cfg.daemon.load_hints {
        "off (the default; `--load-hints` turns them on)".to_string()
    } else if daemon_log.contains("running without load hints") {
        "requested, but the kernel publishes no CPU pressure".to_string()
    } else {
        format!("on, {hints_declared} change(s) declared")
    };
    // the stamping-latency steps the estimator's cadence followed, as the daemon logged them
    let latency_steps = |stream: &str| journal::latency_steps_logged(&daemon_log, stream);
    let mut md = format!(
        "# vlsync load test: profile `{}`{}\n\nRendered seed {}, camera {fps} Hz, LiDAR {lidar_hz} Hz, {cpus} CPUs, daemon budget {budget} µs per sample, estimator window {} s.\nDaemon: {}.\nLoad hints (`daemon.load_hints`): {hints}.\nCamera front-end: {}.\nLiDAR front-end: {}.\nStamp cadence (`estimator.cadence` = \"{}\"): stamping-latency steps followed from the stamps: camera {}, LiDAR {}.\n\n",
        prof.name,
        if interrupted { " (interrupted)" } else { "" },
        a.seed,
        cfg.estimator.window_s,
        if rt.is_empty() { "no real-time setting requested".to_string() } else { rt.join("; ") },
        if a.cam_frame_cpu_ms > 0.0 {
            format!("{} ms of CPU per frame before its stamp (`--cam-frame-cpu-ms`)", a.cam_frame_cpu_ms)
        } else {
            "its own cost per frame (320x240 flow)".to_string()
        },
        if a.front_wall_only {
            "the wall ahead only (`--front-wall-only`)"
        } else {
            "the walls ahead and behind (`lidar.opposite_window`; `--front-wall-only` for the wall ahead only)"
        },
        cfg.estimator.cadence.name(),
        latency_steps("cam"),
        latency_steps("lidar"),
    );
    md.push_str(&tables(&reports));
    md.push_str(&format!(
        "\nAfter the warm-up: {}.\n\nTargets:\n",
        overall.describe()
    ));
    for t in &tg {
        md.push_str(&format!(
            "- [{}] {}: {}\n",
            match t.pass {
                Some(true) => "PASS",
                Some(false) => "MISS",
                None => "n/a",
            },
            t.what,
            t.figure
        ));
    }
    md.push_str("\nProcesses:\n");
    for (r, u) in &usage {
        md.push_str(&format!("- {}: {u}\n", r.name()));
    }
    if !cam_report.is_empty() {
        md.push_str(&format!("- {}\n", cam_report.trim()));
    }
    if let Some(l) = vlsyncd::harness::session::missed_line(&session) {
        md.push_str(&format!("\n{l}.\n"));
    }
    for f in &session.failures {
        md.push_str(&format!("\nEnded with a failure: {f}.\n"));
    }
    md.push_str(&format!(
        "\nAll processes stopped {}.\n",
        vlsyncd::harness::session::stop_words(clean)
    ));
    con.line(format_args!("\n{md}"));

    let json = to_json(
        &reports,
        &tg,
        json!({
            "profile": prof.name,
            "interrupted": interrupted,
            "seed": a.seed,
            "camera_hz": fps,
            "lidar_hz": lidar_hz,
            "cpus": cpus,
            "daemon": {
                "core": a.core,
                "fifo_priority_requested": a.fifo,
                "realtime": rt,
                "latency_budget_us": budget,
            },
            "estimator_window_s": cfg.estimator.window_s,
            "load_hints": {"on": cfg.daemon.load_hints, "declared": hints_declared},
            "cam_frame_cpu_ms": a.cam_frame_cpu_ms,
            "lidar_opposite_window": !a.front_wall_only,
            // nothing scored (an interrupted warm-up): null, as the phases' figures
            "after_warmup": {
                "scored": overall.n,
                "mae_ms": (overall.n > 0).then_some(overall.mae * 1e3),
                "p95_ms": (overall.n > 0).then_some(overall.p95 * 1e3),
                "max_ms": (overall.n > 0).then_some(overall.max * 1e3),
            },
            "processes": usage.iter().map(|(r, u)| json!({"name": r.name(), "usage": u})).collect::<Vec<_>>(),
            "camera_driver": cam_report.trim(),
            "stopped_cleanly": clean,
            "estimates_missed": session.missed,
        }),
    );
    let title = format!(
        "vlsync load test `{}`: estimate ±2σ vs measured truth (seed {})",
        prof.name, a.seed
    );
    for (name, body) in [
        ("loadtest.md", md.clone()),
        (
            "loadtest.json",
            serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?,
        ),
        ("loadtest.svg", svg(&title, &data)),
        ("estimates.csv", estimates_csv(&data)),
    ] {
        let p = out.join(name);
        // whole or not at all: a failed write leaves no truncated report
        vlsync_common::file::write_atomically(&p, body.as_bytes())?;
        con.line(format_args!("wrote {}", p.display()));
    }
    Ok(tg.iter().all(|t| t.pass != Some(false)) && clean && !interrupted && !stress_failed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_arguments_fail_before_the_output_directory_is_made() {
        let out = std::env::temp_dir().join(format!("vlsync-loadtest-bad-{}", std::process::id()));
        let o = out.display().to_string();
        for (argv, want) in [
            // (the idle profile needs no stress-ng)
            (
                &["--profile", "idle", "--fifo", "1000"][..],
                "--fifo 1000: `daemon.fifo_priority`",
            ),
            (
                &["--profile", "idle", "--core", "99999"][..],
                "--core 99999: `daemon.core`",
            ),
            (
                &["--profile", "idle", "--config", "/nonexistent/vlsync.toml"][..],
                "/nonexistent/vlsync.toml",
            ),
            (
                &["--profile", "idle", "--cam-frame-cpu-ms", "nan"][..],
                "--cam-frame-cpu-ms",
            ),
            (&["--profile", "nope"][..], "unknown profile"),
            (
                &["--profile", "idle", "--render-fps", "200"][..],
                "--render-fps 200",
            ),
            (
                &["--profile", "idle", "--render-lidar-hz", "0"][..],
                "--render-lidar-hz 0",
            ),
            // 90 % of a 15 Hz camera's period is 60 ms
            (
                &[
                    "--profile",
                    "idle",
                    "--render-fps",
                    "15",
                    "--cam-frame-cpu-ms",
                    "60.5",
                ][..],
                "allowed 0 ..= 60 (90 % of the camera's 66.7 ms frame period at 15 Hz)",
            ),
        ] {
            let a = Args::try_parse_from(
                ["vlsync-loadtest", "--quiet", "--out", o.as_str()]
                    .iter()
                    .chain(argv),
            )
            .unwrap();
            let e = run(&a).unwrap_err();
            assert!(e.contains(want), "{argv:?}: {e}");
            assert!(!out.exists(), "{argv:?} made {o}");
        }
    }

    #[test]
    fn the_frame_cpu_limit_follows_the_frame_rate() {
        assert_eq!(max_frame_cpu_ms(30.0), 30.0);
        assert_eq!(max_frame_cpu_ms(15.0), 60.0);
        assert_eq!(max_frame_cpu_ms(124.0), 7.25);
        // allowed at 15 Hz, not at the default 30
        let parse = |argv: &[&str]| {
            Args::try_parse_from(["vlsync-loadtest", "--profile", "idle"].iter().chain(argv))
                .unwrap()
        };
        let e = run(&parse(&[
            "--cam-frame-cpu-ms",
            "45",
            "--out",
            "/nonexistent/x",
        ]))
        .unwrap_err();
        assert!(e.contains("--cam-frame-cpu-ms 45"), "{e}");
        // at 15 Hz the same passes its check: the run fails later, at a --config the
        // run would write over in --out, before anything starts (a refusal of its own
        // that comes after the check, and before the workspace's binaries are looked
        // for, which a unit test's build may not have made)
        let (dir, cfg) = config_in("cpu", "vlsyncd.toml", "[daemon]\n");
        let (o, c) = (dir.display().to_string(), cfg.display().to_string());
        let e = run(&parse(&[
            "--render-fps",
            "15",
            "--cam-frame-cpu-ms",
            "45",
            "--out",
            o.as_str(),
            "--config",
            c.as_str(),
        ]))
        .unwrap_err();
        assert!(
            e.starts_with(&format!(
                "--config {c} is the vlsyncd.toml this run writes into --out {o}"
            )),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A directory of this test process (`vlsync-loadtest-<tag>-<pid>`) holding the
    /// configuration file `name` with `text`: the directory and the file.
    fn config_in(tag: &str, name: &str, text: &str) -> (std::path::PathBuf, std::path::PathBuf) {
        let dir =
            std::env::temp_dir().join(format!("vlsync-loadtest-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = dir.join(name);
        std::fs::write(&cfg, text).unwrap();
        (dir, cfg)
    }

    /// A `--config` whose `estimator.max_gap_s` a slow rendered sensor's samples would
    /// break is refused before anything is written.
    #[test]
    fn rates_the_configured_estimator_cannot_use_are_refused() {
        let (dir, cfg) = config_in("gap", "gap.toml", "[estimator]\nmax_gap_s = 0.3\n");
        let out = dir.join("out");
        let (o, c) = (out.display().to_string(), cfg.display().to_string());
        let a = Args::try_parse_from([
            "vlsync-loadtest",
            "--quiet",
            "--profile",
            "idle",
            "--render-lidar-hz",
            "5",
            "--out",
            o.as_str(),
            "--config",
            c.as_str(),
        ])
        .unwrap();
        let e = run(&a).unwrap_err();
        assert!(
            e.contains("--render-lidar-hz 5") && e.contains("--config"),
            "{e}"
        );
        assert!(!out.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// `--config D/vlsyncd.toml --out D` used to replace the user's file with the
    /// generated one; it is refused before anything is written.
    #[test]
    fn a_config_the_run_would_overwrite_is_refused() {
        let text = "# mine\n[daemon]\nlatency_budget_us = 300.0\n";
        let (out, cfg) = config_in("same", "vlsyncd.toml", text);
        let (o, c) = (out.display().to_string(), cfg.display().to_string());
        let a = Args::try_parse_from([
            "vlsync-loadtest",
            "--quiet",
            "--profile",
            "idle",
            "--out",
            o.as_str(),
            "--config",
            c.as_str(),
        ])
        .unwrap();
        let e = run(&a).unwrap_err();
        assert!(e.contains("--config") && e.contains("vlsyncd.toml"), "{e}");
        assert_eq!(std::fs::read_to_string(&cfg).unwrap(), text);
        std::fs::remove_dir_all(&out).unwrap();
    }
}
