#!/usr/bin/env bash
# The main job from a fresh clone: builds every binary (the demo starts the daemon and
# both drivers as separate processes, so they must all exist), then runs the live demo
# on rendered frames and scans through the real front-ends (`--family F`: on the
# signature-level simulator instead). Arguments go to vlsync-demo (see --help).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --bins
exec ./target/release/vlsync-demo "$@"
