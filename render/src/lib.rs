//! Rendering simulator for vlsync: a robot driving in a textured room, seen by
//! a pinhole camera (gray frames) and a sweeping 2-D LiDAR (scans with per-ray
//! times), on two clocks whose offset is known exactly.
//!
//! Where `vlsync-sim` generates *signatures*, this crate generates the *raw
//! sensor data* the front-ends consume, so the whole path — optical flow,
//! wall-distance rate, stamping, estimator — can be scored against the truth.
//!
//! * [`world`]: the room (walls, boxes) and horizontal ray casting;
//! * [`motion`]: the robot's drive (legs toward the front wall, ramps, cruise,
//!   stops, 180° turns at the ends), deterministic from a seed;
//! * [`texture`], [`scene`]: procedural floor, wall and ceiling textures;
//! * [`camera`]: pinhole rendering with motion blur and sensor noise;
//! * [`lidar`]: ray-cast scans, each ray at its own instant of the sweep;
//! * [`clock`]: offset, drift, latency steps, stamp jitter and the truth;
//! * [`output`]: a run on disk (`frames/*.png`, `frames.csv`, `scans.csv`,
//!   `truth.csv`, `motion.csv`);
//! * [`score`]: estimator output against the truth.
//!
//! [`Renderer`] streams the run in time order ([`Renderer::events`]): camera
//! frames as [`RenderedFrame`] (a [`GrayFrame`] with its [`FrameTime`] on the
//! camera clock) and LiDAR revolutions as [`RenderedScan`] (a
//! [`vlsync_signature_lidar::Scan`] on the LiDAR clock), each with its true time.
//!
//! ```
//! use vlsync_render::{Event, RenderConfig, Renderer};
//! let mut cfg = RenderConfig::from_seed(1, 3.0);
//! cfg.camera.width = 80;
//! cfg.camera.height = 60;
//! let mut r = Renderer::new(cfg).unwrap();
//! let truth = r.truth().clone();
//! let (mut frames, mut scans, mut last) = (0, 0, i64::MIN);
//! for ev in r.events() {
//!     let ev = ev.unwrap();
//!     assert!(ev.available_ns() >= last); // time order
//!     last = ev.available_ns();
//!     match ev {
//!         Event::Frame(f) => {
//!             frames += 1;
//!             // the convention: offset(t_L) = t_L - t_C, with t_L = τ (jitter aside)
//!             let err = (f.tau_mid_ns - f.stamp_ns) as f64 * 1e-9 - truth.offset_at(f.tau_mid_ns);
//!             assert!(err.abs() < 0.006);
//!         }
//!         Event::Scan(s) => {
//!             scans += 1;
//!             assert_eq!(s.scan.len(), 450);
//!         }
//!     }
//! }
//! assert!(frames > 80 && scans >= 29);
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod camera;
pub mod clock;
pub mod lidar;
pub mod motion;
pub mod output;
pub mod scene;
pub mod score;
pub mod stream;
pub mod texture;
pub mod world;

use camera::{CameraConfig, CameraModel};
use clock::{camera_stamp, ClockConfig};
use lidar::{LidarConfig, LidarModel};
use motion::{MotionConfig, Pose, Trajectory};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use scene::Scene;
use std::fmt;
use std::path::PathBuf;
use vlsync_common::text::number;
use vlsync_common::{nanos_to_secs, secs_to_nanos, Nanos};
use vlsync_sim::Truth;
use world::{BoxObstacle, Room};

pub use vlsync_signature_cam::{FrameTime, GrayFrame};
pub use vlsync_signature_lidar::{Ray, Rotation, Scan, ScanTiming};

/// An error, naming what and where.
#[derive(Debug)]
pub enum RenderError {
    /// A configuration value out of range.
    InvalidConfig {
        /// The field, e.g. `camera.width`.
        field: &'static str,
        /// What is wrong, with the value.
        reason: String,
    },
    /// A file could not be written.
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// An image could not be encoded or a frame built.
    Encode {
        /// The file (or frame) concerned.
        path: PathBuf,
        /// The cause.
        reason: String,
    },
}

impl RenderError {
    pub(crate) fn config(field: &'static str, reason: String) -> Self {
        RenderError::InvalidConfig { field, reason }
    }
}

impl fmt::Display for RenderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RenderError::InvalidConfig { field, reason } => {
                write!(f, "render config `{field}`: {reason}")
            }
            RenderError::Io { path, source } => write!(f, "{}: {source}", path.display()),
            RenderError::Encode { path, reason } => write!(f, "{}: {reason}", path.display()),
        }
    }
}

impl std::error::Error for RenderError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            RenderError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// Everything that defines a run.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderConfig {
    /// Seed of every random choice (room, drive, textures, noise, clocks).
    pub seed: u64,
    /// Run length, seconds (true time; 1..=3600).
    pub duration_s: f64,
    /// Room length (x, the driving direction), width (y) and height, metres.
    pub room: (f64, f64, f64),
    /// Box obstacles placed along the side walls (0..=8).
    pub boxes: usize,
    /// The drive.
    pub motion: MotionConfig,
    /// The camera.
    pub camera: CameraConfig,
    /// The LiDAR.
    pub lidar: LidarConfig,
    /// The clocks.
    pub clock: ClockConfig,
    /// Probability that a camera frame is dropped (default 2 %: a loaded USB
    /// bus or a busy reader).
    pub frame_drop_probability: f64,
}

impl RenderConfig {
    /// Defaults, with the clock offset (U[-0.2, 0.3] s) and drift (±20-60 ppm)
    /// drawn from `seed`.
    pub fn from_seed(seed: u64, duration_s: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0063_6c6f_636b); // "clock"
        let offset0_s = rng.gen_range(-0.2..0.3);
        let drift_ppm = rng.gen_range(20.0..60.0) * if rng.gen::<bool>() { 1.0 } else { -1.0 };
        Self {
            seed,
            duration_s,
            room: (8.0, 5.0, 2.5),
            boxes: 2,
            motion: MotionConfig::default(),
            camera: CameraConfig::default(),
            lidar: LidarConfig::default(),
            clock: ClockConfig {
                offset0_s,
                drift_ppm,
                ..ClockConfig::default()
            },
            frame_drop_probability: 0.02,
        }
    }

    /// Checks every field (each part's own checks included).
    pub fn validate(&self) -> Result<(), RenderError> {
        if !(self.duration_s.is_finite() && (1.0..=3600.0).contains(&self.duration_s)) {
            return Err(RenderError::config(
                "duration_s",
                format!("{} is outside 1..=3600", number(self.duration_s)),
            ));
        }
        if self.boxes > 8 {
            return Err(RenderError::config(
                "boxes",
                format!("{} is outside 0..=8", self.boxes),
            ));
        }
        if !(0.0..0.5).contains(&self.frame_drop_probability) {
            return Err(RenderError::config(
                "frame_drop_probability",
                format!(
                    "{} is outside 0 <= p < 0.5",
                    number(self.frame_drop_probability)
                ),
            ));
        }
        self.motion.validate()?;
        self.camera.validate()?;
        // a camera at or above the ceiling would see the ceiling from behind: every
        // ray looking up would hit it at a negative distance (the room's own range
        // is checked when the room is built)
        // (a room height out of its own range is left to the room's check, which names it)
        if (0.5..=100.0).contains(&self.room.2) && self.camera.height_m >= self.room.2 {
            return Err(RenderError::config(
                "camera.height_m",
                format!(
                    "{} m is not below the room's height ({} m, room.height): the camera \
                     must be inside the room",
                    number(self.camera.height_m),
                    number(self.room.2)
                ),
            ));
        }
        self.lidar.validate()?;
        self.clock.validate()?;
        // a step the run never reaches would be reported as one it has
        if let Some(&(t, _)) = self.clock.steps.iter().find(|s| s.0 >= self.duration_s) {
            return Err(RenderError::config(
                "clock.steps.time",
                format!(
                    "{} is not before the run's end ({} s)",
                    number(t),
                    number(self.duration_s)
                ),
            ));
        }
        Ok(())
    }
}

/// A scheduled camera frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameInfo {
    /// Frame number counting dropped frames.
    pub index: u64,
    /// True mid-exposure time, ns.
    pub tau_mid_ns: Nanos,
    /// Mid-exposure stamp on the camera clock, ns.
    pub stamp_ns: Nanos,
}

/// A scheduled LiDAR revolution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanInfo {
    /// Revolution number.
    pub index: u64,
    /// True time of the first ray, ns.
    pub tau_start_ns: Nanos,
    /// Stamp of the first ray on the LiDAR clock, ns.
    pub stamp_ns: Nanos,
}

/// One rendered camera frame.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedFrame {
    /// Frame number counting dropped frames (gaps show drops).
    pub index: u64,
    /// The image.
    pub image: GrayFrame<'static, u8>,
    /// Exposure start and duration on the camera clock (what a driver reports).
    pub time: FrameTime,
    /// Mid-exposure stamp on the camera clock, ns.
    pub stamp_ns: Nanos,
    /// True mid-exposure time, ns.
    pub tau_mid_ns: Nanos,
    /// True time at which the frame is complete (end of exposure), ns.
    pub tau_available_ns: Nanos,
}

/// One rendered LiDAR revolution.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedScan {
    /// Revolution number.
    pub index: u64,
    /// The scan on the LiDAR clock, with per-ray times.
    pub scan: Scan,
    /// True time of the first ray, ns.
    pub tau_start_ns: Nanos,
    /// True time at which the revolution is complete, ns.
    pub tau_available_ns: Nanos,
}

/// A frame or a scan, in the order the sensors deliver them.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A camera frame.
    Frame(RenderedFrame),
    /// A LiDAR revolution.
    Scan(RenderedScan),
}

impl Event {
    /// True time at which the data is complete, ns (the sort key of [`Renderer::events`]).
    pub fn available_ns(&self) -> Nanos {
        match self {
            Event::Frame(f) => f.tau_available_ns,
            Event::Scan(s) => s.tau_available_ns,
        }
    }
}

/// A run: the scene, the drive, the sensors, the schedules and the truth.
#[derive(Debug, Clone)]
pub struct Renderer {
    cfg: RenderConfig,
    scene: Scene,
    trajectory: Trajectory,
    camera: CameraModel,
    lidar: LidarModel,
    truth: Truth,
    frames: Vec<FrameInfo>,
    scans: Vec<ScanInfo>,
    dropped: usize,
}

/// Places `n` boxes along the side walls (within 0.8 m of them), clear of the
/// end zones where the robot turns.
fn place_boxes(rng: &mut ChaCha8Rng, room: &mut Room, n: usize) {
    for i in 0..n {
        let w = rng.gen_range(0.3..0.6);
        let d = rng.gen_range(0.3..0.6f64).min(0.8);
        let x0 = rng.gen_range(1.5..(room.length - 1.5 - w).max(1.6));
        let (y0, y1) = if i % 2 == 0 {
            (0.0, d)
        } else {
            (room.width - d, room.width)
        };
        room.boxes.push(BoxObstacle {
            x0,
            y0,
            x1: x0 + w,
            y1,
            height: rng.gen_range(0.3..1.0),
        });
    }
}

impl Renderer {
    /// Builds the run: validates, textures the room, plans the drive and
    /// schedules every frame and scan (rendering happens on demand).
    pub fn new(cfg: RenderConfig) -> Result<Self, RenderError> {
        cfg.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        let mut room = Room::new(cfg.room.0, cfg.room.1, cfg.room.2)?;
        place_boxes(&mut rng, &mut room, cfg.boxes);
        let trajectory = Trajectory::plan(&room, &cfg.motion, cfg.seed, cfg.duration_s)?;
        let scene = Scene::new(room, cfg.seed);
        let camera = CameraModel::new(&cfg.camera)?;
        let lidar = LidarModel::new(&cfg.lidar)?;
        let truth = cfg.clock.truth(cfg.duration_s);
        let end_ns = secs_to_nanos(cfg.duration_s);

        // camera schedule: regular true mid-exposure times, drops, stamp jitter
        let period = 1.0 / cfg.camera.fps;
        let half_exp = 0.5 * cfg.camera.exposure_s;
        let phase = half_exp + rng.gen_range(0.0..period);
        let mut frames = Vec::new();
        let mut dropped = 0;
        for k in 0.. {
            let tau = phase + k as f64 * period;
            if tau + half_exp > cfg.duration_s {
                break;
            }
            let jitter = cfg.clock.cam_jitter_s * rng.sample::<f64, _>(StandardNormal);
            if rng.gen::<f64>() < cfg.frame_drop_probability {
                dropped += 1;
                continue;
            }
            let tau_mid_ns = secs_to_nanos(tau);
            frames.push(FrameInfo {
                index: k,
                tau_mid_ns,
                stamp_ns: camera_stamp(&truth, tau_mid_ns, jitter),
            });
        }
        // LiDAR schedule: whole revolutions inside the run
        let pns = cfg.lidar.period_ns();
        let lphase = rng.gen_range(0..pns);
        let mut scans = Vec::new();
        for k in 0.. {
            let tau_start_ns = lphase + k as i64 * pns;
            if tau_start_ns + pns > end_ns {
                break;
            }
            let jitter = cfg.clock.lidar_jitter_s * rng.sample::<f64, _>(StandardNormal);
            scans.push(ScanInfo {
                index: k,
                tau_start_ns,
                stamp_ns: tau_start_ns + secs_to_nanos(jitter),
            });
        }
        Ok(Self {
            cfg,
            scene,
            trajectory,
            camera,
            lidar,
            truth,
            frames,
            scans,
            dropped,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &RenderConfig {
        &self.cfg
    }

    /// The true offset `t_L - t_C` as a function of LiDAR time.
    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    /// The drive.
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }

    /// The textured room.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Every camera frame that will be delivered (dropped ones excluded).
    pub fn frame_schedule(&self) -> &[FrameInfo] {
        &self.frames
    }

    /// Every LiDAR revolution.
    pub fn scan_schedule(&self) -> &[ScanInfo] {
        &self.scans
    }

    /// Camera frames dropped.
    pub fn frames_dropped(&self) -> usize {
        self.dropped
    }

    /// The pacing anchor of the run: the earlier of the first frame's and the first
    /// scan's stamps. Real-time consumers of a run map true time `τ` to
    /// `τ + start_at - anchor` on `CLOCK_MONOTONIC` (the drivers' `--stamp mono`,
    /// `vlsync-render --raw-stdout`), so they all agree from one `--start-at`.
    pub fn anchor_ns(&self) -> Nanos {
        let c = self.frames.first().map(|f| f.stamp_ns);
        let l = self.scans.first().map(|s| s.stamp_ns);
        match (c, l) {
            (Some(c), Some(l)) => c.min(l),
            (Some(t), None) | (None, Some(t)) => t,
            (None, None) => 0,
        }
    }

    /// LiDAR time at which the robot first moves, ns.
    pub fn motion_start_ns(&self) -> Nanos {
        secs_to_nanos(self.trajectory.motion_start_s())
    }

    /// Renders entry `i` of [`Renderer::frame_schedule`] (`None` past the end).
    pub fn render_frame(&mut self, i: usize) -> Option<Result<RenderedFrame, RenderError>> {
        let info = *self.frames.get(i)?;
        let c = &self.cfg.camera;
        let n = c.exposure_samples;
        let tau = nanos_to_secs(info.tau_mid_ns);
        let mut poses = [Pose {
            x: 0.0,
            y: 0.0,
            yaw: 0.0,
        }; 16];
        for (j, p) in poses.iter_mut().take(n).enumerate() {
            let u = (j as f64 + 0.5) / n as f64 - 0.5;
            *p = self.trajectory.pose(tau + u * c.exposure_s);
        }
        let mut pixels = vec![0u8; c.width * c.height];
        let noise_seed = camera::frame_noise_seed(self.cfg.seed, info.index);
        let (w, h) = (c.width, c.height);
        let exp_ns = secs_to_nanos(c.exposure_s);
        if let Err(e) = self
            .camera
            .render(&self.scene, &poses[..n], noise_seed, &mut pixels)
        {
            return Some(Err(e));
        }
        let image = match GrayFrame::owned(w, h, pixels) {
            Ok(f) => f,
            Err(e) => {
                return Some(Err(RenderError::Encode {
                    path: PathBuf::from(format!("frame {}", info.index)),
                    reason: e.to_string(),
                }))
            }
        };
        Some(Ok(RenderedFrame {
            index: info.index,
            image,
            time: FrameTime::Exposure {
                start_ns: info.stamp_ns - exp_ns / 2,
                duration_ns: exp_ns,
            },
            stamp_ns: info.stamp_ns,
            tau_mid_ns: info.tau_mid_ns,
            tau_available_ns: info.tau_mid_ns + exp_ns / 2,
        }))
    }

    /// Renders entry `i` of [`Renderer::scan_schedule`] (`None` past the end).
    pub fn render_scan(&self, i: usize) -> Option<RenderedScan> {
        let info = *self.scans.get(i)?;
        let l = self.lidar.config();
        let n = l.rays_per_turn;
        let pns = l.period_ns();
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.cfg.seed ^ 0x5ca9 ^ info.index.wrapping_mul(0xD1B5_4A32_D192_ED03),
        );
        let rays = (0..n)
            .map(|k| {
                let dt = (k as i128 * pns as i128 / n as i128) as i64;
                let pose = self.trajectory.pose(nanos_to_secs(info.tau_start_ns + dt));
                let bearing = l.bearing(k);
                let r = self.lidar.range(&self.scene.room, &pose, bearing, &mut rng);
                Ray::timed(
                    bearing,
                    r,
                    if r > 0.0 { 200.0 } else { 0.0 },
                    r > 0.0,
                    info.stamp_ns + dt,
                )
            })
            .collect();
        let timing = ScanTiming {
            start_ns: info.stamp_ns,
            period_ns: pns,
            rotation: l.rotation,
            start_bearing_rad: vlsync_signature_lidar::scan::wrap_pi(
                l.start_bearing_deg.to_radians(),
            ),
        };
        Some(RenderedScan {
            index: info.index,
            scan: Scan::from_timed(timing, rays),
            tau_start_ns: info.tau_start_ns,
            tau_available_ns: info.tau_start_ns + pns,
        })
    }

    /// Frames and scans in the order they are complete (true time; a frame
    /// before a scan on ties). Rendering happens as the iterator advances.
    pub fn events(&mut self) -> Events<'_> {
        Events {
            r: self,
            frame: 0,
            scan: 0,
        }
    }

    /// The run's LiDAR data as an LD06 byte stream (10 Hz at 3600 °/s, 4500
    /// points/s, device clock starting at 0 = true time 0), ray-cast at each
    /// point's own instant with the configured range noise. For the serial path.
    pub fn ld06_bytes(&self) -> Vec<u8> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ 0x1d06);
        let speed_dps = (self.cfg.lidar.rate_hz * 360.0).round().clamp(1.0, 65535.0) as u16;
        vlsync_signature_lidar::encode::ld06_stream(speed_dps, 0, self.cfg.duration_s, |t, b| {
            let pose = self.trajectory.pose(t);
            self.lidar.range(&self.scene.room, &pose, b, &mut rng)
        })
    }
}

/// Iterator over a run's frames and scans in time order; see [`Renderer::events`].
#[derive(Debug)]
pub struct Events<'a> {
    r: &'a mut Renderer,
    frame: usize,
    scan: usize,
}

impl Iterator for Events<'_> {
    type Item = Result<Event, RenderError>;

    fn next(&mut self) -> Option<Self::Item> {
        let exp_half = secs_to_nanos(self.r.cfg.camera.exposure_s) / 2;
        let f = self
            .r
            .frames
            .get(self.frame)
            .map(|f| f.tau_mid_ns + exp_half);
        let s = self
            .r
            .scans
            .get(self.scan)
            .map(|s| s.tau_start_ns + self.r.cfg.lidar.period_ns());
        let take_frame = match (f, s) {
            (None, None) => return None,
            (Some(_), None) => true,
            (None, Some(_)) => false,
            (Some(a), Some(b)) => a <= b,
        };
        if take_frame {
            self.frame += 1;
            self.r
                .render_frame(self.frame - 1)
                .map(|r| r.map(Event::Frame))
        } else {
            self.scan += 1;
            self.r
                .render_scan(self.scan - 1)
                .map(|s| Ok(Event::Scan(s)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small(seed: u64, d: f64) -> RenderConfig {
        let mut c = RenderConfig::from_seed(seed, d);
        c.camera.width = 64;
        c.camera.height = 48;
        c
    }

    #[test]
    fn runs_are_deterministic_and_seed_dependent() {
        let mut a = Renderer::new(small(4, 2.0)).unwrap();
        let mut b = Renderer::new(small(4, 2.0)).unwrap();
        let ea: Vec<Event> = a.events().map(Result::unwrap).collect();
        let eb: Vec<Event> = b.events().map(Result::unwrap).collect();
        assert_eq!(ea, eb);
        let mut c = Renderer::new(small(5, 2.0)).unwrap();
        let ec: Vec<Event> = c.events().map(Result::unwrap).collect();
        assert_ne!(ea, ec);
    }

    #[test]
    fn schedules_drops_and_scan_times() {
        let mut cfg = small(2, 60.0);
        cfg.frame_drop_probability = 0.1;
        let r = Renderer::new(cfg).unwrap();
        let total = r.frame_schedule().len() + r.frames_dropped();
        assert_eq!(total, 1800);
        let share = r.frames_dropped() as f64 / total as f64;
        assert!((0.07..0.13).contains(&share), "{share}");
        assert_eq!(r.scan_schedule().len(), 599);
        let s = r.render_scan(3).unwrap();
        let rays = s.scan.rays();
        assert_eq!(rays.len(), 450);
        // clockwise sweep from straight ahead, one ray every period / n
        assert!(rays[0].bearing_rad.abs() < 1e-12);
        assert!(rays[1].bearing_rad < 0.0);
        assert_eq!(rays[1].t_ns - rays[0].t_ns, 222_222);
        assert_eq!(rays[0].t_ns, s.scan.timing().start_ns);
        assert!((s.scan.timing().start_ns - s.tau_start_ns).abs() < 3_000_000);
        assert!(r.render_scan(599).is_none());
        assert_eq!(r.scan_schedule()[1].index, 1);
    }

    #[test]
    fn config_errors_name_the_field() {
        for (mutate, field) in [
            (
                Box::new(|c: &mut RenderConfig| c.duration_s = 0.0)
                    as Box<dyn Fn(&mut RenderConfig)>,
                "duration_s",
            ),
            (Box::new(|c: &mut RenderConfig| c.boxes = 99), "boxes"),
            (
                Box::new(|c: &mut RenderConfig| c.frame_drop_probability = f64::NAN),
                "frame_drop_probability",
            ),
            (
                Box::new(|c: &mut RenderConfig| c.camera.fps = 0.0),
                "camera.fps",
            ),
            (
                Box::new(|c: &mut RenderConfig| c.lidar.rate_hz = 1e9),
                "lidar.rate_hz",
            ),
            (
                Box::new(|c: &mut RenderConfig| c.room.0 = -1.0),
                "room.length",
            ),
            // a camera above the ceiling: both heights named
            (
                Box::new(|c: &mut RenderConfig| {
                    c.camera.height_m = 1.5;
                    c.room.2 = 1.2;
                }),
                "`camera.height_m`: 1.5 m is not below the room's height (1.2 m, room.height)",
            ),
            // the run is 5 s: a step at 100 s never happens
            (
                Box::new(|c: &mut RenderConfig| c.clock.steps = vec![(100.0, 0.01)]),
                "clock.steps.time",
            ),
        ] {
            let mut c = small(1, 5.0);
            mutate(&mut c);
            let e = Renderer::new(c).unwrap_err().to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
    }

    /// The drive is planned on the ripple-free speed and the poses integrate the
    /// rippled one, never re-synced (`motion`'s docs): over an hour the robot
    /// wanders from its plan, but its camera stays well inside the free space (a
    /// pose outside it fails the render). Seed 109 came nearest of seeds 1-150
    /// (its camera 0.32 m from a wall), seed 10 about as near; the plans keep the
    /// robot 0.7 m or more from the end walls.
    #[test]
    fn an_hour_long_drive_keeps_clear_of_the_walls() {
        for seed in [1, 10, 109] {
            let r = Renderer::new(small(seed, 3600.0)).unwrap();
            let (room, traj) = (&r.scene().room, r.trajectory());
            let forward = r.config().camera.forward_m;
            let mut nearest = f64::INFINITY;
            for k in 0..72_000 {
                let p = traj.pose(k as f64 * 0.05);
                let (x, y) = (p.x + forward * p.yaw.cos(), p.y + forward * p.yaw.sin());
                assert!(room.is_free(x, y), "seed {seed}: {p:?}");
                nearest = nearest.min(room.clearance(x, y));
            }
            assert!(
                nearest > 0.25,
                "seed {seed}: camera {nearest:.3} m from a wall"
            );
        }
    }

    #[test]
    fn ld06_stream_decodes_to_the_scene() {
        use vlsync_signature_lidar::ld06::{Ld06Clock, Ld06Config, Ld06Parser};
        let mut cfg = small(3, 2.0);
        cfg.lidar.range_noise_m = 0.0;
        let r = Renderer::new(cfg).unwrap();
        let bytes = r.ld06_bytes();
        let mut p = Ld06Parser::new(Ld06Config {
            clock: Ld06Clock::Device,
            ..Default::default()
        });
        let mut checked = 0;
        p.push(&bytes, 0, |scan| {
            for ray in scan.rays().iter().filter(|ray| ray.valid).step_by(37) {
                let t = nanos_to_secs(ray.t_ns);
                let pose = r.trajectory().pose(t);
                let expect = r.lidar.range(
                    &r.scene().room,
                    &pose,
                    ray.bearing_rad,
                    &mut rand::rngs::mock::StepRng::new(0, 0),
                );
                // mm quantisation, 0.01° angle quantisation, 1 ms device clock
                assert!(
                    (ray.range_m - expect).abs() < 0.01 + 0.002 * expect,
                    "{} vs {expect}",
                    ray.range_m
                );
                checked += 1;
            }
        });
        assert!(checked > 30, "{checked}");
    }
}
