//! How the service thread logs what the real-time thread reports ([`RtEvent`]):
//! each kind through the journal's throttle, with the count held back.

use super::*;

/// Logs `ev`; `budget_us` is the processing budget a latency line names.
pub(super) fn log_event(
    ev: &RtEvent,
    throttle: &mut journal::Throttle,
    now: Nanos,
    budget_us: f64,
) {
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
            why,
        } => {
            let key = journal::rejected_key(stream_index(*stream), *reason);
            if let Some(n) = throttle.admit(key, 1, now) {
                tracing::warn!(
                    "{stream} sample at t={t_ns} ns rejected: {}{}{}",
                    REJECT_NAMES.get(*reason).copied().unwrap_or("?"),
                    why.map_or(String::new(), |w| format!(" ({w})")),
                    more(n)
                )
            }
        }
        RtEvent::Silence {
            stream,
            after_ns,
            limit_ns,
        } => {
            let key = journal::silence_key(stream_index(*stream));
            if let Some(n) = throttle.admit(key, 1, now) {
                tracing::warn!(
                    "{stream}: {} s without a sample (or its stamps jumped), longer than \
                     estimator.max_gap_s = {} s: the correlation breaks there (a driver \
                     restarted, a sensor stalled; said as the stream resumes; when \
                     every interval is this long, the sensor is slower than max_gap_s allows \
                     and nothing is ever estimated){}",
                    format!("{:.3}", *after_ns as f64 * 1e-9),
                    vlsync_common::text::number((*limit_ns as f64 * 1e-6).round() * 1e-3),
                    more(n)
                )
            }
        }
        RtEvent::Simulated { stream, on } => {
            let key = journal::simulated_key(stream_index(*stream), *on);
            if let Some(n) = throttle.admit(key, 1, now) {
                if *on {
                    tracing::warn!(
                        "{stream}: samples from a simulator (a driver's --sim or --render), not \
                         a sensor: the offset this daemon publishes is not the robot's (point \
                         the driver at the sensor: /etc/vlsync/{stream}.env on the Pi){}",
                        more(n)
                    )
                } else {
                    tracing::info!("{stream}: samples from a sensor again{}", more(n))
                }
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
        RtEvent::Joined { stream, before } => {
            let key = journal::joined_key(stream_index(*stream));
            if let Some(n) = throttle.admit(key, 1, now) {
                tracing::info!(
                    "{stream}: the first sample read from a publisher is its number {before}: the {before} before it were published before this daemon listened, or dropped from the full subscriber buffer before it read any (a driver's --fast burst); not counted as lost{}",
                    more(n)
                )
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
            if let Some(n) = throttle.admit(journal::INVALID_ESTIMATE_KEY, 1, now) {
                tracing::error!(
                    "estimate #{seq} has an invalid field; not published{}",
                    more(n)
                )
            }
        }
        RtEvent::PublishFailed { seq } => {
            if let Some(n) = throttle.admit(journal::PUBLISH_FAILED_KEY, 1, now) {
                tracing::warn!("estimate #{seq} could not be published{}", more(n))
            }
        }
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
        // one a summary period: not throttled; an idle stretch has no latency to tell
        RtEvent::Latency(l) => {
            if l.samples > 0 {
                tracing::info!("{}", journal::latency_line(l, budget_us))
            }
        }
        RtEvent::LastLatency(l) => {
            if l.samples > 0 {
                tracing::info!("at stop, {}", journal::latency_line(l, budget_us))
            }
        }
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
                vlsync_estimator::SearchMoveReason::Drift => format!(
                    "the acquisition found no lock in {:.0} s of motion, and the lost lock's offset has drifted out of the middle of the search",
                    m.after_s
                ),
            };
            if let Some(n) = throttle.admit(journal::SEARCH_MOVE_KEY, 1, now) {
                let causes = match m.reason {
                    // the search follows the drift: nothing to look for
                    vlsync_estimator::SearchMoveReason::Drift => "",
                    _ => " (a restored state far off, clocks that stepped apart, or an offset beyond estimator.max_lag_s of lag_center_s)",
                };
                tracing::warn!(
                    "{why}: searching around {:+.1} ms now instead of {:+.1} ms{causes}{}",
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    /// A log writer into memory.
    #[derive(Clone, Default)]
    struct Buf(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Buf {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().expect("log buffer").extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// What `f` logs, as text.
    fn logged(f: impl FnOnce()) -> String {
        let buf = Buf::default();
        let w = buf.clone();
        let sub = tracing_subscriber::fmt()
            .with_writer(move || w.clone())
            .with_ansi(false)
            .finish();
        tracing::subscriber::with_default(sub, f);
        let bytes = buf.0.lock().expect("log buffer").clone();
        String::from_utf8(bytes).expect("utf-8")
    }

    #[test]
    fn estimates_not_published_are_logged_once_per_period_with_the_count() {
        let text = logged(|| {
            let mut t = journal::Throttle::new(10_000_000_000);
            // a lasting fault: both kinds at every hop (0.5 s) for 20 s
            for seq in 0..40u64 {
                let now = seq as Nanos * 500_000_000;
                log_event(&RtEvent::PublishFailed { seq }, &mut t, now, 200.0);
                log_event(&RtEvent::InvalidEstimate { seq }, &mut t, now, 200.0);
            }
        });
        assert_eq!(text.matches("could not be published").count(), 2, "{text}");
        assert_eq!(text.matches("has an invalid field").count(), 2, "{text}");
        assert!(
            text.contains("estimate #0 could not be published\n"),
            "{text}"
        );
        assert!(
            text.contains("estimate #20 could not be published (19 more since the last such line)"),
            "{text}"
        );
        assert!(
            text.contains("estimate #20 has an invalid field; not published (19 more since"),
            "{text}"
        );
    }

    /// A LiDAR whose every interval is a gap (a 2 Hz sensor against the 0.75 s
    /// limit... here 0.5 s against 0.3 s): a warning naming the key and both
    /// durations, once per period with the count, as a warning, per stream.
    #[test]
    fn silences_are_said_once_per_period_with_the_limit() {
        let text = logged(|| {
            let mut t = journal::Throttle::new(10_000_000_000);
            for k in 0..40i64 {
                let ev = RtEvent::Silence {
                    stream: Stream::Lidar,
                    after_ns: 500_000_000,
                    limit_ns: 300_000_000,
                };
                log_event(&ev, &mut t, k * 500_000_000, 200.0);
            }
        });
        assert_eq!(
            text.matches("lidar: 0.500 s without a sample").count(),
            2,
            "{text}"
        );
        assert!(
            text.contains("longer than estimator.max_gap_s = 0.3 s")
                && text.contains("(19 more since the last such line)")
                && text.contains(" WARN "),
            "{text}"
        );
        assert!(!journal::is_info(journal::silence_key(1)));
        assert_ne!(journal::silence_key(0), journal::silence_key(1));
        assert!(journal::silence_key(1) < journal::KINDS);
        assert_eq!(
            journal::kind_text(journal::silence_key(0)),
            "cam silences longer than estimator.max_gap_s"
        );
    }
}
