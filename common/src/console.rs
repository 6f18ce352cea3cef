//! Printing from the command-line tools without panicking. `println!` and
//! `eprintln!` panic when their stream is closed (`vlsync-sim --list | head -1`, a
//! closed terminal) or full (`> /dev/full`). The one-shot tools write their files
//! first and print through these: a reader that went away ends the printing
//! quietly (it saw what it wanted), any other failure is an error naming stdout,
//! and a failure on stderr is ignored (there is nowhere left to report it). The
//! live runs (demo, soak, load and latency tests) print through
//! `vlsyncd::harness::console::Out` instead: there any failed write ends the output
//! and the run goes on, so that it still stops its children and writes its reports;
//! `vlsync-echo` ends on a gone reader (exit 0) and on a full stdout (exit 1).
//!
//! ```
//! use vlsync_common::console::write_out;
//! let mut full = std::io::Cursor::new([0u8; 4]);
//! assert!(write_out(&mut full, "12345\n").unwrap_err().contains("cannot write to stdout"));
//! let mut room = Vec::new();
//! assert_eq!(write_out(&mut room, "ok\n"), Ok(()));
//! assert_eq!(room, b"ok\n");
//! ```

use std::io::{self, Write};

/// Writes `text` to `w` and flushes it: `Ok` also when the reader has gone (a
/// broken pipe); any other failure is an error that names stdout.
pub fn write_out(w: &mut impl Write, text: &str) -> Result<(), String> {
    match w.write_all(text.as_bytes()).and_then(|()| w.flush()) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        Err(e) => Err(format!("cannot write to stdout: {e}")),
    }
}

/// [`write_out`] to this process's stdout.
pub fn print_out(text: &str) -> Result<(), String> {
    write_out(&mut io::stdout().lock(), text)
}

/// Whether this process's stderr is the systemd journal's stream: `JOURNAL_STREAM`
/// (`device:inode`, set by systemd for a unit's output) names the file stderr is.
/// Inherited by a child whose stderr went elsewhere (a file, a pipe), it names
/// another file, so such output gets no priority prefixes.
pub fn stderr_is_journal() -> bool {
    use std::os::fd::AsFd;
    use std::os::unix::fs::MetadataExt;
    let Some(var) = std::env::var_os("JOURNAL_STREAM") else {
        return false;
    };
    let Some((dev, ino)) = var.to_str().and_then(|v| v.split_once(':')) else {
        return false;
    };
    let (Ok(dev), Ok(ino)) = (dev.parse::<u64>(), ino.parse::<u64>()) else {
        return false;
    };
    io::stderr()
        .as_fd()
        .try_clone_to_owned()
        .map(std::fs::File::from)
        .and_then(|f| f.metadata())
        .is_ok_and(|m| m.dev() == dev && m.ino() == ino)
}

/// The `sd-daemon(3)` priority prefix of a line to the journal (`<3>` error, `<4>`
/// warning, `<6>` information), or nothing when `journal` is false: journald stores
/// a unit's lines at the priority their prefix names (every one at information
/// without it, so `journalctl -p warning` saw none of the warnings).
///
/// ```
/// use vlsync_common::console::{priority_prefix, Priority};
/// assert_eq!(priority_prefix(true, Priority::Warning), "<4>");
/// assert_eq!(priority_prefix(false, Priority::Error), "");
/// ```
pub fn priority_prefix(journal: bool, p: Priority) -> &'static str {
    match (journal, p) {
        (false, _) => "",
        (true, Priority::Error) => "<3>",
        (true, Priority::Warning) => "<4>",
        (true, Priority::Info) => "<6>",
        (true, Priority::Debug) => "<7>",
    }
}

/// Syslog priorities a line may carry ([`priority_prefix`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Priority {
    /// `<3>`.
    Error,
    /// `<4>`.
    Warning,
    /// `<6>`.
    Info,
    /// `<7>`.
    Debug,
}

/// [`print_err`] of `text` at priority `p`: each of its lines prefixed when stderr is
/// the journal ([`stderr_is_journal`], decided once per process; journald reads each
/// line as a record of its own), plain otherwise.
pub fn print_err_at(p: Priority, text: &str) {
    static JOURNAL: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let journal = *JOURNAL.get_or_init(stderr_is_journal);
    print_err(&with_priority(journal, p, text));
}

/// `text` with [`priority_prefix`] at the start of each of its lines.
///
/// ```
/// use vlsync_common::console::{with_priority, Priority};
/// assert_eq!(with_priority(true, Priority::Error, "a\nb\n"), "<3>a\n<3>b\n");
/// assert_eq!(with_priority(false, Priority::Error, "a\nb"), "a\nb");
/// ```
pub fn with_priority(journal: bool, p: Priority, text: &str) -> String {
    let prefix = priority_prefix(journal, p);
    if prefix.is_empty() {
        return text.to_string();
    }
    let mut out = String::with_capacity(text.len() + 8);
    for line in text.split_inclusive('\n') {
        out.push_str(prefix);
        out.push_str(line);
    }
    out
}

/// Writes `text` to stderr, ignoring a failure.
pub fn print_err(text: &str) {
    let mut e = io::stderr().lock();
    let _ = e.write_all(text.as_bytes()).and_then(|()| e.flush());
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reader that has gone: every write fails with a broken pipe.
    struct Gone;
    impl Write for Gone {
        fn write(&mut self, _: &[u8]) -> io::Result<usize> {
            Err(io::ErrorKind::BrokenPipe.into())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// The journal is recognised by the file stderr is, not by the variable alone.
    #[test]
    fn journal_stream_must_name_stderr() {
        use std::os::fd::AsFd;
        use std::os::unix::fs::MetadataExt;
        let m = io::stderr()
            .as_fd()
            .try_clone_to_owned()
            .map(std::fs::File::from)
            .and_then(|f| f.metadata())
            .unwrap();
        // the test harness's own environment is left alone: a child process decides
        if let Some(var) = std::env::var_os("VLSYNC_JOURNAL_PROBE") {
            let want = var == "yes";
            assert_eq!(stderr_is_journal(), want);
            return;
        }
        let exe = std::env::current_exe().unwrap();
        for (value, want) in [
            (format!("{}:{}", m.dev(), m.ino()), "yes"),
            (format!("{}:{}", m.dev(), m.ino().wrapping_add(1)), "no"),
            ("garbage".to_string(), "no"),
        ] {
            let out = std::process::Command::new(&exe)
                .args(["--exact", "console::tests::journal_stream_must_name_stderr"])
                .env("JOURNAL_STREAM", &value)
                .env("VLSYNC_JOURNAL_PROBE", want)
                .stderr(std::process::Stdio::inherit())
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&out.stdout);
            // the probe ran (a renamed test would run none, and pass)
            assert!(
                out.status.success() && text.contains("1 passed"),
                "JOURNAL_STREAM={value}: want {want}: {text}"
            );
        }
    }

    #[test]
    fn a_gone_reader_is_no_error_and_a_full_disk_is() {
        assert_eq!(write_out(&mut Gone, "x\n"), Ok(()));
        let mut full = io::Cursor::new([0u8; 2]);
        let e = write_out(&mut full, "abc").unwrap_err();
        assert!(e.starts_with("cannot write to stdout: "), "{e}");
    }
}
