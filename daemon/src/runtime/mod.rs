//! `vlsyncd run`: the real-time estimator service.
//!
//! Three threads (the third, `vlsync-state`, writes the state file: see
//! [`crate::state::Saver`]):
//!
//! * the **real-time thread** (pinned to `daemon.core`, optionally SCHED_FIFO)
//!   sleeps on one iceoryx2 listener (`<prefix>/signature/ready`) until a driver
//!   publishes, drains both signature subscribers in the order the drivers
//!   published (`first_published`), validates every payload
//!   (shared memory is hostile input), pushes into the [`Estimator`], publishes
//!   every estimate on `<prefix>/offset` and notifies; then, the sample done and
//!   its latency recorded, it runs the estimator's background stage
//!   (`Estimator::idle`: the step test and the next hop's preparation, spread
//!   over the samples between hops). After start-up it logs
//!   nothing, does no I/O and allocates nothing per sample: counters live in
//!   fixed arrays and [`Histogram`]s, and events go to the other thread over a
//!   bounded crossbeam channel with `try_send` (a full channel counts a drop).
//!   The service thread polls that channel and never blocks on it, so no receiver
//!   is ever registered with the channel's waker and a `try_send` is a lock-free
//!   slot write: no mutex (a blocked receiver's waker is one, without priority
//!   inheritance) and no futex wake-up on the real-time path.
//!   The one heap allocation left is inside iceoryx2 0.10: each
//!   `Publisher::loan_uninit` allocates a small shared-state object, i.e. one
//!   per published estimate (2/s by default); `tests/tests/ipc_rt_alloc.rs`
//!   pins that bound;
//! * the **service thread** (the main thread) logs those events with tracing
//!   and publishes the [`Status`] snapshots the real-time thread hands it every
//!   `daemon.status_period_s` (and at the end of each `daemon.summary_period_s`),
//!   polling both channels every [`SERVICE_POLL_BUSY`] while events come, every
//!   [`SERVICE_POLL_IDLE`] when they do not, and again at once after a poll that
//!   met [`EVENTS_PER_POLL`]. Statuses have a channel of their own (capacity
//!   [`STATUS_CAPACITY`]), which the service thread reads before each event: a
//!   flood of events that fills the event channel (a publisher faster than the
//!   daemon) drops events, never the statuses that report it. Every repeated line
//!   goes through one [`journal::Throttle`]: the real-time thread's events, and the
//!   service thread's own (publishers of a stream or clients of the offset and status
//!   services iceoryx2 could not connect, load steps and hints, failed notifications
//!   of systemd); a stream whose received count (stored by the real-time thread every
//!   loop) stands still for [`journal::SILENT_STREAM_NS`] is a warning, its return
//!   information ([`journal::SilentStreams`]);
//! * the **state thread** (`vlsync-state`) writes the state file the service thread
//!   hands it, so a slow SD card never holds up the watchdog's petting.
//!
//! The latency percentiles of a status cover the whole run, or only the last
//! status period with `daemon.latency_per_period` (the load harness reads them
//! per phase). Every `daemon.summary_period_s` (10 min by default) the real-time
//! thread also hands over the percentiles of that stretch alone
//! ([`journal::LatencyStretch`], from a second pair of histograms), logged as one
//! line beside the summary of the estimates: after months a whole-run p99 would
//! no longer move.
//!
//! Over budget (`daemon.latency_budget_us` for one sample) the estimator is put
//! in degraded mode (`Estimator::set_degraded(true)`: a narrower search per
//! sample); it returns to normal after [`DEGRADED_QUIET`] without overrun.
//!
//! # One daemon per prefix
//!
//! The daemon holds an exclusive `flock` on `/tmp/vlsync/<prefix>.lock` (`/` in
//! the prefix written as `%`). The kernel drops the lock when the process dies,
//! even by SIGKILL, so a crash never leaves a stale lock behind and no liveness
//! guessing (pid files, timeouts) is needed; a second daemon on the same prefix
//! fails at once naming the lock and the pid holding it. A clean stop removes the
//! file (per-run prefixes such as the demo's would pile up otherwise); a starting
//! daemon checks that the file it locked is still the one at the path. A file it may
//! not write (another user's, e.g. a daemon run by hand as root) is locked read-only
//! and replaced where the directory allows. The file is opened without following a
//! link (`O_NOFOLLOW`) and must be a regular file with one name, and a lock directory
//! of another user (not root) that others may write without the sticky bit is
//! refused: nobody can make a root daemon truncate a file of theirs choosing.
//!
//! # Crash clean-up
//!
//! At start the daemon removes the iceoryx2 resources of dead nodes
//! (`Node::try_cleanup_dead_nodes`, right after creating its node, which is
//! made without iceoryx2's own clean-up at creation so that the count is the
//! daemon's; iceoryx2 does it whenever any other node is created) and reports
//! how many it reclaimed, so a daemon or driver killed
//! with SIGKILL leaves nothing that blocks a restart.
//!
//! # systemd and persistence
//!
//! Under systemd ([`notify`]) the service thread sends `READY=1` once the real-time
//! thread runs, a `STATUS=` line per status period, and pets the watchdog only
//! while the real-time thread's heartbeat (incremented every loop) moves;
//! `STOPPING=1` on shutdown. A wait on the signature event that fails does not
//! spin the loop: it is said (`RtEvent::Fatal`) and followed by a [`WAKE_PERIOD`]
//! sleep, and after `rt::MAX_WAIT_FAILURES` in a row (about 5 s) the real-time
//! thread gives up and the daemon exits with an error, which systemd restarts. With `daemon.state_file` set ([`crate::state`]) the
//! service thread keeps the last good estimate (handed over as
//! [`RtEvent::Estimate`]) and has it saved atomically by the state thread
//! (`vlsync-state`: an fsync that stalls holds neither the watchdog pings nor the
//! status) at most every 5 s while it changes, every 60 s while it does not
//! (`state::SAVE_PERIOD`, `state::REFRESH_PERIOD`), and on shutdown (waiting up to
//! `state::FINAL_SAVE_WAIT`), and a
//! fresh enough saved estimate is restored into the estimator before the
//! real-time loop starts.
#![forbid(unsafe_code)]

pub mod histogram;
pub mod journal;
pub mod loadwatch;
pub mod notify;
pub mod procs;

mod events;
mod instance;
pub mod iox_log;
#[cfg(test)]
mod live_tests;
pub(crate) mod rt;

use events::{log_event, report_suppressed, tell_clients, tell_silent_streams, tell_unconnected};
pub use instance::{lock_path, single_instance_lock, InstanceLock};
use rt::{rt_thread, RtSetup};
pub use rt::{RtCounters, RtReport};

use crossbeam::channel::{bounded, Receiver, Sender, TrySendError};
use histogram::Histogram;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use vlsync_common::wire::{
    OffsetEstimate, SignatureSample, Status, REJECT_MALFORMED, REJECT_NAMES,
};
use vlsync_common::{Estimate, EstimatorState, Nanos, Stream};
use vlsync_config::Config;
use vlsync_estimator::Estimator;
use vlsync_ipc::iceoryx2::identifiers::UniquePublisherId;
use vlsync_ipc::iceoryx2::port::update_connections::UpdateConnections;
use vlsync_ipc::{
    cleanup_dead_nodes, create_node, listener, monotonic_ns, notifier, open_or_create_event,
    open_or_create_pubsub, publisher_telling, stream_event_id, stream_index, subscriber_telling,
    termination_requested, Qos, ServiceNames,
};

/// Time without budget overrun after which degraded mode is cleared.
pub const DEGRADED_QUIET: Duration = Duration::from_secs(5);
/// Longest sleep of the real-time thread (to notice a stop request and publish status).
pub const WAKE_PERIOD: Duration = Duration::from_millis(100);

/// How long a stop waits for the real-time thread to end (it looks at the stop at
/// least every [`WAKE_PERIOD`]) before the service thread finishes without it: well
/// inside the unit's `TimeoutStopSec`, with the final save's own wait after it.
pub const RT_STOP_WAIT: Duration = Duration::from_secs(3);

/// Samples the real-time loop reads per wake-up at most before it checks for a stop,
/// beats its heartbeat and hands a status over (then it goes on without sleeping):
/// two default subscriber buffers, a few milliseconds of work.
pub const MAX_SAMPLES_PER_WAKE: usize = 512;
/// A sample's publish time further back than this (ns), or in the future, is not a
/// latency: a foreign host's or a hostile `publish_ns`. Such a sample is neither in
/// the end-to-end histogram nor dates a load hint.
pub const MAX_LATENCY_NS: Nanos = 10_000_000_000;
/// Name of the real-time thread (its `comm` in `/proc`, where the demo reads the
/// scheduling the kernel gave it).
pub const RT_THREAD_NAME: &str = "vlsync-rt";
/// Capacity of the event channel between the threads.
pub const EVENT_CAPACITY: usize = 1024;
/// Capacity of the status channel between the threads: statuses the service thread
/// may fall behind by before one is dropped (and counted in `events_dropped`).
pub const STATUS_CAPACITY: usize = 4;
/// Poll period of the service thread while the real-time thread hands it events.
pub const SERVICE_POLL_BUSY: Duration = Duration::from_millis(10);
/// Poll period of the service thread when its last poll found nothing (what an idle
/// daemon wakes for, as the real-time thread's [`WAKE_PERIOD`]).
pub const SERVICE_POLL_IDLE: Duration = WAKE_PERIOD;
/// Events (and statuses) the service thread handles per poll at most before it
/// runs its periodic duties (watchdog, state file, load watch) again.
pub const EVENTS_PER_POLL: usize = EVENT_CAPACITY;

/// Arguments of `vlsyncd run`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct RunArgs {
    /// Configuration file (TOML); defaults are used without it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Service prefix; overrides `services.prefix` of the configuration.
    #[arg(long)]
    pub prefix: Option<String>,
    /// SCHED_FIFO priority of the real-time thread, 0-99 (0: the normal scheduler);
    /// overrides `daemon.fifo_priority` of the configuration. Where the system refuses
    /// it, the daemon says so and runs.
    #[arg(long, allow_negative_numbers = true, value_parser = clap::value_parser!(i64).range(0..=99))]
    pub fifo_priority: Option<i64>,
}

/// What the real-time thread tells the service thread. `Copy`, no heap: sending
/// one never allocates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RtEvent {
    /// A sample failed structural validation or was rejected by the estimator.
    Rejected {
        /// Stream.
        stream: Stream,
        /// Index into [`REJECT_NAMES`].
        reason: usize,
        /// Its timestamp.
        t_ns: Nanos,
        /// What its validation said, for a malformed sample (which flag bits, which
        /// field: what a C driver's author needs to fix it).
        why: Option<vlsync_common::wire::WireError>,
    },
    /// A silence of a stream longer than `estimator.max_gap_s`: the estimator broke
    /// its window there (no interpolation across it).
    Silence {
        /// Stream.
        stream: Stream,
        /// From the stream's last accepted sample to this one, ns (0: none before).
        after_ns: Nanos,
        /// `estimator.max_gap_s`, ns.
        limit_ns: Nanos,
    },
    /// A stream's samples started to come from a simulator (`FLAG_SIMULATED`), or
    /// from a sensor again.
    Simulated {
        /// Stream.
        stream: Stream,
        /// Simulated now.
        on: bool,
    },
    /// Samples lost: a sequence gap.
    Lost {
        /// Stream.
        stream: Stream,
        /// How many.
        count: u64,
    },
    /// A driver (re)started (its first sample arrived).
    DriverStarted {
        /// Stream.
        stream: Stream,
    },
    /// The first sample read from a publisher was not its first one
    /// (`rt::SeqGap::Joined`).
    Joined {
        /// Stream.
        stream: Stream,
        /// Samples it had published before (the number of the first one read).
        before: u64,
    },
    /// The estimator state changed.
    State {
        /// Previous state (`None` before the first estimate).
        from: Option<EstimatorState>,
        /// New state.
        to: EstimatorState,
    },
    /// An estimate failed validation and was not published.
    InvalidEstimate {
        /// Its sequence number.
        seq: u64,
    },
    /// Publishing an estimate failed.
    PublishFailed {
        /// Its sequence number.
        seq: u64,
    },
    /// Degraded mode switched.
    Degraded {
        /// On or off.
        on: bool,
        /// The processing time that switched it on, ns (0 when off).
        processing_ns: u64,
    },
    /// A valid estimate, published (unless its send failed: its own event); persisted
    /// and shown by the service thread.
    Estimate(Estimate),
    /// A load hint became a declared change point of the estimator.
    ChangeDeclared {
        /// The change's time on the LiDAR clock, ns.
        t_lidar_ns: Nanos,
    },
    /// A load hint arrived before any LiDAR sample: no clock to date it on.
    HintUndated,
    /// A stream's stamping latency stepped (the estimator follows it from the stamps).
    LatencyStep(vlsync_estimator::LatencyStep),
    /// The data showed an offset step: the estimator started a new segment.
    OffsetStep(vlsync_estimator::OffsetStep),
    /// The acquisition moved its lag range (nothing found where it searched).
    SearchMoved(vlsync_estimator::SearchMove),
    /// The latency of the stretch of the run that just ended (the log's summary
    /// period, sent even when idle): ends the period's summary, and its latency is
    /// logged as one line when it processed samples.
    Latency(journal::LatencyStretch),
    /// The latency of the stretch since the last [`RtEvent::Latency`], sent once as
    /// the real-time thread stops, after its final status: the service thread writes
    /// the "at stop" summary and this latency line over the same stretch.
    LastLatency(journal::LatencyStretch),
    /// An iceoryx2 call of the real-time loop failed (the text is static); the loop
    /// goes on (a failed receive marks that stream empty until the next wake-up; a
    /// failed wait is followed by a [`WAKE_PERIOD`] sleep, and
    /// `MAX_WAIT_FAILURES` (50) in a row stop the daemon with an error).
    /// Logged as an error through the journal's throttle, with the count.
    Fatal(&'static str),
    /// The real-time loop slept to the end of its wake period after
    /// `rt::MAX_EMPTY_WAKES` notifications in a row that brought no sample (a
    /// process notifying the signature event in a loop). A warning through the
    /// journal's throttle, with the count.
    NotifyFlood,
}

/// The service thread's wait before its next poll of the channels, after a poll
/// that handled `handled` events and statuses: none when it stopped at
/// [`EVENTS_PER_POLL`] (a backlog: a sleep would only let a flood drop more),
/// short while the real-time thread hands it events (on this poll or the one
/// before, `found_last`), else [`SERVICE_POLL_IDLE`].
fn service_wait(found_last: bool, handled: usize) -> Option<Duration> {
    if handled >= EVENTS_PER_POLL {
        None
    } else if handled > 0 || found_last {
        Some(SERVICE_POLL_BUSY)
    } else {
        Some(SERVICE_POLL_IDLE)
    }
}

/// What a thread's panic said (its payload is a `&str` or a `String`).
fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|m| m.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown cause".to_string())
}

/// How often the CPU pressure is read for load hints, ns.
pub const LOAD_PERIOD_NS: Nanos = 250_000_000;
/// At most one load hint per this many seconds.
pub const LOAD_HINT_INTERVAL_S: f64 = 10.0;

/// The load-hint detector and its next reading time, when `daemon.load_hints` is on
/// and the kernel publishes CPU pressure (says so when it does not).
fn load_watch(cfg: &Config) -> Option<(loadwatch::LoadWatch, Nanos)> {
    if !cfg.daemon.load_hints {
        return None;
    }
    match loadwatch::read_pressure(&cfg.daemon.load_hint_source) {
        Ok(_) => {
            tracing::info!(
                "load hints on: a change of {:.0} points of CPU pressure ({}) declares an offset change",
                cfg.daemon.load_hint_threshold * 100.0,
                cfg.daemon.load_hint_source
            );
            Some((
                loadwatch::LoadWatch::new(cfg.daemon.load_hint_threshold, LOAD_HINT_INTERVAL_S),
                0,
            ))
        }
        Err(e) => {
            tracing::warn!(
                "daemon.load_hints: {e} (for /proc/pressure: a kernel without PSI, or booted with psi=0); running without load hints"
            );
            None
        }
    }
}

/// Loads the configuration of `args`.
pub fn load_config(args: &RunArgs) -> Result<Config, String> {
    let mut cfg = match &args.config {
        Some(p) => Config::load(p).map_err(|e| e.to_string())?,
        None => Config::default(),
    };
    if let Some(p) = &args.prefix {
        cfg.services.prefix = p.clone();
        cfg.validate("--prefix").map_err(|e| e.to_string())?;
    }
    if let Some(p) = args.fifo_priority {
        cfg.daemon.fifo_priority = p;
        cfg.validate("--fifo-priority").map_err(|e| e.to_string())?;
    }
    Ok(cfg)
}

/// Exit status of `vlsyncd run` when its configuration cannot be loaded (sysexits'
/// `EX_CONFIG`, which systemd shows as `status=78/CONFIG`): the unit's
/// `RestartPreventExitStatus=78` leaves it failed instead of restarting a daemon
/// that would fail the same way. Every other error exits 2 and is restarted.
pub const EXIT_CONFIG: u8 = 78;

/// `vlsyncd run` with the configuration [`load_config`] gave: runs until
/// SIGINT/SIGTERM.
pub fn run_cli(cfg: Config) -> Result<(), String> {
    // a RUST_LOG that does not parse is said once logging runs, not dropped silently
    let (filter, bad_filter) = log_filter(std::env::var("RUST_LOG").ok().as_deref());
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()));
    let _ = if vlsync_common::console::stderr_is_journal() {
        // under systemd: each line with its priority (journald stored every one at
        // "info"), and without the time journald adds itself
        builder
            .event_format(JournalFormat(
                tracing_subscriber::fmt::format().without_time(),
            ))
            .try_init()
    } else {
        builder.try_init()
    };
    if let Some(why) = bad_filter {
        tracing::warn!("{why}");
    }
    run(cfg, Arc::new(AtomicBool::new(false)))
}

/// The log filter for `RUST_LOG` (`info` without it), and what was wrong with a
/// `RUST_LOG` that does not parse (the daemon then logs at `info`). iceoryx2's own
/// messages (target `iceoryx2`, [`iox_log`]) pass whatever the filter says unless
/// `RUST_LOG` names that target: `IOX2_LOG_LEVEL` already chose them (error by
/// default), as it did when iceoryx2 printed them itself.
fn log_filter(rust_log: Option<&str>) -> (tracing_subscriber::EnvFilter, Option<String>) {
    let info = || tracing_subscriber::EnvFilter::new("info");
    let (f, bad) = match rust_log {
        None => (info(), None),
        Some(v) => match tracing_subscriber::EnvFilter::try_new(v) {
            Ok(f) => (f, None),
            Err(e) => (
                info(),
                Some(format!(
                    "RUST_LOG `{}` is no log filter ({e}): logging at info",
                    vlsync_common::text::clip(v)
                )),
            ),
        },
    };
    if rust_log.is_some_and(|v| bad.is_none() && v.contains("iceoryx2")) {
        return (f, bad);
    }
    match "iceoryx2=trace".parse() {
        Ok(d) => (f.add_directive(d), bad),
        Err(_) => (f, bad),
    }
}

/// A log line to the journal: the `sd-daemon(3)` priority prefix of its level, then
/// the line as `F` formats it.
pub struct JournalFormat<F>(pub F);

impl<S, N, F> tracing_subscriber::fmt::FormatEvent<S, N> for JournalFormat<F>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
    N: for<'a> tracing_subscriber::fmt::FormatFields<'a> + 'static,
    F: tracing_subscriber::fmt::FormatEvent<S, N>,
{
    fn format_event(
        &self,
        ctx: &tracing_subscriber::fmt::FmtContext<'_, S, N>,
        mut writer: tracing_subscriber::fmt::format::Writer<'_>,
        event: &tracing::Event<'_>,
    ) -> std::fmt::Result {
        use vlsync_common::console::{priority_prefix, Priority};
        let p = match *event.metadata().level() {
            tracing::Level::ERROR => Priority::Error,
            tracing::Level::WARN => Priority::Warning,
            tracing::Level::INFO => Priority::Info,
            _ => Priority::Debug,
        };
        writer.write_str(priority_prefix(true, p))?;
        self.0.format_event(ctx, writer, event)
    }
}

/// Runs the daemon with `cfg` until SIGINT/SIGTERM or `stop` is set.
pub fn run(cfg: Config, stop: Arc<AtomicBool>) -> Result<(), String> {
    // first of all, so a stop that comes during start-up is a clean stop (the
    // lock file removed, STOPPING=1) and not the default action's death
    vlsync_ipc::handle_termination_signals();
    let start_ns = monotonic_ns();
    let names = ServiceNames::new(&cfg.services.prefix).map_err(|e| e.to_string())?;
    let _lock = single_instance_lock(&names.prefix)?;
    if let Some(note) = crate::check::work_note(&cfg.estimator) {
        tracing::warn!("{}", note.trim_start_matches("note: "));
    }
    // before the first node: iceoryx2 takes its logger once
    if !iox_log::install() {
        tracing::warn!(
            "iceoryx2 chose its logger before the daemon could route it: its messages on \
             the real-time thread are printed there (stderr), not held"
        );
    }
    let node = vlsync_ipc::create_node_cleaning_later("vlsyncd").map_err(|e| e.to_string())?;
    let (cleaned, failed) = cleanup_dead_nodes(&node);
    if cleaned > 0 || failed > 0 {
        tracing::info!(
            "removed the iceoryx2 resources of {cleaned} dead process(es){}",
            if failed > 0 {
                format!(", {failed} could not be removed")
            } else {
                String::new()
            }
        );
    }
    if cfg.daemon.lock_memory {
        match vlsync_ipc::rt::lock_all_memory() {
            Ok(()) => tracing::info!("memory locked (mlockall)"),
            Err(e) => tracing::warn!("{e}; running without"),
        }
    }
    // held until the daemon returns: closing the file ends the request
    let _cpu_latency = u32::try_from(cfg.daemon.cpu_latency_us)
        .ok()
        .and_then(|us| {
            let dev = Path::new(vlsync_ipc::rt::CPU_LATENCY_DEVICE);
            match vlsync_ipc::rt::request_cpu_latency(us, dev) {
                Ok(f) => {
                    tracing::info!("CPU wake-up latency held at {us} µs ({})", dev.display());
                    Some(f)
                }
                Err(e) => {
                    tracing::warn!("{e}; running without");
                    None
                }
            }
        });
    let status_svc = open_or_create_pubsub::<Status>(&node, &names.status(), Qos::latest())
        .map_err(|e| e.to_string())?;
    // a status service another program created with fewer publishers or smaller
    // buffers than ours still serves; said (a missing history is refused at the open)
    for w in vlsync_ipc::service_warnings(&names.status(), &status_svc, Qos::latest()) {
        tracing::warn!("{w}; starting anyway");
    }
    // a client it cannot connect, or whose connection is corrupt, is counted and said
    // through the throttle (iceoryx2's default: an error line at every status sent)
    let status_degraded = Arc::new(AtomicU64::new(0));
    let status_pub = {
        let count = status_degraded.clone();
        publisher_telling(&status_svc, &names.status(), move || {
            count.fetch_add(1, Ordering::Relaxed);
        })
        .map_err(|e| e.to_string())?
    };
    let status_ev = open_or_create_event(&node, &names.status()).map_err(|e| e.to_string())?;
    let status_not = notifier(&status_ev, &names.status()).map_err(|e| e.to_string())?;

    let (restore, saver) = crate::state::startup(&cfg.daemon, &names.prefix);
    let heartbeat = Arc::new(AtomicU64::new(0));
    let mut systemd = notify::Supervisor::from_env(heartbeat.clone());
    let (tx, rx): (Sender<RtEvent>, Receiver<RtEvent>) = bounded(EVENT_CAPACITY);
    let (status_tx, status_rx) = bounded::<Status>(STATUS_CAPACITY);
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let (hint_tx, hint_rx) = bounded::<Nanos>(4);
    let mut load = load_watch(&cfg);
    let unconnected = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
    let offset_degraded = Arc::new(AtomicU64::new(0));
    // each stream's samples read so far, which the real-time thread stores every wake-up
    let received = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
    let mut muted_log = iox_log::MutedLog::default();
    let setup = RtSetup {
        cfg: cfg.clone(),
        names: names.clone(),
        stop: stop.clone(),
        tx,
        status_tx,
        start_ns,
        heartbeat,
        restore,
        hints: hint_rx,
        unconnected: unconnected.clone(),
        offset_degraded: offset_degraded.clone(),
        received: received.clone(),
    };
    let rt = std::thread::Builder::new()
        .name(RT_THREAD_NAME.into())
        .spawn(move || rt_thread(setup, ready_tx))
        .map_err(|e| format!("cannot spawn the real-time thread: {e}"))?;
    let report = match ready_rx.recv() {
        Ok(Ok(r)) => r,
        Ok(Err(e)) => {
            let _ = rt.join();
            return Err(format!("real-time thread set-up failed: {e}"));
        }
        Err(_) => {
            let _ = rt.join();
            return Err("the real-time thread ended during set-up".into());
        }
    };
    for a in &report.applied {
        tracing::info!("real-time thread: {a}");
    }
    for r in &report.refused {
        tracing::warn!("{r}; starting anyway");
    }
    // this thread, and the state thread it starts, keep off the real-time core where
    // another is allowed (with the unit's CPUAffinity= naming an isolated core too,
    // they would otherwise share it with the real-time thread)
    if let Ok(core) = usize::try_from(cfg.daemon.core) {
        match vlsync_ipc::rt::avoid_core(core) {
            Ok(Some(cores)) => tracing::info!(
                "service threads on cores {cores:?}, off the real-time core {core}"
            ),
            Ok(None) => tracing::info!(
                "service threads share core {core} with the real-time thread (no other core allowed)"
            ),
            Err(e) => tracing::warn!("{e}; starting anyway"),
        }
    }
    // saved on a thread of its own: a stalled fsync must not stop the service
    // thread's status, watchdog pings and reaction to SIGTERM
    let mut saver = saver.map(crate::state::Saver::in_background);
    if report.buffer.1 < report.buffer.0 {
        tracing::warn!(
            "services.subscriber_buffer = {} exceeds what the existing signature services allow; using {} \
             (a process with a smaller services.subscriber_buffer created them: give the drivers \
             the daemon's --config, or start the daemon first)",
            report.buffer.0,
            report.buffer.1
        );
    }
    tracing::info!(
        "serving prefix `{}`: {}, {} -> {} (status on {} every {} s)",
        names.prefix,
        names.signature(Stream::Cam),
        names.signature(Stream::Lidar),
        names.offset(),
        names.status(),
        cfg.daemon.status_period_s
    );
    systemd.ready(&format!(
        "serving prefix {}, waiting for data",
        names.prefix
    ));

    // a status that cannot be published (no loan, a failed send) is said: at
    // once, then at most once a minute with the count, and at stop
    let status_failures = std::cell::Cell::new((0u64, 0u64, i64::MIN));
    let publish_status = |st: &Status| {
        let sent = match status_pub.loan_uninit() {
            Ok(s) => s.write_payload(*st).send().map_err(|e| format!("{e:?}")),
            Err(e) => Err(format!("{e:?}")),
        };
        match sent {
            Ok(_) => {
                let _ = status_not.notify();
            }
            Err(why) => {
                let (total, unsaid, said_at) = status_failures.get();
                let now = monotonic_ns();
                if said_at == i64::MIN || now.saturating_sub(said_at) >= 60_000_000_000 {
                    tracing::warn!(
                        "cannot publish the status on {}: {why} ({} failed so far)",
                        names.status(),
                        total + 1
                    );
                    status_failures.set((total + 1, 0, now));
                } else {
                    status_failures.set((total + 1, unsaid + 1, said_at));
                }
            }
        }
        tracing::debug!(
            "status: received {:?} lost {:?} overruns {} estimates {}",
            st.received,
            st.lost,
            st.budget_overruns,
            st.estimates_published
        );
    };
    // every status waiting: to systemd, the summary and the status service; how many
    let drain_statuses = |systemd: &mut notify::Supervisor, summary: &mut journal::Summary| {
        let mut n = 0;
        while let Ok(st) = status_rx.try_recv() {
            systemd.on_status(&st);
            summary.on_status(&st);
            publish_status(&st);
            n += 1;
        }
        n
    };
    let mut throttle = journal::Throttle::new(journal::THROTTLE_NS)
        .with_period(journal::SEARCH_MOVE_KEY, journal::SEARCH_MOVE_THROTTLE_NS);
    // a stream whose driver stops for good (hung) is said after SILENT_STREAM_NS
    let mut silent = journal::SilentStreams::new(journal::SILENT_STREAM_NS, monotonic_ns());
    // the service thread's own failures, said through the throttle
    let (offset_name, status_name) = (names.offset(), names.status());
    let tell_failures = |throttle: &mut journal::Throttle,
                         told: &mut ([u64; 2], u64, u64),
                         systemd: &mut notify::Supervisor,
                         now: Nanos| {
        tell_unconnected(&unconnected, &mut told.0, &names, throttle, now);
        tell_clients(
            &offset_degraded,
            &mut told.1,
            journal::OFFSET_CLIENTS_KEY,
            &offset_name,
            ("estimates", "at every send and every 0.1 s"),
            throttle,
            now,
        );
        tell_clients(
            &status_degraded,
            &mut told.2,
            journal::STATUS_CLIENTS_KEY,
            &status_name,
            ("statuses", "at every status sent"),
            throttle,
            now,
        );
        if let Some(line) = systemd.failure_line(throttle, now) {
            tracing::warn!("{line}");
        }
    };
    // the counts of those failures already taken: unconnected publishers per stream,
    // offset clients, status clients
    let mut told = ([0u64; 2], 0u64, 0u64);
    let mut summary =
        journal::Summary::new((cfg.daemon.summary_period_s * 1e9) as Nanos, monotonic_ns());
    // The service thread polls its channels and never blocks on them: a receiver
    // blocked in `recv`/`Select` registers with the channel's waker, and every
    // `try_send` of the real-time thread would then take the waker's mutex (no
    // priority inheritance) and make a futex wake-up call. Polled, a send is a
    // lock-free slot write and nothing more (`service_wait`).
    let mut busy = false;
    // the "at stop" summary was written, with the real-time thread's last stretch
    let mut summary_at_stop = false;
    // when the service thread first saw the stop, and whether the real-time thread
    // failed to end within `RT_STOP_WAIT` of it
    let mut stop_seen: Option<std::time::Instant> = None;
    let mut rt_stuck = false;
    loop {
        // statuses before each event: a flood of events cannot hold one back
        let mut got = 0usize;
        let mut disconnected = false;
        while got < EVENTS_PER_POLL {
            got += drain_statuses(&mut systemd, &mut summary);
            match rx.try_recv() {
                Ok(RtEvent::Estimate(e)) => {
                    systemd.on_estimate(&e);
                    summary.on_estimate(&e);
                    if let Some(sv) = saver.as_mut() {
                        sv.offer(&e);
                    }
                }
                Ok(ev) => {
                    match &ev {
                        RtEvent::OffsetStep(_) => summary.on_offset_step(),
                        RtEvent::SearchMoved(_) => summary.on_search_move(),
                        RtEvent::Simulated { stream, on } => {
                            summary.on_simulated(stream_index(*stream), *on)
                        }
                        // the real-time thread's stretch ended: the period's summary,
                        // then its latency line (`log_event`), over the same stretch.
                        // The status it handed over just before may have come after
                        // this poll's drain: read it first, so the summary counts the
                        // samples up to the stretch's end
                        RtEvent::Latency(_) => {
                            got += drain_statuses(&mut systemd, &mut summary);
                            tracing::info!("{}", summary.close(monotonic_ns()))
                        }
                        // the real-time thread stopped: the stretch since the last
                        // summary, then its latency line, after its final status
                        RtEvent::LastLatency(_) => {
                            got += drain_statuses(&mut systemd, &mut summary);
                            tracing::info!("at stop, {}", summary.close(monotonic_ns()));
                            summary_at_stop = true;
                        }
                        _ => {}
                    }
                    log_event(
                        &ev,
                        &mut throttle,
                        monotonic_ns(),
                        cfg.daemon.latency_budget_us,
                    )
                }
                Err(crossbeam::channel::TryRecvError::Empty) => break,
                Err(crossbeam::channel::TryRecvError::Disconnected) => {
                    disconnected = true;
                    break;
                }
            }
            got += 1;
        }
        if disconnected {
            break;
        }
        if let Some(wait) = service_wait(busy, got) {
            std::thread::sleep(wait);
        }
        busy = got > 0;
        let mono = monotonic_ns();
        tell_failures(&mut throttle, &mut told, &mut systemd, mono);
        if let Some(line) = muted_log.take(mono) {
            tracing::warn!("{line}");
        }
        tell_silent_streams(
            &mut silent,
            [0, 1].map(|si| received[si].load(Ordering::Relaxed)),
            &mut throttle,
            mono,
            start_ns,
        );
        throttle.due(mono, report_suppressed);
        if let Some(line) = summary.due(mono) {
            tracing::info!("{line}");
        }
        if let Some((w, next)) = load.as_mut() {
            let t = monotonic_ns();
            if t >= *next {
                *next = t + LOAD_PERIOD_NS;
                match loadwatch::read_pressure(&cfg.daemon.load_hint_source) {
                    Ok(total) => {
                        if let Some(h) = w.observe(t, total) {
                            if let Some(n) = throttle.admit(journal::LOAD_STEP_KEY, 1, t) {
                                tracing::info!(
                                    "CPU pressure {:.0} % -> {:.0} % ({:.1} s ago): load step{}",
                                    h.before * 100.0,
                                    h.after * 100.0,
                                    (t - h.at_ns) as f64 * 1e-9,
                                    events::more(n)
                                );
                            }
                            if hint_tx.try_send(h.at_ns).is_err() {
                                if let Some(n) = throttle.admit(journal::HINT_DROPPED_KEY, 1, t) {
                                    tracing::warn!(
                                        "load hint dropped: the real-time thread lags{}",
                                        events::more(n)
                                    );
                                }
                            }
                        }
                    }
                    Err(e) => {
                        tracing::warn!("{e}; load hints off from now on");
                        load = None;
                    }
                }
            }
        }
        let now = std::time::Instant::now();
        systemd.tick(now);
        if let Some(sv) = saver.as_mut() {
            sv.tick(now);
        }
        if termination_requested() {
            stop.store(true, Ordering::Relaxed);
        }
        if stop.load(Ordering::Relaxed) {
            systemd.stopping();
            // a real-time thread wedged in a call (what the watchdog is for) never
            // closes its channel: the stop goes on without it after a bounded wait,
            // so the last estimate is still saved and the exit says why
            let since = *stop_seen.get_or_insert(now);
            if now.saturating_duration_since(since) > RT_STOP_WAIT {
                rt_stuck = true;
                break;
            }
        }
    }
    systemd.stopping();
    // the real-time thread's last status, handed over before its event channel closed
    while let Ok(st) = status_rx.try_recv() {
        publish_status(&st);
        summary.on_status(&st);
    }
    // the stretch since the last summary line (up to a summary period: its counts
    // would otherwise never reach the journal), when the real-time thread's last
    // stretch did not bring it (it ended without one: a panic)
    if !summary_at_stop {
        tracing::info!("at stop, {}", summary.close(monotonic_ns()));
    }
    // a real-time thread that panicked must not look like a clean stop: its exit code
    // says the failure (`systemctl status`, `NRestarts`; the unit restarts any exit)
    let rt_end = if rt_stuck {
        // not joined (it would never return): the process's exit ends it; its
        // iceoryx2 resources are cleaned at the next start, as a crash's are
        drop(rt);
        Err(format!(
            "the real-time thread did not end within {RT_STOP_WAIT:?} of the stop request (stuck in a call); stopping without it"
        ))
    } else {
        rt_outcome(rt.join())
    };
    // the failures counted since the last poll, every warning still held back (the
    // channel was drained: the loop ends on disconnect) and iceoryx2's held messages
    tell_failures(&mut throttle, &mut told, &mut systemd, monotonic_ns());
    throttle.due(Nanos::MAX, report_suppressed);
    if let Some(line) = muted_log.take(Nanos::MAX) {
        tracing::warn!("{line}");
    }
    if let (total, unsaid @ 1.., _) = status_failures.get() {
        tracing::warn!(
            "{unsaid} more status(es) could not be published on {} ({total} in all)",
            names.status()
        );
    }
    if let Some(sv) = saver.as_mut() {
        if sv.finish(crate::state::FINAL_SAVE_WAIT) {
            tracing::info!("last good estimate saved to {}", sv.path().display());
        }
    }
    // everything the real-time thread sent before it ended has been drained above
    if let Err(e) = &rt_end {
        tracing::error!("{e}; stopping with an error");
    } else {
        tracing::info!("stopped");
    }
    rt_end
}

/// How the real-time thread ended: `Err` naming its panic, or why it gave up (the
/// daemon then exits non-zero, so systemd restarts it).
fn rt_outcome(joined: std::thread::Result<Result<(), String>>) -> Result<(), String> {
    joined.map_err(|p| {
        format!(
            "the real-time thread panicked: {}",
            panic_message(p.as_ref())
        )
    })?
}

#[cfg(test)]
mod tests {
    use super::rt::{first_published, snapshot, SeqGap, SeqTable, MAX_COUNTED_GAP};
    use super::*;
    use vlsync_common::wire::STATE_NONE;
    use vlsync_common::RejectReason;

    #[test]
    fn a_rust_log_that_does_not_parse_is_said() {
        assert_eq!(log_filter(None).1, None);
        let has = |f: &tracing_subscriber::EnvFilter, parts: &[&str]| {
            let text = f.to_string();
            let mut got: Vec<&str> = text.split(',').collect();
            got.sort_unstable();
            let mut want = parts.to_vec();
            want.sort_unstable();
            assert_eq!(got, want, "{text}");
        };
        let (f, bad) = log_filter(Some("vlsyncd=debug"));
        has(&f, &["vlsyncd=debug", "iceoryx2=trace"]);
        assert_eq!(bad, None);
        // iceoryx2's messages as the user filters them, when RUST_LOG names them
        let (f, _) = log_filter(Some("info,iceoryx2=off"));
        has(&f, &["info", "iceoryx2=off"]);
        let (f, bad) = log_filter(Some("vlsync=loud"));
        has(&f, &["info", "iceoryx2=trace"]);
        let bad = bad.expect("said");
        assert!(
            bad.starts_with("RUST_LOG `vlsync=loud` is no log filter (")
                && bad.ends_with("): logging at info"),
            "{bad}"
        );
    }

    #[test]
    fn the_command_lines_fifo_priority_overrides_the_configurations() {
        let dir = std::env::temp_dir().join(format!("vlsyncd-fifo-arg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("rt.toml");
        std::fs::write(&file, "[daemon]\nfifo_priority = 80\n").unwrap();
        let args = |config: Option<&std::path::Path>, fifo: Option<i64>| RunArgs {
            config: config.map(|p| p.to_path_buf()),
            prefix: None,
            fifo_priority: fifo,
        };
        let prio = |a: &RunArgs| load_config(a).unwrap().daemon.fifo_priority;
        assert_eq!(prio(&args(None, None)), 0, "the shipped default");
        assert_eq!(prio(&args(Some(&file), None)), 80);
        assert_eq!(prio(&args(Some(&file), Some(0))), 0);
        assert_eq!(prio(&args(None, Some(50))), 50);
        // out of range (clap refuses it first): the configuration's error, naming the flag
        let e = load_config(&args(None, Some(100))).unwrap_err();
        assert!(
            e.contains("--fifo-priority") && e.contains("fifo_priority"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A distinct publisher id for the sequence tables' tests (ids come from real
    /// publishers), on a service of its own per `tag`.
    pub(super) fn pid(tag: &str, n: u8) -> UniquePublisherId {
        let names =
            ServiceNames::new(&format!("vlsync-test/rt-{tag}-{}-{n}", std::process::id())).unwrap();
        let node = create_node("gap-test", false).unwrap();
        let f = open_or_create_pubsub::<SignatureSample>(
            &node,
            &names.signature(Stream::Cam),
            Qos::signature(4),
        )
        .unwrap();
        let p = vlsync_ipc::publisher(&f, "x").unwrap();
        p.id()
    }

    /// The service thread polls fast while events come and for one poll after, at
    /// once after a poll that met its cap, else as seldom as the real-time thread
    /// wakes when idle.
    #[test]
    fn the_service_poll_is_short_only_while_events_come() {
        assert_eq!(service_wait(false, 1), Some(SERVICE_POLL_BUSY));
        assert_eq!(service_wait(true, 0), Some(SERVICE_POLL_BUSY));
        assert_eq!(service_wait(false, 0), Some(SERVICE_POLL_IDLE));
        // a poll that met its cap left a backlog: the next one comes at once
        assert_eq!(service_wait(false, EVENTS_PER_POLL), None);
        assert_eq!(service_wait(true, EVENTS_PER_POLL + 3), None);
        assert!(SERVICE_POLL_BUSY < SERVICE_POLL_IDLE);
        assert_eq!(SERVICE_POLL_IDLE, WAKE_PERIOD);
    }

    #[test]
    fn a_panicking_thread_is_an_error_with_its_message() {
        let h = std::thread::spawn(|| -> Result<(), String> { panic!("boom {}", 7) });
        assert_eq!(
            rt_outcome(h.join()),
            Err("the real-time thread panicked: boom 7".to_string())
        );
        assert_eq!(rt_outcome(std::thread::spawn(|| Ok(())).join()), Ok(()));
        // a thread that gave up is an error too
        let h = std::thread::spawn(|| Err("gave up".to_string()));
        assert_eq!(rt_outcome(h.join()), Err("gave up".to_string()));
        let h = std::thread::spawn(|| -> () { panic!("plain") });
        let e = h.join().unwrap_err();
        assert_eq!(panic_message(e.as_ref()), "plain");
        let h = std::thread::spawn(|| -> () { std::panic::panic_any(3u8) });
        assert_eq!(
            panic_message(h.join().unwrap_err().as_ref()),
            "unknown cause"
        );
    }

    #[test]
    fn the_held_samples_go_in_the_order_they_were_published() {
        let at = |publish_ns| Some((SignatureSample::new(0, 0.0, 0, publish_ns), pid("gap", 1)));
        assert_eq!(first_published(&[None, None]), None);
        assert_eq!(first_published(&[at(9), None]), Some(0));
        assert_eq!(first_published(&[None, at(9)]), Some(1));
        assert_eq!(first_published(&[at(9), at(5)]), Some(1));
        assert_eq!(first_published(&[at(5), at(9)]), Some(0));
        // a tie: the camera's first; hostile times only reorder, never drop
        assert_eq!(first_published(&[at(5), at(5)]), Some(0));
        assert_eq!(first_published(&[at(i64::MAX), at(i64::MIN)]), Some(1));
    }

    /// Under systemd every log line starts with its level's priority, so journald
    /// stores warnings as warnings (`journalctl -p warning`).
    #[test]
    fn journal_lines_carry_their_priority() {
        let buf = Arc::new(std::sync::Mutex::new(Vec::<u8>::new()));
        let sink = buf.clone();
        let sub = tracing_subscriber::fmt()
            .with_writer(move || Sink(sink.clone()))
            .with_ansi(false)
            .with_max_level(tracing::Level::DEBUG)
            .event_format(JournalFormat(
                tracing_subscriber::fmt::format()
                    .without_time()
                    .with_ansi(false),
            ))
            .finish();
        tracing::subscriber::with_default(sub, || {
            tracing::error!("e");
            tracing::warn!("w");
            tracing::info!("i");
            tracing::debug!("d");
        });
        let text = String::from_utf8(buf.lock().unwrap().clone()).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4, "{text}");
        for (line, (prefix, msg)) in
            lines
                .iter()
                .zip([("<3>", "e"), ("<4>", "w"), ("<6>", "i"), ("<7>", "d")])
        {
            assert!(line.starts_with(prefix) && line.ends_with(msg), "{line}");
        }
    }

    /// A log writer into memory (the live tests' daemons log through it too).
    pub(super) struct Sink(pub(super) Arc<std::sync::Mutex<Vec<u8>>>);
    impl std::io::Write for Sink {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn sequence_gaps_are_counted_per_publisher() {
        let (a, b, c) = (pid("gap", 1), pid("gap", 2), pid("gap", 3));
        let mut slots = SeqTable::default();
        let lost = |slots: &mut SeqTable, p, seq, first| match slots.gap(p, seq, first) {
            SeqGap::Lost(n) => n,
            SeqGap::None => 0,
            SeqGap::Joined(n) => panic!("joined at {n}"),
        };
        assert_eq!(lost(&mut slots, a, 0, true), 0);
        assert_eq!(lost(&mut slots, a, 1, false), 0);
        assert_eq!(lost(&mut slots, a, 5, false), 3);
        // a second publisher does not disturb the first one's count
        assert_eq!(lost(&mut slots, b, 0, true), 0);
        assert_eq!(lost(&mut slots, a, 6, false), 0);
        // restart of a: sequence back to 0 with FLAG_FIRST is not a gap
        assert_eq!(lost(&mut slots, a, 0, true), 0);
        assert_eq!(lost(&mut slots, a, 2, false), 1);
        // a duplicate/backwards sequence is not counted as lost
        assert_eq!(lost(&mut slots, a, 1, false), 0);
        // a hostile jump to the end of the range and back: no count near u64::MAX
        // (which the next gap would overflow)
        assert_eq!(lost(&mut slots, a, u64::MAX, false), 0);
        assert_eq!(lost(&mut slots, a, 0, false), 0);
        assert_eq!(lost(&mut slots, a, 5, false), 4);
        assert_eq!(
            lost(&mut slots, a, 6 + MAX_COUNTED_GAP, false),
            MAX_COUNTED_GAP
        );
        // a publisher first read at 944 (a --fast burst, or a daemon that started
        // under a running driver): said, not counted; a number beyond any buffer is a
        // corrupt counter, and a first sample at 0 without the flag hid nothing
        assert_eq!(slots.gap(c, 944, false), SeqGap::Joined(944));
        assert_eq!(slots.gap(c, 945, false), SeqGap::None);
        let d = pid("gap", 4);
        assert_eq!(slots.gap(d, 0, false), SeqGap::None);
        let e = pid("gap", 5);
        let mut fresh = SeqTable::default();
        assert_eq!(fresh.gap(e, MAX_COUNTED_GAP + 1, false), SeqGap::None);
    }

    /// A driver that restarts is a new publisher each time: every one is judged from
    /// its first sample, the fifth and later too (the dead ones' slots are the least
    /// recently read, and go first).
    #[test]
    fn every_new_publisher_is_judged_after_any_number_of_restarts() {
        let mut slots = SeqTable::default();
        for n in 0..7u8 {
            let p = pid("gap", 10 + n);
            // a driver that was already running when it was first read (its earlier
            // samples dropped from a full buffer, or published before the daemon
            // listened): said, whichever restart it is
            assert_eq!(
                slots.gap(p, 100, false),
                SeqGap::Joined(100),
                "publisher {n}"
            );
            assert_eq!(slots.gap(p, 101, false), SeqGap::None);
            assert_eq!(slots.gap(p, 104, false), SeqGap::Lost(2), "publisher {n}");
        }
    }

    /// Two live publishers on one stream beside three stale ones keep their slots:
    /// the stale ones, read least recently, make room, and no gap goes uncounted
    /// (eviction by the lowest sequence number made the two evict each other, here
    /// on every sample).
    #[test]
    fn two_live_publishers_keep_their_slots_beside_stale_ones() {
        let mut slots = SeqTable::default();
        // three dead publishers, far along in their numbering
        for n in 0..3u8 {
            let stale = pid("gap", 20 + n);
            assert_eq!(slots.gap(stale, 0, true), SeqGap::None);
            assert_eq!(slots.gap(stale, 50_000, false), SeqGap::Lost(49_999));
        }
        let (a, b) = (pid("gap", 30), pid("gap", 31));
        assert_eq!(slots.gap(a, 0, true), SeqGap::None);
        assert_eq!(slots.gap(b, 0, true), SeqGap::None);
        let mut lost = 0;
        for k in 1..=40u64 {
            // each skips one number every fifth sample
            let seq = k + k / 5;
            for p in [a, b] {
                match slots.gap(p, seq, false) {
                    SeqGap::Lost(n) => lost += n,
                    SeqGap::None => {}
                    SeqGap::Joined(n) => panic!("rejoined at {n}: its slot was taken"),
                }
            }
        }
        assert_eq!(lost, 2 * 8);
    }

    #[test]
    fn second_lock_on_a_prefix_fails_with_a_clear_message() {
        let prefix = format!("vlsync-test/lock-{}", std::process::id());
        let l = single_instance_lock(&prefix).unwrap();
        let e = single_instance_lock(&prefix).unwrap_err();
        assert!(e.contains("another vlsyncd") && e.contains(&prefix), "{e}");
        assert!(e.contains(&std::process::id().to_string()), "{e}");
        drop(l);
        // a clean release leaves no file behind
        assert!(!lock_path(&prefix).exists());
        let l = single_instance_lock(&prefix).unwrap();
        // a stale file (a killed daemon's) is taken over
        drop(l);
        std::fs::write(lock_path(&prefix), "999999\n").unwrap();
        let l = single_instance_lock(&prefix).unwrap();
        assert_eq!(
            std::fs::read_to_string(lock_path(&prefix)).unwrap().trim(),
            std::process::id().to_string()
        );
        drop(l);
        assert_eq!(lock_path("a/b"), PathBuf::from("/tmp/vlsync/a%b.lock"));
    }

    #[test]
    fn status_snapshot_carries_percentiles() {
        let mut c = RtCounters::new();
        for v in [1000u64, 2000, 3000] {
            c.processing.record(v);
            c.end_to_end.record(v * 10);
        }
        c.events_dropped = 2;
        let st = snapshot(&mut c, true, 100, 1100);
        assert_eq!(st.uptime_ns, 1000);
        assert_eq!(st.processing_ns[2], 3000);
        assert_eq!(st.latency_count, 3);
        assert_eq!(st.events_dropped, 2);
        assert_eq!(st.degraded, 1);
        assert_eq!(st.state, STATE_NONE);
        st.validate().unwrap();
        assert_eq!(RejectReason::ALL.len() + 1, REJECT_NAMES.len());
    }
}
