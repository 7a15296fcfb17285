"""A linear head gated by object type: which type, then which class of that type.

A flat one-vs-rest linear SVM over many classes z-scores every statistic over all of them.
Where two classes of one type (a relief seal and a flat print of it) differ by a small step
of one statistic that varies widely between types (fruit against card), that step is small
in those units, and the SVM leans on whatever else separates the few training samples of
the pair, which need not hold for a sample it has not seen (docs/LEARNED.md, "The head: gated
by object type": the 16-class mix's held-out seals). Here one linear SVM tells the types apart, and within a type
a class's score is the sum of two linear SVMs' (an average of the two): one fitted on that
type's samples alone, z-scored over them (it sees the small step), and the flat one-vs-rest
SVM over every class (its direction is held by all the data: alone, the per-type SVM lost
green apples of a held-out instance that the flat one classifies).

All are linear in the raw statistics, so the head is one linear layer with ``G + K``
outputs: the G types' scores, then the K classes' scores within their type
(``class_groups[c]`` is class c's type). The class is the best of the best type's classes
(`gated_margins` gives per-class scores whose argmax is that class). Plain arrays, numpy
only: the classifier node needs nothing else.
"""
from __future__ import annotations

import numpy as np

from .estimator import fit_linear

__all__ = ["check_class_groups", "fit_gated_linear", "gated_margins", "NO_SAMPLES_SCORE"]

# the score of a type or class without training samples: never the best (a float32 finite)
NO_SAMPLES_SCORE = float(np.finfo(np.float32).min / 2)


def check_class_groups(class_groups) -> np.ndarray:
    """class_groups as an int64 array (K,) of types 0 .. G - 1, each used; raises ValueError."""
    groups = np.asarray(class_groups)
    if groups.ndim != 1 or groups.size == 0 or not np.issubdtype(groups.dtype, np.integer):
        raise ValueError(f"class_groups must be a non-empty 1-D integer array (each class's "
                         f"type), got dtype {groups.dtype} shape {groups.shape}")
    if (groups.min() < 0 or groups.max() >= groups.size
            or not np.array_equal(np.unique(groups), np.arange(groups.max() + 1))):
        raise ValueError("class_groups must number the types 0 .. G - 1, each type used")
    return groups.astype(np.int64)


def fit_gated_linear(X, y, class_groups, C: float = 1.0, random_state: int = 0,
                     max_iter: int = 10000) -> tuple[np.ndarray, np.ndarray]:
    """A type-gated linear head on raw features X (n, F), labels y (class indices 0 .. K-1).
    Returns coef (G + K, F) and intercept (G + K,) on the raw features: rows 0 .. G-1 score
    the types (a linear SVM over all samples, labels ``class_groups[y]``), rows G + c score
    class c within its type: a linear SVM of c against the other classes of its type (on
    that type's samples, its own z-scoring; none for a type with one class present) plus the
    flat one-vs-rest linear SVM's row for c (all samples). A type or class without training
    samples scores `NO_SAMPLES_SCORE`."""
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y)
    groups = check_class_groups(class_groups)
    if y.shape != (X.shape[0],):
        raise ValueError(f"y must have one label per sample ({X.shape[0]}), got shape {y.shape}")
    if y.size and (y.min() < 0 or y.max() >= groups.size):
        raise ValueError(f"labels must be class indices 0 .. {groups.size - 1}")
    G, K = int(groups.max()) + 1, groups.size
    coef = np.zeros((G + K, X.shape[1]))
    intercept = np.full(G + K, NO_SAMPLES_SCORE)
    present = np.unique(groups[y])
    if present.size == 1:   # one type: it is the answer
        intercept[present[0]] = 0.0
    else:
        c, b, types = fit_linear(X, groups[y], "linear_svm", C=C, max_iter=max_iter,
                                 random_state=random_state)
        coef[types], intercept[types] = c, b
    c, b, classes = fit_linear(X, y, "linear_svm", C=C, max_iter=max_iter,
                               random_state=random_state)
    coef[G + classes], intercept[G + classes] = c, b
    for g in present:
        in_type = groups[y] == g
        classes = np.unique(y[in_type])
        if classes.size == 1:
            continue
        c, b, _ = fit_linear(X[in_type], y[in_type], "linear_svm", C=C, max_iter=max_iter,
                             random_state=random_state)
        coef[G + classes] += c
        intercept[G + classes] += b
    return coef, intercept


def gated_margins(outputs, class_groups) -> np.ndarray:
    """The head's outputs (n, G + K) -> per-class scores (n, K): for class c of type g, the
    smaller of g's lead over the best other type and c's lead over the best other class of g
    (a type or a class alone leads by +inf; the scores are clipped to finite float32).
    Positive for exactly the class the gate picks (the best class of the best type; on a tie
    none is, and argmax takes the first), negative by how far the others fall short at their
    weaker stage."""
    groups = check_class_groups(class_groups)
    out = np.asarray(outputs, dtype=np.float64)
    G, K = int(groups.max()) + 1, groups.size
    if out.ndim != 2 or out.shape[1] != G + K:
        raise ValueError(f"outputs must be (n, {G + K}): {G} type and {K} class scores, "
                         f"got shape {out.shape}")
    margins = np.minimum(_lead(out[:, :G])[:, groups], _lead_within(out[:, G:], groups, G))
    top = float(np.finfo(np.float32).max)   # finite float32 scores, even for one class alone
    return np.clip(margins, -top, top)


def _lead(scores: np.ndarray) -> np.ndarray:
    """Each column's score minus the best of the other columns (+inf with one column)."""
    if scores.shape[1] == 1:
        return np.full(scores.shape, np.inf)
    top2 = -np.partition(-scores, 1, axis=1)[:, :2]
    best_other = np.where(scores == top2[:, :1], top2[:, 1:2], top2[:, :1])
    return scores - best_other


def _lead_within(class_scores: np.ndarray, groups: np.ndarray, G: int) -> np.ndarray:
    """`_lead` of each class among its type's classes, then by type (n, K)."""
    lead = np.empty_like(class_scores)
    for g in range(G):
        members = np.flatnonzero(groups == g)
        lead[:, members] = _lead(class_scores[:, members])
    return lead
