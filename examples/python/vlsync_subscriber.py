#!/usr/bin/env python3
"""Subscribe to the vlsync daemon's offset estimates from Python.

Uses the official iceoryx2 Python package (see requirements.txt; the version
must equal the Rust side's). `OffsetEstimate` mirrors the `#[repr(C)]` Rust
type `vlsync_common::wire::OffsetEstimate` field by field and carries the same
iceoryx2 type name. iceoryx2 compares the type name, size and alignment, not the
fields: the `.v1` in the name is what guards the layout (a change of layout gets
a new name), and `layout_mismatches` pins every field's type and offset against
the Rust layout (a mismatch is exit status 3, each difference named on stderr).
Started before the daemon, it creates the services with the daemon's settings
(the last estimate kept for late subscribers, 16 buffered), as every vlsync
process does, so any start order works.

Run it as the same user as the daemon (`vlsync` in a deployment: `sudo -u vlsync
<venv>/bin/python3 vlsync_subscriber.py ...`). iceoryx2's files are owner-only
(0600): a subscriber of another user cannot open the daemon's services, and one
started before the daemon as another user creates them with files of its own,
which lock the daemon (and every `vlsync` client) out of them for as long as they
exist.

    python3 vlsync_subscriber.py --prefix vlsync/robot [--count N] [--timeout S]
        [--max-age A] [--json]

One line per estimate: `#seq t_ref offset ± σ drift state`, the offset and its σ
as published, at `t_ref` (the estimate's reference time on the LiDAR clock); with
--json one object with every field, `age_s` and `stale`. The service keeps the
daemon's last estimate for late subscribers, in the state it had: one started
after the daemon stopped gets that estimate, `tracking` or not, however old. So
each estimate's age is measured, `CLOCK_MONOTONIC` now minus its `publish_ns`
(the daemon's `CLOCK_MONOTONIC`, on the same machine; the Rust client's rule: a
publish time up to 1 s ahead is age 0, one further ahead counts as 2^63-1 ns),
and one older than --max-age seconds (default 3: six hops at the default 0.5 s,
as `vlsync_convert`'s) has `stale (N s old; STATE when published)` in place of
its state, and `"stale": true` in JSON (`state` stays the published one).

To put a camera stamp on the LiDAR clock, use `camera_to_lidar(estimate, t_cam_ns)`
below: `t_L = t_C + offset(t_L)` with the drift, and the σ of that stamp, which
grows from the printed σ with the drift's σ and the offset's random walk over
`|t_L - t_ref|` (the Rust client's `OffsetClient::camera_to_lidar`, bit for bit).

Every field read from shared memory is validated as the Rust client does
(state and polarity codes, finite offset/drift/deviations, a peak ratio that is
not NaN or negative, a measured offset that is not infinite, zero reserved
bytes); invalid samples are skipped: the first is said on stderr with its
reason, then at most one line per 10 s, with how many more were skipped since the
last such line, and how many were skipped in all is printed at exit. With nothing
received for 5 s it says once on stderr what it waits for (a daemon on another
prefix is the usual cause). Exit
status: 0 after --count valid estimates (stale ones count), on Ctrl-C (SIGINT) or
SIGTERM, or when the reader of its output goes away (`| head -1`); 1 on timeout; 2 on
error (a bad argument, such as a prefix the daemon would refuse or a negative count,
iceoryx2 refusing the node or the service or failing while waiting or receiving, or a
write error on stdout, with its error on stderr); 3 when `OffsetEstimate` here does not
have the Rust layout (an edited copy of this script: each difference on stderr).
"""

import argparse
import ctypes
import json
import math
import os
import re
import signal
import sys
import time

import iceoryx2 as iox2

STATES = {0: "acquiring", 1: "tracking", 2: "holding", 3: "lost"}
POLARITIES = {0: "unknown", 1: "positive", -1: "negative"}


class OffsetEstimate(ctypes.Structure):
    """Layout of vlsync.OffsetEstimate.v1: 88 bytes, alignment 8."""

    _fields_ = [
        ("seq", ctypes.c_uint64),  # 0
        ("t_ref_ns", ctypes.c_int64),  # 8
        ("offset_s", ctypes.c_double),  # 16
        ("drift", ctypes.c_double),  # 24
        ("offset_std_s", ctypes.c_double),  # 32
        ("drift_std", ctypes.c_double),  # 40
        ("peak_score", ctypes.c_double),  # 48
        ("peak_ratio", ctypes.c_double),  # 56
        ("measured_offset_s", ctypes.c_double),  # 64
        ("publish_ns", ctypes.c_int64),  # 72
        ("state", ctypes.c_uint8),  # 80
        ("polarity", ctypes.c_int8),  # 81
        ("reserved", ctypes.c_uint8 * 6),  # 82
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name, identical to the Rust `#[type_name]`."""
        return "vlsync.OffsetEstimate.v1"


# Exit statuses (the docstring says when).
EXIT_OK, EXIT_TIMEOUT, EXIT_ERROR, EXIT_LAYOUT = 0, 1, 2, 3

# The Rust layout of vlsync.OffsetEstimate.v1 (the layout test of common/src/wire.rs):
# size, alignment, and every field with its type and offset.
RUST_LAYOUT = (
    88,
    8,
    [
        ("seq", ctypes.c_uint64, 0),
        ("t_ref_ns", ctypes.c_int64, 8),
        ("offset_s", ctypes.c_double, 16),
        ("drift", ctypes.c_double, 24),
        ("offset_std_s", ctypes.c_double, 32),
        ("drift_std", ctypes.c_double, 40),
        ("peak_score", ctypes.c_double, 48),
        ("peak_ratio", ctypes.c_double, 56),
        ("measured_offset_s", ctypes.c_double, 64),
        ("publish_ns", ctypes.c_int64, 72),
        ("state", ctypes.c_uint8, 80),
        ("polarity", ctypes.c_int8, 81),
        ("reserved", ctypes.c_uint8 * 6, 82),
    ],
)


def layout_mismatches(cls=None):
    """How the ctypes layout of `cls` (default `OffsetEstimate`) differs from the Rust
    one: a list of lines naming each difference, empty when there is none. An explicit
    check, not `assert` (which `python3 -O` strips): main() exits with EXIT_LAYOUT (3)
    on any, before it opens a service."""
    cls = cls or OffsetEstimate
    size, align, fields = RUST_LAYOUT
    problems = []
    if ctypes.sizeof(cls) != size:
        problems.append(f"size {ctypes.sizeof(cls)}, expected {size}")
    if ctypes.alignment(cls) != align:
        problems.append(f"alignment {ctypes.alignment(cls)}, expected {align}")
    ours = [(name, kind, getattr(cls, name).offset) for name, kind, *_ in cls._fields_]

    def show(field):
        return "none" if field is None else f"{field[0]} ({field[1].__name__}) at {field[2]}"

    for i in range(max(len(ours), len(fields))):
        got = ours[i] if i < len(ours) else None
        want = fields[i] if i < len(fields) else None
        if got != want:
            problems.append(f"field {i}: {show(got)}, expected {show(want)}")
    return problems


# The daemon's settings of the offset services (vlsync_ipc::Qos::latest and
# open_or_create_event): whoever starts first creates them, and the others use them.
PUBSUB_SETTINGS = {
    "history_size": 1,
    "subscriber_max_buffer_size": 16,
    "max_publishers": 2,
    "max_subscribers": 16,
    "max_nodes": 32,
}
EVENT_SETTINGS = {"max_nodes": 48, "max_notifiers": 16, "max_listeners": 16}

# The rule of `services.prefix` (vlsync_config::ServicesConfig::validate).
PREFIX_RULE = re.compile(r"[A-Za-z0-9_.\-/]{1,200}")

# With nothing received for this long, say once what is waited for.
QUIET_NOTICE_S = 5.0


# An estimate older than this (seconds) is marked stale (--max-age; vlsync_convert's 3 s).
DEFAULT_MAX_AGE_S = 3.0
MAX_SECONDS = 1e6  # the largest --max-age, as vlsync_convert's

# A publish time at most this far ahead of CLOCK_MONOTONIC is age 0
# (vlsync_ipc::FUTURE_MARGIN_NS, ipc/src/lib.rs).
FUTURE_MARGIN_NS = 1_000_000_000
I64_MIN, I64_MAX = -(2**63), 2**63 - 1

# The offset's random walk (s/√s) a conversion's σ adds from t_ref to the stamp: while
# tracking, the daemon's `estimator.offset_process_noise`; in every other state its
# `estimator.hold_process_noise`. These are the shipped values, the defaults of
# `vlsync_config::EstimatorConfig` (config/src/lib.rs) that the Rust client
# (`vlsync_ipc::OffsetClient::camera_to_lidar`) and libvlsync_client assume too; for a
# daemon configured otherwise, pass its values as `walk` (the Rust client's
# `set_process_noise`).
WALK_TRACKING = 2e-4
WALK_HOLDING = 3e-3


def saturate_i64(n: int) -> int:
    """`n` clamped to a 64-bit signed integer, as Rust's saturating arithmetic."""
    return max(I64_MIN, min(I64_MAX, n))


def estimate_age_ns(publish_ns: int, now_ns=None) -> int:
    """How old an estimate published at `publish_ns` is, ns: `CLOCK_MONOTONIC` now (or
    `now_ns`) minus `publish_ns`, which is on the daemon's `CLOCK_MONOTONIC` (not
    `time.time()`'s clock). The Rust client's rule (`vlsync_ipc::estimate_age_at`): a
    publish time up to FUTURE_MARGIN_NS ahead is age 0; one further ahead (another
    clock, a faulty publisher) is I64_MAX, so that every age check fails."""
    if now_ns is None:
        now_ns = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
    age = saturate_i64(now_ns - publish_ns)
    return I64_MAX if age < -FUTURE_MARGIN_NS else max(age, 0)


def secs_to_nanos(s: float) -> int:
    """Seconds to ns as `vlsync_common::secs_to_nanos`: rounded half away from zero
    (Rust's `f64::round`, not Python's `round`), saturating, NaN 0."""
    x = s * 1e9
    if math.isnan(x):
        return 0
    if x >= 2.0**63:
        return I64_MAX
    if x <= -(2.0**63):
        return I64_MIN
    r = math.floor(x) if x >= 0 else math.ceil(x)  # exact: x - r is exact too
    if abs(x - r) >= 0.5:
        r += 1 if x >= 0 else -1
    return r


def offset_at(e: dict, t_lidar_ns: int) -> float:
    """The offset (s) at LiDAR time `t_lidar_ns`, extrapolated from t_ref with the drift
    (`Estimate::offset_at`)."""
    return e["offset_s"] + e["drift"] * (float(saturate_i64(t_lidar_ns - e["t_ref_ns"])) * 1e-9)


def camera_to_lidar(e: dict, t_cam_ns: int, walk=(WALK_TRACKING, WALK_HOLDING)):
    """Camera stamp `t_cam_ns` (integer ns on the camera's clock) on the LiDAR clock
    with estimate `e` (a dict as `validate` returns): `(t_lidar_ns, std_s)`.

    `t_L = t_C + offset(t_L)`, the offset extrapolated with the drift to the LiDAR time
    it is for, solved by fixed-point steps as `Estimate::camera_to_lidar`
    (common/src/lib.rs; the error is below `drift³ · |t_L - t_ref|`). `std_s` is the σ
    of that stamp (`Estimate::offset_std_with_walk`):
    `sqrt(offset_std² + (drift_std · dt)² + w² · dt)`, `dt = |t_L - t_ref|` in s, `w`
    the offset's random walk, `walk[0]` while tracking, else `walk[1]` (WALK_TRACKING,
    WALK_HOLDING: see there). The printed `±` is σ at t_ref only: 10 s from t_ref, an
    offset_std of 1 ms with drift_std 1e-6 gives 1.18 ms while tracking, 9.5 ms holding.
    The same operations in the same order as the Rust client: the same result, bit for
    bit. Check the estimate's state and age (`estimate_age_ns`) before trusting it.
    """
    t_cam_ns = int(t_cam_ns)

    def shifted(offset_s):  # vlsync_common::camera_to_lidar_ns
        return saturate_i64(t_cam_ns + secs_to_nanos(offset_s))

    first = shifted(e["offset_s"])
    second = shifted(offset_at(e, first))
    t_lidar_ns = shifted(offset_at(e, second))
    w = walk[0] if e["state"] == "tracking" else walk[1]
    dt = abs(float(saturate_i64(t_lidar_ns - e["t_ref_ns"])) * 1e-9)
    sd, dd = e["offset_std_s"], e["drift_std"] * dt
    return t_lidar_ns, math.sqrt(sd * sd + dd * dd + w * w * dt)


class Iox2Failure(Exception):
    """iceoryx2 failed while waiting or receiving: the script exits with status 2."""


def interrupted(err: Exception) -> bool:
    """Whether a ListenerWaitError is ListenerWaitError::InterruptSignal (a signal
    interrupted the wait) rather than ContractViolation or InternalFailure. The binding
    raises one exception class for every variant, with the variant's name as message."""
    # iceoryx2 0.10's variant name, matched as text: recheck it (and "DoesNotExist" and
    # "Incompatible" below) whenever requirements.txt's pinned iceoryx2 version changes
    return "InterruptSignal" in str(err)


def validate(e: OffsetEstimate) -> dict:
    """Returns the estimate as a dict, or raises ValueError naming the bad field."""
    if e.state not in STATES:
        raise ValueError(f"unknown state code {e.state}")
    if e.polarity not in POLARITIES:
        raise ValueError(f"unknown polarity code {e.polarity}")
    for name in ("offset_s", "drift", "offset_std_s", "drift_std", "peak_score"):
        if not math.isfinite(getattr(e, name)):
            raise ValueError(f"field {name} is not finite")
    if e.offset_std_s < 0 or e.drift_std < 0:
        raise ValueError("negative standard deviation")
    # +inf is a valid ratio (no second peak); NaN or negative is not
    if math.isnan(e.peak_ratio) or e.peak_ratio < 0:
        raise ValueError(f"field peak_ratio is {e.peak_ratio}")
    # NaN means "no fresh measurement in this hop"; infinite is invalid
    if math.isinf(e.measured_offset_s):
        raise ValueError("field measured_offset_s is infinite")
    if any(e.reserved):
        raise ValueError("reserved bytes are not zero")
    return {
        "seq": e.seq,
        "t_ref_ns": e.t_ref_ns,
        "offset_s": e.offset_s,
        "drift": e.drift,
        "offset_std_s": e.offset_std_s,
        "drift_std": e.drift_std,
        "state": STATES[e.state],
        "polarity": POLARITIES[e.polarity],
        "peak_score": e.peak_score,
        "peak_ratio": json_number(e.peak_ratio),
        "measured_offset_s": json_number(e.measured_offset_s),
        "publish_ns": e.publish_ns,
    }


def json_number(x: float):
    """JSON has no NaN or infinity: None (null), as `vlsync-echo --json` writes."""
    return x if math.isfinite(x) else None


def prefix_problem(prefix: str):
    """Why the daemon would refuse `prefix` as `services.prefix`, or None."""
    if (
        not PREFIX_RULE.fullmatch(prefix)
        or prefix.startswith("/")
        or prefix.endswith("/")
        or "//" in prefix
    ):
        return (
            f"--prefix {prefix!r} is invalid: allowed 1-200 characters of [A-Za-z0-9_.-/], "
            "no leading, trailing or double `/` (the rule of services.prefix)"
        )
    return None


def open_or_create(builder, settings):
    """Opens the service a fresh `builder()` describes, or creates it with `settings`
    (a service that exists keeps its own: whoever created it first set them)."""
    try:
        return builder().open()
    except Exception as err:  # iceoryx2's typed errors: only a missing service is created
        # the error variant's name in iceoryx2 0.10 (PublishSubscribeOpenError and
        # EventOpenError::DoesNotExist), matched as text: recheck it whenever
        # requirements.txt's pinned iceoryx2 version changes
        if "DoesNotExist" not in repr(err):
            raise
    b = builder()
    for key, value in settings.items():
        b = getattr(b, key)(value)
    if hasattr(b, "enable_safe_overflow"):
        b = b.enable_safe_overflow(True)
    return b.create()


def open_service(node, name, attempts=50):
    """Opens the offset services, or creates them with the daemon's settings; retries
    while another process sets them up (both may try to create them at once)."""
    service = iox2.ServiceName.new(name)
    last = None
    for _ in range(attempts):
        try:
            pubsub = open_or_create(
                lambda: node.service_builder(service).publish_subscribe(OffsetEstimate),
                PUBSUB_SETTINGS,
            )
            event = open_or_create(lambda: node.service_builder(service).event(), EVENT_SETTINGS)
            return pubsub, event
        except Exception as err:  # iceoryx2 raises typed errors; retry transient ones
            last = err
            # a service of another layout or settings stays so: no use retrying
            # (iceoryx2 0.10's IncompatibleTypes, IncompatibleMessagingPattern, ...,
            # matched as text: recheck whenever the pinned iceoryx2 version changes)
            if "Incompatible" in repr(err):
                break
            time.sleep(0.02)
    raise RuntimeError(f"cannot open service {name!r}: {last!r}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prefix", default="vlsync/robot")
    ap.add_argument("--count", type=int, default=0, help="exit after N estimates (0: run until Ctrl-C)")
    ap.add_argument("--timeout", type=float, default=0.0, help="fail if no estimate for S seconds (0: never)")
    ap.add_argument(
        "--max-age",
        type=float,
        default=DEFAULT_MAX_AGE_S,
        help=f"mark an estimate older than A seconds stale (default {DEFAULT_MAX_AGE_S:g})",
    )
    ap.add_argument("--json", action="store_true", help="one JSON object per line")
    args = ap.parse_args()
    mismatches = layout_mismatches()
    if mismatches:
        for line in mismatches:
            print(f"vlsync_subscriber: OffsetEstimate differs from the Rust layout: {line}", file=sys.stderr)
        return EXIT_LAYOUT
    problem = prefix_problem(args.prefix)
    if problem:
        ap.error(problem)  # exit status 2
    if args.count < 0:
        ap.error(f"--count {args.count} is negative (0: run until Ctrl-C)")
    if not math.isfinite(args.timeout) or args.timeout < 0:
        ap.error(f"--timeout {args.timeout} must be a finite number >= 0 (0: never)")
    if not 0 < args.max_age <= MAX_SECONDS:
        ap.error(f"--max-age {args.max_age} must be seconds > 0 (at most {MAX_SECONDS:.0f})")
    max_age_ns = args.max_age * 1e9

    # SIGINT and SIGTERM only set a flag: iceoryx2's wait returns on the signal, and the
    # loop ends as after --count (a KeyboardInterrupt raised inside iceoryx2's call
    # would surface as a traceback instead)
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: stop.append(signum))

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    name = f"{args.prefix}/offset"
    try:
        node = (
            iox2.NodeBuilder.new()
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        pubsub, event = open_service(node, name)
        subscriber = pubsub.subscriber_builder().create()
        listener = event.listener_builder().create()
    except Exception as err:  # iceoryx2's errors (a bad service name, no shared memory, ...)
        print(f"vlsync_subscriber: error: {name!r}: {err}", file=sys.stderr)
        return EXIT_ERROR

    got = invalid = 0
    invalid_said, invalid_told = 0.0, 0  # when the last skipped line was printed, and the count then
    status = EXIT_OK
    started = last_seen = time.monotonic()
    noticed = False
    try:
        while not stop and (args.count == 0 or got < args.count):
            # sleep until the daemon notifies (or 200 ms pass, or a signal arrives)
            woken = True
            try:
                listener.timed_wait(iox2.Duration.from_millis(200))
            except iox2.ListenerWaitError as err:
                if not interrupted(err):  # ContractViolation, InternalFailure
                    raise Iox2Failure(f"waiting on the event failed: ListenerWaitError {err}") from err
                # interrupted by a signal: Ctrl-C or SIGTERM ends the loop as --count
                # does; any other signal goes on to the checks below (--timeout)
                if stop:
                    break
                woken = False
            while woken:
                try:
                    sample = subscriber.receive()
                except iox2.ReceiveError as err:  # ExceedsMaxBorrows, ConnectionFailure(...)
                    raise Iox2Failure(f"receiving an estimate failed: ReceiveError {err}") from err
                if sample is None:
                    break
                # a copy first: validated and printed is then the same bytes, even
                # if a publisher rewrote the shared sample after sending it
                copy = OffsetEstimate.from_buffer_copy(sample.payload().contents)
                try:
                    e = validate(copy)
                except ValueError as err:
                    invalid += 1
                    # the first said at once, then at most a line per 10 s with a count:
                    # a publisher of garbage must not flood stderr
                    now = time.monotonic()
                    if invalid == 1 or now - invalid_said >= 10.0:
                        more = invalid - invalid_told - 1
                        print(
                            f"vlsync_subscriber: skipped invalid estimate: {err}"
                            + (f" ({more} more since the last such line)" if more else ""),
                            file=sys.stderr,
                        )
                        invalid_said, invalid_told = now, invalid
                    continue
                got += 1
                last_seen = time.monotonic()
                # the service hands a late subscriber the daemon's last estimate,
                # however old: its age tells, not its state
                age_ns = estimate_age_ns(e["publish_ns"])
                stale = age_ns > max_age_ns
                if args.json:
                    print(json.dumps({**e, "age_s": age_ns * 1e-9, "stale": stale}), flush=True)
                else:
                    state = e["state"]
                    if stale:
                        state = f"stale ({age_ns * 1e-9:.1f} s old; {state} when published)"
                    print(
                        f"#{e['seq']:<6} t_ref {e['t_ref_ns'] * 1e-9:12.3f} s  "
                        f"offset {e['offset_s'] * 1e3:+9.3f} ms ± {e['offset_std_s'] * 1e3:7.3f} ms  "
                        f"drift {e['drift'] * 1e6:+8.2f} ppm  {state}",
                        flush=True,
                    )
                if args.count and got >= args.count:
                    break
            now = time.monotonic()
            if not got and not invalid and not noticed and now - started >= QUIET_NOTICE_S:
                noticed = True
                print(
                    f"vlsync_subscriber: nothing received on `{name}` for {QUIET_NOTICE_S:.0f} s; "
                    f"waiting (is a daemon running with services.prefix = \"{args.prefix}\"? "
                    "vlsync-demo uses its own prefix, printed at its start)",
                    file=sys.stderr,
                    flush=True,
                )
            if args.timeout and now - last_seen > args.timeout:
                print(f"vlsync_subscriber: no estimate on {name} for {args.timeout} s", file=sys.stderr)
                status = EXIT_TIMEOUT
                break
    except KeyboardInterrupt:  # a SIGINT before the handlers were installed
        pass
    except Iox2Failure as err:
        print(f"vlsync_subscriber: error: {name!r}: {err}", file=sys.stderr)
        status = EXIT_ERROR
    except BrokenPipeError:
        # the reader went away (`| head -1`): done, as vlsync-echo is; stdout points
        # at /dev/null so the interpreter's own flush at exit does not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except OSError as err:  # a full disk or another write error on stdout
        print(f"vlsync_subscriber: error: cannot write to stdout: {err}", file=sys.stderr)
        status = EXIT_ERROR
    if invalid:
        print(f"vlsync_subscriber: {got} estimates received, {invalid} invalid ones skipped", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
