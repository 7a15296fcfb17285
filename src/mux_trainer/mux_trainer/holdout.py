"""Held-out evaluation: train on some poses, test on fresh renders of the others.

The outer split holds out a random subset of pose indices (the same for every class, like
the inner splits), or of physical samples with all their poses (`holdout_by='instances'`:
objects never seen in training); methods are trained (search + classifiers) on the rest
only.
Test images are rendered under each method's patterns with noise drawn independently of
everything used in training, `n_renders` times, and classified by the method's classifier
for each column count.
"""
from __future__ import annotations

import time

import numpy as np

from .column_count import COUNT_RULES, choose_column_count, split_standard_error
from .data import sample_object_types
from .evaluation import render
from .rendering import SearchData, add_noise, image_features, standard_normal
from .splits import pose_splits

HOLDOUT_STREAM = 7919  # seed-sequence tag of the test-noise stream (distinct from the search's)


HOLDOUT_BY = ('poses', 'instances')


def holdout_split(data: SearchData, test_fraction: float = 0.25, seed: int = 0,
                  instance=None):
    """(train indices, test indices): a random subset of pose indices is held out, the same
    for every class; or, given `instance` (each sample's physical sample number within its
    class, `ModelSet.instance`), a random subset of instance numbers with all their poses, so
    no held-out object is seen in training in another pose."""
    groups = data.pose_index if instance is None else np.asarray(instance)
    if groups.shape != data.pose_index.shape:
        raise ValueError(f'instance must hold one entry per sample ({data.n_samples}), got '
                         f'shape {groups.shape}')
    if instance is not None and np.unique(groups).size < 2:
        raise ValueError('holding out instances needs at least 2 physical samples per class; '
                         'this capture has 1 (hold out poses instead)')
    mask = pose_splits(groups, 1, test_fraction,
                       np.random.default_rng([int(seed), HOLDOUT_STREAM, 1]))[0]
    return np.flatnonzero(~mask), np.flatnonzero(mask)


def test_images(test_data: SearchData, mode: str, patterns: np.ndarray, render_index: int,
                seed: int) -> np.ndarray:
    """Freshly rendered noisy test images of all columns, `(n_images, n, pixels)`."""
    clean = render(test_data, mode, patterns)
    rng = np.random.default_rng([int(seed), HOLDOUT_STREAM, 2, int(render_index)])
    return add_noise(test_data, clean, standard_normal(rng, clean.shape))


def test_features(test_data: SearchData, mode: str, patterns: np.ndarray, render_index: int,
                  seed: int) -> np.ndarray:
    """Features of freshly rendered noisy test images of all columns, `(n, features)`."""
    return image_features(test_data, test_images(test_data, mode, patterns, render_index, seed))


def evaluate_heldout(model, test_data: SearchData, n_renders: int = 4, seed: int = 0) -> dict:
    """Held-out accuracy of a fitted pattern model for every column count.

    Returns {'accuracy_by_images': {k: acc}, 'correct': {k: (n,) fraction correct per
    test sample over the renders}, 'infer_ms_per_sample': {k: ms}} (features + classifier,
    not the exposures).
    """
    counts = sorted(model.classifiers_)
    correct = {k: np.zeros(test_data.n_samples) for k in counts}
    infer_s = {k: 0.0 for k in counts}
    per = model.images_per_pattern
    for r in range(int(n_renders)):
        X = test_features(test_data, model.mode, model.patterns_, r, seed)
        for k in counts:
            t0 = time.perf_counter()
            # features of the first k columns are a prefix of all columns' features
            pred = model.predict_features(X, k)
            infer_s[k] += time.perf_counter() - t0
            correct[k] += pred == test_data.labels
    for k in counts:
        correct[k] /= n_renders
    # feature time per sample, measured once for a representative batch
    H, W = test_data.image_shape
    t0 = time.perf_counter()
    image_features(test_data, np.zeros((per, test_data.n_samples, H * W), np.float32))
    hog_ms_per_image = (time.perf_counter() - t0) * 1e3 / (per * test_data.n_samples)
    return {
        'accuracy_by_images': {k: float(correct[k].mean()) for k in counts},
        'correct': correct,
        'infer_ms_per_sample': {k: float(infer_s[k] * 1e3 / (n_renders * test_data.n_samples)
                                         + hog_ms_per_image * per * k) for k in counts},
    }


def evaluate_learned_heldout(model, test_data: SearchData, n_renders: int = 4,
                             seed: int = 0) -> dict:
    """Held-out accuracy of a fitted learned model (`learned.LearnedIlluminationClassifier`)
    under the rules of `evaluate_heldout`: test images rendered under the model's patterns
    with `test_images` (the same noise stream, independent of training), n_renders times,
    classified by the model's numpy forward pass. Returns {'accuracy', 'correct' (n,)}."""
    correct = np.zeros(test_data.n_samples)
    for r in range(int(n_renders)):
        images = test_images(test_data, 'joint', model.patterns_, r, seed)
        correct += model.predict_images(images) == test_data.labels
    correct /= int(n_renders)
    return {'accuracy': float(correct.mean()), 'correct': correct}


def accuracy_by_type(test_data: SearchData, correct: np.ndarray) -> dict:
    """Accuracy per object type (classes sharing the prefix before '-', e.g. real and fake)."""
    types = sample_object_types(test_data)
    return {t: float(correct[types == t].mean()) for t in dict.fromkeys(types.tolist())}


def method_summary(model, test_data: SearchData, n_renders: int = 4, seed: int = 0,
                   train_seconds: float | None = None) -> dict:
    """The JSON-ready result of one method: accuracy at its chosen column count (chosen
    on training data: the search's best split accuracy), per type, and per column count."""
    res = evaluate_heldout(model, test_data, n_renders, seed)
    k = int(model.best_n_patterns_)
    out = {
        'accuracy': res['accuracy_by_images'][k],
        'n_images': k,
        'images_per_pattern': int(model.images_per_pattern),
        'n_exposures': int(k * model.images_per_pattern),
        'accuracy_by_type': accuracy_by_type(test_data, res['correct'][k]),
        'accuracy_by_images': {str(c): a for c, a in res['accuracy_by_images'].items()},
        'search_accuracy_by_images': {str(c): float(a) for c, a in model.accuracy_by_images_.items()},
        'mode': model.mode,
        'features': str(model.rendering.features),
        'inner_estimate': model.inner_estimate_,
        'patterns': np.asarray(model.patterns_).astype(int).tolist(),
        'infer_ms_per_sample': res['infer_ms_per_sample'][k],
    }
    splits = getattr(model, 'split_accuracy_by_images_', None)
    if splits:
        # what each column-count rule would have kept, from the same search, side by side
        out['search_se_by_images'] = {str(c): split_standard_error(a, model.scoring.test_fraction)
                                      for c, a in splits.items()}
        out['count_rule'] = str(getattr(model, 'count_rule', 'max'))
        out['by_count_rule'] = {}
        for rule in COUNT_RULES:
            kr = choose_column_count(model.accuracy_by_images_, splits, rule,
                                     model.scoring.test_fraction)
            out['by_count_rule'][rule] = {'n_images': kr,
                                          'accuracy': res['accuracy_by_images'][kr]}
    if hasattr(model, 'improved_'):
        out['improved'] = [bool(v) for v in model.improved_]
    if train_seconds is not None:
        out['train_seconds'] = float(train_seconds)
    return out
