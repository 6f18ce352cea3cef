//! Stamp cadence: the regular frame clock behind one stream's stamps, and the
//! steps of its stamping latency.
//!
//! A camera delivers frames at a fixed period of its own crystal, and a spinning
//! LiDAR its scans nearly so. A stamp is the frame's event time plus the latency of
//! the path that stamped it, so the stamps sit on a regular grid `a + n·T` (`n` the
//! frame's index: a dropped frame skips one) shifted by that latency: a little
//! jitter from frame to frame, and a *step* whenever the path's latency changes,
//! which is what CPU load does to a camera stamped in software after its
//! processing. An offset step from a load change therefore shows in the stamps of
//! the stream it delays, at once and to a fraction of a millisecond, while the
//! correlation needs seconds of motion to see it.
//!
//! [`Cadence`] learns the grid of a stream (its period by least squares over
//! [`LEARN`] stamps, dropped frames allowed), follows it, and splits the stream's
//! stamping latency into *pieces*: stretches of constant latency between two steps.
//! Every accepted stamp `s` becomes
//!
//! * the **internal stamp** the correlator sees: `s` less the level of its piece
//!   (the first piece's level is 0, so a stream without steps passes unchanged,
//!   jitter and all, but for its late frames); a stamp off the grid (a step's first
//!   samples, a late frame) goes to its frame's grid point instead, so neither
//!   reaches the correlation (one that disagrees with the off-grid stamp before it,
//!   a burst of stamps catching up after a stall, no later than its own stamp); and
//! * its **level** `s - internal`, kept in bins per piece. [`Cadence::level_at`]
//!   gives the level at any recent internal time (the mean of its piece's samples
//!   within [`LEVEL_HALF_WINDOW_NS`]), so an estimate adds back exactly the latency
//!   its stamps carried and stays `t_L - t_C` of the stamps as published.
//!
//! So the correlator sees an offset without the latency steps (its segment keeps
//! all its history across a load change), and a step is followed as soon as the
//! stamps show it: `confirm` frames. Camera samples stamped at the midpoint of two
//! frames sit half a period off the grid when the frame between was dropped; the
//! grid has points there too (in half frames), used only after a period and a half.
//!
//! **A step** is the newest `confirm` samples all off the current level, on one
//! side, by more than `max(min_step, 4σ)` (σ the stamps' jitter) and within
//! `max(that, half the step)` of each other; it is their median, and starts at the
//! first of them beyond half of it. A lone late stamp (a scheduling hiccup) is jitter, not a
//! step. Frames are unwrapped to the nearest grid point when a stamp is within
//! `max(min_step, 5σ)` of one (`4σ` when that means dropped frames), else with the
//! fewest drops: a latency change of less than a period. A step to later stamps
//! may instead have been a period less with a frame dropped at it; the departures
//! from the level just before it usually tell (one reading a period less settles
//! it), and what they leave open [`CadenceStep::ambiguity`] says: the estimator
//! then tests the step against that alternative with the data.
//!
//! **A stream that is not regular** (jitter above `T/15`, half its stamps off the
//! grid, a run of stamps off it that never settles into a step, a step of a period
//! or more) is passed through with its level frozen, and the grid is learnt again.
//! So is **a stream whose rate doubled**, at once: a second sample halfway between
//! two frames' points, with one on a frame's point between them (a LiDAR front-end
//! fitting the walls ahead and behind, whose stream goes from one sample a turn to
//! two when the second wall comes into range). Tracked on, each sample between two
//! frames would go to the next frame's point, half a period late.
//! A step's level is refined over [`LEVEL_SAMPLES`] samples, then fixed: slow
//! latency changes reach the correlator as they are (as drift), and the grid's fit,
//! which only tells stamps on it from stamps off it, follows them ([`FIT_MEMORY_S`]).
//!
//! Everything is in fixed-size buffers: nothing allocates.
//!
//! ```
//! use vlsync_estimator::cadence::{Cadence, CadenceParams, Kind};
//! let mut c = Cadence::new(CadenceParams::default());
//! let t = |k: i64| 1_000_000_000 + k * 33_333_333; // 30 Hz frames
//! let mut internal = Vec::new();
//! for k in 0..300 {
//!     // from frame 150 on, the stamps are 25 ms later (CPU load)
//!     let s = t(k) + if k >= 150 { 25_000_000 } else { 0 };
//!     internal.push(c.push(s, if k == 0 { Kind::First } else { Kind::Normal }));
//! }
//! assert!((internal[299] - t(299)).abs() < 1_000); // the correlator's stamp: on the grid
//! assert_eq!(c.steps(), 1);
//! let (before, _) = c.level_at(internal[140]);
//! let (after, _var) = c.level_at(internal[160]);
//! assert!(before.abs() < 1e3 && (after - 25e6).abs() < 1e3); // ns
//! ```

use vlsync_common::Nanos;

/// Samples the grid is learnt from.
pub const LEARN: usize = 32;
/// A step's level (what the stamps after it are measured against, and take off)
/// is the median of the samples that confirmed it, refined by the mean of this many
/// samples on the grid after it; then it is fixed (the first piece's is 0), and slow
/// latency changes reach the correlator as they are, as drift.
pub const LEVEL_SAMPLES: u32 = 64;
/// Memory of the grid's fit, seconds: long enough to hold the period to a few ppm,
/// short enough to follow a crystal's thermal drift and slow latency changes.
pub const FIT_MEMORY_S: f64 = 300.0;
/// [`Cadence::level_at`] averages the samples of the same piece within this of
/// the time asked for, ns (a piece's level is constant once refined: the window
/// only matters for a young one).
pub const LEVEL_HALF_WINDOW_NS: Nanos = 10_000_000_000;
/// Duration of the bins the levels are kept in, ns.
const BIN_NS: Nanos = 250_000_000;
/// Bins kept: 32 s (estimates refer a few seconds back).
const BINS: usize = 128;
/// Longest step-test window, and the most consecutive off-grid samples tolerated
/// before the grid is learnt again.
const PENDING: usize = 16;
// the configuration's largest `cadence_confirm` is what these buffers hold
const _: () = assert!(PENDING - 1 == vlsync_config::CADENCE_CONFIRM_MAX as usize);
/// Samples between re-anchorings of the fit's coordinates.
const REANCHOR: u32 = 256;
/// Samples after a step during which a return to the level before it is an
/// excursion's end ([`Cadence::excursion_back`]).
const EXCURSION_SAMPLES: u32 = 64;
/// Departures from the level remembered (see [`Cadence::try_step`]).
const TRANS: usize = 8;
/// How far back departures count for a step, ns.
const TRANS_NS: Nanos = 1_500_000_000;
/// Largest level (stamping latency relative to the grid's phase), ns.
const MAX_LEVEL_NS: f64 = 1e9;
/// Samples after a silence longer than the gap limit within which a step is read as a
/// new phase of the frames (a restarted driver), not as a change of latency.
const GAP_PHASE_SAMPLES: u32 = 16;

/// Settings of [`Cadence`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CadenceParams {
    /// Whether the stamps' cadence is used at all (false: every stamp passes
    /// through unchanged and the level stays 0).
    pub enabled: bool,
    /// Smallest latency step detected, and the least tolerance of the grid, ns.
    pub min_step_ns: f64,
    /// Consecutive samples that confirm a step.
    pub confirm: usize,
}

impl Default for CadenceParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_step_ns: 2e6,
            confirm: 3,
        }
    }
}

/// Where a tracked sample fell on the grid (the last two are kept).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Place {
    /// A frame's grid point.
    Frame,
    /// Halfway between two frames' points, less than a period and a half after the
    /// sample before.
    Between,
    /// Anywhere else, or not tracked.
    Other,
}

/// A latency step [`Cadence::push`] just found ([`Cadence::take_step`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CadenceStep {
    /// Internal stamp of its first sample.
    pub start: Nanos,
    /// The step of the stamping latency, ns (positive: the stamps came later).
    pub step_ns: f64,
    /// The grid's period, ns.
    pub period_ns: f64,
    /// The probability that the step was a period less, with a frame dropped at it
    /// (only a step to later stamps can be: its first stamp is then a frame later
    /// than it looks): the stream's share of dropped frames, to the power of the
    /// departures from the level just before that read the same step (each would
    /// have needed a drop of its own); 0 when it drops none or a departure read a
    /// period less (the step is then that).
    pub ambiguity: f64,
}

/// What the stream's validation said of a sample (see
/// [`crate::resample::Resampler::check`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The stream's first sample.
    First,
    /// The next sample.
    Normal,
    /// After a silence longer than the gap limit: the grid carries on, but a step
    /// within the next samples is read as a new phase of the frames (a restarted
    /// driver): the grid is learnt again, the level kept.
    Gap,
    /// After a clock jump: the grid is learnt again, the level kept.
    Reset,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Collecting stamps to learn the grid (they pass through, minus the level).
    Learn,
    /// On the grid.
    Track,
}

/// A sample in the step test's window.
#[derive(Debug, Clone, Copy, Default)]
struct Pend {
    /// Deviation from its grid point at the reference level, ns.
    dev: f64,
    /// What the step test measures: its deviation from the frames' grid (a midpoint
    /// stamp half a period off it counts half a period, unless it is one of a run two
    /// frames apart: every other frame dropped), ns.
    step_dev: f64,
    /// Its internal stamp.
    internal: Nanos,
    /// Its level, `stamp - internal`, ns.
    level: f64,
    /// Whether it was on the grid (within the tolerance).
    on: bool,
}

/// The levels of the samples of one piece within [`BIN_NS`].
#[derive(Debug, Clone, Copy, Default)]
struct Bin {
    /// Internal stamp of its first sample.
    start: Nanos,
    piece: u64,
    sum: f64,
    count: u32,
}

/// Exponentially weighted least-squares line `y = c + T·x` (x: frames since the
/// anchor, y: ns since the anchor's stamp).
#[derive(Debug, Clone, Copy, Default)]
struct Fit {
    sw: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
}

impl Fit {
    fn add(&mut self, lambda: f64, w: f64, x: f64, y: f64) {
        self.sw = lambda * self.sw + w;
        self.sx = lambda * self.sx + w * x;
        self.sy = lambda * self.sy + w * y;
        self.sxx = lambda * self.sxx + w * x * x;
        self.sxy = lambda * self.sxy + w * x * y;
    }

    /// `(c, T)`, when the line is determined.
    fn line(&self) -> Option<(f64, f64)> {
        let den = self.sw * self.sxx - self.sx * self.sx;
        if !(den > 0.0 && self.sw > 0.0) {
            return None;
        }
        let t = (self.sw * self.sxy - self.sx * self.sy) / den;
        let c = (self.sy - t * self.sx) / self.sw;
        (t.is_finite() && c.is_finite() && t > 0.0).then_some((c, t))
    }

    /// The same sums in coordinates moved by `dx` frames and `dy` ns.
    fn shift(&mut self, dx: f64, dy: f64) {
        let Fit {
            sw,
            sx,
            sy,
            sxx,
            sxy,
        } = *self;
        self.sxx = sxx - 2.0 * dx * sx + dx * dx * sw;
        self.sxy = sxy - dy * sx - dx * sy + dx * dy * sw;
        self.sx = sx - dx * sw;
        self.sy = sy - dy * sw;
    }
}

/// The cadence of one stream: see the [module docs](self).
#[derive(Debug, Clone)]
pub struct Cadence {
    p: CadenceParams,
    mode: Mode,
    /// Raw stamps collected while learning.
    learn: [Nanos; LEARN],
    learn_n: usize,
    /// Fit anchor: half-frame index and stamp.
    h0: i64,
    s0: Nanos,
    fit: Fit,
    /// The fit's line `(c, T)` in anchor coordinates.
    line: (f64, f64),
    /// Per-sample decay of the fit's weights.
    lambda: f64,
    since_anchor: u32,
    /// Half-frame index of the last sample (even: a frame's grid point; odd: the
    /// point halfway to the next, where a midpoint stamp spanning a dropped frame
    /// falls).
    h_last: i64,
    /// Robust jitter scale: 1.25 × the weighted mean absolute deviation, ns.
    sigma: f64,
    /// Weighted share of recent samples off the grid.
    off_rate: f64,
    /// Consecutive samples off the grid.
    back: usize,
    /// The step deviation of the last sample, when it was off the grid.
    last_off_dev: Option<f64>,
    /// The step deviation of the last sample.
    last_step_dev: f64,
    /// What the last two samples were, newest last: a frame's grid point, or
    /// halfway to the next one less than a period and a half after the sample
    /// before (the pattern of a rate that doubled, see [`Cadence::push_track`]).
    last_places: [Place; 2],
    /// For a while after a step: the level before it, and how many samples have come
    /// back to it in a row (a latency excursion of a few frames, not a step: see
    /// [`Cadence::excursion_back`]), and how many samples the chance has left.
    prev_level: Option<(f64, u32, u32)>,
    /// Weighted share of recent samples that came a frame or more late (a dropped
    /// frame before them).
    drop_rate: f64,
    /// The step found by the last push, until taken.
    new_step: Option<CadenceStep>,
    /// The newest departures from the level: `(internal stamp, deviation)` of each
    /// off-grid sample that followed one on the grid, newest at `trans_head`.
    trans: [(Nanos, f64); TRANS],
    trans_head: usize,
    trans_n: usize,
    /// Reference level (ns): what stamps are unwrapped and tested against and what
    /// the internal stamps take off; a step's is refined over `level_n` <
    /// [`LEVEL_SAMPLES`] samples after it.
    lref: f64,
    level_n: u32,
    /// The step test's window: the newest samples since the last step.
    pend: [Pend; PENDING],
    pend_n: usize,
    /// The current piece (counts the steps and relearns that started one).
    piece: u64,
    bins: [Bin; BINS],
    /// Index of the newest bin, and how many are valid.
    bin_head: usize,
    bin_n: usize,
    /// The last internal stamp given out (they strictly increase).
    last_internal: Option<Nanos>,
    steps: u64,
    relearns: u64,
    /// Samples left after a gap within which a step is a new phase
    /// ([`GAP_PHASE_SAMPLES`]).
    after_gap: u32,
}

impl Cadence {
    /// A cadence that has seen nothing yet.
    pub fn new(p: CadenceParams) -> Self {
        Self {
            p: CadenceParams {
                enabled: p.enabled,
                min_step_ns: if p.min_step_ns.is_finite() {
                    p.min_step_ns.clamp(1e3, 1e9)
                } else {
                    2e6
                },
                confirm: p.confirm.clamp(1, PENDING - 1),
            },
            mode: Mode::Learn,
            learn: [0; LEARN],
            learn_n: 0,
            h0: 0,
            s0: 0,
            fit: Fit::default(),
            line: (0.0, 1.0),
            lambda: 1.0,
            since_anchor: 0,
            h_last: 0,
            sigma: 0.0,
            off_rate: 0.0,
            back: 0,
            last_off_dev: None,
            last_step_dev: 0.0,
            last_places: [Place::Other; 2],
            prev_level: None,
            drop_rate: 0.0,
            new_step: None,
            trans: [(0, 0.0); TRANS],
            trans_head: 0,
            trans_n: 0,
            lref: 0.0,
            level_n: LEVEL_SAMPLES,
            pend: [Pend::default(); PENDING],
            pend_n: 0,
            piece: 0,
            bins: [Bin::default(); BINS],
            bin_head: 0,
            bin_n: 0,
            last_internal: None,
            steps: 0,
            relearns: 0,
            after_gap: 0,
        }
    }

    /// Latency steps detected so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Times the grid was learnt again (the stream was not regular enough, its clock
    /// jumped, or its frames came back at a new phase after a silence).
    pub fn relearns(&self) -> u64 {
        self.relearns
    }

    /// The step the last [`Cadence::push`] found, if any (taken once).
    pub fn take_step(&mut self) -> Option<CadenceStep> {
        self.new_step.take()
    }

    /// The stream's recent share of dropped frames (as the grid counts them).
    pub fn drop_rate(&self) -> f64 {
        self.drop_rate
    }

    /// Whether the stream is on a learnt grid (its steps are being followed).
    pub fn tracking(&self) -> bool {
        self.mode == Mode::Track
    }

    /// The grid's period, ns, once learnt.
    pub fn period_ns(&self) -> Option<f64> {
        (self.mode == Mode::Track).then_some(self.line.1)
    }

    /// The current reference level, ns: about `stamp - internal stamp` now.
    pub fn level(&self) -> f64 {
        self.lref
    }

    /// The stamping latency level (ns) at internal time `t`: the mean
    /// `stamp - internal stamp` of the samples of `t`'s piece within
    /// [`LEVEL_HALF_WINDOW_NS`] of it, and the variance of that mean (ns²). Outside
    /// the samples kept: the nearest ones'; before any sample: 0.
    pub fn level_at(&self, t: Nanos) -> (f64, f64) {
        if self.bin_n == 0 {
            return (self.lref, 0.0);
        }
        let at = |j: usize| &self.bins[(self.bin_head + BINS - j) % BINS];
        // the newest bin starting at or before t (or the oldest)
        let mut j0 = self.bin_n - 1;
        for j in 0..self.bin_n {
            if at(j).start <= t {
                j0 = j;
                break;
            }
        }
        let piece = at(j0).piece;
        let near = |b: &Bin| {
            let mid = b.start.saturating_add(BIN_NS / 2);
            b.piece == piece && mid.saturating_sub(t).saturating_abs() <= LEVEL_HALF_WINDOW_NS
        };
        let (mut sum, mut count) = (at(j0).sum, at(j0).count as f64);
        for j in (0..j0).rev() {
            let b = at(j);
            if !near(b) {
                break;
            }
            sum += b.sum;
            count += b.count as f64;
        }
        for j in j0 + 1..self.bin_n {
            let b = at(j);
            if !near(b) {
                break;
            }
            sum += b.sum;
            count += b.count as f64;
        }
        let count = count.max(1.0);
        (sum / count, self.sigma * self.sigma / count)
    }

    /// Takes one accepted stamp `s` (raw, on the sensor's clock, validated: it
    /// increases) and returns its internal stamp (strictly increasing, short of the
    /// ends of the i64 range, where it saturates; the resampler then restarts there).
    pub fn push(&mut self, s: Nanos, kind: Kind) -> Nanos {
        if !self.p.enabled {
            return s;
        }
        match kind {
            Kind::First | Kind::Reset => {
                if kind == Kind::Reset {
                    self.relearns += 1;
                }
                self.relearn();
                // a restarted stream starts over: nothing to keep monotonic against
                self.last_internal = None;
            }
            Kind::Gap => {
                // the grid carries on (the frames a stalled driver queued come back to
                // their grid points); but a stream that falls silent for longer than
                // the gap limit may have been restarted (a new capture stream, a driver
                // process started again, a LiDAR's motor spun up again) and come back
                // at a new phase of its frames, which is no change of latency: a step
                // found within its first samples after the silence relearns the grid,
                // the level kept (`try_step`). A latency step at the same time is then
                // left to the correlation's own step test, as for a stream without a
                // cadence.
                self.flush_window();
                self.back = 0;
                self.last_off_dev = None;
                self.last_places = [Place::Other; 2];
                if self.mode == Mode::Track {
                    self.after_gap = GAP_PHASE_SAMPLES;
                }
            }
            Kind::Normal => {}
        }
        let internal = match self.mode {
            Mode::Learn => self.push_learn(s),
            Mode::Track => self.push_track(s),
        };
        let internal = match self.last_internal {
            Some(last) if internal <= last => last.saturating_add(1),
            _ => internal,
        };
        self.last_internal = Some(internal);
        internal
    }

    /// Starts learning the grid again; the level stays (the internal stamps carry on
    /// without a jump).
    fn relearn(&mut self) {
        self.flush_window();
        self.last_places = [Place::Other; 2];
        self.mode = Mode::Learn;
        self.learn_n = 0;
        self.back = 0;
        self.last_off_dev = None;
        self.prev_level = None;
        self.after_gap = 0;
    }

    /// The window's samples on the grid go to the level bins (no step among them).
    fn flush_window(&mut self) {
        for j in 0..self.pend_n {
            let pd = self.pend[j];
            if pd.on {
                self.bin_add(pd.internal, pd.level);
            }
        }
        self.pend_n = 0;
    }

    fn bin_add(&mut self, internal: Nanos, level: f64) {
        let piece = self.piece;
        let b = &mut self.bins[self.bin_head];
        if self.bin_n > 0
            && b.piece == piece
            && internal >= b.start
            && internal < b.start.saturating_add(BIN_NS)
        {
            b.sum += level;
            b.count += 1;
            return;
        }
        if self.bin_n > 0 {
            self.bin_head = (self.bin_head + 1) % BINS;
        }
        self.bin_n = (self.bin_n + 1).min(BINS);
        self.bins[self.bin_head] = Bin {
            start: internal,
            piece,
            sum: level,
            count: 1,
        };
    }

    /// The stamp less the reference level.
    fn pass(&self, s: Nanos) -> Nanos {
        s.saturating_sub(self.lref.round() as Nanos)
    }

    fn push_learn(&mut self, s: Nanos) -> Nanos {
        if self.learn_n == LEARN {
            // a failed attempt: keep the newer half and try again when full
            self.learn.copy_within(LEARN / 2.., 0);
            self.learn_n = LEARN / 2;
        }
        self.learn[self.learn_n] = s;
        self.learn_n += 1;
        let internal = self.pass(s);
        self.bin_add(internal, s.saturating_sub(internal) as f64);
        if self.learn_n == LEARN {
            self.try_lock();
        }
        internal
    }

    /// Fits the grid to the learnt stamps; tracks from the next sample when they are
    /// regular enough.
    fn try_lock(&mut self) {
        let s = &self.learn[..self.learn_n];
        let m = s.len() - 1;
        let mut iv = [0i64; LEARN];
        for i in 0..m {
            iv[i] = s[i + 1].saturating_sub(s[i]);
        }
        let t0 = *iv[..m].select_nth_unstable(m / 2).1 as f64;
        if t0 <= 0.0 {
            return;
        }
        // unwrap in half periods (a dropped frame: about two periods; a midpoint
        // stamp spanning one: a period and a half)
        let mut h = [0i64; LEARN];
        for i in 1..s.len() {
            let d = s[i].saturating_sub(s[i - 1]) as f64;
            let k = (2.0 * d / t0).round();
            if !(1.0..=16.0).contains(&k) || (d - 0.5 * k * t0).abs() > 0.125 * t0 {
                return;
            }
            h[i] = h[i - 1] + k as i64;
        }
        if h[m] > 4 * m as i64 {
            return; // more drops than frames
        }
        // most stamps on the frames' grid points (even), the others halfway
        let odd = h[..s.len()].iter().filter(|&&x| x % 2 != 0).count();
        if 2 * odd > s.len() {
            for x in &mut h[..s.len()] {
                *x += 1;
            }
        }
        let last = s[m];
        let hm = h[m];
        let x = |i: usize| 0.5 * (h[i] - hm) as f64;
        let mut fit = Fit::default();
        for (i, &si) in s.iter().enumerate() {
            fit.add(1.0, 1.0, x(i), si.saturating_sub(last) as f64);
        }
        let Some((c, t)) = fit.line() else {
            return;
        };
        let mut dev = [0f64; LEARN];
        for (i, (d, &si)) in dev.iter_mut().zip(s).enumerate() {
            *d = (si.saturating_sub(last) as f64 - c - t * x(i)).abs();
        }
        let max = dev[..s.len()].iter().fold(0.0f64, |a, &b| a.max(b));
        let mad = *dev[..s.len()]
            .select_nth_unstable_by(s.len() / 2, f64::total_cmp)
            .1;
        let sigma = 1.4826 * mad;
        if sigma > t / 15.0 || max > self.tol_for(sigma).max(0.125 * t) {
            return;
        }
        // track: the fit over the learnt stamps, less the level they carry
        let lambda = (-t * 1e-9 / FIT_MEMORY_S).exp();
        self.h0 = hm;
        self.s0 = last;
        self.fit = Fit::default();
        for (i, &si) in s.iter().enumerate() {
            let y = si.saturating_sub(last) as f64 - self.lref;
            let w = lambda.powi((m - i) as i32);
            self.fit.add(1.0, w, x(i), y);
        }
        let Some(line) = self.fit.line() else {
            return;
        };
        self.line = line;
        self.lambda = lambda;
        self.since_anchor = 0;
        self.h_last = hm;
        self.sigma = sigma.max(1.0);
        self.off_rate = 0.0;
        self.pend_n = 0;
        self.back = 0;
        self.mode = Mode::Track;
    }

    /// The grid point of half-frame `h`, ns since the anchor's stamp.
    fn grid(&self, h: i64) -> f64 {
        self.line.0 + 0.5 * self.line.1 * h.saturating_sub(self.h0) as f64
    }

    fn abs(&self, rel: f64) -> Nanos {
        self.s0.saturating_add(rel.round() as Nanos)
    }

    fn tol_for(&self, sigma: f64) -> f64 {
        self.p.min_step_ns.max(5.0 * sigma)
    }

    fn push_track(&mut self, s: Nanos) -> Nanos {
        self.after_gap = self.after_gap.saturating_sub(1);
        let t = self.line.1;
        let rel = s.saturating_sub(self.s0) as f64 - self.lref;
        let from_last = rel - self.grid(self.h_last);
        // the sample's place in half frames
        let xq = self.h_last as f64 + 2.0 * from_last / t;
        if !xq.is_finite() || xq.abs() > 1e15 {
            self.relearns += 1;
            self.relearn();
            return self.push_learn(s);
        }
        let tol = self.tol_for(self.sigma).min(0.2 * t);
        if let Some(internal) = self.excursion_back(s, tol) {
            return internal;
        }
        // on the grid: a frame's point (normally the next frame, or one after
        // drops; after off-grid stamps also one already counted: a burst of stamps
        // after a stall was spread over the frames after it) ...
        let he = 2.0 * (0.5 * xq).round();
        let d_frame = (xq - he).abs() * 0.5 * t;
        let next = (self.h_last - self.h_last.rem_euclid(2) + 2) as f64;
        // a stamp after dropped frames, or back on time after a burst, is on the grid
        // as exactly as any other (a late stamp a period and a bit later is a step,
        // not a drop): 4σ, not the next frame's 5σ
        let tight = tol.min(self.p.min_step_ns.max(4.0 * self.sigma));
        let on_frame = if he == next {
            d_frame <= tol
        } else if he > next {
            d_frame <= tight.min(t / 6.0)
        } else {
            // a frame already counted (a burst after a stall was spread too far): only
            // a stamp back on its grid point, not one a fraction of a period off it
            // (under load, the way back from a latency excursion)
            he > (self.h_last - 2 * self.back as i64) as f64 && d_frame <= tight.min(t / 8.0)
        };
        // ... or halfway, where a midpoint stamp of two frames falls when the one
        // between was dropped: only after a period and a half (a stamp half a period
        // off the grid a period after the last is a step of the latency)
        let ho = 2.0 * (0.5 * xq).floor() + 1.0;
        let halfway = !on_frame && ho > self.h_last as f64 && (xq - ho).abs() * 0.5 * t <= tol;
        let on_half = halfway && from_last >= 1.5 * t - tol;
        let on = on_frame || on_half;
        // ... or halfway, but sooner: a sample between two frames. Alone it is a late
        // stamp or a step's first (moved to a frame's point below); between samples
        // on the frames' points it says the stream's rate doubled (a LiDAR front-end
        // measuring a second wall half a turn later; a stream stamped per frame back
        // to its full rate): the grid is learnt again at once, the stamps passing unchanged
        // meanwhile. Tracked on, every other sample would go to the next frame's point
        // half a period later (its share of off-grid samples settles just under the
        // half that makes a stream irregular).
        let between = halfway && !on_half;
        let place = if on_frame {
            Place::Frame
        } else if between {
            Place::Between
        } else {
            Place::Other
        };
        if place == Place::Between && self.last_places == [Place::Between, Place::Frame] {
            self.relearns += 1;
            self.relearn();
            return self.push_learn(s);
        }
        self.last_places = [self.last_places[1], place];
        let h = if on_frame {
            he as i64
        } else if on_half {
            ho as i64
        } else {
            // off the grid: a step or a late stamp, on the frames' grid with the
            // fewest drops
            let hf = self.h_last - self.h_last.rem_euclid(2);
            let q = (rel - self.grid(hf)) / t;
            hf.saturating_add(2 * q.floor().clamp(1.0, 1e12) as i64)
        };
        let dev = rel - self.grid(h);
        let dh = h.saturating_sub(self.h_last);
        // A midpoint stamp spanning one dropped frame sits half a period off the frames'
        // grid: alone it is no step, but stamps that stay half a period off while the
        // frames come every period are a step of half a period, which the step test must
        // see: a half point counts its half period when the sample before it was half a
        // period off too (a run of half points two frames apart, every other frame
        // dropped, is the samples' own timing).
        let half_run = self.last_step_dev.abs() >= 0.5 * t - tol;
        let step_dev = if on_half && dh < 4 && half_run {
            rel - self.grid(h.saturating_sub(1))
        } else {
            dev
        };
        self.last_step_dev = step_dev;
        let departs = !on && self.back == 0;
        // frames were dropped before this one: it is two frames or more after the last,
        // or lands on a frame's point a frame and a half after a midpoint stamp (the
        // midpoint that spanned the drop counts once, on the way back)
        let dropped = if dh >= 4 || (dh == 3 && h.rem_euclid(2) == 0) {
            1.0
        } else {
            0.0
        };
        self.drop_rate += (dropped - self.drop_rate) / 256.0;
        self.h_last = h;
        // an off-grid sample that does not agree with the one before (a burst of stamps
        // catching up after a stall, each earlier against its frame than the last) is
        // not moved later than its own stamp: the next frames are on time again
        let agrees = self
            .last_off_dev
            .is_some_and(|d| (step_dev - d).abs() <= tol);
        let inconsistent = !on && self.back > 0 && !agrees;
        self.last_off_dev = (!on).then_some(step_dev);
        if on {
            self.back = 0;
            self.off_rate -= self.off_rate / 32.0;
        } else {
            self.back += 1;
            self.off_rate += (1.0 - self.off_rate) / 32.0;
            if self.back > PENDING || self.off_rate > 0.5 {
                // off the grid for long, or half the time: not regular (now)
                self.relearns += 1;
                self.relearn();
                return self.push_learn(s);
            }
        }
        // on the grid, the stamp less the level: the correlator sees the stream's own
        // jitter (harmless), not the grid's fit; off it (a step's first samples, a late
        // stamp) the frame's grid point, so neither reaches the correlator
        let internal = if on {
            self.pass(s)
        } else if inconsistent {
            self.abs(self.grid(h)).min(self.pass(s))
        } else {
            self.abs(self.grid(h))
        };
        let level = s.saturating_sub(internal) as f64;
        if departs {
            self.trans_head = (self.trans_head + 1) % TRANS;
            self.trans_n = (self.trans_n + 1).min(TRANS);
            self.trans[self.trans_head] = (internal, step_dev);
        }
        self.window_push(Pend {
            dev,
            step_dev,
            internal,
            level,
            on,
        });
        if !self.try_step() && on {
            self.on_grid(h, dev);
        }
        internal
    }

    /// Right after a step, the stamps may come back to the level before it: a latency
    /// excursion of a few frames (the stamping thread starved for a moment), not a
    /// step. Its way back is a step of the size just taken, which read against the
    /// new level can be mistaken by a period (it may exceed half of one); read
    /// against the old level it is plain: `confirm` samples in a row on the old
    /// level's grid return to it (a step back, from the first of them). Returns the
    /// sample's internal stamp when it did.
    fn excursion_back(&mut self, s: Nanos, tol: f64) -> Option<Nanos> {
        let (old, run, left) = self.prev_level?;
        if left == 0 {
            self.prev_level = None;
            return None;
        }
        let t = self.line.1;
        let rel = s.saturating_sub(self.s0) as f64 - old;
        let x = 2.0 * (rel - self.line.0) / t + self.h0 as f64;
        if !x.is_finite() || x.abs() > 1e15 {
            self.prev_level = None;
            return None;
        }
        let he = 2.0 * (0.5 * x).round();
        // on the old level: within the tolerance, and much nearer it than the new one
        let near = tol.min((old - self.lref).abs() / 3.0);
        let back_on = he > self.h_last as f64 - 2.0 * (self.back as f64 + 1.0)
            && (x - he).abs() * 0.5 * t <= near;
        let run = if back_on { run + 1 } else { 0 };
        self.prev_level = Some((old, run, left - 1));
        if (run as usize) < self.p.confirm {
            return None;
        }
        // back: the window's newest samples were the old level's
        let internal = s.saturating_sub(old.round() as Nanos);
        let k = self.p.confirm.min(self.pend_n + 1);
        let first = self
            .pend_n
            .checked_sub(k - 1)
            .filter(|&j| j < self.pend_n)
            .map_or(internal, |j| self.pend[j].internal);
        let step = old - self.lref;
        self.pend_n = 0;
        self.trans_n = 0;
        self.prev_level = None;
        self.piece += 1;
        self.lref = old;
        self.level_n = LEVEL_SAMPLES;
        self.back = 0;
        self.last_off_dev = None;
        self.h_last = he as i64;
        self.steps += 1;
        self.new_step = Some(CadenceStep {
            start: first,
            step_ns: step,
            period_ns: t,
            ambiguity: 0.0,
        });
        let dev = rel - self.grid(self.h_last);
        self.window_push(Pend {
            dev,
            step_dev: dev,
            internal,
            level: s.saturating_sub(internal) as f64,
            on: true,
        });
        Some(internal)
    }

    /// Adds a sample to the step test's window. One leaving it was no step's: if it
    /// was on the grid, its level goes to the bins and the scale learns from it (a
    /// jitter the tolerance cannot hold makes the stream irregular, and the grid is
    /// learnt again).
    fn window_push(&mut self, pd: Pend) {
        let k = self.p.confirm;
        if self.pend_n == k {
            let old = self.pend[0];
            if old.on {
                self.sigma += (1.25 * old.dev.abs() - self.sigma) / 16.0;
                self.bin_add(old.internal, old.level);
            }
            self.pend.copy_within(1..k, 0);
            self.pend_n -= 1;
        }
        self.pend[self.pend_n] = pd;
        self.pend_n += 1;
    }

    /// A sample on the grid: the reference level and the fit learn from it.
    fn on_grid(&mut self, h: i64, dev: f64) {
        // the fit takes the stamp less the reference level (as refined by it)
        let before = self.lref;
        if self.level_n < LEVEL_SAMPLES {
            self.level_n += 1;
            self.lref += dev / self.level_n as f64;
        }
        let y = self.grid(h) + dev + before - self.lref;
        let x = 0.5 * h.saturating_sub(self.h0) as f64;
        self.fit.add(self.lambda, 1.0, x, y);
        self.since_anchor += 1;
        if self.since_anchor >= REANCHOR {
            self.reanchor(h);
        }
        match self.fit.line() {
            Some(line) => self.line = line,
            None => {
                self.relearns += 1;
                self.relearn();
            }
        }
    }

    /// Moves the fit's anchor to half-frame `h` (keeps its coordinates small).
    fn reanchor(&mut self, h: i64) {
        let dx = 0.5 * h.saturating_sub(self.h0) as f64;
        let dy = self.grid(h).round() as Nanos;
        self.fit.shift(dx, dy as f64);
        self.h0 = h;
        self.s0 = self.s0.saturating_add(dy);
        self.since_anchor = 0;
        if let Some(line) = self.fit.line() {
            self.line = line;
        }
    }

    /// Declares a step when the step test's window (the newest `confirm` samples)
    /// has moved off the level: every one beyond `max(min_step, 4σ)` on the same side,
    /// within `max(that, half the step)` of each other (a frame rate that changed
    /// moves them apart). The step is the median; it starts at the window's first
    /// sample beyond half of it. Returns whether the window was used up (a step, or a
    /// relearn for an impossible one).
    fn try_step(&mut self) -> bool {
        let k = self.p.confirm;
        if self.pend_n < k {
            return false;
        }
        let mut devs = [0f64; PENDING];
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (d, pd) in devs.iter_mut().zip(&self.pend[..k]) {
            *d = pd.step_dev;
            lo = lo.min(pd.step_dev);
            hi = hi.max(pd.step_dev);
        }
        let step = *devs[..k].select_nth_unstable_by(k / 2, f64::total_cmp).1;
        let thr = self.p.min_step_ns.max(4.0 * self.sigma);
        // every sample of the window beyond the threshold on the step's side (two
        // early or late stamps among three are jitter's tail under load, not a step),
        // and close together (a late frame, a midpoint stamp and a jittery one are not)
        let beyond = self.pend[..k]
            .iter()
            .all(|pd| pd.step_dev * step.signum() > thr);
        if !beyond || hi - lo > thr.max(0.5 * step.abs()) {
            return false;
        }
        let t = self.line.1;
        // a period or more is no latency step it could follow; found just after a
        // silence, the frames came back at another phase (a restarted driver)
        if step.abs() >= 0.9 * t || self.after_gap > 0 {
            self.relearns += 1;
            self.relearn();
            return true;
        }
        // the window's samples before the step stay with the old piece
        let first = self.pend[..k]
            .iter()
            .position(|pd| (pd.step_dev - 0.5 * step) * step.signum() > 0.0)
            .unwrap_or(0);
        // A step to later stamps may have been a period less, with a frame dropped at
        // the first of the window's samples (they all count from it). The departures
        // from the level just before tell: each that came without a drop before it
        // reads the true step; so one reading a period less settles it, and every
        // one reading the same makes a drop at each of them less likely.
        let (step, shift, ambiguity) = if step > 0.0 {
            let tol_t = thr.max(t / 6.0);
            let newest = self.pend[k - 1].internal;
            let (mut same, mut less) = (0i32, 0i32);
            for j in 0..self.trans_n {
                let (at, d) = self.trans[(self.trans_head + TRANS - j) % TRANS];
                if newest.saturating_sub(at) > TRANS_NS {
                    continue;
                }
                if (d - step).abs() <= tol_t {
                    same += 1;
                } else if (d - (step - t)).abs() <= tol_t {
                    less += 1;
                }
            }
            if less > 0 {
                (step - t, t, 0.0)
            } else {
                (step, 0.0, self.drop_rate.powi(same.max(1)))
            }
        } else {
            (step, 0.0, 0.0)
        };
        let lref = self.lref + step;
        if lref.abs() > MAX_LEVEL_NS || self.pieces_start_after(first) {
            self.relearns += 1;
            self.relearn();
            return true;
        }
        for j in 0..first {
            let pd = self.pend[j];
            if pd.on {
                self.bin_add(pd.internal, pd.level);
            }
        }
        self.piece += 1;
        // a frame dropped at the window's first sample: its samples are a frame later
        // than counted (their internal stamps, given out already, a period early)
        let sh = shift.round() as Nanos;
        for j in first..k {
            let pd = self.pend[j];
            self.bin_add(pd.internal.saturating_add(sh), pd.level - shift);
        }
        if shift > 0.0 {
            self.h_last = self.h_last.saturating_add(2);
        }
        let start = self.pend[first.min(k - 1)].internal.saturating_add(sh);
        self.pend_n = 0;
        self.trans_n = 0;
        self.prev_level = Some((self.lref, 0, EXCURSION_SAMPLES));
        self.lref = lref;
        // the median of the confirming samples counts as that many samples
        self.level_n = k as u32;
        // the jitter after a load change is the new load's: at least what the window
        // shows (a step of less than that would be jitter)
        self.sigma = self.sigma.max(0.25 * (hi - lo));
        self.back = 0;
        self.steps += 1;
        self.new_step = Some(CadenceStep {
            start,
            step_ns: step,
            period_ns: t,
            ambiguity,
        });
        true
    }

    /// Whether the newest level bin starts after the window's sample `first`
    /// (pieces must follow each other in time).
    fn pieces_start_after(&self, first: usize) -> bool {
        self.bin_n > 0 && self.bins[self.bin_head].start > self.pend[first].internal
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const MS: f64 = 1e6;

    fn run(c: &mut Cadence, stamps: &[Nanos]) -> Vec<Nanos> {
        run_levels(c, stamps, 0).0
    }

    /// The internal stamps, sample `gap_at` marked as the first after a silence
    /// longer than the gap limit (as the resampler marks it).
    fn run_with_gap(c: &mut Cadence, stamps: &[Nanos], gap_at: usize) -> Vec<Nanos> {
        let kind = |i: usize| match i {
            0 => Kind::First,
            i if i == gap_at => Kind::Gap,
            _ => Kind::Normal,
        };
        stamps
            .iter()
            .enumerate()
            .map(|(i, &t)| c.push(t, kind(i)))
            .collect()
    }

    /// The internal stamps, and the level of each sample as `level_at` tells it
    /// `lag` samples later (as the estimator asks, a few seconds back).
    fn run_levels(c: &mut Cadence, stamps: &[Nanos], lag: usize) -> (Vec<Nanos>, Vec<f64>) {
        let mut out = Vec::new();
        let mut levels = Vec::new();
        for (i, &s) in stamps.iter().enumerate() {
            out.push(c.push(s, if i == 0 { Kind::First } else { Kind::Normal }));
            if i >= lag {
                levels.push(c.level_at(out[i - lag]).0);
            }
        }
        (out, levels)
    }

    /// About N(0, 1): a sum of four uniforms from a 64-bit LCG.
    fn lcg(seed: &mut u64) -> f64 {
        let mut acc = 0.0;
        for _ in 0..4 {
            *seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            acc += (*seed >> 11) as f64 / (1u64 << 53) as f64;
        }
        (acc - 2.0) * 3.0f64.sqrt()
    }

    /// Frames at `period` with latency `lat(k)` (ns) and Gaussian jitter, some dropped.
    fn stamps(
        n: usize,
        period: f64,
        jitter: f64,
        drop_every: usize,
        lat: impl Fn(usize) -> f64,
    ) -> Vec<Nanos> {
        let mut seed = 7u64;
        (0..n)
            .filter(|k| drop_every == 0 || k % drop_every != drop_every - 1)
            .map(|k| (1e12 + k as f64 * period + lat(k) + jitter * lcg(&mut seed)) as Nanos)
            .collect()
    }

    #[test]
    fn exact_frames_pass_on_the_grid() {
        let mut c = Cadence::new(CadenceParams::default());
        let s = stamps(500, 33.333 * MS, 0.0, 0, |_| 0.0);
        let out = run(&mut c, &s);
        assert!(c.tracking());
        for (a, b) in s.iter().zip(&out) {
            assert!((a - b).abs() < 100, "{a} {b}");
        }
        assert_eq!(c.steps(), 0);
    }

    #[test]
    fn a_latency_step_moves_the_level_not_the_grid() {
        for step in [25.0, -25.0, 12.0, -8.0, 28.0] {
            let mut c = Cadence::new(CadenceParams::default());
            let s = stamps(600, 33.333 * MS, 0.0, 0, |k| {
                if k >= 300 {
                    step * MS
                } else {
                    0.0
                }
            });
            let out = run(&mut c, &s);
            assert_eq!(c.steps(), 1, "step {step}");
            // every internal stamp on the grid (no step enters the correlator)
            for (k, o) in out.iter().enumerate().skip(LEARN) {
                let g = 1e12 + k as f64 * 33.333 * MS;
                assert!(
                    (*o as f64 - g).abs() < 1e3,
                    "step {step} frame {k}: {}",
                    *o as f64 - g
                );
            }
            let (l_before, _) = c.level_at(out[299]);
            let (l_after, _) = c.level_at(out[300]);
            assert!(l_before.abs() < 1e3, "{l_before}");
            assert!(
                (l_after - l_before - step * MS).abs() < 1e3,
                "{step}: {l_after}"
            );
        }
    }

    /// A driver restarted on the same clock (a new capture stream, a LiDAR's motor
    /// started again) comes back after a silence at a new phase of its frames: the
    /// frames moved, not their latency, so it is no step. Read as one, the level would
    /// move the correlator's stamps off the frames' times by the phase, and the
    /// published offset would be off by it until the correlation's own step test
    /// caught up.
    #[test]
    fn a_new_phase_after_a_gap_is_no_step() {
        for (phase, jitter) in [(12.0, 0.0), (25.0, 1.0), (-8.0, 1.0), (5.0, 0.3)] {
            let period = 33.333 * MS;
            let mut seed = 11u64;
            // 300 frames, 3 s of silence, then 300 frames at the new phase
            let s: Vec<Nanos> = (0..690usize)
                .filter(|k| !(300..390).contains(k))
                .map(|k| {
                    let shift = if k >= 390 { phase * MS } else { 0.0 };
                    (1e12 + k as f64 * period + shift + jitter * MS * lcg(&mut seed)) as Nanos
                })
                .collect();
            let mut c = Cadence::new(CadenceParams::default());
            let out = run_with_gap(&mut c, &s, 300);
            assert_eq!(c.steps(), 0, "phase {phase} ms");
            assert!(c.tracking(), "phase {phase} ms");
            // the level stays: the frames after the gap reach the correlator at their
            // own stamps, not moved by the phase
            for i in [300, 350, 599] {
                let (level, _) = c.level_at(out[i]);
                assert!(
                    level.abs() < 0.5 * MS,
                    "phase {phase} ms, sample {i}: {level}"
                );
                assert!(
                    (out[i] - s[i]).abs() as f64 <= 3.0 * jitter * MS + 0.01 * MS || i == 300,
                    "phase {phase} ms, sample {i}: {} ms",
                    (out[i] - s[i]) as f64 / MS
                );
            }
        }
    }

    /// A driver stalled for longer than the gap limit, then stamping the frames it
    /// queued back to back until it is on time: no step, and the frames on time again
    /// sit on their grid points.
    #[test]
    fn a_stall_longer_than_the_gap_limit_keeps_the_grid() {
        let period = 33.333 * MS;
        let mut s = Vec::new();
        let mut next_free = 0.0f64;
        for k in 0..600usize {
            let ev = 1e12 + k as f64 * period;
            let ready = if k == 300 { ev + 1000.0 * MS } else { ev };
            let t = ready.max(next_free);
            next_free = t + 1.0 * MS;
            s.push(t as Nanos);
        }
        let mut c = Cadence::new(CadenceParams::default());
        // the stall's first stamp comes 1.03 s after the one before
        let out = run_with_gap(&mut c, &s, 300);
        // (its backlog of 30 frames, 1 ms apart, is no grid: learnt again after it)
        assert_eq!(c.steps(), 0);
        let phase = out[100] as f64 - (1e12 + 100.0 * period);
        for (k, &o) in out.iter().enumerate().skip(400) {
            let e = o as f64 - (1e12 + k as f64 * period) - phase;
            assert!(e.abs() < 0.01 * MS, "frame {k}: {:.3} ms off", e / MS);
        }
    }

    #[test]
    fn jitter_drops_and_spikes_are_no_steps() {
        let mut c = Cadence::new(CadenceParams::default());
        // 1 ms jitter, every 20th frame dropped, a late frame every 97 (8 or 15 ms)
        let late = |k: usize| match k % 97 {
            50 => 8.0 * MS,
            20 => 15.0 * MS,
            _ => 0.0,
        };
        let s = stamps(3000, 33.333 * MS, 1.0 * MS, 20, late);
        let frames: Vec<usize> = (0..3000).filter(|k| k % 20 != 19).collect();
        let out = run(&mut c, &s);
        assert!(c.tracking());
        assert_eq!(c.steps(), 0);
        assert_eq!(c.relearns(), 0);
        // the stamps pass as they are, jitter and all (no level to take off); a late
        // frame is put back on its grid point, as exactly as the grid's fit is, unless
        // it came half a period late (taken for a midpoint stamp spanning a dropped
        // frame: as late as it was)
        let mut regularised = 0;
        for (i, (&o, &k)) in out.iter().zip(&frames).enumerate().skip(LEARN) {
            if late(k) > 0.0 {
                let e = (o as f64 - (1e12 + k as f64 * 33.333 * MS)).abs();
                assert!(e < 17.5 * MS, "frame {k}: {e}");
                regularised += usize::from(e < 2.0 * MS);
            } else {
                assert_eq!(o, s[i], "frame {k}");
            }
        }
        assert!(regularised > 0);
    }

    #[test]
    fn a_step_under_jitter_is_found_and_measured() {
        // a LiDAR-like stream: 10 Hz, 3 ms jitter, 5 % drops, a 20 ms step
        let mut c = Cadence::new(CadenceParams::default());
        let s = stamps(2000, 100.0 * MS, 3.0 * MS, 20, |k| {
            if k >= 1000 {
                20.0 * MS
            } else {
                0.0
            }
        });
        let (_, levels) = run_levels(&mut c, &s, 30);
        assert_eq!(c.steps(), 1, "relearns {}", c.relearns());
        // 40 s after the step against 10 s before it (each the mean of its 2 s,
        // looked up 3 s later)
        let (after, before) = (levels[1330], levels[855]);
        assert!(
            (after - before - 20.0 * MS).abs() < 1.5 * MS,
            "{}",
            (after - before) / MS
        );
    }

    #[test]
    fn a_stalled_driver_is_no_step() {
        // 30 Hz frames; every 2 s the driver stops for 40-120 ms, then stamps the
        // frames it queued meanwhile back to back (1 ms apart) until it is on time
        let period = 33.333 * MS;
        let mut s = Vec::new();
        let mut next_free = 0.0f64;
        let mut frames = Vec::new();
        for k in 0..1800usize {
            let ev = 1e12 + k as f64 * period;
            let stall = [0.0, 40.0, 75.0, 120.0][(k / 60) % 4] * MS;
            let ready = if k % 60 == 30 { ev + stall } else { ev };
            let t = ready.max(next_free);
            next_free = t + 1.0 * MS;
            s.push(t as Nanos);
            frames.push(ev);
        }
        let mut c = Cadence::new(CadenceParams::default());
        let out = run(&mut c, &s);
        assert_eq!(c.steps(), 0, "relearns {}", c.relearns());
        assert!(c.tracking());
        // the stalled frame and the burst after it reach the correlator no later than
        // their own stamps, and every frame on time again exactly on its grid point
        let phase = out[100] as f64 - frames[100];
        for (k, ((&o, &ev), &st)) in out.iter().zip(&frames).zip(&s).enumerate().skip(100) {
            let late = st as f64 - ev - phase;
            let e = o as f64 - ev - phase;
            if late > 0.01 * MS {
                assert!(
                    e <= late + 0.01 * MS,
                    "frame {k}: {:.3} ms, stamp {:.3}",
                    e / MS,
                    late / MS
                );
            } else {
                assert!(e.abs() < 0.01 * MS, "frame {k}: {:.3} ms off", e / MS);
            }
        }
    }

    #[test]
    fn midpoint_stamps_across_skipped_frames_stay_on_the_grid() {
        // a flow sample is stamped at the midpoint of the two frames it compares: a
        // skipped frame puts one sample half a period off the grid (two skipped in a
        // row: back on it); a 12 ms latency step from frame 600 on
        let period = 33.333 * MS;
        let lat = |k: usize| if k >= 600 { 12.0 * MS } else { 0.0 };
        let kept: Vec<usize> = (0..1200).filter(|k| k % 23 != 7 && k % 97 != 8).collect();
        let s: Vec<Nanos> = kept
            .windows(2)
            .map(|w| {
                let t = |k: usize| 1e12 + k as f64 * period + lat(k);
                (0.5 * (t(w[0]) + t(w[1]))) as Nanos
            })
            .collect();
        let mut c = Cadence::new(CadenceParams::default());
        let (out, levels) = run_levels(&mut c, &s, 90);
        assert_eq!(c.relearns(), 0);
        assert_eq!(c.steps(), 1);
        // every internal stamp is its sample's midpoint less the level: no jitter to
        // remove here, so internal + level is the stamp itself
        for (i, (&o, &l)) in out.iter().zip(&levels).enumerate() {
            let e = (o as f64 + l - s[i] as f64).abs();
            let near_step = (kept[i] as i64 - 600).abs() < 4;
            assert!(near_step || e < 0.05 * MS, "sample {i}: {:.3} ms", e / MS);
        }
    }

    #[test]
    fn a_step_of_half_a_period_is_followed() {
        // a step half a period late puts the stamps where midpoint stamps spanning a
        // dropped frame would be; they keep coming every period, so it is a step
        for (hz, step, jitter) in [
            (30.0, 16.0, 0.0),
            (30.0, 17.0, 0.0),
            (30.0, 16.5, 1.0),
            (60.0, 8.0, 0.0),
        ] {
            let period = 1e3 / hz * MS;
            let s = stamps(1200, period, jitter * MS, 0, |k| {
                if k >= 600 {
                    step * MS
                } else {
                    0.0
                }
            });
            let mut c = Cadence::new(CadenceParams::default());
            let (out, levels) = run_levels(&mut c, &s, 90);
            assert_eq!(c.steps(), 1, "{hz} Hz {step} ms: relearns {}", c.relearns());
            let moved = (levels[900] - levels[300]) / MS;
            assert!(
                (moved - step).abs() < 0.5,
                "{hz} Hz {step} ms: level moved {moved}"
            );
            // from a few frames after the step on, no stamp carries it to the correlator
            for (k, &o) in out.iter().enumerate().skip(605) {
                let e = (o as f64 - (1e12 + k as f64 * period)) / MS;
                assert!(
                    e.abs() < 4.0 * jitter + 0.5,
                    "{hz} Hz {step} ms, frame {k}: {e:.2} ms"
                );
            }
        }
    }

    #[test]
    fn a_latency_excursion_of_a_few_frames_comes_back() {
        // recorded under load: the stamping thread starved for a moment, five frames
        // 14-26 ms late, two catching up, then the latency it had (1 ms of jitter);
        // whether it is taken for a step and a step back or for jitter, the level and
        // the stamps afterwards are what they were before
        let extra = [13.7, 26.0, 22.9, 21.3, 19.9, 14.7, 5.5];
        let s = stamps(900, 33.333 * MS, 1.0 * MS, 0, |k| {
            12.0 * MS
                + if (300..307).contains(&k) {
                    extra[k - 300] * MS
                } else {
                    0.0
                }
        });
        let mut c = Cadence::new(CadenceParams::default());
        let (out, levels) = run_levels(&mut c, &s, 90);
        assert_eq!(c.relearns(), 0);
        let before = levels[250];
        for (k, &l) in levels.iter().enumerate().skip(320).take(400) {
            assert!(
                (l - before).abs() < 1.0 * MS,
                "frame {k}: level {:.2} ms",
                (l - before) / MS
            );
        }
        for k in 320..out.len() {
            assert_eq!(
                out[k] - out[k - 1],
                s[k] - s[k - 1],
                "frame {k}: the stamps pass as they are"
            );
        }
    }

    #[test]
    fn every_other_frame_dropped_is_no_step() {
        // midpoint stamps; from frame 400 to 700 every other frame is dropped (the flow
        // pairs frames two apart, its samples half a period off the grid, every 2 T)
        let period = 33.333 * MS;
        let kept: Vec<usize> = (0..1200)
            .filter(|&k| !(400..700).contains(&k) || k % 2 == 0)
            .collect();
        let s: Vec<Nanos> = kept
            .windows(2)
            .map(|w| (1e12 + 0.5 * (w[0] + w[1]) as f64 * period) as Nanos)
            .collect();
        let mut c = Cadence::new(CadenceParams::default());
        let out = run(&mut c, &s);
        assert_eq!(c.steps(), 0, "relearns {}", c.relearns());
        assert_eq!(out, s, "every stamp passes as it is");
    }

    #[test]
    fn steps_under_a_jitter_that_grows_with_the_load() {
        // idle: 0.02 ms jitter; loaded (frames 400-900): 12 ms later, 1.5 ms jitter
        let mut seed = 11u64;
        let period = 33.333 * MS;
        let s: Vec<Nanos> = (0..1400usize)
            .map(|k| {
                let loaded = (400..900).contains(&k);
                let (lat, jit) = if loaded { (12.0, 1.5) } else { (0.0, 0.02) };
                (1e12 + k as f64 * period + (lat + jit * lcg(&mut seed)) * MS) as Nanos
            })
            .collect();
        let mut c = Cadence::new(CadenceParams::default());
        let (_, levels) = run_levels(&mut c, &s, 90);
        assert_eq!(c.relearns(), 0);
        assert!((2..=4).contains(&c.steps()), "{} steps", c.steps());
        let (idle, loaded, idle2) = (levels[300], levels[700], levels[1200]);
        assert!(
            ((loaded - idle) / MS - 12.0).abs() < 0.5,
            "{}",
            (loaded - idle) / MS
        );
        assert!(((idle2 - idle) / MS).abs() < 0.5, "{}", (idle2 - idle) / MS);
    }

    #[test]
    fn an_irregular_stream_passes_through() {
        let mut c = Cadence::new(CadenceParams::default());
        let mut seed = 3u64;
        let mut t = 1e12;
        let s: Vec<Nanos> = (0..400)
            .map(|_| {
                t += 33.0 * MS * (1.0 + 0.4 * lcg(&mut seed).clamp(-2.0, 2.0));
                t as Nanos
            })
            .collect();
        let out = run(&mut c, &s);
        assert!(!c.tracking());
        assert_eq!(out, s);
    }

    #[test]
    fn a_changed_frame_rate_is_learnt_again() {
        let mut c = Cadence::new(CadenceParams::default());
        let mut s = stamps(300, 33.333 * MS, 0.0, 0, |_| 0.0);
        let t0 = *s.last().unwrap();
        s.extend((1..400).map(|k| t0 + (k as f64 * 40.0 * MS) as Nanos));
        let out = run(&mut c, &s);
        assert!(c.tracking());
        assert_eq!(c.period_ns().map(|t| (t / 1e3).round()), Some(40_000.0));
        // the level never wandered off
        let (l, _) = c.level_at(*out.last().unwrap());
        assert!(l.abs() < 50.0 * MS, "{}", l / MS);
        assert!(out.windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn a_doubled_rate_is_learnt_again_without_moving_its_samples() {
        // a LiDAR front-end fitting the wall ahead and the one behind merges two
        // windows half a turn apart into one stream: 10 Hz while one wall is out of
        // range, 20 Hz while both are seen, and 10 Hz again
        let mut seed = 11u64;
        let mut s: Vec<Nanos> = Vec::new();
        for k in 0..900usize {
            let both = (300..600).contains(&k);
            for half in [0.0, 0.5] {
                if half > 0.0 && !both {
                    continue;
                }
                let t = 1e12 + (k as f64 + half) * 100.0 * MS + 0.2 * MS * lcg(&mut seed);
                s.push(t as Nanos);
            }
        }
        let mut c = Cadence::new(CadenceParams::default());
        let out = run(&mut c, &s);
        // one sample, the first between two frames, goes to the next frame's point
        // before the pattern is plain (and the frame's own stamp after it stays after
        // it, by the jitter); every other stamp reaches the correlator as it is
        let moved: Vec<(usize, f64)> = out
            .iter()
            .zip(&s)
            .enumerate()
            .filter(|(_, (o, s))| o != s)
            .map(|(i, (o, s))| (i, (*o - *s) as f64 / MS))
            .collect();
        assert!(
            moved.len() <= 2 && moved.iter().skip(1).all(|m| m.1.abs() < 1.0),
            "moved (index, ms): {moved:?}"
        );
        assert_eq!((c.steps(), c.relearns()), (0, 1));
        // learnt at 20 Hz, which holds the 10 Hz stretch after it as dropped frames
        assert_eq!(c.period_ns().map(|t| (t / MS).round()), Some(50.0));
        assert!(c.level().abs() < 1e3, "level {} ns", c.level());
    }

    #[test]
    fn disabled_passes_everything() {
        let mut c = Cadence::new(CadenceParams {
            enabled: false,
            ..CadenceParams::default()
        });
        let s = stamps(200, 33.333 * MS, 0.0, 0, |k| {
            if k > 100 {
                25.0 * MS
            } else {
                0.0
            }
        });
        assert_eq!(run(&mut c, &s), s);
        assert_eq!(c.steps(), 0);
    }

    proptest! {
        #[test]
        fn internal_stamps_increase_for_any_increasing_stamps(
            gaps in proptest::collection::vec(1i64..200_000_000, 1..400),
            start in -1_000_000_000_000i64..1_000_000_000_000,
        ) {
            let mut c = Cadence::new(CadenceParams::default());
            let mut t = start;
            let mut last = None;
            for (i, g) in gaps.iter().enumerate() {
                t += g;
                let o = c.push(t, if i == 0 { Kind::First } else { Kind::Normal });
                if let Some(l) = last {
                    prop_assert!(o > l);
                }
                last = Some(o);
                let (lv, var) = c.level_at(o);
                prop_assert!(lv.is_finite() && var.is_finite());
                prop_assert!(lv.abs() <= MAX_LEVEL_NS + 1.0);
            }
        }
    }
}
