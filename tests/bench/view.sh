#!/bin/bash
# sdictl view's benchmark: frames the page draws per second at 640x480 and
# 30 fps (the page's own counter) in headless Chromium, and the CPU share of
# sdictl view beside ffplay showing the same sdid's y4m stream (SDL's dummy
# video driver; no display needed), over a window; the CPU is named first.
# The work is tests/src/bin/view_bench.rs.
#
#   bash tests/bench/view.sh [WINDOW_S]        (default 10 s)
#
# Needs dbus-daemon, ffmpeg (ffplay) and chromium (tests/vm/setup-host.sh
# installs them).
set -eEuo pipefail
trap 'rc=$?; echo "view.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
cd "$(dirname "$0")/../.."
cargo build -q --release -p sdi-tests --bin test_sdid --bin test_sdictl --bin view_bench
echo "CPU: $(lscpu | sed -n 's/^Model name: *//p' | head -1), $(nproc) cores"
SDID=$PWD/target/release/test_sdid SDICTL=$PWD/target/release/test_sdictl \
    target/release/view_bench "${1:-10}"
