#!/bin/bash
# Latency per mode in the QEMU VM on v4l2loopback: sdid replays a 320x240
# recording of the simulator at 60 fps and publishes the 640x480 YUYV view
# and the Y16 data node; a V4L2 reader on each node (loopback_tool latency,
# mmap, 4 buffers) takes CLOCK_MONOTONIC at each DQBUF minus the buffer's
# timestamp (sdid's capture time): median and 99th percentile per mode. Next
# to it sdid's own latency: capture timestamp to the end of the sink's write
# (its `sdid::output::age` trace lines: capture, processing, queue, rendering,
# QBUF), median and p99, and the frame loop's processing from its Stats
# (mean and worst of the last window). Figures in the VM are from the
# emulated (TCG) guest; with SDI_LATENCY_HOST=1 the same runs natively on the
# host through the y4m sink (no V4L2 reader: sdid's own latency only).
#
#   bash tests/bench/latency_vm.sh [WINDOW_S]      (default 8 s per mode)
#   SDI_LATENCY_HOST=1 bash tests/bench/latency_vm.sh [WINDOW_S]
#
# Needs what the VM tests need (bash tests/vm/setup-host.sh).
set -eEuo pipefail
trap 'rc=$?; echo "latency_vm.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
window_s=${1:-8}
cd "$(dirname "$0")/../.."

host=${SDI_LATENCY_HOST:-}
if [ -n "$host" ]; then
    cargo build -q --release -p sdi-daemon -p sdi-cli
elif [ -z "${SDI_LATENCY_IN_VM:-}" ]; then
    # Two builds: `--bin` selects from every `-p` package, so one build
    # with all three made loopback_tool alone, and no sdid.
    cargo build -q --release -p sdi-daemon -p sdi-cli
    cargo build -q --release -p sdi-tests --bin loopback_tool
    # One VM at a time, as the VM tests do.
    exec flock "${TMPDIR:-/tmp}/sdi-vm.lock" tests/vm/vmrun -t 1800 -m 2048 -- bash -c "
      modprobe v4l2loopback devices=2 video_nr=50,51 \
        card_label='SDI camera,SDI data' exclusive_caps=1,1 max_buffers=4 &&
      SDI_LATENCY_IN_VM=1 bash tests/bench/latency_vm.sh $window_s"
fi

. tests/bench/replay_common.sh
# 1. A 320x240 recording of the simulator at 60 fps (8 s).
record_sim

# 2. sdid replaying it in a loop (both loopback nodes, or the y4m view on
#    the host), logging each frame's capture-to-write time.
age_filter="warn,sdid::output::age=trace"
if [ -n "$host" ]; then
    RUST_LOG=$age_filter "$sdid" --session --replay "$tmp/rec.sdirec" --loop --sink y4m \
        --y4m-path "$tmp/view.y4m" --state-dir "$tmp/state" 2>"$tmp/replay.log" &
    sdid_pid=$!
    cat "$tmp/view.y4m" >/dev/null &
    pids+=("$sdid_pid" $!)
else
    printf '[output]\nlabel = "SDI camera"\ndata_label = "SDI data"\n' >"$tmp/sdid.toml"
    RUST_LOG=$age_filter "$sdid" --session --config "$tmp/sdid.toml" --replay "$tmp/rec.sdirec" \
        --loop --sink loopback --state-dir "$tmp/state" 2>"$tmp/replay.log" &
    sdid_pid=$!
    pids+=("$sdid_pid")
fi
wait_bus "$tmp/replay.log"

# "median/p99 us (frames)" from a loopback_tool latency line.
lat() { sed -E 's/.*: ([0-9]+) frames, median (-?[0-9]+) us, p99 (-?[0-9]+) us.*/\2\/\3 (\1)/' "$1"; }
# "median/p99" of MODE's capture_to_write_us in the log lines after line $2.
ages() {
    tail -n +"$(($2 + 1))" "$tmp/replay.log" | /usr/bin/python3 -c '
import re, sys
mode = sys.argv[1]
a = sorted(int(m.group(2)) for m in
           (re.search(r"mode=(\S+) capture_to_write_us=(\d+)", l) for l in sys.stdin)
           if m and m.group(1) == mode)
q = lambda p: a[(len(a) - 1) * p // 100] if a else -1
print("%d/%d (%d)" % (q(50), q(99), len(a)))' "$1"
}
printf '%-20s %6s  %-22s %-22s %-22s %s\n' "mode" "fps" "view DQBUF med/p99 us" \
    "data DQBUF med/p99 us" "sdid capture-to-write" "loop processing mean/max us"
modes=$(ctl --json modes | /usr/bin/python3 -c 'import json,sys; print(" ".join(json.load(sys.stdin)["modes"]))')
for mode in $modes; do
    ctl set-mode "$mode" >/dev/null
    sleep 1 # past the switch
    from=$(wc -l <"$tmp/replay.log")
    if [ -n "$host" ]; then
        sleep "$window_s"
        view="-" data="-"
    else
        "$tool" latency "$view_dev" "$window_s" >"$tmp/lat-view" &
        view_reader=$!
        "$tool" latency "$data_dev" "$window_s" >"$tmp/lat-data" &
        data_reader=$!
        pids+=("$view_reader" "$data_reader")
        wait "$view_reader" "$data_reader"
        view=$(lat "$tmp/lat-view") data=$(lat "$tmp/lat-data")
    fi
    stats=$(ctl --json status | /usr/bin/python3 -c '
import json, sys
s = json.load(sys.stdin)["Stats"]
print("%.1f %.0f/%.0f" % (s.get("fps", 0), s.get("latency_us", -1), s.get("latency_max_us", -1)))')
    printf '%-20s %6s  %-22s %-22s %-22s %s\n' "$mode" "${stats%% *}" "$view" "$data" \
        "$(ages "$mode" "$from")" "${stats#* }"
done
