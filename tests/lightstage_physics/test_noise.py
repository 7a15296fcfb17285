import numpy as np
import pytest

from lightstage_physics.noise import (PAPER_CALIBRATION, PRESETS, SETTINGS, NoiseModel,
                                      choose_gain, gain_ratio, preset)


def brightness_factor(gain_db: float, exposure_ms: float, reference_gain_db: float,
                      reference_exposure_ms: float) -> float:
    """How much brighter an image is at (gain, exposure) than at the reference setting."""
    return gain_ratio(gain_db, reference_gain_db) * exposure_ms / reference_exposure_ms


def test_generalization_formula():
    base = NoiseModel(0.7, 66.0, 15.0, 30.0)
    same = base.at(15.0, 30.0)
    assert same.sigma_p2 == pytest.approx(0.7) and same.sigma_r2 == pytest.approx(66.0)
    # +6.0206 dB doubles the amplitude gain: variance x4; doubling exposure doubles photon term
    m = base.at(15.0 + 20 * np.log10(2), 60.0)
    assert m.sigma_p2 == pytest.approx(0.7 * 4 * 2) and m.sigma_r2 == pytest.approx(66 * 4)
    # generalizing twice equals generalizing once
    twice = base.at(9.0, 50.0).at(17.5, 22.5)
    once = base.at(17.5, 22.5)
    assert twice.sigma_p2 == pytest.approx(once.sigma_p2)
    assert twice.sigma_r2 == pytest.approx(once.sigma_r2)


def test_presets_are_the_papers_printed_values():
    printed = {"sigma1": (0.25, 8.35), "sigma2": (0.50, 33.23), "sigma3": (0.94, 117.37)}
    for name, (p, r) in printed.items():
        assert (preset(name).sigma_p2, preset(name).sigma_r2) == (p, r)
        assert (preset(name).gain_db, preset(name).exposure_ms) == SETTINGS[name]


def test_sigma_presets_reproduced_from_the_15db_30ms_fit():
    """The paper prints its fit rounded (0.7, 66). A fit inside that rounding interval,
    sigma_p2 = 0.708, sigma_r2 = 66.0, reproduces every printed photon coefficient to the
    printed two decimals and Sigma3's read noise to the printed 117.37; Sigma1/Sigma2
    read noise (8.35, 33.23) need sigma_r2 = 66.3 while Sigma3's needs 66.00, so no single
    fit matches those two to the last digit: they agree to 0.5 %. With the rounded 0.7/66
    every coefficient is within 2 %."""
    fit = NoiseModel(0.708, 66.0, 15.0, 30.0)
    for name, (g, e) in SETTINGS.items():
        m = fit.at(g, e)
        assert round(m.sigma_p2, 2) == PRESETS[name].sigma_p2
        assert m.sigma_r2 == pytest.approx(PRESETS[name].sigma_r2, rel=5e-3)
    assert round(fit.at(*SETTINGS["sigma3"]).sigma_r2, 2) == 117.37
    for name, (g, e) in SETTINGS.items():
        m = PAPER_CALIBRATION.at(g, e)
        assert m.sigma_p2 == pytest.approx(PRESETS[name].sigma_p2, rel=0.02)
        assert m.sigma_r2 == pytest.approx(PRESETS[name].sigma_r2, rel=0.006)


def test_preset_errors():
    assert preset("none") is None
    assert preset(" Sigma2 ") is PRESETS["sigma2"]
    with pytest.raises(ValueError, match="sigma1, sigma2, sigma3, none"):
        preset("sigma4")
    with pytest.raises(ValueError, match="sigma_p2"):
        NoiseModel(-1.0, 1.0)


def test_sample_statistics_and_clipping():
    model = PRESETS["sigma3"]
    rng = np.random.default_rng(0)
    mean = np.full((200, 500), 300.0, np.float32)
    x = model.sample(mean, rng)
    assert x.dtype == np.float32
    assert x.mean() == pytest.approx(300, abs=0.2)
    assert x.var() == pytest.approx(model.variance(300.0), rel=0.02)
    y = model.sample(mean, rng, noise_scale=0.25)
    assert y.var() == pytest.approx(model.variance(300.0) / 4, rel=0.02)
    bright = model.sample(np.full((100, 100), 1100.0, np.float32), rng)
    assert bright.max() == 1023 and bright.min() > 900
    dark = model.sample(np.zeros((100, 100), np.float32), rng)
    assert dark.min() == 0
    # in place on the mean array
    buf = mean.copy()
    out = model.sample(buf, np.random.default_rng(5), out=buf)
    assert out is buf
    np.testing.assert_array_equal(out, model.sample(mean, np.random.default_rng(5)))


def test_choose_gain_brings_brightest_image_to_target():
    images = np.stack([np.full((10, 10), 100.0), np.full((10, 10), 400.0)])
    g = choose_gain(images, exposure_ms=30.0, reference_gain_db=15.0, reference_exposure_ms=30.0,
                    target_fraction=0.4)
    assert 400 * gain_ratio(g, 15.0) == pytest.approx(0.4 * 1023)
    # shorter exposure needs more gain, by exactly the exposure ratio
    g_short = choose_gain(images, 15.0, 15.0, 30.0, target_fraction=0.4)
    assert gain_ratio(g_short, g) == pytest.approx(2.0)
    assert brightness_factor(g_short, 15.0, 15.0, 30.0) * 400 == pytest.approx(0.4 * 1023)
    # clipped to the camera's range
    assert choose_gain(images * 1e4, 30.0, 15.0, 30.0) == 0.0
    assert choose_gain(np.zeros((1, 4, 4)), 30.0, 15.0, 30.0) == 24.0
