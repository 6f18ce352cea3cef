//! What the daemon writes to its log over months of running: a warning that repeats
//! (a driver sending NaN at 30 Hz, a lossy link) is logged at once, then at most once
//! per [`THROTTLE_NS`] with the count of those suppressed meanwhile, that period
//! doubling at each line while the events go on, up to [`THROTTLE_MAX_NS`], and back
//! to [`THROTTLE_NS`] after [`THROTTLE_MAX_NS`] without one ([`Throttle`]); and every
//! summary period (`daemon.summary_period_s`, 10 minutes by default) one line says
//! how the estimate and the streams fared ([`Summary`]) and one what the latency was
//! ([`LatencyStretch`], which the real-time thread measures and hands over as the
//! event that ends the period). Pure logic, driven by the service thread with
//! monotonic times.

use vlsync_common::wire::{Status, REJECT_NAMES, REJECT_REASONS};
use vlsync_common::{Estimate, EstimatorState, Nanos};

/// A repeated warning of one kind is logged at most once per this period, ns.
pub const THROTTLE_NS: Nanos = 10_000_000_000;

/// Kinds of throttled lines: rejections per stream and reason, losses per stream,
/// the switches to degraded mode (budget overruns), then the stamping-latency steps
/// per stream and the offset steps found in the data (information, not warnings:
/// a load change), then the moves of the search (a warning), the (re)starts of each
/// stream's driver (information: a publisher that flags every sample as its first
/// would log one a sample), the errors of the real-time loop, the changes of the
/// estimator state per new state (information: a flapping estimator would log two
/// lines a hop), the estimates not published, invalid or refused by the offset
/// service (a lasting fault would log one line per estimate, 170,000 a day), the
/// publishers first read mid-run per stream (information), the silences longer
/// than `estimator.max_gap_s` per stream (a warning: a sensor slower than the limit
/// makes every interval one, and nothing is ever estimated), the switches to simulated
/// samples and back per stream; then the service thread's own: the publishers of each
/// stream that could not be connected, the offset and status clients not served, the
/// streams silent for [`SILENT_STREAM_NS`], the CPU-pressure load steps, the load hints
/// declared, undated and dropped, the failed notifications of systemd, and the real-time
/// loop's sleeps after a flood of empty notifications.
pub const KINDS: usize = 2 * REJECT_REASONS + 36;

/// A search that keeps moving (an offset outside the configured lag range moves
/// it every 30 s, for as long as the daemon runs) is logged at most once per this
/// period, ns (10 minutes).
pub const SEARCH_MOVE_THROTTLE_NS: Nanos = 600_000_000_000;

/// Throttle key of a switch to degraded mode.
pub const DEGRADED_KEY: usize = 2 * REJECT_REASONS + 2;

/// Throttle key of a stamping-latency step of stream `si`.
pub fn latency_step_key(si: usize) -> usize {
    DEGRADED_KEY + 1 + si.min(1)
}

/// Throttle key of an offset step found in the data.
pub const OFFSET_STEP_KEY: usize = DEGRADED_KEY + 3;

/// Throttle key of a move of the acquisition's search.
pub const SEARCH_MOVE_KEY: usize = DEGRADED_KEY + 4;

/// Throttle key of a (re)start of the driver of stream `si`.
pub fn driver_started_key(si: usize) -> usize {
    DEGRADED_KEY + 5 + si.min(1)
}

/// Throttle key of an error of the real-time loop (a failed receive).
pub const RT_ERROR_KEY: usize = DEGRADED_KEY + 7;

/// Throttle key of a change of the estimator state to `to` (the routine changes
/// between tracking and holding are logged at debug level, outside the throttle).
pub fn state_key(to: EstimatorState) -> usize {
    DEGRADED_KEY + 8 + to as usize % 4
}

/// Throttle key of an estimate with an invalid field (not published).
pub const INVALID_ESTIMATE_KEY: usize = DEGRADED_KEY + 12;

/// Throttle key of an estimate the offset service did not take (no free sample).
pub const PUBLISH_FAILED_KEY: usize = DEGRADED_KEY + 13;

/// Throttle key of a publisher of stream `si` first read mid-run (its first sample
/// read not its first one: `RtEvent::Joined`).
pub fn joined_key(si: usize) -> usize {
    DEGRADED_KEY + 14 + si.min(1)
}

/// Throttle key of a silence of stream `si` longer than `estimator.max_gap_s`
/// (`RtEvent::Silence`).
pub fn silence_key(si: usize) -> usize {
    DEGRADED_KEY + 16 + si.min(1)
}

/// Throttle key of a change of stream `si` to simulated samples (`on`) or back to a
/// sensor's (`RtEvent::Simulated`).
pub fn simulated_key(si: usize, on: bool) -> usize {
    DEGRADED_KEY + 18 + si.min(1) + if on { 0 } else { 2 }
}

/// Throttle key of a publisher of stream `si` that joined and could not be connected
/// (the subscriber's degradation handler: its samples are not read).
pub fn unconnected_key(si: usize) -> usize {
    DEGRADED_KEY + 22 + si.min(1)
}

/// Throttle key of the offset clients the offset publisher could not connect, or
/// whose connection it found corrupt (its degradation handler).
pub const OFFSET_CLIENTS_KEY: usize = DEGRADED_KEY + 24;

/// Throttle key of the status clients the status publisher could not connect, or
/// whose connection it found corrupt (its degradation handler).
pub const STATUS_CLIENTS_KEY: usize = DEGRADED_KEY + 25;

/// Throttle key of a stream `si` whose received count has not moved for
/// [`SILENT_STREAM_NS`] ([`SilentStreams`]).
pub fn silent_stream_key(si: usize) -> usize {
    DEGRADED_KEY + 26 + si.min(1)
}

/// Throttle key of a load step seen in the CPU pressure (`daemon.load_hints`).
pub const LOAD_STEP_KEY: usize = DEGRADED_KEY + 28;

/// Throttle key of a load hint the estimator was told of (`RtEvent::ChangeDeclared`).
pub const HINT_DECLARED_KEY: usize = DEGRADED_KEY + 29;

/// Throttle key of a load hint before any LiDAR sample (`RtEvent::HintUndated`).
pub const HINT_UNDATED_KEY: usize = DEGRADED_KEY + 30;

/// Throttle key of a load hint the real-time thread's full channel did not take.
pub const HINT_DROPPED_KEY: usize = DEGRADED_KEY + 31;

/// Throttle key of a failure to notify systemd after a notification that went out
/// (`notify::Supervisor`: a lasting failure is one, a flapping socket one per flap).
pub const NOTIFY_FAILED_KEY: usize = DEGRADED_KEY + 32;

/// Throttle key of the real-time loop's sleeps after a flood of notifications that
/// brought no sample (`rt::EmptyWakes`: a process notifying the signature event in a
/// loop).
pub const NOTIFY_FLOOD_KEY: usize = DEGRADED_KEY + 33;

/// How long a stream's received count may stand still while the daemon runs before
/// [`SilentStreams`] says so, ns (30 s: a driver stopped, hung, waiting for its device,
/// or publishing elsewhere; every driver sends several samples a second).
pub const SILENT_STREAM_NS: Nanos = 30_000_000_000;

/// What [`SilentStreams::observe`] found for one stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamNews {
    /// The stream's received count has not moved for `for_ns` (at least
    /// [`SILENT_STREAM_NS`]), since `since_ns` on the watch's clock (when it last
    /// moved, or when the watch started: `ever` false, nothing received yet).
    Silent {
        /// Stream (0 cam, 1 LiDAR).
        si: usize,
        /// When the count last moved (or the watch started), on the watch's clock, ns.
        since_ns: Nanos,
        /// How long it has stood still, ns.
        for_ns: Nanos,
        /// Whether the stream had delivered anything before.
        ever: bool,
    },
    /// A stream said silent ([`SilentStreams::said`]) moves again, after `after_ns`.
    Resumed {
        /// Stream (0 cam, 1 LiDAR).
        si: usize,
        /// How long it stood still, ns.
        after_ns: Nanos,
    },
}

/// Watches each stream's received count (from the real-time thread, read by the
/// service thread every poll) for a stream that stops for good: a driver that hangs
/// leaves no other trace at warning level (the estimator's silence,
/// `RtEvent::Silence`, is said only when the stream resumes). A stream whose count
/// has not moved for [`SILENT_STREAM_NS`] is news once per silence, whatever the
/// other stream does; once said, its first move again is news too. Pure logic on
/// times the caller gives.
#[derive(Debug, Clone)]
pub struct SilentStreams {
    limit_ns: Nanos,
    /// Per stream: the count last seen and when it last moved (or the watch started).
    seen: [(u64, Nanos); 2],
    /// Per stream: the stream has delivered since the watch started.
    ever: [bool; 2],
    /// Per stream: a silence found (news given), and whether it was said.
    silent: [Option<bool>; 2],
}

impl SilentStreams {
    /// A watch starting at `now` (the counts at zero), news after `limit_ns` still.
    pub fn new(limit_ns: Nanos, now: Nanos) -> Self {
        Self {
            limit_ns,
            seen: [(0, now); 2],
            ever: [false; 2],
            silent: [None; 2],
        }
    }

    /// The counts `received` at `now`: what is news, per stream.
    pub fn observe(&mut self, received: [u64; 2], now: Nanos) -> [Option<StreamNews>; 2] {
        let mut out = [None; 2];
        for si in 0..2 {
            let (count, since) = self.seen[si];
            if received[si] != count {
                let after_ns = now.saturating_sub(since);
                self.seen[si] = (received[si], now);
                self.ever[si] = true;
                if self.silent[si].take() == Some(true) {
                    out[si] = Some(StreamNews::Resumed { si, after_ns });
                }
            } else if self.silent[si].is_none() && now.saturating_sub(since) >= self.limit_ns {
                self.silent[si] = Some(false);
                out[si] = Some(StreamNews::Silent {
                    si,
                    since_ns: since,
                    for_ns: now.saturating_sub(since),
                    ever: self.ever[si],
                });
            }
        }
        out
    }

    /// Stream `si`'s silence was said (not held back by the throttle): its resumption
    /// will be news.
    pub fn said(&mut self, si: usize) {
        if let Some(s) = self.silent.get_mut(si).and_then(Option::as_mut) {
            *s = true;
        }
    }
}

/// How many stamping-latency steps of `stream` (`cam` or `lidar`) a daemon log
/// records: the lines naming one (`cam stamps +12.1 ms later from t=…`) and the
/// counts the throttle held back (`3 more cam stamping-latency steps since …`).
/// The load test's report and the tests read the log with it.
pub fn latency_steps_logged(log: &str, stream: &str) -> usize {
    let named = format!("{stream} stamps ");
    let held = format!("more {stream} stamping-latency steps");
    events_logged(
        log,
        |l| l.contains(&named) && l.contains("later from t="),
        &held,
    )
}

/// How many moves of the search a daemon log records: the lines naming one
/// (`... searching around +0.0 ms now instead of ...`) and the counts the
/// throttle held back (`3 more moves of the search ... since ...`).
pub fn search_moves_logged(log: &str) -> usize {
    events_logged(
        log,
        |l| l.contains("searching around"),
        "more moves of the search",
    )
}

/// How many offset steps found in the data a daemon log records (named lines and
/// the counts held back).
pub fn offset_steps_logged(log: &str) -> usize {
    events_logged(
        log,
        |l| l.contains("offset stepped by about"),
        "more offset steps found in the data",
    )
}

/// How many switches to degraded mode a daemon log records.
pub fn degraded_switches_logged(log: &str) -> usize {
    events_logged(
        log,
        |l| l.contains("over budget: estimator degraded"),
        "more switches to degraded mode",
    )
}

/// Lines of `log` naming one event (with the `(N more since the last such line)`
/// a line carries when it ends a throttled period), plus the `N more <held> ...`
/// counts the throttle reported on their own.
fn events_logged(log: &str, named: impl Fn(&str) -> bool, held: &str) -> usize {
    log.lines()
        .map(|l| {
            if named(l) {
                1 + l
                    .rsplit_once(" more since the last such line)")
                    .and_then(|(head, _)| head.rsplit_once('(').map(|(_, n)| n))
                    .and_then(|n| n.parse::<usize>().ok())
                    .unwrap_or(0)
            } else if l.contains(held) {
                l.split(" more ")
                    .next()
                    .and_then(|head| head.rsplit(' ').next())
                    .and_then(|n| n.parse::<usize>().ok())
                    .unwrap_or(0)
            } else {
                0
            }
        })
        .sum()
}

/// Whether the kind of throttle key `key` is information (not a warning).
pub fn is_info(key: usize) -> bool {
    if key >= unconnected_key(0) {
        // the service thread's own: only the load hints' are information
        return matches!(key, LOAD_STEP_KEY | HINT_DECLARED_KEY | HINT_UNDATED_KEY);
    }
    key > DEGRADED_KEY
        && !matches!(
            key,
            SEARCH_MOVE_KEY | RT_ERROR_KEY | INVALID_ESTIMATE_KEY | PUBLISH_FAILED_KEY
        )
        // silences and switches to simulated samples are warnings; back to a sensor
        // is information
        && !(silence_key(0)..simulated_key(0, false)).contains(&key)
}

/// Throttle key of a rejected sample of stream `si` (0 cam, 1 LiDAR) for `reason`.
pub fn rejected_key(si: usize, reason: usize) -> usize {
    si.min(1) * REJECT_REASONS + reason.min(REJECT_REASONS - 1)
}

/// Throttle key of a sequence gap of stream `si`.
pub fn lost_key(si: usize) -> usize {
    2 * REJECT_REASONS + si.min(1)
}

/// The longest period [`Throttle`] stretches a kind's to while its events go on, ns
/// (10 minutes): a lasting fault logs some 150 lines a day per kind, not 8,600,
/// however often its events come. It is also the quiet gap (no event of the kind at
/// all) after which the kind's period starts again from its own.
pub const THROTTLE_MAX_NS: Nanos = 600_000_000_000;

/// Rate limit per kind of warning. A kind's first event is logged at once; then its
/// period doubles at each line, up to [`THROTTLE_MAX_NS`] (or its own period, if
/// longer), for as long as its events go on: each event within that longest period of
/// the kind's previous one (logged or held back) continues the fault, however sparse
/// (a link dropping a sample every 20 s, a step every 45 s). Only a gap as long as the
/// longest period without any event of the kind (seen by [`Throttle::due`] or the
/// next [`Throttle::admit`]) ends the fault: the next event is logged at once and the
/// period starts again from its own. A lasting fault therefore logs some 150 lines a
/// day, whatever its events' rhythm; one whose events pause for 10 minutes at a time
/// says each return at once.
#[derive(Debug, Clone)]
pub struct Throttle {
    period: [Nanos; KINDS],
    /// The kind's last line.
    last: [Option<Nanos>; KINDS],
    /// The kind's last event, logged or held back.
    last_event: [Option<Nanos>; KINDS],
    /// Events (rejections: samples; losses: samples lost) suppressed since the last line.
    suppressed: [u64; KINDS],
    /// Doublings of the kind's period: lines since the fault began.
    stretch: [u32; KINDS],
}

impl Throttle {
    /// A throttle letting one line per `period` through for each kind.
    pub fn new(period: Nanos) -> Self {
        Self {
            period: [period; KINDS],
            last: [None; KINDS],
            last_event: [None; KINDS],
            suppressed: [0; KINDS],
            stretch: [0; KINDS],
        }
    }

    /// Kind `k`'s longest period: [`THROTTLE_MAX_NS`], or its own if longer.
    fn longest(&self, k: usize) -> Nanos {
        self.period[k].max(THROTTLE_MAX_NS)
    }

    /// Kind `k`'s period now: its own, doubled per line since its fault began.
    fn current(&self, k: usize) -> Nanos {
        let base = self.period[k];
        base.saturating_mul(1i64 << self.stretch[k].min(30))
            .min(self.longest(k))
    }

    /// Whether kind `k` had no event for its longest period before `now` (or none
    /// yet): a fault of that kind is over.
    fn quiet(&self, k: usize, now: Nanos) -> bool {
        self.last_event[k].is_none_or(|t| now.saturating_sub(t) >= self.longest(k))
    }

    /// A line of kind `k` goes out now; `fresh`: the first of a new fault (its next
    /// line waits the kind's own period), else the fault goes on (twice as long).
    fn line(&mut self, k: usize, now: Nanos, fresh: bool) {
        self.last[k] = Some(now);
        self.stretch[k] = if fresh {
            0
        } else {
            self.stretch[k].saturating_add(1)
        };
    }

    /// The same with kind `key` let through once per `period` instead.
    pub fn with_period(mut self, key: usize, period: Nanos) -> Self {
        self.period[key.min(KINDS - 1)] = period;
        self
    }

    /// An event of kind `key` counting `n` at `now`: `Some(suppressed)` when it is to be
    /// logged (with the count suppressed since the last logged one), `None` when it is
    /// counted for later.
    pub fn admit(&mut self, key: usize, n: u64, now: Nanos) -> Option<u64> {
        let k = key.min(KINDS - 1);
        let fresh = self.quiet(k, now);
        self.last_event[k] = Some(now);
        match self.last[k] {
            Some(t) if !fresh && now.saturating_sub(t) < self.current(k) => {
                self.suppressed[k] = self.suppressed[k].saturating_add(n);
                None
            }
            _ => {
                let held = std::mem::take(&mut self.suppressed[k]);
                self.line(k, now, fresh);
                Some(held)
            }
        }
    }

    /// Reports `(key, count)` of every kind whose suppressed events have waited a whole
    /// period, and starts its next period now (twice as long: the fault goes on); a
    /// kind without an event for its longest period starts again from its own.
    pub fn due(&mut self, now: Nanos, mut report: impl FnMut(usize, u64)) {
        for k in 0..KINDS {
            let waited = self.last[k].is_some_and(|t| now.saturating_sub(t) >= self.current(k));
            if waited && self.suppressed[k] > 0 {
                let held = std::mem::take(&mut self.suppressed[k]);
                self.line(k, now, false);
                report(k, held);
            } else if self.suppressed[k] == 0 && self.quiet(k, now) {
                // the fault is over: the next event is said at once, and then after
                // the kind's own period again
                self.stretch[k] = 0;
            }
        }
    }
}

/// Readable text of a throttle key's kind, e.g. `cam samples rejected (non_finite)`.
pub fn kind_text(key: usize) -> String {
    let stream = |si: usize| if si == 0 { "cam" } else { "lidar" };
    if key < 2 * REJECT_REASONS {
        format!(
            "{} samples rejected ({})",
            stream(key / REJECT_REASONS),
            REJECT_NAMES[key % REJECT_REASONS]
        )
    } else if key < DEGRADED_KEY {
        format!(
            "{} samples lost (sequence gaps)",
            stream(key - 2 * REJECT_REASONS)
        )
    } else if key == DEGRADED_KEY {
        "switches to degraded mode (processing over budget)".to_string()
    } else if key == OFFSET_STEP_KEY {
        "offset steps found in the data".to_string()
    } else if key == SEARCH_MOVE_KEY {
        "moves of the search (no lock where it searched)".to_string()
    } else if key == RT_ERROR_KEY {
        "errors of the real-time loop".to_string()
    } else if key == INVALID_ESTIMATE_KEY {
        "estimates with an invalid field (not published)".to_string()
    } else if key == PUBLISH_FAILED_KEY {
        "estimates the offset service did not take".to_string()
    } else if key == NOTIFY_FAILED_KEY {
        "failures to notify systemd (NOTIFY_SOCKET)".to_string()
    } else if key == NOTIFY_FLOOD_KEY {
        "floods of notifications without a sample".to_string()
    } else if key == HINT_DROPPED_KEY {
        "load hints dropped (the real-time thread lags)".to_string()
    } else if key == HINT_UNDATED_KEY {
        "load hints before any LiDAR sample".to_string()
    } else if key == HINT_DECLARED_KEY {
        "load hints told to the estimator".to_string()
    } else if key == LOAD_STEP_KEY {
        "load steps in the CPU pressure".to_string()
    } else if key >= silent_stream_key(0) {
        format!(
            "{} silences of {} s or more (nothing received)",
            stream((key - silent_stream_key(0)).min(1)),
            SILENT_STREAM_NS / 1_000_000_000
        )
    } else if key == STATUS_CLIENTS_KEY {
        "failed connections of status clients".to_string()
    } else if key == OFFSET_CLIENTS_KEY {
        "failed connections of offset clients".to_string()
    } else if key >= unconnected_key(0) {
        format!(
            "{} publishers that could not be connected",
            stream((key - unconnected_key(0)).min(1))
        )
    } else if key >= simulated_key(0, false) {
        format!(
            "{} switches back to sensor samples",
            stream((key - simulated_key(0, false)).min(1))
        )
    } else if key >= simulated_key(0, true) {
        format!(
            "{} switches to simulated samples",
            stream((key - simulated_key(0, true)).min(1))
        )
    } else if key >= silence_key(0) {
        format!(
            "{} silences longer than estimator.max_gap_s",
            stream((key - silence_key(0)).min(1))
        )
    } else if key >= joined_key(0) {
        format!(
            "{} publishers first read mid-run",
            stream((key - joined_key(0)).min(1))
        )
    } else if key >= state_key(EstimatorState::Acquiring) {
        let to = [
            EstimatorState::Acquiring,
            EstimatorState::Tracking,
            EstimatorState::Holding,
            EstimatorState::Lost,
        ][(key - state_key(EstimatorState::Acquiring)).min(3)];
        format!("changes of the estimator state to {}", to.name())
    } else if key >= driver_started_key(0) {
        format!(
            "{} driver (re)starts",
            stream((key - driver_started_key(0)).min(1))
        )
    } else {
        format!(
            "{} stamping-latency steps",
            stream((key - DEGRADED_KEY - 1).min(1))
        )
    }
}

/// The real-time thread's latency over one stretch of the run (a summary period),
/// for the log: a change after months shows there, where the status's whole-run
/// percentiles would hide it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LatencyStretch {
    /// The stretch's length, ns.
    pub span_ns: Nanos,
    /// Samples processed.
    pub samples: u64,
    /// Processing time per sample, `[p50, p99, max]` ns.
    pub processing_ns: [u64; 3],
    /// Samples with a driver's publish time, timed from it to done.
    pub timed: u64,
    /// Driver publish to done with the sample (estimate out), `[p50, p99, max]` ns.
    pub end_to_end_ns: [u64; 3],
    /// Samples over the processing budget.
    pub overruns: u64,
}

/// A summary's span as the log says it: seconds under two minutes, else minutes.
fn span_text(ns: Nanos) -> String {
    let min = ns as f64 / 60e9;
    if ns < 120_000_000_000 {
        format!("{:.0} s", ns as f64 / 1e9)
    } else if (min - min.round()).abs() < 0.05 {
        format!("{min:.0} min")
    } else {
        format!("{min:.1} min")
    }
}

/// The log line of a latency stretch.
///
/// ```
/// use vlsyncd::runtime::journal::{latency_line, LatencyStretch};
/// let s = LatencyStretch {
///     span_ns: 600_000_000_000,
///     samples: 24_000,
///     processing_ns: [9_100, 61_000, 180_000],
///     timed: 24_000,
///     end_to_end_ns: [95_000, 210_000, 480_000],
///     overruns: 0,
/// };
/// assert_eq!(
///     latency_line(&s, 200.0),
///     "latency, last 10 min: 24000 samples, processing p50 9.1 µs, p99 61.0 µs, \
///      max 180.0 µs, 0 over the 200 µs budget; driver publish to done p50 95.0 µs, \
///      p99 210.0 µs, max 480.0 µs"
/// );
/// ```
pub fn latency_line(s: &LatencyStretch, budget_us: f64) -> String {
    let us = |ns: u64| ns as f64 / 1e3;
    let [p50, p99, max] = s.processing_ns;
    let mut out = format!(
        "latency, last {}: {} samples, processing p50 {:.1} µs, p99 {:.1} µs, \
         max {:.1} µs, {} over the {budget_us:.0} µs budget",
        span_text(s.span_ns),
        s.samples,
        us(p50),
        us(p99),
        us(max),
        s.overruns
    );
    if s.timed > 0 {
        let [p50, p99, max] = s.end_to_end_ns;
        out.push_str(&format!(
            "; driver publish to done p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
            us(p50),
            us(p99),
            us(max)
        ));
        if s.timed < s.samples {
            out.push_str(&format!(" ({} of the samples timed)", s.timed));
        }
    }
    out
}

/// The periodic summary of estimates and stream counters. Its line is written when
/// the real-time thread's latency stretch ends ([`Summary::close`]), so the two lines
/// of a period cover the same stretch; [`Summary::due`] writes it when that event
/// has not come for two and a half periods (a flood that filled the event channel
/// dropped it; at two, the next event, a little late, would follow within a
/// fraction of a second with an empty line).
#[derive(Debug, Clone)]
pub struct Summary {
    period: Nanos,
    since: Nanos,
    per_state: [u64; 4],
    /// Offset steps found in the data, and moves of the search, this period.
    steps: u64,
    search_moves: u64,
    last: Option<Estimate>,
    status_then: Option<Status>,
    status_now: Option<Status>,
    /// Per stream: its samples come from a simulator (`FLAG_SIMULATED`).
    simulated: [bool; 2],
}

impl Summary {
    /// A summary every `period`, the first counted from `now`.
    pub fn new(period: Nanos, now: Nanos) -> Self {
        Self {
            period,
            since: now,
            per_state: [0; 4],
            steps: 0,
            search_moves: 0,
            last: None,
            status_then: None,
            status_now: None,
            simulated: [false; 2],
        }
    }

    /// Stream `si`'s samples come from a simulator (`on`), or from a sensor again:
    /// every summary line says so while any does.
    pub fn on_simulated(&mut self, si: usize, on: bool) {
        self.simulated[si.min(1)] = on;
    }

    /// Counts an estimate.
    pub fn on_estimate(&mut self, e: &Estimate) {
        self.per_state[e.state as usize % 4] += 1;
        self.last = Some(*e);
    }

    /// Counts an offset step the estimator found in the data.
    pub fn on_offset_step(&mut self) {
        self.steps += 1;
    }

    /// Counts a move of the acquisition's search.
    pub fn on_search_move(&mut self) {
        self.search_moves += 1;
    }

    /// Keeps the newest status (its counters are totals since the daemon started).
    pub fn on_status(&mut self, s: &Status) {
        self.status_now = Some(*s);
    }

    /// The summary line when two and a half periods have passed since the last one
    /// without a [`Summary::close`] (the real-time thread's event that ends a period
    /// was lost twice in a row; one lost event makes the next one's line cover two
    /// periods).
    pub fn due(&mut self, now: Nanos) -> Option<String> {
        let limit = self.period.saturating_mul(5) / 2;
        (now.saturating_sub(self.since) >= limit).then(|| self.close(now))
    }

    /// The summary line of everything since the last one, and a new period from `now`.
    pub fn close(&mut self, now: Nanos) -> String {
        let since = self.since;
        self.since = now;
        let line = self.line(now.saturating_sub(since));
        self.per_state = [0; 4];
        self.steps = 0;
        self.search_moves = 0;
        self.status_then = self.status_now;
        line
    }

    fn line(&self, span_ns: Nanos) -> String {
        let n: u64 = self.per_state.iter().sum();
        let mut out = format!("last {}: {n} estimates", span_text(span_ns));
        if n > 0 {
            let shares: Vec<String> = [
                EstimatorState::Tracking,
                EstimatorState::Holding,
                EstimatorState::Acquiring,
                EstimatorState::Lost,
            ]
            .iter()
            .filter(|s| self.per_state[**s as usize] > 0)
            .map(|s| {
                let pct = 100.0 * self.per_state[*s as usize] as f64 / n as f64;
                format!("{} {pct:.0} %", s.name())
            })
            .collect();
            out.push_str(&format!(" ({})", shares.join(", ")));
        }
        if self.steps > 0 {
            out.push_str(&format!(", {} offset steps", self.steps));
        }
        if self.search_moves > 0 {
            out.push_str(&format!(", {} search moves", self.search_moves));
        }
        if let Some(e) = &self.last {
            out.push_str(&format!(
                "; now {}: offset {:+.2} ± {:.2} ms, drift {:+.1} ± {:.1} ppm",
                e.state.name(),
                e.offset_s * 1e3,
                e.offset_std_s * 1e3,
                e.drift * 1e6,
                e.drift_std * 1e6
            ));
        }
        if let Some(now) = &self.status_now {
            let then = self.status_then.unwrap_or_default();
            for (si, name) in ["cam", "lidar"].iter().enumerate() {
                out.push_str(&format!(
                    "; {name} {} received, {} rejected, {} lost",
                    now.received[si].saturating_sub(then.received[si]),
                    now.rejected_total(si)
                        .saturating_sub(then.rejected_total(si)),
                    now.lost[si].saturating_sub(then.lost[si])
                ));
            }
            out.push_str(&format!(
                "; {} over budget",
                now.budget_overruns.saturating_sub(then.budget_overruns)
            ));
        }
        let sim: Vec<&str> = ["cam", "lidar"]
            .iter()
            .zip(self.simulated)
            .filter_map(|(name, on)| on.then_some(*name))
            .collect();
        if !sim.is_empty() {
            out.push_str(&format!(
                "; SIMULATED samples ({}): not the robot's offset",
                sim.join(", ")
            ));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use vlsync_common::Polarity;

    const S: Nanos = 1_000_000_000;

    /// A fault that lasts a day (an event a second, the service thread's `due` every
    /// second) logs some 150 lines, not 8,640, and every event is in a line's count.
    #[test]
    fn a_lasting_fault_stretches_the_period_to_ten_minutes() {
        let mut t = Throttle::new(10 * S);
        let k = lost_key(1);
        let (mut lines, mut counted) = (0u64, 0u64);
        for i in 0..86_400i64 {
            if let Some(held) = t.admit(k, 1, i * S) {
                lines += 1;
                counted += held + 1;
            }
            t.due(i * S, |_, held| {
                lines += 1;
                counted += held;
            });
        }
        t.due(i64::MAX, |_, held| counted += held);
        assert_eq!(counted, 86_400);
        assert!((140..=160).contains(&lines), "{lines} lines");
        assert_eq!(t.current(k), THROTTLE_MAX_NS);
    }

    /// A fault whose events come seldom but go on (a lossy link dropping a sample
    /// every 20 s, a latency or offset step every 15-45 s, a NaN every 30 s, a fault
    /// back every 599 s) stretches its period too: some 150 lines a day whatever the
    /// rhythm (once, one line per event while each came after its period: 5,760 a day
    /// for one every 15 s), and every event is in a line's count.
    #[test]
    fn a_sparse_lasting_fault_logs_some_150_lines_a_day() {
        for every_s in [1i64, 15, 20, 25, 30, 45, 100, 300, 599, 601, 1200] {
            let mut t = Throttle::new(10 * S);
            let k = latency_step_key(0);
            let (mut lines, mut counted, mut events) = (0u64, 0u64, 0u64);
            // the service thread's `due` every second, an event every `every_s`
            for i in 0..86_400i64 {
                if i % every_s == 0 {
                    events += 1;
                    if let Some(held) = t.admit(k, 1, i * S) {
                        lines += 1;
                        counted += held + 1;
                    }
                }
                t.due(i * S, |_, held| {
                    lines += 1;
                    counted += held;
                });
            }
            t.due(i64::MAX, |_, held| counted += held);
            assert_eq!(counted, events, "every {every_s} s");
            let bound = 160.min(events);
            assert!(lines <= bound, "every {every_s} s: {lines} lines");
            assert!(lines >= 140.min(events), "every {every_s} s: {lines} lines");
        }
    }

    /// A burst (an event a second for 5 minutes), then silence: the kind's period is
    /// back at its own once 10 minutes passed without an event (not before), and the
    /// next fault is said at once and after 10 s again.
    #[test]
    fn after_a_burst_and_ten_quiet_minutes_the_period_is_the_base_again() {
        let mut t = Throttle::new(10 * S);
        let k = lost_key(0);
        let mut lines = 0;
        for i in 0..300i64 {
            if t.admit(k, 1, i * S).is_some() {
                lines += 1;
            }
            t.due(i * S, |_, _| lines += 1);
        }
        // 0, 10, 30, 70, 150 s: stretched to 160 s, then 320 s
        assert_eq!(lines, 5);
        assert_eq!(t.current(k), 160 * S);
        let mut held = vec![];
        for i in 300..898i64 {
            t.due(i * S, |_, n| held.push((i, n)));
        }
        // the burst's tail said a period after its last line
        assert_eq!(held, vec![(310, 149)]);
        assert_eq!(t.current(k), 320 * S);
        // the last event at 299 s: 10 minutes later, not before, the period is 10 s
        t.due(898 * S, |_, _| {});
        assert_eq!(t.current(k), 320 * S);
        t.due(899 * S, |_, _| {});
        assert_eq!(t.current(k), 10 * S);
        assert_eq!(t.admit(k, 1, 1000 * S), Some(0));
        assert_eq!(t.admit(k, 1, 1005 * S), None);
        assert_eq!(t.admit(k, 1, 1010 * S), Some(1));
        // without `due`: an event after ten quiet minutes is said at once all the same
        let mut t = Throttle::new(10 * S);
        for i in 0..300i64 {
            let _ = t.admit(k, 1, i * S);
        }
        assert_eq!(t.admit(k, 1, 899 * S), Some(149));
        assert_eq!(t.current(k), 10 * S);
    }

    #[test]
    fn first_event_is_logged_then_one_line_per_period_with_the_count() {
        let mut t = Throttle::new(10 * S);
        let k = rejected_key(0, 0);
        assert_eq!(t.admit(k, 1, 0), Some(0));
        for i in 1..=30 {
            assert_eq!(t.admit(k, 1, i * S / 10), None);
        }
        // other kinds are independent
        assert_eq!(t.admit(lost_key(1), 5, S), Some(0));
        let mut seen = vec![];
        t.due(9 * S, |k, n| seen.push((k, n)));
        assert!(seen.is_empty());
        t.due(10 * S, |k, n| seen.push((k, n)));
        assert_eq!(seen, vec![(k, 30)]);
        // reported: the next event waits for the next period, now twice as long (the
        // events went on through the last one), and counts from zero
        assert_eq!(t.admit(k, 1, 11 * S), None);
        assert_eq!(t.admit(k, 1, 20 * S), None);
        assert_eq!(t.admit(k, 1, 30 * S), Some(2));
        // a line that held nothing back does not end the fault (40 s now): its events
        // still come, if sparsely
        assert_eq!(t.current(k), 40 * S);
        assert_eq!(t.admit(k, 1, 70 * S), Some(0));
        assert_eq!(t.current(k), 80 * S);
        assert_eq!(t.admit(k, 1, 80 * S), None);
        // the 80 s event said by `due` a period after the last line: 160 s now
        let mut said = vec![];
        t.due(149 * S, |_, n| said.push(n));
        assert!(said.is_empty());
        t.due(150 * S, |_, n| said.push(n));
        assert_eq!(said, vec![1]);
        assert_eq!(t.current(k), 160 * S);
        // ten minutes without an event, seen by `due`: the fault is over, back to 10 s
        t.due(679 * S, |_, _| panic!("nothing held"));
        assert_eq!(t.current(k), 160 * S);
        t.due(680 * S, |_, _| panic!("nothing held"));
        assert_eq!(t.current(k), 10 * S);
        assert_eq!(t.admit(k, 1, 681 * S), Some(0));
        assert_eq!(t.admit(k, 1, 690 * S), None);
        assert_eq!(t.admit(k, 1, 691 * S), Some(1));
        assert_eq!(kind_text(k), "cam samples rejected (non_finite)");
        assert_eq!(kind_text(lost_key(1)), "lidar samples lost (sequence gaps)");
        assert!(kind_text(DEGRADED_KEY).contains("degraded"));
        assert_eq!(kind_text(latency_step_key(0)), "cam stamping-latency steps");
        assert_eq!(
            kind_text(latency_step_key(1)),
            "lidar stamping-latency steps"
        );
        assert!(latency_step_key(1) < KINDS && is_info(latency_step_key(0)));
        assert_eq!(kind_text(OFFSET_STEP_KEY), "offset steps found in the data");
        assert!(OFFSET_STEP_KEY < KINDS && is_info(OFFSET_STEP_KEY));
        assert!(OFFSET_STEP_KEY > latency_step_key(1));
        assert_eq!(
            kind_text(SEARCH_MOVE_KEY),
            "moves of the search (no lock where it searched)"
        );
        assert!(SEARCH_MOVE_KEY < KINDS && !is_info(SEARCH_MOVE_KEY));
        assert_eq!(kind_text(driver_started_key(0)), "cam driver (re)starts");
        assert_eq!(kind_text(driver_started_key(1)), "lidar driver (re)starts");
        assert!(is_info(driver_started_key(1)) && driver_started_key(1) < KINDS);
        assert_eq!(kind_text(RT_ERROR_KEY), "errors of the real-time loop");
        assert_eq!(
            kind_text(state_key(EstimatorState::Lost)),
            "changes of the estimator state to lost"
        );
        assert_eq!(
            kind_text(state_key(EstimatorState::Acquiring)),
            "changes of the estimator state to acquiring"
        );
        assert_eq!(state_key(EstimatorState::Lost), INVALID_ESTIMATE_KEY - 1);
        assert_eq!(PUBLISH_FAILED_KEY, joined_key(0) - 1);
        assert_eq!(joined_key(1), silence_key(0) - 1);
        assert_eq!(silence_key(1), simulated_key(0, true) - 1);
        assert_eq!(simulated_key(1, true), simulated_key(0, false) - 1);
        assert_eq!(simulated_key(1, false), unconnected_key(0) - 1);
        assert_eq!(unconnected_key(1), OFFSET_CLIENTS_KEY - 1);
        assert_eq!(STATUS_CLIENTS_KEY, silent_stream_key(0) - 1);
        assert_eq!(silent_stream_key(1), LOAD_STEP_KEY - 1);
        assert_eq!(NOTIFY_FAILED_KEY, KINDS - 2);
        assert_eq!(NOTIFY_FLOOD_KEY, KINDS - 1);
        for key in [LOAD_STEP_KEY, HINT_DECLARED_KEY, HINT_UNDATED_KEY] {
            assert!(is_info(key), "{}", kind_text(key));
        }
        for key in [
            unconnected_key(0),
            unconnected_key(1),
            OFFSET_CLIENTS_KEY,
            STATUS_CLIENTS_KEY,
            silent_stream_key(0),
            silent_stream_key(1),
            HINT_DROPPED_KEY,
            NOTIFY_FAILED_KEY,
            NOTIFY_FLOOD_KEY,
        ] {
            assert!(!is_info(key), "{}", kind_text(key));
        }
        assert_eq!(
            kind_text(unconnected_key(1)),
            "lidar publishers that could not be connected"
        );
        assert_eq!(
            kind_text(silent_stream_key(0)),
            "cam silences of 30 s or more (nothing received)"
        );
        assert_eq!(
            kind_text(simulated_key(1, true)),
            "lidar switches to simulated samples"
        );
        assert_eq!(
            kind_text(simulated_key(0, false)),
            "cam switches back to sensor samples"
        );
        assert!(!is_info(simulated_key(0, true)) && !is_info(silence_key(1)));
        assert!(is_info(simulated_key(1, false)));
        assert_eq!(
            kind_text(joined_key(0)),
            "cam publishers first read mid-run"
        );
        assert_eq!(
            kind_text(joined_key(1)),
            "lidar publishers first read mid-run"
        );
        assert!(is_info(joined_key(0)));
        assert!(!is_info(INVALID_ESTIMATE_KEY) && !is_info(PUBLISH_FAILED_KEY));
        assert_eq!(
            kind_text(PUBLISH_FAILED_KEY),
            "estimates the offset service did not take"
        );
        assert!(is_info(state_key(EstimatorState::Tracking)));
        assert!(RT_ERROR_KEY < KINDS && !is_info(RT_ERROR_KEY));
        // every key has its own text
        let texts: std::collections::HashSet<String> = (0..KINDS).map(kind_text).collect();
        assert_eq!(texts.len(), KINDS);
        assert!(!is_info(DEGRADED_KEY) && !is_info(lost_key(1)));
    }

    #[test]
    fn a_kind_with_its_own_period_waits_that_long() {
        // a search that keeps moving every 30 s: one line per 10 minutes
        let mut t = Throttle::new(10 * S).with_period(SEARCH_MOVE_KEY, 600 * S);
        let mut logged = vec![];
        for i in 0..60 {
            if let Some(n) = t.admit(SEARCH_MOVE_KEY, 1, i * 30 * S) {
                logged.push((i, n));
            }
        }
        assert_eq!(logged, vec![(0, 0), (20, 19), (40, 19)]);
        // the other kinds keep the common period
        assert_eq!(t.admit(DEGRADED_KEY, 1, 0), Some(0));
        assert_eq!(t.admit(DEGRADED_KEY, 1, 10 * S), Some(0));
    }

    #[test]
    fn latency_steps_are_counted_from_the_log() {
        let log = "\
x INFO vlsyncd::runtime: cam stamps +12.1 ms later from t=3.000 s on (its stamping latency stepped)
x INFO vlsyncd::runtime: 3 more cam stamping-latency steps since the last such line
x INFO vlsyncd::runtime: lidar stamps -2.0 ms later from t=9.000 s on (its stamping latency stepped)
x WARN vlsyncd::runtime: 2 more cam samples lost (sequence gaps) since the last such line
x INFO vlsyncd::runtime: 1 more cam stamping-latency steps since the last such line";
        assert_eq!(latency_steps_logged(log, "cam"), 5);
        assert_eq!(latency_steps_logged(log, "lidar"), 1);
        assert_eq!(latency_steps_logged("", "cam"), 0);
        let log = "\
x WARN vlsyncd::runtime: the acquisition found no lock in 30 s of motion: searching around +0.0 ms now instead of -310.0 ms (...)
x WARN vlsyncd::runtime: 19 more moves of the search (no lock where it searched) since the last such line";
        assert_eq!(search_moves_logged(log), 20);
        // a named line that ends a throttled period carries the count held back
        let log = "\
x INFO vlsyncd::runtime: offset stepped by about +24.4 ms at LiDAR t=997.878 s (found in the data; the estimate restarts from the data after it)
x INFO vlsyncd::runtime: 4 more offset steps found in the data since the last such line
x INFO vlsyncd::runtime: offset stepped by about -18.1 ms at LiDAR t=1184.878 s (found in the data; the estimate restarts from the data after it) (2 more since the last such line)
x WARN vlsyncd::runtime: processing took 213 µs, over budget: estimator degraded (narrower search) until 5s pass without an overrun
x WARN vlsyncd::runtime: 7 more switches to degraded mode (processing over budget) since the last such line";
        assert_eq!(offset_steps_logged(log), 8);
        assert_eq!(degraded_switches_logged(log), 8);
        assert_eq!(search_moves_logged(log), 0);
    }

    /// A hung driver: its stream's count stands still while the other's moves. Said
    /// once after 30 s (naming since when), not again while it lasts; its return
    /// said once when its silence was said. A stream that never delivered is said
    /// too, from the watch's start.
    #[test]
    fn a_stream_that_stops_for_good_is_news_once_and_its_return_once() {
        let mut w = SilentStreams::new(SILENT_STREAM_NS, 5 * S);
        // polled every 0.1 s: the camera delivers throughout, the LiDAR until 20 s
        let mut news = vec![];
        let mut cam = 0u64;
        let mut lidar = 0u64;
        for i in 50..3000i64 {
            let now = i * S / 10;
            cam += 3;
            if now <= 20 * S {
                lidar += 1;
            }
            if now >= 200 * S {
                lidar += 1;
            }
            for n in w.observe([cam, lidar], now).into_iter().flatten() {
                news.push(n);
                if let StreamNews::Silent { si, .. } = n {
                    w.said(si);
                }
            }
        }
        assert_eq!(
            news,
            vec![
                StreamNews::Silent {
                    si: 1,
                    since_ns: 20 * S,
                    for_ns: 30 * S,
                    ever: true
                },
                StreamNews::Resumed {
                    si: 1,
                    after_ns: 180 * S
                },
            ]
        );
        // a silence not said (held back by the throttle): its return is no news; a
        // stream that never delivered: silent since the watch began
        let mut w = SilentStreams::new(SILENT_STREAM_NS, 0);
        assert_eq!(w.observe([1, 0], 29 * S), [None, None]);
        assert_eq!(
            w.observe([1, 0], 30 * S),
            [
                None,
                Some(StreamNews::Silent {
                    si: 1,
                    since_ns: 0,
                    for_ns: 30 * S,
                    ever: false
                })
            ]
        );
        assert_eq!(w.observe([1, 0], 31 * S)[1], None);
        assert_eq!(w.observe([1, 5], 40 * S), [None, None]);
        assert_eq!(
            w.observe([1, 5], 59 * S)[0],
            Some(StreamNews::Silent {
                si: 0,
                since_ns: 29 * S,
                for_ns: 30 * S,
                ever: true
            })
        );
        w.said(0);
        w.said(7);
        assert_eq!(
            w.observe([2, 6], 60 * S),
            [
                Some(StreamNews::Resumed {
                    si: 0,
                    after_ns: 31 * S
                }),
                None
            ]
        );
    }

    proptest! {
        // Nothing is lost: every event is either in a logged line's own count, a
        // suppressed count reported later, or still pending.
        #[test]
        fn throttle_accounts_for_every_event(
            evs in proptest::collection::vec((0usize..KINDS, 1u64..5, 0i64..(3 * S)), 0..200)
        ) {
            let mut evs = evs;
            evs.sort_by_key(|e| e.2);
            let mut t = Throttle::new(S);
            let mut total = [0u64; KINDS];
            let mut accounted = [0u64; KINDS];
            for &(k, n, at) in &evs {
                total[k] += n;
                if let Some(before) = t.admit(k, n, at) {
                    accounted[k] += before + n;
                }
                t.due(at, |k, c| accounted[k] += c);
            }
            t.due(i64::MAX, |k, c| accounted[k] += c);
            prop_assert_eq!(total, accounted);
        }
    }

    fn est(state: EstimatorState, offset_s: f64) -> Estimate {
        Estimate {
            seq: 0,
            t_ref_ns: 0,
            offset_s,
            drift: 12e-6,
            offset_std_s: 0.0012,
            drift_std: 4e-6,
            state,
            polarity: Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: 2.0,
            measured_offset_s: f64::NAN,
        }
    }

    #[test]
    fn a_latency_line_says_which_samples_were_timed() {
        let s = LatencyStretch {
            span_ns: 120 * S,
            samples: 10,
            processing_ns: [1_000, 2_000, 3_000],
            timed: 4,
            end_to_end_ns: [50_000, 60_000, 70_000],
            overruns: 2,
        };
        let line = latency_line(&s, 150.0);
        assert!(
            line.starts_with("latency, last 2 min: 10 samples, processing p50 1.0 µs"),
            "{line}"
        );
        assert!(line.contains("2 over the 150 µs budget"), "{line}");
        let short = latency_line(
            &LatencyStretch {
                span_ns: 5 * S,
                ..s
            },
            150.0,
        );
        assert!(
            short.starts_with("latency, last 5 s: 10 samples"),
            "{short}"
        );
        let odd = latency_line(
            &LatencyStretch {
                span_ns: 150 * S,
                ..s
            },
            150.0,
        );
        assert!(odd.starts_with("latency, last 2.5 min: "), "{odd}");
        let late = latency_line(
            &LatencyStretch {
                span_ns: 600 * S + 20_000_000,
                ..s
            },
            150.0,
        );
        assert!(late.starts_with("latency, last 10 min: "), "{late}");
        assert!(
            line.ends_with("max 70.0 µs (4 of the samples timed)"),
            "{line}"
        );
        // no driver publish time at all: no end-to-end part
        let line = latency_line(&LatencyStretch { timed: 0, ..s }, 150.0);
        assert!(line.ends_with("over the 150 µs budget"), "{line}");
    }

    #[test]
    fn summary_every_period_with_shares_and_counter_deltas() {
        let mut s = Summary::new(600 * S, 0);
        assert_eq!(s.due(0), None);
        let mut st = Status {
            received: [18_000, 6_000],
            lost: [0, 3],
            ..Default::default()
        };
        s.on_status(&st);
        for i in 0..10 {
            let state = if i < 9 {
                EstimatorState::Tracking
            } else {
                EstimatorState::Holding
            };
            s.on_estimate(&est(state, 0.1234));
        }
        s.on_offset_step();
        s.on_offset_step();
        s.on_search_move();
        // written when the real-time thread's stretch ends
        assert_eq!(s.due(1199 * S), None);
        let line = s.close(600 * S);
        assert!(
            line.starts_with(
                "last 10 min: 10 estimates (tracking 90 %, holding 10 %), 2 offset steps, 1 search moves;"
            ),
            "{line}"
        );
        assert!(
            line.contains("now holding: offset +123.40 ± 1.20 ms, drift +12.0 ± 4.0 ppm"),
            "{line}"
        );
        assert!(
            line.contains("cam 18000 received, 0 rejected, 0 lost"),
            "{line}"
        );
        assert!(
            line.contains("lidar 6000 received, 0 rejected, 3 lost"),
            "{line}"
        );
        // the next period counts from the last summary's totals
        st.received = [18_100, 6_030];
        st.rejected[0][0] = 2;
        s.on_status(&st);
        // that event lost twice (a flooded channel): written after two and a half
        // periods all the same
        assert_eq!(s.due(2099 * S), None);
        let line = s.due(2100 * S).unwrap();
        // the step and move counts are per period too
        assert!(line.starts_with("last 25 min: 0 estimates;"), "{line}");
        assert!(
            line.contains("cam 100 received, 2 rejected, 0 lost"),
            "{line}"
        );
    }
}
