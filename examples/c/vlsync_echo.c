/*
 * vlsync_echo.c - print the vlsync daemon's estimates from C, through libvlsync_client.
 *
 *   cargo build --release -p vlsync-capi
 *   cc -std=c11 -Wall -I capi/include examples/c/vlsync_echo.c \
 *      -L target/release -lvlsync_client -Wl,-rpath,"$PWD/target/release" -o vlsync_echo_c
 *   ./vlsync_echo_c --prefix vlsync/robot [--count N] [--timeout S] [--status]
 *
 * One line per estimate, every one in order (vlsync_client_wait_one): sequence number,
 * state, reference time on the LiDAR clock, offset +- one standard deviation, drift. It
 * converts nothing, and each estimate is printed as it arrives (the first may be the
 * daemon's last before the open: its publish time is not checked here; a program that
 * uses an estimate later checks its age, vlsync_estimate_age_ns). With --status, the
 * daemon's newest counters instead (state, samples received, rejected and lost per
 * stream, estimates, budget overruns, end-to-end p99), polled every 250 ms and printed
 * when they changed: one line per status only while daemon.status_period_s is longer
 * than that (the default 1 s); with a shorter period the statuses between two polls are
 * skipped, and --count counts printed lines. Exit status: 0 after --count lines, on
 * Ctrl-C / SIGTERM or when the reader of its output goes away; 1 when --timeout seconds
 * (at most 1e9) pass without an estimate (a status); 2 on a bad argument, a library error
 * or a failed write to stdout (the message on stderr). Payloads that fail validation (a
 * NaN offset, an unknown state) are skipped by the library and counted: each batch is
 * said on stderr ("skipped N invalid estimate payload(s)"), and the echo reads on. With
 * nothing received for 5 s it says so once on stderr (a wrong --prefix, or no daemon)
 * and keeps waiting.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "vlsync_client.h"

static volatile sig_atomic_t stop = 0;
static void on_signal(int sig) { (void)sig; stop = 1; }

#define USAGE "usage: vlsync_echo_c [--prefix P] [--count N] [--timeout S] [--status]\n"

/* the message `why arg after`, then the usage; exit status 2 */
static int usage3(const char *why, const char *arg, const char *after) {
    fprintf(stderr, "vlsync_echo_c: %s%s%s\n" USAGE, why, arg, after);
    return 2;
}

static int usage(const char *why, const char *arg) { return usage3(why, arg, ""); }

/* the number >= 0 (at most 1e9) in text s, or -1 */
static double number(const char *s) {
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    return (errno || end == s || *end || !(v >= 0.0) || v > 1e9) ? -1.0 : v;
}

static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Flushes stdout: 1, or 0 to stop, with *status 2 and a message on a write error. A
 * signal can interrupt a blocked write: that is a stop, not an error; and so is a
 * reader that went away (EPIPE: `| head -1`; SIGPIPE is ignored, so the client is
 * closed and its iceoryx2 resources released instead of the process being killed). */
static int flushed(int *status) {
    if (fflush(stdout) == 0) return 1;
    if (!stop && errno != EPIPE) {
        fprintf(stderr, "vlsync_echo_c: writing to stdout: %s\n", strerror(errno));
        *status = 2;
    }
    return 0;
}

/* Once, after 5 s with nothing received: what to check (a wrong prefix or no daemon
 * looks the same from here: the client waits for the service either way). */
static void quiet_notice(int *heard, int *told, double start, const char *prefix,
                         const char *service) {
    if (*heard || *told || now_s() - start < 5.0) return;
    *told = 1;
    fprintf(stderr,
            "vlsync_echo_c: nothing on %s/%s for 5 s; waiting (is vlsyncd running with this "
            "prefix?)\n",
            prefix, service);
}

/* rejected samples of stream s, every reason */
static unsigned long long rejected(const vlsync_daemon_status *st, int s) {
    unsigned long long n = 0;
    for (int r = 0; r < VLSYNC_REJECT_REASONS; r++) n += st->rejected[s][r];
    return n;
}

/* --status: the newest status, polled every 250 ms, printed when it is new (statuses
 * published between two polls are not seen) */
static int echo_status(const char *prefix, long count, double timeout) {
    char err[512];
    vlsync_status_client *c = vlsync_status_open(prefix, err, sizeof err);
    if (!c) {
        fprintf(stderr, "vlsync_echo_c: %s\n", err);
        return 2;
    }
    long got = 0;
    int status = 0;
    int64_t last_publish = INT64_MIN;
    double last = now_s(), start = last;
    int heard = 0, told = 0;
    uint64_t invalid = 0;
    struct timespec tick = {0, 250 * 1000 * 1000};
    while (!stop && (count == 0 || got < count)) {
        vlsync_daemon_status st;
        int r = vlsync_status_latest(c, &st, err, sizeof err);
        uint64_t now_invalid = vlsync_status_invalid_count(c);
        if (now_invalid > invalid) {
            /* skipped; -1 with only invalid payloads so far is no error of the reader (a
             * failed receive after them is the next call's -1, the count unchanged) */
            fprintf(stderr, "vlsync_echo_c: skipped %llu invalid status payload(s) on %s/status\n",
                    (unsigned long long)(now_invalid - invalid), prefix);
            invalid = now_invalid;
            heard = 1;
            if (r < 0) r = 0;
        }
        if (r < 0) {
            fprintf(stderr, "vlsync_echo_c: %s\n", err);
            status = 2;
            break;
        }
        if (r == 0 || st.publish_ns == last_publish) {
            quiet_notice(&heard, &told, start, prefix, "status");
            if (timeout > 0 && now_s() - last > timeout) {
                fprintf(stderr, "vlsync_echo_c: no status on %s/status for %.1f s\n", prefix, timeout);
                status = 1;
                break;
            }
            nanosleep(&tick, NULL); /* a signal ends it early */
            continue;
        }
        last_publish = st.publish_ns;
        last = now_s();
        heard = 1;
        got++;
        printf("status %-9s received %llu %llu rejected %llu %llu lost %llu %llu estimates %llu "
               "overruns %llu degraded %u p99 %.1f us\n",
               st.state == VLSYNC_STATE_NONE ? "none" : vlsync_state_name(st.state),
               (unsigned long long)st.received[0], (unsigned long long)st.received[1],
               rejected(&st, 0), rejected(&st, 1), (unsigned long long)st.lost[0],
               (unsigned long long)st.lost[1], (unsigned long long)st.estimates_published,
               (unsigned long long)st.budget_overruns, (unsigned)st.degraded,
               st.end_to_end_ns[1] * 1e-3);
        if (!flushed(&status)) break;
    }
    vlsync_status_close(c);
    return status;
}

int main(int argc, char **argv) {
    const char *prefix = "vlsync/robot";
    double count = 0.0, timeout = 0.0;
    int want_status = 0;
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i];
        if (!strcmp(opt, "--help") || !strcmp(opt, "-h")) {
            printf(USAGE
                   "Prints the vlsync daemon's estimates on prefix P (default vlsync/robot), one line\n"
                   "each in order, or with --status its newest counters (polled every 250 ms, printed\n"
                   "when new); stops after N lines (0: no limit)\n"
                   "or when S seconds pass without one (exit 1; 0: no limit).\n");
            return 0;
        }
        if (!strcmp(opt, "--status")) {
            want_status = 1;
            continue;
        }
        if (strcmp(opt, "--prefix") && strcmp(opt, "--count") && strcmp(opt, "--timeout"))
            return usage("unknown option ", opt);
        if (i + 1 >= argc) return usage("a value is missing after ", opt);
        const char *val = argv[++i];
        if (!strcmp(opt, "--prefix")) prefix = val;
        else if (!strcmp(opt, "--count")) {
            if ((count = number(val)) < 0 || count != (long)count)
                return usage3("--count takes a whole number >= 0, not ", val, " (at most 1e9)");
        } else if ((timeout = number(val)) < 0)
            return usage3("--timeout takes seconds >= 0, not ", val, " (at most 1e9)");
    }
    if (vlsync_client_abi_version() != VLSYNC_CLIENT_ABI_VERSION) {
        fprintf(stderr, "vlsync_echo_c: libvlsync_client has ABI %u, this program %u\n",
                vlsync_client_abi_version(), VLSYNC_CLIENT_ABI_VERSION);
        return 2;
    }
    /* it calls vlsync_status_invalid_count, of minor 2 */
    if (vlsync_client_abi_minor() < VLSYNC_CLIENT_ABI_MINOR) {
        fprintf(stderr, "vlsync_echo_c: libvlsync_client has ABI minor %u, this program needs %u\n",
                vlsync_client_abi_minor(), VLSYNC_CLIENT_ABI_MINOR);
        return 2;
    }
    /* no SA_RESTART: a signal ends the library's wait, which then returns 0 */
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN); /* a closed pipe is EPIPE from the write: see flushed() */

    if (want_status) return echo_status(prefix, (long)count, timeout);

    char err[512];
    vlsync_client *c = vlsync_client_open(prefix, err, sizeof err);
    if (!c) {
        fprintf(stderr, "vlsync_echo_c: %s\n", err);
        return 2;
    }
    long got = 0;
    int status = 0;
    double last = now_s(), start = last;
    int heard = 0, told = 0;
    uint64_t invalid = 0;
    while (!stop && (count == 0 || got < (long)count)) {
        vlsync_estimate e;
        int r = vlsync_client_wait_one(c, 250, &e, err, sizeof err);
        uint64_t now_invalid = vlsync_client_invalid_count(c);
        if (now_invalid > invalid) {
            /* the library skips what fails validation (NaN, an unknown state, ...) */
            fprintf(stderr,
                    "vlsync_echo_c: skipped %llu invalid estimate payload(s) on %s/offset\n",
                    (unsigned long long)(now_invalid - invalid), prefix);
            invalid = now_invalid;
            heard = 1;
        }
        if (r < 0) {
            fprintf(stderr, "vlsync_echo_c: %s\n", err);
            status = 2;
            break;
        }
        if (r == 0) {
            quiet_notice(&heard, &told, start, prefix, "offset");
            if (timeout > 0 && now_s() - last > timeout) {
                fprintf(stderr, "vlsync_echo_c: no estimate on %s/offset for %.1f s\n", prefix, timeout);
                status = 1;
                break;
            }
            continue;
        }
        last = now_s();
        heard = 1;
        got++;
        printf("seq %llu %-9s t_ref %.3f s offset %+.3f ms +- %.3f ms drift %+.2f ppm\n",
               (unsigned long long)e.seq, vlsync_state_name(e.state), e.t_ref_ns * 1e-9,
               e.offset_s * 1e3, e.offset_std_s * 1e3, e.drift * 1e6);
        if (!flushed(&status)) break;
    }
    vlsync_client_close(c);
    return status;
}
