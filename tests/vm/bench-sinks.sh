#!/bin/bash
# CPU per frame of sdid's sinks side by side in one run inside the VM:
# v4l2loopback (read by GStreamer's v4l2src), PipeWire (pipewiresrc), y4m
# (cat), at 640x480 (tests/src/bin/sink_bench.rs).
# usage: tests/vm/bench-sinks.sh [FRAMES] [RATE_HZ]   (from the workspace root)
set -euo pipefail
cd "$(dirname "$0")/../.."
FRAMES=${1:-150}
RATE=${2:-10}
nice -n 10 cargo build -q --profile test -p sdi-tests --bin sink_bench
# WirePlumber 0.4 quits without logind's state directories (as in the VM).
exec flock -w 1800 /tmp/sdi-vm.lock tests/vm/vmrun -t 900 -- bash -c "
  mkdir -p /run/systemd/seats /run/systemd/sessions /run/systemd/users /run/systemd/machines &&
  modprobe v4l2loopback devices=1 video_nr=40 card_label=sdi-bench exclusive_caps=1 max_buffers=10 &&
  target/debug/sink_bench $FRAMES $RATE"
