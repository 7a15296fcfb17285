"""Calibrated probabilities and the anytime stop rule, fitted on held-out inner answers.

After a pattern model (greedy, SNR-optimal, naive) has chosen its patterns, its final
classifier is refitted on the training side of some of its inner splits (held out by
physical sample when the capture has two or more per class, else by pose: the splits the
selection used, `splits.inner_splits`) and scores the held-out side, for every column count.
Those held-out scores fit, per image count, the temperature of `confidence.Confidence`
(softmax of scores / T, minimising the log loss), and choose the anytime rule's target: the
lowest mean number of images whose accuracy stays within ``tolerance`` of the full count's.

Why temperature scaling: the label never changes (it keeps the ranking of the scores), one
parameter per image count fits on a few hundred held-out answers, and multi-class margins
need no one-vs-rest recombination (scikit-learn's sigmoid / isotonic calibration calibrate
each class apart and renormalise).
"""
from __future__ import annotations

import math

import numpy as np
from joblib import Parallel, delayed
from mux_classifier.confidence import (Confidence, anytime_outcomes, expected_calibration_error,
                                       softmax)
from scipy.optimize import minimize_scalar

__all__ = ["ACCEPT_PROBABILITY", "DEFAULT_SPLITS", "DEFAULT_TOLERANCE", "calibrate_learned_model",
           "calibrate_pattern_model", "choose_stop", "confidence_from_scores",
           "calibration_error_floor", "coverage_curve", "evaluate_anytime", "fit_temperature",
           "held_out_scores", "pooled_calibration_error", "reliability_bins",
           "answers_figures", "evaluate_learned_answers"]

DEFAULT_SPLITS = 8        # inner splits refitted per column count
DEFAULT_TOLERANCE = 0.01  # accuracy the anytime rule may give up against the full count


def fit_temperature(scores: np.ndarray, labels: np.ndarray) -> float:
    """The temperature T minimising the log loss of softmax(scores / T) on (scores (n, C),
    labels (n,) class indices), searched over log T in [-3, 3] (decades). Where every
    answer is right, the log loss has no minimum inside (it falls as T -> 0, every later
    answer, wrong ones too, at a probability of 1): T is then the one whose mean top
    probability is (n + 1) / (n + 2), Laplace's rule of succession."""
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(labels, dtype=int)

    def loss(log_t: float) -> float:
        p = softmax(scores, 10.0 ** log_t)[np.arange(labels.size), labels]
        return float(-np.log(np.clip(p, 1e-300, None)).mean())

    def mean_top(log_t: float) -> float:
        return float(softmax(scores, 10.0 ** log_t).max(axis=1).mean())

    log_t = minimize_scalar(loss, bounds=(-3.0, 3.0), method="bounded",
                            options={"xatol": 1e-4}).x
    right = int((scores.argmax(axis=1) == labels).sum())
    bound = (right + 1) / (labels.size + 2)
    if right == labels.size and mean_top(log_t) > bound:  # falls as T grows: bisect
        lo, hi = log_t, 3.0
        for _ in range(60):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if mean_top(mid) > bound else (lo, mid)
        log_t = hi
    return float(10.0 ** log_t)


def _fit_and_score(make_classifier, X, y, test):
    clf = make_classifier().fit_features(X[~test], y[~test])
    return clf.decision_function_features(X[test])


def held_out_scores(model, n_splits: int = DEFAULT_SPLITS) -> tuple[dict, np.ndarray, dict]:
    """Scores of the held-out side of the model's first ``n_splits`` inner splits.

    Returns ({image count: scores (m, n_classes)}, class indices (m,), the splits'
    description). Row j is the same held-out answer at every count (the same splits), so the
    anytime rule can be replayed on them.
    """
    ev = model.evaluator_
    data = ev.data
    labels = np.asarray(data.labels, dtype=int)
    masks = _usable_masks(ev.test_masks[:max(1, int(n_splits))], labels)
    columns = model.patterns_
    per_column = int(model.images_per_pattern)
    counts = list(range(1, columns.shape[1] + 1))
    features = {c: ev.features(columns[:, :c]) for c in counts}
    jobs = [(c, i) for c in counts for i in range(len(masks))]
    parts = Parallel(n_jobs=model.execution.n_jobs)(
        delayed(_fit_and_score)(lambda: model._make_classifier(data), features[c], labels,
                                masks[i]) for c, i in jobs)
    by_count = {c: np.vstack([parts[jobs.index((c, i))] for i in range(len(masks))])
                for c in counts}
    y = np.concatenate([labels[m] for m in masks])
    description = {**ev.inner_, 'calibration_splits': len(masks)}
    return {c * per_column: s for c, s in by_count.items()}, y, description


# The targets the anytime rule chooses from: a short grid keeps the choice stable on a few
# hundred held-out answers and the target readable ("stops at 95 %").
STOP_TARGETS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999)
# The target of a classifier with one image count (naive, a learned model): nothing to stop
# early, so the target only says which answers are accepted; calibrated, 9 in 10 of them are
# right, the rest are "not sure".
ACCEPT_PROBABILITY = 0.9


def choose_stop(probabilities_by_step: list[np.ndarray], steps: list[int], labels: np.ndarray,
                tolerance: float = DEFAULT_TOLERANCE) -> tuple[float, dict]:
    """The anytime target: of `STOP_TARGETS`, the one with the fewest mean images whose
    accuracy on these held-out answers stays within ``tolerance`` of the full count's (ties:
    the higher target; none within: the highest, which stops early only when nearly sure);
    with one image count, `ACCEPT_PROBABILITY`.
    Returns (target, what it measured)."""
    labels = np.asarray(labels, dtype=int)
    steps = np.asarray(steps)
    full_accuracy = float((probabilities_by_step[-1].argmax(axis=1) == labels).mean())
    if len(steps) == 1:
        return ACCEPT_PROBABILITY, {'full_images': int(steps[-1]), 'full_accuracy': full_accuracy,
                                    'anytime_accuracy': full_accuracy,
                                    'anytime_mean_images': float(steps[-1])}
    chosen = None
    for t in sorted(STOP_TARGETS, reverse=True):
        stop, predicted, _ = anytime_outcomes(probabilities_by_step, t)
        accuracy = float((predicted == labels).mean())
        mean_images = float(steps[stop].mean())
        if chosen is None or (accuracy >= full_accuracy - tolerance - 1e-12
                              and mean_images < chosen[1] - 1e-12):
            chosen = (t, mean_images, accuracy)
    target, mean_images, accuracy = chosen
    return target, {'full_images': int(steps[-1]), 'full_accuracy': full_accuracy,
                    'anytime_accuracy': accuracy, 'anytime_mean_images': mean_images}


def calibrate_pattern_model(model, n_splits: int = DEFAULT_SPLITS,
                            tolerance: float = DEFAULT_TOLERANCE) -> Confidence:
    """The `Confidence` of a fitted pattern model (greedy, SNR-optimal, naive): a temperature
    per image count and the anytime target, from its held-out inner answers."""
    _check_tolerance(tolerance)
    scores, labels, description = held_out_scores(model, n_splits)
    return confidence_from_scores(scores, labels, description, tolerance)


def calibrate_learned_model(model, n_splits: int = DEFAULT_SPLITS,
                            tolerance: float = DEFAULT_TOLERANCE) -> Confidence:
    """The `Confidence` of a fitted learned model (`mux_trainer.learned`): its head refitted
    for the kept light (`learned.head.fit_fixed_light_head`'s fit, its renders made once) on
    the training side of its first ``n_splits`` inner splits (held out by physical sample
    where the capture has two or more per class), the held-out scores
    fitting the temperature of its one image count; accepted at `ACCEPT_PROBABILITY`."""
    from .learned.head import fit_head_on_rows, fixed_light_draws
    _check_tolerance(tolerance)
    ev = model.evaluator_
    data, P, offset, draws = fixed_light_draws(ev.data, model.patterns_, head=model.head,
                                               cross_image=bool(model.ratio_stats),
                                               seed=int(model.seed))
    labels = np.asarray(data.labels, dtype=int)
    masks = _usable_masks(ev.test_masks[:max(1, int(n_splits))], labels)

    def held_out(test):
        head = fit_head_on_rows(data, P, offset, draws, ~test, head=model.head,
                                seed=int(model.seed))
        return head.scores_from_features(draws[0][test])

    parts = Parallel(n_jobs=model.execution.n_jobs)(delayed(held_out)(m) for m in masks)
    k = int(model.best_n_patterns_)
    scores = {k: np.vstack(parts)}
    y = np.concatenate([labels[m] for m in masks])
    description = {**ev.inner_, 'calibration_splits': len(masks)}
    return confidence_from_scores(scores, y, description, tolerance)


def _check_tolerance(tolerance: float) -> None:
    if not 0.0 <= tolerance < 1.0 or math.isnan(tolerance):
        raise ValueError(f"tolerance must be in 0 .. 1, got {tolerance}")


def _usable_masks(masks, labels: np.ndarray) -> list[np.ndarray]:
    """The inner splits' held-out masks that hold something out and keep every class on
    their training side; ValueError when none does."""
    masks = [np.asarray(m, dtype=bool) for m in masks]
    masks = [m for m in masks if m.any() and len(np.unique(labels[~m])) == len(np.unique(labels))]
    if not masks:
        raise ValueError("no inner split keeps every class on its training side: cannot "
                         "calibrate")
    return masks


def confidence_from_scores(scores: dict, labels: np.ndarray, description: dict,
                           tolerance: float = DEFAULT_TOLERANCE) -> Confidence:
    """Temperatures per image count and the anytime target (`choose_stop`) of held-out
    answers: ``scores`` {image count: (m, n_classes)}, the same m answers at every count, of
    class indices ``labels``; ``description`` says how they were held out."""
    steps = sorted(scores)
    temperatures = {k: fit_temperature(scores[k], labels) for k in steps}
    probabilities = [softmax(scores[k], temperatures[k]) for k in steps]
    target, measured = choose_stop(probabilities, steps, labels, tolerance)
    stop, predicted, _ = anytime_outcomes(probabilities, target)
    at_stop = np.stack([probabilities[s][j] for j, s in enumerate(stop)])
    estimate = {**measured, 'answers': int(labels.size),
                'calibration_error_full': expected_calibration_error(probabilities[-1], labels),
                'calibration_error_anytime': expected_calibration_error(at_stop, labels),
                'held_out': description.get('held_out'),
                'calibration_splits': int(description['calibration_splits']),
                'note': 'temperatures fitted and scored on the same held-out answers'}
    return Confidence(temperatures=temperatures, stop_probability=target, tolerance=tolerance,
                      estimate=estimate)


def evaluate_anytime(model, confidence: Confidence, test_data, n_renders: int = 4,
                     seed: int = 0, budget: int | None = None) -> dict:
    """The calibrated anytime rule of a fitted pattern model on held-out renders
    (`holdout.test_features`: noise drawn apart from the training's), beside the full count.

    ``budget``: the most pattern columns a call may take (default: the model's kept count).
    Returns plain JSON: the full count's accuracy, images and calibration error; the anytime
    rule's accuracy, mean images and calibration error; and accuracy against coverage when
    the answers below the target (unsure) are set aside.
    """
    from .holdout import test_features
    per = int(model.images_per_pattern)
    budget = int(model.best_n_patterns_ if budget is None else budget)
    columns = [c for c in range(1, budget + 1) if c * per in confidence.temperatures]
    labels, steps_probs = [], [[] for _ in columns]
    for r in range(int(n_renders)):
        X = test_features(test_data, model.mode, model.patterns_, r, seed)
        for i, c in enumerate(columns):
            clf = model.classifiers_[c]
            scores = clf.decision_function_features(X[:, :clf.n_features_in_])
            steps_probs[i].append(confidence.probabilities(scores, c * per))
        labels.append(np.asarray(test_data.labels))
    y = np.concatenate(labels)
    probabilities = [np.vstack(p) for p in steps_probs]
    steps = np.array([c * per for c in columns])
    return answers_figures(probabilities, steps, y, confidence.stop_probability)


def evaluate_learned_answers(model, confidence: Confidence, test_data, n_renders: int = 4,
                             seed: int = 0) -> dict:
    """`evaluate_anytime` of a fitted learned model (`mux_trainer.learned`, one image count):
    its calibrated answers on held-out renders under its LED levels (`holdout.test_images`,
    the renders `evaluate_learned_heldout` scores)."""
    from .holdout import test_images
    from .learned.head import learned_data, stack_features
    k = int(model.best_n_patterns_)
    data = learned_data(test_data)
    parts, labels = [], []
    for r in range(int(n_renders)):
        images = test_images(test_data, 'joint', model.patterns_, r, seed)
        scores = model.model_.scores_from_features(
            stack_features(data, images, model.model_.ratio_offset))
        parts.append(confidence.probabilities(scores, k))
        labels.append(np.asarray(test_data.labels))
    return answers_figures([np.vstack(parts)], np.array([k]), np.concatenate(labels),
                           confidence.stop_probability)


def answers_figures(probabilities: list[np.ndarray], steps: np.ndarray, y: np.ndarray,
                    stop_probability: float) -> dict:
    """Plain JSON of calibrated answers: ``probabilities`` per image count ``steps`` (the
    same answers at each), their class indices ``y``, the anytime target."""
    stop, predicted, reached = anytime_outcomes(probabilities, stop_probability)
    at_stop = np.stack([probabilities[s][j] for j, s in enumerate(stop)])
    full = probabilities[-1]
    coverage = {}
    for t in (0.5, 0.8, 0.9, 0.95, 0.99):
        kept = at_stop.max(axis=1) >= t
        coverage[str(t)] = {'share': float(kept.mean()),
                            'accuracy': float((predicted[kept] == y[kept]).mean())
                            if kept.any() else None}
    return {
        'answers': int(y.size), 'budget_images': int(steps[-1]),
        'stop_probability': float(stop_probability),
        'full_accuracy': float((full.argmax(axis=1) == y).mean()),
        'full_calibration_error': expected_calibration_error(full, y),
        'anytime_accuracy': float((predicted == y).mean()),
        'anytime_mean_images': float(steps[stop].mean()),
        'anytime_calibration_error': expected_calibration_error(at_stop, y),
        'full_calibration_error_floor': calibration_error_floor([reliability_bins(full, y)]),
        'anytime_calibration_error_floor': calibration_error_floor(
            [reliability_bins(at_stop, y)]),
        'accepted_share': float(reached.mean()),
        'accepted_accuracy': float((predicted[reached] == y[reached]).mean())
        if reached.any() else None,
        'coverage': coverage,
        'coverage_curve': coverage_curve(at_stop, y),
        'reliability': {'full': reliability_bins(full, y),
                        'anytime': reliability_bins(at_stop, y)},
    }


def reliability_bins(probabilities: np.ndarray, labels: np.ndarray,
                     n_bins: int = 10) -> list[dict]:
    """The reliability diagram of the top-class probability: per equal-width confidence bin
    with answers in it, its range, the answers, their mean confidence and their accuracy
    (`expected_calibration_error` is the answer-weighted mean of the gaps)."""
    p = np.asarray(probabilities, dtype=np.float64)
    y = np.asarray(labels)
    top = p.max(axis=1)
    correct = p.argmax(axis=1) == y
    edges = np.linspace(0.0, 1.0, int(n_bins) + 1)
    which = np.clip(np.digitize(top, edges[1:-1], right=True), 0, int(n_bins) - 1)
    return [{'low': float(edges[b]), 'high': float(edges[b + 1]), 'answers': int(inside.sum()),
             'confidence': float(top[inside].mean()), 'accuracy': float(correct[inside].mean())}
            for b in range(int(n_bins)) if (inside := which == b).any()]


def calibration_error_floor(reliabilities: list[list[dict]]) -> float:
    """About the calibration error a perfectly calibrated classifier would measure with the
    same confidences on as many answers, from `reliability_bins` (one or several
    evaluations' together): in a bin of n answers at confidence c, the right answers of a
    calibrated classifier miss n c by sqrt(2 n c (1 - c) / pi) on average (normal
    approximation). A measured error near it is as small as that many answers can show; a
    target below it cannot be verified on them. Renders of one object count as apart, so
    where they are alike the true floor is higher."""
    by_bin = _pooled_bins(reliabilities)
    total = sum(n for n, _, _ in by_bin.values())
    return float(sum(math.sqrt(2.0 * n * (conf / n) * (1.0 - conf / n) / math.pi)
                     for n, conf, _ in by_bin.values()) / total)


def _pooled_bins(reliabilities: list[list[dict]]) -> dict:
    by_bin: dict = {}
    for bins in reliabilities:
        for b in bins:
            n, conf, acc = by_bin.get(b['low'], (0, 0.0, 0.0))
            by_bin[b['low']] = (n + b['answers'], conf + b['answers'] * b['confidence'],
                                acc + b['answers'] * b['accuracy'])
    return by_bin


def pooled_calibration_error(reliabilities: list[list[dict]]) -> float:
    """The calibration error of several evaluations' answers taken together, from their
    `reliability_bins` (the same bin edges): what one evaluation of all the answers would
    measure."""
    by_bin = _pooled_bins(reliabilities)
    total = sum(n for n, _, _ in by_bin.values())
    return float(sum(abs(acc - conf) for _, conf, acc in by_bin.values()) / total)


COVERAGE_STEPS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


def coverage_curve(probabilities: np.ndarray, labels: np.ndarray,
                   steps=COVERAGE_STEPS) -> list[dict]:
    """Accuracy against coverage: the answers kept most sure first (by top-class
    probability), at each share of them kept; what a user gets by setting the least sure
    answers aside (to a person, or another look)."""
    p = np.asarray(probabilities, dtype=np.float64)
    y = np.asarray(labels)
    order = np.argsort(-p.max(axis=1), kind='stable')
    correct = (p.argmax(axis=1) == y)[order]
    out = []
    for share in steps:
        n = max(1, int(round(float(share) * len(correct))))
        out.append({'coverage': n / len(correct), 'accuracy': float(correct[:n].mean()),
                    'min_probability': float(p.max(axis=1)[order][n - 1])})
    return out
