#!/usr/bin/env bash
# Run the benchmark scripts (benchmarks/*.py; `_*.py` are their shared modules) one after the
# other, each to its end, and print each one's wall time and exit status. `make bench` runs
# every script with --quick (a small run of each: 8.4 min on 2 shared cores); BENCH_ARGS
# replaces that (e.g. BENCH_ARGS= for the full runs, hours); arguments name the scripts to
# run (default: all). Exits 1 if any script failed, after running the rest.
#
# Several scripts start ROS nodes, Dask or emulated cameras: as scripts/run_tests.sh does,
# everything runs in a private network namespace whose only interface is loopback (`unshare
# --net`) where the platform allows it (root); otherwise on the host's network, said so
# (ROS discovery is LOCALHOST either way).
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# bench_firmware.py builds and runs the checkout's firmware in simavr (as the tests do)
export LIGHTSTAGE_FIRMWARE_DIR="$ROOT/src/lightstage_driver/firmware"
BENCH_ARGS="${BENCH_ARGS---quick}"

if [ -z "${LIGHTSTAGE_BENCH_NETNS:-}" ]; then
  if command -v unshare >/dev/null && command -v ip >/dev/null \
      && unshare --net ip link set lo up 2>/dev/null; then
    echo "[run_benchmarks] in a private network namespace: loopback only"
    LIGHTSTAGE_BENCH_NETNS=private exec unshare --net sh -c 'ip link set lo up && exec "$@"' \
      sh bash "$0" "$@"
  fi
  echo "[run_benchmarks] WARNING: no private network namespace (unshare --net needs root); the host's network"
fi

if [ $# -gt 0 ]; then scripts=("$@"); else scripts=(benchmarks/[!_]*.py); fi
failed=()
summary=()
start_all=$SECONDS
for script in "${scripts[@]}"; do
  echo "== $script $BENCH_ARGS"
  start=$SECONDS
  # shellcheck disable=SC2086  # BENCH_ARGS is a list of arguments
  .venv/bin/python "$script" $BENCH_ARGS
  rc=$?
  summary+=("$(printf '%5d s  rc %d  %s' $((SECONDS - start)) "$rc" "$script")")
  [ $rc -eq 0 ] || failed+=("$script")
done
echo "== wall time per script"
printf '%s\n' "${summary[@]}"
echo "== all: $((SECONDS - start_all)) s"
if [ ${#failed[@]} -gt 0 ]; then
  echo "failed: ${failed[*]}"
  exit 1
fi
