#!/bin/bash
# Whole-daemon CPU: sdid replaying a 320x240 recording at 60 fps into the
# y4m view (C444 at the sensor's 320x240: the y4m sink does not scale; one
# reader), per mode, against ffmpeg on the same frames (Y16 in, scaled to
# 640x480 C444 out to a pipe, so ffmpeg writes 4x the pixels sdid does),
# side by side in one run on the host. Both sides at 640x480: the loopback
# variant in the VM (daemon_cpu_vm.sh). On the host ffmpeg runs through
# every mode's window, so both programs are measured over the same seconds
# under the same load (in the emulated guest, which cannot hold both, it
# runs after sdid); CPU is the scheduler's nanoseconds of every thread
# (/proc/PID/task/*/schedstat: clock ticks counted too few, about 17 of
# sdid's per 10 s), as a share of one core; fps from sdid's own Stats. The
# ratio column is sdid over ffmpeg, the median over the mode's windows. On
# the host a second ffmpeg writes the y4m at sdid's own 320x240 (no
# scaling): the like-for-like ratio.
#
#   bash tests/bench/daemon_cpu.sh [WINDOW_S [REPEATS]]
#                           (default 10 s per window, 3 windows per mode)
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
repeats=${2:-3}
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

# One window: sdid's and the peer's CPU share of one core (%) over the
# same $window_s seconds, printed as "SDID PEER".
window_pcts() {
    local s0 p0 q0 s1 p1 q1 t0 t1
    t0=$(date +%s%N); s0=$(cpu_ns "$sdid_pid"); p0=$(cpu_ns "$ff_pid"); q0=$(cpu_ns "$same_pid")
    sleep "$window_s"
    t1=$(date +%s%N); s1=$(cpu_ns "$sdid_pid"); p1=$(cpu_ns "$ff_pid"); q1=$(cpu_ns "$same_pid")
    awk -v s=$((s1 - s0)) -v p=$((p1 - p0)) -v q=$((q1 - q0)) -v w=$((t1 - t0)) \
        'BEGIN { printf "%.2f %.2f %.2f\n", 100 * s / w, 100 * p / w, 100 * q / w }'
}

# 1. A 320x240 recording of the simulator at 60 fps (8 s), and the same
#    frames as Y16 for the peer.
record_sim_y16

# 2. The peer: ffmpeg on the same frames, Y16 in at 60 fps, 640x480 out.
#    On the host it runs through every window below. The emulated guest
#    cannot hold both at 60 fps (each took about 90 % of a vCPU), so there
#    the peer runs after sdid, alone, for as many windows.
start_loopback_peer() {
    ffmpeg -nostdin -loglevel error -re -stream_loop -1 -f rawvideo -pix_fmt gray16le \
        -video_size 320x240 -framerate 60 -i "$tmp/rec.y16" \
        -vf scale=640:480 -pix_fmt yuyv422 -f v4l2 "$peer_dev" &
    ff_pid=$!
    pids+=("$ff_pid")
    # A reader, like sdid's nodes have; retried until ffmpeg has set the
    # node's format (REQBUFS fails with EINVAL before that, which took more
    # than 2 s in the emulated guest). It reads until the end.
    for _ in $(seq 40); do
        sleep 0.5
        "$tool" latency "$peer_dev" 100000 >"$tmp/lat-peer" 2>&1 &
        reader=$!
        sleep 0.5
        kill -0 "$reader" 2>/dev/null && break
    done
    pids+=("$reader")
}
ff_pid= same_pid=
if [ "$sink" = loopback ]; then
    peer_label="ffmpeg v4l2 %"
else
    ffmpeg -nostdin -loglevel error -re -stream_loop -1 -f rawvideo -pix_fmt gray16le \
        -video_size 320x240 -framerate 60 -i "$tmp/rec.y16" \
        -vf scale=640:480 -pix_fmt yuv444p -f yuv4mpegpipe - >"$tmp/peer.y4m" &
    ff_pid=$!
    pids+=("$ff_pid")
    peer_label="ffmpeg y4m %"
    # A second peer at sdid's own y4m size (no scaling, the same pixels
    # sdid writes): the like-for-like reference.
    ffmpeg -nostdin -loglevel error -re -stream_loop -1 -f rawvideo -pix_fmt gray16le \
        -video_size 320x240 -framerate 60 -i "$tmp/rec.y16" \
        -pix_fmt yuv444p -f yuv4mpegpipe - >"$tmp/peer-same.y4m" &
    same_pid=$!
    pids+=("$same_pid")
fi

# 3. sdid replaying the recording in a loop beside the peer, one reader per
#    published node, per mode.
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
    cat "$tmp/peer.y4m" >/dev/null &
    pids+=($!)
    cat "$tmp/peer-same.y4m" >/dev/null &
    pids+=($!)
fi
wait_bus "$tmp/replay.log"
if [ "$sink" = loopback ]; then
    printf '%-22s %8s %6s   %s\n' "sdid mode" "sdid %" "fps" "capture to dequeue (view; data)"
else
    printf '%-22s %8s %6s %14s %6s %16s %6s\n' "sdid mode" "sdid %" "fps" "$peer_label" "ratio" \
        "ffmpeg 320x240 %" "ratio"
fi
declare -A sdid_pcts
modes=$(ctl --json modes | /usr/bin/python3 -c 'import json,sys; print(" ".join(json.load(sys.stdin)["modes"]))')
for mode in $modes; do
    ctl set-mode "$mode" >/dev/null
    if [ "$sink" = loopback ]; then
        # Both readers run through the warm-up and every window.
        "$tool" latency "$view_dev" $((window_s * repeats + 2)) >"$tmp/lat-view" &
        view_reader=$!
        "$tool" latency "$data_dev" $((window_s * repeats + 2)) >"$tmp/lat-data" &
        data_reader=$!
        pids+=("$view_reader" "$data_reader")
    fi
    sleep 2 # past the switch and any warm-up
    : >"$tmp/windows"
    for _ in $(seq "$repeats"); do window_pcts >>"$tmp/windows"; done
    s_pct=$(awk '{ print $1 }' "$tmp/windows" | median)
    p_pct=$(awk '{ print $2 }' "$tmp/windows" | median)
    ratio=$(awk '$2 > 0 { print $1 / $2 }' "$tmp/windows" | median)
    sdid_pcts[$mode]=$s_pct
    if [ "$sink" != loopback ]; then
        printf '%-22s %8s %6s %14s %6s %16s %6s' "$mode" "$s_pct" "$(stats_fps)" "$p_pct" "$ratio" \
            "$(awk '{ print $3 }' "$tmp/windows" | median)" \
            "$(awk '$3 > 0 { print $1 / $3 }' "$tmp/windows" | median)"
    else
        printf '%-22s %8s %6s' "$mode" "$s_pct" "$(stats_fps)"
        wait "$view_reader" "$data_reader"
        lat=$(sed -E 's/.*: ([0-9]+) frames, median ([0-9]+) us, p99 ([0-9]+) us.*/\2\/\3 us (\1 frames)/' "$tmp/lat-view")
        lat_data=$(sed -E 's/.*: ([0-9]+) frames, median ([0-9]+) us, p99 ([0-9]+) us.*/\2\/\3 us/' "$tmp/lat-data")
        printf '   median/p99 %s; %s' "$lat" "$lat_data"
    fi
    printf '\n'
done

# 4. In the guest: the peer alone, then each mode's ratio to it.
if [ "$sink" = loopback ]; then
    kill "$sdid_pid"
    wait "$sdid_pid" 2>/dev/null || true
    sdid_pid=
    start_loopback_peer
    sleep 2
    : >"$tmp/windows"
    for _ in $(seq "$repeats"); do window_pcts >>"$tmp/windows"; done
    p_pct=$(awk '{ print $2 }' "$tmp/windows" | median)
    printf '%-22s %8s\n' "$peer_label" "$p_pct"
    for mode in $modes; do
        printf '%-22s %8s\n' "ratio $mode" "$(awk -v s="${sdid_pcts[$mode]}" -v p="$p_pct" 'BEGIN { printf "%.2f", s / p }')"
    done
fi
