//! End to end through the real front-ends with their shipped defaults:
//! rendered frames → signature-cam, rendered scans → signature-lidar, both →
//! the estimator (shipped defaults), scored against the renderer's truth.
//!
//! The runs are the renderer's defaults for a seed: 60 s, 320x240 at 30 Hz with
//! 8 ms exposure (blur) and 2 gray levels of noise, 2 % frame drops, 1 ms
//! camera stamp jitter; an LD06-like 10 Hz LiDAR with 8 mm range noise; offset
//! and drift drawn from the seed. One seed takes ~20-30 s of CPU (rendering);
//! the seeds run on two threads (both tests: ~50 s on a busy 2-core machine).
//!
//! Longer sweeps (held-out seeds, other resolutions):
//! `cargo run --release -p vlsync-render --example accuracy -- --seeds 100-109`.

mod support;

use support::pipeline::{
    check_seeds, delay, ideal_sensors, parse_steps, run, run_seeds, table_row, try_run,
    try_run_seeds, RunResult, TABLE_HEADER,
};
use vlsync_render::RenderConfig;

fn cfg(seed: u64) -> RenderConfig {
    RenderConfig::from_seed(seed, 60.0)
}

/// Issue 4's target on one run (midpoint stamping): at least 60 tracking
/// estimates, their mean error at most 3 ms. Returns that error, seconds.
fn meets_the_target(r: &RunResult) -> f64 {
    let mid = &r.scores[0];
    assert!(mid.n >= 60, "seed {}: {} tracking estimates", r.seed, mid.n);
    assert!(
        mid.mae_s <= 0.003,
        "seed {}: midpoint MAE {:.2} ms",
        r.seed,
        mid.mae_s * 1e3
    );
    mid.mae_s
}

fn report(results: &[RunResult]) {
    eprintln!("{TABLE_HEADER}");
    for r in results {
        eprintln!("{}", table_row(r));
    }
}

/// Issue 4's target on the first four seeds (those the front-end defaults were
/// tuned on, with 5 and 6): the mean error of the tracking estimates against the
/// truth is at most 3 ms on every run. Measured with the segment estimator:
/// 2.34, 1.25, 2.22, 0.76 ms (mean 1.64). Held-out seeds 100-109: 0.64-3.07 ms,
/// mean 1.42 (README, `--example accuracy`).
///
/// And the stamping matters: end-of-interval stamping (the camera sample at its
/// later frame, the LiDAR sample at its later measurement) delays the camera by
/// half a frame interval (16.7 ms) and the LiDAR by half a revolution (50 ms),
/// so the offset `t_L - t_C` reads ~33 ms too large: its error exceeds 15 ms on
/// every run.
#[test]
fn midpoint_stamping_meets_the_target_and_end_stamping_does_not() {
    let results = run_seeds(&[1, 2, 3, 4], 2, false, cfg);
    report(&results);
    let mut sum = 0.0;
    for r in &results {
        let [mid, end] = &r.scores;
        let (cams, scans) = r.samples[0];
        assert!(
            cams > 1650 && scans > 560,
            "seed {}: {cams} {scans}",
            r.seed
        );
        let first = mid.first_lock_ns.expect("locks") as f64 * 1e-9;
        assert!(first < 5.0, "seed {}: first lock at {first} s", r.seed);
        sum += meets_the_target(r);
        assert!(
            end.n >= 40,
            "seed {}: {} end-stamped estimates",
            r.seed,
            end.n
        );
        assert!(
            end.mae_s > 0.015,
            "seed {}: end-stamped MAE {:.2} ms",
            r.seed,
            end.mae_s * 1e3
        );
        // the raw correlation measurements move by the predicted 33.3 ms
        let shift = end.measured_bias_s - mid.measured_bias_s;
        assert!(
            (shift - 0.0333).abs() < 0.005,
            "seed {}: bias shift {:.2} ms",
            r.seed,
            shift * 1e3
        );
    }
    let mean = sum / results.len() as f64;
    assert!(mean <= 0.0025, "mean MAE {:.2} ms", mean * 1e3);
}

/// A slow camera: 10 Hz instead of 30, the same drives (seeds 1-4). At 0.6 m/s
/// the floor near the bottom of the ROI moves 30-45 px between frames there, and
/// those points are lost while the robot is fast. They used to stay lost (each
/// searched from zero, beyond the pyramid's reach) and the grid's flow pattern,
/// learning 2 % per frame, had not yet learnt that they are the fast ones, so
/// the signature read the first drives 13-17 % low: MAE 3.18, 5.64, 10.07,
/// 15.15 ms. A lost point now starts from its neighbours' flow and the pattern
/// learns each point's share as a running mean first: 2.13, 0.71, 2.06, 1.36 ms
/// (seeds 1-8: mean 1.62 ms, against 1.60 at 30 Hz); since outliers teach the
/// pattern at a tenth of the settled rate (2026-12-07, session 54), 2.46, 0.87,
/// 1.79, 0.88 ms (seeds 1-8: 1.61 ms).
#[test]
fn a_10_hz_camera_meets_the_target_too() {
    let slow = |seed| {
        let mut c = cfg(seed);
        c.camera.fps = 10.0;
        c
    };
    let results = run_seeds(&[1, 2, 3, 4], 2, false, slow);
    report(&results);
    let sum: f64 = results.iter().map(meets_the_target).sum();
    let mean = sum / results.len() as f64;
    assert!(mean <= 0.0025, "mean MAE {:.2} ms", mean * 1e3);
}

/// A 10 Hz camera on the held-out drives where it read early (sensors ideal, as
/// in the audit below): the bottom rows' points, tracked at 30-45 px a frame,
/// are often mis-tracked, and at the full rate those outliers bent the grid's
/// pattern with the speed, a scale error that follows the speed and reads like
/// a delay: -2.47 ms (seed 101) and -3.36 ms (seed 106), the runs' MAE with
/// noise 4.50 and 6.97 ms. Outliers now teach at a tenth of the settled rate:
/// +0.44 and +0.24 ms (MAE 1.64 and 2.17 ms; seeds 100-109 with noise 2.61 →
/// 1.66 ms).
#[test]
fn a_10_hz_camera_is_on_time_on_its_fastest_drives() {
    let slow_ideal = |seed| {
        let mut c = cfg(seed);
        c.camera.fps = 10.0;
        ideal_sensors(&mut c);
        c
    };
    for r in run_seeds(&[101, 106], 2, true, slow_ideal) {
        let rows = r.audit.expect("audit rows");
        let d = delay(&rows.cam[0]);
        eprintln!("seed {}: camera delay {:+.2} ms", r.seed, d * 1e3);
        assert!(
            d.abs() < 0.001,
            "seed {}: camera delay {:+.2} ms",
            r.seed,
            d * 1e3
        );
    }
}

/// Each front-end on its own, against the true speed of the drive: a sample
/// stamped `t` (mapped to true time) that really describes `t - δ` reads
/// `g·v(t - δ) ≈ g·v(t) - g·δ·a(t)`; the fit of the value on `v(t)` and `a(t)`
/// gives the delay `δ`. With midpoint stamping the samples describe the instant
/// they carry; with end stamping they are late by half a frame interval
/// (16.7 ms) and half a revolution (50 ms).
///
/// The audit run has no stamp jitter, no range noise and no dropped frames
/// (seed 5, otherwise the defaults): what is left is the front-ends' own
/// timing. (A dropped frame makes the camera's next interval two frames long,
/// so with the default 2 % drops end stamping is late by ~17.0 ms on average,
/// not 16.7.) With the default 1 ms
/// camera jitter the camera fit scatters by ±0.7 ms from seed to seed (seed 1:
/// +0.66 ms, seed 2: -0.03, seed 3: -0.30), which would hide a real
/// half-millisecond error. Measured: camera +0.12 / +16.79 ms, LiDAR -0.06 /
/// +49.75 ms.
#[test]
fn each_front_end_is_stamped_where_its_sample_belongs() {
    let mut c = cfg(5);
    ideal_sensors(&mut c);
    let r = run(c, true);
    let rows = r.audit.expect("audit rows");
    let [cm, ce] = [delay(&rows.cam[0]), delay(&rows.cam[1])];
    let [lm, le] = [delay(&rows.lidar[0]), delay(&rows.lidar[1])];
    eprintln!(
        "delays (camera, LiDAR): midpoint {:+.2} ms, {:+.2} ms; end {:+.2} ms, {:+.2} ms",
        cm * 1e3,
        lm * 1e3,
        ce * 1e3,
        le * 1e3
    );
    assert!(cm.abs() < 0.0005, "camera midpoint delay {} ms", cm * 1e3);
    assert!(lm.abs() < 0.0005, "LiDAR midpoint delay {} ms", lm * 1e3);
    assert!(
        (ce - 0.01667).abs() < 0.0005,
        "camera end delay {} ms",
        ce * 1e3
    );
    assert!(
        (le - 0.050).abs() < 0.0005,
        "LiDAR end delay {} ms",
        le * 1e3
    );
}

/// The step-following measure of the accuracy example (`--steps`), on estimates
/// made up for it: published 3 s after their reference times, 2 per second.
#[test]
fn follow_times_judge_a_step_as_the_load_harness_does() {
    use support::pipeline::follow_times;
    use vlsync_common::{Estimate, EstimatorState, Polarity};
    let est = |t: f64, offset_s: f64, state| Estimate {
        seq: 0,
        t_ref_ns: (t * 1e9) as i64,
        offset_s,
        drift: 0.0,
        offset_std_s: 0.001,
        drift_std: 0.0,
        state,
        polarity: Polarity::Positive,
        peak_score: 1.0,
        peak_ratio: 2.0,
        measured_offset_s: f64::NAN,
    };
    // a -12 ms step at 30 s (publish time); the estimates reach the new level when
    // published at 34 s, after a dip past half the step and back at 32.5 s
    let ests: Vec<Estimate> = (0..120)
        .map(|i| {
            let p = i as f64 * 0.5;
            let o = if p >= 34.0 || p == 32.0 { 0.088 } else { 0.100 };
            est(p - 3.0, o, EstimatorState::Tracking)
        })
        .collect();
    let f = follow_times(&ests, &[(30.0, -0.012)], 3.0, 60.0);
    assert_eq!(f.len(), 1);
    assert_eq!(f[0].2, Some(4.0), "{f:?}");
    // a step the estimates never follow, and one with no locked estimates before it
    let flat: Vec<Estimate> = (0..120)
        .map(|i| est(i as f64 * 0.5 - 3.0, 0.1, EstimatorState::Tracking))
        .collect();
    assert_eq!(follow_times(&flat, &[(30.0, -0.012)], 3.0, 60.0)[0].2, None);
    let acquiring: Vec<Estimate> = (0..120)
        .map(|i| est(i as f64 * 0.5 - 3.0, 0.1, EstimatorState::Acquiring))
        .collect();
    assert_eq!(
        follow_times(&acquiring, &[(30.0, -0.012)], 3.0, 60.0)[0].2,
        None
    );
    // moved only in the run's last second: not 2 s of evidence
    let late: Vec<Estimate> = (0..120)
        .map(|i| {
            let p = i as f64 * 0.5;
            est(
                p - 3.0,
                if p >= 59.0 { 0.088 } else { 0.1 },
                EstimatorState::Tracking,
            )
        })
        .collect();
    assert_eq!(follow_times(&late, &[(30.0, -0.012)], 3.0, 60.0)[0].2, None);
    // a step of 0: nothing to follow (it used to divide by it, and estimates a hair
    // above the level read as followed at once); the example refuses it
    let hair: Vec<Estimate> = (0..120)
        .map(|i| {
            let p = i as f64 * 0.5;
            let o = if p >= 30.0 { 0.1001 } else { 0.1 };
            est(p - 3.0, o, EstimatorState::Tracking)
        })
        .collect();
    assert_eq!(follow_times(&hair, &[(30.0, 0.0)], 3.0, 60.0)[0].2, None);
    assert_eq!(
        parse_steps("30:-12,60:12").unwrap(),
        [(30.0, -0.012), (60.0, 0.012)]
    );
    let e = parse_steps("30:-12,60:0").unwrap_err();
    assert!(e.starts_with("--steps: `60:0` is a step of 0 ms"), "{e}");
}

/// A room too narrow for some seeds' boxes (8 x 2 m: seeds 8 and 9 draw boxes,
/// 0.3-0.6 m deep on either side, that leave no 1.2 m lane; 7 and 10 do not) fails
/// those seeds, named with why, before any run is rendered, and a run that cannot
/// be rendered is its own row: only the first seed used to be checked, and a later
/// bad one panicked its worker and with it the whole table.
#[test]
fn a_seed_that_cannot_be_rendered_is_named_not_a_panic() {
    let narrow = |seed| {
        let mut c = RenderConfig::from_seed(seed, 60.0);
        c.room.1 = 2.0;
        c
    };
    let seeds = [7, 8, 9, 10];
    assert_eq!(
        check_seeds(&seeds, narrow).unwrap_err(),
        "2 of the 4 seeds cannot be rendered: seeds 8, 9: render config `room.boxes`: no \
         lane along the room is clear of obstacles (1.2 m wide)"
    );
    let bad = [8, 9];
    assert!(check_seeds(&seeds, cfg).is_ok());
    // run anyway: the bad seed is an error row, the good one's renders are not
    // lost (shortened to 1 s: the good seed's run is not the point)
    let short = |seed| {
        let mut c = narrow(seed);
        c.duration_s = 1.0;
        c
    };
    let good = *seeds.iter().find(|s| !bad.contains(s)).unwrap();
    let rows = try_run_seeds(&[bad[0], good], 2, false, short);
    assert_eq!(rows.len(), 2);
    let (seed, first) = &rows[0];
    assert_eq!(*seed, bad[0]);
    let e = first.as_ref().unwrap_err();
    assert!(e.starts_with(&format!("seed {}: ", bad[0])), "{e}");
    assert!(rows[1].1.is_ok(), "{:?}", rows[1].1.as_ref().err());
    assert!(try_run(short(bad[0]), false).is_err());
}
