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
    optimum) or the gradient vanishes. Whatever the path, the result is the restricted solution
    of the final violator set, so the path only decides the cost.

    The whole Newton loop of one (split, class) problem runs in one compiled kernel
    (`_newton_kernel`, numba). The Cholesky factor of `Kt_VV + lam I` is kept between steps:
    V is factored in a fixed order of the samples (most violating first, from the SVM trained
    on all samples), so the samples that enter or leave V between steps, which sit near the
    margin, are mostly at the end of the factor; the leading rows up to the first sample that
    left are kept (a leading block's factor is the leading part of the factor) and only the
    rest is appended, row by row. Each split starts from the violators of the SVM trained on
    all samples (most splits keep most of them).

    A class absent from a split's training set gets all -1 targets (it can still win the
    argmax, as with ridge; LinearSVC would never predict it). Pose splits keep every class.

    C : as LinearSVC's. tol : gradient tolerance relative to the conditioning bound
    `1 + |Kt|_inf / lam`. max_iter : Newton steps before a ConvergenceWarning (the current
    solution is then used, as LinearSVC does).
    """

    needs_features = False

    def __init__(self, C: float = 1.0, tol: float = 1e-12, max_iter: int = 50):
        if C <= 0:
            raise ValueError(f'C must be > 0, got {C}')
        self.C = C
        self.tol = tol
        self.max_iter = max_iter

    def split_accuracies(self, labels: np.ndarray, test_masks: list[np.ndarray], *,
                         K: np.ndarray | None = None, X: np.ndarray | None = None,
                         n_classes: int | None = None) -> np.ndarray:
        labels = np.asarray(labels)
        acc = np.empty(len(test_masks))
        for where, T, scores in self._split_scores(labels, test_masks, K, X, n_classes):
            acc[where] = np.mean(np.argmax(scores, axis=2) == labels[T], axis=1)
        return acc

    def split_decisions(self, labels: np.ndarray, test_masks: list[np.ndarray], *,
                        K: np.ndarray | None = None, X: np.ndarray | None = None,
                        n_classes: int | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per split, (its test samples' indices (m,), their decision scores (m, n_classes)):
        the SVM trained on the split's other samples, as `split_accuracies` scores it."""
        labels = np.asarray(labels)
        out: list = [None] * len(test_masks)
        for where, T, scores in self._split_scores(labels, test_masks, K, X, n_classes):
            for i, t, s in zip(where, T, scores):
                out[i] = (t, s)
        return out

    def _split_scores(self, labels, test_masks, K, X, n_classes):
        """Yields (split numbers, test indices (S, m), decision scores (S, m, c)) per test
        size."""
        if K is None:
            if X is None:
                raise ValueError('give the kernel K or the features X')
            X = np.asarray(X, dtype=np.float64)
            K = X @ X.T
        n_classes = int(labels.max()) + 1 if n_classes is None else n_classes
        Y = _pm_one_targets(labels, n_classes)
        Kb = np.ascontiguousarray(np.asarray(K, dtype=np.float64) + 1.0)  # bias feature of value 1
        n = labels.size
        # warm start and factor order: the SVM trained on all samples; each split starts at
        # its violators, and the samples enter the factor most violating first
        # a warning names the caller of split_accuracies / split_decisions (this generator
        # is one frame below them)
        a_all = self._fit(Kb, np.arange(n)[None], Y, np.ones(Y.shape, dtype=bool),
                          np.zeros(Y.shape), stacklevel=4)[0]
        margin = Y * (Kb @ a_all)
        start = margin < 1
        sizes = np.array([int(np.sum(m)) for m in test_masks])
        for size in np.unique(sizes):
            where = np.flatnonzero(sizes == size)
            masks = np.stack([np.asarray(test_masks[i], dtype=bool) for i in where])
            T = np.nonzero(masks)[1].reshape(where.size, size)
            train = np.nonzero(~masks)[1].reshape(where.size, n - size)
            a = self._fit(Kb, train, Y, start, margin, stacklevel=4)
            yield where, T, Kb[T[:, :, None], train[:, None, :]] @ a   # (splits, test, classes)

    def fit_kernels(self, Kt: np.ndarray, Y: np.ndarray,
                    start: np.ndarray | None = None) -> np.ndarray:
        """Coefficients a (S, m, c) for training kernels Kt (S, m, m) and +-1 targets
        Y (S, m, c). start: None to start from the ridge solution (every sample a violator),
        or a guess (S, m, c) of the margin violators at the optimum (any start converges to
        the same optimum; a good guess saves Newton steps)."""
        S, m, c = Y.shape
        start = np.ones(Y.shape, dtype=bool) if start is None else np.asarray(start, dtype=bool)
        coef = []
        for s in range(S):   # a loop, not a comprehension: a warning names fit_kernels' caller
            coef.append(self._fit(np.ascontiguousarray(Kt[s], dtype=np.float64),
                                  np.arange(m)[None], np.asarray(Y[s], dtype=np.float64),
                                  start[s], np.zeros((m, c))))
        return np.concatenate(coef)

    def _fit(self, K, train, Y, start, priority, stacklevel: int = 3) -> np.ndarray:
        """Coefficients (S, m, c) of the problems on the training sets `train` (S, m) of the
        kernel K (n, n, bias included), targets Y (n, c), starting at the violators `start`
        (n, c) and factoring samples in increasing `priority` (n, c). An unconverged problem
        warns at `stacklevel` (the public method's caller)."""
        coef = np.zeros(train.shape + (Y.shape[1],))
        unconverged = _newton_kernel(
            K, np.ascontiguousarray(train, dtype=np.int64), np.ascontiguousarray(Y, dtype=np.float64),
            np.ascontiguousarray(start, dtype=np.bool_),
            np.ascontiguousarray(priority, dtype=np.float64), 1.0 / (2.0 * self.C),
            float(self.tol), int(self.max_iter), coef)
        if unconverged:
            import warnings
            from sklearn.exceptions import ConvergenceWarning
            warnings.warn(f'squared-hinge SVM: {unconverged} of {coef.shape[0] * coef.shape[2]} '
                          f'problems not converged after {self.max_iter} Newton steps; using '
                          'the last iterate (raise max_iter, or lower C)', ConvergenceWarning,
                          stacklevel=stacklevel)
        return coef


@numba.njit(cache=True, nogil=True, inline='always')
def _dot(u, v, k):
    """sum u[i] v[i] for i < k, in eight interleaved partial sums (a fixed order: the same bits
    on every CPU, without one long chain of dependent additions)."""
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
    i = 0
    while i + 8 <= k:
        s0 += u[i] * v[i]
        s1 += u[i + 1] * v[i + 1]
        s2 += u[i + 2] * v[i + 2]
        s3 += u[i + 3] * v[i + 3]
        s4 += u[i + 4] * v[i + 4]
        s5 += u[i + 5] * v[i + 5]
        s6 += u[i + 6] * v[i + 6]
        s7 += u[i + 7] * v[i + 7]
        i += 8
    while i < k:
        s0 += u[i] * v[i]
        i += 1
    return ((s0 + s4) + (s1 + s5)) + ((s2 + s6) + (s3 + s7))


@numba.njit(cache=True, nogil=True)
def _delete_row(L, rows, r, k, v):
    """Remove position r from the lower factor L[:k, :k] (L L' = A over rows[:k]): the rows
    below move up without column r, and the trailing block absorbs the removed column as a
    rank-one update, (k - r)^2 work instead of refactoring it."""
    n2 = k - r - 1
    for i in range(n2):
        v[i] = L[r + 1 + i, r]
    for p in range(r + 1, k):
        rows[p - 1] = rows[p]
        Lp, Lq = L[p], L[p - 1]
        for j in range(r):
            Lq[j] = Lp[j]
        for j in range(r + 1, p + 1):
            Lq[j - 1] = Lp[j]
    for j in range(n2):
        jj = r + j
        Ljj = L[jj, jj]
        rr = math.sqrt(Ljj * Ljj + v[j] * v[j])
        cos = rr / Ljj
        sin = v[j] / Ljj
        L[jj, jj] = rr
        for i in range(j + 1, n2):
            ii = r + i
            L[ii, jj] = (L[ii, jj] + sin * v[i]) / cos
            v[i] = cos * v[i] - sin * L[ii, jj]


@numba.njit(cache=True, nogil=True)
def _restricted_solve(Kt, y, viol, order, lam, rows, k, L, z, target):
    """Newton target for the violators `viol` (m,): target_V solves (Kt_VV + lam I) x = y_V,
    0 elsewhere. `rows[:k]` and the lower factor `L[:k, :k]` (L L' = Kt_VV + lam I over those
    rows, in that order) and `z[:k]` (L z = y) are those of the previous call: the rows that
    left V are deleted (rank-one updates; or, when that would cost more, the factor is cut at
    the first of them), the rest of V is appended in `order`. Returns the new k."""
    m = y.size
    n_new = 0
    for i in range(m):
        n_new += viol[i]
    first_left = k
    delete_cost = 0
    for p in range(k - 1, -1, -1):
        if not viol[rows[p]]:
            first_left = p
            delete_cost += 3 * (k - p) * (k - p)
    if first_left < k:
        if 6 * delete_cost < n_new ** 3 - first_left ** 3:
            for p in range(k - 1, first_left - 1, -1):
                if not viol[rows[p]]:
                    _delete_row(L, rows, p, k, target)
                    k -= 1
        else:
            k = first_left
    changed = min(first_left, k)
    kept = np.zeros(m, dtype=np.bool_)
    for p in range(k):
        kept[rows[p]] = True
    for oi in range(m):                       # append V's other samples in `order`
        i = order[oi]
        if not viol[i] or kept[i]:
            continue
        rows[k] = i
        Li = L[k]
        for p in range(k):                    # L[k, p] = (A[i, rows[p]] - L[k,:p].L[p,:p]) / L[p, p]
            Li[p] = (Kt[i, rows[p]] - _dot(Li, L[p], p)) / L[p, p]
        Li[k] = math.sqrt(Kt[i, i] + lam - _dot(Li, Li, k))
        k += 1
    for p in range(changed, k):               # L z = y_V from the first changed row
        z[p] = (y[rows[p]] - _dot(L[p], z, p)) / L[p, p]
    x = target                                 # L' x = z, column by column (contiguous rows)
    w = np.empty(k)
    w[:] = z[:k]
    for i in range(m):
        x[i] = 0.0
    for p in range(k - 1, -1, -1):
        xp = w[p] / L[p, p]
        x[rows[p]] = xp
        Lp = L[p]
        for j in range(p):
            w[j] -= xp * Lp[j]
    return k


@numba.njit(cache=True, nogil=True)
def _newton_kernel(K, train, Y, start, priority, lam, tol_rel, max_iter, coef):
    """`SquaredHingeSplitScorer._fit`: the finite Newton method for every (split, class)
    problem, one at a time, each step's restricted solve by `_restricted_solve` (the factor
    kept between steps) and an exact line search by bisection of the objective's slope.
    Returns the number of problems not converged within max_iter steps."""
    S, m = train.shape
    c = Y.shape[1]
    Kt = np.empty((m, m))
    L = np.empty((m, m))
    z = np.empty(m)
    rows = np.empty(m, dtype=np.int64)
    y = np.empty(m)
    key = np.empty(m)
    viol = np.empty(m, dtype=np.bool_)
    solved_for = np.empty(m, dtype=np.bool_)
    a = np.empty(m)
    out = np.empty(m)
    target = np.empty(m)
    d = np.empty(m)
    Kd = np.empty(m)
    margin = np.empty(m)
    yq = np.empty(m)
    unconverged = 0
    for s in range(S):
        tr = train[s]
        norm = 0.0
        for i in range(m):
            row_sum = 0.0
            for j in range(m):
                Kt[i, j] = K[tr[i], tr[j]]
                row_sum += abs(Kt[i, j])
            norm = max(norm, row_sum)
        tol = tol_rel * (1.0 + norm / lam)
        for q in range(c):
            for i in range(m):
                y[i] = Y[tr[i], q]
                key[i] = priority[tr[i], q]
                viol[i] = start[tr[i], q]
            order = np.argsort(key, kind='mergesort')
            k = _restricted_solve(Kt, y, viol, order, lam, rows, 0, L, z, target)
            a[:] = target
            _matvec_support(Kt, a, out)
            solved_for[:] = viol
            converged = False
            for _ in range(max_iter):
                big_grad = False
                same = True
                for i in range(m):
                    viol[i] = y[i] * out[i] < 1.0
                    g = lam * a[i] + (out[i] - y[i] if viol[i] else 0.0)
                    if abs(g) > tol:
                        big_grad = True
                    if viol[i] != solved_for[i]:
                        same = False
                if not big_grad or same:
                    converged = True
                    break
                k = _restricted_solve(Kt, y, viol, order, lam, rows, k, L, z, target)
                for i in range(m):
                    d[i] = target[i] - a[i]
                _matvec_support(Kt, d, Kd)
                t = _line_search(a, d, out, Kd, y, lam, margin, yq)
                if t == 0.0:
                    # a Newton direction that does not descend means rounding dominates (an
                    # ill-conditioned kernel at a large C): the iterate is as good as it gets
                    converged = True
                    break
                for i in range(m):
                    a[i] += t * d[i]
                    out[i] += t * Kd[i]
                    # after a partial step the violators of the iterate are not known
                    solved_for[i] = viol[i] if t == 1.0 else not viol[i]
            if not converged:
                unconverged += 1
            for i in range(m):
                coef[s, i, q] = a[i]
    return unconverged


@numba.njit(cache=True, nogil=True)
def _matvec_support(Kt, v, out):
    """out = Kt v (Kt symmetric), over the nonzeros of v only, row by row (contiguous)."""
    m = v.size
    out[:] = 0.0
    for j in range(m):
        vj = v[j]
        if vj != 0.0:
            Kj = Kt[j]
            for i in range(m):
                out[i] += vj * Kj[i]


@numba.njit(cache=True, nogil=True)
def _line_search(a, d, out, Kd, y, lam, margin, yq, bisections=30):
    """The step t in (0, 1] minimising the objective along d: it is convex and piecewise
    quadratic in t, so its slope is increasing; a full step where the slope is still <= 0 at
    t = 1, else bisection; 0 where d does not descend at all."""
    m = a.size
    a1 = _dot(a, Kd, m)                       # a'Kd
    a2 = _dot(d, Kd, m)                       # d'Kd
    for i in range(m):
        margin[i] = 1.0 - y[i] * out[i]
        yq[i] = y[i] * Kd[i]
    if _slope(1.0, a1, a2, margin, yq, lam) <= 0.0:
        return 1.0
    if _slope(0.0, a1, a2, margin, yq, lam) >= 0.0:
        return 0.0
    lo, hi = 0.0, 1.0
    for _ in range(bisections):
        mid = 0.5 * (lo + hi)
        if _slope(mid, a1, a2, margin, yq, lam) > 0.0:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


@numba.njit(cache=True, nogil=True, inline='always')
def _slope(t, a1, a2, margin, yq, lam):
    """Half the objective's slope at step t."""
    s = 0.0
    for i in range(margin.size):
        r = margin[i] - t * yq[i]
        if r > 0.0:
            s += r * yq[i]
    return lam * (a1 + t * a2) - s


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
