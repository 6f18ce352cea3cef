//! Tracking: each locked hop's segment measurement at the reference time (mostly
//! prepared on the samples before the hop), its gating against the prediction,
//! the raw window measurement beside it, and the lag slots a lock keeps updated.

use super::*;
use crate::joint::RAW_CONFIRM_S;

/// Lag slots beyond the tracking range that tracking reads (`Estimator::narrow_to`).
pub(super) const TRACK_NEED_SLOTS: f64 = 6.0;

/// Lag slots updated beyond the needed ones on each side once locked (none in
/// degraded mode).
pub(super) const TRACK_SPARE_SLOTS: f64 = 8.0;

/// The next hop as predicted before its block completes ([`Estimator::next_hop`]),
/// for the preparations of its segment combination and its joint maximum.
#[derive(Debug, Clone, Copy)]
pub(super) struct NextHop {
    /// Blocks stored now (the hop adds one).
    pub(super) n: usize,
    /// The hop's last LiDAR grid index.
    pub(super) k_end: i64,
    pub(super) t_ref_ns: Nanos,
    /// The predicted offset at its reference time.
    pub(super) pred_t: f64,
    /// The first stored block its segment will hold.
    pub(super) first: usize,
}

/// How [`Estimator::measure_span`] weights the blocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Weights {
    /// All 1.
    Uniform,
    /// Re-weighted from the residuals, starting from 1 ([`IRLS_PASSES`] passes).
    Robust,
    /// Re-weighted once from the residuals against the last segment measurement,
    /// starting from the current weights (the segment: its weights and fit carry over
    /// from hop to hop).
    Warm,
}

impl Estimator {
    pub(super) fn hop_track(&mut self, t_ref_ns: Nanos, t: f64, motion: bool) {
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
                    measured: t,
                };
                if motion {
                    self.info_t = t;
                    self.stats.measurements += 1;
                    // what motion looks like on this robot, from a confident lock
                    if m.score >= self.p.acq_min_score
                        && self.locked_hops.is_multiple_of(LOCK_MOTION_HOPS)
                    {
                        self.lock_motion = Some(self.motion_refs());
                    }
                }
                let st = self.current_state(motion);
                self.emit(t_ref_ns, st, raw, m.score, m.ratio);
            }
            // (not before the first measurement with motion since a restore: the
            // restored value stands then, and `info_t` is -inf, an infinite growth)
            Some(m) if self.info_t.is_finite() => {
                // no motion for a while: the segment's value stands, its uncertainty grows
                let grow = self.p.q_hold * self.p.q_hold * (t - self.info_t - self.p.window_s);
                self.cur = Current {
                    t,
                    o: m.z,
                    var: m.var + grow.max(0.0),
                    measured: t,
                };
                if self.cur.var > self.p.lost_var {
                    self.lose();
                }
                let st = self.current_state(false);
                self.emit(t_ref_ns, st, raw, m.score, m.ratio);
            }
            _ => {
                self.hold_to(t);
                // moving, yet no peak near the prediction for two windows: the lock is wrong
                self.blind_moving = if motion { self.blind_moving + 1 } else { 0 };
                if self.blind_moving >= 2 * self.p.acq_blocks && self.mode == Mode::Locked {
                    // (a lock that held `RECENTRE_HOPS` hops is kept as `lost_from`:
                    // after a long park, the park's noise passes the motion gate and
                    // ends a good lock here)
                    self.lose();
                    // a restored lock found wrong was no better than its state file:
                    // its drift goes too (a no-op once the restored slope has faded)
                    self.drift.forget_restored();
                    // the lock was wrong: the offset is anywhere in the range the
                    // search covers now, not within the old lock's σ of it
                    let half_range = self.p.half_lags as f64 * self.p.dt_s;
                    self.cur.var = self.cur.var.max(half_range * half_range);
                }
                let st = self.current_state(false);
                let (sc, ra) = meas.map_or((0.0, 0.0), |m| (m.score, m.ratio));
                self.emit(t_ref_ns, st, raw, sc, ra);
            }
        }
    }

    /// Once locked, only the lags tracking can use are updated: the tracking range
    /// around the prediction at fractional slot `pred_slot` and [`TRACK_NEED_SLOTS`]
    /// beyond it (the segment's search and the joint maximum's hypotheses reach that
    /// far), with [`TRACK_SPARE_SLOTS`] to spare each side. When the prediction
    /// moves, the range follows by as little as keeps the needed slots in it, so the
    /// blocks of a segment (60 s) hold the needed slots too: the offset drifts well
    /// under a slot in that time, and a step starts a new segment.
    pub(super) fn narrow_to(&mut self, pred_slot: f64) {
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

    /// The segment's measurement at this hop: near the prediction (`near`), else over
    /// the whole tracking range (`full`), with the segment's weights re-weighted once
    /// from the last fit; with the information-weighted sums `(Σ w·n, Σ w·n·k)` of its
    /// blocks. From the prepared combination when it was prepared for these inputs.
    pub(super) fn measure_segment(
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

    /// Combines `span` with weights `w` and measures its peak.
    pub(super) fn measure_span(&mut self, span: &Span, sign: f64, w: Weights) -> Option<Meas> {
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

    /// Index of the first stored block of the current segment (at most
    /// `segment_s` long), or `None` when it has fewer than the short window's blocks.
    pub(super) fn segment_first(&self) -> Option<usize> {
        let n = self.corr.count();
        let oldest = n.saturating_sub(self.p.seg_blocks);
        let first = (oldest..n).find(|&i| self.corr.block(i).first_k >= self.seg_start_k)?;
        (n - first >= self.p.short_blocks).then_some(first)
    }

    /// Slots `lo..=hi` narrowed to those the acquisition window holds (see
    /// [`Correlator::acq`]); empty (`lo > hi`) when they do not meet.
    pub(super) fn acq_slots(&self, (lo, hi): (usize, usize)) -> (usize, usize) {
        let w = self.corr.acq();
        (lo.max(w.lo), hi.min(w.hi))
    }

    /// Slots within the tracking range around offset `o`.
    pub(super) fn track_slots_around(&self, o: f64) -> (usize, usize) {
        let (a, b) = self.corr.active();
        let c = o * self.p.fs - self.corr.lag0() as f64;
        let lo = (c - self.p.track_slots).floor().max(a as f64) as usize;
        let hi = ((c + self.p.track_slots).ceil().max(0.0) as usize).min(b);
        (lo.min(hi), hi)
    }

    /// One stage of preparing the next tracking hop's segment combination
    /// ([`Segment::prepare_residuals`], then [`Segment::prepare_sums`]) from the
    /// inputs that hop will have if no block, step or lag shift comes between: the
    /// hop then only adds its new block. A hop whose inputs differ combines
    /// directly, so a wrong guess costs time, never accuracy.
    /// Returns whether it had work.
    pub(super) fn prepare_stage(&mut self) -> bool {
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

    /// The next hop's segment (without its new block) and key, predicted.
    pub(super) fn next_hop_key(&self) -> Option<(Span, PrepKey)> {
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
    pub(super) fn next_hop(&self) -> Option<NextHop> {
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
    pub(super) fn prep_key(&self, span: &Span) -> PrepKey {
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
    pub(super) fn slot_of(&self, z: f64) -> f64 {
        z * self.p.fs - self.corr.lag0() as f64
    }

    /// The acquisition window's peak within the tracking range of the prediction,
    /// moved with the drift from the window's centre to tracker time `t`.
    pub(super) fn raw_measurement(&mut self, sign: f64, t: f64) -> Option<f64> {
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
}
