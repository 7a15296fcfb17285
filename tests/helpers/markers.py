"""The `process` marker, declared by a test module, and the guard that keeps the other tests
from starting processes.

A module whose tests start processes (node graphs, CLIs, Dask, simavr, a browser) says so
on one line, `pytestmark = pytest.mark.process` (or in its `pytestmark` list). tests/conftest.py
reads that line from the module's text (`declares_process`) so that `-m fast` does not even
import such a module, and wraps every `fast` test in `ProcessGuard`: a process started there
fails the test, naming the marker to add.
"""
from __future__ import annotations

import _posixsubprocess
import os
import re
import subprocess
import sys

# the module-level `pytestmark = ...` statement (continuation lines indented) naming pytest.mark.process
_DECLARATION = re.compile(r'^pytestmark\s*=[^\n]*(?:\n[ \t)\]][^\n]*)*?\bpytest\.mark\.process\b', re.M)


def declares_process(text: str) -> bool:
    """Does a test module's source mark all its tests `process`? (its `pytestmark` line)"""
    return bool(_DECLARATION.search(text))


class ProcessStartInFastTest(RuntimeError):
    """A test not marked `process` tried to start a process."""


class ProcessGuard:
    """While installed (on a pytest `monkeypatch`), every call through which Python starts a
    process raises `ProcessStartInFastTest` and is recorded in `attempts` (a caller that
    swallows the error still fails the test: conftest checks `attempts` afterwards).

    The calls: `subprocess.Popen._execute_child` (subprocess.run, check_output, asyncio's
    subprocesses, os.popen: fork_exec and posix_spawn alike), `_posixsubprocess.fork_exec`
    (multiprocessing's spawn and forkserver contexts, joblib's loky workers), `os.fork` and
    `os.forkpty` (multiprocessing's fork context, pty.fork, os.spawn*), `os.posix_spawn[p]`
    and `os.system`; and `rclpy.init` when rclpy is imported (a ROS context: `ros` tests
    start their participants in modules marked `process`). Patching these module attributes
    costs microseconds per test, and no process is needed to find out that none was started.
    """

    def __init__(self, test_name: str):
        self.test_name = test_name
        self.attempts: list[str] = []

    def _refuse(self, what: str):
        def refuse(*_args, **_kwargs):
            self.attempts.append(what)
            raise ProcessStartInFastTest(
                f'{self.test_name} is not marked `process` but started a process ({what}): '
                f'add `pytestmark = pytest.mark.process` to its module (tests/helpers/markers.py)')
        return refuse

    def install(self, monkeypatch) -> 'ProcessGuard':
        monkeypatch.setattr(subprocess.Popen, '_execute_child', self._refuse('subprocess.Popen'))
        monkeypatch.setattr(_posixsubprocess, 'fork_exec', self._refuse('_posixsubprocess.fork_exec'))
        for name in ('fork', 'forkpty', 'posix_spawn', 'posix_spawnp', 'system'):
            if hasattr(os, name):
                monkeypatch.setattr(os, name, self._refuse(f'os.{name}'))
        if 'rclpy' in sys.modules:
            monkeypatch.setattr(sys.modules['rclpy'], 'init', self._refuse('rclpy.init'))
        return self
