//! Small statistics of the harness: error summaries, summaries of a long run by
//! periods of reference time, and latency percentiles merged from per-period
//! status snapshots.

use vlsync_common::{Estimate, EstimatorState, Nanos};

/// The `q` quantile (0..=1) of `v` by the nearest-rank rule (smallest value with
/// at least `q` of the data at or below it); `None` when empty.
pub fn quantile(v: &[f64], q: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = ((q.clamp(0.0, 1.0) * s.len() as f64).ceil() as usize).max(1);
    Some(s[rank - 1])
}

/// Error of estimates against a truth, seconds.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ErrorStats {
    /// Estimates scored.
    pub n: usize,
    /// Mean absolute error.
    pub mae: f64,
    /// Root mean square.
    pub rms: f64,
    /// 95th percentile of the absolute error.
    pub p95: f64,
    /// Largest absolute error.
    pub max: f64,
}

impl ErrorStats {
    /// From signed errors (seconds).
    pub fn of(errs: &[f64]) -> Self {
        if errs.is_empty() {
            return Self::default();
        }
        let n = errs.len() as f64;
        let abs: Vec<f64> = errs.iter().map(|e| e.abs()).collect();
        Self {
            n: errs.len(),
            mae: abs.iter().sum::<f64>() / n,
            rms: (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
            p95: quantile(&abs, 0.95).unwrap_or(0.0),
            max: abs.iter().fold(0.0, |m: f64, e| m.max(*e)),
        }
    }

    /// "n estimates: MAE .. ms, p95 .. ms, max .. ms" or a note when empty.
    pub fn describe(&self) -> String {
        if self.n == 0 {
            return "no estimate to score".into();
        }
        format!(
            "{} estimates: MAE {:.2} ms, RMS {:.2} ms, p95 {:.2} ms, max {:.2} ms",
            self.n,
            self.mae * 1e3,
            self.rms * 1e3,
            self.p95 * 1e3,
            self.max * 1e3
        )
    }
}

/// One period of a long run ([`Periods`]): its locked estimates scored against the
/// truth, the estimates per state, the σ's honesty and the drift at its end.
#[derive(Debug, Clone, PartialEq)]
pub struct PeriodSummary {
    /// The period, seconds of LiDAR reference time: `[start_s, end_s)`.
    pub start_s: f64,
    pub end_s: f64,
    /// Error of the locked (tracking or holding) estimates.
    pub errors: ErrorStats,
    pub tracking: usize,
    pub holding: usize,
    /// Estimates acquiring or lost.
    pub unlocked: usize,
    /// Share of the tracking estimates within 2σ + 1 ms of the truth (`None`
    /// without a tracking estimate).
    pub within_2sigma: Option<f64>,
    /// Drift of the period's last estimate (dimensionless).
    pub drift: f64,
}

impl PeriodSummary {
    /// One line: `--- 298-598 s: 600 estimate(s) (468 tracking, 132 holding); locked:
    /// 600 estimates: MAE ... ms, RMS ..., p95 ..., max ...; tracking within 2σ+1 ms
    /// 100.0 %; drift +24.4 ppm (truth +25.0 ppm)`.
    pub fn describe(&self, truth_drift: f64) -> String {
        let n = self.tracking + self.holding + self.unlocked;
        let mut s = format!(
            "--- {:.0}-{:.0} s: {n} estimate(s) ({} tracking, {} holding",
            self.start_s, self.end_s, self.tracking, self.holding
        );
        if self.unlocked > 0 {
            s += &format!(", {} acquiring or lost", self.unlocked);
        }
        s += "); locked: ";
        s += &self.errors.describe();
        if let Some(c) = self.within_2sigma {
            s += &format!("; tracking within 2σ+1 ms {:.1} %", c * 100.0);
        }
        s += &format!(
            "; drift {:+.1} ppm (truth {:+.1} ppm)",
            self.drift * 1e6,
            truth_drift * 1e6
        );
        s
    }
}

/// Summaries of a long run by periods of reference time (the demo's `--summary-every`),
/// counted from the first estimate's: estimates go in as they arrive with the truth at
/// their reference time; when one falls into another period than the one being
/// filled, that period's summary comes out. A restart whose reference times go back
/// starts a new period too. A run shorter than one period has one period, which
/// [`Periods::finish`] gives.
///
/// ```
/// use vlsync_common::{Estimate, EstimatorState, Polarity};
/// use vlsyncd::harness::stats::Periods;
/// let mut p = Periods::new(10.0);
/// let est = |t_s: f64, off: f64| Estimate {
///     seq: 0,
///     t_ref_ns: (t_s * 1e9) as i64,
///     offset_s: off,
///     drift: 0.0,
///     offset_std_s: 0.001,
///     drift_std: 0.0,
///     state: EstimatorState::Tracking,
///     polarity: Polarity::Negative,
///     peak_score: 0.9,
///     peak_ratio: 2.0,
///     measured_offset_s: off,
/// };
/// assert!(p.add(&est(1.0, 0.002), 0.0).is_none());
/// assert!(p.add(&est(10.5, -0.001), 0.0).is_none());
/// let s = p.add(&est(11.5, 0.0), 0.0).expect("the first 10 s are complete");
/// assert_eq!((s.start_s, s.end_s, s.tracking), (1.0, 11.0, 2));
/// assert!((s.errors.mae - 0.0015).abs() < 1e-12);
/// assert_eq!(s.within_2sigma, Some(1.0));
/// assert_eq!(p.finish().map(|s| s.start_s), Some(11.0));
/// ```
#[derive(Debug, Clone)]
pub struct Periods {
    period_ns: Nanos,
    /// Reference time of the first estimate: period 0 starts there.
    origin: Option<Nanos>,
    /// Index of the period being filled, if any estimate is in it.
    current: Option<i64>,
    errs: Vec<f64>,
    tracking: usize,
    holding: usize,
    unlocked: usize,
    tracking_within: usize,
    drift: f64,
}

impl Periods {
    /// Periods of `period_s` seconds (at least 1 ms).
    pub fn new(period_s: f64) -> Self {
        Self {
            period_ns: ((period_s * 1e9) as Nanos).max(1_000_000),
            origin: None,
            current: None,
            errs: Vec::new(),
            tracking: 0,
            holding: 0,
            unlocked: 0,
            tracking_within: 0,
            drift: 0.0,
        }
    }

    /// Adds an estimate and the true offset at its reference time; returns the
    /// summary of the period it closes, if it starts another.
    pub fn add(&mut self, e: &Estimate, truth_s: f64) -> Option<PeriodSummary> {
        let origin = *self.origin.get_or_insert(e.t_ref_ns);
        let idx = e.t_ref_ns.saturating_sub(origin).div_euclid(self.period_ns);
        let done = match self.current {
            Some(c) if c != idx => self.finish(),
            _ => None,
        };
        self.current = Some(idx);
        let err = e.offset_s - truth_s;
        match e.state {
            EstimatorState::Tracking => {
                self.tracking += 1;
                self.errs.push(err);
                if err.abs() <= 2.0 * e.offset_std_s + 1e-3 {
                    self.tracking_within += 1;
                }
            }
            EstimatorState::Holding => {
                self.holding += 1;
                self.errs.push(err);
            }
            EstimatorState::Acquiring | EstimatorState::Lost => self.unlocked += 1,
        }
        self.drift = e.drift;
        done
    }

    /// The summary of the period being filled (then empty), if any.
    pub fn finish(&mut self) -> Option<PeriodSummary> {
        let idx = self.current.take()?;
        let start_s = (self.origin.unwrap_or(0) as f64 + idx as f64 * self.period_ns as f64) * 1e-9;
        let s = PeriodSummary {
            start_s,
            end_s: start_s + self.period_ns as f64 * 1e-9,
            errors: ErrorStats::of(&self.errs),
            tracking: self.tracking,
            holding: self.holding,
            unlocked: self.unlocked,
            within_2sigma: (self.tracking > 0)
                .then(|| self.tracking_within as f64 / self.tracking as f64),
            drift: self.drift,
        };
        self.errs.clear();
        (
            self.tracking,
            self.holding,
            self.unlocked,
            self.tracking_within,
        ) = (0, 0, 0, 0);
        Some(s)
    }
}

/// Latency summary of one status period: `count` values with percentiles
/// `[p50, p99, max]` (ns, each the upper bound of its histogram bucket).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PeriodLatency {
    /// Values in the period.
    pub count: u64,
    /// `[p50, p99, max]`, ns.
    pub pct: [u64; 3],
}

/// Merges per-period summaries into an upper bound of the `q` quantile (0.5 or
/// 0.99) of all their values together.
///
/// Of the values of one period, at most half lie above its p50, at most 1 %
/// above its p99 and none above its max. So at any `x` the share of all values
/// above `x` is at most `Σ count_i · f_i(x) / Σ count_i`, with `f_i` that step
/// bound; the smallest `x` among the periods' own percentiles where this is
/// `<= 1 - q` is an upper bound of the merged quantile (exact when one period
/// holds everything). `None` without values.
pub fn merged_quantile_bound(periods: &[PeriodLatency], q: f64) -> Option<u64> {
    let total = periods.iter().fold(0u64, |a, p| a.saturating_add(p.count));
    if total == 0 {
        return None;
    }
    let above = |x: u64| -> f64 {
        periods
            .iter()
            .map(|p| {
                let f = if x >= p.pct[2] {
                    0.0
                } else if x >= p.pct[1] {
                    0.01
                } else if x >= p.pct[0] {
                    0.5
                } else {
                    1.0
                };
                p.count as f64 * f
            })
            .sum::<f64>()
            / total as f64
    };
    let mut candidates: Vec<u64> = periods
        .iter()
        .filter(|p| p.count > 0)
        .flat_map(|p| p.pct)
        .collect();
    candidates.sort_unstable();
    candidates
        .into_iter()
        .find(|&x| above(x) <= 1.0 - q + 1e-12)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_and_error_stats() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.95), Some(95.0));
        assert_eq!(quantile(&v, 0.0), Some(1.0));
        assert_eq!(quantile(&v, 1.0), Some(100.0));
        assert_eq!(quantile(&[], 0.5), None);
        let s = ErrorStats::of(&[0.001, -0.003, 0.002]);
        assert_eq!(s.n, 3);
        assert!((s.mae - 0.002).abs() < 1e-12);
        assert!((s.max - 0.003).abs() < 1e-12);
        assert!((s.p95 - 0.003).abs() < 1e-12);
        assert!(s.describe().contains("MAE 2.00 ms"));
        assert_eq!(ErrorStats::of(&[]).describe(), "no estimate to score");
    }

    fn est(t_s: f64, offset_s: f64, std_s: f64, state: EstimatorState) -> Estimate {
        Estimate {
            seq: 0,
            t_ref_ns: (t_s * 1e9) as i64,
            offset_s,
            drift: 20e-6,
            offset_std_s: std_s,
            drift_std: 1e-6,
            state,
            polarity: vlsync_common::Polarity::Positive,
            peak_score: 0.9,
            peak_ratio: 2.0,
            measured_offset_s: offset_s,
        }
    }

    #[test]
    fn periods_score_locked_estimates_and_count_the_rest() {
        use EstimatorState::*;
        let mut p = Periods::new(300.0);
        // periods count from the first estimate's reference time, here -2 s
        assert!(p.add(&est(-2.0, 0.5, 0.5, Acquiring), 0.1).is_none());
        assert!(p.add(&est(0.5, 0.5, 0.5, Acquiring), 0.1).is_none());
        // tracking: 2 ms off with σ 1 ms is within 2σ + 1 ms, 4 ms off is not
        assert!(p.add(&est(10.0, 0.102, 0.001, Tracking), 0.1).is_none());
        assert!(p.add(&est(20.0, 0.096, 0.001, Tracking), 0.1).is_none());
        // holding is scored but not in the σ check
        assert!(p.add(&est(297.9, 0.1, 0.0001, Holding), 0.0999).is_none());
        let s = p.add(&est(298.0, 0.1, 0.001, Tracking), 0.1).unwrap();
        assert_eq!((s.start_s, s.end_s), (-2.0, 298.0));
        assert_eq!((s.tracking, s.holding, s.unlocked), (2, 1, 2));
        assert_eq!(s.errors.n, 3);
        assert!((s.errors.max - 0.004).abs() < 1e-9);
        assert!((s.errors.mae - (0.002 + 0.004 + 0.0001) / 3.0).abs() < 1e-9);
        assert_eq!(s.within_2sigma, Some(0.5));
        let line = s.describe(25e-6);
        assert!(
            line.starts_with("--- -2-298 s: 5 estimate(s) (2 tracking, 1 holding, 2 acquiring or lost); locked: 3 estimates: MAE 2.03 ms")
                && line.contains("within 2σ+1 ms 50.0 %")
                && line.ends_with("drift +20.0 ppm (truth +25.0 ppm)"),
            "{line}"
        );
        // a restart whose reference times go back closes the period too
        let back = p.add(&est(5.0, 0.1, 0.001, Tracking), 0.1).unwrap();
        assert_eq!((back.start_s, back.end_s, back.tracking), (298.0, 598.0, 1));
        let last = p.finish().unwrap();
        assert_eq!((last.start_s, last.tracking), (-2.0, 1));
        assert!(p.finish().is_none());
        // a run shorter than one period: nothing until `finish`, then one period
        let mut short = Periods::new(300.0);
        for t in [-2.0, 20.0, 57.5] {
            assert!(short.add(&est(t, 0.5, 0.5, Acquiring), 0.1).is_none());
        }
        let only = short.finish().unwrap();
        assert_eq!(
            (only.unlocked, only.errors.n, only.within_2sigma),
            (3, 0, None)
        );
        assert!(only
            .describe(0.0)
            .contains("; locked: no estimate to score;"));
    }

    #[test]
    fn merged_bound_is_exact_for_one_period_and_bounds_several() {
        let one = [PeriodLatency {
            count: 100,
            pct: [10, 50, 80],
        }];
        assert_eq!(merged_quantile_bound(&one, 0.5), Some(10));
        assert_eq!(merged_quantile_bound(&one, 0.99), Some(50));
        // two periods: a quiet one and a slow one of equal size
        let two = [
            PeriodLatency {
                count: 100,
                pct: [10, 20, 30],
            },
            PeriodLatency {
                count: 100,
                pct: [100, 200, 300],
            },
        ];
        // at most the slow half lies above 30, so the median is <= 30; above 200
        // at most 1 value of 200 lies (the slow period's 1 %), so p99 <= 200
        assert_eq!(merged_quantile_bound(&two, 0.5), Some(30));
        assert_eq!(merged_quantile_bound(&two, 0.99), Some(200));
        // a small slow period barely moves the p99 bound
        let mixed = [
            PeriodLatency {
                count: 990,
                pct: [10, 20, 30],
            },
            PeriodLatency {
                count: 10,
                pct: [100, 200, 300],
            },
        ];
        assert_eq!(merged_quantile_bound(&mixed, 0.99), Some(30));
        assert_eq!(merged_quantile_bound(&[], 0.5), None);
    }

    /// The bound holds on random data: merged exact quantiles never exceed it.
    #[test]
    fn merged_bound_bounds_the_exact_quantile() {
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as f64 / (1u64 << 31) as f64
        };
        for _ in 0..200 {
            let mut all = vec![];
            let mut periods = vec![];
            for _ in 0..(1 + (rnd() * 6.0) as usize) {
                let n = 1 + (rnd() * 60.0) as usize;
                let scale = 1.0 + rnd() * 100.0;
                let v: Vec<f64> = (0..n)
                    .map(|_| (rnd() * rnd() * scale * 1000.0).floor())
                    .collect();
                let p = |q| quantile(&v, q).unwrap() as u64;
                periods.push(PeriodLatency {
                    count: n as u64,
                    pct: [p(0.5), p(0.99), p(1.0)],
                });
                all.extend(v);
            }
            for q in [0.5, 0.99] {
                let exact = quantile(&all, q).unwrap() as u64;
                let bound = merged_quantile_bound(&periods, q).unwrap();
                assert!(bound >= exact, "q {q}: bound {bound} < exact {exact}");
            }
        }
    }
}
