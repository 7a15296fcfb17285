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


def test_squared_hinge_decisions_are_linear_svcs_split_by_split_and_give_its_accuracies():
    X, y, masks = _problem(8)
    masks = list(masks[:6])
    masks[2] = masks[2].copy()
    masks[2][np.flatnonzero(~masks[2])[:3]] = True   # unequal test sizes, in split order
    scorer = SquaredHingeSplitScorer()
    decisions = scorer.split_decisions(y, masks, X=X)
    assert len(decisions) == len(masks)
    for (test, scores), m in zip(decisions, masks):
        np.testing.assert_array_equal(test, np.flatnonzero(m))
        clf = LinearSVC(C=1.0, tol=1e-10, max_iter=500000).fit(X[~m], y[~m])
        np.testing.assert_allclose(scores, clf.decision_function(X[m]), atol=1e-4)
    np.testing.assert_array_equal(
        [np.mean(np.argmax(s, axis=1) == y[t]) for t, s in decisions],
        scorer.split_accuracies(y, masks, X=X))


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
    scorer = SquaredHingeSplitScorer(max_iter=1)
    with pytest.warns(ConvergenceWarning, match='not converged after 1 Newton steps') as caught:
        acc = scorer.split_accuracies(y, masks[:4], X=X)
    assert acc.shape == (4,)
    with pytest.warns(ConvergenceWarning) as caught_decisions:
        scorer.split_decisions(y, masks[:4], X=X)
    m = masks[0]
    train = np.flatnonzero(~m)
    Y = -np.ones((1, train.size, 4))
    Y[0, np.arange(train.size), y[train]] = 1
    with pytest.warns(ConvergenceWarning) as caught_kernels:
        scorer.fit_kernels((X[train] @ X[train].T + 1.0)[None], Y)
    # the warning points at the caller's line, not inside the scorer
    assert {w.filename for w in [*caught, *caught_decisions, *caught_kernels]} == {__file__}


def _recorded_problem(seed):
    """10 classes x 20 poses, 300 features: the search's shape (200 samples, 400 splits of
    25 % of the poses), at accuracies like the search's."""
    rng = np.random.default_rng(seed)
    y = np.repeat(np.arange(10), 20)
    X = rng.normal(size=(y.size, 300))
    X[:, :10] += 5.0 * np.eye(10)[y]
    return X, y, pose_splits(np.tile(np.arange(20), 10), 40, 0.25, rng=seed)


# recorded from the implementation before the Newton loop moved into one compiled kernel
# (per-step batched numpy with a fresh Cholesky solve per step): correct test predictions
# (of 50) of the first 40 splits, and the decision values of the first three test samples of
# split 0 (classifier trained on its 150 training samples from the ridge start)
RECORDED_SQUARED_HINGE = {
    11: ([45, 47, 45, 46, 44, 42, 42, 46, 38, 47, 40, 40, 47, 44, 45, 46, 44, 43, 43, 43, 46, 44, 43, 44, 43, 46, 46, 49, 46, 45, 43, 43, 46, 45, 42, 45, 44, 48, 44, 44],
         [[0.8589894594, -0.9837841337, -0.4943647122, -0.3904344944, -0.7344430662, -0.2746928785, -0.6872013141, -0.8940414711, -0.1293784143, -0.459547764], [0.243458966, -1.1991018095, -1.4370163012, -0.7385771038, -0.9727167087, -1.3005683802, -1.4727416027, -1.2348418946, -1.6169098468, -0.9548143013], [1.0896510431, 0.4076824904, -1.0540778855, 0.4094635899, -0.4539257613, 0.2857327939, 0.1174274848, 0.1814088273, -0.6242826085, 0.1443233706]]),
    12: ([48, 46, 48, 41, 47, 44, 44, 41, 46, 47, 48, 43, 47, 48, 46, 43, 44, 46, 44, 42, 47, 45, 45, 46, 45, 43, 46, 43, 42, 45, 44, 42, 45, 44, 45, 45, 46, 48, 45, 44],
         [[0.8569652167, -1.5813601605, -1.1396767189, 0.1907321311, -0.5831643015, -0.7014564918, -0.6310414189, -0.8465893287, -0.5718001127, -0.6091120528], [0.1311098433, -0.366077412, -1.0689706332, -1.0192973185, -0.9944135565, -0.5775776662, -1.5340455567, -0.7651635019, -0.6308425354, -0.7782939848], [1.1795498932, -0.5670029198, -0.6647440435, -0.6759257645, 0.2834430795, -0.4405364193, -0.7792009353, -0.095033562, 0.2636670949, -0.1153582947]]),
}


@pytest.mark.parametrize('seed', sorted(RECORDED_SQUARED_HINGE))
def test_squared_hinge_gives_the_recorded_accuracies_and_decision_values(seed):
    X, y, masks = _recorded_problem(seed)
    correct, decision = RECORDED_SQUARED_HINGE[seed]
    K = X @ X.T
    acc = SquaredHingeSplitScorer().split_accuracies(y, masks, K=K)
    np.testing.assert_array_equal(np.round(acc * 50).astype(int), correct)
    m = masks[0]
    train, test = np.flatnonzero(~m), np.flatnonzero(m)[:3]
    Kb = K + 1.0
    Y = -np.ones((1, train.size, 10))
    Y[0, np.arange(train.size), y[train]] = 1
    a = SquaredHingeSplitScorer().fit_kernels(Kb[np.ix_(train, train)][None], Y)[0]
    # the same optimum by another path: rounding (~1e-12 here) times the conditioning
    np.testing.assert_allclose(Kb[np.ix_(test, train)] @ a, decision, rtol=0, atol=1e-8)
