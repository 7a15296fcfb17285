"""Where the object lies in a stack of images: a foreground mask and its pose (centroid,
principal axis), shared by the pose-robust feature extractors.

A mask is taken from one gray image: the stage floor (black felt) covers most of the field
of view, so its level is the image's median; a pixel is object when it is brighter than the
floor by a fraction of the object's range (floor to the 99th percentile). All images of a
stack show the same pose, so the pose-robust extractors take one mask per stack, from the
stack's summed image (`stack_masks`); `image_masks` is the same rule on single images
(`intensity_stats` takes each image's own). Nothing is learned: a mask depends on its image
(or stack) alone.
"""
from __future__ import annotations

import numpy as np

__all__ = ["image_masks", "stack_masks", "mask_moments", "MASK_FRACTION"]

MASK_FRACTION = 0.25  # of the way from the floor level to the bright end


def image_masks(images: np.ndarray, fraction: float = MASK_FRACTION) -> np.ndarray:
    """Foreground masks (n, H, W) bool of gray images (n, H, W), each from its image alone
    (exact median and 99th percentile; may be empty: then no pixel stands out)."""
    arr = np.asarray(images, dtype=np.float32)
    flat = arr.reshape(len(arr), -1)
    floor, top = np.percentile(flat, [50, 99], axis=1)
    threshold = floor + fraction * np.maximum(top - floor, 1e-6)
    return arr > threshold[:, None, None]


def stack_masks(stacks: np.ndarray, fraction: float = MASK_FRACTION) -> np.ndarray:
    """Foreground masks (n, H, W) bool of stacks (n, k, H, W), from each stack's summed image."""
    return image_masks(np.asarray(stacks, dtype=np.float32).sum(axis=1), fraction)


def mask_moments(masks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid (n, 2) as (row, col), principal-axis angle (n,) in radians measured from
    the column axis toward the row axis, and object pixel count (n,), of masks (n, H, W).

    The axis's 180-degree ambiguity is resolved by the sign of the third moment along it
    (the heavier tail points to +axis). An empty mask gets the image centre and angle 0.
    """
    n, H, W = masks.shape
    rows = np.arange(H, dtype=np.float64)[None, :, None]
    cols = np.arange(W, dtype=np.float64)[None, None, :]
    m = masks.astype(np.float64)
    area = m.sum(axis=(1, 2))
    safe = np.maximum(area, 1.0)
    cr = (m * rows).sum(axis=(1, 2)) / safe
    cc = (m * cols).sum(axis=(1, 2)) / safe
    cr = np.where(area > 0, cr, (H - 1) / 2)
    cc = np.where(area > 0, cc, (W - 1) / 2)
    dr = rows - cr[:, None, None]
    dc = cols - cc[:, None, None]
    mrr = (m * dr * dr).sum(axis=(1, 2)) / safe
    mcc = (m * dc * dc).sum(axis=(1, 2)) / safe
    mrc = (m * dr * dc).sum(axis=(1, 2)) / safe
    angle = 0.5 * np.arctan2(2 * mrc, mcc - mrr)
    along = dc * np.cos(angle)[:, None, None] + dr * np.sin(angle)[:, None, None]
    skew = (m * along ** 3).sum(axis=(1, 2))
    angle = np.where(skew < 0, angle + np.pi, angle)
    return np.stack([cr, cc], axis=1), angle, area
