//! How the service thread logs what the real-time thread reports ([`RtEvent`]), and
//! its own findings (publishers and clients iceoryx2 could not connect, streams
//! silent for good): each kind through the journal's throttle, with the count held
//! back.

use super::*;

/// Logs `ev`; `budget_us` is the processing budget a latency line names.
pub(super) fn log_event(
    ev: &RtEvent,
    throttle: &mut journal::Throttle,
    now: Nanos,
    budget_us: f64,
) {
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
        RtEvent::ChangeDeclared { t_lidar_ns } => {
            if let Some(n) = throttle.admit(journal::HINT_DECLARED_KEY, 1, now) {
                tracing::info!(
                    "load hint: estimator told the offset may have stepped at LiDAR t={:.3} s{}",
                    *t_lidar_ns as f64 * 1e-9,
                    more(n)
                )
            }
        }
        RtEvent::HintUndated => {
            if let Some(n) = throttle.admit(journal::HINT_UNDATED_KEY, 1, now) {
                tracing::info!(
                    "load hint before any LiDAR sample: nothing to restart yet{}",
                    more(n)
                )
            }
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
        RtEvent::NotifyFlood => {
            if let Some(n) = throttle.admit(journal::NOTIFY_FLOOD_KEY, 1, now) {
                tracing::warn!("real-time loop: {}{}", super::rt::EMPTY_WAKES_SAID, more(n))
            }
        }
    }
}

/// ` (N more since the last such line)` for `n` > 0.
pub(super) fn more(n: u64) -> String {
    if n > 0 {
        format!(" ({n} more since the last such line)")
    } else {
        String::new()
    }
}

/// Says (a warning, through the throttle) when the real-time thread's subscribers
/// counted a publisher they could not connect since the last call (`told`: the counts
/// already taken): its samples are not read, silently otherwise (iceoryx2 tries again
/// only when a publisher joins or leaves). A driver of another user crash-looping
/// every 2 s makes one a restart: the throttle keeps that to some 150 lines a day.
pub(super) fn tell_unconnected(
    counts: &[AtomicU64; 2],
    told: &mut [u64; 2],
    names: &ServiceNames,
    throttle: &mut journal::Throttle,
    now: Nanos,
) {
    for stream in [Stream::Cam, Stream::Lidar] {
        let si = stream_index(stream);
        let n = counts[si].load(Ordering::Relaxed);
        if n <= told[si] {
            continue;
        }
        let new = n - told[si];
        told[si] = n;
        if let Some(held) = throttle.admit(journal::unconnected_key(si), new, now) {
            tracing::warn!(
                "{stream}: a publisher of {} could not be connected ({} time(s) since the last \
                 such line, {n} in all; iceoryx2 could not map its data: memory, file \
                 descriptors, or files of another user): its samples are not read until a \
                 publisher of the stream starts or stops (restart that driver)",
                names.signature(stream),
                new.saturating_add(held)
            );
        }
    }
}

/// Says (a warning, through the throttle, kind `key`) when a publisher of the service
/// `service` could not connect a client or found a client's connection corrupt since
/// the last call (`told`: the count already taken): that client receives no `what`
/// (a crashed or foreign subscriber, or one whose memory could not be mapped).
/// `retries`: when iceoryx2 tries again. The offset's and the status's publishers
/// both count such failures (`vlsync_ipc::publisher_telling`), where iceoryx2's
/// default would log an error at every send.
pub(super) fn tell_clients(
    count: &AtomicU64,
    told: &mut u64,
    key: usize,
    service: &str,
    (what, retries): (&str, &str),
    throttle: &mut journal::Throttle,
    now: Nanos,
) {
    let n = count.load(Ordering::Relaxed);
    if n <= *told {
        return;
    }
    let new = n - *told;
    *told = n;
    if let Some(held) = throttle.admit(key, new, now) {
        tracing::warn!(
            "{service}: a client could not be connected or its connection is corrupt ({} \
             attempt(s) since the last such line, {n} in all; iceoryx2 tries again {retries}): \
             that client receives no {what} until it reopens the service",
            new.saturating_add(held)
        );
    }
}

/// Watches both streams' received counts (`received`, the real-time thread's) at `now`
/// and logs what the watch finds: a stream silent for [`journal::SILENT_STREAM_NS`]
/// as a warning (through the throttle), naming since when (`start_ns`: the daemon's
/// start, on the same clock); its return as information, once, when its silence was
/// said.
pub(super) fn tell_silent_streams(
    watch: &mut journal::SilentStreams,
    received: [u64; 2],
    throttle: &mut journal::Throttle,
    now: Nanos,
    start_ns: Nanos,
) {
    let name = |si: usize| if si == 0 { Stream::Cam } else { Stream::Lidar };
    for news in watch.observe(received, now).into_iter().flatten() {
        match news {
            journal::StreamNews::Silent {
                si,
                since_ns,
                for_ns,
                ever,
            } => {
                let Some(n) = throttle.admit(journal::silent_stream_key(si), 1, now) else {
                    continue;
                };
                watch.said(si);
                let stream = name(si);
                if ever {
                    tracing::warn!(
                        "{stream}: nothing received for {:.0} s (since {:.1} s into the run): \
                         its driver stopped or hung, or its sensor stalled (`systemctl status \
                         vlsync-{stream}`); the estimate holds, then is lost{}",
                        for_ns as f64 * 1e-9,
                        since_ns.saturating_sub(start_ns) as f64 * 1e-9,
                        more(n)
                    )
                } else {
                    tracing::warn!(
                        "{stream}: nothing received in the {:.0} s since the daemon started: \
                         is its driver running, on this prefix (`systemctl status \
                         vlsync-{stream}`)? No offset without it{}",
                        for_ns as f64 * 1e-9,
                        more(n)
                    )
                }
            }
            journal::StreamNews::Resumed { si, after_ns } => tracing::info!(
                "{}: samples received again after {:.0} s without one",
                name(si),
                after_ns as f64 * 1e-9
            ),
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

    const S: Nanos = 1_000_000_000;

    /// A driver of another user crash-looping every 2 s: each restart a publisher the
    /// daemon cannot connect. Once a warning per restart (43,200 a day); through the
    /// throttle some 150, every failure in a line's count, per stream.
    #[test]
    fn unconnected_publishers_are_said_through_the_throttle() {
        let names = ServiceNames::new("vlsync/robot").unwrap();
        let counts = [AtomicU64::new(0), AtomicU64::new(0)];
        let mut told = [0u64; 2];
        let mut counted = 0u64;
        let text = logged(|| {
            let mut t = journal::Throttle::new(journal::THROTTLE_NS);
            // the service thread's poll every 0.1 s, a failed join every 2 s
            for i in 0..864_000i64 {
                if i % 20 == 0 {
                    counts[1].fetch_add(1, Ordering::Relaxed);
                }
                tell_unconnected(&counts, &mut told, &names, &mut t, i * S / 10);
                t.due(i * S / 10, |k, n| {
                    assert_eq!(k, journal::unconnected_key(1));
                    counted += n;
                    report_suppressed(k, n)
                });
            }
            t.due(Nanos::MAX, |_, n| counted += n);
        });
        let lines = text.lines().count() as u64;
        assert!((140..=160).contains(&lines), "{lines} lines");
        let first = text.lines().next().unwrap();
        assert!(
            first.contains(" WARN ")
                && first.contains("lidar: a publisher of vlsync/robot/lidar/signature could not be connected (1 time(s) since the last such line, 1 in all;"),
            "{first}"
        );
        // every failure in a line: the named ones' and the held counts
        counted += text
            .lines()
            .filter_map(|l| l.split_once("could not be connected (")?.1.split_once(' '))
            .map(|(n, _)| n.parse::<u64>().unwrap())
            .sum::<u64>();
        assert_eq!(counted, 43_200);
        assert_eq!(told, [0, 43_200]);
    }

    /// A corrupt connection of a status client (or an offset client) counts at every
    /// status sent (once a second: iceoryx2's default logged an error each time, 86,400
    /// a day): said through the throttle, with its own key per service.
    #[test]
    fn clients_not_served_are_said_through_the_throttle() {
        let count = AtomicU64::new(0);
        let other = AtomicU64::new(0);
        let (mut told, mut told_other, mut held) = (0u64, 0u64, 0u64);
        let text = logged(|| {
            let mut t = journal::Throttle::new(journal::THROTTLE_NS);
            for i in 0..86_400i64 {
                count.fetch_add(1, Ordering::Relaxed);
                for (c, told, key, service) in [
                    (&count, &mut told, journal::STATUS_CLIENTS_KEY, "p/status"),
                    (
                        &other,
                        &mut told_other,
                        journal::OFFSET_CLIENTS_KEY,
                        "p/offset",
                    ),
                ] {
                    tell_clients(
                        c,
                        told,
                        key,
                        service,
                        ("statuses", "at every status sent"),
                        &mut t,
                        i * S,
                    );
                }
                t.due(i * S, report_suppressed);
            }
            t.due(Nanos::MAX, |_, n| held += n);
        });
        let lines = text.lines().count();
        assert!((140..=160).contains(&lines), "{lines} lines");
        assert!(
            text.lines().next().unwrap().contains(
                "p/status: a client could not be connected or its connection is corrupt (1 \
                 attempt(s) since the last such line, 1 in all; iceoryx2 tries again at every \
                 status sent): that client receives no statuses until it reopens the service"
            ),
            "{text}"
        );
        // every attempt in a line's count (the stop's flush of the throttle: none held)
        let said: u64 = text
            .lines()
            .filter_map(|l| l.split_once("corrupt (")?.1.split_once(' '))
            .map(|(n, _)| n.parse::<u64>().unwrap())
            .sum();
        assert_eq!(said + held, 86_400);
        assert!(!text.contains("p/offset"), "{text}");
        assert_eq!(told, 86_400);
    }

    /// A LiDAR driver that hangs at 20 s while the camera's goes on: one warning at
    /// 50 s naming the stream and since when, nothing more while it lasts, one line
    /// when it comes back; a camera never started is said from the watch's start.
    #[test]
    fn a_stream_silent_for_good_is_warned_once_and_its_return_said() {
        let text = logged(|| {
            let mut t = journal::Throttle::new(journal::THROTTLE_NS);
            let start = 3 * S;
            let mut w = journal::SilentStreams::new(journal::SILENT_STREAM_NS, start);
            let mut lidar = 0;
            for i in 30..6000i64 {
                let now = i * S / 10;
                if now <= 20 * S || now >= 500 * S {
                    lidar += 1;
                }
                tell_silent_streams(&mut w, [0, lidar], &mut t, now, start);
                t.due(now, report_suppressed);
            }
        });
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 3, "{text}");
        assert!(
            lines[0].contains(" WARN ")
                && lines[0].contains(
                    "cam: nothing received in the 30 s since the daemon started: is its driver running"
                ),
            "{text}"
        );
        assert!(
            lines[1].contains(" WARN ")
                && lines[1].contains("lidar: nothing received for 30 s (since 17.0 s into the run): its driver stopped or hung"),
            "{text}"
        );
        assert!(
            lines[2].contains(" INFO ")
                && lines[2].contains("lidar: samples received again after 480 s without one"),
            "{text}"
        );
    }

    /// Load hints (up to one per 10 s) go through the throttle: a load that flaps
    /// for a day is not two lines every 10 s.
    #[test]
    fn load_hints_are_said_through_the_throttle() {
        let text = logged(|| {
            let mut t = journal::Throttle::new(journal::THROTTLE_NS);
            for k in 0..8640i64 {
                let ev = RtEvent::ChangeDeclared {
                    t_lidar_ns: k * 10 * S,
                };
                log_event(&ev, &mut t, k * 10 * S, 200.0);
                log_event(&RtEvent::HintUndated, &mut t, k * 10 * S, 200.0);
                t.due(k * 10 * S, report_suppressed);
            }
        });
        let declared = text.matches("load hint: estimator told").count()
            + text
                .matches("more load hints told to the estimator")
                .count();
        assert!((140..=160).contains(&declared), "{declared}");
        assert!(text.contains("stepped at LiDAR t=0.000 s\n"), "{text}");
        let undated = text.matches("load hint before any LiDAR sample").count()
            + text
                .matches("more load hints before any LiDAR sample")
                .count();
        assert!((140..=160).contains(&undated), "{undated}");
        assert!(!text.contains(" WARN "), "{text}");
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
