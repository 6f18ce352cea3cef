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
use vlsync_common::{secs_to_nanos, Nanos};

/// Shortest window accepted by the windowed bound, seconds.
pub const MIN_WINDOW_S: f64 = 0.1;

/// Bound (standard deviation, seconds) for noise `sigma_cam`/`sigma_lidar` and the
/// noiseless signature slopes at the samples. Infinite when a stream carries no
/// information (no samples or all slopes zero); NaN only for NaN inputs.
pub fn crb_std_s(
    sigma_cam: f64,
    cam_slopes: &[f64],
    sigma_lidar: f64,
    lidar_slopes: &[f64],
) -> f64 {
    let term = |sigma: f64, slopes: &[f64]| {
        let info: f64 = slopes.iter().map(|s| s * s).sum();
        if sigma == 0.0 {
            0.0
        } else if info > 0.0 {
            sigma * sigma / info
        } else {
            f64::INFINITY
        }
    };
    (term(sigma_cam, cam_slopes) + term(sigma_lidar, lidar_slopes)).sqrt()
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
