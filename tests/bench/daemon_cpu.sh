#!/bin/bash
# Whole-daemon CPU: sdid replaying a 320x240 recording at 60 fps into the
# y4m view (640x480 C444, one reader), per mode, against ffmpeg doing the
# same job on the same frames (Y16 in, scaled 640x480 out to a pipe), side by
# side in one run on the host. CPU is utime+stime from /proc/PID/stat over a
# window, as a share of one core; fps from sdid's own Stats.
#
#   bash tests/bench/daemon_cpu.sh [WINDOW_S]        (default 10 s per mode)
#
# Needs dbus-daemon, ffmpeg and Debian's python3 with numpy (tests/vm/setup-host.sh
# installs them). The v4l2loopback variant (YUYV view + Y16 data node) needs
# the module, i.e. the VM.
set -eEuo pipefail
trap 'rc=$?; echo "daemon_cpu.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
window_s=${1:-10}
cd "$(dirname "$0")/../.."

cargo build -q --release -p sdi-daemon -p sdi-cli
sdid=$PWD/target/release/sdid sdictl=$PWD/target/release/sdictl
tmp=$(mktemp -d)
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$tmp"
}
trap cleanup EXIT

# A private session bus: nothing of the user's desktop is touched.
eval "$(dbus-daemon --session --fork --print-address=1 --print-pid=1 |
    { read -r a; read -r p; echo "export DBUS_SESSION_BUS_ADDRESS='$a'; bus_pid=$p"; })"
pids+=("$bus_pid")
ctl() { "$sdictl" --session "$@"; }

ticks() { awk '{ print $14 + $15 }' "/proc/$1/stat"; }
hz=$(getconf CLK_TCK)

# Waits until the daemon answers on the bus.
wait_bus() {
    for _ in $(seq 100); do ctl status >/dev/null 2>&1 && return 0; sleep 0.1; done
    echo "daemon_cpu.sh: sdid did not come up" >&2; return 1
}

# CPU share of one core of PID over the window, printed as a percentage.
cpu_pct() {
    local pid=$1 t0 t1
    t0=$(ticks "$pid"); sleep "$window_s"; t1=$(ticks "$pid")
    awk -v d=$((t1 - t0)) -v hz="$hz" -v w="$window_s" 'BEGIN { printf "%.1f", 100 * d / hz / w }'
}

stats_fps() { ctl --json status | /usr/bin/python3 -c 'import json,sys; print("%.1f" % json.load(sys.stdin)["Stats"]["fps"])'; }

# 1. A 320x240 recording of the simulator at 60 fps (8 s).
mkfifo "$tmp/view.y4m"
"$sdid" --session --backend sim --frame-rate-hz 60 --sink y4m --y4m-path "$tmp/view.y4m" \
    --state-dir "$tmp/state" 2>"$tmp/rec.log" &
pids+=($!)
cat "$tmp/view.y4m" >/dev/null &
pids+=($!)
wait_bus
ctl record "$tmp/rec.sdirec" --seconds 8 >/dev/null
ctl stop >/dev/null 2>&1 || true
kill "${pids[-2]}"; wait "${pids[-2]}" 2>/dev/null || true
sleep 0.5

# 2. sdid replaying it in a loop, one reader on the view, per mode.
"$sdid" --session --replay "$tmp/rec.sdirec" --loop --sink y4m --y4m-path "$tmp/view.y4m" \
    --state-dir "$tmp/state" 2>"$tmp/replay.log" &
sdid_pid=$!
pids+=("$sdid_pid")
cat "$tmp/view.y4m" >/dev/null &
pids+=($!)
wait_bus
printf '%-22s %8s %8s\n' "sdid mode" "CPU %" "fps"
modes=$(ctl --json modes | /usr/bin/python3 -c 'import json,sys; print(" ".join(json.load(sys.stdin)["modes"]))')
for mode in $modes; do
    ctl set-mode "$mode" >/dev/null
    sleep 2 # past the switch and any warm-up
    pct=$(cpu_pct "$sdid_pid")
    printf '%-22s %8s %8s\n' "$mode" "$pct" "$(stats_fps)"
done
kill "$sdid_pid"

# 3. The peer: ffmpeg on the same frames, Y16 in at 60 fps, 640x480 out.
ctl export "$tmp/rec.sdirec" "$tmp/rec.npy" >/dev/null
/usr/bin/python3 - "$tmp/rec.npy" "$tmp/rec.y16" <<'EOF'
import sys, numpy as np
dn = np.load(sys.argv[1])
np.clip(np.rint(dn) + 32768, 0, 65535).astype("<u2").tofile(sys.argv[2])
EOF
ffmpeg -nostdin -loglevel error -re -stream_loop -1 -f rawvideo -pix_fmt gray16le \
    -video_size 320x240 -framerate 60 -i "$tmp/rec.y16" \
    -vf scale=640:480 -pix_fmt yuv444p -f yuv4mpegpipe - >"$tmp/view.y4m" &
ff_pid=$!
pids+=("$ff_pid")
cat "$tmp/view.y4m" >/dev/null &
pids+=($!)
sleep 2
printf '%-22s %8s\n' "ffmpeg (scale, y4m)" "$(cpu_pct "$ff_pid")"
