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
//! last [`REACH`] frames' dequeue times carried forward to `k` by the period (or as
//! many as the driver's buffers, if more: a hold-up delays at most those), its own
//! included: a frame dequeued late takes its time from an earlier one that was not.
//! The period is measured from the dequeue times over up to [`BASELINE`] frames
//! (4 s at 30 Hz: the lowest of each half), so a camera whose rate is not its
//! nominal one is followed; until [`MIN_BASELINE`] frames have passed, the dequeue
//! times are used as they are, and the reach grows with the frames measured (an
//! eighth of them), so that a young line's period error stays small against the
//! jitter. A period measured short (a camera that slowed a little) carries every
//! bound early: the line is moved up to the lowest of its frames' lateness within
//! the reach (0 at the right period, where the floor's frames meet their bound),
//! and [`ABOVE_FLOOR_RUN`] frames in a row off the floor have the period measured
//! again from the newest [`REMEASURE_FRAMES`] (a 2 % slowdown: stamps at most
//! 3.9 ms early for half a second, where the period carried 15 frames unchecked put
//! them 9.7 ms early).
//!
//! A restart (every stamp from the frame's own dequeue time again, the period
//! measured anew): a sequence number that repeats or goes back (a driver that does
//! not count: every frame is then stamped at its dequeue), a jump of more than
//! [`MAX_JUMP_NS`] of frames, and [`BEHIND_RUN`] frames in a row (twice the
//! driver's buffers, if more) each dequeued more than half a period after the line
//! (the camera slowed down, or its latency grew for good: the line is behind them
//! all; a driver held up hands over at most the buffers it holds late).
//!
//! Two quicker restarts read the dequeue intervals, each against its frames' step
//! (the sequence numbers' difference) at the period. A frame's interval alone
//! cannot say whether the camera paused or slowed down (the frame is on time, the
//! line behind it) or the frame waited in a buffer (a driver held up, an
//! application kept from its dequeues by a busy CPU: the line is right), so the
//! frames after it decide: a frame that waited is followed by frames that waited
//! behind it (dequeued back to back, early for their step) or by the first fresh
//! one after the frames the driver dropped (early by many steps, back near the
//! line), while after a pause or at a slower rate the frames come their period
//! apart again, or slower still. One frame of either kind can be a hold-up anew
//! (jitter, then a busy moment), so each rule asks for a run:
//!
//! * [`Restart::Slower`]: [`SLOW_RUN`] intervals in a row each more than half a
//!   period longer than their step (30 to 15 Hz with the sequence counting on: the
//!   frames come two periods apart, and the line, carried one period a frame, put
//!   8 of them up to 8 periods early before [`BEHIND_RUN`] saw it; now 2, up to 2
//!   periods early).
//! * [`Restart::Pause`]: an interval longer than its step by more than the
//!   driver's buffers last ([`SequenceClock::with_buffers`]; more than a busy
//!   moment delays a dequeue while the application keeps up), then [`PAUSE_RUN`]
//!   frames in a row still more than half that behind the line and not early for
//!   their step (less than half a period short of it): a camera that paused with
//!   its sequence counting only the frames it sent (uvcvideo). The line put 8
//!   frames after a 5 s pause 5 s early; now the first 2 (3 when the first was
//!   itself delivered late, which makes the next look early for its step).
//!
//! The frame that completes the run is stamped at its own dequeue time, and the
//! line starts again from it. The rules assume an application that, when it finds
//! frames waiting, dequeues the next within half a period (its work per frame under
//! that): a slower one reads its backlog after a long hold-up as frames a period
//! apart, a pause.
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

/// Dequeue intervals in a row, each more than half a period longer than its
/// frames' step, that restart the line ([`Restart::Slower`]). Three: two come of a
/// frame late in the latency's tail followed by a dequeue a busy moment held up
/// (not rare); a camera that slowed keeps coming late, a hold-up does not.
pub const SLOW_RUN: usize = 3;

/// Frames in a row after an interval longer than the driver's buffers last, each
/// still more than half that behind the line and not early for its step, that
/// restart it ([`Restart::Pause`]). Two: one such frame comes of a frame held up
/// anew right after a hold-up's backlog.
pub const PAUSE_RUN: usize = 2;

/// Frames in a row dequeued more than half a period after the line that restart
/// it (a quarter of a second at 30 Hz; twice the 4 buffers a driver holds by
/// default).
pub const BEHIND_RUN: usize = 8;

/// How far after the line a frame may be dequeued and still count as at the
/// latency floor: 1 ms, or a 32nd of the period if longer.
pub const FLOOR_SLACK_NS: f64 = 1e6;

/// How many frames back a dequeue time is carried, at least: a hold-up delays at
/// most the buffers the driver holds (4 by default; more buffers carry further,
/// [`SequenceClock::with_buffers`], up to `WINDOW - 1`). A period off by δ carries
/// a bound off by up to this many δ, so it stays short: 8 frames.
pub const REACH: u64 = 8;

/// Frames in a row none of which is at the latency floor ([`FLOOR_SLACK_NS`]) after
/// which the period is taken as short (a camera that slowed by less than the
/// [`BEHIND_RUN`] rule sees) and measured again from the newest
/// [`REMEASURE_FRAMES`] alone. A step up of the latency leaves at most as many such
/// frames as the reach (the driver's buffers, at most 15), so this tells the two
/// apart.
pub const ABOVE_FLOOR_RUN: usize = WINDOW;

/// Frames a short period is measured again from ([`ABOVE_FLOOR_RUN`]).
pub const REMEASURE_FRAMES: u64 = 2 * WINDOW as u64;

/// Why [`SequenceClock`] restarted its line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Restart {
    /// A sequence number equal to the last, or behind it.
    Repeated,
    /// A step of the sequence numbers longer than [`MAX_JUMP_NS`].
    Jump,
    /// [`BEHIND_RUN`] frames in a row (or twice the driver's buffers, if more:
    /// [`SequenceClock::behind_limit`]) dequeued more than half a period after the line.
    Behind,
    /// [`SLOW_RUN`] dequeue intervals in a row each more than half a period longer
    /// than their frames' step: the camera slowed down (module docs).
    Slower,
    /// A dequeue interval longer than its frames' step by more than the driver's
    /// buffers last, then [`PAUSE_RUN`] frames still far behind the line and not
    /// early for their step: the camera paused (module docs).
    Pause,
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
    /// Frames on the line (`u64`: no saturation on 32-bit targets within years).
    count: u64,
    period_ns: Option<f64>,
    /// Frames in a row more than half a period after the line.
    behind_run: usize,
    /// Frames in a row more than [`FLOOR_SLACK_NS`] after the line: none of them at
    /// the latency floor, so the period is short (the camera slowed a little).
    above_floor_run: usize,
    /// The `behind_run` that restarts the line.
    behind_limit: usize,
    /// The last `WINDOW` frames' dequeue times after their bound (ring by `count`).
    residuals: [Nanos; WINDOW],
    /// How many frames back a dequeue time is carried ([`REACH`], or the driver's
    /// buffers if more, at most `WINDOW - 1`).
    reach: u64,
    /// The driver's buffers (at least 1): a dequeue interval longer than its step by
    /// more than these last is a pause of the camera or of the application (a busy
    /// CPU), which the next frames tell apart.
    buffers: u64,
    /// Dequeue intervals in a row each more than half a period longer than their
    /// frames' step.
    slow_run: usize,
    /// After an interval longer than its step by more than the buffers last: the
    /// frame before it (index, dequeue time), the last known on the line, until a
    /// frame decides between a pause and a hold-up ([`Restart::Pause`]).
    pause_from: Option<(u64, Nanos)>,
    /// Frames in a row since `pause_from` neither back near the line nor early for
    /// their step.
    pause_run: usize,
    last_restart: Option<Restart>,
    restarts: u64,
    remeasures: u64,
}

impl Default for SequenceClock {
    fn default() -> Self {
        Self::new()
    }
}

impl SequenceClock {
    /// A clock with no frame yet, for a driver holding the default 4 buffers.
    pub fn new() -> Self {
        Self::with_buffers(4)
    }

    /// A clock with no frame yet, for a driver holding `buffers` buffers: a driver
    /// held up hands over that many late frames in a row, so the line restarts only
    /// after twice as many ([`BEHIND_RUN`] at least).
    pub fn with_buffers(buffers: u32) -> Self {
        let twice = usize::try_from(buffers)
            .unwrap_or(usize::MAX)
            .saturating_mul(2);
        Self {
            last_seq: None,
            index: 0,
            history: [(0, 0); BASELINE],
            last_stamp: None,
            count: 0,
            period_ns: None,
            behind_run: 0,
            above_floor_run: 0,
            behind_limit: twice.max(BEHIND_RUN),
            residuals: [0; WINDOW],
            reach: u64::from(buffers).clamp(REACH, WINDOW as u64 - 1),
            buffers: u64::from(buffers.max(1)),
            slow_run: 0,
            pause_from: None,
            pause_run: 0,
            last_restart: None,
            restarts: 0,
            remeasures: 0,
        }
    }

    /// Times the period was measured again from the newest frames only, the line
    /// kept (a small slowdown: [`ABOVE_FLOOR_RUN`]).
    pub fn remeasures(&self) -> u64 {
        self.remeasures
    }

    fn slot(&self, n: u64) -> usize {
        (n % BASELINE as u64) as usize
    }

    /// The measured frame period, ns, once [`MIN_BASELINE`] frames are on the line.
    pub fn period_ns(&self) -> Option<f64> {
        self.period_ns
    }

    /// Restarts of the line so far (not counting its first start).
    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// Frames in a row dequeued more than half a period after the line that
    /// restart it ([`Restart::Behind`]): [`BEHIND_RUN`], or twice the driver's
    /// buffers if more.
    pub fn behind_limit(&self) -> usize {
        self.behind_limit
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
                self.period_ns
                    .and_then(|p| self.interval_restart(step, dequeue_ns, p))
            };
            match why {
                Some(why) => self.restart(why),
                None => self.index += u64::from(step),
            }
        }
        self.last_seq = Some(sequence);
        let mut t = dequeue_ns;
        if let Some(p) = self.period_ns {
            // a bound carried k frames by a period off by δ is off by kδ: the reach
            // grows with the frames the period was measured over (an eighth of
            // them), so that a young line's error stays a fraction of the jitter
            let reach = (self.count / 8).min(self.reach);
            for back in 1..=reach {
                let (i, d) = self.history[self.slot(self.count - back)];
                let carried = (self.index - i) as f64 * p;
                t = t.min(d.saturating_add(carried.round() as Nanos));
            }
            let late = dequeue_ns.saturating_sub(t) as f64;
            self.behind_run = if late > p / 2.0 {
                self.behind_run + 1
            } else {
                0
            };
            let slack = FLOOR_SLACK_NS.max(p / 32.0);
            self.above_floor_run = if late > slack {
                self.above_floor_run + 1
            } else {
                0
            };
        }
        // the line rests on the latency floor: when every frame within the reach
        // came after its bound (a period measured short, as a camera that slowed a
        // little has until it is measured again, carries the bounds early), the line
        // is moved up to the nearest of them. At the right period the floor's frames
        // meet their bound, and this moves nothing
        // (the reach's frames and this one: a hold-up's late frames, at most the
        // reach, always have a floor frame among them)
        let rounds = usize::try_from(self.count.min(self.reach)).unwrap_or(0);
        let mut floor = dequeue_ns.saturating_sub(t);
        for back in 1..=rounds as u64 {
            floor = floor.min(self.residuals[((self.count - back) % WINDOW as u64) as usize]);
        }
        self.residuals[(self.count % WINDOW as u64) as usize] = dequeue_ns.saturating_sub(t);
        t = t.saturating_add(floor);
        // the frames keep their order: a dequeue time is never behind the last
        // frame's, but a bound carried by a period measured long could be
        if let Some(last) = self.last_stamp {
            t = t.max(last);
        }
        self.last_stamp = Some(t);
        let at = self.slot(self.count);
        self.history[at] = (self.index, dequeue_ns);
        self.count += 1;
        if self.behind_run >= self.behind_limit {
            // the next frame starts the line again from its own dequeue time
            self.restart(Restart::Behind);
            self.last_seq = Some(sequence);
        } else if self.above_floor_run >= ABOVE_FLOOR_RUN {
            self.keep_newest(REMEASURE_FRAMES);
        }
        self.period_ns = self.measure();
        t
    }

    /// The restart a frame `step` frames after the last one, dequeued at
    /// `dequeue_ns`, calls for at the period `p`, before it is stamped: a jump in
    /// the sequence, or its interval with the one before (module docs).
    fn interval_restart(&mut self, step: u32, dequeue_ns: Nanos, p: f64) -> Option<Restart> {
        let span = f64::from(step) * p;
        if span > MAX_JUMP_NS as f64 {
            return Some(Restart::Jump);
        }
        let last = self.history[self.slot(self.count.checked_sub(1)?)];
        let excess = dequeue_ns.saturating_sub(last.1) as f64 - span;
        self.slow_run = if excess > p / 2.0 {
            self.slow_run + 1
        } else {
            0
        };
        if self.slow_run >= SLOW_RUN {
            // frames late one after the other: not a hold-up, whose late frame is
            // followed by early ones, and not jitter, which does not climb half a
            // period three times running
            return Some(Restart::Slower);
        }
        let buffers = self.buffers as f64 * p;
        if let Some((i, d)) = self.pause_from {
            // how far behind the line this frame is, carried from the dequeue of the
            // last frame known on it (that frame's own latency included)
            let index = self.index + u64::from(step);
            let behind = dequeue_ns.saturating_sub(d) as f64 - (index - i) as f64 * p;
            if behind <= buffers / 2.0 {
                // back near the line: the long interval was a wait in a buffer, the
                // frames after it drained the backlog
                self.pause_from = None;
            } else if excess >= -p / 2.0 {
                // still far behind, and not dequeued back to back with the last
                // frame (nor early after dropped ones), as the frames a hold-up kept
                // waiting are: the frames come their period apart again, behind the
                // line by the pause. Twice in a row: one frame held up anew looks so
                self.pause_run += 1;
                if self.pause_run >= PAUSE_RUN {
                    return Some(Restart::Pause);
                }
            } else {
                self.pause_run = 0;
            }
        } else if excess > buffers {
            // longer than the driver's buffers could hold a frame back while the
            // application keeps up: a pause, or the application was kept from its
            // dequeues; the next frames tell
            self.pause_from = Some(last);
            self.pause_run = 0;
        }
        None
    }

    /// Forgets all but the newest `n` frames (the period is then measured over them
    /// alone, and the reach shrinks with them).
    fn keep_newest(&mut self, n: u64) {
        if self.count <= n {
            return;
        }
        let first = self.count - n;
        let mut kept = [(0, 0); BASELINE];
        for (j, k) in kept.iter_mut().zip(first..self.count) {
            *j = self.history[self.slot(k)];
        }
        // the lateness ring too, so that it stays indexed by the frames' count
        let w = WINDOW as u64;
        let mut residuals = [0; WINDOW];
        for k in self.count.saturating_sub(w).max(first)..self.count {
            residuals[((k - first) % w) as usize] = self.residuals[(k % w) as usize];
        }
        self.history = kept;
        self.residuals = residuals;
        self.count = n;
        self.above_floor_run = 0;
        self.remeasures = self.remeasures.saturating_add(1);
    }

    fn restart(&mut self, why: Restart) {
        self.count = 0;
        self.index = 0;
        self.period_ns = None;
        self.behind_run = 0;
        self.above_floor_run = 0;
        self.slow_run = 0;
        self.pause_from = None;
        self.pause_run = 0;
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
        if self.count < MIN_BASELINE as u64 {
            return None;
        }
        let n = self.count.min(BASELINE as u64) as usize;
        let first = self.count - n as u64;
        let at = |j: usize| self.history[self.slot(first + j as u64)];
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
        let (mut last, mut early) = (0, vec![]);
        for j in 0..300u32 {
            let d = base + i64::from(j) * 2 * P + 2 * MS;
            let t = c.stamp(200 + j, d);
            last = t - d;
            if d - t > P / 2 {
                early.push((j, d - t));
            }
        }
        // the first two frames two periods apart are stamped a period apart, on the
        // old line; the third restarts the line (where the old line carried 8 of
        // them a period a frame, 264 ms early at the last)
        assert_eq!(early, [(1, P), (2, 2 * P)]);
        assert_eq!(c.restarts(), 1);
        assert_eq!(c.take_restart(), Some(Restart::Slower));
        assert_eq!(c.take_restart(), None);
        assert!(last.abs() < MS / 10, "{last}");
        assert!((c.period_ns().unwrap() - 2.0 * P as f64).abs() < 100.0);
    }

    #[test]
    fn a_camera_slowing_by_a_fifth_restarts_behind_the_line() {
        // 30 to 25 Hz: each interval 7 ms longer than its period, short of the half
        // period the interval rules see; the line falls behind until BEHIND_RUN
        // frames in a row are more than half a period after it
        let mut c = SequenceClock::new();
        for k in 0..200u32 {
            c.stamp(k, truth(k) + 2 * MS);
        }
        let slow = P * 6 / 5;
        let base = truth(200);
        let mut last = 0;
        for j in 0..300u32 {
            let d = base + i64::from(j) * slow + 2 * MS;
            last = c.stamp(200 + j, d) - d;
        }
        assert_eq!(c.take_restart(), Some(Restart::Behind));
        assert_eq!(c.restarts(), 1);
        assert!(last.abs() < MS / 10, "{last}");
        assert_eq!(c.behind_limit(), BEHIND_RUN);
        assert_eq!(SequenceClock::with_buffers(12).behind_limit(), 24);
    }

    #[test]
    fn a_camera_that_paused_is_stamped_on_its_own_from_the_third_frame_after() {
        // uvcvideo counts only the frames the camera sent: a 5 s pause is a step of
        // one. The line carried 8 frames after it 5 s early
        for buffers in [2, 4, 12] {
            // the first frame after the pause on time, then held up 30 ms itself
            // (its successor then comes early for its step, as after a hold-up, and
            // the two after that decide)
            for (held, expect) in [(0, &[0u32, 1][..]), (30 * MS, &[0, 1, 2])] {
                let mut c = SequenceClock::with_buffers(buffers);
                let mut lat = latencies();
                for k in 0..300u32 {
                    c.stamp(k, truth(k) + lat(k));
                }
                let resumed = truth(300) + 5_000_000_000;
                let mut early = vec![];
                for j in 0..100u32 {
                    let due = resumed + i64::from(j) * P;
                    let t = c.stamp(300 + j, due + 2 * MS + if j == 0 { held } else { 0 });
                    if due - t > P / 2 {
                        early.push(j);
                    }
                }
                assert_eq!(early, expect, "{buffers} buffers, held {held}");
                assert_eq!(c.take_restart(), Some(Restart::Pause));
                assert_eq!(c.restarts(), 1);
            }
        }
    }

    #[test]
    fn an_application_held_up_past_its_buffers_keeps_the_line() {
        // a busy CPU keeps the application from its dequeues for 300 ms: the frames
        // in the driver's buffers (all but the one the application holds) wait and
        // are dequeued back to back, its work per frame apart (8 or 15 ms), the
        // frames after them dropped until a buffer comes back; the fresh ones after
        // are dequeued once the backlog is done. The long interval is no pause
        for (buffers, work) in [(2u32, 8 * MS), (4, 8 * MS), (4, 15 * MS)] {
            let mut c = SequenceClock::with_buffers(buffers);
            let mut lat = latencies();
            let mut k = 0u32;
            while k < 300 {
                c.stamp(k, truth(k) + lat(k));
                k += 1;
            }
            let stalled_to = truth(k - 1) + 300 * MS;
            let mut d = stalled_to;
            for _ in 0..buffers - 1 {
                let t = c.stamp(k, d);
                assert!((t - truth(k) - 2 * MS).abs() < MS, "{buffers}: frame {k}");
                k += 1;
                d += work;
            }
            // the interval was long enough to be a pause: the next frames decided
            assert!(c.pause_from.is_some(), "{buffers}");
            // the first frame captured after a buffer came back
            k = (k..).find(|&f| truth(f) > stalled_to).unwrap();
            for _ in 0..100 {
                d = (truth(k) + lat(k)).max(d + work);
                let t = c.stamp(k, d);
                // on the line, not restarted from the late dequeues (a line restarted
                // from them is stamped late by the backlog, and after it the
                // jitter's few milliseconds off)
                assert!(
                    (t - truth(k) - 2 * MS).abs() < 3 * MS,
                    "{buffers}: frame {k} {}",
                    t - truth(k)
                );
                k += 1;
            }
            assert_eq!(c.restarts(), 0, "{buffers}: {:?}", c.take_restart());
            assert_eq!(c.pause_from, None);
        }
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
    fn hold_ups_right_after_a_late_frame_keep_the_line() {
        // what one frame of each interval rule would take for a slowdown or a pause:
        // a frame late in the latency's tail (20 ms) and the next held up 60 ms
        // more; a 200 ms hold-up of 2 buffers (past what they last), its backlog, and
        // right after it a frame held up anew
        let mut c = SequenceClock::with_buffers(2);
        let lat = |k: u32| match k {
            100 => 22 * MS,
            101 => 82 * MS,
            200 => 200 * MS,
            // the frame waiting behind it, dequeued 5 ms after it
            201 => 200 * MS + 5 * MS - P,
            202 => 180 * MS,
            _ => 2 * MS,
        };
        let mut prev = 0;
        for k in 0..400u32 {
            let d = (truth(k) + lat(k)).max(prev);
            let t = c.stamp(k, d);
            prev = d;
            if k > 60 {
                assert!(
                    (t - truth(k) - 2 * MS).abs() < MS,
                    "frame {k}: {}",
                    t - truth(k)
                );
            }
        }
        assert_eq!(c.restarts(), 0, "{:?}", c.take_restart());
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
        assert!(worst_interval < 0.15, "{worst_interval}");
        assert!(rms < rms_dequeue / 15.0, "{rms} against {rms_dequeue}");
        assert_eq!(c.restarts(), 0);
    }

    /// Latencies of a driver's deliveries: a 2 ms floor, an exponential tail of mean
    /// 3 ms (a xorshift draws them), and a 30 ms hold-up every 50th frame.
    fn latencies() -> impl FnMut(u32) -> Nanos {
        let mut x = 0x2545_f491_4f6c_dd1d_u64;
        move |k| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let u = (x >> 11) as f64 / (1u64 << 53) as f64;
            let tail = -3.0e6 * (1.0 - u).ln();
            2 * MS + tail as Nanos + if k.is_multiple_of(50) { 30 * MS } else { 0 }
        }
    }

    #[test]
    fn a_camera_slowing_a_little_is_not_stamped_early() {
        // 30 Hz, then 2 % slower from frame 300 (auto-exposure lengthening the frame
        // time): below what the half-period rule sees. A period measured before the
        // change, carried 15 frames, would put every stamp some 10 ms early
        let mut c = SequenceClock::new();
        let mut lat = latencies();
        let slow = P * 102 / 100;
        let frame = |k: i64| {
            if k < 300 {
                T0 + k * P
            } else {
                T0 + 300 * P + (k - 300) * slow
            }
        };
        let (mut early, mut early_dequeue) = (0, 0);
        for k in 0..900u32 {
            let truth = frame(i64::from(k)) + 2 * MS;
            let d = frame(i64::from(k)) + lat(k);
            let t = c.stamp(k, d);
            if k >= 50 {
                early = early.max(truth - t);
                early_dequeue = early_dequeue.max(truth - d);
            }
        }
        // the line's floor is the latency floor: a period measured before the change,
        // carried 15 frames, put stamps 9.7 ms before it; carried 8 frames, the line
        // moved up to the floor of the last 9 and the period measured again once 16 in
        // a row miss it, 3.9 ms at most, for half a second
        assert!(early < 5 * MS, "{early} ns early");
        assert!(early_dequeue <= 0);
        assert_eq!(c.restarts(), 0);
        assert!(c.remeasures() >= 1);
        assert!((c.period_ns().unwrap() - slow as f64).abs() < 0.01 * slow as f64);
    }

    #[test]
    fn a_young_line_is_never_far_from_the_floor() {
        // the frames right after a start, whose period rests on few frames
        for seed in 0..20u32 {
            let mut c = SequenceClock::new();
            let mut lat = latencies();
            for _ in 0..seed * 7 {
                lat(1);
            }
            for k in 0..130u32 {
                let truth = T0 + i64::from(k) * P + 2 * MS;
                let t = c.stamp(k, T0 + i64::from(k) * P + lat(k));
                assert!(
                    truth - t < 2 * MS,
                    "seed {seed} frame {k}: {} ns early",
                    truth - t
                );
            }
        }
    }

    #[test]
    fn a_driver_with_many_buffers_hands_them_over_late_without_a_restart() {
        // 12 buffers: a 400 ms hold-up hands over 12 late frames back to back
        let mut c = SequenceClock::with_buffers(12);
        for k in 0..400u32 {
            let due = T0 + i64::from(k) * P;
            let held = (200..212).contains(&k);
            let d = if held { T0 + 212 * P } else { due + 2 * MS };
            let t = c.stamp(k, d);
            if k > 150 {
                assert!((t - due - 2 * MS).abs() < MS, "frame {k}: {}", t - due);
            }
        }
        assert_eq!(c.restarts(), 0);
    }

    #[test]
    fn a_remeasure_keeps_the_newest_frames_and_their_lateness_in_place() {
        let mut c = SequenceClock::new();
        let mut lat = latencies();
        for k in 0..203u32 {
            c.stamp(k, T0 + i64::from(k) * P + lat(k));
        }
        let w = WINDOW as u64;
        let newest = |c: &SequenceClock| {
            (1..=w)
                .map(|b| {
                    let k = c.count - b;
                    (c.history[c.slot(k)], c.residuals[(k % w) as usize])
                })
                .collect::<Vec<_>>()
        };
        let before = newest(&c);
        c.keep_newest(REMEASURE_FRAMES);
        assert_eq!(c.count, REMEASURE_FRAMES);
        assert_eq!(newest(&c), before);
        assert_eq!(c.remeasures(), 1);
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
