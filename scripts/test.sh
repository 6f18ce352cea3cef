#!/usr/bin/env bash
# The whole test suite, from a fresh clone: installs what the tests need, then runs them.
# Used verbatim by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."
trap 'rm -f "${pip_log:-}" "${test_log:-}" "${VLSYNC_SKIP_LOG:-}"' EXIT

started=$SECONDS
# The Rust toolchain is not installed here (a network install of a compiler is the
# machine's owner's choice): without cargo and rustc at the workspace's rust-version
# (Cargo.toml's `rust-version`), nothing would build; say so, and how, before any
# install or the ten-minute build.
need_rust="$(sed -n 's/^rust-version *= *"\([0-9.]*\)".*/\1/p' Cargo.toml | head -n 1)" || need_rust=""
rust_hint="install it with rustup (https://rustup.rs: curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh), or update it: rustup update stable"
for tool in cargo rustc; do
    if ! command -v "$tool" >/dev/null 2>&1; then
        echo "scripts/test.sh: $tool not found: the tests need the Rust toolchain${need_rust:+ $need_rust or newer}; $rust_hint" >&2
        exit 1
    fi
done
# (rustup's rustc with no toolchain installed fails: said below, not a silent exit)
have_rust="$(rustc --version 2>/dev/null | sed -n 's/^rustc \([0-9][0-9.]*\).*/\1/p')" || have_rust=""
if [ -z "$have_rust" ]; then
    echo "scripts/test.sh: \`rustc --version\` did not say a version (\"$(rustc --version 2>&1 | head -n 1)\"); $rust_hint" >&2
    exit 1
fi
if [ -n "$need_rust" ] && [ "$(printf '%s\n%s\n' "$need_rust" "$have_rust" | sort -V | head -n 1)" != "$need_rust" ]; then
    echo "scripts/test.sh: rustc $have_rust is older than the workspace's rust-version $need_rust (Cargo.toml); $rust_hint" >&2
    exit 1
fi
# apt-get install, as root or through sudo, without questions, waiting up to 5 min for
# another apt (a fresh VM's unattended upgrades) to let go of its lock. Never fatal: when
# it cannot install (not root and no sudo, offline, no such package), it says what will
# not work and the suite runs anyway; the tests that need the package say so.
install_deb() {
    local sudo
    if [ "$(id -u)" -eq 0 ]; then sudo=""; elif command -v sudo >/dev/null 2>&1; then
        # asks for a password on a terminal; elsewhere (CI) fails at once instead of hanging
        if [ -t 0 ]; then sudo="sudo"; else sudo="sudo -n"; fi
    else
        echo "$1 is missing and cannot be installed (not root, no sudo): $2" >&2
        return 0
    fi
    # as root no questions (DEBIAN_FRONTEND); through sudo, apt-get itself (a sudoers rule
    # may allow only that), its questions answered by their defaults off a terminal
    local apt=(apt-get -o DPkg::Lock::Timeout=300)
    if [ -z "$sudo" ]; then apt=(env DEBIAN_FRONTEND=noninteractive "${apt[@]}"); else apt=($sudo "${apt[@]}"); fi
    local in=/dev/stdin
    [ -t 0 ] || in=/dev/null
    # $1: one package, or several separated by spaces
    local pkgs
    read -r -a pkgs <<<"$1"
    "${apt[@]}" install -y "${pkgs[@]}" <"$in" || { "${apt[@]}" update <"$in" && "${apt[@]}" install -y "${pkgs[@]}" <"$in"; } || {
        echo "$1 could not be installed (apt-get failed above): $2" >&2
        return 0
    }
}

# The Python subscriber test needs the official iceoryx2 package, pinned to the
# same version as the Rust crate. Nothing is installed when python3 (or the venv below,
# from an earlier run) already has it. Otherwise it is installed for python3 itself
# where pip may; a Debian/Ubuntu system Python refuses that (PEP 668:
# "externally-managed-environment") or has no pip, and the package then goes into a
# virtual environment under target/ (python3-venv installed when missing), which the
# test runs (VLSYNC_PYTHON). Once the package is there, the test must find it
# (VLSYNC_REQUIRE_PYTHON): a missing package fails the suite instead of skipping.
req=examples/python/requirements.txt
venv=target/python-venv
pinned="$(sed -n 's/^iceoryx2==//p' "$req")"
has_pinned() {
    "$1" -c "import importlib.metadata as m, iceoryx2; assert m.version('iceoryx2') == '$pinned'" 2>/dev/null
}
use_venv() {
    export VLSYNC_PYTHON="$PWD/$venv/bin/python3"
    export VLSYNC_REQUIRE_PYTHON=1
}
# as root (CI) a Python test that cannot run fails instead of skipping (below)
if [ "$(id -u)" -eq 0 ]; then py_lost="will fail"; else py_lost="will be skipped"; fi
command -v python3 >/dev/null 2>&1 || install_deb python3 "the Python subscriber tests $py_lost"
# a pip that fails for another reason (offline, no wheel for this platform) fails the
# Python tests, not the whole suite: they must find the package (VLSYNC_REQUIRE_PYTHON)
pip_failed() {
    echo "pip could not install $req (above): the Python subscriber tests will fail" >&2
    export VLSYNC_REQUIRE_PYTHON=1
}
if ! command -v python3 >/dev/null 2>&1; then
    echo "no python3: the Python subscriber tests $py_lost" >&2
elif has_pinned python3; then
    export VLSYNC_REQUIRE_PYTHON=1
elif [ -x "$venv/bin/python3" ] && has_pinned "$venv/bin/python3"; then
    use_venv
else
    pip_log="$(mktemp)"
    if python3 -m pip install --quiet --disable-pip-version-check -r "$req" 2>"$pip_log"; then
        export VLSYNC_REQUIRE_PYTHON=1
    elif grep -qE 'externally-managed|No module named pip' "$pip_log"; then
        echo "python3 refuses pip installs or has no pip: installing $req into $venv" >&2
        rm -rf "$venv"
        if python3 -m venv "$venv" 2>/dev/null \
            || { rm -rf "$venv"; install_deb python3-venv "no virtual environment can be made" \
                 && python3 -m venv "$venv" 2>/dev/null; }; then
            if "$venv/bin/python3" -m pip install --quiet --disable-pip-version-check -r "$req"; then
                use_venv
            else
                pip_failed
            fi
        else
            rm -rf "$venv"
            echo "cannot make a Python virtual environment: the Python subscriber test $py_lost" >&2
        fi
    else
        cat "$pip_log" >&2
        pip_failed
    fi
fi
# A C compiler and the C library's development files (crt1.o, libc.so): rustc links
# every binary and test with `cc`, so without them nothing builds; the C and C++ client
# tests (tests/tests/ipc_capi.rs, ipc_c_header.rs) also compile the examples against
# libvlsync_client.so. gcc only recommends libc6-dev (an install without recommends
# leaves a cc that cannot link), so both are asked for, and a cc that is there is
# checked by linking a program.
cc_links() {
    local d rc
    command -v cc >/dev/null 2>&1 || return 1
    d="$(mktemp -d)" || return 1
    printf 'int main(void) { return 0; }\n' >"$d/t.c"
    cc "$d/t.c" -o "$d/t" >/dev/null 2>&1
    rc=$?
    rm -rf "$d"
    return "$rc"
}
cc_links || install_deb "gcc libc6-dev" "nothing will build (rustc links with cc; install build-essential, or gcc and libc6-dev)"
command -v c++ >/dev/null 2>&1 || install_deb g++ "the C++ client test will fail"
# The load test (tests/tests/load_short.rs) injects CPU load with stress-ng.
command -v stress-ng >/dev/null 2>&1 || install_deb stress-ng "the load test will fail"
# The units test (tests/tests/systemd_units.rs) runs `systemd-analyze verify`; once it is
# there, the test must find it rather than skip.
command -v systemd-analyze >/dev/null 2>&1 || install_deb systemd "the systemd units will not be verified"
if command -v systemd-analyze >/dev/null 2>&1; then export VLSYNC_REQUIRE_SYSTEMD_ANALYZE=1; fi
# As root (CI runs this as root, as its apt-get needs) every install above could be
# made: a Python or systemd test that would skip for a failed install (the network, a
# mirror) fails instead, so a green run never hides one.
if [ "$(id -u)" -eq 0 ]; then
    export VLSYNC_REQUIRE_PYTHON=1 VLSYNC_REQUIRE_SYSTEMD_ANALYZE=1
fi
# The V4L2 camera source (feature `v4l2`) generates its kernel bindings with libclang
# (bindgen in a build script): without it a build with the feature fails as a whole.
has_libclang() {
    dpkg -s libclang-dev >/dev/null 2>&1 || [ -n "${LIBCLANG_PATH:-}" ] \
        || PATH="$PATH:/sbin:/usr/sbin" ldconfig -p 2>/dev/null \
            | grep -E '^[[:space:]]+libclang(-[0-9.]+)?\.so ' >/dev/null
}
if ! has_libclang; then
    install_deb libclang-dev "the V4L2 source will be left out of the build"
fi

# One build for everything, with the V4L2 source compiled in where libclang is (its tests
# then check the errors for missing and non-video devices; without it they check the
# error of a build without V4L2). `cargo test --workspace` builds every binary before
# running any test; the multi-process tests run those (VLSYNC_PREBUILT_BINS) instead of
# building the workspace a second time.
if has_libclang; then
    export VLSYNC_CARGO_FEATURES="vlsync-driver/v4l2"
else
    echo "scripts/test.sh: no libclang (libclang-dev): building without the V4L2 camera source (feature vlsync-driver/v4l2); its tests with a V4L2 build will not run" >&2
    export VLSYNC_CARGO_FEATURES=""
fi
export VLSYNC_PREBUILT_BINS=1
# The run's output is kept to sum it up at the end: after ten minutes and some eighty
# test binaries, one line says how many tests passed and failed, and how long the
# compile and the tests took. The exit status is cargo's.
test_log="$(mktemp)"
# a test that cannot run its check here (no root, a tool that could not be installed)
# passes for cargo; it writes why into this file, listed after the summary
VLSYNC_SKIP_LOG="$(mktemp)"
export VLSYNC_SKIP_LOG
# cargo's colours and progress bar while compiling, as without the pipe, on a terminal
if [ -t 1 ]; then
    export CARGO_TERM_COLOR="${CARGO_TERM_COLOR:-always}"
    export CARGO_TERM_PROGRESS_WHEN="${CARGO_TERM_PROGRESS_WHEN:-always}"
    export CARGO_TERM_PROGRESS_WIDTH="${CARGO_TERM_PROGRESS_WIDTH:-$(tput cols 2>/dev/null || echo 80)}"
fi
installs=$((SECONDS - started))
set +e
features=()
[ -z "$VLSYNC_CARGO_FEATURES" ] || features=(--features "$VLSYNC_CARGO_FEATURES")
cargo test --workspace --no-fail-fast ${features[@]+"${features[@]}"} 2>&1 | tee "$test_log"
status=${PIPESTATUS[0]}
set -e
awk -v total=$((SECONDS - started)) -v installs="$installs" -v status="$status" '
    # on a terminal cargo colours its lines and redraws its progress bar: plain text first
    { gsub(/\r/, ""); gsub(/\033\[[0-9;]*[A-Za-z]/, "") }
    /^test result:/ { passed += $4; failed += $6; ignored += $8; binaries++ }
    /`test` profile.* target\(s\) in / { line = $0; sub(/.* in /, "", line); compile = line }
    # one per failing target, a test binary that crashed (and so printed no result) too
    /^error: (test|doctest) failed, to rerun pass `/ { t = $0; sub(/.*rerun pass /, "", t); targets = targets sep t; sep = ", "; bad++ }
    END {
        printf "scripts/test.sh: %d passed, %d failed, %d ignored in %d test targets (doc tests included)",
            passed, failed, ignored, binaries
        # a target that crashed or was killed printed no result line: its tests are in no count
        if (bad > 0) printf "; %d target%s failed", bad, (bad > 1 ? "s" : "")
        printf "; %d min %d s in all", total / 60, total % 60
        if (installs > 0) printf " (installs %d s)", installs
        if (compile != "") printf " (compile %s)", compile
        printf "; cargo exited %d\n", status
        if (targets != "") printf "scripts/test.sh: failed targets: %s\n", targets
    }' "$test_log" >&2
if [ -z "$VLSYNC_CARGO_FEATURES" ]; then
    echo "scripts/test.sh: built without the V4L2 camera source (no libclang): its tests with a V4L2 build did not run" >&2
    # as root (CI) libclang-dev could have been installed: a run without it is no pass
    if [ "$(id -u)" -eq 0 ] && [ "$status" -eq 0 ]; then
        echo "scripts/test.sh: failing the run: as root, libclang-dev should have installed (apt-get failed above)" >&2
        status=1
    fi
fi
if [ -s "$VLSYNC_SKIP_LOG" ]; then
    echo "scripts/test.sh: $(wc -l <"$VLSYNC_SKIP_LOG") of the passed tests skipped their check here:" >&2
    sed 's/^/    /' "$VLSYNC_SKIP_LOG" >&2
fi
exit "$status"
