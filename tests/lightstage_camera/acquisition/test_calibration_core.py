"""Noise calibration on the stage without ROS: levels, moments, the fit's uncertainty, files."""
import numpy as np
import pytest
import yaml

from helpers.acquisition import sim_grab
from lightstage_camera import calibration as cal
from lightstage_camera import calibration_outputs as couts
from lightstage_physics import calibration_target as ctarget
from lightstage_physics import noise_fit as nfit
from lightstage_physics.capture_format import load_capture
from lightstage_physics.errors import (AcquisitionError, CaptureCancelled, DestinationError,
                                     NoiseFileError)
from lightstage_physics.noise import (PAPER_CALIBRATION, SETTINGS, NoiseModel, load_noise_file,
                                      noise_setting, save_noise_file)
from lightstage_camera.sim_camera import SimCamera

# the 1/12 gray level^2 that rounding to whole gray levels adds to every frame's variance
QUANTIZATION = 1.0 / 12.0


def test_levels_light_nested_sets_of_leds_spread_over_sites_and_colours():
    p = cal.calibration_patterns(8)
    assert p.shape == (32, 8) and set(np.unique(p)) == {0.0, 1.0}
    counts = p.sum(axis=0)
    assert list(counts) == [4, 8, 12, 16, 20, 24, 28, 32]
    assert np.all(p[:, 1:] >= p[:, :-1])  # nested: each level adds LEDs
    first = np.flatnonzero(p[:, 0])
    assert sorted(first % 4) == [0, 1, 2, 3] and len(set(first // 4)) == 4
    assert sorted(cal.calibration_led_order()) == list(range(32))
    with pytest.raises(ValueError, match='n_levels must be 2..32'):
        cal.calibration_patterns(1)


def test_streamed_moments_and_characteristic_equal_the_batch_ones():
    rng = np.random.default_rng(0)
    stacks = ctarget.simulate_calibration_frames(NoiseModel(0.7, 66.0), n_levels=3, n_frames=15,
                                             shape=(8, 12), rng=rng)
    moments = []
    for stack in stacks:
        acc, split = nfit.PixelMoments(), nfit.SplitMoments()
        for frame in stack:
            acc.add(frame)
            split.add(frame)
        np.testing.assert_allclose(acc.mean(), stack.astype(np.float64).mean(axis=0), rtol=1e-12)
        np.testing.assert_allclose(acc.variance(), stack.astype(np.float64).var(axis=0, ddof=1),
                                   rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(split.mean(), acc.mean(), rtol=1e-12)
        (mean_a, var_a, n_a), (mean_b, var_b, n_b) = split.moments()
        assert (n_a, n_b) == (8, 7)  # even frames, odd frames
        np.testing.assert_allclose(var_b, stack[1::2].astype(np.float64).var(axis=0, ddof=1),
                                   rtol=1e-9, atol=1e-9)
        moments.append(split.moments())
    a, b = nfit.noise_characteristic(stacks), nfit.characteristic_from_moments(moments)
    np.testing.assert_allclose(a.bin_mean, b.bin_mean)
    np.testing.assert_allclose(a.bin_var, b.bin_var, rtol=1e-9)
    np.testing.assert_allclose(a.bin_dof, b.bin_dof)
    # the display moments are every frame's: the two halves recombined
    all_var = np.concatenate([s.astype(np.float64).var(axis=0, ddof=1).ravel() for s in stacks])
    assert np.all(np.isin(np.round(a.pixel_var, 6), np.round(all_var, 6)))
    assert a.bin_dof.sum() <= len(a.pixel_mean) * 13  # 7 + 6 dof per pixel at most


def test_fewer_than_three_frames_per_level_are_refused_with_the_reason():
    frames = ctarget.simulate_calibration_frames(NoiseModel(), n_levels=3, n_frames=2, shape=(8, 12),
                                             rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match='level 0: 2 frames; the fit needs at least 3 frames '
                                         'per level: .*two interleaved halves'):
        nfit.fit_noise_model(frames)
    with pytest.raises(ValueError, match='frames_per_level must be >= 3, got 2: .*halves'):
        cal.CalibrationSettings(frames_per_level=2)
    split = nfit.SplitMoments()
    split.add(frames[0][0])
    with pytest.raises(ValueError, match='1 frames; the fit needs at least 3'):
        split.moments()


@pytest.fixture(scope='module')
def target(tmp_path_factory):
    path = ctarget.write_calibration_target(tmp_path_factory.mktemp('target') / 'target',
                                        shape=(24, 32), dimmer=1.0)
    return load_capture(path, cache=False)


def test_calibration_target_capture_folder(target, tmp_path):
    assert target.sample_names == [ctarget.CALIBRATION_TARGET_NAME]
    all_on = target.models[0].sum(axis=(0, 1))
    assert all_on.max() == pytest.approx(1.1 * 1023, rel=1e-3)  # the top level saturates
    assert all_on.min() > 0.03 * all_on.max()  # a ramp, no black pixels
    (tmp_path / 'x').write_text('x')
    with pytest.raises(ValueError, match='not empty'):
        ctarget.write_calibration_target(tmp_path, shape=8)


def test_calibrating_the_simulated_stage_recovers_its_noise(target):
    exposure_us, gain_db = 5000, 15.0
    cam = SimCamera(target, dimmer=1.0, seed=3)
    settings = cal.CalibrationSettings(exposure_us=exposure_us, gain_db=gain_db,
                                       frames_per_level=24, levels=6)
    progress = []
    result = cal.calibrate_noise(sim_grab(cam, exposure_us, gain_db), settings,
                                 on_frames=lambda *a: progress.append(a))
    assert progress[0] == (1, 6, 16, 24, 5) and progress[-1] == (6, 6, 24, 24, 32)
    truth = PAPER_CALIBRATION.at(gain_db, exposure_us / 1000)
    se_p, se_r = result.stderr
    assert result.model.gain_db == gain_db and result.model.exposure_ms == 5.0
    assert abs(result.model.sigma_p2 - truth.sigma_p2) < 4 * se_p, (result.model, result.stderr)
    assert abs(result.model.sigma_r2 - (truth.sigma_r2 + QUANTIZATION)) < 4 * se_r
    assert result.leds_lit == [5, 11, 16, 21, 27, 32] and result.image_shape == (24, 32)
    assert result.warnings() == []
    general = result.generalized()
    assert set(general) == set(SETTINGS)


def test_cancel_and_a_dark_stage_are_reported(target):
    cam = SimCamera(target, dimmer=1.0, seed=3)
    settings = cal.CalibrationSettings(exposure_us=1000, frames_per_level=4, levels=2)
    with pytest.raises(CaptureCancelled, match='level 1 of 2'):
        cal.calibrate_noise(sim_grab(cam, 1000, 15.0), settings, cancelled=lambda: True)
    black = lambda patterns: [np.zeros((24, 32), np.uint16)] * patterns.shape[1]  # noqa: E731
    with pytest.raises(AcquisitionError, match='fewer than 10 usable pixels.*calibration target'):
        cal.calibrate_noise(black, settings)


def test_noise_file_round_trip_and_errors(tmp_path):
    model = NoiseModel(0.71, 65.5, gain_db=15.0, exposure_ms=30.0)
    path = save_noise_file(tmp_path / 'noise.yaml', model, (0.004, 0.3), {'levels': 8})
    assert load_noise_file(path) == model
    doc = yaml.safe_load(path.read_text())
    assert doc['stderr'] == {'sigma_p2': 0.004, 'sigma_r2': 0.3}
    assert doc['generalized']['sigma3']['sigma_r2'] == pytest.approx(model.at(17.5, 22.5).sigma_r2)
    assert noise_setting(str(path)) == model
    assert noise_setting('sigma3').sigma_r2 == 117.37 and noise_setting('none') is None
    (tmp_path / 'other.yaml').write_text('a: 1\n')
    for name, match in (('missing.yaml', 'cannot read'), ('other.yaml', 'not a noise calibration')):
        with pytest.raises(NoiseFileError, match=match):
            load_noise_file(tmp_path / name)
    (tmp_path / 'bad.yaml').write_text('kind: lightstage-noise-calibration\nversion: 1\n'
                                       'noise_model: {sigma_p2: -1, sigma_r2: 3, gain_db: 1, '
                                       'exposure_ms: 2}\n')
    with pytest.raises(NoiseFileError, match=r'noise_model.sigma_p2 = -1.0 is out of range'):
        load_noise_file(tmp_path / 'bad.yaml')


def test_the_sim_camera_generalizes_a_calibrated_noise_file(tmp_path, target):
    from lightstage_camera.camera_node import noise_calibration
    model = NoiseModel(0.3, 20.0, gain_db=10.0, exposure_ms=5.0)
    path = save_noise_file(tmp_path / 'n.yaml', model)
    assert noise_calibration('') == PAPER_CALIBRATION
    cam = SimCamera(target, calibration=noise_calibration(str(path)))
    got = cam.noise_model(10000, 16.0)
    assert got == model.at(16.0, 10.0)


def test_calibration_outputs_are_written_and_not_replaced_unless_asked(tmp_path, target):
    cam = SimCamera(target, dimmer=1.0, seed=4)
    settings = cal.CalibrationSettings(exposure_us=1000, frames_per_level=6, levels=3)
    result = cal.calibrate_noise(sim_grab(cam, 1000, 15.0), settings)
    noise, plot = couts.write_calibration_outputs(result, tmp_path / 'sub' / 'noise.yaml',
                                                tmp_path / 'noise.png', measured_at='now')
    assert load_noise_file(noise) == result.model
    doc = yaml.safe_load(open(noise))
    assert doc['measured']['levels'] == 3 and doc['measured']['at'] == 'now'
    assert open(plot, 'rb').read(8) == b'\x89PNG\r\n\x1a\n'
    with pytest.raises(DestinationError, match='already exists'):
        couts.write_calibration_outputs(result, noise)
    assert couts.write_calibration_outputs(result, '', '') == ('', '')


def test_synth_writes_a_calibration_target_folder(tmp_path):
    from lightstage_physics import synth_cli
    assert synth_cli.main([str(tmp_path / 't'), '--calibration-target', '--size', '16',
                       '--dimmer', '1.0', '--quiet']) == 0
    ms = load_capture(tmp_path / 't', cache=False)
    assert ms.sample_names == [ctarget.CALIBRATION_TARGET_NAME] and ms.image_shape == (12, 16)
    assert synth_cli.main([str(tmp_path / 't'), '--calibration-target', '--quiet']) == 2  # not empty


def test_output_paths_are_checked_before_anything_is_lit(tmp_path):
    assert couts.check_calibration_outputs('', '') == (None, None)
    noise, plot = couts.check_calibration_outputs(tmp_path / 'n.yaml', tmp_path / 'n.pdf')
    assert (noise.name, plot.name) == ('n.yaml', 'n.pdf')
    with pytest.raises(DestinationError, match=r'plot .*noise\.txt should end in one of \.png'):
        couts.check_calibration_outputs('', tmp_path / 'noise.txt')
    with pytest.raises(DestinationError, match=r'noise file .*noise\.png should end in .*\.yaml'):
        couts.check_calibration_outputs(tmp_path / 'noise.png')
    with pytest.raises(DestinationError, match='should end'):  # one file cannot be both
        couts.check_calibration_outputs(tmp_path / 'same.yaml', tmp_path / 'same.yaml')


def test_a_failed_write_keeps_the_fit_in_the_error(tmp_path, target, monkeypatch):
    cam = SimCamera(target, dimmer=1.0, seed=4)
    settings = cal.CalibrationSettings(exposure_us=1000, frames_per_level=6, levels=3)
    stages = []
    result = cal.calibrate_noise(sim_grab(cam, 1000, 15.0), settings,
                                 on_frames=lambda *a: stages.append('capturing'),
                                 on_fitting=lambda: stages.append('fitting'))
    assert stages[-1] == 'fitting' and stages.count('fitting') == 1

    def full_disk(*_a, **_k):
        raise OSError(28, 'No space left on device')

    from lightstage_physics import camera_plots
    monkeypatch.setattr(camera_plots, 'plot_noise_characteristic', full_disk)
    with pytest.raises(DestinationError) as err:
        couts.write_calibration_outputs(result, tmp_path / 'noise.yaml', tmp_path / 'noise.png')
    message = str(err.value)
    assert 'No space left' in message and f'sigma_p2 = {result.model.sigma_p2:.6g}' in message
    assert 'written: ' in message and 'noise.yaml' in message  # the noise file made it


def test_overwrite_replaces_a_noise_file_and_a_plot_but_not_a_captures_rig_yaml(tmp_path, target):
    """`lightstage calibrate CAPTURE/rig.yaml --overwrite` (and the page's calibrate with that
    output_path) replaced the capture's rig.yaml with a noise file: the capture no longer
    loaded. overwrite replaces only a file of the kind being written."""
    cam = SimCamera(target, dimmer=1.0, seed=4)
    result = cal.calibrate_noise(sim_grab(cam, 1000, 15.0),
                                 cal.CalibrationSettings(exposure_us=1000, frames_per_level=6, levels=3))
    capture = ctarget.write_calibration_target(tmp_path / 'capture', shape=(24, 32), dimmer=1.0)
    rig = capture / 'rig.yaml'
    before = rig.read_bytes()
    with pytest.raises(DestinationError, match=r'rig\.yaml exists and is not a noise file; '
                                               r'overwrite replaces only a noise file'):
        couts.write_calibration_outputs(result, rig, overwrite=True)
    assert rig.read_bytes() == before
    assert len(load_capture(capture, cache=False)) == 1  # the capture still loads
    other = tmp_path / 'notes.png'
    other.write_text('my notes, not an image')
    with pytest.raises(DestinationError, match='notes.png exists and is not a plot'):
        couts.check_calibration_outputs('', other, overwrite=True)
    # a noise file and a plot of an earlier calibration are replaced
    noise, plot = couts.write_calibration_outputs(result, tmp_path / 'noise.yaml', tmp_path / 'n.png')
    again = couts.write_calibration_outputs(result, noise, plot, overwrite=True, measured_at='later')
    assert again == (noise, plot) and yaml.safe_load(open(noise))['measured']['at'] == 'later'
    (tmp_path / 'empty.yaml').touch()  # nothing in it to lose
    assert couts.check_calibration_outputs(tmp_path / 'empty.yaml', overwrite=True)[0].name == 'empty.yaml'
