#!/usr/bin/env bash
# The whole test suite, from a fresh clone: installs what the tests need, then runs them.
# Used verbatim by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."
# The Python subscriber test needs the official iceoryx2 package, pinned to the
# same version as the Rust crate.
if [ -f examples/python/requirements.txt ]; then
    python3 -m pip install --quiet --disable-pip-version-check -r examples/python/requirements.txt
fi
# The load test (tests/tests/load_short.rs) injects CPU load with stress-ng.
if ! command -v stress-ng >/dev/null 2>&1; then
    if [ "$(id -u)" -eq 0 ]; then SUDO=""; elif command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else SUDO="none"; fi
    if [ "$SUDO" = "none" ]; then
        echo "stress-ng is missing and cannot be installed (not root, no sudo): the load test will fail" >&2
    else
        $SUDO apt-get install -y stress-ng || { $SUDO apt-get update && $SUDO apt-get install -y stress-ng; }
    fi
fi
cargo test --workspace
