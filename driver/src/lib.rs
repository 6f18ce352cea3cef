//! Driver side of vlsync: a [`Source`] of signature samples, paced in real
//! time (or as fast as possible) and published on `<prefix>/<stream>/signature`.
//!
//! Sources replay a signature CSV ([`VecSource::from_csv`]), run the live
//! signature simulator ([`VecSource::from_sim`]), or run raw frames and scans
//! through the front-ends ([`raw`]: frame directories, MCAP recordings, V4L2,
//! serial LD06/RPLIDAR, scan CSVs, the rendering simulator). The
//! `vlsync-cam` and `vlsync-lidar` binaries live in this package ([`cli`]).
//!
//! # Pacing and restarts
//!
//! Sample `k` is published at `start + (t_k - anchor) / speed` on
//! `CLOCK_MONOTONIC`. For the simulator and rendered runs `anchor` is a time both
//! drivers of a pair agree on (the earlier of the two streams' first stamps,
//! computed identically by both), so two drivers given the same `--start-at` mono
//! time publish a consistent pair. A recording (`--csv`, `--mcap`, `--frames`,
//! `--scans`) anchors on its own first sample: a pair from one recording whose
//! streams start at different stamps publishes that difference apart (the daemon
//! estimates from stamps; the skew only delays one stream's samples). A driver
//! restarted with the same `--start-at` skips the samples whose time has passed,
//! also those that fell due while its source caught up (a recording decoded frame
//! by frame), so it resumes where the run is now instead of replaying history in
//! a burst.
//! Sequence numbers restart at 0 with `FLAG_FIRST`; the daemon does not count
//! that as lost samples. Publishing never blocks on the daemon: a driver keeps
//! going while the daemon restarts.
#![forbid(unsafe_code)]

pub mod cli;
pub mod raw;
pub mod watchdog;

use std::fmt;
use std::path::Path;
use std::time::Duration;
use vlsync_common::{Nanos, Sample, Stream};
use vlsync_ipc::{monotonic_ns, IpcError, SignaturePublisher};

/// A failure of a source (the file and line, the device, ...).
#[derive(Debug, Clone, PartialEq)]
pub struct SourceError(pub String);

impl fmt::Display for SourceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SourceError {}

/// What a source has next ([`Source::next_event`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Next {
    /// A sample.
    Sample(Sample),
    /// No sample yet after about [`IDLE_EVERY`] of work or waiting (frames or scans
    /// that gave none, a silent sensor): the caller does its periodic work (a
    /// progress line, a stop check) and asks again.
    Idle,
    /// The end of the source, or a stop request it saw.
    End,
}

/// [`Source::next_sample`] of a source that overrides [`Source::next_event`]: its
/// events until a sample or the end, the idle ones passed over.
pub fn sample_of_events(
    mut next_event: impl FnMut() -> Result<Next, SourceError>,
) -> Result<Option<Sample>, SourceError> {
    loop {
        match next_event()? {
            Next::Sample(s) => return Ok(Some(s)),
            Next::End => return Ok(None),
            Next::Idle => {}
        }
    }
}

/// How long a source that overrides [`Source::next_event`] works toward a sample
/// before it returns [`Next::Idle`]. Checked between frames or reads, so a single
/// wait that blocks longer (a camera's wait for a frame, up to its stall time)
/// delays it.
pub const IDLE_EVERY: Duration = Duration::from_secs(1);

/// A stream of signature samples on one sensor clock.
pub trait Source {
    /// The next sample, `Ok(None)` at the end. May block (a live sensor).
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError>;
    /// The next sample, or [`Next::Idle`] when the source has worked or waited
    /// about [`IDLE_EVERY`] without one ([`run`] uses it, so that a driver whose
    /// sensor gives no sample for hours still reports and sees a stop). The default
    /// calls [`Source::next_sample`] and is never idle; the front-end sources
    /// override it, and a source that wraps another should forward it.
    fn next_event(&mut self) -> Result<Next, SourceError> {
        Ok(match self.next_sample()? {
            Some(s) => Next::Sample(s),
            None => Next::End,
        })
    }
    /// A short description for logs.
    fn describe(&self) -> String;
    /// What the source dropped or counted, reported once at exit (front-end
    /// sources: low-texture frames, passes with too few rays, ...).
    fn report(&self) -> Option<String> {
        None
    }
    /// The truth of the sample [`Source::next_sample`] returned last, when the
    /// source knows it (the rendering simulator does; a real sensor does not).
    fn truth(&self) -> Option<SampleTruth> {
        None
    }
}

/// What a simulating source knows about one sample beyond its stamp.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SampleTruth {
    /// True time of the physical event the sample describes (the midpoint of
    /// the two true instants it spans), ns, on the run's time base:
    /// `CLOCK_MONOTONIC` with `--stamp mono|software`, the simulator's own
    /// true time with `--stamp sensor`. `stamp - event` is the stamping error.
    pub event_ns: Nanos,
    /// Camera, software stamping: how late the later frame reached the
    /// front-end after its exposure ended (scheduling, stalls, rendering), ns.
    pub late_ns: Nanos,
    /// Camera, software stamping: front-end processing time of the later frame, ns.
    pub process_ns: Nanos,
    /// Camera, software stamping: how late the renderer finished the later frame
    /// after its exposure ended (0 when it was ready in time), ns.
    pub render_late_ns: Nanos,
}

/// Header of a truth file.
pub const TRUTH_HEADER: &str = "seq,publish_ns,event_ns,stamp_ns,late_ns,process_ns,render_late_ns";

/// Writes one truth row per published sample (`--truth-out`): the sequence
/// number, when it was published, the true event time, the stamp published and
/// the camera's delay diagnostics (see [`SampleTruth`]); `CLOCK_MONOTONIC` ns.
pub struct TruthLog {
    out: std::io::BufWriter<std::fs::File>,
    path: std::path::PathBuf,
    rows: u64,
    last_flush: std::time::Instant,
}

impl TruthLog {
    /// Creates (truncates) `path` and writes the header.
    pub fn create(path: &Path) -> Result<Self, DriverError> {
        use std::io::Write;
        // a FIFO (or a device) would block the open until a reader came, past any
        // SIGTERM (the handler restarts the call): the truth is a file
        if let Ok(m) = std::fs::metadata(path) {
            if !m.is_file() {
                return Err(DriverError::Options(format!(
                    "--truth-out {}: not a regular file (a FIFO, a device or a directory); give a file path",
                    path.display()
                )));
            }
        }
        let f = std::fs::File::create(path)
            .map_err(|e| DriverError::Options(format!("--truth-out {}: {e}", path.display())))?;
        let mut out = std::io::BufWriter::new(f);
        writeln!(out, "{TRUTH_HEADER}")
            .map_err(|e| DriverError::Options(format!("--truth-out {}: {e}", path.display())))?;
        Ok(Self {
            out,
            path: path.to_path_buf(),
            rows: 0,
            last_flush: std::time::Instant::now(),
        })
    }

    /// Appends one row; flushed about once a second (and on [`TruthLog::finish`]).
    pub fn record(
        &mut self,
        seq: u64,
        publish_ns: Nanos,
        stamp_ns: Nanos,
        t: &SampleTruth,
    ) -> Result<(), SourceError> {
        use std::io::Write;
        writeln!(
            self.out,
            "{seq},{publish_ns},{},{stamp_ns},{},{},{}",
            t.event_ns, t.late_ns, t.process_ns, t.render_late_ns
        )
        .map_err(|e| SourceError(format!("--truth-out {}: {e}", self.path.display())))?;
        self.rows += 1;
        if self.last_flush.elapsed() >= Duration::from_secs(1) {
            self.last_flush = std::time::Instant::now();
            self.out
                .flush()
                .map_err(|e| SourceError(format!("--truth-out {}: {e}", self.path.display())))?;
        }
        Ok(())
    }

    /// Rows written.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Flushes everything written.
    pub fn finish(&mut self) -> Result<(), SourceError> {
        use std::io::Write;
        self.out
            .flush()
            .map_err(|e| SourceError(format!("--truth-out {}: {e}", self.path.display())))
    }
}

/// A source over samples already in memory (CSV replay, simulator).
#[derive(Debug, Clone)]
pub struct VecSource {
    samples: Vec<Sample>,
    next: usize,
    what: String,
}

impl VecSource {
    /// Wraps samples.
    pub fn new(samples: Vec<Sample>, what: impl Into<String>) -> Self {
        Self {
            samples,
            next: 0,
            what: what.into(),
        }
    }

    /// Reads a signature CSV (header, then `t,value` rows, t in seconds).
    /// Errors name the file and line.
    pub fn from_csv(path: &Path) -> Result<Self, SourceError> {
        let (samples, _) = vlsync_sim::io::read_signature_csv(path)
            .map_err(|e| SourceError(format!("signature CSV: {e}")))?;
        Ok(Self::new(samples, format!("csv {}", path.display())))
    }

    /// The `stream` half of the simulated run `family`/`seed`/`duration_s`.
    pub fn from_sim(run: &vlsync_sim::SimRun, stream: Stream) -> Self {
        let samples = match stream {
            Stream::Cam => run.cam.clone(),
            Stream::Lidar => run.lidar.clone(),
        };
        Self::new(
            samples,
            format!("sim {} seed {} ({stream})", run.family, run.seed),
        )
    }

    /// First timestamp, if any.
    pub fn first_t_ns(&self) -> Option<Nanos> {
        self.samples.first().map(|s| s.t_ns)
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }
}

impl Source for VecSource {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        let s = self.samples.get(self.next).copied();
        if s.is_some() {
            self.next += 1;
        }
        Ok(s)
    }

    fn describe(&self) -> String {
        format!("{} ({} samples)", self.what, self.samples.len())
    }
}

/// The pacing anchor of a simulated pair: the earlier first stamp of the two streams.
pub fn sim_anchor_ns(run: &vlsync_sim::SimRun) -> Nanos {
    let c = run.cam.first().map_or(0, |s| s.t_ns);
    let l = run.lidar.first().map_or(0, |s| s.t_ns);
    c.min(l)
}

/// How fast to publish.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pacing {
    /// Real time scaled by `speed` (1.0 = real time, 100.0 = 100x).
    Scaled {
        /// Speed factor (> 0).
        speed: f64,
        /// Sensor time that maps to the start instant, ns.
        anchor_ns: Nanos,
        /// Start instant on `CLOCK_MONOTONIC`, ns; `None`: when the run starts.
        start_mono_ns: Option<Nanos>,
    },
    /// As fast as possible.
    Fast,
}

/// What a run did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RunSummary {
    /// Samples published.
    pub published: u64,
    /// Samples skipped because their time had passed before the driver started.
    pub skipped: u64,
    /// Publish attempts that failed.
    pub failed: u64,
    /// True when stopped by a signal (or the stop callback) before the source ended.
    pub interrupted: bool,
    /// Published samples no subscriber was connected for (no daemon running): nobody
    /// received them.
    pub unreached: u64,
    /// Published samples whose wake-up of the daemon failed: it read them at its next
    /// periodic wake-up, up to 0.1 s late.
    pub unwoken: u64,
    /// Stamps that stepped back by more than [`STEP_BACK_NS`] (a restarted sensor,
    /// concatenated recordings): real-time pacing went on from the previous sample's
    /// instant instead of publishing everything up to the old stamps at once.
    pub steps_back: u64,
}

/// A progress report of a long run: once `every` has passed since the start or the
/// last report, [`run`] calls `report` with the totals so far, the time since that
/// previous report and the source's own counts ([`Source::report`]); a driver under
/// systemd runs for months, and its journal should say it is alive and how it fares.
/// The report is due by time, not by samples: it is checked before each sample,
/// while real-time pacing waits, and at each [`Next::Idle`] of the source, so a
/// sensor that gives no sample (a parked robot) still gets its lines, about
/// [`IDLE_EVERY`] late at most (more while a live camera's wait for a frame lasts,
/// up to its stall time).
pub struct Progress<'a> {
    /// The period.
    pub every: Duration,
    /// Called with the totals so far, the real time since the previous report (or
    /// the start) and the source's report.
    pub report: &'a mut dyn FnMut(&RunSummary, Duration, Option<String>),
    /// Called once for each sample real-time pacing waits longer than
    /// [`LONG_WAIT`] for after the previous one (the stamps jump ahead), with a
    /// line that says so: a driver that falls silent for days should say why.
    pub notice: &'a mut dyn FnMut(String),
}

/// A driver failure.
#[derive(Debug, Clone, PartialEq)]
pub enum DriverError {
    /// The source failed.
    Source(SourceError),
    /// iceoryx2 failed.
    Ipc(IpcError),
    /// Invalid options.
    Options(String),
}

impl fmt::Display for DriverError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DriverError::Source(e) => write!(f, "source: {e}"),
            DriverError::Ipc(e) => write!(f, "ipc: {e}"),
            DriverError::Options(e) => write!(f, "options: {e}"),
        }
    }
}

impl std::error::Error for DriverError {}

/// Longest single sleep, so a stop request is seen within this.
const MAX_SLEEP: Duration = Duration::from_millis(50);

/// A stamp this far before the previous one is a clock step back, not jitter:
/// real-time pacing restarts from the previous sample's instant.
pub const STEP_BACK_NS: Nanos = 1_000_000_000;

/// A wait this long between two samples under real-time pacing is noticed
/// ([`Progress::notice`]): the stamps jump ahead (a clock step, a file of two
/// recordings), or the sensor was silent that long.
pub const LONG_WAIT: Duration = Duration::from_secs(10);

/// When each sample of a real-time run is due on `CLOCK_MONOTONIC`: its stamp's
/// distance from an anchor, scaled by the speed, after the start instant. A stamp
/// that steps back by more than [`STEP_BACK_NS`] moves the anchor to itself at the
/// previous sample's instant, so pacing goes on in real time (a step ahead is
/// waited for: it may be a silence of the sensor, which the other stream's driver
/// does not share).
#[derive(Debug, Clone, Copy)]
struct Pacer {
    speed: f64,
    anchor_ns: Nanos,
    start_ns: Nanos,
    prev: Option<(Nanos, Nanos)>,
}

impl Pacer {
    /// The instant sample `t_ns` is due, and whether its stamp stepped back.
    fn due(&mut self, t_ns: Nanos) -> (Nanos, bool) {
        let mut stepped = false;
        if let Some((t, due)) = self.prev {
            if t.saturating_sub(t_ns) > STEP_BACK_NS {
                (self.anchor_ns, self.start_ns) = (t_ns, due);
                stepped = true;
            }
        }
        let due = self
            .start_ns
            .saturating_add((t_ns.saturating_sub(self.anchor_ns) as f64 / self.speed) as i64);
        self.prev = Some((t_ns, due));
        (due, stepped)
    }
}

/// A wait as a person reads it: seconds, minutes, hours or days.
fn wait_text(ns: Nanos) -> String {
    let s = vlsync_common::nanos_to_secs(ns);
    match s {
        s if s < 120.0 => format!("{s:.1} s"),
        s if s < 7200.0 => format!("{:.1} min", s / 60.0),
        s if s < 172_800.0 => format!("{:.1} h", s / 3600.0),
        s => format!("{:.1} days", s / 86_400.0),
    }
}

/// Where [`run`] publishes: the [`SignaturePublisher`] (a test's stand-in).
trait Sink {
    fn publish(&mut self, t_ns: Nanos, value: f64) -> Result<u64, IpcError>;
    fn unreached(&self) -> u64;
    fn unwoken(&self) -> u64;
}

impl Sink for SignaturePublisher {
    fn publish(&mut self, t_ns: Nanos, value: f64) -> Result<u64, IpcError> {
        SignaturePublisher::publish(self, t_ns, value)
    }
    fn unreached(&self) -> u64 {
        SignaturePublisher::unreached(self)
    }
    fn unwoken(&self) -> u64 {
        SignaturePublisher::unwoken(self)
    }
}

/// Publishes every sample of `source` with `pacing` until it ends or `stop()`
/// returns true. Publish failures are counted, not fatal (the daemon may be
/// restarting); more than `max_consecutive_failures` in a row is an error.
/// With `truth`, every published sample whose truth the source knows gets a row.
/// A source that ends while `stop()` is true (a live source returns its end when
/// asked to stop) makes an interrupted run, not a normal end.
pub fn run(
    source: &mut dyn Source,
    publisher: &mut SignaturePublisher,
    pacing: Pacing,
    stop: &dyn Fn() -> bool,
    truth: Option<&mut TruthLog>,
    progress: Option<Progress<'_>>,
) -> Result<RunSummary, DriverError> {
    run_into(source, publisher, pacing, stop, truth, progress)
}

/// [`Progress::report`] when one is due: `every` since `last`, the previous
/// report's instant (the start's at first), which it moves to now.
fn report_if_due(
    progress: Option<&mut Progress<'_>>,
    last: &mut Nanos,
    sum: &RunSummary,
    source: &dyn Source,
) {
    let Some(p) = progress else {
        return;
    };
    let now = monotonic_ns();
    let since = now.saturating_sub(*last).max(0);
    if since as u128 >= p.every.as_nanos() {
        *last = now;
        (p.report)(sum, Duration::from_nanos(since as u64), source.report());
    }
}

/// [`run`] into any [`Sink`].
fn run_into(
    source: &mut dyn Source,
    publisher: &mut dyn Sink,
    pacing: Pacing,
    stop: &dyn Fn() -> bool,
    mut truth: Option<&mut TruthLog>,
    mut progress: Option<Progress<'_>>,
) -> Result<RunSummary, DriverError> {
    const MAX_CONSECUTIVE_FAILURES: u64 = 1000;
    let started = monotonic_ns();
    let (mut pacer, start) = match pacing {
        Pacing::Scaled {
            speed,
            anchor_ns,
            start_mono_ns,
        } => {
            if !(speed.is_finite() && (cli::MIN_SPEED..=cli::MAX_SPEED).contains(&speed)) {
                return Err(DriverError::Options(format!(
                    "speed {} is out of range: allowed {} ..= {}",
                    vlsync_common::text::number(speed),
                    cli::MIN_SPEED,
                    cli::MAX_SPEED
                )));
            }
            let start_ns = start_mono_ns.unwrap_or(started);
            let pacer = Pacer {
                speed,
                anchor_ns,
                start_ns,
                prev: None,
            };
            (Some(pacer), start_ns)
        }
        Pacing::Fast => (None, started),
    };
    let mut sum = RunSummary::default();
    // a start before this process's: a restart into a run under way
    let mut catching_up = pacer.is_some() && start < started;
    let mut consecutive = 0u64;
    // the previous progress report's instant (the start's before the first)
    let mut last_report = started;
    loop {
        let s = match source.next_event().map_err(DriverError::Source)? {
            Next::Sample(s) => s,
            // no sample for a while (a parked robot's sensor): a report may be due
            Next::Idle => {
                report_if_due(progress.as_mut(), &mut last_report, &sum, source);
                if stop() {
                    sum.interrupted = true;
                    return Ok(sum);
                }
                continue;
            }
            Next::End => break,
        };
        report_if_due(progress.as_mut(), &mut last_report, &sum, source);
        if stop() {
            sum.interrupted = true;
            return Ok(sum);
        }
        if let Some(pacer) = pacer.as_mut() {
            let prev = pacer.prev;
            let (due, stepped) = pacer.due(s.t_ns);
            sum.steps_back += u64::from(stepped);
            if catching_up {
                // restarted mid-run: the samples due before now belong to the past,
                // those the source took its time to reach (a recording decoded frame
                // by frame) too; they would go out in one burst, minutes behind the
                // other stream. From the first sample on time, pacing as usual.
                if due < monotonic_ns() {
                    sum.skipped += 1;
                    continue;
                }
                catching_up = false;
            }
            if let (Some(p), Some((prev_t, prev_due))) = (progress.as_mut(), prev) {
                let wait = due.saturating_sub(prev_due.max(monotonic_ns()));
                if wait > LONG_WAIT.as_nanos() as Nanos {
                    (p.notice)(format!(
                        "the next sample (stamp {:.3} s, {:.3} s after the previous one's) is due in {}; pacing waits for it in real time (--fast publishes without pacing)",
                        vlsync_common::nanos_to_secs(s.t_ns),
                        vlsync_common::nanos_to_secs(s.t_ns.saturating_sub(prev_t)),
                        wait_text(wait),
                    ));
                }
            }
            loop {
                let now = monotonic_ns();
                if now >= due {
                    break;
                }
                if stop() {
                    sum.interrupted = true;
                    return Ok(sum);
                }
                // a wait of days for stamps far ahead still reports
                report_if_due(progress.as_mut(), &mut last_report, &sum, source);
                let wait = Duration::from_nanos((due - now) as u64).min(MAX_SLEEP);
                std::thread::sleep(wait);
            }
        }
        match publisher.publish(s.t_ns, s.value) {
            Ok(seq) => {
                sum.published += 1;
                // only a publish moves it: current at every return and progress report
                sum.unreached = publisher.unreached();
                sum.unwoken = publisher.unwoken();
                consecutive = 0;
                if let (Some(log), Some(t)) = (truth.as_deref_mut(), source.truth()) {
                    log.record(seq, monotonic_ns(), s.t_ns, &t)
                        .map_err(DriverError::Source)?;
                }
            }
            Err(e) => {
                sum.failed += 1;
                consecutive += 1;
                if consecutive > MAX_CONSECUTIVE_FAILURES {
                    return Err(DriverError::Ipc(e));
                }
            }
        }
    }
    // a live source (and, asked to stop, any front-end source) ends when stopped:
    // that is an interruption, not the end of its data
    sum.interrupted = stop();
    Ok(sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlsync_common::wire::SignatureSample;
    use vlsync_ipc::{create_node, open_or_create_pubsub, subscriber, Qos, ServiceNames};

    /// --truth-out refuses what is not a regular file: a FIFO's open would block
    /// until a reader came, deaf to SIGTERM.
    #[test]
    fn truth_out_must_be_a_regular_file() {
        let dir = std::env::temp_dir().join(format!("vlsync-truth-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("truth");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let e = match TruthLog::create(&fifo) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("a FIFO was opened as the truth file"),
        };
        assert!(
            e.contains("not a regular file") && e.contains(&fifo.display().to_string()),
            "{e}"
        );
        let e = TruthLog::create(&dir).err().unwrap().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        // a new file and an existing one are fine
        let file = dir.join("truth.csv");
        TruthLog::create(&file).unwrap();
        TruthLog::create(&file).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn vec_source_yields_in_order_then_ends() {
        let mut s = VecSource::new(vec![Sample::new(1, 1.0), Sample::new(2, 2.0)], "t");
        assert_eq!(s.next_sample().unwrap().unwrap().t_ns, 1);
        assert_eq!(s.next_sample().unwrap().unwrap().t_ns, 2);
        assert!(s.next_sample().unwrap().is_none());
    }

    #[test]
    fn csv_errors_name_file_and_line() {
        let dir = std::env::temp_dir().join(format!("vlsync-driver-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("bad.csv");
        std::fs::write(&p, "t,value\n0.0,1.0\n0.1,oops\n").unwrap();
        let e = VecSource::from_csv(&p).unwrap_err().to_string();
        assert!(e.contains("bad.csv") && e.contains(":3"), "{e}");
        std::fs::write(&p, "t,value\n0.0,1.0\n0.5,2.0\n").unwrap();
        let s = VecSource::from_csv(&p).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(s.first_t_ns(), Some(0));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn publish_run(
        pacing: Pacing,
        samples: Vec<Sample>,
        tag: &str,
    ) -> (RunSummary, Vec<SignatureSample>, Duration) {
        publish_run_reporting(pacing, samples, tag, None, &|| false)
    }

    /// [`publish_run`] with a progress report.
    fn publish_run_reporting(
        pacing: Pacing,
        samples: Vec<Sample>,
        tag: &str,
        progress: Option<Progress<'_>>,
        stop: &dyn Fn() -> bool,
    ) -> (RunSummary, Vec<SignatureSample>, Duration) {
        let names =
            ServiceNames::new(&format!("vlsync-test/driver-{tag}-{}", std::process::id())).unwrap();
        let node = create_node("driver-test", false).unwrap();
        let svc = open_or_create_pubsub::<SignatureSample>(
            &node,
            &names.signature(Stream::Cam),
            Qos::signature(256),
        )
        .unwrap();
        let (sub, _) = subscriber(&svc, 256, "cam").unwrap();
        let mut p = SignaturePublisher::open(&node, &names, Stream::Cam).unwrap();
        let mut src = VecSource::new(samples, "test");
        let t0 = std::time::Instant::now();
        let sum = run(&mut src, &mut p, pacing, stop, None, progress).unwrap();
        let el = t0.elapsed();
        let mut got = vec![];
        while let Some(s) = sub.receive().unwrap() {
            got.push(*s.payload());
        }
        (sum, got, el)
    }

    const S: Nanos = 1_000_000_000;

    #[test]
    fn pacing_goes_on_in_real_time_across_a_stamp_step_back() {
        let mut p = Pacer {
            speed: 2.0,
            anchor_ns: 1000 * S,
            start_ns: 5 * S,
            prev: None,
        };
        // 1000.0, 1000.2 s, then the sensor restarts at 16 s: due 5.0, 5.1, 5.1, 5.2 s
        let got: Vec<_> = [1000 * S, 1000 * S + S / 5, 16 * S, 16 * S + S / 5]
            .map(|t| p.due(t))
            .to_vec();
        let want = [
            (5 * S, false),
            (5 * S + S / 10, false),
            (5 * S + S / 10, true),
            (5 * S + S / 5, false),
        ];
        assert_eq!(got, want);
        // a step back within a second (jitter, a reordered sample) keeps the anchor:
        // it is due at once, and the pacing after it is as before
        assert_eq!(p.due(16 * S - S / 2), (4 * S + 85 * S / 100, false));
        assert_eq!(p.due(16 * S + S / 2), (5 * S + 35 * S / 100, false));
        // a step ahead is waited for
        assert_eq!(p.due(1016 * S + S / 2), (505 * S + 35 * S / 100, false));
    }

    proptest::proptest! {
        /// Whatever the stamps do, pacing never schedules a sample more than a step
        /// back's worth (1 s at this speed) before the previous one, re-anchors exactly
        /// on the steps back beyond it, and between steps keeps the stamps' spacing.
        #[test]
        fn pacing_keeps_the_stamps_spacing_and_never_goes_back_beyond_a_step(
            first in -1_000_000_000_000i64..1_000_000_000_000,
            deltas in proptest::collection::vec(-3_000_000_000i64..200_000_000, 1..200),
            speed in 0.5f64..50.0,
        ) {
            let mut p = Pacer { speed, anchor_ns: first, start_ns: 7 * S, prev: None };
            let (mut t, (mut due, _)) = (first, p.due(first));
            for d in deltas {
                let (next, stepped) = p.due(t + d);
                proptest::prop_assert_eq!(stepped, -d > STEP_BACK_NS);
                if stepped {
                    proptest::prop_assert_eq!(next, due);
                } else {
                    let want = due as f64 + d as f64 / speed;
                    proptest::prop_assert!((next as f64 - want).abs() <= 2.0, "{next} vs {want}");
                }
                proptest::prop_assert!(next as f64 >= due as f64 - STEP_BACK_NS as f64 / speed - 2.0);
                (t, due) = (t + d, next);
            }
        }
    }

    #[test]
    fn a_long_wait_for_a_stamp_far_ahead_is_noticed() {
        // two samples, then one stamped 11.6 days later: the driver says why it is silent
        use std::cell::RefCell;
        let samples = vec![
            Sample::new(0, 0.0),
            Sample::new(S / 10, 1.0),
            Sample::new(1_000_000 * S, 2.0),
        ];
        let lines = RefCell::new(vec![]);
        let mut report = |_: &RunSummary, _: Duration, _: Option<String>| {};
        let mut notice = |l: String| lines.borrow_mut().push(l);
        let progress = Progress {
            every: Duration::from_secs(3600),
            report: &mut report,
            notice: &mut notice,
        };
        let pacing = Pacing::Scaled {
            speed: 1.0,
            anchor_ns: 0,
            start_mono_ns: None,
        };
        // (and after 5 s, so that a missing notice fails the test instead of hanging it)
        let t0 = std::time::Instant::now();
        let stop = || !lines.borrow().is_empty() || t0.elapsed() > Duration::from_secs(5);
        let (sum, got, _) =
            publish_run_reporting(pacing, samples, "long-wait", Some(progress), &stop);
        assert_eq!((got.len(), sum.interrupted), (2, true));
        let lines = lines.into_inner();
        assert_eq!(lines.len(), 1);
        assert!(
            lines[0].starts_with("the next sample (stamp 1000000.000 s, 999999.900 s after the previous one's) is due in 11.6 days;"),
            "{}",
            lines[0]
        );
    }

    #[test]
    fn progress_reports_the_totals_so_far() {
        let samples: Vec<Sample> = (0..5).map(|i| Sample::new(i + 1, i as f64)).collect();
        let mut seen = vec![];
        let mut report =
            |s: &RunSummary, _: Duration, r: Option<String>| seen.push((s.published, r));
        let progress = Progress {
            every: Duration::ZERO,
            report: &mut report,
            notice: &mut |_| {},
        };
        let (sum, got, _) =
            publish_run_reporting(Pacing::Fast, samples, "progress", Some(progress), &|| false);
        assert_eq!(got.len(), 5);
        assert_eq!(sum.published, 5);
        // before each sample after the first: the totals published so far
        assert_eq!(seen, (0..5).map(|n| (n, None)).collect::<Vec<_>>());
    }

    /// A [`Sink`] without iceoryx2: counts what it is given.
    #[derive(Default)]
    struct Counting {
        published: Vec<Sample>,
    }

    impl Sink for Counting {
        fn publish(&mut self, t_ns: Nanos, value: f64) -> Result<u64, IpcError> {
            self.published.push(Sample::new(t_ns, value));
            Ok(self.published.len() as u64 - 1)
        }
        fn unreached(&self) -> u64 {
            0
        }
        fn unwoken(&self) -> u64 {
            0
        }
    }

    /// A source of scripted events, each after a pause; ends (as a live source
    /// does) once `stopped` is set.
    struct Scripted {
        events: std::collections::VecDeque<(Duration, Next)>,
        stopped: std::rc::Rc<std::cell::Cell<bool>>,
    }

    impl Source for Scripted {
        fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
            unreachable!("run asks for events")
        }
        fn next_event(&mut self) -> Result<Next, SourceError> {
            if self.stopped.get() {
                return Ok(Next::End);
            }
            let Some((pause, e)) = self.events.pop_front() else {
                return Ok(Next::End);
            };
            std::thread::sleep(pause);
            Ok(e)
        }
        fn describe(&self) -> String {
            "scripted".into()
        }
        fn report(&self) -> Option<String> {
            Some(format!("{} to come", self.events.len()))
        }
    }

    fn scripted(events: Vec<(Duration, Next)>) -> Scripted {
        Scripted {
            events: events.into(),
            stopped: Default::default(),
        }
    }

    /// Progress reports: `(published, since the previous, source report)`.
    type Reports = Vec<(u64, Duration, Option<String>)>;

    /// Runs `src` into a [`Counting`] sink with progress every `every`: the summary,
    /// the reports `(published, since the previous, source report)`, the sink.
    fn run_counting(
        src: &mut dyn Source,
        pacing: Pacing,
        every: Duration,
        stop: &dyn Fn() -> bool,
    ) -> (RunSummary, Reports, Counting) {
        let mut seen = vec![];
        let mut report =
            |s: &RunSummary, d: Duration, r: Option<String>| seen.push((s.published, d, r));
        let mut sink = Counting::default();
        let sum = run_into(
            src,
            &mut sink,
            pacing,
            stop,
            None,
            Some(Progress {
                every,
                report: &mut report,
                notice: &mut |_| {},
            }),
        )
        .unwrap();
        (sum, seen, sink)
    }

    #[test]
    fn progress_is_due_by_time_while_the_source_gives_no_sample() {
        // 30 idle returns 10 ms apart (a sensor whose frames give no sample), then
        // one sample: reports every 50 ms meanwhile, with nothing published
        let ms = Duration::from_millis;
        let mut events: Vec<_> = (0..30).map(|_| (ms(10), Next::Idle)).collect();
        events.push((ms(0), Next::Sample(Sample::new(1, 1.0))));
        let mut src = scripted(events);
        let t0 = std::time::Instant::now();
        let (sum, seen, sink) = run_counting(&mut src, Pacing::Fast, ms(50), &|| false);
        let took = t0.elapsed();
        assert_eq!((sum.published, sum.interrupted), (1, false));
        assert_eq!(sink.published.len(), 1);
        // 300 ms of idling: about 6 reports (fewer on a loaded machine), never more
        // than the run's length allows
        let most = (took.as_millis() / 50) as usize;
        assert!(seen.len() >= 2 && seen.len() <= most, "{took:?}: {seen:?}");
        assert!(seen.iter().all(|(n, _, _)| *n == 0), "{seen:?}");
        // each says the real time since the previous one, and together they cover
        // no more than the run
        assert!(seen.iter().all(|(_, d, _)| *d >= ms(50)), "{seen:?}");
        let covered: Duration = seen.iter().map(|s| s.1).sum();
        assert!(covered <= took, "{covered:?} > {took:?}");
        assert!(seen[0].2.as_deref().is_some_and(|r| r.ends_with("to come")));
    }

    #[test]
    fn a_report_after_a_long_silence_says_how_long_it_was() {
        // the source blocks 300 ms for its second sample; reports are due every
        // 50 ms: the one after the silence says 300 ms, not 50
        let ms = Duration::from_millis;
        let mut src = scripted(vec![
            (ms(0), Next::Sample(Sample::new(1, 1.0))),
            (ms(300), Next::Sample(Sample::new(2, 2.0))),
        ]);
        let (_, seen, _) = run_counting(&mut src, Pacing::Fast, ms(50), &|| false);
        assert_eq!(seen.len(), 1, "{seen:?}");
        assert!(seen[0].1 >= ms(300), "{seen:?}");
    }

    #[test]
    fn real_time_pacing_reports_while_it_waits() {
        // the second sample is due 300 ms after the first: reports every 50 ms
        // come in the wait
        let ms = Duration::from_millis;
        let mut src = scripted(vec![
            (ms(0), Next::Sample(Sample::new(0, 1.0))),
            (ms(0), Next::Sample(Sample::new(300_000_000, 2.0))),
        ]);
        let pacing = Pacing::Scaled {
            speed: 1.0,
            anchor_ns: 0,
            start_mono_ns: None,
        };
        let (sum, seen, _) = run_counting(&mut src, pacing, ms(50), &|| false);
        assert_eq!(sum.published, 2);
        assert!(seen.len() >= 2, "{seen:?}");
        assert!(seen.iter().all(|(n, _, _)| *n == 1), "{seen:?}");
    }

    #[test]
    fn a_source_ended_by_a_stop_is_an_interrupted_run() {
        // a live source returns its end when asked to stop: interrupted
        let ms = Duration::from_millis;
        let mut src = scripted(vec![
            (ms(0), Next::Sample(Sample::new(1, 1.0))),
            (ms(0), Next::Sample(Sample::new(2, 2.0))),
        ]);
        let flag = src.stopped.clone();
        // the stop comes during the first sample's checks (the driver sees it at
        // its next check), the source sees it at its next call and ends
        let asked = std::cell::Cell::new(0);
        let stop = || {
            asked.set(asked.get() + 1);
            flag.set(true);
            asked.get() > 1
        };
        let (sum, _, sink) = run_counting(&mut src, Pacing::Fast, Duration::from_secs(600), &stop);
        assert_eq!(sink.published.len(), 1);
        assert!(sum.interrupted, "{sum:?}");
        // a stop seen at an idle return: interrupted too
        let mut src = scripted(vec![(ms(0), Next::Idle), (ms(0), Next::Idle)]);
        let (sum, _, _) = run_counting(&mut src, Pacing::Fast, Duration::from_secs(600), &|| true);
        assert!(sum.interrupted && sum.published == 0, "{sum:?}");
        // a source that ends by itself, no stop: a normal end
        let mut src = VecSource::new(vec![Sample::new(1, 1.0)], "t");
        let (sum, seen, _) =
            run_counting(&mut src, Pacing::Fast, Duration::from_secs(600), &|| false);
        assert_eq!((sum.published, sum.interrupted, seen.len()), (1, false, 0));
    }

    #[test]
    fn real_time_pacing_follows_the_stamps() {
        // 11 samples 20 ms apart = 200 ms of sensor time
        let samples: Vec<Sample> = (0..11)
            .map(|i| Sample::new(i * 20_000_000, i as f64))
            .collect();
        // the run starts (and so paces from) after this instant
        let before = monotonic_ns();
        let (sum, got, el) = publish_run(
            Pacing::Scaled {
                speed: 1.0,
                anchor_ns: 0,
                start_mono_ns: None,
            },
            samples.clone(),
            "rt",
        );
        assert_eq!(sum.published, 11);
        // only lower bounds: pacing guarantees them, and a loaded machine may
        // publish any later
        assert!(el >= Duration::from_millis(195), "{el:?}");
        assert_eq!(got.len(), 11);
        assert!(got[0].is_first());
        for (i, g) in got.iter().enumerate() {
            assert_eq!(g.seq, i as u64);
            assert_eq!(g.t_ns, samples[i].t_ns);
            // each sample published no earlier than it was due: its stamp after the start
            assert!(
                g.publish_ns >= before + samples[i].t_ns,
                "sample {i} published {} ns before it was due",
                before + samples[i].t_ns - g.publish_ns
            );
        }
        // in order, and spaced at least like the stamps
        assert!(got.windows(2).all(|w| w[1].publish_ns >= w[0].publish_ns));
        let span = got[10].publish_ns - got[0].publish_ns;
        assert!(span >= 195_000_000, "{span}");
        // `Fast` does not pace: stamps a day apart are all published at once. Paced,
        // this run would take ten days; the stop after a minute (which a paced run
        // waits for) makes that a failure instead of a hang.
        const DAY: Nanos = 86_400 * S;
        let far: Vec<Sample> = (0..11).map(|i| Sample::new(i * DAY, i as f64)).collect();
        let t0 = std::time::Instant::now();
        let stop = || t0.elapsed() > Duration::from_secs(60);
        let (sum, got, _) = publish_run_reporting(Pacing::Fast, far, "fast", None, &stop);
        assert_eq!((sum.published, sum.interrupted), (11, false), "{sum:?}");
        assert_eq!(got.len(), 11);
    }

    #[test]
    fn restart_with_a_past_start_skips_the_past() {
        let samples: Vec<Sample> = (0..20).map(|i| Sample::new(i * 10_000_000, 0.0)).collect();
        // the run "started" 100 ms (plus the service set-up time) ago: samples
        // 0..=9 at least are in the past, the last ones (up to 190 ms) are not
        let (sum, got, _) = publish_run(
            Pacing::Scaled {
                speed: 1.0,
                anchor_ns: 0,
                start_mono_ns: Some(monotonic_ns() - 100_000_000),
            },
            samples,
            "skip",
        );
        assert!((9..20).contains(&sum.skipped), "{sum:?}");
        assert_eq!(sum.published + sum.skipped, 20);
        assert_eq!(got.len() as u64, sum.published);
        assert_eq!(got[0].seq, 0);
    }

    /// A restart whose source takes its time to reach the present (a recording
    /// decoded frame by frame) skips the samples that fell due meanwhile too, instead
    /// of publishing them late in one burst; from the first sample on time it paces.
    #[test]
    fn a_restart_skips_what_fell_due_while_the_source_caught_up() {
        let ms = Duration::from_millis;
        // 40 samples 10 ms apart, the first 20 each taking 10 ms to produce, the
        // rest at once; the run started 100 ms before this process: samples due
        // before the source reached them (0..=29 at least) are all in the past
        let events: Vec<_> = (0..40)
            .map(|i| {
                let pause = if i < 20 { ms(10) } else { ms(0) };
                (pause, Next::Sample(Sample::new(i * 10_000_000, 0.0)))
            })
            .collect();
        let mut src = scripted(events);
        let (sum, _, sink) = run_counting(
            &mut src,
            Pacing::Scaled {
                speed: 1.0,
                anchor_ns: 0,
                start_mono_ns: Some(monotonic_ns() - 100_000_000),
            },
            Duration::from_secs(3600),
            &|| false,
        );
        assert_eq!(sum.published + sum.skipped, 40, "{sum:?}");
        // the old rule (skip only what was due before the process started) skipped
        // about 10 and published the next 10 or more in a burst
        assert!(sum.skipped >= 30, "{sum:?}");
        // from the first sample on time, every one is published: a contiguous tail
        let first = sink.published.first().map_or(40, |s| s.t_ns / 10_000_000);
        let tail: Vec<_> = (first..40).map(|i| i * 10_000_000).collect();
        let got: Vec<_> = sink.published.iter().map(|s| s.t_ns).collect();
        assert_eq!(got, tail, "{sum:?}");
    }
}
