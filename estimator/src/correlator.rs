//! Incremental windowed Pearson cross-correlation over a fixed lag range.
//!
//! Both resampled, filtered streams are kept in index-tagged rings. For every
//! LiDAR grid index `k` (the cursor) the pairs `(L[k], C[k - m])` of every
//! active lag `m` are added to the sums of the current *block* (one hop long):
//! `O(lags)` per grid sample. Window totals are maintained per hop by adding
//! the completed block and subtracting the one that leaves the window, and are
//! rebuilt exactly from the blocks once per window length so rounding never
//! accumulates. A second, short window (the last few blocks) feeds step
//! detection. Nothing allocates after construction.
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
}

impl Sums {
    fn new(n_lags: usize) -> Self {
        Self {
            n: 0.0,
            sx: 0.0,
            sxx: 0.0,
            xy: vec![0.0; n_lags],
            y: vec![0.0; n_lags],
            yy: vec![0.0; n_lags],
            first_k: 0,
            last_k: 0,
        }
    }

    fn clear(&mut self) {
        self.n = 0.0;
        self.sx = 0.0;
        self.sxx = 0.0;
        self.xy.iter_mut().for_each(|v| *v = 0.0);
        self.y.iter_mut().for_each(|v| *v = 0.0);
        self.yy.iter_mut().for_each(|v| *v = 0.0);
    }

    fn add(&mut self, o: &Sums, sign: f64) {
        self.n += sign * o.n;
        self.sx += sign * o.sx;
        self.sxx += sign * o.sxx;
        for (a, b) in [
            (&mut self.xy, &o.xy),
            (&mut self.y, &o.y),
            (&mut self.yy, &o.yy),
        ] {
            for (p, q) in a.iter_mut().zip(b.iter()) {
                *p += sign * q;
            }
        }
    }

    /// Pearson correlation at lag slot `slot` (0 when undefined).
    #[inline]
    pub fn ncc(&self, slot: usize) -> f64 {
        let n = self.n;
        if n < 3.0 {
            return 0.0;
        }
        let (sxy, sy, syy) = (self.xy[slot], self.y[slot], self.yy[slot]);
        let vx = self.sxx - self.sx * self.sx / n;
        let vy = syy - sy * sy / n;
        let d = vx * vy;
        if d <= 0.0 || !d.is_finite() {
            return 0.0;
        }
        let r = (sxy - self.sx * sy / n) / d.sqrt();
        r.clamp(-1.0, 1.0)
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
        let n = ((b - a + 1).max(0) as usize).min(self.cap);
        &self.val[s..s + n]
    }
}

/// Result of one cursor step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Waiting for data.
    Idle,
    /// One grid index was added.
    Added,
    /// A block (hop) completed; the window totals are updated.
    Hop,
    /// Data were missing: the window was reset and the cursor jumped.
    Break,
}

/// The incremental correlator.
#[derive(Debug, Clone)]
pub struct Correlator {
    n_lags: usize,
    lag0: i64,
    hop_len: i64,
    window_blocks: usize,
    short_blocks: usize,
    lidar: Ring,
    cam: Ring,
    cursor: Option<i64>,
    cur: Sums,
    blocks: Vec<Sums>,
    /// Ring position of the oldest block in the window and count.
    head: usize,
    count: usize,
    long: Sums,
    short: Sums,
    since_rebuild: usize,
    active: (usize, usize),
}

impl Correlator {
    /// A correlator over `n_lags` lag slots starting at lag `lag0` (grid steps),
    /// hops of `hop_len` grid samples, windows of `window_blocks` and
    /// `short_blocks` blocks; rings able to hold `ring_len` grid samples.
    pub fn new(
        n_lags: usize,
        lag0: i64,
        hop_len: i64,
        window_blocks: usize,
        short_blocks: usize,
        ring_len: usize,
    ) -> Self {
        let n_lags = n_lags.max(3);
        let window_blocks = window_blocks.max(1);
        Self {
            n_lags,
            lag0,
            hop_len: hop_len.max(1),
            window_blocks,
            short_blocks: short_blocks.clamp(1, window_blocks),
            lidar: Ring::new(ring_len.max(n_lags * 2)),
            cam: Ring::new(ring_len.max(n_lags * 2)),
            cursor: None,
            cur: Sums::new(n_lags),
            blocks: (0..window_blocks).map(|_| Sums::new(n_lags)).collect(),
            head: 0,
            count: 0,
            long: Sums::new(n_lags),
            short: Sums::new(n_lags),
            since_rebuild: 0,
            active: (0, n_lags - 1),
        }
    }

    /// Number of lag slots.
    pub fn n_lags(&self) -> usize {
        self.n_lags
    }

    /// Lag (grid steps) of slot 0.
    pub fn lag0(&self) -> i64 {
        self.lag0
    }

    /// Moves the lag range (slot 0 at `lag0`); resets the window.
    pub fn set_lag0(&mut self, lag0: i64) {
        if lag0 != self.lag0 {
            self.lag0 = lag0;
            self.reset_window();
        }
    }

    /// Restricts the updated lag slots to `lo..=hi` (clamped); resets the window when changed.
    pub fn set_active(&mut self, lo: usize, hi: usize) {
        let hi = hi.min(self.n_lags - 1);
        let lo = lo.min(hi);
        if (lo, hi) != self.active {
            self.active = (lo, hi);
            self.reset_window();
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
    pub fn push_lidar(&mut self, k: i64, v: f64) {
        self.lidar.push(k, v);
    }

    /// Stores a filtered camera grid value.
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

    /// Window totals.
    pub fn long(&self) -> &Sums {
        &self.long
    }

    /// Short-window totals (the last `short_blocks` blocks).
    pub fn short(&self) -> &Sums {
        &self.short
    }

    /// Completed blocks in the window.
    pub fn blocks_in_window(&self) -> usize {
        self.count
    }

    /// Blocks in the window when it is full.
    pub fn window_blocks(&self) -> usize {
        self.window_blocks
    }

    /// Blocks in the short window when it is full.
    pub fn short_blocks(&self) -> usize {
        self.short_blocks
    }

    /// Empties the window (the cursor stays).
    pub fn reset_window(&mut self) {
        self.cur.clear();
        self.count = 0;
        self.long.clear();
        self.short.clear();
        self.since_rebuild = 0;
    }

    /// Resets the window and moves the cursor forward to `k` (never backward).
    pub fn skip_to(&mut self, k: i64) {
        self.reset_window();
        self.cursor = Some(self.cursor.map_or(k, |c| c.max(k)));
    }

    /// Keeps only the newest `keep` blocks in the window.
    pub fn truncate(&mut self, keep: usize) {
        if keep >= self.count {
            return;
        }
        let drop = self.count - keep;
        self.head = (self.head + drop) % self.window_blocks;
        self.count = keep;
        self.rebuild();
    }

    fn rebuild(&mut self) {
        self.long.clear();
        self.short.clear();
        let wb = self.window_blocks;
        for i in 0..self.count {
            let b = &self.blocks[(self.head + i) % wb];
            self.long.add(b, 1.0);
            if i + self.short_blocks >= self.count {
                self.short.add(b, 1.0);
            }
        }
        if self.count > 0 {
            self.long.first_k = self.blocks[self.head].first_k;
            self.long.last_k = self.blocks[(self.head + self.count - 1) % wb].last_k;
            let s0 = self.count.saturating_sub(self.short_blocks);
            self.short.first_k = self.blocks[(self.head + s0) % wb].first_k;
            self.short.last_k = self.long.last_k;
        }
        self.since_rebuild = 0;
    }

    /// Adds at most one grid index. Call until it returns [`Step::Idle`].
    pub fn step(&mut self) -> Step {
        let (Some(l0), Some(c0)) = (self.lidar.seg_start, self.cam.seg_start) else {
            return Step::Idle;
        };
        let m_lo = self.lag0 + self.active.0 as i64;
        let m_hi = self.lag0 + self.active.1 as i64;
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
        // the oldest camera value needed must still be in the ring
        // the oldest and newest camera values needed must be in the ring (segments are contiguous)
        let (Some(x), Some(_), Some(_)) = (
            self.lidar.get(k),
            self.cam.get(k - m_hi),
            self.cam.get(k - m_lo),
        ) else {
            self.skip_to(k + 1);
            return Step::Break;
        };
        if self.cur.n == 0.0 {
            self.cur.first_k = k;
        }
        self.cur.last_k = k;
        self.cur.n += 1.0;
        self.cur.sx += x;
        self.cur.sxx += x * x;
        let (lo, hi) = self.active;
        // slot s pairs x with camera index k - lag0 - s: the span, read backwards.
        // Only Σxy needs the pair; Σy and Σy² of a block are sliding sums over the
        // camera ring, filled in once when the block completes.
        let ys = self.cam.span(k - m_hi, k - m_lo);
        for (sxy, &y) in self.cur.xy[lo..=hi].iter_mut().zip(ys.iter().rev()) {
            *sxy += x * y;
        }
        self.cursor = Some(k + 1);
        if (k + 1).rem_euclid(self.hop_len) == 0 {
            self.complete_block();
            Step::Hop
        } else {
            Step::Added
        }
    }

    /// Σy and Σy² of the current block for every active slot: for slot `s` the
    /// camera indices `first_k - lag0 - s ..= last_k - lag0 - s`, a window that
    /// slides by one index per slot. Returns false if the ring no longer holds them.
    fn fill_y_sums(&mut self) -> bool {
        let (lo, hi) = self.active;
        let (k0, k1) = (self.cur.first_k, self.cur.last_k);
        let a_hi = k0 - self.lag0 - hi as i64;
        let b_lo = k1 - self.lag0 - lo as i64;
        if self.cam.get(a_hi).is_none() || self.cam.get(b_lo).is_none() {
            return false;
        }
        let ys = self.cam.span(a_hi, b_lo);
        let len = (k1 - k0 + 1) as usize;
        if ys.len() < len + (hi - lo) {
            return false;
        }
        let (mut sy, mut syy) = (0.0, 0.0);
        for &y in &ys[..len] {
            sy += y;
            syy += y * y;
        }
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

    fn complete_block(&mut self) {
        if !self.fill_y_sums() {
            self.reset_window();
            return;
        }
        let wb = self.window_blocks;
        if self.count == wb {
            // evict the oldest
            let old = std::mem::replace(&mut self.blocks[self.head], Sums::new(0));
            self.long.add(&old, -1.0);
            self.blocks[self.head] = old;
            self.head = (self.head + 1) % wb;
            self.count -= 1;
        }
        let pos = (self.head + self.count) % wb;
        std::mem::swap(&mut self.blocks[pos], &mut self.cur);
        self.cur.clear();
        self.count += 1;
        self.since_rebuild += 1;
        if self.since_rebuild >= wb {
            self.rebuild();
            return;
        }
        let nb = &self.blocks[pos];
        self.long.add(nb, 1.0);
        self.short.add(nb, 1.0);
        if self.count > self.short_blocks {
            let leaving = (self.head + self.count - 1 - self.short_blocks) % wb;
            let lb = std::mem::replace(&mut self.blocks[leaving], Sums::new(0));
            self.short.add(&lb, -1.0);
            self.blocks[leaving] = lb;
        }
        self.long.first_k = self.blocks[self.head].first_k;
        self.long.last_k = self.blocks[pos].last_k;
        let s0 = self.count.saturating_sub(self.short_blocks);
        self.short.first_k = self.blocks[(self.head + s0) % wb].first_k;
        self.short.last_k = self.long.last_k;
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
        let mut c = Correlator::new(41, -20, 50, 6, 2, 4096);
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
        let w = c.long();
        assert_eq!(c.blocks_in_window(), 6);
        let l: Vec<(i64, f64)> = (w.first_k..=w.last_k)
            .map(|k| (k, sig(k - true_lag)))
            .collect();
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
        assert!((c.short().n - 100.0).abs() < 1e-9);
    }

    #[test]
    fn gap_breaks_window() {
        let mut c = Correlator::new(11, -5, 10, 4, 2, 1024);
        for k in 0..200i64 {
            c.push_cam(k, (k as f64).sin());
            c.push_lidar(k, (k as f64).sin());
            while c.step() != Step::Idle {}
        }
        assert_eq!(c.blocks_in_window(), 4);
        c.break_lidar();
        let mut saw_break = false;
        for k in 300..320i64 {
            c.push_cam(k, 0.0);
            c.push_lidar(k, 0.0);
            loop {
                match c.step() {
                    Step::Idle => break,
                    Step::Break => saw_break = true,
                    _ => {}
                }
            }
        }
        assert!(saw_break);
        assert!(c.blocks_in_window() <= 2);
    }
}
