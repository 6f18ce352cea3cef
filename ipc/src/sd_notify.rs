//! systemd service notifications (the `sd_notify` protocol) without libsystemd:
//! the daemon's and the drivers' side of the service manager.
//!
//! systemd passes `NOTIFY_SOCKET` (a filesystem path, or `@name` for a socket in
//! the abstract namespace) to a `Type=notify` service, and to any service with
//! `WatchdogSec=` or `NotifyAccess=`; the service sends newline-separated
//! `KEY=VALUE` datagrams to it:
//!
//! * `READY=1` once it serves (the daemon: services open and the real-time thread
//!   running; a driver: publishing);
//! * `STATUS=...` a human line (`systemctl status` shows it);
//! * `WATCHDOG=1` at half of `WATCHDOG_USEC` (`WatchdogSec=` of the unit), sent only
//!   while the process shows progress: the daemon's service thread pets while the
//!   real-time thread's heartbeat moves (`vlsyncd`'s `runtime::notify`), a driver
//!   from its stop check, which every wait and every sample of its loop makes
//!   (`vlsync_driver::watchdog`); a process stuck in a call that does not return
//!   stops petting and systemd restarts it;
//! * `STOPPING=1` when shutting down.
//!
//! Without `NOTIFY_SOCKET` every call is a no-op. `WATCHDOG_PID`, when set, must
//! name this process or the watchdog stays off (systemd's rule for processes
//! that inherited the variables).

use std::ffi::OsStr;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::time::Duration;

/// The longest `sun_path` of a Unix socket address on Linux (without the NUL).
const MAX_SOCKET_PATH: usize = 107;

/// Where notifications go; `None` inside when `NOTIFY_SOCKET` is unset.
#[derive(Debug)]
pub struct SdNotify {
    target: Option<(UnixDatagram, SocketAddr, String)>,
    watchdog: Option<Duration>,
}

impl SdNotify {
    /// A notifier that sends nothing (no `NOTIFY_SOCKET`).
    pub fn disabled() -> Self {
        Self {
            target: None,
            watchdog: None,
        }
    }

    /// From the process environment (`NOTIFY_SOCKET`, `WATCHDOG_USEC`,
    /// `WATCHDOG_PID`). Returns the notifier and the problems found (each a
    /// sentence naming the variable and its value); a problem disables only the
    /// part it concerns.
    pub fn from_env() -> (Self, Vec<String>) {
        let socket = std::env::var_os("NOTIFY_SOCKET");
        let usec = std::env::var_os("WATCHDOG_USEC");
        let pid = std::env::var_os("WATCHDOG_PID");
        Self::from_values(
            socket.as_deref(),
            usec.as_deref(),
            pid.as_deref(),
            std::process::id(),
        )
    }

    /// Like [`SdNotify::from_env`] with explicit values; `own_pid` is this process.
    pub fn from_values(
        socket: Option<&OsStr>,
        watchdog_usec: Option<&OsStr>,
        watchdog_pid: Option<&OsStr>,
        own_pid: u32,
    ) -> (Self, Vec<String>) {
        let mut problems = vec![];
        let target = match socket.filter(|s| !s.is_empty()) {
            None => None,
            Some(s) => match connect_target(s) {
                Ok(t) => Some(t),
                Err(e) => {
                    problems.push(e);
                    None
                }
            },
        };
        let watchdog = match (target.is_some(), watchdog_usec) {
            (false, _) | (true, None) => None,
            (true, Some(usec)) => match watchdog_period(usec, watchdog_pid, own_pid) {
                Ok(p) => p,
                Err(e) => {
                    problems.push(e);
                    None
                }
            },
        };
        (Self { target, watchdog }, problems)
    }

    /// True when notifications are sent somewhere.
    pub fn enabled(&self) -> bool {
        self.target.is_some()
    }

    /// How often to send `WATCHDOG=1`: half of `WATCHDOG_USEC`; `None` when the
    /// watchdog is off.
    pub fn watchdog_period(&self) -> Option<Duration> {
        self.watchdog
    }

    /// Sends `msg` (one or more `KEY=VALUE` lines). A no-op when disabled.
    pub fn send(&self, msg: &str) -> Result<(), String> {
        let Some((sock, addr, shown)) = &self.target else {
            return Ok(());
        };
        match sock.send_to_addr(msg.as_bytes(), addr) {
            Ok(n) if n == msg.len() => Ok(()),
            Ok(n) => Err(format!(
                "notification to NOTIFY_SOCKET {shown} truncated ({n} of {} bytes)",
                msg.len()
            )),
            Err(e) => Err(format!("cannot notify NOTIFY_SOCKET {shown}: {e}")),
        }
    }

    /// `READY=1` (with a status line).
    pub fn ready(&self, status: &str) -> Result<(), String> {
        self.send(&format!("READY=1\nSTATUS={}", one_line(status)))
    }

    /// `STATUS=<line>`.
    pub fn status(&self, status: &str) -> Result<(), String> {
        self.send(&format!("STATUS={}", one_line(status)))
    }

    /// `WATCHDOG=1`.
    pub fn watchdog(&self) -> Result<(), String> {
        self.send("WATCHDOG=1")
    }

    /// `STOPPING=1` (with a status line).
    pub fn stopping(&self, status: &str) -> Result<(), String> {
        self.send(&format!("STOPPING=1\nSTATUS={}", one_line(status)))
    }
}

/// A status text on one line (a newline would start a new assignment).
fn one_line(s: &str) -> String {
    s.replace(['\n', '\r'], " ")
}

fn connect_target(s: &OsStr) -> Result<(UnixDatagram, SocketAddr, String), String> {
    let shown = s.to_string_lossy().into_owned();
    let bytes = s.as_bytes();
    let addr = match bytes.first() {
        Some(b'@') => abstract_addr(&bytes[1..]).map_err(|e| {
            format!("NOTIFY_SOCKET={shown:?}: not a usable abstract socket name: {e}")
        })?,
        Some(b'/') => {
            if bytes.len() > MAX_SOCKET_PATH {
                return Err(format!(
                    "NOTIFY_SOCKET={shown:?}: path longer than {MAX_SOCKET_PATH} bytes"
                ));
            }
            SocketAddr::from_pathname(std::path::Path::new(s))
                .map_err(|e| format!("NOTIFY_SOCKET={shown:?}: not a usable socket path: {e}"))?
        }
        _ => {
            return Err(format!(
                "NOTIFY_SOCKET={shown:?}: neither an absolute path nor an abstract name (@...)"
            ))
        }
    };
    let sock = UnixDatagram::unbound()
        .map_err(|e| format!("cannot create a socket for NOTIFY_SOCKET={shown:?}: {e}"))?;
    Ok((sock, addr, shown))
}

#[cfg(any(target_os = "linux", target_os = "android"))]
fn abstract_addr(name: &[u8]) -> std::io::Result<SocketAddr> {
    #[cfg(target_os = "android")]
    use std::os::android::net::SocketAddrExt;
    #[cfg(target_os = "linux")]
    use std::os::linux::net::SocketAddrExt;
    SocketAddr::from_abstract_name(name)
}

#[cfg(not(any(target_os = "linux", target_os = "android")))]
fn abstract_addr(_name: &[u8]) -> std::io::Result<SocketAddr> {
    Err(std::io::Error::new(
        std::io::ErrorKind::Unsupported,
        "abstract Unix sockets exist only on Linux",
    ))
}

fn watchdog_period(
    usec: &OsStr,
    pid: Option<&OsStr>,
    own_pid: u32,
) -> Result<Option<Duration>, String> {
    if let Some(pid) = pid.filter(|p| !p.is_empty()) {
        let text = pid.to_string_lossy();
        match text.trim().parse::<u32>() {
            Ok(p) if p == own_pid => {}
            // the variables were inherited from another process: not ours
            Ok(_) => return Ok(None),
            Err(_) => return Err(format!("WATCHDOG_PID={text:?} is not a process id")),
        }
    }
    let text = usec.to_string_lossy();
    match text.trim().parse::<u64>() {
        Ok(0) => Err("WATCHDOG_USEC=0: the watchdog interval must be positive".into()),
        Ok(u) => Ok(Some(Duration::from_micros(u) / 2)),
        Err(_) => Err(format!(
            "WATCHDOG_USEC={text:?} is not a number of microseconds"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsString;

    fn os(s: &str) -> OsString {
        OsString::from(s)
    }

    #[test]
    fn unset_socket_is_a_silent_no_op() {
        let (n, problems) = SdNotify::from_values(None, Some(&os("1000000")), None, 1);
        assert!(problems.is_empty());
        assert!(!n.enabled());
        assert_eq!(n.watchdog_period(), None);
        n.ready("x").unwrap();
        n.watchdog().unwrap();
        n.stopping("x").unwrap();
    }

    #[test]
    fn path_socket_receives_every_message() {
        let dir = std::env::temp_dir().join(format!("vlsync-notify-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("notify.sock");
        let _ = std::fs::remove_file(&path);
        let rx = UnixDatagram::bind(&path).unwrap();
        rx.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        let (n, problems) = SdNotify::from_values(Some(path.as_os_str()), None, None, 1);
        assert!(problems.is_empty(), "{problems:?}");
        assert!(n.enabled());
        let mut buf = [0u8; 256];
        n.ready("serving\nprefix").unwrap();
        let k = rx.recv(&mut buf).unwrap();
        assert_eq!(&buf[..k], b"READY=1\nSTATUS=serving prefix");
        n.watchdog().unwrap();
        let k = rx.recv(&mut buf).unwrap();
        assert_eq!(&buf[..k], b"WATCHDOG=1");
        n.stopping("bye").unwrap();
        let k = rx.recv(&mut buf).unwrap();
        assert_eq!(&buf[..k], b"STOPPING=1\nSTATUS=bye");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn abstract_socket_names_work() {
        use std::os::linux::net::SocketAddrExt;
        let name = format!("vlsync-notify-unit-{}", std::process::id());
        let rx = UnixDatagram::bind_addr(&SocketAddr::from_abstract_name(name.as_bytes()).unwrap())
            .unwrap();
        rx.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        let (n, problems) = SdNotify::from_values(Some(&os(&format!("@{name}"))), None, None, 1);
        assert!(problems.is_empty(), "{problems:?}");
        n.status("hello").unwrap();
        let mut buf = [0u8; 64];
        let k = rx.recv(&mut buf).unwrap();
        assert_eq!(&buf[..k], b"STATUS=hello");
    }

    #[test]
    fn a_missing_listener_is_an_error_naming_the_socket() {
        let (n, _) = SdNotify::from_values(Some(&os("/nonexistent/vlsync/notify")), None, None, 1);
        let e = n.watchdog().unwrap_err();
        assert!(e.contains("/nonexistent/vlsync/notify"), "{e}");
    }

    #[test]
    fn bad_variables_are_reported_and_disable_only_their_part() {
        let (n, p) = SdNotify::from_values(Some(&os("relative/path")), None, None, 1);
        assert!(!n.enabled());
        assert!(
            p[0].contains("NOTIFY_SOCKET") && p[0].contains("relative/path"),
            "{p:?}"
        );
        let long = format!("/{}", "x".repeat(200));
        let (_, p) = SdNotify::from_values(Some(&os(&long)), None, None, 1);
        assert!(p[0].contains("longer than"), "{p:?}");

        let sock = os("@vlsync-notify-unit-unused");
        let (n, p) = SdNotify::from_values(Some(&sock), Some(&os("soon")), None, 1);
        assert!(n.enabled() && n.watchdog_period().is_none());
        assert!(
            p[0].contains("WATCHDOG_USEC") && p[0].contains("soon"),
            "{p:?}"
        );
        let (_, p) = SdNotify::from_values(Some(&sock), Some(&os("0")), None, 1);
        assert!(p[0].contains("WATCHDOG_USEC=0"), "{p:?}");
        let (_, p) = SdNotify::from_values(Some(&sock), Some(&os("100")), Some(&os("me")), 1);
        assert!(p[0].contains("WATCHDOG_PID"), "{p:?}");
    }

    #[test]
    fn watchdog_pid_must_be_ours() {
        let sock = os("@vlsync-notify-unit-unused");
        let usec = os("5000000");
        let (n, p) = SdNotify::from_values(Some(&sock), Some(&usec), Some(&os("42")), 42);
        assert!(p.is_empty());
        assert_eq!(n.watchdog_period(), Some(Duration::from_millis(2500)));
        let (n, p) = SdNotify::from_values(Some(&sock), Some(&usec), Some(&os("43")), 42);
        assert!(p.is_empty());
        assert_eq!(n.watchdog_period(), None);
        // no socket: no watchdog either
        let (n, _) = SdNotify::from_values(None, Some(&usec), None, 42);
        assert_eq!(n.watchdog_period(), None);
    }
}
