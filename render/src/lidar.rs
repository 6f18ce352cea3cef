//! The 2-D LiDAR: a spinning range finder ray-cast against the room, each ray
//! at its own instant of the sweep (the robot pose at that instant).
//!
//! Scan `k` starts at true time `τ_k = phase + k · period` with the beam at
//! bearing [`LidarConfig::start_bearing_deg`]; ray `i` of `n` is measured at
//! `τ_k + i · period / n` at bearing `start ∓ i · 360° / n` (clockwise like an
//! LD06 by default). Ranges get Gaussian noise; beyond
//! [`LidarConfig::max_range_m`] a ray is "no return" (range 0, invalid).
//!
//! ```
//! use vlsync_render::lidar::{LidarConfig, LidarModel};
//! use vlsync_render::motion::Pose;
//! use vlsync_render::world::Room;
//! let room = Room::new(8.0, 5.0, 2.5).unwrap();
//! let lidar = LidarModel::new(&LidarConfig { range_noise_m: 0.0, ..LidarConfig::default() }).unwrap();
//! let pose = Pose { x: 2.0, y: 2.5, yaw: 0.0 };
//! // ray 0 looks straight ahead: 6 m to the front wall minus the 5 cm mount offset
//! let r = lidar.range(&room, &pose, 0.0, &mut rand::rngs::mock::StepRng::new(0, 0));
//! assert!((r - 5.95).abs() < 1e-9);
//! ```

use crate::motion::Pose;
use crate::world::Room;
use crate::RenderError;
use rand::Rng;
use rand_distr::StandardNormal;
use vlsync_common::text::number;
use vlsync_signature_lidar::Rotation;

/// LiDAR parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LidarConfig {
    /// Revolutions per second.
    pub rate_hz: f64,
    /// Rays per revolution.
    pub rays_per_turn: usize,
    /// Sweep direction.
    pub rotation: Rotation,
    /// Bearing of the first ray of a scan, degrees (CCW positive).
    pub start_bearing_deg: f64,
    /// Range noise, metres (1σ), independent from ray to ray. The LD19 (LD06
    /// family) datasheet gives a 10 mm typical ranging standard deviation over
    /// 0.3-12 m at 70 % reflectivity and ±45 mm of mean (systematic) error; the
    /// default 8 mm is that noise on indoor walls at 1-7 m (paint reflects
    /// better than the datasheet's target). The systematic part is not modelled:
    /// a constant range error does not move a distance *rate*.
    pub range_noise_m: f64,
    /// Farther returns are lost, metres.
    pub max_range_m: f64,
    /// Mounting point ahead of the robot's centre, metres.
    pub forward_m: f64,
}

impl Default for LidarConfig {
    /// An LD06-like scanner: 10 Hz, 450 rays (4500 points/s, 0.8° apart),
    /// clockwise, 8 mm range noise, 12 m range, 5 cm ahead of the robot's
    /// centre (so turning in place moves it).
    fn default() -> Self {
        Self {
            rate_hz: 10.0,
            rays_per_turn: 450,
            rotation: Rotation::Cw,
            start_bearing_deg: 0.0,
            range_noise_m: 0.008,
            max_range_m: 12.0,
            forward_m: 0.05,
        }
    }
}

impl LidarConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), RenderError> {
        let ranges = [
            ("lidar.rate_hz", self.rate_hz, 0.5, 100.0),
            (
                "lidar.start_bearing_deg",
                self.start_bearing_deg,
                -360.0,
                360.0,
            ),
            ("lidar.range_noise_m", self.range_noise_m, 0.0, 1.0),
            ("lidar.max_range_m", self.max_range_m, 0.5, 100.0),
            ("lidar.forward_m", self.forward_m, -1.0, 1.0),
        ];
        for (field, v, lo, hi) in ranges {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(RenderError::config(
                    field,
                    format!("{} is outside {}..={}", number(v), number(lo), number(hi)),
                ));
            }
        }
        if !(8..=100_000).contains(&self.rays_per_turn) {
            return Err(RenderError::config(
                "lidar.rays_per_turn",
                format!("{} is outside 8..=100000", self.rays_per_turn),
            ));
        }
        Ok(())
    }

    /// Rotation period, ns.
    pub fn period_ns(&self) -> i64 {
        (1e9 / self.rate_hz).round() as i64
    }

    /// Bearing of ray `i`, radians (unwrapped).
    pub fn bearing(&self, i: usize) -> f64 {
        let step = std::f64::consts::TAU * i as f64 / self.rays_per_turn as f64;
        let start = self.start_bearing_deg.to_radians();
        match self.rotation {
            Rotation::Ccw => start + step,
            Rotation::Cw => start - step,
        }
    }
}

/// A validated LiDAR.
#[derive(Debug, Clone)]
pub struct LidarModel {
    cfg: LidarConfig,
}

impl LidarModel {
    /// Validates the configuration.
    pub fn new(cfg: &LidarConfig) -> Result<Self, RenderError> {
        cfg.validate()?;
        Ok(Self { cfg: *cfg })
    }

    /// The configuration.
    pub fn config(&self) -> &LidarConfig {
        &self.cfg
    }

    /// The measured range at `bearing_rad` (scanner frame) from `pose`, noise
    /// drawn from `rng`; `0.0` for no return.
    pub fn range(&self, room: &Room, pose: &Pose, bearing_rad: f64, rng: &mut impl Rng) -> f64 {
        let (s, c) = pose.yaw.sin_cos();
        let (x, y) = (
            pose.x + c * self.cfg.forward_m,
            pose.y + s * self.cfg.forward_m,
        );
        let (bs, bc) = (pose.yaw + bearing_rad).sin_cos();
        let hit = room.cast(x, y, bc, bs);
        let noise: f64 = if self.cfg.range_noise_m > 0.0 {
            self.cfg.range_noise_m * rng.sample::<f64, _>(StandardNormal)
        } else {
            0.0
        };
        let r = hit.distance + noise;
        if hit.distance.is_finite() && hit.distance <= self.cfg.max_range_m && r > 0.0 {
            r
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn bearings_sweep_in_the_rotation_direction() {
        let cw = LidarConfig::default();
        assert!(cw.bearing(1) < cw.bearing(0));
        let ccw = LidarConfig {
            rotation: Rotation::Ccw,
            ..cw
        };
        assert!(ccw.bearing(1) > ccw.bearing(0));
        assert!((cw.bearing(450) + std::f64::consts::TAU).abs() < 1e-12);
        assert_eq!(cw.period_ns(), 100_000_000);
        let bad = LidarConfig {
            rays_per_turn: 2,
            ..cw
        };
        assert!(LidarModel::new(&bad)
            .unwrap_err()
            .to_string()
            .contains("rays_per_turn"));
    }

    #[test]
    fn noise_has_the_configured_spread_and_far_walls_are_lost() {
        let room = Room::new(8.0, 5.0, 2.5).unwrap();
        let m = LidarModel::new(&LidarConfig::default()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let p = Pose {
            x: 2.0,
            y: 2.5,
            yaw: 0.0,
        };
        let r: Vec<f64> = (0..4000)
            .map(|_| m.range(&room, &p, 0.0, &mut rng))
            .collect();
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        let sd = (r.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / r.len() as f64).sqrt();
        assert!(
            (mean - 5.95).abs() < 1e-3 && (sd - 0.008).abs() < 5e-4,
            "{mean} {sd}"
        );
        let short = LidarModel::new(&LidarConfig {
            max_range_m: 1.0,
            ..LidarConfig::default()
        })
        .unwrap();
        assert_eq!(short.range(&room, &p, 0.0, &mut rng), 0.0);
        // left: 2.5 m to the y = 5 wall
        let left = m.range(&room, &p, std::f64::consts::FRAC_PI_2, &mut rng);
        assert!((left - 2.5).abs() < 0.05, "{left}");
    }
}
