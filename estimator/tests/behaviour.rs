//! Behaviour of the whole estimator on simulated runs and hostile input.

use proptest::prelude::*;
use vlsync_common::{EstimatorState, Polarity, RejectReason, Sample, Stream};
use vlsync_config::EstimatorConfig;
use vlsync_estimator::{Estimator, SearchMoveReason};
use vlsync_sim::families::{generate, Family, SimRun};

mod common;
use common::saved_tracking;

/// The newest estimate in state `tracking`, if any.
fn last_tracking(out: &[vlsync_common::Estimate]) -> Option<&vlsync_common::Estimate> {
    out.iter()
        .rev()
        .find(|e| e.state == EstimatorState::Tracking)
}

fn replay(run: &SimRun, est: &mut Estimator) -> Vec<vlsync_common::Estimate> {
    replay_announcing(run, est, &[], |_, _| {})
}

/// Index of the first tracking estimate (the run must lock).
fn first_lock(out: &[vlsync_common::Estimate]) -> usize {
    out.iter()
        .position(|e| e.state == EstimatorState::Tracking)
        .expect("locks")
}

/// The defaults without the stamps' cadence: offset steps reach the correlation,
/// whose step test (or an announcement) must find them.
fn no_cadence() -> EstimatorConfig {
    EstimatorConfig {
        cadence: vlsync_config::CadenceStreams::Off,
        ..EstimatorConfig::default()
    }
}

#[test]
fn robot_run_locks_with_negative_polarity_and_converges() {
    let run = generate(Family::Robot, 11, Some(90.0));
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay(&run, &mut est);
    let last = out.last().unwrap();
    assert_eq!(last.polarity, Polarity::Negative);
    assert!(out.iter().any(|e| e.state == EstimatorState::Tracking));
    // the last 30 s: mean error within a few ms of the truth
    let tail: Vec<f64> = out
        .iter()
        .filter(|e| e.t_ref_ns > last.t_ref_ns - 30_000_000_000)
        .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
        .collect();
    let mae = tail.iter().sum::<f64>() / tail.len() as f64;
    assert!(mae < 0.006, "tail MAE {mae}");
    // sequence numbers are contiguous
    assert!(out.windows(2).all(|w| w[1].seq == w[0].seq + 1));
}

/// Held-out `big-offset` seed 1005: the offset (450 ms) locks near the edge of the
/// ±0.5 s lag range, so the first tracking hop re-centres the range. That used to
/// restart the acquisition window, and with it the motion gate: the lock's first
/// estimate, 20.2 ms off with a σ of 26 ms, was then held for three hops while the
/// robot moved (1.7 % of the run's estimates beyond 20 ms, the limit 0.5 %).
/// The window now keeps its blocks across the shift, valid on the lags they all hold.
#[test]
fn a_re_centred_lag_range_keeps_the_tracker_measuring() {
    let run = generate(Family::BigOffset, 1005, None);
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay(&run, &mut est);
    let first = first_lock(&out);
    // the lock is near the range's edge: the lag range must have moved for this test
    // to test anything (the acquisition range is ±0.5 s around 0)
    assert!(out[first].offset_s > 0.4, "{}", out[first].offset_s);
    let next: Vec<EstimatorState> = out[first + 1..first + 5].iter().map(|e| e.state).collect();
    assert!(
        next.iter().all(|&s| s == EstimatorState::Tracking),
        "after the lock: {next:?}"
    );
    let locked: Vec<f64> = out[first..]
        .iter()
        .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
        .collect();
    let over = locked.iter().filter(|&&e| e > 0.020).count() as f64 / locked.len() as f64;
    assert!(over < 0.005, "{:.1} % beyond 20 ms", over * 100.0);
    assert!(
        locked[4] < 0.006,
        "four hops after the lock: {:.1} ms",
        locked[4] * 1e3
    );
}

/// Held-out `clocks` seed 2009: the robot slows to a stop just before the LiDAR's
/// gap. The newest two seconds then hold almost no motion, yet their correlation
/// showed a confident peak 46 ms away, and the step test took it for a step (max
/// error 46.7 ms, 4 % of estimates off by more than 20 ms). A short window must move
/// as the motion gate asks before it can measure a step or feed the drift.
#[test]
fn a_window_at_the_end_of_motion_is_no_step() {
    let run = generate(Family::Clocks, 2009, None);
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay(&run, &mut est);
    let first_lock = first_lock(&out);
    let worst = out[first_lock..]
        .iter()
        .filter(|e| matches!(e.state, EstimatorState::Tracking | EstimatorState::Holding))
        .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
        .fold(0.0, f64::max);
    assert!(worst < 0.015, "worst locked error {:.1} ms", worst * 1e3);
    assert_eq!(est.stats().steps, 0, "false steps: {:?}", est.stats());
}

/// Mean absolute error (s) of the locked estimates whose reference time lies
/// 3..10 s after one of `steps`.
fn error_after_steps(out: &[vlsync_common::Estimate], run: &SimRun) -> f64 {
    let errs: Vec<f64> = out
        .iter()
        .filter(|e| matches!(e.state, EstimatorState::Tracking | EstimatorState::Holding))
        .filter(|e| {
            run.truth
                .steps
                .iter()
                .any(|&(s, _)| (3_000_000_000..10_000_000_000).contains(&(e.t_ref_ns - s)))
        })
        .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
        .collect();
    assert!(errs.len() > 20, "{} estimates after the steps", errs.len());
    errs.iter().sum::<f64>() / errs.len() as f64
}

#[test]
fn sigma_stays_honest_while_a_step_is_not_yet_detected() {
    // ±25 ms load steps take the step test several seconds to confirm; meanwhile the
    // newest data contradict the estimate, and its σ must say so: at least 90 % of the
    // tracking estimates (3 s after each step excluded, as the benchmark scores them)
    // lie within 2σ + 1 ms of the truth (without the innovation bias term: 80 %)
    let run = generate(Family::LoadSteps, 2, Some(120.0));
    let out = replay(&run, &mut Estimator::new(&no_cadence()));
    let scored: Vec<bool> = out
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking)
        .filter(|e| {
            !run.truth
                .steps
                .iter()
                .any(|&(s, _)| (0..3_000_000_000).contains(&(e.t_ref_ns - s)))
        })
        .map(|e| {
            (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs() <= 2.0 * e.offset_std_s + 0.001
        })
        .collect();
    let share = scored.iter().filter(|&&ok| ok).count() as f64 / scored.len() as f64;
    assert!(
        scored.len() > 150 && share >= 0.9,
        "{} scored, {share}",
        scored.len()
    );
}

#[test]
fn announced_changes_restart_the_segment_at_the_step() {
    // load steps of ±25 ms: with their times announced (as a caller that knows a
    // driver restarted would), the 3-10 s after each step are far closer to the truth
    // than when the step test has to find them in the data
    let run = generate(Family::LoadSteps, 2, Some(120.0));
    let cfg = no_cadence();
    let detected = replay(&run, &mut Estimator::new(&cfg));
    let steps: Vec<i64> = run.truth.steps.iter().map(|s| s.0).collect();
    let mut est = Estimator::new(&cfg);
    let out = replay_announcing(&run, &mut est, &steps, |e, t| e.declare_change(t));
    assert!(steps.len() >= 4);
    let (known, found) = (
        error_after_steps(&out, &run),
        error_after_steps(&detected, &run),
    );
    assert!(
        known < 0.005 && known < 0.5 * found,
        "announced {known}, detected {found}"
    );
    // every announced step restarted the segment once
    assert!(est.stats().steps >= run.truth.steps.len() as u64);
}

/// Each offset step the step test finds is reported once (`take_offset_step`, what
/// the daemon logs): near a true step and with its sign; announced changes are not
/// reported (their announcer knows). The size is the test's own measurement, new
/// offset against the old segment's prediction: on this run -31 / +25 / +41 / -46 ms
/// for steps of 25 ms (the last one after a step the test missed: -50 ms in all).
#[test]
fn offset_steps_found_in_the_data_are_reported_where_they_are() {
    let run = generate(Family::LoadSteps, 2, Some(120.0));
    let mut est = Estimator::new(&no_cadence());
    let mut found = Vec::new();
    for (stream, s) in run.pushes() {
        let _ = est.push(stream, s);
        while est.poll().is_some() {}
        found.extend(est.take_offset_step());
    }
    assert!(!run.truth.steps.is_empty());
    assert_eq!(found.len() as u64, est.stats().steps, "{found:?}");
    assert!(found.len() >= 2, "{found:?}");
    for f in &found {
        let (t, delta) = *run
            .truth
            .steps
            .iter()
            .min_by_key(|(t, _)| (t - f.t_ns).abs())
            .unwrap();
        assert!(
            (t - f.t_ns).abs() < 4_000_000_000,
            "step found at {} s, nearest true one at {} s",
            f.t_ns as f64 * 1e-9,
            t as f64 * 1e-9
        );
        assert!(
            f.step_s.signum() == delta.signum() && f.step_s.abs() < 0.06,
            "step of {:+.1} ms found, true {:+.1} ms",
            f.step_s * 1e3,
            delta * 1e3
        );
    }
    // announced: the segment restarts there, and no step is reported there
    let steps: Vec<i64> = run.truth.steps.iter().map(|s| s.0).collect();
    let mut est = Estimator::new(&no_cadence());
    let (mut c, mut reported) = (0, Vec::new());
    for (stream, s) in run.pushes() {
        if stream == Stream::Lidar {
            if let Some(&t) = steps.get(c).filter(|&&t| t <= s.t_ns) {
                est.declare_change(t);
                c += 1;
            }
        }
        let _ = est.push(stream, s);
        while est.poll().is_some() {}
        reported.extend(est.take_offset_step());
    }
    assert_eq!(c, steps.len());
    assert!(est.stats().steps >= steps.len() as u64 + reported.len() as u64);
    for f in &reported {
        assert!(
            steps.iter().all(|&t| (t - f.t_ns).abs() > 1_000_000_000),
            "an announced step was reported as found: {f:?}"
        );
    }
}

/// An offset step found in the data is reported at the LiDAR's own stamps, its
/// cadence's latency level added back (the correlator's internal clock has it taken
/// out): the same run with the LiDAR's stamps stepping 25 ms later every 20 s (which
/// its cadence follows) reports the same steps, each later by the LiDAR's level then.
#[test]
fn offset_steps_are_reported_on_the_lidars_own_stamps() {
    let cfg = EstimatorConfig {
        cadence: vlsync_config::CadenceStreams::Lidar,
        ..EstimatorConfig::default()
    };
    let run = generate(Family::LoadSteps, 2, Some(120.0));
    let level =
        |t: i64| 25_000_000 * ((t - 10_000_000_000).div_euclid(20_000_000_000) + 1).clamp(0, 5);
    let mut later = run.clone();
    for s in &mut later.lidar {
        s.t_ns += level(s.t_ns);
    }
    let found = |run: &SimRun| {
        let mut est = Estimator::new(&cfg);
        let mut found = Vec::new();
        for (stream, s) in run.pushes() {
            let _ = est.push(stream, s);
            while est.poll().is_some() {}
            found.extend(est.take_offset_step());
        }
        (found, est.stats().cadence_steps[1])
    };
    let ((plain, _), (stepped, lidar_steps)) = (found(&run), found(&later));
    assert_eq!(lidar_steps, 5);
    assert!(
        plain.len() >= 2 && plain.len() == stepped.len(),
        "{plain:?}\n{stepped:?}"
    );
    let mut moved = 0;
    for (a, b) in plain.iter().zip(&stepped) {
        let want = level(a.t_ns);
        moved += usize::from(want > 0);
        assert!(
            (b.t_ns - a.t_ns - want).abs() <= 10_000_000,
            "step at {} s reported at {} s, the LiDAR's level then {} ms",
            a.t_ns as f64 * 1e-9,
            b.t_ns as f64 * 1e-9,
            want as f64 * 1e-6
        );
    }
    assert!(moved >= 1, "no step after a LiDAR latency step: {plain:?}");
}

#[test]
fn load_steps_are_followed_from_the_stamps_cadence() {
    // the camera's stamps carry each ±25 ms step, on a regular frame grid: the
    // cadence follows the step within a few frames, the correlation never sees it
    // (no segment restart), and the 3-10 s after each step are as good as the rest
    let run = generate(Family::LoadSteps, 2, Some(120.0));
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay(&run, &mut est);
    let correlation_only = replay(&run, &mut Estimator::new(&no_cadence()));
    let stats = est.stats();
    assert_eq!(
        stats.cadence_steps,
        [run.truth.steps.len() as u64, 0],
        "{stats:?}"
    );
    assert_eq!(stats.steps, 0, "the step test found none: {stats:?}");
    let (after, before) = (
        error_after_steps(&out, &run),
        error_after_steps(&correlation_only, &run),
    );
    let (mae, _) = locked_errors(&out, &run);
    // the worst error away from the steps themselves (an estimate whose reference
    // time falls within a frame of a step may take either side's latency)
    let worst = out
        .iter()
        .skip_while(|e| e.state != EstimatorState::Tracking)
        .filter(|e| {
            let near = |&(s, _): &(i64, f64)| (e.t_ref_ns - s).abs() < 50_000_000;
            !run.truth.steps.iter().any(near)
        })
        .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
        .fold(0.0, f64::max);
    assert!(
        after < 0.002 && after < 0.25 * before && worst < 0.01,
        "after steps {:.2} ms (correlation only {:.2}), MAE {:.2}, worst {:.2} ms",
        after * 1e3,
        before * 1e3,
        mae * 1e3,
        worst * 1e3
    );
}

#[test]
fn a_camera_falling_behind_in_small_steps_is_followed_without_checks() {
    // a camera pipeline falling behind: from 30 s on its latency grows 3 ms every 1.5 s
    // for 15 s (30 ms in all), and it drops every 20th frame. The cadence follows each
    // small step; none is tested against "a period less, a frame dropped" (each test
    // would restart the segment), and the estimates follow the growing latency.
    let mut run = generate(Family::Robot, 5, Some(90.0));
    let lat = |t_ns: i64| {
        let t = t_ns as f64 * 1e-9;
        (((t - 30.0) / 1.5).floor().clamp(-1.0, 9.0) + 1.0) * 0.003
    };
    let mut k = 0;
    run.cam.retain(|_| {
        k += 1;
        k % 20 != 0
    });
    for s in run.cam.iter_mut() {
        s.t_ns += (lat(s.t_ns) * 1e9) as i64;
    }
    let mut est = Estimator::new(&EstimatorConfig::default());
    let mut out = Vec::new();
    let mut steps = Vec::new();
    for (stream, s) in run.pushes() {
        let _ = est.push(stream, s);
        if let Some(st) = est.take_latency_step() {
            steps.push(st);
        }
        while let Some(e) = est.poll() {
            out.push(e);
        }
    }
    assert!(steps.len() >= 9, "{steps:?}");
    assert!(steps.iter().all(|s| !s.checked), "{steps:?}");
    assert_eq!(est.stats().steps, 0, "{:?}", est.stats());
    // the offset falls by the camera's latency (t_L - t_C, the camera stamps later)
    let errs: Vec<f64> = out
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking && e.t_ref_ns > 20_000_000_000)
        .map(|e| (e.offset_s - (run.truth.offset_at(e.t_ref_ns) - lat(e.t_ref_ns))).abs())
        .collect();
    let mae = errs.iter().sum::<f64>() / errs.len() as f64;
    assert!(
        errs.len() > 80 && mae < 0.003,
        "{} estimates, MAE {:.2} ms",
        errs.len(),
        mae * 1e3
    );
}

/// Replays `run`, calling `announce(est, t)` for each of `times` (LiDAR clock)
/// just before the first LiDAR sample at or after it.
fn replay_announcing(
    run: &SimRun,
    est: &mut Estimator,
    times: &[i64],
    announce: impl Fn(&mut Estimator, i64),
) -> Vec<vlsync_common::Estimate> {
    let mut out = Vec::new();
    let mut c = 0;
    for (stream, s) in run.pushes() {
        if stream == Stream::Lidar {
            if let Some(&t) = times.get(c).filter(|&&t| t <= s.t_ns) {
                announce(est, t);
                c += 1;
            }
        }
        let _ = est.push(stream, s);
        while let Some(e) = est.poll() {
            out.push(e);
        }
    }
    assert_eq!(c, times.len(), "every time announced");
    out
}

/// MAE (s) and worst error of the locked estimates after the first lock.
fn locked_errors(out: &[vlsync_common::Estimate], run: &SimRun) -> (f64, f64) {
    let errs: Vec<f64> = out
        .iter()
        .skip_while(|e| e.state != EstimatorState::Tracking)
        .filter(|e| matches!(e.state, EstimatorState::Tracking | EstimatorState::Holding))
        .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
        .collect();
    assert!(errs.len() > 100);
    (
        errs.iter().sum::<f64>() / errs.len() as f64,
        errs.iter().copied().fold(0.0, f64::max),
    )
}

#[test]
fn hints_follow_real_steps_and_cost_little_when_wrong() {
    let cfg = no_cadence();
    let hint = |e: &mut Estimator, t: i64| e.hint_change(t, vlsync_estimator::HINT_STEP_STD_S);
    // real ±25 ms steps, hinted where they happen: followed as fast as announced ones
    let run = generate(Family::LoadSteps, 2, Some(120.0));
    let steps: Vec<i64> = run.truth.steps.iter().map(|s| s.0).collect();
    let detected = replay(&run, &mut Estimator::new(&cfg));
    let hinted = replay_announcing(&run, &mut Estimator::new(&cfg), &steps, hint);
    let (h, d) = (
        error_after_steps(&hinted, &run),
        error_after_steps(&detected, &run),
    );
    assert!(h < 0.005 && h < 0.5 * d, "hinted {h}, detected {d}");
    // hints every 15 s on a run without steps: only history is lost
    let run = generate(Family::Robot, 3, Some(120.0));
    let wrong: Vec<i64> = (1..8).map(|k| k * 15_000_000_000).collect();
    let plain = locked_errors(&replay(&run, &mut Estimator::new(&cfg)), &run);
    let mut est = Estimator::new(&cfg);
    let with = locked_errors(&replay_announcing(&run, &mut est, &wrong, hint), &run);
    assert!(
        est.stats().steps >= 5,
        "hints restarted the segment: {:?}",
        est.stats()
    );
    assert!(
        with.0 < 1.5 * plain.0 + 0.0005 && with.1 < 0.015,
        "wrong hints: MAE {:.2} ms, worst {:.2} ms; without: {:.2} / {:.2} ms",
        with.0 * 1e3,
        with.1 * 1e3,
        plain.0 * 1e3,
        plain.1 * 1e3
    );
}

#[test]
fn an_hour_of_drifting_clocks_keeps_one_lock_and_learns_the_drift() {
    // a robot running for an hour: 20-60 ppm between the clocks moves the offset by
    // up to 216 ms, far beyond the tracking range, so the lag range must follow it;
    // jitter, drops and a LiDAR gap as in the clocks family
    let run = generate(Family::Clocks, 1, Some(3600.0));
    let truth_drift = (run.truth.offset_at(3_600_000_000_000) - run.truth.offset_at(0)) / 3600.0;
    assert!(truth_drift.abs() > 20e-6, "drift {truth_drift}");
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay(&run, &mut est);
    assert_eq!(est.stats().locks, 1, "{:?}", est.stats());
    assert!(out
        .iter()
        .all(|e| e.state != EstimatorState::Lost && e.offset_s.is_finite()));
    // the last half hour: ms-level error, the drift known to a few ppm
    let last = out.last().unwrap();
    let tail: Vec<f64> = out
        .iter()
        .filter(|e| e.t_ref_ns > last.t_ref_ns - 1_800_000_000_000)
        .filter(|e| e.state == EstimatorState::Tracking)
        .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
        .collect();
    let mae = tail.iter().sum::<f64>() / tail.len() as f64;
    assert!(
        tail.len() > 3000 && mae < 0.002,
        "{} estimates, MAE {mae}",
        tail.len()
    );
    assert!(
        (last.drift - truth_drift).abs() < 5e-6 && last.drift_std < 5e-6,
        "drift {} ± {} vs {truth_drift}",
        last.drift,
        last.drift_std
    );
}

#[test]
fn bad_samples_are_rejected_counted_and_harmless() {
    let run = generate(Family::Robot, 5, Some(60.0));
    let mut clean = Estimator::new(&EstimatorConfig::default());
    let a = replay(&run, &mut clean);
    let mut dirty = Estimator::new(&EstimatorConfig::default());
    let mut out = Vec::new();
    let mut last_t = [0i64; 2];
    let (mut i, mut j) = (0, 0);
    while i < run.cam.len() || j < run.lidar.len() {
        let (s, x) = if j >= run.lidar.len()
            || (i < run.cam.len() && run.cam[i].t_ns <= run.lidar[j].t_ns)
        {
            i += 1;
            (Stream::Cam, run.cam[i - 1])
        } else {
            j += 1;
            (Stream::Lidar, run.lidar[j - 1])
        };
        let si = if s == Stream::Cam { 0 } else { 1 };
        dirty.push(s, x).unwrap();
        let n = if si == 0 { i } else { j };
        if n % 20 == 0 && last_t[si] > 0 {
            assert_eq!(
                dirty.push(s, Sample::new(x.t_ns + 1, f64::NAN)),
                Err(RejectReason::NonFinite)
            );
            assert_eq!(
                dirty.push(s, Sample::new(x.t_ns + 1, 1e12)),
                Err(RejectReason::TooLarge)
            );
            assert_eq!(
                dirty.push(s, Sample::new(x.t_ns, 0.0)),
                Err(RejectReason::Repeated)
            );
            assert_eq!(
                dirty.push(s, Sample::new(x.t_ns - 1000, 0.0)),
                Err(RejectReason::Backwards)
            );
        }
        last_t[si] = x.t_ns;
        while let Some(e) = dirty.poll() {
            out.push(e);
        }
    }
    let st = dirty.stats();
    assert!(st.rejected[0].iter().sum::<u64>() > 10);
    assert!(st.rejected[1].iter().sum::<u64>() > 10);
    // identical estimates: rejected samples never reach the sums
    assert_eq!(a.len(), out.len());
    for (x, y) in a.iter().zip(&out) {
        // every field (Debug prints each f64 exactly, NaN included)
        assert_eq!(format!("{x:?}"), format!("{y:?}"));
    }
}

#[test]
fn stalled_stream_goes_holding_then_lost_then_reacquires() {
    let run = generate(Family::Robot, 3, Some(120.0));
    let cut = (40_000_000_000i64, 100_000_000_000i64); // LiDAR silent for 60 s
    let mut est = Estimator::new(&EstimatorConfig::default());
    let mut states = Vec::new();
    let (mut i, mut j) = (0, 0);
    while i < run.cam.len() || j < run.lidar.len() {
        if j >= run.lidar.len() || (i < run.cam.len() && run.cam[i].t_ns <= run.lidar[j].t_ns) {
            let _ = est.push(Stream::Cam, run.cam[i]);
            i += 1;
        } else {
            let s = run.lidar[j];
            j += 1;
            if s.t_ns < cut.0 || s.t_ns > cut.1 {
                let _ = est.push(Stream::Lidar, s);
            }
        }
        while let Some(e) = est.poll() {
            states.push((e.t_ref_ns, e.state, e.offset_std_s));
        }
    }
    let during: Vec<_> = states
        .iter()
        .filter(|s| s.0 > cut.0 + 5_000_000_000 && s.0 < cut.1)
        .collect();
    assert!(
        !during.is_empty(),
        "estimates continue while the LiDAR is silent"
    );
    assert!(
        during.iter().all(|s| s.1 != EstimatorState::Tracking),
        "{during:?}"
    );
    assert!(during.iter().any(|s| s.1 == EstimatorState::Holding));
    assert!(during.iter().any(|s| s.1 == EstimatorState::Lost));
    // std grows while blind
    assert!(during.last().unwrap().2 > during.first().unwrap().2);
    assert!(
        states
            .iter()
            .any(|s| s.0 > cut.1 && s.1 == EstimatorState::Tracking),
        "re-acquires"
    );
}

#[test]
fn clock_jump_in_camera_stamps_is_followed() {
    let run = generate(Family::Robot, 9, Some(120.0));
    let jump = 30_000_000_000i64; // camera clock steps forward by 30 s at 60 s (an NTP step)
    let mut est = Estimator::new(&EstimatorConfig::default());
    let mut out = Vec::new();
    let (mut i, mut j) = (0, 0);
    while i < run.cam.len() || j < run.lidar.len() {
        if j >= run.lidar.len() || (i < run.cam.len() && run.cam[i].t_ns <= run.lidar[j].t_ns) {
            let mut s = run.cam[i];
            if s.t_ns > 60_000_000_000 {
                s.t_ns += jump;
            }
            let _ = est.push(Stream::Cam, s);
            i += 1;
        } else {
            let _ = est.push(Stream::Lidar, run.lidar[j]);
            j += 1;
        }
        while let Some(e) = est.poll() {
            out.push(e);
        }
    }
    assert_eq!(est.stats().resets[0], 1);
    let last = out.last().unwrap();
    let truth = run.truth.offset_at(last.t_ref_ns) - 30.0;
    assert_eq!(last.state, EstimatorState::Tracking);
    assert!(
        (last.offset_s - truth).abs() < 0.01,
        "{} vs {}",
        last.offset_s,
        truth
    );
}

/// A regular run with latency steps (what the stamp cadence follows) moved to the
/// ends of the i64 range: no overflow anywhere on the path (this runs in debug,
/// where overflow panics), every estimate finite, and still locked and stepped.
#[test]
fn stepped_streams_at_the_ends_of_the_time_range_are_harmless() {
    let run = generate(Family::LoadSteps, 7, Some(40.0));
    for base in [
        i64::MAX - 20_000_000_000,
        i64::MAX - 45_000_000_000,
        i64::MIN + 1,
        i64::MIN / 2,
    ] {
        let mut est = Estimator::new(&EstimatorConfig::default());
        let moved = |s: &Sample| Sample::new(s.t_ns.saturating_add(base), s.value);
        let (mut i, mut j) = (0, 0);
        while i < run.cam.len() || j < run.lidar.len() {
            if j >= run.lidar.len() || (i < run.cam.len() && run.cam[i].t_ns <= run.lidar[j].t_ns) {
                let _ = est.push(Stream::Cam, moved(&run.cam[i]));
                i += 1;
            } else {
                let _ = est.push(Stream::Lidar, moved(&run.lidar[j]));
                j += 1;
            }
            while let Some(e) = est.poll() {
                assert!(
                    e.offset_s.is_finite() && e.offset_std_s.is_finite(),
                    "base {base}: {e:?}"
                );
            }
        }
        // the path was exercised: locked, and the camera's latency steps followed
        let st = est.stats();
        assert!(
            st.locks >= 1 && st.cadence_steps[0] >= 1,
            "base {base}: {st:?}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// Arbitrary sample sequences never panic, and every estimate is finite.
    #[test]
    fn never_panics(samples in proptest::collection::vec((any::<bool>(), any::<i64>(), any::<f64>()), 0..400)) {
        let mut est = Estimator::new(&EstimatorConfig::default());
        for (cam, t, v) in samples {
            let _ = est.push(if cam { Stream::Cam } else { Stream::Lidar }, Sample::new(t, v));
            while let Some(e) = est.poll() {
                prop_assert!(e.offset_s.is_finite() && e.offset_std_s.is_finite());
            }
        }
    }

    /// Regular streams from any start, with hostile samples mixed in (NaN, infinite
    /// and huge values, stamps a little back, rare jumps an hour ahead): no panic,
    /// estimates come out (the test above rarely gets that far: random stamps are
    /// mostly rejected or reset a stream), and every one is finite.
    #[test]
    fn hostile_samples_in_regular_streams_never_panic(
        start in -(1i64 << 60)..(1i64 << 60),
        steps in proptest::collection::vec((any::<bool>(), 5i64..60, -10.0f64..10.0, 0u16..400), 600..1200),
    ) {
        const MS: i64 = 1_000_000;
        let mut est = Estimator::new(&EstimatorConfig::default());
        let (mut tc, mut tl) = (start, start);
        let mut n = 0usize;
        for (cam, gap_ms, v, bad) in steps {
            let t = if cam { &mut tc } else { &mut tl };
            *t = t.saturating_add(gap_ms * MS);
            let mut s = Sample::new(*t, v);
            match bad {
                0 => s.value = f64::NAN,
                1 => s.value = f64::NEG_INFINITY,
                2 => s.value = 1e300,
                3 => s.t_ns = s.t_ns.saturating_sub(20 * MS),
                4 => {
                    *t = t.saturating_add(3_600_000 * MS);
                    s.t_ns = *t;
                }
                _ => {}
            }
            let _ = est.push(if cam { Stream::Cam } else { Stream::Lidar }, s);
            while let Some(e) = est.poll() {
                n += 1;
                prop_assert!(e.offset_s.is_finite() && e.offset_std_s.is_finite(), "{e:?}");
                prop_assert!(e.drift.is_finite() && e.drift_std.is_finite(), "{e:?}");
            }
        }
        prop_assert!(n > 0, "no estimate from {} samples", est.stats().accepted[0]);
    }

    /// Announced changes at any time (far past, far future, extremes) on a locked
    /// run: no panic, every estimate finite.
    #[test]
    fn announced_changes_at_any_time_are_harmless(
        times in proptest::collection::vec((0usize..400, any::<i64>(), proptest::option::of(any::<f64>())), 0..6),
    ) {
        // certain changes and hints (any step size, NaN and infinities included)
        let run = generate(Family::Robot, 4, Some(40.0));
        let mut est = Estimator::new(&EstimatorConfig::default());
        for (j, s) in run.lidar.iter().enumerate() {
            for &(at, t, hint) in &times {
                if at == j {
                    match hint {
                        Some(sd) => est.hint_change(t, sd),
                        None => est.declare_change(t),
                    }
                }
            }
            let _ = est.push(Stream::Lidar, *s);
            for c in run.cam.iter().skip(3 * j).take(3) {
                let _ = est.push(Stream::Cam, *c);
            }
            while let Some(e) = est.poll() {
                prop_assert!(e.offset_s.is_finite() && e.offset_std_s.is_finite());
            }
        }
        prop_assert!(run.lidar.len() <= 400 && est.stats().locks >= 1);
    }

    /// Plausible streams with random rates, offsets and noise: estimates stay finite.
    #[test]
    fn random_streams_stay_finite(offset in -0.4f64..0.4, cam_hz in 5.0f64..90.0, lidar_hz in 4.0f64..40.0, seed in 0u64..1000) {
        let mut est = Estimator::new(&EstimatorConfig::default());
        let s = |t: f64| (0.9 * t + seed as f64).sin() + (2.3 * t).sin() * 0.5;
        let mut tc = 0.0; let mut tl = 0.0;
        let mut n = 0;
        while tc < 30.0 || tl < 30.0 {
            if tc <= tl { let _ = est.push(Stream::Cam, Sample::new((tc * 1e9) as i64, s(tc + offset))); tc += 1.0 / cam_hz; }
            else { let _ = est.push(Stream::Lidar, Sample::new((tl * 1e9) as i64, s(tl))); tl += 1.0 / lidar_hz; }
            while let Some(e) = est.poll() {
                prop_assert!(e.offset_s.is_finite() && e.drift.is_finite() && e.offset_std_s >= 0.0);
                n += 1;
            }
        }
        // 30 s of both streams: a hop every 0.5 s once the window has filled
        prop_assert!(n > 20, "{} estimates", n);
    }
}

#[test]
fn restore_starts_holding_near_the_saved_offset_and_relocks() {
    let run = generate(Family::Robot, 21, Some(60.0));
    let mut first = Estimator::new(&EstimatorConfig::default());
    let out = replay(&run, &mut first);
    let saved = *last_tracking(&out).unwrap();
    let mut est = Estimator::new(&EstimatorConfig::default());
    est.restore(&saved, 30.0);
    assert_eq!(est.state(), EstimatorState::Holding);
    let again = replay(&run, &mut est);
    let e0 = again[0];
    assert_eq!(e0.state, EstimatorState::Holding);
    assert!((e0.offset_s - saved.offset_s).abs() < 0.002);
    assert!(e0.offset_std_s > saved.offset_std_s, "uncertainty inflated");
    assert!(again.iter().any(|e| e.state == EstimatorState::Tracking));
    let last = again.last().unwrap();
    assert!((last.offset_s - run.truth.offset_at(last.t_ref_ns)).abs() < 0.01);
}

/// A restored drift is kept: the first tracking estimates after a restart carry the
/// saved slope, not the prior's 0 (until 2026-12-06 the drift fit never heard of it and
/// the first tracking hop replaced it with 0 ± 50 ppm).
#[test]
fn a_restored_drift_is_kept_after_the_relock() {
    for seed in [1000u64, 1001, 1002] {
        let run = generate(Family::Clocks, seed, Some(120.0));
        let out = replay(&run, &mut Estimator::new(&EstimatorConfig::default()));
        // as a daemon saves it after hours of tracking: the drift learnt to 2 ppm
        let saved = vlsync_common::Estimate {
            drift: run.truth.drift,
            drift_std: 2e-6,
            ..*last_tracking(&out).unwrap()
        };
        assert!(saved.drift.abs() > 10e-6, "seed {seed}: {saved:?}");
        // the same run replayed from its start after the restore (the saved offset
        // is its last, about drift x 117 s from the start's: within the tracking range)
        // restored a second old, and ten minutes old: σ then starts beyond
        // lost_std_s, so the first blind hop goes lost, which must not drop the drift
        for age_s in [1.0, 600.0] {
            let mut est = Estimator::new(&EstimatorConfig::default());
            est.restore(&saved, age_s);
            let again = replay(&run, &mut est);
            let first = &again[first_lock(&again)..];
            for e in first
                .iter()
                .filter(|e| e.state == EstimatorState::Tracking)
                .take(10)
            {
                assert!(
                (e.drift - saved.drift).abs() <= 8e-6 && e.drift_std <= 5e-6,
                "seed {seed}, {age_s} s old: drift {} ± {} ppm after the restore, {} ± {} saved",
                e.drift * 1e6,
                e.drift_std * 1e6,
                saved.drift * 1e6,
                saved.drift_std * 1e6
            );
            }
        }
    }
}

#[test]
fn restore_from_a_wrong_offset_goes_lost_and_reacquires() {
    let run = generate(Family::Robot, 22, Some(90.0));
    let mut est = Estimator::new(&EstimatorConfig::default());
    let truth0 = run.truth.offset_at(0);
    let bogus = saved_tracking(truth0 + 0.3);
    est.restore(&bogus, 1.0);
    let out = replay(&run, &mut est);
    assert!(out.iter().any(|e| e.state == EstimatorState::Lost));
    // once the lock is found wrong (moving, no peak near it), the σ says so: the
    // offset is anywhere in the search range, not within the restored σ of it
    for e in out.iter().filter(|e| e.state == EstimatorState::Lost) {
        let err = (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs();
        assert!(
            err <= 2.0 * e.offset_std_s,
            "{err} s off with σ {} s: {e:?}",
            e.offset_std_s
        );
    }
    let last = out.last().unwrap();
    assert_eq!(last.state, EstimatorState::Tracking);
    assert!((last.offset_s - run.truth.offset_at(last.t_ref_ns)).abs() < 0.01);
}

/// The configuration's cross-key limits are where the estimator still works: the
/// shortest window that covers the reference time (2.75 s runs as 3 s in whole hops),
/// a reset jump just beyond the longest gap, the narrowest lag range (four grid steps
/// each side, around the offset), the shortest window for a lag range (its width),
/// the shortest segment (two windows), the shortest gap limit, the lowest low-pass:
/// each validated as it is, each locks and tracks within 20 ms.
#[test]
fn configurations_at_the_validated_limits_lock() {
    let d = EstimatorConfig::default();
    // each configuration made from the run's true offset at its start
    type Make = fn(f64) -> EstimatorConfig;
    let cases: [(Family, Make); 7] = [
        (Family::Robot, |_| EstimatorConfig {
            window_s: 2.75,
            step_window_s: 2.0,
            ..EstimatorConfig::default()
        }),
        (Family::Clocks, |_| EstimatorConfig {
            reset_jump_s: 0.76,
            ..EstimatorConfig::default()
        }),
        (Family::Robot, |offset| EstimatorConfig {
            max_lag_s: 0.04,
            track_range_s: 0.04,
            lag_center_s: offset,
            ..EstimatorConfig::default()
        }),
        (Family::Robot, |_| EstimatorConfig {
            window_s: 2.0,
            max_lag_s: 1.0,
            reference_lag_s: 2.0,
            step_window_s: 2.0,
            ..EstimatorConfig::default()
        }),
        (Family::Clocks, |_| EstimatorConfig {
            segment_s: 12.0,
            ..EstimatorConfig::default()
        }),
        (Family::Rates60x5, |_| EstimatorConfig {
            max_gap_s: vlsync_config::MIN_MAX_GAP_S,
            ..EstimatorConfig::default()
        }),
        (Family::Robot, |_| EstimatorConfig {
            lowpass_hz: vlsync_config::MIN_LOWPASS_HZ,
            ..EstimatorConfig::default()
        }),
    ];
    for (i, (family, make)) in cases.into_iter().enumerate() {
        let run = generate(family, 3, Some(60.0));
        let cfg = make(run.truth.offset_at(0));
        cfg.validate("limits").unwrap();
        assert!(cfg != d, "case {i} is the default");
        let out = replay(&run, &mut Estimator::new(&cfg));
        let tracking: Vec<_> = out
            .iter()
            .filter(|e| e.state == EstimatorState::Tracking)
            .collect();
        // (a 2 s window holds through more of the drive's pauses than 6 s: 58 of 117)
        assert!(
            tracking.len() > out.len() / 3,
            "case {i} ({family:?}): {} of {} tracking",
            tracking.len(),
            out.len()
        );
        let worst = tracking
            .iter()
            .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.02, "case {i} ({family:?}): {worst} s off");
    }
}

/// A saved standard deviation of 0 (a hand-edited or foreign state file; the estimator
/// never publishes one) is read as the floor of one measurement's: a wrong restored
/// offset is left as soon as with an honest σ.
#[test]
fn a_restored_zero_sigma_is_no_surer_than_one_measurement() {
    let run = generate(Family::Robot, 22, Some(90.0));
    let truth0 = run.truth.offset_at(0);
    let hops_until_lost = |std: f64| {
        let mut est = Estimator::new(&EstimatorConfig::default());
        let bogus = vlsync_common::Estimate {
            offset_std_s: std,
            drift_std: 0.0,
            ..saved_tracking(truth0 + 0.3)
        };
        est.restore(&bogus, 0.0);
        let out = replay(&run, &mut est);
        assert!(out[0].offset_std_s >= 2e-4, "σ {}", out[0].offset_std_s);
        out.iter()
            .position(|e| e.state == EstimatorState::Lost)
            .expect("the wrong offset is left")
    };
    assert_eq!(hops_until_lost(0.0), hops_until_lost(2e-4));
    assert!(
        hops_until_lost(0.0) <= hops_until_lost(1e-3),
        "as soon as with 1 ms"
    );
}

/// Pushes `run` in timestamp order with `cam_shift`/`lidar_shift` (ns) added to
/// every stamp from `at_ns` on (each stream's own clock), as live drivers deliver
/// it: interleaved by the time the samples happen, not by their shifted stamps.
fn replay_with_clock_steps(
    run: &SimRun,
    est: &mut Estimator,
    at_ns: i64,
    cam_shift: i64,
    lidar_shift: i64,
) -> Vec<vlsync_common::Estimate> {
    let mut out = Vec::new();
    let (mut i, mut j) = (0, 0);
    while i < run.cam.len() || j < run.lidar.len() {
        if j >= run.lidar.len() || (i < run.cam.len() && run.cam[i].t_ns <= run.lidar[j].t_ns) {
            let mut s = run.cam[i];
            if s.t_ns >= at_ns {
                s.t_ns += cam_shift;
            }
            let _ = est.push(Stream::Cam, s);
            i += 1;
        } else {
            let mut s = run.lidar[j];
            if s.t_ns >= at_ns {
                s.t_ns += lidar_shift;
            }
            let _ = est.push(Stream::Lidar, s);
            j += 1;
        }
        while let Some(e) = est.poll() {
            out.push(e);
        }
    }
    out
}

/// The last estimate tracks within 10 ms of the truth, `shift_s` added (what the
/// clock steps did to the offset).
fn assert_relocked(out: &[vlsync_common::Estimate], run: &SimRun, back_ns: i64, shift_s: f64) {
    let last = out.last().unwrap();
    assert_eq!(last.state, EstimatorState::Tracking, "{last:?}");
    let truth = run.truth.offset_at(last.t_ref_ns - back_ns) + shift_s;
    assert!(
        (last.offset_s - truth).abs() < 0.01,
        "{} vs {truth}",
        last.offset_s
    );
}

/// Both clocks step back by 60 s together (the drivers replay a recording again, or
/// a sensor hub restarts its clock): the offset is unchanged. The second clock's
/// step used to be measured against the first's stepped progress, so the offset
/// came out 60 s off and the search never found the data again.
#[test]
fn both_clocks_stepping_together_keep_the_offset() {
    let run = generate(Family::Robot, 9, Some(120.0));
    let back = -60_000_000_000i64;
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay_with_clock_steps(&run, &mut est, 60_000_000_000, back, back);
    assert_eq!(est.stats().resets, [1, 1], "{:?}", est.stats());
    // found where the two steps put it, not by a search elsewhere
    assert_eq!(est.stats().recentres, 0, "{:?}", est.stats());
    assert_relocked(&out, &run, back, 0.0);
    // and apart: the camera 60 s back, the LiDAR 59.5 s: the offset moves by +0.5 s
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay_with_clock_steps(&run, &mut est, 60_000_000_000, back, back + 500_000_000);
    assert_relocked(&out, &run, back + 500_000_000, 0.5);
}

/// The LiDAR's clock steps back by 30 s: the grid is on the LiDAR clock, so its
/// indices restart below the correlator's cursor (which used to wait for the data to
/// reach it again, emitting nothing).
#[test]
fn a_lidar_clock_stepping_back_is_followed() {
    let run = generate(Family::Robot, 9, Some(120.0));
    let back = -30_000_000_000i64;
    let mut est = Estimator::new(&EstimatorConfig::default());
    let out = replay_with_clock_steps(&run, &mut est, 60_000_000_000, 0, back);
    assert_eq!(est.stats().resets[1], 1);
    // a hop every 0.5 s over the whole run, the step included (236; 118 when the
    // cursor waited for the data)
    assert!(out.len() >= 225, "{} estimates", out.len());
    assert_relocked(&out, &run, back, -30.0);
}

/// A restored estimate 5 s off (a state file from another robot or setup) puts the
/// search where no data correlate: the camera data it asks for are older than the
/// correlator keeps, no hop completes (predict-only estimates, `lost`), and after 30 s
/// of LiDAR time it moves to the start's range around 0 and locks there. No tracking
/// estimate is then more than 100 ms off the truth.
#[test]
fn a_restore_far_outside_the_lag_range_is_searched_away_from() {
    let run = generate(Family::Robot, 22, Some(90.0));
    let mut est = Estimator::new(&EstimatorConfig::default());
    let bogus = saved_tracking(5.0);
    est.restore(&bogus, 1.0);
    let (out, moves) = replay_moves(&run, &mut est);
    assert!(est.stats().recentres >= 1, "{:?}", est.stats());
    // reported as it happens (what the daemon logs): from the restore's range to
    // the start's, because no hop came out
    assert_eq!(moves.len() as u64, est.stats().recentres, "{moves:?}");
    assert!((moves[0].from_s - 5.0).abs() < 0.01, "{moves:?}");
    assert!(moves[0].to_s.abs() < 0.01, "{moves:?}");
    assert_eq!(moves[0].reason, SearchMoveReason::Unserved);
    assert_eq!(moves[0].after_s, 30.0);
    assert!(out.iter().all(|e| e.offset_s.abs() < 10.0));
    let off = out
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking)
        .filter(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs() > 0.1)
        .count();
    assert_eq!(off, 0, "tracking estimates more than 100 ms off");
    assert_relocked(&out, &run, 0, 0.0);
    // absurdly far, drifting at the limit: the correlator waits for camera data 11
    // days old and no hop comes out while both streams deliver; after 30 s the
    // search moves to the start's range, the cursor back to the data
    let mut est = Estimator::new(&EstimatorConfig::default());
    est.restore(
        &vlsync_common::Estimate {
            offset_s: 1e6,
            drift: 0.1,
            ..bogus
        },
        1.0,
    );
    let (out, moves) = replay_moves(&run, &mut est);
    assert_relocked(&out, &run, 0, 0.0);
    assert_eq!(moves.len(), 1, "{moves:?}");
    assert_eq!(moves[0].reason, SearchMoveReason::Unserved);
    assert!((moves[0].from_s - 1e6).abs() < 1.0 && moves[0].to_s.abs() < 0.01);
}

/// [`replay`], collecting the search's moves as they are reported.
fn replay_moves(
    run: &SimRun,
    est: &mut Estimator,
) -> (
    Vec<vlsync_common::Estimate>,
    Vec<vlsync_estimator::SearchMove>,
) {
    let (mut out, mut moves) = (Vec::new(), Vec::new());
    for (stream, s) in run.pushes() {
        let _ = est.push(stream, s);
        while let Some(e) = est.poll() {
            out.push(e);
        }
        moves.extend(est.take_search_move());
    }
    (out, moves)
}

/// The camera alone falls silent for 10 s while the LiDAR runs on: predict-only
/// estimates, none stamped after the newest LiDAR sample, no search moved, and the
/// lock is back within a few seconds of the camera's return.
#[test]
fn a_camera_silence_is_held_over_and_relocked_in_place() {
    let run = generate(Family::Robot, 9, Some(120.0));
    let (from, to) = (60_000_000_000i64, 70_000_000_000i64);
    let mut est = Estimator::new(&EstimatorConfig::default());
    let (mut i, mut j, mut newest_lidar) = (0, 0, i64::MIN);
    let mut out = Vec::new();
    let mut future = 0;
    while i < run.cam.len() || j < run.lidar.len() {
        if j >= run.lidar.len() || (i < run.cam.len() && run.cam[i].t_ns <= run.lidar[j].t_ns) {
            let s = run.cam[i];
            i += 1;
            if s.t_ns >= from && s.t_ns < to {
                continue;
            }
            let _ = est.push(Stream::Cam, s);
        } else {
            newest_lidar = run.lidar[j].t_ns;
            let _ = est.push(Stream::Lidar, run.lidar[j]);
            j += 1;
        }
        while let Some(e) = est.poll() {
            future += usize::from(e.t_ref_ns > newest_lidar);
            out.push((newest_lidar, e));
        }
    }
    assert_eq!(future, 0, "estimates stamped after the newest LiDAR sample");
    assert_eq!(est.stats().recentres, 0, "{:?}", est.stats());
    let back = out
        .iter()
        .find(|(l, e)| *l >= to && e.state == EstimatorState::Tracking)
        .map(|(l, _)| l - to)
        .expect("relocks");
    assert!(
        back <= 6_000_000_000,
        "relocked {} s after the camera's return",
        back as f64 * 1e-9
    );
    let last = out.last().unwrap().1;
    assert!((last.offset_s - run.truth.offset_at(last.t_ref_ns)).abs() < 0.01);
}

/// The LiDAR's clock steps forward by 60 s (wherever within a hop it happens): the
/// offset follows the step, and no search moves away from it.
#[test]
fn a_lidar_clock_stepping_forward_moves_no_search() {
    let run = generate(Family::Robot, 9, Some(120.0));
    for k in 0..4 {
        let at = 60_000_000_000i64 + k * 150_000_000;
        let mut est = Estimator::new(&EstimatorConfig::default());
        let out = replay_with_clock_steps(&run, &mut est, at, 0, 60_000_000_000);
        assert_eq!(est.stats().recentres, 0, "step at {at}: {:?}", est.stats());
        assert_relocked(&out, &run, 60_000_000_000, 60.0);
    }
}

/// A lock updates only the lags near the prediction, degraded mode (a daemon over its
/// latency budget) fewer still; the acquisition after the lock is gone searches the
/// whole range again. Here the drivers restart as a new session whose offset is
/// 300 ms from the old one (both clocks back to 0): the narrowing used to outlive
/// the lock, and a daemon kept over budget searched only the ±0.2 s around the old
/// prediction, moving its search back and forth every 30 s without finding the
/// offset (an hour-long soak at 200x stayed lost for 1000 s).
#[test]
fn degraded_mode_searches_the_whole_range_once_the_lock_is_gone() {
    let first = generate(Family::Robot, 9, Some(120.0));
    let mut second = generate(Family::Robot, 10, Some(120.0));
    let shift = 300_000_000;
    for s in &mut second.lidar {
        s.t_ns += shift;
    }
    let mut est = Estimator::new(&EstimatorConfig::default());
    est.set_degraded(true);
    let _ = replay(&first, &mut est);
    let second_out = replay(&second, &mut est);
    assert_eq!(est.stats().resets, [1, 1], "{:?}", est.stats());
    let last = last_tracking(&second_out).expect("tracks in the second session");
    assert!(last.t_ref_ns > 100_000_000_000, "{last:?}");
    let truth = second.truth.offset_at(last.t_ref_ns - shift) + 0.3;
    assert!(
        (last.offset_s - truth).abs() < 0.01,
        "{} vs {truth}",
        last.offset_s
    );
    // locked early in the second session, not after a search elsewhere
    let lock = second_out
        .iter()
        .position(|e| e.state == EstimatorState::Tracking)
        .unwrap();
    assert!(lock < 40, "second session's first lock at hop {lock}");
}

/// Replays `run` with its LiDAR stamps moved so that the offset at the start is
/// `offset_s`; returns the estimates and the shift, ns.
fn replay_at_offset(
    run: &SimRun,
    est: &mut Estimator,
    offset_s: f64,
) -> (Vec<vlsync_common::Estimate>, i64) {
    let shift = ((offset_s - run.truth.offset_at(0)) * 1e9) as i64;
    let mut moved = run.clone();
    for s in &mut moved.lidar {
        s.t_ns += shift;
    }
    (replay(&moved, est), shift)
}

/// The drivers restart as a new session (both clocks back to 0) whose offset,
/// +250 ms, is 600 ms from the old one: outside the ±0.5 s range around the
/// prediction, inside the start's. The search after the clock steps lies midway
/// between the two and finds it at once (it used to search around the prediction
/// first, for 30 s of motion); the same session replayed at its old offset is found
/// there too.
#[test]
fn a_new_session_far_from_the_old_offset_is_found_without_a_search_move() {
    let first = generate(Family::Robot, 9, Some(120.0));
    let second = generate(Family::Robot, 10, Some(120.0));
    for (new_offset, label) in [(0.25, "new offset"), (-0.35, "old offset")] {
        let mut est = Estimator::new(&EstimatorConfig::default());
        let _ = replay_at_offset(&first, &mut est, -0.35);
        let (out, shift) = replay_at_offset(&second, &mut est, new_offset);
        assert_eq!(est.stats().resets, [1, 1], "{label}: {:?}", est.stats());
        assert_eq!(est.stats().recentres, 0, "{label}: {:?}", est.stats());
        let lock = out
            .iter()
            .position(|e| e.state == EstimatorState::Tracking)
            .unwrap_or_else(|| panic!("{label}: never locked"));
        assert!(lock < 30, "{label}: first lock at hop {lock}");
        let e = last_tracking(&out[lock..]).unwrap();
        let truth = second.truth.offset_at(e.t_ref_ns - shift) + shift as f64 * 1e-9;
        assert!(
            (e.offset_s - truth).abs() < 0.01,
            "{label}: {e:?} vs {truth}"
        );
    }
}

/// The start's range (`lag_center_s`) is an offset of the stamps as they come; the
/// correlator sees the internal stamps, the cadences' latency levels taken out, and
/// those levels add up every step followed, also across a clock jump. Here the
/// camera's stamps step 12 times by +25 ms (a level of +300 ms), then a new session
/// starts (both clocks back to 0) at an offset of +300 ms: +600 ms on the internal
/// stamps, outside the search midway between the prediction and the start, inside
/// the start's range once the levels are taken out of it. It used to be searched
/// for without the levels and never found (a soak's fourth session of `load-jitter`
/// stayed lost for its whole hour).
#[test]
fn the_start_range_is_searched_on_the_internal_stamps_after_latency_steps() {
    let mut first = generate(Family::Robot, 9, Some(120.0));
    let shift = ((-0.2 - first.truth.offset_at(0)) * 1e9) as i64;
    for s in &mut first.lidar {
        s.t_ns += shift;
    }
    let step = 25_000_000i64;
    for s in &mut first.cam {
        let k = ((s.t_ns - 10_000_000_000) / 8_000_000_000 + 1).clamp(0, 12);
        s.t_ns += k * step;
    }
    let second = generate(Family::Robot, 10, Some(120.0));
    let mut est = Estimator::new(&EstimatorConfig::default());
    let _ = replay(&first, &mut est);
    assert!(est.stats().cadence_steps[0] >= 12, "{:?}", est.stats());
    let (out, shift2) = replay_at_offset(&second, &mut est, 0.3);
    let (moves, lock) = (
        est.stats().recentres,
        out.iter()
            .position(|e| e.state == EstimatorState::Tracking)
            .unwrap_or_else(|| panic!("never locked: {:?}", est.stats())),
    );
    assert!(
        moves >= 1 && lock < 120,
        "lock at hop {lock} after {moves} moves"
    );
    let e = last_tracking(&out).unwrap();
    let truth = second.truth.offset_at(e.t_ref_ns - shift2) + shift2 as f64 * 1e-9;
    assert!((e.offset_s - truth).abs() < 0.01, "{e:?} vs {truth}");
}

/// Replays `second` after `first` as a new session (both clocks back to 0), the
/// camera's samples pushed `cam_late_ms` of stamp time after the LiDAR's (negative:
/// before) throughout; returns the estimates of the new session.
fn replay_new_session_skewed(
    first: &SimRun,
    second: &SimRun,
    cam_late_ms: i64,
    est: &mut Estimator,
) -> Vec<vlsync_common::Estimate> {
    let _ = replay(first, est);
    let mut out = Vec::new();
    let (cam, lid) = (&second.cam, &second.lidar);
    let (mut i, mut j) = (0, 0);
    while i < cam.len() || j < lid.len() {
        let take_cam = j >= lid.len()
            || (i < cam.len() && cam[i].t_ns + cam_late_ms * 1_000_000 <= lid[j].t_ns);
        if take_cam {
            let _ = est.push(Stream::Cam, cam[i]);
            i += 1;
        } else {
            let _ = est.push(Stream::Lidar, lid[j]);
            j += 1;
        }
        out.extend(std::iter::from_fn(|| est.poll()));
    }
    out
}

/// A new session whose two streams arrive skewed: the clock steps are judged by each
/// stream's progress against the other's (`Estimator`'s documentation), so a skew of
/// a fifth of a second still finds the new offset at once, while one of a second
/// (of stamp time: 5 ms of wall time in a 200x soak) puts the search far enough off
/// that the offset is found only by the search move 30 s of motion later. A 24-session
/// soak on 2026-12-05 met the second case once in 48 restarts. The test pins both,
/// so that a better judgement of skewed restarts shows here.
#[test]
fn a_new_session_arriving_skewed_is_found_at_once_or_after_one_search_move() {
    for (a, b) in [(1u64, 2u64), (2, 3), (3, 4)] {
        let first = generate(Family::Clocks, a, Some(300.0));
        let second = generate(Family::Clocks, b, Some(120.0));
        for late_ms in [0i64, 200, -200, 1000, -1000] {
            let mut est = Estimator::new(&EstimatorConfig::default());
            let out = replay_new_session_skewed(&first, &second, late_ms, &mut est);
            let label = format!("{a} -> {b}, camera {late_ms} ms late");
            let lock = out
                .iter()
                .find(|e| e.state == EstimatorState::Tracking)
                .unwrap_or_else(|| panic!("{label}: never locked"));
            let lock_s = lock.t_ref_ns as f64 * 1e-9;
            let moves = est.stats().recentres;
            if late_ms.abs() <= 200 {
                assert!(
                    moves == 0 && lock_s < 4.0,
                    "{label}: {moves} moves, lock {lock_s} s"
                );
            } else {
                assert!(
                    moves == 1 && lock_s < 45.0,
                    "{label}: {moves} moves, lock {lock_s} s"
                );
            }
            let last = last_tracking(&out).unwrap();
            let err = last.offset_s - second.truth.offset_at(last.t_ref_ns);
            assert!(err.abs() < 0.005, "{label}: {err} s off");
        }
    }
}

/// Deterministic standard normal draws from `seed` (the simulator's generator).
fn normal(seed: u64) -> impl FnMut() -> f64 {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    move || rng.sample(rand_distr::StandardNormal)
}

/// Both streams pure white noise at the robot families' levels (a parked robot: flow
/// and range noise), 4 x 15 minutes: never one estimate in state `tracking`. With an
/// acquisition score of 0.4 (`min_peak_score`'s, the only score gate until 2026-12-06)
/// the same noise locked: 406 tracking estimates in 8 x 10 minutes.
#[test]
fn noise_alone_never_tracks() {
    use vlsync_sim::families::{CAM_NOISE, LIDAR_NOISE};
    for seed in 1..=4u64 {
        let mut n = normal(seed);
        let mut est = Estimator::new(&EstimatorConfig::default());
        let (mut tc, mut tl) = (0.01, 0.02);
        let mut tracking = 0;
        while tl < 900.0 {
            if tc <= tl {
                let _ = est.push(Stream::Cam, Sample::new((tc * 1e9) as i64, CAM_NOISE * n()));
                tc += 1.0 / 30.0;
            } else {
                let _ = est.push(
                    Stream::Lidar,
                    Sample::new((tl * 1e9) as i64, LIDAR_NOISE * n()),
                );
                tl += 0.1;
            }
            while let Some(e) = est.poll() {
                assert_ne!(e.state, EstimatorState::Tracking, "seed {seed}: {e:?}");
                tracking += usize::from(e.state == EstimatorState::Tracking);
            }
        }
        assert_eq!(tracking, 0);
    }
}

/// A robot that parks for 10 minutes mid-run (its motion fading out over 2 s, pure
/// noise while parked, then driving again): no tracking estimate during the park is
/// more than 20 ms off, and it tracks again within 20 ms after it. The motion gate's
/// reference is the last 120 s of windows, so after two minutes parked noise passes it;
/// the acquisition score (`min_acquire_score`) must then keep noise from locking (before 2026-12-06 3 seeds gave
/// 13-22 tracking estimates beyond 20 ms in a 5-minute park, 60-103 in a 15-minute one).
#[test]
fn a_long_park_does_not_track_noise() {
    use vlsync_sim::families::{try_generate_with, CAM_NOISE, LIDAR_NOISE};
    let (park_at, park_s, ramp) = (60.0, 600.0, 2.0);
    let envelope = park_envelope(park_at, park_s, ramp);
    for seed in 1..=2u64 {
        let run =
            try_generate_with(Family::Robot, seed, Some(park_at + park_s + 90.0), 0.0).unwrap();
        let mut n = normal(100 + seed);
        let mut est = Estimator::new(&EstimatorConfig::default());
        let mut out = vec![];
        for (stream, s) in run.pushes() {
            let t = s.t_ns as f64 * 1e-9;
            // the event time on the LiDAR clock (the offset is constant in this family)
            let (tau, sd) = match stream {
                Stream::Cam => (t + run.truth.offset_at(s.t_ns), CAM_NOISE),
                Stream::Lidar => (t, LIDAR_NOISE),
            };
            let v = envelope(tau) * s.value + sd * n();
            let _ = est.push(stream, Sample::new(s.t_ns, v));
            out.extend(std::iter::from_fn(|| est.poll()));
        }
        let err =
            |e: &vlsync_common::Estimate| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs();
        let parked = |e: &vlsync_common::Estimate| {
            let t = e.t_ref_ns as f64 * 1e-9;
            t > park_at + ramp && t < park_at + ramp + park_s
        };
        for e in out
            .iter()
            .filter(|e| e.state == EstimatorState::Tracking && parked(e))
        {
            assert!(
                err(e) <= 0.02,
                "seed {seed}: parked, tracking {} ms off: {e:?}",
                err(e) * 1e3
            );
        }
        let after = park_at + park_s + 2.0 * ramp + 15.0;
        assert!(
            out.iter().any(|e| e.state == EstimatorState::Tracking
                && e.t_ref_ns as f64 * 1e-9 > after
                && err(e) <= 0.02),
            "seed {seed}: no tracking estimate within 20 ms after the park"
        );
    }
}

/// A LiDAR front-end fitting the wall ahead and the wall behind publishes one stream
/// at twice its rotation rate while both walls are seen, and at the rotation rate
/// while one is out of range (a long room): here a `rates-15x20` run whose 20 Hz
/// LiDAR loses every other sample outside two stretches. The stamps' cadence learnt
/// at 10 Hz must take the 20 Hz stretches for what they are: until 2026-12-07 it moved
/// every sample between two frames to the next frame's point, 50 ms late, and the
/// rendered long room read 4-8 ms off (docs/accuracy.md, "A long room").
#[test]
fn a_lidar_stream_whose_rate_doubles_keeps_its_stamps() {
    let mut worst = 0.0f64;
    for seed in [1, 2, 3] {
        let mut run = generate(Family::Rates15x20, seed, Some(100.0));
        let t0 = run.lidar[0].t_ns;
        let both = |t: i64| {
            let s = (t - t0) as f64 * 1e-9;
            (30.0..55.0).contains(&s) || (75.0..85.0).contains(&s)
        };
        let mut k = 0usize;
        run.lidar.retain(|s| {
            k += 1;
            both(s.t_ns) || k % 2 == 1
        });
        let lidar_cadence_off = EstimatorConfig {
            cadence: vlsync_config::CadenceStreams::Camera,
            ..EstimatorConfig::default()
        };
        let mut with = Estimator::new(&EstimatorConfig::default());
        let (mae, _) = locked_errors(&replay(&run, &mut with), &run);
        let mut without = Estimator::new(&lidar_cadence_off);
        let (mae_off, _) = locked_errors(&replay(&run, &mut without), &run);
        eprintln!(
            "seed {seed}: MAE {:.3} ms with the LiDAR's cadence, {:.3} ms without; {} relearns",
            mae * 1e3,
            mae_off * 1e3,
            with.stats().cadence_relearns[1]
        );
        worst = worst.max(mae - mae_off);
    }
    assert!(
        worst < 0.1e-3,
        "the cadence costs up to {:.3} ms",
        worst * 1e3
    );
}

/// A camera driver restarted on the same clock: 3 s of silence, then frames at a new
/// phase (12 ms later in each period: a new capture stream), their stamps as right as
/// before. The frames moved, not their latency, so the published offset must not move:
/// no cadence step, and the estimates after the return as close to the truth as before
/// the silence. (Read as a latency step, the phase used to put the estimates 12 ms off
/// until the correlation's own step test caught up.)
#[test]
fn a_camera_restarted_at_a_new_phase_keeps_the_offset() {
    let run = generate(Family::Robot, 9, Some(120.0));
    let (from, to) = (60_000_000_000i64, 63_000_000_000i64);
    let phase_ns = 12_000_000i64;
    // the camera's signature at a time between its frames, interpolated
    let value_at = |t: i64| -> f64 {
        let k = run
            .cam
            .partition_point(|s| s.t_ns <= t)
            .clamp(1, run.cam.len() - 1);
        let (a, b) = (run.cam[k - 1], run.cam[k]);
        let w = (t - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
        a.value + w.clamp(0.0, 1.0) * (b.value - a.value)
    };
    let mut cam: Vec<Sample> = Vec::new();
    for s in &run.cam {
        if s.t_ns < from {
            cam.push(*s);
        } else if s.t_ns >= to {
            let t = s.t_ns + phase_ns;
            cam.push(Sample::new(t, value_at(t)));
        }
    }
    let mut est = Estimator::new(&EstimatorConfig::default());
    let (mut i, mut j) = (0, 0);
    let mut out = Vec::new();
    while i < cam.len() || j < run.lidar.len() {
        if j >= run.lidar.len() || (i < cam.len() && cam[i].t_ns <= run.lidar[j].t_ns) {
            let _ = est.push(Stream::Cam, cam[i]);
            i += 1;
        } else {
            let _ = est.push(Stream::Lidar, run.lidar[j]);
            j += 1;
        }
        while let Some(e) = est.poll() {
            out.push(e);
        }
    }
    assert_eq!(est.stats().cadence_steps, [0, 0], "{:?}", est.stats());
    let worst = |lo: i64, hi: i64| {
        out.iter()
            .filter(|e| e.state == EstimatorState::Tracking && (lo..hi).contains(&e.t_ref_ns))
            .map(|e| (e.offset_s - run.truth.offset_at(e.t_ref_ns)).abs())
            .fold(0.0f64, f64::max)
    };
    let (before, after) = (worst(30_000_000_000, from), worst(to, 120_000_000_000));
    assert!(
        after < before.max(0.004) + 0.002,
        "after the restart up to {:.2} ms off, before it {:.2} ms",
        after * 1e3,
        before * 1e3
    );
}

/// The motion's envelope of a park at `park_at` s (LiDAR time) lasting `park_s`: the
/// motion fades out over `ramp` s, is 0 in the park, and fades in over `ramp` s.
fn park_envelope(park_at: f64, park_s: f64, ramp: f64) -> impl Fn(f64) -> f64 + Copy {
    move |tau: f64| {
        let x = tau - park_at;
        if x < 0.0 || x > park_s + 2.0 * ramp {
            1.0
        } else if x < ramp {
            0.5 * (1.0 + (std::f64::consts::PI * x / ramp).cos())
        } else if x < ramp + park_s {
            0.0
        } else {
            0.5 * (1.0 - (std::f64::consts::PI * (x - ramp - park_s) / ramp).cos())
        }
    }
}

/// A robot run of `family` (seed `seed`) with the camera clock drifting `drift_ppm`
/// away from the start's range (sign taken from the first offset), 300 s of motion, a
/// 50-minute park, 240 s of motion: the estimates, the search moves, the truth and
/// the park, from the motion's fading out to its end (LiDAR s).
#[allow(clippy::type_complexity)]
fn park_with_drift(
    family: Family,
    seed: u64,
    drift_ppm: f64,
) -> (
    Vec<vlsync_common::Estimate>,
    Vec<vlsync_estimator::SearchMove>,
    impl Fn(i64) -> f64,
    std::ops::Range<f64>,
) {
    use vlsync_sim::families::{try_generate_with, CAM_NOISE, LIDAR_NOISE};
    let (park_at, park_s, ramp, after_s) = (300.0, 3000.0, 2.0, 240.0);
    let envelope = park_envelope(park_at, park_s, ramp);
    let run = try_generate_with(
        family,
        seed,
        Some(park_at + park_s + 2.0 * ramp + after_s),
        0.0,
    )
    .unwrap();
    let o0 = run.truth.offset_at(run.lidar[0].t_ns);
    // away from the start's range (centred on 0)
    let drift = drift_ppm * 1e-6 * o0.signum();
    let t0 = run.lidar[0].t_ns as f64 * 1e-9;
    let truth = move |t_lidar_ns: i64| o0 + drift * (t_lidar_ns as f64 * 1e-9 - t0);
    let mut n = normal(77);
    let mut pushes: Vec<(Stream, Sample)> = run
        .pushes()
        .into_iter()
        .map(|(stream, s)| {
            let t = s.t_ns as f64 * 1e-9;
            match stream {
                Stream::Cam => {
                    // the event's LiDAR time; the camera's stamp is that less the
                    // drifting offset
                    let tau = t + o0;
                    let v = envelope(tau) * s.value + CAM_NOISE * n();
                    let t_c = tau - (o0 + drift * (tau - t0));
                    (stream, Sample::new((t_c * 1e9).round() as i64, v))
                }
                Stream::Lidar => (
                    stream,
                    Sample::new(s.t_ns, envelope(t) * s.value + LIDAR_NOISE * n()),
                ),
            }
        })
        .collect();
    pushes.sort_by_key(|(_, s)| s.t_ns);
    let mut est = Estimator::new(&EstimatorConfig::default());
    let (mut out, mut moves) = (vec![], vec![]);
    for (stream, s) in pushes {
        let _ = est.push(stream, s);
        out.extend(std::iter::from_fn(|| est.poll()));
        moves.extend(est.take_search_move());
    }
    (out, moves, truth, park_at..park_at + park_s + 2.0 * ramp)
}

/// Two clocks 250 ppm apart and the robot parked for 50 minutes: the offset moves by
/// 0.75 s meanwhile, out of the range the lock was lost in (and of the start's). The lost
/// search must follow the drift's prediction, as the published offset does; it used to
/// stay on the two ranges it knew and never find the offset again.
#[test]
fn a_lost_search_follows_the_drift_through_a_long_park() {
    let (out, moves, truth, park) = park_with_drift(Family::Robot, 5, 250.0);
    let resumed = park.end;
    let moved = (truth(out.last().unwrap().t_ref_ns) - truth(out[0].t_ref_ns)).abs();
    assert!(moved > 0.75, "the offset moved by {moved} s only");
    // only to follow the drift: the park's noise moves it nowhere else
    assert!(
        !moves.is_empty() && moves.iter().all(|m| m.reason == SearchMoveReason::Drift),
        "{moves:?}"
    );
    let back = out.iter().find(|e| {
        e.state == EstimatorState::Tracking
            && e.t_ref_ns as f64 * 1e-9 > resumed
            && (e.offset_s - truth(e.t_ref_ns)).abs() <= 0.02
    });
    let last = out.last().unwrap();
    eprintln!(
        "back {:?} s after the park; {} search moves",
        back.map(|e| e.t_ref_ns as f64 * 1e-9 - resumed),
        moves.len()
    );
    assert!(
        back.is_some_and(|e| e.t_ref_ns as f64 * 1e-9 < resumed + 120.0),
        "not tracking within 20 ms in the 120 s after the park (found at {:?} s); last: {} \
         ms off, {:?}",
        back.map(|e| e.t_ref_ns as f64 * 1e-9 - resumed),
        (last.offset_s - truth(last.t_ref_ns)) * 1e3,
        last.state,
    );
}

/// The same park with clocks that do not drift apart, at an offset of 0.45 s (a lock
/// near the range's edge): no search moves at all, and the lock comes back.
#[test]
fn a_park_without_drift_moves_no_search_for_drift() {
    let (out, moves, truth, park) = park_with_drift(Family::BigOffset, 5, 0.0);
    let at = |e: &vlsync_common::Estimate| e.t_ref_ns as f64 * 1e-9;
    let on_truth = |e: &vlsync_common::Estimate| (e.offset_s - truth(e.t_ref_ns)).abs() <= 0.02;
    // a lock on the truth before the park, and a search during it: the lock is lost
    // in the park, so that "no search moves" below is about a lost search, not about
    // a lock that never was or never went
    assert!(
        out.iter()
            .any(|e| e.state == EstimatorState::Tracking && at(e) < park.start && on_truth(e)),
        "no lock on the truth before the park at {} s",
        park.start
    );
    assert!(
        out.iter()
            .any(|e| e.state == EstimatorState::Lost && park.contains(&at(e))),
        "the lock was never lost during the park ({park:?} s)"
    );
    // the park's noise passes the motion gate after two minutes, but is no motion
    // like the lock's: no search moves (it moved every 30 s, between the start's
    // range and the lock's, before `Estimator::moving_as_locked`)
    assert!(moves.is_empty(), "{moves:?}");
    assert!(
        out.iter()
            .any(|e| e.state == EstimatorState::Tracking && at(e) > park.end && on_truth(e)),
        "not tracking on the truth after the park"
    );
}
