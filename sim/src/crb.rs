//! Cramér-Rao bound of the offset (high SNR, white noise), as in the reference notes:
//!
//! ```text
//! var(offset) >= σ_c² / Σ_cam s_c'(t_i)²  +  σ_l² / Σ_lidar s_l'(t_j)²
//! ```
//!
//! where `s_c`, `s_l` are the noiseless signatures of each stream (the simulator knows
//! them: [`crate::families::CleanPoint::slope`]) and the sums run over the samples
//! actually delivered (drops and gaps remove information). At low SNR side-peak errors
//! dominate before this bound applies; it is a floor, not a prediction.
//!
//! ```
//! use vlsync_sim::crb::crb_std_s;
//! // 100 samples of slope 1/s with noise 0.01 on each stream: sqrt(2 * 1e-4 / 100)
//! let s = crb_std_s(0.01, &[1.0; 100], 0.01, &[1.0; 100]);
//! assert!((s - (2e-6f64).sqrt()).abs() < 1e-12);
//! assert!(crb_std_s(0.01, &[], 0.01, &[1.0]).is_infinite());
//! ```

use crate::families::{CleanPoint, SimError, SimRun};
use vlsync_common::{nanos_to_secs, secs_to_nanos, Nanos};

/// Shortest window accepted by the windowed bound, seconds.
pub const MIN_WINDOW_S: f64 = 0.1;

/// Bound (standard deviation, seconds) for noise `sigma_cam`/`sigma_lidar` and the
/// noiseless signature slopes at the samples. Infinite when a stream carries no
/// information (no samples or all slopes zero), even without noise; 0 without noise
/// on either stream otherwise; NaN only for NaN inputs.
pub fn crb_std_s(
    sigma_cam: f64,
    cam_slopes: &[f64],
    sigma_lidar: f64,
    lidar_slopes: &[f64],
) -> f64 {
    let info = |slopes: &[f64]| slopes.iter().map(|s| s * s).sum::<f64>();
    (stream_variance(sigma_cam, info(cam_slopes))
        + stream_variance(sigma_lidar, info(lidar_slopes)))
    .sqrt()
}

/// One stream's term of the bound: `σ² / Σ s'²`, infinite without information
/// (whatever the noise: a stream without samples or motion measures nothing, noisy or
/// not), 0 without noise where it has some.
fn stream_variance(sigma: f64, info: f64) -> f64 {
    // the information first: without it there is no bound, noisy or not
    if info > 0.0 {
        if sigma == 0.0 {
            0.0
        } else {
            sigma * sigma / info
        }
    } else {
        f64::INFINITY
    }
}

/// Slopes of the points with `tau` in `[a, b)`; `points` sorted by `tau` (as generated).
fn slopes_in(points: &[CleanPoint], a: Nanos, b: Nanos) -> Vec<f64> {
    let i = points.partition_point(|p| p.tau_ns < a);
    let j = points.partition_point(|p| p.tau_ns < b);
    points[i..j.max(i)].iter().map(|p| p.slope).collect()
}

/// Bound over the whole run (constant offset), seconds. Stored in [`SimRun::crb_std_s`].
pub fn crb_run_std_s(run: &SimRun) -> f64 {
    let c: Vec<f64> = run.cam_clean.iter().map(|p| p.slope).collect();
    let l: Vec<f64> = run.lidar_clean.iter().map(|p| p.slope).collect();
    crb_std_s(run.noise_cam, &c, run.noise_lidar, &l)
}

/// Bound of one `window_s`-second window, per window: windows `[k·W/2, k·W/2 + W)` on
/// the LiDAR clock (50 % overlap) that fit in the run. Windows without motion give
/// infinity. Errors when `window_s` is not in `[MIN_WINDOW_S, run length]`.
pub fn crb_windows_std_s(run: &SimRun, window_s: f64) -> Result<Vec<(Nanos, f64)>, SimError> {
    if !(window_s.is_finite() && window_s >= MIN_WINDOW_S && window_s <= run.duration_s) {
        return Err(SimError::InvalidWindow {
            window_s,
            duration_s: run.duration_s,
        });
    }
    let w = secs_to_nanos(window_s);
    let hop = (w / 2).max(1);
    let end = secs_to_nanos(run.duration_s);
    let mut out = Vec::new();
    let mut a: Nanos = 0;
    while a + w <= end {
        let c = slopes_in(&run.cam_clean, a, a + w);
        let l = slopes_in(&run.lidar_clean, a, a + w);
        out.push((a + w / 2, crb_std_s(run.noise_cam, &c, run.noise_lidar, &l)));
        a += hop;
    }
    Ok(out)
}

/// Median over the windows of [`crb_windows_std_s`], seconds: the typical bound of one
/// `window_s` window (for reference beside a windowed estimator's error).
///
/// ```
/// use vlsync_sim::{crb::crb_window_std_s, families::{generate, Family}};
/// let run = generate(Family::Seed, 3, None);
/// let w4 = crb_window_std_s(&run, 4.0).unwrap();
/// assert!(w4 > run.crb_std_s && w4 < 0.02);
/// assert!(crb_window_std_s(&run, 0.0).is_err());
/// ```
pub fn crb_window_std_s(run: &SimRun, window_s: f64) -> Result<f64, SimError> {
    let mut v: Vec<f64> = crb_windows_std_s(run, window_s)?
        .into_iter()
        .map(|x| x.1)
        .collect();
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    Ok(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// Width of the bins in which [`causal_std_s`] measures the offset, ns (one default hop).
pub const CAUSAL_BIN_NS: Nanos = 500_000_000;

/// The causal bound: for each time in `times_ns` (LiDAR clock), the standard deviation
/// (seconds) of the best estimate of the offset at that time that an estimator could
/// make from the data up to `lookahead_s` later, knowing the signatures' shapes and
/// noise and the sizes of the offset steps, with the drift drawn from a zero-mean prior
/// of standard deviation `drift_prior_std` (s/s; 0 or less: the drift is known;
/// infinite: nothing is known of it). A NaN `drift_prior_std` or `lookahead_s` gives
/// NaN for every time.
///
/// Where [`crb_run_std_s`] is the bound of one constant offset measured with the whole
/// run, this is the bound of what vlsync publishes: an offset that may drift, estimated
/// online, `reference_lag_s` behind the newest data. The model:
/// * every [`CAUSAL_BIN_NS`] bin of data measures the offset at the bin's centre with the
///   reference notes' variance `σ_c²/Σ_cam s'² + σ_l²/Σ_lidar s'²` over that bin's
///   samples (drops, gaps and standstills give a bin no information);
/// * the offset is a line `o + d·(t - t_ref)` plus the known steps; the bins up to the
///   horizon `t_ref + lookahead_s` inform `o` and `d`, the prior adds
///   `1/drift_prior_std²` to `d`'s information. A bin is selected by its centre: one
///   whose centre lies at or before the horizon counts whole, though its data reach
///   up to half a bin (0.25 s) beyond;
/// * the variance of `o` is the `(0, 0)` element of the inverse information matrix,
///   computed from the bins' information-weighted mean time and spread around it (no
///   cancellation). Where that matrix is singular (the drift not known, no prior on
///   it, and a single informative bin: a line through one point) or the variance is
///   not a finite number, the bound is infinite.
///
/// Known step sizes make it a floor for the families with steps too (vlsync measures
/// them from the stamps' cadence, not exactly). It is a floor, not a prediction:
/// side-peak errors at low SNR, stamp jitter and the estimator's robustness against
/// outliers and steps all come on top. A time without information up to its horizon
/// gives infinity, with noise or without; a run without noise gives zero where it has
/// some (a bin where both streams see motion measures the offset exactly).
///
/// ```
/// use vlsync_sim::{crb::causal_std_s, families::{generate, Family}};
/// let run = generate(Family::Robot, 2, None);
/// let t = [20_000_000_000, 60_000_000_000, 110_000_000_000];
/// // with the drift known: more data, a tighter bound, never better than the whole
/// // run's constant-offset bound
/// let known = causal_std_s(&run, &t, 3.0, 0.0);
/// assert!(known[0] > known[1] && known[1] > known[2] && known[2] > run.crb_std_s);
/// // a drift drawn from a 50 ppm prior costs more, a drift not known at all more still
/// // (with a drift, later is not always better: the newest data lie far from the older)
/// let prior = causal_std_s(&run, &t, 3.0, 50e-6);
/// let free = causal_std_s(&run, &t, 3.0, 1.0);
/// assert!((0..3).all(|i| known[i] < prior[i] && prior[i] < free[i]));
/// ```
pub fn causal_std_s(
    run: &SimRun,
    times_ns: &[Nanos],
    lookahead_s: f64,
    drift_prior_std: f64,
) -> Vec<f64> {
    if drift_prior_std.is_nan() || lookahead_s.is_nan() {
        return vec![f64::NAN; times_ns.len()];
    }
    let bin_of = |p: &CleanPoint| p.tau_ns.div_euclid(CAUSAL_BIN_NS);
    let (first, last) = match (run.lidar_clean.first(), run.lidar_clean.last()) {
        (Some(a), Some(b)) => (bin_of(a), bin_of(b)),
        _ => return vec![f64::INFINITY; times_ns.len()],
    };
    // per bin from the LiDAR's first: Σ s'² of each stream
    let n = usize::try_from(last - first + 1).unwrap_or(0);
    let mut sums = vec![(0.0, 0.0); n];
    for (points, lidar) in [(&run.cam_clean, false), (&run.lidar_clean, true)] {
        for p in points.iter() {
            let Some(e) = usize::try_from(bin_of(p) - first)
                .ok()
                .and_then(|i| sums.get_mut(i))
            else {
                continue;
            };
            if lidar {
                e.1 += p.slope * p.slope;
            } else {
                e.0 += p.slope * p.slope;
            }
        }
    }
    // (bin centre s, information 1/s²) of the bins that carry any; a bin measured
    // without noise has infinite information
    let bins: Vec<(f64, f64)> = sums
        .iter()
        .enumerate()
        .map(|(i, &(c, l))| {
            let v = stream_variance(run.noise_cam, c) + stream_variance(run.noise_lidar, l);
            let centre = ((first + i as i64) as f64 + 0.5) * nanos_to_secs(CAUSAL_BIN_NS);
            (centre, 1.0 / v)
        })
        .filter(|b| b.1 > 0.0)
        .collect();
    let known_drift = drift_prior_std <= 0.0;
    // the drift's information from its prior (0 for an infinite prior)
    let prior_info = 1.0 / (drift_prior_std * drift_prior_std);
    times_ns
        .iter()
        .map(|&t| {
            let t_s = nanos_to_secs(t);
            // bins are sorted by centre: those up to the horizon are a prefix
            let within = &bins[..bins.partition_point(|b| b.0 <= t_s + lookahead_s)];
            let j_oo: f64 = within.iter().map(|b| b.1).sum();
            if within.is_empty() || j_oo <= 0.0 {
                return f64::INFINITY;
            }
            // an exact measurement up to the horizon (a run without noise)
            if j_oo.is_infinite() {
                return 0.0;
            }
            let var = if known_drift {
                1.0 / j_oo
            } else {
                // The information matrix [[J, Σ i·x], [Σ i·x, Σ i·x² + prior]] (x: a
                // bin's centre from t) has the determinant J·(S + prior), S = Σ i·(x - x̄)²
                // the spread around the information-weighted mean x̄; the inverse's
                // (0, 0) element is 1/J + x̄²/(S + prior). One bin has no spread (set
                // exactly: x - x̄ would leave rounding).
                let x_mean = within.iter().map(|&(c, i)| i * (c - t_s)).sum::<f64>() / j_oo;
                let spread: f64 = if within.len() < 2 {
                    0.0
                } else {
                    within
                        .iter()
                        .map(|&(c, i)| i * (c - t_s - x_mean) * (c - t_s - x_mean))
                        .sum()
                };
                let det_per_j = spread + prior_info;
                // singular; a NaN (from NaN sums) makes `var` NaN, caught below
                if det_per_j <= 0.0 {
                    return f64::INFINITY;
                }
                1.0 / j_oo + x_mean * x_mean / det_per_j
            };
            if var.is_finite() && var >= 0.0 {
                var.sqrt()
            } else {
                f64::INFINITY
            }
        })
        .collect()
}

/// The expected share of estimates off by more than `threshold_s` when each is off by a
/// zero-mean Gaussian error of the given standard deviation (seconds): the mean of
/// `erfc(threshold / (σ·√2))`. With [`causal_std_s`] it is the tail an ideal online
/// estimator could not avoid. NaN for an empty slice; an infinite σ counts as 1.
///
/// ```
/// use vlsync_sim::crb::share_beyond;
/// // 1σ, 2σ and 3σ two-sided tails
/// let t = share_beyond(&[0.02, 0.01, 0.02 / 3.0], 0.02);
/// assert!((t - (0.317311 + 0.045500 + 0.002700) / 3.0).abs() < 1e-5);
/// assert_eq!(share_beyond(&[0.0, f64::INFINITY], 0.02), 0.5);
/// ```
pub fn share_beyond(stds: &[f64], threshold_s: f64) -> f64 {
    let tail = |sd: f64| {
        if sd <= 0.0 {
            0.0
        } else if sd.is_infinite() {
            1.0
        } else {
            erfc(threshold_s / (sd * std::f64::consts::SQRT_2))
        }
    };
    stds.iter().map(|&sd| tail(sd)).sum::<f64>() / stds.len() as f64
}

/// Complementary error function for `x >= 0` (Abramowitz and Stegun 7.1.26, absolute
/// error under 1.5e-7).
fn erfc(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    poly * (-x * x).exp()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn more_samples_tighten_and_more_noise_loosens(
            slopes in proptest::collection::vec(-5.0f64..5.0, 1..60),
            extra in proptest::collection::vec(0.01f64..5.0, 1..20),
            sc in 0.001f64..1.0, sl in 0.001f64..1.0, k in 1.01f64..10.0,
        ) {
            let base = crb_std_s(sc, &slopes, sl, &slopes);
            let mut more = slopes.clone();
            more.extend(&extra);
            prop_assert!(crb_std_s(sc, &more, sl, &more) < base);
            prop_assert!(crb_std_s(sc * k, &slopes, sl, &slopes) > base || base.is_infinite());
            prop_assert!(crb_std_s(sc, &slopes, sl * k, &slopes) > base || base.is_infinite());
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn causal_bound_falls_with_data_and_rises_with_the_prior(
            seed in 0u64..1000, t_s in 5.0f64..110.0, look in 0.0f64..5.0,
            prior in 1e-6f64..1e-3,
        ) {
            let run = crate::families::generate(crate::families::Family::Clocks, seed, None);
            let t = [secs_to_nanos(t_s)];
            let base = causal_std_s(&run, &t, look, prior)[0];
            prop_assert!(base.is_finite() && base > 0.0);
            prop_assert!(causal_std_s(&run, &t, look + 1.0, prior)[0] <= base);
            prop_assert!(causal_std_s(&run, &t, look, prior * 2.0)[0] >= base);
            prop_assert!(causal_std_s(&run, &t, look, 0.0)[0] <= base);
        }
    }

    #[test]
    fn causal_bound_with_all_data_and_a_known_drift_is_the_run_bound() {
        for family in [
            crate::families::Family::Robot,
            crate::families::Family::Clocks,
        ] {
            let run = crate::families::generate(family, 7, None);
            let end = run.lidar_clean.last().unwrap().tau_ns;
            let b = causal_std_s(&run, &[end], 1.0, 0.0)[0];
            // bins can only lose information against the whole run's sums (the combined
            // variance is concave in the two streams' information), and lose little when
            // both streams see the same motion
            assert!(
                b >= run.crb_std_s && b < 1.1 * run.crb_std_s,
                "{family:?}: {b} vs {}",
                run.crb_std_s
            );
        }
        // before any data, and without noise
        let mut run = crate::families::generate(crate::families::Family::Robot, 7, Some(30.0));
        assert_eq!(
            causal_std_s(&run, &[-secs_to_nanos(5.0)], 1.0, 50e-6),
            [f64::INFINITY]
        );
        run.noise_cam = 0.0;
        run.noise_lidar = 0.0;
        assert_eq!(
            causal_std_s(&run, &[secs_to_nanos(10.0)], 1.0, 50e-6),
            [0.0]
        );
    }

    /// Without a drift prior a line needs two bins: one informative bin leaves the
    /// offset unbounded (it came out 0 or garbage), and NaN inputs give NaN, not 0.
    #[test]
    fn causal_bound_is_infinite_where_the_information_is_singular() {
        let run = crate::families::generate(crate::families::Family::Robot, 7, Some(30.0));
        let bin_s = nanos_to_secs(CAUSAL_BIN_NS);
        let centre = |k: i64| secs_to_nanos((k as f64 + 0.5) * bin_s);
        // the first bin with information (both streams moving): a bin counts once its
        // centre is within the horizon
        let k = (0..60)
            .find(|&k| causal_std_s(&run, &[centre(k)], 0.0, 0.0)[0].is_finite())
            .expect("the robot moves within 30 s");
        let known = causal_std_s(&run, &[centre(k)], 0.0, 0.0)[0];
        assert!(known > 0.0);
        let before = centre(k) - secs_to_nanos(0.1);
        for (t, look) in [(centre(k), 0.0), (before, 0.1), (before, 0.2)] {
            assert_eq!(
                causal_std_s(&run, &[t], look, f64::INFINITY),
                [f64::INFINITY],
                "t {t} ns, lookahead {look} s: one bin and no drift prior"
            );
            // a prior makes it finite, and no better than with the drift known
            let p = causal_std_s(&run, &[t], look, 50e-6)[0];
            assert!(p.is_finite() && p >= known, "{p} against {known}");
        }
        // at the bin's own centre the drift does not matter
        assert_eq!(causal_std_s(&run, &[centre(k)], 0.0, 50e-6)[0], known);
        // a second bin pins the line: finite, and more than a 1 s/s prior gives
        let two = causal_std_s(&run, &[centre(k + 1)], 0.0, f64::INFINITY)[0];
        let wide = causal_std_s(&run, &[centre(k + 1)], 0.0, 1.0)[0];
        assert!(two.is_finite() && two >= wide && wide > 0.0, "{two} {wide}");
        // NaN in, NaN out (it gave 0 for a NaN prior), for every time
        for (look, prior) in [(0.0, f64::NAN), (f64::NAN, 50e-6), (f64::NAN, 0.0)] {
            let v = causal_std_s(&run, &[centre(k), centre(k + 10)], look, prior);
            assert!(v.iter().all(|x| x.is_nan()), "{look} {prior}: {v:?}");
        }
        // a negative prior is a known drift, as documented
        assert_eq!(
            causal_std_s(&run, &[centre(k + 4)], 1.0, -1.0),
            causal_std_s(&run, &[centre(k + 4)], 1.0, 0.0)
        );
    }

    /// Without information the bound is infinite whatever the noise: without noise it
    /// came out 0 (no samples, or a standstill), as if the offset were known exactly.
    #[test]
    fn no_information_is_no_bound_even_without_noise() {
        assert!(crb_std_s(0.0, &[], 0.0, &[1.0]).is_infinite());
        assert!(crb_std_s(0.0, &[0.0; 5], 0.0, &[1.0]).is_infinite());
        assert!(crb_std_s(0.01, &[1.0], 0.0, &[]).is_infinite());
        // with information: exact without noise, one stream's term with noise on it alone
        assert_eq!(crb_std_s(0.0, &[1.0], 0.0, &[2.0]), 0.0);
        assert!((crb_std_s(0.0, &[1.0; 100], 0.01, &[1.0; 100]) - 1e-3).abs() < 1e-15);

        let run = crate::families::try_generate_with(
            crate::families::Family::Standstill,
            3,
            Some(60.0),
            0.0,
        )
        .unwrap();
        assert_eq!(run.noise_cam, 0.0);
        let (a, b) = run.standstills[0];
        // a window inside the standstill has no information; one in motion is exact
        let w = crb_windows_std_s(&run, 4.0).unwrap();
        let w_ns = secs_to_nanos(4.0);
        let inside = w
            .iter()
            .find(|x| x.0 - w_ns / 2 >= a && x.0 + w_ns / 2 <= b)
            .unwrap();
        assert!(inside.1.is_infinite(), "{inside:?}");
        assert!(w.iter().any(|x| x.1 == 0.0));
        // causal: nothing before the data, exact once both streams have seen motion
        let before = -secs_to_nanos(5.0);
        let moving = b + secs_to_nanos(5.0);
        for prior in [0.0, 50e-6] {
            assert_eq!(
                causal_std_s(&run, &[before, moving], 1.0, prior),
                [f64::INFINITY, 0.0],
                "prior {prior}"
            );
        }
    }

    /// A window's error quotes the numbers as the duration's and the noise scale's do
    /// (`vlsync_common::text::number`): a tiny or huge window was printed in full.
    #[test]
    fn window_errors_quote_numbers_as_the_other_errors_do() {
        let run = crate::families::generate(crate::families::Family::Robot, 1, Some(60.0));
        let e = |w: f64| crb_window_std_s(&run, w).unwrap_err().to_string();
        assert_eq!(
            e(1e-9),
            "window 1e-9 s is invalid: expected a finite number in [0.1, 60] s (the run length)"
        );
        assert!(
            e(1e300).starts_with("window 1e300 s is invalid"),
            "{}",
            e(1e300)
        );
        assert!(
            e(f64::NAN).starts_with("window NaN s is invalid"),
            "{}",
            e(f64::NAN)
        );
    }

    #[test]
    fn run_bound_matches_generated_noise_and_windows() {
        let run = crate::families::generate(crate::families::Family::Robot, 1, Some(60.0));
        assert!(run.crb_std_s > 0.0 && run.crb_std_s.is_finite());
        let w = crb_windows_std_s(&run, 6.0).unwrap();
        assert_eq!(w.len(), 19);
        // every window is worse than the whole run
        assert!(w.iter().all(|x| x.1 >= run.crb_std_s));
        assert!(crb_window_std_s(&run, 61.0).is_err());
        assert!(crb_window_std_s(&run, f64::NAN).is_err());
        assert!(crb_window_std_s(&run, 1e-9).is_err());
        // the sorted lookup agrees with a plain filter
        let (a, b) = (secs_to_nanos(12.0), secs_to_nanos(18.0));
        let plain: Vec<f64> = run
            .lidar_clean
            .iter()
            .filter(|p| p.tau_ns >= a && p.tau_ns < b)
            .map(|p| p.slope)
            .collect();
        assert_eq!(slopes_in(&run.lidar_clean, a, b), plain);
        assert_eq!(plain.len(), 60);
        // a longer run of the same family has a tighter bound
        let long = crate::families::generate(crate::families::Family::Robot, 1, Some(240.0));
        assert!(long.crb_std_s < run.crb_std_s);
    }
}
