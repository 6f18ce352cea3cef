//! A signature publisher that never notifies (a third-party driver that skips the
//! `<prefix>/signature/ready` event) is still served: the daemon reads every stream
//! after the first sample of each wake-up, and on its 100 ms timeout, so the LiDAR
//! samples published this way reach the estimator, none is lost, and the daemon
//! locks on the truth.

use std::time::Duration;
use vlsync_common::wire::{SignatureSample, FLAG_FIRST};
use vlsync_common::Stream;
use vlsync_ipc::{
    create_node, monotonic_ns, open_or_create_pubsub, publisher, OffsetClient, Qos, ServiceNames,
    StatusClient,
};
use vlsync_tests::{collect, locked_errors, status_when, Rig};

#[test]
fn a_publisher_that_does_not_notify_is_served() {
    let speed = 4.0;
    let rig = Rig::new("quiet", "robot", 3, 40.0, speed);
    let mut daemon = rig.daemon(0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let mut status = StatusClient::open(&rig.prefix).unwrap();
    let mut cam = rig.driver(Stream::Cam, 0);

    // the LiDAR stream, published by this test on the drivers' schedule, no notify
    let (prefix, start_at, samples) = (rig.prefix.clone(), rig.start_at, rig.sim.lidar.clone());
    let anchor = rig.sim.cam[0].t_ns.min(rig.sim.lidar[0].t_ns);
    let lidar = std::thread::spawn(move || {
        let node = create_node("quiet-lidar", false).unwrap();
        let names = ServiceNames::new(&prefix).unwrap();
        let name = names.signature(Stream::Lidar);
        let f =
            open_or_create_pubsub::<SignatureSample>(&node, &name, Qos::signature(256)).unwrap();
        let p = publisher(&f, &name).unwrap();
        for (seq, s) in samples.iter().enumerate() {
            let due = start_at + ((s.t_ns - anchor) as f64 / speed) as i64;
            let wait = due - monotonic_ns();
            if wait > 0 {
                std::thread::sleep(Duration::from_nanos(wait as u64));
            }
            let mut w = SignatureSample::new(s.t_ns, s.value, seq as u64, monotonic_ns());
            if seq == 0 {
                w.flags |= FLAG_FIRST;
            }
            p.loan_uninit().unwrap().write_payload(w).send().unwrap();
        }
        samples.len() as u64
    });

    let est = collect(&mut client, rig.remaining() + Duration::from_millis(1000));
    let published = lidar.join().unwrap();
    let st = status_when(&mut status, Duration::from_secs(10), |st| {
        st.received[1] >= published
    })
    .expect("a status from the daemon");
    assert!(cam.stop(Duration::from_secs(3)));
    assert!(daemon.stop(Duration::from_secs(3)));
    let log = rig.log("vlsyncd-0.log");
    assert_eq!(st.received[1], published, "{st:?}\n{log}");
    assert_eq!(st.lost, [0, 0], "{st:?}\n{log}");
    let errs = locked_errors(&est, &rig.sim);
    assert!(
        errs.len() >= 20,
        "only {} locked estimates:\n{log}",
        errs.len()
    );
    let tail = &errs[errs.len() - 20..];
    assert!(
        tail.iter().all(|e| *e < 0.015),
        "off the truth: {tail:?}\n{log}"
    );
}
