//! Live runs of the whole pipeline, shared by `vlsync-demo` and
//! `vlsync-loadtest`: [`session`] starts `vlsyncd run` and both drivers on a
//! unique prefix and records what the daemon publishes; [`truth`] is what the
//! estimates are scored against (a known model, or the offset the drivers
//! measured); [`load`] injects CPU load, memory pressure and driver stalls by
//! phase; [`report`] turns a load run into tables, JSON and a plot; [`stats`]
//! holds the small statistics they share; [`console`] is their standard output,
//! which a reader that goes away does not turn into a panic.

pub mod console;
pub mod load;
pub mod report;
pub mod session;
pub mod stats;
pub mod truth;

/// The real-time speed factors the live tools accept (`--speed`): the drivers'.
pub use vlsync_driver::cli::{MAX_SPEED, MIN_SPEED};

/// Checks a numeric command-line argument before anything is started or written:
/// finite and within `min ..= max`; the error names the flag.
///
/// ```
/// use vlsyncd::harness::check_arg;
/// assert_eq!(check_arg("--speed", 2.0, 0.01, 1000.0), Ok(2.0));
/// assert_eq!(
///     check_arg("--speed", 0.0, 0.01, 1000.0).unwrap_err(),
///     "--speed 0 is out of range: allowed 0.01 ..= 1000"
/// );
/// assert!(check_arg("--speed", f64::NAN, 0.01, 1000.0).is_err());
/// assert_eq!(
///     check_arg("--duration", 1e300, 1.0, 1e6).unwrap_err(),
///     "--duration 1e300 is out of range: allowed 1 ..= 1e6"
/// );
/// ```
pub fn check_arg(flag: &str, v: f64, min: f64, max: f64) -> Result<f64, String> {
    if v.is_finite() && (min..=max).contains(&v) {
        Ok(v)
    } else {
        // 1e300 as 1e300, not its 301 digits
        Err(format!(
            "{flag} {} is out of range: allowed {} ..= {}",
            vlsync_common::text::number(v),
            vlsync_common::text::number(min),
            vlsync_common::text::number(max)
        ))
    }
}
