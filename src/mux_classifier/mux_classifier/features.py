"""A sample's feature vector: the features of its images, concatenated in image order.

The paper's feature is the HOG grid (`stack_features`, below). Other extractors are chosen
by name (`extractor(name)`, `EXTRACTORS`); every one keeps the layout described here (a
fixed number of values per image, image j's in columns j*d .. (j+1)*d - 1) and has a
scikit-learn style ``fit(stacks)`` / ``transform(stacks)``: whatever it learns (a codebook,
standardisation statistics) comes from the stacks given to ``fit`` only, so fit on
training poses and transform held-out ones. Every image's raw features come from that
image alone (`image_features`; the pose-robust ones find the object in each image), so the
layout's prefix property holds exactly.

The pattern search and the trained classifier (`MuxClassifier(features=NAME)`, the
artifact) use the raw per-image features of a `searchable` extractor; the ones marked
`standardise` are z-scored per column by the classifier, which learns that from its
training samples and folds it into its linear weights.

A *stack* is the k images of one sample taken under k illumination patterns, shape
(k, H, W); a batch of stacks is (n, k, H, W). Image j's 900 HOG values occupy columns
``j*900 .. (j+1)*900 - 1`` of the result, so the features of the first j images of a
stack are a prefix of the features of all k: a classifier for j images can be trained
on ``X[:, :j * 900]`` without recomputing anything.
"""
from __future__ import annotations

import numpy as np

from .hog import HogConfig, hog_batch

__all__ = ["stack_features", "check_stacks", "EXTRACTORS", "DEFAULT_EXTRACTOR", "extractor",
           "StackFeatureExtractor", "features_for_split", "make_extractor", "searchable_extractor",
           "column_scaling"]


def check_stacks(stacks, config: HogConfig = HogConfig(), n_images: int | None = None,
                 image_size: int | None = None) -> np.ndarray:
    """Validate a batch of stacks (n, k, H, W) of images of `image_size` (default: the HOG
    configuration's) and return it as an array.

    Raises ValueError saying what is wrong (rank, image size, number of images) and what
    to do about it.
    """
    arr = np.asarray(stacks)
    if arr.ndim != 4:
        hint = (" (one sample's stack (k, H, W)? pass stacks[None])" if arr.ndim == 3 else "")
        raise ValueError(f"expected a batch of image stacks (n, k, H, W), got shape {arr.shape}{hint}")
    size = config.image_size if image_size is None else image_size
    if arr.shape[2:] != (size, size):
        raise ValueError(
            f"images are {arr.shape[2]} x {arr.shape[3]} px but the features are configured "
            f"for {size} x {size}; downscale the images to {size} px first"
        )
    if n_images is not None and arr.shape[1] != n_images:
        raise ValueError(
            f"expected {n_images} images per sample, got {arr.shape[1]}; take one image per "
            "illumination pattern, in the pattern order"
        )
    if arr.shape[1] < 1:
        raise ValueError("stacks hold no images (k = 0)")
    return arr


def stack_features(stacks, config: HogConfig = HogConfig()) -> np.ndarray:
    """HOG features of a batch of stacks: (n, k, H, W) -> float32 (n, k * n_features)."""
    arr = check_stacks(stacks, config)
    n, k = arr.shape[:2]
    if n == 0:
        return np.zeros((0, k * config.n_features), dtype=np.float32)
    flat = hog_batch(arr.reshape(n * k, *arr.shape[2:]), config)
    return flat.reshape(n, k * config.n_features)


def column_scaling(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column mean and scale (std, never 0) of features X (n, F): a z-scoring learnt
    from the rows given (training samples only)."""
    X = np.asarray(X, dtype=np.float64)
    mean = X.mean(axis=0)
    scale = X.std(axis=0)
    return mean, np.where(scale > 1e-9 * (np.abs(mean) + 1.0), scale, 1.0)


# ---- feature extractors by name ------------------------------------------------------------
class StackFeatureExtractor:
    """Base of the named extractors: stacks (n, k, H, W) -> float32 (n, k * features_per_image).

    Subclasses implement ``_raw(stacks)``; with ``standardise`` each of the per-image values
    is z-scored with a mean and scale learnt in ``fit`` over all training images (the same
    for every image position, so any k can be transformed and a prefix of the columns is the
    features of the first images).
    """

    name = ""
    standardise = False
    searchable = True  # its raw features learn nothing from images: the search can score with it

    def __init__(self, image_size: int = 120):
        self.image_size = int(image_size)

    def image_features(self, images) -> np.ndarray:
        """Raw features of single images (N, H, W) -> float32 (N, features_per_image), each
        from its own image alone (its own object mask): what the pattern search and the
        classifier compute, before any standardisation."""
        arr = np.asarray(images)
        if arr.ndim != 3:
            raise ValueError(f"expected images (N, H, W), got shape {arr.shape}")
        self._check(arr[:, None])
        return np.ascontiguousarray(self._raw(arr[:, None]).reshape(len(arr), -1), np.float32)

    def raw_features(self, stacks) -> np.ndarray:
        """Raw features of stacks (n, k, H, W) -> float32 (n, k * features_per_image): each
        image's own `image_features`, in image order."""
        arr = self._check(stacks)
        n, k = arr.shape[:2]
        return self.image_features(arr.reshape(n * k, *arr.shape[2:])).reshape(n, -1)

    @property
    def features_per_image(self) -> int:
        raise NotImplementedError

    def _raw(self, stacks: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _check(self, stacks) -> np.ndarray:
        return check_stacks(stacks, image_size=self.image_size)

    def fit(self, stacks, y=None):
        """Learn from training stacks only (nothing for a stateless extractor); returns self."""
        arr = self._check(stacks)
        if self.standardise:
            per_image = self.raw_features(arr).reshape(-1, self.features_per_image)
            self.mean_, self.scale_ = column_scaling(per_image)
        self.fitted_ = True
        return self

    def transform(self, stacks) -> np.ndarray:
        arr = self._check(stacks)
        if not getattr(self, "fitted_", False):
            raise ValueError(f"feature extractor {self.name!r} is not fitted; call fit(training "
                             "stacks) first")
        n, k = arr.shape[:2]
        X = self.raw_features(arr)
        if self.standardise:
            X = ((X.reshape(n, k, -1) - self.mean_) / self.scale_).reshape(n, -1)
        return np.ascontiguousarray(X, dtype=np.float32)

    def fit_transform(self, stacks, y=None) -> np.ndarray:
        return self.fit(stacks).transform(stacks)

    def learned_state(self) -> dict:
        """The arrays learnt in fit (for the artifact and for leak tests)."""
        return {k: v for k, v in (("mean", getattr(self, "mean_", None)),
                                  ("scale", getattr(self, "scale_", None))) if v is not None}

    def restore(self, state: dict) -> "StackFeatureExtractor":
        """A fitted extractor from `learned_state()` arrays (loading an artifact; no pickle)."""
        if self.standardise:
            d = self.features_per_image
            missing = {"mean", "scale"} - set(state)
            if missing:
                raise ValueError(f"feature extractor {self.name!r} needs learned arrays "
                                 f"{sorted(missing)} to be restored")
            self.mean_ = np.asarray(state["mean"], dtype=np.float64).reshape(-1)
            self.scale_ = np.asarray(state["scale"], dtype=np.float64).reshape(-1)
            if self.mean_.size != d or self.scale_.size != d or not (self.scale_ > 0).all():
                raise ValueError(f"feature extractor {self.name!r}: mean and scale must hold "
                                 f"{d} values (scale > 0), got {self.mean_.size} and "
                                 f"{self.scale_.size}")
        elif state:
            raise ValueError(f"feature extractor {self.name!r} learns nothing; got arrays "
                             f"{sorted(state)}")
        self.fitted_ = True
        return self


class HogGridExtractor(StackFeatureExtractor):
    """The paper's HOG grid (`stack_features`): 900 values per 120 px image; nothing learnt."""

    name = "hog_grid"

    def __init__(self, image_size: int = 120, config: HogConfig | None = None):
        super().__init__(image_size)
        self.config = HogConfig(image_size=self.image_size) if config is None else config

    @property
    def features_per_image(self) -> int:
        return self.config.n_features

    def _check(self, stacks):
        return check_stacks(stacks, self.config)

    def _raw(self, stacks):
        return stack_features(stacks, self.config)


class PoseNormalisedHogExtractor(HogGridExtractor):
    """Centre the object on its principal axis, then the HOG grid (`pose_normalise`)."""

    name = "pose_hog"

    def _raw(self, stacks):
        from .pose_normalise import pose_normalised_hog
        return pose_normalised_hog(stacks, self.config)


class PooledHogExtractor(StackFeatureExtractor):
    """Dense local HOG pooled over the object (`pooled_hog`), standardised: 72 per image."""

    name = "pooled_hog"
    standardise = True

    @property
    def features_per_image(self) -> int:
        return 72

    def _raw(self, stacks):
        from .pooled_hog import pooled_hog
        return pooled_hog(stacks, self.image_size)


class IntensityStatsExtractor(StackFeatureExtractor):
    """Object reflectance statistics per image (`intensity_stats`), standardised: 9 per image."""

    name = "intensity_stats"
    standardise = True

    @property
    def features_per_image(self) -> int:
        from .intensity_stats import N_STATS
        return N_STATS

    def _raw(self, stacks):
        from .intensity_stats import intensity_stats
        return intensity_stats(stacks)


class PooledHogStatsExtractor(StackFeatureExtractor):
    """Pooled local HOG and reflectance statistics side by side, per image: 81 per image."""

    name = "pooled_hog_stats"
    standardise = True

    def __init__(self, image_size: int = 120):
        super().__init__(image_size)
        self._parts = (PooledHogExtractor(image_size), IntensityStatsExtractor(image_size))

    @property
    def features_per_image(self) -> int:
        return sum(p.features_per_image for p in self._parts)

    def _raw(self, stacks):
        n, k = stacks.shape[:2]
        return np.concatenate([p._raw(stacks).reshape(n, k, -1) for p in self._parts],
                              axis=2).reshape(n, -1)


class BagOfWordsExtractor(StackFeatureExtractor):
    """Dense-HOG bag of visual words per image (`bow.BagOfVisualWords`, hellinger norm);
    the codebook is learnt in fit."""

    name = "bow"
    searchable = False  # its codebook is learnt from images

    def __init__(self, image_size: int = 120, n_words: int = 200, random_state: int = 0):
        super().__init__(image_size)
        self.n_words = n_words
        self.random_state = random_state

    @property
    def features_per_image(self) -> int:
        return self.n_words

    def fit(self, stacks, y=None):
        from .bow import BagOfVisualWords
        arr = self._check(stacks)
        self.bow_ = BagOfVisualWords(n_words=self.n_words, norm="hellinger",
                                     image_size=self.image_size,
                                     random_state=self.random_state).fit(arr)
        self.fitted_ = True
        return self

    def _raw(self, stacks):
        return self.bow_.transform(stacks)

    def learned_state(self) -> dict:
        return {"codebook": self.bow_.codebook_} if hasattr(self, "bow_") else {}

    def restore(self, state: dict):
        raise ValueError("the bag-of-words extractor cannot be restored from arrays yet "
                         "(its transform needs the fitted k-means); refit it")


EXTRACTORS: dict[str, type[StackFeatureExtractor]] = {
    cls.name: cls for cls in (HogGridExtractor, PoseNormalisedHogExtractor, PooledHogExtractor,
                              IntensityStatsExtractor, PooledHogStatsExtractor,
                              BagOfWordsExtractor)}
DEFAULT_EXTRACTOR = "hog_grid"


def extractor(name: str = DEFAULT_EXTRACTOR, **params) -> StackFeatureExtractor:
    """A new, unfitted feature extractor by name (see `EXTRACTORS`)."""
    if name not in EXTRACTORS:
        raise ValueError(f"unknown feature extractor {name!r}; choose from "
                         f"{', '.join(EXTRACTORS)}")
    return EXTRACTORS[name](**params)


def make_extractor(name: str = DEFAULT_EXTRACTOR, hog_config: HogConfig | None = None):
    """The extractor `name` for images of `hog_config`'s size (the HOG grid with that very
    configuration), as the search, the classifier and the artifact use it."""
    config = HogConfig() if hog_config is None else hog_config
    if name == HogGridExtractor.name:
        return HogGridExtractor(config.image_size, config)
    return extractor(name, image_size=config.image_size)


def searchable_extractor(name: str, hog_config: HogConfig | None = None):
    """`make_extractor`, refusing an extractor that learns from images (the search and the
    trained classifier need features of each image alone)."""
    ex = make_extractor(name, hog_config)
    if not ex.searchable:
        choices = ", ".join(n for n, cls in EXTRACTORS.items() if cls.searchable)
        raise ValueError(f"feature extractor {name!r} learns from images and cannot be used "
                         f"by the pattern search or a trained classifier; choose from {choices}")
    return ex


def features_for_split(name: str, stacks, train, test, **params):
    """Features of one train/test split: a new extractor fit on ``stacks[train]`` alone, then
    (X_train, X_test, fitted extractor). The held-out stacks never reach ``fit``."""
    arr = np.asarray(stacks)
    ex = extractor(name, **params).fit(arr[train])
    return ex.transform(arr[train]), ex.transform(arr[test]), ex
