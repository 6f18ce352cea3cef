//! Raw-sensor sources: frames and scans run through the front-ends
//! (`vlsync-signature-cam`, `vlsync-signature-lidar`) into signature samples.
//!
//! | stream | source | input |
//! |---|---|---|
//! | camera | [`CamSource::frames_dir`] | a directory of PNG/JPEG frames with `frames.csv` |
//! | camera | [`CamSource::mcap`] | a ROS 2 recording (`sensor_msgs/Image` or `CompressedImage`) |
//! | camera | [`CamSource::v4l2`] | a V4L2 device (cargo feature `v4l2`) |
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

use crate::{SampleTruth, Source, SourceError};
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
use lidar::serial::SerialLidar;

/// Returns true when the driver should stop (a live source checks it while it waits).
pub type StopFn = fn() -> bool;

fn never() -> bool {
    false
}

/// Default render duration when none is given, seconds.
pub const DEFAULT_RENDER_DURATION_S: f64 = 60.0;

/// The rendering simulator's run for `seed` (camera and LiDAR drivers given the
/// same seed and duration render the same run).
pub fn renderer(seed: u64, duration_s: f64) -> Result<vlsync_render::Renderer, SourceError> {
    vlsync_render::Renderer::new(vlsync_render::RenderConfig::from_seed(seed, duration_s))
        .map_err(|e| SourceError(format!("render seed {seed}: {e}")))
}

/// The pacing anchor of a rendered pair: the earlier of the first frame's and
/// the first scan's stamps (both drivers compute the same).
pub fn render_anchor_ns(r: &vlsync_render::Renderer) -> Nanos {
    let c = r.frame_schedule().first().map(|f| f.stamp_ns);
    let l = r.scan_schedule().first().map(|s| s.stamp_ns);
    match (c, l) {
        (Some(c), Some(l)) => c.min(l),
        (Some(t), None) | (None, Some(t)) => t,
        (None, None) => 0,
    }
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

// ---------------------------------------------------------------- camera

/// What the driver knows about a rendered frame beyond its image and time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct FrameTruth {
    /// Frame number counting dropped frames (a V4L2 buffer's `sequence`).
    sequence: u64,
    /// The camera's nominal frame period, ns.
    period_ns: Nanos,
    /// True mid-exposure, on the run's time base.
    event_ns: Nanos,
    /// Delivered this late after the end of exposure (software stamping).
    late_ns: Nanos,
    /// Rendered this late after the end of exposure (software stamping).
    render_late_ns: Nanos,
}

/// A frame, its time and its truth.
type TimedFrame<'a> = (cam::GrayFrame<'a, u8>, cam::FrameTime, Option<FrameTruth>);

/// Frames with their truth when the source knows it.
trait Frames {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error>;
    /// Real-time delivery counts and the render thread's priority (live rendering only).
    fn live(&self) -> Option<(LiveCounts, String)> {
        None
    }
    /// Frames the source skipped as unusable, and the last one's reason.
    fn unusable(&self) -> Option<(u64, &str)> {
        None
    }
}

/// A front-end frame source: no truth.
struct Plain(Box<dyn FrameSource>);

impl Frames for Plain {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error> {
        Ok(self.0.next_frame()?.map(|(f, t)| (f, t, None)))
    }
    fn unusable(&self) -> Option<(u64, &str)> {
        self.0.unusable()
    }
}

fn render_error(seed: u64, i: u64, e: &vlsync_render::RenderError) -> cam::Error {
    cam::Error::Decode {
        path: PathBuf::from(format!("render seed {seed} frame {i}")),
        reason: e.to_string(),
    }
}

/// Rendered frames on the rendered camera clock (shifted by `shift` ns), in turn.
struct RenderFrames {
    r: vlsync_render::Renderer,
    next: usize,
    shift: Nanos,
    period_ns: Nanos,
    cur: Option<vlsync_render::RenderedFrame>,
}

/// The nominal frame period of a rendered run, ns.
fn frame_period_ns(r: &vlsync_render::Renderer) -> Nanos {
    (1e9 / r.config().camera.fps).round() as Nanos
}

impl Frames for RenderFrames {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error> {
        let i = self.next;
        match self.r.render_frame(i) {
            None => Ok(None),
            // a frame that failed is skipped like one the camera dropped: the
            // next call renders the frame after it, not this one again
            Some(Err(e)) => {
                self.next += 1;
                Err(render_error(self.r.config().seed, i as u64, &e))
            }
            Some(Ok(f)) => {
                self.next += 1;
                let time = match f.time {
                    cam::FrameTime::Instant(t) => cam::FrameTime::Instant(t + self.shift),
                    cam::FrameTime::Exposure {
                        start_ns,
                        duration_ns,
                    } => cam::FrameTime::Exposure {
                        start_ns: start_ns + self.shift,
                        duration_ns,
                    },
                };
                let truth = FrameTruth {
                    sequence: f.index,
                    period_ns: self.period_ns,
                    event_ns: f.tau_mid_ns + self.shift,
                    ..FrameTruth::default()
                };
                let f = self.cur.insert(f);
                Ok(Some((f.image.view(), time, Some(truth))))
            }
        }
    }
}

/// Frames rendered ahead of time on a thread ("the camera hardware").
pub const RENDER_AHEAD_FRAMES: usize = 30;
/// Nice value asked for the render thread, so host load does not slow the
/// simulated camera hardware (refusal is reported, not fatal).
pub const RENDER_THREAD_NICE: i32 = -10;

struct Rendered {
    /// The frame's index in the run (named by an error).
    index: usize,
    frame: Result<vlsync_render::RenderedFrame, vlsync_render::RenderError>,
    /// `CLOCK_MONOTONIC` when rendering finished.
    done_ns: Nanos,
}

/// Rendered frames delivered in real time for software stamping.
struct LiveRender {
    rx: Receiver<Rendered>,
    seed: u64,
    shift: Nanos,
    period_ns: Nanos,
    stop: StopFn,
    /// Frames whose exposure ended before this were skipped (a restarted driver).
    skip_before: Nanos,
    cur: Option<vlsync_render::RenderedFrame>,
    nice: std::sync::Arc<std::sync::Mutex<Option<String>>>,
    live: LiveCounts,
}

/// What the real-time delivery of rendered frames saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LiveCounts {
    /// Frames delivered.
    pub delivered: u64,
    /// Frames skipped because their time passed before the driver started.
    pub skipped: u64,
    /// Frames the renderer finished after their exposure ended.
    pub render_late: u64,
    /// Largest render lateness, ns.
    pub max_render_late_ns: Nanos,
    /// Largest delivery lateness (end of exposure to front-end), ns.
    pub max_late_ns: Nanos,
}

impl LiveRender {
    fn start(r: vlsync_render::Renderer, shift: Nanos, stop: StopFn) -> Result<Self, SourceError> {
        let seed = r.config().seed;
        let period_ns = frame_period_ns(&r);
        let now = monotonic_ns();
        let exp_half = vlsync_common::secs_to_nanos(r.config().camera.exposure_s) / 2;
        // a driver restarted mid-run (start_at in the past) resumes at the current frame
        let skip_before = if shift + render_anchor_ns(&r) < now {
            now
        } else {
            Nanos::MIN
        };
        let first = r
            .frame_schedule()
            .iter()
            .position(|f| f.tau_mid_ns + exp_half + shift >= skip_before)
            .unwrap_or(r.frame_schedule().len());
        let (tx, rx) = sync_channel(RENDER_AHEAD_FRAMES);
        let nice = std::sync::Arc::new(std::sync::Mutex::new(None));
        let nice_t = nice.clone();
        let mut r = r;
        std::thread::Builder::new()
            .name("vlsync-render".into())
            .spawn(move || {
                let got = vlsync_ipc::rt::set_current_thread_nice(
                    RENDER_THREAD_NICE,
                    &format!("render thread nice {RENDER_THREAD_NICE}"),
                );
                if let Ok(mut n) = nice_t.lock() {
                    *n = Some(match got {
                        Ok(()) => format!("render thread at nice {RENDER_THREAD_NICE}"),
                        Err(e) => format!("{e}; render thread at the default priority"),
                    });
                }
                let mut i = first;
                while let Some(frame) = r.render_frame(i) {
                    let index = i;
                    i += 1;
                    let done_ns = monotonic_ns();
                    if tx
                        .send(Rendered {
                            index,
                            frame,
                            done_ns,
                        })
                        .is_err()
                    {
                        break; // the driver is gone
                    }
                }
            })
            .map_err(|e| {
                SourceError(format!(
                    "render seed {seed}: cannot start the render thread: {e}"
                ))
            })?;
        Ok(Self {
            rx,
            seed,
            shift,
            period_ns,
            stop,
            skip_before,
            cur: None,
            nice,
            live: LiveCounts {
                skipped: first as u64,
                ..LiveCounts::default()
            },
        })
    }
}

impl Frames for LiveRender {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error> {
        let f = loop {
            if (self.stop)() {
                return Ok(None);
            }
            let r = match self.rx.recv_timeout(MAX_WAIT) {
                Ok(r) => r,
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => return Ok(None),
            };
            let f = r
                .frame
                .map_err(|e| render_error(self.seed, r.index as u64, &e))?;
            let due = f.tau_available_ns + self.shift;
            if due < self.skip_before {
                self.live.skipped += 1;
                continue;
            }
            let render_late = (r.done_ns - due).max(0);
            if render_late > 0 {
                self.live.render_late += 1;
                self.live.max_render_late_ns = self.live.max_render_late_ns.max(render_late);
            }
            // the exposure ends at `due`: the frame exists from then on
            loop {
                let now = monotonic_ns();
                if now >= due {
                    break;
                }
                if (self.stop)() {
                    return Ok(None);
                }
                std::thread::sleep(Duration::from_nanos((due - now) as u64).min(MAX_WAIT));
            }
            break (f, render_late, due);
        };
        let (f, render_late_ns, due) = f;
        let now = monotonic_ns();
        let late_ns = now - due;
        self.live.delivered += 1;
        self.live.max_late_ns = self.live.max_late_ns.max(late_ns);
        let truth = FrameTruth {
            sequence: f.index,
            period_ns: self.period_ns,
            event_ns: f.tau_mid_ns + self.shift,
            late_ns,
            render_late_ns,
        };
        let f = self.cur.insert(f);
        Ok(Some((
            f.image.view(),
            cam::FrameTime::Instant(now),
            Some(truth),
        )))
    }

    fn live(&self) -> Option<(LiveCounts, String)> {
        let nice = self
            .nice
            .lock()
            .ok()
            .and_then(|n| n.clone())
            .unwrap_or_else(|| "render thread priority unknown".into());
        Some((self.live, nice))
    }
}

/// Longest single wait of the live render source, so a stop request is seen.
const MAX_WAIT: Duration = Duration::from_millis(50);

/// What the camera front-end did with the frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CamCounts {
    /// Frames read.
    pub frames: u64,
    /// Samples published.
    pub samples: u64,
    /// Samples dropped for low texture (too few tracked points).
    pub low_texture: u64,
    /// Samples dropped because no point was tracked or the value was not finite.
    pub no_flow: u64,
    /// Sequences restarted by a gap longer than `max_gap_ns` (dropped frames).
    pub gaps: u64,
    /// Frames whose time was not after the previous one (sequence restarted).
    pub not_increasing: u64,
    /// Frames whose size changed (sequence restarted).
    pub size_changed: u64,
    /// Frames the processor refused (bad exposure time, unusable size).
    pub refused: u64,
}

/// Camera frames through `SignatureProcessor`.
pub struct CamSource {
    frames: Box<dyn Frames>,
    proc: cam::SignatureProcessor,
    what: String,
    stop: StopFn,
    counts: CamCounts,
    last_refusal: Option<String>,
    /// Stamp each frame with `CLOCK_MONOTONIC` after processing it.
    software: bool,
    /// Software stamp and truth of the previous frame the processor kept.
    prev: Option<(Nanos, Option<FrameTruth>)>,
    last_truth: Option<SampleTruth>,
    /// CPU time each frame costs before it is stamped, ns (0: the front-end's own).
    frame_cpu_ns: Nanos,
    /// Frames of a recording that could not be read (an undecodable or missing
    /// image): skipped as dropped frames, until too many come in a row.
    skipped: cam::UnusableFrames,
}

impl std::fmt::Debug for CamSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CamSource")
            .field("what", &self.what)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

impl CamSource {
    fn new(frames: Box<dyn FrameSource>, what: String, stop: StopFn) -> Result<Self, SourceError> {
        Self::with_frames(Box::new(Plain(frames)), what, stop, false)
    }

    fn with_frames(
        frames: Box<dyn Frames>,
        what: String,
        stop: StopFn,
        software: bool,
    ) -> Result<Self, SourceError> {
        let proc = cam::SignatureProcessor::new(cam::SignatureConfig::default())
            .map_err(|e| SourceError(format!("{what}: camera signature config: {e}")))?;
        Ok(Self {
            frames,
            proc,
            what,
            stop,
            counts: CamCounts::default(),
            last_refusal: None,
            software,
            prev: None,
            last_truth: None,
            frame_cpu_ns: 0,
            skipped: cam::UnusableFrames::default(),
        })
    }

    /// With software stamping: keep each frame's thread busy until it has spent
    /// `ns` of CPU on the frame (front-end included) before stamping it; stands in
    /// for a heavier front-end, whose stamps CPU contention delays accordingly.
    pub fn set_frame_cpu_ns(&mut self, ns: Nanos) {
        self.frame_cpu_ns = ns.max(0);
    }

    /// A directory of frames with `frames.csv` (see `vlsync_signature_cam::source`).
    pub fn frames_dir(dir: &Path) -> Result<Self, SourceError> {
        let src = cam::DirSource::open(dir).map_err(|e| SourceError(format!("--frames: {e}")))?;
        let n = src.entries().len();
        Self::new(
            Box::new(src),
            format!("frames {} ({n} frames)", dir.display()),
            never,
        )
    }

    /// The image topic of a recording (`topic`, or the only image topic).
    pub fn mcap(path: &Path, topic: Option<&str>) -> Result<Self, SourceError> {
        let opts = match topic {
            Some(t) => vlsync_mcap::ImageSourceOptions::topic(t),
            None => vlsync_mcap::ImageSourceOptions::default(),
        };
        let src = vlsync_mcap::McapImageSource::open(path, opts)
            .map_err(|e| SourceError(format!("--mcap: {e}")))?;
        let what = format!("mcap {} topic {}", path.display(), src.topic().topic);
        Self::new(Box::new(src), what, never)
    }

    /// A V4L2 camera (`/dev/videoN`); needs the `v4l2` cargo feature.
    pub fn v4l2(device: &Path, stop: StopFn) -> Result<Self, SourceError> {
        if !cfg!(feature = "v4l2") {
            return Err(SourceError(format!(
                "--v4l2 {}: built without V4L2 support; rebuild with --features vlsync-driver/v4l2",
                device.display()
            )));
        }
        let cfg = cam::V4l2Config {
            device: device.to_path_buf(),
            ..cam::V4l2Config::default()
        };
        let mut src =
            cam::V4l2Source::open(&cfg).map_err(|e| SourceError(format!("--v4l2: {e}")))?;
        // a stalled camera's wait wakes to check the stop (and ends in an error after
        // `V4l2Config::stall`), instead of blocking the driver for good
        src.set_stop(stop);
        let (w, h) = src.frame_size();
        Self::new(
            Box::new(src),
            format!("v4l2 {} ({w}x{h})", device.display()),
            stop,
        )
    }

    /// The frames of rendered run `seed` on the rendered camera clock (see [`renderer`]).
    pub fn render(r: vlsync_render::Renderer) -> Result<Self, SourceError> {
        Self::render_with(r, RenderStamp::Sensor, never)
    }

    /// The frames of a rendered run, stamped as `stamp` says. `Software`
    /// renders on a thread and delivers each frame at the end of its exposure
    /// (`stop` is polled while waiting); the others render on demand.
    pub fn render_with(
        r: vlsync_render::Renderer,
        stamp: RenderStamp,
        stop: StopFn,
    ) -> Result<Self, SourceError> {
        let what = format!(
            "render seed {} ({} s, {} frames{})",
            r.config().seed,
            r.config().duration_s,
            r.frame_schedule().len(),
            match stamp {
                RenderStamp::Sensor => "",
                RenderStamp::Mono { .. } => ", sensor stamps on CLOCK_MONOTONIC",
                RenderStamp::Software { .. } =>
                    ", real time, stamped on CLOCK_MONOTONIC after processing",
            }
        );
        match stamp {
            RenderStamp::Software { shift_ns } => Self::with_frames(
                Box::new(LiveRender::start(r, shift_ns, stop)?),
                what,
                stop,
                true,
            ),
            _ => Self::with_frames(
                Box::new(RenderFrames {
                    period_ns: frame_period_ns(&r),
                    r,
                    next: 0,
                    shift: stamp.shift_ns(),
                    cur: None,
                }),
                what,
                never,
                false,
            ),
        }
    }

    /// The counts so far.
    pub fn counts(&self) -> CamCounts {
        self.counts
    }

    /// Real-time delivery counts of a software-stamped render.
    pub fn live_counts(&self) -> Option<LiveCounts> {
        self.frames.live().map(|l| l.0)
    }
}

impl Source for CamSource {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        loop {
            if (self.stop)() {
                return Ok(None);
            }
            let Self {
                frames,
                proc,
                what,
                counts,
                last_refusal,
                software,
                prev,
                last_truth,
                frame_cpu_ns,
                skipped,
                ..
            } = self;
            let next = match frames.next() {
                Ok(next) => next,
                // one bad image of a recording is a dropped frame, not the end of it
                Err(e) if e.is_one_frame() => {
                    skipped
                        .skip(e.to_string())
                        .map_err(|m| SourceError(format!("{what}: {m}")))?;
                    continue;
                }
                Err(e) => return Err(SourceError(format!("{what}: {e}"))),
            };
            let Some((frame, time, truth)) = next else {
                return Ok(None);
            };
            skipped.used();
            counts.frames += 1;
            let t_in = monotonic_ns();
            let cpu_in = (*frame_cpu_ns > 0)
                .then(vlsync_ipc::rt::thread_cpu_ns)
                .flatten();
            let step = proc.process(&frame, time);
            if let Some(c0) = cpu_in {
                burn_cpu_until(c0.saturating_add(*frame_cpu_ns));
            }
            // software stamping: the clock is read once the front-end is done
            let t_done = monotonic_ns();
            let this = (t_done, truth);
            match step {
                Err(e) => {
                    counts.refused += 1;
                    *last_refusal = Some(e.to_string());
                    *prev = None;
                }
                Ok(cam::Step::Started(r)) => {
                    *prev = Some(this);
                    match r {
                        cam::StartReason::First => {}
                        cam::StartReason::Gap { .. } => counts.gaps += 1,
                        cam::StartReason::NotIncreasing { .. } => counts.not_increasing += 1,
                        cam::StartReason::SizeChanged { .. } => counts.size_changed += 1,
                    }
                }
                Ok(cam::Step::Sample(s)) => {
                    let before = prev.replace(this);
                    let mut sample = s.sample;
                    if *software {
                        // stamped at the midpoint of the two software stamps; the
                        // flow is over the frames' own interval: the frame numbers
                        // times the nominal period when known (software stamps
                        // jitter by tens of ms under load, the sensor's clock does
                        // not), else the software interval
                        let p_sw = before.map_or(t_done, |b| b.0);
                        let dt = t_done - p_sw;
                        if dt <= 0 {
                            counts.not_increasing += 1;
                            continue;
                        }
                        let interval = match (before.and_then(|b| b.1), truth) {
                            (Some(a), Some(b)) if b.sequence > a.sequence && b.period_ns > 0 => {
                                (b.sequence - a.sequence) as f64 * b.period_ns as f64
                            }
                            _ => dt as f64,
                        };
                        sample = Sample::new(
                            mid(p_sw, t_done),
                            s.flow_px * vlsync_common::NANOS_PER_SEC as f64 / interval,
                        );
                    }
                    if !sample.value.is_finite() {
                        counts.no_flow += 1;
                    } else if s.low_texture() {
                        counts.low_texture += 1;
                    } else {
                        counts.samples += 1;
                        *last_truth = match (before.and_then(|b| b.1), truth) {
                            (Some(a), Some(b)) => Some(SampleTruth {
                                event_ns: mid(a.event_ns, b.event_ns),
                                late_ns: b.late_ns,
                                process_ns: t_done - t_in,
                                render_late_ns: b.render_late_ns,
                            }),
                            _ => None,
                        };
                        return Ok(Some(sample));
                    }
                }
            }
        }
    }

    fn describe(&self) -> String {
        self.what.clone()
    }

    fn truth(&self) -> Option<SampleTruth> {
        self.last_truth
    }

    fn report(&self) -> Option<String> {
        let c = &self.counts;
        let mut s = format!(
            "{} frames, {} samples; dropped: {} low texture, {} no flow; restarts: {} gaps, \
             {} non-increasing times, {} size changes; {} frames refused",
            c.frames,
            c.samples,
            c.low_texture,
            c.no_flow,
            c.gaps,
            c.not_increasing,
            c.size_changed,
            c.refused
        );
        if let Some(r) = &self.last_refusal {
            s.push_str(&format!(" (last: {r})"));
        }
        // a live camera's bad buffers (its source counts them), a recording's bad images
        for (n, last) in [self.frames.unusable(), self.skipped.counts()]
            .into_iter()
            .flatten()
        {
            s.push_str(&format!("; {n} unusable frames skipped (last: {last})"));
        }
        if let Some((l, nice)) = self.frames.live() {
            s.push_str(&format!(
                "; real time: {} frames delivered, {} skipped (before a restart), {} rendered late \
                 (worst {:.1} ms), worst delivery {:.1} ms after exposure end; {nice}",
                l.delivered,
                l.skipped,
                l.render_late,
                l.max_render_late_ns as f64 / 1e6,
                l.max_late_ns as f64 / 1e6
            ));
        }
        Some(s)
    }
}

// ---------------------------------------------------------------- LiDAR

/// Which serial LiDAR.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SerialKind {
    /// LDROBOT LD06 / LD19 (230400 baud, streams on power-up).
    Ld06,
    /// Slamtec RPLIDAR standard scan (115200 baud by default; the scan request is sent).
    Rplidar,
}

impl SerialKind {
    /// The usual baud rate.
    pub fn default_baud(self) -> u32 {
        match self {
            SerialKind::Ld06 => lidar::ld06::BAUD,
            SerialKind::Rplidar => RplidarConfig::default().baud,
        }
    }

    fn flag(self) -> &'static str {
        match self {
            SerialKind::Ld06 => "--ld06",
            SerialKind::Rplidar => "--rplidar",
        }
    }
}

enum Parser {
    Ld06(Ld06Parser),
    Rplidar(RplidarParser),
}

/// A live serial LiDAR.
struct Serial {
    port: SerialLidar,
    parser: Parser,
    stop: StopFn,
    /// No bytes for this long is an error.
    silence: Duration,
    last_bytes: Instant,
    last_scan: Instant,
    scans: u64,
}

impl Drop for Serial {
    fn drop(&mut self) {
        if matches!(self.parser, Parser::Rplidar(_)) {
            // stop the scan stream; nothing to do if the device is gone. The A1/A2
            // motor keeps spinning: asserting DTR here would not outlast the close,
            // whose hang-up (HUPCL, which serialport leaves set) releases it again
            let _ = self.port.write_request(&lidar::rplidar::stop_request());
        }
    }
}

/// Nodes per second an RPLIDAR sends in standard scan mode at `baud`: the C1
/// (460800 baud) 5000, the A1/A2 (115200) 2000. It dates a revolution's start from
/// the bytes that came after its start node in the same read, so a wrong rate
/// biases every stamp by up to a read's worth of bytes (tens of ms at 460800).
pub fn rplidar_node_rate_hz(baud: u32) -> u32 {
    if baud >= 460_800 {
        5000
    } else {
        2000
    }
}

enum ScanInput {
    Csv(lidar::csv::CsvScanReader<std::io::BufReader<std::fs::File>>),
    Mcap(vlsync_mcap::McapScanSource),
    Render {
        r: Box<vlsync_render::Renderer>,
        next: usize,
        shift: Nanos,
        /// `(first-ray stamp, stamp - true time)` of the last scans: the jitter to undo.
        recent: VecDeque<(Nanos, Nanos)>,
    },
    Serial(Box<Serial>),
}

/// LiDAR scans through `SignatureProcessor::push_scan`.
pub struct LidarSource {
    input: ScanInput,
    proc: lidar::WallFront,
    queue: VecDeque<(Sample, Option<SampleTruth>)>,
    what: String,
    scans: u64,
    last_truth: Option<SampleTruth>,
    /// Scans of a recording that could not be used (a malformed `LaserScan`):
    /// skipped as missed revolutions, until too many come in a row.
    skipped: cam::UnusableFrames,
}

impl std::fmt::Debug for LidarSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LidarSource")
            .field("what", &self.what)
            .field("scans", &self.scans)
            .finish_non_exhaustive()
    }
}

impl LidarSource {
    fn new(input: ScanInput, what: String) -> Result<Self, SourceError> {
        let proc = lidar::SignatureProcessor::new(lidar::SignatureConfig::default())
            .map_err(|e| SourceError(format!("{what}: {e}")))?;
        Ok(Self {
            input,
            proc: lidar::WallFront::One(Box::new(proc)),
            queue: VecDeque::new(),
            what,
            scans: 0,
            last_truth: None,
            skipped: cam::UnusableFrames::named("scans"),
        })
    }

    /// Fits the wall in the bearing window(s) `f` gives (the `[lidar]` section of
    /// the configuration) instead of the default window.
    pub fn with_front(mut self, f: &vlsync_config::LidarConfig) -> Result<Self, SourceError> {
        let cfg = lidar::SignatureConfig {
            window_centre_rad: lidar::scan::wrap_pi(f.window_centre_deg.to_radians()),
            window_half_width_rad: f.window_half_width_deg.to_radians(),
            ..lidar::SignatureConfig::default()
        };
        let err = |e: lidar::ConfigError| SourceError(format!("{}: {e}", self.what));
        self.proc = lidar::WallFront::new(cfg, f.opposite_window).map_err(err)?;
        self.what = format!(
            "{}; wall window {:.1}° ± {:.1}°{}",
            self.what,
            f.window_centre_deg,
            f.window_half_width_deg,
            if f.opposite_window {
                " and the opposite one"
            } else {
                ""
            }
        );
        Ok(self)
    }

    /// A scan CSV (`vlsync_signature_lidar::csv`'s format).
    pub fn scans_csv(path: &Path) -> Result<Self, SourceError> {
        let r = lidar::csv::CsvScanReader::open(path)
            .map_err(|e| SourceError(format!("--scans: {e}")))?;
        Self::new(ScanInput::Csv(r), format!("scans {}", path.display()))
    }

    /// The `LaserScan` topic of a recording (`topic`, or the only one).
    pub fn mcap(path: &Path, topic: Option<&str>) -> Result<Self, SourceError> {
        let opts = match topic {
            Some(t) => vlsync_mcap::ScanSourceOptions::topic(t),
            None => vlsync_mcap::ScanSourceOptions::default(),
        };
        let src = vlsync_mcap::McapScanSource::open(path, opts)
            .map_err(|e| SourceError(format!("--mcap: {e}")))?;
        let what = format!("mcap {} topic {}", path.display(), src.topic().topic);
        Self::new(ScanInput::Mcap(src), what)
    }

    /// The scans of a rendered run on the rendered LiDAR clock (see [`renderer`]).
    pub fn render(r: vlsync_render::Renderer) -> Result<Self, SourceError> {
        Self::render_with(r, RenderStamp::Sensor)
    }

    /// The scans of a rendered run, stamped as `stamp` says (`Software` is a
    /// camera mode and is refused).
    pub fn render_with(
        r: vlsync_render::Renderer,
        stamp: RenderStamp,
    ) -> Result<Self, SourceError> {
        let what = format!(
            "render seed {} ({} s, {} scans{})",
            r.config().seed,
            r.config().duration_s,
            r.scan_schedule().len(),
            match stamp {
                RenderStamp::Sensor => "",
                RenderStamp::Mono { .. } => ", sensor stamps on CLOCK_MONOTONIC",
                RenderStamp::Software { .. } => {
                    return Err(SourceError(format!(
                        "render seed {}: software stamping is a camera mode; the LiDAR \
                         stamps like its sensor (--stamp sensor or mono)",
                        r.config().seed
                    )));
                }
            }
        );
        Self::new(
            ScanInput::Render {
                r: Box::new(r),
                next: 0,
                shift: stamp.shift_ns(),
                recent: VecDeque::new(),
            },
            what,
        )
    }

    /// A serial LiDAR at `path`; `baud` defaults to the device's usual rate.
    /// Rays are stamped on arrival with `CLOCK_MONOTONIC`. No bytes for
    /// `silence` is an error naming the device.
    pub fn serial(
        kind: SerialKind,
        path: &str,
        baud: Option<u32>,
        silence: Duration,
        stop: StopFn,
    ) -> Result<Self, SourceError> {
        let baud = baud.unwrap_or(kind.default_baud());
        let flag = kind.flag();
        let mut port = SerialLidar::open(path, baud, Duration::from_millis(50))
            .map_err(|e| SourceError(format!("{flag}: {e}")))?;
        let parser = match kind {
            SerialKind::Ld06 => Parser::Ld06(Ld06Parser::new(Ld06Config {
                baud,
                ..Ld06Config::default()
            })),
            SerialKind::Rplidar => {
                // the A1/A2 USB adapter runs the motor while DTR is released, and
                // Linux asserted it on open; a C1 or a port without modem lines
                // ignores or refuses this, which does not matter to the scan
                let _ = port.set_dtr(false);
                port.write_request(&lidar::rplidar::scan_request())
                    .map_err(|e| SourceError(format!("{flag}: scan request: {e}")))?;
                Parser::Rplidar(RplidarParser::new(RplidarConfig {
                    baud,
                    sample_rate_hz: rplidar_node_rate_hz(baud),
                    ..RplidarConfig::default()
                }))
            }
        };
        let now = Instant::now();
        let what = format!("{} {path} at {baud} baud", &flag[2..]);
        Self::new(
            ScanInput::Serial(Box::new(Serial {
                port,
                parser,
                stop,
                silence,
                last_bytes: now,
                last_scan: now,
                scans: 0,
            })),
            what,
        )
    }

    /// Scans read so far.
    pub fn scans(&self) -> u64 {
        self.scans
    }

    /// The front-end's counters.
    pub fn counters(&self) -> lidar::Counters {
        *self.proc.ahead().counters()
    }

    /// Reads more input into the queue; false at the end of the input.
    fn fill(&mut self) -> Result<bool, SourceError> {
        let Self {
            input,
            proc,
            queue,
            what,
            scans,
            skipped,
            ..
        } = self;
        // returns how many samples were queued
        let mut push = |scan: &lidar::Scan| {
            *scans += 1;
            let mut n = 0;
            proc.push_scan(scan, |s| {
                if s.value.is_finite() {
                    queue.push_back((s, None));
                    n += 1;
                }
            });
            n
        };
        match input {
            ScanInput::Csv(r) => match r.next() {
                None => Ok(false),
                Some(Err(e)) => Err(SourceError(format!("--scans: {e}"))),
                Some(Ok(scan)) => {
                    push(&scan);
                    Ok(true)
                }
            },
            ScanInput::Mcap(m) => match m.next_scan() {
                Ok(None) => Ok(false),
                // one malformed message is a missed revolution, not the end of the recording
                Err(e @ vlsync_mcap::Error::Message { .. }) => {
                    skipped
                        .skip(e.to_string())
                        .map_err(|m| SourceError(format!("--mcap: {m}")))?;
                    Ok(true)
                }
                Err(e) => Err(SourceError(format!("--mcap: {e}"))),
                Ok(Some(scan)) => {
                    skipped.used();
                    push(scan);
                    Ok(true)
                }
            },
            ScanInput::Render {
                r,
                next,
                shift,
                recent,
            } => match r.render_scan(*next) {
                None => Ok(false),
                Some(s) => {
                    *next += 1;
                    let start = s.scan.timing().start_ns;
                    recent.push_back((start, start - s.tau_start_ns));
                    if recent.len() > 8 {
                        recent.pop_front();
                    }
                    let n = push(&s.scan);
                    let period = s.scan.timing().period_ns;
                    let before = queue.len() - n;
                    for (sample, truth) in queue.iter_mut().skip(before) {
                        *truth = Some(SampleTruth {
                            event_ns: lidar_event_ns(recent, sample.t_ns, period) + *shift,
                            ..SampleTruth::default()
                        });
                        sample.t_ns += *shift;
                    }
                    Ok(true)
                }
            },
            ScanInput::Serial(s) => {
                if (s.stop)() {
                    return Ok(false);
                }
                let Serial {
                    port,
                    parser,
                    last_bytes,
                    last_scan,
                    scans: serial_scans,
                    silence,
                    ..
                } = &mut **s;
                let (chunk, t) = port
                    .read_chunk(&vlsync_ipc::monotonic_ns)
                    .map_err(|e| SourceError(format!("{what}: {e}")))?;
                let now = Instant::now();
                if !chunk.is_empty() {
                    *last_bytes = now;
                }
                let before = *serial_scans;
                let mut on_scan = |scan: &lidar::Scan| {
                    *serial_scans += 1;
                    push(scan);
                };
                match parser {
                    Parser::Ld06(p) => p.push(chunk, t, &mut on_scan),
                    Parser::Rplidar(p) => p.push(chunk, t, &mut on_scan),
                }
                if *serial_scans != before {
                    *last_scan = now;
                }
                if now.duration_since(*last_bytes) > *silence {
                    return Err(SourceError(format!(
                        "{what}: no data for {:.1} s (is the LiDAR powered and the baud rate right?)",
                        silence.as_secs_f64()
                    )));
                }
                if now.duration_since(*last_scan) > *silence {
                    return Err(SourceError(format!(
                        "{what}: bytes but no complete scan for {:.1} s (wrong device type or baud rate?)",
                        silence.as_secs_f64()
                    )));
                }
                Ok(true)
            }
        }
    }
}

/// True time of a LiDAR sample stamped `t` (the midpoint of two passes over the
/// bearing window, one revolution apart): `t` minus the mean stamp jitter of the
/// scans holding `t - period/2` and `t + period/2`. Exact unless a pass's median
/// ray lies within the jitter of a scan boundary.
fn lidar_event_ns(recent: &VecDeque<(Nanos, Nanos)>, t: Nanos, period: Nanos) -> Nanos {
    let jitter_at = |x: Nanos| {
        recent
            .iter()
            .rev()
            .find(|(start, _)| *start <= x)
            .or(recent.front())
            .map_or(0, |(_, j)| *j)
    };
    t - mid(jitter_at(t - period / 2), jitter_at(t + period / 2))
}

impl Source for LidarSource {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        loop {
            if let Some((s, truth)) = self.queue.pop_front() {
                self.last_truth = truth;
                return Ok(Some(s));
            }
            if !self.fill()? {
                return Ok(None);
            }
        }
    }

    fn describe(&self) -> String {
        self.what.clone()
    }

    fn truth(&self) -> Option<SampleTruth> {
        self.last_truth
    }

    fn report(&self) -> Option<String> {
        let c = self.proc.ahead().counters();
        let mut s = format!(
            "{} scans, {} passes, {} samples; dropped:",
            self.scans, c.passes, c.samples
        );
        for r in lidar::DropReason::ALL {
            s.push_str(&format!(" {} {},", r.name(), c.dropped(r)));
        }
        s.push_str(&format!(" invalid returns {}", c.invalid_returns));
        if let Some((n, last)) = self.skipped.counts() {
            s.push_str(&format!("; {n} unusable scans skipped (last: {last})"));
        }
        if let Some(w) = self.proc.opposite() {
            let c = w.behind().counters();
            s.push_str(&format!(
                "; opposite window: {} passes, {} samples, {} dropped out of time order",
                c.passes,
                c.samples,
                w.out_of_order()
            ));
        }
        if let ScanInput::Serial(ser) = &self.input {
            match &ser.parser {
                Parser::Ld06(p) => {
                    let st = p.stats();
                    s.push_str(&format!(
                        "; LD06: {} bytes, {} packets, {} CRC errors, {} skipped bytes, {} invalid packets",
                        st.bytes, st.packets, st.crc_errors, st.skipped_bytes, st.invalid_packets
                    ));
                }
                Parser::Rplidar(p) => {
                    let st = p.stats();
                    s.push_str(&format!(
                        "; RPLIDAR: {} bytes, {} nodes, {} skipped bytes, {} false starts",
                        st.bytes, st.nodes, st.skipped_bytes, st.false_starts
                    ));
                }
            }
        }
        Some(s)
    }
}

/// A source whose first sample was read ahead (to anchor the pacing on it).
pub struct Prefetched {
    first: Option<(Sample, Option<SampleTruth>)>,
    first_out: bool,
    inner: Box<dyn Source>,
}

impl Prefetched {
    /// Reads the first sample of `inner`.
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

impl Source for Prefetched {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        match self.first {
            Some((s, _)) if !self.first_out => {
                self.first_out = true;
                Ok(Some(s))
            }
            _ => {
                self.first = None;
                self.inner.next_sample()
            }
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
