"""The object statistics of `intensity_stats` and `ratio_stats` in JAX, differentiable in
the gray levels, so the training criterion's gradient reaches the LED levels through them
and the image formation.

Why these features and not a CNN: the captures hold 6-20 poses per class, objects lying
anywhere and any way; the statistics ignore where the object lies by construction (a CNN
would have to learn that from a handful of poses), they are what the greedy search scores
with on free placement (`--features intensity_stats`), so a comparison isolates what
learning the light adds, and they are cheap (two sorts per image) and exact to reproduce
in numpy for the node (`mux_classifier.learned_model`). A small CNN over the images was
measured: 65-82 % where the statistics give 97 %, 15 training samples per class
(docs/research/LEARNED_PATH.md).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mux_classifier.intensity_stats import GRADIENT_QUANTILES, LEVEL_QUANTILES, N_STATS
from mux_classifier.object_mask import image_masks
from mux_classifier.ratio_stats import object_masks, pair_ratio_stats

__all__ = ['image_stats', 'stack_stats', 'stack_ratio_stats']

_LEVEL_F = np.array(LEVEL_QUANTILES, np.float32) / 100
_GRAD_F = np.array(GRADIENT_QUANTILES, np.float32) / 100

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

