"""What the camera node needs from a camera: triggers in, stamped frames out.

The camera node (``camera_node.py``) maps ROS onto this small interface; every camera,
simulated or real, implements it in its own module:

- ``sim``    `sim_camera.SimCameraBackend`: renders the sample "on the stage" under the
             trigger's LED intensities and adds the camera's noise (no hardware);
- ``basler`` `basler_backend.BaslerBackend` (pypylon) and ``aravis``
             `aravis_backend.AravisBackend` (any GenICam camera): both
             `triggered_backend.TriggeredBackend`s, which grab in a thread and pair each
             frame with its trigger (`trigger_pairing.TriggerPairing`); a frame that cannot be
             paired for certain is reported through `lost` as a `LostFrame`, never delivered.

No rclpy here: a backend is usable from a notebook or a test.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from lightstage_graph.limits import LimitError, check_exposure_us, check_gain_db


@dataclass(frozen=True)
class Trigger:
    """One camera trigger as the light stage reported it (an IlluminationState).

    stamp_ns         trigger time (ROS time, ns): the frame's acquisition time
    sequence         the driver's trigger counter
    led_intensities  (32,) float32, site-major LED drive in [0, 1]
    exposure_us      exposure / LED on-time [us]
    gain_db          camera gain [dB]; NaN = the camera's default gain
    """
    stamp_ns: int
    sequence: int
    led_intensities: np.ndarray
    exposure_us: int
    gain_db: float = math.nan


@dataclass(frozen=True)
class Frame:
    """One image a backend produced for a trigger.

    image      uint16 (H, W), gray levels MSB-aligned in 16 bits (``mono16``, as Basler
               cameras deliver 10-bit data: value << 6)
    bit_depth  significant bits of the camera (10: gray level = value >> 6)
    """
    trigger: Trigger
    image: np.ndarray
    bit_depth: int
    info: dict = field(default_factory=dict)


@dataclass(frozen=True)
class LostFrame:
    """A trigger that produced no usable frame, and why (failed buffer, BlockID gap, ...)."""
    trigger: Trigger
    reason: str


class CameraError(RuntimeError):
    """The camera cannot be used (missing, unplugged, refused a setting); says what to do."""


def check_trigger(trigger: Trigger) -> None:
    """Refuse a trigger whose values no camera can take (LimitError naming the field): gain_db
    in the shared range or NaN (the camera's default), exposure_us in range or 0 (the
    camera's default), 32 LED intensities in [0, 1]. The driver checks requests; a trigger
    from a bag, another publisher or an older driver is checked here again."""
    check_gain_db(trigger.gain_db)
    check_exposure_us(trigger.exposure_us, zero_is_default=True)
    leds = np.asarray(trigger.led_intensities)
    if leds.shape != (32,):
        raise LimitError(f'intensities must hold 32 LED values, got shape {leds.shape}')
    if not (np.isfinite(leds).all() and leds.min() >= 0 and leds.max() <= 1):
        raise LimitError('intensities must be numbers in 0 .. 1, got '
                         f'{leds[~(np.isfinite(leds) & (leds >= 0) & (leds <= 1))][:3].tolist()}')


def hand_trigger(backend: 'CameraBackend', trigger: Trigger) -> str:
    """Give `trigger` to `backend`: '' if it took it, else why not. Nothing a trigger holds
    may stop the camera, so no exception gets out: values out of range are refused naming the
    field, and whatever else the backend trips over is the reason."""
    try:
        check_trigger(trigger)
    except LimitError as exc:
        return f'bad trigger values: {exc}'
    try:
        backend.trigger(trigger)
    except Exception as exc:  # noqa: BLE001 - one trigger's failure must not end the node
        return str(exc) if isinstance(exc, (ValueError, CameraError)) else f'{type(exc).__name__}: {exc}'
    return ''


def to_mono16(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """An LSB-aligned camera image (uint8 / uint16, `bit_depth` significant bits) -> uint16
    MSB-aligned (``mono16``: a 10-bit value v becomes v << 6), as the project publishes."""
    if not 8 <= int(bit_depth) <= 16:
        raise ValueError(f'bit_depth must be 8..16, got {bit_depth}')
    return np.asarray(image).astype(np.uint16) << np.uint16(16 - int(bit_depth))


@dataclass
class BackendStatus:
    """Health of a backend for /diagnostics: ok, a one-line message, key/value details."""
    ok: bool
    message: str
    values: dict = field(default_factory=dict)


class CameraBackend(ABC):
    """A camera driven by light-stage triggers; frames go to the `deliver` callback."""

    name = 'abstract'

    def __init__(self, deliver: Callable[[Frame], None],
                 lost: Callable[[LostFrame], None] | None = None):
        self._deliver = deliver
        self._lost = lost or (lambda _lost_frame: None)

    @abstractmethod
    def trigger(self, trigger: Trigger) -> None:
        """A trigger fired: deliver its frame (now, or later from a grab thread)."""

    @abstractmethod
    def status(self) -> BackendStatus:
        """Current health, for /diagnostics."""

    def close(self) -> None:
        """Release the camera (default: nothing to release)."""
