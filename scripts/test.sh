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
# same version as the Rust crate.
if [ -f examples/python/requirements.txt ]; then
    python3 -m pip install --quiet --disable-pip-version-check -r examples/python/requirements.txt
fi
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
