//! The segment's joint (offset, drift) maximum, run in stages on the pushes after
//! each tracking hop, and the raw window measurements' trend that confirms a fast
//! slope early: the slope measurements that let a drift far outside the prior win
//! ([`crate::drift::DriftFit::set_joint`], [`crate::drift::DriftFit::set_raw_trend`]).

use super::*;
use crate::track::NextHop;

/// Slots by which the joint maximum's drift hypotheses shift the segment's far end
/// ([`Estimator::joint_stage`]).
pub(super) const JOINT_SHIFT: f64 = 3.0;

/// Rounds of the joint maximum's hypotheses per hop at most: the first and up to two
/// re-centrings (a vertex still beyond the hypotheses after them fails the hop).
pub(super) const JOINT_ROUNDS: usize = 3;

/// Raw window measurements kept for their trend ([`DriftFit::set_raw_trend`]).
pub(super) const RAW_TREND: usize = 8;

/// Raw window measurements a trend needs at least.
pub(super) const RAW_TREND_MIN: usize = 4;

/// The raw trend confirms a joint slope ([`DriftFit::set_raw_trend`]) while the
/// reference time is at most this long (s) after the segment's start: its first
/// hops (the reference time is 3 s after the start at a lock, `window_s` less
/// `reference_lag_s`: the lock's hop and the two after it), while the prior's lag costs most and the
/// segment alone cannot show a fast drift at 5σ. Later a true one shows on the
/// segment alone (the seed run's 12 ms/s: 6-13σ by then), and the windows' own
/// excursions would pass: without the limit, a rates-60x5 run (2002) took a
/// 23 ms/s slope 7 s after its start and a heavy-noise run (6000) -7 ms/s 8 s after
/// (estimates 21-25 ms off), and free slopes over 1 ms/s appeared in 41 hops of the
/// drift-free families' 190 seeds each instead of 17 (22 with the limit).
pub(super) const RAW_CONFIRM_S: f64 = 4.0;

/// The newest raw window measurements `(t, z, σ)`: peaks of the acquisition
/// window at its centre time, oldest first; the acquisition's consistent windows
/// before a lock, then each tracking hop's raw measurement. A hop without one (no
/// motion, no peak) or an acquisition's restart clears them. Their trend confirms a
/// joint slope ([`DriftFit::set_raw_trend`]).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct RawTrend {
    pts: [(f64, f64, f64); RAW_TREND],
    n: usize,
}

impl RawTrend {
    pub(super) fn clear(&mut self) {
        self.n = 0;
    }

    pub(super) fn push(&mut self, t: f64, z: f64, var: f64) {
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
    pub(super) fn slope(&self, window_s: f64) -> Option<(f64, f64)> {
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

/// The segment's joint (offset, drift) maximum of a tracking hop
/// ([`Estimator::joint_stage`]), run one combination per pushed sample after the
/// hop, with the weights the hop found (kept by [`Segment::snapshot_weights`]):
/// its result informs the drift fit from the next hop on.
#[derive(Debug, Clone, Copy)]
pub(super) struct JointJob {
    /// The hop's segment at its start: its blocks, slots and reference index.
    pub(super) first: usize,
    pub(super) last: usize,
    pub(super) k_ref: f64,
    pub(super) lo: usize,
    pub(super) hi: usize,
    pub(super) sign: f64,
    /// Hypotheses' spacing and centre.
    pub(super) delta: f64,
    pub(super) c: f64,
    /// Re-centrings done, and the hypothesis the next stage combines.
    pub(super) round: usize,
    pub(super) j: usize,
    /// Peak heights of the round's hypotheses so far, and the pairs each combined.
    pub(super) h: [f64; 3],
    pub(super) nsum: [f64; 3],
    /// The sample rate the hop saw (every push moves the streams' mean intervals).
    pub(super) rate: f64,
    /// Tracker times of the hop and of its segment's end.
    pub(super) t: f64,
    pub(super) t_end: f64,
}

impl JointJob {
    /// The segment under hypothesis `j` of the current round.
    pub(super) fn span(&self, j: usize) -> Span {
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
pub(super) struct JointKey {
    pub(super) epoch: u64,
    /// The blocks the preparation holds (the hop adds its new one), by grid index:
    /// their store indices move when the store is full.
    pub(super) blocks: usize,
    pub(super) first_k: i64,
    pub(super) last_k: i64,
    pub(super) k_ref: f64,
    pub(super) lo: usize,
    pub(super) hi: usize,
    pub(super) c: f64,
    pub(super) delta: f64,
}

impl Estimator {
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
    pub(super) fn start_joint(&mut self, t_ref_ns: Nanos, t: f64, pred_t: f64, sign: f64) -> bool {
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
    pub(super) fn joint_stage(&mut self) {
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
    pub(super) fn joint_fit(&mut self, mut job: JointJob) {
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

    pub(super) fn joint_failed(&mut self, job: &JointJob) {
        self.joint_d = None;
        self.drift.set_joint(job.t, f64::NAN, f64::INFINITY);
    }

    /// Runs the pending joint maximum to its end: before anything changes the stored
    /// blocks (a block completing, a stall, a clock jump) and at the next hop.
    pub(super) fn finish_joint(&mut self) {
        while self.joint_job.is_some() {
            self.joint_stage();
        }
    }

    /// One stage of preparing the next hop's joint maximum's first round (after the
    /// segment's preparation): one hypothesis's combination of the blocks it will
    /// hold besides its new one, from the inputs it will have if no block, step or
    /// lag shift comes between ([`JointKey`]). A hop whose inputs differ combines
    /// its first round directly: the same measurement, at a cost.
    pub(super) fn prepare_joint_stage(&mut self) {
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
    pub(super) fn next_joint_key(&self) -> Option<(JointKey, usize)> {
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
    pub(super) fn joint_inputs(
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
}
