//! `vlsyncd replay`: the estimator offline on recorded signature CSV files.

use std::fmt::Write as _;
use std::path::Path;
use vlsync_common::{nanos_to_secs, Estimate, Nanos, RejectReason, Sample, Stream};
use vlsync_config::{Config, EstimatorConfig};
use vlsync_estimator::{Estimator, EstimatorStats};

/// Runs the estimator over two complete streams, pushed in timestamp order,
/// and returns every estimate.
pub fn run_estimator(
    cfg: &EstimatorConfig,
    cam: &[Sample],
    lidar: &[Sample],
) -> (Vec<Estimate>, EstimatorStats) {
    run_estimator_with_changes(cfg, cam, lidar, &[], None)
}

/// The order in which the two streams are pushed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Order<'a> {
    /// By stamp, the camera's moved onto the LiDAR clock by the configuration's prior
    /// (`lag_center_s`), the camera's sample first on a tie: as the samples would have
    /// arrived if both clocks ran on. (Merged by their raw stamps, clocks seconds
    /// apart would look like a stalled stream to the estimator.)
    Stamp,
    /// By each sample's publish time (camera, LiDAR; one per sample, as `vlsyncd
    /// record` writes them), the camera's first on a tie: the order the daemon read
    /// them in.
    Publish(&'a [Nanos], &'a [Nanos]),
}

/// [`run_estimator`] with the samples pushed in `order`.
pub fn run_estimator_in_order(
    cfg: &EstimatorConfig,
    cam: &[Sample],
    lidar: &[Sample],
    order: Order<'_>,
) -> (Vec<Estimate>, EstimatorStats) {
    run_merged(cfg, cam, lidar, order, &[], None)
}

/// [`run_estimator`], announcing each of `changes` (LiDAR times, ns, sorted) to the
/// estimator when the first LiDAR sample at or after it is pushed: as a certain
/// change ([`Estimator::declare_change`]), or with `hint_std_s` as a hint of a step
/// of about that size ([`Estimator::hint_change`]).
pub fn run_estimator_with_changes(
    cfg: &EstimatorConfig,
    cam: &[Sample],
    lidar: &[Sample],
    changes: &[Nanos],
    hint_std_s: Option<f64>,
) -> (Vec<Estimate>, EstimatorStats) {
    run_merged(cfg, cam, lidar, Order::Stamp, changes, hint_std_s)
}

fn run_merged(
    cfg: &EstimatorConfig,
    cam: &[Sample],
    lidar: &[Sample],
    order: Order<'_>,
    changes: &[Nanos],
    hint_std_s: Option<f64>,
) -> (Vec<Estimate>, EstimatorStats) {
    // a sample's merge key: its publish time, or its stamp on the LiDAR clock (the
    // camera's moved by the prior offset; also for a sample without a publish time,
    // which the command line never hands in)
    let prior = (cfg.lag_center_s * 1e9).round() as Nanos;
    let key = |s: &[Sample], k: usize, publish: Option<&[Nanos]>, shift: Nanos| {
        publish
            .and_then(|p| p.get(k).copied())
            .unwrap_or(s[k].t_ns.saturating_add(shift))
    };
    let (pub_cam, pub_lidar) = match order {
        Order::Stamp => (None, None),
        Order::Publish(c, l) => (Some(c), Some(l)),
    };
    let mut est = Estimator::new(cfg);
    let mut out = Vec::with_capacity(lidar.len() / 2 + 16);
    let (mut i, mut j, mut c) = (0, 0, 0);
    while i < cam.len() || j < lidar.len() {
        let take_cam = j >= lidar.len()
            || (i < cam.len() && key(cam, i, pub_cam, prior) <= key(lidar, j, pub_lidar, 0));
        let r = if take_cam {
            i += 1;
            est.push(Stream::Cam, cam[i - 1])
        } else {
            while c < changes.len() && changes[c] <= lidar[j].t_ns {
                match hint_std_s {
                    Some(sd) => est.hint_change(changes[c], sd),
                    None => est.declare_change(changes[c]),
                }
                c += 1;
            }
            j += 1;
            est.push(Stream::Lidar, lidar[j - 1])
        };
        // rejections are counted inside the estimator
        let _: Result<(), RejectReason> = r;
        while let Some(e) = est.poll() {
            out.push(e);
        }
    }
    (out, est.stats().clone())
}

/// The CSV header of estimate files.
pub const ESTIMATE_HEADER: &str =
    "t,offset,drift,offset_std,drift_std,state,polarity,peak_score,peak_ratio,measured_offset,seq";

/// Formats one estimate as a CSV row (without newline).
pub fn estimate_row(e: &Estimate, buf: &mut String) {
    buf.clear();
    // the reference time exactly, as the sample files' stamps: through an f64 an
    // epoch-sized stamp (1.7e18 ns) would be off by up to 240 ns, and `--compare`
    // matches estimates by their exact reference times
    vlsync_sim::io::write_secs(buf, e.t_ref_ns);
    let _ = write!(
        buf,
        ",{:.9},{:.9},{:.9},{:.9},{},{},{:.4},{:.4},{:.9},{}",
        e.offset_s,
        e.drift,
        e.offset_std_s,
        e.drift_std,
        e.state,
        e.polarity,
        e.peak_score,
        if e.peak_ratio.is_finite() {
            e.peak_ratio
        } else {
            99.0
        },
        e.measured_offset_s,
        e.seq
    );
}

/// Writes estimates as CSV, atomically: a failed write leaves no partial file
/// ([`vlsync_common::file::write_atomically`]).
pub fn write_estimates(path: &Path, ests: &[Estimate]) -> Result<(), String> {
    let mut text = String::with_capacity(160 * (ests.len() + 1));
    let mut line = String::new();
    text.push_str(ESTIMATE_HEADER);
    text.push('\n');
    for e in ests {
        estimate_row(e, &mut line);
        text.push_str(&line);
        text.push('\n');
    }
    vlsync_common::file::write_atomically(path, text.as_bytes())
}

/// Human summary of a replay.
pub fn summary(stats: &EstimatorStats, ests: &[Estimate], rows: [usize; 2]) -> String {
    let mut s = String::new();
    for (i, name) in ["cam", "lidar"].iter().enumerate() {
        let rej: Vec<String> = RejectReason::ALL
            .iter()
            .filter(|r| stats.rejected[i][r.index()] > 0)
            .map(|r| format!("{} {}", stats.rejected[i][r.index()], r.name()))
            .collect();
        let _ = writeln!(
            s,
            "{name:>5}: {} rows read, {} accepted, {} rejected{}{}, {} gaps, {} resets; {} latency steps followed from the stamps' cadence, {} cadence relearns",
            rows[i],
            stats.accepted[i],
            stats.rejected[i].iter().sum::<u64>(),
            if rej.is_empty() { "" } else { " (" },
            if rej.is_empty() {
                String::new()
            } else {
                rej.join(", ") + ")"
            },
            stats.gaps[i],
            stats.resets[i],
            stats.cadence_steps[i],
            stats.cadence_relearns[i]
        );
    }
    let count = |st: vlsync_common::EstimatorState| ests.iter().filter(|e| e.state == st).count();
    let _ = writeln!(
        s,
        "estimates: {} written ({} tracking, {} holding, {} acquiring, {} lost); {} measurements, {} outliers, {} steps, {} locks",
        ests.len(),
        count(vlsync_common::EstimatorState::Tracking),
        count(vlsync_common::EstimatorState::Holding),
        count(vlsync_common::EstimatorState::Acquiring),
        count(vlsync_common::EstimatorState::Lost),
        stats.measurements,
        stats.outliers,
        stats.steps,
        stats.locks
    );
    if stats.recentres > 0 {
        let _ = writeln!(
            s,
            "searches moved: {} (an acquisition found nothing where it searched and moved to the other centre or to a lost lock's drifted offset, or could not be served)",
            stats.recentres
        );
    }
    match ests.last() {
        Some(e) => {
            let _ = writeln!(
                s,
                "final: t={:.3} s offset={:+.4} ms ± {:.4} ms (1σ), drift={:+.2} ppm ± {:.2} ppm, state {}, polarity {}",
                nanos_to_secs(e.t_ref_ns),
                e.offset_s * 1e3,
                e.offset_std_s * 1e3,
                e.drift * 1e6,
                e.drift_std * 1e6,
                e.state,
                e.polarity
            );
        }
        None => {
            let _ = writeln!(
                s,
                "final: no estimate (streams too short or never overlapping)"
            );
        }
    }
    s
}

/// `replay --order`: how the two files are merged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum OrderArg {
    /// By publish time when both files carry it (`vlsyncd record`'s) and every
    /// publish time is positive, else by stamp (saying why).
    #[default]
    Auto,
    /// By stamp.
    Stamp,
    /// By publish time (both files must carry it).
    Publish,
}

/// Arguments of the `replay` command.
#[derive(Debug, Clone, Copy)]
pub struct ReplayArgs<'a> {
    /// Camera signature CSV.
    pub cam: &'a Path,
    /// LiDAR signature CSV.
    pub lidar: &'a Path,
    /// Output estimates CSV.
    pub out: &'a Path,
    /// Configuration file.
    pub config: Option<&'a Path>,
    /// Truth CSV (`t,offset`).
    pub truth: Option<&'a Path>,
    /// SVG plot to write.
    pub plot: Option<&'a Path>,
    /// Another run's estimates file to compare with (e.g. `vlsyncd record`'s `est.csv`).
    pub compare: Option<&'a Path>,
    /// How the two files are merged.
    pub order: OrderArg,
}

/// Refuses outputs that name an input or each other: `--out` and `--plot` are
/// truncated when written, and an estimates file written over `--cam` (or a plot over
/// the estimates) destroys what the run was made from.
fn check_outputs(a: &ReplayArgs<'_>) -> Result<(), String> {
    let files = [
        ("--out", Some(a.out)),
        ("--plot", a.plot),
        ("--cam", Some(a.cam)),
        ("--lidar", Some(a.lidar)),
        ("--truth", a.truth),
        ("--config", a.config),
        ("--compare", a.compare),
    ];
    if vlsync_common::file::same_file(a.cam, a.lidar) {
        return Err(format!(
            "--cam and --lidar name the same file ({}): the two streams come from two sensors",
            a.cam.display()
        ));
    }
    for (i, (out_flag, out)) in files.iter().take(2).enumerate() {
        let Some(out) = out else { continue };
        for (j, (flag, other)) in files.iter().enumerate().skip(i + 1) {
            // both outputs to one device (`/dev/null`, a terminal) truncate nothing
            if j < 2 && other.is_some_and(is_char_device) {
                continue;
            }
            if other.is_some_and(|p| vlsync_common::file::same_file(out, p)) {
                return Err(format!(
                    "{out_flag} {} is the same file as {flag}: refusing to overwrite it",
                    out.display()
                ));
            }
        }
    }
    Ok(())
}

/// A change of the truth between two of its rows that is a step (a load step is
/// ±25 ms at once; a drift of 100 ppm moves it 1 µs between 10 ms rows).
const TRUTH_STEP_S: f64 = 0.005;

/// Whether `p` names a character device (after links): `/dev/null`, a terminal.
fn is_char_device(p: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::metadata(p).is_ok_and(|m| m.file_type().is_char_device())
}

/// Truth offset at `t`, linearly interpolated (clamped at the ends); `None` when empty.
pub fn truth_at(truth: &[(Nanos, f64)], t: Nanos) -> Option<f64> {
    let i = truth.partition_point(|p| p.0 <= t);
    match (i.checked_sub(1).and_then(|j| truth.get(j)), truth.get(i)) {
        (Some(a), Some(b)) if b.0 > a.0 => {
            // in i128: stamps far apart (a hostile truth file) must not overflow
            let (dt, span) = (
                i128::from(t) - i128::from(a.0),
                i128::from(b.0) - i128::from(a.0),
            );
            Some(a.1 + (b.1 - a.1) * dt as f64 / span as f64)
        }
        (Some(a), _) => Some(a.1),
        (None, Some(b)) => Some(b.1),
        (None, None) => None,
    }
}

/// Error summary of locked estimates (tracking or holding) against a truth table.
/// Only estimates within the truth's time span are scored (the table is not
/// extrapolated): the others are counted and named, so a truth file of another
/// length or another run does not pass unnoticed.
pub fn error_summary(ests: &[Estimate], truth: &[(Nanos, f64)]) -> String {
    let (Some(first), Some(last)) = (truth.first(), truth.last()) else {
        return "error vs truth: the truth table is empty".to_string();
    };
    let span = format!(
        "{:.3}..{:.3} s",
        first.0 as f64 * 1e-9,
        last.0 as f64 * 1e-9
    );
    let locked = ests.iter().filter(|e| {
        matches!(
            e.state,
            vlsync_common::EstimatorState::Tracking | vlsync_common::EstimatorState::Holding
        )
    });
    let mut outside = 0usize;
    let mut errs: Vec<f64> = locked
        .filter_map(|e| {
            if (first.0..=last.0).contains(&e.t_ref_ns) {
                truth_at(truth, e.t_ref_ns).map(|o| (e.offset_s - o).abs())
            } else {
                outside += 1;
                None
            }
        })
        .collect();
    let mut left_out = if outside > 0 {
        format!(
            "; {outside} locked estimate(s) outside the truth's time span ({span}) not scored: is it this run's truth?"
        )
    } else {
        String::new()
    };
    // a truth that steps (the load-steps family: ±25 ms at once) is scored here
    // right after each step too, where `vlsyncd bench` leaves 3 s out
    let steps = truth
        .windows(2)
        .filter(|w| (w[1].1 - w[0].1).abs() > TRUTH_STEP_S)
        .count();
    if steps > 0 {
        left_out.push_str(&format!(
            "; the truth steps {steps} time(s), every estimate scored (`vlsyncd bench` leaves out the 3 s after each step)"
        ));
    }
    if errs.is_empty() {
        return format!("error vs truth: no locked estimate to score{left_out}");
    }
    errs.sort_by(f64::total_cmp);
    let n = errs.len();
    format!(
        "error vs truth over {n} locked estimates: MAE {:.3} ms, p95 {:.3} ms, max {:.3} ms, >20 ms {:.1} %{left_out}",
        errs.iter().sum::<f64>() / n as f64 * 1e3,
        // nearest rank, as `vlsyncd bench` scores
        errs[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1] * 1e3,
        errs[n - 1] * 1e3,
        errs.iter().filter(|e| **e > 0.020).count() as f64 * 100.0 / n as f64
    )
}

/// What is wrong with a stream's publish times as the order its samples were read
/// in: `Err` when one is not positive (a publisher that leaves them 0: merging by
/// them would feed one stream whole before the other), `Ok(Some)` when they go back
/// (two publishers on one stream; the merge still follows them), 1-based sample
/// numbers.
fn publish_problem(p: &[Nanos]) -> Result<Option<String>, String> {
    let secs = |t: Nanos| t as f64 * 1e-9;
    if let Some((i, &t)) = p.iter().enumerate().find(|(_, &t)| t <= 0) {
        return Err(format!(
            "publish time {} s of sample {} is not positive",
            secs(t),
            i + 1
        ));
    }
    Ok(p.windows(2).position(|w| w[1] < w[0]).map(|i| {
        format!(
            "publish times go back at sample {} ({:.9} s after {:.9} s)",
            i + 2,
            secs(p[i + 1]),
            secs(p[i])
        )
    }))
}

/// The `replay` command.
pub fn run_cli(a: &ReplayArgs<'_>) -> Result<(), String> {
    check_outputs(a)?;
    // before the run, so that a typo in a path does not cost it
    vlsync_common::file::check_writable("--out", a.out)?;
    if let Some(p) = a.plot {
        vlsync_common::file::check_writable("--plot", p)?;
    }
    let cfg = match a.config {
        Some(p) => Config::load(p).map_err(|e| e.to_string())?,
        None => Config::default(),
    };
    let read = |p: &Path| {
        if a.order == OrderArg::Stamp {
            // the publish column is not needed: a recording cut mid-row in it, or one
            // a third party wrote, replays all the same
            vlsync_sim::io::read_signature_csv(p).map(|(samples, _)| (samples, None))
        } else {
            vlsync_sim::io::read_recorded_csv(p).map(|r| (r.samples, r.publish))
        }
        .map_err(|e| e.to_string())
    };
    let ((cam_s, cam_pub), (lidar_s, lidar_pub)) = (read(a.cam)?, read(a.lidar)?);
    // publish times that cannot be the order the daemon read the samples in (not
    // positive: a publisher that leaves them 0): `auto` merges by stamp, an explicit
    // `publish` is obeyed with a warning; times that go back (two publishers on a
    // stream) are followed with a note
    let (mut wrong, mut back) = (None, None);
    for (path, p) in [(a.cam, &cam_pub), (a.lidar, &lidar_pub)] {
        match p.as_deref().map(publish_problem) {
            Some(Err(why)) if wrong.is_none() => wrong = Some(format!("{}: {why}", path.display())),
            Some(Ok(Some(why))) if back.is_none() => {
                back = Some(format!("{}: {why}", path.display()))
            }
            _ => {}
        }
    }
    let order = match (a.order, cam_pub.as_deref(), lidar_pub.as_deref()) {
        (OrderArg::Stamp, _, _) | (OrderArg::Auto, None, _) | (OrderArg::Auto, _, None) => {
            Order::Stamp
        }
        (OrderArg::Auto, Some(_), Some(_)) if wrong.is_some() => {
            vlsync_common::console::print_err(&format!(
                "--order auto: {}: merging by stamp\n",
                wrong.take().unwrap_or_default()
            ));
            Order::Stamp
        }
        (_, Some(c), Some(l)) => {
            if let Some(d) = wrong.take() {
                vlsync_common::console::print_err(&format!("warning: --order publish: {d}\n"));
            }
            if let Some(d) = back.take() {
                vlsync_common::console::print_err(&format!(
                    "note: {d}; merged in that order all the same (two publishers on one stream?)\n"
                ));
            }
            Order::Publish(c, l)
        }
        (OrderArg::Publish, c, _) => {
            let without = if c.is_none() { a.cam } else { a.lidar };
            return Err(format!(
                "--order publish: {} has no `publish` column (the fourth, as `vlsyncd record` writes it)",
                without.display()
            ));
        }
    };
    let truth = match a.truth {
        Some(p) => Some(vlsync_sim::io::read_truth_csv(p).map_err(|e| e.to_string())?),
        None => None,
    };
    let compared = match a.compare {
        Some(p) => crate::compare::read_estimates_csv(p).map_err(|e| e.to_string())?,
        None => Vec::new(),
    };
    let t0 = std::time::Instant::now();
    let (ests, stats) = run_estimator_in_order(&cfg.estimator, &cam_s, &lidar_s, order);
    let elapsed = t0.elapsed();
    write_estimates(a.out, &ests)?;
    // stderr through `print_err`: a closed or full one must not panic
    let err = vlsync_common::console::print_err;
    err(match order {
        Order::Stamp => "merged by stamp\n",
        Order::Publish(..) => "merged by publish time (the order the daemon read the samples in)\n",
    });
    err(&summary(&stats, &ests, [cam_s.len(), lidar_s.len()]));
    if let Some(tr) = &truth {
        err(&format!("{}\n", error_summary(&ests, tr)));
    }
    if let Some(p) = a.compare {
        let c = crate::compare::compare(&ests, &compared);
        err(&format!("{}\n", c.describe(&p.display().to_string())));
    }
    if let Some(p) = a.plot {
        let title = format!(
            "vlsyncd replay: {} + {}",
            a.cam.display(),
            a.lidar.display()
        );
        let svg = crate::plot::offset_svg_compared(&title, &ests, truth.as_deref(), &[], &compared);
        vlsync_common::file::write_atomically(p, svg.as_bytes())?;
        err(&format!("wrote plot {}\n", p.display()));
    }
    err(&format!(
        "estimator time: {:.2} ms for {} samples; wrote {}\n",
        elapsed.as_secs_f64() * 1e3,
        cam_s.len() + lidar_s.len(),
        a.out.display()
    ));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{error_summary, truth_at};
    use vlsync_common::{Estimate, EstimatorState, Polarity};

    fn est(t_s: f64, offset_s: f64) -> Estimate {
        Estimate {
            seq: 0,
            t_ref_ns: (t_s * 1e9) as i64,
            offset_s,
            drift: 0.0,
            offset_std_s: 1e-3,
            drift_std: 1e-6,
            state: EstimatorState::Tracking,
            polarity: Polarity::Positive,
            peak_score: 0.9,
            peak_ratio: 2.0,
            measured_offset_s: f64::NAN,
        }
    }

    #[test]
    fn clocks_seconds_apart_are_merged_by_the_prior_and_lock() {
        // a robot run whose camera clock is 5 s behind the LiDAR's (offset +5 s),
        // with the prior set to it: merged by raw stamps, every camera sample came
        // 5 s early and the estimator took the LiDAR for stalled (no lock at all)
        let run =
            vlsync_sim::families::generate(vlsync_sim::families::Family::Robot, 3, Some(60.0));
        let shift = 5_000_000_000;
        let cam: Vec<_> = run
            .cam
            .iter()
            .map(|s| vlsync_common::Sample {
                t_ns: s.t_ns - shift,
                ..*s
            })
            .collect();
        let cfg = vlsync_config::EstimatorConfig {
            lag_center_s: 5.0,
            ..Default::default()
        };
        let (ests, _) = super::run_estimator(&cfg, &cam, &run.lidar);
        let tracking: Vec<_> = ests
            .iter()
            .filter(|e| e.state == EstimatorState::Tracking)
            .collect();
        assert!(
            tracking.len() > ests.len() / 2,
            "{} of {}",
            tracking.len(),
            ests.len()
        );
        let last = tracking.last().unwrap();
        let truth = run.truth.offset_at(last.t_ref_ns) + 5.0;
        assert!(
            (last.offset_s - truth).abs() < 0.01,
            "{} vs {truth}",
            last.offset_s
        );
    }

    #[test]
    fn a_stepping_truth_is_said_to_be_scored_whole() {
        let step = [
            (0, 0.010),
            (5_000_000_000, 0.010),
            (5_010_000_000, 0.035),
            (10_000_000_000, 0.035),
        ];
        let ests = [est(2.0, 0.011), est(8.0, 0.036)];
        let s = error_summary(&ests, &step);
        assert!(
            s.ends_with(
                "; the truth steps 1 time(s), every estimate scored (`vlsyncd bench` leaves \
                 out the 3 s after each step)"
            ),
            "{s}"
        );
        // a drifting truth does not step
        let drift = [(0, 0.010), (10_000_000, 0.010001), (20_000_000, 0.010002)];
        assert!(!error_summary(&ests[..1], &drift).contains("steps"));
    }

    #[test]
    fn estimates_outside_the_truths_span_are_counted_not_scored() {
        let truth = [(0, 0.010), (10_000_000_000, 0.010)];
        let ests = [est(5.0, 0.011), est(9.0, 0.012), est(30.0, 0.5)];
        let s = error_summary(&ests, &truth);
        assert!(
            s.starts_with("error vs truth over 2 locked estimates: MAE 1.500 ms")
                && s.ends_with(
                    "; 1 locked estimate(s) outside the truth's time span (0.000..10.000 s) \
                     not scored: is it this run's truth?"
                ),
            "{s}"
        );
        let s = error_summary(&ests[..2], &truth);
        assert!(!s.contains("outside"), "{s}");
        let s = error_summary(&ests[2..], &truth);
        assert!(
            s.starts_with("error vs truth: no locked estimate to score; 1 locked"),
            "{s}"
        );
        assert_eq!(
            error_summary(&ests, &[]),
            "error vs truth: the truth table is empty"
        );
    }

    #[test]
    fn the_p95_is_the_nearest_rank_as_bench_scores_it() {
        let truth = [(0, 0.0), (100_000_000_000, 0.0)];
        // errors 1..=20 ms: the nearest rank of 95 % of 20 is the 19th
        let ests: Vec<Estimate> = (1..=20).map(|i| est(i as f64, i as f64 * 1e-3)).collect();
        let s = error_summary(&ests, &truth);
        assert!(s.contains("p95 19.000 ms, max 20.000 ms"), "{s}");
        let s = error_summary(&ests[..1], &truth);
        assert!(s.contains("p95 1.000 ms, max 1.000 ms"), "{s}");
    }

    #[test]
    fn the_truth_is_interpolated_and_clamped_even_across_the_whole_stamp_range() {
        let tr = [(0, 0.0), (10, 1.0)];
        assert_eq!(truth_at(&tr, 5), Some(0.5));
        assert_eq!(truth_at(&tr, -3), Some(0.0));
        assert_eq!(truth_at(&tr, 30), Some(1.0));
        assert_eq!(truth_at(&[], 30), None);
        // rows 18 s of i64 nanoseconds apart: the differences overflow i64
        let far = [
            (-9_000_000_000_000_000_000, 0.0),
            (9_000_000_000_000_000_000, 2.0),
        ];
        let mid = truth_at(&far, 0).unwrap();
        assert!((mid - 1.0).abs() < 1e-9, "{mid}");
        assert_eq!(truth_at(&far, i64::MIN), Some(0.0));
        assert_eq!(truth_at(&far, i64::MAX), Some(2.0));
    }
}
