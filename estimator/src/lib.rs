//! The vlsync estimator: pure, deterministic, allocation-free after construction.
//!
//! Push `(timestamp, value)` samples of the camera and LiDAR signature streams in
//! any interleaving; poll [`Estimate`]s, one per completed hop.
//!
//! Pipeline: [`resample`] validates each sample on its stamp; [`cadence`] follows the
//! stream's regular frame grid and takes steps of its stamping latency out of the
//! stamp (estimates add them back) → [`resample`] (linear interpolation onto a
//! uniform grid on each sensor's own clock) → [`filter`] (the same band-pass on both) →
//! [`correlator`] (incremental Pearson sums per lag in blocks of one hop, O(lags) per
//! grid sample) → [`peak`] (gated peak search, sub-sample refinement, polarity);
//! once locked, [`segment`] (robust, drift-compensated combination of every block
//! since the last change point, mostly prepared on the samples before each hop) with
//! a two-sample step test run in stages on the samples after it, and [`drift`] (a
//! line through disjoint short-window peaks).
//!
//! ```
//! use vlsync_common::{Sample, Stream, EstimatorState};
//! use vlsync_config::EstimatorConfig;
//! use vlsync_estimator::Estimator;
//!
//! // a motion signature: a few bumps, seen by the LiDAR 120 ms after the camera's stamp
//! let s = |t: f64| (0.7 * t).sin() + (1.9 * t).sin() * (0.3 * t).cos();
//! let mut est = Estimator::new(&EstimatorConfig::default());
//! let mut last = None;
//! for i in 0..1200 {
//!     let t = i as f64 / 30.0; // camera clock, 30 Hz
//!     est.push(Stream::Cam, Sample::new((t * 1e9) as i64, s(t + 0.12))).unwrap();
//!     if i % 3 == 0 { // LiDAR clock, 10 Hz
//!         est.push(Stream::Lidar, Sample::new((t * 1e9) as i64, s(t))).unwrap();
//!     }
//!     while let Some(e) = est.poll() { last = Some(e); }
//! }
//! let e = last.unwrap();
//! assert_eq!(e.state, EstimatorState::Tracking);
//! assert!((e.offset_s - 0.12).abs() < 0.002, "{}", e.offset_s);
//! ```
//! (The camera frame stamped `t` shows the event the LiDAR stamps `t + 0.12`,
//! so `offset = t_L - t_C = +0.12 s`.)
#![forbid(unsafe_code)]

pub mod cadence;
pub mod correlator;
pub mod drift;
pub mod filter;
pub mod peak;
pub mod resample;
pub mod segment;

use cadence::{Cadence, CadenceParams};
use correlator::{Correlator, Step, Sums};
use drift::DriftFit;
use filter::BandPass;
use resample::{Discontinuity, Resampler};
use segment::{PrepKey, Segment, Span};
use vlsync_common::{Estimate, EstimatorState, Nanos, Polarity, RejectReason, Sample, Stream};
use vlsync_config::EstimatorConfig;

/// Counters of the estimator.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EstimatorStats {
    /// Accepted samples per stream (index: 0 cam, 1 lidar).
    pub accepted: [u64; 2],
    /// Rejected samples per stream and reason (`RejectReason::index`).
    pub rejected: [[u64; 4]; 2],
    /// Stream resets (timestamp jumps beyond `reset_jump_s`) per stream.
    pub resets: [u64; 2],
    /// Window breaks caused by gaps per stream.
    pub gaps: [u64; 2],
    /// Estimates produced.
    pub estimates: u64,
    /// Estimates dropped because `poll` was not called often enough.
    pub dropped_estimates: u64,
    /// Segment measurements accepted (estimates in state `tracking`).
    pub measurements: u64,
    /// Short-window measurements rejected as outliers of the segment estimate.
    pub outliers: u64,
    /// Offset steps detected (a new segment started).
    pub steps: u64,
    /// Locks acquired (first lock and re-acquisitions).
    pub locks: u64,
    /// Times an acquisition that found nothing moved its lag range to the other
    /// candidate centre (the start's, or the one it left).
    pub recentres: u64,
    /// Stamping-latency steps each stream's cadence found (index: 0 cam, 1 lidar):
    /// followed from the stamps, not the correlation ([`cadence`]).
    pub cadence_steps: [u64; 2],
    /// Times each stream's cadence was learnt again (not regular enough, a clock jump).
    pub cadence_relearns: [u64; 2],
}

fn idx(s: Stream) -> usize {
    match s {
        Stream::Cam => 0,
        Stream::Lidar => 1,
    }
}

const QUEUE: usize = 64;
/// Acquisition hops with motion after which an acquisition that found nothing moves
/// its lag range to the other candidate centre (see [`Estimator::alt_lag0`]), and
/// the LiDAR time without a correlator hop, both streams delivering, after which it
/// moves at once ([`Estimator::check_unserved`]): 30 s at the default hop.
const RECENTRE_HOPS: usize = 60;
/// Lag slots beyond the tracking range that tracking reads (`Estimator::narrow_to`).
const TRACK_NEED_SLOTS: f64 = 6.0;
/// Lag slots updated beyond the needed ones on each side once locked (none in
/// degraded mode).
const TRACK_SPARE_SLOTS: f64 = 8.0;
/// Hops of acquisition-window variances behind the motion gate's reference (120 s at
/// the default hop).
const MOTION_HISTORY: usize = 240;
/// Floor of the measurement standard deviation (stamp jitter, interpolation), seconds.
const MIN_MEAS_STD_S: f64 = 2e-4;
/// Window length at which the peak-sharpness variance formula matches the observed scatter, s.
const CAL_WINDOW_S: f64 = 4.0;
/// Step-test statistic (squared sigmas) from which a possible change inflates σ.
const SUSPECT_STAT: f64 = 4.0;
/// Disjoint short-window innovations (newest data against the estimate's
/// prediction) whose mean estimates the estimate's current bias: 4 step windows,
/// 8 s by default.
const BIAS_WINDOWS: usize = 4;
/// Re-weighting passes of a fresh robust combination (the segment's weights carry
/// over from hop to hop, so it needs one pass per hop).
const IRLS_PASSES: usize = 1;

/// Slots by which the joint maximum's drift hypotheses shift the segment's far end
/// ([`Estimator::joint_stage`]).
const JOINT_SHIFT: f64 = 3.0;
/// Re-centrings of the joint maximum's hypotheses per hop at most.
const JOINT_ROUNDS: usize = 3;

/// Numbers derived once from the configuration.
#[derive(Debug, Clone)]
struct Params {
    dt_ns: Nanos,
    dt_s: f64,
    fs: f64,
    hop_len: i64,
    half_lags: i64,
    center_lag: i64,
    track_slots: f64,
    short_blocks: usize,
    acq_blocks: usize,
    seg_blocks: usize,
    ref_lag_ns: Nanos,
    window_s: f64,
    hop_s: f64,
    lowpass_hz: f64,
    highpass_hz: f64,
    min_score: f64,
    min_ratio: f64,
    min_motion: f64,
    acquire_confirm: u32,
    noise_scale: f64,
    qo: f64,
    q_hold: f64,
    drift0: f64,
    drift_memory_s: f64,
    gate: f64,
    step_gate: f64,
    step_confirm: u32,
    lost_var: f64,
    stall_slots: i64,
    max_lag_s: f64,
    max_gap_ns: Nanos,
}

impl Params {
    fn new(c: &EstimatorConfig) -> Self {
        // clamp to the validated ranges so an unvalidated config cannot panic or exhaust memory
        let cl = |v: f64, lo: f64, hi: f64| if v.is_finite() { v.clamp(lo, hi) } else { lo };
        let fs = cl(c.grid_hz, 10.0, 2000.0);
        let dt_ns = ((1e9 / fs).round() as Nanos).max(1);
        let fs = 1e9 / dt_ns as f64;
        let dt_s = 1.0 / fs;
        let window_s = cl(c.window_s, 1.0, 120.0);
        let hop_s = cl(c.hop_s, dt_s, window_s);
        let hop_len = ((hop_s * fs).round() as i64).max(1);
        let hop_s = hop_len as f64 * dt_s;
        let segment_s = cl(c.segment_s, window_s, 600.0);
        let max_lag_s = cl(c.max_lag_s, 0.01, 2.0);
        let lowpass_hz = cl(c.lowpass_hz, 0.05, 0.45 * fs);
        let blocks = |s: f64| ((s / hop_s).round() as usize).max(1);
        let acq_blocks = blocks(window_s);
        Self {
            dt_ns,
            dt_s,
            fs,
            hop_len,
            half_lags: ((max_lag_s * fs).round() as i64).max(2),
            center_lag: (cl(c.lag_center_s, -1e6, 1e6) * fs).round() as i64,
            track_slots: (cl(c.track_range_s, 0.005, max_lag_s) * fs).max(2.0),
            short_blocks: blocks(cl(c.step_window_s, 0.5, window_s)).min(acq_blocks),
            acq_blocks,
            seg_blocks: blocks(segment_s).max(acq_blocks),
            ref_lag_ns: (cl(c.reference_lag_s, 0.0, segment_s) * 1e9) as Nanos,
            window_s,
            hop_s,
            lowpass_hz,
            highpass_hz: cl(c.highpass_hz, 0.0, 0.9 * lowpass_hz),
            min_score: cl(c.min_peak_score, 0.0, 1.0),
            min_ratio: cl(c.min_peak_ratio, 1.0, 100.0),
            min_motion: cl(c.min_motion_ratio, 0.0, 1.0),
            acquire_confirm: c.acquire_confirm.clamp(1, vlsync_config::CONFIRM_MAX),
            noise_scale: cl(c.measurement_noise_scale, 1e-3, 1e3),
            qo: cl(c.offset_process_noise, 0.0, 1.0),
            q_hold: cl(c.hold_process_noise, 0.0, 1.0),
            drift0: cl(c.initial_drift_std, 1e-9, 0.1),
            drift_memory_s: cl(c.drift_memory_s, 1.0, 1e9),
            gate: cl(c.gate_sigma, 1.0, 100.0),
            step_gate: cl(c.step_gate_sigma, 1.0, 100.0),
            step_confirm: c.step_confirm.clamp(1, vlsync_config::CONFIRM_MAX),
            lost_var: cl(c.lost_std_s, 1e-4, 10.0).powi(2),
            stall_slots: ((cl(c.max_gap_s, 0.01, 60.0) + 2.0 * max_lag_s + hop_s) * fs).ceil()
                as i64,
            max_lag_s,
            max_gap_ns: (cl(c.max_gap_s, 0.01, 60.0) * 1e9) as Nanos,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Acquire,
    Locked,
}

/// A measurement candidate kept across hops (acquisition confirmation, step detection).
#[derive(Debug, Clone, Copy, Default)]
struct Streak {
    count: u32,
    z: f64,
    var: f64,
    sign: f64,
}

/// Fixed-capacity queue of pending estimates.
#[derive(Debug, Clone)]
struct Queue {
    buf: [Option<Estimate>; QUEUE],
    head: usize,
    len: usize,
}

impl Queue {
    fn push(&mut self, e: Estimate) -> bool {
        let dropped = self.len == QUEUE;
        if dropped {
            self.head = (self.head + 1) % QUEUE;
            self.len -= 1;
        }
        self.buf[(self.head + self.len) % QUEUE] = Some(e);
        self.len += 1;
        dropped
    }

    fn pop(&mut self) -> Option<Estimate> {
        if self.len == 0 {
            return None;
        }
        let e = self.buf[self.head].take();
        self.head = (self.head + 1) % QUEUE;
        self.len -= 1;
        e
    }
}

/// Raw window measurements kept for their trend ([`DriftFit::set_raw_trend`]).
const RAW_TREND: usize = 8;

/// Raw window measurements a trend needs at least.
const RAW_TREND_MIN: usize = 4;

/// The raw trend confirms a joint slope ([`DriftFit::set_raw_trend`]) while the
/// reference time is at most this long (s) after the segment's start: its first
/// hops (2 s after the start at a lock), while the prior's lag costs most and the
/// segment alone cannot show a fast drift at 5σ. Later a true one shows on the
/// segment alone (the seed run's 12 ms/s: 6-13σ by then), and the windows' own
/// excursions would pass: without the limit, a rates-60x5 run (2002) took a
/// 23 ms/s slope 7 s after its start and a heavy-noise run (6000) -7 ms/s 8 s after
/// (estimates 21-25 ms off), and free slopes over 1 ms/s appeared in 41 hops of the
/// drift-free families' 190 seeds each instead of 17 (22 with the limit).
const RAW_CONFIRM_S: f64 = 4.0;

/// The newest raw window measurements `(t, z, σ)`: peaks of the acquisition
/// window at its centre time, oldest first; the acquisition's consistent windows
/// before a lock, then each tracking hop's raw measurement. A hop without one (no
/// motion, no peak) or an acquisition's restart clears them. Their trend confirms a
/// joint slope ([`DriftFit::set_raw_trend`]).
#[derive(Debug, Clone, Copy, Default)]
struct RawTrend {
    pts: [(f64, f64, f64); RAW_TREND],
    n: usize,
}

impl RawTrend {
    fn clear(&mut self) {
        self.n = 0;
    }

    fn push(&mut self, t: f64, z: f64, var: f64) {
        if !(t.is_finite() && z.is_finite() && var.is_finite() && var > 0.0) {
            return;
        }
        if self.n == RAW_TREND {
            self.pts.copy_within(1.., 0);
            self.n -= 1;
        }
        self.pts[self.n] = (t, z, var.sqrt());
        self.n += 1;
    }

    /// The least-squares slope through the measurements and its variance: the
    /// larger of the windows' overlap model (each window's variance, errors
    /// correlated by the share of data two windows of length `window_s` hold in
    /// common) and the scatter about the line. Against the truth its z-scores have
    /// an RMS of 1.0-1.1 in the steady families (1.3 in heavy noise, 0.8 in the seed
    /// run; seeds 0-19), with tails: 1-3 % beyond 3σ.
    fn slope(&self, window_s: f64) -> Option<(f64, f64)> {
        let n = self.n;
        if n < RAW_TREND_MIN {
            return None;
        }
        let pts = &self.pts[..n];
        let nf = n as f64;
        let tb = pts.iter().map(|p| p.0).sum::<f64>() / nf;
        let zb = pts.iter().map(|p| p.1).sum::<f64>() / nf;
        let stt: f64 = pts.iter().map(|p| (p.0 - tb) * (p.0 - tb)).sum();
        if stt <= 0.0 || !stt.is_finite() {
            return None;
        }
        let s = pts.iter().map(|p| (p.0 - tb) * (p.1 - zb)).sum::<f64>() / stt;
        let (mut model, w) = (0.0, window_s.max(1e-3));
        for a in pts {
            for b in pts {
                let c = (1.0 - (a.0 - b.0).abs() / w).max(0.0);
                model += (a.0 - tb) * (b.0 - tb) * a.2 * b.2 * c;
            }
        }
        model /= stt * stt;
        let rss: f64 = pts
            .iter()
            .map(|p| (p.1 - zb - s * (p.0 - tb)).powi(2))
            .sum();
        let scatter = rss / (nf - 2.0) / stt;
        let var = model.max(scatter);
        (s.is_finite() && var.is_finite()).then_some((s, var))
    }
}

/// One correlation measurement.
#[derive(Debug, Clone, Copy)]
struct Meas {
    z: f64,
    var: f64,
    score: f64,
    ratio: f64,
    sign: f64,
}

/// The segment's joint (offset, drift) maximum of a tracking hop
/// ([`Estimator::joint_stage`]), run one combination per pushed sample after the
/// hop, with the weights the hop found (kept by [`Segment::snapshot_weights`]):
/// its result informs the drift fit from the next hop on.
#[derive(Debug, Clone, Copy)]
struct JointJob {
    /// The hop's segment at its start: its blocks, slots and reference index.
    first: usize,
    last: usize,
    k_ref: f64,
    lo: usize,
    hi: usize,
    sign: f64,
    /// Hypotheses' spacing and centre.
    delta: f64,
    c: f64,
    /// Re-centrings done, and the hypothesis the next stage combines.
    round: usize,
    j: usize,
    /// Peak heights of the round's hypotheses so far, and the pairs each combined.
    h: [f64; 3],
    nsum: [f64; 3],
    /// The sample rate the hop saw (every push moves the streams' mean intervals).
    rate: f64,
    /// Tracker times of the hop and of its segment's end.
    t: f64,
    t_end: f64,
}

impl JointJob {
    /// The segment under hypothesis `j` of the current round.
    fn span(&self, j: usize) -> Span {
        Span {
            first: self.first,
            last: self.last,
            drift: self.c + (j as f64 - 1.0) * self.delta,
            k_ref: self.k_ref,
            lo: self.lo,
            hi: self.hi,
        }
    }
}

/// The inputs of the next hop's joint maximum its first round was prepared for
/// ([`Estimator::prepare_joint_stage`]): the hop uses the preparation when it
/// finds them unchanged.
#[derive(Debug, Clone, Copy, PartialEq)]
struct JointKey {
    epoch: u64,
    /// The blocks the preparation holds (the hop adds its new one), by grid index:
    /// their store indices move when the store is full.
    blocks: usize,
    first_k: i64,
    last_k: i64,
    k_ref: f64,
    lo: usize,
    hi: usize,
    c: f64,
    delta: f64,
}

/// The next hop as predicted before its block completes ([`Estimator::next_hop`]),
/// for the preparations of its segment combination and its joint maximum.
#[derive(Debug, Clone, Copy)]
struct NextHop {
    /// Blocks stored now (the hop adds one).
    n: usize,
    /// The hop's last LiDAR grid index.
    k_end: i64,
    t_ref_ns: Nanos,
    /// The predicted offset at its reference time.
    pred_t: f64,
    /// The first stored block its segment will hold.
    first: usize,
}

/// Where a step test in progress stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StepStage {
    /// A change announced from outside; the newest `short` blocks.
    Start,
    /// The segment's total with its weights (a stage per [`segment::PREP_BLOCKS`] blocks).
    Total,
    /// The post window of `len` blocks (then the next, or the verdict).
    Post,
}

/// The step test of one tracking hop ([`Estimator::step_start`]), split into stages
/// of a few microseconds each, one per pushed sample, so that no single sample
/// carries the whole test. Everything it reads stays as it was at the hop until the
/// next block completes, and it is finished before that (or before a stall, a clock
/// jump, a restore changes what it reads), so its verdict is the one an unsplit
/// test would give at the first push after the hop. One difference from the code
/// before the stages: when one push completes two blocks (short hops, a burst after
/// a stall), the first hop's test is now finished before the second block; it used
/// to be dropped. At the default hop the replays of every simulated family are
/// byte for byte those of that code.
#[derive(Debug, Clone, Copy)]
struct StepJob {
    sign: f64,
    pred_t: f64,
    stage: StepStage,
    /// The segment's first stored block and the number stored.
    first: usize,
    n: usize,
    /// Lag slots searched.
    lo: usize,
    hi: usize,
    /// Motion references (see [`Estimator::seg_moving`]).
    refs: [f64; 2],
    /// Longest post window, and the current and previous lengths, in blocks.
    max_post: usize,
    len: usize,
    prev: usize,
    /// The most significant split so far: statistic, first post block, post
    /// measurement, innovation.
    best: Option<(f64, usize, Meas, f64)>,
    /// The slower stream's sample rate when the test started ([`Estimator::min_rate`]).
    rate: f64,
    /// Blocks of the segment's total summed so far (the total takes a stage per
    /// [`segment::PREP_BLOCKS`] blocks).
    total_done: usize,
}

impl StepJob {
    fn new(sign: f64, pred_t: f64) -> Self {
        Self {
            sign,
            pred_t,
            stage: StepStage::Start,
            first: 0,
            n: 0,
            lo: 0,
            hi: 0,
            refs: [0.0; 2],
            max_post: 0,
            len: 0,
            prev: 0,
            best: None,
            rate: 0.0,
            total_done: 0,
        }
    }

    /// Blocks `first..=last` at slots `lo..=hi`, without drift compensation.
    fn span(&self, first: usize, last: usize, lo: usize, hi: usize) -> Span {
        Span {
            first,
            last,
            drift: 0.0,
            k_ref: 0.0,
            lo,
            hi,
        }
    }
}

/// The current offset estimate: offset `o` at tracker time `t`, its variance.
#[derive(Debug, Clone, Copy)]
struct Current {
    t: f64,
    o: f64,
    var: f64,
}

/// The last [`MOTION_HISTORY`] values of one signal's window variance.
#[derive(Debug, Clone)]
struct History {
    buf: [f64; MOTION_HISTORY],
    n: usize,
    pos: usize,
    sort: [f64; MOTION_HISTORY],
}

impl Default for History {
    fn default() -> Self {
        Self {
            buf: [0.0; MOTION_HISTORY],
            n: 0,
            pos: 0,
            sort: [0.0; MOTION_HISTORY],
        }
    }
}

impl History {
    fn push(&mut self, v: f64) {
        if v.is_finite() {
            self.buf[self.pos] = v;
            self.pos = (self.pos + 1) % MOTION_HISTORY;
            self.n = (self.n + 1).min(MOTION_HISTORY);
        }
    }

    /// The 75th percentile of the values held (0 when empty).
    fn upper_quartile(&mut self) -> f64 {
        if self.n == 0 {
            return 0.0;
        }
        let v = &mut self.sort[..self.n];
        v.copy_from_slice(&self.buf[..self.n]);
        let k = (3 * self.n) / 4;
        *v.select_nth_unstable_by(k.min(self.n - 1), f64::total_cmp)
            .1
    }
}

/// Why the acquisition's lag range moved ([`SearchMove`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SearchMoveReason {
    /// An acquisition found no lock in `RECENTRE_HOPS` hops with motion.
    NothingFound,
    /// Both streams delivered but the correlator completed no hop for
    /// `RECENTRE_HOPS` hops of LiDAR time: the prediction put the camera's
    /// data out of reach (a restored state far off, clocks that stepped apart).
    Unserved,
}

/// A move of the acquisition's lag range to its other candidate centre
/// ([`Estimator::take_search_move`]); counted in [`EstimatorStats::recentres`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchMove {
    /// Centre of the lag range left, as an offset of the stamps as they come (like
    /// a published estimate's), s.
    pub from_s: f64,
    /// Centre of the lag range searched from now on, the same way, s.
    pub to_s: f64,
    /// What made it move.
    pub reason: SearchMoveReason,
    /// How long it waited before moving (motion for [`SearchMoveReason::NothingFound`],
    /// LiDAR time for [`SearchMoveReason::Unserved`]), s.
    pub after_s: f64,
}

/// An offset step the step test found in the data (a new segment started;
/// counted in [`EstimatorStats::steps`]); taken with [`Estimator::take_offset_step`].
/// Changes announced from outside (load hints, cadence steps) are not reported
/// here: their announcer knows of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetStep {
    /// Where the new segment starts, on the LiDAR clock, ns.
    pub t_ns: Nanos,
    /// The step's size as the test measured it (new offset less the old one's
    /// prediction), s.
    pub step_s: f64,
}

/// A step of one stream's stamping latency, found in its cadence
/// ([`Estimator::take_latency_step`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatencyStep {
    /// The stream whose stamps moved.
    pub stream: Stream,
    /// How much later its stamps come now, seconds (negative: earlier). The offset
    /// moves by minus this for the camera, by this for the LiDAR.
    pub step_s: f64,
    /// The stamp (on that stream's clock) of its first sample, ns.
    pub t_ns: Nanos,
    /// Whether the estimator checks it against a period less (a frame dropped at it).
    pub checked: bool,
}

/// A cadence step is tested against a period less (a frame dropped at it) when
/// its stream drops at least this share of frames.
const CADENCE_AMBIGUITY_MIN: f64 = 0.002;
/// Uncertainty of that alternative step, s (the stamps measure both to a
/// fraction of a millisecond).
const CADENCE_ALT_STD_S: f64 = 1e-3;
/// ...and when it is at least this large, s ...
const CADENCE_CHECK_MIN_STEP_S: f64 = 0.004;
/// ...and the stream's previous cadence step is at least this long before it, ns.
const CADENCE_ISOLATION_NS: Nanos = 5_000_000_000;

/// The step a hint announces by default (1σ), seconds: the seed article's load
/// steps were ±25 ms. `vlsyncd`'s load hints and `bench --known-steps --hinted` use it.
pub const HINT_STEP_STD_S: f64 = 0.025;

/// What a hinted change may have done to the offset.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Hint {
    /// Variance of the step the hint announces (about 0 when `alt` is known).
    v_step: f64,
    /// The one step the alternative to "no step" is, s (a stream's cadence whose
    /// step could also have been a frame period less, with a frame dropped at it);
    /// `None`: a step of any size, `v_step` its variance.
    alt: Option<f64>,
    /// Prior log-odds of the step against no step.
    logit: f64,
}

/// The old segment at a hinted change (see [`Estimator::hint_change`]).
#[derive(Debug, Clone, Copy)]
struct HintPrior {
    /// Offset at the change, s, and its variance.
    o: f64,
    v: f64,
    /// What the hint announced.
    hint: Hint,
    /// Tracker time of the change.
    t: f64,
    /// Where the old segment started (grid index, tracker time).
    start_k: i64,
    start_t: f64,
}

/// Online offset/drift estimator. Push samples of both streams in any
/// interleaving; poll estimates. Allocates nothing after [`Estimator::new`].
///
/// The correlation does not depend on the interleaving; the judgement of a clock
/// jump does: a stream's jump is its step less the other stream's progress
/// meanwhile, so push samples in the order they were made (by stamp offline, by
/// publish time live, as `vlsyncd run` does) for a restart of both clocks to be read
/// right. One stream's backlog pushed before the other's counts as time passed.
#[derive(Debug, Clone)]
pub struct Estimator {
    p: Params,
    /// Each stream's stamp cadence: the internal stamps the resamplers interpolate
    /// at, and the latency levels added back to what is reported.
    cad: [Cadence; 2],
    rs: [Resampler; 2],
    bp: [BandPass; 2],
    corr: Correlator,
    seg: Segment,
    /// Step test: the segment with the last weights, its newest blocks, the rest.
    glr: [Sums; 3],
    scratch: Vec<f64>,
    group_delay_ns: Nanos,
    mode: Mode,
    ever_locked: bool,
    cur: Current,
    drift: DriftFit,
    /// Drift estimate and variance, refreshed each hop.
    d: (f64, f64),
    /// The current segment holds blocks from this LiDAR grid index on.
    seg_start_k: i64,
    /// Tracker time of the start of the current segment (estimates before it
    /// come from the previous segment's prediction).
    seg_start_t: f64,
    /// Tracker time of the newest hop with motion and an accepted segment measurement.
    info_t: f64,
    /// The segment started at a change point and has not given an estimate yet.
    fresh: bool,
    /// The last segment measurement (offset) and its regression `(α, β)`: the next
    /// hop re-weights from them before its single combination.
    seg_fit: Option<(f64, (f64, f64))>,
    /// The step test of the last tracking hop, run in stages by the next pushes.
    step_job: Option<StepJob>,
    /// While a step test's later stage runs: the sample rate its first stage saw
    /// (every push moves the streams' mean intervals).
    step_rate: Option<f64>,
    /// The segment's last joint (offset, drift) maximum's drift, where the next
    /// hop's drift hypotheses centre ([`Estimator::start_joint`]).
    joint_d: Option<f64>,
    /// The newest raw window measurements, for their trend.
    raw_trend: RawTrend,
    /// The last tracking hop's joint maximum, run in stages by the next pushes once
    /// its step test is done.
    joint_job: Option<JointJob>,
    /// The next hop's joint maximum's first round, prepared for these inputs, and
    /// its hypotheses done.
    /// (Key, its first block's store index, hypotheses done.)
    joint_prep: Option<(JointKey, usize, usize)>,
    /// Whether the first round of the joint maximum is prepared before its hop
    /// (always, except in the test that compares it with the direct one).
    prepare_joint: bool,
    /// Joint maxima started, and those whose first round was prepared.
    joint_hops: (u64, u64),
    /// Whether the joint maximum runs one stage per push (always, except in the test
    /// that compares it with the whole maximum at the end of its hop).
    split_joint: bool,
    /// Whether the step test runs one stage per push (always, except in the test
    /// that compares it with the whole test at once).
    split_step: bool,
    /// Whether the next hop's segment combination is prepared in stages before its
    /// block completes (always, except in the test that compares it with the
    /// direct combination).
    prepare: bool,
    /// Segment measurements, and those from a prepared combination.
    prepared_hops: (u64, u64),
    /// Whether the last push's stage before its sample ran a step-test stage.
    staged: bool,
    /// After an accepted sample, until its stage after it ran: whether the push
    /// completed no hop.
    pushed: Option<bool>,
    /// Variance added to the estimate while the step test sees a change it cannot
    /// confirm yet (a possible step's size squared, weighted by its evidence).
    suspect_var: f64,
    /// Accumulated step-test evidence of the current streak.
    step_evidence: f64,
    /// The newest disjoint short-window innovations `(ν, var)` of this segment,
    /// newest first (`innov_n` of them valid).
    innov: [(f64, f64); BIAS_WINDOWS],
    innov_n: usize,
    /// Squared bias of the estimate the innovations show (unbiased: their weighted
    /// mean squared, less its variance), added to the reported variance.
    bias_var: f64,
    /// A change point announced from outside ([`Estimator::declare_change`]), as a
    /// LiDAR grid index, applied once the data reach past it.
    known_change: Option<i64>,
    /// The step the pending `known_change` may have made, when it is only a hint
    /// ([`Estimator::hint_change`], an ambiguous cadence step).
    hint: Option<Hint>,
    /// After a hinted change: the old offset at the change and the old segment's
    /// start, weighed against the new segment until it is as precise alone
    /// ([`Self::hinted`]).
    seg_prior: Option<HintPrior>,
    /// The newest latency step a cadence found, until taken.
    latency_step: Option<LatencyStep>,
    /// The newest move of the search, until taken.
    search_move: Option<SearchMove>,
    /// The newest offset step the step test found, until taken.
    offset_step: Option<OffsetStep>,
    /// Per stream, the internal time of its cadence's last step.
    last_cadence_step: [Option<Nanos>; 2],
    epoch_ns: Option<Nanos>,
    polarity: Polarity,
    acq: Streak,
    step: Streak,
    /// Hops since the last short-window measurement given to the drift fit.
    since_chunk: usize,
    /// Consecutive hops with motion but no usable peak near the prediction.
    blind_moving: usize,
    /// Recent acquisition-window variances of each signal (the motion gate's reference).
    motion_hist: [History; 2],
    /// Per stream: the other stream's newest accepted time, and the clock jumps it
    /// had taken in all, when this stream's newest sample was accepted (tells a
    /// silence from a clock step, also when both clocks step together).
    other_at_last: [Option<(Nanos, Nanos)>; 2],
    /// Per stream: the sum of the clock jumps taken ([`Estimator::clock_jump`]).
    jumps: [Nanos; 2],
    /// Where an acquisition that finds nothing searches next: the start's range
    /// (centred on `lag_center_s`) when the search is elsewhere (set by a clock jump
    /// and by losing a lock: the prediction that put the range where it is may be
    /// wrong), then the range it left. `None`: nowhere else (at the start's range, or
    /// the range left could not be served, [`Estimator::check_unserved`]).
    alt_lag0: Option<i64>,
    /// Acquisition hops with motion since the range last moved (a lock
    /// lost within `RECENTRE_HOPS` hops does not reset them: at a wrong centre the
    /// signatures' own structure can lock for a few seconds).
    acq_tries: usize,
    /// Tracking hops since the last lock.
    locked_hops: usize,
    /// Where the watch of [`Estimator::check_unserved`] started: the LiDAR's and the
    /// camera's newest times, and the correlator's hops counted then.
    unserved_since: Option<(Nanos, Option<Nanos>, u64)>,
    /// Hops the correlator completed (blind estimates of a stall not counted).
    hops_done: u64,
    degraded: bool,
    queue: Queue,
    seq: u64,
    stats: EstimatorStats,
}

impl Estimator {
    /// Builds an estimator. `cfg` should be validated ([`EstimatorConfig::validate`]);
    /// out-of-range values are clamped to the validated ranges.
    pub fn new(cfg: &EstimatorConfig) -> Self {
        let p = Params::new(cfg);
        let n_lags = (2 * p.half_lags + 1) as usize;
        let ring_len = n_lags + 2 * p.stall_slots as usize + 64;
        let corr = Correlator::new(
            n_lags,
            p.center_lag - p.half_lags,
            p.hop_len,
            p.acq_blocks,
            p.seg_blocks,
            ring_len,
        );
        let max_gap_ns = p.max_gap_ns;
        let reset_ns = (cfg.reset_jump_s.clamp(0.1, 1e6) * 1e9) as Nanos;
        let max_abs = if cfg.max_abs_value.is_finite() && cfg.max_abs_value > 0.0 {
            cfg.max_abs_value
        } else {
            1e6
        };
        let rs = Resampler::new(p.dt_ns, max_gap_ns, reset_ns, max_abs);
        let bp = BandPass::new(p.highpass_hz, p.lowpass_hz, p.fs);
        // the band's geometric centre carries most of the timing information
        let f_mid = if p.highpass_hz > 0.0 {
            (p.highpass_hz * p.lowpass_hz)
                .sqrt()
                .max(0.3 * p.lowpass_hz)
        } else {
            0.3 * p.lowpass_hz
        };
        let group_delay_ns = (bp.group_delay_s(f_mid) * 1e9).round() as Nanos;
        let cad = |enabled| {
            Cadence::new(CadenceParams {
                enabled,
                min_step_ns: cfg.cadence_min_step_s * 1e9,
                confirm: cfg.cadence_confirm as usize,
            })
        };
        Self {
            cad: [cad(cfg.cadence.camera()), cad(cfg.cadence.lidar())],
            rs: [rs.clone(), rs],
            bp: [bp.clone(), bp],
            seg: Segment::new(n_lags, p.seg_blocks),
            glr: [Sums::new(n_lags), Sums::new(n_lags), Sums::new(n_lags)],
            corr,
            scratch: vec![0.0; n_lags],
            group_delay_ns,
            mode: Mode::Acquire,
            ever_locked: false,
            cur: Current {
                t: 0.0,
                o: cfg.lag_center_s,
                var: p.max_lag_s.powi(2),
            },
            drift: DriftFit::new(p.drift0, p.drift_memory_s),
            d: (0.0, p.drift0.powi(2)),
            seg_start_k: i64::MIN,
            seg_start_t: f64::NEG_INFINITY,
            info_t: f64::NEG_INFINITY,
            fresh: false,
            suspect_var: 0.0,
            seg_fit: None,
            step_job: None,
            step_rate: None,
            joint_d: None,
            raw_trend: RawTrend::default(),
            joint_job: None,
            joint_prep: None,
            prepare_joint: true,
            joint_hops: (0, 0),
            split_joint: true,
            split_step: true,
            prepare: true,
            prepared_hops: (0, 0),
            staged: false,
            pushed: None,
            step_evidence: 0.0,
            innov: [(0.0, 0.0); BIAS_WINDOWS],
            innov_n: 0,
            bias_var: 0.0,
            known_change: None,
            hint: None,
            seg_prior: None,
            latency_step: None,
            search_move: None,
            offset_step: None,
            last_cadence_step: [None; 2],
            epoch_ns: None,
            polarity: Polarity::Unknown,
            acq: Streak::default(),
            step: Streak::default(),
            since_chunk: 0,
            blind_moving: 0,
            motion_hist: [History::default(), History::default()],
            other_at_last: [None; 2],
            jumps: [0; 2],
            alt_lag0: None,
            acq_tries: 0,
            locked_hops: 0,
            unserved_since: None,
            hops_done: 0,
            degraded: false,
            queue: Queue {
                buf: [None; QUEUE],
                head: 0,
                len: 0,
            },
            seq: 0,
            stats: EstimatorStats::default(),
            p,
        }
    }

    /// Pushes one sample of `stream`. Rejected samples are counted and never reach the sums.
    ///
    /// Besides the sample's own work (and the hop it may complete), a push runs one
    /// stage of the work spread over the samples between hops: the last hop's step
    /// test, then the preparation of the next hop's combination. No sample carries
    /// both a hop and that work. [`Estimator::push_urgent`] with [`Estimator::idle`]
    /// does the same in two calls.
    pub fn push(&mut self, stream: Stream, sample: Sample) -> Result<(), RejectReason> {
        self.stage_before_push();
        let r = self.push_urgent(stream, sample);
        self.stage_after_push();
        r
    }

    /// The sample's own work only: what [`Estimator::push`] does without its stage of
    /// background work. A caller that wants each estimate out first (the daemon
    /// measures each sample's latency up to it) calls this, polls, then
    /// [`Estimator::idle`] once before the next sample: the estimates are exactly
    /// those of `push` alone. Without `idle` the estimates stay correct; the work it
    /// would have spread then lands on the samples that complete blocks.
    pub fn push_urgent(&mut self, stream: Stream, sample: Sample) -> Result<(), RejectReason> {
        self.pushed = None;
        let hops = self.stats.estimates;
        let si = idx(stream);
        let other_now = self.rs[1 - si].last_time().map(|t| (t, self.jumps[1 - si]));
        let kind = match self.rs[si].check(sample) {
            Ok(k) => k,
            Err(r) => {
                self.stats.rejected[si][r.index()] += 1;
                return Err(r);
            }
        };
        // the stamp on the stream's cadence: latency steps and jitter taken out
        let t_int = self.cad[si].push(sample.t_ns, kind.cadence());
        self.stats.cadence_steps[si] = self.cad[si].steps();
        self.stats.cadence_relearns[si] = self.cad[si].relearns();
        if let Some(st) = self.cad[si].take_step() {
            self.cadence_step(stream, st);
        }
        let Self { rs, bp, corr, .. } = self;
        let bp_s = &mut bp[si];
        let disc = rs[si].accept(sample, t_int, kind, |k, v| {
            let y = bp_s.step(v);
            match stream {
                Stream::Cam => corr.push_cam(k, y),
                Stream::Lidar => corr.push_lidar(k, y),
            }
        });
        self.stats.accepted[si] += 1;
        let other_then = std::mem::replace(&mut self.other_at_last[si], other_now);
        match disc {
            Discontinuity::None => {}
            Discontinuity::Gap => {
                self.stats.gaps[si] += 1;
                self.break_stream(stream);
            }
            Discontinuity::Reset(step) => {
                // the other stream's progress over the same span tells a silence
                // (both advanced alike) from a step of this stream's clock; a step
                // the other clock took meanwhile is no progress (both clocks stepping
                // together, e.g. a recording replayed again, move the offset by the
                // difference of their steps)
                let elapsed = match (other_now, other_then) {
                    (Some((a, ja)), Some((b, jb))) => {
                        a.saturating_sub(b).saturating_sub(ja.saturating_sub(jb))
                    }
                    _ => 0,
                };
                let interval = (self.rs[si].mean_interval_s() * 1e9) as Nanos;
                let jump = step.saturating_sub(elapsed).saturating_sub(interval);
                self.break_stream(stream);
                if jump.saturating_abs() as f64 > self.p.max_gap_ns as f64 {
                    self.stats.resets[si] += 1;
                    self.clock_jump(stream, jump);
                } else {
                    self.stats.gaps[si] += 1;
                }
            }
        }
        self.run_correlator();
        self.check_stall(stream, t_int);
        if stream == Stream::Lidar {
            self.check_unserved(t_int);
        }
        self.pushed = Some(self.stats.estimates == hops);
        Ok(())
    }

    /// One stage of the background work spread over the samples between hops (see
    /// [`Estimator::push_urgent`]); it never produces an estimate. Call it once after
    /// each `push_urgent` and its polls, when no sample is waiting.
    pub fn idle(&mut self) {
        self.stage_after_push();
        self.stage_before_push();
    }

    /// The stage a push runs before its sample: the last hop's step test (the whole
    /// test at once in the test that compares the two).
    fn stage_before_push(&mut self) {
        self.staged = self.step_job.is_some() || self.joint_job.is_some();
        if !self.split_step {
            self.finish_step();
        } else if self.step_job.is_some() {
            self.step_stage();
            return;
        }
        // then the joint maximum's combinations
        if self.split_joint {
            self.joint_stage();
        }
    }

    /// The stage a push runs after its sample: once the step test is done, and if the
    /// sample was accepted and completed no hop, the next hop's preparation.
    fn stage_after_push(&mut self) {
        if self.pushed.take() == Some(true)
            && !self.staged
            && self.step_job.is_none()
            && self.joint_job.is_none()
            && !self.prepare_stage()
        {
            self.prepare_joint_stage();
        }
    }

    /// Announces that the offset may have stepped at LiDAR time `t_lidar_ns` (the
    /// caller knows something the data cannot show quickly: a driver restarted or
    /// changed its stamping, a CPU governor switched). Once the estimator holds a
    /// step window (`step_window_s`) of data after that time, its segment restarts
    /// there, as after a detected step (counted in `EstimatorStats::steps`); a later
    /// announcement replaces an earlier one still pending, and one that precedes the
    /// current segment (a lock after it) is dropped. `vlsyncd bench --known-steps`
    /// uses it to measure how well the estimator could do if it detected the
    /// simulated load steps instantly.
    pub fn declare_change(&mut self, t_lidar_ns: Nanos) {
        // on the LiDAR's internal clock (its cadence's latency level taken out)
        let t = t_lidar_ns.saturating_sub(self.cad[1].level().round() as Nanos);
        self.change_at_internal(t, None);
    }

    /// A change (or, with `hint`, a possible one) at internal LiDAR time `t`.
    fn change_at_internal(&mut self, t: Nanos, hint: Option<Hint>) {
        let k = t.saturating_add(self.group_delay_ns) / self.p.dt_ns;
        self.known_change = Some(k);
        self.hint = hint;
    }

    /// Like [`Self::declare_change`], for a change that may not have happened: a
    /// hint such as a CPU-load change (`vlsyncd`'s `daemon.load_hints`). The segment
    /// restarts at `t_lidar_ns` alike, but until the new segment alone is as
    /// precise as the old offset, the estimate weighs "no step" against "a step of
    /// about `step_std_s`" by the data; then a step keeps the new segment and no step
    /// gives the old one its history back. A hint without a step costs a few
    /// noisier seconds, not the history.
    pub fn hint_change(&mut self, t_lidar_ns: Nanos, step_std_s: f64) {
        let s = if step_std_s.is_finite() {
            step_std_s.clamp(1e-4, 1.0)
        } else {
            HINT_STEP_STD_S
        };
        let t = t_lidar_ns.saturating_sub(self.cad[1].level().round() as Nanos);
        let hint = Hint {
            v_step: s * s,
            alt: None,
            logit: 0.0,
        };
        self.change_at_internal(t, Some(hint));
    }

    /// A stream's cadence found a latency step (its stamps say how large, and the
    /// estimates add it back: the correlation sees none). A step to later stamps
    /// on a stream that drops frames may instead have been a period less, a frame
    /// dropped at it: the internal stamps then moved by a period. The estimator
    /// tests that as a hint with that one alternative, weighed by the stream's
    /// share of dropped frames; the data tell the two apart within the first
    /// seconds after the step (a period is 33 ms at 30 Hz), and "no step" gives the
    /// segment its history back.
    fn cadence_step(&mut self, stream: Stream, st: cadence::CadenceStep) {
        let si = idx(stream);
        // only a step on its own is checked: one of a run (a pipeline falling behind
        // and catching up steps every second or two) or a small one (its alternative
        // would be a latency falling by nearly a period, a frame dropped just then) is
        // taken as read, and a check still open is not restarted
        let isolated = self.last_cadence_step[si]
            .is_none_or(|t| st.start.saturating_sub(t) > CADENCE_ISOLATION_NS);
        self.last_cadence_step[si] = Some(st.start);
        let checked = self.mode == Mode::Locked
            && st.ambiguity >= CADENCE_AMBIGUITY_MIN
            && isolated
            && st.step_ns.abs() * 1e-9 >= CADENCE_CHECK_MIN_STEP_S
            && self.known_change.is_none()
            && self.seg_prior.is_none();
        self.latency_step = Some(LatencyStep {
            stream,
            step_s: st.step_ns * 1e-9,
            t_ns: st
                .start
                .saturating_add(self.cad[si].level_at(st.start).0.round() as Nanos),
            checked,
        });
        if !checked {
            return;
        }
        let p = st.ambiguity.clamp(CADENCE_AMBIGUITY_MIN, 0.5);
        let period = st.period_ns * 1e-9;
        // a frame dropped at the step: the frames after it are one later than the
        // cadence counts, their internal stamps a period early (the camera's: the
        // offset a period more; the LiDAR's: a period less)
        let (alt, t) = match stream {
            Stream::Cam => (period, st.start.saturating_add((self.cur.o * 1e9) as Nanos)),
            Stream::Lidar => (-period, st.start),
        };
        let hint = Hint {
            v_step: CADENCE_ALT_STD_S * CADENCE_ALT_STD_S,
            alt: Some(alt),
            logit: (p / (1.0 - p)).ln(),
        };
        self.change_at_internal(t, Some(hint));
    }

    /// Takes the oldest pending estimate, if any.
    pub fn poll(&mut self) -> Option<Estimate> {
        self.queue.pop()
    }

    /// The stamping-latency step the last push found in a stream's cadence, if any
    /// (taken once): for a caller that logs it.
    pub fn take_latency_step(&mut self) -> Option<LatencyStep> {
        self.latency_step.take()
    }

    /// The newest move of the acquisition's lag range, if any since the last call
    /// (taken once): for a caller that logs it.
    pub fn take_search_move(&mut self) -> Option<SearchMove> {
        self.search_move.take()
    }

    /// The newest offset step found in the data, if any since the last call (taken
    /// once): for a caller that logs it.
    pub fn take_offset_step(&mut self) -> Option<OffsetStep> {
        self.offset_step.take()
    }

    /// Counters.
    pub fn stats(&self) -> &EstimatorStats {
        &self.stats
    }

    /// Current state (the state of the last estimate).
    pub fn state(&self) -> EstimatorState {
        self.current_state(false)
    }

    /// Degraded mode, for a caller over its latency budget: once locked, no lags
    /// are updated beyond those tracking reads ([`TRACK_SPARE_SLOTS`] fewer each
    /// side). Nothing stored is forgotten.
    pub fn set_degraded(&mut self, on: bool) {
        self.degraded = on;
    }

    /// Whether degraded mode is on.
    pub fn degraded(&self) -> bool {
        self.degraded
    }

    /// Starts from a previously saved estimate (e.g. after a restart): the state is
    /// `holding` around `est.offset_s` with the standard deviation inflated for
    /// `age_s` seconds of blindness, and the search is centred on it.
    pub fn restore(&mut self, est: &Estimate, age_s: f64) {
        if !(est.offset_s.is_finite()
            && est.drift.is_finite()
            && est.offset_std_s.is_finite()
            && est.drift_std.is_finite())
        {
            return;
        }
        let age = if age_s.is_finite() {
            age_s.clamp(0.0, 1e9)
        } else {
            0.0
        };
        // the last hop's step test, as it would have run at the next push
        self.finish_step();
        self.finish_joint();
        let drift = est.drift.clamp(-drift::MAX_DRIFT, drift::MAX_DRIFT);
        let drift_std = est.drift_std.clamp(1e-9, self.p.drift0.max(1e-9));
        // blind for `age` seconds: the offset moved by the drift, and its uncertainty
        // grew like a holding state's (plus the drift's); never surer than one
        // measurement can be (a saved 0 would gate out every measurement against it)
        let std = est.offset_std_s.max(MIN_MEAS_STD_S);
        let var = std * std + self.p.q_hold.powi(2) * age + (drift_std * age).powi(2);
        // the offset between the internal stamps (both cadences' levels taken out)
        let levels = (self.cad[1].level() - self.cad[0].level()) * 1e-9;
        self.cur = Current {
            t: 0.0,
            o: est.offset_s + drift * age - levels,
            var,
        };
        self.d = (drift, drift_std * drift_std);
        self.epoch_ns = None;
        self.ever_locked = true;
        self.polarity = est.polarity;
        // tracking around the restored value (state `holding` until a measurement);
        // without a peak near it while moving, the estimator turns `lost` and re-acquires
        self.mode = Mode::Locked;
        self.locked_hops = 0;
        // a lost restored lock searches the start's range next (see `lose`)
        self.acq_tries = 0;
        self.alt_lag0 = None;
        self.unserved_since = None;
        self.info_t = f64::NEG_INFINITY;
        let lag = (self.cur.o * self.p.fs).round() as i64;
        self.corr.set_lag0(lag.saturating_sub(self.p.half_lags));
        self.new_segment(i64::MIN, f64::NEG_INFINITY);
    }

    fn break_stream(&mut self, stream: Stream) {
        let si = idx(stream);
        self.bp[si].reset();
        match stream {
            Stream::Cam => self.corr.break_cam(),
            Stream::Lidar => self.corr.break_lidar(),
        }
    }

    /// Starts a new segment at LiDAR grid index `k` (tracker time `t`); the drift
    /// fit keeps the slope of the old one.
    fn new_segment(&mut self, k: i64, t: f64) {
        self.seg_prior = None;
        self.innov_n = 0;
        self.bias_var = 0.0;
        self.fresh = false;
        self.seg_start_k = k;
        self.seg_start_t = t;
        self.drift.close_segment();
        self.step = Streak::default();
        self.since_chunk = 0;
    }

    /// A stream's clock stepped by `jump_ns` (beyond one sample interval): the offset
    /// moves by the same amount (LiDAR: +, camera: -); re-acquire around the new value.
    fn clock_jump(&mut self, stream: Stream, jump_ns: Nanos) {
        self.finish_step();
        self.finish_joint();
        let si = idx(stream);
        self.jumps[si] = self.jumps[si].saturating_add(jump_ns);
        let j = jump_ns as f64 * 1e-9;
        let shift = match stream {
            Stream::Cam => -j,
            Stream::Lidar => j,
        };
        let interval = self.rs[idx(stream)].mean_interval_s();
        self.cur.o += shift;
        self.cur.var += interval * interval;
        self.epoch_ns = None;
        // the offset is kept if both clocks stepped alike (a recording replayed
        // again) but may be anything if the sensors began a new session: when the
        // start's range is near, search midway, covering both the prediction and
        // the start's centre (its range stays the alternative)
        let lag = (self.cur.o * self.p.fs).round() as i64;
        let home = self.home_lag();
        let centre = if lag.abs_diff(home) <= self.p.half_lags.unsigned_abs() {
            home + (lag - home) / 2
        } else {
            lag
        };
        self.corr.set_lag0(centre.saturating_sub(self.p.half_lags));
        self.corr.clear_blocks();
        if stream == Stream::Lidar {
            // the grid is on the LiDAR clock: its indices moved with it
            self.corr.restart_cursor();
        }
        self.known_change = None;
        self.enter_acquisition();
        self.acq = Streak::default();
        self.acq_tries = 0;
        self.alt_lag0 = self.home_alt();
        // the watch's times are on the clock before the step
        self.unserved_since = None;
        self.new_segment(i64::MIN, f64::NEG_INFINITY);
    }

    /// The lag range's position at the start (centred on `lag_center_s`), as the
    /// alternative of an acquisition elsewhere; `None` when the range is there.
    fn home_alt(&self) -> Option<i64> {
        let home = self.home_lag().saturating_sub(self.p.half_lags);
        (self.corr.lag0() != home).then_some(home)
    }

    /// The start's centre (`lag_center_s`, an offset of the stamps as they come) as
    /// a lag of the internal stamps the correlator sees: both cadences' latency
    /// levels taken out, as from every offset it measures. The levels add up every
    /// latency step the cadences follow, also across clock jumps: after hours of
    /// load steps or a few restarted sessions they reach hundreds of milliseconds,
    /// and the start's range taken as is missed the offset (a soak's fourth session
    /// searched for an hour without a lock).
    fn home_lag(&self) -> i64 {
        let levels = (self.cad[1].level() - self.cad[0].level()) * 1e-9;
        let shift = (levels * self.p.fs).round();
        if shift.is_finite() {
            self.p.center_lag.saturating_sub(shift as i64)
        } else {
            self.p.center_lag
        }
    }

    /// Counts an acquisition hop that could have locked (the window moved); after
    /// `RECENTRE_HOPS` of them, unless consistent peaks are building a lock here,
    /// the lag range moves to the alternative centre ([`Estimator::alt_lag0`]) and
    /// the one it left becomes the alternative: a wrong prediction (a restored state
    /// off, two clocks that stepped apart) cannot keep the search away from the
    /// offset. Returns whether it moved.
    fn acquisition_try(&mut self) -> bool {
        if self.mode != Mode::Acquire {
            return false;
        }
        self.acq_tries += 1;
        // not while consistent peaks are building up to a lock here
        if self.acq_tries < RECENTRE_HOPS || self.acq.count > 0 {
            return false;
        }
        self.acq_tries = 0;
        self.move_search(SearchMoveReason::NothingFound)
    }

    /// Moves the lag range to [`Estimator::alt_lag0`] (the one it leaves becomes the
    /// alternative) and restarts the acquisition there; `false` when there is no
    /// alternative.
    fn move_search(&mut self, reason: SearchMoveReason) -> bool {
        let Some(to) = self.alt_lag0 else {
            return false;
        };
        // reported as offsets of the stamps as they come (the cadences' levels added
        // back, as to every estimate), comparable with the published offsets
        let levels = (self.cad[1].level() - self.cad[0].level()) * 1e-9;
        let centre =
            |lag0: i64| lag0.saturating_add(self.p.half_lags) as f64 * self.p.dt_s + levels;
        self.search_move = Some(SearchMove {
            from_s: centre(self.corr.lag0()),
            to_s: centre(to),
            reason,
            after_s: RECENTRE_HOPS as f64 * self.p.hop_len as f64 * self.p.dt_s,
        });
        self.acq_tries = 0;
        self.alt_lag0 = Some(self.corr.lag0());
        self.corr.set_lag0(to);
        self.corr.clear_blocks();
        // the old prediction may have made the camera look far ahead of the LiDAR
        // (check_stall), and the cursor skip past the data
        self.corr.pull_cursor_back();
        self.acq = Streak::default();
        let o = to.saturating_add(self.p.half_lags) as f64 * self.p.dt_s;
        self.cur.var += (o - self.cur.o).powi(2);
        self.cur.o = o;
        self.stats.recentres += 1;
        true
    }

    fn run_correlator(&mut self) {
        loop {
            if (self.step_job.is_some() || self.joint_job.is_some())
                && self.corr.may_complete_block()
            {
                self.finish_step();
                self.finish_joint();
            }
            match self.corr.step() {
                Step::Idle => break,
                Step::Added | Step::Break => {}
                Step::Hop => self.hop(),
            }
        }
    }

    /// If the newest sample is far ahead of the correlation cursor (the other
    /// stream stopped), emit predict-only estimates for the missed hops.
    fn check_stall(&mut self, stream: Stream, t_ns: Nanos) {
        let Some(cur) = self.corr.cursor() else {
            return;
        };
        let t_l = match stream {
            Stream::Lidar => t_ns,
            Stream::Cam => t_ns.saturating_add((self.cur.o * 1e9) as Nanos),
        };
        let k_now = t_l.div_euclid(self.p.dt_ns);
        if k_now.saturating_sub(cur) <= self.p.stall_slots {
            return;
        }
        let hl = self.p.hop_len;
        let target = (k_now - self.p.stall_slots).div_euclid(hl) * hl;
        // the boundary at (or before) the cursor has been emitted already
        let first = (cur.div_euclid(hl) + 1) * hl;
        if target < first {
            return;
        }
        self.finish_step();
        self.finish_joint();
        // at most one queue's worth of blind estimates
        let start = first.max(target - (QUEUE as i64 - 1) * hl);
        let mut b = start;
        while b <= target {
            let t_ref = self.t_ref_of(b);
            let t = self.rel(t_ref);
            self.hold_to(t);
            // a silent sensor (not just a still robot) may come back with another
            // latency: after two windows without data, re-acquire instead of holding
            if self.mode == Mode::Locked && t - self.info_t > 2.0 * self.p.window_s {
                self.lose();
            }
            let st = self.current_state(false);
            self.emit(t_ref, st, None, 0.0, 0.0);
            b += hl;
        }
        self.corr.skip_to(target);
        // the acquisition window never spans a silence; the segment may
        self.corr.restart_acq();
        self.acq = Streak::default();
        self.step = Streak::default();
    }

    /// Both streams deliver (the camera advanced by half the watch), yet the
    /// correlator completed no hop for `RECENTRE_HOPS` hops of LiDAR time (blind
    /// estimates of a stall do not count): the lag range is so far off (a restored
    /// offset of days) that the correlator waits for camera data it will never get,
    /// or the offset's mapping of camera time makes the LiDAR look stalled. The lock,
    /// if any, is lost and the search moves to [`Estimator::alt_lag0`] at once; the
    /// range it left is not searched again.
    fn check_unserved(&mut self, t_lidar: Nanos) {
        let cam = self.rs[0].last_time();
        let now = (t_lidar, cam, self.hops_done);
        let (t0, cam0, hops0) = *self.unserved_since.get_or_insert(now);
        let limit = (RECENTRE_HOPS as i64).saturating_mul(self.p.hop_len * self.p.dt_ns);
        // the camera must have delivered over the watch too (a silent camera is a
        // stall: blind estimates, then lost, see check_stall)
        let cam_moved = match (cam0, cam) {
            (Some(a), Some(b)) => b.saturating_sub(a) > limit / 2,
            _ => false,
        };
        if self.hops_done != hops0 || t_lidar < t0 {
            self.unserved_since = Some(now);
        } else if t_lidar.saturating_sub(t0) > limit {
            self.unserved_since = Some(now);
            if !cam_moved {
                return;
            }
            self.finish_step();
            self.finish_joint();
            if self.mode == Mode::Locked {
                self.lose();
            }
            if self.move_search(SearchMoveReason::Unserved) {
                // the range just left could not be served: no way back to it
                self.alt_lag0 = None;
            }
        }
    }

    /// Tracker time of LiDAR time `t_ns`. After a clock jump the epoch is
    /// re-anchored so the tracker's time continues where it was.
    fn rel(&mut self, t_ns: Nanos) -> f64 {
        let cur_t = self.cur.t;
        let e = *self
            .epoch_ns
            .get_or_insert_with(|| t_ns.saturating_sub((cur_t * 1e9) as Nanos));
        t_ns.saturating_sub(e) as f64 * 1e-9
    }

    /// Reference time (LiDAR clock, ns) of the hop ending before grid index `k_next`:
    /// the filter's output delay and the reference lag before it (saturating: stamps
    /// near the ends of the i64 range must not overflow).
    fn t_ref_of(&self, k_next: i64) -> Nanos {
        k_next
            .saturating_mul(self.p.dt_ns)
            .saturating_sub(self.group_delay_ns)
            .saturating_sub(self.p.ref_lag_ns)
    }

    /// Tracker time of (fractional) LiDAR grid index `k`, at the filter's output delay.
    fn rel_k(&mut self, k: f64) -> f64 {
        let t_ns = ((k * self.p.dt_ns as f64) as Nanos).saturating_sub(self.group_delay_ns);
        self.rel(t_ns)
    }

    fn meas_var(&self, pk: &peak::Peak, n: f64, min_rate: f64) -> f64 {
        let rho = pk.score.clamp(1e-3, 0.999);
        let kappa = (pk.curvature / (self.p.dt_s * self.p.dt_s)).max(1e-6);
        let band = (self.p.lowpass_hz.min(0.5 * min_rate) - self.p.highpass_hz).max(0.1);
        let n_eff = (2.0 * band * n / self.p.fs).max(1.0);
        // the small-error formula (1 - ρ²)/(ρ κ n_eff); measured on simulated runs,
        // errors shrink faster with the window than 1/n (slow signature mismatch averages
        // out), about n^-1.5: calibrated to 1 at a 4 s window
        let secs = (n / self.p.fs).max(1e-3);
        let var = self.p.noise_scale * (1.0 - rho * rho) / (rho * kappa * n_eff)
            * (CAL_WINDOW_S / secs).sqrt();
        var.max(MIN_MEAS_STD_S * MIN_MEAS_STD_S)
    }

    /// The slower stream's mean sample rate (it bounds the band a measurement's
    /// variance counts); during a step test's later stages, the rate its first stage saw.
    fn min_rate(&self) -> f64 {
        if let Some(r) = self.step_rate {
            return r;
        }
        let r = |i: usize| {
            let m = self.rs[i].mean_interval_s();
            if m > 0.0 {
                1.0 / m
            } else {
                self.p.fs
            }
        };
        r(0).min(r(1))
    }

    /// Peak of `sums` within `lo..=hi` with polarity `sign` (0: free).
    fn measure_sums(&mut self, which: Which, lo: usize, hi: usize, sign: f64) -> Option<Meas> {
        let min_rate = self.min_rate();
        let sums: &Sums = match which {
            Which::Acq => self.corr.acq(),
            Which::Seg => &self.seg.sums,
            Which::Glr(i) => &self.glr[i],
        };
        let pk = peak::find(sums, lo, hi, sign, &mut self.scratch)?;
        let n = sums.n;
        let z = (self.corr.lag0() as f64 + pk.slot) * self.p.dt_s;
        Some(Meas {
            z,
            var: self.meas_var(&pk, n, min_rate),
            score: pk.score,
            ratio: pk.ratio,
            sign: pk.sign,
        })
    }

    /// Motion gate on the acquisition window: both signals vary at least
    /// `min_motion_ratio` of their typical variance, the upper quartile of the
    /// acquisition windows of the last [`MOTION_HISTORY`] hops. A quantile rather than
    /// a decaying maximum: a few seconds of one signature spiking (a turn sweeping the
    /// LiDAR's window across a corner) must not make ordinary motion look like none.
    fn motion_ok(&mut self, update_ref: bool) -> bool {
        let w = self.corr.acq();
        let mid = self.corr.n_lags() / 2;
        let (a, b) = self.corr.active();
        // within the slots the window holds (all of them but after a lag shift); a
        // window whose blocks share none cannot tell
        if w.lo > w.hi {
            return false;
        }
        let slot = mid.clamp(a, b).clamp(w.lo, w.hi);
        let v = [w.var_y(slot), w.var_x()];
        let mut ok = true;
        for (h, &vi) in self.motion_hist.iter_mut().zip(v.iter()) {
            if update_ref {
                h.push(vi);
            }
            let r = h.upper_quartile();
            if !(vi > 0.0 && vi >= self.p.min_motion * r) {
                ok = false;
            }
        }
        ok
    }

    /// The motion references: the upper quartiles of the acquisition windows'
    /// camera and LiDAR variances over the last [`MOTION_HISTORY`] hops.
    fn motion_refs(&mut self) -> [f64; 2] {
        let [c, l] = &mut self.motion_hist;
        [c.upper_quartile(), l.upper_quartile()]
    }

    /// Whether the short-window combination in `self.seg.sums` moves as the motion
    /// gate asks (both signals at least `min_motion_ratio` of `refs`) at the lag of
    /// offset `z`. A window at the end of motion (the robot slowing to a stop) can
    /// show a confident peak in what is only noise: it must not measure a step.
    fn seg_moving(&self, z: f64, refs: [f64; 2]) -> bool {
        let sums = &self.seg.sums;
        let last = self.corr.n_lags().saturating_sub(1);
        let slot = (z * self.p.fs - self.corr.lag0() as f64).round();
        let slot = (slot.max(0.0) as usize).min(last);
        let v = [sums.var_y(slot), sums.var_x()];
        v.iter()
            .zip(refs)
            .all(|(&vi, r)| vi > 0.0 && vi >= self.p.min_motion * r)
    }

    /// Offset and variance predicted at tracker time `t` from the current estimate.
    fn predict(&self, t: f64) -> (f64, f64) {
        let dt = t - self.cur.t;
        let (d, vd) = self.d;
        (
            self.cur.o + d * dt,
            self.cur.var + vd * dt * dt + self.p.qo * self.p.qo * dt.abs(),
        )
    }

    /// Moves the estimate to time `t` without a measurement: the offset follows the
    /// drift, the uncertainty grows (faster once no measurement came for a window).
    fn hold_to(&mut self, t: f64) {
        if !self.ever_locked {
            self.cur.t = t;
            return;
        }
        let dt = t - self.cur.t;
        if dt <= 0.0 {
            return;
        }
        let q = if t - self.info_t > self.p.window_s {
            self.p.q_hold
        } else {
            self.p.qo
        };
        let (d, vd) = self.d;
        self.cur = Current {
            t,
            o: self.cur.o + d * dt,
            var: self.cur.var + vd * dt * dt + q * q * dt,
        };
        if self.mode == Mode::Locked && self.cur.var > self.p.lost_var {
            self.lose();
        }
    }

    /// The lock is gone: re-acquire (state `lost` once it had locked).
    fn lose(&mut self) {
        self.step_job = None;
        self.corr.restart_acq();
        self.enter_acquisition();
        self.acq = Streak::default();
        self.blind_moving = 0;
        if self.locked_hops >= RECENTRE_HOPS || self.alt_lag0.is_none() {
            self.acq_tries = 0;
            self.alt_lag0 = self.home_alt();
        }
    }

    /// Acquisition searches every lag of the range: degraded mode's narrowing
    /// around the prediction ([`Estimator::set_degraded`]) is for a lock only (it
    /// used to outlive the lock, so a daemon kept over budget searched only the
    /// lags near the prediction it had lost, and found nothing elsewhere).
    fn enter_acquisition(&mut self) {
        self.mode = Mode::Acquire;
        self.raw_trend.clear();
        let n = self.corr.n_lags();
        self.corr.set_active(0, n - 1);
    }

    fn current_state(&self, measured: bool) -> EstimatorState {
        match (self.mode, self.ever_locked) {
            (Mode::Acquire, false) => EstimatorState::Acquiring,
            (Mode::Acquire, true) => EstimatorState::Lost,
            (Mode::Locked, _) if measured => EstimatorState::Tracking,
            (Mode::Locked, _) => EstimatorState::Holding,
        }
    }

    fn hop(&mut self) {
        self.hops_done += 1;
        self.hop_inner();
        if !self.split_joint {
            self.finish_joint();
        }
        self.joint_prep = None;
        // what was prepared was for this hop (used, or its inputs changed)
        self.seg.drop_prepared();
    }

    fn hop_inner(&mut self) {
        // normally finished already, before the block that makes this hop completed
        self.finish_step();
        self.finish_joint();
        let count = self.corr.count();
        if count == 0 {
            return;
        }
        // a new block enters the segment's weights at 1
        self.seg.set_weight(&self.corr, count - 1, 1.0);
        let k_end = self.corr.block(count - 1).last_k;
        // estimates refer to `reference_lag_s` before the newest data: the segment
        // has that much data after the reference time on hand
        let t_ref_ns = self.t_ref_of(k_end.saturating_add(1));
        let t = self.rel(t_ref_ns);
        let full = self.corr.acq_count() >= self.p.acq_blocks;
        let motion = self.motion_ok(full);
        if self.corr.acq_count() < self.p.short_blocks {
            self.hold_to(t);
            let st = self.current_state(false);
            self.emit(t_ref_ns, st, None, 0.0, 0.0);
            return;
        }
        match self.mode {
            Mode::Acquire => self.hop_acquire(t_ref_ns, t, motion),
            Mode::Locked => self.hop_track(t_ref_ns, t, motion),
        }
    }

    fn hop_acquire(&mut self, t_ref_ns: Nanos, t: f64, motion: bool) {
        if motion && self.acquisition_try() {
            // the window restarts at the new range
            self.hold_to(t);
            let st = self.current_state(false);
            self.emit(t_ref_ns, st, None, 0.0, 0.0);
            return;
        }
        // the whole active range: the window restarts when the lock is lost
        let (lo, hi) = self.acq_slots(self.corr.active());
        let m = self.measure_sums(Which::Acq, lo, hi, 0.0);
        self.hold_to(t);
        // a lock's first estimate must refer to a time its window covers
        let covered = self.rel_k(self.corr.acq().first_k as f64) <= t;
        let Some(m) = m.filter(|m| {
            covered && motion && m.score >= self.p.min_score && m.ratio >= self.p.min_ratio
        }) else {
            self.acq = Streak::default();
            self.raw_trend.clear();
            let st = self.current_state(false);
            let (sc, ra) = m.map_or((0.0, 0.0), |m| (m.score, m.ratio));
            self.emit(t_ref_ns, st, m.map(|m| m.z), sc, ra);
            return;
        };
        let allowance = 3.0 * (self.p.drift0 * self.p.hop_s) + 0.002;
        let consistent = self.acq.count > 0
            && self.acq.sign == m.sign
            && (m.z - self.acq.z).abs() <= 3.0 * (m.var + self.acq.var).sqrt() + allowance;
        if !consistent {
            self.raw_trend.clear();
        }
        let w = self.corr.acq();
        let t_c = self.rel_k(0.5 * (w.first_k + w.last_k) as f64);
        self.raw_trend.push(t_c, m.z, m.var);
        self.acq = Streak {
            count: if consistent { self.acq.count + 1 } else { 1 },
            z: m.z,
            var: m.var,
            sign: m.sign,
        };
        if self.acq.count < self.p.acquire_confirm {
            let st = self.current_state(false);
            self.emit(t_ref_ns, st, Some(m.z), m.score, m.ratio);
            return;
        }
        // lock: a new segment from the acquisition window's first block
        self.polarity = if m.sign > 0.0 {
            Polarity::Positive
        } else {
            Polarity::Negative
        };
        let first_k = self.corr.acq().first_k;
        let window_t = self.rel_k(first_k as f64);
        self.new_segment(first_k, window_t);
        if !self.ever_locked {
            self.drift.reset();
        }
        let centre = 0.5 * (self.corr.acq().first_k + self.corr.acq().last_k) as f64;
        let t_c = self.rel_k(centre);
        self.halves_drift(m.z);
        self.d = self.drift.estimate();
        self.cur = Current {
            t,
            o: m.z + self.d.0 * (t - t_c),
            var: m.var,
        };
        self.mode = Mode::Locked;
        self.ever_locked = true;
        self.info_t = t;
        self.acq = Streak::default();
        self.stats.locks += 1;
        self.locked_hops = 0;
        // the lock's own estimate comes from the segment (robust, at the reference time)
        self.hop_track(t_ref_ns, t, motion);
    }

    /// Starts the segment's joint (offset, drift) maximum of this hop: its blocks
    /// combined (with the weights they have now) under three drift hypotheses
    /// around the last one, each hypothesis's peak maximised over the lag, a
    /// parabola through the three heights. Its vertex is the segment's own slope,
    /// measured from all its data at once; the parabola's curvature gives its
    /// variance as the lag's curvature gives the offset's ([`Estimator::meas_var`]).
    /// It informs the drift fit as the segment's slope measurement
    /// ([`DriftFit::set_joint`]). The combinations run one per pushed sample after
    /// the hop ([`Estimator::joint_stage`]), so its result informs the next hop's
    /// drift. Returns whether the segment can be measured.
    fn start_joint(&mut self, t_ref_ns: Nanos, t: f64, pred_t: f64, sign: f64) -> bool {
        let Some(first) = self.segment_first() else {
            return false;
        };
        let n = self.corr.count();
        let (k0, k1) = (
            self.corr.block(first).first_k,
            self.corr.block(n - 1).last_k,
        );
        let Some((lo, hi, k_ref, delta)) = self.joint_inputs(first, n, (k0, k1), t_ref_ns, pred_t)
        else {
            return false;
        };
        let c = self.joint_d.unwrap_or(self.d.0);
        self.joint_d = None;
        self.seg.snapshot_weights();
        let mut job = JointJob {
            first,
            last: n - 1,
            k_ref,
            lo,
            hi,
            sign,
            delta,
            c,
            round: 0,
            j: 0,
            h: [0.0; 3],
            nsum: [0.0; 3],
            rate: self.min_rate(),
            t,
            t_end: self.rel_k(k1 as f64),
        };
        // the first round: prepared on the samples before this hop (its new block
        // added now), else combined now; the same sums either way
        let key = JointKey {
            epoch: self.corr.epoch(),
            blocks: n - 1 - first,
            first_k: k0,
            last_k: self.corr.block(n - 2).last_k,
            k_ref,
            lo,
            hi,
            c,
            delta,
        };
        let prepared = self
            .joint_prep
            .take()
            .is_some_and(|(k, _, done)| done == 3 && k == key);
        self.joint_hops.0 += 1;
        self.joint_hops.1 += u64::from(prepared);
        for j in 0..3 {
            let span = job.span(j);
            let sums = if prepared {
                self.seg.finish_joint(&self.corr, &span, j, n - 1)
            } else {
                self.seg.combine_snapshot(&self.corr, &span);
                &self.seg.sums
            };
            job.nsum[j] = sums.n;
            let Some(pk) = peak::find(sums, lo, hi, sign, &mut self.scratch) else {
                self.joint_failed(&job);
                return true;
            };
            job.h[j] = pk.score;
        }
        // a measurement informs this hop's drift; re-centred rounds, the next hop's
        self.joint_fit(job);
        true
    }

    /// One stage of the pending joint maximum, if any: one hypothesis's combination
    /// and peak; the third of a round fits the parabola and either gives the
    /// measurement or re-centres the next round. A joint maximum that fails gives
    /// the drift fit its hop without one (it breaks the run a free slope needs).
    fn joint_stage(&mut self) {
        let Some(mut job) = self.joint_job.take() else {
            return;
        };
        let span = job.span(job.j);
        job.nsum[job.j] = self.seg.combine_snapshot(&self.corr, &span);
        let Some(pk) = peak::find(&self.seg.sums, job.lo, job.hi, job.sign, &mut self.scratch)
        else {
            self.joint_failed(&job);
            return;
        };
        job.h[job.j] = pk.score;
        job.j += 1;
        if job.j < 3 {
            self.joint_job = Some(job);
            return;
        }
        self.joint_fit(job);
    }

    /// The parabola through a round's three heights: the measurement, or the next
    /// round (re-centred, staged), or a failure.
    fn joint_fit(&mut self, mut job: JointJob) {
        let (h, delta) = (job.h, job.delta);
        // the hypotheses compare like with like only: one that shifts a block beyond
        // the lags it holds leaves it out, and a shorter combination peaks higher
        let [n0, n1, n2] = job.nsum;
        if n0 != n1 || n1 != n2 {
            self.joint_failed(&job);
            return;
        }
        let den = h[0] - 2.0 * h[1] + h[2];
        let curv = -den / (delta * delta);
        if !(curv > 0.0 && curv.is_finite()) {
            self.joint_failed(&job);
            return;
        }
        let x = (0.5 * (h[0] - h[2]) / den * delta).clamp(-2.0 * delta, 2.0 * delta);
        if x.abs() > delta {
            // too far from the hypotheses for the parabola: centre there, again
            job.round += 1;
            if job.round == JOINT_ROUNDS {
                self.joint_failed(&job);
                return;
            }
            job.c += x;
            job.j = 0;
            self.joint_job = Some(job);
            return;
        }
        let d = job.c + x;
        let rho = (h[1] + 0.25 * (h[0] - h[2]) * x / delta).clamp(1e-3, 0.999);
        let band = (self.p.lowpass_hz.min(0.5 * job.rate) - self.p.highpass_hz).max(0.1);
        let n_eff = (2.0 * band * job.nsum[1] / self.p.fs).max(1.0);
        let secs = (job.nsum[1] / self.p.fs).max(1e-3);
        let var = self.p.noise_scale * (1.0 - rho * rho) / (rho * curv * n_eff)
            * (CAL_WINDOW_S / secs).sqrt();
        self.joint_d = Some(d);
        self.drift.set_joint(job.t_end, d, var);
    }

    fn joint_failed(&mut self, job: &JointJob) {
        self.joint_d = None;
        self.drift.set_joint(job.t, f64::NAN, f64::INFINITY);
    }

    /// Runs the pending joint maximum to its end: before anything changes the stored
    /// blocks (a block completing, a stall, a clock jump) and at the next hop.
    fn finish_joint(&mut self) {
        while self.joint_job.is_some() {
            self.joint_stage();
        }
    }

    /// The two halves of the acquisition window measure the offset at two times
    /// from disjoint data: their difference informs the drift (what lets a fast
    /// drift, far outside the prior, win early).
    fn halves_drift(&mut self, o: f64) {
        let n = self.corr.count();
        let half = self.corr.acq_count() / 2;
        if half < 2 {
            return;
        }
        let sign = self.polarity.sign();
        let mut pts = [(0.0, 0.0, 0.0); 2];
        for (j, first) in [n - 2 * half, n - half].into_iter().enumerate() {
            let span = Span {
                first,
                last: first + half - 1,
                drift: 0.0,
                k_ref: 0.0,
                lo: 0,
                hi: 0,
            };
            let (lo, hi) = self.track_slots_around(o);
            let span = Span { lo, hi, ..span };
            let Some(m) = self.measure_span(&span, sign, Weights::Uniform) else {
                return;
            };
            let (k0, k1) = (self.seg.sums.first_k, self.seg.sums.last_k);
            pts[j] = (self.rel_k(0.5 * (k0 + k1) as f64), m.z, m.var);
        }
        for (t, z, v) in pts {
            self.drift.add(t, z, v);
        }
        self.drift.close_segment();
    }

    /// Combines `span` with weights `w` and measures its peak.
    fn measure_span(&mut self, span: &Span, sign: f64, w: Weights) -> Option<Meas> {
        match w {
            Weights::Uniform => self.seg.reset_weights(&self.corr, span),
            Weights::Robust => {
                self.seg.reset_weights(&self.corr, span);
                for _ in 0..IRLS_PASSES {
                    self.seg.combine(&self.corr, span);
                    let pk = peak::find(&self.seg.sums, span.lo, span.hi, sign, &mut self.scratch)?;
                    let fit = self.seg.regression(span, pk.slot)?;
                    self.seg.reweight(&self.corr, span, pk.slot, fit);
                }
            }
            Weights::Warm => {
                // the last segment measurement's peak and regression re-weight the blocks
                // before the one combination of this hop
                if let Some((z, fit)) = self.seg_fit {
                    self.seg.reweight(&self.corr, span, self.slot_of(z), fit);
                }
            }
        }
        self.seg.combine(&self.corr, span);
        let m = self.measure_sums(Which::Seg, span.lo, span.hi, sign);
        if w == Weights::Warm {
            self.seg_fit =
                m.and_then(|m| Some((m.z, self.seg.regression(span, self.slot_of(m.z))?)));
        }
        m
    }

    /// Slots `lo..=hi` narrowed to those the acquisition window holds (see
    /// [`Correlator::acq`]); empty (`lo > hi`) when they do not meet.
    fn acq_slots(&self, (lo, hi): (usize, usize)) -> (usize, usize) {
        let w = self.corr.acq();
        (lo.max(w.lo), hi.min(w.hi))
    }

    /// Slots within the tracking range around offset `o`.
    fn track_slots_around(&self, o: f64) -> (usize, usize) {
        let (a, b) = self.corr.active();
        let c = o * self.p.fs - self.corr.lag0() as f64;
        let lo = (c - self.p.track_slots).floor().max(a as f64) as usize;
        let hi = ((c + self.p.track_slots).ceil().max(0.0) as usize).min(b);
        (lo.min(hi), hi)
    }

    /// Index of the first stored block of the current segment (at most
    /// `segment_s` long), or `None` when it has fewer than the short window's blocks.
    fn segment_first(&self) -> Option<usize> {
        let n = self.corr.count();
        let oldest = n.saturating_sub(self.p.seg_blocks);
        let first = (oldest..n).find(|&i| self.corr.block(i).first_k >= self.seg_start_k)?;
        (n - first >= self.p.short_blocks).then_some(first)
    }

    /// One stage of preparing the next tracking hop's segment combination
    /// ([`Segment::prepare_residuals`], then [`Segment::prepare_sums`]) from the
    /// inputs that hop will have if no block, step or lag shift comes between: the
    /// hop then only adds its new block. A hop whose inputs differ combines
    /// directly, so a wrong guess costs time, never accuracy.
    /// Returns whether it had work.
    fn prepare_stage(&mut self) -> bool {
        if !self.prepare || self.mode != Mode::Locked || self.seg.prepared_ready() {
            return false;
        }
        if self.seg.preparing() {
            self.seg.prepare_sums(&self.corr);
            return true;
        }
        let Some((span, key)) = self.next_hop_key() else {
            return false;
        };
        self.seg.prepare_residuals(&self.corr, &span, key);
        true
    }

    /// One stage of preparing the next hop's joint maximum's first round (after the
    /// segment's preparation): one hypothesis's combination of the blocks it will
    /// hold besides its new one, from the inputs it will have if no block, step or
    /// lag shift comes between ([`JointKey`]). A hop whose inputs differ combines
    /// its first round directly: the same measurement, at a cost.
    fn prepare_joint_stage(&mut self) {
        if !self.prepare_joint || self.mode != Mode::Locked {
            return;
        }
        let Some((key, first)) = self.next_joint_key() else {
            return;
        };
        let done = match self.joint_prep {
            Some((k, _, done)) if k == key => done,
            _ => 0,
        };
        if done == 3 {
            return;
        }
        let span = Span {
            first,
            last: first + key.blocks - 1,
            drift: key.c + (done as f64 - 1.0) * key.delta,
            k_ref: key.k_ref,
            lo: key.lo,
            hi: key.hi,
        };
        self.seg.prepare_joint(&self.corr, &span, done);
        self.joint_prep = Some((key, first, done + 1));
    }

    /// The next hop's joint maximum's inputs ([`Estimator::start_joint`]), predicted,
    /// and the store index of its first block.
    fn next_joint_key(&self) -> Option<(JointKey, usize)> {
        let NextHop {
            n,
            k_end,
            t_ref_ns,
            pred_t,
            first,
        } = self.next_hop()?;
        let k0 = self.corr.block(first).first_k;
        let (lo, hi, k_ref, delta) = self.joint_inputs(first, n, (k0, k_end), t_ref_ns, pred_t)?;
        let key = JointKey {
            epoch: self.corr.epoch(),
            blocks: n - first,
            first_k: k0,
            last_k: self.corr.block(n - 1).last_k,
            k_ref,
            lo,
            hi,
            c: self.joint_d.unwrap_or(self.d.0),
            delta,
        };
        Some((key, first))
    }

    /// The joint maximum's slots, reference index and hypotheses' spacing for the
    /// segment of blocks `first..held` (those that hold its slots) spanning grid
    /// indices `k0..=k1`; `None` when it is too short or holds too few slots.
    fn joint_inputs(
        &self,
        first: usize,
        held: usize,
        (k0, k1): (i64, i64),
        t_ref_ns: Nanos,
        pred_t: f64,
    ) -> Option<(usize, usize, f64, f64)> {
        let len = (k1 - k0) as f64;
        if len < (2 * self.p.short_blocks as i64 * self.p.hop_len) as f64 - 1.0 {
            return None;
        }
        let (lo, hi) = self.track_slots_around(pred_t);
        let (held_lo, held_hi) = self.corr.slots_held(first, held);
        let (lo, hi) = (lo.max(held_lo + 4), hi.min(held_hi.saturating_sub(5)));
        if hi < lo + 4 {
            return None;
        }
        let k_ref = t_ref_ns.saturating_add(self.group_delay_ns) as f64 / self.p.dt_ns as f64;
        // hypotheses shifting the segment's far end by JOINT_SHIFT slots
        let far = (k_ref - k0 as f64)
            .abs()
            .max((k1 as f64 - k_ref).abs())
            .max(1.0);
        Some((lo, hi, k_ref, JOINT_SHIFT / far))
    }

    /// The next hop's segment (without its new block) and key, predicted.
    fn next_hop_key(&self) -> Option<(Span, PrepKey)> {
        let NextHop {
            n,
            t_ref_ns,
            pred_t,
            first,
            ..
        } = self.next_hop()?;
        if n + 1 - first < self.p.short_blocks {
            return None;
        }
        let (lo, hi) = self.track_slots_around(pred_t);
        let span = Span {
            first,
            last: n - 1,
            drift: self.drift.estimate().0,
            k_ref: t_ref_ns.saturating_add(self.group_delay_ns) as f64 / self.p.dt_ns as f64,
            lo,
            hi,
        };
        Some((span, self.prep_key(&span)))
    }

    /// What the next hop will be, as far as the blocks stored and the cursor tell:
    /// its last grid index, reference time and predicted offset, and the first
    /// stored block its segment will hold besides its new one. `None` before the
    /// tracker has a time origin (after a restore or a clock jump the next hop sets
    /// it, and nothing is prepared before: the preparation sets nothing), or when
    /// the reference time precedes the current segment (a change just detected).
    fn next_hop(&self) -> Option<NextHop> {
        let n = self.corr.count();
        let cursor = self.corr.cursor()?;
        if n == 0 {
            return None;
        }
        let epoch = self.epoch_ns?;
        let hl = self.p.hop_len;
        let k_end = (cursor.div_euclid(hl) + 1) * hl - 1;
        let t_ref_ns = self.t_ref_of(k_end.saturating_add(1));
        let t = t_ref_ns.saturating_sub(epoch) as f64 * 1e-9;
        if t < self.seg_start_t {
            return None;
        }
        let (pred_t, _) = self.predict(t);
        let oldest = (n + 1).saturating_sub(self.p.seg_blocks);
        let first = (oldest..n).find(|&i| self.corr.block(i).first_k >= self.seg_start_k)?;
        Some(NextHop {
            n,
            k_end,
            t_ref_ns,
            pred_t,
            first,
        })
    }

    /// The key of a combination of `span`'s blocks prepared for the next hop: what
    /// that hop must find unchanged to use it.
    fn prep_key(&self, span: &Span) -> PrepKey {
        PrepKey {
            epoch: self.corr.epoch(),
            first_k: self.corr.block(span.first).first_k,
            last_k: self.corr.block(span.last).last_k,
            blocks: span.last + 1 - span.first,
            drift: span.drift,
            k_ref: span.k_ref,
            lo: span.lo,
            hi: span.hi,
            fit: self.seg_fit.map(|(z, fit)| (self.slot_of(z), fit)),
        }
    }

    /// Fractional lag slot of offset `z`.
    fn slot_of(&self, z: f64) -> f64 {
        z * self.p.fs - self.corr.lag0() as f64
    }

    /// The segment's measurement at this hop: near the prediction (`near`), else over
    /// the whole tracking range (`full`), with the segment's weights re-weighted once
    /// from the last fit; with the information-weighted sums `(Σ w·n, Σ w·n·k)` of its
    /// blocks. From the prepared combination when it was prepared for these inputs.
    fn measure_segment(
        &mut self,
        near: &Span,
        full: &Span,
        sign: f64,
    ) -> Option<(Meas, (f64, f64))> {
        let n = full.last + 1;
        let prepared = if self.seg.prepared_ready() && full.last > full.first {
            let key = self.prep_key(&Span {
                last: full.last - 1,
                ..*full
            });
            self.seg.finish_prepared(&self.corr, full, &key)
        } else {
            None
        };
        self.prepared_hops.0 += 1;
        self.prepared_hops.1 += u64::from(prepared.is_some());
        self.seg.drop_prepared();
        let Some((lever, _)) = prepared else {
            let m = match self.measure_span(near, sign, Weights::Warm) {
                Some(m) => m,
                None => self.measure_span(full, sign, Weights::Warm)?,
            };
            let (mut sw, mut swk) = (0.0, 0.0);
            for i in full.first..n {
                let b = self.corr.block(i);
                let w = self.seg.weight(&self.corr, i) * b.n;
                sw += w;
                swk += w * 0.5 * (b.first_k + b.last_k) as f64;
            }
            return Some((m, (sw, swk)));
        };
        // the combination covers the whole tracking range: measure as the direct path does
        let mut used = near;
        let mut m = self.measure_sums(Which::Seg, near.lo, near.hi, sign);
        if m.is_none() {
            used = full;
            m = self.measure_sums(Which::Seg, full.lo, full.hi, sign);
        }
        self.seg_fit = m.and_then(|m| Some((m.z, self.seg.regression(used, self.slot_of(m.z))?)));
        Some((m?, lever))
    }

    /// Once locked, only the lags tracking can use are updated: the tracking range
    /// around the prediction at fractional slot `pred_slot` and [`TRACK_NEED_SLOTS`]
    /// beyond it (the segment's search and the joint maximum's hypotheses reach that
    /// far), with [`TRACK_SPARE_SLOTS`] to spare each side. When the prediction
    /// moves, the range follows by as little as keeps the needed slots in it, so the
    /// blocks of a segment (60 s) hold the needed slots too: the offset drifts well
    /// under a slot in that time, and a step starts a new segment.
    fn narrow_to(&mut self, pred_slot: f64) {
        let need = self.p.track_slots + TRACK_NEED_SLOTS;
        let spare = if self.degraded {
            0.0
        } else {
            TRACK_SPARE_SLOTS
        };
        let n = self.corr.n_lags();
        let width = (2.0 * (need + spare)).round() as usize;
        if width + 1 >= n {
            return;
        }
        let (a, b) = self.corr.active();
        let need_lo = (pred_slot - need).floor();
        let need_hi = (pred_slot + need).ceil();
        let lo = if b - a != width {
            // entering the lock, or degraded mode switched: centred on the prediction
            (pred_slot - 0.5 * width as f64).round()
        } else if need_lo < a as f64 {
            need_lo
        } else if need_hi > b as f64 {
            need_hi - width as f64
        } else {
            return;
        };
        let lo = lo.clamp(0.0, (n - 1 - width) as f64) as usize;
        self.corr.set_active(lo, lo + width);
    }

    fn hop_track(&mut self, t_ref_ns: Nanos, t: f64, motion: bool) {
        self.locked_hops = self.locked_hops.saturating_add(1);
        let sign = self.polarity.sign();
        let n = self.corr.count();
        // keep the lag range centred on the prediction (a lock near the edge, drift
        // over hours); the stored blocks move with it
        let (pred_t, pred_var) = self.predict(t);
        let mid = (self.corr.n_lags() / 2) as f64;
        let pred_slot = pred_t * self.p.fs - self.corr.lag0() as f64;
        // only when the peak could fall off the range: a shift leaves the stored
        // blocks without the lags that enter, so the segment is short for a while
        let margin = (3.0 * pred_var.sqrt() * self.p.fs).max(3.0) + 2.0;
        if (pred_slot - mid).abs() > mid - margin {
            self.corr.shift_lags((pred_slot - mid).round() as i64);
        }
        let pred_slot = pred_t * self.p.fs - self.corr.lag0() as f64;
        self.narrow_to(pred_slot);
        // 1. step test and drift chunks on the newest blocks: run in stages by the
        // next samples pushed, so no single sample carries both it and the segment,
        // nor the whole test (its verdict applies from the next hop on)
        if motion {
            self.step_job = Some(StepJob::new(sign, pred_t));
        } else {
            self.step_job = None;
            self.suspect_var = 0.0;
            self.step = Streak::default();
        }
        // the raw measurement of this hop: the acquisition window's peak near the
        // prediction, moved from the window's centre to the reference time
        let raw = if motion {
            self.raw_measurement(sign, t)
        } else {
            None
        };
        if raw.is_none() {
            self.raw_trend.clear();
        }
        // the raw trend confirms a joint slope in the segment's first seconds only
        let young = t - self.seg_start_t <= RAW_CONFIRM_S;
        let trend = self.raw_trend.slope(self.p.window_s).filter(|_| young);
        self.drift.set_raw_trend(trend);

        // the joint maximum runs on the next pushes (after the step test): its slope
        // informs the drift from the next hop on
        if !(motion
            && raw.is_some()
            && t >= self.seg_start_t
            && self.start_joint(t_ref_ns, t, pred_t, sign))
        {
            self.joint_d = None;
            self.drift.set_joint(t, f64::NAN, f64::INFINITY);
        }
        self.d = self.drift.estimate();
        // 2. the segment's offset at the reference time
        if t < self.seg_start_t {
            // the reference time precedes a change just detected: the old segment's
            // prediction is the better estimate there
            self.hold_to(t);
            let st = self.current_state(motion);
            self.emit(t_ref_ns, st, raw, 0.0, 0.0);
            return;
        }
        let meas = self.segment_first().and_then(|first| {
            let k_ref = t_ref_ns.saturating_add(self.group_delay_ns) as f64 / self.p.dt_ns as f64;
            // the peak is searched near the prediction first (a few of its sigmas: the
            // combination costs per lag), then over the whole tracking range
            let (lo, hi) = self.track_slots_around(pred_t);
            let near = (4.0 * pred_var.sqrt() * self.p.fs).ceil().max(3.0) + 1.0;
            let c = pred_t * self.p.fs - self.corr.lag0() as f64;
            // lags every block of the segment holds (after a shift of the lag range the
            // older blocks lack the entering lags), one slot kept for the drift shift
            let (held_lo, held_hi) = self.corr.slots_held(first, n);
            let (ilo, ihi) = (lo.max(held_lo + 1), hi.min(held_hi.saturating_sub(2)));
            let (lo_n, hi_n) = if ihi >= ilo + 4 { (ilo, ihi) } else { (lo, hi) };
            let nlo = ((c - near).floor().max(lo_n as f64) as usize).min(hi_n);
            let nhi = ((c + near).ceil().max(0.0) as usize).clamp(nlo, hi_n);
            let span = Span {
                first,
                last: n - 1,
                drift: self.d.0,
                k_ref,
                lo: nlo,
                hi: nhi,
            };
            // information-weighted centre of the segment: the drift's uncertainty and
            // the offset's random walk act over the distance to it
            let (m, (sw, swk)) = self.measure_segment(&span, &Span { lo, hi, ..span }, sign)?;
            let lever = if sw > 0.0 {
                (k_ref - swk / sw) * self.p.dt_s
            } else {
                0.0
            };
            let var = m.var + self.d.1 * lever * lever + self.p.qo * self.p.qo * lever.abs();
            Some(Meas { var, ..m })
        });
        // after a hinted change: the old offset and the new segment, weighed
        let meas = match (meas, self.seg_prior) {
            (Some(m), Some(h)) => self.hinted(m, h, t),
            (m, _) => m,
        };
        // a segment measurement replaces the estimate when it is consistent with the
        // prediction and about as precise (a short segment after a re-centre, or one
        // that just grew past a gap, is not); a segment just started at a change
        // point is taken as it is (the step test vouched for it), and so is one under
        // a hint's prior (the prior keeps it honest)
        let fresh = self.fresh || self.seg_prior.is_some();
        let usable = |m: &Meas| {
            fresh
                || (m.var <= 2.0 * pred_var
                    && (m.z - pred_t).abs() <= self.p.gate * (pred_var + m.var).sqrt())
        };
        let meas = meas.filter(|m| m.score >= self.p.min_score);
        if meas.is_some_and(|m| !usable(&m)) {
            self.stats.outliers += 1;
        }
        match meas.filter(usable) {
            Some(m) if motion || t - self.info_t <= self.p.window_s => {
                self.blind_moving = 0;
                self.fresh = false;
                self.cur = Current {
                    t,
                    o: m.z,
                    var: m.var,
                };
                if motion {
                    self.info_t = t;
                    self.stats.measurements += 1;
                }
                let st = self.current_state(motion);
                self.emit(t_ref_ns, st, raw, m.score, m.ratio);
            }
            Some(m) => {
                // no motion for a while: the segment's value stands, its uncertainty grows
                let grow = self.p.q_hold * self.p.q_hold * (t - self.info_t - self.p.window_s);
                self.cur = Current {
                    t,
                    o: m.z,
                    var: m.var + grow.max(0.0),
                };
                if self.cur.var > self.p.lost_var {
                    self.lose();
                }
                let st = self.current_state(false);
                self.emit(t_ref_ns, st, raw, m.score, m.ratio);
            }
            None => {
                self.hold_to(t);
                // moving, yet no peak near the prediction for two windows: the lock is wrong
                self.blind_moving = if motion { self.blind_moving + 1 } else { 0 };
                if self.blind_moving >= 2 * self.p.acq_blocks && self.mode == Mode::Locked {
                    self.lose();
                }
                let st = self.current_state(false);
                let (sc, ra) = meas.map_or((0.0, 0.0), |m| (m.score, m.ratio));
                self.emit(t_ref_ns, st, raw, sc, ra);
            }
        }
    }

    /// Runs the next stage of the pending step test, if any.
    fn step_stage(&mut self) {
        let Some(mut job) = self.step_job.take() else {
            return;
        };
        let more = match job.stage {
            StepStage::Start => {
                job.rate = self.min_rate();
                self.step_start(&mut job)
            }
            StepStage::Total => {
                if !self.step_total(&mut job) {
                    job.stage = StepStage::Post;
                }
                true
            }
            StepStage::Post => {
                self.step_rate = Some(job.rate);
                let more = self.step_post(&mut job);
                self.step_rate = None;
                more
            }
        };
        if more {
            self.step_job = Some(job);
        }
    }

    /// Runs the pending step test to its end: before anything changes the stored
    /// blocks or the estimate it reads (a block completing, a stall, a clock jump).
    fn finish_step(&mut self) {
        while self.step_job.is_some() {
            self.step_stage();
        }
    }

    /// Two-sample test for an offset step: the segment's newest blocks (the last
    /// `short..=4·short`) against the rest of it, the most significant split winning.
    /// Consecutive hops whose split exceeds half the `step_gate_sigma` gate and agree
    /// accumulate evidence; at `step_confirm` times half the gate², a new segment
    /// starts at the split. The newest `short` blocks' measurement calibrates the
    /// scale, and every `short` hops feeds the drift fit. Post windows and drift
    /// chunks must move as the motion gate asks ([`Self::seg_moving`]): the end of
    /// a drive holds seconds of noise whose peak can look confident. The innovation
    /// record for the σ takes every chunk (it only ever widens the σ).
    ///
    /// The test runs in stages, one per pushed sample after the hop that asked for
    /// it ([`StepJob`]): this one (a change announced from outside, the newest
    /// `short` blocks), the segment's total, then one post window each; the last
    /// gives the verdict. Returns whether stages remain.
    fn step_start(&mut self, job: &mut StepJob) -> bool {
        self.suspect_var = 0.0;
        let n = self.corr.count();
        let short = self.p.short_blocks;
        let Some(first) = self.segment_first() else {
            return false;
        };
        // a change announced from outside, once a step window of data follows it
        if let Some(kc) = self.known_change {
            if self.seg_start_k >= kc {
                self.known_change = None;
            } else if self.corr.block(n - 1).last_k
                >= kc.saturating_add(short as i64 * self.p.hop_len)
            {
                self.known_change = None;
                let hint = self.hint.take();
                if let Some(c) = (first..n).find(|&i| self.corr.block(i).last_k >= kc) {
                    let t_c = self.rel_k(self.corr.block(c).first_k as f64);
                    let (o, v) = self.predict(t_c);
                    let (start_k, start_t) = (self.seg_start_k, self.seg_start_t);
                    self.change_at_block(c);
                    self.seg_prior = hint.map(|hint| HintPrior {
                        o,
                        v,
                        hint,
                        t: t_c,
                        start_k,
                        start_t,
                    });
                    return false;
                }
            }
        }
        let len_seg = n - first;
        // the lags every block of the segment holds (after a shift of the lag range the
        // older blocks lack the entering ones): the test's totals add whole blocks
        let (lo, hi) = self.track_slots_around(job.pred_t);
        let (held_lo, held_hi) = self.corr.slots_held(first, n);
        let (lo, hi) = (lo.max(held_lo), hi.min(held_hi));
        if hi < lo + 2 {
            return false;
        }
        // the newest `short` blocks, robustly
        let refs = self.motion_refs();
        let chunk = self
            .measure_span(
                &job.span(n - short, n - 1, lo, hi),
                job.sign,
                Weights::Robust,
            )
            .filter(|m| m.score >= self.p.min_score);
        let moving = chunk.is_some_and(|m| self.seg_moving(m.z, refs));
        if let Some(m) = chunk {
            let t_s = self.rel_k(0.5 * (self.seg.sums.first_k + self.seg.sums.last_k) as f64);
            let (pred_s, var_s) = self.predict(t_s);
            let nu = m.z - pred_s;
            if nu.abs() > self.p.gate * (var_s + m.var).sqrt() {
                self.stats.outliers += 1;
            }
            // disjoint windows only: independent measurements
            self.since_chunk += 1;
            if self.since_chunk >= short {
                if moving {
                    self.drift.add(t_s, m.z, m.var);
                }
                self.since_chunk = 0;
                self.add_innovation(nu, var_s + m.var);
            }
        }
        // post windows of short, 2·short, ... blocks (robust on their own) against the
        // blocks before them (with the weights of the segment's last combination):
        // pre = segment - post, both with those weights, so one pass over the segment
        let max_post = (4 * short).min(len_seg.saturating_sub(short));
        *job = StepJob {
            stage: StepStage::Total,
            first,
            n,
            lo,
            hi,
            refs,
            max_post,
            len: short,
            prev: 0,
            ..*job
        };
        if max_post < short {
            self.step_verdict(job);
            return false;
        }
        true
    }

    /// The step test's second stage: the segment's blocks with their weights, summed,
    /// at most [`segment::PREP_BLOCKS`] blocks per call (in order, so the total is the
    /// one a single pass gives). Returns whether blocks remain.
    fn step_total(&mut self, job: &mut StepJob) -> bool {
        let [total, post, _] = &mut self.glr;
        if job.total_done == 0 {
            total.clear();
            post.clear();
            total.first_k = self.corr.block(job.first).first_k;
        }
        let from = job.first + job.total_done;
        let to = (from + segment::PREP_BLOCKS).min(job.n);
        for i in from..to {
            let w = self.seg.weight(&self.corr, i);
            total.add_range(self.corr.block(i), w, job.lo, job.hi);
        }
        job.total_done = to - job.first;
        to < job.n
    }

    /// One post window of the step test against the blocks before it; the verdict
    /// after the last one. Returns whether post windows remain.
    fn step_post(&mut self, job: &mut StepJob) -> bool {
        let (n, len, lo, hi, sign) = (job.n, job.len, job.lo, job.hi, job.sign);
        let (d, vd) = self.d;
        // the blocks entering the post window, with their segment weights
        // (before the post window's own re-weighting changes them)
        for i in n - len..n - job.prev {
            let w = self.seg.weight(&self.corr, i);
            self.glr[1].add_range(self.corr.block(i), w, lo, hi);
        }
        {
            let [total, post, pre] = &mut self.glr;
            pre.diff_range(total, post, lo, hi);
            pre.first_k = total.first_k;
            pre.last_k = self.corr.block(n - len - 1).last_k;
        }
        let t_pre = self.rel_k(0.5 * (self.glr[2].first_k + self.glr[2].last_k) as f64);
        let pre = self.measure_sums(Which::Glr(2), lo, hi, sign);
        let post = self
            .measure_span(&job.span(n - len, n - 1, lo, hi), sign, Weights::Robust)
            .filter(|m| self.seg_moving(m.z, job.refs));
        let t_post = self.rel_k(0.5 * (self.seg.sums.first_k + self.seg.sums.last_k) as f64);
        if let (Some(mp), Some(mq)) = (post, pre) {
            if mp.score >= self.p.min_score && mq.score >= self.p.min_score {
                let lever = t_post - t_pre;
                let nu = mp.z - (mq.z + d * lever);
                let stat = nu * nu / (mp.var + mq.var + vd * lever * lever);
                if job.best.is_none_or(|b| stat > b.0) {
                    job.best = Some((stat, n - len, mp, nu));
                }
            }
        }
        job.prev = len;
        job.len += self.p.short_blocks;
        if job.len <= job.max_post {
            return true;
        }
        self.step_verdict(job);
        false
    }

    /// The step test's verdict from its most significant split.
    fn step_verdict(&mut self, job: &StepJob) {
        let best = job.best;
        // evidence short of a step still makes the estimate less certain: a change of
        // size nu may be under way (honest σ while the test accumulates evidence)
        if let Some((stat, _, _, nu)) = best {
            let gate2 = self.p.step_gate * self.p.step_gate;
            let p = ((stat - SUSPECT_STAT) / (gate2 - SUSPECT_STAT).max(1e-9)).clamp(0.0, 1.0);
            self.suspect_var = p * nu * nu;
        }
        match best {
            // evidence accumulates over consecutive hops whose statistic exceeds half the
            // gate and whose new offsets agree (a CUSUM): a large step is declared after
            // a hop or two, a marginal one after `step_confirm` hops
            Some((stat, c, mp, nu)) if stat > 0.5 * self.p.step_gate * self.p.step_gate => {
                let half = 0.5 * self.p.step_gate * self.p.step_gate;
                let same = self.step.count > 0
                    && self.step.sign == nu.signum()
                    && (mp.z - self.step.z).abs() <= 3.0 * (mp.var + self.step.var).sqrt();
                self.step_evidence = if same { self.step_evidence } else { 0.0 } + stat - half;
                self.step = Streak {
                    count: if same { self.step.count + 1 } else { 1 },
                    z: mp.z,
                    var: mp.var,
                    sign: nu.signum(),
                };
                if self.step_evidence >= self.p.step_confirm as f64 * half {
                    self.change_at_block(c);
                    // the block's start on the internal LiDAR clock, then with the
                    // LiDAR cadence's level added back: the LiDAR's own stamps
                    let k = self.corr.block(c).first_k;
                    let t_int = k
                        .saturating_mul(self.p.dt_ns)
                        .saturating_sub(self.group_delay_ns);
                    let level = self.cad[1].level_at(t_int).0.round();
                    self.offset_step = Some(OffsetStep {
                        t_ns: t_int.saturating_add(if level.is_finite() {
                            level as Nanos
                        } else {
                            0
                        }),
                        step_s: nu,
                    });
                }
            }
            _ => {
                self.step = Streak::default();
                self.step_evidence = 0.0;
            }
        }
    }

    /// The estimate after a hinted change, from the new segment's measurement `m` at
    /// tracker time `t` and the old segment `h`: a mixture of "no step" (the old
    /// offset, moved with the drift, fused with `m`) and "a step of about
    /// `h.v_step`" (`m`, with the old offset as a prior that wide), weighed by how
    /// likely `m`'s departure from the old offset is under each, with even prior
    /// odds; its σ covers both. A wrong hint keeps the old estimate; a real step
    /// wins as soon as the new segment shows it. Once the new segment alone is as
    /// precise as the old offset, the verdict is final: a step keeps the new
    /// segment, no step gives the old segment its history back (its start again;
    /// the drift fit keeps the extra intercept the change gave it). `None`: `m` is
    /// beyond the gate of even the step hypothesis, an outlier.
    fn hinted(&mut self, m: Meas, h: HintPrior, t: f64) -> Option<Meas> {
        let (o, v, v_step) = (h.o, h.v, h.hint.v_step);
        let alt = h.hint.alt.unwrap_or(0.0);
        let dt = t - h.t;
        let v0 = v + self.d.1 * dt * dt + self.p.qo * self.p.qo * dt.abs();
        let o_t = o + self.d.0 * dt;
        let fuse = |mu: f64, vp: f64| {
            let w = m.var / (m.var + vp);
            (m.z + w * (mu - m.z), m.var * vp / (m.var + vp))
        };
        let (z0, var0) = fuse(o_t, v0);
        let (z1, var1) = fuse(o_t + alt, v0 + v_step);
        let (nu0, nu1) = (m.z - o_t, m.z - o_t - alt);
        let (s0, s1) = (m.var + v0, m.var + v0 + v_step);
        if nu0.abs() > self.p.gate * s0.sqrt() && nu1.abs() > self.p.gate * s1.sqrt() {
            self.stats.outliers += 1;
            return None;
        }
        // log-likelihood ratio of "step" against "no step", with the prior odds
        let llr = h.hint.logit + 0.5 * ((s0 / s1).ln() + nu0 * nu0 / s0 - nu1 * nu1 / s1);
        let p1 = 1.0 / (1.0 + (-llr.clamp(-50.0, 50.0)).exp());
        // a step of one known size is told from none as soon as the data are decisive
        let decided = h.hint.alt.is_some() && !(1e-4..=1.0 - 1e-4).contains(&p1);
        if m.var <= v0 || decided {
            self.seg_prior = None;
            if p1 >= 0.5 {
                return Some(if h.hint.alt.is_some() {
                    Meas {
                        z: z1,
                        var: var1,
                        ..m
                    }
                } else {
                    m
                });
            }
            self.seg_start_k = h.start_k;
            self.seg_start_t = h.start_t;
            return Some(Meas {
                z: z0,
                var: var0,
                ..m
            });
        }
        let z = (1.0 - p1) * z0 + p1 * z1;
        let var = (1.0 - p1) * (var0 + (z0 - z).powi(2)) + p1 * (var1 + (z1 - z).powi(2));
        Some(Meas { z, var, ..m })
    }

    /// Adds a disjoint short-window innovation `nu` (variance `var`, clipped at 3σ:
    /// the short windows' errors have heavy tails) and re-estimates the squared
    /// bias of the estimate: the weighted mean of the newest [`BIAS_WINDOWS`]
    /// innovations, squared, less its own variance. An estimate that the newest data
    /// keep contradicting (a step the step test cannot confirm yet, a drift outside
    /// the prior) reports that in its σ; the estimate itself is unchanged.
    fn add_innovation(&mut self, nu: f64, var: f64) {
        if !(nu.is_finite() && var.is_finite() && var > 0.0) {
            return;
        }
        let sd = var.sqrt();
        self.innov.copy_within(0..BIAS_WINDOWS - 1, 1);
        self.innov[0] = (nu.clamp(-3.0 * sd, 3.0 * sd), var);
        self.innov_n = (self.innov_n + 1).min(BIAS_WINDOWS);
        let (mut sw, mut swn) = (0.0, 0.0);
        for &(x, v) in &self.innov[..self.innov_n] {
            sw += 1.0 / v;
            swn += x / v;
        }
        let mean = swn / sw;
        self.bias_var = (mean * mean - 1.0 / sw).max(0.0);
    }

    /// A change point at stored block `c`: the segment restarts there.
    fn change_at_block(&mut self, c: usize) {
        self.seg_prior = None;
        self.innov_n = 0;
        self.bias_var = 0.0;
        let k = self.corr.block(c).first_k;
        let t_c = self.rel_k(k as f64);
        self.drift.change_at(t_c);
        self.fresh = true;
        self.seg_start_k = k;
        self.seg_start_t = t_c;
        // the joint maximum under way measured the old segment through the change: the
        // new segment's hypotheses centre on the drift estimate
        self.joint_job = None;
        self.joint_d = None;
        self.step = Streak::default();
        self.step_evidence = 0.0;
        self.since_chunk = 0;
        self.stats.steps += 1;
    }

    /// The acquisition window's peak within the tracking range of the prediction,
    /// moved with the drift from the window's centre to tracker time `t`.
    fn raw_measurement(&mut self, sign: f64, t: f64) -> Option<f64> {
        let w = self.corr.acq();
        let t_c = self.rel_k(0.5 * (w.first_k + w.last_k) as f64);
        let (pred, _) = self.predict(t_c);
        let (lo, hi) = self.acq_slots(self.track_slots_around(pred));
        let m = self
            .measure_sums(Which::Acq, lo, hi, sign)
            .filter(|m| m.score >= self.p.min_score)?;
        self.raw_trend.push(t_c, m.z, m.var);
        Some(m.z + self.d.0 * (t - t_c))
    }

    fn emit(
        &mut self,
        t_ref_ns: Nanos,
        state: EstimatorState,
        z: Option<f64>,
        score: f64,
        ratio: f64,
    ) {
        // a change the step test sees but has not confirmed, and a bias the newest
        // data show, widen what is reported, not the state the next hops predict from
        let (offset, std) = if self.ever_locked {
            (
                self.cur.o,
                (self.cur.var + self.suspect_var + self.bias_var)
                    .max(0.0)
                    .sqrt(),
            )
        } else {
            (
                z.unwrap_or(self.corr.lag0() as f64 * self.p.dt_s + self.p.max_lag_s),
                self.p.max_lag_s,
            )
        };
        // back from the internal stamps to the stamps as published: the LiDAR's
        // latency level at the reference time, the camera's at the same event
        let (lev_l, var_l) = self.cad[1].level_at(t_ref_ns);
        let t_cam = t_ref_ns.saturating_sub((offset * 1e9) as Nanos);
        let (lev_c, var_c) = self.cad[0].level_at(t_cam);
        let shift = (lev_l - lev_c) * 1e-9;
        let e = Estimate {
            seq: self.seq,
            t_ref_ns: t_ref_ns.saturating_add(lev_l.round() as Nanos),
            offset_s: offset + shift,
            drift: if self.ever_locked { self.d.0 } else { 0.0 },
            offset_std_s: (std * std + (var_l + var_c) * 1e-18).sqrt(),
            drift_std: if self.ever_locked {
                self.d.1.max(0.0).sqrt()
            } else {
                self.p.drift0
            },
            state,
            polarity: self.polarity,
            peak_score: score,
            peak_ratio: ratio,
            measured_offset_s: z.map_or(f64::NAN, |z| z + shift),
        };
        self.seq += 1;
        self.stats.estimates += 1;
        if self.queue.push(e) {
            self.stats.dropped_estimates += 1;
        }
    }
}

/// How [`Estimator::measure_span`] weights the blocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Weights {
    /// All 1.
    Uniform,
    /// Re-weighted from the residuals, starting from 1 ([`IRLS_PASSES`] passes).
    Robust,
    /// Re-weighted once from the residuals against the last segment measurement,
    /// starting from the current weights (the segment: its weights and fit carry over
    /// from hop to hop).
    Warm,
}

#[derive(Debug, Clone, Copy)]
enum Which {
    Acq,
    Seg,
    Glr(usize),
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlsync_sim::families::{generate, Family};

    /// The configuration validates against the hop and acquisition window the
    /// estimator runs (`EstimatorConfig::effective_hop_s`, `effective_window_s`):
    /// both round the same way as [`Params::new`] for every valid configuration.
    #[test]
    fn the_configs_effective_hop_and_window_are_the_estimators() {
        for grid_hz in [10.0, 30.0, 100.0, 333.0, 1000.0, 2000.0] {
            for hop_s in [0.1, 0.25, 0.5, 0.77, 1.3] {
                for window_s in [2.0, 2.75, 6.0, 7.4, 30.0] {
                    let c = EstimatorConfig {
                        grid_hz,
                        hop_s,
                        window_s,
                        ..EstimatorConfig::default()
                    };
                    if hop_s > window_s || hop_s * grid_hz < 1.0 {
                        continue;
                    }
                    let p = Params::new(&c);
                    assert!(
                        (p.hop_s - c.effective_hop_s()).abs() < 1e-12,
                        "{grid_hz} {hop_s}: {} against {}",
                        p.hop_s,
                        c.effective_hop_s()
                    );
                    let w = p.acq_blocks as f64 * p.hop_s;
                    assert!(
                        (w - c.effective_window_s()).abs() < 1e-9,
                        "{grid_hz} {hop_s} {window_s}: {w} against {}",
                        c.effective_window_s()
                    );
                }
            }
        }
    }

    /// Once locked, only the lags tracking reads (and a few to spare) are updated,
    /// fewer in degraded mode; acquisition updates them all. Degraded mode, with no
    /// lag to spare, tracks within 5 ms of the normal lock. (That the normal lock
    /// gives the estimates of one updating every lag is measured by `vlsyncd bench`,
    /// docs/performance.md: no configuration here updates them all once locked.)
    #[test]
    fn a_lock_updates_only_the_lags_tracking_reads() {
        let cfg = EstimatorConfig::default();
        let (mut narrow, mut degraded) = (Estimator::new(&cfg), Estimator::new(&cfg));
        degraded.set_degraded(true);
        let n = narrow.corr.n_lags();
        // (acquiring, locked) widths seen after each push
        let mut seen = [Vec::new(), Vec::new()];
        let (a, b) = replay_both(Family::Robot, 1000, &mut narrow, &mut degraded, |e| {
            let (lo, hi) = e.corr.active();
            seen[usize::from(e.mode == Mode::Locked)].push(hi - lo + 1);
        });
        assert!(
            seen[0].iter().all(|&w| w == n),
            "acquisition: {:?}",
            seen[0]
        );
        let locked = &seen[1];
        assert!(locked.len() > 1000);
        // the hop that locks updates the whole range until it narrows
        assert!(
            locked.iter().skip(100).all(|&w| w == 45),
            "{:?}",
            &locked[..110]
        );
        let (lo, hi) = degraded.corr.active();
        assert_eq!(hi - lo + 1, 29);
        // each tracked within a few ms of the other
        let track = |e: &[Estimate]| -> Vec<(i64, f64)> {
            e.iter()
                .filter(|e| e.state == EstimatorState::Tracking)
                .map(|e| (e.t_ref_ns, e.offset_s))
                .collect()
        };
        let (ta, tb) = (track(&a), track(&b));
        assert!(
            ta.len() > 150 && tb.len() > 150,
            "{} {}",
            ta.len(),
            tb.len()
        );
        let matched = ta
            .iter()
            .filter_map(|&(t, o)| tb.iter().find(|x| x.0 == t).map(|x| (o - x.1).abs()))
            .collect::<Vec<_>>();
        assert!(matched.len() > 150);
        assert!(matched.iter().all(|&d| d < 0.005), "{matched:?}");
    }

    /// Replays a run of `family` (seed `seed`) into `a` and `b` alike, calling
    /// `after_push` with `a` after each push; returns both estimate sequences.
    fn replay_both(
        family: Family,
        seed: u64,
        a: &mut Estimator,
        b: &mut Estimator,
        mut after_push: impl FnMut(&Estimator),
    ) -> (Vec<Estimate>, Vec<Estimate>) {
        let (mut ea, mut eb) = (Vec::new(), Vec::new());
        for (stream, s) in generate(family, seed, None).pushes() {
            let _ = a.push(stream, s);
            let _ = b.push(stream, s);
            after_push(a);
            ea.extend(std::iter::from_fn(|| a.poll()));
            eb.extend(std::iter::from_fn(|| b.poll()));
        }
        (ea, eb)
    }

    /// Replays a run into two estimators that combine directly (a prepared
    /// combination sums in another order, and when it is ready differs between the
    /// two: its own tests compare it): `split` as built, `whole` set up by
    /// `make_whole`. Returns both estimate sequences, the split one's step count,
    /// and how many pushes left `split` with `part_done` true after their own stage.
    fn replay_pair(
        family: Family,
        seed: u64,
        cfg: &EstimatorConfig,
        make_whole: impl Fn(&mut Estimator),
        part_done: impl Fn(&Estimator) -> bool,
    ) -> (Vec<Estimate>, Vec<Estimate>, u64, usize) {
        let (mut split, mut whole) = (Estimator::new(cfg), Estimator::new(cfg));
        make_whole(&mut whole);
        split.prepare = false;
        whole.prepare = false;
        let mut pending = 0;
        let (a, b) = replay_both(family, seed, &mut split, &mut whole, |e| {
            pending += usize::from(part_done(e))
        });
        (a, b, split.stats().steps, pending)
    }

    /// Replays `run`, one estimator splitting its step tests over the pushes and one
    /// running each whole at the first push after its hop. Returns both estimate
    /// sequences, the split one's step count, and how many pushes found a step test
    /// still unfinished after their own stage.
    fn split_and_whole(
        family: Family,
        seed: u64,
        cfg: &EstimatorConfig,
    ) -> (Vec<Estimate>, Vec<Estimate>, u64, usize) {
        replay_pair(
            family,
            seed,
            cfg,
            |w| w.split_step = false,
            |e| e.step_job.is_some_and(|j| j.stage != StepStage::Start),
        )
    }

    /// Estimates with the joint maximum's re-centred rounds staged over the pushes
    /// after its hop and with them run whole at the end of its hop (the whole one
    /// leaves no pushes for the preparation, so both combine directly); the pushes
    /// during which a staged round stood part-done.
    fn joint_staged_and_whole(
        family: Family,
        seed: u64,
        cfg: &EstimatorConfig,
    ) -> (Vec<Estimate>, Vec<Estimate>, usize) {
        let (a, b, _, part_done) = replay_pair(
            family,
            seed,
            cfg,
            |w| w.split_joint = false,
            |e| e.joint_job.is_some_and(|j| j.j > 0),
        );
        (a, b, part_done)
    }

    /// The joint maximum's re-centred rounds run one combination per push after its
    /// hop, once the step test is done, give the estimates of the rounds run whole
    /// at the end of its hop (the weights they combine with are kept at its start:
    /// the hop's and the step test's re-weighting in between do not reach them),
    /// with steps that drop them and 0.1 s hops that finish them on the sample
    /// completing the next block.
    #[test]
    fn the_joint_maximum_in_stages_gives_the_estimates_of_the_whole_one() {
        let short_hops = EstimatorConfig {
            hop_s: 0.1,
            ..EstimatorConfig::default()
        };
        let no_cadence = EstimatorConfig {
            cadence: vlsync_config::CadenceStreams::Off,
            ..EstimatorConfig::default()
        };
        for (family, seed, cfg) in [
            (Family::Seed, 1000, EstimatorConfig::default()),
            (Family::Seed, 1003, short_hops),
            (Family::LoadSteps, 3, no_cadence),
            (Family::Clocks, 1000, EstimatorConfig::default()),
        ] {
            let (split, whole, part_done) = joint_staged_and_whole(family, seed, &cfg);
            assert!(
                split.len() > 15,
                "{family:?} {seed}: {} estimates",
                split.len()
            );
            // the re-centred rounds are staged (the first is combined at the hop):
            // load-steps' steps leave the hypotheses far from the new segment's slope
            if family == Family::LoadSteps {
                assert!(part_done > 5, "{family:?}: {part_done} pushes part-done");
            }
            assert_eq!(split.len(), whole.len());
            for (x, y) in split.iter().zip(&whole) {
                assert_eq!(format!("{x:?}"), format!("{y:?}"), "{family:?} {seed}");
            }
            if family == Family::Seed {
                // the joint slope decided: the seed's 12 ms/s drift is learnt
                let d = split.last().unwrap().drift;
                assert!((d - 0.012).abs() < 0.002, "{family:?} {seed}: drift {d}");
            }
        }
    }

    /// The joint maximum's first round prepared on the samples before its hop gives
    /// the estimates of the one combined at the hop, bit for bit (the hop adds its
    /// new block to sums of the same blocks in the same order), and the hops used
    /// what was prepared.
    #[test]
    fn a_prepared_joint_maximum_gives_the_estimates_of_the_direct_one() {
        let no_cadence = EstimatorConfig {
            cadence: vlsync_config::CadenceStreams::Off,
            ..EstimatorConfig::default()
        };
        // (family, seed, configuration, degraded mode, share of joint maxima prepared
        // at least). The seed's runs drift by 1.2 %: the lags updated move every other
        // hop, and a hop whose new block holds other slots than its preparation
        // assumed combines its first round directly
        for (family, seed, cfg, degraded, share) in [
            (Family::Seed, 1000, EstimatorConfig::default(), false, 0.8),
            (Family::Seed, 4001, EstimatorConfig::default(), false, 0.8),
            (Family::Robot, 1000, EstimatorConfig::default(), false, 0.9),
            (Family::LoadSteps, 3, no_cadence, false, 0.9),
            (Family::Clocks, 1000, EstimatorConfig::default(), false, 0.9),
            // the tracking range narrowed around each hop's prediction
            (Family::Robot, 1001, EstimatorConfig::default(), true, 0.9),
        ] {
            let (mut prep, mut direct) = (Estimator::new(&cfg), Estimator::new(&cfg));
            prep.set_degraded(degraded);
            direct.set_degraded(degraded);
            direct.prepare_joint = false;
            let (a, b) = replay_both(family, seed, &mut prep, &mut direct, |_| {});
            let (started, prepared) = prep.joint_hops;
            assert_eq!(direct.joint_hops.1, 0);
            assert!(
                started >= 10 && prepared as f64 >= share * started as f64,
                "{family:?} {seed}: {prepared} of {started} joint maxima prepared"
            );
            assert_eq!(a.len(), b.len(), "{family:?} {seed}");
            for (x, y) in a.iter().zip(&b) {
                assert_eq!(format!("{x:?}"), format!("{y:?}"), "{family:?} {seed}");
            }
        }
    }

    #[test]
    fn a_prepared_segment_combination_gives_the_estimates_of_the_direct_one() {
        let short_hops = EstimatorConfig {
            hop_s: 0.1,
            ..EstimatorConfig::default()
        };
        let degraded = |e: &mut Estimator| e.set_degraded(true);
        let none = |_: &mut Estimator| {};
        // (family, seed, configuration, setup, share of tracking hops prepared at least)
        type Case<'a> = (
            Family,
            u64,
            EstimatorConfig,
            &'a dyn Fn(&mut Estimator),
            f64,
        );
        let cases: [Case; 6] = [
            (Family::Robot, 1000, EstimatorConfig::default(), &none, 0.97),
            // drift over hours moves the lag range (a shift makes the prepared stale)
            (Family::Clocks, 1, EstimatorConfig::default(), &none, 0.97),
            (
                Family::LoadSteps,
                3,
                EstimatorConfig::default(),
                &none,
                0.97,
            ),
            (
                Family::HeavyNoise,
                1,
                EstimatorConfig::default(),
                &none,
                0.8,
            ),
            // 4 pushes between hops: the step test's stages leave little room
            (Family::LoadSteps, 3, short_hops, &none, 0.0),
            (
                Family::Robot,
                1001,
                EstimatorConfig::default(),
                &degraded,
                0.5,
            ),
        ];
        for (family, seed, cfg, setup, share) in cases {
            let (mut prep, mut direct) = (Estimator::new(&cfg), Estimator::new(&cfg));
            direct.prepare = false;
            setup(&mut prep);
            setup(&mut direct);
            let (a, b) = replay_both(family, seed, &mut prep, &mut direct, |_| {});
            let (measured, prepared) = prep.prepared_hops;
            assert_eq!(direct.prepared_hops.1, 0);
            // the hops used what the samples before them prepared
            assert!(
                prepared as f64 >= share * measured as f64 && measured > 150,
                "{family:?}: {prepared} of {measured} segment measurements prepared"
            );
            assert_eq!(a.len(), b.len(), "{family:?}");
            assert_eq!(prep.stats(), direct.stats(), "{family:?}");
            // the same weights, summed in another order: equal to rounding
            for (x, y) in a.iter().zip(&b) {
                assert_eq!((x.state, x.seq, x.t_ref_ns), (y.state, y.seq, y.t_ref_ns));
                for (p, q) in [
                    (x.offset_s, y.offset_s),
                    (x.offset_std_s, y.offset_std_s),
                    (x.drift, y.drift),
                    (x.peak_score, y.peak_score),
                ] {
                    let close = p == q || (p - q).abs() <= 1e-10;
                    assert!(close, "{family:?} #{}: {p} vs {q}", x.seq);
                }
            }
        }
    }

    #[test]
    fn the_step_test_in_stages_gives_the_verdicts_of_the_whole_test() {
        // the correlation's step test (the load steps' stamps are not followed by
        // their cadence here, so the test has steps to find)
        let no_cadence = EstimatorConfig {
            cadence: vlsync_config::CadenceStreams::Off,
            ..EstimatorConfig::default()
        };
        // hops of 0.1 s leave 4 pushes between hops: the test is finished before the
        // next block completes, not only by the pushes between
        let short_hops = EstimatorConfig {
            hop_s: 0.1,
            ..no_cadence.clone()
        };
        for (family, seed, cfg) in [
            (Family::LoadSteps, 3, no_cadence),
            (Family::Clocks, 1000, EstimatorConfig::default()),
            (Family::LoadSteps, 3, short_hops),
            // a 5.5 Hz LiDAR below twice the low-pass: the slower stream's rate, which
            // every push moves, bounds the measurements' band
            (
                Family::Rates60x5,
                1000,
                EstimatorConfig {
                    lowpass_hz: 3.0,
                    ..EstimatorConfig::default()
                },
            ),
        ] {
            let (split, whole, steps, pending) = split_and_whole(family, seed, &cfg);
            assert!(split.len() > 150, "{family:?}: {} estimates", split.len());
            // the comparison means something: the test ran in stages and found steps
            assert!(
                pending > 500,
                "{family:?}: {pending} pushes with a test under way"
            );
            if family == Family::LoadSteps {
                assert!(steps >= 2, "{steps} steps");
            }
            assert_eq!(split.len(), whole.len());
            // exact (Debug prints every f64 round-trip; NaN equals NaN there)
            for (x, y) in split.iter().zip(&whole) {
                assert_eq!(format!("{x:?}"), format!("{y:?}"), "{family:?}");
            }
        }
    }

    /// How long after a load step the restore case interrupts its step test: 6 s into
    /// load-steps seed 3's first step the test's verdict widens the σ, and a restore
    /// that dropped the test half-done (instead of finishing it) changes the
    /// estimates (checked: 3-5 s would not show it).
    const RESTORE_AFTER_STEP_NS: Nanos = 6_000_000_000;

    /// What interrupts a step test under way in [`interrupted_tests_finish_first`].
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Interrupt {
        /// Both streams silent for 3 s, then the camera first: a stall.
        Silence,
        /// The LiDAR's clock steps 8 s forward: a reset and a clock jump.
        ClockJump,
        /// The caller restores a saved estimate.
        Restore,
    }

    /// Replays `all` into `a` and `b` alike and interrupts both with `what` at the
    /// first push after which `due(a, a's estimates so far, sample time)` holds; a
    /// restore gives back `a`'s last estimate moved by `restore_shift_s`. Returns
    /// both estimate sequences and when the interruption came.
    fn replay_interrupted(
        all: &[(Stream, Sample)],
        what: Interrupt,
        restore_shift_s: f64,
        (a, b): (&mut Estimator, &mut Estimator),
        mut due: impl FnMut(&Estimator, &[Estimate], Nanos) -> bool,
    ) -> (Vec<Estimate>, Vec<Estimate>, Option<Nanos>) {
        let (mut ea, mut eb) = (Vec::<Estimate>::new(), Vec::<Estimate>::new());
        let mut injected: Option<Nanos> = None;
        let mut lidar_shift = 0;
        for &(stream, s) in all {
            if let Some(t0) = injected {
                if what == Interrupt::Silence && s.t_ns < t0 + 3_000_000_000 {
                    continue;
                }
            }
            let s = match stream {
                Stream::Lidar => Sample {
                    t_ns: s.t_ns + lidar_shift,
                    ..s
                },
                Stream::Cam => s,
            };
            let _ = a.push(stream, s);
            let _ = b.push(stream, s);
            ea.extend(std::iter::from_fn(|| a.poll()));
            eb.extend(std::iter::from_fn(|| b.poll()));
            if injected.is_none() && due(a, &ea, s.t_ns) {
                injected = Some(s.t_ns);
                match what {
                    Interrupt::Silence => {}
                    Interrupt::ClockJump => lidar_shift = 8_000_000_000,
                    Interrupt::Restore => {
                        let mut last = ea[ea.len() - 1];
                        last.offset_s += restore_shift_s;
                        a.restore(&last, 1.0);
                        b.restore(&last, 1.0);
                    }
                }
            }
        }
        (ea, eb, injected)
    }

    /// Each way a step test can be interrupted before its stages are done: injected
    /// right after a tracking hop (its test pending), into an estimator splitting the
    /// test and one running it whole; the estimates must stay identical.
    #[test]
    fn urgent_pushes_with_idle_give_the_estimates_of_pushes() {
        // the daemon's order: the sample, its estimates, then the background stage
        for (family, seed) in [
            (Family::LoadSteps, 3),
            (Family::Clocks, 1000),
            (Family::Rates60x5, 1000),
        ] {
            let all = generate(family, seed, None).pushes();
            let cfg = EstimatorConfig::default();
            let (mut one, mut two) = (Estimator::new(&cfg), Estimator::new(&cfg));
            let (mut a, mut b) = (Vec::new(), Vec::new());
            let (mut bad, mut last) = (0, [None; 2]);
            for (i, &(stream, s)) in all.iter().enumerate() {
                // now and then a rejected sample first (this stream's last, repeated)
                let again = last[idx(stream)].filter(|_| i % 97 == 0);
                last[idx(stream)] = Some(s);
                for s in again.into_iter().chain([s]) {
                    let r1 = one.push(stream, s);
                    a.extend(std::iter::from_fn(|| one.poll()));
                    let r2 = two.push_urgent(stream, s);
                    b.extend(std::iter::from_fn(|| two.poll()));
                    two.idle();
                    assert!(two.poll().is_none(), "idle produced an estimate");
                    assert_eq!(r1, r2);
                    bad += usize::from(r1.is_err());
                }
            }
            assert!(bad > 10, "{family:?}: {bad} rejected");
            assert!(
                a.len() > 150 && one.prepared_hops.1 > 100,
                "{family:?}: {} {:?}",
                a.len(),
                one.prepared_hops
            );
            assert_eq!(a.len(), b.len(), "{family:?}");
            for (x, y) in a.iter().zip(&b) {
                assert_eq!(format!("{x:?}"), format!("{y:?}"), "{family:?}");
            }
            assert_eq!(one.stats(), two.stats());
            assert_eq!(one.prepared_hops, two.prepared_hops);
        }
    }

    #[test]
    fn a_prepared_combination_is_not_used_after_an_interruption() {
        // each interruption comes when a combination is prepared for the next hop:
        // that hop must see that its inputs changed and combine directly
        for what in [Interrupt::Silence, Interrupt::ClockJump, Interrupt::Restore] {
            let all = generate(Family::Robot, 11, Some(90.0)).pushes();
            let cfg = EstimatorConfig::default();
            let (mut prep, mut direct) = (Estimator::new(&cfg), Estimator::new(&cfg));
            direct.prepare = false;
            let (a, b, injected) =
                replay_interrupted(&all, what, 0.004, (&mut prep, &mut direct), |e, _, t| {
                    t > 40_000_000_000 && e.seg.prepared_ready()
                });
            assert!(injected.is_some(), "{what:?} never injected");
            assert!(
                prep.prepared_hops.1 > 100,
                "{what:?}: {:?}",
                prep.prepared_hops
            );
            assert_eq!(a.len(), b.len(), "{what:?}");
            assert!(a.len() > 150, "{what:?}: {} estimates", a.len());
            // equal to rounding (an infinite σ, once lost, equals itself)
            let close = |p: f64, q: f64| p == q || (p - q).abs() <= 1e-10;
            for (x, y) in a.iter().zip(&b) {
                assert_eq!((x.state, x.t_ref_ns), (y.state, y.t_ref_ns), "{what:?}");
                assert!(
                    close(x.offset_s, y.offset_s) && close(x.offset_std_s, y.offset_std_s),
                    "{what:?}: {x:?} vs {y:?}"
                );
            }
        }
    }

    #[test]
    fn interrupted_tests_finish_first() {
        for what in [Interrupt::Silence, Interrupt::ClockJump, Interrupt::Restore] {
            // a restore where the step test may be about to widen the σ or declare a
            // step (seconds after a load step), so that dropping it half-done would show
            let (run, from_ns) = if what == Interrupt::Restore {
                let run = generate(Family::LoadSteps, 3, None);
                let t = RESTORE_AFTER_STEP_NS + run.step_times_ns[0];
                (run, t)
            } else {
                (generate(Family::Robot, 11, Some(90.0)), 40_000_000_000)
            };
            let all = run.pushes();
            let cfg = EstimatorConfig::default();
            let (mut split, mut whole) = (Estimator::new(&cfg), Estimator::new(&cfg));
            whole.split_step = false;
            split.prepare = false;
            whole.prepare = false;
            // pushes since the tracking hop chosen for the interruption: a restore two
            // pushes after the hop, when the split test has run its first stages and
            // the whole one is done; the others right after it
            let mut after_hop: Option<usize> = None;
            let mut seen = 0;
            let due = if what == Interrupt::Restore { 2 } else { 0 };
            let (a, b, injected) =
                replay_interrupted(&all, what, 0.0, (&mut split, &mut whole), |e, est, t| {
                    let tracking =
                        est.len() > seen && est[est.len() - 1].state == EstimatorState::Tracking;
                    seen = est.len();
                    if t > from_ns {
                        after_hop = match after_hop {
                            None if tracking => Some(0),
                            Some(k) => Some(k + 1),
                            None => None,
                        };
                    }
                    let now = after_hop == Some(due);
                    if now {
                        assert!(e.step_job.is_some(), "{what:?}: no test under way");
                    }
                    now
                });
            assert!(injected.is_some(), "{what:?} never injected");
            match what {
                Interrupt::Silence => assert!(split.stats().gaps[0] > 0),
                Interrupt::ClockJump => assert!(split.stats().resets[1] > 0),
                Interrupt::Restore => {}
            }
            assert!(a.len() > 150, "{what:?}: {} estimates", a.len());
            assert_eq!(a.len(), b.len(), "{what:?}");
            for (x, y) in a.iter().zip(&b) {
                assert_eq!(format!("{x:?}"), format!("{y:?}"), "{what:?}");
            }
        }
    }
}
