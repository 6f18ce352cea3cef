//! **BASELINE**: the seed article's chunked cross-correlation, with its two outright
//! bugs fixed and nothing else improved. It exists to be beaten, not used.
//!
//! As published:
//! * resampling of both streams onto a grid at the camera rate spanning the overlap of
//!   the two streams' raw timestamps, taking for each grid time the first sample at or
//!   after it (numpy `searchsorted(side="left")`, clipped; the article calls it
//!   nearest-neighbour);
//! * chunks of 2.4 s (`int(2.4 / dt)` grid samples) with 50 % overlap, while
//!   `start + chunk < grid length`;
//! * per chunk: means removed, un-normalised full cross-correlation (`np.correlate`)
//!   restricted to integer lags, argmax of the raw correlation (positive peaks only,
//!   first maximum on ties).
//!
//! Fixed:
//! * **sign**: `np.correlate(cam, lidar)` peaks at lag `-offset/dt`; the estimate is
//!   `-lag * dt`, i.e. `t_L - t_C`;
//! * **lag range**: ±0.5 s converted with the *grid* rate (`int(0.5 * cam_hz)` lags), not
//!   with the slower sensor's rate.
//!
//! Each estimate is reported at the chunk centre (read as LiDAR time). Non-finite
//! samples are skipped; the inputs are expected sorted by time (as the seed assumes).
//!
//! ```
//! use vlsync_sim::{baseline::seed_chunked, families::{generate, Family}};
//! let run = generate(Family::Seed, 3, None);
//! let est = seed_chunked(&run.cam, &run.lidar, 30.0);
//! assert_eq!(est.len(), 8);
//! assert!(seed_chunked(&[], &run.lidar, 30.0).is_empty());
//! ```

use vlsync_common::{secs_to_nanos, Nanos, Sample};

/// Chunk length of the seed, seconds.
pub const CHUNK_S: f64 = 2.4;
/// Lag half-range of the seed, seconds.
pub const MAX_OFFSET_S: f64 = 0.5;
/// Longest grid (samples) the baseline builds; longer overlaps give no estimates
/// rather than an unbounded allocation (10^7 samples: 3.8 days at 30 Hz, 240 MB for the
/// grid and the two resampled streams; the longest simulated run is an hour).
pub const MAX_GRID: usize = 10_000_000;
/// Most grid samples per input sample (both streams' finite ones together): the grid
/// is at the camera rate, so one far longer than the inputs would only repeat a few
/// samples (streams with long gaps, a wrong `cam_hz`); two samples a day apart would
/// otherwise take millions of grid points. Keeps the memory in proportion to the input.
pub const MAX_GRID_PER_SAMPLE: usize = 16;

/// The seed's chunked estimator (bugs fixed, see the [module docs](self)):
/// `(chunk centre on the LiDAR clock, offset t_L - t_C in seconds)` per chunk.
/// Returns nothing for empty/non-overlapping inputs, a non-positive `cam_hz`, or an
/// overlap longer than [`MAX_GRID`] grid samples or [`MAX_GRID_PER_SAMPLE`] per input
/// sample. Any stamps are accepted (the overlap's span is computed without overflow).
pub fn seed_chunked(cam: &[Sample], lidar: &[Sample], cam_hz: f64) -> Vec<(Nanos, f64)> {
    let cam: Vec<Sample> = cam
        .iter()
        .copied()
        .filter(|s| s.value.is_finite())
        .collect();
    let lidar: Vec<Sample> = lidar
        .iter()
        .copied()
        .filter(|s| s.value.is_finite())
        .collect();
    if !(cam_hz.is_finite() && cam_hz > 0.0) || cam.is_empty() || lidar.is_empty() {
        return Vec::new();
    }
    let dt = 1.0 / cam_hz;
    let dt_ns = 1e9 / cam_hz;
    let t0 = cam[0].t_ns.max(lidar[0].t_ns);
    let t1 = cam[cam.len() - 1].t_ns.min(lidar[lidar.len() - 1].t_ns);
    if t1 <= t0 {
        return Vec::new();
    }
    // np.arange(t0, t1, dt); the span of stamps far apart overflows i64
    let span_ns = i128::from(t1) - i128::from(t0);
    let n_f = (span_ns as f64 / dt_ns).ceil();
    let most = MAX_GRID.min(MAX_GRID_PER_SAMPLE.saturating_mul(cam.len() + lidar.len()));
    if n_f > most as f64 {
        return Vec::new();
    }
    let n = n_f as usize;
    let grid: Vec<Nanos> = (0..n)
        .map(|i| t0.saturating_add((i as f64 * dt_ns).round() as Nanos))
        .collect();
    let resample = |s: &[Sample]| -> Vec<f64> {
        grid.iter()
            .map(|&g| {
                let i = s.partition_point(|x| x.t_ns < g).min(s.len() - 1);
                s[i].value
            })
            .collect()
    };
    let cam_g = resample(&cam);
    let lid_g = resample(&lidar);
    let chunk_n = (CHUNK_S / dt + 1e-9) as usize;
    let max_lag = (MAX_OFFSET_S * cam_hz + 1e-9) as i64;
    let mut out = Vec::new();
    if chunk_n < 2 {
        return out;
    }
    let mut start = 0usize;
    while start + chunk_n < grid.len() {
        let a = demean(&cam_g[start..start + chunk_n]);
        let b = demean(&lid_g[start..start + chunk_n]);
        let lag = argmax_lag(&a, &b, max_lag);
        let centre = grid[start].saturating_add(secs_to_nanos(chunk_n as f64 * dt / 2.0));
        out.push((centre, -(lag as f64) * dt));
        start += (chunk_n / 2).max(1);
    }
    out
}

fn demean(x: &[f64]) -> Vec<f64> {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    x.iter().map(|v| v - m).collect()
}

/// `argmax_L sum_n a[n+L] b[n]` over `L in -max..=max` (the `np.correlate(a, b, "full")` lags).
fn argmax_lag(a: &[f64], b: &[f64], max: i64) -> i64 {
    let n = a.len() as i64;
    let mut best = (f64::NEG_INFINITY, 0i64);
    for lag in -max.min(n - 1)..=max.min(n - 1) {
        let mut c = 0.0;
        for j in 0..n {
            let i = j + lag;
            if i >= 0 && i < n {
                c += a[i as usize] * b[j as usize];
            }
        }
        if c > best.0 {
            best = (c, lag);
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::families::{generate, Family};

    #[test]
    fn bad_inputs_give_no_estimates() {
        let a = [Sample::new(0, 1.0), Sample::new(i64::MAX, 2.0)];
        let b = [
            Sample::new(i64::MIN, 1.0),
            Sample::new(i64::MAX - 5, f64::NAN),
        ];
        assert!(seed_chunked(&a, &b, 30.0).is_empty());
        assert!(seed_chunked(&a, &a, f64::NAN).is_empty());
        assert!(seed_chunked(&a, &a, -30.0).is_empty());
        assert!(seed_chunked(&a[..1], &a[..1], 30.0).is_empty());
    }

    /// Stamps far apart: their span overflowed i64 (a panic with overflow checks), and
    /// two samples a day apart built a grid of 2.6 million points (10^8 were allowed: 2.4
    /// GB) to resample them over and over.
    #[test]
    fn extreme_or_sparse_stamps_give_no_estimates() {
        let far = [
            Sample::new(-5_000_000_000_000_000_000, 1.0),
            Sample::new(5_000_000_000_000_000_000, 2.0),
        ];
        assert!(seed_chunked(&far, &far, 30.0).is_empty());
        let wide = [Sample::new(i64::MIN, 1.0), Sample::new(i64::MAX, 2.0)];
        assert!(seed_chunked(&wide, &wide, 1e-9).is_empty());
        let day = secs_to_nanos(86_400.0);
        let sparse = [Sample::new(0, 1.0), Sample::new(day, 2.0)];
        assert!(seed_chunked(&sparse, &sparse, 30.0).is_empty());
        // a dense stream of the same span is the grid's own length: estimated
        let cam: Vec<Sample> = (0..300)
            .map(|k| Sample::new(k * 33_333_333, (k as f64 * 0.3).sin()))
            .collect();
        assert!(!seed_chunked(&cam, &cam, 30.0).is_empty());
    }

    #[test]
    fn correlation_lag_sign_matches_numpy() {
        // a is b delayed by 2 samples: a[n] = b[n-2]  =>  np.correlate(a, b) peaks at lag +2
        let b = [0.0, 1.0, 3.0, 1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0];
        let mut a = [0.0; 10];
        a[2..].copy_from_slice(&b[..8]);
        assert_eq!(argmax_lag(&demean(&a), &demean(&b), 4), 2);
    }

    #[test]
    fn seed_family_mae_is_tens_of_ms() {
        let mut maes = Vec::new();
        for seed in 0..4 {
            let run = generate(Family::Seed, seed, None);
            let est = seed_chunked(&run.cam, &run.lidar, run.cam_hz);
            assert_eq!(est.len(), 8);
            let mae = est
                .iter()
                .map(|&(t, o)| (o - run.truth.offset_at(t)).abs())
                .sum::<f64>()
                / est.len() as f64;
            // the article scores against the truth at the chunk *start* (centre - 1.2 s)
            let mae_start = est
                .iter()
                .map(|&(t, o)| (o - run.truth.offset_at(t - secs_to_nanos(1.2))).abs())
                .sum::<f64>()
                / est.len() as f64;
            println!(
                "seed {seed}: baseline MAE {:.1} ms (vs truth at chunk start, as the article scores: {:.1} ms)",
                mae * 1e3,
                mae_start * 1e3
            );
            maes.push(mae);
        }
        let mean = maes.iter().sum::<f64>() / maes.len() as f64;
        println!(
            "Seed family baseline MAE (mean of 4 seeds): {:.1} ms",
            mean * 1e3
        );
        assert!((0.005..0.08).contains(&mean), "baseline MAE {mean}");
    }

    #[test]
    fn unbroken_lag_range_reaches_big_offsets() {
        // a noiseless seed-like pair shifted by 0.4 s: the fixed range (±15 lags) reaches it
        let f = |t: f64| {
            (-((t - 3.0) / 0.3f64).powi(2)).exp() + 0.5 * (-((t - 4.5) / 0.2f64).powi(2)).exp()
        };
        let cam: Vec<Sample> = (0..300)
            .map(|k| {
                let t = k as f64 / 30.0;
                Sample::new(secs_to_nanos(t), f(t + 0.4))
            })
            .collect();
        let lidar: Vec<Sample> = (0..100)
            .map(|k| {
                let t = k as f64 / 10.0;
                Sample::new(secs_to_nanos(t), f(t))
            })
            .collect();
        let est = seed_chunked(&cam, &lidar, 30.0);
        let near = est
            .iter()
            .find(|e| (e.0 - secs_to_nanos(3.0)).abs() < secs_to_nanos(0.7))
            .unwrap();
        assert!((near.1 - 0.4).abs() < 0.07, "{near:?}");
    }
}
