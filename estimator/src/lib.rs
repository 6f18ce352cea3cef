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
//! The [`Estimator`]'s hop is split by stage into private modules on the same
//! state: `acquire` (search and lock), `track` (a locked hop's segment
//! measurement), `step` (the step test), `joint` (the joint offset-drift maximum),
//! `motion` (the motion gate) and `change` (changes announced from outside).
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

mod acquire;
mod change;
mod joint;
mod motion;
mod step;
mod track;

use cadence::{Cadence, CadenceParams};
use correlator::{Correlator, Step, Sums};
use drift::DriftFit;
use filter::BandPass;
use resample::{Discontinuity, Resampler};
use segment::{PrepKey, Segment, Span};
use vlsync_common::{
    Estimate, EstimatorState, Nanos, Polarity, RejectReason, Sample, Stream, MAX_ABS_OFFSET_S,
};
use vlsync_config::EstimatorConfig;

pub use change::HINT_STEP_STD_S;
use change::{Hint, HintPrior};
use joint::{JointJob, JointKey, RawTrend};
use motion::History;
use step::{StepJob, BIAS_WINDOWS};
use track::Weights;

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
    /// Times an acquisition moved its lag range: having found nothing, to the other
    /// candidate centre (the start's, or the one it left) or to a lost lock's offset
    /// as its drift predicts it; or away from a range it could not be served in.
    pub recentres: u64,
    /// Stamping-latency steps each stream's cadence found (index: 0 cam, 1 lidar):
    /// followed from the stamps, not the correlation ([`cadence`]).
    pub cadence_steps: [u64; 2],
    /// Times each stream's cadence was learnt again (not regular enough, a clock jump,
    /// a new phase of its frames after a silence).
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
/// Tracking hops between two refreshes of [`Estimator::lock_motion`].
const LOCK_MOTION_HOPS: usize = 20;
/// Floor of the measurement standard deviation (stamp jitter, interpolation), seconds.
const MIN_MEAS_STD_S: f64 = 2e-4;
/// Window length at which the peak-sharpness variance formula matches the observed scatter, s.
const CAL_WINDOW_S: f64 = 4.0;
/// Re-weighting passes of a fresh robust combination (the segment's weights carry
/// over from hop to hop, so it needs one pass per hop).
const IRLS_PASSES: usize = 1;

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
    acq_min_score: f64,
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
        // each value clamped to its validated range, so an unvalidated config cannot
        // panic; its memory is bounded below (the segment), not to `validate`'s bound
        let cl = |v: f64, lo: f64, hi: f64| if v.is_finite() { v.clamp(lo, hi) } else { lo };
        let fs = cl(c.grid_hz, 10.0, 2000.0);
        let dt_ns = ((1e9 / fs).round() as Nanos).max(1);
        let fs = 1e9 / dt_ns as f64;
        let dt_s = 1.0 / fs;
        let window_s = cl(c.window_s, 1.0, 120.0);
        let hop_s = cl(c.hop_s, 0.05, window_s);
        let hop_len = ((hop_s * fs).round() as i64).max(1);
        let hop_s = hop_len as f64 * dt_s;
        let segment_s = cl(c.segment_s, window_s, 600.0);
        let max_lag_s = cl(c.max_lag_s, 0.01, 2.0);
        let lowpass_hz = cl(c.lowpass_hz, 0.05, 0.45 * fs);
        let blocks = |s: f64| ((s / hop_s).round() as usize).max(1);
        let acq_blocks = blocks(window_s);
        let half_lags = ((max_lag_s * fs).round() as i64).max(2);
        // the segment's lag sums within `validate`'s bound (a segment of 600 s in hops
        // of 0.5 ms at ±2 s would be 230 GB), never shorter than the acquisition window
        let lags = (2 * half_lags + 1) as f64;
        let seg_cap = ((vlsync_config::MAX_LAG_SUMS / lags) as usize).saturating_sub(1);
        let seg_blocks = blocks(segment_s).min(seg_cap).max(acq_blocks);
        let highpass_hz = cl(c.highpass_hz, 0.0, 0.9 * lowpass_hz);
        Self {
            dt_ns,
            dt_s,
            fs,
            hop_len,
            half_lags,
            center_lag: (cl(c.lag_center_s, -1e6, 1e6) * fs).round() as i64,
            track_slots: (cl(c.track_range_s, 0.005, max_lag_s) * fs).max(2.0),
            short_blocks: blocks(cl(c.step_window_s, 0.5, window_s)).min(acq_blocks),
            acq_blocks,
            seg_blocks,
            ref_lag_ns: (cl(c.reference_lag_s, 0.0, segment_s) * 1e9) as Nanos,
            window_s,
            hop_s,
            lowpass_hz,
            // 0 (off) or at least the validated floor: a tiny cut-off's filter has a
            // DC gain of 0/0, and every filtered value would be NaN
            highpass_hz: if highpass_hz < vlsync_config::MIN_HIGHPASS_HZ {
                0.0
            } else {
                highpass_hz
            },
            min_score: cl(c.min_peak_score, 0.0, 1.0),
            // never below the measurements' own gate (a configuration that raised
            // min_peak_score from before this key raised the acquisition's with it)
            acq_min_score: cl(c.min_acquire_score.max(c.min_peak_score), 0.0, 1.0),
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

/// One correlation measurement.
#[derive(Debug, Clone, Copy)]
struct Meas {
    z: f64,
    var: f64,
    score: f64,
    ratio: f64,
    sign: f64,
}

/// The current offset estimate: offset `o` at tracker time `t`, its variance.
#[derive(Debug, Clone, Copy)]
struct Current {
    t: f64,
    o: f64,
    var: f64,
    /// Tracker time of the measurement `o` was last taken from: the drift's error
    /// moves the offset by `drift error × time since then`, so its share of `var`
    /// grows with the square of the whole time blind ([`Estimator::drift_growth`]),
    /// not hop by hop.
    measured: f64,
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
    /// A lock lost long ago (a long park) and clocks that drift apart: the drift the
    /// lock had measured carried the offset's prediction out of the middle of the
    /// range searched, so the search follows it.
    Drift,
}

/// Where a lost lock was ([`Estimator::lost_from`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct LostFrom {
    /// Tracker time of the loss, s.
    t: f64,
    /// The offset then (internal stamps), s.
    o: f64,
    /// The drift the lock had measured, and its variance.
    drift: f64,
    drift_var: f64,
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
    /// How long it waited before moving (hops with motion for
    /// [`SearchMoveReason::NothingFound`] and [`SearchMoveReason::Drift`], LiDAR time
    /// for [`SearchMoveReason::Unserved`]), s.
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
    /// The last lock that held `RECENTRE_HOPS` hops and was lost: its offset, when,
    /// and the drift it had measured, for the search to follow
    /// ([`SearchMoveReason::Drift`]). `None` before such a lock, and once a clock
    /// jump, a restore or an unserved range put the offset elsewhere.
    lost_from: Option<LostFrom>,
    /// Acquisition hops with motion since the range last moved (a lock
    /// lost within `RECENTRE_HOPS` hops does not reset them: at a wrong centre the
    /// signatures' own structure can lock for a few seconds).
    acq_tries: usize,
    /// Of those, the hops whose motion was not as the last lock's
    /// ([`Estimator::moving_as_locked`]): a park's noise.
    acq_quiet: usize,
    /// The motion references while the last lock tracked with motion (refreshed every
    /// [`LOCK_MOTION_HOPS`] tracking hops): what motion looks like on this robot.
    lock_motion: Option<[f64; 2]>,
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
    /// out-of-range values are clamped to the validated ranges, and a segment whose
    /// lag sums `validate` would refuse is shortened to fit (never below the
    /// acquisition window, whose sums an unvalidated extreme can still make large).
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
        // as validated (an unvalidated NaN would be 0 ns: every sample a clock jump),
        // and beyond the longest gap, as the configuration's rule asks
        let defaults = EstimatorConfig::default();
        let reset_s = if cfg.reset_jump_s.is_finite() {
            cfg.reset_jump_s.clamp(0.1, 1e6)
        } else {
            defaults.reset_jump_s
        };
        let reset_ns = ((reset_s * 1e9) as Nanos).max(max_gap_ns.saturating_add(1));
        let max_abs = if cfg.max_abs_value.is_finite() && cfg.max_abs_value > 0.0 {
            cfg.max_abs_value.min(vlsync_config::MAX_ABS_VALUE)
        } else {
            defaults.max_abs_value
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
                measured: 0.0,
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
            lost_from: None,
            acq_tries: 0,
            acq_quiet: 0,
            lock_motion: None,
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
                // The time the step really spanned: one sample interval of this
                // stream, unless the other stream moved clearly further (both fell
                // silent, e.g. drivers paused). The other stream's progress measures
                // that time only to within its own interval (no sample of the faster
                // stream between two of the slower; three of the faster between two
                // of the slower give its whole interval), so it is taken only beyond
                // this stream's interval and two of the other's; subtracting it and the
                // interval both misjudged a step of the slower stream's clock by one
                // of its intervals (100 ms for a 10 Hz LiDAR).
                let interval = (self.rs[si].mean_interval_s() * 1e9) as Nanos;
                let other_interval = (self.rs[1 - si].mean_interval_s() * 1e9) as Nanos;
                let spanned = if elapsed > interval.saturating_add(other_interval.saturating_mul(2))
                {
                    elapsed
                } else {
                    interval
                };
                let jump = step.saturating_sub(spanned);
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

    /// The state an estimate without a new measurement would have now: `holding`
    /// once locked (never `tracking`, which only a measurement gives), else
    /// `acquiring` or `lost`. The last estimate's own state is in that estimate.
    pub fn state(&self) -> EstimatorState {
        self.current_state(false)
    }

    /// Degraded mode, for a caller over its latency budget: once locked, no lags
    /// are updated beyond those tracking reads (8 fewer each side). Nothing stored is forgotten.
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
    ///
    /// An estimate with a NaN or infinite value, or an offset beyond
    /// ±[`MAX_ABS_OFFSET_S`], is ignored (the estimator goes on as it was); the drift,
    /// its standard deviation and the age are clamped to their ranges.
    pub fn restore(&mut self, est: &Estimate, age_s: f64) {
        // NaN fails the comparison too
        if !(est.offset_s.abs() <= MAX_ABS_OFFSET_S
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
            // the saved estimate was measured `age` ago: its drift share goes on
            // growing from there
            measured: -age,
        };
        self.d = (drift, drift_std * drift_std);
        // the drift fit keeps the saved slope too: the first tracking hop takes its
        // estimate from the fit, which otherwise knew only the prior (0 ± 50 ppm)
        self.drift.restore(drift, drift_std * drift_std);
        self.epoch_ns = None;
        self.ever_locked = true;
        self.polarity = est.polarity;
        // tracking around the restored value (state `holding` until a measurement);
        // without a peak near it while moving, the estimator turns `lost` and re-acquires
        self.mode = Mode::Locked;
        self.locked_hops = 0;
        // a lost restored lock searches the start's range next (see `lose`)
        self.acq_tries = 0;
        self.acq_quiet = 0;
        self.alt_lag0 = None;
        self.lost_from = None;
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
        self.acq_quiet = 0;
        self.alt_lag0 = self.home_alt();
        self.lost_from = None;
        // the watch's times are on the clock before the step
        self.unserved_since = None;
        self.new_segment(i64::MIN, f64::NEG_INFINITY);
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
    ///
    /// `k · dt` in two parts: the whole indices in integer nanoseconds (saturating),
    /// the fraction (the callers' ½) in `f64`, both truncated toward zero as the one
    /// product was. One `f64` product rounds to 2^(e-52) ns beyond 2^53 ns (104 days
    /// of `CLOCK_MONOTONIC` uptime: 256 ns at 1.8e18); below it, the two give the same
    /// nanosecond for every whole or half index.
    fn rel_k(&mut self, k: f64) -> f64 {
        let whole = k.trunc();
        // NaN and ±∞ as before: NaN 0, ±∞ saturated (its fraction, NaN, adds 0)
        let frac_ns = ((k - whole) * self.p.dt_ns as f64) as Nanos;
        let t_ns = (whole as Nanos)
            .saturating_mul(self.p.dt_ns)
            .saturating_add(frac_ns)
            .saturating_sub(self.group_delay_ns);
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

    /// Offset and variance predicted at tracker time `t` from the current estimate.
    fn predict(&self, t: f64) -> (f64, f64) {
        let dt = t - self.cur.t;
        (
            self.cur.o + self.d.0 * dt,
            self.cur.var + self.drift_growth(t) + self.p.qo * self.p.qo * dt.abs(),
        )
    }

    /// What the drift's uncertainty adds to the current variance between the
    /// current estimate's time and `t`: `vd·((t - m)² - (t_cur - m)²)` with `m` the
    /// last measurement's time, so that any number of hops blind add up to
    /// `vd·(t - m)²` (hop by hop, `vd·dt²` summed to `vd·(t - m)²/hops`: a σ that
    /// after an hour blind still told of milliseconds); at least `vd·dt²`.
    fn drift_growth(&self, t: f64) -> f64 {
        let vd = self.d.1;
        let dt = t - self.cur.t;
        let (a, b) = (t - self.cur.measured, self.cur.t - self.cur.measured);
        (vd * (a * a - b * b)).max(vd * dt * dt)
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
        self.cur = Current {
            t,
            o: self.cur.o + self.d.0 * dt,
            var: self.cur.var + self.drift_growth(t) + q * q * dt,
            measured: self.cur.measured,
        };
        if self.mode == Mode::Locked && self.cur.var > self.p.lost_var {
            self.lose();
        }
    }

    /// The lock is gone: re-acquire (state `lost` once it had locked).
    fn lose(&mut self) {
        // a lock that held (the same test as for the alternative below): one of a few
        // hops may have been the signatures' own structure, and leaves an earlier
        // lock's record as it was
        if self.mode == Mode::Locked && self.locked_hops >= RECENTRE_HOPS {
            self.lost_from = Some(LostFrom {
                t: self.cur.t,
                o: self.cur.o,
                drift: self.d.0,
                drift_var: self.d.1,
            });
        }
        self.step_job = None;
        self.corr.restart_acq();
        self.enter_acquisition();
        self.acq = Streak::default();
        self.blind_moving = 0;
        if self.locked_hops >= RECENTRE_HOPS || self.alt_lag0.is_none() {
            self.acq_tries = 0;
            self.acq_quiet = 0;
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

#[derive(Debug, Clone, Copy)]
enum Which {
    Acq,
    Seg,
    Glr(usize),
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::step::StepStage;
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
            // equal to rounding
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

    /// An unvalidated configuration (a library caller's) with a non-finite or
    /// out-of-range reset jump or value limit runs as the validated one would.
    #[test]
    fn an_unvalidated_nan_reset_jump_runs_as_the_default() {
        let run = generate(Family::Robot, 1, Some(40.0)).pushes();
        let count = |cfg: &EstimatorConfig| {
            let mut e = Estimator::new(cfg);
            let mut n = 0;
            for &(stream, s) in &run {
                let _ = e.push(stream, s);
                n += std::iter::from_fn(|| e.poll()).count();
            }
            (n, e.stats().locks)
        };
        let ok = count(&EstimatorConfig::default());
        assert!(ok.0 > 50 && ok.1 > 0, "{ok:?}");
        for bad in [
            EstimatorConfig {
                reset_jump_s: f64::NAN,
                ..EstimatorConfig::default()
            },
            EstimatorConfig {
                reset_jump_s: 0.1,
                max_abs_value: f64::INFINITY,
                ..EstimatorConfig::default()
            },
        ] {
            assert_eq!(count(&bad), ok, "{bad:?}");
        }
    }

    /// An unvalidated configuration `validate` refuses builds within bounds: a
    /// segment of 600 s in hops of 0.5 ms at ±2 s on a 2 kHz grid asked for 1.2
    /// million blocks of 8001 lags (230 GB, an abort), and a high-pass cut-off of
    /// 1e-10 Hz made every filtered value NaN (never a lock).
    #[test]
    fn an_unvalidated_extreme_config_is_bounded_and_still_filters() {
        let huge = EstimatorConfig {
            grid_hz: 2000.0,
            hop_s: 0.0005,
            segment_s: 600.0,
            max_lag_s: 2.0,
            ..EstimatorConfig::default()
        };
        let p = Params::new(&huge);
        let lags = (2 * p.half_lags + 1) as f64;
        assert!(
            lags * (p.seg_blocks as f64 + 1.0) <= vlsync_config::MAX_LAG_SUMS,
            "{} blocks of {lags} lags",
            p.seg_blocks
        );
        assert!(p.seg_blocks >= p.acq_blocks);
        assert!(p.hop_s >= 0.05, "hop {} s", p.hop_s);
        let tiny_highpass = EstimatorConfig {
            highpass_hz: 1e-10,
            ..EstimatorConfig::default()
        };
        assert_eq!(Params::new(&tiny_highpass).highpass_hz, 0.0);
        let mut e = Estimator::new(&tiny_highpass);
        let mut locked = 0;
        for (stream, s) in generate(Family::Robot, 1, Some(40.0)).pushes() {
            let _ = e.push(stream, s);
            while let Some(x) = e.poll() {
                assert!(x.offset_s.is_finite(), "{x:?}");
                locked += usize::from(x.state == EstimatorState::Tracking);
            }
        }
        assert!(locked > 20, "{locked} tracking estimates");
    }

    /// The acquisition's score gate is `min_acquire_score`, never below
    /// `min_peak_score` (a configuration from before the key that raised
    /// `min_peak_score` keeps its stricter acquisition).
    #[test]
    fn the_acquisition_asks_at_least_the_measurements_score() {
        let p = |peak: f64, acq: f64| {
            Params::new(&EstimatorConfig {
                min_peak_score: peak,
                min_acquire_score: acq,
                ..EstimatorConfig::default()
            })
            .acq_min_score
        };
        assert_eq!(p(0.4, 0.7), 0.7);
        assert_eq!(p(0.8, 0.7), 0.8);
        assert_eq!(p(0.4, 0.2), 0.4);
    }

    /// A restore mid-run, wherever it falls (moving or at a stop), publishes finite
    /// standard deviations only: before the first measurement with motion after it,
    /// a segment measurement without motion once grew the variance by the time since
    /// the last information, which a restore leaves at -inf (σ = inf, then `lost`;
    /// the daemon refuses to publish such an estimate).
    #[test]
    fn a_restore_mid_run_never_gives_an_infinite_sigma() {
        let all = generate(Family::Robot, 1, Some(150.0)).pushes();
        let cfg = EstimatorConfig::default();
        let mut restored = 0;
        for at_s in (20..=140).step_by(10) {
            let (mut a, mut b) = (Estimator::new(&cfg), Estimator::new(&cfg));
            let at_ns = at_s * 1_000_000_000;
            let (ea, _, injected) = replay_interrupted(
                &all,
                Interrupt::Restore,
                0.0,
                (&mut a, &mut b),
                |_, e, t| {
                    t > at_ns
                        && e.last()
                            .is_some_and(|l| l.state != EstimatorState::Acquiring)
                },
            );
            restored += usize::from(injected.is_some());
            for e in &ea {
                assert!(
                    e.offset_std_s.is_finite() && e.drift_std.is_finite(),
                    "restored at {at_s} s: {e:?}"
                );
            }
        }
        assert!(restored >= 10, "{restored} restores");
    }

    /// A saved estimate with an offset beyond `vlsync_common::MAX_ABS_OFFSET_S` is
    /// refused, like a non-finite one: the estimator stays as it was. Such an offset
    /// used to centre the lags at a saturated lag, and the first step's lag range
    /// overflowed (a panic with overflow checks, as in the tests and the fuzz targets).
    #[test]
    fn a_restore_beyond_the_offset_range_is_refused_and_pushes_never_overflow() {
        let cfg = EstimatorConfig::default();
        let saved = |offset_s: f64, drift: f64| Estimate {
            seq: 0,
            t_ref_ns: 0,
            offset_s,
            drift,
            offset_std_s: 0.001,
            drift_std: 1e-6,
            state: EstimatorState::Tracking,
            polarity: Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: 2.0,
            measured_offset_s: f64::NAN,
        };
        let feed = |e: &mut Estimator| {
            for i in 0..300i64 {
                let t = i * 10_000_000;
                let v = (i as f64 * 0.1).sin();
                let _ = e.push(Stream::Cam, Sample::new(t, v));
                let _ = e.push(Stream::Lidar, Sample::new(t + 1_000_000, v));
                while e.poll().is_some() {}
            }
        };
        for offset_s in [1e17, -1e17, f64::MAX, -f64::MAX, 1.000001e6, -1.000001e6] {
            let mut e = Estimator::new(&cfg);
            e.restore(&saved(offset_s, 0.0), 0.0);
            assert_eq!(e.state(), EstimatorState::Acquiring, "{offset_s}");
            feed(&mut e);
        }
        // the largest accepted offset restores, drifted as far as a restore allows,
        // and the pushes after it run
        for (offset_s, drift) in [(MAX_ABS_OFFSET_S, 1.0), (-MAX_ABS_OFFSET_S, -1.0)] {
            let mut e = Estimator::new(&cfg);
            e.restore(&saved(offset_s, drift), 1e9);
            assert_eq!(e.state(), EstimatorState::Holding, "{offset_s}");
            feed(&mut e);
        }
    }

    /// Tracker times of grid indices on a time base of 1.8e18 ns (57 years; past
    /// 2^53 ns, 104 days of uptime, one `f64` product `k · dt` rounds to 256 ns) are
    /// exact: whole and half indices a whole number of half grid steps apart.
    #[test]
    fn tracker_times_of_indices_are_exact_on_a_late_time_base() {
        for grid_hz in [100.0, 30.0, 333.0, 2000.0] {
            let cfg = EstimatorConfig {
                grid_hz,
                ..EstimatorConfig::default()
            };
            let mut e = Estimator::new(&cfg);
            let dt = e.p.dt_ns;
            let k0 = (1_800_000_000_000_000_000 / dt + 1) as f64;
            // the first call anchors the tracker's time (0 at k0)
            assert_eq!(e.rel_k(k0), 0.0);
            let mut inexact = 0;
            for j in 1..200i64 {
                let want = (j * dt / 2) as f64 * 1e-9;
                assert_eq!(
                    e.rel_k(k0 + 0.5 * j as f64),
                    want,
                    "{grid_hz} Hz, {j} half steps"
                );
                // one product, as before, is not
                let one = |k: f64| (k * dt as f64) as Nanos;
                inexact += usize::from(one(k0 + 0.5 * j as f64) - one(k0) != j * dt / 2);
            }
            assert!(inexact > 0, "{grid_hz} Hz: one product was exact too");
            // and going back before the anchor
            assert_eq!(e.rel_k(k0 - 3.0), (-3 * dt) as f64 * 1e-9);
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

    /// A clock step of either stream, forward or back, is taken at its size: the
    /// other stream's progress over the step tells only a silence of both. The
    /// LiDAR's steps (10 Hz, the slower stream) were taken 100 ms short, one of its
    /// intervals: the jump less the other's progress (its whole interval) less the
    /// interval again; the camera's 33 ms off when a LiDAR scan fell in between.
    #[test]
    fn a_clock_step_of_either_stream_is_taken_at_its_size() {
        let run = generate(Family::Robot, 3, Some(90.0)).pushes();
        for stream in [Stream::Cam, Stream::Lidar] {
            for jump_s in [7.0, -7.0, 12.345] {
                let jump = (jump_s * 1e9) as Nanos;
                // the step at several phases of the other stream's samples
                for at_ms in [40_000, 40_011, 40_023, 40_050, 40_077] {
                    let mut e = Estimator::new(&EstimatorConfig::default());
                    for &(s_stream, mut s) in &run {
                        if s_stream == stream && s.t_ns > at_ms * 1_000_000 {
                            s.t_ns += jump;
                        }
                        let _ = e.push(s_stream, s);
                        while e.poll().is_some() {}
                    }
                    let si = idx(stream);
                    assert_eq!(e.stats().resets[si], 1, "{stream:?} {jump_s} at {at_ms}");
                    let err_ms = (e.jumps[si] - jump) as f64 * 1e-6;
                    assert!(
                        err_ms.abs() < 10.0,
                        "{stream:?} stepped {jump_s} s at {at_ms} ms: taken {err_ms:+.1} ms off"
                    );
                }
            }
        }
    }

    /// Held blind, the offset's σ grows with the drift's σ times the whole time
    /// since the last measurement (the drift's error moves the offset linearly):
    /// added hop by hop as `vd·hop²`, an hour blind added `vd·hop·3600 s` instead of
    /// `vd·(3600 s)²` (σ 1.0 ms instead of 18 ms at 5 ppm). Without the holding
    /// random walk (`hold_process_noise = 0`) the drift's share is all there is.
    #[test]
    fn a_held_sigma_grows_with_the_drifts_sigma_times_the_time_blind() {
        let cfg = EstimatorConfig {
            hold_process_noise: 0.0,
            ..EstimatorConfig::default()
        };
        let mut e = Estimator::new(&cfg);
        // locked at t = 0 on a measurement of σ 1 ms, the drift known to 5 ppm
        e.ever_locked = true;
        e.mode = Mode::Locked;
        e.info_t = 0.0;
        e.cur = Current {
            t: 0.0,
            o: 0.1,
            var: 1e-6,
            measured: 0.0,
        };
        let vd = 5e-6f64.powi(2);
        e.d = (2e-6, vd);
        // the offset's own walk during the first window (`qo` until then)
        let walk = e.p.qo.powi(2) * e.p.window_s;
        let hop = e.p.hop_s;
        let hops = (3600.0 / hop).round() as i64;
        let (_, predicted) = e.predict(3600.0);
        for i in 1..=hops {
            e.hold_to(i as f64 * hop);
        }
        let want = 1e-6 + vd * 3600f64.powi(2) + walk;
        assert_eq!(e.mode, Mode::Locked);
        assert!(
            (e.cur.var / want - 1.0).abs() < 0.01,
            "σ after an hour blind {:.2} ms, want {:.2} ms",
            e.cur.var.sqrt() * 1e3,
            want.sqrt() * 1e3
        );
        assert!((e.cur.o - (0.1 + 2e-6 * 3600.0)).abs() < 1e-9);
        // the prediction over the hour at once (the gate's width: the offset's walk
        // at the tracking rate `qo` throughout) has the same drift share
        let want_predicted = 1e-6 + vd * 3600f64.powi(2) + e.p.qo.powi(2) * 3600.0;
        assert!(
            (predicted / want_predicted - 1.0).abs() < 0.01,
            "predicted σ {:.2} ms, want {:.2} ms",
            predicted.sqrt() * 1e3,
            want_predicted.sqrt() * 1e3
        );
        // and a prediction from the held estimate one hop on adds that hop's share
        let (_, next) = e.predict(3600.0 + hop);
        let want_next = 1e-6 + vd * (3600.0 + hop).powi(2) + walk + e.p.qo.powi(2) * hop;
        assert!((next / want_next - 1.0).abs() < 0.01, "{next} {want_next}");
    }
}
