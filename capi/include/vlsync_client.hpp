// vlsync_client.hpp - C++17 wrapper of vlsync_client.h: one owning, movable handle;
// errors as exceptions, "nothing yet" as an empty std::optional.
//
//   vlsync::Client c("vlsync/robot");          // throws vlsync::Error
//   if (auto e = c.wait_next(std::chrono::seconds(1)))
//       std::cout << vlsync::state_name(*e) << " " << e->offset_s << "\n";
//   if (auto v = c.camera_to_lidar(t_cam_ns); v && vlsync::is_locked(v->estimate))
//       use(v->t_lidar_ns);
//   vlsync::StatusClient s("vlsync/robot");    // the daemon's counters, for diagnostics
//   if (auto st = s.latest()) report(st->lost[0] + st->lost[1], st->budget_overruns);
//
// Like the handle it wraps, a Client (and a StatusClient) is used, and destroyed, on the
// thread that constructed it: close() throws when called from another thread (the
// handle stays open); a destructor there cannot throw, so it says on stderr that the
// handle leaks. A move assignment closes the handle the target held first, the same way.
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

/// Tracking or holding: the estimator has a lock.
inline bool is_locked(const vlsync_estimate &e) {
    return e.state == VLSYNC_STATE_TRACKING || e.state == VLSYNC_STATE_HOLDING;
}

class Client {
  public:
    explicit Client(const std::string &prefix) {
        if (vlsync_client_abi_version() != VLSYNC_CLIENT_ABI_VERSION)
            throw Error("libvlsync_client has ABI version " +
                        std::to_string(vlsync_client_abi_version()) + ", this header " +
                        std::to_string(VLSYNC_CLIENT_ABI_VERSION));
        char err[512] = {0};
        c_ = vlsync_client_open(prefix.c_str(), err, sizeof err);
        if (!c_) throw Error(err);
    }
    ~Client() { close_or_report(); }
    Client(const Client &) = delete;
    Client &operator=(const Client &) = delete;
    Client(Client &&o) noexcept : c_(std::exchange(o.c_, nullptr)) {}
    Client &operator=(Client &&o) noexcept {
        if (this != &o) {
            close_or_report();
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

    /// The most recent estimate; empty before the first.
    std::optional<vlsync_estimate> latest() {
        vlsync_estimate e;
        switch (vlsync_client_latest(c_, &e)) {
        case 1: return e;
        case 0: return std::nullopt;
        default: throw Error("vlsync_client_latest: invalid handle or wrong thread");
        }
    }

    /// A camera stamp on the LiDAR clock; empty before the first estimate.
    std::optional<vlsync_conversion> camera_to_lidar(int64_t t_cam_ns) {
        vlsync_conversion v;
        switch (vlsync_client_camera_to_lidar(c_, t_cam_ns, &v)) {
        case 1: return v;
        case 0: return std::nullopt;
        default: throw Error("vlsync_client_camera_to_lidar: invalid handle or wrong thread");
        }
    }

    void set_process_noise(double tracking, double holding) {
        char err[512] = {0};
        if (vlsync_client_set_process_noise(c_, tracking, holding, err, sizeof err) != 0)
            throw Error(err);
    }

    uint64_t invalid_count() { return vlsync_client_invalid_count(c_); }

  private:
    void close_or_report() noexcept {
        if (vlsync_client_close(c_) != 0)
            std::fputs("vlsync::Client destroyed on another thread than the one that opened "
                       "it: its handle is left open (leaked)\n",
                       stderr);
        c_ = nullptr;
    }

    vlsync_client *c_ = nullptr;
};

/// The daemon's counters (`<prefix>/status`): one owning, movable handle, used on the
/// thread that constructed it, like a Client.
class StatusClient {
  public:
    explicit StatusClient(const std::string &prefix) {
        if (vlsync_client_abi_version() != VLSYNC_CLIENT_ABI_VERSION)
            throw Error("libvlsync_client has ABI version " +
                        std::to_string(vlsync_client_abi_version()) + ", this header " +
                        std::to_string(VLSYNC_CLIENT_ABI_VERSION));
        char err[512] = {0};
        c_ = vlsync_status_open(prefix.c_str(), err, sizeof err);
        if (!c_) throw Error(err);
    }
    ~StatusClient() { close_or_report(); }
    StatusClient(const StatusClient &) = delete;
    StatusClient &operator=(const StatusClient &) = delete;
    StatusClient(StatusClient &&o) noexcept : c_(std::exchange(o.c_, nullptr)) {}
    StatusClient &operator=(StatusClient &&o) noexcept {
        if (this != &o) {
            close_or_report();
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

    /// The newest valid status; empty before the first.
    std::optional<vlsync_daemon_status> latest() {
        vlsync_daemon_status s;
        char err[512] = {0};
        switch (vlsync_status_latest(c_, &s, err, sizeof err)) {
        case 1: return s;
        case 0: return std::nullopt;
        default: throw Error(err);
        }
    }

  private:
    void close_or_report() noexcept {
        if (vlsync_status_close(c_) != 0)
            std::fputs("vlsync::StatusClient destroyed on another thread than the one that "
                       "opened it: its handle is left open (leaked)\n",
                       stderr);
        c_ = nullptr;
    }

    vlsync_status_client *c_ = nullptr;
};

} // namespace vlsync

#endif // VLSYNC_CLIENT_HPP
