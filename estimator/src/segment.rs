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
//! The hop's combination is mostly **prepared** before the hop, on the samples
//! between hops ([`Segment::prepare_residuals`], [`Segment::prepare_sums`]): the
//! blocks already complete are re-weighted and summed for the inputs the hop will
//! have, and the hop only adds its new block ([`Segment::finish_prepared`]). That
//! keeps the sample that completes a block, whose estimate waits for it, cheap.
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
    /// The weights as [`Segment::snapshot_weights`] kept them, for combinations
    /// staged over later samples while the live weights move
    /// ([`Segment::combine_snapshot`]).
    w_snap: Vec<f64>,
    /// The next hop's joint maximum's first three hypotheses, prepared before its
    /// block completes ([`Segment::prepare_joint`]).
    joint: [Sums; 3],
    /// Residual energy per sample per stored block.
    e: Vec<f64>,
    sort: Vec<f64>,
    /// The next hop's combination, prepared before its block completes.
    prep: Prepared,
}

/// What [`Segment::prepare_residuals`] and [`Segment::prepare_sums`] computed for the
/// next hop, and the inputs they assumed ([`PrepKey`]).
///
/// The hop's re-weighting sets each block's weight to 1 or to `thr / e` (its
/// residual energy `e` against the threshold `thr`, a multiple of their median),
/// so its combination is `Σ_one B + thr · Σ_down B / e`, plus the new block. Both
/// sums, and the residual energies, need only blocks that are already complete:
/// they are prepared in stages on the samples before the hop, with the partition
/// from the median without the new block. The hop adds the new block's residual,
/// takes the median of all, moves the few blocks that changed side of the
/// threshold, and adds the new block: the same weights and the same combination as
/// [`Segment::reweight`] then [`Segment::combine`], summed in another order.
#[derive(Debug, Clone)]
struct Prepared {
    key: Option<PrepKey>,
    /// The blocks and slots prepared (the hop's segment without its new block).
    span: Span,
    /// Residual energy per stored block (by physical position; NaN: the block's
    /// weight stays as it is), of the blocks of the key.
    e: Vec<f64>,
    /// Whether the block is in `down` (else in `one`, with its weight when `e` is NaN).
    down: Vec<bool>,
    /// Blocks at weight 1 (or their fixed weight), and down-weighted blocks divided
    /// by their residual energy, over the key's slots.
    one: Sums,
    down_sums: Sums,
    /// `(Σ w·n, Σ w·n·k_centre)` of `one` and (divided by `e`) of `down`: the
    /// segment's information-weighted centre.
    lever_one: (f64, f64),
    lever_down: (f64, f64),
    /// Blocks summed so far (from the span's first).
    next: usize,
    /// Every stage done.
    ready: bool,
}

impl Prepared {
    /// Adds `w` times block `b` to the down-weighted part (`down`) or the other,
    /// with its lever sums; its lag sums only with a `shift` (a block that holds
    /// the slots and carries weight).
    fn add(&mut self, down: bool, b: &Sums, w: f64, shift: Option<(isize, f64)>) {
        let (sums, lever) = if down {
            (&mut self.down_sums, &mut self.lever_down)
        } else {
            (&mut self.one, &mut self.lever_one)
        };
        let kc = 0.5 * (b.first_k + b.last_k) as f64;
        lever.0 += w * b.n;
        lever.1 += w * b.n * kc;
        if let Some(sh) = shift {
            accumulate(sums, b, w, &self.span, sh);
        }
    }
}

/// Blocks one call of [`Segment::prepare_sums`] sums at most: a full 60 s segment
/// takes three samples, each costing about what one stage of the step test does.
pub const PREP_BLOCKS: usize = 40;

/// The inputs a prepared combination assumed; the hop uses it only if its own
/// inputs are these, else it combines directly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PrepKey {
    /// [`Correlator::epoch`] when prepared.
    pub epoch: u64,
    /// First grid index of the segment's first block.
    pub first_k: i64,
    /// Last grid index of the newest block before the hop's.
    pub last_k: i64,
    /// Blocks prepared (the segment's before the hop's).
    pub blocks: usize,
    /// Drift, slots per grid step (as in [`Span`]).
    pub drift: f64,
    /// Reference grid index (as in [`Span`]).
    pub k_ref: f64,
    /// First lag slot prepared.
    pub lo: usize,
    /// Last lag slot prepared (inclusive).
    pub hi: usize,
    /// The last fit the hop re-weights from: peak slot and regression `(α, β)`
    /// (`None`: no re-weighting, the weights stay).
    pub fit: Option<(f64, (f64, f64))>,
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
            w_snap: vec![1.0; cap_blocks],
            joint: [Sums::new(n_lags), Sums::new(n_lags), Sums::new(n_lags)],
            e: vec![0.0; cap_blocks],
            sort: vec![0.0; cap_blocks],
            prep: Prepared {
                key: None,
                span: Span {
                    first: 0,
                    last: 0,
                    drift: 0.0,
                    k_ref: 0.0,
                    lo: 0,
                    hi: 0,
                },
                e: vec![f64::NAN; cap_blocks],
                down: vec![false; cap_blocks],
                one: Sums::new(n_lags),
                down_sums: Sums::new(n_lags),
                lever_one: (0.0, 0.0),
                lever_down: (0.0, 0.0),
                next: 0,
                ready: false,
            },
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
        combine_into(&mut self.sums, &self.w, corr, span)
    }

    /// Keeps the current weights for [`Segment::combine_snapshot`] (valid until a
    /// block completes: the weights are by stored position).
    pub fn snapshot_weights(&mut self) {
        self.w_snap.copy_from_slice(&self.w);
    }

    /// Combines the blocks of `span` with the current weights into joint hypothesis
    /// `j`'s sums, as [`Segment::combine`] does: the next hop adds its new block
    /// ([`Segment::finish_joint`]). Returns the weighted number of pairs.
    pub fn prepare_joint(&mut self, corr: &Correlator, span: &Span, j: usize) -> f64 {
        combine_into(&mut self.joint[j], &self.w, corr, span)
    }

    /// Adds stored block `i` (with its current weight) to joint hypothesis `j`'s
    /// prepared sums, shifted as `span` asks: what [`Segment::combine`] of the span
    /// through `i` would hold, summed in the same order. Returns those sums.
    pub fn finish_joint(&mut self, corr: &Correlator, span: &Span, j: usize, i: usize) -> &Sums {
        let s = &mut self.joint[j];
        let w = self.w[corr.phys(i)];
        let b = corr.block(i);
        if w > 0.0 && b.n > 0.0 {
            if let Some(sh) = Self::shift(b, span) {
                if s.n == 0.0 {
                    s.first_k = b.first_k;
                }
                s.last_k = b.last_k;
                accumulate(s, b, w, span, sh);
            }
        }
        &self.joint[j]
    }

    /// [`Segment::combine`] with the weights [`Segment::snapshot_weights`] kept.
    pub fn combine_snapshot(&mut self, corr: &Correlator, span: &Span) -> f64 {
        combine_into(&mut self.sums, &self.w_snap, corr, span)
    }
}

/// Combines the blocks of `span` with weights `w` (by stored position) into `s`.
/// Returns the weighted number of pairs.
fn combine_into(s: &mut Sums, w: &[f64], corr: &Correlator, span: &Span) -> f64 {
    zero(s, span.lo, span.hi);
    let mut first = true;
    for i in span.first..=span.last.min(corr.count().saturating_sub(1)) {
        let w = w[corr.phys(i)];
        let b = corr.block(i);
        if w <= 0.0 || b.n <= 0.0 {
            continue;
        }
        let Some(sh) = Segment::shift(b, span) else {
            continue;
        };
        if first {
            s.first_k = b.first_k;
            first = false;
        }
        s.last_k = b.last_k;
        accumulate(s, b, w, span, sh);
    }
    s.n
}

/// Zeroes the lag-free sums of `s` and its slots `lo..=hi`.
fn zero(s: &mut Sums, lo: usize, hi: usize) {
    s.n = 0.0;
    s.sx = 0.0;
    s.sxx = 0.0;
    for v in [&mut s.xy, &mut s.y, &mut s.yy] {
        v[lo..=hi].iter_mut().for_each(|x| *x = 0.0);
    }
}

/// Adds `w` times block `b`, shifted by `(sh, f)` ([`Segment::shift`]), to the
/// slots `span.lo..=span.hi` of `s` (and its lag-free sums).
fn accumulate(s: &mut Sums, b: &Sums, w: f64, span: &Span, (sh, f): (isize, f64)) {
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

/// The fit to re-weight from, if it is finite ([`Segment::reweight`] ignores another).
fn finite_fit(fit: Option<(f64, (f64, f64))>) -> Option<(f64, (f64, f64))> {
    fit.filter(|&(p, (a, b))| p.is_finite() && a.is_finite() && b.is_finite())
}

/// Residual energy per sample of block `b` against the regression `(alpha, beta)`
/// at fractional slot `p` of `span`, moved with the drift to the block's centre.
fn residual(b: &Sums, span: &Span, p: f64, (alpha, beta): (f64, f64)) -> Option<f64> {
    let kb = 0.5 * (b.first_k + b.last_k) as f64;
    let x = p + span.drift * (kb - span.k_ref);
    let bxy = at(&b.xy, b.lo, b.hi, x)?;
    let by = at(&b.y, b.lo, b.hi, x)?;
    let byy = at(&b.yy, b.lo, b.hi, x)?;
    let en = byy - 2.0 * alpha * bxy - 2.0 * beta * by
        + alpha * alpha * b.sxx
        + 2.0 * alpha * beta * b.sx
        + b.n * beta * beta;
    Some((en / b.n).max(0.0))
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
            let Some(e) = residual(b, span, p, (alpha, beta)) else {
                continue;
            };
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

    /// Forgets a prepared combination.
    pub fn drop_prepared(&mut self) {
        self.prep.key = None;
        self.prep.next = 0;
        self.prep.ready = false;
    }

    /// Whether a combination is prepared or under way.
    pub fn preparing(&self) -> bool {
        self.prep.key.is_some()
    }

    /// Whether every stage of the prepared combination is done.
    pub fn prepared_ready(&self) -> bool {
        self.prep.key.is_some() && self.prep.ready
    }

    /// First stage of preparing the next hop's combination of the blocks
    /// `span.first..=span.last` (the segment's blocks before the hop's new one): the
    /// residual energies against `key.fit` and the partition at their median.
    /// False (nothing prepared) when a block does not hold the slots `span.lo..=span.hi`
    /// at its shift, or there is nothing to re-weight: the hop then combines directly.
    pub fn prepare_residuals(&mut self, corr: &Correlator, span: &Span, key: PrepKey) -> bool {
        self.drop_prepared();
        let fit = finite_fit(key.fit);
        let last = span.last.min(corr.count().saturating_sub(1));
        let mut m = 0;
        for i in span.first..=last {
            let b = corr.block(i);
            let pi = corr.phys(i);
            if b.n > 0.0 && self.w[pi] > 0.0 && Self::shift(b, span).is_none() {
                return false;
            }
            let e = match fit {
                Some((p, fit)) if b.n > 0.0 && self.w[pi] > 0.0 => residual(b, span, p, fit),
                _ => None,
            };
            self.prep.e[pi] = e.unwrap_or(f64::NAN);
            if let Some(e) = e {
                self.sort[m] = e;
                m += 1;
            }
        }
        let thr0 = if fit.is_some() {
            if m < 2 {
                return false;
            }
            let (_, med, _) = self.sort[..m].select_nth_unstable_by(m / 2, f64::total_cmp);
            ROBUST_C * *med
        } else {
            f64::INFINITY
        };
        for i in span.first..=last {
            let pi = corr.phys(i);
            let e = self.prep.e[pi];
            self.prep.down[pi] = e.is_finite() && e > thr0;
        }
        self.prep.key = Some(key);
        self.prep.span = *span;
        self.prep.ready = false;
        true
    }

    /// Later stages: the sums of both parts over the prepared slots and their lever
    /// sums, at most [`PREP_BLOCKS`] blocks per call, until
    /// [`Segment::prepared_ready`].
    pub fn prepare_sums(&mut self, corr: &Correlator) {
        if self.prep.key.is_none() || self.prep.ready {
            return;
        }
        let span = self.prep.span;
        if self.prep.next == 0 {
            zero(&mut self.prep.one, span.lo, span.hi);
            zero(&mut self.prep.down_sums, span.lo, span.hi);
            self.prep.lever_one = (0.0, 0.0);
            self.prep.lever_down = (0.0, 0.0);
        }
        let last = span.last.min(corr.count().saturating_sub(1));
        let from = span.first + self.prep.next;
        if from > last || corr.count() == 0 {
            // the blocks it was preparing have left the window (a reset, a restore):
            // nothing to prepare, the hop combines directly
            self.prep.key = None;
            return;
        }
        let to = (from + PREP_BLOCKS - 1).min(last);
        for i in from..=to {
            let b = corr.block(i);
            let pi = corr.phys(i);
            let (e, down) = (self.prep.e[pi], self.prep.down[pi]);
            let w = if down {
                1.0 / e
            } else if e.is_finite() {
                1.0
            } else {
                self.w[pi]
            };
            let shift = if w > 0.0 && b.n > 0.0 {
                Self::shift(b, &span)
            } else {
                None
            };
            self.prep.add(down, b, w, shift);
        }
        self.prep.next = to + 1 - span.first;
        self.prep.ready = to >= last;
    }

    /// The hop's combination from the prepared one: `span` is the segment with the
    /// new block (`span.last`), `key` the hop's inputs. Re-weights as
    /// [`Segment::reweight`] would (the new block's residual joins the median) and
    /// leaves in [`Segment::sums`] what [`Segment::combine`] would over the prepared
    /// slots. Returns the lever sums `(Σ w·n, Σ w·n·k_centre)` of the whole segment
    /// and how many prepared blocks changed side of the threshold, or `None`
    /// (nothing changed) when the prepared inputs are not the hop's.
    pub fn finish_prepared(
        &mut self,
        corr: &Correlator,
        span: &Span,
        key: &PrepKey,
    ) -> Option<((f64, f64), usize)> {
        let prepared = self.prep.key.take()?;
        if !self.prep.ready || prepared != *key || span.last != span.first + key.blocks {
            return None;
        }
        let last = span.last;
        if last + 1 != corr.count() {
            return None;
        }
        let nb = corr.block(last);
        let np = corr.phys(last);
        let new_shift = if nb.n > 0.0 && self.w[np] > 0.0 {
            Some(Self::shift(nb, span)?)
        } else {
            None
        };
        // the new block's residual, and the median of all
        let fit = finite_fit(key.fit);
        let e_new = match fit {
            Some((p, fit)) if nb.n > 0.0 && self.w[np] > 0.0 => residual(nb, span, p, fit),
            _ => None,
        };
        let thr = if fit.is_some() {
            let mut m = 0;
            for i in span.first..last {
                let e = self.prep.e[corr.phys(i)];
                if e.is_finite() {
                    self.sort[m] = e;
                    m += 1;
                }
            }
            if let Some(e) = e_new {
                self.sort[m] = e;
                m += 1;
            }
            if m < 3 {
                return None;
            }
            let (_, med, _) = self.sort[..m].select_nth_unstable_by(m / 2, f64::total_cmp);
            let thr = ROBUST_C * *med;
            if thr <= 0.0 || !thr.is_finite() {
                return None;
            }
            thr
        } else {
            f64::INFINITY
        };
        // blocks whose side of the threshold moved with the new block's residual
        let mut moved = 0;
        for i in span.first..last {
            let b = corr.block(i);
            let pi = corr.phys(i);
            let (ei, was_down) = (self.prep.e[pi], self.prep.down[pi]);
            if !ei.is_finite() || (ei > thr) == was_down {
                continue;
            }
            moved += 1;
            let (w_from, w_to) = if was_down {
                (1.0 / ei, 1.0)
            } else {
                (1.0, 1.0 / ei)
            };
            let shift = if b.n > 0.0 {
                Self::shift(b, span)
            } else {
                None
            };
            self.prep.add(was_down, b, -w_from, shift);
            self.prep.add(!was_down, b, w_to, shift);
            self.prep.down[pi] = !was_down;
        }
        // the weights reweight() would set
        for i in span.first..last {
            let pi = corr.phys(i);
            let ei = self.prep.e[pi];
            if ei.is_finite() {
                self.w[pi] = if ei > thr { thr / ei } else { 1.0 };
            }
        }
        if let Some(en) = e_new {
            self.w[np] = if en > thr { thr / en } else { 1.0 };
        }
        // one + thr · down + the new block
        let (s, p) = (&mut self.sums, &self.prep);
        let thr_s = if thr.is_finite() { thr } else { 0.0 };
        s.n = p.one.n + thr_s * p.down_sums.n;
        s.sx = p.one.sx + thr_s * p.down_sums.sx;
        s.sxx = p.one.sxx + thr_s * p.down_sums.sxx;
        for (dst, (a, b)) in [
            (&mut s.xy, (&p.one.xy, &p.down_sums.xy)),
            (&mut s.y, (&p.one.y, &p.down_sums.y)),
            (&mut s.yy, (&p.one.yy, &p.down_sums.yy)),
        ] {
            for ((o, &x), &y) in dst[span.lo..=span.hi]
                .iter_mut()
                .zip(&a[span.lo..=span.hi])
                .zip(&b[span.lo..=span.hi])
            {
                *o = x + thr_s * y;
            }
        }
        let mut lever = (
            p.lever_one.0 + thr_s * p.lever_down.0,
            p.lever_one.1 + thr_s * p.lever_down.1,
        );
        let w_new = self.w[np];
        lever.0 += w_new * nb.n;
        lever.1 += w_new * nb.n * (0.5 * (nb.first_k + nb.last_k) as f64);
        if let Some(sh) = new_shift {
            accumulate(s, nb, w_new, span, sh);
        }
        // first and last blocks in the combination
        s.first_k = nb.first_k;
        for i in span.first..=last {
            let b = corr.block(i);
            if self.w[corr.phys(i)] > 0.0 && b.n > 0.0 {
                s.first_k = b.first_k;
                break;
            }
        }
        s.last_k = if new_shift.is_some() {
            nb.last_k
        } else {
            (span.first..last)
                .rev()
                .find(|&i| self.w[corr.phys(i)] > 0.0 && corr.block(i).n > 0.0)
                .map_or(nb.last_k, |i| corr.block(i).last_k)
        };
        Some((lever, moved))
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

    /// The direct hop: re-weight from `fit`, combine; lever sums over the span.
    fn direct(
        seg: &mut Segment,
        c: &Correlator,
        span: &Span,
        fit: Option<(f64, (f64, f64))>,
    ) -> (f64, f64) {
        if let Some((p, f)) = fit {
            seg.reweight(c, span, p, f);
        }
        seg.combine(c, span);
        let (mut sw, mut swk) = (0.0, 0.0);
        for i in span.first..=span.last {
            let b = c.block(i);
            let w = seg.weight(c, i) * b.n;
            sw += w;
            swk += w * 0.5 * (b.first_k + b.last_k) as f64;
        }
        (sw, swk)
    }

    /// The hop's span of blocks `first..` of `c` (the newest block the hop's own),
    /// the span prepared before it, and the key for `fit`.
    fn hop_spans(
        c: &Correlator,
        first: usize,
        (drift, k_ref): (f64, f64),
        (lo, hi): (usize, usize),
        fit: Option<(f64, (f64, f64))>,
    ) -> (Span, Span, PrepKey) {
        let n = c.count();
        let full = Span {
            first,
            last: n - 1,
            drift,
            k_ref,
            lo,
            hi,
        };
        let key = PrepKey {
            epoch: c.epoch(),
            first_k: c.block(first).first_k,
            last_k: c.block(n - 2).last_k,
            blocks: n - 1 - first,
            drift,
            k_ref,
            lo,
            hi,
            fit,
        };
        (
            full,
            Span {
                last: n - 2,
                ..full
            },
            key,
        )
    }

    #[test]
    fn a_prepared_combination_is_the_direct_one() {
        // mismatching blocks give a spread of residuals, so the new block's residual
        // moves some blocks across the threshold
        let c = store(0.002, Some((900, 1400)));
        let n = c.count();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()));
        let mut moved_total = 0;
        let mut checked = 0;
        for (j, first) in [0usize, 3, 20].into_iter().enumerate() {
            for (q, fit) in [
                None,
                Some((35.0, (1.0, 0.0))),
                Some((34.3, (0.8, 0.05))),
                Some((36.7, (1.3, -0.1))),
                Some((35.2, (0.4, 0.2))),
            ]
            .into_iter()
            .enumerate()
            {
                let drift = [0.0, 0.002, -0.001][(j + q) % 3];
                let k_ref = c.block(n - 1).last_k as f64 - 100.0 * q as f64;
                let (full, pre, key) = hop_spans(&c, first, (drift, k_ref), (18, 50), fit);
                let mut a = Segment::new(61, 40);
                let mut b = Segment::new(61, 40);
                // earlier weights that stay where a block has no residual
                for i in 0..n {
                    let w = 0.5 + 0.5 * ((i * 7) % 5) as f64 / 4.0;
                    a.set_weight(&c, i, w);
                    b.set_weight(&c, i, w);
                }
                let lever_direct = direct(&mut a, &c, &full, fit);
                assert!(b.prepare_residuals(&c, &pre, key));
                assert!(!b.prepared_ready());
                while !b.prepared_ready() {
                    b.prepare_sums(&c);
                }
                let (lever, moved) = b.finish_prepared(&c, &full, &key).expect("prepared");
                moved_total += moved;
                assert!(close(lever.0, lever_direct.0) && close(lever.1, lever_direct.1));
                for i in first..n {
                    assert_eq!(a.weight(&c, i), b.weight(&c, i), "block {i}");
                }
                let (x, y) = (&a.sums, &b.sums);
                assert!(close(x.n, y.n) && close(x.sx, y.sx) && close(x.sxx, y.sxx));
                assert_eq!((x.first_k, x.last_k), (y.first_k, y.last_k));
                for s in full.lo..=full.hi {
                    assert!(
                        close(x.xy[s], y.xy[s]) && close(x.y[s], y.y[s]) && close(x.yy[s], y.yy[s])
                    );
                    assert!(close(x.ncc(s), y.ncc(s)), "slot {s}");
                }
                checked += 1;
            }
        }
        assert_eq!(checked, 15);
        assert!(
            moved_total > 0,
            "no block changed side: the test does not reach that path"
        );
    }

    /// A reset or a restore empties the block store while a preparation is under
    /// way: the next stage drops it (it once computed its progress as `to + 1 -
    /// first` with `to` below `first`, an overflow).
    #[test]
    fn a_preparation_whose_blocks_left_the_store_is_dropped() {
        let mut c = store(0.0, None);
        let fit = Some((35.0, (1.0, 0.0)));
        let (full, pre, key) = hop_spans(&c, 5, (0.0, 0.0), (20, 50), fit);
        let mut seg = Segment::new(61, 40);
        assert!(seg.prepare_residuals(&c, &pre, key));
        assert!(seg.preparing() && !seg.prepared_ready());
        c.clear_blocks();
        seg.prepare_sums(&c);
        assert!(!seg.preparing());
        assert!(seg.finish_prepared(&c, &full, &key).is_none());
    }

    #[test]
    fn a_prepared_combination_for_other_inputs_is_not_used() {
        let c = store(0.0, None);
        let fit = Some((35.0, (1.0, 0.0)));
        let (full, pre, key) = hop_spans(&c, 0, (0.0, 0.0), (20, 50), fit);
        let other = [
            PrepKey { drift: 1e-4, ..key },
            PrepKey { k_ref: 1.0, ..key },
            PrepKey {
                epoch: key.epoch + 1,
                ..key
            },
            PrepKey { hi: 49, ..key },
            PrepKey { fit: None, ..key },
            PrepKey {
                first_k: key.first_k + 50,
                ..key
            },
        ];
        for k in other {
            let mut seg = Segment::new(61, 40);
            seg.prepare_residuals(&c, &pre, key);
            seg.prepare_sums(&c);
            let before = seg.weight(&c, 3);
            assert!(seg.finish_prepared(&c, &full, &k).is_none(), "{k:?}");
            assert_eq!(seg.weight(&c, 3), before);
            // used up either way
            assert!(seg.finish_prepared(&c, &full, &key).is_none());
        }
        // unfinished: not used
        let mut seg = Segment::new(61, 40);
        seg.prepare_residuals(&c, &pre, key);
        assert!(seg.finish_prepared(&c, &full, &key).is_none());
    }
}
