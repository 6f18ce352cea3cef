//! The command line shared by `vlsync-cam` and `vlsync-lidar`.

use crate::{
    raw, run, sim_anchor_ns, DriverError, Pacing, Progress, RunSummary, Source, VecSource,
};
use clap::Parser;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;
use vlsync_common::Stream;
use vlsync_ipc::{create_node, ServiceNames, SignaturePublisher};

/// Arguments of a signature driver.
#[derive(Parser, Debug, Clone)]
// each binary's name, about and list of sources: `command`
#[command(version)]
pub struct DriverArgs {
    /// Service prefix (`services.prefix`); overrides the one of --config.
    #[arg(long)]
    pub prefix: Option<String>,
    /// Configuration file (`[services]`; `vlsync-lidar` also reads `[lidar]`, the
    /// bearing window of the wall its front-end fits, and `vlsync-cam` `[camera]`,
    /// the frame rate it asks of a V4L2 camera).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// --config as first read: every later use takes this one, so that a file edited
    /// while `--wait-device` waits (hours, maybe) cannot stop the driver for good
    /// when the device appears (an options error, not restarted), nor give its prefix
    /// and its buffer from two versions of the file.
    #[arg(skip)]
    pub loaded_config: std::sync::OnceLock<vlsync_config::Config>,
    /// LiDAR front-ends: also fit the wall opposite the window and publish its rate,
    /// negated, in the same stream (`lidar.opposite_window = true`).
    #[arg(long)]
    pub opposite_window: bool,
    /// Replay this signature CSV (header, then `t,value` rows, t in seconds).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Run the live signature simulator of this family (e.g. `robot`).
    #[arg(long)]
    pub sim: Option<String>,
    /// With --sim: the simulator's seed (both drivers of a pair must use the same);
    /// default 1. (--render takes its seed as its value.)
    #[arg(long, allow_negative_numbers = true)]
    pub seed: Option<u64>,
    /// Simulated or rendered duration in seconds (default: the family's; 60 s rendered).
    #[arg(long, allow_negative_numbers = true)]
    pub duration: Option<f64>,
    /// Camera: a directory of PNG/JPEG frames with `frames.csv` (what `vlsync-render` writes).
    #[arg(long, value_name = "DIR")]
    pub frames: Option<PathBuf>,
    /// Camera: a V4L2 device, e.g. /dev/video0 (needs the `v4l2` cargo feature).
    #[arg(long, value_name = "DEVICE")]
    pub v4l2: Option<PathBuf>,
    /// With --v4l2: the frame rate to ask the camera for, Hz (VIDIOC_S_PARM; the rate
    /// it grants is said at the start); overrides `camera.v4l2_fps` of --config.
    /// 0: the camera's own rate. 0 or 1..=1000.
    #[arg(long, allow_negative_numbers = true, value_name = "HZ")]
    pub fps: Option<f64>,
    /// Camera: raw frames from a pipe, `-` for the standard input (`rpicam-vid ... -o - |
    /// vlsync-cam --pipe - --size 320x240`) or a named FIFO; stamped as they arrive.
    /// Needs --size.
    #[arg(long, value_name = "PATH")]
    pub pipe: Option<PathBuf>,
    /// Camera: run COMMAND (`sh -c`) and read raw frames from its standard output, e.g.
    /// "rpicam-vid -t 0 -n --flush --codec yuv420 --width 320 --height 240 --framerate 30 -o -"
    /// for a Raspberry Pi camera module; started again when it stalls. Needs --size.
    #[arg(long, value_name = "COMMAND", value_parser = not_blank)]
    pub pipe_cmd: Option<String>,
    /// With --pipe or --pipe-cmd: the frames' size, WIDTHxHEIGHT (e.g. 320x240).
    #[arg(long, value_name = "WxH")]
    pub size: Option<String>,
    /// With --pipe or --pipe-cmd: the frames' layout: i420 (rpicam-vid's yuv420, the
    /// default), nv12, yuyv or gray.
    #[arg(long, value_name = "FORMAT")]
    pub raw_format: Option<String>,
    /// With --pipe or --pipe-cmd: bytes per row of the luma plane, when rows are
    /// padded (default: no padding).
    #[arg(long, allow_negative_numbers = true, value_name = "BYTES")]
    pub stride: Option<usize>,
    /// LiDAR: an LD06/LD19 on this serial port, e.g. /dev/ttyUSB0.
    #[arg(long, value_name = "DEVICE", value_parser = not_blank)]
    pub ld06: Option<String>,
    /// LiDAR: an RPLIDAR (A1/A2/C1, standard scan) on this serial port; the scan request is sent.
    #[arg(long, value_name = "DEVICE", value_parser = not_blank)]
    pub rplidar: Option<String>,
    /// Serial baud rate (default: LD06 230400, RPLIDAR 115200).
    #[arg(long, allow_negative_numbers = true)]
    pub baud: Option<u32>,
    /// LiDAR: a scan CSV, one row per ray (what `vlsync-render` writes as scans.csv).
    #[arg(long, value_name = "FILE")]
    pub scans: Option<PathBuf>,
    /// A ROS 2 recording: the camera reads an Image/CompressedImage topic, the LiDAR a LaserScan topic.
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Topic of --mcap (default: the only topic of the right type).
    #[arg(long, requires = "mcap")]
    pub topic: Option<String>,
    /// Render this seed's run with the rendering simulator (both drivers of a pair use the same).
    #[arg(long, allow_negative_numbers = true, value_name = "SEED")]
    pub render: Option<u64>,
    /// With --render: the rendered camera's frame rate, Hz (default 30). The run's
    /// draws depend on it, so both drivers of a pair take the same, as they take the
    /// same seed. Under 125 (the frame's 8 ms exposure must fit its period), and frames
    /// at most half `estimator.max_gap_s` apart (2.67 Hz or more by default).
    #[arg(long, allow_negative_numbers = true, value_name = "HZ")]
    pub render_fps: Option<f64>,
    /// With --render: the rendered LiDAR's revolutions a second, Hz (default 10, an
    /// LD06's). Both drivers of a pair take the same. Up to 100, and scans at most half
    /// `estimator.max_gap_s` apart (2.67 Hz or more by default).
    #[arg(long, allow_negative_numbers = true, value_name = "HZ")]
    pub render_lidar_hz: Option<f64>,
    /// Publish as fast as possible instead of in real time (recorded and simulated
    /// sources; a live device publishes as its data arrives). Nothing slows the
    /// driver down for the daemon: a running daemon keeps what its subscriber buffer
    /// (`services.subscriber_buffer`, default 256 samples) holds when it cannot keep
    /// up; --speed 100 is lossless.
    #[arg(long, conflicts_with = "speed")]
    pub fast: bool,
    /// Real-time speed factor (1 = real time, 100 = 100x), 0.01 ..= 1000; live devices accept only 1.
    #[arg(long, allow_negative_numbers = true)]
    pub speed: Option<f64>,
    /// Live devices (--v4l2, --ld06, --rplidar): wait for the device node to appear
    /// instead of failing at once, saying so then and every 10 minutes (what the
    /// systemd units do, so an unplugged sensor is picked up again when it returns).
    /// Other sources have no device node and start at once.
    #[arg(long)]
    pub wait_device: bool,
    /// Common start instant on CLOCK_MONOTONIC in ns (the demo gives both drivers
    /// the same one; a restarted driver given the same resumes at the current position).
    /// Recorded and simulated sources paced in real time only (not with --fast, nor
    /// a live device).
    #[arg(long, allow_negative_numbers = true)]
    pub start_at: Option<i64>,
    /// With --sim, paced in real time: start at the latest multiple of the run's
    /// duration on CLOCK_MONOTONIC, skipping what has passed of it, instead of now.
    /// Both drivers of a pair compute the same instant on one machine, so the pair
    /// stays consistent however often either restarts (the shipped units' simulator
    /// restarts every run: without it the two drifted apart by up to a sample period
    /// an hour, and by each restart's start-up time).
    #[arg(long, conflicts_with = "start_at")]
    pub aligned: bool,
    /// How a rendered run is stamped: `sensor` (the rendered sensor clocks),
    /// `mono` (the same stamps carried onto CLOCK_MONOTONIC from --start-at),
    /// `software` (camera only: CLOCK_MONOTONIC read after the front-end
    /// processed each frame, frames delivered in real time). `mono` and
    /// `software` need real time (no --fast or --speed other than 1) and both
    /// drivers of a pair must share --start-at (without it a driver picks one, 1 s
    /// ahead, and says it in its `publishing` line).
    #[arg(long, value_enum, default_value_t = StampArg::Sensor)]
    pub stamp: StampArg,
    /// With `--stamp software`: the camera front-end's CPU cost per frame, ms. The
    /// driver works on after processing until its thread has spent this much CPU on
    /// the frame, then stamps it: a heavier front-end (a slower board, a bigger image,
    /// a JPEG decode) on this machine, whose stamps CPU load delays accordingly.
    /// 0: the front-end's own cost only.
    #[arg(
        long,
        allow_negative_numbers = true,
        value_name = "MS",
        default_value_t = 0.0
    )]
    pub frame_cpu_ms: f64,
    /// Write one truth row per published sample of a rendered run to FILE:
    /// `seq,publish_ns,event_ns,stamp_ns,late_ns,process_ns,render_late_ns`
    /// (true event time against the stamp published; see `vlsync_driver::SampleTruth`).
    #[arg(long, value_name = "FILE")]
    pub truth_out: Option<PathBuf>,
    /// Seconds between progress lines (default 600, what the systemd units use):
    /// published samples, drops, and what the front-end sees (the LiDAR's fitted wall:
    /// distance, normal and returns; the camera's tracked points). `--report-every 1`
    /// while aiming the sensors. 1 ..= 86400.
    #[arg(long, allow_negative_numbers = true, value_name = "SECS")]
    pub report_every: Option<f64>,
}

/// Largest real-time speed factor `--speed` accepts (and the live tools built on the
/// drivers).
pub const MAX_SPEED: f64 = 1000.0;
/// Smallest real-time speed factor `--speed` accepts.
pub const MIN_SPEED: f64 = 0.01;

/// `--report-every`: the period of the progress lines ([`PROGRESS_EVERY`] without it).
pub fn report_every(args: &DriverArgs) -> Result<Duration, DriverError> {
    match args.report_every {
        None => Ok(PROGRESS_EVERY),
        Some(s) if s.is_finite() && (1.0..=86_400.0).contains(&s) => Ok(Duration::from_secs_f64(s)),
        Some(s) => Err(DriverError::Options(format!(
            "--report-every {} is out of range: allowed 1 ..= 86400 seconds",
            vlsync_common::text::number(s)
        ))),
    }
}

/// `--stamp`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampArg {
    /// The rendered sensor clocks.
    Sensor,
    /// The rendered sensor clocks on CLOCK_MONOTONIC.
    Mono,
    /// Camera: CLOCK_MONOTONIC after processing.
    Software,
}

/// How long after now a `--stamp mono|software` run without `--start-at` starts
/// (the render thread fills its queue meanwhile).
pub const DEFAULT_START_DELAY_NS: i64 = 1_000_000_000;

/// `--seed` when not given.
pub const DEFAULT_SEED: u64 = 1;

/// Refuses an empty (or blank) device path or command, naming its flag (clap's
/// error): `--ld06 ''` would otherwise open nothing, or wait forever with
/// `--wait-device`.
fn not_blank(s: &str) -> Result<String, String> {
    if s.trim().is_empty() {
        Err("an empty value names no device or command".into())
    } else {
        Ok(s.to_string())
    }
}

/// A source with how to pace it.
pub struct Selected {
    /// The source.
    pub source: Box<dyn Source>,
    /// Pacing anchor (sensor time of the start instant); `None`: a live device,
    /// published as data arrives.
    pub anchor_ns: Option<i64>,
    /// The start instant: `--start-at`, or the one `--stamp mono|software` without
    /// it picked (its stamps are built on it); `None`: the start of the run.
    pub start_at: Option<i64>,
    /// Stopped before there was a source (a stop while waiting for the device):
    /// why, for the log; the driver then publishes nothing.
    pub stopped: Option<String>,
}

/// How long a serial LiDAR may stay silent before the driver says so and reopens its
/// port (again after each such period while the silence lasts).
const SERIAL_SILENCE: std::time::Duration = std::time::Duration::from_secs(10);

/// Serial rates `--baud` accepts (the LD06's 230400 and the RPLIDARs' 115200 to
/// 1000000 among them).
pub const BAUD_RANGE: std::ops::RangeInclusive<u32> = 1200..=4_000_000;

/// Builds the source `args` select for `stream`; `stop` is polled by live sources while they wait.
pub fn select_source(
    args: &DriverArgs,
    stream: Stream,
    stop: raw::StopFn,
) -> Result<Selected, DriverError> {
    let given = given_sources(args);
    let choices = match stream {
        Stream::Cam => "--csv FILE, --sim FAMILY, --frames DIR, --mcap FILE, --v4l2 DEVICE, --pipe PATH, --pipe-cmd COMMAND or --render SEED",
        Stream::Lidar => {
            "--csv FILE, --sim FAMILY, --ld06 DEVICE, --rplidar DEVICE, --scans FILE, --mcap FILE or --render SEED"
        }
    };
    let flag = match given.as_slice() {
        [f] => *f,
        [] => {
            return Err(DriverError::Options(format!(
                "give exactly one source: {choices}"
            )))
        }
        many => {
            return Err(DriverError::Options(format!(
                "give exactly one source, not {}: {choices}",
                many.join(" and ")
            )))
        }
    };
    let wrong_stream = |f: &str| {
        DriverError::Options(format!(
            "{f} is not a source of vlsync-{stream}; give one of {choices}"
        ))
    };
    // the other driver's sources and options first: what follows checks them as if
    // they applied here ("this vlsync-cam is built without V4L2" from vlsync-lidar)
    let (other_sources, other_options): (&[&str], Vec<(&str, bool)>) = match stream {
        Stream::Cam => (
            &["--ld06", "--rplidar", "--scans"],
            vec![
                ("--opposite-window", args.opposite_window),
                ("--baud", args.baud.is_some()),
            ],
        ),
        Stream::Lidar => (
            &["--frames", "--v4l2", "--pipe", "--pipe-cmd"],
            vec![
                ("--fps", args.fps.is_some()),
                ("--size", args.size.is_some()),
                ("--raw-format", args.raw_format.is_some()),
                ("--stride", args.stride.is_some()),
                ("--frame-cpu-ms", args.frame_cpu_ms != 0.0),
            ],
        ),
    };
    if other_sources.contains(&flag) {
        return Err(wrong_stream(flag));
    }
    if let Some((o, _)) = other_options.iter().find(|o| o.1) {
        let other = match stream {
            Stream::Cam => "lidar",
            Stream::Lidar => "cam",
        };
        return Err(DriverError::Options(format!(
            "{o} is an option of vlsync-{other}, not of vlsync-{stream}"
        )));
    }
    if args.stamp != StampArg::Sensor {
        if flag != "--render" {
            return Err(DriverError::Options(format!(
                "--stamp {} applies to --render only",
                args.stamp.name()
            )));
        }
        if args.stamp == StampArg::Software && stream != Stream::Cam {
            return Err(DriverError::Options(
                "--stamp software is a camera mode; the LiDAR stamps like its sensor (--stamp sensor or mono)"
                    .into(),
            ));
        }
        if args.fast || args.speed.is_some_and(|s| s != 1.0) {
            return Err(DriverError::Options(format!(
                "--stamp {} stamps on CLOCK_MONOTONIC: it needs real time (no --fast, --speed 1)",
                args.stamp.name()
            )));
        }
    }
    if let Some(t) = args.start_at {
        vlsync_common::check_start_at(t, vlsync_ipc::monotonic_ns())
            .map_err(DriverError::Options)?;
    }
    if args.frame_cpu_ms != 0.0 {
        if args.stamp != StampArg::Software || stream != Stream::Cam {
            return Err(DriverError::Options(
                "--frame-cpu-ms applies to vlsync-cam --stamp software only".into(),
            ));
        }
        if !(args.frame_cpu_ms.is_finite() && (0.0..=1000.0).contains(&args.frame_cpu_ms)) {
            return Err(DriverError::Options(format!(
                "--frame-cpu-ms {} is out of range: allowed 0 ..= 1000",
                vlsync_common::text::number(args.frame_cpu_ms)
            )));
        }
        if vlsync_ipc::rt::thread_cpu_ns().is_none() {
            return Err(DriverError::Options(
                "--frame-cpu-ms needs the thread CPU clock, which this system lacks".into(),
            ));
        }
    }
    if args.truth_out.is_some() && flag != "--render" {
        return Err(DriverError::Options(
            "--truth-out needs --render (only the rendering simulator knows the truth)".into(),
        ));
    }
    if let Some(fps) = args.fps {
        if flag != "--v4l2" {
            return Err(DriverError::Options(
                "--fps applies to --v4l2 only (other sources keep their own times)".into(),
            ));
        }
        if !vlsync_config::CameraConfig::fps_is_valid(fps) {
            return Err(DriverError::Options(format!(
                "--fps {} is out of range: allowed 0 (the camera's own rate) or {} ..= {}",
                vlsync_common::text::number(fps),
                vlsync_config::CAMERA_FPS_RANGE.start(),
                vlsync_config::CAMERA_FPS_RANGE.end()
            )));
        }
        // at start, not once --wait-device has seen the camera (maybe hours later);
        // a rate in the file was checked as the file was read
        if let Some(why) = config(args)?.camera_rate_problem(fps) {
            return Err(DriverError::Options(format!(
                "--fps {fps}: {why} ({})",
                config_source(args)
            )));
        }
    }
    render_rates(args, flag)?;
    let piped = ["--pipe", "--pipe-cmd"].contains(&flag);
    let raw_layout = pipe_layout(args, piped)?;
    if args.baud.is_some() && args.ld06.is_none() && args.rplidar.is_none() {
        return Err(DriverError::Options(
            "--baud applies to --ld06 and --rplidar only".into(),
        ));
    }
    if let Some(b) = args.baud {
        // host stamps are corrected by the bytes' transfer time at this rate
        if !BAUD_RANGE.contains(&b) {
            return Err(DriverError::Options(format!(
                "--baud {b} is outside {}..={}",
                BAUD_RANGE.start(),
                BAUD_RANGE.end()
            )));
        }
    }
    if let Some(v) = args.speed {
        if !(v.is_finite() && (MIN_SPEED..=MAX_SPEED).contains(&v)) {
            // a factor of 1e-300 would pace the second sample centuries out
            return Err(DriverError::Options(format!(
                "--speed {} is out of range: allowed {MIN_SPEED} ..= {MAX_SPEED}",
                vlsync_common::text::number(v)
            )));
        }
    }
    if args.duration.is_some() && !["--sim", "--render"].contains(&flag) {
        return Err(DriverError::Options(format!(
            "--duration applies to --sim and --render only; {flag} lasts as long as its data"
        )));
    }
    if flag == "--v4l2" && !cfg!(feature = "v4l2") {
        // an options error (exit 78): a unit restarting it every 2 s would fail the
        // same way forever
        return Err(DriverError::Options(format!(
            "--v4l2 {}: this vlsync-cam is built without V4L2 support; rebuild with \
             --features vlsync-driver/v4l2",
            args.v4l2.as_deref().unwrap_or(Path::new("")).display()
        )));
    }
    let live = LIVE_SOURCES;
    // `--speed 1` is what a live device does anyway: accepted, as `--stamp` accepts it
    if live.contains(&flag) && (args.fast || args.speed.is_some_and(|s| s != 1.0)) {
        return Err(DriverError::Options(format!(
            "{} applies to recorded and simulated sources; {flag} is a live device, published \
             as its data arrives (in real time)",
            if args.fast {
                "--fast".to_string()
            } else {
                format!("--speed {}", args.speed.unwrap_or(1.0))
            }
        )));
    }
    // options that would do nothing here are refused, not ignored
    if args.start_at.is_some() {
        if live.contains(&flag) {
            return Err(DriverError::Options(format!(
                "--start-at applies to recorded and simulated sources paced in real time; \
                 {flag} is a live device, published as its data arrives"
            )));
        }
        if args.fast {
            return Err(DriverError::Options(
                "--start-at sets when real-time pacing starts; --fast publishes at once, \
                 without pacing"
                    .into(),
            ));
        }
    }
    if args.aligned {
        if flag != "--sim" {
            return Err(DriverError::Options(format!(
                "--aligned applies to --sim (its runs repeat); {flag} is not a simulator run"
            )));
        }
        if args.fast {
            return Err(DriverError::Options(
                "--aligned sets when real-time pacing starts; --fast publishes at once, \
                 without pacing"
                    .into(),
            ));
        }
        if args.speed.is_some_and(|v| v != 1.0) {
            // a run then lasts its duration / speed of real time, and the period both
            // drivers align on would not be the run's
            return Err(DriverError::Options(
                "--aligned paces the run in real time (its period is the run's duration); \
                 drop --speed"
                    .into(),
            ));
        }
    }
    if args.seed.is_some() && flag != "--sim" {
        return Err(DriverError::Options(if flag == "--render" {
            "--seed applies to --sim only; --render takes its seed as its value (--render SEED)"
                .into()
        } else {
            format!("--seed applies to --sim only; {flag} has no seed")
        }));
    }
    let scan_flags = ["--render", "--mcap", "--scans", "--ld06", "--rplidar"];
    if args.opposite_window && !(stream == Stream::Lidar && scan_flags.contains(&flag)) {
        return Err(DriverError::Options(
            "--opposite-window applies to vlsync-lidar with a scan source (--render, --mcap, --scans, --ld06, --rplidar)".into(),
        ));
    }
    let front = lidar_front(args)?;
    let src = DriverError::Source;
    // every front-end source ends at a stop, the recorded ones too (read ahead
    // here up to their first usable sample)
    let fronted = |s: raw::LidarSource| {
        s.with_front(&front)
            .map(|s| s.with_stop(stop))
            .map_err(DriverError::Source)
    };
    let offline = |source: Box<dyn Source>| -> Result<Selected, DriverError> {
        let p = raw::Prefetched::new(source).map_err(DriverError::Source)?;
        let anchor = p.first_t_ns().unwrap_or(0);
        Ok(Selected {
            source: Box::new(p),
            anchor_ns: Some(anchor),
            start_at: args.start_at,
            stopped: None,
        })
    };
    match (flag, stream) {
        ("--csv", _) => {
            let p = args.csv.as_deref().unwrap_or(Path::new(""));
            let s = VecSource::from_csv(p).map_err(src)?;
            let anchor = s.first_t_ns().unwrap_or(0);
            Ok(Selected {
                source: Box::new(s),
                anchor_ns: Some(anchor),
                start_at: args.start_at,
                stopped: None,
            })
        }
        ("--sim", _) => {
            let fam = args.sim.as_deref().unwrap_or_default();
            let family: vlsync_sim::Family = fam
                .parse()
                .map_err(|e| DriverError::Options(format!("--sim: {e}")))?;
            let seed = args.seed.unwrap_or(DEFAULT_SEED);
            let run = vlsync_sim::try_generate(family, seed, args.duration)
                .map_err(|e| DriverError::Options(format!("--duration: {e}")))?;
            let start_at = if args.aligned {
                Some(aligned_start_ns(
                    vlsync_ipc::monotonic_ns(),
                    vlsync_common::secs_to_nanos(run.duration_s),
                ))
            } else {
                args.start_at
            };
            Ok(Selected {
                source: Box::new(VecSource::from_sim(&run, stream)),
                anchor_ns: Some(sim_anchor_ns(&run)),
                start_at,
                stopped: None,
            })
        }
        ("--render", _) => {
            let seed = args.render.unwrap_or_default();
            let duration = args.duration.unwrap_or(raw::DEFAULT_RENDER_DURATION_S);
            // the renderer's configuration is the command line's: an options error
            let r = raw::renderer_at(seed, duration, render_rates(args, flag)?).map_err(|e| {
                DriverError::Options(format!(
                    "--duration {}: {e}",
                    vlsync_common::text::number(duration)
                ))
            })?;
            let anchor = raw::render_anchor_ns(&r);
            // mono stamps are built on the start instant: pick one now if none was given
            let start_at = match args.stamp {
                StampArg::Sensor => args.start_at,
                _ => Some(
                    args.start_at
                        .unwrap_or_else(|| vlsync_ipc::monotonic_ns() + DEFAULT_START_DELAY_NS),
                ),
            };
            let shift_ns = start_at.unwrap_or(0) - anchor;
            let stamp = match args.stamp {
                StampArg::Sensor => raw::RenderStamp::Sensor,
                StampArg::Mono => raw::RenderStamp::Mono { shift_ns },
                StampArg::Software => raw::RenderStamp::Software { shift_ns },
            };
            let source: Box<dyn Source> = match stream {
                Stream::Cam => {
                    let mut c = raw::CamSource::render_with(r, stamp, stop).map_err(src)?;
                    c.set_frame_cpu_ns((args.frame_cpu_ms * 1e6) as vlsync_common::Nanos);
                    Box::new(c)
                }
                Stream::Lidar => Box::new(fronted(
                    raw::LidarSource::render_with(r, stamp).map_err(src)?,
                )?),
            };
            Ok(Selected {
                source,
                // software stamping paces itself (frames are delivered in real time)
                anchor_ns: match stamp {
                    raw::RenderStamp::Software { .. } => None,
                    _ => Some(anchor + stamp.shift_ns()),
                },
                start_at,
                stopped: None,
            })
        }
        ("--mcap", _) => {
            let p = args.mcap.as_deref().unwrap_or(Path::new(""));
            let topic = args.topic.as_deref();
            match stream {
                Stream::Cam => offline(Box::new(
                    raw::CamSource::mcap(p, topic).map_err(src)?.with_stop(stop),
                )),
                Stream::Lidar => offline(Box::new(fronted(
                    raw::LidarSource::mcap(p, topic).map_err(src)?,
                )?)),
            }
        }
        ("--frames", Stream::Cam) => {
            let d = args.frames.as_deref().unwrap_or(Path::new(""));
            offline(Box::new(
                raw::CamSource::frames_dir(d).map_err(src)?.with_stop(stop),
            ))
        }
        ("--scans", Stream::Lidar) => {
            let p = args.scans.as_deref().unwrap_or(Path::new(""));
            offline(Box::new(fronted(
                raw::LidarSource::scans_csv(p).map_err(src)?,
            )?))
        }
        ("--v4l2", Stream::Cam) => {
            let d = args.v4l2.as_deref().unwrap_or(Path::new(""));
            if args.wait_device && !wait_for_device(d, stream, stop, DEVICE_POLL) {
                return Ok(stopped_while_waiting(d));
            }
            Ok(Selected {
                source: Box::new(raw::CamSource::v4l2_at(d, camera_fps(args)?, stop).map_err(src)?),
                anchor_ns: None,
                start_at: None,
                stopped: None,
            })
        }
        ("--pipe" | "--pipe-cmd", Stream::Cam) => {
            let input = match (&args.pipe, &args.pipe_cmd) {
                (Some(p), _) if p.as_os_str() == "-" => raw::PipeInput::Stdin,
                (Some(p), _) => raw::PipeInput::Path(p.clone()),
                (None, c) => raw::PipeInput::Command(c.clone().unwrap_or_default()),
            };
            let cfg = raw_layout
                .ok_or_else(|| DriverError::Options(format!("{flag} needs --size WIDTHxHEIGHT")))?;
            pipe_input_can_carry_frames(&input)?;
            Ok(Selected {
                source: Box::new(raw::CamSource::pipe(input, cfg, stop).map_err(src)?),
                anchor_ns: None,
                start_at: None,
                stopped: None,
            })
        }
        ("--ld06" | "--rplidar", Stream::Lidar) => {
            let (kind, dev) = match (&args.ld06, &args.rplidar) {
                (Some(d), _) => (raw::SerialKind::Ld06, d.as_str()),
                (None, d) => (raw::SerialKind::Rplidar, d.as_deref().unwrap_or_default()),
            };
            if args.wait_device && !wait_for_device(Path::new(dev), stream, stop, DEVICE_POLL) {
                return Ok(stopped_while_waiting(Path::new(dev)));
            }
            Ok(Selected {
                source: Box::new(fronted(
                    raw::LidarSource::serial(kind, dev, args.baud, SERIAL_SILENCE, stop)
                        .map_err(src)?,
                )?),
                anchor_ns: None,
                start_at: None,
                stopped: None,
            })
        }
        (f, _) => Err(wrong_stream(f)),
    }
}

/// The sources a driver can be given, with the flags `args` set.
fn given_sources(args: &DriverArgs) -> Vec<&'static str> {
    [
        ("--csv", args.csv.is_some()),
        ("--sim", args.sim.is_some()),
        ("--render", args.render.is_some()),
        ("--mcap", args.mcap.is_some()),
        ("--frames", args.frames.is_some()),
        ("--v4l2", args.v4l2.is_some()),
        ("--pipe", args.pipe.is_some()),
        ("--pipe-cmd", args.pipe_cmd.is_some()),
        ("--ld06", args.ld06.is_some()),
        ("--rplidar", args.rplidar.is_some()),
        ("--scans", args.scans.is_some()),
    ]
    .into_iter()
    .filter_map(|(f, on)| on.then_some(f))
    .collect()
}

/// The live devices among the sources: published as their data arrives; every wait of
/// theirs checks the stop. The others are recordings and simulations.
const LIVE_SOURCES: [&str; 5] = ["--v4l2", "--ld06", "--rplidar", "--pipe", "--pipe-cmd"];

/// Whether the source is a recording or a simulation, not a device: its reads make
/// no stop checks (a whole CSV read before the first sample, an MCAP file's chunks
/// walked to the next message), where every wait of a device source checks.
fn recorded_source(args: &DriverArgs) -> bool {
    let given = given_sources(args);
    !given.is_empty() && !given.iter().any(|f| LIVE_SOURCES.contains(f))
}

/// `--pipe -` or `--pipe PATH`: the input must be something a camera program writes
/// into (a pipe, a FIFO, a file), not a character device: `/dev/null` (systemd's
/// standard input: the unit would restart an empty run every 2 s for ever), a
/// terminal, or either behind `/dev/stdin`. An options error, so the unit stays
/// failed with the reason; a path that cannot be read is left to the pipe source's
/// open, which names it.
fn pipe_input_can_carry_frames(input: &raw::PipeInput) -> Result<(), DriverError> {
    use std::os::fd::AsFd;
    let (meta, shown) = match input {
        // (a closed standard input is /dev/null already: Rust's start-up reopens it so)
        raw::PipeInput::Stdin => (
            std::io::stdin()
                .as_fd()
                .try_clone_to_owned()
                .ok()
                .and_then(|fd| std::fs::File::from(fd).metadata().ok()),
            "--pipe -: standard input".to_string(),
        ),
        raw::PipeInput::Path(p) => (std::fs::metadata(p).ok(), format!("--pipe {}", p.display())),
        raw::PipeInput::Command(_) => return Ok(()),
    };
    refuse_character_device(meta.as_ref(), &shown)
}

/// [`pipe_input_can_carry_frames`]'s rule on what the input is (`shown` names it).
fn refuse_character_device(
    meta: Option<&std::fs::Metadata>,
    shown: &str,
) -> Result<(), DriverError> {
    use std::os::unix::fs::FileTypeExt;
    if meta.is_some_and(|m| m.file_type().is_char_device()) {
        return Err(DriverError::Options(format!(
            "{shown} is a character device (/dev/null, as systemd's standard input, or a \
             terminal), not a camera program's output: pipe the program into it \
             (`rpicam-vid ... -o - | vlsync-cam --pipe - ...`), give a FIFO it writes into, \
             or use --pipe-cmd"
        )));
    }
    Ok(())
}

/// `--aligned`'s start: the latest multiple of `period_ns` at or before `now_ns`
/// (`now_ns` itself for a period that is not positive).
pub fn aligned_start_ns(
    now_ns: vlsync_common::Nanos,
    period_ns: vlsync_common::Nanos,
) -> vlsync_common::Nanos {
    if period_ns <= 0 {
        return now_ns;
    }
    now_ns - now_ns.rem_euclid(period_ns)
}

/// How often `--wait-device` looks for the device node.
pub const DEVICE_POLL: Duration = Duration::from_millis(500);

/// Waits until `dev` exists, checking every `poll` and saying so on stderr at the
/// start and every [`PROGRESS_EVERY`]. False when `stop` asked to stop first.
pub fn wait_for_device(dev: &Path, stream: Stream, stop: raw::StopFn, poll: Duration) -> bool {
    if dev.exists() {
        return true;
    }
    vlsync_common::console::print_err(&format!(
        "vlsync-{stream}: waiting for {} to appear (unplugged, or not enumerated yet); \
         checking every {} ms\n",
        dev.display(),
        poll.as_millis()
    ));
    let t0 = std::time::Instant::now();
    let mut next_note = PROGRESS_EVERY;
    loop {
        // sleep in short steps so a stop request is seen at once
        let until = std::time::Instant::now() + poll;
        while std::time::Instant::now() < until {
            if stop() {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20).min(poll));
        }
        if dev.exists() {
            vlsync_common::console::print_err(&format!(
                "vlsync-{stream}: {} appeared after {:.1} s\n",
                dev.display(),
                t0.elapsed().as_secs_f64()
            ));
            // a new node gets its group and mode from udev just after it appears
            std::thread::sleep(poll);
            return !stop();
        }
        if t0.elapsed() >= next_note {
            vlsync_common::console::print_err(&format!(
                "vlsync-{stream}: still waiting for {} ({} min)\n",
                dev.display(),
                t0.elapsed().as_secs() / 60
            ));
            next_note += PROGRESS_EVERY;
        }
    }
}

/// A source with nothing to publish: stopped while waiting for `dev`
/// ([`Selected::stopped`]).
fn stopped_while_waiting(dev: &Path) -> Selected {
    Selected {
        source: Box::new(VecSource::new(Vec::new(), "nothing")),
        anchor_ns: None,
        start_at: None,
        stopped: Some(format!("stopped while waiting for {}", dev.display())),
    }
}

/// Why the driver stops before it publishes anything: a stop while it waited for
/// the device (`stopped`), or one that came while the source opened or read ahead
/// (`stop()`); `None`: it goes on to publish. Either way no iceoryx2 node is made.
fn stopped_before_publishing(stopped: Option<String>, stop: raw::StopFn) -> Option<String> {
    stopped.or_else(|| stop().then(|| "stopped before publishing".to_string()))
}

/// The driver's first line once it publishes: what, where, and the start instant
/// it picked, if it did (`--stamp mono|software` without `--start-at`), so that
/// the other driver of the pair can be given the same.
fn publishing_line(stream: Stream, what: &str, service: &str, picked: Option<i64>) -> String {
    let mut line = format!("vlsync-{stream}: publishing {what} on {service}");
    if let Some(t) = picked {
        line.push_str(&format!(
            "; start instant picked: --start-at {t} (CLOCK_MONOTONIC ns): give the other \
             driver of the pair the same"
        ));
    }
    line.push('\n');
    line
}

/// A span of time as the progress line says it: seconds, minutes, hours or days.
fn span_text(d: Duration) -> String {
    let s = d.as_secs_f64();
    match s {
        s if s < 120.0 => format!("{s:.0} s"),
        s if s < 7200.0 => format!("{:.0} min", s / 60.0),
        s if s < 172_800.0 => format!("{:.1} h", s / 3600.0),
        s => format!("{:.1} days", s / 86_400.0),
    }
}

/// A progress line: what the run did in the `since` since the previous one
/// (`last`'s totals), and the source's report.
fn progress_line(
    stream: Stream,
    s: &RunSummary,
    last: &RunSummary,
    since: Duration,
    r: Option<String>,
) -> String {
    let unreached = s.unreached - last.unreached;
    format!(
        "vlsync-{stream}: last {}: {} published, {} failed ({} published in all){}{}\n",
        span_text(since),
        s.published - last.published,
        s.failed - last.failed,
        s.published,
        when_any(unreached, |n| format!(
            ", {n} of them reached no subscriber (no daemon running)"
        )),
        r.map(|r| format!("; {r}")).unwrap_or_default()
    )
}

/// The configuration of --config (defaults without one), read once per `args`
/// ([`DriverArgs::loaded_config`]).
fn config(args: &DriverArgs) -> Result<vlsync_config::Config, DriverError> {
    if let Some(c) = args.loaded_config.get() {
        return Ok(c.clone());
    }
    let c = match &args.config {
        Some(path) => {
            vlsync_config::Config::load(path).map_err(|e| DriverError::Options(e.to_string()))?
        }
        None => vlsync_config::Config::default(),
    };
    Ok(args.loaded_config.get_or_init(|| c).clone())
}

/// The LiDAR front-end's windows: `[lidar]` of --config, `--opposite-window` on top.
fn lidar_front(args: &DriverArgs) -> Result<vlsync_config::LidarConfig, DriverError> {
    let mut f = config(args)?.lidar;
    f.opposite_window |= args.opposite_window;
    Ok(f)
}

/// The raw frames' layout of --pipe / --pipe-cmd (`None` without --size); the layout
/// options without either are an error.
fn pipe_layout(
    args: &DriverArgs,
    piped: bool,
) -> Result<Option<vlsync_signature_cam::pipe::PipeConfig>, DriverError> {
    use vlsync_signature_cam::pipe::{PipeConfig, PipeFormat};
    let given = [
        ("--size", args.size.is_some()),
        ("--raw-format", args.raw_format.is_some()),
        ("--stride", args.stride.is_some()),
    ];
    if !piped {
        if let Some((f, _)) = given.iter().find(|g| g.1) {
            return Err(DriverError::Options(format!(
                "{f} applies to --pipe and --pipe-cmd only"
            )));
        }
        return Ok(None);
    }
    let format = match args.raw_format.as_deref() {
        Some(f) => {
            PipeFormat::parse(f).map_err(|e| DriverError::Options(format!("--raw-format: {e}")))?
        }
        None => PipeFormat::I420,
    };
    let Some(size) = args.size.as_deref() else {
        return Ok(None);
    };
    let bad = || {
        DriverError::Options(format!(
            "--size `{}`: expected WIDTHxHEIGHT in pixels, each 1 ..= 16384 (e.g. 320x240)",
            vlsync_common::text::clip(size)
        ))
    };
    let (w, h) = size.trim().split_once(['x', 'X']).ok_or_else(bad)?;
    let dim = |t: &str| {
        t.trim()
            .parse::<usize>()
            .ok()
            .filter(|v| (1..=16384).contains(v))
            .ok_or_else(bad)
    };
    let cfg = PipeConfig {
        width: dim(w)?,
        height: dim(h)?,
        stride: args.stride,
        format,
        silence: raw::PIPE_SILENCE,
    };
    // the geometry's own checks (an odd YUYV width, a stride short of a row)
    cfg.layout()
        .map_err(|e| DriverError::Options(format!("--size {size} --raw-format {format}: {e}")))?;
    Ok(Some(cfg))
}

/// Where a value of the driver's configuration comes from, for a message about it.
fn config_source(args: &DriverArgs) -> &'static str {
    if args.config.is_some() {
        "as --config sets it"
    } else {
        "its default: no --config"
    }
}

/// `--render-fps` and `--render-lidar-hz`: refused without `--render`, and checked
/// as [`raw::RenderRates::check`] does against this driver's configuration.
fn render_rates(args: &DriverArgs, flag: &str) -> Result<raw::RenderRates, DriverError> {
    let rates = raw::RenderRates {
        cam_fps: args.render_fps,
        lidar_hz: args.render_lidar_hz,
    };
    if rates == raw::RenderRates::default() {
        return Ok(rates);
    }
    if flag != "--render" {
        let name = if rates.cam_fps.is_some() {
            "--render-fps"
        } else {
            "--render-lidar-hz"
        };
        return Err(DriverError::Options(format!(
            "{name} applies to --render only (other sources keep their own rates)"
        )));
    }
    rates
        .check(config(args)?.estimator.max_gap_s, config_source(args))
        .map_err(DriverError::Options)?;
    Ok(rates)
}

/// The frame rate asked of a V4L2 camera: `--fps`, else `camera.v4l2_fps` of
/// --config; `None` (0 in either): the camera's own.
fn camera_fps(args: &DriverArgs) -> Result<Option<f64>, DriverError> {
    match args.fps {
        Some(fps) => Ok((fps != 0.0).then_some(fps)),
        None => Ok(config(args)?.camera.v4l2_fps()),
    }
}

/// `--prefix`, else `services.prefix` of --config.
fn prefix(args: &DriverArgs) -> Result<String, DriverError> {
    match &args.prefix {
        Some(p) => Ok(p.clone()),
        None => Ok(config(args)?.services.prefix),
    }
}

/// Runs a driver for `stream` with `args`; prints what the source dropped at the end.
pub fn run_driver(stream: Stream, args: &DriverArgs) -> Result<crate::RunSummary, DriverError> {
    // before a source opens (a serial port or a camera may take a while): a stop
    // from then on ends the driver cleanly
    vlsync_ipc::handle_termination_signals();
    // systemd's watchdog is petted from the stop check every wait and sample of
    // this thread makes (crate::watchdog): a driver stuck in a call restarts
    let (problems, watchdog_on) = crate::watchdog::init(&format!("vlsync-{stream}"));
    for p in problems {
        vlsync_common::console::print_err_at(
            vlsync_common::console::Priority::Warning,
            &format!("vlsync-{stream}: systemd notification: {p}\n"),
        );
    }
    if recorded_source(args) {
        // a recorded or simulated source's reads make no stop checks (a whole CSV
        // before the first sample, an MCAP file's chunks walked to the next message):
        // a helper thread pets for the whole run; the watchdog guards device sources
        crate::watchdog::petting_while(|| publish_source(stream, args, watchdog_on))
    } else {
        publish_source(stream, args, watchdog_on)
    }
}

/// [`run_driver`] once signals and systemd are set up: selects the source and
/// publishes it.
fn publish_source(
    stream: Stream,
    args: &DriverArgs,
    watchdog_on: bool,
) -> Result<crate::RunSummary, DriverError> {
    let stop_check: raw::StopFn = crate::watchdog::stop_check;
    let prefix = prefix(args)?;
    let every = report_every(args)?;
    // an invalid prefix is an options error (exit 78, not restarted), wherever it came from
    let names = ServiceNames::new(&prefix).map_err(|e| DriverError::Options(e.to_string()))?;
    let Selected {
        mut source,
        anchor_ns,
        start_at,
        stopped,
    } = select_source(args, stream, stop_check)?;
    if let Some(why) = stopped_before_publishing(stopped, stop_check) {
        vlsync_common::console::print_err(&format!("vlsync-{stream}: {why}\n"));
        return Ok(RunSummary {
            interrupted: true,
            ..RunSummary::default()
        });
    }
    // the truth file before the node: its error is an options error, said before
    // anything is published
    let mut truth = match &args.truth_out {
        Some(p) => Some(crate::TruthLog::create(p)?),
        None => None,
    };
    let node = create_node(&format!("vlsync-{stream}"), true).map_err(DriverError::Ipc)?;
    // a service this driver creates serves the daemon's configured buffer
    // (validated 1..=65536)
    let buffer = usize::try_from(config(args)?.services.subscriber_buffer).unwrap_or(1);
    let mut publisher =
        SignaturePublisher::open_sized(&node, &names, stream, buffer).map_err(DriverError::Ipc)?;
    // the simulators' samples say so: the daemon warns that its offset is not the
    // robot's (a unit shipped with --sim and never pointed at the sensors)
    publisher.set_simulated(args.sim.is_some() || args.render.is_some());
    let pacing = match anchor_ns {
        _ if args.fast => Pacing::Fast,
        // a live device: publish as the data arrives
        None => Pacing::Fast,
        Some(anchor) => Pacing::Scaled {
            speed: args.speed.unwrap_or(1.0),
            anchor_ns: anchor,
            start_mono_ns: start_at,
        },
    };
    let line = publishing_line(
        stream,
        &source.describe(),
        &names.signature(stream),
        start_at.filter(|_| args.start_at.is_none() && !args.aligned),
    );
    vlsync_common::console::print_err(&line);
    if let (true, Some(t)) = (args.aligned, start_at) {
        vlsync_common::console::print_err(&format!(
            "vlsync-{stream}: --aligned: this run started at {t} (CLOCK_MONOTONIC ns), {:.1} s ago; publishing from there\n",
            vlsync_common::nanos_to_secs(vlsync_ipc::monotonic_ns().saturating_sub(t))
        ));
    }
    if let Err(e) = crate::watchdog::ready(line.trim_end()) {
        vlsync_common::console::print_err_at(
            vlsync_common::console::Priority::Warning,
            &format!("vlsync-{stream}: systemd notification: {e}\n"),
        );
    }
    if watchdog_on {
        vlsync_common::console::print_err(&format!(
            "vlsync-{stream}: systemd watchdog on: petted while this driver's loop runs\n"
        ));
    }
    let mut last = RunSummary::default();
    let mut report = |s: &RunSummary, since: Duration, r: Option<String>| {
        let line = progress_line(stream, s, &last, since, r);
        vlsync_common::console::print_err(&line);
        // `systemctl status` shows the newest (a failure to send is said by the pets)
        let _ = crate::watchdog::status(line.trim_end());
        last = *s;
    };
    let result = run(
        &mut *source,
        &mut publisher,
        pacing,
        &stop_check,
        truth.as_mut(),
        Some(Progress {
            every,
            report: &mut report,
            notice: &mut |line| {
                vlsync_common::console::print_err(&format!("vlsync-{stream}: {line}\n"))
            },
        }),
    );
    if let Some(r) = source.report() {
        vlsync_common::console::print_err(&format!("vlsync-{stream}: {r}\n"));
    }
    // the samples live in this process's shared memory until the daemon has taken
    // them: leaving right after the last send (a fast replay above all) would take
    // the newest ones away with the publisher before the daemon woke to read them
    if matches!(&result, Ok(s) if !s.interrupted && s.published > s.unreached) {
        let until = std::time::Instant::now() + LINGER;
        while std::time::Instant::now() < until && !stop_check() {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    if let (Some(t), Some(p)) = (truth.as_mut(), &args.truth_out) {
        match (t.finish(), &result) {
            (Ok(()), _) => vlsync_common::console::print_err(&format!(
                "vlsync-{stream}: {} truth rows written to {}\n",
                t.rows(),
                p.display()
            )),
            // the run's own error is the one to return; the truth file's is said
            (Err(e), Err(_)) => vlsync_common::console::print_err_at(
                vlsync_common::console::Priority::Warning,
                &format!("vlsync-{stream}: {e}\n"),
            ),
            (Err(e), Ok(_)) => return Err(DriverError::Source(e)),
        }
    }
    result
}

impl StampArg {
    /// The value as written on the command line.
    pub fn name(self) -> &'static str {
        match self {
            StampArg::Sensor => "sensor",
            StampArg::Mono => "mono",
            StampArg::Software => "software",
        }
    }
}

/// Exit status of a driver whose options or configuration file are wrong (sysexits'
/// `EX_CONFIG`, `status=78/CONFIG` under systemd): the driver units do not restart
/// it (`RestartPreventExitStatus=78`), since it would fail the same way. A source
/// or iceoryx2 error exits 2 and is restarted (a sensor unplugged, a daemon
/// restarting). A command line that cannot be parsed is an options error too.
pub const EXIT_CONFIG: u8 = 78;

/// How long a driver keeps its publisher after its source ended, so the daemon can
/// take the last samples (it needs well under a millisecond once woken).
pub const LINGER: Duration = Duration::from_millis(500);

/// How often a driver writes a progress line (journald under systemd), whether it
/// publishes or not (a sensor that gives no sample: a parked robot); each says the
/// real time since the previous one.
pub const PROGRESS_EVERY: Duration = Duration::from_secs(600);

/// Options only the camera driver takes (clap's ids).
const CAM_ONLY: [&str; 9] = [
    "frames",
    "v4l2",
    "fps",
    "pipe",
    "pipe_cmd",
    "size",
    "raw_format",
    "stride",
    "frame_cpu_ms",
];
/// Options only the LiDAR driver takes.
const LIDAR_ONLY: [&str; 5] = ["opposite_window", "ld06", "rplidar", "baud", "scans"];

/// The command line of one driver binary: [`DriverArgs`] with the other driver's
/// options left out of `--help` (still parsed, so giving one is refused naming the
/// binary: "--frames is not a source of vlsync-lidar"), and its own sources listed.
pub fn command(stream: Stream) -> clap::Command {
    use clap::CommandFactory;
    let (name, hidden, sources): (&str, &[&str], &str) = match stream {
        Stream::Cam => (
            "vlsync-cam",
            &LIDAR_ONLY,
            "Sources (give exactly one): --csv, --sim, --render, --mcap (an Image or \
             CompressedImage topic), --frames, --v4l2, --pipe, --pipe-cmd. Files and \
             simulators are paced by their timestamps (or --fast); live devices publish as \
             data arrives.",
        ),
        Stream::Lidar => (
            "vlsync-lidar",
            &CAM_ONLY,
            "Sources (give exactly one): --csv, --sim, --render, --mcap (a LaserScan topic), \
             --ld06, --rplidar, --scans. Files and simulators are paced by their timestamps \
             (or --fast); live devices publish as data arrives.",
        ),
    };
    let mut cmd = DriverArgs::command()
        .name(name)
        .bin_name(name)
        .about(format!(
            "Publish the {stream} signature stream to the vlsync daemon"
        ))
        .after_help(sources);
    for id in hidden {
        cmd = cmd.mut_arg(*id, |a| a.hide(true));
    }
    // the shared doc comment names both drivers' devices; each binary names its own
    let devices = match stream {
        Stream::Cam => "--v4l2",
        Stream::Lidar => "--ld06, --rplidar",
    };
    cmd.mut_arg("wait_device", |a| {
        a.help(format!(
            "Live devices ({devices}): wait for the device node to appear instead of \
             failing at once, saying so then and every 10 minutes (what the systemd units \
             do, so an unplugged sensor is picked up again when it returns). Other sources \
             have no device node and start at once."
        ))
    })
}

/// `main` of a driver binary.
pub fn main(stream: Stream) -> ExitCode {
    use clap::FromArgMatches;
    let parsed = command(stream)
        .try_get_matches_from(std::env::args_os())
        .and_then(|m| DriverArgs::from_arg_matches(&m));
    let args = match parsed {
        Ok(a) => a,
        Err(e) => {
            // --help and --version print and succeed; a command line that cannot be
            // parsed is an options error like the others (not restarted under systemd),
            // an error in the journal
            if !e.use_stderr() {
                let _ = e.print();
                return ExitCode::SUCCESS;
            }
            vlsync_common::console::print_err_at(
                vlsync_common::console::Priority::Error,
                &format!("{}\n", e.render().to_string().trim_end()),
            );
            return ExitCode::from(EXIT_CONFIG);
        }
    };
    match run_driver(stream, &args) {
        Ok(s) => {
            let summary = format!(
                "vlsync-{stream}: {} published, {} skipped (before restart), {} failed{}{}{}{}\n",
                s.published,
                s.skipped,
                s.failed,
                when_any(s.steps_back, |n| {
                    format!(
                    "; {n} stamp step(s) back by more than {} s: pacing went on in real time from each",
                    crate::STEP_BACK_NS / 1_000_000_000
                )
                }),
                when_any(s.unreached, |n| format!(
                    "; {n} reached no subscriber (no daemon running on this prefix then)"
                )),
                when_any(s.unwoken, |n| {
                    format!(
                    "; {n} without a wake-up of the daemon (its notify failed; read up to 0.1 s late)"
                )
                }),
                if s.interrupted { ", interrupted" } else { "" }
            );
            vlsync_common::console::print_err(&summary);
            // systemd's STOPPING=1 with the summary (a failure to send is moot now)
            let _ = crate::watchdog::stopping(summary.trim_end());
            ExitCode::SUCCESS
        }
        Err(e) => {
            let line = format!("vlsync-{stream}: error: {e}\n");
            vlsync_common::console::print_err_at(vlsync_common::console::Priority::Error, &line);
            let _ = crate::watchdog::stopping(line.trim_end());
            ExitCode::from(match e {
                DriverError::Options(_) => EXIT_CONFIG,
                _ => 2,
            })
        }
    }
}

/// `text(n)` when `n` counts something, else nothing: the optional parts of the
/// drivers' summary and progress lines.
fn when_any(n: u64, text: impl FnOnce(u64) -> String) -> String {
    if n > 0 {
        text(n)
    } else {
        String::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn never() -> bool {
        false
    }

    fn args(a: &[&str]) -> DriverArgs {
        DriverArgs::try_parse_from(std::iter::once("vlsync-cam").chain(a.iter().copied())).unwrap()
    }

    #[test]
    fn the_report_period_is_checked_and_defaults_to_ten_minutes() {
        assert_eq!(report_every(&args(&[])).unwrap(), PROGRESS_EVERY);
        assert_eq!(
            report_every(&args(&["--report-every", "1"])).unwrap(),
            Duration::from_secs(1)
        );
        assert_eq!(
            report_every(&args(&["--report-every", "86400"])).unwrap(),
            Duration::from_secs(86_400)
        );
        for bad in ["0.5", "0", "-1", "NaN", "inf", "86401"] {
            let e = report_every(&args(&["--report-every", bad])).unwrap_err();
            assert_eq!(
                e.to_string(),
                format!(
                    "options: --report-every {} is out of range: allowed 1 ..= 86400 seconds",
                    vlsync_common::text::number(bad.parse::<f64>().unwrap())
                )
            );
        }
    }

    /// Each binary's `--help` lists its own sources and options, not the other's;
    /// the other's still parse (and are then refused naming the binary).
    #[test]
    fn each_binary_helps_with_its_own_options() {
        use clap::FromArgMatches;
        for (stream, own, other) in [
            (Stream::Cam, &CAM_ONLY[..], &LIDAR_ONLY[..]),
            (Stream::Lidar, &LIDAR_ONLY[..], &CAM_ONLY[..]),
        ] {
            let mut cmd = command(stream);
            cmd.build();
            let help = cmd.render_long_help().to_string();
            let flag = |id: &str| format!("--{}", id.replace('_', "-"));
            let shown = |id: &str| {
                [" ", "\n", ",", ")"]
                    .iter()
                    .any(|end| help.contains(&format!("{}{end}", flag(id))))
            };
            for id in own {
                assert!(shown(id), "{stream}: {id} missing:\n{help}");
            }
            for id in other {
                assert!(!shown(id), "{stream}: {id} shown:\n{help}");
            }
            assert!(help.contains(&format!("vlsync-{stream}")), "{help}");
            for id in ["--csv ", "--sim ", "--render ", "--mcap ", "--prefix "] {
                assert!(help.contains(id), "{stream}: {id} missing:\n{help}");
            }
            let hidden = flag(other[0]);
            let m = command(stream)
                .try_get_matches_from([
                    "x",
                    hidden.as_str(),
                    if other[0] == "opposite_window" {
                        "--fast"
                    } else {
                        "v"
                    },
                ])
                .unwrap();
            DriverArgs::from_arg_matches(&m).unwrap();
        }
    }

    fn options_error(a: &[&str]) -> String {
        match select_source(&args(a), Stream::Cam, never) {
            Err(DriverError::Options(e)) => e,
            Err(e) => panic!("not an options error: {e}"),
            Ok(_) => panic!("accepted: {a:?}"),
        }
    }

    #[test]
    fn fps_applies_to_v4l2_only_and_within_its_range() {
        assert_eq!(
            options_error(&["--csv", "/nonexistent.csv", "--fps", "30"]),
            "--fps applies to --v4l2 only (other sources keep their own times)"
        );
        for bad in ["0.5", "1001", "-30", "NaN"] {
            assert_eq!(
                options_error(&["--v4l2", "/dev/video-vlsync-none", "--fps", bad]),
                format!(
                    "--fps {} is out of range: allowed 0 (the camera's own rate) or 1 ..= 1000",
                    bad.parse::<f64>().unwrap()
                )
            );
        }
        // a rate whose frames are further apart than the estimator interpolates
        // across: refused at start, named with the rate it needs
        let e = options_error(&["--v4l2", "/dev/video-vlsync-none", "--fps", "1"]);
        assert!(
            e.starts_with("--fps 1: camera samples 1 s apart, more than `estimator.max_gap_s` = 0.75")
                && e.ends_with("ask for at least 1.34 frames a second or raise `estimator.max_gap_s` (its default: no --config)"),
            "{e}"
        );
    }

    #[test]
    fn fps_overrides_the_configuration_and_zero_keeps_the_cameras_rate() {
        let dir = std::env::temp_dir().join(format!("vlsync-cli-fps-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = dir.join("cam.toml");
        std::fs::write(&cfg, "[camera]\nv4l2_fps = 25.0\n").unwrap();
        let c = cfg.to_str().unwrap();
        let v4l2 = ["--v4l2", "/dev/video-vlsync-none"];
        assert_eq!(camera_fps(&args(&v4l2)).unwrap(), None);
        assert_eq!(
            camera_fps(&args(&[&v4l2[..], &["--config", c]].concat())).unwrap(),
            Some(25.0)
        );
        assert_eq!(
            camera_fps(&args(
                &[&v4l2[..], &["--config", c, "--fps", "7.5"]].concat()
            ))
            .unwrap(),
            Some(7.5)
        );
        assert_eq!(
            camera_fps(&args(&[&v4l2[..], &["--config", c, "--fps", "0"]].concat())).unwrap(),
            None
        );
        // a rate out of range in the file is an options error naming the key
        std::fs::write(&cfg, "[camera]\nv4l2_fps = 0.5\n").unwrap();
        match camera_fps(&args(&[&v4l2[..], &["--config", c]].concat())) {
            Err(DriverError::Options(e)) => assert!(e.contains("`camera.v4l2_fps` = 0.5"), "{e}"),
            other => panic!("{:?}", other.map_err(|e| e.to_string())),
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn pipe_options_are_checked_before_anything_starts() {
        for (a, want) in [
            (
                &["--pipe", "-"][..],
                "--pipe needs --size WIDTHxHEIGHT".to_string(),
            ),
            (
                &["--pipe-cmd", "true", "--size", "320"][..],
                "--size `320`: expected WIDTHxHEIGHT in pixels, each 1 ..= 16384 (e.g. 320x240)"
                    .to_string(),
            ),
            (
                &["--pipe", "-", "--size", "0x240"][..],
                "--size `0x240`: expected WIDTHxHEIGHT in pixels, each 1 ..= 16384 (e.g. 320x240)"
                    .to_string(),
            ),
            (
                &["--pipe", "-", "--size", "321x240", "--raw-format", "yuyv"][..],
                "--size 321x240 --raw-format yuyv: bad frame dimensions 321x240: YUYV needs an \
                 even width"
                    .to_string(),
            ),
            (
                &["--pipe", "-", "--size", "320x240", "--stride", "100"][..],
                "--size 320x240 --raw-format i420: invalid configuration `stride`: 100 bytes is \
                 less than a i420 row of 320 pixels (320 bytes)"
                    .to_string(),
            ),
            (
                &["--pipe", "-", "--size", "320x240", "--raw-format", "mjpeg"][..],
                "--raw-format: `mjpeg` is not a raw frame format this source reads (one of: \
                 gray, i420, nv12, yuyv)"
                    .to_string(),
            ),
            (
                &["--csv", "/nonexistent.csv", "--size", "320x240"][..],
                "--size applies to --pipe and --pipe-cmd only".to_string(),
            ),
            (
                &["--pipe-cmd", "true", "--size", "320x240", "--fast"][..],
                "--fast applies to recorded and simulated sources; --pipe-cmd is a live device, \
                 published as its data arrives (in real time)"
                    .to_string(),
            ),
        ] {
            assert_eq!(options_error(a), want, "{a:?}");
        }
        // the LiDAR driver has no pipe
        match select_source(
            &args(&["--pipe", "-", "--size", "8x8"]),
            Stream::Lidar,
            never,
        ) {
            Err(DriverError::Options(e)) => assert!(
                e.starts_with("--pipe is not a source of vlsync-lidar"),
                "{e}"
            ),
            other => panic!("{:?}", other.map(|_| ()).map_err(|e| e.to_string())),
        }
    }

    #[test]
    fn the_other_drivers_sources_and_options_are_named_as_its() {
        let lidar_error = |a: &[&str]| match select_source(&args(a), Stream::Lidar, never) {
            Err(DriverError::Options(e)) => e,
            other => panic!("{a:?}: {:?}", other.map(|_| ()).map_err(|e| e.to_string())),
        };
        // before the checks of a camera source's own (a build without V4L2 said
        // "this vlsync-cam is built without V4L2 support" from vlsync-lidar)
        for a in [
            &["--v4l2", "/dev/video0"][..],
            &["--v4l2", "/dev/video0", "--fps", "30"],
        ] {
            let e = lidar_error(a);
            assert!(
                e.starts_with("--v4l2 is not a source of vlsync-lidar; give one of"),
                "{e}"
            );
        }
        for (a, o) in [
            (&["--render", "1", "--fps", "30"][..], "--fps"),
            (&["--render", "1", "--size", "8x8"], "--size"),
            (&["--render", "1", "--raw-format", "gray"], "--raw-format"),
            (&["--render", "1", "--stride", "8"], "--stride"),
            (&["--render", "1", "--frame-cpu-ms", "2"], "--frame-cpu-ms"),
        ] {
            assert_eq!(
                lidar_error(a),
                format!("{o} is an option of vlsync-cam, not of vlsync-lidar")
            );
        }
        for (a, o) in [
            (
                &["--render", "1", "--opposite-window"][..],
                "--opposite-window",
            ),
            (&["--render", "1", "--baud", "230400"], "--baud"),
        ] {
            assert_eq!(
                options_error(a),
                format!("{o} is an option of vlsync-lidar, not of vlsync-cam")
            );
        }
        assert!(options_error(&["--ld06", "/dev/ttyUSB0"])
            .starts_with("--ld06 is not a source of vlsync-cam"));
    }

    #[test]
    fn a_camera_program_that_ends_is_an_error_naming_how() {
        // a program that writes two 8x8 gray frames a little apart, then fails
        let cmd = "head -c 64 /dev/zero; sleep 0.1; head -c 64 /dev/zero; exit 3";
        let mut src = match select_source(
            &args(&["--pipe-cmd", cmd, "--size", "8x8", "--raw-format", "gray"]),
            Stream::Cam,
            never,
        ) {
            Ok(s) => s.source,
            Err(e) => panic!("{e}"),
        };
        assert!(
            src.describe().starts_with("pipe raw gray frames 8x8"),
            "{}",
            src.describe()
        );
        // uniform frames carry no flow: no sample, then the program's end
        let e = loop {
            match src.next_sample() {
                Ok(Some(_)) => {}
                Ok(None) => panic!("the end of a camera program is not a clean end"),
                Err(e) => break e.to_string(),
            }
        };
        assert!(
            e.ends_with("camera program: the command ended (exit status: 3) after 2 frames"),
            "{e}"
        );
    }

    /// 8x8 gray frames from a pipe that may stay silent for `silence`.
    fn gray8_frames(silence: Duration) -> vlsync_signature_cam::pipe::PipeConfig {
        vlsync_signature_cam::pipe::PipeConfig {
            width: 8,
            height: 8,
            stride: None,
            format: vlsync_signature_cam::pipe::PipeFormat::Gray,
            silence,
        }
    }

    #[test]
    fn a_camera_program_that_stalls_is_started_again() {
        static STOP: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
        // one frame, then silence: each start of the program gives one frame
        let cfg = gray8_frames(Duration::from_millis(300));
        let mut src = raw::CamSource::pipe(
            raw::PipeInput::Command("head -c 64 /dev/zero; exec sleep 30".into()),
            cfg,
            || STOP.load(std::sync::atomic::Ordering::Relaxed),
        )
        .unwrap();
        let stopper = std::thread::spawn(|| {
            std::thread::sleep(Duration::from_millis(1500));
            STOP.store(true, std::sync::atomic::Ordering::Relaxed);
        });
        // 8x8 frames are too small for the flow: no sample, until the stop
        assert!(src.next_sample().unwrap().is_none());
        stopper.join().unwrap();
        let report = src.report().unwrap();
        let reopens: u64 = report
            .split("; the camera program restarted ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no restart in: {report}"));
        // 1.5 s of a program that stalls 0.3 s after each start
        assert!(reopens >= 2, "{report}");
    }

    #[test]
    fn a_camera_program_s_whole_group_goes_with_the_driver() {
        let dir = std::env::temp_dir().join(format!("vlsync-pipe-group-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pid_file = dir.join("pid");
        // a script whose own child (the sleep) would outlive a kill of `sh` alone
        let cmd = format!(
            "sleep 300 & echo $! > {}; head -c 64 /dev/zero; wait",
            pid_file.display()
        );
        let cfg = gray8_frames(Duration::from_secs(5));
        let src = raw::CamSource::pipe(raw::PipeInput::Command(cmd), cfg, never).unwrap();
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        let pid = loop {
            if let Some(p) = std::fs::read_to_string(&pid_file)
                .ok()
                .and_then(|t| t.trim().parse::<u32>().ok())
            {
                break p;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "the script never started"
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        let alive = |pid: u32| {
            // gone, or a zombie no one reaped yet: not running
            std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .ok()
                .and_then(|st| st.rsplit(") ").next().map(|r| !r.starts_with('Z')))
                .unwrap_or(false)
        };
        assert!(alive(pid));
        drop(src);
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        while alive(pid) {
            assert!(
                std::time::Instant::now() < deadline,
                "the program's child {pid} outlived the driver's source"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_camera_program_that_dies_mid_frame_is_named_with_its_status() {
        // one frame and a half, then the program kills itself
        let cfg = gray8_frames(Duration::from_secs(5));
        let cmd = "head -c 100 /dev/zero; kill -9 $$".to_string();
        let mut src = raw::CamSource::pipe(raw::PipeInput::Command(cmd), cfg, never).unwrap();
        let e = loop {
            match src.next_sample() {
                Err(e) => break e.to_string(),
                Ok(Some(_)) => {}
                Ok(None) => panic!("the stream ended without the error"),
            }
        };
        assert!(
            e.contains("inside frame") && e.contains("the command ended (signal: 9"),
            "{e}"
        );
    }

    /// A pipe that ends before any frame (standard input of /dev/null under systemd,
    /// an empty file) is an error naming it, not a clean run of nothing that
    /// `Restart=always` repeats without a word; one that ends after frames is the
    /// stream's end.
    #[test]
    fn a_pipe_that_ends_before_any_frame_is_an_error() {
        let dir = std::env::temp_dir().join(format!("vlsync-pipe-end-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let empty = dir.join("empty");
        std::fs::write(&empty, b"").unwrap();
        let cfg = gray8_frames(Duration::from_secs(5));
        let mut src =
            raw::CamSource::pipe(raw::PipeInput::Path(empty.clone()), cfg, never).unwrap();
        let e = src.next_sample().unwrap_err().to_string();
        assert!(
            e.contains(&empty.display().to_string()) && e.contains("ended before any frame"),
            "{e}"
        );
        // two 8x8 frames, then the end: no error (the frames are too small for the
        // flow, so no sample either)
        let two = dir.join("two");
        std::fs::write(&two, [0u8; 128]).unwrap();
        let mut src = raw::CamSource::pipe(raw::PipeInput::Path(two), cfg, never).unwrap();
        let end = src.next_sample();
        assert!(
            !matches!(&end, Err(e) if e.to_string().contains("before any frame")),
            "{end:?}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// --aligned starts a simulator run at the latest multiple of its duration, the
    /// same instant for both drivers of a pair whenever either starts; it applies to
    /// --sim paced in real time only.
    #[test]
    fn aligned_runs_start_at_a_multiple_of_their_duration() {
        assert_eq!(aligned_start_ns(7_300, 3_600), 7_200);
        assert_eq!(aligned_start_ns(7_200, 3_600), 7_200);
        assert_eq!(aligned_start_ns(3_599, 3_600), 0);
        assert_eq!(aligned_start_ns(5, 0), 5);
        let minute = 60_000_000_000;
        let a = args(&["--sim", "robot", "--duration", "60", "--aligned"]);
        let before = vlsync_ipc::monotonic_ns();
        let cam = select_source(&a, Stream::Cam, never)
            .unwrap()
            .start_at
            .unwrap();
        let lidar = select_source(&a, Stream::Lidar, never)
            .unwrap()
            .start_at
            .unwrap();
        let after = vlsync_ipc::monotonic_ns();
        assert_eq!(cam % minute, 0);
        assert!(
            cam <= after && after - cam < minute + (after - before),
            "{cam} {after}"
        );
        // the pair agrees unless a minute boundary passed between the two calls
        assert!(cam == lidar || lidar - cam == minute, "{cam} {lidar}");
        for (bad, why) in [
            (
                &["--csv", "x.csv", "--aligned"][..],
                "--aligned applies to --sim",
            ),
            (
                &["--sim", "robot", "--aligned", "--fast"][..],
                "--fast publishes at once",
            ),
            (
                &["--sim", "robot", "--aligned", "--speed", "2"][..],
                "drop --speed",
            ),
        ] {
            let e = select_source(&args(bad), Stream::Cam, never)
                .err()
                .unwrap()
                .to_string();
            assert!(e.contains(why), "{bad:?}: {e}");
        }
        assert!(DriverArgs::try_parse_from([
            "vlsync-cam",
            "--sim",
            "robot",
            "--aligned",
            "--start-at",
            "5"
        ])
        .is_err());
    }

    /// `--pipe -` refuses a character device as its standard input (/dev/null under
    /// systemd, a terminal), an options error; a pipe or a file is fine.
    #[test]
    fn a_character_device_is_no_camera_pipe() {
        // what standard input may be: /dev/null is refused, a pipe or a file is not
        let meta = |f: &std::fs::File| f.metadata().unwrap();
        let null = std::fs::File::open("/dev/null").unwrap();
        let e =
            refuse_character_device(Some(&meta(&null)), "--pipe -: standard input").unwrap_err();
        assert!(
            matches!(&e, DriverError::Options(m) if m.contains("--pipe -: standard input is a character device")),
            "{e}"
        );
        let (r, _w) = std::io::pipe().unwrap();
        refuse_character_device(
            Some(
                &std::fs::File::from(std::os::fd::OwnedFd::from(r))
                    .metadata()
                    .unwrap(),
            ),
            "x",
        )
        .unwrap();
        let exe = std::env::current_exe().unwrap();
        refuse_character_device(Some(&meta(&std::fs::File::open(&exe).unwrap())), "x").unwrap();
        // by path: /dev/null itself (and behind /dev/stdin when that is /dev/null)
        let e = pipe_input_can_carry_frames(&raw::PipeInput::Path("/dev/null".into())).unwrap_err();
        assert!(
            matches!(&e, DriverError::Options(m) if m.contains("--pipe /dev/null is a character device")),
            "{e}"
        );
        pipe_input_can_carry_frames(&raw::PipeInput::Path(exe)).unwrap();
        pipe_input_can_carry_frames(&raw::PipeInput::Path("/nonexistent/vlsync/fifo".into()))
            .unwrap();
    }

    /// --config is read once: a file broken while the driver waits for its device
    /// (hours, maybe) does not turn the device's arrival into an options error
    /// (exit 78, never restarted).
    #[test]
    fn the_configuration_is_read_once() {
        let dir = std::env::temp_dir().join(format!("vlsync-cfg-once-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("vlsync.toml");
        std::fs::write(
            &path,
            "[services]\nprefix = \"robot-a\"\n\n[camera]\nv4l2_fps = 30\n",
        )
        .unwrap();
        let a = args(&["--config", path.to_str().unwrap()]);
        assert_eq!(prefix(&a).unwrap(), "robot-a");
        std::fs::write(&path, "[services\nprefix = ").unwrap();
        assert_eq!(camera_fps(&a).unwrap(), Some(30.0));
        assert_eq!(prefix(&a).unwrap(), "robot-a");
        // a new start reads the file again, and says what is wrong with it
        let fresh = args(&["--config", path.to_str().unwrap()]);
        let e = prefix(&fresh).unwrap_err().to_string();
        assert!(e.contains("vlsync.toml"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_fifo_without_a_writer_is_a_stall_not_a_hang() {
        let dir = std::env::temp_dir().join(format!("vlsync-pipe-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("frames");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let cfg = gray8_frames(Duration::from_millis(300));
        // the open returns at once; no writer ever comes: the driver's error, no reopen
        let mut src = raw::CamSource::pipe(raw::PipeInput::Path(fifo.clone()), cfg, never).unwrap();
        let e = src.next_sample().unwrap_err().to_string();
        // no program behind a FIFO that this driver knows of: its writer is named
        assert!(
            e.contains(&format!("writer of {}: no frame for 0.", fifo.display())),
            "{e}"
        );
        assert!(!e.contains("camera program:"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn frames_too_small_for_the_flow_end_the_source_naming_why() {
        // 8x8 frames cannot hold the region of interest, its margin and pyramid:
        // every one is refused, and the source ends instead of publishing nothing
        let cfg = gray8_frames(Duration::from_secs(5));
        // paced as a camera is (frames already waiting in the pipe are dropped)
        let cmd = "for i in $(seq 40); do head -c 64 /dev/zero; sleep 0.03; done; exec sleep 30"
            .to_string();
        let mut src = raw::CamSource::pipe(raw::PipeInput::Command(cmd), cfg, never).unwrap();
        let e = match src.next_sample() {
            Err(e) => e.to_string(),
            Ok(Some(_)) => panic!("a sample from 8x8 frames"),
            Ok(None) => panic!("the stream ended without the error"),
        };
        assert!(
            e.contains("frame 8x8 too small") && e.contains("10 frames in a row"),
            "{e}"
        );
        assert!(e.contains("--size"), "{e}");
    }

    fn yes() -> bool {
        true
    }

    #[test]
    fn options_that_would_do_nothing_are_refused_naming_why() {
        let t = vlsync_ipc::monotonic_ns().to_string();
        let lidar_error = |a: &[&str]| match select_source(&args(a), Stream::Lidar, never) {
            Err(DriverError::Options(e)) => e,
            Err(e) => panic!("not an options error: {e}"),
            Ok(_) => panic!("accepted: {a:?}"),
        };
        for (a, want) in [
            (
                vec!["--pipe-cmd", "true", "--size", "8x8", "--start-at", &t],
                "--start-at applies to recorded and simulated sources paced in real time; \
                 --pipe-cmd is a live device, published as its data arrives",
            ),
            (
                vec!["--pipe", "-", "--size", "8x8", "--start-at", &t],
                "--start-at applies to recorded and simulated sources paced in real time; \
                 --pipe is a live device, published as its data arrives",
            ),
            (
                vec!["--csv", "/nonexistent.csv", "--fast", "--start-at", &t],
                "--start-at sets when real-time pacing starts; --fast publishes at once, \
                 without pacing",
            ),
            (
                vec!["--render", "2", "--seed", "2"],
                "--seed applies to --sim only; --render takes its seed as its value \
                 (--render SEED)",
            ),
            (
                vec!["--csv", "/nonexistent.csv", "--seed", "1"],
                "--seed applies to --sim only; --csv has no seed",
            ),
        ] {
            assert_eq!(options_error(&a), want, "{a:?}");
        }
        assert_eq!(
            lidar_error(&["--ld06", "/dev/ttyUSB0", "--start-at", &t]),
            "--start-at applies to recorded and simulated sources paced in real time; \
             --ld06 is a live device, published as its data arrives"
        );
        // where they matter they pass (here on to the missing file)
        for a in [
            vec!["--csv", "/nonexistent.csv", "--start-at", &t],
            vec![
                "--csv",
                "/nonexistent.csv",
                "--speed",
                "2",
                "--start-at",
                &t,
            ],
        ] {
            match select_source(&args(&a), Stream::Cam, never) {
                Err(DriverError::Source(e)) => assert!(e.0.contains("/nonexistent.csv"), "{e}"),
                other => panic!("{a:?}: {:?}", other.map(|_| ()).map_err(|e| e.to_string())),
            }
        }
        let sim = select_source(
            &args(&[
                "--sim",
                "robot",
                "--seed",
                "2",
                "--duration",
                "5",
                "--start-at",
                &t,
            ]),
            Stream::Cam,
            never,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(sim.start_at, Some(t.parse().unwrap()));
        assert!(sim.source.describe().contains("seed 2"));
        // without --seed the simulator's seed is 1, as before
        let sim = select_source(
            &args(&["--sim", "robot", "--duration", "5"]),
            Stream::Cam,
            never,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert!(sim.source.describe().contains("seed 1"));
    }

    /// An empty device or command is refused by the parser, naming its flag (an
    /// options error: exit 78); a negative --stride is its flag's invalid value.
    #[test]
    fn empty_devices_and_commands_and_negative_strides_are_refused_naming_the_flag() {
        for (stream, a, flag) in [
            (Stream::Lidar, &["--ld06", ""][..], "--ld06 <DEVICE>"),
            (
                Stream::Lidar,
                &["--ld06", "", "--wait-device"][..],
                "--ld06 <DEVICE>",
            ),
            (Stream::Lidar, &["--rplidar", " "][..], "--rplidar <DEVICE>"),
            (Stream::Cam, &["--pipe-cmd", ""][..], "--pipe-cmd <COMMAND>"),
            (
                Stream::Cam,
                &["--v4l2", "", "--wait-device"][..],
                "--v4l2 <DEVICE>",
            ),
            (
                Stream::Cam,
                &["--pipe", "", "--size", "8x8"][..],
                "--pipe <PATH>",
            ),
            (
                Stream::Cam,
                &["--pipe", "-", "--size", "8x8", "--stride", "-1"][..],
                "'-1' for '--stride <BYTES>'",
            ),
        ] {
            let e = command(stream)
                .try_get_matches_from(std::iter::once("x").chain(a.iter().copied()))
                .map(|_| ())
                .expect_err("accepted");
            // `main` exits 78 on every error that goes to stderr
            assert!(e.use_stderr(), "{a:?}");
            let text = e.render().to_string();
            assert!(text.contains(flag), "{a:?}: {text}");
            assert!(!text.contains("unexpected argument"), "{a:?}: {text}");
        }
    }

    #[test]
    fn a_stop_while_waiting_for_the_device_publishes_nothing() {
        let sel = match select_source(
            &args(&["--ld06", "/nonexistent/vlsync-tty", "--wait-device"]),
            Stream::Lidar,
            yes,
        ) {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        let why = stopped_before_publishing(sel.stopped, never);
        assert_eq!(
            why.as_deref(),
            Some("stopped while waiting for /nonexistent/vlsync-tty")
        );
        // a stop while a source opened or read ahead: nothing published either
        assert_eq!(
            stopped_before_publishing(None, yes).as_deref(),
            Some("stopped before publishing")
        );
        assert_eq!(stopped_before_publishing(None, never), None);
    }

    #[test]
    fn render_rates_apply_to_render_only_and_within_their_ranges() {
        assert_eq!(
            options_error(&["--csv", "/nonexistent.csv", "--render-fps", "15"]),
            "--render-fps applies to --render only (other sources keep their own rates)"
        );
        assert_eq!(
            options_error(&["--sim", "robot", "--render-lidar-hz", "5"]),
            "--render-lidar-hz applies to --render only (other sources keep their own rates)"
        );
        // a speed that would pace the second sample centuries out, or none at all
        for (bad, shown) in [("1e-300", "1e-300"), ("0.001", "0.001"), ("2e3", "2000")] {
            assert_eq!(
                options_error(&["--csv", "/nonexistent.csv", "--speed", bad]),
                format!("--speed {shown} is out of range: allowed 0.01 ..= 1000")
            );
        }
        for bad in ["0.5", "2.6", "125", "1e9", "-30", "NaN", "inf"] {
            let e = options_error(&["--render", "1", "--render-fps", bad]);
            assert_eq!(
                e,
                format!(
                    "--render-fps {} is out of range: allowed 2.67 <= HZ < 125 (samples at \
                     most half `estimator.max_gap_s` = 0.75 apart (its default: no --config), \
                     so that a dropped one does not break the stream; the rendered camera \
                     exposes each frame for 8 ms)",
                    vlsync_common::text::number(bad.parse::<f64>().unwrap())
                )
            );
        }
        for bad in ["0.4", "1", "101", "NaN"] {
            let e = options_error(&["--render", "1", "--render-lidar-hz", bad]);
            assert!(
                e.starts_with(&format!(
                    "--render-lidar-hz {} is out of range: allowed 2.67 ..= 100",
                    bad.parse::<f64>().unwrap()
                )),
                "{e}"
            );
        }
        // a configuration with a longer gap limit lets a slower LiDAR through
        let dir = std::env::temp_dir().join(format!("vlsync-cli-rates-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = dir.join("gap.toml");
        std::fs::write(&cfg, "[estimator]\nmax_gap_s = 2.0\n").unwrap();
        let c = cfg.to_str().unwrap();
        let a = args(&["--render", "1", "--render-lidar-hz", "1", "--config", c]);
        assert_eq!(render_rates(&a, "--render").unwrap().lidar_hz, Some(1.0));
        let e = options_error(&["--render", "1", "--render-lidar-hz", "0.9", "--config", c]);
        assert!(e.contains("= 2 apart (as --config sets it)"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_rendered_lidar_at_half_the_rate_gives_half_the_samples() {
        let count = |extra: &[&str]| {
            let a = [&["--render", "2", "--duration", "6", "--fast"][..], extra].concat();
            let mut sel = match select_source(&args(&a), Stream::Lidar, never) {
                Ok(s) => s,
                Err(e) => panic!("{e}"),
            };
            let mut n = 0;
            while sel.source.next_sample().unwrap().is_some() {
                n += 1;
            }
            n as f64
        };
        let (n10, n5) = (count(&[]), count(&["--render-lidar-hz", "5"]));
        assert!(n5 >= 20.0 && (n10 / n5 - 2.0).abs() < 0.2, "{n10} {n5}");
    }

    #[test]
    fn recorded_and_rendered_sources_end_at_a_stop() {
        for stream in [Stream::Cam, Stream::Lidar] {
            let mut sel =
                match select_source(&args(&["--render", "1", "--duration", "2"]), stream, yes) {
                    Ok(s) => s,
                    Err(e) => panic!("{e}"),
                };
            assert_eq!(sel.source.next_sample().unwrap(), None, "{stream}");
            let report = sel.source.report().unwrap();
            assert!(report.starts_with("0 "), "{stream}: {report}");
        }
    }

    #[test]
    fn a_start_instant_picked_for_mono_stamps_is_said() {
        let before = vlsync_ipc::monotonic_ns();
        let sel = match select_source(
            &args(&["--render", "1", "--duration", "2", "--stamp", "mono"]),
            Stream::Lidar,
            never,
        ) {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        let t = sel.start_at.expect("a start instant");
        assert!(t >= before + DEFAULT_START_DELAY_NS, "{t} {before}");
        let line = publishing_line(Stream::Lidar, "render", "p/lidar/signature", Some(t));
        assert_eq!(
            line,
            format!(
                "vlsync-lidar: publishing render on p/lidar/signature; start instant picked: \
                 --start-at {t} (CLOCK_MONOTONIC ns): give the other driver of the pair the same\n"
            )
        );
        assert_eq!(
            publishing_line(Stream::Cam, "x", "p/cam/signature", None),
            "vlsync-cam: publishing x on p/cam/signature\n"
        );
    }

    #[test]
    fn a_progress_line_says_the_real_time_since_the_previous_one() {
        let last = RunSummary {
            published: 10,
            ..RunSummary::default()
        };
        let now = RunSummary {
            published: 12,
            ..RunSummary::default()
        };
        assert_eq!(
            progress_line(Stream::Cam, &now, &last, PROGRESS_EVERY, Some("r".into())),
            "vlsync-cam: last 10 min: 2 published, 0 failed (12 published in all); r\n"
        );
        let hours = Duration::from_secs(3 * 3600 + 1800);
        assert!(progress_line(Stream::Lidar, &now, &now, hours, None)
            .starts_with("vlsync-lidar: last 3.5 h: 0 published,"));
        assert_eq!(span_text(Duration::from_secs(90)), "90 s");
        assert_eq!(span_text(Duration::from_secs(3 * 86_400)), "3.0 days");
    }
}
