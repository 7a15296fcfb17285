"""A sample's feature vector: the HOG descriptors of its images, concatenated in image order.

A *stack* is the k images of one sample taken under k illumination patterns, shape
(k, H, W); a batch of stacks is (n, k, H, W). Image j's 900 HOG values occupy columns
``j*900 .. (j+1)*900 - 1`` of the result, so the features of the first j images of a
stack are a prefix of the features of all k: a classifier for j images can be trained
on ``X[:, :j * 900]`` without recomputing anything.
"""
from __future__ import annotations

import numpy as np

from .hog import HogConfig, hog_batch

__all__ = ["stack_features", "check_stacks"]


def check_stacks(stacks, config: HogConfig = HogConfig(), n_images: int | None = None) -> np.ndarray:
    """Validate a batch of stacks (n, k, H, W) and return it as an array.

    Raises ValueError saying what is wrong (rank, image size, number of images) and what
    to do about it.
    """
    arr = np.asarray(stacks)
    if arr.ndim != 4:
        hint = (" (one sample's stack (k, H, W)? pass stacks[None])" if arr.ndim == 3 else "")
        raise ValueError(f"expected a batch of image stacks (n, k, H, W), got shape {arr.shape}{hint}")
    size = config.image_size
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
