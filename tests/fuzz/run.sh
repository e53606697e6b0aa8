#!/usr/bin/env bash
# Runs every fuzz target for SECONDS each (fuzz/fuzz_targets/): builds them
# with libFuzzer's coverage instrumentation on stable rustc (no cargo-fuzz,
# no nightly: tests/fuzz/rustc-sancov.sh adds the flags to the workspace's
# own crates, the dependencies are the ones `cargo test` built), then runs
# each from its seeds in fuzz/corpus/TARGET. Exits non-zero on a crash,
# a timeout (one input slower than TIMEOUT_S), or memory past the bound.
# The grown corpus goes to a scratch directory, never into the repository.
#
# Usage: tests/fuzz/run.sh SECONDS [TARGET...]
# Env: FUZZ_TIMEOUT_S (per input, default 10), FUZZ_RSS_MB (default 2048),
#      FUZZ_WORK (scratch directory, default target/fuzz-work).
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=${1:?usage: tests/fuzz/run.sh SECONDS [TARGET...]}
shift
if [ $# -gt 0 ]; then
    targets=("$@")
else
    mapfile -t targets < <(ls fuzz/fuzz_targets | sed 's/\.rs$//')
fi
timeout_s=${FUZZ_TIMEOUT_S:-10}
rss_mb=${FUZZ_RSS_MB:-2048}
work=${FUZZ_WORK:-target/fuzz-work}

RUSTC_WORKSPACE_WRAPPER="$PWD/tests/fuzz/rustc-sancov.sh" \
    cargo build -p sdi-fuzz --features libfuzzer --bins
bin_dir=${CARGO_TARGET_DIR:-target}/debug

failed=()
for t in "${targets[@]}"; do
    corpus="$work/corpus/$t"
    artifacts="$work/artifacts/$t/"
    mkdir -p "$corpus" "$artifacts"
    echo "== fuzz $t: ${seconds}s"
    # -malloc_limit_mb: one allocation past the bound is a failure even
    # when the RSS stays under it.
    if ! "$bin_dir/$t" "$corpus" "fuzz/corpus/$t" \
        -max_total_time="$seconds" -timeout="$timeout_s" \
        -rss_limit_mb="$rss_mb" -malloc_limit_mb="$rss_mb" \
        -artifact_prefix="$artifacts" -print_final_stats=1 \
        >"$work/$t.log" 2>&1; then
        failed+=("$t")
        tail -n 40 "$work/$t.log"
        echo "fuzz $t FAILED: input in $artifacts (log $work/$t.log)"
    fi
    grep -E '^(#[0-9]+.*DONE|stat::number_of_executed_units|stat::peak_rss_mb)' "$work/$t.log" | sed "s/^/   $t: /" || true
done
if [ ${#failed[@]} -gt 0 ]; then
    echo "fuzz: ${#failed[@]} target(s) failed: ${failed[*]}"
    exit 1
fi
echo "fuzz: ${#targets[@]} targets ran ${seconds}s each without a failure"
