/*
 * vlsync_echo.c - print the vlsync daemon's estimates from C, through libvlsync_client.
 *
 *   cargo build --release -p vlsync-capi
 *   cc -std=c11 -Wall -I capi/include examples/c/vlsync_echo.c \
 *      -L target/release -lvlsync_client -Wl,-rpath,"$PWD/target/release" -o vlsync_echo_c
 *   ./vlsync_echo_c --prefix vlsync/robot [--count N] [--timeout S]
 *
 * One line per estimate, every one in order (vlsync_client_wait_one): sequence number, state, reference time on the LiDAR clock,
 * offset +- one standard deviation, drift. Exit status: 0 after --count estimates or on
 * Ctrl-C / SIGTERM; 1 when --timeout seconds pass without an estimate; 2 on a bad
 * argument or a library error (its message on stderr).
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

static int usage(const char *why, const char *arg) {
    fprintf(stderr, "vlsync_echo: %s%s\nusage: vlsync_echo [--prefix P] [--count N] [--timeout S]\n",
            why, arg);
    return 2;
}

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

int main(int argc, char **argv) {
    const char *prefix = "vlsync/robot";
    double count = 0.0, timeout = 0.0;
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i];
        if (strcmp(opt, "--prefix") && strcmp(opt, "--count") && strcmp(opt, "--timeout"))
            return usage("unknown option ", opt);
        if (i + 1 >= argc) return usage("a value is missing after ", opt);
        const char *val = argv[++i];
        if (!strcmp(opt, "--prefix")) prefix = val;
        else if (!strcmp(opt, "--count")) {
            if ((count = number(val)) < 0 || count != (long)count)
                return usage("--count takes a whole number >= 0, not ", val);
        } else if ((timeout = number(val)) < 0)
            return usage("--timeout takes seconds >= 0, not ", val);
    }
    if (vlsync_client_abi_version() != VLSYNC_CLIENT_ABI_VERSION) {
        fprintf(stderr, "vlsync_echo: libvlsync_client has ABI %u, this program %u\n",
                vlsync_client_abi_version(), VLSYNC_CLIENT_ABI_VERSION);
        return 2;
    }
    /* no SA_RESTART: a signal ends the library's wait, which then returns 0 */
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    char err[512];
    vlsync_client *c = vlsync_client_open(prefix, err, sizeof err);
    if (!c) {
        fprintf(stderr, "vlsync_echo: %s\n", err);
        return 2;
    }
    long got = 0;
    int status = 0;
    double last = now_s();
    while (!stop && (count == 0 || got < (long)count)) {
        vlsync_estimate e;
        int r = vlsync_client_wait_one(c, 250, &e, err, sizeof err);
        if (r < 0) {
            fprintf(stderr, "vlsync_echo: %s\n", err);
            status = 2;
            break;
        }
        if (r == 0) {
            if (timeout > 0 && now_s() - last > timeout) {
                fprintf(stderr, "vlsync_echo: no estimate on %s/offset for %.1f s\n", prefix, timeout);
                status = 1;
                break;
            }
            continue;
        }
        last = now_s();
        got++;
        printf("seq %llu %-9s t_ref %.3f s offset %+.3f ms +- %.3f ms drift %+.2f ppm\n",
               (unsigned long long)e.seq, vlsync_state_name(e.state), e.t_ref_ns * 1e-9,
               e.offset_s * 1e3, e.offset_std_s * 1e3, e.drift * 1e6);
        if (fflush(stdout) != 0) {
            /* a signal can interrupt a blocked write: that is a stop, not an error */
            if (!stop) {
                fprintf(stderr, "vlsync_echo: writing to stdout: %s\n", strerror(errno));
                status = 2;
            }
            break;
        }
    }
    vlsync_client_close(c);
    return status;
}
