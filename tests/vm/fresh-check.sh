#!/bin/bash
# Runs .ci/run as CI does on a new machine, without a new machine: a fresh
# clone of HEAD, run with every cache the harness keeps hidden.
#   - /var/lib/sdi-test (the built v4l2loopback 0.15) and the vmrun cache
#     (initramfs, uncompressed kernel) under empty tmpfs mounts, in a private
#     mount namespace (the VM's 9p root is served from that namespace too);
#   - a new CARGO_HOME (no crate cache); the build in the clone's own
#     target/, with CARGO_TARGET_DIR unset, as on CI (a relative path in
#     .ci/run once worked here and failed there);
#   - CI=true, no standard input.
# What it cannot hide: Debian packages already installed on this machine
# (setup-host.sh installs them when missing).
#
#   tests/vm/fresh-check.sh [RUNS]     (root; default 1 run; logs in $FRESH_LOGS or /var/tmp)
set -eEuo pipefail
trap 'rc=$?; echo "fresh-check.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
[ "$(id -u)" = 0 ] || { echo "fresh-check.sh: run as root (mount namespaces, apt)" >&2; exit 2; }
runs=${1:-1}
repo=$(git -C "$(dirname "$0")/../.." rev-parse --show-toplevel)
head=$(git -C "$repo" rev-parse HEAD)
logs=${FRESH_LOGS:-/var/tmp/sdi-fresh-check}
mkdir -p "$logs"
cache_dir=${XDG_CACHE_HOME:-$HOME/.cache}/vmrun
mkdir -p /var/lib/sdi-test "$cache_dir"
shared=$(cd "$repo/.." && pwd)/shared

status=0
for i in $(seq 1 "$runs"); do
    work=$(mktemp -d /var/tmp/sdi-fresh.XXXXXX)
    git clone -q "$repo" "$work/sdi"
    git -C "$work/sdi" checkout -q "$head"
    # CI has shared/ beside the clone.
    [ -d "$shared" ] && ln -s "$shared" "$work/shared"
    log=$logs/run-$i.log
    echo "== fresh check $i/$runs of $head in $work (log $log)"
    start=$(date +%s)
    rc=0
    unshare -m --propagation private env -i \
        PATH="$PATH" HOME="$HOME" USER="${USER:-root}" LANG=C.UTF-8 \
        RUSTUP_HOME="${RUSTUP_HOME:-$HOME/.rustup}" \
        CARGO_HOME="$work/cargo-home" \
        XDG_CACHE_HOME="$HOME/.cache" CI=true \
        bash -c 'set -e
            mount -t tmpfs sdi-test-empty /var/lib/sdi-test
            mount -t tmpfs vmrun-cache-empty "$1"
            # cargo and rustup binaries stay reachable; the registry does not
            mkdir -p "$CARGO_HOME"
            cd "$2" && exec bash .ci/run </dev/null' _ "$cache_dir" "$work/sdi" >"$log" 2>&1 || rc=$?
    secs=$(( $(date +%s) - start ))
    summary=$(grep -aE '^test result:' "$log" | awk '{p+=$4; f+=$6} END {print p+0 " passed, " f+0 " failed"}')
    echo "run $i: exit $rc after $((secs / 60)) min $((secs % 60)) s; $summary"
    [ "$rc" = 0 ] || { status=1; tail -30 "$log"; }
    rm -rf "$work"
done
exit $status
