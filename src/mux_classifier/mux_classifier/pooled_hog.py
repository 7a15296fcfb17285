"""Dense local HOG pooled over the object without position: a placement-robust feature.

Local descriptors are HOG blocks of 2 x 2 cells of 8 px (36 values, L2-Hys normalised) on a
one-cell grid, as in the bag of words (`bow.py`), computed with the same batched HOG. They
are pooled over the object with weights = the fraction of each block that is object
(`object_mask.stack_masks`): the weighted mean and the weighted standard deviation of each
of the 36 values, 72 values per image. The floor does not dilute the pool, and no position
survives it. Orientation bins are kept as they are: gradients that the light draws (shading
of relief, shadows) point the same way whatever the object's rotation, because the sites
do not move with the object.
"""
from __future__ import annotations

import numpy as np

from .hog import HogConfig, hog_batch
from .object_mask import stack_masks

__all__ = ["pooled_hog"]

LOCAL = dict(cell_px=8, block_cells=2, orientations=9)


def _block_weights(masks: np.ndarray, config: HogConfig) -> np.ndarray:
    """Object fraction of each local block: (n, n_blocks ** 2)."""
    n = len(masks)
    c, nc, b = config.cell_px, config.n_cells, config.block_cells
    cells = masks[:, :nc * c, :nc * c].reshape(n, nc, c, nc, c).mean(axis=(2, 4))
    nb = config.n_blocks
    blocks = np.zeros((n, nb, nb))
    for i in range(b):
        for j in range(b):
            blocks += cells[:, i:i + nb, j:j + nb]
    return (blocks / (b * b)).reshape(n, nb * nb)


def pooled_hog(stacks: np.ndarray, image_size: int = 120) -> np.ndarray:
    """(n, k, H, W) -> float32 (n, k * 72): per image, the object-weighted mean and std of
    its dense local HOG blocks, concatenated in image order."""
    config = HogConfig(image_size=image_size, **LOCAL)
    n, k = stacks.shape[:2]
    d = config.block_cells ** 2 * config.orientations
    desc = hog_batch(stacks.reshape(n * k, *stacks.shape[2:]), config).reshape(n, k, -1, d)
    weights = _block_weights(stack_masks(stacks), config) + 1e-6
    weights = (weights / weights.sum(axis=1, keepdims=True))[:, None, :, None]
    mean = (desc * weights).sum(axis=2)
    var = (((desc - mean[:, :, None, :]) ** 2) * weights).sum(axis=2)
    return np.concatenate([mean, np.sqrt(var)], axis=2).reshape(n, k * 2 * d).astype(np.float32)
