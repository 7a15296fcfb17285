"""Supervise a set of child processes: start, forward their output, notice deaths, stop in order.

Pure Python (no rclpy), used by `lightstage up` and by tests that run nodes in their own
processes. Each child:

* runs in its own process group, so a Ctrl-C in the terminal reaches only the supervisor,
  which then stops the children in order (SIGINT, then SIGTERM, then SIGKILL);
* gets SIGTERM from the kernel if the supervisor dies without cleaning up (Linux
  PR_SET_PDEATHSIG; it fires when the *thread* that started the child exits, so start
  children from a thread that outlives them, normally the main thread);
* has its stdout and stderr forwarded line by line, prefixed with its name, to the
  supervisor's streams and, with a log directory, to `<log_dir>/<name>.log`.
"""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Mapping, Sequence

from lightstage_graph.exits import describe_exit

_PR_SET_PDEATHSIG = 1
_libc = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith('linux') else None

# Exit statuses that mean "stopped by the signal the supervisor sent": killed by it
# (negative in subprocess), or Python's 128 + signal convention.
_CLEAN_STOP_CODES = {0, -signal.SIGINT, -signal.SIGTERM,
                     128 + signal.SIGINT, 128 + signal.SIGTERM}


def _child_setup() -> None:  # runs in the child between fork and exec
    if _libc is not None:
        _libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    # An ignored SIGINT survives exec: started from a background job (`cmd &` in a script,
    # nohup) the supervisor ignores it, and so would every node, deaf to the SIGINT that
    # asks it to stop cleanly. Each child starts with the default disposition instead.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@dataclass(frozen=True)
class ProcessSpec:
    """What to run: a name (for prefixes and messages), the argv and its environment."""
    name: str
    argv: Sequence[str]
    env: Mapping[str, str] | None = None  # None: inherit this process's environment
    cwd: str | None = None

    def __post_init__(self):
        if not self.name or any(c.isspace() for c in self.name):
            raise ValueError(f'process name {self.name!r} must be non-empty without spaces')
        if not self.argv:
            raise ValueError(f'process {self.name!r}: argv is empty; give the command to run')


@dataclass
class ExitReport:
    """How one child ended: its exit status and the last signal the supervisor had to send."""
    name: str
    pid: int
    returncode: int | None
    signal_sent: str | None = None  # None, 'SIGINT', 'SIGTERM' or 'SIGKILL'
    expected: bool = True  # False when the child exited before being asked to stop

    @property
    def clean(self) -> bool:
        """Exited on its own accord or after SIGINT/SIGTERM, without needing SIGKILL."""
        return self.signal_sent != 'SIGKILL' and self.returncode in _CLEAN_STOP_CODES

    def __str__(self) -> str:
        how = describe_exit(self.returncode)
        after = f' after {self.signal_sent}' if self.signal_sent else ''
        return f'{self.name} (pid {self.pid}): {how}{after}'


@dataclass
class ManagedProcess:
    spec: ProcessSpec
    popen: subprocess.Popen
    started_at: float
    signal_sent: str | None = None
    stop_requested: bool = False
    _threads: list[threading.Thread] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def pid(self) -> int:
        return self.popen.pid

    @property
    def returncode(self) -> int | None:
        return self.popen.poll()

    def report(self) -> ExitReport:
        return ExitReport(self.name, self.pid, self.popen.poll(), self.signal_sent,
                          expected=self.stop_requested)


class Supervisor:
    """Start child processes, forward their output, and stop them all in order.

    Use as a context manager (`with Supervisor() as sup:`); leaving the block stops every
    child that is still running. `sigint_timeout_s` / `sigterm_timeout_s` bound how long
    the children get after SIGINT and after SIGTERM before the next, harder signal.
    """

    def __init__(self, *, stdout: IO[str] | None = None, stderr: IO[str] | None = None,
                 log_dir: str | os.PathLike | None = None, sigint_timeout_s: float = 5.0,
                 sigterm_timeout_s: float = 3.0):
        if sigint_timeout_s < 0 or sigterm_timeout_s < 0:
            raise ValueError('shutdown timeouts must be >= 0 s')
        self._stdout = stdout
        self._stderr = stderr
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self.sigint_timeout_s = sigint_timeout_s
        self.sigterm_timeout_s = sigterm_timeout_s
        self._processes: dict[str, ManagedProcess] = {}
        self._write_lock = threading.Lock()
        self._log_files: dict[str, IO[str]] = {}

    # -- starting ---------------------------------------------------------------------
    @property
    def processes(self) -> list[ManagedProcess]:
        return list(self._processes.values())

    def __getitem__(self, name: str) -> ManagedProcess:
        return self._processes[name]

    def start(self, spec: ProcessSpec) -> ManagedProcess:
        """Start one child; its output is forwarded from now on."""
        if spec.name in self._processes:
            raise ValueError(f'a process named {spec.name!r} was already started; names must be unique')
        env = dict(os.environ if spec.env is None else spec.env)
        env.setdefault('PYTHONUNBUFFERED', '1')  # lines arrive when printed, not at exit
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            self._log_files[spec.name] = open(self.log_dir / f'{spec.name}.log', 'a',
                                              encoding='utf-8', buffering=1)
        popen = subprocess.Popen(
            list(spec.argv), env=env, cwd=spec.cwd, stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, encoding='utf-8',
            errors='replace', bufsize=1, process_group=0, preexec_fn=_child_setup)
        proc = ManagedProcess(spec, popen, time.monotonic())
        for pipe, stream_name in ((popen.stdout, 'stdout'), (popen.stderr, 'stderr')):
            t = threading.Thread(target=self._forward, args=(spec.name, pipe, stream_name),
                                 name=f'forward-{spec.name}-{stream_name}', daemon=True)
            t.start()
            proc._threads.append(t)
        self._processes[spec.name] = proc
        return proc

    def _forward(self, name: str, pipe: IO[str], stream_name: str) -> None:
        prefix = f'[{name}] '
        for line in pipe:
            line = line.rstrip('\n')
            with self._write_lock:
                out = self._stdout if stream_name == 'stdout' else self._stderr
                out = out if out is not None else (sys.stdout if stream_name == 'stdout' else sys.stderr)
                out.write(prefix + line + '\n')
                out.flush()
                log = self._log_files.get(name)
                if log is not None and not log.closed:
                    log.write(line + '\n')
        pipe.close()

    # -- watching ---------------------------------------------------------------------
    def exited(self) -> list[ManagedProcess]:
        """Children that have exited, in start order."""
        return [p for p in self._processes.values() if p.popen.poll() is not None]

    def wait_for_exit(self, timeout_s: float | None = None, poll_s: float = 0.05,
                      stop_event: threading.Event | None = None) -> ManagedProcess | None:
        """Block until some child exits (returned), `stop_event` is set or the timeout passes
        (None returned)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            dead = self.exited()
            if dead:
                return dead[0]
            if stop_event is not None and stop_event.is_set():
                return None
            if deadline is not None and time.monotonic() >= deadline:
                return None
            time.sleep(poll_s)

    # -- stopping ---------------------------------------------------------------------
    def _signal_group(self, proc: ManagedProcess, sig: signal.Signals) -> None:
        try:
            os.killpg(proc.pid, sig)  # the child's group: its own children stop too
        except ProcessLookupError:
            pass
        except PermissionError:
            proc.popen.send_signal(sig)
        proc.signal_sent = sig.name

    def _wait_all(self, procs: list[ManagedProcess], timeout_s: float) -> list[ManagedProcess]:
        deadline = time.monotonic() + timeout_s
        while True:
            running = [p for p in procs if p.popen.poll() is None]
            if not running or time.monotonic() >= deadline:
                return running
            time.sleep(0.02)

    def stop(self, name: str) -> ExitReport:
        """Stop one child as `shutdown` stops them all (SIGINT, then SIGTERM, then SIGKILL
        after the timeouts); its report."""
        proc = self._processes[name]
        proc.stop_requested = True
        for sig, timeout_s in ((signal.SIGINT, self.sigint_timeout_s),
                               (signal.SIGTERM, self.sigterm_timeout_s),
                               (signal.SIGKILL, 5.0)):
            if proc.popen.poll() is not None:
                break
            self._signal_group(proc, sig)
            self._wait_all([proc], timeout_s)
        return proc.report()

    def shutdown(self) -> list[ExitReport]:
        """Stop every running child: SIGINT, then SIGTERM, then SIGKILL after the timeouts.

        Returns one report per child ever started, in start order.
        """
        running = [p for p in self._processes.values() if p.popen.poll() is None]
        for p in running:
            p.stop_requested = True
        for sig, timeout_s in ((signal.SIGINT, self.sigint_timeout_s),
                               (signal.SIGTERM, self.sigterm_timeout_s),
                               (signal.SIGKILL, 5.0)):
            if not running:
                break
            for p in running:
                self._signal_group(p, sig)
            running = self._wait_all(running, timeout_s)
        for p in self._processes.values():
            try:
                p.popen.wait(timeout=1.0)
            except subprocess.TimeoutExpired:  # a zombie-proof last resort; should not happen
                pass
            for t in p._threads:
                t.join(timeout=2.0)
        for log in self._log_files.values():
            log.close()
        return [p.report() for p in self._processes.values()]

    def __enter__(self) -> 'Supervisor':
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()
