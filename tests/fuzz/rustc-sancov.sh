#!/usr/bin/env bash
# rustc wrapper (RUSTC_WORKSPACE_WRAPPER) for the fuzz build: adds
# libFuzzer's coverage instrumentation (the flags cargo-fuzz passes) to the
# workspace's own crates only, so the dependencies CI already compiled for
# `cargo test` are reused and stable rustc needs no -Z flag.
set -euo pipefail
rustc=$1
shift
crate_name=
crate_type=
prev=
for a in "$@"; do
    case $prev in
    --crate-name) crate_name=$a ;;
    --crate-type) crate_type=$a ;;
    esac
    prev=$a
done
# Build scripts and proc macros run on the host without libFuzzer linked.
case $crate_name:$crate_type in
build_script_* | *:proc-macro) exec "$rustc" "$@" ;;
esac
exec "$rustc" "$@" \
    -Cpasses=sancov-module \
    -Cllvm-args=-sanitizer-coverage-level=4 \
    -Cllvm-args=-sanitizer-coverage-inline-8bit-counters \
    -Cllvm-args=-sanitizer-coverage-pc-table \
    -Cllvm-args=-sanitizer-coverage-trace-compares \
    --cfg fuzzing
