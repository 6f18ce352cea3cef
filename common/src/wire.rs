//! Shared-memory payloads of the vlsync iceoryx2 services (feature `wire`).
//!
//! Every type here is `#[repr(C)]` with a fixed, documented layout, explicit
//! padding and an explicit iceoryx2 type name, so that C, C++ and Python
//! subscribers can open the same services (`examples/c/vlsync_wire.h` mirrors
//! all three layouts; `examples/python/vlsync_subscriber.py` mirrors
//! [`OffsetEstimate`], the one it reads). The layout
//! tests at the bottom pin size, alignment and every field offset: a change
//! that breaks them is an ABI change and must bump the `.vN` suffix of the
//! type name, so that old and new processes refuse to share a service instead
//! of misreading each other.
//!
//! Shared memory is written by other processes: every payload is hostile
//! input. [`SignatureSample::validate`], [`Status::validate`] and
//! `Estimate::try_from(&OffsetEstimate)` check every field before use.
//!
//! All `*_ns` fields are integer nanoseconds. `publish_ns` fields are on the
//! publishing host's `CLOCK_MONOTONIC` (the same clock for every process of
//! one machine), which makes end-to-end latency measurable across processes.

use crate::{Estimate, EstimatorState, Nanos, Polarity};
use iceoryx2::prelude::ZeroCopySend;
use std::fmt;

/// iceoryx2 type name of [`SignatureSample`].
pub const SIGNATURE_SAMPLE_TYPE_NAME: &str = "vlsync.SignatureSample.v1";
/// iceoryx2 type name of [`OffsetEstimate`].
pub const OFFSET_ESTIMATE_TYPE_NAME: &str = "vlsync.OffsetEstimate.v1";
/// iceoryx2 type name of [`Status`].
pub const STATUS_TYPE_NAME: &str = "vlsync.Status.v1";

/// [`SignatureSample::flags`] bit: the first sample a driver publishes after it
/// (re)started; its sequence number restarts and must not count as a gap.
pub const FLAG_FIRST: u32 = 1;
/// [`SignatureSample::flags`] bit: the sample comes from a simulator (the drivers'
/// `--sim` and `--render` sources), not from a sensor: an offset estimated from it is
/// not the robot's. The daemon says so in its log while such samples arrive.
pub const FLAG_SIMULATED: u32 = 2;
/// All flag bits defined in this version; any other bit makes a sample malformed.
pub const KNOWN_FLAGS: u32 = FLAG_FIRST | FLAG_SIMULATED;

/// One signature sample on the wire (`<prefix>/cam/signature`, `<prefix>/lidar/signature`).
///
/// Layout (size 40, alignment 8):
///
/// | offset | field        | type |
/// |-------:|--------------|------|
/// | 0      | `t_ns`       | i64  |
/// | 8      | `value`      | f64  |
/// | 16     | `seq`        | u64  |
/// | 24     | `publish_ns` | i64  |
/// | 32     | `flags`      | u32  |
/// | 36     | `reserved`   | u32 (must be 0) |
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("vlsync.SignatureSample.v1")]
#[repr(C)]
pub struct SignatureSample {
    /// Timestamp on the producing sensor's clock, ns.
    pub t_ns: i64,
    /// Signature value.
    pub value: f64,
    /// Per-driver sequence number: 0 for the first sample after the driver
    /// started, +1 per sample. A jump counts as lost samples.
    pub seq: u64,
    /// When the driver published the sample, `CLOCK_MONOTONIC` ns.
    pub publish_ns: i64,
    /// Bit set of `FLAG_*`.
    pub flags: u32,
    /// Explicit padding; must be zero.
    pub reserved: u32,
}

/// Why a wire payload was refused before it reached the estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireError {
    /// A flag bit outside [`KNOWN_FLAGS`] was set.
    UnknownFlags {
        /// The offending flags.
        flags: u32,
    },
    /// A padding/reserved field was not zero (likely a layout mismatch).
    NonZeroPadding {
        /// The field name.
        field: &'static str,
    },
    /// A field that must be finite was NaN or infinite.
    NonFinite {
        /// The field name.
        field: &'static str,
    },
    /// A field was outside its allowed range.
    OutOfRange {
        /// The field name.
        field: &'static str,
    },
    /// Unknown estimator state code.
    UnknownState {
        /// The code.
        code: u8,
    },
    /// Unknown polarity code.
    UnknownPolarity {
        /// The code.
        code: i8,
    },
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WireError::UnknownFlags { flags } => {
                write!(
                    f,
                    "unknown flag bits {:#x} (known: {KNOWN_FLAGS:#x})",
                    flags & !KNOWN_FLAGS
                )
            }
            WireError::NonZeroPadding { field } => {
                write!(f, "padding field `{field}` is not zero (layout mismatch?)")
            }
            WireError::NonFinite { field } => write!(f, "field `{field}` is not finite"),
            WireError::OutOfRange { field } => write!(f, "field `{field}` is out of range"),
            WireError::UnknownState { code } => write!(f, "unknown estimator state code {code}"),
            WireError::UnknownPolarity { code } => write!(f, "unknown polarity code {code}"),
        }
    }
}

impl std::error::Error for WireError {}

impl SignatureSample {
    /// A sample with no flags.
    pub fn new(t_ns: Nanos, value: f64, seq: u64, publish_ns: Nanos) -> Self {
        Self {
            t_ns,
            value,
            seq,
            publish_ns,
            flags: 0,
            reserved: 0,
        }
    }

    /// Structural checks of a received payload: known flags, zero padding.
    /// The value itself (NaN, magnitude) and the time order are the
    /// estimator's to judge, so they are counted under its [`crate::RejectReason`]s.
    pub fn validate(&self) -> Result<(), WireError> {
        if self.flags & !KNOWN_FLAGS != 0 {
            return Err(WireError::UnknownFlags { flags: self.flags });
        }
        if self.reserved != 0 {
            return Err(WireError::NonZeroPadding { field: "reserved" });
        }
        Ok(())
    }

    /// True when [`FLAG_SIMULATED`] is set.
    pub fn is_simulated(&self) -> bool {
        self.flags & FLAG_SIMULATED != 0
    }

    /// True when [`FLAG_FIRST`] is set.
    pub fn is_first(&self) -> bool {
        self.flags & FLAG_FIRST != 0
    }

    /// The estimator sample.
    pub fn sample(&self) -> crate::Sample {
        crate::Sample::new(self.t_ns, self.value)
    }
}

/// One offset estimate on the wire (`<prefix>/offset`): every field of
/// [`Estimate`] plus the daemon's publish time.
///
/// Layout (size 88, alignment 8):
///
/// | offset | field               | type |
/// |-------:|---------------------|------|
/// | 0      | `seq`               | u64  |
/// | 8      | `t_ref_ns`          | i64  |
/// | 16     | `offset_s`          | f64  |
/// | 24     | `drift`             | f64  |
/// | 32     | `offset_std_s`      | f64  |
/// | 40     | `drift_std`         | f64  |
/// | 48     | `peak_score`        | f64  |
/// | 56     | `peak_ratio`        | f64 (may be +inf) |
/// | 64     | `measured_offset_s` | f64 (NaN when none) |
/// | 72     | `publish_ns`        | i64  |
/// | 80     | `state`             | u8: 0 acquiring, 1 tracking, 2 holding, 3 lost |
/// | 81     | `polarity`          | i8: 0 unknown, 1 positive, -1 negative |
/// | 82     | `reserved`          | [u8; 6] (must be 0) |
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("vlsync.OffsetEstimate.v1")]
#[repr(C)]
pub struct OffsetEstimate {
    /// Estimate sequence number.
    pub seq: u64,
    /// Reference time on the LiDAR clock, ns.
    pub t_ref_ns: i64,
    /// `t_L - t_C` at `t_ref_ns`, seconds.
    pub offset_s: f64,
    /// `d offset / d t_L`.
    pub drift: f64,
    /// One standard deviation of `offset_s`, seconds.
    pub offset_std_s: f64,
    /// One standard deviation of `drift`.
    pub drift_std: f64,
    /// Normalised correlation at the peak.
    pub peak_score: f64,
    /// Main-to-second peak ratio (`+inf` when there is no second peak).
    pub peak_ratio: f64,
    /// Raw measurement of this hop, seconds; NaN when none.
    pub measured_offset_s: f64,
    /// When the daemon published it, `CLOCK_MONOTONIC` ns.
    pub publish_ns: i64,
    /// [`EstimatorState`] code.
    pub state: u8,
    /// [`Polarity`] code.
    pub polarity: i8,
    /// Explicit padding; must be zero.
    pub reserved: [u8; 6],
}

fn finite(v: f64, field: &'static str) -> Result<(), WireError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(WireError::NonFinite { field })
    }
}

fn finite_non_negative(v: f64, field: &'static str) -> Result<(), WireError> {
    finite(v, field)?;
    if v < 0.0 {
        return Err(WireError::OutOfRange { field });
    }
    Ok(())
}

/// Checks the fields of an estimate that have constraints:
/// offset, drift and both standard deviations finite (deviations >= 0),
/// `peak_score` finite, `peak_ratio` >= 0 and not NaN (`+inf` allowed),
/// `measured_offset_s` finite or NaN (not infinite).
fn check_estimate(e: &Estimate) -> Result<(), WireError> {
    finite(e.offset_s, "offset_s")?;
    finite(e.drift, "drift")?;
    finite_non_negative(e.offset_std_s, "offset_std_s")?;
    finite_non_negative(e.drift_std, "drift_std")?;
    finite(e.peak_score, "peak_score")?;
    if e.peak_ratio.is_nan() {
        return Err(WireError::NonFinite {
            field: "peak_ratio",
        });
    }
    if e.peak_ratio < 0.0 {
        return Err(WireError::OutOfRange {
            field: "peak_ratio",
        });
    }
    if e.measured_offset_s.is_infinite() {
        return Err(WireError::NonFinite {
            field: "measured_offset_s",
        });
    }
    Ok(())
}

impl OffsetEstimate {
    /// Builds the wire form of `e`, stamped `publish_ns`. Fails if `e` has a
    /// field no subscriber would accept (see [`Estimate`]'s documented ranges).
    pub fn from_estimate(e: &Estimate, publish_ns: Nanos) -> Result<Self, WireError> {
        check_estimate(e)?;
        Ok(Self {
            seq: e.seq,
            t_ref_ns: e.t_ref_ns,
            offset_s: e.offset_s,
            drift: e.drift,
            offset_std_s: e.offset_std_s,
            drift_std: e.drift_std,
            peak_score: e.peak_score,
            peak_ratio: e.peak_ratio,
            measured_offset_s: e.measured_offset_s,
            publish_ns,
            state: e.state as u8,
            polarity: e.polarity as i8,
            reserved: [0; 6],
        })
    }
}

impl TryFrom<&OffsetEstimate> for Estimate {
    type Error = WireError;

    /// Validates every field of a received estimate.
    fn try_from(w: &OffsetEstimate) -> Result<Self, WireError> {
        let state =
            EstimatorState::from_code(w.state).ok_or(WireError::UnknownState { code: w.state })?;
        let polarity = Polarity::from_code(w.polarity)
            .ok_or(WireError::UnknownPolarity { code: w.polarity })?;
        if w.reserved != [0; 6] {
            return Err(WireError::NonZeroPadding { field: "reserved" });
        }
        let e = Estimate {
            seq: w.seq,
            t_ref_ns: w.t_ref_ns,
            offset_s: w.offset_s,
            drift: w.drift,
            offset_std_s: w.offset_std_s,
            drift_std: w.drift_std,
            state,
            polarity,
            peak_score: w.peak_score,
            peak_ratio: w.peak_ratio,
            measured_offset_s: w.measured_offset_s,
        };
        check_estimate(&e)?;
        Ok(e)
    }
}

impl TryFrom<&Estimate> for OffsetEstimate {
    type Error = WireError;

    /// Like [`OffsetEstimate::from_estimate`] with `publish_ns = 0`.
    fn try_from(e: &Estimate) -> Result<Self, WireError> {
        OffsetEstimate::from_estimate(e, 0)
    }
}

/// Number of reject reasons counted in [`Status::rejected`]: the four
/// [`crate::RejectReason`]s (by [`crate::RejectReason::index`]) then [`REJECT_MALFORMED`].
pub const REJECT_REASONS: usize = 5;
/// Index in [`Status::rejected`] of samples refused by [`SignatureSample::validate`].
pub const REJECT_MALFORMED: usize = 4;
/// Name of each [`Status::rejected`] column.
pub const REJECT_NAMES: [&str; REJECT_REASONS] = [
    "non_finite",
    "too_large",
    "backwards",
    "repeated",
    "malformed",
];
/// [`Status::state`] before the first estimate.
pub const STATE_NONE: u8 = 0xFF;

/// Daemon counters on the wire (`<prefix>/status`), published every
/// `daemon.status_period_s`. Per-stream arrays are indexed 0 = cam, 1 = lidar.
/// Latency arrays hold `[p50, p99, max]` in ns, since the daemon started, or with
/// `daemon.latency_per_period = true` over the last status period only (the
/// histograms restart after each status). `latency_count` is how many end-to-end
/// measurements `end_to_end_ns` covers: the samples whose driver publish time gave
/// a latency (within 10 s before the daemon was done with them). `processing_ns`
/// covers every sample that passed validation, which may be more (a publisher that
/// leaves `publish_ns` 0, another host's clock). Percentiles are bucket upper bounds of a
/// fixed log-linear histogram, within 1/16 of the true value.
///
/// Layout (size 224, alignment 8):
///
/// | offset | field                 | type |
/// |-------:|-----------------------|------|
/// | 0      | `uptime_ns`           | i64 |
/// | 8      | `publish_ns`          | i64 |
/// | 16     | `received`            | [u64; 2] |
/// | 32     | `rejected`            | [[u64; 5]; 2] |
/// | 112    | `lost`                | [u64; 2] |
/// | 128    | `budget_overruns`     | u64 |
/// | 136    | `estimates_published` | u64 |
/// | 144    | `events_dropped`      | u64 |
/// | 152    | `processing_ns`       | [u64; 3] |
/// | 176    | `end_to_end_ns`       | [u64; 3] |
/// | 200    | `latency_count`       | u64 |
/// | 208    | `state`               | u8 ([`STATE_NONE`] before the first estimate) |
/// | 209    | `degraded`            | u8 (0 or 1) |
/// | 210    | `reserved`            | [u8; 14] (must be 0) |
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("vlsync.Status.v1")]
#[repr(C)]
pub struct Status {
    /// Time since the daemon started, ns.
    pub uptime_ns: i64,
    /// When this status was published, `CLOCK_MONOTONIC` ns.
    pub publish_ns: i64,
    /// Samples received per stream (including rejected ones).
    pub received: [u64; 2],
    /// Rejected samples per stream and reason (see [`REJECT_NAMES`]).
    pub rejected: [[u64; REJECT_REASONS]; 2],
    /// Samples lost per stream (sequence gaps).
    pub lost: [u64; 2],
    /// Samples whose processing exceeded `daemon.latency_budget_us`.
    pub budget_overruns: u64,
    /// Estimates published on `<prefix>/offset`.
    pub estimates_published: u64,
    /// Events the real-time thread could not hand to the logging thread.
    pub events_dropped: u64,
    /// Processing time per sample: from the sample's turn in the publish-order merge
    /// (after `receive`) to the daemon done with it (validated, in the estimator, its
    /// estimate published if one was due), `[p50, p99, max]` ns.
    pub processing_ns: [u64; 3],
    /// Sample publish (driver) to the daemon done with that sample (its estimate
    /// published if one was due), `[p50, p99, max]` ns.
    pub end_to_end_ns: [u64; 3],
    /// Number of end-to-end latency measurements (`end_to_end_ns`'s; `processing_ns`
    /// may cover more samples).
    pub latency_count: u64,
    /// State of the last published estimate, or [`STATE_NONE`].
    pub state: u8,
    /// 1 while the estimator runs degraded (over budget), else 0.
    pub degraded: u8,
    /// Explicit padding; must be zero.
    pub reserved: [u8; 14],
}

impl Default for Status {
    fn default() -> Self {
        Self {
            uptime_ns: 0,
            publish_ns: 0,
            received: [0; 2],
            rejected: [[0; REJECT_REASONS]; 2],
            lost: [0; 2],
            budget_overruns: 0,
            estimates_published: 0,
            events_dropped: 0,
            processing_ns: [0; 3],
            end_to_end_ns: [0; 3],
            latency_count: 0,
            state: STATE_NONE,
            degraded: 0,
            reserved: [0; 14],
        }
    }
}

impl Status {
    /// Checks a received status: known state code, boolean `degraded`, zero padding,
    /// non-negative times, ordered percentiles.
    pub fn validate(&self) -> Result<(), WireError> {
        if self.state != STATE_NONE && EstimatorState::from_code(self.state).is_none() {
            return Err(WireError::UnknownState { code: self.state });
        }
        if self.degraded > 1 {
            return Err(WireError::OutOfRange { field: "degraded" });
        }
        if self.reserved != [0; 14] {
            return Err(WireError::NonZeroPadding { field: "reserved" });
        }
        if self.uptime_ns < 0 {
            return Err(WireError::OutOfRange { field: "uptime_ns" });
        }
        if self.publish_ns < 0 {
            return Err(WireError::OutOfRange {
                field: "publish_ns",
            });
        }
        for (name, l) in [
            ("processing_ns", &self.processing_ns),
            ("end_to_end_ns", &self.end_to_end_ns),
        ] {
            if !(l[0] <= l[1] && l[1] <= l[2]) {
                return Err(WireError::OutOfRange { field: name });
            }
        }
        Ok(())
    }

    /// The state of the last estimate, `None` before the first one.
    pub fn estimator_state(&self) -> Option<EstimatorState> {
        EstimatorState::from_code(self.state)
    }

    /// Total rejected samples of stream index `i` (0 cam, 1 lidar).
    pub fn rejected_total(&self, i: usize) -> u64 {
        self.rejected
            .get(i)
            .map_or(0, |r| r.iter().fold(0u64, |a, &x| a.saturating_add(x)))
    }
}

/// One readable line (what `vlsync-echo --status` prints): uptime, state, per
/// stream received / rejected (by reason, when any) / lost, estimates, budget
/// overruns, latency percentiles in µs.
///
/// ```
/// use vlsync_common::wire::Status;
/// let mut s = Status { uptime_ns: 12_500_000_000, received: [375, 125], ..Status::default() };
/// s.rejected[0][2] = 3; // camera samples that went backwards
/// let line = s.to_string();
/// assert!(line.starts_with("up 12.5 s  state none  cam 375 received, 3 rejected (backwards 3), 0 lost"));
/// ```
impl core::fmt::Display for Status {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let state = self.estimator_state().map_or("none", |s| s.name());
        write!(f, "up {:.1} s  state {state}", self.uptime_ns as f64 * 1e-9)?;
        if self.degraded == 1 {
            write!(f, " (degraded)")?;
        }
        for (i, name) in ["cam", "lidar"].iter().enumerate() {
            write!(
                f,
                "  {name} {} received, {} rejected",
                self.received[i],
                self.rejected_total(i)
            )?;
            if self.rejected_total(i) > 0 {
                let mut sep = " (";
                for (r, n) in REJECT_NAMES.iter().enumerate() {
                    if self.rejected[i][r] > 0 {
                        write!(f, "{sep}{n} {}", self.rejected[i][r])?;
                        sep = ", ";
                    }
                }
                write!(f, ")")?;
            }
            write!(f, ", {} lost", self.lost[i])?;
        }
        let us = |v: u64| v as f64 * 1e-3;
        let [p50, p99, max] = self.processing_ns;
        let [e50, e99, emax] = self.end_to_end_ns;
        write!(
            f,
            "  estimates {}  overruns {}  processing p50/p99/max {:.1}/{:.1}/{:.1} µs  end-to-end {:.1}/{:.1}/{:.1} µs",
            self.estimates_published,
            self.budget_overruns,
            us(p50),
            us(p99),
            us(max),
            us(e50),
            us(e99),
            us(emax)
        )?;
        if self.events_dropped > 0 {
            write!(f, "  log events dropped {}", self.events_dropped)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RejectReason;
    use core::mem::{align_of, offset_of, size_of};

    use iceoryx2::service::static_config::message_type_details::{TypeDetail, TypeVariant};

    /// The type name iceoryx2 records for `T` in the service's static config.
    fn type_name<T: ZeroCopySend>() -> String {
        TypeDetail::new::<T>(TypeVariant::FixedSize)
            .type_name()
            .to_string()
    }

    #[test]
    fn signature_sample_layout() {
        assert_eq!(size_of::<SignatureSample>(), 40);
        assert_eq!(align_of::<SignatureSample>(), 8);
        assert_eq!(offset_of!(SignatureSample, t_ns), 0);
        assert_eq!(offset_of!(SignatureSample, value), 8);
        assert_eq!(offset_of!(SignatureSample, seq), 16);
        assert_eq!(offset_of!(SignatureSample, publish_ns), 24);
        assert_eq!(offset_of!(SignatureSample, flags), 32);
        assert_eq!(offset_of!(SignatureSample, reserved), 36);
        assert_eq!(type_name::<SignatureSample>(), SIGNATURE_SAMPLE_TYPE_NAME);
    }

    #[test]
    fn offset_estimate_layout() {
        assert_eq!(size_of::<OffsetEstimate>(), 88);
        assert_eq!(align_of::<OffsetEstimate>(), 8);
        assert_eq!(offset_of!(OffsetEstimate, seq), 0);
        assert_eq!(offset_of!(OffsetEstimate, t_ref_ns), 8);
        assert_eq!(offset_of!(OffsetEstimate, offset_s), 16);
        assert_eq!(offset_of!(OffsetEstimate, drift), 24);
        assert_eq!(offset_of!(OffsetEstimate, offset_std_s), 32);
        assert_eq!(offset_of!(OffsetEstimate, drift_std), 40);
        assert_eq!(offset_of!(OffsetEstimate, peak_score), 48);
        assert_eq!(offset_of!(OffsetEstimate, peak_ratio), 56);
        assert_eq!(offset_of!(OffsetEstimate, measured_offset_s), 64);
        assert_eq!(offset_of!(OffsetEstimate, publish_ns), 72);
        assert_eq!(offset_of!(OffsetEstimate, state), 80);
        assert_eq!(offset_of!(OffsetEstimate, polarity), 81);
        assert_eq!(offset_of!(OffsetEstimate, reserved), 82);
        assert_eq!(type_name::<OffsetEstimate>(), OFFSET_ESTIMATE_TYPE_NAME);
    }

    #[test]
    fn status_layout() {
        assert_eq!(size_of::<Status>(), 224);
        assert_eq!(align_of::<Status>(), 8);
        assert_eq!(offset_of!(Status, uptime_ns), 0);
        assert_eq!(offset_of!(Status, publish_ns), 8);
        assert_eq!(offset_of!(Status, received), 16);
        assert_eq!(offset_of!(Status, rejected), 32);
        assert_eq!(offset_of!(Status, lost), 112);
        assert_eq!(offset_of!(Status, budget_overruns), 128);
        assert_eq!(offset_of!(Status, estimates_published), 136);
        assert_eq!(offset_of!(Status, events_dropped), 144);
        assert_eq!(offset_of!(Status, processing_ns), 152);
        assert_eq!(offset_of!(Status, end_to_end_ns), 176);
        assert_eq!(offset_of!(Status, latency_count), 200);
        assert_eq!(offset_of!(Status, state), 208);
        assert_eq!(offset_of!(Status, degraded), 209);
        assert_eq!(offset_of!(Status, reserved), 210);
        assert_eq!(type_name::<Status>(), STATUS_TYPE_NAME);
        assert_eq!(REJECT_NAMES[REJECT_MALFORMED], "malformed");
        for r in RejectReason::ALL {
            assert_eq!(REJECT_NAMES[r.index()], r.name());
        }
    }

    fn estimate() -> Estimate {
        Estimate {
            seq: 7,
            t_ref_ns: 123_456_789,
            offset_s: 0.025,
            drift: 1e-5,
            offset_std_s: 0.001,
            drift_std: 1e-6,
            state: EstimatorState::Tracking,
            polarity: Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: f64::INFINITY,
            measured_offset_s: f64::NAN,
        }
    }

    #[test]
    fn estimate_roundtrip_keeps_every_field() {
        let e = estimate();
        let w = OffsetEstimate::from_estimate(&e, 42).unwrap();
        assert_eq!(w.publish_ns, 42);
        assert_eq!(w.state, 1);
        assert_eq!(w.polarity, -1);
        let back = Estimate::try_from(&w).unwrap();
        assert_eq!(back.seq, e.seq);
        assert_eq!(back.t_ref_ns, e.t_ref_ns);
        assert_eq!(back.offset_s, e.offset_s);
        assert_eq!(back.drift, e.drift);
        assert_eq!(back.offset_std_s, e.offset_std_s);
        assert_eq!(back.drift_std, e.drift_std);
        assert_eq!(back.state, e.state);
        assert_eq!(back.polarity, e.polarity);
        assert_eq!(back.peak_score, e.peak_score);
        assert_eq!(back.peak_ratio, e.peak_ratio);
        assert!(back.measured_offset_s.is_nan());
    }

    #[test]
    fn hostile_estimates_are_refused_with_the_field_named() {
        let good = OffsetEstimate::from_estimate(&estimate(), 0).unwrap();
        let mut w = good;
        w.state = 9;
        assert_eq!(
            Estimate::try_from(&w).unwrap_err(),
            WireError::UnknownState { code: 9 }
        );
        let mut w = good;
        w.polarity = 3;
        assert!(matches!(
            Estimate::try_from(&w),
            Err(WireError::UnknownPolarity { code: 3 })
        ));
        let mut w = good;
        w.offset_s = f64::NAN;
        let err = Estimate::try_from(&w).unwrap_err();
        assert_eq!(err, WireError::NonFinite { field: "offset_s" });
        assert!(err.to_string().contains("offset_s"));
        let mut w = good;
        w.drift = f64::INFINITY;
        assert!(Estimate::try_from(&w).is_err());
        let mut w = good;
        w.offset_std_s = -1.0;
        assert_eq!(
            Estimate::try_from(&w).unwrap_err(),
            WireError::OutOfRange {
                field: "offset_std_s"
            }
        );
        let mut w = good;
        w.peak_ratio = f64::NAN;
        assert!(Estimate::try_from(&w).is_err());
        let mut w = good;
        w.measured_offset_s = f64::NEG_INFINITY;
        assert!(Estimate::try_from(&w).is_err());
        let mut w = good;
        w.reserved[3] = 1;
        assert!(Estimate::try_from(&w).is_err());
        let mut e = estimate();
        e.drift_std = f64::NAN;
        assert!(OffsetEstimate::try_from(&e).is_err());
    }

    #[test]
    fn sample_validation() {
        let s = SignatureSample::new(1, 2.0, 3, 4);
        assert!(s.validate().is_ok());
        assert!(!s.is_first());
        let mut f = s;
        f.flags = FLAG_FIRST | FLAG_SIMULATED;
        assert!(f.validate().is_ok() && f.is_first() && f.is_simulated());
        assert!(!s.is_simulated());
        f.flags = 4;
        assert!(f
            .validate()
            .unwrap_err()
            .to_string()
            .contains("0x4 (known: 0x3)"));
        f.flags = 0x10;
        assert!(f.validate().unwrap_err().to_string().contains("0x10"));
        let mut p = s;
        p.reserved = 1;
        assert!(p.validate().is_err());
    }

    #[test]
    fn status_validation() {
        let s = Status::default();
        assert!(s.validate().is_ok());
        assert_eq!(s.estimator_state(), None);
        let mut b = s;
        b.state = 7;
        assert!(b.validate().is_err());
        let mut b = s;
        b.processing_ns = [5, 3, 9];
        assert!(b.validate().is_err());
        let mut b = s;
        b.degraded = 2;
        assert!(b.validate().is_err());
        // an uptime and a CLOCK_MONOTONIC time: never negative
        let mut b = s;
        b.uptime_ns = -1;
        assert!(b.validate().unwrap_err().to_string().contains("uptime_ns"));
        let mut b = s;
        b.publish_ns = -1;
        assert!(b.validate().unwrap_err().to_string().contains("publish_ns"));
        let mut b = s;
        b.rejected[1] = [1, 2, 3, 4, 5];
        assert_eq!(b.rejected_total(1), 15);
        assert_eq!(b.rejected_total(5), 0);
        // a hostile status passes validation (counters are any u64) and must still
        // print: `vlsync-echo --status` formats what it receives
        let mut h = s;
        h.rejected[0] = [u64::MAX, 1, 0, 0, 0];
        h.received = [u64::MAX; 2];
        h.lost = [u64::MAX; 2];
        assert!(h.validate().is_ok());
        assert_eq!(h.rejected_total(0), u64::MAX);
        assert!(h.to_string().contains(&u64::MAX.to_string()), "{h}");
    }
}
