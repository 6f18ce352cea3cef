//! LiDAR signature for vlsync: the robust rate of change of the distance to a
//! wall in a narrow bearing window, one [`vlsync_common::Sample`] per rotation.
//!
//! * [`scan`]: rays with per-ray measurement times, scan timing and the
//!   bearing / rotation conventions.
//! * [`signature`]: the allocation-free signature processor (median distance
//!   per window pass, derivative stamped at the midpoint, gap resets, drop
//!   counters).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod csv;
pub mod encode;
pub mod ld06;
pub mod rplidar;
pub mod scan;
pub mod serial;
pub mod signature;

pub use scan::{Ray, Rotation, Scan, ScanTiming};
pub use signature::{
    ConfigError, Counters, DropReason, Measurement, SignatureConfig, SignatureProcessor, Stamping,
};
