//! Frame times for a camera stamped at dequeue, recovered from the driver's
//! buffer sequence numbers.
//!
//! A V4L2 camera whose buffer stamps are not on `CLOCK_MONOTONIC` is stamped when
//! each buffer is dequeued ([`crate::v4l2::FrameStamps::Dequeue`]). That time is the
//! frame's plus the delivery latency, and the latency's variable part is not
//! small: a driver thread held up for 20 ms hands over two frames together. The
//! flow of such a pair is measured over the frame period but divided by the
//! dequeue times' interval, so its value is off by their ratio (two frames 8 ms
//! apart instead of 33: 4× too fast), and the sample lands late.
//!
//! The buffers' sequence numbers say which frames these are: frame `k` was taken
//! at `a + k P` for the camera's period `P`, and its dequeue time is that plus a
//! latency that is never negative. So every dequeue time is an upper bound of
//! its frame's line, and [`SequenceClock`] stamps frame `k` at the lowest of the
//! last [`WINDOW`] frames' dequeue times carried forward to `k` by the period,
//! its own included: a frame dequeued late takes its time from an earlier one
//! that was not, and a run that was never late keeps its own times. The period
//! is measured from the stamps themselves over up to [`BASELINE`] frames (4 s at
//! 30 Hz), so a camera whose rate is not its nominal one (auto-exposure in dim
//! light) is followed; until [`MIN_BASELINE`] frames have passed, the dequeue
//! times are used as they are.
//!
//! A restart (every stamp from the frame's own dequeue time again, the period
//! measured anew): a sequence number that repeats or goes back (a driver that does
//! not count: every frame is then stamped at its dequeue), a jump of more than
//! [`MAX_JUMP_NS`] of frames, and [`BEHIND_RUN`] frames in a row each dequeued
//! more than half a period after the line (the camera slowed down, or its latency
//! grew for good: the line is behind them all; a driver held up hands over at
//! most the buffers it holds late, 4 by default).
//!
//! Allocation-free: the windows are fixed arrays.
//!
//! ```
//! use vlsync_signature_cam::sequence_clock::SequenceClock;
//! const P: i64 = 33_333_333;
//! let mut clock = SequenceClock::new();
//! let mut last = 0;
//! for k in 0..200u32 {
//!     // every fourth frame is dequeued 20 ms late
//!     let late = if k % 4 == 3 { 20_000_000 } else { 1_000_000 };
//!     let t = clock.stamp(k, 5_000_000_000 + i64::from(k) * P + late);
//!     if k >= 100 {
//!         // past the first frames, the late ones are put back on the line
//!         assert!((t - (5_000_000_000 + i64::from(k) * P + 1_000_000)).abs() < 200_000, "{k}");
//!     }
//!     last = t;
//! }
//! assert!(last > 0);
//! ```
use vlsync_common::Nanos;

/// Frames whose dequeue times, carried forward, bound a frame's time: half a
/// second at 30 Hz. A frame later than every one of the last `WINDOW` keeps
/// their lowest bound.
pub const WINDOW: usize = 16;

/// Frames over which the period is measured, at most (4.3 s at 30 Hz).
pub const BASELINE: usize = 128;

/// Frames before the period is measured: the dequeue times are used as they are
/// until then.
pub const MIN_BASELINE: usize = 16;

/// The longest step of the sequence numbers (in time, at the measured period) that
/// keeps the line; a longer one restarts it. Two seconds: a camera that paused
/// that long may come back at another rate.
pub const MAX_JUMP_NS: Nanos = 2_000_000_000;

/// Frames in a row dequeued more than half a period after the line that restart
/// it (a quarter of a second at 30 Hz; twice the 4 buffers a driver holds by
/// default).
pub const BEHIND_RUN: usize = 8;

/// Why [`SequenceClock`] restarted its line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Restart {
    /// A sequence number equal to the last, or behind it.
    Repeated,
    /// A step of the sequence numbers longer than [`MAX_JUMP_NS`].
    Jump,
    /// [`BEHIND_RUN`] frames in a row dequeued more than half a period after the line.
    Behind,
}

/// Frame times from dequeue times and buffer sequence numbers (module docs).
#[derive(Debug, Clone)]
pub struct SequenceClock {
    last_seq: Option<u32>,
    /// The frames' index since the line's start: the sequence numbers' steps
    /// summed (wrapping `u32` steps).
    index: u64,
    /// The last `BASELINE` frames: (index, dequeue time).
    history: [(u64, Nanos); BASELINE],
    last_stamp: Option<Nanos>,
    /// Frames on the line (saturating).
    count: usize,
    period_ns: Option<f64>,
    behind_run: usize,
    last_restart: Option<Restart>,
    restarts: u64,
}

impl Default for SequenceClock {
    fn default() -> Self {
        Self::new()
    }
}

impl SequenceClock {
    /// A clock with no frame yet.
    pub fn new() -> Self {
        Self {
            last_seq: None,
            index: 0,
            history: [(0, 0); BASELINE],
            last_stamp: None,
            count: 0,
            period_ns: None,
            behind_run: 0,
            last_restart: None,
            restarts: 0,
        }
    }

    /// The measured frame period, ns, once [`MIN_BASELINE`] frames are on the line.
    pub fn period_ns(&self) -> Option<f64> {
        self.period_ns
    }

    /// Restarts of the line so far (not counting its first start).
    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// Why the line last restarted, taken once.
    pub fn take_restart(&mut self) -> Option<Restart> {
        self.last_restart.take()
    }

    /// The time of the frame with buffer sequence number `sequence`, dequeued when
    /// the clock read `dequeue_ns`: never later than `dequeue_ns`, never earlier
    /// than the last frame's time.
    pub fn stamp(&mut self, sequence: u32, dequeue_ns: Nanos) -> Nanos {
        if let Some(last) = self.last_seq {
            let step = sequence.wrapping_sub(last);
            // a step in the upper half of u32 is one that went back
            let why = if step == 0 || step > u32::MAX / 2 {
                Some(Restart::Repeated)
            } else {
                let span = self.period_ns.map_or(0.0, |p| f64::from(step) * p);
                (span > MAX_JUMP_NS as f64).then_some(Restart::Jump)
            };
            match why {
                Some(why) => self.restart(why),
                None => self.index += u64::from(step),
            }
        }
        self.last_seq = Some(sequence);
        let mut t = dequeue_ns;
        if let Some(p) = self.period_ns {
            for back in 1..=self.count.min(WINDOW - 1) {
                let (i, d) = self.history[(self.count - back) % BASELINE];
                let carried = (self.index - i) as f64 * p;
                t = t.min(d.saturating_add(carried.round() as Nanos));
            }
            if dequeue_ns.saturating_sub(t) as f64 > p / 2.0 {
                self.behind_run += 1;
            } else {
                self.behind_run = 0;
            }
        }
        // the frames keep their order: a dequeue time is never behind the last
        // frame's, but a bound carried by a period measured long could be
        if let Some(last) = self.last_stamp {
            t = t.max(last);
        }
        self.last_stamp = Some(t);
        self.history[self.count % BASELINE] = (self.index, dequeue_ns);
        self.count = self.count.saturating_add(1);
        self.period_ns = self.measure();
        if self.behind_run >= BEHIND_RUN {
            // the next frame starts the line again from its own dequeue time
            self.restart(Restart::Behind);
            self.last_seq = Some(sequence);
        }
        t
    }

    fn restart(&mut self, why: Restart) {
        self.count = 0;
        self.index = 0;
        self.period_ns = None;
        self.behind_run = 0;
        self.last_seq = None;
        self.last_restart = Some(why);
        self.restarts = self.restarts.saturating_add(1);
    }

    /// The period of the frames kept: the slope between the lowest dequeue time
    /// of their older half and of their newer half, each lowest against the line
    /// of the period known before (the raw slope from the oldest to the newest at
    /// first), measured twice. A late frame is never the lowest; a floor of
    /// latency reached once in each half gives the period to that floor's spread
    /// over half the frames kept.
    fn measure(&self) -> Option<f64> {
        if self.count < MIN_BASELINE {
            return None;
        }
        let n = self.count.min(BASELINE);
        let first = self.count - n;
        let at = |j: usize| self.history[(first + j) % BASELINE];
        let (i0, d0) = at(0);
        // (frames, ns) since the oldest kept: small numbers, exact in f64
        let rel = |j: usize| {
            let (i, d) = at(j);
            ((i - i0) as f64, d.saturating_sub(d0) as f64)
        };
        let lowest = |range: std::ops::Range<usize>, p: f64| {
            range
                .map(rel)
                .min_by(|a, b| (a.1 - p * a.0).total_cmp(&(b.1 - p * b.0)))
        };
        let (fk, fd) = rel(n - 1);
        let mut p = self.period_ns.unwrap_or(fd / fk);
        for _ in 0..2 {
            let (a, b) = (lowest(0..n / 2, p)?, lowest(n / 2..n, p)?);
            p = (b.1 - a.1) / (b.0 - a.0);
        }
        (p.is_finite() && p > 0.0).then_some(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const P: Nanos = 33_333_333;
    const T0: Nanos = 1_000_000_000_000;
    const MS: Nanos = 1_000_000;

    fn truth(k: u32) -> Nanos {
        T0 + i64::from(k) * P
    }

    #[test]
    fn frames_delivered_together_are_put_back_on_their_line() {
        let mut c = SequenceClock::new();
        let mut worst_late = 0;
        for k in 0..300u32 {
            // a driver held up 20-60 ms every 10th frame hands over the frames it held
            let lat = match k % 10 {
                7 => 40 * MS,
                8 => 7 * MS,
                _ => 2 * MS,
            };
            let t = c.stamp(k, truth(k) + lat);
            if k >= 60 {
                worst_late = worst_late.max((t - truth(k) - 2 * MS).abs());
            }
        }
        assert!(worst_late < MS / 5, "{worst_late} ns off the line");
        assert!((c.period_ns().unwrap() - P as f64).abs() < 20.0);
        assert_eq!(c.restarts(), 0);
    }

    #[test]
    fn dropped_frames_keep_their_place() {
        let mut c = SequenceClock::new();
        let mut k = 0u32;
        let mut got = Vec::new();
        while k < 400 {
            let lat = if k.is_multiple_of(5) { 25 * MS } else { 3 * MS };
            got.push((k, c.stamp(k, truth(k) + lat)));
            // the driver skips a frame every 7th
            k += if k.is_multiple_of(7) { 2 } else { 1 };
        }
        for &(k, t) in got.iter().filter(|(k, _)| *k > 100) {
            assert!(
                (t - truth(k) - 3 * MS).abs() < MS / 5,
                "frame {k}: {}",
                t - truth(k)
            );
        }
    }

    #[test]
    fn a_slower_camera_restarts_the_line_and_is_followed() {
        let mut c = SequenceClock::new();
        for k in 0..200u32 {
            c.stamp(k, truth(k) + 2 * MS);
        }
        // auto-exposure halves the rate; the sequence counts on
        let base = truth(200);
        let mut last = 0;
        for j in 0..300u32 {
            let t = c.stamp(200 + j, base + i64::from(j) * 2 * P + 2 * MS);
            last = t - (base + i64::from(j) * 2 * P + 2 * MS);
        }
        assert_eq!(c.restarts(), 1);
        assert_eq!(c.take_restart(), Some(Restart::Behind));
        assert_eq!(c.take_restart(), None);
        assert!(last.abs() < MS / 10, "{last}");
        assert!((c.period_ns().unwrap() - 2.0 * P as f64).abs() < 100.0);
    }

    #[test]
    fn a_driver_that_does_not_count_gets_its_dequeue_times() {
        let mut c = SequenceClock::new();
        for k in 0..50u32 {
            let d = truth(k) + if k % 3 == 0 { 15 * MS } else { MS };
            assert_eq!(c.stamp(0, d), d);
        }
        assert_eq!(c.take_restart(), Some(Restart::Repeated));
        assert_eq!(c.period_ns(), None);
    }

    #[test]
    fn a_long_pause_restarts_and_the_sequence_wraps() {
        let mut c = SequenceClock::new();
        let start = u32::MAX - 100;
        for j in 0..200u32 {
            c.stamp(start.wrapping_add(j), truth(j) + MS);
        }
        assert_eq!(c.restarts(), 0, "the wrap is a step of one");
        let d = truth(199 + 90) + MS;
        assert_eq!(c.stamp(start.wrapping_add(199 + 90), d), d);
        assert_eq!(c.take_restart(), Some(Restart::Jump));
    }

    #[test]
    fn jittered_dequeues_give_even_intervals() {
        // a latency floor of 2 ms, an exponential tail of mean 3 ms, and a 30 ms
        // hold-up every 50 frames (a xorshift for the draws)
        let mut c = SequenceClock::new();
        let mut x = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut prev, mut worst_interval, mut worst_dequeue) = (None, 0.0f64, 0.0f64);
        let (mut sq, mut sq_dequeue, mut n) = (0.0, 0.0, 0.0);
        for k in 0..2000u32 {
            let tail = -3.0e6 * (1.0 - uniform()).ln();
            let lat = 2 * MS + tail as i64 + if k.is_multiple_of(50) { 30 * MS } else { 0 };
            let d = truth(k) + lat;
            let t = c.stamp(k, d);
            if let Some((pd, pt)) = prev.filter(|_| k > 200) {
                worst_interval = worst_interval.max(((t - pt) as f64 / P as f64 - 1.0).abs());
                worst_dequeue = worst_dequeue.max(((d - pd) as f64 / P as f64 - 1.0).abs());
                sq += ((t - pt) as f64 / P as f64 - 1.0).powi(2);
                sq_dequeue += ((d - pd) as f64 / P as f64 - 1.0).powi(2);
                n += 1.0;
            }
            prev = Some((d, t));
        }
        let (rms, rms_dequeue) = ((sq / n).sqrt(), (sq_dequeue / n).sqrt());
        eprintln!("interval error: stamps rms {rms:.4} worst {worst_interval:.4}; dequeue rms {rms_dequeue:.4} worst {worst_dequeue:.4}");
        assert!(worst_dequeue > 0.5, "{worst_dequeue}");
        assert!(worst_interval < 0.06, "{worst_interval}");
        assert!(rms < rms_dequeue / 10.0, "{rms} against {rms_dequeue}");
        assert_eq!(c.restarts(), 0);
    }

    proptest! {
        #[test]
        fn stamps_never_pass_their_dequeue_nor_go_back(
            lats in proptest::collection::vec(0i64..80_000_000, 1..400),
            steps in proptest::collection::vec(0u32..4, 1..400),
        ) {
            let mut c = SequenceClock::new();
            let (mut seq, mut k, mut prev_t, mut prev_d) = (7u32, 0i64, i64::MIN, i64::MIN);
            for (i, lat) in lats.iter().enumerate() {
                let step = steps[i % steps.len()];
                seq = seq.wrapping_add(step);
                k += i64::from(step.max(1));
                // dequeue times never go back
                let d = (T0 + k * P + lat).max(prev_d);
                let t = c.stamp(seq, d);
                prop_assert!(t <= d);
                prop_assert!(t >= prev_t);
                prev_t = t;
                prev_d = d;
            }
        }
    }
}
