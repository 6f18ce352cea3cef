//! A run on disk, in the formats the front-ends and tools read:
//!
//! * `frames/frame_NNNNNN.png` (gray) and `frames.csv`
//!   (`file,t_s,exposure_start_s,exposure_s`, camera clock; `t_s` is the
//!   mid-exposure stamp) — `vlsync_signature_cam::DirSource`'s format;
//! * `scans.csv` — `vlsync_signature_lidar::csv`'s format, one row per ray with
//!   its own time `t_s` (LiDAR clock);
//! * `truth.csv` — `t,offset` every 10 ms (LiDAR clock), as `vlsync-sim` writes it;
//! * `motion.csv` — `t,x,y,yaw,speed,yaw_rate` every 10 ms (true time), for plots;
//! * optionally ([`write_run_with`], `vlsync-render --mcap`) a ROS 2 recording
//!   of the same frames and scans, which `vlsync_mcap::McapImageSource` and
//!   `McapScanSource` (the drivers' `--mcap`) read. See below.
//!
//! # The MCAP recording
//!
//! One file, profile `ros2`, two topics, written in the order the sensors
//! deliver ([`Renderer::events`]):
//!
//! * [`MCAP_IMAGE_TOPIC`] (`/camera/image_raw`): `sensor_msgs/msg/Image`,
//!   `mono8`, frame id [`MCAP_CAMERA_FRAME_ID`]; with [`McapOutput::png`]
//!   instead [`MCAP_PNG_TOPIC`] (`/camera/image_raw/compressed`, image_transport's
//!   name): `sensor_msgs/msg/CompressedImage`, lossless PNG. `header.stamp` is
//!   the **mid-exposure** stamp on the camera clock, `frames.csv`'s `t_s`. The
//!   message has no exposure field, so `exposure_start_s` and `exposure_s` are
//!   not recorded: `McapImageSource` takes the stamp as the frame's instant
//!   (`FrameTime::Instant(t_s)`), which is exactly the instant `DirSource`
//!   derives from `frames.csv` (`start + duration / 2`, to the nanosecond), so
//!   the camera front-end stamps the same samples from either.
//! * [`MCAP_SCAN_TOPIC`] (`/scan`): `sensor_msgs/msg/LaserScan`, frame id
//!   [`MCAP_LIDAR_FRAME_ID`], written by `vlsync_mcap::McapWriter::write_scan`:
//!   `header.stamp` is the first ray's time on the LiDAR clock (`scans.csv`'s
//!   first `t_s` of the scan), `time_increment` and `angle_increment` the ray
//!   spacing, `scan_time` the period. Read back, ray `i` is at
//!   `stamp + round(i · time_increment)`: the rays are evenly spaced (the
//!   LiDAR clock's jitter is per scan), and the `float32` increment puts them
//!   within a few ns of `scans.csv`'s times (1 ns at the default 450 rays,
//!   10 Hz). Ranges are `float32`; invalid rays (no return) are NaN.
//!
//! Stamps may be negative (with a positive offset `t_L - t_C` the camera clock
//! reads less than the true time, which starts at 0); `builtin_interfaces/Time`
//! holds them. The MCAP **log time** of a message is the true time at which the
//! sensor delivered it (end of exposure, end of the revolution): a recorder
//! with a perfect clock and no transport latency. It is never negative, orders
//! the file as the sensors deliver, and is what `StampSource::LogTime` reads.
//!
//! ```
//! use vlsync_render::{output::write_run, RenderConfig, Renderer};
//! let dir = std::env::temp_dir().join(format!("vlsync-render-doc-{}", std::process::id()));
//! let mut cfg = RenderConfig::from_seed(2, 1.0);
//! cfg.camera.width = 48;
//! cfg.camera.height = 32;
//! let mut r = Renderer::new(cfg).unwrap();
//! let s = write_run(&mut r, &dir, true).unwrap();
//! assert_eq!(s.frames, r.frame_schedule().len());
//! let src = vlsync_signature_cam::DirSource::open(&dir).unwrap();
//! assert_eq!(src.entries().len(), s.frames);
//! std::fs::remove_dir_all(&dir).unwrap();
//! ```

use crate::{Event, RenderError, Renderer};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Component, Path, PathBuf};
use std::time::{Duration, Instant};
use vlsync_common::Nanos;
use vlsync_mcap::McapWriter;
use vlsync_signature_lidar::csv::{format_seconds, write_header, write_scan};

/// Topic of the frames in the MCAP recording (`sensor_msgs/msg/Image`, `mono8`).
pub const MCAP_IMAGE_TOPIC: &str = "/camera/image_raw";
/// Topic of the frames when written as PNG (`sensor_msgs/msg/CompressedImage`).
pub const MCAP_PNG_TOPIC: &str = "/camera/image_raw/compressed";
/// Topic of the scans in the MCAP recording (`sensor_msgs/msg/LaserScan`).
pub const MCAP_SCAN_TOPIC: &str = "/scan";
/// `header.frame_id` of the frames.
pub const MCAP_CAMERA_FRAME_ID: &str = "camera";
/// `header.frame_id` of the scans.
pub const MCAP_LIDAR_FRAME_ID: &str = "laser";

/// An MCAP recording to write beside the directory (see the module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct McapOutput {
    /// The file (created or truncated; its directory must exist).
    pub path: PathBuf,
    /// Frames as PNG `CompressedImage`s on [`MCAP_PNG_TOPIC`] instead of
    /// `mono8` `Image`s on [`MCAP_IMAGE_TOPIC`].
    pub png: bool,
}

impl McapOutput {
    /// The topic the frames go to.
    pub fn image_topic(&self) -> &'static str {
        if self.png {
            MCAP_PNG_TOPIC
        } else {
            MCAP_IMAGE_TOPIC
        }
    }
}

/// What [`write_run`] wrote, and how long it took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Frames rendered: written as PNGs and listed in `frames.csv` (and in the
    /// MCAP recording, if any); with `png = false` neither (no `frames.csv`).
    pub frames: usize,
    /// Frames dropped by the camera model.
    pub frames_dropped: usize,
    /// Scans written.
    pub scans: usize,
    /// Rays written.
    pub rays: usize,
    /// Time spent rendering frames and scans.
    pub render_time: Duration,
    /// Time spent encoding and writing.
    pub write_time: Duration,
}

/// How far a [`write_run_observed`] has got, after each frame or scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Progress {
    /// True time at which the last frame or scan done was complete, ns.
    pub sim_ns: Nanos,
    /// The run's length (true time), ns.
    pub sim_total_ns: Nanos,
    /// Frames done.
    pub frames: usize,
    /// Scans done.
    pub scans: usize,
}

/// The files of a run in its directory besides `frames/*.png` and the default
/// recording ([`DEFAULT_MCAP`]): a new run removes them all (and those) before it
/// writes any (`frames.csv` is not written with
/// `png = false`), so a run that fails leaves none of an earlier run's beside
/// its own.
pub const RUN_FILES: [&str; 4] = ["frames.csv", "scans.csv", "truth.csv", "motion.csv"];

/// The header of a run's `motion.csv`: it marks a directory an earlier render
/// wrote, whose frames and default recording a new run removes.
const MOTION_HEADER: &str = "t,x,y,yaw,speed,yaw_rate";

/// The recording's file name in the run's directory when `--mcap` names none;
/// an earlier render's (its `motion.csv` there) is removed with [`RUN_FILES`]
/// and `frames/frame_*.png`, unless this run writes it.
pub const DEFAULT_MCAP: &str = "run.mcap";

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RenderError + '_ {
    move |source| RenderError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn create(path: &Path) -> Result<BufWriter<File>, RenderError> {
    File::create(path).map(BufWriter::new).map_err(io_err(path))
}

/// An MCAP error as a render error (`vlsync_mcap::Error` names the file).
fn mcap_err(e: vlsync_mcap::Error) -> RenderError {
    RenderError::Encode {
        path: e.path().to_path_buf(),
        reason: e.detail(),
    }
}

/// `p` absolute, through the symbolic links of its longest existing prefix, with
/// `.` and `..` of the rest resolved by name (the rest need not exist yet).
fn resolve(p: &Path) -> PathBuf {
    let abs = if p.is_absolute() {
        p.to_path_buf()
    } else {
        match std::env::current_dir() {
            Ok(d) => d.join(p),
            Err(_) => p.to_path_buf(),
        }
    };
    let comps: Vec<Component<'_>> = abs.components().collect();
    for k in (1..=comps.len()).rev() {
        let prefix: PathBuf = comps[..k].iter().collect();
        if let Ok(mut out) = prefix.canonicalize() {
            for c in &comps[k..] {
                match c {
                    Component::ParentDir => {
                        out.pop();
                    }
                    Component::CurDir => {}
                    other => out.push(other.as_os_str()),
                }
            }
            return out;
        }
    }
    abs
}

/// Which of the run's own outputs in `dir` the file `path` is, if any: one of
/// [`RUN_FILES`], the `frames` directory or a `frames/frame_*.png` (relative to
/// `dir`). An MCAP recording there would be overwritten by the run itself.
///
/// ```
/// use std::path::Path;
/// use vlsync_render::output::own_output;
/// let dir = Path::new("/tmp/some-run");
/// assert_eq!(own_output(dir, Path::new("/tmp/some-run/./truth.csv")).as_deref(), Some("truth.csv"));
/// assert_eq!(own_output(dir, Path::new("/tmp/some-run/run.mcap")), None);
/// ```
pub fn own_output(dir: &Path, path: &Path) -> Option<String> {
    let d = resolve(dir);
    let p = resolve(path);
    if let Some(f) = RUN_FILES.iter().find(|f| p == d.join(f)) {
        return Some((*f).to_string());
    }
    let frames = d.join("frames");
    if p == frames {
        return Some("frames".into());
    }
    let name = p.file_name()?.to_string_lossy().into_owned();
    (p.parent() == Some(frames.as_path()) && name.starts_with("frame_") && name.ends_with(".png"))
        .then(|| format!("frames/{name}"))
}

/// Whether a run into `dir` makes the directory `d` itself: `d` does not exist yet
/// and is `dir`, its `frames/` when PNGs are written, or an ancestor of `dir`
/// (compared resolved, so `./out` is `out`). An MCAP recording's directory that the
/// run makes need not exist before it; one that exists already is checked before
/// the run like any other (an existing ancestor was taken for one the run makes,
/// and a recording there that could not be written failed after the setup).
///
/// ```
/// use std::path::Path;
/// use vlsync_render::output::run_makes;
/// let dir = Path::new("/tmp/no-such-base/runs/seed3");
/// assert!(run_makes(dir, false, Path::new("/tmp/no-such-base/runs/./seed3")));
/// assert!(run_makes(dir, false, Path::new("/tmp/no-such-base/runs")));
/// assert!(run_makes(dir, true, Path::new("/tmp/no-such-base/runs/seed3/frames")));
/// assert!(!run_makes(dir, false, Path::new("/tmp/no-such-base/runs/seed3/frames")));
/// assert!(!run_makes(dir, false, Path::new("/tmp/no-such-base/elsewhere")));
/// // an ancestor that exists is not made by the run
/// assert!(!run_makes(dir, false, Path::new("/tmp")));
/// ```
pub fn run_makes(dir: &Path, png: bool, d: &Path) -> bool {
    let (dir, d) = (resolve(dir), resolve(d));
    // `symlink_metadata`: anything at `d`, a file or a dangling link too, is not made
    let absent = std::fs::symlink_metadata(&d).is_err();
    absent && (d == dir || (png && d == dir.join("frames")) || dir.starts_with(&d))
}

/// Renders the whole run into `dir` (created if needed). With `png = false`
/// the frames are rendered but neither written nor listed: no `frames/` and no
/// `frames.csv` (for timing, or with an MCAP recording only).
pub fn write_run(r: &mut Renderer, dir: &Path, png: bool) -> Result<Summary, RenderError> {
    write_run_with(r, dir, png, None)
}

/// [`write_run`], and with `mcap` also the MCAP recording of the same frames
/// and scans (see the module docs), in the same rendering pass. The recording
/// is complete only when this returns `Ok`.
pub fn write_run_with(
    r: &mut Renderer,
    dir: &Path,
    png: bool,
    mcap: Option<&McapOutput>,
) -> Result<Summary, RenderError> {
    write_run_observed(r, dir, png, mcap, &mut |_| {})
}

/// [`write_run_with`], calling `progress` after each frame and scan (for a
/// progress report: a long run takes minutes).
///
/// The order makes a failed run unable to leave a mixed directory: the MCAP
/// recording is created first (a path it cannot create fails before anything in
/// `dir` is touched), then every file of [`RUN_FILES`] an earlier run left is
/// removed, then `truth.csv` and `motion.csv` (known before rendering) are
/// written, then the frames and scans as they are rendered. A run that fails
/// part way leaves only its own files, the last ones partial. An `mcap` path
/// that is one of the run's own outputs ([`own_output`]) is refused.
pub fn write_run_observed(
    r: &mut Renderer,
    dir: &Path,
    png: bool,
    mcap: Option<&McapOutput>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Summary, RenderError> {
    let frames_dir = dir.join("frames");
    let made = if png { &frames_dir } else { dir };
    std::fs::create_dir_all(made).map_err(io_err(made))?;
    if let Some(name) = mcap.and_then(|m| own_output(dir, &m.path)) {
        let m = mcap.map(|m| m.path.clone()).unwrap_or_default();
        return Err(RenderError::Io {
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "the MCAP recording would be {}, one of the run's own outputs",
                    dir.join(name).display()
                ),
            ),
            path: m,
        });
    }
    // the recording first: a path it cannot create must fail before the files of an
    // earlier run in `dir` are removed
    let mut rec = match mcap {
        Some(m) => Some((McapWriter::create(&m.path).map_err(mcap_err)?, m)),
        None => None,
    };
    // an earlier render's frames (a longer run's beyond this one's last) and its
    // default recording, unless that is the recording being written now: a
    // directory then holds one run, not parts of two. Only where an earlier
    // render is (its motion.csv): a user's own frames or recording in a
    // directory that held no render are left alone
    let earlier_render = std::fs::read(dir.join("motion.csv"))
        .is_ok_and(|b| b.starts_with(MOTION_HEADER.as_bytes()));
    let default_mcap = dir.join(DEFAULT_MCAP);
    let old_mcap = (earlier_render
        && default_mcap.exists()
        && !mcap.is_some_and(|m| vlsync_common::file::same_file(&m.path, &default_mcap)))
    .then_some(default_mcap);
    let old_frames = std::fs::read_dir(&frames_dir)
        .into_iter()
        .filter(|_| earlier_render)
        .flatten()
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("frame_") && n.ends_with(".png"))
        });
    let stale: Vec<PathBuf> = RUN_FILES
        .iter()
        .map(|f| dir.join(f))
        .chain(old_mcap)
        .chain(old_frames)
        .collect();
    for path in stale {
        match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(io_err(&path)(e));
            }
            _ => {}
        }
    }
    let t = Instant::now();
    write_truth_and_motion(r, dir)?;
    let truth_time = t.elapsed();
    let frames_csv = dir.join("frames.csv");
    let scans_csv = dir.join("scans.csv");
    let mut fcsv = if png {
        let mut w = create(&frames_csv)?;
        writeln!(w, "file,t_s,exposure_start_s,exposure_s").map_err(io_err(&frames_csv))?;
        Some(w)
    } else {
        None
    };
    let mut scsv = create(&scans_csv)?;
    write_header(&mut scsv).map_err(io_err(&scans_csv))?;
    let mut s = Summary {
        frames: 0,
        frames_dropped: r.frames_dropped(),
        scans: 0,
        rays: 0,
        render_time: Duration::ZERO,
        write_time: truth_time,
    };
    let sim_total_ns = r.truth().end_ns;
    let mut events = r.events();
    loop {
        let t0 = Instant::now();
        let Some(ev) = events.next() else { break };
        let ev = ev?;
        let t1 = Instant::now();
        s.render_time += t1 - t0;
        let sim_ns = ev.available_ns();
        match ev {
            Event::Frame(f) => {
                if let Some(fcsv) = &mut fcsv {
                    let name = format!("frame_{:06}.png", f.index);
                    let path: PathBuf = frames_dir.join(&name);
                    image::save_buffer(
                        &path,
                        f.image.pixels(),
                        f.image.width() as u32,
                        f.image.height() as u32,
                        image::ExtendedColorType::L8,
                    )
                    .map_err(|e| RenderError::Encode {
                        path: path.clone(),
                        reason: e.to_string(),
                    })?;
                    let (start, dur) = match f.time {
                        vlsync_signature_cam::FrameTime::Exposure {
                            start_ns,
                            duration_ns,
                        } => (start_ns, duration_ns),
                        vlsync_signature_cam::FrameTime::Instant(t) => (t, 0),
                    };
                    writeln!(
                        fcsv,
                        "frames/{name},{},{},{}",
                        format_seconds(f.stamp_ns),
                        format_seconds(start),
                        format_seconds(dur)
                    )
                    .map_err(io_err(&frames_csv))?;
                }
                if let Some((w, m)) = &mut rec {
                    // log time = stamp + delay = the true time the frame is complete
                    w.set_log_delay_ns(f.tau_available_ns - f.stamp_ns);
                    w.set_frame_id(MCAP_CAMERA_FRAME_ID);
                    if m.png {
                        w.write_compressed_png(MCAP_PNG_TOPIC, f.stamp_ns, &f.image)
                    } else {
                        w.write_image(MCAP_IMAGE_TOPIC, f.stamp_ns, &f.image)
                    }
                    .map_err(mcap_err)?;
                }
                s.frames += 1;
            }
            Event::Scan(sc) => {
                write_scan(&mut scsv, &sc.scan).map_err(io_err(&scans_csv))?;
                if let Some((w, _)) = &mut rec {
                    // write_scan stamps the first ray
                    let stamp = sc
                        .scan
                        .rays()
                        .first()
                        .map_or(sc.scan.timing().start_ns, |ray| ray.t_ns);
                    w.set_log_delay_ns(sc.tau_available_ns - stamp);
                    w.set_frame_id(MCAP_LIDAR_FRAME_ID);
                    w.write_scan(MCAP_SCAN_TOPIC, &sc.scan).map_err(mcap_err)?;
                }
                s.scans += 1;
                s.rays += sc.scan.len();
            }
        }
        s.write_time += t1.elapsed();
        progress(&Progress {
            sim_ns,
            sim_total_ns,
            frames: s.frames,
            scans: s.scans,
        });
    }
    if let Some(fcsv) = &mut fcsv {
        fcsv.flush().map_err(io_err(&frames_csv))?;
    }
    scsv.flush().map_err(io_err(&scans_csv))?;
    if let Some((w, _)) = rec {
        let t = Instant::now();
        w.finish().map_err(mcap_err)?;
        s.write_time += t.elapsed();
    }
    Ok(s)
}

/// `truth.csv` and `motion.csv`: both known before anything is rendered.
fn write_truth_and_motion(r: &Renderer, dir: &Path) -> Result<(), RenderError> {
    let truth_csv = dir.join("truth.csv");
    r.truth()
        .write_csv(&truth_csv)
        .map_err(|e| RenderError::Encode {
            path: truth_csv.clone(),
            reason: e.to_string(),
        })?;
    let motion_csv = dir.join("motion.csv");
    let mut m = create(&motion_csv)?;
    writeln!(m, "{MOTION_HEADER}").map_err(io_err(&motion_csv))?;
    let traj = r.trajectory();
    let steps = (r.config().duration_s * 100.0).floor() as usize;
    for k in 0..=steps {
        let t = k as f64 * 0.01;
        let p = traj.pose(t);
        writeln!(
            m,
            "{t:.2},{:.6},{:.6},{:.6},{:.6},{:.6}",
            p.x,
            p.y,
            p.yaw,
            traj.speed(t),
            traj.yaw_rate(t)
        )
        .map_err(io_err(&motion_csv))?;
    }
    m.flush().map_err(io_err(&motion_csv))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RenderConfig;
    use vlsync_signature_cam::FrameSource;
    use vlsync_signature_lidar::csv::CsvScanReader;

    #[test]
    fn files_read_back_exactly() {
        let dir = std::env::temp_dir().join(format!("vlsync-render-test-{}", std::process::id()));
        let mut cfg = RenderConfig::from_seed(6, 2.0);
        cfg.camera.width = 40;
        cfg.camera.height = 30;
        let mut r = Renderer::new(cfg.clone()).unwrap();
        let s = write_run(&mut r, &dir, true).unwrap();
        let mut again = Renderer::new(cfg).unwrap();
        let events: Vec<Event> = again.events().map(Result::unwrap).collect();
        let mut src = vlsync_signature_cam::DirSource::open(&dir).unwrap();
        let mut scans = CsvScanReader::open(&dir.join("scans.csv")).unwrap();
        let (mut nf, mut ns) = (0, 0);
        for ev in events {
            match ev {
                Event::Frame(f) => {
                    let (img, time) = src.next_frame().unwrap().unwrap();
                    assert_eq!(img.pixels(), f.image.pixels());
                    assert_eq!(time, f.time);
                    nf += 1;
                }
                Event::Scan(sc) => {
                    let back = scans.next().unwrap().unwrap();
                    assert_eq!(back.len(), sc.scan.len());
                    for (a, b) in back.rays().iter().zip(sc.scan.rays()) {
                        assert_eq!(a.t_ns, b.t_ns);
                        assert!((a.bearing_rad - b.bearing_rad).abs() < 1e-9);
                        assert_eq!(a.range_m, b.range_m);
                        assert_eq!(a.valid, b.valid);
                    }
                    ns += 1;
                }
            }
        }
        assert!(src.next_frame().unwrap().is_none() && scans.next().is_none());
        assert_eq!((nf, ns), (s.frames, s.scans));
        let truth = std::fs::read_to_string(dir.join("truth.csv")).unwrap();
        assert!(truth.starts_with("t,offset\n"));
        assert_eq!(truth.lines().count(), 202);
        let bad = write_run(&mut r, Path::new("/proc/no/such/dir"), false).unwrap_err();
        assert!(bad.to_string().starts_with("/proc/no/such/dir: "), "{bad}");
        let bad = write_run(&mut r, Path::new("/proc/no/such/dir"), true).unwrap_err();
        assert!(
            bad.to_string().starts_with("/proc/no/such/dir/frames: "),
            "{bad}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn temp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("vlsync-render-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    fn small(seed: u64) -> Renderer {
        let mut cfg = RenderConfig::from_seed(seed, 2.0);
        cfg.camera.width = 32;
        cfg.camera.height = 24;
        Renderer::new(cfg).unwrap()
    }

    fn read(p: &Path) -> String {
        std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
    }

    /// A run that fails part way (a frame's PNG cannot be written) over an earlier
    /// run's directory: every file left is the new run's, the CSVs it was writing
    /// cut short, none of the earlier run's (truth.csv and motion.csv used to be).
    #[test]
    fn a_failed_run_leaves_only_its_own_files() {
        let (reference, dir) = (temp("ref"), temp("failed"));
        write_run(&mut small(8), &reference, true).unwrap();
        write_run(&mut small(9), &dir, true).unwrap();
        let mut r = small(8);
        let third = r.frame_schedule()[2].index;
        let png = dir.join(format!("frames/frame_{third:06}.png"));
        std::fs::remove_file(&png).ok();
        std::fs::create_dir(&png).unwrap();
        let e = write_run(&mut r, &dir, true).unwrap_err();
        assert!(e.to_string().starts_with(&png.display().to_string()), "{e}");
        for f in ["truth.csv", "motion.csv"] {
            assert_eq!(read(&dir.join(f)), read(&reference.join(f)), "{f}");
        }
        let frames = read(&dir.join("frames.csv"));
        assert_eq!(frames.lines().count(), 3, "{frames}"); // header, 2 frames
        for f in ["frames.csv", "scans.csv"] {
            let (part, whole) = (read(&dir.join(f)), read(&reference.join(f)));
            assert!(whole.starts_with(&part) && part.len() < whole.len(), "{f}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
        std::fs::remove_dir_all(&reference).unwrap();
    }

    /// Without PNGs no frames.csv is written (its rows would name files that do
    /// not exist), and an earlier run's is removed, with its frames and its
    /// default recording.
    #[test]
    fn without_png_no_frame_list_is_left() {
        let dir = temp("nopng");
        let fresh = temp("nopng-fresh");
        let s = write_run(&mut small(4), &fresh, false).unwrap();
        assert!(!fresh.join("frames.csv").exists() && !fresh.join("frames").exists());
        let r = small(4);
        assert_eq!(s.frames, r.frame_schedule().len());
        assert_eq!(s.scans, r.scan_schedule().len());
        // an earlier run with its frames and its default recording
        let m = McapOutput {
            path: dir.join(DEFAULT_MCAP),
            png: false,
        };
        write_run_with(&mut small(5), &dir, true, Some(&m)).unwrap();
        let pngs = |d: &Path| {
            std::fs::read_dir(d.join("frames"))
                .map(|r| r.flatten().count())
                .unwrap_or(0)
        };
        assert!(pngs(&dir) > 0 && dir.join(DEFAULT_MCAP).exists());
        // the same recording written again is kept (it is this run's)
        write_run_with(&mut small(4), &dir, true, Some(&m)).unwrap();
        assert!(dir.join(DEFAULT_MCAP).metadata().unwrap().len() > 0);
        write_run(&mut small(4), &dir, false).unwrap();
        assert!(!dir.join("frames.csv").exists());
        // neither the earlier frames nor its recording are left beside this run
        assert_eq!(pngs(&dir), 0);
        assert!(!dir.join(DEFAULT_MCAP).exists());
        // a directory no render wrote: a user's own frames and recording are kept
        let own = temp("nopng-own");
        std::fs::create_dir_all(own.join("frames")).unwrap();
        std::fs::write(own.join("frames/frame_000001.png"), b"mine").unwrap();
        std::fs::write(own.join(DEFAULT_MCAP), b"mine").unwrap();
        write_run(&mut small(4), &own, false).unwrap();
        assert_eq!(read(&own.join(DEFAULT_MCAP)), "mine");
        assert_eq!(read(&own.join("frames/frame_000001.png")), "mine");
        std::fs::remove_dir_all(&own).unwrap();
        for f in ["scans.csv", "truth.csv", "motion.csv"] {
            assert_eq!(read(&dir.join(f)), read(&fresh.join(f)), "{f}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
        std::fs::remove_dir_all(&fresh).unwrap();
    }

    #[test]
    fn an_mcap_path_on_the_runs_own_outputs_is_refused() {
        let dir = temp("clash");
        write_run(&mut small(3), &dir, true).unwrap();
        let before: Vec<String> = RUN_FILES.iter().map(|f| read(&dir.join(f))).collect();
        let first = small(3).frame_schedule()[0].index;
        let png = format!("frames/frame_{first:06}.png");
        for own in [
            "frames.csv",
            "scans.csv",
            "truth.csv",
            "motion.csv",
            "frames",
            &png,
        ] {
            // spelled another way: through `.` and `..`
            let path = dir.join("frames/..").join(".").join(own);
            assert_eq!(own_output(&dir, &path).as_deref(), Some(own));
            let m = McapOutput { path, png: false };
            let e = write_run_with(&mut small(3), &dir, true, Some(&m)).unwrap_err();
            assert!(
                e.to_string().ends_with(&format!(
                    "would be {}, one of the run's own outputs",
                    dir.join(own).display()
                )),
                "{e}"
            );
        }
        let after: Vec<String> = RUN_FILES.iter().map(|f| read(&dir.join(f))).collect();
        assert!(before == after, "the run's files were touched");
        // relative to the working directory, and not yet existing
        let cwd = std::env::current_dir().unwrap();
        assert_eq!(
            own_output(Path::new("no-such-run"), &cwd.join("no-such-run/scans.csv")).as_deref(),
            Some("scans.csv")
        );
        for other in [
            "run.mcap",
            "frames/run.mcap",
            "frames.csv.mcap",
            "../frames.csv",
        ] {
            assert_eq!(own_output(&dir, &dir.join(other)), None, "{other}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Only a directory that does not exist yet is one the run makes: an existing
    /// ancestor of `--out` (or `--out` itself) is the user's, and a recording there
    /// is checked before the run.
    #[test]
    fn an_existing_directory_is_not_one_the_run_makes() {
        let base = std::env::temp_dir().join(format!("vlsync-run-makes-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let dir = base.join("runs").join("seed3");
        for d in [&base, &base.join("runs"), &dir, &dir.join("frames")] {
            assert!(run_makes(&dir, true, d), "{}", d.display());
        }
        std::fs::create_dir_all(base.join("runs")).unwrap();
        assert!(!run_makes(&dir, true, &base));
        assert!(!run_makes(&dir, true, &base.join("runs")));
        assert!(run_makes(&dir, true, &dir));
        // a file where an ancestor would be: not a directory the run can make
        std::fs::write(base.join("file"), b"").unwrap();
        let under_file = base.join("file").join("run");
        assert!(!run_makes(&under_file, false, &base.join("file")));
        std::fs::create_dir_all(dir.join("frames")).unwrap();
        assert!(!run_makes(&dir, true, &dir) && !run_makes(&dir, true, &dir.join("frames")));
        assert!(!run_makes(&dir, false, Path::new("/")));
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn progress_follows_the_run() {
        let dir = temp("progress");
        let mut seen: Vec<Progress> = Vec::new();
        let mut r = small(7);
        let total = r.truth().end_ns;
        let s = write_run_observed(&mut r, &dir, false, None, &mut |p| seen.push(*p)).unwrap();
        assert_eq!(seen.len(), s.frames + s.scans);
        assert!(seen.windows(2).all(|w| w[0].sim_ns <= w[1].sim_ns
            && w[0].frames + w[0].scans + 1 == w[1].frames + w[1].scans));
        let last = seen.last().unwrap();
        assert_eq!(
            (last.frames, last.scans, last.sim_total_ns),
            (s.frames, s.scans, total)
        );
        assert!(last.sim_ns <= total && last.sim_ns > total - 200_000_000);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
