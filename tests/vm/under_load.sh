#!/usr/bin/env bash
# Runs the VM tests (tests/vm/run.sh, arguments passed on) while two busy loops load the host,
# as other jobs do on a shared CI host; the loops are killed however the run ends.
#
#   bash tests/vm/under_load.sh        (or: make vm-load)
set -euo pipefail
loops=()
trap 'kill "${loops[@]}" 2>/dev/null || true' EXIT
for _ in 1 2; do
    bash -c 'while :; do :; done' &
    loops+=($!)
done
echo "vm: two busy loops load the host (pids ${loops[*]})"
start=$(date +%s)
status=0
bash "$(dirname "$0")/run.sh" "$@" || status=$?
echo "vm: under load, the run took $(($(date +%s) - start)) s (exit $status)"
exit "$status"
