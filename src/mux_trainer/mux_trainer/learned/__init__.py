"""Learned illumination: LED levels chosen through the image formation, with a linear
classifier (docs/LEARNED.md).

The patterns are a (32, k) matrix of LED levels, graded or on/off (``binary``: runs on
``pwm_bits = 0`` firmware), one image per column (k exposures = k images, the budget of the
other methods: greedy's per-colour column is 4 images). Candidate lights are rendered for
the training samples, described by the 9 pose-robust object statistics of
`intensity_stats` per image and by default the cross-image relief statistics of every pair
(`mux_classifier.ratio_stats`), and scored by the greedy search's own inner splits with the
exact linear SVM; the best is kept and a linear head is fitted on it.

Modules:
    params      the method's setting groups: `Starts`, `Descent`, `Head` (beside the
                search's `SplitScoring`, `Rendering`, `Execution`)
    statistics  the statistics in JAX, differentiable in the gray levels
    starts      the candidate lights made without gradient (random, per-colour,
                raking sides; the SNR-optimal and greedy ones come from those methods)
    descent     gradient steps on the LED logits: the pose-held-out ridge loss, Adam (optax)
    head        the final classifier (flat or gated by object type), also for a fixed
                light on some rows (`fit_fixed_light_head`)
    streams     the method's random streams
    estimator   `LearnedIlluminationClassifier`, the scikit-learn-style estimator

`evaluate_learned_heldout` (held-out accuracy under the rules of every method) lives in
`holdout` beside `evaluate_heldout`. Importing this package imports JAX.
"""
from ..holdout import evaluate_learned_heldout
from .descent import (adam, cv_ridge_loss, descend, inner_folds, instance_folds, levels,
                      logits_of, pose_folds)
from .estimator import LearnedIlluminationClassifier
from .head import (FEATURES, fit_fixed_light_head, fit_head, head_features, ratio_offset,
                   stack_features)
from .params import BUILTIN_STARTS, DEFAULT_FINE_TUNE, HEADS, Descent, Head, Starts
from .starts import (low_side_splits, opposite_low_sides, per_colour_start, raking_name,
                     raking_sides_start, random_start)
from .statistics import image_stats, stack_ratio_stats, stack_stats
from .streams import HEAD_NOISE_STREAM, LEARNED_STREAM, inner_seeds, raking_rng

__all__ = [
    'LearnedIlluminationClassifier', 'Starts', 'Descent', 'Head',
    'BUILTIN_STARTS', 'DEFAULT_FINE_TUNE', 'HEADS', 'FEATURES',
    'evaluate_learned_heldout', 'fit_fixed_light_head', 'fit_head', 'head_features',
    'stack_features', 'ratio_offset',
    'image_stats', 'stack_stats', 'stack_ratio_stats',
    'per_colour_start', 'random_start', 'low_side_splits', 'opposite_low_sides', 'raking_name',
    'raking_sides_start',
    'levels', 'logits_of', 'pose_folds', 'instance_folds', 'inner_folds', 'cv_ridge_loss',
    'adam', 'descend',
    'LEARNED_STREAM', 'HEAD_NOISE_STREAM', 'inner_seeds', 'raking_rng',
]
