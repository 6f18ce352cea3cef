//! The stamp cadence on stamps recorded live: a camera stamped in software after
//! 12 ms of processing per frame, on this project's 2-core VM, while stress-ng
//! loaded every core for 30 s (`tests/data/software_stamps_under_load.csv`, cut from
//! a `vlsync-loadtest --profile steps --cam-frame-cpu-ms 12` run's truth file). The
//! load moves the stamps 12 ms later, with 1-2 ms of jitter and frames skipped
//! (midpoint stamps half a period off the grid); the events are the true frame
//! times.

use vlsync_estimator::cadence::{Cadence, CadenceParams, Kind};

/// `(event, stamp)`, ns.
fn recorded() -> Vec<(i64, i64)> {
    let text = include_str!("data/software_stamps_under_load.csv");
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("event"))
        .map(|l| {
            let (e, s) = l.split_once(',').expect("two columns");
            (
                e.parse::<i64>().expect("event") * 1000,
                s.parse::<i64>().expect("stamp") * 1000,
            )
        })
        .collect()
}

#[test]
fn recorded_load_steps_leave_the_stamps_and_reach_the_level() {
    let rows = recorded();
    assert!(rows.len() > 1400);
    let mut c = Cadence::new(CadenceParams::default());
    // the level of each sample as the estimator asks for it, 3 s (90 samples) later
    let lag = 90;
    let mut internal = Vec::with_capacity(rows.len());
    let mut level = vec![f64::NAN; rows.len()];
    for (i, &(_, s)) in rows.iter().enumerate() {
        internal.push(c.push(s, if i == 0 { Kind::First } else { Kind::Normal }));
        if i >= lag {
            level[i - lag] = c.level_at(internal[i - lag]).0;
        }
    }
    assert_eq!(c.relearns(), 0);
    assert!((2..=8).contains(&c.steps()), "{} steps", c.steps());
    // means over the 2 s around each sample
    let mean = |i: usize, f: &dyn Fn(usize) -> f64| {
        let (lo, hi) = (i.saturating_sub(30), (i + 30).min(rows.len() - 1));
        (lo..=hi).map(f).sum::<f64>() / (hi - lo + 1) as f64
    };
    let true_lat = |i: usize| mean(i, &|j| (rows[j].1 - rows[j].0) as f64);
    let internal_lat = |i: usize| mean(i, &|j| (internal[j] - rows[j].0) as f64);
    // what the estimate stands for (internal stamps, plus the level looked up 3 s
    // later) against the true latency; away from the two load changes
    let t0 = rows[0].0;
    let changes = [8.0, 38.0];
    let away = |i: usize| {
        let t = (rows[i].0 - t0) as f64 * 1e-9;
        !changes.iter().any(|c| (t - c).abs() < 2.5)
    };
    let mut errs: Vec<f64> = (60..rows.len() - lag)
        .filter(|&i| away(i))
        .map(|i| ((internal_lat(i) + level[i] - true_lat(i)) * 1e-6).abs())
        .collect();
    errs.sort_by(f64::total_cmp);
    let mean_err = errs.iter().sum::<f64>() / errs.len() as f64;
    let p95 = errs[errs.len() * 95 / 100];
    assert!(
        mean_err < 0.3 && p95 < 1.0,
        "mean {mean_err:.3} ms, p95 {p95:.3} ms"
    );
    // the levels differ by the load's 12 ms between loaded and idle stretches, and
    // the internal stamps carry none of it (the correlator sees no step)
    let at = |t: f64| {
        rows.iter()
            .position(|r| (r.0 - t0) as f64 * 1e-9 >= t)
            .expect("time")
    };
    let (idle, loaded) = (at(5.0), at(25.0));
    let level_step = (level[loaded] - level[idle]) * 1e-6;
    assert!((level_step - 12.0).abs() < 1.0, "{level_step:.2} ms");
    let raw_step = (true_lat(loaded) - true_lat(idle)) * 1e-6;
    let internal_step = (internal_lat(loaded) - internal_lat(idle)) * 1e-6;
    assert!(
        raw_step > 11.0 && internal_step.abs() < 1.0,
        "{raw_step:.2} {internal_step:.2}"
    );
}
