//! What the estimator targets share: the motion both sensors see and the check of
//! every estimate.
use vlsync_common::{Estimate, EstimatorState};

/// A motion both sensors see: two incommensurate tones, seconds in.
pub fn motion(t_s: f64) -> f64 {
    (t_s * 2.1).sin() + 0.6 * (t_s * 5.3 + 1.0).sin()
}

/// An estimate is well-formed: non-negative, non-NaN standard deviations, finite
/// offset and σ while tracking, and a sequence number above the last one.
pub fn check(e: &Estimate, last_seq: &mut Option<u64>) {
    assert!(e.offset_std_s >= 0.0 && !e.offset_std_s.is_nan(), "{e:?}");
    assert!(e.drift_std >= 0.0 && !e.drift_std.is_nan(), "{e:?}");
    if e.state == EstimatorState::Tracking {
        assert!(
            e.offset_s.is_finite() && e.offset_std_s.is_finite(),
            "{e:?}"
        );
    }
    if let Some(s) = *last_seq {
        assert!(e.seq > s, "sequence {} after {s}", e.seq);
    }
    *last_seq = Some(e.seq);
}
