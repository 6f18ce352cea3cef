//! Shared vocabulary of vlsync.
//!
//! # Clock convention
//!
//! For one physical event stamped `t_L` by the LiDAR and `t_C` by the camera,
//! the **offset** at LiDAR time `t_L` is
//!
//! ```text
//! offset(t_L) = t_L - t_C
//! ```
//!
//! and the **drift** is `d offset / d t_L` (dimensionless, seconds per second).
//! A client converts a camera stamp to the LiDAR time base with
//! `t_L = t_C + offset`.
//!
//! # Time units
//!
//! Every timestamp is an integer number of nanoseconds ([`Nanos`]) on the clock
//! of the sensor that produced it. Estimated quantities (offset, its standard
//! deviation) are `f64` seconds; drift is a dimensionless `f64`.
//!
//! ```
//! use vlsync_common::{camera_to_lidar_ns, secs_to_nanos};
//! // the LiDAR stamps the same event 25 ms later than the camera
//! let offset_s = 0.025;
//! let t_cam = secs_to_nanos(10.0);
//! assert_eq!(camera_to_lidar_ns(t_cam, offset_s), secs_to_nanos(10.025));
//! ```
#![forbid(unsafe_code)]

use serde::{Deserialize, Serialize};
use std::fmt;

pub mod console;
pub mod file;
pub mod text;
#[cfg(feature = "wire")]
pub mod wire;

/// A timestamp or duration in integer nanoseconds.
pub type Nanos = i64;

/// Nanoseconds in one second.
pub const NANOS_PER_SEC: i64 = 1_000_000_000;

/// Largest |offset| between the clocks anyone takes from outside, seconds (11.6
/// days; the range of `estimator.lag_center_s`): a saved estimate beyond it is
/// refused, by the daemon's state file and by `Estimator::restore` (the estimator's
/// lag arithmetic stays far from the `i64` range within it).
pub const MAX_ABS_OFFSET_S: f64 = 1e6;

/// Converts seconds to the nearest nanosecond, saturating at the `i64` range.
/// NaN maps to 0; callers validate their inputs before converting.
pub fn secs_to_nanos(s: f64) -> Nanos {
    let ns = (s * 1e9).round();
    if ns.is_nan() {
        0
    } else if ns >= i64::MAX as f64 {
        i64::MAX
    } else if ns <= i64::MIN as f64 {
        i64::MIN
    } else {
        ns as i64
    }
}

/// Converts nanoseconds to seconds.
pub fn nanos_to_secs(ns: Nanos) -> f64 {
    ns as f64 * 1e-9
}

/// How far ahead of now a start instant (`--start-at`, `CLOCK_MONOTONIC` ns, the
/// drivers' and `vlsync-render --raw-stdout`'s) may be: a day.
pub const MAX_START_AHEAD_NS: Nanos = 86_400_000_000_000;

/// Checks a `--start-at` instant against `CLOCK_MONOTONIC` now: not before boot, at
/// most [`MAX_START_AHEAD_NS`] ahead. Stamps are built on it: far out of range they
/// would overflow, and an instant on another clock (`CLOCK_REALTIME`'s 1.7e18 ns)
/// would be waited for for decades.
///
/// ```
/// use vlsync_common::check_start_at;
/// assert_eq!(check_start_at(5_000, 1_000), Ok(()));
/// assert_eq!(
///     check_start_at(-1, 1_000).unwrap_err(),
///     "--start-at -1 is out of range: allowed 0 ..= 86400000001000 (CLOCK_MONOTONIC ns, at most a day from now)"
/// );
/// ```
pub fn check_start_at(t: Nanos, now_mono_ns: Nanos) -> Result<(), String> {
    let latest = now_mono_ns.saturating_add(MAX_START_AHEAD_NS);
    if (0..=latest).contains(&t) {
        Ok(())
    } else {
        Err(format!(
            "--start-at {t} is out of range: allowed 0 ..= {latest} (CLOCK_MONOTONIC ns, at most a day from now)"
        ))
    }
}

/// Converts a camera timestamp to the LiDAR time base: `t_L = t_C + offset`.
pub fn camera_to_lidar_ns(t_cam: Nanos, offset_s: f64) -> Nanos {
    t_cam.saturating_add(secs_to_nanos(offset_s))
}

/// Which sensor a signature stream comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stream {
    /// The camera (optical-flow signature).
    Cam,
    /// The LiDAR (wall-distance derivative signature).
    Lidar,
}

impl Stream {
    /// Lowercase name, as used in files and service names.
    pub fn name(self) -> &'static str {
        match self {
            Stream::Cam => "cam",
            Stream::Lidar => "lidar",
        }
    }
}

impl fmt::Display for Stream {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One signature sample: a scalar stamped on its sensor's own clock.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Timestamp on the producing sensor's clock, nanoseconds.
    pub t_ns: Nanos,
    /// Signature value (flow magnitude, distance rate, ...).
    pub value: f64,
}

impl Sample {
    /// Creates a sample.
    pub fn new(t_ns: Nanos, value: f64) -> Self {
        Self { t_ns, value }
    }
}

/// State of the estimator, as carried by every estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u8)]
pub enum EstimatorState {
    /// Searching the wide lag range; no lock yet.
    Acquiring = 0,
    /// Locked; this estimate includes a fresh accepted measurement.
    Tracking = 1,
    /// Locked earlier; no usable measurement now (no motion, weak or rejected peak).
    /// The offset is predicted from the last state and its uncertainty grows.
    Holding = 2,
    /// Held for too long: the estimate is too uncertain to use; reacquiring.
    Lost = 3,
}

impl EstimatorState {
    /// Lowercase name as written in CSV and logs.
    pub fn name(self) -> &'static str {
        match self {
            EstimatorState::Acquiring => "acquiring",
            EstimatorState::Tracking => "tracking",
            EstimatorState::Holding => "holding",
            EstimatorState::Lost => "lost",
        }
    }

    /// Inverse of `as u8`; `None` for an unknown code (e.g. from shared memory).
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Self::Acquiring),
            1 => Some(Self::Tracking),
            2 => Some(Self::Holding),
            3 => Some(Self::Lost),
            _ => None,
        }
    }

    /// Parses the lowercase name.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "acquiring" => Some(Self::Acquiring),
            "tracking" => Some(Self::Tracking),
            "holding" => Some(Self::Holding),
            "lost" => Some(Self::Lost),
            _ => None,
        }
    }
}

impl fmt::Display for EstimatorState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Relative sign of the two signatures: whether the LiDAR signature rises
/// (`Positive`) or falls (`Negative`) when the camera signature rises.
/// Driving toward a wall makes the LiDAR distance derivative fall while the
/// flow magnitude rises: `Negative`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(i8)]
pub enum Polarity {
    /// Not determined yet.
    Unknown = 0,
    /// The signatures rise together.
    Positive = 1,
    /// One rises while the other falls.
    Negative = -1,
}

impl Polarity {
    /// `+1.0`, `-1.0`, or `0.0` for unknown.
    pub fn sign(self) -> f64 {
        match self {
            Polarity::Unknown => 0.0,
            Polarity::Positive => 1.0,
            Polarity::Negative => -1.0,
        }
    }

    /// Lowercase name.
    pub fn name(self) -> &'static str {
        match self {
            Polarity::Unknown => "unknown",
            Polarity::Positive => "positive",
            Polarity::Negative => "negative",
        }
    }

    /// Inverse of `as i8`.
    pub fn from_code(code: i8) -> Option<Self> {
        match code {
            0 => Some(Self::Unknown),
            1 => Some(Self::Positive),
            -1 => Some(Self::Negative),
            _ => None,
        }
    }
}

impl fmt::Display for Polarity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One offset estimate, produced each time a hop completes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Sequence number, starting at 0, +1 per estimate.
    pub seq: u64,
    /// Reference time on the LiDAR clock (ns): the estimate is the offset at this instant.
    /// It lags the newest LiDAR data by `estimator.reference_lag_s` (3 s by default), so
    /// the estimate rests on data from both sides of it; use [`Estimate::offset_at`] to
    /// extrapolate to now.
    pub t_ref_ns: Nanos,
    /// `t_L - t_C` at `t_ref_ns`, seconds.
    pub offset_s: f64,
    /// `d offset / d t_L`, dimensionless.
    pub drift: f64,
    /// One standard deviation of `offset_s`, seconds.
    pub offset_std_s: f64,
    /// One standard deviation of `drift`.
    pub drift_std: f64,
    /// Estimator state.
    pub state: EstimatorState,
    /// Detected polarity.
    pub polarity: Polarity,
    /// Normalised cross-correlation at the peak of this hop (0 when none), sign removed.
    pub peak_score: f64,
    /// Main-peak to second-peak ratio of this hop (`f64::INFINITY` when there is no second peak, 0 when no peak).
    pub peak_ratio: f64,
    /// Raw measurement of this hop: the peak of the newest `window_s` of data (near the
    /// prediction once locked), moved from that window's centre to `t_ref_ns` with the
    /// drift, seconds; NaN when none. Noisier than `offset_s`, which rests on the
    /// whole segment.
    pub measured_offset_s: f64,
}

impl Estimate {
    /// Offset predicted at LiDAR time `t_ns` using the drift.
    pub fn offset_at(&self, t_ns: Nanos) -> f64 {
        self.offset_s + self.drift * nanos_to_secs(t_ns.saturating_sub(self.t_ref_ns))
    }

    /// Standard deviation of [`Estimate::offset_at`] from the offset's and the drift's
    /// standard deviations alone: `sqrt(offset_std² + (drift_std · dt)²)`, `dt = |t - t_ref|`.
    /// The estimator tracks no offset/drift covariance, so none is added; nor is the
    /// offset's random walk between `t_ref` and `t`, which the estimator's own
    /// prediction adds (see [`Estimate::offset_std_with_walk`]).
    pub fn offset_std_at(&self, t_ns: Nanos) -> f64 {
        self.offset_std_with_walk(t_ns, 0.0)
    }

    /// LiDAR time of the camera stamp `t_cam_ns`: `t_L = t_C + offset(t_L)`, the offset
    /// extrapolated with the drift to the LiDAR time it is for (two fixed-point steps:
    /// the error is below `drift³ · |t_L - t_ref|`, nanoseconds at any real drift).
    ///
    /// ```
    /// # use vlsync_common::{Estimate, EstimatorState, Polarity};
    /// // offset 0.1 s at LiDAR time 10 s, drifting 100 ppm
    /// let e = Estimate { seq: 0, t_ref_ns: 10_000_000_000, offset_s: 0.1, drift: 1e-4,
    ///     offset_std_s: 0.001, drift_std: 1e-6, state: EstimatorState::Tracking,
    ///     polarity: Polarity::Positive, peak_score: 0.9, peak_ratio: 2.0,
    ///     measured_offset_s: f64::NAN };
    /// let t_l = e.camera_to_lidar(19_900_000_000);
    /// // 10 s after t_ref on the LiDAR clock the offset is 0.101 s
    /// assert!((t_l - 20_001_000_100).abs() <= 1, "{t_l}");
    /// ```
    pub fn camera_to_lidar(&self, t_cam_ns: Nanos) -> Nanos {
        let first = camera_to_lidar_ns(t_cam_ns, self.offset_s);
        let second = camera_to_lidar_ns(t_cam_ns, self.offset_at(first));
        camera_to_lidar_ns(t_cam_ns, self.offset_at(second))
    }

    /// [`Estimate::offset_std_at`] plus the offset's random walk of `walk` s/√s over
    /// `dt`, as the estimator predicts: `sqrt(offset_std² + (drift_std · dt)² + walk² · dt)`.
    /// The estimator's walk is `estimator.offset_process_noise` (2e-4 by default) while
    /// measurements come and `estimator.hold_process_noise` (3e-3) once a whole window
    /// passed without one: at the 3 s between `t_ref` and a live stamp, 0.35 ms and
    /// 5.2 ms added in quadrature.
    ///
    /// ```
    /// # use vlsync_common::{Estimate, EstimatorState, Polarity};
    /// let e = Estimate { seq: 0, t_ref_ns: 0, offset_s: 0.1, drift: 0.0, offset_std_s: 0.001,
    ///     drift_std: 0.0, state: EstimatorState::Tracking, polarity: Polarity::Positive,
    ///     peak_score: 0.9, peak_ratio: 2.0, measured_offset_s: f64::NAN };
    /// let three_s = 3_000_000_000;
    /// assert_eq!(e.offset_std_at(three_s), 0.001);
    /// let with_walk = e.offset_std_with_walk(three_s, 2e-4);
    /// assert!((with_walk - (1e-6f64 + 4e-8 * 3.0).sqrt()).abs() < 1e-12);
    /// ```
    pub fn offset_std_with_walk(&self, t_ns: Nanos, walk: f64) -> f64 {
        let dt = nanos_to_secs(t_ns.saturating_sub(self.t_ref_ns)).abs();
        (self.offset_std_s.powi(2) + (self.drift_std * dt).powi(2) + walk * walk * dt).sqrt()
    }
}

/// Why a sample was rejected before it reached the correlator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RejectReason {
    /// Value was NaN or infinite.
    NonFinite,
    /// Value magnitude above the configured limit.
    TooLarge,
    /// Timestamp earlier than the previous accepted one (small step back).
    Backwards,
    /// Timestamp equal to the previous accepted one.
    Repeated,
}

impl RejectReason {
    /// All reasons, in counter order.
    pub const ALL: [RejectReason; 4] = [
        RejectReason::NonFinite,
        RejectReason::TooLarge,
        RejectReason::Backwards,
        RejectReason::Repeated,
    ];

    /// Index into counter arrays.
    pub fn index(self) -> usize {
        self as usize
    }

    /// snake_case name.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::NonFinite => "non_finite",
            RejectReason::TooLarge => "too_large",
            RejectReason::Backwards => "backwards",
            RejectReason::Repeated => "repeated",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn state_codes_roundtrip() {
        for s in [
            EstimatorState::Acquiring,
            EstimatorState::Tracking,
            EstimatorState::Holding,
            EstimatorState::Lost,
        ] {
            assert_eq!(EstimatorState::from_code(s as u8), Some(s));
            assert_eq!(EstimatorState::from_name(s.name()), Some(s));
        }
        assert_eq!(EstimatorState::from_code(9), None);
    }

    #[test]
    fn polarity_codes_roundtrip() {
        for p in [Polarity::Unknown, Polarity::Positive, Polarity::Negative] {
            assert_eq!(Polarity::from_code(p as i8), Some(p));
        }
        assert_eq!(Polarity::from_code(5), None);
    }

    #[test]
    fn conversion_saturates_and_handles_nan() {
        assert_eq!(secs_to_nanos(f64::NAN), 0);
        assert_eq!(secs_to_nanos(1e30), i64::MAX);
        assert_eq!(secs_to_nanos(-1e30), i64::MIN);
    }

    #[test]
    fn offset_extrapolates_with_drift() {
        let e = Estimate {
            seq: 0,
            t_ref_ns: secs_to_nanos(100.0),
            offset_s: 0.1,
            drift: 1e-4,
            offset_std_s: 0.001,
            drift_std: 1e-5,
            state: EstimatorState::Tracking,
            polarity: Polarity::Positive,
            peak_score: 0.9,
            peak_ratio: 2.0,
            measured_offset_s: 0.1,
        };
        assert!((e.offset_at(secs_to_nanos(110.0)) - 0.101).abs() < 1e-12);
        assert!(e.offset_std_at(secs_to_nanos(110.0)) > 0.001);
    }

    proptest! {
        #[test]
        fn secs_nanos_roundtrip(ns in -4_000_000_000_000_000_000i64..4_000_000_000_000_000_000i64) {
            // f64 has 53 bits of mantissa: exact up to ~2^53 ns (~104 days), within 1 µs beyond
            let back = secs_to_nanos(nanos_to_secs(ns));
            prop_assert!((back - ns).abs() <= 1024);
        }
    }
}
