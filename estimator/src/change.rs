//! Changes announced from outside the data: declared change points, load hints
//! (a step that may not have happened, weighed against none by the data,
//! [`Estimator::hinted`]) and the stamping-latency steps the cadences find.

use super::*;

/// A cadence step is tested against a period less (a frame dropped at it) when
/// its stream drops at least this share of frames.
pub(super) const CADENCE_AMBIGUITY_MIN: f64 = 0.002;

/// Uncertainty of that alternative step, s (the stamps measure both to a
/// fraction of a millisecond).
pub(super) const CADENCE_ALT_STD_S: f64 = 1e-3;

/// ...and when it is at least this large, s ...
pub(super) const CADENCE_CHECK_MIN_STEP_S: f64 = 0.004;

/// ...and the stream's previous cadence step is at least this long before it, ns.
pub(super) const CADENCE_ISOLATION_NS: Nanos = 5_000_000_000;

/// The step a hint announces by default (1σ), seconds: the seed article's load
/// steps were ±25 ms. `vlsyncd`'s load hints and `bench --known-steps --hinted` use it.
pub const HINT_STEP_STD_S: f64 = 0.025;

/// What a hinted change may have done to the offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Hint {
    /// Variance of the step the hint announces (about 0 when `alt` is known).
    pub(super) v_step: f64,
    /// The one step the alternative to "no step" is, s (a stream's cadence whose
    /// step could also have been a frame period less, with a frame dropped at it);
    /// `None`: a step of any size, `v_step` its variance.
    pub(super) alt: Option<f64>,
    /// Prior log-odds of the step against no step.
    pub(super) logit: f64,
}

/// The old segment at a hinted change (see [`Estimator::hint_change`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct HintPrior {
    /// Offset at the change, s, and its variance.
    pub(super) o: f64,
    pub(super) v: f64,
    /// What the hint announced.
    pub(super) hint: Hint,
    /// Tracker time of the change.
    pub(super) t: f64,
    /// Where the old segment started (grid index, tracker time).
    pub(super) start_k: i64,
    pub(super) start_t: f64,
}

impl Estimator {
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
    pub(super) fn change_at_internal(&mut self, t: Nanos, hint: Option<Hint>) {
        // floor division, as every other grid index (a negative time rounds down too)
        let k = t
            .saturating_add(self.group_delay_ns)
            .div_euclid(self.p.dt_ns);
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
    pub(super) fn cadence_step(&mut self, stream: Stream, st: cadence::CadenceStep) {
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
    pub(super) fn hinted(&mut self, m: Meas, h: HintPrior, t: f64) -> Option<Meas> {
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
}
