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

/// Most samples one scan can give per window (a window crossed twice in a scan
/// whose rays wrap around its start); more are counted as out of order.
const PER_SCAN: usize = 8;

/// The window of a configuration and the one opposite it, merged into one stream.
#[derive(Debug, Clone)]
pub struct OppositeWindows {
    ahead: SignatureProcessor,
    behind: SignatureProcessor,
    last_t: Option<Nanos>,
    out_of_order: u64,
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
        })
    }

    /// Feeds `scan` to both windows; `emit` gets their samples (the one behind
    /// negated) in increasing time, each after the last one emitted (a sample that
    /// is not is dropped and counted). Returns the number emitted.
    pub fn push_scan(&mut self, scan: &Scan, mut emit: impl FnMut(Sample)) -> usize {
        let mut buf = [Sample::new(0, 0.0); 2 * PER_SCAN];
        let mut n = 0;
        let mut over = 0u64;
        let mut keep = |s: Sample| {
            if n < buf.len() {
                buf[n] = s;
                n += 1;
            } else {
                over += 1;
            }
        };
        self.ahead.push_scan(scan, &mut keep);
        self.behind
            .push_scan(scan, |s| keep(Sample::new(s.t_ns, -s.value)));
        self.out_of_order += over;
        buf[..n].sort_unstable_by_key(|s| s.t_ns);
        let mut emitted = 0;
        for s in &buf[..n] {
            if self.last_t.is_some_and(|l| s.t_ns <= l) {
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
