//! After construction, pushing samples and polling estimates allocates nothing.
//! `vlsync-alloc-count`'s allocator counts this thread's allocations.

use vlsync_common::{Sample, Stream};
use vlsync_config::EstimatorConfig;
use vlsync_estimator::Estimator;

mod common;

#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

#[test]
fn push_and_poll_allocate_nothing() {
    // an hour of a simulated run with drops, jitter, a gap, load steps, hints and bad
    // samples (long enough for a rare periodic allocation to show),
    // generated before arming so only the estimator is observed
    let run = vlsync_sim::families::generate(vlsync_sim::families::Family::Clocks, 7, Some(3600.0));
    let steps =
        vlsync_sim::families::generate(vlsync_sim::families::Family::LoadSteps, 3, Some(60.0));
    // the second configuration pushes as the daemon does: push_urgent, poll, idle
    for (cfg, urgent) in [
        (EstimatorConfig::default(), false),
        (
            EstimatorConfig {
                max_lag_s: 2.0,
                window_s: 12.0,
                ..EstimatorConfig::default()
            },
            true,
        ),
    ] {
        let mut est = Estimator::new(&cfg);
        // pushes one sample; returns the estimates it polled (the daemon's order polls
        // before `idle`, the other leaves them to the loop)
        let push = |est: &mut Estimator, stream: Stream, s: Sample| -> usize {
            if urgent {
                let _ = est.push_urgent(stream, s);
                let n = std::iter::from_fn(|| est.poll()).count();
                est.idle();
                n
            } else {
                let _ = est.push(stream, s);
                0
            }
        };
        let mut n_est = 0usize;
        let before = vlsync_alloc_count::this_thread();
        for r in [&run, &steps] {
            let (mut i, mut j) = (0, 0);
            while i < r.cam.len() || j < r.lidar.len() {
                if j >= r.lidar.len() || (i < r.cam.len() && r.cam[i].t_ns <= r.lidar[j].t_ns) {
                    n_est += push(&mut est, Stream::Cam, r.cam[i]);
                    i += 1;
                } else {
                    // a load hint every 30 s (right or wrong): the mixture and
                    // the segment's restart and revert allocate nothing either
                    if j % 300 == 150 {
                        est.hint_change(r.lidar[j].t_ns, vlsync_estimator::HINT_STEP_STD_S);
                    }
                    n_est += push(&mut est, Stream::Lidar, r.lidar[j]);
                    j += 1;
                }
                if i % 97 == 0 {
                    n_est += push(&mut est, Stream::Cam, Sample::new(0, f64::NAN));
                }
                while est.poll().is_some() {
                    n_est += 1;
                }
            }
            // degraded mode switches, too
            est.set_degraded(true);
        }
        let allocs = vlsync_alloc_count::this_thread() - before;
        // a zero below means none only if the allocator counts
        vlsync_alloc_count::assert_counting();
        assert!(n_est > 100, "estimates: {n_est}");
        // and the paths named above ran while counting
        let st = est.stats();
        assert!(st.locks >= 1 && st.steps >= 1 && st.outliers >= 1, "{st:?}");
        assert!(st.cadence_steps[0] >= 1, "{st:?}");
        assert!(
            st.gaps[1] >= 1 && st.resets.iter().sum::<u64>() >= 1,
            "{st:?}"
        );
        assert!(st.rejected[0].iter().sum::<u64>() >= 1, "{st:?}");
        assert_eq!(allocs, 0, "allocations on the hot path");
    }
}

/// The rare paths allocate nothing either, counted from the first push: a restored
/// lock found wrong (lost, its search moved), a camera restarted at a new frame
/// phase after a silence (the cadence relearns its grid), a LiDAR silence long
/// enough to hold, degraded mode switched on and off while locked. Each is asserted
/// to have run.
#[test]
fn rare_paths_allocate_nothing() {
    use vlsync_common::EstimatorState;
    use vlsync_sim::families::{generate, Family};
    let run = generate(Family::Robot, 22, Some(240.0));
    let s = |t: f64| (t * 1e9) as i64;
    // the camera silent 60-63 s, then 12 ms later in its frame phase (a driver restart)
    let phase = 12_000_000;
    let cam: Vec<Sample> = run
        .cam
        .iter()
        .filter(|x| !(s(60.0)..s(63.0)).contains(&x.t_ns))
        .map(|x| {
            if x.t_ns >= s(63.0) {
                Sample::new(x.t_ns + phase, x.value)
            } else {
                *x
            }
        })
        .collect();
    // the LiDAR silent 150-170 s
    let mut lidar: Vec<Sample> = run
        .lidar
        .iter()
        .filter(|x| !(s(150.0)..s(170.0)).contains(&x.t_ns))
        .copied()
        .collect();
    // then the run again from 250 s (both streams reset: a clock jump) with the
    // offset 0.6 s further, out of both ranges the search alternates between: it
    // moves every 30 s
    let mut cam = cam;
    let (again, further) = (s(250.0), s(0.6));
    cam.extend(
        run.cam
            .iter()
            .map(|x| Sample::new(x.t_ns + again - further, x.value)),
    );
    lidar.extend(
        run.lidar
            .iter()
            .map(|x| Sample::new(x.t_ns + again, x.value)),
    );
    let truth0 = run.truth.offset_at(0);
    let mut est = Estimator::new(&EstimatorConfig::default());
    // a state file 0.3 s off (restored before the loop, as the daemon does)
    est.restore(&common::saved_tracking(truth0 + 0.3), 1.0);
    let (mut states, mut moves, mut switched) = ([0usize; 4], 0usize, 0);
    // the state when degraded mode was switched, and whether the restored lock was
    // lost before the LiDAR's silence
    let mut last_state = EstimatorState::Acquiring;
    let mut switched_in = [EstimatorState::Acquiring; 2];
    let mut lost_early = false;
    let before = vlsync_alloc_count::this_thread();
    let (mut i, mut j) = (0, 0);
    while i < cam.len() || j < lidar.len() {
        if j >= lidar.len() || (i < cam.len() && cam[i].t_ns <= lidar[j].t_ns) {
            let _ = est.push(Stream::Cam, cam[i]);
            i += 1;
        } else {
            let t = lidar[j].t_ns;
            // degraded mode on at 100 s and off at 120 s, while locked
            if (t >= s(100.0) && switched == 0) || (t >= s(120.0) && switched == 1) {
                est.set_degraded(switched == 0);
                switched_in[switched] = last_state;
                switched += 1;
            }
            let _ = est.push(Stream::Lidar, lidar[j]);
            j += 1;
        }
        while let Some(e) = est.poll() {
            states[e.state as usize] += 1;
            last_state = e.state;
            lost_early |= e.state == EstimatorState::Lost && e.t_ref_ns < s(150.0);
        }
        moves += est.take_search_move().is_some() as usize;
    }
    let allocs = vlsync_alloc_count::this_thread() - before;
    vlsync_alloc_count::assert_counting();
    // each path ran while counting (here: 2 locks, 85 holding and 508 lost
    // estimates, 6 search moves, a relearn and a reset per stream)
    let st = est.stats().clone();
    assert_eq!(switched, 2);
    assert!(
        switched_in.iter().all(|&st| st == EstimatorState::Tracking),
        "degraded mode switched while {switched_in:?}"
    );
    assert!(lost_early, "the restored lock, 0.3 s off, was never lost");
    assert!(
        st.locks >= 2 && states[2] >= 1 && states[3] >= 1,
        "{st:?} {states:?}"
    );
    assert!(st.recentres >= 1 && moves >= 1, "{st:?} {moves}");
    assert!(
        st.cadence_relearns.iter().all(|&n| n >= 1) && st.resets.iter().all(|&n| n >= 1),
        "{st:?}"
    );
    assert_eq!(allocs, 0, "allocations on the rare paths");
}
