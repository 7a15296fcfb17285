import numpy as np

from mux_trainer.baselines import NaiveClassifier
from mux_trainer.search_params import SplitScoring
from mux_trainer.holdout import accuracy_by_type, evaluate_heldout, holdout_split, method_summary


def test_holdout_keeps_whole_pose_indices_out_of_training(tiny_data):
    train, test = holdout_split(tiny_data, 0.25, seed=4)
    assert np.intersect1d(train, test).size == 0 and train.size + test.size == tiny_data.n_samples
    held = set(tiny_data.pose_index[test])
    assert len(held) == 2  # 25 % of 8 poses
    assert not held & set(tiny_data.pose_index[train])
    for k in range(4):
        assert set(tiny_data.pose_index[test][tiny_data.labels[test] == k]) == held


def test_heldout_accuracy_is_reproducible_and_groups_types(tiny_data):
    train, test = holdout_split(tiny_data, 0.25, seed=0)
    model = NaiveClassifier(scoring=SplitScoring(n_repeats=4)).fit(tiny_data.subset(train))
    test_data = tiny_data.subset(test)
    a = evaluate_heldout(model, test_data, n_renders=2, seed=1)
    b = evaluate_heldout(model, test_data, n_renders=2, seed=1)
    assert a['accuracy_by_images'] == b['accuracy_by_images']
    correct = np.zeros(test_data.n_samples)
    correct[test_data.labels <= 1] = 1.0  # fruit0-fake and fruit0-real right, fruit1 wrong
    assert accuracy_by_type(test_data, correct) == {'fruit0': 1.0, 'fruit1': 0.0}
    s = method_summary(model, test_data, n_renders=2, seed=1)
    assert s['accuracy'] == a['accuracy_by_images'][1] and s['n_exposures'] == 1


def test_holdout_by_instance_keeps_whole_physical_samples_out_of_training(tiny_data):
    instance = tiny_data.pose_index // 2  # 4 physical samples of 2 poses per class
    train, test = holdout_split(tiny_data, 0.25, seed=4, instance=instance)
    assert np.intersect1d(train, test).size == 0 and train.size + test.size == tiny_data.n_samples
    held = set(instance[test])
    assert len(held) == 1  # 25 % of 4 samples
    assert not held & set(instance[train])  # no held-out object in training, in any pose
    for k in range(4):  # the same sample numbers for every class, with all their poses
        in_class = tiny_data.labels == k
        assert set(instance[test][tiny_data.labels[test] == k]) == held
        assert set(tiny_data.pose_index[test][tiny_data.labels[test] == k]) == \
            set(tiny_data.pose_index[in_class & np.isin(instance, list(held))])


def test_holdout_by_instance_needs_two_samples_and_one_entry_per_sample(tiny_data):
    import pytest
    with pytest.raises(ValueError, match='at least 2 physical samples'):
        holdout_split(tiny_data, 0.25, instance=np.zeros(tiny_data.n_samples, int))
    with pytest.raises(ValueError, match='one entry per sample'):
        holdout_split(tiny_data, 0.25, instance=np.zeros(3, int))
