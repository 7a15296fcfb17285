import numpy as np

from mux_trainer.baselines import NaiveClassifier
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
    model = NaiveClassifier(n_repeats=4).fit(tiny_data.subset(train))
    test_data = tiny_data.subset(test)
    a = evaluate_heldout(model, test_data, n_renders=2, seed=1)
    b = evaluate_heldout(model, test_data, n_renders=2, seed=1)
    assert a['accuracy_by_images'] == b['accuracy_by_images']
    correct = np.zeros(test_data.n_samples)
    correct[test_data.labels <= 1] = 1.0  # fruit0-fake and fruit0-real right, fruit1 wrong
    assert accuracy_by_type(test_data, correct) == {'fruit0': 1.0, 'fruit1': 0.0}
    s = method_summary(model, test_data, n_renders=2, seed=1)
    assert s['accuracy'] == a['accuracy_by_images'][1] and s['n_exposures'] == 1
