#!/usr/bin/env bash
# Run the test suite in .venv (after scripts/bootstrap.sh). Extra arguments go to pytest.
#
# No packet may leave the machine, by construction: pytest runs in a private network
# namespace whose only interface is loopback (`unshare --net`, then `ip link set lo up`), when
# the platform allows it (as root: CI). Otherwise it runs in the host's network and says so;
# LIGHTSTAGE_TEST_NETNS=off skips the namespace on purpose. (Not `unshare -r` for other
# users: root in a user namespace passes the permission checks some tests rely on.)
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# Discovery never leaves this machine; tests/conftest.py gives the run its own domain id
# and tests that start processes pick theirs.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# The installed lightstage_driver does not carry the firmware sources; the AVR tests build
# and run the checkout's firmware, and must not be skipped here.
export LIGHTSTAGE_FIRMWARE_DIR="$ROOT/src/lightstage_driver/firmware"
export LIGHTSTAGE_REQUIRE_AVR=1

# pytest-xdist workers, a test file per worker at a time (its module fixtures set up once):
# one more than the cores, as a graph test spends much of its time waiting on other
# processes (on 2 cores the suite used 1.65 cores with 2 workers; with 3 it took 602-620 s where
# 2 took 697-718 s). LIGHTSTAGE_TEST_WORKERS=N sets the number (0: one process); a later -n
# in the arguments wins.
WORKERS="${LIGHTSTAGE_TEST_WORKERS:-$(( $(nproc) + 1 ))}"
if [ "$WORKERS" = 0 ]; then
  PYTEST=(.venv/bin/python -m pytest "$@")
else
  PYTEST=(.venv/bin/python -m pytest -n "$WORKERS" --dist loadfile "$@")
fi
UNSHARE=(unshare --net)
why=""
if [ "${LIGHTSTAGE_TEST_NETNS:-on}" = off ]; then
  why="LIGHTSTAGE_TEST_NETNS=off"
elif ! command -v unshare >/dev/null || ! command -v ip >/dev/null; then
  why="unshare (util-linux) or ip (iproute2) is not installed"
elif ! err=$("${UNSHARE[@]}" ip link set lo up 2>&1); then
  why="unshare --net failed: ${err:-no reason given} (needs root)"
fi
if [ -z "$why" ]; then
  echo "[run_tests] pytest runs in a private network namespace: loopback only, no packet can leave the machine"
  # tests/conftest.py reports the interfaces it sees in pytest's header; "private" tells the
  # test that checks nothing can leave (tests/lightstage_graph/test_ros_environment.py) that it should
  export LIGHTSTAGE_TEST_NETNS=private
  "${UNSHARE[@]}" sh -c 'ip link set lo up && exec "$@"' sh "${PYTEST[@]}"
  rc=$?
else
  echo "[run_tests] WARNING: no private network namespace ($why); pytest runs in the host's network (LOCALHOST discovery still keeps ROS traffic on loopback)"
  "${PYTEST[@]}"
  rc=$?
fi
if [ $rc -eq 5 ]; then
  echo "pytest collected no tests (exit 5); nothing failed"
  exit 0
fi
exit $rc
