"""The learned method's final classifier (docs/LEARNED.md, "The head: gated by object
type"): greedy's kind, linear SVMs on the kept light's rendered training statistics
(`Head.renders` noise draws), stored as one linear layer of a numpy `LearnedModel`.

`fit_fixed_light_head` fits it for a given light on some training rows and scores others:
the head the estimator keeps is the one it fits on every row.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from mux_classifier.estimator import fit_linear
from mux_classifier.gated_head import NO_SAMPLES_SCORE, fit_gated_linear
from mux_classifier.learned_model import LearnedModel
from mux_classifier.ratio_stats import OFFSET_FRACTION, ratio_stats

from ..data import class_type_groups
from ..evaluation import CandidateEvaluator
from ..rendering import SearchData, add_noise, clean_led_images, image_features, standard_normal
from .params import Head
from .streams import head_rng

__all__ = ['FEATURES', 'learned_data', 'ratio_offset', 'stack_features', 'head_features',
           'fit_head', 'fit_fixed_light_head', 'fit_head_on_rows', 'fixed_light_draws']

# the statistics a learned model classifies with (the inner splits and the head score them)
FEATURES = 'intensity_stats'


def learned_data(data: SearchData) -> SearchData:
    """`data` scored with the statistics the learned model classifies with."""
    return data if data.features == FEATURES else replace(data, features=FEATURES)


def ratio_offset(data: SearchData, cross_image: bool) -> float:
    """The cross-image statistics' offset (gray levels), 0 without them."""
    return float(OFFSET_FRACTION * data.max_level) if cross_image else 0.0


def stack_features(data: SearchData, images: np.ndarray, offset: float) -> np.ndarray:
    """Raw features (n, k * 9 [+ cross-image]) of images (k, n, pixels): each image's
    statistics, then with `offset` > 0 the cross-image ones (`mux_classifier.ratio_stats`)."""
    X = image_features(data, images)
    if not offset:
        return X
    k, n, _ = images.shape
    stacks = images.reshape(k, n, *data.image_shape).transpose(1, 0, 2, 3)
    return np.hstack([X, ratio_stats(stacks, offset)])


def head_features(data: SearchData, first_draw: np.ndarray, patterns: np.ndarray, head: Head,
                  offset: float, seed: int) -> list[np.ndarray]:
    """The samples' features under the patterns, one (n, F) array per noise draw: the
    images `first_draw` (the inner splits' draw), then `head.renders` - 1 draws of a stream
    of their own (a head fitted on one draw may learn that draw's noise with it; measured:
    docs/research/LEARNED_PATH.md). Data without noise has one draw (the others would be
    copies)."""
    parts = [stack_features(data, first_draw, offset)]
    renders = int(head.renders) if data.noise_a or data.noise_b else 1
    if renders > 1:
        clean = clean_led_images(data, patterns)
        rng = head_rng(seed)
        for _ in range(renders - 1):
            noisy = add_noise(data, clean, standard_normal(rng, clean.shape))
            parts.append(stack_features(data, noisy, offset))
    return parts


def fit_head(X: np.ndarray, y: np.ndarray, class_names, patterns: np.ndarray, head: Head,
             offset: float, seed: int) -> LearnedModel:
    """Linear SVMs (`fit_linear`, as `MuxClassifier` fits them: statistics z-scored over the
    samples each is fitted on) on raw features X (m, F) of labels y, flat or gated by object
    type (`head.kind`, `data.class_type_groups`), as a `LearnedModel` with one linear layer
    on the raw statistics. A class without samples in y scores `NO_SAMPLES_SCORE`."""
    names = list(class_names)
    groups = class_type_groups(names) if head.kind == 'by_type' else None
    if groups is not None:
        coef, intercept = fit_gated_linear(X, y, groups, C=float(head.C), random_state=int(seed))
        return LearnedModel(patterns, np.zeros(X.shape[1]), np.ones(X.shape[1]),
                            [(coef.T, intercept)], names, ratio_offset=offset,
                            class_groups=groups)
    coef, intercept, classes = fit_linear(X, y, 'linear_svm', C=float(head.C),
                                          random_state=int(seed))
    n_in = coef.shape[1]
    W = np.zeros((n_in, len(names)), np.float64)
    b = np.full(len(names), NO_SAMPLES_SCORE)
    W[:, classes] = coef.T
    b[classes] = intercept
    return LearnedModel(patterns, np.zeros(n_in), np.ones(n_in), [(W, b)], names,
                        ratio_offset=offset)


def fit_fixed_light_head(data: SearchData, patterns, train, test, *, head: Head = Head(),
                         cross_image: bool = True,
                         seed: int = 0) -> tuple[LearnedModel, np.ndarray]:
    """The learned head for a fixed light, fitted on some rows and scoring others: the
    samples of `data` rendered under `patterns` (32, k) as the estimator renders them for
    its head (`head_features` with the noise of the inner splits' evaluator of `seed`),
    the head fitted on the rows `train` of every draw (`fit_head`), and the per-class
    scores (`LearnedModel.scores_from_features`, argmax = the label) of the rows `test` on
    the inner splits' draw. `train` / `test`: row indices or boolean masks over the samples.
    With `train` every row, the model is the estimator's `model_` for that light (same
    head, cross_image = its `ratio_stats` and seed). Returns (model, scores (len(test),
    classes))."""
    data, P, offset, draws = fixed_light_draws(data, patterns, head=head,
                                               cross_image=cross_image, seed=seed)
    rows = np.arange(data.n_samples)
    train, test = rows[np.asarray(train)], rows[np.asarray(test)]
    if not train.size:
        raise ValueError('no training rows: the head needs at least one')
    model = fit_head_on_rows(data, P, offset, draws, train, head=head, seed=seed)
    return model, model.scores_from_features(draws[0][test])


def fit_head_on_rows(data: SearchData, P: np.ndarray, offset: float, draws, rows, *,
                     head: Head = Head(), seed: int = 0) -> LearnedModel:
    """`fit_head` on the rows `rows` (indices or a boolean mask) of every draw of
    `fixed_light_draws`' (data, P, offset, draws)."""
    X = np.vstack([d[rows] for d in draws])
    y = np.tile(np.asarray(data.labels)[rows], len(draws))
    return fit_head(X, y, data.class_names, P, head, offset, seed)


def fixed_light_draws(data: SearchData, patterns, *, head: Head = Head(),
                      cross_image: bool = True, seed: int = 0):
    """What `fit_fixed_light_head` fits on, rendered once for any number of row splits:
    (the data scored with the head's statistics, the patterns (32, k) as float32, the
    cross-image offset, `head_features`' draws of every row)."""
    data = learned_data(data)
    P = np.asarray(patterns, np.float32)
    L = data.n_sites * data.n_channels
    if P.ndim != 2 or P.shape[0] != L:
        raise ValueError(f'patterns must be ({L}, k) LED levels, got shape {P.shape}')
    head.check()
    offset = ratio_offset(data, cross_image)
    first = CandidateEvaluator(data, mode='joint', n_repeats=1, seed=int(seed)).images(P)
    return data, P, offset, head_features(data, first, P, head, offset, seed)
