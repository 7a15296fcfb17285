"""A linear head gated by object type (`gated_head`, docs/LEARNED.md): fitted per
type on that type's samples, its scores pick the best class of the best type."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mux_classifier.gated_head import (NO_SAMPLES_SCORE, check_class_groups, fit_gated_linear,
                                       gated_margins)

GROUPS = np.array([0, 0, 1, 1, 2])   # two pairs and a type of one class


def _hierarchical(outputs, groups):
    G = groups.max() + 1
    best_type = outputs[:, :G].argmax(axis=1)
    picked = []
    for row, g in zip(outputs, best_type):
        members = np.flatnonzero(groups == g)
        picked.append(members[row[G:][members].argmax()])
    return np.array(picked)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, (7, 3 + 5), elements=st.floats(-50, 50, width=32)))
def test_margins_pick_the_best_class_of_the_best_type(outputs):
    scores = gated_margins(outputs, GROUPS)
    G = 3
    type_tie = (np.sort(outputs[:, :G], axis=1)[:, -1] == np.sort(outputs[:, :G], axis=1)[:, -2])
    expected = _hierarchical(outputs, GROUPS)
    for n in range(len(outputs)):
        members = GROUPS == GROUPS[expected[n]]
        class_tie = (outputs[n, G:][members] == outputs[n, G + expected[n]]).sum() > 1
        if type_tie[n] or class_tie:   # no positive score on a tie
            assert (scores[n] <= 0).all()
            continue
        assert scores[n].argmax() == expected[n]
        assert scores[n, expected[n]] > 0 and (np.delete(scores[n], expected[n]) < 0).all()


def _two_types(rng, n=40):
    """Type 0 around feature 0 = 0, type 1 around 100; within each, the classes differ on
    feature 1 by a step that is small against the types' spread."""
    y = np.repeat([0, 1, 2, 3], n)
    X = rng.normal(0, 0.2, (y.size, 3))
    X[:, 0] += np.where(y >= 2, 100.0, 0.0)
    X[:, 1] += np.where(y % 2 == 1, 1.0, 0.0) + np.where(y >= 2, 50.0, 0.0)
    return X, y


def test_fitted_head_tells_types_and_their_classes_apart():
    rng = np.random.default_rng(0)
    X, y = _two_types(rng)
    groups = np.array([0, 0, 1, 1])
    coef, intercept = fit_gated_linear(X, y, groups)
    assert coef.shape == (2 + 4, 3) and intercept.shape == (6,)
    Xt, yt = _two_types(np.random.default_rng(1))
    pred = gated_margins(Xt @ coef.T + intercept, groups).argmax(axis=1)
    assert (pred == yt).mean() > 0.95
    # a class's row: its type's own SVM (z-scored on that type) plus the flat SVM's row
    from mux_classifier.estimator import fit_linear
    flat, flat_b, _ = fit_linear(X, y, 'linear_svm')
    own, own_b, _ = fit_linear(X[y >= 2], y[y >= 2], 'linear_svm')
    np.testing.assert_allclose(coef[2 + 2:], flat[2:] + own, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(intercept[2 + 2:], flat_b[2:] + own_b, rtol=1e-6, atol=1e-9)


def test_a_type_with_one_class_and_classes_without_samples():
    rng = np.random.default_rng(0)
    X, y = _two_types(rng)
    keep = y != 3                     # class 3 (type 1) has no training samples
    coef, intercept = fit_gated_linear(X[keep], y[keep], np.array([0, 0, 1, 1]))
    assert intercept[2 + 3] == NO_SAMPLES_SCORE and not coef[2 + 3].any()
    # alone in its type: the flat SVM's row only
    from mux_classifier.estimator import fit_linear
    flat_coef, flat_b, _ = fit_linear(X[keep], y[keep], 'linear_svm')
    np.testing.assert_allclose(coef[2 + 2], flat_coef[2])
    np.testing.assert_allclose(intercept[2 + 2], flat_b[2])
    only_type0 = y < 2
    coef, intercept = fit_gated_linear(X[only_type0], y[only_type0], np.array([0, 0, 1, 1]))
    assert intercept[0] == 0 and intercept[1] == NO_SAMPLES_SCORE   # one type: it is the answer
    scores = gated_margins(X @ coef.T + intercept, np.array([0, 0, 1, 1]))
    assert set(scores.argmax(axis=1)) <= {0, 1}


@pytest.mark.parametrize("groups, message", [
    ([], "non-empty"), ([[0, 1]], "1-D"), ([0.0, 1.0], "integer"), ([0, 2], "number the types"),
    ([-1, 0], "number the types"), ([0, 10 ** 15], "number the types")])
def test_bad_class_groups_are_refused(groups, message):
    with pytest.raises(ValueError, match=message):
        check_class_groups(np.asarray(groups))


def test_fit_refuses_labels_outside_the_classes():
    with pytest.raises(ValueError, match="class indices 0 .. 1"):
        fit_gated_linear(np.zeros((3, 2)), np.array([0, 1, 2]), np.array([0, 1]))


def test_scores_are_finite_even_for_a_type_and_class_alone():
    scores = gated_margins(np.array([[1.0, 2.0, 3.0]]), np.array([0, 0]))   # one type
    assert np.isfinite(scores).all() and scores.argmax() == 1
    alone = gated_margins(np.array([[1.0, 5.0]]), np.array([0]))         # one class
    assert np.isfinite(alone.astype(np.float32)).all()
