"""Learned illumination: LED levels learned through the image formation, with a linear classifier.

The patterns are a (32, k) matrix of LED levels, ``sigmoid(theta)`` (graded) or its
straight-through binarisation (``binary=True``: on/off, runs on ``pwm_bits = 0``
firmware), one image per column (k exposures = k images, the budget of the other methods:
greedy's per-colour column is 4 images). Each training step renders a batch of training
samples under the current levels (`lightstage_physics.render_jax`: the relit images as
`rendering.clean_led_images`, the calibrated affine noise drawn afresh by
reparameterisation, the saturation clip, at the classifier's 120 px), computes per image
the 9 pose-robust object statistics of `intensity_stats` made differentiable
(`image_stats`) and z-scores them; the training criterion's gradient reaches the LED levels
through the statistics and the image formation.

Why these features and not a CNN: the captures hold 6-20 poses per class, objects lying
anywhere and any way; the statistics ignore where the object lies by construction (a CNN
would have to learn that from a handful of poses), they are what the greedy search scores
with on free placement (`--features intensity_stats`), so a comparison isolates what
learning the light adds, and they are cheap (two sorts per image) and exact to reproduce
in numpy for the node (`mux_classifier.learned_model`). A small CNN over the images was
measured: 65-82 % where the statistics give 97 %, 15 training samples per class
(docs/research/LEARNED_PATH.md).
By default (`ratio_stats`) statistics across images follow (`mux_classifier.ratio_stats`,
in JAX `stack_ratio_stats`): per pair, the log ratio's spread and gradient, which a
relief's shading keeps and a print of it does not.

Training (why: docs/LEARNED.md, "Candidate lights and how one is kept"). Candidate lights are scored with the
greedy search's own inner splits and the exact linear SVM on them
(`evaluation.CandidateEvaluator` in the joint mode) and the best is kept (a tie keeps the
earlier): the starts (a random graded light with every LED partly on, the per-colour
start, the SNR-optimal baseline's site columns expanded to LED levels, greedy's columns,
a raking-sides light per split of the rig's low sites, any the caller gives) and, with
``max_steps`` > 0 (0 by default: no descent was ever kept), snapshots of gradient steps from some of them.
The steps run on the training samples (a fresh noise draw each step, Adam on the LED
logits) against the pose-held-out loss of a closed-form ridge classifier (`cv_ridge_loss`:
per fold of training poses, the head solved on the other poses, its squared hinge on the
fold's), so the light is asked for what the inner splits measure: separation that holds on
poses it was not fitted on.
The final classifier is greedy's kind: a linear SVM on the chosen patterns' rendered
training statistics (`head_renders` noise draws), stored as one linear layer. The shrunk
Fisher criterion and cross-entropy through a head trained alongside remain as `objective`
options.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
from joblib import Parallel
from lightstage_physics.render_jax import add_noise, relight
from lightstage_physics.rig import CHANNELS, Rig, site_to_led_patterns
from mux_classifier.estimator import fit_linear
from mux_classifier.gated_head import NO_SAMPLES_SCORE, fit_gated_linear
from mux_classifier.intensity_stats import GRADIENT_QUANTILES, LEVEL_QUANTILES, N_STATS
from mux_classifier.learned_model import LearnedModel
from mux_classifier.object_mask import image_masks
from mux_classifier.ratio_stats import (OFFSET_FRACTION, n_ratio_stats, object_masks,
                                        pair_ratio_stats, ratio_stats)

from .baselines import SnrOptimalClassifier
from .data import class_type_groups, search_data
from .evaluation import CandidateEvaluator
from .greedy import GreedyPatternSelector
from .holdout import test_images
from .learned_schedule import DEFAULT_STEPS
from .rendering import SearchData, clean_led_images, image_features, standard_normal
from .rendering import add_noise as add_noise_images
from .search_params import SplitScoring
from .split_scoring import SCORERS
from .splits import check_inner_groups, resolve_inner_groups

# criteria for the light's gradient steps (docs/LEARNED.md, "Gradient steps on the
# levels"): the pose-held-out ridge classifier's squared hinge (default), the shrunk Fisher
# criterion, cross-entropy through a head trained alongside
OBJECTIVES = ('cv_ridge', 'fisher', 'cross_entropy')
HEADS = ('by_type', 'flat')
BUILTIN_STARTS = ('random', 'per_colour', 'snr_optimal', 'greedy', 'raking_sides')
HEAD_NOISE_STREAM = 5   # the head's extra noise draws (`_head_features`)
# seed-sequence tag of every random stream of the learned method (apart from the search's)
LEARNED_STREAM = 26
INNER_DRAW_STREAM = 7   # the seeds of the inner splits' further draws (`inner_seeds`)
_LEVEL_F = np.array(LEVEL_QUANTILES, np.float32) / 100
_GRAD_F = np.array(GRADIENT_QUANTILES, np.float32) / 100


# --- differentiable features --------------------------------------------------------------

def _ranks(count: int, fractions: np.ndarray):
    """np.percentile's linear rule over `count` sorted values: the order statistics around
    each fraction (2 per fraction: lower, upper) and the interpolation weights."""
    pos = fractions.astype(np.float64) * (count - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, count - 1)
    return np.stack([lo, hi], axis=1).reshape(-1), (pos - lo).astype(np.float32)


def _object_order(images: np.ndarray, grads: np.ndarray, image_shape):
    """The non-differentiable part of the statistics, in numpy (a host callback: XLA's CPU
    sort is ~10 x slower than numpy's partition): each image's object mask
    (`object_mask.image_masks`, the rule of `intensity_stats`; none: the whole image) and
    the pixel indices and weights of the order statistics that the quantiles of the
    object's levels and gradient magnitudes interpolate."""
    N, P = images.shape
    mask = image_masks(images.reshape(N, *image_shape)).reshape(N, P)
    mask[~mask.any(axis=1)] = True
    level_idx = np.empty((N, 2 * len(_LEVEL_F)), np.int32)
    level_t = np.empty((N, len(_LEVEL_F)), np.float32)
    grad_idx = np.empty((N, 2 * len(_GRAD_F)), np.int32)
    grad_t = np.empty((N, len(_GRAD_F)), np.float32)
    for i in range(N):
        obj = np.flatnonzero(mask[i])
        for values, fractions, idx, t in ((images[i], _LEVEL_F, level_idx, level_t),
                                          (grads[i], _GRAD_F, grad_idx, grad_t)):
            ranks, t[i] = _ranks(obj.size, fractions)
            order = np.argpartition(values[obj], ranks)
            idx[i] = obj[order[ranks]]
    return mask, level_idx, level_t, grad_idx, grad_t


def _gathered_quantiles(values, idx, t):
    v = jnp.take_along_axis(values, idx, axis=1).reshape(idx.shape[0], -1, 2)
    return v[:, :, 0] + (v[:, :, 1] - v[:, :, 0]) * t


def image_stats(images: jnp.ndarray, image_shape) -> jnp.ndarray:
    """`intensity_stats_images_numpy` in JAX, differentiable in the gray levels: images
    (N, pixels) -> (N, 9): over each image's object (brighter than its median by a quarter
    of the way to its 99th percentile; none: the whole image) the level quantiles
    10/25/50/75/90 %, the mean level, the mean gradient magnitude and its quantiles 50/90 %.

    Where the object lies and which pixels are the order statistics are found without
    gradient (`_object_order`); the quantiles are then those pixels' values interpolated,
    so the gradient flows to them, as it does through a sort."""
    N, P = images.shape
    H, W = image_shape
    img = images.reshape(N, H, W)
    gr = jnp.pad(img[:, 2:, :] - img[:, :-2, :], ((0, 0), (1, 1), (0, 0)))
    gc = jnp.pad(img[:, :, 2:] - img[:, :, :-2], ((0, 0), (0, 0), (1, 1)))
    sq = (gr * gr + gc * gc).reshape(N, P)
    positive = sq > 0
    grad = jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)  # finite gradient at 0
    n_l, n_g = len(_LEVEL_F), len(_GRAD_F)
    shapes = (jax.ShapeDtypeStruct((N, P), jnp.bool_),
              jax.ShapeDtypeStruct((N, 2 * n_l), jnp.int32), jax.ShapeDtypeStruct((N, n_l), jnp.float32),
              jax.ShapeDtypeStruct((N, 2 * n_g), jnp.int32), jax.ShapeDtypeStruct((N, n_g), jnp.float32))
    mask, level_idx, level_t, grad_idx, grad_t = jax.pure_callback(
        lambda x, g: _object_order(np.asarray(x), np.asarray(g), (H, W)), shapes,
        jax.lax.stop_gradient(images), jax.lax.stop_gradient(grad))
    n_obj = mask.sum(axis=1).astype(jnp.float32)
    mean = jnp.where(mask, images, 0.0).sum(axis=1) / n_obj
    grad_mean = jnp.where(mask, grad, 0.0).sum(axis=1) / n_obj
    return jnp.concatenate([_gathered_quantiles(images, level_idx, level_t), mean[:, None],
                            grad_mean[:, None], _gathered_quantiles(grad, grad_idx, grad_t)],
                           axis=1)


def stack_stats(images: jnp.ndarray, image_shape) -> jnp.ndarray:
    """Images (k, n, pixels) -> features (n, k * 9), image order (the prefix layout)."""
    k, n, P = images.shape
    f = image_stats(images.reshape(k * n, P), image_shape).reshape(k, n, N_STATS)
    return f.transpose(1, 0, 2).reshape(n, k * N_STATS)


def stack_ratio_stats(images: jnp.ndarray, image_shape, offset: float) -> jnp.ndarray:
    """`ratio_stats` in JAX, differentiable in the gray levels: images (k, n, pixels) ->
    (n, 2 * k (k - 1) / 2). The stack's object mask is found without gradient (numpy,
    `ratio_stats.object_masks`), as the statistics' masks are."""
    k, n, P = images.shape
    img = images.reshape(k, n, *image_shape)
    mask = jax.pure_callback(
        lambda x: object_masks(np.asarray(x).transpose(1, 0, 2, 3)),
        jax.ShapeDtypeStruct((n, *image_shape), jnp.bool_), jax.lax.stop_gradient(img))
    log_images = jnp.log(jnp.maximum(img, 0) + jnp.float32(offset))
    return pair_ratio_stats(jnp, log_images, mask.astype(jnp.float32), 1e-12)


# --- the model --------------------------------------------------------------------------

def levels(theta: jnp.ndarray, binary: bool) -> jnp.ndarray:
    """LED levels in [0, 1] from the logits theta; binary: 0/1 forward, the sigmoid's
    gradient backward (straight-through)."""
    soft = jax.nn.sigmoid(theta)
    if not binary:
        return soft
    return soft + jax.lax.stop_gradient((soft > 0.5).astype(jnp.float32) - soft)


def head_logits(layers, X):
    """Dense layers with ReLU between them."""
    h = X
    for i, (W, b) in enumerate(layers):
        h = h @ W + b
        if i < len(layers) - 1:
            h = jax.nn.relu(h)
    return h


def forward_features(layers, mean, scale, X):
    """Raw features -> logits (the numpy `LearnedModel.logits_from_features`)."""
    return head_logits(layers, (X - mean) / scale)


def _cross_entropy(logits, y):
    return -jnp.mean(jnp.take_along_axis(jax.nn.log_softmax(logits), y[:, None], axis=1))


def _adam_init(params):
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
    return {'m': zeros, 'v': zeros, 't': jnp.zeros((), jnp.float32)}


def _adam_update(params, grads, state, lr, b1=0.9, b2=0.999, eps=1e-8):
    """Adam (Kingma & Ba) with per-leaf learning rates `lr` (a pytree like params)."""
    t = state['t'] + 1
    m = jax.tree_util.tree_map(lambda m, g: b1 * m + (1 - b1) * g, state['m'], grads)
    v = jax.tree_util.tree_map(lambda v, g: b2 * v + (1 - b2) * g * g, state['v'], grads)
    params = jax.tree_util.tree_map(
        lambda p, m, v, r: p - r * (m / (1 - b1 ** t)) / (jnp.sqrt(v / (1 - b2 ** t)) + eps),
        params, m, v, lr)
    return params, {'m': m, 'v': v, 't': t}


def _init_head(rng, n_in, n_hidden, n_classes):
    sizes = [n_in] + ([n_hidden] if n_hidden else []) + [n_classes]
    return [(jnp.asarray(rng.normal(0, np.sqrt(2.0 / a), (a, b)), jnp.float32),
             jnp.zeros((b,), jnp.float32)) for a, b in zip(sizes[:-1], sizes[1:])]


def per_colour_start(n_sites: int, n_channels: int, k: int, rng) -> np.ndarray:
    """The per-colour start (sites * channels, k), site-major, 0/1: image j lights colour
    j mod 4, at every site for the first four images and at a random half of the sites for
    each later group of four. It keeps the colours apart (a random mixture of colours blurs
    the spectral cue the classes differ by; measured worse in docs/LEARNED.md)."""
    on = np.zeros((n_sites, n_channels, k), np.float32)
    for j in range(k):
        sites = (np.arange(n_sites) if j < n_channels
                 else rng.choice(n_sites, max(1, n_sites // 2), replace=False))
        on[sites, j % n_channels, j] = 1
    return on.reshape(n_sites * n_channels, k)


def low_side_splits(site_positions_mm) -> list[tuple[np.ndarray, np.ndarray]]:
    """The splits of the low sites (elevation at most the median), in azimuth order, into
    two contiguous halves (two groups on two sides of the object), each once, the one whose
    halves' mean horizontal directions are most nearly opposite first (then by that
    measure; ties in azimuth order). Low sites light at a grazing angle, where shallow
    relief casts shading that turns with the light; which axis of the relief shows best
    depends on the object, so each split is a start of its own (`raking_sides_start`)."""
    pos = np.asarray(site_positions_mm, np.float64)
    horizontal = np.hypot(pos[:, 0], pos[:, 1])
    elevation = np.arctan2(pos[:, 2], horizontal)
    low = np.flatnonzero(elevation <= np.median(elevation))
    if low.size < 2:
        low = np.arange(len(pos))
    ring = low[np.argsort(np.arctan2(pos[low, 1], pos[low, 0]))]
    half = ring.size // 2

    def direction(sites):
        v = (pos[sites, :2] / np.maximum(horizontal[sites, None], 1e-9)).mean(axis=0)
        return v / max(np.linalg.norm(v), 1e-9)

    splits, seen = [], set()
    for shift in range(ring.size):
        a, b = np.sort(np.roll(ring, -shift)[:half]), np.sort(np.roll(ring, -shift)[half:])
        key = frozenset((tuple(a), tuple(b)))
        if key not in seen:
            seen.add(key)
            splits.append((a, b))
    # a stable sort: equally opposite splits keep their azimuth order
    return sorted(splits, key=lambda ab: float(direction(ab[0]) @ direction(ab[1])))


def opposite_low_sides(site_positions_mm) -> tuple[np.ndarray, np.ndarray]:
    """The two groups of low sites most nearly opposite (`low_side_splits`' first)."""
    return low_side_splits(site_positions_mm)[0]


def raking_name(split: int) -> str:
    """The start's name for the split-th split of the low sites."""
    return 'raking_sides' if split == 0 else f'raking_sides/{split}'


def raking_rng(seed: int, split: int) -> np.random.Generator:
    """The stream of the split-th raking start of a fit with `seed` (its later images'
    random halves), one per split so that no start's draws change another's."""
    return np.random.default_rng([int(seed), LEARNED_STREAM, zlib.crc32(b'raking_sides'), 1 + int(split)])


def raking_sides_start(site_positions_mm, n_channels: int, k: int, rng,
                       split: int = 0) -> np.ndarray:
    """The raking-sides start (sites * channels, k), site-major, 0/1, for k >= 4: every
    colour from one of two groups of low sites on two sides of the object
    (`low_side_splits`, its `split`-th; 0: the most nearly opposite), then from the other
    (relief's shading differs between the two, a flat print's does not), the
    visible colours from every site, NIR from every site (inks that differ in NIR); the
    images after the first four are `per_colour_start`'s (each colour alone). A light a
    person would set up to tell relief and inks apart; measured against the other starts
    in docs/research/LEARNED_PATH.md: not a default start."""
    if n_channels != len(CHANNELS) or k < 4:
        raise ValueError(f'the raking-sides start needs the {len(CHANNELS)} channels '
                         f'{", ".join(CHANNELS)} and k >= 4; got {n_channels} channels, k {k}')
    positions = np.asarray(site_positions_mm, np.float64)
    n_sites = len(positions)
    splits = low_side_splits(positions)
    if not 0 <= int(split) < len(splits):
        raise ValueError(f'split must be in 0..{len(splits) - 1} (the low sites\' splits), got {split}')
    side_a, side_b = splits[int(split)]
    nir = CHANNELS.index('nir')
    visible = [c for c in range(n_channels) if c != nir]
    on = np.zeros((n_sites, n_channels, 4), np.float32)
    on[side_a, :, 0] = 1
    on[side_b, :, 1] = 1
    on[:, visible, 2] = 1
    on[:, nir, 3] = 1
    first = on.reshape(n_sites * n_channels, 4)
    if k == 4:
        return first
    return np.hstack([first, per_colour_start(n_sites, n_channels, k - 4, rng)])


def fisher_loss(F: jnp.ndarray, onehot: jnp.ndarray, shrinkage: float) -> jnp.ndarray:
    """Minus the shrunk Fisher discriminant criterion tr((S_w + shrinkage I)^-1 S_b) of the
    features F (n, d) z-scored over the batch (differentiably, so scaling the light up does
    not pay), classes `onehot` (n, classes). S_w, S_b: within- and between-class scatter;
    every column has unit total variance, so the criterion is the classes' separation
    measured against the noise and pose spread, and its optimum does not depend on a head's
    weights (cross-entropy through a head that is learning at the same time is noisier)."""
    Z = (F - F.mean(axis=0)) / (F.std(axis=0) + 1e-3)
    counts = onehot.sum(axis=0)
    mu = (onehot.T @ Z) / jnp.maximum(counts, 1.0)[:, None]
    n, d = Z.shape
    Sb = (mu.T * counts) @ mu / n
    R = Z - onehot @ mu
    Sw = R.T @ R / n
    return -jnp.trace(jnp.linalg.solve(Sw + shrinkage * jnp.eye(d, dtype=Z.dtype), Sb))


def pose_folds(pose_index: np.ndarray, n_folds: int) -> np.ndarray:
    """Boolean (folds, n) masks of the samples each fold holds out: the pose indices dealt
    round-robin into at most `n_folds` groups (every pose of a fold is held out together, so
    the criterion asks for light that generalises to poses it was not fitted on)."""
    poses = np.unique(pose_index)
    n_folds = max(2, min(int(n_folds), poses.size))
    group = {int(p): i % n_folds for i, p in enumerate(poses)}
    fold_of = np.array([group[int(p)] for p in pose_index])
    return np.stack([fold_of == f for f in range(n_folds)])


def instance_folds(labels: np.ndarray, instance: np.ndarray, n_folds: int) -> np.ndarray:
    """Boolean (folds, n) masks holding out whole physical samples: the sample numbers dealt
    round-robin into at most `n_folds` folds (at least 2, at most the number of distinct
    sample numbers), the same numbers in every class (as `splits.instance_splits`), so
    every sample is held out once: the loss asks for light that tells new objects apart,
    not other poses of the ones fitted on."""
    labels, instance = np.asarray(labels), np.asarray(instance)
    numbers = np.unique(instance)
    n_folds = max(2, min(int(n_folds), numbers.size))
    fold = {int(s): i % n_folds for i, s in enumerate(numbers)}
    fold_of = np.array([fold[int(s)] for s in instance])
    return np.stack([fold_of == f for f in range(n_folds)])


def inner_folds(data: SearchData, n_folds: int, inner_groups: str = 'auto') -> np.ndarray:
    """The loss's folds: `instance_folds` where `splits.resolve_inner_groups` says
    'instances', else `pose_folds`."""
    if resolve_inner_groups(inner_groups, data.labels, data.instance) == 'instances':
        return instance_folds(data.labels, data.instance, n_folds)
    return pose_folds(data.pose_index, n_folds)


def cv_ridge_loss(F: jnp.ndarray, onehot: jnp.ndarray, held_out: jnp.ndarray,
                  ridge: float, class_power: float = 1.0) -> jnp.ndarray:
    """The pose-held-out loss of the classifier greedy's inner splits imitate, in closed
    form: for each fold (`held_out` (folds, n) masks from `pose_folds`) the features F
    (n, d) are z-scored over the fold's training samples, a ridge least-squares classifier
    on +-1 targets is solved on them (`ridge` times the sample count on the diagonal), and
    the squared hinge of its scores is averaged over the held-out samples; the mean over
    folds. Differentiable through the solve, so the light's gradient is that of held-out
    error under the head that is optimal for the light at this step (no head is learned
    alongside), and light that only fits the training poses does not pay.

    `class_power` p: each fold's held-out loss is the power mean over classes of their mean
    held-out loss, weighted by their held-out counts, (sum_c n_c L_c^p / sum_c n_c)^(1/p):
    p = 1 is the mean over the held-out samples; above 1 the classes the light separates
    worst weigh more (a 16-class capture whose errors are one pair)."""
    Y = 2.0 * onehot - 1.0
    p = float(class_power)
    d = F.shape[1]
    eye = jnp.eye(d, dtype=F.dtype)

    def fold(test):
        w = (1.0 - test.astype(F.dtype))[:, None]
        n_train = jnp.maximum(w.sum(), 1.0)
        mu = (F * w).sum(axis=0) / n_train
        # off zero inside the root: a feature constant over a fold keeps a finite gradient
        sd = jnp.sqrt((((F - mu) ** 2) * w).sum(axis=0) / n_train + 1e-6)
        Z = (F - mu) / sd
        Zc = Z - (Z * w).sum(axis=0) / n_train  # centred over the fold's training samples
        Yc = Y - (Y * w).sum(axis=0) / n_train
        W = jnp.linalg.solve((Zc * w).T @ Zc + ridge * n_train * eye, (Zc * w).T @ Yc)
        b = (Y * w).sum(axis=0) / n_train - ((Z * w).sum(axis=0) / n_train) @ W
        hinge = jnp.maximum(0.0, 1.0 - Y * (Z @ W + b)) ** 2
        t = test.astype(F.dtype)[:, None]
        if p == 1.0:
            return (hinge * t).sum() / jnp.maximum(t.sum(), 1.0)
        counts = (onehot * t).sum(axis=0)                    # held-out samples per class
        per_class = (onehot * t).T @ hinge.sum(axis=1) / jnp.maximum(counts, 1.0)
        mean_p = (counts * per_class ** p).sum() / jnp.maximum(counts.sum(), 1.0)
        return mean_p ** (1.0 / p)

    return jnp.mean(jax.vmap(fold)(held_out))


def random_start(data: SearchData, k: int, rng, headroom: float = 0.5) -> np.ndarray:
    """Levels sigmoid(N(0, 1)) per LED and image: every LED partly on, no two images alike
    (a start whose images are equal would keep them equal: the gradient is symmetric). Each
    image's levels are scaled down where its brightest pixels (the 99.9th percentile over
    the samples) would pass `headroom` of the saturation level: no gradient passes a
    saturated pixel, so a start that saturates the object could not learn."""
    L = data.n_sites * data.n_channels
    P = 1.0 / (1.0 + np.exp(-rng.normal(0.0, 1.0, (L, k))))
    rows = rng.choice(data.n_samples, min(64, data.n_samples), replace=False)
    bright = np.percentile(clean_led_images(data.subset(np.sort(rows)), P), 99.9, axis=(1, 2))
    scale = np.minimum(1.0, headroom * data.max_level / np.maximum(bright, 1e-6))
    return (P * scale).astype(np.float32)


def _logits_of(P: np.ndarray, margin: float = 0.05) -> np.ndarray:
    """Logits whose sigmoid is P with levels kept `margin` from 0 and 1 (the sigmoid's
    gradient vanishes at the ends)."""
    q = np.clip(np.asarray(P, np.float64), margin, 1 - margin)
    return np.log(q / (1 - q)).astype(np.float32)


def inner_seeds(seed: int, draws: int) -> list[int]:
    """The evaluator seeds of `draws` inner draws: ``seed`` itself (the splits and noise of a
    single draw, as before draws existed), then seeds of a stream of their own."""
    more = np.random.SeedSequence([int(seed), LEARNED_STREAM, INNER_DRAW_STREAM]).generate_state(
        max(int(draws) - 1, 0))
    return [int(seed)] + [int(s) for s in more]


class LearnedIlluminationClassifier:
    """LED levels and a linear classifier over the k images (module docstring).

    Parameters
    - n_images: k exposures = k images; binary: on/off levels (straight-through).
    - starts: built-in start patterns, among 'random' (`random_start`), 'per_colour'
      (`per_colour_start`), 'snr_optimal' (the SNR-optimal baseline's first k / 4 site
      columns), 'greedy' (the greedy search's k / 4 per-colour columns on the same
      training data and inner splits), both expanded to LEDs by `rig.site_to_led_patterns`,
      and 'raking_sides' (`raking_sides_start` on the rig's site positions, one start per
      split of the low sites, `low_side_splits`: 'raking_sides', 'raking_sides/1', ...;
      docs/LEARNED.md, "Candidate lights and how one is kept"); default: all five; the last three are skipped unless
      4 divides k; start_patterns: more starts, {name: (32, k) LED levels}. Every start is
      scored by the inner splits and may be kept as it is.
    - fine_tune: the starts the gradient steps run from, each for max_steps (default 0: no
      descent, the starts alone; docs/LEARNED.md, "Gradient steps on the levels"): names of starts (default
      ('random', 'greedy', 'raking_sides'): from the random start, which needs many steps to
      find the cue where no on/off column shows it, from greedy's columns, whose choice of
      sites a descent refines where many classes need them, and from the raking sides), or
      'best' (the start the inner splits score best), 'all', 'none'; 'raking_sides' means
      the best scored of its splits. Each descent draws
      from a stream of its own, so one never changes another's. A perfect inner score
      ends the fit early (nothing after it could be kept: a tie keeps the earlier).
    - objective: 'cv_ridge' (`cv_ridge_loss` over `inner_folds(n_folds)`, ridge, class_power;
      no head during training), 'fisher' (`fisher_loss`, fisher_shrinkage) or 'cross_entropy'
      (a head of n_hidden units, lr_head, weight_decay, trained together with the light).
    - max_steps, eval_every (a snapshot of the levels every so many steps), batch_size
      (samples per step; all of them when it is at least their number), lr_patterns (Adam
      on the logits).
    - inner_groups: 'auto' (default), 'poses' or 'instances': what the inner splits and the
      loss's folds hold out (`SplitScoring.inner_groups`: whole physical samples where the
      data has two or more of every class, with 'auto'; `splits.inner_splits`,
      `inner_folds`); the greedy start is searched on the same splits.
    - n_repeats, test_fraction, split_classifier: the inner splits that score every
      start and snapshot (`evaluation.CandidateEvaluator` in the joint mode: greedy's split
      scoring and its noise streams) and their classifier: 'squared_hinge' (default: the
      exact linear SVM, the head's kind; it ranks lights more nearly as their held-out
      accuracy does, docs/research/LEARNED_PATH.md) or 'ridge' (the search's fast screen),
      final_C: the linear SVM head's C, head_renders: the noise
      draws of the training samples it is fitted on (default 6: the inner splits' draw and
      5 more; a head on one draw may learn its noise; 4 draws measured level with one without
      the cross-image statistics).
    - head: 'by_type' (default; docs/LEARNED.md, "The head: gated by object type"): a head gated by object type
      (`mux_classifier.gated_head`, types from the class names' prefix,
      `data.class_type_groups`): one linear SVM tells the types apart; within a type a
      class scores by its type's own SVM (that type's samples and z-scoring) plus the flat
      SVM; the flat head where gating changes nothing (one type, or one class per type).
      'flat': one one-vs-rest linear SVM over every class.
    - inner_draws: independent sets of inner splits, each with its own noise draw
      (`inner_seeds`; the first is the one seed gives), whose mean accuracy scores a
      candidate: more draws, less of the ranking left to one draw (two raking
      starts tied on one draw of the 16-class mix; 1, the default).
    - site_positions_mm: (n_sites, 3) for the raking-sides start; None: the rig of the
      ModelSet fitted, or the paper's stage for a SearchData (which carries no rig).
    - ratio_stats: after the images' own statistics, the cross-image relief statistics of
      every pair of images (`mux_classifier.ratio_stats`: the log ratio's spread and mean
      gradient over the object; albedo and print cancel in a ratio, relief's shading does
      not) in the descent's criterion, the inner splits and the head (the model stores their
      offset). Default True (docs/LEARNED.md); False: the 9 statistics per image alone.
    - noise, dimmer, hog_config (the image size) when fitting a ModelSet; seed; progress.
    - callback: called with a dict per step of the fit (as greedy's `callback`): a start
      begun and scored, greedy's columns while its start is made, a descent's snapshot
      (`learned_method.progress_text` words one). An exception it raises ends the fit
      there: the trainer node's cancel.

    After fit: patterns_ (32, k) site-major levels, model_ (a numpy `LearnedModel`: the
    head as one linear layer), classifiers_ {k: model_}, best_n_patterns_ = k,
    accuracy_by_images_ {k: the chosen candidate's inner split accuracy},
    candidate_scores_ {name: inner split accuracy}, chosen_ (its name), best_step_ (0: a
    start was kept), inner_estimate_ (the chosen candidate's inner accuracy and how the
    splits were made, `splits.inner_splits`), history_, train_seconds_.
    """

    method_name = 'learned'
    mode = 'joint'
    images_per_pattern = 1

    def __init__(self, n_images=4, binary=False,
                 starts=BUILTIN_STARTS, start_patterns=None,
                 fine_tune=('random', 'greedy', 'raking_sides'), objective='cv_ridge',
                 max_steps=DEFAULT_STEPS,
                 eval_every=50, batch_size=256, lr_patterns=0.2, n_folds=5, ridge=0.01,
                 class_power=1.0, fisher_shrinkage=1.0, n_hidden=0, lr_head=0.01, weight_decay=1e-3,
                 n_repeats=400, test_fraction=0.25, split_classifier='squared_hinge',
                 final_C=1.0, head_renders=6, head='by_type', inner_draws=1,
                 site_positions_mm=None, ratio_stats=True, inner_groups='auto',
                 noise='sigma3',
                 dimmer=None, hog_config=None, seed=0, progress=False, callback=None):
        self.n_images = n_images
        self.binary = binary
        self.starts = starts
        self.start_patterns = start_patterns
        self.fine_tune = fine_tune
        self.objective = objective
        self.max_steps = max_steps
        self.eval_every = eval_every
        self.batch_size = batch_size
        self.lr_patterns = lr_patterns
        self.n_folds = n_folds
        self.ridge = ridge
        self.class_power = class_power
        self.fisher_shrinkage = fisher_shrinkage
        self.n_hidden = n_hidden
        self.lr_head = lr_head
        self.weight_decay = weight_decay
        self.n_repeats = n_repeats
        self.test_fraction = test_fraction
        self.split_classifier = split_classifier
        self.final_C = final_C
        self.head_renders = head_renders
        self.head = head
        self.inner_draws = inner_draws
        self.site_positions_mm = site_positions_mm
        self.ratio_stats = ratio_stats
        self.inner_groups = inner_groups
        self.noise = noise
        self.dimmer = dimmer
        self.hog_config = hog_config
        self.seed = seed
        self.progress = progress
        self.callback = callback

    def _check(self):
        if int(self.n_images) < 1:
            raise ValueError(f'n_images must be >= 1, got {self.n_images}')
        for name in ('batch_size', 'eval_every', 'n_repeats', 'n_folds', 'head_renders',
                     'inner_draws'):
            if int(getattr(self, name)) < 1:
                raise ValueError(f'{name} must be >= 1, got {getattr(self, name)}')
        if int(self.max_steps) < 0:
            raise ValueError(f'max_steps must be >= 0, got {self.max_steps}')
        names = set(self.starts) | set(self.start_patterns or {})
        unknown = [n for n in self._tuned_names() if n not in ('best', 'all', 'none')
                   and n not in names]
        if unknown or not self._tuned_names():
            raise ValueError(f"fine_tune must be 'best', 'all', 'none' or names of starts "
                             f"({', '.join(sorted(names)) or 'none given'}), got {self.fine_tune!r}")
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {self.objective!r}")
        unknown = set(self.starts) - set(BUILTIN_STARTS)
        if unknown:
            raise ValueError(f"unknown starts {sorted(unknown)}; use {', '.join(BUILTIN_STARTS)}")
        if not (np.isfinite(float(self.ridge)) and float(self.ridge) > 0):
            raise ValueError(f'ridge must be a positive number, got {self.ridge}')
        if not (np.isfinite(float(self.class_power)) and float(self.class_power) >= 1):
            raise ValueError(f'class_power must be a number >= 1, got {self.class_power}')
        if self.head not in HEADS:
            raise ValueError(f"head must be one of {', '.join(HEADS)}, got {self.head!r}")
        check_inner_groups(self.inner_groups)
        if self.split_classifier not in SCORERS:
            raise ValueError(f"split_classifier must be one of {', '.join(sorted(SCORERS))}, "
                             f"got {self.split_classifier!r}")

    def _tuned_names(self) -> tuple:
        """fine_tune as a tuple of names (one name may be given as a string)."""
        tune = self.fine_tune
        return (tune,) if isinstance(tune, str) else tuple(str(n) for n in tune)

    def _data(self, X) -> SearchData:
        if isinstance(X, SearchData):
            data = X
        else:
            kwargs = {} if self.dimmer is None else {'dimmer': self.dimmer}
            data = search_data(X, self.noise, hog_config=self.hog_config,
                               features='intensity_stats', **kwargs)
        # the inner splits and the head score what the model classifies with
        return data if data.features == 'intensity_stats' else replace(data, features='intensity_stats')

    def _site_positions(self, X) -> np.ndarray:
        """(n_sites, 3) mm: site_positions_mm, else the fitted capture's rig (a ModelSet's),
        else the paper's stage (a SearchData carries no rig)."""
        if self.site_positions_mm is not None:
            positions = np.asarray(self.site_positions_mm, np.float64)
            if positions.ndim != 2 or positions.shape[1] != 3:
                raise ValueError(f'site_positions_mm must be (n_sites, 3), got shape {positions.shape}')
            return positions
        rig = getattr(X, 'rig', None)
        return (rig if rig is not None else Rig.paper_default()).site_positions_mm()

    def _start_makers(self, data: SearchData, k: int, rng) -> list:
        """[(name, () -> (32, k) levels)]: each start made only when it is scored
        (greedy's search is the costly one; none is made after a perfect score)."""
        L = data.n_sites * data.n_channels
        per_colour = k % data.n_channels == 0
        makers = []
        # the two drawn starts are drawn now, in this order (the stream's first draws)
        if 'random' in self.starts:
            P_random = random_start(data, k, rng)
            makers.append(('random', lambda: P_random))
        if 'per_colour' in self.starts:
            P_colour = per_colour_start(data.n_sites, data.n_channels, k, rng)
            makers.append(('per_colour', lambda: P_colour))
        if 'snr_optimal' in self.starts and per_colour:
            snr = SnrOptimalClassifier(n_images=k // data.n_channels, seed=int(self.seed))
            makers.append(('snr_optimal', lambda: site_to_led_patterns(
                snr._patterns_for(data), data.n_channels)))
        if 'greedy' in self.starts and per_colour:
            greedy = GreedyPatternSelector(
                mode='per_colour', n_patterns=k // data.n_channels, seed=int(self.seed),
                scoring=SplitScoring(n_repeats=int(self.n_repeats),
                                     test_fraction=float(self.test_fraction),
                                     inner_groups=self.inner_groups),
                callback=None if self.callback is None else self._greedy_progress)
            makers.append(('greedy', lambda: site_to_led_patterns(
                greedy.fit(data).patterns_, data.n_channels)))
        positions = self._site_positions_
        if 'raking_sides' in self.starts and per_colour and len(positions) == data.n_sites:
            # one start per split of the low sites ('raking_sides' the most nearly opposite,
            # then 'raking_sides/1', ...), each with a stream of its own (its later images'
            # random halves): the others' draws stay
            for split in range(len(low_side_splits(positions))):
                makers.append((raking_name(split), lambda rng=raking_rng(self.seed, split),
                               split=split: (
                    raking_sides_start(positions, data.n_channels, k, rng, split))))
        for name, P in dict(self.start_patterns or {}).items():
            P = np.asarray(P, np.float32)
            if P.shape != (L, k) or P.min() < 0 or P.max() > 1:
                raise ValueError(f'start pattern {name!r} must be ({L}, {k}) LED levels in '
                                 f'[0, 1], got shape {P.shape}')
            makers.append((str(name), lambda P=P: P))
        if not makers:
            raise ValueError('no start pattern: give starts or start_patterns')
        return makers

    def fit(self, X, y=None):
        """Fit on a SearchData or a ModelSet (its labels; y is ignored)."""
        self._check()
        t_start = time.perf_counter()
        data = self._data(X)
        self._site_positions_ = self._site_positions(X)
        by = resolve_inner_groups(self.inner_groups, data.labels, data.instance)
        if by == 'poses' and np.unique(data.pose_index).size < 2:
            raise ValueError('learned illumination needs at least 2 training poses per class '
                             '(the inner splits hold poses out); capture more poses')
        k = int(self.n_images)
        rng = np.random.default_rng([int(self.seed), LEARNED_STREAM])
        evaluators = [CandidateEvaluator(data, mode='joint', n_repeats=int(self.n_repeats),
                                         test_fraction=float(self.test_fraction), seed=s,
                                         inner_classifier=self.split_classifier, n_jobs=1,
                                         inner_groups=self.inner_groups)
                      for s in inner_seeds(self.seed, self.inner_draws)]
        ev = evaluators[0]   # the head's first draw is the first inner draw's
        history = []
        with Parallel(n_jobs=1) as parallel:
            def inner(P):
                # the mean split accuracy over the inner draws (each its splits and noise)
                if self.ratio_stats:   # cross-image statistics: the whole stack's features
                    return float(np.mean([
                        e.score_features(self._features(data, e.images(P))).mean()
                        for e in evaluators]))
                return float(np.mean([
                    e.score(e.prepare_column(P[:, :k - 1] if k > 1 else None), P[:, k - 1:],
                            parallel).mean() for e in evaluators]))

            # a perfect inner score cannot be beaten (a tie keeps the earlier candidate),
            # so nothing is made or descended after one
            candidates, scores = {}, {}

            def perfect():
                return bool(scores) and max(scores.values()) >= 1.0

            makers = self._start_makers(data, k, rng)
            for i, (name, make) in enumerate(makers):
                if perfect():
                    break
                self._notify(event='start', start=name, index=i + 1, of=len(makers))
                P = np.asarray(make(), np.float32)
                if self.binary:
                    P = (P >= 0.5).astype(np.float32)
                if P.any():   # an all-dark start (e.g. greedy found nothing) is no start
                    candidates[name], scores[name] = P, inner(P)
                    self._notify(event='start_scored', start=name, index=i + 1, of=len(makers),
                                 accuracy=scores[name], best_accuracy=max(scores.values()))
            if not candidates:
                raise ValueError('no start pattern lights anything: give starts or start_patterns')
            steps = dict.fromkeys(candidates, 0)
            self._say(k, 'starts', scores)
            tune = self._tuned_names()
            if 'none' not in tune and int(self.max_steps) > 0:
                starts = list(candidates)
                tuned = (starts if 'all' in tune
                         else [max(scores, key=scores.get)] if 'best' in tune
                         else [n for n in (self._family_best(t, scores) for t in tune)
                               if n is not None])
                for name in tuned:
                    # the random start's descent continues the stream that drew it (round
                    # 3's draws); any other start's has a stream of its own (seed, name)
                    chain_rng = rng if name == 'random' else np.random.default_rng(
                        [int(self.seed), LEARNED_STREAM, zlib.crc32(name.encode())])
                    for step, P, loss in ([] if perfect() else
                                          self._descend(data, candidates[name], chain_rng)):
                        tag = f'{name}+{step}'
                        candidates[tag], steps[tag], scores[tag] = P, step, inner(P)
                        history.append({'start': name, 'step': step, 'loss': loss,
                                        'inner_accuracy': scores[tag]})
                        self._say(k, tag, {tag: scores[tag]}, loss)
                        self._notify(event='step', start=name, step=step,
                                     of=int(self.max_steps), accuracy=scores[tag],
                                     best_accuracy=max(scores.values()))
                        if perfect():
                            break
            # the best inner score; a tie keeps the earlier candidate (a start before its tuning)
            chosen = max(scores, key=scores.get)
            patterns = candidates[chosen]
            self.model_ = self._svm_head(data, ev, patterns)
        self.patterns_ = patterns
        self.class_names_ = list(data.class_names)
        self.classifiers_ = {k: self.model_}
        self.best_n_patterns_ = k
        self.accuracy_by_images_ = {k: scores[chosen]}
        self.candidate_scores_ = scores
        self.inner_estimate_ = {'accuracy': float(scores[chosen]), 'n_images': k,
                                **ev.inner_,
                                'n_repeats': int(self.n_repeats) * int(self.inner_draws)}
        self.chosen_ = chosen
        self.best_step_ = int(steps[chosen])
        self.history_ = history
        self.train_seconds_ = time.perf_counter() - t_start
        return self

    @staticmethod
    def _family_best(name: str, scores: dict) -> str | None:
        """The start a fine_tune name means: itself, or for 'raking_sides' the best scored of
        its splits (a tie keeps the earlier); None if no such start was made."""
        family = [n for n in scores if n == name or (name == 'raking_sides'
                                                      and n.startswith('raking_sides/'))]
        return max(family, key=scores.get) if family else None

    def _greedy_progress(self, event: dict) -> None:
        """Greedy's events while its start is made: 'start_column' (a column begun or chosen)
        and 'start_candidates' (candidates scored so far of the column's)."""
        if event['event'] == 'candidates':
            self._notify(event='start_candidates', start='greedy', column=event['column'],
                         done=event['done'], of=event['of'])
        else:
            self._notify(event='start_column', start='greedy', column=event['column'],
                         of=event['of'], done=event['event'] == 'column_done')

    def _notify(self, **event) -> None:
        """Progress for `callback` (a dict with 'event': 'start' / 'start_scored' / 'step' /
        'start_column' / 'start_candidates', greedy's progress while its start is made;
        `progress_text` words it).
        An exception the callback raises ends the fit there: how a cancel stops it."""
        if self.callback is not None:
            self.callback(event)

    def _say(self, k, what, scores, loss=None):
        if self.progress:
            text = ', '.join(f'{n} {s:.3f}' for n, s in scores.items())
            extra = '' if loss is None else f' (loss {loss:.3f})'
            levels = 'on/off' if self.binary else 'graded'
            what = 'the starts' if what == 'starts' else what
            print(f'[learned, {k} exposures, {levels}] inner accuracy of {what}: {text}{extra}',
                  flush=True)

    def _descend(self, data: SearchData, P0: np.ndarray, rng):
        """Gradient steps on the LED logits from P0 on every training sample (fresh noise and
        a fresh batch each step); yields (step, levels, loss) every eval_every steps."""
        k, binary = int(self.n_images), bool(self.binary)
        L = data.n_sites * data.n_channels
        basis = jnp.asarray(data.basis.reshape(L, data.n_samples, -1))
        labels = jnp.asarray(data.labels, jnp.int32)
        onehot = jax.nn.one_hot(labels, len(data.class_names), dtype=jnp.float32)
        shape, a, b, top = data.image_shape, data.noise_a, data.noise_b, data.max_level
        wd, shrink = float(self.weight_decay), float(self.fisher_shrinkage)
        objective, ridge, power = self.objective, float(self.ridge), float(self.class_power)
        folds = inner_folds(data, int(self.n_folds), self.inner_groups)
        offset = self._ratio_offset(data)

        def loss_fn(params, idx, eps):
            mean = relight(jnp.take(basis, idx, axis=1), levels(params['theta'], binary))
            images = add_noise(mean, eps, a, b, top)
            F = stack_stats(images, shape)
            if offset:
                F = jnp.concatenate([F, stack_ratio_stats(images, shape, offset)], axis=1)
            if objective == 'cv_ridge':
                return cv_ridge_loss(F, onehot[idx], jnp.take(held_out, idx, axis=1), ridge, power)
            if objective == 'fisher':
                return fisher_loss(F, onehot[idx], shrink)
            # z-scored by the batch's own statistics, not differentiated (no collapse of scale)
            mean = jax.lax.stop_gradient(F.mean(axis=0))
            scale = jax.lax.stop_gradient(F.std(axis=0) + 1e-3)
            l2 = sum(jnp.sum(W * W) for W, _ in params['head'])
            return _cross_entropy(forward_features(params['head'], mean, scale, F),
                                  labels[idx]) + wd * l2

        held_out = jnp.asarray(folds)
        params = {'theta': jnp.asarray(_logits_of(P0)), 'head': []}
        if objective == 'cross_entropy':
            n_in = k * N_STATS + (n_ratio_stats(k) if offset else 0)
            params['head'] = _init_head(rng, n_in, int(self.n_hidden), len(data.class_names))
        lr = {'theta': jnp.float32(self.lr_patterns),
              'head': jax.tree_util.tree_map(lambda _: jnp.float32(self.lr_head), params['head'])}

        @jax.jit
        def step(params, opt, idx, eps):
            loss, grads = jax.value_and_grad(loss_fn)(params, idx, eps)
            params, opt = _adam_update(params, grads, opt, lr)
            return params, opt, loss

        opt = _adam_init(params)
        B = min(int(self.batch_size), data.n_samples)
        for it in range(1, int(self.max_steps) + 1):
            # every sample when the batch holds them all (sorted: the same order each step)
            idx = np.sort(rng.choice(data.n_samples, B, replace=False))
            # the normals from numpy: JAX's threefry on the CPU took a third of a step
            eps = rng.standard_normal((k, B, basis.shape[2]), dtype=np.float32)
            params, opt, loss = step(params, opt, jnp.asarray(idx), jnp.asarray(eps))
            if it % int(self.eval_every) == 0 or it == int(self.max_steps):
                yield it, np.asarray(levels(params['theta'], binary), np.float32), float(loss)

    def _head_features(self, data: SearchData, ev, patterns) -> np.ndarray:
        """The training samples' statistics under the patterns, head_renders noise draws
        stacked: the inner splits' draw, then draws of a stream of its own (a head fitted on
        one draw may learn that draw's noise with it; measured: docs/research/LEARNED_PATH.md)."""
        parts = [self._features(data, ev.images(patterns))]
        renders = int(self.head_renders) if data.noise_a or data.noise_b else 1
        if renders > 1:
            clean = clean_led_images(data, patterns)
            rng = np.random.default_rng([int(self.seed), LEARNED_STREAM, HEAD_NOISE_STREAM])
            for _ in range(renders - 1):
                noisy = add_noise_images(data, clean, standard_normal(rng, clean.shape))
                parts.append(self._features(data, noisy))
        return np.vstack(parts)

    def _ratio_offset(self, data: SearchData) -> float:
        """The cross-image statistics' offset (gray levels), 0 without them."""
        return float(OFFSET_FRACTION * data.max_level) if self.ratio_stats else 0.0

    def _features(self, data: SearchData, images: np.ndarray) -> np.ndarray:
        """Raw features (n, k * 9 [+ cross-image]) of images (k, n, pixels)."""
        X = image_features(data, images)
        offset = self._ratio_offset(data)
        if not offset:
            return X
        k, n, _ = images.shape
        stacks = images.reshape(k, n, *data.image_shape).transpose(1, 0, 2, 3)
        return np.hstack([X, ratio_stats(stacks, offset)])

    def _svm_head(self, data: SearchData, ev, patterns) -> LearnedModel:
        """The final classifier: linear SVMs (`fit_linear`, as `MuxClassifier` fits them:
        statistics z-scored over the samples each is fitted on) on the training samples
        rendered under the patterns (`_head_features`), flat or gated by object type
        (`head`, `class_groups`); stored as one linear layer on the raw statistics."""
        X = self._head_features(data, ev, patterns)
        y = np.tile(data.labels, len(X) // data.n_samples)
        groups = class_type_groups(data.class_names) if self.head == 'by_type' else None
        offset = self._ratio_offset(data)
        if groups is not None:
            coef, intercept = fit_gated_linear(X, y, groups, C=float(self.final_C),
                                               random_state=int(self.seed))
            return LearnedModel(patterns, np.zeros(X.shape[1]), np.ones(X.shape[1]),
                                [(coef.T, intercept)], list(data.class_names),
                                ratio_offset=offset, class_groups=groups)
        coef, intercept, classes = fit_linear(X, y, 'linear_svm', C=float(self.final_C),
                                              random_state=int(self.seed))
        n_classes, n_in = len(data.class_names), coef.shape[1]
        W = np.zeros((n_in, n_classes), np.float64)
        b = np.full(n_classes, NO_SAMPLES_SCORE)
        W[:, classes] = coef.T
        b[classes] = intercept
        return LearnedModel(patterns, np.zeros(n_in), np.ones(n_in), [(W, b)],
                            list(data.class_names), ratio_offset=offset)

    # --- prediction ----------------------------------------------------------------------
    def predict_images(self, images: np.ndarray) -> np.ndarray:
        """Class indices of images (k, n, pixels) rendered under patterns_ (the numpy model)."""
        k, n, P = images.shape
        side = int(round(np.sqrt(P)))
        stacks = np.asarray(images).transpose(1, 0, 2).reshape(n, k, side, P // side)
        return self.model_.predict(stacks)

    def predict_features(self, X: np.ndarray, n_patterns: int) -> np.ndarray:
        """Class indices from the model's raw features (n, `LearnedModel.n_features`) of the
        k images (the PatternModelMixin interface; only n_patterns = n_images exists)."""
        if int(n_patterns) not in self.classifiers_:
            raise ValueError(f'this learned model has {self.n_images} images; n_patterns '
                             f'{n_patterns} is not available')
        X = np.asarray(X)
        if self.model_.ratio_offset:
            if X.shape[1] != self.model_.n_features:
                raise ValueError(f'features must be the model\'s {self.model_.n_features} '
                                 f'statistics (intensity and cross-image); got {X.shape[1]}')
            return self.model_.predict_features(X)
        if X.shape[1] != self.model_.n_images * N_STATS:
            raise ValueError(f'features must be the {N_STATS} intensity statistics of each of '
                             f'{self.model_.n_images} images ({self.model_.n_images * N_STATS} '
                             f'values); got {X.shape[1]} (use --features intensity_stats)')
        return self.model_.predict_features(X)

    def predict(self, stacks) -> np.ndarray:
        """Class indices of stacks (n, k, H, W) taken under patterns_."""
        return self.model_.predict(stacks)


def evaluate_learned_heldout(model, test_data: SearchData, n_renders: int = 4,
                             seed: int = 0) -> dict:
    """Held-out accuracy under the same rules as `holdout.evaluate_heldout`: test images
    rendered under the model's patterns with `holdout.test_images` (the same noise stream,
    independent of training), n_renders times. Returns {'accuracy', 'correct' (n,)}."""
    correct = np.zeros(test_data.n_samples)
    for r in range(int(n_renders)):
        images = test_images(test_data, 'joint', model.patterns_, r, seed)
        correct += model.predict_images(images) == test_data.labels
    correct /= int(n_renders)
    return {'accuracy': float(correct.mean()), 'correct': correct}
