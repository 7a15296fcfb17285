import numpy as np
import pytest
from sklearn.svm import LinearSVC

from mux_trainer.reference import reference_split_accuracies
from mux_trainer.split_scoring import LinearSvcSplitScorer, RidgeSplitScorer, make_scorer
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
    with pytest.raises(ValueError, match='needs the features'):
        LinearSvcSplitScorer().split_accuracies(np.zeros(3, int), [], K=np.eye(3))
