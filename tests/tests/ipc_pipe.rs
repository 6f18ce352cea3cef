//! A camera program on a pipe, as a Raspberry Pi camera module reaches vlsync:
//! `vlsync-cam --pipe-cmd` runs `vlsync-render --raw-stdout` (standing in for
//! `rpicam-vid --codec yuv420 -o -`: raw I420 frames, each written when its exposure
//! ends), stamps each frame as it arrives and publishes the flow signature; the
//! LiDAR driver renders the same run's scans on `CLOCK_MONOTONIC` from the same start
//! instant, and the daemon locks onto their offset.
//!
//! The truth: arrival stamps trail the frames' mid-exposure by half the exposure
//! (plus the pipe's own delay, well under a millisecond), the LiDAR's mono stamps
//! trail its events by what its truth file says, so the offset `t_L - t_C` is
//! `(stamp - event)_LiDAR - exposure / 2`.

use std::time::Duration;
use vlsync_common::EstimatorState;
use vlsync_ipc::OffsetClient;
use vlsync_tests::{assert_nothing_left, bin, collect, ipc_resources, Managed, Rig};

#[test]
fn a_camera_program_on_a_pipe_locks_to_the_offset_of_its_arrival_stamps() {
    let before = ipc_resources();
    let seed = 2;
    let duration = 22.0;
    // the rig's simulator run is not used: its prefix, logs and start instant are
    let rig = Rig::new("pipe", "robot", seed, duration, 1.0);
    let mut daemon = rig.daemon(0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let (start, d) = (rig.start_at.to_string(), duration.to_string());
    let seed_s = seed.to_string();
    let lidar_truth = rig.logs.join("lidar.truth.csv");
    let mut lidar = Managed::spawn(
        "vlsync-lidar",
        &bin("vlsync-lidar"),
        &[
            "--prefix",
            &rig.prefix,
            "--render",
            &seed_s,
            "--duration",
            &d,
            "--stamp",
            "mono",
            "--start-at",
            &start,
            "--truth-out",
            &lidar_truth.display().to_string(),
        ]
        .map(String::from),
        Some(&rig.logs.join("vlsync-lidar.log")),
    )
    .unwrap();
    let camera_program = format!(
        "{} --raw-stdout i420 --seed {seed} --duration {duration} --start-at {start}",
        bin("vlsync-render").display()
    );
    let cam_log = rig.logs.join("vlsync-cam.log");
    let mut cam = Managed::spawn(
        "vlsync-cam",
        &bin("vlsync-cam"),
        &[
            "--prefix",
            &rig.prefix,
            "--pipe-cmd",
            &camera_program,
            "--size",
            "320x240",
        ]
        .map(String::from),
        Some(&cam_log),
    )
    .unwrap();
    let est = collect(&mut client, rig.remaining() + Duration::from_secs(2));
    // the camera program ends with the run; the driver says how, and exits 2 (a live
    // camera's stream does not end by itself: its unit restarts it)
    let cam_exit = cam.wait_up_to(Duration::from_secs(10));
    assert!(lidar.stop(Duration::from_secs(5)));
    assert!(
        daemon.stop(Duration::from_secs(5)),
        "{}",
        rig.log("vlsyncd-0.log")
    );
    let cam_text = rig.log("vlsync-cam.log");
    assert_eq!(cam_exit.and_then(|s| s.code()), Some(2), "{cam_text}");
    let written = cam_text
        .lines()
        .find_map(|l| {
            l.strip_prefix("vlsync-render: ")?
                .split_once(" frames written to stdout")
                .map(|(n, _)| n.parse::<u64>().unwrap())
        })
        .unwrap_or_else(|| panic!("no summary of the camera program:\n{cam_text}"));
    assert!(
        cam_text.contains(&format!(
            "the command ended (exit status: 0) after {written} frames"
        )),
        "{cam_text}"
    );
    // 30 Hz over the run, a few dropped by the renderer's camera
    assert!(written as f64 > 25.0 * duration, "{cam_text}");
    // every frame arrived whole; those that waited in the pipe (none on an idle
    // machine) are dropped and said
    let read = cam_text
        .lines()
        .find_map(|l| {
            l.strip_prefix("vlsync-cam: ")?
                .split_once(" frames, ")
                .map(|(n, _)| n.parse::<u64>().ok())
        })
        .flatten()
        .unwrap_or_else(|| panic!("no driver summary:\n{cam_text}"));
    assert!(
        read <= written && read > written * 9 / 10,
        "{read} of {written}:\n{cam_text}"
    );

    // the truth: the LiDAR's stamping error (mean of its truth rows) less half the
    // exposure (vlsync-render's default camera)
    let exposure = vlsync_render::RenderConfig::from_seed(seed, duration)
        .camera
        .exposure_s;
    let rows = std::fs::read_to_string(&lidar_truth).unwrap();
    let lidar_err: Vec<f64> = rows
        .lines()
        .skip(1)
        .map(|l| {
            let c: Vec<i64> = l.split(',').map(|v| v.parse().unwrap()).collect();
            (c[3] - c[2]) as f64 * 1e-9
        })
        .collect();
    assert!(
        lidar_err.len() > 200,
        "{} LiDAR truth rows",
        lidar_err.len()
    );
    let truth = lidar_err.iter().sum::<f64>() / lidar_err.len() as f64 - exposure / 2.0;
    let mut tracking: Vec<f64> = est
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking)
        .map(|e| e.offset_s)
        .collect();
    assert!(
        tracking.len() >= 20,
        "{} tracking estimates of {}:\n{}",
        tracking.len(),
        est.len(),
        rig.log("vlsyncd-0.log")
    );
    tracking.sort_by(f64::total_cmp);
    let median = tracking[tracking.len() / 2];
    eprintln!(
        "pipe: {written} frames written, {read} read; {} tracking estimates, median offset \
         {:+.2} ms, truth {:+.2} ms",
        tracking.len(),
        median * 1e3,
        truth * 1e3
    );
    // the estimator's own 2σ on a run this short with these signals is 4-6 ms
    assert!(
        (median - truth).abs() < 0.004,
        "median tracking offset {:+.2} ms against the truth {:+.2} ms",
        median * 1e3,
        truth * 1e3
    );
    drop(client);
    assert_nothing_left(&before);
}
