"""Per-image reflectance statistics over the object: what HOG's block normalisation removes.

HOG keeps only the shape of the gradients; how much light an object returns in each band
under each pattern is lost. These features keep it, and ignore where the object lies: per
image, over the object's pixels (`object_mask.stack_masks`), the quantiles 10/25/50/75/90 %
and the mean of the gray level, and the mean and quantiles 50/90 % of the gradient
magnitude (relief and texture contrast), in gray levels: 9 values per image.
"""
from __future__ import annotations

import numpy as np

from .object_mask import stack_masks

__all__ = ["intensity_stats", "N_STATS"]

LEVEL_QUANTILES = (10, 25, 50, 75, 90)
GRADIENT_QUANTILES = (50, 90)
N_STATS = len(LEVEL_QUANTILES) + 1 + 1 + len(GRADIENT_QUANTILES)


def intensity_stats(stacks: np.ndarray) -> np.ndarray:
    """(n, k, H, W) -> float32 (n, k * 9) object statistics, concatenated in image order."""
    arr = np.asarray(stacks, dtype=np.float32)
    n, k = arr.shape[:2]
    masks = stack_masks(arr)
    gr = np.zeros_like(arr)
    gc = np.zeros_like(arr)
    gr[..., 1:-1, :] = arr[..., 2:, :] - arr[..., :-2, :]
    gc[..., :, 1:-1] = arr[..., :, 2:] - arr[..., :, :-2]
    grad = np.sqrt(gr * gr + gc * gc)
    out = np.zeros((n, k, N_STATS), np.float32)
    for i in range(n):
        mask = masks[i]
        if not mask.any():  # no object found: the whole image stands in for it
            mask = np.ones_like(mask)
        levels = arr[i][:, mask]  # (k, object pixels)
        grads = grad[i][:, mask]
        out[i, :, :5] = np.percentile(levels, LEVEL_QUANTILES, axis=1).T
        out[i, :, 5] = levels.mean(axis=1)
        out[i, :, 6] = grads.mean(axis=1)
        out[i, :, 7:] = np.percentile(grads, GRADIENT_QUANTILES, axis=1).T
    return out.reshape(n, k * N_STATS)
