#!/bin/bash
# daemon_cpu.sh inside the QEMU VM on v4l2loopback: sdid's 640x480 YUYV view
# and Y16 data node, each with a V4L2 reader that reports the latency from
# capture timestamp to dequeue per mode, against ffmpeg writing the same
# frames scaled to YUYV into a loopback node. Figures are CPU of the
# emulated (TCG) guest: compare the ratios, not the absolute values.
#
#   bash tests/bench/daemon_cpu_vm.sh [WINDOW_S]      (default 10 s per mode)
#
# Needs what the VM tests need (bash tests/vm/setup-host.sh).
set -eEuo pipefail
trap 'rc=$?; echo "daemon_cpu_vm.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
window_s=${1:-10}
cd "$(dirname "$0")/../.."
# Two builds: `--bin` selects from every `-p` package, so one build
# with all three made loopback_tool alone, and no sdid.
cargo build -q --release -p sdi-daemon -p sdi-cli
cargo build -q --release -p sdi-tests --bin loopback_tool
# One VM at a time, as the VM tests do.
exec flock "${TMPDIR:-/tmp}/sdi-vm.lock" tests/vm/vmrun -t 1800 -m 2048 -- bash -c "
  modprobe v4l2loopback devices=3 video_nr=50,51,52 \
    card_label='SDI camera,SDI data,ffmpeg peer' exclusive_caps=1,1,1 max_buffers=4 &&
  SDI_BENCH_SINK=loopback SDI_BENCH_PREBUILT=1 bash tests/bench/daemon_cpu.sh $window_s"
