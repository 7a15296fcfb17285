"""`FirmwareBackend` for the Python firmware simulator, run as its own process.

The simulator process (`firmware_sim`) owns the pty; this object starts it, keeps the
port path stable across restarts (a symlink in a private temp dir), sends fault commands
on its stdin and collects the LED words and trigger pulses it reports on stdout.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import weakref
from pathlib import Path

from .firmware_backend import ChildProcessBackend, LatchedWord, TriggerPulse
from .firmware_model import FirmwareLimits

_PACKAGE_PARENT = str(Path(__file__).resolve().parent.parent)


class PythonSimBackend(ChildProcessBackend):
    name = 'python'
    supports_faults = True
    pulse_tolerance_us = 1.0   # the model's timer is exact on the firmware clock

    def __init__(self, pwm_bits: int = 0, latency_ms: float = 0.0, emulate_baud: int = 0,
                 clock_offset_us: int = 0, min_exposure_us: int = 20,
                 max_exposure_us: int = 2_000_000, start_timeout_s: float = 10.0):
        FirmwareLimits(pwm_bits=pwm_bits, min_exposure_us=min_exposure_us,
                       max_exposure_us=max_exposure_us)    # refuse bad limits here, not in the child
        self.options = ['--pwm-bits', str(pwm_bits), '--latency-ms', str(latency_ms),
                        '--emulate-baud', str(emulate_baud), '--clock-offset-us', str(clock_offset_us),
                        '--min-exposure-us', str(min_exposure_us),
                        '--max-exposure-us', str(max_exposure_us)]
        self.start_timeout_s = start_timeout_s
        self._dir = tempfile.mkdtemp(prefix='lightstage-sim-')
        self._link = os.path.join(self._dir, 'tty')
        # the temp dir goes even if close() is never called (the process dies on its own when
        # our end of its stdin closes)
        self._cleanup = weakref.finalize(self, shutil.rmtree, self._dir, ignore_errors=True)
        self._proc: subprocess.Popen | None = None
        self._reader: threading.Thread | None = None
        self._lock = threading.Condition()
        self._words: list[LatchedWord] = []
        self._pulses: list[TriggerPulse] = []
        self._acks: dict[int, dict] = {}
        self._ready = 0
        self._next_id = 0
        self.pty_path = ''

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self.running:
            return
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(filter(None, [_PACKAGE_PARENT, env.get('PYTHONPATH')]))
        cmd = [sys.executable, '-m', 'lightstage_driver.firmware_sim', '--link', self._link,
               '--control', '--observe', *self.options]
        with self._lock:
            ready_before = self._ready
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
                                      start_new_session=True)
        self._reader = threading.Thread(target=self._read, args=(self._proc,), daemon=True,
                                        name='pysim-observer')
        self._reader.start()
        with self._lock:
            if not self._lock.wait_for(lambda: self._ready > ready_before or self._proc.poll() is not None,
                                       self.start_timeout_s) or self._ready == ready_before:
                self.kill()
                raise RuntimeError(f'firmware simulator did not come up within {self.start_timeout_s} s '
                                   f'(command: {" ".join(cmd)})')

    def _read(self, proc: subprocess.Popen) -> None:
        for raw in proc.stdout:
            try:
                record = json.loads(raw)
            except ValueError:
                continue    # the human-readable 'PTY ...' line
            with self._lock:
                ev = record.get('ev')
                if ev == 'latch':
                    self._words.append(LatchedWord(record['t'], record['word']))
                elif ev == 'pulse':
                    self._pulses.append(TriggerPulse(record['t'], record['width_us']))
                elif ev == 'ready':
                    self.pty_path = record['pty']
                    self._ready += 1
                elif ev == 'ack':
                    self._acks[record['id']] = record
                self._lock.notify_all()
        self._notify_exit(proc)

    def close(self) -> None:
        """Stop and remove the temp dir holding the port link."""
        self.stop()
        self._cleanup()

    @property
    def port(self) -> str:
        return self._link

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        """The simulator process's id while it runs."""
        proc = self._proc
        return proc.pid if proc is not None and proc.poll() is None else None

    # ------------------------------------------------------------------ observations
    def led_words(self) -> list[LatchedWord]:
        with self._lock:
            return list(self._words)

    def trigger_pulses(self) -> list[TriggerPulse]:
        with self._lock:
            return list(self._pulses)

    def reset_observations(self) -> None:
        with self._lock:
            self._words.clear()
            self._pulses.clear()

    def wait_for(self, predicate, timeout_s: float) -> bool:
        """Wait until predicate(led_words, trigger_pulses) holds (checked on every observation)."""
        with self._lock:
            return self._lock.wait_for(lambda: predicate(self._words, self._pulses), timeout_s)

    # ------------------------------------------------------------------ faults
    def _control(self, message: dict, timeout_s: float = 5.0) -> dict:
        if not self.running:
            raise RuntimeError('firmware simulator is not running')
        with self._lock:
            self._next_id += 1
            ident = self._next_id
        self._proc.stdin.write((json.dumps({**message, 'id': ident}) + '\n').encode())
        self._proc.stdin.flush()
        with self._lock:
            if not self._lock.wait_for(lambda: ident in self._acks, timeout_s):
                raise RuntimeError(f'firmware simulator did not acknowledge {message}')
            return self._acks.pop(ident)

    def set_faults(self, **faults) -> None:
        """Change `firmware_sim.FaultConfig` fields in the running simulator."""
        self._control({'faults': faults})

    def disconnect(self, reconnect_after_s: float | None = None) -> None:
        """Close the pty like a pulled cable; a new one (reset firmware) after the delay."""
        with self._lock:
            ready_before = self._ready
        self._control({'disconnect': reconnect_after_s})
        if reconnect_after_s is not None:
            with self._lock:
                self._lock.wait_for(lambda: self._ready > ready_before, reconnect_after_s + 5.0)


SIM_SCHEME = 'sim'


def is_sim_url(port: str) -> bool:
    return port == SIM_SCHEME or port.startswith(SIM_SCHEME + '://')


def backend_from_url(port: str) -> PythonSimBackend:
    """`sim` or `sim://?pwm_bits=8&latency_ms=1&emulate_baud=115200` -> a simulator backend."""
    from urllib.parse import parse_qsl, urlsplit
    if not is_sim_url(port):
        raise ValueError(f'{port!r} is not a simulator URL (use `sim` or `sim://?option=value`)')
    options = dict(parse_qsl(urlsplit(port).query)) if '://' in port else {}
    kinds = {'pwm_bits': int, 'latency_ms': float, 'emulate_baud': int, 'clock_offset_us': int,
             'min_exposure_us': int, 'max_exposure_us': int}
    unknown = set(options) - set(kinds)
    if unknown:
        raise ValueError(f'unknown simulator option(s) {sorted(unknown)} in {port!r}; known: {sorted(kinds)}')
    try:
        return PythonSimBackend(**{key: kinds[key](value) for key, value in options.items()})
    except ValueError as exc:
        raise ValueError(f'bad simulator option in {port!r}: {exc}') from exc
