//! A restart of both drivers (a new session: another run, both clocks back at its
//! start) that the daemon reads from a backlog: it was subscribed but not running
//! when the new drivers began (SIGSTOPped: a starved or stalled process, as a
//! daemon descheduled for a few ms is at 200x), so when it resumes both streams'
//! first seconds of the new session wait in its buffers. Each clock jump is judged
//! by the other stream's progress, so the daemon must take the two backlogs in the
//! order they were published, not one stream's after the other's: then it relocks
//! on the new offset within seconds, without a search move.

use std::time::Duration;
use vlsync_common::{EstimatorState, Stream};
use vlsync_ipc::{monotonic_ns, OffsetClient};
use vlsync_tests::{collect, locked_errors, Managed, Rig};

/// A process stopped with SIGSTOP until this guard is dropped, which resumes it with
/// SIGCONT: also when an assertion fails in between, since a stopped process acts on
/// no SIGINT or SIGTERM, and only the SIGKILL at the end of its [`Managed`] stop
/// would end it, leaving its iceoryx2 resources behind.
struct Stopped<'a>(&'a mut Managed);

impl<'a> Stopped<'a> {
    fn stop(m: &'a mut Managed) -> Self {
        m.signal("STOP").expect("SIGSTOP");
        Self(m)
    }
}

impl Drop for Stopped<'_> {
    fn drop(&mut self) {
        if let Err(e) = self.0.signal("CONT") {
            eprintln!("cannot resume {}: {e}", self.0.name);
        }
    }
}

#[test]
fn a_restart_of_both_drivers_found_in_the_backlog_relocks_without_a_search_move() {
    let speed = 4.0;
    let rig = Rig::new("backlog", "robot", 7, 60.0, speed);
    let mut daemon = rig.daemon(0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    let first = collect(&mut client, Duration::from_secs(6));
    assert!(
        !locked_errors(&first, &rig.sim).is_empty(),
        "no lock in the first session"
    );

    // the session ends; a new one (another seed, so another offset, both clocks back
    // at the start) starts 1.5 s after the daemon stopped reading, which it does
    // before the new drivers are even started: stopped after the session began, it
    // would have read its start live and the backlog this test is about would not
    // exist, so the order is made, not left to a sleep's precision. Its subscribers
    // stay on the services, and the new drivers deliver into their buffers; when it
    // resumes, 1 s of wall time (4 s of the session) waits in both of them
    assert!(cam.stop(Duration::from_secs(3)) & lidar.stop(Duration::from_secs(3)));
    let seed = 8;
    let new = vlsync_sim::generate("robot".parse().unwrap(), seed, Some(60.0));
    // a moment to read the first session's last samples, as it had before (what it has
    // not read by then comes first after the resume, which the checks below allow)
    std::thread::sleep(Duration::from_secs(1));
    let stopped = Stopped::stop(&mut daemon);
    let start_at = monotonic_ns() + 1_500_000_000;
    let mut next =
        [Stream::Cam, Stream::Lidar].map(|st| rig.session_driver(st, seed, 60.0, start_at, "new"));
    let resume = start_at + 1_000_000_000 - monotonic_ns();
    std::thread::sleep(Duration::from_nanos(resume.max(0) as u64));
    drop(stopped);

    // 10 s of wall time: 40 s of the new session
    let after = collect(&mut client, Duration::from_secs(10));
    for d in &mut next {
        assert!(d.stop(Duration::from_secs(3)));
    }
    assert!(daemon.stop(Duration::from_secs(3)));
    let log = rig.log("vlsyncd-0.log");
    assert!(
        !log.contains("searching around"),
        "the restart needed a search move:\n{log}"
    );
    // the new session starts where the clock jump sent the estimator back to the
    // acquisition, reported `lost` after a lock (the first session's last buffered
    // samples may come before)
    let start = after
        .iter()
        .position(|e| matches!(e.state, EstimatorState::Acquiring | EstimatorState::Lost))
        .expect("the restart did not restart the acquisition");
    let after = &after[start..];
    // its first lock: early, and on its own offset
    let locked: Vec<_> = after
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking)
        .collect();
    let first_lock = locked.first().expect("no lock in the new session");
    assert!(
        first_lock.t_ref_ns < 15_000_000_000,
        "first lock of the new session at t_ref {} s:\n{log}",
        first_lock.t_ref_ns as f64 * 1e-9
    );
    let errs = locked_errors(after, &new);
    let near = errs.iter().filter(|e| **e < 0.02).count();
    assert!(
        near * 10 >= errs.len() * 9,
        "the new session's estimates are off its truth: {errs:?}"
    );
}

/// A daemon stalled longer than its camera buffer holds (256 samples: 8.5 s of
/// camera, 25.6 s of LiDAR): when it resumes, the camera's oldest samples are gone,
/// so the camera's data resume 11.5 s after the LiDAR's, more than
/// `estimator.reset_jump_s`. Read in publish order that is a camera gap (the LiDAR's
/// progress covers it); read camera first, it passed for an 11.5 s step of the
/// camera's clock. The daemon must count the lost samples and find its lock again in
/// place, without a search move.
#[test]
fn a_stall_that_overflows_the_camera_buffer_is_a_gap_not_a_clock_jump() {
    let speed = 4.0;
    let rig = Rig::new("stall", "robot", 7, 90.0, speed);
    let mut daemon = rig.daemon(0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let mut drivers = [Stream::Cam, Stream::Lidar].map(|st| rig.driver(st, 0));
    let first = collect(&mut client, Duration::from_secs(5));
    assert!(
        !locked_errors(&first, &rig.sim).is_empty(),
        "no lock before the stall"
    );
    // 5 s of wall time: 20 s of the run, 11.5 s more than the camera's buffer holds
    let stopped = Stopped::stop(&mut daemon);
    std::thread::sleep(Duration::from_secs(5));
    drop(stopped);
    let after = collect(&mut client, Duration::from_secs(5));
    for d in &mut drivers {
        assert!(d.stop(Duration::from_secs(3)));
    }
    assert!(daemon.stop(Duration::from_secs(3)));
    let log = rig.log("vlsyncd-0.log");
    assert!(
        !log.contains("searching around"),
        "the stall needed a search move:\n{log}"
    );
    assert!(
        log.contains("cam: ") && log.contains("sample(s) lost"),
        "the camera's overflowed samples were not counted:\n{log}"
    );
    let errs = locked_errors(&after, &rig.sim);
    let near = errs.iter().filter(|e| **e < 0.02).count();
    assert!(
        errs.len() >= 10 && near * 10 >= errs.len() * 9,
        "after the stall the estimates are off the truth or missing: {errs:?}\n{log}"
    );
}
