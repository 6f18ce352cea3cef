//! Incremental windowed Pearson cross-correlation over a fixed lag range.
//!
//! Both resampled, filtered streams are kept in index-tagged rings. For every
//! LiDAR grid index `k` (the cursor) the pairs `(L[k], C[k - m])` of every
//! active lag `m` are added to the sums of the current *block* (one hop long):
//! `O(lags)` per grid sample; a block's Σy, Σy² per lag are sliding sums over
//! the camera ring, computed once when the block completes.
//!
//! Completed blocks are kept in a ring (the longest segment the estimator may
//! combine, see [`crate::segment`]). The acquisition window, the newest
//! `acq_blocks` blocks, is maintained as a running total: the completed block is
//! added and the one leaving is subtracted (one pass), and the total is rebuilt
//! exactly from its blocks once per four window lengths, so each sum carries the
//! rounding of at most eight additions per block of the window (96 at the
//! defaults). The two inner loops (a step's products, the correlation of a range of
//! lags) are `vlsync-simd`'s, vectorised with AVX where the CPU has it.
//! A break in the data (a gap) drops the unfinished block and keeps the
//! completed ones: a segment may span a gap. Nothing allocates after construction.
//!
//! Lag `m` (grid steps) pairs LiDAR time `k·dt` with camera time `(k-m)·dt`; a
//! peak at `m` means `offset = t_L - t_C = m·dt`.

/// Sums of one block or one window.
#[derive(Debug, Clone)]
pub struct Sums {
    /// Pairs per lag (same for every lag).
    pub n: f64,
    /// Σx, Σx² of the LiDAR values.
    pub sx: f64,
    /// Σx².
    pub sxx: f64,
    /// Per lag slot: Σxy.
    pub xy: Vec<f64>,
    /// Per lag slot: Σy.
    pub y: Vec<f64>,
    /// Per lag slot: Σy².
    pub yy: Vec<f64>,
    /// First LiDAR grid index covered (valid when n > 0).
    pub first_k: i64,
    /// Last LiDAR grid index covered.
    pub last_k: i64,
    /// Lag slots these sums hold (of a block: the slots active for all of it).
    pub lo: usize,
    /// Last lag slot held (inclusive).
    pub hi: usize,
}

impl Sums {
    /// Empty sums over `n_lags` lag slots.
    pub fn new(n_lags: usize) -> Self {
        Self {
            n: 0.0,
            sx: 0.0,
            sxx: 0.0,
            xy: vec![0.0; n_lags],
            y: vec![0.0; n_lags],
            yy: vec![0.0; n_lags],
            first_k: 0,
            last_k: 0,
            lo: 0,
            hi: n_lags.saturating_sub(1),
        }
    }

    /// Zeroes every sum.
    pub fn clear(&mut self) {
        self.n = 0.0;
        self.sx = 0.0;
        self.sxx = 0.0;
        self.xy.iter_mut().for_each(|v| *v = 0.0);
        self.y.iter_mut().for_each(|v| *v = 0.0);
        self.yy.iter_mut().for_each(|v| *v = 0.0);
    }

    /// Adds `sign` times `o` on the slots it holds (a window of blocks is valid on
    /// the slots all of them hold, so what the others hold does not matter).
    fn add(&mut self, o: &Sums, sign: f64) {
        self.n += sign * o.n;
        self.sx += sign * o.sx;
        self.sxx += sign * o.sxx;
        let (lo, hi) = (o.lo, o.hi.min(o.xy.len() - 1));
        if lo > hi {
            return;
        }
        for (a, b) in [
            (&mut self.xy, &o.xy),
            (&mut self.y, &o.y),
            (&mut self.yy, &o.yy),
        ] {
            for (p, q) in a[lo..=hi].iter_mut().zip(&b[lo..=hi]) {
                *p += sign * q;
            }
        }
    }

    /// Subtracts `out` and adds `inn` (a window moving by one block): the sums of
    /// `self.add(out, -1.0)` then `self.add(inn, 1.0)`, bit for bit, in one pass
    /// when both hold the same slots.
    fn replace(&mut self, out: &Sums, inn: &Sums) {
        if (out.lo, out.hi) != (inn.lo, inn.hi) || out.hi >= out.xy.len() || out.lo > out.hi {
            self.add(out, -1.0);
            self.add(inn, 1.0);
            return;
        }
        self.n = (self.n - out.n) + inn.n;
        self.sx = (self.sx - out.sx) + inn.sx;
        self.sxx = (self.sxx - out.sxx) + inn.sxx;
        let r = out.lo..=out.hi;
        for (a, b, c) in [
            (&mut self.xy, &out.xy, &inn.xy),
            (&mut self.y, &out.y, &inn.y),
            (&mut self.yy, &out.yy, &inn.yy),
        ] {
            for (p, (q, w)) in a[r.clone()]
                .iter_mut()
                .zip(b[r.clone()].iter().zip(&c[r.clone()]))
            {
                *p = (*p - q) + w;
            }
        }
    }

    /// Adds `sign` times the slots `lo..=hi` of `o` (and its lag-free sums). The slots
    /// must be ones `o` holds (its `lo..=hi`) unless it is empty: the lag-free sums
    /// count every pair, so a slot it lacks would make a sum of no lag.
    pub fn add_range(&mut self, o: &Sums, sign: f64, lo: usize, hi: usize) {
        debug_assert!(
            o.n == 0.0 || (lo >= o.lo && hi <= o.hi),
            "slots {lo}..={hi} of a block holding {}..={}",
            o.lo,
            o.hi
        );
        self.n += sign * o.n;
        self.sx += sign * o.sx;
        self.sxx += sign * o.sxx;
        for (a, b) in [
            (&mut self.xy, &o.xy),
            (&mut self.y, &o.y),
            (&mut self.yy, &o.yy),
        ] {
            for (p, q) in a[lo..=hi].iter_mut().zip(&b[lo..=hi]) {
                *p += sign * q;
            }
        }
    }

    /// Sets `self` to `a - b` on slots `lo..=hi` (and the lag-free sums).
    pub fn diff_range(&mut self, a: &Sums, b: &Sums, lo: usize, hi: usize) {
        self.n = a.n - b.n;
        self.sx = a.sx - b.sx;
        self.sxx = a.sxx - b.sxx;
        for (d, (x, y)) in [
            (&mut self.xy, (&a.xy, &b.xy)),
            (&mut self.y, (&a.y, &b.y)),
            (&mut self.yy, (&a.yy, &b.yy)),
        ] {
            for (p, (q, r)) in d[lo..=hi]
                .iter_mut()
                .zip(x[lo..=hi].iter().zip(&y[lo..=hi]))
            {
                *p = q - r;
            }
        }
    }

    /// Pearson correlation at lag slot `slot` (0 when undefined).
    #[inline]
    pub fn ncc(&self, slot: usize) -> f64 {
        if self.n < 3.0 {
            return 0.0;
        }
        let vx = self.n * self.sxx - self.sx * self.sx;
        vlsync_simd::pearson(
            self.n,
            self.sx,
            vx,
            self.xy[slot],
            self.y[slot],
            self.yy[slot],
        )
    }

    /// [`Sums::ncc`] of the slots `lo..=hi` into `out[lo..=hi]` (`out` and the sums
    /// must hold slot `hi`), vectorised ([`vlsync_simd::pearson_range`]).
    pub fn ncc_range(&self, lo: usize, hi: usize, out: &mut [f64]) {
        let out = &mut out[lo..=hi];
        if self.n < 3.0 {
            out.fill(0.0);
            return;
        }
        let vx = self.n * self.sxx - self.sx * self.sx;
        vlsync_simd::pearson_range(
            self.n,
            self.sx,
            vx,
            &self.xy[lo..=hi],
            &self.y[lo..=hi],
            &self.yy[lo..=hi],
            out,
        );
    }

    /// Variance of the LiDAR values.
    pub fn var_x(&self) -> f64 {
        if self.n < 2.0 {
            return 0.0;
        }
        ((self.sxx - self.sx * self.sx / self.n) / self.n).max(0.0)
    }

    /// Variance of the camera values paired at lag slot `slot`.
    pub fn var_y(&self, slot: usize) -> f64 {
        if self.n < 2.0 {
            return 0.0;
        }
        let (sy, syy) = (self.y[slot], self.yy[slot]);
        ((syy - sy * sy / self.n) / self.n).max(0.0)
    }
}

/// A ring of index-tagged grid values. Values are stored twice (at `p` and
/// `p + cap`) so any span of up to `cap` consecutive indices is one contiguous
/// slice: the per-lag inner loop then vectorises.
#[derive(Debug, Clone)]
struct Ring {
    idx: Vec<i64>,
    val: Vec<f64>,
    cap: usize,
    mask: usize,
    seg_start: Option<i64>,
    end: i64,
}

impl Ring {
    fn new(min_cap: usize) -> Self {
        let cap = min_cap.next_power_of_two();
        Self {
            idx: vec![i64::MIN; cap],
            val: vec![0.0; 2 * cap],
            cap,
            mask: cap - 1,
            seg_start: None,
            end: i64::MIN,
        }
    }

    #[inline]
    fn push(&mut self, k: i64, v: f64) {
        if self.seg_start.is_none() || k != self.end.wrapping_add(1) {
            self.seg_start = Some(k);
        }
        let s = (k as usize) & self.mask;
        self.idx[s] = k;
        self.val[s] = v;
        self.val[s + self.cap] = v;
        self.end = k;
    }

    fn brk(&mut self) {
        self.seg_start = None;
    }

    #[inline]
    fn get(&self, k: i64) -> Option<f64> {
        let s = (k as usize) & self.mask;
        (self.idx[s] == k).then(|| self.val[s])
    }

    /// The values of indices `a..=b` (the caller checked they are present; `b - a < cap`).
    #[inline]
    fn span(&self, a: i64, b: i64) -> &[f64] {
        let s = (a as usize) & self.mask;
        let n = (b.saturating_sub(a).saturating_add(1).max(0) as usize).min(self.cap);
        &self.val[s..s + n]
    }
}

/// Most grid indices one [`Correlator::step`] adds: a 10 Hz LiDAR scan brings ten grid
/// values at 100 Hz, and each Σxy slot is then loaded and stored once for all of them.
const BATCH: usize = 10;

/// The acquisition window's running total is rebuilt exactly from its blocks once
/// per this many window lengths: in between each sum takes one addition and one
/// subtraction per hop, 96 at the defaults (12 blocks), whose rounding stays near
/// 1e-14 of the sums.
const REBUILD_WINDOWS: usize = 4;

/// The farthest slot 0 may be from lag 0, grid steps (either way): a lag range asked
/// beyond it (a saturated conversion of an absurd offset) is clamped to it, so that a
/// lag plus a slot, and a grid index less a lag, stay far from the `i64` range. Real
/// lags are many orders of magnitude smaller (a 1e6 s offset at 2 kHz is 2e9 steps).
pub const MAX_ABS_LAG0: i64 = i64::MAX / 4;

/// `p % len` for `p < 2·len` (a ring position: the head, below `len`, plus an index
/// below `len`), without the division that `%` by a length known only at run time
/// costs: the block store's positions are computed several times per sample.
#[inline]
fn wrap(p: usize, len: usize) -> usize {
    debug_assert!(p < 2 * len, "ring position {p} of {len}");
    if p >= len {
        p - len
    } else {
        p
    }
}

/// Result of one cursor step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Waiting for data.
    Idle,
    /// Grid indices were added (one, or a few of one block).
    Added,
    /// A block (hop) completed and was stored.
    Hop,
    /// Data were missing: the unfinished block was dropped and the cursor jumped.
    Break,
}

/// The incremental correlator.
#[derive(Debug, Clone)]
pub struct Correlator {
    n_lags: usize,
    lag0: i64,
    hop_len: i64,
    acq_blocks: usize,
    lidar: Ring,
    cam: Ring,
    cursor: Option<i64>,
    /// The unfinished block; its Σxy holds slot `s` at `n_lags - 1 - s` until it
    /// completes ([`vlsync_simd::add_products`]: both run forward, and the loop
    /// vectorises without shuffles).
    cur: Sums,
    /// Last grid index of the unfinished block (valid while it has indices).
    cur_end: i64,
    /// Completed blocks, a ring of `blocks.len()`; `head` is the oldest.
    blocks: Vec<Sums>,
    head: usize,
    count: usize,
    /// Running total of the newest `acq_count` blocks.
    acq: Sums,
    acq_count: usize,
    since_rebuild: usize,
    active: (usize, usize),
    /// Changes whenever stored blocks change other than by a block completing
    /// (lag shift, forgetting): what was computed from them is stale.
    epoch: u64,
}

impl Correlator {
    /// A correlator over `n_lags` lag slots starting at lag `lag0` (grid steps),
    /// hops of `hop_len` grid samples, an acquisition window of `acq_blocks`
    /// blocks, a store of `cap_blocks` completed blocks, and rings able to hold
    /// `ring_len` grid samples.
    pub fn new(
        n_lags: usize,
        lag0: i64,
        hop_len: i64,
        acq_blocks: usize,
        cap_blocks: usize,
        ring_len: usize,
    ) -> Self {
        let n_lags = n_lags.max(3);
        let lag0 = lag0.clamp(-MAX_ABS_LAG0, MAX_ABS_LAG0);
        let acq_blocks = acq_blocks.max(1);
        let cap_blocks = cap_blocks.max(acq_blocks);
        Self {
            n_lags,
            lag0,
            hop_len: hop_len.max(1),
            acq_blocks,
            lidar: Ring::new(ring_len.max(n_lags * 2)),
            cam: Ring::new(ring_len.max(n_lags * 2)),
            cursor: None,
            cur: Sums::new(n_lags),
            cur_end: 0,
            blocks: (0..cap_blocks).map(|_| Sums::new(n_lags)).collect(),
            head: 0,
            count: 0,
            acq: Sums::new(n_lags),
            acq_count: 0,
            since_rebuild: 0,
            active: (0, n_lags - 1),
            epoch: 0,
        }
    }

    /// Counter of changes to the stored blocks other than a block completing (a
    /// lag shift, forgetting them): equal epochs and equal block times mean equal
    /// blocks.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Number of lag slots.
    pub fn n_lags(&self) -> usize {
        self.n_lags
    }

    /// Lag (grid steps) of slot 0.
    pub fn lag0(&self) -> i64 {
        self.lag0
    }

    /// Grid samples per block.
    pub fn hop_len(&self) -> i64 {
        self.hop_len
    }

    /// Moves the lag range (slot 0 at `lag0`, clamped to ±[`MAX_ABS_LAG0`]); forgets
    /// every block.
    pub fn set_lag0(&mut self, lag0: i64) {
        let lag0 = lag0.clamp(-MAX_ABS_LAG0, MAX_ABS_LAG0);
        if lag0 != self.lag0 {
            self.lag0 = lag0;
            self.clear_blocks();
        }
    }

    /// Moves the lag range by `delta` slots (slot 0 at `lag0 + delta`, clamped to
    /// ±[`MAX_ABS_LAG0`]) keeping the stored blocks: each keeps the lags it holds that
    /// stay in range (its `lo..=hi` narrows). The unfinished block and the acquisition
    /// window restart.
    pub fn shift_lags(&mut self, delta: i64) {
        let lag0 = self
            .lag0
            .saturating_add(delta)
            .clamp(-MAX_ABS_LAG0, MAX_ABS_LAG0);
        // the move made (within ±2·MAX_ABS_LAG0: the slot arithmetic below cannot overflow)
        let delta = lag0 - self.lag0;
        if delta == 0 {
            return;
        }
        let n = self.n_lags as i64;
        self.lag0 = lag0;
        self.epoch += 1;
        for i in 0..self.count {
            let p = self.phys(i);
            let b = &mut self.blocks[p];
            let lo = (b.lo as i64 - delta).max(0);
            let hi = (b.hi as i64 - delta).min(n - 1);
            if lo > hi {
                // none of its lags stays: it holds nothing (and adds nothing to a window)
                b.clear();
                continue;
            }
            let (lo, hi) = (lo as usize, hi as usize);
            let src = (lo as i64 + delta) as usize;
            for v in [&mut b.xy, &mut b.y, &mut b.yy] {
                v.copy_within(src..=src + (hi - lo), lo);
                // the entering slots hold nothing (sums over them stay defined)
                v[..lo].iter_mut().for_each(|x| *x = 0.0);
                v[hi + 1..].iter_mut().for_each(|x| *x = 0.0);
            }
            b.lo = lo;
            b.hi = hi;
        }
        // the active range keeps its lags where it can (its width always)
        let (a, b) = self.active;
        let width = b - a;
        let a = (a as i64 - delta).clamp(0, n - 1 - width as i64) as usize;
        self.active = (a, a + width);
        self.cur.clear();
        // the acquisition window keeps its blocks, valid on the slots they all hold
        // (a re-centre must not leave the tracker without its motion gate for a
        // window's worth of hops)
        self.rebuild_acq();
    }

    /// Restricts the updated lag slots to `lo..=hi` (clamped). Nothing is forgotten:
    /// each stored block knows the slots it holds, so the acquisition window stays
    /// valid on the slots all its blocks hold, and the unfinished block will hold
    /// the slots that were active for all of it.
    pub fn set_active(&mut self, lo: usize, hi: usize) {
        let hi = hi.min(self.n_lags - 1);
        let lo = lo.min(hi);
        self.active = (lo, hi);
        if self.cur.n > 0.0 {
            self.cur.lo = self.cur.lo.max(lo);
            self.cur.hi = self.cur.hi.min(hi);
        }
    }

    /// Active lag slots.
    pub fn active(&self) -> (usize, usize) {
        self.active
    }

    /// Next LiDAR grid index to be added.
    pub fn cursor(&self) -> Option<i64> {
        self.cursor
    }

    /// Stores a filtered LiDAR grid value.
    #[inline]
    pub fn push_lidar(&mut self, k: i64, v: f64) {
        self.lidar.push(k, v);
    }

    /// Stores a filtered camera grid value.
    #[inline]
    pub fn push_cam(&mut self, k: i64, v: f64) {
        self.cam.push(k, v);
    }

    /// The LiDAR stream broke (gap or reset).
    pub fn break_lidar(&mut self) {
        self.lidar.brk();
    }

    /// The camera stream broke.
    pub fn break_cam(&mut self) {
        self.cam.brk();
    }

    /// Totals of the acquisition window (the newest blocks, at most `acq_blocks`),
    /// valid on the lag slots `lo..=hi` it names: after [`Correlator::shift_lags`] the
    /// slots every one of its blocks holds (the whole range again once the blocks from
    /// before the shift have left it).
    pub fn acq(&self) -> &Sums {
        &self.acq
    }

    /// Blocks in the acquisition window.
    pub fn acq_count(&self) -> usize {
        self.acq_count
    }

    /// Blocks in the acquisition window when it is full.
    pub fn acq_blocks(&self) -> usize {
        self.acq_blocks
    }

    /// Completed blocks stored.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Stored block `i`, 0 the oldest, `count() - 1` the newest.
    pub fn block(&self, i: usize) -> &Sums {
        &self.blocks[self.phys(i)]
    }

    /// Position in the store of block `i` (stable while the block is stored).
    #[inline]
    pub fn phys(&self, i: usize) -> usize {
        wrap(self.head + i, self.blocks.len())
    }

    /// Forgets every completed block and the unfinished one (the cursor stays); every
    /// lag slot is active again.
    pub fn clear_blocks(&mut self) {
        self.active = (0, self.n_lags - 1);
        self.cur.clear();
        self.epoch += 1;
        self.count = 0;
        self.restart_acq();
    }

    /// Empties the acquisition window only (the blocks stay for the segment).
    pub fn restart_acq(&mut self) {
        self.acq.clear();
        self.acq_count = 0;
        self.since_rebuild = 0;
        self.acq_range();
    }

    /// Sets the acquisition window's valid slots: those every block in it holds.
    fn acq_range(&mut self) {
        (self.acq.lo, self.acq.hi) = self.slots_held(self.count - self.acq_count, self.count);
    }

    /// The lag slots every non-empty stored block `first..end` holds (all slots when
    /// none is; `lo > hi` when they share none): after [`Correlator::shift_lags`] the
    /// older blocks lack the entering lags.
    pub fn slots_held(&self, first: usize, end: usize) -> (usize, usize) {
        let (mut lo, mut hi) = (0, self.n_lags - 1);
        for i in first..end.min(self.count) {
            let b = self.block(i);
            if b.n > 0.0 {
                lo = lo.max(b.lo);
                hi = hi.min(b.hi);
            }
        }
        (lo, hi)
    }

    /// Drops the unfinished block and moves the cursor forward to `k` (never backward).
    pub fn skip_to(&mut self, k: i64) {
        self.cur.clear();
        self.cursor = Some(self.cursor.map_or(k, |c| c.max(k)));
    }

    /// Forgets the cursor (the unfinished block with it): the next step starts at
    /// the first index both streams cover. After the LiDAR's clock stepped back, the
    /// grid's indices restart below the cursor, which [`Correlator::skip_to`] never
    /// moves back.
    pub fn restart_cursor(&mut self) {
        self.cur.clear();
        self.cursor = None;
    }

    /// Moves the cursor back to just after the newest LiDAR index stored, if it is
    /// beyond (with a lag range far off the cursor waits at, or skipped to, indices
    /// the data will not reach for a long time): the next data are correlated again.
    pub fn pull_cursor_back(&mut self) {
        let next = self.lidar.end.saturating_add(1);
        if self.lidar.seg_start.is_some() && self.cursor.is_some_and(|c| c > next) {
            self.cur.clear();
            self.cursor = Some(next);
        }
    }

    fn rebuild_acq(&mut self) {
        self.acq.clear();
        for i in self.count - self.acq_count..self.count {
            let b = &self.blocks[self.phys(i)];
            self.acq.add(b, 1.0);
        }
        if self.acq_count > 0 {
            self.acq.first_k = self.block(self.count - self.acq_count).first_k;
            self.acq.last_k = self.block(self.count - 1).last_k;
        }
        self.since_rebuild = 0;
        self.acq_range();
    }

    /// Whether the next [`Correlator::step`] may complete a block (conservative:
    /// true before the first index). Until it does, the stored blocks stay as they are.
    pub fn may_complete_block(&self) -> bool {
        let Some(k) = self.cursor else {
            return true;
        };
        // a step adds up to BATCH indices, and only those whose data are in: the
        // block's last index needs its LiDAR value and the camera's at the lowest lag
        let end = self.block_end(k);
        let left = end - k;
        let m_lo = self.lag0.saturating_add(self.active.0 as i64);
        left < BATCH as i64 && self.lidar.end >= end && self.cam.end >= end.saturating_sub(m_lo)
    }

    /// Adds the next grid index, with up to nine more of the same block whose data
    /// are in. Call until it returns [`Step::Idle`].
    pub fn step(&mut self) -> Step {
        self.step_up_to(BATCH)
    }

    /// [`Correlator::step`] adding at most `batch` (1..=[`BATCH`]) indices.
    fn step_up_to(&mut self, batch: usize) -> Step {
        let (Some(l0), Some(c0)) = (self.lidar.seg_start, self.cam.seg_start) else {
            return Step::Idle;
        };
        // saturating (as every lag and index sum here): `lag0` is clamped well inside
        // the range, but an index near its ends must not overflow either
        let m_lo = self.lag0.saturating_add(self.active.0 as i64);
        let m_hi = self.lag0.saturating_add(self.active.1 as i64);
        let earliest = l0.max(c0.saturating_add(m_hi));
        let k = match self.cursor {
            Some(k) if k >= earliest => k,
            _ => {
                let had = self.cursor.is_some();
                self.skip_to(earliest);
                if had {
                    return Step::Break;
                }
                earliest
            }
        };
        if self.lidar.end < k || self.cam.end < k.saturating_sub(m_lo) {
            return Step::Idle;
        }
        // the oldest and newest camera values needed must be in the ring (segments are contiguous)
        let (Some(x), Some(_), Some(_)) = (
            self.lidar.get(k),
            self.cam.get(k.saturating_sub(m_hi)),
            self.cam.get(k.saturating_sub(m_lo)),
        ) else {
            self.skip_to(k.saturating_add(1));
            return Step::Break;
        };
        // up to BATCH consecutive indices of the same block at once, when their data are
        // in (a LiDAR sample brings several grid values): each Σxy slot is then loaded
        // and stored once for all of them, its additions in index order as one by one.
        // Both rings hold every index from their segment's start to their end (k is at
        // or after both starts, and its values are still in), so the indices up to
        // the newest each stream covers are all there.
        let block_end = self.block_end(k);
        let last = k
            .saturating_add(batch.clamp(1, BATCH) as i64 - 1)
            .min(block_end)
            .min(self.lidar.end)
            .min(self.cam.end.saturating_add(m_lo));
        let xs = self.lidar.span(k, last);
        debug_assert_eq!(xs.first(), Some(&x));
        if self.cur.n == 0.0 {
            self.cur.first_k = k;
            self.cur_end = block_end;
            (self.cur.lo, self.cur.hi) = self.active;
        }
        self.cur.last_k = last;
        for &xj in xs {
            self.cur.n += 1.0;
            self.cur.sx += xj;
            self.cur.sxx += xj * xj;
        }
        let (lo, hi) = self.active;
        // slot s pairs index k + j with camera index k + j - lag0 - s: in the span from
        // k - m_hi, position hi - s + j. The unfinished block's Σxy holds slot s at
        // n_lags - 1 - s until it completes, so that position is its offset from slot
        // hi's, plus j. Only Σxy needs the pair; Σy and Σy² of a block are sliding sums
        // over the camera ring, filled in once when the block completes.
        let ys = self
            .cam
            .span(k.saturating_sub(m_hi), last.saturating_sub(m_lo));
        let n = self.n_lags;
        vlsync_simd::add_products(&mut self.cur.xy[n - 1 - hi..=n - 1 - lo], ys, xs);
        self.cursor = Some(last.saturating_add(1));
        // the only block end in k..=last can be the block's own
        if last == block_end {
            if self.complete_block() {
                Step::Hop
            } else {
                Step::Break
            }
        } else {
            Step::Added
        }
    }

    /// Last index of the block holding index `k`: the unfinished block's, kept while
    /// it has indices (the cursor stays in it: every jump clears it), else computed
    /// (a division, which a step otherwise paid twice).
    #[inline]
    fn block_end(&self, k: i64) -> i64 {
        if self.cur.n > 0.0 {
            debug_assert_eq!(
                self.cur_end,
                (k.div_euclid(self.hop_len) + 1) * self.hop_len - 1
            );
            self.cur_end
        } else {
            (k.div_euclid(self.hop_len) + 1) * self.hop_len - 1
        }
    }

    /// Σy and Σy² of the current block for every active slot: for slot `s` the
    /// camera indices `first_k - lag0 - s ..= last_k - lag0 - s`, a window that
    /// slides by one index per slot. Returns false if the ring no longer holds them.
    fn fill_y_sums(&mut self) -> bool {
        let (lo, hi) = self.active;
        let (k0, k1) = (self.cur.first_k, self.cur.last_k);
        let a_hi = k0.saturating_sub(self.lag0).saturating_sub(hi as i64);
        let b_lo = k1.saturating_sub(self.lag0).saturating_sub(lo as i64);
        if self.cam.get(a_hi).is_none() || self.cam.get(b_lo).is_none() {
            return false;
        }
        let ys = self.cam.span(a_hi, b_lo);
        let len = (k1 - k0 + 1) as usize;
        if ys.len() < len + (hi - lo) {
            return false;
        }
        // slot hi's sums in four interleaved partial sums: four short chains of
        // additions instead of one long one
        let (mut py, mut pyy) = ([0.0f64; 4], [0.0f64; 4]);
        let mut quads = ys[..len].chunks_exact(4);
        for q in &mut quads {
            for i in 0..4 {
                py[i] += q[i];
                pyy[i] += q[i] * q[i];
            }
        }
        for (i, &y) in quads.remainder().iter().enumerate() {
            py[i] += y;
            pyy[i] += y * y;
        }
        let mut sy = (py[0] + py[1]) + (py[2] + py[3]);
        let mut syy = (pyy[0] + pyy[1]) + (pyy[2] + pyy[3]);
        // slot hi covers ys[0..len]; each lower slot shifts the range up by one
        for (j, s) in (lo..=hi).rev().enumerate() {
            if j > 0 {
                let (out, inn) = (ys[j - 1], ys[j - 1 + len]);
                sy += inn - out;
                syy += inn * inn - out * out;
            }
            self.cur.y[s] = sy;
            self.cur.yy[s] = syy;
        }
        true
    }

    /// Stores the finished block; false (and the block dropped) when the camera
    /// ring no longer holds its values.
    fn complete_block(&mut self) -> bool {
        if self.cur.n == 0.0 || self.cur.lo > self.cur.hi || !self.fill_y_sums() {
            self.cur.clear();
            return false;
        }
        // its Σxy was summed with the slots in reverse order (`add_products`): slot s
        // at n - 1 - s. Reversing the span symmetric about the middle that covers both
        // puts the held slots in place (the others hold nothing anyone reads)
        let n = self.n_lags;
        let p = self.cur.lo.min(n - 1 - self.cur.hi);
        self.cur.xy[p..n - p].reverse();
        let cap = self.blocks.len();
        // the block leaving the acquisition window, if one does: the oldest stored one
        // when the window is the whole store (it is swapped into `cur` below), else the
        // one `acq_blocks` back
        let mut evicted_from_acq = false;
        if self.count == cap {
            // the oldest block leaves the store (it left the acquisition window long ago
            // unless the window is the whole store)
            if self.acq_count == cap {
                evicted_from_acq = true;
                self.acq_count -= 1;
            }
            self.head = wrap(self.head + 1, cap);
            self.count -= 1;
        }
        let pos = wrap(self.head + self.count, cap);
        std::mem::swap(&mut self.blocks[pos], &mut self.cur);
        self.count += 1;
        self.acq_count += 1;
        self.since_rebuild += 1;
        let mut leaving = None;
        if self.acq_count > self.acq_blocks {
            self.acq_count = self.acq_blocks;
            leaving = Some(wrap(self.head + self.count - 1 - self.acq_blocks, cap));
        }
        if self.since_rebuild >= REBUILD_WINDOWS * self.acq_blocks {
            self.rebuild_acq();
        } else {
            // the window moves by one block: one pass subtracts the leaving block and
            // adds the new one
            match (evicted_from_acq, leaving) {
                (true, _) => self.acq.replace(&self.cur, &self.blocks[pos]),
                (false, Some(l)) => self.acq.replace(&self.blocks[l], &self.blocks[pos]),
                (false, None) => self.acq.add(&self.blocks[pos], 1.0),
            }
            self.acq.first_k = self.block(self.count - self.acq_count).first_k;
            self.acq.last_k = self.block(self.count - 1).last_k;
            self.acq_range();
        }
        self.cur.clear();
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct batch Pearson correlation of the same window, for comparison.
    fn batch(l: &[(i64, f64)], c: &dyn Fn(i64) -> f64, m: i64) -> f64 {
        let n = l.len() as f64;
        let (mut sx, mut sy, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(k, x) in l {
            let y = c(k - m);
            sx += x;
            sy += y;
            sxx += x * x;
            syy += y * y;
            sxy += x * y;
        }
        (sxy - sx * sy / n) / ((sxx - sx * sx / n) * (syy - sy * sy / n)).sqrt()
    }

    #[test]
    fn incremental_matches_batch_and_finds_lag() {
        let sig = |i: i64| ((i as f64) * 0.05).sin() + 0.5 * ((i as f64) * 0.013).cos();
        let true_lag = 7; // L[k] = C[k - 7]
        let mut c = Correlator::new(41, -20, 50, 6, 10, 4096);
        let mut hops = 0;
        for k in 0..2000i64 {
            c.push_cam(k, sig(k));
            c.push_lidar(k, sig(k - true_lag));
            while let s @ (Step::Added | Step::Hop | Step::Break) = c.step() {
                if s == Step::Hop {
                    hops += 1;
                }
            }
        }
        assert!(hops > 10);
        let w = c.acq();
        assert_eq!(c.acq_count(), 6);
        assert_eq!(c.count(), 10);
        let l: Vec<(i64, f64)> = (w.first_k..=w.last_k)
            .map(|k| (k, sig(k - true_lag)))
            .collect();
        assert_eq!(l.len(), 300);
        for slot in 0..41 {
            let m = -20 + slot as i64;
            let b = batch(&l, &sig, m);
            assert!(
                (w.ncc(slot) - b).abs() < 1e-9,
                "slot {slot}: {} vs {b}",
                w.ncc(slot)
            );
        }
        let best = (0..41)
            .max_by(|&a, &b| w.ncc(a).partial_cmp(&w.ncc(b)).unwrap())
            .unwrap();
        assert_eq!(-20 + best as i64, true_lag);
        // the stored blocks add up to the acquisition window
        let mut sum = Sums::new(41);
        for i in c.count() - 6..c.count() {
            sum.add(c.block(i), 1.0);
        }
        for slot in 0..41 {
            assert!((sum.xy[slot] - w.xy[slot]).abs() < 1e-6);
        }
    }

    #[test]
    fn gap_drops_the_unfinished_block_and_keeps_the_stored_ones() {
        let mut c = Correlator::new(11, -5, 10, 4, 8, 1024);
        for k in 0..200i64 {
            c.push_cam(k, (k as f64).sin());
            c.push_lidar(k, (k as f64).sin());
            while c.step() != Step::Idle {}
        }
        assert_eq!(c.acq_count(), 4);
        assert_eq!(c.count(), 8);
        let newest = c.block(7).last_k;
        c.break_lidar();
        let mut saw_break = false;
        for k in 300..335i64 {
            c.push_cam(k, (k as f64).cos());
            c.push_lidar(k, (k as f64).cos());
            loop {
                match c.step() {
                    Step::Idle => break,
                    Step::Break => saw_break = true,
                    _ => {}
                }
            }
        }
        assert!(saw_break);
        // blocks before the gap are still stored; new ones follow after it
        assert_eq!(c.count(), 8);
        assert!(c.block(0).last_k <= newest);
        assert!(c.block(7).first_k >= 300);
    }

    #[test]
    fn narrowing_the_active_range_keeps_blocks_with_their_own_range() {
        let mut c = Correlator::new(21, -10, 10, 4, 8, 1024);
        let feed = |c: &mut Correlator, r: std::ops::Range<i64>| {
            for k in r {
                c.push_cam(k, (k as f64 * 0.1).sin());
                c.push_lidar(k, (k as f64 * 0.1).sin());
                while c.step() != Step::Idle {}
            }
        };
        feed(&mut c, 0..100);
        assert_eq!((c.block(0).lo, c.block(0).hi), (0, 20));
        c.set_active(5, 15);
        // the window keeps its blocks; it holds what they all hold
        assert_eq!(c.acq_count(), 4);
        assert_eq!((c.acq().lo, c.acq().hi), (0, 20));
        feed(&mut c, 100..140);
        let n = c.count();
        assert_eq!((c.block(n - 1).lo, c.block(n - 1).hi), (5, 15));
        assert_eq!((c.block(0).lo, c.block(0).hi), (0, 20));
        assert_eq!((c.acq().lo, c.acq().hi), (5, 15));
        // forgetting the blocks makes every slot active again
        c.clear_blocks();
        assert_eq!(c.active(), (0, 20));
    }

    /// A block holds the slots that were active for all of it: moving the range
    /// mid-block keeps the unfinished block, which then holds their intersection,
    /// with the sums a correlator on that range throughout has.
    #[test]
    fn moving_the_active_range_mid_block_keeps_the_block_on_the_common_slots() {
        let feed = |c: &mut Correlator, r: std::ops::Range<i64>| feed_tones(c, r, 3);
        let mut moved = Correlator::new(21, -10, 10, 4, 8, 1024);
        let mut fixed = Correlator::new(21, -10, 10, 4, 8, 1024);
        moved.set_active(4, 16);
        fixed.set_active(6, 16);
        // index k pairs with camera index k + 6 at slot 4: the cursor is at 104
        feed(&mut moved, 0..110);
        feed(&mut fixed, 0..110);
        assert_eq!(moved.cursor(), Some(104));
        moved.set_active(6, 18); // mid-block (indices 100..=109)
        feed(&mut moved, 110..118);
        feed(&mut fixed, 110..118);
        let (m, f) = (
            moved.block(moved.count() - 1),
            fixed.block(fixed.count() - 1),
        );
        assert_eq!((m.first_k, m.last_k), (100, 109));
        assert_eq!((m.lo, m.hi), (6, 16));
        assert_eq!(m.n, f.n);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * (1.0 + b.abs());
        for s in 6..=16 {
            // Σxy summed alike; Σy and Σy² slide from the range's top slot
            assert_eq!(m.xy[s], f.xy[s], "slot {s}");
            assert!(close(m.y[s], f.y[s]) && close(m.yy[s], f.yy[s]), "slot {s}");
        }
        // the window holds the slots every block in it holds
        assert_eq!((moved.acq().lo, moved.acq().hi), (6, 16));
        for s in 6..=16 {
            assert!(
                (moved.acq().ncc(s) - fixed.acq().ncc(s)).abs() < 1e-12,
                "slot {s}"
            );
        }
        // a range moved off every slot of the unfinished block (110..=119) loses it
        let newest = |c: &Correlator| c.block(c.count() - 1).first_k;
        assert!(moved.cursor().is_some_and(|k| k > 110));
        moved.set_active(0, 3);
        feed(&mut moved, 118..135);
        assert_eq!(
            newest(&moved),
            100,
            "a block that holds no slot is not stored"
        );
        feed(&mut moved, 135..145);
        let b = moved.block(moved.count() - 1);
        assert_eq!((b.first_k, b.lo, b.hi), (120, 0, 3));
    }

    #[test]
    fn shifting_the_lag_range_keeps_each_blocks_lags() {
        let mut c = Correlator::new(21, -10, 10, 4, 8, 1024);
        for k in 0..100i64 {
            c.push_cam(k, (k as f64 * 0.1).sin());
            c.push_lidar(k, (k as f64 * 0.1).cos());
            while c.step() != Step::Idle {}
        }
        let before: Vec<f64> = c.block(0).xy.clone();
        c.shift_lags(6);
        assert_eq!(c.lag0(), -4);
        let b = c.block(0);
        assert_eq!((b.lo, b.hi), (0, 14));
        // new slot s holds what old slot s + 6 held (the same lag)
        for s in 0..=14 {
            assert_eq!(b.xy[s], before[s + 6]);
        }
        // the acquisition window keeps its blocks, valid where they all are
        assert_eq!(c.acq_count(), 4);
        assert_eq!((c.acq().lo, c.acq().hi), (0, 14));
        for s in 0..=14 {
            let r = c.acq().ncc(s);
            assert!(r.is_finite() && r.abs() <= 1.0);
        }
    }

    proptest::proptest! {
        /// Indices added several per step (as a LiDAR sample's grid values arrive) give
        /// the sums of adding them one per step, bit for bit: through block ends, a gap
        /// and a narrowed active range, both fed alike.
        #[test]
        fn indices_added_in_bursts_give_the_sums_of_one_at_a_time(
            bursts in proptest::collection::vec(1usize..23, 1..60),
            gap_at in 0usize..400,
            narrow in proptest::bool::ANY,
        ) {
            let sig = |k: i64| (k as f64 * 0.07).sin() + 0.4 * ((k * 7919) % 13) as f64 / 13.0;
            let mut one = Correlator::new(31, -15, 10, 4, 12, 1024);
            let mut burst = one.clone();
            if narrow {
                one.set_active(6, 24);
                burst.set_active(6, 24);
            }
            let mut k = 0i64;
            for n in bursts {
                for _ in 0..n {
                    for c in [&mut one, &mut burst] {
                        if k as usize == gap_at {
                            c.break_cam();
                        }
                        c.push_cam(k, sig(k));
                        c.push_lidar(k, sig(k - 4));
                    }
                    k += 1;
                }
                while one.step_up_to(1) != Step::Idle {}
                while burst.step() != Step::Idle {}
            }
            proptest::prop_assert_eq!(one.count(), burst.count());
            for i in 0..one.count() {
                let (a, b) = (one.block(i), burst.block(i));
                proptest::prop_assert_eq!((a.first_k, a.last_k, a.n), (b.first_k, b.last_k, b.n));
                proptest::prop_assert_eq!(a.sx.to_bits(), b.sx.to_bits());
                for s in a.lo..=a.hi {
                    proptest::prop_assert_eq!(a.xy[s].to_bits(), b.xy[s].to_bits());
                    proptest::prop_assert_eq!(a.yy[s].to_bits(), b.yy[s].to_bits());
                }
            }
            for s in one.acq().lo..=one.acq().hi {
                proptest::prop_assert_eq!(one.acq().xy[s].to_bits(), burst.acq().xy[s].to_bits());
            }
        }
    }

    proptest::proptest! {
        /// However the active lags move (any range, at any index, mid-block or not), every
        /// stored block holds on its slots the sums of its own indices at those lags, and
        /// the acquisition window those of its blocks on the slots they all hold.
        #[test]
        fn blocks_hold_exact_sums_on_their_slots_however_the_active_range_moves(
            moves in proptest::collection::vec((0usize..31, 0usize..31, 1usize..40), 1..30),
        ) {
            let sig = |k: i64| (k as f64 * 0.11).sin() + 0.3 * ((k * 7919) % 17) as f64 / 17.0;
            let lag0 = -15i64;
            let mut c = Correlator::new(31, lag0, 10, 4, 64, 2048);
            let mut k = 0i64;
            for (a, b, n) in moves {
                c.set_active(a.min(b), a.max(b));
                for _ in 0..n {
                    c.push_cam(k, sig(k));
                    c.push_lidar(k, sig(k - 3));
                    k += 1;
                    while c.step() != Step::Idle {}
                }
            }
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + b.abs());
            for i in 0..c.count() {
                let bl = c.block(i);
                proptest::prop_assert!(bl.lo <= bl.hi);
                proptest::prop_assert_eq!(bl.n, (bl.last_k - bl.first_k + 1) as f64);
                for s in bl.lo..=bl.hi {
                    let m = lag0 + s as i64;
                    let (mut xy, mut y, mut yy) = (0.0, 0.0, 0.0);
                    for j in bl.first_k..=bl.last_k {
                        let (xv, yv) = (sig(j - 3), sig(j - m));
                        xy += xv * yv;
                        y += yv;
                        yy += yv * yv;
                    }
                    proptest::prop_assert!(
                        close(bl.xy[s], xy) && close(bl.y[s], y) && close(bl.yy[s], yy),
                        "block {} ({}..={}) slot {}", i, bl.first_k, bl.last_k, s
                    );
                }
            }
            let w = c.acq();
            let first = c.count() - c.acq_count();
            proptest::prop_assert_eq!((w.lo, w.hi), c.slots_held(first, c.count()));
            for s in w.lo..=w.hi.min(30) {
                let want: f64 = (first..c.count()).map(|i| c.block(i).xy[s]).sum();
                proptest::prop_assert!(close(w.xy[s], want), "window slot {}", s);
            }
        }
    }

    proptest::proptest! {
        /// The branch-free range and the per-slot correlation give the textbook
        /// formula's values bit for bit, on any sums: too few pairs, a variance that is
        /// zero, negative or infinite by cancellation or overflow (one term or both),
        /// any bit pattern.
        #[test]
        fn ncc_range_is_ncc_slot_by_slot(
            n in proptest::prop_oneof![0.0..5.0f64, 3.0..1e6, proptest::num::f64::ANY],
            sx in proptest::prop_oneof![-1e3..1e3f64, proptest::num::f64::ANY],
            sxx in proptest::prop_oneof![0.0..1e6f64, proptest::num::f64::ANY],
            slots in proptest::collection::vec(
                (-1e3..1e3f64, -1e3..1e3f64, proptest::prop_oneof![0.0..1e6f64, proptest::num::f64::ANY]),
                3..40,
            ),
            lo_frac in 0.0..1.0f64,
        ) {
            let mut sums = Sums::new(slots.len());
            (sums.n, sums.sx, sums.sxx) = (n.floor(), sx, sxx);
            for (s, &(xy, y, yy)) in slots.iter().enumerate() {
                (sums.xy[s], sums.y[s], sums.yy[s]) = (xy, y, yy);
            }
            let hi = slots.len() - 1;
            let lo = (lo_frac * hi as f64) as usize;
            let mut out = vec![7.0; slots.len()];
            sums.ncc_range(lo, hi, &mut out);
            for (s, &v) in out.iter().enumerate() {
                if s < lo {
                    proptest::prop_assert_eq!(v, 7.0, "slot {} outside the range written", s);
                } else {
                    // the textbook form, with branches and `clamp`
                    let want = if sums.n < 3.0 {
                        0.0
                    } else {
                        let n = sums.n;
                        let vx = n * sums.sxx - sums.sx * sums.sx;
                        let vy = n * sums.yy[s] - sums.y[s] * sums.y[s];
                        let d = vx * vy;
                        // a ratio that overflows (or is NaN) says nothing either:
                        // 0, not a clamped ±1 (a numerator past f64::MAX over a
                        // finite root, found by this test with n ~ 3e307)
                        let r = (n * sums.xy[s] - sums.sx * sums.y[s]) / d.sqrt();
                        // and two variance terms negative by cancellation, whose
                        // product is positive, are no correlation either
                        if vx <= 0.0 || vy <= 0.0 || d <= 0.0 || !d.is_finite() || !r.is_finite() {
                            0.0
                        } else {
                            r.clamp(-1.0, 1.0)
                        }
                    };
                    for got in [v, sums.ncc(s)] {
                        proptest::prop_assert!(
                            got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                            "slot {}: {} against {}", s, got, want
                        );
                    }
                }
            }
        }
    }

    /// Feeds grid indices `r` of `L[k] = C[k - lag]` (a two-tone signal), stepping
    /// after each.
    fn feed_tones(c: &mut Correlator, r: std::ops::Range<i64>, lag: i64) {
        let sig = |k: i64| (k as f64 * 0.13).sin() + 0.2 * (k as f64 * 0.41).cos();
        for k in r {
            c.push_cam(k, sig(k));
            c.push_lidar(k, sig(k - lag));
            while c.step() != Step::Idle {}
        }
    }

    /// A lag range asked far beyond any real lag (a saturated conversion of an absurd
    /// offset, a huge shift) is clamped to ±`MAX_ABS_LAG0`, and stepping through data
    /// then never overflows (the tests run with overflow checks): it correlates nothing
    /// there, and comes back to real lags when asked.
    #[test]
    fn a_lag_range_beyond_the_limit_is_clamped_and_never_overflows() {
        let mut c = Correlator::new(21, i64::MIN, 10, 4, 8, 1024);
        assert_eq!(c.lag0(), -MAX_ABS_LAG0);
        feed_tones(&mut c, 0..50, 2);
        for (set, want) in [
            (i64::MAX, MAX_ABS_LAG0),
            (i64::MIN, -MAX_ABS_LAG0),
            (i64::MAX - 5, MAX_ABS_LAG0),
        ] {
            c.set_lag0(set);
            assert_eq!(c.lag0(), want);
            feed_tones(&mut c, 50..80, 2);
            c.pull_cursor_back();
            assert_eq!(c.count(), 0, "no data at lag {want}");
        }
        for (delta, want) in [
            (i64::MAX, MAX_ABS_LAG0),
            (i64::MIN, -MAX_ABS_LAG0),
            (i64::MIN, -MAX_ABS_LAG0),
            (3, 3 - MAX_ABS_LAG0),
            (i64::MAX, MAX_ABS_LAG0),
        ] {
            c.shift_lags(delta);
            assert_eq!(c.lag0(), want);
            feed_tones(&mut c, 80..100, 2);
            c.pull_cursor_back();
        }
        // back at real lags the data correlate again
        c.set_lag0(-10);
        c.restart_cursor();
        feed_tones(&mut c, 100..200, 2);
        assert!(c.count() > 0);
        let w = c.acq();
        assert!(w.ncc(12) > 0.99, "{}", w.ncc(12));
    }

    #[test]
    fn a_block_shifted_out_of_range_adds_nothing_to_the_window() {
        let feed = |c: &mut Correlator, r| feed_tones(c, r, 2);
        let mut c = Correlator::new(21, -10, 10, 4, 8, 1024);
        feed(&mut c, 0..100);
        c.shift_lags(15); // the old blocks keep slots 0..=5
        feed(&mut c, 100..120); // three new blocks (90..=119), all slots
        c.shift_lags(10); // the old blocks lose every slot, the new keep 0..=10
        let n = c.count();
        assert_eq!(c.acq_count(), 4);
        assert_eq!((c.acq().lo, c.acq().hi), (0, 10));
        assert_eq!(c.block(n - 4).n, 0.0);
        // the window is the new blocks alone
        let mut want = Sums::new(21);
        for i in n - 4..n {
            if c.block(i).n > 0.0 {
                want.add(c.block(i), 1.0);
            }
        }
        assert_eq!(want.n, 30.0);
        for s in 0..=10 {
            assert!((c.acq().ncc(s) - want.ncc(s)).abs() < 1e-12, "slot {s}");
        }
        assert_eq!(c.acq().n, want.n);
    }

    #[test]
    fn the_window_is_whole_again_once_the_blocks_before_a_shift_left_it() {
        let feed = |c: &mut Correlator, r| feed_tones(c, r, 3);
        let mut shifted = Correlator::new(21, -10, 10, 4, 8, 1024);
        feed(&mut shifted, 0..100);
        shifted.shift_lags(6);
        feed(&mut shifted, 100..125);
        // two new blocks and two from before the shift
        assert_eq!((shifted.acq().lo, shifted.acq().hi), (0, 14));
        feed(&mut shifted, 125..200);
        assert_eq!((shifted.acq().lo, shifted.acq().hi), (0, 20));
        // the same window of a correlator that had the new range all along
        let mut direct = Correlator::new(21, -4, 10, 4, 8, 1024);
        feed(&mut direct, 0..200);
        let (a, b) = (shifted.acq(), direct.acq());
        assert_eq!((a.first_k, a.last_k), (b.first_k, b.last_k));
        for s in 0..21 {
            assert!((a.ncc(s) - b.ncc(s)).abs() < 1e-9, "slot {s}");
        }
    }
}
