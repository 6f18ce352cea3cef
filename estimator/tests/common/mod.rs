//! Shared by the estimator's integration tests (`mod common;` in each).

use vlsync_common::{Estimate, EstimatorState, Polarity};

/// A saved tracking estimate of `offset_s` (1 ms, 1 ppm), as a state file holds one.
pub fn saved_tracking(offset_s: f64) -> Estimate {
    Estimate {
        seq: 0,
        t_ref_ns: 0,
        offset_s,
        drift: 0.0,
        offset_std_s: 0.001,
        drift_std: 1e-6,
        state: EstimatorState::Tracking,
        polarity: Polarity::Negative,
        peak_score: 0.9,
        peak_ratio: 2.0,
        measured_offset_s: f64::NAN,
    }
}
