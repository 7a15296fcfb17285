"""Candidate evaluation on an existing Dask cluster (`dask scheduler` / `dask worker`,
dask-jobqueue, Kubernetes): the project only connects to one, it never starts one.

`dask_cluster(address)` connects and makes the connection the active one for the code run
inside it: every `CandidateEvaluator.score` then sends its candidate chunks to the cluster
(`active_cluster()`), so `lightstage train`, `lightstage eval` and the trainer node need no
other change to search remotely. Without it everything stays local (joblib, `--jobs`).

What moves: the search data (the models, the same for the whole search) and each column's
shared state (`ColumnContext`: candidate noise, earlier columns' kernel, splits) are
broadcast to every worker once (`Client.scatter(..., broadcast=True)`), and each task takes
their futures plus its chunk of candidate columns (a few hundred bytes). Results are keyed
by task (gathered in the order submitted), so which worker ran a task, or whether it ran
twice because its first worker was lost, changes nothing: a lost worker costs only its
unfinished tasks, which the scheduler gives to the others. While connected, the scheduler's
active memory manager is paused (it would drop the broadcast copies between tasks; see
`DaskCluster.__init__`) and restarted on close. A scheduler that cannot be
reached, that goes away, or that has no worker left for `timeout_s` raises
`ClusterUnavailable` (a ConnectionError) naming the address: an error, not a hang.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
import time

DASK_SCHEDULER_ENV = 'LIGHTSTAGE_DASK_SCHEDULER'
DEFAULT_TIMEOUT_S = 30.0
POLL_S = 0.5  # how often a waiting search checks that its scheduler and workers are there

_active = contextvars.ContextVar('mux_trainer_dask_cluster', default=None)


class ClusterUnavailable(ConnectionError):
    """The Dask scheduler cannot be reached, went away, or has no workers; says which."""


def scheduler_from_env(value: str | None = None) -> str:
    """The scheduler address to use: `value` if given, else $LIGHTSTAGE_DASK_SCHEDULER, else
    '' (local)."""
    if value:
        return value.strip()
    return os.environ.get(DASK_SCHEDULER_ENV, '').strip()


def active_cluster() -> 'DaskCluster | None':
    """The cluster of the innermost `dask_cluster` block of this thread, or None (local)."""
    return _active.get()


@contextlib.contextmanager
def dask_cluster(address: str | None, timeout_s: float = DEFAULT_TIMEOUT_S):
    """Connect to the scheduler at `address` and make it the active cluster inside the
    block; with an empty address, do nothing (local search). Yields the DaskCluster or None."""
    if not address:
        yield None
        return
    cluster = DaskCluster(address, timeout_s)
    token = _active.set(cluster)
    try:
        yield cluster
    finally:
        _active.reset(token)
        cluster.close()


def probe_scheduler(address: str, timeout_s: float) -> None:
    """Refuse at once an address that is not one (`not a url`) or a TCP port that refuses
    connections (nothing listens: no need to wait `timeout_s`); ClusterUnavailable naming
    it. Anything else (no answer yet, another protocol) is left to the Client's timeout."""
    import socket

    from distributed.comm.addressing import parse_address, parse_host_port
    hint = ('give the address `dask scheduler` prints, tcp://HOST:PORT (e.g. '
            'tcp://10.0.0.5:8786), or train locally without --dask-scheduler / '
            f'{DASK_SCHEDULER_ENV}')
    try:
        protocol, location = parse_address(address.strip())
        if protocol not in ('tcp', 'tls'):
            return
        host, port = parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise ClusterUnavailable(f'{address!r} is not a Dask scheduler address ({exc}); '
                                 f'{hint}') from None
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except ConnectionRefusedError:
        raise ClusterUnavailable(f'the Dask scheduler {address} refused the connection: nothing '
                                 f'listens on port {port} of {host}; start `dask scheduler` '
                                 f'there or {hint[0].lower()}{hint[1:]}') from None
    except OSError:
        return  # unresolvable, unreachable, slow: the Client says so within its timeout


class DaskCluster:
    """A connection to a Dask scheduler that runs chunks of candidate evaluations."""

    def __init__(self, address: str, timeout_s: float = DEFAULT_TIMEOUT_S):
        if timeout_s <= 0:
            raise ValueError(f'the Dask timeout must be > 0 s, got {timeout_s}')
        try:
            from distributed import Client
        except ImportError as exc:  # the optional extra requirements-cluster.txt
            raise ClusterUnavailable(f'cannot use the Dask scheduler {address}: the '
                                     f'`distributed` package is missing ({exc}); install it with '
                                     '`bash scripts/bootstrap.sh --with cluster` (requirements-cluster.txt)') from None
        self.address = address
        self.timeout_s = float(timeout_s)
        # before a Client exists: a Client that fails in its constructor still closes itself
        # when collected, and prints "Exception ignored in Client.__del__" after the message
        probe_scheduler(address, self.timeout_s)
        try:
            self.client = Client(address, timeout=self.timeout_s, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise ClusterUnavailable(
                f'cannot reach the Dask scheduler {address} within {self.timeout_s:g} s '
                f'({type(exc).__name__}: {exc}); check that `dask scheduler` runs there and '
                f'that the address (tcp://HOST:PORT) is right, or train locally without '
                f'--dask-scheduler / {DASK_SCHEDULER_ENV}') from None
        # Dask's active memory manager drops the replicas that no waiting task needs (every
        # 2 s): between the screen and each refinement batch it would take the broadcast data
        # off all workers but one, and they would fetch it again. Paused while connected.
        try:
            self._memory_manager_paused = bool(self.client.amm.running())
            if self._memory_manager_paused:
                self.client.amm.stop()
        except (OSError, TimeoutError) as exc:
            self.client.close()
            raise self._lost(f'{type(exc).__name__}: {exc}') from None
        self._shared = {}  # slot -> (object, its future on the workers)
        self.bytes_broadcast = 0  # pickled bytes of the shared objects, times their workers
        self.tasks_submitted = 0

    def close(self) -> None:
        try:
            if self._memory_manager_paused and self.client.status == 'running':
                self.client.amm.start()
            self.client.close(timeout=self.timeout_s)
        except Exception:  # noqa: BLE001 - closing a connection to a dead scheduler
            pass

    def _lost(self, what: str) -> ClusterUnavailable:
        return ClusterUnavailable(f'lost the Dask scheduler {self.address}: {what}; the search '
                                  'stopped (nothing was written); check the scheduler and its '
                                  'workers, then run again')

    def share(self, slot: str, obj):
        """`obj` on every worker, broadcast once while it stays the object of `slot` (the
        search data; the current column's context); the slot's previous object is released."""
        held = self._shared.get(slot)
        if held is not None and held[0] is obj:
            return held[1]
        if held is not None:
            held[1].release()
        n_workers = self._wait_for_workers()
        try:
            future = self.client.scatter(obj, broadcast=True, hash=False,
                                         timeout=self.timeout_s)
        except (OSError, TimeoutError) as exc:
            raise self._lost(f'broadcasting the {slot} failed ({type(exc).__name__}: {exc})') \
                from None
        self._shared[slot] = (obj, future)
        self.bytes_broadcast += shared_bytes(obj) * n_workers
        return future

    def _wait_for_workers(self) -> int:
        """The number of workers, waiting up to timeout_s for at least one."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                n = len(self.client.scheduler_info(n_workers=-1)['workers'])
            except (OSError, TimeoutError) as exc:
                raise self._lost(f'{type(exc).__name__}: {exc}') from None
            if n:
                return n
            if time.monotonic() > deadline:
                raise self._lost(f'it has had no workers for {self.timeout_s:g} s')
            time.sleep(POLL_S)

    def map(self, function, shared: dict, items: list, **kwargs) -> list:
        """`[function(*shared futures, item, **kwargs) for item in items]` on the workers, in
        the order of `items` whatever order or worker they ran in. `shared` maps a slot
        name to the object broadcast in it (`share`)."""
        if not items:
            return []
        args = [self.share(slot, obj) for slot, obj in shared.items()]
        try:
            futures = [self.client.submit(function, *args, item, pure=False, **kwargs)
                       for item in items]
        except (OSError, TimeoutError) as exc:
            raise self._lost(f'{type(exc).__name__}: {exc}') from None
        self.tasks_submitted += len(futures)
        results = []
        alone_since = None
        for future in futures:  # in task order: the result does not depend on arrival
            troubled_since = None
            while True:
                try:
                    results.append(future.result(timeout=POLL_S))
                    break
                except TimeoutError:
                    pass
                except Exception as exc:  # CancelledError once the client gave up
                    if 'deserializ' in str(exc):  # e.g. an older mux_trainer on the cluster
                        raise ClusterUnavailable(
                            f'the Dask cluster {self.address} cannot run the search\'s tasks '
                            f'({type(exc).__name__}: {exc}); its scheduler and workers need the '
                            'same lightstage packages as this machine') from None
                    if self.client.status == 'running' and future.status == 'error':
                        raise  # the task's own error: the search code's, not the cluster's
                    # While a lost worker's task is being moved, result() itself can fail
                    # (distributed 2026.8 raised UnboundLocalError from it, once, on a
                    # SIGKILLed worker): wait on while the client runs, for up to timeout_s.
                    now = time.monotonic()
                    troubled_since = now if troubled_since is None else troubled_since
                    if (self.client.status != 'running' or future.status == 'cancelled'
                            or now - troubled_since > self.timeout_s):
                        raise self._lost(f'{type(exc).__name__}: {exc}') from None
                alone_since = self._check_alive(alone_since)
        return results

    def _check_alive(self, alone_since):
        """Raise when the connection is closed, or has been down or without workers for
        timeout_s; returns since when it has been so (None: it is fine)."""
        if self.client.status not in ('running', 'connecting'):
            raise self._lost(f'the connection is {self.client.status}')
        # scheduler_info asks the scheduler; when it cannot, it returns what it knew
        stalled = (self.client.status != 'running'
                   or not self.client.scheduler_info(n_workers=-1)['workers'])
        if not stalled:
            return None
        now = time.monotonic()
        if alone_since is not None and now - alone_since > self.timeout_s:
            raise self._lost(f'no connection or no workers for {self.timeout_s:g} s')
        return now if alone_since is None else alone_since


def shared_bytes(obj) -> int:
    """Bytes `obj` takes on the wire (pickle protocol 5, buffers included)."""
    import pickle
    buffers = []
    head = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    return len(head) + sum(memoryview(b).nbytes for b in buffers)


def array_nbytes(obj) -> int:
    """Bytes of the numpy arrays among `obj`'s attributes (also in lists)."""
    import numpy as np
    total = 0
    for value in vars(obj).values():
        for item in (value if isinstance(value, (list, tuple)) else (value,)):
            if isinstance(item, np.ndarray):
                total += item.nbytes
    return total


class ArraySized:
    """Mixin for the array holders a Dask worker keeps (`SearchData`, `ColumnContext`): their
    `__sizeof__` counts their arrays, so Dask's `sizeof` (sys.getsizeof for unknown types),
    run on the workers, reports them and not a few hundred bytes. Through `__sizeof__` rather
    than a registration with Dask, a worker that only unpickled the object (and imported its
    module, nothing else) measures it right too."""

    def __sizeof__(self) -> int:
        return object.__sizeof__(self) + array_nbytes(self)
