//! The segment: a robust, drift-compensated combination of stored blocks.
//!
//! Once locked, the estimator measures the offset on every block since the last
//! change point (lock, step, re-acquisition), up to the store's length, instead
//! of averaging the peaks of short windows: summing correlation sums keeps the
//! information of a long window without the heavy tails of many short-window
//! peaks. Two refinements make the long window safe:
//!
//! * **Drift compensation.** Block `b`, centred `k_b` grid steps after the
//!   reference index `k_ref`, is read at lag slot `s + d·(k_b - k_ref)` (linear
//!   interpolation between slots), so with the right drift `d` every block peaks
//!   at the slot of the offset *at the reference time*.
//! * **Robust block weights** (iteratively re-weighted). At the current peak,
//!   the camera signal is regressed on the LiDAR signal over the whole segment;
//!   a block whose residual energy per sample is far above the segment's median
//!   (the two signatures disagree there: rotation seen by the camera only, an
//!   obstacle crossing the LiDAR's bearing window, a stretch after an offset
//!   step) gets weight `c·median / residual` instead of 1.
//!
//! All sums are computed into preallocated buffers: nothing allocates.

use crate::correlator::{Correlator, Sums};

/// Residual energy, relative to the segment median, above which a block's weight falls.
pub const ROBUST_C: f64 = 3.0;

/// Working buffers for combining blocks.
#[derive(Debug, Clone)]
pub struct Segment {
    /// The combined sums (slots `lo..=hi` of the last [`Segment::combine`] are valid).
    pub sums: Sums,
    /// Weight per stored block (by [`Correlator::phys`] position, so weights stay
    /// with their blocks as the store turns).
    w: Vec<f64>,
    /// Residual energy per sample per stored block.
    e: Vec<f64>,
    sort: Vec<f64>,
}

/// Which blocks to combine and how.
#[derive(Debug, Clone, Copy)]
pub struct Span {
    /// First stored block (inclusive).
    pub first: usize,
    /// Last stored block (inclusive).
    pub last: usize,
    /// Drift in lag slots per grid step (= drift in s/s).
    pub drift: f64,
    /// Reference grid index (fractional) the combination aligns to.
    pub k_ref: f64,
    /// Lag slots to fill.
    pub lo: usize,
    /// Last lag slot to fill (inclusive).
    pub hi: usize,
}

impl Segment {
    /// Buffers for `n_lags` slots and `cap_blocks` stored blocks.
    pub fn new(n_lags: usize, cap_blocks: usize) -> Self {
        Self {
            sums: Sums::new(n_lags),
            w: vec![1.0; cap_blocks],
            e: vec![0.0; cap_blocks],
            sort: vec![0.0; cap_blocks],
        }
    }

    /// Sets every weight of `span` to 1.
    pub fn reset_weights(&mut self, corr: &Correlator, span: &Span) {
        for i in span.first..=span.last.min(corr.count().saturating_sub(1)) {
            self.w[corr.phys(i)] = 1.0;
        }
    }

    /// Weight of stored block `i`.
    pub fn weight(&self, corr: &Correlator, i: usize) -> f64 {
        self.w[corr.phys(i)]
    }

    /// Sets the weight of stored block `i`.
    pub fn set_weight(&mut self, corr: &Correlator, i: usize, w: f64) {
        self.w[corr.phys(i)] = w;
    }

    /// Shift of block `b` (slots) and whether slots `lo..=hi` shifted by it stay
    /// within the slots the block holds (with one slot to interpolate).
    fn shift(b: &Sums, span: &Span) -> Option<(isize, f64)> {
        let (a, z) = (b.lo, b.hi);
        let kb = 0.5 * (b.first_k + b.last_k) as f64;
        let d = span.drift * (kb - span.k_ref);
        if !d.is_finite() {
            return None;
        }
        let i = d.floor();
        let f = d - i;
        let i = i as isize;
        let lo = span.lo as isize + i;
        let hi = span.hi as isize + i + isize::from(f > 0.0);
        (lo >= a as isize && hi <= z as isize).then_some((i, f))
    }

    /// Combines the blocks of `span` with the current weights into [`Segment::sums`].
    /// Returns the weighted number of pairs.
    pub fn combine(&mut self, corr: &Correlator, span: &Span) -> f64 {
        let s = &mut self.sums;
        s.n = 0.0;
        s.sx = 0.0;
        s.sxx = 0.0;
        for v in [&mut s.xy, &mut s.y, &mut s.yy] {
            v[span.lo..=span.hi].iter_mut().for_each(|x| *x = 0.0);
        }
        let mut first = true;
        for i in span.first..=span.last.min(corr.count().saturating_sub(1)) {
            let w = self.w[corr.phys(i)];
            let b = corr.block(i);
            if w <= 0.0 || b.n <= 0.0 {
                continue;
            }
            let Some((sh, f)) = Self::shift(b, span) else {
                continue;
            };
            if first {
                s.first_k = b.first_k;
                first = false;
            }
            s.last_k = b.last_k;
            s.n += w * b.n;
            s.sx += w * b.sx;
            s.sxx += w * b.sxx;
            let src0 = (span.lo as isize + sh) as usize;
            let len = span.hi - span.lo + 1;
            for (dst, src) in [(&mut s.xy, &b.xy), (&mut s.y, &b.y), (&mut s.yy, &b.yy)] {
                let d = &mut dst[span.lo..=span.hi];
                if f == 0.0 {
                    for (o, &v) in d.iter_mut().zip(&src[src0..src0 + len]) {
                        *o += w * v;
                    }
                } else {
                    let (wa, wb) = (w * (1.0 - f), w * f);
                    let (a, b) = (&src[src0..src0 + len], &src[src0 + 1..src0 + len + 1]);
                    for ((o, &x), &y) in d.iter_mut().zip(a).zip(b) {
                        *o += wa * x + wb * y;
                    }
                }
            }
        }
        s.n
    }
}

/// Linear interpolation of slot array `v` (holding slots `a..=z`) at fractional slot `x`.
fn at(v: &[f64], a: usize, z: usize, x: f64) -> Option<f64> {
    let i = x.floor();
    if i < a as f64 || i + 1.0 > z as f64 {
        return None;
    }
    let (i, f) = (i as usize, x - i);
    Some(v[i] * (1.0 - f) + v[i + 1] * f)
}

impl Segment {
    /// The regression `y ≈ α x + β` of camera on LiDAR values in the last
    /// combination at fractional slot `slot` of `span`: `(α, β)`.
    pub fn regression(&self, span: &Span, slot: f64) -> Option<(f64, f64)> {
        let s = &self.sums;
        if s.n < 3.0 || !slot.is_finite() {
            return None;
        }
        let lo = span.lo as f64;
        let p = slot.clamp(lo, (span.hi as f64 - 1.0).max(lo));
        let sxy = at(&s.xy, span.lo, span.hi, p)?;
        let sy = at(&s.y, span.lo, span.hi, p)?;
        let n = s.n;
        let (mx, my) = (s.sx / n, sy / n);
        let vx = s.sxx / n - mx * mx;
        if vx <= 0.0 || !vx.is_finite() {
            return None;
        }
        let alpha = (sxy / n - mx * my) / vx;
        Some((alpha, my - alpha * mx))
    }

    /// Re-weights the blocks of `span` from their residuals against the regression
    /// `(alpha, beta)` at fractional slot `slot`. Returns the number of down-weighted blocks.
    pub fn reweight(
        &mut self,
        corr: &Correlator,
        span: &Span,
        slot: f64,
        (alpha, beta): (f64, f64),
    ) -> usize {
        if !(slot.is_finite() && alpha.is_finite() && beta.is_finite()) {
            return 0;
        }
        let p = slot;
        let mut m = 0;
        for i in span.first..=span.last.min(corr.count().saturating_sub(1)) {
            let b = corr.block(i);
            let pi = corr.phys(i);
            self.e[pi] = f64::NAN;
            if b.n <= 0.0 || self.w[pi] <= 0.0 {
                continue;
            }
            let kb = 0.5 * (b.first_k + b.last_k) as f64;
            let x = p + span.drift * (kb - span.k_ref);
            let (Some(bxy), Some(by), Some(byy)) = (
                at(&b.xy, b.lo, b.hi, x),
                at(&b.y, b.lo, b.hi, x),
                at(&b.yy, b.lo, b.hi, x),
            ) else {
                continue;
            };
            let en = byy - 2.0 * alpha * bxy - 2.0 * beta * by
                + alpha * alpha * b.sxx
                + 2.0 * alpha * beta * b.sx
                + b.n * beta * beta;
            let e = (en / b.n).max(0.0);
            self.e[pi] = e;
            self.sort[m] = e;
            m += 1;
        }
        if m < 3 {
            return 0;
        }
        let mid = m / 2;
        let (_, med, _) = self.sort[..m].select_nth_unstable_by(mid, f64::total_cmp);
        let thr = ROBUST_C * *med;
        if thr <= 0.0 || !thr.is_finite() {
            return 0;
        }
        let mut down = 0;
        for i in span.first..=span.last.min(corr.count().saturating_sub(1)) {
            let pi = corr.phys(i);
            let e = self.e[pi];
            if e.is_finite() && self.w[pi] > 0.0 {
                self.w[pi] = if e > thr { thr / e } else { 1.0 };
                if e > thr {
                    down += 1;
                }
            }
        }
        down
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::correlator::Step;
    use crate::peak;

    fn sig(k: f64) -> f64 {
        (k * 0.031).sin() + 0.6 * (k * 0.0113).cos() + 0.3 * (k * 0.071).sin()
    }

    /// Blocks of `L[k] = C[k - lag(k)]` with a lag that drifts by `drift` slots per
    /// grid step; `mismatch` adds a camera-only bump to blocks in that range.
    fn store(drift: f64, mismatch: Option<(i64, i64)>) -> Correlator {
        let mut c = Correlator::new(61, -30, 50, 4, 40, 8192);
        for k in 0..2000i64 {
            let lag = 5.0 + drift * k as f64;
            let mut y = sig(k as f64);
            if let Some((a, b)) = mismatch {
                if (a..b).contains(&k) {
                    y += 3.0;
                }
            }
            c.push_cam(k, y);
            c.push_lidar(k, sig(k as f64 - lag));
            while c.step() != Step::Idle {}
        }
        c
    }

    fn peak_slot(seg: &mut Segment, c: &Correlator, span: &Span) -> f64 {
        seg.combine(c, span);
        let mut scratch = vec![0.0; 61];
        peak::find(&seg.sums, span.lo, span.hi, 1.0, &mut scratch)
            .unwrap()
            .slot
    }

    #[test]
    fn drift_compensation_aligns_blocks_to_the_reference_time() {
        let drift = 0.004; // slots per grid step: 8 slots over the stored 2000 steps
        let c = store(drift, None);
        let n = c.count();
        let k_ref = c.block(n - 1).last_k as f64;
        let mut seg = Segment::new(61, 40);
        let span = Span {
            first: 0,
            last: n - 1,
            drift,
            k_ref,
            lo: 20,
            hi: 55,
        };
        seg.reset_weights(&c, &span);
        let slot = peak_slot(&mut seg, &c, &span);
        // slot of lag 5 + drift·k_ref, relative to lag0 = -30
        let want = 5.0 + drift * k_ref + 30.0;
        assert!((slot - want).abs() < 0.3, "{slot} vs {want}");
        // without compensation the peak is the segment's average lag, far off
        let flat = Span { drift: 0.0, ..span };
        let slot0 = peak_slot(&mut seg, &c, &flat);
        assert!((slot0 - want).abs() > 2.0, "{slot0}");
    }

    #[test]
    fn mismatching_blocks_are_down_weighted() {
        let c = store(0.0, Some((1200, 1350)));
        let n = c.count();
        let mut seg = Segment::new(61, 40);
        let span = Span {
            first: 0,
            last: n - 1,
            drift: 0.0,
            k_ref: 0.0,
            lo: 25,
            hi: 45,
        };
        seg.reset_weights(&c, &span);
        for _ in 0..2 {
            let slot = peak_slot(&mut seg, &c, &span);
            let fit = seg.regression(&span, slot).unwrap();
            seg.reweight(&c, &span, slot, fit);
        }
        for i in 0..n {
            let b = c.block(i);
            // LiDAR k pairs with camera k - 5 at the peak
            let bumped = b.last_k - 5 >= 1200 && b.first_k - 5 < 1350;
            let w = seg.weight(&c, i);
            if bumped {
                assert!(
                    w < 0.2,
                    "block {i} ({}..{}) weight {w}",
                    b.first_k,
                    b.last_k
                );
            } else {
                assert!(w > 0.8, "block {i} weight {w}");
            }
        }
        let slot = peak_slot(&mut seg, &c, &span);
        assert!((slot - 35.0).abs() < 0.05, "{slot}");
    }
}
