//! vlsync configuration: typed sections, defaults, strict validation.
//!
//! Unknown keys are errors; every out-of-range value is an error that names the
//! key, the value and the allowed range. The shipped `config/vlsync.toml`
//! documents every key and holds exactly the defaults of [`Config::default`].
//!
//! ```
//! let cfg = vlsync_config::Config::from_toml_str("[estimator]\nwindow_s = 8.0\n", "inline").unwrap();
//! assert_eq!(cfg.estimator.window_s, 8.0);
//! let err = vlsync_config::Config::from_toml_str("[estimator]\nwindow_s = -1.0\n", "inline").unwrap_err();
//! assert!(err.to_string().contains("estimator.window_s"));
//! ```
#![forbid(unsafe_code)]

use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;
use vlsync_common::text::clip;

/// A configuration error: where, and what was wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    /// The file (or other source) the configuration came from.
    pub source_name: String,
    /// What was wrong, naming the key.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "config {}: {}", self.source_name, self.message)
    }
}

impl std::error::Error for ConfigError {}

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// The estimator (correlator, gating, segment and drift estimation).
    pub estimator: EstimatorConfig,
    /// The daemon process (core, priority, budget, state file).
    pub daemon: DaemonConfig,
    /// iceoryx2 service naming.
    pub services: ServicesConfig,
    /// The LiDAR driver's front-end: where the wall is.
    pub lidar: LidarConfig,
    /// The camera driver: what it asks of a V4L2 camera.
    pub camera: CameraConfig,
}

/// Estimator parameters. Times in seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorConfig {
    /// Rate of the common resampling grid, Hz.
    pub grid_hz: f64,
    /// Acquisition window length (also the motion gate's window), seconds; the estimator
    /// runs it in whole hops ([`EstimatorConfig::effective_window_s`]).
    pub window_s: f64,
    /// Longest segment: once locked, the offset is measured on every block since the
    /// last change point (lock, step), at most this long, seconds.
    pub segment_s: f64,
    /// Estimates refer to this long before the newest data (the segment holds this
    /// much data after the reference time), seconds.
    pub reference_lag_s: f64,
    /// Hop between estimates, seconds (also the block length of the incremental sums).
    pub hop_s: f64,
    /// Half-width of the acquisition lag search, seconds.
    pub max_lag_s: f64,
    /// Centre of the acquisition lag search (prior offset), seconds.
    pub lag_center_s: f64,
    /// Half-width of the tracking search around the predicted offset, seconds.
    pub track_range_s: f64,
    /// Short window used to detect offset steps, seconds.
    pub step_window_s: f64,
    /// A gap between consecutive samples of one stream longer than this breaks the window.
    pub max_gap_s: f64,
    /// A timestamp jump forward or backward larger than this resets that stream (a
    /// smaller step backward is rejected as `backwards`).
    pub reset_jump_s: f64,
    /// Low-pass cut-off applied identically to both resampled signals, Hz.
    pub lowpass_hz: f64,
    /// High-pass cut-off applied identically to both resampled signals, Hz: 0 (off) or
    /// at least [`MIN_HIGHPASS_HZ`].
    pub highpass_hz: f64,
    /// Samples with |value| above this are rejected.
    pub max_abs_value: f64,
    /// Minimum normalised correlation at the peak for a measurement.
    pub min_peak_score: f64,
    /// Minimum normalised correlation at the acquisition window's peak for it to count
    /// towards a lock (a short window: noise scores higher there than on a segment);
    /// the estimator never asks less than `min_peak_score`.
    pub min_acquire_score: f64,
    /// Minimum main-to-second peak ratio during acquisition.
    pub min_peak_ratio: f64,
    /// Minimum window variance of each signal relative to its recent typical motion variance.
    pub min_motion_ratio: f64,
    /// Consecutive consistent acquisition measurements needed to lock.
    #[serde(deserialize_with = "count::<1, { CONFIRM_MAX }, _>")]
    pub acquire_confirm: u32,
    /// Scale applied to the peak-sharpness measurement noise.
    pub measurement_noise_scale: f64,
    /// Random-walk intensity of the offset, s/sqrt(s).
    pub offset_process_noise: f64,
    /// Time constant with which old drift information fades, seconds.
    pub drift_memory_s: f64,
    /// Prior standard deviation of the drift at lock, s/s.
    pub initial_drift_std: f64,
    /// Random-walk intensity of the offset once no measurement was accepted for a
    /// whole window (holding), s/sqrt(s): the uncertainty grows honestly while blind.
    pub hold_process_noise: f64,
    /// Innovation gate, in standard deviations.
    pub gate_sigma: f64,
    /// Step test threshold, in standard deviations: hops beyond half of its square
    /// accumulate evidence.
    pub step_gate_sigma: f64,
    /// A step is declared once the evidence reaches `step_confirm · step_gate_sigma² / 2`.
    #[serde(deserialize_with = "count::<1, { CONFIRM_MAX }, _>")]
    pub step_confirm: u32,
    /// Holding becomes lost when the held offset's standard deviation (the part that
    /// grows while blind; the published σ adds the step test's and the cadence's terms)
    /// exceeds this, seconds.
    pub lost_std_s: f64,
    /// Which streams' stamp cadence is followed: steps of a regular stream's
    /// stamping latency (CPU load on a software-stamped camera) are found in its
    /// stamps within a few frames and kept out of the correlation.
    pub cadence: CadenceStreams,
    /// Smallest stamping-latency step the cadence follows (and the least tolerance
    /// of its grid), seconds.
    pub cadence_min_step_s: f64,
    /// Consecutive samples off the grid, on the same side and agreeing, that
    /// confirm a latency step.
    #[serde(deserialize_with = "count::<1, { CADENCE_CONFIRM_MAX }, _>")]
    pub cadence_confirm: u32,
}

/// Largest `estimator.acquire_confirm` and `estimator.step_confirm` (hops).
pub const CONFIRM_MAX: u32 = 100;
/// Largest `estimator.cadence_confirm` (samples).
pub const CADENCE_CONFIRM_MAX: u32 = 15;

/// A count key read from TOML as any integer, so a negative or huge value gets the
/// key's range in its error (TOML's own message for a `u32` names no range); the
/// parse error quotes the line with the key.
fn count<'de, const MIN: u32, const MAX: u32, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<u32, D::Error> {
    struct Count<const MIN: u32, const MAX: u32>;
    impl<const MIN: u32, const MAX: u32> serde::de::Visitor<'_> for Count<MIN, MAX> {
        type Value = u32;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(f, "a whole number {MIN} ..= {MAX}")
        }
        fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<u32, E> {
            match u32::try_from(v) {
                Ok(n) if (MIN..=MAX).contains(&n) => Ok(n),
                _ => Err(E::custom(format!(
                    "{v} is out of range: allowed {MIN} ..= {MAX}"
                ))),
            }
        }
        fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<u32, E> {
            self.visit_i64(i64::try_from(v).unwrap_or(i64::MAX))
        }
        // a count written as 2.0 or 2.5: said with the range (serde's own message
        // would be "expected i64")
        fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<u32, E> {
            Err(E::custom(format!(
                "{v:?} is not a whole number: allowed {MIN} ..= {MAX}"
            )))
        }
    }
    d.deserialize_any(Count::<MIN, MAX>)
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            grid_hz: 100.0,
            window_s: 6.0,
            segment_s: 60.0,
            reference_lag_s: 3.0,
            hop_s: 0.5,
            max_lag_s: 0.5,
            lag_center_s: 0.0,
            track_range_s: 0.08,
            step_window_s: 2.0,
            max_gap_s: 0.75,
            reset_jump_s: 5.0,
            lowpass_hz: 2.0,
            highpass_hz: 0.0,
            max_abs_value: 1e6,
            min_peak_score: 0.4,
            min_acquire_score: 0.7,
            min_peak_ratio: 1.3,
            min_motion_ratio: 0.05,
            acquire_confirm: 4,
            measurement_noise_scale: 1.0,
            offset_process_noise: 2e-4,
            drift_memory_s: 900.0,
            initial_drift_std: 5e-5,
            hold_process_noise: 3e-3,
            gate_sigma: 3.0,
            step_gate_sigma: 4.5,
            step_confirm: 3,
            lost_std_s: 0.05,
            cadence: CadenceStreams::Both,
            cadence_min_step_s: 0.002,
            cadence_confirm: 3,
        }
    }
}

/// Which streams' stamp cadence the estimator follows (`estimator.cadence`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CadenceStreams {
    /// Camera and LiDAR.
    Both,
    /// The camera only (the stream whose stamping moves with CPU load on most robots).
    Camera,
    /// The LiDAR only.
    Lidar,
    /// Neither: every stamp reaches the correlator as it is.
    Off,
}

impl CadenceStreams {
    /// The name in the configuration file.
    pub fn name(self) -> &'static str {
        match self {
            CadenceStreams::Both => "both",
            CadenceStreams::Camera => "camera",
            CadenceStreams::Lidar => "lidar",
            CadenceStreams::Off => "off",
        }
    }

    /// Whether the camera's cadence is followed.
    pub fn camera(self) -> bool {
        matches!(self, CadenceStreams::Both | CadenceStreams::Camera)
    }

    /// Whether the LiDAR's cadence is followed.
    pub fn lidar(self) -> bool {
        matches!(self, CadenceStreams::Both | CadenceStreams::Lidar)
    }
}

/// Daemon process settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaemonConfig {
    /// CPU core the real-time thread is pinned to; -1: no pinning.
    pub core: i64,
    /// SCHED_FIFO priority of the real-time thread (1-99); 0 keeps the normal scheduler.
    pub fifo_priority: i64,
    /// Lock the process memory (mlockall) when allowed.
    pub lock_memory: bool,
    /// CPU wake-up latency the daemon asks the kernel for while it runs,
    /// microseconds (a PM QoS request on `/dev/cpu_dma_latency`, as cyclictest
    /// makes): 0 keeps idle cores polling instead of halting, so a sample wakes the
    /// daemon sooner, at the price of power on every core. -1: no request.
    pub cpu_latency_us: i64,
    /// Processing budget per sample, microseconds.
    pub latency_budget_us: f64,
    /// Status publication period, seconds (while no samples arrive the real-time
    /// loop wakes every 0.1 s, so no faster than that then); one more status comes
    /// at the end of each summary period (`summary_period_s`).
    pub status_period_s: f64,
    /// When true, the latency percentiles of each status cover only the last
    /// status period (the histograms restart after each status) instead of the
    /// whole run; a load test reads them per phase.
    pub latency_per_period: bool,
    /// Period of the log's summary lines, seconds: the estimates and stream counters
    /// of the stretch, and its latency percentiles (whatever `latency_per_period` says).
    pub summary_period_s: f64,
    /// Where the last good estimate is saved, an absolute path; empty: no persistence.
    pub state_file: String,
    /// A saved state older than this is ignored at start, seconds (one saved up to
    /// 60 s in the future counts as age 0).
    pub state_max_age_s: f64,
    /// Watch the kernel's CPU pressure (`/proc/pressure/cpu`) and tell the estimator
    /// that the offset may have stepped where it changes (software-stamped sensors
    /// are late by a processing time that grows with contention).
    pub load_hints: bool,
    /// Change of CPU pressure (share of time some task waited for a CPU, newest 2 s
    /// against the 4 s before) that counts as a load step.
    pub load_hint_threshold: f64,
    /// The pressure file read for load hints, an absolute path (PSI format: the
    /// system's `/proc/pressure/cpu`, or a cgroup's `cpu.pressure`).
    pub load_hint_source: String,
}

impl Default for DaemonConfig {
    fn default() -> Self {
        Self {
            core: 1,
            fifo_priority: 0,
            lock_memory: false,
            cpu_latency_us: -1,
            latency_budget_us: 200.0,
            status_period_s: 1.0,
            latency_per_period: false,
            summary_period_s: 600.0,
            state_file: String::new(),
            state_max_age_s: 3600.0,
            load_hints: false,
            load_hint_threshold: 0.1,
            load_hint_source: "/proc/pressure/cpu".into(),
        }
    }
}

/// The LiDAR driver's front-end (`vlsync-lidar`): the bearing window in which it
/// fits the wall whose distance rate is the signature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LidarConfig {
    /// Centre of the bearing window, degrees (the scan's frame, counter-clockwise).
    pub window_centre_deg: f64,
    /// Half-width of the bearing window, degrees.
    pub window_half_width_deg: f64,
    /// Also fit the wall opposite the window (centre + 180°) and publish its distance
    /// rate, negated, in the same stream: twice the returns, about half the noise
    /// variance, where a wall faces each way (a corridor, a room driven lengthwise).
    pub opposite_window: bool,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            window_centre_deg: 0.0,
            window_half_width_deg: 20.0,
            opposite_window: false,
        }
    }
}

impl LidarConfig {
    /// Checks every value.
    pub fn validate(&self, source: &str) -> Result<(), ConfigError> {
        let c = Checker { source };
        c.range(
            "lidar.window_centre_deg",
            self.window_centre_deg,
            -360.0,
            360.0,
        )?;
        c.range(
            "lidar.window_half_width_deg",
            self.window_half_width_deg,
            1.0,
            90.0,
        )?;
        Ok(())
    }
}

/// Frame rates `camera.v4l2_fps` may ask for, Hz (0 asks for none).
pub const CAMERA_FPS_RANGE: std::ops::RangeInclusive<f64> = 1.0..=1000.0;

/// The camera driver (`vlsync-cam`): what it asks of a V4L2 camera (`--v4l2`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Frame rate asked of a V4L2 camera (`VIDIOC_S_PARM`), Hz; the rate it grants is
    /// said when the driver starts. 0: the camera's own rate is kept. At least
    /// 1 / `estimator.max_gap_s` ([`Config::camera_rate_problem`]).
    pub v4l2_fps: f64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self { v4l2_fps: 0.0 }
    }
}

impl CameraConfig {
    /// The frame rate to ask a V4L2 camera for (`None`: keep its own).
    pub fn v4l2_fps(&self) -> Option<f64> {
        (self.v4l2_fps != 0.0).then_some(self.v4l2_fps)
    }

    /// Whether a frame rate can be asked for: 0 (none asked) or within
    /// [`CAMERA_FPS_RANGE`].
    pub fn fps_is_valid(fps: f64) -> bool {
        fps == 0.0 || (fps.is_finite() && CAMERA_FPS_RANGE.contains(&fps))
    }

    /// Checks every value.
    pub fn validate(&self, source: &str) -> Result<(), ConfigError> {
        let c = Checker { source };
        c.rule(Self::fps_is_valid(self.v4l2_fps), || {
            format!(
                "`camera.v4l2_fps` = {} is out of range: allowed 0 (the camera's own rate) or {} ..= {}",
                num(self.v4l2_fps),
                num(*CAMERA_FPS_RANGE.start()),
                num(*CAMERA_FPS_RANGE.end())
            )
        })
    }
}

/// iceoryx2 service naming.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServicesConfig {
    /// Service name prefix, one robot per prefix: `<prefix>/cam/signature`, ...
    pub prefix: String,
    /// Buffered samples per subscriber.
    pub subscriber_buffer: i64,
}

impl Default for ServicesConfig {
    fn default() -> Self {
        Self {
            prefix: "vlsync/robot".to_string(),
            subscriber_buffer: 256,
        }
    }
}

struct Checker<'a> {
    source: &'a str,
}

/// The largest configuration file read, bytes (1 MiB, far more than the shipped
/// file with every key commented): a larger one is refused before it is read whole.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Most characters kept of each line of a TOML parse error (it quotes the offending
/// line of the file, which may be megabytes long).
const MAX_ERROR_LINE_CHARS: usize = 200;
/// Most lines kept of a TOML parse error.
const MAX_ERROR_LINES: usize = 12;

/// Most characters of the key list an unknown key's error gives (`expected one of
/// ...`): the longest section's list is about 600.
const MAX_KEY_LIST_CHARS: usize = 2000;

/// The TOML parser's message, each line cut at [`MAX_ERROR_LINE_CHARS`]; the first
/// line (`TOML parse error at line L, column C`) is kept whole when it is short, and
/// an unknown key's list of the keys allowed is kept whole (the unknown key clipped):
/// cut, it ended in the middle of a key name, the one the user may have meant.
fn clip_toml_error(text: &str) -> String {
    let mut out: Vec<String> = text
        .trim_end()
        .lines()
        .take(MAX_ERROR_LINES)
        .map(|l| {
            let known = l.strip_prefix("unknown field `").and_then(|rest| {
                let i = rest.find("`, expected ")?;
                let (name, list) = rest.split_at(i);
                (list.chars().count() <= MAX_KEY_LIST_CHARS)
                    .then(|| format!("unknown field `{}{list}", clip(name)))
            });
            if let Some(line) = known {
                line
            } else if l.chars().count() > MAX_ERROR_LINE_CHARS {
                let mut c: String = l.chars().take(MAX_ERROR_LINE_CHARS).collect();
                c.push('…');
                c
            } else {
                l.to_string()
            }
        })
        .collect();
    if text.trim_end().lines().count() > MAX_ERROR_LINES {
        out.push("…".into());
    }
    out.join("\n")
}

/// A number for an error message (`vlsync_common::text::number`).
fn num(v: f64) -> String {
    vlsync_common::text::number(v)
}

/// A duration the estimator derives (a hop in whole grid steps, a window in whole
/// hops) for an error message, to the microsecond: 0.044543 s, not 0.044543427999999996.
fn secs(v: f64) -> String {
    num((v * 1e6).round() / 1e6)
}

impl Checker<'_> {
    fn err(&self, message: String) -> ConfigError {
        ConfigError {
            source_name: self.source.to_string(),
            message,
        }
    }

    fn range(&self, key: &str, v: f64, min: f64, max: f64) -> Result<(), ConfigError> {
        if v.is_finite() && v >= min && v <= max {
            Ok(())
        } else {
            Err(self.err(format!(
                "`{key}` = {} is out of range: allowed {} ..= {}",
                num(v),
                num(min),
                num(max)
            )))
        }
    }

    fn int_range(&self, key: &str, v: i64, min: i64, max: i64) -> Result<(), ConfigError> {
        if v >= min && v <= max {
            Ok(())
        } else {
            Err(self.err(format!(
                "`{key}` = {v} is out of range: allowed {min} ..= {max}"
            )))
        }
    }

    fn rule(&self, ok: bool, msg: impl FnOnce() -> String) -> Result<(), ConfigError> {
        if ok {
            Ok(())
        } else {
            Err(self.err(msg()))
        }
    }
}

/// Largest accepted `estimator.max_abs_value`: a value's square and the correlation
/// sums stay far from overflow (a single accepted 1e200 overflows them and blinds the
/// estimator for a minute; signatures are of order 1-1000).
pub const MAX_ABS_VALUE: f64 = 1e12;

/// Smallest accepted `estimator.max_gap_s`: above the slowest LiDAR's sample interval
/// with its jitter (0.18 s at 5.5 Hz); below it every interval is a gap and nothing
/// is ever estimated.
pub const MIN_MAX_GAP_S: f64 = 0.25;

/// Smallest accepted `estimator.lowpass_hz`: the signatures' motion lies at 0.3-3 Hz,
/// and a lower cut blurs the correlation peak into one wider than its reported σ
/// (robot, 6 s window: MAE 1.1 ms at 0.3 Hz, 2.7 at 0.2, 13 at 0.1 with a quarter of
/// the tracking estimates beyond 20 ms).
pub const MIN_LOWPASS_HZ: f64 = 0.5;

/// Largest accepted `estimator.min_peak_score` and `estimator.min_acquire_score`: a
/// normalised correlation of 1 is never reached by data with any noise, so nothing
/// would ever lock.
pub const MAX_SCORE: f64 = 0.99;

/// Smallest accepted `daemon.latency_budget_us`: a sample's processing alone takes
/// 5-20 µs on a 2-core x86 VM and several times that on a Pi, so a smaller budget
/// degrades the estimator for good.
pub const MIN_LATENCY_BUDGET_US: f64 = 20.0;

/// The fewest grid steps `estimator.max_lag_s` may span: a lag range of three steps
/// each side locks, then can never track (robot at 10, 20 and 100 Hz: 0-27 tracking
/// estimates of 239); four steps track as the defaults do.
pub const MIN_LAG_STEPS: f64 = 4.0;

/// Smallest non-zero `estimator.highpass_hz`. The high-pass biquad's coefficients
/// (estimator `filter.rs`) rest on k = tan(π·highpass_hz/grid_hz): below k ≈ 1e-8 its
/// DC gain's denominator (4k², from sums of terms near 1) rounds to 0 and every
/// filtered value is NaN, and somewhat above, its poles sit within rounding of the
/// unit circle. At 0.01 Hz and the fastest grid (2000 Hz) k is 1.6e-5: the poles
/// stay 2e-5 inside the circle and that denominator is exact to 1e-7. (A cut-off
/// that low, a 16 s time constant, removes nothing the Pearson normalisation does
/// not; 0 turns the high-pass off.)
pub const MIN_HIGHPASS_HZ: f64 = 0.01;

/// The most lag sums the estimator's segment may hold ([`EstimatorConfig::lag_sums`]):
/// three `f64` each, about 100 MB.
pub const MAX_LAG_SUMS: f64 = 4.0e6;

impl EstimatorConfig {
    /// The grid rate the estimator runs: `grid_hz` with its step in whole nanoseconds.
    pub fn effective_grid_hz(&self) -> f64 {
        let dt_ns = (1e9 / self.grid_hz).round().max(1.0);
        1e9 / dt_ns
    }

    /// The hop the estimator runs: `hop_s` in whole steps of the grid (at least one),
    /// computed as the estimator computes it.
    pub fn effective_hop_s(&self) -> f64 {
        let fs = self.effective_grid_hz();
        (self.hop_s * fs).round().max(1.0) * (1.0 / fs)
    }

    /// The acquisition window the estimator runs: `window_s` in whole hops (at least one).
    pub fn effective_window_s(&self) -> f64 {
        self.window_blocks() as f64 * self.effective_hop_s()
    }

    /// The acquisition window's blocks (hops) as the estimator counts them.
    pub fn window_blocks(&self) -> usize {
        ((self.window_s / self.effective_hop_s()).round() as usize).max(1)
    }

    /// The segment's blocks (hops) as the estimator keeps them: `segment_s` in whole
    /// hops, at least the acquisition window's.
    pub fn segment_blocks(&self) -> usize {
        ((self.segment_s / self.effective_hop_s()).round() as usize)
            .max(1)
            .max(self.window_blocks())
    }

    /// The lag slots the estimator searches: 2·round(`max_lag_s`·grid rate) + 1, at
    /// least 5.
    pub fn lag_slots(&self) -> usize {
        let half = ((self.max_lag_s * self.effective_grid_hz()).round() as usize).max(2);
        half.saturating_mul(2).saturating_add(1)
    }

    /// The lag sums the estimator holds for the segment: [`Self::lag_slots`] for each of
    /// its [`Self::segment_blocks`] and the block being filled. Bounded by
    /// [`MAX_LAG_SUMS`]. (An `f64`: no overflow whatever the values.)
    pub fn lag_sums(&self) -> f64 {
        self.lag_slots() as f64 * (self.segment_blocks() as f64 + 1.0)
    }

    /// Checks every value; the error names the key, value and allowed range.
    pub fn validate(&self, source: &str) -> Result<(), ConfigError> {
        let c = Checker { source };
        let k = |n: &str| format!("estimator.{n}");
        c.range(&k("grid_hz"), self.grid_hz, 10.0, 2000.0)?;
        c.range(&k("window_s"), self.window_s, 1.0, 120.0)?;
        c.range(&k("segment_s"), self.segment_s, 1.0, 600.0)?;
        c.range(&k("reference_lag_s"), self.reference_lag_s, 0.0, 600.0)?;
        c.range(&k("hop_s"), self.hop_s, 0.05, 10.0)?;
        c.range(&k("max_lag_s"), self.max_lag_s, 0.01, 2.0)?;
        c.range(&k("lag_center_s"), self.lag_center_s, -1e6, 1e6)?;
        c.range(&k("track_range_s"), self.track_range_s, 0.005, 2.0)?;
        c.range(&k("step_window_s"), self.step_window_s, 0.5, 120.0)?;
        c.range(&k("max_gap_s"), self.max_gap_s, MIN_MAX_GAP_S, 60.0)?;
        c.range(&k("reset_jump_s"), self.reset_jump_s, 0.1, 1e6)?;
        c.range(&k("lowpass_hz"), self.lowpass_hz, MIN_LOWPASS_HZ, 500.0)?;
        // 0 (off) or at least the floor: a tiny cut-off makes the filter degenerate
        c.rule(
            self.highpass_hz == 0.0
                || (self.highpass_hz.is_finite()
                    && (MIN_HIGHPASS_HZ..=100.0).contains(&self.highpass_hz)),
            || {
                format!(
                    "`estimator.highpass_hz` = {} is out of range: allowed 0 (no high-pass) or {} ..= 100 (a cut-off under {1} Hz rounds the filter to nothing or NaN)",
                    num(self.highpass_hz),
                    num(MIN_HIGHPASS_HZ)
                )
            },
        )?;
        c.range(&k("max_abs_value"), self.max_abs_value, 1e-9, MAX_ABS_VALUE)?;
        c.range(&k("min_peak_score"), self.min_peak_score, 0.0, MAX_SCORE)?;
        c.range(
            &k("min_acquire_score"),
            self.min_acquire_score,
            0.0,
            MAX_SCORE,
        )?;
        c.range(&k("min_peak_ratio"), self.min_peak_ratio, 1.0, 100.0)?;
        c.range(&k("min_motion_ratio"), self.min_motion_ratio, 0.0, 1.0)?;
        c.int_range(
            &k("acquire_confirm"),
            self.acquire_confirm.into(),
            1,
            CONFIRM_MAX.into(),
        )?;
        c.range(
            &k("measurement_noise_scale"),
            self.measurement_noise_scale,
            0.1,
            1e3,
        )?;
        c.range(
            &k("offset_process_noise"),
            self.offset_process_noise,
            0.0,
            1.0,
        )?;
        c.range(&k("drift_memory_s"), self.drift_memory_s, 1.0, 1e9)?;
        c.range(&k("initial_drift_std"), self.initial_drift_std, 1e-9, 0.02)?;
        c.range(&k("hold_process_noise"), self.hold_process_noise, 0.0, 1.0)?;
        c.range(&k("gate_sigma"), self.gate_sigma, 1.0, 100.0)?;
        c.range(&k("step_gate_sigma"), self.step_gate_sigma, 1.0, 100.0)?;
        c.int_range(
            &k("step_confirm"),
            self.step_confirm.into(),
            1,
            CONFIRM_MAX.into(),
        )?;
        c.range(&k("lost_std_s"), self.lost_std_s, 1e-4, 10.0)?;
        c.range(&k("cadence_min_step_s"), self.cadence_min_step_s, 1e-4, 0.1)?;
        c.int_range(
            &k("cadence_confirm"),
            self.cadence_confirm.into(),
            1,
            CADENCE_CONFIRM_MAX.into(),
        )?;
        c.rule(self.hop_s <= self.window_s, || {
            format!(
                "`estimator.hop_s` = {} must not exceed `estimator.window_s` = {}",
                num(self.hop_s),
                num(self.window_s)
            )
        })?;
        // a segment of one window measures each hop on the data it was locked on:
        // most measurements are outliers and the estimate is held (robot: MAE 4.2 ms)
        c.rule(self.segment_s >= 2.0 * self.window_s, || {
            format!(
                "`estimator.segment_s` = {} must be at least twice `estimator.window_s` = {}",
                num(self.segment_s),
                num(self.window_s)
            )
        })?;
        // the estimator runs the window in whole hops: the rules below compare that
        // window, said beside window_s where the two differ
        let window = self.effective_window_s();
        let runs_as = if (window - self.window_s).abs() > 1e-9 {
            format!(
                " in whole hops of {} s is {} s",
                secs(self.effective_hop_s()),
                secs(window)
            )
        } else {
            String::new()
        };
        // a window shorter than the lag range is wide leaves the second peak as high as
        // the first: no lock ever (1 s at ±1 s), or one tens of ms off (3 s at ±2 s)
        c.rule(window >= 2.0 * self.max_lag_s - 1e-9, || {
            format!(
                "`estimator.window_s` = {}{runs_as}{} must be at least the lag range's width, 2 × `estimator.max_lag_s` ({})",
                num(self.window_s),
                if runs_as.is_empty() { "" } else { ", which" },
                num(2.0 * self.max_lag_s)
            )
        })?;
        // a gap interpolated across more than half a window measures the line drawn
        // over a silent sensor as if it were data
        c.rule(self.max_gap_s <= 0.5 * window + 1e-9, || {
            if runs_as.is_empty() {
                format!(
                    "`estimator.max_gap_s` = {} must not exceed half of `estimator.window_s` ({})",
                    num(self.max_gap_s),
                    num(0.5 * window)
                )
            } else {
                format!(
                    "`estimator.max_gap_s` = {} must not exceed half of the acquisition window ({}): `estimator.window_s` = {}{runs_as}",
                    num(self.max_gap_s),
                    num(0.5 * window),
                    num(self.window_s)
                )
            }
        })?;
        // the lock's first estimate refers to a time its acquisition window covers:
        // a reference further back than the window never locks
        c.rule(self.reference_lag_s <= window + 1e-9, || {
            // a shorter window_s alone trips this rule on a key the file may not set
            let default = self.reference_lag_s == EstimatorConfig::default().reference_lag_s;
            format!(
                "`estimator.reference_lag_s` = {} must not exceed the acquisition window: `estimator.window_s` = {} in whole hops of {} s is {} s{}",
                num(self.reference_lag_s),
                num(self.window_s),
                secs(self.effective_hop_s()),
                secs(window),
                if default {
                    " (reference_lag_s is at its default: set it within the window too, or lengthen window_s)"
                } else {
                    ""
                }
            )
        })?;
        c.rule(self.step_window_s <= self.window_s, || {
            format!(
                "`estimator.step_window_s` = {} must not exceed `estimator.window_s` = {}",
                num(self.step_window_s),
                num(self.window_s)
            )
        })?;
        // the step test's window is whole hops: a shorter one would run as one hop
        let hop = self.effective_hop_s();
        c.rule(self.step_window_s >= hop - 1e-9, || {
            format!(
                "`estimator.step_window_s` = {} is shorter than one hop (`estimator.hop_s` = {} in whole grid steps is {} s)",
                num(self.step_window_s),
                num(self.hop_s),
                num(hop)
            )
        })?;
        c.rule(self.hop_s * self.grid_hz >= 1.0, || {
            format!(
                "`estimator.hop_s` = {} is shorter than one grid step (1/`estimator.grid_hz` = {} s)",
                num(self.hop_s),
                num(1.0 / self.grid_hz)
            )
        })?;
        c.rule(self.lowpass_hz <= 0.45 * self.grid_hz, || {
            format!(
                "`estimator.lowpass_hz` = {} must not exceed 0.45 × `estimator.grid_hz` ({})",
                num(self.lowpass_hz),
                num(0.45 * self.grid_hz)
            )
        })?;
        c.rule(self.highpass_hz <= 0.9 * self.lowpass_hz, || {
            format!(
                "`estimator.highpass_hz` = {} must not exceed 0.9 × `estimator.lowpass_hz` ({})",
                num(self.highpass_hz),
                num(0.9 * self.lowpass_hz)
            )
        })?;
        c.rule(self.reset_jump_s > self.max_gap_s, || {
            format!(
                "`estimator.reset_jump_s` = {} must exceed `estimator.max_gap_s` = {} (a gap longer than the reset jump resets the stream instead)",
                num(self.reset_jump_s),
                num(self.max_gap_s)
            )
        })?;
        let step = 1.0 / self.grid_hz;
        for (key, v, steps) in [
            ("max_lag_s", self.max_lag_s, MIN_LAG_STEPS),
            ("track_range_s", self.track_range_s, 2.0),
        ] {
            c.rule(v >= steps * step - 1e-12, || {
                let words = if steps == 2.0 { "two" } else { "four" };
                format!(
                    "`estimator.{key}` = {} is narrower than {words} grid steps ({steps}/`estimator.grid_hz` = {} s)",
                    num(v),
                    num(steps * step)
                )
            })?;
        }
        // the estimator's own counts: the hop in whole grid steps, the segment in whole
        // hops, the lags in whole grid steps
        let sums = self.lag_sums();
        c.rule(sums <= MAX_LAG_SUMS, || {
            format!(
                "`estimator.max_lag_s` = {} with `estimator.grid_hz` = {} and `estimator.segment_s`/`estimator.hop_s` = {}/{} need {sums:.0} lag sums ({} lags × {} + 1 blocks: the segment in whole hops of {} s, and the block being filled): allowed at most {MAX_LAG_SUMS:.0} (about 100 MB)",
                num(self.max_lag_s),
                num(self.grid_hz),
                num(self.segment_s),
                num(self.hop_s),
                self.lag_slots(),
                self.segment_blocks(),
                secs(self.effective_hop_s()),
            )
        })?;
        c.rule(self.track_range_s <= self.max_lag_s, || {
            format!(
                "`estimator.track_range_s` = {} must not exceed `estimator.max_lag_s` = {}",
                num(self.track_range_s),
                num(self.max_lag_s)
            )
        })?;
        Ok(())
    }
}

impl DaemonConfig {
    /// Checks every value.
    pub fn validate(&self, source: &str) -> Result<(), ConfigError> {
        let c = Checker { source };
        c.int_range("daemon.core", self.core, -1, 1023)?;
        c.int_range("daemon.fifo_priority", self.fifo_priority, 0, 99)?;
        c.int_range("daemon.cpu_latency_us", self.cpu_latency_us, -1, 1_000_000)?;
        c.range(
            "daemon.latency_budget_us",
            self.latency_budget_us,
            MIN_LATENCY_BUDGET_US,
            1e6,
        )?;
        c.range("daemon.status_period_s", self.status_period_s, 0.05, 3600.0)?;
        c.range(
            "daemon.summary_period_s",
            self.summary_period_s,
            1.0,
            86400.0,
        )?;
        c.range("daemon.state_max_age_s", self.state_max_age_s, 0.0, 1e9)?;
        c.range(
            "daemon.load_hint_threshold",
            self.load_hint_threshold,
            0.01,
            1.0,
        )?;
        for (key, path) in [
            ("daemon.state_file", &self.state_file),
            ("daemon.load_hint_source", &self.load_hint_source),
        ] {
            c.rule(!path.contains('\0'), || {
                format!(
                    "`{key}` = {:?} contains a NUL byte, which no file name can",
                    clip(path)
                )
            })?;
            // "" is the key's own meaning (no persistence; no pressure file, refused
            // below while load hints are on); blanks are a slip, not a file name
            c.rule(path.is_empty() || !path.trim().is_empty(), || {
                format!(
                    "`{key}` = {:?} is blank: give an absolute path{}",
                    clip(path),
                    if key == "daemon.state_file" {
                        ", or \"\" for no persistence"
                    } else {
                        ""
                    }
                )
            })?;
            // the daemon's working directory is not the file's: under the systemd unit
            // it is /, read-only (ProtectSystem=strict), where every save would fail
            c.rule(path.trim().is_empty() || Path::new(path).is_absolute(), || {
                format!(
                    "`{key}` = {:?} is not an absolute path: it would be taken from the daemon's working directory, / under its systemd unit (read-only there); give the whole path, such as {}",
                    clip(path),
                    if key == "daemon.state_file" {
                        "/run/vlsync/vlsync.state"
                    } else {
                        "/proc/pressure/cpu"
                    }
                )
            })?;
        }
        c.rule(
            !(self.load_hints && self.load_hint_source.trim().is_empty()),
            || "`daemon.load_hint_source` is empty while `daemon.load_hints` is on: give a pressure file such as /proc/pressure/cpu".to_string(),
        )?;
        Ok(())
    }
}

/// The longest `services.prefix`, bytes.
pub const MAX_PREFIX_BYTES: usize = 200;

/// Whether `p` is a `services.prefix` a daemon accepts: non-empty, at most 200
/// bytes, only ASCII letters, digits, `_`, `-`, `.` and `/`, no leading or trailing
/// `/`, no `//`.
pub fn prefix_is_valid(p: &str) -> bool {
    !p.is_empty()
        && p.len() <= MAX_PREFIX_BYTES
        && p.chars()
            .all(|ch| ch.is_ascii_alphanumeric() || "_-./".contains(ch))
        && !p.starts_with('/')
        && !p.ends_with('/')
        && !p.contains("//")
}

impl ServicesConfig {
    /// Checks every value; the prefix by [`prefix_is_valid`].
    pub fn validate(&self, source: &str) -> Result<(), ConfigError> {
        let c = Checker { source };
        let p = &self.prefix;
        c.rule(
            prefix_is_valid(p),
            || {
                format!(
                    "`services.prefix` = {:?} is invalid: allowed 1-200 characters of [A-Za-z0-9_.-/], no leading, trailing or double `/`",
                    clip(p)
                )
            },
        )?;
        c.int_range(
            "services.subscriber_buffer",
            self.subscriber_buffer,
            1,
            65536,
        )?;
        Ok(())
    }
}

/// The line (from 1) where the top-level key `key`'s value starts in `text` (for
/// `[[key]]`, its first header); `None` when the text does not parse.
fn value_line(text: &str, key: &str) -> Option<usize> {
    let spans: std::collections::BTreeMap<String, toml::Spanned<toml::Value>> =
        toml::from_str(text).ok()?;
    let start = spans.get(key)?.span().start;
    let before = text.as_bytes().get(..start)?;
    Some(1 + before.iter().filter(|&&b| b == b'\n').count())
}

impl Config {
    /// Parses and validates TOML text; `source_name` names it in errors.
    pub fn from_toml_str(text: &str, source_name: &str) -> Result<Self, ConfigError> {
        let err = |message: String| ConfigError {
            source_name: source_name.to_string(),
            message,
        };
        // a section given as an array (`lidar = [10.0, 30.0]`, `[[estimator]]`) would
        // fill its keys by position, unnamed and unchecked for extras: only a table is
        // a section
        let table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| err(clip_toml_error(&e.to_string())))?;
        for (key, value) in &table {
            // unknown names are serde's to refuse, by name
            let section = ["estimator", "daemon", "services", "lidar", "camera"];
            if section.contains(&key.as_str()) && !value.is_table() {
                return Err(err(format!(
                    "{}`{}` must be a section (`[{1}]` and its keys), not {}",
                    value_line(text, key).map_or(String::new(), |l| format!("line {l}: ")),
                    clip(key),
                    match value {
                        toml::Value::Array(_) => "an array",
                        _ => "a value",
                    }
                )));
            }
        }
        let cfg: Config = toml::from_str(text).map_err(|e| err(clip_toml_error(&e.to_string())))?;
        cfg.validate(source_name)?;
        Ok(cfg)
    }

    /// Reads, parses and validates a TOML file (a regular file only: opening a named
    /// pipe would block until a writer appears; at most [`MAX_FILE_BYTES`]).
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let name = path.display().to_string();
        let cannot_read = |e: &dyn fmt::Display| ConfigError {
            source_name: name.clone(),
            message: format!("cannot read: {e}"),
        };
        let bytes =
            vlsync_common::file::read_regular_at_most(path, MAX_FILE_BYTES).map_err(|e| {
                cannot_read(&format!(
                    "{e}{}",
                    if e.kind() == std::io::ErrorKind::InvalidData {
                        ": too large for a configuration file"
                    } else {
                        ""
                    }
                ))
            })?;
        let text = String::from_utf8(bytes).map_err(|e| {
            // where: TOML is UTF-8, and an editor's Latin-1 character is one byte
            let at = e.utf8_error().valid_up_to();
            let line = 1 + e.as_bytes()[..at].iter().filter(|&&b| b == b'\n').count();
            ConfigError {
                source_name: name.clone(),
                message: format!("line {line}: not UTF-8 (at byte offset {at})"),
            }
        })?;
        Self::from_toml_str(&text, &name)
    }

    /// Validates every section, then what one section asks of another.
    pub fn validate(&self, source_name: &str) -> Result<(), ConfigError> {
        self.estimator.validate(source_name)?;
        self.daemon.validate(source_name)?;
        self.services.validate(source_name)?;
        self.lidar.validate(source_name)?;
        self.camera.validate(source_name)?;
        let c = Checker {
            source: source_name,
        };
        let problem = self.camera_rate_problem(self.camera.v4l2_fps);
        c.rule(problem.is_none(), || {
            format!(
                "`camera.v4l2_fps` = {}: {}",
                num(self.camera.v4l2_fps),
                problem.unwrap_or_default()
            )
        })
    }

    /// Why a camera asked for `fps` frames a second (0: its own rate, not known
    /// here) would give the estimator nothing to use: its samples would be further
    /// apart than `estimator.max_gap_s`, and the estimator never interpolates across
    /// such a gap. `None` when it is fine.
    pub fn camera_rate_problem(&self, fps: f64) -> Option<String> {
        let gap = self.estimator.max_gap_s;
        (fps > 0.0 && 1.0 / fps > gap).then(|| {
            format!(
                "camera samples {} s apart, more than `estimator.max_gap_s` = {} (the longest gap the estimator interpolates across): no camera signature would be usable; ask for at least {} frames a second or raise `estimator.max_gap_s`",
                num(1.0 / fps),
                num(gap),
                // rounded up to what passes: 1 / 0.75 s is 1.333..., and 1.33 is refused
                num((100.0 / gap).ceil() / 100.0)
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const SHIPPED: &str = include_str!("../vlsync.toml");

    #[test]
    fn a_camera_slower_than_the_estimators_gap_is_refused() {
        // 1 Hz: samples 1 s apart, beyond the default max_gap_s of 0.75 s
        let e = Config::from_toml_str("[camera]\nv4l2_fps = 1.0\n", "my.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("config my.toml: `camera.v4l2_fps` = 1: camera samples 1 s apart, more than `estimator.max_gap_s` = 0.75"),
            "{e}"
        );
        assert!(e.contains("ask for at least 1.34 frames a second"), "{e}");
        Config::from_toml_str("[camera]\nv4l2_fps = 1.34\n", "x").unwrap();
        assert!(Config::from_toml_str("[camera]\nv4l2_fps = 1.33\n", "x").is_err());
        // the same rate with a longer gap allowed, and 1.5 Hz with the default
        Config::from_toml_str(
            "[camera]\nv4l2_fps = 1.0\n[estimator]\nmax_gap_s = 1.5\nreset_jump_s = 2.0\n",
            "x",
        )
        .unwrap();
        Config::from_toml_str("[camera]\nv4l2_fps = 1.5\n", "x").unwrap();
        assert_eq!(Config::default().camera_rate_problem(0.0), None);
    }

    #[test]
    fn defaults_are_valid() {
        Config::default().validate("default").unwrap();
    }

    #[test]
    fn shipped_file_parses_and_equals_defaults() {
        let cfg = Config::from_toml_str(SHIPPED, "config/vlsync.toml").unwrap();
        assert_eq!(cfg, Config::default());
    }

    #[test]
    fn shipped_file_documents_every_key() {
        // every key serialised from the defaults appears, uncommented, in the shipped file
        let text = toml::to_string(&Config::default()).unwrap();
        for line in text.lines() {
            if let Some((key, _)) = line.split_once(" = ") {
                let found = SHIPPED
                    .lines()
                    .any(|l| l.trim_start().starts_with(&format!("{key} =")));
                assert!(found, "key `{key}` is not in config/vlsync.toml");
            }
        }
    }

    #[test]
    fn a_file_name_with_a_nul_byte_is_refused() {
        let e = Config::from_toml_str("[daemon]\nstate_file = \"/tmp/a\\u0000b\"\n", "x.toml")
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "config x.toml: `daemon.state_file` = \"/tmp/a\\0b\" contains a NUL byte, which no file name can"
        );
    }

    #[test]
    fn a_section_is_a_table_never_an_array_of_its_values() {
        for (text, want) in [
            (
                "lidar = [10.0, 30.0, true, 5]\n",
                "line 1: `lidar` must be a section (`[lidar]` and its keys), not an array",
            ),
            (
                "# the camera\n\ncamera = [30.0]\n",
                "line 3: `camera` must be a section (`[camera]` and its keys), not an array",
            ),
            (
                "[daemon]\ncore = 1\n\n[[estimator]]\ngrid_hz = 100.0\n",
                "line 4: `estimator` must be a section (`[estimator]` and its keys), not an array",
            ),
            (
                "x = 1\ndaemon = 3\n",
                "line 2: `daemon` must be a section (`[daemon]` and its keys), not a value",
            ),
        ] {
            let e = Config::from_toml_str(text, "x.toml").unwrap_err();
            assert_eq!(e.to_string(), format!("config x.toml: {want}"), "{text}");
        }
        // an unknown top-level value is still refused by its name
        let e = Config::from_toml_str("nope = 1\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("unknown field `nope`"), "{e}");
        // inline tables are tables
        Config::from_toml_str("lidar = { window_centre_deg = 10.0 }\n", "x.toml").unwrap();
    }

    #[test]
    fn unknown_key_is_an_error_naming_it() {
        let e = Config::from_toml_str("[estimator]\nwindow = 3.0\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("window"), "{e}");
        assert!(e.to_string().contains("x.toml"), "{e}");
        let e = Config::from_toml_str("[nope]\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("nope"), "{e}");
        // the keys allowed, every one: cut at 200 characters, the list ended in the
        // middle of a name
        let e = Config::from_toml_str("[estimator]\nmax_lags = 0.5\n", "x.toml").unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("unknown field `max_lags`, expected one of `grid_hz`, ")
                && s.trim_end().ends_with('`')
                && !s.contains('…'),
            "{s}"
        );
        for key in ["reset_jump_s", "max_lag_s", "cadence"] {
            assert!(s.contains(&format!("`{key}`")), "{key}: {s}");
        }
    }

    #[test]
    fn out_of_range_names_key_value_and_range() {
        let e = Config::from_toml_str("[estimator]\nmax_lag_s = 5.0\n", "x.toml").unwrap_err();
        let s = e.to_string();
        assert!(s.contains("estimator.max_lag_s"), "{s}");
        assert!(s.contains('5'), "{s}");
        assert!(s.contains("0.01 ..= 2"), "{s}");
        let e = Config::from_toml_str("[daemon]\ncpu_latency_us = -2\n", "x.toml").unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("daemon.cpu_latency_us") && s.contains("-2"),
            "{s}"
        );
        let c = Config::from_toml_str("[daemon]\ncpu_latency_us = 0\n", "x.toml").unwrap();
        assert_eq!(c.daemon.cpu_latency_us, 0);
    }

    #[test]
    fn cadence_streams_and_ranges() {
        let c = Config::from_toml_str("[estimator]\ncadence = \"camera\"\n", "x").unwrap();
        assert!(c.estimator.cadence.camera() && !c.estimator.cadence.lidar());
        let c = Config::from_toml_str("[estimator]\ncadence = \"off\"\n", "x").unwrap();
        assert!(!c.estimator.cadence.camera() && !c.estimator.cadence.lidar());
        let e = Config::from_toml_str("[estimator]\ncadence = \"yes\"\n", "x.toml").unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("cadence") && s.contains("yes") && s.contains("both"),
            "{s}"
        );
        let e = Config::from_toml_str("[estimator]\ncadence_confirm = 0\n", "x").unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("cadence_confirm = 0") && s.contains("1 ..= 15"),
            "{s}"
        );
        let e = Config::from_toml_str("[estimator]\ncadence_min_step_s = 0.5\n", "x").unwrap_err();
        assert!(
            e.to_string().contains("estimator.cadence_min_step_s"),
            "{e}"
        );
    }

    #[test]
    fn the_camera_frame_rate_is_none_or_in_range() {
        let c = Config::from_toml_str("[camera]\nv4l2_fps = 30.0\n", "x").unwrap();
        assert_eq!(c.camera.v4l2_fps(), Some(30.0));
        let c = Config::from_toml_str("[camera]\nv4l2_fps = 7.5\n", "x").unwrap();
        assert_eq!(c.camera.v4l2_fps(), Some(7.5));
        assert_eq!(Config::default().camera.v4l2_fps(), None);
        for bad in ["0.5", "1000.5", "-30.0", "nan", "inf"] {
            let e = Config::from_toml_str(&format!("[camera]\nv4l2_fps = {bad}\n"), "my.toml")
                .unwrap_err();
            let s = e.to_string();
            assert!(
                s.starts_with("config my.toml: `camera.v4l2_fps` = ")
                    && s.ends_with(
                        "is out of range: allowed 0 (the camera's own rate) or 1 ..= 1000"
                    ),
                "{s}"
            );
        }
        let e = Config::from_toml_str("[camera]\nfps = 30.0\n", "x").unwrap_err();
        assert!(e.to_string().contains("fps"), "{e}");
    }

    #[test]
    fn wrong_type_is_an_error() {
        let e = Config::from_toml_str("[daemon]\ncore = \"one\"\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("core"), "{e}");
    }

    #[test]
    fn cross_field_rules() {
        let e =
            Config::from_toml_str("[estimator]\nhop_s = 8.0\nwindow_s = 4.0\n", "x").unwrap_err();
        assert!(e.to_string().contains("hop_s"), "{e}");
        let e = Config::from_toml_str("[estimator]\nreference_lag_s = 70.0\n", "x").unwrap_err();
        assert!(e.to_string().contains("reference_lag_s"), "{e}");
        let e = Config::from_toml_str("[estimator]\nsegment_s = 5.0\n", "x").unwrap_err();
        assert!(e.to_string().contains("segment_s"), "{e}");
        let e = Config::from_toml_str("[services]\nprefix = \"/a//b\"\n", "x").unwrap_err();
        assert!(e.to_string().contains("services.prefix"), "{e}");
    }

    /// Values each in range whose combination the estimator could not run as written:
    /// refused, not silently run otherwise (or never locking).
    #[test]
    fn combinations_the_estimator_cannot_run_are_refused() {
        let err = |t: &str| Config::from_toml_str(t, "x.toml").unwrap_err().message;
        // a reference time the acquisition window never covers: no lock, ever
        assert_eq!(
            err("[estimator]\nwindow_s = 2.0\n"),
            "`estimator.reference_lag_s` = 3 must not exceed the acquisition window: `estimator.window_s` = 2 in whole hops of 0.5 s is 2 s (reference_lag_s is at its default: set it within the window too, or lengthen window_s)"
        );
        let e = err("[estimator]\nreference_lag_s = 6.5\n");
        assert!(e.contains("is 6 s") && !e.contains("default"), "{e}");
        // in whole hops: 2.75 s runs as 3 s, which covers the 3 s reference
        assert!(Config::from_toml_str("[estimator]\nwindow_s = 2.75\n", "x").is_ok());
        assert!(Config::from_toml_str("[estimator]\nwindow_s = 2.7\n", "x").is_err());
        // every gap longer than the reset jump resets the stream
        let e = err("[estimator]\nreset_jump_s = 0.5\n");
        assert!(
            e.contains("`estimator.reset_jump_s` = 0.5 must exceed `estimator.max_gap_s` = 0.75"),
            "{e}"
        );
        // the estimator would clamp these to other values
        let e = err("[estimator]\ngrid_hz = 10.0\nlowpass_hz = 4.9\n");
        assert!(e.contains("0.45 × `estimator.grid_hz` (4.5)"), "{e}");
        let e = err("[estimator]\nlowpass_hz = 2.0\nhighpass_hz = 1.99\n");
        assert!(e.contains("0.9 × `estimator.lowpass_hz` (1.8)"), "{e}");
        let e = err("[estimator]\ngrid_hz = 10.0\nmax_lag_s = 0.3\ntrack_range_s = 0.2\n");
        assert_eq!(e, "`estimator.max_lag_s` = 0.3 is narrower than four grid steps (4/`estimator.grid_hz` = 0.4 s)");
        let e = err("[estimator]\ngrid_hz = 10.0\nmax_lag_s = 0.4\ntrack_range_s = 0.1\n");
        assert!(e.contains("`estimator.track_range_s` = 0.1 is narrower than two grid steps (2/`estimator.grid_hz` = 0.2 s)"), "{e}");
        let e = err("[estimator]\ntrack_range_s = 0.01\n");
        assert!(e.contains("`estimator.track_range_s` = 0.01"), "{e}");
        // the limits themselves are accepted
        let ok = "[estimator]\ngrid_hz = 10.0\nlowpass_hz = 4.5\nhighpass_hz = 4.05\nmax_lag_s = 0.4\ntrack_range_s = 0.2\nreset_jump_s = 0.76\n";
        Config::from_toml_str(ok, "x").unwrap();
    }

    /// Combinations the estimator runs but badly, each measured on simulated runs
    /// (`vlsyncd replay --truth`): refused with the keys named, their limits accepted.
    #[test]
    fn combinations_that_never_lock_or_mislead_are_refused() {
        let err = |t: &str| Config::from_toml_str(t, "x.toml").unwrap_err().message;
        let ok = |t: &str| {
            Config::from_toml_str(t, "x.toml").unwrap_or_else(|e| panic!("{t}: {e}"));
        };
        // a window no wider than the lag range never locks
        let short = "[estimator]\nwindow_s = 1.5\nmax_lag_s = 1.0\nreference_lag_s = 1.5\nstep_window_s = 1.5\nmax_gap_s = 0.5\n";
        assert_eq!(
            err(short),
            "`estimator.window_s` = 1.5 must be at least the lag range's width, 2 × `estimator.max_lag_s` (2)"
        );
        ok(&short.replace("max_lag_s = 1.0", "max_lag_s = 0.75"));
        // a segment of one window
        let e = err("[estimator]\nsegment_s = 8.0\n");
        assert_eq!(
            e,
            "`estimator.segment_s` = 8 must be at least twice `estimator.window_s` = 6"
        );
        ok("[estimator]\nsegment_s = 12.0\n");
        // a gap limit under the slowest LiDAR's interval: every interval a gap
        let e = err("[estimator]\nmax_gap_s = 0.1\n");
        assert!(
            e.contains("estimator.max_gap_s") && e.contains("0.25"),
            "{e}"
        );
        ok("[estimator]\nmax_gap_s = 0.25\n");
        // a silence interpolated across most of a window
        let e = err("[estimator]\nmax_gap_s = 3.5\n");
        assert_eq!(
            e,
            "`estimator.max_gap_s` = 3.5 must not exceed half of `estimator.window_s` (3)"
        );
        ok("[estimator]\nmax_gap_s = 3.0\n");
        // a step window shorter than a hop would run as one hop
        let e = err("[estimator]\nhop_s = 1.0\nstep_window_s = 0.6\n");
        assert_eq!(
            e,
            "`estimator.step_window_s` = 0.6 is shorter than one hop (`estimator.hop_s` = 1 in whole grid steps is 1 s)"
        );
        ok("[estimator]\nhop_s = 1.0\nstep_window_s = 1.0\n");
        // a low-pass that blurs the motion, scores nothing reaches, σ made tiny, a
        // drift prior wide enough for noise to pass as drift, a budget nothing meets
        for (text, key) in [
            ("[estimator]\nlowpass_hz = 0.2\n", "estimator.lowpass_hz"),
            (
                "[estimator]\nmin_peak_score = 1.0\n",
                "estimator.min_peak_score",
            ),
            (
                "[estimator]\nmin_acquire_score = 1.0\n",
                "estimator.min_acquire_score",
            ),
            (
                "[estimator]\nmeasurement_noise_scale = 0.01\n",
                "estimator.measurement_noise_scale",
            ),
            (
                "[estimator]\ninitial_drift_std = 0.05\n",
                "estimator.initial_drift_std",
            ),
            (
                "[daemon]\nlatency_budget_us = 5.0\n",
                "daemon.latency_budget_us",
            ),
        ] {
            let e = err(text);
            assert!(e.contains(key) && e.contains("allowed"), "{text}: {e}");
        }
        ok("[estimator]\nlowpass_hz = 0.5\nmin_peak_score = 0.99\nmin_acquire_score = 0.99\nmeasurement_noise_scale = 0.1\ninitial_drift_std = 0.02\n[daemon]\nlatency_budget_us = 20.0\n");
    }

    /// A high-pass cut-off is 0 (off) or at least [`MIN_HIGHPASS_HZ`]: a tiny one
    /// (1e-15 Hz passed the old range 0 ..= 100) turns the filter's output to NaN and
    /// the estimator never locks (the real filter: `daemon/src/check.rs`).
    #[test]
    fn a_highpass_below_its_floor_is_refused() {
        for bad in ["1e-15", "1e-7", "0.009", "-0.01", "nan", "100.5"] {
            let e = Config::from_toml_str(&format!("[estimator]\nhighpass_hz = {bad}\n"), "x")
                .unwrap_err()
                .message;
            assert!(
                e.starts_with("`estimator.highpass_hz` = ")
                    && e.contains(
                        "is out of range: allowed 0 (no high-pass) or 0.01 ..= 100 (a cut-off under 0.01 Hz rounds the filter to nothing or NaN)"
                    ),
                "{bad}: {e}"
            );
        }
        let e = Config::from_toml_str("[estimator]\nhighpass_hz = 1e-15\n", "x").unwrap_err();
        assert!(
            e.message.starts_with("`estimator.highpass_hz` = 1e-15 "),
            "{e}"
        );
        for ok in ["0.0", "-0.0", "0.01", "0.5", "1.8"] {
            Config::from_toml_str(&format!("[estimator]\nhighpass_hz = {ok}\n"), "x")
                .unwrap_or_else(|e| panic!("{ok}: {e}"));
        }
        // the upper end as before, with a low-pass and grid that allow it
        Config::from_toml_str(
            "[estimator]\ngrid_hz = 2000.0\nlowpass_hz = 200.0\nhighpass_hz = 100.0\n",
            "x",
        )
        .unwrap();
    }

    /// The lag-range and gap rules compare the window the estimator runs, `window_s` in
    /// whole hops, as the reference-lag rule does: a 2.9 s window of 2 s hops runs as
    /// 2 s, too short for a 2.9 s lag range (it never locks).
    #[test]
    fn window_rules_compare_the_window_in_whole_hops() {
        let err = |t: &str| Config::from_toml_str(t, "x.toml").unwrap_err().message;
        let base = "[estimator]\nhop_s = 2.0\nwindow_s = 2.9\nstep_window_s = 2.0\nreference_lag_s = 2.0\n";
        assert_eq!(
            err(&format!("{base}max_lag_s = 1.45\nmax_gap_s = 1.0\n")),
            "`estimator.window_s` = 2.9 in whole hops of 2 s is 2 s, which must be at least the lag range's width, 2 × `estimator.max_lag_s` (2.9)"
        );
        assert_eq!(
            err(&format!("{base}max_lag_s = 1.0\nmax_gap_s = 1.4\n")),
            "`estimator.max_gap_s` = 1.4 must not exceed half of the acquisition window (1): `estimator.window_s` = 2.9 in whole hops of 2 s is 2 s"
        );
        Config::from_toml_str(&format!("{base}max_lag_s = 1.0\nmax_gap_s = 1.0\n"), "x").unwrap();
        // rounded up: 2.75 s of 0.5 s hops runs as 3 s, wide enough for ±1.5 s
        Config::from_toml_str(
            "[estimator]\nwindow_s = 2.75\nmax_lag_s = 1.5\nmax_gap_s = 1.5\n",
            "x",
        )
        .unwrap();
        // a window of whole hops says only window_s, as before
        let e = err("[estimator]\nwindow_s = 1.5\nmax_lag_s = 1.0\nreference_lag_s = 1.5\nstep_window_s = 1.5\nmax_gap_s = 0.5\n");
        assert!(!e.contains("whole hops"), "{e}");
    }

    /// The ~100 MB bound counts the lag sums as the estimator allocates them (hop in
    /// whole grid steps, segment in whole hops, lags in whole grid steps), not from the
    /// values as written: this one, some 108 MB, passed as under 4000000.
    #[test]
    fn the_memory_bound_counts_lag_sums_as_the_estimator_does() {
        let text = "[estimator]\ngrid_hz = 89.8\nhop_s = 0.05\nmax_lag_s = 2.0\nwindow_s = 4.0\nsegment_s = 555.0\n";
        let e = Config::from_toml_str(text, "x").unwrap_err().message;
        assert_eq!(
            e,
            "`estimator.max_lag_s` = 2 with `estimator.grid_hz` = 89.8 and `estimator.segment_s`/`estimator.hop_s` = 555/0.05 need 4498421 lag sums (361 lags × 12460 + 1 blocks: the segment in whole hops of 0.044543 s, and the block being filled): allowed at most 4000000 (about 100 MB)"
        );
        let c: EstimatorConfig = toml::from_str(&text.replace("[estimator]\n", "")).unwrap();
        assert_eq!((c.lag_slots(), c.segment_blocks()), (361, 12460));
        Config::from_toml_str(&text.replace("555.0", "490.0"), "x").unwrap();
        // the defaults: ±50 lags, 120 blocks of 0.5 s
        let d = EstimatorConfig::default();
        assert_eq!(
            (d.lag_slots(), d.window_blocks(), d.segment_blocks()),
            (101, 12, 120)
        );
        assert_eq!(d.lag_sums(), 101.0 * 121.0);
        // the estimator's floors: two grid steps each side, a segment of a window
        let tiny = EstimatorConfig {
            max_lag_s: 0.0,
            segment_s: 0.0,
            ..d.clone()
        };
        assert_eq!((tiny.lag_slots(), tiny.segment_blocks()), (5, 12));
        // no panic on values never validated
        let wild = EstimatorConfig {
            max_lag_s: f64::INFINITY,
            grid_hz: f64::NAN,
            hop_s: 0.0,
            segment_s: f64::INFINITY,
            ..d
        };
        assert!(wild.lag_sums() > MAX_LAG_SUMS);
    }

    /// `daemon.state_file` and `daemon.load_hint_source` are absolute: the daemon's
    /// working directory under its systemd unit is /, read-only, where every save of a
    /// relative state file failed. A blank state file is refused, not taken for "".
    #[test]
    fn daemon_file_names_are_absolute() {
        let err = |t: &str| Config::from_toml_str(t, "x.toml").unwrap_err().message;
        assert_eq!(
            err("[daemon]\nstate_file = \"vlsync.state\"\n"),
            "`daemon.state_file` = \"vlsync.state\" is not an absolute path: it would be taken from the daemon's working directory, / under its systemd unit (read-only there); give the whole path, such as /run/vlsync/vlsync.state"
        );
        assert_eq!(
            err("[daemon]\nload_hint_source = \"proc/pressure/cpu\"\n"),
            "`daemon.load_hint_source` = \"proc/pressure/cpu\" is not an absolute path: it would be taken from the daemon's working directory, / under its systemd unit (read-only there); give the whole path, such as /proc/pressure/cpu"
        );
        for rel in ["./s", "../s", "~/s", " /run/s"] {
            let e = err(&format!("[daemon]\nstate_file = \"{rel}\"\n"));
            assert!(e.contains("is not an absolute path"), "{rel}: {e}");
        }
        assert_eq!(
            err("[daemon]\nstate_file = \"  \"\n"),
            "`daemon.state_file` = \"  \" is blank: give an absolute path, or \"\" for no persistence"
        );
        assert_eq!(
            err("[daemon]\nload_hints = true\nload_hint_source = \"\\t\"\n"),
            "`daemon.load_hint_source` = \"\\t\" is blank: give an absolute path"
        );
        let c = Config::from_toml_str(
            "[daemon]\nstate_file = \"/run/vlsync/vlsync.state\"\nload_hint_source = \"/sys/fs/cgroup/a/cpu.pressure\"\n",
            "x",
        )
        .unwrap();
        assert_eq!(c.daemon.state_file, "/run/vlsync/vlsync.state");
        // "" keeps its meaning: no persistence; no pressure file while hints are off
        Config::from_toml_str(
            "[daemon]\nstate_file = \"\"\nload_hint_source = \"\"\n",
            "x",
        )
        .unwrap();
        let e = err("[daemon]\nload_hints = true\nload_hint_source = \"\"\n");
        assert!(
            e.contains("is empty while `daemon.load_hints` is on"),
            "{e}"
        );
    }

    /// The installed configuration (deploy/vlsync.toml) validates, and names its
    /// state file by an absolute path.
    #[test]
    fn the_installed_file_validates() {
        let cfg =
            Config::from_toml_str(include_str!("../../deploy/vlsync.toml"), "deploy").unwrap();
        assert!(Path::new(&cfg.daemon.state_file).is_absolute());
    }

    #[test]
    fn count_keys_name_their_range_whatever_the_integer() {
        for (text, range) in [
            (
                "acquire_confirm = -1",
                "-1 is out of range: allowed 1 ..= 100",
            ),
            (
                "step_confirm = 4294967296",
                "4294967296 is out of range: allowed 1 ..= 100",
            ),
            (
                "cadence_confirm = 16",
                "16 is out of range: allowed 1 ..= 15",
            ),
            (
                "acquire_confirm = 2.5",
                "2.5 is not a whole number: allowed 1 ..= 100",
            ),
            (
                "acquire_confirm = 2.0",
                "2.0 is not a whole number: allowed 1 ..= 100",
            ),
            ("step_confirm = \"3\"", "expected a whole number 1 ..= 100"),
        ] {
            let e = Config::from_toml_str(&format!("[estimator]\n{text}\n"), "x.toml")
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(range) && e.contains(text) && e.contains("line 2"),
                "{e}"
            );
        }
        let c = Config::from_toml_str("[estimator]\nacquire_confirm = 100\n", "x").unwrap();
        assert_eq!(c.estimator.acquire_confirm, 100);
    }

    #[test]
    fn long_values_are_clipped_in_errors() {
        let long = "a".repeat(10_000_000);
        let e = Config::from_toml_str(&format!("[services]\nprefix = \"/{long}\"\n"), "x.toml")
            .unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("`services.prefix` = \"/aaa") && s.contains("…"),
            "{}",
            &s[..200]
        );
        assert!(s.len() < 300, "{} bytes", s.len());
        // a parse error quotes the offending line: cut, with its line and column kept
        let e = Config::from_toml_str(&format!("[estimator]\nwindow_s = 1 {long}\n"), "x.toml")
            .unwrap_err();
        let s = e.to_string();
        assert!(s.len() < 1000, "{} bytes", s.len());
        assert!(s.contains("line 2, column"), "{s}");
        let e = Config::from_toml_str(&format!("[{long}]\n"), "x.toml").unwrap_err();
        assert!(e.to_string().len() < 2000, "{} bytes", e.to_string().len());
    }

    #[test]
    fn range_errors_print_readable_numbers() {
        let e = Config::from_toml_str("[estimator]\nmax_abs_value = 1e301\n", "x").unwrap_err();
        assert_eq!(
            e.message,
            "`estimator.max_abs_value` = 1e301 is out of range: allowed 1e-9 ..= 1e12"
        );
        let e = Config::from_toml_str("[estimator]\nlag_center_s = -2e6\n", "x").unwrap_err();
        assert_eq!(
            e.message,
            "`estimator.lag_center_s` = -2e6 is out of range: allowed -1e6 ..= 1e6"
        );
        // everyday magnitudes as before (the README quotes this one)
        let e = Config::from_toml_str("[estimator]\nmax_lag_s = 5.0\n", "my.toml").unwrap_err();
        assert_eq!(
            e.to_string(),
            "config my.toml: `estimator.max_lag_s` = 5 is out of range: allowed 0.01 ..= 2"
        );
        assert_eq!(num(0.0), "0");
        assert_eq!(num(0.001), "0.001");
        assert_eq!(num(999_999.5), "999999.5");
        assert_eq!(num(f64::NAN), "NaN");
    }

    #[test]
    fn a_file_that_is_not_utf8_is_refused_at_its_line() {
        let dir = std::env::temp_dir().join(format!("vlsync-config-utf8-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("latin1.toml");
        // `# Caf\xe9` as an editor set to Latin-1 writes it
        std::fs::write(&f, b"[daemon]\n# Caf\xe9\ncore = 1\n").unwrap();
        let e = Config::load(&f).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "config {}: line 2: not UTF-8 (at byte offset 14)",
                f.display()
            )
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn only_regular_files_are_loaded() {
        let dir = std::env::temp_dir().join(format!("vlsync-config-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let e = Config::load(&dir).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        // a named pipe without a writer would block the read forever
        let fifo = dir.join("vlsync.toml");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        let e = Config::load(&fifo).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "config {}: cannot read: not a regular file (a named pipe)",
                fifo.display()
            )
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_too_large_to_be_a_configuration_is_refused_unread() {
        let dir = std::env::temp_dir().join(format!("vlsync-config-big-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // a sparse 1 GiB file (a recording given as --config): refused at once
        let big = dir.join("big.toml");
        std::fs::File::create(&big)
            .unwrap()
            .set_len(1 << 30)
            .unwrap();
        let e = Config::load(&big).unwrap_err().to_string();
        assert!(
            e.ends_with(
                "cannot read: larger than 1048576 bytes: too large for a configuration file"
            ),
            "{e}"
        );
        // the largest allowed still loads
        let edge = dir.join("edge.toml");
        let mut text = SHIPPED.to_string();
        text.push_str(&" ".repeat(MAX_FILE_BYTES as usize - text.len()));
        std::fs::write(&edge, &text).unwrap();
        assert!(Config::load(&edge).is_ok());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    proptest! {
        // The parser never panics on arbitrary text, and what it accepts validates.
        #[test]
        fn parser_never_panics(text in "\\PC{0,200}") {
            if let Ok(cfg) = Config::from_toml_str(&text, "fuzz") {
                prop_assert!(cfg.validate("fuzz").is_ok());
            }
        }

        /// Real keys with values of any type and size: what is accepted validates,
        /// and what is refused names the key it refuses. (Random text above rarely
        /// parses at all.)
        #[test]
        fn any_value_of_a_real_key_is_validated_or_named(
            picks in proptest::collection::vec((any::<proptest::sample::Index>(), 0u8..6, any::<f64>(), any::<i64>(), any::<bool>()), 1..4),
        ) {
            let defaults: toml::Table = toml::from_str(&toml::to_string(&Config::default()).unwrap()).unwrap();
            let keys: Vec<(String, String)> = defaults
                .iter()
                .flat_map(|(sec, t)| {
                    t.as_table().into_iter().flat_map(move |t| t.keys().map(move |k| (sec.clone(), k.clone())))
                })
                .collect();
            let mut table = defaults.clone();
            let mut changed = Vec::new();
            for (at, kind, x, n, b) in picks {
                let (sec, key) = &keys[at.index(keys.len())];
                let value = match kind {
                    0 if x.is_finite() => toml::Value::Float(x),
                    0 | 1 => toml::Value::Float((n % 10_000) as f64 / 7.0),
                    2 => toml::Value::Integer(n),
                    3 => toml::Value::Integer(n % 100),
                    4 => toml::Value::Boolean(b),
                    _ => toml::Value::String(format!("v{n}")),
                };
                table[sec.as_str()][key.as_str()] = value;
                changed.push(key.clone());
            }
            let text = toml::to_string(&table).unwrap();
            match Config::from_toml_str(&text, "p") {
                Ok(cfg) => prop_assert!(cfg.validate("p").is_ok()),
                Err(e) => {
                    let e = e.to_string();
                    prop_assert!(changed.iter().any(|k| e.contains(k.as_str())), "{e}\n{text}");
                }
            }
        }

        #[test]
        fn window_values_accepted_iff_in_range(w in -10.0f64..200.0) {
            let text = format!("[estimator]\nwindow_s = {w:?}\n");
            let r = Config::from_toml_str(&text, "p");
            // the default reference lag (3 s, covered by a window of 2.75 s or more: it
            // runs in whole 0.5 s hops) and segment (60 s, at least two windows) are the
            // binding limits
            let in_range = (2.75..=30.0).contains(&w);
            prop_assert_eq!(r.is_ok(), in_range, "w={}", w);
        }
    }
}
