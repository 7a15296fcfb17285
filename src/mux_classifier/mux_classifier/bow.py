"""Bag of visual words over dense local HOG descriptors (the paper's "naive + BoW" baseline).

Each image is described by many local descriptors: HOG blocks of ``patch_cells`` x
``patch_cells`` cells of ``cell_px`` pixels on a one-cell grid (by default 2 x 2 cells of
8 px: 36 values, L2-Hys normalised, 196 per 120 x 120 image), computed with the same
batched HOG as the classifier's features. A MiniBatchKMeans codebook of ``n_words``
visual words is learnt from (a seeded subsample of) the training descriptors; an image is
encoded as the normalised histogram of its descriptors' nearest words. A stack of k
images (n, k, H, W) is encoded as the k histograms concatenated, in image order.

The authors' MATLAB baseline used MATLAB's bag of features (SURF); dense HOG keeps this
baseline within the packages the project already depends on.
"""
from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.cluster import MiniBatchKMeans
from sklearn.utils.validation import check_is_fitted

from .hog import HogConfig, hog_batch

__all__ = ["BagOfVisualWords"]

_NORMS = ("l1", "l2", "hellinger", "none")


class BagOfVisualWords(TransformerMixin, BaseEstimator):
    """Dense-HOG bag of visual words (scikit-learn transformer).

    Parameters
    ----------
    n_words : int
        Codebook size (k-means clusters).
    cell_px, patch_cells, orientations : int
        Local descriptor: HOG blocks of patch_cells x patch_cells cells of cell_px pixels.
    image_size : int
        Side of the (square) images.
    norm : {"l1", "l2", "hellinger", "none"}
        Histogram normalisation ("hellinger": square root of the l1-normalised histogram).
    max_descriptors : int
        Descriptors sampled (seeded) from the training images to learn the codebook.
    n_init, batch_size : int
        MiniBatchKMeans settings.
    random_state : int
        Seed of the subsample and of k-means.

    Fitted attributes: ``codebook_`` (n_words, descriptor length), ``kmeans_``,
    ``n_images_`` (images per sample seen in fit).
    """

    def __init__(self, n_words=200, cell_px=8, patch_cells=2, orientations=9, image_size=120,
                 norm="l1", max_descriptors=50000, n_init=3, batch_size=4096, random_state=0):
        self.n_words = n_words
        self.cell_px = cell_px
        self.patch_cells = patch_cells
        self.orientations = orientations
        self.image_size = image_size
        self.norm = norm
        self.max_descriptors = max_descriptors
        self.n_init = n_init
        self.batch_size = batch_size
        self.random_state = random_state

    def _local_config(self) -> HogConfig:
        return HogConfig(image_size=self.image_size, cell_px=self.cell_px,
                         block_cells=self.patch_cells, orientations=self.orientations)

    def _images(self, X) -> tuple[np.ndarray, int]:
        """(n, H, W) or (n, k, H, W) -> flat images (n * k, H, W) and k."""
        arr = np.asarray(X)
        if arr.ndim == 3:
            return arr, 1
        if arr.ndim == 4:
            return arr.reshape(-1, *arr.shape[2:]), arr.shape[1]
        raise ValueError(
            f"BagOfVisualWords expects images (n, H, W) or stacks (n, k, H, W), got shape {arr.shape}")

    def local_descriptors(self, images) -> np.ndarray:
        """Dense descriptors of images (N, H, W): (N, patches per image, descriptor length)."""
        config = self._local_config()
        d = self.patch_cells ** 2 * self.orientations
        return hog_batch(images, config).reshape(len(images), -1, d)

    def fit(self, X, y=None):
        """Learn the codebook from training images (n, H, W) or stacks (n, k, H, W)."""
        if self.norm not in _NORMS:
            raise ValueError(f"norm must be one of {_NORMS}, got {self.norm!r}")
        images, k = self._images(X)
        desc = self.local_descriptors(images).reshape(-1, self.patch_cells ** 2 * self.orientations)
        if desc.shape[0] < self.n_words:
            raise ValueError(
                f"only {desc.shape[0]} local descriptors for {self.n_words} visual words; "
                "give more training images or lower n_words")
        rng = np.random.default_rng(self.random_state)
        if desc.shape[0] > self.max_descriptors:
            desc = desc[rng.choice(desc.shape[0], self.max_descriptors, replace=False)]
        self.kmeans_ = MiniBatchKMeans(
            n_clusters=self.n_words, n_init=self.n_init, batch_size=self.batch_size,
            random_state=self.random_state).fit(desc)
        self.codebook_ = self.kmeans_.cluster_centers_.astype(np.float32)
        self.n_images_ = k
        return self

    def transform(self, X) -> np.ndarray:
        """Word histograms: (n, n_words) for images, (n, k * n_words) for stacks."""
        check_is_fitted(self, "codebook_")
        images, k = self._images(X)
        n = images.shape[0] // k
        desc = self.local_descriptors(images)
        n_patches = desc.shape[1]
        words = self.kmeans_.predict(desc.reshape(-1, desc.shape[2])).reshape(len(images), n_patches)
        offsets = (np.arange(len(images)) * self.n_words)[:, None]
        hist = np.bincount((words + offsets).ravel(), minlength=len(images) * self.n_words)
        hist = hist.reshape(len(images), self.n_words).astype(np.float64)
        if self.norm in ("l1", "hellinger"):
            hist /= n_patches
            if self.norm == "hellinger":
                np.sqrt(hist, out=hist)
        elif self.norm == "l2":
            hist /= np.linalg.norm(hist, axis=1, keepdims=True)
        return hist.reshape(n, k * self.n_words).astype(np.float32)
