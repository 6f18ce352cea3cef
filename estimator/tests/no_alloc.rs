//! After construction, pushing samples and polling estimates allocates nothing.
//! `vlsync-alloc-count`'s allocator counts this thread's allocations.

use vlsync_common::{Sample, Stream};
use vlsync_config::EstimatorConfig;
use vlsync_estimator::Estimator;

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
