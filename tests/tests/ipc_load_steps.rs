//! Load steps through the whole pipeline: the camera driver publishes stamps that
//! step by ±25 ms (the simulator's `load-steps` family, as CPU load moves a camera
//! stamped in software), the daemon follows each step from the stamps' cadence,
//! its estimates stay on the truth after every step, and its log names each step.

use std::time::Duration;
use vlsync_common::{EstimatorState, Stream};
use vlsync_ipc::OffsetClient;
use vlsync_tests::{collect, Rig};
use vlsyncd::runtime::journal::latency_steps_logged;

#[test]
fn load_steps_are_followed_from_the_stamps_and_logged() {
    // 90 simulated seconds at 9x: 10 s of wall time
    let rig = Rig::new("loadsteps", "load-steps", 2, 90.0, 9.0);
    let steps = rig.sim.truth.steps.clone();
    assert!(steps.len() >= 3, "{steps:?}");
    let mut daemon = rig.daemon(0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let est = collect(&mut client, rig.remaining() + Duration::from_millis(1500));
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(daemon.stop(Duration::from_secs(3)));
    let log = rig.log("vlsyncd-0.log");

    // every tracking estimate from 3 s after a step on (the benchmark's scoring)
    // close to the truth: each step was followed, not smeared over seconds; and once
    // the first lock has converged (its first 10 s are a few ms off, with the σ to
    // say so), none far off
    let scored: Vec<(i64, f64)> = est
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking)
        .filter(|e| {
            !steps
                .iter()
                .any(|&(s, _)| (0..3_000_000_000).contains(&(e.t_ref_ns - s)))
        })
        .map(|e| {
            (
                e.t_ref_ns,
                (e.offset_s - rig.sim.truth.offset_at(e.t_ref_ns)).abs(),
            )
        })
        .collect();
    assert!(scored.len() > 100, "{} scored\n{log}", scored.len());
    let mae = scored.iter().map(|s| s.1).sum::<f64>() / scored.len() as f64;
    let worst = scored
        .iter()
        .filter(|s| s.0 >= steps[0].0)
        .map(|s| s.1)
        .fold(0.0, f64::max);
    assert!(
        mae < 0.0025 && worst < 0.008,
        "MAE {:.2} ms, worst after the first step {:.2} ms\n{log}",
        mae * 1e3,
        worst * 1e3
    );
    // the journal: a line for the first step with its size, then (the steps come
    // seconds apart at this speed, the journal gives a kind one line per 10 s) the
    // count of those held back: every step is there
    let first = log
        .lines()
        .find(|l| l.contains("cam stamps") && l.contains("later from t="))
        .unwrap_or_else(|| panic!("no step line\n{log}"));
    let want = format!("{:+.1} ms later", -steps[0].1 * 1e3);
    assert!(first.contains(&want), "{first} (want {want})");
    assert_eq!(latency_steps_logged(&log, "cam"), steps.len(), "{log}");
}
