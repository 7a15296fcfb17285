"""Mean test accuracy of a classifier over many train/test splits of one feature set.

Two scorers with one interface, `split_accuracies(...) -> (n_splits,)`:

- `RidgeSplitScorer`: a one-vs-all least-squares (ridge) classifier with targets +-1 and a
  bias feature. All splits share one kernel `K = X X^T`: with `G = (K + 1 + alpha I)^-1` and
  `A = G Y` computed once, the held-out predictions of the model trained without the test
  samples S are exactly `Y_S - (G_SS)^-1 A_S` (block inversion of the kernel ridge system),
  so each split costs one small solve instead of a fit. The kernel can be grown column by
  column (`K_prev + X_new X_new^T`), which keeps a candidate's cost independent of how many
  images came before.
- `LinearSvcSplitScorer`: the paper's classifier, one `sklearn.svm.LinearSVC` fit per split.
  Slow (seconds per candidate); kept selectable and used to check that ridge ranks the
  candidates the same way (benchmarks/rank_agreement.py).
"""
from __future__ import annotations

import numpy as np
from sklearn.svm import LinearSVC


def _pm_one_targets(labels: np.ndarray, n_classes: int) -> np.ndarray:
    Y = -np.ones((labels.size, n_classes))
    Y[np.arange(labels.size), labels] = 1.0
    return Y


def _group_by_size(test_masks: list[np.ndarray]) -> dict[int, np.ndarray]:
    """Test masks -> {test size: (n_splits_of_that_size, size) index array, ...}."""
    groups: dict[int, list[np.ndarray]] = {}
    for mask in test_masks:
        idx = np.flatnonzero(mask)
        groups.setdefault(idx.size, []).append(idx)
    return {size: np.stack(rows) for size, rows in groups.items()}


class RidgeSplitScorer:
    """Kernel-shared ridge classifier over repeated splits.

    alpha: ridge penalty in the units of K (HOG descriptors have unit norm, so the diagonal
    of K is about the number of images).
    """

    needs_features = False

    def __init__(self, alpha: float = 0.1):
        if alpha <= 0:
            raise ValueError(f'alpha must be > 0, got {alpha}')
        self.alpha = alpha

    def split_accuracies(self, labels: np.ndarray, test_masks: list[np.ndarray], *,
                         K: np.ndarray | None = None, X: np.ndarray | None = None,
                         n_classes: int | None = None) -> np.ndarray:
        if K is None:
            if X is None:
                raise ValueError('give the kernel K or the features X')
            X = np.asarray(X, dtype=np.float64)
            K = X @ X.T
        labels = np.asarray(labels)
        n = labels.size
        n_classes = int(labels.max()) + 1 if n_classes is None else n_classes
        Y = _pm_one_targets(labels, n_classes)
        # the constant 1 is the kernel of a bias feature of value 1 (penalised like the rest)
        G = np.linalg.inv(np.asarray(K, dtype=np.float64) + 1.0 + self.alpha * np.eye(n))
        A = G @ Y
        acc = np.empty(len(test_masks))
        order = []
        results = []
        for size, T in _group_by_size(test_masks).items():
            G_SS = G[T[:, :, None], T[:, None, :]]
            resid = np.linalg.solve(G_SS, A[T])
            pred = np.argmax(Y[T] - resid, axis=2)
            results.append(np.mean(pred == labels[T], axis=1))
            order.append(size)
        # restore the split order
        sizes = np.array([int(m.sum()) for m in test_masks])
        for size, res in zip(order, results):
            acc[sizes == size] = res
        return acc


class LinearSvcSplitScorer:
    """One LinearSVC (one-vs-rest, squared hinge) fit per split: the paper's classifier."""

    needs_features = True

    def __init__(self, C: float = 1.0, max_iter: int = 5000):
        self.C = C
        self.max_iter = max_iter

    def split_accuracies(self, labels: np.ndarray, test_masks: list[np.ndarray], *,
                         K: np.ndarray | None = None, X: np.ndarray | None = None,
                         n_classes: int | None = None) -> np.ndarray:
        if X is None:
            raise ValueError('LinearSvcSplitScorer needs the features X')
        labels = np.asarray(labels)
        acc = np.empty(len(test_masks))
        for i, mask in enumerate(test_masks):
            clf = LinearSVC(C=self.C, max_iter=self.max_iter)
            clf.fit(X[~mask], labels[~mask])
            acc[i] = np.mean(clf.predict(X[mask]) == labels[mask])
        return acc


def make_scorer(name: str, **params):
    """'ridge' | 'linear_svm' -> a split scorer."""
    if name == 'ridge':
        return RidgeSplitScorer(**params)
    if name == 'linear_svm':
        return LinearSvcSplitScorer(**params)
    raise ValueError(f'unknown inner classifier {name!r}; use "ridge" or "linear_svm"')
