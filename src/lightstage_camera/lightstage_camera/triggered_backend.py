"""A real, triggered camera behind the `CameraBackend` interface: one worker thread that
opens the camera (and reopens it after a fault), applies each trigger's exposure and gain,
fires software triggers, grabs, and pairs frames with triggers (`TriggerPairing`).

Subclasses (`basler_backend`, `aravis_backend`) implement only the device calls (the
``_device_*`` methods). Trigger sources:

- a hardware line (``Line1``: the stage's trigger pin wired to the camera): the frame is
  taken when the firmware pulses the pin; the camera exposes for the pulse width when it
  can (``ExposureMode=TriggerWidth``: the firmware holds the pin high for exactly the
  exposure), and the trigger announced on ``/illumination`` is paired with it afterwards;
- ``Software``: the backend fires the trigger itself when it is announced, after waiting
  for the camera to be ready for it (a trigger sent too early is dropped by the camera).

A fault (camera missing, unplugged, a grab error) loses every waiting trigger with the
reason, closes the camera and reopens it every ``reopen_period_s``. No rclpy here.
"""
from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from typing import Callable, Sequence

from .camera_backend import BackendStatus, CameraBackend, CameraError, Frame, LostFrame, Trigger
from .trigger_pairing import GrabbedFrame, TriggerPairing

SOFTWARE = 'Software'
GAIN_TOLERANCE_DB = 0.05   # cameras quantise gain; closer than this counts as "the same"
RATE_WINDOW_S = 5.0        # /diagnostics frame rate: frames delivered over the last 5 s
PIXEL_FORMATS = {'Mono8': 8, 'Mono10': 10, 'Mono12': 12, 'Mono16': 16}


def parse_features(features: Sequence[str]) -> list[tuple[str, str | None]]:
    """``["Name=Value", "Command", ...]`` -> [(name, value or None for a command to execute)];
    ValueError naming a malformed entry."""
    out = []
    for item in features:
        name, sep, value = (part.strip() for part in str(item).partition('='))
        if not name.isidentifier():
            raise ValueError(f'camera feature {item!r} is not Name=Value or a command Name (e.g. '
                             'ImageFileMode=On, UserSetLoad)')
        out.append((name, value if sep else None))
    return out


def check_pixel_format(pixel_format: str) -> int:
    """Bit depth of a supported pixel format; ValueError naming the supported ones."""
    if pixel_format not in PIXEL_FORMATS:
        raise ValueError(f'pixel format {pixel_format!r} is not supported; use one of '
                         f'{", ".join(PIXEL_FORMATS)} (published as mono16, MSB-aligned)')
    return PIXEL_FORMATS[pixel_format]


class TriggeredBackend(CameraBackend):
    """Base of the real-camera backends; see the module docstring."""

    name = 'triggered'

    def __init__(self, deliver: Callable[[Frame], None], lost: Callable[[LostFrame], None] | None = None,
                 *, trigger_source: str = 'Line1', exposure_us: float = 30000.0, gain_db: float = 0.0,
                 frame_timeout_s: float = 1.0, reopen_period_s: float = 1.0):
        super().__init__(deliver, lost)
        self.trigger_source = str(trigger_source)
        self.exposure_us = float(exposure_us)   # for triggers that carry none (0)
        self.gain_db = float(gain_db)           # for triggers that ask for the default (NaN)
        self.frame_timeout_s = float(frame_timeout_s)
        self.reopen_period_s = float(reopen_period_s)
        self.pairing = TriggerPairing(self._time_limit_s, early_limit_s=self.frame_timeout_s)
        self.device_info: dict = {}
        self.error = ''                   # why the camera is not open ('' while it is)
        self.last_fault = ''
        self.reopens = 0
        self.frames = 0
        self.lost_unpaired = 0   # lost without reaching the pairing (its own count: `pairing.lost`)
        self.actual_exposure_us = math.nan
        self.actual_gain_db = math.nan
        self._frame_times: deque[float] = deque(maxlen=4096)
        self._mismatched: dict[int, str] = {}  # trigger sequence -> why its frame is not its own
        self._taken_with: dict[int, tuple[float, float]] = {}  # sequence -> (exposure, gain) read back
        self._open = False
        self._triggers: queue.Queue[Trigger] = queue.Queue()
        self._stop = threading.Event()
        self._opened = threading.Event()   # the first open attempt finished (either way)
        self._emit_lock = threading.Lock()    # outcomes come from the control and grab threads
        self._grabbing = threading.Event()
        self._grab_thread: threading.Thread | None = None
        self._grab_fault = ''                 # set by the grab thread, handled by the control thread
        self._thread = threading.Thread(target=self._run, name=f'{self.name}-control', daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ device calls
    def _device_open(self) -> dict:
        """Open and configure (trigger on, pixel format, ...), start grabbing; returns a
        description (model, serial, pixel_format, bit_depth, ...). Raises CameraError."""
        raise NotImplementedError

    def _device_close(self) -> None:
        raise NotImplementedError

    def _device_apply(self, exposure_us: float, gain_db: float) -> tuple[float, float]:
        """Set exposure [us] and gain [dB]; return the values the camera took (read back).
        Raises ValueError for a value the camera cannot meet (naming its range)."""
        raise NotImplementedError

    def _device_exposure_by_pulse(self) -> bool:
        """True if the camera exposes for the trigger pulse's width (hardware trigger)."""
        return False

    def _device_wait_ready(self, timeout_s: float) -> bool:
        raise NotImplementedError

    def _device_fire(self) -> None:
        raise NotImplementedError

    def _device_retrieve(self, timeout_s: float) -> GrabbedFrame | None:
        """The next grabbed buffer, or None after `timeout_s`. Raises CameraError when the
        camera is gone (unplugged)."""
        raise NotImplementedError

    def _device_temperature(self) -> float | None:
        return None

    # ------------------------------------------------------------------ interface
    @property
    def software_trigger(self) -> bool:
        return self.trigger_source == SOFTWARE

    def wait_open(self, timeout_s: float) -> bool:
        """Wait for the first open attempt; True if the camera is open."""
        self._opened.wait(timeout_s)
        return self._open

    def trigger(self, trigger: Trigger) -> None:
        self._triggers.put(trigger)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)

    def status(self) -> BackendStatus:
        now = time.monotonic()
        rate = sum(1 for t in list(self._frame_times) if now - t <= RATE_WINDOW_S) / RATE_WINDOW_S
        temperature = self._device_temperature() if self._open else None
        values = {**self.device_info, 'trigger_source': self.trigger_source, 'frames': self.frames,
                  'frame_rate_hz': f'{rate:.2f}', 'frames_lost': self.pairing.lost + self.lost_unpaired,
                  'grab_timeouts': self.pairing.timeouts, 'unclaimed_frames': self.pairing.unclaimed,
                  'exposure_us_actual': f'{self.actual_exposure_us:.1f}',
                  'gain_db_actual': f'{self.actual_gain_db:.3f}', 'reopens': self.reopens,
                  'last_fault': self.last_fault}
        if temperature is not None:
            values['temperature_c'] = f'{temperature:.1f}'
        if not self._open:
            return BackendStatus(False, f'camera not open: {self.error}', values)
        model = self.device_info.get('model', self.name)
        return BackendStatus(True, f'{model} {self.device_info.get("serial", "")} open, '
                                   f'trigger {self.trigger_source}', values)

    # ------------------------------------------------------------------ worker
    def _time_limit_s(self, trigger: Trigger) -> float:
        return self._exposure_of(trigger) / 1e6 + self.frame_timeout_s

    def _exposure_of(self, trigger: Trigger) -> float:
        return float(trigger.exposure_us) if trigger.exposure_us > 0 else self.exposure_us

    def _gain_of(self, trigger: Trigger) -> float:
        return self.gain_db if not math.isfinite(trigger.gain_db) else float(trigger.gain_db)

    def _lose(self, trigger: Trigger, reason: str) -> None:
        """A trigger lost before it reached the pairing (camera closed, refused, not ready)."""
        with self._emit_lock:
            self.lost_unpaired += 1
            self._lost(LostFrame(trigger, reason))

    def _emit(self, outcomes) -> None:
        with self._emit_lock:
            self._emit_locked(outcomes)

    def _emit_locked(self, outcomes) -> None:
        for outcome in outcomes:
            if isinstance(outcome, Frame):
                reason = self._mismatched.pop(outcome.trigger.sequence, None)
                if reason is not None:
                    self.lost_unpaired += 1
                    self._lost(LostFrame(outcome.trigger, reason))
                    continue
                self.frames += 1
                self._frame_times.append(time.monotonic())
                exposure, gain = self._taken_with.pop(outcome.trigger.sequence, (math.nan, math.nan))
                outcome.info.update(exposure_us=exposure, gain_db=gain)
                self._deliver(outcome)
            else:
                self._mismatched.pop(outcome.trigger.sequence, None)
                self._taken_with.pop(outcome.trigger.sequence, None)
                self._lost(outcome)

    def _run(self) -> None:
        """The control thread: opens (and reopens) the camera, handles triggers in order."""
        next_open = 0.0
        while not self._stop.is_set():
            if not self._open:
                if time.monotonic() >= next_open:
                    self._try_open()
                    next_open = time.monotonic() + self.reopen_period_s
                    self._opened.set()
                self._lose_queued(f'camera not open: {self.error}')
                if not self._open:
                    self._stop.wait(0.02)
                continue
            if self._grab_fault:
                self._fault(self._grab_fault)
                continue
            try:
                trigger = self._triggers.get(timeout=0.02)
            except queue.Empty:
                continue
            try:
                self._handle_trigger(trigger)
            except Exception as exc:  # noqa: BLE001 - a device error of any kind is a fault
                self._fault(str(exc) if isinstance(exc, CameraError) else f'{type(exc).__name__}: {exc}')
        self._stop_grabbing()
        self._lose_queued('camera backend closed')
        self._emit(self.pairing.fail_all('camera backend closed'))
        if self._open:
            self._safe_close()

    def _grab(self) -> None:
        """The grab thread (one per opening): frames in, paired; triggers past their limit lost.
        Separate from the control thread, so that waiting for trigger-ready never keeps the
        camera's buffers from being emptied."""
        while self._grabbing.is_set():
            try:
                grabbed = self._device_retrieve(0.02)
                if grabbed is not None:
                    self._emit(self.pairing.add_frame(grabbed))
                self._emit(self.pairing.expire())
            except Exception as exc:  # noqa: BLE001 - a device error of any kind is a fault
                self._grab_fault = str(exc) if isinstance(exc, CameraError) else f'{type(exc).__name__}: {exc}'
                return

    def _stop_grabbing(self) -> None:
        self._grabbing.clear()
        if self._grab_thread is not None:
            self._grab_thread.join(timeout=10.0)
            self._grab_thread = None

    def _try_open(self) -> None:
        try:
            self.device_info = self._device_open()
            self.actual_exposure_us, self.actual_gain_db = self._device_apply(self.exposure_us, self.gain_db)
        except Exception as exc:  # noqa: BLE001 - any failure to open is reported the same way
            self.error = str(exc) if isinstance(exc, CameraError) else f'{type(exc).__name__}: {exc}'
            self._safe_close()
            return
        if self.error:
            self.reopens += 1
        self._open, self.error, self._grab_fault = True, '', ''
        self._grabbing.set()
        self._grab_thread = threading.Thread(target=self._grab, name=f'{self.name}-grab', daemon=True)
        self._grab_thread.start()

    def _fault(self, reason: str) -> None:
        self._stop_grabbing()
        self.last_fault = reason
        self._open, self.error = False, f'{reason}; reopening every {self.reopen_period_s:g} s'
        self._safe_close()
        self._emit(self.pairing.fail_all(f'camera fault: {reason}'))

    def _safe_close(self) -> None:
        try:
            self._device_close()
        except Exception:  # noqa: BLE001 - closing a camera that is gone may fail; it is closed
            pass

    def _lose_queued(self, reason: str) -> None:
        while True:
            try:
                trigger = self._triggers.get_nowait()
            except queue.Empty:
                return
            self._lose(trigger, reason)

    def _handle_trigger(self, trigger: Trigger) -> None:
        exposure, gain = self._exposure_of(trigger), self._gain_of(trigger)
        if self.software_trigger:
            try:
                self.actual_exposure_us, self.actual_gain_db = self._device_apply(exposure, gain)
            except ValueError as exc:
                self._lose(trigger, f'the camera cannot take this trigger\'s settings: {exc}')
                return
            if not self._device_wait_ready(self._time_limit_s(trigger)):
                self._lose(trigger, 'the camera was not ready for the trigger within '
                                    f'{self._time_limit_s(trigger):.3g} s')
                return
            self._taken_with[trigger.sequence] = (self.actual_exposure_us, self.actual_gain_db)
            self._emit(self.pairing.add_trigger(trigger))
            self._device_fire()
            return
        # hardware trigger: the frame was (or is being) taken when the pin pulsed, with the
        # settings the camera had then; one taken with other settings is not the frame asked for
        by_pulse = self._device_exposure_by_pulse()
        wrong_gain = abs(gain - self.actual_gain_db) > GAIN_TOLERANCE_DB
        wrong_exposure = not by_pulse and abs(exposure - self.actual_exposure_us) > max(1.0, 1e-3 * exposure)
        if wrong_gain or wrong_exposure:
            taken, asked = f'{self.actual_gain_db:.2f} dB', f'{gain:.2f} dB'
            if not by_pulse:   # with TriggerWidth the pulse is the exposure: always the asked one
                taken, asked = f'{taken}, {self.actual_exposure_us:.0f} us', f'{asked}, {exposure:.0f} us'
            self._mismatched[trigger.sequence] = (
                f'the frame was taken at {taken}, the trigger asked for {asked} (a '
                'hardware-triggered camera is set when the trigger is announced, after it fired); '
                'the camera has them now for the next triggers')
        else:
            self._taken_with[trigger.sequence] = (self.actual_exposure_us, self.actual_gain_db)
        self._emit(self.pairing.add_trigger(trigger))
        if wrong_gain or wrong_exposure:
            try:
                self.actual_exposure_us, self.actual_gain_db = self._device_apply(exposure, gain)
            except ValueError as exc:
                self._mismatched[trigger.sequence] += f' (no: the camera refused them: {exc})'
