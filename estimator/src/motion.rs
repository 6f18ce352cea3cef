//! The motion gate: whether both signals move enough, against the upper quartile
//! of their recent window variances, for a window to measure anything.

use super::*;

/// Hops of acquisition-window variances behind the motion gate's reference (120 s at
/// the default hop).
pub(super) const MOTION_HISTORY: usize = 240;

/// The last [`MOTION_HISTORY`] values of one signal's window variance.
#[derive(Debug, Clone)]
pub(super) struct History {
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
    pub(super) fn push(&mut self, v: f64) {
        if v.is_finite() {
            self.buf[self.pos] = v;
            self.pos = (self.pos + 1) % MOTION_HISTORY;
            self.n = (self.n + 1).min(MOTION_HISTORY);
        }
    }

    /// The 75th percentile of the values held (0 when empty).
    pub(super) fn upper_quartile(&mut self) -> f64 {
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

impl Estimator {
    /// Motion gate on the acquisition window: both signals vary at least
    /// `min_motion_ratio` of their typical variance, the upper quartile of the
    /// acquisition windows of the last [`MOTION_HISTORY`] hops. A quantile rather than
    /// a decaying maximum: a few seconds of one signature spiking (a turn sweeping the
    /// LiDAR's window across a corner) must not make ordinary motion look like none.
    pub(super) fn motion_ok(&mut self, update_ref: bool) -> bool {
        let Some(v) = self.window_vars() else {
            return false;
        };
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

    /// The acquisition window's LiDAR and camera variances, at the middle of the
    /// active slots it holds (all of them but after a lag shift); `None` for a window
    /// whose blocks share none, which cannot tell.
    fn window_vars(&self) -> Option<[f64; 2]> {
        let w = self.corr.acq();
        let mid = self.corr.n_lags() / 2;
        let (a, b) = self.corr.active();
        if w.lo > w.hi {
            return None;
        }
        let slot = mid.clamp(a, b).clamp(w.lo, w.hi);
        Some([w.var_y(slot), w.var_x()])
    }

    /// Whether the acquisition window moves as the signatures did while the last lock
    /// tracked with motion (both at least `min_motion_ratio` of that lock's motion
    /// references, [`Estimator::lock_motion`]); true before any such lock. After
    /// minutes of a park the motion gate's own reference is the park's noise, which
    /// then passes it: that noise must not move the search between its ranges.
    pub(super) fn moving_as_locked(&self) -> bool {
        let Some(refs) = self.lock_motion else {
            return true;
        };
        self.window_vars().is_some_and(|v| {
            v.iter()
                .zip(refs)
                .all(|(&vi, r)| vi > 0.0 && vi >= self.p.min_motion * r)
        })
    }

    /// The motion references: the upper quartiles of the acquisition windows'
    /// camera and LiDAR variances over the last [`MOTION_HISTORY`] hops.
    pub(super) fn motion_refs(&mut self) -> [f64; 2] {
        let [c, l] = &mut self.motion_hist;
        [c.upper_quartile(), l.upper_quartile()]
    }

    /// Whether the short-window combination in `self.seg.sums` moves as the motion
    /// gate asks (both signals at least `min_motion_ratio` of `refs`) at the lag of
    /// offset `z`. A window at the end of motion (the robot slowing to a stop) can
    /// show a confident peak in what is only noise: it must not measure a step.
    pub(super) fn seg_moving(&self, z: f64, refs: [f64; 2]) -> bool {
        let sums = &self.seg.sums;
        let last = self.corr.n_lags().saturating_sub(1);
        let slot = (z * self.p.fs - self.corr.lag0() as f64).round();
        let slot = (slot.max(0.0) as usize).min(last);
        let v = [sums.var_y(slot), sums.var_x()];
        v.iter()
            .zip(refs)
            .all(|(&vi, r)| vi > 0.0 && vi >= self.p.min_motion * r)
    }
}
