/*
 * vlsync_client.h - read the vlsync daemon's offset from C (and C++: vlsync_client.hpp).
 *
 * Link with libvlsync_client.so (`cargo build --release -p vlsync-capi` writes it to
 * target/release/). The library opens <prefix>/offset of the daemon's iceoryx2 services,
 * validates every payload as the Rust and Python clients do, and converts camera stamps
 * to the LiDAR time base; a second handle type reads the daemon's counters
 * (<prefix>/status, vlsync_status_*). No iceoryx2 C/C++ bindings are needed, and a
 * process should not load them beside this library: it carries its own iceoryx2, and
 * exports one of iceoryx2's symbols besides vlsync_* (__internal_default_logger, which
 * rustc exports from every cdylib and a version script cannot hide), so the two copies
 * would share that one. Use one or the other in a process.
 *
 *   char err[256];
 *   vlsync_client *c = vlsync_client_open("vlsync/robot", err, sizeof err);
 *   if (!c) { fprintf(stderr, "%s\n", err); return 1; }
 *   vlsync_estimate e;
 *   if (vlsync_client_wait_next(c, 1000, &e, err, sizeof err) == 1)
 *       printf("%s offset %.3f ms\n", vlsync_state_name(e.state), e.offset_s * 1e3);
 *   vlsync_client_close(c);
 *
 * Clock convention: offset = t_lidar - t_cam for one event, so t_lidar = t_cam + offset;
 * drift = d offset / d t_lidar. Times are integer nanoseconds; publish_ns is
 * CLOCK_MONOTONIC. An estimate's offset refers to its t_ref_ns, which lags the newest
 * LiDAR data by the daemon's reference lag (3 s by default):
 * vlsync_client_camera_to_lidar extrapolates with the drift.
 *
 * Staleness: check an estimate's state AND its age (vlsync_estimate_age_ns, i.e.
 * CLOCK_MONOTONIC now - publish_ns). The daemon publishes one per hop (0.5 s by
 * default); when it stops, nothing clears the client's last estimate: latest() and
 * camera_to_lidar() keep returning 1 with it, its state still "tracking" (or
 * "holding"), its std_s growing only by the random walk (about 2 ms after 100 s). An
 * estimate several hops old (say over 2-3 s at the default hop) means the daemon is not
 * publishing: do not treat it as a lock.
 *
 * Errors: every function checks its pointers (NULL is an error, never a crash) and
 * returns a code; those taking `err, err_len` write the reason there, NUL-terminated and
 * cut to fit (`err` may be NULL). Those without (vlsync_client_latest,
 * vlsync_client_camera_to_lidar, the two closes, vlsync_client_invalid_count,
 * vlsync_status_invalid_count) give a bare -1 (0 for the counts) and cannot report a
 * failed receive: prefer the _err variants. Every call first finds its handle among the
 * open ones: a handle closed already (a second close, a use after close), a handle of the
 * other type or a pointer that never was a handle is an error (-1, 0 for the counts,
 * "not an open handle"), not a crash. (A later open may be given the same address: a
 * stale pointer then reaches that open handle, so do not keep pointers past close.)
 * A handle is single-threaded: use it on the thread that opened it (calls from another
 * thread are refused with -1: a check that catches the mistake, not a licence to share
 * it), and close it before that thread exits: no other thread can close it, and it holds
 * one of the service's 16 subscriber places until the process exits. No function is
 * async-signal-safe: do not call one from a signal handler (set a flag there instead).
 * vlsync_client_open and vlsync_status_open may block for up to about 2 s while a
 * daemon that is starting creates the services.
 *
 * Signals: the library leaves every signal's disposition as it found it. The first open
 * in a process lets iceoryx2 install its handlers (SIGINT, SIGTERM and others) and at
 * once puts back the dispositions that were there; a signal that arrives in that short
 * window is raised again with raise(), i.e. to the opening thread only (lost if that
 * thread blocks it, as in a sigwait() design; of several such signals only the last is
 * kept). A signal ends a wait early (it returns 0) only when it is delivered to the
 * waiting thread and its handler interrupts the wait's system call (EINTR). The kernel delivers a
 * process-directed signal (Ctrl-C's SIGINT, SIGTERM) to any one thread that does not
 * block it: delivered to another thread, it leaves the wait running to its timeout (with
 * no limit, until the next estimate, which never comes while the daemon is down).
 * Multi-threaded callers should therefore wait with a bounded timeout (e.g. 250 ms) in a
 * loop that checks their own stop flag (an atomic or volatile sig_atomic_t their handler
 * or another thread sets):
 *   while (!stop) { int r = vlsync_client_wait_next(c, 250, &e, err, sizeof err); ... }
 *
 * Which call takes which estimate: vlsync_client_wait_one hands out every estimate, one
 * per call, oldest first (a recorder), starting with the daemon's last estimate before
 * vlsync_client_open when it had one (its publish time tells); vlsync_client_wait_next,
 * vlsync_client_latest and vlsync_client_camera_to_lidar (and their _err variants) take
 * everything pending and keep the newest, so an estimate they passed over is not handed
 * out by a later wait_one.
 */
#ifndef VLSYNC_CLIENT_H
#define VLSYNC_CLIENT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The ABI this header describes; compare with vlsync_client_abi_version(): a different
 * version must not be used. VLSYNC_CLIENT_ABI_MINOR counts additions to that ABI
 * (existing functions and structs unchanged): a program that calls a function of minor
 * n needs vlsync_client_abi_minor() >= n. Minor 1 added vlsync_client_abi_minor,
 * vlsync_client_latest_err, vlsync_client_camera_to_lidar_err and
 * vlsync_estimate_age_ns; a library of minor 0 has none of them (a program calling one
 * fails to load or to resolve it: "undefined symbol"). Minor 2 added
 * vlsync_status_invalid_count. */
#define VLSYNC_CLIENT_ABI_VERSION 1u
#define VLSYNC_CLIENT_ABI_MINOR 2u

/* vlsync_estimate.state */
#define VLSYNC_STATE_ACQUIRING 0 /* searching; no lock yet */
#define VLSYNC_STATE_TRACKING 1  /* locked, with a fresh measurement */
#define VLSYNC_STATE_HOLDING 2   /* locked earlier, predicted (no motion); uncertainty grows */
#define VLSYNC_STATE_LOST 3      /* too uncertain to use; reacquiring */

/* vlsync_estimate.polarity (the same definitions as in examples/c/vlsync_wire.h) */
#define VLSYNC_POLARITY_UNKNOWN 0
#define VLSYNC_POLARITY_POSITIVE 1  /* the signatures rise together */
#define VLSYNC_POLARITY_NEGATIVE (-1) /* one rises while the other falls */

typedef struct vlsync_client vlsync_client; /* opaque handle */

/* The offset service's payload as received and validated (the same layout as
 * vlsync_offset_estimate in examples/c/vlsync_wire.h), with its publish time. */
typedef struct vlsync_estimate {
    uint64_t seq;             /* +1 per estimate of one daemon run */
    int64_t t_ref_ns;         /* reference time on the LiDAR clock */
    double offset_s;          /* t_lidar - t_cam at t_ref_ns */
    double drift;             /* d offset / d t_lidar (s/s) */
    double offset_std_s;      /* one standard deviation of offset_s */
    double drift_std;         /* one standard deviation of drift */
    double peak_score;        /* correlation at the hop's peak (0: none) */
    double peak_ratio;        /* main to second peak (+inf: no second peak; 0: no peak) */
    double measured_offset_s; /* the hop's raw window measurement; NaN: none */
    int64_t publish_ns;       /* CLOCK_MONOTONIC when the daemon published it: its age */
    uint8_t state;            /* VLSYNC_STATE_* */
    int8_t polarity;          /* VLSYNC_POLARITY_*: +1, -1, 0 unknown */
    uint8_t reserved[6];      /* 0 */
} vlsync_estimate;

typedef struct vlsync_conversion {
    int64_t t_lidar_ns;       /* the camera stamp on the LiDAR clock */
    double std_s;             /* one standard deviation of t_lidar_ns, seconds */
    vlsync_estimate estimate; /* what it was converted with: check its state and age
                                 (vlsync_estimate_age_ns) */
} vlsync_conversion;

typedef struct vlsync_status_client vlsync_status_client; /* opaque handle */

/* vlsync_daemon_status.rejected[stream][reason] */
#define VLSYNC_REJECT_NON_FINITE 0
#define VLSYNC_REJECT_TOO_LARGE 1
#define VLSYNC_REJECT_BACKWARDS 2
#define VLSYNC_REJECT_REPEATED 3
#define VLSYNC_REJECT_MALFORMED 4
#define VLSYNC_REJECT_REASONS 5
/* vlsync_daemon_status.state before the first estimate */
#define VLSYNC_STATE_NONE 0xFF

/* The daemon's counters (<prefix>/status, every daemon.status_period_s), validated: the
 * layout of vlsync_status in examples/c/vlsync_wire.h. Per-stream arrays: 0 camera,
 * 1 LiDAR; latency arrays {p50, p99, max} in ns; latency_count is how many end-to-end
 * measurements end_to_end_ns covers (processing_ns covers every valid sample, which may
 * be more: samples without a usable driver publish time). */
typedef struct vlsync_daemon_status {
    int64_t uptime_ns;                           /* since the daemon started */
    int64_t publish_ns;                          /* CLOCK_MONOTONIC of this status */
    uint64_t received[2];                        /* samples, rejected ones included */
    uint64_t rejected[2][VLSYNC_REJECT_REASONS]; /* by VLSYNC_REJECT_* */
    uint64_t lost[2];                            /* sequence gaps */
    uint64_t budget_overruns;                    /* samples over daemon.latency_budget_us */
    uint64_t estimates_published;
    uint64_t events_dropped;                     /* log events the real-time thread dropped */
    uint64_t processing_ns[3];                   /* sample's turn after receive to daemon done
                                                    (validated, estimated, estimate published) */
    uint64_t end_to_end_ns[3];                   /* driver publish to daemon done with the sample
                                                    (its estimate published if one was due) */
    uint64_t latency_count;
    uint8_t state;                               /* VLSYNC_STATE_* of the last estimate, or NONE */
    uint8_t degraded;                            /* 1 while over budget (narrower search) */
    uint8_t reserved[14];                        /* 0 */
} vlsync_daemon_status;

/* Layout checks, every size, alignment and offset (the Rust tests pin the same), where
 * the language has static assertions (C11, C++11); older C and C++ (C89/C99, C++98/03)
 * include the header without them. */
#if defined(__cplusplus) && __cplusplus >= 201103L
#define VLSYNC_CLIENT_STATIC_ASSERT(c, m) static_assert(c, m)
#define VLSYNC_CLIENT_ALIGNOF(t) alignof(t)
#elif !defined(__cplusplus) && defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L
#define VLSYNC_CLIENT_STATIC_ASSERT(c, m) _Static_assert(c, m)
#define VLSYNC_CLIENT_ALIGNOF(t) _Alignof(t)
#endif
#ifdef VLSYNC_CLIENT_STATIC_ASSERT
VLSYNC_CLIENT_STATIC_ASSERT(sizeof(vlsync_estimate) == 88, "vlsync_estimate size");
VLSYNC_CLIENT_STATIC_ASSERT(VLSYNC_CLIENT_ALIGNOF(vlsync_estimate) == 8, "vlsync_estimate alignment");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, seq) == 0, "vlsync_estimate.seq");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, t_ref_ns) == 8, "vlsync_estimate.t_ref_ns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, offset_s) == 16, "vlsync_estimate.offset_s");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, drift) == 24, "vlsync_estimate.drift");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, offset_std_s) == 32, "vlsync_estimate.offset_std_s");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, drift_std) == 40, "vlsync_estimate.drift_std");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, peak_score) == 48, "vlsync_estimate.peak_score");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, peak_ratio) == 56, "vlsync_estimate.peak_ratio");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, measured_offset_s) == 64, "vlsync_estimate.measured_offset_s");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, publish_ns) == 72, "vlsync_estimate.publish_ns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, state) == 80, "vlsync_estimate.state");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, polarity) == 81, "vlsync_estimate.polarity");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_estimate, reserved) == 82, "vlsync_estimate.reserved");
VLSYNC_CLIENT_STATIC_ASSERT(sizeof(vlsync_conversion) == 104, "vlsync_conversion size");
VLSYNC_CLIENT_STATIC_ASSERT(VLSYNC_CLIENT_ALIGNOF(vlsync_conversion) == 8, "vlsync_conversion alignment");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_conversion, t_lidar_ns) == 0, "vlsync_conversion.t_lidar_ns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_conversion, std_s) == 8, "vlsync_conversion.std_s");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_conversion, estimate) == 16, "vlsync_conversion.estimate");
VLSYNC_CLIENT_STATIC_ASSERT(sizeof(vlsync_daemon_status) == 224, "vlsync_daemon_status size");
VLSYNC_CLIENT_STATIC_ASSERT(VLSYNC_CLIENT_ALIGNOF(vlsync_daemon_status) == 8, "vlsync_daemon_status alignment");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, uptime_ns) == 0, "vlsync_daemon_status.uptime_ns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, publish_ns) == 8, "vlsync_daemon_status.publish_ns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, received) == 16, "vlsync_daemon_status.received");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, rejected) == 32, "vlsync_daemon_status.rejected");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, lost) == 112, "vlsync_daemon_status.lost");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, budget_overruns) == 128, "vlsync_daemon_status.budget_overruns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, estimates_published) == 136, "vlsync_daemon_status.estimates_published");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, events_dropped) == 144, "vlsync_daemon_status.events_dropped");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, processing_ns) == 152, "vlsync_daemon_status.processing_ns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, end_to_end_ns) == 176, "vlsync_daemon_status.end_to_end_ns");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, latency_count) == 200, "vlsync_daemon_status.latency_count");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, state) == 208, "vlsync_daemon_status.state");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, degraded) == 209, "vlsync_daemon_status.degraded");
VLSYNC_CLIENT_STATIC_ASSERT(offsetof(vlsync_daemon_status, reserved) == 210, "vlsync_daemon_status.reserved");
#undef VLSYNC_CLIENT_STATIC_ASSERT
#undef VLSYNC_CLIENT_ALIGNOF
#endif

/* The ABI version the library was built with. */
uint32_t vlsync_client_abi_version(void);

/* The ABI minor version the library was built with (see VLSYNC_CLIENT_ABI_MINOR). Minor 1. */
uint32_t vlsync_client_abi_minor(void);

/* Opens the offset service of robot `prefix` (e.g. "vlsync/robot"). The daemon need not
 * run yet. Returns NULL with the reason in err on failure (an invalid prefix, no shared
 * memory, ...). Each handle takes one of the service's 16 subscriber slots, shared by
 * every client of the prefix on the machine (vlsync-echo, vlsyncd record, the Python
 * subscriber included): a 17th open fails with ExceedsMaxSupportedSubscribers. Right
 * after the open, vlsync_client_latest() may still say "none yet" for up to about 0.1 s
 * while the daemon's newest estimate reaches the new subscriber (the daemon connects new
 * subscribers every 0.1 s): wait for one
 * (vlsync_client_wait_next) before relying on latest() or camera_to_lidar(). That wait
 * may take up to about 0.35 s for this first estimate even from a daemon that publishes
 * it at once: its delivery to a new subscriber raises no event, so the wait sees it at
 * its next check (every 250 ms). */
vlsync_client *vlsync_client_open(const char *prefix, char *err, size_t err_len);

/* Closes a handle (NULL: nothing). 0, or -1 from another thread (the handle stays open;
 * no message: there is no err buffer) or for a handle closed already. */
int vlsync_client_close(vlsync_client *c);

/* Waits up to timeout_ms (negative: no limit) for the next estimate: the newest when
 * several are pending (the older are passed over).
 * 1: written to *out; 0: timeout, or a signal handled on this thread interrupted the wait
 * (EINTR; a signal handled on another thread does not: see the top of this file, and
 * use a bounded timeout in a loop that checks a stop flag); -1: error (err). */
int vlsync_client_wait_next(vlsync_client *c, int64_t timeout_ms, vlsync_estimate *out,
                            char *err, size_t err_len);

/* Waits up to timeout_ms (negative: no limit) for an estimate and writes the oldest one
 * pending: every estimate, one per call, in the order they were published (the first
 * is the daemon's last one before vlsync_client_open, when it had one). The
 * subscriber buffers 16 (8 s at the default hop): a caller further behind loses the
 * oldest. 1: written to *out; 0: timeout, or a signal handled on this thread interrupted
 * the wait (EINTR; as for vlsync_client_wait_next); -1: error (err). */
int vlsync_client_wait_one(vlsync_client *c, int64_t timeout_ms, vlsync_estimate *out,
                           char *err, size_t err_len);

/* The most recent estimate (after taking what is pending). 1: written; 0: none yet;
 * -1: c or out NULL, a handle of another thread, or an internal error (a caught panic;
 * an estimate failing validation when handed out), with no message. A failed receive is
 * NOT reported here: the last estimate is written as if nothing happened. Check its state
 * and age (vlsync_estimate_age_ns; see "Staleness" at the top): after the daemon stops,
 * this keeps returning 1 with its last estimate, still "tracking". */
int vlsync_client_latest(vlsync_client *c, vlsync_estimate *out);

/* vlsync_client_latest with the reason for -1 in err, -1 also covering a failed receive
 * on the offset service (the client keeps its last estimate). ABI minor 1. */
int vlsync_client_latest_err(vlsync_client *c, vlsync_estimate *out, char *err,
                             size_t err_len);

/* Converts camera stamp t_cam_ns with the latest estimate, extrapolated with its drift;
 * std_s includes the offset's random walk since t_ref_ns. 1: written; 0: no estimate
 * yet; -1: as vlsync_client_latest (no message; a failed receive not reported). Trust
 * the result only when out->estimate is in a tracking or holding state AND recent
 * (vlsync_estimate_age_ns(&out->estimate) a few hops at most): after the daemon stops,
 * the last estimate keeps converting, still "tracking". */
int vlsync_client_camera_to_lidar(vlsync_client *c, int64_t t_cam_ns, vlsync_conversion *out);

/* vlsync_client_camera_to_lidar with the reason for -1 in err, -1 also covering a failed
 * receive on the offset service. ABI minor 1. */
int vlsync_client_camera_to_lidar_err(vlsync_client *c, int64_t t_cam_ns,
                                      vlsync_conversion *out, char *err, size_t err_len);

/* How old estimate e is, ns: CLOCK_MONOTONIC now - e->publish_ns (0 if that is up to
 * 1 s in the future; INT64_MAX if further, which this machine's daemon never gives, so
 * that every age check fails); -1 when e is NULL. e need not be aligned. ABI minor 1. */
int64_t vlsync_estimate_age_ns(const vlsync_estimate *e);

/* The offset's random walk (s/sqrt(s)) conversions assume while tracking and otherwise:
 * the daemon's estimator.offset_process_noise and estimator.hold_process_noise when it
 * does not run the shipped 2e-4 and 3e-3. 0, or -1 (err): NULL or foreign handle, or a
 * value that is NaN, infinite or negative (the setting then stays as it was). */
int vlsync_client_set_process_noise(vlsync_client *c, double tracking, double holding,
                                    char *err, size_t err_len);

/* Payloads refused by validation so far; 0 too for a NULL or another thread's handle. */
uint64_t vlsync_client_invalid_count(vlsync_client *c);

/* Opens the status service of robot `prefix` (the daemon need not run yet); NULL with
 * the reason in err on failure. Used on its opening thread, like a vlsync_client. */
vlsync_status_client *vlsync_status_open(const char *prefix, char *err, size_t err_len);

/* Closes a status handle (NULL: nothing). 0, or -1 from another thread (it stays open;
 * no message) or for a handle closed already. */
int vlsync_status_close(vlsync_status_client *c);

/* The newest valid status (invalid payloads are skipped). 1: written to *out; 0: none
 * yet; -1: error (err): NULL argument, wrong thread, transport failure, or only invalid
 * payloads so far. */
int vlsync_status_latest(vlsync_status_client *c, vlsync_daemon_status *out, char *err,
                         size_t err_len);

/* Status payloads refused by validation so far; 0 too for a NULL or another thread's
 * handle. A vlsync_status_latest that returned -1 while this count rose met only invalid
 * payloads: they are skipped, and the next call reads on. Minor 2. */
uint64_t vlsync_status_invalid_count(vlsync_status_client *c);

/* "acquiring", "tracking", "holding", "lost", or "unknown": a static string. */
const char *vlsync_state_name(uint8_t state);

#ifdef __cplusplus
}
#endif

#endif /* VLSYNC_CLIENT_H */
