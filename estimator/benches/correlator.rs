//! Cost of the incremental correlator against a batch recompute of the same window.
//!
//! Per estimate (one hop): the incremental path adds `hop` grid samples (O(lags) each)
//! and moves the acquisition window by one block; the batch paths recompute the whole
//! window's correlation at every lag, directly (O(window·lags)) or with FFTs
//! (O(n log n)). `segment` measures the whole estimator per hop while tracking (the
//! samples of one hop, the robust drift-compensated combination of a 60 s segment,
//! the step test) against a batch recompute of the same 60 s at the tracking range's
//! lags and with FFTs at every lag.
//! `cargo bench -p vlsync-estimator --bench correlator`; the ratio is what matters.

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};
use rustfft::{num_complex::Complex, FftPlanner};
use vlsync_common::Stream;
use vlsync_config::EstimatorConfig;
use vlsync_estimator::correlator::{Correlator, Step};
use vlsync_estimator::Estimator;

struct Setting {
    name: &'static str,
    fs: f64,
    window_s: f64,
    hop_s: f64,
    max_lag_s: f64,
}

const SETTINGS: [Setting; 3] = [
    Setting {
        name: "default 6s/±0.5s",
        fs: 100.0,
        window_s: 6.0,
        hop_s: 0.5,
        max_lag_s: 0.5,
    },
    Setting {
        name: "12s/±1s",
        fs: 100.0,
        window_s: 12.0,
        hop_s: 0.5,
        max_lag_s: 1.0,
    },
    Setting {
        name: "30s/±2s",
        fs: 100.0,
        window_s: 30.0,
        hop_s: 0.5,
        max_lag_s: 2.0,
    },
];

fn sig(i: i64) -> f64 {
    let t = i as f64 * 0.01;
    (0.9 * t).sin() + 0.5 * (2.7 * t).cos() + 0.1 * ((i * 7919) % 101) as f64 / 101.0
}

/// Length of the precomputed input (a power of two; 655 s at 100 Hz).
const TABLE: usize = 1 << 16;

/// The input signal, precomputed: the batch paths get their windows as ready slices, so
/// the incremental path reads its samples from a table too instead of paying four
/// trigonometric calls per grid sample for generating them (which the figures before
/// 2026-12-01 23:00 included, in the incremental path only).
fn sig_table() -> Vec<f64> {
    (0..TABLE as i64).map(sig).collect()
}

#[inline]
fn at(table: &[f64], i: i64) -> f64 {
    table[(i as usize) & (TABLE - 1)]
}

/// Direct batch Pearson correlation of the window at every lag.
fn batch_direct(x: &[f64], y: &[f64], n_lags: usize, out: &mut [f64]) {
    let n = x.len();
    let sx: f64 = x.iter().sum();
    let sxx: f64 = x.iter().map(|v| v * v).sum();
    for (m, o) in out.iter_mut().enumerate().take(n_lags) {
        let (mut sy, mut syy, mut sxy) = (0.0, 0.0, 0.0);
        for k in 0..n {
            let yv = y[k + m];
            sy += yv;
            syy += yv * yv;
            sxy += x[k] * yv;
        }
        let nf = n as f64;
        *o = (sxy - sx * sy / nf) / ((sxx - sx * sx / nf) * (syy - sy * sy / nf)).sqrt();
    }
}

/// FFT batch: cross-correlation by FFT plus prefix sums for the per-lag moments.
fn batch_fft(x: &[f64], y: &[f64], n_lags: usize, planner: &mut FftPlanner<f64>, out: &mut [f64]) {
    let n = x.len();
    let len = (n + y.len()).next_power_of_two();
    let fft = planner.plan_fft_forward(len);
    let ifft = planner.plan_fft_inverse(len);
    let mut a: Vec<Complex<f64>> = (0..len)
        .map(|i| Complex::new(if i < n { x[i] } else { 0.0 }, 0.0))
        .collect();
    let mut b: Vec<Complex<f64>> = (0..len)
        .map(|i| Complex::new(if i < y.len() { y[i] } else { 0.0 }, 0.0))
        .collect();
    fft.process(&mut a);
    fft.process(&mut b);
    for (p, q) in a.iter_mut().zip(&b) {
        *p = p.conj() * q;
    }
    ifft.process(&mut a);
    let mut pre = vec![0.0; y.len() + 1];
    let mut pre2 = vec![0.0; y.len() + 1];
    for i in 0..y.len() {
        pre[i + 1] = pre[i] + y[i];
        pre2[i + 1] = pre2[i] + y[i] * y[i];
    }
    let sx: f64 = x.iter().sum();
    let sxx: f64 = x.iter().map(|v| v * v).sum();
    let nf = n as f64;
    for (m, o) in out.iter_mut().enumerate().take(n_lags) {
        let sxy = a[m].re / len as f64;
        let sy = pre[m + n] - pre[m];
        let syy = pre2[m + n] - pre2[m];
        *o = (sxy - sx * sy / nf) / ((sxx - sx * sx / nf) * (syy - sy * sy / nf)).sqrt();
    }
}

fn bench(c: &mut Criterion) {
    let table = sig_table();
    let mut g = c.benchmark_group("per_estimate");
    for s in &SETTINGS {
        let hop = (s.hop_s * s.fs) as i64;
        let half = (s.max_lag_s * s.fs) as i64;
        let n_lags = (2 * half + 1) as usize;
        let wb = (s.window_s / s.hop_s) as usize;
        let win = (s.window_s * s.fs) as usize;
        // incremental: warm a correlator, then measure one hop (hop samples + block combine)
        // fed one index of each stream, then a step; and as the estimator feeds it from
        // a 10 Hz LiDAR: each scan brings ten grid values, then the correlator steps (up
        // to four indices per step)
        for (name, burst) in [("incremental", 1), ("incremental_10hz_bursts", 10)] {
            let mut corr = Correlator::new(n_lags, -half, hop, wb, wb, 8192);
            let mut k = 0i64;
            let feed = |corr: &mut Correlator, k: &mut i64, n: i64| {
                for _ in 0..n / burst {
                    for _ in 0..burst {
                        corr.push_cam(*k, at(&table, *k));
                        corr.push_lidar(*k, at(&table, *k - 12));
                        *k += 1;
                    }
                    while corr.step() != Step::Idle {}
                }
            };
            feed(&mut corr, &mut k, win as i64 + 4 * half);
            g.bench_function(BenchmarkId::new(name, s.name), |b| {
                b.iter(|| {
                    feed(&mut corr, &mut k, hop);
                    black_box(corr.acq().ncc(n_lags / 2))
                })
            });
        }
        let x: Vec<f64> = (0..win as i64).map(|i| sig(i - 12)).collect();
        let y: Vec<f64> = (0..(win + n_lags) as i64).map(|i| sig(i - half)).collect();
        let mut out = vec![0.0; n_lags];
        g.bench_function(BenchmarkId::new("batch_direct", s.name), |b| {
            b.iter(|| {
                batch_direct(black_box(&x), black_box(&y), n_lags, &mut out);
                black_box(out[0])
            })
        });
        let mut planner = FftPlanner::new();
        g.bench_function(BenchmarkId::new("batch_fft", s.name), |b| {
            b.iter(|| {
                batch_fft(black_box(&x), black_box(&y), n_lags, &mut planner, &mut out);
                black_box(out[0])
            })
        });
    }
    g.finish();
    let mut g = c.benchmark_group("per_sample");
    for s in &SETTINGS {
        let hop = (s.hop_s * s.fs) as i64;
        let half = (s.max_lag_s * s.fs) as i64;
        let n_lags = (2 * half + 1) as usize;
        let wb = (s.window_s / s.hop_s) as usize;
        let mut corr = Correlator::new(n_lags, -half, hop, wb, wb, 8192);
        let mut k = 0i64;
        g.bench_function(BenchmarkId::new("incremental", s.name), |b| {
            b.iter(|| {
                corr.push_cam(k, at(&table, k));
                corr.push_lidar(k, at(&table, k - 12));
                k += 1;
                while corr.step() != Step::Idle {}
            })
        });
    }
    g.finish();
}

/// The whole estimator per hop while tracking a 60 s segment, against batch
/// recomputes of that segment.
fn segment(c: &mut Criterion) {
    let mut g = c.benchmark_group("segment");
    let cfg = EstimatorConfig::default();
    let run = vlsync_sim::families::generate(vlsync_sim::families::Family::Robot, 1, Some(3600.0));
    let mut est = Estimator::new(&cfg);
    // cursors into the camera and LiDAR samples
    let mut ij = (0usize, 0usize);
    let push_until = |est: &mut Estimator, ij: &mut (usize, usize), t_ns: i64| {
        while ij.0 < run.cam.len() && run.cam[ij.0].t_ns <= t_ns {
            let _ = est.push(Stream::Cam, run.cam[ij.0]);
            ij.0 += 1;
        }
        while ij.1 < run.lidar.len() && run.lidar[ij.1].t_ns <= t_ns {
            let _ = est.push(Stream::Lidar, run.lidar[ij.1]);
            ij.1 += 1;
        }
        while est.poll().is_some() {}
    };
    // warm up past a full segment
    let mut t = 90_000_000_000i64;
    push_until(&mut est, &mut ij, t);
    let hop_ns = (cfg.hop_s * 1e9) as i64;
    g.bench_function("estimator_hop", |b| {
        b.iter(|| {
            t += hop_ns;
            if t > 3_590_000_000_000 {
                t = 90_000_000_000;
                est = Estimator::new(&cfg);
                ij = (0, 0);
            }
            push_until(&mut est, &mut ij, t);
            black_box(est.state())
        })
    });
    let win = (cfg.segment_s * cfg.grid_hz) as usize;
    let half = (cfg.max_lag_s * cfg.grid_hz) as usize;
    let track = (2.0 * cfg.track_range_s * cfg.grid_hz) as usize + 1;
    let x: Vec<f64> = (0..win as i64).map(|i| sig(i - 12)).collect();
    let y: Vec<f64> = (0..(win + 2 * half + 1) as i64)
        .map(|i| sig(i - half as i64))
        .collect();
    let mut out = vec![0.0; 2 * half + 1];
    g.bench_function("batch_direct_tracking_lags", |b| {
        b.iter(|| {
            batch_direct(black_box(&x), black_box(&y), track, &mut out);
            black_box(out[0])
        })
    });
    let mut planner = FftPlanner::new();
    g.bench_function("batch_fft_all_lags", |b| {
        b.iter(|| {
            batch_fft(
                black_box(&x),
                black_box(&y),
                2 * half + 1,
                &mut planner,
                &mut out,
            );
            black_box(out[0])
        })
    });
    g.finish();
}

/// The stamp cadence per sample: a 30 Hz stream with 1 ms of jitter, 5 % of its
/// frames dropped and a 12 ms latency step every 20 s (what every accepted sample
/// pays before the resampler).
fn cadence(c: &mut Criterion) {
    use vlsync_estimator::cadence::{Cadence, CadenceParams, Kind};
    let mut g = c.benchmark_group("cadence");
    let mut seed = 1u64;
    let mut noise = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let stamps: Vec<i64> = (0..36_000i64)
        .filter(|k| k % 20 != 7)
        .map(|k| {
            let step = if (k / 600) % 2 == 1 { 12e6 } else { 0.0 };
            (1e12 + k as f64 * 33.333e6 + step + 3.4e6 * noise()) as i64
        })
        .collect();
    let mut cad = Cadence::new(CadenceParams::default());
    let mut i = 0usize;
    g.bench_function("push_30hz_jitter_drops_steps", |b| {
        b.iter(|| {
            if i == stamps.len() {
                cad = Cadence::new(CadenceParams::default());
                i = 0;
            }
            let kind = if i == 0 { Kind::First } else { Kind::Normal };
            let t = cad.push(black_box(stamps[i]), kind);
            i += 1;
            black_box(t)
        })
    });
    // a lookup as an estimate makes it: 3 s (90 frames) before the newest sample
    let mut cad = Cadence::new(CadenceParams::default());
    let mut internal = 0;
    for (i, &s) in stamps.iter().enumerate().take(20_000) {
        let t = cad.push(s, if i == 0 { Kind::First } else { Kind::Normal });
        if i == 20_000 - 90 {
            internal = t;
        }
    }
    g.bench_function("level_at_3s_back", |b| {
        b.iter(|| black_box(cad.level_at(black_box(internal))))
    });
    g.finish();
}

criterion_group!(benches, bench, segment, cadence);
criterion_main!(benches);
