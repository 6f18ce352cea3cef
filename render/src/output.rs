//! A run on disk, in the formats the front-ends and tools read:
//!
//! * `frames/frame_NNNNNN.png` (gray) and `frames.csv`
//!   (`file,t_s,exposure_start_s,exposure_s`, camera clock; `t_s` is the
//!   mid-exposure stamp) — `vlsync_signature_cam::DirSource`'s format;
//! * `scans.csv` — `vlsync_signature_lidar::csv`'s format, one row per ray with
//!   its own time `t_s` (LiDAR clock);
//! * `truth.csv` — `t,offset` every 10 ms (LiDAR clock), as `vlsync-sim` writes it;
//! * `motion.csv` — `t,x,y,yaw,speed,yaw_rate` every 10 ms (true time), for plots.
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
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use vlsync_signature_lidar::csv::{format_seconds, write_header, write_scan};

/// What [`write_run`] wrote, and how long it took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Frames written.
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

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RenderError + '_ {
    move |source| RenderError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn create(path: &Path) -> Result<BufWriter<File>, RenderError> {
    File::create(path).map(BufWriter::new).map_err(io_err(path))
}

/// Renders the whole run into `dir` (created if needed). With `png = false`
/// the frames are rendered and listed but not written (for timing).
pub fn write_run(r: &mut Renderer, dir: &Path, png: bool) -> Result<Summary, RenderError> {
    let frames_dir = dir.join("frames");
    std::fs::create_dir_all(&frames_dir).map_err(io_err(&frames_dir))?;
    let frames_csv = dir.join("frames.csv");
    let scans_csv = dir.join("scans.csv");
    let mut fcsv = create(&frames_csv)?;
    let mut scsv = create(&scans_csv)?;
    writeln!(fcsv, "file,t_s,exposure_start_s,exposure_s").map_err(io_err(&frames_csv))?;
    write_header(&mut scsv).map_err(io_err(&scans_csv))?;
    let mut s = Summary {
        frames: 0,
        frames_dropped: r.frames_dropped(),
        scans: 0,
        rays: 0,
        render_time: Duration::ZERO,
        write_time: Duration::ZERO,
    };
    let mut events = r.events();
    loop {
        let t0 = Instant::now();
        let Some(ev) = events.next() else { break };
        let ev = ev?;
        let t1 = Instant::now();
        s.render_time += t1 - t0;
        match ev {
            Event::Frame(f) => {
                let name = format!("frame_{:06}.png", f.index);
                let path: PathBuf = frames_dir.join(&name);
                if png {
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
                }
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
                s.frames += 1;
            }
            Event::Scan(sc) => {
                write_scan(&mut scsv, &sc.scan).map_err(io_err(&scans_csv))?;
                s.scans += 1;
                s.rays += sc.scan.len();
            }
        }
        s.write_time += t1.elapsed();
    }
    fcsv.flush().map_err(io_err(&frames_csv))?;
    scsv.flush().map_err(io_err(&scans_csv))?;
    let truth_csv = dir.join("truth.csv");
    r.truth()
        .write_csv(&truth_csv)
        .map_err(|e| RenderError::Encode {
            path: truth_csv.clone(),
            reason: e.to_string(),
        })?;
    let motion_csv = dir.join("motion.csv");
    let mut m = create(&motion_csv)?;
    writeln!(m, "t,x,y,yaw,speed,yaw_rate").map_err(io_err(&motion_csv))?;
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
    m.flush().map_err(io_err(&motion_csv))?;
    Ok(s)
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
        assert!(
            bad.to_string().starts_with("/proc/no/such/dir/frames"),
            "{bad}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
