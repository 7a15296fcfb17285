"""Rendering and noise for the search, laid out for speed.

`SearchData` holds the relightable models of a training set at the feature resolution
(120 px), multiplied by the dimmer and stored LED-major, `basis[site, channel]` being one
contiguous `(n_samples, n_pixels)` block, so that adding or removing one site or LED to a
rendered stack is a single contiguous add (Gray-code rendering).

Noise follows the affine model `variance = a * mean + b`. Noise is physically added at full
resolution before downscaling; averaging over the downscale divides the variance by the
ModelSet's `noise_scale`, so rendering at low resolution with variance
`noise_scale * (sigma_p^2 * mean + sigma_r^2)` is equivalent, and 30-40 x cheaper.
Noise is drawn as float32 standard normals and added in one compiled pass (`add_noise`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numba
import numpy as np

from mux_classifier.features import DEFAULT_EXTRACTOR, column_scaling, searchable_extractor
from mux_classifier.hog import HogConfig

from lightstage_physics.rig import DEFAULT_DIMMER

from .cluster import ArraySized


@dataclass
class SearchData(ArraySized):
    """The training set as the search sees it.

    basis: float32 `(n_sites, n_channels, n_samples, n_pixels)`, dimmer applied.
    labels: int `(n_samples,)`; pose_index: int `(n_samples,)`; class_names: list.
    image_shape: (H, W) of the rendered images.
    noise_a, noise_b: variance = noise_a * mean + noise_b at this resolution (0, 0 = no noise).
    max_level: saturation level (1023 for a 10-bit camera).
    noise_name, noise_model: the noise setting and its camera NoiseModel at full resolution
    (None without noise), for the artifact.
    features: the feature extractor the search scores with (`mux_classifier.features`);
    hog_config is the HOG grid's configuration and sets the image size of every extractor.
    instance: int `(n_samples,)`, each sample's physical sample number within its class
    (`ModelSet.instance`), or None (unknown: one physical sample per class). With two or more
    per class, every method's inner splits hold out whole physical samples
    (`SplitScoring.inner_groups`, `splits.inner_splits`).
    """

    basis: np.ndarray
    labels: np.ndarray
    pose_index: np.ndarray
    class_names: list
    image_shape: tuple
    noise_a: float = 0.0
    noise_b: float = 0.0
    max_level: float = 1023.0
    noise_name: str = 'none'
    noise_model: object = None
    hog_config: HogConfig = field(default_factory=HogConfig)
    features: str = DEFAULT_EXTRACTOR
    instance: np.ndarray | None = None

    def __post_init__(self):
        self.basis = np.ascontiguousarray(self.basis, dtype=np.float32)
        if self.basis.ndim != 4:
            raise ValueError(f'basis must be (sites, channels, samples, pixels), got {self.basis.shape}')
        self.labels = np.asarray(self.labels, dtype=np.int64)
        self.pose_index = np.asarray(self.pose_index, dtype=np.int64)
        n = self.basis.shape[2]
        if self.labels.shape != (n,) or self.pose_index.shape != (n,):
            raise ValueError(f'{n} samples in basis but labels {self.labels.shape} and '
                             f'pose_index {self.pose_index.shape}')
        if self.instance is not None:
            self.instance = np.asarray(self.instance, dtype=np.int64)
            if self.instance.shape != (n,):
                raise ValueError(f'{n} samples in basis but instance {self.instance.shape}')
        H, W = self.image_shape
        if H * W != self.basis.shape[3]:
            raise ValueError(f'image_shape {self.image_shape} does not match {self.basis.shape[3]} pixels')
        searchable_extractor(self.features, self.hog_config)  # a clear error for a bad name

    @property
    def extractor(self):
        return searchable_extractor(self.features, self.hog_config)

    @classmethod
    def from_models(cls, models: np.ndarray, labels, pose_index, class_names, *,
                    dimmer: float = DEFAULT_DIMMER, **kwargs) -> 'SearchData':
        """From a ModelSet-shaped array `(n, channels, sites, H, W)` in gray levels."""
        models = np.asarray(models, dtype=np.float32)
        if models.ndim != 5:
            raise ValueError(f'models must be (samples, channels, sites, H, W), got {models.shape}')
        n, C, S, H, W = models.shape
        basis = np.empty((S, C, n, H * W), dtype=np.float32)
        for s in range(S):
            for c in range(C):
                np.multiply(models[:, c, s].reshape(n, H * W), np.float32(dimmer), out=basis[s, c])
        return cls(basis=basis, labels=labels, pose_index=pose_index,
                   class_names=list(class_names), image_shape=(H, W), **kwargs)

    @property
    def n_samples(self) -> int:
        return self.basis.shape[2]

    @property
    def n_sites(self) -> int:
        return self.basis.shape[0]

    @property
    def n_channels(self) -> int:
        return self.basis.shape[1]

    def subset(self, index) -> 'SearchData':
        """The same data restricted to some samples (for held-out evaluation)."""
        index = np.asarray(index)
        return replace(self, basis=self.basis[:, :, index], labels=self.labels[index],
                       pose_index=self.pose_index[index],
                       instance=None if self.instance is None else self.instance[index])


def clean_site_images(data: SearchData, W: np.ndarray) -> np.ndarray:
    """Per-colour site patterns `(sites, k)` -> noise-free images `(k * channels, n, pixels)`.

    Image order: pattern 0's R, G, B, NIR, then pattern 1's, ... (as in the artifact).
    """
    W = np.asarray(W, dtype=np.float32).reshape(data.n_sites, -1)
    out = np.zeros((W.shape[1],) + data.basis.shape[1:], dtype=np.float32)
    for j in range(W.shape[1]):
        # a sum over the lit sites beats einsum here (contiguous adds, no temporaries)
        for site in np.flatnonzero(W[:, j]):
            if W[site, j] == 1:
                out[j] += data.basis[site]
            else:
                out[j] += W[site, j] * data.basis[site]
    return out.reshape(-1, data.n_samples, data.basis.shape[3])


def clean_led_images(data: SearchData, P: np.ndarray) -> np.ndarray:
    """LED patterns `(sites * channels, k)` (site-major) -> noise-free images `(k, n, pixels)`."""
    P = np.asarray(P, dtype=np.float32).reshape(data.n_sites * data.n_channels, -1)
    flat = data.basis.reshape(data.n_sites * data.n_channels, -1)
    out = np.zeros((P.shape[1], flat.shape[1]), dtype=np.float32)
    for j in range(P.shape[1]):
        lit = np.flatnonzero(P[:, j])
        # sum only the lit LEDs' images: patterns are sparse early in the joint search
        for led in lit:
            out[j] += P[led, j] * flat[led]
    return out.reshape(P.shape[1], data.n_samples, -1)


def standard_normal(rng: np.random.Generator, shape) -> np.ndarray:
    """float32 standard normals (about twice as fast as float64 draws)."""
    return rng.standard_normal(shape, dtype=np.float32)


def add_noise(data: SearchData, clean: np.ndarray, z: np.ndarray | None,
              out: np.ndarray | None = None) -> np.ndarray:
    """clip(clean + sqrt(a * max(clean, 0) + b) * z, 0, max_level) in float32, in one pass
    (compiled; the same float32 operations in the same order as `add_noise_numpy`, so the
    same bits).

    z: standard normals of clean's shape (None or a noise-free setting: just clipping).
    """
    if out is None:
        out = np.empty_like(clean, dtype=np.float32)
    if z is None or (data.noise_a == 0 and data.noise_b == 0):
        np.copyto(out, clean)
        np.clip(out, 0, data.max_level, out=out)
        return out
    clean32 = np.ascontiguousarray(clean, dtype=np.float32)
    z32 = np.ascontiguousarray(z, dtype=np.float32)
    if clean32.shape != z32.shape or out.shape != clean32.shape or out.dtype != np.float32 \
            or not out.flags.c_contiguous:
        return add_noise_numpy(data, clean, z, out)
    _noisy_kernel(clean32.reshape(-1), z32.reshape(-1), np.float32(data.noise_a),
                  np.float32(data.noise_b), np.float32(data.max_level), out.reshape(-1))
    return out


@numba.njit(cache=True, nogil=True)
def _noisy_kernel(clean, z, a, b, top, out):
    zero = np.float32(0.0)
    for i in range(clean.size):
        c = clean[i]
        v = max(c, zero) * a + b
        v = np.sqrt(v) * z[i] + c
        out[i] = min(max(v, zero), top)


def add_noise_numpy(data: SearchData, clean: np.ndarray, z: np.ndarray | None,
                    out: np.ndarray | None = None) -> np.ndarray:
    """`add_noise` in numpy, pass by pass (the reference; any shapes that broadcast)."""
    if out is None:
        out = np.empty_like(clean, dtype=np.float32)
    if z is None or (data.noise_a == 0 and data.noise_b == 0):
        np.copyto(out, clean)
    else:
        np.maximum(clean, 0, out=out)
        out *= np.float32(data.noise_a)
        out += np.float32(data.noise_b)
        np.sqrt(out, out=out)
        out *= z
        out += clean
    np.clip(out, 0, data.max_level, out=out)
    return out


def image_features(data: SearchData, images: np.ndarray) -> np.ndarray:
    """Images `(m, n, pixels)` -> per-sample concatenated raw features `(n, m * d)` float32
    (d values per image of the data's extractor; the HOG grid: 900)."""
    m, n, _ = images.shape
    H, W = data.image_shape
    feats = data.extractor.image_features(images.reshape(m * n, H, W))
    return np.ascontiguousarray(
        feats.reshape(m, n, -1).transpose(1, 0, 2).reshape(n, -1))


def scoring_features(data: SearchData, images: np.ndarray) -> np.ndarray:
    """`image_features` as the search's split scorers see them: an extractor marked
    `standardise` has each column z-scored over the search's samples (its training data;
    held-out poses are never among them), as `MuxClassifier` does on its training samples."""
    X = image_features(data, images)
    return standardise_columns(X) if data.extractor.standardise else X


def standardise_columns(X: np.ndarray) -> np.ndarray:
    """Each column of X z-scored over its rows (the search's samples), float32."""
    mean, scale = column_scaling(X)
    return ((X - mean) / scale).astype(np.float32)


def compile_kernels() -> None:
    """Compile (or load from numba's cache) every compiled kernel of the search and the
    classify path: HOG, intensity statistics, noise and the exact SVM's Newton solves.
    scripts/bootstrap.sh calls it after installing the packages, so the cache is written
    once, there."""
    from .split_scoring import SquaredHingeSplitScorer
    rng = np.random.default_rng(0)
    config = HogConfig()
    data = SearchData(basis=np.zeros((1, 1, 4, config.image_size ** 2), np.float32),
                      labels=[0, 1, 0, 1], pose_index=[0, 0, 1, 1], class_names=['a', 'b'],
                      image_shape=(config.image_size,) * 2, noise_a=1.0, noise_b=1.0)
    clean = rng.uniform(0, 1023, (1, 4, config.image_size ** 2)).astype(np.float32)
    X = image_features(data, add_noise(data, clean, standard_normal(rng, clean.shape)))
    image_features(replace(data, features='intensity_stats'), clean)
    masks = [np.array([True, False, False, False]), np.array([False, True, True, False])]
    SquaredHingeSplitScorer().split_accuracies(data.labels, masks, X=X, n_classes=2)
