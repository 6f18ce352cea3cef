//! Scan types: rays with their own measurement times.
//!
//! # Conventions
//!
//! * **Bearing**: radians in the scanner's own frame, counter-clockwise
//!   positive seen from above (ROS REP-103), `0` = the sensor's forward mark,
//!   normalised to `(-π, π]`. Device parsers convert their native angles
//!   (LD06 and RPLIDAR report degrees **clockwise**) into this convention.
//! * **Rotation direction**: [`Rotation::Ccw`] means the beam sweeps
//!   counter-clockwise seen from above, so bearings *increase* with time;
//!   [`Rotation::Cw`] means they decrease. LD06/LD19 and RPLIDAR spin
//!   clockwise.
//! * **Ray time**: every [`Ray`] carries its own measurement time `t_ns`
//!   on the clock the scan was stamped with. When the source gives per-point
//!   times they are stored as given (exact); otherwise
//!   [`Scan::from_uniform`] derives them from the scan start, the rotation
//!   period and the direction: a ray at bearing `θ` is measured
//!   `Δθ / 2π · period` after the start, where `Δθ` is the angle swept from
//!   the start bearing in the rotation direction.
//!
//! The rays of a [`Scan`] are always kept in time order.
//!
//! ```
//! use vlsync_signature_lidar::scan::{Ray, Rotation, Scan, ScanTiming};
//! let timing = ScanTiming { start_ns: 1_000, period_ns: 100_000_000, rotation: Rotation::Ccw, start_bearing_rad: 0.0 };
//! let rays = vec![Ray::new(std::f64::consts::FRAC_PI_2, 2.0, 100.0, true)];
//! let scan = Scan::from_uniform(timing, rays);
//! // a quarter turn after the start
//! assert_eq!(scan.rays()[0].t_ns, 1_000 + 25_000_000);
//! ```

use std::f64::consts::{PI, TAU};
use vlsync_common::Nanos;

/// Direction in which the beam sweeps, seen from above.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Rotation {
    /// Counter-clockwise: bearings increase with time.
    #[default]
    Ccw,
    /// Clockwise: bearings decrease with time (LD06/LD19, RPLIDAR).
    Cw,
}

impl Rotation {
    /// Lowercase name, as used in CSV files.
    pub fn name(self) -> &'static str {
        match self {
            Rotation::Ccw => "ccw",
            Rotation::Cw => "cw",
        }
    }

    /// Parses `"cw"` / `"ccw"` (case-insensitive).
    pub fn from_name(s: &str) -> Option<Self> {
        if s.eq_ignore_ascii_case("ccw") {
            Some(Rotation::Ccw)
        } else if s.eq_ignore_ascii_case("cw") {
            Some(Rotation::Cw)
        } else {
            None
        }
    }
}

/// One range measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Bearing, radians, CCW positive, in `(-π, π]` (see module docs).
    pub bearing_rad: f64,
    /// Range, metres. 0, NaN or infinite means "no return".
    pub range_m: f64,
    /// Intensity or quality as reported by the device (device units).
    pub intensity: f32,
    /// Device-side validity flag (e.g. RPLIDAR quality > 0).
    pub valid: bool,
    /// Measurement time of this ray, ns, on the scan's clock.
    pub t_ns: Nanos,
}

impl Ray {
    /// A ray whose time is filled in later (by [`Scan::from_uniform`]).
    pub fn new(bearing_rad: f64, range_m: f64, intensity: f32, valid: bool) -> Self {
        Self {
            bearing_rad: wrap_pi(bearing_rad),
            range_m,
            intensity,
            valid,
            t_ns: 0,
        }
    }

    /// A ray with its own measurement time.
    pub fn timed(bearing_rad: f64, range_m: f64, intensity: f32, valid: bool, t_ns: Nanos) -> Self {
        Self {
            t_ns,
            ..Self::new(bearing_rad, range_m, intensity, valid)
        }
    }

    /// Bearing in degrees, CCW positive, in `(-180, 180]`.
    pub fn bearing_deg(&self) -> f64 {
        self.bearing_rad.to_degrees()
    }
}

/// How a scan was timed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanTiming {
    /// Time of the first ray of the scan, ns (sensor or host clock as given).
    pub start_ns: Nanos,
    /// Rotation period, ns (0 when unknown).
    pub period_ns: Nanos,
    /// Sweep direction.
    pub rotation: Rotation,
    /// Bearing of the beam at `start_ns`, radians.
    pub start_bearing_rad: f64,
}

impl ScanTiming {
    /// Time at which the beam points at `bearing_rad` during this revolution:
    /// `start + Δθ / 2π · period`, `Δθ ∈ [0, 2π)` swept in the rotation direction.
    pub fn time_at_bearing(&self, bearing_rad: f64) -> Nanos {
        let swept = match self.rotation {
            Rotation::Ccw => bearing_rad - self.start_bearing_rad,
            Rotation::Cw => self.start_bearing_rad - bearing_rad,
        };
        let frac = wrap_tau(swept) / TAU;
        let dt = (frac * self.period_ns as f64).round();
        if dt.is_finite() {
            self.start_ns.saturating_add(dt as i64)
        } else {
            self.start_ns
        }
    }
}

/// One revolution (or part of one) of a scanning range finder.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    timing: ScanTiming,
    rays: Vec<Ray>,
}

impl Scan {
    /// A scan whose rays already carry their own times (exact per-point times).
    /// Rays are sorted by time (stable).
    pub fn from_timed(timing: ScanTiming, mut rays: Vec<Ray>) -> Self {
        rays.sort_by_key(|r| r.t_ns);
        Self { timing, rays }
    }

    /// A scan whose ray times are derived from their bearings with
    /// [`ScanTiming::time_at_bearing`] (any `t_ns` in `rays` is overwritten).
    pub fn from_uniform(timing: ScanTiming, mut rays: Vec<Ray>) -> Self {
        for r in &mut rays {
            r.t_ns = timing.time_at_bearing(r.bearing_rad);
        }
        Self::from_timed(timing, rays)
    }

    /// An empty scan with room for `capacity` rays (for parsers reusing buffers).
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            timing: ScanTiming {
                start_ns: 0,
                period_ns: 0,
                rotation: Rotation::Ccw,
                start_bearing_rad: 0.0,
            },
            rays: Vec::with_capacity(capacity),
        }
    }

    /// Timing of the scan.
    pub fn timing(&self) -> &ScanTiming {
        &self.timing
    }

    /// Rays, in time order.
    pub fn rays(&self) -> &[Ray] {
        &self.rays
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.rays.len()
    }

    /// True when the scan has no rays.
    pub fn is_empty(&self) -> bool {
        self.rays.is_empty()
    }

    /// Consumes the scan, returning its rays.
    pub fn into_rays(self) -> Vec<Ray> {
        self.rays
    }

    pub(crate) fn clear(&mut self) {
        self.rays.clear();
    }

    /// Appends a ray; keeps time order (a late ray is inserted in place).
    pub(crate) fn push(&mut self, ray: Ray) {
        match self.rays.last() {
            Some(last) if last.t_ns > ray.t_ns => {
                let pos = self.rays.partition_point(|r| r.t_ns <= ray.t_ns);
                self.rays.insert(pos, ray);
            }
            _ => self.rays.push(ray),
        }
    }

    pub(crate) fn set_timing(&mut self, timing: ScanTiming) {
        self.timing = timing;
    }
}

/// Wraps an angle into `(-π, π]`; non-finite input is returned unchanged.
pub fn wrap_pi(a: f64) -> f64 {
    if !a.is_finite() {
        return a;
    }
    let w = wrap_tau(a);
    if w > PI {
        w - TAU
    } else {
        w
    }
}

/// Wraps an angle into `[0, 2π)`; non-finite input is returned unchanged.
pub fn wrap_tau(a: f64) -> f64 {
    if !a.is_finite() {
        return a;
    }
    let w = a.rem_euclid(TAU);
    // rem_euclid can return TAU itself for tiny negative inputs
    if w >= TAU {
        0.0
    } else {
        w
    }
}

/// Converts a device angle in degrees measured **clockwise** (LD06, RPLIDAR)
/// into a CCW-positive bearing in `(-π, π]`.
pub fn cw_degrees_to_bearing(deg: f64) -> f64 {
    wrap_pi(-deg.to_radians())
}

/// Inverse of [`cw_degrees_to_bearing`]: clockwise degrees in `[0, 360)`.
pub fn bearing_to_cw_degrees(bearing_rad: f64) -> f64 {
    let d = (-bearing_rad).to_degrees().rem_euclid(360.0);
    if d >= 360.0 {
        0.0
    } else {
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn timing(rotation: Rotation) -> ScanTiming {
        ScanTiming {
            start_ns: 10_000,
            period_ns: 100_000_000,
            rotation,
            start_bearing_rad: 0.0,
        }
    }

    #[test]
    fn ccw_time_grows_with_bearing() {
        let t = timing(Rotation::Ccw);
        assert_eq!(t.time_at_bearing(0.0), 10_000);
        assert_eq!(t.time_at_bearing(PI / 2.0), 10_000 + 25_000_000);
        assert_eq!(t.time_at_bearing(-PI / 2.0), 10_000 + 75_000_000);
    }

    #[test]
    fn cw_time_grows_as_bearing_falls() {
        let t = timing(Rotation::Cw);
        assert_eq!(t.time_at_bearing(-PI / 2.0), 10_000 + 25_000_000);
        assert_eq!(t.time_at_bearing(PI / 2.0), 10_000 + 75_000_000);
    }

    #[test]
    fn start_bearing_offsets_the_sweep() {
        let mut t = timing(Rotation::Ccw);
        t.start_bearing_rad = PI / 2.0;
        assert_eq!(t.time_at_bearing(PI), 10_000 + 25_000_000);
        assert_eq!(t.time_at_bearing(0.0), 10_000 + 75_000_000);
    }

    #[test]
    fn rays_are_time_ordered() {
        let rays = vec![
            Ray::new(-PI / 2.0, 1.0, 0.0, true),
            Ray::new(PI / 2.0, 1.0, 0.0, true),
        ];
        let s = Scan::from_uniform(timing(Rotation::Ccw), rays);
        assert!(s.rays()[0].t_ns < s.rays()[1].t_ns);
        assert!((s.rays()[0].bearing_rad - PI / 2.0).abs() < 1e-12);
    }

    #[test]
    fn push_keeps_order() {
        let mut s = Scan::with_capacity(4);
        s.push(Ray::timed(0.0, 1.0, 0.0, true, 5));
        s.push(Ray::timed(0.0, 1.0, 0.0, true, 9));
        s.push(Ray::timed(0.0, 1.0, 0.0, true, 7));
        let t: Vec<_> = s.rays().iter().map(|r| r.t_ns).collect();
        assert_eq!(t, vec![5, 7, 9]);
    }

    #[test]
    fn a_ray_is_32_bytes() {
        // the LD06 and RPLIDAR parsers reserve room for `max_scan_rays` of them when
        // made, so no scan grows after start-up: 256 KiB a buffer at the default 8192
        assert_eq!(std::mem::size_of::<Ray>(), 32);
    }

    #[test]
    fn device_degrees_convert_both_ways() {
        assert!((cw_degrees_to_bearing(90.0) + PI / 2.0).abs() < 1e-12);
        assert!((cw_degrees_to_bearing(270.0) - PI / 2.0).abs() < 1e-12);
        assert!((bearing_to_cw_degrees(PI / 2.0) - 270.0).abs() < 1e-9);
        assert!(wrap_pi(f64::NAN).is_nan());
    }

    proptest! {
        #[test]
        fn wrap_pi_in_range(a in -1e6f64..1e6) {
            let w = wrap_pi(a);
            prop_assert!(w > -PI - 1e-12 && w <= PI + 1e-12);
            prop_assert!(((a - w) / TAU - ((a - w) / TAU).round()).abs() < 1e-6);
        }

        #[test]
        fn time_within_one_period(b in -10.0f64..10.0, cw in any::<bool>()) {
            let t = timing(if cw { Rotation::Cw } else { Rotation::Ccw });
            let at = t.time_at_bearing(b);
            prop_assert!(at >= t.start_ns && at <= t.start_ns + t.period_ns);
        }

        #[test]
        fn degrees_roundtrip(d in 0.0f64..359.999) {
            let back = bearing_to_cw_degrees(cw_degrees_to_bearing(d));
            prop_assert!((back - d).abs() < 1e-9);
        }
    }
}
