//! The driver's side of systemd: the watchdog, `READY=1`, `STATUS=` and
//! `STOPPING=1` (the protocol is [`vlsync_ipc::sd_notify`]).
//!
//! A driver's units run with `WatchdogSec=` (which implies `NotifyAccess=main`):
//! systemd restarts a driver that does not send `WATCHDOG=1` within that time. The
//! driver pets from its stop check, [`stop_check`], which its thread calls before
//! every sample, every 50 ms while pacing waits, at every idle second of a source
//! with no sample, every slice of a camera's wait for a frame (0.5 s), every
//! serial read of a LiDAR and every poll of `--wait-device`. So the watchdog
//! lapses exactly when that thread stops coming back: a `read` or `ioctl` that
//! never returns (a wedged USB serial adapter, a camera driver's `VIDIOC_DQBUF`
//! that hangs), a dead lock, a loop that never checks; a sensor that is merely
//! silent, unplugged or stalled keeps petting, since those waits check the stop
//! and have their own reports and reopens.
//!
//! Only the thread that called [`init`] pets: a helper thread's stop checks (a
//! rendering camera's worker) do not keep a stuck main loop alive.
//!
//! Without `NOTIFY_SOCKET` (a driver run by hand, by the demo or the tests'
//! rigs) every call is a no-op costing one atomic load.

use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::OnceLock;
use std::thread::ThreadId;
use vlsync_common::Nanos;
use vlsync_ipc::sd_notify::SdNotify;

/// How soon a pet that could not be sent is tried again, ns.
pub const RETRY_NS: Nanos = 1_000_000_000;

/// What the process-wide notifier holds.
static NOTIFIER: OnceLock<Notifier> = OnceLock::new();

/// A notifier and its watchdog's schedule: pets due every `period_ns` on the
/// thread that made it.
#[derive(Debug)]
pub struct Notifier {
    sd: SdNotify,
    /// Half of `WATCHDOG_USEC`; 0 when the watchdog is off.
    period_ns: Nanos,
    /// When the next pet is due (`CLOCK_MONOTONIC` ns); `i64::MIN` = at once.
    next_ns: AtomicI64,
    /// The thread whose stop checks pet.
    thread: ThreadId,
    /// The last send failed (its error was said; the next is said after a success).
    failing: AtomicBool,
    /// The process, as its lines name it (`vlsync-cam`).
    who: String,
}

/// What [`Notifier::pet_if_due`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Pet {
    /// Nothing due, no watchdog, or not the petting thread.
    Idle,
    /// `WATCHDOG=1` went out.
    Sent,
    /// It could not be sent; the text is said the first time in a row only
    /// (`Some`), `None` while the failure lasts.
    Failed(Option<String>),
}

impl Notifier {
    /// A notifier petting on the calling thread; `who` names the process in its lines.
    pub fn new(sd: SdNotify, who: &str) -> Self {
        let period_ns = sd.watchdog_period().map_or(0, |p| {
            Nanos::try_from(p.as_nanos()).unwrap_or(Nanos::MAX).max(1)
        });
        Self {
            sd,
            period_ns,
            next_ns: AtomicI64::new(i64::MIN),
            thread: std::thread::current().id(),
            failing: AtomicBool::new(false),
            who: who.to_string(),
        }
    }

    /// Whether `WATCHDOG=1` is expected (systemd gave `WATCHDOG_USEC` for this process).
    pub fn watchdog_on(&self) -> bool {
        self.period_ns > 0
    }

    /// Sends `WATCHDOG=1` when one is due at `now_ns` and this is the petting thread.
    pub fn pet_if_due(&self, now_ns: Nanos) -> Pet {
        if self.period_ns == 0
            || now_ns < self.next_ns.load(Ordering::Relaxed)
            || std::thread::current().id() != self.thread
        {
            return Pet::Idle;
        }
        match self.sd.watchdog() {
            Ok(()) => {
                self.next_ns
                    .store(now_ns.saturating_add(self.period_ns), Ordering::Relaxed);
                self.failing.store(false, Ordering::Relaxed);
                Pet::Sent
            }
            Err(e) => {
                // tried again within a second, not a period: one failed send (ENOBUFS
                // under memory pressure) followed by a whole period's wait would miss
                // systemd's deadline, and a healthy driver would be killed
                self.next_ns.store(
                    now_ns.saturating_add(self.period_ns.min(RETRY_NS)),
                    Ordering::Relaxed,
                );
                Pet::Failed((!self.failing.swap(true, Ordering::Relaxed)).then_some(e))
            }
        }
    }

    /// `READY=1` with a status line.
    pub fn ready(&self, status: &str) -> Result<(), String> {
        self.sd.ready(status)
    }

    /// `STATUS=` line.
    pub fn status(&self, status: &str) -> Result<(), String> {
        self.sd.status(status)
    }

    /// `STOPPING=1` with a status line.
    pub fn stopping(&self, status: &str) -> Result<(), String> {
        self.sd.stopping(status)
    }
}

/// Sets up the process's notifier from the environment, petting on the calling
/// thread (call it from the driver's main thread, once; later calls keep the
/// first); `who` names the process in its lines. Returns the problems with the
/// variables, each a sentence naming the variable and its value, and whether the
/// watchdog is on.
pub fn init(who: &str) -> (Vec<String>, bool) {
    let (sd, problems) = SdNotify::from_env();
    let n = NOTIFIER.get_or_init(|| Notifier::new(sd, who));
    (problems, n.watchdog_on())
}

/// The driver's stop check: pets the watchdog when due (see the module's text),
/// then whether a termination signal came ([`vlsync_ipc::termination_requested`]).
pub fn stop_check() -> bool {
    if let Some(n) = NOTIFIER.get() {
        if let Pet::Failed(Some(e)) = n.pet_if_due(vlsync_ipc::monotonic_ns()) {
            vlsync_common::console::print_err_at(
                vlsync_common::console::Priority::Warning,
                &format!(
                    "{}: systemd watchdog: {e} (said again only after a pet goes out)\n",
                    n.who
                ),
            );
        }
    }
    vlsync_ipc::termination_requested()
}

/// Runs `work` while a helper thread pets the watchdog every period: the whole run of
/// a recorded or simulated source, whose reads make no stop checks (a whole CSV
/// before the first sample, an MCAP file's chunks walked to the next message on its
/// topic), so that a file bigger than `WatchdogSec` can read does not restart the
/// unit for ever. Device sources are not run under it: every wait of theirs checks
/// the stop, and a stuck call there is what the watchdog is for.
pub fn petting_while<T>(work: impl FnOnce() -> T) -> T {
    match NOTIFIER.get() {
        Some(n) if n.watchdog_on() => n.petting_while(work),
        _ => work(),
    }
}

impl Notifier {
    /// [`petting_while`] with this notifier (pets from a helper thread, at once and
    /// then every period, until `work` returns).
    pub fn petting_while<T>(&self, work: impl FnOnce() -> T) -> T {
        use std::sync::mpsc::{channel, RecvTimeoutError};
        let period = std::time::Duration::from_nanos(self.period_ns.max(1) as u64);
        std::thread::scope(|sc| {
            let (done, finished) = channel::<()>();
            sc.spawn(move || loop {
                // a lasting failure is said by the stop checks' pets; a failed send is
                // tried again within a second, as theirs
                let wait = match self.sd.watchdog() {
                    Ok(()) => period,
                    Err(_) => period.min(std::time::Duration::from_nanos(RETRY_NS as u64)),
                };
                match finished.recv_timeout(wait) {
                    Err(RecvTimeoutError::Timeout) => {}
                    _ => return,
                }
            });
            let out = work();
            drop(done);
            out
        })
    }
}

/// Sends `send(notifier)` when a notifier is set up; a failure is returned to be said.
fn with(send: impl FnOnce(&Notifier) -> Result<(), String>) -> Result<(), String> {
    NOTIFIER.get().map_or(Ok(()), send)
}

/// `READY=1`: the driver publishes.
pub fn ready(status: &str) -> Result<(), String> {
    with(|n| n.ready(status))
}

/// A `STATUS=` line (`systemctl status` shows the newest).
pub fn status(status: &str) -> Result<(), String> {
    with(|n| n.status(status))
}

/// `STOPPING=1`.
pub fn stopping(status: &str) -> Result<(), String> {
    with(|n| n.stopping(status))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::net::UnixDatagram;
    use std::time::Duration;

    fn listening(tag: &str) -> (UnixDatagram, std::path::PathBuf) {
        let dir =
            std::env::temp_dir().join(format!("vlsync-driver-wd-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("notify.sock");
        let _ = std::fs::remove_file(&path);
        let rx = UnixDatagram::bind(&path).unwrap();
        rx.set_nonblocking(true).unwrap();
        (rx, path)
    }

    fn drain(rx: &UnixDatagram) -> Vec<String> {
        let mut out = vec![];
        let mut buf = [0u8; 512];
        while let Ok(k) = rx.recv(&mut buf) {
            out.push(String::from_utf8_lossy(&buf[..k]).into_owned());
        }
        out
    }

    fn notifier(path: &std::path::Path, usec: &str) -> Notifier {
        let (sd, problems) = SdNotify::from_values(
            Some(path.as_os_str()),
            Some(std::ffi::OsStr::new(usec)),
            None,
            1,
        );
        assert!(problems.is_empty(), "{problems:?}");
        Notifier::new(sd, "vlsync-test")
    }

    /// Pets go out at once, then once per half of WATCHDOG_USEC however often the
    /// stop is checked.
    #[test]
    fn pets_once_per_half_period() {
        let (rx, path) = listening("period");
        let n = notifier(&path, "2000000"); // pets every 1 s
        assert!(n.watchdog_on());
        let s = 1_000_000_000;
        let mut sent = 0;
        // checked every 10 ms for 10 s
        for k in 0..1000 {
            if n.pet_if_due(10 * s + k * 10_000_000) == Pet::Sent {
                sent += 1;
            }
        }
        assert_eq!(sent, 10);
        let got = drain(&rx);
        assert_eq!(got.len(), 10);
        assert!(got.iter().all(|m| m == "WATCHDOG=1"), "{got:?}");
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// Another thread's stop checks do not pet: a stuck main loop lets the
    /// watchdog lapse even while a worker thread keeps checking.
    #[test]
    fn only_the_thread_that_made_it_pets() {
        let (rx, path) = listening("thread");
        let n = notifier(&path, "200000");
        std::thread::scope(|sc| {
            sc.spawn(|| {
                for k in 0..100 {
                    assert_eq!(n.pet_if_due(k * 1_000_000_000), Pet::Idle);
                }
            });
        });
        assert!(drain(&rx).is_empty());
        assert_eq!(n.pet_if_due(0), Pet::Sent);
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// No WATCHDOG_USEC (or not this process's): never pets, though READY and
    /// STATUS still go out.
    #[test]
    fn no_watchdog_no_pets() {
        let (rx, path) = listening("off");
        let (sd, _) = SdNotify::from_values(Some(path.as_os_str()), None, None, 1);
        let n = Notifier::new(sd, "vlsync-test");
        assert!(!n.watchdog_on());
        for k in 0..10 {
            assert_eq!(n.pet_if_due(k * 10_000_000_000), Pet::Idle);
        }
        n.ready("publishing").unwrap();
        assert_eq!(drain(&rx), ["READY=1\nSTATUS=publishing"]);
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// A recorded source's run is petted for from a helper thread while it lasts,
    /// and no longer.
    #[test]
    fn work_is_petted_for_while_it_runs() {
        let (rx, path) = listening("work");
        let n = notifier(&path, "100000"); // every 50 ms
        let t0 = std::time::Instant::now();
        let r = n.petting_while(|| {
            std::thread::sleep(Duration::from_millis(500));
            7
        });
        let took = t0.elapsed();
        assert_eq!(r, 7);
        let pets = drain(&rx);
        // at once, then every 50 ms for as long as the work took (a late wake-up of
        // either thread moves the count, never beyond this)
        let most = (took.as_millis() / 50 + 1) as usize;
        assert!(
            (2..=most).contains(&pets.len()),
            "{} pets in {took:?}",
            pets.len()
        );
        assert!(pets.iter().all(|m| m == "WATCHDOG=1"), "{pets:?}");
        std::thread::sleep(Duration::from_millis(200));
        assert!(drain(&rx).is_empty(), "pets after the work ended");
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// A socket that goes away: the failure is said once, not at every pet, and
    /// again after a pet went out; a failed pet is tried again within a second, not
    /// a period (one failure then a period's wait would miss systemd's deadline).
    #[test]
    fn a_lasting_failure_is_said_once_and_retried_soon() {
        let (rx, path) = listening("fail");
        let n = notifier(&path, "20000000"); // pets every 10 s
        let s = 1_000_000_000;
        assert_eq!(n.pet_if_due(0), Pet::Sent);
        assert_eq!(n.pet_if_due(9 * s), Pet::Idle);
        drop(rx);
        std::fs::remove_file(&path).unwrap();
        let first = n.pet_if_due(10 * s);
        assert!(
            matches!(&first, Pet::Failed(Some(e)) if e.contains("notify.sock")),
            "{first:?}"
        );
        assert_eq!(n.pet_if_due(10 * s + RETRY_NS - 1), Pet::Idle);
        assert_eq!(n.pet_if_due(10 * s + RETRY_NS), Pet::Failed(None));
        assert_eq!(n.pet_if_due(12 * s), Pet::Failed(None));
        let rx = UnixDatagram::bind(&path).unwrap();
        rx.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        assert_eq!(n.pet_if_due(13 * s), Pet::Sent);
        // back to the period once a pet went out
        assert_eq!(n.pet_if_due(14 * s), Pet::Idle);
        assert_eq!(n.pet_if_due(23 * s), Pet::Sent);
        drop(rx);
        std::fs::remove_file(&path).unwrap();
        assert!(matches!(n.pet_if_due(33 * s), Pet::Failed(Some(_))));
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }
}
