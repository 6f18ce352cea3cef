//! Hostile payloads on a signature service (NaN, huge value, time going
//! backwards, unknown flags, non-zero padding) are rejected and counted in the
//! status, and the estimate is not disturbed.

use std::time::Duration;
use vlsync_common::wire::{SignatureSample, REJECT_MALFORMED};
use vlsync_common::{EstimatorState, RejectReason, Stream};
use vlsync_ipc::{
    create_node, monotonic_ns, OffsetClient, ServiceNames, SignaturePublisher, StatusClient,
};
use vlsync_tests::{collect, locked_errors, Rig};

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
    // 2 s back in sensor time: behind the stream, within the reset distance
    evil.publish_raw(at(now_t - 2_000_000_000, 1.0)).unwrap();
    let mut bad_flags = at(now_t, 1.0);
    bad_flags.flags = 0x8000_0000;
    evil.publish_raw(bad_flags).unwrap();
    let mut bad_pad = at(now_t, 1.0);
    bad_pad.reserved = 7;
    evil.publish_raw(bad_pad).unwrap();

    let after = collect(&mut client, rig.remaining() + Duration::from_millis(1000));
    std::thread::sleep(Duration::from_millis(1200));
    let st = status.latest().unwrap().expect("status");
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    assert!(daemon.stop(Duration::from_secs(3)));

    let cam_rej = st.rejected[0];
    assert!(cam_rej[RejectReason::NonFinite.index()] >= 2, "{st:?}");
    assert!(cam_rej[RejectReason::TooLarge.index()] >= 1, "{st:?}");
    assert!(cam_rej[RejectReason::Backwards.index()] >= 1, "{st:?}");
    assert_eq!(cam_rej[REJECT_MALFORMED], 2, "{st:?}");
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
