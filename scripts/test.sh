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
cargo test --workspace
