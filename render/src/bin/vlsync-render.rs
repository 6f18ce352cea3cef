//! `vlsync-render`: renders a simulated run (camera frames, LiDAR scans, truth) to a directory.
#![forbid(unsafe_code)]

use clap::Parser;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;
use vlsync_render::output::{write_run_with, McapOutput};
use vlsync_render::{RenderConfig, Renderer};

/// Renders a robot driving in a textured room as seen by a camera and a 2-D LiDAR,
/// with known clock truth: DIR/frames/*.png + DIR/frames.csv (signature-cam's
/// DirSource format), DIR/scans.csv (signature-lidar's scan CSV), DIR/truth.csv
/// (`t,offset`, offset = t_L - t_C), DIR/motion.csv; with --mcap also a ROS 2
/// MCAP recording of the same frames and scans (/camera/image_raw, /scan) for
/// the drivers' --mcap. With --raw-stdout it is a camera program instead: the
/// camera's frames written raw to standard output in real time, for `vlsync-cam
/// --pipe-cmd` (what `rpicam-vid --codec yuv420 -o -` is on a Raspberry Pi).
#[derive(Debug, Parser)]
#[command(name = "vlsync-render", version)]
struct Args {
    /// Seed of every random choice.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed: u64,
    /// Run length, seconds.
    #[arg(long, allow_negative_numbers = true, default_value_t = 60.0)]
    duration: f64,
    /// Output directory (created if needed).
    #[arg(
        long,
        required_unless_present = "raw_stdout",
        conflicts_with = "raw_stdout"
    )]
    out: Option<PathBuf>,
    /// Write no files: write the camera's frames raw to standard output, each when its
    /// exposure ends, in real time from --start-at (LAYOUT: i420 or gray); the run's
    /// true time τ is τ + start_at - anchor on CLOCK_MONOTONIC, as for the drivers'
    /// `--render --stamp mono`.
    #[arg(long, value_name = "LAYOUT", value_parser = vlsync_render::stream::RawLayout::parse)]
    raw_stdout: Option<vlsync_render::stream::RawLayout>,
    /// With --raw-stdout: the start instant, CLOCK_MONOTONIC ns (default: now + 1 s).
    #[arg(long, requires = "raw_stdout", allow_negative_numbers = true)]
    start_at: Option<i64>,
    /// Image width, pixels.
    #[arg(long, allow_negative_numbers = true, default_value_t = 320)]
    width: usize,
    /// Image height, pixels.
    #[arg(long, allow_negative_numbers = true, default_value_t = 240)]
    height: usize,
    /// Camera frame rate, Hz.
    #[arg(long, allow_negative_numbers = true, default_value_t = 30.0)]
    fps: f64,
    /// LiDAR revolutions per second.
    #[arg(long, allow_negative_numbers = true, default_value_t = 10.0)]
    lidar_hz: f64,
    /// LiDAR rays per revolution.
    #[arg(long, allow_negative_numbers = true, default_value_t = 450)]
    rays: usize,
    /// Offset t_L - t_C at t = 0, seconds (default: drawn from the seed).
    #[arg(long, allow_hyphen_values = true)]
    offset: Option<f64>,
    /// Drift, ppm (default: drawn from the seed).
    #[arg(long, allow_hyphen_values = true)]
    drift_ppm: Option<f64>,
    /// An offset step `TIME_S:DELTA_S` (repeatable), e.g. a camera latency change.
    #[arg(long = "step", value_parser = parse_step, allow_hyphen_values = true)]
    steps: Vec<(f64, f64)>,
    /// Camera frame drop probability.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.02)]
    drop: f64,
    /// Render but do not write PNG files (timing).
    #[arg(long)]
    no_png: bool,
    /// Also write a ROS 2 MCAP recording of the run to FILE (default, when
    /// given without a value: DIR/run.mcap; FILE's directory must exist):
    /// /camera/image_raw (sensor_msgs/Image, mono8) and /scan
    /// (sensor_msgs/LaserScan), header stamps on each sensor's clock as in
    /// frames.csv (mid-exposure) and scans.csv (first ray); log time = true
    /// delivery time.
    #[arg(long, value_name = "FILE")]
    mcap: Option<Option<PathBuf>>,
    /// With --mcap: frames as lossless PNG sensor_msgs/CompressedImage on
    /// /camera/image_raw/compressed instead of raw Image.
    #[arg(long, requires = "mcap")]
    mcap_png: bool,
}

fn parse_step(s: &str) -> Result<(f64, f64), String> {
    let (t, d) = s
        .split_once(':')
        .ok_or_else(|| format!("`{s}` is not TIME_S:DELTA_S"))?;
    let num = |x: &str| {
        x.trim()
            .parse::<f64>()
            .map_err(|e| format!("`{x}` in step `{s}`: {e}"))
    };
    Ok((num(t)?, num(d)?))
}

fn main() -> ExitCode {
    let a = Args::parse();
    // the drivers' check: an instant on another clock would be waited for for decades
    if let Err(e) = a
        .start_at
        .map_or(Ok(()), |t| vlsync_common::check_start_at(t, monotonic_ns()))
    {
        vlsync_common::console::print_err(&format!("vlsync-render: error: {e}\n"));
        return ExitCode::from(2);
    }
    let mut cfg = RenderConfig::from_seed(a.seed, a.duration);
    cfg.camera.width = a.width;
    cfg.camera.height = a.height;
    cfg.camera.fps = a.fps;
    cfg.lidar.rate_hz = a.lidar_hz;
    cfg.lidar.rays_per_turn = a.rays;
    if let Some(o) = a.offset {
        cfg.clock.offset0_s = o;
    }
    if let Some(d) = a.drift_ppm {
        cfg.clock.drift_ppm = d;
    }
    cfg.clock.steps = a.steps;
    cfg.frame_drop_probability = a.drop;
    let t0 = Instant::now();
    let mut r = match Renderer::new(cfg) {
        Ok(r) => r,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-render: error: {e}\n"));
            return ExitCode::from(2);
        }
    };
    let setup = t0.elapsed();
    if let Some(layout) = a.raw_stdout {
        return raw_stdout(&mut r, layout, a.start_at);
    }
    let Some(out_dir) = a.out.as_ref() else {
        // clap requires --out without --raw-stdout
        return ExitCode::from(2);
    };
    let mcap = a.mcap.as_ref().map(|file| McapOutput {
        path: file.clone().unwrap_or_else(|| out_dir.join("run.mcap")),
        png: a.mcap_png,
    });
    let s = match write_run_with(&mut r, out_dir, !a.no_png, mcap.as_ref()) {
        Ok(s) => s,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-render: error: {e}\n"));
            return ExitCode::FAILURE;
        }
    };
    let c = r.config();
    let truth = r.truth();
    let end = truth.end_ns;
    // printed after the files are written: a closed or full stdout must not panic
    let mut text = String::new();
    let _ = writeln!(
        text,
        "vlsync-render: seed {} duration {} s -> {}",
        c.seed,
        c.duration_s,
        out_dir.display()
    );
    let _ = writeln!(
        text,
        "  camera {}x{} @ {} Hz: {} frames written, {} dropped; LiDAR {} Hz x {} rays: {} scans",
        c.camera.width,
        c.camera.height,
        c.camera.fps,
        s.frames,
        s.frames_dropped,
        c.lidar.rate_hz,
        c.lidar.rays_per_turn,
        s.scans
    );
    if let Some(m) = &mcap {
        let _ = writeln!(
            text,
            "  mcap {}: {} frames on {}, {} scans on {}",
            m.path.display(),
            s.frames,
            m.image_topic(),
            s.scans,
            vlsync_render::output::MCAP_SCAN_TOPIC
        );
    }
    let _ = writeln!(
        text,
        "  truth offset t_L - t_C: {:+.6} s at 0, {:+.6} s at end (drift {:+.1} ppm, {} steps)",
        truth.offset_at(0),
        truth.offset_at(end),
        c.clock.drift_ppm,
        truth.steps.len()
    );
    let _ = writeln!(
        text,
        "  drive: motion starts {:.2} s, {} turns, {} stops",
        r.trajectory().motion_start_s(),
        r.trajectory().turns().len(),
        r.trajectory().stops().len()
    );
    let _ = writeln!(
        text,
        "  time: setup {:.2} s, render {:.2} s, write {:.2} s",
        setup.as_secs_f64(),
        s.render_time.as_secs_f64(),
        s.write_time.as_secs_f64()
    );
    match vlsync_common::console::print_out(&text) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-render: error: {e}\n"));
            ExitCode::FAILURE
        }
    }
}

/// `CLOCK_MONOTONIC` now, ns.
fn monotonic_ns() -> i64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    // tv_nsec is a C long: i32 on 32-bit ARM
    #[allow(clippy::useless_conversion)]
    t.tv_sec
        .saturating_mul(1_000_000_000)
        .saturating_add(i64::from(t.tv_nsec))
}

/// `--raw-stdout`: the frames to standard output in real time; a summary on stderr.
/// A reader that goes away (`EPIPE`) ends the stream quietly: that is how a camera
/// program is stopped.
fn raw_stdout(
    r: &mut Renderer,
    layout: vlsync_render::stream::RawLayout,
    start_at: Option<i64>,
) -> ExitCode {
    let start_at = start_at.unwrap_or_else(|| monotonic_ns() + 1_000_000_000);
    let mut out = std::io::stdout().lock();
    let res =
        vlsync_render::stream::stream_raw(r, &mut out, layout, start_at, &monotonic_ns, &|due| {
            let wait = due - monotonic_ns();
            if wait > 0 {
                std::thread::sleep(std::time::Duration::from_nanos(wait as u64));
            }
        });
    match res {
        Ok(s) => {
            vlsync_common::console::print_err(&format!(
                "vlsync-render: {} frames written to stdout, {} late (latest {:.1} ms)\n",
                s.frames,
                s.late,
                s.max_late_ns as f64 * 1e-6
            ));
            ExitCode::SUCCESS
        }
        Err(vlsync_render::stream::StreamError::Write(e))
            if e.kind() == std::io::ErrorKind::BrokenPipe =>
        {
            ExitCode::SUCCESS
        }
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-render: error: {e}\n"));
            ExitCode::FAILURE
        }
    }
}
