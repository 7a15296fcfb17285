"""Classifications take turns on the stage: first come, first served, one at a time.

The stage (one driver, one camera) lights one sequence at a time, so the classifier's calls
wait in `StageQueue`, a FIFO served by one worker thread. The executor's threads never wait
for the stage: the service handler submits its call and awaits the outcome, so the driver's
replies and the images always find a thread (with every executor thread blocked on the
stage, as before, four concurrent calls all failed).

A call comes with its deadline (the request's time limit). It is refused at once, with the
reason, when it cannot be served in time: when the calls ahead of it would, at the recent
time per call, keep the stage past its deadline, or when `max_waiting` wait already. A call
that had to wait and whose turn comes with less time left than a call takes is refused
then, not started to fail halfway. "What a call takes" is the recent time per call plus
four times its recent spread (as TCP's retransmission timeout, RFC 6298): with the mean
alone, a call starting just above it ran over in about half such cases and failed with
its last image missing (once in a full suite run under load). A call with nothing ahead
of it always starts. Nothing here imports rclpy.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from concurrent.futures import Future
from typing import Callable

MAX_WAITING = 256  # calls waiting for the stage beyond this are refused at once
SMOOTHING = 0.3    # weight of the newest call in the recent time per call
SPREAD_MARGIN = 4.0  # a waiting call starts with the mean time per call + this many spreads


class StageBusy(Exception):
    """The call cannot be served within its time limit (or the queue is full / closed); the
    message says why and what to do."""


class _Job:
    __slots__ = ('fn', 'deadline', 'timeout_s', 'future', 'submitted', 'ahead')

    def __init__(self, fn, submitted, timeout_s, ahead):
        self.fn, self.submitted, self.timeout_s, self.ahead = fn, submitted, timeout_s, ahead
        self.deadline = submitted + timeout_s
        self.future: Future = Future()


class StageQueue:
    """`submit(fn, timeout_s)` -> a `concurrent.futures.Future` of ``fn(remaining_s)``, run
    on the worker thread in submission order; `StageBusy` (raised at once by `submit`, or set
    on the future when the call's turn comes too late) when it cannot be served in time.

    ``clock``: monotonic seconds (tests pass their own).
    """

    def __init__(self, max_waiting: int = MAX_WAITING, clock: Callable[[], float] = time.monotonic,
                 name: str = 'stage-queue'):
        self.max_waiting = int(max_waiting)
        self.clock = clock
        self._jobs: deque[_Job] = deque()
        self._cond = threading.Condition()
        self._running: _Job | None = None
        self._running_since = 0.0
        self._closed = False
        self.seconds_per_call: float | None = None  # recent time of one call on the stage
        self.seconds_per_call_spread = 0.0  # recent mean deviation from it
        self.served = 0
        self.refused = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def __len__(self) -> int:
        """Calls waiting or being served."""
        with self._cond:
            return len(self._jobs) + (self._running is not None)

    def submit(self, fn: Callable[[float], object], timeout_s: float) -> Future:
        now = self.clock()
        with self._cond:
            ahead = len(self._jobs) + (self._running is not None)
            if self._closed:
                raise self._refuse('the classifier is shutting down; nothing more is served')
            if len(self._jobs) >= self.max_waiting:
                raise self._refuse(f'{len(self._jobs)} classifications are already waiting for '
                                   'the stage, the most this node queues; try again when they '
                                   'are done')
            wait_s = self._wait_estimate_s(now)
            per_call = self.seconds_per_call
            if ahead and per_call is not None and wait_s + per_call > timeout_s:
                raise self._refuse(
                    f'{ahead} classification(s) ahead of this one would keep the stage busy '
                    f'for about {wait_s:.1f} s ({per_call:.2f} s each), and this one takes '
                    f'about {per_call:.2f} s more: beyond this request\'s time limit of '
                    f'{timeout_s:g} s; try again later or give a longer timeout_s')
            job = _Job(fn, now, timeout_s, ahead)
            self._jobs.append(job)
            self._cond.notify_all()
        return job.future

    def close(self, timeout_s: float = 5.0) -> None:
        """Refuse what waits and what comes; let the call being served finish (up to
        `timeout_s`)."""
        with self._cond:
            self._closed = True
            waiting, self._jobs = list(self._jobs), deque()
            self._cond.notify_all()
        for job in waiting:
            job.future.set_exception(
                self._refuse('the classifier is shutting down before this call\'s turn came'))
        self._thread.join(timeout_s)

    def _refuse(self, message: str) -> StageBusy:
        self.refused += 1
        return StageBusy(message)

    def _wait_estimate_s(self, now: float) -> float:
        """Until the stage is free for a call submitted now (lock held)."""
        per_call = self.seconds_per_call
        if per_call is None:
            return 0.0
        running_left = 0.0
        if self._running is not None:
            running_left = max(0.0, per_call - (now - self._running_since))
        return running_left + per_call * len(self._jobs)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._jobs and not self._closed:
                    self._cond.wait()
                if not self._jobs:
                    return
                job = self._jobs.popleft()
                self._running, self._running_since = job, self.clock()
            try:
                self._serve(job)
            finally:
                with self._cond:
                    self._running = None

    def _serve(self, job: _Job) -> None:
        start = self.clock()
        remaining = job.deadline - start
        per_call = self.seconds_per_call or 0.0
        needed = per_call + SPREAD_MARGIN * self.seconds_per_call_spread
        # a call that had to wait starts only with the time a call takes still left
        if remaining <= 0 or (job.ahead and remaining < needed):
            job.future.set_exception(self._refuse(
                f'this call waited {start - job.submitted:.1f} s for the stage behind '
                f'{job.ahead} earlier classification(s); {max(0.0, remaining):.2f} s of its '
                f'{job.timeout_s:g} s time limit was left, less than a call takes (about '
                f'{per_call:.2f} s, up to {needed:.2f} s): not started. Try again, or give a '
                f'longer timeout_s'))
            return
        try:
            result = job.fn(remaining)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller, the worker goes on
            job.future.set_exception(exc)
        else:
            job.future.set_result(result)
        took = self.clock() - start
        with self._cond:
            self.served += 1
            if self.seconds_per_call is None:   # RFC 6298's first measurement
                self.seconds_per_call, self.seconds_per_call_spread = took, took / 2
            else:   # the spread against the mean before this call, then the mean
                self.seconds_per_call_spread = (
                    SMOOTHING * abs(took - self.seconds_per_call)
                    + (1.0 - SMOOTHING) * self.seconds_per_call_spread)
                self.seconds_per_call = (SMOOTHING * took
                                         + (1.0 - SMOOTHING) * self.seconds_per_call)
