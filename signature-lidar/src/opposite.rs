//! Two walls, one ahead and one behind: a second bearing window opposite the
//! first (centre + 180°), whose distance rate, negated (that wall recedes as the
//! one ahead approaches), joins the same stream in time order. Where a wall faces
//! each way (a corridor, a room driven lengthwise) this doubles the independent
//! returns per revolution and about halves the signature's noise variance; where
//! nothing is behind, that window's passes are dropped as usual and the stream is
//! the window ahead alone.
//!
//! ```
//! use vlsync_signature_lidar::{OppositeWindows, Ray, Rotation, Scan, ScanTiming, SignatureConfig};
//!
//! // a corridor along the x axis, 2 m ahead and 3 m behind at the start, driven
//! // forward at 0.5 m/s; 360 rays counter-clockwise from the front, 10 Hz
//! let scan = |k: i64| {
//!     let x = 0.05 * k as f64;
//!     let rays = (0..360).map(|i| {
//!         let b = (i as f64).to_radians();
//!         let c = b.cos();
//!         let r = if c > 0.3 { (2.0 - x) / c } else if c < -0.3 { -(3.0 + x) / c } else { 0.0 };
//!         Ray::new(b, r, 50.0, r > 0.0)
//!     }).collect();
//!     let timing = ScanTiming { start_ns: k * 100_000_000, period_ns: 100_000_000,
//!                               rotation: Rotation::Ccw, start_bearing_rad: 0.0 };
//!     Scan::from_uniform(timing, rays)
//! };
//! let mut w = OppositeWindows::new(SignatureConfig::default()).unwrap();
//! let mut out = Vec::new();
//! for k in 0..20 {
//!     w.push_scan(&scan(k), |s| out.push(s));
//! }
//! // both walls say the robot approaches the one ahead at 0.5 m/s, in time order
//! assert!(out.len() >= 30);
//! assert!(out.iter().all(|s| (s.value + 0.5).abs() < 0.01));
//! assert!(out.windows(2).all(|p| p[0].t_ns < p[1].t_ns));
//! ```

use crate::scan::{wrap_pi, Scan};
use crate::signature::{ConfigError, SignatureConfig, SignatureProcessor};
use std::f64::consts::PI;
use vlsync_common::{Nanos, Sample};

/// Samples one scan gives per window, at most, in a scan of one revolution (a window
/// crossed twice when its rays wrap around its start); the merge buffer starts with
/// room for both windows' and grows for a scan of several revolutions (a scan CSV may
/// give one scan every ray of a recording), so no sample is lost to its size.
const PER_SCAN: usize = 8;

/// The window of a configuration and the one opposite it, merged into one stream.
#[derive(Debug, Clone)]
pub struct OppositeWindows {
    ahead: SignatureProcessor,
    behind: SignatureProcessor,
    last_t: Option<Nanos>,
    out_of_order: u64,
    /// One scan's samples of both windows, sorted before they are emitted (reused:
    /// no allocation per scan once it holds a scan's worth).
    buf: Vec<Sample>,
}

impl OppositeWindows {
    /// The window of `cfg` and its opposite (same settings, centre + 180°).
    pub fn new(cfg: SignatureConfig) -> Result<Self, ConfigError> {
        let behind = SignatureConfig {
            window_centre_rad: wrap_pi(cfg.window_centre_rad + PI),
            ..cfg
        };
        Ok(Self {
            ahead: SignatureProcessor::new(cfg)?,
            behind: SignatureProcessor::new(behind)?,
            last_t: None,
            out_of_order: 0,
            buf: Vec::with_capacity(2 * PER_SCAN),
        })
    }

    /// Feeds `scan` to both windows; `emit` gets their samples (the one behind
    /// negated) in increasing time, each after the last one emitted (a sample that
    /// is not is dropped and counted, unless the clock stepped back by more than
    /// `max_gap_ns`: the stream then restarts, as each window does). Returns the
    /// number emitted.
    pub fn push_scan(&mut self, scan: &Scan, mut emit: impl FnMut(Sample)) -> usize {
        let buf = &mut self.buf;
        buf.clear();
        self.ahead.push_scan(scan, |s| buf.push(s));
        self.behind
            .push_scan(scan, |s| buf.push(Sample::new(s.t_ns, -s.value)));
        buf.sort_unstable_by_key(|s| s.t_ns);
        let mut emitted = 0;
        let max_gap = self.ahead.config().max_gap_ns;
        for s in buf.iter() {
            if !admits(self.last_t, s.t_ns, max_gap) {
                self.out_of_order += 1;
                continue;
            }
            self.last_t = Some(s.t_ns);
            emit(*s);
            emitted += 1;
        }
        emitted
    }

    /// The window ahead.
    pub fn ahead(&self) -> &SignatureProcessor {
        &self.ahead
    }

    /// The window behind.
    pub fn behind(&self) -> &SignatureProcessor {
        &self.behind
    }

    /// Samples dropped because they were not after the last one emitted.
    pub fn out_of_order(&self) -> u64 {
        self.out_of_order
    }
}

/// Whether the merged stream takes a sample at `t` after the last one emitted at
/// `last`: one after it, or one before it by more than `max_gap` (the clock stepped
/// back, a restarted sensor or concatenated recordings: both windows restarted on it,
/// and so does the merge, instead of dropping everything until time passes the old
/// stamps). A sample at or just before `last` is out of order.
fn admits(last: Option<Nanos>, t: Nanos, max_gap: Nanos) -> bool {
    last.is_none_or(|l| t > l || l.saturating_sub(t) > max_gap)
}

/// The wall front-end a LiDAR driver runs: the window of a configuration alone, or
/// with the one opposite it ([`OppositeWindows`], `lidar.opposite_window`).
#[derive(Debug, Clone)]
pub enum WallFront {
    /// The window alone.
    One(Box<SignatureProcessor>),
    /// The window and the one opposite it.
    Two(Box<OppositeWindows>),
}

impl WallFront {
    /// The window of `cfg`, and with `opposite` the one opposite it too.
    pub fn new(cfg: SignatureConfig, opposite: bool) -> Result<Self, ConfigError> {
        Ok(if opposite {
            Self::Two(Box::new(OppositeWindows::new(cfg)?))
        } else {
            Self::One(Box::new(SignatureProcessor::new(cfg)?))
        })
    }

    /// Feeds `scan`; `emit` gets the samples in increasing time. Returns their number.
    pub fn push_scan(&mut self, scan: &Scan, emit: impl FnMut(Sample)) -> usize {
        match self {
            Self::One(p) => p.push_scan(scan, emit),
            Self::Two(w) => w.push_scan(scan, emit),
        }
    }

    /// The window ahead (the configuration's own).
    pub fn ahead(&self) -> &SignatureProcessor {
        match self {
            Self::One(p) => p,
            Self::Two(w) => w.ahead(),
        }
    }

    /// Both windows, when the opposite one runs too.
    pub fn opposite(&self) -> Option<&OppositeWindows> {
        match self {
            Self::One(_) => None,
            Self::Two(w) => Some(w),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::{Ray, Rotation, ScanTiming};

    /// A scan of a corridor (2 m ahead, 3 m behind at `x = 0`) at position `x`, from
    /// `start_ns`: 360 rays counter-clockwise from the front, 10 Hz.
    fn corridor(x: f64, start_ns: Nanos) -> Scan {
        let rays = (0..360)
            .map(|i| {
                let c = (i as f64).to_radians().cos();
                let r = if c > 0.3 {
                    (2.0 - x) / c
                } else if c < -0.3 {
                    -(3.0 + x) / c
                } else {
                    0.0
                };
                Ray::new((i as f64).to_radians(), r, 50.0, r > 0.0)
            })
            .collect();
        let timing = ScanTiming {
            start_ns,
            period_ns: 100_000_000,
            rotation: Rotation::Ccw,
            start_bearing_rad: 0.0,
        };
        Scan::from_uniform(timing, rays)
    }

    #[test]
    fn a_clock_step_back_restarts_the_merged_stream() {
        // scans at 1000 s, then the sensor restarts at 16 s (or the next recording of
        // a concatenation begins): the stream goes on from there
        let mut w = OppositeWindows::new(SignatureConfig::default()).unwrap();
        let mut out = Vec::new();
        for k in 0..10 {
            w.push_scan(
                &corridor(0.05 * k as f64, 1_000_000_000_000 + k * 100_000_000),
                |s| out.push(s),
            );
        }
        let before = out.len();
        assert!(before >= 10, "{before}");
        for k in 0..10 {
            w.push_scan(
                &corridor(0.05 * k as f64, 16_000_000_000 + k * 100_000_000),
                |s| out.push(s),
            );
        }
        let after = &out[before..];
        assert!(after.len() >= 10, "{} after the step", after.len());
        assert!(after
            .iter()
            .all(|s| s.t_ns < 20_000_000_000 && (s.value + 0.5).abs() < 0.01));
        assert!(after.windows(2).all(|p| p[0].t_ns < p[1].t_ns));
    }

    /// A scan CSV may give one scan all the rays of several revolutions (one
    /// `scan_start_s` for every row, each ray its own time): every pass of both
    /// windows is published, none is lost to a per-scan limit.
    #[test]
    fn a_scan_of_many_revolutions_gives_every_pass_of_both_windows() {
        let turns = 30;
        let mut rays = Vec::new();
        for k in 0..turns {
            let one = corridor(0.05 * k as f64, k * 100_000_000);
            rays.extend(one.rays().iter().copied());
        }
        let timing = *corridor(0.0, 0).timing();
        let scan = Scan::from_timed(timing, rays);
        let mut w = OppositeWindows::new(SignatureConfig::default()).unwrap();
        let mut out = Vec::new();
        let n = w.push_scan(&scan, |s| out.push(s));
        // the same revolutions as one scan each
        let mut each = OppositeWindows::new(SignatureConfig::default()).unwrap();
        let mut want = Vec::new();
        for k in 0..turns {
            each.push_scan(&corridor(0.05 * k as f64, k * 100_000_000), |s| {
                want.push(s)
            });
        }
        assert!(want.len() > 2 * 2 * PER_SCAN, "{} samples", want.len());
        assert_eq!(n, out.len());
        assert_eq!(w.out_of_order(), 0);
        assert_eq!(out.len(), want.len());
        assert!(out.iter().all(|s| (s.value + 0.5).abs() < 0.01));
        assert!(out.windows(2).all(|p| p[0].t_ns < p[1].t_ns));
    }

    #[test]
    fn the_merge_drops_a_sample_at_or_just_before_the_last_and_restarts_after_a_clock_step() {
        let gap = 500_000_000;
        let last = Some(10_000_000_000);
        assert!(admits(None, 5, gap));
        assert!(admits(last, 10_000_000_001, gap));
        // out of order: the same stamp, or one earlier within the gap limit
        assert!(!admits(last, 10_000_000_000, gap));
        assert!(!admits(last, 9_500_000_000, gap));
        // the clock stepped back: a restart
        assert!(admits(last, 9_499_999_999, gap));
        assert!(admits(last, i64::MIN, gap));
    }
}
