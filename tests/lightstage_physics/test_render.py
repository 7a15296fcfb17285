import numpy as np
import pytest

from lightstage_physics.render import (led_to_channel_major, render_led_patterns,
                                       render_noisy, render_site_patterns)
from lightstage_physics.rig import led_index
from lightstage_physics.noise import PRESETS


def test_site_patterns_shape_and_order(small_modelset):
    m = small_modelset.models
    W = np.zeros((8, 2), np.float32)
    W[3, 0] = 1.0
    W[[0, 5], 1] = [0.5, 1.0]
    out = render_site_patterns(small_modelset, W, dimmer=1.0)
    assert out.shape == (len(m), 8, 24, 24) and out.dtype == np.float32
    for c in range(4):
        np.testing.assert_allclose(out[:, 0 * 4 + c], m[:, c, 3], rtol=1e-6)
        np.testing.assert_allclose(out[:, 1 * 4 + c], 0.5 * m[:, c, 0] + m[:, c, 5], rtol=1e-5)


def test_dimmer_and_linearity(small_modelset):
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 0.5, (8, 3)), rng.uniform(0, 0.5, (8, 3))
    ra = render_site_patterns(small_modelset, a)
    rb = render_site_patterns(small_modelset, b)
    rab = render_site_patterns(small_modelset, a + b)
    np.testing.assert_allclose(rab, ra + rb, rtol=1e-4, atol=1e-3)
    full = render_site_patterns(small_modelset, a, dimmer=1.0)
    np.testing.assert_allclose(ra, 0.45 * full, rtol=1e-5, atol=1e-4)


def test_led_patterns_site_major(small_modelset):
    m = small_modelset.models
    P = np.zeros((32, 3))
    P[led_index(2, "nir"), 0] = 1
    P[led_index(7, "red"), 1] = 1
    P[:, 2] = 1
    out = render_led_patterns(small_modelset, P, dimmer=1.0)
    assert out.shape == (len(m), 3, 24, 24)
    np.testing.assert_allclose(out[:, 0], m[:, 3, 2])
    np.testing.assert_allclose(out[:, 1], m[:, 0, 7])
    np.testing.assert_allclose(out[:, 2], m.sum(axis=(1, 2)), rtol=1e-5)


def test_led_mode_equals_site_mode_for_one_colour(small_modelset):
    w = np.array([1, 0, 1, 1, 0, 0, 1, 0], np.float32)
    P = np.zeros((32, 1))
    P[[led_index(s, "green") for s in range(8) if w[s]], 0] = 1
    np.testing.assert_allclose(render_led_patterns(small_modelset, P)[:, 0],
                               render_site_patterns(small_modelset, w)[:, 1], rtol=1e-5)


def test_led_to_channel_major_roundtrip():
    P = np.arange(32)[:, None]
    cm = led_to_channel_major(P)[:, 0]
    assert cm[0 * 8 + 5] == led_index(5, "red") and cm[3 * 8 + 1] == led_index(1, "nir")


@pytest.mark.parametrize("W, message", [
    (np.ones((7, 1)), "shape"),
    (np.full((8, 1), np.nan), "non-finite"),
    (np.full((8, 1), 1.5), r"\[0, 1\]"),
    (-np.ones((8, 1)), r"\[0, 1\]"),
    (np.ones((8, 0)), "no columns"),
])
def test_bad_site_patterns(small_modelset, W, message):
    with pytest.raises(ValueError, match=message):
        render_site_patterns(small_modelset, W)


def test_bad_led_pattern_and_models(small_modelset):
    with pytest.raises(ValueError, match=r"\(32, k\)"):
        render_led_patterns(small_modelset, np.ones((8, 1)))
    with pytest.raises(ValueError, match="models must be"):
        render_site_patterns(np.ones((2, 3, 8, 4, 4)), np.ones((8, 1)))
    with pytest.raises(ValueError, match="dimmer"):
        render_site_patterns(small_modelset, np.ones((8, 1)), dimmer=0)


def test_render_noisy_clips_and_is_seeded(small_modelset):
    W = np.ones((8, 1))
    a = render_noisy(small_modelset, W, PRESETS["sigma3"], np.random.default_rng(3))
    b = render_noisy(small_modelset, W, PRESETS["sigma3"], np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert a.min() >= 0 and a.max() <= 1023
    clean = render_noisy(small_modelset, W, None, np.random.default_rng(3))
    np.testing.assert_allclose(clean, np.clip(render_site_patterns(small_modelset, W), 0, 1023))


def test_render_noisy_modes_and_noise_scale(small_modelset):
    P = np.ones((32, 2))
    led = render_noisy(small_modelset, P, None, np.random.default_rng(0), mode="led")
    assert led.shape == (len(small_modelset), 2, 24, 24)
    with pytest.raises(ValueError, match="mode"):
        render_noisy(small_modelset, P, None, np.random.default_rng(0), mode="joint")
    # a downscaled ModelSet carries its noise_scale into the noise
    small = small_modelset.downscaled(12)
    flat = small.subset([0])
    flat.models[:] = 100.0
    x = render_noisy(flat, np.ones((8, 1)), PRESETS["sigma3"], np.random.default_rng(1),
                     dimmer=1 / 8)
    expected = PRESETS["sigma3"].variance(100.0) / 4
    assert x.var() == pytest.approx(expected, rel=0.2)
