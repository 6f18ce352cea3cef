//! Correlation peak search: main peak, sub-sample refinement, second peak.

use crate::correlator::Sums;

/// A refined correlation peak.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// Refined lag position in slots (fractional).
    pub slot: f64,
    /// Correlation at the refined peak, sign removed (polarity applied).
    pub score: f64,
    /// Curvature `-d²ρ/dτ²` at the peak, per slot².
    pub curvature: f64,
    /// Polarity sign applied (+1 or -1).
    pub sign: f64,
    /// Main-to-second peak ratio (infinite when there is no competitor).
    pub ratio: f64,
    /// Slot of the integer maximum.
    pub slot_int: usize,
}

/// Searches `lo..=hi` of `sums` for the largest local maximum of `sign·ρ`
/// (both signs when `sign == 0`). `scratch` must hold at least `hi+1` values.
/// Returns `None` when the maximum lies on the range edge (the true peak is outside)
/// or the range is shorter than 3 slots.
pub fn find(sums: &Sums, lo: usize, hi: usize, sign: f64, scratch: &mut [f64]) -> Option<Peak> {
    if hi < lo + 2 || hi >= scratch.len() {
        return None;
    }
    sums.ncc_range(lo, hi, scratch);
    let signs: &[f64] = if sign == 0.0 {
        &[1.0, -1.0]
    } else if sign > 0.0 {
        &[1.0]
    } else {
        &[-1.0]
    };
    let mut best: Option<(usize, f64, f64)> = None; // slot, value, sign
    for &sg in signs {
        for (s, &r) in scratch.iter().enumerate().take(hi + 1).skip(lo) {
            let v = sg * r;
            if best.is_none_or(|(_, bv, _)| v > bv) {
                best = Some((s, v, sg));
            }
        }
    }
    let (i, _, sg) = best?;
    if i == lo || i == hi {
        return None;
    }
    let (a, b, c) = (sg * scratch[i - 1], sg * scratch[i], sg * scratch[i + 1]);
    let denom = a - 2.0 * b + c;
    let (delta, score) = if denom < 0.0 {
        let d = (0.5 * (a - c) / denom).clamp(-0.5, 0.5);
        (d, b - 0.25 * (a - c) * d)
    } else {
        (0.0, b)
    };
    // competitor: best other local maximum of the same sign, or the opposite sign's maximum
    // when the polarity was free
    let mut second = f64::NEG_INFINITY;
    for s in lo..=hi {
        let v = sg * scratch[s];
        let left = if s > lo {
            sg * scratch[s - 1]
        } else {
            f64::NEG_INFINITY
        };
        let right = if s < hi {
            sg * scratch[s + 1]
        } else {
            f64::NEG_INFINITY
        };
        if s != i && v >= left && v > right {
            second = second.max(v);
        }
        if sign == 0.0 {
            second = second.max(-v);
        }
    }
    let ratio = if second <= 0.0 {
        f64::INFINITY
    } else {
        score / second
    };
    Some(Peak {
        slot: i as f64 + delta,
        score,
        curvature: -denom.min(0.0),
        sign: sg,
        ratio,
        slot_int: i,
    })
}
