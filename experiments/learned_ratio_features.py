"""A probe: does a cross-image feature learned jointly with the light carry the seal
pair's relief cue in the 16-class mix at 4 exposures? (docs/research/LEARNED_PATH.md;
the model's option `ratio_stats` now, whose functions this probe uses)

Pair features, per pair of images (i, j), over the object (the mask of the images' sum):
R = log(I_i + c) - log(I_j + c) (albedo and print cancel; relief's shading does not), its
spread (std over the object) and its mean gradient magnitude (`mux_classifier.ratio_stats`).
2 * 6 = 12 features beside the 36 intensity statistics.

From the same start light (a run's kept learned light), `steps` more steps of the round-4
descent (cv_ridge, pose folds, batch 256, fresh noise) with features 'base' (the 36
statistics, the control) or 'pair' (36 + 12). Every 50 steps: the inner criterion (pose-held-out
linear SVM on 1 draw of the training samples) and the held-out accuracy (a linear SVM on 6
draws, tested on 4 renders), overall and on the seal pair.

    PYTHONPATH=src/lightstage_physics:src/mux_classifier:src/mux_trainer \\
        .venv/bin/python benchmarks/learned_ratio_features.py DIR/mix16 instances 0 r5_instances.json pair 200 OUT.json
"""
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import LinearSVC

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from learned_vs_greedy import split_capture
from lightstage_physics.render_jax import add_noise, relight
from mux_classifier.intensity_stats import intensity_stats_images
from mux_classifier.ratio_stats import OFFSET_FRACTION, ratio_stats
from mux_trainer.holdout import test_images
import optax
from mux_trainer.learned import (cv_ridge_loss, levels, pose_folds, stack_ratio_stats,
                                 stack_stats)
from mux_trainer.learned import logits_of as _logits_of


# Adam as the descent's (optax, mux_trainer.learned.descent.adam), the learning rate per call
_ADAM = optax.scale_by_adam()


def _adam_init(params):
    return _ADAM.init(params)


def _adam_update(params, grads, state, lr):
    """One Adam step at learning rate lr (a number, or a pytree like params)."""
    updates, state = _ADAM.update(grads, state)
    same = jax.tree_util.tree_structure(lr) == jax.tree_util.tree_structure(params)
    lrs = lr if same else jax.tree_util.tree_map(lambda _: lr, params)
    return jax.tree_util.tree_map(lambda p, u, r: p - r * u, params, updates, lrs), state

cap, hold, seed, start_json, mode, steps, out_json = (sys.argv[1], sys.argv[2], int(sys.argv[3]),
                                                      sys.argv[4], sys.argv[5], int(sys.argv[6]),
                                                      sys.argv[7])
C_LOG = OFFSET_FRACTION   # of max level, inside the log

train, test, train_instance = split_capture(cap, hold, seed)
shape, top = train.image_shape, train.max_level
res = json.load(open(start_json))['results']
P0 = np.array(next(iter(res.values()))['learned']['patterns_4'], np.float32)
seal = [i for i, n in enumerate(test.class_names) if n.startswith('seal')]


# --- pair features: the product's (mux_classifier.ratio_stats, learned.stack_ratio_stats) --
def pair_np(images):                         # (k, n, pixels) -> (n, 12)
    k, n, p = images.shape
    return ratio_stats(images.reshape(k, n, *shape).transpose(1, 0, 2, 3), C_LOG * top)


def pair_jax(images):                        # (k, n, pixels) -> (n, 12)
    return stack_ratio_stats(images, shape, C_LOG * top)


def base_np(images):
    k, n, p = images.shape
    return intensity_stats_images(images.reshape(k * n, *shape)).reshape(k, n, -1).transpose(1, 0, 2).reshape(n, -1)


def feats_np(images):
    A = base_np(images)
    return A if mode == 'base' else np.hstack([A, pair_np(images)])


def feats_jax(images):
    A = stack_stats(images, shape)
    return A if mode == 'base' else jnp.concatenate([A, pair_jax(images)], axis=1)


# --- evaluation ---------------------------------------------------------------------------
def heldout(P):
    X = np.vstack([feats_np(test_images(train, 'joint', P, 100 + r, seed)) for r in range(6)])
    y = np.tile(train.labels, 6)
    clf = make_pipeline(StandardScaler(), LinearSVC(C=1.0, max_iter=20000)).fit(X, y)
    correct = np.mean([clf.predict(feats_np(test_images(test, 'joint', P, r, seed))) == test.labels
                       for r in range(4)], axis=0)
    on_seal = np.isin(test.labels, seal)
    return float(correct.mean()), float(correct[on_seal].mean())


def inner(P):
    """Pose-fold CV of a linear SVM on one draw of the training samples (5 folds)."""
    X = feats_np(test_images(train, 'joint', P, 200, seed))
    folds = pose_folds(train.pose_index, 5)
    acc = []
    for f in folds:
        clf = make_pipeline(StandardScaler(), LinearSVC(C=1.0, max_iter=20000)).fit(X[~f], train.labels[~f])
        acc.append(np.mean(clf.predict(X[f]) == train.labels[f]))
    return float(np.mean(acc))


# --- descent ------------------------------------------------------------------------------
basis = jnp.asarray(train.basis.reshape(32, train.n_samples, -1))
onehot = jax.nn.one_hot(jnp.asarray(train.labels), len(train.class_names), dtype=jnp.float32)
held = jnp.asarray(pose_folds(train.pose_index, 5))
a, b = train.noise_a, train.noise_b


def loss_fn(theta, idx, eps):
    images = add_noise(relight(jnp.take(basis, idx, axis=1), levels(theta, False)), eps, a, b, top)
    return cv_ridge_loss(feats_jax(images), onehot[idx], jnp.take(held, idx, axis=1), 0.01)


@jax.jit
def step(theta, opt, idx, eps):
    loss, g = jax.value_and_grad(loss_fn)(theta, idx, eps)
    theta, opt = _adam_update(theta, g, opt, jnp.float32(0.2))
    return theta, opt, loss


# numpy and jax pair features agree
imgs = test_images(train.subset(np.arange(8)), 'joint', P0, 0, seed)
print('pair np/jax max diff', float(np.abs(pair_np(imgs) - np.asarray(pair_jax(jnp.asarray(imgs)))).max()), flush=True)

rng = np.random.default_rng([seed, 26, 7])
theta = jnp.asarray(_logits_of(P0))
opt = _adam_init(theta)
B = min(256, train.n_samples)
out = {}
t0 = time.time()
h = heldout(P0)
out[0] = {'inner': inner(P0), 'heldout': h[0], 'seal': h[1]}
print(mode, 0, out[0], flush=True)
for it in range(1, steps + 1):
    idx = np.sort(rng.choice(train.n_samples, B, replace=False))
    eps = rng.standard_normal((4, B, basis.shape[2]), dtype=np.float32)
    theta, opt, loss = step(theta, opt, jnp.asarray(idx), jnp.asarray(eps))
    if it % 50 == 0:
        P = np.asarray(levels(theta, False), np.float32)
        h = heldout(P)
        out[it] = {'inner': inner(P), 'heldout': h[0], 'seal': h[1], 'loss': float(loss),
                   'P': P.round(3).tolist()}
        print(mode, it, {k: v for k, v in out[it].items() if k != 'P'}, f'{time.time() - t0:.0f} s', flush=True)
json.dump(out, open(out_json, 'w'))
