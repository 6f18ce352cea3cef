//! The seed article's own 12 s run (its exact draws, `data/seed_article/`, written by
//! `docs/analysis/seed_article_run.py`) through `vlsyncd replay`, as a user would
//! replay it, scored against its truth; and the seed's chunked algorithm with its two
//! bugs fixed (`vlsync_sim::baseline`, the bench's baseline) on the same data.
//!
//! Measured when this test was written (2026-12-07): vlsync MAE 4.149 ms, max 7.135 ms
//! over 13 locked estimates, final drift 11819 ± 981 ppm against 11858; the baseline
//! 58.6 ms. Issue 2's target for this run is 4 ms: the bounds below guard what is
//! reached, they do not claim the target.

use std::path::{Path, PathBuf};
use std::process::Command;
use vlsync_common::Sample;
use vlsync_sim::baseline::seed_chunked;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/seed_article")
        .join(name)
}

/// `t,value` rows (seconds) as samples.
fn samples(name: &str) -> Vec<Sample> {
    std::fs::read_to_string(data(name))
        .expect("fixture")
        .lines()
        .skip(1)
        .map(|l| {
            let mut f = l.split(',').map(|x| x.parse::<f64>().expect("number"));
            let (t, v) = (f.next().expect("t"), f.next().expect("value"));
            Sample::new((t * 1e9).round() as i64, v)
        })
        .collect()
}

/// The article's truth on the LiDAR clock: offset(t_L) = t_L - (t_L - 0.18) / 1.012.
fn truth(t_l: f64) -> f64 {
    t_l - (t_l - 0.18) / 1.012
}

/// The number after `key` in `line` (up to the next space or comma).
fn number_after(line: &str, key: &str) -> f64 {
    let rest = &line[line
        .find(key)
        .unwrap_or_else(|| panic!("`{key}` in `{line}`"))
        + key.len()..];
    rest.trim_start()
        .split([' ', ','])
        .next()
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("a number after `{key}` in `{line}`"))
}

#[test]
fn the_articles_own_run_replays_within_a_few_milliseconds() {
    let dir = std::env::temp_dir().join(format!("vlsync-seed-article-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let est = dir.join("est.csv");
    let out = Command::new(env!("CARGO_BIN_EXE_vlsyncd"))
        .arg("replay")
        .arg("--cam")
        .arg(data("cam.csv"))
        .arg("--lidar")
        .arg(data("lidar.csv"))
        .arg("--truth")
        .arg(data("truth.csv"))
        .arg("--out")
        .arg(&est)
        .output()
        .expect("run vlsyncd replay");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "vlsyncd replay failed:\n{err}");
    let line = err
        .lines()
        .find(|l| l.starts_with("error vs truth"))
        .unwrap_or_else(|| panic!("no error line in:\n{err}"));
    let (mae, max) = (number_after(line, "MAE"), number_after(line, "max"));
    let locked = number_after(line, "over");
    eprintln!("{line}");
    assert!(locked >= 12.0, "{line}");
    assert!(mae <= 4.5 && max <= 9.0, "{line}");

    // the estimates' own columns: every locked one positive polarity and within 2σ + 1 ms,
    // the drift learnt by the end (the run's true 0.012 / 1.012 s/s)
    let text = std::fs::read_to_string(&est).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| head.iter().position(|h| *h == n).unwrap();
    let mut last = None;
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        if f[col("state")] != "tracking" {
            continue;
        }
        let num = |n: &str| f[col(n)].parse::<f64>().unwrap();
        let e = num("offset") - truth(num("t"));
        assert_eq!(f[col("polarity")], "positive", "{l}");
        assert!(e.abs() <= 2.0 * num("offset_std") + 1e-3, "{l}: error {e}");
        last = Some((num("drift"), num("drift_std")));
    }
    let (drift, drift_std) = last.expect("tracking estimates");
    let true_drift = 0.012 / 1.012;
    assert!(
        (drift - true_drift).abs() <= 3.0 * drift_std && drift_std < 0.002,
        "final drift {drift} ± {drift_std} against {true_drift}"
    );
    std::fs::remove_dir_all(&dir).ok();

    // the seed's algorithm, its sign and lag range fixed, on the same data: its
    // estimates sit on the 33 ms grid and behind the drift
    let base = seed_chunked(&samples("cam.csv"), &samples("lidar.csv"), 30.0);
    assert_eq!(base.len(), 8);
    let base_mae = base
        .iter()
        .map(|&(t, o)| (o - truth(t as f64 * 1e-9)).abs())
        .sum::<f64>()
        / base.len() as f64;
    eprintln!("baseline MAE {:.1} ms", base_mae * 1e3);
    assert!(
        base_mae > 10.0 * mae * 1e-3,
        "baseline {base_mae} s, vlsync {mae} ms"
    );
}
