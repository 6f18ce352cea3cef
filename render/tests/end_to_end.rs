//! End to end through the real front-ends: rendered frames → signature-cam,
//! rendered scans → signature-lidar, both → the estimator, scored against the
//! renderer's truth.

use std::time::Instant;
use vlsync_common::{Estimate, Sample, Stream};
use vlsync_config::EstimatorConfig;
use vlsync_estimator::Estimator;
use vlsync_render::score::{score, Score};
use vlsync_render::{Event, RenderConfig, Renderer};
use vlsync_signature_cam as cam;
use vlsync_signature_lidar as lidar;

struct Outcome {
    score: Score,
    estimates: Vec<Estimate>,
    cam: Vec<Sample>,
    lidar: Vec<Sample>,
    truth: vlsync_sim::Truth,
}

fn pipeline(
    cfg: RenderConfig,
    cam_stamping: cam::Stamping,
    lidar_stamping: lidar::Stamping,
    lidar_half_width_deg: f64,
) -> Outcome {
    let t0 = Instant::now();
    let mut r = Renderer::new(cfg).expect("valid config");
    let truth = r.truth().clone();
    let mut cp = cam::SignatureProcessor::new(cam::SignatureConfig {
        stamping: cam_stamping,
        ..cam::SignatureConfig::default()
    })
    .unwrap();
    let mut lp = lidar::SignatureProcessor::new(lidar::SignatureConfig {
        stamping: lidar_stamping,
        window_half_width_rad: lidar_half_width_deg.to_radians(),
        ..lidar::SignatureConfig::default() // window straight ahead
    })
    .unwrap();
    let mut est = Estimator::new(&EstimatorConfig::default());
    let (mut cs, mut ls, mut estimates) = (Vec::new(), Vec::new(), Vec::new());
    for ev in r.events() {
        match ev.expect("render") {
            Event::Frame(f) => {
                if let cam::Step::Sample(s) = cp.process(&f.image, f.time).unwrap() {
                    if s.sample.value.is_finite() && !s.low_texture() {
                        cs.push(s.sample);
                        let _ = est.push(Stream::Cam, s.sample);
                    }
                }
            }
            Event::Scan(s) => {
                lp.push_scan(&s.scan, |x| {
                    ls.push(x);
                    let _ = est.push(Stream::Lidar, x);
                });
            }
        }
        while let Some(e) = est.poll() {
            estimates.push(e);
        }
    }
    let score = score(&estimates, &truth);
    eprintln!(
        "stamping cam {cam_stamping:?} lidar {lidar_stamping:?}: {} cam, {} lidar samples, {} estimates; \
         tracking n {} MAE {:.2} ms bias {:+.2} ms p95 {:.2} ms max {:.2} ms; measured MAE {:.2} ms bias {:+.2} ms (n {}); \
         first lock {:?}; {:.1} s",
        cs.len(), ls.len(), estimates.len(), score.n, score.mae_s * 1e3, score.bias_s * 1e3,
        score.p95_s * 1e3, score.max_abs_s * 1e3, score.measured_mae_s * 1e3, score.measured_bias_s * 1e3,
        score.n_measured, score.first_lock_ns.map(|t| t as f64 * 1e-9), t0.elapsed().as_secs_f64()
    );
    Outcome {
        score,
        estimates,
        cam: cs,
        lidar: ls,
        truth,
    }
}

#[test]
#[ignore = "exploration: VLSYNC_SEEDS=1,2,3 cargo test -p vlsync-render --test end_to_end explore -- --ignored --nocapture"]
fn explore() {
    let seeds = std::env::var("VLSYNC_SEEDS").unwrap_or_else(|_| "1".into());
    let mut maes = Vec::new();
    for seed in seeds
        .split(',')
        .map(|s| s.trim().parse::<u64>().expect("seed"))
    {
        let o = pipeline(
            {
                let mut cfg = RenderConfig::from_seed(seed, 60.0);
                if let Ok(l) = std::env::var("VLSYNC_ROOM_LEN") {
                    cfg.room.0 = l.parse().unwrap();
                    cfg.lidar.max_range_m = cfg.room.0 + 1.0;
                }
                if let Ok(j) = std::env::var("VLSYNC_CAM_JITTER") {
                    cfg.clock.cam_jitter_s = j.parse().unwrap();
                }
                if let Ok(n) = std::env::var("VLSYNC_LIDAR_NOISE") {
                    cfg.lidar.range_noise_m = n.parse().unwrap();
                }
                cfg
            },
            cam::Stamping::Midpoint,
            lidar::Stamping::Midpoint,
            std::env::var("VLSYNC_LIDAR_HALF_DEG").map_or(5.0, |h| h.parse().unwrap()),
        );
        maes.push((seed, o.score.mae_s * 1e3, o.score.n));
    }
    eprintln!("{maes:?}");
    let cfg = RenderConfig::from_seed(1, 60.0);
    let o = pipeline(cfg, cam::Stamping::Midpoint, lidar::Stamping::Midpoint, 5.0);
    for e in &o.estimates {
        eprintln!(
            "{:.2} {:?} off {:+.4} meas {:+.4} truth {:+.4} score {:.2} ratio {:.2}",
            e.t_ref_ns as f64 * 1e-9,
            e.state,
            e.offset_s,
            e.measured_offset_s,
            o.truth.offset_at(e.t_ref_ns),
            e.peak_score,
            e.peak_ratio
        );
    }
    let w = |name: &str, v: &[Sample]| {
        let text: String = v
            .iter()
            .map(|s| format!("{},{}\n", s.t_ns as f64 * 1e-9, s.value))
            .collect();
        std::fs::write(name, text).unwrap();
    };
    w("/tmp/e2e_cam.csv", &o.cam);
    w("/tmp/e2e_lidar.csv", &o.lidar);
}

/// The configuration of the scored runs: the defaults (320x240 at 30 Hz, an
/// LD06-like 10 Hz LiDAR with 8 mm noise, 2 % frame drops, 1 ms camera jitter,
/// drift and offset drawn from the seed), 60 s.
/// The LiDAR front-end's window: straight ahead, ±5° (its default).
const LIDAR_HALF_WIDTH_DEG: f64 = 5.0;

fn run_cfg(seed: u64) -> RenderConfig {
    RenderConfig::from_seed(seed, 60.0)
}

fn mid(seed: u64) -> Outcome {
    pipeline(
        run_cfg(seed),
        cam::Stamping::Midpoint,
        lidar::Stamping::Midpoint,
        LIDAR_HALF_WIDTH_DEG,
    )
}

/// Midpoint stamping through both real front-ends: seed 1 reaches the 3 ms
/// target (2.85 ms measured); other seeds do not (2.6-14 ms over seeds 1-6:
/// LD06-level range noise, 4 % camera value noise, and the 180° turns at the
/// room's ends, after which the estimator mostly holds).
#[test]
fn midpoint_stamping_tracks_the_truth_and_end_stamping_does_not() {
    let m = mid(1);
    assert!(
        m.cam.len() > 1700 && m.lidar.len() > 590,
        "{} {}",
        m.cam.len(),
        m.lidar.len()
    );
    let first = m.score.first_lock_ns.expect("locks") as f64 * 1e-9;
    assert!(first < 5.0, "first lock at {first} s");
    assert!(m.score.n >= 40, "{} tracking estimates", m.score.n);
    assert!(
        m.score.mae_s <= 0.0030,
        "midpoint MAE {} ms",
        m.score.mae_s * 1e3
    );
    assert!(
        m.score.measured_bias_s.abs() <= 0.002,
        "raw measurement bias {} ms",
        m.score.measured_bias_s * 1e3
    );

    let e = pipeline(
        run_cfg(1),
        cam::Stamping::End,
        lidar::Stamping::End,
        LIDAR_HALF_WIDTH_DEG,
    );
    assert!(e.score.n >= 20, "{} tracking estimates", e.score.n);
    assert!(
        e.score.mae_s > 0.015,
        "end-stamped MAE {} ms",
        e.score.mae_s * 1e3
    );
    // end stamping delays LiDAR samples by half a revolution (50 ms) and camera
    // samples by half a frame interval (16.7 ms): the offset t_L - t_C reads
    // 33.3 ms too large
    let shift = e.score.measured_bias_s - m.score.measured_bias_s;
    assert!(
        (shift - 0.0333).abs() < 0.005,
        "bias shift {} ms",
        shift * 1e3
    );
}

/// Other seeds, the same pipeline: the achieved level (measured 6.2 and 10.6
/// ms for seeds 2 and 3), asserted with a small margin so a regression shows.
#[test]
fn midpoint_stamping_other_seeds() {
    let maes: Vec<f64> = [2, 3].iter().map(|&s| mid(s).score.mae_s).collect();
    let mean = maes.iter().sum::<f64>() / maes.len() as f64;
    assert!(mean <= 0.0095, "mean MAE {} ms ({maes:?})", mean * 1e3);
    assert!(maes.iter().all(|&m| m <= 0.012), "{maes:?}");
}

/// Least-squares fit `y = g·x + h·a` (no intercept); returns `(g, h)`.
fn fit2(rows: &[(f64, f64, f64)]) -> (f64, f64) {
    let (mut sxx, mut sxa, mut saa, mut sxy, mut say) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(y, x, a) in rows {
        sxx += x * x;
        sxa += x * a;
        saa += a * a;
        sxy += x * y;
        say += a * y;
    }
    let det = sxx * saa - sxa * sxa;
    ((sxy * saa - say * sxa) / det, (say * sxx - sxy * sxa) / det)
}

/// The timing audit: each front-end's samples against the true speed of the
/// drive. A sample stamped `t` (mapped to true time) that really describes
/// `t - δ` reads `g·v(t - δ) ≈ g·v(t) - g·δ·a(t)`: the fit of the value on
/// `v(t)` and `a(t)` gives the gain and the delay `δ` (positive = stamped late).
/// Turns (±1 s) are excluded: the camera sees rotation there, the LiDAR corners.
/// Returns `[(camera delay, LiDAR delay)]` in seconds for midpoint, then end stamping.
fn audit(seed: u64, lidar_noise_m: f64) -> [(f64, f64); 2] {
    let mut cfg = run_cfg(seed);
    cfg.lidar.range_noise_m = lidar_noise_m;
    let mut r = Renderer::new(cfg).unwrap();
    let truth = r.truth().clone();
    let traj = r.trajectory().clone();
    let stampings = [
        (cam::Stamping::Midpoint, lidar::Stamping::Midpoint),
        (cam::Stamping::End, lidar::Stamping::End),
    ];
    let mut cps = stampings.map(|(c, _)| {
        cam::SignatureProcessor::new(cam::SignatureConfig {
            stamping: c,
            ..Default::default()
        })
        .unwrap()
    });
    let mut lps = stampings.map(|(_, l)| {
        lidar::SignatureProcessor::new(lidar::SignatureConfig {
            stamping: l,
            window_half_width_rad: LIDAR_HALF_WIDTH_DEG.to_radians(),
            ..Default::default()
        })
        .unwrap()
    });
    let mut crow = [Vec::new(), Vec::new()];
    let mut lrow = [Vec::new(), Vec::new()];
    let turning = |t: f64| {
        traj.turns()
            .iter()
            .any(|&(a, b)| t > a - 1.0 && t < b + 1.0)
    };
    let acc = |t: f64| (traj.speed(t + 0.005) - traj.speed(t - 0.005)) / 0.01;
    for ev in r.events() {
        match ev.unwrap() {
            Event::Frame(f) => {
                for (cp, rows) in cps.iter_mut().zip(crow.iter_mut()) {
                    if let cam::Step::Sample(s) = cp.process(&f.image, f.time).unwrap() {
                        // camera stamp to true time: τ = t_C + offset(τ)
                        let t =
                            (s.sample.t_ns as f64 + truth.offset_at(s.sample.t_ns) * 1e9) * 1e-9;
                        if !turning(t) && s.sample.value.is_finite() {
                            rows.push((s.sample.value, traj.speed(t), acc(t)));
                        }
                    }
                }
            }
            Event::Scan(sc) => {
                for (lp, rows) in lps.iter_mut().zip(lrow.iter_mut()) {
                    lp.push_scan(&sc.scan, |x| {
                        let t = x.t_ns as f64 * 1e-9;
                        if !turning(t) {
                            rows.push((x.value, traj.speed(t), acc(t)));
                        }
                    });
                }
            }
        }
    }
    let delay = |rows: &[(f64, f64, f64)]| {
        let (g, h) = fit2(rows);
        -h / g
    };
    let out = [0, 1].map(|i| (delay(&crow[i]), delay(&lrow[i])));
    eprintln!(
        "seed {seed} delays (camera, LiDAR): midpoint {:+.2} ms, {:+.2} ms; end {:+.2} ms, {:+.2} ms",
        out[0].0 * 1e3,
        out[0].1 * 1e3,
        out[1].0 * 1e3,
        out[1].1 * 1e3
    );
    out
}

/// Each front-end on its own: with midpoint stamping the samples describe the
/// instant they are stamped with, with end stamping they are late by half a
/// frame interval (16.7 ms) and half a revolution (50 ms). Noise-free ranges
/// make the LiDAR fit exact. Measured on seed 1: camera -0.19 / +16.68 ms,
/// LiDAR +0.52 / +51.10 ms (the LiDAR's half-millisecond: the median *range*
/// of a pass comes from a ray a few degrees off centre, measured ~0.7 ms from
/// the median *time* it is stamped with). With the default 8 mm noise the
/// LiDAR fit itself scatters by a few ms (-2.9 ms measured).
#[test]
fn each_front_end_is_stamped_where_its_sample_belongs() {
    let [(cm, lm), (ce, le)] = audit(1, 0.0);
    assert!(cm.abs() < 0.0005, "camera midpoint delay {} ms", cm * 1e3);
    assert!(lm.abs() < 0.001, "LiDAR midpoint delay {} ms", lm * 1e3);
    assert!(
        (ce - 0.01667).abs() < 0.0005,
        "camera end delay {} ms",
        ce * 1e3
    );
    assert!(
        (le - 0.050).abs() < 0.0015,
        "LiDAR end delay {} ms",
        le * 1e3
    );
}
