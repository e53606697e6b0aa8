#!/bin/bash
# Whole-daemon CPU: sdid replaying a 320x240 recording at 60 fps into the
# y4m view (C444 at the sensor's 320x240: the y4m sink does not scale; one
# reader), per mode, against ffmpeg on the same frames (Y16 in, scaled to
# 640x480 C444 out to a pipe, so ffmpeg writes 4x the pixels sdid does),
# side by side in one run on the host. Both sides at 640x480: the loopback
# variant in the VM (daemon_cpu_vm.sh). CPU is utime+stime from /proc/PID/stat over a
# window, as a share of one core; fps from sdid's own Stats.
#
#   bash tests/bench/daemon_cpu.sh [WINDOW_S]        (default 10 s per mode)
#
# Needs dbus-daemon, ffmpeg and Debian's python3 with numpy (tests/vm/setup-host.sh
# installs them). With SDI_BENCH_SINK=loopback (inside the VM: see
# daemon_cpu_vm.sh) sdid publishes the 640x480 YUYV view and the Y16 data
# node on v4l2loopback, each read by a V4L2 client that also measures the
# latency from capture timestamp to dequeue, and ffmpeg writes its scaled
# YUYV to a third loopback node.
set -eEuo pipefail
trap 'rc=$?; echo "daemon_cpu.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
window_s=${1:-10}
cd "$(dirname "$0")/../.."

sink=${SDI_BENCH_SINK:-y4m}
# Inside the VM the target directory is read-only: the wrapper builds first.
if [ -z "${SDI_BENCH_PREBUILT:-}" ]; then
    # Two builds: `--bin` selects from every `-p` package, so one build
    # with all three made loopback_tool alone, and no sdid.
    cargo build -q --release -p sdi-daemon -p sdi-cli
    cargo build -q --release -p sdi-tests --bin loopback_tool
fi
. tests/bench/replay_common.sh
peer_dev=/dev/video52

ticks() { awk '{ print $14 + $15 }' "/proc/$1/stat"; }
hz=$(getconf CLK_TCK)

# CPU share of one core of PID over the window, printed as a percentage.
cpu_pct() {
    local pid=$1 t0 t1
    t0=$(ticks "$pid"); sleep "$window_s"; t1=$(ticks "$pid")
    awk -v d=$((t1 - t0)) -v hz="$hz" -v w="$window_s" 'BEGIN { printf "%.1f", 100 * d / hz / w }'
}

stats_fps() { ctl --json status | /usr/bin/python3 -c 'import json,sys; print("%.1f" % json.load(sys.stdin)["Stats"]["fps"])'; }

# 1. A 320x240 recording of the simulator at 60 fps (8 s).
record_sim

# 2. sdid replaying it in a loop, one reader per published node, per mode.
if [ "$sink" = loopback ]; then
    printf '[output]\nlabel = "SDI camera"\ndata_label = "SDI data"\n' >"$tmp/sdid.toml"
    "$sdid" --session --config "$tmp/sdid.toml" --replay "$tmp/rec.sdirec" --loop \
        --sink loopback --state-dir "$tmp/state" 2>"$tmp/replay.log" &
else
    "$sdid" --session --replay "$tmp/rec.sdirec" --loop --sink y4m --y4m-path "$tmp/view.y4m" \
        --state-dir "$tmp/state" 2>"$tmp/replay.log" &
fi
sdid_pid=$!
pids+=("$sdid_pid")
if [ "$sink" != loopback ]; then
    cat "$tmp/view.y4m" >/dev/null &
    pids+=($!)
fi
wait_bus "$tmp/replay.log"
if [ "$sink" = loopback ]; then
    printf '%-22s %8s %8s   %s\n' "sdid mode" "CPU %" "fps" "capture to dequeue (view; data)"
else
    printf '%-22s %8s %8s\n' "sdid mode" "CPU %" "fps"
fi
modes=$(ctl --json modes | /usr/bin/python3 -c 'import json,sys; print(" ".join(json.load(sys.stdin)["modes"]))')
for mode in $modes; do
    ctl set-mode "$mode" >/dev/null
    if [ "$sink" = loopback ]; then
        # Both readers run through the warm-up and the whole window.
        "$tool" latency "$view_dev" $((window_s + 2)) >"$tmp/lat-view" &
        view_reader=$!
        "$tool" latency "$data_dev" $((window_s + 2)) >"$tmp/lat-data" &
        data_reader=$!
        pids+=("$view_reader" "$data_reader")
    fi
    sleep 2 # past the switch and any warm-up
    pct=$(cpu_pct "$sdid_pid")
    if [ "$sink" = loopback ]; then
        wait "$view_reader" "$data_reader"
        lat=$(sed -E 's/.*: ([0-9]+) frames, median ([0-9]+) us, p99 ([0-9]+) us.*/\2\/\3 us (\1 frames)/' "$tmp/lat-view")
        lat_data=$(sed -E 's/.*: ([0-9]+) frames, median ([0-9]+) us, p99 ([0-9]+) us.*/\2\/\3 us/' "$tmp/lat-data")
        printf '%-22s %8s %8s   median/p99 %s; %s\n' "$mode" "$pct" "$(stats_fps)" "$lat" "$lat_data"
    else
        printf '%-22s %8s %8s\n' "$mode" "$pct" "$(stats_fps)"
    fi
done
kill "$sdid_pid"

# 3. The peer: ffmpeg on the same frames, Y16 in at 60 fps, 640x480 out.
ctl export "$tmp/rec.sdirec" "$tmp/rec.npy" >/dev/null
/usr/bin/python3 - "$tmp/rec.npy" "$tmp/rec.y16" <<'EOF'
import sys, numpy as np
dn = np.load(sys.argv[1])
np.clip(np.rint(dn) + 32768, 0, 65535).astype("<u2").tofile(sys.argv[2])
EOF
if [ "$sink" = loopback ]; then
    ffmpeg -nostdin -loglevel error -re -stream_loop -1 -f rawvideo -pix_fmt gray16le \
        -video_size 320x240 -framerate 60 -i "$tmp/rec.y16" \
        -vf scale=640:480 -pix_fmt yuyv422 -f v4l2 "$peer_dev" &
    ff_pid=$!
    pids+=("$ff_pid")
    # A reader, like sdid's nodes have; retried until ffmpeg has set the
    # node's format (REQBUFS fails with EINVAL before that, which took more
    # than 2 s in the emulated guest).
    for _ in $(seq 40); do
        sleep 0.5
        "$tool" latency "$peer_dev" $((window_s + 1)) >"$tmp/lat-peer" 2>&1 &
        reader=$!
        sleep 0.5
        kill -0 "$reader" 2>/dev/null && break
    done
    pids+=("$reader")
    printf '%-22s %8s\n' "ffmpeg (scale, v4l2)" "$(cpu_pct "$ff_pid")"
else
    ffmpeg -nostdin -loglevel error -re -stream_loop -1 -f rawvideo -pix_fmt gray16le \
        -video_size 320x240 -framerate 60 -i "$tmp/rec.y16" \
        -vf scale=640:480 -pix_fmt yuv444p -f yuv4mpegpipe - >"$tmp/view.y4m" &
    ff_pid=$!
    pids+=("$ff_pid")
    cat "$tmp/view.y4m" >/dev/null &
    pids+=($!)
    sleep 2
    printf '%-22s %8s\n' "ffmpeg (scale, y4m)" "$(cpu_pct "$ff_pid")"
fi
