"""A real Dask cluster for the tests: `dask scheduler` and `dask worker`s as separate
processes bound to 127.0.0.1 (no dashboards, no nanny, so that a worker's PID is the process
that runs its tasks), always stopped at the end of the test (finalizers). The fixtures
`dask_scheduler` and `cluster` (tests/mux_trainer/conftest.py) start them."""
import json
import subprocess
import sys
import time

import distributed

DASK = [sys.executable, '-m', 'dask']  # this venv's (a copied venv's scripts may name another)
START_TIMEOUT_S = 120  # a process start on a loaded 2-core machine; not a timed assertion


def start_process(request, args, log):
    """Start `args` with its output in `log`; killed (if still running) when the test ends."""
    proc = subprocess.Popen(args, stdout=log.open('wb'), stderr=subprocess.STDOUT,
                            start_new_session=True)

    def stop():
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)
    request.addfinalizer(stop)
    return proc


def start_scheduler(request, tmp_path):
    """A `dask scheduler` on 127.0.0.1, a free port; returns (address, process)."""
    file = tmp_path / 'scheduler.json'
    proc = start_process(request, [*DASK, 'scheduler', '--host', '127.0.0.1', '--port', '0',
                                   '--no-dashboard', '--scheduler-file', str(file)],
                         tmp_path / 'scheduler.log')
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        assert proc.poll() is None, (tmp_path / 'scheduler.log').read_text()
        try:
            return json.loads(file.read_text())['address'], proc
        except (OSError, ValueError, KeyError):  # not written yet, or half written
            assert time.monotonic() < deadline, 'dask scheduler did not start'
            time.sleep(0.1)


def start_workers(request, tmp_path, address, names=('a', 'b')):
    """One one-thread worker per name on the scheduler at `address`, once all have joined:
    {name: worker process}."""
    workers = {name: start_process(request, [*DASK, 'worker', address, '--host', '127.0.0.1',
                                             '--nthreads', '1', '--no-dashboard', '--no-nanny',
                                             '--name', name], tmp_path / f'worker-{name}.log')
               for name in names}
    with distributed.Client(address, timeout=START_TIMEOUT_S, set_as_default=False) as client:
        client.wait_for_workers(len(names), timeout=START_TIMEOUT_S)
    return workers
