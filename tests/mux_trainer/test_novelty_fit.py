"""Unknown objects at training time and in the artifact: a known object's render scores below
1, a foreign object's above, and the file keeps the models."""
import dataclasses

import numpy as np
import pytest
from mux_classifier.artifact import ArtifactError, TrainedArtifact
from mux_classifier.confidence import UNKNOWN
from mux_trainer.evaluation import render
from mux_trainer.novelty_fit import fit_pattern_novelty
from mux_trainer.rendering import add_noise, standard_normal

from helpers.artifact_checks import rewrite_artifact


@pytest.fixture(scope='module')
def trained(stage_modelset, tmp_path_factory):
    """The stage capture's fixed-pattern model (banana and orange, 2 samples per class) and
    its artifact with novelty models, saved and loaded."""
    from mux_trainer.baselines import FixedPatternClassifier
    from mux_trainer.search_params import Rendering, SplitScoring
    from helpers.suite import TRAIN_SITE_PATTERNS
    model = FixedPatternClassifier(patterns=TRAIN_SITE_PATTERNS, seed=0,
                                   scoring=SplitScoring(n_repeats=4),
                                   rendering=Rendering(noise='sigma3')).fit(stage_modelset)
    artifact = dataclasses.replace(model.to_artifact(), novelty=fit_pattern_novelty(model))
    path = tmp_path_factory.mktemp('novelty') / 'classifier.npz'
    artifact.save(path)
    return model, path


def _stacks(data, patterns, seed):
    """Noisy images of every sample of `data` under per-colour `patterns`: (n, k, H, W)."""
    clean = render(data, 'per_colour', patterns)
    noisy = add_noise(data, clean, standard_normal(np.random.default_rng(seed), clean.shape))
    return noisy.transpose(1, 0, 2).reshape(data.n_samples, -1, *data.image_shape)


def _foreign_data(model, tmp_path):
    """A grape (a type the stage capture has not) as the model's search data."""
    from lightstage_physics import synth
    from mux_trainer.data import search_data
    from mux_trainer.training import load_training_set
    out = synth.generate(tmp_path / 'grape', image_size=120, n_samples_per_class=1, n_poses=1,
                         object_types=('grape',), n_jobs=1, seed=3)
    return search_data(load_training_set(out), 'sigma3')


def test_known_renders_score_below_one_and_a_foreign_object_is_unknown(trained, tmp_path):
    model, path = trained
    art = TrainedArtifact.load(path)
    assert sorted(art.novelty) == [4, 8] and art.describe().endswith(
        'noise sigma3, dimmer 0.45') and 'unknown objects flagged at 5 % false alarms' in art.describe()
    known = _stacks(model.evaluator_.data, model.patterns_, seed=11)  # fresh camera noise
    scores = np.array([art.decide(s).novelty for s in known])
    # measured: at most 0.51 (4 images) and 0.23 (8), medians 0.21 and 0.14
    assert np.median(scores) < 0.5 and (scores >= 1).mean() <= 0.1
    foreign = _stacks(_foreign_data(model, tmp_path), model.patterns_, seed=12)
    for k in (4, 8):
        d = art.decide(foreign[0, :k])
        assert d.decision == UNKNOWN and d.novelty > 3 and d.n_images == k  # measured: 4.2, 4.8
    # the empty stage (the floor alone) is no trained object either (measured: 880)
    assert art.decide(np.full((8, 120, 120), 40.0, np.float32)).decision == UNKNOWN


def test_the_file_keeps_the_novelty_models_and_refuses_broken_ones(trained, tmp_path):
    model, path = trained
    art = TrainedArtifact.load(path)
    before = fit_pattern_novelty(model)[8].to_arrays()
    for name, a in art.novelty[8].to_arrays().items():
        np.testing.assert_array_equal(a, before[name])
    bad = tmp_path / 'bad.npz'
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez(bad, **{**arrays, 'novelty_8_threshold': np.array([-1.0])})
    with pytest.raises(ArtifactError, match="novelty model for 8 images.*'threshold' must be > 0"):
        TrainedArtifact.load(bad)
    rewrite_artifact(path, bad, drop=['novelty_4_precision'])
    with pytest.raises(ArtifactError, match="no array 'novelty_4_precision'"):
        TrainedArtifact.load(bad)
    rewrite_artifact(path, bad, lambda h: h.update(novelty={'features': 'hog_grid',
                                                            'n_images': [4]}))
    with pytest.raises(ArtifactError, match="'novelty.features' must be 'intensity_stats'"):
        TrainedArtifact.load(bad)
    rewrite_artifact(path, bad, lambda h: h.update(novelty={'features': 'intensity_stats',
                                                            'n_images': [12]}))
    with pytest.raises(ArtifactError, match="no array 'novelty_12_projection'"):
        TrainedArtifact.load(bad)
    # without its novelty models the artifact never says unknown
    plain = dataclasses.replace(art, novelty=None)
    assert np.isnan(plain.decide(np.zeros((8, 120, 120), np.float32)).novelty)
