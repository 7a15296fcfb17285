"""The trained-classifier artifact: what training produces and the classify node loads.

``TrainedArtifact``: the LED pattern matrix (32, N) in image order, the per-colour site
matrix when the paper's mode was used, the noise setting and the dimmer it was trained for,
class names, the feature extractor (by name) and HOG configuration, one linear classifier
for each image count (on the extractor's raw features), and provenance. This module is the
data model and its validation; prediction is the estimator's (`MuxClassifier`, one per image
count) and the ``.npz`` file format is `artifact_format`'s (docs/CLASSIFIER.md).
"""
from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from lightstage_physics.noise import check_noise_coefficients
from lightstage_physics.rig import DEFAULT_DIMMER, N_LEDS, site_to_led_patterns
from lightstage_graph.limits import DIMMER_MAX, DIMMER_MIN, LimitError, check_range
from sklearn.utils.validation import check_is_fitted

from .artifact_format import (FORMAT_NAME, FORMAT_VERSION, LEARNED_MODE, MAX_IMAGES,
                              MAX_LEARNED_WIDTH, MODES, READABLE_VERSIONS, UNRECORDED_DIMMER,
                              ArtifactError, read_artifact, write_artifact)
from .confidence import (ACCEPTED, UNKNOWN, UNSURE, Confidence, ConfidenceError, Decision,
                         check_target_probability)
from .estimator import LearnedModelClassifier, MuxClassifier
from .features import DEFAULT_EXTRACTOR, check_stacks, make_extractor, searchable_extractor
from .hog import HogConfig
from .learned_model import LearnedModel
from .novelty import NOVELTY_FEATURES, NoveltyModel

# the features a learned model classifies with (`learned_model`: intensity statistics)
LEARNED_FEATURES = "intensity_stats"

__all__ = [
    "LinearStage", "Prediction", "TrainedArtifact", "ArtifactError", "DimmerMismatch",
    "FORMAT_NAME", "FORMAT_VERSION", "READABLE_VERSIONS", "UNRECORDED_DIMMER", "noise_to_dict",
    "check_dimmer", "LEARNED_FEATURES", "Decision",
]

class DimmerMismatch(ArtifactError):
    """The camera's dimmer differs from the one the classifier was trained with."""



def noise_to_dict(noise, name: str | None = None) -> dict:
    """Noise setting as plain JSON: name, sigma_p2, sigma_r2, gain_db, exposure_ms.

    Accepts a dict with those keys, an object with those attributes (a NoiseModel), or
    None / "none" for noise-free rendering.
    """
    keys = ("sigma_p2", "sigma_r2", "gain_db", "exposure_ms")
    if noise is None or (isinstance(noise, str) and noise.lower() == "none"):
        return {"name": "none", **{k: None for k in keys}}
    if isinstance(noise, dict):
        missing = [k for k in ("name", *keys) if k not in noise]
        if missing:
            raise ArtifactError(f"noise setting lacks {missing}; give name and {', '.join(keys)}")
        values = {k: noise[k] for k in keys}
        name = noise["name"] if name is None else name
    else:
        try:
            values = {k: getattr(noise, k) for k in keys}
        except AttributeError as exc:
            raise ArtifactError(
                f"noise setting must be a dict or have attributes {keys} (a NoiseModel); "
                f"got {type(noise).__name__}") from exc
        name = name or getattr(noise, "name", None) or "custom"
    result = {"name": str(name)}
    for k, v in values.items():
        if v is None:
            result[k] = None
            continue
        try:
            result[k] = float(v)
        except (TypeError, ValueError, OverflowError):
            raise ArtifactError(f"noise setting {k} must be a number or null, got "
                                f"{reprlib.repr(v)}") from None
        if isinstance(v, bool) or not math.isfinite(result[k]) or (k != "gain_db" and result[k] < 0):
            raise ArtifactError(f"noise setting {k} must be a finite number"
                                f"{'' if k == 'gain_db' else ' >= 0'}, got {reprlib.repr(v)}")
    given = [k for k in keys if result[k] is not None]
    if given and len(given) != len(keys):
        raise ArtifactError(f"noise setting: give all of {', '.join(keys)} or none of them "
                            f"(noise-free), got only {', '.join(given)}")
    if given:
        try:
            check_noise_coefficients(result["sigma_p2"], result["sigma_r2"], result["gain_db"],
                                     result["exposure_ms"], what="noise setting {}")
        except ValueError as exc:
            raise ArtifactError(str(exc)) from None
    return result


@dataclass
class LinearStage:
    """The linear classifier that uses the first ``n_images`` images of the artifact."""

    n_images: int
    coef: np.ndarray       # (n_classes, n_images * n_features)
    intercept: np.ndarray  # (n_classes,)


class Prediction(NamedTuple):
    label: str             # class name
    index: int             # class index into class_names
    scores: np.ndarray     # (n_classes,) decision values, higher = more likely
    n_images: int          # how many images the prediction used


@dataclass
class TrainedArtifact:
    """A trained multiplexed-illumination classifier: patterns + one classifier per image count.

    ``led_patterns`` (32, N): column i is the LED pattern of image i (site-major LEDs,
    values in [0, 1]). ``stages``: classifiers using the first n images, for increasing n
    (per-colour mode: 4, 8, ..., one per site-pattern column). ``site_patterns`` (8, m)
    and ``mode == "per_colour"`` when the paper's mode produced them. ``dimmer``: the scale
    of the single-LED images the training rendered with (a camera must use the same,
    `check_dimmer`); ``dimmer_recorded`` is False for a format-1 file, which did not record
    it (its trainings all used `UNRECORDED_DIMMER`). ``led_patterns`` may be None when
    ``site_patterns`` are given: they are derived from them (`rig.site_to_led_patterns`).
    ``learned``: a learned-illumination model (`LearnedModel`, or its `to_arrays()` dict),
    with ``mode == "learned"``, no linear ``stages``, its patterns as ``led_patterns`` (None:
    taken from it) and its own classifier for its k images.
    ``confidence``: the calibration of the classifiers' scores and the anytime stop rule
    (`confidence.Confidence`, or its dict), fitted at training time; None (every file before
    format 7): uncalibrated, scores only, every image taken.
    ``novelty``: {image count: `novelty.NoveltyModel`} (or each model's `to_arrays()` dict),
    scoring the images' `NOVELTY_FEATURES` against the trained classes; `decide` answers
    "unknown" where the score is >= 1. None: never unknown.
    Prediction is the estimator's: `classifier` (a fitted `MuxClassifier` per image count, or
    the learned model's `LearnedModelClassifier`).
    """

    led_patterns: np.ndarray
    class_names: list
    stages: list
    noise: dict = field(default_factory=lambda: noise_to_dict(None))
    hog_config: HogConfig = field(default_factory=HogConfig)
    mode: str = "joint"
    site_patterns: np.ndarray | None = None
    provenance: dict = field(default_factory=dict)
    dimmer: float = DEFAULT_DIMMER
    dimmer_recorded: bool = True
    features: str = DEFAULT_EXTRACTOR
    learned: LearnedModel | None = None
    confidence: Confidence | None = None
    novelty: dict | None = None

    def __post_init__(self):
        if self.novelty is not None:
            self.novelty = _novelty_models(self.novelty)
        if self.learned is not None and not isinstance(self.learned, LearnedModel):
            self.learned = _learned_model(self.learned)
        if self.confidence is not None and not isinstance(self.confidence, Confidence):
            try:
                self.confidence = Confidence.from_dict(self.confidence)
            except ConfidenceError as exc:
                raise ArtifactError(str(exc)) from None
        # the LED patterns the site patterns give (the one expansion of a construction)
        from_sites = None
        if self.site_patterns is not None:
            with np.errstate(over="ignore"):  # out-of-range values become inf: refused below
                self.site_patterns = np.asarray(self.site_patterns, dtype=np.float32)
            if self.site_patterns.ndim == 2:
                from_sites = site_to_led_patterns(self.site_patterns)
        if self.led_patterns is None and self.learned is not None:
            self.led_patterns = self.learned.patterns
        if self.led_patterns is None:
            if from_sites is None:
                raise ArtifactError("give led_patterns (32, N) or site_patterns (8, m)")
            self.led_patterns = from_sites
        with np.errstate(over="ignore"):
            self.led_patterns = np.asarray(self.led_patterns, dtype=np.float32)
        self.class_names = [str(c) for c in self.class_names]
        if isinstance(self.hog_config, dict):
            self.hog_config = HogConfig.from_dict(self.hog_config)
        self.noise = noise_to_dict(self.noise)
        self.stages = [s if isinstance(s, LinearStage) else LinearStage(*s) for s in self.stages]
        self.stages.sort(key=lambda s: s.n_images)
        self._validate(from_sites)

    # --- construction
    @classmethod
    def from_classifiers(cls, classifiers, led_patterns=None, *, site_patterns=None,
                         mode=None, class_names=None, noise=None, provenance=None,
                         dimmer=DEFAULT_DIMMER):
        """Build from fitted MuxClassifiers (one per image count) and the patterns.

        Give ``site_patterns`` (8, m) for the paper's per-colour mode (the LED patterns are
        derived from it) or ``led_patterns`` (32, N). ``class_names`` default to the
        classifiers' ``classes_`` (as strings); the stored labels are their indices.
        ``dimmer``: the one the training rendered its images with.
        """
        classifiers = list(classifiers)
        if not classifiers:
            raise ArtifactError("no classifiers given; train at least one image count")
        first = classifiers[0]
        for clf in classifiers:
            check_is_fitted(clf, "coef_")
            if not np.array_equal(clf.classes_, first.classes_):
                raise ArtifactError("classifiers were trained on different classes")
        if site_patterns is not None:
            led_patterns = None  # derived from the site patterns
            mode = mode or "per_colour"
        elif led_patterns is None:
            raise ArtifactError("give led_patterns (32, N) or site_patterns (8, m)")
        names = class_names if class_names is not None else [str(c) for c in first.classes_]
        if len({c.features for c in classifiers}) != 1:
            raise ArtifactError("classifiers were trained on different features")
        stages = [LinearStage(int(c.n_images_), c.coef_, c.intercept_) for c in classifiers]
        return cls(led_patterns=led_patterns, class_names=list(names), stages=stages,
                   noise=noise, hog_config=first._config(), mode=mode or "joint",
                   site_patterns=site_patterns, provenance=dict(provenance or {}),
                   dimmer=dimmer, features=first.features)

    @classmethod
    def from_learned(cls, model: LearnedModel, *, noise=None, hog_config=None,
                     provenance=None, dimmer=DEFAULT_DIMMER, class_names=None):
        """Build from a fitted learned-illumination model (`LearnedModel`): its patterns,
        its classifier for its k images; ``class_names`` default to the model's."""
        names = list(model.class_names) if class_names is None else list(class_names)
        return cls(led_patterns=None, class_names=names, stages=[], noise=noise,
                   hog_config=hog_config or HogConfig(), mode=LEARNED_MODE,
                   provenance=dict(provenance or {}), dimmer=dimmer,
                   features=LEARNED_FEATURES, learned=model)

    def _validate(self, from_sites):
        """Refuse inconsistent fields; then build the estimators that predict.
        ``from_sites``: the LED patterns the site patterns give (None if they give none)."""
        P = self.led_patterns
        if P.ndim != 2 or P.shape[0] != N_LEDS or P.shape[1] < 1:
            raise ArtifactError(f"led_patterns must be ({N_LEDS}, N >= 1), got shape {P.shape}")
        if not np.isfinite(P).all() or P.min() < 0 or P.max() > 1:
            raise ArtifactError("led_patterns must hold values in [0, 1]")
        if self.mode not in MODES:
            raise ArtifactError(f"mode must be one of {MODES}, got {self.mode!r}")
        self.dimmer = _positive_dimmer(self.dimmer, "dimmer")
        if self.site_patterns is not None:
            if from_sites is None or not np.array_equal(from_sites, P):
                raise ArtifactError("site_patterns do not give led_patterns (per-colour order R, G, B, NIR)")
        n_classes = len(self.class_names)
        if n_classes < 2 or len(set(self.class_names)) != n_classes:
            raise ArtifactError(f"need at least 2 distinct class names, got {self.class_names}")
        if (self.learned is not None) != (self.mode == LEARNED_MODE):
            raise ArtifactError(f"mode {self.mode!r} with{'' if self.learned is not None else 'out'}"
                                f" a learned model: mode {LEARNED_MODE!r} goes with one, and only "
                                "with one")
        if self.learned is not None:
            self._validate_learned()
            self._validate_confidence()
            self._validate_novelty()
            return
        if not self.stages:
            raise ArtifactError("the artifact holds no classifier")
        if not isinstance(self.features, str):
            raise ArtifactError(f"features must name a feature extractor, got "
                                f"{reprlib.repr(self.features)}")
        try:
            nf = searchable_extractor(self.features, self.hog_config).features_per_image
        except ValueError as exc:
            raise ArtifactError(str(exc)) from None
        seen = set()
        for s in self.stages:
            s.n_images = int(s.n_images)
            s.coef = np.asarray(s.coef, dtype=np.float64)
            s.intercept = np.asarray(s.intercept, dtype=np.float64).reshape(-1)
            if not 1 <= s.n_images <= P.shape[1] or s.n_images in seen:
                raise ArtifactError(
                    f"classifier for {s.n_images} images: must be 1..{P.shape[1]} and unique")
            seen.add(s.n_images)
            if s.coef.shape != (n_classes, s.n_images * nf) or s.intercept.shape != (n_classes,):
                raise ArtifactError(
                    f"classifier for {s.n_images} images has coef {s.coef.shape} and intercept "
                    f"{s.intercept.shape}; expected ({n_classes}, {s.n_images * nf}) and ({n_classes},)")
            if not (np.isfinite(s.coef).all() and np.isfinite(s.intercept).all()):
                raise ArtifactError(f"classifier for {s.n_images} images has non-finite weights")
        classes = np.asarray(self.class_names)
        self._classifiers = {
            s.n_images: MuxClassifier.from_linear(s.coef, s.intercept, classes,
                                                  hog_config=self.hog_config,
                                                  features=self.features)
            for s in self.stages}
        self._validate_confidence()
        self._validate_novelty()

    def _validate_novelty(self):
        """Novelty models cover only image counts the artifact has a classifier for, each on
        that many images' `NOVELTY_FEATURES`."""
        if not self.novelty:
            self.novelty = None
            return
        extra = sorted(set(self.novelty) - set(self.n_images))
        if extra:
            raise ArtifactError(f"the novelty models name image counts {extra} that have no "
                                f"classifier (it has {self.n_images})")
        per_image = make_extractor(NOVELTY_FEATURES, self.hog_config).features_per_image
        for k, model in self.novelty.items():
            if model.n_features_in_ != k * per_image:
                raise ArtifactError(f"the novelty model for {k} images scores "
                                    f"{model.n_features_in_} features, not {k} x {per_image} "
                                    f"({NOVELTY_FEATURES})")

    def _validate_confidence(self):
        """A calibration covers only image counts the artifact has a classifier for."""
        if self.confidence is None:
            return
        extra = sorted(set(self.confidence.counts) - set(self.n_images))
        if extra:
            raise ArtifactError(f"the calibration names image counts {extra} that have no "
                                f"classifier (it has {self.n_images})")

    def _validate_learned(self):
        """A learned model's arrays are finite and sized as the artifact says; it is the
        artifact's one classifier."""
        m = self.learned
        arrays = {"patterns": m.patterns, "feature_mean": m.feature_mean,
                  "feature_scale": m.feature_scale}
        for i, (W, b) in enumerate(m.layers):
            arrays[f"layer{i}_W"], arrays[f"layer{i}_b"] = W, b
        for name, a in arrays.items():
            if not np.isfinite(a).all():
                raise ArtifactError(f"learned model array {name!r} holds non-finite values")
        if m.patterns.shape[0] != N_LEDS or not 1 <= m.n_images <= MAX_IMAGES:
            raise ArtifactError(f"learned model array 'patterns' must be ({N_LEDS}, k) with k "
                                f"in 1 .. {MAX_IMAGES}, got shape {m.patterns.shape}")
        if not np.array_equal(m.patterns, self.led_patterns):
            raise ArtifactError("led_patterns differ from the learned model's patterns")
        for i, (W, _) in enumerate(m.layers[:-1]):
            if W.shape[1] > MAX_LEARNED_WIDTH:
                raise ArtifactError(f"learned model layer {i} has {W.shape[1]} outputs, more "
                                    f"than {MAX_LEARNED_WIDTH}")
        if m.n_classes != len(self.class_names):
            raise ArtifactError(f"the learned model scores {m.n_classes} classes but "
                                f"class_names lists {len(self.class_names)}")
        if m.class_names and list(m.class_names) != self.class_names:
            raise ArtifactError(f"the learned model's class names {reprlib.repr(m.class_names)} "
                                f"differ from class_names {reprlib.repr(self.class_names)}")
        if self.stages:
            raise ArtifactError("a learned artifact classifies with its learned model: give no "
                                "linear stages")
        if self.features != LEARNED_FEATURES:
            raise ArtifactError(f"a learned model classifies with {LEARNED_FEATURES!r} "
                                f"features, not {reprlib.repr(self.features)}")
        self._classifiers = {m.n_images: LearnedModelClassifier.from_model(
            m, np.asarray(self.class_names), hog_config=self.hog_config)}

    # --- use
    def describe(self) -> str:
        """One line of what the artifact holds, for logs and listings."""
        dimmer = f"dimmer {self.dimmer:g}"
        if not self.dimmer_recorded:
            dimmer += (f" (not recorded: a format-1 file; every training before format 2 "
                       f"used {UNRECORDED_DIMMER:g})")
        mode = f"{self.mode} patterns"
        if self.learned is not None:
            levels = "on/off" if np.isin(self.led_patterns, (0, 1)).all() else "graded"
            gated = ", gated by object type" if self.learned.class_groups is not None else ""
            mode = f"learned {levels} patterns ({len(self.learned.layers)}-layer head{gated})"
        features = self.features + (" + cross-image relief"
                                    if self.learned is not None and self.learned.ratio_offset else "")
        calibrated = ("calibrated, anytime stop at "
                      f"{100 * self.confidence.stop_probability:.0f} %"
                      if self.confidence is not None else "uncalibrated")
        if self.novelty:
            rate = max(m.false_alarm_rate_ for m in self.novelty.values())
            calibrated += f"; unknown objects flagged at {100 * rate:g} % false alarms"
        inner = self.provenance.get("inner_estimate")
        if isinstance(inner, dict) and isinstance(inner.get("accuracy"), (int, float)):
            calibrated += (f"; inner estimate {100 * inner['accuracy']:.1f} % on held-out "
                           f"{inner.get('held_out', 'poses')}")
        return (f"{len(self.class_names)} classes, {mode}, {features} "
                f"features, classifiers for {self.n_images} images ({calibrated}), noise "
                f"{self.noise.get('name')}, {dimmer}")

    @property
    def n_images(self) -> list[int]:
        """Image counts that have a classifier, increasing."""
        if self.learned is not None:
            return [self.learned.n_images]
        return [s.n_images for s in self.stages]

    def stage(self, n_images: int | None = None) -> LinearStage:
        """The classifier for ``n_images`` (None: the one using the most images)."""
        if n_images is None:
            return self.stages[-1]
        for s in self.stages:
            if s.n_images == n_images:
                return s
        raise self._no_classifier(n_images)

    def _no_classifier(self, n_images) -> ArtifactError:
        return ArtifactError(
            f"this artifact has classifiers for {self.n_images} images, not {n_images}; "
            f"capture the first k images of its patterns (in order) for one of those k")

    def classifier(self, n_images: int | None = None):
        """The fitted estimator for ``n_images`` (labels are class names): a MuxClassifier,
        or a learned artifact's LearnedModelClassifier; every prediction of the artifact is
        its."""
        k = self.n_images[-1] if n_images is None else n_images
        if k not in self._classifiers:
            raise self._no_classifier(n_images)
        return self._classifiers[k]

    def _check(self, stacks, n_images):
        try:
            arr = check_stacks(stacks, self.hog_config)
        except ValueError as exc:
            raise ArtifactError(str(exc)) from None
        k = arr.shape[1]
        if n_images is None:
            n_images = k
        elif k != n_images:
            raise ArtifactError(f"expected {n_images} images per stack, got {k}")
        self.classifier(n_images)
        return arr

    def decision_function(self, stacks, n_images: int | None = None) -> np.ndarray:
        """Scores (n, n_classes) for stacks (n, k, H, W); k selects the classifier."""
        arr = self._check(stacks, n_images)
        return self.classifier(arr.shape[1]).decision_function(arr)

    def predict(self, stacks, n_images: int | None = None) -> np.ndarray:
        """Class names (n,) for stacks (n, k, H, W)."""
        arr = self._check(stacks, n_images)
        return self.classifier(arr.shape[1]).predict(arr)

    def predict_stack(self, images) -> Prediction:
        """Classify one sample from its images (k, H, W) taken under the first k patterns."""
        arr = np.asarray(images)
        if arr.ndim != 3:
            raise ArtifactError(
                f"predict_stack expects one sample's images (k, H, W), got shape {arr.shape}")
        scores = self.decision_function(arr[None])[0]
        i = int(np.argmax(scores))
        return Prediction(self.class_names[i], i, scores, arr.shape[0])

    # --- calibrated answers (`confidence`)
    @property
    def calibrated(self) -> bool:
        """True when the artifact carries calibrated probabilities (format 7 on)."""
        return self.confidence is not None

    def anytime_steps(self, max_images: int = 0) -> list[int]:
        """The image counts at which a calibrated answer may stop, increasing; the last is
        the budget (the largest count <= ``max_images``, 0 = all). Uncalibrated: [budget]."""
        usable = [k for k in self.n_images if max_images <= 0 or k <= max_images]
        if not usable:
            raise self._no_classifier(max_images)
        budget = usable[-1]
        if self.confidence is None:
            return [budget]
        steps = [k for k in usable if k in self.confidence.temperatures]
        return steps if steps and steps[-1] == budget else [*steps, budget]

    def decide(self, images, target_probability: float | None = None,
               final: bool = False) -> Decision:
        """The answer from one sample's images (k, H, W) under the first k patterns.

        Calibrated: probabilities of the classifier for k images; the decision is accepted
        when the top class reaches the target (``target_probability``; None or >= 1: the
        trained one), else unsure; ``stop`` when it is accepted (unless
        ``target_probability`` >= 1: every image) or when ``final`` (the budget is spent).
        Uncalibrated: no probabilities; it stops only when ``final`` and accepts the label.
        Either way, with a novelty model for k images: ``novelty`` is its score and the
        decision is unknown where it is >= 1 (when it stops is unchanged).
        """
        prediction = self.predict_stack(images)
        k = prediction.n_images
        novelty = self.novelty_score(images)
        unknown = bool(novelty >= 1.0)
        if self.confidence is None or k not in self.confidence.temperatures:
            return Decision(prediction.label, prediction.index, prediction.scores,
                            np.empty(0, dtype=np.float64), UNKNOWN if unknown else ACCEPTED,
                            novelty, bool(final), k)
        fixed = target_probability is not None and float(target_probability) >= 1.0
        target = (self.confidence.stop_probability if target_probability is None or fixed
                  else float(target_probability))
        probabilities = self.confidence.probabilities(prediction.scores, k)[0]
        reached = bool(probabilities[prediction.index] >= target)
        decision = UNKNOWN if unknown else ACCEPTED if reached else UNSURE
        return Decision(prediction.label, prediction.index, prediction.scores, probabilities,
                        decision, novelty, (reached and not fixed) or bool(final), k)

    def novelty_score(self, images) -> float:
        """How unlike every trained class one sample's images (k, H, W) are: >= 1 unknown,
        NaN without a novelty model for k images."""
        arr = np.asarray(images)
        if not self.novelty or arr.ndim != 3 or arr.shape[0] not in self.novelty:
            return math.nan
        try:
            X = make_extractor(NOVELTY_FEATURES, self.hog_config).raw_features(arr[None])
        except ValueError as exc:
            raise ArtifactError(str(exc)) from None
        return float(self.novelty[arr.shape[0]].score(X)[0])

    @staticmethod
    def check_target_probability(value) -> float | None:
        """A requested target: 0 -> None (the trained rule); ArtifactError outside 0 .. 1."""
        try:
            return check_target_probability(value)
        except ConfidenceError as exc:
            raise ArtifactError(str(exc)) from None


    # --- file (`artifact_format`)
    def save(self, path) -> None:
        """Write the artifact to ``path`` (``.npz``); written to a temporary file first."""
        write_artifact(path, self)

    @classmethod
    def load(cls, path) -> "TrainedArtifact":
        """Read an artifact written by :meth:`save` (any readable format version); never
        unpickles, never runs code.

        Whatever else ``path`` holds (nothing, a directory, another kind of file, an archive
        whose members are not .npy arrays, a malformed header or arrays) raises ArtifactError
        saying what is wrong: a caller catches that one type.
        """
        return read_artifact(path, cls)


def _learned_model(arrays) -> LearnedModel:
    """A LearnedModel from its named arrays (`LearnedModel.to_arrays`); ArtifactError naming
    what is wrong."""
    try:
        return LearnedModel.from_arrays(dict(arrays))
    except KeyError as exc:
        raise ArtifactError(f"learned model arrays lack {exc}; retrain to get a new file") from None
    except (TypeError, ValueError) as exc:
        raise ArtifactError(f"learned model arrays: {exc}") from None


def _novelty_models(novelty) -> dict:
    """{image count: NoveltyModel} from models or their named arrays; ArtifactError naming
    what is wrong."""
    if not isinstance(novelty, dict):
        raise ArtifactError(f"novelty must map image counts to novelty models, got "
                            f"{type(novelty).__name__}")
    models = {}
    for k, model in novelty.items():
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ArtifactError(f"novelty key {reprlib.repr(k)} is not an image count")
        if not isinstance(model, NoveltyModel):
            try:
                model = NoveltyModel.from_arrays(dict(model))
            except (TypeError, ValueError) as exc:
                raise ArtifactError(f"the novelty model for {k} images: {exc}") from None
        elif not hasattr(model, "threshold_"):
            raise ArtifactError(f"the novelty model for {k} images is not fitted")
        models[int(k)] = model
    return dict(sorted(models.items()))


def _positive_dimmer(value, what: str) -> float:
    try:
        dimmer = float(value)
    except (TypeError, ValueError, OverflowError):
        dimmer = math.nan
    if isinstance(value, bool) or not (math.isfinite(dimmer) and dimmer > 0):
        raise ArtifactError(f"{what} must be a positive number, got {reprlib.repr(value)}")
    try:
        return check_range(dimmer, what, DIMMER_MIN, DIMMER_MAX)
    except LimitError as exc:
        raise ArtifactError(str(exc)) from None


def check_dimmer(artifact_dimmer: float, camera_dimmer: float) -> None:
    """Refuse a camera whose dimmer differs from the classifier's training dimmer.

    The dimmer scales every single-LED image, so a classifier sees images brighter or dimmer
    than it was trained on and classifies wrong without any error. Raises DimmerMismatch
    naming both values and the parameter to set.
    """
    trained = _positive_dimmer(artifact_dimmer, "the classifier's dimmer")
    camera = _positive_dimmer(camera_dimmer, "the camera's dimmer")
    if not math.isclose(trained, camera, rel_tol=1e-6):
        raise DimmerMismatch(
            f"the classifier was trained with dimmer {trained:g} but the camera's dimmer is "
            f"{camera:g}: its images would be {camera / trained:.3g} x as bright as the "
            f"training's and classify wrong. Set the camera node's dimmer parameter to "
            f"{trained:g}, or use a classifier trained with dimmer {camera:g}")

