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
use realfft::{num_complex::Complex, ComplexToReal, RealFftPlanner, RealToComplex};
use std::sync::Arc;
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

/// Lag slots the estimator updates while tracking at the default setting: the
/// tracking range (±8 slots), the 6 slots beyond it tracking reads and 8 to spare,
/// each side of the prediction (`Estimator::narrow_to`).
const TRACKING_SLOTS: usize = 45;

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

/// FFT batch: the cross-correlation of the window at every lag by real FFTs, the
/// per-lag moments by prefix sums. Planned once, its buffers allocated once, at the
/// shortest power of two that holds the linear correlation (`y.len()`, which is at
/// least `x.len() + n_lags - 1`: no lag wraps around): what a careful batch
/// implementation would do. Until 2026-12-03 the bench used complex FFTs of twice that
/// length and allocated its buffers per call, which made the FFT about three times
/// slower than it needs to be (docs/performance.md).
struct BatchFft {
    len: usize,
    r2c: Arc<dyn RealToComplex<f64>>,
    c2r: Arc<dyn ComplexToReal<f64>>,
    a: Vec<f64>,
    b: Vec<f64>,
    sa: Vec<Complex<f64>>,
    sb: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    pre: Vec<f64>,
    pre2: Vec<f64>,
}

impl BatchFft {
    fn new(x_len: usize, y_len: usize, n_lags: usize) -> Self {
        assert!(y_len + 1 >= x_len + n_lags, "y must cover every lag");
        let len = y_len.next_power_of_two();
        let mut planner = RealFftPlanner::<f64>::new();
        let r2c = planner.plan_fft_forward(len);
        let c2r = planner.plan_fft_inverse(len);
        let scratch_len = r2c.get_scratch_len().max(c2r.get_scratch_len());
        Self {
            len,
            a: r2c.make_input_vec(),
            b: r2c.make_input_vec(),
            sa: r2c.make_output_vec(),
            sb: r2c.make_output_vec(),
            scratch: vec![Complex::new(0.0, 0.0); scratch_len],
            pre: vec![0.0; y_len + 1],
            pre2: vec![0.0; y_len + 1],
            r2c,
            c2r,
        }
    }

    fn run(&mut self, x: &[f64], y: &[f64], n_lags: usize, out: &mut [f64]) {
        let n = x.len();
        self.a.fill(0.0);
        self.a[..n].copy_from_slice(x);
        self.b.fill(0.0);
        self.b[..y.len()].copy_from_slice(y);
        self.r2c
            .process_with_scratch(&mut self.a, &mut self.sa, &mut self.scratch)
            .expect("forward FFT of x");
        self.r2c
            .process_with_scratch(&mut self.b, &mut self.sb, &mut self.scratch)
            .expect("forward FFT of y");
        for (p, q) in self.sa.iter_mut().zip(&self.sb) {
            *p = p.conj() * q;
        }
        // the spectrum of a real correlation: real at DC and at the Nyquist bin
        let last = self.sa.len() - 1;
        self.sa[0].im = 0.0;
        self.sa[last].im = 0.0;
        self.c2r
            .process_with_scratch(&mut self.sa, &mut self.a, &mut self.scratch)
            .expect("inverse FFT");
        for (i, &v) in y.iter().enumerate() {
            self.pre[i + 1] = self.pre[i] + v;
            self.pre2[i + 1] = self.pre2[i] + v * v;
        }
        let sx: f64 = x.iter().sum();
        let sxx: f64 = x.iter().map(|v| v * v).sum();
        let nf = n as f64;
        for (m, o) in out.iter_mut().enumerate().take(n_lags) {
            let sxy = self.a[m] / self.len as f64;
            let sy = self.pre[m + n] - self.pre[m];
            let syy = self.pre2[m + n] - self.pre2[m];
            *o = (sxy - sx * sy / nf) / ((sxx - sx * sx / nf) * (syy - sy * sy / nf)).sqrt();
        }
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
        // to ten indices of a block per step); both then evaluate the correlation at every lag,
        // as the batch paths return it. The third is the second once locked: the
        // estimator then updates, and evaluates, only the `TRACKING_SLOTS` lags near
        // the prediction (a batch recompute at those lags alone is `segment`'s
        // `batch_direct_tracking_lags`; an FFT's costs the same at any)
        let peak = (half + 12) as usize;
        let (t_lo, t_hi) = (peak - TRACKING_SLOTS / 2, peak + TRACKING_SLOTS / 2);
        for (name, burst, (lo, hi)) in [
            ("incremental", 1, (0, n_lags - 1)),
            ("incremental_10hz_bursts", 10, (0, n_lags - 1)),
            ("incremental_10hz_tracking", 10, (t_lo, t_hi)),
        ] {
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
            corr.set_active(lo, hi);
            feed(&mut corr, &mut k, win as i64 + 4 * half);
            assert_eq!((corr.acq().lo, corr.acq().hi), (lo, hi));
            let mut out = vec![0.0; n_lags];
            g.bench_function(BenchmarkId::new(name, s.name), |b| {
                b.iter(|| {
                    feed(&mut corr, &mut k, hop);
                    corr.acq().ncc_range(lo, hi, &mut out);
                    black_box(out[n_lags / 2])
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
        // the direct recompute at the lags a lock updates alone (an FFT's cost does not
        // depend on how many lags are read)
        let mut part = vec![0.0; TRACKING_SLOTS];
        let y_part = &y[t_lo..t_lo + win + TRACKING_SLOTS];
        batch_direct(&x, y_part, TRACKING_SLOTS, &mut part);
        batch_direct(&x, &y, n_lags, &mut out);
        assert_eq!(part[..], out[t_lo..=t_hi]);
        g.bench_function(
            BenchmarkId::new("batch_direct_tracking_lags", s.name),
            |b| {
                b.iter(|| {
                    batch_direct(black_box(&x), black_box(y_part), TRACKING_SLOTS, &mut part);
                    black_box(part[0])
                })
            },
        );
        let mut fft = BatchFft::new(x.len(), y.len(), n_lags);
        // the same correlation as the direct recompute
        let mut check = vec![0.0; n_lags];
        batch_direct(&x, &y, n_lags, &mut check);
        fft.run(&x, &y, n_lags, &mut out);
        assert!(out.iter().zip(&check).all(|(a, b)| (a - b).abs() < 1e-9));
        g.bench_function(BenchmarkId::new("batch_fft", s.name), |b| {
            b.iter(|| {
                fft.run(black_box(&x), black_box(&y), n_lags, &mut out);
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
    // the next hop's end; past the run's end, a new estimator warmed up again
    let next_hop = |t: &mut i64, est: &mut Estimator, ij: &mut (usize, usize)| {
        *t += hop_ns;
        if *t > 3_590_000_000_000 {
            *t = 90_000_000_000;
            *est = Estimator::new(&cfg);
            *ij = (0, 0);
            push_until(est, ij, *t);
            *t += hop_ns;
        }
    };
    g.bench_function("estimator_hop", |b| {
        b.iter(|| {
            next_hop(&mut t, &mut est, &mut ij);
            push_until(&mut est, &mut ij, t);
            black_box(est.state())
        })
    });
    // the same hops, timing each push: the pushes that complete a hop (what the
    // daemon's p99 sees), and the costliest of the other pushes of each hop (the
    // work staged over the samples between hops)
    for (name, hop_sample) in [
        ("estimator_hop_sample", true),
        ("estimator_busiest_other_sample", false),
    ] {
        let mut est = Estimator::new(&cfg);
        let mut ij = (0usize, 0usize);
        let mut t = 90_000_000_000i64;
        push_until(&mut est, &mut ij, t);
        g.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = std::time::Duration::ZERO;
                for _ in 0..iters {
                    next_hop(&mut t, &mut est, &mut ij);
                    let mut busiest = std::time::Duration::ZERO;
                    // both streams in time order, as the daemon pushes them
                    loop {
                        let c = run.cam.get(ij.0).filter(|s| s.t_ns <= t);
                        let l = run.lidar.get(ij.1).filter(|s| s.t_ns <= t);
                        let (stream, s) = match (c, l) {
                            (Some(c), Some(l)) if c.t_ns <= l.t_ns => (Stream::Cam, *c),
                            (Some(c), None) => (Stream::Cam, *c),
                            (_, Some(l)) => (Stream::Lidar, *l),
                            (None, None) => break,
                        };
                        match stream {
                            Stream::Cam => ij.0 += 1,
                            Stream::Lidar => ij.1 += 1,
                        }
                        let hops = est.stats().estimates;
                        let t0 = std::time::Instant::now();
                        let _ = est.push(stream, s);
                        let dt = t0.elapsed();
                        if (est.stats().estimates != hops) == hop_sample {
                            if hop_sample {
                                total += dt;
                            } else {
                                busiest = busiest.max(dt);
                            }
                        }
                        while est.poll().is_some() {}
                    }
                    total += busiest;
                }
                total
            })
        });
    }
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
    let mut fft = BatchFft::new(x.len(), y.len(), 2 * half + 1);
    g.bench_function("batch_fft_all_lags", |b| {
        b.iter(|| {
            fft.run(black_box(&x), black_box(&y), 2 * half + 1, &mut out);
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
