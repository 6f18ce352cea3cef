//! The vlsync estimator: pure, deterministic, allocation-free after construction.
//!
//! Push `(timestamp, value)` samples of the camera and LiDAR signature streams in
//! any interleaving; poll [`Estimate`]s, one per completed hop.
//!
//! Pipeline: [`resample`] (validate, linear interpolation onto a uniform grid on
//! each sensor's own clock) → [`filter`] (the same band-pass on both) →
//! [`correlator`] (incremental windowed Pearson correlation per lag, O(lags) per
//! grid sample) → [`peak`] (gated peak search, sub-sample refinement, polarity) →
//! [`tracker`] (Kalman filter on offset and drift, innovation gate, step re-lock).
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

pub mod correlator;
pub mod filter;
pub mod peak;
pub mod resample;
pub mod tracker;

use correlator::{Correlator, Step, Sums};
use filter::BandPass;
use resample::{Discontinuity, Resampler};
use tracker::{Tracker, Update};
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
    /// Accepted correlation measurements.
    pub measurements: u64,
    /// Measurements rejected by the innovation gate.
    pub outliers: u64,
    /// Offset steps detected (fast re-lock).
    pub steps: u64,
    /// Locks acquired (first lock and re-acquisitions).
    pub locks: u64,
}

fn idx(s: Stream) -> usize {
    match s {
        Stream::Cam => 0,
        Stream::Lidar => 1,
    }
}

const QUEUE: usize = 64;
/// Consecutive mutually consistent long-window deviations that re-lock the filter on them.
const OUTLIER_RELOCK: u32 = 8;
/// Normalised innovation counted as a deviation for the re-lock rule.
const RELOCK_NORM: f64 = 2.0;
/// Normalised innovation beyond which a measurement's weight falls (Huber).
const HUBER_K: f64 = 1.5;
/// Time constant of the decay of each stream's "typical motion" variance, seconds.
const MOTION_REF_TAU_S: f64 = 120.0;
/// Floor of the measurement standard deviation (stamp jitter, interpolation), seconds.
const MIN_MEAS_STD_S: f64 = 2e-4;

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
    min_n: f64,
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
    qd: f64,
    q_hold: f64,
    drift0: f64,
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
        let max_lag_s = cl(c.max_lag_s, 0.01, 2.0);
        let lowpass_hz = cl(c.lowpass_hz, 0.05, 0.45 * fs);
        Self {
            dt_ns,
            dt_s,
            fs,
            hop_len: ((hop_s * fs).round() as i64).max(1),
            half_lags: ((max_lag_s * fs).round() as i64).max(2),
            center_lag: (cl(c.lag_center_s, -1e6, 1e6) * fs).round() as i64,
            track_slots: (cl(c.track_range_s, 0.005, max_lag_s) * fs).max(2.0),
            min_n: cl(c.step_window_s, 0.5, window_s) * fs,
            window_s,
            hop_s,
            lowpass_hz,
            highpass_hz: cl(c.highpass_hz, 0.0, 0.9 * lowpass_hz),
            min_score: cl(c.min_peak_score, 0.0, 1.0),
            min_ratio: cl(c.min_peak_ratio, 1.0, 100.0),
            min_motion: cl(c.min_motion_ratio, 0.0, 1.0),
            acquire_confirm: c.acquire_confirm.clamp(1, 100),
            noise_scale: cl(c.measurement_noise_scale, 1e-3, 1e3),
            qo: cl(c.offset_process_noise, 0.0, 1.0),
            qd: cl(c.drift_process_noise, 0.0, 1.0),
            q_hold: cl(c.hold_process_noise, 0.0, 1.0),
            drift0: cl(c.initial_drift_std, 1e-9, 0.1),
            gate: cl(c.gate_sigma, 1.0, 100.0),
            step_gate: cl(c.step_gate_sigma, 1.0, 100.0),
            step_confirm: c.step_confirm.clamp(1, 100),
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

/// One hop's correlation measurement.
#[derive(Debug, Clone, Copy)]
struct Meas {
    z: f64,
    var: f64,
    score: f64,
    ratio: f64,
    sign: f64,
}

/// Online offset/drift estimator. Push samples of both streams in any
/// interleaving; poll estimates. Allocates nothing after [`Estimator::new`].
#[derive(Debug, Clone)]
pub struct Estimator {
    p: Params,
    rs: [Resampler; 2],
    bp: [BandPass; 2],
    corr: Correlator,
    scratch: Vec<f64>,
    group_delay_ns: Nanos,
    half_window_ns: Nanos,
    mode: Mode,
    ever_locked: bool,
    kf: Tracker,
    epoch_ns: Option<Nanos>,
    polarity: Polarity,
    acq: Streak,
    step: Streak,
    /// Consecutive long-window outliers.
    outl: Streak,
    /// Consecutive hops with motion but no usable peak near the prediction.
    blind_moving: usize,
    /// Since the last lock or re-lock the filter holds one window's information:
    /// while that window grows, its newest measurement replaces the offset.
    superseding: bool,
    motion_ref: [f64; 2],
    /// Per stream: the other stream's newest accepted time when this stream's newest
    /// sample was accepted (tells a silence from a clock step).
    other_at_last: [Option<Nanos>; 2],
    last_meas_t: f64,
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
        let window_blocks = ((p.window_s / p.hop_s).round() as usize).max(1);
        let short_blocks = ((p.min_n / p.hop_len as f64).round() as usize).clamp(1, window_blocks);
        let ring_len = n_lags + 2 * p.stall_slots as usize + 64;
        let corr = Correlator::new(
            n_lags,
            p.center_lag - p.half_lags,
            p.hop_len,
            window_blocks,
            short_blocks,
            ring_len,
        );
        let max_gap_ns = (cfg.max_gap_s.clamp(0.01, 60.0) * 1e9) as Nanos;
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
        Self {
            rs: [rs.clone(), rs],
            bp: [bp.clone(), bp],
            corr,
            scratch: vec![0.0; n_lags],
            group_delay_ns,
            half_window_ns: (p.window_s * 0.5e9) as Nanos,
            mode: Mode::Acquire,
            ever_locked: false,
            kf: Tracker::new(0.0, cfg.lag_center_s, p.max_lag_s.powi(2), p.drift0),
            epoch_ns: None,
            polarity: Polarity::Unknown,
            acq: Streak::default(),
            step: Streak::default(),
            outl: Streak::default(),
            blind_moving: 0,
            superseding: false,
            motion_ref: [0.0; 2],
            other_at_last: [None; 2],
            last_meas_t: f64::NEG_INFINITY,
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
    pub fn push(&mut self, stream: Stream, sample: Sample) -> Result<(), RejectReason> {
        let si = idx(stream);
        let other_now = self.rs[1 - si].last_time();
        let Self { rs, bp, corr, .. } = self;
        let bp_s = &mut bp[si];
        let res = rs[si].push(sample, |k, v| {
            let y = bp_s.step(v);
            match stream {
                Stream::Cam => corr.push_cam(k, y),
                Stream::Lidar => corr.push_lidar(k, y),
            }
        });
        let disc = match res {
            Ok(d) => d,
            Err(r) => {
                self.stats.rejected[si][r.index()] += 1;
                return Err(r);
            }
        };
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
                // (both advanced alike) from a step of this stream's clock
                let elapsed = match (other_now, other_then) {
                    (Some(a), Some(b)) => a.saturating_sub(b),
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
        self.check_stall(stream, sample.t_ns);
        Ok(())
    }

    /// Takes the oldest pending estimate, if any.
    pub fn poll(&mut self) -> Option<Estimate> {
        self.queue.pop()
    }

    /// Counters.
    pub fn stats(&self) -> &EstimatorStats {
        &self.stats
    }

    /// Current state (the state of the last estimate).
    pub fn state(&self) -> EstimatorState {
        self.current_state(false)
    }

    /// Degraded mode, for a caller over its latency budget: once locked, only the
    /// lags within the tracking range are updated (about 6x less work per sample
    /// at default settings). Switching resets the correlation window.
    pub fn set_degraded(&mut self, on: bool) {
        self.degraded = on;
        if !on {
            let n = self.corr.n_lags();
            self.corr.set_active(0, n - 1);
        }
    }

    /// Whether degraded mode is on.
    pub fn degraded(&self) -> bool {
        self.degraded
    }

    /// Starts from a previously saved estimate (e.g. after a restart): the state is
    /// `holding` around `est.offset_s` with the standard deviation inflated for
    /// `age_s` seconds of blindness, and acquisition searches around it.
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
        let drift = est.drift.clamp(-0.1, 0.1);
        let drift_std = est.drift_std.clamp(1e-9, self.p.drift0.max(1e-9));
        // blind for `age` seconds: the offset moved by the drift, and its uncertainty
        // grew like a holding state's (plus the drift's)
        let var =
            est.offset_std_s.powi(2) + self.p.q_hold.powi(2) * age + (drift_std * age).powi(2);
        self.kf = Tracker::new(0.0, est.offset_s + drift * age, var, drift_std);
        self.kf.x[1] = drift;
        self.epoch_ns = None;
        self.ever_locked = true;
        self.polarity = est.polarity;
        // tracking around the restored value (state `holding` until a measurement);
        // without a peak near it while moving, the estimator turns `lost` and re-acquires
        self.mode = Mode::Locked;
        self.superseding = true;
        self.last_meas_t = f64::NEG_INFINITY;
        let lag = (self.kf.x[0] * self.p.fs).round() as i64;
        self.corr.set_lag0(lag - self.p.half_lags);
    }

    fn break_stream(&mut self, stream: Stream) {
        let si = idx(stream);
        self.bp[si].reset();
        match stream {
            Stream::Cam => self.corr.break_cam(),
            Stream::Lidar => self.corr.break_lidar(),
        }
    }

    /// A stream's clock stepped by `jump_ns` (beyond one sample interval): the offset
    /// moves by the same amount (LiDAR: +, camera: -); re-acquire around the new value.
    fn clock_jump(&mut self, stream: Stream, jump_ns: Nanos) {
        let j = jump_ns as f64 * 1e-9;
        let shift = match stream {
            Stream::Cam => -j,
            Stream::Lidar => j,
        };
        let interval = self.rs[idx(stream)].mean_interval_s();
        self.kf.x[0] += shift;
        self.kf.p[(0, 0)] += interval * interval;
        self.epoch_ns = None;
        let lag = (self.kf.x[0] * self.p.fs).round() as i64;
        self.corr.set_lag0(lag - self.p.half_lags);
        self.mode = Mode::Acquire;
        self.acq = Streak::default();
        self.step = Streak::default();
    }

    fn run_correlator(&mut self) {
        loop {
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
            Stream::Cam => t_ns.saturating_add((self.kf.x[0] * 1e9) as Nanos),
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
        // at most one queue's worth of blind estimates
        let start = first.max(target - (QUEUE as i64 - 1) * hl);
        let mut b = start;
        while b <= target {
            // blind estimates refer to where a full window's centre would be
            let t_ref = b * self.p.dt_ns - self.group_delay_ns - self.half_window_ns;
            let t = self.rel(t_ref);
            self.blind(t);
            // a silent sensor (not just a still robot) may come back with another
            // latency: after two windows without data, re-acquire instead of holding
            if self.mode == Mode::Locked && t - self.last_meas_t > 2.0 * self.p.window_s {
                self.mode = Mode::Acquire;
                self.acq = Streak::default();
            }
            let st = self.current_state(false);
            self.emit(t_ref, st, None, 0.0, 0.0);
            b += hl;
        }
        self.corr.skip_to(target);
        self.acq = Streak::default();
        self.step = Streak::default();
    }

    /// Tracker time of LiDAR time `t_ns`. After a clock jump the epoch is
    /// re-anchored so the tracker's time continues where it was.
    fn rel(&mut self, t_ns: Nanos) -> f64 {
        let kf_t = self.kf.t;
        let e = *self
            .epoch_ns
            .get_or_insert_with(|| t_ns.saturating_sub((kf_t * 1e9) as Nanos));
        t_ns.saturating_sub(e) as f64 * 1e-9
    }

    fn meas_var(&self, pk: &peak::Peak, n: f64, min_rate: f64) -> f64 {
        let rho = pk.score.clamp(1e-3, 0.999);
        let kappa = (pk.curvature / (self.p.dt_s * self.p.dt_s)).max(1e-6);
        let band = (self.p.lowpass_hz.min(0.5 * min_rate) - self.p.highpass_hz).max(0.1);
        let n_eff = (2.0 * band * n / self.p.fs).max(1.0);
        let var = self.p.noise_scale * (1.0 - rho * rho) / (rho * kappa * n_eff);
        var.max(MIN_MEAS_STD_S * MIN_MEAS_STD_S)
    }

    fn min_rate(&self) -> f64 {
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

    /// Measures on `sums` within `lo..=hi` with polarity `sign` (0: free).
    fn measure(&mut self, which: Window, lo: usize, hi: usize, sign: f64) -> Option<Meas> {
        let min_rate = self.min_rate();
        let sums: &Sums = match which {
            Window::Long => self.corr.long(),
            Window::Short => self.corr.short(),
        };
        let pk = peak::find(sums, lo, hi, sign, &mut self.scratch)?;
        let n = sums.n;
        let lag0 = self.corr.lag0();
        let z = (lag0 as f64 + pk.slot) * self.p.dt_s;
        Some(Meas {
            z,
            var: self.meas_var(&pk, n, min_rate),
            score: pk.score,
            ratio: pk.ratio,
            sign: pk.sign,
        })
    }

    fn motion_ok(&mut self, update_ref: bool) -> bool {
        let w = self.corr.long();
        let mid = self.corr.n_lags() / 2;
        let (a, b) = self.corr.active();
        let slot = mid.clamp(a, b);
        let v = [w.var_y(slot), w.var_x()];
        let decay = (-self.p.hop_s / MOTION_REF_TAU_S).exp();
        let mut ok = true;
        for (r, &vi) in self.motion_ref.iter_mut().zip(v.iter()) {
            if update_ref {
                *r = (*r * decay).max(vi);
            }
            if !(vi > 0.0 && vi >= self.p.min_motion * *r) {
                ok = false;
            }
        }
        ok
    }

    /// Predict-only step to time `t` (no measurement).
    fn blind(&mut self, t: f64) {
        let q = if t - self.last_meas_t > self.p.window_s {
            self.p.q_hold
        } else {
            self.p.qo
        };
        if self.ever_locked {
            self.kf.predict(t, q, self.p.qd);
            if self.mode == Mode::Locked && self.kf.p[(0, 0)] > self.p.lost_var {
                self.mode = Mode::Acquire;
                self.acq = Streak::default();
            }
        } else {
            self.kf.t = t;
        }
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
        let (first_k, last_k, n) = {
            let w = self.corr.long();
            (w.first_k, w.last_k, w.n)
        };
        // an estimate refers to the centre of its window: the correlation measures
        // the window's average offset, so no drift extrapolation enters it
        let t_ref_ns = self.window_centre_ns(first_k, last_k);
        let t = self.rel(t_ref_ns);
        let h = 0.0;
        let motion = self.motion_ok(n >= self.p.min_n);
        if n < self.p.min_n {
            self.blind(t);
            let st = self.current_state(false);
            self.emit(t_ref_ns, st, None, 0.0, 0.0);
            return;
        }
        match self.mode {
            Mode::Acquire => self.hop_acquire(t_ref_ns, t, h, motion),
            Mode::Locked => self.hop_track(t_ref_ns, t, h, motion),
        }
    }

    /// LiDAR time of the centre of the window covering grid indices `first..=last`,
    /// corrected for the band-pass delay.
    fn window_centre_ns(&self, first: i64, last: i64) -> Nanos {
        (first + last) * self.p.dt_ns / 2 - self.group_delay_ns
    }

    fn hop_acquire(&mut self, t_ref_ns: Nanos, t: f64, h: f64, motion: bool) {
        let (lo, hi) = self.corr.active();
        let m = self.measure(Window::Long, lo, hi, 0.0);
        self.blind(t);
        let Some(m) =
            m.filter(|m| motion && m.score >= self.p.min_score && m.ratio >= self.p.min_ratio)
        else {
            self.acq = Streak::default();
            let st = self.current_state(false);
            let (sc, ra) = m.map_or((0.0, 0.0), |m| (m.score, m.ratio));
            self.emit(t_ref_ns, st, m.map(|m| m.z), sc, ra);
            return;
        };
        let allowance = 3.0 * (self.p.drift0 * self.p.hop_s) + 0.002;
        let consistent = self.acq.count > 0
            && self.acq.sign == m.sign
            && (m.z - self.acq.z).abs() <= 3.0 * (m.var + self.acq.var).sqrt() + allowance;
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
        // lock: offset measured at the window centre, h before t
        let (drift, drift_var) = if self.ever_locked {
            (
                self.kf.x[1],
                self.kf.p[(1, 1)].max(self.p.drift0.powi(2) * 0.01),
            )
        } else {
            (0.0, self.p.drift0.powi(2))
        };
        self.kf = Tracker::new(t, m.z + drift * h, m.var, drift_var.sqrt());
        self.kf.x[1] = drift;
        self.mode = Mode::Locked;
        self.ever_locked = true;
        self.superseding = true;
        self.polarity = if m.sign > 0.0 {
            Polarity::Positive
        } else {
            Polarity::Negative
        };
        self.last_meas_t = t;
        self.acq = Streak::default();
        self.step = Streak::default();
        self.stats.locks += 1;
        self.stats.measurements += 1;
        self.emit(
            t_ref_ns,
            EstimatorState::Tracking,
            Some(m.z),
            m.score,
            m.ratio,
        );
    }

    /// Slots around the offset predicted at the centre of a window ending `h` before... at `t - h`.
    fn track_slots(&self, pred: f64) -> (usize, usize) {
        let (a, b) = self.corr.active();
        let c = pred * self.p.fs - self.corr.lag0() as f64;
        let lo = (c - self.p.track_slots).floor().max(a as f64) as usize;
        let hi = ((c + self.p.track_slots).ceil().max(0.0) as usize).min(b);
        (lo.min(hi), hi)
    }

    fn hop_track(&mut self, t_ref_ns: Nanos, t: f64, h: f64, motion: bool) {
        self.blind(t);
        if self.mode != Mode::Locked {
            // just became lost
            self.emit(t_ref_ns, EstimatorState::Lost, None, 0.0, 0.0);
            return;
        }
        let sign = self.polarity.sign();
        // keep the lag range centred on the prediction (drift over hours) and, in degraded
        // mode, restrict the work to the tracking range
        let pred_slot = self.kf.x[0] * self.p.fs - self.corr.lag0() as f64;
        let mid = (self.corr.n_lags() / 2) as f64;
        // re-centre only when the tracking range nears the edge of the lag range:
        // every re-centre empties the window
        if (pred_slot - mid).abs() > mid - 2.0 * self.p.track_slots {
            let lag = (self.kf.x[0] * self.p.fs).round() as i64;
            self.corr.set_lag0(lag - self.p.half_lags);
            self.emit(t_ref_ns, EstimatorState::Holding, None, 0.0, 0.0);
            return;
        }
        if self.degraded {
            let margin = self.p.track_slots + 0.25 * self.p.fs * self.p.max_lag_s;
            let lo = (pred_slot - margin).floor().max(0.0) as usize;
            let hi = (pred_slot + margin).ceil().max(0.0) as usize;
            if (lo, hi.min(self.corr.n_lags() - 1)) != self.corr.active() {
                self.corr.set_active(lo, hi);
                self.emit(t_ref_ns, EstimatorState::Holding, None, 0.0, 0.0);
                return;
            }
        }
        // step detection on the short window
        let short_full = self.corr.blocks_in_window() > self.corr.short_blocks();
        if short_full && motion {
            let (s_first, s_last) = (self.corr.short().first_k, self.corr.short().last_k);
            // the short window's centre is later than the long one's: hs < 0
            let t_s_ns = self.window_centre_ns(s_first, s_last);
            let hs = t - self.rel(t_s_ns);
            let pred_s = self.kf.offset_at(t - hs);
            let (lo, hi) = self.track_slots(pred_s);
            match self.measure(Window::Short, lo, hi, sign) {
                Some(ms) if ms.score >= self.p.min_score => {
                    let nu = ms.z - pred_s;
                    let thr = self.p.step_gate * (self.kf.var_at_lag(hs) + ms.var).sqrt();
                    if nu.abs() > thr {
                        let same = self.step.count > 0
                            && self.step.sign == nu.signum()
                            && (ms.z - self.step.z).abs() <= 3.0 * (ms.var + self.step.var).sqrt();
                        self.step = Streak {
                            count: if same { self.step.count + 1 } else { 1 },
                            z: ms.z,
                            var: ms.var,
                            sign: nu.signum(),
                        };
                    } else {
                        self.step = Streak::default();
                    }
                    if self.step.count >= self.p.step_confirm {
                        let short_blocks = self.corr.short_blocks();
                        self.corr.truncate(short_blocks);
                        // the short window's variance is optimistic; keep the step's own
                        // size as uncertainty so the long window can still correct it
                        let var = ms.var.max(0.25 * (ms.z - pred_s).powi(2));
                        self.superseding = true;
                        self.step = Streak::default();
                        self.adopt(t_ref_ns, t, ms.z + self.kf.x[1] * hs, var, &ms, true);
                        return;
                    }
                }
                _ => self.step = Streak::default(),
            }
        }
        let pred_c = self.kf.offset_at(t - h);
        let (lo, hi) = self.track_slots(pred_c);
        let m = self.measure(Window::Long, lo, hi, sign);
        let Some(m) = m.filter(|m| motion && m.score >= self.p.min_score) else {
            let (sc, ra) = m.map_or((0.0, 0.0), |m| (m.score, m.ratio));
            // moving, yet no peak near the prediction for two windows: the lock is wrong
            self.blind_moving = if motion { self.blind_moving + 1 } else { 0 };
            if self.blind_moving >= 2 * self.corr.window_blocks() {
                self.blind_moving = 0;
                self.mode = Mode::Acquire;
                self.acq = Streak::default();
                self.emit(t_ref_ns, EstimatorState::Lost, m.map(|m| m.z), sc, ra);
                return;
            }
            self.emit(t_ref_ns, EstimatorState::Holding, m.map(|m| m.z), sc, ra);
            return;
        };
        self.blind_moving = 0;
        // overlapping windows reuse each sample window/hop times: inflate R so the
        // filter does not count the same information repeatedly
        let n = self.corr.long().n;
        let overlap = (n / self.p.hop_len as f64).max(1.0);
        let hph = self.kf.var_at_lag(h);
        let norm = (m.z - self.kf.offset_at(t - h)) / (hph + m.var).sqrt();
        // one window that knows more than the filter (the window is still growing
        // after a lock or a step) replaces the filter's offset instead of being fused
        let growing = self.corr.blocks_in_window() < self.corr.window_blocks();
        self.superseding &= growing;
        if self.superseding && m.var < self.kf.var_at_lag(h) && norm.abs() <= self.p.gate {
            self.adopt(t_ref_ns, t, m.z + self.kf.x[1] * h, m.var, &m, false);
            return;
        }
        // deviations that agree with each other are the truth moving (a step the
        // short window missed, or a wrong reset): re-lock on them
        if norm.abs() > RELOCK_NORM {
            let same = self.outl.count > 0
                && self.outl.sign == norm.signum()
                && (m.z - self.outl.z).abs() <= 3.0 * (m.var + self.outl.var).sqrt() + 0.002;
            self.outl = Streak {
                count: if same { self.outl.count + 1 } else { 1 },
                z: m.z,
                var: m.var,
                sign: norm.signum(),
            };
            if self.outl.count >= OUTLIER_RELOCK {
                self.outl = Streak::default();
                let var = m.var.max(0.25 * (m.z - self.kf.offset_at(t - h)).powi(2));
                self.adopt(t_ref_ns, t, m.z + self.kf.x[1] * h, var, &m, true);
                return;
            }
        } else {
            self.outl = Streak::default();
        }
        // Huber weighting: a measurement far from the prediction (a signature
        // mismatch, e.g. rotation seen by the camera only) counts for less
        let huber = if norm.abs() > HUBER_K {
            (norm.abs() / HUBER_K).powi(2)
        } else {
            1.0
        };
        match self
            .kf
            .update(m.z, h, m.var * overlap * huber, m.var, self.p.gate)
        {
            Update::Accepted => self.measured(t_ref_ns, t, &m),
            Update::Outlier(_) => {
                self.stats.outliers += 1;
                self.emit(
                    t_ref_ns,
                    EstimatorState::Holding,
                    Some(m.z),
                    m.score,
                    m.ratio,
                );
            }
        }
    }

    /// Replaces the filter's offset by a measurement (a step, a re-lock, or a
    /// growing window that knows more than the filter) and emits a tracking estimate.
    fn adopt(&mut self, t_ref_ns: Nanos, t: f64, offset: f64, var: f64, m: &Meas, step: bool) {
        self.kf.reset_offset(offset, var);
        if step {
            self.stats.steps += 1;
        }
        self.measured(t_ref_ns, t, m);
    }

    /// Books an accepted measurement and emits a tracking estimate.
    fn measured(&mut self, t_ref_ns: Nanos, t: f64, m: &Meas) {
        self.stats.measurements += 1;
        self.last_meas_t = t;
        self.emit(
            t_ref_ns,
            EstimatorState::Tracking,
            Some(m.z),
            m.score,
            m.ratio,
        );
    }

    fn emit(
        &mut self,
        t_ref_ns: Nanos,
        state: EstimatorState,
        z: Option<f64>,
        score: f64,
        ratio: f64,
    ) {
        let (offset, std) = if self.ever_locked {
            (self.kf.x[0], self.kf.offset_std())
        } else {
            (
                z.unwrap_or(self.corr.lag0() as f64 * self.p.dt_s + self.p.max_lag_s),
                self.p.max_lag_s,
            )
        };
        let e = Estimate {
            seq: self.seq,
            t_ref_ns,
            offset_s: offset,
            drift: if self.ever_locked { self.kf.x[1] } else { 0.0 },
            offset_std_s: std,
            drift_std: if self.ever_locked {
                self.kf.drift_std()
            } else {
                self.p.drift0
            },
            state,
            polarity: self.polarity,
            peak_score: score,
            peak_ratio: ratio,
            measured_offset_s: z.unwrap_or(f64::NAN),
        };
        self.seq += 1;
        self.stats.estimates += 1;
        if self.queue.push(e) {
            self.stats.dropped_estimates += 1;
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum Window {
    Long,
    Short,
}
