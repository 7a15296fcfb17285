"""A probe (docs/research/LEARNED_PATH.md): a small convolutional head instead of the statistics.
Conv layers (3 x 3, ReLU, 2 x 2 average pooling) over the k images' logs, then the global
mean and max of each channel (pose-robust by construction) and a linear layer; trained by
Adam with fresh noise every step on the training samples relit under a fixed light, early
stopped on one pose fold of them (`pose_folds`), tested on the held-out samples (4 renders).
With joint=1 the light's logits are trained too. Not a part of the model.

    PYTHONPATH=src/lightstage_physics:src/mux_classifier:src/mux_trainer CNN_POOL=2 CNN_WIDTH=8 \
        CNN_DEPTH=3 .venv/bin/python benchmarks/learned_cnn_head.py DIR/mix16 instances 0 \
        sides_visible_nir 1500 0 out.json

light: a hand matrix of learned_light_headroom.py, 'raking_sides', or a learned_vs_greedy.py
JSON (its kept 4-exposure light). Environment: CNN_WIDTH (channels of the first layer),
CNN_DEPTH (layers), CNN_POOL (the input downscaled by this first), CNN_LR, CNN_WD, CNN_BATCH.
"""
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from learned_light_headroom import hand_patterns
from learned_vs_greedy import split_capture
from lightstage_physics.render_jax import add_noise, relight
from lightstage_physics.rig import Rig
from mux_trainer.holdout import test_images
import optax
from mux_trainer.learned import levels, pose_folds, raking_sides_start
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

cap, hold, seed, light, steps, joint, out_json = (sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4],
                                                   int(sys.argv[5]), int(sys.argv[6]), sys.argv[7])
WIDTH = int(os.environ.get('CNN_WIDTH', 16)); LR = float(os.environ.get('CNN_LR', 3e-3))
WD = float(os.environ.get('CNN_WD', 1e-4)); BATCH = int(os.environ.get('CNN_BATCH', 64))
train, test, _ = split_capture(cap, hold, seed)
H, W = train.image_shape; top = train.max_level; a, b = train.noise_a, train.noise_b
if light.endswith('.json'):
    P0 = np.array(next(iter(json.load(open(light))['results'].values()))['learned']['patterns_4'], np.float32)
elif light == 'raking_sides':
    P0 = raking_sides_start(Rig.paper_default().site_positions_mm(), 4, 4, None)
else:
    P0 = hand_patterns()[light]
k = P0.shape[1]; n_classes = len(train.class_names)
folds = pose_folds(train.pose_index, 5)
val = folds[0]; fit_idx = np.flatnonzero(~val); val_idx = np.flatnonzero(val)
basis = jnp.asarray(train.basis.reshape(32, train.n_samples, -1))
C0 = 0.01 * top

POOL = int(os.environ.get('CNN_POOL', 1))
def prep(images):  # (k, n, pixels) -> (n, H, W, k)
    x = images.reshape(k, -1, H // POOL, POOL, W // POOL, POOL).mean((3, 5))
    x = jnp.log(jnp.maximum(x, 0) + C0) - jnp.log(top)
    return x.transpose(1, 2, 3, 0)

def conv(x, w, bias):
    y = jax.lax.conv_general_dilated(x, w, (1, 1), 'SAME', dimension_numbers=('NHWC', 'HWIO', 'NHWC'))
    return jax.nn.relu(y + bias)

def pool(x):
    n, h, w_, c = x.shape
    return x[:, :h // 2 * 2, :w_ // 2 * 2].reshape(n, h // 2, 2, w_ // 2, 2, c).mean((2, 4))

def net(params, x):
    x = x - params['mu']
    for i, (w, bias) in enumerate(params['convs']):
        x = conv(x, w, bias)
        x = pool(x)
    f = jnp.concatenate([x.mean((1, 2)), x.max((1, 2))], axis=1)
    return f @ params['W'] + params['b']

rng = np.random.default_rng([seed, 99])
def init():
    chans = [k, WIDTH, 2 * WIDTH, 2 * WIDTH, 2 * WIDTH][:int(os.environ.get('CNN_DEPTH', 4)) + 1]
    convs = [(jnp.asarray(rng.standard_normal((3, 3, ci, co)) * np.sqrt(2 / (9 * ci)), jnp.float32),
              jnp.zeros(co, jnp.float32)) for ci, co in zip(chans[:-1], chans[1:])]
    return {'convs': convs, 'W': jnp.asarray(rng.standard_normal((2 * chans[-1], n_classes)) * 0.01, jnp.float32),
            'b': jnp.zeros(n_classes, jnp.float32)}

clean0 = relight(basis, jnp.asarray(P0))
mu = jnp.asarray(np.asarray(prep(clean0)).mean((0, 1, 2)))
params = init(); theta = jnp.asarray(_logits_of(P0))
labels = jnp.asarray(train.labels, jnp.int32)

def loss_fn(params, theta, idx, eps):
    P = levels(theta, False) if joint else jnp.asarray(P0)
    imgs = add_noise(relight(jnp.take(basis, idx, axis=1), P), eps, a, b, top)
    logits = net({**params, 'mu': mu}, prep(imgs))
    ce = -jnp.mean(jnp.take_along_axis(jax.nn.log_softmax(logits), labels[idx][:, None], 1))
    l2 = sum(jnp.sum(w * w) for w, _ in params['convs']) + jnp.sum(params['W'] ** 2)
    return ce + WD * l2

@jax.jit
def step(params, theta, sp, st, idx, eps):
    loss, (gp, gt) = jax.value_and_grad(loss_fn, argnums=(0, 1))(params, theta, idx, eps)
    params, sp = _adam_update(params, gp, sp, jax.tree_util.tree_map(lambda _: jnp.float32(LR), params))
    theta, st = _adam_update(theta, gt, st, jnp.float32(0.05 * joint))
    return params, theta, sp, st, loss


@jax.jit
def predict(params, images):
    return jnp.argmax(net({**params, 'mu': mu}, prep(images)), 1)

def accuracy(params, P, data, renders, r0, idx=None):
    acc = []
    for r in range(renders):
        imgs = test_images(data, 'joint', P, r0 + r, seed)
        if idx is not None:
            imgs = imgs[:, idx]
        yy = data.labels if idx is None else data.labels[idx]
        acc.append(np.asarray(predict(params, jnp.asarray(imgs))) == yy)
    return np.mean(acc, axis=0)

sp, st = _adam_init(params), _adam_init(theta)
best = (-1, None, None, 0)
seal = np.array([n.startswith('seal') for n in test.class_names])[test.labels]
t0 = time.time(); log = []
for it in range(1, steps + 1):
    idx = np.sort(rng.choice(fit_idx, min(BATCH, fit_idx.size), replace=False))
    eps = rng.standard_normal((k, idx.size, H * W), dtype=np.float32)
    params, theta, sp, st, loss = step(params, theta, sp, st, jnp.asarray(idx), jnp.asarray(eps))
    if it % 100 == 0:
        P = np.asarray(levels(theta, False), np.float32) if joint else P0
        v = float(accuracy(params, P, train, 2, 300, val_idx).mean())
        tst = accuracy(params, P, test, 4, 0)
        log.append({'step': it, 'loss': float(loss), 'val': v, 'test': float(tst.mean()), 'seal': float(tst[seal].mean())})
        print(light, it, log[-1], f'{time.time() - t0:.0f} s', flush=True)
        if v > best[0]:
            best = (v, params, P, it)
v, params, P, it = best
tst = accuracy(params, P, test, 4, 0)
res = {'light': light, 'hold': hold, 'seed': seed, 'joint': joint, 'best_step': it, 'val': v,
       'test': float(tst.mean()), 'seal': float(tst[seal].mean()), 'log': log, 'seconds': time.time() - t0}
print('RESULT', light, hold, seed, 'joint' if joint else 'fixed', f'val {v:.3f} step {it} test {100 * res["test"]:.1f} seal {100 * res["seal"]:.1f}', flush=True)
json.dump(res, open(out_json, 'w'))
