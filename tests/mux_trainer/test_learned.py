"""Learned illumination: the differentiable statistics, the training and the numpy model."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mux_classifier.intensity_stats import intensity_stats_images_numpy
from mux_classifier.learned_model import LearnedModel

from mux_trainer.holdout import holdout_split
from mux_trainer.learned import (LearnedIlluminationClassifier, evaluate_learned_heldout,
                                 forward_features, image_stats, stack_stats)
from mux_trainer.rendering import SearchData, clean_led_images


def disk_data(n_classes=3, n_poses=8, size=24, seed=0):
    """A bright disk anywhere on a dark floor; class k reflects 60 % more under one LED
    (site k, NIR) than the others do; each pose also varies in overall brightness (a
    nuisance every LED sees)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    models, labels, poses = [], [], []
    for k in range(n_classes):
        for p in range(n_poses):
            cy, cx = rng.uniform(7, size - 7, 2)
            disk = ((yy - cy) ** 2 + (xx - cx) ** 2 < 25).astype(np.float32)
            refl = rng.uniform(0.8, 1.2) * rng.uniform(0.9, 1.1, (4, 8)).astype(np.float32)
            refl[3, k] *= 1.6
            models.append(8.0 + 90.0 * refl[:, :, None, None] * disk)
            labels.append(k)
            poses.append(p)
    return SearchData.from_models(np.stack(models), labels, poses,
                                  [f'c{k}' for k in range(n_classes)], dimmer=1.0,
                                  noise_a=0.7, noise_b=66.0)


def _images(data, k=3, seed=0):
    P = np.random.default_rng(seed).uniform(0, 1, (32, k)).astype(np.float32)
    return clean_led_images(data, P)  # (k, n, pixels)


def test_statistics_equal_the_numpy_reference(tiny_data):
    images = _images(tiny_data)
    k, n, p = images.shape
    # a dark floor around a bright object, as on the stage, so the mask matters
    framed = np.zeros((k * n, 30, 30), np.float32)
    framed[:, 3:27, 3:27] = images.reshape(k * n, 24, 24)
    framed += np.random.default_rng(1).normal(5, 1, framed.shape).astype(np.float32)
    ref = intensity_stats_images_numpy(framed)
    out = np.asarray(jax.jit(lambda x: image_stats(x, (30, 30)))(
        jnp.asarray(framed.reshape(k * n, -1))))
    np.testing.assert_allclose(out, ref, rtol=2e-5, atol=1e-3)


def test_statistics_pass_a_finite_gradient_to_the_levels(tiny_data):
    basis = jnp.asarray(tiny_data.basis[:, :, :8].reshape(32, 8, -1))

    def score(P):
        images = jnp.tensordot(P, basis, axes=([0], [0]))
        return stack_stats(images, tiny_data.image_shape).sum()

    g = np.asarray(jax.grad(score)(jnp.full((32, 2), 0.5)))
    assert np.isfinite(g).all() and np.abs(g).max() > 0


@pytest.fixture(scope='module')
def fitted():
    data = disk_data()
    train_idx, test_idx = holdout_split(data, 0.25, seed=0)
    train, test = data.subset(train_idx), data.subset(test_idx)
    model = LearnedIlluminationClassifier(n_images=2, max_steps=40, batch_size=16,
                                          head_steps=100, seed=0).fit(train)
    return model, test


def test_learns_the_classes_above_chance(fitted):
    model, test = fitted
    acc = evaluate_learned_heldout(model, test, n_renders=2, seed=0)['accuracy']
    # 3 classes (chance 33 %); the cue is strong where the light finds it
    assert acc >= 0.8, acc
    assert model.patterns_.shape == (32, 2)
    assert model.patterns_.min() >= 0 and model.patterns_.max() <= 1
    assert model.classifiers_ == {2: model.model_} and model.best_n_patterns_ == 2
    assert 0 <= model.accuracy_by_images_[2] <= 1


def test_numpy_forward_equals_jax_forward(fitted):
    model, test = fitted
    m = model.model_
    images = clean_led_images(test, m.patterns) + np.float32(3.0)
    k, n, p = images.shape
    stacks = images.transpose(1, 0, 2).reshape(n, k, *test.image_shape)
    F_jax = stack_stats(jnp.asarray(images), test.image_shape)
    logits_jax = np.asarray(forward_features([(jnp.asarray(W), jnp.asarray(b)) for W, b in m.layers],
                                             jnp.asarray(m.feature_mean),
                                             jnp.asarray(m.feature_scale), F_jax))
    logits_np = m.logits_from_features(m.features(stacks))
    np.testing.assert_allclose(logits_np, logits_jax, rtol=1e-4,
                               atol=1e-4 * np.abs(logits_jax).max())
    np.testing.assert_array_equal(m.predict(stacks), np.argmax(logits_jax, axis=1))
    again = LearnedModel.from_arrays(m.to_arrays())
    np.testing.assert_array_equal(again.logits_from_features(m.features(stacks)), logits_np)
    assert again.class_names == m.class_names


def test_binary_patterns_are_on_off(tiny_data):
    model = LearnedIlluminationClassifier(n_images=1, binary=True, max_steps=10, batch_size=8,
                                          head_steps=20, head_renders=2, seed=1).fit(tiny_data)
    assert set(np.unique(model.patterns_)) <= {0.0, 1.0}
    assert model.patterns_.any()


def test_bad_settings_and_inputs_are_refused(tiny_data, fitted):
    one_pose = tiny_data.subset(np.flatnonzero(tiny_data.pose_index == 0))
    with pytest.raises(ValueError, match='at least 2 training poses'):
        LearnedIlluminationClassifier(max_steps=1).fit(one_pose)
    with pytest.raises(ValueError, match='n_images'):
        LearnedIlluminationClassifier(n_images=0).fit(tiny_data)
    model, _ = fitted
    with pytest.raises(ValueError, match='intensity statistics'):
        model.predict_features(np.zeros((3, 5)), 2)
    with pytest.raises(ValueError, match='not available'):
        model.predict_features(np.zeros((3, 18)), 1)
    with pytest.raises(ValueError, match='stacks'):
        model.model_.predict(np.zeros((2, 3, 24, 24)))
