"""Pose normalisation before the HOG grid: move the object to the image centre and turn its
principal axis to the column axis, then take the paper's HOG grid.

The pose comes from the stack's foreground mask (`object_mask`): centroid and principal
axis (second moments; the 180-degree ambiguity resolved by the third moment). Every image of
a stack is warped the same way (bilinear, compiled; out-of-image samples take the nearest
edge pixel, i.e. floor). Round objects have no principal axis, so for them only the
translation is normalised; and the light's direction turns with the warp, so gradients the
light draws are no longer at a fixed orientation.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .hog import HogConfig, hog_batch
from .object_mask import mask_moments, stack_masks

__all__ = ["normalise_poses", "pose_normalised_hog"]


@numba.njit(cache=True, nogil=True)
def _warp(stacks, centroid, angle, out):
    n, k, H, W = stacks.shape
    oc_r, oc_c = (H - 1) / 2.0, (W - 1) / 2.0
    for i in range(n):
        ca, sa = math.cos(angle[i]), math.sin(angle[i])
        for r in range(H):
            dr = r - oc_r
            for c in range(W):
                dc = c - oc_c
                src_c = centroid[i, 1] + dc * ca - dr * sa
                src_r = centroid[i, 0] + dc * sa + dr * ca
                src_r = min(max(src_r, 0.0), H - 1.0)
                src_c = min(max(src_c, 0.0), W - 1.0)
                r0 = min(int(src_r), H - 2)
                c0 = min(int(src_c), W - 2)
                fr, fc = src_r - r0, src_c - c0
                for j in range(k):
                    img = stacks[i, j]
                    top = img[r0, c0] * (1 - fc) + img[r0, c0 + 1] * fc
                    bottom = img[r0 + 1, c0] * (1 - fc) + img[r0 + 1, c0 + 1] * fc
                    out[i, j, r, c] = top * (1 - fr) + bottom * fr


def normalise_poses(stacks: np.ndarray) -> np.ndarray:
    """Stacks (n, k, H, W) warped so each object is centred on its principal axis."""
    arr = np.ascontiguousarray(stacks, dtype=np.float32)
    centroid, angle, _ = mask_moments(stack_masks(arr))
    out = np.empty_like(arr)
    _warp(arr, np.ascontiguousarray(centroid), np.ascontiguousarray(angle), out)
    return out


def pose_normalised_hog(stacks: np.ndarray, config: HogConfig = HogConfig()) -> np.ndarray:
    """(n, k, H, W) -> float32 (n, k * 900): the HOG grid of the pose-normalised images."""
    warped = normalise_poses(stacks)
    n, k = warped.shape[:2]
    return hog_batch(warped.reshape(n * k, *warped.shape[2:]), config).reshape(n, -1)
