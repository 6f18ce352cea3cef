//! `vlsync-soak`: one daemon for many simulated hours. Starts `vlsyncd run`, then
//! a new driver pair on the signature simulator for each session (the next seed:
//! another offset, both clocks back to 0, as when the drivers restart), faster than
//! real time. After each session it prints that session's accuracy against the
//! simulator's truth, how long the daemon took to lock again, and the daemon's
//! resident memory and CPU; at the end a summary with the memory's growth, the
//! status counters and what the daemon's journal said. What months on a robot
//! would show, in minutes: memory that creeps, a restart that is not relocked, a
//! counter that drifts. The orchestration is `vlsyncd::harness::session`.
#![forbid(unsafe_code)]

use clap::Parser;
use std::process::ExitCode;
use std::time::Duration;
use vlsync_common::EstimatorState;
use vlsync_ipc::termination_requested;
use vlsyncd::harness::console::Out;
use vlsyncd::harness::session::{
    counters_line, stop_words, ProcessArgs, Received, Role, Session, Source,
};
use vlsyncd::harness::stats::ErrorStats;
use vlsyncd::harness::{check_arg, MAX_SPEED, MIN_SPEED};

#[derive(Parser)]
#[command(
    name = "vlsync-soak",
    version,
    about = "One vlsync daemon over many simulated sessions (driver restarts, new offsets), faster than real time: accuracy, relock and memory per session"
)]
struct Args {
    /// Signature-simulator family of every session (see `vlsync-sim --list`).
    #[arg(long, default_value = "clocks")]
    family: String,
    /// Number of sessions (a new driver pair and seed each).
    #[arg(long, allow_negative_numbers = true, default_value_t = 10)]
    sessions: u32,
    /// Simulated length of each session, seconds.
    #[arg(long, allow_negative_numbers = true, default_value_t = 3600.0)]
    session_s: f64,
    /// Real-time speed factor.
    #[arg(long, allow_negative_numbers = true, default_value_t = 200.0)]
    speed: f64,
    /// Seed of the first session; session i runs seed `seed_base + i`.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed_base: u64,
    #[command(flatten)]
    procs: ProcessArgs,
    /// Exit 1 unless every session locked, no sample was lost and the daemon's
    /// resident memory after the last session is within `--max-growth-kb` of its
    /// memory after the first.
    #[arg(long)]
    check: bool,
    /// Memory growth `--check` allows, kB.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1024)]
    max_growth_kb: u64,
}

/// Error beyond which an estimate counts as far off, s (issue 2's 20 ms).
const FAR_S: f64 = 0.020;

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-soak: error: {e}\n"));
            ExitCode::from(2)
        }
    }
}

fn check_args(a: &Args) -> Result<vlsync_sim::Family, String> {
    check_arg(
        "--session-s",
        a.session_s,
        vlsync_sim::families::MIN_DURATION_S,
        vlsync_sim::families::MAX_DURATION_S,
    )?;
    check_arg("--speed", a.speed, MIN_SPEED, MAX_SPEED)?;
    if !(1..=10_000).contains(&a.sessions) {
        return Err(format!(
            "--sessions {} is out of range: allowed 1 ..= 10000",
            a.sessions
        ));
    }
    if a.max_growth_kb > MAX_GROWTH_KB {
        return Err(format!(
            "--max-growth-kb {} is out of range: allowed 0 ..= {MAX_GROWTH_KB}",
            a.max_growth_kb
        ));
    }
    // the sessions' seeds are seed_base ..= seed_base + sessions - 1
    let last = u64::MAX - (u64::from(a.sessions) - 1);
    if a.seed_base > last {
        return Err(format!(
            "--seed-base {} leaves no room for {} sessions' seeds: allowed 0 ..= {last}",
            a.seed_base, a.sessions
        ));
    }
    a.family.parse().map_err(|e| format!("--family: {e}"))
}

fn source(a: &Args, family: vlsync_sim::Family, i: u32) -> Source {
    Source::Sim {
        family,
        seed: a.seed_base + u64::from(i),
        duration_s: a.session_s,
        speed: a.speed,
    }
}

/// One session's figures.
struct SessionResult {
    seed: u64,
    estimates: usize,
    /// LiDAR time of the first tracking estimate, s (≈ since the session's start).
    lock_s: Option<f64>,
    /// Signed errors of the locked estimates from the first lock on (the 3 s after
    /// each load step left out), s.
    errs: Vec<f64>,
    rss_kb: Option<u64>,
    cpu_s: Option<f64>,
}

/// The first lock's LiDAR time and the errors of the locked estimates from it on,
/// scored as `vlsyncd bench` scores: the 3 s after each load step are left out
/// (`vlsync_sim::score::STEP_GRACE_NS`).
fn score(got: &[Received], truth: &vlsync_sim::Truth) -> (Option<f64>, Vec<f64>) {
    let grace = vlsync_sim::score::STEP_GRACE_NS;
    let after_step = |t: i64| {
        truth
            .steps
            .iter()
            .any(|&(s, _)| t >= s && t <= s.saturating_add(grace))
    };
    let Some(first) = got
        .iter()
        .position(|r| r.est.state == EstimatorState::Tracking)
    else {
        return (None, vec![]);
    };
    let errs = got[first..]
        .iter()
        .filter(|r| {
            matches!(
                r.est.state,
                EstimatorState::Tracking | EstimatorState::Holding
            ) && (0..=truth.end_ns).contains(&r.est.t_ref_ns)
                && !after_step(r.est.t_ref_ns)
        })
        .map(|r| r.est.offset_s - truth.offset_at(r.est.t_ref_ns))
        .collect();
    (Some(got[first].est.t_ref_ns as f64 * 1e-9), errs)
}

/// Share of `errs` beyond [`FAR_S`], %; a non-finite error counts as far. `None`
/// with nothing scored (a session that never locked is not "0 % beyond").
fn far_share(errs: &[f64]) -> Option<f64> {
    if errs.is_empty() {
        return None;
    }
    let far = |e: &&f64| e.is_nan() || e.abs() > FAR_S;
    Some(100.0 * errs.iter().filter(far).count() as f64 / errs.len() as f64)
}

/// [`far_share`] as printed: `-` when nothing was scored.
fn far_text(errs: &[f64], decimals: usize) -> String {
    far_share(errs).map_or("-".into(), |p| format!("{p:.decimals$} %"))
}

/// Largest `--max-growth-kb` (1 TiB).
const MAX_GROWTH_KB: u64 = 1 << 30;

fn run(a: Args) -> Result<bool, String> {
    let family = check_args(&a)?;
    let mut out = Out::new();
    let mut s = Session::start(a.procs.session_options(
        "vlsync-soak",
        source(&a, family, 0),
        Duration::from_millis(1500),
    ))?;
    out.line(format_args!(
        "vlsync-soak: {} sessions of {} s of `{}` at {}x ({:.1} simulated hours, about {:.0} s of wall time) on prefix `{}` (logs in {})",
        a.sessions,
        a.session_s,
        family.name(),
        a.speed,
        f64::from(a.sessions) * a.session_s / 3600.0,
        f64::from(a.sessions) * (a.session_s / a.speed + 2.0),
        s.prefix,
        s.log_dir.display()
    ));
    let mut results: Vec<SessionResult> = vec![];
    // simulated time the sessions covered (the last one's part when interrupted), s
    let mut covered_s = 0.0;
    let mut interrupted = false;
    for i in 0..a.sessions {
        if i > 0 {
            s.next_drivers(
                source(&a, family, i),
                Duration::from_millis(1000),
                &i.to_string(),
            )?;
        }
        let truth = s
            .source
            .known_truth()?
            .ok_or("the simulator's sessions have a known truth")?;
        let begin = s.estimates.len();
        let end = s.end_ns() + 5_000_000_000;
        let mut late = false;
        loop {
            if termination_requested() || out.closed() {
                interrupted = true;
                break;
            }
            if vlsync_ipc::monotonic_ns() >= end {
                late = true;
                break;
            }
            s.poll(Duration::from_millis(200))?;
            if s.check_children() {
                // the daemon died: the sessions left cannot run without it
                interrupted = true;
                break;
            }
            if s.drivers_done() {
                // the last hops follow the drivers' last samples shortly
                s.poll(Duration::from_millis(300))?;
                break;
            }
        }
        if late {
            out.line(format_args!(
                "session {}: the drivers were still running 5 s after the session's end (a machine too slow for --speed {}?); they are stopped",
                i + 1,
                a.speed
            ));
        }
        s.sample_usage(true);
        // this session's only: an estimate of the last one published late (after
        // this session's drivers started) would be scored against the wrong truth
        let start_at = s.start_at;
        let got: Vec<Received> = s.estimates[begin..]
            .iter()
            .filter(|r| r.publish_ns >= start_at)
            .copied()
            .collect();
        let got = &got[..];
        covered_s += got
            .iter()
            .map(|r| r.est.t_ref_ns as f64 * 1e-9)
            .fold(0.0, f64::max)
            .clamp(0.0, a.session_s);
        let (lock_s, errs) = score(got, &truth);
        let d = s.usage(Role::Daemon);
        let r = SessionResult {
            seed: a.seed_base + u64::from(i),
            estimates: got.len(),
            lock_s,
            errs,
            rss_kb: d.rss_kb,
            cpu_s: d.cpu_s,
        };
        let st = ErrorStats::of(&r.errs);
        out.line(format_args!(
            "session {}/{} (seed {}): {} estimates, {}, {}; {} beyond 20 ms; daemon RSS {}, CPU {}",
            i + 1,
            a.sessions,
            r.seed,
            r.estimates,
            r.lock_s
                .map_or("never locked".into(), |t| format!("locked at {t:.1} s")),
            st.describe(),
            far_text(&r.errs, 2),
            r.rss_kb
                .map_or("?".into(), |k| format!("{:.1} MB", k as f64 / 1024.0)),
            r.cpu_s.map_or("?".into(), |c| format!("{c:.1} s"))
        ));
        results.push(r);
        if interrupted {
            break;
        }
    }
    let clean = s.stop()?;
    interrupted |= termination_requested();

    out.line(format_args!(
        "\n=== summary{} ===",
        if interrupted { " (interrupted)" } else { "" }
    ));
    let all: Vec<f64> = results
        .iter()
        .flat_map(|r| r.errs.iter().copied())
        .collect();
    let locks: Vec<f64> = results.iter().filter_map(|r| r.lock_s).collect();
    out.line(format_args!(
        "accuracy over {} sessions ({:.1} simulated hours; tracking and holding estimates from each session's first lock, the 3 s after each load step left out): {}; {} beyond 20 ms",
        results.len(),
        covered_s / 3600.0,
        ErrorStats::of(&all).describe(),
        far_text(&all, 3)
    ));
    let never = results.len() - locks.len();
    out.line(format_args!(
        "relock after each driver restart: {} of {} sessions locked, at {} s of session time",
        locks.len(),
        results.len(),
        if locks.is_empty() {
            "-".to_string()
        } else {
            format!(
                "{:.1}-{:.1}",
                locks.iter().copied().fold(f64::INFINITY, f64::min),
                locks.iter().copied().fold(0.0, f64::max)
            )
        }
    ));
    let rss: Vec<u64> = results.iter().filter_map(|r| r.rss_kb).collect();
    // growth between the first session's end and the last's: one reading measures none
    let growth = match (rss.first(), rss.last()) {
        (Some(f), Some(l)) if rss.len() >= 2 => Some(*l as i64 - *f as i64),
        _ => None,
    };
    out.line(format_args!(
        "daemon memory: RSS {} after the first session, {} after the last (growth {}), at most {}",
        rss.first()
            .map_or("?".into(), |k| format!("{:.1} MB", *k as f64 / 1024.0)),
        rss.last()
            .map_or("?".into(), |k| format!("{:.1} MB", *k as f64 / 1024.0)),
        growth.map_or(
            if rss.len() == 1 {
                "not measured: one session".to_string()
            } else {
                "?".into()
            },
            |g| format!("{g:+} kB")
        ),
        rss.iter()
            .max()
            .map_or("?".into(), |k| format!("{:.1} MB", *k as f64 / 1024.0))
    ));
    if let Some(c) = results.last().and_then(|r| r.cpu_s) {
        out.line(format_args!(
            "daemon CPU: {c:.1} s for {:.1} simulated hours at {}x ({})",
            covered_s / 3600.0,
            a.speed,
            if covered_s > 0.0 {
                format!("{:.2} s per simulated hour", c / (covered_s / 3600.0))
            } else {
                "no estimate, so no simulated time to divide by".into()
            }
        ));
    }
    let lost = match s.last_status() {
        Some(st) => {
            out.line(format_args!("{}", counters_line(st)));
            Some(st.lost[0].saturating_add(st.lost[1]))
        }
        None => {
            out.line(format_args!("daemon: no status received"));
            None
        }
    };
    let log = s.log("vlsyncd.log");
    let count = |pat: &str| log.lines().filter(|l| l.contains(pat)).count();
    out.line(format_args!(
        "daemon journal: {} lines, {} warnings ({} search moves, {} switches to degraded mode), {} offset steps found in the data, {} errors",
        log.lines().count(),
        count(" WARN "),
        vlsyncd::runtime::journal::search_moves_logged(&log),
        vlsyncd::runtime::journal::degraded_switches_logged(&log),
        vlsyncd::runtime::journal::offset_steps_logged(&log),
        count(" ERROR ")
    ));
    if let Some(l) = vlsyncd::harness::session::missed_line(&s) {
        out.line(format_args!("{l}"));
    }
    for f in &s.failures {
        out.line(format_args!("ended with a failure: {f}"));
    }
    out.line(format_args!("children stopped {}", stop_words(clean)));
    if !a.check {
        return Ok(true);
    }
    let mut failed = vec![];
    if interrupted {
        failed.push("interrupted".to_string());
    }
    for f in &s.failures {
        failed.push(format!("ended with a failure: {f}"));
    }
    if !clean && s.failures.is_empty() {
        failed.push("a child needed SIGKILL to stop".to_string());
    }
    if never > 0 {
        failed.push(format!("{never} sessions never locked"));
    }
    match lost {
        Some(0) => {}
        Some(n) => failed.push(format!("{n} samples lost")),
        None => failed.push("no status received".into()),
    }
    let mut not_judged = "";
    match growth {
        Some(g) if g <= a.max_growth_kb as i64 => {}
        Some(g) => failed.push(format!(
            "daemon memory grew {g} kB (allowed {} kB)",
            a.max_growth_kb
        )),
        None if rss.len() == 1 => {
            not_judged = " (memory growth not judged: it needs two sessions)";
        }
        None => failed.push("daemon memory not read".into()),
    }
    if failed.is_empty() {
        out.line(format_args!("check: passed{not_judged}"));
        Ok(true)
    } else {
        out.line(format_args!("check: FAILED: {}", failed.join("; ")));
        Ok(false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(extra: &[&str]) -> Args {
        Args::try_parse_from(["vlsync-soak"].iter().chain(extra)).unwrap()
    }

    #[test]
    fn bad_options_are_refused_naming_the_flag() {
        assert!(check_args(&args(&[])).is_ok());
        for (argv, flag) in [
            (&["--speed", "0"][..], "--speed"),
            (&["--speed", "nan"][..], "--speed"),
            (&["--session-s", "1"][..], "--session-s"),
            (&["--session-s", "1e9"][..], "--session-s"),
            (&["--sessions", "0"][..], "--sessions"),
            (&["--seed-base", "18446744073709551615"][..], "--seed-base"),
            (&["--family", "nope"][..], "--family"),
            (
                &["--max-growth-kb", "18446744073709551615"][..],
                "--max-growth-kb",
            ),
        ] {
            let e = check_args(&args(argv)).unwrap_err();
            assert!(e.starts_with(flag), "{argv:?}: {e}");
        }
        // the last seeds are usable: seed_base ..= seed_base + sessions - 1
        let max = u64::MAX.to_string();
        assert!(check_args(&args(&["--seed-base", &max, "--sessions", "1"])).is_ok());
        let room = (u64::MAX - 9).to_string();
        assert!(check_args(&args(&["--seed-base", &room, "--sessions", "10"])).is_ok());
        let e = check_args(&args(&["--seed-base", &max, "--sessions", "2"])).unwrap_err();
        assert!(
            e.contains(&format!("allowed 0 ..= {}", u64::MAX - 1)),
            "{e}"
        );
    }

    #[test]
    fn scoring_starts_at_the_first_lock_and_counts_far_estimates() {
        let truth = vlsync_sim::generate(vlsync_sim::Family::Robot, 1, Some(20.0)).truth;
        let est = |t_s: f64, state, err: f64| Received {
            est: vlsync_common::Estimate {
                seq: 0,
                t_ref_ns: (t_s * 1e9) as i64,
                offset_s: truth.offset_at((t_s * 1e9) as i64) + err,
                drift: 0.0,
                offset_std_s: 0.001,
                drift_std: 1e-6,
                state,
                polarity: vlsync_common::Polarity::Negative,
                peak_score: 0.9,
                peak_ratio: 3.0,
                measured_offset_s: f64::NAN,
            },
            publish_ns: 0,
        };
        let got = [
            est(1.0, EstimatorState::Lost, 0.5),
            est(2.0, EstimatorState::Holding, 0.5),
            est(3.0, EstimatorState::Tracking, 0.001),
            est(4.0, EstimatorState::Holding, -0.030),
            est(5.0, EstimatorState::Lost, 0.5),
            est(6.0, EstimatorState::Tracking, 0.002),
        ];
        let (lock, errs) = score(&got, &truth);
        assert_eq!(lock, Some(3.0));
        assert_eq!(errs.len(), 3);
        assert!((far_share(&errs).unwrap() - 100.0 / 3.0).abs() < 1e-9);
        assert_eq!(far_share(&[0.001, f64::NAN]), Some(50.0));
        // nothing scored (never locked) is not "0 % beyond"
        assert_eq!(far_share(&[]), None);
        assert_eq!(far_text(&[], 2), "-");
        assert_eq!(score(&got[..2], &truth), (None, vec![]));
        // a load step at 3.5 s: the estimates of the 3 s after it are not scored
        let stepped = vlsync_sim::Truth {
            steps: vec![(3_500_000_000, 0.025)],
            ..truth.clone()
        };
        let (_, errs) = score(&got, &stepped);
        assert_eq!(errs.len(), 1);
    }
}
