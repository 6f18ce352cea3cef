//! The correlator's two inner loops, each compiled twice: for the baseline
//! instruction set, and on x86-64 also with AVX (four `f64` per instruction instead
//! of SSE2's two), chosen at run time when the CPU has it.
//! * [`add_products`]: `acc[i] += Σ_j xs[j] · ys[i + j]`, the Σxy of a step's grid
//!   values at every active lag;
//! * [`pearson_range`]: the Pearson correlation of a range of lags from their sums.
//!
//! Why a crate of its own: calling a `#[target_feature]` function from code built
//! without that feature is `unsafe`, and the estimator forbids unsafe code. This
//! crate holds those two calls (each with its `SAFETY` comment) and nothing else.
//!
//! Both versions perform the same multiplications and additions in the same order
//! (Rust never fuses a multiply and an add unless asked, and only AVX, not FMA, is
//! enabled; division and square root are correctly rounded in both), so they give
//! the same values bit for bit: an estimate does not depend on the machine it was
//! computed on. On aarch64 (the Raspberry Pi) NEON is part of the baseline and the
//! portable version is the vectorised one.
//!
//! ```
//! let ys = [1.0, 2.0, 3.0, 4.0, 5.0];
//! let mut acc = [0.0; 3];
//! // acc[i] += 10·ys[i] + 100·ys[i + 1] + 1000·ys[i + 2]
//! vlsync_simd::add_products(&mut acc, &ys, &[10.0, 100.0, 1000.0]);
//! assert_eq!(acc, [3210.0, 4320.0, 5430.0]);
//! ```
#![deny(unsafe_code)]

/// `acc[i] += Σ_j xs[j] · ys[i + j]` for every `i` of `acc`, the additions of each
/// slot in the order of `j` (the same sums, bit for bit, as adding `xs` one at a
/// time). `ys` must hold at least `acc.len() + xs.len() - 1` values (panics
/// otherwise, like a slice index). Up to ten `xs` are unrolled into one pass.
#[inline]
pub fn add_products(acc: &mut [f64], ys: &[f64], xs: &[f64]) {
    if !check_products(acc, ys, xs) {
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        #[allow(unsafe_code)]
        // SAFETY: `add_products_avx` is compiled with AVX enabled; the CPU was just
        // checked to have AVX, which is all that makes calling it sound. Its body is
        // safe Rust (bounds-checked slices).
        unsafe {
            add_products_avx(acc, ys, xs)
        };
        return;
    }
    add_products_any(acc, ys, xs);
}

/// [`add_products`] always in the portable build (what a CPU without AVX runs): the
/// benches compare the two.
pub fn add_products_portable(acc: &mut [f64], ys: &[f64], xs: &[f64]) {
    if check_products(acc, ys, xs) {
        add_products_any(acc, ys, xs);
    }
}

/// Whether there is anything to add; panics when `ys` is too short.
#[inline]
fn check_products(acc: &[f64], ys: &[f64], xs: &[f64]) -> bool {
    if xs.is_empty() {
        return false;
    }
    assert!(
        ys.len() >= acc.len() + xs.len() - 1,
        "add_products: {} values for {} slots and {} products",
        ys.len(),
        acc.len(),
        xs.len()
    );
    true
}

/// [`add_products`] with AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn add_products_avx(acc: &mut [f64], ys: &[f64], xs: &[f64]) {
    add_products_any(acc, ys, xs);
}

/// [`add_products`] in portable code; inlined into the AVX version, it is compiled
/// again with AVX there.
#[inline(always)]
fn add_products_any(acc: &mut [f64], ys: &[f64], xs: &[f64]) {
    match *xs {
        [a] => add_n(acc, ys, &[a]),
        [a, b] => add_n(acc, ys, &[a, b]),
        [a, b, c] => add_n(acc, ys, &[a, b, c]),
        [a, b, c, d] => add_n(acc, ys, &[a, b, c, d]),
        [a, b, c, d, e] => add_n(acc, ys, &[a, b, c, d, e]),
        [a, b, c, d, e, f] => add_n(acc, ys, &[a, b, c, d, e, f]),
        [a, b, c, d, e, f, g] => add_n(acc, ys, &[a, b, c, d, e, f, g]),
        [a, b, c, d, e, f, g, h] => add_n(acc, ys, &[a, b, c, d, e, f, g, h]),
        [a, b, c, d, e, f, g, h, i] => add_n(acc, ys, &[a, b, c, d, e, f, g, h, i]),
        [a, b, c, d, e, f, g, h, i, j] => add_n(acc, ys, &[a, b, c, d, e, f, g, h, i, j]),
        // more than ten: one pass per index, in order
        _ => {
            for (j, &x) in xs.iter().enumerate() {
                add_n(acc, &ys[j..], &[x]);
            }
        }
    }
}

/// [`add_products`] for `N` values, unrolled: each slot is loaded and stored once.
#[inline(always)]
fn add_n<const N: usize>(acc: &mut [f64], ys: &[f64], xs: &[f64; N]) {
    let ys = &ys[..acc.len() + N - 1];
    for (i, o) in acc.iter_mut().enumerate() {
        let y: &[f64; N] = ys[i..i + N].try_into().expect("N values from i");
        let mut v = *o;
        for j in 0..N {
            v += xs[j] * y[j];
        }
        *o = v;
    }
}

/// Pearson correlation of one lag's sums over `n` pairs, given the LiDAR values' Σx
/// and `vx = n·Σx² - (Σx)²` (n ≥ 3): `(n·Σxy - Σx·Σy) / √(vx·(n·Σy² - (Σy)²))`,
/// one division and one root.
///
/// Always a finite number in `[-1, 1]`:
/// * 0 unless both variance terms, `vx` and `vy = n·Σy² - (Σy)²`, are positive, their
///   product is positive and finite, and the ratio is finite: no variance, a variance
///   term negative by cancellation (two negative terms have a positive product, whose
///   ratio is rounding noise), sums that overflowed to ±∞, and any NaN or infinite
///   input all give 0 (no correlation), never NaN nor a perfect ±1 from an ∞/finite
///   ratio;
/// * a finite ratio beyond ±1 (rounding in the sums of a near-perfect correlation) is
///   clamped to ±1.
///
/// Written as selects, without branches, so that [`pearson_range`]'s loop vectorises
/// (and its AVX and portable builds give the same bits).
///
/// ```
/// // y = 2x + 1 over x = 1, 2, 3: n = 3, Σx = 6, Σx² = 14, Σy = 15, Σy² = 83, Σxy = 34
/// let vx = 3.0 * 14.0 - 6.0 * 6.0;
/// assert_eq!(vlsync_simd::pearson(3.0, 6.0, vx, 34.0, 15.0, 83.0), 1.0);
/// // no variance: 0, not NaN
/// assert_eq!(vlsync_simd::pearson(3.0, 6.0, vx, 30.0, 15.0, 75.0), 0.0);
/// // both variance terms negative (cancellation): 0, though their product is positive
/// assert_eq!(vlsync_simd::pearson(3.0, 6.0, -1.0, 1.0, 15.0, 74.0), 0.0);
/// // an overflowed or undefined Σxy: 0, not ±1 or NaN
/// assert_eq!(vlsync_simd::pearson(3.0, 6.0, vx, f64::INFINITY, 15.0, 83.0), 0.0);
/// assert_eq!(vlsync_simd::pearson(3.0, 6.0, vx, f64::NAN, 15.0, 83.0), 0.0);
/// ```
#[inline(always)]
pub fn pearson(n: f64, sx: f64, vx: f64, sxy: f64, sy: f64, syy: f64) -> f64 {
    let vy = n * syy - sy * sy;
    let d = vx * vy;
    let r = (n * sxy - sx * sy) / d.sqrt();
    // every comparison is false for NaN: a NaN denominator or ratio is not `ok`; each
    // variance term on its own too (a positive product of two negative ones is noise)
    let ok = (vx > 0.0) & (vy > 0.0) & (d > 0.0) & (d < f64::INFINITY) & (r.abs() < f64::INFINITY);
    let r = if r < -1.0 { -1.0 } else { r };
    let r = if r > 1.0 { 1.0 } else { r };
    if ok {
        r
    } else {
        0.0
    }
}

/// [`pearson`] of every lag: `out[i]` from `xy[i]`, `y[i]`, `yy[i]` (all five slices
/// the same length; panics otherwise).
pub fn pearson_range(n: f64, sx: f64, vx: f64, xy: &[f64], y: &[f64], yy: &[f64], out: &mut [f64]) {
    check_range(xy, y, yy, out);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        #[allow(unsafe_code)]
        // SAFETY: `pearson_range_avx` is compiled with AVX enabled and the CPU was
        // just checked to have AVX; its body is safe Rust.
        unsafe {
            pearson_range_avx(n, sx, vx, xy, y, yy, out)
        };
        return;
    }
    pearson_range_any(n, sx, vx, xy, y, yy, out);
}

/// [`pearson_range`] always in the portable build (the benches compare the two).
pub fn pearson_range_portable(
    n: f64,
    sx: f64,
    vx: f64,
    xy: &[f64],
    y: &[f64],
    yy: &[f64],
    out: &mut [f64],
) {
    check_range(xy, y, yy, out);
    pearson_range_any(n, sx, vx, xy, y, yy, out);
}

/// Panics unless the four slices are as long as each other.
#[inline]
fn check_range(xy: &[f64], y: &[f64], yy: &[f64], out: &[f64]) {
    let len = out.len();
    assert!(
        xy.len() == len && y.len() == len && yy.len() == len,
        "pearson_range: {} outputs from {} / {} / {} sums",
        len,
        xy.len(),
        y.len(),
        yy.len()
    );
}

/// [`pearson_range`] with AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn pearson_range_avx(n: f64, sx: f64, vx: f64, xy: &[f64], y: &[f64], yy: &[f64], out: &mut [f64]) {
    pearson_range_any(n, sx, vx, xy, y, yy, out);
}

#[inline(always)]
fn pearson_range_any(n: f64, sx: f64, vx: f64, xy: &[f64], y: &[f64], yy: &[f64], out: &mut [f64]) {
    for (o, ((&sxy, &sy), &syy)) in out.iter_mut().zip(xy.iter().zip(y).zip(yy)) {
        *o = pearson(n, sx, vx, sxy, sy, syy);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition, one product at a time.
    fn one_by_one(acc: &mut [f64], ys: &[f64], xs: &[f64]) {
        for (j, &x) in xs.iter().enumerate() {
            for (i, o) in acc.iter_mut().enumerate() {
                *o += x * ys[i + j];
            }
        }
    }

    proptest::proptest! {
        /// The dispatched kernel (AVX where the CPU has it), the portable one and the
        /// definition agree bit for bit, for any number of slots and products.
        #[test]
        fn every_version_gives_the_definitions_sums_bit_for_bit(
            acc in proptest::collection::vec(-1e6..1e6f64, 0..130),
            xs in proptest::collection::vec(-1e3..1e3f64, 0..14),
            extra in proptest::collection::vec(-1e3..1e3f64, 13..14),
            ys_seed in proptest::collection::vec(-1e3..1e3f64, 150..160),
        ) {
            let ys: Vec<f64> = ys_seed.iter().chain(&extra).copied().collect();
            let mut want = acc.clone();
            one_by_one(&mut want, &ys, &xs);
            let mut got = acc.clone();
            add_products(&mut got, &ys, &xs);
            let mut any = acc.clone();
            add_products_portable(&mut any, &ys, &xs);
            for (i, ((g, a), w)) in got.iter().zip(&any).zip(&want).enumerate() {
                proptest::prop_assert_eq!(g.to_bits(), w.to_bits(), "dispatched, slot {}", i);
                proptest::prop_assert_eq!(a.to_bits(), w.to_bits(), "portable, slot {}", i);
            }
        }
    }

    proptest::proptest! {
        /// The dispatched range and the portable one give [`pearson`]'s values bit for
        /// bit, on any sums, non-finite ones included.
        #[test]
        fn every_version_gives_pearsons_values_bit_for_bit(
            n in proptest::prop_oneof![3.0..1e6f64, proptest::num::f64::ANY],
            sx in proptest::prop_oneof![-1e3..1e3f64, proptest::num::f64::ANY],
            vx in proptest::prop_oneof![0.0..1e6f64, proptest::num::f64::ANY],
            slots in proptest::collection::vec(
                (
                    proptest::prop_oneof![-1e3..1e3f64, proptest::num::f64::ANY],
                    proptest::prop_oneof![-1e3..1e3f64, proptest::num::f64::ANY],
                    proptest::prop_oneof![0.0..1e6f64, proptest::num::f64::ANY],
                ),
                0..40,
            ),
        ) {
            let xy: Vec<f64> = slots.iter().map(|s| s.0).collect();
            let y: Vec<f64> = slots.iter().map(|s| s.1).collect();
            let yy: Vec<f64> = slots.iter().map(|s| s.2).collect();
            let mut got = vec![7.0; slots.len()];
            pearson_range(n, sx, vx, &xy, &y, &yy, &mut got);
            let mut any = vec![7.0; slots.len()];
            pearson_range_portable(n, sx, vx, &xy, &y, &yy, &mut any);
            for i in 0..slots.len() {
                let want = pearson(n, sx, vx, xy[i], y[i], yy[i]);
                for v in [got[i], any[i]] {
                    proptest::prop_assert_eq!(
                        v.to_bits(), want.to_bits(), "slot {}: {} against {}", i, v, want
                    );
                }
            }
        }

        /// [`pearson`] is always a correlation: finite, within ±1, and 0 as soon as
        /// any input is NaN or infinite (or the sums overflow on the way).
        #[test]
        fn pearson_is_finite_within_one_and_zero_for_non_finite_inputs(
            finite in proptest::array::uniform6(
                proptest::prop_oneof![3 => -1e3..1e3f64, 1 => -1e300..1e300f64],
            ),
            bad in proptest::prop_oneof![
                proptest::strategy::Just(f64::NAN),
                proptest::strategy::Just(f64::INFINITY),
                proptest::strategy::Just(f64::NEG_INFINITY),
            ],
            which in 0..7usize,
        ) {
            let mut a = finite;
            if which < 6 {
                a[which] = bad;
            }
            let r = pearson(a[0], a[1], a[2], a[3], a[4], a[5]);
            proptest::prop_assert!(r.is_finite() && r.abs() <= 1.0, "{:?} gave {}", a, r);
            if which < 6 {
                proptest::prop_assert_eq!(r.to_bits(), 0.0f64.to_bits(), "{:?}", a);
            }
        }
    }

    /// The textbook form with branches and `clamp`, as [`pearson`] was before it
    /// checked each variance term: 0 unless the variance product is positive and
    /// finite and the ratio finite.
    fn textbook(n: f64, sx: f64, vx: f64, sxy: f64, sy: f64, syy: f64) -> f64 {
        let d = vx * (n * syy - sy * sy);
        let r = (n * sxy - sx * sy) / d.sqrt();
        if d <= 0.0 || !d.is_finite() || !r.is_finite() {
            0.0
        } else {
            r.clamp(-1.0, 1.0)
        }
    }

    /// Both variance terms negative (cancellation in `n·Σ² - (Σ)²` of sums of
    /// near-constant values): their product is positive, but the ratio is noise, not a
    /// correlation, so 0 in every build (the textbook form gives ±1 or noise).
    #[test]
    fn both_variance_terms_negative_is_no_correlation() {
        // n = 3, Σy = 15: vy = 3·Σy² - 225 < 0 for Σy² < 75
        let cases = [
            (-1.0, 1.0, 74.0),
            (-1e-3, 34.0, 74.9),
            (-4.0, -50.0, 70.0),
            (-1e-9, 1e3, 74.999_999),
        ];
        for (vx, sxy, syy) in cases {
            let vy = 3.0 * syy - 15.0 * 15.0;
            assert!(vx < 0.0 && vy < 0.0 && vx * vy > 0.0, "{vx} {vy}");
            assert_ne!(
                textbook(3.0, 6.0, vx, sxy, 15.0, syy),
                0.0,
                "{vx} {sxy} {syy}"
            );
            assert_eq!(
                pearson(3.0, 6.0, vx, sxy, 15.0, syy).to_bits(),
                0.0f64.to_bits()
            );
            let (mut out, mut portable) = ([7.0; 3], [7.0; 3]);
            let (xy, y, yy) = ([sxy; 3], [15.0; 3], [syy; 3]);
            pearson_range(3.0, 6.0, vx, &xy, &y, &yy, &mut out);
            pearson_range_portable(3.0, 6.0, vx, &xy, &y, &yy, &mut portable);
            assert_eq!(out, [0.0; 3], "{vx} {sxy} {syy}");
            assert_eq!(portable, [0.0; 3], "{vx} {sxy} {syy}");
        }
        // one negative term alone gave 0 before too (a negative product)
        assert_eq!(pearson(3.0, 6.0, -1.0, 34.0, 15.0, 83.0), 0.0);
        assert_eq!(pearson(3.0, 6.0, 6.0, 34.0, 15.0, 74.0), 0.0);
    }

    proptest::proptest! {
        /// With both variance terms positive, [`pearson`] (and both range builds) give
        /// the textbook form's value bit for bit: checking each term changed nothing
        /// where the old form gave a genuine correlation.
        #[test]
        fn positive_variances_give_the_textbook_value_bit_for_bit(
            n in proptest::prop_oneof![3.0..1e3f64, 3.0..1e6f64],
            sx in proptest::prop_oneof![-1e3..1e3f64, -1e300..1e300f64],
            vx in proptest::prop_oneof![1e-12..1e6f64, f64::MIN_POSITIVE..1e300f64],
            slots in proptest::collection::vec(
                (
                    proptest::prop_oneof![-1e3..1e3f64, -1e300..1e300f64],
                    -1e3..1e3f64,
                    // Σy² above (Σy)²/n by this much
                    proptest::prop_oneof![1e-12..1e6f64, 1e-300..1e300f64],
                ),
                1..40,
            ),
        ) {
            let n = n.floor();
            let xy: Vec<f64> = slots.iter().map(|s| s.0).collect();
            let y: Vec<f64> = slots.iter().map(|s| s.1).collect();
            let yy: Vec<f64> = slots.iter().map(|s| (s.1 * s.1 + s.2) / n).collect();
            let mut got = vec![7.0; slots.len()];
            pearson_range(n, sx, vx, &xy, &y, &yy, &mut got);
            let mut any = vec![7.0; slots.len()];
            pearson_range_portable(n, sx, vx, &xy, &y, &yy, &mut any);
            let mut checked = 0;
            for i in 0..slots.len() {
                // rounding may still leave a term at or below 0: the forms differ
                // (on purpose) only where one is
                if n * yy[i] - y[i] * y[i] <= 0.0 {
                    continue;
                }
                checked += 1;
                let want = textbook(n, sx, vx, xy[i], y[i], yy[i]);
                for v in [pearson(n, sx, vx, xy[i], y[i], yy[i]), got[i], any[i]] {
                    proptest::prop_assert_eq!(
                        v.to_bits(), want.to_bits(), "slot {}: {} against {}", i, v, want
                    );
                }
            }
            proptest::prop_assume!(checked > 0);
        }
    }

    #[test]
    fn overflowed_or_undefined_sums_are_no_correlation() {
        // y = 2x + 1 over x = 1, 2, 3 (the doc's example) but with Σxy replaced
        let vx = 3.0 * 14.0 - 6.0 * 6.0;
        for sxy in [f64::INFINITY, f64::NEG_INFINITY, f64::NAN, f64::MAX] {
            let mut out = [7.0; 5];
            let xy = [34.0, sxy, 34.0, sxy, sxy];
            pearson_range(3.0, 6.0, vx, &xy, &[15.0; 5], &[83.0; 5], &mut out);
            let mut portable = [7.0; 5];
            pearson_range_portable(3.0, 6.0, vx, &xy, &[15.0; 5], &[83.0; 5], &mut portable);
            // 3·f64::MAX overflows to ∞ in n·Σxy: no correlation either
            assert_eq!(out, [1.0, 0.0, 1.0, 0.0, 0.0], "Σxy = {sxy}");
            assert_eq!(portable, out, "Σxy = {sxy}");
        }
        // a finite ratio past 1 (rounding, or sums that disagree) is still clamped
        assert_eq!(pearson(3.0, 6.0, vx, 1e300, 15.0, 83.0), 1.0);
    }

    #[test]
    #[should_panic(expected = "add_products: 4 values for 3 slots and 3 products")]
    fn too_few_values_is_a_clear_panic_not_a_wrong_sum() {
        add_products(&mut [0.0; 3], &[1.0; 4], &[1.0; 3]);
    }
}
