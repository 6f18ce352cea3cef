//! The daemon's side of systemd (the protocol is `vlsync_ipc::sd_notify`):
//!
//! * `READY=1` once the services are open and the real-time thread runs;
//! * `STATUS=...` a line per status period (`systemctl status vlsyncd` shows it);
//! * `WATCHDOG=1` at half of `WATCHDOG_USEC`, sent by the service thread only while
//!   the real-time thread shows progress (see [`WatchdogGate`]): a stuck real-time
//!   loop stops the petting and systemd restarts the daemon;
//! * `STOPPING=1` when shutting down.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vlsync_common::wire::Status;
use vlsync_common::Estimate;
pub use vlsync_ipc::sd_notify::SdNotify;

/// Decides when to pet the watchdog: every `period`, and only if the real-time
/// thread's heartbeat counter moved within the last `stall_after` (so a stuck
/// real-time loop lets the watchdog expire).
#[derive(Debug)]
pub struct WatchdogGate {
    period: Duration,
    stall_after: Duration,
    next: Instant,
    last_beat: u64,
    last_change: Instant,
    stalled: bool,
}

/// How soon a withheld pet is looked at again ([`WatchdogGate::poll`]).
const STALL_RECHECK: Duration = Duration::from_millis(100);

/// What [`WatchdogGate::poll`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchdogAction {
    /// Nothing due.
    Idle,
    /// Send `WATCHDOG=1`.
    Pet,
    /// A pet was due but the real-time thread made no progress for the given time:
    /// withheld (reported once per stall).
    Withheld(Duration),
    /// Still stalled; withheld again.
    StillWithheld,
    /// Progress again after a stall; send `WATCHDOG=1`.
    Resumed,
}

impl WatchdogGate {
    /// Pets every `period`; the real-time thread counts as stuck when its
    /// heartbeat did not move for `max(period, min_stall)` (`min_stall` covers
    /// the real-time thread's own longest sleep).
    pub fn new(period: Duration, min_stall: Duration, now: Instant, beat: u64) -> Self {
        Self {
            period,
            stall_after: period.max(min_stall),
            // the first pet goes out right away: READY=1 has just been sent
            next: now,
            last_beat: beat,
            last_change: now,
            stalled: false,
        }
    }

    /// Call at least a few times per `period` with the current heartbeat.
    pub fn poll(&mut self, now: Instant, beat: u64) -> WatchdogAction {
        if beat != self.last_beat {
            self.last_beat = beat;
            self.last_change = now;
        }
        if now < self.next {
            return WatchdogAction::Idle;
        }
        let quiet = now.saturating_duration_since(self.last_change);
        if quiet <= self.stall_after {
            self.next = now + self.period;
            if std::mem::replace(&mut self.stalled, false) {
                WatchdogAction::Resumed
            } else {
                WatchdogAction::Pet
            }
        } else {
            // withheld: looked at again soon, not a period on. systemd's deadline is
            // two periods after the last pet, at most one period after this poll; a
            // thread that recovers before it is petted then (a period on, the next
            // look fell on the deadline itself and every stall past `stall_after`
            // ended in a restart)
            self.next = now + self.period.min(STALL_RECHECK);
            if std::mem::replace(&mut self.stalled, true) {
                WatchdogAction::StillWithheld
            } else {
                WatchdogAction::Withheld(quiet)
            }
        }
    }

    /// A pet that could not be sent: tried again within a second, not a period (one
    /// failed send, ENOBUFS under memory pressure, then a period's wait would miss
    /// systemd's deadline).
    pub fn retry_soon(&mut self, now: Instant) {
        self.next = now + self.period.min(Duration::from_secs(1));
    }

    /// Time until the next pet is due.
    pub fn due_in(&self, now: Instant) -> Duration {
        self.next.saturating_duration_since(now)
    }
}

/// The service thread's side of systemd: `READY=1`, the periodic `STATUS=` line,
/// the gated watchdog and `STOPPING=1`. A failure to send after a send that went out
/// is one event of the journal's throttle ([`Supervisor::failure_line`]): a lasting
/// failure is said once, a socket that fails every other send some 150 times a day.
#[derive(Debug)]
pub struct Supervisor {
    sd: SdNotify,
    gate: Option<WatchdogGate>,
    heartbeat: Arc<AtomicU64>,
    last: Option<Estimate>,
    stopping: bool,
    send_failed: bool,
    /// Failures after a send that went out, not yet handed to the throttle, and the
    /// newest one's text.
    failures: (u64, Option<String>),
}

impl Supervisor {
    /// From the environment; `heartbeat` is the counter the real-time thread
    /// increments every loop. Logs problems with the variables.
    pub fn from_env(heartbeat: Arc<AtomicU64>) -> Self {
        let (sd, problems) = SdNotify::from_env();
        for p in problems {
            tracing::warn!("systemd notification: {p}");
        }
        Self::new(sd, heartbeat)
    }

    /// With an explicit notifier.
    pub fn new(sd: SdNotify, heartbeat: Arc<AtomicU64>) -> Self {
        Self {
            sd,
            gate: None,
            heartbeat,
            last: None,
            stopping: false,
            send_failed: false,
            failures: (0, None),
        }
    }

    fn check(&mut self, r: Result<(), String>) {
        match r {
            Ok(()) => self.send_failed = false,
            Err(e) => {
                if !std::mem::replace(&mut self.send_failed, true) {
                    self.failures.0 += 1;
                    self.failures.1 = Some(e);
                }
            }
        }
    }

    /// The warning to log for the failures to notify since the last call (the first
    /// after a send that went out, each), through `throttle` at `now` (kind
    /// [`super::journal::NOTIFY_FAILED_KEY`]): `None` when there were none, or the
    /// throttle holds them back (it says their count later).
    pub fn failure_line(
        &mut self,
        throttle: &mut super::journal::Throttle,
        now: vlsync_common::Nanos,
    ) -> Option<String> {
        let (n, text) = std::mem::take(&mut self.failures);
        let text = text?;
        let held = throttle.admit(super::journal::NOTIFY_FAILED_KEY, n, now)?;
        let more = (n - 1).saturating_add(held);
        Some(if more > 0 {
            format!("{text} ({more} more since the last such line)")
        } else {
            text
        })
    }

    /// `READY=1`: the services are open and the real-time thread runs. Starts the watchdog.
    pub fn ready(&mut self, what: &str) {
        self.ready_at(what, Instant::now());
    }

    /// [`Supervisor::ready`] at `now` (the tests drive the watchdog on instants of
    /// their own).
    fn ready_at(&mut self, what: &str, now: Instant) {
        if !self.sd.enabled() {
            return;
        }
        let r = self.sd.ready(what);
        self.check(r);
        if let Some(period) = self.sd.watchdog_period() {
            tracing::info!(
                "systemd watchdog: petting every {period:?} while the real-time thread runs"
            );
            self.gate = Some(WatchdogGate::new(
                period,
                3 * super::WAKE_PERIOD,
                now,
                self.heartbeat.load(Ordering::Relaxed),
            ));
        }
        self.tick(now);
    }

    /// Remembers the newest estimate for the status line.
    pub fn on_estimate(&mut self, e: &Estimate) {
        self.last = Some(*e);
    }

    /// Sends the status line for a status snapshot.
    pub fn on_status(&mut self, st: &Status) {
        if self.sd.enabled() && !self.stopping {
            let r = self.sd.status(&status_line(st, self.last.as_ref()));
            self.check(r);
        }
    }

    /// Pets the watchdog when due and the real-time thread shows progress.
    pub fn tick(&mut self, now: Instant) {
        let Some(gate) = self.gate.as_mut() else {
            return;
        };
        if self.stopping {
            return;
        }
        match gate.poll(now, self.heartbeat.load(Ordering::Relaxed)) {
            WatchdogAction::Idle | WatchdogAction::StillWithheld => {}
            WatchdogAction::Pet => {
                let r = self.sd.watchdog();
                if r.is_err() {
                    gate.retry_soon(now);
                }
                self.check(r);
            }
            WatchdogAction::Resumed => {
                tracing::warn!("real-time thread progresses again; petting the systemd watchdog");
                let r = self.sd.watchdog();
                if r.is_err() {
                    gate.retry_soon(now);
                }
                self.check(r);
            }
            WatchdogAction::Withheld(quiet) => tracing::error!(
                "real-time thread made no progress for {quiet:?}: not petting the systemd watchdog (systemd restarts the daemon when it expires)"
            ),
        }
    }

    /// `STOPPING=1`, once.
    pub fn stopping(&mut self) {
        if self.sd.enabled() && !std::mem::replace(&mut self.stopping, true) {
            let r = self.sd.stopping("stopping");
            self.check(r);
        }
    }
}

/// The human status line: state, offset, its standard deviation, drift, counters.
pub fn status_line(st: &Status, last: Option<&Estimate>) -> String {
    let counts = format!(
        "received cam {} lidar {}, {} estimates",
        st.received[0], st.received[1], st.estimates_published
    );
    match last {
        Some(e) => format!(
            "{}: offset {:+.3} ms ± {:.3} ms, drift {:+.2} ppm{}; {counts}",
            e.state,
            e.offset_s * 1e3,
            e.offset_std_s * 1e3,
            e.drift * 1e6,
            if st.degraded != 0 { ", degraded" } else { "" }
        ),
        None => format!("waiting for both sensors; {counts}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsString;
    use std::os::unix::net::UnixDatagram;

    fn os(s: &str) -> OsString {
        OsString::from(s)
    }

    /// A notify socket that fails every other send (a status every 2.5 s, say) logs
    /// through the throttle, some 150 lines a day with the failures' count, not one
    /// line per failure after a success (17,280 a day); a lasting failure is said
    /// once.
    #[test]
    fn failures_to_notify_are_said_through_the_throttle() {
        use super::super::journal::{Throttle, THROTTLE_NS};
        let mut sv = Supervisor::new(SdNotify::disabled(), Arc::new(AtomicU64::new(0)));
        let mut t = Throttle::new(THROTTLE_NS);
        let s = 1_000_000_000i64;
        assert_eq!(sv.failure_line(&mut t, 0), None);
        let (mut lines, mut failures) = (0u64, 0u64);
        let mut first = None;
        for k in 0..34_560i64 {
            let now = k * 5 * s / 2;
            if k % 2 == 0 {
                sv.check(Err(format!("cannot notify NOTIFY_SOCKET /x: failure {k}")));
                failures += 1;
            } else {
                sv.check(Ok(()));
            }
            if let Some(line) = sv.failure_line(&mut t, now) {
                lines += 1;
                first.get_or_insert(line);
            }
            t.due(now, |_, _| lines += 1);
        }
        assert_eq!(failures, 17_280);
        assert!((100..=160).contains(&lines), "{lines} lines");
        assert_eq!(
            first.as_deref(),
            Some("cannot notify NOTIFY_SOCKET /x: failure 0")
        );
        // a lasting failure: one event, said at once (after ten quiet minutes)
        let mut sv = Supervisor::new(SdNotify::disabled(), Arc::new(AtomicU64::new(0)));
        let mut t = Throttle::new(THROTTLE_NS);
        let mut said = vec![];
        for k in 0..1000i64 {
            sv.check(Err(format!("failure {k}")));
            said.extend(sv.failure_line(&mut t, k * s));
        }
        assert_eq!(said, vec!["failure 0".to_string()]);
        // two failures between two calls: one line, the second in its count
        sv.check(Ok(()));
        sv.check(Err("a".into()));
        sv.check(Ok(()));
        sv.check(Err("b".into()));
        assert_eq!(
            sv.failure_line(&mut t, 5000 * s).as_deref(),
            Some("b (1 more since the last such line)")
        );
    }

    #[test]
    fn gate_pets_only_while_the_heartbeat_moves() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut g = WatchdogGate::new(ms(500), ms(300), t0, 7);
        assert_eq!(g.poll(t0, 7), WatchdogAction::Pet);
        assert_eq!(g.poll(t0 + ms(100), 8), WatchdogAction::Idle);
        assert_eq!(g.due_in(t0 + ms(100)), ms(400));
        assert_eq!(g.poll(t0 + ms(500), 9), WatchdogAction::Pet);
        // the heartbeat freezes at 9 (last change at 500 ms)
        assert_eq!(g.poll(t0 + ms(1000), 9), WatchdogAction::Pet);
        assert_eq!(g.poll(t0 + ms(1501), 9), WatchdogAction::Withheld(ms(1001)));
        assert_eq!(g.poll(t0 + ms(2001), 9), WatchdogAction::StillWithheld);
        // progress again
        assert_eq!(g.poll(t0 + ms(2100), 10), WatchdogAction::Idle);
        assert_eq!(g.poll(t0 + ms(2501), 10), WatchdogAction::Resumed);
        assert_eq!(g.poll(t0 + ms(3001), 11), WatchdogAction::Pet);
    }

    /// A real-time thread that stalls past `stall_after` just after a pet and
    /// recovers before systemd's deadline (two periods after that pet) is petted
    /// before the deadline: the withheld pet is looked at again within 100 ms, not a
    /// period on (which fell on the deadline itself: a 2.7 s stall under
    /// `WatchdogSec=5s` restarted the daemon).
    #[test]
    fn a_thread_that_recovers_before_the_deadline_is_petted_in_time() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        // WATCHDOG_USEC 5 s: pets every 2.5 s, stuck after 2.5 s without a beat
        let mut g = WatchdogGate::new(ms(2500), ms(1000), t0, 1);
        assert_eq!(g.poll(t0, 1), WatchdogAction::Pet);
        // the heartbeat last moved at t0
        assert_eq!(g.poll(t0 + ms(2600), 1), WatchdogAction::Withheld(ms(2600)));
        assert!(g.due_in(t0 + ms(2600)) <= ms(100));
        assert_eq!(g.poll(t0 + ms(2700), 1), WatchdogAction::StillWithheld);
        // progress at 2.75 s: petted at the next look, well before the 5 s deadline
        assert_eq!(g.poll(t0 + ms(2800), 2), WatchdogAction::Resumed);
        assert_eq!(g.due_in(t0 + ms(2800)), ms(2500));
        assert_eq!(g.poll(t0 + ms(5300), 3), WatchdogAction::Pet);
    }

    /// A pet that could not be sent is due again within a second, not a period.
    #[test]
    fn a_failed_pet_is_retried_within_a_second() {
        let t0 = Instant::now();
        let s = Duration::from_secs;
        let mut g = WatchdogGate::new(s(10), s(1), t0, 0);
        assert_eq!(g.poll(t0, 1), WatchdogAction::Pet);
        assert_eq!(g.due_in(t0), s(10));
        g.retry_soon(t0);
        assert_eq!(g.due_in(t0), s(1));
        assert_eq!(g.poll(t0 + s(1), 2), WatchdogAction::Pet);
        assert_eq!(g.due_in(t0 + s(1)), s(10));
        // a period under a second is kept
        let mut g = WatchdogGate::new(Duration::from_millis(200), s(1), t0, 0);
        g.retry_soon(t0);
        assert_eq!(g.due_in(t0), Duration::from_millis(200));
    }

    /// Every datagram waiting on `rx` (non-blocking): a send to a Unix datagram
    /// socket is queued at the receiver when `send_to` returns, so what a `tick` sent
    /// is here when it returns.
    fn received(rx: &UnixDatagram) -> Vec<String> {
        let mut buf = [0u8; 256];
        let mut got = vec![];
        loop {
            match rx.recv(&mut buf) {
                Ok(k) => got.push(String::from_utf8_lossy(&buf[..k]).into_owned()),
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return got,
                Err(e) => panic!("receive on the test's notify socket: {e}"),
            }
        }
    }

    /// The `Supervisor`'s wiring of the gate: it sends `WATCHDOG=1` while the
    /// real-time thread's heartbeat moves, none while it stands still beyond the
    /// stall limit (systemd then restarts the daemon), again once it moves, and none
    /// after `STOPPING=1`. Synthetic instants every 100 ms (the service thread's idle
    /// poll); the datagrams go through a real socket.
    #[test]
    fn supervisor_pets_only_while_the_real_time_heartbeat_moves() {
        let dir = std::env::temp_dir().join(format!("vlsync-notify-sv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("notify.sock");
        let _ = std::fs::remove_file(&path);
        let rx = UnixDatagram::bind(&path).unwrap();
        rx.set_nonblocking(true).unwrap();
        // WATCHDOG_USEC 1 s: a pet due every 0.5 s; the real-time thread counts as
        // stuck after max(0.5 s, 3 wake periods) without a beat
        let (sd, problems) =
            SdNotify::from_values(Some(path.as_os_str()), Some(&os("1000000")), None, 1);
        assert!(problems.is_empty(), "{problems:?}");
        let period = Duration::from_millis(500);
        assert_eq!(sd.watchdog_period(), Some(period));
        let stall = period.max(3 * super::super::WAKE_PERIOD);
        let beat = Arc::new(AtomicU64::new(0));
        let mut sv = Supervisor::new(sd, beat.clone());
        let t0 = Instant::now();
        sv.ready_at("serving", t0);
        let first = received(&rx);
        assert_eq!(first.len(), 2, "{first:?}");
        assert!(first[0].starts_with("READY=1\n"), "{first:?}");
        assert_eq!(first[1], "WATCHDOG=1", "the first pet comes with READY=1");

        let ms = |m: u64| t0 + Duration::from_millis(m);
        // (instant, the heartbeat's last move then) of every pet
        let mut pets: Vec<(Instant, Instant)> = vec![(t0, t0)];
        let mut last_move = t0;
        // the heartbeat moves until 3 s, stands still until 6 s, moves again to 9 s
        let moving = |m: u64| m <= 3000 || m > 6000;
        for m in (100..=9000).step_by(100) {
            if moving(m) {
                beat.fetch_add(1, Ordering::Relaxed);
                last_move = ms(m);
            }
            sv.tick(ms(m));
            for msg in received(&rx) {
                assert_eq!(msg, "WATCHDOG=1", "at {m} ms");
                pets.push((ms(m), last_move));
            }
        }
        let at = |p: &(Instant, Instant)| (p.0 - t0).as_millis();
        let times: Vec<u128> = pets.iter().map(at).collect();
        // never a pet for a heartbeat that stood still beyond the stall limit
        for p in &pets {
            assert!(
                p.0 - p.1 <= stall,
                "pet at {} ms, the heartbeat still since {} ms: {times:?}",
                at(p),
                (p.1 - t0).as_millis()
            );
        }
        // while it moves, a pet every period: none more than a period apart (so
        // within systemd's WATCHDOG_USEC, twice that), the first stretch and the last
        let gaps_within = |from: u128, to: u128| {
            let t: Vec<u128> = times
                .iter()
                .copied()
                .filter(|&t| t >= from && t <= to)
                .collect();
            t.len() >= 2
                && t.first() == Some(&from)
                && t.windows(2).all(|w| w[1] - w[0] <= period.as_millis())
                && to - t[t.len() - 1] < period.as_millis()
        };
        assert!(gaps_within(0, 3000), "pets while it moved: {times:?}");
        // a stall of 3 s: pets stop, at most one more while within the stall limit
        let during: Vec<u128> = times
            .iter()
            .copied()
            .filter(|&t| t > 3000 && t <= 6000)
            .collect();
        assert!(
            during.len() <= 1 && during.iter().all(|&t| t <= 3000 + stall.as_millis()),
            "pets while the heartbeat stood still (3 s to 6 s): {times:?}"
        );
        // resumed within a period of the heartbeat's first move, then every period
        let resumed = times.iter().copied().find(|&t| t > 6000);
        assert!(
            resumed.is_some_and(|t| t <= 6100 + period.as_millis()),
            "no pet within a period of the heartbeat moving again: {times:?}"
        );
        assert!(
            gaps_within(resumed.unwrap(), 9000),
            "pets after the stall: {times:?}"
        );

        // STOPPING=1, and no pet after it though the heartbeat moves
        sv.stopping();
        assert_eq!(received(&rx), ["STOPPING=1\nSTATUS=stopping"]);
        for m in (9100..=11000).step_by(100) {
            beat.fetch_add(1, Ordering::Relaxed);
            sv.tick(ms(m));
        }
        assert_eq!(received(&rx), Vec::<String>::new(), "after STOPPING=1");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn status_line_shows_state_offset_and_std() {
        let st = Status {
            received: [300, 100],
            estimates_published: 12,
            ..Status::default()
        };
        assert_eq!(
            status_line(&st, None),
            "waiting for both sensors; received cam 300 lidar 100, 12 estimates"
        );
        let e = Estimate {
            seq: 3,
            t_ref_ns: 0,
            offset_s: -0.0123456,
            drift: 2.5e-6,
            offset_std_s: 0.0008,
            drift_std: 1e-6,
            state: vlsync_common::EstimatorState::Tracking,
            polarity: vlsync_common::Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: 2.0,
            measured_offset_s: f64::NAN,
        };
        assert_eq!(
            status_line(&st, Some(&e)),
            "tracking: offset -12.346 ms ± 0.800 ms, drift +2.50 ppm; received cam 300 lidar 100, 12 estimates"
        );
    }

    #[test]
    fn gate_tolerates_a_period_shorter_than_the_rt_sleep() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        // 50 ms period, the real-time thread beats every 100 ms at worst
        let mut g = WatchdogGate::new(ms(50), ms(300), t0, 0);
        let mut beat = 0;
        let mut pets = 0;
        for i in 1..=40u64 {
            if i % 10 == 0 {
                beat += 1;
            }
            let a = g.poll(t0 + ms(i * 10), beat);
            assert!(
                matches!(a, WatchdogAction::Idle | WatchdogAction::Pet),
                "{a:?} at {i}"
            );
            pets += u32::from(a == WatchdogAction::Pet);
        }
        assert!(pets >= 7, "{pets}");
    }
}
