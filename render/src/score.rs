//! Estimator output against the truth.
//!
//! The error of an estimate and the first lock are `vlsync_sim::score`'s: the
//! error is `offset_s - truth.offset_at(t_ref_ns)`; the **first lock** is the
//! first estimate in `Tracking`. The estimates scored are not: `mae_s` is the mean
//! |error| over the `Tracking` estimates from the first lock on, all of them, where
//! `vlsync_sim::score` also scores `Holding` ones and leaves out those within 3 s
//! after an offset step. So a rendered run's figures (the README's, "MAE of the
//! tracking estimates") are of what the estimator tracked, steps' transients
//! included; how long a step took to follow is reported apart (the `accuracy`
//! example's `--steps`). `measured_mae_s` is the same over the raw correlation
//! measurements (`measured_offset_s`, when finite) of those estimates.
//!
//! ```
//! use vlsync_common::{Estimate, EstimatorState, Polarity};
//! use vlsync_render::score::score;
//! use vlsync_sim::Truth;
//! let truth = Truth { offset0_s: 0.1, drift: 0.0, steps: vec![], end_ns: 10_000_000_000 };
//! let e = |state, off| Estimate { seq: 0, t_ref_ns: 5_000_000_000, offset_s: off, drift: 0.0,
//!     offset_std_s: 0.001, drift_std: 0.0, state, polarity: Polarity::Negative,
//!     peak_score: 0.9, peak_ratio: 2.0, measured_offset_s: f64::NAN };
//! let s = score(&[e(EstimatorState::Acquiring, 0.5), e(EstimatorState::Tracking, 0.102),
//!                 e(EstimatorState::Holding, 0.2), e(EstimatorState::Tracking, 0.097)], &truth);
//! assert_eq!(s.n, 2);
//! assert!((s.mae_s - 0.0025).abs() < 1e-12 && (s.bias_s + 0.0005).abs() < 1e-12);
//! assert!(s.measured_mae_s.is_nan());
//! ```

use vlsync_common::{Estimate, EstimatorState, Nanos};
use vlsync_sim::Truth;

/// Error statistics of one run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    /// Tracking estimates scored.
    pub n: usize,
    /// Mean |error|, s (NaN when none).
    pub mae_s: f64,
    /// Mean error, s (NaN when none).
    pub bias_s: f64,
    /// 95th percentile of |error| (nearest rank), s (NaN when none).
    pub p95_s: f64,
    /// Largest |error|, s (NaN when none).
    pub max_abs_s: f64,
    /// Mean |error| of the raw measurements of the scored estimates, s.
    pub measured_mae_s: f64,
    /// Mean error of those measurements, s.
    pub measured_bias_s: f64,
    /// Scored estimates with a finite measurement.
    pub n_measured: usize,
    /// Reference time of the first lock, ns.
    pub first_lock_ns: Option<Nanos>,
}

/// Scores `estimates` (in output order) against `truth`.
pub fn score(estimates: &[Estimate], truth: &Truth) -> Score {
    let first = estimates
        .iter()
        .position(|e| e.state == EstimatorState::Tracking);
    let scored: Vec<&Estimate> = first
        .map(|i| &estimates[i..])
        .unwrap_or(&[])
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking)
        .collect();
    let errs: Vec<f64> = scored
        .iter()
        .map(|e| e.offset_s - truth.offset_at(e.t_ref_ns))
        .collect();
    let meas: Vec<f64> = scored
        .iter()
        .filter(|e| e.measured_offset_s.is_finite())
        .map(|e| e.measured_offset_s - truth.offset_at(e.t_ref_ns))
        .collect();
    let mean = |v: &mut dyn Iterator<Item = f64>| {
        let (s, c) = v.fold((0.0, 0usize), |(s, c), x| (s + x, c + 1));
        if c == 0 {
            f64::NAN
        } else {
            s / c as f64
        }
    };
    let mut abs: Vec<f64> = errs.iter().map(|e| e.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let n = abs.len();
    Score {
        n,
        mae_s: mean(&mut abs.iter().copied()),
        bias_s: mean(&mut errs.iter().copied()),
        p95_s: if n == 0 {
            f64::NAN
        } else {
            abs[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1]
        },
        max_abs_s: abs.last().copied().unwrap_or(f64::NAN),
        measured_mae_s: mean(&mut meas.iter().map(|e| e.abs())),
        measured_bias_s: mean(&mut meas.iter().copied()),
        n_measured: meas.len(),
        first_lock_ns: first.map(|i| estimates[i].t_ref_ns),
    }
}
