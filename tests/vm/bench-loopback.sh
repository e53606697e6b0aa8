#!/bin/bash
# Write-path benchmark inside the VM: the glue (mmap and write()) vs
# `ffmpeg -f v4l2` writing the same raw 640x480 frames, YUYV and Y16.
# usage: tests/vm/bench-loopback.sh [FRAMES]   (from the workspace root)
set -euo pipefail
cd "$(dirname "$0")/../.."
FRAMES=${1:-300}
cargo build -q --release -p sdi-tests --bin loopback_tool
exec tests/vm/vmrun -t 900 -- bash -c "
  modprobe v4l2loopback devices=4 video_nr=40,41,42,43 card_label=bench-yuyv,bench-y16,ff-yuyv,ff-y16 exclusive_caps=1,1,1,1 max_buffers=4 &&
  target/release/loopback_tool bench /dev/video40 /dev/video42 $FRAMES"
