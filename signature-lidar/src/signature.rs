//! The LiDAR signature: rate of change of the robust distance to a wall.
//!
//! For each pass of the beam through a bearing window (`centre ± half_width`),
//! the processor takes
//!
//! * the **robust distance** `d[k]` from the valid returns in the window
//!   (device-invalid, zero, NaN, infinite and out-of-range returns are
//!   dropped), by default ([`Distance::Wall`]) the perpendicular distance to
//!   the wall straight ahead, fitted robustly to the returns (below), or
//!   ([`Distance::Median`]) the median range, and
//! * its **measurement time** `t_d[k]`: when the beam pointed along the fitted
//!   wall's normal, found from the times of the returns it was fitted to (their
//!   mean time, at both ends of a derivative across a turn; the median time of
//!   the rays used, for the median),
//!
//! and emits the sample `(d[k] - d[k-1]) / (t_d[k] - t_d[k-1])` in m/s,
//! stamped by default at the **midpoint** `(t_d[k-1] + t_d[k]) / 2`
//! ([`Stamping::Midpoint`]): a difference of two distances is the mean speed
//! over the interval between them, so stamping it at the end
//! ([`Stamping::End`], available for comparison) biases every sample late by
//! half a rotation period.
//!
//! # The wall, not the median
//!
//! A cheap 2-D LiDAR (LD06: ~1 cm range noise, 0.8° between returns at 10 Hz)
//! puts a dozen returns into a ±5° window; their median is noisy (a 4.5 cm/s
//! rate noise at 10 Hz), and wider windows do not help the median because a flat
//! wall's ranges grow as `1/cos` away from its normal. A straight line fitted to
//! the returns uses all of them (±20° by default: ~50 returns, 1.6 cm/s), and
//! its perpendicular distance does not change when the robot turns in place,
//! whereas the range along a fixed bearing swings through metres as the beam
//! sweeps along a wall or across a corner. The fit grows from the window centre
//! and stops at corners and edges (see [`Distance::Wall`]), so it measures the
//! surface straight ahead; stray returns and other surfaces are left out.
//!
//! # Implausible derivatives
//!
//! A derivative is not formed across a change of surface: when the fitted
//! wall's normal turned by more than [`SignatureConfig::max_normal_change_rad`]
//! between two passes (a turn has carried the window across a corner), or when
//! it implies a speed above [`SignatureConfig::max_rate_mps`] (a jump to a nearer
//! surface). Those are [`DropReason::SurfaceChange`] and
//! [`DropReason::Implausible`]; the next pass differences normally again.
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
//! than `max_gap_ns` apart (at the default 300 ms and 10 Hz: two or more
//! consecutive scans or passes lost; one lost pass only makes the derivative
//! span two revolutions, still divided by its true interval), the new
//! distance restarts the derivative ([`DropReason::Gap`]). A pass cut by a gap
//! between two rays, or one already under way when the stream (re)started, is
//! dropped ([`DropReason::Partial`]).
//!
//! # Allocation
//!
//! All buffers are allocated in [`SignatureProcessor::new`]
//! (`max_window_rays` ranges, times, bearings and fit scratch); processing never
//! allocates.
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
//!     // a flat wall on the left (normal at bearing 90°) receding at 0.5 m/s
//!     let wall = 2.0 + 0.05 * k as f64;
//!     let rays = (0..360)
//!         .map(|i| {
//!             let off = (i as f64 - 90.0).to_radians();
//!             let r = if off.abs() < 1.0 { wall / off.cos() } else { 9.0 };
//!             Ray::new((i as f64).to_radians(), r, 100.0, true)
//!         })
//!         .collect();
//!     let timing = ScanTiming { start_ns: k * period, period_ns: period, rotation: Rotation::Ccw, start_bearing_rad: 0.0 };
//!     p.push_scan(&Scan::from_uniform(timing, rays), |s| samples.push(s));
//! }
//! assert_eq!(samples.len(), 2);
//! assert!((samples[0].value - 0.5).abs() < 1e-9);
//! // midpoint of the two measurements of the window around 90°, 25 ms into scans 0 and 1
//! assert_eq!(samples[0].t_ns, 75_000_000);
//! ```

use crate::scan::{wrap_pi, Ray, Scan};
use std::f64::consts::{FRAC_PI_2, PI, TAU};
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

/// How a pass's returns become one distance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Distance {
    /// Perpendicular distance to the wall straight ahead, a straight line fitted
    /// to the window's returns (the default). Uses every return on the wall, so
    /// its noise is that of a mean of all of them; turning in place leaves it
    /// unchanged.
    ///
    /// In the window frame (`x` along the window centre, `y` to its left) the
    /// returns are points `r (cos θ, sin θ)` in sweep order; the wall is a line
    /// `x = a + b y`.
    /// 1. Seed: the central third of the returns (7 to 25 of them); `b` is the
    ///    repeated median of their pairwise slopes (right while fewer than half
    ///    of them lie off the wall: past a corner, strays), `a` the median of
    ///    `x - b y`; seed returns within `3 · 1.4826 · MAD` (clamped to 2-8 cm)
    ///    of that line start a least-squares fit.
    /// 2. Growth: outwards on both sides, a return joins when it lies within
    ///    `max(3 σ, 2 cm) + 3 s` (at most 8 cm) of the current least-squares
    ///    line (`σ` the fit's residual standard deviation, `s` the line's
    ///    standard error where it is extrapolated; refitted after every return);
    ///    a side stops after 3 consecutive misses (a corner, an edge, another
    ///    surface).
    /// 3. Settling: the returns of the grown span within `max(3 σ, 2 cm)` of the
    ///    grown line are refitted, twice, so the result does not depend on the
    ///    order in which the returns joined.
    ///
    /// The distance is `a / √(1 + b²)`, its time the time the beam pointed
    /// along the wall's normal, from the returns' times regressed on their
    /// position along the line (a wall moving steadily during the sweep tilts
    /// the fitted line so that its distance is the wall's at that time, not at
    /// the returns' mean time: up to `period / 4π` apart for a wall seen at an
    /// angle; the two agree for a wall square to the window); a derivative
    /// across passes whose normals differ by more than 1° (a turn) takes both
    /// at the returns' mean times instead. No
    /// distance ([`DropReason::NoWall`]) when the line explains
    /// fewer than [`SignatureConfig::min_inlier_fraction`] of the returns (or
    /// fewer than `min_valid_rays`, or 3), or its normal is farther than
    /// [`SignatureConfig::max_incidence_rad`] from the window centre.
    #[default]
    Wall,
    /// Median of the valid ranges, timed at the median time of the rays used.
    Median,
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
    /// How the returns of a pass become one distance.
    pub distance: Distance,
    /// [`Distance::Wall`]: a fitted wall whose normal is farther than this from
    /// the window centre (a grazing view) yields no distance, radians, in `(0, π/2)`.
    pub max_incidence_rad: f64,
    /// [`Distance::Wall`]: smallest share of the valid returns the fitted wall
    /// must explain (the rest are outliers: another surface, a corner), in `(0, 1]`.
    pub min_inlier_fraction: f64,
    /// [`Distance::Wall`]: a wall whose normal turned by more than this between two
    /// measurements is another surface (the window crossed a corner or an edge):
    /// no derivative across it, radians (> 0).
    pub max_normal_change_rad: f64,
    /// Derivatives faster than this (m/s) are not a robot's motion but a jump
    /// between surfaces: dropped (> 0; `inf` disables).
    pub max_rate_mps: f64,
}

impl Default for SignatureConfig {
    fn default() -> Self {
        Self {
            window_centre_rad: 0.0,
            window_half_width_rad: 20f64.to_radians(),
            min_range_m: 0.05,
            max_range_m: 40.0,
            min_valid_rays: 3,
            max_window_rays: 1024,
            max_gap_ns: 300_000_000,
            stamping: Stamping::Midpoint,
            distance: Distance::Wall,
            max_incidence_rad: 60f64.to_radians(),
            min_inlier_fraction: 0.5,
            max_normal_change_rad: 20f64.to_radians(),
            max_rate_mps: 2.0,
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
        if self.distance == Distance::Wall && self.max_window_rays < 3 {
            return err(
                "max_window_rays",
                format!(
                    "must be >= 3 with the wall fit (it needs 3 returns on the line), got {}",
                    self.max_window_rays
                ),
            );
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
        let inc = self.max_incidence_rad;
        if !(inc > 0.0 && inc < FRAC_PI_2) {
            return err(
                "max_incidence_rad",
                format!("must be in (0, pi/2), got {inc}"),
            );
        }
        let f = self.min_inlier_fraction;
        if !(f > 0.0 && f <= 1.0) {
            return err("min_inlier_fraction", format!("must be in (0, 1], got {f}"));
        }
        if self.max_normal_change_rad.is_nan() || self.max_normal_change_rad <= 0.0 {
            return err(
                "max_normal_change_rad",
                format!("must be > 0, got {}", self.max_normal_change_rad),
            );
        }
        if self.max_rate_mps.is_nan() || self.max_rate_mps <= 0.0 {
            return err(
                "max_rate_mps",
                format!("must be > 0 (inf disables), got {}", self.max_rate_mps),
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
    /// A ray earlier than the previous ray (by at most `max_gap_ns`) was
    /// ignored; a larger step back restarts, counted as [`Self::NonIncreasingTime`].
    RayOutOfOrder,
    /// [`Distance::Wall`]: no wall explains enough of the returns, or it is seen
    /// too obliquely (see [`SignatureConfig::max_incidence_rad`]).
    NoWall,
    /// [`Distance::Wall`]: the wall's normal turned more than
    /// [`SignatureConfig::max_normal_change_rad`]: another surface, no derivative.
    SurfaceChange,
    /// The derivative exceeded [`SignatureConfig::max_rate_mps`].
    Implausible,
}

impl DropReason {
    /// All reasons, in counter order.
    pub const ALL: [DropReason; 9] = [
        DropReason::TooFewValid,
        DropReason::WindowOverflow,
        DropReason::Partial,
        DropReason::Gap,
        DropReason::NonIncreasingTime,
        DropReason::RayOutOfOrder,
        DropReason::NoWall,
        DropReason::SurfaceChange,
        DropReason::Implausible,
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
            DropReason::NoWall => "no_wall",
            DropReason::SurfaceChange => "surface_change",
            DropReason::Implausible => "implausible",
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
    pub dropped: [u64; 9],
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
    /// Distance, metres: to the fitted wall ([`Distance::Wall`]) or the median range.
    pub distance_m: f64,
    /// Time the distance refers to, ns: for the wall, when the beam pointed
    /// along its normal (see [`Distance::Wall`]), or the median time of the rays
    /// used.
    pub t_ns: Nanos,
    /// The mean time of the wall's inlier rays, ns (for the median, `t_ns`): the
    /// time a derivative across a turn uses at both ends (see [`Distance::Wall`]).
    pub mean_t_ns: Nanos,
    /// Number of returns used (the wall's inliers, or all valid returns).
    pub rays_used: usize,
    /// Bearing of the fitted wall's normal in the scan frame, radians (NaN for
    /// [`Distance::Median`]).
    pub normal_rad: f64,
}

/// Streaming signature processor; allocation-free after [`SignatureProcessor::new`].
#[derive(Debug, Clone)]
pub struct SignatureProcessor {
    cfg: SignatureConfig,
    ranges: Vec<f64>,
    times: Vec<Nanos>,
    bearings: Vec<f64>,
    /// Scratch of the wall fit (points, then residuals), `max_window_rays` each.
    xs: Vec<f64>,
    ys: Vec<f64>,
    scratch: Vec<f64>,
    medians: Vec<f64>,
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
            bearings: Vec::with_capacity(cfg.max_window_rays),
            xs: Vec::with_capacity(cfg.max_window_rays),
            ys: Vec::with_capacity(cfg.max_window_rays),
            scratch: Vec::with_capacity(cfg.max_window_rays),
            medians: Vec::with_capacity(cfg.max_window_rays),
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
        self.bearings.clear();
        self.in_pass = false;
        self.pass_partial = false;
        self.pass_overflow = false;
        self.last_ray_t = None;
        self.prev = None;
    }

    /// True when `bearing_rad` lies inside the window (edges included, with a
    /// 1 µrad tolerance: a window a whole number of angular steps wide has rays
    /// exactly on its edges, and rounding, e.g. a recording's float32 angles,
    /// must not move them in or out).
    pub fn in_window(&self, bearing_rad: f64) -> bool {
        offset(bearing_rad, self.cfg.window_centre_rad).abs()
            <= self.cfg.window_half_width_rad + 1e-6
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
                if lt.saturating_sub(ray.t_ns) <= self.cfg.max_gap_ns {
                    self.drop_reason(DropReason::RayOutOfOrder);
                    return None;
                }
                // the clock stepped back (a restarted sensor, concatenated
                // recordings, one ray stamped far ahead): start over from this ray
                // instead of waiting for time to pass the old one
                self.drop_reason(DropReason::NonIncreasingTime);
                self.reset();
                after_gap = true;
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
                    self.bearings.push(ray.bearing_rad);
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
            self.clear_pass();
            return None;
        }
        let m = match self.cfg.distance {
            Distance::Median => {
                let n = self.ranges.len();
                let distance_m = median_in_place(&mut self.ranges);
                // times are in push order, which is time order
                let (a, b) = (self.times[(n - 1) / 2], self.times[n / 2]);
                Some(Measurement {
                    distance_m,
                    t_ns: midpoint(a, b),
                    mean_t_ns: midpoint(a, b),
                    rays_used: n,
                    normal_rad: f64::NAN,
                })
            }
            Distance::Wall => self.fit_wall(),
        };
        self.clear_pass();
        let Some(m) = m else {
            self.drop_reason(DropReason::NoWall);
            return None;
        };
        self.counters.measurements += 1;
        self.derivative(m)
    }

    fn clear_pass(&mut self) {
        self.ranges.clear();
        self.times.clear();
        self.bearings.clear();
    }

    /// [`Distance::Wall`]: the line grown from the window centre, or `None`.
    fn fit_wall(&mut self) -> Option<Measurement> {
        const FLOOR_M: f64 = 0.02;
        // no return farther than this from the line joins it, however scattered
        // the fit: a wall, not a compromise between two
        const CAP_M: f64 = 0.08;
        const MAX_MISSES: u32 = 3;
        let n = self.ranges.len();
        if n < 3 {
            return None;
        }
        let centre = self.cfg.window_centre_rad;
        self.xs.clear();
        self.ys.clear();
        let mut c = 0;
        let mut best = f64::INFINITY;
        for (i, (&r, &b)) in self.ranges.iter().zip(&self.bearings).enumerate() {
            let th = offset(b, centre);
            // the return nearest the centre; two about equally near (the centre
            // ray lost, its neighbours at ±one step) go to the later one, so a
            // rounding of the bearings cannot pick a different seed
            if th.abs() < best - 1e-6 || th.abs() <= best + 1e-6 {
                best = best.min(th.abs());
                c = i;
            }
            let (s, co) = th.sin_cos();
            self.xs.push(r * co);
            self.ys.push(r * s);
        }
        // 1. seed
        let seed_half = (n / 6).clamp(3, 12);
        let lo = c.saturating_sub(seed_half);
        let hi = (c + seed_half).min(n - 1);
        // repeated median (Siegel): for each seed return the median slope to the
        // others, then the median of those; right while fewer than half of the
        // seed returns are off the line (another wall past a corner, strays)
        self.medians.clear();
        for i in lo..=hi {
            self.scratch.clear();
            for j in lo..=hi {
                let dy = self.ys[j] - self.ys[i];
                if j != i && dy.abs() > 1e-9 {
                    self.scratch.push((self.xs[j] - self.xs[i]) / dy);
                }
            }
            if !self.scratch.is_empty() {
                self.medians.push(median_in_place(&mut self.scratch));
            }
        }
        if self.medians.is_empty() {
            return None;
        }
        let b0 = median_in_place(&mut self.medians);
        self.scratch.clear();
        self.scratch
            .extend((lo..=hi).map(|i| self.xs[i] - b0 * self.ys[i]));
        let a0 = median_in_place(&mut self.scratch);
        let norm0 = (1.0 + b0 * b0).sqrt();
        self.scratch.clear();
        self.scratch
            .extend((lo..=hi).map(|i| (self.xs[i] - a0 - b0 * self.ys[i]).abs() / norm0));
        let seed_thr = (3.0 * 1.4826 * median_in_place(&mut self.scratch)).clamp(FLOOR_M, CAP_M);
        // running least squares, relative to the centre return (precision) and
        // the first time
        let (xc, yc, t0) = (self.xs[c], self.ys[c], self.times[0]);
        let mut fit = LineFit::default();
        let (mut first, mut last) = (c, c);
        for i in lo..=hi {
            if (self.xs[i] - a0 - b0 * self.ys[i]).abs() / norm0 <= seed_thr {
                fit.add(self.xs[i] - xc, self.ys[i] - yc);
                first = first.min(i);
                last = last.max(i);
            }
        }
        if fit.k < 2 {
            return None;
        }
        // 2. growth
        let (mut left, mut right) = (lo, hi + 1);
        let (mut miss_l, mut miss_r) = (0, 0);
        loop {
            let mut moved = false;
            for side in [1, 0] {
                let i = if side == 1 {
                    if miss_r >= MAX_MISSES || right >= n {
                        continue;
                    }
                    right += 1;
                    right - 1
                } else {
                    if miss_l >= MAX_MISSES || left == 0 {
                        continue;
                    }
                    left -= 1;
                    left
                };
                moved = true;
                let (u, v) = (self.xs[i] - xc, self.ys[i] - yc);
                // the line's own uncertainty where it is extrapolated adds to the
                // returns' scatter
                let ok = fit.residual(u, v).is_some_and(|(e, sd, se)| {
                    e <= ((3.0 * sd).max(FLOOR_M) + 3.0 * se).min(CAP_M)
                });
                let miss = if side == 1 { &mut miss_r } else { &mut miss_l };
                if ok {
                    fit.add(u, v);
                    first = first.min(i);
                    last = last.max(i);
                    *miss = 0;
                } else {
                    *miss += 1;
                }
            }
            if !moved {
                break;
            }
        }
        // 3. settle: the returns of the grown span within `max(3 σ, 2 cm)` of the
        // grown line, twice. The result then depends on the wall, not on the
        // order the returns joined in (a slightly different seed, a rounding of
        // the bearings: the same returns, the same distance)
        let mut times = TimeSums::default();
        for _ in 0..2 {
            let (a, b) = fit.line()?;
            let norm = (1.0 + b * b).sqrt();
            let thr = (3.0 * fit.sd()).clamp(FLOOR_M, CAP_M);
            let mut settled = LineFit::default();
            times = TimeSums::default();
            for i in first..=last {
                let (u, v) = (self.xs[i] - xc, self.ys[i] - yc);
                if (u - a - b * v).abs() / norm <= thr {
                    settled.add(u, v);
                    times.add(self.times[i].saturating_sub(t0), u, v);
                }
            }
            fit = settled;
        }
        let need = self
            .cfg
            .min_valid_rays
            .max((self.cfg.min_inlier_fraction * n as f64).ceil() as usize);
        let (a, b) = fit.line()?;
        if fit.k < need.max(3) {
            return None;
        }
        let a = a + xc - b * yc;
        let normal = -b.atan();
        if !(a > 0.0 && normal.abs() <= self.cfg.max_incidence_rad) {
            return None;
        }
        // the line's own time (relative to the centre return: xc, yc are still
        // subtracted from the sums)
        let shift = times.foot_shift_ns(&fit, b, -xc, -yc);
        let mean = i128::from(t0) + times.st / fit.k as i128;
        Some(Measurement {
            distance_m: a / (1.0 + b * b).sqrt(),
            t_ns: (mean + shift) as Nanos,
            mean_t_ns: mean as Nanos,
            rays_used: fit.k,
            normal_rad: wrap_pi(centre + normal),
        })
    }

    fn derivative(&mut self, m: Measurement) -> Option<Sample> {
        let prev = self.prev.replace(m)?;
        // both ends at the wall's normal while it keeps its direction, both at
        // their returns' mean times across a turn (see `TimeSums`): one
        // convention per derivative, whatever the next one uses
        let turned = wrap_pi(m.normal_rad - prev.normal_rad).abs();
        let (t_prev, t_now) = if turned <= TURNING_RAD {
            (prev.t_ns, m.t_ns)
        } else {
            (prev.mean_t_ns, m.mean_t_ns)
        };
        if t_now <= t_prev {
            self.drop_reason(DropReason::NonIncreasingTime);
            return None;
        }
        // saturates for absurd inputs; a saturated interval is a gap
        let dt = t_now.saturating_sub(t_prev);
        if dt > self.cfg.max_gap_ns {
            self.drop_reason(DropReason::Gap);
            return None;
        }
        // (not finite for the median's normals: no surface to change)
        if turned.is_finite() && turned > self.cfg.max_normal_change_rad {
            self.drop_reason(DropReason::SurfaceChange);
            return None;
        }
        let value = (m.distance_m - prev.distance_m) / (dt as f64 / NANOS_PER_SEC as f64);
        if value.is_nan() || value.abs() > self.cfg.max_rate_mps {
            self.drop_reason(DropReason::Implausible);
            return None;
        }
        let t_ns = match self.cfg.stamping {
            Stamping::Midpoint => midpoint(t_prev, t_now),
            Stamping::End => t_now,
        };
        self.counters.samples += 1;
        Some(Sample::new(t_ns, value))
    }
}

/// A wall whose normal moved more than this between two passes (1°) is turning
/// in the scan frame: the derivative across them takes both distances at their
/// returns' mean times, not at the foot of the normal (see [`TimeSums`]).
const TURNING_RAD: f64 = 0.0175;

/// The inlier returns' times (ns after the first ray of the pass) and their
/// moments with the fit's coordinates: the time of the fitted line.
///
/// A wall that moves while the beam sweeps it is a different distance at each
/// return, so the fitted line is tilted: each return's distance along the true
/// normal is `d(t_i)`, and with the time of a return linear in its position
/// `s` along the wall (`t = t̄ + κ (s - s̄)`, the least-squares slope) the
/// returns lie on a line through their centroid tilted by `v κ`. The
/// perpendicular distance of that line is the wall's at the time the beam
/// points along its normal, `t̄ + κ (s_foot - s̄)`, not at the returns' mean
/// time `t̄`: for a wall seen at an angle `α` from the normal that is about
/// `sin 2α / (2 ω)` earlier or later (8 ms at 45° at 10 Hz), a delay of the
/// signature that changes with the heading. Square to the window
/// (`s̄ = s_foot`) the two agree.
///
/// While the robot turns, the rotation bends the returns too (the distance
/// gains about `ω κ (s̄² - var s)`, `ω` the turn rate), a term that moves with
/// the wall across the window and has no time of its own. There the returns'
/// mean time is kept for both ends of a derivative: on rendered drives (`vlsync-render --example accuracy
/// --seeds 1-6`) the foot's time in turns too moved the estimates by up to
/// 2.6 ms (MAE 1.53 → 2.31 ms), kept to straight passes it gives 1.51 ms.
#[derive(Debug, Default, Clone, Copy)]
struct TimeSums {
    st: i128,
    /// Σ τ, Σ τ u, Σ τ v in f64 (τ in ns within one pass: exact enough).
    t: f64,
    tu: f64,
    tv: f64,
}

impl TimeSums {
    fn add(&mut self, tau: Nanos, u: f64, v: f64) {
        self.st += i128::from(tau);
        let t = tau as f64;
        self.t += t;
        self.tu += t * u;
        self.tv += t * v;
    }

    /// `κ (s_foot - s̄)` in ns for the line `x = a + b y` fitted in `fit`
    /// (the same points), with the origin (the scanner) at `(ox, oy)` in the
    /// fit's coordinates; 0 when the returns do not spread along the line.
    /// Bounded by the returns' own time span either side (the foot is within
    /// `max_incidence_rad` of the window: an extrapolation, not a guess).
    fn foot_shift_ns(&self, fit: &LineFit, b: f64, ox: f64, oy: f64) -> i128 {
        let k = fit.k as f64;
        if fit.k < 3 {
            return 0;
        }
        // s = (b u + v) / norm along the line; the norm cancels in κ (s_foot - s̄)
        let (mu, mv, mt) = (fit.sx / k, fit.sy / k, self.t / k);
        let var_u = fit.sxx / k - mu * mu;
        let var_v = fit.syy / k - mv * mv;
        let cov_uv = fit.sxy / k - mu * mv;
        let var_s = b * b * var_u + 2.0 * b * cov_uv + var_v;
        let cov_ts = b * (self.tu / k - mt * mu) + (self.tv / k - mt * mv);
        if var_s.is_nan() || var_s <= 1e-12 {
            return 0;
        }
        let shift = cov_ts / var_s * ((b * ox + oy) - (b * mu + mv));
        // the span of the returns' times, from the spread of τ along s
        let span = 4.0 * (cov_ts * cov_ts / var_s).sqrt();
        if !shift.is_finite() {
            return 0;
        }
        shift.clamp(-span.max(0.0), span.max(0.0)) as i128
    }
}

/// Incremental least squares of `x = a + b y`.
#[derive(Debug, Clone, Copy, Default)]
struct LineFit {
    k: usize,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
    syy: f64,
}

impl LineFit {
    fn add(&mut self, x: f64, y: f64) {
        self.k += 1;
        self.sx += x;
        self.sy += y;
        self.sxx += x * x;
        self.sxy += x * y;
        self.syy += y * y;
    }

    /// `(a, b)`, or `None` when the points do not spread in `y`.
    fn line(&self) -> Option<(f64, f64)> {
        let k = self.k as f64;
        let d = k * self.syy - self.sy * self.sy;
        if !(self.k >= 2 && d > 1e-12 * k * k) {
            return None;
        }
        let b = (k * self.sxy - self.sx * self.sy) / d;
        Some(((self.sx - b * self.sy) / k, b))
    }

    /// The residual standard deviation, perpendicular to the line (0 with
    /// fewer than 3 points or no line).
    fn sd(&self) -> f64 {
        match self.line() {
            Some((a, b)) if self.k > 2 => {
                let sse = (self.sxx - a * self.sx - b * self.sxy).max(0.0);
                (sse / (self.k - 2) as f64).sqrt() / (1.0 + b * b).sqrt()
            }
            _ => 0.0,
        }
    }

    /// Perpendicular distance of `(x, y)` from the line, the fit's residual
    /// standard deviation (perpendicular; 0 with fewer than 3 points) and the
    /// standard error of the line itself at `y`.
    fn residual(&self, x: f64, y: f64) -> Option<(f64, f64, f64)> {
        let (a, b) = self.line()?;
        let norm = (1.0 + b * b).sqrt();
        let sd = self.sd();
        let k = self.k as f64;
        let my = self.sy / k;
        let syy = (self.syy - k * my * my).max(1e-12);
        let se = sd * (1.0 / k + (y - my) * (y - my) / syy).sqrt();
        Some(((x - a - b * y).abs() / norm, sd, se))
    }
}

/// `wrap_pi(bearing - centre)`, without the remainder in the common case of
/// both angles within a turn of each other (once per ray: it matters).
#[inline]
fn offset(bearing: f64, centre: f64) -> f64 {
    let d = bearing - centre;
    if d.abs() <= PI {
        d
    } else if d > PI && d <= 3.0 * PI {
        d - TAU
    } else if (-3.0 * PI..-PI).contains(&d) {
        d + TAU
    } else {
        wrap_pi(d)
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
    use std::f64::consts::{FRAC_PI_4, PI, TAU};

    const PERIOD: Nanos = 100_000_000;

    /// The window of the tests of pass and stamping logic below: ±5°, median
    /// distance (their "walls" are circles of constant range around the sensor),
    /// no rate limit (they move walls by up to 10 m/s).
    fn legacy() -> SignatureConfig {
        SignatureConfig {
            window_half_width_rad: 5f64.to_radians(),
            distance: Distance::Median,
            max_rate_mps: f64::INFINITY,
            ..SignatureConfig::default()
        }
    }

    /// Scan `k` (starting at `k · PERIOD`) of `rays` spread uniformly over the revolution.
    fn uniform(k: i64, rotation: Rotation, rays: Vec<Ray>) -> Scan {
        let timing = ScanTiming {
            start_ns: k * PERIOD,
            period_ns: PERIOD,
            rotation,
            start_bearing_rad: 0.0,
        };
        Scan::from_uniform(timing, rays)
    }

    fn scan_at(k: i64, wall: impl Fn(usize) -> f64, rotation: Rotation) -> Scan {
        let rays = (0..360)
            .map(|i| Ray::new((i as f64).to_radians(), wall(i), 50.0, true))
            .collect();
        uniform(k, rotation, rays)
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
            ..legacy()
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
        let (out, p) = run(legacy(), &scans);
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
            ..legacy()
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
            ..legacy()
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
            ..legacy()
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
            ..legacy()
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
            ..legacy()
        };
        let scans: Vec<_> = (0..5)
            .map(|k| {
                let rays = (86..=94)
                    .map(|i| Ray::new((i as f64).to_radians(), 1.0 + 0.1 * k as f64, 0.0, true))
                    .collect();
                uniform(k, Rotation::Ccw, rays)
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

    /// A scan of a room corner seen from the origin: a flat wall with its
    /// normal at bearing `normal` and distance `d` (returns within ±60° of the
    /// normal), nothing elsewhere; 0.8° between returns, clockwise like an LD06,
    /// range noise `sigma` from `seed`.
    fn wall_scan(k: i64, d: f64, normal: f64, sigma: f64, seed: u64) -> Scan {
        let n = 450;
        let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut gauss = || {
            // sum of 4 uniforms: approximately normal
            (0..4)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    (x >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                * 3f64.sqrt()
                - 2.0 * 3f64.sqrt()
        };
        let rays = (0..n)
            .map(|i| {
                let b = -(i as f64) * TAU / n as f64;
                let off = wrap_pi(b - normal);
                let r = if off.abs() < 1.05 {
                    d / off.cos() + sigma * gauss()
                } else {
                    0.0
                };
                Ray::new(b, r, 50.0, r > 0.0)
            })
            .collect();
        uniform(k, Rotation::Cw, rays)
    }

    /// The distance of the pass that straddles scans 0 and 1 of `make(k)`
    /// (the window at bearing 0 spans the scan start).
    fn measure(cfg: SignatureConfig, make: impl Fn(i64) -> Scan) -> Option<Measurement> {
        let mut p = SignatureProcessor::new(cfg).unwrap();
        p.push_scan(&make(0), |_| {});
        p.push_scan(&make(1), |_| {});
        p.last_measurement()
    }

    #[test]
    fn wall_distance_is_perpendicular_and_turning_leaves_it() {
        // the same wall, 1.5 m away, seen head-on and with the robot turned by up
        // to 40°: the range straight ahead goes from 1.5 to 1.96 m, the wall's
        // distance stays
        for turn_deg in [0.0f64, 10.0, 25.0, 40.0] {
            let scan = |k| wall_scan(k, 1.5, -turn_deg.to_radians(), 0.0, 1);
            let m = measure(SignatureConfig::default(), scan).unwrap();
            assert!((m.distance_m - 1.5).abs() < 1e-9, "{turn_deg}: {m:?}");
            assert!(
                (m.normal_rad + turn_deg.to_radians()).abs() < 1e-9,
                "{turn_deg}: {m:?}"
            );
            // ±20° of returns on the wall
            assert!((49..=52).contains(&m.rays_used), "{m:?}");
            let median = measure(
                SignatureConfig {
                    distance: Distance::Median,
                    ..SignatureConfig::default()
                },
                scan,
            )
            .unwrap();
            if turn_deg > 0.0 {
                assert!(median.distance_m > m.distance_m + 0.01, "{median:?}");
            }
        }
        // beyond the incidence limit: no wall
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        p.push_scan(&wall_scan(0, 1.5, 70f64.to_radians(), 0.0, 1), |_| {});
        p.push_scan(&wall_scan(1, 1.5, 70f64.to_radians(), 0.0, 1), |_| {});
        assert_eq!(p.counters().dropped(DropReason::NoWall), 1);
        assert!(p.last_measurement().is_none());
    }

    #[test]
    fn wall_fit_averages_the_noise_the_median_keeps() {
        // LD06-like noise (8 mm): the spread of the distance over many scans
        let spread = |distance| {
            let cfg = SignatureConfig {
                distance,
                ..SignatureConfig::default()
            };
            let d: Vec<f64> = (0..200)
                .map(|s| {
                    measure(cfg, |k| wall_scan(k, 2.0, 0.0, 0.008, s + 1000 * k as u64))
                        .unwrap()
                        .distance_m
                })
                .collect();
            let m = d.iter().sum::<f64>() / d.len() as f64;
            let sd = (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / d.len() as f64).sqrt();
            (m, sd)
        };
        let (mw, sw) = spread(Distance::Wall);
        let (mm, sm) = spread(Distance::Median);
        // the line through ~50 returns: 8 mm / sqrt(50) = 1.1 mm
        assert!((mw - 2.0).abs() < 5e-4 && sw < 0.0016, "wall {mw} {sw}");
        // the median of the same returns reads the 1/cos growth and its own noise
        assert!(mm > 2.02 && sm > 1.5 * sw, "median {mm} {sm}");
    }

    #[test]
    fn wall_fit_ignores_stray_returns_and_stops_at_a_corner() {
        // a 1.5 m wall ahead, and a box edge at 0.6 m covering the left 6° of the
        // window: the fit keeps the wall
        let boxed = |k| {
            let scan = wall_scan(k, 1.5, 0.0, 0.004, 3 + k as u64);
            let rays: Vec<Ray> = scan
                .rays()
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    let mut r = *r;
                    let b = r.bearing_rad.to_degrees();
                    if (14.0..20.0).contains(&b) || i % 17 == 5 {
                        // the box, and one stray return in 17
                        r.range_m = 0.6;
                    }
                    r
                })
                .collect();
            Scan::from_timed(*scan.timing(), rays)
        };
        let m = measure(SignatureConfig::default(), boxed).unwrap();
        assert!((m.distance_m - 1.5).abs() < 0.003, "{m:?}");
        // a corner: a wall with its normal at -45° (right) meets one with its
        // normal at +45° at bearing `split`: the fit follows the wall at the
        // window centre, and gives no distance when that holds too few returns
        let corner = |split_deg: f64, min_inlier_fraction: f64| {
            let cfg = SignatureConfig {
                min_inlier_fraction,
                ..SignatureConfig::default()
            };
            measure(cfg, |k| {
                let rays: Vec<Ray> = (0..450)
                    .map(|i| {
                        let b = -(i as f64) * TAU / 450.0;
                        let n = if wrap_pi(b).to_degrees() < split_deg {
                            -FRAC_PI_4
                        } else {
                            FRAC_PI_4
                        };
                        Ray::new(b, 2.0 / wrap_pi(b - n).cos(), 50.0, true)
                    })
                    .collect();
                uniform(k, Rotation::Cw, rays)
            })
        };
        for split in [8.0, 3.0, -3.0, -8.0] {
            let m = corner(split, 0.5).unwrap();
            let normal = if split > 0.0 { -FRAC_PI_4 } else { FRAC_PI_4 };
            assert!(
                (m.normal_rad - normal).abs() < 1e-6 && (m.distance_m - 2.0).abs() < 1e-6,
                "{split}: {m:?}"
            );
        }
        // 3° off centre, the centre's wall holds 29 of the 51 returns: under 70 %
        assert!(corner(3.0, 0.7).is_none());
    }

    #[test]
    fn turning_across_a_corner_is_no_derivative() {
        // a window on the right (bearing -90°, inside each scan); scans 0-1 and
        // 3 see one wall, scan 2 a wall turned by 40°: no sample across
        let cfg = SignatureConfig {
            window_centre_rad: -FRAC_PI_2,
            ..SignatureConfig::default()
        };
        let right = -FRAC_PI_2;
        let scans = [
            wall_scan(0, 2.0, right, 0.0, 1),
            wall_scan(1, 2.0, right, 0.0, 1),
            wall_scan(2, 2.0, right + 40f64.to_radians(), 0.0, 1),
            wall_scan(3, 2.0, right, 0.0, 1),
        ];
        let (out, p) = run(cfg, &scans);
        assert_eq!(
            p.counters().dropped(DropReason::SurfaceChange),
            2,
            "{:?}",
            p.counters()
        );
        assert_eq!(out.len(), 1);
        assert!(out[0].value.abs() < 1e-9, "{out:?}");
        // a jump to a nearer surface ahead is implausibly fast
        let scans = [
            wall_scan(0, 2.0, right, 0.0, 1),
            wall_scan(1, 2.0, right, 0.0, 1),
            wall_scan(2, 1.6, right, 0.0, 1),
            wall_scan(3, 1.58, right, 0.0, 1),
        ];
        let (out, p) = run(cfg, &scans);
        assert_eq!(p.counters().dropped(DropReason::Implausible), 1);
        assert_eq!(out.len(), 2);
        assert!((out[1].value + 0.2).abs() < 1e-6, "{out:?}");
    }

    /// Scan `k` (10 Hz, 450 rays clockwise) of a flat wall whose normal lies at
    /// bearing `normal`, `2 - t` m away at each ray's own time (approaching at
    /// 1 m/s), seen within `reach` rad of its normal.
    fn approaching_wall(k: i64, normal: f64, reach: f64) -> Scan {
        let rays: Vec<Ray> = (0..450)
            .map(|i| {
                let t = k * PERIOD + i * PERIOD / 450;
                let d = 2.0 - 1.0 * t as f64 * 1e-9;
                let b = wrap_pi(-(i as f64) * TAU / 450.0);
                let off = wrap_pi(b - normal);
                let r = if off.abs() < reach {
                    d / off.cos()
                } else {
                    0.0
                };
                Ray::timed(b, r, 50.0, r > 0.0, t)
            })
            .collect();
        let timing = ScanTiming {
            start_ns: k * PERIOD,
            period_ns: PERIOD,
            rotation: Rotation::Cw,
            start_bearing_rad: 0.0,
        };
        Scan::from_timed(timing, rays)
    }

    #[test]
    fn a_moving_wall_gives_its_speed_whatever_the_window() {
        // a wall moving at 1 m/s: each distance is the wall's at its stamp, so
        // the derivative is exact whatever the window (the stamps themselves:
        // `an_oblique_wall_is_stamped_when_its_distance_holds`)
        for hw in [5.0f64, 20.0, 40.0] {
            let cfg = SignatureConfig {
                window_centre_rad: 0.3,
                window_half_width_rad: hw.to_radians(),
                ..SignatureConfig::default()
            };
            let mut p = SignatureProcessor::new(cfg).unwrap();
            let mut out = Vec::new();
            for k in 0..4i64 {
                // per-ray times: the wall is where it is when each ray is measured
                p.push_scan(&approaching_wall(k, 0.3, 1.2), |s| out.push(s));
            }
            assert!(out.len() >= 2, "{hw}: {:?}", p.counters());
            for s in &out {
                assert!((s.value + 1.0).abs() < 1e-3, "{hw}: {s:?}");
            }
        }
    }

    #[test]
    fn an_oblique_wall_is_stamped_when_its_distance_holds() {
        // the wall's normal 0.3 rad, the window centred `alpha` from it: the
        // distance measured is the wall's at the stamp, whatever the angle
        for alpha in [0.0f64, 0.25, -0.4, 0.6] {
            let cfg = SignatureConfig {
                window_centre_rad: 0.3 + alpha,
                ..SignatureConfig::default()
            };
            let mut p = SignatureProcessor::new(cfg).unwrap();
            let d_at = |t: i64| 2.0 - 1.0 * t as f64 * 1e-9;
            let mut checked = 0;
            for k in 0..4i64 {
                p.push_scan(&approaching_wall(k, 0.3, 1.4), |_| {});
                if let Some(m) = p.last_measurement() {
                    let err = m.distance_m - d_at(m.t_ns);
                    assert!(err.abs() < 2e-4, "alpha {alpha}: {m:?} off by {err} m");
                    checked += 1;
                }
            }
            assert!(checked >= 2, "alpha {alpha}: {:?}", p.counters());
        }
    }

    #[test]
    fn a_derivative_takes_one_stamp_convention_at_both_ends() {
        // a wall 0.4 rad off the window's centre, moving at 1 m/s: a pair of
        // passes whose normals agree is stamped between the two feet of the
        // normal; one across a turn (the normal 2° on) between the two mean times
        let pass = |p: &mut SignatureProcessor, k: i64, normal: f64| {
            let mut out = vec![];
            p.push_scan(&approaching_wall(k, normal, 1.4), |s| out.push(s));
            (out, p.last_measurement())
        };
        for (turn, name) in [(0.0f64, "straight"), (2f64.to_radians(), "turning")] {
            let cfg = SignatureConfig {
                window_centre_rad: 0.7,
                ..SignatureConfig::default()
            };
            let mut p = SignatureProcessor::new(cfg).unwrap();
            let mut ms = vec![];
            let mut samples = vec![];
            for k in 0..4 {
                let (out, m) = pass(&mut p, k, 0.3 + turn * k as f64);
                if let Some(m) = m {
                    if ms.last() != Some(&m) {
                        ms.push(m);
                    }
                }
                samples.extend(out);
            }
            assert!(ms.len() >= 3 && samples.len() >= 2, "{name}: {ms:?}");
            // the foot and the mean differ here by milliseconds
            let a = ms[ms.len() - 2];
            let b = ms[ms.len() - 1];
            assert!((a.t_ns - a.mean_t_ns).abs() > 1_000_000, "{a:?}");
            let want = if turn == 0.0 {
                midpoint(a.t_ns, b.t_ns)
            } else {
                midpoint(a.mean_t_ns, b.mean_t_ns)
            };
            assert_eq!(samples.last().unwrap().t_ns, want, "{name}");
        }
    }

    #[test]
    fn wall_fit_does_not_depend_on_rounding() {
        // the same scans through a float32 recording (bearings rebuilt from
        // angle_min + i · angle_increment, ranges as f32, times within 1 µs)
        // give the same returns on the wall, the same distance and time. The
        // window edges (±20°) fall exactly on rays 0.8° apart.
        let f32ed = |scan: &Scan| {
            let inc = (-TAU / 450.0) as f32;
            let rays: Vec<Ray> = scan
                .rays()
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    let b = f64::from(inc) * i as f64;
                    let jitter = ((i * 7919) % 1001) as i64 - 500;
                    Ray::timed(
                        b,
                        f64::from(r.range_m as f32),
                        50.0,
                        r.valid,
                        r.t_ns + jitter,
                    )
                })
                .collect();
            Scan::from_timed(*scan.timing(), rays)
        };
        for seed in 0..40u64 {
            let d = 0.8 + 0.15 * seed as f64;
            let normal = 0.02 * (seed as f64 - 20.0);
            let make = |k| wall_scan(k, d - 0.03 * k as f64, normal, 0.008, seed * 10 + k as u64);
            let a = measure(SignatureConfig::default(), make).unwrap();
            let b = measure(SignatureConfig::default(), |k| f32ed(&make(k))).unwrap();
            assert_eq!(a.rays_used, b.rays_used, "seed {seed}: {a:?} {b:?}");
            assert!(
                (a.distance_m - b.distance_m).abs() < 1e-5,
                "seed {seed}: {a:?} {b:?}"
            );
            assert!((a.t_ns - b.t_ns).abs() <= 500, "seed {seed}: {a:?} {b:?}");
        }
    }

    #[test]
    fn out_of_order_ray_ignored() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        p.push_ray(&Ray::timed(1.0, 1.0, 0.0, true, 100));
        p.push_ray(&Ray::timed(1.0, 1.0, 0.0, true, 50));
        assert_eq!(p.counters().dropped(DropReason::RayOutOfOrder), 1);
    }

    #[test]
    fn a_clock_step_back_restarts_instead_of_stalling() {
        // one ray stamped 1000 s ahead (a mistyped CSV row), then the stream goes on
        let cfg = SignatureConfig {
            window_centre_rad: PI / 2.0,
            ..legacy()
        };
        let mut p = SignatureProcessor::new(cfg).unwrap();
        let mut out = Vec::new();
        for k in 0..5 {
            p.push_scan(&scan_at(k, |_| 3.0 - 0.1 * k as f64, Rotation::Ccw), |x| {
                out.push(x)
            });
        }
        assert_eq!(out.len(), 4);
        p.push_ray(&Ray::timed(1.0, 2.0, 0.0, true, 1_000 * 1_000_000_000));
        for k in 5..10 {
            p.push_scan(&scan_at(k, |_| 3.0 - 0.1 * k as f64, Rotation::Ccw), |x| {
                out.push(x)
            });
        }
        assert_eq!(p.counters().dropped(DropReason::NonIncreasingTime), 1);
        assert_eq!(p.counters().dropped(DropReason::RayOutOfOrder), 0);
        // restarted at scan 5: its pass starts a new derivative, scans 6..9 give samples
        assert_eq!(out.len(), 8, "{out:?}");
        assert!(out[4..].iter().all(|s| (s.value + 1.0).abs() < 1e-9));
        assert!(out.windows(2).skip(4).all(|w| w[1].t_ns > w[0].t_ns));
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
        // the wall fit needs room for 3 returns; the median does not
        let tiny = SignatureConfig {
            min_valid_rays: 1,
            max_window_rays: 2,
            ..Default::default()
        };
        assert_eq!(tiny.validate().unwrap_err().field, "max_window_rays");
        let median = SignatureConfig {
            distance: Distance::Median,
            ..tiny
        };
        assert!(median.validate().is_ok());
    }

    #[test]
    fn offset_is_wrap_pi_of_the_difference() {
        for (b, c) in [
            (0.1, -0.2),
            (3.0, -3.0),
            (-3.0, 3.0),
            (PI, -PI),
            (10.0, 0.5),
            (-20.0, 7.0),
            (f64::NAN, 0.0),
        ] {
            let (o, w) = (offset(b, c), wrap_pi(b - c));
            assert!(
                o == w || (o - w).abs() < 1e-12 || (o.is_nan() && w.is_nan()),
                "{b} {c}: {o} {w}"
            );
            assert!(o.is_nan() || (-PI..=PI).contains(&o));
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
