//! LiDAR signature for vlsync: the robust rate of change of the distance to a
//! wall in a bearing window, one [`vlsync_common::Sample`] (m/s) per
//! rotation, stamped at the midpoint of the two measurements it differences.
//!
//! * [`scan`]: rays with per-ray measurement times, scan timing, and the
//!   bearing (CCW positive) and rotation-direction conventions.
//! * [`signature`]: the allocation-free signature processor (per pass of the
//!   beam through the window, the perpendicular distance to the wall fitted to
//!   the returns, or their median; the time of the returns used; derivative
//!   stamped at the midpoint; gap resets; implausible and cross-surface
//!   derivatives dropped; drop counters).
//! * [`opposite`]: the window and the one opposite it (the wall behind), merged
//!   into one stream.
//! * [`ld06`]: LDROBOT LD06/LD19 packets (CRC-8 0x4D), resynchronising decoder,
//!   360° scan assembly with per-point times, encoder.
//! * [`rplidar`]: Slamtec RPLIDAR standard scan (A1/A2/C1): requests,
//!   resynchronising node parser, scan assembly, encoder.
//! * [`rplidar_start`]: the RPLIDAR's start sequence as Slamtec's SDK runs it
//!   (stop, health and reset, the A2's motor PWM, scan).
//! * [`csv`]: scans as CSV, one row per ray, with exact decimal-second times.
//! * [`serial`]: opening a serial port and pumping its bytes into a parser.
//! * [`encode`]: byte-stream encoders for simulators and tests.
//!
//! ```
//! use vlsync_signature_lidar::encode::ld06_stream;
//! use vlsync_signature_lidar::ld06::{Ld06Clock, Ld06Config, Ld06Parser};
//! use vlsync_signature_lidar::{SignatureConfig, SignatureProcessor};
//!
//! // a flat wall on the left (normal at bearing +90°) receding at 0.5 m/s, seen by
//! // an LD06 at 10 Hz
//! let bytes = ld06_stream(3600, 0, 1.0, |t, bearing| {
//!     let off = bearing - std::f64::consts::FRAC_PI_2;
//!     if off.abs() < 0.6 { (2.0 + 0.5 * t) / off.cos() } else { 6.0 }
//! });
//! let mut parser = Ld06Parser::new(Ld06Config { clock: Ld06Clock::Device, ..Default::default() });
//! let mut sig = SignatureProcessor::new(SignatureConfig {
//!     window_centre_rad: std::f64::consts::FRAC_PI_2,
//!     ..Default::default()
//! }).unwrap();
//! let mut samples = Vec::new();
//! parser.push(&bytes, 0, |scan| { sig.push_scan(scan, |s| samples.push(s)); });
//! assert!(samples.len() >= 7);
//! assert!(samples.iter().all(|s| (s.value - 0.5).abs() < 0.02));
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod csv;
pub mod encode;
pub mod ld06;
pub mod opposite;
pub mod rplidar;
pub mod rplidar_start;
pub mod scan;
pub mod serial;
pub mod signature;

pub use opposite::{OppositeWindows, WallFront};
pub use scan::{Ray, Rotation, Scan, ScanTiming};
pub use signature::{
    ConfigError, Counters, DropReason, Measurement, SignatureConfig, SignatureProcessor, Stamping,
};
