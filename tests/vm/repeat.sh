#!/bin/bash
# Flake hunt: runs tests N times in a row and counts failed runs.
#   tests/vm/repeat.sh TARGET N
#     TARGET: a test binary of sdi-tests (vm_plain, vm_desktop, vm_systemd,
#             integration, soak, ...), one module of it (vm_plain::board,
#             integration::dbus_api), or `all`: the README's `cargo test`,
#             every test of the workspace, as CI runs it.
# VM and packaging tests are mandatory here (SDI_REQUIRE_VM=1,
# SDI_REQUIRE_PACKAGING=1). Logs of failed runs are kept in $REPEAT_LOGS
# (default /var/tmp/sdi-repeat); the last line is "TARGET: F of N failed".
set -eEuo pipefail
trap 'rc=$?; echo "repeat.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
[ $# = 2 ] || { sed -n '2,10p' "$0" >&2; exit 2; }
target=$1 n=$2
cd "$(dirname "$0")/../.."
case $target in
    all) args=() ;;
    *::*) args=(-p sdi-tests --test "${target%%::*}" -- "${target#*::}::") ;;
    *) args=(-p sdi-tests --test "$target") ;;
esac
logs=${REPEAT_LOGS:-/var/tmp/sdi-repeat}
mkdir -p "$logs"
export SDI_REQUIRE_VM=1 SDI_REQUIRE_PACKAGING=1
cargo test -q --no-run 2>&1 | tail -3
failed=0
for i in $(seq 1 "$n"); do
    log=$logs/${target//[:\/]/_}-$i.log
    start=$(date +%s)
    if cargo test "${args[@]}" >"$log" 2>&1; then
        summary=$(grep -aE '^test result:' "$log" | awk '{p+=$4; f+=$6} END {print p+0 " passed, " f+0 " failed"}')
        rm -f "$log"
        echo "$target run $i: ok ($(($(date +%s) - start)) s; $summary)"
    else
        failed=$((failed + 1))
        echo "$target run $i: FAILED ($(($(date +%s) - start)) s), log $log"
        grep -a -m3 -E "panicked at|assertion" -A2 "$log" | sed 's/^/    /' || true
    fi
done
echo "$target: $failed of $n failed"
[ "$failed" = 0 ]
