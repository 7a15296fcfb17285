"""The optimism of choosing the best candidate on the inner splits (`selection_bias`), and
the greedy search's inner estimate corrected for it."""
import numpy as np
import pytest

from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.search_params import SplitScoring
from mux_trainer.selection_bias import NESTED_SCALE, group_means, selection_optimism, split_groups
from mux_trainer.splits import describe_inner

from test_inner_groups import memorisable_data


def test_splits_holding_out_the_same_samples_form_one_group():
    a = np.array([True, False, False])
    b = np.array([False, True, False])
    assert split_groups([a, b, a.copy(), b, np.array([False, False, True])]).tolist() \
        == [0, 1, 0, 1, 2]


def test_optimism_is_the_chosen_mean_less_the_choice_made_without_each_group():
    # 3 candidates x 6 splits in 3 groups (splits g and g + 3)
    means = np.array([[0.9, 0.8, 0.7],     # mean 0.8 (chosen)
                      [0.6, 1.0, 0.5],     # mean 0.7
                      [1.0, 0.4, 0.9]])    # mean 0.77
    acc = np.hstack([means, means])
    groups = np.array([0, 1, 2, 0, 1, 2])
    np.testing.assert_allclose(group_means(acc, groups), means)
    # without group 0: candidate 0 (0.75) beats 1 (0.75: a tie, shared) and 2 (0.65):
    # group 0 scores (0.9 + 0.6) / 2; without group 1: candidate 2 (0.95): 0.4;
    # without group 2: candidate 0 (0.85): 0.7
    nested = np.mean([(0.9 + 0.6) / 2, 0.4, 0.7])
    assert selection_optimism(acc, 0, groups, scale=1.0) == pytest.approx(0.8 - nested)
    # by default scaled: the nested choice sees only part of the optimism
    assert selection_optimism(acc, 0, groups) == pytest.approx(NESTED_SCALE * (0.8 - nested))
    assert NESTED_SCALE > 1


def test_no_optimism_where_nothing_was_chosen_between_or_nothing_to_measure_it_on():
    acc = np.array([[0.9, 0.8], [0.5, 0.6]])
    assert selection_optimism(acc, 0, np.array([0, 1])) == 0.0          # best everywhere
    assert selection_optimism(acc[:1], 0, np.array([0, 1])) == 0.0      # one candidate
    assert selection_optimism(acc, 1, np.array([0, 0])) == 0.0          # one group
    with pytest.raises(ValueError, match='candidates'):
        selection_optimism(acc, 0, np.array([0, 1, 2]))


def test_greedy_reports_its_split_accuracy_less_the_optimism_of_each_column_so_far():
    """No class cue, every physical sample its own texture: the best of 254 site patterns
    over all held-out groups is not the one chosen without each group, so the search has
    an optimism, and its inner estimate is its split accuracy less it, column by column."""
    data = memorisable_data(n_samples=4, seed=1)
    greedy = GreedyPatternSelector(mode='per_colour', n_patterns=2,
                                   scoring=SplitScoring(n_repeats=16)).fit(data)
    per_column = [record['optimism'] for record in greedy.history_]
    assert max(per_column) > 0
    assert [greedy.optimism_by_images_[k] for k in (1, 2)] == per_column
    for k in (1, 2):
        assert greedy.estimate_by_images_[k] == pytest.approx(
            greedy.accuracy_by_images_[k] - greedy.optimism_by_images_[k])
    inner = greedy.inner_estimate_
    k = greedy.best_n_patterns_
    assert inner['held_out'] == 'physical samples'
    assert inner['accuracy'] == pytest.approx(greedy.estimate_by_images_[k])
    assert inner['search_accuracy'] == greedy.accuracy_by_images_[k]
    assert inner['selection_optimism'] == pytest.approx(greedy.optimism_by_images_[k])
    k = max(greedy.optimism_by_images_, key=greedy.optimism_by_images_.get)
    inner = inner | {'search_accuracy': greedy.accuracy_by_images_[k],
                     'selection_optimism': greedy.optimism_by_images_[k]}
    words = describe_inner(inner, greedy.estimate_by_images_[k])
    assert (f'split accuracy {100 * greedy.accuracy_by_images_[k]:.1f} % less '
            f'{100 * greedy.optimism_by_images_[k]:.1f} points for having chosen') in words
    better = describe_inner(inner | {'selection_optimism': -0.012}, 0.9)
    assert 'plus 1.2 points for having chosen the light' in better
    assert 'objects never seen in training' in words
