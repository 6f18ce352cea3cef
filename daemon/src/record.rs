//! `vlsyncd record`: the live signature streams of one prefix, and the daemon's
//! estimates, written as the CSV files `vlsyncd replay` reads and writes, so a run
//! on the robot can be replayed offline (another configuration, a bug report, a
//! regression test).
//!
//! The recorder reads every 20 ms at nice 10 rather than on the daemon's events, so
//! that it never runs while the daemon finishes a sample (see `run_cli`). Files in the
//! output directory, written row by row as samples arrive and flushed every second (a
//! recorder killed outright, or stopped by a full disk, leaves the complete rows of its
//! last flush, [`RowFile`]); created once the services are open:
//! * `cam.csv`, `lidar.csv`: header `t,value,seq,publish,flags`. `t` is the stamp on
//!   the sensor's clock and `publish` the driver's `CLOCK_MONOTONIC` publish time,
//!   both seconds with nine decimals (exact nanoseconds); the value in shortest
//!   round-trip notation, NaN and infinities kept as published (the estimator rejects
//!   and counts them on replay as it did live). `replay` reads the first two
//!   columns and ignores the rest.
//! * `est.csv`: the estimates the daemon published while recording (not the last one
//!   before, which a new subscriber is handed), in `replay`'s own format
//!   ([`crate::replay::ESTIMATE_HEADER`]), so the two compare row by row.
//!
//! A payload whose structure is invalid (unknown flags, non-zero padding) is skipped
//! and counted, as the daemon refuses it. Sequence numbers tell lost samples (a jump)
//! and driver restarts (`FLAG_FIRST`, or a number that goes back), by the daemon's
//! rule (`runtime::rt::seq_step`; a malformed sample counts nothing and is followed only
//! when it is exactly the next number, `seq_followed`), with one difference: the
//! recorder follows one sequence per stream, where the daemon follows each publisher's
//! (its payloads come without the publisher's id). One driver per stream, restarts
//! included (a restarted driver's first sample is a new run), reads the same either
//! way; two publishers alive on one stream at once (a test publisher beside a driver)
//! interleave their numbers, and the recorder counts losses and restarts in them
//! where the daemon counts none.
//!
//! ```
//! use vlsync_common::{wire::SignatureSample, Stream};
//! use vlsyncd::record::Recording;
//! let mut r = Recording::new(Vec::new(), Vec::new(), Vec::new()).unwrap();
//! r.signature(Stream::Cam, &SignatureSample::new(1_500_000_000, 0.25, 0, 7_000_000_000))
//!     .unwrap();
//! r.signature(Stream::Cam, &SignatureSample::new(1_533_333_333, 0.5, 2, 7_033_000_000))
//!     .unwrap();
//! let (cam, _, _) = r.into_writers();
//! assert_eq!(
//!     String::from_utf8(cam).unwrap(),
//!     "t,value,seq,publish,flags\n1.500000000,0.25,0,7.000000000,0\n1.533333333,0.5,2,7.033000000,0\n"
//! );
//! ```

use crate::runtime::rt::{seq_followed, seq_step, SeqStep};
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use vlsync_common::wire::SignatureSample;
use vlsync_common::{nanos_to_secs, Estimate, EstimatorState, Nanos, Stream};
use vlsync_sim::io::format_secs;

/// The header of the recorded signature files.
pub const SIGNATURE_HEADER: &str = "t,value,seq,publish,flags";

/// The files a recording writes into its directory: camera, LiDAR, estimates.
pub const FILES: [&str; 3] = ["cam.csv", "lidar.csv", "est.csv"];

/// A recording file that always ends on a whole row: rows gather in memory and go to
/// the file at each [`Write::flush`] (every second, `FLUSH_EVERY`); a flush that fails part
/// way (a full disk) cuts the file back to the end of the last flush that succeeded,
/// so `vlsyncd replay` reads it whole, never a row cut in its value.
pub struct RowFile<F: Cut = std::fs::File> {
    file: F,
    buf: Vec<u8>,
    /// Bytes in the file: every flush that succeeded.
    committed: u64,
}

/// A file [`RowFile`] can cut back to a length after a failed write.
pub trait Cut: Write {
    /// Sets the length to `len` and the position to its end.
    fn cut(&mut self, len: u64) -> std::io::Result<()>;
}

impl Cut for std::fs::File {
    fn cut(&mut self, len: u64) -> std::io::Result<()> {
        use std::io::Seek;
        self.set_len(len)?;
        self.seek(std::io::SeekFrom::Start(len)).map(drop)
    }
}

impl<F: Cut> RowFile<F> {
    /// Rows go to `file`, which is empty.
    pub fn new(file: F) -> Self {
        Self {
            file,
            buf: Vec::with_capacity(64 * 1024),
            committed: 0,
        }
    }

    /// The file.
    pub fn into_inner(self) -> F {
        self.file
    }
}

impl<F: Cut> Write for RowFile<F> {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.buf.extend_from_slice(b);
        Ok(b.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.buf.is_empty() {
            return Ok(());
        }
        match self.file.write_all(&self.buf) {
            Ok(()) => {
                self.committed += self.buf.len() as u64;
                self.buf.clear();
                self.file.flush()
            }
            Err(e) => {
                // the part that went in is cut off again (a device such as /dev/full
                // has no length to set: nothing went in); the rows stay for a retry
                let _ = self.file.cut(self.committed);
                Err(e)
            }
        }
    }
}

/// What one stream's recording saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamCounts {
    /// Rows written (to the file at its next flush).
    pub rows: u64,
    /// Samples missing between received ones (sequence-number jumps): lost by the
    /// recorder's buffer or before it.
    pub lost: u64,
    /// Samples a driver published before the first one recorded of its run: the
    /// sequence number of a run's first row when that is not the driver's first
    /// sample (published before the recorder listened, or dropped from its buffer
    /// before it read any). The daemon's estimator may have had them; a replay
    /// does not.
    pub before_first: u64,
    /// Driver restarts seen (`FLAG_FIRST` after the first row, or a sequence
    /// number that went back).
    pub restarts: u64,
    /// Payloads skipped because their structure is invalid.
    pub malformed: u64,
    /// What was wrong with the last of them.
    pub last_malformed: Option<vlsync_common::wire::WireError>,
    /// Rows written whose value is NaN or infinite.
    pub non_finite: u64,
}

/// A recording in progress: three CSV writers and what went into them.
pub struct Recording<W: Write> {
    out: [W; 3],
    /// How errors name the three files.
    names: [String; 3],
    counts: [StreamCounts; 2],
    last_seq: [Option<u64>; 2],
    states: [u64; 4],
    last_estimate: Option<Estimate>,
    line: String,
    /// Rows given to each writer since the recording began, and as of the last flush
    /// that succeeded (what a file holds when a flush fails).
    rows: [u64; 3],
    flushed: [u64; 3],
}

impl<W: Write> Recording<W> {
    /// Starts a recording into the camera, LiDAR and estimate writers: writes the
    /// headers. An error names the file ([`FILES`]) that could not be written.
    pub fn new(cam: W, lidar: W, est: W) -> Result<Self, String> {
        Self::named([cam, lidar, est], FILES.map(String::from))
    }

    /// [`Recording::new`] with the names errors give the files (their paths).
    pub fn named(out: [W; 3], names: [String; 3]) -> Result<Self, String> {
        let mut r = Self {
            out,
            names,
            counts: [StreamCounts::default(); 2],
            last_seq: [None; 2],
            states: [0; 4],
            last_estimate: None,
            line: String::with_capacity(128),
            rows: [0; 3],
            flushed: [0; 3],
        };
        r.write(0, SIGNATURE_HEADER)?;
        r.write(1, SIGNATURE_HEADER)?;
        r.write(2, crate::replay::ESTIMATE_HEADER)?;
        Ok(r)
    }

    fn write(&mut self, file: usize, row: &str) -> Result<(), String> {
        let name = &self.names[file];
        writeln!(self.out[file], "{row}").map_err(|e| format!("cannot write {name}: {e}"))?;
        self.rows[file] += 1;
        Ok(())
    }

    /// Writes one received signature sample (or skips and counts it when its
    /// structure is invalid).
    pub fn signature(&mut self, stream: Stream, s: &SignatureSample) -> Result<(), String> {
        let i = vlsync_ipc::stream_index(stream);
        let check = s.validate();
        let valid = check.is_ok();
        let c = &mut self.counts[i];
        // the daemon's rule: a gap is lost; a new run after the first row is a driver
        // restart; a run's first row that is not its driver's first sample leaves the
        // samples numbered before it unread. A malformed sample counts nothing, and its
        // number is followed only when it is exactly the next (it was published: the
        // next one is its successor, not one after a lost sample); any other number it
        // carries is as unreliable as the rest of it, and the next good sample is
        // judged against the last one followed (`seq_followed`, as the daemon judges)
        let step = seq_step(self.last_seq[i], s.seq, s.is_first());
        if valid {
            match step {
                SeqStep::Next => {}
                SeqStep::Lost(n) => c.lost = c.lost.saturating_add(n),
                SeqStep::NewRun { before } => {
                    if self.last_seq[i].is_some() {
                        c.restarts += 1;
                    }
                    c.before_first = c.before_first.saturating_add(before);
                }
            }
        }
        if seq_followed(step, valid) {
            self.last_seq[i] = Some(s.seq);
        }
        if let Err(e) = check {
            c.malformed += 1;
            c.last_malformed = Some(e);
            return Ok(());
        }
        c.rows += 1;
        if !s.value.is_finite() {
            c.non_finite += 1;
        }
        let mut line = std::mem::take(&mut self.line);
        line.clear();
        let _ = write!(
            line,
            "{},{},{},{},{}",
            format_secs(s.t_ns),
            s.value,
            s.seq,
            format_secs(s.publish_ns),
            s.flags
        );
        let r = self.write(i, &line);
        self.line = line;
        r
    }

    /// Writes one estimate the daemon published.
    pub fn estimate(&mut self, e: &Estimate) -> Result<(), String> {
        let mut line = std::mem::take(&mut self.line);
        crate::replay::estimate_row(e, &mut line);
        let r = self.write(2, &line);
        self.line = line;
        r?;
        self.states[e.state as usize] += 1;
        self.last_estimate = Some(*e);
        Ok(())
    }

    /// Flushes the three writers. An error names the file and how many rows it holds
    /// (header included): those of its last flush that succeeded, when its writer is
    /// a [`RowFile`].
    pub fn flush(&mut self) -> Result<(), String> {
        // every file, whichever fails: the others' rows are not held back by it
        let mut first = Ok(());
        for (i, (w, name)) in self.out.iter_mut().zip(&self.names).enumerate() {
            match w.flush() {
                Ok(()) => self.flushed[i] = self.rows[i],
                Err(e) if first.is_ok() => {
                    first = Err(format!(
                        "cannot write {name}: {e} (it keeps the {} rows of the last complete flush)",
                        self.flushed[i]
                    ));
                }
                Err(_) => {}
            }
        }
        first
    }

    /// What each stream's recording saw (0 camera, 1 LiDAR).
    pub fn counts(&self) -> [StreamCounts; 2] {
        self.counts
    }

    /// Estimates written.
    pub fn estimates(&self) -> u64 {
        self.states.iter().sum()
    }

    /// One line on the recording so far (the progress line).
    pub fn progress(&self, elapsed_s: f64) -> String {
        let [c, l] = self.counts;
        let last = match &self.last_estimate {
            Some(e) => format!(
                " (last {}, offset {:+.3} ms ± {:.3} ms)",
                e.state.name(),
                e.offset_s * 1e3,
                e.offset_std_s * 1e3
            ),
            None => String::new(),
        };
        format!(
            "{elapsed_s:.0} s: cam {} samples ({} lost), lidar {} ({} lost), {} estimates{last}",
            c.rows,
            c.lost,
            l.rows,
            l.lost,
            self.estimates()
        )
    }

    /// The closing summary, a line per file.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        for (name, c) in ["cam", "lidar"].iter().zip(self.counts) {
            let _ = writeln!(
                s,
                "{name:>9}: {} samples, {} lost (sequence gaps), {} published before the first recorded, {} driver restarts, {} malformed payloads skipped{}, {} non-finite values kept",
                c.rows,
                c.lost,
                c.before_first,
                c.restarts,
                c.malformed,
                c.last_malformed
                    .map_or(String::new(), |e| format!(" (the last: {e})")),
                c.non_finite
            );
        }
        let st = |x: EstimatorState| self.states[x as usize];
        let _ = write!(
            s,
            "estimates: {} ({} tracking, {} holding, {} acquiring, {} lost)",
            self.estimates(),
            st(EstimatorState::Tracking),
            st(EstimatorState::Holding),
            st(EstimatorState::Acquiring),
            st(EstimatorState::Lost)
        );
        match &self.last_estimate {
            Some(e) => {
                let _ = writeln!(
                    s,
                    "; the last at t={:.3} s: offset {:+.4} ms ± {:.4} ms (1σ), drift {:+.2} ppm, {}",
                    nanos_to_secs(e.t_ref_ns),
                    e.offset_s * 1e3,
                    e.offset_std_s * 1e3,
                    e.drift * 1e6,
                    e.state
                );
            }
            None => s.push('\n'),
        }
        s
    }

    /// The three writers, camera, LiDAR, estimates (tests read what was written).
    pub fn into_writers(self) -> (W, W, W) {
        let [c, l, e] = self.out;
        (c, l, e)
    }
}

/// Arguments of `vlsyncd record`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    /// Directory to write cam.csv, lidar.csv and est.csv into (created when missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Service prefix (`services.prefix`); overrides the one of --config.
    #[arg(long)]
    pub prefix: Option<String>,
    /// Configuration file of the daemon: its `services.prefix` (the default prefix
    /// without either), and the replay command printed at the end uses it too.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Stop after this many seconds (0: at Ctrl-C or SIGTERM).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0)]
    pub duration: f64,
    /// A progress line on stderr every this many seconds, 1 or more (0: none).
    #[arg(long, allow_negative_numbers = true, default_value_t = 10.0)]
    pub progress_every: f64,
    /// Overwrite the files of an earlier recording in --out.
    #[arg(long)]
    pub force: bool,
    /// Nice value of the recorder, 0..=19: it yields the CPU to the daemon, which it
    /// would otherwise delay on a small machine at high sample rates.
    #[arg(long, allow_negative_numbers = true, default_value_t = 10)]
    pub nice: i32,
}

/// After this long without any sample or estimate, the recorder says what it waits for.
const QUIET_NOTICE: Duration = Duration::from_secs(5);
/// How often the files are flushed.
const FLUSH_EVERY: Duration = Duration::from_secs(1);
/// The sleep between two reads of the subscribers: the signature services' buffer
/// holds 256 samples, 64 ms at 100x the nominal 30 + 10 Hz, and the offset
/// service's 16 estimates, 80 ms at 100x the default hop.
const POLL: Duration = Duration::from_millis(20);
/// The subscriber buffer asked for (the services grant their maximum, 256 by default).
const BUFFER: usize = 4096;

/// The service names, and `services.subscriber_buffer` (for services the recorder
/// creates, as a driver would).
fn check_args(a: &RecordArgs) -> Result<(vlsync_ipc::ServiceNames, usize), String> {
    if !(a.duration.is_finite() && a.duration >= 0.0) {
        return Err(format!(
            "--duration {} must be a finite number of seconds >= 0",
            vlsync_common::text::number(a.duration)
        ));
    }
    if !(a.progress_every == 0.0 || (a.progress_every.is_finite() && a.progress_every >= 1.0)) {
        // a tiny period would print a line at every poll, for ever
        return Err(format!(
            "--progress-every {} is out of range: allowed 0 (no progress lines) or 1 s or more",
            vlsync_common::text::number(a.progress_every)
        ));
    }
    if !(0..=19).contains(&a.nice) {
        return Err(format!(
            "--nice {} must be within 0..=19 (the recorder yields to the daemon, never the reverse)",
            a.nice
        ));
    }
    let cfg = match &a.config {
        Some(p) => vlsync_config::Config::load(p).map_err(|e| e.to_string())?,
        None => vlsync_config::Config::default(),
    };
    let prefix = a.prefix.clone().unwrap_or(cfg.services.prefix);
    let names = vlsync_ipc::ServiceNames::new(&prefix).map_err(|e| e.to_string())?;
    // validated 1..=65536
    let service_buffer = usize::try_from(cfg.services.subscriber_buffer).unwrap_or(1);
    Ok((names, service_buffer))
}

/// Creates `dir` and the three files in it; refuses to overwrite an earlier
/// recording unless `force`.
fn create_files(dir: &Path, force: bool) -> Result<[RowFile; 3], String> {
    vlsync_common::file::create_out_dir("--out", dir)?;
    if !force {
        if let Some(p) = FILES.iter().map(|f| dir.join(f)).find(|p| p.exists()) {
            return Err(format!(
                "{} exists: refusing to overwrite a recording (--force overwrites it)",
                p.display()
            ));
        }
    }
    let open = |f: &str| {
        let p = dir.join(f);
        std::fs::File::create(&p)
            .map(RowFile::new)
            .map_err(|e| format!("cannot create {}: {e}", p.display()))
    };
    Ok([open(FILES[0])?, open(FILES[1])?, open(FILES[2])?])
}

/// Reads the pending samples of both streams into the recording, at most
/// [`BUFFER`] of each: a publisher faster than the recorder (a driver's `--fast`
/// replay) would otherwise keep it in one stream's loop, reading neither the other
/// stream, nor the estimates, nor Ctrl-C, nor the clock.
fn drain_signatures<W: Write>(
    subs: &mut [vlsync_ipc::SignatureSubscriber; 2],
    rec: &mut Recording<W>,
) -> Result<bool, String> {
    let mut any = false;
    for (sub, stream) in subs.iter_mut().zip([Stream::Cam, Stream::Lidar]) {
        for _ in 0..BUFFER {
            let Some(s) = sub.receive().map_err(|e| e.to_string())? else {
                break;
            };
            rec.signature(stream, &s)?;
            any = true;
        }
    }
    Ok(any)
}

/// `s` as one word of a POSIX shell: as it is when it holds only characters no shell
/// treats specially, else in single quotes (a `'` in it as `'\''`).
fn sh_quote(s: &str) -> String {
    let plain = !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"_./:@%+=,-".contains(&b));
    if plain {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// The `record` command.
pub fn run_cli(a: &RecordArgs) -> Result<(), String> {
    let (names, service_buffer) = check_args(a)?;
    let prefix = names.prefix.clone();
    let err = vlsync_common::console::print_err;
    if a.nice > 0 {
        // raising one's own nice value needs no privilege; should it fail, say so
        if let Err(e) = vlsync_ipc::rt::set_current_thread_nice(a.nice, "--nice") {
            err(&format!("vlsyncd record: {e}; recording anyway\n"));
        }
    }
    // a node that handles SIGINT/SIGTERM, so Ctrl-C ends the recording cleanly
    let node = vlsync_ipc::create_node("vlsyncd-record", true).map_err(|e| e.to_string())?;
    let open = |s| vlsync_ipc::SignatureSubscriber::open(&node, &names, s, service_buffer, BUFFER);
    let mut subs = [
        open(Stream::Cam).map_err(|e| e.to_string())?,
        open(Stream::Lidar).map_err(|e| e.to_string())?,
    ];
    let mut offsets = vlsync_ipc::OffsetClient::open(&prefix).map_err(|e| e.to_string())?;
    // the files once the services are open: a recorder that cannot listen (the
    // daemon's shared memory is another user's) leaves no empty recording behind to
    // refuse the retry, and with --force destroys no earlier one
    let files = create_files(&a.out, a.force)?;
    let paths = FILES.map(|f| a.out.join(f).display().to_string());
    let mut rec = Recording::named(files, paths)?;
    let start_ns: Nanos = vlsync_ipc::monotonic_ns();
    err(&format!(
        "vlsyncd record: recording prefix `{prefix}` into {} (subscriber buffer {} samples){}; Ctrl-C stops\n",
        a.out.display(),
        subs[0].buffer().granted.min(subs[1].buffer().granted),
        if a.duration > 0.0 {
            format!(" for {} s", a.duration)
        } else {
            String::new()
        }
    ));
    let t0 = Instant::now();
    let (mut last_flush, mut next_progress) = (t0, a.progress_every);
    let mut told = false;
    let mut heard = false;
    // one round: every pending sample, then every pending estimate. Between rounds
    // the recorder sleeps instead of waiting on the offset event: woken by each
    // estimate, it would run while the daemon finishes the sample that made it (and
    // on a 2-core machine at 100x the nominal rates, it lifted the daemon's
    // processing p99 from 12-14 µs to 59-107 µs)
    let mut round = |rec: &mut Recording<_>| -> Result<bool, String> {
        let mut any = drain_signatures(&mut subs, rec)?;
        let pending = offsets.wait_all(Duration::ZERO);
        for (e, publish_ns) in pending.map_err(|e| e.to_string())? {
            // the estimate handed to every new subscriber was published before
            if publish_ns >= start_ns {
                rec.estimate(&e)?;
                any = true;
            }
        }
        Ok(any)
    };
    let result = loop {
        let step = round(&mut rec).map(|any| heard |= any);
        if let Err(e) = step {
            break Err(e);
        }
        let elapsed = t0.elapsed();
        if last_flush.elapsed() >= FLUSH_EVERY {
            if let Err(e) = rec.flush() {
                break Err(e);
            }
            last_flush = Instant::now();
        }
        if !heard && !told && elapsed >= QUIET_NOTICE {
            told = true;
            err(&format!(
                "vlsyncd record: nothing received on prefix `{prefix}` for {} s; waiting (are the drivers running with this prefix? vlsync-demo prints its own at its start)\n",
                QUIET_NOTICE.as_secs()
            ));
        }
        if a.progress_every > 0.0 && elapsed.as_secs_f64() >= next_progress {
            err(&format!(
                "vlsyncd record: {}\n",
                rec.progress(elapsed.as_secs_f64())
            ));
            next_progress += a.progress_every;
        }
        if vlsync_ipc::termination_requested()
            || (a.duration > 0.0 && elapsed.as_secs_f64() >= a.duration)
        {
            // what arrived up to the stop belongs to the recording
            break round(&mut rec).map(|_| ());
        }
        std::thread::sleep(POLL);
    };
    // whatever ended the loop, what was received is flushed and summarised
    let result = result.and(rec.flush());
    let stopped_by = match &result {
        Ok(()) => String::new(),
        Err(e) => format!(
            "; ended after {:.1} s by an error ({e}): the files hold what was written before it",
            t0.elapsed().as_secs_f64()
        ),
    };
    err(&format!(
        "vlsyncd record: {:.1} s on prefix `{prefix}` into {}{stopped_by}\n{}",
        t0.elapsed().as_secs_f64(),
        a.out.display(),
        rec.summary()
    ));
    if offsets.invalid_count() > 0 {
        err(&format!(
            "{} estimate payloads on `{prefix}/offset` were invalid and are not in est.csv\n",
            offsets.invalid_count()
        ));
    }
    if result.is_ok() && rec.estimates() == 0 {
        err(&format!(
            "no estimate was published while recording (is vlsyncd running with services.prefix = \"{prefix}\"?)\n"
        ));
    }
    if result.is_ok() && rec.counts().iter().all(|c| c.rows > 0) {
        let [c, l] = rec.counts().map(|c| c.before_first);
        if c + l > 0 {
            err(&format!(
                "the drivers published {c} camera and {l} LiDAR samples before this recording read any: the daemon may have had them, a replay will not, so its estimates may differ from est.csv (start the drivers once the recorder says \"Ctrl-C stops\")\n"
            ));
        }
        // the replay's output where it is run, not in the recording (the daemon
        // user's, and a later record --force would leave it beside another run)
        let q = |p: &Path| sh_quote(&p.display().to_string());
        err(&format!(
            "replay it: vlsyncd replay --cam {} --lidar {} --out replayed.csv --compare {}{}\n",
            q(&a.out.join(FILES[0])),
            q(&a.out.join(FILES[1])),
            q(&a.out.join(FILES[2])),
            a.config
                .as_ref()
                .map(|c| format!(" --config {}", q(c)))
                .unwrap_or_default()
        ));
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlsync_common::wire::FLAG_FIRST;
    use vlsync_common::Polarity;

    /// A disk that takes `room` bytes, then is full; a cut sets its length.
    struct SmallDisk {
        data: Vec<u8>,
        room: usize,
    }

    impl Write for SmallDisk {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            let n = b.len().min(self.room - self.data.len().min(self.room));
            if n == 0 {
                return Err(std::io::Error::new(std::io::ErrorKind::StorageFull, "full"));
            }
            self.data.extend_from_slice(&b[..n]);
            Ok(n)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Cut for SmallDisk {
        fn cut(&mut self, len: u64) -> std::io::Result<()> {
            self.data.truncate(len as usize);
            Ok(())
        }
    }

    #[test]
    fn a_disk_that_fills_mid_row_leaves_the_rows_of_the_last_complete_flush() {
        let disk = |room| {
            RowFile::new(SmallDisk {
                data: Vec::new(),
                room,
            })
        };
        let mut r = Recording::new(disk(200), disk(10_000), disk(10_000)).unwrap();
        let mut seq = 0;
        let mut push = |r: &mut Recording<_>, n| {
            for _ in 0..n {
                r.signature(Stream::Cam, &sample(seq as i64 * 33, 0.125, seq))
                    .unwrap();
                seq += 1;
            }
        };
        push(&mut r, 3);
        r.flush().unwrap();
        // the next flush no longer fits: the file keeps the header and three rows
        push(&mut r, 3);
        let e = r.flush().unwrap_err();
        assert_eq!(
            e,
            "cannot write cam.csv: full (it keeps the 4 rows of the last complete flush)"
        );
        r.signature(Stream::Lidar, &sample(0, 0.5, 0)).unwrap();
        assert!(r.flush().is_err());
        let (cam, lidar, _) = r.into_writers();
        // the LiDAR's file is flushed all the same
        assert_eq!(
            lidar
                .into_inner()
                .data
                .iter()
                .filter(|&&b| b == b'\n')
                .count(),
            2
        );
        let text = String::from_utf8(cam.into_inner().data).unwrap();
        assert!(text.ends_with('\n'), "{text:?}");
        assert_eq!(text.lines().count(), 4, "{text:?}");
        let (samples, _) = vlsync_sim::io::parse_signature_csv(text.as_bytes(), "cam").unwrap();
        assert_eq!(samples.len(), 3);
    }

    fn sample(t_ms: i64, v: f64, seq: u64) -> SignatureSample {
        SignatureSample::new(t_ms * 1_000_000, v, seq, 5_000_000_000 + t_ms * 1_000_000)
    }

    #[test]
    fn rows_read_back_as_replay_input_with_their_exact_stamps_and_values() {
        let mut r = Recording::new(vec![], vec![], vec![]).unwrap();
        let sent = [
            sample(1_700_000_000_123, 0.1 + 0.2, 0),
            sample(1_700_000_000_156, -3.5e-7, 1),
            sample(1_700_000_000_190, f64::NAN, 2),
        ];
        for s in &sent {
            r.signature(Stream::Lidar, s).unwrap();
        }
        assert_eq!(r.counts()[1].non_finite, 1);
        let (_, lidar, _) = r.into_writers();
        let (back, stats) = vlsync_sim::io::parse_signature_csv(&lidar, "lidar.csv").unwrap();
        assert_eq!(back.len(), 3);
        assert_eq!(stats.extra_column_rows, 3);
        for (b, s) in back.iter().zip(&sent) {
            assert_eq!(b.t_ns, s.t_ns);
            assert!(b.value == s.value || (b.value.is_nan() && s.value.is_nan()));
        }
    }

    #[test]
    fn gaps_restarts_and_malformed_payloads_are_counted() {
        let mut r = Recording::new(vec![], vec![], vec![]).unwrap();
        // joined mid-stream at 40: no gap before it
        for seq in [40, 41, 44, 45] {
            r.signature(Stream::Cam, &sample(seq as i64 * 33, 1.0, seq))
                .unwrap();
        }
        // a restarted driver: FLAG_FIRST, then a number that goes back without it
        let mut first = sample(10, 1.0, 0);
        first.flags |= FLAG_FIRST;
        r.signature(Stream::Cam, &first).unwrap();
        r.signature(Stream::Cam, &sample(12, 1.0, 1)).unwrap();
        r.signature(Stream::Cam, &sample(20, 1.0, 0)).unwrap();
        // unknown flags and non-zero padding: skipped, as the daemon refuses them
        let mut bad = sample(30, 1.0, 1);
        bad.flags = 0x80;
        r.signature(Stream::Cam, &bad).unwrap();
        bad.flags = 0;
        bad.reserved = 1;
        r.signature(Stream::Cam, &bad).unwrap();
        // the next after them is their successor: not a gap (the daemon's rule)
        r.signature(Stream::Cam, &sample(40, 1.0, 2)).unwrap();
        // a malformed one numbered far off is no restart, and is not followed
        bad.seq = u64::MAX;
        r.signature(Stream::Cam, &bad).unwrap();
        r.signature(Stream::Cam, &sample(41, 1.0, 3)).unwrap();
        let c = r.counts()[0];
        assert_eq!(
            c,
            StreamCounts {
                rows: 9,
                lost: 2,
                before_first: 40,
                restarts: 2,
                malformed: 3,
                last_malformed: Some(vlsync_common::wire::WireError::NonZeroPadding {
                    field: "reserved"
                }),
                non_finite: 0
            }
        );
        assert_eq!(r.counts()[1], StreamCounts::default());
        let summary = r.summary();
        assert!(
            summary.contains("cam: 9 samples, 2 lost (sequence gaps), 40 published before the first recorded, 2 driver restarts, 3 malformed payloads skipped (the last: padding field `reserved` is not zero (layout mismatch?)), 0 non-finite"),
            "{summary}"
        );
        assert!(summary.contains("estimates: 0 ("), "{summary}");
        let (cam, _, _) = r.into_writers();
        assert_eq!(String::from_utf8(cam).unwrap().lines().count(), 10);
    }

    proptest::proptest! {
        /// Whatever a publisher puts in shared memory is written or skipped and
        /// counted, never a panic: every sample is a row or a malformed one.
        #[test]
        fn any_payload_is_written_or_counted(
            raw in proptest::collection::vec(
                (proptest::prelude::any::<i64>(), proptest::prelude::any::<f64>(),
                 proptest::prelude::any::<u64>(), proptest::prelude::any::<i64>(),
                 0u32..4, 0u32..2),
                0..40,
            )
        ) {
            let mut r = Recording::new(vec![], vec![], vec![]).unwrap();
            for &(t, v, seq, publish, flags, reserved) in &raw {
                let s = SignatureSample { t_ns: t, value: v, seq, publish_ns: publish, flags, reserved };
                r.signature(Stream::Cam, &s).unwrap();
            }
            let c = r.counts()[0];
            proptest::prop_assert_eq!(c.rows + c.malformed, raw.len() as u64);
            let (cam, _, _) = r.into_writers();
            proptest::prop_assert_eq!(String::from_utf8(cam).unwrap().lines().count() as u64, c.rows + 1);
        }
    }

    /// A malformed sample's number counts nothing and is followed only when it is the
    /// exact next one (the daemon's rule): garbage there used to count good samples
    /// lost, or a restart after a jump it made.
    #[test]
    fn a_malformed_sample_is_followed_only_as_the_next_number() {
        let mut r = Recording::new(vec![], vec![], vec![]).unwrap();
        let bad = |seq| {
            let mut s = sample(1, 1.0, seq);
            s.reserved = 1;
            s
        };
        let (b0, b_jump, b_next) = (bad(0), bad(101 + (1 << 31)), bad(103));
        for s in [
            sample(1, 1.0, 100),
            b0,
            sample(2, 1.0, 101),
            b_jump,
            sample(3, 1.0, 102),
            b_next,
            sample(4, 1.0, 104),
        ] {
            r.signature(Stream::Lidar, &s).unwrap();
        }
        let c = r.counts()[1];
        assert_eq!(
            (c.rows, c.malformed, c.lost, c.restarts, c.before_first),
            (4, 3, 0, 0, 100)
        );
    }

    #[test]
    fn a_sequence_jump_beyond_any_buffer_is_a_restart_not_a_loss() {
        let mut r = Recording::new(vec![], vec![], vec![]).unwrap();
        for seq in [5, u64::MAX, 6, 8] {
            r.signature(Stream::Lidar, &sample(1, 1.0, seq)).unwrap();
        }
        let c = r.counts()[1];
        assert_eq!((c.rows, c.lost, c.restarts), (4, 1, 2));
    }

    #[test]
    fn estimates_are_written_in_the_replay_format_and_summarised() {
        let mut r = Recording::new(vec![], vec![], vec![]).unwrap();
        let e = Estimate {
            seq: 9,
            t_ref_ns: 12_500_000_000,
            offset_s: 0.0251,
            drift: 2.5e-5,
            offset_std_s: 0.0008,
            drift_std: 1e-5,
            state: EstimatorState::Tracking,
            polarity: Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: f64::INFINITY,
            measured_offset_s: 0.025,
        };
        r.estimate(&e).unwrap();
        r.estimate(&Estimate {
            seq: 10,
            state: EstimatorState::Holding,
            ..e
        })
        .unwrap();
        assert_eq!(r.estimates(), 2);
        let summary = r.summary();
        assert!(
            summary.contains("estimates: 2 (1 tracking, 1 holding, 0 acquiring, 0 lost); the last at t=12.500 s: offset +25.1000 ms ± 0.8000 ms (1σ), drift +25.00 ppm, holding"),
            "{summary}"
        );
        assert!(r.progress(3.0).starts_with("3 s: cam 0 samples (0 lost), lidar 0 (0 lost), 2 estimates (last holding, offset +25.100 ms"));
        let (_, _, est) = r.into_writers();
        let text = String::from_utf8(est).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some(crate::replay::ESTIMATE_HEADER));
        let mut row = String::new();
        crate::replay::estimate_row(&e, &mut row);
        assert_eq!(lines.next(), Some(row.as_str()));
        assert!(lines.next().unwrap().ends_with(",10"));
    }

    /// A writer that takes `ok` bytes, then fails.
    struct Failing {
        ok: usize,
    }
    impl Write for Failing {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.ok < buf.len() {
                return Err(std::io::Error::other("disk full"));
            }
            self.ok -= buf.len();
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_write_error_names_the_file() {
        let header = SIGNATURE_HEADER.len() + 1;
        let big = Failing { ok: 1 << 20 };
        let mut r = Recording::new(Failing { ok: 1 << 20 }, Failing { ok: header }, big).unwrap();
        let e = r.signature(Stream::Lidar, &sample(1, 1.0, 0)).unwrap_err();
        assert_eq!(e, "cannot write lidar.csv: disk full");
        let e = Recording::new(Failing { ok: 3 }, Failing { ok: 99 }, Failing { ok: 999 });
        assert_eq!(e.err().unwrap(), "cannot write cam.csv: disk full");
    }

    #[test]
    fn arguments_out_of_range_and_an_earlier_recording_are_refused() {
        let dir = std::env::temp_dir().join(format!("vlsync-record-unit-{}", std::process::id()));
        let args = |d: f64, p: f64| RecordArgs {
            out: dir.clone(),
            prefix: None,
            config: None,
            duration: d,
            progress_every: p,
            force: false,
            nice: 10,
        };
        assert!(check_args(&args(-1.0, 10.0))
            .unwrap_err()
            .starts_with("--duration -1 must be"));
        for (bad, shown) in [
            (f64::NAN, "NaN"),
            (1e-300, "1e-300"),
            (0.5, "0.5"),
            (-1.0, "-1"),
        ] {
            assert_eq!(
                check_args(&args(1.0, bad)).unwrap_err(),
                format!(
                    "--progress-every {shown} is out of range: allowed 0 (no progress lines) or 1 s or more"
                )
            );
        }
        assert!(check_args(&args(1.0, 1.0)).is_ok());
        let (names, service_buffer) = check_args(&args(0.0, 0.0)).unwrap();
        assert_eq!(
            (names.prefix.as_str(), service_buffer),
            ("vlsync/robot", 256)
        );
        for nice in [-1, 20] {
            let mut a = args(0.0, 0.0);
            a.nice = nice;
            assert!(check_args(&a)
                .unwrap_err()
                .starts_with(&format!("--nice {nice} must be within 0..=19")));
        }
        let mut bad = args(0.0, 0.0);
        bad.prefix = Some("no spaces allowed".into());
        assert!(check_args(&bad).is_err());
        let _ = std::fs::remove_dir_all(&dir);
        drop(create_files(&dir, false).unwrap());
        let e = create_files(&dir, false).err().unwrap();
        assert!(
            e.ends_with(
                "cam.csv exists: refusing to overwrite a recording (--force overwrites it)"
            ),
            "{e}"
        );
        assert!(create_files(&dir, true).is_ok());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
