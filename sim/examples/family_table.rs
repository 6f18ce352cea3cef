//! Prints, per family over seeds 0..5: the Cramér-Rao bound (whole run and median per
//! 6 s window), the seed baseline's score, and the baseline's MAE when it is handed the
//! LiDAR signature with the polarity already corrected (negated for the robot families).
//!
//! `cargo run --release -p vlsync-sim --example family_table`

use vlsync_sim::{baseline, crb, generate, score, Family};

fn main() {
    println!(
        "{:<16} {:>10} {:>10} {:>12} {:>10} {:>9} {:>14}",
        "family", "CRB run", "CRB 6 s", "base MAE", "base p95", "base >20", "MAE pol-fixed"
    );
    for f in Family::ALL {
        let mut scores = Vec::new();
        let mut fixed = Vec::new();
        let (mut c_run, mut c_win) = (0.0, 0.0);
        let seeds = 5;
        for seed in 0..seeds {
            let run = generate(f, seed, None);
            c_run += run.crb_std_s / seeds as f64;
            c_win += crb::crb_window_std_s(&run, 6.0).unwrap_or(f64::NAN) / seeds as f64;
            let est = baseline::seed_chunked(&run.cam, &run.lidar, run.cam_hz);
            scores.push(score::score_pairs(&est, &run));
            let sign = run.polarity.sign();
            let lidar: Vec<_> = run
                .lidar
                .iter()
                .map(|x| vlsync_common::Sample::new(x.t_ns, sign * x.value))
                .collect();
            let est = baseline::seed_chunked(&run.cam, &lidar, run.cam_hz);
            fixed.push(score::score_pairs(&est, &run));
        }
        let s = score::Score::aggregate(&scores);
        let g = score::Score::aggregate(&fixed);
        println!(
            "{:<16} {:>7.2} ms {:>7.2} ms {:>9.1} ms {:>7.1} ms {:>8.0} % {:>11.1} ms",
            f.name(),
            c_run * 1e3,
            c_win * 1e3,
            s.mae_s * 1e3,
            s.p95_s * 1e3,
            s.share_over_20ms * 100.0,
            g.mae_s * 1e3
        );
    }
}
