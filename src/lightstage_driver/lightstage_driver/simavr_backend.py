"""`FirmwareBackend` for the real AVR firmware, compiled and run in simavr.

The harness (`firmware/harness/lightstage_simavr.c`, built with the firmware by
`firmware/Makefile`) loads `build/lightstage.elf` into a simulated ATmega328P at 16 MHz,
bridges UART0 to a pseudo-terminal and reports what the pins do: every word latched into
the 74HC595 chain and every trigger pulse, with simulated-cycle timestamps, so pulse widths
are exact. This object builds the firmware when it is missing or stale (`make`), starts
the harness, keeps the port path stable across restarts (a symlink in a private temp
dir) and collects the observations.

Observations start once the firmware is up: the word 0 it latches at power-up (the
74HC595 outputs are undefined until the first latch) is not reported.
"""
from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

from .firmware_backend import ChildProcessBackend, LatchedWord, TriggerPulse

#: where the firmware sources and Makefile live (override with LIGHTSTAGE_FIRMWARE_DIR)
DEFAULT_FIRMWARE_DIR = Path(__file__).resolve().parent.parent / 'firmware'
#: Debian packages the build needs, named in error messages
DEBIAN_PACKAGES = 'gcc-avr binutils-avr avr-libc libsimavr-dev libelf-dev gcc make'


class SimavrUnavailable(RuntimeError):
    """The firmware or its simavr harness cannot be built or run on this machine."""


def firmware_dir() -> Path:
    return Path(os.environ.get('LIGHTSTAGE_FIRMWARE_DIR', DEFAULT_FIRMWARE_DIR))


def missing_tools() -> list[str]:
    """What is missing to build and simulate the firmware (empty when all is there)."""
    missing = [tool for tool in ('make', 'avr-gcc', 'avr-objcopy', 'cc') if shutil.which(tool) is None]
    if not Path('/usr/include/simavr/sim_avr.h').exists():
        missing.append('simavr headers (/usr/include/simavr)')
    if not (firmware_dir() / 'Makefile').exists():
        missing.append(f'firmware sources ({firmware_dir()}/Makefile)')
    return missing


_build_lock = threading.Lock()


#: build-time pin options of the Makefile (Arduino pin numbers)
PIN_NAMES = ('data', 'clock', 'latch', 'trigger')


def build_firmware(directory: Path | None = None, build_dir: Path | None = None,
                   pins: dict[str, int] | None = None, timeout_s: float = 300.0) -> tuple[Path, Path]:
    """Run `make` in the firmware directory (a no-op when up to date); return (harness, elf).

    `pins` overrides the wiring ({'data': 12, 'clock': 10, 'latch': 11, 'trigger': 8} by
    default, Arduino pin numbers); use a separate `build_dir` for a non-default wiring.
    Serialised across threads and processes (a lock file in the build dir), since several
    test processes may start at once.
    """
    directory = Path(directory or firmware_dir())
    missing = missing_tools()
    if missing:
        raise SimavrUnavailable(f'cannot build the AVR firmware: missing {", ".join(missing)}; '
                                f'install the Debian packages {DEBIAN_PACKAGES}')
    if not (directory / 'Makefile').exists():
        raise SimavrUnavailable(f'no firmware Makefile in {directory}; set LIGHTSTAGE_FIRMWARE_DIR to the '
                                f'lightstage_driver/firmware directory of a source checkout')
    unknown = set(pins or {}) - set(PIN_NAMES)
    if unknown:
        raise ValueError(f'unknown pin name(s) {sorted(unknown)}; the wiring has {list(PIN_NAMES)}')
    build = Path(build_dir) if build_dir else directory / 'build'
    build.mkdir(parents=True, exist_ok=True)
    make_vars = [f'BUILD={build}'] + [f'PIN_{name.upper()}={int(pin)}' for name, pin in (pins or {}).items()]
    with _build_lock, open(build / '.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        result = subprocess.run(['make', '-s', '-C', str(directory), *make_vars, 'firmware', 'harness'],
                                capture_output=True, text=True, timeout=timeout_s)
    if result.returncode != 0:
        raise SimavrUnavailable(f'building the AVR firmware failed (make -C {directory}):\n'
                                f'{result.stdout}{result.stderr}')
    return build / 'lightstage_simavr', build / 'lightstage.elf'


class SimavrBackend(ChildProcessBackend):
    name = 'avr'
    supports_faults = False
    #: one Timer1 tick (0.5 us at 16 MHz): both edges sit on tick boundaries
    pulse_tolerance_us = 0.5

    def __init__(self, throttle: bool = True, start_timeout_s: float = 10.0,
                 directory: str | os.PathLike | None = None, build_dir: str | os.PathLike | None = None,
                 pins: dict[str, int] | None = None, trace_bytes: bool = False):
        """throttle=False lets simulated time run ahead of wall time (as fast as the host
        can); the firmware's millisecond timeouts then elapse faster than the host's.
        `pins` and `build_dir` select a non-default wiring (see `build_firmware`).
        trace_bytes=True logs every byte crossing the UART, with its cycle, to `log_path`."""
        self.throttle = throttle
        self.start_timeout_s = start_timeout_s
        self.directory = Path(directory) if directory else firmware_dir()
        self.build_dir = Path(build_dir) if build_dir else None
        self.pins = dict(pins or {})
        self.trace_bytes = trace_bytes
        self._dir = tempfile.mkdtemp(prefix='lightstage-avr-')
        self._link = os.path.join(self._dir, 'tty')
        self._log_path = os.path.join(self._dir, 'harness.log')
        self._proc: subprocess.Popen | None = None
        self._reader: threading.Thread | None = None
        self._lock = threading.Condition()
        self._words: list[LatchedWord] = []
        self._pulses: list[TriggerPulse] = []
        self._pulse_cycles: list[tuple[int, int]] = []
        self._resets = 0
        self._syncs = 0
        self._stdin_lock = threading.Lock()
        self._recording = False
        self._crashed = ''
        self._output_ended = False
        self.frequency_hz = 16_000_000
        self.pty_path = ''

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self.running:
            return
        harness, elf = build_firmware(self.directory, self.build_dir, self.pins)
        cmd = [str(harness), str(elf)] + ([] if self.throttle else ['--no-throttle']) + \
            (['--trace-bytes'] if self.trace_bytes else [])
        with self._lock:
            self.pty_path = ''
            self._recording = False
            self._crashed = ''
            self._output_ended = False
        log = open(self._log_path, 'ab')
        try:
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          stderr=log, start_new_session=True)
        finally:
            log.close()
        self._reader = threading.Thread(target=self._read, args=(self._proc,), daemon=True,
                                        name='simavr-observer')
        self._reader.start()
        with self._lock:
            # up = the pty exists and the firmware has cleared the chain at power-up
            self._lock.wait_for(lambda: self._recording or self._output_ended, self.start_timeout_s)
            up, pty_path = self._recording, self.pty_path
        if not up:
            self.kill()
            raise SimavrUnavailable(
                f'the simavr harness did not come up within {self.start_timeout_s} s '
                f'(command: {" ".join(cmd)}; log: {self._log_path}: {self._log_tail()})')
        tmp = self._link + '.new'
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(pty_path, tmp)
        os.replace(tmp, self._link)

    @property
    def log_path(self) -> str:
        """The harness's stderr (simavr messages, byte trace)."""
        return self._log_path

    def _log_tail(self) -> str:
        try:
            return Path(self._log_path).read_text(errors='replace')[-500:].strip() or '(empty)'
        except OSError:
            return '(no log)'

    def _read(self, proc: subprocess.Popen) -> None:
        for raw in proc.stdout:
            fields = raw.decode(errors='replace').split()
            if not fields:
                continue
            kind = fields[0]
            with self._lock:
                if kind == 'L':
                    if self._recording:
                        self._words.append(LatchedWord(int(fields[1]) / self.frequency_hz,
                                                       int(fields[2], 16)))
                    else:
                        self._recording = True   # the power-up clear of the chain
                elif kind == 'T':
                    rise, fall = int(fields[1]), int(fields[2])
                    self._pulse_cycles.append((rise, fall))
                    self._pulses.append(TriggerPulse(rise / self.frequency_hz,
                                                     (fall - rise) * 1e6 / self.frequency_hz))
                elif kind == 'PTY':
                    self.pty_path = fields[1]
                elif kind == 'F':
                    self.frequency_hz = int(fields[1])
                elif kind == 'R':
                    self._resets += 1
                elif kind == 'S':
                    self._syncs += 1
                elif kind == 'X':
                    self._crashed = ' '.join(fields[1:])
                self._lock.notify_all()
        with self._lock:
            self._output_ended = True
            self._lock.notify_all()
        self._notify_exit(proc)

    def _request_exit(self, proc) -> None:
        try:
            self._command(b'quit')
        except (OSError, ValueError):
            pass

    def close(self) -> None:
        """Stop and remove the temp dir holding the port link and the harness log."""
        self.stop()
        shutil.rmtree(self._dir, ignore_errors=True)

    def reset(self, timeout_s: float = 5.0) -> None:
        """Pulse the MCU's reset line (what opening the port does to a real Uno): state is
        lost, the firmware boots again and sends EVT_READY. The pty stays the same."""
        if not self.running:
            raise RuntimeError('the simavr harness is not running')
        with self._lock:
            before = self._resets
        self._command(b'reset')
        with self._lock:
            if not self._lock.wait_for(lambda: self._resets > before, timeout_s):
                raise RuntimeError('the simavr harness did not acknowledge the reset')

    def _command(self, line: bytes) -> None:
        with self._stdin_lock:
            self._proc.stdin.write(line + b'\n')
            self._proc.stdin.flush()

    def sync(self, timeout_s: float = 5.0) -> None:
        """Return once every pin event up to the harness's present has been collected (a
        reply read from the port may otherwise arrive before the events that preceded it)."""
        if not self.running:
            raise RuntimeError('the simavr harness is not running')
        with self._lock:
            before = self._syncs
        self._command(b'sync')
        with self._lock:
            if not self._lock.wait_for(lambda: self._syncs > before or not self.running, timeout_s):
                raise RuntimeError(f'the simavr harness did not answer sync within {timeout_s} s')

    @property
    def port(self) -> str:
        return self._link

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    @property
    def crashed(self) -> str:
        """Why the simulated CPU stopped ('' while it runs normally)."""
        with self._lock:
            return self._crashed

    # ------------------------------------------------------------------ observations
    def _sync_if_running(self) -> None:
        if self.running:
            try:
                self.sync()
            except (RuntimeError, OSError):
                pass    # the harness went away: report what was collected

    def led_words(self) -> list[LatchedWord]:
        """Every word latched up to now (the harness is synced first)."""
        self._sync_if_running()
        with self._lock:
            return list(self._words)

    def trigger_pulses(self) -> list[TriggerPulse]:
        self._sync_if_running()
        with self._lock:
            return list(self._pulses)

    def trigger_pulse_cycles(self) -> list[tuple[int, int]]:
        """Trigger pulses as (rising, falling) simulated CPU cycles, for exact widths."""
        self._sync_if_running()
        with self._lock:
            return list(self._pulse_cycles)

    def reset_observations(self) -> None:
        """Forget what was observed up to now (the harness is synced first, so an event
        from before this call cannot turn up afterwards)."""
        self._sync_if_running()
        with self._lock:
            self._words.clear()
            self._pulses.clear()
            self._pulse_cycles.clear()

    def wait_for(self, predicate, timeout_s: float) -> bool:
        """Wait until predicate(led_words, trigger_pulses) holds (checked on every observation)."""
        with self._lock:
            return self._lock.wait_for(lambda: predicate(self._words, self._pulses), timeout_s)
