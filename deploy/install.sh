#!/usr/bin/env bash
# Installs vlsync as systemd services (see deploy/README.md):
#   user and group `vlsync`; vlsyncd, vlsync-cam, vlsync-lidar, vlsync-echo to
#   /usr/local/bin; /etc/vlsync/{vlsync.toml,cam.env,lidar.env} (existing ones are
#   kept, the new version goes next to them as *.new); the units to
#   /etc/systemd/system; /etc/tmpfiles.d/vlsync.conf, applied at once with
#   systemd-tmpfiles --create; deploy/README.md to /usr/local/share/doc/vlsync;
#   the C/C++ client library libvlsync_client.so to /usr/local/lib (then ldconfig),
#   its headers to /usr/local/include and its pkg-config file vlsync_client.pc to
#   /usr/local/lib/pkgconfig, when it was built (cargo build --release
#   builds it; --bins alone does not); then daemon-reload. It first checks the
#   configuration in place with the vlsyncd it installs (an error stops it before any
#   change). It does not enable or start anything; vlsync units already running are
#   restarted on the new binaries (try-restart).
#
#   sudo deploy/install.sh [--bin-dir DIR] [--dry-run]
#
#   --bin-dir DIR   where the built binaries are (default: target/release of this
#                   checkout; a cross build: target/aarch64-unknown-linux-gnu/release)
#   --dry-run       print every action instead of doing it (needs no root)
set -euo pipefail

orig_args=("$@")
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/.." && pwd)"
bin_dir="$repo/target/release"
dry_run=0
binaries=(vlsyncd vlsync-cam vlsync-lidar vlsync-echo)
units=(vlsyncd.service vlsync-cam.service vlsync-lidar.service vlsync.target)
prefix_bin=/usr/local/bin
etc_dir=/etc/vlsync
unit_dir=/etc/systemd/system
tmpfiles_dir=/etc/tmpfiles.d
doc_dir=/usr/local/share/doc/vlsync
lib_dir=/usr/local/lib
include_dir=/usr/local/include

# the comment block above, up to its first line that is not a comment
usage() { awk 'NR == 1 { next } !/^#/ { exit } { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; }
die() { echo "install.sh: error: $*" >&2; exit 1; }

while [ $# -gt 0 ]; do
    case "$1" in
        --dry-run) dry_run=1 ;;
        --bin-dir)
            [ $# -ge 2 ] || die "--bin-dir needs a directory"
            bin_dir="$2"
            shift
            ;;
        --bin-dir=*) bin_dir="${1#--bin-dir=}" ;;
        -h | --help) usage; exit 0 ;;
        *) die "unknown option \`$1\` (see --help)" ;;
    esac
    shift
done

if [ "$dry_run" -eq 0 ] && [ "$(id -u)" -ne 0 ]; then
    die "must run as root (it creates a system user and writes /usr/local/bin, /etc/vlsync and /etc/systemd/system): sudo $0 ${orig_args[*]}; or preview with --dry-run"
fi

# every input must exist before anything is changed
for b in "${binaries[@]}"; do
    [ -x "$bin_dir/$b" ] || die "binary $bin_dir/$b missing or not executable: build first (cargo build --release) or pass --bin-dir"
done
for f in "${units[@]}"; do
    [ -f "$here/systemd/$f" ] || die "unit $here/systemd/$f missing"
done
for f in vlsync.toml cam.env lidar.env tmpfiles.d/vlsync.conf README.md; do
    [ -f "$here/$f" ] || die "$here/$f missing"
done
# the C/C++ client library is optional: installed when it was built
capi_lib="$bin_dir/libvlsync_client.so"
# its headers: in the checkout, or copied next to the binaries (include/, a cross build)
capi_include="$repo/capi/include"
[ -d "$capi_include" ] || capi_include="$bin_dir/include"
capi_headers=("$capi_include/vlsync_client.h" "$capi_include/vlsync_client.hpp")
capi_pc="$capi_include/../vlsync_client.pc.in"
[ -f "$capi_pc" ] || capi_pc="$bin_dir/vlsync_client.pc.in"
if [ -f "$capi_lib" ]; then
    for h in "${capi_headers[@]}"; do
        [ -f "$h" ] || die "header $h missing (copy capi/include next to the library)"
    done
    [ -f "$capi_pc" ] || die "pkg-config template $capi_pc missing (copy capi/vlsync_client.pc.in next to the library)"
fi

# run a command, or print it in --dry-run mode
run() {
    if [ "$dry_run" -eq 1 ]; then
        echo "would run: $(printf '%q ' "$@")"
    else
        echo "+ $(printf '%q ' "$@")"
        "$@"
    fi
}

# installs a configuration file without overwriting the operator's version
install_config() {
    local src="$1" dst="$2"
    if [ -e "$dst" ]; then
        if cmp -s "$src" "$dst"; then
            echo "$dst is up to date"
        else
            echo "$dst exists and was edited: keeping it, the shipped version goes to $dst.new"
            run install -m 0644 "$src" "$dst.new"
        fi
    else
        run install -m 0644 "$src" "$dst"
    fi
}

[ "$dry_run" -eq 1 ] && echo "dry run: nothing is changed"

# the configuration in place (kept from an earlier install, or the shipped one), checked
# by the daemon about to be installed, before anything changes: a key it no longer takes
# would stop it at its next restart for good (exit 78), weeks later
in_place="$etc_dir/vlsync.toml"
[ -e "$in_place" ] || in_place="$here/vlsync.toml"
if ! "$bin_dir/vlsyncd" --version >/dev/null 2>&1; then
    echo "note: $bin_dir/vlsyncd does not run here (built for another machine?): $in_place is not checked; run \`vlsyncd check --config $etc_dir/vlsync.toml\` on the robot"
elif ! "$bin_dir/vlsyncd" check --config "$in_place"; then
    echo "error: $in_place does not pass this vlsyncd's check (above): fix it (compare the shipped deploy/vlsync.toml) and run this again; nothing was changed" >&2
    exit 1
fi


# user and group shared by the daemon, the drivers and every client
# (iceoryx2 creates its files mode 0600)
if getent group vlsync >/dev/null; then
    echo "group vlsync exists"
else
    run groupadd --system vlsync
fi
if id -u vlsync >/dev/null 2>&1; then
    echo "user vlsync exists"
    # logind's RemoveIPC=yes (its default) removes a regular user's /dev/shm files when
    # that user's last login session ends: every iceoryx2 segment of the running units
    if [ "$(id -u vlsync)" -ge 1000 ]; then
        echo "warning: user vlsync has uid $(id -u vlsync), a regular user's: logind removes its shared memory (iceoryx2's) whenever a login session of vlsync ends; make it a system user (uid below 1000) or set RemoveIPC=no in /etc/systemd/logind.conf" >&2
    fi
else
    run useradd --system --gid vlsync --home-dir /var/lib/vlsync --no-create-home \
        --shell /usr/sbin/nologin --comment "vlsync daemon and drivers" vlsync
fi

for b in "${binaries[@]}"; do
    run install -m 0755 "$bin_dir/$b" "$prefix_bin/$b"
done

run install -d -m 0755 "$etc_dir"
install_config "$here/vlsync.toml" "$etc_dir/vlsync.toml"
# an earlier install kept the saved estimate in /var/lib/vlsync (StateDirectory=); the
# unit no longer creates that directory, and a kept configuration may still name it
if [ -e "$etc_dir/vlsync.toml" ] && grep -Eq '^[[:space:]]*state_file[[:space:]]*=[[:space:]]*"/var/lib/vlsync/' "$etc_dir/vlsync.toml"; then
    echo "note: $etc_dir/vlsync.toml keeps daemon.state_file in /var/lib/vlsync: it works while that"
    echo "      directory exists; the shipped configuration uses /run/vlsync (see deploy/README.md)"
fi
install_config "$here/cam.env" "$etc_dir/cam.env"
install_config "$here/lidar.env" "$etc_dir/lidar.env"

for f in "${units[@]}"; do
    run install -m 0644 "$here/systemd/$f" "$unit_dir/$f"
done
run install -m 0644 "$here/tmpfiles.d/vlsync.conf" "$tmpfiles_dir/vlsync.conf"
run install -d -m 0755 "$doc_dir"
run install -m 0644 "$here/README.md" "$doc_dir/README.md"
if [ -f "$capi_lib" ]; then
    run install -d -m 0755 "$lib_dir" "$include_dir" "$lib_dir/pkgconfig"
    run install -m 0755 "$capi_lib" "$lib_dir/libvlsync_client.so"
    for h in "${capi_headers[@]}"; do
        run install -m 0644 "$h" "$include_dir/$(basename "$h")"
    done
    # the version of the binaries installed (`vlsyncd 0.1.0`), which a cross build's
    # bin dir has without the checkout's Cargo.toml; the checkout's as a fallback
    version="$("$bin_dir/vlsyncd" --version 2>/dev/null | sed -n 's/^vlsyncd \([0-9][^ ]*\)$/\1/p' | head -1 || true)"
    [ -n "$version" ] || version="$(sed -n 's/^version = "\(.*\)"/\1/p' "$repo/Cargo.toml" 2>/dev/null | head -1 || true)"
    pc="$lib_dir/pkgconfig/vlsync_client.pc"
    if [ "$dry_run" -eq 1 ]; then
        echo "would write: $pc (prefix /usr/local, version ${version:-0})"
    else
        echo "+ write $pc"
        sed -e "s|@PREFIX@|/usr/local|" -e "s|@VERSION@|${version:-0}|" "$capi_pc" >"$pc"
        chmod 0644 "$pc"
    fi
    run ldconfig
else
    echo "$capi_lib not built: the C/C++ client library is not installed (cargo build --release -p vlsync-capi, then run this again)"
fi

# /tmp/iceoryx2 created earlier by another user (e.g. a test run as root) would
# lock the vlsync user out of iceoryx2
if [ -d /tmp/iceoryx2 ] && [ "$(stat -c %U /tmp/iceoryx2)" != vlsync ]; then
    echo "warning: /tmp/iceoryx2 belongs to $(stat -c %U /tmp/iceoryx2), not vlsync; stop every iceoryx2 process and remove it (or reboot) before starting vlsync" >&2
fi
if [ -d /run/systemd/system ]; then
    run systemd-tmpfiles --create "$tmpfiles_dir/vlsync.conf"
    run systemctl daemon-reload
else
    echo "systemd is not running here: skipped systemd-tmpfiles and daemon-reload"
fi

# units already running keep the binaries they started with until they restart, and a
# running daemon and the new drivers may not speak the same wire (a flag it does not
# know is a malformed sample to it): the running ones are restarted
if [ -d /run/systemd/system ] && systemctl is-active --quiet vlsyncd.service vlsync-cam.service vlsync-lidar.service 2>/dev/null; then
    echo "restarting the running vlsync units on the new binaries"
    run systemctl try-restart vlsyncd.service vlsync-cam.service vlsync-lidar.service
fi
cat <<EOF
done. Next:
  check that CPUAffinity= in $unit_dir/vlsyncd.service includes the core in $etc_dir/vlsync.toml (daemon.core);
    change it in a drop-in (sudo systemctl edit vlsyncd.service), which a later install leaves alone
  sudo systemctl enable --now vlsync.target
  systemctl status vlsyncd            # READY, state, offset ± std in the status line
  journalctl -u vlsyncd -f
  sudo -u vlsync vlsync-echo --prefix vlsync/robot
EOF
