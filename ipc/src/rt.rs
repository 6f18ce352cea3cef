//! Real-time settings of the calling thread/process: core pinning, SCHED_FIFO,
//! mlockall. Each returns what the system refused, so a daemon without
//! privileges starts anyway and says what it could not get.
//!
//! One of the few modules with `unsafe` (ARCHITECTURE.md lists them):
//! `sched_setscheduler` (and a thread's set of cores, [`avoid_core`], the thread CPU
//! clock, [`thread_cpu_ns`], and the kernel's clock status, [`wall_clock_synchronized`])
//! have no safe wrapper in the crates the workspace uses.
#![allow(unsafe_code)]

use std::fmt;

/// A real-time setting the system refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RtRefused {
    /// The setting (e.g. `daemon.core = 7`).
    pub setting: String,
    /// Why.
    pub reason: String,
}

impl fmt::Display for RtRefused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "could not apply {}: {}", self.setting, self.reason)
    }
}

/// The CPUs the calling thread may run on (its affinity), in order.
pub fn available_cores() -> Vec<usize> {
    let mut ids: Vec<usize> = core_affinity::get_core_ids()
        .unwrap_or_default()
        .iter()
        .map(|c| c.id)
        .collect();
    ids.sort_unstable();
    ids
}

/// Pins the calling thread to CPU `core`.
pub fn pin_current_thread(core: usize) -> Result<(), RtRefused> {
    let setting = format!("daemon.core = {core}");
    let ids = core_affinity::get_core_ids().unwrap_or_default();
    let Some(id) = ids.iter().find(|c| c.id == core) else {
        let avail: Vec<String> = ids.iter().map(|c| c.id.to_string()).collect();
        return Err(RtRefused {
            setting,
            reason: format!(
                "core {core} does not exist or is not allowed for this process (available: [{}])",
                avail.join(", ")
            ),
        });
    };
    if core_affinity::set_for_current(*id) {
        Ok(())
    } else {
        Err(RtRefused {
            setting,
            reason: "sched_setaffinity failed".to_string(),
        })
    }
}

/// Switches the calling thread to SCHED_FIFO at `priority` (1..=99).
pub fn set_current_thread_fifo(priority: i32) -> Result<(), RtRefused> {
    let setting =
        format!("SCHED_FIFO priority {priority} (daemon.fifo_priority, or --fifo-priority)");
    if !(1..=99).contains(&priority) {
        return Err(RtRefused {
            setting,
            reason: "priority must be within 1..=99".to_string(),
        });
    }
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pid 0 designates the calling thread; `param` is a valid, initialised
    // sched_param that outlives the call, and the kernel only reads it.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        let err = std::io::Error::last_os_error();
        let hint = if err.raw_os_error() == Some(libc::EPERM) {
            " (needs CAP_SYS_NICE or an RLIMIT_RTPRIO >= the priority)"
        } else {
            ""
        };
        Err(RtRefused {
            setting,
            reason: format!("sched_setscheduler: {err}{hint}"),
        })
    }
}

/// Sets the nice value of the calling thread (-20..=19; below 0 needs
/// CAP_SYS_NICE or RLIMIT_NICE). Linux keeps nice per thread, so other threads
/// of the process keep theirs. `setting` names what asked for it in the error.
pub fn set_current_thread_nice(nice: i32, setting: &str) -> Result<(), RtRefused> {
    if !(-20..=19).contains(&nice) {
        return Err(RtRefused {
            setting: setting.to_string(),
            reason: format!("nice {nice} is outside -20..=19"),
        });
    }
    // SAFETY: gettid takes no argument and cannot fail.
    let tid = unsafe { libc::gettid() };
    // SAFETY: setpriority takes plain integers and touches no memory of ours;
    // PRIO_PROCESS with a thread id designates that one thread on Linux.
    let rc = unsafe { libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, nice) };
    if rc == 0 {
        Ok(())
    } else {
        let err = std::io::Error::last_os_error();
        let hint = if matches!(err.raw_os_error(), Some(libc::EPERM | libc::EACCES)) {
            " (needs CAP_SYS_NICE or an RLIMIT_NICE allowing it)"
        } else {
            ""
        };
        Err(RtRefused {
            setting: setting.to_string(),
            reason: format!("setpriority(nice {nice}): {err}{hint}"),
        })
    }
}

/// CPU time the calling thread has used, ns (`CLOCK_THREAD_CPUTIME_ID`); `None`
/// where the clock is unavailable.
pub fn thread_cpu_ns() -> Option<i64> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec into `ts`, a valid, exclusively
    // borrowed local that outlives the call.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    // time_t and c_long are 32 bits on 32-bit Linux (a Pi with a 32-bit OS)
    #[allow(clippy::unnecessary_cast)]
    let (sec, nsec) = (ts.tv_sec as i64, ts.tv_nsec as i64);
    (rc == 0).then(|| sec.saturating_mul(1_000_000_000).saturating_add(nsec))
}

/// Whether the kernel holds the wall clock (`CLOCK_REALTIME`) synchronized: a time
/// daemon disciplining it (chrony, ntpd, systemd-timesyncd) clears `STA_UNSYNC`, and
/// the kernel sets it again once the clock's maximum error grows past 16 s without
/// an update (what `timedatectl` shows as "System clock synchronized"). `adjtimex`
/// with no modes only reads, so no privilege is needed. `false` where the kernel
/// does not say.
pub fn wall_clock_synchronized() -> bool {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: `timex` is plain integers (and padding), for which all zeros is a
        // valid value; zero `modes` asks for no change.
        let mut tx: libc::timex = unsafe { std::mem::zeroed() };
        // SAFETY: adjtimex reads `tx.modes` (0: read only) and writes the clock's
        // state into `tx`, a valid, exclusively borrowed local that outlives the call.
        let state = unsafe { libc::adjtimex(&mut tx) };
        synchronized(state, tx.status)
    }
    #[cfg(not(target_os = "linux"))]
    {
        false
    }
}

/// Moves the calling thread off CPU `core` (the real-time thread's): it may then
/// run on the other cores it was allowed, so the daemon's other threads do not
/// compete with the real-time one on its core (an isolated core, `isolcpus`, would
/// otherwise hold them there). `Ok(Some(cores))`: the cores it may use now; `Ok(None)`:
/// no other core was allowed, nothing changed.
pub fn avoid_core(core: usize) -> Result<Option<Vec<usize>>, RtRefused> {
    let rest: Vec<usize> = available_cores()
        .into_iter()
        .filter(|&c| c != core)
        .collect();
    if rest.is_empty() {
        return Ok(None);
    }
    #[cfg(target_os = "linux")]
    {
        // SAFETY: `cpu_set_t` is a plain bit array, for which all zeros (the empty
        // set) is a valid value.
        let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
        for &c in &rest {
            // SAFETY: CPU_SET writes one bit of `set` (a valid, exclusively borrowed
            // local); `c` comes from the kernel's own affinity mask, below
            // CPU_SETSIZE.
            unsafe { libc::CPU_SET(c, &mut set) };
        }
        // SAFETY: the size passed is `set`'s own, and the kernel only reads `set`,
        // which outlives the call; pid 0 is the calling thread.
        let rc =
            unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) };
        if rc != 0 {
            return Err(RtRefused {
                setting: format!("the service threads off core {core}"),
                reason: format!("sched_setaffinity: {}", std::io::Error::last_os_error()),
            });
        }
        Ok(Some(rest))
    }
    #[cfg(not(target_os = "linux"))]
    {
        Ok(None)
    }
}

/// What `adjtimex`'s return value (the clock state, -1 on error) and `status`
/// flags say of the wall clock's synchronization.
#[cfg(target_os = "linux")]
fn synchronized(state: libc::c_int, status: libc::c_int) -> bool {
    state >= 0 && state != libc::TIME_ERROR && status & libc::STA_UNSYNC == 0
}

/// Locks all current and future pages of the process in RAM.
pub fn lock_all_memory() -> Result<(), RtRefused> {
    // SAFETY: mlockall takes only flags and touches no memory of ours.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if rc == 0 {
        Ok(())
    } else {
        Err(RtRefused {
            setting: "daemon.lock_memory = true".to_string(),
            reason: format!(
                "mlockall: {} (needs CAP_IPC_LOCK or a large enough RLIMIT_MEMLOCK)",
                std::io::Error::last_os_error()
            ),
        })
    }
}

/// The kernel's CPU latency (PM QoS) request file.
pub const CPU_LATENCY_DEVICE: &str = "/dev/cpu_dma_latency";

/// Asks the kernel to keep CPU wake-up latency at or below `us` microseconds by
/// writing the 32-bit request to `device` ([`CPU_LATENCY_DEVICE`]). The request
/// lasts while the returned file stays open (the kernel drops it on close, so a
/// crash cannot leave it behind).
pub fn request_cpu_latency(us: u32, device: &std::path::Path) -> Result<std::fs::File, RtRefused> {
    use std::io::Write;
    let refused = |what: String| RtRefused {
        setting: format!("daemon.cpu_latency_us = {us}"),
        reason: what,
    };
    let value = i32::try_from(us).map_err(|_| refused(format!("{us} µs is too large")))?;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .open(device)
        .map_err(|e| {
            let hint = if e.kind() == std::io::ErrorKind::PermissionDenied {
                " (root, or a udev rule giving the daemon's group write access)"
            } else {
                ""
            };
            refused(format!("cannot open {}: {e}{hint}", device.display()))
        })?;
    f.write_all(&value.to_ne_bytes())
        .map_err(|e| refused(format!("cannot write {}: {e}", device.display())))?;
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thread_moves_off_a_core_when_another_is_allowed() {
        let all = available_cores();
        let (moved, allowed) = std::thread::spawn(|| {
            let moved = avoid_core(0).unwrap();
            (moved, available_cores())
        })
        .join()
        .unwrap();
        // the calling thread alone moved
        assert_eq!(available_cores(), all);
        if all.len() > 1 {
            let rest: Vec<usize> = all.iter().copied().filter(|&c| c != 0).collect();
            assert_eq!(moved.as_ref(), Some(&rest));
            assert_eq!(allowed, rest);
        } else {
            // one core only: it stays there
            assert_eq!((moved, allowed), (None, all));
        }
    }

    #[test]
    fn the_clock_is_synchronized_only_when_the_kernel_says_so() {
        use libc::{STA_PLL, STA_UNSYNC, TIME_ERROR, TIME_INS, TIME_OK};
        assert!(synchronized(TIME_OK, STA_PLL));
        assert!(synchronized(TIME_INS, 0)); // a leap second announced
        assert!(!synchronized(TIME_OK, STA_PLL | STA_UNSYNC));
        assert!(!synchronized(TIME_ERROR, 0));
        assert!(!synchronized(-1, 0));
        // and the call itself works here, whatever this machine's clock
        let _ = wall_clock_synchronized();
    }

    #[test]
    fn thread_cpu_clock_advances_with_work() {
        let a = thread_cpu_ns().expect("Linux has a thread CPU clock");
        let mut x = 0u64;
        while thread_cpu_ns().unwrap() - a < 2_000_000 {
            x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
        }
        let b = thread_cpu_ns().unwrap();
        assert!(b - a >= 2_000_000 && b - a < 1_000_000_000, "{a} {b} {x}");
    }

    #[test]
    fn missing_core_is_reported_not_fatal() {
        let e = pin_current_thread(100_000).unwrap_err();
        assert!(e.to_string().contains("daemon.core = 100000"), "{e}");
        assert!(e.reason.contains("available"), "{e}");
    }

    #[test]
    fn cpu_latency_request_is_a_32_bit_value_held_open() {
        let dir = std::env::temp_dir().join(format!("vlsync-rt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let dev = dir.join("cpu_dma_latency");
        std::fs::write(&dev, b"").unwrap();
        let f = request_cpu_latency(25, &dev).unwrap();
        assert_eq!(std::fs::read(&dev).unwrap(), 25i32.to_ne_bytes());
        drop(f);
        let e = request_cpu_latency(0, &dir.join("missing")).unwrap_err();
        assert!(e.to_string().contains("daemon.cpu_latency_us = 0"), "{e}");
        assert!(e.reason.contains("missing"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn fifo_out_of_range_is_refused() {
        assert!(set_current_thread_fifo(0).is_err());
        assert!(set_current_thread_fifo(100).is_err());
    }

    fn own_thread_nice() -> i32 {
        let stat = std::fs::read_to_string("/proc/thread-self/stat").unwrap();
        let rest = &stat[stat.rfind(')').unwrap() + 1..];
        // after ')': field 3 (state) is at index 0, so nice (field 19) is at 16
        rest.split_whitespace().nth(16).unwrap().parse().unwrap()
    }

    #[test]
    fn nice_applies_to_the_calling_thread_only() {
        assert!(set_current_thread_nice(40, "x").is_err());
        let before = own_thread_nice();
        let target = (before + 3).min(19);
        // raising nice (lower priority) is always allowed
        let got = std::thread::spawn(move || {
            set_current_thread_nice(target, "test").unwrap();
            own_thread_nice()
        })
        .join()
        .unwrap();
        assert_eq!(got, target);
        assert_eq!(own_thread_nice(), before);
    }

    #[test]
    fn pinning_to_core_zero_works() {
        // core 0 exists on every machine this runs on; the kernel then lets the
        // thread run there only
        let allowed = std::thread::spawn(|| {
            pin_current_thread(0).unwrap();
            let status = std::fs::read_to_string("/proc/thread-self/status").unwrap();
            status
                .lines()
                .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))
                .map(|v| v.trim().to_string())
        })
        .join()
        .unwrap();
        assert_eq!(allowed.as_deref(), Some("0"));
    }
}
