//! Signature publishers faster than the daemon (here: both streams flooded without
//! notifying, as fast as iceoryx2 sends) does not take the daemon's real-time loop
//! away from everything else: it reads at most `MAX_SAMPLES_PER_WAKE` samples per
//! wake-up, so statuses keep coming during the flood and SIGINT stops it (cleanly,
//! on its own: no SIGTERM or SIGKILL needed).
//! Statuses have a channel of their own to the service thread: the flood's events
//! fill the event channel (thousands dropped a second), which dropped statuses too
//! (a CI run saw one status in 3.5 s).
//! Before, the loop left only when both streams were empty at the same time, which a
//! flood never allows: no status, no stop, and a frozen heartbeat (the watchdog's
//! restart of a working daemon).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vlsync_common::wire::{SignatureSample, Status, FLAG_FIRST};
use vlsync_common::Stream;
use vlsync_ipc::{
    create_node, monotonic_ns, open_or_create_pubsub, publisher, Qos, ServiceNames, StatusClient,
};
use vlsync_tests::Rig;

#[test]
fn a_flood_leaves_the_daemon_its_statuses_and_its_stop() {
    let rig = Rig::new("flood", "robot", 1, 10.0, 1.0);
    // the daemon's life is within this test's from here to its exit
    let spawned = Instant::now();
    let mut daemon = rig.daemon(0);
    let mut status = StatusClient::open(&rig.prefix).unwrap();
    let flooding = Arc::new(AtomicBool::new(true));
    let (prefix, run) = (rig.prefix.clone(), flooding.clone());
    let flood = std::thread::spawn(move || {
        let node = create_node("flood", false).unwrap();
        let names = ServiceNames::new(&prefix).unwrap();
        let ports: Vec<_> = [Stream::Cam, Stream::Lidar]
            .iter()
            .map(|&st| {
                let name = names.signature(st);
                let f = open_or_create_pubsub::<SignatureSample>(&node, &name, Qos::signature(256))
                    .unwrap();
                let p = publisher(&f, &name).unwrap();
                (f, p)
            })
            .collect();
        let mut seq = 0u64;
        while run.load(Ordering::Relaxed) {
            // both streams at 10 Hz of their clocks, moving: every sample is ten grid
            // steps of correlator work and every fifth one a hop, far more work for the
            // daemon than a send is for this thread
            let t_ns = 1_000_000_000 + seq as i64 * 100_000_000;
            let v = (seq as f64 * 0.7).sin() + (seq as f64 * 0.23).cos();
            for (_, p) in &ports {
                let mut w = SignatureSample::new(t_ns, v, seq, monotonic_ns());
                if seq == 0 {
                    w.flags |= FLAG_FIRST;
                }
                if let Ok(s) = p.loan_uninit() {
                    let _ = s.write_payload(w).send();
                }
            }
            seq += 1;
        }
        seq
    });
    // statuses (one a second) while the flood runs: until three have come and one
    // shows samples lost (the daemon could not keep up: a flood), however slow a
    // loaded machine makes them; the generous deadline only ends a test whose
    // statuses stopped (the bug: none during a flood)
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut seen = vec![];
    while (seen.len() < 3 || !seen.iter().any(|s: &Status| s.lost[1] > 0))
        && Instant::now() < deadline
    {
        if let Ok(all) = status.receive_all() {
            seen.extend(all);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    // SIGINT during the flood: the daemon stops on its own and cleanly. No SIGTERM
    // follows (`Managed::stop` sends one halfway, which would stop a daemon that
    // missed the SIGINT); 30 s is a deadline for a daemon that never stops, not a
    // measure of how fast it does
    daemon.signal("INT").unwrap();
    let exit = daemon.wait_up_to(Duration::from_secs(30));
    let life = spawned.elapsed();
    flooding.store(false, Ordering::Relaxed);
    let sent = flood.join().unwrap();
    let log = rig.log("vlsyncd-0.log");
    let received: Vec<u64> = seen.iter().map(|s| s.received[1]).collect();
    let lost: Vec<u64> = seen.iter().map(|s| s.lost[1]).collect();
    eprintln!("flood: {sent} samples sent per stream; LiDAR received {received:?}, lost {lost:?}; daemon life {life:?}");
    assert!(
        seen.len() >= 3
            && received.windows(2).all(|w| w[1] >= w[0])
            && received[received.len() - 1] > 0,
        "statuses during the flood (LiDAR samples received): {received:?}\n{log}"
    );
    // a flood: more than the daemon could read (the buffer overflowed, samples
    // lost), more than it had read by the last status
    assert!(
        lost.iter().any(|&l| l > 0) && sent > received[received.len() - 1],
        "not a flood: {sent} samples sent per stream, LiDAR received {received:?}, lost {lost:?}"
    );
    let exit =
        exit.unwrap_or_else(|| panic!("vlsyncd ran on 30 s after SIGINT during the flood\n{log}"));
    assert!(
        exit.success(),
        "no clean stop during the flood: {exit:?}\n{log}"
    );
    assert!(
        log.lines()
            .any(|l| l.contains(" INFO ") && l.trim_end().ends_with(" stopped")),
        "no \"stopped\" line after SIGINT\n{log}"
    );
    // the flood resets the estimator every few hops (its sequence gaps are time
    // jumps): a change to each of the four states is logged at most once per 10 s
    // throttle period of the daemon's life, the rest counted (a CI run's log had
    // hundreds of such lines in 4 s)
    let state_lines = log
        .lines()
        .filter(|l| l.contains(" INFO ") && l.contains("estimator state ") && l.contains(" -> "))
        .count();
    let periods = life.as_secs() / 10 + 1;
    assert!(
        state_lines as u64 <= 4 * periods,
        "{state_lines} lines of estimator state changes in {periods} throttle periods\n{log}"
    );
}
