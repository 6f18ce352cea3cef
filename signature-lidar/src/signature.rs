//! The LiDAR signature: rate of change of the robust distance to a wall.
//!
//! For each pass of the beam through a narrow bearing window
//! (`centre ± half_width`), the processor takes
//!
//! * the **robust distance** `d[k]`: the median of the valid returns in the
//!   window (device-invalid, zero, NaN, infinite and out-of-range returns are
//!   dropped), and
//! * its **measurement time** `t_d[k]`: the median time of the rays actually
//!   used (rays are in time order, so this is the middle ray's time, or the
//!   mean of the two middle ones),
//!
//! and emits the sample `(d[k] - d[k-1]) / (t_d[k] - t_d[k-1])` in m/s,
//! stamped by default at the **midpoint** `(t_d[k-1] + t_d[k]) / 2`
//! ([`Stamping::Midpoint`]): a difference of two distances is the mean speed
//! over the interval between them, so stamping it at the end
//! ([`Stamping::End`], available for comparison) biases every sample late by
//! half a rotation period.
//!
//! # Passes, not scans
//!
//! The processor consumes rays in time order ([`SignatureProcessor::push_ray`])
//! and closes a pass when the first ray outside the window follows rays inside
//! it. A window that straddles the bearing where a device starts its scans
//! (typically straight ahead) is therefore measured once per revolution from
//! the rays at the end of one scan and the start of the next, never averaged
//! across a whole revolution. [`SignatureProcessor::push_scan`] simply feeds a
//! scan's rays; one revolution closes one pass. When the rotation period is
//! known (from the scan timing, or [`SignatureProcessor::set_period_hint`]) a
//! pass also closes once it has lasted 1.5× the window's share of a
//! revolution, so recordings holding only the window's rays work too.
//!
//! # Gaps
//!
//! No derivative spans a gap: if two consecutive measurement times are more
//! than `max_gap_ns` apart (a scan was lost, or a pass was dropped), the new
//! distance restarts the derivative ([`DropReason::Gap`]). A pass cut by a gap
//! between two rays, or one already under way when the stream (re)started, is
//! dropped ([`DropReason::Partial`]).
//!
//! # Allocation
//!
//! All buffers are allocated in [`SignatureProcessor::new`]
//! (`max_window_rays` distances and times); processing never allocates.
//!
//! ```
//! use vlsync_signature_lidar::scan::{Ray, Rotation, Scan, ScanTiming};
//! use vlsync_signature_lidar::signature::{SignatureConfig, SignatureProcessor};
//!
//! let cfg = SignatureConfig { window_centre_rad: std::f64::consts::FRAC_PI_2, ..SignatureConfig::default() };
//! let mut p = SignatureProcessor::new(cfg).unwrap();
//! let period = 100_000_000; // 10 Hz
//! let mut samples = Vec::new();
//! for k in 0..3i64 {
//!     let wall = 2.0 + 0.05 * k as f64; // receding at 0.5 m/s
//!     let rays = (0..360)
//!         .map(|i| Ray::new((i as f64).to_radians(), wall, 100.0, true))
//!         .collect();
//!     let timing = ScanTiming { start_ns: k * period, period_ns: period, rotation: Rotation::Ccw, start_bearing_rad: 0.0 };
//!     p.push_scan(&Scan::from_uniform(timing, rays), |s| samples.push(s));
//! }
//! assert_eq!(samples.len(), 2);
//! assert!((samples[0].value - 0.5).abs() < 1e-9);
//! // midpoint of the two measurements of bearing 90°, 25 ms into scans 0 and 1
//! assert_eq!(samples[0].t_ns, 75_000_000);
//! ```

use crate::scan::{wrap_pi, Ray, Scan};
use std::f64::consts::FRAC_PI_2;
use std::fmt;
use vlsync_common::{Nanos, Sample, NANOS_PER_SEC};

/// Where a derivative sample is stamped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Stamping {
    /// `(t_d[k-1] + t_d[k]) / 2`: the centre of the interval the difference
    /// averages over. Unbiased; the default.
    #[default]
    Midpoint,
    /// `t_d[k]`: the end of the interval. Late by half a rotation period;
    /// only for comparison experiments.
    End,
}

/// Configuration of the signature processor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignatureConfig {
    /// Centre of the bearing window, radians (CCW positive, scan frame).
    pub window_centre_rad: f64,
    /// Half-width of the bearing window, radians, in `(0, π/2]`.
    pub window_half_width_rad: f64,
    /// Returns closer than this (metres) are dropped.
    pub min_range_m: f64,
    /// Returns farther than this (metres) are dropped.
    pub max_range_m: f64,
    /// A pass with fewer valid returns yields no distance.
    pub min_valid_rays: usize,
    /// Capacity of the window buffers; a pass with more valid returns is dropped.
    pub max_window_rays: usize,
    /// Longest allowed interval between consecutive measurements (and between
    /// consecutive rays inside a pass), ns.
    pub max_gap_ns: Nanos,
    /// Sample stamping.
    pub stamping: Stamping,
}

impl Default for SignatureConfig {
    fn default() -> Self {
        Self {
            window_centre_rad: 0.0,
            window_half_width_rad: 5f64.to_radians(),
            min_range_m: 0.05,
            max_range_m: 40.0,
            min_valid_rays: 3,
            max_window_rays: 1024,
            max_gap_ns: 300_000_000,
            stamping: Stamping::Midpoint,
        }
    }
}

/// A configuration value out of its allowed range.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    /// Field name.
    pub field: &'static str,
    /// What is wrong, with the offending value.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "signature config `{}`: {}", self.field, self.message)
    }
}

impl std::error::Error for ConfigError {}

impl SignatureConfig {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let err = |field, message: String| Err(ConfigError { field, message });
        if !self.window_centre_rad.is_finite() {
            return err(
                "window_centre_rad",
                format!("must be finite, got {}", self.window_centre_rad),
            );
        }
        let hw = self.window_half_width_rad;
        if !(hw > 0.0 && hw <= FRAC_PI_2) {
            return err(
                "window_half_width_rad",
                format!("must be in (0, pi/2], got {hw}"),
            );
        }
        if !(self.min_range_m.is_finite() && self.min_range_m >= 0.0) {
            return err(
                "min_range_m",
                format!("must be finite and >= 0, got {}", self.min_range_m),
            );
        }
        if !(self.max_range_m.is_finite() && self.max_range_m > self.min_range_m) {
            return err(
                "max_range_m",
                format!(
                    "must be finite and > min_range_m ({}), got {}",
                    self.min_range_m, self.max_range_m
                ),
            );
        }
        if self.min_valid_rays == 0 {
            return err("min_valid_rays", "must be >= 1, got 0".into());
        }
        if self.max_window_rays < self.min_valid_rays || self.max_window_rays > 1 << 20 {
            return err(
                "max_window_rays",
                format!(
                    "must be in [min_valid_rays ({}), 1048576], got {}",
                    self.min_valid_rays, self.max_window_rays
                ),
            );
        }
        if self.max_gap_ns <= 0 {
            return err(
                "max_gap_ns",
                format!("must be > 0, got {}", self.max_gap_ns),
            );
        }
        Ok(())
    }
}

/// Why a pass (or a derivative) produced no sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DropReason {
    /// Fewer valid returns in the window than `min_valid_rays`.
    TooFewValid,
    /// More valid returns in the window than `max_window_rays`.
    WindowOverflow,
    /// The pass began before the stream (re)started or was cut by a gap.
    Partial,
    /// The interval to the previous measurement exceeded `max_gap_ns`:
    /// the distance restarts the derivative.
    Gap,
    /// Measurement time not after the previous one: restarts the derivative.
    NonIncreasingTime,
    /// A ray earlier than the previous ray was ignored.
    RayOutOfOrder,
}

impl DropReason {
    /// All reasons, in counter order.
    pub const ALL: [DropReason; 6] = [
        DropReason::TooFewValid,
        DropReason::WindowOverflow,
        DropReason::Partial,
        DropReason::Gap,
        DropReason::NonIncreasingTime,
        DropReason::RayOutOfOrder,
    ];

    /// Index into [`Counters::dropped`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// snake_case name.
    pub fn name(self) -> &'static str {
        match self {
            DropReason::TooFewValid => "too_few_valid",
            DropReason::WindowOverflow => "window_overflow",
            DropReason::Partial => "partial",
            DropReason::Gap => "gap",
            DropReason::NonIncreasingTime => "non_increasing_time",
            DropReason::RayOutOfOrder => "ray_out_of_order",
        }
    }
}

/// Processing counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    /// Rays pushed.
    pub rays: u64,
    /// Rays inside the window that were dropped as invalid returns.
    pub invalid_returns: u64,
    /// Passes through the window that were closed.
    pub passes: u64,
    /// Robust distances measured.
    pub measurements: u64,
    /// Samples emitted.
    pub samples: u64,
    /// Drops by reason, indexed by [`DropReason::index`].
    pub dropped: [u64; 6],
}

impl Counters {
    /// Count for one reason.
    pub fn dropped(&self, reason: DropReason) -> u64 {
        self.dropped[reason.index()]
    }
}

/// One robust distance measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Median distance, metres.
    pub distance_m: f64,
    /// Median time of the rays used, ns.
    pub t_ns: Nanos,
    /// Number of valid returns used.
    pub rays_used: usize,
}

/// Streaming signature processor; allocation-free after [`SignatureProcessor::new`].
#[derive(Debug, Clone)]
pub struct SignatureProcessor {
    cfg: SignatureConfig,
    ranges: Vec<f64>,
    times: Vec<Nanos>,
    in_pass: bool,
    pass_partial: bool,
    pass_overflow: bool,
    pass_start_t: Nanos,
    period_hint_ns: Nanos,
    last_ray_t: Option<Nanos>,
    prev: Option<Measurement>,
    counters: Counters,
}

impl SignatureProcessor {
    /// Validates the configuration and allocates the window buffers.
    pub fn new(cfg: SignatureConfig) -> Result<Self, ConfigError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            ranges: Vec::with_capacity(cfg.max_window_rays),
            times: Vec::with_capacity(cfg.max_window_rays),
            in_pass: false,
            pass_partial: false,
            pass_overflow: false,
            pass_start_t: 0,
            period_hint_ns: 0,
            last_ray_t: None,
            prev: None,
            counters: Counters::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SignatureConfig {
        &self.cfg
    }

    /// Counters since construction.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// The latest robust distance measurement, if any since the last reset.
    pub fn last_measurement(&self) -> Option<Measurement> {
        self.prev
    }

    /// Forgets the stream state (open pass, previous distance); keeps counters.
    pub fn reset(&mut self) {
        self.ranges.clear();
        self.times.clear();
        self.in_pass = false;
        self.pass_partial = false;
        self.pass_overflow = false;
        self.last_ray_t = None;
        self.prev = None;
    }

    /// True when `bearing_rad` lies inside the window (edges included, with a
    /// 1 nrad tolerance so that rays exactly on an edge are not lost to rounding).
    pub fn in_window(&self, bearing_rad: f64) -> bool {
        wrap_pi(bearing_rad - self.cfg.window_centre_rad).abs()
            <= self.cfg.window_half_width_rad + 1e-9
    }

    /// Sets the rotation period used to bound the length of a pass (0 = unknown,
    /// no bound). [`SignatureProcessor::push_scan`] sets it from the scan timing.
    pub fn set_period_hint(&mut self, period_ns: Nanos) {
        self.period_hint_ns = period_ns.max(0);
    }

    /// Longest time a pass can last: the window's share of a revolution,
    /// plus half of that as slack; 0 when the period is unknown.
    fn pass_limit_ns(&self) -> Nanos {
        if self.period_hint_ns <= 0 {
            return 0;
        }
        let frac = self.cfg.window_half_width_rad / std::f64::consts::PI;
        (1.5 * frac * self.period_hint_ns as f64).ceil() as Nanos
    }

    /// Feeds every ray of `scan`, calling `emit` for each sample produced.
    /// Returns the number of samples produced.
    pub fn push_scan(&mut self, scan: &Scan, mut emit: impl FnMut(Sample)) -> usize {
        self.set_period_hint(scan.timing().period_ns);
        let mut n = 0;
        for ray in scan.rays() {
            if let Some(s) = self.push_ray(ray) {
                emit(s);
                n += 1;
            }
        }
        n
    }

    /// Feeds one ray (rays must come in time order); returns a sample when
    /// this ray closes a pass and the derivative can be formed.
    pub fn push_ray(&mut self, ray: &Ray) -> Option<Sample> {
        self.counters.rays += 1;
        let mut after_gap = self.last_ray_t.is_none();
        if let Some(lt) = self.last_ray_t {
            if ray.t_ns < lt {
                self.drop_reason(DropReason::RayOutOfOrder);
                return None;
            }
            if ray.t_ns.saturating_sub(lt) > self.cfg.max_gap_ns {
                after_gap = true;
                if self.in_pass {
                    self.pass_partial = true;
                }
            }
        }
        self.last_ray_t = Some(ray.t_ns);

        // a pass longer than the window's share of a revolution means the
        // data holds no ray outside the window (e.g. a sector-only recording):
        // the beam has come round again, so close the pass first
        let mut closed = None;
        let limit = self.pass_limit_ns();
        if self.in_pass && limit > 0 && ray.t_ns.saturating_sub(self.pass_start_t) > limit {
            closed = self.close_pass();
        }

        if self.in_window(ray.bearing_rad) {
            if !self.in_pass {
                self.in_pass = true;
                self.pass_partial = after_gap;
                self.pass_overflow = false;
                self.pass_start_t = ray.t_ns;
            }
            if self.usable(ray) {
                if self.ranges.len() < self.cfg.max_window_rays {
                    self.ranges.push(ray.range_m);
                    self.times.push(ray.t_ns);
                } else {
                    self.pass_overflow = true;
                }
            } else {
                self.counters.invalid_returns += 1;
            }
            closed
        } else if self.in_pass {
            self.close_pass()
        } else {
            closed
        }
    }

    fn usable(&self, ray: &Ray) -> bool {
        ray.valid
            && ray.range_m.is_finite()
            && ray.range_m > 0.0
            && ray.range_m >= self.cfg.min_range_m
            && ray.range_m <= self.cfg.max_range_m
    }

    fn drop_reason(&mut self, r: DropReason) {
        self.counters.dropped[r.index()] += 1;
    }

    fn close_pass(&mut self) -> Option<Sample> {
        self.in_pass = false;
        self.counters.passes += 1;
        let reason = if self.pass_partial {
            Some(DropReason::Partial)
        } else if self.pass_overflow {
            Some(DropReason::WindowOverflow)
        } else if self.ranges.len() < self.cfg.min_valid_rays {
            Some(DropReason::TooFewValid)
        } else {
            None
        };
        if let Some(r) = reason {
            self.drop_reason(r);
            self.ranges.clear();
            self.times.clear();
            return None;
        }
        let n = self.ranges.len();
        let distance_m = median_in_place(&mut self.ranges);
        // times are in push order, which is time order
        let (a, b) = (self.times[(n - 1) / 2], self.times[n / 2]);
        let t_ns = midpoint(a, b);
        self.ranges.clear();
        self.times.clear();
        let m = Measurement {
            distance_m,
            t_ns,
            rays_used: n,
        };
        self.counters.measurements += 1;
        self.derivative(m)
    }

    fn derivative(&mut self, m: Measurement) -> Option<Sample> {
        let prev = self.prev.replace(m)?;
        if m.t_ns <= prev.t_ns {
            self.drop_reason(DropReason::NonIncreasingTime);
            return None;
        }
        // saturates for absurd inputs; a saturated interval is a gap
        let dt = m.t_ns.saturating_sub(prev.t_ns);
        if dt > self.cfg.max_gap_ns {
            self.drop_reason(DropReason::Gap);
            return None;
        }
        let value = (m.distance_m - prev.distance_m) / (dt as f64 / NANOS_PER_SEC as f64);
        let t_ns = match self.cfg.stamping {
            Stamping::Midpoint => midpoint(prev.t_ns, m.t_ns),
            Stamping::End => m.t_ns,
        };
        self.counters.samples += 1;
        Some(Sample::new(t_ns, value))
    }
}

/// `(a + b) / 2` without overflow (rounded towards `a` for odd sums, i.e. down when `a <= b`).
fn midpoint(a: Nanos, b: Nanos) -> Nanos {
    ((a as i128 + b as i128).div_euclid(2)) as Nanos
}

/// Median of a non-empty slice of finite values (reorders the slice);
/// the mean of the two middle values for an even length.
fn median_in_place(v: &mut [f64]) -> f64 {
    let n = v.len();
    let mid = n / 2;
    let (left, upper, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    let upper = *upper;
    if n % 2 == 1 {
        upper
    } else {
        let lower = left.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lower + upper)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::{Rotation, ScanTiming};
    use proptest::prelude::*;
    use std::f64::consts::PI;

    const PERIOD: Nanos = 100_000_000;

    fn scan_at(k: i64, wall: impl Fn(usize) -> f64, rotation: Rotation) -> Scan {
        let rays = (0..360)
            .map(|i| Ray::new((i as f64).to_radians(), wall(i), 50.0, true))
            .collect();
        let timing = ScanTiming {
            start_ns: k * PERIOD,
            period_ns: PERIOD,
            rotation,
            start_bearing_rad: 0.0,
        };
        Scan::from_uniform(timing, rays)
    }

    fn run(cfg: SignatureConfig, scans: &[Scan]) -> (Vec<Sample>, SignatureProcessor) {
        let mut p = SignatureProcessor::new(cfg).unwrap();
        let mut out = Vec::new();
        for s in scans {
            p.push_scan(s, |x| out.push(x));
        }
        (out, p)
    }

    #[test]
    fn constant_speed_midpoint_and_end() {
        let scans: Vec<_> = (0..5)
            .map(|k| scan_at(k, |_| 3.0 - 0.1 * k as f64, Rotation::Ccw))
            .collect();
        let cfg = SignatureConfig {
            window_centre_rad: PI / 2.0,
            ..Default::default()
        };
        let (mid, p) = run(cfg, &scans);
        assert_eq!(mid.len(), 4);
        for (j, s) in mid.iter().enumerate() {
            assert!((s.value + 1.0).abs() < 1e-9, "{s:?}");
            // measurements at k*P + P/4; midpoint between j and j+1
            assert_eq!(s.t_ns, j as i64 * PERIOD + PERIOD / 4 + PERIOD / 2);
        }
        assert_eq!(p.counters().samples, 4);
        let (end, _) = run(
            SignatureConfig {
                stamping: Stamping::End,
                ..cfg
            },
            &scans,
        );
        assert_eq!(end[0].t_ns, PERIOD + PERIOD / 4);
    }

    #[test]
    fn window_across_scan_seam_is_one_pass() {
        // window at 0 rad: rays 355..359 end scan k, rays 0..5 start scan k+1
        let scans: Vec<_> = (0..4)
            .map(|k| scan_at(k, |_| 2.0 + 0.2 * k as f64, Rotation::Ccw))
            .collect();
        let (out, p) = run(SignatureConfig::default(), &scans);
        // first pass (rays 0..5 of scan 0) started with the stream: partial
        assert_eq!(p.counters().dropped(DropReason::Partial), 1);
        // passes closing in scans 1, 2 and 3 each straddle a seam: 3 distances, 2 samples
        assert_eq!(p.counters().measurements, 3);
        assert_eq!(out.len(), 2);
        let m = p.last_measurement().unwrap();
        // 11 rays (355..=359 then 0..=5): the middle one is ray 0 of scan 3
        assert_eq!(m.t_ns, 3 * PERIOD);
        assert_eq!(m.rays_used, 11);
        // the majority of each pass is in the later scan: 0.2 m per 0.1 s
        assert!((out[0].value - 2.0).abs() < 1e-9, "{out:?}");
        assert_eq!(out[0].t_ns, PERIOD + PERIOD / 2);
    }

    #[test]
    fn too_few_valid_and_invalid_returns_are_counted() {
        let cfg = SignatureConfig {
            window_centre_rad: PI / 2.0,
            ..Default::default()
        };
        let bad = |i: usize| {
            if (86..=94).contains(&i) {
                if i.is_multiple_of(3) {
                    f64::NAN
                } else {
                    0.0
                }
            } else {
                2.0
            }
        };
        let scans = [
            scan_at(0, |_| 2.0, Rotation::Ccw),
            scan_at(1, bad, Rotation::Ccw),
        ];
        let (out, p) = run(cfg, &scans);
        assert!(out.is_empty());
        assert_eq!(p.counters().dropped(DropReason::TooFewValid), 1);
        assert_eq!(p.counters().invalid_returns, 9);
    }

    #[test]
    fn median_rejects_outliers() {
        let cfg = SignatureConfig {
            window_centre_rad: PI / 2.0,
            ..Default::default()
        };
        let spiky = |k: i64| {
            move |i: usize| {
                if i == 90 {
                    30.0
                } else {
                    2.0 + 0.1 * k as f64
                }
            }
        };
        let scans: Vec<_> = (0..3)
            .map(|k| scan_at(k, spiky(k), Rotation::Ccw))
            .collect();
        let (out, _) = run(cfg, &scans);
        assert!((out[0].value - 1.0).abs() < 1e-9);
    }

    #[test]
    fn missing_scan_resets_derivative() {
        let cfg = SignatureConfig {
            window_centre_rad: PI / 2.0,
            max_gap_ns: 150_000_000,
            ..Default::default()
        };
        let scans = [
            scan_at(0, |_| 2.0, Rotation::Ccw),
            scan_at(1, |_| 2.1, Rotation::Ccw),
            // scan 2 lost
            scan_at(3, |_| 2.3, Rotation::Ccw),
            scan_at(4, |_| 2.4, Rotation::Ccw),
        ];
        let (out, p) = run(cfg, &scans);
        assert_eq!(out.len(), 2);
        assert_eq!(p.counters().dropped(DropReason::Gap), 1);
        assert_eq!(out[1].t_ns, 3 * PERIOD + PERIOD / 4 + PERIOD / 2);
    }

    #[test]
    fn cw_rotation_measures_later_in_scan() {
        let cfg = SignatureConfig {
            window_centre_rad: PI / 2.0,
            ..Default::default()
        };
        let scans: Vec<_> = (0..2)
            .map(|k| scan_at(k, |_| 1.0 + k as f64, Rotation::Cw))
            .collect();
        let (out, _) = run(cfg, &scans);
        // bearing +90 deg is reached after 3/4 of a clockwise turn
        assert_eq!(out[0].t_ns, 3 * PERIOD / 4 + PERIOD / 2);
        assert!((out[0].value - 10.0).abs() < 1e-9);
    }

    #[test]
    fn sector_only_scans_still_close_passes() {
        let cfg = SignatureConfig {
            window_centre_rad: PI / 2.0,
            ..Default::default()
        };
        let scans: Vec<_> = (0..5)
            .map(|k| {
                let rays = (86..=94)
                    .map(|i| Ray::new((i as f64).to_radians(), 1.0 + 0.1 * k as f64, 0.0, true))
                    .collect();
                let timing = ScanTiming {
                    start_ns: k * PERIOD,
                    period_ns: PERIOD,
                    rotation: Rotation::Ccw,
                    start_bearing_rad: 0.0,
                };
                Scan::from_uniform(timing, rays)
            })
            .collect();
        let (out, p) = run(cfg, &scans);
        // passes close when the next scan's window rays arrive; the first
        // one began with the stream (partial): 3 distances, 2 samples
        assert_eq!(p.counters().dropped(DropReason::Partial), 1);
        assert_eq!(p.counters().measurements, 3, "{:?}", p.counters());
        assert_eq!(out.len(), 2);
        assert!((out[0].value - 1.0).abs() < 1e-9);
        assert_eq!(out[0].t_ns, PERIOD + PERIOD / 4 + PERIOD / 2);
    }

    #[test]
    fn out_of_order_ray_ignored() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        p.push_ray(&Ray::timed(1.0, 1.0, 0.0, true, 100));
        p.push_ray(&Ray::timed(1.0, 1.0, 0.0, true, 50));
        assert_eq!(p.counters().dropped(DropReason::RayOutOfOrder), 1);
    }

    #[test]
    fn config_errors_name_the_field() {
        let e = SignatureConfig {
            window_half_width_rad: 3.0,
            ..Default::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(e.field, "window_half_width_rad");
        assert!(e.to_string().contains('3'));
        for bad in [
            SignatureConfig {
                max_range_m: 0.0,
                ..Default::default()
            },
            SignatureConfig {
                min_valid_rays: 0,
                ..Default::default()
            },
            SignatureConfig {
                max_gap_ns: 0,
                ..Default::default()
            },
            SignatureConfig {
                window_centre_rad: f64::NAN,
                ..Default::default()
            },
        ] {
            assert!(SignatureProcessor::new(bad).is_err());
        }
    }

    #[test]
    fn median_even_and_odd() {
        assert_eq!(median_in_place(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median_in_place(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median_in_place(&mut [7.0]), 7.0);
    }

    proptest! {
        #[test]
        fn arbitrary_rays_never_panic(rays in proptest::collection::vec(
            (any::<f64>(), any::<f64>(), any::<bool>(), 0i64..2_000_000_000), 0..400)) {
            let mut p = SignatureProcessor::new(SignatureConfig { max_window_rays: 8, ..Default::default() }).unwrap();
            let mut t = 0;
            for (b, r, v, dt) in rays {
                t += dt / 10;
                if let Some(s) = p.push_ray(&Ray::timed(b, r, 0.0, v, t)) {
                    prop_assert!(s.value.is_finite());
                }
            }
        }

        #[test]
        fn extreme_times_never_panic(ts in proptest::collection::vec(any::<i64>(), 0..60), gap in 1i64..i64::MAX) {
            let mut p = SignatureProcessor::new(SignatureConfig { max_gap_ns: gap, min_valid_rays: 1, ..Default::default() }).unwrap();
            p.set_period_hint(i64::MAX);
            let mut sorted = ts;
            sorted.sort_unstable();
            for (i, t) in sorted.into_iter().enumerate() {
                let b = if i % 2 == 0 { 0.0 } else { 2.0 };
                if let Some(s) = p.push_ray(&Ray::timed(b, 1.0 + i as f64, 0.0, true, t)) {
                    prop_assert!(s.value.is_finite());
                }
            }
        }

        #[test]
        fn median_matches_sort(mut v in proptest::collection::vec(-1e6f64..1e6, 1..50)) {
            let mut sorted = v.clone();
            sorted.sort_by(f64::total_cmp);
            let n = sorted.len();
            let want = if n % 2 == 1 { sorted[n / 2] } else { 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]) };
            prop_assert_eq!(median_in_place(&mut v), want);
        }
    }
}
