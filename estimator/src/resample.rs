//! Sample validation and linear resampling of one stream onto the uniform grid.
//!
//! Grid index `k` is the instant `k * dt_ns` on the stream's own clock. A grid
//! value is emitted once the first sample after it has arrived, by linear
//! interpolation between the two samples around it. A gap longer than
//! `max_gap_ns` is never interpolated across: it breaks the stream's segment.

use vlsync_common::{Nanos, RejectReason, Sample};

/// What one push produced, besides grid values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Discontinuity {
    /// Nothing special.
    None,
    /// A gap longer than the limit: the segment restarts at this sample.
    Gap,
    /// A timestamp jump larger than the reset limit: the stream restarts.
    /// Carries the raw step from the previous accepted sample, ns (signed).
    Reset(Nanos),
}

/// Validating linear resampler of one stream.
#[derive(Debug, Clone)]
pub struct Resampler {
    dt_ns: Nanos,
    max_gap_ns: Nanos,
    reset_jump_ns: Nanos,
    max_abs: f64,
    /// The previous accepted sample, at its interpolation time.
    prev: Option<Sample>,
    /// The previous accepted sample's own stamp (what validation compares with).
    prev_raw: Option<Nanos>,
    /// Exponential average of the accepted sample interval, ns (0: unknown).
    mean_interval_ns: f64,
}

impl Resampler {
    /// A resampler with grid step `dt_ns`.
    pub fn new(dt_ns: Nanos, max_gap_ns: Nanos, reset_jump_ns: Nanos, max_abs: f64) -> Self {
        Self {
            dt_ns,
            max_gap_ns,
            reset_jump_ns,
            max_abs,
            prev: None,
            prev_raw: None,
            mean_interval_ns: 0.0,
        }
    }

    /// Mean interval between accepted samples, seconds (0 when unknown).
    pub fn mean_interval_s(&self) -> f64 {
        self.mean_interval_ns * 1e-9
    }

    /// Interpolation time of the last accepted sample.
    pub fn last_time(&self) -> Option<Nanos> {
        self.prev.map(|p| p.t_ns)
    }

    /// Validates `s`; on acceptance calls `emit(k, value)` for every grid index
    /// now interpolable, in increasing order, and reports any discontinuity
    /// (reported before the values it precedes: a gap or reset means no value
    /// of this push is interpolated from the previous segment).
    pub fn push(
        &mut self,
        s: Sample,
        emit: impl FnMut(i64, f64),
    ) -> Result<Discontinuity, RejectReason> {
        let kind = self.check(s)?;
        Ok(self.accept(s, s.t_ns, kind, emit))
    }

    /// Validates `s` against the stream so far without taking it: what
    /// [`Resampler::accept`] then does with it.
    pub fn check(&self, s: Sample) -> Result<Kind, RejectReason> {
        if !s.value.is_finite() {
            return Err(RejectReason::NonFinite);
        }
        if s.value.abs() > self.max_abs {
            return Err(RejectReason::TooLarge);
        }
        let Some(p) = self.prev_raw else {
            return Ok(Kind::First);
        };
        let step = s.t_ns.saturating_sub(p);
        if step == 0 {
            return Err(RejectReason::Repeated);
        }
        if step < 0 {
            if step.saturating_neg() > self.reset_jump_ns {
                return Ok(Kind::Reset(step));
            }
            return Err(RejectReason::Backwards);
        }
        if step > self.reset_jump_ns {
            return Ok(Kind::Reset(step));
        }
        if step > self.max_gap_ns {
            return Ok(Kind::Gap);
        }
        Ok(Kind::Normal)
    }

    /// Takes `s`, checked by [`Resampler::check`] as `kind`, at time `t_ns` on the
    /// grid's clock (its own stamp, or the stamp the stream's cadence gives it,
    /// [`crate::cadence`]). An interpolation time that does not increase (it never
    /// should) restarts the stream there instead of interpolating backwards.
    pub fn accept(
        &mut self,
        s: Sample,
        t_ns: Nanos,
        kind: Kind,
        mut emit: impl FnMut(i64, f64),
    ) -> Discontinuity {
        self.prev_raw = Some(s.t_ns);
        let cur = Sample {
            t_ns,
            value: s.value,
        };
        let prev = self.prev.replace(cur);
        let p = match (kind, prev) {
            (Kind::First, _) | (_, None) => return Discontinuity::None,
            (Kind::Reset(step), _) => return Discontinuity::Reset(step),
            (Kind::Gap, _) => return Discontinuity::Gap,
            (Kind::Normal, Some(p)) => p,
        };
        let step = t_ns.saturating_sub(p.t_ns);
        if step <= 0 {
            return Discontinuity::Gap;
        }
        let a = if self.mean_interval_ns == 0.0 {
            1.0
        } else {
            0.02
        };
        self.mean_interval_ns += a * (step as f64 - self.mean_interval_ns);
        // grid indices k with p.t < k*dt <= s.t
        let first = p.t_ns.div_euclid(self.dt_ns) + 1;
        let last = t_ns.div_euclid(self.dt_ns);
        let span = step as f64;
        let mut k = first;
        while k <= last {
            let tk = k.saturating_mul(self.dt_ns);
            let w = (tk - p.t_ns) as f64 / span;
            emit(k, p.value + w * (cur.value - p.value));
            k += 1;
        }
        Discontinuity::None
    }
}

/// What [`Resampler::check`] found a valid sample to be.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The stream's first sample.
    First,
    /// The next one, within the gap limit.
    Normal,
    /// After a gap longer than the limit.
    Gap,
    /// After a jump beyond the reset limit (the raw step, ns).
    Reset(Nanos),
}

impl Kind {
    /// The same, as the stream's cadence takes it.
    pub fn cadence(self) -> crate::cadence::Kind {
        match self {
            Kind::First => crate::cadence::Kind::First,
            Kind::Normal => crate::cadence::Kind::Normal,
            Kind::Gap => crate::cadence::Kind::Gap,
            Kind::Reset(_) => crate::cadence::Kind::Reset,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const MS: i64 = 1_000_000;

    fn r() -> Resampler {
        Resampler::new(10 * MS, 500 * MS, 5_000 * MS, 1e6)
    }

    #[test]
    fn interpolates_linearly() {
        let mut rs = r();
        let mut out = Vec::new();
        rs.push(Sample::new(5 * MS, 0.0), |k, v| out.push((k, v)))
            .unwrap();
        rs.push(Sample::new(35 * MS, 3.0), |k, v| out.push((k, v)))
            .unwrap();
        assert_eq!(out.len(), 3);
        assert_eq!(out[0].0, 1);
        assert!((out[0].1 - 0.5).abs() < 1e-12);
        assert!((out[2].1 - 2.5).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_samples() {
        let mut rs = r();
        rs.push(Sample::new(100 * MS, 1.0), |_, _| {}).unwrap();
        assert_eq!(
            rs.push(Sample::new(200 * MS, f64::NAN), |_, _| {}),
            Err(RejectReason::NonFinite)
        );
        assert_eq!(
            rs.push(Sample::new(200 * MS, 1e9), |_, _| {}),
            Err(RejectReason::TooLarge)
        );
        assert_eq!(
            rs.push(Sample::new(100 * MS, 1.0), |_, _| {}),
            Err(RejectReason::Repeated)
        );
        assert_eq!(
            rs.push(Sample::new(90 * MS, 1.0), |_, _| {}),
            Err(RejectReason::Backwards)
        );
    }

    #[test]
    fn gap_and_reset() {
        let mut rs = r();
        rs.push(Sample::new(0, 1.0), |_, _| {}).unwrap();
        rs.push(Sample::new(100 * MS, 1.0), |_, _| {}).unwrap();
        let mut n = 0;
        let d = rs.push(Sample::new(900 * MS, 1.0), |_, _| n += 1).unwrap();
        assert_eq!(d, Discontinuity::Gap);
        assert_eq!(n, 0);
        let d = rs
            .push(Sample::new(90_000 * MS, 1.0), |_, _| n += 1)
            .unwrap();
        assert!(matches!(d, Discontinuity::Reset(j) if j > 0));
        let d = rs.push(Sample::new(10 * MS, 1.0), |_, _| n += 1).unwrap();
        assert!(matches!(d, Discontinuity::Reset(j) if j < 0));
        assert_eq!(n, 0);
    }

    proptest! {
        /// Any sequence of samples: emitted grid indices strictly increase within a segment,
        /// values stay within the range of the accepted inputs, and nothing panics.
        #[test]
        fn never_panics_and_stays_bounded(
            start in -(1i64 << 60)..(1i64 << 60),
            pts in proptest::collection::vec((0i64..700, -1e3f64..1e3, 0u8..30), 0..200)
        ) {
            // stamps from any start, mostly 0-700 ms apart (0: a repeat; over 500 ms: a
            // gap), with some a little back and some 10 s ahead (a reset)
            let mut rs = r();
            let mut last_k: Option<i64> = None;
            let (mut now, mut emitted) = (start, 0usize);
            let n_pts = pts.len();
            for (gap_ms, v, odd) in pts {
                now = now.saturating_add(gap_ms * MS);
                let t = match odd {
                    0 => now.saturating_sub(300 * MS),
                    1 => {
                        now = now.saturating_add(10_000 * MS);
                        now
                    }
                    _ => now,
                };
                let mut ok = true;
                let mut ks = Vec::new();
                let res = rs.push(Sample::new(t, v), |k, x| {
                    ks.push(k);
                    if !(-1e3..=1e3).contains(&x) { ok = false; }
                });
                prop_assert!(ok);
                emitted += ks.len();
                if let Ok(Discontinuity::None) = res {
                    for k in ks {
                        if let Some(lk) = last_k { prop_assert!(k > lk); }
                        last_k = Some(k);
                    }
                } else {
                    last_k = None;
                }
            }
            // the checks above ran on values: runs of close samples are the common case
            prop_assert!(emitted > 0 || n_pts < 40, "{n_pts} samples, nothing emitted");
        }
    }
}
