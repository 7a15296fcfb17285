"""Learned illumination: LED levels and a small classifier trained together, end to end.

The patterns are a (32, k) matrix of LED levels, ``sigmoid(theta)`` (graded) or its
straight-through binarisation (``binary=True``: on/off, runs on ``pwm_bits = 0``
firmware), one image per column (k exposures = k images, the budget of the other methods:
greedy's per-colour column is 4 images). Each training step renders a batch of training
samples under the current levels (`lightstage_physics.render_jax`: the relit images as
`rendering.clean_led_images`, the calibrated affine noise drawn afresh by
reparameterisation, the saturation clip, at the classifier's 120 px), computes per image
the 9 pose-robust object statistics of `intensity_stats` made differentiable
(`image_stats`), z-scores them and classifies with a small dense head; the cross-entropy's
gradient reaches the LED levels through the statistics and the image formation.

Why these features and not a CNN: the captures hold 6-20 poses per class, objects lying
anywhere and any way; the statistics ignore where the object lies by construction (a CNN
would have to learn that from a handful of poses), they are what the greedy search scores
with on free placement (`--features intensity_stats`), so a comparison isolates what
learning the light adds, and they are cheap (two sorts per image) and exact to reproduce
in numpy for the node (`mux_classifier.learned_model`).

Training: Adam, a fraction of the training poses held out for early stopping (pose
indices, the same for every class), then the head refit on all training poses with the
feature standardisation frozen (statistics of the final patterns' features over several
noise draws), for the number of steps the held-out poses chose.
"""
from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
from lightstage_physics.render_jax import render_noisy
from mux_classifier.intensity_stats import GRADIENT_QUANTILES, LEVEL_QUANTILES, N_STATS
from mux_classifier.learned_model import LearnedModel
from mux_classifier.object_mask import image_masks

from .data import search_data
from .holdout import test_images
from .rendering import SearchData

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


def initial_logits(n_sites: int, n_channels: int, k: int, rng, level: float = 0.9) -> np.ndarray:
    """Start logits (sites * channels, k), site-major: image j lights colour j mod 4 at
    level 0.9 (others 0.1), at every site for the first four images and at a random half of
    the sites for each later group of four. The per-colour start keeps the colours apart (a
    random mixture of colours would blur the spectral cue the classes differ by) and is where
    the per-colour methods start too; 0.9 rather than 1 leaves the sigmoid a gradient."""
    on = np.zeros((n_sites, n_channels, k), bool)
    for j in range(k):
        sites = (np.arange(n_sites) if j < n_channels
                 else rng.choice(n_sites, max(1, n_sites // 2), replace=False))
        on[sites, j % n_channels, j] = True
    logit = np.float32(np.log(level / (1 - level)))
    return np.where(on, logit, -logit).reshape(n_sites * n_channels, k).astype(np.float32)


def _val_split(pose_index, fraction, rng):
    poses = np.unique(pose_index)
    if poses.size < 2:
        raise ValueError('learned illumination needs at least 2 training poses per class '
                         '(one is held out for early stopping); capture more poses')
    n_val = min(poses.size - 1, max(1, int(round(fraction * poses.size))))
    val_poses = rng.choice(poses, n_val, replace=False)
    val = np.isin(pose_index, val_poses)
    return np.flatnonzero(~val), np.flatnonzero(val)


class LearnedIlluminationClassifier:
    """LED levels and a classifier over the k images, learned end to end (module docstring).

    Parameters: n_images (k exposures = k images), binary (on/off levels by
    straight-through), n_hidden (0: a linear softmax head), batch_size, max_steps,
    eval_every / patience (early stopping, in evaluations), lr_patterns / lr_head,
    weight_decay (L2 on the head's weights), val_fraction (training poses held out for
    early stopping), head_renders (noise draws of the frozen-feature head refit), noise,
    dimmer, hog_config (the image size) when fitting a ModelSet, seed.

    After fit: patterns_ (32, k) site-major levels, model_ (a numpy `LearnedModel`),
    classifiers_ {k: model_}, best_n_patterns_ = k, accuracy_by_images_ {k: accuracy on
    the early-stopping poses}, history_, train_seconds_.
    """

    method_name = 'learned'
    mode = 'joint'
    images_per_pattern = 1

    def __init__(self, n_images=4, binary=False, n_hidden=0, batch_size=24, max_steps=150,
                 eval_every=10, patience=6, lr_patterns=0.1, lr_head=0.01, weight_decay=1e-3,
                 val_fraction=0.25, head_renders=8, head_steps=400, noise='sigma3',
                 dimmer=None, hog_config=None, seed=0, progress=False):
        self.n_images = n_images
        self.binary = binary
        self.n_hidden = n_hidden
        self.batch_size = batch_size
        self.max_steps = max_steps
        self.eval_every = eval_every
        self.patience = patience
        self.lr_patterns = lr_patterns
        self.lr_head = lr_head
        self.weight_decay = weight_decay
        self.val_fraction = val_fraction
        self.head_renders = head_renders
        self.head_steps = head_steps
        self.noise = noise
        self.dimmer = dimmer
        self.hog_config = hog_config
        self.seed = seed
        self.progress = progress

    def _check(self):
        if int(self.n_images) < 1:
            raise ValueError(f'n_images must be >= 1, got {self.n_images}')
        for name in ('batch_size', 'max_steps', 'eval_every', 'patience', 'head_renders'):
            if int(getattr(self, name)) < 1:
                raise ValueError(f'{name} must be >= 1, got {getattr(self, name)}')
        if not 0 < float(self.val_fraction) < 1:
            raise ValueError(f'val_fraction must lie in (0, 1), got {self.val_fraction}')

    def _data(self, X) -> SearchData:
        if isinstance(X, SearchData):
            return X
        kwargs = {} if self.dimmer is None else {'dimmer': self.dimmer}
        return search_data(X, self.noise, hog_config=self.hog_config,
                           features='intensity_stats', **kwargs)

    def fit(self, X, y=None):
        """Fit on a SearchData or a ModelSet (its labels; y is ignored)."""
        self._check()
        t_start = time.perf_counter()
        data = self._data(X)
        k, binary = int(self.n_images), bool(self.binary)
        n_classes = len(data.class_names)
        rng = np.random.default_rng([int(self.seed), 26])
        key = jax.random.PRNGKey(int(self.seed))
        fit_idx, val_idx = _val_split(data.pose_index, float(self.val_fraction), rng)
        L = data.n_sites * data.n_channels
        basis = jnp.asarray(data.basis.reshape(L, data.n_samples, -1))
        labels = jnp.asarray(data.labels, jnp.int32)
        shape, a, b, top = data.image_shape, data.noise_a, data.noise_b, data.max_level
        wd = float(self.weight_decay)

        def features_of(theta, idx, key):
            images = render_noisy(jnp.take(basis, idx, axis=1), levels(theta, binary), key, a, b, top)
            return stack_stats(images, shape)

        def loss_fn(params, idx, key):
            F = features_of(params['theta'], idx, key)
            # z-scored by the batch's own statistics, not differentiated (no collapse of scale)
            mean = jax.lax.stop_gradient(F.mean(axis=0))
            scale = jax.lax.stop_gradient(F.std(axis=0) + 1e-3)
            logits = forward_features(params['head'], mean, scale, F)
            l2 = sum(jnp.sum(W * W) for W, _ in params['head'])
            return _cross_entropy(logits, labels[idx]) + wd * l2, (mean, scale)

        params = {'theta': jnp.asarray(initial_logits(data.n_sites, data.n_channels, k, rng)),
                  'head': _init_head(rng, k * N_STATS, int(self.n_hidden), n_classes)}
        lr = {'theta': jnp.float32(self.lr_patterns),
              'head': jax.tree_util.tree_map(lambda _: jnp.float32(self.lr_head), params['head'])}

        @jax.jit
        def step(params, opt, idx, key, ema):
            (loss, (mean, scale)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, idx, key)
            params, opt = _adam_update(params, grads, opt, lr)
            ema = (0.9 * ema[0] + 0.1 * mean, 0.9 * ema[1] + 0.1 * scale)
            return params, opt, loss, ema

        @jax.jit
        def evaluate(params, idx, key, ema):
            F = features_of(params['theta'], idx, key)
            logits = forward_features(params['head'], ema[0], ema[1], F)
            return _cross_entropy(logits, labels[idx]), jnp.mean(jnp.argmax(logits, 1) == labels[idx])

        opt = _adam_init(params)
        # the first batch's statistics start the running ones
        _, (m0, s0) = loss_fn(params, jnp.asarray(fit_idx[:min(len(fit_idx), 64)]), key)
        ema = (m0, s0)
        val_keys = [jax.random.fold_in(jax.random.PRNGKey(int(self.seed) + 1), r) for r in range(2)]
        val_j = jnp.asarray(val_idx)
        best = (-1.0, np.inf)
        best_state, best_step, bad_evals = None, 0, 0
        history = []
        B = min(int(self.batch_size), len(fit_idx))
        for it in range(1, int(self.max_steps) + 1):
            idx = jnp.asarray(rng.choice(fit_idx, B, replace=False))
            key, sub = jax.random.split(key)
            params, opt, loss, ema = step(params, opt, idx, sub, ema)
            if it % int(self.eval_every) and it != int(self.max_steps):
                continue
            res = [evaluate(params, val_j, vk, ema) for vk in val_keys]
            v_loss = float(np.mean([float(r[0]) for r in res]))
            v_acc = float(np.mean([float(r[1]) for r in res]))
            history.append({'step': it, 'train_loss': float(loss), 'val_loss': v_loss,
                            'val_accuracy': v_acc})
            if self.progress:
                print(f'[learned k={k}{" binary" if binary else ""}] step {it}: loss '
                      f'{float(loss):.3f}, held-out poses {v_acc:.3f} ({v_loss:.3f})', flush=True)
            if (v_acc, -v_loss) > (best[0], -best[1]):
                best = (v_acc, v_loss)
                best_state, best_step, bad_evals = jax.tree_util.tree_map(np.asarray, params), it, 0
            else:
                bad_evals += 1
                if bad_evals >= int(self.patience):
                    break
        theta = jnp.asarray(best_state['theta'])
        patterns = np.asarray(levels(theta, binary), np.float32)
        self._refit_head(data, basis, patterns, best_state['head'], fit_idx, val_idx, key)
        self.patterns_ = patterns
        self.class_names_ = list(data.class_names)
        self.classifiers_ = {k: self.model_}
        self.best_n_patterns_ = k
        self.accuracy_by_images_ = {k: float(best[0])}
        self.best_step_ = int(best_step)
        self.history_ = history
        self.train_seconds_ = time.perf_counter() - t_start
        return self

    def _refit_head(self, data, basis, patterns, head, fit_idx, val_idx, key):
        """Freeze the standardisation at the final patterns' training features (several
        noise draws), fit the head on the early-stopping split to choose the step count,
        then refit it on every training pose for that many steps."""
        shape, a, b, top = data.image_shape, data.noise_a, data.noise_b, data.max_level
        P = jnp.asarray(patterns)

        @jax.jit
        def feats(idx, key):
            return stack_stats(render_noisy(jnp.take(basis, idx, axis=1), P, key, a, b, top), shape)

        R = int(self.head_renders)
        keys = jax.random.split(jax.random.fold_in(key, 7), R)
        every = np.arange(data.n_samples)
        chunks = np.array_split(every, max(1, data.n_samples // 64))
        F = np.stack([np.concatenate([np.asarray(feats(jnp.asarray(c), kk)) for c in chunks])
                      for kk in keys])  # (R, n, features)
        y = np.asarray(data.labels)
        mean = F[:, fit_idx].reshape(-1, F.shape[2]).mean(axis=0)
        scale = F[:, fit_idx].reshape(-1, F.shape[2]).std(axis=0) + 1e-3
        wd = float(self.weight_decay)

        def loss_fn(layers, X, yy):
            l2 = sum(jnp.sum(W * W) for W, _ in layers)
            return _cross_entropy(forward_features(layers, mean, scale, X), yy) + wd * l2

        @jax.jit
        def step(layers, opt, X, yy):
            g = jax.grad(loss_fn)(layers, X, yy)
            return _adam_update(layers, g, opt, jax.tree_util.tree_map(
                lambda _: jnp.float32(self.lr_head), layers))

        def fit(idx, n_steps, val=None):
            X = jnp.asarray(F[:, idx].reshape(-1, F.shape[2]))
            yy = jnp.asarray(np.tile(y[idx], R))
            layers = jax.tree_util.tree_map(jnp.asarray, head)
            opt = _adam_init(layers)
            best_acc, best_at = -1.0, 0
            for it in range(1, n_steps + 1):
                layers, opt = step(layers, opt, X, yy)
                if val is not None and it % 10 == 0:
                    Xv = F[:, val].reshape(-1, F.shape[2])
                    acc = float(np.mean(np.argmax(np.asarray(forward_features(
                        layers, mean, scale, Xv)), 1) == np.tile(y[val], R)))
                    if acc > best_acc:
                        best_acc, best_at = acc, it
            return layers, best_at

        _, n_steps = fit(fit_idx, int(self.head_steps), val=val_idx)
        layers, _ = fit(every, max(n_steps, 10))
        self.model_ = LearnedModel(patterns, mean, scale,
                                   [(np.asarray(W), np.asarray(bb)) for W, bb in layers],
                                   list(data.class_names))
        self.head_steps_ = int(n_steps)

    # --- prediction ----------------------------------------------------------------------
    def predict_images(self, images: np.ndarray) -> np.ndarray:
        """Class indices of images (k, n, pixels) rendered under patterns_ (the numpy model)."""
        k, n, P = images.shape
        side = int(round(np.sqrt(P)))
        stacks = np.asarray(images).transpose(1, 0, 2).reshape(n, k, side, P // side)
        return self.model_.predict(stacks)

    def predict_features(self, X: np.ndarray, n_patterns: int) -> np.ndarray:
        """Class indices from intensity-statistics features (n, k * 9) of the k images (the
        PatternModelMixin interface; only n_patterns = n_images exists)."""
        if int(n_patterns) not in self.classifiers_:
            raise ValueError(f'this learned model has {self.n_images} images; n_patterns '
                             f'{n_patterns} is not available')
        X = np.asarray(X)
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
