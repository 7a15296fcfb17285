import numpy as np
import pytest

from mux_trainer.splits import (describe_inner, inner_splits, instance_splits, n_test_poses,
                                 pose_splits, resolve_inner_groups)


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


def _samples(n_classes=3, per_class=(4, 4, 4), poses=3):
    """labels, pose index within class, physical sample within class."""
    labels, pose, inst = [], [], []
    for c in range(n_classes):
        for s in range(per_class[c]):
            for p in range(poses):
                labels.append(c)
                pose.append(s * poses + p)
                inst.append(s)
    return np.array(labels), np.array(pose), np.array(inst)


def test_instance_splits_hold_out_the_same_whole_samples_of_every_class_each_in_turn():
    labels, _, inst = _samples(per_class=(4, 4, 6))
    masks = instance_splits(labels, inst, 12, 0.25, rng=0)
    for mask in masks:
        held = [set(inst[mask & (labels == c)]) for c in range(3)]
        for c in range(3):
            assert not held[c] & set(inst[~mask & (labels == c)])   # every pose of a sample
        # one number (25 % of the fewest, 4), the same in every class that has it
        assert len(held[2]) == 1 and held[0] == held[1] == held[2] - {4, 5}
    # every sample number held out within ceil(6 / 1) + 1 consecutive splits
    assert set().union(*(set(inst[m]) for m in masks[:7])) == set(range(6))


def test_auto_groups_by_sample_only_where_every_class_has_two():
    labels, pose, inst = _samples(per_class=(2, 2, 2))
    assert resolve_inner_groups('auto', labels, inst) == 'instances'
    assert resolve_inner_groups('auto', labels, None) == 'poses'
    one = np.zeros_like(inst)
    assert resolve_inner_groups('auto', labels, one) == 'poses'
    # with one sample per class the draws are the pose splits', unchanged
    masks, desc = inner_splits(labels, pose, one, 5, 0.25, rng=4)
    assert all(np.array_equal(a, b) for a, b in zip(masks, pose_splits(pose, 5, 0.25, rng=4)))
    assert desc['held_out'] == 'poses' and desc['groups_per_class'] == 6
    assert 'holds only for the objects trained on' in describe_inner(desc, 0.9)
    masks, desc = inner_splits(labels, pose, inst, 5, 0.25, rng=4, inner_groups='auto')
    assert desc['held_out'] == 'physical samples' and desc['groups_per_class'] == 2
    assert 'objects never seen in training' in describe_inner(desc, 0.9)
    with pytest.raises(ValueError, match='at least 2 physical samples of every class'):
        resolve_inner_groups('instances', labels, one)
    with pytest.raises(ValueError, match='inner_groups must be one of'):
        resolve_inner_groups('samples', labels, inst)
