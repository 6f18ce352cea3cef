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
fn recorded_load_steps_are_followed_to_a_fraction_of_a_millisecond() {
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
    // the stamp the estimate stands for (internal + level) against the true latency,
    // the mean over the 2 s around each sample; away from the two load changes
    let true_lat = |i: usize| {
        let (lo, hi) = (i.saturating_sub(30), (i + 30).min(rows.len() - 1));
        rows[lo..=hi]
            .iter()
            .map(|r| (r.1 - r.0) as f64)
            .sum::<f64>()
            / (hi - lo + 1) as f64
    };
    let t0 = rows[0].0;
    let changes = [8.0, 38.0];
    let mut errs = Vec::new();
    for i in 60..rows.len() - lag {
        let t = (rows[i].0 - t0) as f64 * 1e-9;
        if changes.iter().any(|c| (t - c).abs() < 2.5) {
            continue;
        }
        let eff = (internal[i] - rows[i].0) as f64 + level[i];
        errs.push(((eff - true_lat(i)) * 1e-6).abs());
    }
    errs.sort_by(f64::total_cmp);
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    let p95 = errs[errs.len() * 95 / 100];
    assert!(
        mean < 0.3 && p95 < 1.0,
        "mean {mean:.3} ms, p95 {p95:.3} ms"
    );
    // the levels differ by the load's 12 ms between loaded and idle stretches
    let at = |t: f64| {
        let i = rows
            .iter()
            .position(|r| (r.0 - t0) as f64 * 1e-9 >= t)
            .expect("time");
        level[i]
    };
    let (idle, loaded) = (at(5.0), at(25.0));
    assert!(
        ((loaded - idle) * 1e-6 - 12.0).abs() < 1.0,
        "{:.2} ms",
        (loaded - idle) * 1e-6
    );
    // the grid the correlator sees stays put (the frames' times, up to a constant)
    let ie: Vec<f64> = (60..rows.len())
        .map(|i| (internal[i] - rows[i].0) as f64 * 1e-6)
        .collect();
    let mut sorted = ie.clone();
    sorted.sort_by(f64::total_cmp);
    let spread = sorted[sorted.len() * 99 / 100] - sorted[sorted.len() / 100];
    assert!(spread < 1.5, "internal stamps wander {spread:.2} ms");
}
