"""The column-count rules (mux_trainer.column_count)."""
import numpy as np
import pytest
from mux_trainer.column_count import choose_column_count, split_standard_error


def _splits(rng, mean, std, n=400):
    return np.clip(rng.normal(mean, std, n), 0, 1)


def test_max_keeps_the_best_mean_and_the_fewest_columns_on_a_tie():
    acc = {1: 0.70, 2: 0.80, 3: 0.80, 4: 0.79}
    assert choose_column_count(acc, rule='max') == 2


def test_one_se_keeps_fewer_columns_when_the_best_is_within_noise_of_them():
    rng = np.random.default_rng(0)
    # split spread 0.10 with 1/4 held out: standard error 0.10 / 2 = 0.05
    acc = {1: 0.60, 2: 0.78, 3: 0.81, 4: 0.82}
    splits = {k: _splits(rng, v, 0.10) for k, v in acc.items()}
    acc = {k: float(v.mean()) for k, v in splits.items()}
    se = split_standard_error(splits[4], 0.25)
    assert 0.04 < se < 0.06
    assert choose_column_count(acc, splits, rule='max') == 4
    assert choose_column_count(acc, splits, rule='one_se') == 2


def test_one_se_keeps_the_best_when_it_is_clearly_better():
    rng = np.random.default_rng(1)
    splits = {1: _splits(rng, 0.6, 0.02), 2: _splits(rng, 0.7, 0.02), 3: _splits(rng, 0.9, 0.02)}
    acc = {k: float(v.mean()) for k, v in splits.items()}
    assert choose_column_count(acc, splits, rule='one_se') == 3


def test_the_standard_error_counts_disjoint_test_sets_not_overlapping_splits():
    # 400 overlapping splits must not claim a standard error 10x smaller than 4 folds do
    a = np.random.default_rng(2).normal(0.8, 0.08, 400)
    assert split_standard_error(a, 0.25) == pytest.approx(a.std(ddof=1) / 2)
    assert split_standard_error(a, 0.5) > split_standard_error(a, 0.25)


def test_an_unknown_rule_is_refused_by_name():
    with pytest.raises(ValueError, match="unknown column-count rule 'median'.*max, one_se"):
        choose_column_count({1: 0.5}, rule='median')
