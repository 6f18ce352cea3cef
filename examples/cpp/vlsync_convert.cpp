// vlsync_convert.cpp - put camera stamps on the LiDAR clock from C++, through
// libvlsync_client and its C++ wrapper (capi/include/vlsync_client.hpp).
//
//   cargo build --release -p vlsync-capi
//   c++ -std=c++17 -Wall -I capi/include examples/cpp/vlsync_convert.cpp -L target/release
//       -lvlsync_client -Wl,-rpath,"$PWD/target/release" -o vlsync_convert   (one line: a
//       backslash would continue this comment)
//   ./vlsync_convert --prefix vlsync/robot [--timeout S] [--max-age A] < camera_stamps_ns.txt
//
// Waits (up to --timeout seconds, default 30, at most 1e6; 0: no limit) for the
// estimator's lock in an estimate at most --max-age seconds old (default 3: six hops at
// the default 0.5 s), then reads one camera stamp per line (integer ns on the camera's
// clock) and prints `t_cam_ns t_lidar_ns std_us state` for each, with the newest estimate
// at that moment. The state is the estimate's, or `stale` when that estimate is older
// than --max-age: the daemon stopped publishing (its last estimate stays "tracking"
// forever in the client), so the stamp is not to be trusted; stderr says when that
// starts (with the age) and when fresh estimates come back.
// Exit status: 0 at the end of the input, on Ctrl-C / SIGTERM, or when the reader of its
// output goes away; 1 when no lock came within the timeout (the message counts the invalid
// payloads the library skipped meanwhile, if any); 2 on a bad argument, a line
// that is not a 64-bit integer (named by its number), an output that cannot be written,
// or a library error. Each path out closes the client (its iceoryx2 resources released).
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <iomanip>
#include <iostream>
#include <string>

#include <signal.h>

#include "vlsync_client.hpp"

namespace {
const char *const kUsage =
    "usage: vlsync_convert [--prefix P] [--timeout S] [--max-age A] < camera_stamps_ns.txt\n";
constexpr double kMaxTimeout = 1e6;  // seconds, for --timeout and --max-age
volatile std::sig_atomic_t stop = 0;
extern "C" void on_signal(int) { stop = 1; }

// After a line: -1 to go on; else the exit status (a reader that went away, EPIPE, is a
// normal end, 0; any other write error is 2, with its reason).
int written() {
    if (std::cout.flush()) return -1;
    if (errno == EPIPE || stop) return 0;
    std::cerr << "vlsync_convert: writing to stdout: " << std::strerror(errno) << "\n";
    return 2;
}
// The seconds >= 0 (at most kMaxTimeout) in text v, or -1.
double seconds(const char *v) {
    char *end = nullptr;
    errno = 0;
    double s = std::strtod(v, &end);
    return (errno || end == v || *end || !(s >= 0.0) || s > kMaxTimeout) ? -1.0 : s;
}
}  // namespace

int main(int argc, char **argv) {
    std::string prefix = "vlsync/robot";
    double timeout_s = 30.0;
    double max_age_s = 3.0;
    for (int i = 1; i < argc; i++) {
        std::string a = argv[i];
        if (a == "--help" || a == "-h") {
            std::cout << kUsage
                      << "Reads camera stamps (integer ns, one per line) on stdin and prints each on the\n"
                         "LiDAR clock: t_cam_ns t_lidar_ns std_us state, once the daemon on prefix P\n"
                         "(default vlsync/robot) has locked; waits up to S seconds for that (default 30;\n"
                         "0: no limit). The state is `stale` for an estimate older than A seconds\n"
                         "(default 3): the daemon stopped publishing.\n";
            return 0;
        }
        if (a != "--prefix" && a != "--timeout" && a != "--max-age") {
            std::cerr << "vlsync_convert: unknown option " << a << "\n" << kUsage;
            return 2;
        }
        if (i + 1 >= argc) {
            std::cerr << "vlsync_convert: a value is missing after " << a << "\n" << kUsage;
            return 2;
        }
        const char *v = argv[++i];
        if (a == "--prefix") {
            prefix = v;
        } else if (a == "--timeout") {
            if ((timeout_s = seconds(v)) < 0) {
                std::cerr << "vlsync_convert: --timeout takes seconds >= 0, not " << v
                          << " (at most " << static_cast<long>(kMaxTimeout) << ")\n";
                return 2;
            }
        } else if (!((max_age_s = seconds(v)) > 0)) {
            std::cerr << "vlsync_convert: --max-age takes seconds > 0, not " << v << " (at most "
                      << static_cast<long>(kMaxTimeout) << ")\n";
            return 2;
        }
    }
    // no SA_RESTART: a signal ends the library's wait and the read of stdin
    struct sigaction sa;
    std::memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, nullptr);
    sigaction(SIGTERM, &sa, nullptr);
    std::signal(SIGPIPE, SIG_IGN);  // a closed pipe is EPIPE from the write: see written()
    try {
        vlsync::Client c(prefix);
        using clock = std::chrono::steady_clock;
        auto deadline = clock::now() + std::chrono::duration<double>(timeout_s);
        const auto max_age = std::chrono::duration<double>(max_age_s);
        // the age check: the client keeps the daemon's last estimate, "tracking" and all,
        // after the daemon stops
        auto fresh = [&](const vlsync_estimate &e) { return vlsync::age(e) <= max_age; };
        for (;;) {
            if (stop) return 0;
            auto e = c.latest();
            if (e && vlsync::is_locked(*e) && fresh(*e)) break;
            if (timeout_s > 0 && clock::now() >= deadline) {
                std::cerr << "vlsync_convert: no lock on " << prefix << "/offset within "
                          << timeout_s << " s";
                if (e && vlsync::is_locked(*e))
                    std::cerr << " (only a stale one, "
                              << std::chrono::duration<double>(vlsync::age(*e)).count()
                              << " s old)";
                // what the library skipped: a publisher of broken payloads, not no lock
                if (auto bad = c.invalid_count())
                    std::cerr << "; " << bad
                              << " invalid estimate payload(s) skipped (NaN, unknown state, ...)";
                std::cerr << "\n";
                return 1;
            }
            c.wait_next(std::chrono::milliseconds(250));
        }
        bool stale = false;
        std::string line;
        for (long n = 1; !stop && std::getline(std::cin, line); n++) {
            char *end = nullptr;
            errno = 0;
            long long t_cam = std::strtoll(line.c_str(), &end, 10);
            if (line.empty() || *end || errno == ERANGE) {
                std::cerr << "vlsync_convert: line " << n
                          << " is not an integer stamp (64-bit ns): " << line << "\n";
                return 2;
            }
            auto v = c.camera_to_lidar(t_cam);  // a lock was seen, so never empty
            if (fresh(v->estimate) == stale) {
                stale = !stale;
                if (stale)
                    std::cerr << "vlsync_convert: the newest estimate on " << prefix << "/offset is "
                              << std::fixed << std::setprecision(1)
                              << std::chrono::duration<double>(vlsync::age(v->estimate)).count()
                              << std::defaultfloat << std::setprecision(6) << " s old ("
                              << vlsync::state_name(v->estimate)
                              << " when published): the daemon is not publishing; stamps are "
                                 "marked stale\n";
                else
                    // fresh is not locked: a restarted daemon acquires first
                    std::cerr << "vlsync_convert: fresh estimates again on " << prefix
                              << "/offset (" << vlsync::state_name(v->estimate)
                              << (vlsync::is_locked(v->estimate) ? ")\n"
                                                                 : ", no lock yet)\n");
            }
            std::cout << t_cam << " " << v->t_lidar_ns << " " << v->std_s * 1e6 << " "
                      << (stale ? "stale" : vlsync::state_name(v->estimate)) << "\n";
            if (int status = written(); status >= 0) return status;
        }
    } catch (const vlsync::Error &e) {
        std::cerr << "vlsync_convert: " << e.what() << "\n";
        return 2;
    }
    return 0;
}
