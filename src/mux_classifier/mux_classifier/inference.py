"""Classifying the sample on the stage: patterns out, stamped images back, a label.

One classification (the classifier node maps ROS onto this; nothing here imports rclpy):

1. `plan_acquisition`: the first k LED patterns of the artifact (k = the largest image count
   it has a classifier for, at most ``max_images``) and the exposure / gain of the noise
   setting it was trained for;
2. ``apply(plan, timeout_s)``: the caller lights them, one camera trigger each, and returns
   the trigger stamps (and sequence numbers);
3. `ImageMatcher.collect`: the images whose header stamps *equal* those trigger stamps, in
   pattern order; never by arrival order. Images that arrive before the trigger stamps are
   known (the camera can be faster than the driver's reply) wait in a small buffer; a
   missing image fails the call at once when the camera reports it lost;
4. `classify_frames`: mono16 -> gray levels, the same area downscale training used
   (`lightstage_physics.scene_models.downscale_images`), HOG, the artifact's classifier for k.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
# The downscale training uses (ModelSet.downscaled / load_capture(downscale_to=...)): the
# classifier must see images prepared exactly as the training renders were.
from lightstage_physics.scene_models import downscale_images
# Stamped-frame matching and mono16 decoding are the graph contract's (lightstage_graph),
# shared with model acquisition; re-exported here as part of this module's API.
from lightstage_graph.errors import MissingImagesError, StageError
from lightstage_graph.frames import ImageMatcher, image_from_buffer, mono16_to_gray
from lightstage_graph.stamps import format_stamp

from .artifact import ArtifactError, Prediction, TrainedArtifact


class InferenceError(StageError):
    """A classification on the stage could not be made; the message says why. Missing images
    are a `MissingImagesError`: catch `StageError` for both."""


__all__ = ["AcquisitionPlan", "Classification", "ImageMatcher", "InferenceError",
           "MissingImagesError", "plan_acquisition", "image_from_buffer", "mono16_to_gray",
           "classify_frames", "classify_collected", "classify_on_stage", "format_stamp"]

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
    # what lightstage_interfaces/Pattern can carry (uint32 exposure_us, float32 gain_db)
    if exposure_us > 0xFFFFFFFF or abs(gain) > float(np.finfo(np.float32).max):
        raise InferenceError(
            f"the classifier's noise setting asks for exposure {exposure_ms} ms / gain {gain_db} "
            "dB, beyond what a light pattern can carry (uint32 us, float32 dB); retrain it with "
            "a real camera setting")
    return AcquisitionPlan(np.ascontiguousarray(artifact.led_patterns[:, :k]), exposure_us, gain)


# --------------------------------------------------------------------------- images


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


def classify_collected(artifact: TrainedArtifact, frames: Sequence[np.ndarray], bit_depth: int,
                       sequences: list, first_stamp_ns: int,
                       acquisition_ms: float) -> Classification:
    """Classify the frames collected for one sequence of triggers; `compute_ms` is the time of
    the classification itself."""
    start = time.perf_counter()
    prediction, stack = classify_frames(artifact, frames, bit_depth)
    compute_ms = (time.perf_counter() - start) * 1e3
    return Classification(
        label=prediction.label, class_names=list(artifact.class_names),
        scores=np.asarray(prediction.scores, dtype=np.float32), images_used=prediction.n_images,
        sequences=sequences, first_stamp_ns=first_stamp_ns, acquisition_ms=acquisition_ms,
        compute_ms=compute_ms, stack=stack)


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
    return classify_collected(artifact, frames, bit_depth, list(sequences or []), stamps[0],
                              (last_arrival_ns - stamps[0]) / 1e6)
