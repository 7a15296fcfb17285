"""Which pytest-xdist worker this process is (scripts/run_tests.sh runs one per core), so
that workers running tests at the same time take disjoint ROS domain ids. No imports beyond
the standard library: tests/conftest.py uses it before any ROS module is loaded."""
from __future__ import annotations

import os


def xdist_worker() -> tuple[int, int]:
    """(this process's worker index, the number of workers); (0, 1) in a run without workers."""
    name = os.environ.get('PYTEST_XDIST_WORKER', '')
    count = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    return (int(name[2:]) if name.startswith('gw') else 0), max(count, 1)
