//! Clock models and the truth.
//!
//! The true event time `τ` is the LiDAR's time base (as in `vlsync-sim`). The
//! LiDAR stamps a scan starting at `τ` with `t_L = τ + j_L` (`j_L` Gaussian
//! jitter per scan, the rays keep their exact spacing); the camera stamps a frame
//! whose exposure is centred on `τ` with a mid-exposure instant
//! `t_C = τ - offset(τ) + j_C`. So, jitter aside, for one physical event
//! `offset(t_L) = t_L - t_C`, the convention of `vlsync_common`.
//!
//! `offset(τ) = offset0 + drift·τ + Σ steps up to τ` — exactly
//! [`vlsync_sim::Truth::offset_at`], which the run reports as its truth.
//!
//! ```
//! use vlsync_render::clock::ClockConfig;
//! let c = ClockConfig { offset0_s: 0.1, drift_ppm: 50.0, steps: vec![(10.0, -0.02)], ..ClockConfig::default() };
//! let truth = c.truth(20.0);
//! assert!((truth.offset_at(20_000_000_000) - (0.1 + 50e-6 * 20.0 - 0.02)).abs() < 1e-12);
//! ```

use crate::RenderError;
use vlsync_common::text::number;
use vlsync_common::{secs_to_nanos, Nanos};
use vlsync_sim::Truth;

/// Offset, drift, latency steps and stamp jitter.
#[derive(Debug, Clone, PartialEq)]
pub struct ClockConfig {
    /// Offset `t_L - t_C` at `τ = 0`, seconds.
    pub offset0_s: f64,
    /// Drift `d offset / dτ`, parts per million.
    pub drift_ppm: f64,
    /// Offset steps (e.g. load-dependent latency changes): `(τ seconds, delta seconds)`.
    /// A camera latency increase of `Δ` is a step of `-Δ`.
    pub steps: Vec<(f64, f64)>,
    /// Camera stamp jitter, seconds (1σ). Default 1 ms: host-side capture stamps
    /// of a USB camera (the frames themselves stay regular: the sensor clocks
    /// them).
    pub cam_jitter_s: f64,
    /// LiDAR scan stamp jitter, seconds (1σ). Default 0.3 ms: device-clocked
    /// scans (the LD06 stamps every packet with its own millisecond clock).
    pub lidar_jitter_s: f64,
}

impl Default for ClockConfig {
    fn default() -> Self {
        Self {
            offset0_s: 0.1,
            drift_ppm: 40.0,
            steps: Vec::new(),
            cam_jitter_s: 0.001,
            lidar_jitter_s: 0.0003,
        }
    }
}

impl ClockConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), RenderError> {
        let check = |field: &'static str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(RenderError::config(
                    field,
                    format!("{} is outside {}..={}", number(v), number(lo), number(hi)),
                ))
            }
        };
        check("clock.offset0_s", self.offset0_s, -10.0, 10.0)?;
        check("clock.drift_ppm", self.drift_ppm, -1000.0, 1000.0)?;
        check("clock.cam_jitter_s", self.cam_jitter_s, 0.0, 0.1)?;
        check("clock.lidar_jitter_s", self.lidar_jitter_s, 0.0, 0.1)?;
        let mut last = f64::NEG_INFINITY;
        for &(t, d) in &self.steps {
            check("clock.steps.time", t, 0.0, 3600.0)?;
            check("clock.steps.delta", d, -1.0, 1.0)?;
            if t <= last {
                return Err(RenderError::config(
                    "clock.steps.time",
                    format!("{t} s is not after the previous step ({last} s)"),
                ));
            }
            last = t;
        }
        Ok(())
    }

    /// The truth over a run of `duration_s` seconds.
    pub fn truth(&self, duration_s: f64) -> Truth {
        Truth {
            offset0_s: self.offset0_s,
            drift: self.drift_ppm * 1e-6,
            steps: self
                .steps
                .iter()
                .map(|&(t, d)| (secs_to_nanos(t), d))
                .collect(),
            end_ns: secs_to_nanos(duration_s),
        }
    }
}

/// `τ - offset(τ)` plus jitter, rounded to ns: the camera's reading at true time `τ`.
pub fn camera_stamp(truth: &Truth, tau_ns: Nanos, jitter_s: f64) -> Nanos {
    let off = truth.offset_at(tau_ns) - jitter_s;
    tau_ns.saturating_sub(secs_to_nanos(off))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn validation_names_fields() {
        let bad = ClockConfig {
            steps: vec![(5.0, 0.01), (5.0, 0.01)],
            ..ClockConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("clock.steps.time"));
        let bad = ClockConfig {
            drift_ppm: f64::NAN,
            ..ClockConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("clock.drift_ppm"));
        assert!(ClockConfig::default().validate().is_ok());
    }

    proptest! {
        /// Without jitter the camera stamp obeys the convention exactly:
        /// `offset(t_L) = t_L - t_C` with `t_L = τ` (to the nanosecond rounding).
        #[test]
        fn camera_stamps_obey_the_convention(
            off in -0.5f64..0.5, ppm in -100f64..100.0, tau in 0i64..3_600_000_000_000,
        ) {
            let c = ClockConfig { offset0_s: off, drift_ppm: ppm, steps: vec![(10.0, 0.025)], ..ClockConfig::default() };
            let truth = c.truth(3600.0);
            let t_c = camera_stamp(&truth, tau, 0.0);
            prop_assert!(((tau - t_c) as f64 * 1e-9 - truth.offset_at(tau)).abs() <= 1e-9);
        }
    }
}
