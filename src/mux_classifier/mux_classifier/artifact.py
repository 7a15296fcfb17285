"""The trained-classifier artifact: what training produces and the classify node loads.

``TrainedArtifact``: the LED pattern matrix (32, N) in image order, the per-colour site
matrix when the paper's mode was used, the noise setting and the dimmer it was trained for,
class names, the feature extractor (by name) and HOG configuration, one linear classifier
for each image count (on the extractor's raw features), and provenance.
``save``/``load`` use a versioned ``.npz`` whose metadata is a JSON document stored as a
uint8 array; it is read with ``allow_pickle=False``, so opening a file never runs code. The
file format is documented in docs/CLASSIFIER.md.
"""
from __future__ import annotations

import io
import json
import math
import os
import reprlib
import secrets
import stat
import zipfile
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from lightstage_physics.noise import check_noise_coefficients
from lightstage_physics.rig import DEFAULT_DIMMER, N_LEDS, site_to_led_patterns
from lightstage_graph.limits import DIMMER_MAX, DIMMER_MIN, LimitError, check_range
from sklearn.utils.validation import check_is_fitted

from .estimator import MuxClassifier
from .features import DEFAULT_EXTRACTOR, check_stacks, searchable_extractor
from .hog import HogConfig

__all__ = [
    "LinearStage", "Prediction", "TrainedArtifact", "ArtifactError", "DimmerMismatch",
    "FORMAT_NAME", "FORMAT_VERSION", "READABLE_VERSIONS", "UNRECORDED_DIMMER", "noise_to_dict",
    "check_dimmer",
]

FORMAT_NAME = "lightstage.mux_classifier"
# 3: the header names the feature extractor ("features"); before, it was always the HOG grid.
# 2: the header records the dimmer the training rendered with. 1: it did not; every
# training that wrote version 1 rendered at the authors' dimmer, `UNRECORDED_DIMMER` (should
# DEFAULT_DIMMER ever change, this must keep its old value).
FORMAT_VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
UNRECORDED_DIMMER = DEFAULT_DIMMER
MODES = ("per_colour", "joint", "naive")
MAX_IMAGES = 4096  # images of one classification: far beyond any search (16 in the paper)
DIMMER_RANGE = (DIMMER_MIN, DIMMER_MAX)


class ArtifactError(ValueError):
    """A trained-classifier file or its input is unusable; the message says why and what to do."""


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
    it (its trainings all used `UNRECORDED_DIMMER`).
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

    def __post_init__(self):
        with np.errstate(over="ignore"):  # out-of-range values become inf: refused below
            self.led_patterns = np.asarray(self.led_patterns, dtype=np.float32)
        self.class_names = [str(c) for c in self.class_names]
        if isinstance(self.hog_config, dict):
            self.hog_config = HogConfig.from_dict(self.hog_config)
        self.noise = noise_to_dict(self.noise)
        if self.site_patterns is not None:
            with np.errstate(over="ignore"):
                self.site_patterns = np.asarray(self.site_patterns, dtype=np.float32)
        self.stages = [s if isinstance(s, LinearStage) else LinearStage(*s) for s in self.stages]
        self.stages.sort(key=lambda s: s.n_images)
        self._validate()

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
            led_patterns = site_to_led_patterns(site_patterns)
            mode = mode or "per_colour"
        if led_patterns is None:
            raise ArtifactError("give led_patterns (32, N) or site_patterns (8, m)")
        names = class_names if class_names is not None else [str(c) for c in first.classes_]
        if len({c.features for c in classifiers}) != 1:
            raise ArtifactError("classifiers were trained on different features")
        stages = [LinearStage(int(c.n_images_), c.coef_, c.intercept_) for c in classifiers]
        return cls(led_patterns=led_patterns, class_names=list(names), stages=stages,
                   noise=noise, hog_config=first._config(), mode=mode or "joint",
                   site_patterns=site_patterns, provenance=dict(provenance or {}),
                   dimmer=dimmer, features=first.features)

    def _validate(self):
        P = self.led_patterns
        if P.ndim != 2 or P.shape[0] != N_LEDS or P.shape[1] < 1:
            raise ArtifactError(f"led_patterns must be ({N_LEDS}, N >= 1), got shape {P.shape}")
        if not np.isfinite(P).all() or P.min() < 0 or P.max() > 1:
            raise ArtifactError("led_patterns must hold values in [0, 1]")
        if self.mode not in MODES:
            raise ArtifactError(f"mode must be one of {MODES}, got {self.mode!r}")
        self.dimmer = _positive_dimmer(self.dimmer, "dimmer")
        if self.site_patterns is not None:
            W = self.site_patterns
            if W.ndim != 2 or not np.array_equal(site_to_led_patterns(W), P):
                raise ArtifactError("site_patterns do not give led_patterns (per-colour order R, G, B, NIR)")
        n_classes = len(self.class_names)
        if n_classes < 2 or len(set(self.class_names)) != n_classes:
            raise ArtifactError(f"need at least 2 distinct class names, got {self.class_names}")
        if not self.stages:
            raise ArtifactError("the artifact holds no classifier")
        if not isinstance(self.features, str):
            raise ArtifactError(f"features must name a feature extractor, got "
                                f"{reprlib.repr(self.features)}")
        try:
            self._extractor = searchable_extractor(self.features, self.hog_config)
        except ValueError as exc:
            raise ArtifactError(str(exc)) from None
        nf = self._extractor.features_per_image
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

    # --- use
    def describe(self) -> str:
        """One line of what the artifact holds, for logs and listings."""
        dimmer = f"dimmer {self.dimmer:g}"
        if not self.dimmer_recorded:
            dimmer += (f" (not recorded: a format-1 file; every training before format 2 "
                       f"used {UNRECORDED_DIMMER:g})")
        return (f"{len(self.class_names)} classes, {self.mode} patterns, {self.features} "
                f"features, classifiers for {self.n_images} images, noise "
                f"{self.noise.get('name')}, {dimmer}")

    @property
    def n_images(self) -> list[int]:
        """Image counts that have a classifier, increasing."""
        return [s.n_images for s in self.stages]

    def stage(self, n_images: int | None = None) -> LinearStage:
        """The classifier for ``n_images`` (None: the one using the most images)."""
        if n_images is None:
            return self.stages[-1]
        for s in self.stages:
            if s.n_images == n_images:
                return s
        raise ArtifactError(
            f"this artifact has classifiers for {self.n_images} images, not {n_images}; "
            f"capture the first k images of its patterns (in order) for one of those k")

    def classifier(self, n_images: int | None = None) -> MuxClassifier:
        """A fitted MuxClassifier for ``n_images`` (labels are class names)."""
        s = self.stage(n_images)
        return MuxClassifier.from_linear(s.coef, s.intercept, np.asarray(self.class_names),
                                         hog_config=self.hog_config, features=self.features)

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
        self.stage(n_images)
        return arr

    def decision_function(self, stacks, n_images: int | None = None) -> np.ndarray:
        """Scores (n, n_classes) for stacks (n, k, H, W); k selects the classifier."""
        arr = self._check(stacks, n_images)
        s = self.stage(arr.shape[1])
        X = self._extractor.raw_features(arr)
        return X.astype(np.float64) @ s.coef.T + s.intercept

    def predict(self, stacks, n_images: int | None = None) -> np.ndarray:
        """Class names (n,) for stacks (n, k, H, W)."""
        scores = self.decision_function(stacks, n_images)
        return np.asarray(self.class_names)[np.argmax(scores, axis=1)]

    def predict_stack(self, images) -> Prediction:
        """Classify one sample from its images (k, H, W) taken under the first k patterns."""
        arr = np.asarray(images)
        if arr.ndim != 3:
            raise ArtifactError(
                f"predict_stack expects one sample's images (k, H, W), got shape {arr.shape}")
        scores = self.decision_function(arr[None])[0]
        i = int(np.argmax(scores))
        return Prediction(self.class_names[i], i, scores, arr.shape[0])

    # --- file
    def _header(self) -> dict:
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "mode": self.mode,
            "class_names": self.class_names,
            "noise": self.noise,
            "hog_config": self.hog_config.to_dict(),
            "n_images": self.n_images,
            "has_site_patterns": self.site_patterns is not None,
            "provenance": self.provenance,
            "dimmer": self.dimmer,
            "features": self.features,
        }

    def save(self, path) -> None:
        """Write the artifact to ``path`` (``.npz``); written to a temporary file first."""
        try:
            header = json.dumps(self._header(), sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ArtifactError(f"provenance/noise must be plain JSON (no NaN): {exc}") from exc
        arrays = {"header": np.frombuffer(header.encode("utf-8"), dtype=np.uint8),
                  "led_patterns": self.led_patterns}
        if self.site_patterns is not None:
            arrays["site_patterns"] = self.site_patterns
        for s in self.stages:
            arrays[f"coef_{s.n_images}"] = s.coef
            arrays[f"intercept_{s.n_images}"] = s.intercept
        path = os.fspath(path)
        directory = os.path.dirname(os.path.abspath(path))
        # a new file of its own ("x": never another's), created with the umask's mode as any
        # other file (mkstemp's 0600 would survive the rename: unreadable to other users)
        tmp = os.path.join(directory, f".artifact-{os.getpid()}-{secrets.token_hex(6)}.npz")
        fh = open(tmp, "xb")
        try:
            with fh:
                np.savez_compressed(fh, **arrays)
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise

    @classmethod
    def load(cls, path) -> "TrainedArtifact":
        """Read an artifact written by :meth:`save`; never unpickles, never runs code.

        Whatever else ``path`` holds (nothing, a directory, another kind of file, an archive
        whose members are not .npy arrays, a malformed header or arrays) raises ArtifactError
        saying what is wrong: a caller catches that one type.
        """
        path = os.fspath(path)
        what = f"{path!r} is not a readable lightstage classifier file"
        arrays = _read_npz(path, what)
        header = _read_header(arrays, what)
        version = header.get("format_version")
        if isinstance(version, bool) or version not in READABLE_VERSIONS:
            raise ArtifactError(
                f"{path!r}: its header field 'format_version' gives classifier format version "
                f"{reprlib.repr(version)}; this lightstage "
                f"reads version {FORMAT_VERSION} and the older "
                f"{', '.join(str(v) for v in READABLE_VERSIONS if v != FORMAT_VERSION)}. "
                "Retrain with this version (`lightstage train`) or use the lightstage release "
                "that wrote it")
        try:
            return cls._from_file(header, arrays)
        except ArtifactError as exc:
            raise ArtifactError(f"{what}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - whatever else a malformed file trips over
            raise ArtifactError(f"{what}: malformed content ({type(exc).__name__}: {exc}); "
                                "retrain to get a new file") from exc

    @classmethod
    def _from_file(cls, header: dict, arrays: dict) -> "TrainedArtifact":
        def field_of(key, kind, description):
            value = header.get(key)
            if not isinstance(value, kind):
                raise ArtifactError(f"header field {key!r} must be {description}, got "
                                    f"{reprlib.repr(value)}")
            return value

        def array(name):
            if name not in arrays:
                raise ArtifactError(f"it has no array {name!r}; retrain to get a new file")
            a = arrays[name]
            if a.dtype.kind not in "biuf":
                raise ArtifactError(f"array {name!r} holds {a.dtype} values, not real numbers")
            return a

        _check_header_ranges(header)
        n_images = field_of("n_images", list, "a list of image counts")
        if not all(isinstance(k, int) and not isinstance(k, bool) for k in n_images):
            raise ArtifactError(f"header field 'n_images' must list integers, got "
                                f"{reprlib.repr(n_images)}")
        class_names = field_of("class_names", list, "a list of class names")
        if not all(isinstance(c, str) for c in class_names):
            raise ArtifactError(f"header field 'class_names' must list strings, got "
                                f"{reprlib.repr(class_names)}")
        if header["format_version"] == 1:  # before the dimmer was recorded
            dimmer, recorded = UNRECORDED_DIMMER, False
        else:  # a number here; __post_init__ refuses booleans and values <= 0
            dimmer, recorded = field_of("dimmer", (int, float), "a positive number"), True
        features = (field_of("features", str, "the name of a feature extractor")
                    if header["format_version"] >= 3 else DEFAULT_EXTRACTOR)
        return cls(
            led_patterns=array("led_patterns"),
            class_names=class_names,
            stages=[LinearStage(k, array(f"coef_{k}"), array(f"intercept_{k}")) for k in n_images],
            noise=field_of("noise", dict, "an object (the noise setting)"),
            hog_config=HogConfig.from_dict(field_of("hog_config", dict, "an object")),
            mode=field_of("mode", str, f"one of {MODES}"),
            site_patterns=(_site_patterns(arrays, array)
                           if field_of("has_site_patterns", bool, "true or false") else None),
            provenance=dict(field_of("provenance", (dict, type(None)), "an object") or {}),
            dimmer=dimmer,
            dimmer_recorded=recorded,
            features=features,
        )


def _site_patterns(arrays: dict, array) -> np.ndarray:
    if "site_patterns" not in arrays:
        raise ArtifactError("header field 'has_site_patterns' is true but it has no array "
                            "'site_patterns'; retrain to get a new file")
    return array("site_patterns")


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


def _read_npz(path: str, what: str) -> dict:
    """The arrays of the .npz at ``path``; ArtifactError for anything else."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        raise ArtifactError(f"cannot read classifier file {path!r}: {exc}") from exc
    if not stat.S_ISREG(mode):  # a directory, a device (endless), a pipe (blocks)
        raise ArtifactError(f"{path!r} is not a regular file; point to the .npz written by "
                            "`lightstage train`")
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise ArtifactError(f"cannot read classifier file {path!r}: {exc}") from exc
    if not zipfile.is_zipfile(io.BytesIO(data)):
        raise ArtifactError(
            f"{what}: it is not an .npz archive (truncated, or another kind of file); "
            "point to the .npz written by `lightstage train`, or retrain")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except Exception as exc:  # noqa: BLE001 - corrupt members, pickled object arrays, bad CRC ...
        raise ArtifactError(f"{what}: {type(exc).__name__}: {exc}; retrain to get a new file") from exc
    # np.load hands a member that is not an .npy file back as its raw bytes
    not_arrays = sorted(name for name, a in arrays.items() if not isinstance(a, np.ndarray))
    if not_arrays:
        raise ArtifactError(f"{what}: its members {not_arrays} are not .npy arrays; retrain to "
                            "get a new file")
    return arrays


# The range of every header field the loader reads, beyond its type: (lo, hi) of a number, or
# of a list's length / a string's length. A field out of range is refused naming it.
MAX_CLASSES = 10_000
MAX_NAME_CHARS = 200
HOG_RANGES = {"image_size": (4, 2048), "cell_px": (1, 2048), "block_cells": (1, 2048),
              "orientations": (1, 360), "batch_size": (1, 4096)}


def _non_finite_field(value, path: str = "") -> str | None:
    """The path ('noise.gain_db', 'n_images[2]') of the first NaN or infinite number in a
    parsed header, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return path
    children = (value.items() if isinstance(value, dict)
                else enumerate(value) if isinstance(value, list) else ())
    for key, child in children:
        where = f"{path}[{key}]" if isinstance(key, int) else (f"{path}.{key}" if path else str(key))
        found = _non_finite_field(child, where)
        if found is not None:
            return found
    return None


def _check_header_ranges(header: dict) -> None:
    """Refuse, naming the field, a header value out of its range (the types are checked where
    each field is read; NaN and inf are refused by `_read_header`): the noise setting's coefficients,
    gain and exposure, the dimmer, the HOG configuration, the class names and image counts."""
    def within(path, value, lo, hi, unit=""):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                check_range(value, f"header field {path!r}", lo, hi, unit)
            except LimitError as exc:
                raise ArtifactError(str(exc)) from None

    noise = header.get("noise")
    if isinstance(noise, dict):
        unknown = sorted(set(noise) - {"name", "sigma_p2", "sigma_r2", "gain_db", "exposure_ms"})
        if unknown:
            raise ArtifactError(f"header field 'noise' has unknown keys {unknown}")
        if not isinstance(noise.get("name"), str):
            raise ArtifactError(f"header field 'noise.name' must be a string, got "
                                f"{reprlib.repr(noise.get('name'))}")
        for key in ("sigma_p2", "sigma_r2", "gain_db", "exposure_ms"):
            value = noise.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise ArtifactError(f"header field 'noise.{key}' must be a number or null, got "
                                    f"{reprlib.repr(value)}")
        if all(isinstance(noise.get(k), (int, float)) for k in ("sigma_p2", "sigma_r2", "gain_db",
                                                                "exposure_ms")):
            try:
                check_noise_coefficients(noise["sigma_p2"], noise["sigma_r2"], noise["gain_db"],
                                         noise["exposure_ms"], what="header field 'noise.{}'")
            except ValueError as exc:
                raise ArtifactError(str(exc)) from None
    hog = header.get("hog_config")
    if isinstance(hog, dict):
        unknown = sorted(set(hog) - set(HogConfig.__dataclass_fields__))
        if unknown:
            raise ArtifactError(f"header field 'hog_config' has unknown keys {unknown}")
        for key, (lo, hi) in HOG_RANGES.items():
            value = hog.get(key)
            if key in hog and (isinstance(value, bool) or not isinstance(value, int)):
                raise ArtifactError(f"header field 'hog_config.{key}' must be a whole number in "
                                    f"{lo} .. {hi}, got {reprlib.repr(value)}")
            within(f"hog_config.{key}", value, lo, hi)
    if "dimmer" in header:
        within("dimmer", header["dimmer"], DIMMER_RANGE[0], DIMMER_RANGE[1])
    names = header.get("class_names")
    if isinstance(names, list):
        if not 2 <= len(names) <= MAX_CLASSES:
            raise ArtifactError(f"header field 'class_names' must list 2 .. {MAX_CLASSES} "
                                f"classes, got {len(names)}")
        for i, name in enumerate(names):
            if isinstance(name, str) and not 1 <= len(name) <= MAX_NAME_CHARS:
                raise ArtifactError(f"header field 'class_names[{i}]' must be 1 .. "
                                    f"{MAX_NAME_CHARS} characters, got {reprlib.repr(name)}")
    counts = header.get("n_images")
    if isinstance(counts, list):
        if not counts:
            raise ArtifactError("header field 'n_images' lists no image count; the artifact "
                                "holds no classifier")
        for i, k in enumerate(counts):
            within(f"n_images[{i}]", k, 1, MAX_IMAGES)
    features = header.get("features")
    if isinstance(features, str):
        try:
            searchable_extractor(features)
        except ValueError as exc:
            raise ArtifactError(f"header field 'features': {exc}") from None
    mode = header.get("mode")
    if isinstance(mode, str) and mode not in MODES:
        raise ArtifactError(f"header field 'mode' must be one of {MODES}, got {reprlib.repr(mode)}")


def _json_number(text: str) -> float:
    return float(text)  # 1e400 is inf: refused naming its field (_check_header_ranges)


def _json_constant(name: str) -> float:
    return float(name.replace("Infinity", "inf"))  # NaN, Infinity: refused naming the field


def _read_header(arrays: dict, what: str) -> dict:
    """The artifact's JSON header (format name checked); ArtifactError if there is none."""
    if "header" not in arrays:
        raise ArtifactError(f"{what}: it has no header (an .npz from something else?)")
    raw = arrays["header"]
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise ArtifactError(f"{what}: its header is a {raw.dtype} array of shape {raw.shape}, "
                            "not the bytes of a JSON document (uint8, 1-D)")
    try:
        header = json.loads(raw.tobytes().decode("utf-8"), parse_float=_json_number,
                            parse_constant=_json_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ArtifactError(f"{what}: its header is not valid JSON ({exc})") from exc
    found = header.get("format") if isinstance(header, dict) else header
    if found != FORMAT_NAME or not isinstance(header, dict):
        raise ArtifactError(f"{what}: header format is {reprlib.repr(found)}, expected "
                            f"{FORMAT_NAME!r}")
    bad = _non_finite_field(header)
    if bad is not None:
        raise ArtifactError(f"{what}: its header field {bad!r} is not a finite number (NaN, "
                            "infinite or beyond a float); retrain to get a new file")
    return header
