"""Repeated random pose splits (the paper's 75 / 25 train/test rule) and splits that hold
out whole physical samples (`instance_splits`, `inner_splits`: what every method is chosen by).

Each split draws a random subset of the pose indices as the test poses; every sample whose
pose index is in that subset is a test sample, whatever its class. So the same pose indices
are held out for every class, and a class never sees a test pose in training.
"""
from __future__ import annotations

import numpy as np


def n_test_poses(n_poses: int, test_fraction: float) -> int:
    """How many of `n_poses` pose indices a split holds out (at least 1, at most n - 1)."""
    if n_poses < 2:
        raise ValueError(f'pose splits need at least 2 distinct poses, got {n_poses}; '
                         'capture more poses per class')
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f'test_fraction must be in (0, 1), got {test_fraction}')
    return int(min(max(round(test_fraction * n_poses), 1), n_poses - 1))


def pose_splits(pose_index: np.ndarray, n_repeats: int, test_fraction: float = 0.25,
                rng: np.random.Generator | int | None = 0) -> list[np.ndarray]:
    """`n_repeats` boolean test masks over the samples (True = test sample).

    pose_index: the pose number of each sample within its class. The held-out pose indices
    are drawn without replacement, independently per split, from `rng`.
    """
    pose_index = np.asarray(pose_index)
    if pose_index.ndim != 1:
        raise ValueError(f'pose_index must be 1-D (one entry per sample), got {pose_index.shape}')
    if n_repeats < 1:
        raise ValueError(f'n_repeats must be >= 1, got {n_repeats}')
    rng = np.random.default_rng(rng)
    poses = np.unique(pose_index)
    k = n_test_poses(poses.size, test_fraction)
    masks = []
    for _ in range(n_repeats):
        test_poses = rng.choice(poses, size=k, replace=False)
        masks.append(np.isin(pose_index, test_poses))
    return masks


def split_indices(masks: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boolean test masks -> (train indices, test indices) pairs."""
    return [(np.flatnonzero(~m), np.flatnonzero(m)) for m in masks]


# What the inner splits hold out (`SplitScoring.inner_groups`): 'instances' holds out whole
# physical samples (every pose of them), so the inner estimate is one for objects never seen
# in training, the product's use; 'poses' holds out pose indices (the paper's rule: a test
# object is seen in training in other poses); 'auto' is 'instances' where every class has
# two or more physical samples, else 'poses'.
INNER_GROUPS = ('auto', 'poses', 'instances')


def check_inner_groups(inner_groups: str) -> None:
    if inner_groups not in INNER_GROUPS:
        raise ValueError(f"inner_groups must be one of {', '.join(INNER_GROUPS)}, got "
                         f'{inner_groups!r}')


def samples_per_class(labels: np.ndarray, instance: np.ndarray | None) -> np.ndarray:
    """Physical samples of each class present in the data (0 for a class with no sample);
    1 per class when `instance` is None (a capture that does not say)."""
    labels = np.asarray(labels)
    n_classes = int(labels.max()) + 1 if labels.size else 0
    if instance is None:
        return (np.bincount(labels, minlength=n_classes) > 0).astype(np.int64)
    instance = np.asarray(instance)
    return np.array([np.unique(instance[labels == c]).size for c in range(n_classes)], np.int64)


def resolve_inner_groups(inner_groups: str, labels: np.ndarray,
                         instance: np.ndarray | None) -> str:
    """'poses' or 'instances' for `inner_groups` on data with these labels and physical
    sample numbers ('auto': 'instances' where every class present has >= 2 samples).
    ValueError for 'instances' where a class has a single physical sample."""
    check_inner_groups(inner_groups)
    counts = samples_per_class(labels, instance)
    counts = counts[counts > 0]
    grouped_possible = counts.size > 0 and int(counts.min()) >= 2
    if inner_groups == 'auto':
        return 'instances' if grouped_possible else 'poses'
    if inner_groups == 'instances' and not grouped_possible:
        raise ValueError('inner splits by physical sample need at least 2 physical samples of '
                         f'every class; this data has {int(counts.min()) if counts.size else 0} '
                         "for some class (use inner_groups 'poses' or 'auto')")
    return inner_groups


def instance_splits(labels: np.ndarray, instance: np.ndarray, n_repeats: int,
                    test_fraction: float = 0.25,
                    rng: np.random.Generator | int | None = 0) -> list[np.ndarray]:
    """`n_repeats` boolean test masks (True = test sample), each holding out whole physical
    samples with all their poses: the same physical sample numbers in every class (as
    `holdout.holdout_split` holds out instances, stratified and grouped in the spirit of
    scikit-learn's StratifiedGroupKFold), `n_test_poses(fewest samples of a class,
    test_fraction)` of them. The same numbers, not independent draws per class: where a
    fake is a copy of the real sample of its number (`lightstage synth`'s flat objects), a
    split that held out one and trained on the other would test how a copy of a seen
    object is told from it, which the outer test never asks (measured: SNR-optimal's inner
    estimate at 25 % on a 2-class seal capture whose held-out accuracy is 47 %).

    Every sample is held out in turn: the sample numbers are dealt from a shuffled deck,
    the next ones for each split, reshuffled when the deck runs out, so over any
    `ceil(numbers / held out)` + 1 consecutive splits each number is held out at least
    once (a split never holds out a number twice).
    """
    labels = np.asarray(labels)
    instance = np.asarray(instance)
    if labels.shape != instance.shape or labels.ndim != 1:
        raise ValueError(f'labels and instance must be 1-D of one length, got {labels.shape} '
                         f'and {instance.shape}')
    if n_repeats < 1:
        raise ValueError(f'n_repeats must be >= 1, got {n_repeats}')
    rng = np.random.default_rng(rng)
    numbers = np.unique(instance)
    fewest = int(samples_per_class(labels, instance)[np.unique(labels)].min())
    k = n_test_poses(fewest, test_fraction)
    deck: list = []
    masks = []
    for _ in range(int(n_repeats)):
        chosen = deck[:k]
        del deck[:k]
        if len(chosen) < k:
            fresh = [int(i) for i in rng.permutation(numbers) if int(i) not in chosen]
            need = k - len(chosen)
            chosen += fresh[:need]
            deck[:] = fresh[need:]
        masks.append(np.isin(instance, chosen))
    return masks


def inner_splits(labels: np.ndarray, pose_index: np.ndarray, instance: np.ndarray | None,
                 n_repeats: int, test_fraction: float = 0.25,
                 rng: np.random.Generator | int | None = 0,
                 inner_groups: str = 'auto') -> tuple[list[np.ndarray], dict]:
    """The inner test masks of a method and how they were made.

    'poses' (after `resolve_inner_groups`): `pose_splits`, the same draws as ever;
    'instances': `instance_splits`. Returns (masks, description): description is
    {'held_out': 'physical samples' | 'poses', 'inner_groups': the setting asked for,
    'groups_per_class' / 'groups_per_class_max': physical samples (or pose indices) per
    class, the fewest / the most, 'held_out_per_class' (of the class with the fewest),
    'n_repeats', 'test_fraction'}, what the provenance records.
    """
    by = resolve_inner_groups(inner_groups, labels, instance)
    if by == 'instances':
        masks = instance_splits(labels, instance, n_repeats, test_fraction, rng)
        counts = samples_per_class(labels, instance)[np.unique(labels)]
        n_groups, most = int(counts.min()), int(counts.max())
    else:
        masks = pose_splits(pose_index, n_repeats, test_fraction, rng)
        n_groups = most = int(np.unique(pose_index).size)
    return masks, {'held_out': 'physical samples' if by == 'instances' else 'poses',
                   'inner_groups': str(inner_groups), 'groups_per_class': n_groups,
                   'groups_per_class_max': most,
                   'held_out_per_class': n_test_poses(n_groups, test_fraction),
                   'n_repeats': int(n_repeats), 'test_fraction': float(test_fraction)}


def describe_inner(description: dict | None, accuracy: float | None = None) -> str:
    """An inner estimate and how it was made, in plain words (what `lightstage train`
    prints): by physical sample, an estimate for objects never seen in training; by pose,
    one that holds only for the objects trained on."""
    if not description:
        return ''
    head = '' if accuracy is None else f'inner estimate {100 * float(accuracy):.1f} %: '
    n, k, r = (description['groups_per_class'], description['held_out_per_class'],
               description['n_repeats'])
    most = description.get('groups_per_class_max', n)
    optimism = description.get('selection_optimism')
    if head and optimism:
        sign = 'less' if optimism > 0 else 'plus'
        head = (f'{head}the split accuracy {100 * float(description["search_accuracy"]):.1f} % '
                f'{sign} {100 * abs(float(optimism)):.1f} points for having chosen the light on '
                'these splits (a nested choice over them); ')
    if description['held_out'] == 'physical samples':
        of = f'{n}' if most == n else f'{n} to {most}'
        return (f'{head}the mean over {r} inner split(s), each holding out {k} of the {of} '
                'physical samples of every class with all their poses (every sample in '
                'turn): an estimate for objects never seen in training')
    single = (' (every class has one physical sample)' if description.get('inner_groups') == 'auto'
              else '')
    return (f'{head}the mean over {r} inner split(s), each holding out {k} of {n} pose '
            f'indices{single}: it holds only for the objects trained on, seen in new poses; '
            'objects never seen may score lower')
