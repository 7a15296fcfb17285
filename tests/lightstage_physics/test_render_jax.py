"""The differentiable renderer (render_jax) against the numpy renderer and noise."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from lightstage_physics.render import render_led_patterns
from lightstage_physics.render_jax import add_noise, led_basis, relight, render_noisy


def test_relight_equals_numpy_renderer(small_modelset):
    rng = np.random.default_rng(0)
    P = rng.uniform(0, 1, (32, 3)).astype(np.float32)
    P[:, 0] = rng.uniform(size=32) > 0.5  # an on/off column too
    ref = render_led_patterns(small_modelset, P, dimmer=0.45)  # (n, k, H, W)
    basis = led_basis(small_modelset, dimmer=0.45)
    out = np.asarray(relight(basis, jnp.asarray(P)))  # (k, n, pixels)
    n, k, H, W = ref.shape
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, ref.transpose(1, 0, 2, 3).reshape(k, n, H * W),
                               rtol=1e-5, atol=1e-5 * ref.max())


def test_noise_equals_numpy_on_the_same_normals():
    from mux_trainer.rendering import SearchData, add_noise_numpy
    rng = np.random.default_rng(1)
    clean = rng.uniform(-20, 1100, (2, 3, 400)).astype(np.float32)
    z = rng.standard_normal(clean.shape, dtype=np.float32)
    data = SearchData(basis=np.zeros((1, 1, 3, 400), np.float32), labels=[0, 1, 0],
                      pose_index=[0, 0, 1], class_names=['a', 'b'], image_shape=(20, 20),
                      noise_a=0.8, noise_b=50.0, max_level=1023.0)
    ref = add_noise_numpy(data, clean, z)
    out = np.asarray(add_noise(jnp.asarray(clean), jnp.asarray(z), 0.8, 50.0, 1023.0))
    np.testing.assert_allclose(out, ref, rtol=1e-6, atol=1e-3)
    assert out.max() <= 1023.0 and out.min() >= 0.0


@pytest.mark.parametrize('level', [30.0, 400.0])
def test_noise_statistics_follow_the_affine_model(level):
    a, b = 0.7, 66.0
    mean = jnp.full((1, 1, 200_000), level, jnp.float32)
    basis = mean.reshape(1, 1, -1)
    out = np.asarray(render_noisy(basis, jnp.ones((1, 1)), jax.random.PRNGKey(3), a, b, 1e6))
    n = out.size
    var = a * level + b
    # the mean within 5 standard errors, the variance within 5 of its standard errors
    assert abs(out.mean() - level) < 5 * np.sqrt(var / n)
    assert abs(out.var() - var) < 5 * var * np.sqrt(2.0 / n)


def test_gradient_reaches_the_levels_and_stops_at_saturation(small_modelset):
    basis = led_basis(small_modelset, dimmer=0.45)
    key = jax.random.PRNGKey(0)

    def total(P, top, a=0.7, b=66.0):
        return render_noisy(basis, P, key, a, b, top).sum()

    P = jnp.full((32, 1), 0.5)
    g = np.asarray(jax.grad(total)(P, 1e6))
    assert np.isfinite(g).all() and (g > 0).all()  # more light, brighter images
    g_sat = np.asarray(jax.grad(total)(P, 1e-3, 0.0, 0.0))  # every pixel clipped: none
    np.testing.assert_array_equal(g_sat, 0)


def test_bad_input_names_the_problem(small_modelset):
    with pytest.raises(ValueError, match='dimmer'):
        led_basis(small_modelset, dimmer=0)
    with pytest.raises(ValueError, match='rows'):
        relight(led_basis(small_modelset), jnp.ones((8, 1)))
