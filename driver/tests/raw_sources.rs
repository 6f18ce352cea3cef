//! The raw-sensor sources on small generated data: a rendered run as a frame
//! directory, a scan CSV and an MCAP recording (each must give what the
//! rendered source gives), LD06 and RPLIDAR byte streams through a
//! pseudo-terminal, and the errors of the device and option checks.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use vlsync_common::{Sample, Stream};
use vlsync_driver::cli::{select_source, DriverArgs, StampArg};
use vlsync_driver::raw::{self, CamSource, LidarSource, SerialKind};
use vlsync_driver::Source;

const SEED: u64 = 7;
const DURATION_S: f64 = 3.0;

fn drain(s: &mut dyn Source) -> Vec<Sample> {
    let mut v = Vec::new();
    while let Some(x) = s.next_sample().expect("sample") {
        v.push(x);
    }
    v
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vlsync-driver-raw-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

fn never() -> bool {
    false
}

fn assert_close(a: &[Sample], b: &[Sample], dt_ns: i64, dv: f64, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: sample counts");
    for (x, y) in a.iter().zip(b) {
        assert!((x.t_ns - y.t_ns).abs() <= dt_ns, "{what}: {x:?} vs {y:?}");
        assert!(
            (x.value - y.value).abs() <= dv * (1.0 + y.value.abs()),
            "{what}: {x:?} vs {y:?}"
        );
    }
}

#[test]
fn rendered_run_on_disk_and_in_mcap_matches_the_rendered_source() {
    let dir = temp_dir("render");
    let mut r = raw::renderer(SEED, DURATION_S).unwrap();
    vlsync_render::output::write_run(&mut r, &dir, true).expect("write run");

    let mut cam_r = CamSource::render(raw::renderer(SEED, DURATION_S).unwrap()).unwrap();
    let cam_ref = drain(&mut cam_r);
    assert!(cam_ref.len() > 50, "{}", cam_ref.len());
    assert!(cam_ref.windows(2).all(|w| w[0].t_ns < w[1].t_ns));
    let report = cam_r.report().unwrap();
    assert!(report.contains("low texture"), "{report}");
    let c = cam_r.counts();
    assert_eq!(
        c.samples
            + c.low_texture
            + c.no_flow
            + c.gaps
            + c.not_increasing
            + c.size_changed
            + c.refused
            + 1,
        c.frames,
        "{c:?}"
    );

    let mut lidar_r = LidarSource::render(raw::renderer(SEED, DURATION_S).unwrap()).unwrap();
    let lidar_ref = drain(&mut lidar_r);
    assert!(lidar_r.scans() >= 28, "{}", lidar_r.scans());
    assert!(lidar_ref.len() >= 20, "{}", lidar_ref.len());
    assert!(lidar_r.report().unwrap().contains("too_few_valid"));

    // frame directory (lossless PNG): the very same samples
    let mut frames = CamSource::frames_dir(&dir).unwrap();
    assert!(frames.describe().contains(&dir.display().to_string()));
    assert_eq!(drain(&mut frames), cam_ref);

    // scan CSV: decimal times and ranges, so equal within rounding
    let mut scans = LidarSource::scans_csv(&dir.join("scans.csv")).unwrap();
    assert_close(&drain(&mut scans), &lidar_ref, 2, 1e-3, "scans.csv");

    // an MCAP recording of the same run
    let mcap = dir.join("run.mcap");
    let mut w = vlsync_mcap::McapWriter::create(&mcap).unwrap();
    // camera stamps start before 0 (the clock offset): log them a second later
    w.set_log_delay_ns(1_000_000_000);
    let mut r = raw::renderer(SEED, DURATION_S).unwrap();
    for ev in r.events() {
        match ev.unwrap() {
            vlsync_render::Event::Frame(f) => w
                .write_image("/camera/image_raw", f.stamp_ns, &f.image)
                .unwrap(),
            vlsync_render::Event::Scan(s) => w.write_scan("/scan", &s.scan).unwrap(),
        }
    }
    w.finish().unwrap();
    // mid-exposure stamps as instants: the same frame times as the rendered exposure
    let mut m = CamSource::mcap(&mcap, Some("/camera/image_raw")).unwrap();
    assert_eq!(drain(&mut m), cam_ref);
    // the only image topic is found without naming it
    let mut m = CamSource::mcap(&mcap, None).unwrap();
    assert!(m.describe().contains("/camera/image_raw"));
    assert_eq!(drain(&mut m).len(), cam_ref.len());
    let mut m = LidarSource::mcap(&mcap, Some("/scan")).unwrap();
    assert_close(&drain(&mut m), &lidar_ref, 1_000, 1e-3, "mcap scans");

    // errors name the file or topic
    let e = CamSource::mcap(&mcap, Some("/nope"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nope") && e.contains("run.mcap"), "{e}");
    let e = CamSource::frames_dir(&dir.join("missing"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing"), "{e}");
    std::fs::write(dir.join("bad.csv"), "t_s,bearing_rad\n0.0,oops\n").unwrap();
    let e = match LidarSource::scans_csv(&dir.join("bad.csv")) {
        Err(e) => e.to_string(),
        Ok(mut s) => s.next_sample().unwrap_err().to_string(),
    };
    assert!(e.contains("bad.csv"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Writes `bytes` to the pty master at `bytes_per_s`, then keeps it open a while.
fn feed(
    mut master: serialport::TTYPort,
    bytes: Vec<u8>,
    bytes_per_s: f64,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let t0 = Instant::now();
        let mut sent = 0usize;
        while sent < bytes.len() {
            let due = ((t0.elapsed().as_secs_f64() * bytes_per_s) as usize).min(bytes.len());
            if due > sent {
                master
                    .write_all(&bytes[sent..due])
                    .expect("write to pty master");
                sent = due;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(300));
        drop(master);
    })
}

static LD06_STOP: AtomicBool = AtomicBool::new(false);

/// 2 s of LD06 output: a wall straight ahead approaching at 0.5 m/s.
fn approaching_wall_ld06() -> Vec<u8> {
    vlsync_signature_lidar::encode::ld06_stream(3600, 0, 2.0, |t, b| {
        if b.abs() < 0.3 {
            3.0 - 0.5 * t
        } else {
            6.0
        }
    })
}

#[test]
fn ld06_through_a_pty() {
    use serialport::SerialPort;
    // a wall straight ahead approaching at 0.5 m/s, 2 s of output at the real byte rate
    let bytes = approaching_wall_ld06();
    let rate = bytes.len() as f64 / 2.0;
    let (master, slave) = serialport::TTYPort::pair().expect("pty pair");
    let path = slave.name().expect("slave path");
    let mut src = LidarSource::serial(
        SerialKind::Ld06,
        &path,
        None,
        Duration::from_secs(2),
        || LD06_STOP.load(Ordering::Relaxed),
    )
    .unwrap();
    drop(slave);
    assert!(src.describe().contains(&path), "{}", src.describe());
    let writer = feed(master, bytes, rate);
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(10);
    while got.len() < 15 && Instant::now() < deadline {
        match src.next_sample() {
            Ok(Some(s)) => got.push(s),
            Ok(None) => break,
            Err(e) => panic!("{e}"),
        }
    }
    LD06_STOP.store(true, Ordering::Relaxed);
    // stopped: ends instead of waiting for more bytes
    assert_eq!(src.next_sample().unwrap(), None);
    writer.join().unwrap();
    assert!(got.len() >= 15, "{} samples; {:?}", got.len(), src.report());
    // host-stamped (monotonic clock), in order
    let now = vlsync_ipc::monotonic_ns();
    assert!(got.windows(2).all(|w| w[0].t_ns < w[1].t_ns));
    assert!(got
        .iter()
        .all(|s| s.t_ns <= now && s.t_ns > now - 20_000_000_000));
    let mut v: Vec<f64> = got.iter().map(|s| s.value).collect();
    v.sort_by(f64::total_cmp);
    let median = v[v.len() / 2];
    assert!((median + 0.5).abs() < 0.15, "median {median} m/s: {v:?}");
    let report = src.report().unwrap();
    assert!(report.contains("0 CRC errors"), "{report}");
}

static RP_STOP: AtomicBool = AtomicBool::new(false);

#[test]
fn rplidar_gets_the_scan_request_and_its_scans_through_a_pty() {
    use serialport::SerialPort;
    use vlsync_signature_lidar::rplidar_start::{
        answer, parse_request, ANS_ACC_BOARD_FLAG, ANS_HEALTH, ANS_SAMPLE_RATE,
    };
    let (mut master, slave) = serialport::TTYPort::pair().expect("pty pair");
    let path = slave.name().expect("slave path");
    master.set_timeout(Duration::from_millis(50)).unwrap();
    // an A2 on Slamtec's accessory board: answers health, its sample durations
    // (500 µs standard, 250 µs express) and the board flag (motor control), and
    // streams once asked to scan
    let device = std::thread::spawn(move || {
        let (mut inbox, mut log) = (Vec::new(), Vec::new());
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            let mut buf = [0u8; 64];
            if let Ok(n) = master.read(&mut buf) {
                inbox.extend_from_slice(&buf[..n]);
            }
            while let Some((cmd, payload, used)) = parse_request(&inbox) {
                let payload = payload.to_vec();
                inbox.drain(..used);
                match cmd {
                    0x52 => master.write_all(&answer(ANS_HEALTH, &[0, 0, 0])).unwrap(),
                    0x59 => master
                        .write_all(&answer(ANS_SAMPLE_RATE, &[0xF4, 0x01, 0xFA, 0x00]))
                        .unwrap(),
                    0xFF => master
                        .write_all(&answer(ANS_ACC_BOARD_FLAG, &1u32.to_le_bytes()))
                        .unwrap(),
                    _ => {}
                }
                log.push((cmd, payload));
                if cmd == 0x20 {
                    return (master, log);
                }
            }
            if inbox.first().is_some_and(|&b| b != 0xA5) {
                inbox.remove(0);
            }
            assert!(Instant::now() < deadline, "no scan request: {log:?}");
        }
    });
    let mut src = LidarSource::serial(
        SerialKind::Rplidar,
        &path,
        Some(115_200),
        Duration::from_secs(2),
        || RP_STOP.load(Ordering::Relaxed),
    )
    .unwrap();
    drop(slave);
    let (master, log) = device.join().unwrap();
    let commands: Vec<u8> = log.iter().map(|r| r.0).collect();
    // stop, health, sample rate, board flag, the motor's PWM (660), scan: as
    // Slamtec's SDK
    assert_eq!(commands, [0x25, 0x52, 0x59, 0xFF, 0xF0, 0x20], "{log:?}");
    assert_eq!(log[4].1, 660u16.to_le_bytes());
    // 5.5 Hz, 360 nodes per revolution, wall straight ahead receding at 1 m/s
    let period = 1.0 / 5.5;
    let mut bytes = vlsync_signature_lidar::rplidar::SCAN_DESCRIPTOR.to_vec();
    for k in 0..12 {
        bytes.extend(vlsync_signature_lidar::encode::rplidar_revolution(
            360,
            k as f64 * period,
            period,
            |t, b| if b.abs() < 0.3 { 2.0 + t } else { 5.0 },
        ));
    }
    let rate = 360.0 * 5.0 * 5.5;
    let writer = feed(master, bytes, rate);
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(10);
    while got.len() < 6 && Instant::now() < deadline {
        got.push(src.next_sample().unwrap().expect("a sample"));
    }
    RP_STOP.store(true, Ordering::Relaxed);
    assert_eq!(src.next_sample().unwrap(), None);
    writer.join().unwrap();
    assert!(got.len() >= 6);
    let mut v: Vec<f64> = got.iter().map(|s| s.value).collect();
    v.sort_by(f64::total_cmp);
    assert!((v[v.len() / 2] - 1.0).abs() < 0.3, "{v:?}");
    assert!(src.report().unwrap().contains("RPLIDAR"));
}

#[test]
fn the_rplidar_node_rate_follows_the_model_the_baud_rate_names() {
    // the C1's 460800 baud carries 5000 nodes/s: at the A1's 2000 a revolution start
    // followed by 500 bytes in one read would be dated 30 ms too early
    assert_eq!(vlsync_driver::raw::rplidar_node_rate_hz(460_800), 5000);
    assert_eq!(vlsync_driver::raw::rplidar_node_rate_hz(115_200), 2000);
}

/// Scans the parser gives for `turns` revolutions at `hz` (360 nodes each, one
/// chunk per revolution, received as it ends) with the settings the driver runs
/// at `baud`.
fn rplidar_scans(baud: u32, hz: f64, turns: usize) -> usize {
    use vlsync_signature_lidar::rplidar::RplidarParser;
    let mut p = RplidarParser::new(vlsync_driver::raw::rplidar_config(baud, None));
    let period = 1.0 / hz;
    let mut scans = 0;
    p.push(&vlsync_signature_lidar::rplidar::SCAN_DESCRIPTOR, 0, |_| {
        scans += 1
    });
    for k in 0..turns {
        let rev = vlsync_signature_lidar::encode::rplidar_revolution(
            360,
            k as f64 * period,
            period,
            |_, _| 3.0,
        );
        let rx = ((k + 1) as f64 * period * 1e9).round() as i64;
        p.push(&rev, rx, |_| scans += 1);
    }
    scans
}

#[test]
fn an_rplidar_c1_keeps_its_first_revolution() {
    // the C1 (460800 baud) turns at 10 Hz: checked against the A1's 5.5 Hz its first
    // revolution (100 ms, under 2/3 of 181.8 ms) was dropped
    assert_eq!(
        vlsync_driver::raw::rplidar_nominal_period_ns(460_800),
        100_000_000
    );
    let c1 = rplidar_scans(460_800, 10.0, 6);
    // an A1 at its 5.5 Hz keeps its first revolution too; an A2M8 at 10 Hz on the
    // same 115200 baud loses it (the rate is unknown before two turns)
    let a1 = rplidar_scans(115_200, 5.5, 6);
    let a2 = rplidar_scans(115_200, 10.0, 6);
    assert_eq!(
        (c1, a1),
        (a2 + 1, a2 + 1),
        "C1 {c1}, A1 {a1}, A2M8 {a2} scans"
    );
    assert!(a2 >= 3, "{a2} scans of 6 revolutions");
}

static QUIET_STOP: AtomicBool = AtomicBool::new(false);

/// A LiDAR that falls silent while its port stays (powered down on a parked robot):
/// the driver reopens the port and waits instead of ending (its unit restarted it
/// every 12 s for as long as that lasted), and goes on when scans come again; a
/// port that is gone is an error naming it.
#[test]
fn a_silent_serial_device_is_waited_for_with_its_port_reopened() {
    use serialport::SerialPort;
    let (master, slave) = serialport::TTYPort::pair().expect("pty pair");
    let path = slave.name().expect("slave path");
    let mut src = LidarSource::serial(
        SerialKind::Ld06,
        &path,
        None,
        Duration::from_millis(200),
        || QUIET_STOP.load(Ordering::Relaxed),
    )
    .unwrap();
    drop(slave);
    // 1 s of silence, then 2 s of scans
    let bytes = approaching_wall_ld06();
    let rate = bytes.len() as f64 / 2.0;
    let writer = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_secs(1));
        feed(master, bytes, rate).join().unwrap();
    });
    let mut got = 0;
    let deadline = Instant::now() + Duration::from_secs(10);
    while got < 15 && Instant::now() < deadline {
        match src.next_sample() {
            Ok(Some(_)) => got += 1,
            other => panic!("{other:?}; {:?}", src.report()),
        }
    }
    let report = src.report().unwrap();
    QUIET_STOP.store(true, Ordering::Relaxed);
    assert_eq!(src.next_sample().unwrap(), None);
    writer.join().unwrap();
    assert_eq!(got, 15, "{report}");
    assert!(
        report.contains("the port reopened") && report.contains("after silences of 0.2 s"),
        "{report}"
    );
    // the port gone: an error naming it
    let e = LidarSource::serial(
        SerialKind::Ld06,
        "/dev/does-not-exist-vlsync",
        None,
        Duration::from_secs(1),
        never,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("/dev/does-not-exist-vlsync") && e.contains("--ld06"),
        "{e}"
    );
}

#[test]
fn v4l2_errors_name_the_device_or_the_missing_feature() {
    let r = CamSource::v4l2(Path::new("/dev/video0"), never);
    if cfg!(feature = "v4l2") {
        // with the feature: a missing or non-video device is still an error naming it
        let e = CamSource::v4l2(Path::new("/dev/video-vlsync-missing"), never)
            .expect_err("a missing device is an error");
        assert!(e.to_string().contains("/dev/video-vlsync-missing"), "{e}");
    } else {
        let e = r.unwrap_err().to_string();
        assert!(
            e.contains("built without V4L2 support; rebuild with --features vlsync-driver/v4l2")
                && e.contains("/dev/video0"),
            "{e}"
        );
    }
}

fn args(a: &[&str]) -> DriverArgs {
    use clap::Parser;
    DriverArgs::try_parse_from(std::iter::once("vlsync-test").chain(a.iter().copied()))
        .expect("args")
}

#[test]
fn option_errors_name_the_flags() {
    let err = |a: &[&str], s: Stream| match select_source(&args(a), s, never) {
        Ok(_) => panic!("{a:?} accepted"),
        Err(e) => e.to_string(),
    };
    let e = err(&[], Stream::Cam);
    assert!(e.contains("--frames DIR") && e.contains("--v4l2"), "{e}");
    let e = err(&[], Stream::Lidar);
    assert!(e.contains("--ld06") && e.contains("--scans"), "{e}");
    let e = err(&["--frames", "/tmp", "--render", "1"], Stream::Cam);
    assert!(e.contains("--render and --frames"), "{e}");
    let e = err(&["--ld06", "/dev/ttyUSB0"], Stream::Cam);
    assert!(e.contains("--ld06 is not a source of vlsync-cam"), "{e}");
    let e = err(&["--frames", "/tmp"], Stream::Lidar);
    assert!(
        e.contains("--frames is not a source of vlsync-lidar"),
        "{e}"
    );
    let e = err(&["--render", "1", "--baud", "9600"], Stream::Lidar);
    assert!(e.contains("--baud"), "{e}");
    // the transfer-time correction of host stamps needs a plausible rate
    let e = err(&["--ld06", "/dev/ttyUSB0", "--baud", "1"], Stream::Lidar);
    assert!(e.contains("--baud 1 is outside 1200..=4000000"), "{e}");
    // a live device is published as its data arrives
    for (extra, flag) in [
        (&["--fast"][..], "--fast"),
        (&["--speed", "2"][..], "--speed 2"),
    ] {
        let mut a = vec!["--ld06", "/dev/ttyUSB0"];
        a.extend_from_slice(extra);
        let e = err(&a, Stream::Lidar);
        assert!(
            e.contains(&format!(
                "{flag} applies to recorded and simulated sources; --ld06 is a live device"
            )),
            "{e}"
        );
    }
    // `--speed 1` is real time, what a live device does: past the options to the device
    for (a, stream) in [
        (
            &["--ld06", "/nonexistent/tty", "--speed", "1"][..],
            Stream::Lidar,
        ),
        (
            &["--rplidar", "/nonexistent/tty", "--speed", "1.0"][..],
            Stream::Lidar,
        ),
        (
            &["--v4l2", "/nonexistent/tty", "--speed", "1"][..],
            Stream::Cam,
        ),
    ] {
        let e = err(a, stream);
        assert!(!e.contains("applies to"), "{a:?}: {e}");
        assert!(e.contains("/nonexistent/tty"), "{a:?}: {e}");
    }
    let e = err(&["--render", "1", "--duration", "0.1"], Stream::Lidar);
    assert!(e.contains("duration"), "{e}");
    // the rendered pair shares one anchor
    let c = select_source(
        &args(&["--render", "3", "--duration", "2"]),
        Stream::Cam,
        never,
    )
    .unwrap();
    let l = select_source(
        &args(&["--render", "3", "--duration", "2"]),
        Stream::Lidar,
        never,
    )
    .unwrap();
    assert_eq!(c.anchor_ns, l.anchor_ns);
    assert!(c.anchor_ns.is_some());
}

#[test]
fn stamping_options_are_checked() {
    let err = |a: &[&str], s: Stream| match select_source(&args(a), s, never) {
        Ok(_) => panic!("{a:?} accepted"),
        Err(e) => e.to_string(),
    };
    let e = err(&["--render", "1", "--stamp", "software"], Stream::Lidar);
    assert!(e.contains("--stamp software is a camera mode"), "{e}");
    let e = err(
        &["--render", "1", "--stamp", "mono", "--fast"],
        Stream::Lidar,
    );
    assert!(e.contains("--stamp mono") && e.contains("real time"), "{e}");
    let e = err(
        &["--render", "1", "--stamp", "software", "--speed", "2"],
        Stream::Cam,
    );
    assert!(
        e.contains("--stamp software") && e.contains("real time"),
        "{e}"
    );
    let e = err(&["--frames", "/tmp", "--stamp", "mono"], Stream::Cam);
    assert!(e.contains("--stamp mono applies to --render only"), "{e}");
    let e = err(&["--render", "1", "--frame-cpu-ms", "5"], Stream::Cam);
    assert!(
        e.contains("--frame-cpu-ms applies to vlsync-cam --stamp software"),
        "{e}"
    );
    let e = err(
        &["--render", "1", "--stamp", "mono", "--frame-cpu-ms", "5"],
        Stream::Lidar,
    );
    assert_eq!(
        e,
        "options: --frame-cpu-ms is an option of vlsync-cam, not of vlsync-lidar"
    );
    let e = err(
        &[
            "--render",
            "1",
            "--stamp",
            "software",
            "--frame-cpu-ms",
            "5000",
        ],
        Stream::Cam,
    );
    assert!(e.contains("--frame-cpu-ms 5000 is out of range"), "{e}");
    // a start instant far outside CLOCK_MONOTONIC's range would overflow the stamps
    for (t, s) in [
        ("--start-at=-9223372036854775808", StampArg::Mono),
        ("--start-at=9223372036854775807", StampArg::Mono),
        ("--start-at=-1", StampArg::Sensor),
    ] {
        let stamp = if s == StampArg::Mono {
            "mono"
        } else {
            "sensor"
        };
        let e = err(&["--render", "1", "--stamp", stamp, t], Stream::Lidar);
        assert!(
            e.contains("--start-at") && e.contains("out of range"),
            "{t}: {e}"
        );
    }
    let e = err(
        &["--frames", "/tmp", "--truth-out", "/tmp/x.csv"],
        Stream::Cam,
    );
    assert!(e.contains("--truth-out needs --render"), "{e}");
    // mono stamps are the sensor stamps moved by start_at - anchor; the pacing
    // anchor moves with them, so both drivers still publish in step
    let sensor = select_source(
        &args(&["--render", "3", "--duration", "2"]),
        Stream::Lidar,
        never,
    )
    .unwrap();
    let start_at = 5_000_000_000_000;
    let mut mono = select_source(
        &args(&[
            "--render",
            "3",
            "--duration",
            "2",
            "--stamp",
            "mono",
            "--start-at",
            &start_at.to_string(),
        ]),
        Stream::Lidar,
        never,
    )
    .unwrap();
    let anchor = sensor.anchor_ns.unwrap();
    assert_eq!(mono.anchor_ns, Some(start_at));
    let mut plain = sensor.source;
    let (a, b) = (
        plain.next_sample().unwrap().unwrap(),
        mono.source.next_sample().unwrap().unwrap(),
    );
    assert_eq!(b.t_ns - a.t_ns, start_at - anchor);
    assert_eq!(a.value, b.value);
    // its truth: the stamp with the scans' jitter (0.3 ms 1σ) removed
    let t = mono.source.truth().unwrap();
    assert!((b.t_ns - t.event_ns).abs() < 2_000_000, "{t:?} vs {b:?}");
    assert!(plain.truth().is_some());
}

/// When each frame of `r`'s schedule becomes available (its exposure ends) on
/// `CLOCK_MONOTONIC` when the run is shifted by `shift`: what the live render source
/// waits for, and skips when it is past at the start.
fn frame_ends(r: &vlsync_render::Renderer, shift: i64) -> Vec<i64> {
    let exp_ns = vlsync_common::secs_to_nanos(r.config().camera.exposure_s);
    r.frame_schedule()
        .iter()
        .map(|f| f.tau_mid_ns + exp_ns / 2 + shift)
        .collect()
}

/// How many of `ends` lie before `t`.
fn ended_before(ends: &[i64], t: i64) -> u64 {
    ends.iter().filter(|&&e| e < t).count() as u64
}

#[test]
fn software_stamping_runs_in_real_time_and_knows_its_truth() {
    let duration = 2.0;
    let r = raw::renderer(SEED, duration).unwrap();
    let anchor = raw::render_anchor_ns(&r);
    let exposure_ns = (r.config().camera.exposure_s * 1e9) as i64;
    let start_at = vlsync_ipc::monotonic_ns() + 300_000_000;
    let shift = start_at - anchor;
    let ends = frame_ends(&r, shift);
    let mut cam =
        CamSource::render_with(r, raw::RenderStamp::Software { shift_ns: shift }, never).unwrap();
    // the source started before this instant
    let started = vlsync_ipc::monotonic_ns();
    assert!(cam.describe().contains("after processing"));
    let mut n = 0;
    let mut last = i64::MIN;
    while let Some(s) = cam.next_sample().unwrap() {
        let t = cam.truth().expect("rendered samples carry their truth");
        let now = vlsync_ipc::monotonic_ns();
        // stamped on CLOCK_MONOTONIC after the frame: at least half an exposure
        // after the true mid-exposure (delivered in real time, never ahead of the
        // exposure's end), never in the future
        assert!(s.t_ns - t.event_ns >= exposure_ns / 2, "{s:?} {t:?}");
        assert!(s.t_ns <= now && s.t_ns > last, "{s:?}");
        assert!(t.process_ns > 0 && t.late_ns >= 0, "{t:?}");
        last = s.t_ns;
        n += 1;
    }
    // delivered in real time: the run ends no earlier than the last frame's exposure
    // (how much later is a loaded machine's business; the per-sample checks above
    // bound each stamp from below the same way)
    let ended = vlsync_ipc::monotonic_ns();
    assert!(
        ended >= ends[ends.len() - 1],
        "the run ended at {ended}, before the last exposure's end {}",
        ends[ends.len() - 1]
    );
    assert!(n > 40, "{n}");
    let live = cam.live_counts().unwrap();
    // every frame of the run accounted for: delivered, or skipped because its
    // exposure had ended when the source started (only when a loaded machine made
    // the start outlast the 0.3 s lead: then at most the frames past by `started`)
    assert_eq!(
        live.delivered + live.skipped,
        ends.len() as u64,
        "{live:?} for {} frames",
        ends.len()
    );
    if started < start_at {
        assert_eq!(live.skipped, 0, "{live:?}: no frame was past at the start");
    } else {
        assert!(
            live.skipped <= ended_before(&ends, started),
            "{live:?}: more skipped than the {} frames past by the start",
            ended_before(&ends, started)
        );
        eprintln!(
            "note: the source started {:.3} s after its start instant (a loaded machine): {} frames skipped",
            (started - start_at) as f64 * 1e-9,
            live.skipped
        );
    }
    assert!(live.delivered as usize > n);
    let report = cam.report().unwrap();
    assert!(
        report.contains("real time:") && report.contains("render thread"),
        "{report}"
    );
    // a driver (re)started after its start instant skips the frames already past:
    // those that ended before it started, and none still to come when it delivered
    // its first sample
    let r = raw::renderer(SEED, duration).unwrap();
    let before = vlsync_ipc::monotonic_ns();
    let shift = before - 1_000_000_000 - raw::render_anchor_ns(&r);
    let ends = frame_ends(&r, shift);
    let mut late =
        CamSource::render_with(r, raw::RenderStamp::Software { shift_ns: shift }, never).unwrap();
    assert!(late.next_sample().unwrap().is_some());
    let after = vlsync_ipc::monotonic_ns();
    let skipped = late.live_counts().unwrap().skipped;
    let (past, by_first) = (ended_before(&ends, before), ended_before(&ends, after));
    assert!(
        past >= 25 && (past..=by_first).contains(&skipped),
        "{skipped} skipped; {past} frames were past at the start, {by_first} at the first sample: {:?}",
        late.live_counts()
    );
}

#[test]
fn the_opposite_window_doubles_the_lidar_stream_in_time_order() {
    // a run long enough for the robot to drive between the two end walls
    let secs = 12.0;
    let mut front = LidarSource::render(raw::renderer(SEED, secs).unwrap()).unwrap();
    let front = drain(&mut front);
    let both = vlsync_config::LidarConfig {
        opposite_window: true,
        ..vlsync_config::LidarConfig::default()
    };
    let mut src = LidarSource::render(raw::renderer(SEED, secs).unwrap())
        .unwrap()
        .with_front(&both)
        .unwrap();
    assert!(
        src.describe().contains("and the opposite one"),
        "{}",
        src.describe()
    );
    let merged = drain(&mut src);
    assert!(merged.windows(2).all(|w| w[0].t_ns < w[1].t_ns));
    // the front window's samples are all there, and the wall behind adds as many again
    assert!(front.iter().all(|f| merged.contains(f)));
    let behind: Vec<&Sample> = merged.iter().filter(|m| !front.contains(m)).collect();
    assert!(
        behind.len() * 10 >= front.len() * 7,
        "{} behind, {} ahead",
        behind.len(),
        front.len()
    );
    // negated, the receding wall's rate moves with the approaching wall's: at each
    // sample behind, the front stream interpolated there agrees in sign when moving
    let at = |t: i64| {
        let i = front
            .partition_point(|f| f.t_ns < t)
            .clamp(1, front.len() - 1);
        let (a, b) = (front[i - 1], front[i]);
        a.value + (b.value - a.value) * (t - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64
    };
    let moving: Vec<(f64, f64)> = behind
        .iter()
        .map(|m| (m.value, at(m.t_ns)))
        .filter(|(_, f)| f.abs() > 0.1)
        .collect();
    assert!(moving.len() >= 10, "{}", moving.len());
    let agree = moving.iter().filter(|(b, f)| b * f > 0.0).count();
    assert!(
        agree * 10 >= moving.len() * 9,
        "{agree} of {}",
        moving.len()
    );
    assert!(src.report().unwrap().contains("opposite window:"));
}

#[test]
fn lidar_window_options_are_checked() {
    let err = |a: &[&str], s: Stream| match select_source(&args(a), s, never) {
        Ok(_) => panic!("{a:?} accepted"),
        Err(e) => e.to_string(),
    };
    let dir = temp_dir("window-opts");
    let cfg = dir.join("bad.toml");
    std::fs::write(&cfg, "[lidar]\nwindow_half_width_deg = 0.0\n").unwrap();
    let e = err(
        &["--render", "1", "--config", cfg.to_str().unwrap()],
        Stream::Lidar,
    );
    assert!(
        e.contains("lidar.window_half_width_deg") && e.contains("bad.toml"),
        "{e}"
    );
    let e = err(&["--render", "1", "--opposite-window"], Stream::Cam);
    assert_eq!(
        e,
        "options: --opposite-window is an option of vlsync-lidar, not of vlsync-cam"
    );
    let e = err(&["--sim", "robot", "--opposite-window"], Stream::Lidar);
    assert!(
        e.contains("--opposite-window applies to vlsync-lidar"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// One bad image (undecodable, missing) or malformed scan of a recording is a
/// dropped frame or a missed revolution, counted in the report; 30 in a row end
/// the driver with the reason.
#[test]
fn an_unusable_image_or_scan_in_a_recording_is_skipped_and_counted() {
    use vlsync_mcap::cdr::CdrMessage;
    let dir = temp_dir("unusable");
    let mut r = raw::renderer(SEED, DURATION_S).unwrap();
    vlsync_render::output::write_run(&mut r, &dir, true).expect("write run");
    let cam_ref = drain(&mut CamSource::frames_dir(&dir).unwrap());
    let end = |src: &mut dyn Source| loop {
        match src.next_sample() {
            Ok(Some(_)) => {}
            Ok(None) => panic!("the bad input did not end the stream"),
            Err(e) => break e.to_string(),
        }
    };
    let frame = |k: usize| dir.join("frames").join(format!("frame_{k:06}.png"));

    // one frame that is not an image, one deleted after the directory was opened
    std::fs::write(frame(20), b"not a png").unwrap();
    let mut src = CamSource::frames_dir(&dir).unwrap();
    std::fs::remove_file(frame(40)).unwrap();
    let out = drain(&mut src);
    // each bad frame is a dropped frame: its two samples become one across it, the
    // rest keep their times and (the flow's prediction aside) their values
    assert_eq!(out.len() + 2, cam_ref.len());
    let mut across = 0;
    for s in &out {
        match cam_ref.iter().find(|r| r.t_ns == s.t_ns) {
            Some(r) => assert!(
                (s.value - r.value).abs() <= 1e-3 + 2e-3 * r.value.abs(),
                "{s:?} vs {r:?}"
            ),
            None => across += 1,
        }
    }
    assert_eq!(across, 2);
    let report = src.report().unwrap();
    assert!(
        report.contains("; 2 unusable frames skipped (last: ")
            && report.contains("frame_000040.png: frame file not found"),
        "{report}"
    );

    // 30 bad images in a row end the stream with the reason
    let n = std::fs::read_dir(dir.join("frames")).unwrap().count();
    assert!(n > 60, "{n} frames");
    std::fs::write(frame(40), b"").unwrap();
    for k in 41..71 {
        std::fs::write(frame(k), b"\x89PNG but cut").unwrap();
    }
    let e = end(&mut CamSource::frames_dir(&dir).unwrap());
    assert!(
        e.contains("30 frames in a row unusable, the last: ") && e.contains("frame_000069.png"),
        "{e}"
    );

    // a recording with `bad` unusable images after its 10th frame and as many
    // malformed LaserScans after its 10th scan
    let mcap = |bad: u64| {
        let path = dir.join(format!("run-{bad}.mcap"));
        let mut w = vlsync_mcap::McapWriter::create(&path).unwrap();
        let delay = 1_000_000_000;
        w.set_log_delay_ns(delay);
        let mut malformed = Vec::new();
        vlsync_mcap::cdr::LaserScan {
            ranges: vlsync_mcap::cdr::F32Seq::from_slice(&[1.0; 4]),
            ..vlsync_mcap::cdr::LaserScan::default()
        }
        .encode(&mut malformed)
        .unwrap();
        malformed.truncate(malformed.len() - 6);
        let bayer = vlsync_mcap::cdr::Image {
            encoding: "bayer_rggb8",
            width: 2,
            height: 2,
            step: 2,
            data: &[0; 4],
            ..vlsync_mcap::cdr::Image::default()
        };
        let (mut frames, mut scans) = (0, 0);
        let mut r = raw::renderer(SEED, DURATION_S).unwrap();
        for ev in r.events() {
            // each bad message is logged just after the 10th good one of its topic
            match ev.unwrap() {
                vlsync_render::Event::Frame(f) => {
                    w.write_image("/camera/image_raw", f.stamp_ns, &f.image)
                        .unwrap();
                    if frames == 10 {
                        let log = u64::try_from(f.stamp_ns + delay).unwrap();
                        for j in 1..=bad {
                            w.write_message("/camera/image_raw", log + j, &bayer)
                                .unwrap();
                        }
                    }
                    frames += 1;
                }
                vlsync_render::Event::Scan(s) => {
                    w.write_scan("/scan", &s.scan).unwrap();
                    if scans == 10 {
                        let log = u64::try_from(s.scan.rays()[0].t_ns + delay).unwrap();
                        for j in 1..=bad {
                            w.write_serialized::<vlsync_mcap::cdr::LaserScan>(
                                "/scan",
                                log + j,
                                &malformed,
                            )
                            .unwrap();
                        }
                    }
                    scans += 1;
                }
            }
        }
        w.finish().unwrap();
        path
    };
    let lidar_ref = drain(&mut LidarSource::mcap(&mcap(0), None).unwrap());
    let one = mcap(1);
    // the bad messages came between good ones: nothing of theirs is lost
    let mut src = CamSource::mcap(&one, None).unwrap();
    assert_eq!(drain(&mut src), cam_ref);
    let report = src.report().unwrap();
    assert!(
        report.contains("; 1 unusable frames skipped (last: ")
            && report.contains("unsupported image encoding `bayer_rggb8`"),
        "{report}"
    );
    let mut src = LidarSource::mcap(&one, None).unwrap();
    assert_eq!(drain(&mut src), lidar_ref);
    let report = src.report().unwrap();
    assert!(
        report.contains("; 1 unusable scans skipped (last: ")
            && report.contains("CDR field `ranges`"),
        "{report}"
    );
    let thirty = mcap(30);
    let e = end(&mut CamSource::mcap(&thirty, None).unwrap());
    assert!(
        e.contains("30 frames in a row unusable, the last: ") && e.contains("bayer_rggb8"),
        "{e}"
    );
    let e = end(&mut LidarSource::mcap(&thirty, None).unwrap());
    assert!(e.contains("30 scans in a row unusable, the last: "), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
