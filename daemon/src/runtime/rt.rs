//! The real-time thread: its set-up (core, SCHED_FIFO, the services), then the loop
//! that receives, estimates and publishes, with its counters and histograms. After
//! start-up it allocates nothing per sample, logs nothing and does no I/O: events
//! and statuses go to the service thread over bounded channels (`try_send`).

use super::*;
use vlsync_ipc::iceoryx2::port::listener::ListenerWaitError;

/// Counters and histograms of the real-time thread, preallocated.
pub struct RtCounters {
    pub(super) status: Status,
    pub(super) processing: Histogram,
    pub(super) end_to_end: Histogram,
    pub(super) last_seq: [SeqTable; 2],
    pub(super) events_dropped: u64,
    /// The current stretch's latency (the log's summary period), beside the run's.
    stretch: Stretch,
}

/// Latency histograms of one stretch of the run.
#[derive(Debug)]
struct Stretch {
    start_ns: Nanos,
    processing: Histogram,
    end_to_end: Histogram,
    overruns_before: u64,
}

impl RtCounters {
    pub(super) fn new() -> Self {
        Self {
            status: Status::default(),
            processing: Histogram::new(),
            end_to_end: Histogram::new(),
            last_seq: [SeqTable::default(); 2],
            events_dropped: 0,
            stretch: Stretch {
                start_ns: 0,
                processing: Histogram::new(),
                end_to_end: Histogram::new(),
                overruns_before: 0,
            },
        }
    }

    /// Records one sample's processing time and, when its driver's publish time
    /// gave one, its end-to-end latency, in the run's and the stretch's histograms.
    pub(super) fn record_latency(&mut self, processing_ns: u64, end_to_end_ns: Option<u64>) {
        self.processing.record(processing_ns);
        self.stretch.processing.record(processing_ns);
        if let Some(e) = end_to_end_ns {
            self.end_to_end.record(e);
            self.stretch.end_to_end.record(e);
        }
    }

    /// Starts the first stretch at `now`.
    pub(super) fn start_stretch(&mut self, now: Nanos) {
        self.stretch.start_ns = now;
        self.stretch.overruns_before = self.status.budget_overruns;
    }

    /// Ends the stretch at `now` and starts the next: its latency (`samples` 0 for
    /// an idle stretch). No allocation.
    pub(super) fn end_stretch(&mut self, now: Nanos) -> journal::LatencyStretch {
        let st = &mut self.stretch;
        let out = journal::LatencyStretch {
            span_ns: now.saturating_sub(st.start_ns).max(0),
            samples: st.processing.count(),
            processing_ns: st.processing.summary(),
            timed: st.end_to_end.count(),
            end_to_end_ns: st.end_to_end.summary(),
            overruns: self
                .status
                .budget_overruns
                .saturating_sub(st.overruns_before),
        };
        st.processing.clear();
        st.end_to_end.clear();
        st.start_ns = now;
        st.overruns_before = self.status.budget_overruns;
        out
    }
}

pub(super) fn emit(tx: &Sender<RtEvent>, c: &mut RtCounters, ev: RtEvent) {
    emit_sent(tx, c, ev);
}

/// [`emit`], saying whether the event went out (false: dropped and counted).
pub(super) fn emit_sent(tx: &Sender<RtEvent>, c: &mut RtCounters, ev: RtEvent) -> bool {
    match tx.try_send(ev) {
        Ok(()) => true,
        Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
            c.events_dropped += 1;
            false
        }
    }
}

/// Which held sample (0: camera, 1: LiDAR) comes next: the one its driver published
/// first (`publish_ns`, both drivers on this host's `CLOCK_MONOTONIC`), the camera's
/// on a tie; `None` when none is held. Only the order within the backlog depends on
/// it, so a foreign or hostile `publish_ns` cannot hold a sample back for longer
/// than the other stream's backlog takes to drain (over several wake-ups when it is
/// longer than [`MAX_SAMPLES_PER_WAKE`]).
pub(super) fn first_published(
    pending: &[Option<(SignatureSample, UniquePublisherId)>; 2],
) -> Option<usize> {
    match (&pending[0], &pending[1]) {
        (None, None) => None,
        (Some(_), None) => Some(0),
        (None, Some(_)) => Some(1),
        (Some((cam, _)), Some((lidar, _))) => Some(usize::from(lidar.publish_ns < cam.publish_ns)),
    }
}

/// The largest sequence jump counted as lost samples (see [`SeqTable::gap_of`]); the
/// recorder (`vlsyncd record`) judges gaps by the same rule ([`seq_step`] and
/// [`seq_followed`]), on one sequence per stream where the daemon follows each
/// publisher's.
pub(crate) const MAX_COUNTED_GAP: u64 = 1 << 32;

/// What a sample's sequence number says ([`SeqTable::gap_of`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum SeqGap {
    /// The next one of its publisher, a restart, a jump back, or one beyond
    /// [`MAX_COUNTED_GAP`]: nothing lost.
    None,
    /// This many samples lost since the publisher's previous one.
    Lost(u64),
    /// The first sample read from a publisher, numbered `n` without `FLAG_FIRST`:
    /// its `n` earlier samples were published before this daemon listened (a
    /// daemon restarted under running drivers), or dropped from a full buffer
    /// before the daemon read any (a driver's `--fast` burst at its start); the
    /// daemon cannot tell which, so they are not counted as lost.
    Joined(u64),
}

/// What a sample numbered `seq` says after its publisher's previous one read, `last`
/// (`None`: none read yet): the rule the daemon ([`SeqTable::gap_of`]) and the recorder
/// (`vlsyncd record`) both judge by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum SeqStep {
    /// The next one.
    Next,
    /// This many samples lost since the previous one.
    Lost(u64),
    /// A run's first sample read: a publisher's first, its restart (`FLAG_FIRST`), a
    /// number that went back, or one that jumped further than any buffer loses (a
    /// counter restarted or corrupt). `before`: the samples the publisher numbered
    /// before it and nobody read (0 after `FLAG_FIRST` or a corrupt counter).
    NewRun {
        /// Samples published before it, unread.
        before: u64,
    },
}

/// Whether a sample whose number says `step` becomes its publisher's last one read, the
/// one the next is judged after: every valid sample; a malformed one (its structure
/// invalid, e.g. `reserved` not zero) only when it is exactly the next number
/// ([`SeqStep::Next`]: it was published, so its successor is no gap). Its number is
/// otherwise as unreliable as the rest of it: followed, garbage would count the gap
/// before the next good sample as lost (good 100, malformed 0, good 101 counted 100
/// lost), or a jump forward as up to [`MAX_COUNTED_GAP`] lost. Nothing is counted for
/// a malformed sample (lost samples, a restart, samples before it); the samples lost
/// before one that was not followed are counted at its publisher's next good sample,
/// whose gap then covers the malformed one too (rejected and lost: its number could
/// not be trusted). The daemon and the recorder both judge by this.
pub(crate) fn seq_followed(step: SeqStep, valid: bool) -> bool {
    valid || step == SeqStep::Next
}

/// [`SeqStep`] of `seq` after `last`; `first`: the sample carries `FLAG_FIRST`.
pub(crate) fn seq_step(last: Option<u64>, seq: u64, first: bool) -> SeqStep {
    let new_run = SeqStep::NewRun {
        before: if first || seq > MAX_COUNTED_GAP {
            0
        } else {
            seq
        },
    };
    match last {
        None => new_run,
        Some(_) if first => new_run,
        // no subscriber buffer loses billions of samples: a jump that far is a
        // publisher whose counter restarted or is corrupt, not a loss
        Some(l) if seq <= l || seq - l - 1 > MAX_COUNTED_GAP => new_run,
        Some(l) if seq - l == 1 => SeqStep::Next,
        Some(l) => SeqStep::Lost(seq - l - 1),
    }
}

/// Publishers of one stream whose sequence the daemon follows at once: a driver and
/// its restarts, a recorder's replay, a second publisher beside them.
pub(super) const SEQ_SLOTS: usize = 4;

/// One publisher's entry in a [`SeqTable`].
#[derive(Debug, Clone, Copy)]
struct SeqSlot {
    publisher: UniquePublisherId,
    /// The sequence number of its last sample read.
    seq: u64,
    /// When it was last read (the table's read counter): the least recently read
    /// slot is the one a new publisher takes.
    read: u64,
}

/// The sequence of each publisher of a stream ([`SeqTable::gap_of`]): what a sample's
/// sequence number says of the samples before it. Fixed size, no allocation.
///
/// A publisher whose slot is needed goes when it is the least recently read of
/// [`SEQ_SLOTS`]: a driver that died (or restarted, which is a new publisher) stops
/// being read, so after any number of restarts the live publishers keep their slots
/// and each new one is still judged from its first sample ([`SeqGap::Joined`]). Only
/// more than [`SEQ_SLOTS`] publishers alive on one stream at once take slots from one
/// another: a publisher that comes back to a stream it was evicted from is then said
/// to have joined again (a log line, never a count), and the gap across its absence
/// goes uncounted.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct SeqTable {
    slots: [Option<SeqSlot>; SEQ_SLOTS],
    /// Samples read so far: the stamp of the newest read.
    reads: u64,
}

impl SeqTable {
    /// [`SeqTable::gap_of`] for a valid sample (the tests' shorthand).
    #[cfg(test)]
    pub(super) fn gap(&mut self, publisher: UniquePublisherId, seq: u64, first: bool) -> SeqGap {
        self.gap_of(publisher, seq, first, true)
    }

    /// What a sample numbered `seq` of `publisher` says ([`seq_step`] per
    /// publisher); `first`: it carries `FLAG_FIRST`; `valid`: it passed validation.
    /// Every sample read goes through here. A malformed one says nothing
    /// ([`SeqGap::None`]), and is followed only as [`seq_followed`] says: when it is
    /// exactly the next number of a publisher already read (its successor is then no
    /// gap); it takes no slot for a publisher not read yet, and otherwise leaves its
    /// publisher's sequence as it was.
    pub(super) fn gap_of(
        &mut self,
        publisher: UniquePublisherId,
        seq: u64,
        first: bool,
        valid: bool,
    ) -> SeqGap {
        if !valid {
            if let Some(slot) = self
                .slots
                .iter_mut()
                .flatten()
                .find(|s| s.publisher == publisher)
            {
                if seq_followed(seq_step(Some(slot.seq), seq, first), false) {
                    self.reads += 1;
                    slot.seq = seq;
                    slot.read = self.reads;
                }
            }
            return SeqGap::None;
        }
        self.reads += 1;
        let read = self.reads;
        if let Some(slot) = self
            .slots
            .iter_mut()
            .flatten()
            .find(|s| s.publisher == publisher)
        {
            let last = slot.seq;
            slot.seq = seq;
            slot.read = read;
            // a run restarted within a publisher the daemon reads: nothing to count
            return match seq_step(Some(last), seq, first) {
                SeqStep::Lost(n) => SeqGap::Lost(n),
                SeqStep::Next | SeqStep::NewRun { .. } => SeqGap::None,
            };
        }
        // a new publisher: a free slot, or the least recently read one's
        let idx = self
            .slots
            .iter()
            .position(Option::is_none)
            .unwrap_or_else(|| {
                self.slots
                    .iter()
                    .enumerate()
                    .min_by_key(|(_, s)| s.map_or(0, |s| s.read))
                    .map_or(0, |(i, _)| i)
            });
        self.slots[idx] = Some(SeqSlot {
            publisher,
            seq,
            read,
        });
        match seq_step(None, seq, first) {
            SeqStep::NewRun { before } if before > 0 => SeqGap::Joined(before),
            _ => SeqGap::None,
        }
    }
}

/// The bookkeeping of one sample read from `stream`, before the estimator: counts it
/// received, follows its publisher's sequence and says a driver's (re)start; then
/// rejects (and counts) a malformed sample. Whether the sample goes on to the
/// estimator.
///
/// A malformed sample counts no loss, and its sequence number is followed only when
/// it is exactly its publisher's next ([`seq_followed`]): then the next sample is its
/// successor, not one after a lost sample (it used to be counted both rejected and
/// lost); any other number it carries is ignored (garbage there counted good samples
/// lost), and a gap before it is counted at the next good sample. No allocation.
pub(super) fn admit(
    c: &mut RtCounters,
    tx: &Sender<RtEvent>,
    stream: Stream,
    w: &SignatureSample,
    publisher: UniquePublisherId,
) -> bool {
    let si = stream_index(stream);
    c.status.received[si] += 1;
    let check = w.validate();
    let valid = check.is_ok();
    if valid && w.is_first() {
        emit(tx, c, RtEvent::DriverStarted { stream });
    }
    match c.last_seq[si].gap_of(publisher, w.seq, w.is_first(), valid) {
        SeqGap::None => {}
        SeqGap::Lost(lost) => {
            c.status.lost[si] = c.status.lost[si].saturating_add(lost);
            emit(
                tx,
                c,
                RtEvent::Lost {
                    stream,
                    count: lost,
                },
            );
        }
        SeqGap::Joined(before) => emit(tx, c, RtEvent::Joined { stream, before }),
    }
    if !valid {
        c.status.rejected[si][REJECT_MALFORMED] += 1;
        emit(
            tx,
            c,
            RtEvent::Rejected {
                stream,
                reason: REJECT_MALFORMED,
                t_ns: w.t_ns,
                why: check.err(),
            },
        );
    }
    valid
}

/// Failed waits on the signature event in a row after which the real-time thread
/// gives up (about 5 s of them, each followed by a [`WAKE_PERIOD`] sleep): the daemon
/// then stops with an error, which makes systemd restart it (`Restart=always`; its
/// non-zero exit also marks the stop as a failure in `systemctl status`),
/// rather than read its streams by polling for good.
pub const MAX_WAIT_FAILURES: u32 = 50;

/// What the real-time loop does after a wait on the signature event ([`WaitFailures`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum AfterWait {
    /// It waited (woken, timed out, or interrupted by a signal): go on.
    Go,
    /// It failed: say so, sleep [`WAKE_PERIOD`], then read the streams.
    Pause,
    /// It failed [`MAX_WAIT_FAILURES`] times in a row: stop with an error.
    GiveUp,
}

/// Counts the real-time loop's failed waits in a row (a wait that fails at once,
/// retried at once, would spin the loop at SCHED_FIFO).
#[derive(Debug, Default)]
pub(super) struct WaitFailures {
    in_a_row: u32,
}

impl WaitFailures {
    /// What to do after a wait that returned `waited`.
    pub(super) fn after<T>(&mut self, waited: &Result<T, ListenerWaitError>) -> AfterWait {
        match waited {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => {
                self.in_a_row = 0;
                AfterWait::Go
            }
            Err(_) => {
                self.in_a_row = self.in_a_row.saturating_add(1);
                if self.in_a_row >= MAX_WAIT_FAILURES {
                    AfterWait::GiveUp
                } else {
                    AfterWait::Pause
                }
            }
        }
    }
}

/// Wake-ups by a notification in a row that read no sample, within one
/// [`WAKE_PERIOD`], after which the real-time loop sleeps to that period's end
/// ([`EmptyWakes`]).
pub(super) const MAX_EMPTY_WAKES: u32 = 64;

/// What a sleep of the real-time loop after [`MAX_EMPTY_WAKES`] wake-ups without a
/// sample says (through the journal's throttle, with the count of the others).
pub(super) const EMPTY_WAKES_SAID: &str = "64 wake-ups on the signature event within 0.1 s \
     read no sample (a process notifying `<prefix>/signature/ready` in a loop?): slept to \
     the end of the 0.1 s, the streams read after it";

/// Counts the real-time loop's wake-ups by a notification that read no sample. A
/// process notifying the signature event in a loop keeps the listener signalled:
/// each wait returns at once, finds nothing, and the loop would spin at SCHED_FIFO.
/// After [`MAX_EMPTY_WAKES`] of them within one [`WAKE_PERIOD`] the loop sleeps to
/// that period's end (then reads both streams and checks its stop and heartbeat, as
/// after a timeout). A wake-up that read a sample, or a timeout, starts the count
/// again: a notification with data never sleeps. No allocation.
#[derive(Debug, Default)]
pub(super) struct EmptyWakes {
    in_a_row: u32,
    /// When the first of them in a row came.
    since: Nanos,
}

impl EmptyWakes {
    /// After a wake-up at `now`: `notified` (an event woke it, not the timeout),
    /// `served` samples read. How long the loop sleeps before its next wait: none,
    /// but after the [`MAX_EMPTY_WAKES`]-th wake-up in a row that was notified and
    /// read nothing within `period_ns` (the first of them starts the period), what is
    /// left of that period.
    pub(super) fn after(
        &mut self,
        now: Nanos,
        notified: bool,
        served: usize,
        period_ns: Nanos,
    ) -> Option<Duration> {
        if !notified || served > 0 {
            self.in_a_row = 0;
            return None;
        }
        if self.in_a_row == 0 || now.saturating_sub(self.since) >= period_ns {
            self.in_a_row = 0;
            self.since = now;
        }
        self.in_a_row += 1;
        if self.in_a_row < MAX_EMPTY_WAKES {
            return None;
        }
        self.in_a_row = 0;
        let left = self
            .since
            .saturating_add(period_ns)
            .saturating_sub(now)
            .clamp(0, period_ns.max(0));
        Some(Duration::from_nanos(left as u64))
    }
}

/// Everything the real-time thread needs, built before its loop starts.
pub(super) struct RtSetup {
    pub(super) cfg: Config,
    pub(super) names: ServiceNames,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) tx: Sender<RtEvent>,
    /// The periodic status snapshots (their own channel: a full event channel
    /// does not drop them).
    pub(super) status_tx: Sender<Status>,
    pub(super) start_ns: Nanos,
    /// Incremented every loop: the watchdog's proof of progress.
    pub(super) heartbeat: Arc<AtomicU64>,
    /// A saved estimate and its age (s) to start from.
    pub(super) restore: Option<(Estimate, f64)>,
    /// Load hints: `CLOCK_MONOTONIC` times at which the offset may have stepped.
    pub(super) hints: Receiver<Nanos>,
    /// Per stream: publishers that joined and could not be connected (counted by the
    /// subscriber's degradation handler; the service thread says so).
    pub(super) unconnected: Arc<[AtomicU64; 2]>,
    /// Offset clients the publisher could not connect, or whose connection it found
    /// corrupt at a send (its degradation handler; the service thread says so).
    pub(super) offset_degraded: Arc<AtomicU64>,
    /// Per stream: the samples read so far (`Status::received`), stored every loop
    /// (relaxed, no wait): the service thread says a stream that stops for good.
    pub(super) received: Arc<[AtomicU64; 2]>,
}

/// What the real-time thread reports once, before its loop.
#[derive(Debug, Clone)]
pub struct RtReport {
    /// System refusals of real-time settings, and the settings of services another
    /// program created below vlsync's where the daemon works with them
    /// (`vlsync_ipc::QosWarning`: the offset service's, the signature services' fewer
    /// publishers); each a readable sentence, said as a warning.
    pub refused: Vec<String>,
    /// Real-time settings applied.
    pub applied: Vec<String>,
    /// Subscriber buffer requested/granted.
    pub buffer: (usize, usize),
}

pub(super) fn apply_rt_settings(cfg: &Config) -> RtReport {
    let mut r = RtReport {
        refused: vec![],
        applied: vec![],
        buffer: (0, 0),
    };
    if cfg.daemon.core >= 0 {
        match vlsync_ipc::rt::pin_current_thread(cfg.daemon.core as usize) {
            Ok(()) => r
                .applied
                .push(format!("pinned to core {}", cfg.daemon.core)),
            Err(e) => r.refused.push(e.to_string()),
        }
    }
    if cfg.daemon.fifo_priority > 0 {
        match vlsync_ipc::rt::set_current_thread_fifo(cfg.daemon.fifo_priority as i32) {
            Ok(()) => r
                .applied
                .push(format!("SCHED_FIFO priority {}", cfg.daemon.fifo_priority)),
            Err(e) => r.refused.push(e.to_string()),
        }
    }
    r
}

/// The real-time thread: set-up, then the loop. A set-up error goes to `ready` as
/// text; `Err` when the loop gave up ([`MAX_WAIT_FAILURES`]), so the daemon exits
/// with an error and its service manager restarts it.
pub(super) fn rt_thread(
    s: RtSetup,
    ready: std::sync::mpsc::Sender<Result<RtReport, String>>,
) -> Result<(), String> {
    let mut report = apply_rt_settings(&s.cfg);
    let setup = (|| -> Result<_, vlsync_ipc::IpcError> {
        let node = create_node("vlsyncd-rt", false)?;
        let buf = s.cfg.services.subscriber_buffer.max(1) as usize;
        let mut subs = Vec::with_capacity(2);
        let mut granted = buf;
        let mut factories = Vec::with_capacity(2);
        for stream in [Stream::Cam, Stream::Lidar] {
            let name = s.names.signature(stream);
            let f = open_or_create_pubsub::<SignatureSample>(&node, &name, Qos::signature(buf))?;
            // a service another program created with fewer publishers (its smaller
            // buffer is the granted buffer, said on its own)
            for w in vlsync_ipc::service_warnings(&name, &f, Qos::signature(buf)) {
                if matches!(w, vlsync_ipc::QosWarning::FewerPublishers { .. }) {
                    report.refused.push(w.to_string());
                }
            }
            let count = s.unconnected.clone();
            let (sub, b) = subscriber_telling(&f, buf, &name, move || {
                count[stream_index(stream)].fetch_add(1, Ordering::Relaxed);
            })?;
            granted = granted.min(b.granted);
            subs.push(sub);
            factories.push(f);
        }
        let ready_ev = open_or_create_event(&node, &s.names.signature_ready())?;
        let lis = listener(&ready_ev, &s.names.signature_ready())?;
        let off = open_or_create_pubsub::<OffsetEstimate>(&node, &s.names.offset(), Qos::latest())?;
        for w in vlsync_ipc::service_warnings(&s.names.offset(), &off, Qos::latest()) {
            report.refused.push(w.to_string());
        }
        let degraded = s.offset_degraded.clone();
        let off_pub = publisher_telling(&off, &s.names.offset(), move || {
            degraded.fetch_add(1, Ordering::Relaxed);
        })?;
        let off_ev = open_or_create_event(&node, &s.names.offset())?;
        let off_not = notifier(&off_ev, &s.names.offset())?;
        Ok((
            node, subs, factories, ready_ev, lis, off, off_pub, off_ev, off_not, granted,
        ))
    })();
    let (_node, subs, _factories, _ready_ev, lis, _off, off_pub, _off_ev, off_not, granted) =
        match setup {
            Ok(v) => v,
            Err(e) => {
                let _ = ready.send(Err(e.to_string()));
                return Ok(());
            }
        };
    report.buffer = (s.cfg.services.subscriber_buffer.max(1) as usize, granted);
    let mut est = Estimator::new(&s.cfg.estimator);
    if let Some((saved, age_s)) = &s.restore {
        est.restore(saved, *age_s);
    }
    let mut c = RtCounters::new();
    let budget_ns = (s.cfg.daemon.latency_budget_us * 1e3) as u64;
    let status_period_ns = (s.cfg.daemon.status_period_s * 1e9) as i64;
    let quiet_ns = DEGRADED_QUIET.as_nanos() as i64;
    let mut degraded = false;
    let mut last_overrun: Nanos = 0;
    let mut last_state: Option<EstimatorState> = None;
    let mut next_status = monotonic_ns() + status_period_ns;
    // the offset publisher's connections are updated every WAKE_PERIOD
    let wake_ns = WAKE_PERIOD.as_nanos() as i64;
    let mut next_connect = monotonic_ns();
    // the log's latency line, every summary period (`daemon.summary_period_s`)
    let stretch_ns = (s.cfg.daemon.summary_period_s * 1e9) as i64;
    let mut next_stretch = monotonic_ns() + stretch_ns;
    c.start_stretch(monotonic_ns());
    // the newest LiDAR sample: its stamp and when its driver published it
    // (`CLOCK_MONOTONIC`), which dates a load hint on the LiDAR clock
    let mut lidar_clock: Option<(Nanos, Nanos)> = None;
    // per stream: the estimator's gap count already said, the last accepted stamp
    let mut seen_gaps = [0u64; 2];
    // per stream: its samples come from a simulator (FLAG_SIMULATED), said on change
    let mut simulated = [false; 2];
    let mut last_t: [Option<Nanos>; 2] = [None; 2];
    let max_gap_ns = (s.cfg.estimator.max_gap_s * 1e9) as Nanos;
    let _ = ready.send(Ok(report));

    // a wake-up that served MAX_SAMPLES_PER_WAKE left samples waiting: the next one
    // does not sleep
    let mut backlog = false;
    // the sample held per stream for the publish-order merge below; kept across
    // wake-ups, so a wake-up that ends at MAX_SAMPLES_PER_WAKE resumes the merge
    // where it stopped (the order does not break at the boundary)
    let mut pending: [Option<(SignatureSample, UniquePublisherId)>; 2] = [None, None];
    let mut wait_failures = WaitFailures::default();
    // wake-ups by a notification that read nothing (a process notifying in a loop)
    let mut empty_wakes = EmptyWakes::default();
    // how the loop ended: a stop, or (Err) a wait that kept failing
    let mut ended = Ok(());
    // ---- real-time loop: no logging, no I/O, no allocation per sample below ----
    // (iceoryx2's own messages from the calls below are held, not printed: iox_log)
    super::iox_log::mute_this_thread();
    while !s.stop.load(Ordering::Relaxed) && !termination_requested() {
        s.heartbeat.fetch_add(1, Ordering::Relaxed);
        for (count, &n) in s.received.iter().zip(&c.status.received) {
            count.store(n, Ordering::Relaxed);
        }
        // sleeps until a driver notifies; a signal or timeout just loops
        // which streams notified (each driver notifies with its stream's event id);
        // a timeout or a foreign id reads both
        let mut ready = [false; 2];
        let on_event =
            |ev: vlsync_ipc::iceoryx2::port::EventActivation| match [Stream::Cam, Stream::Lidar]
                .map(|st| ev.id == stream_event_id(st))
            {
                [true, _] => ready[0] = true,
                [_, true] => ready[1] = true,
                _ => ready = [true; 2],
            };
        let waited = if backlog {
            lis.try_wait(on_event)
        } else {
            lis.timed_wait(on_event, WAKE_PERIOD)
        };
        // a notification woke it (not the timeout, not a failure)
        let notified = matches!(waited, Ok(n) if n > 0);
        if backlog || ready == [false; 2] {
            // a backlog, or no driver notified (idle, a driver that does not
            // notify, or a failed wait): both streams are read
            ready = [true; 2];
        }
        match wait_failures.after(&waited) {
            AfterWait::Go => {}
            AfterWait::Pause => {
                // a wait that fails at once would make this loop a busy spin (at
                // SCHED_FIFO, the heartbeat still feeding the watchdog): said, and
                // the period slept instead, the streams read after it as after a
                // timeout
                emit(
                    &s.tx,
                    &mut c,
                    RtEvent::Fatal(
                        "wait on the signature event failed; reading every 0.1 s instead",
                    ),
                );
                std::thread::sleep(WAKE_PERIOD);
            }
            AfterWait::GiveUp => {
                ended = Err(format!(
                    "the real-time thread gave up: its wait on `{}` failed {MAX_WAIT_FAILURES} \
                     times in a row ({:?})",
                    s.names.signature_ready(),
                    waited.err()
                ));
                break;
            }
        }
        // both streams' waiting samples in the order their drivers published them
        // (one held per stream): after a stall the backlogs interleave as they were
        // made, which the estimator's judgement of a clock jump relies on. Before the
        // first sample only the streams that notified are read, so a lone sample's
        // latency holds no read of the other subscriber; after it every stream is
        // read until it is empty (a publisher that does not notify is still served)
        let mut empty = [false; 2];
        let mut any = pending.iter().any(Option::is_some);
        // at most MAX_SAMPLES_PER_WAKE handled per wake-up: a publisher faster than
        // the daemon (or one that floods without notifying) cannot keep it from its
        // stop check, its heartbeat (the watchdog), statuses and the end of degraded
        // mode
        let mut served = 0usize;
        backlog = false;
        loop {
            if served >= MAX_SAMPLES_PER_WAKE {
                backlog = true;
                break;
            }
            for (i, sub) in subs.iter().enumerate() {
                if pending[i].is_some() || empty[i] || !(ready[i] || any) {
                    continue;
                }
                match sub.receive() {
                    Ok(Some(x)) => pending[i] = Some((*x.payload(), x.header().publisher_id())),
                    Ok(None) => empty[i] = true,
                    Err(_) => {
                        empty[i] = true;
                        emit(
                            &s.tx,
                            &mut c,
                            RtEvent::Fatal("receive on a signature service failed"),
                        );
                    }
                }
            }
            let Some(si) = first_published(&pending) else {
                if any || empty == [true; 2] {
                    break;
                }
                // the streams that notified had nothing: read the others
                any = true;
                continue;
            };
            any = true;
            let Some((w, pid)) = pending[si].take() else {
                break;
            };
            served += 1;
            let stream = if si == 0 { Stream::Cam } else { Stream::Lidar };
            let t0 = monotonic_ns();
            if !admit(&mut c, &s.tx, stream, &w, pid) {
                continue;
            }
            // the state changes only with an event that reached the service thread (a
            // full channel drops it: the next sample tries again)
            if w.is_simulated() != simulated[si]
                && emit_sent(
                    &s.tx,
                    &mut c,
                    RtEvent::Simulated {
                        stream,
                        on: w.is_simulated(),
                    },
                )
            {
                simulated[si] = w.is_simulated();
            }
            let clock_reading =
                (stream == Stream::Lidar && w.publish_ns > 0).then_some((w.t_ns, w.publish_ns));
            let pushed = est.push_urgent(stream, w.sample());
            // a silence longer than estimator.max_gap_s broke the window here: said
            // (throttled), or a stream whose every interval is one would leave the
            // daemon silent with a clean log
            // (said when the stream resumes; a gap the estimator counts for a stamp
            // that did not advance after its cadence correction is no silence)
            let gaps = est.stats().gaps[si];
            if gaps > seen_gaps[si] {
                seen_gaps[si] = gaps;
                let after_ns = last_t[si].map_or(0, |t| w.t_ns.saturating_sub(t));
                if after_ns > max_gap_ns {
                    emit(
                        &s.tx,
                        &mut c,
                        RtEvent::Silence {
                            stream,
                            after_ns,
                            limit_ns: max_gap_ns,
                        },
                    );
                }
            }
            if pushed.is_ok() {
                last_t[si] = Some(w.t_ns);
            }
            if let Err(r) = pushed {
                c.status.rejected[si][r.index()] += 1;
                emit(
                    &s.tx,
                    &mut c,
                    RtEvent::Rejected {
                        stream,
                        reason: r.index(),
                        t_ns: w.t_ns,
                        why: None,
                    },
                );
            } else if let Some((t_l, pub_ns)) = clock_reading {
                // only a sample the estimator took dates load hints, and only with a
                // publish time that is a latency (as below): a rejected far-future
                // stamp or a foreign publish_ns would put a hint's change where no
                // data ever comes
                if (0..MAX_LATENCY_NS).contains(&(t0 - pub_ns)) {
                    lidar_clock = Some((t_l, pub_ns));
                }
            }
            if let Some(st) = est.take_latency_step() {
                emit(&s.tx, &mut c, RtEvent::LatencyStep(st));
            }
            while let Some(e) = est.poll() {
                // an estimate the wire refuses (a σ that is not finite and positive,
                // say) is counted and goes nowhere: not published, so neither saved
                // for the next start nor shown as the daemon's state
                if !publish_estimate(&e, &off_pub, &off_not, &s.tx, &mut c) {
                    continue;
                }
                emit(&s.tx, &mut c, RtEvent::Estimate(e));
                if last_state != Some(e.state) {
                    emit(
                        &s.tx,
                        &mut c,
                        RtEvent::State {
                            from: last_state,
                            to: e.state,
                        },
                    );
                    last_state = Some(e.state);
                    c.status.state = e.state as u8;
                }
            }
            let t1 = monotonic_ns();
            let proc_ns = (t1 - t0).max(0) as u64;
            // driver publish -> done with the sample (estimate published if one was due);
            // a hostile or foreign-host publish_ns outside 0..MAX_LATENCY_NS is not a
            // latency (a positive one cannot overflow the difference)
            let e2e = (w.publish_ns > 0)
                .then(|| t1 - w.publish_ns)
                .filter(|e| (0..MAX_LATENCY_NS).contains(e))
                .map(|e| e as u64);
            c.record_latency(proc_ns, e2e);
            if proc_ns > budget_ns {
                c.status.budget_overruns += 1;
                last_overrun = t1;
                if !degraded {
                    degraded = true;
                    est.set_degraded(true);
                    emit(
                        &s.tx,
                        &mut c,
                        RtEvent::Degraded {
                            on: true,
                            processing_ns: proc_ns,
                        },
                    );
                }
            }
            // the estimator's background stage (step test, next hop's preparation)
            // once the sample is done and its estimate out: the same estimates as
            // `push` alone, none of that work in the sample's latency; a sample
            // arriving meanwhile waits for it, and its latency shows that
            est.idle();
            // the step test's verdict comes from either stage, a search moves in `push`
            if let Some(st) = est.take_offset_step() {
                emit(&s.tx, &mut c, RtEvent::OffsetStep(st));
            }
            if let Some(m) = est.take_search_move() {
                emit(&s.tx, &mut c, RtEvent::SearchMoved(m));
            }
        }
        while let Ok(at_mono) = s.hints.try_recv() {
            match lidar_clock {
                Some((t_l, pub_ns)) => {
                    let t_lidar_ns = t_l.saturating_add(at_mono.saturating_sub(pub_ns));
                    est.hint_change(t_lidar_ns, vlsync_estimator::HINT_STEP_STD_S);
                    emit(&s.tx, &mut c, RtEvent::ChangeDeclared { t_lidar_ns });
                }
                None => emit(&s.tx, &mut c, RtEvent::HintUndated),
            }
        }
        let now = monotonic_ns();
        // a wake-up by a notification that read nothing, the 64th within 0.1 s: the
        // rest of that 0.1 s is slept below, after the periodic work
        let flood_sleep = empty_wakes.after(now, notified, served, wake_ns);
        if now >= next_connect {
            // connect the offset subscribers that came since the last estimate,
            // which hands them the last one (history 1) now, not at the next
            // estimate: a hop away, or never from an idle daemon. By time, not at a
            // wake-up without notification, which drivers at 10-30 Hz never leave;
            // cheap when no subscriber came or went
            next_connect = now + wake_ns;
            let _ = off_pub.update_connections();
        }
        if degraded && now - last_overrun > quiet_ns {
            degraded = false;
            est.set_degraded(false);
            emit(
                &s.tx,
                &mut c,
                RtEvent::Degraded {
                    on: false,
                    processing_ns: 0,
                },
            );
        }
        // a stretch's end comes with a status of its own: the service thread reads
        // statuses before events, so the summary it writes at the stretch's end
        // counts the samples up to it, as the latency line does
        let stretch_ends = now >= next_stretch;
        if now >= next_status || stretch_ends {
            next_status = now + status_period_ns;
            let st = snapshot(&mut c, degraded, s.start_ns, now);
            hand_status(&s.status_tx, &mut c, st);
            if s.cfg.daemon.latency_per_period {
                c.processing.clear();
                c.end_to_end.clear();
            }
        }
        if stretch_ends {
            next_stretch = now + stretch_ns;
            let l = c.end_stretch(now);
            emit(&s.tx, &mut c, RtEvent::Latency(l));
        }
        if let Some(d) = flood_sleep {
            // said through the throttle (the count of sleeps is the count of lines
            // held back); the streams are read after the sleep, as after a timeout
            emit(&s.tx, &mut c, RtEvent::NotifyFlood);
            std::thread::sleep(d);
        }
    }
    super::iox_log::unmute_this_thread();
    // final status so the last counters are not lost, then the last stretch's
    // latency (since the last summary period's end), which the service thread logs
    // with its "at stop" summary. The thread is ending: it may wait for a slot (a
    // service thread that fell STATUS_CAPACITY statuses or a full channel of events
    // behind) rather than lose either
    let now = monotonic_ns();
    let st = snapshot(&mut c, degraded, s.start_ns, now);
    let _ = s.status_tx.send_timeout(st, Duration::from_secs(1));
    let last = c.end_stretch(now);
    let _ =
        s.tx.send_timeout(RtEvent::LastLatency(last), Duration::from_secs(1));
    ended
}

/// Hands a status snapshot to the service thread; a full status channel (a service
/// thread that has fallen [`STATUS_CAPACITY`] statuses behind) counts a drop.
pub(super) fn hand_status(tx: &Sender<Status>, c: &mut RtCounters, st: Status) {
    if tx.try_send(st).is_err() {
        c.events_dropped += 1;
    }
}

pub(super) fn snapshot(c: &mut RtCounters, degraded: bool, start_ns: Nanos, now: Nanos) -> Status {
    c.status.uptime_ns = (now - start_ns).max(0);
    c.status.publish_ns = now;
    c.status.processing_ns = c.processing.summary();
    c.status.end_to_end_ns = c.end_to_end.summary();
    c.status.latency_count = c.end_to_end.count();
    c.status.events_dropped = c.events_dropped;
    c.status.degraded = u8::from(degraded);
    c.status
}

/// Publishes `e`; `false` when the wire refuses it (counted as an
/// `InvalidEstimate` event), `true` when it is valid, sent or not (a failed send
/// is its own event).
pub(super) fn publish_estimate(
    e: &Estimate,
    off_pub: &vlsync_ipc::iceoryx2::port::publisher::Publisher<vlsync_ipc::Svc, OffsetEstimate, ()>,
    off_not: &vlsync_ipc::iceoryx2::port::notifier::Notifier<vlsync_ipc::Svc>,
    tx: &Sender<RtEvent>,
    c: &mut RtCounters,
) -> bool {
    let w = match OffsetEstimate::from_estimate(e, monotonic_ns()) {
        Ok(w) => w,
        Err(_) => {
            emit(tx, c, RtEvent::InvalidEstimate { seq: e.seq });
            return false;
        }
    };
    let sent = match off_pub.loan_uninit() {
        Ok(s) => s.write_payload(w).send().is_ok(),
        Err(_) => false,
    };
    if sent {
        c.status.estimates_published += 1;
        let _ = off_not.notify();
    } else {
        emit(tx, c, RtEvent::PublishFailed { seq: e.seq });
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: Nanos = 1_000_000_000;

    /// A wait that keeps failing pauses the loop each time and stops it after
    /// MAX_WAIT_FAILURES in a row; a wait that works (or a signal) starts the count
    /// again.
    #[test]
    fn failed_waits_pause_the_loop_and_end_it_when_they_go_on() {
        let mut w = WaitFailures::default();
        let fail: Result<u64, _> = Err(ListenerWaitError::InternalFailure);
        assert_eq!(w.after(&Ok(0u64)), AfterWait::Go);
        for _ in 1..MAX_WAIT_FAILURES {
            assert_eq!(w.after(&fail), AfterWait::Pause);
        }
        assert_eq!(w.after(&Ok(3u64)), AfterWait::Go);
        for _ in 1..MAX_WAIT_FAILURES {
            assert_eq!(w.after(&fail), AfterWait::Pause);
        }
        assert_eq!(
            w.after(&Err::<u64, _>(ListenerWaitError::InterruptSignal)),
            AfterWait::Go
        );
        for _ in 1..MAX_WAIT_FAILURES {
            assert_eq!(w.after(&fail), AfterWait::Pause);
        }
        assert_eq!(
            w.after(&Err::<u64, _>(ListenerWaitError::ContractViolation)),
            AfterWait::GiveUp
        );
        // about 5 s of pauses: the watchdog's period
        assert_eq!(WAKE_PERIOD * MAX_WAIT_FAILURES, Duration::from_secs(5));
    }

    fn pid(n: u8) -> UniquePublisherId {
        crate::runtime::tests::pid("mal", n)
    }

    /// A malformed sample's number is followed only when it is exactly the next one:
    /// garbage there neither counts good samples lost nor moves its publisher's
    /// sequence, and a malformed first sample takes no slot.
    #[test]
    fn a_malformed_sample_is_followed_only_as_the_next_number() {
        let (a, b) = (pid(1), pid(2));
        let mut t = SeqTable::default();
        assert_eq!(t.gap(a, 100, false), SeqGap::Joined(100));
        // a malformed one numbered 0 between 100 and 101: nothing lost
        assert_eq!(t.gap_of(a, 0, false, false), SeqGap::None);
        assert_eq!(t.gap(a, 101, false), SeqGap::None);
        // one jumping forward: neither counted, nor followed
        assert_eq!(t.gap_of(a, 101 + (1 << 31), false, false), SeqGap::None);
        assert_eq!(t.gap(a, 102, false), SeqGap::None);
        // one at the end of the range, and one with FLAG_FIRST: the same
        assert_eq!(t.gap_of(a, u64::MAX, false, false), SeqGap::None);
        assert_eq!(t.gap_of(a, 0, true, false), SeqGap::None);
        assert_eq!(t.gap(a, 103, false), SeqGap::None);
        // the exact next one is followed: its successor is no gap...
        assert_eq!(t.gap_of(a, 104, false, false), SeqGap::None);
        assert_eq!(t.gap(a, 105, false), SeqGap::None);
        // ...but one further on is not: the next good one's gap counts from 105
        assert_eq!(t.gap_of(a, 110, false, false), SeqGap::None);
        assert_eq!(t.gap(a, 108, false), SeqGap::Lost(2));
        // a publisher first read through a malformed sample: no slot taken, so its
        // first good sample is judged as its first
        assert_eq!(t.gap_of(b, 7, false, false), SeqGap::None);
        assert_eq!(t.gap(b, 50, false), SeqGap::Joined(50));
        // the rule the recorder shares
        assert!(seq_followed(SeqStep::Next, false));
        assert!(!seq_followed(SeqStep::Lost(3), false));
        assert!(!seq_followed(SeqStep::NewRun { before: 0 }, false));
        assert!(seq_followed(SeqStep::Lost(3), true));
        assert!(seq_followed(SeqStep::NewRun { before: 9 }, true));
    }

    /// A process notifying the signature event in a loop: the 64th notified wake-up
    /// in a row that read nothing within 0.1 s sleeps the rest of that 0.1 s; a
    /// wake-up that read a sample, or a timeout, never sleeps and starts the count
    /// again; empty wake-ups spread over more than 0.1 s never add up to a sleep.
    #[test]
    fn empty_wake_ups_in_a_flood_sleep_to_the_end_of_the_period() {
        const P: Nanos = 100_000_000;
        let mut w = EmptyWakes::default();
        let t0 = 5 * S;
        for k in 0..MAX_EMPTY_WAKES as i64 - 1 {
            assert_eq!(w.after(t0 + k * 1_000, true, 0, P), None, "wake-up {k}");
        }
        let at = t0 + 63_000;
        assert_eq!(
            w.after(at, true, 0, P),
            Some(Duration::from_nanos((P - 63_000) as u64))
        );
        // the next flood: counted from its own first wake-up
        for k in 0..MAX_EMPTY_WAKES as i64 - 1 {
            assert_eq!(w.after(t0 + P + k, true, 0, P), None);
        }
        // a notification with data: no sleep, and the count starts again
        assert_eq!(w.after(t0 + P + 100, true, 1, P), None);
        for k in 0..MAX_EMPTY_WAKES as i64 - 1 {
            assert_eq!(w.after(t0 + P + 200 + k, true, 0, P), None);
        }
        // a timeout (no notification) too
        assert_eq!(w.after(t0 + P + 300, false, 0, P), None);
        for k in 0..MAX_EMPTY_WAKES as i64 - 1 {
            assert_eq!(w.after(t0 + 2 * P + k, true, 0, P), None);
        }
        assert!(w.after(t0 + 2 * P + 64, true, 0, P).is_some());
        // a slow trickle (one empty wake-up every 2 ms): never 64 within 0.1 s
        let mut w = EmptyWakes::default();
        for k in 0..1_000 {
            assert_eq!(w.after(k * 2_000_000, true, 0, P), None, "wake-up {k}");
        }
        // hostile clock values: no overflow, a sleep of at most the period
        let mut w = EmptyWakes::default();
        for _ in 0..MAX_EMPTY_WAKES - 1 {
            assert_eq!(w.after(i64::MAX, true, 0, P), None);
        }
        assert_eq!(w.after(i64::MAX, true, 0, P), Some(Duration::ZERO));
    }

    #[test]
    fn each_stretch_reports_only_its_own_latency() {
        let mut c = RtCounters::new();
        c.start_stretch(10 * S);
        // a slow first stretch: 99 samples of 10 µs, one of 500 µs over budget
        for _ in 0..99 {
            c.record_latency(10_000, Some(100_000));
        }
        c.record_latency(500_000, None);
        c.status.budget_overruns += 1;
        let first = c.end_stretch(610 * S);
        assert_eq!(first.span_ns, 600 * S);
        assert_eq!((first.samples, first.timed, first.overruns), (100, 99, 1));
        assert_eq!(first.processing_ns[2], 500_000);
        assert!(
            (10_000..=10_700).contains(&first.processing_ns[0]),
            "{first:?}"
        );
        // a quiet second stretch: the first one's outlier is gone from it
        for _ in 0..50 {
            c.record_latency(8_000, Some(90_000));
        }
        let second = c.end_stretch(1210 * S);
        assert_eq!((second.samples, second.timed, second.overruns), (50, 50, 0));
        assert_eq!(second.processing_ns[2], 8_000);
        assert_eq!(second.end_to_end_ns[2], 90_000);
        // the run's histograms keep everything
        assert_eq!(c.processing.count(), 150);
        assert_eq!(c.processing.max(), 500_000);
        assert_eq!(c.end_to_end.count(), 149);
        // an idle stretch: nothing processed
        let idle = c.end_stretch(1810 * S);
        assert_eq!(
            (idle.samples, idle.timed, idle.processing_ns),
            (0, 0, [0; 3])
        );
        c.record_latency(7_000, None);
        let after_idle = c.end_stretch(2410 * S);
        assert_eq!((after_idle.span_ns, after_idle.samples), (600 * S, 1));
    }

    #[test]
    fn a_stretch_is_recorded_ended_and_sent_without_allocating() {
        let mut c = RtCounters::new();
        let (tx, rx) = crossbeam::channel::bounded(4);
        c.start_stretch(0);
        let before = vlsync_alloc_count::this_thread();
        for k in 0..3 {
            for i in 0..1000u64 {
                c.record_latency(1_000 + i * 37, (i % 3 != 0).then_some(50_000 + i));
            }
            let l = c.end_stretch((k + 1) * 600 * S);
            emit(&tx, &mut c, RtEvent::Latency(l));
        }
        let allocated = vlsync_alloc_count::this_thread() - before;
        vlsync_alloc_count::assert_counting();
        // it ran: three stretches reached the channel, each its own
        let got: Vec<_> = rx.try_iter().collect();
        assert_eq!(got.len(), 3);
        assert!(got
            .iter()
            .all(|e| matches!(e, RtEvent::Latency(l) if l.samples == 1000 && l.timed == 666)));
        assert_eq!(allocated, 0);
    }
}
