import numpy as np
import pytest

from lightstage_physics.calibration_target import simulate_calibration_frames
from lightstage_physics.noise_fit import fit_noise_model, noise_characteristic
from lightstage_physics.noise import PRESETS, SETTINGS, NoiseModel


@pytest.mark.parametrize("truth", [NoiseModel(0.7, 66.0), NoiseModel(0.25, 8.35),
                                   NoiseModel(1.8, 20.0), NoiseModel(0.3, 150.0)])
def test_calibration_recovers_known_parameters(truth):
    frames = simulate_calibration_frames(truth, n_levels=8, n_frames=60,
                                         rng=np.random.default_rng(1))
    fit = fit_noise_model(frames, gain_db=truth.gain_db, exposure_ms=truth.exposure_ms)
    assert fit.sigma_p2 == pytest.approx(truth.sigma_p2, rel=0.05)
    assert fit.sigma_r2 == pytest.approx(truth.sigma_r2, rel=0.05)


def test_calibrated_model_generalizes_to_sigma_settings():
    """Calibrate at 15 dB / 30 ms from frames, then predict Sigma3 and check it against
    frames simulated at the Sigma3 setting (the paper's validation experiment)."""
    truth = NoiseModel(0.7, 66.0)
    fit = fit_noise_model(simulate_calibration_frames(truth, n_frames=60,
                                                      rng=np.random.default_rng(2)))
    predicted = fit.at(*SETTINGS["sigma3"])
    measured = fit_noise_model(simulate_calibration_frames(truth.at(*SETTINGS["sigma3"]),
                                                           n_frames=60,
                                                           rng=np.random.default_rng(3)))
    assert predicted.sigma_p2 == pytest.approx(measured.sigma_p2, rel=0.06)
    assert predicted.sigma_r2 == pytest.approx(measured.sigma_r2, rel=0.06)
    assert predicted.sigma_r2 == pytest.approx(PRESETS["sigma3"].sigma_r2, rel=0.05)


def test_saturated_pixels_are_excluded():
    truth = NoiseModel(0.7, 66.0)
    frames = simulate_calibration_frames(truth, n_levels=4, n_frames=30, peak_level=2500,
                                         rng=np.random.default_rng(4))
    char = noise_characteristic(frames)
    assert char.pixel_mean.max() < 1023
    # without the exclusion the clipped pixels would pull the slope down
    fit = fit_noise_model(frames)
    assert fit.sigma_p2 == pytest.approx(0.7, rel=0.08)


def test_bad_calibration_input():
    with pytest.raises(ValueError, match="at least 3 frames per level"):
        fit_noise_model([np.zeros((1, 4, 4))])
    with pytest.raises(ValueError, match="no calibration levels"):
        fit_noise_model([])
    with pytest.raises(ValueError, match="usable pixels"):
        fit_noise_model([np.full((5, 8, 8), 1023.0)])
