// vlsync_client.hpp - C++17 wrapper of vlsync_client.h: one owning, movable handle;
// errors as exceptions, "nothing yet" as an empty std::optional.
//
//   vlsync::Client c("vlsync/robot");          // throws vlsync::Error
//   if (auto e = c.wait_next(std::chrono::seconds(1)))
//       std::cout << vlsync::state_name(*e) << " " << e->offset_s << "\n";
//   if (auto v = c.camera_to_lidar(t_cam_ns);
//       v && vlsync::is_locked(v->estimate) && vlsync::age(v->estimate) < std::chrono::seconds(3))
//       use(v->t_lidar_ns);
//   vlsync::StatusClient s("vlsync/robot");    // the daemon's counters, for diagnostics
//   if (auto st = s.latest()) report(st->lost[0] + st->lost[1], st->budget_overruns);
//
// Staleness: an estimate's state alone does not say the daemon is alive. After it stops,
// latest() and camera_to_lidar() keep handing out its last estimate, still "tracking",
// its std_s growing only by the random walk. Check the age as well (vlsync::age: now on
// CLOCK_MONOTONIC minus publish_ns); the daemon publishes one per hop (0.5 s by default),
// so an estimate several hops old (over 2-3 s, say) is stale.
//
// Errors: every failure throws vlsync::Error with the library's message, which names the
// C function and the cause (a handle used on another thread, a failed receive on the
// offset service, an internal error). latest() and camera_to_lidar() call the _err
// variants of ABI minor 1 and StatusClient the invalid count of minor 2, so each
// constructor requires a library of this header's minor (VLSYNC_CLIENT_ABI_MINOR).
// invalid_count() does not throw: 0 on a moved-from object or another thread.
//
// Like the handle it wraps, a Client (and a StatusClient) is used, and destroyed, on the
// thread that constructed it: close() throws when called from another thread (the
// handle stays open); a destructor there cannot throw, so it says on stderr that the
// handle leaks. A move assignment closes the handle the target held first, the same way
// (on another thread: a message on stderr that the target's old handle leaks).
//
// Signals: a wait returns empty early only when a signal is delivered to the waiting
// thread and interrupts its system call (EINTR); a process-directed signal (Ctrl-C's
// SIGINT, SIGTERM) delivered to another thread leaves the wait running to its timeout.
// In a multi-threaded program, wait with a bounded timeout in a loop that checks your
// own stop flag (a std::atomic<bool> your handler or another thread sets):
//
//   while (!stop.load()) if (auto e = c.wait_next(std::chrono::milliseconds(250))) use(*e);
#ifndef VLSYNC_CLIENT_HPP
#define VLSYNC_CLIENT_HPP

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

#include "vlsync_client.h"

namespace vlsync {

/// A failed call; what() is the library's message.
class Error : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

inline const char *state_name(const vlsync_estimate &e) { return vlsync_state_name(e.state); }

/// Tracking or holding: the estimator had a lock when it published `e` (check its age,
/// too: see the top of this file).
inline bool is_locked(const vlsync_estimate &e) {
    return e.state == VLSYNC_STATE_TRACKING || e.state == VLSYNC_STATE_HOLDING;
}

/// How old `e` is: CLOCK_MONOTONIC now minus its publish_ns (the clock the daemon stamps
/// with, whatever std::chrono::steady_clock is).
inline std::chrono::nanoseconds age(const vlsync_estimate &e) {
    return std::chrono::nanoseconds(vlsync_estimate_age_ns(&e));
}

namespace detail {
/// Throws unless the loaded library has this header's ABI version and at least its minor.
inline void check_abi() {
    if (vlsync_client_abi_version() != VLSYNC_CLIENT_ABI_VERSION)
        throw Error("libvlsync_client has ABI version " +
                    std::to_string(vlsync_client_abi_version()) + ", this header " +
                    std::to_string(VLSYNC_CLIENT_ABI_VERSION));
    if (vlsync_client_abi_minor() < VLSYNC_CLIENT_ABI_MINOR)
        throw Error("libvlsync_client has ABI minor " +
                    std::to_string(vlsync_client_abi_minor()) + ", this header needs " +
                    std::to_string(VLSYNC_CLIENT_ABI_MINOR));
}

/// `prefix` as a C string for `what`; throws when it holds a NUL byte, which would cut
/// it short (a "vlsync/robot\0x" would open vlsync/robot).
inline const char *c_prefix(const std::string &prefix, const char *what) {
    auto nul = prefix.find('\0');
    if (nul != std::string::npos)
        throw Error(std::string(what) + ": the prefix holds a NUL byte at position " +
                    std::to_string(nul));
    return prefix.c_str();
}
}  // namespace detail

class Client {
  public:
    /// Opens the handle; throws Error on a library of another ABI, a prefix with a NUL
    /// byte, or what vlsync_client_open refuses.
    explicit Client(const std::string &prefix) {
        detail::check_abi();
        const char *p = detail::c_prefix(prefix, "vlsync::Client");
        char err[512] = {0};
        c_ = vlsync_client_open(p, err, sizeof err);
        if (!c_) throw Error(err);
    }
    ~Client() { close_or_report("destroyed"); }
    Client(const Client &) = delete;
    Client &operator=(const Client &) = delete;
    Client(Client &&o) noexcept : c_(std::exchange(o.c_, nullptr)) {}
    Client &operator=(Client &&o) noexcept {
        if (this != &o) {
            close_or_report("move-assigned");
            c_ = std::exchange(o.c_, nullptr);
        }
        return *this;
    }

    /// Closes the handle now (a moved-from or closed Client: nothing to do); throws,
    /// leaving it open, when called on another thread than the one that opened it.
    void close() {
        if (vlsync_client_close(c_) != 0)
            throw Error("vlsync_client_close: the client was opened on another thread");
        c_ = nullptr;
    }

    /// The next estimate within `timeout` (negative: no limit), the newest when several
    /// are pending; empty on timeout or when a signal delivered to this thread
    /// interrupted the wait (EINTR; one delivered to another thread does not: use a
    /// bounded timeout, e.g. 250 ms, in a loop that checks your stop flag).
    std::optional<vlsync_estimate> wait_next(std::chrono::milliseconds timeout) {
        vlsync_estimate e;
        char err[512] = {0};
        switch (vlsync_client_wait_next(c_, timeout.count(), &e, err, sizeof err)) {
        case 1: return e;
        case 0: return std::nullopt;
        default: throw Error(err);
        }
    }

    /// The oldest estimate pending within `timeout` (negative: no limit): every
    /// estimate, one per call, in order; empty on timeout or when a signal delivered to
    /// this thread interrupted the wait (EINTR; as for wait_next). wait_next, latest and
    /// camera_to_lidar take what is pending.
    std::optional<vlsync_estimate> wait_one(std::chrono::milliseconds timeout) {
        vlsync_estimate e;
        char err[512] = {0};
        switch (vlsync_client_wait_one(c_, timeout.count(), &e, err, sizeof err)) {
        case 1: return e;
        case 0: return std::nullopt;
        default: throw Error(err);
        }
    }

    /// The most recent estimate; empty before the first. Throws on a closed or
    /// moved-from Client, on another thread, on a failed receive (the client keeps its
    /// last estimate) or an internal error. The estimate stays after the daemon stops,
    /// state and all: check vlsync::age.
    std::optional<vlsync_estimate> latest() {
        vlsync_estimate e;
        char err[512] = {0};
        switch (vlsync_client_latest_err(c_, &e, err, sizeof err)) {
        case 1: return e;
        case 0: return std::nullopt;
        default: throw Error(err);
        }
    }

    /// A camera stamp on the LiDAR clock; empty before the first estimate. Throws as
    /// latest() does. Trust it when vlsync::is_locked(v->estimate) and
    /// vlsync::age(v->estimate) is a few hops at most.
    std::optional<vlsync_conversion> camera_to_lidar(int64_t t_cam_ns) {
        vlsync_conversion v;
        char err[512] = {0};
        switch (vlsync_client_camera_to_lidar_err(c_, t_cam_ns, &v, err, sizeof err)) {
        case 1: return v;
        case 0: return std::nullopt;
        default: throw Error(err);
        }
    }

    void set_process_noise(double tracking, double holding) {
        char err[512] = {0};
        if (vlsync_client_set_process_noise(c_, tracking, holding, err, sizeof err) != 0)
            throw Error(err);
    }

    /// Payloads refused by validation so far (0 too on another thread: no error here).
    uint64_t invalid_count() { return vlsync_client_invalid_count(c_); }

  private:
    /// Closes the handle for the destructor or a move assignment (`how`, "destroyed"
    /// or "move-assigned"), which cannot throw: on another thread, a message on stderr.
    void close_or_report(const char *how) noexcept {
        if (vlsync_client_close(c_) != 0)
            std::fprintf(stderr,
                         "vlsync::Client %s on another thread than the one that opened its "
                         "handle: the handle is left open (leaked)\n",
                         how);
        c_ = nullptr;
    }

    vlsync_client *c_ = nullptr;
};

/// The daemon's counters (`<prefix>/status`): one owning, movable handle, used on the
/// thread that constructed it, like a Client.
class StatusClient {
  public:
    /// Opens the handle; throws Error on a library of another ABI, a prefix with a NUL
    /// byte, or what vlsync_status_open refuses.
    explicit StatusClient(const std::string &prefix) {
        detail::check_abi();
        const char *p = detail::c_prefix(prefix, "vlsync::StatusClient");
        char err[512] = {0};
        c_ = vlsync_status_open(p, err, sizeof err);
        if (!c_) throw Error(err);
    }
    ~StatusClient() { close_or_report("destroyed"); }
    StatusClient(const StatusClient &) = delete;
    StatusClient &operator=(const StatusClient &) = delete;
    StatusClient(StatusClient &&o) noexcept : c_(std::exchange(o.c_, nullptr)) {}
    StatusClient &operator=(StatusClient &&o) noexcept {
        if (this != &o) {
            close_or_report("move-assigned");
            c_ = std::exchange(o.c_, nullptr);
        }
        return *this;
    }

    /// Closes the handle now (a moved-from or closed StatusClient: nothing to do);
    /// throws, leaving it open, when called on another thread than the one that opened it.
    void close() {
        if (vlsync_status_close(c_) != 0)
            throw Error("vlsync_status_close: the status client was opened on another thread");
        c_ = nullptr;
    }

    /// The newest valid status; empty before the first (invalid payloads are skipped
    /// and counted: invalid_count()).
    std::optional<vlsync_daemon_status> latest() {
        vlsync_daemon_status s;
        char err[512] = {0};
        const uint64_t invalid = invalid_count();
        switch (vlsync_status_latest(c_, &s, err, sizeof err)) {
        case 1: return s;
        case 0: return std::nullopt;
        default:
            // only invalid payloads so far: skipped, no error of this reader (the
            // library reports a failed receive after them as the next call's -1, with
            // the count unchanged, so a real error still throws)
            if (invalid_count() > invalid) return std::nullopt;
            throw Error(err);
        }
    }

    /// Status payloads refused by validation so far (ABI minor 2).
    uint64_t invalid_count() { return vlsync_status_invalid_count(c_); }

  private:
    /// As Client's.
    void close_or_report(const char *how) noexcept {
        if (vlsync_status_close(c_) != 0)
            std::fprintf(stderr,
                         "vlsync::StatusClient %s on another thread than the one that "
                         "opened its handle: the handle is left open (leaked)\n",
                         how);
        c_ = nullptr;
    }

    vlsync_status_client *c_ = nullptr;
};

} // namespace vlsync

#endif // VLSYNC_CLIENT_HPP
