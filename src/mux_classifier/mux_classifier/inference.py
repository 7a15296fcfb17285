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

Anytime (a calibrated artifact, `TrainedArtifact.anytime_steps`): steps 2-4 run one pattern
column at a time, and after each the artifact decides (`TrainedArtifact.decide`) whether
the top class's probability reached the target; the call stops there, or when the budget is
spent. An uncalibrated artifact takes every image in one sequence, as ever.
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

from .artifact import ArtifactError, Decision, Prediction, TrainedArtifact


class InferenceError(StageError):
    """A classification on the stage could not be made; the message says why. Missing images
    are a `MissingImagesError`: catch `StageError` for both."""


__all__ = ["AcquisitionPlan", "Classification", "ImageMatcher", "InferenceError",
           "MissingImagesError", "plan_acquisition", "image_from_buffer", "mono16_to_gray",
           "classify_frames", "classify_collected", "classify_on_stage", "decide_frames",
           "format_stamp"]

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


def plan_acquisition(artifact: TrainedArtifact, max_images: int = 0,
                     first_image: int = 0) -> AcquisitionPlan:
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
    return AcquisitionPlan(np.ascontiguousarray(artifact.led_patterns[:, int(first_image):k]),
                           exposure_us, gain)


# --------------------------------------------------------------------------- images


def _stack(artifact: TrainedArtifact, frames: Sequence[np.ndarray], bit_depth: int) -> np.ndarray:
    """The (k, size, size) float32 stack the classifier sees, from mono16 frames (H, W)."""
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
    return stack


def classify_frames(artifact: TrainedArtifact, frames: Sequence[np.ndarray],
                    bit_depth: int = 10) -> tuple[Prediction, np.ndarray]:
    """Predict from the mono16 frames (H, W) taken under the artifact's first k patterns.

    Returns the prediction and the (k, size, size) float32 stack the classifier saw.
    """
    stack = _stack(artifact, frames, bit_depth)
    try:
        return artifact.predict_stack(stack), stack
    except ArtifactError as exc:
        raise InferenceError(str(exc)) from None


def decide_frames(artifact: TrainedArtifact, frames: Sequence[np.ndarray], bit_depth: int = 10,
                  target_probability: float | None = None,
                  final: bool = False) -> tuple[Decision, np.ndarray]:
    """`TrainedArtifact.decide` on the mono16 frames (H, W) under the first k patterns;
    returns the decision and the stack the classifier saw."""
    stack = _stack(artifact, frames, bit_depth)
    try:
        return artifact.decide(stack, target_probability, final), stack
    except ArtifactError as exc:
        raise InferenceError(str(exc)) from None


# --------------------------------------------------------------------------- one call


@dataclass
class Classification:
    """The outcome of one classification on the stage. ``probabilities``: calibrated, class
    order (empty when the artifact is uncalibrated); ``decision``: accepted / unsure /
    unknown; ``novelty``: NaN when not modelled; ``images_budget``: the images the call could
    have used."""
    label: str
    class_names: list
    scores: np.ndarray
    images_used: int
    sequences: list
    first_stamp_ns: int
    acquisition_ms: float
    compute_ms: float
    stack: np.ndarray = field(repr=False, default=None)
    probabilities: np.ndarray = field(default_factory=lambda: np.empty(0, np.float32))
    decision: str = "accepted"
    novelty: float = math.nan
    images_budget: int = 0
    calibrated: bool = False


def classify_collected(artifact: TrainedArtifact, frames: Sequence[np.ndarray], bit_depth: int,
                       sequences: list, first_stamp_ns: int, acquisition_ms: float,
                       target_probability: float | None = None,
                       images_budget: int | None = None) -> Classification:
    """Classify the frames collected for one sequence of triggers; `compute_ms` is the time of
    the classification itself."""
    start = time.perf_counter()
    decision, stack = decide_frames(artifact, frames, bit_depth, target_probability, final=True)
    compute_ms = (time.perf_counter() - start) * 1e3
    return _classification(artifact, decision, stack, sequences, first_stamp_ns,
                           acquisition_ms, compute_ms, images_budget or decision.n_images)


def _classification(artifact, decision: Decision, stack, sequences, first_stamp_ns,
                    acquisition_ms, compute_ms, images_budget) -> Classification:
    return Classification(
        label=decision.label, class_names=list(artifact.class_names),
        scores=np.asarray(decision.scores, dtype=np.float32), images_used=decision.n_images,
        sequences=sequences, first_stamp_ns=first_stamp_ns, acquisition_ms=acquisition_ms,
        compute_ms=compute_ms, stack=stack,
        probabilities=np.asarray(decision.probabilities, dtype=np.float32),
        decision=decision.decision, novelty=float(decision.novelty),
        images_budget=int(images_budget), calibrated=artifact.calibrated)


ApplyFn = Callable[[AcquisitionPlan, float], tuple[Sequence[int], Sequence[int]]]


def classify_on_stage(artifact: TrainedArtifact, apply: ApplyFn, matcher: ImageMatcher, *,
                      max_images: int = 0, timeout_s: float = 10.0,
                      bit_depth: int = 10,
                      target_probability: float | None = None) -> Classification:
    """Light the artifact's patterns, collect their images by stamp, classify.

    `apply(plan, timeout_s) -> (trigger stamps ns, trigger sequences)` lights the patterns
    with one trigger each and raises InferenceError if it cannot. `timeout_s` bounds the
    whole call (lighting + waiting for images). A calibrated artifact is asked one pattern
    column at a time and stops once the top class reaches ``target_probability`` (None: the
    trained target; >= 1: every image); `acquisition_ms` then spans the first trigger to the
    last image used.
    """
    if not timeout_s > 0:
        raise InferenceError(f"timeout_s must be > 0, got {timeout_s}")
    deadline = time.monotonic() + float(timeout_s)
    plan_acquisition(artifact, max_images)  # InferenceError for a bad max_images
    try:
        steps = artifact.anytime_steps(max_images)
    except ArtifactError as exc:
        raise InferenceError(str(exc)) from None
    frames: list = []
    all_stamps: list[int] = []
    all_sequences: list[int] | None = []
    compute_ms = 0.0
    last_arrival_ns = 0
    decision = stack = None
    for i, k in enumerate(steps):
        plan = plan_acquisition(artifact, k, first_image=len(frames))
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise InferenceError(f"timed out after {timeout_s} s with {len(frames)} of "
                                 f"{steps[-1]} images")
        stamps, sequences = apply(plan, remaining)
        stamps, sequences = [int(s) for s in stamps], [int(s) for s in sequences]
        if len(stamps) != plan.n_images:
            raise InferenceError(f"asked for {plan.n_images} triggers but the driver reported "
                                 f"{len(stamps)}; check the driver's log")
        if len(sequences) != len(stamps):
            sequences = None
        step_frames, last_arrival_ns = matcher.collect(stamps, deadline - time.monotonic(),
                                                       sequences)
        frames += list(step_frames)
        all_stamps += stamps
        all_sequences = None if sequences is None or all_sequences is None \
            else all_sequences + sequences
        start = time.perf_counter()
        decision, stack = decide_frames(artifact, frames, bit_depth, target_probability,
                                        final=i == len(steps) - 1)
        compute_ms += (time.perf_counter() - start) * 1e3
        if decision.stop:
            break
    return _classification(artifact, decision, stack, list(all_sequences or []),
                           all_stamps[0], (last_arrival_ns - all_stamps[0]) / 1e6, compute_ms,
                           steps[-1])
