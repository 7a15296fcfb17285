"""Is this object unlike every trained class? A novelty score with a stated false-alarm rate.

A classifier always answers one of its classes, also for an object of a kind it never saw
(a new forgery, another fruit, an empty stage). `NoveltyModel` scores how far a sample's
features lie from every trained class: the class-conditional Mahalanobis distance (Lee et
al., "A simple unified framework for detecting out-of-distribution samples", NeurIPS 2018)
in a low-dimensional projection, with one covariance shared by the classes and shrunk by
Ledoit-Wolf (a few hundred training renders of a few physical samples per class cannot
estimate a full covariance per class). The distance to the nearest class mean, divided by
a threshold set on training data, is the score: >= 1 means unknown.

The threshold is set on *held-out physical samples*: the training rows are split into
folds by group (a physical sample, so all its poses and renders fall on one side), each
fold is scored by a model fitted on the others, and the threshold is an upper confidence
bound (99 %) of the (1 - false-alarm rate) quantile of those held-out distances,
bootstrapped over the groups. A plain quantile is right on average over many captures, but
with a few physical samples per class the next samples can lie wider than the held-out ones
did (a coin whose motif none of the four trained coins had): on synthetic captures the plain
quantile gave up to 7.6 % false alarms for a stated 5 % (docs/NOVELTY.md). The bound
costs little: renders of an untrained type score 5-9 times the threshold (median).

Features: what `score` is given. The trained artifact gives it `NOVELTY_FEATURES` of its
images (the per-image object statistics, `intensity_stats`, 9 per image): on synthetic
captures with an object type left out of training they flagged every left-out type, where
the HOG grid, which the linear classifiers use, missed most renders of some types (grapes,
oranges, apples), and a k-nearest-neighbour distance, an isolation forest and a one-class
SVM flagged fewer (docs/NOVELTY.md has the comparison).

Stored as plain numeric arrays (`to_arrays` / `from_arrays`): an artifact is an untrusted
file, so no pickle; `from_arrays` refuses malformed arrays with `NoveltyError` naming them.
No rclpy; numpy only to score (scikit-learn to fit).
"""
from __future__ import annotations

import math
import reprlib

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_is_fitted

__all__ = ["DEFAULT_FALSE_ALARM_RATE", "NOVELTY_FEATURES", "NoveltyError", "NoveltyModel",
           "ARRAY_NAMES", "class_distance", "fit_class_distance"]

NOVELTY_FEATURES = "intensity_stats"  # the features an artifact's novelty models score
DEFAULT_FALSE_ALARM_RATE = 0.05
ARRAY_NAMES = ("projection", "offset", "class_means", "precision", "threshold",
               "false_alarm_rate", "held_out_false_alarm")
MAX_FEATURES = 1 << 20  # a stored projection's width: far beyond 4096 images x 9 statistics


class NoveltyError(ValueError):
    """A novelty model cannot be fitted from these data or rebuilt from these arrays; says
    why."""


def _check_rate(rate) -> float:
    if isinstance(rate, bool) or not isinstance(rate, (int, float, np.floating)) \
            or not math.isfinite(rate) or not 0.0 < rate < 0.5:
        raise NoveltyError(f"false_alarm_rate must be a number in (0, 0.5), got "
                           f"{reprlib.repr(rate)}")
    return float(rate)


class NoveltyModel(BaseEstimator):
    """Distance to the nearest trained class, in units of a threshold set at a stated
    false-alarm rate on held-out groups (module docstring).

    Parameters
    ----------
    n_components : int
        Dimensions the standardised features are projected to (principal components of the
        training rows) before the Mahalanobis distance; fewer if the rows span fewer.
    n_splits : int
        Folds by group whose held-out distances set the threshold (fewer if there are fewer
        groups; at least 2 groups are needed).
    confidence : float
        The threshold is this upper confidence bound of the (1 - rate) quantile of the
        held-out distances over bootstraps of the groups (0.5: about the plain quantile).
    n_bootstrap : int
        Bootstrap resamples of the groups.
    random_state : int
        Seed of the bootstrap.

    Fitted attributes: ``projection_`` (r, F) and ``offset_`` (r,) (features -> the
    standardised, centred projection: ``X @ projection_.T + offset_``), ``class_means_``
    (C, r), ``precision_`` (r, r), ``threshold_``, ``false_alarm_rate_`` (the stated rate),
    ``held_out_false_alarm_`` (the share of held-out training rows at or above the
    threshold), ``n_features_in_``.
    """

    def __init__(self, n_components=16, n_splits=5, confidence=0.99, n_bootstrap=500,
                 random_state=0):
        self.n_components = n_components
        self.n_splits = n_splits
        self.confidence = confidence
        self.n_bootstrap = n_bootstrap
        self.random_state = random_state

    # --- fitting
    def fit(self, X, y, groups=None, false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE):
        """Fit on training features X (n, F) of the known classes y (n,).

        ``groups`` (n,): the physical sample of each row (rows of one group are held out
        together when the threshold is set; None: every row its own group). The threshold
        makes about ``false_alarm_rate`` of new samples of the known classes score >= 1
        (module docstring). Returns self.
        """
        rate = _check_rate(false_alarm_rate)
        X, y = self._check_training(X, y)
        groups = np.arange(len(X)) if groups is None else np.asarray(groups)
        if groups.shape != (len(X),):
            raise NoveltyError(f"groups must give one group per row ({len(X)}), got shape "
                               f"{groups.shape}")
        _, group_index = np.unique(groups, return_inverse=True)
        n_groups = int(group_index.max()) + 1
        if n_groups < 2:
            raise NoveltyError("need rows of at least 2 groups (physical samples or poses) "
                               "to hold some out when setting the threshold")
        held_out = np.empty(len(X))
        for fold in _group_folds(group_index, min(int(self.n_splits), n_groups)):
            train = ~fold
            core = fit_class_distance(X[train], y[train], int(self.n_components))
            held_out[fold] = class_distance(core, X[fold])
        threshold = _bootstrap_threshold(held_out, group_index, rate, float(self.confidence),
                                         int(self.n_bootstrap), self.random_state)
        core = fit_class_distance(X, y, int(self.n_components))
        self.projection_, self.offset_, self.class_means_, self.precision_ = core
        self.threshold_ = float(max(threshold, np.finfo(float).tiny))
        self.false_alarm_rate_ = rate
        self.held_out_false_alarm_ = float((held_out >= self.threshold_).mean())
        self.n_features_in_ = X.shape[1]
        return self

    @staticmethod
    def _check_training(X, y):
        X = np.asarray(X, dtype=np.float64)
        y = np.asarray(y)
        if X.ndim != 2 or X.shape[1] == 0 or X.shape[0] < 2:
            raise NoveltyError(f"X must be (n_rows >= 2, n_features >= 1), got shape {X.shape}")
        if y.shape != (X.shape[0],):
            raise NoveltyError(f"y must give one class per row ({X.shape[0]}), got shape "
                               f"{y.shape}")
        if not np.isfinite(X).all():
            raise NoveltyError("X holds non-finite values")
        return X, y

    # --- scoring
    def distance(self, X) -> np.ndarray:
        """Squared Mahalanobis distance to the nearest class mean per projected dimension
        (n,), before the threshold."""
        check_is_fitted(self, "threshold_")
        X = np.asarray(X, dtype=np.float64)
        if X.ndim == 1:
            X = X[None]
        if X.ndim != 2 or X.shape[1] != self.n_features_in_:
            raise NoveltyError(f"features must be (n, {self.n_features_in_}), got shape "
                               f"{X.shape}")
        core = (self.projection_, self.offset_, self.class_means_, self.precision_)
        return class_distance(core, X)

    def score(self, X) -> np.ndarray:
        """Novelty (n,): the distance in units of the threshold; >= 1 means unknown, NaN
        for a row with non-finite features."""
        return self.distance(X) / self.threshold_

    def is_unknown(self, X) -> np.ndarray:
        """True where the score is >= 1."""
        return self.score(X) >= 1.0

    # --- plain arrays (the artifact stores these)
    def to_arrays(self) -> dict[str, np.ndarray]:
        """Every fitted value as a plain float64 array (`ARRAY_NAMES`)."""
        check_is_fitted(self, "threshold_")
        return {"projection": np.asarray(self.projection_, np.float64),
                "offset": np.asarray(self.offset_, np.float64),
                "class_means": np.asarray(self.class_means_, np.float64),
                "precision": np.asarray(self.precision_, np.float64),
                "threshold": np.array([self.threshold_], np.float64),
                "false_alarm_rate": np.array([self.false_alarm_rate_], np.float64),
                "held_out_false_alarm": np.array([self.held_out_false_alarm_], np.float64)}

    @classmethod
    def from_arrays(cls, arrays) -> "NoveltyModel":
        """A fitted model from `to_arrays()`; NoveltyError naming the first array that is
        missing, not real numbers, not finite, or not sized as the others say."""
        if not isinstance(arrays, dict):
            raise NoveltyError(f"novelty arrays must be a dict of arrays, got "
                               f"{type(arrays).__name__}")
        missing = [n for n in ARRAY_NAMES if n not in arrays]
        if missing:
            raise NoveltyError(f"novelty arrays lack {missing}")
        extra = sorted(set(arrays) - set(ARRAY_NAMES))
        if extra:
            raise NoveltyError(f"novelty arrays hold unknown names {extra}")
        a = {}
        for name in ARRAY_NAMES:
            value = np.asarray(arrays[name])
            if value.dtype.kind not in "biuf":
                raise NoveltyError(f"novelty array {name!r} holds {value.dtype} values, not "
                                   "real numbers")
            value = value.astype(np.float64)
            if not np.isfinite(value).all():
                raise NoveltyError(f"novelty array {name!r} holds non-finite values")
            a[name] = value
        P = a["projection"]
        if P.ndim != 2 or not 1 <= P.shape[0] <= P.shape[1] or P.shape[1] > MAX_FEATURES:
            raise NoveltyError(f"novelty array 'projection' must be (r, F) with 1 <= r <= F "
                               f"<= {MAX_FEATURES}, got shape {P.shape}")
        r = P.shape[0]
        checks = (("offset", (r,)), ("precision", (r, r)), ("threshold", (1,)),
                  ("false_alarm_rate", (1,)), ("held_out_false_alarm", (1,)))
        for name, shape in checks:
            if a[name].shape != shape:
                raise NoveltyError(f"novelty array {name!r} must have shape {shape}, got "
                                   f"{a[name].shape}")
        means = a["class_means"]
        if means.ndim != 2 or means.shape[1] != r or means.shape[0] < 1:
            raise NoveltyError(f"novelty array 'class_means' must be (n_classes >= 1, {r}), "
                               f"got shape {means.shape}")
        if not np.allclose(a["precision"], a["precision"].T, rtol=1e-9, atol=1e-12):
            raise NoveltyError("novelty array 'precision' is not symmetric")
        if not a["threshold"][0] > 0:
            raise NoveltyError(f"novelty array 'threshold' must be > 0, got "
                               f"{a['threshold'][0]!r}")
        held = a["held_out_false_alarm"][0]
        if not 0.0 <= held <= 1.0:
            raise NoveltyError(f"novelty array 'held_out_false_alarm' must be a share in "
                               f"0 .. 1, got {held!r}")
        rate = _check_rate(float(a["false_alarm_rate"][0]))
        model = cls()
        model.projection_, model.offset_ = P, a["offset"]
        model.class_means_, model.precision_ = means, a["precision"]
        model.threshold_ = float(a["threshold"][0])
        model.false_alarm_rate_ = rate
        model.held_out_false_alarm_ = float(held)
        model.n_features_in_ = P.shape[1]
        return model


def _group_folds(group_index: np.ndarray, n_splits: int) -> list[np.ndarray]:
    """Held-out masks of ``n_splits`` folds, whole groups each, the groups dealt round-robin
    in order (deterministic; scikit-learn's GroupKFold balances sizes the same way)."""
    from sklearn.model_selection import GroupKFold
    folds = []
    dummy = np.zeros(len(group_index))
    for _, test in GroupKFold(n_splits=max(2, n_splits)).split(dummy, groups=group_index):
        mask = np.zeros(len(group_index), dtype=bool)
        mask[test] = True
        folds.append(mask)
    return folds


def fit_class_distance(X: np.ndarray, y: np.ndarray, n_components: int):
    """The distance's fitted arrays, before any threshold: (projection (r, F), offset (r,),
    class means (C, r), the shared Ledoit-Wolf precision (r, r)) of training rows X (n, F)
    of classes y, standardised and projected on their first ``n_components`` principal
    components."""
    from sklearn.covariance import LedoitWolf

    mean = X.mean(axis=0)
    scale = X.std(axis=0)
    scale = np.where(scale > 1e-9 * (np.abs(mean) + 1.0), scale, 1.0)
    Z = (X - mean) / scale
    _, s, Vt = np.linalg.svd(Z, full_matrices=False)
    keep = s > s[0] * 1e-9 if s.size and s[0] > 0 else np.zeros(0, bool)
    r = max(1, min(int(n_components), int(keep.sum())))
    V = Vt[:r]
    projection = V / scale
    offset = -(mean / scale) @ V.T
    T = Z @ V.T
    classes, index = np.unique(y, return_inverse=True)
    means = np.stack([T[index == c].mean(axis=0) for c in range(classes.size)])
    residual = T - means[index]
    if len(residual) > 1 and np.ptp(residual, axis=0).max() > 0:
        precision = LedoitWolf().fit(residual).precision_
    else:  # every row at its class mean: distances in standardised units
        precision = np.eye(r)
    precision = (precision + precision.T) / 2
    return projection, offset, means, precision


def class_distance(core, X: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance (n,) of rows X to the nearest class mean of
    `fit_class_distance`'s ``core``, per projected dimension."""
    projection, offset, means, precision = core
    T = X @ projection.T + offset
    diff = T[:, None, :] - means[None, :, :]
    d2 = np.einsum("ncr,rs,ncs->nc", diff, precision, diff)
    return d2.min(axis=1) / projection.shape[0]


def _bootstrap_threshold(held_out: np.ndarray, group_index: np.ndarray, rate: float,
                         confidence: float, n_bootstrap: int, random_state) -> float:
    """The ``confidence`` quantile, over bootstraps of the groups, of the (1 - rate) quantile
    of the held-out distances."""
    if not 0.0 < confidence < 1.0:
        raise NoveltyError(f"confidence must be in (0, 1), got {confidence!r}")
    n_groups = int(group_index.max()) + 1
    order = np.argsort(group_index, kind="stable")
    starts = np.searchsorted(group_index[order], np.arange(n_groups + 1))
    members = [order[starts[g]:starts[g + 1]] for g in range(n_groups)]
    rng = np.random.default_rng(random_state)
    quantiles = [np.quantile(held_out, 1.0 - rate)]
    for _ in range(max(0, int(n_bootstrap))):
        pick = rng.integers(0, n_groups, n_groups)
        quantiles.append(np.quantile(held_out[np.concatenate([members[g] for g in pick])],
                                     1.0 - rate))
    return float(np.quantile(quantiles, confidence))
