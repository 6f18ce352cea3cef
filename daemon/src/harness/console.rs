//! Standard output of the live runs' binaries. `println!` panics when the reader
//! has gone (`vlsync-demo | head`, a closed terminal); here a failed write only
//! marks the output closed, so the binary can stop its children cleanly (the demo
//! ends its run, the load test goes on writing its report files) instead of
//! unwinding out of its loop.

use std::fmt;
use std::io::Write;

/// Line output to stdout that stops, without panicking, once stdout is closed.
#[derive(Debug, Default)]
pub struct Out {
    closed: bool,
}

impl Out {
    /// Output to this process's stdout.
    pub fn new() -> Self {
        Self::default()
    }

    /// Writes one line (and flushes it, so a pipe sees it at once); false once
    /// stdout is closed, and nothing more is written after that.
    pub fn line(&mut self, args: fmt::Arguments<'_>) -> bool {
        self.write_to(&mut std::io::stdout().lock(), args)
    }

    /// Whether a write has failed.
    pub fn closed(&self) -> bool {
        self.closed
    }

    fn write_to(&mut self, w: &mut impl Write, args: fmt::Arguments<'_>) -> bool {
        if !self.closed && (writeln!(w, "{args}").is_err() || w.flush().is_err()) {
            self.closed = true;
        }
        !self.closed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A writer that accepts `room` bytes, then fails as a closed pipe does.
    struct Pipe {
        got: Vec<u8>,
        room: usize,
    }

    impl Write for Pipe {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.got.len() + buf.len() > self.room {
                return Err(std::io::ErrorKind::BrokenPipe.into());
            }
            self.got.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_closed_reader_stops_the_output_without_a_panic() {
        let mut out = Out::new();
        let mut p = Pipe {
            got: vec![],
            room: 12,
        };
        assert!(out.write_to(&mut p, format_args!("first {}", 1)));
        assert!(!out.closed());
        assert!(!out.write_to(&mut p, format_args!("second line")));
        assert!(out.closed());
        // nothing more is attempted once closed, even with room again
        p.room = 1000;
        assert!(!out.write_to(&mut p, format_args!("third")));
        assert_eq!(p.got, b"first 1\n");
    }
}
