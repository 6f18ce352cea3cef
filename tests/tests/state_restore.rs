//! `daemon.state_file` end to end: a daemon on a simulated run saves its last
//! good estimate when stopped; a restarted daemon starts from it (its first
//! estimates carry the saved offset instead of an acquisition search), and a
//! corrupt file is named in the log and ignored.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use vlsync_common::{EstimatorState, Stream};
use vlsync_ipc::OffsetClient;
use vlsync_tests::{assert_serving, bin, collect, write_daemon_config, Managed, Rig};
use vlsyncd::state::{load, unix_now_ns};

fn config(dir: &Path, prefix: &str, state_file: &Path) -> PathBuf {
    let keys = format!(
        "state_file = \"{}\"\nstate_max_age_s = 60.0\n",
        state_file.display()
    );
    write_daemon_config(dir, prefix, &keys)
}

/// `vlsyncd run --config cfg`, waited for until it serves (its subscribers exist
/// before the drivers' first samples, however slow its start on a loaded machine).
fn daemon(cfg: &Path, log: &Path) -> Managed {
    let mut m = Managed::spawn(
        "vlsyncd",
        &bin("vlsyncd"),
        &["run".into(), "--config".into(), cfg.display().to_string()],
        Some(log),
    )
    .expect("spawn vlsyncd");
    assert_serving(&mut m, log);
    m
}

/// A saved tracking estimate of `offset_s`, saved at `saved_unix_ns` by the daemon
/// of `prefix`, in this boot `mono_ago_s` seconds ago (the daemon dates a file of its
/// own boot by the monotonic clock; another boot's only by a wall clock it can trust,
/// which a test machine without a real-time clock or NTP has not).
fn tracking_saved(
    prefix: &str,
    offset_s: f64,
    saved_unix_ns: i64,
    mono_ago_s: i64,
) -> vlsyncd::state::SavedState {
    let boot = vlsyncd::state::BootStamp::current().map(|b| vlsyncd::state::BootStamp {
        mono_ns: b.mono_ns - mono_ago_s * 1_000_000_000,
        ..b
    });
    vlsyncd::state::SavedState {
        prefix: Some(prefix.to_string()),
        saved_unix_ns,
        boot,
        estimate: vlsync_common::Estimate {
            seq: 0,
            t_ref_ns: 0,
            offset_s,
            drift: 0.0,
            offset_std_s: 0.001,
            drift_std: 1e-6,
            state: EstimatorState::Tracking,
            polarity: vlsync_common::Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: 3.0,
            measured_offset_s: f64::NAN,
        },
    }
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

#[test]
fn saved_estimate_survives_a_restart() {
    // 90 simulated seconds at 5x: 18 s of wall time
    let rig = Rig::new("state", "robot", 11, 90.0, 5.0);
    let state_file = rig.logs.join("vlsync.state");
    let _ = std::fs::remove_file(&state_file);
    let cfg = config(&rig.logs, &rig.prefix, &state_file);
    let log0 = rig.logs.join("vlsyncd-0.log");
    let mut d0 = daemon(&cfg, &log0);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let _cam = rig.driver(Stream::Cam, 0);
    let _lidar = rig.driver(Stream::Lidar, 0);

    // run until the daemon tracks for a while
    let t0 = Instant::now();
    let mut tracking = vec![];
    while tracking.len() < 6 && t0.elapsed() < Duration::from_secs(12) {
        tracking.extend(
            collect(&mut client, Duration::from_millis(300))
                .into_iter()
                .filter(|e| e.state == EstimatorState::Tracking),
        );
    }
    assert!(
        tracking.len() >= 6,
        "only {} tracking estimates\n{}",
        tracking.len(),
        read(&log0)
    );
    assert!(d0.stop(Duration::from_secs(5)), "{}", read(&log0));
    let last = *tracking.last().unwrap();

    // the file holds a good estimate near the truth, saved just now
    let (saved, age_s) = load(&state_file, &rig.prefix, unix_now_ns(), 600.0)
        .unwrap_or_else(|e| panic!("{e}\n{}", read(&log0)))
        .unwrap_or_else(|| panic!("no state file after the stop\n{}", read(&log0)));
    assert!(age_s < 10.0, "saved {age_s} s ago");
    let s = saved.estimate;
    assert!(
        matches!(s.state, EstimatorState::Tracking | EstimatorState::Holding),
        "{s:?}"
    );
    let truth = rig.sim.truth.offset_at(s.t_ref_ns);
    assert!(
        (s.offset_s - truth).abs() < 0.02,
        "saved offset {} vs truth {truth}",
        s.offset_s
    );
    assert!(
        (s.offset_s - last.offset_s).abs() < 0.01,
        "saved {s:?}\nlast tracking {last:?}"
    );
    assert!(read(&log0).contains("last good estimate saved to"));

    // the first daemon's estimates published after the last collect (between it and
    // the stop) are still queued for the client: drain them, so that what follows
    // comes from the restarted daemon only
    let _ = collect(&mut client, Duration::from_millis(300));

    // restart on the same running drivers: the first estimates start from the file
    let log1 = rig.logs.join("vlsyncd-1.log");
    let mut d1 = daemon(&cfg, &log1);
    // the first estimate of the restarted daemon (its start-up may take seconds on a
    // loaded machine), then what follows it
    let mut first: Vec<_> = client
        .wait_all(Duration::from_secs(15))
        .unwrap_or_default()
        .into_iter()
        .map(|(e, _)| e)
        .collect();
    if !first.is_empty() {
        first.extend(collect(&mut client, Duration::from_millis(500)));
    }
    assert!(d1.running(), "{}", read(&log1));
    let text = read(&log1);
    assert!(
        text.contains(&format!(
            "state file {}: restoring offset",
            state_file.display()
        )),
        "{text}"
    );
    let e = *first
        .first()
        .unwrap_or_else(|| panic!("no estimate after the restart\n{text}"));
    // a cold start would report `acquiring` with the lag-range search value
    assert_ne!(e.state, EstimatorState::Acquiring, "{first:?}");
    assert!(
        e.state == EstimatorState::Holding,
        "first estimate after restart must hold the restored offset: {e:?}"
    );
    assert!(
        (e.offset_s - s.offset_s).abs() < 0.002 + 3.0 * e.offset_std_s.min(0.005),
        "first offset {} far from the saved {}: {first:?}",
        e.offset_s,
        s.offset_s
    );
    assert!(
        e.offset_std_s >= s.offset_std_s,
        "uncertainty not inflated: {} < saved {}",
        e.offset_std_s,
        s.offset_std_s
    );
    assert!(d1.stop(Duration::from_secs(5)), "{}", read(&log1));
}

#[test]
fn corrupt_or_stale_state_files_are_named_and_ignored() {
    let dir = std::env::temp_dir().join(format!("vlsync-it-statebad-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let state_file = dir.join("vlsync.state");
    let prefix = format!("vlsync-it/statebad-{}", std::process::id());
    let cfg = config(&dir, &prefix, &state_file);
    // two minutes old (the configuration allows one): stale
    let good = vlsyncd::state::encode(&tracking_saved(
        &prefix,
        0.031,
        unix_now_ns() - 120_000_000_000,
        120,
    ));
    // a fresh file of another robot's daemon (the same configuration file, another
    // --prefix): refused by name, not restored (that such a daemon does not save over
    // it is `state::tests::the_prefix_binds_a_file_to_its_daemon`; here nothing is
    // ever worth saving)
    let other = vlsyncd::state::encode(&tracking_saved("other/robot", 0.031, unix_now_ns(), 0));
    let cases = [
        (good.replace("0.031", "0.032"), "checksum mismatch"),
        (good[..good.len() - 30].to_string(), "truncated"),
        (good.clone(), "stale"),
        (other, "saved by the daemon of prefix `other/robot`"),
    ];
    for (i, (content, reason)) in cases.iter().enumerate() {
        std::fs::write(&state_file, content).unwrap();
        let log = dir.join(format!("vlsyncd-{i}.log"));
        let mut d = daemon(&cfg, &log);
        assert!(d.stop(Duration::from_secs(5)));
        let text = read(&log);
        let want = format!("state file {}:", state_file.display());
        let line = text
            .lines()
            .find(|l| l.contains(&want))
            .unwrap_or_else(|| panic!("no line naming {want}\n{text}"));
        assert!(
            line.contains(reason) && line.contains("cold start") && line.contains("WARN"),
            "{line}"
        );
        // the bad file is left for inspection, not overwritten (nothing good to save)
        assert_eq!(&read(&state_file), content);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A state file from another setup, 5 s off: the daemon starts from it, finds the
/// camera's data out of reach, and after 30 s of LiDAR time moves its search to
/// the configured centre, says so in its log (a warning naming both centres), and
/// tracks the truth; no tracking estimate is far off on the way.
#[test]
fn a_far_off_state_file_is_searched_away_from_and_logged() {
    // 80 simulated seconds at 8x: 10 s of wall time
    let rig = Rig::new("statefar", "robot", 22, 80.0, 8.0);
    let state_file = rig.logs.join("vlsync.state");
    let far = tracking_saved(&rig.prefix, 5.0, unix_now_ns(), 0);
    vlsyncd::state::save(&state_file, &far).unwrap();
    let cfg = config(&rig.logs, &rig.prefix, &state_file);
    let log = rig.logs.join("vlsyncd-far.log");
    let mut d = daemon(&cfg, &log);
    let mut client = OffsetClient::open(&rig.prefix).unwrap();
    let _cam = rig.driver(Stream::Cam, 0);
    let _lidar = rig.driver(Stream::Lidar, 0);
    let t0 = Instant::now();
    let mut all = vec![];
    while t0.elapsed() < Duration::from_secs(25) {
        all.extend(collect(&mut client, Duration::from_millis(300)));
        let near = all.iter().rev().take(5).filter(|e| {
            e.state == EstimatorState::Tracking
                && (e.offset_s - rig.sim.truth.offset_at(e.t_ref_ns)).abs() < 0.01
        });
        if near.count() == 5 {
            break;
        }
    }
    assert!(d.stop(Duration::from_secs(5)), "{}", read(&log));
    let text = read(&log);
    assert!(text.contains("restoring offset"), "{text}");
    let line = text
        .lines()
        .find(|l| l.contains("searching around"))
        .unwrap_or_else(|| panic!("no search move logged\n{text}"));
    assert!(
        line.contains("WARN")
            && line.contains("no correlation for 30 s")
            && line.contains("around +0.0 ms now instead of +5000.0 ms"),
        "{line}"
    );
    let tracking: Vec<_> = all
        .iter()
        .filter(|e| e.state == EstimatorState::Tracking)
        .map(|e| (e.offset_s - rig.sim.truth.offset_at(e.t_ref_ns)).abs())
        .collect();
    assert!(
        tracking.len() >= 5 && tracking.iter().rev().take(5).all(|&x| x < 0.01),
        "not tracking the truth at the end: {:?}\n{text}",
        &all[all.len().saturating_sub(5)..]
    );
    assert!(
        tracking.iter().all(|&x| x < 0.1),
        "a tracking estimate over 100 ms off\n{text}"
    );
}
