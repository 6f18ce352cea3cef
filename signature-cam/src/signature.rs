//! The per-frame processor: frames and their times in, [`Sample`]s out.
//!
//! The flow between frames `k-1` and `k` measures motion over that interval, so
//! by default a sample is stamped at the **midpoint** `(t[k-1] + t[k]) / 2`
//! ([`Stamping::Midpoint`]); stamping at `t[k]` ([`Stamping::End`]) biases the
//! signature late by half a frame interval (16.7 ms at 30 Hz). When the source
//! gives exposure start and duration ([`FrameTime::Exposure`]), each frame's time
//! is its mid-exposure instant.
//!
//! Values are in **pixels per second**: the reduced flow divided by the frame
//! interval, so a dropped frame doubles the flow and the interval alike and
//! leaves the scale unchanged. An interval longer than the gap limit
//! ([`SignatureConfig::max_gap_ns`], 250 ms, or 4.5 frame periods of a camera
//! slower than 18 Hz: [`SignatureProcessor::gap_limit_ns`]), or a time that does
//! not increase, or, once the frame period is confirmed, by less than a quarter of
//! it ([`SignatureConfig::SHORT_PERIODS`]: two frames' times bunched, one frame's
//! flow over a sliver of its interval; a run of them held to the period before
//! it until together they span it), produces no sample: the processor restarts
//! from the new frame.
//!
//! # Stamp jitter and the scale
//!
//! A camera exposes on its own sensor clock, at a steady rate; the stamps a
//! driver attaches carry host jitter (about 1 ms on a USB camera). Divided by
//! the raw stamp difference, 1 ms of jitter on a 33 ms interval is 4 % of noise
//! on every value: more than the flow's own error. So by default
//! ([`SignatureConfig::dejitter`]) the interval used for the scale is a whole
//! number of frame periods, the period being tracked from the stamps themselves
//! ([`FramePeriod`]): a running mean over the last ~64 intervals that are within
//! 30 % of a period of a whole number of periods, so a dropped frame counts as
//! two periods and slow drifts are followed. A change of rate by more than 30 %
//! is adopted after three intervals that disagree (the fourth becomes the
//! period); a smaller one is followed only by the running mean, over seconds
//! (30 to 25 Hz: 16 % off at first, 6 % after 2 s; [`FramePeriod`] says why no
//! faster rule was kept). The *stamps* are never smoothed: a sample is still
//! stamped at the midpoint of its two frames' own times.
//!
//! ```
//! use vlsync_signature_cam::image::GrayFrame;
//! use vlsync_signature_cam::signature::{FrameTime, SignatureConfig, SignatureProcessor, Step};
//! let (w, h) = (160, 120);
//! let tex = |x: f32, y: f32| 128.0 + 60.0 * ((0.31 * x).sin() * (0.23 * y).cos() + (0.17 * (x + y)).sin());
//! let make = |dy: f32| -> GrayFrame<'static, f32> {
//!     GrayFrame::owned_f32(w, h, (0..w * h).map(|i| tex((i % w) as f32, (i / w) as f32 - dy)).collect()).unwrap()
//! };
//! let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
//! // 2 px down in 40 ms: 50 px/s, stamped at the midpoint 1.02 s
//! assert!(matches!(p.process(&make(0.0), FrameTime::Instant(1_000_000_000)).unwrap(), Step::Started(_)));
//! let Step::Sample(s) = p.process(&make(2.0), FrameTime::Instant(1_040_000_000)).unwrap() else { panic!() };
//! assert_eq!(s.sample.t_ns, 1_020_000_000);
//! assert!((s.sample.value - 50.0).abs() < 1.0, "{}", s.sample.value);
//! ```

use crate::flow::{FlowConfig, FlowStats, PyrLk};
use crate::image::{GrayFrame, Pixel};
use crate::reduce::{Reducer, Reduction, DEFAULT_TRIM};
use crate::Error;
use serde::{Deserialize, Serialize};
use vlsync_common::{Nanos, Sample, NANOS_PER_SEC};

/// Where a sample is stamped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stamping {
    /// `(t[k-1] + t[k]) / 2`: the centre of the interval the flow measures (default).
    #[default]
    Midpoint,
    /// `t[k]`: the later frame. Biased late by half a frame interval; for tests
    /// and comparisons only.
    End,
}

/// When a frame was taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameTime {
    /// One stamp taken as the frame's instant (e.g. a driver's capture time).
    Instant(Nanos),
    /// Exposure start and duration: the frame's instant is mid-exposure.
    Exposure {
        /// Start of exposure, ns.
        start_ns: Nanos,
        /// Exposure duration, ns (>= 0).
        duration_ns: Nanos,
    },
}

impl FrameTime {
    /// The frame's instant: the stamp, or `start + duration / 2` (saturating).
    /// A negative duration is an error.
    pub fn instant_ns(self) -> Result<Nanos, Error> {
        match self {
            FrameTime::Instant(t) => Ok(t),
            FrameTime::Exposure {
                start_ns,
                duration_ns,
            } => {
                if duration_ns < 0 {
                    return Err(Error::BadFrameTime {
                        reason: format!(
                            "negative exposure duration {duration_ns} ns (start {start_ns} ns)"
                        ),
                    });
                }
                Ok(start_ns.saturating_add(duration_ns / 2))
            }
        }
    }
}

/// Configuration of [`SignatureProcessor`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SignatureConfig {
    /// Optical flow.
    pub flow: FlowConfig,
    /// Flow vectors to scalar (default: the downward component, reduced over the
    /// whole grid against its learnt pattern, see `normalise`).
    pub reduction: Reduction,
    /// Trim fraction at each end for the trimmed means (default 0.1); used only
    /// with `normalise = false` (the grid reduction drops outliers by a MAD test).
    pub trim: f32,
    /// Sample stamping (default midpoint).
    pub stamping: Stamping,
    /// Longest frame interval a sample may span, ns (default 250 ms), or
    /// [`SignatureConfig::GAP_PERIODS`] tracked frame periods if that is longer
    /// (once the period is confirmed, see [`FramePeriod::confirmed_period_ns`]):
    /// a longer interval restarts the processor ([`StartReason::Gap`]). At 30 Hz
    /// the 250 ms hold (up to 6 dropped frames in a row); below 18 Hz the
    /// periods do, so a camera at 3 Hz gives samples and one at 7.5 Hz survives
    /// up to 3 dropped frames in a row. A camera slower than 4 Hz restarts on
    /// its first two intervals (the period is not yet confirmed) and gives
    /// samples from its third interval on; one that slows down to that from a
    /// faster rate gives samples again from its sixth slow interval (three
    /// gaps in a row make the fourth the period, see [`FramePeriod::gap`], and
    /// the fifth confirms it). One that slows from 30 to 15 or 7.5 Hz keeps
    /// 33 ms as its period (each interval agrees as 2 or 4 of them), and the
    /// periods are counted in the fewest the last 8 intervals spanned: after 8
    /// intervals at 7.5 Hz the limit is 600 ms.
    pub max_gap_ns: Nanos,
    /// Scale values by a whole number of tracked frame periods instead of the raw
    /// stamp difference (default true; see the module docs).
    pub dejitter: bool,
    /// Reduce the whole grid against its learnt flow pattern, so that the value
    /// does not depend on which points were tracked
    /// ([`crate::reduce::Reducer::reduce_grid`]; default true). Off: the
    /// reduction of the tracked vectors alone ([`crate::reduce::Reducer::reduce`]).
    pub normalise: bool,
}

impl Default for SignatureConfig {
    fn default() -> Self {
        Self {
            flow: FlowConfig::default(),
            reduction: Reduction::default(),
            trim: DEFAULT_TRIM,
            stamping: Stamping::default(),
            max_gap_ns: 250_000_000,
            dejitter: true,
            normalise: true,
        }
    }
}

impl SignatureConfig {
    /// Frame periods an interval may span before it is a gap, when that is
    /// longer than [`SignatureConfig::max_gap_ns`]: up to three dropped frames in
    /// a row, with room for jitter. (Under 7.5, so that at 30 Hz the 250 ms
    /// default decides.)
    pub const GAP_PERIODS: f64 = 4.5;

    /// Share of a confirmed frame period under which an interval gives no sample
    /// ([`StartReason::Bunched`]): no camera delivers two frames a quarter
    /// of a period apart, but a source that stamps at arrival may see two
    /// frames that were held up come together (a late dequeue, a pipe's writer
    /// that fell behind), and one frame's flow divided by such a sliver would be
    /// many times the true speed (0.5 ms at 30 Hz: 67 times). A run of them is
    /// held to the period before it until together they span it, so a backlog
    /// of frames delivered at once stays refused however long it is. A real
    /// change to over four times the rate is still followed: each such interval
    /// counts as one that disagrees with the period ([`FramePeriod::interval`]),
    /// so the fourth makes the new period, and samples resume once the new
    /// rate's intervals have lasted one old period.
    pub const SHORT_PERIODS: f64 = 0.25;

    /// Checks every field.
    pub fn validate(&self) -> Result<(), Error> {
        self.flow.validate()?;
        Reducer::new(self.reduction, self.trim)?;
        if self.max_gap_ns <= 0 {
            return Err(Error::InvalidConfig {
                field: "max_gap_ns",
                reason: format!("{} must be positive", self.max_gap_ns),
            });
        }
        Ok(())
    }
}

/// One camera signature sample with its diagnostics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CamSample {
    /// The sample: stamp per [`Stamping`], value in pixels per second.
    /// The value is NaN when no point was tracked (`stats.tracked == 0`).
    pub sample: Sample,
    /// Interval between the two frames compared, ns (> 0).
    pub dt_ns: Nanos,
    /// Interval the value was scaled by, ns: `dt_ns`, or a whole number of tracked
    /// frame periods with [`SignatureConfig::dejitter`].
    pub scale_dt_ns: f64,
    /// The reduced flow over that interval, pixels (NaN when no point was tracked).
    pub flow_px: f64,
    /// Point counts; `stats.low_texture` flags too few tracked points.
    pub stats: FlowStats,
}

impl CamSample {
    /// Too few points were tracked for the value to be trusted.
    pub fn low_texture(&self) -> bool {
        self.stats.low_texture
    }
}

/// Why a frame started a new sequence instead of producing a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StartReason {
    /// First frame (or first after [`SignatureProcessor::reset`] or an error).
    First,
    /// The interval from the previous frame exceeds the gap limit
    /// ([`SignatureConfig::max_gap_ns`], or more periods of a slow camera).
    Gap {
        /// The interval, ns.
        dt_ns: Nanos,
    },
    /// The frame time is not after the previous one.
    NotIncreasing {
        /// The interval, ns (<= 0).
        dt_ns: Nanos,
    },
    /// Once the frame period is confirmed, the frame time is after the previous
    /// one by less than [`SignatureConfig::SHORT_PERIODS`] of it: two frames'
    /// times bunched, no interval to scale a frame's flow by.
    Bunched {
        /// The interval, ns (under a quarter of the period).
        dt_ns: Nanos,
    },
    /// The frame size differs from the previous frame's.
    SizeChanged {
        /// Previous (width, height).
        from: (usize, usize),
        /// New (width, height).
        to: (usize, usize),
    },
}

/// The outcome of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    /// A sample for the interval ending at this frame.
    Sample(CamSample),
    /// No sample: this frame starts a new sequence.
    Started(StartReason),
}

/// Turns a stream of frames into camera signature samples.
#[derive(Debug, Clone)]
pub struct SignatureProcessor {
    cfg: SignatureConfig,
    lk: PyrLk,
    reducer: Reducer,
    prev_t: Option<Nanos>,
    period: FramePeriod,
    /// The previous sample's interval as scaled, ns (for the flow prediction; 0:
    /// none since the last start).
    prev_scale_dt: f64,
    /// Whole periods spanned by the last [`RECENT_SPANS`] intervals (a ring; 0:
    /// not yet filled): a camera that slowed to a whole fraction of its rate (30
    /// to 15 or 7.5 Hz) keeps its old period, each interval agreeing as 2 or 4 of
    /// them, and the gap limit counts in the fewest of them.
    recent_spans: [u8; RECENT_SPANS],
    recent_pos: usize,
    /// Frame size the reducer's learnt grid pattern belongs to.
    pattern_size: Option<(usize, usize)>,
    /// A run of bunched intervals: the confirmed period they are held to and
    /// their sum, ns (see [`SignatureProcessor::bunched`]).
    bunch: Option<(f64, Nanos)>,
}

/// Intervals whose fewest periods spanned scale the gap limit
/// ([`SignatureProcessor::gap_limit_ns`]).
const RECENT_SPANS: usize = 8;

/// Running estimate of a camera's frame period from its (jittered) stamps.
///
/// Each interval `dt` is matched to the nearest whole number `n` (1..=8) of
/// periods. It *agrees* when `dt` is within 30 % of one period of `n` periods:
/// it is then scaled as `n · period` and refines the period, a running mean over
/// the last ~64 agreeing intervals. Three disagreeing intervals in a row (a
/// change of rate by more than 30 %, or irregular timing) make the fourth the
/// new period.
///
/// A change of rate by less than 30 % (30 to 25 or 40 Hz, an automatic
/// exposure's) agrees interval by interval, so only the running mean follows it:
/// a step from 30 to 25 Hz is scaled 16 % short at first, 14 % after 9
/// intervals, 6 % after 63 and 2 % after 129 (30 to 40 Hz: 32 / 29 / 12 / 4 %
/// long). A faster rule (the third interval off to the same side by more than
/// the stamps' jitter makes the new period) was tried and not kept: stamps that
/// grow late for a few frames, as a loaded host's arrival stamps do (the pipe
/// source's), look the same for three intervals, and it turned each such ramp
/// into a false change of rate (stamps 2, 4, 6 ms late: the next samples 6.6 %
/// off, where the running mean stays within 0.3 %). Fix a V4L2 camera's rate
/// instead (README, "Front-ends").
///
/// ```
/// use vlsync_signature_cam::signature::FramePeriod;
/// let mut p = FramePeriod::default();
/// // 30 Hz with +-1 ms of stamp jitter; the third interval spans a dropped frame
/// for dt in [33_000_000, 34_200_000, 66_100_000, 32_400_000, 33_500_000] {
///     p.interval(dt);
/// }
/// assert!((p.period_ns() - 33_330_000.0).abs() < 300_000.0);
/// assert_eq!(p.interval(67_400_000).1, 2.0);
/// // 20 Hz (1.5 periods): three intervals disagree, the fourth is the period
/// for _ in 0..3 {
///     assert_eq!(p.interval(50_000_000).0, 50_000_000.0);
/// }
/// p.interval(50_000_000);
/// assert_eq!(p.period_ns(), 50_000_000.0);
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FramePeriod {
    period_ns: f64,
    /// Agreeing intervals in the running mean (at most `MEMORY`).
    count: u32,
    /// Disagreeing intervals in a row.
    misses: u32,
}

impl FramePeriod {
    /// Intervals averaged at most (the running mean becomes an exponential one).
    const MEMORY: u32 = 64;
    /// Largest deviation of one interval from a whole number of periods, as a
    /// share of one period.
    /// (1 ms of stamp jitter makes intervals at 30 Hz vary by 4 % rms, and
    /// 1 in 1000 by 15 %: a 15 % tolerance left those unscaled, 18 % off.)
    const TOLERANCE: f64 = 0.3;
    /// Consecutive disagreeing intervals that make the next one the new period.
    const MAX_MISSES: u32 = 3;
    /// Most periods one interval may span and still count as frame drops.
    const MAX_PERIODS: f64 = 8.0;

    /// The tracked period, ns (0 before the first interval).
    pub fn period_ns(&self) -> f64 {
        self.period_ns
    }

    /// The tracked period once an interval has agreed with it since it was
    /// adopted (`None` before: the first interval, or the one a change of rate
    /// made the period, may have been irregular).
    pub fn confirmed_period_ns(&self) -> Option<f64> {
        (self.count >= 2).then_some(self.period_ns)
    }

    /// Forgets the period.
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// Takes one positive interval `dt_ns` between consecutive frames and returns
    /// `(interval to scale by, periods spanned)`: `(n · period, n)` when `dt_ns` is
    /// within 30 % of one period of a whole number `n` (1..=8) of periods, else
    /// `(dt_ns, dt_ns / period)` (raw; the first interval, a changed rate or
    /// irregular timing). Agreeing intervals refine the period. An interval under
    /// half a period (`n = 0`) spans no whole period: it disagrees, is returned
    /// raw, and counts towards a change of rate like any other (the processor
    /// gives no sample for one under a quarter of a confirmed period,
    /// [`SignatureConfig::SHORT_PERIODS`], rather than scale a frame's flow by
    /// it). A `dt_ns <= 0` is returned as `(dt_ns, 0)` and changes nothing.
    pub fn interval(&mut self, dt_ns: Nanos) -> (f64, f64) {
        self.take(dt_ns, Self::MAX_PERIODS)
    }

    /// Takes an interval too long to be used (a gap: the caller restarts after
    /// it). It cannot be dropped frames, but it may be the camera's new, slower
    /// rate: it agrees only when within 30 % of *one* period, and otherwise
    /// counts as a disagreeing interval, so three gaps in a row make the fourth
    /// the new period. A `dt_ns <= 0` changes nothing.
    pub fn gap(&mut self, dt_ns: Nanos) {
        self.take(dt_ns, 1.0);
    }

    fn take(&mut self, dt_ns: Nanos, max_periods: f64) -> (f64, f64) {
        let dt = dt_ns as f64;
        if dt_ns <= 0 {
            // not an interval: changes nothing
            return (dt, 0.0);
        }
        if self.period_ns <= 0.0 || self.misses >= Self::MAX_MISSES {
            *self = Self {
                period_ns: dt,
                count: 1,
                misses: 0,
            };
            return (dt, 1.0);
        }
        let n = (dt / self.period_ns).round();
        // the tolerance applies to the interval, not to the period it implies:
        // 1.5 periods is a miss, not two periods 25 % short; so is an interval
        // under half a period (n = 0), though within 30 % of a period of none:
        // returned raw, it may be a faster rate's (three of them adopt it)
        if (1.0..=max_periods).contains(&n)
            && (dt - n * self.period_ns).abs() <= Self::TOLERANCE * self.period_ns
        {
            let r = dt / n - self.period_ns;
            self.count = (self.count + 1).min(Self::MEMORY);
            self.period_ns += r / f64::from(self.count);
            self.misses = 0;
            return (n * self.period_ns, n);
        }
        self.misses += 1;
        (dt, dt / self.period_ns)
    }
}

impl SignatureProcessor {
    /// A processor; fails on an invalid configuration.
    pub fn new(cfg: SignatureConfig) -> Result<Self, Error> {
        cfg.validate()?;
        let mut reducer = Reducer::new(cfg.reduction, cfg.trim)?;
        reducer.reserve(cfg.flow.grid_cols * cfg.flow.grid_rows);
        Ok(Self {
            cfg,
            lk: PyrLk::new(cfg.flow)?,
            reducer,
            prev_t: None,
            period: FramePeriod::default(),
            prev_scale_dt: 0.0,
            recent_spans: [0; RECENT_SPANS],
            recent_pos: 0,
            pattern_size: None,
            bunch: None,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SignatureConfig {
        &self.cfg
    }

    /// The flow tracker (e.g. to read the vectors of the last sample).
    pub fn flow(&self) -> &PyrLk {
        &self.lk
    }

    /// Forgets the previous frame.
    pub fn reset(&mut self) {
        self.lk.reset();
        self.prev_t = None;
        self.prev_scale_dt = 0.0;
    }

    /// The longest interval a sample may span, ns: [`SignatureConfig::max_gap_ns`]
    /// or [`SignatureConfig::GAP_PERIODS`] confirmed frame periods, whichever is
    /// longer; the periods counted in the fewest whole periods the last 8
    /// intervals spanned, so that a camera slowed from 30 to 7.5 Hz (its intervals
    /// agreeing as 4 periods of 33 ms) gets the limit of 7.5 Hz.
    pub fn gap_limit_ns(&self) -> Nanos {
        let fewest = if self.recent_spans.contains(&0) {
            1
        } else {
            self.recent_spans.iter().copied().min().unwrap_or(1).max(1)
        };
        // `as` saturates: the limit stays within Nanos
        let periods = self.period.confirmed_period_ns().map_or(0, |p| {
            (SignatureConfig::GAP_PERIODS * f64::from(fewest) * p) as Nanos
        });
        self.cfg.max_gap_ns.max(periods)
    }

    /// An interval under [`SignatureConfig::SHORT_PERIODS`] of the confirmed
    /// frame period: two frames' times bunched, no interval to scale by. A run of
    /// them is held to the period confirmed before it until together they span
    /// that period: a backlog of buffers dequeued at once (eight in a
    /// millisecond) stays refused, where the period tracker adopts the fourth as
    /// a new rate and the fifth gave one frame's flow over a sliver; a camera
    /// that really sped up gives samples again once its frames have lasted one
    /// old period.
    fn bunched(&mut self, dt_ns: Nanos) -> bool {
        let held = self
            .bunch
            .filter(|&(period, sum)| (sum as f64) < period)
            .map(|(period, _)| period);
        let Some(period) = held.or_else(|| self.period.confirmed_period_ns()) else {
            self.bunch = None;
            return false;
        };
        if (dt_ns as f64) < SignatureConfig::SHORT_PERIODS * period {
            let sum = self.bunch.filter(|_| held.is_some()).map_or(0, |b| b.1);
            self.bunch = Some((period, sum.saturating_add(dt_ns)));
            true
        } else {
            self.bunch = None;
            false
        }
    }

    /// The frame period tracker (the period is kept across restarts).
    pub fn frame_period(&self) -> &FramePeriod {
        &self.period
    }

    /// Processes one frame taken at `time`. After the first frame of a given size
    /// this allocates nothing. On error the processor restarts with the next frame.
    pub fn process<T: Pixel>(
        &mut self,
        frame: &GrayFrame<'_, T>,
        time: FrameTime,
    ) -> Result<Step, Error> {
        let t = match time.instant_ns() {
            Ok(t) => t,
            Err(e) => {
                self.reset();
                return Err(e);
            }
        };
        let size = (frame.width(), frame.height());
        let prev_size = self.lk.frame_size();
        let reason = match self.prev_t {
            None => Some(StartReason::First),
            Some(_) if prev_size != Some(size) => Some(StartReason::SizeChanged {
                from: prev_size.unwrap_or((0, 0)),
                to: size,
            }),
            Some(p) => {
                let dt = i128::from(t) - i128::from(p);
                let dt_ns = dt.clamp(i128::from(Nanos::MIN), i128::from(Nanos::MAX)) as Nanos;
                if dt <= 0 {
                    Some(StartReason::NotIncreasing { dt_ns })
                } else if dt > i128::from(self.gap_limit_ns()) {
                    // not a sample, but maybe the camera's new, slower rate
                    self.period.gap(dt_ns);
                    self.bunch = None;
                    Some(StartReason::Gap { dt_ns })
                } else if self.bunched(dt_ns) {
                    // two times bunched (see SHORT_PERIODS): no sample, but taken as
                    // a disagreeing interval, so a camera that did speed up that
                    // much gets its new period
                    self.period.interval(dt_ns);
                    Some(StartReason::Bunched { dt_ns })
                } else {
                    None
                }
            }
        };
        // the interval this frame closes, in tracked periods (for the scale and
        // for the flow prediction: a dropped frame doubles the flow)
        let mut scaled = None;
        if let (None, Some(p)) = (reason, self.prev_t) {
            let (scale_dt, periods) = self.period.interval(t - p);
            // (a raw interval's share of a period rounds to a whole number too)
            self.recent_spans[self.recent_pos] = periods.round().clamp(1.0, 255.0) as u8;
            self.recent_pos = (self.recent_pos + 1) % RECENT_SPANS;
            // the ratio of the intervals themselves, not of their periods: the
            // interval that makes a new rate the period counts 1 period where the
            // same interval counted 1.5 of the old one just before (and thousands of
            // a backlog's sliver-sized period), though the frames came no closer
            if self.prev_scale_dt > 0.0 {
                self.lk
                    .set_prediction_scale((scale_dt / self.prev_scale_dt) as f32);
            }
            self.prev_scale_dt = scale_dt;
            scaled = Some(scale_dt);
        }
        if reason.is_some() {
            self.lk.reset();
            self.prev_scale_dt = 0.0;
        }
        // a pattern learnt on another frame size (also across a reset or an
        // error, after which the size change reads as a first frame) is void
        if self.pattern_size != Some(size) {
            if self.pattern_size.is_some() {
                self.reducer.reset_pattern();
            }
            self.pattern_size = Some(size);
        }
        let stats = match self.lk.push(frame) {
            Ok(s) => s,
            Err(e) => {
                self.prev_t = None;
                return Err(e);
            }
        };
        let prev = self.prev_t.replace(t);
        match (reason, stats, prev) {
            (None, Some(stats), Some(p)) => {
                let dt_ns = t - p; // 0 < dt <= gap limit <= Nanos::MAX: no overflow
                let reduced = if self.cfg.normalise {
                    self.reducer.reduce_grid(self.lk.grid(), size)
                } else {
                    self.reducer.reduce(self.lk.vectors(), size)
                };
                let flow_px = reduced.unwrap_or(f64::NAN);
                let t_ns = match self.cfg.stamping {
                    Stamping::Midpoint => p + dt_ns / 2,
                    Stamping::End => t,
                };
                let scale_dt_ns = match scaled {
                    Some(d) if self.cfg.dejitter => d,
                    _ => dt_ns as f64,
                };
                let value = flow_px * NANOS_PER_SEC as f64 / scale_dt_ns;
                Ok(Step::Sample(CamSample {
                    sample: Sample::new(t_ns, value),
                    dt_ns,
                    scale_dt_ns,
                    flow_px,
                    stats,
                }))
            }
            (Some(r), _, _) => Ok(Step::Started(r)),
            // the tracker had no previous frame although we had a time: treat as first
            _ => Ok(Step::Started(StartReason::First)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::tests::frame;

    const MS: Nanos = 1_000_000;

    fn shifted(dy: f32) -> GrayFrame<'static, f32> {
        frame(200, 150, move |x, y| (x, y - dy))
    }

    fn sample(step: Step) -> CamSample {
        match step {
            Step::Sample(s) => s,
            other => panic!("expected a sample, got {other:?}"),
        }
    }

    #[test]
    fn midpoint_and_end_stamping() {
        for (stamping, expect) in [
            (Stamping::Midpoint, 1_016 * MS),
            (Stamping::End, 1_032 * MS),
        ] {
            let cfg = SignatureConfig {
                stamping,
                ..SignatureConfig::default()
            };
            let mut p = SignatureProcessor::new(cfg).unwrap();
            p.process(&shifted(0.0), FrameTime::Instant(1_000 * MS))
                .unwrap();
            let s = sample(
                p.process(&shifted(1.0), FrameTime::Instant(1_032 * MS))
                    .unwrap(),
            );
            assert_eq!(s.sample.t_ns, expect);
            assert_eq!(s.dt_ns, 32 * MS);
        }
    }

    #[test]
    fn exposure_times_are_mid_exposure() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let e = |start_ms: i64, dur_ms: i64| FrameTime::Exposure {
            start_ns: start_ms * MS,
            duration_ns: dur_ms * MS,
        };
        p.process(&shifted(0.0), e(1_000, 10)).unwrap(); // mid 1005
        let s = sample(p.process(&shifted(1.0), e(1_030, 20)).unwrap()); // mid 1040
        assert_eq!(s.dt_ns, 35 * MS);
        assert_eq!(s.sample.t_ns, 1_022_500_000);
        assert!(matches!(
            p.process(&shifted(0.0), e(1_100, -1)),
            Err(Error::BadFrameTime { .. })
        ));
    }

    #[test]
    fn value_is_pixels_per_second_independent_of_frame_drops() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        // 60 px/s: 2 px per 33.3 ms frame; frame 2 is dropped, so 1->3 spans 4 px
        let frames = [(0.0, 0), (2.0, 33_333_333), (6.0, 100_000_000)];
        let mut values = Vec::new();
        for (dy, t) in frames {
            if let Step::Sample(s) = p.process(&shifted(dy), FrameTime::Instant(t)).unwrap() {
                values.push(s.sample.value);
            }
        }
        assert_eq!(values.len(), 2);
        for v in values {
            assert!((v - 60.0).abs() < 1.5, "{v}");
        }
    }

    #[test]
    fn gaps_and_time_going_back_restart() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let f = shifted(0.0);
        assert_eq!(
            p.process(&f, FrameTime::Instant(0)).unwrap(),
            Step::Started(StartReason::First)
        );
        assert_eq!(
            p.process(&f, FrameTime::Instant(300 * MS)).unwrap(),
            Step::Started(StartReason::Gap { dt_ns: 300 * MS })
        );
        assert_eq!(
            p.process(&f, FrameTime::Instant(300 * MS)).unwrap(),
            Step::Started(StartReason::NotIncreasing { dt_ns: 0 })
        );
        let s = sample(p.process(&f, FrameTime::Instant(330 * MS)).unwrap());
        assert_eq!(s.sample.value, 0.0);
        let g = frame(180, 150, |x, y| (x, y));
        assert_eq!(
            p.process(&g, FrameTime::Instant(360 * MS)).unwrap(),
            Step::Started(StartReason::SizeChanged {
                from: (200, 150),
                to: (180, 150)
            })
        );
        // extreme stamps do not overflow
        assert!(matches!(
            p.process(&g, FrameTime::Instant(i64::MIN)).unwrap(),
            Step::Started(StartReason::NotIncreasing { .. })
        ));
        assert!(matches!(
            p.process(&g, FrameTime::Instant(i64::MAX)).unwrap(),
            Step::Started(StartReason::Gap { dt_ns: i64::MAX })
        ));
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(32))]
        /// Any start time and any interval up to the gap limit: the midpoint (or the
        /// end) exactly, and the px/s value scales with 1 / interval.
        #[test]
        fn stamps_are_exact_for_any_times(
            t0 in -4_000_000_000_000_000_000i64..4_000_000_000_000_000_000i64,
            dt in 1i64..=250_000_000,
            end in proptest::bool::ANY,
        ) {
            use std::sync::OnceLock;
            static FRAMES: OnceLock<(GrayFrame<'static, f32>, GrayFrame<'static, f32>)> = OnceLock::new();
            let (a, b) = FRAMES.get_or_init(|| (shifted(0.0), shifted(1.0)));
            let stamping = if end { Stamping::End } else { Stamping::Midpoint };
            let mut p = SignatureProcessor::new(SignatureConfig { stamping, ..SignatureConfig::default() }).unwrap();
            p.process(a, FrameTime::Instant(t0)).unwrap();
            let s = sample(p.process(b, FrameTime::Instant(t0 + dt)).unwrap());
            let expect = if end { t0 + dt } else { t0 + dt / 2 };
            proptest::prop_assert_eq!(s.sample.t_ns, expect);
            proptest::prop_assert!((s.sample.value * dt as f64 / 1e9 - s.flow_px).abs() < 1e-9 * s.flow_px.abs().max(1.0));
            proptest::prop_assert!((s.flow_px - 1.0).abs() < 0.05);
        }
    }

    #[test]
    fn stamp_jitter_does_not_become_value_noise() {
        // 2 px down per true 33.3 ms frame, stamps jittered by up to ±1.5 ms,
        // every 7th frame dropped: with dejitter the values are 60 px/s to the
        // flow's own precision, without they scatter by the jitter (~4 %)
        let spread = |dejitter| {
            let mut p = SignatureProcessor::new(SignatureConfig {
                dejitter,
                ..SignatureConfig::default()
            })
            .unwrap();
            let mut x = 7u64;
            let mut values = Vec::new();
            for k in 0..120i64 {
                if k % 7 == 3 {
                    continue;
                }
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let jitter = (x % 3_000_001) as i64 - 1_500_000;
                let t = 1_000 * MS + k * 33_333_333 + jitter;
                if let Step::Sample(s) = p
                    .process(&shifted(2.0 * k as f32), FrameTime::Instant(t))
                    .unwrap()
                {
                    values.push(s.sample.value);
                }
            }
            let tail = &values[20..];
            let m = tail.iter().sum::<f64>() / tail.len() as f64;
            let sd = (tail.iter().map(|v| (v - m).powi(2)).sum::<f64>() / tail.len() as f64).sqrt();
            (m, sd)
        };
        let (m, sd) = spread(true);
        assert!((m - 60.0).abs() < 0.3 && sd < 0.3, "dejittered {m} {sd}");
        let (m0, sd0) = spread(false);
        assert!((m0 - 60.0).abs() < 1.0 && sd0 > 4.0 * sd, "raw {m0} {sd0}");
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// Any frame rate, jitter up to ±3 % of the period and drops of up to 3
        /// frames: the period is learnt to 0.5 %, each interval gets its true
        /// number of periods and a scale within 1 % of the true interval.
        #[test]
        fn frame_period_follows_jittered_stamps(
            period in 1_000_000i64..200_000_000,
            seed in proptest::prelude::any::<u64>(),
        ) {
            let mut fp = FramePeriod::default();
            let mut x = seed | 1;
            let mut next = || { x ^= x << 13; x ^= x >> 7; x ^= x << 17; x };
            let jit = |r: u64| ((r % 2001) as f64 / 1000.0 - 1.0) * 0.03 * period as f64;
            let mut k = 0i64;
            let mut prev = jit(next());
            for i in 0..200 {
                let span = if next() % 5 == 0 { 1 + (next() % 3) as i64 } else { 1 };
                k += span;
                let now = k as f64 * period as f64 + jit(next());
                let (scale, n) = fp.interval((now - prev).round() as i64);
                prev = now;
                if i >= 30 {
                    proptest::prop_assert_eq!(n, span as f64);
                    let truth = (span * period) as f64;
                    proptest::prop_assert!((scale - truth).abs() <= 0.01 * truth, "{} vs {}", scale, truth);
                }
            }
            proptest::prop_assert!((fp.period_ns() / period as f64 - 1.0).abs() < 0.005);
        }
    }

    #[test]
    fn frame_period_adopts_a_new_rate() {
        let mut fp = FramePeriod::default();
        for _ in 0..50 {
            fp.interval(33_333_333);
        }
        // a 28 ms interval (5 ms of jitter) is still one period
        assert_eq!(fp.interval(28_000_000).1, 1.0);
        // the camera speeds up to 50 Hz (0.6 periods: no whole number): three
        // raw intervals, then the new period
        for _ in 0..3 {
            let (scale, n) = fp.interval(20_000_000);
            assert!(
                scale == 20_000_000.0 && (n - 0.6).abs() < 0.01,
                "{scale} {n}"
            );
        }
        assert_eq!(fp.interval(20_000_000), (20_000_000.0, 1.0));
        assert_eq!(fp.interval(40_000_000), (40_000_000.0, 2.0));
        assert!((fp.period_ns() - 20_000_000.0).abs() < 1.0);
        fp.reset();
        assert_eq!(fp.period_ns(), 0.0);
        // 30 Hz slowing to 20 Hz (auto-exposure): 1.5 periods is not two short
        // ones; three raw intervals, then the new period
        for _ in 0..50 {
            fp.interval(33_333_333);
        }
        for _ in 0..3 {
            let (scale, n) = fp.interval(50_000_000);
            assert!(
                scale == 50_000_000.0 && (n - 1.5).abs() < 0.01,
                "{scale} {n}"
            );
        }
        assert_eq!(fp.interval(50_000_000), (50_000_000.0, 1.0));
        assert!((fp.period_ns() - 50_000_000.0).abs() < 1.0);
    }

    /// xorshift64: uniform in `-a..=a` ns.
    fn jitter(x: &mut u64, a: i64) -> i64 {
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        if a == 0 {
            0
        } else {
            (*x % (2 * a as u64 + 1)) as i64 - a
        }
    }

    /// 30 Hz for 200 frames, then `new_ns` frames, stamps jittered by ±`jit`:
    /// `scale / true interval` of each interval after the step.
    fn rate_step(new_ns: i64, jit: i64, seed: u64) -> Vec<f64> {
        let mut fp = FramePeriod::default();
        let mut x = seed | 1;
        let mut truth = 0i64;
        let mut prev = jitter(&mut x, jit);
        let mut out = Vec::new();
        for k in 0..400 {
            let step = if k < 200 { 33_333_333 } else { new_ns };
            truth += step;
            let now = truth + jitter(&mut x, jit);
            let (scale, _) = fp.interval(now - prev);
            prev = now;
            if k >= 200 {
                out.push(scale / step as f64);
            }
        }
        out
    }

    #[test]
    fn frame_period_follows_a_rate_change_within_the_tolerance_by_its_mean() {
        // 30 -> 25 Hz (1.2 periods) and 30 -> 40 Hz (0.75 periods) both agree
        // with one period: only the running mean follows them, as the type's
        // docs give (interval 2 / 9 / 63 / 129 after the step)
        for (new, want) in [
            // 25 Hz: 40 ms intervals, scaled short; 40 Hz: 25 ms, scaled long
            (40_000_000, [0.841, 0.858, 0.939, 0.978]),
            (25_000_000, [1.318, 1.285, 1.122, 1.043]),
        ] {
            let r = rate_step(new, 0, 1);
            for (k, w) in [2, 9, 63, 129].into_iter().zip(want) {
                assert!((r[k] - w).abs() < 0.005, "{new}: interval {k}: {}", r[k]);
            }
        }
    }

    #[test]
    fn stamps_growing_late_for_a_few_frames_leave_the_period() {
        // a loaded host's arrival stamps: 2, 4, 6 ms late, then on time (or 2 to
        // 8 ms), every 20 frames; no sample is scaled more than 0.5 % off (a rule
        // adopting a rate from three one-sided intervals made 6.6 %). Larger
        // ramps, 4 to 16 ms every 20 frames, bias the running mean by up to 3 %:
        // their return to time is no agreeing interval
        for (step, len) in [(2_000_000i64, 3i64), (2_000_000, 4)] {
            let p = 33_333_333i64;
            let mut fp = FramePeriod::default();
            let mut prev = 0i64;
            let mut worst = 0.0f64;
            for k in 1..3_000i64 {
                let phase = k % 20;
                let late = if (1..=len).contains(&phase) {
                    phase * step
                } else {
                    0
                };
                let now = k * p + late;
                let (scale, n) = fp.interval(now - prev);
                prev = now;
                if k > 100 && n == 1.0 {
                    worst = worst.max((scale / p as f64 - 1.0).abs());
                }
            }
            assert!(worst < 0.005, "{step} x {len}: {worst}");
        }
    }

    #[test]
    fn frame_period_holds_under_jitter_drops_and_late_stamps() {
        // 30 Hz, stamps jittered by ±1, ±2 or ±3 ms, 1 in 6 intervals spanning
        // a dropped frame, 1 in 10 two, and 1 stamp in 50 another 8 or 4 ms late
        // (a host hiccup; within the 10 ms tolerance with the jitter): the period
        // stays within 1 % (±3 ms: 1.5 %, the running mean being 1.1 % off at
        // worst there) and every interval gets its whole number of periods
        for (jit, hiccup, bound, seed) in [
            (1_000_000, 8_000_000, 0.01, 11),
            (2_000_000, 4_000_000, 0.01, 12),
            (3_000_000, 4_000_000, 0.015, 13),
            (3_000_000, 4_000_000, 0.015, 14),
        ] {
            let p = 33_333_333i64;
            let mut fp = FramePeriod::default();
            let mut x = seed;
            let mut k = 0i64;
            let mut prev = 0;
            let mut worst = 0.0f64;
            for i in 0..5_000 {
                let r = jitter(&mut x, 1000).rem_euclid(60);
                let span = if r < 10 {
                    2
                } else if r < 16 {
                    3
                } else {
                    1
                };
                k += span;
                let late = if jitter(&mut x, 1000).rem_euclid(50) == 0 {
                    hiccup
                } else {
                    0
                };
                let now = k * p + jitter(&mut x, jit) + late;
                let (_, n) = fp.interval(now - prev);
                prev = now;
                if i >= 30 {
                    assert_eq!(n, span as f64, "±{jit}: interval {i}");
                    worst = worst.max((fp.period_ns() / p as f64 - 1.0).abs());
                }
            }
            assert!(worst < bound, "±{jit}: period off by {worst}");
        }
    }

    #[test]
    fn a_frame_rate_step_beyond_the_tolerance_is_followed_in_a_few_frames() {
        // 60 px/s, 30 Hz then 20 Hz (1.5 periods) or 60 Hz (0.5): the first three
        // intervals at the new rate are scaled by their raw length, the fourth
        // becomes the period; every value within 2 % of the true speed
        for new in [50_000_000i64, 16_666_667] {
            let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
            let mut t = 1_000 * MS;
            let mut values = Vec::new();
            for k in 0..60 {
                if k > 0 {
                    t += if k < 40 { 33_333_333 } else { new };
                }
                let dy = (t - 1_000 * MS) as f32 * 60e-9;
                if let Step::Sample(s) = p.process(&shifted(dy), FrameTime::Instant(t)).unwrap() {
                    values.push((k, s.sample.value));
                }
            }
            assert!(values.len() > 50, "{new}: {values:?}");
            for &(k, v) in &values {
                assert!((v / 60.0 - 1.0).abs() < 0.02, "{new}: frame {k}: {v}");
            }
            assert!((p.frame_period().period_ns() - new as f64).abs() < 1e3);
        }
    }

    #[test]
    fn bunched_frame_times_give_no_sample_not_a_spike() {
        // 60 px/s at 30 Hz (2 px a frame); frame 30 held up and stamped 0.5 ms
        // before frame 31, on time: one frame's flow over 0.5 ms would be
        // 4000 px/s. The bunched interval restarts (`StartReason::Bunched`);
        // every value is the true speed's, but frame
        // 30's (stamped late: half of it)
        let p_ns = 33_333_333i64;
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let mut steps = Vec::new();
        for k in 0..50i64 {
            let t = if k == 30 {
                31 * p_ns - 500_000
            } else {
                k * p_ns
            };
            let step = p
                .process(&shifted(2.0 * k as f32), FrameTime::Instant(t))
                .unwrap();
            steps.push(step);
        }
        assert_eq!(
            steps[31],
            Step::Started(StartReason::Bunched { dt_ns: 500_000 })
        );
        for (k, s) in steps.iter().enumerate().skip(1) {
            match s {
                // frame 30's late stamp makes 29 to 30 two periods: half the speed
                Step::Sample(s) if k == 30 => {
                    assert!((s.sample.value / 30.0 - 1.0).abs() < 0.02, "{s:?}")
                }
                Step::Sample(s) => {
                    assert!((s.sample.value / 60.0 - 1.0).abs() < 0.02, "{k}: {s:?}")
                }
                other => assert_eq!(k, 31, "{other:?}"),
            }
        }
        // the period is left as it was (but for frame 30's late stamp, which
        // agreed as two periods 0.5 ms short)
        assert!((p.frame_period().period_ns() - p_ns as f64).abs() < 2e4);
        // without dejitter too: the raw interval would divide alike
        let mut p = SignatureProcessor::new(SignatureConfig {
            dejitter: false,
            ..SignatureConfig::default()
        })
        .unwrap();
        for k in 0..31i64 {
            p.process(&shifted(2.0 * k as f32), FrameTime::Instant(k * p_ns))
                .unwrap();
        }
        let t = 30 * p_ns + 2 * MS;
        assert_eq!(
            p.process(&shifted(62.0), FrameTime::Instant(t)).unwrap(),
            Step::Started(StartReason::Bunched { dt_ns: 2 * MS })
        );
    }

    #[test]
    fn a_camera_that_speeds_up_past_a_quarter_period_gives_samples_again() {
        // 30 Hz, then 150 Hz (a fifth of the period, under the quarter): the
        // first five fast intervals (one old period) give no sample, the fourth
        // making the new period, and from the sixth on every value is the true
        // 120 px/s
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let mut t = 0;
        for k in 0..70 {
            if k > 0 {
                t += if k < 40 { 33_333_333 } else { 6_666_667 };
            }
            let step = p
                .process(&shifted(t as f32 * 120e-9), FrameTime::Instant(t))
                .unwrap();
            match k {
                0 => assert_eq!(step, Step::Started(StartReason::First)),
                40..=44 => assert!(
                    matches!(step, Step::Started(StartReason::Bunched { .. })),
                    "{k}: {step:?}"
                ),
                _ => {
                    let v = sample(step).sample.value;
                    assert!((v / 120.0 - 1.0).abs() < 0.03, "{k}: {v}");
                }
            }
        }
        assert!((p.frame_period().period_ns() - 6_666_667.0).abs() < 1e3);
    }

    #[test]
    fn a_backlog_of_frames_delivered_at_once_gives_no_sample_however_long() {
        // 30 Hz, then eight buffers dequeued within a millisecond (a driver held
        // up 250 ms): every one of the seven slivers is refused (the period
        // tracker adopts the fourth as a rate, which let the fifth through), and
        // the camera's own rate gives samples again after it
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let p_ns = 33_333_333i64;
        let mut t = 0;
        let mut values = vec![];
        for k in 0..60 {
            if k > 0 {
                t += match k {
                    30 => 250_000_000,
                    31..=37 => 140_000,
                    _ => p_ns,
                };
            }
            // the camera captures at its own rate; the stamps are the late ones
            let captured = k as f32 * p_ns as f32;
            let step = p
                .process(&shifted(captured * 60e-9), FrameTime::Instant(t))
                .unwrap();
            match (k, step) {
                (31..=37, s) => assert!(
                    matches!(s, Step::Started(StartReason::Bunched { .. })),
                    "{k}: {s:?}"
                ),
                (_, Step::Sample(s)) => values.push((k, s.sample.value)),
                _ => {}
            }
        }
        assert!(values.iter().all(|&(_, v)| v < 200.0), "{values:?}");
        assert!(values.iter().any(|&(k, _)| k > 45), "{values:?}");
    }

    #[test]
    fn fast_motion_stays_tracked_when_the_period_is_adopted_after_a_backlog() {
        // 36 px a frame, beyond the 28 px the pyramid reaches from zero: every pair
        // is tracked from its prediction. After a backlog the tracker adopts a
        // sliver as the period, and the interval that adopts the camera's own rate
        // again counted 1 period after 3 that counted some 240: a prediction scale
        // of 1/240, every point started from nothing. The intervals themselves are
        // equal, and so is the scale
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let p_ns = 33_333_333i64;
        let mut t = 0;
        let mut tracked = vec![];
        for k in 0..50 {
            if k > 0 {
                t += match k {
                    30 => 250_000_000,
                    31..=37 => 140_000,
                    _ => p_ns,
                };
            }
            let dx = 36.0 * k as f32;
            let f = crate::flow::tests::grain_frame(360, 240, move |x, y| (x + dx, y));
            if let Step::Sample(s) = p.process(&f, FrameTime::Instant(t)).unwrap() {
                tracked.push((k, s.stats.tracked, s.stats.points));
            }
        }
        assert!(tracked.iter().any(|&(k, _, _)| k == 41), "{tracked:?}");
        for &(k, n, of) in tracked.iter().filter(|&&(k, _, _)| k > 39) {
            assert!(n * 2 > of, "frame {k}: {n} of {of} points tracked");
        }
    }

    #[test]
    fn frame_period_takes_an_interval_under_half_a_period_as_a_miss() {
        let mut fp = FramePeriod::default();
        for _ in 0..50 {
            fp.interval(33_333_333);
        }
        // no whole number of periods (n = 0): raw, the period unchanged, and an
        // agreeing interval after it clears the miss
        assert_eq!(fp.interval(500_000), (500_000.0, 500_000.0 / 33_333_333.0));
        assert_eq!(fp.period_ns(), 33_333_333.0);
        assert_eq!(fp.interval(33_333_333).1, 1.0);
        // three in a row make the fourth the period (a camera that sped up)
        for _ in 0..3 {
            assert!(fp.interval(8_000_000).1 < 0.5);
        }
        assert_eq!(fp.interval(8_000_000), (8_000_000.0, 1.0));
        assert_eq!(fp.confirmed_period_ns(), None);
        assert_eq!(fp.interval(8_000_000).1, 1.0);
        assert_eq!(fp.confirmed_period_ns(), Some(8_000_000.0));
    }

    #[test]
    fn slow_cameras_give_samples_and_survive_dropped_frames() {
        // (frame period, dropped frames): 3 Hz and 3.75 Hz (over the 250 ms
        // limit), 7.5 Hz with 1 and 3 dropped frames in a row; stamps jittered
        // by up to ±3 ms
        let run = |period: i64, drop: &[i64]| {
            let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
            let (mut samples, mut gaps) = (Vec::new(), 0);
            for k in 0..20i64 {
                if drop.contains(&k) {
                    continue;
                }
                match p
                    .process(
                        &shifted(k as f32),
                        FrameTime::Instant(k * period + (k * 7919 % 7 - 3) * MS),
                    )
                    .unwrap()
                {
                    Step::Sample(s) => samples.push(s),
                    Step::Started(StartReason::Gap { .. }) => gaps += 1,
                    Step::Started(r) => assert_eq!(r, StartReason::First),
                }
            }
            (samples, gaps)
        };
        for period in [333_333_333, 266_666_667] {
            let (samples, gaps) = run(period, &[]);
            // the first two intervals restart (the period is not yet confirmed)
            assert_eq!((samples.len(), gaps), (17, 2), "{period}");
            for s in &samples {
                // 1 px per frame
                let want = 1e9 / period as f64;
                assert!(
                    (s.sample.value / want - 1.0).abs() < 0.02,
                    "{period}: {s:?}"
                );
            }
        }
        let (samples, gaps) = run(133_333_333, &[5]);
        assert_eq!((samples.len(), gaps), (18, 0));
        assert!(samples
            .iter()
            .all(|s| (s.sample.value / 7.5 - 1.0).abs() < 0.02));
        let (samples, gaps) = run(133_333_333, &[5, 6, 7]);
        assert_eq!((samples.len(), gaps), (16, 0));
        // over 4.5 periods is a gap: 4 dropped frames in a row restart
        let (samples, gaps) = run(133_333_333, &[5, 6, 7, 8]);
        assert_eq!((samples.len(), gaps), (14, 1));
    }

    #[test]
    fn at_30_hz_the_gap_limit_is_still_250_ms() {
        for (gap, restarts) in [
            (250 * MS, false),
            (251 * MS, true),
            (33_333_333 + 250 * MS, true),
            (300 * MS, true),
        ] {
            let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
            let mut t = 0;
            for k in 0..40 {
                t += 33_333_333;
                p.process(&shifted(k as f32), FrameTime::Instant(t))
                    .unwrap();
            }
            assert_eq!(p.gap_limit_ns(), 250 * MS);
            t += gap;
            let step = p.process(&shifted(40.0), FrameTime::Instant(t)).unwrap();
            assert_eq!(
                step == Step::Started(StartReason::Gap { dt_ns: gap }),
                restarts,
                "{gap}: {step:?}"
            );
            // and the rate is unchanged after it
            t += 33_333_333;
            sample(p.process(&shifted(41.0), FrameTime::Instant(t)).unwrap());
            assert!((p.frame_period().period_ns() - 33_333_333.0).abs() < 1e5);
        }
    }

    #[test]
    fn a_camera_that_slows_down_past_the_gap_limit_gives_samples_again() {
        // 30 Hz, then 3 Hz: three gaps change the rate, the fifth slow interval
        // confirms it, samples from the sixth
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let mut t = 0;
        let mut steps = Vec::new();
        for k in 0..40 {
            t += if k < 30 { 33_333_333 } else { 333_333_333 };
            let dy = if k < 30 {
                k as f32 * 0.2
            } else {
                6.0 + (k - 29) as f32 * 2.0
            };
            steps.push(p.process(&shifted(dy), FrameTime::Instant(t)).unwrap());
        }
        for (k, s) in steps.iter().enumerate().skip(1) {
            let gap = matches!(s, Step::Started(StartReason::Gap { .. }));
            assert_eq!(gap, (30..35).contains(&k), "frame {k}: {s:?}");
        }
        for s in &steps[35..] {
            let v = sample(*s).sample.value;
            assert!((v / 6.0 - 1.0).abs() < 0.02, "{v}");
        }
        let period = p.frame_period().period_ns();
        assert!((period - 333_333_333.0).abs() < 1.0, "{period}");
        assert_eq!(p.gap_limit_ns(), (4.5 * period) as Nanos);
    }

    #[test]
    fn a_camera_slowed_to_a_whole_fraction_of_its_rate_gets_that_rates_gap_limit() {
        // 30 Hz, then 7.5 Hz (each interval agrees as 4 periods of 33 ms, which
        // stays the period), then a dropped frame (266 ms, over the 250 ms): after
        // 8 slow intervals the limit is 4.5 x 4 periods, so no restart, and every
        // value is the true 60 px/s
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let mut t = 0;
        let mut steps = Vec::new();
        for k in 0..60 {
            t += match k {
                0..30 => 33_333_333,
                50 => 266_666_667,
                _ => 133_333_333,
            };
            let dy = t as f32 * 60e-9;
            steps.push((k, p.process(&shifted(dy), FrameTime::Instant(t)).unwrap()));
        }
        let period = p.frame_period().period_ns();
        assert!((period - 33_333_333.0).abs() < 1e3, "{period}");
        assert_eq!(p.gap_limit_ns(), (4.5 * 4.0 * period) as Nanos);
        for (k, s) in &steps[1..] {
            let v = sample(*s).sample.value;
            assert!((v / 60.0 - 1.0).abs() < 0.02, "frame {k}: {v}");
        }
        // back at 30 Hz, the limit is 250 ms again once 8 intervals span one period
        for _ in 0..8 {
            t += 33_333_333;
            let _ = p.process(&shifted(t as f32 * 60e-9), FrameTime::Instant(t));
        }
        assert_eq!(p.gap_limit_ns(), 250_000_000);
    }

    #[test]
    fn a_pattern_learnt_on_one_size_is_void_on_another_even_after_an_error() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        // flow that grows across the image (0.5 px/frame at the left, 2.5 at the
        // right): the learnt pattern is far from flat
        let sheared = |k: f32| frame(200, 150, move |x, y| (x, y - k * (0.5 + x / 100.0)));
        for k in 0..40 {
            let _ = p.process(&sheared(k as f32), FrameTime::Instant(k * 33 * MS));
        }
        assert!(
            p.reducer.pattern().iter().any(|&g| (g - 1.0).abs() > 0.1),
            "{:?}",
            p.reducer.pattern()
        );
        // a bad stamp restarts the processor; the next frame, of another size,
        // reads as a first frame, and the old pattern must not carry over
        let bad = FrameTime::Exposure {
            start_ns: 0,
            duration_ns: -1,
        };
        assert!(p.process(&sheared(40.0), bad).is_err());
        let small = frame(180, 150, |x, y| (x, y));
        assert_eq!(
            p.process(&small, FrameTime::Instant(2_000 * MS)).unwrap(),
            Step::Started(StartReason::First)
        );
        assert!(p.reducer.pattern().iter().all(|&g| g == 1.0));
    }

    #[test]
    fn flat_frames_give_flagged_nan() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let f = GrayFrame::owned(200, 150, vec![50u8; 200 * 150]).unwrap();
        p.process(&f, FrameTime::Instant(0)).unwrap();
        let s = sample(p.process(&f, FrameTime::Instant(33 * MS)).unwrap());
        assert!(s.low_texture());
        assert_eq!(s.stats.tracked, 0);
        assert!(s.sample.value.is_nan());
    }

    #[test]
    fn errors_restart() {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let tiny = GrayFrame::owned(4, 4, vec![0u8; 16]).unwrap();
        assert!(p.process(&tiny, FrameTime::Instant(0)).is_err());
        assert_eq!(
            p.process(&shifted(0.0), FrameTime::Instant(MS)).unwrap(),
            Step::Started(StartReason::First)
        );
        let bad = SignatureConfig {
            max_gap_ns: 0,
            ..SignatureConfig::default()
        };
        assert!(SignatureProcessor::new(bad).is_err());
    }
}
