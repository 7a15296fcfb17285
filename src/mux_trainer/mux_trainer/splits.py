"""Repeated random pose splits: the paper's 75 / 25 train/test rule.

Each split draws a random subset of the pose indices as the test poses; every sample whose
pose index is in that subset is a test sample, whatever its class. So the same pose indices
are held out for every class, and a class never sees a test pose in training.
"""
from __future__ import annotations

import numpy as np


def n_test_poses(n_poses: int, test_fraction: float) -> int:
    """How many of `n_poses` pose indices a split holds out (at least 1, at most n - 1)."""
    if n_poses < 2:
        raise ValueError(f'pose splits need at least 2 distinct poses, got {n_poses}; '
                         'capture more poses per class')
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f'test_fraction must be in (0, 1), got {test_fraction}')
    return int(min(max(round(test_fraction * n_poses), 1), n_poses - 1))


def pose_splits(pose_index: np.ndarray, n_repeats: int, test_fraction: float = 0.25,
                rng: np.random.Generator | int | None = 0) -> list[np.ndarray]:
    """`n_repeats` boolean test masks over the samples (True = test sample).

    pose_index: the pose number of each sample within its class. The held-out pose indices
    are drawn without replacement, independently per split, from `rng`.
    """
    pose_index = np.asarray(pose_index)
    if pose_index.ndim != 1:
        raise ValueError(f'pose_index must be 1-D (one entry per sample), got {pose_index.shape}')
    if n_repeats < 1:
        raise ValueError(f'n_repeats must be >= 1, got {n_repeats}')
    rng = np.random.default_rng(rng)
    poses = np.unique(pose_index)
    k = n_test_poses(poses.size, test_fraction)
    masks = []
    for _ in range(n_repeats):
        test_poses = rng.choice(poses, size=k, replace=False)
        masks.append(np.isin(pose_index, test_poses))
    return masks


def split_indices(masks: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boolean test masks -> (train indices, test indices) pairs."""
    return [(np.flatnonzero(~m), np.flatnonzero(m)) for m in masks]
