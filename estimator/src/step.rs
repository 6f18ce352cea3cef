//! The step test: a two-sample test of the segment's newest blocks against the
//! rest, run in stages on the pushes after each tracking hop; its evidence
//! accumulates over hops into a change point (a new segment), and short of one it
//! widens the reported σ. It also feeds the drift fit its disjoint short windows
//! and the bias record.

use super::*;

/// Step-test statistic (squared sigmas) from which a possible change inflates σ.
pub(super) const SUSPECT_STAT: f64 = 4.0;

/// Disjoint short-window innovations (newest data against the estimate's
/// prediction) whose mean estimates the estimate's current bias: 4 step windows,
/// 8 s by default.
pub(super) const BIAS_WINDOWS: usize = 4;

/// Where a step test in progress stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum StepStage {
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
pub(super) struct StepJob {
    pub(super) sign: f64,
    pub(super) pred_t: f64,
    pub(super) stage: StepStage,
    /// The segment's first stored block and the number stored.
    pub(super) first: usize,
    pub(super) n: usize,
    /// Lag slots searched.
    pub(super) lo: usize,
    pub(super) hi: usize,
    /// Motion references (see [`Estimator::seg_moving`]).
    pub(super) refs: [f64; 2],
    /// Longest post window, and the current and previous lengths, in blocks.
    pub(super) max_post: usize,
    pub(super) len: usize,
    pub(super) prev: usize,
    /// The most significant split so far: statistic, first post block, post
    /// measurement, innovation.
    pub(super) best: Option<(f64, usize, Meas, f64)>,
    /// The slower stream's sample rate when the test started ([`Estimator::min_rate`]).
    pub(super) rate: f64,
    /// Blocks of the segment's total summed so far (the total takes a stage per
    /// [`segment::PREP_BLOCKS`] blocks).
    pub(super) total_done: usize,
}

impl StepJob {
    pub(super) fn new(sign: f64, pred_t: f64) -> Self {
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
    pub(super) fn span(&self, first: usize, last: usize, lo: usize, hi: usize) -> Span {
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

impl Estimator {
    /// Runs the next stage of the pending step test, if any.
    pub(super) fn step_stage(&mut self) {
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
    pub(super) fn finish_step(&mut self) {
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
    pub(super) fn step_start(&mut self, job: &mut StepJob) -> bool {
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
    pub(super) fn step_total(&mut self, job: &mut StepJob) -> bool {
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
    pub(super) fn step_post(&mut self, job: &mut StepJob) -> bool {
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
    pub(super) fn step_verdict(&mut self, job: &StepJob) {
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

    /// Adds a disjoint short-window innovation `nu` (variance `var`, clipped at 3σ:
    /// the short windows' errors have heavy tails) and re-estimates the squared
    /// bias of the estimate: the weighted mean of the newest [`BIAS_WINDOWS`]
    /// innovations, squared, less its own variance. An estimate that the newest data
    /// keep contradicting (a step the step test cannot confirm yet, a drift outside
    /// the prior) reports that in its σ; the estimate itself is unchanged.
    pub(super) fn add_innovation(&mut self, nu: f64, var: f64) {
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
    pub(super) fn change_at_block(&mut self, c: usize) {
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
}
