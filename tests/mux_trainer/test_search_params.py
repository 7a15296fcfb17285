"""The estimators' grouped parameters follow scikit-learn's conventions (search_params)."""
import dataclasses

import numpy as np
import pytest
from sklearn.base import clone

from mux_trainer.baselines import FixedPatternClassifier, NaiveClassifier, SnrOptimalClassifier
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.search_params import (Execution, FinalClassifier, Refinement, Rendering,
                                       SplitScoring)
from mux_trainer.training import build_model

ESTIMATORS = [GreedyPatternSelector, FixedPatternClassifier, SnrOptimalClassifier,
              NaiveClassifier]


@pytest.mark.parametrize('cls', ESTIMATORS)
def test_clone_copies_every_parameter_and_its_groups(cls):
    est = cls(scoring=SplitScoring(n_repeats=7, C=2.0),
              rendering=Rendering(noise='sigma1', dimmer=0.3),
              final_classifier=FinalClassifier('ridge', alpha=0.2),
              execution=Execution(n_jobs=2), seed=5)
    copy = clone(est)
    assert copy is not est and type(copy) is cls
    assert copy.get_params(deep=False) == est.get_params(deep=False)
    assert copy.scoring is not est.scoring and copy.scoring == SplitScoring(n_repeats=7, C=2.0)
    # stored as given: the very objects passed in
    assert est.rendering.dimmer == 0.3 and est.final_classifier.estimator == 'ridge'


@pytest.mark.parametrize('cls', ESTIMATORS)
def test_deep_params_name_the_groups_fields(cls):
    params = cls().get_params(deep=True)
    for key in ('scoring__n_repeats', 'scoring__classifier', 'rendering__noise',
                'rendering__features', 'final_classifier__C', 'execution__n_jobs'):
        assert key in params
    assert ('refinement__top' in params) == (cls is GreedyPatternSelector)
    assert params['scoring__n_repeats'] == 400 and params['scoring__classifier'] is None


def test_set_params_replaces_a_group_by_a_changed_copy():
    a, b = GreedyPatternSelector(), GreedyPatternSelector()
    default = a.scoring
    assert a.set_params(scoring__n_repeats=9, refinement__top=0, seed=3) is a
    assert a.scoring == SplitScoring(n_repeats=9) and a.refinement == Refinement(top=0)
    assert a.seed == 3
    # frozen groups: the default shared by every instance is never changed
    assert default == SplitScoring() and b.scoring is default
    # a whole group and a field of it together: the group first, then the field
    a.set_params(scoring=SplitScoring(n_repeats=5, C=4.0), scoring__C=0.5)
    assert a.scoring == SplitScoring(n_repeats=5, C=0.5)
    with pytest.raises(ValueError, match='no field'):
        a.set_params(scoring__repeats=3)
    with pytest.raises(ValueError, match='Invalid parameter'):
        a.set_params(scoring_n_repeats=3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.scoring.n_repeats = 2


def test_set_params_changes_what_fit_does(tiny_data):
    made = NaiveClassifier(scoring=SplitScoring(n_repeats=4), seed=1).fit(tiny_data)
    tuned = clone(NaiveClassifier(seed=1)).set_params(scoring__n_repeats=4).fit(tiny_data)
    assert tuned.split_accuracy_by_images_[1].shape == (4,)
    np.testing.assert_array_equal(tuned.split_accuracy_by_images_[1],
                                  made.split_accuracy_by_images_[1])
    np.testing.assert_array_equal(tuned.classifiers_[1].coef_, made.classifiers_[1].coef_)


def test_fit_checks_the_groups(tiny_data):
    with pytest.raises(TypeError, match='must be a SplitScoring'):
        GreedyPatternSelector(scoring={'n_repeats': 4}).fit(tiny_data)
    with pytest.raises(TypeError, match='must be a Rendering'):
        NaiveClassifier(rendering='sigma3').fit(tiny_data)
    with pytest.raises(ValueError, match='n_repeats must be >= 1'):
        NaiveClassifier(scoring=SplitScoring(n_repeats=0)).fit(tiny_data)
    with pytest.raises(ValueError, match=r'test_fraction must be in \(0, 1\)'):
        GreedyPatternSelector(scoring=SplitScoring(test_fraction=1.0)).fit(tiny_data)
    with pytest.raises(ValueError, match='chunk_size must be >= 1'):
        GreedyPatternSelector(execution=Execution(chunk_size=0)).fit(tiny_data)
    with pytest.raises(ValueError, match='refine_top must be >= 0'):
        GreedyPatternSelector(refinement=Refinement(top=-1)).fit(tiny_data)


def test_the_split_classifier_is_the_methods_own_unless_given():
    assert GreedyPatternSelector().split_classifier == 'ridge'
    assert NaiveClassifier().split_classifier == 'squared_hinge'
    assert SnrOptimalClassifier().split_classifier == 'squared_hinge'
    given = SplitScoring(classifier='linear_svm')
    assert GreedyPatternSelector(scoring=given).split_classifier == 'linear_svm'
    assert NaiveClassifier(scoring=given).split_classifier == 'linear_svm'


def test_build_model_maps_the_user_options_onto_the_groups():
    greedy = build_model('greedy', repeats=7, seed=4, n_jobs=2, refine_top=3, features='hog_grid',
                         final_classifier='ridge', progress=True, fixed_count=True, max_images=5)
    assert greedy.scoring == SplitScoring(n_repeats=7)
    assert greedy.refinement == Refinement(top=3)
    assert greedy.rendering == Rendering(noise='sigma3')
    assert greedy.final_classifier == FinalClassifier(estimator='ridge')
    assert greedy.execution == Execution(n_jobs=2, progress=True)
    assert (greedy.seed, greedy.n_patterns, greedy.max_patterns) == (4, 5, 5)
    assert build_model('greedy').refinement == Refinement()
    snr = build_model('snr_optimal', repeats=9, inner_classifier='ridge', max_images=3)
    assert snr.scoring == SplitScoring(n_repeats=9, classifier='ridge') and snr.n_images == 3
    assert build_model('naive').split_classifier == 'squared_hinge'
