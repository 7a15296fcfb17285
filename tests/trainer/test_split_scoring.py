import numpy as np
import pytest
from sklearn.svm import LinearSVC

from mux_trainer.reference import reference_split_accuracies
from mux_trainer.split_scoring import (LinearSvcSplitScorer, RidgeSplitScorer,
                                       SquaredHingeSplitScorer, make_scorer)
from mux_trainer.splits import pose_splits


def _problem(seed=0):
    rng = np.random.default_rng(seed)
    y = np.repeat(np.arange(4), 12)
    X = rng.normal(size=(y.size, 40))
    X[:, :4] += 2.0 * np.eye(4)[y]
    pose = np.tile(np.arange(12), 4)
    return X, y, pose_splits(pose, 25, 0.25, rng=seed)


def test_shared_kernel_ridge_equals_a_ridge_fit_per_split():
    X, y, masks = _problem()
    fast = RidgeSplitScorer(alpha=0.3).split_accuracies(y, masks, K=X @ X.T)
    slow = reference_split_accuracies(X, y, masks, classifier='ridge', alpha=0.3)
    np.testing.assert_array_equal(fast, slow)
    assert 0.3 < fast.mean() < 1.0  # a problem where the classifier matters


def test_ridge_handles_unequal_test_sizes_in_split_order():
    X, y, masks = _problem(1)
    masks = list(masks)
    masks[3] = masks[3].copy()
    masks[3][np.flatnonzero(~masks[3])[:2]] = True  # one split with a larger test set
    fast = RidgeSplitScorer(alpha=0.3).split_accuracies(y, masks, X=X)
    slow = reference_split_accuracies(X, y, masks, classifier='ridge', alpha=0.3)
    np.testing.assert_array_equal(fast, slow)


def test_linear_svc_scorer_fits_one_svm_per_split():
    X, y, masks = _problem(2)
    acc = LinearSvcSplitScorer(C=1.0).split_accuracies(y, masks[:3], X=X)
    for a, m in zip(acc, masks[:3]):
        clf = LinearSVC(C=1.0, max_iter=5000).fit(X[~m], y[~m])
        assert a == np.mean(clf.predict(X[m]) == y[m])


def test_scorer_errors():
    with pytest.raises(ValueError, match='unknown inner classifier'):
        make_scorer('knn')
    with pytest.raises(ValueError, match='alpha'):
        RidgeSplitScorer(alpha=0)
    with pytest.raises(ValueError, match='C must be'):
        SquaredHingeSplitScorer(C=0)
    with pytest.raises(ValueError, match='needs the features'):
        LinearSvcSplitScorer().split_accuracies(np.zeros(3, int), [], K=np.eye(3))


@pytest.mark.parametrize('C', [0.1, 1.0, 10.0])
def test_squared_hinge_predicts_what_linear_svc_predicts_split_by_split(C):
    X, y, masks = _problem(3)
    fast = SquaredHingeSplitScorer(C=C).split_accuracies(y, masks, K=X @ X.T)
    for a, m in zip(fast, masks):
        # liblinear run to a tight tolerance: the same optimum
        clf = LinearSVC(C=C, tol=1e-8, max_iter=200000).fit(X[~m], y[~m])
        assert a == np.mean(clf.predict(X[m]) == y[m])
    assert 0.3 < fast.mean() < 1.0


def test_squared_hinge_reaches_linear_svc_decision_values():
    """Not only the same predictions: the same classifier (w and bias) as liblinear."""
    X, y, masks = _problem(4)
    m = masks[0]
    scorer = SquaredHingeSplitScorer(C=1.0)
    Xa = np.hstack([X, np.ones((y.size, 1))])   # the bias feature liblinear appends
    train = np.flatnonzero(~m)
    Kt = (Xa[train] @ Xa[train].T)[None]
    Y = -np.ones((1, train.size, 4))
    Y[0, np.arange(train.size), y[train]] = 1
    beta = scorer.fit_kernels(Kt, Y)[0]
    w = Xa[train].T @ beta                       # (features + 1, classes)
    clf = LinearSVC(C=1.0, tol=1e-10, max_iter=500000).fit(X[train], y[train])
    np.testing.assert_allclose(w[:-1].T, clf.coef_, atol=1e-5)
    np.testing.assert_allclose(w[-1], clf.intercept_, atol=1e-5)


def test_squared_hinge_handles_unequal_test_sizes_in_split_order():
    X, y, masks = _problem(5)
    masks = list(masks)
    masks[2] = masks[2].copy()
    masks[2][np.flatnonzero(~masks[2])[:3]] = True
    fast = SquaredHingeSplitScorer().split_accuracies(y, masks, X=X)
    for a, m in zip(fast, masks):
        clf = LinearSVC(C=1.0, tol=1e-8, max_iter=200000).fit(X[~m], y[~m])
        assert a == np.mean(clf.predict(X[m]) == y[m])


def test_squared_hinge_terminates_on_an_ill_conditioned_kernel():
    """Few features (a rank-deficient kernel) and a large C: the finite termination (a full
    step that leaves the margin violators unchanged) or, where rounding leaves no descent
    direction, the stall check ends it; no warning, no spinning to max_iter."""
    rng = np.random.default_rng(6)
    y = np.repeat(np.arange(4), 10)
    X = rng.normal(size=(y.size, 3)) + np.eye(4)[y][:, :3]
    masks = pose_splits(np.tile(np.arange(10), 4), 6, 0.25, rng=0)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        acc = SquaredHingeSplitScorer(C=1e4).split_accuracies(y, masks, X=X)
    assert np.all((acc >= 0) & (acc <= 1))


def test_squared_hinge_warns_and_keeps_the_last_iterate_when_out_of_steps():
    from sklearn.exceptions import ConvergenceWarning
    X, y, masks = _problem(7)
    with pytest.warns(ConvergenceWarning, match='not converged after 1 Newton steps'):
        acc = SquaredHingeSplitScorer(max_iter=1).split_accuracies(y, masks[:4], X=X)
    assert acc.shape == (4,)
