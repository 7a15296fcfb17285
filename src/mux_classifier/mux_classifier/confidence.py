"""Calibrated class probabilities, the anytime stop rule, and the decision of one answer.

A trained artifact's classifiers give raw per-class scores (SVM margins, a learned head's
logits). `Confidence` turns them into probabilities by temperature scaling, one temperature
per image count (softmax of scores / T, T fitted at training time on held-out inner splits:
`mux_trainer.calibration`), and holds the anytime rule: after each pattern column, stop as
soon as the top class's probability reaches `stop_probability`, or when the budget is spent.

One answer's `Decision`:

- ``accepted``: the top class reached the target probability;
- ``unsure``: the budget ran out below it (look again, or ask a person);
- ``unknown``: the object is unlike every trained class (novelty >= 1; an artifact without a
  novelty model never says it).

Temperature scaling keeps the ranking of the scores (the label never changes) and has one
parameter per image count, so that a few hundred held-out answers fit it without
over-fitting (Guo et al., "On calibration of modern neural networks", ICML 2017). Pure
numpy: no rclpy, no scikit-learn at classification time.
"""
from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

__all__ = ["ACCEPTED", "UNSURE", "UNKNOWN", "DECISIONS", "Confidence", "ConfidenceError",
           "Decision", "softmax", "expected_calibration_error", "anytime_outcomes"]

ACCEPTED, UNSURE, UNKNOWN = "accepted", "unsure", "unknown"
DECISIONS = (ACCEPTED, UNSURE, UNKNOWN)
# temperatures are fitted in this range (a margin scale of 1e-3 .. 1e3)
MIN_TEMPERATURE, MAX_TEMPERATURE = 1e-3, 1e3


class ConfidenceError(ValueError):
    """A confidence setting (stored in an artifact, or asked for) is unusable; says why."""


def softmax(scores: np.ndarray, temperature: float = 1.0) -> np.ndarray:
    """Row-wise softmax of ``scores / temperature`` (n, n_classes), computed stably."""
    z = np.asarray(scores, dtype=np.float64) / float(temperature)
    z = z - z.max(axis=-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=-1, keepdims=True)


def expected_calibration_error(probabilities: np.ndarray, labels: np.ndarray,
                               n_bins: int = 10) -> float:
    """The expected calibration error of the top-class probability: the mean over equal-width
    confidence bins of |accuracy - mean confidence|, weighted by the bin's share of answers.
    ``probabilities`` (n, n_classes), ``labels`` (n,) class indices."""
    p = np.asarray(probabilities, dtype=np.float64)
    y = np.asarray(labels)
    if p.ndim != 2 or y.shape != (p.shape[0],) or p.shape[0] == 0:
        raise ValueError(f"need probabilities (n, n_classes) and n labels, got {p.shape} and "
                         f"{y.shape}")
    top = p.max(axis=1)
    correct = (p.argmax(axis=1) == y).astype(np.float64)
    edges = np.linspace(0.0, 1.0, int(n_bins) + 1)
    which = np.clip(np.digitize(top, edges[1:-1], right=True), 0, int(n_bins) - 1)
    ece = 0.0
    for b in range(int(n_bins)):
        inside = which == b
        if inside.any():
            ece += inside.mean() * abs(correct[inside].mean() - top[inside].mean())
    return float(ece)


def anytime_outcomes(probabilities_by_step: list[np.ndarray],
                     stop_probability: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the anytime rule stops each sample and what it answers.

    ``probabilities_by_step``: for each step (ascending image counts), (n, n_classes)
    calibrated probabilities of the same n samples. Returns (step index where each sample
    stopped, predicted class index, whether the target was reached there)."""
    steps = [np.asarray(p, dtype=np.float64) for p in probabilities_by_step]
    if not steps:
        raise ValueError("need the probabilities of at least one step")
    n = steps[0].shape[0]
    stop = np.full(n, len(steps) - 1)
    reached = np.zeros(n, dtype=bool)
    for i, p in enumerate(steps):
        hit = (p.max(axis=1) >= stop_probability) & ~reached
        stop[hit] = i
        reached |= hit
    predicted = np.array([steps[s][j].argmax() for j, s in enumerate(stop)], dtype=int)
    return stop, predicted, reached


class Decision(NamedTuple):
    """One answer from the images so far. ``probabilities``: empty when uncalibrated;
    ``novelty``: NaN without a novelty model; ``stop``: take no more images."""
    label: str
    index: int
    scores: np.ndarray
    probabilities: np.ndarray
    decision: str
    novelty: float
    stop: bool
    n_images: int


def _positive_finite(value, what: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not lo <= value <= hi:
        raise ConfidenceError(f"{what} must be a number in {lo:g} .. {hi:g}, got "
                              f"{reprlib.repr(value)}")
    return float(value)


def check_target_probability(value) -> float | None:
    """A requested target probability: 0 = the classifier's own rule (None), 1 = never stop
    early, between: that target. ConfidenceError outside 0 .. 1 or not a number."""
    target = _positive_finite(value, "target_probability", 0.0, 1.0)
    return None if target == 0.0 else target


@dataclass(frozen=True)
class Confidence:
    """Temperature per image count, the anytime rule's target, and how they were fitted.

    temperatures: {image count: T}; probabilities are softmax(scores / T).
    stop_probability: the trained target of the anytime rule (1.0: never stop early).
    tolerance: the accuracy the rule was allowed to give up against the full count.
    estimate: what the fit measured on the held-out inner answers (plain JSON): the rule's
    accuracy and mean images, the full count's, the calibration error, how it was held out.
    """
    temperatures: dict
    stop_probability: float
    tolerance: float = 0.01
    estimate: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.temperatures, dict) or not self.temperatures:
            raise ConfidenceError("temperatures must map each image count to a temperature")
        temps = {}
        for k, t in self.temperatures.items():
            try:
                count = int(k)
            except (TypeError, ValueError):
                raise ConfidenceError(f"temperature key {reprlib.repr(k)} is not an image "
                                      "count") from None
            if count < 1 or str(count) != str(k).strip():
                raise ConfidenceError(f"temperature key {reprlib.repr(k)} is not an image count")
            temps[count] = _positive_finite(t, f"the temperature of {count} images",
                                            MIN_TEMPERATURE, MAX_TEMPERATURE)
        object.__setattr__(self, "temperatures", dict(sorted(temps.items())))
        object.__setattr__(self, "stop_probability", _positive_finite(
            self.stop_probability, "stop_probability", 0.0, 1.0))
        object.__setattr__(self, "tolerance", _positive_finite(
            self.tolerance, "tolerance", 0.0, 1.0))
        if not isinstance(self.estimate, dict):
            raise ConfidenceError("estimate must be an object")

    @property
    def counts(self) -> list[int]:
        return list(self.temperatures)

    def probabilities(self, scores: np.ndarray, n_images: int) -> np.ndarray:
        """Calibrated probabilities (n, n_classes) of the scores of the classifier for
        ``n_images``."""
        if int(n_images) not in self.temperatures:
            raise ConfidenceError(f"no calibration for {n_images} images (calibrated: "
                                  f"{self.counts})")
        return softmax(np.atleast_2d(scores), self.temperatures[int(n_images)])

    def to_dict(self) -> dict:
        return {"temperatures": {str(k): float(t) for k, t in self.temperatures.items()},
                "stop_probability": float(self.stop_probability),
                "tolerance": float(self.tolerance), "estimate": dict(self.estimate)}

    @classmethod
    def from_dict(cls, doc) -> "Confidence":
        if not isinstance(doc, dict):
            raise ConfidenceError(f"the confidence setting must be an object, got "
                                  f"{reprlib.repr(doc)}")
        unknown = sorted(set(doc) - {"temperatures", "stop_probability", "tolerance",
                                     "estimate"})
        if unknown:
            raise ConfidenceError(f"the confidence setting has unknown keys {unknown}")
        missing = [k for k in ("temperatures", "stop_probability") if k not in doc]
        if missing:
            raise ConfidenceError(f"the confidence setting lacks {missing}")
        return cls(temperatures=doc["temperatures"], stop_probability=doc["stop_probability"],
                   tolerance=doc.get("tolerance", 0.01), estimate=doc.get("estimate", {}))
