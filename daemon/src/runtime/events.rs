//! How the service thread logs what the real-time thread reports ([`RtEvent`]):
//! each kind through the journal's throttle, with the count held back.

use super::*;

pub(super) fn log_event(ev: &RtEvent, throttle: &mut journal::Throttle, now: Nanos) {
    let more = |n: u64| {
        if n > 0 {
            format!(" ({n} more since the last such line)")
        } else {
            String::new()
        }
    };
    match ev {
        RtEvent::Rejected {
            stream,
            reason,
            t_ns,
        } => {
            let key = journal::rejected_key(stream_index(*stream), *reason);
            if let Some(n) = throttle.admit(key, 1, now) {
                tracing::warn!(
                    "{stream} sample at t={t_ns} ns rejected: {}{}",
                    REJECT_NAMES.get(*reason).copied().unwrap_or("?"),
                    more(n)
                )
            }
        }
        RtEvent::Lost { stream, count } => {
            let key = journal::lost_key(stream_index(*stream));
            if let Some(n) = throttle.admit(key, *count, now) {
                tracing::warn!("{stream}: {count} sample(s) lost (sequence gap){}", more(n))
            }
        }
        RtEvent::DriverStarted { stream } => {
            let key = journal::driver_started_key(stream_index(*stream));
            if let Some(n) = throttle.admit(key, 1, now) {
                tracing::info!("{stream} driver (re)started{}", more(n))
            }
        }
        RtEvent::State { from, to } => {
            let from_name = from.map_or("none", |s| s.name());
            // every stop of the robot holds and every start tracks again: routine
            if matches!(
                (from, to),
                (Some(EstimatorState::Tracking), EstimatorState::Holding)
                    | (Some(EstimatorState::Holding), EstimatorState::Tracking)
            ) {
                tracing::debug!("estimator state {from_name} -> {to}")
            } else if let Some(n) = throttle.admit(journal::state_key(*to), 1, now) {
                // an estimator that flaps (a hostile or flooding publisher resets it
                // every hop) logs each kind of change once per period, with the count
                tracing::info!("estimator state {from_name} -> {to}{}", more(n))
            }
        }
        RtEvent::InvalidEstimate { seq } => {
            tracing::error!("estimate #{seq} has an invalid field; not published")
        }
        RtEvent::PublishFailed { seq } => tracing::warn!("estimate #{seq} could not be published"),
        RtEvent::Degraded { on, processing_ns } => {
            if !*on {
                tracing::debug!("no budget overrun for {DEGRADED_QUIET:?}: degraded mode off")
            } else if let Some(n) = throttle.admit(journal::DEGRADED_KEY, 1, now) {
                tracing::warn!(
                    "processing took {} µs, over budget: estimator degraded (narrower search) until {DEGRADED_QUIET:?} pass without an overrun{}",
                    processing_ns / 1000,
                    more(n)
                )
            }
        }
        // persisted and shown by the service loop itself
        RtEvent::Estimate(_) => {}
        RtEvent::ChangeDeclared { t_lidar_ns } => tracing::info!(
            "load hint: estimator told the offset may have stepped at LiDAR t={:.3} s",
            *t_lidar_ns as f64 * 1e-9
        ),
        RtEvent::HintUndated => {
            tracing::info!("load hint before any LiDAR sample: nothing to restart yet")
        }
        RtEvent::LatencyStep(st) => {
            let si = stream_index(st.stream);
            if let Some(n) = throttle.admit(journal::latency_step_key(si), 1, now) {
                tracing::info!(
                    "{} stamps {:+.1} ms later from t={:.3} s on (its stamping latency stepped; followed from the stamps{}){}",
                    st.stream,
                    st.step_s * 1e3,
                    st.t_ns as f64 * 1e-9,
                    if st.checked {
                        ", checked against a dropped frame"
                    } else {
                        ""
                    },
                    more(n)
                )
            }
        }
        RtEvent::OffsetStep(st) => {
            if let Some(n) = throttle.admit(journal::OFFSET_STEP_KEY, 1, now) {
                tracing::info!(
                    "offset stepped by about {:+.1} ms at LiDAR t={:.3} s (found in the data; the estimate restarts from the data after it){}",
                    st.step_s * 1e3,
                    st.t_ns as f64 * 1e-9,
                    more(n)
                )
            }
        }
        RtEvent::SearchMoved(m) => {
            let why = match m.reason {
                vlsync_estimator::SearchMoveReason::NothingFound => format!(
                    "the acquisition found no lock in {:.0} s of motion",
                    m.after_s
                ),
                vlsync_estimator::SearchMoveReason::Unserved => format!(
                    "no correlation for {:.0} s although both streams deliver (the prediction is far from the data)",
                    m.after_s
                ),
            };
            if let Some(n) = throttle.admit(journal::SEARCH_MOVE_KEY, 1, now) {
                tracing::warn!(
                    "{why}: searching around {:+.1} ms now instead of {:+.1} ms (a restored state far off, clocks that stepped apart, or an offset beyond estimator.max_lag_s of lag_center_s){}",
                    m.to_s * 1e3,
                    m.from_s * 1e3,
                    more(n)
                )
            }
        }
        RtEvent::Fatal(what) => {
            if let Some(n) = throttle.admit(journal::RT_ERROR_KEY, 1, now) {
                tracing::error!("real-time loop: {what}{}", more(n))
            }
        }
    }
}

/// Logs the count of warnings of throttle kind `key` held back since its last line.
pub(super) fn report_suppressed(key: usize, n: u64) {
    if journal::is_info(key) {
        tracing::info!(
            "{n} more {} since the last such line",
            journal::kind_text(key)
        )
    } else {
        tracing::warn!(
            "{n} more {} since the last such line",
            journal::kind_text(key)
        )
    }
}
