//! Persistence of the last good estimate across daemon restarts
//! (`daemon.state_file`, `daemon.state_max_age_s`).
//!
//! The service thread (never the real-time thread) keeps the newest estimate
//! worth saving ([`worth_saving`]: tracking, or holding with a small standard
//! deviation) and has it written (by a thread of its own in the daemon,
//! [`Saver::in_background`]) at most every [`SAVE_PERIOD`] while it tells a restart
//! something new (its offset off what the saved one predicts by more than the
//! smaller of their standard deviations, its drift off the saved one by more than
//! the smaller drift deviation, a standard deviation shrunk by more than a fifth,
//! another polarity), at least every [`REFRESH_PERIOD`] while it does not (fewer
//! fsyncs wear an SD card less: 99-114 saves in a simulated hour of steady tracking,
//! against 704-712 at one every 5 s), and once more on shutdown
//! ([`Saver`]). A save is atomic: the text goes to `<file>.tmp-<pid>` in the
//! same directory (leftovers of ended processes are removed at start), is fsynced, renamed over the file, and the directory is
//! fsynced, so a crash at any point leaves either the old or the new file.
//!
//! At start ([`load_at`]) the file is hostile input: a missing file is a cold start;
//! a corrupt one (wrong magic or version, truncated, bad checksum, a malformed,
//! missing, duplicate or unknown key, a non-finite or out-of-range number), one
//! saved in the future, one older than `daemon.state_max_age_s` or one whose age
//! cannot be known gives an error naming the file and the reason, and the daemon
//! starts cold. A good one is handed to `Estimator::restore` with its age.
//!
//! The age of a file saved during this boot is the monotonic clock's (the file
//! carries the boot id and the `CLOCK_MONOTONIC` time at which the service thread got
//! its estimate, [`Saver::offer`]: not the later time of the save, which waits up to
//! [`REFRESH_PERIOD`] or comes at the stop, and would make the estimate look younger
//! than it is, its drift extrapolated over too short a time), whatever the wall clock
//! did meanwhile; `saved_unix_ns` is the wall clock's at that same moment. Another boot's file is dated by the wall clock only where that
//! clock is synchronized or kept by a real-time clock ([`Clocks::wall_trusted`]);
//! elsewhere (a Raspberry Pi before NTP has synced: it boots at `fake-hwclock`'s
//! last saved time, so a file saved at the last shutdown looks seconds old after a
//! night off) its age is unknown and it is not restored: restored as seconds old,
//! its offset would have been extrapolated over seconds instead of hours, with a
//! standard deviation grown as little.
//!
//! The file names the `services.prefix` of the daemon that saved it. A daemon on
//! another prefix (a second robot's daemon started with `--prefix` and the same
//! configuration file) neither restores it (another robot's offset) nor saves over
//! it: it says so and runs without persistence ([`startup`]). A version-1 file,
//! from before the prefix was written, is read as any prefix's; a version-2 file,
//! from before the boot was written, as another boot's.
//!
//! # Format (version 3)
//!
//! ```text
//! vlsync-state 3
//! # saved 2026-11-23T13:53:12Z by vlsyncd; written atomically, do not edit
//! prefix = vlsync/robot
//! boot_id = 2269c875-ef3a-433a-afa6-076765882294
//! saved_mono_ns = 1234567890123
//! saved_unix_ns = 1795442000000000000
//! t_ref_ns = 120000000000
//! offset_s = 0.0123
//! drift = 1.5e-5
//! offset_std_s = 0.0008
//! drift_std = 2e-6
//! state = tracking
//! polarity = negative
//! checksum = fnv1a64:0123456789abcdef
//! ```
//!
//! The checksum is FNV-1a (64 bit) over every byte before the `checksum` line.
//! Numbers are written in Rust's shortest round-trip form, so a load returns
//! exactly what was saved.

use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use vlsync_common::text::clip;
use vlsync_common::{Estimate, EstimatorState, Nanos, Polarity};

/// First word of the file.
pub const MAGIC: &str = "vlsync-state";
/// Format version written (versions 1, without `prefix`, and 2, without the boot, are
/// read too).
pub const VERSION: u32 = 3;
/// A state file is a few hundred bytes; anything larger than this is not one.
pub const MAX_FILE_BYTES: u64 = 16 * 1024;
/// Minimum time between two saves.
pub const SAVE_PERIOD: Duration = Duration::from_secs(5);
/// An estimate whose offset is within this (seconds), or within [`UNCHANGED_SIGMAS`]
/// of the smaller standard deviation, of what the last saved one predicts for it,
/// with the same polarity, a drift within the smaller drift deviation of the saved
/// one and a standard deviation not below [`SHRUNK_STD`] of the saved one, is not
/// saved again before [`REFRESH_PERIOD`]: a restart from the saved one would start
/// within its uncertainty of it (see `unchanged`).
pub const UNCHANGED_S: f64 = 1e-4;
/// See [`UNCHANGED_S`].
pub const UNCHANGED_SIGMAS: f64 = 1.0;
/// A standard deviation below this share of the saved one is news worth saving soon.
pub const SHRUNK_STD: f64 = 0.8;
/// The longest time between two saves while a good estimate keeps arriving.
pub const REFRESH_PERIOD: Duration = Duration::from_secs(60);
/// A holding estimate is saved only while its standard deviation is at most this, seconds.
pub const HOLD_SAVE_MAX_STD_S: f64 = 0.01;
/// A file saved further in the future than this (the wall clock moved back, or a
/// board without a real-time clock booted with an old time) is not trusted, seconds.
pub const FUTURE_TOLERANCE_S: f64 = 60.0;
// the largest accepted |offset|: the estimator's own bound (the range of
// `estimator.lag_center_s`), which `Estimator::restore` checks too
use vlsync_common::MAX_ABS_OFFSET_S;
/// Largest accepted |drift| (the estimator clamps to ±0.1 anyway).
pub const MAX_ABS_DRIFT: f64 = 0.1;
/// Largest accepted offset standard deviation, seconds.
pub const MAX_OFFSET_STD_S: f64 = 10.0;
/// Largest accepted drift standard deviation.
pub const MAX_DRIFT_STD: f64 = 1.0;

const KEYS: [&str; 11] = [
    "saved_unix_ns",
    "t_ref_ns",
    "offset_s",
    "drift",
    "offset_std_s",
    "drift_std",
    "state",
    "polarity",
    "prefix",
    "boot_id",
    "saved_mono_ns",
];

/// Slot of `prefix` in `KEYS`: required from version 2 on.
const PREFIX_SLOT: usize = 8;
/// Slots of `boot_id` and `saved_mono_ns`: version 3, both or neither.
const BOOT_SLOTS: [usize; 2] = [9, 10];

/// The boot a file was saved in and the `CLOCK_MONOTONIC` time of the save: within
/// one boot the age of a file is the monotonic clock's difference, whatever the wall
/// clock did meanwhile (NTP stepping it after a boot from `fake-hwclock`'s time).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BootStamp {
    /// The kernel's boot id (`/proc/sys/kernel/random/boot_id`).
    pub id: String,
    /// `CLOCK_MONOTONIC` when the daemon got the saved estimate, ns (it stops while a
    /// machine is suspended, so one that suspends would date its file younger by that
    /// time; a robot does not).
    pub mono_ns: i64,
}

impl BootStamp {
    /// This boot, now (`None` where the kernel gives no boot id).
    pub fn current() -> Option<Self> {
        let text = std::fs::read_to_string("/proc/sys/kernel/random/boot_id").ok()?;
        let id = text.trim();
        boot_id_is_valid(id).then(|| Self {
            id: id.to_string(),
            mono_ns: vlsync_ipc::monotonic_ns(),
        })
    }
}

/// A boot id as the kernel writes it: a UUID's hex digits and dashes.
fn boot_id_is_valid(id: &str) -> bool {
    (1..=64).contains(&id.len()) && id.bytes().all(|b| b.is_ascii_hexdigit() || b == b'-')
}

/// What the daemon knows of "now" when it loads a file ([`load_at`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Clocks {
    /// The wall clock, ns since the Unix epoch.
    pub unix_ns: i64,
    /// This boot and the monotonic clock now.
    pub boot: Option<BootStamp>,
    /// Whether the wall clock can date a file saved during another boot: it is
    /// synchronized (the kernel's clock status,
    /// [`vlsync_ipc::rt::wall_clock_synchronized`], which chrony, ntpd and
    /// systemd-timesyncd set; or `/run/systemd/timesync/synchronized`, which
    /// systemd-timesyncd writes at its first sync), or the kernel set it from a
    /// real-time clock at boot (`/sys/class/rtc/rtc0/hctosys` is 1; a battery-less
    /// RTC that lost its time is not used so). A Raspberry Pi has neither until NTP
    /// syncs: it boots at `fake-hwclock`'s last saved time, so a file saved at the
    /// last shutdown looks seconds old after a night off.
    pub wall_trusted: bool,
}

impl Clocks {
    /// This machine's, now.
    pub fn now() -> Self {
        Self {
            unix_ns: unix_now_ns(),
            boot: BootStamp::current(),
            wall_trusted: vlsync_ipc::rt::wall_clock_synchronized()
                || Path::new("/run/systemd/timesync/synchronized").exists()
                || std::fs::read_to_string("/sys/class/rtc/rtc0/hctosys")
                    .is_ok_and(|t| t.trim() == "1"),
        }
    }
}

/// A saved estimate and when it was saved.
#[derive(Debug, Clone, PartialEq)]
pub struct SavedState {
    /// `services.prefix` of the daemon that saved it (`None`: a version-1 file).
    pub prefix: Option<String>,
    /// Wall-clock time of the saved estimate (when the daemon got it), ns since the
    /// Unix epoch.
    pub saved_unix_ns: i64,
    /// The boot it was saved in (`None`: a file of version 1 or 2, or a kernel
    /// without a boot id).
    pub boot: Option<BootStamp>,
    /// The estimate (`seq`, peak fields and the measurement are not saved: 0, 0,
    /// 0 and NaN after a load).
    pub estimate: Estimate,
}

/// Why a state file was not used.
#[derive(Debug, Clone, PartialEq)]
pub enum Problem {
    /// Reading failed.
    Io(String),
    /// A directory, FIFO, device, ...
    NotAFile,
    /// Larger than [`MAX_FILE_BYTES`].
    TooLarge,
    /// Not UTF-8 text.
    NotText,
    /// The first line is not `vlsync-state <version>`.
    BadHeader(String),
    /// A version this daemon does not read.
    WrongVersion(String),
    /// The `checksum` line is missing or not the last line: the file is cut short.
    Truncated,
    /// The checksum line is malformed.
    BadChecksumLine {
        /// 1-based line number.
        line: usize,
    },
    /// The checksum does not match the contents.
    ChecksumMismatch {
        /// Stored.
        stored: u64,
        /// Computed over the contents.
        computed: u64,
    },
    /// A line that is not `key = value`.
    BadLine {
        /// 1-based line number.
        line: usize,
    },
    /// A key this version does not know.
    UnknownKey {
        /// 1-based line number.
        line: usize,
        /// The key.
        key: String,
    },
    /// A key given twice.
    DuplicateKey {
        /// 1-based line number of the second one.
        line: usize,
        /// The key.
        key: &'static str,
    },
    /// A required key is absent.
    MissingKey(&'static str),
    /// A value that does not parse.
    BadValue {
        /// 1-based line number.
        line: usize,
        /// The key.
        key: &'static str,
        /// The value as written (shortened).
        value: String,
    },
    /// NaN or infinite.
    NonFinite {
        /// The key.
        key: &'static str,
    },
    /// Outside the plausible range.
    OutOfRange {
        /// The key.
        key: &'static str,
        /// The value.
        value: f64,
        /// The allowed range, as text.
        allowed: &'static str,
    },
    /// Older than `daemon.state_max_age_s`.
    Stale {
        /// Age, seconds.
        age_s: f64,
        /// The limit, seconds.
        max_age_s: f64,
    },
    /// Saved after "now".
    InTheFuture {
        /// How far ahead, seconds.
        ahead_s: f64,
    },
    /// Saved during another boot, and the wall clock cannot tell when
    /// ([`Clocks::wall_trusted`]).
    AgeUnknown,
    /// Saved in this boot at a monotonic time still to come: a corrupt or forged
    /// `saved_mono_ns`.
    MonotonicAhead {
        /// How far ahead, seconds.
        ahead_s: f64,
    },
    /// Saved by the daemon of another `services.prefix`.
    OtherPrefix {
        /// The file's prefix (clipped).
        saved: String,
        /// This daemon's.
        ours: String,
    },
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Problem::Io(e) => write!(f, "cannot read: {e}"),
            Problem::NotAFile => write!(f, "not a regular file"),
            Problem::TooLarge => write!(f, "larger than {MAX_FILE_BYTES} bytes: not a state file"),
            Problem::NotText => write!(f, "not UTF-8 text: corrupt"),
            Problem::BadHeader(h) => write!(
                f,
                "line 1: expected `{MAGIC} {VERSION}`, found {:?}: not a vlsync state file",
                h
            ),
            Problem::WrongVersion(v) => write!(
                f,
                "line 1: format version {v:?}, this vlsyncd reads versions 1 to {VERSION}"
            ),
            Problem::Truncated => write!(
                f,
                "no `checksum` line at the end: truncated (interrupted write?)"
            ),
            Problem::BadChecksumLine { line } => write!(
                f,
                "line {line}: malformed checksum (expected `checksum = fnv1a64:<16 hex digits>`)"
            ),
            Problem::ChecksumMismatch { stored, computed } => write!(
                f,
                "checksum mismatch (stored {stored:016x}, contents give {computed:016x}): corrupt"
            ),
            Problem::BadLine { line } => write!(f, "line {line}: not `key = value`"),
            Problem::UnknownKey { line, key } => write!(f, "line {line}: unknown key {key:?}"),
            Problem::DuplicateKey { line, key } => {
                write!(f, "line {line}: key `{key}` given twice")
            }
            Problem::MissingKey(k) => write!(f, "key `{k}` missing"),
            Problem::BadValue { line, key, value } => {
                write!(f, "line {line}: `{key}` = {value:?} is not a valid value")
            }
            Problem::NonFinite { key } => write!(f, "`{key}` is not a finite number"),
            Problem::OutOfRange {
                key,
                value,
                allowed,
            } => write!(f, "`{key}` = {value} is out of range: allowed {allowed}"),
            Problem::Stale { age_s, max_age_s } => write!(
                f,
                "saved {age_s:.0} s ago, older than daemon.state_max_age_s = {max_age_s} s: stale"
            ),
            Problem::InTheFuture { ahead_s } => write!(
                f,
                "saved {ahead_s:.0} s in the future: the wall clock moved back, age unknown"
            ),
            Problem::MonotonicAhead { ahead_s } => write!(
                f,
                "`saved_mono_ns` is {ahead_s:.0} s after this boot's monotonic clock: corrupt"
            ),
            Problem::AgeUnknown => write!(
                f,
                "saved during another boot, and this machine's wall clock may be wrong (neither \
                 synchronized by a time daemon, the kernel's clock status as timedatectl \
                 shows it, nor set from a real-time clock at boot, \
                 /sys/class/rtc/rtc0/hctosys): its age is unknown"
            ),
            Problem::OtherPrefix { saved, ours } => write!(
                f,
                "saved by the daemon of prefix `{saved}`, not of `{ours}`: another robot's \
                 estimate (give each daemon its own daemon.state_file)"
            ),
        }
    }
}

/// A problem with a named state file.
#[derive(Debug, Clone, PartialEq)]
pub struct StateError {
    /// The file.
    pub path: PathBuf,
    /// What was wrong.
    pub problem: Problem,
}

impl fmt::Display for StateError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "state file {}: {}", self.path.display(), self.problem)
    }
}

impl std::error::Error for StateError {}

/// FNV-1a, 64 bit.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Now on the wall clock, ns since the Unix epoch (0 if the clock is before 1970).
pub fn unix_now_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

/// True for an estimate worth saving: tracking, or holding with a standard
/// deviation of at most [`HOLD_SAVE_MAX_STD_S`]; all numbers finite.
pub fn worth_saving(e: &Estimate) -> bool {
    let finite = e.offset_s.is_finite()
        && e.drift.is_finite()
        && e.offset_std_s.is_finite()
        && e.drift_std.is_finite();
    finite
        && match e.state {
            EstimatorState::Tracking => true,
            EstimatorState::Holding => e.offset_std_s <= HOLD_SAVE_MAX_STD_S,
            EstimatorState::Acquiring | EstimatorState::Lost => false,
        }
}

/// The file's text.
pub fn encode(s: &SavedState) -> String {
    let e = &s.estimate;
    let mut body = format!(
        "{MAGIC} {}\n# saved {} by vlsyncd; written atomically, do not edit\n",
        if s.prefix.is_some() { VERSION } else { 1 },
        utc_text(s.saved_unix_ns)
    );
    if let Some(p) = &s.prefix {
        body.push_str(&format!("prefix = {p}\n"));
        if let Some(b) = &s.boot {
            body.push_str(&format!(
                "boot_id = {}\nsaved_mono_ns = {}\n",
                b.id, b.mono_ns
            ));
        }
    }
    body.push_str(&format!(
        "saved_unix_ns = {}\nt_ref_ns = {}\noffset_s = {:?}\ndrift = {:?}\noffset_std_s = {:?}\ndrift_std = {:?}\nstate = {}\npolarity = {}\n",
        s.saved_unix_ns,
        e.t_ref_ns,
        e.offset_s,
        e.drift,
        e.offset_std_s,
        e.drift_std,
        e.state.name(),
        e.polarity.name(),
    ));
    let sum = fnv1a64(body.as_bytes());
    body.push_str(&format!("checksum = fnv1a64:{sum:016x}\n"));
    body
}

/// Parses a state file's bytes (no staleness check).
pub fn decode(bytes: &[u8]) -> Result<SavedState, Problem> {
    let text = std::str::from_utf8(bytes).map_err(|_| Problem::NotText)?;
    // header
    let first = text.split('\n').next().unwrap_or("");
    let mut words = first.split_whitespace();
    if words.next() != Some(MAGIC) {
        return Err(Problem::BadHeader(clip(first)));
    }
    let version = match (words.next(), words.next()) {
        (Some("1"), None) => 1,
        (Some("2"), None) => 2,
        (Some(v), None) if v == VERSION.to_string() => VERSION,
        (Some(v), None) => return Err(Problem::WrongVersion(clip(v))),
        _ => return Err(Problem::BadHeader(clip(first))),
    };
    // the checksum line is the last line and ends with a newline
    let Some(body_and_sum) = text.strip_suffix('\n') else {
        return Err(Problem::Truncated);
    };
    let (body_len, sum_line) = match body_and_sum.rfind('\n') {
        Some(i) => (i + 1, &body_and_sum[i + 1..]),
        None => return Err(Problem::Truncated),
    };
    let body = &text[..body_len];
    let sum_lineno = body.matches('\n').count() + 1;
    let Some(stored) = sum_line.trim().strip_prefix("checksum") else {
        return Err(Problem::Truncated);
    };
    let stored = stored
        .trim_start()
        .strip_prefix('=')
        .map(str::trim)
        .and_then(|v| v.strip_prefix("fnv1a64:"))
        .filter(|h| h.len() == 16)
        .and_then(|h| u64::from_str_radix(h, 16).ok())
        .ok_or(Problem::BadChecksumLine { line: sum_lineno })?;
    let computed = fnv1a64(body.as_bytes());
    if stored != computed {
        return Err(Problem::ChecksumMismatch { stored, computed });
    }
    // key = value lines
    let mut values: [Option<(usize, &str)>; KEYS.len()] = [None; KEYS.len()];
    for (i, line) in body.lines().enumerate().skip(1) {
        let lineno = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let Some((k, v)) = line.split_once('=') else {
            return Err(Problem::BadLine { line: lineno });
        };
        let k = k.trim();
        // the boot's keys came with version 3
        let Some(slot) = KEYS
            .iter()
            .position(|key| *key == k)
            .filter(|slot| version >= 3 || !BOOT_SLOTS.contains(slot))
        else {
            return Err(Problem::UnknownKey {
                line: lineno,
                key: clip(k),
            });
        };
        if values[slot].is_some() {
            return Err(Problem::DuplicateKey {
                line: lineno,
                key: KEYS[slot],
            });
        }
        values[slot] = Some((lineno, v.trim()));
    }
    let get = |slot: usize| values[slot].ok_or(Problem::MissingKey(KEYS[slot]));
    let int = |slot: usize| -> Result<i64, Problem> {
        let (line, v) = get(slot)?;
        v.parse::<i64>().map_err(|_| Problem::BadValue {
            line,
            key: KEYS[slot],
            value: clip(v),
        })
    };
    let float = |slot: usize, max_abs: f64, allowed: &'static str, non_negative: bool| {
        let (line, v) = get(slot)?;
        let x = v.parse::<f64>().map_err(|_| Problem::BadValue {
            line,
            key: KEYS[slot],
            value: clip(v),
        })?;
        if !x.is_finite() {
            return Err(Problem::NonFinite { key: KEYS[slot] });
        }
        if x.abs() > max_abs || (non_negative && x < 0.0) {
            return Err(Problem::OutOfRange {
                key: KEYS[slot],
                value: x,
                allowed,
            });
        }
        Ok(x)
    };
    let saved_unix_ns = int(0)?;
    let t_ref_ns: Nanos = int(1)?;
    let offset_s = float(2, MAX_ABS_OFFSET_S, "-1e6 ..= 1e6 s", false)?;
    let drift = float(3, MAX_ABS_DRIFT, "-0.1 ..= 0.1", false)?;
    let offset_std_s = float(4, MAX_OFFSET_STD_S, "0 ..= 10 s", true)?;
    let drift_std = float(5, MAX_DRIFT_STD, "0 ..= 1", true)?;
    let (line, v) = get(6)?;
    let state = match v {
        "tracking" => EstimatorState::Tracking,
        "holding" => EstimatorState::Holding,
        _ => {
            return Err(Problem::BadValue {
                line,
                key: KEYS[6],
                value: clip(v),
            })
        }
    };
    let (line, v) = get(7)?;
    let polarity = match v {
        "positive" => Polarity::Positive,
        "negative" => Polarity::Negative,
        "unknown" => Polarity::Unknown,
        _ => {
            return Err(Problem::BadValue {
                line,
                key: KEYS[7],
                value: clip(v),
            })
        }
    };
    // a prefix is one a daemon accepts (`services.prefix`'s rule)
    let prefix = match values[PREFIX_SLOT] {
        None if version == 1 => None,
        None => return Err(Problem::MissingKey(KEYS[PREFIX_SLOT])),
        Some((line, v)) => {
            if !vlsync_config::prefix_is_valid(v) {
                return Err(Problem::BadValue {
                    line,
                    key: KEYS[PREFIX_SLOT],
                    value: clip(v),
                });
            }
            Some(v.to_string())
        }
    };
    let boot = match BOOT_SLOTS.map(|slot| values[slot]) {
        [None, None] => None,
        [None, Some(_)] => return Err(Problem::MissingKey(KEYS[BOOT_SLOTS[0]])),
        [Some(_), None] => return Err(Problem::MissingKey(KEYS[BOOT_SLOTS[1]])),
        [Some((line, id)), Some(_)] => {
            if !boot_id_is_valid(id) {
                return Err(Problem::BadValue {
                    line,
                    key: KEYS[BOOT_SLOTS[0]],
                    value: clip(id),
                });
            }
            Some(BootStamp {
                id: id.to_string(),
                mono_ns: int(BOOT_SLOTS[1])?,
            })
        }
    };
    Ok(SavedState {
        prefix,
        saved_unix_ns,
        boot,
        estimate: Estimate {
            seq: 0,
            t_ref_ns,
            offset_s,
            drift,
            offset_std_s,
            drift_std,
            state,
            polarity,
            peak_score: 0.0,
            peak_ratio: 0.0,
            measured_offset_s: f64::NAN,
        },
    })
}

/// [`load_at`] with the wall clock at `now_unix_ns` trusted, and no boot to compare
/// (the age of every file from the wall clock).
pub fn load(
    path: &Path,
    prefix: &str,
    now_unix_ns: i64,
    max_age_s: f64,
) -> Result<Option<(SavedState, f64)>, StateError> {
    let clocks = Clocks {
        unix_ns: now_unix_ns,
        boot: None,
        wall_trusted: true,
    };
    load_at(path, prefix, &clocks, max_age_s)
}

/// Loads `path` for the daemon of `prefix` and checks its age against `max_age_s`.
/// The age: from the monotonic clock for a file saved during this boot; from the
/// wall clock for another boot's, where the wall clock can be trusted
/// ([`Clocks::wall_trusted`]), else [`Problem::AgeUnknown`]. `Ok(None)`: no file (a
/// first start). `Ok(Some((state, age_s)))`: usable. A file of another prefix is
/// [`Problem::OtherPrefix`], whatever its age.
pub fn load_at(
    path: &Path,
    prefix: &str,
    clocks: &Clocks,
    max_age_s: f64,
) -> Result<Option<(SavedState, f64)>, StateError> {
    let err = |problem| StateError {
        path: path.to_path_buf(),
        problem,
    };
    // a FIFO would block the open: only regular files (following a symlink) are read,
    // and no more of one than a state file can hold
    use std::io::ErrorKind;
    let bytes = match vlsync_common::file::read_regular_at_most(path, MAX_FILE_BYTES) {
        Ok(b) => b,
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(None),
        Err(e) if e.kind() == ErrorKind::InvalidInput => return Err(err(Problem::NotAFile)),
        Err(e) if e.kind() == ErrorKind::InvalidData => return Err(err(Problem::TooLarge)),
        Err(e) => return Err(err(Problem::Io(e.to_string()))),
    };
    let s = decode(&bytes).map_err(err)?;
    if let Some(saved) = s.prefix.as_deref().filter(|p| *p != prefix) {
        return Err(err(Problem::OtherPrefix {
            saved: clip(saved),
            ours: clip(prefix),
        }));
    }
    let same_boot = match (&s.boot, &clocks.boot) {
        (Some(saved), Some(now)) if saved.id == now.id => {
            Some(now.mono_ns as f64 - saved.mono_ns as f64)
        }
        _ => None,
    };
    let age_s = if let Some(d) = same_boot {
        // the monotonic clock does not go back within a boot
        if d < 0.0 {
            return Err(err(Problem::MonotonicAhead { ahead_s: -d * 1e-9 }));
        }
        d * 1e-9
    } else if clocks.wall_trusted {
        let age_s = (clocks.unix_ns as f64 - s.saved_unix_ns as f64) * 1e-9;
        if age_s < -FUTURE_TOLERANCE_S {
            return Err(err(Problem::InTheFuture { ahead_s: -age_s }));
        }
        age_s
    } else {
        return Err(err(Problem::AgeUnknown));
    };
    if age_s > max_age_s {
        return Err(err(Problem::Stale { age_s, max_age_s }));
    }
    Ok(Some((s, age_s.max(0.0))))
}

/// The temporary file a save of this process writes before renaming it over `path`:
/// `<name>.tmp-<pid>`, its own, so that two daemons misconfigured to share a file
/// never rename each other's half-written one.
pub fn temp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp-{}", std::process::id()));
    path.with_file_name(name)
}

/// Removes what saves of processes no longer running left beside `path` (a crash
/// between writing the temporary file and renaming it): `<name>.tmp` of earlier
/// versions, `<name>.tmp-<pid>` of a pid without a process. Returns how many.
pub fn remove_stale_temps(path: &Path) -> usize {
    let (Some(name), Some(dir)) = (
        path.file_name().and_then(|n| n.to_str()),
        Some(vlsync_common::file::dir_of(path)),
    ) else {
        return 0;
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let f = e.file_name();
        let Some(rest) = f.to_str().and_then(|f| f.strip_prefix(name)) else {
            continue;
        };
        let stale = match rest.strip_prefix(".tmp") {
            Some("") => true,
            Some(pid) => pid
                .strip_prefix('-')
                .filter(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()))
                .is_some_and(|p| !Path::new("/proc").join(p).exists()),
            None => false,
        };
        // only this user's regular files: another user's daemon, alive but hidden
        // from this one's /proc (hidepid, another pid namespace), keeps its own
        let mine = || {
            use std::os::unix::fs::MetadataExt;
            e.metadata().is_ok_and(|m| {
                m.file_type().is_file() && m.uid() == rustix::process::geteuid().as_raw()
            })
        };
        if stale && mine() && std::fs::remove_file(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Why a save to `path` cannot work on this machine as it is now, checked without
/// writing anything: not a file name, or a directory that is missing or not a
/// directory. `None` when nothing is known to be wrong (permissions show only when a
/// save is tried: the daemon may run as another user than whoever checks).
pub fn directory_problem(path: &Path) -> Option<String> {
    if path.file_name().is_none() {
        return Some(format!("state file {}: not a file name", path.display()));
    }
    if path.as_os_str().as_encoded_bytes().contains(&0) {
        return Some(format!(
            "state file {:?}: contains a NUL byte, which no file name can",
            path
        ));
    }
    if path.is_dir() {
        return Some(format!("state file {}: is a directory", path.display()));
    }
    let dir = vlsync_common::file::dir_of(path);
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => None,
        Ok(_) => Some(format!(
            "state file {}: {} is not a directory",
            path.display(),
            dir.display()
        )),
        Err(e) => Some(format!(
            "state file {}: directory {}: {e}",
            path.display(),
            dir.display()
        )),
    }
}

/// Saves `s` to `path` atomically (temp file, fsync, rename, fsync of the directory).
pub fn save(path: &Path, s: &SavedState) -> Result<(), String> {
    let dir = vlsync_common::file::dir_of(path);
    if path.file_name().is_none() {
        return Err(format!("state file {}: not a file name", path.display()));
    }
    // the file of another prefix's daemon (two sharing `state_file`, both started
    // before either saved) is not saved over: checked at every save, not only at
    // the start
    if let Ok(bytes) = vlsync_common::file::read_regular_at_most(path, MAX_FILE_BYTES) {
        if let Ok(SavedState {
            prefix: Some(theirs),
            ..
        }) = decode(&bytes)
        {
            if s.prefix.as_deref().is_some_and(|ours| ours != theirs) {
                return Err(format!(
                    "state file {}: now holds the state of prefix `{theirs}`, not saved over (is `daemon.state_file` shared by two daemons?)",
                    path.display()
                ));
            }
        }
    }
    let tmp = temp_path(path);
    let text = encode(s);
    let write = || -> std::io::Result<()> {
        // a symlink planted at the predictable name is refused (ELOOP), not followed:
        // `truncate` would have emptied its target (as root, with a state file in a
        // directory others may write), as the instance lock's open refuses one too
        use std::os::unix::fs::OpenOptionsExt;
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .custom_flags(vlsync_ipc::O_NOFOLLOW)
            .open(&tmp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()
    };
    write().map_err(|e| {
        // a part written (a full /run) is not left behind
        let _ = std::fs::remove_file(&tmp);
        format!("cannot write state file {}: {e}", tmp.display())
    })?;
    if let Err(e) = std::fs::rename(&tmp, path) {
        let _ = std::fs::remove_file(&tmp);
        return Err(format!(
            "cannot rename {} to {}: {e}",
            tmp.display(),
            path.display()
        ));
    }
    std::fs::File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| {
            format!(
                "cannot sync directory {} of the state file: {e}",
                dir.display()
            )
        })
}

/// `2026-11-23T13:53:12Z` for ns since the Unix epoch.
pub fn utc_text(unix_ns: i64) -> String {
    let secs = unix_ns.div_euclid(1_000_000_000);
    let days = secs.div_euclid(86_400);
    let tod = secs.rem_euclid(86_400);
    // civil date from days since 1970-01-01 (H. Hinnant's algorithm)
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        tod / 3600,
        tod / 60 % 60,
        tod % 60
    )
}

/// Reads the state file of the configuration at start-up for the daemon of `prefix`
/// and logs the outcome: the estimate to restore with its age (`None`: a cold
/// start), and the saver (`None`: persistence off, or the file is another prefix's,
/// which this daemon must not overwrite).
pub fn startup(
    cfg: &vlsync_config::DaemonConfig,
    prefix: &str,
) -> (Option<(Estimate, f64)>, Option<Saver>) {
    if cfg.state_file.is_empty() {
        return (None, None);
    }
    let path = Path::new(&cfg.state_file);
    let stale = remove_stale_temps(path);
    if stale > 0 {
        tracing::info!(
            "state file {}: removed {stale} temporary file(s) a save left when its process ended",
            path.display()
        );
    }
    if let Some(problem) = directory_problem(path) {
        // said now rather than at the first save, minutes after the lock
        tracing::warn!("{problem}; estimates are not saved until it is fixed (each save retries)");
    }
    let saver = Some(Saver::new(
        PathBuf::from(&cfg.state_file),
        prefix,
        SAVE_PERIOD,
    ));
    match load_at(path, prefix, &Clocks::now(), cfg.state_max_age_s) {
        Ok(Some((s, age_s))) => {
            tracing::info!(
                "state file {}: restoring offset {:+.3} ms ± {:.3} ms (drift {:+.2} ppm, {}) saved {age_s:.0} s ago",
                path.display(),
                s.estimate.offset_s * 1e3,
                s.estimate.offset_std_s * 1e3,
                s.estimate.drift * 1e6,
                s.estimate.state
            );
            (Some((s.estimate, age_s)), saver)
        }
        Ok(None) => {
            tracing::info!("state file {}: none yet; cold start", path.display());
            (None, saver)
        }
        Err(e) if matches!(e.problem, Problem::OtherPrefix { .. }) => {
            tracing::warn!("{e}; cold start, and estimates are not saved there");
            (None, None)
        }
        Err(e) => {
            tracing::warn!("{e}; ignoring it, cold start");
            (None, saver)
        }
    }
}

/// Whether `new` tells a restart nothing `saved` does not. A restore starts from
/// `saved`: its offset moved on by its drift, with its standard deviations (grown
/// for the time since). So `new` is no news when it has the same polarity, its
/// offset is within [`UNCHANGED_S`], or [`UNCHANGED_SIGMAS`] of the smaller of the
/// two standard deviations, of that prediction (a step stays news while the new σ
/// is inflated by it), its drift within the smaller of the two drift deviations of
/// the saved drift (a restore after an hour extrapolates it over the hour), and its
/// standard deviation not below [`SHRUNK_STD`] of the saved one. The state does not
/// count: a restore starts in `holding` either way.
fn unchanged(saved: &Estimate, new: &Estimate) -> bool {
    let dt_s = new.t_ref_ns.saturating_sub(saved.t_ref_ns) as f64 * 1e-9;
    let predicted = saved.offset_s + saved.drift * dt_s;
    let tolerance = UNCHANGED_S.max(UNCHANGED_SIGMAS * saved.offset_std_s.min(new.offset_std_s));
    saved.polarity == new.polarity
        && (new.offset_s - predicted).abs() <= tolerance
        && (new.drift - saved.drift).abs() <= saved.drift_std.min(new.drift_std)
        && new.offset_std_s >= SHRUNK_STD * saved.offset_std_s
}

/// A save that takes longer than this is logged: the storage stalls (an SD card
/// collecting garbage under a recording's writes can hold an fsync for seconds).
pub const SLOW_SAVE: Duration = Duration::from_secs(1);

/// How long the daemon's stop waits for its last save.
pub const FINAL_SAVE_WAIT: Duration = Duration::from_secs(3);

/// Where a [`Saver`]'s files are written: on the caller's thread, or on a thread of
/// their own (the daemon's), so that storage that stalls cannot stop the service
/// thread (its status, its watchdog pings, its reaction to SIGTERM).
#[derive(Debug)]
enum Writer {
    Inline { last_error: Option<String> },
    Thread(SaveThread),
}

/// What became of a save offered to the [`SaveThread`].
enum Offer {
    Taken,
    /// The previous save is still being written.
    Busy,
    /// The thread has ended (a panic): the save comes back.
    Gone(Box<SavedState>),
}

/// The thread that writes the state file: one save at a time, handed over through a
/// one-slot channel; it logs what fails (once until a save succeeds again) and
/// what is slow, and sends each save's outcome back (the estimate saved, or `None`).
#[derive(Debug)]
struct SaveThread {
    jobs: Option<crossbeam::channel::Sender<SavedState>>,
    done: crossbeam::channel::Receiver<Option<Estimate>>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl SaveThread {
    fn spawn(path: PathBuf) -> std::io::Result<Self> {
        let (tx, rx) = crossbeam::channel::bounded::<SavedState>(1);
        // at most two saves are in flight (one written, one waiting): never full
        let (done_tx, done) = crossbeam::channel::bounded(4);
        let handle = std::thread::Builder::new()
            .name("vlsync-state".into())
            .spawn(move || {
                let mut last_error = None;
                for s in rx {
                    let t0 = Instant::now();
                    let r = save(&path, &s);
                    let took = t0.elapsed();
                    if took > SLOW_SAVE {
                        tracing::warn!(
                            "state file {}: a save took {:.1} s (the storage stalls)",
                            path.display(),
                            took.as_secs_f64()
                        );
                    }
                    let ok = report(&path, r, &mut last_error);
                    let _ = done_tx.try_send(ok.then_some(s.estimate));
                }
            })?;
        Ok(Self {
            jobs: Some(tx),
            done,
            handle: Some(handle),
        })
    }

    /// Hands `s` over.
    fn offer(&self, s: SavedState) -> Offer {
        use crossbeam::channel::TrySendError;
        let Some(jobs) = &self.jobs else {
            return Offer::Busy;
        };
        match jobs.try_send(s) {
            Ok(()) => Offer::Taken,
            Err(TrySendError::Full(_)) => Offer::Busy,
            Err(TrySendError::Disconnected(s)) => Offer::Gone(Box::new(s)),
        }
    }

    /// The outcomes of the saves finished since the last call, oldest first.
    fn outcomes(&self) -> impl Iterator<Item = Option<Estimate>> + '_ {
        self.done.try_iter()
    }

    /// Hands `s` over (waiting up to `wait` for the previous save), then waits up to
    /// what is left of `wait` for the thread to end. `Ok(None)` when it did not in
    /// time (the storage stalls); else whether `s` was written (false with no `s`, or
    /// a save that failed, which the thread has logged with its reason). `Err(s)`:
    /// the thread had ended (a panic) and `s` is the caller's to write.
    fn finish(
        &mut self,
        s: Option<SavedState>,
        wait: Duration,
    ) -> Result<Option<bool>, Box<SavedState>> {
        use crossbeam::channel::SendTimeoutError;
        let deadline = Instant::now() + wait;
        let handed = match (s, self.jobs.take()) {
            (Some(s), Some(jobs)) => match jobs.send_timeout(s, wait) {
                Ok(()) => true,
                Err(SendTimeoutError::Disconnected(s)) => return Err(Box::new(s)),
                Err(SendTimeoutError::Timeout(_)) => false,
            },
            _ => false,
        };
        let Some(h) = self.handle.take() else {
            return Ok(None);
        };
        while !h.is_finished() {
            if Instant::now() >= deadline {
                // left behind: the process ends without it
                return Ok(None);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        // the last outcome is the handed estimate's (it was the last job)
        let last = self.done.try_iter().last();
        Ok(Some(
            h.join().is_ok() && handed && last.is_some_and(|o| o.is_some()),
        ))
    }
}

/// Writes `s` to `path` on a thread of its own, waiting up to `wait` for it (the
/// stop's bound on its last save, which stalled storage must not stretch: systemd
/// kills a stop past `TimeoutStopSec`): `None` when it was not written in time (the
/// caller says so, as for the saving thread's own last save), else whether it was
/// written (not when no thread could be made, said).
fn last_save_within(path: &Path, s: SavedState, wait: Duration) -> Option<bool> {
    let (tx, rx) = crossbeam::channel::bounded(1);
    let owned = path.to_path_buf();
    let spawned = std::thread::Builder::new()
        .name("vlsync-state".into())
        .spawn(move || {
            let ok = report(&owned, save(&owned, &s), &mut None);
            let _ = tx.send(ok);
        });
    if let Err(e) = spawned {
        tracing::warn!(
            "state file {}: no thread for the last save ({e})",
            path.display()
        );
        return Some(false);
    }
    rx.recv_timeout(wait).ok()
}

/// Logs the outcome of a save: an error once until a save succeeds again.
fn report(path: &Path, r: Result<(), String>, last_error: &mut Option<String>) -> bool {
    match r {
        Ok(()) => {
            if last_error.take().is_some() {
                tracing::info!("state file {}: saving works again", path.display());
            }
            true
        }
        Err(msg) => {
            if last_error.as_deref() != Some(msg.as_str()) {
                tracing::warn!("{msg}; the last good estimate is not persisted");
                *last_error = Some(msg);
            }
            false
        }
    }
}

/// When the service thread got an estimate ([`Saver::offer`]): the file's
/// `saved_mono_ns` and `saved_unix_ns`, so a restart dates the estimate, not its save
/// (which waits up to [`REFRESH_PERIOD`], or comes at the stop).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Offered {
    /// `CLOCK_MONOTONIC`, ns.
    mono_ns: i64,
    /// The wall clock, ns since the Unix epoch.
    unix_ns: i64,
}

impl Offered {
    fn now() -> Self {
        Self {
            mono_ns: vlsync_ipc::monotonic_ns(),
            unix_ns: unix_now_ns(),
        }
    }
}

/// Saves the newest estimate worth saving at most every `period` (service thread).
#[derive(Debug)]
pub struct Saver {
    path: PathBuf,
    prefix: String,
    /// This boot's id (read once: it does not change while the process runs).
    boot_id: Option<String>,
    period: Duration,
    refresh: Duration,
    /// The estimate to save next, with the clocks when it was offered.
    pending: Option<(Estimate, Offered)>,
    last_save: Option<Instant>,
    last_saved: Option<Estimate>,
    writer: Writer,
}

impl Saver {
    /// A saver for `path` of the daemon of `prefix` (written into the file), at most
    /// one save per `period`; an unchanged estimate (see [`UNCHANGED_S`]) only every
    /// [`REFRESH_PERIOD`].
    pub fn new(path: PathBuf, prefix: &str, period: Duration) -> Self {
        Self {
            path,
            prefix: prefix.to_string(),
            boot_id: BootStamp::current().map(|b| b.id),
            period,
            refresh: REFRESH_PERIOD.max(period),
            pending: None,
            last_save: None,
            last_saved: None,
            writer: Writer::Inline { last_error: None },
        }
    }

    /// The same saver writing on a thread of its own (`SaveThread`): its
    /// [`Saver::tick`] and [`Saver::flush`] hand the estimate over and return at
    /// once. Stays inline, saying why, when no thread can be started.
    pub fn in_background(mut self) -> Self {
        match SaveThread::spawn(self.path.clone()) {
            Ok(t) => self.writer = Writer::Thread(t),
            Err(e) => tracing::warn!(
                "state file {}: no thread for saving ({e}); saving on the service thread",
                self.path.display()
            ),
        }
        self
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Offers an estimate; it is kept if [`worth_saving`], with the monotonic and wall
    /// clocks now: the file dates the estimate by them, however long it then waits for
    /// its save (a restore extrapolates it by its drift over that age).
    pub fn offer(&mut self, e: &Estimate) {
        self.offer_at(e, Offered::now());
    }

    /// [`Saver::offer`] with the clocks `at`.
    fn offer_at(&mut self, e: &Estimate, at: Offered) {
        if worth_saving(e) {
            self.pending = Some((*e, at));
        }
    }

    /// Saves the pending estimate if the period since the last save has passed
    /// (the refresh period if it tells nothing new: [`UNCHANGED_S`]). Returns whether it
    /// saved (in the background: handed it over); an error is logged once until a
    /// save succeeds.
    pub fn tick(&mut self, now: Instant) -> bool {
        if let Writer::Thread(t) = &self.writer {
            // what the thread saved is what a restart would find
            for saved in t.outcomes().flatten() {
                self.last_saved = Some(saved);
            }
        }
        let Some((p, _)) = self.pending else {
            return false;
        };
        let since = self.last_save.map(|t| now.saturating_duration_since(t));
        let wait = match &self.last_saved {
            Some(l) if unchanged(l, &p) => self.refresh,
            _ => self.period,
        };
        if since.is_none_or(|d| d >= wait) {
            let before = self.last_save.replace(now);
            let done = self.flush();
            if !done && self.pending.is_some() {
                // the thread still writes the previous save: again at the next tick
                self.last_save = before;
            }
            return done;
        }
        false
    }

    /// Saves the pending estimate now. Returns whether it saved (in the background:
    /// handed it over; while the previous save is still being written it stays
    /// pending, and [`Saver::tick`] tries again at its next call).
    pub fn flush(&mut self) -> bool {
        let Some((e, at)) = self.pending.take() else {
            return false;
        };
        let s = self.state_of(e, at);
        match &mut self.writer {
            Writer::Inline { last_error } => {
                let done = report(&self.path, save(&self.path, &s), last_error);
                if done {
                    self.last_saved = Some(e);
                }
                done
            }
            // `last_saved` follows the thread's outcomes (`tick`): a failed save is
            // retried a period later, as inline
            Writer::Thread(t) => match t.offer(s) {
                Offer::Taken => true,
                Offer::Busy => {
                    self.pending = Some((e, at));
                    false
                }
                // the thread is gone: said once, and saved here from now on
                Offer::Gone(s) => {
                    tracing::error!(
                        "state file {}: the saving thread has ended; saving on the service thread from now on",
                        self.path.display()
                    );
                    let mut last_error = None;
                    let done = report(&self.path, save(&self.path, &s), &mut last_error);
                    if done {
                        self.last_saved = Some(e);
                    }
                    self.writer = Writer::Inline { last_error };
                    done
                }
            },
        }
    }

    /// The daemon's stop: saves the pending estimate and, in the background, waits
    /// up to `wait` in all for it (and a save still being written) to be on disk.
    /// Returns whether the pending estimate was saved; false with nothing pending.
    pub fn finish(&mut self, wait: Duration) -> bool {
        let pending = self.pending.take();
        let s = pending.map(|(e, at)| self.state_of(e, at));
        match &mut self.writer {
            Writer::Inline { last_error } => {
                s.is_some_and(|s| report(&self.path, save(&self.path, &s), last_error))
            }
            Writer::Thread(t) => {
                let had = s.is_some();
                let done = match t.finish(s, wait) {
                    Ok(done) => done,
                    // the thread is gone (a panic after the last tick's hand-over):
                    // the last save is written here, as `flush` does
                    Err(s) => {
                        tracing::error!(
                            "state file {}: the saving thread has ended; the last save is written on a thread of its own",
                            self.path.display()
                        );
                        last_save_within(&self.path, *s, wait)
                    }
                };
                if done.is_none() && had {
                    tracing::warn!(
                        "state file {}: the last save was not written within {:.0} s (the storage stalls); stopping without it",
                        self.path.display(),
                        wait.as_secs_f64()
                    );
                }
                done == Some(true)
            }
        }
    }

    /// What the file says of `e`, offered `at`: dated then, not now.
    fn state_of(&self, e: Estimate, at: Offered) -> SavedState {
        SavedState {
            prefix: Some(self.prefix.clone()),
            saved_unix_ns: at.unix_ns,
            boot: self.boot_id.clone().map(|id| BootStamp {
                id,
                mono_ns: at.mono_ns,
            }),
            estimate: e,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::io::Read;

    fn est() -> Estimate {
        Estimate {
            seq: 17,
            t_ref_ns: 123_456_789_012,
            offset_s: -0.012_345_678_901_234_5,
            drift: 1.234_567e-5,
            offset_std_s: 0.000_812_3,
            drift_std: 2.5e-6,
            state: EstimatorState::Tracking,
            polarity: Polarity::Negative,
            peak_score: 0.8,
            peak_ratio: 2.0,
            measured_offset_s: -0.0123,
        }
    }

    fn state() -> SavedState {
        SavedState {
            prefix: Some("vlsync/robot".to_string()),
            saved_unix_ns: 1_795_442_000_123_456_789,
            boot: None,
            estimate: est(),
        }
    }

    fn dir(tag: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("vlsync-state-unit-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// A background saver's jobs waiting in its slot for the thread, and the outcomes
    /// of saves its [`Saver::tick`] has not taken yet.
    fn queued(sv: &Saver) -> (usize, usize) {
        match &sv.writer {
            Writer::Thread(t) => (t.jobs.as_ref().map_or(0, |j| j.len()), t.done.len()),
            Writer::Inline { .. } => panic!("the saver writes inline, not in the background"),
        }
    }

    /// Waits until `done` holds, for up to 20 s (a busy machine may keep a thread
    /// from running for long), failing the test with `what` after that.
    fn wait_until(what: &str, mut done: impl FnMut() -> bool) {
        let t0 = Instant::now();
        while !done() {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "{what}: not within 20 s"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Re-signs a modified body so that only the modification is wrong.
    fn resign(text: &str) -> String {
        let i = text.trim_end_matches('\n').rfind('\n').unwrap() + 1;
        let body = &text[..i];
        format!(
            "{body}checksum = fnv1a64:{:016x}\n",
            fnv1a64(body.as_bytes())
        )
    }

    #[test]
    fn round_trip_is_exact() {
        let s = SavedState {
            boot: Some(BootStamp {
                id: "2269c875-ef3a-433a-afa6-076765882294".into(),
                mono_ns: 1_234_567_890_123,
            }),
            ..state()
        };
        let text = encode(&s);
        assert!(
            text.starts_with("vlsync-state 3\n# saved 2026-11-23T")
                && text.contains(
                    "\nboot_id = 2269c875-ef3a-433a-afa6-076765882294\nsaved_mono_ns = 1234567890123\n"
                ),
            "{text}"
        );
        let back = decode(text.as_bytes()).unwrap();
        assert_eq!(back.saved_unix_ns, s.saved_unix_ns);
        assert_eq!(back.prefix, s.prefix);
        assert_eq!(back.boot, s.boot);
        let (a, b) = (back.estimate, s.estimate);
        assert_eq!(a.t_ref_ns, b.t_ref_ns);
        assert_eq!(a.offset_s.to_bits(), b.offset_s.to_bits());
        assert_eq!(a.drift.to_bits(), b.drift.to_bits());
        assert_eq!(a.offset_std_s.to_bits(), b.offset_std_s.to_bits());
        assert_eq!(a.drift_std.to_bits(), b.drift_std.to_bits());
        assert_eq!((a.state, a.polarity), (b.state, b.polarity));
        assert!(a.measured_offset_s.is_nan());
    }

    #[test]
    fn utc_text_matches_known_dates() {
        assert_eq!(utc_text(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_text(951_782_400_000_000_000), "2000-02-29T00:00:00Z");
        assert_eq!(utc_text(1_795_442_000_000_000_000), "2026-11-23T13:53:20Z");
        assert_eq!(utc_text(-1_000_000_000), "1969-12-31T23:59:59Z");
    }

    /// A file's age: by the monotonic clock within its boot, whatever the wall clock
    /// says; by the wall clock for another boot's file only where that clock can be
    /// trusted; else unknown, and the file is not restored.
    #[test]
    fn the_age_comes_from_the_boot_or_a_trusted_wall_clock() {
        let d = dir("ages");
        let p = d.join("vlsync.state");
        let boot = |id: &str, mono_ns| {
            Some(BootStamp {
                id: id.into(),
                mono_ns,
            })
        };
        let day_ns = 86_400_000_000_000;
        let saved = SavedState {
            saved_unix_ns: 10 * day_ns,
            boot: boot("aa-1", 50_000_000_000),
            ..state()
        };
        save(&p, &saved).unwrap();
        let at = |unix_ns, now_boot: Option<BootStamp>, wall_trusted| {
            let clocks = Clocks {
                unix_ns,
                boot: now_boot,
                wall_trusted,
            };
            load_at(&p, "vlsync/robot", &clocks, 3600.0).map(|r| r.map(|(_, age)| age))
        };
        // the same boot 5 s later: 5 s old, though the wall clock stepped two days
        // ahead (NTP after a boot at fake-hwclock's time) or one back
        for unix in [12 * day_ns, 9 * day_ns] {
            for trusted in [true, false] {
                let age = at(unix, boot("aa-1", 55_000_000_000), trusted)
                    .unwrap()
                    .unwrap();
                assert!((age - 5.0).abs() < 1e-9, "{age}");
            }
        }
        // the same boot, the monotonic clock behind the save: corrupt, not restored
        let e = at(10 * day_ns, boot("aa-1", 1), true).unwrap_err();
        assert!(matches!(e.problem, Problem::MonotonicAhead { .. }), "{e}");
        assert!(
            e.to_string().contains("`saved_mono_ns` is 50 s after"),
            "{e}"
        );
        // another boot: the wall clock's age where it is trusted
        let age = at(10 * day_ns + 60_000_000_000, boot("bb-2", 1), true)
            .unwrap()
            .unwrap();
        assert!((age - 60.0).abs() < 1e-9, "{age}");
        let e = at(12 * day_ns, boot("bb-2", 1), true).unwrap_err();
        assert!(matches!(e.problem, Problem::Stale { .. }), "{e}");
        // ... and unknown where not: a Pi after a night off reads its last shutdown's
        // time at boot, so the file would look seconds old
        for now_boot in [boot("bb-2", 1), None] {
            let e = at(10 * day_ns + 5_000_000_000, now_boot, false).unwrap_err();
            assert_eq!(e.problem, Problem::AgeUnknown);
            assert!(e.to_string().contains("its age is unknown"), "{e}");
        }
        // a version-2 file (no boot; written as the daemons before version 3 did): as
        // another boot's
        let v3 = encode(&SavedState {
            boot: None,
            ..saved.clone()
        });
        let v2 = resign(&v3.replacen("vlsync-state 3", "vlsync-state 2", 1));
        assert!(
            v2.starts_with("vlsync-state 2\n") && !v2.contains("boot"),
            "{v2}"
        );
        assert_eq!(decode(v2.as_bytes()).unwrap().boot, None);
        std::fs::write(&p, &v2).unwrap();
        let e = at(10 * day_ns, boot("aa-1", 55_000_000_000), false).unwrap_err();
        assert_eq!(e.problem, Problem::AgeUnknown);
        let age = at(10 * day_ns + 7_000_000_000, boot("aa-1", 1), true)
            .unwrap()
            .unwrap();
        assert!((age - 7.0).abs() < 1e-9, "{age}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn every_corruption_kind_is_named() {
        let good = encode(&SavedState {
            boot: Some(BootStamp {
                id: "2269c875-ef3a-433a-afa6-076765882294".into(),
                mono_ns: 5_000_000_000,
            }),
            ..state()
        });
        let set = |key: &str, value: &str| -> String {
            let mut out = String::new();
            for l in good.lines() {
                if l.split('=').next().map(str::trim) == Some(key) {
                    out.push_str(&format!("{key} = {value}\n"));
                } else {
                    out.push_str(&format!("{l}\n"));
                }
            }
            resign(&out)
        };
        let without_checksum: String = good
            .lines()
            .filter(|l| !l.starts_with("checksum"))
            .map(|l| format!("{l}\n"))
            .collect();
        let cases: Vec<(String, &str)> = vec![
            ("".into(), "expected `vlsync-state 3`"),
            (
                good.replacen("vlsync-state", "other-state", 1),
                "not a vlsync state file",
            ),
            (
                good.replacen("vlsync-state 3", "vlsync-state 4", 1),
                "format version \"4\", this vlsyncd reads versions 1 to 3",
            ),
            (
                good.replacen("vlsync-state 3", "vlsync-state 3 x", 1),
                "expected `vlsync-state 3`",
            ),
            // the boot's keys: version 3's, both or neither, a boot id as the kernel's
            (
                resign(&good.replacen("vlsync-state 3", "vlsync-state 2", 1)),
                "unknown key \"boot_id\"",
            ),
            (
                resign(&good.replacen("saved_mono_ns = 5000000000\n", "", 1)),
                "key `saved_mono_ns` missing",
            ),
            (
                set("boot_id", "not a uuid"),
                "`boot_id` = \"not a uuid\" is not a valid value",
            ),
            (set("saved_mono_ns", "-"), "`saved_mono_ns` = \"-\""),
            (good[..good.len() / 2].to_string(), "truncated"),
            (good.trim_end_matches('\n').to_string(), "truncated"),
            (without_checksum, "truncated"),
            (good.replacen("fnv1a64:", "crc32:", 1), "malformed checksum"),
            (
                good.replacen("state = tracking", "state = trackinh", 1),
                "checksum mismatch",
            ),
            (
                resign(&good.replacen("drift = ", "drift: ", 1)),
                "not `key = value`",
            ),
            (
                resign(&good.replacen("drift = ", "drift_rate = ", 1)),
                "unknown key \"drift_rate\"",
            ),
            (
                resign(&good.replacen(
                    "state = tracking\n",
                    "state = tracking\nstate = holding\n",
                    1,
                )),
                "`state` given twice",
            ),
            (
                resign(&good.replacen("polarity = negative\n", "", 1)),
                "key `polarity` missing",
            ),
            (
                set("offset_s", "abc"),
                "`offset_s` = \"abc\" is not a valid value",
            ),
            (set("offset_s", "NaN"), "`offset_s` is not a finite"),
            (set("drift_std", "inf"), "`drift_std` is not a finite"),
            (
                set("offset_s", "2e6"),
                "`offset_s` = 2000000 is out of range",
            ),
            (set("drift", "0.5"), "`drift` = 0.5 is out of range"),
            (
                set("offset_std_s", "-1"),
                "`offset_std_s` = -1 is out of range",
            ),
            (set("state", "lost"), "`state` = \"lost\""),
            (set("polarity", "sideways"), "`polarity` = \"sideways\""),
            (set("saved_unix_ns", "1.5"), "`saved_unix_ns` = \"1.5\""),
            (set("t_ref_ns", "99999999999999999999"), "`t_ref_ns`"),
        ];
        for (text, want) in cases {
            let e = decode(text.as_bytes()).expect_err(&text).to_string();
            assert!(e.contains(want), "{e:?} lacks {want:?} for\n{text}");
        }
        let e = decode(&[0xff, 0xfe, b'\n']).unwrap_err();
        assert_eq!(e, Problem::NotText);
        // the checksum covers the comment too
        let e = decode(good.replacen("do not edit", "do not edlt", 1).as_bytes()).unwrap_err();
        assert!(matches!(e, Problem::ChecksumMismatch { .. }), "{e:?}");
    }

    /// The file names its daemon's prefix: another prefix's file is refused by name
    /// whatever its age, and `startup` then neither restores nor saves; a
    /// version-1 file (no prefix) is anyone's; version 2 without a prefix, or
    /// with one no daemon accepts, is corrupt.
    #[test]
    fn the_prefix_binds_a_file_to_its_daemon() {
        let d = dir("prefix");
        let p = d.join("vlsync.state");
        // saved now, in this boot: `startup` below judges its age by the monotonic
        // clock (this machine's wall clock may not date another boot's file)
        let s = SavedState {
            saved_unix_ns: unix_now_ns(),
            boot: BootStamp::current(),
            ..state()
        };
        save(&p, &s).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(
            text.starts_with("vlsync-state 3\n") && text.contains("\nprefix = vlsync/robot\n"),
            "{text}"
        );
        let e = load(&p, "vlsync/robot2", s.saved_unix_ns, 1e9).unwrap_err();
        assert_eq!(
            e.problem,
            Problem::OtherPrefix {
                saved: "vlsync/robot".into(),
                ours: "vlsync/robot2".into()
            }
        );
        let msg = e.to_string();
        assert!(
            msg.contains(&p.display().to_string()) && msg.contains("own daemon.state_file"),
            "{msg}"
        );
        let cfg = vlsync_config::DaemonConfig {
            state_file: p.display().to_string(),
            state_max_age_s: 1e9,
            ..Default::default()
        };
        let (restore, saver) = startup(&cfg, "vlsync/robot2");
        assert!(restore.is_none() && saver.is_none());
        let (restore, saver) = startup(&cfg, "vlsync/robot");
        assert!(restore.is_some() && saver.is_some());
        // version 1: no prefix line, read as this daemon's
        let v1 = encode(&SavedState {
            prefix: None,
            ..state()
        });
        assert!(
            v1.starts_with("vlsync-state 1\n") && !v1.contains("prefix"),
            "{v1}"
        );
        let back = decode(v1.as_bytes()).unwrap();
        assert_eq!(back.prefix, None);
        std::fs::write(&p, &v1).unwrap();
        assert!(load(&p, "any/robot", s.saved_unix_ns, 1e9)
            .unwrap()
            .is_some());
        // version 2 needs its prefix, a valid one
        let v2_without = encode(&SavedState {
            prefix: Some("x".into()),
            ..state()
        })
        .replace("prefix = x\n", "");
        let v2_without = resign(&v2_without);
        assert_eq!(
            decode(v2_without.as_bytes()).unwrap_err(),
            Problem::MissingKey("prefix")
        );
        // the daemon's own rule for services.prefix: a space, a double or a leading `/`
        for refused in ["a b", "vlsync//robot", "/vlsync"] {
            let bad =
                resign(&text.replace("prefix = vlsync/robot", &format!("prefix = {refused}")));
            assert!(
                matches!(
                    decode(bad.as_bytes()).unwrap_err(),
                    Problem::BadValue { key: "prefix", .. }
                ),
                "{bad}"
            );
        }
    }

    #[test]
    fn load_names_the_file_and_checks_age() {
        let d = dir("age");
        let p = d.join("vlsync.state");
        assert_eq!(load(&p, "vlsync/robot", 0, 10.0), Ok(None));
        let s = state();
        save(&p, &s).unwrap();
        let now = s.saved_unix_ns + 30_000_000_000;
        let (back, age) = load(&p, "vlsync/robot", now, 3600.0).unwrap().unwrap();
        assert_eq!(back.estimate.offset_s, s.estimate.offset_s);
        assert!((age - 30.0).abs() < 1e-6, "{age}");
        let e = load(&p, "vlsync/robot", now, 10.0).unwrap_err();
        assert!(matches!(e.problem, Problem::Stale { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains(&p.display().to_string()) && msg.contains("stale"),
            "{msg}"
        );
        // slightly in the future (clock adjustments) is fine, far is not
        let (_, age) = load(&p, "vlsync/robot", s.saved_unix_ns - 5_000_000_000, 10.0)
            .unwrap()
            .unwrap();
        assert_eq!(age, 0.0);
        let e = load(
            &p,
            "vlsync/robot",
            s.saved_unix_ns - 3_600_000_000_000,
            10.0,
        )
        .unwrap_err();
        assert!(e.to_string().contains("in the future"), "{e}");
        // oversized and unreadable files
        std::fs::write(&p, vec![b'#'; MAX_FILE_BYTES as usize + 1]).unwrap();
        assert_eq!(
            load(&p, "vlsync/robot", now, 10.0).unwrap_err().problem,
            Problem::TooLarge
        );
        let e = load(&d, "vlsync/robot", now, 10.0).unwrap_err();
        assert_eq!(e.problem, Problem::NotAFile, "{e}");
        assert!(e.to_string().contains("not a regular file"), "{e}");
        // a FIFO is refused without blocking
        let fifo = d.join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        assert_eq!(
            load(&fifo, "vlsync/robot", now, 10.0).unwrap_err().problem,
            Problem::NotAFile
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_save_never_replaces_the_file_of_another_prefix() {
        let d = dir("shared");
        let p = d.join("vlsync.state");
        let theirs = SavedState {
            prefix: Some("vlsync/other".into()),
            ..state()
        };
        save(&p, &theirs).unwrap();
        // the other daemon saved first: ours is refused, the file stays theirs
        let e = save(&p, &state()).unwrap_err();
        assert!(
            e.contains("now holds the state of prefix `vlsync/other`, not saved over"),
            "{e}"
        );
        let (back, _) = load(&p, "vlsync/other", theirs.saved_unix_ns, 60.0)
            .unwrap()
            .unwrap();
        assert_eq!(back.prefix.as_deref(), Some("vlsync/other"));
        // a file of no prefix (version 1) or a corrupt one is saved over
        std::fs::write(&p, "garbage\n").unwrap();
        save(&p, &state()).unwrap();
        let left: Vec<_> = std::fs::read_dir(&d).unwrap().flatten().collect();
        assert_eq!(left.len(), 1, "no temporary file left");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn temporary_files_of_ended_saves_are_removed_and_no_others() {
        let d = dir("stale");
        let p = d.join("vlsync.state");
        // a pid no process has (above the kernel's pid_max limit of 2^22)
        let dead = d.join("vlsync.state.tmp-4194305");
        let legacy = d.join("vlsync.state.tmp");
        let ours = temp_path(&p);
        let other = d.join("vlsync.state.tmp-x");
        let unrelated = d.join("other.state.tmp");
        for f in [&dead, &legacy, &ours, &other, &unrelated, &p] {
            std::fs::write(f, "x").unwrap();
        }
        assert_eq!(remove_stale_temps(&p), 2);
        assert!(!dead.exists() && !legacy.exists());
        assert!(ours.exists() && other.exists() && unrelated.exists() && p.exists());
        // a state file naming a directory is said to be one, and one no file can have
        let e = directory_problem(&d).unwrap();
        assert!(e.ends_with(": is a directory"), "{e}");
        let e = directory_problem(Path::new("/tmp/a\0b")).unwrap();
        assert!(
            e.ends_with("contains a NUL byte, which no file name can"),
            "{e}"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_crash_mid_write_leaves_the_old_file_intact() {
        let d = dir("atomic");
        let p = d.join("vlsync.state");
        let old = state();
        save(&p, &old).unwrap();
        assert!(!temp_path(&p).exists(), "temp file left after a save");
        // a crash after part of the new text reached the temp file
        let mut new = old.clone();
        new.estimate.offset_s = 0.5;
        let text = encode(&new);
        std::fs::write(temp_path(&p), &text[..text.len() / 3]).unwrap();
        let (back, _) = load(&p, "vlsync/robot", old.saved_unix_ns, 60.0)
            .unwrap()
            .unwrap();
        assert_eq!(back.estimate.offset_s, old.estimate.offset_s);
        // the next save overwrites the leftover and replaces the file
        save(&p, &new).unwrap();
        assert!(!temp_path(&p).exists());
        let (back, _) = load(&p, "vlsync/robot", new.saved_unix_ns, 60.0)
            .unwrap()
            .unwrap();
        assert_eq!(back.estimate.offset_s, 0.5);
        // a failed save (directory gone) reports the path and leaves nothing
        let gone = d.join("missing").join("vlsync.state");
        let e = save(&gone, &new).unwrap_err();
        assert!(e.contains("missing/vlsync.state.tmp"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// The file dates the estimate by when it was offered, not by its save: the
    /// pending estimate waits for the refresh period (up to 60 s) or the stop, and a
    /// restore extrapolates it by its drift over its age (at 50 ppm, 3 ms per minute
    /// the age was short). Inline and through the background thread, at a tick and
    /// at the stop.
    #[test]
    fn the_file_dates_the_estimate_by_its_offer_not_by_its_save() {
        let d = dir("offer-stamp");
        let p = d.join("s");
        let boot = BootStamp::current();
        let at = |k: i64| Offered {
            mono_ns: 1_000_000_000_000 + k,
            unix_ns: 1_795_442_000_000_000_000 + k,
        };
        let read = || decode(&std::fs::read(&p).unwrap()).unwrap();
        let check = |s: SavedState, k: i64, offset_s: f64| {
            assert_eq!(s.estimate.offset_s, offset_s);
            assert_eq!(s.saved_unix_ns, at(k).unix_ns);
            assert_eq!(
                s.boot,
                boot.as_ref().map(|b| BootStamp {
                    id: b.id.clone(),
                    mono_ns: at(k).mono_ns
                })
            );
        };
        let t0 = Instant::now();
        let mut sv = Saver::new(p.clone(), "vlsync/robot", SAVE_PERIOD);
        sv.offer_at(&est(), at(1));
        assert!(sv.tick(t0));
        check(read(), 1, est().offset_s);
        // offered at 2, saved a minute later by the refresh
        sv.offer_at(&est(), at(2));
        assert!(!sv.tick(t0 + Duration::from_secs(30)));
        assert!(sv.tick(t0 + Duration::from_secs(60)));
        check(read(), 2, est().offset_s);
        // pending at the stop: dated by its offer, not by the stop
        let e3 = Estimate {
            offset_s: 0.5,
            ..est()
        };
        sv.offer_at(&e3, at(3));
        assert!(sv.finish(Duration::from_secs(1)));
        check(read(), 3, 0.5);
        // in the background, the last one handed over at the stop
        let mut sv = Saver::new(p.clone(), "vlsync/robot", SAVE_PERIOD).in_background();
        sv.offer_at(&est(), at(4));
        assert!(sv.flush());
        sv.offer_at(&e3, at(5));
        assert!(sv.finish(Duration::from_secs(20)));
        check(read(), 5, 0.5);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn saving_in_the_background_writes_the_file_and_waits_for_it_at_stop() {
        let d = dir("background");
        let p = d.join("s");
        let mut sv = Saver::new(p.clone(), "vlsync/robot", Duration::from_secs(5)).in_background();
        sv.offer(&est());
        assert!(sv.tick(Instant::now()));
        sv.offer(&Estimate {
            offset_s: 0.25,
            ..est()
        });
        // the stop waits for both saves and leaves the last one on disk
        assert!(sv.finish(Duration::from_secs(10)));
        let (back, _) = load(&p, "vlsync/robot", unix_now_ns(), 60.0)
            .unwrap()
            .unwrap();
        assert_eq!(back.estimate.offset_s, 0.25);
        // nothing pending: nothing to save
        assert!(!sv.finish(Duration::from_secs(1)));
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_failed_background_save_is_retried_a_period_later_and_reported_at_stop() {
        let d = dir("background-fail");
        let p = d.join("missing").join("s");
        let mut sv = Saver::new(p.clone(), "vlsync/robot", Duration::from_secs(5)).in_background();
        let t0 = Instant::now();
        sv.offer(&est());
        assert!(sv.tick(t0), "handed over");
        // the outcome arrives; the same estimate is tried again after the period (5 s),
        // not after the refresh period (60 s) of an estimate already saved
        wait_until("the failed save's outcome", || queued(&sv) == (0, 1));
        sv.offer(&est());
        assert!(!sv.tick(t0 + Duration::from_secs(4)));
        assert!(sv.tick(t0 + Duration::from_secs(5)), "retried");
        // the stop reports a save that failed as not saved
        sv.offer(&est());
        assert!(!sv.finish(Duration::from_secs(5)));
        // and one that works as saved
        std::fs::create_dir_all(d.join("missing")).unwrap();
        let mut sv = Saver::new(p.clone(), "vlsync/robot", Duration::from_secs(5)).in_background();
        sv.offer(&est());
        assert!(sv.finish(Duration::from_secs(5)));
        assert!(p.exists());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_busy_save_thread_is_offered_the_estimate_again_at_the_next_tick() {
        // the temporary file is a FIFO nobody reads until the test does: the first
        // save blocks in it, the second waits in the slot, the third is refused
        let (d, fifo, mut sv) = saver_over_a_fifo("busy");
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let e = |k: u32| Estimate {
            offset_s: f64::from(k) * 1e-3,
            ..est()
        };
        sv.offer(&e(1));
        assert!(sv.tick(at(0)));
        // the thread takes it out of the slot, and blocks in the FIFO
        wait_until("the thread took the first save", || queued(&sv).0 == 0);
        sv.offer(&e(2));
        assert!(sv.tick(at(5)), "into the slot");
        sv.offer(&e(3));
        assert!(!sv.tick(at(10)), "refused: the slot is full");
        // not a period later: at the next tick
        assert!(!sv.tick(at(10) + Duration::from_millis(100)));
        // release the writer: it drains the FIFO's job and the slot's
        let reader = std::thread::spawn(move || {
            let mut sink = Vec::new();
            let _ = std::fs::File::open(&fifo).map(|mut f| f.read_to_end(&mut sink));
        });
        let mut k = 0;
        wait_until("the pending estimate offered again", || {
            k += 1;
            sv.tick(at(10) + Duration::from_millis(200 + k))
        });
        let _ = sv.finish(Duration::from_millis(300));
        let _ = reader.join();
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A background saver (period 5 s) whose temporary file is a FIFO nobody reads:
    /// opening it to save blocks, as an fsync on stalled storage does. Returns the
    /// test's directory, the FIFO and the saver.
    fn saver_over_a_fifo(tag: &str) -> (PathBuf, PathBuf, Saver) {
        let d = dir(tag);
        let p = d.join("s");
        let fifo = temp_path(&p);
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        let sv = Saver::new(p, "vlsync/robot", Duration::from_secs(5)).in_background();
        (d, fifo, sv)
    }

    #[test]
    fn a_stalled_save_stops_neither_the_service_thread_nor_the_daemons_stop() {
        // the temporary file is a FIFO nobody reads: opening it blocks, as an fsync
        // on stalled storage does. Saved inline, every tick would hang on it
        let (d, fifo, mut sv) = saver_over_a_fifo("stalled");
        // the service thread's part on a thread of the test's, so that a regression
        // fails the test instead of hanging it
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let t0 = Instant::now();
            for k in 0..20u32 {
                sv.offer(&Estimate {
                    offset_s: f64::from(k) * 1e-3,
                    ..est()
                });
                sv.tick(t0 + Duration::from_secs(5 * u64::from(k)));
            }
            let ticks = t0.elapsed();
            let stop = Instant::now();
            let saved = sv.finish(Duration::from_millis(300));
            let _ = tx.send((ticks, saved, stop.elapsed()));
        });
        // a tick or a stop that waits on the save never sends: the timeout fails it
        // (no ceiling on the times themselves: the machine may be loaded)
        let (_ticks, saved, waited) = rx
            .recv_timeout(Duration::from_secs(10))
            .expect("the service thread blocked on a stalled save");
        assert!(!saved);
        // the stop gave the save its 300 ms
        assert!(waited >= Duration::from_millis(300), "{waited:?}");
        // release the writer (it writes into the FIFO, whose content is discarded)
        let _ = std::fs::File::open(&fifo).map(|mut f| {
            let mut sink = Vec::new();
            let _ = f.read_to_end(&mut sink);
        });
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn only_good_estimates_are_saved_and_at_most_every_period() {
        let d = dir("saver");
        let p = d.join("s");
        let mut sv = Saver::new(p.clone(), "vlsync/robot", Duration::from_secs(5));
        let t0 = Instant::now();
        let acquiring = Estimate {
            state: EstimatorState::Acquiring,
            ..est()
        };
        let loose_hold = Estimate {
            state: EstimatorState::Holding,
            offset_std_s: 0.02,
            ..est()
        };
        sv.offer(&acquiring);
        sv.offer(&loose_hold);
        sv.offer(&Estimate {
            offset_s: f64::NAN,
            ..est()
        });
        assert!(!sv.tick(t0), "nothing worth saving yet");
        assert!(!p.exists());
        sv.offer(&est());
        assert!(sv.tick(t0));
        sv.offer(&Estimate {
            state: EstimatorState::Holding,
            offset_std_s: 0.004,
            offset_s: 0.25,
            ..est()
        });
        assert!(
            !sv.tick(t0 + Duration::from_secs(4)),
            "saved within the period"
        );
        assert!(sv.tick(t0 + Duration::from_secs(5)));
        let (s, _) = load(&p, "vlsync/robot", unix_now_ns(), 60.0)
            .unwrap()
            .unwrap();
        assert_eq!(s.estimate.offset_s, 0.25);
        assert_eq!(s.estimate.state, EstimatorState::Holding);
        // nothing new: no save
        assert!(!sv.tick(t0 + Duration::from_secs(20)));
        // the same estimate again (within 0.1 ms): saved only after the refresh period
        sv.offer(&Estimate {
            state: EstimatorState::Holding,
            offset_std_s: 0.004,
            offset_s: 0.250_05,
            ..est()
        });
        assert!(!sv.tick(t0 + Duration::from_secs(20)));
        assert!(!sv.tick(t0 + Duration::from_secs(64)));
        assert!(sv.tick(t0 + Duration::from_secs(65)));
        // a moved estimate goes out after the short period again
        sv.offer(&Estimate {
            offset_s: 0.26,
            ..est()
        });
        assert!(!sv.tick(t0 + Duration::from_secs(69)));
        assert!(sv.tick(t0 + Duration::from_secs(70)));
        let (s, _) = load(&p, "vlsync/robot", unix_now_ns(), 60.0)
            .unwrap()
            .unwrap();
        assert_eq!(s.estimate.offset_s, 0.26);
        // flush saves what is pending regardless of the period
        sv.offer(&Estimate {
            offset_s: 0.125,
            ..est()
        });
        assert!(sv.flush());
        let (s, _) = load(&p, "vlsync/robot", unix_now_ns(), 60.0)
            .unwrap()
            .unwrap();
        assert_eq!(s.estimate.offset_s, 0.125);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn what_a_restart_would_learn_is_saved_soon_the_rest_once_a_minute() {
        let saved = est(); // offset -12.35 ms, drift +12.3 ppm, σ 0.81 ms
        let later = |dt_s: f64, offset_s: f64, std_s: f64| Estimate {
            t_ref_ns: saved.t_ref_ns + (dt_s * 1e9) as i64,
            offset_s,
            offset_std_s: std_s,
            state: EstimatorState::Holding,
            ..saved
        };
        let predicted = |dt_s: f64| saved.offset_s + saved.drift * dt_s;
        // the drift carries the offset on by 1.5 ms in 120 s: that is what the saved one says
        assert!(unchanged(&saved, &later(120.0, predicted(120.0), 0.0008)));
        assert!(!unchanged(&saved, &later(120.0, saved.offset_s, 0.0008)));
        // within the new σ of the prediction (the state does not count)
        assert!(unchanged(
            &saved,
            &later(5.0, predicted(5.0) + 0.00079, 0.0008)
        ));
        assert!(!unchanged(
            &saved,
            &later(5.0, predicted(5.0) - 0.00081, 0.0008)
        ));
        // a σ shrunk by more than a fifth is news, a grown one is not
        assert!(!unchanged(&saved, &later(5.0, predicted(5.0), 0.0006)));
        assert!(unchanged(&saved, &later(5.0, predicted(5.0), 0.0030)));
        // but a step stays news while it inflates the new σ: the saved σ bounds it
        assert!(!unchanged(
            &saved,
            &later(5.0, predicted(5.0) - 0.025, 0.082)
        ));
        // a drift moved by more than its deviation is news (a restore extrapolates it)
        let drifted = Estimate {
            drift: saved.drift + 3.0 * saved.drift_std,
            ..later(5.0, predicted(5.0), 0.0008)
        };
        assert!(!unchanged(&saved, &drifted));
        let drifted = Estimate {
            drift: saved.drift + 0.9 * saved.drift_std,
            ..later(5.0, predicted(5.0), 0.0008)
        };
        assert!(unchanged(&saved, &drifted));
        // another polarity is news
        let flipped = Estimate {
            polarity: Polarity::Positive,
            ..later(5.0, predicted(5.0), 0.0008)
        };
        assert!(!unchanged(&saved, &flipped));
        // a tiny σ still allows 0.1 ms
        let sharp = Estimate {
            offset_std_s: 0.00001,
            ..saved
        };
        assert!(unchanged(
            &sharp,
            &later(5.0, predicted(5.0) + 0.00009, 0.00001)
        ));
        assert!(!unchanged(
            &sharp,
            &later(5.0, predicted(5.0) + 0.00011, 0.00001)
        ));
        // absurd times saturate instead of overflowing
        let far = Estimate {
            t_ref_ns: i64::MIN,
            ..saved
        };
        assert!(!unchanged(&far, &saved), "292 years of drift is news");
        assert!(!unchanged(&saved, &far));
    }

    /// A saving thread that has ended (as after a panic): its job channel closed,
    /// with `handle` as its join handle.
    fn ended_save_thread(handle: Option<std::thread::JoinHandle<()>>) -> Writer {
        let (jobs, rx) = crossbeam::channel::bounded::<SavedState>(1);
        drop(rx);
        let (done_tx, done) = crossbeam::channel::bounded(4);
        drop(done_tx);
        Writer::Thread(SaveThread {
            jobs: Some(jobs),
            done,
            handle,
        })
    }

    #[test]
    fn a_saving_thread_that_ended_hands_over_to_the_service_thread() {
        let d = dir("thread-gone");
        let path = d.join("state");
        let mut sv = Saver::new(path.clone(), "vlsync/robot", Duration::ZERO);
        // a thread that has ended (as after a panic): its job channel is closed
        sv.writer = ended_save_thread(None);
        sv.offer(&est());
        assert!(sv.flush(), "saved on the service thread");
        assert!(matches!(sv.writer, Writer::Inline { .. }));
        let back = load(&path, "vlsync/robot", unix_now_ns(), 10.0)
            .unwrap()
            .unwrap();
        assert_eq!(back.0.estimate.offset_s, est().offset_s);
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// A symlink planted at the temporary file's name (a state file in a directory
    /// others may write) is refused, never followed: its target keeps its content,
    /// the error names the file, and the state file is not replaced.
    #[test]
    fn a_symlink_at_the_temporary_name_is_not_followed() {
        let d = dir("tmp-symlink");
        let path = d.join("state");
        let victim = d.join("victim");
        std::fs::write(&victim, "precious\n").unwrap();
        std::os::unix::fs::symlink(&victim, temp_path(&path)).unwrap();
        let s = SavedState {
            prefix: Some("vlsync/robot".into()),
            saved_unix_ns: unix_now_ns(),
            boot: None,
            estimate: est(),
        };
        let err = save(&path, &s).unwrap_err();
        assert!(
            err.contains("cannot write state file") && err.contains(".tmp-"),
            "{err}"
        );
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious\n");
        assert!(!path.exists());
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// A saving thread that ended after the last tick's hand-over (a panic): the
    /// stop's final save is written on the service thread, not dropped unsaid.
    #[test]
    fn the_final_save_is_written_when_the_saving_thread_has_ended() {
        let d = dir("thread-gone-at-stop");
        let path = d.join("state");
        let mut sv = Saver::new(path.clone(), "vlsync/robot", Duration::ZERO);
        sv.writer = ended_save_thread(Some(std::thread::spawn(|| {})));
        sv.offer(&est());
        assert!(sv.finish(Duration::from_secs(1)), "saved at the stop");
        let back = load(&path, "vlsync/robot", unix_now_ns(), 10.0)
            .unwrap()
            .unwrap();
        assert_eq!(back.0.estimate.offset_s, est().offset_s);
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// ...and on stalled storage that last save is bounded by the stop's wait too
    /// (the temporary file a FIFO nobody reads, as in `saver_over_a_fifo`): written on
    /// the service thread, it held the stop until systemd's SIGKILL.
    #[test]
    fn the_last_save_after_the_saving_thread_ended_is_bounded() {
        let d = dir("thread-gone-stalled");
        let path = d.join("state");
        let fifo = temp_path(&path);
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        let mut sv = Saver::new(path.clone(), "vlsync/robot", Duration::ZERO);
        sv.writer = ended_save_thread(Some(std::thread::spawn(|| {})));
        sv.offer(&est());
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let t0 = Instant::now();
            let saved = sv.finish(Duration::from_millis(300));
            let _ = tx.send((saved, t0.elapsed()));
        });
        let (saved, waited) = rx
            .recv_timeout(Duration::from_secs(10))
            .expect("the stop blocked on the last save");
        assert!(!saved);
        assert!(waited >= Duration::from_millis(300), "{waited:?}");
        // release the writer (its bytes go nowhere)
        let _ = std::fs::File::open(&fifo).map(|mut f| {
            let mut sink = Vec::new();
            let _ = f.read_to_end(&mut sink);
        });
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn steady_tracking_saves_about_once_a_minute() {
        // an hour of estimates every 0.5 s on a drifting offset, each off the line by
        // up to 0.3 of its σ (1 ms): the rule before saved every 5 s (720 in the hour)
        let d = dir("steady");
        let mut sv = Saver::new(d.join("s"), "vlsync/robot", SAVE_PERIOD);
        let t0 = Instant::now();
        let mut saves = 0;
        for k in 0..7200u32 {
            let t_s = f64::from(k) * 0.5;
            let wobble = 0.0003 * (f64::from(k) * 0.7).sin();
            sv.offer(&Estimate {
                seq: u64::from(k),
                t_ref_ns: (t_s * 1e9) as i64,
                offset_s: 0.05 + 30e-6 * t_s + wobble,
                drift: 30e-6,
                offset_std_s: 0.001,
                drift_std: 2e-6,
                state: EstimatorState::Tracking,
                polarity: Polarity::Negative,
                ..est()
            });
            if sv.tick(t0 + Duration::from_secs_f64(t_s)) {
                saves += 1;
            }
        }
        assert!((55..=70).contains(&saves), "{saves} saves in an hour");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn an_hour_of_the_estimators_output_saves_a_fraction_of_one_every_5_s() {
        // the estimates of simulated one-hour runs through the saver, the saver's clock
        // following the estimates' reference time: one save every 5 s would be 720
        use vlsync_sim::families::{generate, Family};
        let d = dir("hour");
        let cfg = vlsync_config::Config::default();
        for (family, most) in [
            (Family::Robot, 150),
            (Family::Clocks, 150),
            (Family::LoadJitter, 360),
        ] {
            let run = generate(family, 3, Some(3600.0));
            let (ests, _) = crate::replay::run_estimator(&cfg.estimator, &run.cam, &run.lidar);
            let mut sv = Saver::new(d.join("s"), "vlsync/robot", SAVE_PERIOD);
            let (t0, ns0) = (Instant::now(), ests[0].t_ref_ns);
            let saves = ests
                .iter()
                .filter(|e| {
                    sv.offer(e);
                    let since = Duration::from_nanos((e.t_ref_ns - ns0).max(0) as u64);
                    sv.tick(t0 + since)
                })
                .count();
            eprintln!("{}: {} estimates, {saves} saves", family.name(), ests.len());
            assert!((60..=most).contains(&saves), "{}: {saves}", family.name());
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
            let _ = decode(&bytes);
        }

        #[test]
        fn mutated_files_never_panic(pos in 0usize..400, byte in any::<u8>(), cut in 0usize..400) {
            let mut b = encode(&state()).into_bytes();
            let i = pos % b.len();
            b[i] = byte;
            b.truncate(cut.max(1).min(b.len()));
            let _ = decode(&b);
            // the same with a valid checksum, so the key parser sees the mutation
            if let Ok(text) = std::str::from_utf8(&b) {
                if let Some(i) = text.trim_end_matches('\n').rfind('\n') {
                    let body = &text[..i + 1];
                    let resigned = format!("{body}checksum = fnv1a64:{:016x}\n", fnv1a64(body.as_bytes()));
                    if let Ok(s) = decode(resigned.as_bytes()) {
                        prop_assert!(s.estimate.offset_s.is_finite() && s.estimate.offset_std_s >= 0.0);
                    }
                }
            }
        }
    }
}
