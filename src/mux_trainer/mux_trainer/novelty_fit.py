"""The unknown-object (novelty) models of a trained pattern model, fitted at training time.

For every image count the artifact classifies with, a `mux_classifier.novelty.NoveltyModel`
on the `NOVELTY_FEATURES` of the training samples' images under the model's patterns, each
sample rendered ``n_renders`` times with camera noise drawn apart from the search's
(`NOVELTY_STREAM`). Its threshold is set on held-out physical samples (each sample's poses
and renders held out together; by pose where the capture has one sample per class), so the
stated false-alarm rate is about new samples of the known types (docs/NOVELTY.md).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from mux_classifier.novelty import DEFAULT_FALSE_ALARM_RATE, NOVELTY_FEATURES, NoveltyModel

from .evaluation import render
from .rendering import SearchData, add_noise, image_features, standard_normal

__all__ = ["DEFAULT_RENDERS", "NOVELTY_STREAM", "UNKNOWN_TEST_STREAM", "evaluate_unknown",
           "fit_learned_novelty", "fit_novelty", "fit_pattern_novelty",
           "novelty_features", "sample_groups"]

NOVELTY_STREAM = 6151  # seed-sequence tag of the novelty renders' noise
DEFAULT_RENDERS = 3    # noisy renders of each training sample


def novelty_features(data: SearchData, mode: str, patterns: np.ndarray, render_index: int,
                     seed: int, stream: int = NOVELTY_STREAM,
                     features: str = NOVELTY_FEATURES) -> np.ndarray:
    """``features`` (n, images * values per image; `NOVELTY_FEATURES`: 9) of one noisy render
    of every sample of ``data`` under ``patterns`` (all columns, in image order), rendered
    one column at a time."""
    stats = dataclasses.replace(data, features=features)
    parts = []
    for c in range(patterns.shape[1]):
        clean = render(data, mode, patterns[:, c:c + 1])
        rng = np.random.default_rng([int(seed), int(stream), int(render_index), c])
        parts.append(image_features(stats, add_noise(data, clean,
                                                     standard_normal(rng, clean.shape))))
    return np.hstack(parts).astype(np.float64)


def sample_groups(data: SearchData) -> np.ndarray:
    """Each sample's physical sample as one integer across classes (by pose where the data
    has no physical-sample numbers)."""
    within = data.pose_index if data.instance is None else data.instance
    return np.asarray(data.labels, np.int64) * (int(within.max()) + 1) + within


def fit_novelty(data: SearchData, mode: str, patterns: np.ndarray, images_per_column: int,
                seed: int, false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
                n_renders: int = DEFAULT_RENDERS, only_all: bool = False) -> dict:
    """{image count: fitted NoveltyModel} for the first 1 .. all columns of ``patterns``
    (``images_per_column`` images each; ``only_all``: all columns only), on ``n_renders``
    noisy renders of every sample."""
    patterns = np.asarray(patterns)
    X = np.vstack([novelty_features(data, mode, patterns, r, seed)
                   for r in range(int(n_renders))])
    y = np.tile(data.labels, int(n_renders))
    groups = np.tile(sample_groups(data), int(n_renders))
    per_column = X.shape[1] // patterns.shape[1]
    first = patterns.shape[1] if only_all else 1
    return {c * int(images_per_column): NoveltyModel().fit(X[:, :c * per_column], y, groups,
                                                           false_alarm_rate)
            for c in range(first, patterns.shape[1] + 1)}


def fit_learned_novelty(model, data: SearchData,
                        false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
                        n_renders: int = DEFAULT_RENDERS) -> dict:
    """`fit_novelty` of a fitted learned model (`mux_trainer.learned`: one image per learned
    LED pattern, graded levels rendered as the stage lights them) on its training ``data``,
    for its one image count."""
    return fit_novelty(data, 'joint', np.asarray(model.patterns_, np.float64), 1,
                       int(model.seed), false_alarm_rate, n_renders, only_all=True)


def fit_pattern_novelty(model, false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
                        n_renders: int = DEFAULT_RENDERS, n_columns: int | None = None) -> dict:
    """`fit_novelty` of a fitted pattern model (greedy, SNR-optimal, naive) on its training
    data, for its first 1 .. ``n_columns`` pattern columns (default all: what
    `to_artifact` keeps)."""
    patterns = np.asarray(model.patterns_)
    columns = patterns.shape[1] if n_columns is None else int(n_columns)
    return fit_novelty(model.evaluator_.data, model.mode, patterns[:, :columns],
                       int(model.images_per_pattern), int(model.seed), false_alarm_rate,
                       n_renders)


UNKNOWN_TEST_STREAM = 6152  # seed-sequence tag of the renders an unknown-object test scores


def evaluate_unknown(model, train_data: SearchData, test_data: SearchData,
                     n_renders: int = 4, seed: int = 0,
                     false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE) -> dict | None:
    """How well objects of a type never trained are flagged unknown, under a fitted pattern
    model's patterns at its kept column count.

    Each object type in turn is left out: novelty models are fitted (as `lightstage train`
    fits them) on the other types' training samples, then ``n_renders`` fresh noisy renders
    of the held-out test samples are scored: the left-out type's (the share flagged unknown
    is the detection) and the other types' (new samples of trained types: the share flagged
    is the false alarms). The patterns are the model's, chosen on every type: the left-out
    type's looks took part in choosing the light, not in the novelty model
    (benchmarks/novelty_benchmark.py leaves types out of everything, on fixed patterns).
    Returns plain JSON, or None with fewer than two object types.
    """
    from .data import sample_object_types

    patterns = np.asarray(model.patterns_)[:, :int(model.best_n_patterns_)]
    per = int(model.images_per_pattern)
    k = patterns.shape[1] * per
    train_types, test_types = sample_object_types(train_data), sample_object_types(test_data)
    types = list(dict.fromkeys(train_types.tolist()))
    if len(types) < 2:
        return None
    X_test = np.vstack([novelty_features(test_data, model.mode, patterns, r, seed,
                                         UNKNOWN_TEST_STREAM) for r in range(int(n_renders))])
    tiled_types = np.tile(test_types, int(n_renders))
    by_type = {}
    flagged_known, known_answers = 0, 0
    for left_out in types:
        keep = np.flatnonzero(train_types != left_out)
        models = fit_novelty(train_data.subset(keep), model.mode, patterns, per, int(model.seed),
                             false_alarm_rate)
        flagged = models[k].score(X_test) >= 1.0
        novel = tiled_types == left_out
        known = ~novel
        by_type[left_out] = {'flagged': float(flagged[novel].mean()) if novel.any() else None,
                             'false_alarms': float(flagged[known].mean()) if known.any()
                             else None}
        flagged_known += int(flagged[known].sum())
        known_answers += int(known.sum())
    detected = [v['flagged'] for v in by_type.values() if v['flagged'] is not None]
    return {'n_images': k, 'false_alarm_rate': float(false_alarm_rate),
            'renders': int(n_renders), 'by_left_out_type': by_type,
            'flagged': float(np.mean(detected)) if detected else None,
            'flagged_worst': float(min(detected)) if detected else None,
            'false_alarms': flagged_known / known_answers if known_answers else None}
