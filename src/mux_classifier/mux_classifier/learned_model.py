"""Inference of a learned-illumination model in numpy (no autodiff library).

A learned model (`mux_trainer.learned`) is an LED pattern matrix ``patterns`` (32, k),
site-major, levels in [0, 1], one image per column, and a small classifier over the k
images: per image the 9 pose-robust object statistics of `intensity_stats` (exact,
`intensity_stats_images_numpy`: the values the training differentiated through), the
concatenated ``k * 9`` values z-scored with the training set's ``feature_mean`` and
``feature_scale``, then dense layers (ReLU between them; none after the last), whose
argmax is the class; or, for a model with ``class_groups``, a head gated by object type
(`gated_head`): its last layer scores the types, then each class within its type, and the
class is the best of the best type's. A model with a ``ratio_offset`` (gray levels, > 0)
has the stack's cross-image relief statistics after those (`ratio_stats`, that offset inside the log); one
without has none (every model written before them). Everything is plain arrays, for an npz
artifact without pickle.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .gated_head import check_class_groups, gated_margins
from .intensity_stats import N_STATS, intensity_stats_images_numpy
from .ratio_stats import n_ratio_stats, ratio_stats

__all__ = ["LearnedModel"]


@dataclass
class LearnedModel:
    """patterns (32, k); feature_mean, feature_scale (`n_features`,); layers: [(W, b), ...]
    with W (inputs, outputs), the last layer's outputs the classes' logits; class_names;
    ratio_offset: 0 (no cross-image statistics) or the offset of `ratio_stats`;
    class_groups: None (the last layer scores the classes) or each class's type 0 .. G - 1
    (it scores the G types, then the classes within their types: `gated_head`)."""

    patterns: np.ndarray
    feature_mean: np.ndarray
    feature_scale: np.ndarray
    layers: list
    class_names: list = field(default_factory=list)
    ratio_offset: float = 0.0
    class_groups: np.ndarray | None = None

    def __post_init__(self):
        self.patterns = np.asarray(self.patterns, dtype=np.float32)
        if self.patterns.ndim != 2:
            raise ValueError(f"patterns must be (LEDs, k), got shape {self.patterns.shape}")
        if self.patterns.min() < 0 or self.patterns.max() > 1:
            raise ValueError("patterns: LED levels must lie in [0, 1]")
        self.ratio_offset = float(self.ratio_offset)
        if not (np.isfinite(self.ratio_offset) and self.ratio_offset >= 0):
            raise ValueError(f"ratio_offset must be 0 or a positive number of gray levels, "
                             f"got {self.ratio_offset}")
        self.feature_mean = np.asarray(self.feature_mean, dtype=np.float32).reshape(-1)
        self.feature_scale = np.asarray(self.feature_scale, dtype=np.float32).reshape(-1)
        n_in = self.n_features
        if self.feature_mean.size != n_in or self.feature_scale.size != n_in:
            ratio = (f" + {n_ratio_stats(self.n_images)} cross-image statistics"
                     if self.ratio_offset else "")
            raise ValueError(f"feature_mean and feature_scale must hold {n_in} values "
                             f"({self.n_images} images x {N_STATS}{ratio}), got "
                             f"{self.feature_mean.size} and {self.feature_scale.size}")
        if not (self.feature_scale > 0).all():
            raise ValueError("feature_scale must be > 0 everywhere")
        self.layers = [(np.asarray(W, np.float32), np.asarray(b, np.float32).reshape(-1))
                       for W, b in self.layers]
        if not self.layers:
            raise ValueError("layers: give at least one (W, b) layer")
        width = n_in
        for i, (W, b) in enumerate(self.layers):
            if W.ndim != 2 or W.shape[0] != width or b.shape != (W.shape[1],):
                raise ValueError(f"layer {i}: W must be ({width}, m) and b (m,), got "
                                 f"{W.shape} and {b.shape}")
            width = W.shape[1]
        self.class_names = list(self.class_names)
        if self.class_groups is not None:
            self.class_groups = check_class_groups(self.class_groups)
            if width != self.n_groups + self.class_groups.size:
                raise ValueError(f"a head gated by type scores the {self.n_groups} types, then "
                                 f"the {self.class_groups.size} classes: its last layer needs "
                                 f"{self.n_groups + self.class_groups.size} outputs, got {width}")

    @property
    def n_groups(self) -> int:
        """Types the head is gated by (0: not gated)."""
        return 0 if self.class_groups is None else int(self.class_groups.max()) + 1

    @property
    def n_images(self) -> int:
        return self.patterns.shape[1]

    @property
    def n_features(self) -> int:
        """Raw features per stack: k * 9 object statistics (+ the cross-image ones)."""
        k = self.n_images
        return k * N_STATS + (n_ratio_stats(k) if self.ratio_offset else 0)

    @property
    def n_classes(self) -> int:
        return self.layers[-1][0].shape[1] - self.n_groups

    def features(self, stacks) -> np.ndarray:
        """Stacks (n, k, H, W) gray levels -> float32 (n, `n_features`) raw statistics."""
        arr = np.asarray(stacks, dtype=np.float32)
        if arr.ndim != 4 or arr.shape[1] != self.n_images:
            raise ValueError(f"expected stacks (n, {self.n_images}, H, W), one image per "
                             f"learned pattern in pattern order; got shape {arr.shape}")
        n, k, H, W = arr.shape
        X = intensity_stats_images_numpy(arr.reshape(n * k, H, W)).reshape(n, k * N_STATS)
        if not self.ratio_offset:
            return X
        return np.hstack([X, ratio_stats(arr, self.ratio_offset)])

    def logits_from_features(self, X) -> np.ndarray:
        """Raw features (n, `n_features`) -> the last layer's outputs, float32: (n, classes),
        or with `class_groups` (n, types + classes)."""
        h = (np.asarray(X, np.float32) - self.feature_mean) / self.feature_scale
        for i, (W, b) in enumerate(self.layers):
            h = h @ W + b
            if i < len(self.layers) - 1:
                h = np.maximum(h, 0)
        return h

    def scores_from_features(self, X) -> np.ndarray:
        """Raw features (n, `n_features`) -> per-class scores (n, classes) whose argmax is the
        class: the logits, or for a head gated by type its margins (`gated_margins`)."""
        out = self.logits_from_features(X)
        if self.class_groups is None:
            return out
        return gated_margins(out, self.class_groups).astype(np.float32)

    def predict_features(self, X) -> np.ndarray:
        return np.argmax(self.scores_from_features(X), axis=1)

    def predict(self, stacks) -> np.ndarray:
        """Class indices of stacks (n, k, H, W) taken under `patterns`."""
        return self.predict_features(self.features(stacks))

    def to_arrays(self) -> dict:
        """Named arrays (for an npz; `from_arrays` inverts it)."""
        out = {"patterns": self.patterns, "feature_mean": self.feature_mean,
               "feature_scale": self.feature_scale,
               "class_names": np.asarray(self.class_names, dtype=str)}
        if self.ratio_offset:   # absent: a model without them, readable by older releases too
            out["ratio_offset"] = np.float64(self.ratio_offset)
        if self.class_groups is not None:   # absent: the last layer scores the classes
            out["class_groups"] = self.class_groups
        for i, (W, b) in enumerate(self.layers):
            out[f"layer{i}_W"] = W
            out[f"layer{i}_b"] = b
        return out

    @classmethod
    def from_arrays(cls, arrays) -> "LearnedModel":
        layers = []
        while f"layer{len(layers)}_W" in arrays:
            i = len(layers)
            layers.append((arrays[f"layer{i}_W"], arrays[f"layer{i}_b"]))
        missing = {"patterns", "feature_mean", "feature_scale"} - set(arrays)
        if missing:
            raise ValueError(f"learned model arrays lack {sorted(missing)}")
        offset = np.asarray(arrays.get("ratio_offset", 0.0), dtype=np.float64)
        if offset.size != 1:
            raise ValueError(f"ratio_offset must be one number, got shape {offset.shape}")
        groups = arrays.get("class_groups")
        return cls(arrays["patterns"], arrays["feature_mean"], arrays["feature_scale"], layers,
                   [str(c) for c in arrays.get("class_names", [])], float(offset.reshape(())),
                   None if groups is None else np.asarray(groups))
