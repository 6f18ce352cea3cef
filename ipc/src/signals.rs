//! Termination signals without iceoryx2's signal handler.
//!
//! iceoryx2 0.10 installs, the first time its POSIX layer's `SignalHandler` is
//! used (creating a zeroed shared-memory segment does it, so does asking it whether
//! a termination was requested), a handler for twelve signals (SIGCONT, SIGABRT,
//! SIGINT, SIGQUIT, SIGTERM, SIGTSTP, SIGTTIN, SIGTTOU, SIGUSR1, SIGPROF, SIGURG,
//! SIGVTALRM) that only stores the *last* signal in one slot. That loses a stop:
//! systemd stops a unit with SIGTERM followed at once by SIGCONT, which overwrote the
//! SIGTERM before the daemon looked; the watchdog's SIGABRT and Ctrl-Z did nothing;
//! an application using the client library had its own handlers replaced.
//!
//! [`tame_iceoryx2_signals`] (called by every `create_node`) lets iceoryx2 set its
//! handlers up once, then puts back the actions those twelve signals had before, so
//! a process keeps its signal dispositions. [`handle_termination_signals`] installs
//! vlsync's own SIGINT/SIGTERM handler, which sets a flag that stays set:
//! [`termination_requested`] reads it.
#![allow(unsafe_code)]

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Once;

/// Set by [`on_termination`], never cleared.
static TERMINATION: AtomicBool = AtomicBool::new(false);

/// The signals iceoryx2's `SignalHandler` takes over (its "non-fatal fetchable" list).
const TAKEN: [libc::c_int; 12] = [
    libc::SIGCONT,
    libc::SIGABRT,
    libc::SIGINT,
    libc::SIGQUIT,
    libc::SIGTERM,
    libc::SIGTSTP,
    libc::SIGTTIN,
    libc::SIGTTOU,
    libc::SIGUSR1,
    libc::SIGPROF,
    libc::SIGURG,
    libc::SIGVTALRM,
];

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
/// the actions every signal it took had before: the process keeps its own signal
/// handling (default actions, an application's handlers, vlsync's own). Called by
/// [`crate::create_node`] before any iceoryx2 resource exists; later calls do
/// nothing.
pub fn tame_iceoryx2_signals() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let before = TAKEN.map(current_action);
        // the first use of iceoryx2's SignalHandler creates it, which installs its
        // handlers; it never installs them again
        let _ = iceoryx2_bb_posix::signal::SignalHandler::call_and_fetch(|| ());
        for (signal, action) in TAKEN.iter().zip(before.iter()) {
            if let Some(a) = action {
                set_action(*signal, a);
            }
        }
    });
}

/// Installs vlsync's SIGINT/SIGTERM handler (once per process): from then on a stop
/// request sets the flag [`termination_requested`] reads, and no later signal (the
/// SIGCONT systemd sends after SIGTERM) clears it. `SA_RESTART`, so other system
/// calls carry on; waits with a timeout still return early (Linux does not restart
/// them), and the loops check the flag at least every 100 ms.
pub fn handle_termination_signals() {
    static ONCE: Once = Once::new();
    tame_iceoryx2_signals();
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
    });
}

/// True once SIGINT or SIGTERM arrived after [`handle_termination_signals`] (which
/// `create_node(_, true)` calls), and from then on, in every thread.
pub fn termination_requested() -> bool {
    TERMINATION.load(Ordering::SeqCst)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The process keeps the actions its signals had: iceoryx2's set-up (here
    /// forced, as a node's first shared memory does) leaves SIGUSR2's and SIGCONT's
    /// as they were, and SIGTERM reaches vlsync's flag even when SIGCONT follows
    /// at once, as systemd sends them.
    #[test]
    fn iceoryx2_keeps_its_hands_off_and_a_stop_survives_sigcont() {
        let usr1_before = current_action(libc::SIGUSR1).unwrap().sa_sigaction;
        let cont_before = current_action(libc::SIGCONT).unwrap().sa_sigaction;
        tame_iceoryx2_signals();
        // iceoryx2 asked again (it would, inside shared-memory creation): no new handler
        let _ = iceoryx2_bb_posix::signal::SignalHandler::call_and_fetch(|| ());
        assert_eq!(
            current_action(libc::SIGUSR1).unwrap().sa_sigaction,
            usr1_before
        );
        assert_eq!(
            current_action(libc::SIGCONT).unwrap().sa_sigaction,
            cont_before
        );
        handle_termination_signals();
        assert_eq!(
            current_action(libc::SIGTERM).unwrap().sa_sigaction,
            on_termination as extern "C" fn(libc::c_int) as libc::sighandler_t
        );
        assert!(!termination_requested());
        // SAFETY: raising a signal whose handler is `on_termination` (SIGTERM) or
        // whose action is the default "continue" (SIGCONT) in a running process.
        unsafe {
            libc::raise(libc::SIGTERM);
            libc::raise(libc::SIGCONT);
        }
        assert!(termination_requested());
        assert!(termination_requested(), "the flag stays set");
    }
}
