//! Termination signals without iceoryx2's signal handler.
//!
//! iceoryx2 0.10 installs, the first time its POSIX layer's `SignalHandler` is
//! used (creating a zeroed shared-memory segment does it, so does asking it whether
//! a termination was requested), a handler for thirteen signals (SIGCONT, SIGABRT,
//! SIGINT, SIGQUIT, SIGTERM, SIGTSTP, SIGTTIN, SIGTTOU, SIGUSR1, SIGUSR2, SIGPROF,
//! SIGURG, SIGVTALRM) that only stores the *last* signal in one slot. That loses a stop:
//! systemd stops a unit with SIGTERM followed at once by SIGCONT, which overwrote the
//! SIGTERM before the daemon looked; the watchdog's SIGABRT and Ctrl-Z did nothing;
//! an application using the client library had its own handlers replaced.
//!
//! [`tame_iceoryx2_signals`] (called by every `create_node`) lets iceoryx2 set its
//! handlers up once, then puts back the action its thirteen signals had before,
//! where iceoryx2's handler is the one in place (an action another thread set
//! meanwhile stays), so a process keeps its signal dispositions; the calling thread
//! holds every signal back meanwhile, so one that arrives then reaches the restored
//! action (one another thread took in iceoryx2's slot is raised again for it).
//! [`handle_termination_signals`] installs vlsync's own SIGINT/SIGTERM (and SIGHUP,
//! unless ignored) handler, which sets a flag that stays set: [`termination_requested`]
//! reads it; and, for a process a vlsync launcher started ([`STOP_WITH_PARENT_ENV`]),
//! asks the kernel for SIGTERM when that launcher dies.
#![allow(unsafe_code)]

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Once;

/// Set by [`on_termination`], never cleared.
static TERMINATION: AtomicBool = AtomicBool::new(false);

/// The environment variable a launcher (`vlsync-demo`, `vlsync-latency`,
/// `vlsync-loadtest`, `vlsync-soak`, the tests' rigs) sets to its own process id
/// for the processes it starts: a vlsync process that finds it stops, as on
/// SIGTERM, when that launcher dies without stopping it (SIGKILL, the OOM
/// killer), where it used to run on forever (a daemon at SCHED_FIFO holding its
/// prefix and shared memory). See [`handle_termination_signals`].
pub const STOP_WITH_PARENT_ENV: &str = "VLSYNC_STOP_WITH_PARENT";

/// Every signal whose action can be set: 1..=SIGRTMAX but SIGKILL and SIGSTOP (the
/// C library's reserved ones refuse `sigaction` and are skipped).
#[cfg(test)]
fn settable() -> impl Iterator<Item = libc::c_int> {
    (1..=libc::SIGRTMAX()).filter(|&s| s != libc::SIGKILL && s != libc::SIGSTOP)
}

/// The signals iceoryx2 0.10 installs its handler on (its `NonFatalFetchableSignal`,
/// in `iceoryx2-bb-posix`'s `signal.rs`; the crate is pinned to that release).
const ICEORYX2_SIGNALS: [libc::c_int; 13] = [
    libc::SIGCONT,
    libc::SIGABRT,
    libc::SIGINT,
    libc::SIGQUIT,
    libc::SIGTERM,
    libc::SIGTSTP,
    libc::SIGTTIN,
    libc::SIGTTOU,
    libc::SIGUSR1,
    libc::SIGUSR2,
    libc::SIGPROF,
    libc::SIGURG,
    libc::SIGVTALRM,
];

/// The signals of [`ICEORYX2_SIGNALS`] whose action from before iceoryx2's set-up is
/// put back, given each one's handler `(signal, before, now)`: those where the
/// handler now is the one iceoryx2 installed. iceoryx2 does not say where its handler
/// is (a private function), but it installs that one handler on all thirteen at once:
/// it is the handler now found, in place of the one before, on most of them (at
/// least 7). Another thread that sets a few of these signals meanwhile (an application's
/// SIGINT and SIGTERM handlers) keeps its own, and where iceoryx2's handlers were in
/// place already (installed before, nothing changed) nothing is restored.
fn installed_by_iceoryx2(
    handlers: &[(libc::c_int, libc::sighandler_t, libc::sighandler_t)],
) -> Vec<libc::c_int> {
    let changed = |h: libc::sighandler_t| {
        handlers
            .iter()
            .filter(|&&(_, before, now)| now == h && before != h)
            .count()
    };
    let theirs = handlers
        .iter()
        .map(|&(_, _, now)| now)
        .filter(|&h| h != libc::SIG_DFL && h != libc::SIG_IGN)
        .find(|&h| changed(h) > ICEORYX2_SIGNALS.len() / 2);
    match theirs {
        Some(h) => handlers
            .iter()
            .filter(|&&(_, before, now)| now == h && before != h)
            .map(|&(s, _, _)| s)
            .collect(),
        None => vec![],
    }
}

extern "C" fn on_termination(_signal: libc::c_int) {
    // an atomic store is async-signal-safe
    TERMINATION.store(true, Ordering::SeqCst);
}

/// The action of `signal` now.
fn current_action(signal: libc::c_int) -> Option<libc::sigaction> {
    // SAFETY: `sigaction` with a null new action only writes the current action into
    // `old`, a properly sized, zero-initialised `libc::sigaction` owned by this frame.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        (libc::sigaction(signal, std::ptr::null(), &mut old) == 0).then_some(old)
    }
}

/// Makes `action` the action of `signal`; whether the system accepted it.
fn set_action(signal: libc::c_int, action: &libc::sigaction) -> bool {
    // SAFETY: `action` is a valid `libc::sigaction` (read from the system by
    // `current_action`, or built by `handle_termination_signals` with an
    // async-signal-safe handler and an empty mask); the old action is not asked for.
    unsafe { libc::sigaction(signal, action, std::ptr::null_mut()) == 0 }
}

/// Lets iceoryx2 install its signal handlers now (once per process), then restores
/// the action of each of its signals where its handler is the one in place: the
/// process keeps its own signal handling (default actions, an application's handlers,
/// vlsync's own, and one another thread installs meanwhile). A signal iceoryx2's
/// handler caught meanwhile is raised again, for the restored action. Called by
/// [`crate::create_node`] before any iceoryx2 resource exists; later calls do
/// nothing.
pub fn tame_iceoryx2_signals() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        use iceoryx2_bb_posix::signal::{Signal, SignalHandler};
        // every signal held back on this thread from the snapshot to the restore: a
        // stop arriving while iceoryx2 installs its handlers or before the restore
        // waits, and reaches the restored action when unblocked. Another thread of
        // the process may still take one meanwhile in iceoryx2's handler, which
        // keeps only the last signal in its slot: that one is raised again below,
        // but of two caught between two reads of the slot (systemd's SIGTERM and
        // the SIGCONT right after it) only the second is.
        // restored when dropped, on every path (iceoryx2's set-up may panic)
        let held = block_all_signals();
        let before: Vec<(libc::c_int, libc::sigaction)> = ICEORYX2_SIGNALS
            .iter()
            .filter_map(|&s| current_action(s).map(|a| (s, a)))
            .collect();
        // the first use of iceoryx2's SignalHandler creates it, which installs its
        // handlers; it never installs them again. `last_signal` takes what its slot
        // caught since (`call_and_fetch` would clear the slot after the install, and
        // erase a signal another thread caught in between)
        let first = SignalHandler::last_signal();
        let handlers: Vec<_> = before
            .iter()
            .filter_map(|(s, a)| {
                current_action(*s).map(|now| (*s, a.sa_sigaction, now.sa_sigaction))
            })
            .collect();
        let ours = installed_by_iceoryx2(&handlers);
        for (signal, action) in before.iter().filter(|(s, _)| ours.contains(s)) {
            set_action(*signal, action);
        }
        drop(held);
        // where iceoryx2's handlers were in place before (the application used
        // iceoryx2 itself first), the signal its slot held may be an old one: only
        // one caught since that first read is raised again
        let first = first.filter(|_| !ours.is_empty());
        for signal in [first, SignalHandler::last_signal()].into_iter().flatten() {
            let signal = Signal::from(signal) as libc::c_int;
            // SAFETY: raise(3) of a signal number iceoryx2 took from the system; its
            // action is the restored one (vlsync's flag for SIGINT/SIGTERM once
            // `handle_termination_signals` ran), or one another thread installed
            unsafe {
                libc::raise(signal);
            }
        }
    });
}

/// The calling thread's signal mask before [`block_all_signals`], put back when
/// dropped (the signals that arrived meanwhile are delivered then).
struct HeldSignals(Option<libc::sigset_t>);

impl Drop for HeldSignals {
    fn drop(&mut self) {
        if let Some(mask) = &self.0 {
            // SAFETY: `mask` is a valid `sigset_t` filled by `pthread_sigmask`; the
            // old mask is not asked for.
            unsafe {
                libc::pthread_sigmask(libc::SIG_SETMASK, mask, std::ptr::null_mut());
            }
        }
    }
}

/// Blocks every signal on the calling thread until the value returned is dropped.
fn block_all_signals() -> HeldSignals {
    // SAFETY: `sigfillset` initialises `all`, a zeroed `sigset_t` owned by this
    // frame; `pthread_sigmask` reads it and writes the old mask into `old`, also
    // owned by this frame.
    unsafe {
        let mut all: libc::sigset_t = std::mem::zeroed();
        let mut old: libc::sigset_t = std::mem::zeroed();
        libc::sigfillset(&mut all);
        HeldSignals((libc::pthread_sigmask(libc::SIG_BLOCK, &all, &mut old) == 0).then_some(old))
    }
}

/// Installs vlsync's SIGINT/SIGTERM handler, and SIGHUP's unless it is ignored (once
/// per process), then
/// [`tame_iceoryx2_signals`]: from then on a stop request sets the flag
/// [`termination_requested`] reads, and no later signal (the SIGCONT systemd sends
/// after SIGTERM) clears it. `SA_RESTART`, so other system calls carry on; waits
/// with a timeout still return early (Linux does not restart them), and the loops
/// check the flag at least every 100 ms.
pub fn handle_termination_signals() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // SAFETY: a zeroed `libc::sigaction` is a valid "no flags, empty mask" value;
        // `sigemptyset` initialises the mask it is given, which lives in `action`.
        let mut action: libc::sigaction = unsafe { std::mem::zeroed() };
        action.sa_sigaction = on_termination as extern "C" fn(libc::c_int) as libc::sighandler_t;
        action.sa_flags = libc::SA_RESTART;
        // SAFETY: see above; `action.sa_mask` is a valid, writable sigset_t.
        unsafe {
            libc::sigemptyset(&mut action.sa_mask);
        }
        for signal in [libc::SIGINT, libc::SIGTERM] {
            set_action(signal, &action);
        }
        // a closed terminal or ssh session (SIGHUP) stops as Ctrl-C does, with every
        // clean-up (a camera program's process group, buffered truth rows), where its
        // default action killed the process outright; unless it is ignored (`nohup`:
        // the caller asked to outlive the terminal)
        if current_action(libc::SIGHUP).is_some_and(|a| a.sa_sigaction != libc::SIG_IGN) {
            set_action(libc::SIGHUP, &action);
        }
    });
    // after ours, so a stop iceoryx2's handler caught in between reaches the flag
    tame_iceoryx2_signals();
    static FOLLOW: Once = Once::new();
    FOLLOW.call_once(follow_launcher);
}

/// With [`STOP_WITH_PARENT_ENV`] naming this process's parent: asks the kernel
/// for SIGTERM when the parent ends (`PR_SET_PDEATHSIG`; it reaches the flag
/// [`termination_requested`] reads), and stops at once if the parent has ended
/// already (between its fork and this call the signal could not be asked for).
/// A process whose parent is not the one named inherited the variable from a
/// launcher further up (a camera program's child, say): it follows nothing while
/// that launcher lives, and stops if it has gone.
fn follow_launcher() {
    let Some(launcher) = std::env::var(STOP_WITH_PARENT_ENV)
        .ok()
        .and_then(|v| v.trim().parse::<libc::pid_t>().ok())
        .filter(|&p| p > 1)
    else {
        return;
    };
    let parent_is_launcher =
        || libc::pid_t::try_from(std::os::unix::process::parent_id()) == Ok(launcher);
    if !parent_is_launcher() {
        if !alive(launcher) {
            TERMINATION.store(true, Ordering::SeqCst);
        }
        return;
    }
    // SAFETY: prctl(PR_SET_PDEATHSIG) takes a signal number and no pointer; it
    // only sets this process's parent-death signal.
    unsafe {
        libc::prctl(
            libc::PR_SET_PDEATHSIG,
            libc::SIGTERM as libc::c_ulong,
            0 as libc::c_ulong,
            0 as libc::c_ulong,
            0 as libc::c_ulong,
        );
    }
    if !parent_is_launcher() {
        TERMINATION.store(true, Ordering::SeqCst);
    }
}

/// Whether process `pid` exists (signal 0: checked, not sent; a process of
/// another user exists too).
fn alive(pid: libc::pid_t) -> bool {
    // SAFETY: kill(2) with signal 0 sends nothing; it only checks the pid.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// True once SIGINT, SIGTERM or (unless it was ignored) SIGHUP arrived after [`handle_termination_signals`] (which
/// `create_node(_, true)` calls), and from then on, in every thread.
pub fn termination_requested() -> bool {
    TERMINATION.load(Ordering::SeqCst)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The process keeps the actions its signals had: after iceoryx2's set-up (here
    /// forced, as a node's first shared memory does; asked again, as shared-memory
    /// creation does later) no signal but SIGINT, SIGTERM and SIGHUP (vlsync's, not
    /// ignored in a test process) has a handler, none of them iceoryx2's (a test process has default or ignored actions, and std's own
    /// handlers for SIGSEGV and SIGBUS); and SIGTERM reaches vlsync's flag even when
    /// SIGCONT follows at once, as systemd sends them.
    #[test]
    fn iceoryx2_keeps_its_hands_off_and_a_stop_survives_sigcont() {
        handle_termination_signals();
        let _ = iceoryx2_bb_posix::signal::SignalHandler::call_and_fetch(|| ());
        let ours = on_termination as extern "C" fn(libc::c_int) as libc::sighandler_t;
        for signal in settable() {
            let Some(a) = current_action(signal) else {
                continue;
            };
            let want_ours =
                signal == libc::SIGINT || signal == libc::SIGTERM || signal == libc::SIGHUP;
            let std_own = signal == libc::SIGSEGV || signal == libc::SIGBUS;
            // (SIGHUP stays ignored where the test runs under nohup)
            let nohup = signal == libc::SIGHUP && a.sa_sigaction == libc::SIG_IGN;
            if want_ours && !nohup {
                assert_eq!(a.sa_sigaction, ours, "signal {signal}");
            } else if !std_own {
                assert!(
                    a.sa_sigaction == libc::SIG_DFL || a.sa_sigaction == libc::SIG_IGN,
                    "signal {signal} has a handler"
                );
            }
        }
        // SAFETY: raising a signal whose handler is `on_termination` (SIGTERM) or
        // whose action is the default "continue" (SIGCONT) in a running process.
        unsafe {
            libc::raise(libc::SIGTERM);
            libc::raise(libc::SIGCONT);
        }
        assert!(termination_requested());
        assert!(termination_requested(), "the flag stays set");
    }

    /// Only the signals where iceoryx2's handler is in place get their action back:
    /// the SIGINT and SIGTERM handlers another thread of an application installed
    /// while iceoryx2 set up stay (the restore used to put back every signal whose
    /// action had changed); where iceoryx2's handlers were in place already, nothing
    /// is undone.
    #[test]
    fn only_iceoryx2s_own_handlers_are_undone() {
        let (dfl, iceoryx2, app) = (libc::SIG_DFL, 0x1000, 0x2000);
        let app_thread = |s| s == libc::SIGINT || s == libc::SIGTERM;
        let h: Vec<_> = ICEORYX2_SIGNALS
            .iter()
            .map(|&s| (s, dfl, if app_thread(s) { app } else { iceoryx2 }))
            .collect();
        let want: Vec<_> = ICEORYX2_SIGNALS
            .iter()
            .copied()
            .filter(|&s| !app_thread(s))
            .collect();
        assert_eq!(installed_by_iceoryx2(&h), want);
        // an application's handlers before, on every signal: all undone
        let h: Vec<_> = ICEORYX2_SIGNALS
            .iter()
            .map(|&s| (s, app, iceoryx2))
            .collect();
        assert_eq!(installed_by_iceoryx2(&h), ICEORYX2_SIGNALS.to_vec());
        // iceoryx2's handlers in place already, one signal changed by another thread
        let h: Vec<_> = ICEORYX2_SIGNALS
            .iter()
            .map(|&s| (s, iceoryx2, if s == libc::SIGINT { app } else { iceoryx2 }))
            .collect();
        assert!(installed_by_iceoryx2(&h).is_empty());
        // a few signals changed to one handler, the rest untouched: no set-up of
        // iceoryx2's (which changes all thirteen at once)
        let h: Vec<_> = ICEORYX2_SIGNALS
            .iter()
            .map(|&s| (s, dfl, if app_thread(s) { app } else { dfl }))
            .collect();
        assert!(installed_by_iceoryx2(&h).is_empty());
    }
}
