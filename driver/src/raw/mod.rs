//! Raw-sensor sources: frames and scans run through the front-ends
//! (`vlsync-signature-cam`, `vlsync-signature-lidar`) into signature samples.
//!
//! | stream | source | input |
//! |---|---|---|
//! | camera | [`CamSource::frames_dir`] | a directory of PNG/JPEG frames with `frames.csv` |
//! | camera | [`CamSource::mcap`] | a ROS 2 recording (`sensor_msgs/Image` or `CompressedImage`) |
//! | camera | [`CamSource::v4l2`] | a V4L2 device (cargo feature `v4l2`) |
//! | camera | [`CamSource::pipe`] | raw frames from a camera program's pipe (`rpicam-vid`) |
//! | camera | [`CamSource::render`] | frames of the rendering simulator |
//! | LiDAR | [`LidarSource::serial`] | an LD06/LD19 or RPLIDAR on a serial port |
//! | LiDAR | [`LidarSource::scans_csv`] | a scan CSV (one row per ray) |
//! | LiDAR | [`LidarSource::mcap`] | a ROS 2 recording (`sensor_msgs/LaserScan`) |
//! | LiDAR | [`LidarSource::render`] | scans of the rendering simulator |
//!
//! Samples the front-ends cannot vouch for (low texture, no tracked point,
//! passes with too few returns, ...) are not published: they are counted and
//! [`Source::report`] lists the counts. Errors name the file or device.
//!
//! Live devices stamp on the host's `CLOCK_MONOTONIC` (V4L2 buffer times
//! normally are; serial LiDAR chunks are stamped with it on arrival), so both
//! drivers of a robot share a time base up to the sensors' latencies.
//!
//! # Rendered runs: stamping and truth ([`RenderStamp`])
//!
//! * `Sensor`: the rendered sensor clocks (the camera clock carries the run's
//!   offset and drift; the LiDAR clock is the true time plus per-scan jitter).
//! * `Mono`: the same stamps carried onto `CLOCK_MONOTONIC`: true time `τ` maps
//!   to `τ + shift`, `shift = start_at - anchor` (both drivers of a pair compute
//!   the same from `--start-at`), so stamps of a real-time run read like the
//!   host clock while keeping the sensors' own stamping.
//! * `Software` (camera): frames are rendered ahead on their own thread (the
//!   "camera hardware", raised to nice −10 when allowed so host load does not
//!   slow it) and handed to the front-end when their exposure ends, at
//!   `τ_end + shift`; the driver reads `CLOCK_MONOTONIC` **after** the
//!   front-end processed the frame and uses that as the frame's time, like a
//!   cheap camera stamped in software. The sample is stamped at the midpoint of
//!   the two software stamps (the processor's rule with those times), so
//!   scheduling delays, CPU load and stalls move the stamps as they would on a
//!   robot. Its value is the flow over the frames' own interval, from their
//!   frame numbers and the nominal period (what a V4L2 buffer's `sequence`
//!   gives), not over the software interval: late frames would otherwise
//!   arrive in bursts a millisecond apart and turn into spikes of the signature.
//!
//! Every sample of a rendered source carries a [`SampleTruth`]: its true event
//! time on the run's time base (the midpoint of the two true mid-exposure
//! instants for the camera; for the LiDAR the stamp with the jitter of the two
//! scans it spans removed), so `stamp - event` is the stamping error and the
//! true offset of a pair is `(stamp - event)_LiDAR - (stamp - event)_camera`.

use crate::{Next, SampleTruth, Source, SourceError};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};
use vlsync_common::{Nanos, Sample};
use vlsync_ipc::monotonic_ns;
use vlsync_signature_cam as cam;
use vlsync_signature_lidar as lidar;

use cam::FrameSource;
use lidar::ld06::{Ld06Config, Ld06Parser};
use lidar::rplidar::{RplidarConfig, RplidarParser};
use lidar::rplidar_start::StartReport;
use lidar::serial::SerialLidar;

/// Returns true when the driver should stop (a live source checks it while it waits).
pub type StopFn = fn() -> bool;

fn never() -> bool {
    false
}

/// While a live device stays silent, how often its driver says so again.
pub const SILENCE_REPEAT: Duration = Duration::from_secs(600);

/// A live device's silence going on (a serial LiDAR without data, a V4L2 camera
/// without frames) while its driver reopens it: since when, when it was last said,
/// how many reopens it took.
#[derive(Debug, Clone, Copy)]
struct Silence {
    since: Instant,
    said: Instant,
    reopens: u64,
}

/// What to say about a silence now.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Say {
    /// It began (the first line).
    Began,
    /// It goes on: minutes so far, reopens so far (every [`SILENCE_REPEAT`]).
    Still { minutes: f64, reopens: u64 },
    /// Nothing yet.
    Nothing,
}

impl Silence {
    /// Notes in `slot` a silence at `now` that has lasted `so_far`: what to say.
    fn note(slot: &mut Option<Silence>, now: Instant, so_far: Duration) -> Say {
        match slot {
            None => {
                *slot = Some(Silence {
                    since: now.checked_sub(so_far).unwrap_or(now),
                    said: now,
                    reopens: 0,
                });
                Say::Began
            }
            Some(s) if now.duration_since(s.said) >= SILENCE_REPEAT => {
                s.said = now;
                Say::Still {
                    minutes: now.duration_since(s.since).as_secs_f64() / 60.0,
                    reopens: s.reopens,
                }
            }
            Some(_) => Say::Nothing,
        }
    }

    /// Counts a reopen of the device in the silence in `slot`.
    fn reopened(slot: &mut Option<Silence>) {
        if let Some(s) = slot {
            s.reopens += 1;
        }
    }

    /// Ends the silence in `slot`, if any: how long it lasted and its reopens.
    fn end(slot: &mut Option<Silence>) -> Option<(Duration, u64)> {
        slot.take().map(|s| (s.since.elapsed(), s.reopens))
    }

    /// How long the silence in `slot` has lasted, if one goes on.
    fn lasted(slot: &Option<Silence>) -> Option<Duration> {
        slot.map(|s| s.since.elapsed())
    }

    /// Notes a silence as [`Silence::note`] does and prints what there is to say
    /// ([`Silence::line`]).
    fn say(
        slot: &mut Option<Silence>,
        now: Instant,
        so_far: Duration,
        w: &SilenceWords,
        what: &str,
        why: &dyn std::fmt::Display,
    ) {
        if let Some(line) = Silence::line(Silence::note(slot, now, so_far), w, what, why) {
            // a sensor gone silent: a warning in the journal
            vlsync_common::console::print_err_at(vlsync_common::console::Priority::Warning, &line);
        }
    }

    /// The line for `say`: `why` when the silence begins, how long so far every
    /// [`SILENCE_REPEAT`], nothing between.
    fn line(say: Say, w: &SilenceWords, what: &str, why: &dyn std::fmt::Display) -> Option<String> {
        match say {
            Say::Began => Some(format!(
                "{}: {what}: {why}; {} the {} and waiting for it (said again every {} min while it lasts)\n",
                w.program,
                w.reopening,
                w.unit,
                SILENCE_REPEAT.as_secs() / 60
            )),
            Say::Still { minutes, reopens } => Some(format!(
                "{}: {what}: {} after {minutes:.0} min ({reopens} {} of the {})\n",
                w.program, w.still, w.reopens, w.unit
            )),
            Say::Nothing => None,
        }
    }

    /// Ends the silence in `slot`, if any, printing how long it lasted.
    fn say_end(slot: &mut Option<Silence>, w: &SilenceWords, what: &str) {
        if let Some((lasted, reopens)) = Silence::end(slot) {
            vlsync_common::console::print_err(&Silence::end_line(w, what, lasted, reopens));
        }
    }

    /// The line for `say_end`.
    fn end_line(w: &SilenceWords, what: &str, lasted: Duration, reopens: u64) -> String {
        format!(
            "{}: {what}: {} after {:.1} s of {} ({reopens} {} of the {})\n",
            w.program,
            w.again,
            lasted.as_secs_f64(),
            w.kind,
            w.reopens,
            w.unit
        )
    }
}

/// How a driver's lines name its device's silence.
struct SilenceWords {
    /// The driver, e.g. `vlsync-cam`.
    program: &'static str,
    /// What is reopened: `device`, `port`, `camera program`.
    unit: &'static str,
    /// What is done to it: `reopening`, `restarting`.
    reopening: &'static str,
    /// Those done: `reopens`, `restarts`.
    reopens: &'static str,
    /// Done: `reopened`, `restarted`.
    reopened: &'static str,
    /// The silence so far: `still no frame`, `still silent`.
    still: &'static str,
    /// Its end: `frames again`, `scans again`.
    again: &'static str,
    /// What it was: `stall`, `silence`.
    kind: &'static str,
}

#[cfg(test)]
mod render_rates_tests {
    use super::*;

    #[test]
    fn the_rates_reach_the_rendered_run() {
        let at = |cam_fps, lidar_hz| {
            renderer_at(3, 20.0, RenderRates { cam_fps, lidar_hz }).expect("a valid run")
        };
        let default = at(None, None);
        assert_eq!(RenderRates::default().resolved(), (30.0, 10.0));
        assert!(RenderRates::default().is_default());
        assert!(RenderRates {
            cam_fps: Some(30.0),
            lidar_hz: Some(10.0)
        }
        .is_default());
        let slow = at(Some(15.0), Some(5.0));
        assert!(!RenderRates {
            cam_fps: Some(15.0),
            lidar_hz: None
        }
        .is_default());
        // half the rates, about half the frames and scans (2 % of frames dropped at random)
        let (f30, f15) = (
            default.frame_schedule().len() as f64,
            slow.frame_schedule().len() as f64,
        );
        assert!((f30 / f15 - 2.0).abs() < 0.1, "{f30} {f15}");
        let (s10, s5) = (
            default.scan_schedule().len() as f64,
            slow.scan_schedule().len() as f64,
        );
        assert!((s10 / s5 - 2.0).abs() < 0.1, "{s10} {s5}");
        // the clocks are the seed's whatever the rates
        assert_eq!(default.truth(), slow.truth());
        // the LiDAR's scans depend on the camera's rate too (the draws are one
        // sequence): why both drivers of a pair take both rates
        let cam_only = at(Some(15.0), None);
        let scan_stamps = |r: &vlsync_render::Renderer| {
            r.scan_schedule()
                .iter()
                .map(|s| s.stamp_ns)
                .collect::<Vec<_>>()
        };
        assert_eq!(
            cam_only.scan_schedule().len(),
            default.scan_schedule().len()
        );
        assert_ne!(scan_stamps(&cam_only), scan_stamps(&default));
    }

    #[test]
    fn rates_are_checked_where_the_renderer_and_the_estimator_would_refuse_them() {
        let check = |cam_fps, lidar_hz, gap| RenderRates { cam_fps, lidar_hz }.check(gap, "here");
        assert!(check(None, None, 0.75).is_ok());
        assert!(check(Some(124.9), Some(100.0), 0.75).is_ok());
        assert!(check(Some(2.67), Some(2.67), 0.75).is_ok());
        // what the renderer refuses is refused here, the exposure's edge included
        for fps in [
            125.0,
            124.99999999999999,
            1e9,
            f64::NAN,
            f64::INFINITY,
            -30.0,
        ] {
            let e = check(Some(fps), None, 0.75).unwrap_err();
            assert!(
                e.starts_with(&format!(
                    "--render-fps {} is out of range",
                    vlsync_common::text::number(fps)
                )),
                "{e}"
            );
            let render = |cam_fps| {
                renderer_at(
                    1,
                    2.0,
                    RenderRates {
                        cam_fps,
                        lidar_hz: None,
                    },
                )
            };
            assert!(render(Some(fps)).is_err(), "{fps}");
        }
        assert!(renderer_at(
            1,
            2.0,
            RenderRates {
                cam_fps: Some(124.9),
                lidar_hz: Some(100.0)
            }
        )
        .is_ok());
        let e = check(None, Some(2.6), 0.75).unwrap_err();
        assert_eq!(
            e,
            "--render-lidar-hz 2.6 is out of range: allowed 2.67 ..= 100 (samples at most half \
             `estimator.max_gap_s` = 0.75 apart (here), so that a dropped one does not break \
             the stream)"
        );
        // a gap limit no camera rate fits says so (not "allowed 200 <= HZ < 125")
        let e = check(Some(30.0), None, 0.01).unwrap_err();
        assert!(
            e.starts_with("--render-fps 30: no camera rate fits: samples at most half"),
            "{e}"
        );
        assert!(e.contains("needs 200 Hz or more"), "{e}");
        // a longer gap limit lets slower sensors through, down to the renderer's own limits
        assert!(check(Some(1.0), Some(0.5), 4.0).is_ok());
        assert!(check(None, Some(0.4), 4.0).is_err());
    }
}

#[cfg(test)]
mod silence_tests {
    use super::*;

    #[test]
    fn each_driver_words_its_silence_as_before() {
        let cam = cam_source::CAM_STALL;
        let lidar = lidar_source::LIDAR_SILENCE;
        assert_eq!(
            Silence::line(Say::Began, &cam, "v4l2 /dev/video0", &"no frame for 10.0 s").unwrap(),
            "vlsync-cam: v4l2 /dev/video0: no frame for 10.0 s; reopening the device and waiting for it (said again every 10 min while it lasts)\n"
        );
        assert_eq!(
            Silence::line(Say::Still { minutes: 20.2, reopens: 121 }, &lidar, "ld06 /dev/ttyUSB0", &"")
                .unwrap(),
            "vlsync-lidar: ld06 /dev/ttyUSB0: still silent after 20 min (121 reopens of the port)\n"
        );
        assert_eq!(Silence::line(Say::Nothing, &lidar, "x", &""), None);
        assert_eq!(
            Silence::end_line(&cam, "v4l2 /dev/video0", Duration::from_millis(12_340), 1),
            "vlsync-cam: v4l2 /dev/video0: frames again after 12.3 s of stall (1 reopens of the device)\n"
        );
        assert_eq!(
            Silence::end_line(&lidar, "ld06 /dev/ttyUSB0", Duration::from_secs(3), 0),
            "vlsync-lidar: ld06 /dev/ttyUSB0: scans again after 3.0 s of silence (0 reopens of the port)\n"
        );
    }

    #[test]
    fn a_camera_program_s_stall_says_it_is_restarted_not_a_device_reopened() {
        let program = cam_source::PROGRAM_STALL;
        let what = "pipe raw i420 frames 320x240 (...) from `rpicam-vid`";
        assert_eq!(
            Silence::line(Say::Began, &program, what, &"camera program: no frame for 10.0 s")
                .unwrap(),
            format!("vlsync-cam: {what}: camera program: no frame for 10.0 s; restarting the camera program and waiting for it (said again every 10 min while it lasts)\n")
        );
        assert_eq!(
            Silence::line(Say::Still { minutes: 20.0, reopens: 60 }, &program, what, &"").unwrap(),
            format!("vlsync-cam: {what}: still no frame after 20 min (60 restarts of the camera program)\n")
        );
        assert_eq!(
            Silence::end_line(&program, what, Duration::from_secs(3), 1),
            format!("vlsync-cam: {what}: frames again after 3.0 s of stall (1 restarts of the camera program)\n")
        );
    }

    #[test]
    fn a_silence_is_said_once_then_every_repeat_period_with_its_reopens() {
        let t0 = Instant::now();
        let mut slot = None;
        let ten = Duration::from_secs(10);
        assert_eq!(Silence::note(&mut slot, t0, ten), Say::Began);
        Silence::reopened(&mut slot);
        assert_eq!(Silence::note(&mut slot, t0 + ten, ten), Say::Nothing);
        Silence::reopened(&mut slot);
        let later = t0 + SILENCE_REPEAT;
        assert_eq!(
            Silence::note(&mut slot, later, ten),
            Say::Still {
                minutes: (SILENCE_REPEAT + ten).as_secs_f64() / 60.0,
                reopens: 2
            }
        );
        assert_eq!(Silence::note(&mut slot, later + ten, ten), Say::Nothing);
        assert!(Silence::lasted(&slot).is_some());
        assert_eq!(Silence::end(&mut slot).map(|(_, n)| n), Some(2));
        assert!(slot.is_none() && Silence::end(&mut slot).is_none());
    }
}

/// Default render duration when none is given, seconds.
pub const DEFAULT_RENDER_DURATION_S: f64 = 60.0;

/// The rendering simulator's run for `seed` at its default sensor rates (camera and
/// LiDAR drivers given the same seed and duration render the same run).
pub fn renderer(seed: u64, duration_s: f64) -> Result<vlsync_render::Renderer, SourceError> {
    renderer_at(seed, duration_s, RenderRates::default())
}

/// The sensor rates of a rendered run (`vlsync-cam` / `vlsync-lidar --render-fps`,
/// `--render-lidar-hz`); `None` keeps the rendering simulator's default (a 30 Hz
/// camera, a 10 Hz LiDAR). The run's draws depend on both, so the two drivers of a
/// pair must be given the same rates, as they are the same seed.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RenderRates {
    /// Camera frames a second.
    pub cam_fps: Option<f64>,
    /// LiDAR revolutions a second.
    pub lidar_hz: Option<f64>,
}

impl RenderRates {
    /// The rendered rates, `(camera fps, LiDAR Hz)`, defaults filled in.
    pub fn resolved(self) -> (f64, f64) {
        let c = vlsync_render::RenderConfig::from_seed(0, 1.0);
        (
            self.cam_fps.unwrap_or(c.camera.fps),
            self.lidar_hz.unwrap_or(c.lidar.rate_hz),
        )
    }

    /// Whether both are the defaults.
    pub fn is_default(self) -> bool {
        let (c, l) = self.resolved();
        (c, l) == RenderRates::default().resolved()
    }

    /// The rates given, checked as options (`--render-fps`, `--render-lidar-hz`):
    /// within the rendering simulator's ranges (the camera's period longer than its
    /// exposure, as the renderer checks it), and samples at most half `max_gap_s`
    /// apart, so that one dropped sample does not break the stream (the estimator
    /// never interpolates across a gap longer than `max_gap_s`; `whose` says where
    /// that value came from).
    pub fn check(self, max_gap_s: f64, whose: &str) -> Result<(), String> {
        // the rendered camera exposes each frame for a fixed time, shorter than its period
        let exposure_s = vlsync_render::RenderConfig::from_seed(0, 1.0)
            .camera
            .exposure_s;
        // the slowest rate that passes, rounded up to the hundredth shown
        let slowest = (200.0 / max_gap_s).ceil() / 100.0;
        let gap = format!(
            "samples at most half `estimator.max_gap_s` = {max_gap_s} apart ({whose}), so that \
             a dropped one does not break the stream"
        );
        let given = [
            ("--render-fps", self.cam_fps, 1.0_f64, 1000.0_f64),
            ("--render-lidar-hz", self.lidar_hz, 0.5, 100.0),
        ];
        for (name, hz, lo, hi) in given {
            let Some(hz) = hz else { continue };
            let camera = name == "--render-fps";
            let in_range = hz.is_finite()
                && hz >= lo.max(slowest)
                && hz <= hi
                && (!camera || exposure_s < 1.0 / hz);
            if camera && lo.max(slowest) >= 1.0 / exposure_s {
                return Err(format!(
                    "{name} {}: no camera rate fits: {gap} needs {slowest} Hz or more, and \
                     the rendered camera's {} ms exposure allows under {} Hz",
                    vlsync_common::text::number(hz),
                    exposure_s * 1e3,
                    1.0 / exposure_s
                ));
            }
            if !in_range {
                let allowed = if camera {
                    format!(
                        "{} <= HZ < {} ({gap}; the rendered camera exposes each frame for {} ms)",
                        lo.max(slowest),
                        1.0 / exposure_s,
                        exposure_s * 1e3
                    )
                } else {
                    format!("{} ..= {hi} ({gap})", lo.max(slowest))
                };
                return Err(format!(
                    "{name} {} is out of range: allowed {allowed}",
                    vlsync_common::text::number(hz)
                ));
            }
        }
        Ok(())
    }
}

/// The rendering simulator's run for `seed` at `rates`.
pub fn renderer_at(
    seed: u64,
    duration_s: f64,
    rates: RenderRates,
) -> Result<vlsync_render::Renderer, SourceError> {
    let mut cfg = vlsync_render::RenderConfig::from_seed(seed, duration_s);
    (cfg.camera.fps, cfg.lidar.rate_hz) = rates.resolved();
    vlsync_render::Renderer::new(cfg).map_err(|e| SourceError(format!("render seed {seed}: {e}")))
}

/// The pacing anchor of a rendered pair: the earlier of the first frame's and
/// the first scan's stamps (both drivers compute the same).
pub fn render_anchor_ns(r: &vlsync_render::Renderer) -> Nanos {
    r.anchor_ns()
}

/// How a rendered source stamps its samples (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RenderStamp {
    /// The rendered sensor clocks.
    Sensor,
    /// The rendered sensor clocks carried onto `CLOCK_MONOTONIC` (`+ shift_ns`).
    Mono {
        /// `start_at - anchor`: true time `τ` happens at `τ + shift_ns` on `CLOCK_MONOTONIC`.
        shift_ns: Nanos,
    },
    /// Camera only: `CLOCK_MONOTONIC` read after the front-end processed each
    /// frame; frames are delivered in real time at the end of their exposure.
    Software {
        /// As for `Mono`.
        shift_ns: Nanos,
    },
}

impl RenderStamp {
    /// The shift from the run's true time to the published time base.
    pub fn shift_ns(self) -> Nanos {
        match self {
            RenderStamp::Sensor => 0,
            RenderStamp::Mono { shift_ns } | RenderStamp::Software { shift_ns } => shift_ns,
        }
    }
}

/// Works on the calling thread until its CPU clock reaches `until_ns`.
fn burn_cpu_until(until_ns: Nanos) {
    let mut x = 0x9e37_79b9_7f4a_7c15_u64;
    while vlsync_ipc::rt::thread_cpu_ns().is_some_and(|t| t < until_ns) {
        for _ in 0..256 {
            x = std::hint::black_box(x ^ (x << 13) ^ (x >> 7));
        }
    }
}

/// `(a + b) / 2` without overflow.
fn mid(a: Nanos, b: Nanos) -> Nanos {
    ((i128::from(a) + i128::from(b)).div_euclid(2)) as Nanos
}

mod cam_source;
mod lidar_source;

pub use cam_source::{
    CamCounts, CamSource, LiveCounts, PipeInput, PIPE_SILENCE, RENDER_AHEAD_FRAMES,
    RENDER_THREAD_NICE,
};
pub use lidar_source::{
    rplidar_config, rplidar_node_rate_hz, rplidar_nominal_period_ns, LidarSource, SerialKind,
};

/// A source whose first sample was read ahead (to anchor the pacing on it).
pub struct Prefetched {
    first: Option<(Sample, Option<SampleTruth>)>,
    first_out: bool,
    inner: Box<dyn Source>,
}

impl Prefetched {
    /// Reads the first sample of `inner` (which ends at once, without one, when a
    /// stop it checks was asked for meanwhile: give it the driver's stop).
    pub fn new(mut inner: Box<dyn Source>) -> Result<Self, SourceError> {
        let first = inner.next_sample()?.map(|s| (s, inner.truth()));
        Ok(Self {
            first,
            first_out: false,
            inner,
        })
    }

    /// The first sample's time.
    pub fn first_t_ns(&self) -> Option<Nanos> {
        self.first.map(|s| s.0.t_ns)
    }
}

impl Prefetched {
    /// The first sample, the first time; after it `None`.
    fn take_first(&mut self) -> Option<Sample> {
        match self.first {
            Some((s, _)) if !self.first_out => {
                self.first_out = true;
                Some(s)
            }
            _ => {
                self.first = None;
                None
            }
        }
    }
}

impl Source for Prefetched {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        match self.take_first() {
            Some(s) => Ok(Some(s)),
            None => self.inner.next_sample(),
        }
    }

    fn next_event(&mut self) -> Result<Next, SourceError> {
        match self.take_first() {
            Some(s) => Ok(Next::Sample(s)),
            None => self.inner.next_event(),
        }
    }

    fn truth(&self) -> Option<SampleTruth> {
        match self.first {
            Some((_, t)) if self.first_out => t,
            _ => self.inner.truth(),
        }
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn report(&self) -> Option<String> {
        self.inner.report()
    }
}
