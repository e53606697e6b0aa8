#!/bin/bash
# Flake hunt: runs integration tests N times in a row and counts failures.
#   tests/vm/repeat.sh TEST N          one test file of sdi-tests (e.g. vm_daemon,
#                                      or dbus_api: a module of the integration binary)
#   tests/vm/repeat.sh 'vm_*' N        a glob over tests/tests/*.rs and tests/tests/integration/*.rs
#   tests/vm/repeat.sh all N           every VM and D-Bus test (vm_*, dbus_*,
#                                      daemon_*, system_dbus_*, system_hotplug, system_sandbox, pipewire_*)
# VM tests are mandatory here (SDI_REQUIRE_VM=1). Logs of failed runs are kept
# in $REPEAT_LOGS (default /var/tmp/sdi-repeat); the last line per test is
# "TEST: F of N failed".
set -eEuo pipefail
trap 'rc=$?; echo "repeat.sh: failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
[ $# = 2 ] || { sed -n '2,9p' "$0" >&2; exit 2; }
pattern=$1 n=$2
cd "$(dirname "$0")/../.."
if [ "$pattern" = all ]; then
    pattern='vm_* dbus_* daemon_* system_dbus_* system_hotplug system_sandbox pipewire_*'
fi
tests=()
for p in $pattern; do
    for f in tests/tests/$p.rs tests/tests/integration/$p.rs; do
        [ -f "$f" ] && [ "$(basename "$f")" != main.rs ] && tests+=("$(basename "$f" .rs)")
    done
done
# A file under integration/ is a module of the one binary `integration`.
target_of() { if [ -f "tests/tests/integration/$1.rs" ]; then echo "--test integration -- $1::"; else echo "--test $1"; fi; }
[ ${#tests[@]} -gt 0 ] || { echo "repeat.sh: no test matches '$1'" >&2; exit 2; }
logs=${REPEAT_LOGS:-/var/tmp/sdi-repeat}
mkdir -p "$logs"
export SDI_REQUIRE_VM=1
cargo test -q -p sdi-tests --no-run --tests 2>&1 | tail -3
total_failed=0
for t in "${tests[@]}"; do
    failed=0
    for i in $(seq 1 "$n"); do
        log=$logs/$t-$i.log
        start=$(date +%s)
        # shellcheck disable=SC2046 # target_of gives several words
        if cargo test -q -p sdi-tests $(target_of "$t") >"$log" 2>&1; then
            rm -f "$log"
            echo "$t run $i: ok ($(( $(date +%s) - start )) s)"
        else
            failed=$((failed + 1))
            echo "$t run $i: FAILED ($(( $(date +%s) - start )) s), log $log"
            grep -a -m3 -E "panicked at|assertion" -A2 "$log" | sed 's/^/    /' || true
        fi
    done
    echo "$t: $failed of $n failed"
    total_failed=$((total_failed + failed))
done
[ "$total_failed" = 0 ]
