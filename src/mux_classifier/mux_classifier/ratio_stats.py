"""Cross-image relief statistics: per pair of images of a stack, how the log ratio of the two
varies over the object.

A flat print of a relief (a forged seal, a printed coin) reproduces the relief's shading as
ink. The ratio of two images of one pose under two lights cancels what multiplies both
(albedo, ink, print, the instance's tint), but not shading, which turns with the light: on a
relief the log ratio varies over the object and has edges, on a print it is flat up to the
noise. `intensity_stats` sees each image alone and cannot tell the two apart once the print
matches the relief under one light. Per pair ``(i, j)``, ``i < j``, of the k images:
``R = log(I_i + c) - log(I_j + c)``, its spread (standard deviation over the object) and the
mean magnitude of its gradient (central differences, zero on the border rows and columns),
so ``2 * k (k - 1) / 2`` values per stack. ``c`` (``offset``, gray levels; the learned model
stores it) keeps the dark pixels' noise from ruling the logarithm: `OFFSET_FRACTION` of the
camera's top level.

The object is the stack's (`object_mask.stack_masks`, one mask from the summed image; none:
the whole image): a ratio needs the same pixels in both images. `pair_ratio_stats` takes the
array module, so the learned trainer differentiates the very same formula in JAX
(`mux_trainer.learned`); this package never imports JAX.
"""
from __future__ import annotations

import itertools

import numpy as np

from .object_mask import stack_masks

__all__ = ["ratio_stats", "pair_ratio_stats", "object_masks", "object_box", "image_pairs",
           "n_ratio_stats", "N_RATIO_STATS", "OFFSET_FRACTION"]

N_RATIO_STATS = 2        # per image pair: the log ratio's spread and its mean gradient
OFFSET_FRACTION = 0.01   # c, as a fraction of the camera's top gray level


def image_pairs(k: int) -> list[tuple[int, int]]:
    """The pairs ``(i, j)``, ``i < j``, of k images, in the features' order."""
    return list(itertools.combinations(range(int(k)), 2))


def n_ratio_stats(k: int) -> int:
    """Values per stack of k images."""
    return N_RATIO_STATS * len(image_pairs(k))


def pair_ratio_stats(xp, log_images, mask, grad_eps: float = 0.0):
    """The statistics from log images ``(k, n, H, W)`` and object masks ``(n, H, W)`` (0/1
    floats, none empty) with array module ``xp`` (numpy or jax.numpy): ``(n, n_ratio_stats(k))``.
    grad_eps (inside the gradient's square root) keeps JAX's derivative finite where the ratio
    is locally flat."""
    count = mask.sum((1, 2))
    if log_images.shape[0] < 2:   # one image: no pair
        return xp.zeros((mask.shape[0], 0), log_images.dtype)
    out = []
    for i, j in image_pairs(log_images.shape[0]):
        R = log_images[i] - log_images[j]
        gr = xp.pad(R[:, 2:, :] - R[:, :-2, :], ((0, 0), (1, 1), (0, 0)))
        gc = xp.pad(R[:, :, 2:] - R[:, :, :-2], ((0, 0), (0, 0), (1, 1)))
        grad = xp.sqrt(gr * gr + gc * gc + grad_eps)
        mean = (R * mask).sum((1, 2)) / count
        spread = xp.sqrt((((R - mean[:, None, None]) ** 2) * mask).sum((1, 2)) / count + 1e-8)
        out += [spread, (grad * mask).sum((1, 2)) / count]
    return xp.stack(out, 1)


def object_masks(stacks: np.ndarray) -> np.ndarray:
    """The stacks' object masks ``(n, H, W)`` bool (`stack_masks`; an empty one: every pixel)."""
    mask = stack_masks(stacks)
    mask[~mask.reshape(len(mask), -1).any(axis=1)] = True
    return mask


def object_box(mask: np.ndarray) -> tuple[slice, slice]:
    """The rows and columns of a mask ``(H, W)``'s pixels with one pixel around them (inside
    the image): the crop in which `pair_ratio_stats` gives a mask's pixels the values it gives
    them in the whole image (a mask pixel is on the crop's border only where it is on the
    image's, where its gradient is zero in both)."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    H, W = mask.shape
    return (slice(max(rows[0] - 1, 0), min(rows[-1] + 2, H)),
            slice(max(cols[0] - 1, 0), min(cols[-1] + 2, W)))


def ratio_stats(stacks: np.ndarray, offset: float) -> np.ndarray:
    """Stacks ``(n, k, H, W)`` gray levels -> float32 ``(n, n_ratio_stats(k))``, in float32
    over each stack's object box (`object_box`): what the classifier computes per sample."""
    arr = np.asarray(stacks, dtype=np.float32)
    if arr.ndim != 4:
        raise ValueError(f"ratio_stats expects stacks of shape (n, k, H, W), got {arr.shape}")
    if not (np.isfinite(offset) and offset > 0):
        raise ValueError(f"offset must be a positive number of gray levels, got {offset}")
    masks = object_masks(arr)
    out = np.empty((arr.shape[0], n_ratio_stats(arr.shape[1])), np.float32)
    for s, (stack, mask) in enumerate(zip(arr, masks)):
        rows, cols = object_box(mask)
        log_images = np.log(np.maximum(stack[:, rows, cols], 0) + np.float32(offset))
        box_mask = mask[None, rows, cols].astype(np.float32)
        out[s] = pair_ratio_stats(np, log_images[:, None], box_mask)[0]
    return out
