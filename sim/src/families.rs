//! Deterministic simulator of camera/LiDAR signature streams with known truth.
//!
//! # Model
//!
//! The true event time `tau` is the LiDAR clock. A LiDAR scan happens at `tau` and is
//! stamped `t_L = tau + jitter_L`; a camera frame happens at `tau` and is stamped
//! `t_C = tau - offset(tau) + jitter_C`. So, jitter aside, `offset(t_L) = t_L - t_C`
//! exactly as in `vlsync_common`. Each sample's value is the noiseless signature of its
//! stream at `tau`, plus white Gaussian noise.
//!
//! Both sensors start stamping at 0 on their own clock and stop at the run duration on
//! their own clock (so with a positive offset the first camera frames see events a bit
//! after LiDAR time 0). The camera frames are regular on the camera's own (drifting)
//! clock; offset *steps* (software latency changes) move the stamps, not the frames.
//!
//! # Robot profile
//!
//! A ground robot drives forward toward a wall: a speed profile `v(t) >= 0` made of
//! raised-cosine ramps (peak acceleration 0.3-0.45 m/s²), cruises at 0.2-0.6 m/s with
//! 4 % RMS of floor/controller ripple (0.2-1.5 Hz), stops of 1-4 s and turns
//! (slow down to 0.05-0.15 m/s, yaw-rate bump of 0.4-1.0 rad/s for 1-3 s). It never
//! reverses, so the polarity is negative throughout:
//!
//! * LiDAR signature: wall-distance derivative `-v(t)` in m/s, noise 0.0045 m/s (1σ,
//!   [`LIDAR_NOISE`]);
//! * camera signature: forward optical-flow magnitude `150·(|v| + 0.1·|ω|)` in px/s
//!   (a turn leaks a little rotational flow into the camera only), noise 0.4 px/s
//!   ([`CAM_NOISE`]), i.e. 0.0027 m/s-equivalent: the LiDAR's is the larger one.
//!
//! Noise levels do not depend on the sample rates. The robot first moves 1-3 s after
//! the start ([`SimRun::motion_start_ns`]), or after the standstill when a short
//! `standstill` run's rest begins before that.
//!
//! # Families
//!
//! | family | rates cam/LiDAR | offset at t=0 | clocks | other |
//! |---|---|---|---|---|
//! | `seed` | 30/10 Hz | 0.18 s + 0.012 s/s (camera clock) | exact | article signal, 12 s, noise 0.06, positive polarity |
//! | `robot` | 30/10 | U[-0.15, 0.30] s | exact | |
//! | `clocks` | 30/10 | U[-0.3, 0.3] s, ±20-60 ppm | jitter 1 ms cam, 3 ms LiDAR | 5 % drops each, one 1.2-2 s LiDAR gap at 30-70 % of the run |
//! | `load-steps` | 30/10 | U[0, 0.2] s | exact | ±25 ms steps every U[15, 25] s, cumulative within ±50 ms |
//! | `standstill` | 30/10 | U[-0.1, 0.2] s | exact | 30 s rest centred in the run (min(30 s, duration/3)); under [`MIN_STANDSTILL_S`] (runs under 15 s) not reported as a standstill unless it joins the initial rest |
//! | `rates-60x5` | 60/5.5 | U[0, 0.3] s | exact | |
//! | `rates-15x20` | 15/20 | U[0, 0.3] s | exact | |
//! | `big-offset` | 30/10 | 0.45 s | exact | |
//! | `negative-offset` | 30/10 | U[-0.25, -0.15] s | exact | |
//! | `heavy-noise` | 30/10 | U[-0.2, 0.2] s | exact | noise [`HEAVY_NOISE_FACTOR`] (3) times the robot families' on each stream |
//! | `load-jitter` | 30/10 | U[0, 0.2] s, ±20-60 ppm | as `clocks` | `load-steps`' steps, each spread over 0.3 s (a frame takes the new latency with a probability rising from 0 to 1) |
//!
//! For `seed` the camera samples on its own grid `k/30` and sees the event at
//! `t_C + 0.18 + 0.012 t_C`, as in the article; in our convention that is
//! `offset(t_L) = (0.18 + 0.012 t_L) / 1.012`. The article's 1-sample Gaussian smoothing
//! is applied as a continuous 7-tap filter with taps one sample period apart (its
//! zero-padded edges are not reproduced).
//!
//! # Determinism
//!
//! Everything is drawn from a ChaCha8 generator seeded from `(family, seed)`; the same
//! arguments give bit-identical runs.
//!
//! ```
//! use vlsync_sim::families::{generate, Family};
//! let run = generate(Family::Robot, 3, Some(30.0));
//! assert!(run.cam.len() > 800 && run.lidar.len() > 280);
//! // the truth convention: offset(t_L) = t_L - t_C for every camera frame (no jitter here)
//! for (s, c) in run.cam.iter().zip(&run.cam_clean) {
//!     let t_l = c.tau_ns;
//!     assert!((run.truth.offset_at(t_l) - (t_l - s.t_ns) as f64 * 1e-9).abs() < 2e-9);
//! }
//! assert_eq!(generate(Family::Robot, 3, Some(30.0)).cam, run.cam);
//! ```

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;
use vlsync_common::{nanos_to_secs, secs_to_nanos, Nanos, Polarity, Sample, Stream};

/// Shortest run accepted, seconds.
pub const MIN_DURATION_S: f64 = 2.0;
/// Longest run accepted, seconds.
pub const MAX_DURATION_S: f64 = 3600.0;
/// Largest noise scale accepted ([`try_generate_with`]): 1000 times a family's noise
/// buries any signature (the `heavy-noise` family has 3), while far larger scales
/// overflow the bounds to infinity and the values towards it.
pub const MAX_NOISE_SCALE: f64 = 1000.0;
/// A rest at least this long (seconds) is reported in [`SimRun::standstills`].
pub const MIN_STANDSTILL_S: f64 = 5.0;
/// Camera flow gain, px/s per m/s.
pub const FLOW_GAIN: f64 = 150.0;
/// Rotational flow leaking into the camera signature, m/s-equivalent per rad/s.
pub const ROT_LEAK: f64 = 0.1;
/// Camera signature noise (1σ) of the robot families, px/s: about 0.013 px/frame of
/// mean-flow noise at 30 Hz (a grid of ~100 tracked points), i.e. 0.0027 m/s-equivalent.
///
/// The robot families' noise levels are calibrated to the reference regime of
/// `shared/reference/NOTES.md`: a Cramér-Rao bound of about 4-5 ms for a 4 s window
/// (and under 1 ms for a 120 s run), the same as the seed article's own data.
pub const CAM_NOISE: f64 = 0.4;
/// LiDAR signature noise (1σ) of the robot families, m/s: a wall-patch median range with
/// about 0.32 mm of noise per scan, differenced at 10 Hz (√2 · 0.32 mm · 10 Hz).
pub const LIDAR_NOISE: f64 = 0.0045;
/// Noise multiplier of the `heavy-noise` family over the robot families.
pub const HEAVY_NOISE_FACTOR: f64 = 3.0;

/// A simulated scenario.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Family {
    /// The seed article's generator, conventions fixed: 12 s, 30/10 Hz, offset 0.18 s + 0.012 s/s.
    Seed,
    /// Robot profile, constant offset, clean clocks.
    Robot,
    /// Robot profile, 20-60 ppm drift, stamp jitter, 5 % drops, one LiDAR gap.
    Clocks,
    /// Robot profile with ±25 ms offset steps every 15-25 s.
    LoadSteps,
    /// Robot profile with one standstill in the middle: 30 s, a third of a run
    /// shorter than 90 s (see [`Family::description`]).
    Standstill,
    /// 60 Hz camera, 5.5 Hz LiDAR.
    Rates60x5,
    /// 15 Hz camera, 20 Hz LiDAR.
    Rates15x20,
    /// Offset 0.45 s.
    BigOffset,
    /// Offset around -0.2 s.
    NegativeOffset,
    /// Three times the robot families' noise.
    HeavyNoise,
    /// `load-steps` on `clocks`' timing: drift, jitter, drops, a LiDAR gap, and
    /// each step spread over 0.3 s.
    LoadJitter,
}

impl Family {
    /// Every family, in listing order.
    pub const ALL: [Family; 11] = [
        Family::Seed,
        Family::Robot,
        Family::Clocks,
        Family::LoadSteps,
        Family::Standstill,
        Family::Rates60x5,
        Family::Rates15x20,
        Family::BigOffset,
        Family::NegativeOffset,
        Family::HeavyNoise,
        Family::LoadJitter,
    ];

    /// Kebab-case name, as accepted by [`FromStr`].
    pub fn name(self) -> &'static str {
        match self {
            Family::Seed => "seed",
            Family::Robot => "robot",
            Family::Clocks => "clocks",
            Family::LoadSteps => "load-steps",
            Family::Standstill => "standstill",
            Family::Rates60x5 => "rates-60x5",
            Family::Rates15x20 => "rates-15x20",
            Family::BigOffset => "big-offset",
            Family::NegativeOffset => "negative-offset",
            Family::HeavyNoise => "heavy-noise",
            Family::LoadJitter => "load-jitter",
        }
    }

    /// One-line description.
    pub fn description(self) -> &'static str {
        match self {
            Family::Seed => "seed article generator (osc+bursts, σ=1-sample smoothing), 30/10 Hz, 12 s, offset 0.18 s + 0.012 s/s, noise 0.06, positive polarity",
            Family::Robot => "robot drive (accelerations, cruise 0.2-0.6 m/s, 1-4 s stops, turns), 30/10 Hz, constant offset in [-0.15, 0.30] s, negative polarity",
            Family::Clocks => "robot; offset in [-0.3, 0.3] s + 20-60 ppm drift, jitter 1 ms cam / 3 ms LiDAR, 5 % dropped frames and scans, one 1.2-2 s LiDAR gap",
            Family::LoadSteps => "robot; offset in [0, 0.2] s with ±25 ms steps every 15-25 s",
            Family::Standstill => "robot with one standstill in the middle (signatures are pure noise there): 30 s, a third of a run under 90 s; in a run under 15 s that rest is under 5 s, a stop like the robot's, not reported as a standstill",
            Family::Rates60x5 => "robot; 60 Hz camera, 5.5 Hz LiDAR, offset in [0, 0.3] s",
            Family::Rates15x20 => "robot; 15 Hz camera, 20 Hz LiDAR, offset in [0, 0.3] s",
            Family::BigOffset => "robot; offset 0.45 s",
            Family::NegativeOffset => "robot; offset in [-0.25, -0.15] s",
            Family::HeavyNoise => "robot with three times the noise of the other robot families, offset in [-0.2, 0.2] s",
            Family::LoadJitter => "load-steps on clocks' timing: offset in [0, 0.2] s + 20-60 ppm, jitter 1 ms cam / 3 ms LiDAR, 5 % drops, a LiDAR gap; ±25 ms steps every 15-25 s, each spread over 0.3 s (frames at the old or new latency at random)",
        }
    }

    /// Default run duration, seconds (12 s for `Seed`, 120 s otherwise).
    pub fn default_duration_s(self) -> f64 {
        match self {
            Family::Seed => 12.0,
            _ => 120.0,
        }
    }

    /// How long a load step takes to reach every frame, seconds: within this after a
    /// step, a frame's stamp carries the old latency or the new one (0: at once).
    pub fn step_spread_s(self) -> f64 {
        params(self).step_spread_s
    }

    /// `(camera Hz, LiDAR Hz)`.
    pub fn rates_hz(self) -> (f64, f64) {
        match self {
            Family::Rates60x5 => (60.0, 5.5),
            Family::Rates15x20 => (15.0, 20.0),
            _ => (30.0, 10.0),
        }
    }

    fn index(self) -> u64 {
        Family::ALL.iter().position(|&f| f == self).unwrap_or(0) as u64
    }
}

impl fmt::Display for Family {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An unknown family name; its message lists the valid ones.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownFamily(pub String);

impl fmt::Display for UnknownFamily {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<&str> = Family::ALL.iter().map(|f| f.name()).collect();
        write!(
            f,
            "unknown family `{}`; valid families: {}",
            self.0,
            names.join(", ")
        )
    }
}

impl std::error::Error for UnknownFamily {}

impl FromStr for Family {
    type Err = UnknownFamily;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let key = s.trim().to_ascii_lowercase().replace('_', "-");
        Family::ALL
            .iter()
            .copied()
            .find(|f| f.name() == key)
            .ok_or_else(|| UnknownFamily(s.to_string()))
    }
}

/// Invalid simulation input.
#[derive(Debug, Clone, PartialEq)]
pub enum SimError {
    /// The requested duration is not a finite number within the allowed range.
    InvalidDuration {
        /// What was asked for.
        duration_s: f64,
    },
    /// The noise scale is not a finite number in `[0, MAX_NOISE_SCALE]`.
    InvalidNoiseScale {
        /// What was asked for.
        noise_scale: f64,
    },
    /// A window length is not a finite number between the minimum and the run length.
    InvalidWindow {
        /// What was asked for.
        window_s: f64,
        /// The run length.
        duration_s: f64,
    },
}

impl fmt::Display for SimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SimError::InvalidDuration { duration_s } => write!(
                f,
                "duration {} s is invalid: expected a finite number in [{MIN_DURATION_S}, {MAX_DURATION_S}] s",
                vlsync_common::text::number(*duration_s)
            ),
            SimError::InvalidNoiseScale { noise_scale } => write!(
                f,
                "noise scale {} is invalid: expected a finite number in [0, {MAX_NOISE_SCALE}]",
                vlsync_common::text::number(*noise_scale)
            ),
            SimError::InvalidWindow { window_s, duration_s } => write!(
                f,
                "window {} s is invalid: expected a finite number in [{}, {}] s (the run length)",
                vlsync_common::text::number(*window_s),
                vlsync_common::text::number(crate::crb::MIN_WINDOW_S),
                vlsync_common::text::number(*duration_s)
            ),
        }
    }
}

impl std::error::Error for SimError {}

/// The true offset `t_L - t_C` as a function of LiDAR time.
///
/// `offset(t) = offset0_s + drift * t + sum of the step deltas with step time <= t`
/// (t in seconds on the LiDAR clock).
///
/// ```
/// use vlsync_sim::families::Truth;
/// let tr = Truth { offset0_s: 0.1, drift: 1e-4, steps: vec![(5_000_000_000, 0.025)], end_ns: 10_000_000_000 };
/// assert!((tr.offset_at(0) - 0.1).abs() < 1e-12);
/// assert!((tr.offset_at(5_000_000_000) - (0.1 + 5e-4 + 0.025)).abs() < 1e-12);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// Offset at LiDAR time 0, seconds.
    pub offset0_s: f64,
    /// `d offset / d t_L` (dimensionless).
    pub drift: f64,
    /// Offset steps: `(LiDAR time ns, delta s)`, sorted by time.
    pub steps: Vec<(Nanos, f64)>,
    /// End of the run on the LiDAR clock, ns (the extent of the truth CSV).
    pub end_ns: Nanos,
}

impl Truth {
    /// True offset `t_L - t_C` (seconds) at LiDAR time `t_lidar_ns`.
    pub fn offset_at(&self, t_lidar_ns: Nanos) -> f64 {
        self.offset0_s + self.drift * nanos_to_secs(t_lidar_ns) + self.steps_at(t_lidar_ns)
    }

    /// Sum of the step deltas at or before `t_lidar_ns`, seconds.
    pub fn steps_at(&self, t_lidar_ns: Nanos) -> f64 {
        self.steps
            .iter()
            .take_while(|&&(t, _)| t <= t_lidar_ns)
            .map(|&(_, d)| d)
            .sum()
    }

    /// The truth as CSV `t,offset` (seconds, LiDAR clock) every 10 ms.
    pub fn to_csv_string(&self) -> String {
        crate::io::truth_csv_string(self, 10_000_000)
    }

    /// Writes [`Truth::to_csv_string`] to `path`.
    pub fn write_csv(&self, path: impl AsRef<std::path::Path>) -> Result<(), crate::io::CsvError> {
        crate::io::write_truth_csv(path, self)
    }
}

/// The noiseless signature behind one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CleanPoint {
    /// True event time (= LiDAR clock), ns.
    pub tau_ns: Nanos,
    /// Noiseless signature value at `tau`.
    pub value: f64,
    /// Derivative of the noiseless signature at `tau`, per second.
    pub slope: f64,
}

/// One simulated run with its truth.
#[derive(Debug, Clone, PartialEq)]
pub struct SimRun {
    /// The scenario.
    pub family: Family,
    /// The seed it was generated from.
    pub seed: u64,
    /// Camera signature samples (camera clock).
    pub cam: Vec<Sample>,
    /// LiDAR signature samples (LiDAR clock).
    pub lidar: Vec<Sample>,
    /// The true offset.
    pub truth: Truth,
    /// Cramér-Rao bound of a constant offset over the whole run, standard deviation in seconds
    /// (see [`crate::crb`]; for runs with drift or steps it is the bound of the mean offset).
    pub crb_std_s: f64,
    /// LiDAR time at which the robot first moves, ns.
    pub motion_start_ns: Nanos,
    /// LiDAR times of the offset steps, ns.
    pub step_times_ns: Vec<Nanos>,
    /// Rests of at least [`MIN_STANDSTILL_S`] (v = 0 and no turn), LiDAR clock, ns.
    /// The same rule for every family: a `standstill` run under 15 s, whose rest is a
    /// third of it, reports that rest only where it joins the initial rest (the robot
    /// family's 1-4 s stops are not reported either: a window spans them).
    pub standstills: Vec<(Nanos, Nanos)>,
    /// Intervals (LiDAR clock, ns) in which every LiDAR scan was removed.
    pub lidar_gaps: Vec<(Nanos, Nanos)>,
    /// Nominal camera rate, Hz.
    pub cam_hz: f64,
    /// Nominal LiDAR rate, Hz.
    pub lidar_hz: f64,
    /// Run duration, seconds.
    pub duration_s: f64,
    /// Camera noise standard deviation (signature units).
    pub noise_cam: f64,
    /// LiDAR noise standard deviation (signature units).
    pub noise_lidar: f64,
    /// Camera stamp jitter (1σ), seconds.
    pub jitter_cam_s: f64,
    /// LiDAR stamp jitter (1σ), seconds.
    pub jitter_lidar_s: f64,
    /// Camera frames removed by random drops.
    pub cam_dropped: usize,
    /// LiDAR scans removed by random drops (not counting the gap).
    pub lidar_dropped: usize,
    /// Relative sign of the two signatures.
    pub polarity: Polarity,
    /// Noiseless signature behind each camera sample (same order as `cam`).
    pub cam_clean: Vec<CleanPoint>,
    /// Noiseless signature behind each LiDAR sample (same order as `lidar`).
    pub lidar_clean: Vec<CleanPoint>,
}

impl SimRun {
    /// Both streams' samples in the order a live system would push them: by
    /// timestamp, the camera's first on a tie.
    ///
    /// ```
    /// use vlsync_common::Stream;
    /// use vlsync_sim::families::{generate, Family};
    /// let run = generate(Family::Robot, 1, Some(20.0));
    /// let p = run.pushes();
    /// assert_eq!(p.len(), run.cam.len() + run.lidar.len());
    /// assert!(p.windows(2).all(|w| w[0].1.t_ns <= w[1].1.t_ns));
    /// assert!(p.iter().any(|(s, _)| *s == Stream::Lidar));
    /// ```
    pub fn pushes(&self) -> Vec<(Stream, Sample)> {
        let mut all: Vec<(Stream, Sample)> = self
            .cam
            .iter()
            .map(|s| (Stream::Cam, *s))
            .chain(self.lidar.iter().map(|s| (Stream::Lidar, *s)))
            .collect();
        // stable: the camera's samples come first on equal stamps
        all.sort_by_key(|(_, s)| s.t_ns);
        all
    }
}

// ---------------------------------------------------------------------------
// motion models

/// The seed article's true signal: a 0.9 Hz oscillation plus three bursts.
fn seed_signal(t: f64) -> f64 {
    let osc = (2.0 * PI * 0.9 * t).sin() * 0.6;
    let b = (-((t - 2.2) / 0.25).powi(2)).exp() * 1.4
        + (-((t - 6.7) / 0.35).powi(2)).exp() * 1.0
        + (-((t - 8.6) / 0.18).powi(2)).exp() * 1.2;
    osc + b
}

/// Gaussian kernel of the seed (sigma 1 sample, radius 3), normalised.
fn seed_kernel() -> [f64; 7] {
    let mut k = [0.0; 7];
    for (i, w) in k.iter_mut().enumerate() {
        let t = i as f64 - 3.0;
        *w = (-(t * t) / 2.0).exp();
    }
    let s: f64 = k.iter().sum();
    k.map(|w| w / s)
}

/// A drive's speed and yaw-rate profile: raised-cosine speed segments, a
/// multiplicative floor/controller ripple while moving, and yaw-rate bumps.
///
/// The signature simulator's robot families plan one (position-unaware: speed
/// changes, stops and turns while rolling) and so does the rendering simulator
/// (`vlsync-render`: legs toward the front wall of a room, braking before it,
/// 180° turns on the spot); both evaluate it here.
///
/// ```
/// use vlsync_sim::families::{ramp_len, DriveProfile};
/// let mut d = DriveProfile::default();
/// let l = ramp_len(0.4, 0.0, 0.5); // 0 -> 0.5 m/s at a peak of 0.4 m/s²
/// d.push_segment(1.0, l, 0.0, 0.5);
/// d.push_segment(1.0 + l, 2.0, 0.5, 0.5);
/// d.push_turn(4.0, 2.0, 1.0);
/// assert_eq!(d.base_speed(0.5), 0.0);
/// assert!((d.base_speed(1.0 + l / 2.0) - 0.25).abs() < 1e-12);
/// assert_eq!(d.speed(2.0 + l), 0.5); // no ripple drawn
/// assert!((d.yaw_rate(5.0) - 1.0).abs() < 1e-12); // peak of the sin² bump
/// ```
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DriveProfile {
    segs: Vec<Seg>,
    ripple: Vec<(f64, f64, f64)>,
    turns: Vec<Turn>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Seg {
    t0: f64,
    t1: f64,
    v0: f64,
    v1: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Turn {
    t0: f64,
    t1: f64,
    peak: f64,
}

/// Length of a raised-cosine speed ramp from `v0` to `v1` whose peak
/// acceleration is `accel` (m/s²), at least 0.4 s.
pub fn ramp_len(accel: f64, v0: f64, v1: f64) -> f64 {
    (PI * (v1 - v0).abs() / (2.0 * accel)).max(0.4)
}

impl DriveProfile {
    /// Appends a speed segment from `t0` lasting `len` seconds, a raised-cosine
    /// ramp from `v0` to `v1` (a hold when they are equal). Segments must come in
    /// time order; before the first one the speed is 0, after the last one it
    /// stays at that segment's `v1`.
    pub fn push_segment(&mut self, t0: f64, len: f64, v0: f64, v1: f64) {
        self.segs.push(Seg {
            t0,
            t1: t0 + len,
            v0,
            v1,
        });
    }

    /// Appends a yaw-rate bump `peak · sin²(π (t - t0) / len)` (rad/s; it turns
    /// by `peak · len / 2` radians). Bumps must come in time order.
    pub fn push_turn(&mut self, t0: f64, len: f64, peak: f64) {
        self.turns.push(Turn {
            t0,
            t1: t0 + len,
            peak,
        });
    }

    /// Draws the multiplicative ripple: 5 sinusoids of 0.2-1.5 Hz (log-uniform),
    /// random phases, `rms` in total (e.g. 0.04 for 4 %), from `rng`.
    pub fn draw_ripple<R: Rng + ?Sized>(&mut self, rng: &mut R, rms: f64) {
        self.ripple = (0..5)
            .map(|_| {
                let f = 0.2 * (1.5f64 / 0.2).powf(rng.gen::<f64>());
                (
                    rms * (2.0f64 / 5.0).sqrt() * rng.gen_range(0.6..1.4),
                    f,
                    rng.gen_range(0.0..2.0 * PI),
                )
            })
            .collect();
    }

    /// The planned speed at `t` (no ripple), m/s.
    pub fn base_speed(&self, t: f64) -> f64 {
        let i = self.segs.partition_point(|s| s.t0 <= t);
        if i == 0 {
            return 0.0;
        }
        let s = self.segs[i - 1];
        if t >= s.t1 {
            return s.v1;
        }
        let x = (t - s.t0) / (s.t1 - s.t0);
        s.v0 + (s.v1 - s.v0) * 0.5 * (1.0 - (PI * x).cos())
    }

    /// The speed at `t` with the ripple (0 whenever the planned speed is 0), m/s.
    pub fn speed(&self, t: f64) -> f64 {
        let b = self.base_speed(t);
        if b == 0.0 {
            return 0.0;
        }
        let w: f64 = self
            .ripple
            .iter()
            .map(|&(a, f, p)| a * (2.0 * PI * f * t + p).sin())
            .sum();
        b * (1.0 + w)
    }

    /// The yaw rate at `t`, rad/s.
    pub fn yaw_rate(&self, t: f64) -> f64 {
        let i = self.turns.partition_point(|s| s.t0 <= t);
        if i == 0 {
            return 0.0;
        }
        let s = self.turns[i - 1];
        if t >= s.t1 {
            return 0.0;
        }
        let x = (t - s.t0) / (s.t1 - s.t0);
        s.peak * (PI * x).sin().powi(2)
    }
}

/// A robot drive of the signature simulator: the profile, when motion starts,
/// and the rests.
#[derive(Debug, Clone)]
struct RobotProfile {
    drive: DriveProfile,
    motion_start: f64,
    rests: Vec<(f64, f64)>,
}

impl RobotProfile {
    fn speed(&self, t: f64) -> f64 {
        self.drive.speed(t)
    }

    fn yaw_rate(&self, t: f64) -> f64 {
        self.drive.yaw_rate(t)
    }
}

/// Plans a drive over `[0, end]`; `forced` = (start, length) of a standstill to insert.
fn plan_robot(rng: &mut ChaCha8Rng, end: f64, forced: Option<(f64, f64)>) -> RobotProfile {
    let mut drive = DriveProfile::default();
    let mut rests = Vec::new();
    let mut t = 0.0;
    let mut v = 0.0;
    let initial_rest = rng.gen_range(1.0..3.0);
    rests.push((0.0, initial_rest));
    t += initial_rest;
    let ramp_len = |rng: &mut ChaCha8Rng, v0: f64, v1: f64| {
        let a = rng.gen_range(0.3..0.45);
        crate::families::ramp_len(a, v0, v1)
    };
    fn push(segs: &mut DriveProfile, t: &mut f64, v: &mut f64, v1: f64, len: f64) {
        segs.push_segment(*t, len, *v, v1);
        *t += len;
        *v = v1;
    }
    let mut forced = forced;
    while t < end {
        if let Some((fs, flen)) = forced {
            let decel = ramp_len(rng, v, 0.0);
            if t + 12.0 >= fs - decel {
                if v == 0.0 && fs - t >= 1.6 {
                    // at rest already: drive off slowly, then stop exactly at `fs`
                    let l = PI * 0.2 / (2.0 * 0.4);
                    push(&mut drive, &mut t, &mut v, 0.2, l);
                    let hold = fs - l - t;
                    push(&mut drive, &mut t, &mut v, 0.2, hold);
                    push(&mut drive, &mut t, &mut v, 0.0, l);
                } else if v > 0.0 && fs - decel > t {
                    let hold = fs - decel - t;
                    {
                        let cur = v;
                        push(&mut drive, &mut t, &mut v, cur, hold);
                    }
                }
                if v > 0.0 {
                    push(&mut drive, &mut t, &mut v, 0.0, decel);
                }
                rests.push((t, t + flen));
                push(&mut drive, &mut t, &mut v, 0.0, flen);
                forced = None;
                continue;
            }
        }
        if v == 0.0 {
            let v1 = rng.gen_range(0.2..0.6);
            let l = ramp_len(rng, 0.0, v1);
            push(&mut drive, &mut t, &mut v, v1, l);
            let hold = rng.gen_range(1.0..3.0);
            {
                let cur = v;
                push(&mut drive, &mut t, &mut v, cur, hold);
            }
            continue;
        }
        let u: f64 = rng.gen();
        if u < 0.45 {
            let v1 = rng.gen_range(0.2..0.6);
            let l = ramp_len(rng, v, v1);
            push(&mut drive, &mut t, &mut v, v1, l);
            let hold = rng.gen_range(1.5..5.0);
            {
                let cur = v;
                push(&mut drive, &mut t, &mut v, cur, hold);
            }
        } else if u < 0.7 {
            let l = ramp_len(rng, v, 0.0);
            push(&mut drive, &mut t, &mut v, 0.0, l);
            let rest = rng.gen_range(1.0..4.0);
            rests.push((t, t + rest));
            push(&mut drive, &mut t, &mut v, 0.0, rest);
        } else {
            let vt = rng.gen_range(0.05..0.15);
            let l = ramp_len(rng, v, vt);
            push(&mut drive, &mut t, &mut v, vt, l);
            let dur = rng.gen_range(1.0..3.0);
            drive.push_turn(t, dur, rng.gen_range(0.4..1.0));
            push(&mut drive, &mut t, &mut v, vt, dur);
            let v1 = rng.gen_range(0.2..0.6);
            let l = ramp_len(rng, vt, v1);
            push(&mut drive, &mut t, &mut v, v1, l);
        }
    }
    // ripple: 5 sinusoids, 0.2-1.5 Hz, about 4 % RMS in total
    drive.draw_ripple(rng, 0.04);
    // merge adjacent rests (e.g. initial rest + first zero segment never happens, but stops can chain)
    let mut merged: Vec<(f64, f64)> = Vec::new();
    for r in rests {
        match merged.last_mut() {
            Some(last) if (r.0 - last.1).abs() < 1e-9 => last.1 = r.1,
            _ => merged.push(r),
        }
    }
    // the robot first moves where the first segment with speed begins: after the
    // initial rest, or after the forced rest when that comes at once (a short run's
    // standstill centred before the initial rest ends); the end of the plan if it never
    // moves
    let motion_start = drive
        .segs
        .iter()
        .find(|s| s.v0 > 0.0 || s.v1 > 0.0)
        .map_or(t, |s| s.t0);
    RobotProfile {
        drive,
        motion_start,
        rests: merged,
    }
}

#[derive(Debug, Clone)]
enum Motion {
    Seed {
        cam_period: f64,
        lidar_period: f64,
        kernel: [f64; 7],
    },
    Robot(RobotProfile),
}

impl Motion {
    fn cam(&self, tau: f64) -> f64 {
        match self {
            Motion::Seed {
                cam_period, kernel, ..
            } => smoothed(kernel, *cam_period, tau),
            Motion::Robot(p) => FLOW_GAIN * (p.speed(tau).abs() + ROT_LEAK * p.yaw_rate(tau).abs()),
        }
    }

    fn lidar(&self, tau: f64) -> f64 {
        match self {
            Motion::Seed {
                lidar_period,
                kernel,
                ..
            } => smoothed(kernel, *lidar_period, tau),
            Motion::Robot(p) => -p.speed(tau),
        }
    }
}

/// The seed's per-sample Gaussian smoothing as a continuous FIR: taps one sample period apart.
fn smoothed(kernel: &[f64; 7], period: f64, tau: f64) -> f64 {
    kernel
        .iter()
        .enumerate()
        .map(|(i, w)| w * seed_signal(tau + (i as f64 - 3.0) * period))
        .sum()
}

/// Tick `k` of a regular `hz` clock starting at `phase_ns` (the same arithmetic as the
/// baseline's grid, so that equal instants compare equal).
fn tick_ns(phase_ns: Nanos, k: u64, hz: f64) -> Nanos {
    phase_ns + (k as f64 * (1e9 / hz)).round() as Nanos
}

fn slope(f: impl Fn(f64) -> f64, tau: f64) -> f64 {
    let h = 1e-4;
    (f(tau + h) - f(tau - h)) / (2.0 * h)
}

// ---------------------------------------------------------------------------
// families

struct Params {
    cam_hz: f64,
    lidar_hz: f64,
    offset_range: (f64, f64),
    drift_ppm: Option<(f64, f64)>,
    steps: bool,
    jitter: (f64, f64),
    drop_p: f64,
    lidar_gap: bool,
    standstill_s: Option<f64>,
    heavy_noise: bool,
    /// A step's latency reaches the frames over this long: within it, each frame
    /// carries the new latency with a probability rising linearly from 0 to 1.
    step_spread_s: f64,
}

impl Family {
    /// The drift's root mean square over the family's runs (s/s): the prior an estimator
    /// made for this family alone would hold ([`crate::crb::causal_std_s`]). 0 for the
    /// families without drift and for `seed`, whose drift is always the same 12 ms/s.
    ///
    /// ```
    /// use vlsync_sim::families::Family;
    /// // 20-60 ppm of either sign: sqrt((60³ - 20³) / (3 · 40)) ≈ 41.6 ppm
    /// assert!((Family::Clocks.drift_rms() * 1e6 - 41.63).abs() < 0.01);
    /// assert_eq!(Family::Robot.drift_rms(), 0.0);
    /// ```
    pub fn drift_rms(self) -> f64 {
        match params(self).drift_ppm {
            Some((a, b)) if b > a => ((b.powi(3) - a.powi(3)) / (3.0 * (b - a))).sqrt() * 1e-6,
            Some((a, _)) => a * 1e-6,
            None => 0.0,
        }
    }
}

fn params(f: Family) -> Params {
    let (cam_hz, lidar_hz) = f.rates_hz();
    let mut p = Params {
        cam_hz,
        lidar_hz,
        offset_range: (-0.15, 0.30),
        drift_ppm: None,
        steps: false,
        jitter: (0.0, 0.0),
        drop_p: 0.0,
        lidar_gap: false,
        standstill_s: None,
        heavy_noise: false,
        step_spread_s: 0.0,
    };
    match f {
        Family::Seed | Family::Robot => {}
        Family::Clocks => {
            p.offset_range = (-0.3, 0.3);
            p.drift_ppm = Some((20.0, 60.0));
            p.jitter = (0.001, 0.003);
            p.drop_p = 0.05;
            p.lidar_gap = true;
        }
        Family::LoadSteps => {
            p.offset_range = (0.0, 0.2);
            p.steps = true;
        }
        Family::Standstill => {
            p.offset_range = (-0.1, 0.2);
            p.standstill_s = Some(30.0);
        }
        Family::Rates60x5 | Family::Rates15x20 => p.offset_range = (0.0, 0.3),
        Family::BigOffset => p.offset_range = (0.45, 0.45),
        Family::NegativeOffset => p.offset_range = (-0.25, -0.15),
        Family::HeavyNoise => {
            p.offset_range = (-0.2, 0.2);
            p.heavy_noise = true;
        }
        Family::LoadJitter => {
            p.offset_range = (0.0, 0.2);
            p.drift_ppm = Some((20.0, 60.0));
            p.jitter = (0.001, 0.003);
            p.drop_p = 0.05;
            p.lidar_gap = true;
            p.steps = true;
            p.step_spread_s = 0.3;
        }
    }
    p
}

/// Generates a run. `duration_s = None` uses [`Family::default_duration_s`]; a duration
/// outside `[MIN_DURATION_S, MAX_DURATION_S]` is clamped into it and a non-finite one is
/// replaced by the default (use [`try_generate`] to get an error instead).
pub fn generate(family: Family, seed: u64, duration_s: Option<f64>) -> SimRun {
    let d = match duration_s {
        Some(d) if d.is_finite() => d.clamp(MIN_DURATION_S, MAX_DURATION_S),
        _ => family.default_duration_s(),
    };
    build(family, seed, d, 1.0)
}

/// Like [`generate`], but an invalid duration is an error.
///
/// ```
/// use vlsync_sim::families::{try_generate, Family};
/// assert!(try_generate(Family::Seed, 1, Some(-3.0)).unwrap_err().to_string().contains("-3"));
/// ```
pub fn try_generate(
    family: Family,
    seed: u64,
    duration_s: Option<f64>,
) -> Result<SimRun, SimError> {
    try_generate_with(family, seed, duration_s, 1.0)
}

/// Like [`try_generate`], with the signature noise of the family multiplied by
/// `noise_scale`, in `[0, MAX_NOISE_SCALE]` (0: noiseless values; jitter, drops and
/// gaps are unchanged). The same `(family, seed, duration)` gives the same motion,
/// clocks and drops at any scale.
///
/// ```
/// use vlsync_sim::families::{try_generate_with, Family};
/// let run = try_generate_with(Family::Robot, 4, Some(20.0), 0.0).unwrap();
/// assert!(run.cam.iter().zip(&run.cam_clean).all(|(s, c)| s.value == c.value));
/// assert!(try_generate_with(Family::Robot, 4, None, -1.0).is_err());
/// assert!(try_generate_with(Family::Robot, 4, None, 1e308).is_err());
/// ```
pub fn try_generate_with(
    family: Family,
    seed: u64,
    duration_s: Option<f64>,
    noise_scale: f64,
) -> Result<SimRun, SimError> {
    if !(0.0..=MAX_NOISE_SCALE).contains(&noise_scale) {
        return Err(SimError::InvalidNoiseScale { noise_scale });
    }
    let d = match duration_s {
        None => family.default_duration_s(),
        Some(d) if d.is_finite() && (MIN_DURATION_S..=MAX_DURATION_S).contains(&d) => d,
        Some(d) => return Err(SimError::InvalidDuration { duration_s: d }),
    };
    Ok(build(family, seed, d, noise_scale))
}

fn build(family: Family, seed: u64, duration: f64, noise_scale: f64) -> SimRun {
    let mut rng =
        ChaCha8Rng::seed_from_u64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (family.index() + 1));
    let p = params(family);

    // --- truth
    let mut truth = Truth {
        offset0_s: 0.0,
        drift: 0.0,
        steps: Vec::new(),
        end_ns: secs_to_nanos(duration),
    };
    if family == Family::Seed {
        // seed: t_L = t_C + 0.18 + 0.012 t_C  =>  offset(t_L) = (0.18 + 0.012 t_L) / 1.012
        truth.offset0_s = 0.18 / 1.012;
        truth.drift = 0.012 / 1.012;
    } else {
        let (lo, hi) = p.offset_range;
        truth.offset0_s = if hi > lo { rng.gen_range(lo..hi) } else { lo };
        if let Some((a, b)) = p.drift_ppm {
            let sign = if rng.gen::<bool>() { 1.0 } else { -1.0 };
            truth.drift = sign * rng.gen_range(a..b) * 1e-6;
        }
        if p.steps {
            let mut t = rng.gen_range(15.0..25.0);
            let mut cum: f64 = 0.0;
            while t < duration - 3.0 {
                let mut delta: f64 = if rng.gen::<bool>() { 0.025 } else { -0.025 };
                if (cum + delta).abs() > 0.051 {
                    delta = -delta;
                }
                cum += delta;
                truth.steps.push((secs_to_nanos(t), delta));
                t += rng.gen_range(15.0..25.0);
            }
        }
    }

    // --- motion
    let max_offset = truth.offset0_s.abs() + truth.drift.abs() * duration + 0.06;
    let motion = if family == Family::Seed {
        Motion::Seed {
            cam_period: (1.0 + 0.012) / p.cam_hz,
            lidar_period: 1.0 / p.lidar_hz,
            kernel: seed_kernel(),
        }
    } else {
        let forced = p.standstill_s.map(|len| {
            let len = len.min(duration / 3.0);
            (duration / 2.0 - len / 2.0, len)
        });
        Motion::Robot(plan_robot(&mut rng, duration + max_offset + 1.0, forced))
    };

    // --- noise levels
    let (noise_cam, noise_lidar) = match (&motion, p.heavy_noise) {
        (Motion::Seed { .. }, _) => (0.06, 0.06),
        (Motion::Robot(_), false) => (CAM_NOISE, LIDAR_NOISE),
        (Motion::Robot(_), true) => (
            HEAVY_NOISE_FACTOR * CAM_NOISE,
            HEAVY_NOISE_FACTOR * LIDAR_NOISE,
        ),
    };

    let (noise_cam, noise_lidar) = (noise_cam * noise_scale, noise_lidar * noise_scale);

    // --- gap
    let mut lidar_gaps = Vec::new();
    if p.lidar_gap {
        let g0 = rng.gen_range(0.3..0.7) * duration;
        let len = rng.gen_range(1.2..2.0);
        lidar_gaps.push((secs_to_nanos(g0), secs_to_nanos(g0 + len)));
    }
    let in_gap = |tau_ns: Nanos| lidar_gaps.iter().any(|&(a, b)| tau_ns >= a && tau_ns < b);

    // --- LiDAR scans: regular in tau (= LiDAR clock)
    let mut lidar = Vec::new();
    let mut lidar_clean = Vec::new();
    let mut lidar_dropped = 0;
    let lp = 1.0 / p.lidar_hz;
    let lphase = if family == Family::Seed {
        0
    } else {
        secs_to_nanos(rng.gen_range(0.01..lp))
    };
    let mut k = 0u64;
    loop {
        let tau_ns = tick_ns(lphase, k, p.lidar_hz);
        let tau = nanos_to_secs(tau_ns);
        k += 1;
        if tau >= duration {
            break;
        }
        let jit = p.jitter.1 * rng.sample::<f64, _>(StandardNormal);
        let noise = noise_lidar * rng.sample::<f64, _>(StandardNormal);
        let drop = p.drop_p > 0.0 && rng.gen::<f64>() < p.drop_p;
        if in_gap(tau_ns) {
            continue;
        }
        if drop {
            lidar_dropped += 1;
            continue;
        }
        let clean = motion.lidar(tau);
        lidar.push(Sample::new(secs_to_nanos(tau + jit), clean + noise));
        lidar_clean.push(CleanPoint {
            tau_ns,
            value: clean,
            slope: slope(|x| motion.lidar(x), tau),
        });
    }

    // --- camera frames: regular on the camera clock (continuous part of the offset)
    let mut cam = Vec::new();
    let mut cam_clean = Vec::new();
    let mut cam_dropped = 0;
    let cp = 1.0 / p.cam_hz;
    let cphase = if family == Family::Seed {
        0
    } else {
        secs_to_nanos(rng.gen_range(0.01..cp))
    };
    let mut k = 0u64;
    loop {
        let c_ns = tick_ns(cphase, k, p.cam_hz);
        let c = nanos_to_secs(c_ns);
        k += 1;
        if c >= duration {
            break;
        }
        // tau - (o0 + d tau) = c: the frame happens at tau; steps only move its stamp
        let tau = (c + truth.offset0_s) / (1.0 - truth.drift);
        let jit = p.jitter.0 * rng.sample::<f64, _>(StandardNormal);
        let noise = noise_cam * rng.sample::<f64, _>(StandardNormal);
        let drop = p.drop_p > 0.0 && rng.gen::<f64>() < p.drop_p;
        if drop {
            cam_dropped += 1;
            continue;
        }
        let tau_ns = secs_to_nanos(tau);
        let mut late = truth.steps_at(tau_ns);
        if p.step_spread_s > 0.0 {
            // the newest step reaches this frame yet only with the spread's probability
            if let Some(&(t_s, delta)) = truth.steps.iter().rev().find(|s| s.0 <= tau_ns) {
                let frac = nanos_to_secs(tau_ns - t_s) / p.step_spread_s;
                if frac < 1.0 && rng.gen::<f64>() >= frac {
                    late -= delta;
                }
            }
        }
        let t_c = c_ns - secs_to_nanos(late) + secs_to_nanos(jit);
        let clean = motion.cam(tau);
        cam.push(Sample::new(t_c, clean + noise));
        cam_clean.push(CleanPoint {
            tau_ns,
            value: clean,
            slope: slope(|x| motion.cam(x), tau),
        });
    }

    let (motion_start_ns, standstills, polarity) = match &motion {
        Motion::Seed { .. } => (0, Vec::new(), Polarity::Positive),
        Motion::Robot(pr) => (
            secs_to_nanos(pr.motion_start),
            pr.rests
                .iter()
                .filter(|(a, b)| b - a >= MIN_STANDSTILL_S - 1e-9 && *a < duration)
                .map(|&(a, b)| (secs_to_nanos(a), secs_to_nanos(b.min(duration))))
                .collect(),
            Polarity::Negative,
        ),
    };

    let mut run = SimRun {
        family,
        seed,
        cam,
        lidar,
        step_times_ns: truth.steps.iter().map(|s| s.0).collect(),
        truth,
        crb_std_s: f64::INFINITY,
        motion_start_ns,
        standstills,
        lidar_gaps,
        cam_hz: p.cam_hz,
        lidar_hz: p.lidar_hz,
        duration_s: duration,
        noise_cam,
        noise_lidar,
        jitter_cam_s: p.jitter.0,
        jitter_lidar_s: p.jitter.1,
        cam_dropped,
        lidar_dropped,
        polarity,
        cam_clean,
        lidar_clean,
    };
    run.crb_std_s = crate::crb::crb_run_std_s(&run);
    run
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn noiseless(f: Family, seed: u64) -> SimRun {
        try_generate_with(f, seed, None, 0.0).unwrap()
    }

    /// Linear-interpolated time at which `xs` first reaches `thr` (in absolute value).
    fn crossing(xs: &[Sample], thr: f64) -> f64 {
        let i = xs.iter().position(|s| s.value.abs() >= thr).unwrap();
        assert!(i > 0);
        let (a, b) = (xs[i - 1], xs[i]);
        let f = (thr - a.value.abs()) / (b.value.abs() - a.value.abs());
        nanos_to_secs(a.t_ns) + f * nanos_to_secs(b.t_ns - a.t_ns)
    }

    #[test]
    fn sharp_event_lines_up_with_truth_offset() {
        // the motion onset, seen by both sensors, noiselessly: t_C + offset = t_L
        for (f, seed) in [
            (Family::BigOffset, 1),
            (Family::NegativeOffset, 2),
            (Family::Robot, 3),
            (Family::Rates15x20, 4),
        ] {
            let run = noiseless(f, seed);
            let t_l = crossing(&run.lidar, 0.1);
            let t_c = crossing(&run.cam, 0.1 * FLOW_GAIN);
            let off = run.truth.offset_at(secs_to_nanos(t_l));
            assert!(
                (t_c + off - t_l).abs() < 0.01,
                "{f}: t_c {t_c} + offset {off} != t_l {t_l}"
            );
            assert!(t_l > nanos_to_secs(run.motion_start_ns));
        }
    }

    #[test]
    fn seed_family_matches_the_article_with_fixed_conventions() {
        let run = generate(Family::Seed, 3, None);
        assert_eq!((run.cam.len(), run.lidar.len()), (360, 120));
        assert_eq!(run.polarity, Polarity::Positive);
        // the article samples the camera at t_cam + 0.18 + 0.012 t_cam
        for (s, c) in run.cam.iter().zip(&run.cam_clean).step_by(37) {
            let t_cam = nanos_to_secs(s.t_ns);
            assert!((nanos_to_secs(c.tau_ns) - (t_cam + 0.18 + 0.012 * t_cam)).abs() < 2e-9);
            let want = smoothed(&seed_kernel(), 1.012 / 30.0, t_cam + 0.18 + 0.012 * t_cam);
            assert!((c.value - want).abs() < 1e-9);
        }
        assert!((run.truth.offset_at(0) - 0.18 / 1.012).abs() < 1e-12);
        assert_eq!(run.noise_cam, 0.06);
        let resid: Vec<f64> = run
            .lidar
            .iter()
            .zip(&run.lidar_clean)
            .map(|(s, c)| s.value - c.value)
            .collect();
        let sd = (resid.iter().map(|r| r * r).sum::<f64>() / resid.len() as f64).sqrt();
        assert!((sd - 0.06).abs() < 0.012, "lidar noise sd {sd}");
    }

    #[test]
    fn every_sample_obeys_the_convention() {
        for f in Family::ALL {
            let run = generate(f, 11, Some(60.0));
            for (s, c) in run.cam.iter().zip(&run.cam_clean) {
                let implied = nanos_to_secs(c.tau_ns - s.t_ns);
                let tol = 6.0 * run.jitter_cam_s + 3e-9;
                let now = run.truth.offset_at(c.tau_ns);
                // within a step's spread, the frame may still carry the old latency
                let spread = secs_to_nanos(f.step_spread_s());
                let before = run
                    .truth
                    .steps
                    .iter()
                    .rev()
                    .find(|st| st.0 <= c.tau_ns && c.tau_ns < st.0 + spread)
                    .map(|st| now - st.1);
                assert!(
                    (implied - now).abs() <= tol
                        || before.is_some_and(|b| (implied - b).abs() <= tol),
                    "{f}"
                );
            }
            for (s, c) in run.lidar.iter().zip(&run.lidar_clean) {
                assert!(
                    nanos_to_secs((s.t_ns - c.tau_ns).abs()) <= 6.0 * run.jitter_lidar_s + 1e-9
                );
            }
            let o = |t: f64| run.truth.offset_at(secs_to_nanos(t));
            if f != Family::Seed {
                assert!(o(0.0).abs() <= 0.5 && o(60.0).abs() <= 0.5, "{f}");
            }
            assert!(
                run.cam.windows(2).all(|w| w[1].t_ns > w[0].t_ns),
                "{f}: cam not increasing"
            );
            assert!(
                run.lidar.windows(2).all(|w| w[1].t_ns > w[0].t_ns),
                "{f}: lidar not increasing"
            );
            assert!(run.crb_std_s.is_finite() && run.crb_std_s > 0.0);
        }
    }

    #[test]
    fn rates_and_durations() {
        for f in Family::ALL {
            let run = generate(f, 5, None);
            let d = f.default_duration_s();
            assert_eq!(run.duration_s, d);
            let (ch, lh) = f.rates_hz();
            let kept = |n: usize, dropped: usize| (n + dropped) as f64;
            let gap = run
                .lidar_gaps
                .iter()
                .map(|g| nanos_to_secs(g.1 - g.0))
                .sum::<f64>();
            assert!(
                (kept(run.cam.len(), run.cam_dropped) - d * ch).abs() <= 1.0,
                "{f} cam"
            );
            assert!(
                (kept(run.lidar.len(), run.lidar_dropped) - (d - gap) * lh).abs() <= 2.0,
                "{f} lidar"
            );
        }
        assert_eq!(generate(Family::Robot, 1, Some(45.0)).duration_s, 45.0);
        assert_eq!(
            generate(Family::Robot, 1, Some(-5.0)).duration_s,
            MIN_DURATION_S
        );
        assert_eq!(generate(Family::Robot, 1, Some(f64::NAN)).duration_s, 120.0);
        assert_eq!(
            generate(Family::Robot, 1, Some(1e9)).duration_s,
            MAX_DURATION_S
        );
        let e = try_generate(Family::Robot, 1, Some(f64::INFINITY)).unwrap_err();
        assert!(e.to_string().contains("inf"), "{e}");
    }

    #[test]
    fn drift_rms_is_the_generated_drifts_rms() {
        for family in Family::ALL {
            let drifts: Vec<f64> = (0..60)
                .map(|seed| generate(family, seed, Some(20.0)).truth.drift)
                .collect();
            let rms = (drifts.iter().map(|d| d * d).sum::<f64>() / 60.0).sqrt();
            match family {
                Family::Seed => assert!(drifts.iter().all(|&d| d == drifts[0])),
                _ if family.drift_rms() == 0.0 => assert_eq!(rms, 0.0, "{family:?}"),
                _ => assert!(
                    (rms / family.drift_rms() - 1.0).abs() < 0.12,
                    "{family:?}: {rms} vs {}",
                    family.drift_rms()
                ),
            }
        }
    }

    #[test]
    fn clocks_drops_jitter_gap_and_drift() {
        let (mut cam_drop, mut cam_n, mut lid_drop, mut lid_n) = (0, 0, 0, 0);
        for seed in 0..4 {
            let run = generate(Family::Clocks, seed, None);
            cam_drop += run.cam_dropped;
            cam_n += run.cam_dropped + run.cam.len();
            lid_drop += run.lidar_dropped;
            lid_n += run.lidar_dropped + run.lidar.len();
            // drift 20-60 ppm
            let ppm = run.truth.drift.abs() * 1e6;
            assert!((20.0..=60.0).contains(&ppm), "drift {ppm} ppm");
            // jitter statistics
            let cj: Vec<f64> = run
                .cam
                .iter()
                .zip(&run.cam_clean)
                .map(|(s, c)| nanos_to_secs(s.t_ns - c.tau_ns) + run.truth.offset_at(c.tau_ns))
                .collect();
            let lj: Vec<f64> = run
                .lidar
                .iter()
                .zip(&run.lidar_clean)
                .map(|(s, c)| nanos_to_secs(s.t_ns - c.tau_ns))
                .collect();
            for (j, want) in [(cj, 0.001), (lj, 0.003)] {
                let m = j.iter().sum::<f64>() / j.len() as f64;
                let sd = (j.iter().map(|x| (x - m).powi(2)).sum::<f64>() / j.len() as f64).sqrt();
                assert!(
                    m.abs() < want * 0.15 && (sd / want - 1.0).abs() < 0.1,
                    "jitter mean {m} sd {sd} want {want}"
                );
            }
            // exactly one LiDAR gap of 1.2-2 s, where recorded
            assert_eq!(run.lidar_gaps.len(), 1);
            let big: Vec<(Nanos, Nanos)> = run
                .lidar
                .windows(2)
                .filter(|w| w[1].t_ns - w[0].t_ns > secs_to_nanos(1.0))
                .map(|w| (w[0].t_ns, w[1].t_ns))
                .collect();
            assert_eq!(big.len(), 1);
            let (a, b) = run.lidar_gaps[0];
            assert!((1.2..=2.0).contains(&nanos_to_secs(b - a)));
            assert!(big[0].0 < a && big[0].1 >= b && nanos_to_secs(big[0].1 - big[0].0) < 2.4);
        }
        let cr = cam_drop as f64 / cam_n as f64;
        let lr = lid_drop as f64 / lid_n as f64;
        assert!((0.04..0.06).contains(&cr), "camera drop rate {cr}");
        assert!((0.035..0.065).contains(&lr), "lidar drop rate {lr}");
        // no drops, jitter or gaps elsewhere
        let r = generate(Family::Robot, 0, None);
        assert_eq!(
            (r.cam_dropped, r.lidar_dropped, r.lidar_gaps.len()),
            (0, 0, 0)
        );
    }

    #[test]
    fn load_steps_are_25ms_every_15_to_25_s() {
        for seed in 0..5 {
            let run = generate(Family::LoadSteps, seed, None);
            let st = &run.truth.steps;
            assert!((4..=7).contains(&st.len()), "{} steps", st.len());
            assert_eq!(
                run.step_times_ns,
                st.iter().map(|s| s.0).collect::<Vec<_>>()
            );
            let mut prev = 0;
            let mut cum = 0.0;
            for &(t, d) in st {
                assert!((d.abs() - 0.025).abs() < 1e-12);
                let dt = nanos_to_secs(t - prev);
                assert!((15.0..25.0).contains(&dt), "step interval {dt}");
                prev = t;
                cum += d;
                assert!(f64::abs(cum) <= 0.0501);
                let jump = run.truth.offset_at(t) - run.truth.offset_at(t - 1);
                assert!((jump - d).abs() < 1e-9);
            }
            // the camera stamps carry the step: implied offset of frames right after it
            let (t0, d0) = st[0];
            let implied = |lo: f64, hi: f64| {
                let v: Vec<f64> = run
                    .cam
                    .iter()
                    .zip(&run.cam_clean)
                    .filter(|(_, c)| {
                        c.tau_ns >= t0 + secs_to_nanos(lo) && c.tau_ns < t0 + secs_to_nanos(hi)
                    })
                    .map(|(s, c)| nanos_to_secs(c.tau_ns - s.t_ns))
                    .collect();
                v.iter().sum::<f64>() / v.len() as f64
            };
            assert!((implied(0.0, 1.0) - implied(-1.0, 0.0) - d0).abs() < 1e-6);
        }
    }

    #[test]
    fn load_jitter_spreads_each_step_over_its_frames() {
        let run = generate(Family::LoadJitter, 3, None);
        assert!(run.jitter_cam_s > 0.0 && run.cam_dropped > 0 && !run.lidar_gaps.is_empty());
        assert!(run.truth.drift != 0.0 && run.truth.steps.len() >= 4);
        let (mut old, mut new, mut late_old) = (0, 0, 0);
        for (s, c) in run.cam.iter().zip(&run.cam_clean) {
            let implied = nanos_to_secs(c.tau_ns - s.t_ns);
            for &(t, d) in &run.truth.steps {
                let since = nanos_to_secs(c.tau_ns - t);
                let is_old = (implied - (run.truth.offset_at(c.tau_ns) - d)).abs() < 0.006;
                if (0.0..0.3).contains(&since) {
                    if is_old {
                        old += 1;
                    } else {
                        new += 1;
                    }
                } else if (0.3..1.0).contains(&since) && is_old {
                    late_old += 1;
                }
            }
        }
        // inside the spread both latencies, after it only the new one
        assert!(old > 5 && new > 5, "{old} old, {new} new");
        assert_eq!(late_old, 0);
    }

    #[test]
    fn standstill_is_pure_noise() {
        let run = generate(Family::Standstill, 7, None);
        let ss: Vec<_> = run
            .standstills
            .iter()
            .filter(|s| nanos_to_secs(s.1 - s.0) > 29.9)
            .collect();
        assert_eq!(ss.len(), 1);
        let (a, b) = *ss[0];
        assert!((nanos_to_secs(a) - 45.0).abs() < 3.0, "starts at {a}");
        assert!(
            (30.0..34.0).contains(&nanos_to_secs(b - a)),
            "lasts {}",
            b - a
        );
        for clean in [&run.cam_clean, &run.lidar_clean] {
            let inside: Vec<&CleanPoint> = clean
                .iter()
                .filter(|c| c.tau_ns >= a && c.tau_ns < b)
                .collect();
            assert!(inside.len() > 250);
            assert!(inside.iter().all(|c| c.value == 0.0 && c.slope == 0.0));
        }
        let lv: Vec<f64> = run
            .lidar
            .iter()
            .filter(|s| s.t_ns >= a && s.t_ns < b)
            .map(|s| s.value)
            .collect();
        let sd = (lv.iter().map(|x| x * x).sum::<f64>() / lv.len() as f64).sqrt();
        assert!(
            (sd / run.noise_lidar - 1.0).abs() < 0.15,
            "standstill lidar sd {sd}"
        );
        // moving on both sides of the standstill
        let moving = |lo: f64, hi: f64| {
            run.lidar_clean.iter().any(|c| {
                let t = nanos_to_secs(c.tau_ns);
                t > lo && t < hi && c.value < -0.1
            })
        };
        assert!(moving(30.0, nanos_to_secs(a)) && moving(nanos_to_secs(b), 90.0));
        // the robot family has no long standstill apart from short stops
        assert!(generate(Family::Robot, 7, None)
            .standstills
            .iter()
            .all(|s| nanos_to_secs(s.1 - s.0) < 29.0));
    }

    /// A short standstill run whose rest comes before the initial rest ends pushes the
    /// rest at once: the robot first moves after it, and the motion start says so (it
    /// said the end of the initial rest, some 4 s early, so time to first lock and the
    /// CLI's "motion starts" were off by the rest).
    #[test]
    fn motion_start_is_where_the_robot_first_moves() {
        let mut late_starts = 0;
        for (family, duration) in [
            (Family::Standstill, Some(12.0)),
            (Family::Standstill, Some(6.0)),
            (Family::Standstill, None),
            (Family::Robot, None),
        ] {
            for seed in 0..12 {
                let run = try_generate_with(family, seed, duration, 0.0).unwrap();
                let ms = run.motion_start_ns;
                let first = run
                    .lidar_clean
                    .iter()
                    .find(|c| c.value != 0.0)
                    .expect("the robot moves")
                    .tau_ns;
                // the first scan after the start sees it moving (a LiDAR period later at most)
                assert!(
                    first > ms && first - ms <= 100_000_000,
                    "{family} {duration:?} seed {seed}: moves at {first} ns, start said {ms} ns"
                );
                if ms > secs_to_nanos(3.0) {
                    late_starts += 1;
                }
            }
        }
        assert!(late_starts > 0, "no run with the rest first");
    }

    /// The description says how long the standstill is and when it is reported: a
    /// third of a short run, and not at all under 15 s (it said "one 30 s standstill"
    /// whatever the duration, while a 12 s run reported none or the initial rest).
    #[test]
    fn standstill_description_says_what_a_short_run_does() {
        let d = Family::Standstill.description();
        assert!(
            d.contains("30 s, a third of a run under 90 s") && d.contains("under 15 s"),
            "{d}"
        );
        let lengths = |duration: f64| -> Vec<Vec<(f64, f64)>> {
            (0..6)
                .map(|seed| {
                    generate(Family::Standstill, seed, Some(duration))
                        .standstills
                        .iter()
                        .map(|&(a, b)| (nanos_to_secs(a), nanos_to_secs(b - a)))
                        .collect()
                })
                .collect()
        };
        for (duration, len) in [(60.0, 20.0), (15.0, 5.0)] {
            for s in lengths(duration) {
                assert!(
                    s.len() == 1 && (s[0].1 - len).abs() < 1e-6,
                    "{duration} s: {s:?}"
                );
            }
        }
        // under 15 s: nothing, or the rest where it joins the initial one
        for s in lengths(14.9).into_iter().chain(lengths(12.0)) {
            assert!(s.iter().all(|r| r.0 == 0.0), "{s:?}");
        }
    }

    #[test]
    fn robot_motion_is_plausible() {
        for seed in 0..5 {
            let run = noiseless(Family::Robot, seed);
            let v: Vec<f64> = run.lidar_clean.iter().map(|c| -c.value).collect();
            let a: Vec<f64> = run.cam_clean.iter().map(|c| c.slope / FLOW_GAIN).collect();
            assert!(v.iter().all(|&x| (0.0..0.7).contains(&x)), "speed range");
            assert!(v.iter().any(|&x| x > 0.3));
            let amax = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(amax < 0.75 && amax > 0.2, "max accel {amax}");
            // rests before the motion start, stops and motion in between
            let ms = run.motion_start_ns;
            assert!(run
                .lidar_clean
                .iter()
                .filter(|c| c.tau_ns < ms)
                .all(|c| c.value == 0.0));
            let moving = v.iter().filter(|&&x| x > 0.0).count() as f64 / v.len() as f64;
            assert!((0.6..0.98).contains(&moving), "moving share {moving}");
            assert_eq!(run.polarity, Polarity::Negative);
        }
    }

    #[test]
    fn offsets_and_noise_per_family() {
        for seed in 0..6 {
            assert_eq!(
                generate(Family::BigOffset, seed, Some(10.0))
                    .truth
                    .offset0_s,
                0.45
            );
            let n = generate(Family::NegativeOffset, seed, Some(10.0))
                .truth
                .offset0_s;
            assert!((-0.25..=-0.15).contains(&n));
        }
        let h = generate(Family::HeavyNoise, 2, None);
        assert!((h.noise_cam / CAM_NOISE - HEAVY_NOISE_FACTOR).abs() < 1e-12);
        let r = generate(Family::Robot, 2, None);
        assert!(r.noise_lidar / LIDAR_NOISE > 0.99 && h.crb_std_s > 2.0 * r.crb_std_s);
        // LiDAR noise is the larger one, in m/s-equivalent
        assert!(r.noise_lidar > r.noise_cam / FLOW_GAIN);
    }

    /// The module's doc quotes the noise constants (it once gave 0.012 m/s and 1.0 px/s
    /// for 0.0045 and 0.4, and "each signature's std" for three times the noise).
    #[test]
    fn the_module_doc_states_the_noise_constants() {
        let doc: Vec<&str> = include_str!("families.rs")
            .lines()
            .filter_map(|l| l.strip_prefix("//!"))
            .collect();
        let doc = doc.join("\n");
        for want in [
            format!("noise {LIDAR_NOISE} m/s"),
            format!("noise {CAM_NOISE} px/s"),
            format!("{:.4} m/s-equivalent", CAM_NOISE / FLOW_GAIN),
        ] {
            assert!(doc.contains(&want), "the module doc lacks `{want}`");
        }
        let heavy = doc
            .lines()
            .find(|l| l.starts_with(" | `heavy-noise`"))
            .expect("the heavy-noise row");
        assert!(
            heavy.contains(&format!("[`HEAVY_NOISE_FACTOR`] ({HEAVY_NOISE_FACTOR})")),
            "{heavy}"
        );
        assert_eq!(HEAVY_NOISE_FACTOR, 3.0, "description() says three times");
        assert!(Family::HeavyNoise.description().contains("three times"));
    }

    #[test]
    fn noise_scales_outside_0_to_1000_are_refused_naming_value_and_range() {
        for (bad, shown) in [
            (-1.0, "-1"),
            (f64::NAN, "NaN"),
            (f64::INFINITY, "inf"),
            (1000.5, "1000.5"),
            (1e308, "1e308"),
        ] {
            let e = try_generate_with(Family::Robot, 1, Some(10.0), bad).unwrap_err();
            assert!(
                matches!(e, SimError::InvalidNoiseScale { noise_scale } if noise_scale.to_bits() == bad.to_bits()),
                "{e:?}"
            );
            let msg = e.to_string();
            assert!(
                msg.contains(&format!("noise scale {shown} is invalid"))
                    && msg.contains("[0, 1000]"),
                "{msg}"
            );
        }
        // the bound itself: finite values and a finite bound
        let run = try_generate_with(Family::HeavyNoise, 1, Some(10.0), MAX_NOISE_SCALE).unwrap();
        assert!(run.crb_std_s.is_finite() && run.crb_std_s > 0.0);
        assert!(run
            .cam
            .iter()
            .chain(&run.lidar)
            .all(|s| s.value.is_finite()));
    }

    #[test]
    fn names_parse_and_runs_are_deterministic() {
        for f in Family::ALL {
            assert_eq!(f.name().parse::<Family>(), Ok(f));
            assert_eq!(f.to_string().to_uppercase().parse::<Family>(), Ok(f));
        }
        assert_eq!("rates_60x5".parse::<Family>(), Ok(Family::Rates60x5));
        let e = "warp".parse::<Family>().unwrap_err().to_string();
        assert!(
            e.contains("warp") && e.contains("rates-15x20") && e.contains("heavy-noise"),
            "{e}"
        );
        let a = generate(Family::Clocks, 9, Some(30.0));
        assert_eq!(a, generate(Family::Clocks, 9, Some(30.0)));
        assert_ne!(a.cam, generate(Family::Clocks, 10, Some(30.0)).cam);
        assert_ne!(
            generate(Family::Robot, 9, Some(30.0)).cam,
            generate(Family::BigOffset, 9, Some(30.0)).cam
        );
        // the noise scale changes values only
        let q = try_generate_with(Family::Clocks, 9, Some(30.0), 0.0).unwrap();
        assert_eq!(q.cam.len(), a.cam.len());
        assert!(q.cam.iter().zip(&a.cam).all(|(x, y)| x.t_ns == y.t_ns));
        assert_eq!(q.crb_std_s, 0.0);
    }

    #[test]
    fn truth_csv() {
        let run = generate(Family::LoadSteps, 1, Some(30.0));
        let text = run.truth.to_csv_string();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], "t,offset");
        assert_eq!(lines.len(), 1 + 3001);
        assert!(lines[1].starts_with("0.000000000,"));
        assert!(lines[3001].starts_with("30.000000000,"));
        let rows = crate::io::parse_truth_csv(text.as_bytes(), "truth").unwrap();
        for &(t, offset) in rows.iter().step_by(97) {
            assert!((offset - run.truth.offset_at(t)).abs() < 1e-9);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn any_seed_and_duration_gives_a_sane_run(seed in any::<u64>(), d in 2.0f64..40.0, fi in 0usize..Family::ALL.len()) {
            let f = Family::ALL[fi];
            let run = generate(f, seed, Some(d));
            prop_assert!(!run.cam.is_empty() && !run.lidar.is_empty());
            prop_assert!(run.cam.iter().chain(&run.lidar).all(|s| s.value.is_finite()));
            prop_assert!(run.truth.offset_at(0).abs() <= 0.5);
            prop_assert!(run.crb_std_s > 0.0);
        }
    }
}
