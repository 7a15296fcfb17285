import numpy as np
import pytest

from mux_trainer.splits import n_test_poses, pose_splits


def test_same_pose_indices_held_out_for_every_class():
    labels = np.repeat(np.arange(5), 20)
    pose = np.tile(np.arange(20), 5)
    masks = pose_splits(pose, 50, 0.25, rng=3)
    for mask in masks:
        assert mask.sum() == 5 * 5  # 25 % of 20 poses, in each of 5 classes
        held = [set(pose[mask & (labels == k)]) for k in range(5)]
        assert all(h == held[0] for h in held)
        assert not set(pose[~mask]) & held[0]


def test_splits_reproducible_and_varied():
    pose = np.tile(np.arange(20), 3)
    a = pose_splits(pose, 20, 0.25, rng=7)
    b = pose_splits(pose, 20, 0.25, rng=7)
    c = pose_splits(pose, 20, 0.25, rng=8)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))
    assert len({m.tobytes() for m in a}) > 10


def test_split_rule_errors():
    assert n_test_poses(20, 0.25) == 5
    assert n_test_poses(2, 0.25) == 1
    with pytest.raises(ValueError, match='at least 2 distinct poses'):
        pose_splits(np.zeros(6, int), 3)
    with pytest.raises(ValueError, match='test_fraction'):
        pose_splits(np.arange(6), 3, test_fraction=1.0)
