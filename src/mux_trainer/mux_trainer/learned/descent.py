"""Gradient steps on the LED levels (docs/LEARNED.md, "Gradient steps on the levels"): the
training samples rendered under the current levels (`lightstage_physics.render_jax`: the
relit images as `rendering.clean_led_images`, the calibrated affine noise drawn afresh by
reparameterisation, the saturation clip), their statistics (`statistics`), and the
pose-held-out loss of a closed-form ridge classifier on them (`cv_ridge_loss`), whose
gradient Adam (optax) follows on the LED logits. The light is asked for what the inner
splits measure: separation that holds on poses (or physical samples) it was not fitted on.
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import optax
from lightstage_physics.render_jax import add_noise, relight

from ..rendering import SearchData
from ..splits import resolve_inner_groups
from .params import Descent
from .statistics import stack_ratio_stats, stack_stats

__all__ = ['levels', 'logits_of', 'pose_folds', 'instance_folds', 'inner_folds',
           'cv_ridge_loss', 'adam', 'descend']

# Adam's constants (Kingma & Ba): eps added to the root of the bias-corrected second moment
ADAM_B1, ADAM_B2, ADAM_EPS = 0.9, 0.999, 1e-8


def levels(theta: jnp.ndarray, binary: bool) -> jnp.ndarray:
    """LED levels in [0, 1] from the logits theta; binary: 0/1 forward, the sigmoid's
    gradient backward (straight-through)."""
    soft = jax.nn.sigmoid(theta)
    if not binary:
        return soft
    return soft + jax.lax.stop_gradient((soft > 0.5).astype(jnp.float32) - soft)


def logits_of(P: np.ndarray, margin: float = 0.05) -> np.ndarray:
    """Logits whose sigmoid is P with levels kept `margin` from 0 and 1 (the sigmoid's
    gradient vanishes at the ends)."""
    q = np.clip(np.asarray(P, np.float64), margin, 1 - margin)
    return np.log(q / (1 - q)).astype(np.float32)


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
                  ridge: float) -> jnp.ndarray:
    """The pose-held-out loss of the classifier greedy's inner splits imitate, in closed
    form: for each fold (`held_out` (folds, n) masks from `inner_folds`) the features F
    (n, d) are z-scored over the fold's training samples, a ridge least-squares classifier
    on +-1 targets is solved on them (`ridge` times the sample count on the diagonal), and
    the squared hinge of its scores is averaged over the held-out samples; the mean over
    folds. Differentiable through the solve, so the light's gradient is that of held-out
    error under the head that is optimal for the light at this step (no head is learned
    alongside), and light that only fits the training poses does not pay."""
    Y = 2.0 * onehot - 1.0
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
        return (hinge * t).sum() / jnp.maximum(t.sum(), 1.0)

    return jnp.mean(jax.vmap(fold)(held_out))


def adam(lr: float) -> optax.GradientTransformation:
    """Adam on the LED logits: optax's, bias-corrected, eps added outside the root of the
    second moment (`ADAM_*`)."""
    return optax.adam(float(lr), b1=ADAM_B1, b2=ADAM_B2, eps=ADAM_EPS)


@partial(jax.jit, static_argnames=('shape', 'binary', 'offset', 'lr'))
def _step(theta, state, idx, eps, basis, onehot, held_out, a, b, top, ridge, *,
          shape, binary, offset, lr):
    """One Adam step on the LED logits. Module-level and given the data as arguments, so one
    compilation (seconds) serves every descent of the same shapes and settings in the
    process: the descents from several starts of one fit, and the fits that follow."""
    def loss_fn(theta):
        mean = relight(jnp.take(basis, idx, axis=1), levels(theta, binary))
        images = add_noise(mean, eps, a, b, top)
        F = stack_stats(images, shape)
        if offset:
            F = jnp.concatenate([F, stack_ratio_stats(images, shape, offset)], axis=1)
        return cv_ridge_loss(F, onehot[idx], jnp.take(held_out, idx, axis=1), ridge)

    loss, grad = jax.value_and_grad(loss_fn)(theta)
    updates, state = adam(lr).update(grad, state, theta)
    return optax.apply_updates(theta, updates), state, loss


def descend(data: SearchData, P0: np.ndarray, rng: np.random.Generator, descent: Descent, *,
            binary: bool, ratio_offset: float, inner_groups: str = 'auto'):
    """Gradient steps on the LED logits from the levels P0 (32, k) on the training samples
    of `data` (a fresh batch of `descent.batch_size` and a fresh noise draw from `rng` each
    step); yields (step, levels (32, k), loss) every `descent.eval_every` steps and at the
    last. `binary`: straight-through on/off levels (`levels`); `ratio_offset` > 0: the
    cross-image statistics follow each image's (`statistics.stack_ratio_stats`)."""
    k = P0.shape[1]
    L = data.n_sites * data.n_channels
    basis = jnp.asarray(data.basis.reshape(L, data.n_samples, -1))
    labels = jnp.asarray(data.labels, jnp.int32)
    onehot = jax.nn.one_hot(labels, len(data.class_names), dtype=jnp.float32)
    held_out = jnp.asarray(inner_folds(data, int(descent.n_folds), inner_groups))
    # traced scalars (float32, as the constants they replace): other noise or ridge values
    # reuse the compilation
    a, b, top, ridge = (jnp.float32(v) for v in (data.noise_a, data.noise_b, data.max_level,
                                                 descent.ridge))
    static = dict(shape=tuple(int(n) for n in data.image_shape), binary=bool(binary),
                  offset=float(ratio_offset), lr=float(descent.lr))

    def step(theta, state, idx, eps):
        return _step(theta, state, idx, eps, basis, onehot, held_out, a, b, top, ridge,
                     **static)

    theta = jnp.asarray(logits_of(P0))
    state = adam(descent.lr).init(theta)
    B = min(int(descent.batch_size), data.n_samples)
    max_steps, every = int(descent.max_steps), int(descent.eval_every)
    for it in range(1, max_steps + 1):
        # every sample when the batch holds them all (sorted: the same order each step)
        idx = np.sort(rng.choice(data.n_samples, B, replace=False))
        # the normals from numpy: JAX's threefry on the CPU took a third of a step
        eps = rng.standard_normal((k, B, basis.shape[2]), dtype=np.float32)
        theta, state, loss = step(theta, state, jnp.asarray(idx), jnp.asarray(eps))
        if it % every == 0 or it == max_steps:
            yield it, np.asarray(levels(theta, binary), np.float32), float(loss)
