#!/usr/bin/env bash
# The whole test suite, from a fresh clone: installs what the tests need, then runs them.
# Used verbatim by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."

# apt-get install, as root or through sudo; says so when neither is possible
install_deb() {
    local sudo
    if [ "$(id -u)" -eq 0 ]; then sudo=""; elif command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
        echo "$1 is missing and cannot be installed (not root, no sudo): $2" >&2
        return 0
    fi
    $sudo apt-get install -y "$1" || { $sudo apt-get update && $sudo apt-get install -y "$1"; }
}

# The Python subscriber test needs the official iceoryx2 package, pinned to the
# same version as the Rust crate. Installed for python3 itself where pip may; a
# Debian/Ubuntu system Python refuses that (PEP 668: "externally-managed-environment"),
# and the package then goes into a virtual environment under target/, which the test
# runs (VLSYNC_PYTHON). Once this has installed it, the test must find it
# (VLSYNC_REQUIRE_PYTHON): a missing package fails the suite instead of skipping.
req=examples/python/requirements.txt
pip_log="$(mktemp)"
if python3 -m pip install --quiet --disable-pip-version-check -r "$req" 2>"$pip_log"; then
    :
elif grep -q externally-managed "$pip_log"; then
    venv=target/python-venv
    echo "python3 is externally managed: installing $req into $venv" >&2
    python3 -m venv "$venv" 2>/dev/null || { rm -rf "$venv"; install_deb python3-venv "the Python subscriber test will fail" && python3 -m venv "$venv"; }
    "$venv/bin/python3" -m pip install --quiet --disable-pip-version-check -r "$req"
    export VLSYNC_PYTHON="$PWD/$venv/bin/python3"
else
    cat "$pip_log" >&2
    exit 1
fi
rm -f "$pip_log"
export VLSYNC_REQUIRE_PYTHON=1
# The load test (tests/tests/load_short.rs) injects CPU load with stress-ng.
command -v stress-ng >/dev/null 2>&1 || install_deb stress-ng "the load test will fail"
# The V4L2 camera source (feature `v4l2`) generates its kernel bindings with libclang.
if ! dpkg -s libclang-dev >/dev/null 2>&1; then
    install_deb libclang-dev "the V4L2 source's tests will fail to build"
fi

# One build for everything, with the V4L2 source compiled in (its tests then check the
# errors for missing and non-video devices). `cargo test --workspace` builds every binary
# before running any test; the multi-process tests run those (VLSYNC_PREBUILT_BINS)
# instead of building the workspace a second time.
export VLSYNC_CARGO_FEATURES="vlsync-driver/v4l2"
export VLSYNC_PREBUILT_BINS=1
cargo test --workspace --features "$VLSYNC_CARGO_FEATURES"
