//! Drift from the short-window measurements: a weighted least-squares line with
//! one intercept per segment and a common slope.
//!
//! Non-overlapping short-window measurements `(t, z, var)` are accumulated: peaks
//! searched within the tracking range around the estimate, in windows where both
//! signals move (they are not gated on their innovation: gating them at 2 or 3σ
//! changed no family by more than 0.04 ms). A change point (offset step, re-lock) closes
//! the segment: its centred moments keep informing the slope, its intercept is
//! dropped, because a load step moves the offset but not the clocks' rate. Old
//! information fades with the time constant `memory_s` (oscillators drift with
//! temperature).
//!
//! Two models compete: the prior `N(0, prior_std²)` of consumer clocks (tens of
//! ppm), and a free slope for runs whose data say overwhelmingly that the rate
//! differs more (the seed article's 12 ms/s). The free slope wins when it is more
//! than 5 of its own standard deviations and 3 prior standard deviations from 0.
//! Besides the short windows, the segment's joint (offset, drift) maximum
//! ([`DriftFit::set_joint`]) measures the slope from all the segment's data at once;
//! it stands in for the segment's windows only when it makes the free slope win
//! (confirmed by the hop before), so the prior's regime is the windows' alone.
//!
//! ```
//! use vlsync_estimator::drift::DriftFit;
//! let mut f = DriftFit::new(50e-6, 900.0);
//! for i in 0..40 {
//!     let t = i as f64 * 2.0;
//!     f.add(t, 0.1 + 30e-6 * t, 1e-6);
//! }
//! let (d, var) = f.estimate();
//! assert!((d - 30e-6).abs() < 3.0 * var.sqrt() && var.sqrt() < 20e-6);
//! ```

use nalgebra::{Matrix2, Vector2};

/// Weighted moments of `(t, z)` pairs, `t` relative to the segment's first measurement.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    /// Measurements added (not faded).
    count: u32,
    /// Faded measurement count.
    n: f64,
    sw: f64,
    st: f64,
    sz: f64,
    stt: f64,
    stz: f64,
    szz: f64,
}

impl Moments {
    fn scale(&mut self, f: f64) {
        self.n *= f;
        self.sw *= f;
        self.st *= f;
        self.sz *= f;
        self.stt *= f;
        self.stz *= f;
        self.szz *= f;
    }

    /// Centred `(Stt, Stz, Szz)`.
    fn centred(&self) -> (f64, f64, f64) {
        if self.sw <= 0.0 {
            return (0.0, 0.0, 0.0);
        }
        (
            (self.stt - self.st * self.st / self.sw).max(0.0),
            self.stz - self.st * self.sz / self.sw,
            (self.szz - self.sz * self.sz / self.sw).max(0.0),
        )
    }
}

/// The largest drift the fit reports (s/s): no pair of clocks runs 10 % apart; a
/// slope the data put beyond is a fit gone wrong (a configuration far from the
/// defaults), and must not carry the offset away.
pub const MAX_DRIFT: f64 = 0.1;

/// Measurements younger than this many are pending: a change point found later
/// may still move them into the new segment.
pub const PENDING: usize = 8;

/// Joint (offset, drift) measurements of the current segment kept, newest last: a
/// change point found later takes the newest one whose data end before it.
pub const JOINT_HISTORY: usize = 20;

/// Sigmas from 0 of the joint measurement before the one that lets a free slope
/// win (at 5 sigmas) ([`DriftFit::set_joint`]).
pub const JOINT_CONFIRM_SIGMA: f64 = 3.0;

/// Sigmas from 0 at which a joint measurement lets a free slope win on its own,
/// without the hop before, when the raw window measurements' trend confirms it
/// ([`DriftFit::set_raw_trend`]).
pub const JOINT_RAW_SIGMA: f64 = 3.0;

/// Sigmas of the raw trend from 0, and the joint slope's distance from 0 in the raw
/// trend's sigmas (a slope the raw trend cannot tell from 0 is not confirmed by it)
/// ([`DriftFit::set_raw_trend`]).
pub const RAW_TREND_SIGMA: f64 = 2.0;

/// Sigmas (of both) within which the raw trend and the joint slope must agree
/// ([`DriftFit::set_raw_trend`]).
pub const RAW_AGREE_SIGMA: f64 = 1.5;

/// The drift estimator.
#[derive(Debug, Clone)]
pub struct DriftFit {
    prior_var: f64,
    memory_s: f64,
    /// Pending measurements `(t, z, var)`, oldest first.
    pending: [(f64, f64, f64); PENDING],
    n_pending: usize,
    cur: Moments,
    t0: f64,
    z0: f64,
    last_t: Option<f64>,
    /// Centred moments and counts of closed segments.
    closed_tt: f64,
    closed_tz: f64,
    closed_zz: f64,
    closed_n: f64,
    closed_segments: f64,
    /// The current segment's joint slope measurements `(t_end, drift, var)`, oldest
    /// first: each measures the slope from all the segment's data up to `t_end`.
    joint: [(f64, f64, f64); JOINT_HISTORY],
    /// Per joint measurement: whether the raw trend confirmed it.
    joint_raw: [bool; JOINT_HISTORY],
    n_joint: usize,
    /// The raw window measurements' trend `(slope, var)` at the next joint measurement.
    raw_trend: Option<(f64, f64)>,
    /// A restored slope's information `[tt, tz, zz, n]` ([`DriftFit::restore`]), added
    /// to the closed segments' when estimating; it fades as they do.
    restored: [f64; 4],
}

impl DriftFit {
    /// A fit with prior standard deviation `prior_std` (s/s) and memory `memory_s`.
    pub fn new(prior_std: f64, memory_s: f64) -> Self {
        Self {
            prior_var: (prior_std * prior_std).max(1e-30),
            memory_s: memory_s.max(1.0),
            pending: [(0.0, 0.0, 0.0); PENDING],
            n_pending: 0,
            cur: Moments::default(),
            t0: 0.0,
            z0: 0.0,
            last_t: None,
            closed_tt: 0.0,
            closed_tz: 0.0,
            closed_zz: 0.0,
            closed_n: 0.0,
            closed_segments: 0.0,
            joint: [(0.0, 0.0, 0.0); JOINT_HISTORY],
            joint_raw: [false; JOINT_HISTORY],
            n_joint: 0,
            raw_trend: None,
            restored: [0.0; 4],
        }
    }

    /// A slope measurement `drift` (variance `var`) from the current segment's data
    /// up to time `t_end` as a whole (the joint maximum over offset and drift). It
    /// does not add to the segment's short-window measurements, which hold the same
    /// data: the more informative of the two informs the slope.
    /// A hop without a joint measurement passes `var = ∞` (it breaks the run of
    /// consecutive ones a free slope needs).
    pub fn set_joint(&mut self, t_end: f64, drift: f64, var: f64) {
        if !(t_end.is_finite() && var > 0.0) {
            return;
        }
        let (drift, var) = if drift.is_finite() && var.is_finite() {
            (drift, var)
        } else {
            (0.0, f64::INFINITY)
        };
        if self.n_joint == JOINT_HISTORY {
            self.joint.copy_within(1.., 0);
            self.joint_raw.copy_within(1.., 0);
            self.n_joint -= 1;
        }
        let (k, a) = (RAW_TREND_SIGMA, RAW_AGREE_SIGMA);
        let raw = self.raw_trend.is_some_and(|(s, vs)| {
            var.is_finite()
                && vs.is_finite()
                && s * s > k * k * vs
                && drift * drift > k * k * vs
                && (s - drift).powi(2) <= a * a * (vs + var)
        });
        self.joint[self.n_joint] = (t_end, drift, var);
        self.joint_raw[self.n_joint] = raw;
        self.n_joint += 1;
    }

    /// The trend `(slope, var)` of the newest raw window measurements (peaks of
    /// overlapping windows at their centres, which a drift does not bias to first
    /// order), evidence besides the segment's surface: a joint measurement it
    /// confirms (the trend and the joint slope both [`RAW_TREND_SIGMA`] trend sigmas
    /// from 0, within [`RAW_AGREE_SIGMA`] of each other) lets a free slope win at
    /// [`JOINT_RAW_SIGMA`], without the hop before, and stands in for the segment's
    /// windows. A false joint slope (a stretch where the signatures disagree) moves
    /// the segment's surface, not the windows' peaks. Applies to the next
    /// [`DriftFit::set_joint`].
    pub fn set_raw_trend(&mut self, trend: Option<(f64, f64)>) {
        self.raw_trend = trend;
    }

    /// A slope known from before (a restored state: `drift` with variance `var`), kept
    /// as a closed segment's slope information is: it fades with the fit's memory and
    /// wins over the prior as the data do, until [`DriftFit::forget_restored`].
    pub fn restore(&mut self, drift: f64, var: f64) {
        if !(drift.is_finite() && var.is_finite() && var > 0.0) {
            return;
        }
        self.restored = [1.0 / var, drift / var, drift * drift / var, 1.0];
    }

    /// Drops the restored slope (the restored lock was found wrong: the state came
    /// from another setup, and its drift is no more to be trusted than its offset).
    pub fn forget_restored(&mut self) {
        self.restored = [0.0; 4];
    }

    /// Forgets everything.
    pub fn reset(&mut self) {
        *self = Self::new(self.prior_var.sqrt(), self.memory_s);
    }

    /// Adds a measurement `z` (s) of the offset at time `t` (s) with variance `var`.
    /// It stays pending (see [`DriftFit::change_at`]) until [`PENDING`] newer ones came.
    pub fn add(&mut self, t: f64, z: f64, var: f64) {
        if !(t.is_finite() && z.is_finite() && var.is_finite() && var > 0.0) {
            return;
        }
        if self.n_pending == PENDING {
            let (t0, z0, v0) = self.pending[0];
            self.pending.copy_within(1.., 0);
            self.n_pending -= 1;
            self.commit(t0, z0, v0);
        }
        self.pending[self.n_pending] = (t, z, var);
        self.n_pending += 1;
    }

    /// The offset changed at time `t` (a step): pending measurements before it stay
    /// in the current segment, which closes; those after it open the next one.
    pub fn change_at(&mut self, t: f64) {
        let n = self.n_pending;
        let split = self.pending[..n].iter().take_while(|p| p.0 < t).count();
        for i in 0..split {
            let (a, b, c) = self.pending[i];
            self.commit(a, b, c);
        }
        // the newest joint measurement whose data end before the change
        let j = (0..self.n_joint)
            .rev()
            .find(|&i| self.joint[i].0 <= t)
            .and_then(|i| self.free_joint(i));
        self.n_joint = 0;
        self.close_committed(j);
        self.pending.copy_within(split..n, 0);
        self.n_pending = n - split;
    }

    fn commit(&mut self, t: f64, z: f64, var: f64) {
        if let Some(last) = self.last_t {
            let f = (-(t - last).max(0.0) / self.memory_s).exp();
            self.cur.scale(f);
            self.closed_tt *= f;
            self.closed_tz *= f;
            self.closed_zz *= f;
            self.closed_n *= f;
            self.closed_segments *= f;
            for r in &mut self.restored {
                *r *= f;
            }
        }
        self.last_t = Some(t);
        if self.cur.count == 0 {
            self.t0 = t;
            self.z0 = z;
        }
        let (dt, dz, w) = (t - self.t0, z - self.z0, 1.0 / var);
        let m = &mut self.cur;
        m.count += 1;
        m.n += 1.0;
        m.sw += w;
        m.st += w * dt;
        m.sz += w * dz;
        m.stt += w * dt * dt;
        m.stz += w * dt * dz;
        m.szz += w * dz * dz;
    }

    /// Closes the current segment (re-lock) with every pending measurement: its
    /// slope information stays, its intercept goes.
    pub fn close_segment(&mut self) {
        for i in 0..self.n_pending {
            let (a, b, c) = self.pending[i];
            self.commit(a, b, c);
        }
        self.n_pending = 0;
        let j = self.n_joint.checked_sub(1).and_then(|i| self.free_joint(i));
        self.n_joint = 0;
        self.close_committed(j);
    }

    /// Joint measurement `i` if it makes a free slope win on its own (as
    /// [`DriftFit::estimate`] lets one win), and the one before it, from the hop
    /// before, agrees and is at least [`JOINT_CONFIRM_SIGMA`] from 0: a joint measurement decides between the prior and a
    /// free slope, never moves a slope the prior rules, and one hop's surface (a
    /// stretch where the signatures disagree) does not decide alone.
    fn free_joint(&self, i: usize) -> Option<((f64, f64, f64), bool)> {
        let free = |(_, d, v): (f64, f64, f64), k: f64| {
            v.is_finite() && d * d > k * k * v && d * d > 9.0 * self.prior_var
        };
        let j = self.joint[i];
        if self.joint_raw[i] && free(j, JOINT_RAW_SIGMA) {
            return Some((j, true));
        }
        let p = self.joint[i.checked_sub(1)?];
        (free(j, 5.0)
            && free(p, JOINT_CONFIRM_SIGMA)
            && (j.1 - p.1).abs() <= 3.0 * (j.2 + p.2).sqrt())
        .then_some((j, false))
    }

    /// Closes the committed segment: its slope information (its short windows', or
    /// the joint measurement `joint` of it when that informs the slope more) stays.
    fn close_committed(&mut self, joint: Option<((f64, f64, f64), bool)>) {
        let (tt, _, _) = self.cur.centred();
        match joint {
            Some(((_, d, v), forced)) if forced || 1.0 / v > tt => {
                self.closed_tt += 1.0 / v;
                self.closed_tz += d / v;
                self.closed_zz += d * d / v;
                self.closed_n += 1.0;
            }
            _ if self.cur.count >= 2 => {
                let (tt, tz, zz) = self.cur.centred();
                self.closed_tt += tt;
                self.closed_tz += tz;
                self.closed_zz += zz;
                self.closed_n += self.cur.n;
                self.closed_segments += 1.0;
            }
            _ => {}
        }
        self.cur = Moments::default();
    }

    /// `(drift, variance)` in s/s and (s/s)², pending measurements included.
    pub fn estimate(&self) -> (f64, f64) {
        let mut all = self.clone();
        let [tt, tz, zz, n] = self.restored;
        all.closed_tt += tt;
        all.closed_tz += tz;
        all.closed_zz += zz;
        all.closed_n += n;
        for i in 0..self.n_pending {
            let (a, b, c) = self.pending[i];
            all.commit(a, b, c);
        }
        // the current segment's joint measurement, when it informs the slope more
        // than its short windows, stands in for them (their intercept does not
        // inform the slope)
        let mut k = 5.0;
        if let Some(j) = self.n_joint.checked_sub(1).and_then(|i| self.free_joint(i)) {
            if j.1 || 1.0 / j.0 .2 > all.cur.centred().0 {
                all.close_committed(Some(j));
                if j.1 {
                    k = JOINT_RAW_SIGMA;
                }
            }
        }
        all.estimate_committed(k)
    }

    fn estimate_committed(&self, k: f64) -> (f64, f64) {
        // information on [intercept of the current segment, slope]; closed segments
        // add centred slope information
        let m = &self.cur;
        let h = Matrix2::new(m.sw, m.st, m.st, m.stt + self.closed_tt);
        let b = Vector2::new(m.sz, m.stz + self.closed_tz);
        let (tt, tz, zz) = {
            let (a, b_, c) = m.centred();
            (a + self.closed_tt, b_ + self.closed_tz, c + self.closed_zz)
        };
        let segments = self.closed_segments + if m.n > 0.0 { 1.0 } else { 0.0 };
        let dof = self.closed_n + m.n - segments - 1.0;
        // posterior of the slope with data information divided by `s` and `extra`
        // added as prior information on the slope
        let posterior = |extra: f64, s: f64| -> Option<(f64, f64)> {
            let (hp, bb) = if m.sw > 0.0 {
                (h / s + Matrix2::new(0.0, 0.0, 0.0, extra), b / s)
            } else {
                (
                    Matrix2::new(1.0, 0.0, 0.0, tt / s + extra),
                    Vector2::new(0.0, tz / s),
                )
            };
            let inv = hp.try_inverse()?;
            let x = inv * bb;
            Some((x[1], inv[(1, 1)]))
        };
        let with_prior =
            |s: f64| posterior(1.0 / self.prior_var, s).unwrap_or((0.0, self.prior_var));
        if tt <= 0.0 {
            return with_prior(1.0);
        }
        let Some((d, var)) = posterior(0.0, 1.0) else {
            return with_prior(1.0);
        };
        // measurements that scatter more than their variances say widen the fit
        let scale = if dof >= 2.0 {
            let rss = (zz - 2.0 * d * tz + d * d * tt).max(0.0);
            (rss / dof).max(1.0)
        } else {
            1.0
        };
        let var = var * scale;
        let (d, var) = if d * d > k * k * var && d * d > 9.0 * self.prior_var {
            (d, var)
        } else {
            with_prior(scale)
        };
        // a capped slope is as uncertain as the cap is far from the fit
        let capped = d.clamp(-MAX_DRIFT, MAX_DRIFT);
        (capped, var.max((d - capped).powi(2)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slope_survives_a_step_between_segments() {
        let mut f = DriftFit::new(50e-6, 900.0);
        for i in 0..20 {
            let t = i as f64 * 2.0;
            f.add(t, 0.2 + 40e-6 * t, 4e-6);
        }
        f.close_segment();
        for i in 20..40 {
            let t = i as f64 * 2.0;
            f.add(t, 0.225 + 40e-6 * t, 4e-6);
        }
        let (d, v) = f.estimate();
        assert!((d - 40e-6).abs() < 10e-6, "{d} ± {}", v.sqrt());
    }

    #[test]
    fn large_drift_wins_over_the_prior() {
        let mut f = DriftFit::new(50e-6, 900.0);
        for i in 0..6 {
            let t = i as f64 * 2.0;
            f.add(t, 0.18 + 0.012 * t, 1e-5);
        }
        let (d, _) = f.estimate();
        assert!((d - 0.012).abs() < 1e-4, "{d}");
    }

    #[test]
    fn two_measurements_far_apart_still_inform_the_slope() {
        // faded weights must not drop a two-point segment (regression: the faded count
        // fell below 2 and the segment was discarded)
        let mut f = DriftFit::new(50e-6, 900.0);
        f.add(3.75, 0.1936, 5e-5);
        f.add(6.25, 0.2351, 4.1e-5);
        f.close_segment();
        let (d, v) = f.estimate();
        // the prior (50 ppm) still dominates two points 2.5 s apart, but they count
        assert!(v < 50e-6 * 50e-6 && d > 0.0, "{d} ± {}", v.sqrt());
    }

    /// A slope beyond any pair of clocks (4 s/s, what a configuration far from the
    /// defaults once produced) is capped, so the offset cannot run away with it.
    #[test]
    fn a_slope_beyond_max_drift_is_not_taken() {
        let mut f = DriftFit::new(50e-6, 900.0);
        for i in 0..20 {
            let t = i as f64 * 2.0;
            f.add(t, 4.0 * t, 1e-6);
        }
        let (d, _) = f.estimate();
        assert!(d.abs() <= MAX_DRIFT, "{d}");
    }

    /// A joint slope measurement decides for a free slope only when the one of the
    /// hop before agrees; a hop without one breaks the run; a change point keeps the
    /// newest decisive one whose data end before it.
    #[test]
    fn a_joint_slope_wins_when_the_hop_before_confirms_it() {
        let mut f = DriftFit::new(50e-6, 900.0);
        f.set_joint(5.0, 0.012, 4e-6);
        assert!(f.estimate().0.abs() < 1e-4, "one hop decided");
        f.set_joint(5.5, f64::NAN, f64::INFINITY);
        f.set_joint(6.0, 0.012, 4e-6);
        assert!(f.estimate().0.abs() < 1e-4, "a gap did not break the run");
        f.set_joint(6.5, 0.0118, 3e-6);
        let (d, v) = f.estimate();
        assert!(
            (d - 0.0118).abs() < 1e-9 && (v - 3e-6).abs() < 1e-12,
            "{d} {v}"
        );
        // a change after both: the segment's slope information stays
        f.set_joint(7.0, 0.0119, 2.5e-6);
        f.change_at(6.8);
        let (d, _) = f.estimate();
        assert!((d - 0.0118).abs() < 1e-9, "{d}");
        // a joint measurement far from the one before does not decide
        let mut g = DriftFit::new(50e-6, 900.0);
        g.set_joint(5.0, -0.012, 4e-6);
        g.set_joint(5.5, 0.012, 4e-6);
        assert!(g.estimate().0.abs() < 1e-4);
    }

    /// A joint slope at 3-5σ wins on its own when the raw windows' trend confirms it,
    /// not when the trend stays near 0 or cannot tell it from 0.
    #[test]
    fn a_joint_slope_the_raw_trend_confirms_wins_at_once() {
        // 0.012 ± 0.0033 s/s: 3.6σ, alone not enough
        let mut f = DriftFit::new(50e-6, 900.0);
        f.set_joint(5.0, 0.012, 1.1e-5);
        assert!(f.estimate().0.abs() < 1e-4);
        // confirmed by a trend of 0.010 ± 0.004 s/s
        f.set_raw_trend(Some((0.010, 1.6e-5)));
        f.set_joint(5.5, 0.012, 1.1e-5);
        let (d, v) = f.estimate();
        assert!(
            (d - 0.012).abs() < 1e-9 && (v - 1.1e-5).abs() < 1e-12,
            "{d} {v}"
        );
        // a trend near 0 (the false 50 ms/s slope of a heavy-noise run at its lock)
        let mut g = DriftFit::new(50e-6, 900.0);
        g.set_raw_trend(Some((0.0098, 1.3e-4)));
        g.set_joint(5.0, 0.05, 1.3e-4);
        assert!(g.estimate().0.abs() < 1e-4);
        // a trend of the same sign that cannot tell a small slope from 0
        let mut h = DriftFit::new(50e-6, 900.0);
        h.set_raw_trend(Some((0.008, 1.6e-5)));
        h.set_joint(5.0, 0.0005, 1.6e-8);
        assert!(h.estimate().0.abs() < 1e-4);
    }

    #[test]
    fn no_data_gives_the_prior() {
        let f = DriftFit::new(50e-6, 900.0);
        let (d, v) = f.estimate();
        assert_eq!(d, 0.0);
        assert!((v.sqrt() - 50e-6).abs() < 1e-12);
    }

    #[test]
    fn noise_is_shrunk_towards_zero() {
        let mut f = DriftFit::new(50e-6, 900.0);
        // pure noise of ±5 ms over 20 s: the prior keeps the slope small
        for (i, z) in [0.005, -0.005, 0.004, -0.003, 0.002, -0.005]
            .iter()
            .enumerate()
        {
            f.add(i as f64 * 4.0, *z, 2.5e-5);
        }
        let (d, _) = f.estimate();
        assert!(d.abs() < 50e-6, "{d}");
    }
}
