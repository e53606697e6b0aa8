# Sourced by the replay benches (daemon_cpu.sh, daemon_cpu_pipewire.sh,
# latency_vm.sh, sink_auto_vm.sh), from the
# repository root: the release binaries, a scratch directory, a private
# session bus (nothing of the user's desktop is touched), cleanup on exit,
# the 320x240 simulator recording at 60 fps they replay, and the CPU
# helpers of the daemon_cpu benches.

sdid=$PWD/target/release/sdid sdictl=$PWD/target/release/sdictl
tool=$PWD/target/release/loopback_tool
view_dev=/dev/video50 data_dev=/dev/video51
tmp=$(mktemp -d)
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$tmp"
}
trap cleanup EXIT

eval "$(dbus-daemon --session --fork --print-address=1 --print-pid=1 |
    { read -r a; read -r p; echo "export DBUS_SESSION_BUS_ADDRESS='$a'; bus_pid=$p"; })"
pids+=("$bus_pid")
ctl() { "$sdictl" --session "$@"; }

# Waits until the daemon answers on the bus; if it does not, says why from
# its log ($1).
wait_bus() {
    for _ in $(seq 300); do ctl status >/dev/null 2>&1 && return 0; sleep 0.1; done
    echo "$(basename "$0"): sdid did not come up in 30 s; the end of its log ($1):" >&2
    tail -20 "$1" >&2 || true
    return 1
}

# Records 8 s of the simulator (320x240, 60 fps) to $tmp/rec.sdirec; leaves
# the FIFO $tmp/view.y4m for a y4m replay.
record_sim() {
    mkfifo "$tmp/view.y4m"
    "$sdid" --session --backend sim --frame-rate-hz 60 --sink y4m --y4m-path "$tmp/view.y4m" \
        --state-dir "$tmp/state" 2>"$tmp/rec.log" &
    pids+=($!)
    cat "$tmp/view.y4m" >/dev/null &
    pids+=($!)
    wait_bus "$tmp/rec.log"
    ctl record "$tmp/rec.sdirec" --seconds 8 >/dev/null
    ctl stop >/dev/null 2>&1 || true
    kill "${pids[-2]}"; wait "${pids[-2]}" 2>/dev/null || true
    sleep 0.5
}

# Nanoseconds on a CPU of every thread of PID so far (0 for no PID): the
# scheduler's count, where /proc/PID/stat's clock ticks count too few.
cpu_ns() {
    if [ -z "$1" ]; then echo 0; return; fi
    cat /proc/"$1"/task/*/schedstat | awk '{ t += $1 } END { printf "%.0f", t }'
}

# The median of the numbers on standard input.
median() {
    sort -g | awk '{ v[NR] = $1 } END { m = int((NR + 1) / 2); printf "%.2f", (NR % 2) ? v[m] : (v[m] + v[m + 1]) / 2 }'
}

stats_fps() { ctl --json status | /usr/bin/python3 -c 'import json,sys; print("%.1f" % json.load(sys.stdin)["Stats"]["fps"])'; }

# record_sim, then its frames as Y16 in $tmp/rec.y16 for an ffmpeg peer.
record_sim_y16() {
    record_sim
    ctl export "$tmp/rec.sdirec" "$tmp/rec.npy" >/dev/null
    /usr/bin/python3 - "$tmp/rec.npy" "$tmp/rec.y16" <<'PY'
import sys, numpy as np
dn = np.load(sys.argv[1])
np.clip(np.rint(dn) + 32768, 0, 65535).astype("<u2").tofile(sys.argv[2])
PY
}
