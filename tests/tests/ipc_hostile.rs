//! Hostile payloads on a signature service (NaN, huge value, time going
//! backwards, unknown flags, non-zero padding, sequence numbers and publish times
//! at the ends of their ranges) are rejected and counted in the status, the
//! daemon keeps running, and the estimate is not disturbed.

use std::time::Duration;
use vlsync_common::wire::{SignatureSample, FLAG_FIRST, REJECT_MALFORMED};
use vlsync_common::{EstimatorState, RejectReason, Stream};
use vlsync_ipc::{
    create_node, monotonic_ns, OffsetClient, ServiceNames, SignaturePublisher, StatusClient,
};
use vlsync_tests::{collect, locked_errors, status_when, Rig};

#[test]
fn hostile_samples_are_rejected_counted_and_harmless() {
    let rig = Rig::new("hostile", "robot", 5, 60.0, 5.0);
    let mut daemon = rig.daemon(0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let mut status = StatusClient::open(&rig.prefix).unwrap();
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let warm = collect(&mut client, Duration::from_secs(5));
    assert!(
        !locked_errors(&warm, &rig.sim).is_empty(),
        "no lock before the attack"
    );

    let node = create_node("hostile", false).unwrap();
    let names = ServiceNames::new(&rig.prefix).unwrap();
    let evil = SignaturePublisher::open(&node, &names, Stream::Cam).unwrap();
    let now_t = rig.sim_now_ns();
    let at = |t: i64, v: f64| SignatureSample::new(t, v, 1_000_000, monotonic_ns());
    evil.publish_raw(at(now_t + 1_000_000, f64::NAN)).unwrap();
    evil.publish_raw(at(now_t + 2_000_000, f64::INFINITY))
        .unwrap();
    evil.publish_raw(at(now_t + 3_000_000, 1e300)).unwrap();
    // 3.5 s back in sensor time: behind the stream even if its driver runs 0.7 s of
    // wall time late (5x), within the reset distance (estimator.reset_jump_s = 5)
    evil.publish_raw(at(now_t - 3_500_000_000, 1.0)).unwrap();
    let mut bad_flags = at(now_t, 1.0);
    bad_flags.flags = 0x8000_0000;
    evil.publish_raw(bad_flags).unwrap();
    let mut bad_pad = at(now_t, 1.0);
    bad_pad.reserved = 7;
    evil.publish_raw(bad_pad).unwrap();
    // a flood: counted, but the log names it once and then counts it; each sample
    // also claims to be its driver's first (a restart), which is logged the same way
    const FLOOD: u64 = 300;
    for i in 0..FLOOD as i64 {
        let mut w = at(now_t + 4_000_000 + i, f64::NAN);
        w.flags |= FLAG_FIRST;
        evil.publish_raw(w).unwrap();
        if i % 50 == 49 {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    // a second publisher with hostile bookkeeping: a sequence that jumps to the end
    // of its range and back (a naive gap count reaches 2^64 and overflows), and
    // publish times no clock has (a naive latency overflows); the values are NaN,
    // so only the bookkeeping sees them
    let evil2 = SignaturePublisher::open(&node, &names, Stream::Cam).unwrap();
    for (i, (seq, publish_ns)) in [
        (0, monotonic_ns()),
        (u64::MAX, i64::MIN),
        (0, i64::MAX),
        (5, i64::MIN + 1),
    ]
    .into_iter()
    .enumerate()
    {
        let mut w = SignatureSample::new(now_t + 5_000_000 + i as i64, f64::NAN, seq, publish_ns);
        if i == 0 {
            w.flags |= FLAG_FIRST;
        }
        evil2.publish_raw(w).unwrap();
    }

    let after = collect(&mut client, rig.remaining() + Duration::from_millis(1000));
    // a status made after the drivers ended that counts every hostile sample (one
    // that does not, after 10 s, is the one the assertions below then show)
    let t_end = monotonic_ns();
    let st = status_when(&mut status, Duration::from_secs(10), |st| {
        let rej = st.rejected[0];
        st.publish_ns > t_end
            && rej[RejectReason::NonFinite.index()] >= 2 + FLOOD
            && rej[RejectReason::TooLarge.index()] >= 1
            && rej[RejectReason::Backwards.index()] >= 1
            && rej[REJECT_MALFORMED] >= 2
            && st.lost[0] >= 4
    })
    .expect("status");
    assert!(
        daemon.running(),
        "the daemon died:\n{}",
        rig.log("vlsyncd-0.log")
    );
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(daemon.stop(Duration::from_secs(3)));
    // the jump to u64::MAX is no loss, the 0 -> 5 after it four lost samples (and
    // the real camera driver, at 5x, loses none or a few)
    assert!((4..100).contains(&st.lost[0]), "{st:?}");

    let cam_rej = st.rejected[0];
    assert!(
        cam_rej[RejectReason::NonFinite.index()] >= 2 + FLOOD,
        "{st:?}"
    );
    let log = rig.log("vlsyncd-0.log");
    let lines = log.matches("rejected: non_finite").count();
    assert_eq!(lines, 1, "each rejected sample logged:\n{log}");
    let held: u64 = log
        .lines()
        .filter(|l| l.contains("more cam samples rejected (non_finite)"))
        .filter_map(|l| {
            l.split(" WARN ")
                .nth(1)?
                .split_whitespace()
                .nth(1)?
                .parse::<u64>()
                .ok()
        })
        .sum();
    // every rejection is in the log's counts (unless the event channel overflowed,
    // which the status counts too)
    let n = cam_rej[RejectReason::NonFinite.index()];
    assert!(
        held < n && held + 1 + st.events_dropped >= n,
        "{n} {st:?}\n{log}"
    );
    // the real driver's start, the flood's first claim, and at most a count of the
    // rest (it used to be a line per sample)
    let restarts = log.matches("cam driver (re)started").count();
    assert!(
        (1..=3).contains(&restarts),
        "{restarts} restart lines:\n{log}"
    );
    assert!(cam_rej[RejectReason::TooLarge.index()] >= 1, "{st:?}");
    assert!(cam_rej[RejectReason::Backwards.index()] >= 1, "{st:?}");
    assert_eq!(cam_rej[REJECT_MALFORMED], 2, "{st:?}");
    // the first malformed sample's line says what was wrong with it (the second is
    // counted in the throttle's next line)
    assert!(
        log.contains("rejected: malformed (unknown flag bits 0x80000000 (known: 0x3))"),
        "{log}"
    );
    assert_eq!(st.rejected_total(1), 0, "{st:?}");
    // the estimator never fell back to acquisition and stays near the truth
    assert!(
        after.iter().all(|e| e.state != EstimatorState::Acquiring),
        "the attack reset the estimator"
    );
    let errs = locked_errors(&after, &rig.sim);
    assert!(errs.len() >= 10);
    assert!(
        errs.iter().all(|e| *e < 0.02),
        "errors after the attack: {errs:?}"
    );
}
