//! Small statistics of the harness: error summaries and latency percentiles
//! merged from per-period status snapshots.

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
