//! Scoring of an estimator's output against a run's truth.
//!
//! Definitions (error = `offset_s - truth.offset_at(t_ref_ns)`):
//! * **first lock**: the first estimate (in slice order) whose state is `Tracking`;
//! * **scored** estimates: from the first lock on (inclusive), state `Tracking` or
//!   `Holding`, excluding those with `t_ref` in `[step, step + 3 s]` for any step time;
//! * `mae_s`, `p95_s`, `share_over_20ms`: of |error| over the scored estimates;
//! * `coverage`: estimates from the first lock on in `Tracking`/`Holding` divided by all
//!   estimates from the first lock on;
//! * `time_to_first_lock_s`: `t_ref` of the first lock minus the run's motion start;
//! * `consistency_2sigma`: share of scored `Tracking` estimates with
//!   `|error| <= 2 offset_std_s + 1 ms`;
//! * `standstill_tracking_over_20ms`: `Tracking` estimates (anywhere) with `t_ref` inside
//!   a standstill interval and |error| > 20 ms.
//!
//! Statistics over an empty set are NaN (and `coverage` 0 without a lock), so a run that
//! never locks cannot look good.
//!
//! ```
//! use vlsync_common::{Estimate, EstimatorState, Polarity};
//! use vlsync_sim::{families::{generate, Family}, score::score_estimates};
//! let run = generate(Family::Robot, 1, Some(20.0));
//! let est: Vec<Estimate> = (0..30).map(|i| {
//!     let t = 5_000_000_000 + i * 500_000_000;
//!     Estimate { seq: i as u64, t_ref_ns: t, offset_s: run.truth.offset_at(t) + 0.002,
//!         drift: 0.0, offset_std_s: 0.002, drift_std: 0.0, state: EstimatorState::Tracking,
//!         polarity: Polarity::Negative, peak_score: 0.9, peak_ratio: 2.0, measured_offset_s: f64::NAN }
//! }).collect();
//! let s = score_estimates(&est, &run);
//! assert_eq!(s.n, 30);
//! assert!((s.mae_s - 0.002).abs() < 1e-9 && s.share_over_20ms == 0.0 && s.coverage == 1.0);
//! assert_eq!(s.consistency_2sigma, Some(1.0));
//! ```

use crate::families::SimRun;
use std::fmt;
use vlsync_common::{nanos_to_secs, Estimate, EstimatorState, Nanos, NANOS_PER_SEC};

/// Estimates within this long after a step are not scored, ns.
pub const STEP_GRACE_NS: Nanos = 3 * NANOS_PER_SEC;
/// The error threshold of `share_over_20ms` and `standstill_tracking_over_20ms`, seconds.
pub const BIG_ERROR_S: f64 = 0.020;

/// Score of one run (or, from [`Score::aggregate`], of several).
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    /// Scored estimates.
    pub n: usize,
    /// All estimates given.
    pub n_total: usize,
    /// Mean |error| over scored estimates, s (NaN when none).
    pub mae_s: f64,
    /// Mean signed error (bias) over scored estimates, s (NaN when none).
    pub bias_s: f64,
    /// 95th percentile of |error| (nearest rank), s (NaN when none).
    pub p95_s: f64,
    /// Largest |error| over scored estimates, s (NaN when none).
    pub max_abs_s: f64,
    /// Share of scored estimates with |error| > 20 ms (NaN when none); aggregated: the
    /// worst run's.
    pub share_over_20ms: f64,
    /// The same share over all scored estimates together (for one run, the run's).
    pub share_over_20ms_pooled: f64,
    /// Tracking/Holding share from the first lock on (0 without a lock).
    pub coverage: f64,
    /// First lock time minus motion start, s; `None` when never locked.
    pub time_to_first_lock_s: Option<f64>,
    /// Share of scored Tracking estimates within 2σ + 1 ms; `None` when not applicable.
    pub consistency_2sigma: Option<f64>,
    /// Tracking estimates inside a standstill with |error| > 20 ms.
    pub standstill_tracking_over_20ms: usize,
    /// Runs aggregated (1 for a single run).
    pub runs: usize,
}

struct Item {
    t: Nanos,
    err: f64,
    std: Option<f64>,
    state: EstimatorState,
}

fn in_step_grace(run: &SimRun, t: Nanos) -> bool {
    run.step_times_ns
        .iter()
        .any(|&s| t >= s && t <= s.saturating_add(STEP_GRACE_NS))
}

fn in_standstill(run: &SimRun, t: Nanos) -> bool {
    run.standstills.iter().any(|&(a, b)| t >= a && t <= b)
}

fn ok_state(s: EstimatorState) -> bool {
    matches!(s, EstimatorState::Tracking | EstimatorState::Holding)
}

/// The first lock's index and the scored items (see the module docs).
fn scored_items<'a>(items: &'a [Item], run: &SimRun) -> (Option<usize>, Vec<&'a Item>) {
    let first = items
        .iter()
        .position(|e| e.state == EstimatorState::Tracking);
    let locked: &[Item] = first.map_or(&[], |i| &items[i..]);
    let scored = locked
        .iter()
        .filter(|e| ok_state(e.state) && !in_step_grace(run, e.t))
        .collect();
    (first, scored)
}

/// Reference times of the estimates [`score_estimates`] scores, in order: what a bound
/// must be evaluated at to stand beside the score ([`crate::crb::causal_std_s`]).
pub fn scored_times(estimates: &[Estimate], run: &SimRun) -> Vec<Nanos> {
    let items: Vec<Item> = estimates
        .iter()
        .map(|e| Item {
            t: e.t_ref_ns,
            err: 0.0,
            std: None,
            state: e.state,
        })
        .collect();
    scored_items(&items, run).1.iter().map(|e| e.t).collect()
}

fn score_items(items: &[Item], run: &SimRun, with_std: bool) -> Score {
    let (first, scored) = scored_items(items, run);
    let locked: &[Item] = first.map_or(&[], |i| &items[i..]);
    let mut abs: Vec<f64> = scored.iter().map(|e| e.err.abs()).collect();
    abs.sort_by(|a, b| a.total_cmp(b));
    let n = abs.len();
    let mean = |v: &mut dyn Iterator<Item = f64>| -> f64 {
        let (s, c) = v.fold((0.0, 0usize), |(s, c), x| (s + x, c + 1));
        if c == 0 {
            f64::NAN
        } else {
            s / c as f64
        }
    };
    let p95_s = if n == 0 {
        f64::NAN
    } else {
        abs[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1]
    };
    let share = if n == 0 {
        f64::NAN
    } else {
        abs.iter().filter(|&&a| a > BIG_ERROR_S).count() as f64 / n as f64
    };
    let consistency_2sigma = if with_std {
        let tr: Vec<&&Item> = scored
            .iter()
            .filter(|e| e.state == EstimatorState::Tracking)
            .collect();
        if tr.is_empty() {
            None
        } else {
            let good = tr
                .iter()
                .filter(|e| e.err.abs() <= 2.0 * e.std.unwrap_or(0.0) + 0.001)
                .count();
            Some(good as f64 / tr.len() as f64)
        }
    } else {
        None
    };
    Score {
        n,
        n_total: items.len(),
        mae_s: mean(&mut abs.iter().copied()),
        bias_s: mean(&mut scored.iter().map(|e| e.err)),
        p95_s,
        max_abs_s: abs.last().copied().unwrap_or(f64::NAN),
        share_over_20ms: share,
        share_over_20ms_pooled: share,
        coverage: if locked.is_empty() {
            0.0
        } else {
            locked.iter().filter(|e| ok_state(e.state)).count() as f64 / locked.len() as f64
        },
        time_to_first_lock_s: first
            .map(|i| nanos_to_secs(items[i].t.saturating_sub(run.motion_start_ns))),
        consistency_2sigma,
        standstill_tracking_over_20ms: items
            .iter()
            .filter(|e| {
                e.state == EstimatorState::Tracking
                    && in_standstill(run, e.t)
                    && e.err.abs() > BIG_ERROR_S
            })
            .count(),
        runs: 1,
    }
}

/// Scores estimator output against the run (see the [module docs](self)).
/// A NaN offset counts as an error larger than any threshold.
pub fn score_estimates(estimates: &[Estimate], run: &SimRun) -> Score {
    let items: Vec<Item> = estimates
        .iter()
        .map(|e| Item {
            t: e.t_ref_ns,
            err: nan_to_inf(e.offset_s - run.truth.offset_at(e.t_ref_ns)),
            std: Some(e.offset_std_s),
            state: e.state,
        })
        .collect();
    score_items(&items, run, true)
}

/// Scores the baseline's `(t_lidar_ns, offset_s)` output: every estimate counts as
/// `Tracking`; there is no standard deviation, so `consistency_2sigma` is `None`.
pub fn score_pairs(pairs: &[(Nanos, f64)], run: &SimRun) -> Score {
    let items: Vec<Item> = pairs
        .iter()
        .map(|&(t, o)| Item {
            t,
            err: nan_to_inf(o - run.truth.offset_at(t)),
            std: None,
            state: EstimatorState::Tracking,
        })
        .collect();
    score_items(&items, run, false)
}

fn nan_to_inf(x: f64) -> f64 {
    if x.is_nan() {
        f64::INFINITY
    } else {
        x
    }
}

impl Score {
    /// Combines per-seed scores: mean of `mae_s`, `bias_s`, `p95_s` and
    /// `consistency_2sigma` (over the runs that have one), max of `max_abs_s`,
    /// `share_over_20ms` and `time_to_first_lock_s` (`None` if any run never locked),
    /// `share_over_20ms_pooled` over all the runs' scored estimates together,
    /// min of `coverage`, sums of the counts. An empty slice gives NaN statistics.
    pub fn aggregate(scores: &[Score]) -> Score {
        let k = scores.len();
        let mean = |f: &dyn Fn(&Score) -> f64| {
            if k == 0 {
                f64::NAN
            } else {
                scores.iter().map(f).sum::<f64>() / k as f64
            }
        };
        let max = |f: &dyn Fn(&Score) -> f64| {
            scores
                .iter()
                .map(f)
                .fold(if k == 0 { f64::NAN } else { f64::NEG_INFINITY }, |a, b| {
                    if a.is_nan() || b.is_nan() {
                        f64::NAN
                    } else {
                        a.max(b)
                    }
                })
        };
        let cons: Vec<f64> = scores.iter().filter_map(|s| s.consistency_2sigma).collect();
        let ttl: Option<Vec<f64>> = scores.iter().map(|s| s.time_to_first_lock_s).collect();
        Score {
            n: scores.iter().map(|s| s.n).sum(),
            n_total: scores.iter().map(|s| s.n_total).sum(),
            mae_s: mean(&|s| s.mae_s),
            bias_s: mean(&|s| s.bias_s),
            p95_s: mean(&|s| s.p95_s),
            max_abs_s: max(&|s| s.max_abs_s),
            share_over_20ms: max(&|s| s.share_over_20ms),
            share_over_20ms_pooled: {
                let n: usize = scores.iter().map(|s| s.n).sum();
                let over: f64 = scores
                    .iter()
                    .filter(|s| s.n > 0)
                    .map(|s| s.share_over_20ms_pooled * s.n as f64)
                    .sum();
                if n == 0 {
                    f64::NAN
                } else {
                    over / n as f64
                }
            },
            coverage: if k == 0 {
                f64::NAN
            } else {
                scores
                    .iter()
                    .map(|s| s.coverage)
                    .fold(f64::INFINITY, f64::min)
            },
            time_to_first_lock_s: match ttl {
                Some(v) if !v.is_empty() => Some(v.into_iter().fold(f64::NEG_INFINITY, f64::max)),
                _ => None,
            },
            consistency_2sigma: if cons.is_empty() {
                None
            } else {
                Some(cons.iter().sum::<f64>() / cons.len() as f64)
            },
            standstill_tracking_over_20ms: scores
                .iter()
                .map(|s| s.standstill_tracking_over_20ms)
                .sum(),
            runs: scores.iter().map(|s| s.runs).sum(),
        }
    }
}

impl fmt::Display for Score {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let opt = |o: Option<f64>, scale: f64, unit: &str| match o {
            Some(v) => format!("{:.2}{unit}", v * scale),
            None => "n/a".to_string(),
        };
        write!(
            f,
            "n={} MAE={:.2} ms p95={:.2} ms bias={:+.2} ms max={:.2} ms >20ms={:.1} % coverage={:.1} % lock={} consistency={} standstill>20ms={}",
            self.n,
            self.mae_s * 1e3,
            self.p95_s * 1e3,
            self.bias_s * 1e3,
            self.max_abs_s * 1e3,
            self.share_over_20ms * 100.0,
            self.coverage * 100.0,
            opt(self.time_to_first_lock_s, 1.0, " s"),
            opt(self.consistency_2sigma, 100.0, " %"),
            self.standstill_tracking_over_20ms
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::families::{generate, Family};
    use vlsync_common::{secs_to_nanos, Polarity};

    fn est(t_s: f64, off: f64, std: f64, state: EstimatorState) -> Estimate {
        Estimate {
            seq: 0,
            t_ref_ns: secs_to_nanos(t_s),
            offset_s: off,
            drift: 0.0,
            offset_std_s: std,
            drift_std: 0.0,
            state,
            polarity: Polarity::Negative,
            peak_score: 0.0,
            peak_ratio: 0.0,
            measured_offset_s: f64::NAN,
        }
    }

    #[test]
    fn definitions_hand_checked() {
        use EstimatorState::*;
        let mut run = generate(Family::Robot, 2, Some(60.0));
        run.step_times_ns = vec![secs_to_nanos(20.0)];
        run.standstills = vec![(secs_to_nanos(30.0), secs_to_nanos(40.0))];
        run.motion_start_ns = secs_to_nanos(2.0);
        let o = |t: f64| run.truth.offset_at(secs_to_nanos(t));
        let list = vec![
            est(3.0, o(3.0) + 0.5, 0.1, Acquiring), // before lock: ignored
            est(5.0, o(5.0) + 0.001, 0.001, Tracking), // first lock; consistent (1 ms <= 3 ms)
            est(6.0, o(6.0) - 0.030, 0.001, Tracking), // > 20 ms, inconsistent
            est(7.0, o(7.0) + 0.004, 0.01, Holding), // scored, not in consistency
            est(8.0, o(8.0) + 0.5, 0.1, Lost),      // hurts coverage only
            est(21.0, o(21.0) + 0.2, 0.1, Tracking), // in step grace: not scored
            est(35.0, o(35.0) + 0.025, 0.001, Tracking), // standstill, > 20 ms
            est(36.0, o(36.0) + 0.010, 0.001, Holding), // standstill but holding
        ];
        let s = score_estimates(&list, &run);
        assert_eq!(s.n, 5);
        assert_eq!(s.n_total, 8);
        let errs = [0.001, 0.030, 0.004, 0.025, 0.010];
        let mae: f64 = errs.iter().sum::<f64>() / 5.0;
        assert!((s.mae_s - mae).abs() < 1e-9, "{s}");
        assert!((s.p95_s - 0.030).abs() < 1e-9);
        assert!((s.share_over_20ms - 0.4).abs() < 1e-12);
        assert!((s.coverage - 6.0 / 7.0).abs() < 1e-12);
        assert!((s.time_to_first_lock_s.unwrap() - 3.0).abs() < 1e-9);
        // scored tracking: 5 s (ok), 6 s (bad), 35 s (bad)
        assert!((s.consistency_2sigma.unwrap() - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(s.standstill_tracking_over_20ms, 1);
        let times: Vec<Nanos> = [5.0, 6.0, 7.0, 35.0, 36.0].map(secs_to_nanos).to_vec();
        assert_eq!(scored_times(&list, &run), times);
    }

    #[test]
    fn never_locked_and_nan() {
        let run = generate(Family::Robot, 2, Some(20.0));
        let s = score_estimates(&[est(5.0, 0.0, 0.01, EstimatorState::Acquiring)], &run);
        assert_eq!((s.n, s.coverage, s.time_to_first_lock_s), (0, 0.0, None));
        assert!(s.mae_s.is_nan());
        let s = score_pairs(&[(secs_to_nanos(5.0), f64::NAN)], &run);
        assert_eq!(s.share_over_20ms, 1.0);
        assert_eq!(s.consistency_2sigma, None);
        let agg = Score::aggregate(&[s.clone(), score_estimates(&[], &run)]);
        assert_eq!(agg.time_to_first_lock_s, None);
        assert_eq!(agg.runs, 2);
    }

    #[test]
    fn aggregate_rules() {
        let run = generate(Family::Robot, 2, Some(20.0));
        let o = |t: f64| run.truth.offset_at(secs_to_nanos(t));
        let a = score_pairs(&[(secs_to_nanos(4.0), o(4.0) + 0.01)], &run);
        let b = score_pairs(
            &[
                (secs_to_nanos(6.0), o(6.0) + 0.03),
                (secs_to_nanos(7.0), o(7.0) + 0.03),
            ],
            &run,
        );
        let g = Score::aggregate(&[a.clone(), b.clone()]);
        assert!((g.mae_s - 0.02).abs() < 1e-9);
        assert_eq!(g.share_over_20ms, 1.0);
        // pooled: 2 of the 3 scored estimates are beyond 20 ms
        assert!((g.share_over_20ms_pooled - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(g.n, 3);
        assert_eq!(g.coverage, 1.0);
        let lock = |s: &Score| s.time_to_first_lock_s.unwrap();
        assert!((lock(&g) - lock(&b)).abs() < 1e-12 && lock(&b) > lock(&a));
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        #[test]
        fn statistics_are_ordered_and_bounded(
            rows in proptest::collection::vec((0u8..4, -0.2f64..0.2, 0.0f64..0.05), 0..80)
        ) {
            let run = generate(Family::LoadSteps, 1, Some(60.0));
            let states = [EstimatorState::Acquiring, EstimatorState::Tracking, EstimatorState::Holding, EstimatorState::Lost];
            let list: Vec<Estimate> = rows
                .iter()
                .enumerate()
                .map(|(i, &(st, e, sd))| {
                    let t = 2.0 + i as f64 * 0.5;
                    est(t, run.truth.offset_at(secs_to_nanos(t)) + e, sd, states[st as usize])
                })
                .collect();
            let s = score_estimates(&list, &run);
            proptest::prop_assert!(s.n <= s.n_total);
            if s.n > 0 {
                proptest::prop_assert!(s.mae_s <= s.max_abs_s + 1e-15 && s.p95_s <= s.max_abs_s);
                proptest::prop_assert!(s.bias_s.abs() <= s.mae_s + 1e-15);
                proptest::prop_assert!((0.0..=1.0).contains(&s.share_over_20ms));
            } else {
                proptest::prop_assert!(s.mae_s.is_nan());
            }
            proptest::prop_assert!((0.0..=1.0).contains(&s.coverage));
            if let Some(c) = s.consistency_2sigma {
                proptest::prop_assert!((0.0..=1.0).contains(&c));
            }
            let g = Score::aggregate(&[s.clone(), s.clone()]);
            proptest::prop_assert_eq!(g.n, 2 * s.n);
            proptest::prop_assert!(g.mae_s == s.mae_s || (g.mae_s.is_nan() && s.mae_s.is_nan()));
        }
    }
}
