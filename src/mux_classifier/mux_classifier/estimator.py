"""The multiplexed-illumination classifier, in scikit-learn estimator style.

``MuxClassifier``: features of a sample's k images (the paper's HOG grid, or another
extractor of `features` by name), concatenated in image order, then a multi-class linear
classifier, either a linear SVM (``LinearSVC``, one-vs-rest: the authors'
MATLAB code uses one-vs-all error-correcting output codes, which is the same decomposition)
or a ridge least-squares classifier (``RidgeClassifier``, the fast stand-in used inside the
pattern search). The trained classifier's file is `artifact.TrainedArtifact`.
"""
from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils.validation import check_is_fitted

from .features import DEFAULT_EXTRACTOR, check_stacks, column_scaling, searchable_extractor
from .hog import HogConfig

__all__ = ["ESTIMATORS", "LearnedModelClassifier", "MuxClassifier", "column_scaling",
           "fit_linear"]

ESTIMATORS = ("linear_svm", "ridge")



def _linear_arrays(estimator, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """coef (n_classes, F), intercept (n_classes,) from a fitted sklearn linear classifier.

    sklearn stores a two-class problem as one row (positive = classes[1]); it is expanded to
    two rows [-w, w] so that ``argmax`` always gives the prediction, as with more classes.
    """
    coef = np.asarray(estimator.coef_, dtype=np.float64)
    intercept = np.atleast_1d(np.asarray(estimator.intercept_, dtype=np.float64))
    if n_classes == 2 and coef.shape[0] == 1:
        coef = np.vstack([-coef, coef])
        intercept = np.concatenate([-intercept, intercept])
    return coef, intercept


def _make_estimator(estimator: str, C: float, alpha: float, max_iter: int, random_state):
    if estimator == "linear_svm":
        from sklearn.svm import LinearSVC

        return LinearSVC(C=C, max_iter=max_iter, random_state=random_state)
    if estimator == "ridge":
        from sklearn.linear_model import RidgeClassifier

        return RidgeClassifier(alpha=alpha)
    raise ValueError(f"MuxClassifier: estimator must be one of {ESTIMATORS}, got {estimator!r}")


def fit_linear(X, y, estimator="linear_svm", C=1.0, alpha=1.0, max_iter=10000, random_state=0,
               standardise=True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A multi-class linear classifier (`MuxClassifier`'s ``estimator``) on raw features X
    (n, F), each column z-scored over X first if ``standardise``. Returns coef (n_classes, F),
    intercept (n_classes,), both applying to the raw features (the scaling folded in), and
    the classes. For features that are not k images' alike (`MuxClassifier.fit_features`
    checks that layout and calls this)."""
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y)
    if y.shape != (X.shape[0],):
        raise ValueError(f"y must have one label per sample ({X.shape[0]}), got shape {y.shape}")
    classes = np.unique(y)
    if classes.size < 2:
        raise ValueError(f"need samples of at least 2 classes to fit, got {classes.size}")
    est = _make_estimator(estimator, C, alpha, max_iter, random_state)
    if not standardise:
        est.fit(X, y)
        return (*_linear_arrays(est, classes.size), est.classes_)
    mean, scale = column_scaling(X)
    est.fit((X - mean) / scale, y)
    coef, intercept = _linear_arrays(est, classes.size)
    # w.((x - mean) / scale) + b = (w / scale).x + (b - (w / scale).mean)
    coef = coef / scale
    return coef, intercept - coef @ mean, est.classes_


class MuxClassifier(ClassifierMixin, BaseEstimator):
    """Features of each image of a stack, concatenated, then a multi-class linear classifier.

    Parameters
    ----------
    estimator : {"linear_svm", "ridge"}
        ``linear_svm``: sklearn ``LinearSVC`` (one-vs-rest, squared hinge, L2).
        ``ridge``: sklearn ``RidgeClassifier`` (least squares on +-1 targets).
    C : float
        Inverse regularisation of the linear SVM.
    alpha : float
        Regularisation of the ridge classifier.
    max_iter : int
        Iteration limit of the linear SVM solver.
    hog_config : HogConfig or None
        Feature configuration (None: the paper's, 900 values per 120 x 120 image).
    features : str
        The feature extractor by name (`mux_classifier.features.EXTRACTORS`, one that the
        search can use): "hog_grid" (the paper's) or a pose-robust one such as
        "intensity_stats". An extractor marked ``standardise`` has each feature column
        z-scored with statistics of the training samples; that scaling is folded into
        ``coef_`` and ``intercept_``, which therefore apply to the raw features.
    random_state : int
        Seed of the SVM solver's coordinate order (makes fits reproducible).

    Fitted attributes: ``classes_``, ``coef_`` (n_classes, n_images_ * values per image),
    ``intercept_`` (n_classes,), ``n_images_``, ``n_features_in_`` (feature length).
    ``decision_function`` always returns (n, n_classes), also for two classes.
    """

    def __init__(self, estimator="linear_svm", C=1.0, alpha=1.0, max_iter=10000,
                 hog_config=None, random_state=0, features=DEFAULT_EXTRACTOR):
        self.estimator = estimator
        self.C = C
        self.alpha = alpha
        self.max_iter = max_iter
        self.hog_config = hog_config
        self.random_state = random_state
        self.features = features

    def _config(self) -> HogConfig:
        return HogConfig() if self.hog_config is None else self.hog_config

    def _extractor(self):
        return searchable_extractor(self.features, self._config())

    # --- stacks of images
    def fit(self, stacks, y):
        """Fit on stacks (n, k, H, W) of images and labels y (n,); returns self."""
        X = self._extractor().raw_features(stacks)
        return self.fit_features(X, y, n_images=np.asarray(stacks).shape[1])

    def decision_function(self, stacks) -> np.ndarray:
        """Per-class scores (n, n_classes) for stacks (n, k, H, W)."""
        check_is_fitted(self, "coef_")
        arr = check_stacks(stacks, self._config(), n_images=self.n_images_)
        return self.decision_function_features(self._extractor().raw_features(arr))

    def predict(self, stacks) -> np.ndarray:
        """Predicted class labels for stacks (n, k, H, W)."""
        scores = self.decision_function(stacks)
        return self.classes_[np.argmax(scores, axis=1)]

    # --- precomputed features (the search computes them once for many fits)
    def fit_features(self, X, y, n_images: int | None = None):
        """Fit on concatenated raw features X (n, k * values per image); returns self."""
        X = np.asarray(X, dtype=np.float64)
        y = np.asarray(y)
        extractor = self._extractor()
        n_per_image = extractor.features_per_image
        if X.ndim != 2 or X.shape[1] == 0 or X.shape[1] % n_per_image:
            raise ValueError(
                f"features must be (n_samples, k * {n_per_image}), got shape {X.shape}")
        k = X.shape[1] // n_per_image
        if n_images is not None and n_images != k:
            raise ValueError(f"features hold {k} images but n_images={n_images}")
        self.coef_, self.intercept_, self.classes_ = fit_linear(
            X, y, self.estimator, self.C, self.alpha, self.max_iter, self.random_state,
            standardise=extractor.standardise)
        self.n_images_ = k
        self.n_features_in_ = X.shape[1]
        return self

    def decision_function_features(self, X) -> np.ndarray:
        check_is_fitted(self, "coef_")
        X = np.asarray(X)
        if X.ndim != 2 or X.shape[1] != self.coef_.shape[1]:
            raise ValueError(
                f"features must be (n_samples, {self.coef_.shape[1]}) for this classifier "
                f"({self.n_images_} images), got shape {X.shape}")
        return X @ self.coef_.T + self.intercept_

    def predict_features(self, X) -> np.ndarray:
        scores = self.decision_function_features(X)
        return self.classes_[np.argmax(scores, axis=1)]

    @classmethod
    def from_linear(cls, coef, intercept, classes, hog_config=None, **params) -> "MuxClassifier":
        """A fitted classifier from stored arrays (used when loading an artifact); `coef`
        applies to the raw features of ``params['features']`` (default the HOG grid)."""
        clf = cls(hog_config=hog_config, **params)
        coef = np.asarray(coef, dtype=np.float64)
        n_per_image = clf._extractor().features_per_image
        if coef.ndim != 2 or coef.shape[1] % n_per_image or coef.shape[1] == 0:
            raise ValueError(f"coef must be (n_classes, k * {n_per_image}), got shape {coef.shape}")
        clf.classes_ = np.asarray(classes)
        clf.coef_ = coef
        clf.intercept_ = np.asarray(intercept, dtype=np.float64).reshape(-1)
        if clf.coef_.shape[0] != clf.classes_.size or clf.intercept_.size != clf.classes_.size:
            raise ValueError(
                f"coef {coef.shape} / intercept {clf.intercept_.shape} do not match "
                f"{clf.classes_.size} classes")
        clf.n_images_ = coef.shape[1] // n_per_image
        clf.n_features_in_ = coef.shape[1]
        return clf


class LearnedModelClassifier(ClassifierMixin, BaseEstimator):
    """A learned-illumination model (`learned_model.LearnedModel`: its own patterns, object
    statistics, z-scoring and dense head) as a fitted estimator with MuxClassifier's
    prediction interface on stacks, so that an artifact predicts through one path whatever
    its method. Scores are the head's logits (for a head gated by type, its margins).
    Fitting is the trainer's (`mux_trainer.learned`, JAX); this side is numpy only.

    Fitted attributes (`from_model`): ``model_``, ``classes_``, ``n_images_``.
    """

    def __init__(self, hog_config=None):
        self.hog_config = hog_config

    @classmethod
    def from_model(cls, model, classes, hog_config=None) -> "LearnedModelClassifier":
        clf = cls(hog_config=hog_config)
        clf.model_ = model
        clf.classes_ = np.asarray(classes)
        clf.n_images_ = int(model.n_images)
        if clf.classes_.size != model.n_classes:
            raise ValueError(f"the learned model scores {model.n_classes} classes, "
                             f"got {clf.classes_.size} class names")
        return clf

    def fit(self, stacks, y):
        raise NotImplementedError("a learned model is trained with its patterns "
                                  "(mux_trainer.learned.LearnedIlluminationClassifier)")

    def decision_function(self, stacks) -> np.ndarray:
        """Per-class scores (n, n_classes), the logits, for stacks (n, k, H, W)."""
        check_is_fitted(self, "model_")
        config = HogConfig() if self.hog_config is None else self.hog_config
        arr = check_stacks(stacks, config, n_images=self.n_images_)
        return self.model_.scores_from_features(self.model_.features(arr)).astype(np.float64)

    def predict(self, stacks) -> np.ndarray:
        return self.classes_[np.argmax(self.decision_function(stacks), axis=1)]
