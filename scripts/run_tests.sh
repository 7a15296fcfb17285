#!/usr/bin/env bash
# Run the test suite in .venv (after scripts/bootstrap.sh). Extra arguments go to pytest.
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# Discovery never leaves this machine; tests/conftest.py gives the run its own domain id
# and tests that start processes pick theirs.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
.venv/bin/python -m pytest "$@"
rc=$?
if [ $rc -eq 5 ]; then
  echo "pytest collected no tests (exit 5); nothing failed"
  exit 0
fi
exit $rc
