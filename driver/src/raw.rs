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

use crate::{Source, SourceError};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use vlsync_common::{Nanos, Sample};
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

// ---------------------------------------------------------------- camera

/// Rendered frames as a [`FrameSource`].
struct RenderFrames {
    r: vlsync_render::Renderer,
    next: usize,
    cur: Option<vlsync_render::RenderedFrame>,
}

impl FrameSource for RenderFrames {
    fn next_frame(
        &mut self,
    ) -> Result<Option<(cam::GrayFrame<'_, u8>, cam::FrameTime)>, cam::Error> {
        let i = self.next;
        match self.r.render_frame(i) {
            None => Ok(None),
            Some(Err(e)) => Err(cam::Error::Decode {
                path: PathBuf::from(format!("render seed {} frame {i}", self.r.config().seed)),
                reason: e.to_string(),
            }),
            Some(Ok(f)) => {
                self.next += 1;
                let f = self.cur.insert(f);
                Ok(Some((f.image.view(), f.time)))
            }
        }
    }
}

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
    frames: Box<dyn FrameSource>,
    proc: cam::SignatureProcessor,
    what: String,
    stop: StopFn,
    counts: CamCounts,
    last_refusal: Option<String>,
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
        let proc = cam::SignatureProcessor::new(cam::SignatureConfig::default())
            .map_err(|e| SourceError(format!("{what}: camera signature config: {e}")))?;
        Ok(Self {
            frames,
            proc,
            what,
            stop,
            counts: CamCounts::default(),
            last_refusal: None,
        })
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
                "--v4l2 {}: built without V4L2 support; rebuild with --features v4l2",
                device.display()
            )));
        }
        let cfg = cam::V4l2Config {
            device: device.to_path_buf(),
            ..cam::V4l2Config::default()
        };
        let src = cam::V4l2Source::open(&cfg).map_err(|e| SourceError(format!("--v4l2: {e}")))?;
        let (w, h) = src.frame_size();
        Self::new(
            Box::new(src),
            format!("v4l2 {} ({w}x{h})", device.display()),
            stop,
        )
    }

    /// The frames of rendered run `seed` (see [`renderer`]).
    pub fn render(r: vlsync_render::Renderer) -> Result<Self, SourceError> {
        let what = format!(
            "render seed {} ({} s, {} frames)",
            r.config().seed,
            r.config().duration_s,
            r.frame_schedule().len()
        );
        Self::new(
            Box::new(RenderFrames {
                r,
                next: 0,
                cur: None,
            }),
            what,
            never,
        )
    }

    /// The counts so far.
    pub fn counts(&self) -> CamCounts {
        self.counts
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
                ..
            } = self;
            let Some((frame, time)) = frames
                .next_frame()
                .map_err(|e| SourceError(format!("{what}: {e}")))?
            else {
                return Ok(None);
            };
            counts.frames += 1;
            match proc.process(&frame, time) {
                Err(e) => {
                    counts.refused += 1;
                    *last_refusal = Some(e.to_string());
                }
                Ok(cam::Step::Started(r)) => match r {
                    cam::StartReason::First => {}
                    cam::StartReason::Gap { .. } => counts.gaps += 1,
                    cam::StartReason::NotIncreasing { .. } => counts.not_increasing += 1,
                    cam::StartReason::SizeChanged { .. } => counts.size_changed += 1,
                },
                Ok(cam::Step::Sample(s)) => {
                    if !s.sample.value.is_finite() {
                        counts.no_flow += 1;
                    } else if s.low_texture() {
                        counts.low_texture += 1;
                    } else {
                        counts.samples += 1;
                        return Ok(Some(s.sample));
                    }
                }
            }
        }
    }

    fn describe(&self) -> String {
        self.what.clone()
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
            // stop the motor's scan stream; nothing to do if the device is gone
            let _ = self.port.write_request(&lidar::rplidar::stop_request());
        }
    }
}

enum ScanInput {
    Csv(lidar::csv::CsvScanReader<std::io::BufReader<std::fs::File>>),
    Mcap(vlsync_mcap::McapScanSource),
    Render {
        r: Box<vlsync_render::Renderer>,
        next: usize,
    },
    Serial(Box<Serial>),
}

/// LiDAR scans through `SignatureProcessor::push_scan`.
pub struct LidarSource {
    input: ScanInput,
    proc: lidar::SignatureProcessor,
    queue: VecDeque<Sample>,
    what: String,
    scans: u64,
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
            proc,
            queue: VecDeque::new(),
            what,
            scans: 0,
        })
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

    /// The scans of a rendered run (see [`renderer`]).
    pub fn render(r: vlsync_render::Renderer) -> Result<Self, SourceError> {
        let what = format!(
            "render seed {} ({} s, {} scans)",
            r.config().seed,
            r.config().duration_s,
            r.scan_schedule().len()
        );
        Self::new(
            ScanInput::Render {
                r: Box::new(r),
                next: 0,
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
                port.write_request(&lidar::rplidar::scan_request())
                    .map_err(|e| SourceError(format!("{flag}: scan request: {e}")))?;
                Parser::Rplidar(RplidarParser::new(RplidarConfig {
                    baud,
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
        *self.proc.counters()
    }

    /// Reads more input into the queue; false at the end of the input.
    fn fill(&mut self) -> Result<bool, SourceError> {
        let Self {
            input,
            proc,
            queue,
            what,
            scans,
        } = self;
        let mut push = |scan: &lidar::Scan| {
            *scans += 1;
            proc.push_scan(scan, |s| {
                if s.value.is_finite() {
                    queue.push_back(s)
                }
            });
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
                Err(e) => Err(SourceError(format!("--mcap: {e}"))),
                Ok(Some(scan)) => {
                    push(scan);
                    Ok(true)
                }
            },
            ScanInput::Render { r, next } => match r.render_scan(*next) {
                None => Ok(false),
                Some(s) => {
                    *next += 1;
                    push(&s.scan);
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

impl Source for LidarSource {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        loop {
            if let Some(s) = self.queue.pop_front() {
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

    fn report(&self) -> Option<String> {
        let c = self.proc.counters();
        let mut s = format!(
            "{} scans, {} passes, {} samples; dropped:",
            self.scans, c.passes, c.samples
        );
        for r in lidar::DropReason::ALL {
            s.push_str(&format!(" {} {},", r.name(), c.dropped(r)));
        }
        s.push_str(&format!(" invalid returns {}", c.invalid_returns));
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
    first: Option<Sample>,
    inner: Box<dyn Source>,
}

impl Prefetched {
    /// Reads the first sample of `inner`.
    pub fn new(mut inner: Box<dyn Source>) -> Result<Self, SourceError> {
        let first = inner.next_sample()?;
        Ok(Self { first, inner })
    }

    /// The first sample's time.
    pub fn first_t_ns(&self) -> Option<Nanos> {
        self.first.map(|s| s.t_ns)
    }
}

impl Source for Prefetched {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        match self.first.take() {
            Some(s) => Ok(Some(s)),
            None => self.inner.next_sample(),
        }
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn report(&self) -> Option<String> {
        self.inner.report()
    }
}
