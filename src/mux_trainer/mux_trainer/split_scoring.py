"""Mean test accuracy of a classifier over many train/test splits of one feature set.

Three scorers with one interface, `split_accuracies(...) -> (n_splits,)`:

- `RidgeSplitScorer`: a one-vs-all least-squares (ridge) classifier with targets +-1 and a
  bias feature. All splits share one kernel `K = X X^T`: with `G = (K + 1 + alpha I)^-1` and
  `A = G Y` computed once, the held-out predictions of the model trained without the test
  samples S are exactly `Y_S - (G_SS)^-1 A_S` (block inversion of the kernel ridge system),
  so each split costs one small solve instead of a fit. The kernel can be grown column by
  column (`K_prev + X_new X_new^T`), which keeps a candidate's cost independent of how many
  images came before.
- `SquaredHingeSplitScorer`: the paper's classifier, exactly: LinearSVC's problem (one-vs-rest,
  L2-regularised squared hinge, a penalised bias feature of value 1) solved to optimality in
  kernel form by the finite Newton method of Keerthi & DeCoste (2005) / Chapelle (2007): each
  Newton step is a ridge solve restricted to the margin violators, batched over splits and
  classes. It predicts what LinearSVC predicts (tested split by split, and its w and bias
  agree to 1e-5) for a fraction of LinearSVC's time (benchmarks/bench_search.py).
- `LinearSvcSplitScorer`: one `sklearn.svm.LinearSVC` fit per split (liblinear). Slowest; the
  reference the others are checked against.
"""
from __future__ import annotations

import math

import numba
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
    of K is about the number of images). The default 0.5 = 1 / (2 C) for LinearSVC's C = 1
    makes this ridge the first Newton iterate of `SquaredHingeSplitScorer` (every sample a
    margin violator), and it ranked candidates most like the SVM on our data
    (benchmarks/rank_agreement.py).
    """

    needs_features = False

    def __init__(self, alpha: float = 0.5):
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


class SquaredHingeSplitScorer:
    """Exact one-vs-rest squared-hinge linear SVM (LinearSVC's problem) over repeated splits.

    LinearSVC minimises `0.5 |w|^2 + C sum_i max(0, 1 - y_i w.x_i)^2` per class, with a
    penalised bias feature of value 1. In kernel form, w = sum_i a_i x_i for a split's training
    kernel `Kt` (bias included) and one class's +-1 targets `y`; divided by C the problem is
    `lam a'Kt a + sum_i max(0, 1 - y_i (Kt a)_i)^2` with `lam = 1 / (2 C)`. At the optimum
    a_i = 2 C y_i max(0, 1 - y_i (Kt a)_i) (the signed dual variables).

    Finite Newton method (Keerthi & DeCoste 2005; Chapelle 2007): with V the current margin
    violators (y_i (Kt a)_i < 1) and N the rest, the Newton target solves
    `(Kt_VV + lam I) a_V = y_V`, a_N = 0, and an exact line search toward it keeps the
    objective decreasing. It stops when a full step leaves the violators unchanged (the
    optimum; usually 4-6 steps) or the gradient vanishes. The start is the ridge solution
    (every sample a violator). Each (split, class) target costs one solve over the smaller of
    V and N: directly over V, or over N through the split's ridge inverse
    `H = (Kt + lam I)^-1` as `a = H r` with r = y on V and `H_NN r_N = -(H r)_N` on N.
    Problems are batched by the size of that solve.

    A class absent from a split's training set gets all -1 targets (it can still win the
    argmax, as with ridge; LinearSVC would never predict it). Pose splits keep every class.

    C : as LinearSVC's. tol : gradient tolerance relative to the conditioning bound
    `1 + |Kt|_inf / lam`. max_iter : Newton steps before a ConvergenceWarning (the current
    solution is then used, as LinearSVC does). split_block : splits solved together (memory
    is ~5 x split_block x m^2 floats for m training samples).
    """

    needs_features = False

    def __init__(self, C: float = 1.0, tol: float = 1e-12, max_iter: int = 50,
                 split_block: int = 100):
        if C <= 0:
            raise ValueError(f'C must be > 0, got {C}')
        self.C = C
        self.tol = tol
        self.max_iter = max_iter
        self.split_block = split_block

    def split_accuracies(self, labels: np.ndarray, test_masks: list[np.ndarray], *,
                         K: np.ndarray | None = None, X: np.ndarray | None = None,
                         n_classes: int | None = None) -> np.ndarray:
        if K is None:
            if X is None:
                raise ValueError('give the kernel K or the features X')
            X = np.asarray(X, dtype=np.float64)
            K = X @ X.T
        labels = np.asarray(labels)
        n_classes = int(labels.max()) + 1 if n_classes is None else n_classes
        Y = _pm_one_targets(labels, n_classes)
        Kb = np.asarray(K, dtype=np.float64) + 1.0  # bias feature of value 1 (intercept_scaling)
        n = labels.size
        lam = 1.0 / (2.0 * self.C)
        G = np.linalg.inv(Kb + lam * np.eye(n))
        # warm start: each split's problem begins at the solution for the margin violators
        # of the SVM trained on all samples (most splits keep most of them), so it usually
        # needs one or two Newton steps instead of four to six from the ridge solution
        a_all = self.fit_kernels(Kb[None], Y[None], H=G[None])[0]
        start = Y * (Kb @ a_all) < 1
        acc = np.empty(len(test_masks))
        sizes = np.array([int(np.sum(m)) for m in test_masks])
        for size, T_all in _group_by_size(test_masks).items():
            group_acc = []
            for b in range(0, T_all.shape[0], self.split_block):
                T = T_all[b:b + self.split_block]
                keep = np.ones((T.shape[0], n), dtype=bool)
                keep[np.arange(T.shape[0])[:, None], T] = False
                train = np.nonzero(keep)[1].reshape(T.shape[0], n - size)
                # each split's (Kt + lam I)^-1 from the inverse over all samples: the inverse of
                # a principal block is G_TT - G_TS G_SS^-1 G_ST (a small solve over the test set)
                G_TS = G[train[:, :, None], T[:, None, :]]
                H = G[train[:, :, None], train[:, None, :]] - G_TS @ np.linalg.solve(
                    G[T[:, :, None], T[:, None, :]], G_TS.transpose(0, 2, 1))
                a = self.fit_kernels(Kb[train[:, :, None], train[:, None, :]], Y[train], H=H,
                                     start=start[train])
                scores = Kb[T[:, :, None], train[:, None, :]] @ a   # (splits, test, classes)
                group_acc.append(np.mean(np.argmax(scores, axis=2) == labels[T], axis=1))
            acc[sizes == size] = np.concatenate(group_acc)
        return acc

    def fit_kernels(self, Kt: np.ndarray, Y: np.ndarray, H: np.ndarray | None = None,
                    start: np.ndarray | None = None) -> np.ndarray:
        """Coefficients a (S, m, c) for training kernels Kt (S, m, m), +-1 targets Y (S, m, c);
        H: (Kt + lam I)^-1 if already known. start: None to start from the ridge solution
        (every sample a violator), or a guess (S, m, c) of the margin violators at the
        optimum to start from their restricted ridge solution (any start converges to the
        same optimum; a good guess saves Newton steps)."""
        lam = 1.0 / (2.0 * self.C)
        m = Kt.shape[1]
        if H is None:
            H = np.linalg.inv(Kt + lam * np.eye(m))
        if start is None:
            solved_for = np.ones(Y.shape, dtype=bool)      # violators of the last full step
            a = H @ Y                                      # ridge: every sample a violator
        else:
            solved_for = np.asarray(start, dtype=bool)
            a = self._newton_targets(Kt, H, Y, solved_for,
                                     np.ones((Y.shape[0], Y.shape[2]), dtype=bool), lam)
        out = Kt @ a
        tol = self.tol * (1.0 + np.abs(Kt).sum(axis=2).max(axis=1) / lam)[:, None]   # (S, 1)
        stalled = np.zeros((Y.shape[0], Y.shape[2]), dtype=bool)
        for _ in range(self.max_iter):
            viol = Y * out < 1
            grad = lam * a + np.where(viol, out - Y, 0.0)
            todo = ((np.abs(grad).max(axis=1) > tol)
                    & ~np.all(viol == solved_for, axis=1) & ~stalled)      # (S, c)
            if not todo.any():
                return a
            target = self._newton_targets(Kt, H, Y, viol, todo, lam)
            d = np.where(todo[:, None, :], target - a, 0.0)
            Kd = Kt @ d
            t = self._line_search(a, d, out, Kd, Y, lam)
            # a Newton direction that does not descend means rounding dominates (an
            # ill-conditioned kernel at a large C): the iterate is as good as it gets
            stalled |= todo & (t == 0)
            t = t[:, None, :]
            a += t * d
            out += t * Kd
            solved_for = np.where(t == 1.0, viol, ~viol)   # after a partial step: none known
        import warnings
        from sklearn.exceptions import ConvergenceWarning
        warnings.warn(f'squared-hinge SVM: {int(todo.sum())} of {todo.size} problems not '
                      f'converged after {self.max_iter} Newton steps; using the last iterate '
                      '(raise max_iter, or lower C)', ConvergenceWarning, stacklevel=3)
        return a

    @staticmethod
    def _newton_targets(Kt, H, Y, viol, todo, lam) -> np.ndarray:
        """Each todo problem's restricted ridge solution (a_V solves (Kt_VV + lam I) a_V =
        y_V, a_N = 0), computed over the smaller of V and N (compiled: `_targets_kernel`)."""
        target = np.zeros(Y.shape)
        _targets_kernel(np.ascontiguousarray(Kt, dtype=np.float64),
                        np.ascontiguousarray(H, dtype=np.float64),
                        np.ascontiguousarray(Y, dtype=np.float64),
                        np.ascontiguousarray(viol, dtype=np.bool_),
                        np.ascontiguousarray(todo, dtype=np.bool_), float(lam), target)
        return target

    @staticmethod
    def _line_search(a, d, out, Kd, Y, lam, bisections: int = 30) -> np.ndarray:
        """The step t in (0, 1] minimising the objective along d, per problem (S, c).

        The objective is convex and piecewise quadratic in t, so its slope is increasing: a
        full step is taken where the slope is still <= 0 at t = 1, the rest are bisected; 0
        where d does not descend at all.
        """
        def rows(x):                                       # (S, m, c) -> (S * c, m)
            return x.transpose(0, 2, 1).reshape(-1, x.shape[1])

        a1 = np.sum(a * Kd, axis=1).ravel()               # a'Kd, per problem
        a2 = np.sum(d * Kd, axis=1).ravel()               # d'Kd
        margin, yq = rows(1.0 - Y * out), rows(Y * Kd)

        def slope(t, p):                                   # half the objective's slope at t
            return lam * (a1[p] + t * a2[p]) - np.sum(
                np.maximum(margin[p] - t[:, None] * yq[p], 0.0) * yq[p], axis=1)

        t = np.ones(a1.size)
        p = np.flatnonzero(slope(t, slice(None)) > 0)
        if p.size:
            lo, hi = np.zeros(p.size), np.ones(p.size)
            for _ in range(bisections):
                mid = 0.5 * (lo + hi)
                up = slope(mid, p) > 0
                hi = np.where(up, mid, hi)
                lo = np.where(up, lo, mid)
            ascent = slope(np.zeros(p.size), p) >= 0         # not a descent direction: t = 0
            t[p] = np.where(ascent, 0.0, 0.5 * (lo + hi))
        return t.reshape(a.shape[0], a.shape[2])


@numba.njit(cache=True, nogil=True)
def _cholesky_solve(A, b, k):
    """Solve A x = b for the symmetric positive definite A[:k, :k] (upper triangle used,
    overwritten by its Cholesky factor U, A = U'U); b[:k] becomes x. Row-oriented updates
    (contiguous, vectorizable without reordering any sum: the same bits on every CPU)."""
    for j in range(k):
        d = math.sqrt(A[j, j])
        for i in range(j, k):
            A[j, i] /= d
        for p in range(j + 1, k):
            f = A[j, p]
            for i in range(p, k):
                A[p, i] -= f * A[j, i]
    for j in range(k):                       # U' z = b
        b[j] /= A[j, j]
        z = b[j]
        for i in range(j + 1, k):
            b[i] -= A[j, i] * z
    for j in range(k - 1, -1, -1):           # U x = z
        acc = b[j]
        for i in range(j + 1, k):
            acc -= A[j, i] * b[i]
        b[j] = acc / A[j, j]


@numba.njit(cache=True, nogil=True)
def _targets_kernel(Kt, H, Y, viol, todo, lam, target):
    """`SquaredHingeSplitScorer._newton_targets` for every todo (split, class) problem, one at
    a time: gather the smaller of the violator / non-violator blocks, solve it by Cholesky.
    Over N: r = y on V, 0 on N; r_N = -H_NN^-1 (H r)_N; target = H r (H symmetric, so H r is
    a sum of rows of H). Over V: target_V = (Kt_VV + lam I)^-1 y_V, target_N = 0."""
    S, m, c = Y.shape
    A = np.empty((m, m))
    idx = np.empty(m, dtype=np.int64)
    rhs = np.empty(m)
    r = np.empty(m)
    acc = np.empty(m)
    for s in range(S):
        Hs = H[s]
        for q in range(c):
            if not todo[s, q]:
                continue
            n_viol = 0
            for i in range(m):
                n_viol += viol[s, i, q]
            k = 0
            if n_viol >= m - n_viol:
                for i in range(m):
                    if viol[s, i, q]:
                        r[i] = Y[s, i, q]
                    else:
                        r[i] = 0.0
                        idx[k] = i
                        k += 1
                acc[:] = 0.0
                for j in range(m):
                    if r[j] != 0.0:
                        rj = r[j]
                        for i in range(m):
                            acc[i] += rj * Hs[j, i]
                if k:
                    for a in range(k):
                        rhs[a] = -acc[idx[a]]
                        for b in range(a, k):
                            A[a, b] = Hs[idx[a], idx[b]]
                    _cholesky_solve(A, rhs, k)
                    for a in range(k):
                        ra = rhs[a]
                        row = idx[a]
                        for i in range(m):
                            acc[i] += ra * Hs[row, i]
                for i in range(m):
                    target[s, i, q] = acc[i]
            else:
                for i in range(m):
                    target[s, i, q] = 0.0
                    if viol[s, i, q]:
                        idx[k] = i
                        k += 1
                for a in range(k):
                    rhs[a] = Y[s, idx[a], q]
                    for b in range(a, k):
                        A[a, b] = Kt[s, idx[a], idx[b]]
                    A[a, a] += lam
                _cholesky_solve(A, rhs, k)
                for a in range(k):
                    target[s, idx[a], q] = rhs[a]


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


SCORERS = {'ridge': RidgeSplitScorer, 'squared_hinge': SquaredHingeSplitScorer,
           'linear_svm': LinearSvcSplitScorer}


def make_scorer(name: str, **params):
    """'ridge' | 'squared_hinge' | 'linear_svm' -> a split scorer."""
    if name not in SCORERS:
        raise ValueError(f'unknown inner classifier {name!r}; use one of {sorted(SCORERS)}')
    return SCORERS[name](**params)
