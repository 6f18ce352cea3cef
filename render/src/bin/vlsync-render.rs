//! `vlsync-render`: renders a simulated run (camera frames, LiDAR scans, truth) to a directory.
#![forbid(unsafe_code)]

use clap::{CommandFactory, Parser};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};
use vlsync_common::text::number;
use vlsync_render::output::{own_output, write_run_observed, McapOutput, Progress};
use vlsync_render::{RenderConfig, RenderError, Renderer};

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
    /// Run length, seconds (1 to 3600).
    #[arg(long, allow_negative_numbers = true, default_value_t = 60.0)]
    duration: f64,
    /// Output directory (created if needed); give --out DIR or --raw-stdout LAYOUT.
    /// An earlier run's frames.csv, scans.csv, truth.csv and motion.csv in DIR are
    /// removed first (after an earlier render, its frames/frame_*.png and run.mcap
    /// too), so a run that fails leaves only its own files.
    #[arg(long, value_name = "DIR", conflicts_with = "raw_stdout")]
    out: Option<PathBuf>,
    /// Write no files: write the camera's frames raw to standard output (LAYOUT:
    /// i420 or gray), each when its exposure ends, in real time: true time τ is
    /// written at τ + start_at - anchor on CLOCK_MONOTONIC, as the drivers'
    /// `--render --stamp mono` map it, where anchor is the earlier of the run's
    /// first camera and first LiDAR stamps. Frames whose exposure ends before the
    /// anchor are therefore written before --start-at (by up to about a LiDAR
    /// period). The run must be the drivers': the --seed, --duration, --fps and
    /// --lidar-hz of their --render SEED, --duration, --render-fps and
    /// --render-lidar-hz (the run's draws, and so its anchor, depend on all four).
    /// Its frames are on the seed's clocks and dropped as the drivers' are (2 %):
    /// --offset, --drift-ppm, --step, --drop, --rays, --mcap, --mcap-png and
    /// --no-png are refused with it.
    #[arg(
        long,
        value_name = "LAYOUT",
        value_parser = vlsync_render::stream::RawLayout::parse,
        conflicts_with_all = [
            "mcap", "mcap_png", "no_png", "offset", "drift_ppm", "steps", "drop", "rays",
        ]
    )]
    raw_stdout: Option<vlsync_render::stream::RawLayout>,
    /// Only with --raw-stdout: the stream's start instant, CLOCK_MONOTONIC ns
    /// (default: now + 1 s). A stream started after it (a camera program restarted
    /// mid-run) skips the frames already due more than one frame period ago and
    /// resumes at the current frame, as the drivers' --render do.
    #[arg(long, allow_negative_numbers = true)]
    start_at: Option<i64>,
    /// Image width, pixels (16 to 4096).
    #[arg(long, allow_negative_numbers = true, default_value_t = 320)]
    width: usize,
    /// Image height, pixels (16 to 4096).
    #[arg(long, allow_negative_numbers = true, default_value_t = 240)]
    height: usize,
    /// Camera frame rate, Hz (1 to 1000, and below 125: the frame period must be
    /// longer than the camera's 8 ms exposure).
    #[arg(long, allow_negative_numbers = true, default_value_t = 30.0)]
    fps: f64,
    /// LiDAR revolutions per second (0.5 to 100; --duration must hold at least one
    /// whole revolution). With --raw-stdout it writes no scans but sets the anchor
    /// (the first scan's stamp): give the LiDAR driver's --render-lidar-hz.
    #[arg(long, allow_negative_numbers = true, default_value_t = 10.0)]
    lidar_hz: f64,
    /// LiDAR rays per revolution (8 to 100000). Not with --raw-stdout (it writes no
    /// scans).
    #[arg(long, allow_negative_numbers = true, default_value_t = 450)]
    rays: usize,
    /// Offset t_L - t_C at t = 0, seconds (-10 to 10; default: drawn from the seed).
    /// Not with --raw-stdout: its frames are written on true time, and the drivers'
    /// --render, paced from the same --start-at, use the seed's clocks.
    #[arg(long, allow_hyphen_values = true)]
    offset: Option<f64>,
    /// Drift, ppm (-1000 to 1000; default: drawn from the seed). Not with
    /// --raw-stdout (see --offset).
    #[arg(long, allow_hyphen_values = true)]
    drift_ppm: Option<f64>,
    /// An offset step `TIME_S:DELTA_S` (repeatable), e.g. a camera latency change:
    /// TIME_S from 0 to before the end of --duration, each after the previous;
    /// DELTA_S -1 to 1. Not with --raw-stdout (see --offset).
    #[arg(long = "step", value_parser = parse_step, allow_hyphen_values = true)]
    steps: Vec<(f64, f64)>,
    /// Camera frame drop probability (0 <= p < 0.5). Not with --raw-stdout: the
    /// drivers' --render drop the default 2 %, and a stream that kept (or dropped)
    /// another first frame would pace from another anchor than theirs.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.02)]
    drop: f64,
    /// Render the frames but write no PNG files and no frames.csv (timing, or
    /// with --mcap a recording only). Not with --raw-stdout.
    #[arg(long)]
    no_png: bool,
    /// Also write a ROS 2 MCAP recording of the run to FILE (default, when
    /// given without a value: DIR/run.mcap; FILE's directory must exist or be one
    /// the run makes, DIR, its frames/ or an ancestor of DIR, and FILE must not be
    /// one of the run's own files):
    /// /camera/image_raw (sensor_msgs/Image, mono8) and /scan
    /// (sensor_msgs/LaserScan), header stamps on each sensor's clock as in
    /// frames.csv (mid-exposure) and scans.csv (first ray); log time = true
    /// delivery time. Not with --raw-stdout.
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

/// A usage error in clap's form (exit status 2).
fn usage_error(msg: &str) -> ! {
    Args::command()
        .error(clap::error::ErrorKind::ArgumentConflict, msg)
        .exit()
}

/// The checks clap's attributes cannot word clearly.
fn check_args(a: &Args) -> Result<(), String> {
    if a.start_at.is_some() && a.raw_stdout.is_none() {
        return Err(
            "--start-at needs --raw-stdout LAYOUT: it is the instant the raw stream of \
             frames starts; a run written with --out DIR is not paced in real time"
                .into(),
        );
    }
    if a.out.is_none() && a.raw_stdout.is_none() {
        return Err(
            "give --out DIR (write the run to files) or --raw-stdout LAYOUT (write the \
             camera's frames to standard output in real time)"
                .into(),
        );
    }
    Ok(())
}

/// The run the command line describes.
fn config(a: &Args) -> RenderConfig {
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
    cfg.clock.steps = a.steps.clone();
    cfg.frame_drop_probability = a.drop;
    cfg
}

/// The flag that sets a [`RenderConfig`] field, if one does.
fn flag_of(field: &str) -> Option<&'static str> {
    Some(match field {
        "duration_s" => "--duration",
        "camera.width" => "--width",
        "camera.height" => "--height",
        // the exposure is fixed: only --fps can make the period too short for it
        "camera.fps" | "camera.exposure_s" => "--fps",
        "lidar.rate_hz" => "--lidar-hz",
        "lidar.rays_per_turn" => "--rays",
        "clock.offset0_s" => "--offset",
        "clock.drift_ppm" => "--drift-ppm",
        "clock.steps.time" => "--step (TIME_S)",
        "clock.steps.delta" => "--step (DELTA_S)",
        "frame_drop_probability" => "--drop",
        _ => return None,
    })
}

/// A configuration error in terms of the command line's flags.
fn config_error(e: &RenderError, c: &RenderConfig) -> String {
    let RenderError::InvalidConfig { field, reason } = e else {
        return e.to_string();
    };
    match (*field, flag_of(field)) {
        ("camera.exposure_s", _) => {
            let exp = c.camera.exposure_s;
            format!(
                "--fps {}: the frame period ({} ms) must be longer than the camera's {} ms \
                 exposure: allowed 1 <= --fps < {}",
                number(c.camera.fps),
                number(1e3 / c.camera.fps),
                number(exp * 1e3),
                number(1.0 / exp)
            )
        }
        ("clock.steps.time", Some(flag)) if reason.contains("run's end") => {
            format!("{flag}: {reason}, set by --duration")
        }
        (_, Some(flag)) => format!("{flag}: {reason}"),
        (_, None) => e.to_string(),
    }
}

/// A run with no frame or no scan: the flags that leave it empty.
fn empty_schedule(r: &Renderer, scans_needed: bool) -> Option<String> {
    let c = r.config();
    if r.frame_schedule().is_empty() {
        let drops = if r.frames_dropped() > 0 {
            format!(
                " (--drop {} dropped them all)",
                number(c.frame_drop_probability)
            )
        } else {
            String::new()
        };
        return Some(format!(
            "--duration {} at --fps {} gives no camera frame{drops}: lengthen --duration \
             or raise --fps",
            number(c.duration_s),
            number(c.camera.fps)
        ));
    }
    if scans_needed && r.scan_schedule().is_empty() {
        return Some(format!(
            "--duration {} holds no whole LiDAR revolution at --lidar-hz {} (a {} s \
             period): lengthen --duration or raise --lidar-hz",
            number(c.duration_s),
            number(c.lidar.rate_hz),
            number(1.0 / c.lidar.rate_hz)
        ));
    }
    None
}

/// How often a run written to files reports its progress, wall time.
const PROGRESS_EVERY: Duration = Duration::from_secs(5);

/// A progress line: simulated seconds done, counts, elapsed and remaining time.
fn progress_line(p: &Progress, elapsed: Duration) -> String {
    let done = p.sim_ns.max(0) as f64 * 1e-9;
    let total = p.sim_total_ns as f64 * 1e-9;
    let el = elapsed.as_secs_f64();
    let left = if done > 0.0 {
        format!("about {:.0} s left", el * (total - done).max(0.0) / done)
    } else {
        "time left unknown".into()
    };
    format!(
        "vlsync-render: {done:.1} of {total:.1} s rendered ({:.0} %), {} frames, {} scans, \
         {el:.0} s elapsed, {left}\n",
        100.0 * done / total,
        p.frames,
        p.scans
    )
}

fn main() -> ExitCode {
    let a = Args::parse();
    if let Err(msg) = check_args(&a) {
        usage_error(&msg);
    }
    // the drivers' check: an instant on another clock would be waited for for decades
    if let Err(e) = a
        .start_at
        .map_or(Ok(()), |t| vlsync_common::check_start_at(t, monotonic_ns()))
    {
        vlsync_common::console::print_err(&format!("vlsync-render: error: {e}\n"));
        return ExitCode::from(2);
    }
    let cfg = config(&a);
    let mcap = a.out.as_ref().and_then(|out_dir| {
        a.mcap.as_ref().map(|file| McapOutput {
            path: file
                .clone()
                .unwrap_or_else(|| out_dir.join(vlsync_render::output::DEFAULT_MCAP)),
            png: a.mcap_png,
        })
    });
    if let (Some(m), Some(out_dir)) = (&mcap, &a.out) {
        if let Some(own) = own_output(out_dir, &m.path) {
            vlsync_common::console::print_err(&format!(
                "vlsync-render: error: --mcap {} names {own} of --out {}, one of the run's \
                 own files: it would be overwritten (give another FILE, or --mcap alone for \
                 {})\n",
                m.path.display(),
                out_dir.display(),
                out_dir.join(vlsync_render::output::DEFAULT_MCAP).display()
            ));
            return ExitCode::from(2);
        }
        // an explicit FILE is checked before the run's directory is made and rendered
        // into, unless the run makes FILE's directory itself (--out, its frames/, an
        // ancestor of --out)
        let made = vlsync_render::output::run_makes(
            out_dir,
            !a.no_png,
            vlsync_common::file::dir_of(&m.path),
        );
        if let (Some(Some(file)), false) = (&a.mcap, made) {
            if let Err(e) = vlsync_common::file::check_writable("--mcap", file) {
                vlsync_common::console::print_err(&format!("vlsync-render: error: {e}\n"));
                return ExitCode::from(2);
            }
        }
    }
    let t0 = Instant::now();
    let mut r = match Renderer::new(cfg.clone()) {
        Ok(r) => r,
        Err(e) => {
            vlsync_common::console::print_err(&format!(
                "vlsync-render: error: {}\n",
                config_error(&e, &cfg)
            ));
            return ExitCode::from(2);
        }
    };
    if let Some(msg) = empty_schedule(&r, a.raw_stdout.is_none()) {
        vlsync_common::console::print_err(&format!("vlsync-render: error: {msg}\n"));
        return ExitCode::from(2);
    }
    let setup = t0.elapsed();
    if let Some(layout) = a.raw_stdout {
        return raw_stdout(&mut r, layout, a.start_at);
    }
    let Some(out_dir) = a.out.as_ref() else {
        // check_args: --out without --raw-stdout
        return ExitCode::from(2);
    };
    let t_render = Instant::now();
    let mut next_report = PROGRESS_EVERY;
    let mut progress = |p: &Progress| {
        let elapsed = t_render.elapsed();
        if elapsed >= next_report {
            next_report = elapsed + PROGRESS_EVERY;
            vlsync_common::console::print_err(&progress_line(p, elapsed));
        }
    };
    let s = match write_run_observed(&mut r, out_dir, !a.no_png, mcap.as_ref(), &mut progress) {
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
    let frames = if a.no_png {
        format!(
            "{} frames rendered, no PNGs or frames.csv (--no-png)",
            s.frames
        )
    } else {
        format!("{} frames written", s.frames)
    };
    let _ = writeln!(
        text,
        "  camera {}x{} @ {} Hz: {frames}, {} dropped; LiDAR {} Hz x {} rays: {} scans",
        c.camera.width,
        c.camera.height,
        c.camera.fps,
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
/// program is stopped. Started after `start_at`, it skips the frames already due
/// (more than a frame period ago) and says so.
fn raw_stdout(
    r: &mut Renderer,
    layout: vlsync_render::stream::RawLayout,
    start_at: Option<i64>,
) -> ExitCode {
    let start_at = start_at.unwrap_or_else(|| monotonic_ns() + 1_000_000_000);
    let now = monotonic_ns();
    let first = vlsync_render::stream::first_live_frame(r, start_at, now);
    let n = r.frame_schedule().len();
    if first > 0 {
        vlsync_common::console::print_err(&format!(
            "vlsync-render: --start-at was {:.3} s ago: skipping the {first} of {n} frames \
             already due{}\n",
            (now - start_at) as f64 * 1e-9,
            if first < n {
                ", resuming at the current frame"
            } else {
                ": the run is over"
            }
        ));
    }
    let mut out = std::io::stdout().lock();
    let res = vlsync_render::stream::stream_raw(
        r,
        &mut out,
        layout,
        start_at,
        first,
        &monotonic_ns,
        &|due| {
            let wait = due - monotonic_ns();
            if wait > 0 {
                std::thread::sleep(std::time::Duration::from_nanos(wait as u64));
            }
        },
    );
    match res {
        Ok(s) => {
            let skipped = if s.skipped > 0 {
                format!(", {} skipped (due before the stream started)", s.skipped)
            } else {
                String::new()
            };
            vlsync_common::console::print_err(&format!(
                "vlsync-render: {} frames written to stdout{skipped}, {} late (latest {:.1} ms)\n",
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::error::ErrorKind;

    fn args(extra: &[&str]) -> Result<Args, clap::Error> {
        Args::try_parse_from(
            ["vlsync-render", "--out", "/nowhere"]
                .iter()
                .chain(extra)
                .copied(),
        )
    }

    /// The ranges the --help text states are the ones the configuration enforces,
    /// and a value outside one is refused naming its flag.
    #[test]
    fn help_ranges_match_the_validation_and_errors_name_the_flags() {
        // the --fps help's "8 ms exposure" and "below 125"
        assert_eq!(
            vlsync_render::camera::CameraConfig::default().exposure_s,
            0.008
        );
        let help = Args::command().render_long_help().to_string();
        for words in [
            "Run length, seconds (1 to 3600)",
            "(16 to 4096)",
            "(1 to 1000, and below 125: the frame period must be longer than the camera's 8 ms exposure)",
            "(0.5 to 100;",
            "(8 to 100000)",
            "(-10 to 10;",
            "(-1000 to 1000;",
            "TIME_S from 0 to before the end of --duration, each after the previous; DELTA_S -1 to 1",
            "(0 <= p < 0.5)",
        ] {
            assert!(help.contains(words), "{words}");
        }
        let cases: &[(&[&str], Option<&str>)] = &[
            (&["--duration", "1"], None),
            (&["--duration", "3600"], None),
            (&["--duration", "0.99"], Some("--duration: ")),
            (&["--duration", "3601"], Some("--duration: ")),
            (&["--width", "16", "--height", "4096"], None),
            (&["--width", "15"], Some("--width: ")),
            (&["--height", "4097"], Some("--height: ")),
            (&["--fps", "1"], None),
            (&["--fps", "124.9"], None),
            (&["--fps", "0.99"], Some("--fps: ")),
            (&["--fps", "125"], Some("--fps 125: ")),
            (&["--fps", "200"], Some("--fps 200: ")),
            (&["--fps", "1001"], Some("--fps: ")),
            (&["--lidar-hz", "0.5"], None),
            (&["--lidar-hz", "100"], None),
            (&["--lidar-hz", "0.49"], Some("--lidar-hz: ")),
            (&["--lidar-hz", "101"], Some("--lidar-hz: ")),
            (&["--rays", "8"], None),
            (&["--rays", "100000"], None),
            (&["--rays", "7"], Some("--rays: ")),
            (&["--rays", "100001"], Some("--rays: ")),
            (&["--offset", "-10", "--drift-ppm", "1000"], None),
            (&["--offset", "10", "--drift-ppm", "-1000"], None),
            (&["--offset", "10.01"], Some("--offset: ")),
            (&["--drift-ppm", "-1000.1"], Some("--drift-ppm: ")),
            (&["--drop", "0"], None),
            (&["--drop", "0.499"], None),
            (&["--drop", "0.5"], Some("--drop: ")),
            (&["--drop", "-0.01"], Some("--drop: ")),
            (
                &["--duration", "10", "--step", "0:-1", "--step", "9.99:1"],
                None,
            ),
            (
                &["--duration", "10", "--step", "10:0.1"],
                Some("--step (TIME_S): "),
            ),
            (
                &["--step", "5:0.1", "--step", "5:0.1"],
                Some("--step (TIME_S): "),
            ),
            (&["--step", "5:1.01"], Some("--step (DELTA_S): ")),
        ];
        for (extra, want) in cases {
            let c = config(&args(extra).unwrap());
            match (c.validate(), want) {
                (Ok(()), None) => {}
                (Err(e), Some(flag)) => {
                    let msg = config_error(&e, &c);
                    assert!(msg.starts_with(flag), "{extra:?}: {msg}");
                    assert!(!msg.contains('`'), "{extra:?}: {msg}"); // no field name
                }
                (got, _) => panic!("{extra:?}: {got:?}"),
            }
        }
        let c = config(&args(&["--fps", "200"]).unwrap());
        assert_eq!(
            config_error(&c.validate().unwrap_err(), &c),
            "--fps 200: the frame period (5 ms) must be longer than the camera's 8 ms exposure: \
             allowed 1 <= --fps < 125"
        );
        let c = config(&args(&["--duration", "5", "--step", "6:0.1"]).unwrap());
        let msg = config_error(&c.validate().unwrap_err(), &c);
        assert!(msg.contains("--duration"), "{msg}");
    }

    #[test]
    fn raw_stdout_refuses_the_flags_it_would_ignore() {
        let raw = |extra: &[&str]| {
            Args::try_parse_from(
                ["vlsync-render", "--raw-stdout", "gray"]
                    .iter()
                    .chain(extra)
                    .copied(),
            )
        };
        // its own flags, and those that set the run's draws as the drivers' --render
        // options do, are fine
        assert!(raw(&[
            "--seed",
            "3",
            "--duration",
            "5",
            "--fps",
            "15",
            "--lidar-hz",
            "5.5",
        ])
        .is_ok());
        for flag in [
            &["--mcap"][..],
            &["--mcap", "/tmp/x.mcap"],
            &["--mcap", "--mcap-png"],
            &["--no-png"],
            &["--offset", "0.1"],
            &["--drift-ppm", "5"],
            &["--step", "1:0.01"],
            &["--drop", "0"],
            &["--drop", "0.02"],
            &["--rays", "100"],
            &["--out", "/tmp/x"],
        ] {
            let e = raw(flag).unwrap_err();
            assert_eq!(e.kind(), ErrorKind::ArgumentConflict, "{flag:?}: {e}");
            let text = e.to_string();
            assert!(
                text.contains("--raw-stdout") && text.contains(flag[0]),
                "{flag:?}: {text}"
            );
        }
    }

    /// A raw stream paces its frames from the anchor its run's first camera and
    /// LiDAR stamps give; the LiDAR driver of the pair (`vlsync-lidar --render SEED
    /// --render-lidar-hz HZ`, the drivers' `raw::renderer_at`: the seed's defaults
    /// with the two rates set) must find the same one, or the offset between the
    /// pair is not the one the truth says. The LiDAR's rate moves the anchor (its
    /// first scan's phase is drawn over a period), so `--lidar-hz` is taken with
    /// `--raw-stdout`, and the frame drops are the drivers' (`--drop` is refused).
    #[test]
    fn a_raw_stream_paces_from_the_anchor_of_the_drivers_run() {
        let raw = |extra: &[&str]| {
            let a = Args::try_parse_from(
                ["vlsync-render", "--raw-stdout", "gray", "--duration", "22"]
                    .iter()
                    .chain(extra)
                    .copied(),
            )
            .unwrap_or_else(|e| panic!("{extra:?}: {e}"));
            Renderer::new(config(&a)).unwrap()
        };
        let driver = |seed: u64, fps: f64, lidar_hz: f64| {
            let mut c = RenderConfig::from_seed(seed, 22.0);
            (c.camera.fps, c.lidar.rate_hz) = (fps, lidar_hz);
            Renderer::new(c).unwrap()
        };
        let mut moved = 0;
        for seed in [1u64, 2, 3] {
            let s = seed.to_string();
            let at_10 = driver(seed, 30.0, 10.0).anchor_ns();
            for (fps, hz) in [(30.0, 5.5), (30.0, 10.0), (15.0, 20.0)] {
                let r = raw(&[
                    "--seed",
                    &s,
                    "--fps",
                    &fps.to_string(),
                    "--lidar-hz",
                    &hz.to_string(),
                ]);
                let d = driver(seed, fps, hz);
                assert_eq!(r.anchor_ns(), d.anchor_ns(), "seed {seed} {fps} {hz}");
                assert_eq!(r.frame_schedule(), d.frame_schedule());
                moved += usize::from(fps == 30.0 && d.anchor_ns() != at_10);
            }
        }
        // what the option is for: at 5.5 Hz the anchor is another than at 10 Hz
        assert!(moved > 0, "the LiDAR's rate never moved the anchor");
    }

    #[test]
    fn start_at_needs_raw_stdout_and_a_mode_is_required() {
        let a = args(&["--start-at", "5"]).unwrap();
        let e = check_args(&a).unwrap_err();
        assert!(e.starts_with("--start-at needs --raw-stdout LAYOUT"), "{e}");
        let a = Args::try_parse_from(["vlsync-render", "--start-at", "5"]).unwrap();
        assert!(check_args(&a)
            .unwrap_err()
            .starts_with("--start-at needs --raw-stdout"));
        let a = Args::try_parse_from(["vlsync-render"]).unwrap();
        let e = check_args(&a).unwrap_err();
        assert!(
            e.contains("--out DIR") && e.contains("--raw-stdout LAYOUT"),
            "{e}"
        );
        let a = Args::try_parse_from(["vlsync-render", "--raw-stdout", "i420", "--start-at", "5"]);
        assert!(check_args(&a.unwrap()).is_ok());
        assert!(check_args(&args(&[]).unwrap()).is_ok());
    }

    #[test]
    fn an_empty_schedule_names_the_flags() {
        let c = config(
            &args(&[
                "--duration",
                "1",
                "--fps",
                "1",
                "--lidar-hz",
                "0.5",
                "--width",
                "16",
                "--height",
                "16",
            ])
            .unwrap(),
        );
        let r = Renderer::new(c).unwrap();
        assert!(r.scan_schedule().is_empty());
        assert_eq!(empty_schedule(&r, false), None); // a raw stream needs no scan
        let msg = empty_schedule(&r, true).unwrap();
        assert!(
            msg.starts_with("--duration 1 holds no whole LiDAR revolution at --lidar-hz 0.5"),
            "{msg}"
        );
        // one frame in the run, dropped half the time
        let empty = (1..40)
            .map(|seed| {
                let seed = seed.to_string();
                let a = args(&[
                    "--seed",
                    &seed,
                    "--duration",
                    "1",
                    "--fps",
                    "1",
                    "--drop",
                    "0.49",
                    "--width",
                    "16",
                    "--height",
                    "16",
                ]);
                Renderer::new(config(&a.unwrap())).unwrap()
            })
            .find(|r| r.frame_schedule().is_empty())
            .expect("a seed that drops its only frame");
        let msg = empty_schedule(&empty, false).unwrap();
        assert!(
            msg.starts_with(
                "--duration 1 at --fps 1 gives no camera frame (--drop 0.49 dropped them all)"
            ),
            "{msg}"
        );
        let r = Renderer::new(config(
            &args(&["--duration", "1", "--width", "16", "--height", "16"]).unwrap(),
        ))
        .unwrap();
        assert_eq!(empty_schedule(&r, true), None);
    }

    #[test]
    fn progress_lines_say_how_far_and_how_long() {
        let p = Progress {
            sim_ns: 15_000_000_000,
            sim_total_ns: 60_000_000_000,
            frames: 440,
            scans: 149,
        };
        assert_eq!(
            progress_line(&p, Duration::from_secs(5)),
            "vlsync-render: 15.0 of 60.0 s rendered (25 %), 440 frames, 149 scans, 5 s elapsed, \
             about 15 s left\n"
        );
        let p = Progress { sim_ns: 0, ..p };
        assert!(progress_line(&p, Duration::from_secs(5)).ends_with("time left unknown\n"));
    }
}
