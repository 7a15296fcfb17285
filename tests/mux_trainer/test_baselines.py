import numpy as np
import pytest

from mux_trainer.baselines import FixedPatternClassifier, NaiveClassifier, SnrOptimalClassifier
from mux_trainer.evaluation import CandidateEvaluator
from mux_trainer.search_params import Rendering, SplitScoring
from mux_trainer.snr_optimal import SnrOptimalMultiplexer, s_matrix_for_sites


def test_snr_optimal_uses_the_multiplexer_matrix_and_scores_each_prefix(tiny_data):
    model = SnrOptimalClassifier(n_iter=500, seed=2,
                                 scoring=SplitScoring(n_repeats=8)).fit(tiny_data)
    ref = SnrOptimalMultiplexer(n_sites=8, noise=(tiny_data.noise_a, tiny_data.noise_b),
                                n_iter=500, seed=2).fit(float(tiny_data.basis.mean(dtype=np.float64)))
    np.testing.assert_array_equal(model.patterns_, ref.W_)
    assert sorted(model.classifiers_) == list(range(1, 9))
    assert [c.n_images_ for c in model.classifiers_.values()] == [4 * k for k in range(1, 9)]
    # accuracy for k columns = the candidate score of column k given the first k - 1
    ev = CandidateEvaluator(tiny_data, n_repeats=8, seed=2)
    k = 3
    expected = ev.score(ev.prepare_column(model.patterns_[:, :k - 1]), model.patterns_[:, [k - 1]])
    assert model.accuracy_by_images_[k] == pytest.approx(expected.mean())
    assert model.best_n_patterns_ == max(model.accuracy_by_images_, key=lambda c: (model.accuracy_by_images_[c], -c))


def test_snr_optimal_without_noise_falls_back_to_the_s_matrix():
    from helpers.trainer import make_search_data
    quiet = make_search_data(noise_a=0.0, noise_b=0.0)
    model = SnrOptimalClassifier(n_images=3, scoring=SplitScoring(n_repeats=4)).fit(quiet)
    np.testing.assert_array_equal(model.patterns_, s_matrix_for_sites(8)[:, :3])
    assert model.multiplexer_ is None


def test_naive_is_one_image_with_every_led_on(tiny_data):
    model = NaiveClassifier(scoring=SplitScoring(n_repeats=6)).fit(tiny_data)
    assert model.patterns_.shape == (32, 1) and model.patterns_.min() == 1
    assert list(model.accuracy_by_images_) == [1]
    art = model.to_artifact()
    assert art.mode == 'naive' and art.n_images == [1]


def test_fixed_patterns_shape_is_checked(tiny_data):
    with pytest.raises(ValueError, match=r'per_colour patterns must be \(8, k >= 1\)'):
        FixedPatternClassifier(patterns=np.ones((5, 2))).fit(tiny_data)


def test_the_artifact_records_the_dimmer_the_training_rendered_with():
    from helpers.trainer import TINY_HOG, make_modelset
    ms = make_modelset(n_poses=8)
    model = NaiveClassifier(scoring=SplitScoring(n_repeats=4),
                            rendering=Rendering(dimmer=0.3, hog_config=TINY_HOG)).fit(ms)
    basis = model.evaluator_.data.basis  # (sites, channels, samples, pixels), dimmer applied
    np.testing.assert_allclose(basis[2, 1, 5], 0.3 * ms.models[5, 1, 2].ravel(), rtol=1e-6)
    art = model.to_artifact()
    assert art.dimmer == 0.3 and art.dimmer_recorded
