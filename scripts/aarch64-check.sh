#!/usr/bin/env bash
# The Raspberry Pi's build, checked on an x86-64 Debian 12 / Ubuntu host:
#
#  1. cross-compiles every binary and the C/C++ client library (libvlsync_client.so) for
#     aarch64-unknown-linux-gnu (what deploy/README.md copies to the Pi);
#  2. runs the numeric crates' tests (common, config, simd, estimator, sim) on aarch64
#     under qemu user-mode emulation;
#  3. runs `vlsyncd bench` (every simulated family, two seed sets) and one replay with the
#     aarch64 build and the native one, and requires the same results bit for bit: the
#     estimator promises the same estimates on any CPU (ARCHITECTURE.md, invariants);
#  4. with --ipc, the multi-process tests (crate vlsync-tests: daemon, drivers, echo, the
#     Python subscriber, and the C and C++ examples compiled with the aarch64 cross
#     compilers against the aarch64 library) with the aarch64 binaries, but for four that
#     cannot hold under emulation: the rendered demo, the short load profile and the camera
#     program on a pipe (each renders in real time, and emulated the renderer falls 30 s
#     behind: the pipe's 22 s run had written 460 of its 660 frames when the test gave up)
#     and the daemon's signal-handler census (qemu itself catches every signal).
# Tests that run the binaries exec aarch64 files, so the kernel must hand them to qemu
# (binfmt_misc): the script registers qemu-aarch64 there when missing (as root; until reboot).
#
# It installs what it needs when missing (gcc-aarch64-linux-gnu, g++-aarch64-linux-gnu,
# libc6-dev-arm64-cross, qemu-user through apt-get, which needs root; the Rust target through rustup).
# The Python subscriber's test (step 4) needs the pinned iceoryx2 package that
# ./scripts/test.sh installs. From a fresh clone on 2 cores, 11.5 minutes with --ipc, most
# of it the cross and the native builds (step 4 about 5 of them). Not part of
# ./scripts/test.sh: it would take the suite past its time budget. qemu checks results,
# not timing, and emulates aarch64 on x86's stronger memory ordering: the Pi's own soak
# (deploy/README.md) is the check of the real board.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=aarch64-unknown-linux-gnu
ipc=0
for a in "$@"; do
    case "$a" in
        --ipc) ipc=1 ;;
        -h | --help)
            sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
            exit 0
            ;;
        *)
            echo "error: unknown argument '$a' (accepted: --ipc, --help)" >&2
            exit 2
            ;;
    esac
done
SYSROOT=/usr/aarch64-linux-gnu

missing=()
command -v aarch64-linux-gnu-gcc >/dev/null || missing+=(gcc-aarch64-linux-gnu)
command -v aarch64-linux-gnu-g++ >/dev/null || missing+=(g++-aarch64-linux-gnu)
[ -e "$SYSROOT/lib/ld-linux-aarch64.so.1" ] || missing+=(libc6-dev-arm64-cross)
command -v qemu-aarch64 >/dev/null || missing+=(qemu-user)
if [ ${#missing[@]} -gt 0 ]; then
    echo "==> installing ${missing[*]}"
    if [ "$(id -u)" -ne 0 ]; then
        echo "error: ${missing[*]} missing and not root: install them with apt-get, or run this as root" >&2
        exit 1
    fi
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"
fi
command -v cargo >/dev/null || { echo "error: cargo not found (install Rust: https://rustup.rs)" >&2; exit 1; }
if ! [ -d "$(rustc --print sysroot)/lib/rustlib/$TARGET" ]; then
    command -v rustup >/dev/null || {
        echo "error: the Rust standard library for $TARGET is missing and there is no rustup to add it" >&2
        exit 1
    }
    echo "==> rustup target add $TARGET"
    rustup target add "$TARGET"
fi

# tests that run the binaries (the CLIs' own, the multi-process ones) exec aarch64 files:
# the kernel hands them to qemu through binfmt_misc
reg=/proc/sys/fs/binfmt_misc
if ! grep -qx enabled "$reg/qemu-aarch64" 2>/dev/null; then
    if [ "$(id -u)" -ne 0 ]; then
        echo "error: aarch64 binaries do not run here (no binfmt_misc entry for qemu-aarch64) and not root to register one" >&2
        exit 1
    fi
    [ -e "$reg/register" ] || mount -t binfmt_misc binfmt_misc "$reg"
    echo "    registering qemu-aarch64 in $reg (until reboot)"
    printf '%s' ':qemu-aarch64:M::\x7fELF\x02\x01\x01\x00\x00\x00\x00\x00\x00\x00\x00\x00\x02\x00\xb7\x00:\xff\xff\xff\xff\xff\xff\xff\x00\xff\xff\xff\xff\xff\xff\xff\xff\xfe\xff\xff\xff:/usr/bin/qemu-aarch64:' >"$reg/register"
fi
export QEMU_LD_PREFIX=$SYSROOT
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="qemu-aarch64 -L $SYSROOT"
arm() { qemu-aarch64 -L "$SYSROOT" "$@"; }

echo "==> 1. cross build: cargo build --release --bins --target $TARGET, and -p vlsync-capi"
cargo build --release --bins --target "$TARGET"
cargo build --release -p vlsync-capi --target "$TARGET"
ls -l target/$TARGET/release/{vlsync{d,-cam,-lidar,-echo,-soak},libvlsync_client.so} | awk '{print "    " $5 " bytes  " $9}'

echo "==> 2. the numeric crates' tests on aarch64 (qemu)"
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
if ! cargo test --release --target "$TARGET" -p vlsync-common -p vlsync-config -p vlsync-simd \
    -p vlsync-estimator -p vlsync-sim >"$out/test.log" 2>&1; then
    grep -E '^(failures:|---- )|panicked|^error' "$out/test.log" | head -40 >&2
    echo "error: a test failed on aarch64 (log above)" >&2
    exit 1
fi
awk '/^test result: ok/ { p += $4 } END { print "    " p " tests passed" }' "$out/test.log"

echo "==> 3. the same results as the native build, bit for bit"
cargo build --release -p vlsyncd --bin vlsyncd -p vlsync-sim --bin vlsync-sim
native=target/release
cross=target/$TARGET/release
fail=0
for set in "1000 5" "4000 10"; do
    read -r base seeds <<<"$set"
    $native/vlsyncd bench --seed-base "$base" --seeds "$seeds" --json "$out/x86-$base.json" >/dev/null 2>&1
    arm $cross/vlsyncd bench --seed-base "$base" --seeds "$seeds" --json "$out/arm-$base.json" >/dev/null 2>&1
    python3 - "$out/x86-$base.json" "$out/arm-$base.json" "$base" "$seeds" <<'EOF' || fail=1
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
for x in a + b:
    x.pop("estimator_time_s", None)  # wall-clock time, not a result
same = [fa["family"] for fa, fb in zip(a, b) if fa == fb]
diff = [fa["family"] for fa, fb in zip(a, b) if fa != fb]
first, n = int(sys.argv[3]), int(sys.argv[4])
print(f"    bench on seeds {first}-{first + n - 1}: {len(same)} of {len(a)} families identical"
      + (f"; DIFFERENT: {', '.join(diff)}" if diff else ""))
sys.exit(1 if diff or len(a) != len(b) else 0)
EOF
done
$native/vlsync-sim --family clocks --seed 1 --out "$out/run-x86" >/dev/null
arm $cross/vlsync-sim --family clocks --seed 1 --out "$out/run-arm" >/dev/null
for f in cam lidar truth; do
    cmp -s "$out/run-x86/$f.csv" "$out/run-arm/$f.csv" || { echo "    vlsync-sim: $f.csv differs"; fail=1; }
done
$native/vlsyncd replay --cam "$out/run-x86/cam.csv" --lidar "$out/run-x86/lidar.csv" --out "$out/est-x86.csv" 2>/dev/null
arm $cross/vlsyncd replay --cam "$out/run-x86/cam.csv" --lidar "$out/run-x86/lidar.csv" --out "$out/est-arm.csv" 2>/dev/null
if cmp -s "$out/est-x86.csv" "$out/est-arm.csv"; then
    echo "    replay of clocks seed 1 (120 s): $(($(wc -l <"$out/est-x86.csv") - 1)) estimates, byte for byte the same"
else
    echo "    replay of clocks seed 1: the estimates differ"
    fail=1
fi
if [ $fail -ne 0 ]; then
    echo "error: the aarch64 build's results differ from the native build's" >&2
    exit 1
fi

if [ $ipc -eq 1 ]; then
    echo "==> 4. the multi-process tests with the aarch64 binaries (qemu through binfmt_misc)"
    # the binaries were cross-built in step 1; the tests must not rebuild them natively.
    # The C and C++ examples are compiled for aarch64 too, against the aarch64 library
    if ! CC=aarch64-linux-gnu-gcc CXX=aarch64-linux-gnu-g++ VLSYNC_PREBUILT_BINS=1 cargo test --release --no-fail-fast --target "$TARGET" -p vlsync-tests -- \
        --skip demo_ctrl_c_stops_children_and_leaves_nothing \
        --skip short_load_profile_keeps_error_and_loss_in_bounds \
        --skip a_camera_program_on_a_pipe_locks_to_the_offset_of_its_arrival_stamps \
        --skip without_notify_socket_the_daemon_runs_and_stops_as_before >"$out/ipc.log" 2>&1; then
        # each failing test's own output (its assertion message with the logs it names),
        # up to its backtrace, then cargo's summary of the failed targets
        awk '/^---- .* stdout ----$/ { p = 1; n = 0 } /^stack backtrace:/ { p = 0 }
             p && n++ < 25 { print } /^error/ { print }' "$out/ipc.log" >&2
        echo "error: a multi-process test failed with the aarch64 binaries (log above)" >&2
        exit 1
    fi
    awk '/^test result: ok/ { p += $4; f += $12 } END { print "    " p " tests passed, " f " skipped (see the header)" }' "$out/ipc.log"
fi
echo "==> aarch64: built, tests passed, results identical to x86-64"
