"""ExitDeadline: a command-line call that always ends, whatever it is stuck in.

A CLI verb's waits are bounded one by one (the service's appearance, its answer), but a
process can still hang where no timeout reaches: in creating or destroying its DDS
participant (C++ code holding the main thread), in an interpreter shutdown that waits for a
thread. `lightstage classify` calls started twelve at once once printed nothing and still
ran after 60 s (once in 120 runs). So a verb runs under an ExitDeadline: a daemon timer that,
if the call is still running when it fires, writes what the call was doing (`phase`) and how
long it ran to stderr and ends the process with `os._exit` (the only exit that does not
wait for the stuck thread). Pure Python, no rclpy.

    with ExitDeadline(40.0, 'lightstage classify', exit_code=3) as deadline:
        deadline.phase = 'setting up the ROS client'
        ...
"""
from __future__ import annotations

import os
import sys
import threading
import time

__all__ = ["ExitDeadline"]


class ExitDeadline:
    """Ends this process with `exit_code` `seconds` after `start()` (or entering the `with`)
    unless `cancel()`ed (or the `with` left) first. `phase` names what the call is doing, for
    the message; `restart(seconds, exit_code)` sets a new deadline from now (e.g. a short one
    for the teardown once the answer is printed)."""

    def __init__(self, seconds: float, prog: str, exit_code: int, phase: str = 'starting'):
        self.prog = prog
        self.phase = phase
        self._seconds = float(seconds)
        self._exit_code = int(exit_code)
        self._timer: threading.Timer | None = None
        self._started = time.monotonic()
        self._lock = threading.Lock()

    def start(self) -> ExitDeadline:
        self.restart(self._seconds, self._exit_code)
        return self

    def restart(self, seconds: float, exit_code: int | None = None) -> None:
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
            self._seconds = float(seconds)
            if exit_code is not None:
                self._exit_code = int(exit_code)
            self._timer = threading.Timer(self._seconds, self._expire)
            self._timer.daemon = True
            self._timer.start()

    def cancel(self) -> None:
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None

    def __enter__(self) -> ExitDeadline:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.cancel()

    def _expire(self) -> None:
        ran = time.monotonic() - self._started
        message = (f'{self.prog}: still {self.phase} after {ran:.0f} s, beyond this call\'s '
                   f'{self._seconds:g} s limit for it; ending the process (exit code '
                   f'{self._exit_code})\n')
        try:  # os.write, not print: the stuck thread may hold sys.stdout's or sys.stderr's lock
            os.write(sys.stderr.fileno(), message.encode())
        except (OSError, ValueError):
            pass
        os._exit(self._exit_code)
