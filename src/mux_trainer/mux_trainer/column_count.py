"""How many pattern columns a trained model keeps: the rule applied to the search's split
accuracies.

- 'max': the count with the highest mean split accuracy (the paper's; the fewest columns
  on a tie).
- 'one_se': the one-standard-error rule (Breiman et al. 1984; Hastie, Tibshirani & Friedman,
  "Elements of Statistical Learning", 7.10): the fewest columns whose mean split accuracy is
  within one standard error of the best count's. Where the cue is near the noise the means
  of neighbouring counts differ by less than their uncertainty, and 'max' picks whichever
  count the splits happened to favour; the smaller model is the one that generalises.

The standard error: the repeated splits overlap (each holds out `test_fraction` of the
poses, drawn again for every split), so the spread of their accuracies divided by
sqrt(n_splits) would claim a certainty the data do not hold. The data hold about
1 / test_fraction disjoint test sets, as K-fold cross-validation does with K = 1 /
test_fraction, and the K-fold rule's standard error std / sqrt(K) is used.
"""
from __future__ import annotations

import numpy as np

COUNT_RULES = ('max', 'one_se')


def split_standard_error(split_accuracy, test_fraction: float) -> float:
    """Standard error of a mean split accuracy (see the module docstring)."""
    acc = np.asarray(split_accuracy, dtype=np.float64)
    if acc.size < 2:
        return 0.0
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f'test_fraction must be in (0, 1), got {test_fraction}')
    n_folds = max(1.0, 1.0 / float(test_fraction))
    return float(acc.std(ddof=1) / np.sqrt(n_folds))


def choose_column_count(accuracy_by_count: dict, split_accuracy_by_count: dict | None = None,
                        rule: str = 'max', test_fraction: float = 0.25) -> int:
    """The column count to keep: `accuracy_by_count` {count: mean split accuracy};
    `split_accuracy_by_count` {count: the split accuracies behind that mean} (needed by
    'one_se'; a count without them has no spread)."""
    if rule not in COUNT_RULES:
        raise ValueError(f'unknown column-count rule {rule!r}; choose from {", ".join(COUNT_RULES)}')
    if not accuracy_by_count:
        raise ValueError('no column count to choose from')
    acc = {int(k): float(v) for k, v in accuracy_by_count.items()}
    best = max(acc, key=lambda k: (acc[k], -k))
    if rule == 'max':
        return best
    splits = split_accuracy_by_count or {}
    se = split_standard_error(splits[best], test_fraction) if best in splits else 0.0
    return min(k for k in acc if acc[k] >= acc[best] - se)
