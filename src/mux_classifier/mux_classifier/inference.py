"""Classifying the sample on the stage: patterns out, stamped images back, a label.

One classification (the classifier node maps ROS onto this; nothing here imports rclpy):

1. `plan_acquisition`: the first k LED patterns of the artifact (k = the largest image count
   it has a classifier for, at most ``max_images``) and the exposure / gain of the noise
   setting it was trained for;
2. ``apply(plan, timeout_s)``: the caller lights them, one camera trigger each, and returns
   the trigger stamps (and sequence numbers);
3. `ImageMatcher.collect`: the images whose header stamps *equal* those trigger stamps, in
   pattern order; never by arrival order. Images that arrive before the trigger stamps are
   known (the camera can be faster than the driver's reply) wait in a small buffer;
4. `classify_frames`: mono16 -> gray levels, the same area downscale training used
   (`lightstage_camera.models.downscale_images`), HOG, the artifact's classifier for k.
"""
from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
# The downscale training uses (ModelSet.downscaled / load_capture(downscale_to=...)): the
# classifier must see images prepared exactly as the training renders were.
from lightstage_camera.models import downscale_images

from .model import ArtifactError, Prediction, TrainedArtifact

__all__ = ["AcquisitionPlan", "Classification", "ImageMatcher", "InferenceError",
           "MissingImagesError", "plan_acquisition", "image_from_buffer", "mono16_to_gray",
           "classify_frames", "classify_on_stage", "format_stamp"]

MONO16_ENCODINGS = ("mono16", "16UC1")


class InferenceError(RuntimeError):
    """A classification that could not be done; the message says why and what to do."""


class MissingImagesError(InferenceError):
    """Some images of a trigger sequence did not arrive in time (or arrived unusable)."""

    def __init__(self, message: str, missing: list[int]):
        super().__init__(message)
        self.missing = missing


def format_stamp(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


# --------------------------------------------------------------------------- plan


@dataclass(frozen=True)
class AcquisitionPlan:
    """What to light: ``led_patterns`` (32, k) in image order, one trigger each.

    exposure_us: 0 = the driver's default; gain_db: NaN = the camera's default.
    """
    led_patterns: np.ndarray
    exposure_us: int
    gain_db: float

    @property
    def n_images(self) -> int:
        return int(self.led_patterns.shape[1])


def plan_acquisition(artifact: TrainedArtifact, max_images: int = 0) -> AcquisitionPlan:
    """The first k patterns of the artifact, k = its largest image count <= ``max_images``.

    ``max_images`` 0 means all the artifact has a classifier for. Per-colour artifacts have
    classifiers for multiples of 4 images only (4 per site pattern), so e.g. 6 gives 4.
    """
    max_images = int(max_images)
    if max_images < 0:
        raise InferenceError(f"max_images must be >= 0 (0 = all), got {max_images}")
    counts = artifact.n_images
    usable = [k for k in counts if max_images == 0 or k <= max_images]
    if not usable:
        raise InferenceError(
            f"max_images={max_images} is fewer than the smallest image count this classifier "
            f"has ({counts[0]}); ask for 0 (all) or one of {counts}")
    k = usable[-1]
    noise = artifact.noise or {}
    exposure_ms, gain_db = noise.get("exposure_ms"), noise.get("gain_db")
    exposure_us = int(round(float(exposure_ms) * 1000.0)) if exposure_ms else 0
    gain = float(gain_db) if gain_db is not None else math.nan
    return AcquisitionPlan(np.ascontiguousarray(artifact.led_patterns[:, :k]), exposure_us, gain)


# --------------------------------------------------------------------------- images


def image_from_buffer(data, height: int, width: int, step: int, encoding: str,
                      is_bigendian: bool = False) -> np.ndarray:
    """A ``mono16`` image message's fields -> uint16 (H, W); ValueError if it is not one."""
    if encoding not in MONO16_ENCODINGS:
        raise ValueError(f"image encoding is {encoding!r}; the classifier needs 16-bit mono "
                         f"({' or '.join(MONO16_ENCODINGS)}) as the light-stage camera publishes")
    if height < 1 or width < 1 or step < 2 * width:
        raise ValueError(f"image is {width}x{height} with step {step}: not a valid mono16 image")
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size < height * step:
        raise ValueError(f"image data holds {buf.size} bytes, a {width}x{height} mono16 image "
                         f"with step {step} needs {height * step}")
    rows = buf[:height * step].reshape(height, step)[:, :2 * width]
    dtype = np.dtype(">u2" if is_bigendian else "<u2")
    return np.ascontiguousarray(rows).view(dtype).reshape(height, width).astype(np.uint16)


def mono16_to_gray(image: np.ndarray, bit_depth: int = 10) -> np.ndarray:
    """MSB-aligned 16-bit values -> float32 gray levels in camera units (10-bit: value / 64)."""
    if not 8 <= int(bit_depth) <= 16:
        raise ValueError(f"bit_depth must be 8..16, got {bit_depth}")
    gray = np.asarray(image, dtype=np.float32)
    gray *= np.float32(1.0 / (1 << (16 - int(bit_depth))))
    return gray


def classify_frames(artifact: TrainedArtifact, frames: Sequence[np.ndarray],
                    bit_depth: int = 10) -> tuple[Prediction, np.ndarray]:
    """Predict from the mono16 frames (H, W) taken under the artifact's first k patterns.

    Returns the prediction and the (k, size, size) float32 stack the classifier saw.
    """
    if len(frames) == 0:
        raise InferenceError("no images to classify")
    shapes = {np.shape(f) for f in frames}
    if len(shapes) != 1:
        raise InferenceError(f"the images differ in size ({sorted(shapes)}); all must come from "
                             "the same camera settings")
    gray = np.stack([mono16_to_gray(f, bit_depth) for f in frames])
    size = artifact.hog_config.image_size
    try:
        stack, _ = downscale_images(gray, size)
    except ValueError as exc:
        raise InferenceError(f"camera images are {gray.shape[2]}x{gray.shape[1]} px but the "
                             f"classifier needs at least {size}x{size}: {exc}") from None
    try:
        return artifact.predict_stack(stack), stack
    except ArtifactError as exc:
        raise InferenceError(str(exc)) from None


# --------------------------------------------------------------------------- matching


@dataclass
class _Entry:
    image: np.ndarray | None
    error: str
    arrival_ns: int


class ImageMatcher:
    """Images keyed by their header stamp (ns), waited for by trigger stamp. Thread-safe.

    `add` is called from the image subscription; `collect` from the service handler. The
    `capacity` most recent images are kept, so images may arrive before they are asked for.
    `clock` gives the arrival time in ns, on the same time base as the trigger stamps.
    """

    def __init__(self, capacity: int = 64, clock: Callable[[], int] = time.time_ns):
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self.clock = clock
        self._entries: OrderedDict[int, _Entry] = OrderedDict()
        self._cond = threading.Condition()
        self.received = 0
        self.evicted = 0

    def __len__(self) -> int:
        with self._cond:
            return len(self._entries)

    def add(self, stamp_ns: int, image: np.ndarray | None, error: str = "") -> None:
        """An image (or, with `error`, the reason it was unusable) stamped `stamp_ns`."""
        entry = _Entry(image, error, int(self.clock()))
        with self._cond:
            self._entries[int(stamp_ns)] = entry
            self._entries.move_to_end(int(stamp_ns))
            while len(self._entries) > self.capacity:
                self._entries.popitem(last=False)
                self.evicted += 1
            self.received += 1
            self._cond.notify_all()

    def collect(self, stamps_ns: Sequence[int], timeout_s: float,
                sequences: Sequence[int] | None = None) -> tuple[list[np.ndarray], int]:
        """The images stamped ``stamps_ns`` in that order, and the last one's arrival time.

        Waits up to `timeout_s`; raises MissingImagesError naming each image (position,
        trigger sequence, stamp) that did not arrive or arrived unusable. Collected images
        leave the buffer.
        """
        stamps = [int(s) for s in stamps_ns]
        deadline = time.monotonic() + max(0.0, float(timeout_s))
        with self._cond:
            while True:
                missing = [i for i, s in enumerate(stamps) if s not in self._entries]
                remaining = deadline - time.monotonic()
                if not missing or remaining <= 0:
                    break
                self._cond.wait(remaining)
            bad = [i for i, s in enumerate(stamps)
                   if s in self._entries and self._entries[s].image is None]
            if missing or bad:
                raise self._missing_error(stamps, sequences, missing, bad, timeout_s)
            entries = [self._entries.pop(s) for s in stamps]
        return [e.image for e in entries], max(e.arrival_ns for e in entries)

    def _missing_error(self, stamps, sequences, missing, bad, timeout_s) -> MissingImagesError:
        def name(i: int) -> str:
            seq = f"trigger sequence {sequences[i]}, " if sequences is not None else ""
            return f"image {i + 1} ({seq}stamp {format_stamp(stamps[i])})"

        parts = []
        if missing:
            parts.append(f"{len(missing)} of {len(stamps)} images did not arrive within "
                         f"{float(timeout_s):g} s: {', '.join(name(i) for i in missing)}; is the "
                         "camera node running, subscribed to /illumination and publishing "
                         "/image_raw stamped with the trigger stamps?")
        for i in bad:
            parts.append(f"{name(i)} is unusable: {self._entries[stamps[i]].error}")
        return MissingImagesError("; ".join(parts), sorted(missing + bad))


# --------------------------------------------------------------------------- one call


@dataclass
class Classification:
    """The outcome of one classification on the stage."""
    label: str
    class_names: list
    scores: np.ndarray
    images_used: int
    sequences: list
    first_stamp_ns: int
    acquisition_ms: float
    compute_ms: float
    stack: np.ndarray = field(repr=False, default=None)


ApplyFn = Callable[[AcquisitionPlan, float], tuple[Sequence[int], Sequence[int]]]


def classify_on_stage(artifact: TrainedArtifact, apply: ApplyFn, matcher: ImageMatcher, *,
                      max_images: int = 0, timeout_s: float = 10.0,
                      bit_depth: int = 10) -> Classification:
    """Light the artifact's patterns, collect their images by stamp, classify.

    `apply(plan, timeout_s) -> (trigger stamps ns, trigger sequences)` lights the patterns
    with one trigger each and raises InferenceError if it cannot. `timeout_s` bounds the
    whole call (lighting + waiting for images).
    """
    if not timeout_s > 0:
        raise InferenceError(f"timeout_s must be > 0, got {timeout_s}")
    deadline = time.monotonic() + float(timeout_s)
    plan = plan_acquisition(artifact, max_images)
    stamps, sequences = apply(plan, float(timeout_s))
    stamps, sequences = [int(s) for s in stamps], [int(s) for s in sequences]
    if len(stamps) != plan.n_images:
        raise InferenceError(f"asked for {plan.n_images} triggers but the driver reported "
                             f"{len(stamps)}; check the driver's log")
    if len(sequences) != len(stamps):
        sequences = None
    frames, last_arrival_ns = matcher.collect(stamps, deadline - time.monotonic(), sequences)
    start = time.perf_counter()
    prediction, stack = classify_frames(artifact, frames, bit_depth)
    compute_ms = (time.perf_counter() - start) * 1e3
    return Classification(
        label=prediction.label, class_names=list(artifact.class_names),
        scores=np.asarray(prediction.scores, dtype=np.float32), images_used=prediction.n_images,
        sequences=list(sequences or []), first_stamp_ns=stamps[0],
        acquisition_ms=(last_arrival_ns - stamps[0]) / 1e6, compute_ms=compute_ms, stack=stack)
