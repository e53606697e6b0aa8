#!/bin/bash
# Whole-daemon CPU into a 640x480 view, natively on the host: sdid replaying
# a 320x240 recording at 60 fps with `--sink pipewire` (the view is YUYV
# 640x480, read by `pipewiresrc` into fakesink), per mode, against ffmpeg
# on the same frames (Y16 in, scaled to 640x480 YUYV, raw to a pipe),
# running through the same windows. The y4m bench (daemon_cpu.sh) publishes
# only 320x240, and the loopback one needs the emulated guest; this is the
# 640x480 figure on real cores. sdid's CPU and the camera process's
# (sdi-pipewire-camera, which copies each frame into PipeWire's buffers)
# are given apart and summed. CPU is the scheduler's nanoseconds of every
# thread (/proc/PID/task/*/schedstat) over a window, as a share of one
# core; ratios are medians over the mode's windows.
#
#   bash tests/bench/daemon_cpu_pipewire.sh [WINDOW_S [REPEATS]]
#                           (default 10 s per window, 3 windows per mode)
#
# Needs dbus-daemon, ffmpeg, pipewire, wireplumber, gstreamer1.0-pipewire,
# gstreamer1.0-tools and Debian's python3 with numpy (tests/vm/setup-host.sh
# installs them).
set -eEuo pipefail
trap 'rc=$?; echo "daemon_cpu_pipewire.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
window_s=${1:-10}
repeats=${2:-3}
cd "$(dirname "$0")/../.."
if [ -z "${SDI_BENCH_PREBUILT:-}" ]; then
    # Separate builds: `--bin` selects from every `-p` package.
    cargo build -q --release -p sdi-daemon -p sdi-cli
    cargo build -q --release -p sdi-pipewire-camera
fi
. tests/bench/replay_common.sh
camera_prog=$PWD/target/release/sdi-pipewire-camera
[ -x "$camera_prog" ] || { echo "no $camera_prog (cargo build --release -p sdi-pipewire-camera)" >&2; exit 1; }
echo "CPU: $(lscpu | sed -n 's/^Model name: *//p') ($(nproc) cores); $(pipewire --version | tail -1)"

# 1. The recording, and its frames as Y16 for the peer.
record_sim_y16

# 2. The private PipeWire session.
. tests/bench/pipewire_session.sh

# 3. The peer, through every window.
mkfifo "$tmp/peer.yuyv"
ffmpeg -nostdin -loglevel error -re -stream_loop -1 -f rawvideo -pix_fmt gray16le \
    -video_size 320x240 -framerate 60 -i "$tmp/rec.y16" \
    -vf scale=640:480 -pix_fmt yuyv422 -f rawvideo - >"$tmp/peer.yuyv" &
ff_pid=$!
pids+=("$ff_pid")
cat "$tmp/peer.yuyv" >/dev/null &
pids+=($!)

# 4. sdid on the PipeWire camera, its view read by pipewiresrc.
"$sdid" --session --replay "$tmp/rec.sdirec" --loop --sink pipewire \
    --state-dir "$tmp/state" 2>"$tmp/replay.log" &
sdid_pid=$!
pids+=("$sdid_pid")
wait_bus "$tmp/replay.log"
for _ in $(seq 300); do node_up sdi-camera && break; sleep 0.2; done
node_up sdi-camera || { echo "PipeWire lists no sdi-camera; sdid's log:" >&2; tail -20 "$tmp/replay.log" >&2; exit 1; }
cam_pid=$(pgrep -n -f "^$camera_prog( |\$)" || true)
[ -n "$cam_pid" ] || { echo "no camera process found" >&2; exit 1; }
gst-launch-1.0 -q pipewiresrc target-object=sdi-camera \
    ! video/x-raw,format=YUY2,width=640,height=480 ! fakesink sync=false >"$tmp/reader.log" 2>&1 &
pids+=($!)

printf '%-22s %7s %6s %8s %9s %9s %6s %8s\n' "sdid mode" "sdid %" "fps" "camera %" \
    "sum %" "ffmpeg %" "ratio" "sum/ff"
modes=$(ctl --json modes | /usr/bin/python3 -c 'import json,sys; print(" ".join(json.load(sys.stdin)["modes"]))')
for mode in $modes; do
    ctl set-mode "$mode" >/dev/null
    sleep 2 # past the switch and any warm-up
    : >"$tmp/windows"
    for _ in $(seq "$repeats"); do
        t0=$(date +%s%N); s0=$(cpu_ns "$sdid_pid"); c0=$(cpu_ns "$cam_pid"); p0=$(cpu_ns "$ff_pid")
        sleep "$window_s"
        t1=$(date +%s%N); s1=$(cpu_ns "$sdid_pid"); c1=$(cpu_ns "$cam_pid"); p1=$(cpu_ns "$ff_pid")
        awk -v s=$((s1 - s0)) -v c=$((c1 - c0)) -v p=$((p1 - p0)) -v w=$((t1 - t0)) \
            'BEGIN { printf "%.2f %.2f %.2f %.2f\n", 100 * s / w, 100 * c / w, 100 * p / w, 100 * (s + c) / w }' \
            >>"$tmp/windows"
    done
    col() { awk -v c="$1" '{ print $c }' "$tmp/windows" | median; }
    printf '%-22s %7s %6s %8s %9s %9s %6s %8s\n' "$mode" "$(col 1)" "$(stats_fps)" "$(col 2)" \
        "$(col 4)" "$(col 3)" \
        "$(awk '$3 > 0 { print $1 / $3 }' "$tmp/windows" | median)" \
        "$(awk '$3 > 0 { print $4 / $3 }' "$tmp/windows" | median)"
done
