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

    #[test]
    fn a_gone_reader_is_no_error_and_a_full_disk_is() {
        assert_eq!(write_out(&mut Gone, "x\n"), Ok(()));
        let mut full = io::Cursor::new([0u8; 2]);
        let e = write_out(&mut full, "abc").unwrap_err();
        assert!(e.starts_with("cannot write to stdout: "), "{e}");
    }
}
