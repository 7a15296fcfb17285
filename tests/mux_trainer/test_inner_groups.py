"""Every method is chosen and scored by inner splits that hold out whole physical samples
where the data has two or more of every class (`SplitScoring.inner_groups`)."""
import dataclasses

import numpy as np
import pytest

from helpers.trainer import TINY_HOG
from mux_trainer.baselines import NaiveClassifier, SnrOptimalClassifier
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.rendering import SearchData
from mux_trainer.search_params import SplitScoring


def memorisable_data(n_samples=8, n_poses=4, size=24, seed=0) -> SearchData:
    """2 classes with no class cue at all, each physical sample its own strong texture that
    every pose of it shows (shifted a little): a classifier can recognise a sample it has
    seen in other poses, never a new sample's class."""
    rng = np.random.default_rng(seed)
    models, labels, poses, inst = [], [], [], []
    for c in range(2):
        for s in range(n_samples):
            texture = rng.uniform(20, 230, size=(size, size)).astype(np.float32)
            for p in range(n_poses):
                shifted = np.roll(texture, p % 2, axis=1)
                m = np.broadcast_to(shifted, (4, 8, size, size)).astype(np.float32)
                models.append(m)
                labels.append(c)
                poses.append(s * n_poses + p)
                inst.append(s)
    return SearchData.from_models(np.stack(models), labels, poses, ['a-fake', 'a-real'],
                                  noise_a=0.9, noise_b=100.0, hog_config=TINY_HOG,
                                  noise_name='custom', instance=inst)


@pytest.fixture(scope='module')
def memorisable():
    return memorisable_data()


def test_pose_splits_score_samples_seen_grouped_splits_score_new_ones(memorisable):
    """The inner estimate by pose recognises the samples (far above chance although no class
    cue exists); by physical sample it is at chance, what a new object gets."""
    by_pose = NaiveClassifier(scoring=SplitScoring(n_repeats=40, inner_groups='poses')
                              ).fit(memorisable)
    grouped = NaiveClassifier(scoring=SplitScoring(n_repeats=40)).fit(memorisable)
    assert by_pose.inner_estimate_['held_out'] == 'poses'
    assert grouped.inner_estimate_['held_out'] == 'physical samples'   # 'auto'
    assert by_pose.inner_estimate_['accuracy'] > 0.9
    assert grouped.inner_estimate_['accuracy'] < 0.75


def test_every_search_holds_out_whole_samples_and_says_so_in_the_artifact(memorisable):
    greedy = GreedyPatternSelector(mode='per_colour', n_patterns=1,
                                   scoring=SplitScoring(n_repeats=8)).fit(memorisable)
    snr = SnrOptimalClassifier(n_images=1, n_iter=200,
                               scoring=SplitScoring(n_repeats=8)).fit(memorisable)
    labels, inst = memorisable.labels, memorisable.instance
    for model in (greedy, snr):
        for mask in model.evaluator_.test_masks:
            held = [set(inst[mask & (labels == c)]) for c in (0, 1)]
            assert len(held[0]) == 2 and held[0] == held[1]   # the same samples of each class
            for c in (0, 1):
                assert not held[c] & set(inst[~mask & (labels == c)])
        prov = model.to_artifact().provenance['inner_estimate']
        assert prov['held_out'] == 'physical samples' and prov['groups_per_class'] == 8
        assert prov['held_out_per_class'] == 2
        assert prov['n_repeats'] == 8 and prov['accuracy'] == model.accuracy_by_images_[1]


def test_one_sample_per_class_keeps_the_pose_splits(memorisable):
    """Without physical sample numbers (or with one per class) 'auto' is the pose splits,
    the same draws and scores as 'poses'."""
    unknown = dataclasses.replace(memorisable, instance=None)
    auto = NaiveClassifier(scoring=SplitScoring(n_repeats=6)).fit(unknown)
    poses = NaiveClassifier(scoring=SplitScoring(n_repeats=6, inner_groups='poses')
                            ).fit(memorisable)
    assert auto.inner_estimate_ == poses.inner_estimate_ | {'inner_groups': 'auto'}
    assert auto.accuracy_by_images_ == poses.accuracy_by_images_
    with pytest.raises(ValueError, match='at least 2 physical samples of every class'):
        NaiveClassifier(scoring=SplitScoring(n_repeats=6, inner_groups='instances')).fit(unknown)
    with pytest.raises(ValueError, match='inner_groups must be one of'):
        NaiveClassifier(scoring=SplitScoring(inner_groups='objects')).fit(unknown)


def test_learned_loss_folds_hold_out_whole_samples(memorisable):
    from mux_trainer.learned import inner_folds, instance_folds
    labels, inst = memorisable.labels, memorisable.instance
    folds = instance_folds(labels, inst, 5)
    assert folds.shape[0] == 5 and np.all(folds.sum(axis=0) == 1)   # each sample once
    for fold in folds:
        held = [set(inst[fold & (labels == c)]) for c in (0, 1)]
        assert len(held[0]) in (1, 2) and held[0] == held[1]
        for c in (0, 1):
            assert not held[c] & set(inst[~fold & (labels == c)])
    poses = inner_folds(memorisable, 5, 'poses')
    assert any(len(set(inst[f & (labels == 0)])) > 1 for f in poses)
    np.testing.assert_array_equal(inner_folds(memorisable, 5), folds)


def test_trainer_node_has_an_inner_groups_parameter():
    from lightstage_graph.params import check_value
    from mux_trainer.trainer_node import PARAMETERS
    default, descriptor = PARAMETERS['inner_groups']
    assert default == 'auto'
    assert descriptor.additional_constraints == 'auto, poses, instances'
    assert check_value('inner_groups', 'instances', descriptor) == 'instances'
