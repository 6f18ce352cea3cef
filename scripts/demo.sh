#!/usr/bin/env bash
# The main job from a fresh clone: builds every binary (the demo starts the daemon and
# both drivers as separate processes, so they must all exist), then runs the live demo
# on rendered frames and scans through the real front-ends (`--family F`: on the
# signature-level simulator instead). Arguments go to vlsync-demo (see --help); paths in
# them (`--plot`, `--record`, `--config`, `--log-dir`) are relative to where it is run.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
# rustc links with the system C compiler: without one nothing builds
command -v cc >/dev/null 2>&1 || {
    echo "demo.sh: no C compiler (cc), which rustc needs to link: install build-essential (or gcc)" >&2
    exit 1
}
cargo build --release --bins --manifest-path "$root/Cargo.toml"
exec "$root/target/release/vlsync-demo" "$@"
