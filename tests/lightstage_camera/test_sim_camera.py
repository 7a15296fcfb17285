"""The simulated camera without ROS: rendering, noise statistics, mono16 encoding, samples."""
import math

import numpy as np
import pytest
from lightstage_camera.camera_backend import Trigger
from lightstage_physics.noise import PAPER_CALIBRATION, PRESETS
from lightstage_physics.render import render_led_patterns, render_site_patterns
from lightstage_physics.rig import Rig
from lightstage_physics.scene_models import ModelSet
from lightstage_camera.sim_camera import (SampleError, SimCamera, SimCameraBackend, encode_mono16,
                                          resolve_sample)


def flat_modelset(level=100.0, size=64, n=3, seed=0):
    """Models whose every LED image is a constant `level` (x a per-sample factor), plus a
    random one, so noise statistics can be read off one frame's pixels."""
    rng = np.random.default_rng(seed)
    models = np.full((n, 4, 8, size, size), level, np.float32)
    models[-1] = rng.uniform(0, 200, size=(4, 8, size, size))
    labels = np.arange(n) % 2
    names = [f"{['apple-fake', 'apple-real'][lab]}/s{i}/p00" for i, lab in enumerate(labels)]
    return ModelSet(models, labels, ['apple-fake', 'apple-real'], names, np.arange(n),
                    np.arange(n), Rig.paper_default(size))


def one_led(led):
    p = np.zeros(32, np.float32)
    p[led] = 1
    return p


def test_render_is_the_joint_render_of_the_current_sample_and_matches_per_colour_mode():
    ms = flat_modelset()
    cam = SimCamera(ms, sample=2, noise='none', dimmer=0.45)
    rng = np.random.default_rng(1)
    leds = (rng.random(32) > 0.5).astype(np.float32)
    np.testing.assert_allclose(cam.render(leds), render_led_patterns(ms.models[2:3], leds, 0.45)[0, 0],
                               rtol=1e-6)
    # a site pattern in the paper's per-colour mode: LEDs site*4 + c for colour c
    w = np.array([1, 0, 1, 0, 0, 1, 0, 1], np.float32)
    site_images = render_site_patterns(ms.models[2:3], w[:, None], 0.45)[0]  # (4, H, W)
    for c in range(4):
        leds = np.zeros(32, np.float32)
        leds[np.flatnonzero(w) * 4 + c] = 1
        np.testing.assert_allclose(cam.render(leds), site_images[c], rtol=1e-5)


def test_capture_is_mono16_msb_aligned_whole_levels_and_noise_free_when_off():
    ms = flat_modelset()
    cam = SimCamera(ms, sample=2, noise='none')
    leds = np.ones(32, np.float32) * 0.5
    frame = cam.capture(leds, 30000, 15.0)
    assert frame.dtype == np.uint16 and frame.shape == ms.image_shape
    assert np.all(frame & 0x3F == 0)  # 10-bit values << 6
    expected = np.clip(np.rint(cam.render(leds)), 0, 1023)
    np.testing.assert_array_equal(frame >> 6, expected)


def test_saturation_clips_at_the_camera_range():
    ms = flat_modelset(level=1000.0)
    frame = SimCamera(ms, sample=0, noise='auto', seed=0).capture(np.ones(32), 30000, 15.0)
    assert frame.max() == 1023 << 6 and np.all(frame == 1023 << 6)
    assert encode_mono16(np.array([-5.0, 0.4, 1022.6, 4000.0]), 10).tolist() == [0, 0, 1023 << 6, 1023 << 6]
    assert encode_mono16(np.array([255.0]), 12).tolist() == [255 << 4]


@pytest.mark.parametrize('gain_db, exposure_us', [(17.5, 22500), (6.0, 84000), (12.0, 42000)])
def test_auto_noise_has_the_affine_variance_at_the_triggers_gain_and_exposure_and_fixed_mean(
        gain_db, exposure_us):
    ms = flat_modelset(level=100.0, size=128)
    cam = SimCamera(ms, sample=0, noise='auto', seed=5)
    leds = one_led(5) + one_led(9)  # two LEDs of 100 at dimmer 0.45: mean 90
    gray = cam.capture(leds, exposure_us, gain_db).astype(np.float64) / 64
    expected = PAPER_CALIBRATION.at(gain_db, exposure_us / 1000).variance(90.0)
    # the paper's presets are those settings (to the rounding of the fit)
    name = {17.5: 'sigma3', 6.0: 'sigma1', 12.0: 'sigma2'}[gain_db]
    assert expected == pytest.approx(PRESETS[name].variance(90.0), rel=0.02)
    assert gray.mean() == pytest.approx(90.0, abs=0.1)  # mean independent of gain/exposure
    # variance of 16k pixels: +-2.2 % (1 sigma); quantisation adds 1/12
    assert gray.var() == pytest.approx(expected + 1 / 12, rel=0.08)


def test_preset_noise_ignores_the_trigger_settings_and_nan_gain_uses_the_default():
    ms = flat_modelset(level=100.0, size=128)
    leds = one_led(0) + one_led(1)
    fixed = SimCamera(ms, sample=0, noise='sigma1', seed=0)
    a = fixed.capture(leds, 1000, 24.0).astype(np.float64) / 64
    assert a.var() == pytest.approx(PRESETS['sigma1'].variance(90.0) + 1 / 12, rel=0.08)
    auto = SimCamera(ms, sample=0, noise='auto', default_gain_db=6.0, seed=0)
    assert auto.noise_model(84000, math.nan) == PAPER_CALIBRATION.at(6.0, 84.0)
    assert auto.noise_model(84000, 12.0) == PAPER_CALIBRATION.at(12.0, 84.0)
    with pytest.raises(ValueError, match='exposure_us must be > 0'):
        auto.capture(leds, 0, 12.0)
    with pytest.raises(ValueError, match='unknown noise setting'):
        SimCamera(ms, noise='sigma9')


def test_samples_by_name_or_index_and_clear_errors():
    ms = flat_modelset()
    assert resolve_sample(ms, 'apple-real/s1/p00') == 1
    assert resolve_sample(ms, 2) == 2 and resolve_sample(ms, '2') == 2
    with pytest.raises(SampleError, match=r"did you mean apple-real/s1/p00"):
        resolve_sample(ms, 'apple-real/s1/p0')
    with pytest.raises(SampleError, match=r'out of range.*0\.\.2'):
        resolve_sample(ms, 7)
    cam = SimCamera(ms, sample='apple-fake/s0/p00', noise='none')
    assert cam.label == 'apple-fake'
    before = cam.capture(one_led(3), 30000)
    cam.set_sample(2)
    assert cam.sample_name == 'apple-fake/s2/p00'
    assert not np.array_equal(before, cam.capture(one_led(3), 30000))
    with pytest.raises(SampleError):
        cam.set_sample('banana-fake/s0/p00')
    assert cam.sample_index == 2  # a rejected change leaves the stage as it was


def test_bad_led_patterns_are_rejected_with_the_reason():
    cam = SimCamera(flat_modelset(), noise='none')
    with pytest.raises(ValueError, match=r'\(32, k\)'):
        cam.capture(np.ones(31), 30000)
    with pytest.raises(ValueError, match='must lie in'):
        cam.capture(np.full(32, 1.5), 30000)


def test_seeded_cameras_repeat_and_differ_between_frames():
    ms = flat_modelset()
    a, b = SimCamera(ms, noise='sigma3', seed=4), SimCamera(ms, noise='sigma3', seed=4)
    f1, f2 = a.capture(one_led(0), 30000), a.capture(one_led(0), 30000)
    assert np.array_equal(f1, b.capture(one_led(0), 30000))
    assert not np.array_equal(f1, f2)


def test_sim_backend_delivers_one_frame_per_trigger_with_that_trigger(stage_capture):
    frames = []
    backend = SimCameraBackend.from_capture(frames.append, stage_capture, sample='orange-fake/s1/p02',
                                            noise='none')
    trigger = Trigger(stamp_ns=1_700_000_000_123_456_789, sequence=41, led_intensities=one_led(2),
                      exposure_us=22500, gain_db=17.5)
    backend.trigger(trigger)
    (frame,) = frames
    assert frame.trigger is trigger and frame.bit_depth == 10
    assert frame.info == {'sample': 'orange-fake/s1/p02', 'label': 'orange-fake'}
    np.testing.assert_array_equal(frame.image, backend.camera.capture(one_led(2), 22500, 17.5))
    status = backend.status()
    assert status.ok and status.values['frames'] == 1 and status.values['samples'] == 24


def test_from_capture_names_a_missing_folder(tmp_path):
    with pytest.raises(ValueError, match='not a directory'):
        SimCameraBackend.from_capture(lambda f: None, tmp_path / 'missing')
