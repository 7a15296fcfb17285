"""The search, the baselines, the kept classifiers and the artifact with a feature extractor
other than the paper's HOG grid; what is learnt from data (the classifier's column scaling)
comes from training poses only."""
import dataclasses

import numpy as np
import pytest

from mux_trainer.baselines import NaiveClassifier
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.holdout import test_images as render_test_images
from mux_trainer.rendering import image_features, scoring_features
from mux_trainer.report import evaluate_noise_setting
from mux_trainer.search_params import Rendering, SplitScoring
from helpers.trainer import TINY_HOG, make_modelset


def test_scoring_features_are_standardised_for_the_extractors_that_ask(tiny_data):
    data = dataclasses.replace(tiny_data, features='intensity_stats')
    images = np.random.default_rng(0).uniform(0, 900, (2, data.n_samples, 24 * 24)).astype(np.float32)
    raw = image_features(data, images)
    assert raw.shape == (data.n_samples, 2 * 9)
    scaled = scoring_features(data, images)
    np.testing.assert_allclose(scaled.mean(axis=0), 0, atol=1e-4)
    np.testing.assert_allclose(scaled.std(axis=0), 1, atol=1e-3)
    # the paper's HOG grid is scored as it is
    np.testing.assert_array_equal(scoring_features(tiny_data, images), image_features(tiny_data, images))


def test_an_unknown_or_learning_extractor_is_refused_up_front(tiny_data):
    with pytest.raises(ValueError, match="unknown feature extractor 'sift'"):
        dataclasses.replace(tiny_data, features='sift')
    with pytest.raises(ValueError, match="learns from images"):
        dataclasses.replace(tiny_data, features='bow')


def test_greedy_with_intensity_stats_keeps_its_classifiers_and_artifact_on_those_features(tiny_data):
    data = dataclasses.replace(tiny_data, features='intensity_stats')
    model = GreedyPatternSelector(n_patterns=2, seed=0,
                                  scoring=SplitScoring(n_repeats=8)).fit(data)
    assert all(c.features == 'intensity_stats' for c in model.classifiers_.values())
    assert model.classifiers_[2].coef_.shape[1] == 2 * 4 * 9
    artifact = model.to_artifact()
    assert artifact.features == 'intensity_stats'
    # the artifact classifies raw stacks as the model classifies their features
    images = render_test_images(data, 'per_colour', model.patterns_, 0, seed=1)
    stacks = images.reshape(images.shape[0], data.n_samples, 24, 24).transpose(1, 0, 2, 3)
    expected = np.asarray(data.class_names)[model.predict_features(image_features(data, images), 2)]
    np.testing.assert_array_equal(artifact.predict(stacks), expected)


def _corrupt_poses(modelset, poses):
    """A copy of the modelset whose samples of `poses` are changed beyond recognition."""
    models = modelset.models.copy()
    held = np.isin(modelset.pose_index, poses)
    models[held] = models[held] * 3.0 + 200.0
    return dataclasses.replace(modelset, models=models)


def test_the_evaluation_learns_nothing_from_the_held_out_poses():
    """Every trained method (search scores, chosen patterns, classifier weights with their
    column scaling) must come out the same when the held-out poses are replaced: it would
    not if those poses reached the scaling, the search or the classifiers' fits."""
    modelset = make_modelset(n_types=2, n_poses=8)
    options = dict(methods=('naive', 'greedy'), n_repeats=8, max_images=2, seed=0,
                   hog_config=TINY_HOG, quiet=True, features='intensity_stats')
    clean = evaluate_noise_setting(modelset, 'sigma3', **options)
    held = clean['test_poses']
    assert held and len(held) < 8
    other = evaluate_noise_setting(_corrupt_poses(modelset, held), 'sigma3', **options)
    assert other['test_poses'] == held
    for name in ('naive', 'greedy'):
        a, b = clean['_models'][name], other['_models'][name]
        np.testing.assert_array_equal(a.patterns_, b.patterns_)
        assert a.accuracy_by_images_ == b.accuracy_by_images_
        for k in a.classifiers_:
            np.testing.assert_array_equal(a.classifiers_[k].coef_, b.classifiers_[k].coef_)
            np.testing.assert_array_equal(a.classifiers_[k].intercept_, b.classifiers_[k].intercept_)
    # ... and the held-out accuracy does see them (the corruption is not a no-op)
    assert clean['methods']['greedy']['accuracy'] != other['methods']['greedy']['accuracy'] or \
        clean['methods']['naive']['accuracy'] != other['methods']['naive']['accuracy']


def test_held_out_physical_samples_never_reach_training():
    """--holdout-by instances: replacing every pose of the held-out samples changes no trained
    weight, and those samples are the test set."""
    base = make_modelset(n_types=2, n_poses=8)
    modelset = dataclasses.replace(base, instance=base.pose_index // 2)  # 4 samples x 2 poses
    options = dict(methods=('naive', 'greedy'), n_repeats=8, max_images=2, seed=0,
                   hog_config=TINY_HOG, quiet=True, features='intensity_stats',
                   holdout_by='instances')
    clean = evaluate_noise_setting(modelset, 'sigma3', **options)
    assert clean['holdout_by'] == 'instances' and len(clean['test_instances']) == 1
    held_poses = np.unique(modelset.pose_index[np.isin(modelset.instance, clean['test_instances'])])
    assert clean['test_poses'] == sorted(held_poses.tolist())
    other = evaluate_noise_setting(_corrupt_poses(modelset, held_poses), 'sigma3', **options)
    for name in ('naive', 'greedy'):
        a, b = clean['_models'][name], other['_models'][name]
        np.testing.assert_array_equal(a.patterns_, b.patterns_)
        for k in a.classifiers_:
            np.testing.assert_array_equal(a.classifiers_[k].coef_, b.classifiers_[k].coef_)
    with pytest.raises(ValueError, match='holdout_by'):
        evaluate_noise_setting(modelset, 'sigma3', **{**options, 'holdout_by': 'classes'})


def test_a_global_standardisation_would_be_caught(monkeypatch):
    """The negative control: scaling the features over all samples before the hold-out
    (the leak the test above guards against) changes the trained weights."""
    import mux_trainer.report as report
    from mux_classifier.estimator import column_scaling
    modelset = make_modelset(n_types=2, n_poses=8)
    options = dict(methods=('naive',), n_repeats=8, max_images=1, seed=0,
                   hog_config=TINY_HOG, quiet=True, features='intensity_stats')
    real_search_data = report.search_data

    def leaky_search_data(ms, *args, **kwargs):  # brightness scaled by a statistic of ALL poses
        data = real_search_data(ms, *args, **kwargs)
        scale, _ = column_scaling(data.basis.reshape(-1, 1))
        data.basis = np.ascontiguousarray(data.basis / np.float32(scale[0] / 100.0))
        return data
    monkeypatch.setattr(report, 'search_data', leaky_search_data)
    clean = evaluate_noise_setting(modelset, 'sigma3', **options)
    other = evaluate_noise_setting(_corrupt_poses(modelset, clean['test_poses']), 'sigma3', **options)
    assert not np.array_equal(clean['_models']['naive'].classifiers_[1].coef_,
                              other['_models']['naive'].classifiers_[1].coef_)


def test_naive_baseline_takes_the_feature_name(tiny_data):
    model = NaiveClassifier(scoring=SplitScoring(n_repeats=4),
                            rendering=Rendering(features='intensity_stats')).fit(
        dataclasses.replace(tiny_data, features='intensity_stats'))
    assert model.classifiers_[1].features == 'intensity_stats'
    assert model.to_artifact().features == 'intensity_stats'
