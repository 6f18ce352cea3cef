//! Acquisition: the search over the whole lag range until consistent peaks
//! lock ([`Estimator::hop_acquire`]), the lock's first drift measurement from the
//! window's two halves, and where the search looks when it finds nothing (the
//! start's range or the one it left) or the correlator cannot be served.

use super::*;

impl Estimator {
    /// Counts an acquisition hop that could have locked (the window moved); after
    /// `RECENTRE_HOPS` of them, unless consistent peaks are building a lock here,
    /// the lag range moves to a lost lock's drifted offset ([`Self::drifted_lag0`])
    /// or, when most of those hops moved as the last lock's motion did
    /// ([`Estimator::moving_as_locked`]: a park's noise does not), to the alternative
    /// centre ([`Estimator::alt_lag0`]), the one it left becoming the alternative: a
    /// wrong prediction (a restored state off, two clocks that stepped apart) cannot
    /// keep the search away from the offset. Returns whether it moved.
    pub(super) fn acquisition_try(&mut self) -> bool {
        if self.mode != Mode::Acquire {
            return false;
        }
        self.acq_tries += 1;
        if !self.moving_as_locked() {
            self.acq_quiet += 1;
        }
        // not while consistent peaks are building up to a lock here
        if self.acq_tries < RECENTRE_HOPS || self.acq.count > 0 {
            return false;
        }
        let quiet = self.acq_quiet;
        self.acq_tries = 0;
        self.acq_quiet = 0;
        if let Some(to) = self.drifted_lag0() {
            // the lost lock's offset has drifted out of the middle of this range
            self.alt_lag0 = Some(to);
            return self.move_search(SearchMoveReason::Drift);
        }
        // most of them a park's noise: nothing says the offset is elsewhere
        if 2 * quiet > RECENTRE_HOPS {
            return false;
        }
        self.move_search(SearchMoveReason::NothingFound)
    }

    /// The range centred on the lost lock's offset as its drift predicts it now, when
    /// the drift has moved it by more than a quarter of the range since the loss, that
    /// prediction is known to within a quarter of the range (the drift's uncertainty,
    /// at least 1 ppm, over the time since the loss), and it lies outside the middle
    /// half of the range searched. Two clocks tens of ppm apart carry the offset out of
    /// the range the lock was lost in after hours of a park; the range must follow, as
    /// the published offset does. Clocks that do not drift apart never move it.
    fn drifted_lag0(&self) -> Option<i64> {
        let lost = self.lost_from?;
        let dt = self.cur.t - lost.t;
        let max_lag_s = self.p.half_lags as f64 * self.p.dt_s;
        // a restored drift's variance may be tiny: no clock pair is known that well
        let sd = lost.drift_var.max(1e-12).sqrt();
        if !(dt > 0.0 && (lost.drift * dt).abs() > 0.25 * max_lag_s && sd * dt < 0.25 * max_lag_s) {
            return None;
        }
        let centre = ((lost.o + lost.drift * dt) * self.p.fs).round();
        if !centre.is_finite() {
            return None;
        }
        let to = (centre as i64).saturating_sub(self.p.half_lags);
        let off = to.saturating_sub(self.corr.lag0()).unsigned_abs();
        (off > self.p.half_lags.unsigned_abs() / 2).then_some(to)
    }

    /// Moves the lag range to [`Estimator::alt_lag0`] (the one it leaves becomes the
    /// alternative) and restarts the acquisition there; `false` when there is no
    /// alternative.
    pub(super) fn move_search(&mut self, reason: SearchMoveReason) -> bool {
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
        self.acq_quiet = 0;
        // nothing found where the search was (a restored offset from another setup,
        // clocks that stepped apart): a restored drift is no better than that offset
        self.drift.forget_restored();
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

    /// Both streams deliver (the camera advanced by half the watch), yet the
    /// correlator completed no hop for `RECENTRE_HOPS` hops of LiDAR time (blind
    /// estimates of a stall do not count): the lag range is so far off (a restored
    /// offset of days) that the correlator waits for camera data it will never get,
    /// or the offset's mapping of camera time makes the LiDAR look stalled. The lock,
    /// if any, is lost and the search moves to [`Estimator::alt_lag0`] at once; the
    /// range it left is not searched again.
    pub(super) fn check_unserved(&mut self, t_lidar: Nanos) {
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
                // the range just left could not be served: no way back to it, nor
                // to where its lock's drift would take it
                self.alt_lag0 = None;
                self.lost_from = None;
            }
        }
    }

    pub(super) fn hop_acquire(&mut self, t_ref_ns: Nanos, t: f64, motion: bool) {
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
            covered && motion && m.score >= self.p.acq_min_score && m.ratio >= self.p.min_ratio
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
            measured: t,
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

    /// The two halves of the acquisition window measure the offset at two times
    /// from disjoint data: their difference informs the drift (what lets a fast
    /// drift, far outside the prior, win early).
    pub(super) fn halves_drift(&mut self, o: f64) {
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

    /// The lag range's position at the start (centred on `lag_center_s`), as the
    /// alternative of an acquisition elsewhere; `None` when the range is there.
    pub(super) fn home_alt(&self) -> Option<i64> {
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
    pub(super) fn home_lag(&self) -> i64 {
        let levels = (self.cad[1].level() - self.cad[0].level()) * 1e-9;
        let shift = (levels * self.p.fs).round();
        if shift.is_finite() {
            self.p.center_lag.saturating_sub(shift as i64)
        } else {
            self.p.center_lag
        }
    }
}
