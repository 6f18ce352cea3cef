#!/usr/bin/env bash
# The main job from a fresh clone: builds every binary (the demo starts the daemon and
# both drivers as separate processes, so they must all exist), then runs the live demo
# on the simulated robot. Arguments go to vlsync-demo (see --help).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --bins
exec ./target/release/vlsync-demo "$@"
