//! Reading a LiDAR from a serial port into a streaming parser.
//!
//! Uses the `serialport` crate built without default features (no libudev:
//! ports are opened by path, not enumerated). Each chunk read is stamped with
//! the host clock right after the read returns; the parsers turn that into
//! per-ray times (see [`crate::ld06`] and [`crate::rplidar`]).
//!
//! ```no_run
//! use std::time::Duration;
//! use vlsync_signature_lidar::ld06::{Ld06Config, Ld06Parser, BAUD};
//! use vlsync_signature_lidar::serial::{host_clock_ns, SerialLidar};
//! let mut port = SerialLidar::open("/dev/ttyUSB0", BAUD, Duration::from_millis(50))?;
//! let mut parser = Ld06Parser::new(Ld06Config::default());
//! port.pump(&mut parser, Duration::from_secs(1), &host_clock_ns, &mut |scan| {
//!     println!("{} rays", scan.len());
//! })?;
//! # Ok::<(), vlsync_signature_lidar::serial::SerialError>(())
//! ```

use crate::ld06::Ld06Parser;
use crate::rplidar::RplidarParser;
use crate::scan::Scan;
use std::fmt;
use std::io::{self, Read, Write};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use vlsync_common::Nanos;

/// Bits on the line per byte (8N1: start, 8 data, stop): a byte's wire time is
/// `10 / baud` s.
pub const BITS_PER_BYTE: u32 = 10;

/// A byte-stream parser that yields scans.
pub trait ScanParser {
    /// Pushes a chunk received at host time `rx_ns` (time of its last byte).
    fn push_bytes(&mut self, bytes: &[u8], rx_ns: Nanos, on_scan: &mut dyn FnMut(&Scan));
    /// Emits the scan in progress, if any.
    fn finish_scans(&mut self, on_scan: &mut dyn FnMut(&Scan));
}

impl ScanParser for Ld06Parser {
    fn push_bytes(&mut self, bytes: &[u8], rx_ns: Nanos, on_scan: &mut dyn FnMut(&Scan)) {
        self.push(bytes, rx_ns, on_scan);
    }
    fn finish_scans(&mut self, on_scan: &mut dyn FnMut(&Scan)) {
        self.finish(on_scan);
    }
}

impl ScanParser for RplidarParser {
    fn push_bytes(&mut self, bytes: &[u8], rx_ns: Nanos, on_scan: &mut dyn FnMut(&Scan)) {
        self.push(bytes, rx_ns, on_scan);
    }
    fn finish_scans(&mut self, on_scan: &mut dyn FnMut(&Scan)) {
        self.finish(on_scan);
    }
}

/// Host wall-clock time (CLOCK_REALTIME), ns since the Unix epoch; 0 if the
/// clock is before 1970.
pub fn host_clock_ns() -> Nanos {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
        .unwrap_or(0)
}

/// What went wrong with a serial port.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SerialErrorKind {
    /// The device does not exist (or disappeared).
    NotFound,
    /// No permission to open the device.
    PermissionDenied,
    /// The device is in use by another process.
    Busy,
    /// A setting (e.g. the baud rate) was refused.
    InvalidSetting,
    /// Any other I/O error.
    Io,
}

/// A serial-port error naming the device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialError {
    /// Device path.
    pub path: String,
    /// Category.
    pub kind: SerialErrorKind,
    /// What was being done and the system's message.
    pub message: String,
}

impl fmt::Display for SerialError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "serial port {}: {}", self.path, self.message)
    }
}

impl std::error::Error for SerialError {}

fn open_error(path: &str, e: serialport::Error) -> SerialError {
    let exists = std::path::Path::new(path).exists();
    let (kind, hint) = match e.kind() {
        serialport::ErrorKind::Io(io::ErrorKind::NotFound) => (
            SerialErrorKind::NotFound,
            "device not found: is the LiDAR plugged in and the path right?",
        ),
        serialport::ErrorKind::Io(io::ErrorKind::PermissionDenied) => (
            SerialErrorKind::PermissionDenied,
            "permission denied: add the user to the `dialout` group or fix the device's mode",
        ),
        serialport::ErrorKind::NoDevice if !exists => (
            SerialErrorKind::NotFound,
            "device not found: is the LiDAR plugged in and the path right?",
        ),
        serialport::ErrorKind::NoDevice => (
            SerialErrorKind::Busy,
            "device busy: another process has it open",
        ),
        serialport::ErrorKind::InvalidInput => (
            SerialErrorKind::InvalidSetting,
            "setting refused by the device",
        ),
        _ if !exists => (
            SerialErrorKind::NotFound,
            "device not found: is the LiDAR plugged in and the path right?",
        ),
        _ => (SerialErrorKind::Io, "cannot open"),
    };
    SerialError {
        path: path.to_string(),
        kind,
        message: format!("{hint} ({})", e.description),
    }
}

/// An open serial port with a read buffer.
pub struct SerialLidar {
    port: Box<dyn serialport::SerialPort>,
    path: String,
    buf: Vec<u8>,
}

impl fmt::Debug for SerialLidar {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SerialLidar")
            .field("path", &self.path)
            .finish()
    }
}

impl SerialLidar {
    /// Opens `path` at `baud` (8N1, no flow control); reads wait at most
    /// `read_timeout` for data.
    pub fn open(path: &str, baud: u32, read_timeout: Duration) -> Result<Self, SerialError> {
        if baud == 0 {
            return Err(SerialError {
                path: path.to_string(),
                kind: SerialErrorKind::InvalidSetting,
                message: "baud rate 0".into(),
            });
        }
        let port = serialport::new(path, baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(read_timeout)
            .open()
            .map_err(|e| open_error(path, e))?;
        Ok(Self::from_port(port, path))
    }

    /// Wraps a port opened elsewhere; `path` names it in errors.
    pub fn from_port(port: Box<dyn serialport::SerialPort>, path: &str) -> Self {
        Self {
            port,
            path: path.to_string(),
            buf: vec![0; 4096],
        }
    }

    /// Device path.
    pub fn path(&self) -> &str {
        &self.path
    }

    fn io_error(&self, what: &str, e: io::Error) -> SerialError {
        let kind = match e.kind() {
            io::ErrorKind::NotFound => SerialErrorKind::NotFound,
            io::ErrorKind::PermissionDenied => SerialErrorKind::PermissionDenied,
            _ => SerialErrorKind::Io,
        };
        SerialError {
            path: self.path.clone(),
            kind,
            message: format!("{what}: {e}"),
        }
    }

    /// Sets the DTR line (`true`: asserted). The USB adapter of the RPLIDAR A1/A2
    /// drives the motor from it: asserted stops the motor, released spins it
    /// (Linux asserts DTR when a port opens). A port without modem lines (a pty)
    /// refuses; the caller decides whether that matters.
    pub fn set_dtr(&mut self, asserted: bool) -> Result<(), SerialError> {
        self.port
            .write_data_terminal_ready(asserted)
            .map_err(|e| SerialError {
                path: self.path.clone(),
                kind: SerialErrorKind::Io,
                message: format!("set DTR {}: {e}", if asserted { "on" } else { "off" }),
            })
    }

    /// Writes a request (e.g. [`crate::rplidar::SCAN_REQUEST`]).
    pub fn write_request(&mut self, bytes: &[u8]) -> Result<(), SerialError> {
        self.port
            .write_all(bytes)
            .and_then(|_| self.port.flush())
            .map_err(|e| self.io_error("write failed", e))
    }

    /// Reads one chunk; returns it with the host time `clock()` taken right
    /// after the read. A read timeout yields an empty chunk.
    pub fn read_chunk(&mut self, clock: &dyn Fn() -> Nanos) -> Result<(&[u8], Nanos), SerialError> {
        match self.port.read(&mut self.buf) {
            Ok(n) => {
                let t = clock();
                Ok((&self.buf[..n], t))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut
                        | io::ErrorKind::WouldBlock
                        | io::ErrorKind::Interrupted
                ) =>
            {
                Ok((&self.buf[..0], clock()))
            }
            Err(e) => Err(self.io_error("read failed", e)),
        }
    }
}

impl crate::rplidar_start::Link for SerialLidar {
    fn send(&mut self, bytes: &[u8]) -> Result<(), String> {
        self.write_request(bytes).map_err(|e| e.to_string())
    }

    fn receive(&mut self, into: &mut Vec<u8>) -> Result<(), String> {
        let (chunk, _) = self.read_chunk(&host_clock_ns).map_err(|e| e.to_string())?;
        into.extend_from_slice(chunk);
        Ok(())
    }

    fn pause(&mut self, d: Duration) {
        std::thread::sleep(d);
    }
}

impl SerialLidar {
    /// Reads for `duration`, pushing every chunk into `parser` and calling
    /// `on_scan` for each scan. Returns the number of bytes read.
    pub fn pump(
        &mut self,
        parser: &mut dyn ScanParser,
        duration: Duration,
        clock: &dyn Fn() -> Nanos,
        on_scan: &mut dyn FnMut(&Scan),
    ) -> Result<u64, SerialError> {
        let deadline = Instant::now() + duration;
        let mut total = 0u64;
        while Instant::now() < deadline {
            let (chunk, t) = self.read_chunk(clock)?;
            total += chunk.len() as u64;
            parser.push_bytes(chunk, t, on_scan);
        }
        Ok(total)
    }
}

/// Host clock: the time (ns) from the measurement of a packet's (or node's) last point
/// to the arrival of the last byte of its chunk, `bytes_after` bytes later. Units of
/// `unit_len` bytes leave one every `interval_ns`, each `unit_len · byte_ns` long on the
/// wire, after their last point is measured: a chunk ending with a whole unit ends
/// `whole` intervals on plus that unit's wire time; one ending `part` bytes into the
/// unit after the whole ones, one interval more plus those bytes.
pub(crate) fn wire_shift_ns(
    bytes_after: usize,
    unit_len: usize,
    interval_ns: f64,
    byte_ns: f64,
) -> i64 {
    let unit_len = unit_len.max(1);
    let (whole, part) = (bytes_after / unit_len, bytes_after % unit_len);
    let shift = if part == 0 {
        whole as f64 * interval_ns + unit_len as f64 * byte_ns
    } else {
        (whole + 1) as f64 * interval_ns + part as f64 * byte_ns
    };
    shift.round() as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_device_is_named() {
        let e = SerialLidar::open(
            "/dev/does-not-exist-vlsync",
            230_400,
            Duration::from_millis(10),
        )
        .unwrap_err();
        assert_eq!(e.kind, SerialErrorKind::NotFound);
        let s = e.to_string();
        assert!(
            s.starts_with("serial port /dev/does-not-exist-vlsync: device not found"),
            "{s}"
        );
    }

    #[test]
    fn zero_baud_refused() {
        let e = SerialLidar::open("/dev/null", 0, Duration::from_millis(10)).unwrap_err();
        assert_eq!(e.kind, SerialErrorKind::InvalidSetting);
    }

    #[test]
    fn host_clock_is_after_2020() {
        assert!(host_clock_ns() > 1_577_836_800 * 1_000_000_000);
    }
}
