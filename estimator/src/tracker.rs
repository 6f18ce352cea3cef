//! Kalman filter on `[offset, drift]` over LiDAR time.

use nalgebra::{Matrix2, RowVector2, Vector2};

/// The filter state.
#[derive(Debug, Clone, Copy)]
pub struct Tracker {
    /// `[offset s, drift s/s]`.
    pub x: Vector2<f64>,
    /// Covariance.
    pub p: Matrix2<f64>,
    /// LiDAR time of the state, seconds (relative to an arbitrary epoch).
    pub t: f64,
}

/// Outcome of a measurement update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Update {
    /// Accepted.
    Accepted,
    /// Rejected by the innovation gate; carries the normalised innovation.
    Outlier(f64),
}

impl Tracker {
    /// A filter at time `t` with offset `o` (variance `var_o`) and drift 0 (std `drift_std`).
    pub fn new(t: f64, o: f64, var_o: f64, drift_std: f64) -> Self {
        Self {
            x: Vector2::new(o, 0.0),
            p: Matrix2::new(var_o, 0.0, 0.0, drift_std * drift_std),
            t,
        }
    }

    /// Propagates to time `t` with offset and drift random-walk intensities `qo`, `qd`.
    pub fn predict(&mut self, t: f64, qo: f64, qd: f64) {
        let dt = t - self.t;
        if dt <= 0.0 {
            return;
        }
        let f = Matrix2::new(1.0, dt, 0.0, 1.0);
        let (qo2, qd2) = (qo * qo, qd * qd);
        let q = Matrix2::new(
            qo2 * dt + qd2 * dt.powi(3) / 3.0,
            qd2 * dt * dt / 2.0,
            qd2 * dt * dt / 2.0,
            qd2 * dt,
        );
        self.x = f * self.x;
        self.p = f * self.p * f.transpose() + q;
        self.t = t;
    }

    /// Offset predicted at time `t` (no state change).
    pub fn offset_at(&self, t: f64) -> f64 {
        self.x[0] + self.x[1] * (t - self.t)
    }

    /// Variance of the offset predicted `h` seconds before the state time (no process noise).
    pub fn var_at_lag(&self, h: f64) -> f64 {
        let hh = RowVector2::new(1.0, -h);
        (hh * self.p * hh.transpose())[(0, 0)]
    }

    /// Updates with a measurement `z` of the offset `h` seconds before the state
    /// time: `r_update` is the variance used in the update, `r_gate` the one
    /// used in the innovation gate `gate` (in sigmas).
    pub fn update(&mut self, z: f64, h: f64, r_update: f64, r_gate: f64, gate: f64) -> Update {
        let hh = RowVector2::new(1.0, -h);
        let nu = z - (hh * self.x)[0];
        let hph = (hh * self.p * hh.transpose())[(0, 0)];
        let norm = nu / (hph + r_gate).sqrt();
        if !norm.is_finite() || norm.abs() > gate {
            return Update::Outlier(norm);
        }
        let s = hph + r_update;
        let k = self.p * hh.transpose() / s;
        self.x += k * nu;
        let i_kh = Matrix2::identity() - k * hh;
        // Joseph form keeps P symmetric positive semi-definite
        self.p = i_kh * self.p * i_kh.transpose() + k * k.transpose() * r_update;
        Update::Accepted
    }

    /// Replaces the offset (after a detected step), keeping the drift.
    pub fn reset_offset(&mut self, o: f64, var_o: f64) {
        self.x[0] = o;
        self.p[(0, 0)] = var_o;
        self.p[(0, 1)] = 0.0;
        self.p[(1, 0)] = 0.0;
    }

    /// Offset standard deviation.
    pub fn offset_std(&self) -> f64 {
        self.p[(0, 0)].max(0.0).sqrt()
    }

    /// Drift standard deviation.
    pub fn drift_std(&self) -> f64 {
        self.p[(1, 1)].max(0.0).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_on_line_with_noise_free_measurements() {
        let mut tr = Tracker::new(0.0, 0.1, 1e-4, 1e-3);
        for i in 1..200 {
            let t = i as f64 * 0.5;
            tr.predict(t, 1e-5, 1e-7);
            let z = 0.1 + 50e-6 * (t - 2.0);
            assert_eq!(tr.update(z, 2.0, 1e-6, 1e-6, 5.0), Update::Accepted);
        }
        assert!((tr.x[0] - (0.1 + 50e-6 * 99.5)).abs() < 1e-5);
        assert!((tr.x[1] - 50e-6).abs() < 1e-6);
    }

    #[test]
    fn gate_rejects_outlier() {
        let mut tr = Tracker::new(0.0, 0.0, 1e-6, 1e-6);
        tr.predict(0.5, 1e-5, 1e-7);
        assert!(matches!(
            tr.update(0.1, 0.0, 1e-6, 1e-6, 3.0),
            Update::Outlier(_)
        ));
    }
}
