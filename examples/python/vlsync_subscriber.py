#!/usr/bin/env python3
"""Subscribe to the vlsync daemon's offset estimates from Python.

Uses the official iceoryx2 Python package (see requirements.txt; the version
must equal the Rust side's). `OffsetEstimate` mirrors the `#[repr(C)]` Rust
type `vlsync_common::wire::OffsetEstimate` field by field and carries the same
iceoryx2 type name. iceoryx2 compares the type name, size and alignment, not the
fields: the `.v1` in the name is what guards the layout (a change of layout gets
a new name), and the asserts below pin every offset against the Rust one.
Started before the daemon, it creates the services with the daemon's settings
(the last estimate kept for late subscribers, 16 buffered), as every vlsync
process does, so any start order works.

    python3 vlsync_subscriber.py --prefix vlsync/robot [--count N] [--timeout S] [--json]

Every field read from shared memory is validated as the Rust client does
(state and polarity codes, finite offset/drift/deviations, a peak ratio that is
not NaN or negative, a measured offset that is not infinite, zero reserved
bytes); invalid samples are skipped: the first is said on stderr with its
reason, then at most one line per 10 s, with how many more were skipped since the
last such line, and how many were skipped in all is printed at exit. With nothing
received for 5 s it says once on stderr what it waits for (a daemon on another
prefix is the usual cause). Exit
status: 0 after --count valid estimates, on Ctrl-C (SIGINT) or SIGTERM, or when
the reader of its output goes away (`| head -1`); 1 on timeout; 2 on error (a bad
argument, such as a prefix the daemon would refuse or a negative count, iceoryx2
refusing the node or the service or failing while waiting or receiving, or a write
error on stdout, with its error on stderr).
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


assert ctypes.sizeof(OffsetEstimate) == 88
assert ctypes.alignment(OffsetEstimate) == 8
# every field at the offset the Rust layout test pins (common/src/wire.rs)
assert [(name, getattr(OffsetEstimate, name).offset) for name, _ in OffsetEstimate._fields_] == [
    ("seq", 0),
    ("t_ref_ns", 8),
    ("offset_s", 16),
    ("drift", 24),
    ("offset_std_s", 32),
    ("drift_std", 40),
    ("peak_score", 48),
    ("peak_ratio", 56),
    ("measured_offset_s", 64),
    ("publish_ns", 72),
    ("state", 80),
    ("polarity", 81),
    ("reserved", 82),
]

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


class Iox2Failure(Exception):
    """iceoryx2 failed while waiting or receiving: the script exits with status 2."""


def interrupted(err: Exception) -> bool:
    """Whether a ListenerWaitError is ListenerWaitError::InterruptSignal (a signal
    interrupted the wait) rather than ContractViolation or InternalFailure. The binding
    raises one exception class for every variant, with the variant's name as message."""
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
            if "Incompatible" in repr(err):
                break
            time.sleep(0.02)
    raise RuntimeError(f"cannot open service {name!r}: {last!r}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prefix", default="vlsync/robot")
    ap.add_argument("--count", type=int, default=0, help="exit after N estimates (0: run until Ctrl-C)")
    ap.add_argument("--timeout", type=float, default=0.0, help="fail if no estimate for S seconds (0: never)")
    ap.add_argument("--json", action="store_true", help="one JSON object per line")
    args = ap.parse_args()
    problem = prefix_problem(args.prefix)
    if problem:
        ap.error(problem)  # exit status 2
    if args.count < 0:
        ap.error(f"--count {args.count} is negative (0: run until Ctrl-C)")
    if not math.isfinite(args.timeout) or args.timeout < 0:
        ap.error(f"--timeout {args.timeout} must be a finite number >= 0 (0: never)")

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
        return 2

    got = invalid = 0
    invalid_said, invalid_told = 0.0, 0  # when the last skipped line was printed, and the count then
    status = 0
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
                if args.json:
                    print(json.dumps(e), flush=True)
                else:
                    print(
                        f"#{e['seq']:<6} t_ref {e['t_ref_ns'] * 1e-9:12.3f} s  "
                        f"offset {e['offset_s'] * 1e3:+9.3f} ms ± {e['offset_std_s'] * 1e3:7.3f} ms  "
                        f"drift {e['drift'] * 1e6:+8.2f} ppm  {e['state']}",
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
                status = 1
                break
    except KeyboardInterrupt:  # a SIGINT before the handlers were installed
        pass
    except Iox2Failure as err:
        print(f"vlsync_subscriber: error: {name!r}: {err}", file=sys.stderr)
        status = 2
    except BrokenPipeError:
        # the reader went away (`| head -1`): done, as vlsync-echo is; stdout points
        # at /dev/null so the interpreter's own flush at exit does not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except OSError as err:  # a full disk or another write error on stdout
        print(f"vlsync_subscriber: error: cannot write to stdout: {err}", file=sys.stderr)
        status = 2
    if invalid:
        print(f"vlsync_subscriber: {got} estimates received, {invalid} invalid ones skipped", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
