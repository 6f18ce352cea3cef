//! The two kernels as the correlator calls them, dispatched (AVX where the CPU has it)
//! against the portable build, in one run: their ratio is what AVX buys here.
//! `cargo bench -p vlsync-simd`.

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};

fn kernels(c: &mut Criterion) {
    let mut g = c.benchmark_group("add_products");
    // a locked hop's 45 lags and an acquiring one's 101, ten grid values per step
    for lags in [45usize, 101] {
        let ys: Vec<f64> = (0..lags + 9).map(|i| (i as f64 * 0.37).sin()).collect();
        let xs: Vec<f64> = (0..10).map(|i| (i as f64 * 0.11).cos()).collect();
        let mut acc = vec![0.0; lags];
        g.bench_function(BenchmarkId::new("dispatched", lags), |b| {
            b.iter(|| vlsync_simd::add_products(black_box(&mut acc), black_box(&ys), &xs))
        });
        g.bench_function(BenchmarkId::new("portable", lags), |b| {
            b.iter(|| vlsync_simd::add_products_portable(black_box(&mut acc), black_box(&ys), &xs))
        });
    }
    g.finish();
    let mut g = c.benchmark_group("pearson_range");
    for lags in [45usize, 101] {
        let xy: Vec<f64> = (0..lags).map(|i| 10.0 + i as f64).collect();
        let y: Vec<f64> = (0..lags).map(|i| 5.0 + 0.1 * i as f64).collect();
        let yy: Vec<f64> = (0..lags).map(|i| 400.0 + i as f64).collect();
        let mut out = vec![0.0; lags];
        g.bench_function(BenchmarkId::new("dispatched", lags), |b| {
            b.iter(|| {
                vlsync_simd::pearson_range(600.0, 30.0, 900.0, &xy, &y, black_box(&yy), &mut out);
                black_box(out[0])
            })
        });
        g.bench_function(BenchmarkId::new("portable", lags), |b| {
            b.iter(|| {
                vlsync_simd::pearson_range_portable(
                    600.0,
                    30.0,
                    900.0,
                    &xy,
                    &y,
                    black_box(&yy),
                    &mut out,
                );
                black_box(out[0])
            })
        });
    }
    g.finish();
}

criterion_group!(benches, kernels);
criterion_main!(benches);
