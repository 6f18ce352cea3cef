//! iceoryx2's own log, routed so that the real-time thread never prints.
//!
//! iceoryx2 logs from inside the calls the real-time loop makes (`receive`,
//! `send`, `notify`): a corrupt connection to a crashed or hostile peer, a client's
//! full socket buffer, and with `IOX2_LOG_LEVEL=debug` much more. Its default logger
//! formats into a `String` and writes to stderr, on the calling thread. [`install`]
//! replaces it for the daemon's process: on a thread that called
//! [`mute_this_thread`] (the real-time thread, for its loop) a message is counted
//! and not formatted (iceoryx2's messages print the port that logged them with its
//! `Debug`, which allocates for every string in its configuration): only a message
//! without arguments is kept, as the `&'static str` it is, in a slot the thread only
//! tries to lock; on every other thread it goes to `tracing` (target `iceoryx2`) as
//! the daemon's own lines do. The service thread says what the real-time thread's
//! messages were ([`MutedLog::take`]).

use std::cell::Cell;
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::Mutex;

use iceoryx2_log::{Log, LogLevel};

thread_local! {
    static MUTED: Cell<bool> = const { Cell::new(false) };
}

static MUTED_COUNT: AtomicU64 = AtomicU64::new(0);
static MUTED_WORST: AtomicU8 = AtomicU8::new(0);
/// The newest muted message that had no arguments, and its level.
static LAST: Mutex<Option<(&'static str, u8)>> = Mutex::new(None);

struct Router;

static ROUTER: Router = Router;

impl Log for Router {
    fn log(
        &self,
        level: LogLevel,
        origin: std::fmt::Arguments,
        formatted_message: std::fmt::Arguments,
    ) {
        if MUTED.with(Cell::get) {
            MUTED_COUNT.fetch_add(1, Ordering::Relaxed);
            MUTED_WORST.fetch_max(level as u8, Ordering::Relaxed);
            // never waits: a message while the service thread reads the slot is
            // counted, its text not kept
            if let (Some(text), Ok(mut last)) = (formatted_message.as_str(), LAST.try_lock()) {
                *last = Some((text, level as u8));
            }
            return;
        }
        match level {
            LogLevel::Trace => tracing::trace!(target: "iceoryx2", "{origin}: {formatted_message}"),
            LogLevel::Debug => tracing::debug!(target: "iceoryx2", "{origin}: {formatted_message}"),
            LogLevel::Info => tracing::info!(target: "iceoryx2", "{origin}: {formatted_message}"),
            LogLevel::Warn => tracing::warn!(target: "iceoryx2", "{origin}: {formatted_message}"),
            _ => tracing::error!(target: "iceoryx2", "{origin}: {formatted_message}"),
        }
    }
}

/// Routes iceoryx2's log for this process (before its first node: iceoryx2 takes
/// its logger once). False when a logger was already set.
pub fn install() -> bool {
    iceoryx2_log::set_logger(&ROUTER)
}

/// iceoryx2's messages on this thread are counted and kept, not printed, until
/// [`unmute_this_thread`].
pub fn mute_this_thread() {
    MUTED.with(|m| m.set(true));
}

/// Ends [`mute_this_thread`] on this thread.
pub fn unmute_this_thread() {
    MUTED.with(|m| m.set(false));
}

fn level_name(level: u8) -> &'static str {
    match level {
        l if l == LogLevel::Trace as u8 => "trace",
        l if l == LogLevel::Debug as u8 => "debug",
        l if l == LogLevel::Info as u8 => "info",
        l if l == LogLevel::Warn as u8 => "warn",
        l if l == LogLevel::Error as u8 => "error",
        _ => "fatal",
    }
}

/// Shortest time between two [`MutedLog::take`] lines (ns): a corrupt client
/// connection logs at every estimate.
pub const MUTED_LINE_EVERY_NS: i64 = 60_000_000_000;

/// What the muted threads logged since the last line of [`MutedLog::take`].
#[derive(Debug, Default)]
pub struct MutedLog {
    told: u64,
    said_at: Option<i64>,
}

impl MutedLog {
    /// A line for the log when muted messages came since the last line, at most one
    /// per [`MUTED_LINE_EVERY_NS`] (`now_ns`: a monotonic time): their count, the
    /// worst level, the newest one's text (as far as it was kept).
    pub fn take(&mut self, now_ns: i64) -> Option<String> {
        let n = MUTED_COUNT.load(Ordering::Relaxed);
        if n <= self.told
            || self
                .said_at
                .is_some_and(|t| now_ns - t < MUTED_LINE_EVERY_NS)
        {
            return None;
        }
        self.said_at = Some(now_ns);
        let new = n - self.told;
        self.told = n;
        let worst = level_name(MUTED_WORST.load(Ordering::Relaxed));
        let last = match LAST.lock().map(|mut l| l.take()) {
            Ok(Some((text, level))) => {
                format!(
                    "; the newest without arguments ({}): {text}",
                    level_name(level)
                )
            }
            _ => String::new(),
        };
        Some(format!(
            "iceoryx2 logged {new} message(s) on the real-time thread ({n} since start, the worst \
             at level {worst}), counted there, not formatted{last}"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A muted thread's messages are counted without allocating (the counting
    /// allocator sees none on that thread), even those whose arguments would
    /// allocate to format (a `String` built by a `Debug`); only one without
    /// arguments is kept. The service side's line says them once, then not again
    /// within the minute, and at the minute's end the newer ones.
    #[test]
    fn a_muted_thread_counts_without_allocating() {
        struct Allocates;
        impl std::fmt::Debug for Allocates {
            fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                // what iceoryx2's StaticString does in its Debug
                let s: String = "node config".chars().collect();
                f.write_str(&s)
            }
        }
        vlsync_alloc_count::assert_counting();
        let mut told = MutedLog::default();
        let _ = told.take(0);
        let allocs = std::thread::spawn(|| {
            mute_this_thread();
            let before = vlsync_alloc_count::this_thread();
            ROUTER.log(
                LogLevel::Error,
                format_args!("{:?}", Allocates),
                format_args!("a corrupted connection was detected"),
            );
            ROUTER.log(
                LogLevel::Warn,
                format_args!("{:?}", Allocates),
                format_args!("a message with {:?}", Allocates),
            );
            let after = vlsync_alloc_count::this_thread();
            unmute_this_thread();
            after - before
        })
        .join()
        .unwrap();
        assert_eq!(allocs, 0);
        // (the count may include a live test daemon's, in this process)
        let line = told.take(1).expect("a line");
        assert!(
            line.contains(" message(s) on the real-time thread"),
            "{line}"
        );
        assert!(line.contains("the worst at level error"), "{line}");
        assert!(
            line.ends_with(
                "the newest without arguments (error): a corrupted connection was detected"
            ),
            "{line}"
        );
        assert!(told.take(2).is_none());
        std::thread::spawn(|| {
            mute_this_thread();
            ROUTER.log(LogLevel::Warn, format_args!("x"), format_args!("y"));
        })
        .join()
        .unwrap();
        assert!(told.take(2).is_none(), "within the minute");
        let line = told
            .take(1 + MUTED_LINE_EVERY_NS)
            .expect("a line after the minute");
        assert!(line.ends_with("(warn): y"), "{line}");
    }
}
