"""Learned illumination as a method beside the others: built from the same options,
written to the same artifact, evaluated into the same Table 1 row.

`build_learned` makes the `learned.LearnedIlluminationClassifier` of `lightstage train
--method learned` (and the trainer node's `method: learned`), `learned_artifact` its
trained artifact (format 4, 5 with cross-image statistics, 6 with a head gated by object
type: the numpy `LearnedModel`'s arrays, `artifact.TrainedArtifact.from_learned`),
`learned_summary` its held-out result for `lightstage eval`, one model per exposure count.
JAX is imported only when a model is built (`learned`), so importing this module costs
nothing.
"""
from __future__ import annotations

import time

import numpy as np


def build_learned(n_images=8, *, binary=False, steps=None, noise='sigma3',
                  hog_config=None, seed=0, progress=False, n_repeats=400,
                  inner_groups='auto', callback=None, **params):
    """The unfitted learned-illumination estimator from the options of `lightstage train`
    and `lightstage eval`: ``n_images`` exposures (one image per learned pattern), graded
    or on/off (``binary``) LED levels, ``steps`` gradient steps (None: `DEFAULT_STEPS`) on
    ``params``' descent group (default `learned.Descent()`), camera ``noise`` and
    ``hog_config`` (the rendering), ``n_repeats`` inner splits holding out what
    ``inner_groups`` says, ``progress`` lines; ``params``: more of its constructor's
    (starts, head, ratio_stats, ...). The estimator checks every setting when it fits."""
    from .learned import Descent, LearnedIlluminationClassifier
    from .learned.head import FEATURES
    from .search_params import Execution, Rendering, SplitScoring
    descent = params.pop('descent', Descent())
    if steps is not None:
        descent = descent.replace(max_steps=int(steps))
    return LearnedIlluminationClassifier(
        n_images=int(n_images), binary=bool(binary), descent=descent, seed=int(seed),
        scoring=SplitScoring(n_repeats=int(n_repeats), inner_groups=inner_groups),
        rendering=Rendering(noise=noise, hog_config=hog_config, features=FEATURES),
        execution=Execution(progress=bool(progress)), callback=callback, **params)


def describe_choice(chosen: str, max_steps: int = 0) -> str:
    """What a fitted model's `chosen_` candidate is, in words: 'random+200' is 200 gradient
    steps from the random start, 'per_colour' a start kept as it is (the best scored of the
    starts; with ``max_steps`` > 0, also better than every snapshot of the descents)."""
    start, _, steps = str(chosen).partition('+')
    if steps:
        return f'{chosen}: {steps} gradient steps from the {start} start'
    if int(max_steps) > 0:
        return f'{chosen}: a start kept as it is, no snapshot of the gradient steps scored better'
    return f'{chosen}: the start the inner splits score best, kept as it is (no gradient steps)'


def progress_text(event: dict) -> str:
    """One `LearnedIlluminationClassifier` progress event (its `callback`) in words."""
    kind, start = event['event'], event.get('start', '')
    if kind == 'start':
        return f'learned: start {event["index"]} of {event["of"]} ({start}): scoring'
    if kind == 'start_scored':
        return (f'learned: start {event["index"]} of {event["of"]} ({start}): inner accuracy '
                f'{event["accuracy"]:.3f}')
    if kind == 'start_column':
        state = 'chosen' if event['done'] else 'searching'
        return f'learned: greedy start, column {event["column"]} of {event["of"]}: {state}'
    if kind == 'start_candidates':
        return (f'learned: greedy start, column {event["column"]}: {event["done"]} of '
                f'{event["of"]} candidates scored')
    if kind == 'step':
        return (f'learned: {start} + {event["step"]} of {event["of"]} gradient steps: inner '
                f'accuracy {event["accuracy"]:.3f}')
    return f'learned: {kind}'


def head_name(model) -> str:
    """The fitted model's head: 'by_type' (gated by object type) or 'flat'."""
    return 'flat' if model.model_.class_groups is None else 'by_type'


def level_kind(patterns) -> str:
    """'on/off' when every LED level of the patterns is 0 or 1, else 'graded'."""
    P = np.asarray(patterns, dtype=np.float64)
    return 'on/off' if bool(np.all((P == 0) | (P == 1))) else 'graded'


def pattern_levels(patterns) -> list:
    """LED levels as JSON (rounded to 1/1000: a graded board has 1/255 steps)."""
    return np.round(np.asarray(patterns, dtype=np.float64), 3).tolist()


def learned_artifact(model, provenance: dict | None = None):
    """The trained artifact of a fitted learned model (the classifier node's file)."""
    from mux_classifier.artifact import TrainedArtifact
    from mux_classifier.hog import HogConfig
    prov = {'method': 'learned', 'binary': bool(model.binary), 'seed': int(model.seed),
            'max_steps': int(model.descent.max_steps), 'best_step': int(model.best_step_),
            'chosen': str(model.chosen_),
            'head': head_name(model),
            'levels': level_kind(model.patterns_),
            'n_repeats': int(model.scoring.n_repeats),
            'inner_estimate': dict(model.inner_estimate_),
            'accuracy_by_patterns': {str(k): float(v)
                                     for k, v in model.accuracy_by_images_.items()},
            'best_n_patterns': int(model.best_n_patterns_)}
    prov.update(provenance or {})
    return TrainedArtifact.from_learned(
        model.model_, noise=model.noise_, hog_config=model.rendering.hog_config or HogConfig(),
        provenance=prov, dimmer=model.rendering.dimmer)


def learned_summary(models: dict, test_data, n_renders: int = 4, seed: int = 0,
                    train_seconds: float | None = None) -> dict:
    """The Table 1 result of learned models {exposures: fitted model}: held-out accuracy
    of each (`holdout.evaluate_learned_heldout`: the test-noise stream of every method),
    the row at the count whose inner split accuracy (training poses only) is best,
    fewer images on a tie -- the other methods choose theirs on training data too."""
    from .holdout import accuracy_by_type, evaluate_learned_heldout, test_images
    results = {k: evaluate_learned_heldout(model, test_data, n_renders, seed)
               for k, model in sorted(models.items())}
    search = {k: float(m.accuracy_by_images_[k]) for k, m in models.items()}
    best = max(sorted(models), key=lambda k: search[k])
    chosen = models[best]
    # features + head per sample (as the other methods report it: not the rendering)
    images = test_images(test_data, 'joint', chosen.patterns_, 0, seed)
    t0 = time.perf_counter()
    chosen.predict_images(images)
    infer_ms = (time.perf_counter() - t0) * 1e3 / test_data.n_samples
    out = {
        'accuracy': results[best]['accuracy'], 'n_images': int(best),
        'images_per_pattern': 1, 'n_exposures': int(best),
        'accuracy_by_type': accuracy_by_type(test_data, results[best]['correct']),
        'accuracy_by_images': {str(k): r['accuracy'] for k, r in results.items()},
        'search_accuracy_by_images': {str(k): a for k, a in sorted(search.items())},
        'mode': 'learned', 'binary': bool(chosen.binary), 'head': head_name(chosen),
        'levels': level_kind(chosen.patterns_), 'features': 'intensity_stats',
        'cross_image_stats': bool(chosen.model_.ratio_offset),
        'inner_estimate': dict(chosen.inner_estimate_),
        'patterns': pattern_levels(chosen.patterns_),
        'infer_ms_per_sample': float(infer_ms),
        'best_step_by_images': {str(k): int(m.best_step_) for k, m in sorted(models.items())},
    }
    if train_seconds is not None:
        out['train_seconds'] = float(train_seconds)
    return out
