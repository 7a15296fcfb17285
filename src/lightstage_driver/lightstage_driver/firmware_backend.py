"""What a firmware under test looks like to the driver's test suite and benchmark.

Two backends implement it: the Python firmware simulator
(`lightstage_driver.sim_backend.PythonSimBackend`) and the compiled AVR firmware running
in simavr (`lightstage_driver.simavr_backend.SimavrBackend`). The driver opens `port`
like a USB serial port; the backend watches the stage's outputs (the LED word latched
into the shift-register chain, the camera trigger pin) and reports them.

Times reported here are on the backend's own clock: seconds since the backend's firmware
started (simulated time for simavr, host monotonic time for the Python simulator).
Pulse widths are in microseconds as measured on the pins (simulated cycles for simavr).
"""
from __future__ import annotations

import abc
import subprocess
from collections.abc import Callable
from dataclasses import dataclass

from .firmware_sim import remove_link


@dataclass(frozen=True)
class LatchedWord:
    """One LED word latched to the LEDs (bit i = LED i, site-major)."""
    time_s: float
    word: int


@dataclass(frozen=True)
class TriggerPulse:
    """One camera trigger pulse: rising edge time and width."""
    start_s: float
    width_us: float


class FirmwareBackend(abc.ABC):
    """A firmware the driver can talk to over a pseudo-terminal, with its pins observed.

    Lifecycle: `start()` brings the firmware up (power-on: LEDs off, `EVT_READY` sent);
    `stop()` shuts it down cleanly; `kill()` cuts it off abruptly (like pulling the USB
    cable: the pty closes, the host's reads fail); `restart()` powers it up again after
    `stop()` or `kill()`. `port` stays the same path across restarts (a symlink to the
    current pty slave, like /dev/serial/by-id/...), so a driver that reconnects by path
    finds the firmware again. Usable as a context manager (start on enter, stop on exit).
    """

    #: short name used in test ids and benchmark output ("python", "avr")
    name: str = 'backend'
    #: True if `set_faults` is implemented (only the Python simulator has fault knobs)
    supports_faults: bool = False
    #: how far a measured trigger pulse width may be from the requested exposure [us]
    pulse_tolerance_us: float = 10.0

    @abc.abstractmethod
    def start(self) -> None:
        """Power the firmware up. Returns once `port` can be opened."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Shut the firmware down cleanly and release its pty. Idempotent."""

    @abc.abstractmethod
    def kill(self) -> None:
        """Cut the firmware off abruptly (process killed, pty closed without warning)."""

    def restart(self) -> None:
        """Power up again after `stop()` or `kill()` (state lost, as after a reset)."""
        self.stop()
        self.start()

    @property
    @abc.abstractmethod
    def port(self) -> str:
        """Path the driver opens (stable across restarts)."""

    @property
    @abc.abstractmethod
    def running(self) -> bool:
        """True while the firmware is up."""

    @abc.abstractmethod
    def led_words(self) -> list[LatchedWord]:
        """Every LED word latched since start or the last `reset_observations()`, in order."""

    @abc.abstractmethod
    def trigger_pulses(self) -> list[TriggerPulse]:
        """Every complete trigger pulse since start or the last `reset_observations()`."""

    @abc.abstractmethod
    def reset_observations(self) -> None:
        """Forget the recorded LED words and trigger pulses."""

    def current_word(self) -> int:
        """The LED word latched now (0 if none was latched yet)."""
        words = self.led_words()
        return words[-1].word if words else 0

    def set_faults(self, **faults) -> None:
        """Inject faults (Python simulator only; see `firmware_sim.FaultConfig`)."""
        raise NotImplementedError(f'{type(self).__name__} has no fault injection')

    def __enter__(self) -> 'FirmwareBackend':
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


class ChildProcessBackend(FirmwareBackend):
    """A backend whose firmware runs in a child process (`_proc`) read by a thread (`_reader`).

    Subclasses start both in `start()` and say how to ask the child to exit politely
    (`_request_exit`); stopping, killing and reaping are the same for every such backend.
    Their reader calls `_notify_exit(proc)` when the child's output ends: `port` stops pointing
    at the child's pty (a SIGKILLed child cannot remove its link itself), and the child's exit
    status goes to `on_exit` (if set) from the reader's thread, so an owner that did not stop
    the child learns at once that its firmware is gone. An owner that stops the child on
    purpose clears `on_exit` first.
    """

    _proc = None
    _reader = None
    pty_path = ''      # the child's current pty (`port` links to it)
    #: called with the exit status (None: still running after its output ended) when a child exits
    on_exit: Callable[[int | None], None] | None = None

    def _notify_exit(self, proc) -> None:
        remove_link(self.port, self.pty_path)
        callback = self.on_exit
        if callback is None:
            return
        try:
            code = proc.wait(5)
        except subprocess.TimeoutExpired:
            code = None
        callback(code)

    def _request_exit(self, proc) -> None:
        proc.terminate()

    def stop(self) -> None:
        proc = self._proc
        if proc is None:
            return
        if proc.poll() is None:
            self._request_exit(proc)
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self._reap(proc)

    def kill(self) -> None:
        proc = self._proc
        if proc is None:
            return
        if proc.poll() is None:
            proc.kill()  # SIGKILL: an abrupt disconnect, as a pulled USB cable
        proc.wait()
        self._reap(proc)

    def _reap(self, proc) -> None:
        if self._reader is not None:
            self._reader.join(5)
        for stream in (proc.stdin, proc.stdout):
            if stream:
                try:
                    stream.close()
                except OSError:
                    pass
        self._proc = None

    def close(self) -> None:
        """Stop the child and remove what the backend created."""
        self.stop()

    def __exit__(self, *exc) -> None:
        self.close()
