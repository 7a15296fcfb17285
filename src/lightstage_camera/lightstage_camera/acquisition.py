"""Model acquisition: one averaged image per single LED, written into a capture folder.

The paper's model capture (Sect. "Scene Model Acquisition"): light each of the 32 LEDs
alone, expose long, average several frames, and keep the result as the sample's relightable
model. This module is that procedure without ROS (the acquisition node maps an action onto
it; tests drive it with a `sim_camera.SimCamera` directly):

1. `CaptureSettings` + `led_patterns`: what to light (one LED at full power per image,
   site-major ``led = site * 4 + channel``), for how long, at which gain, how many frames;
2. `check_exposure` (the preview): one frame per LED before the long capture; an LED image
   with more clipped pixels than allowed stops the capture *before* it starts, naming the LED
   and suggesting an exposure;
3. `capture_model`: frames of each LED in chunks (one stage request each), averaged in
   float64 (`FrameAverager`), pixels that reached the camera's maximum in any frame counted;
   `cancelled()` is checked between chunks and nothing is written on cancel;
4. `acquire_pose`: 1-3 in order, then the pose written into the capture folder
   (`capture_destination`: checked before anything is lit and again before writing, written
   atomically). A capture that cannot be written (disk full, the pose appeared meanwhile)
   is not lost: it goes to a rescue file (`rescue`).

A frame source is a callable ``grab(led_patterns (32, k)) -> list of k uint16 frames``
(MSB-aligned ``mono16``, one per pattern, in pattern order). The acquisition node builds it
from the driver's ApplyPatterns and `frames.ImageMatcher`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from lightstage_graph.frames import mono16_to_gray
from lightstage_physics.errors import AcquisitionError, CaptureCancelled, DestinationError, ExposureError
from lightstage_physics.rig import CHANNELS, N_CHANNELS, N_SITES, Rig

from .capture_destination import (Destination, capture_rig, check_destination, folder_rig,
                                  write_model)
from .capture_settings import CaptureSettings
from .rescue import RescuedModel, rescue_message

__all__ = ["FrameAverager", "CapturedModel", "ExposureCheck", "led_name", "led_patterns",
           "check_exposure", "capture_model", "acquire_pose"]

Grab = Callable[[np.ndarray], Sequence[np.ndarray]]


# --------------------------------------------------------------------------- plan


def led_name(led: int, n_sites: int = N_SITES) -> str:
    """``s<site>_<channel>`` of a site-major LED index (the image's file name stem)."""
    if not 0 <= int(led) < n_sites * N_CHANNELS:
        raise ValueError(f"LED {led} out of range 0..{n_sites * N_CHANNELS - 1}")
    return f"s{int(led) // N_CHANNELS}_{CHANNELS[int(led) % N_CHANNELS]}"


def led_patterns(n_sites: int = N_SITES) -> np.ndarray:
    """``(n_leds, n_leds)`` float32: column ``led`` lights that LED alone at full power."""
    return np.eye(n_sites * N_CHANNELS, dtype=np.float32)


# --------------------------------------------------------------------------- averaging


class FrameAverager:
    """Running mean of frames in float64, and which pixels ever reached the camera's maximum.

    A pixel that hit the maximum in any frame was clipped there: its average is biased low
    (the camera cannot report more), so it is counted as saturated.
    """

    def __init__(self, max_level: int):
        self.max_level = float(max_level)
        self.count = 0
        self._sum: np.ndarray | None = None
        self._saturated: np.ndarray | None = None

    def add(self, gray: np.ndarray) -> None:
        gray = np.asarray(gray)
        if gray.ndim != 2:
            raise ValueError(f"a frame must be an (H, W) image, got shape {gray.shape}")
        if self._sum is None:
            self._sum = np.zeros(gray.shape, np.float64)
            self._saturated = np.zeros(gray.shape, bool)
        elif gray.shape != self._sum.shape:
            raise ValueError(f"frame of {gray.shape[1]}x{gray.shape[0]} px after frames of "
                             f"{self._sum.shape[1]}x{self._sum.shape[0]} px; the camera changed "
                             "its image size during the capture")
        self._sum += gray
        self._saturated |= gray >= self.max_level
        self.count += 1

    @property
    def shape(self) -> tuple[int, int] | None:
        return None if self._sum is None else tuple(self._sum.shape)

    def mean(self) -> np.ndarray:
        if self.count == 0:
            raise ValueError("no frames averaged yet")
        return (self._sum / self.count).astype(np.float32)

    @property
    def saturated(self) -> np.ndarray:
        if self._saturated is None:
            raise ValueError("no frames averaged yet")
        return self._saturated

    @property
    def saturated_pixels(self) -> int:
        return 0 if self._saturated is None else int(self._saturated.sum())


# --------------------------------------------------------------------------- the preview


@dataclass
class ExposureCheck:
    """One frame per LED at the capture setting: how close each LED image comes to clipping.

    peak_level   per LED, the 99.9th percentile gray level of its frame
    clipped      per LED, the fraction of pixels at the camera's maximum
    image_shape  (H, W) of the camera's frames
    """
    settings: CaptureSettings
    peak_level: np.ndarray
    clipped: np.ndarray
    image_shape: tuple[int, int]

    @property
    def brightest_led(self) -> int:
        return int(np.argmax(self.peak_level + self.clipped * 1e6))

    def suggested_exposure_us(self, target_fraction: float = 0.8) -> int:
        """An exposure that puts the brightest LED image's 99.9th percentile at
        `target_fraction` of the range, assuming the camera's response is linear in exposure.
        When that LED is clipped its true level is unknown: half the exposure, at most."""
        s = self.settings
        peak = float(np.max(self.peak_level))
        factor = target_fraction * s.max_level / max(peak, 1.0)
        if np.any(self.clipped > 0):
            factor = min(factor, 0.5)
        return max(1, int(s.exposure_us * factor))

    def problems(self) -> list[str]:
        """Human-readable problems: LED images with more clipped pixels than allowed."""
        s = self.settings
        bad = np.flatnonzero(self.clipped > s.max_saturated_fraction)
        return [f"{led_name(i, s.n_sites)} has {100 * self.clipped[i]:.2g} % of its pixels at the "
                f"camera's maximum ({s.max_level})" for i in bad]


def check_exposure(grab: Grab, settings: CaptureSettings,
                   cancelled: Callable[[], bool] | None = None) -> ExposureCheck:
    """The preview: one frame per LED; raises ExposureError if an LED image clips too much."""
    patterns = led_patterns(settings.n_sites)
    peaks, clipped, shape = [], [], None
    for start in range(0, settings.n_leds, settings.frames_per_request):
        if cancelled is not None and cancelled():
            raise CaptureCancelled("cancelled during the exposure preview; nothing was written")
        chunk = patterns[:, start:start + settings.frames_per_request]
        frames = _grab(grab, chunk)
        for frame in frames:
            gray = mono16_to_gray(frame, settings.bit_depth)
            if shape is None:
                shape = gray.shape
            peaks.append(float(np.percentile(gray, 99.9)))
            clipped.append(float(np.mean(gray >= settings.max_level)))
    check = ExposureCheck(settings, np.array(peaks), np.array(clipped), tuple(shape))
    problems = check.problems()
    if problems:
        raise ExposureError(
            f"the exposure preview at exposure_us {settings.exposure_us}, gain_db "
            f"{settings.gain_db:g} clips: {'; '.join(problems)}. Lower the exposure (about "
            f"exposure_us {check.suggested_exposure_us()} puts the brightest LED image at 80 % "
            f"of the range) or the gain, or allow some clipped pixels with the node's "
            f"max_saturated_fraction parameter. Nothing was captured.")
    return check


# --------------------------------------------------------------------------- the capture


@dataclass
class CapturedModel:
    """The averaged single-LED images of one pose, ready to write.

    model            (4, n_sites, H, W) float32 gray levels, channel-major (capture format)
    saturated        (n_leds,) pixels of each LED image that reached the maximum in a frame
    frames           frames averaged per image
    """
    model: np.ndarray
    saturated: np.ndarray
    frames: int
    settings: CaptureSettings
    elapsed_s: float = 0.0
    preview: ExposureCheck | None = field(default=None, repr=False)

    @property
    def saturated_pixels(self) -> int:
        return int(np.sum(self.saturated))

    def saturation_warning(self) -> str:
        """'' when no pixel clipped, else which LED images and what to do."""
        if self.saturated_pixels == 0:
            return ""
        n = self.settings.n_sites
        worst = [f"{led_name(i, n)} ({int(self.saturated[i])} px)"
                 for i in np.argsort(-self.saturated)[:4] if self.saturated[i] > 0]
        return (f"{self.saturated_pixels} pixels reached the camera's maximum in at least one "
                f"frame ({', '.join(worst)}): their averages are biased low. Recapture with "
                "a lower exposure_us or gain_db if those pixels matter")


def _grab(grab: Grab, patterns: np.ndarray) -> list[np.ndarray]:
    frames = list(grab(patterns))
    if len(frames) != patterns.shape[1]:
        raise AcquisitionError(f"asked the stage for {patterns.shape[1]} frames, got "
                               f"{len(frames)}")
    return frames


def capture_model(grab: Grab, settings: CaptureSettings, *,
                  on_image: Callable[[int, int, str], None] | None = None,
                  cancelled: Callable[[], bool] | None = None,
                  preview: bool = True) -> CapturedModel:
    """Capture one pose: per LED, `settings.frames` frames averaged.

    `on_image(images_done, images_total, led_name)` after each LED image; `cancelled()` is
    asked before every stage request and raises CaptureCancelled (nothing written: this
    function never writes). `preview` runs `check_exposure` first.
    """
    start = time.perf_counter()
    check = check_exposure(grab, settings, cancelled) if preview else None
    patterns = led_patterns(settings.n_sites)
    images: list[np.ndarray] = []
    saturated = np.zeros(settings.n_leds, np.int64)
    for led in range(settings.n_leds):
        averager = FrameAverager(settings.max_level)
        remaining = int(settings.frames)
        while remaining > 0:
            if cancelled is not None and cancelled():
                raise CaptureCancelled(f"cancelled at {led_name(led, settings.n_sites)} "
                                       f"({led} of {settings.n_leds} LED images done); nothing "
                                       "was written")
            k = min(remaining, int(settings.frames_per_request))
            chunk = np.repeat(patterns[:, led:led + 1], k, axis=1)
            for frame in _grab(grab, chunk):
                averager.add(mono16_to_gray(frame, settings.bit_depth))
            remaining -= k
        if images and averager.shape != images[0].shape:
            raise AcquisitionError(f"{led_name(led, settings.n_sites)}: the camera's images "
                                   f"changed size during the capture")
        images.append(averager.mean())
        saturated[led] = averager.saturated_pixels
        if on_image is not None:
            on_image(led + 1, settings.n_leds, led_name(led, settings.n_sites))
    stack = np.stack(images)  # (n_leds, H, W), site-major
    h, w = stack.shape[1:]
    model = stack.reshape(settings.n_sites, N_CHANNELS, h, w).transpose(1, 0, 2, 3)
    return CapturedModel(np.ascontiguousarray(model), saturated, int(settings.frames), settings,
                         time.perf_counter() - start, check)



def acquire_pose(grab: Grab, settings: CaptureSettings, root, label: str, sample: str, pose: str,
                 *, base_rig: Rig | None = None, overwrite: bool = False, preview: bool = True,
                 cancelled: Callable[[], bool] | None = None,
                 before_capture: Callable[[], None] | None = None,
                 on_progress: Callable[[int, int, str, str], None] | None = None,
                 ) -> tuple[Path, CapturedModel]:
    """Capture one pose into the capture folder ``root``; returns (pose folder, capture).

    The destination (names, writable folder, rig.yaml agreement, existing pose) is checked
    before anything is lit, with the preview's image size again after the preview, and with
    the captured size before writing. ``base_rig`` is an explicit rig description (site
    geometry; None: the folder's, else the paper's stage). ``before_capture()`` runs once
    the destination is checked (the node waits for its stage there).
    ``on_progress(images_done, images_total, led_name, stage)`` with stage 'preview',
    'capturing', 'writing'. A capture that cannot be written raises DestinationError naming
    the rescue file it was saved to instead.
    """
    root = Path(root).expanduser() if str(root).strip() else Path("")
    existing = folder_rig(root) if str(root) != "." else None  # "" / "." refused below

    def destination(shape) -> Destination:
        return check_destination(root, label, sample, pose,
                                 capture_rig(settings, tuple(shape), base_rig or existing),
                                 overwrite=overwrite, rig_from_file=base_rig is not None)

    destination(existing.image_size if existing else (1, 1))
    if before_capture is not None:
        before_capture()
    report = on_progress or (lambda *_a: None)
    total = settings.n_leds
    check = None
    if preview:
        report(0, total, "", "preview")
        check = check_exposure(grab, settings, cancelled)
        destination(check.image_shape)
    captured = capture_model(grab, settings, preview=False, cancelled=cancelled,
                             on_image=lambda done, n, led: report(done, n, led, "capturing"))
    captured.preview = check
    report(total, total, "", "writing")
    try:
        target = destination(captured.model.shape[-2:])
        return write_model(target, captured.model, overwrite=overwrite), captured
    except DestinationError as exc:
        rig = capture_rig(settings, captured.model.shape[-2:], base_rig or existing)
        raise DestinationError(rescue_message(exc, RescuedModel(root, label, sample, pose, rig,
                                                                captured.model))) from None

